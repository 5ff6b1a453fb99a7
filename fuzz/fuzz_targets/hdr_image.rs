//! Recorded frames: arbitrary bytes decoded as an OpenEXR file and as a Radiance HDR file.
#![no_main]

use std::path::Path;

use envlight::capture::image_file::{decode_hdr_image, ImageFormat};
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let _ = decode_hdr_image(data, ImageFormat::OpenExr, Path::new("fuzz.exr"));
    let _ = decode_hdr_image(data, ImageFormat::RadianceHdr, Path::new("fuzz.hdr"));
});
