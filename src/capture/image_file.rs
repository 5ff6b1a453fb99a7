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
//!   luminance-only `Y` (returned as grey RGB; a luminance/chroma image's `RY` and `BY` are not
//!   read, with a warning naming the file). Names may carry a layer/view prefix
//!   (`left.R`, `diffuse.R`). In a multi-part or multi-layer file, of the channel groups with R,
//!   G and B (part by part; in a part the unprefixed channels first, then prefixes in the
//!   file's alphabetical channel order) the first that is unprefixed or a beauty pass
//!   (Blender's `ViewLayer.Combined`, `beauty`, `rgba`, `rgb`, `color`, `colour`) is used, else
//!   the first; which one is said once when there are several. Only if none has R, G and B,
//!   the first with `Y`. Otherwise a `Format` error lists the channels found.
//! - Colour: the channels are taken as Rec. 709 primaries; a file whose `chromaticities` say
//!   otherwise (ACES AP0) is read the same, with a warning (once).
//! - **Data window**: the image returned is the size of the chosen part's *data window*, not of
//!   its display window; an offset or smaller data window is not padded or cropped to the
//!   display window. (Environment maps have data window = display window; for the rest this is
//!   the simplest honest answer: every pixel returned is one the file stores.) A warning says
//!   so, once per process, when the windows differ.
//! - Only the chosen part is read and decompressed (`decode_exr_part`): the other parts' blocks are
//!   skipped, so a multi-part file (views, passes) costs what its one part does.
//! - Compressed blocks are decompressed on rayon's global pool and put in place as each one is
//!   done (`decode_exr_part`, `par_iter`: a panic in a decoder unwinds into the caller, where
//!   `catch_unwind` below turns it into an error); uncompressed and RLE ones on the calling
//!   thread (`parallel_pays`). Not the `exr` crate's own parallel reader: it builds a thread
//!   pool per file and spawns its jobs there, where a panic on corrupt data aborts the process.
//! - Each block's lines of the chosen channels go straight into the interleaved RGB pixels
//!   (half floats become f32 a line at a time, F16C where the CPU has it); the output is
//!   allocated zeroed and is the only image-sized buffer, so its pages are touched only as
//!   blocks fill them: a damaged file that declares a large image but holds few blocks costs
//!   little memory.
//!
//! Radiance `.hdr`: RLE or flat RGBE with the usual `-Y H +X W` orientation (the decoder rejects
//! others); comment lines in the header (including a repeated `#?RADIANCE` magic line) are
//! skipped. Values are divided by the header's cumulative `EXPOSURE` and per-channel
//! `COLORCORR` if there are any, so they are the radiance the file describes (in f64, clamped to
//! f32's range); a factor that is not positive and within f32's range, its reciprocal included,
//! is an error. A header whose lines end in CR LF is named as such.
//!
//! Robustness: the decoders should return errors on bad input, but they do not always (the
//! corruption test in `tests/capture.rs` hits an arithmetic-overflow panic in `exr`'s B44
//! decoder when overflow checks are on), so decoding runs inside [`std::panic::catch_unwind`]
//! and a panic becomes a `Format` error (the default panic hook still prints the panic message
//! to stderr). Files over [`MAX_FILE_BYTES`] are refused before they are read (a sparse file of
//! a terabyte made `std::fs::read` ask for a terabyte at once). Images of more than
//! [`MAX_PIXELS`] pixels are rejected from a header found in the file's first MiB before the
//! file is read when it is over 256 MiB (`oversized_by_header`), else before pixel data is
//! allocated, and so are files too short for what their headers declare (an EXR's offset
//! tables, an HDR's rows). What a decoder cannot catch is an allocation that fails, which
//! aborts: a DWA block's counters are checked against the block's size before it is
//! decompressed (`check_dwa_counters`), and every block's declared data size against the
//! bytes after it before the `exr` crate reads the blocks, which fills a buffer of that size
//! first (`check_block_sizes`). An EXR part is read only if its blocks store every
//! pixel (`check_every_pixel_stored`): the lenient block reader skips blocks it cannot place,
//! which would leave rows black.

use super::CaptureError;
use exr::block::reader::ChunksReader;
use exr::block::UncompressedBlock;
use exr::error::UnitResult;
use exr::meta::{header::Header, MetaData};
use half::slice::HalfFloatSliceExt;
use image::ImageDecoder;
use rayon::prelude::*;
use std::io::Cursor;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::{Path, PathBuf};

/// Largest image (in pixels, summed over all parts of an EXR file) that is decoded: 16384×8192.
pub const MAX_PIXELS: u64 = 16384 * 8192;

/// Largest file [`read_hdr_image`] reads: 4 GiB, eight uncompressed 32-bit channels of
/// [`MAX_PIXELS`] pixels. Larger files (and anything that is not a regular file: a pipe, a
/// device) are errors before they are read.
pub const MAX_FILE_BYTES: u64 = 32 * MAX_PIXELS;

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

/// How envlight writes EXR files (recorded frames, rendered frames, wavelet reconstructions):
/// the `exr` crate's fast lossless default (RLE in 64×64 tiles), with the tiles in increasing
/// order, so the same image gives the same bytes (in the crate's unspecified order its parallel
/// writer stored the tiles as they were done: files differed from run to run).
pub const WRITE_ENCODING: exr::prelude::Encoding = exr::prelude::Encoding {
    line_order: exr::prelude::LineOrder::Increasing,
    ..exr::prelude::Encoding::FAST_LOSSLESS
};

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
    let io_error = |source| CaptureError::Io {
        path: path.to_path_buf(),
        source,
    };
    // Only regular files of bounded size are frames: a pipe or a device would block the open
    // or never end.
    // A file too large to read cheaply is first judged by its header (smaller ones, every
    // ordinary frame, are read once, not opened twice).
    if std::fs::metadata(path).is_ok_and(|m| m.is_file() && m.len() > PEEK_FILES_OVER_BYTES) {
        if let Some(message) = oversized_by_header(path, format) {
            return Err(format_error(path, message));
        }
    }
    let bytes =
        crate::read_file::read_regular_file(path, MAX_FILE_BYTES, "an image").map_err(io_error)?;
    decode_hdr_image(&bytes, format, path)
}

