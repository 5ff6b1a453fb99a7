//! Integration tests of the capture module: reading the real files in tests/data, channel
//! layouts of generated EXRs, bad input, and `SequenceSource` ordering, looping and pacing.

mod test_data;

use envlight::capture::image_file::{decode_hdr_image, read_hdr_image, ImageFormat, RgbImage};
use envlight::capture::sequence::{SequenceOptions, SequenceSource, NOMINAL_FPS};
use envlight::capture::{CaptureError, FrameSource};
use envlight::envmap::Projection;
use envlight::frame::{luminance, HdrFrame};
use exr::prelude::{
    f16, AnyChannel, AnyChannels, Blocks, Compression, Encoding, FlatSamples, Image,
    ImageAttributes, IntegerBounds, Layer, LayerAttributes, LineOrder, SmallVec, Vec2,
    WritableImage,
};
use std::path::Path;
use std::time::Instant;
use test_data::{data, HDRIS};

/// Sanitises like a frame source does; returns the image as a frame and the count.
fn sanitized(image: RgbImage) -> (HdrFrame, usize) {
    let mut frame = HdrFrame::new(image.width, image.height, image.pixels, Projection::LatLong)
        .expect("consistent image");
    let bad = frame.sanitize();
    (frame, bad)
}

fn mean_luminance(frame: &HdrFrame) -> f64 {
    frame
        .pixels
        .iter()
        .map(|&p| f64::from(luminance(p)))
        .sum::<f64>()
        / frame.pixels.len() as f64
}

fn assert_sane(name: &str, image: RgbImage, width: u32, height: u32) {
    assert_eq!((image.width, image.height), (width, height), "{name}");
    assert_eq!(image.pixels.len(), (width * height) as usize, "{name}");
    let (frame, bad) = sanitized(image);
    assert_eq!(bad, 0, "{name}: unexpected bad pixels");
    assert!(frame.pixels.iter().flatten().all(|c| c.is_finite()));
    let mean = mean_luminance(&frame);
    assert!(
        mean > 0.0 && mean.is_finite(),
        "{name}: mean luminance {mean}"
    );
}

// ----------------------------------------------------------------------------------------------
// The real files

#[test]
fn every_radiance_file_reads() {
    for name in HDRIS {
        let image = read_hdr_image(&data(name)).unwrap_or_else(|e| panic!("{e}"));
        assert_sane(name, image, 1024, 512);
    }
}

#[test]
fn kerner_tiled_mipmapped_reads_largest_level() {
    let image = read_hdr_image(&data("KernerEnvLatLong.exr")).unwrap();
    assert_sane("Kerner", image, 1024, 512);
}

#[test]
fn stage_non_power_of_two_reads() {
    let image = read_hdr_image(&data("StageEnvLatLong.exr")).unwrap();
    assert_sane("Stage", image, 1000, 500);
}

/// multipart.0001.exr: 10 parts; the first with R,G,B is part 0 ("rgba_right"), whose data
/// window is 877×876 at (654, 245) inside a 2048×1556 display window. The image is the size of
/// the data window.
#[test]
fn multipart_uses_first_rgb_part_and_its_data_window() {
    let image = read_hdr_image(&data("multipart.0001.exr")).unwrap();
    assert_sane("multipart", image, 877, 876);
}

#[test]
fn all_half_values_are_sanitized() {
    let image = read_hdr_image(&data("AllHalfValues.exr")).unwrap();
    assert_eq!((image.width, image.height), (256, 256));
    // Every half bit pattern appears: NaN, ±Inf and negatives must be there before sanitising.
    assert!(image.pixels.iter().flatten().any(|c| c.is_nan()));
    assert!(image.pixels.iter().flatten().any(|c| c.is_infinite()));
    let (frame, bad) = sanitized(image);
    assert!(bad > 0);
    assert!(frame
        .pixels
        .iter()
        .flatten()
        .all(|c| c.is_finite() && *c >= 0.0));
}

#[test]
fn uppercase_extension_reads() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("SKY.HDR");
    std::fs::copy(data("noon_grass_1k.hdr"), &path).unwrap();
    let image = read_hdr_image(&path).unwrap();
    assert_eq!((image.width, image.height), (1024, 512));
}

// ----------------------------------------------------------------------------------------------
// Generated EXR layouts

fn channel(name: &str, samples: FlatSamples) -> AnyChannel<FlatSamples> {
    AnyChannel::new(name, samples)
}

