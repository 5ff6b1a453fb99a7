//! The `envlight wavelet …` subcommands of the command line: `approx` (sparse wavelet sets of
//! HDR frames); `relight` and `recover` are in [`super::wavelet_transport`]. Only argument
//! handling, I/O and printing; the work is in `envlight::wavelet`.

use anyhow::{bail, Context, Result};
use clap::{Args, Subcommand, ValueEnum};
use envlight::capture::sky::{SkyOptions, SkySource};
use envlight::capture::FrameSource;
use envlight::config::RawConfig;
use envlight::wavelet::approx::Coefficients;
use envlight::wavelet::sphere::Resampler;
use envlight::wavelet::transform::{max_levels, Workspace};
use envlight::wavelet::{Basis, WaveletSet};
use std::path::{Path, PathBuf};

const APPROX_LONG_ABOUT: &str = "\
Resample HDR frames onto the equal-area octahedral map (SIZE x SIZE texels, each of solid angle
4π/SIZE²), transform it with an orthonormal wavelet basis (periodic boundary) and keep the K
coefficients with the largest RGB norm. Prints one JSON line per frame:

  {\"seq\":0,\"time\":0.0,\"basis\":\"db4\",\"side\":128,\"levels\":7,
   \"coefficients\":[[index,[r,g,b]],…],\"relative_l2\":0.031,\"integral\":[r,g,b]}

`index` is a position in the SIZE x SIZE coefficient array (Mallat layout, docs/wavelets.md),
`relative_l2` the RGB L2 error of the K-term reconstruction relative to the full map (exact, by
Parseval) and `integral` the map's ∫L dω. Without INPUT the built-in sky is used (1 frame
unless --frames says otherwise).

Bases: haar, db2..db10 (the number is PyWavelets': vanishing moments, db2 = D4 with 4 taps),
coif1..coif5 (coif1 = C6 with 6 taps); d4..d20 and c6..c30 name them by filter length.";

/// `envlight wavelet <SUBCOMMAND>`.
#[derive(Args, Debug)]
pub struct WaveletArgs {
    #[command(subcommand)]
    command: WaveletCommand,
}

#[derive(Subcommand, Debug)]
enum WaveletCommand {
    /// Keep the K largest wavelet coefficients of HDR frames (files or the built-in sky).
    #[command(long_about = APPROX_LONG_ABOUT)]
    Approx(ApproxArgs),
    /// Relight a static mesh with wavelet lighting, frame by frame (precomputed transport).
    #[command(long_about = crate::cli::wavelet_transport::RELIGHT_LONG_ABOUT)]
    Relight(crate::cli::wavelet_transport::RelightArgs),
    /// Recover lighting from synthetic observations of a known object (hierarchical refinement).
    // One frame: --frames is not shown (given, it is a usage error that says so).
    #[command(
        long_about = crate::cli::wavelet_transport::RECOVER_LONG_ABOUT,
        mut_arg("frames", |a| a.hide(true)),
        mut_arg("inputs", |a| a.help(
            "One .exr/.hdr file (or a directory or glob pattern naming one). None: the built-in sky."
        ))
    )]
    Recover(crate::cli::wavelet_transport::RecoverArgs),
}

/// Projection of INPUT files.
#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum ProjectionArg {
    /// Equirectangular (lat-long), row 0 = zenith; axes as `envlight --help` gives them.
    Latlong,
    /// Debevec's angular map.
    Angular,
    /// Zenith-looking fisheye (the upper hemisphere); see --fisheye-model, --center,
    /// --radius, --fov, --rotation.
    Fisheye,
}

impl ProjectionArg {
    /// The name `[source] projection` takes.
    fn config_name(self) -> &'static str {
        match self {
            ProjectionArg::Latlong => "latlong",
            ProjectionArg::Angular => "angular",
            ProjectionArg::Fisheye => "fisheye",
        }
    }
}

/// The frames every wavelet subcommand reads: INPUT files or the built-in sky.
#[derive(Args, Debug)]
pub struct FrameInput {
    /// .exr/.hdr files, directories or glob patterns (quote globs). None: the built-in sky.
    #[arg(value_name = "INPUT", value_parser = crate::cli::Utf8Input)]
    inputs: Vec<String>,
    /// Projection of the INPUT files. [default: latlong]
    #[arg(long, value_enum)]
    projection: Option<ProjectionArg>,
    /// Frames to process; 0 = every frame (the sky: endless). [default: 1 for the sky, every
    /// file for INPUT]
    #[arg(long, value_name = "N")]
    frames: Option<u64>,
    #[command(flatten)]
    fisheye: crate::cli::fisheye_flags::FisheyeFlags,
}

impl FrameInput {
    /// Whether --frames was given.
    pub fn frames_given(&self) -> bool {
        self.frames.is_some()
    }

