//! `envlight decompose`: frames (files, a camera or the built-in sky) to JSON Lines of
//! lights, optionally also the newest frame kept in a file (`--latest`).

use super::fisheye_flags::{validate_with_flags, FisheyeFlags};
use super::{on_off, open_source, parse_size, split_description, usage_error, Utf8Input};
use anyhow::{bail, Context, Result};
use clap::{Args, ValueEnum};
use envlight::config::{Config, RawConfig};
use envlight::decompose::{BrightHistory, Decomposer};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

pub(crate) const LONG_ABOUT: &str = "\
Decompose frames into directional lights and print them as JSON Lines, one object per frame:

  {\"seq\":0,\"time\":0.0,\"lights\":[{\"id\":3,\"dir\":[0.71,0.60,-0.35],\"rgb\":[812.1,790.4,701.9],\"solid_angle\":0.0021}]}

seq: frame number; time: frame time in seconds; id: the light's index in the fixed point set
(stable across frames); dir: unit direction towards the light (+Y up); rgb: integrated radiance
(W/m² at normal incidence); solid_angle: size of the light's region or merged source (sr).

Without INPUT the built-in sky is rendered (60 frames unless --frames says otherwise).
Logs go to stderr (RUST_LOG overrides the level, e.g. RUST_LOG=debug).";

#[derive(Clone, Copy, Debug, ValueEnum)]
enum ProjectionArg {
    /// Equirectangular (lat-long), row 0 = zenith.
    Latlong,
    /// Zenith-looking fisheye; see --fisheye-model, --center, --radius, --fov, --rotation.
    Fisheye,
    /// Light-probe angular map.
    Angular,
}

#[derive(Clone, Copy, Debug, ValueEnum)]
enum WarpArg {
    /// Row-by-row inverse CDF, continuous in the point (default).
    Rows,
    /// k-d tree of mass splits: steadier lights when bright sources move.
    Hierarchical,
}

#[derive(Clone, Copy, Debug, ValueEnum)]
enum BrightHistoryArg {
    /// Group the window in 0.1° cones; older groups go to the light nearest to them now
    /// (default; ids and count stay those of the point set).
    Fold,
    /// Group the window in 0.1° cones; older groups are extra lights (ids from 2^24) that fade
    /// out over the window.
    Fade,
    /// The plain per-id mean (the filter before 2026-12-01).
    Blend,
}

#[derive(Clone, Copy, Debug, ValueEnum)]
enum PlacementArg {
    /// Luminance-weighted centroid of the light's region (most accurate).
    Centroid,
    /// The warped sample point (Havran et al. 2005).
    SamplePoint,
}

#[derive(Args, Debug)]
pub(crate) struct DecomposeArgs {
    /// .exr/.hdr files, directories or glob patterns (quote globs). None: the built-in sky.
    #[arg(value_name = "INPUT", value_parser = Utf8Input)]
    inputs: Vec<String>,

    /// TOML config file (see config/envlight.toml); flags override its values.
    #[arg(long, value_name = "FILE")]
    config: Option<PathBuf>,

    /// Number of lights per frame (1..=16384; merging may leave fewer). [default: 256]
    #[arg(long, short = 'n', value_name = "N")]
    lights: Option<usize>,

    /// Frames to process; 0 = no limit. [default: 60 for the sky, every file for a sequence]
    #[arg(long, value_name = "N")]
    frames: Option<u64>,

    /// Pace frames at F frames per second (at least 0.0001). [default: as fast as possible]
    #[arg(long, value_name = "F")]
    fps: Option<f64>,

    /// Replay the input sequence forever (stop with --frames or Ctrl-C).
    #[arg(long = "loop")]
    looped: bool,

    /// How input pixels map to directions. [default: latlong]
    #[arg(long, value_enum)]
    projection: Option<ProjectionArg>,

    #[command(flatten)]
    fisheye: FisheyeFlags,

    #[command(flatten)]
    filter: crate::cli::FilterFlags,

    /// Merge lights crowding a concentrated source (the sun) into one light that records the
    /// source's spread in `solid_angle`. Off by default.
    #[arg(long)]
    merge: bool,

    /// Disable merging (overrides the config file).
    #[arg(long, conflicts_with_all = ["merge_fraction", "merge"])]
    no_merge: bool,

    /// Merge radius as a fraction of the mean light spacing, in (0, 2]; implies --merge.
    /// [default: 0.1]
    #[arg(long, value_name = "F")]
    merge_fraction: Option<f64>,

    /// Width of the internal lat-long working map in pixels (16..=4096). [default: 256]
    #[arg(long, value_name = "W")]
    working_width: Option<u32>,

    /// Threads that resample each frame that is not a lat-long map of a multiple of the working
    /// size (a fisheye camera's, an angular map's) to the working map, 1..=64, at most the
    /// machine's cores; the lights are the same with any number. [default: 2]
    #[arg(long, value_name = "N")]
    resample_threads: Option<usize>,

    /// Lights are placed with density ∝ luminance^γ, γ in (0, 1]; 1 is Havran et al.'s pure
    /// inverse-transform sampling. [default: 0.75]
    #[arg(long, value_name = "GAMMA")]
    pdf_exponent: Option<f64>,

    /// Where a light points within its region. [default: centroid]
    #[arg(long, value_enum)]
    placement: Option<PlacementArg>,

    /// How the fixed point set is warped onto the density: `rows` (continuous) or
    /// `hierarchical` (steadier under moving sources; see docs/quality.md). [default: rows]
    #[arg(long, value_enum)]
    warp: Option<WarpArg>,

    /// One Lloyd step for the lights holding lamps and suns (sharper shadows of small bright
    /// sources, 8-40% more instructions per frame than the default; docs/quality.md). Off by
    /// default.
    #[arg(long)]
    concentrated_lloyd: bool,

    /// Leave out the refinement of lamps and suns: by default the lights holding them move to
    /// their regions' centroids and the sources' full-resolution pixels go again to their
    /// nearest light (69 rows of docs/quality.md's 72 beat median cut instead of 68, for about
    /// 7–10% more time per frame on the benchmark's map).
    #[arg(long)]
    no_refine_concentrated: bool,

    /// Split the lights of bright lamps and suns: a light holding a concentrated source and
    /// more than 3.5× the mean light's energy splits into up to 8 pieces, taken from the
    /// weakest lights (sharper lamp shadows, 71 of docs/quality.md's 72 rows against 69; with
    /// the filter on, 16–18% more ground flicker on two of its four sequences). Off by default.
    #[arg(long)]
    split: bool,

    /// Do not split bright lights (overrides the config file).
    #[arg(long, conflicts_with_all = ["split", "split_factor"])]
    no_split: bool,

    /// Energy, as a multiple (≥ 1) of the mean light's, above which a light holding a
    /// concentrated source splits; implies --split. [default: 3.5]
    #[arg(long, value_name = "F")]
    split_factor: Option<f64>,

    /// What the filter does with the window of a light brighter than 10× the frame's mean light
    /// (a sun's or a lamp's, whose few pixels change hands between lights): see
    /// docs/quality.md, "Temporal stability". [default: fold]
    #[arg(long, value_enum, value_name = "HOW", conflicts_with = "no_filter")]
    bright_history: Option<BrightHistoryArg>,

    /// Size of the built-in sky map in pixels, at most 16384 a side and 16384x8192 in all
    /// (about 68 bytes a pixel). [default: 512x256]
    #[arg(long, value_name = "WxH", value_parser = parse_size)]
    sky_size: Option<(u32, u32)>,

    /// Render the built-in sky without clouds.
    #[arg(long)]
    no_clouds: bool,

    /// Seed of the sky's clouds. [default: 2]
    #[arg(long)]
    seed: Option<u64>,

    /// Capture from a V4L2 camera (path or name; see `envlight devices` and `[camera]`).
    /// INPUT `v4l2:DEVICE` does the same.
    #[arg(long, value_name = "DEVICE", conflicts_with = "inputs")]
    device: Option<String>,

    /// Write the JSON lines to FILE (created or truncated) instead of stdout.
    #[arg(long, short = 'o', value_name = "FILE")]
    out: Option<PathBuf>,

    /// Also keep FILE holding only the newest frame's JSON, replaced atomically (written to
    /// FILE.tmp, then renamed) after every frame: bounded output for a long-running service.
    #[arg(long, value_name = "FILE")]
    latest: Option<PathBuf>,
}

impl DecomposeArgs {
    /// Applies the flags to the raw configuration. Returns, for each config key a flag set,
    /// the flag's name (so validation errors can name the flag).
    fn apply(&self, raw: &mut RawConfig) -> Result<Vec<(&'static str, &'static str)>> {
        let mut set = Vec::new();
        let mut note = |key, flag| set.push((key, flag));
        crate::cli::refuse_camera_among_files(&self.inputs)?;
        let device = self
            .device
            .clone()
            .or_else(|| envlight::daemon::camera_input(&self.inputs).map(str::to_owned));
        // A camera or INPUT files replace the configured source, whatever its kind (the
        // config's files are not used with a camera, nor its camera with files).
        let src = &mut raw.source;
        if let Some(dev) = device {
            src.kind = Some("v4l2".into());
            src.paths = None;
            raw.camera.device = Some(dev);
        } else if !self.inputs.is_empty() {
            src.kind = Some("sequence".into());
            src.paths = Some(self.inputs.clone());
            note("source.paths", "INPUT");
        }
        let src = &mut raw.source;
        if let Some(v) = self.frames {
            src.frames = Some(v);
        }
        if let Some(v) = self.fps {
            src.fps = Some(v);
            note("source.fps", "--fps");
        }
        if self.looped {
            match src.kind.as_deref().unwrap_or("sky") {
                "sky" => usage_error!(
                    "--loop replays INPUT files; the built-in sky is endless with --frames 0"
                ),
                "v4l2" => usage_error!("--loop replays INPUT files, not a camera (--device)"),
                _ => {}
            }
            src.looped = Some(true);
        }
        if let Some(p) = self.projection {
            let name = match p {
                ProjectionArg::Latlong => "latlong",
                ProjectionArg::Fisheye => "fisheye",
                ProjectionArg::Angular => "angular",
            };
            if name != "latlong" && src.kind.as_deref().unwrap_or("sky") == "sky" {
                usage_error!(
                    "--projection {name} maps INPUT files or a camera; the built-in sky is always \
                     lat-long"
                );
            }
            src.projection = Some(name.into());
            note("source.projection", "--projection");
        }
        self.fisheye.apply(src, &mut note)?;

        let sky_flags = self.sky_size.is_some() || self.no_clouds || self.seed.is_some();
        if sky_flags && src.kind.as_deref().unwrap_or("sky") != "sky" {
            usage_error!(
                "--sky-size, --no-clouds and --seed apply to the built-in sky, not to INPUT files \
                 or a camera"
            );
        }
        if let Some((w, h)) = self.sky_size {
            raw.sky.width = Some(w);
            raw.sky.height = Some(h);
            note("sky.width", "--sky-size width");
            note("sky.height", "--sky-size height");
        }
        if self.no_clouds {
            raw.sky.clouds = Some(false);
        }
        if let Some(s) = self.seed {
            raw.sky.seed = Some(s);
        }

        let dec = &mut raw.decompose;
        if let Some(n) = self.lights {
            dec.lights = Some(n);
            note("decompose.lights", "--lights");
        }
        if let Some(g) = self.pdf_exponent {
            dec.pdf_exponent = Some(g);
            note("decompose.pdf_exponent", "--pdf-exponent");
        }
        if let Some(w) = self.working_width {
            dec.working_width = Some(w);
            note("decompose.working_width", "--working-width");
        }
        if let Some(n) = self.resample_threads {
            dec.resample_threads = Some(n);
            note("decompose.resample_threads", "--resample-threads");
        }
        if let Some(w) = self.warp {
            dec.warp = Some(
                match w {
                    WarpArg::Rows => "rows",
                    WarpArg::Hierarchical => "hierarchical",
                }
                .into(),
            );
            note("decompose.warp", "--warp");
        }
        if self.concentrated_lloyd {
            dec.concentrated_lloyd = Some(true);
            note("decompose.concentrated_lloyd", "--concentrated-lloyd");
        }
        if self.no_refine_concentrated {
            dec.refine_concentrated = Some(false);
            note("decompose.refine_concentrated", "--no-refine-concentrated");
        }
        if self.split {
            dec.split = Some(true);
            note("decompose.split", "--split");
        }
        if self.no_split {
            dec.split = Some(false);
            note("decompose.split", "--no-split");
        }
        if let Some(f) = self.split_factor {
            dec.split = Some(true);
            dec.split_factor = Some(f);
            note("decompose.split", "--split-factor");
            note("decompose.split_factor", "--split-factor");
        }
        if let Some(b) = self.bright_history {
            dec.bright_history = Some(
                match b {
                    BrightHistoryArg::Fold => BrightHistory::Fold,
                    BrightHistoryArg::Fade => BrightHistory::Fade,
                    BrightHistoryArg::Blend => BrightHistory::Blend,
                }
                .name()
                .into(),
            );
        }
        if let Some(p) = self.placement {
            dec.placement = Some(
                match p {
                    PlacementArg::Centroid => "centroid",
                    PlacementArg::SamplePoint => "sample-point",
                }
                .into(),
            );
            note("decompose.placement", "--placement");
        }
        if self.filter.no_filter {
            dec.filter = Some(false);
        }
        if let Some(taps) = &self.filter.taps {
            dec.filter = Some(true);
            dec.filter_taps = Some(taps.clone());
            note("decompose.filter_taps", "--taps");
        }
        if self.bright_history.is_some() && dec.filter == Some(false) {
            usage_error!(
                "--bright-history shapes the temporal filter, which the config file turns off \
                 (decompose.filter = false; --taps would turn it on)"
            );
        }
        if self.merge {
            dec.merge = Some(true);
        }
        if self.no_merge {
            dec.merge = Some(false);
        }
        if let Some(f) = self.merge_fraction {
            dec.merge = Some(true);
            dec.merge_spacing_fraction = Some(f);
            note("decompose.merge_spacing_fraction", "--merge-fraction");
        }
        Ok(set)
    }
}

/// `envlight decompose`.
pub(crate) fn run(args: &DecomposeArgs) -> Result<()> {
    let (mut raw, config_name) = match &args.config {
        Some(path) => (
            RawConfig::from_file(path)?,
            format!("config file {}", path.display()),
        ),
        None => (RawConfig::default(), "the built-in defaults".to_string()),
    };
    let flags = args.apply(&mut raw)?;
    let config = validate_with_flags(&raw, &flags, &config_name)?;
    // The config file and the response curve it names are inputs too: no output may be them.
    let read: Vec<PathBuf> = (args.config.iter().cloned())
        .chain(raw.camera.curve.iter().map(PathBuf::from))
        .collect();
    run_decompose(&config, &read, args.out.as_deref(), args.latest.as_deref())
}

/// Replaces `path` with `contents` atomically: readers see the old or the new file, never half.
fn replace_file(path: &Path, contents: &[u8]) -> std::io::Result<()> {
    // Again at each frame: a device or pipe may have taken the path since the start.
    envlight::read_file::check_replaceable(path, "--latest")?;
    let tmp = latest_tmp(path);
    std::fs::write(&tmp, contents)?;
    std::fs::rename(&tmp, path)
}

/// The temporary file `path` + `.tmp` through which [`replace_file`] replaces `path`.
fn latest_tmp(path: &Path) -> PathBuf {
    let mut tmp = path.as_os_str().to_owned();
    tmp.push(".tmp");
    PathBuf::from(tmp)
}

/// Decomposes `config`'s source into `out` (stdout when `None`) and `latest`; `read` lists the
/// files other than the frames that the command read (the config file, a response curve),
/// which no output may overwrite either.
fn run_decompose(
    config: &Config,
    read: &[PathBuf],
    out: Option<&Path>,
    latest: Option<&Path>,
) -> Result<()> {
    let mut source = open_source(config)?;
    let mut decomposer =
        Decomposer::new(config.decompose.clone()).context("invalid decomposition settings")?;
    let inputs = crate::cli::output::InputFiles::new(&[source.files(), read].concat());
    if let Some(path) = latest {
        crate::cli::output::check_output_path(path, "--latest")?;
        envlight::read_file::check_replaceable(path, "--latest")
            .with_context(|| format!("--latest {}", path.display()))?;
        inputs.refuse(path, "--latest")?;
        // Written before each rename: an input of that name would be destroyed too.
        inputs.refuse(&latest_tmp(path), "--latest's temporary file")?;
        // --latest is replaced through LATEST.tmp: neither may be the --out file.
        if let Some(out) = out {
            for (file, what) in [
                (path.to_path_buf(), "--latest"),
                (latest_tmp(path), "--latest's temporary file"),
            ] {
                if crate::cli::output::same_file(out, &file) {
                    bail!(
                        "--out {} is also {what} {}: the newest frame would replace the \
                         stream; choose another output path",
                        out.display(),
                        file.display()
                    );
                }
            }
        }
    }
    let mut writer =
        std::io::BufWriter::new(crate::cli::output::open_output(out, "--out", &inputs)?);
    let out_name = out.map_or("stdout".to_string(), |p| p.display().to_string());

    tracing::info!("source: {}", source.describe());
    let d = &config.decompose;
    tracing::info!(
        "decomposing into {} lights (working width {}, placement {}, warp {}, density \
         exponent {}, refinement of concentrated sources {}, concentrated Lloyd step {}, split \
         of bright lights {}, filter {}, merge {})",
        d.lights,
        d.working_width,
        envlight::config::placement_name(d.placement),
        envlight::config::warp_name(d.warp),
        d.pdf_exponent,
        on_off(d.refine_concentrated),
        on_off(d.concentrated_lloyd),
        split_description(d.split_factor),
        d.filter_taps
            .as_ref()
            .map_or("off".to_string(), |t| format!(
                "{t:?}, bright lights: {}",
                d.bright_history.name()
            )),
        d.merge_spacing_fraction
            .map_or("off".to_string(), |f| format!("at {f} of the spacing")),
    );
    tracing::info!(
        "temporal filter delay: {} frames",
        decomposer.filter_delay_frames()
    );

    let mut frames = 0u64;
    let mut lights_total = 0u64;
    let mut decompose_time = Duration::ZERO;
    let mut line = Vec::with_capacity(64 * 1024);
    loop {
        let Some(frame) = source.next_frame().context("cannot read a frame")? else {
            break;
        };
        let start = Instant::now();
        let lights = decomposer.decompose(&frame);
        decompose_time += start.elapsed();
        frames += 1;
        lights_total += lights.lights.len() as u64;

        line.clear();
        serde_json::to_writer(&mut line, &lights).context("cannot serialise a light frame")?;
        line.push(b'\n');
        if let Some(path) = latest {
            replace_file(path, &line)
                .with_context(|| format!("cannot write the newest frame to {}", path.display()))?;
        }
        // Flush every frame: a consumer tailing the output sees whole frames as they come.
        let written = writer.write_all(&line).and_then(|()| writer.flush());
        match written {
            Err(e) if out.is_none() && crate::cli::output::is_broken_pipe(&e) => {
                tracing::debug!("stdout closed after {frames} frames; stopping");
                return Ok(());
            }
            r => r.with_context(|| format!("cannot write to {out_name}"))?,
        }
    }
    match writer.flush() {
        Err(e) if out.is_none() && crate::cli::output::is_broken_pipe(&e) => return Ok(()),
        r => r.with_context(|| format!("cannot write to {out_name}"))?,
    }

    let per_frame = |total: f64| {
        if frames > 0 {
            total / frames as f64
        } else {
            0.0
        }
    };
    tracing::info!(
        "done: {frames} frames, {:.1} lights/frame on average, {:.2} ms mean decomposition time per frame",
        per_frame(lights_total as f64),
        per_frame(decompose_time.as_secs_f64() * 1e3),
    );
    Ok(())
}