fn write_exr(
    path: &Path,
    width: usize,
    height: usize,
    encoding: Encoding,
    layers: Vec<(Option<&str>, Vec<AnyChannel<FlatSamples>>)>,
) {
    let layers: Vec<Layer<AnyChannels<FlatSamples>>> = layers
        .into_iter()
        .map(|(name, channels)| {
            let attributes = match name {
                Some(n) => LayerAttributes::named(n),
                None => LayerAttributes::default(),
            };
            Layer::new(
                (width, height),
                attributes,
                encoding,
                AnyChannels::sort(SmallVec::from_vec(channels)),
            )
        })
        .collect();
    let image = Image::from_layers(
        ImageAttributes::new(IntegerBounds::from_dimensions((width, height))),
        layers,
    );
    image.write().to_file(path).unwrap();
}

fn ramp(n: usize, scale: f32) -> Vec<f32> {
    (0..n).map(|i| i as f32 * scale).collect()
}

fn half(v: &[f32]) -> FlatSamples {
    FlatSamples::F16(v.iter().map(|&x| f16::from_f32(x)).collect())
}

#[test]
fn rgb_f32_scanline_file_roundtrips() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("rgb.exr");
    exr::prelude::write_rgb_file(&path, 3, 2, |x, y| {
        (x as f32, y as f32, (x + 10 * y) as f32 * 0.5)
    })
    .unwrap();
    let image = read_hdr_image(&path).unwrap();
    assert_eq!((image.width, image.height), (3, 2));
    // Row-major, top row first.
    assert_eq!(image.pixels[0], [0.0, 0.0, 0.0]);
    assert_eq!(image.pixels[2], [2.0, 0.0, 1.0]);
    assert_eq!(image.pixels[4], [1.0, 1.0, 5.5]);
}

#[test]
fn rgba_half_tiled_file_ignores_alpha() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("rgba.exr");
    let (w, h) = (20, 10);
    let n = w * h;
    let encoding = Encoding {
        compression: Compression::ZIP16,
        blocks: Blocks::Tiles(Vec2(8, 8)),
        line_order: LineOrder::Increasing,
    };
    write_exr(
        &path,
        w,
        h,
        encoding,
        vec![(
            None,
            vec![
                channel("R", half(&ramp(n, 1.0))),
                channel("G", half(&ramp(n, 0.5))),
                channel("B", half(&ramp(n, 0.25))),
                channel("A", half(&vec![-7.0; n])),
            ],
        )],
    );
    let image = read_hdr_image(&path).unwrap();
    assert_eq!((image.width, image.height), (20, 10));
    assert_eq!(image.pixels[0], [0.0, 0.0, 0.0]);
    assert_eq!(image.pixels[21], [21.0, 10.5, 5.25]);
    assert_eq!(image.pixels[n - 1], [199.0, 99.5, 49.75]);
}

#[test]
fn luminance_only_file_reads_as_grey() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("y.exr");
    write_exr(
        &path,
        4,
        3,
        Encoding::SMALL_LOSSLESS,
        vec![(None, vec![channel("Y", FlatSamples::F32(ramp(12, 2.0)))])],
    );
    let image = read_hdr_image(&path).unwrap();
    assert_eq!((image.width, image.height), (4, 3));
    assert_eq!(image.pixels[5], [10.0, 10.0, 10.0]);
}

#[test]
fn u32_samples_convert_to_f32() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("u32.exr");
    let u = |v: u32| FlatSamples::U32(vec![v; 4]);
    write_exr(
        &path,
        2,
        2,
        Encoding::UNCOMPRESSED,
        vec![(
            None,
            vec![channel("R", u(1)), channel("G", u(2)), channel("B", u(3))],
        )],
    );
    let image = read_hdr_image(&path).unwrap();
    assert_eq!(image.pixels, vec![[1.0, 2.0, 3.0]; 4]);
}

#[test]
fn layer_prefixed_channels_and_later_parts() {
    let dir = tempfile::tempdir().unwrap();
    // One part, view-prefixed channels only.
    let path = dir.path().join("prefixed.exr");
    let f = |v: f32| FlatSamples::F32(vec![v; 4]);
    write_exr(
        &path,
        2,
        2,
        Encoding::SMALL_LOSSLESS,
        vec![(
            None,
            vec![
                channel("Z", f(9.0)),
                channel("left.R", f(1.0)),
                channel("left.G", f(2.0)),
                channel("left.B", f(3.0)),
            ],
        )],
    );
    assert_eq!(
        read_hdr_image(&path).unwrap().pixels,
        vec![[1.0, 2.0, 3.0]; 4]
    );

    // Two parts: depth first, then colour; a Y part before does not win over RGB.
    let path = dir.path().join("parts.exr");
    write_exr(
        &path,
        2,
        2,
        Encoding::SMALL_LOSSLESS,
        vec![
            (Some("depth"), vec![channel("Z", f(9.0))]),
            (Some("grey"), vec![channel("Y", f(5.0))]),
            (
                Some("beauty"),
                vec![
                    channel("beauty.R", f(4.0)),
                    channel("beauty.G", f(5.0)),
                    channel("beauty.B", f(6.0)),
                ],
            ),
        ],
    );
    assert_eq!(
        read_hdr_image(&path).unwrap().pixels,
        vec![[4.0, 5.0, 6.0]; 4]
    );
}

