//! `envlight fit-asg`: anisotropic spherical Gaussians fitted to frames, as JSON Lines.

use super::Utf8Input;
use anyhow::{anyhow, Context, Result};
use clap::Args;
use envlight::capture::sequence::{SequenceOptions, SequenceSource};
use envlight::capture::sky::{SkyOptions, SkySource};
use envlight::capture::FrameSource;
use envlight::envmap::Projection;
use std::io::Write;
use std::path::PathBuf;

/// `envlight fit-asg --help`.
pub(crate) const LONG_ABOUT: &str = "\
Fit anisotropic spherical Gaussians to HDR frames (files or the built-in sky), JSON Lines.

Each frame's K lobes are fitted as the daemon's [asg] stage fits them (the first frame from
scratch, each later one warm-started; docs/asg.md) and then, by default, filtered in time by lobe
id with the lights' FIR taps (energy, power-weighted axis and tangent, bandwidths), so that they
describe the moment the lights of `envlight decompose` describe (3 frames behind with the default
taps). --no-filter prints each frame's own fit; --taps sets the taps. Each line's \"loss\" is that
of its frame's own fit, before the filter.";

/// `fit-asg`: one JSON line per frame,
/// {"seq","time","lobes":[{"axis","tangent","bitangent","lambda","mu","rgb"}],"loss"}; the lobes
/// filtered in time with the lights' taps unless --no-filter.
#[derive(Args, Debug)]
pub(crate) struct FitAsgArgs {
    /// .exr/.hdr lat-long files, directories or glob patterns. None: the built-in sky. Every
    /// file is read as a lat-long map covering the whole sphere, whatever its aspect ratio (a
    /// frame that is not 2:1 is stretched to it; a fisheye image is not detected: its
    /// projection is set in the daemon's [source], not here).
    #[arg(value_name = "INPUT", value_parser = Utf8Input)]
    inputs: Vec<String>,
    /// Number of lobes K (1..=64).
    #[arg(long, default_value_t = envlight::asg::fit::DEFAULT_LOBES)]
    lobes: usize,
    /// Adam iterations of the first frame at full size, each taking its gradient on a rotating
    /// quarter of the map (the default, about 2,000 whole-map iterations, converges); at most
    /// 10^7. 0 keeps the greedy peak-picking initialisation as the fit.
    #[arg(long, default_value_t = envlight::asg::fit::FitSettings::default().iterations)]
    iterations: usize,
    /// Adam iterations of each warm-started frame (after a centroid step for narrow lobes;
    /// continuing the previous frame's Adam state; L_T applied as a proximal step); at most
    /// 10^7. 0 keeps the previous frame's lobes, only narrow ones (min(λ, μ) ≥ 100) moved by
    /// the centroid step.
    #[arg(long, default_value_t = envlight::asg::fit::FitSettings::default().warm_iterations)]
    warm_iterations: usize,
    /// Fit-map height (width is twice), 4..=1024.
    #[arg(long, default_value_t = envlight::asg::fit::DEFAULT_HEIGHT)]
    height: u32,
    /// Weight of the temporal loss L_T (0 disables it).
    #[arg(long, default_value_t = envlight::asg::fit::FitSettings::default().temporal_weight)]
    temporal_weight: f64,
    /// Frames to fit; 0 = every frame (the sky: endless). [default: 10 for the sky, every
    /// file for INPUT]
    #[arg(long, value_name = "N")]
    frames: Option<u64>,
    /// Output file (JSON Lines). [default: stdout]
    #[arg(long, value_name = "FILE")]
    out: Option<PathBuf>,
    /// The lobes' temporal filter (`LONG_ABOUT`).
    #[command(flatten)]
    filter: crate::cli::FilterFlags,
}

pub(crate) fn run(args: &FitAsgArgs) -> Result<()> {
    use envlight::asg::fit::{AsgFitter, FitSettings};
    let settings = FitSettings {
        lobes: args.lobes,
        iterations: args.iterations,
        warm_iterations: args.warm_iterations,
        height: args.height,
        temporal_weight: args.temporal_weight,
        // Every line reports its frame's loss.
        warm_loss: true,
        ..FitSettings::default()
    };
    // Name the option a setting came from (the fitter names its field).
    let mut fitter = AsgFitter::new(settings).map_err(|e| {
        use envlight::asg::AsgError;
        let flag = match &e {
            AsgError::LobeCount(_) => "--lobes",
            AsgError::MapSize { .. } => "--height",
            AsgError::Setting { name, .. } => match *name {
                "iterations" => "--iterations",
                "warm_iterations" => "--warm-iterations",
                "temporal_weight" => "--temporal-weight",
                _ => "",
            },
            _ => "",
        };
        if flag.is_empty() {
            anyhow!(e).context("invalid fit-asg options")
        } else {
            crate::cli::usage(format!("invalid {flag}: {e}"))
        }
    })?;
    let mut filter =
        match envlight::asg::temporal::LobeFilter::new(args.filter.chosen_taps().as_deref()) {
            Ok(filter) => filter,
            Err(rule) => crate::cli::usage_error!("invalid --taps: {rule}"),
        };
    let mut source: Box<dyn FrameSource> = if args.inputs.is_empty() {
        let options = SkyOptions {
            frames: args.frames.map_or(Some(10), |n| (n > 0).then_some(n)),
            ..SkyOptions::default()
        };
        Box::new(SkySource::new(options).context("cannot set up the built-in sky")?)
    } else {
        let options = SequenceOptions {
            fps: None,
            looped: false,
            projection: Projection::LatLong,
        };
        Box::new(super::wavelet::Limited {
            inner: SequenceSource::new(&args.inputs, options)
                .context("cannot open the input frames")?,
            left: args.frames.filter(|&n| n > 0),
        })
    };
    let mut writer = std::io::BufWriter::new(crate::cli::output::open_output(
        args.out.as_deref(),
        "--out",
        &crate::cli::output::InputFiles::new(source.files()),
    )?);
    while let Some(frame) = source.next_frame().context("cannot read a frame")? {
        let mut result = fitter
            .fit_frame(&frame)
            .with_context(|| format!("cannot fit frame {}", frame.seq))?;
        filter.apply(&mut result.lobes);
        #[derive(serde::Serialize)]
        struct Line<'a> {
            seq: u64,
            time: f64,
            lobes: &'a [envlight::asg::Asg],
            loss: Option<f64>,
        }
        let line = Line {
            seq: frame.seq,
            time: frame.time,
            lobes: &result.lobes,
            loss: result.loss.map(|l| l.total),
        };
        let line = serde_json::to_string(&line).context("cannot encode a frame")?;
        match writeln!(writer, "{line}") {
            Err(e) if crate::cli::output::is_broken_pipe(&e) => return Ok(()),
            r => r.context("cannot write the output")?,
        }
    }
    match writer.flush() {
        Err(e) if crate::cli::output::is_broken_pipe(&e) => Ok(()),
        r => r.context("cannot write the output"),
    }
}
