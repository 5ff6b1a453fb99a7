//! `envlight render`: a scene under the lights of each frame (decomposed here, read from a
//! `--lights` file, or ASG lobes fitted here), written as PNG and EXR with per-frame stats.

use super::{
    open_source, parse_finite_f32, parse_point, parse_render_size, parse_shadow_raster,
    usage_error, Utf8Input,
};
use anyhow::{anyhow, bail, Context, Result};
use clap::{Args, ValueEnum};
use envlight::config::{ConfigError, RawConfig};
use envlight::decompose::Decomposer;
use std::io::Write;
use std::path::PathBuf;

pub(crate) const LONG_ABOUT: &str = "\
Render a scene (glTF 2.0 / OBJ via --scene, or the built-in spheres on a ground plane) under
directional lights with per-light PCF shadows, on the best graphics adapter (a GPU, else Mesa's
lavapipe). Lights come from --lights (the JSON Lines of `envlight decompose`), from INPUT frames
decomposed in-process, or from the built-in sky (1 frame unless --frames says otherwise).
Writes OUT/frame_NNNNN.png (tone-mapped sRGB, RGBA), OUT/frame_NNNNN.exr (linear, premultiplied
RGBA) and OUT/stats.jsonl (lights, shadow maps and time of every frame).
--catcher makes the ground a shadow catcher (RGBA to composite over a camera image);
--background composites over the environment map (not with --lights).
--budget-ms holds a frame time by rendering a prefix of the progressive light set (the other
lights' power merged into their nearest prefix light).
--lighting asg shades instead with ASG lobes fitted to each INPUT frame (or sky frame), in closed
form (Lambert + GGX, each lobe with a soft shadow; --lobes, --fit-height); --lighting sh with the
frame's spherical-harmonic coefficients (Lambert + GGX, unshadowed ambient light; --degree). Lobes
and coefficients are filtered in time with the lights' default taps, as the lights are.";

#[derive(Args, Debug)]
pub(crate) struct RenderArgs {
    /// .exr/.hdr frames to decompose in-process. None (and no --lights): the built-in sky.
    #[arg(value_name = "INPUT", conflicts_with = "lights", value_parser = Utf8Input)]
    inputs: Vec<String>,
    /// Light list: JSON Lines as written by `envlight decompose`.
    #[arg(long, value_name = "FILE")]
    lights: Option<PathBuf>,
    /// Scene file (.gltf, .glb, .obj; glTF base-colour, metallic-roughness, normal, occlusion
    /// and emissive textures, vertex colours, emission, alpha cut-outs and blending, the index
    /// of refraction, specular and clear-coat factors, and an MTL's map_Kd, Ke, map_Ke, map_d,
    /// d, Pr, Pm, Pc and Pcr are drawn, and unlit materials; PNG, JPEG or WebP; Draco- or
    /// meshopt-compressed geometry is decoded; glTF node animations and skins play, see
    /// --animation).
    /// [default: built-in spheres on a ground plane]
    #[arg(long, value_name = "FILE")]
    scene: Option<PathBuf>,
    /// Image size, 1..=16384 a side (the GPU's own limit applies too: 16384 on most).
    #[arg(long, value_name = "WxH", value_parser = parse_render_size, default_value = "640x360")]
    size: (u32, u32),
    /// Output folder (created if missing). Required unless --window.
    #[arg(long, value_name = "DIR", required_unless_present = "window")]
    out: Option<PathBuf>,
    /// Lights per frame when decomposing INPUT or the sky (1..=16384). [default: 256]
    #[arg(long, short = 'n', value_name = "N")]
    light_count: Option<usize>,
    /// Frames to render; 0 = every frame (the sky: until stopped). [default: every frame of
    /// --lights or INPUT; 1 for the sky]
    #[arg(long, value_name = "N")]
    frames: Option<u64>,
    /// Shadow-map side in texels (16..=8192). [default: 512]
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u32).range(16..=8192))]
    shadow_res: Option<u32>,
    /// Supersampling anti-aliasing: render at N times the width and height and average each
    /// pixel's N × N samples (1..=4; about N² the shading time and G-buffer memory).
    /// [default: 1, off]
    #[arg(
        long,
        value_name = "N",
        value_parser = clap::value_parser!(u32)
            .range(1..=i64::from(envlight::render::supersample::MAX_SUPERSAMPLE))
    )]
    supersample: Option<u32>,
    /// The camera's position, X,Y,Z in the scene's coordinates (+Y up). [default: a glTF
    /// scene's first camera, else one fitted to the scene]
    #[arg(long, value_name = "X,Y,Z", value_parser = parse_point, allow_hyphen_values = true)]
    eye: Option<[f32; 3]>,
    /// The point the camera looks at, X,Y,Z (the camera keeps its up direction: +Y, level,
    /// unless a glTF camera is rolled).
    #[arg(long, value_name = "X,Y,Z", value_parser = parse_point, allow_hyphen_values = true)]
    look_at: Option<[f32; 3]>,
    /// The camera's vertical field of view in degrees (1..=179); it makes a glTF scene's
    /// orthographic camera a perspective one. [default: the scene camera's; 40 for a fitted one]
    #[arg(long, value_name = "DEG", value_parser = parse_finite_f32)]
    fov: Option<f32>,
    /// An orthographic camera showing this many scene units from the bottom of the image to
    /// its top (parallel rays along the view: sizes do not shrink with distance, as for
    /// product shots and plans); its width follows the image's aspect ratio. Not with --fov.
    #[arg(long, value_name = "UNITS", value_parser = parse_finite_f32, conflicts_with = "fov")]
    ortho_height: Option<f32>,
    /// Fast approximate anti-aliasing (FXAA 3.11, quality variant) of each frame: edges
    /// smoothed along their length from the image alone, at a small part of supersampling's
    /// cost (docs/rendering.md, "Anti-aliasing"). Not with --supersample above 1.
    #[arg(long)]
    fxaa: bool,
    /// How the shadow maps are drawn: `pipeline`, a depth-only render pass per light, or
    /// `compute`, compute shaders (faster where the raster pipeline is a small part of the GPU,
    /// as on an H200), or `auto`: compute on a GPU, pipeline on a CPU rasteriser such as
    /// lavapipe (docs/rendering.md). [default: auto]
    #[arg(long, value_name = "HOW", value_parser = parse_shadow_raster)]
    shadow_raster: Option<envlight::render::ShadowRaster>,
    /// No shadows.
    #[arg(long)]
    no_shadows: bool,
    /// No per-pixel light culling (every light takes the full path).
    #[arg(long)]
    no_culling: bool,
    /// The ground plane catches shadows: RGBA output to composite over a camera image.
    #[arg(long)]
    catcher: bool,
    /// Composite over the environment map (INPUT frames or the sky).
    #[arg(long, conflicts_with = "lights")]
    background: bool,
    /// Frame-time budget in ms: render the prefix of the light set (by id) that holds it.
    #[arg(long, value_name = "MS")]
    budget_ms: Option<f64>,
    /// Exposure scale before tone mapping. [default: from the median luminance of the first
    /// frame with lit pixels]
    #[arg(long, value_name = "X", value_parser = parse_finite_f32)]
    exposure: Option<f32>,
    /// The glTF animation to play: by index (0, 1, …) or name, or `none` for the scene's rest
    /// pose. The frames' capture times are its clock, from the first frame's (plus
    /// --animation-start); it loops. [default: the scene's first animation]
    #[arg(long, value_name = "CLIP")]
    animation: Option<String>,
    /// Where the animation stands at the first frame, in seconds (with one frame, the pose
    /// drawn). [default: 0]
    #[arg(long, value_name = "SECONDS", value_parser = parse_seconds)]
    animation_start: Option<f64>,
    /// Show the frames in a window instead of writing files (needs the `window` feature).
    #[arg(long, conflicts_with = "background")]
    window: bool,
    /// Shade with the decomposed lights (shadow maps), with ASG lobes fitted to each frame
    /// (closed-form Lambert + GGX, each lobe shadowed by a soft shadow map along its axis;
    /// warm-started from frame to frame), or with each frame's SH coefficients (closed-form
    /// Lambert + GGX, no shadows; also not with --catcher, --shadow-res or --shadow-raster).
    /// asg and sh: not with --lights, --window, --budget-ms, --light-count or --no-culling.
    #[arg(long, value_enum, default_value = "lights")]
    lighting: LightingArg,
    /// ASG lobes per frame with --lighting asg (1..=64). [default: 16]
    #[arg(long, value_name = "K")]
    lobes: Option<usize>,
    /// Fit-map height with --lighting asg (width is twice; 4..=1024). [default: 64]
    #[arg(long, value_name = "H")]
    fit_height: Option<u32>,
    /// SH degree with --lighting sh: (L + 1)² coefficients per channel (0..=15). [default: 2]
    #[arg(long, value_name = "L")]
    degree: Option<usize>,
}