    /// Opens the frames: a sequence of INPUT files, or the built-in sky.
    pub fn open(&self) -> Result<Box<dyn FrameSource>> {
        if self.inputs.is_empty()
            && self
                .projection
                .is_some_and(|p| !matches!(p, ProjectionArg::Latlong))
        {
            crate::cli::usage_error!(
                "--projection describes INPUT files; the built-in sky is a lat-long map"
            );
        }
        if self.inputs.is_empty() && self.fisheye.given() {
            crate::cli::usage_error!(
                "--fisheye-model, --center, --radius, --fov and --rotation describe fisheye INPUT \
                 files; the built-in sky is a lat-long map"
            );
        }
        if let Some(camera) = self.inputs.iter().find(|p| p.starts_with("v4l2:")) {
            crate::cli::usage_error!(
                "INPUT {camera}: this command reads frame files; a camera is read by `envlight \
                 decompose` or `envlight run`"
            );
        }
        if self.inputs.is_empty() {
            let frames = match self.frames {
                Some(0) => None,
                Some(n) => Some(n),
                None => Some(1),
            };
            let options = SkyOptions {
                frames,
                ..SkyOptions::default()
            };
            return Ok(Box::new(
                SkySource::new(options).context("cannot set up the built-in sky")?,
            ));
        }
        // As `decompose` opens INPUT files: the projection and calibration checked as a
        // config's (a bad flag named), the calibration against the frames' size.
        let mut raw = RawConfig::default();
        let mut flags = Vec::new();
        let src = &mut raw.source;
        src.kind = Some("sequence".into());
        src.paths = Some(self.inputs.clone());
        flags.push(("source.paths", "INPUT"));
        src.frames = self.frames;
        src.projection = Some(
            self.projection
                .unwrap_or(ProjectionArg::Latlong)
                .config_name()
                .into(),
        );
        self.fisheye
            .apply(src, |key, flag| flags.push((key, flag)))?;
        let config = crate::cli::fisheye_flags::validate_with_flags(&raw, &flags, "the flags")?;
        crate::cli::open_source(&config)
    }
}

/// A source cut after `left` frames (`None`: no limit).
pub(crate) struct Limited<S> {
    pub(crate) inner: S,
    pub(crate) left: Option<u64>,
}

impl<S: FrameSource> FrameSource for Limited<S> {
    fn next_frame(
        &mut self,
    ) -> Result<Option<envlight::HdrFrame>, envlight::capture::CaptureError> {
        match &mut self.left {
            Some(0) => Ok(None),
            Some(n) => {
                *n -= 1;
                self.inner.next_frame()
            }
            None => self.inner.next_frame(),
        }
    }

    fn describe(&self) -> String {
        self.inner.describe()
    }

    fn files(&self) -> &[PathBuf] {
        self.inner.files()
    }
}

fn parse_basis(s: &str) -> Result<Basis, String> {
    Basis::parse(s).map_err(|e| e.to_string())
}

#[derive(Args, Debug)]
pub struct ApproxArgs {
    #[command(flatten)]
    input: FrameInput,
    /// Wavelet basis: haar (= db1 = d2), db2..db10, coif1..coif5 (or d4..d20, c6..c30 by filter length).
    #[arg(long, value_parser = parse_basis, default_value = "db4")]
    basis: Basis,
    /// Coefficients to keep per frame (1..=SIZE²). [default: 1024, or SIZE² when that is less]
    #[arg(long, short = 'k', value_name = "K")]
    coefficients: Option<usize>,
    /// Side of the octahedral map, a power of two in 2..=1024.
    #[arg(long, value_name = "SIZE", default_value_t = 128)]
    size: usize,
    /// Decomposition levels (1..=log2 SIZE). [default: log2 SIZE, the full pyramid]
    #[arg(long, value_name = "L")]
    levels: Option<u32>,
    /// Output file (JSON Lines). [default: stdout]
    #[arg(long, value_name = "FILE")]
    out: Option<PathBuf>,
    /// Also write each frame's K-term reconstruction (the SIZE x SIZE octahedral map) as a linear
    /// RGB EXR. `{seq}` in the path is replaced by the frame's sequence number; without it each
    /// frame overwrites the file.
    #[arg(long, value_name = "FILE.exr")]
    reconstruct: Option<PathBuf>,
}

/// Runs `envlight wavelet …`.
pub fn run(args: &WaveletArgs) -> Result<()> {
    match &args.command {
        WaveletCommand::Approx(a) => approx(a),
        WaveletCommand::Relight(a) => crate::cli::wavelet_transport::relight(a),
        WaveletCommand::Recover(a) => crate::cli::wavelet_transport::recover(a),
    }
}

