//! Benchmarks of the camera conversions (on one thread unless the name says `pool2`), per
//! 1280×960 frame, and of reading recorded frame files:
//!
//! - `decode/{y16,yuyv,mjpeg}`: raw buffer → normalised code values
//!   ([`pixel_format::decode_into`], output image reused as in the capture loop);
//! - `radiance/{y16,yuyv,mjpeg}`: the same plus linearisation to radiance ([`Linearizer`]:
//!   linear response for Y16, sRGB for YUYV and MJPEG), i.e. the whole conversion cost of a
//!   frame;
//! - `radiance_pool2/…`: the same in bands of rows on two threads, the bench's and one helper
//!   (src/parallel.rs), as the camera source converts with `camera.convert_threads = 2` (the
//!   default; on a machine of one core, on one thread);
//! - `radiance_one_pass{,_pool2,_reused}/…` (Y16, YUYV, NV12, Bayer, packed Bayer): decoded and linearised in one
//!   pass over bands of rows ([`Linearizer::decode_linearize_into_on`]), as the camera source
//!   converts the packed formats, into a new buffer (on one and two threads) and into a reused
//!   one;
//! - `decode_bytes/mjpeg`, `radiance_bytes{,_pool2}/mjpeg`, `linearize_bytes_reused/mjpeg`:
//!   the same for a frame kept as bytes and linearised through 256-entry tables, as the camera
//!   source converts formats whose codes are bytes ([`Linearizer::linearize_bytes_into_on`]);
//! - `…/bayer_rg12`: a 12-bit RGGB mosaic of the same scene (bilinear demosaic);
//! - `…/bayer_rg12_csi2`: the same mosaic in the MIPI CSI-2 12-bit packing (`pRCC`);
//! - `…/bayer_rg14`, `…/bayer_rg14_csi2`: a 14-bit RGGB mosaic in 16-bit words (`RG14`) and in
//!   the CSI-2 14-bit packing (`pREE`, four samples in seven bytes);
//! - `…/nv12`: the scene as NV12 (planar 4:2:0, BT.709, each 2 × 2 block's mean chroma);
//! - `…/nv16`: the scene as NV16 (planar 4:2:2: YUYV's samples in a luma and a chroma plane);
//! - `…/nv24`: the scene as NV24 (planar 4:4:4: every pixel's own Cb, Cr);
//! - `…/y210`, `…/p010`: YUYV's and NV12's samples as 16-bit words (10-bit `Y210`, `P010`);
//! - `…/yuv3`, `…/vuya`: NV24's samples packed, three bytes a pixel (`YUV3`: Y Cb Cr) and
//!   four (`VUYA`: Cr Cb Y alpha);
//! - `merge/3_brackets`: merging three 1280×960 brackets into one HDR frame;
//! - `response_recovery/levels_L_samples_S`: recovering a response curve from four 200×150
//!   brackets (Debevec & Malik's gsolve, three channels) at L levels and S sample pixels;
//! - `read/…`: reading a recorded frame file into linear RGB ([`read_hdr_image`]: the file
//!   read, the decoding, the conversion to f32 RGB), for the test maps: an RLE Radiance `.hdr`
//!   (1024×512), a frame as `envlight record` stores it (f32 RGB in RLE tiles, 1024×512), tiled
//!   mip-mapped ZIP16 half-float EXRs (1024×512, 1000×500), a 10-part ZIP1 EXR (877×876; one
//!   part is read) and a PIZ EXR holding every half bit pattern (256×256). Compressed blocks
//!   are decompressed on several threads (`capture::image_file`).
//!
//! The frames are rooitou_park (tests/data) resampled to 1280×960: Y16 holds its luminance,
//! YUYV its sRGB-encoded colours (BT.709), MJPEG the same encoded at quality 90.
//!
//! Run with `cargo bench --bench capture`; quote the medians.

use criterion::{criterion_group, criterion_main, Criterion};
use envlight::capture::bracket::{
    merge_brackets, recover_response, Bracket, MergeLimits, SolveSettings,
};
use envlight::capture::image_file::read_hdr_image;
use envlight::capture::pixel_format::{
    self, ByteImage, CodeImage, PackedYuv, PixelFormat, RawFrame, YuvMatrix,
};
use envlight::capture::response::{Linearizer, Radiometry, ResponseModel};
use std::hint::black_box;
use std::path::Path;
use std::time::Duration;