/// `render --shadow-res` when not given.
const DEFAULT_SHADOW_RES: u32 = 512;

impl RenderArgs {
    /// The options that the chosen lighting or light source would ignore are usage errors.
    fn check_usage(&self) -> Result<()> {
        if self.lighting != LightingArg::Lights {
            // The value as given on the command line (clap's name of the variant).
            let name = self
                .lighting
                .to_possible_value()
                .map_or_else(String::new, |v| v.get_name().to_owned());
            let with = [
                (self.lights.is_some(), "--lights"),
                (self.window, "--window"),
                (self.budget_ms.is_some(), "--budget-ms"),
                (self.light_count.is_some(), "--light-count"),
                (self.no_culling, "--no-culling"),
            ];
            if let Some((_, flag)) = with.iter().find(|(given, _)| *given) {
                usage_error!(
                    "--lighting {name} is computed from INPUT frames or the sky; {flag} applies to directional lights"
                );
            }
        }
        if self.lighting != LightingArg::Asg && (self.lobes.is_some() || self.fit_height.is_some())
        {
            usage_error!("--lobes and --fit-height apply to --lighting asg");
        }
        if self.lighting == LightingArg::Sh {
            let with = [
                (self.catcher, "--catcher"),
                (self.shadow_res.is_some(), "--shadow-res"),
                (self.shadow_raster.is_some(), "--shadow-raster"),
            ];
            if let Some((_, flag)) = with.iter().find(|(given, _)| *given) {
                usage_error!(
                    "--lighting sh is unshadowed ambient light; {flag} applies to shadows (use --lighting lights or asg)"
                );
            }
            if let Some(degree) = self.degree.filter(|&l| l > envlight::sh::MAX_DEGREE) {
                usage_error!(
                    "invalid --degree {degree}: must be an integer in 0..={}",
                    envlight::sh::MAX_DEGREE
                );
            }
        } else if self.degree.is_some() {
            usage_error!("--degree applies to --lighting sh");
        }
        if self.no_shadows && self.shadow_res.is_some() {
            usage_error!("--shadow-res sizes the shadow maps; with --no-shadows there are none");
        }
        if self.no_shadows && self.shadow_raster.is_some() {
            usage_error!("--shadow-raster draws the shadow maps; with --no-shadows there are none");
        }
        if self.lights.is_some() && self.light_count.is_some() {
            usage_error!(
                "--light-count sets the lights of frames decomposed here (INPUT or the sky); --lights renders every light of each frame in the file"
            );
        }
        if self.fxaa && self.supersample.is_some_and(|n| n > 1) {
            usage_error!(
                "--fxaa with --supersample above 1: FXAA would blur the resolved edges; choose one"
            );
        }
        Ok(())
    }
}