/// One output line of `approx`.
#[derive(serde::Serialize)]
struct ApproxLine<'a> {
    seq: u64,
    time: f64,
    #[serde(flatten)]
    set: &'a WaveletSet,
    relative_l2: f64,
    integral: [f64; 3],
}

fn approx(args: &ApproxArgs) -> Result<()> {
    envlight::wavelet::sphere::check_side(args.size)
        .map_err(|e| crate::cli::usage(format!("invalid --size: {e}")))?;
    let max = max_levels(args.size);
    let levels = args.levels.unwrap_or(max);
    if levels == 0 || levels > max {
        crate::cli::usage_error!(
            "invalid --levels {levels}: a map of side {} allows 1..={max}",
            args.size
        );
    }
    let coefficients = args
        .coefficients
        .unwrap_or((args.size * args.size).min(1024));
    if coefficients == 0 || coefficients > args.size * args.size {
        crate::cli::usage_error!(
            "invalid --coefficients {coefficients}: expected 1..={} for --size {}",
            args.size * args.size,
            args.size
        );
    }
    if let Some(path) = &args.reconstruct {
        crate::cli::output::require_exr_name(path, "--reconstruct")?;
        // Before --out is created (truncated): the same path for both was refused only at the
        // first reconstruction, after an existing file of that name had been emptied.
        if let Some(out) = &args.out {
            if reconstruct_may_be(out, path) {
                bail!(
                    "--reconstruct {} is also the --out output {}: the two outputs would \
                     overwrite each other; choose another output path",
                    path.display(),
                    out.display()
                );
            }
        }
    }
    let mut source = args.input.open()?;
    let mut inputs = crate::cli::output::InputFiles::new(source.files());
    let mut output =
        crate::cli::output::JsonLines::open(args.out.as_deref(), "--out", &mut inputs)?;
    let mut ws = Workspace::new();
    let mut resampler: Option<Resampler> = None;
    while let Some(frame) = source.next_frame().context("cannot read a frame")? {
        // One resampling plan per projection and frame size.
        let plan = match resampler.take() {
            Some(r) if r.fits(&frame) => r,
            _ => Resampler::new(frame.projection, frame.width, frame.height, args.size)
                .with_context(|| format!("cannot resample frame {}", frame.seq))?,
        };
        let map = plan
            .resample(&frame)
            .with_context(|| format!("cannot resample frame {}", frame.seq))?;
        resampler = Some(plan);
        let coeffs =
            Coefficients::analyze_with(map.texels(), args.size, args.basis, levels, &mut ws)
                .with_context(|| format!("cannot transform frame {}", frame.seq))?;
        let set = coeffs.truncate(coefficients);
        let relative_l2 = coeffs.relative_l2_error(set.coefficients.iter().map(|&(i, _)| i));
        if let Some(path) = &args.reconstruct {
            let path = expand_seq(path, frame.seq);
            let rec = set
                .reconstruct()
                .with_context(|| format!("cannot reconstruct frame {}", frame.seq))?;
            crate::cli::output::write_rgb_exr(
                &path,
                "--reconstruct",
                &inputs,
                (args.size, args.size),
                |x, y| rec[y * args.size + x].map(|c| c as f32),
            )?;
        }
        let line = ApproxLine {
            seq: frame.seq,
            time: frame.time,
            set: &set,
            relative_l2,
            integral: map.integral(),
        };
        let line = serde_json::to_string(&line).context("cannot encode a frame")?;
        if !output.line(&line)? {
            return Ok(());
        }
        tracing::info!(
            "frame {}: {} of {} coefficients ({}), relative L2 error {:.4}",
            frame.seq,
            set.len(),
            args.size * args.size,
            args.basis,
            relative_l2
        );
    }
    output.finish()
}

/// Whether `--reconstruct pattern` names `out` for some frame: the same file, or with `{seq}`
/// the file of the number that `out`'s name holds in its place (`--out r0.exr --reconstruct
/// 'r{seq}.exr'` emptied r0.exr before the first frame was refused).
fn reconstruct_may_be(out: &Path, pattern: &Path) -> bool {
    let text = pattern.to_string_lossy();
    let Some((before, after)) = text.split_once("{seq}") else {
        return crate::cli::output::same_file(out, pattern);
    };
    let out_text = out.to_string_lossy();
    let Some(digits) = out_text
        .strip_prefix(before)
        .and_then(|rest| rest.strip_suffix(after))
    else {
        return false;
    };
    digits
        .parse::<u64>()
        .is_ok_and(|seq| crate::cli::output::same_file(out, &expand_seq(pattern, seq)))
}

/// `path` with `{seq}` replaced by `seq`.
fn expand_seq(path: &Path, seq: u64) -> PathBuf {
    let s = path.to_string_lossy();
    if s.contains("{seq}") {
        PathBuf::from(s.replace("{seq}", &seq.to_string()))
    } else {
        path.to_path_buf()
    }
}