#[test]
fn missing_colour_channels_lists_channels_found() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("depth.exr");
    write_exr(
        &path,
        2,
        2,
        Encoding::SMALL_LOSSLESS,
        vec![(
            None,
            vec![
                channel("Z", FlatSamples::F32(vec![1.0; 4])),
                channel("R", FlatSamples::F32(vec![1.0; 4])),
            ],
        )],
    );
    let err = read_hdr_image(&path).unwrap_err();
    let msg = err.to_string();
    assert!(matches!(err, CaptureError::Format { .. }), "{msg}");
    // What is missing, said without contradicting the list (it said "no R,G,B or Y
    // channels" and listed R).
    assert!(
        msg.contains("depth.exr")
            && msg.contains("no part has all of R, G and B, or a Y channel")
            && msg.contains("[R, Z]"),
        "{msg}"
    );
}

// ----------------------------------------------------------------------------------------------
// Bad input

#[test]
fn truncated_files_are_format_errors_naming_the_file() {
    let dir = tempfile::tempdir().unwrap();
    for name in [
        "KernerEnvLatLong.exr",
        "AllHalfValues.exr",
        "multipart.0001.exr",
        "rooitou_park_1k.hdr",
    ] {
        let bytes = std::fs::read(data(name)).unwrap();
        for fraction in [0.5, 0.02] {
            let cut = (bytes.len() as f64 * fraction) as usize;
            let path = dir.path().join(format!("cut_{cut}_{name}"));
            std::fs::write(&path, &bytes[..cut]).unwrap();
            let err = read_hdr_image(&path).unwrap_err();
            assert!(
                matches!(err, CaptureError::Format { .. }),
                "{name} cut at {cut}: {err}"
            );
            assert!(
                err.to_string().contains(&format!("cut_{cut}_{name}")),
                "{err}"
            );
        }
    }
}

/// The byte position of a single-part file's offset table: the one place whose first entry
/// points just past a table of `chunks` entries.
fn offset_table_at(bytes: &[u8], chunks: usize) -> usize {
    let entry = |at: usize| u64::from_le_bytes(bytes[at..at + 8].try_into().unwrap());
    let found: Vec<usize> = (0..bytes.len() - 8 * chunks)
        .filter(|&at| entry(at) == (at + 8 * chunks) as u64)
        .collect();
    assert_eq!(found.len(), 1, "offset table of {chunks} chunks: {found:?}");
    found[0]
}

fn scanline_exr(w: usize, h: usize, compression: Compression) -> Vec<u8> {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("f.exr");
    let encoding = Encoding {
        compression,
        blocks: Blocks::ScanLines,
        line_order: LineOrder::Increasing,
    };
    let n = w * h;
    let smooth: Vec<f32> = (0..n)
        .map(|i| 1.0 + ((i % w) as f32 * 0.05).sin())
        .collect();
    write_exr(
        &path,
        w,
        h,
        encoding,
        vec![(
            None,
            vec![
                channel("R", half(&smooth)),
                channel("G", half(&smooth)),
                channel("B", half(&smooth)),
            ],
        )],
    );
    std::fs::read(path).unwrap()
}

/// A DWA block opens with counters the decoder allocates by: one that declares far more
/// coefficients than the block has pixels is an error, not a terabyte allocation that aborts
/// the process (a 506-byte damaged file once asked for 1.7 TB).
#[test]
fn dwa_block_counters_beyond_the_block_are_errors() {
    let (w, h) = (64, 32);
    for compression in [Compression::DWAA(None), Compression::DWAB(None)] {
        let bytes = scanline_exr(w, h, compression);
        let name = Path::new("dwa.exr");
        assert!(decode_hdr_image(&bytes, ImageFormat::OpenExr, name).is_ok());
        let chunks = h.div_ceil(compression.scan_lines_per_block());
        let table = offset_table_at(&bytes, chunks);
        let chunk = u64::from_le_bytes(bytes[table..table + 8].try_into().unwrap()) as usize;
        // The chunk: y (i32), data size (i32), then the data; its counters are u64s, the DC
        // count the tenth, the AC count the ninth.
        let size = i32::from_le_bytes(bytes[chunk + 4..chunk + 8].try_into().unwrap());
        assert!((size as usize) < w * h * 6, "{compression:?} stored raw");
        for (counter, what) in [(9, "DC coefficient count"), (8, "AC coefficient count")] {
            let mut damaged = bytes.clone();
            let at = chunk + 8 + 8 * counter;
            damaged[at..at + 8].copy_from_slice(&(1u64 << 40).to_le_bytes());
            let err = decode_hdr_image(&damaged, ImageFormat::OpenExr, name).unwrap_err();
            assert!(
                err.to_string().contains(what) && err.to_string().contains("dwa.exr"),
                "{compression:?}: {err}"
            );
        }
    }
}