const W: u32 = 1280;
const H: u32 = 960;

fn srgb(x: f32) -> f32 {
    let x = x.clamp(0.0, 1.0);
    if x <= 0.003_130_8 {
        12.92 * x
    } else {
        1.055 * x.powf(1.0 / 2.4) - 0.055
    }
}

/// rooitou_park resampled (nearest) to 1280×960 and scaled so its median is 0.18.
fn scene() -> Vec<[f32; 3]> {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/rooitou_park_1k.hdr");
    let img = read_hdr_image(&path).unwrap_or_else(|e| panic!("{e}"));
    let mut out = Vec::with_capacity((W * H) as usize);
    for y in 0..H {
        for x in 0..W {
            let (sx, sy) = (x * img.width / W, y * img.height / H);
            out.push(img.pixels[(sy * img.width + sx) as usize]);
        }
    }
    let mut g: Vec<f32> = out.iter().map(|p| p[1]).collect();
    g.sort_by(f32::total_cmp);
    let k = 0.18 / g[g.len() / 2].max(1e-6);
    out.iter().map(|p| p.map(|v| v * k)).collect()
}

fn y16(scene: &[[f32; 3]]) -> Vec<u8> {
    scene
        .iter()
        .flat_map(|p| {
            {
                let l = envlight::frame::luminance(*p);
                ((l * 0.25).clamp(0.0, 1.0) * 65535.0).round() as u16
            }
            .to_le_bytes()
        })
        .collect()
}

/// A linear colour's sRGB-encoded BT.709 Y', Cb, Cr (Y' in [0, 1], Cb and Cr in ±0.5).
fn ycbcr709(p: [f32; 3]) -> (f32, f32, f32) {
    let (kr, kb) = (0.2126f32, 0.0722f32);
    let (r, g, b) = (srgb(p[0]), srgb(p[1]), srgb(p[2]));
    let y = kr * r + (1.0 - kr - kb) * g + kb * b;
    (
        y,
        (b - y) / (2.0 * (1.0 - kb)),
        (r - y) / (2.0 * (1.0 - kr)),
    )
}

/// A limited-range 8-bit code: Y' as 16 + 219·Y', a chroma as 128 + 224·C.
fn code8(v: f32) -> u8 {
    v.round().clamp(0.0, 255.0) as u8
}

fn yuyv(scene: &[[f32; 3]]) -> Vec<u8> {
    let mut out = Vec::with_capacity(scene.len() * 2);
    for pair in scene.chunks_exact(2) {
        let (y0, u0, v0) = ycbcr709(pair[0]);
        let (y1, u1, v1) = ycbcr709(pair[1]);
        out.extend_from_slice(&[
            code8(16.0 + 219.0 * y0),
            code8(128.0 + 112.0 * (u0 + u1)),
            code8(16.0 + 219.0 * y1),
            code8(128.0 + 112.0 * (v0 + v1)),
        ]);
    }
    out
}

/// NV12 (4:2:0): the luma plane, then each 2 × 2 block's mean Cb and Cr interleaved.
fn nv12(scene: &[[f32; 3]]) -> Vec<u8> {
    let (w, h) = (W as usize, H as usize);
    let mut out: Vec<u8> = scene
        .iter()
        .map(|&p| code8(16.0 + 219.0 * ycbcr709(p).0))
        .collect();
    for y in (0..h).step_by(2) {
        for x in (0..w).step_by(2) {
            let (mut u, mut v) = (0.0, 0.0);
            for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
                let (_, cb, cr) = ycbcr709(scene[(y + dy) * w + x + dx]);
                u += cb / 4.0;
                v += cr / 4.0;
            }
            out.extend_from_slice(&[code8(128.0 + 224.0 * u), code8(128.0 + 224.0 * v)]);
        }
    }
    out
}

/// NV16 (4:2:2): the luma plane, then every row's interleaved Cb and Cr (YUYV's samples).
fn nv16(scene: &[[f32; 3]]) -> Vec<u8> {
    let yuyv = yuyv(scene);
    let luma = yuyv.chunks_exact(4).flat_map(|q| [q[0], q[2]]);
    let chroma = yuyv.chunks_exact(4).flat_map(|q| [q[1], q[3]]);
    luma.chain(chroma).collect()
}