/// Files larger than this are judged by their header before they are read (256 MiB: a
/// 16384 × 8192 half-float RGBA EXR, the largest image read, is about 1 GiB uncompressed).
const PEEK_FILES_OVER_BYTES: u64 = 256 << 20;

/// Bytes of a file's start in which [`oversized_by_header`] looks for its header.
const HEADER_PEEK_BYTES: u64 = 1 << 20;

/// The size check of an image's header, made on the file's first MiB before the whole file is
/// read: a 20000 × 10000 EXR (2.4 GB) was read whole, 2.3 GB resident, before its header
/// refused it (an audit). `None` when the header is within the limits or is not found there
/// (the whole file's decoding then says what is wrong).
fn oversized_by_header(path: &Path, format: ImageFormat) -> Option<String> {
    use std::io::Read;
    let mut head = Vec::new();
    std::fs::File::open(path)
        .ok()?
        .take(HEADER_PEEK_BYTES)
        .read_to_end(&mut head)
        .ok()?;
    let sizes: Vec<(u64, u64)> = catch_unwind(AssertUnwindSafe(|| match format {
        ImageFormat::OpenExr => exr::meta::MetaData::read_from_buffered(Cursor::new(&head), false)
            .ok()
            .map(|meta| {
                let sizes = meta.headers.iter().map(|h| h.layer_size);
                sizes
                    .map(|s| (s.width() as u64, s.height() as u64))
                    .collect()
            }),
        ImageFormat::RadianceHdr => image::codecs::hdr::HdrDecoder::new(Cursor::new(&head))
            .ok()
            .map(|d| {
                let (w, h) = d.dimensions();
                vec![(u64::from(w), u64::from(h))]
            }),
    }))
    .ok()
    .flatten()?;
    sizes
        .iter()
        .find_map(|&(w, h)| check_size(w, h).err().filter(|_| w > 0 && h > 0))
}