/// A block that names the wrong rows (here the last block claims row 0, which already has
/// one) leaves rows no block stores: an error, not a black band.
#[test]
fn rows_no_block_stores_are_errors() {
    let (w, h) = (16, 8);
    let bytes = scanline_exr(w, h, Compression::Uncompressed);
    let table = offset_table_at(&bytes, h);
    let last = u64::from_le_bytes(
        bytes[table + 8 * (h - 1)..table + 8 * h]
            .try_into()
            .unwrap(),
    );
    let mut damaged = bytes.clone();
    let at = last as usize;
    assert_eq!(
        i32::from_le_bytes(damaged[at..at + 4].try_into().unwrap()),
        h as i32 - 1
    );
    damaged[at..at + 4].copy_from_slice(&0i32.to_le_bytes());
    let err = decode_hdr_image(&damaged, ImageFormat::OpenExr, Path::new("rows.exr")).unwrap_err();
    let text = err.to_string();
    assert!(
        text.contains("16 of the 128 pixels are in no block"),
        "{text}"
    );
    assert!(text.contains("rows.exr"), "{text}");
}

/// A file too short for the offset tables its header declares fails before the tables are
/// read (a 405-byte file declaring 1x1 tiles over 16384x8192 made 800 MB of tables).
#[test]
fn offset_tables_longer_than_the_file_are_errors() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("tiles.exr");
    let (w, h) = (64, 64);
    let encoding = Encoding {
        compression: Compression::Uncompressed,
        blocks: Blocks::Tiles(Vec2(1, 1)),
        line_order: LineOrder::Increasing,
    };
    let grey = FlatSamples::F32(vec![0.5; w * h]);
    write_exr(
        &path,
        w,
        h,
        encoding,
        vec![(None, vec![channel("Y", grey)])],
    );
    let bytes = std::fs::read(&path).unwrap();
    let table = offset_table_at(&bytes, w * h);
    let cut = &bytes[..table + 100];
    let err = decode_hdr_image(cut, ImageFormat::OpenExr, Path::new("tiles.exr")).unwrap_err();
    let text = err.to_string();
    assert!(
        text.contains("declare 4096 blocks") && text.contains("offset tables"),
        "{text}"
    );
}

/// Radiance headers: rows the file is too short to hold fail before the image is allocated;
/// an EXPOSURE that is not a positive number is an error, not silently 1.
#[test]
fn radiance_headers_that_cannot_be_right_are_errors() {
    let name = Path::new("bad.hdr");
    let header = b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 8192 +X 16384\n".to_vec();
    let err = decode_hdr_image(&header, ImageFormat::RadianceHdr, name).unwrap_err();
    assert!(err.to_string().contains("file is truncated"), "{err}");
    for exposure in ["0", "-2", "nan"] {
        let mut file =
            format!("#?RADIANCE\nFORMAT=32-bit_rle_rgbe\nEXPOSURE={exposure}\n\n-Y 2 +X 1\n")
                .into_bytes();
        file.extend_from_slice(&[128, 64, 32, 129, 128, 64, 32, 129]);
        let err = decode_hdr_image(&file, ImageFormat::RadianceHdr, name).unwrap_err();
        assert!(err.to_string().contains("EXPOSURE"), "{exposure}: {err}");
    }
}

#[test]
fn garbage_bytes_are_errors() {
    let dir = tempfile::tempdir().unwrap();
    // Deterministic pseudo-random bytes (xorshift).
    let mut state = 0x9E37_79B9_7F4A_7C15_u64;
    let garbage: Vec<u8> = (0..4096)
        .map(|_| {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state as u8
        })
        .collect();
    for name in ["noise.exr", "noise.hdr", "empty.exr", "empty.hdr"] {
        let path = dir.path().join(name);
        let bytes: &[u8] = if name.starts_with("empty") {
            &[]
        } else {
            &garbage
        };
        std::fs::write(&path, bytes).unwrap();
        let err = read_hdr_image(&path).unwrap_err();
        assert!(matches!(err, CaptureError::Format { .. }), "{name}: {err}");
        assert!(err.to_string().contains(name));
    }
    // A valid EXR magic number followed by garbage.
    let path = dir.path().join("magic.exr");
    let mut bytes = vec![0x76, 0x2f, 0x31, 0x01, 2, 0, 0, 0];
    bytes.extend_from_slice(&garbage);
    std::fs::write(&path, &bytes).unwrap();
    assert!(read_hdr_image(&path).is_err());
    // A valid Radiance header followed by garbage.
    let path = dir.path().join("magic.hdr");
    let mut bytes = b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 64 +X 64\n".to_vec();
    bytes.extend_from_slice(&garbage);
    std::fs::write(&path, &bytes).unwrap();
    assert!(read_hdr_image(&path).is_err());
}

