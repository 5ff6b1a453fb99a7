//! What the table examples share (`mod common;` in each).

use anyhow::{bail, Context, Result};
use envlight::capture::image_file::read_hdr_image;
use envlight::envmap::Projection;
use envlight::HdrFrame;
use std::path::Path;

/// A 2:1 lat-long map file (`.hdr` or `.exr`) as a frame, non-finite and negative pixels set
/// to 0.
pub fn read_latlong_map(path: &Path) -> Result<HdrFrame> {
    let image = read_hdr_image(path)?;
    if image.width != 2 * image.height {
        bail!("{}x{} is not a 2:1 lat-long map", image.width, image.height);
    }
    let mut frame = HdrFrame::new(image.width, image.height, image.pixels, Projection::LatLong)
        .context("empty image")?;
    frame.sanitize();
    Ok(frame)
}
