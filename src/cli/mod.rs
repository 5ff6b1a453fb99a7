//! The subcommands of the `envlight` binary, one module each: argument definitions (clap),
//! the checks clap cannot make, building the configuration, calling the library and printing.
//! The work itself is in the `envlight` library.
//!
//! - [`decompose`]: `decompose`, frames to JSON Lines of lights;
//! - [`daemon`]: `run`, `record` and `check-config`;
//! - [`subscribe`]: `subscribe`, a client of a running daemon;
//! - [`render`]: `render`, a scene under the lights (PNG and EXR);
//! - [`fit_asg`]: `fit-asg`, anisotropic spherical Gaussians;
//! - [`camera`]: `devices`, `calibrate-response`, `calibrate-fisheye`;
//! - [`wavelet`] and [`wavelet_transport`]: `wavelet approx`, `relight` and `recover`;
//! - [`output`]: output files and stdout shared by the one-shot commands;
//! - [`fisheye_flags`]: the fisheye calibration flags of `decompose` and `wavelet`.
//!
//! Here: what several subcommands share (value parsers, [`UsageError`], the frame source a
//! config names).

pub(crate) mod camera;
pub(crate) mod daemon;
pub(crate) mod decompose;
pub(crate) mod fisheye_flags;
pub(crate) mod fit_asg;
pub(crate) mod output;
pub(crate) mod render;
pub(crate) mod sh;
pub(crate) mod subscribe;
pub(crate) mod wavelet;
pub(crate) mod wavelet_transport;

use anyhow::{Context, Result};
use envlight::capture::FrameSource;
use envlight::config::{Config, SourceKind};

/// Parses an INPUT argument (a file, directory or glob pattern), refusing one that is not
/// UTF-8 with its name (glob patterns and config paths are UTF-8 text; clap's own message
/// did not say which argument it was). A file with such a name is still read when its
/// directory is given.
#[derive(Clone)]
struct Utf8Input;

impl clap::builder::TypedValueParser for Utf8Input {
    type Value = String;

    fn parse_ref(
        &self,
        cmd: &clap::Command,
        _arg: Option<&clap::Arg>,
        value: &std::ffi::OsStr,
    ) -> std::result::Result<String, clap::Error> {
        value.to_str().map(str::to_owned).ok_or_else(|| {
            clap::Error::raw(
                clap::error::ErrorKind::InvalidUtf8,
                format!(
                    "INPUT {:?} is not valid UTF-8; rename the file or give its directory \
                     (every .exr/.hdr in it is read)\n",
                    value.to_string_lossy()
                ),
            )
            .with_cmd(cmd)
        })
    }
}

/// A misuse of the command line that clap's parsing cannot see (a flag's value out of its
/// range, options that do not go together, an option that the chosen mode would ignore): exit
/// status 2, like clap's own. (An invalid value in a config file is a runtime error, 1.)
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub(crate) struct UsageError(pub(crate) String);

/// A [`UsageError`] as an error to return or map to (a flag's value out of its range).
pub(crate) fn usage(message: impl Into<String>) -> anyhow::Error {
    UsageError(message.into()).into()
}

/// A `v4l2:DEVICE` INPUT among others is a usage error: a camera is given as the only INPUT.
pub(crate) fn refuse_camera_among_files(inputs: &[String]) -> Result<()> {
    match inputs.iter().find(|p| p.starts_with("v4l2:")) {
        Some(camera) if inputs.len() > 1 => Err(usage(format!(
            "INPUT {camera}: a camera is the only INPUT (one v4l2:DEVICE, no files with it)"
        ))),
        _ => Ok(()),
    }
}

/// Returns a [`UsageError`] from the enclosing function.
macro_rules! usage_error {
    ($($arg:tt)*) => {
        return Err(crate::cli::UsageError(format!($($arg)*)).into())
    };
}
pub(crate) use usage_error;

fn parse_pair(s: &str) -> Result<[f64; 2], String> {
    let (x, y) = s
        .split_once(',')
        .ok_or_else(|| format!("expected X,Y (two numbers), got {s:?}"))?;
    let num = |v: &str| {
        v.trim()
            .parse::<f64>()
            .map_err(|e| format!("{v:?} is not a number: {e}"))
    };
    Ok([num(x)?, num(y)?])
}

fn parse_shadow_raster(s: &str) -> Result<envlight::render::ShadowRaster, String> {
    envlight::render::ShadowRaster::parse(s)
        .ok_or_else(|| format!("expected \"auto\", \"pipeline\" or \"compute\", got {s:?}"))
}

fn parse_size(s: &str) -> Result<(u32, u32), String> {
    let (w, h) = s
        .split_once(['x', 'X'])
        .ok_or_else(|| format!("expected WIDTHxHEIGHT, got {s:?}"))?;
    let num = |v: &str| {
        v.trim()
            .parse::<u32>()
            .map_err(|e| format!("{v:?} is not a pixel count: {e}"))
    };
    Ok((num(w)?, num(h)?))
}