#[test]
fn missing_file_is_io_error_naming_it() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("nope_0001.exr");
    let err = read_hdr_image(&path).unwrap_err();
    assert!(matches!(err, CaptureError::Io { .. }), "{err}");
    assert!(err.to_string().contains("nope_0001.exr"));
}

#[test]
fn unsupported_extension_is_format_error() {
    let err = read_hdr_image(&data("LICENSES.txt")).unwrap_err();
    assert!(matches!(err, CaptureError::Format { .. }), "{err}");
    assert!(err.to_string().contains(".exr"));
}

// ----------------------------------------------------------------------------------------------
// Sequences

/// Writes a w×h RGB frame whose every pixel is `value`.
fn write_frame(path: &Path, w: usize, h: usize, value: f32) {
    exr::prelude::write_rgb_file(path, w, h, |_, _| (value, value, value)).unwrap();
}

fn s(p: &Path) -> String {
    p.to_string_lossy().into_owned()
}

fn file_names(source: &SequenceSource) -> Vec<String> {
    source
        .paths()
        .iter()
        .map(|p| p.file_name().unwrap().to_string_lossy().into_owned())
        .collect()
}

#[test]
fn directory_is_ordered_by_the_numbers_in_names() {
    let dir = tempfile::tempdir().unwrap();
    for (name, v) in [
        ("frame_10.exr", 10.0),
        ("frame_2.exr", 2.0),
        ("frame_1.exr", 1.0),
        ("take2_frame_3.EXR", 3.0),
    ] {
        write_frame(&dir.path().join(name), 4, 2, v);
    }
    std::fs::write(dir.path().join("notes_5.txt"), "not a frame").unwrap();
    std::fs::create_dir(dir.path().join("sub_4.exr")).unwrap(); // a directory, skipped

    let mut source = SequenceSource::new(&[s(dir.path())], SequenceOptions::default()).unwrap();
    assert_eq!(source.frame_count(), 4);
    assert_eq!(
        file_names(&source),
        [
            "frame_1.exr",
            "frame_2.exr",
            "take2_frame_3.EXR",
            "frame_10.exr"
        ]
    );
    let mut values = Vec::new();
    while let Some(frame) = source.next_frame().unwrap() {
        assert_eq!(frame.seq, values.len() as u64);
        assert!((frame.time - frame.seq as f64 / NOMINAL_FPS).abs() < 1e-12);
        values.push(frame.pixels[0][0]);
    }
    assert_eq!(values, [1.0, 2.0, 3.0, 10.0]);
    assert!(source.next_frame().unwrap().is_none());
}

#[test]
fn glob_files_and_duplicates() {
    let dir = tempfile::tempdir().unwrap();
    for i in [3, 1, 2] {
        write_frame(&dir.path().join(format!("a_{i}.exr")), 2, 2, i as f32);
    }
    std::fs::copy(data("noon_grass_1k.hdr"), dir.path().join("b_9.hdr")).unwrap();
    let pattern = s(&dir.path().join("a_*.exr"));
    let inputs = [
        pattern.clone(),
        s(&dir.path().join("a_2.exr")),   // duplicate of a glob match
        s(&dir.path().join("./a_1.exr")), // the same file spelled differently
        pattern,
    ];
    let source = SequenceSource::new(&inputs, SequenceOptions::default()).unwrap();
    assert_eq!(file_names(&source), ["a_1.exr", "a_2.exr", "a_3.exr"]);

    let hdr_glob = s(&dir.path().join("*.hdr"));
    let source = SequenceSource::new(&[hdr_glob], SequenceOptions::default()).unwrap();
    assert_eq!(file_names(&source), ["b_9.hdr"]);
}