/// Decodes the contents of an `.exr` or `.hdr` file held in memory; `path` only names the data
/// in errors. Every failure is a [`CaptureError::Format`].
pub fn decode_hdr_image(
    bytes: &[u8],
    format: ImageFormat,
    path: &Path,
) -> Result<RgbImage, CaptureError> {
    let decoded = catch_unwind(AssertUnwindSafe(|| match format {
        ImageFormat::OpenExr => decode_exr(bytes, path),
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
    let decoder = image::codecs::hdr::HdrDecoder::new(Cursor::new(bytes)).map_err(|e| {
        // A header whose lines end in CR LF reads as one that never ends ("EOF in header").
        let head = &bytes[..bytes.len().min(4096)];
        if head.windows(2).any(|w| w == b"\r\n") {
            format!(
                "not a valid Radiance HDR file: its header's lines end in CR LF (Windows line \
                 ends; Radiance uses LF alone), as when a file is copied as text, which \
                 corrupts its pixels too ({e})"
            )
        } else {
            format!("not a valid Radiance HDR file: {e}")
        }
    })?;
    let (width, height) = decoder.dimensions();
    check_size(u64::from(width), u64::from(height))?;
    // Every scan line takes at least 4 bytes (one pixel) and, wider than one pixel, 8 (a
    // pixel and a run): a file too short for its declared rows fails here, before the decoder
    // allocates the whole image.
    let least_bytes = u64::from(height) * if width == 1 { 4 } else { 8 };
    if (bytes.len() as u64) < least_bytes {
        return Err(format!(
            "file is truncated: {} bytes cannot hold the {width}x{height} pixels its header \
             declares (at least {least_bytes})",
            bytes.len()
        ));
    }
    let scale = radiance_scale(&decoder.metadata().custom_attributes)?;
    if image::ImageDecoder::color_type(&decoder) != image::ColorType::Rgb32F {
        return Err("decoder returned pixels that are not RGB floats".to_string());
    }
    // Decoded straight into the frame's pixels: through an image of the decoder's and a copy
    // of it, a 16384 × 8192 file took twice its 1.6 GB (an audit).
    let mut pixels = vec![[0.0f32; 3]; width as usize * height as usize];
    image::ImageDecoder::read_image(decoder, bytemuck::cast_slice_mut(&mut pixels))
        .map_err(|e| format!("cannot decode Radiance HDR pixels: {e}"))?;
    for p in &mut pixels {
        // In f64 and clamped to f32's range: a bright pixel divided by a small EXPOSURE
        // overflowed f32 to infinity, which the frame's sanitising then set to 0 (a sun turned
        // black).
        for (v, s) in p.iter_mut().zip(scale) {
            *v = (f64::from(*v) * s).min(f64::from(f32::MAX)) as f32;
        }
    }
    Ok(RgbImage {
        width,
        height,
        pixels,
    })
}

/// What a Radiance file's values are multiplied by to be the radiance it describes, per
/// channel: 1 / (EXPOSURE × COLORCORR), each header line of them cumulative (Radiance's
/// definitions). From the lines as written, in f64: the decoder's f32 product turned
/// `EXPOSURE=1e-300` into 0 and reported it as such. A factor that is not positive, or whose
/// reciprocal or itself is beyond f32's range, is an error quoting the lines.
fn radiance_scale(header: &[(String, String)]) -> Result<[f64; 3], String> {
    let mut factor = [1.0f64; 3];
    let mut lines = Vec::new();
    for (key, value) in header {
        let numbers: Vec<f64> = match key.as_str() {
            "EXPOSURE" | "COLORCORR" => value
                .split_whitespace()
                .map(str::parse)
                .collect::<Result<_, _>>()
                .map_err(|_| format!("header line {key}={value} is not numbers"))?,
            _ => continue,
        };
        lines.push(format!("{key}={}", value.trim()));
        match (key.as_str(), numbers.as_slice()) {
            ("EXPOSURE", [e, ..]) => factor.iter_mut().for_each(|f| *f *= e),
            ("COLORCORR", [r, g, b, ..]) => {
                for (f, c) in factor.iter_mut().zip([r, g, b]) {
                    *f *= c;
                }
            }
            _ => return Err(format!("header line {key}={value} has too few numbers")),
        }
    }
    let limit = f64::from(f32::MAX);
    if factor
        .iter()
        .all(|&f| f > 0.0 && f <= limit && 1.0 / f <= limit)
    {
        Ok(factor.map(|f| 1.0 / f))
    } else {
        Err(format!(
            "header's {} make a factor of {:?} per channel: not positive numbers within f32's \
             range (reciprocals included)",
            lines.join(", "),
            factor
        ))
    }
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

/// Whether a layer prefix names a beauty pass: its last component (`ViewLayer.Combined.` →
/// `Combined`) is Blender's `Combined`, or `beauty`, `rgba`, `rgb`, `color` or `colour`, in any
/// case.
fn is_beauty_pass(prefix: &str) -> bool {
    let last = prefix
        .trim_end_matches('.')
        .rsplit('.')
        .next()
        .unwrap_or("");
    ["combined", "beauty", "rgba", "rgb", "color", "colour"]
        .iter()
        .any(|name| last.eq_ignore_ascii_case(name))
}

/// The channel groups of every part that have R, G and B, in priority order (per part, the
/// unprefixed group first, then the others in the order they first appear), each with its
/// prefix.
fn rgb_groups(parts: &[Vec<String>]) -> Vec<(ChannelChoice, &str)> {
    channel_groups(parts)
        .into_iter()
        .filter_map(|(part, prefix)| {
            let find = |base| find_channel(parts, part, prefix, base);
            let channels = [find("R")?, find("G")?, find("B")?];
            Some((ChannelChoice { part, channels }, prefix))
        })
        .collect()
}

/// Channel groups in priority order: per part, the unprefixed group first, then the others in
/// the order they first appear.
fn channel_groups(parts: &[Vec<String>]) -> Vec<(usize, &str)> {
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
    groups
}

/// The index of channel `prefix` + `base` in part `part`.
fn find_channel(parts: &[Vec<String>], part: usize, prefix: &str, base: &str) -> Option<usize> {
    parts[part]
        .iter()
        .position(|n| split_channel_name(n) == (prefix, base))
}

/// Picks the channels to use from the channel names of every part (see the module docs): of
/// the groups with R, G and B the first that is unprefixed or a beauty pass
/// ([`is_beauty_pass`]: Blender's `ViewLayer.Combined` sorts after `ViewLayer.AO`), else the
/// first; without any, the first group with Y.
fn choose_channels(parts: &[Vec<String>]) -> Option<ChannelChoice> {
    let rgb = rgb_groups(parts);
    let beauty = rgb
        .iter()
        .position(|(_, prefix)| prefix.is_empty() || is_beauty_pass(prefix))
        .unwrap_or(0);
    if let Some((choice, _)) = rgb.into_iter().nth(beauty) {
        return Some(choice);
    }
    channel_groups(parts)
        .into_iter()
        .find_map(|(part, prefix)| {
            let y = find_channel(parts, part, prefix, "Y")?;
            Some(ChannelChoice {
                part,
                channels: [y; 3],
            })
        })
}

/// A chroma channel (`RY` or `BY` beside a luminance `Y`) of `names` that a luminance-only read
/// of channel `luminance` leaves out, if there is one.
fn dropped_chroma(names: &[String], luminance: usize) -> Option<&str> {
    let (prefix, base) = split_channel_name(names.get(luminance)?);
    if base != "Y" {
        return None;
    }
    names
        .iter()
        .find(|n| {
            let (p, b) = split_channel_name(n);
            p == prefix && (b == "RY" || b == "BY")
        })
        .map(String::as_str)
}

fn decode_exr(bytes: &[u8], path: &Path) -> Result<RgbImage, String> {
    // The header first: reject deep data and absurd sizes before any pixel is allocated.
    // Read through a counter: the header ends (and the offset tables begin) where the
    // reader stopped, as the `exr` crate itself parsed it.
    let mut header_reader = CountingReader {
        bytes: Cursor::new(bytes),
        consumed: 0,
    };
    let meta = exr::meta::MetaData::read_from_buffered(&mut header_reader, false)
        .map_err(|e| format!("not a valid OpenEXR file: {e}"))?;
    let tables = header_reader.consumed;
    // Each block has an 8-byte entry in the offset tables, which are read (and allocated)
    // before any block: a file too short for its tables fails here.
    let blocks = meta
        .headers
        .iter()
        .fold(0u64, |sum, h| sum.saturating_add(h.chunk_count as u64));
    if blocks.saturating_mul(8) > bytes.len() as u64 {
        return Err(format!(
            "file is truncated: its headers declare {blocks} blocks, whose offset tables alone \
             take {} bytes, and the file has {}",
            blocks.saturating_mul(8),
            bytes.len()
        ));
    }
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
            "no part has all of R, G and B, or a Y channel (channels found: {})",
            found.join("; ")
        )
    })?;
    if meta.headers.iter().any(|h| h.deep) {
        return Err("deep OpenEXR data is not supported".to_string());
    }
    if let Some(chroma) = dropped_chroma(&parts[choice.part], choice.channels[0]) {
        tracing::warn!(
            "{}: read as grey from its luminance channel {}; its chroma channel {chroma} is \
             not read (luminance/chroma images are not supported)",
            path.display(),
            parts[choice.part][choice.channels[0]]
        );
    }

    let header = &meta.headers[choice.part];
    warn_of_a_cropped_data_window(header, path);
    warn_of_other_rgb_layers(&parts, &choice, path);
    warn_of_other_primaries(header, path);
    for &index in &choice.channels {
        let channel = &header.channels.list[index];
        if channel.sampling.x() != 1 || channel.sampling.y() != 1 {
            return Err(format!(
                "channel {} is subsampled ({}x{}), which is not supported",
                channel.name,
                channel.sampling.x(),
                channel.sampling.y()
            ));
        }
    }
    let grey = choice.channels[0] == choice.channels[1];
    // (channel index, RGB lane): luminance fills the red lane, copied to the others below.
    let lanes: Vec<(usize, usize)> = if grey {
        vec![(choice.channels[0], 0)]
    } else {
        choice
            .channels
            .iter()
            .enumerate()
            .map(|(lane, &index)| (index, lane))
            .collect()
    };
    let size = header.layer_size;
    check_block_sizes(bytes, tables, &meta, choice.part)
        .map_err(|e| format!("damaged OpenEXR file: {e}"))?;
    let parallel = parallel_pays(header);
    let mut pixels = decode_exr_part(bytes, choice.part, &lanes, parallel)
        .map_err(|e| format!("cannot decode OpenEXR pixels: {e}"))?;
    if grey {
        pixels.iter_mut().for_each(|p| *p = [p[0]; 3]);
    }
    Ok(RgbImage {
        width: u32::try_from(size.width()).map_err(|_| "image too wide".to_string())?,
        height: u32::try_from(size.height()).map_err(|_| "image too high".to_string())?,
        pixels,
    })
}

/// Which RGB layer was read, said once per process when the file has several (a sequence of
/// such frames would say it every frame): nothing else tells which pass became the lights.
fn warn_of_other_rgb_layers(parts: &[Vec<String>], choice: &ChannelChoice, path: &Path) {
    static WARNED: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);
    // Once said, a sequence's later frames do not list their groups again.
    if WARNED.load(std::sync::atomic::Ordering::Relaxed) {
        return;
    }
    let groups = rgb_groups(parts);
    if groups.len() < 2 || WARNED.swap(true, std::sync::atomic::Ordering::Relaxed) {
        return;
    }
    let name = |(group, prefix): &(ChannelChoice, &str)| {
        let layer = prefix.trim_end_matches('.');
        let layer = if layer.is_empty() { "R, G, B" } else { layer };
        format!("{layer} (part {})", group.part)
    };
    let chosen = groups.iter().find(|(g, _)| g == choice).map(name);
    let others: Vec<String> = groups
        .iter()
        .filter(|(g, _)| g != choice)
        .map(name)
        .collect();
    tracing::warn!(
        "{}: its colour is read from the layer {}; its other RGB layers are not read: {} \
         (said once)",
        path.display(),
        chosen.unwrap_or_default(),
        others.join(", ")
    );
}

