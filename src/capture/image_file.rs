//! Reading one HDR image file (`.exr` or `.hdr`) into linear RGB ([`read_hdr_image`]).
//!
//! The format is chosen by the file extension (case-insensitive): `.exr` (OpenEXR, via the `exr`
//! crate) or `.hdr` (Radiance RGBE, via the `image` crate). The whole file is read into memory
//! first, so a missing or unreadable file is a [`CaptureError::Io`] and everything that goes
//! wrong afterwards (truncated, corrupt or unsupported data) is a [`CaptureError::Format`] that
//! carries the decoder's message. Both name the file.
//!
//! OpenEXR:
//! - half, f32 and u32 samples (u32 is converted to f32); scan-line or tiled; every compression
//!   the `exr` crate reads; of a mip- or rip-mapped file only the largest resolution level.
//! - Channels: `R`,`G`,`B` (any further channel such as `A` is ignored) or, failing that,
//!   luminance-only `Y` (returned as grey RGB). Names may carry a layer/view prefix
//!   (`left.R`, `diffuse.R`). In a multi-part or multi-layer file the first part, and within it
//!   the first channel group (the unprefixed channels first, then prefixes in the file's
//!   alphabetical channel order), that has R, G and B is used; only if none has, the first with
//!   `Y`. Otherwise a `Format` error lists the channels found.
//! - **Data window**: the image returned is the size of the chosen part's *data window*, not of
//!   its display window; an offset or smaller data window is not padded or cropped to the
//!   display window. (Environment maps have data window = display window; for the rest this is
//!   the simplest honest answer: every pixel returned is one the file stores.)
//! - Every part of a multi-part file is decoded (the `exr` reading API has no per-part
//!   selection), then the chosen one is kept; single-part environment maps pay nothing extra.
//! - Decoding runs on the calling thread (`non_parallel`): `exr` decompresses on a rayon pool
//!   otherwise, and a panic inside that pool on corrupt data would abort the process instead of
//!   unwinding into our `catch_unwind`.
//!
//! Radiance `.hdr`: RLE or flat RGBE with the usual `-Y H +X W` orientation (the decoder rejects
//! others); comment lines in the header (including a repeated `#?RADIANCE` magic line) are
//! skipped. Values are divided by the header's cumulative `EXPOSURE` if there is one, so they are
//! the radiance the file describes.
//!
//! Robustness: the decoders should return errors on bad input, but they do not always (the
//! corruption test in `tests/capture.rs` hits an arithmetic-overflow panic in `exr`'s B44
//! decoder when overflow checks are on), so decoding runs inside [`std::panic::catch_unwind`]
//! and a panic becomes a `Format` error (the default panic hook still prints the panic message
//! to stderr). Images of more than
//! [`MAX_PIXELS`] pixels are rejected before pixel data is allocated.

use super::CaptureError;
use exr::prelude::{FlatSamples, ReadChannels, ReadLayers};
use image::ImageDecoder;
use std::io::Cursor;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::{Path, PathBuf};

/// Largest image (in pixels, summed over all parts of an EXR file) that is decoded: 16384×8192.
pub const MAX_PIXELS: u64 = 16384 * 8192;

/// The file extensions [`read_hdr_image`] reads (compared case-insensitively).
pub const SUPPORTED_EXTENSIONS: [&str; 2] = ["exr", "hdr"];

/// A linear RGB image: `width * height` pixels, row-major, top row first.
#[derive(Clone, Debug, PartialEq)]
pub struct RgbImage {
    pub width: u32,
    pub height: u32,
    pub pixels: Vec<[f32; 3]>,
}

/// The file formats [`read_hdr_image`] reads.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ImageFormat {
    OpenExr,
    RadianceHdr,
}

impl ImageFormat {
    /// The format of `path` from its extension (case-insensitive), `None` if unsupported.
    pub fn from_path(path: &Path) -> Option<Self> {
        let ext = path.extension()?.to_str()?;
        if ext.eq_ignore_ascii_case("exr") {
            Some(Self::OpenExr)
        } else if ext.eq_ignore_ascii_case("hdr") {
            Some(Self::RadianceHdr)
        } else {
            None
        }
    }
}

