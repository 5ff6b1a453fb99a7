//! `envlight sh`: spherical-harmonic coefficients of HDR frames (files or the built-in sky), as
//! JSON Lines in the wire's JSON form. Only argument handling, I/O and printing; the work is in
//! `envlight::sh`.

use crate::cli::output::JsonLines;
use anyhow::{Context, Result};
use clap::Args;
use envlight::sh::MAX_DEGREE;
use envlight::sh_stage::{ShProjector, ShSettings, ShStageError};
use envlight::stream::protocol::{sh_frame_to_json, ShFrame};
use std::path::PathBuf;

pub(crate) const LONG_ABOUT: &str = "\
Project HDR frames onto the real spherical harmonics up to --degree: (degree + 1)² rgb
coefficients of radiance per frame, the ambient light of engines' light probes (at degree 2
three.js's SphericalHarmonics3, +Y up). Prints one JSON line per frame, the JSON form of the
daemon's representation `sh` (docs/protocol.md) with the frame's ∫L dω added:

  {\"seq\":0,\"time\":0.0,\"representation\":\"sh\",\"stale\":false,\"degree\":2,
   \"sh\":[[r,g,b],…],\"integral\":[r,g,b]}

Coefficient l² + l + m belongs to Y_l^m (docs/sh.md gives the basis); the irradiance of a
surface of normal n is Σ_l Â_l Σ_m L_lm Y_lm(n) with Â = π, 2π/3, π/4, 0, −π/24, …
Without INPUT the built-in sky is used (1 frame unless --frames says otherwise).

The sets are filtered in time with the lights' FIR taps (those of `envlight decompose`, newest
frame first; --taps, --no-filter as there): the set of frame t is Σ_k w_k · set(t−k), the set of
the filtered map, so it lags the frames by the lights' delay (3 frames with the default taps)
and describes the same moment as `envlight decompose`'s lights of the same seq. The first
frame's set fills the window, so a single frame's set is its own.";

#[derive(Args, Debug)]
pub(crate) struct ShArgs {
    #[command(flatten)]
    input: crate::cli::wavelet::FrameInput,
    /// Highest band, 0..=15: (degree + 1)² coefficients per channel.
    #[arg(long, value_name = "L", default_value_t = envlight::sh_stage::DEFAULT_DEGREE,
          value_parser = parse_degree)]
    degree: usize,
    /// Output file (JSON Lines). [default: stdout]
    #[arg(long, value_name = "FILE")]
    out: Option<PathBuf>,
    #[command(flatten)]
    filter: crate::cli::FilterFlags,
}

fn parse_degree(text: &str) -> Result<usize, String> {
    match text.parse::<usize>() {
        Ok(degree) if degree <= MAX_DEGREE => Ok(degree),
        _ => Err(format!("{text:?}: must be an integer in 0..={MAX_DEGREE}")),
    }
}

pub(crate) fn run(args: &ShArgs) -> Result<()> {
    let mut source = args.input.open()?;
    let mut inputs = crate::cli::output::InputFiles::new(source.files());
    let mut output = JsonLines::open(args.out.as_deref(), "--out", &mut inputs)?;
    let filter_taps = args.filter.chosen_taps();
    // One projection plan per projection and frame size; the filter's window.
    let mut projector = match ShProjector::new(ShSettings {
        degree: args.degree,
        filter_taps,
    }) {
        Ok(projector) => projector,
        // The degree is clap's to check; the taps' rule is the lights' filter's.
        Err(ShStageError::Settings { rule, .. }) => {
            crate::cli::usage_error!("invalid --taps: {rule}")
        }
        Err(e) => return Err(e.into()),
    };
    while let Some(frame) = source.next_frame().context("cannot read a frame")? {
        let set = projector.coefficients(&frame);
        let sh = ShFrame::new(frame.seq, frame.time, &set);
        // The wire's JSON frame (an object) with the frame's ∫L dω appended.
        let frame_json = sh_frame_to_json(&sh, None, false);
        let integral = serde_json::to_string(&set.integral()).context("cannot encode a frame")?;
        let line = format!(
            "{},\"integral\":{integral}}}",
            frame_json.strip_suffix('}').unwrap_or(&frame_json)
        );
        if !output.line(&line)? {
            return Ok(());
        }
        let up = set.irradiance(glam::DVec3::Y);
        tracing::info!(
            "frame {}: degree {}, irradiance up [{:.4}, {:.4}, {:.4}]",
            frame.seq,
            set.degree(),
            up[0],
            up[1],
            up[2]
        );
    }
    output.finish()
}