/// NV24 (4:4:4): the luma plane, then every pixel's Cb and Cr interleaved.
fn nv24(scene: &[[f32; 3]]) -> Vec<u8> {
    let mut out: Vec<u8> = scene
        .iter()
        .map(|&p| code8(16.0 + 219.0 * ycbcr709(p).0))
        .collect();
    for &p in scene {
        let (_, cb, cr) = ycbcr709(p);
        out.extend_from_slice(&[code8(128.0 + 224.0 * cb), code8(128.0 + 224.0 * cr)]);
    }
    out
}

/// Packed 4:4:4 (`YUV3`, or `VUYA` with an alpha byte): NV24's samples, a pixel's Y, Cb and
/// Cr next to each other.
fn packed444(scene: &[[f32; 3]], alpha: bool) -> Vec<u8> {
    let nv24 = nv24(scene);
    let (luma, chroma) = nv24.split_at(scene.len());
    let pixels = luma.iter().zip(chroma.chunks_exact(2));
    if alpha {
        pixels.flat_map(|(&y, c)| [c[1], c[0], y, 255]).collect()
    } else {
        pixels.flat_map(|(&y, c)| [y, c[0], c[1]]).collect()
    }
}

/// A layout of 16-bit words from the 8-bit one carrying the same samples (`P010` from NV12,
/// `Y210` from YUYV): each byte c as the word 256·c, which decodes to the same codes.
fn widened(bytes: &[u8]) -> Vec<u8> {
    bytes.iter().flat_map(|&c| [0, c]).collect()
}

/// An RGGB mosaic's samples with `bits`-bit codes.
fn bayer_samples(scene: &[[f32; 3]], bits: u32) -> Vec<u16> {
    let max = ((1u32 << bits) - 1) as f32;
    scene
        .iter()
        .enumerate()
        .map(|(i, p)| {
            let (x, y) = (i % W as usize, i / W as usize);
            let c = [[0, 1], [1, 2]][y & 1][x & 1];
            ((p[c] * 0.25).clamp(0.0, 1.0) * max).round() as u16
        })
        .collect()
}

/// An RGGB mosaic with `bits`-bit codes in little-endian 16-bit words.
fn bayer_words(scene: &[[f32; 3]], bits: u32) -> Vec<u8> {
    bayer_samples(scene, bits)
        .iter()
        .flat_map(|v| v.to_le_bytes())
        .collect()
}

/// The 14-bit mosaic in the MIPI CSI-2 14-bit packing (`pREE`): four samples' high bytes, then
/// their low 6-bit parts in order from bit 0 of the fifth byte on.
fn bayer14_packed(scene: &[[f32; 3]]) -> Vec<u8> {
    bayer_samples(scene, 14)
        .chunks_exact(4)
        .flat_map(|s| {
            let low = s
                .iter()
                .enumerate()
                .fold(0u32, |acc, (k, v)| acc | (u32::from(v & 0x3F) << (6 * k)));
            [
                (s[0] >> 6) as u8,
                (s[1] >> 6) as u8,
                (s[2] >> 6) as u8,
                (s[3] >> 6) as u8,
                low as u8,
                (low >> 8) as u8,
                (low >> 16) as u8,
            ]
        })
        .collect()
}

/// The 12-bit mosaic in the MIPI CSI-2 12-bit packing (`pRCC`): two samples' high bytes, then
/// their low nibbles.
fn bayer12_packed(scene: &[[f32; 3]]) -> Vec<u8> {
    bayer_samples(scene, 12)
        .chunks_exact(2)
        .flat_map(|s| {
            [
                (s[0] >> 4) as u8,
                (s[1] >> 4) as u8,
                (s[0] & 0xF) as u8 | (((s[1] & 0xF) as u8) << 4),
            ]
        })
        .collect()
}

fn mjpeg(scene: &[[f32; 3]]) -> Vec<u8> {
    let rgb: Vec<u8> = scene
        .iter()
        .flat_map(|p| p.map(|v| (srgb(v) * 255.0).round() as u8))
        .collect();
    let mut out = Vec::new();
    jpeg_encoder::Encoder::new(&mut out, 90)
        .encode(&rgb, W as u16, H as u16, jpeg_encoder::ColorType::Rgb)
        .unwrap_or_else(|e| panic!("{e}"));
    out
}