/// Reads an `.exr` or `.hdr` file into linear RGB. See the module docs for what is supported.
pub fn read_hdr_image(path: &Path) -> Result<RgbImage, CaptureError> {
    let format = ImageFormat::from_path(path).ok_or_else(|| CaptureError::Format {
        path: path.to_path_buf(),
        message: format!(
            "unsupported file type; supported extensions are {}",
            SUPPORTED_EXTENSIONS
                .iter()
                .map(|e| format!(".{e}"))
                .collect::<Vec<_>>()
                .join(", ")
        ),
    })?;
    let bytes = std::fs::read(path).map_err(|source| CaptureError::Io {
        path: path.to_path_buf(),
        source,
    })?;
    decode_hdr_image(&bytes, format, path)
}

/// Decodes the contents of an `.exr` or `.hdr` file held in memory; `path` only names the data
/// in errors. Every failure is a [`CaptureError::Format`].
pub fn decode_hdr_image(
    bytes: &[u8],
    format: ImageFormat,
    path: &Path,
) -> Result<RgbImage, CaptureError> {
    let decoded = catch_unwind(AssertUnwindSafe(|| match format {
        ImageFormat::OpenExr => decode_exr(bytes),
        ImageFormat::RadianceHdr => decode_hdr(bytes),
    }));
    let result = match decoded {
        Ok(result) => result,
        Err(panic) => {
            let what = panic
                .downcast_ref::<&str>()
                .map(|s| s.to_string())
                .or_else(|| panic.downcast_ref::<String>().cloned())
                .unwrap_or_else(|| "unknown panic".to_string());
            Err(format!("decoder panicked (corrupt file?): {what}"))
        }
    };
    result.map_err(|message| format_error(path, message))
}

fn format_error(path: &Path, message: String) -> CaptureError {
    CaptureError::Format {
        path: PathBuf::from(path),
        message,
    }
}

fn check_size(width: u64, height: u64) -> Result<(), String> {
    if width == 0 || height == 0 {
        return Err(format!("image is empty ({width}x{height})"));
    }
    if width.saturating_mul(height) > MAX_PIXELS {
        return Err(format!(
            "image is too large ({width}x{height}; at most {MAX_PIXELS} pixels are read)"
        ));
    }
    Ok(())
}

// ---------------------------------------------------------------------------------------------
// Radiance HDR

fn decode_hdr(bytes: &[u8]) -> Result<RgbImage, String> {
    let decoder = image::codecs::hdr::HdrDecoder::new(Cursor::new(bytes))
        .map_err(|e| format!("not a valid Radiance HDR file: {e}"))?;
    let (width, height) = decoder.dimensions();
    check_size(u64::from(width), u64::from(height))?;
    let exposure = decoder
        .metadata()
        .exposure
        .filter(|e| e.is_finite() && *e > 0.0)
        .unwrap_or(1.0);
    let image = image::DynamicImage::from_decoder(decoder)
        .map_err(|e| format!("cannot decode Radiance HDR pixels: {e}"))?
        .into_rgb32f();
    let scale = 1.0 / exposure;
    let pixels: Vec<[f32; 3]> = image
        .pixels()
        .map(|p| [p.0[0] * scale, p.0[1] * scale, p.0[2] * scale])
        .collect();
    if pixels.len() != width as usize * height as usize {
        return Err("decoder returned the wrong number of pixels".to_string());
    }
    Ok(RgbImage {
        width,
        height,
        pixels,
    })
}

// ---------------------------------------------------------------------------------------------
// OpenEXR

/// Which channels of which part make the image.
#[derive(Debug, PartialEq, Eq)]
struct ChannelChoice {
    part: usize,
    /// Indices into the part's channel list: `[R, G, B]`, or `[Y, Y, Y]` for luminance.
    channels: [usize; 3],
}

/// Splits `left.R` into (`left.`, `R`) and `R` into (``, `R`).
fn split_channel_name(name: &str) -> (&str, &str) {
    match name.rfind('.') {
        Some(dot) => (&name[..=dot], &name[dot + 1..]),
        None => ("", name),
    }
}

