//! The test maps in tests/data (licences in tests/data/LICENSES.txt), shared by the tests that
//! read them (tests/camera.rs, capture.rs, decompose.rs, yardstick.rs) and by
//! examples/quality_probe.rs (through `#[path]`).

// Each user takes what it needs.
#![allow(dead_code)]

use std::path::{Path, PathBuf};

/// The Radiance .hdr HDRIs (1024×512 lat-long, Poly Haven, CC0).
pub const HDRIS: [&str; 7] = [
    "empty_warehouse_01_1k.hdr",
    "noon_grass_1k.hdr",
    "potsdamer_platz_1k.hdr",
    "rooitou_park_1k.hdr",
    "st_peters_square_night_1k.hdr",
    "studio_small_03_1k.hdr",
    "venice_sunset_1k.hdr",
];

/// The maps of docs/quality.md's table: the HDRIs and two OpenEXR lat-long maps (the OpenEXR
/// project's test images, BSD-3).
pub const QUALITY_MAPS: [&str; 9] = [
    HDRIS[0],
    HDRIS[1],
    HDRIS[2],
    HDRIS[3],
    HDRIS[4],
    HDRIS[5],
    HDRIS[6],
    "KernerEnvLatLong.exr",
    "StageEnvLatLong.exr",
];

/// Path of a file in tests/data.
pub fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data")
        .join(name)
}
