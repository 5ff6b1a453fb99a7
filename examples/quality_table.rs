//! Prints a Markdown table of the yardsticks (DESIGN.md) for each light-generation method on each
//! given lat-long map, at N = 64 and 256 lights.
//!
//! ```text
//! cargo run --release --example quality_table -- tests/data/*.hdr
//! ```
//!
//! Only Radiance `.hdr` files are read here (through the `image` crate); any other file is
//! reported on stderr and skipped, and the exit status is then 1. A method is one more entry in
//! `methods`.

use anyhow::{bail, Context, Result};
use envlight::envmap::Projection;
use envlight::yardstick::{evaluate, median_cut, ReferenceMap};
use envlight::{HdrFrame, LightFrame};
use std::path::Path;

/// Width of the reference map the yardsticks are computed on.
const REFERENCE_WIDTH: u32 = 256;
/// Light counts of the table.
const LIGHT_COUNTS: [usize; 2] = [64, 256];

/// A light-generation method: frame and light count in, lights out.
type Method = Box<dyn Fn(&HdrFrame, usize) -> Result<LightFrame>>;

fn read_hdr(path: &Path) -> Result<HdrFrame> {
    let is_hdr = path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("hdr"));
    if !is_hdr {
        bail!("only Radiance .hdr files are supported by this example");
    }
    let image = image::open(path)?.to_rgb32f();
    let (w, h) = image.dimensions();
    if w != 2 * h {
        bail!("{w}x{h} is not a 2:1 lat-long map");
    }
    let pixels = image.pixels().map(|p| p.0).collect();
    let mut frame = HdrFrame::new(w, h, pixels, Projection::LatLong).context("empty image")?;
    frame.sanitize();
    Ok(frame)
}

fn main() {
    let paths: Vec<String> = std::env::args().skip(1).collect();
    if paths.is_empty() {
        eprintln!("usage: quality_table MAP.hdr...");
        std::process::exit(2);
    }
    let methods: Vec<(&str, Method)> = vec![(
        "median cut",
        Box::new(|frame: &HdrFrame, n: usize| Ok(median_cut(frame, n)?)),
    )];

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
        let (frame, map) = match read_hdr(path).and_then(|frame| {
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
