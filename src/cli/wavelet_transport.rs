//! `envlight wavelet relight` and `envlight wavelet recover`: argument handling, I/O and
//! printing for wavelet relighting and hierarchical lighting recovery. The work is in
//! `envlight::wavelet::{visibility, relight, triple, inverse}`.

use crate::cli::wavelet::FrameInput;
use anyhow::{bail, Context, Result};
use clap::{Args, ValueEnum};
use envlight::render::scene::{Projection, Scene};
use envlight::wavelet::approx::Coefficients;
use envlight::wavelet::inverse::{
    prediction_error, refine, relative_error, synthesize, transport_rows, upper_hemisphere_error,
    ObservationSetup, RefineOptions,
};
use envlight::wavelet::relight::{
    brute_force, check_precompute_memory, Brdf, DenseLighting, Grid, Transport, View,
};
use envlight::wavelet::sphere::OctahedralMap;
use envlight::wavelet::visibility::{vertex_visibility, Bvh, Mesh};
use envlight::wavelet::Basis;
use glam::Vec3;
use std::io::Write;
use std::path::PathBuf;
use std::time::Instant;

pub const RELIGHT_LONG_ABOUT: &str = "\
Relight a static mesh with wavelet lighting, frame by frame. Once: trace the visibility of every
direction of the SIZE x SIZE equal-area octahedral map from every vertex (CPU ray casting, BVH),
multiply by the BRDF slice (Lambert cosine, a normalised Phong lobe or a GGX lobe seen from --eye), project
onto the wavelet basis and keep the --transport largest coefficients per vertex. Per frame:
resample the frame onto the map, keep its K largest coefficients and compute every vertex's
outgoing radiance as a sparse dot product (all cores). Prints one JSON line per frame:

  {\"seq\":0,\"vertices\":10446,\"light_coefficients\":1000,\"transport_entries\":2674176,
   \"relight_ms\":3.1,\"check\":{\"vertices\":200,\"rms_relative\":0.012,\"max_relative\":0.08}}

`check` compares --check vertices (evenly spread) with brute-force integration over all texels
(Σ V·L·ρ·dω of the full-resolution map), relative to each vertex's radiance; a vertex that
receives no light (in shadow, or facing away from every lit direction) has no relative error
and is left out, so `check.vertices` counts those compared (with none, the errors are null).
Radiance is per
channel; the Lambertian result is multiplied by the vertex's material albedo (its base colour
times its base-colour texture at the vertex's texture coordinates). Without INPUT the
built-in sky is used. A precomputation that would need more memory than the machine has
available (an upper bound: per vertex a bit per texel and 14 bytes per kept coefficient) is
refused before it starts. --out writes the JSON lines to a file (as decompose, fit-asg and wavelet
approx do); --radiance writes the last frame's per-vertex radiance as CSV (x,y,z,r,g,b).";

pub const RECOVER_LONG_ABOUT: &str = "\
Recover lighting from synthetic observations of a known object by hierarchical refinement
(Michiels et al. 2013). The object: a unit sphere on a subdivided ground plane; observations:
the ground vertices (Lambertian, they see the sphere's shadow) and the sphere's vertices as a
glossy Phong surface seen from --views directions around it, evenly subsampled to
--observations. Their radiance is rendered from the INPUT frame (one file, or the built-in sky
without INPUT: the truth, resampled to SIZE x SIZE) plus Gaussian noise of --noise times the
RMS radiance. The refinement starts at the
root of the wavelet tree, adds the children of significant nodes only while the least-squares
system stays full rank (rank-revealing QR, --rank-tol) and, unless --no-bic, while a level lowers
the Bayesian information criterion; it solves the system at every level. Prints one JSON object:

  {\"basis\":\"coif1\",\"side\":16,\"observations\":2000,\"noise\":0.01,\"active\":93,
   \"relative_error\":0.21,\"upper_hemisphere_error\":0.1,\"best_error_same_nodes\":0.18,
   \"prediction_error\":0.01,\"steps\":[…]}

`relative_error` is the RGB L2 error of the recovered map against the truth on the whole sphere
(the ground plane hides the lower hemisphere from every observation, so that part cannot be
recovered), `upper_hemisphere_error` the same over the upper hemisphere (null where no texel lies
above the horizon: --size 2), `best_error_same_nodes`
the error of the truth restricted to the recovered nodes (the floor for that tree) and
`prediction_error` the relative RMS error of the radiance the recovered lighting gives every
observable (vertex, view), noise-free, against the truth's. --out writes the recovered map (SIZE x SIZE octahedral, linear RGB EXR).";

fn parse_basis(s: &str) -> Result<Basis, String> {
    Basis::parse(s).map_err(|e| e.to_string())
}

fn parse_vec3(s: &str) -> Result<Vec3, String> {
    let v: Vec<f32> = s
        .split(',')
        .map(|p| p.trim().parse::<f32>())
        .collect::<Result<_, _>>()
        .map_err(|e| format!("expected x,y,z: {e}"))?;
    match v[..] {
        [x, y, z] if x.is_finite() && y.is_finite() && z.is_finite() => Ok(Vec3::new(x, y, z)),
        _ => Err(format!("expected three finite numbers x,y,z, got {s:?}")),
    }
}

/// BRDF of the relit surface.
#[derive(Clone, Copy, Debug, ValueEnum, PartialEq)]
pub enum BrdfArg {
    /// Lambertian (times the material albedo).
    Lambert,
    /// Normalised Phong lobe of --exponent, seen from --eye.
    Phong,
    /// GGX microfacet specular (Smith height-correlated, F = 1) of roughness --alpha, seen
    /// from --eye.
    Ggx,
}

#[derive(Args, Debug)]
pub struct RelightArgs {
    #[command(flatten)]
    input: FrameInput,
    /// Mesh to relight (.gltf, .glb or .obj). [default: the built-in scene: three spheres and a
    /// box on a ground plane]
    #[arg(long, value_name = "FILE")]
    scene: Option<PathBuf>,
    /// Add a ground plane under a --scene file (it casts shadows and is relit too).
    #[arg(long)]
    ground: bool,
    /// Wavelet basis: haar (= db1 = d2), db2..db10, coif1..coif5 (or d4..d20, c6..c30 by filter length).
    #[arg(long, value_parser = parse_basis, default_value = "coif1")]
    basis: Basis,
    /// Side of the octahedral map (power of two, 2..=128): SIZE² directions per vertex.
    #[arg(long, value_name = "SIZE", default_value_t = 32)]
    size: usize,
    /// Lighting coefficients kept per frame (1..=SIZE²). [default: 1000, or SIZE² when that is
    /// less]
    #[arg(long, short = 'k', value_name = "K")]
    coefficients: Option<usize>,
    /// Transport coefficients kept per vertex (1..=SIZE²). [default: 256, or SIZE² when that is
    /// less]
    #[arg(long, value_name = "N")]
    transport: Option<usize>,
    /// BRDF of every surface.
    #[arg(long, value_enum, default_value_t = BrdfArg::Lambert)]
    brdf: BrdfArg,
    /// Phong exponent for --brdf phong (≥ 0). [default: 32]
    #[arg(long, value_parser = parse_phong_exponent)]
    exponent: Option<f32>,
    /// GGX α for --brdf ggx (α = perceptual roughness², 0.001..=1). [default: 0.3]
    #[arg(long, value_parser = parse_ggx_alpha)]
    alpha: Option<f32>,
    /// Eye position for --brdf phong or ggx, x,y,z. [default: the scene's camera; an
    /// orthographic camera's view direction for every vertex]
    #[arg(long, value_parser = parse_vec3, value_name = "X,Y,Z")]
    eye: Option<Vec3>,
    /// Vertices compared with brute-force integration per frame (0: no check); unlit ones are
    /// left out of the comparison.
    #[arg(long, value_name = "N", default_value_t = 200)]
    check: usize,
    /// Output file (JSON Lines). [default: stdout]
    #[arg(long, value_name = "FILE")]
    out: Option<PathBuf>,
    /// Write the last frame's per-vertex radiance as CSV (x,y,z,r,g,b).
    #[arg(long, value_name = "FILE.csv")]
    radiance: Option<PathBuf>,
    /// The JSON Lines output's former name (until 2026-12-05; `--out` was then the CSV): refused
    /// with the new names, so an old command line does not write JSON where it meant CSV.
    #[arg(long, value_name = "FILE", hide = true)]
    json: Option<PathBuf>,
}

#[derive(Args, Debug)]
pub struct RecoverArgs {
    #[command(flatten)]
    input: FrameInput,
    /// Wavelet basis: haar (= db1 = d2), db2..db10, coif1..coif5 (or d4..d20, c6..c30 by filter length).
    #[arg(long, value_parser = parse_basis, default_value = "coif1")]
    basis: Basis,
    /// Side of the octahedral map (power of two, 2..=64): SIZE² unknowns.
    #[arg(long, value_name = "SIZE", default_value_t = 16)]
    size: usize,
    /// Observations used (evenly subsampled; 0: all, about 3,000 for --views 4; more than the
    /// views give is an error).
    #[arg(long, value_name = "N", default_value_t = 0)]
    observations: usize,
    /// Views of the glossy sphere (evenly around it, slightly above; 1..=32).
    #[arg(long, value_name = "N", default_value_t = 4)]
    views: usize,
    /// Phong exponent of the observed sphere (≥ 0).
    #[arg(long, default_value_t = 32.0, value_parser = parse_phong_exponent)]
    exponent: f32,
    /// Gaussian noise, as a fraction of the RMS observed radiance (0..=100).
    #[arg(long, default_value_t = 0.01)]
    noise: f64,
    /// Seed of the noise (needs --noise above 0). [default: 1]
    #[arg(long)]
    seed: Option<u64>,
    /// Rank test: minimum norm of a new column orthogonal to the others, relative to the
    /// largest column norm, in (0, 1).
    #[arg(long, default_value_t = RefineOptions::default().rank_tol, value_parser = parse_rank_tol)]
    rank_tol: f64,
    /// Split nodes whose coefficient is at least this fraction of the largest at their level
    /// (0..=1).
    #[arg(long, default_value_t = RefineOptions::default().split_fraction, value_parser = parse_split_fraction)]
    split: f64,
    /// Do not stop at the level that stops lowering the Bayesian information criterion.
    #[arg(long)]
    no_bic: bool,
    /// Write the recovered map (SIZE x SIZE octahedral, linear RGB EXR).
    #[arg(long, value_name = "FILE.exr")]
    out: Option<PathBuf>,
}

/// `--exponent`: a finite f32 ≥ 0 (checked when the flag is read, so the error names it and
/// comes before any input is read).
fn parse_phong_exponent(s: &str) -> Result<f32, String> {
    let x = crate::cli::parse_finite_f32(s)?;
    if x < 0.0 {
        return Err(format!("the Phong exponent must be ≥ 0, got {s}"));
    }
    Ok(x)
}

/// `--alpha`: GGX roughness in [`envlight::wavelet::relight::MIN_GGX_ALPHA`], 1].
fn parse_ggx_alpha(s: &str) -> Result<f32, String> {
    let x = crate::cli::parse_finite_f32(s)?;
    let min = envlight::wavelet::relight::MIN_GGX_ALPHA;
    if !(min..=1.0).contains(&x) {
        return Err(format!("GGX roughness α must be in [{min}, 1], got {s}"));
    }
    Ok(x)
}

/// `--rank-tol`: a number in (0, 1).
fn parse_rank_tol(s: &str) -> Result<f64, String> {
    let x: f64 = (s.trim().parse()).map_err(|_| format!("{s:?} is not a number"))?;
    if !(x > 0.0 && x < 1.0) {
        return Err(format!("the rank tolerance must be in (0, 1), got {s}"));
    }
    Ok(x)
}

/// `--split`: a fraction in [0, 1].
fn parse_split_fraction(s: &str) -> Result<f64, String> {
    let x: f64 = (s.trim().parse()).map_err(|_| format!("{s:?} is not a number"))?;
    if !(0.0..=1.0).contains(&x) {
        return Err(format!("the split fraction must be in [0, 1], got {s}"));
    }
    Ok(x)
}

/// `wavelet relight --exponent` when not given (with --brdf phong).
const DEFAULT_PHONG_EXPONENT: f32 = 32.0;
/// `wavelet relight --alpha` when not given (with --brdf ggx).
const DEFAULT_GGX_ALPHA: f32 = 0.3;

/// The most views of the observed sphere `recover` accepts: each adds every sphere vertex's
/// transport row (SIZE² values): 52 MB per view at SIZE 64 (measured, peak resident memory
/// 130 MB with one view, 233 MB with three), so 32 views take about 1.8 GB.
const MAX_VIEWS: usize = 32;

fn check_size(size: usize, max: usize) -> Result<()> {
    if !(2..=max).contains(&size) || !size.is_power_of_two() {
        crate::cli::usage_error!("invalid --size {size}: must be a power of two in 2..={max}");
    }
    Ok(())
}

#[derive(serde::Serialize)]
struct Check {
    vertices: usize,
    /// `None` (null) when no vertex was compared: no error is not a zero error.
    rms_relative: Option<f64>,
    max_relative: Option<f64>,
}

#[derive(serde::Serialize)]
struct RelightLine {
    seq: u64,
    vertices: usize,
    light_coefficients: usize,
    transport_entries: usize,
    relight_ms: f64,
    #[serde(skip_serializing_if = "Option::is_none")]
    check: Option<Check>,
}

/// Bytes of memory available for new allocations (`MemAvailable` in /proc/meminfo).
fn available_memory() -> Option<u64> {
    let text = std::fs::read_to_string("/proc/meminfo").ok()?;
    let line = text.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kib: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    kib.checked_mul(1024)
}

/// Runs `envlight wavelet relight`.
pub fn relight(args: &RelightArgs) -> Result<()> {
    check_size(args.size, 128)?;
    let texels = args.size * args.size;
    let coefficients = args.coefficients.unwrap_or(texels.min(1000));
    if coefficients == 0 || coefficients > texels {
        crate::cli::usage_error!(
            "invalid --coefficients {coefficients}: expected 1..={texels} for --size {}",
            args.size
        );
    }
    let transport_kept = args.transport.unwrap_or(texels.min(256));
    if transport_kept == 0 || transport_kept > texels {
        crate::cli::usage_error!(
            "invalid --transport {transport_kept}: expected 1..={texels} for --size {}",
            args.size
        );
    }
    if args.ground && args.scene.is_none() {
        crate::cli::usage_error!(
            "--ground adds a ground plane under a --scene file; the built-in scene has one"
        );
    }
    match args.brdf {
        BrdfArg::Lambert
            if args.exponent.is_some() || args.alpha.is_some() || args.eye.is_some() =>
        {
            crate::cli::usage_error!("--exponent, --alpha and --eye apply to --brdf phong or ggx")
        }
        BrdfArg::Phong if args.alpha.is_some() => {
            crate::cli::usage_error!("--alpha applies to --brdf ggx; --brdf phong takes --exponent")
        }
        BrdfArg::Ggx if args.exponent.is_some() => {
            crate::cli::usage_error!("--exponent applies to --brdf phong; --brdf ggx takes --alpha")
        }
        _ => {}
    }
    if args.json.is_some() {
        crate::cli::usage_error!(
            "--json is now --out (the JSON lines, as in decompose, fit-asg and wavelet approx); \
             the per-vertex CSV, formerly --out, is --radiance FILE.csv"
        );
    }
    if let Some(out) = &args.out {
        if out
            .extension()
            .is_some_and(|e| e.eq_ignore_ascii_case("csv"))
        {
            crate::cli::usage_error!(
                "--out {} would hold JSON lines: the per-vertex CSV (formerly --out) is \
                 --radiance FILE.csv",
                out.display()
            );
        }
    }
    let mut source = args.input.open()?;
    // The frames and the mesh with the files it references (glTF buffers, MTL libraries): no
    // output may overwrite them, nor --radiance the --out output. Checked before the
    // precomputation, whose work a late refusal would throw away.
    let mut read = source.files().to_vec();
    if let Some(scene) = &args.scene {
        read.extend(envlight::render::scene::scene_files(scene));
    }
    let inputs = crate::cli::output::InputFiles::new(&read);
    for (path, option) in [(&args.out, "--out"), (&args.radiance, "--radiance")] {
        if let Some(path) = path {
            inputs.refuse(path, option)?;
            crate::cli::output::check_output_path(path, option)?;
        }
    }
    if let (Some(out), Some(radiance)) = (&args.out, &args.radiance) {
        if crate::cli::output::same_file(out, radiance) {
            bail!(
                "--radiance {} is also the --out output {}: the two outputs would overwrite \
                 each other; choose another output path",
                radiance.display(),
                out.display()
            );
        }
    }
    let scene = match &args.scene {
        Some(path) => Scene::load(path, args.ground)
            .with_context(|| format!("cannot load scene {}", path.display()))?,
        None => Scene::default_scene(),
    };
    let mesh = Mesh::from_scene(&scene).context("scene mesh")?;
    let albedo: Vec<[f32; 3]> = (0..scene.vertices.len())
        .map(|i| scene.vertex_base_color(i))
        .collect();
    // What the materials emit (glTF's emission), added to the reflected light.
    let emission: Vec<[f32; 3]> = (0..scene.vertices.len())
        .map(|i| scene.vertex_emission(i))
        .collect();
    let grid = Grid::new(args.size, args.basis, None)?;
    // Before the ray casting: a precomputation past the machine's memory would abort the process
    // when its allocation failed (a mesh of tens of millions of vertices loads).
    check_precompute_memory(
        mesh.positions.len(),
        grid.len(),
        transport_kept,
        available_memory(),
    )
    .with_context(|| {
        format!(
            "--size {} and --transport {transport_kept} on this mesh: use a smaller mesh, \
             --size or --transport",
            args.size
        )
    })?;
    let bvh = Bvh::build(&mesh).context("scene mesh")?;
    let t0 = Instant::now();
    let vis = vertex_visibility(&mesh, &bvh, &grid.dirs);
    let brdf = match args.brdf {
        BrdfArg::Lambert => Brdf::Lambert,
        BrdfArg::Phong => Brdf::Phong {
            exponent: args.exponent.unwrap_or(DEFAULT_PHONG_EXPONENT),
        },
        BrdfArg::Ggx => Brdf::Ggx {
            alpha: args.alpha.unwrap_or(DEFAULT_GGX_ALPHA),
        },
    };
    let view = match (args.eye, scene.camera.projection) {
        (Some(eye), _) => View::Eye(eye),
        (None, Projection::Orthographic { .. }) => View::Direction(-scene.camera.forward()),
        (None, _) => View::Eye(scene.camera.eye),
    };
    let transport = Transport::precompute(
        &grid,
        &mesh.positions,
        &mesh.normals,
        &vis,
        brdf,
        view,
        transport_kept,
    )?;
    tracing::info!(
        vertices = mesh.positions.len(),
        triangles = mesh.triangles.len(),
        seconds = t0.elapsed().as_secs_f64(),
        "visibility and transport precomputed"
    );
    let mut json = crate::cli::output::open_output(args.out.as_deref(), "--out", &inputs)?;
    let json_name = args
        .out
        .as_ref()
        .map_or("stdout".to_string(), |p| p.display().to_string());
    let mut light = DenseLighting::new(&grid);
    let mut out = vec![[0.0f32; 3]; mesh.positions.len()];
    let lambert = args.brdf == BrdfArg::Lambert;
    while let Some(frame) = source
        .next_frame()
        .with_context(|| format!("cannot read a frame from {}", source.describe()))?
    {
        let map = OctahedralMap::from_frame(&frame, grid.side)
            .with_context(|| format!("cannot resample frame {}", frame.seq))?;
        let coeffs = Coefficients::analyze(map.texels(), grid.side, grid.basis, grid.levels)?;
        let set = coeffs.truncate(coefficients);
        let t = Instant::now();
        light.set(&grid, &set)?;
        transport.relight(&light, &mut out)?;
        let relight_ms = t.elapsed().as_secs_f64() * 1e3;
        for ((o, a), e) in out.iter_mut().zip(&albedo).zip(&emission) {
            for c in 0..3 {
                if lambert {
                    o[c] *= a[c];
                }
                o[c] += e[c];
            }
        }
        let check = (args.check > 0).then(|| {
            let texels: Vec<[f64; 3]> = map.texels().iter().map(|t| t.map(f64::from)).collect();
            let n = args.check.min(mesh.positions.len());
            let step = mesh.positions.len() / n;
            let (mut sq, mut max, mut count) = (0.0f64, 0.0f64, 0usize);
            for v in (0..n).map(|i| i * step) {
                let slice = grid.brdf_slice(brdf, mesh.normals[v], view.at(mesh.positions[v]));
                let mut b = brute_force(&grid, &vis, v, &slice, &texels);
                for c in 0..3 {
                    if lambert {
                        b[c] *= f64::from(albedo[v][c]);
                    }
                    b[c] += f64::from(emission[v][c]);
                }
                let norm = (b.iter().map(|x| x * x).sum::<f64>()).sqrt();
                if norm <= 0.0 {
                    continue;
                }
                let err = (0..3)
                    .map(|c| (f64::from(out[v][c]) - b[c]).powi(2))
                    .sum::<f64>()
                    .sqrt()
                    / norm;
                sq += err * err;
                max = max.max(err);
                count += 1;
            }
            Check {
                vertices: count,
                rms_relative: (count > 0).then(|| (sq / count as f64).sqrt()),
                max_relative: (count > 0).then_some(max),
            }
        });
        let line = RelightLine {
            seq: frame.seq,
            vertices: out.len(),
            light_coefficients: set.len(),
            transport_entries: transport.entries(),
            relight_ms,
            check,
        };
        let mut text = serde_json::to_string(&line).context("cannot encode a frame")?;
        text.push('\n');
        match json.write_all(text.as_bytes()).and_then(|()| json.flush()) {
            Err(e) if args.out.is_none() && crate::cli::output::is_broken_pipe(&e) => break,
            r => r.with_context(|| format!("cannot write to {json_name}"))?,
        }
    }
    if let Some(path) = &args.radiance {
        let mut w =
            std::io::BufWriter::new(crate::cli::output::create(path, "--radiance", &inputs)?);
        let written = (|| -> std::io::Result<()> {
            writeln!(w, "x,y,z,r,g,b")?;
            for (p, o) in mesh.positions.iter().zip(&out) {
                writeln!(w, "{},{},{},{},{},{}", p.x, p.y, p.z, o[0], o[1], o[2])?;
            }
            w.flush()
        })();
        written.with_context(|| format!("cannot write {}", path.display()))?;
    }
    Ok(())
}

#[derive(serde::Serialize)]
struct RecoverReport {
    basis: String,
    side: usize,
    observations: usize,
    noise: f64,
    active: usize,
    relative_error: f64,
    upper_hemisphere_error: Option<f64>,
    best_error_same_nodes: f64,
    prediction_error: f64,
    steps: Vec<serde_json::Value>,
}

/// Runs `envlight wavelet recover`.
pub fn recover(args: &RecoverArgs) -> Result<()> {
    check_size(args.size, 64)?;
    if !(1..=MAX_VIEWS).contains(&args.views) {
        crate::cli::usage_error!("invalid --views {}: expected 1..={MAX_VIEWS}", args.views);
    }
    if args.input.frames_given() {
        crate::cli::usage_error!(
            "wavelet recover uses the first frame of INPUT (or the sky); --frames does not apply"
        );
    }
    let max_noise = envlight::wavelet::inverse::MAX_NOISE;
    if !(0.0..=max_noise).contains(&args.noise) {
        crate::cli::usage_error!(
            "invalid --noise {}: must be in 0..={max_noise} (a fraction of the RMS radiance)",
            envlight::config::shown_number(args.noise)
        );
    }
    if args.seed.is_some() && args.noise == 0.0 {
        crate::cli::usage_error!("--seed seeds the noise; with --noise 0 there is none");
    }
    let mut source = args.input.open()?;
    let files = source.files();
    if files.len() > 1 {
        crate::cli::usage_error!(
            "wavelet recover uses one frame; INPUT names {} files ({} first)",
            files.len(),
            files[0].display()
        );
    }
    let inputs = crate::cli::output::InputFiles::new(files);
    if let Some(path) = &args.out {
        inputs.refuse(path, "--out")?;
        crate::cli::output::check_output_path(path, "--out")?;
        crate::cli::output::require_exr_name(path, "--out")?;
    }
    let frame = source
        .next_frame()
        .with_context(|| format!("cannot read a frame from {}", source.describe()))?
        .context("the input has no frame")?;
    let grid = Grid::new(args.size, args.basis, None)?;
    let map = OctahedralMap::from_frame(&frame, grid.side).context("cannot resample the frame")?;
    let truth = Coefficients::analyze(map.texels(), grid.side, grid.basis, grid.levels)?;
    let scale = grid.d_omega().sqrt();
    let truth: [Vec<f64>; 3] = truth
        .planes
        .map(|p| p.into_iter().map(|v| v * scale).collect());

    let mesh = Mesh::sphere_on_plane(32, 24);
    let bvh = Bvh::build(&mesh)?;
    let vis = vertex_visibility(&mesh, &bvh, &grid.dirs);
    let (sphere, ground): (Vec<usize>, Vec<usize>) =
        (0..mesh.positions.len()).partition(|&v| mesh.positions[v].y > 1e-3);
    let mut setups = vec![ObservationSetup {
        brdf: Brdf::Lambert,
        view: View::Direction(Vec3::Y),
        vertices: ground,
    }];
    for i in 0..args.views {
        let a = std::f32::consts::TAU * i as f32 / args.views as f32;
        setups.push(ObservationSetup {
            brdf: Brdf::Phong {
                exponent: args.exponent,
            },
            view: View::Eye(Vec3::new(4.0 * a.sin(), 1.5, 4.0 * a.cos())),
            vertices: sphere.clone(),
        });
    }
    let mut rows = transport_rows(&grid, &mesh, &vis, &setups)?;
    // More than there are was silently all of them (an audit).
    if args.observations > rows.len() {
        crate::cli::usage_error!(
            "invalid --observations {}: the object gives {} observations with --views {} \
             (0: all of them)",
            args.observations,
            rows.len(),
            args.views
        );
    }
    let every_row = rows.clone();
    if args.observations > 0 && args.observations < rows.len() {
        let n = rows.len();
        let keep: Vec<usize> = (0..args.observations)
            .map(|i| i * n / args.observations)
            .collect();
        rows = keep
            .into_iter()
            .map(|i| std::mem::take(&mut rows[i]))
            .collect();
    }
    let obs = synthesize(&rows, &truth, args.noise, args.seed.unwrap_or(1))?;
    let opts = RefineOptions {
        rank_tol: args.rank_tol,
        split_fraction: args.split,
        bic: !args.no_bic,
        ..RefineOptions::default()
    };
    let rec = refine(&grid, &obs, opts)?;
    let mut masked: [Vec<f64>; 3] = std::array::from_fn(|_| vec![0.0; grid.len()]);
    for &k in &rec.active {
        for c in 0..3 {
            masked[c][k as usize] = truth[c][k as usize];
        }
    }
    let report = RecoverReport {
        basis: grid.basis.to_string(),
        side: grid.side,
        observations: obs.len(),
        noise: args.noise,
        active: rec.active.len(),
        relative_error: relative_error(&rec.planes, &truth),
        upper_hemisphere_error: upper_hemisphere_error(&grid, &rec.planes, &truth)?,
        best_error_same_nodes: relative_error(&masked, &truth),
        prediction_error: prediction_error(&every_row, &rec.planes, &truth),
        steps: rec
            .steps
            .iter()
            .map(|s| {
                serde_json::json!({"level": s.level, "candidates": s.candidates, "added": s.added,
                    "rejected": s.rejected, "active": s.active, "residual_rms": s.residual_rms})
            })
            .collect(),
    };
    crate::cli::output::print(&(serde_json::to_string(&report)? + "\n"))?;
    if let Some(path) = &args.out {
        let planes: Vec<Vec<f64>> = rec
            .planes
            .iter()
            .map(|p| grid.reconstruct(p))
            .collect::<Result<_, _>>()?;
        crate::cli::output::write_rgb_exr(
            path,
            "--out",
            &inputs,
            (grid.side, grid.side),
            |x, y| {
                let t = y * grid.side + x;
                [
                    planes[0][t] as f32,
                    planes[1][t] as f32,
                    planes[2][t] as f32,
                ]
            },
        )?;
    }
    Ok(())
}