/// A number an option holds as f32: one beyond f32's range (`1e39`) is an error naming it,
/// not infinity (which later checks reported as "got inf", without the value given), and so is
/// a non-zero one too small to be other than 0 (`1e-300`).
/// A point X,Y,Z of three finite numbers (`render --eye`, `--look-at`).
pub(crate) fn parse_point(s: &str) -> Result<[f32; 3], String> {
    let parts: Vec<&str> = s.split(',').collect();
    let [x, y, z] = parts[..] else {
        return Err(format!("{s:?} is not three numbers X,Y,Z"));
    };
    Ok([
        parse_finite_f32(x)?,
        parse_finite_f32(y)?,
        parse_finite_f32(z)?,
    ])
}

pub(crate) fn parse_finite_f32(s: &str) -> Result<f32, String> {
    let x: f64 = (s.trim().parse()).map_err(|_| format!("{s:?} is not a number"))?;
    if x.is_finite() && x.abs() <= f64::from(f32::MAX) {
        // Below f32's smallest subnormal a number given as non-zero would become 0, and be
        // refused as such ("must be a positive number") without the value given.
        if x != 0.0 && x as f32 == 0.0 {
            return Err(format!(
                "{s} is too small for single precision (not 0 and under 1.4e-45)"
            ));
        }
        Ok(x as f32)
    } else {
        Err(format!(
            "{s} is not a finite number of single precision (at most 3.4e38)"
        ))
    }
}

/// `--no-filter` and `--taps`: the temporal FIR filter of `decompose`'s lights and, with the
/// same taps, of `sh`'s sets and `fit-asg`'s lobes.
#[derive(clap::Args, Debug)]
pub(crate) struct FilterFlags {
    /// Disable the temporal FIR filter.
    #[arg(long, conflicts_with = "taps")]
    pub(crate) no_filter: bool,

    /// FIR filter taps, newest frame first: 1 to 64 non-negative weights, normalised to sum to 1.
    /// [default: 1,6,15,20,15,6,1]
    #[arg(
        long,
        value_name = "W,W,…",
        value_delimiter = ',',
        num_args = 1,
        value_parser = parse_tap
    )]
    pub(crate) taps: Option<Vec<f64>>,
}

impl FilterFlags {
    /// The taps asked for: none with `--no-filter`, `--taps`, or the lights' default taps.
    pub(crate) fn chosen_taps(&self) -> Option<Vec<f64>> {
        match (&self.taps, self.no_filter) {
            (_, true) => None,
            (Some(taps), false) => Some(taps.clone()),
            (None, false) => Some(envlight::decompose::filter::DEFAULT_TAPS.to_vec()),
        }
    }
}

/// One weight of `--taps` (spaces around it allowed, as in `--taps "1, 2, 1"`).
fn parse_tap(s: &str) -> Result<f64, String> {
    s.trim()
        .parse()
        .map_err(|_| format!("{s:?} is not a number"))
}

/// `render --size`: [`parse_size`] within 1..=[`envlight::config::MAX_RENDER_SIDE`] a side, as
/// `render.width` and `render.height` are.
fn parse_render_size(s: &str) -> Result<(u32, u32), String> {
    let (w, h) = parse_size(s)?;
    let max = envlight::config::MAX_RENDER_SIDE;
    if (1..=max).contains(&w) && (1..=max).contains(&h) {
        Ok((w, h))
    } else {
        Err(format!("{w}x{h}: each side must be 1..={max} pixels"))
    }
}

/// The configured frame source (sky, sequence or camera), limited to `source.frames` and with a
/// fisheye calibration checked against the frames: [`envlight::capture::open`].
fn open_source(config: &Config) -> Result<Box<dyn FrameSource>> {
    let context = match config.source.kind {
        SourceKind::Sky => "cannot set up the built-in sky",
        SourceKind::Sequence => "cannot open the input frames",
        SourceKind::V4l2 => "cannot open the camera",
    };
    envlight::capture::open(config).context(context)
}

/// "on" or "off", for the settings in log lines and `check-config`.
/// "above F× the mean light" or "off", for the split of bright lights.
fn split_description(factor: Option<f64>) -> String {
    factor.map_or("off".to_string(), |f| format!("above {f}× the mean light"))
}

fn on_off(on: bool) -> &'static str {
    if on {
        "on"
    } else {
        "off"
    }
}

/// Writes a line to stderr, ignoring a failure: stderr whose reader went away (`2>&1 | head`,
/// a journald stream that closed) must not turn into a panic (`eprintln!` panics on a write
/// error) and exit status 101.
pub(crate) fn print_to_stderr(line: std::fmt::Arguments) {
    use std::io::Write;
    let _ = writeln!(std::io::stderr().lock(), "{line}");
}