/// A frame file in a directory that cannot be read as a file (a broken link) is an error
/// naming it, not a frame silently left out; two names of one file are one frame.
#[test]
fn broken_links_are_errors_and_links_to_a_frame_are_one_frame() {
    let dir = tempfile::tempdir().unwrap();
    write_frame(&dir.path().join("f_1.exr"), 2, 2, 1.0);
    // The first name in the sequence's order is kept, whatever the directory's order.
    for i in [2, 4, 10, 11, 12] {
        std::os::unix::fs::symlink("f_1.exr", dir.path().join(format!("f_{i}.exr"))).unwrap();
    }
    let inputs = [s(dir.path())];
    let source = SequenceSource::new(&inputs, SequenceOptions::default()).unwrap();
    assert_eq!(file_names(&source), ["f_1.exr"]);
    std::fs::rename(dir.path().join("f_1.exr"), dir.path().join("f_20.exr")).unwrap();
    for i in [2, 4, 10, 11, 12] {
        let link = dir.path().join(format!("f_{i}.exr"));
        std::fs::remove_file(&link).unwrap();
        std::os::unix::fs::symlink("f_20.exr", link).unwrap();
    }
    let source = SequenceSource::new(&inputs, SequenceOptions::default()).unwrap();
    assert_eq!(file_names(&source), ["f_2.exr"]);
    std::os::unix::fs::symlink("/nonexistent/f.exr", dir.path().join("f_3.exr")).unwrap();
    let err = SequenceSource::new(&inputs, SequenceOptions::default())
        .err()
        .unwrap();
    assert!(err.to_string().contains("f_3.exr"), "{err}");
}

/// A frame path that is a pipe is refused before it is opened (opening it blocked forever).
#[test]
fn a_pipe_is_no_frame_file() {
    let dir = tempfile::tempdir().unwrap();
    let fifo = dir.path().join("frame.exr");
    let made = std::process::Command::new("mkfifo")
        .arg(&fifo)
        .status()
        .unwrap();
    assert!(made.success());
    let err = read_hdr_image(&fifo).unwrap_err();
    assert!(err.to_string().contains("not a regular file"), "{err}");
}

/// A frame file larger than any frame envlight reads (here a sparse terabyte) is refused from
/// its size: reading it asked for a terabyte at once, and a failed allocation aborts.
#[test]
fn a_frame_file_of_a_terabyte_is_refused_unread() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("huge.exr");
    std::fs::File::create(&path)
        .unwrap()
        .set_len(1 << 40)
        .unwrap();
    let err = read_hdr_image(&path).unwrap_err().to_string();
    assert!(
        err.contains("huge.exr") && err.contains("1099511627776 bytes, more than the"),
        "{err}"
    );
}

/// An image whose header declares more than the pixels envlight reads is refused from its
/// header, before the file is read (a 20000 × 10000 EXR was read whole, 2.3 GB resident, before
/// its header refused it; an audit). Here the header of a 20000 × 10000 Radiance file at the
/// start of a sparse terabyte: its size is what the error names, not the file's.
#[test]
fn an_oversized_image_is_refused_from_its_header() {
    use std::io::Write;
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("big.hdr");
    let mut file = std::fs::File::create(&path).unwrap();
    file.write_all(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 10000 +X 20000\n")
        .unwrap();
    file.set_len(1 << 40).unwrap();
    let err = read_hdr_image(&path).unwrap_err().to_string();
    assert!(
        err.contains("big.hdr") && err.contains("image is too large (20000x10000"),
        "{err}"
    );
}

#[test]
fn no_frames_names_inputs() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("readme.txt"), "x").unwrap();
    let err = SequenceSource::new(&[s(dir.path())], SequenceOptions::default()).unwrap_err();
    assert!(matches!(err, CaptureError::NoFrames(_)), "{err}");
    assert!(err.to_string().contains(&s(dir.path())));

    let pattern = s(&dir.path().join("*.exr"));
    let err = SequenceSource::new(std::slice::from_ref(&pattern), SequenceOptions::default())
        .unwrap_err();
    assert!(matches!(err, CaptureError::NoFrames(_)), "{err}");
    assert!(err.to_string().contains(&pattern));
}

#[test]
fn missing_plain_path_names_it() {
    let dir = tempfile::tempdir().unwrap();
    let missing = s(&dir.path().join("gone_7.exr"));
    let err = SequenceSource::new(std::slice::from_ref(&missing), SequenceOptions::default())
        .unwrap_err();
    assert!(matches!(err, CaptureError::Io { .. }), "{err}");
    assert!(err.to_string().contains("gone_7.exr"));
}