/// A packed `W`×`H` frame of `format` in `data`.
fn frame(format: PixelFormat, data: &[u8]) -> RawFrame<'_> {
    RawFrame {
        data,
        format,
        width: W,
        height: H,
        stride: 0,
    }
}

fn bench_capture(c: &mut Criterion) {
    let scene = scene();
    let buffers = [
        ("y16", PixelFormat::Grey { bits: 16 }, y16(&scene)),
        (
            "yuyv",
            PixelFormat::PackedYuv(PackedYuv::Yuyv),
            yuyv(&scene),
        ),
        (
            "nv12",
            PixelFormat::PlanarYuv(pixel_format::PlanarYuv::Nv12),
            nv12(&scene),
        ),
        (
            "y210",
            PixelFormat::PackedYuv(PackedYuv::Y210),
            widened(&yuyv(&scene)),
        ),
        (
            "p010",
            PixelFormat::PlanarYuv(pixel_format::PlanarYuv::P010),
            widened(&nv12(&scene)),
        ),
        (
            "nv16",
            PixelFormat::PlanarYuv(pixel_format::PlanarYuv::Nv16),
            nv16(&scene),
        ),
        (
            "nv24",
            PixelFormat::PlanarYuv(pixel_format::PlanarYuv::Nv24),
            nv24(&scene),
        ),
        (
            "yuv3",
            PixelFormat::PackedYuv(PackedYuv::Yuv24),
            packed444(&scene, false),
        ),
        (
            "vuya",
            PixelFormat::PackedYuv(PackedYuv::Vuya32),
            packed444(&scene, true),
        ),
        ("mjpeg", PixelFormat::Mjpeg, mjpeg(&scene)),
        (
            "bayer_rg12",
            PixelFormat::Bayer {
                pattern: pixel_format::BayerPattern::Rggb,
                bits: 12,
            },
            bayer_words(&scene, 12),
        ),
        (
            "bayer_rg12_csi2",
            PixelFormat::Csi2Packed {
                pattern: Some(pixel_format::BayerPattern::Rggb),
                bits: 12,
            },
            bayer12_packed(&scene),
        ),
        (
            "bayer_rg14",
            PixelFormat::Bayer {
                pattern: pixel_format::BayerPattern::Rggb,
                bits: 14,
            },
            bayer_words(&scene, 14),
        ),
        (
            "bayer_rg14_csi2",
            PixelFormat::Csi2Packed {
                pattern: Some(pixel_format::BayerPattern::Rggb),
                bits: 14,
            },
            bayer14_packed(&scene),
        ),
    ];
    // The packed buffers hold the words' samples: the same codes once decoded.
    let codes_of = |name: &str| {
        let (_, format, data) = buffers.iter().find(|b| b.0 == name).expect("a buffer");
        let raw = frame(*format, data);
        let mut codes = CodeImage {
            width: 0,
            height: 0,
            pixels: Vec::new(),
        };
        pixel_format::decode_into(&raw, YuvMatrix::Bt709, &mut codes)
            .unwrap_or_else(|e| panic!("{name}: {e}"));
        codes.pixels
    };
    for packed in ["yuv3", "vuya"] {
        assert!(
            codes_of(packed) == codes_of("nv24"),
            "{packed}: NV24's samples"
        );
    }
    for (wide, narrow) in [("y210", "yuyv"), ("p010", "nv12")] {
        assert!(
            codes_of(wide) == codes_of(narrow),
            "{wide}: {narrow}'s samples"
        );
    }
    for bits in [12, 14] {
        let words = format!("bayer_rg{bits}");
        assert!(
            codes_of(&words) == codes_of(&format!("{words}_csi2")),
            "the {bits}-bit packing"
        );
    }
    let radiometry = Radiometry {
        exposure_s: 0.01,
        ..Radiometry::default()
    };
    let mut group = c.benchmark_group("capture");
    // Two threads in all, as the camera source converts: the bench's thread and one helper.
    let pool2 = envlight::parallel::helper_pool(2, "bench-convert").expect("a helper thread");
    for (name, format, data) in &buffers {
        let raw = frame(*format, data);
        let model = if format.is_raw() {
            ResponseModel::Linear
        } else {
            ResponseModel::Srgb
        };
        let lin = Linearizer::new(&model, format.code_max(), &radiometry);
        let mut codes = CodeImage {
            width: 0,
            height: 0,
            pixels: Vec::new(),
        };
        group.bench_function(format!("decode/{name}_1280x960"), |b| {
            b.iter(|| {
                pixel_format::decode_into(black_box(&raw), YuvMatrix::Bt709, &mut codes)
                    .unwrap_or_else(|e| panic!("{e}"))
            })
        });
        group.bench_function(format!("radiance/{name}_1280x960"), |b| {
            b.iter(|| {
                pixel_format::decode_into(black_box(&raw), YuvMatrix::Bt709, &mut codes)
                    .unwrap_or_else(|e| panic!("{e}"));
                lin.linearize(&codes)
            })
        });
        group.bench_function(format!("radiance_pool2/{name}_1280x960"), |b| {
            b.iter(|| {
                pixel_format::decode_into_on(
                    black_box(&raw),
                    YuvMatrix::Bt709,
                    &mut codes,
                    pool2.as_ref(),
                )
                .unwrap_or_else(|e| panic!("{e}"));
                lin.linearize_on(&codes, pool2.as_ref())
            })
        });
        let mut out = Vec::new();
        pixel_format::decode_into(&raw, YuvMatrix::Bt709, &mut codes)
            .unwrap_or_else(|e| panic!("{e}"));
        group.bench_function(format!("linearize_reused/{name}_1280x960"), |b| {
            b.iter(|| lin.linearize_into(black_box(&codes), &mut out))
        });
        if !format.has_byte_codes() {
            // Decoded and linearised band by band, as the camera source converts the packed
            // formats (its copy of the driver's buffer left out).
            let mut fresh = Vec::new();
            for (bench, helpers) in [
                ("radiance_one_pass", None),
                ("radiance_one_pass_pool2", pool2.as_ref()),
            ] {
                group.bench_function(format!("{bench}/{name}_1280x960"), |b| {
                    b.iter(|| {
                        fresh = Vec::new();
                        lin.decode_linearize_into_on(
                            black_box(&raw),
                            YuvMatrix::Bt709,
                            &mut fresh,
                            helpers,
                        )
                        .unwrap_or_else(|e| panic!("{e}"))
                    })
                });
            }
            group.bench_function(format!("radiance_one_pass_reused/{name}_1280x960"), |b| {
                b.iter(|| {
                    lin.decode_linearize_into_on(black_box(&raw), YuvMatrix::Bt709, &mut out, None)
                        .unwrap_or_else(|e| panic!("{e}"))
                })
            });
            continue;
        }
        // The same frame kept as bytes, as the camera source keeps a one-byte-code format.
        let mut bytes = ByteImage::default();
        group.bench_function(format!("decode_bytes/{name}_1280x960"), |b| {
            b.iter(|| {
                pixel_format::decode_bytes_into_on(black_box(&raw), &mut bytes, None)
                    .unwrap_or_else(|e| panic!("{e}"))
            })
        });
        group.bench_function(format!("radiance_bytes/{name}_1280x960"), |b| {
            b.iter(|| {
                pixel_format::decode_bytes_into_on(black_box(&raw), &mut bytes, None)
                    .unwrap_or_else(|e| panic!("{e}"));
                let mut fresh = Vec::new();
                lin.linearize_bytes_into_on(&bytes, &mut fresh, None);
                fresh
            })
        });
        group.bench_function(format!("radiance_bytes_pool2/{name}_1280x960"), |b| {
            b.iter(|| {
                pixel_format::decode_bytes_into_on(black_box(&raw), &mut bytes, pool2.as_ref())
                    .unwrap_or_else(|e| panic!("{e}"));
                let mut fresh = Vec::new();
                lin.linearize_bytes_into_on(&bytes, &mut fresh, pool2.as_ref());
                fresh
            })
        });
        group.bench_function(format!("linearize_bytes_reused/{name}_1280x960"), |b| {
            b.iter(|| lin.linearize_bytes_into_on(black_box(&bytes), &mut out, None))
        });
    }
    let raw = RawFrame {
        data: &buffers[1].2,
        format: PixelFormat::PackedYuv(PackedYuv::Yuyv),
        width: W,
        height: H,
        stride: 0,
    };
    let codes = pixel_format::decode(&raw, YuvMatrix::Bt709).unwrap_or_else(|e| panic!("{e}"));
    let brackets: Vec<Bracket> = [0.0025, 0.01, 0.04]
        .iter()
        .map(|&t| Bracket {
            image: codes.clone(),
            exposure_s: t,
            gain: 1.0,
        })
        .collect();
    group.bench_function("merge/3_brackets_1280x960", |b| {
        b.iter(|| {
            merge_brackets(
                black_box(&brackets),
                &ResponseModel::Srgb,
                255.0,
                &Radiometry::default(),
                MergeLimits::default(),
            )
        })
    });
    group.finish();

    let mut group = c.benchmark_group("read");
    let data = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data");
    // A frame as `envlight record` writes it: f32 RGB, RLE tiles (the exr crate's
    // `write_rgb_file`), of rooitou_park.
    let recorded = tempfile::tempdir().unwrap_or_else(|e| panic!("{e}"));
    let map = read_hdr_image(&data.join("rooitou_park_1k.hdr")).unwrap_or_else(|e| panic!("{e}"));
    let width = map.width as usize;
    exr::prelude::write_rgb_file(
        recorded.path().join("recorded.exr"),
        width,
        map.height as usize,
        |x, y| {
            let p = map.pixels[y * width + x];
            (p[0], p[1], p[2])
        },
    )
    .unwrap_or_else(|e| panic!("{e}"));
    group.bench_function("exr_rle_tiled_f32_1024x512_recorded", |b| {
        let path = recorded.path().join("recorded.exr");
        b.iter(|| read_hdr_image(black_box(&path)).unwrap_or_else(|e| panic!("{e}")))
    });
    for (name, file) in [
        ("hdr_rle_1024x512", "rooitou_park_1k.hdr"),
        ("exr_zip16_tiled_1024x512", "KernerEnvLatLong.exr"),
        ("exr_zip16_tiled_1000x500", "StageEnvLatLong.exr"),
        ("exr_zip1_10_parts_877x876", "multipart.0001.exr"),
        ("exr_piz_256x256", "AllHalfValues.exr"),
    ] {
        let path = data.join(file);
        group.bench_function(name, |b| {
            b.iter(|| read_hdr_image(black_box(&path)).unwrap_or_else(|e| panic!("{e}")))
        });
    }
    group.finish();
}