/// Rec. 709 / sRGB primaries and D65 white, as (x, y) chromaticities: red, green, blue, white.
const REC709_CHROMATICITIES: [[f32; 2]; 4] =
    [[0.64, 0.33], [0.30, 0.60], [0.15, 0.06], [0.3127, 0.3290]];

/// Said once per process when a file's `chromaticities` are not Rec. 709's (within 0.002): its
/// channels are read as Rec. 709 all the same (luminance, the PDF and the lights' colours
/// assume those primaries), so an ACES AP0 file's colours and energies come out wrong.
fn warn_of_other_primaries(header: &exr::meta::header::Header, path: &Path) {
    static WARNED: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);
    let Some(c) = header.shared_attributes.chromaticities else {
        return;
    };
    let found = [c.red, c.green, c.blue, c.white].map(|v| [v.x(), v.y()]);
    let rec709 = found
        .iter()
        .zip(REC709_CHROMATICITIES)
        .all(|(f, r)| (f[0] - r[0]).abs() <= 2e-3 && (f[1] - r[1]).abs() <= 2e-3);
    if rec709 || WARNED.swap(true, std::sync::atomic::Ordering::Relaxed) {
        return;
    }
    let shown: Vec<String> = found
        .iter()
        .map(|[x, y]| format!("({x:.4}, {y:.4})"))
        .collect();
    tracing::warn!(
        "{}: its chromaticities (red, green, blue, white: {}) are not Rec. 709's; its channels \
         are read as Rec. 709 all the same, so the lights' colours and luminance are off \
         (convert the frames to Rec. 709 primaries; said once)",
        path.display(),
        shown.join(", ")
    );
}

/// The module doc's data-window rule, said once per process when it applies: a data window
/// other than the display window is read as the whole map, so its directions are not those
/// the display window would give (once: a sequence of such frames would say it every frame).
fn warn_of_a_cropped_data_window(header: &exr::meta::header::Header, path: &Path) {
    static WARNED: std::sync::atomic::AtomicBool = std::sync::atomic::AtomicBool::new(false);
    let window = header.shared_attributes.display_window;
    let (position, size) = (header.own_attributes.layer_position, header.layer_size);
    if window.position == position && window.size == size {
        return;
    }
    if !WARNED.swap(true, std::sync::atomic::Ordering::Relaxed) {
        tracing::warn!(
            "{}: its data window ({}x{} at {}, {}) is not its display window ({}x{} at {}, {}); \
             the data window is read as the whole map (said once)",
            path.display(),
            size.width(),
            size.height(),
            position.x(),
            position.y(),
            window.size.width(),
            window.size.height(),
            window.position.x(),
            window.position.y()
        );
    }
}

