//! Writes the progressive point set that envlight ships (`src/decompose/progressive_points.bin`):
//! the relaxation of all `MAX_POINTS` points (src/decompose/point_set.rs), as little-endian f64
//! pairs. Run it after a change of the relaxation; the test `the_shipped_set_is_the_relaxation`
//! fails until the table is written again.
//!
//! ```sh
//! cargo run --release --example point_set_table [-- OUT]
//! ```

use anyhow::Context;
use envlight::decompose::point_set::{relax_progressive_points, table_bytes};
use envlight::decompose::MAX_POINTS;

fn main() -> anyhow::Result<()> {
    let out = std::env::args()
        .nth(1)
        .unwrap_or_else(|| "src/decompose/progressive_points.bin".to_owned());
    let started = std::time::Instant::now();
    let points = relax_progressive_points(MAX_POINTS);
    let bytes = table_bytes(&points);
    std::fs::write(&out, &bytes).with_context(|| format!("cannot write {out}"))?;
    eprintln!(
        "{} points relaxed in {:.2} s, {} bytes written to {out}",
        points.len(),
        started.elapsed().as_secs_f64(),
        bytes.len()
    );
    Ok(())
}
