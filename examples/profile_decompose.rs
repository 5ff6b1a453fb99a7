//! Runs the default decomposition of one map many times (for `perf record`).
//!
//! ```text
//! cargo run --release --example profile_decompose -- tests/data/rooitou_park_1k.hdr 2000
//! ```
use envlight::capture::image_file::read_hdr_image;
use envlight::decompose::{DecomposeSettings, Decomposer};
use envlight::envmap::Projection;
use envlight::HdrFrame;

fn main() -> anyhow::Result<()> {
    let mut args = std::env::args().skip(1);
    let path = args
        .next()
        .unwrap_or_else(|| "tests/data/rooitou_park_1k.hdr".into());
    let iterations: usize = args.next().map_or(Ok(1000), |s| s.parse())?;
    let image = read_hdr_image(std::path::Path::new(&path))?;
    let frame = HdrFrame::new(image.width, image.height, image.pixels, Projection::LatLong)
        .ok_or_else(|| anyhow::anyhow!("empty image"))?;
    let mut decomposer = Decomposer::new(DecomposeSettings::default())?;
    let start = std::time::Instant::now();
    let mut lights = 0;
    for _ in 0..iterations {
        lights += decomposer.decompose(&frame).lights.len();
    }
    let per_frame = start.elapsed().as_secs_f64() / iterations as f64;
    println!(
        "{:.3} ms per frame, {} lights per frame",
        per_frame * 1e3,
        lights / iterations
    );
    Ok(())
}