/// Decodes part `part` of an OpenEXR file (its largest resolution level) into RGB pixels:
/// each block's lines of the chosen channels (`lanes`: channel index in the part's list, RGB
/// lane) are converted straight into the output. Only that part's blocks are read and
/// decompressed; with `parallel` they are decompressed on rayon's global pool (`par_iter`, so
/// a panic in a decoder unwinds into the caller, where [`decode_hdr_image`] catches it; the
/// `exr` crate's own parallel reader spawns its jobs on a new pool per file, where a panic
/// aborts the process), each put in place (under a lock) as soon as it is done, so the
/// copying overlaps the other blocks' decompression.
///
/// The output is allocated zeroed and nothing else of the image's size is: its pages are
/// touched only as blocks fill them, so a damaged file that declares a large image but holds
/// few blocks costs memory for what it holds (with the `exr` crate's layer reader, which
/// fills every channel's samples first, a 418-byte file declaring 393 985 × 251 pixels
/// touched 0.6 GB before failing; found by fuzz/).
fn decode_exr_part(
    bytes: &[u8],
    part: usize,
    lanes: &[(usize, usize)],
    parallel: bool,
) -> exr::error::Result<Vec<[f32; 3]>> {
    let chunks = exr::block::read(Cursor::new(bytes), false)?;
    let chunks = chunks.filter_chunks(false, |_, tile, block| {
        block.layer == part && tile.is_largest_resolution_level()
    })?;
    let meta = chunks.meta_data().clone();
    let header = part_header(&meta.headers, part)?;
    let size = header.layer_size;
    let mut pixels = vec![[0.0f32; 3]; size.area()];
    let mut covered: Vec<(exr::math::Vec2<usize>, usize)> = Vec::new();
    let decompress = |chunk| {
        check_dwa_counters(&chunk, &meta)?;
        UncompressedBlock::decompress_chunk(chunk, &meta, false)
    };
    let place = |block: UncompressedBlock, pixels: &mut [[f32; 3]], covered: &mut Vec<_>| {
        covered.push((block.index.pixel_position, block.index.pixel_size.area()));
        write_block(&block, header, lanes, pixels)
    };
    if parallel {
        let compressed = chunks.collect::<exr::error::Result<Vec<_>>>()?;
        let output = std::sync::Mutex::new((&mut pixels, &mut covered));
        compressed.into_par_iter().try_for_each(|chunk| {
            let block = decompress(chunk)?;
            let mut guard = output
                .lock()
                .unwrap_or_else(|poisoned| poisoned.into_inner());
            let (pixels, covered) = &mut *guard;
            place(block, pixels, covered)
        })?;
    } else {
        for chunk in chunks {
            place(decompress(chunk?)?, &mut pixels, &mut covered)?;
        }
    }
    check_every_pixel_stored(covered, size.area())?;
    Ok(pixels)
}

/// Writes a decompressed block's lines of the chosen channels (`lanes`: channel index, RGB
/// lane) into `pixels`, the part's rows: half floats converted a line at a time (F16C where
/// the CPU has it; every half is exact in f32), floats copied, unsigned integers rounded to
/// the nearest f32 as the `exr` crate's `Sample::to_f32` does.
fn write_block(
    block: &UncompressedBlock,
    header: &Header,
    lanes: &[(usize, usize)],
    pixels: &mut [[f32; 3]],
) -> UnitResult {
    use exr::meta::attribute::SampleType;
    let width = header.layer_size.width();
    let mut halves: Vec<half::f16> = Vec::new();
    let mut floats: Vec<f32> = Vec::new();
    for line in block.lines(&header.channels) {
        let at = line.location;
        let Some(&(channel, lane)) = lanes.iter().find(|&&(c, _)| c == at.channel) else {
            continue;
        };
        let n = at.sample_count;
        let target = at
            .position
            .y()
            .checked_mul(width)
            .and_then(|row| row.checked_add(at.position.x()))
            .and_then(|start| pixels.get_mut(start..start.checked_add(n)?))
            .ok_or_else(|| {
                exr::error::Error::Invalid("a block's line lies outside the image".into())
            })?;
        floats.resize(n, 0.0);
        match header.channels.list[channel].sample_type {
            SampleType::F16 => {
                halves.resize(n, half::f16::ZERO);
                line.read_samples_into_slice(&mut halves)?;
                halves.convert_to_f32_slice(&mut floats);
            }
            SampleType::F32 => line.read_samples_into_slice(&mut floats)?,
            SampleType::U32 => {
                for (float, integer) in floats.iter_mut().zip(line.read_samples::<u32>()) {
                    *float = integer? as f32;
                }
            }
        }
        for (pixel, &value) in target.iter_mut().zip(&floats) {
            pixel[lane] = value;
        }
    }
    Ok(())
}

/// Fails unless the blocks read (`covered`: each block's first pixel and pixel count) store
/// every one of the part's `total` pixels. The `exr` crate's lenient reader skips a block its
/// offset table cannot place and keeps the last of two blocks at one place, leaving the
/// missing rows zero: a truncated or damaged file would otherwise read as a black band.
fn check_every_pixel_stored(
    mut covered: Vec<(exr::math::Vec2<usize>, usize)>,
    total: usize,
) -> UnitResult {
    covered.sort_unstable_by_key(|&(position, _)| (position.y(), position.x()));
    covered.dedup_by_key(|&mut (position, _)| position);
    let stored: usize = covered.iter().map(|&(_, pixels)| pixels).sum();
    if stored < total {
        return Err(exr::error::Error::Invalid(
            format!(
                "{} of the {total} pixels are in no block (a truncated file or a damaged \
                 offset table)",
                total - stored
            )
            .into(),
        ));
    }
    Ok(())
}