#[test]
fn size_mismatch_names_the_file_and_is_skipped() {
    let dir = tempfile::tempdir().unwrap();
    write_frame(&dir.path().join("f_1.exr"), 4, 2, 1.0);
    write_frame(&dir.path().join("f_2.exr"), 3, 2, 2.0);
    write_frame(&dir.path().join("f_3.exr"), 4, 2, 3.0);
    let mut source = SequenceSource::new(&[s(dir.path())], SequenceOptions::default()).unwrap();
    assert_eq!(source.next_frame().unwrap().unwrap().seq, 0);
    let err = source.next_frame().unwrap_err();
    match &err {
        CaptureError::SizeMismatch {
            path,
            width,
            height,
            first_width,
            first_height,
        } => {
            assert!(path.ends_with("f_2.exr"));
            assert_eq!((*width, *height, *first_width, *first_height), (3, 2, 4, 2));
        }
        other => panic!("expected SizeMismatch, got {other}"),
    }
    assert!(err.to_string().contains("f_2.exr"));
    let next = source.next_frame().unwrap().unwrap();
    assert_eq!((next.seq, next.pixels[0][0]), (1, 3.0));
}

#[test]
fn corrupt_frame_in_sequence_is_format_error() {
    let dir = tempfile::tempdir().unwrap();
    write_frame(&dir.path().join("f_1.exr"), 4, 2, 1.0);
    let bytes = std::fs::read(data("KernerEnvLatLong.exr")).unwrap();
    std::fs::write(dir.path().join("f_2.exr"), &bytes[..bytes.len() / 2]).unwrap();
    let mut source = SequenceSource::new(&[s(dir.path())], SequenceOptions::default()).unwrap();
    source.next_frame().unwrap().unwrap();
    let err = source.next_frame().unwrap_err();
    assert!(matches!(err, CaptureError::Format { .. }), "{err}");
    assert!(err.to_string().contains("f_2.exr"));
    assert!(source.next_frame().unwrap().is_none());
}

#[test]
fn sequence_sanitizes_pixels() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::copy(data("AllHalfValues.exr"), dir.path().join("all_1.exr")).unwrap();
    let mut source = SequenceSource::new(&[s(dir.path())], SequenceOptions::default()).unwrap();
    let frame = source.next_frame().unwrap().unwrap();
    assert!(frame
        .pixels
        .iter()
        .flatten()
        .all(|c| c.is_finite() && *c >= 0.0));
}

#[test]
fn looped_source_wraps_and_seq_keeps_increasing() {
    let dir = tempfile::tempdir().unwrap();
    for i in 1..=3 {
        write_frame(&dir.path().join(format!("f_{i}.exr")), 2, 2, i as f32);
    }
    let options = SequenceOptions {
        looped: true,
        projection: Projection::AngularMap,
        ..Default::default()
    };
    let mut source = SequenceSource::new(&[s(dir.path())], options).unwrap();
    assert!(source.describe().contains("looped"));
    for expected_seq in 0..10u64 {
        let frame = source.next_frame().unwrap().expect("looped never ends");
        assert_eq!(frame.seq, expected_seq);
        assert_eq!(frame.pixels[0][0], (expected_seq % 3 + 1) as f32);
        assert_eq!(frame.projection, Projection::AngularMap);
    }
}

#[test]
fn paced_mode_takes_at_least_the_nominal_time() {
    let dir = tempfile::tempdir().unwrap();
    for i in 0..6 {
        write_frame(&dir.path().join(format!("f_{i}.exr")), 2, 2, 1.0);
    }
    let fps = 200.0;
    let options = SequenceOptions {
        fps: Some(fps),
        ..Default::default()
    };
    let mut source = SequenceSource::new(&[s(dir.path())], options).unwrap();
    let start = Instant::now();
    let mut n = 0;
    while let Some(frame) = source.next_frame().unwrap() {
        assert!((frame.time - frame.seq as f64 / fps).abs() < 1e-12);
        n += 1;
    }
    let elapsed = start.elapsed().as_secs_f64();
    assert_eq!(n, 6);
    let nominal = (n - 1) as f64 / fps;
    assert!(elapsed >= nominal * 0.9, "{elapsed} s < {nominal} s");
}