/// Picks the channels to use from the channel names of every part (see the module docs).
fn choose_channels(parts: &[Vec<String>]) -> Option<ChannelChoice> {
    // Channel groups in priority order: per part, the unprefixed group first, then the others
    // in the order they first appear.
    let mut groups: Vec<(usize, &str)> = Vec::new();
    for (part, names) in parts.iter().enumerate() {
        groups.push((part, ""));
        for name in names {
            let (prefix, _) = split_channel_name(name);
            if !groups.contains(&(part, prefix)) {
                groups.push((part, prefix));
            }
        }
    }
    let find = |part: usize, prefix: &str, base: &str| {
        parts[part]
            .iter()
            .position(|n| split_channel_name(n) == (prefix, base))
    };
    let rgb = groups.iter().find_map(|&(part, prefix)| {
        Some(ChannelChoice {
            part,
            channels: [
                find(part, prefix, "R")?,
                find(part, prefix, "G")?,
                find(part, prefix, "B")?,
            ],
        })
    });
    rgb.or_else(|| {
        groups.iter().find_map(|&(part, prefix)| {
            let y = find(part, prefix, "Y")?;
            Some(ChannelChoice {
                part,
                channels: [y; 3],
            })
        })
    })
}

fn decode_exr(bytes: &[u8]) -> Result<RgbImage, String> {
    // The header first: reject deep data and absurd sizes before any pixel is allocated.
    let meta = exr::meta::MetaData::read_from_buffered(Cursor::new(bytes), false)
        .map_err(|e| format!("not a valid OpenEXR file: {e}"))?;
    let mut total_samples: u64 = 0;
    for header in meta.headers.iter() {
        let size = header.layer_size;
        check_size(size.width() as u64, size.height() as u64)?;
        total_samples = total_samples.saturating_add(
            (size.width() as u64)
                .saturating_mul(size.height() as u64)
                .saturating_mul(header.channels.list.len() as u64),
        );
    }
    if total_samples > 4 * MAX_PIXELS {
        return Err(format!(
            "file holds too many samples ({total_samples}; at most {} are read)",
            4 * MAX_PIXELS
        ));
    }
    let parts: Vec<Vec<String>> = meta
        .headers
        .iter()
        .map(|h| h.channels.list.iter().map(|c| c.name.to_string()).collect())
        .collect();
    let choice = choose_channels(&parts).ok_or_else(|| {
        let found: Vec<String> = parts
            .iter()
            .enumerate()
            .map(|(i, names)| format!("part {i}: [{}]", names.join(", ")))
            .collect();
        format!(
            "no R,G,B or Y channels (channels found: {})",
            found.join("; ")
        )
    })?;
    if meta.headers.iter().any(|h| h.deep) {
        return Err("deep OpenEXR data is not supported".to_string());
    }

    let image = exr::prelude::read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .all_layers()
        .all_attributes()
        .non_parallel()
        .from_buffered(Cursor::new(bytes))
        .map_err(|e| format!("cannot decode OpenEXR pixels: {e}"))?;

    let layer = image
        .layer_data
        .get(choice.part)
        .ok_or_else(|| format!("part {} is missing from the decoded file", choice.part))?;
    let (width, height) = (layer.size.width(), layer.size.height());
    check_size(width as u64, height as u64)?;
    let count = width * height;
    // The decoded channel list is sorted by name just like the header's, but look the channels
    // up by name rather than trust the indices.
    let mut samples: Vec<&FlatSamples> = Vec::with_capacity(3);
    for &index in &choice.channels {
        let name = &parts[choice.part][index];
        let channel = layer
            .channel_data
            .list
            .iter()
            .find(|c| c.name.to_string() == *name)
            .ok_or_else(|| format!("channel {name} is missing from the decoded file"))?;
        if channel.sampling.x() != 1 || channel.sampling.y() != 1 {
            return Err(format!(
                "channel {name} is subsampled ({}x{}), which is not supported",
                channel.sampling.x(),
                channel.sampling.y()
            ));
        }
        if channel.sample_data.len() != count {
            return Err(format!(
                "channel {name} has {} samples, expected {count}",
                channel.sample_data.len()
            ));
        }
        samples.push(&channel.sample_data);
    }
    let to_f32 = |s: &FlatSamples| -> Vec<f32> { s.values_as_f32().collect() };
    let r = to_f32(samples[0]);
    let (g, b) = if choice.channels[0] == choice.channels[1] {
        (r.clone(), r.clone())
    } else {
        (to_f32(samples[1]), to_f32(samples[2]))
    };
    let pixels = r
        .iter()
        .zip(&g)
        .zip(&b)
        .map(|((&r, &g), &b)| [r, g, b])
        .collect();
    Ok(RgbImage {
        width: u32::try_from(width).map_err(|_| "image too wide".to_string())?,
        height: u32::try_from(height).map_err(|_| "image too high".to_string())?,
        pixels,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn names(list: &[&str]) -> Vec<String> {
        list.iter().map(|s| s.to_string()).collect()
    }

    #[test]
    fn format_from_extension_is_case_insensitive() {
        assert_eq!(
            ImageFormat::from_path(Path::new("a/b.EXR")),
            Some(ImageFormat::OpenExr)
        );
        assert_eq!(
            ImageFormat::from_path(Path::new("x.Hdr")),
            Some(ImageFormat::RadianceHdr)
        );
        assert_eq!(ImageFormat::from_path(Path::new("x.png")), None);
        assert_eq!(ImageFormat::from_path(Path::new("exr")), None);
    }

    #[test]
    fn splits_layer_prefix() {
        assert_eq!(split_channel_name("R"), ("", "R"));
        assert_eq!(split_channel_name("left.R"), ("left.", "R"));
        assert_eq!(split_channel_name("a.b.G"), ("a.b.", "G"));
    }

    #[test]
    fn chooses_unprefixed_rgb_first() {
        let parts = vec![names(&["A", "B", "G", "R", "left.B", "left.G", "left.R"])];
        assert_eq!(
            choose_channels(&parts),
            Some(ChannelChoice {
                part: 0,
                channels: [3, 2, 1]
            })
        );
    }

    #[test]
    fn chooses_prefixed_rgb_and_later_parts() {
        let parts = vec![
            names(&["Z"]),
            names(&["Y"]),
            names(&["depth.Z", "left.B", "left.G", "left.R"]),
        ];
        // RGB anywhere wins over an earlier Y.
        assert_eq!(
            choose_channels(&parts),
            Some(ChannelChoice {
                part: 2,
                channels: [3, 2, 1]
            })
        );
    }

    #[test]
    fn falls_back_to_luminance() {
        let parts = vec![names(&["A", "R", "G"]), names(&["BY", "RY", "Y"])];
        assert_eq!(
            choose_channels(&parts),
            Some(ChannelChoice {
                part: 1,
                channels: [2, 2, 2]
            })
        );
        assert_eq!(choose_channels(&[names(&["Z", "A"])]), None);
        assert_eq!(choose_channels(&[]), None);
    }

    #[test]
    fn unsupported_extension_names_file_and_extensions() {
        let err = read_hdr_image(Path::new("/nonexistent/frame.png")).unwrap_err();
        let msg = err.to_string();
        assert!(matches!(err, CaptureError::Format { .. }), "{msg}");
        assert!(msg.contains("frame.png") && msg.contains(".exr") && msg.contains(".hdr"));
    }

    #[test]
    fn missing_file_is_io_error() {
        let err = read_hdr_image(Path::new("/nonexistent/frame.exr")).unwrap_err();
        assert!(matches!(err, CaptureError::Io { .. }), "{err}");
        assert!(err.to_string().contains("/nonexistent/frame.exr"));
    }

    #[test]
    fn garbage_is_format_error() {
        assert!(decode_exr(b"not an exr file at all").is_err());
        assert!(decode_hdr(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 2 +X 2\n\x01").is_err());
        assert!(decode_hdr(b"").is_err());
    }

    #[test]
    fn decodes_flat_rgbe() {
        // 1×2 image, flat (non-RLE) RGBE: (128,64,32,129) = (1.0, 0.5, 0.25); exposure 2.
        let mut file = b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\nEXPOSURE=2\n\n-Y 2 +X 1\n".to_vec();
        file.extend_from_slice(&[128, 64, 32, 129, 0, 0, 0, 0]);
        let image = decode_hdr(&file).unwrap();
        assert_eq!((image.width, image.height), (1, 2));
        assert_eq!(image.pixels[0], [0.5, 0.25, 0.125]);
        assert_eq!(image.pixels[1], [0.0, 0.0, 0.0]);
    }
}
