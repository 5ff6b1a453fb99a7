//! Prints a Markdown table of the yardsticks (DESIGN.md) for each light-generation method on each
//! given lat-long map, at N = 64 and 256 lights.
//!
//! ```text
//! cargo run --release --example quality_table -- tests/data/*.hdr
//! ```
//!
//! Reads `.hdr` and `.exr` lat-long maps; a file that cannot be read is reported on stderr and
//! skipped, and the exit status is then 1. A method is one more entry in `methods`.

mod common;

use anyhow::Result;
use envlight::decompose::merge::DEFAULT_SPACING_FRACTION;
use envlight::decompose::split::DEFAULT_SPLIT_FACTOR;
use envlight::decompose::{
    DecomposeSettings, Decomposer, LightPlacement, Warp, DEFAULT_PDF_EXPONENT,
};
use envlight::yardstick::{evaluate, median_cut, ReferenceMap};
use envlight::{HdrFrame, LightFrame};
use std::path::Path;

/// Width of the reference map the yardsticks are computed on.
const REFERENCE_WIDTH: u32 = 256;
/// Light counts of the table.
const LIGHT_COUNTS: [usize; 2] = [64, 256];

/// A light-generation method: frame and light count in, lights out.
type Method = Box<dyn Fn(&HdrFrame, usize) -> Result<LightFrame>>;

/// envlight's decomposition of a single frame (the temporal filter is a no-op on one frame).
fn envlight_method(placement: LightPlacement, merge: bool, pdf_exponent: f64) -> Method {
    envlight_warp(placement, merge, pdf_exponent, Warp::Rows)
}

fn envlight_warp(placement: LightPlacement, merge: bool, pdf_exponent: f64, warp: Warp) -> Method {
    Box::new(move |frame: &HdrFrame, n: usize| {
        let settings = DecomposeSettings {
            lights: n,
            warp,
            placement,
            pdf_exponent,
            filter_taps: None,
            merge_spacing_fraction: merge.then_some(DEFAULT_SPACING_FRACTION),
            ..DecomposeSettings::default()
        };
        Ok(Decomposer::new(settings)?.decompose(frame))
    })
}

fn main() {
    let paths: Vec<String> = std::env::args().skip(1).collect();
    if paths.is_empty() {
        eprintln!("usage: quality_table MAP.hdr|MAP.exr...");
        std::process::exit(2);
    }
    let gamma = DEFAULT_PDF_EXPONENT;
    let centroid = LightPlacement::Centroid;
    let methods: Vec<(&str, Method)> = vec![
        (
            "median cut",
            Box::new(|frame: &HdrFrame, n: usize| Ok(median_cut(frame, n)?)),
        ),
        ("envlight", envlight_method(centroid, false, gamma)),
        (
            "envlight, no refinement",
            Box::new(move |frame: &HdrFrame, n: usize| {
                let settings = DecomposeSettings {
                    lights: n,
                    filter_taps: None,
                    refine_concentrated: false,
                    ..DecomposeSettings::default()
                };
                Ok(Decomposer::new(settings)?.decompose(frame))
            }),
        ),
        (
            "envlight, split",
            Box::new(move |frame: &HdrFrame, n: usize| {
                let settings = DecomposeSettings {
                    lights: n,
                    filter_taps: None,
                    split_factor: Some(DEFAULT_SPLIT_FACTOR),
                    ..DecomposeSettings::default()
                };
                Ok(Decomposer::new(settings)?.decompose(frame))
            }),
        ),
        ("envlight, γ=0.5", envlight_method(centroid, false, 0.5)),
        (
            "envlight, hierarchical warp",
            envlight_warp(centroid, false, gamma, Warp::Hierarchical),
        ),
        ("envlight, merge", envlight_method(centroid, true, gamma)),
        (
            "Havran-style: γ=1, sample point",
            envlight_method(LightPlacement::SamplePoint, false, 1.0),
        ),
    ];

    println!(
        "| map | N | method | lights | diffuse | glossy-16 | glossy-128 | ground-shadow | energy |"
    );
    println!("|---|---:|---|---:|---:|---:|---:|---:|---:|");
    let mut failed = false;
    for path in &paths {
        let path = Path::new(path);
        let name = path.file_stem().map_or_else(
            || path.display().to_string(),
            |s| s.to_string_lossy().into_owned(),
        );
        let (frame, map) = match common::read_latlong_map(path).and_then(|frame| {
            let map = ReferenceMap::new(&frame, REFERENCE_WIDTH)?;
            Ok((frame, map))
        }) {
            Ok(loaded) => loaded,
            Err(e) => {
                eprintln!("error: {}: {e:#}", path.display());
                failed = true;
                continue;
            }
        };
        for n in LIGHT_COUNTS {
            for (method, run) in &methods {
                match run(&frame, n) {
                    Ok(lights) => {
                        let r = evaluate(&map, &lights.lights);
                        println!(
                            "| {name} | {n} | {method} | {} | {:.4} | {:.4} | {:.4} | {:.4} | {:.1e} |",
                            lights.lights.len(),
                            r.diffuse,
                            r.glossy16,
                            r.glossy128,
                            r.ground_shadow,
                            r.energy
                        );
                    }
                    Err(e) => {
                        eprintln!("error: {}: {method} with N={n}: {e:#}", path.display());
                        failed = true;
                    }
                }
            }
        }
    }
    if failed {
        std::process::exit(1);
    }
}