/// Checks the size that each block of part `part` declares against the bytes after it in the
/// file, before the `exr` crate reads the blocks: it sizes its buffer from that field (up to
/// the part's largest block) and fills it before it finds that the data ends early, so a
/// 660-byte damaged file whose one block declared 1.7 GB made `envlight decompose` touch
/// 1.7 GB (found by fuzz/). Blocks whose offsets lie outside the file are left to the reader
/// (and to [`check_every_pixel_stored`]). `tables`: where the offset tables begin.
///
/// A block of no data is an error too: every block of a part envlight reads holds samples
/// (its channels are not subsampled), and the `exr` crate decodes an empty DWAA/DWAB block as
/// zeros of the block's size, so a 456-byte damaged file whose one empty block stood for
/// 16,056,314 × 4 pixels became a black 770 MB image that took 1.2 GB and 12 s to decompose
/// (found by fuzz/).
fn check_block_sizes(
    bytes: &[u8],
    tables: usize,
    meta: &MetaData,
    part: usize,
) -> Result<(), String> {
    let multipart = meta.requirements.has_multiple_layers;
    let skipped: usize = meta.headers[..part].iter().map(|h| h.chunk_count).sum();
    let header = &meta.headers[part];
    // Before a block's size: its part number (multi-part files), then its row (scan lines)
    // or its tile and level coordinates (tiles).
    let tiled = matches!(header.blocks, exr::meta::BlockDescription::Tiles(_));
    let before_size = usize::from(multipart) * 4 + if tiled { 16 } else { 4 };
    let read_u64 = |at: usize| {
        bytes
            .get(at..at + 8)
            .map(|b| u64::from_le_bytes(b.try_into().unwrap_or_default()))
    };
    for block in 0..header.chunk_count {
        let entry = tables + (skipped + block) * 8;
        let Some(offset) = read_u64(entry).and_then(|o| usize::try_from(o).ok()) else {
            return Ok(()); // a short offset table: the block reader names it
        };
        let Some(size_at) = offset.checked_add(before_size) else {
            continue;
        };
        let Some(size) = size_at
            .checked_add(4)
            .and_then(|end| bytes.get(size_at..end))
        else {
            continue;
        };
        let size = i32::from_le_bytes(size.try_into().unwrap_or_default());
        let available = bytes.len() - (size_at + 4);
        if size == 0 {
            return Err(format!(
                "block {block} of part {part} declares 0 bytes of data for its pixels"
            ));
        }
        if size < 0 || size as usize > available {
            return Err(format!(
                "block {block} of part {part} declares {size} bytes of data, and the file has \
                 {available} after it"
            ));
        }
    }
    Ok(())
}

/// A reader of `bytes` that counts what was taken from it: where the `exr` crate's header
/// reader stopped is where the header ends (it takes one byte at a time past the attributes).
struct CountingReader<'a> {
    bytes: Cursor<&'a [u8]>,
    consumed: usize,
}

impl std::io::Read for CountingReader<'_> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let n = self.bytes.read(buf)?;
        self.consumed += n;
        Ok(n)
    }
}

/// Checks the eleven counters that open a DWAA or DWAB block against the block's own size
/// before it is decompressed: the `exr` crate allocates what they declare before inflating
/// anything, so a 506-byte damaged file asked for 1.7 TB and aborted the process (an allocation
/// failure cannot be caught). A genuine block's counts are bounded by its pixels: raw bytes
/// (the unknown and RLE sections) by its decoded size, DCT coefficients (AC and DC counts) by
/// its samples padded to whole 8×8 blocks. Other compressions size their buffers from the
/// block's decoded size already.
fn check_dwa_counters(chunk: &exr::block::chunk::Chunk, meta: &MetaData) -> UnitResult {
    use exr::block::chunk::CompressedBlock;
    use exr::compression::Compression;
    let invalid = |what: &str| exr::error::Error::Invalid(what.to_string().into());
    let header = part_header(&meta.headers, chunk.layer_index)?;
    if !matches!(
        header.compression,
        Compression::DWAA(_) | Compression::DWAB(_)
    ) {
        return Ok(());
    }
    let data = match &chunk.compressed_block {
        CompressedBlock::ScanLine(block) => &block.compressed_pixels_le,
        CompressedBlock::Tile(block) => &block.compressed_pixels_le,
        _ => return Ok(()),
    };
    let tile = header.get_block_data_indices(&chunk.compressed_block)?;
    let bounds = header.get_absolute_block_pixel_coordinates(tile)?;
    let decoded_bytes = bounds.size.area() * header.channels.bytes_per_pixel;
    if data.is_empty() || data.len() == decoded_bytes {
        return Ok(()); // stored raw: no counters
    }
    let counter = |index: usize| -> exr::error::Result<u64> {
        let bytes = data
            .get(index * 8..index * 8 + 8)
            .ok_or_else(|| invalid("truncated DWA block header"))?;
        Ok(u64::from_le_bytes(bytes.try_into().unwrap_or_default()))
    };
    let padded = bounds.size.x().div_ceil(8) * 8 * (bounds.size.y().div_ceil(8) * 8);
    let samples = (padded * header.channels.list.len()) as u64;
    let bytes = decoded_bytes as u64;
    // (counter index, what it counts, its bound): RLE tokens expand by at most 1/128, plus a
    // little room for the deflate and token framing.
    let slack = 4096;
    for (index, what, bound) in [
        (1, "unknown section size", bytes + slack),
        (6, "RLE section size", 2 * bytes + slack),
        (7, "RLE raw size", bytes + slack),
        (8, "AC coefficient count", samples),
        (9, "DC coefficient count", samples),
    ] {
        let value = counter(index)?;
        if value > bound {
            return Err(invalid(&format!(
                "DWA block declares a {what} of {value}, more than its {}x{} pixels can hold",
                bounds.size.x(),
                bounds.size.y()
            )));
        }
    }
    Ok(())
}