/// A time in seconds: a finite number (negative allowed: the clip loops).
fn parse_seconds(s: &str) -> Result<f64, String> {
    match s.trim().parse::<f64>() {
        Ok(x) if x.is_finite() => Ok(x),
        _ => Err(format!("{s:?} is not a finite number of seconds")),
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
enum LightingArg {
    /// Directional lights from the decomposition, with shadow maps.
    Lights,
    /// Anisotropic spherical Gaussians fitted to each frame, in closed form.
    Asg,
    /// Spherical harmonics projected from each frame, in closed form, unshadowed.
    Sh,
}

impl LightingArg {
    /// What `FrameStats::lights` counts.
    fn counted(self) -> &'static str {
        match self {
            LightingArg::Lights => "lights",
            LightingArg::Asg => "lobes",
            LightingArg::Sh => "SH coefficients a channel",
        }
    }
}

/// The frames of `render --lights`, read as they are rendered.
struct LightFileFrames {
    /// The first frame, read before rendering starts.
    first: Option<envlight::LightFrame>,
    reader: envlight::light::JsonLinesReader,
    /// The seqs rendered so far.
    seen: std::collections::HashSet<u64>,
}

impl LightFileFrames {
    /// The next frame, or the error of its line; a seq seen before is an error (each frame's
    /// images are named by its seq, so a repeat would overwrite them).
    fn next_frame(&mut self) -> Result<Option<envlight::LightFrame>> {
        let frame = match self.first.take() {
            Some(frame) => frame,
            None => match self.reader.next().transpose()? {
                Some(frame) => frame,
                None => return Ok(None),
            },
        };
        if !self.seen.insert(frame.seq) {
            bail!(
                "{}: frame seq {} appears more than once; the images of a frame are named by \
                 its seq (frame_NNNNN), so a repeat would overwrite them",
                self.reader.path().display(),
                frame.seq
            );
        }
        Ok(Some(frame))
    }
}

pub(crate) fn run(args: &RenderArgs) -> Result<()> {
    use envlight::render::{self, budget, output, scene::Scene, RenderSettings, Renderer};
    args.check_usage()?;
    if let Some(b) = args.budget_ms.filter(|b| !(b.is_finite() && *b > 0.0)) {
        crate::cli::usage_error!(
            "invalid --budget-ms {b}: must be a positive number of milliseconds"
        );
    }
    if args.exposure.is_some_and(|e| !(e.is_finite() && e > 0.0)) {
        crate::cli::usage_error!("invalid --exposure: must be a positive number");
    }
    let mut scene = match &args.scene {
        Some(path) => Scene::load(path, true)?,
        None => Scene::default_scene(),
    };
    let camera = envlight::render::scene::CameraOverride {
        eye: args.eye.map(glam::Vec3::from_array),
        look_at: args.look_at.map(glam::Vec3::from_array),
        fov_deg: args.fov,
        ortho_height: args.ortho_height,
    };
    scene.camera = match camera.apply(scene.camera) {
        Ok(c) => c,
        Err(m) => crate::cli::usage_error!("invalid camera: {m}"),
    };
    if camera != envlight::render::scene::CameraOverride::default() {
        // Placed by hand: an animated camera node no longer moves it.
        scene.hold_camera();
    }
    if let Some(clip) = &args.animation {
        let choice = envlight::render::scene::AnimationChoice::parse(clip);
        if let Err(m) = scene.select_animation(&choice) {
            crate::cli::usage_error!("invalid --animation {clip:?}: {m}");
        }
    }
    if let Some((index, name, seconds)) = scene.playing_animation() {
        tracing::info!(
            "animation {index} ({name:?}): {seconds:.3} s, looped over the frames' times"
        );
    }
    tracing::info!("scene: {}", scene.summary());
    tracing::info!("camera: {}", scene.camera.describe());
    let asg_lighting = args.lighting == LightingArg::Asg;
    let sh_lighting = args.lighting == LightingArg::Sh;
    // The projection plan of the frames' shape is kept from frame to frame.
    let mut sh_projector = if sh_lighting {
        // Filtered in time with the lights' default taps, as the lights of `--lighting lights`
        // and the daemon's SH stage are.
        let settings = envlight::sh_stage::ShSettings {
            degree: args.degree.unwrap_or(envlight::sh_stage::DEFAULT_DEGREE),
            ..envlight::sh_stage::ShSettings::default()
        };
        Some(
            envlight::sh_stage::ShProjector::new(settings)
                .map_err(|e| crate::cli::usage(format!("invalid --degree: {e}")))?,
        )
    } else {
        None
    };
    let mut fitter = if asg_lighting {
        let settings = envlight::asg::fit::FitSettings {
            lobes: args.lobes.unwrap_or(envlight::asg::fit::DEFAULT_LOBES),
            height: args
                .fit_height
                .unwrap_or(envlight::config::DEFAULT_ASG_FIT_HEIGHT),
            ..envlight::asg::fit::FitSettings::default()
        };
        // Name the flag at fault (both were named whichever it was).
        let fitter = envlight::asg::fit::AsgFitter::new(settings).map_err(|e| {
            let flag = match &e {
                envlight::asg::AsgError::MapSize { .. } => "--fit-height",
                envlight::asg::AsgError::LobeCount(_) => "--lobes",
                _ => "--lobes or --fit-height",
            };
            crate::cli::usage(format!("invalid {flag}: {e}"))
        })?;
        // The lobes filtered in time with the lights' default taps, as the lights of
        // `--lighting lights` and the daemon's ASG stage are.
        let filter = envlight::asg::temporal::LobeFilter::new(Some(
            &envlight::decompose::filter::DEFAULT_TAPS,
        ))
        .map_err(|rule| anyhow::anyhow!("the default taps are refused: {rule}"))?;
        Some((fitter, filter))
    } else {
        None
    };
    // Lights: a JSON Lines file, or frames decomposed here (INPUT or the sky).
    let mut from_file = None;
    let mut source = None;
    // The files read, which no output may overwrite.
    let mut inputs: Vec<PathBuf> = args.lights.iter().cloned().collect();
    if let Some(path) = &args.lights {
        // Read a frame at a time (a long session is gigabytes of JSON); the first frame is read
        // here, so an empty or unreadable file is refused before the GPU is set up.
        let mut reader = envlight::light::JsonLinesReader::open(path)?;
        let Some(first) = reader.next().transpose()? else {
            bail!(
                "{}: no light frames in it (expected the JSON Lines of `envlight decompose`)",
                path.display()
            );
        };
        from_file = Some(LightFileFrames {
            first: Some(first),
            reader,
            seen: std::collections::HashSet::new(),
        });
    } else {
        let mut raw = RawConfig::default();
        if !args.inputs.is_empty() {
            raw.source.kind = Some("sequence".into());
            raw.source.paths = Some(args.inputs.clone());
        }
        raw.source.frames = Some(args.frames.unwrap_or(u64::from(args.inputs.is_empty())));
        raw.decompose.lights = args.light_count;
        let config = raw.validate().map_err(|e| match &e {
            ConfigError::Invalid {
                key: "decompose.lights",
                value,
                message,
            } => crate::cli::usage(format!("invalid --light-count {value}: {message}")),
            _ => anyhow!(e).context("invalid INPUT"),
        })?;
        let src = open_source(&config)?;
        inputs.extend_from_slice(src.files());
        let dec =
            Decomposer::new(config.decompose.clone()).context("invalid decomposition settings")?;
        source = Some((src, dec));
    }
    let settings = RenderSettings {
        width: args.size.0,
        height: args.size.1,
        shadow_resolution: args.shadow_res.unwrap_or(DEFAULT_SHADOW_RES),
        shadows: !args.no_shadows,
        culling: !args.no_culling,
        shadow_catcher: args.catcher,
        shadow_raster: args.shadow_raster.unwrap_or_default(),
        supersample: args.supersample.unwrap_or(1),
        fxaa: args.fxaa,
        ..RenderSettings::default()
    };
    let mut next_frame =
        move || -> Result<Option<(envlight::LightFrame, Option<envlight::HdrFrame>)>> {
            if let Some(frames) = &mut from_file {
                return Ok(frames.next_frame()?.map(|f| (f, None)));
            }
            let Some((src, dec)) = &mut source else {
                return Ok(None);
            };
            Ok(src
                .next_frame()
                .context("cannot read a frame")?
                .map(|frame| {
                    // ASG and SH lighting use the frame itself; the lights are not needed.
                    let lights = if asg_lighting || sh_lighting {
                        envlight::LightFrame {
                            seq: frame.seq,
                            time: frame.time,
                            lights: Vec::new(),
                        }
                    } else {
                        dec.decompose(&frame)
                    };
                    (lights, Some(frame))
                }))
        };
    // The scene's clock: each frame's time from the first frame's, plus --animation-start.
    let animation_start = args.animation_start.unwrap_or(0.0);
    let mut first_time = None;
    let mut scene_time = move |frame_time: f64| {
        animation_start + (frame_time - *first_time.get_or_insert(frame_time))
    };
    let Some(out) = args.out.as_ref().filter(|_| !args.window) else {
        #[cfg(feature = "window")]
        {
            let source = Box::new(move || {
                next_frame()
                    .map(|f| {
                        f.map(|(mut l, _)| {
                            l.time = scene_time(l.time);
                            l
                        })
                    })
                    .map_err(|e| format!("{e:#}"))
            });
            let exposure = args.exposure.unwrap_or(0.02);
            render::window::run(scene, settings, exposure, args.budget_ms, source)?;
            return Ok(());
        }
        #[cfg(not(feature = "window"))]
        bail!("--window needs envlight built with `--features window`");
    };
    // --out is a folder of frame_NNNNN.png/.exr and stats.jsonl; `--out frame.png` would make
    // a folder of that name.
    let image_extension = out.extension().and_then(|e| e.to_str()).is_some_and(|e| {
        ["png", "exr", "hdr", "jpg", "jpeg"].contains(&e.to_ascii_lowercase().as_str())
    });
    if image_extension && !out.is_dir() {
        usage_error!(
            "--out {} looks like an image file, but --out is the folder the frames \
             (frame_00000.png, .exr) and stats.jsonl are written to; give a folder",
            out.display()
        );
    }
    // Before the GPU starts: an existing file was found only when the folder was created
    // ("File exists", without the option).
    if out.exists() && !out.is_dir() {
        usage_error!(
            "--out {} is a file, but --out is the folder the frames (frame_00000.png, .exr) \
             and stats.jsonl are written to; give a folder",
            out.display()
        );
    }
    let inputs = crate::cli::output::InputFiles::new(&inputs);
    let mut renderer = Renderer::new(scene, settings)?;
    tracing::info!(
        "adapter: {}; shadow maps: {}",
        renderer.gpu().describe(),
        renderer.settings().shadow_raster.name()
    );
    std::fs::create_dir_all(out)
        .with_context(|| format!("cannot create the --out folder {}", out.display()))?;
    let stats_path = out.join("stats.jsonl");
    let mut stats_file =
        std::io::BufWriter::new(crate::cli::output::create(&stats_path, "--out", &inputs)?);
    let mut controller = None;
    let mut warned_budget_cap = false;
    let mut exposure = args.exposure;
    let limit = args.frames.filter(|&n| n > 0);
    let mut done = 0u64;
    while limit.is_none_or(|n| done < n) {
        let Some((lights, env)) = next_frame()? else {
            break;
        };
        renderer.set_scene_time(scene_time(lights.time));
        let all = render::light_prefix(&lights.lights, usize::MAX);
        // The controller's range is every light a list can hold, not the first frame's count
        // (which capped every later frame: a first frame of one light left one of 70 at one).
        let ctl = controller.get_or_insert_with(|| {
            args.budget_ms.map(|ms| {
                let settings = budget::BudgetSettings::new(ms, envlight::decompose::MAX_POINTS);
                budget::BudgetController::new(settings, all.len())
            })
        });
        let count = ctl.as_ref().map_or(all.len(), |c| c.count());
        if ctl.is_some() && all.len() > envlight::decompose::MAX_POINTS && !warned_budget_cap {
            warned_budget_cap = true;
            tracing::warn!(
                "frame {} has {} lights; --budget-ms draws at most {} of them (the first by id, \
                 a prefix of the progressive set; without --budget-ms every light is drawn)",
                lights.seq,
                all.len(),
                envlight::decompose::MAX_POINTS
            );
        }
        let (mut image, stats) = match (&mut fitter, &mut sh_projector, &env) {
            (Some((fitter, filter)), _, Some(frame)) => {
                let mut lobes = fitter
                    .fit_frame(frame)
                    .with_context(|| format!("cannot fit ASG lobes to frame {}", frame.seq))?
                    .lobes;
                filter.apply(&mut lobes);
                renderer.render_asg(&lobes)?
            }
            (None, Some(projector), Some(frame)) => {
                renderer.render_sh(&projector.coefficients(frame))?
            }
            _ => renderer.render(&render::light_prefix(&all, count))?,
        };
        if let Some(c) = ctl.as_mut() {
            c.update(stats.frame_ms());
        }
        if let (true, Some(env)) = (args.background, &env) {
            let rays: Vec<_> = (0..image.height)
                .flat_map(|y| (0..image.width).map(move |x| (x, y)))
                .map(|(x, y)| renderer.pixel_ray(x as f32, y as f32))
                .collect();
            let w = image.width;
            output::composite_background(&mut image, |x, y| {
                let d = rays[(y * w + x) as usize].as_dvec3();
                env.projection
                    .direction_to_pixel(env.width, env.height, d)
                    .map_or([0.0; 3], |(px, py)| {
                        env.pixel(
                            (px as u32).min(env.width - 1),
                            (py as u32).min(env.height - 1),
                        )
                    })
            });
        }
        let saturated = output::saturate(&mut image);
        if saturated.infinite > 0 {
            tracing::warn!(
                "frame {}: {} pixel values beyond f32's range (lights too bright to sum) \
                 written as the largest f32",
                lights.seq,
                saturated.infinite
            );
        }
        if saturated.nan > 0 {
            tracing::warn!(
                "frame {}: {} pixel values not a number (a shading fault; please report it \
                 with the light list) written as 0",
                lights.seq,
                saturated.nan
            );
        }
        // Fixed from the first frame with lit pixels (one with no lights tells nothing: its
        // fallback of 1 was kept for every later frame, which came out nearly white).
        if exposure.is_none() {
            exposure = output::auto_exposure(&image);
        }
        let exp = exposure.unwrap_or(1.0);
        let stem = out.join(format!("frame_{:05}", lights.seq));
        for extension in ["png", "exr"] {
            inputs.refuse(&stem.with_extension(extension), "--out")?;
        }
        output::write_png(&stem.with_extension("png"), &image, exp)?;
        output::write_exr(&stem.with_extension("exr"), &image)?;
        let line = serde_json::json!({
            "seq": lights.seq, "lights": stats.lights, "shadow_maps": stats.shadow_maps,
            "gpu_ms": stats.gpu_ms, "shadow_gpu_ms": stats.shadow_gpu_ms,
            "cpu_ms": stats.cpu_ms, "encode_ms": stats.encode_ms, "frame_ms": stats.frame_ms(),
        });
        writeln!(stats_file, "{line}")
            .with_context(|| format!("cannot write {}", stats_path.display()))?;
        tracing::info!(
            "frame {}: {} {}, {} shadow maps, {:.2} ms ({})",
            lights.seq,
            stats.lights,
            args.lighting.counted(),
            stats.shadow_maps,
            stats.frame_ms(),
            if stats.gpu_ms.is_some() {
                "GPU timestamps"
            } else {
                "CPU time"
            }
        );
        done += 1;
    }
    stats_file
        .flush()
        .with_context(|| format!("cannot write {}", stats_path.display()))?;
    tracing::info!("rendered {done} frames into {}", out.display());
    Ok(())
}
