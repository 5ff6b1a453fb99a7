//! Prints a Markdown table of how well spherical harmonics hold each given lat-long map's
//! diffuse light: the relative RMS error of the irradiance E(n) over the yardstick's 1,024
//! normals (DESIGN.md; `envlight::yardstick`) for SH sets of degree 1, 2, 3, 4, 6 and 8, and
//! for envlight's lights at N = 16 and 64 (one frame, no temporal filter), each with the size
//! of its binary frame message (docs/protocol.md).
//!
//! ```text
//! cargo run --release --example sh_table -- tests/data/*.hdr
//! ```
//!
//! A file that cannot be read is reported on stderr and skipped; the exit status is then 1.

mod common;

use anyhow::Result;
use envlight::decompose::{DecomposeSettings, Decomposer};
use envlight::sh::{coefficient_count, project};
use envlight::yardstick::{
    diffuse_irradiance_error, evaluation_directions, relative_rms, ReferenceMap,
};
use std::path::Path;

/// Width of the reference map the yardsticks are computed on (as docs/quality.md).
const REFERENCE_WIDTH: u32 = 256;
const DEGREES: [usize; 6] = [1, 2, 3, 4, 6, 8];
const LIGHT_COUNTS: [usize; 2] = [16, 64];

/// One row per representation of the map at `path`.
fn rows(path: &Path) -> Result<Vec<String>> {
    let frame = common::read_latlong_map(path)?;
    let name = path.file_stem().map_or_else(
        || path.display().to_string(),
        |s| s.to_string_lossy().into(),
    );
    let reference = ReferenceMap::new(&frame, REFERENCE_WIDTH)?;
    let truth = &reference.truth().diffuse;
    let mut rows = Vec::new();
    for degree in DEGREES {
        let set = project(&frame, degree);
        let irradiance: Vec<[f64; 3]> = evaluation_directions()
            .into_iter()
            .map(|n| set.irradiance(n))
            .collect();
        let count = coefficient_count(degree);
        rows.push(format!(
            "| {name} | SH degree {degree} | {count} × 3 | {} | {:.4} |",
            40 + 12 * count,
            relative_rms(&irradiance, truth)
        ));
    }
    for n in LIGHT_COUNTS {
        let settings = DecomposeSettings {
            lights: n,
            filter_taps: None,
            ..DecomposeSettings::default()
        };
        let lights = Decomposer::new(settings)?.decompose(&frame);
        rows.push(format!(
            "| {name} | {n} lights | {n} × 8 | {} | {:.4} |",
            36 + 32 * lights.lights.len(),
            diffuse_irradiance_error(&reference, &lights.lights)
        ));
    }
    Ok(rows)
}

fn main() {
    let paths: Vec<String> = std::env::args().skip(1).collect();
    if paths.is_empty() {
        eprintln!("usage: sh_table MAP.hdr|MAP.exr...");
        std::process::exit(2);
    }
    println!("| map | representation | numbers | message bytes | diffuse error |");
    println!("|---|---|---:|---:|---:|");
    let mut failed = false;
    for path in &paths {
        match rows(Path::new(path)) {
            Ok(rows) => rows.iter().for_each(|r| println!("{r}")),
            Err(e) => {
                eprintln!("{path}: {e:#}");
                failed = true;
            }
        }
    }
    if failed {
        std::process::exit(1);
    }
}