/// The header of part `part`, or an error if the file has fewer parts.
fn part_header(headers: &[Header], part: usize) -> exr::error::Result<&Header> {
    headers
        .get(part)
        .ok_or_else(|| exr::error::Error::Invalid("part index beyond the file's parts".into()))
}

/// Whether decompressing `header`'s blocks on several threads pays: for ZIP, PIZ, PXR24, B44
/// and DWA (a fifth to a half off the test maps on two cores, for 3–6% more CPU time), not for
/// uncompressed or run-length-encoded data, where decoding is little more than a copy (the
/// recorder's frames, RLE tiles of f32: 4–21% slower in parallel). docs/performance.md,
/// "Reading recorded frames".
fn parallel_pays(header: &Header) -> bool {
    use exr::compression::Compression;
    !matches!(
        header.compression,
        Compression::Uncompressed | Compression::RLE
    )
}

#[cfg(test)]
mod tests {
    use super::*;
    use exr::image::read::image::ReadLayers;
    use exr::image::read::layers::ReadChannels;

    fn names(list: &[&str]) -> Vec<String> {
        list.iter().map(|s| s.to_string()).collect()
    }

    #[test]
    fn dropped_chroma_is_found_beside_its_luminance() {
        let yc = names(&["BY", "RY", "Y"]);
        assert_eq!(dropped_chroma(&yc, 2), Some("BY"));
        assert_eq!(dropped_chroma(&names(&["A", "Y"]), 1), None);
        // Another layer's chroma is not this luminance's.
        assert_eq!(dropped_chroma(&names(&["left.RY", "Y"]), 1), None);
        assert_eq!(
            dropped_chroma(&names(&["left.RY", "left.Y"]), 1),
            Some("left.RY")
        );
    }

    /// The exr crate's own reading of a file (every part, sequential, sample by sample), as
    /// this module read files before it read only the chosen part: the chosen part's R, G, B
    /// (or Y) channels per pixel.
    fn reference_exr(bytes: &[u8]) -> (usize, usize, Vec<[f32; 3]>) {
        let meta = exr::meta::MetaData::read_from_buffered(Cursor::new(bytes), false).unwrap();
        let parts: Vec<Vec<String>> = meta
            .headers
            .iter()
            .map(|h| h.channels.list.iter().map(|c| c.name.to_string()).collect())
            .collect();
        let choice = choose_channels(&parts).unwrap();
        let image = exr::prelude::read()
            .no_deep_data()
            .largest_resolution_level()
            .all_channels()
            .all_layers()
            .all_attributes()
            .non_parallel()
            .from_buffered(Cursor::new(bytes))
            .unwrap();
        let layer = &image.layer_data[choice.part];
        let channel = |i: usize| -> Vec<f32> {
            let name = &parts[choice.part][choice.channels[i]];
            let c = layer
                .channel_data
                .list
                .iter()
                .find(|c| c.name.to_string() == *name);
            c.unwrap().sample_data.values_as_f32().collect()
        };
        let (r, g, b) = (channel(0), channel(1), channel(2));
        let pixels = (0..r.len()).map(|k| [r[k], g[k], b[k]]).collect();
        (layer.size.width(), layer.size.height(), pixels)
    }