/// Response recovery (`envlight calibrate-response`): four brackets, two stops apart, of the
/// scene resampled to 200×150 and encoded through a gamma-2.2 curve, solved at the default
/// settings (256 levels, 300 samples), at 1024 levels and 2000 samples, and at the largest
/// (4096 levels, 5000 samples; seconds per solve: filter it out with
/// `-- 'response_recovery/levels_(256|1024)'` for a quick run).
fn bench_response_recovery(c: &mut Criterion) {
    let scene = scene();
    let (w, h) = (200u32, 150u32);
    let small: Vec<[f32; 3]> = (0..h)
        .flat_map(|y| (0..w).map(move |x| (x, y)))
        .map(|(x, y)| scene[((y * H / h) * W + x * W / w) as usize])
        .collect();
    let brackets: Vec<Bracket> = [0.25f32, 1.0, 4.0, 16.0]
        .iter()
        .map(|&t| Bracket {
            image: CodeImage {
                width: w,
                height: h,
                pixels: small
                    .iter()
                    .map(|p| p.map(|v| (v * t).clamp(0.0, 1.0).powf(1.0 / 2.2)))
                    .collect(),
            },
            exposure_s: f64::from(t),
            gain: 1.0,
        })
        .collect();
    let mut group = c.benchmark_group("response_recovery");
    group.sample_size(10);
    for (levels, samples) in [(256, 300), (1024, 2000), (4096, 5000)] {
        let settings = SolveSettings {
            levels,
            samples,
            ..SolveSettings::default()
        };
        group.bench_function(format!("levels_{levels}_samples_{samples}"), |b| {
            b.iter(|| {
                recover_response(black_box(&brackets), settings).unwrap_or_else(|e| panic!("{e}"))
            })
        });
    }
    group.finish();
}

criterion_group! {
    name = benches;
    config = Criterion::default()
        .sample_size(30)
        .warm_up_time(Duration::from_millis(500))
        .measurement_time(Duration::from_secs(4));
    targets = bench_capture, bench_response_recovery
}
criterion_main!(benches);