/// Damaged EXR files of a few hundred bytes that declare about 10⁸ pixels or a block of
/// 0.5–1.7 GB (found by fuzz/): `envlight decompose` fails on each naming the problem, and its
/// peak resident memory stays small, because nothing of the declared size is filled before
/// blocks arrive, no block's declared size is trusted past the file's end and an empty block
/// is not read as zeros. Before, the peaks were 0.59, 0.80, 0.49, 1.7, 1.6 and 1.2 GB; now
/// about 9 MB.
#[test]
fn small_damaged_exr_files_declaring_huge_images_cost_little_memory() {
    for name in [
        "damaged/b44_declares_99_megapixels.exr",
        "damaged/piz_inverted_data_window.exr",
        "damaged/piz_inverted_data_window_2.exr",
        "damaged/pxr24_one_block_of_65_megapixels.exr",
        "damaged/pxr24_header_with_an_untyped_attribute.exr",
        "damaged/dwab_empty_block_of_64_megapixels.exr",
    ] {
        let path = data(name);
        // Reaped below with wait4 rather than Child::wait, for its resource usage.
        #[allow(clippy::zombie_processes)]
        let child = std::process::Command::new(env!("CARGO_BIN_EXE_envlight"))
            .args(["decompose", "--lights", "16"])
            .arg(&path)
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap();
        let pid = libc::pid_t::try_from(child.id()).unwrap();
        let stderr = std::io::read_to_string(child.stderr.unwrap()).unwrap();
        // Reaped with wait4 for the child's own peak resident set (kilobytes on Linux).
        let mut status = 0;
        // SAFETY: an all-zero rusage is valid; wait4 fills it for our own child.
        let mut usage: libc::rusage = unsafe { std::mem::zeroed() };
        // SAFETY: valid pointers to locals; the child is ours and not yet reaped.
        let reaped = unsafe { libc::wait4(pid, &mut status, 0, &mut usage) };
        assert_eq!(reaped, pid, "{name}");
        assert!(
            libc::WIFEXITED(status) && libc::WEXITSTATUS(status) != 0,
            "{name}: {stderr}"
        );
        assert!(
            stderr.contains("OpenEXR") && stderr.contains(name),
            "{name}: {stderr}"
        );
        let peak_mb = usage.ru_maxrss as f64 / 1024.0;
        assert!(
            peak_mb < 150.0,
            "{name}: peak resident memory {peak_mb:.0} MB"
        );
    }
}

/// Truncation at every length and single-byte corruption of small files of every encoding:
/// reading must return (Ok or Err), never panic or abort.
#[test]
fn corrupted_small_files_never_panic() {
    let dir = tempfile::tempdir().unwrap();
    let (w, h) = (24, 20);
    let n = w * h;
    let mut originals = Vec::new();
    for (i, compression) in [
        Compression::Uncompressed,
        Compression::RLE,
        Compression::ZIP1,
        Compression::ZIP16,
        Compression::PIZ,
        Compression::PXR24,
        Compression::B44,
    ]
    .into_iter()
    .enumerate()
    {
        for (j, blocks) in [Blocks::ScanLines, Blocks::Tiles(Vec2(8, 8))]
            .into_iter()
            .enumerate()
        {
            let path = dir.path().join(format!("orig_{i}_{j}.exr"));
            let encoding = Encoding {
                compression,
                blocks,
                line_order: LineOrder::Increasing,
            };
            write_exr(
                &path,
                w,
                h,
                encoding,
                vec![(
                    None,
                    vec![
                        channel("R", half(&ramp(n, 0.1))),
                        channel("G", FlatSamples::F32(ramp(n, 0.2))),
                        channel("B", half(&ramp(n, 0.3))),
                    ],
                )],
            );
            originals.push((path, "exr"));
        }
    }
    let hdr = dir.path().join("orig.hdr");
    let pixels: Vec<image::Rgb<f32>> = (0..n)
        .map(|i| image::Rgb([i as f32, 1.0, 0.5 * i as f32]))
        .collect();
    let file = std::fs::File::create(&hdr).unwrap();
    image::codecs::hdr::HdrEncoder::new(std::io::BufWriter::new(file))
        .encode(&pixels, w, h)
        .unwrap();
    originals.push((hdr, "hdr"));

    let mut decoder_panics = 0;
    for (path, ext) in &originals {
        let bytes = std::fs::read(path).unwrap();
        assert!(read_hdr_image(path).is_ok(), "{}", path.display());
        let format = ImageFormat::from_path(path).unwrap();
        let name = Path::new(if *ext == "exr" { "bad.exr" } else { "bad.hdr" });
        let mut check = |content: &[u8]| match decode_hdr_image(content, format, name) {
            Ok(image) => assert_eq!(image.pixels.len(), (image.width * image.height) as usize),
            Err(e) => {
                assert!(matches!(e, CaptureError::Format { .. }), "{e}");
                decoder_panics += usize::from(e.to_string().contains("panicked"));
            }
        };
        for len in 0..bytes.len() {
            check(&bytes[..len]);
        }
        let mut state = 0x2545_F491_4F6C_DD1D_u64 ^ bytes.len() as u64;
        for _ in 0..500 {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            let mut corrupt = bytes.clone();
            let at = (state % bytes.len() as u64) as usize;
            corrupt[at] ^= (state >> 32) as u8 | 1;
            check(&corrupt);
        }
    }
    // Informational: panics inside the decoders were turned into Format errors.
    eprintln!("decoder panics caught: {decoder_panics}");
}