    /// The counted header length is where the offset tables begin: in files written by
    /// OpenEXR the first block follows the tables at once, so the first entry points just past
    /// them (one part, tiled mip-maps, ten parts); and `check_block_sizes` passes them.
    #[test]
    fn offset_tables_are_found_where_the_counted_header_ends() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data");
        for name in [
            "AllHalfValues.exr",
            "KernerEnvLatLong.exr",
            "multipart.0001.exr",
        ] {
            let bytes = std::fs::read(dir.join(name)).unwrap();
            let mut reader = CountingReader {
                bytes: Cursor::new(&bytes),
                consumed: 0,
            };
            let meta = MetaData::read_from_buffered(&mut reader, false).unwrap();
            let tables = reader.consumed;
            let blocks: usize = meta.headers.iter().map(|h| h.chunk_count).sum();
            let first = u64::from_le_bytes(bytes[tables..tables + 8].try_into().unwrap());
            assert_eq!(first as usize, tables + 8 * blocks, "{name}");
            for part in 0..meta.headers.len() {
                check_block_sizes(&bytes, tables, &meta, part).unwrap();
            }
        }
    }

    /// Reading only the chosen part, converting half floats a slice at a time and
    /// decompressing on several threads where that pays gives what the exr crate's plain
    /// reading gives, bit for bit (NaN as NaN): every half bit pattern (PIZ scan lines), a
    /// tiled mip-mapped ZIP16 file (the parallel path), a multi-part file (part 0 of 10, ZIP1:
    /// the sequential path).
    #[test]
    fn fast_exr_reading_equals_the_crates_plain_reading() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data");
        for name in [
            "AllHalfValues.exr",
            "KernerEnvLatLong.exr",
            "StageEnvLatLong.exr",
            "multipart.0001.exr",
        ] {
            let bytes = std::fs::read(dir.join(name)).unwrap();
            let (width, height, expected) = reference_exr(&bytes);
            let image = decode_exr(&bytes, Path::new("t.exr")).unwrap();
            assert_eq!(
                (image.width as usize, image.height as usize),
                (width, height),
                "{name}"
            );
            assert_eq!(image.pixels.len(), expected.len(), "{name}");
            for (k, (a, b)) in image.pixels.iter().zip(&expected).enumerate() {
                for c in 0..3 {
                    let same = a[c].to_bits() == b[c].to_bits() || (a[c].is_nan() && b[c].is_nan());
                    assert!(
                        same,
                        "{name}: pixel {k} channel {c}: {} against {}",
                        a[c], b[c]
                    );
                }
            }
        }
    }

    #[test]
    fn parallel_decompression_for_compressed_blocks_only() {
        let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data");
        let header = |name: &str| {
            let bytes = std::fs::read(dir.join(name)).unwrap();
            exr::meta::MetaData::read_from_buffered(Cursor::new(bytes), false)
                .unwrap()
                .headers[0]
                .clone()
        };
        assert!(parallel_pays(&header("KernerEnvLatLong.exr"))); // ZIP16 tiles
        assert!(parallel_pays(&header("AllHalfValues.exr"))); // PIZ
        assert!(parallel_pays(&header("multipart.0001.exr"))); // ZIP1

        // The recorder's frames: RLE (which leaves f32 data at about its size).
        let dir = tempfile::tempdir().unwrap();
        let recorded = dir.path().join("frame.exr");
        exr::prelude::write_rgb_file(&recorded, 4, 2, |x, y| (x as f32, y as f32, 1.0)).unwrap();
        let bytes = std::fs::read(&recorded).unwrap();
        let meta = exr::meta::MetaData::read_from_buffered(Cursor::new(&bytes[..]), false).unwrap();
        assert!(!parallel_pays(&meta.headers[0]));
        let image = decode_exr(&bytes, Path::new("t.exr")).unwrap();
        assert_eq!(image.pixels[5], [1.0, 1.0, 1.0]);
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

    /// Blender's multilayer files sort `ViewLayer.AO` before `ViewLayer.Combined`: the beauty
    /// pass is read, not the first RGB layer (the AO pass was).
    #[test]
    fn chooses_a_beauty_pass_over_earlier_layers() {
        let parts = vec![names(&[
            "ViewLayer.AO.B",
            "ViewLayer.AO.G",
            "ViewLayer.AO.R",
            "ViewLayer.Combined.A",
            "ViewLayer.Combined.B",
            "ViewLayer.Combined.G",
            "ViewLayer.Combined.R",
        ])];
        assert_eq!(
            choose_channels(&parts),
            Some(ChannelChoice {
                part: 0,
                channels: [6, 5, 4]
            })
        );
        assert!(is_beauty_pass("beauty.") && is_beauty_pass("RGBA.") && !is_beauty_pass("AO."));
        // Without a beauty pass, the first RGB layer.
        let parts = vec![names(&[
            "diffuse.B",
            "diffuse.G",
            "diffuse.R",
            "spec.B",
            "spec.G",
            "spec.R",
        ])];
        assert_eq!(
            choose_channels(&parts),
            Some(ChannelChoice {
                part: 0,
                channels: [2, 1, 0]
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
        assert!(decode_exr(b"not an exr file at all", Path::new("t.exr")).is_err());
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

    /// An EXPOSURE that is infinite (or beyond f32: it reads as infinite) is an error, not a
    /// black frame; a tiny one makes a bright pixel huge, never infinite (which the frame's
    /// sanitising would set to 0: a sun turned black).
    #[test]
    fn radiance_exposure_extremes() {
        let file = |exposure: &str| {
            let mut file =
                format!("#?RADIANCE\nFORMAT=32-bit_rle_rgbe\nEXPOSURE={exposure}\n\n-Y 2 +X 1\n")
                    .into_bytes();
            // 1.0 and 2^100 (mantissa 128, exponent 128 + 101)
            file.extend_from_slice(&[128, 128, 128, 129, 128, 128, 128, 229]);
            file
        };
        for exposure in ["inf", "1e39", "0", "-1"] {
            let e = decode_hdr(&file(exposure)).unwrap_err();
            assert!(e.contains("EXPOSURE"), "{exposure}: {e}");
        }
        let image = decode_hdr(&file("1e-30")).unwrap();
        assert!(
            (image.pixels[0][0] / 1e30 - 1.0).abs() < 1e-6,
            "{:?}",
            image.pixels[0]
        );
        assert_eq!(image.pixels[1], [f32::MAX; 3]);
        // Quoted as written (the decoder's f32 product showed 1e-300 as 0).
        let e = decode_hdr(&file("1e-300")).unwrap_err();
        assert!(e.contains("EXPOSURE=1e-300"), "{e}");
    }

    /// COLORCORR divides each channel, cumulatively, with EXPOSURE (it was ignored).
    #[test]
    fn radiance_colour_correction_divides_each_channel() {
        let mut file = b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\nCOLORCORR=2 1 0.5\nEXPOSURE=2\n\
                         COLORCORR=1 4 1\n\n-Y 1 +X 1\n"
            .to_vec();
        file.extend_from_slice(&[128, 128, 128, 129]);
        let image = decode_hdr(&file).unwrap();
        assert_eq!(image.pixels[0], [0.25, 0.125, 1.0]);
        let mut bad =
            b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\nCOLORCORR=1 0 1\n\n-Y 1 +X 1\n".to_vec();
        bad.extend_from_slice(&[128, 128, 128, 129]);
        let e = decode_hdr(&bad).unwrap_err();
        assert!(e.contains("COLORCORR=1 0 1"), "{e}");
    }

    /// A header whose lines end in CR LF is named as such (it read as "EOF in header").
    #[test]
    fn radiance_header_with_crlf_is_named() {
        let mut file = b"#?RADIANCE\r\nFORMAT=32-bit_rle_rgbe\r\n\r\n-Y 1 +X 1\r\n".to_vec();
        file.extend_from_slice(&[128, 128, 128, 129]);
        let e = decode_hdr(&file).unwrap_err();
        assert!(e.contains("CR LF"), "{e}");
    }
}
