//! Per-frame cost of the camera conversions as *CPU time*, for a busy machine where
//! criterion's wall-clock medians are inflated by other processes (docs/performance.md).
//!
//! ```text
//! cargo run --release --example profile_capture -- 100
//! ```
//!
//! For each format a 1280×960 buffer of rooitou_park (as in `benches/capture.rs`) is converted to
//! radiance `N` times, into a new buffer every frame and into one buffer reused (as the camera
//! source does with the buffers the pipeline hands back), two ways: through a whole-frame code
//! image, and the camera source's way (MJPEG kept as bytes; the packed formats' buffer copied,
//! then decoded and linearised in one pass; "decode" is then the check and the copy). The
//! process's user + system time comes from `/proc/self/stat` (clock ticks, 10 ms), so N should
//! make each run last a second or more. It counts every thread: the
//! conversions run in bands of rows on rayon's pool (`RAYON_NUM_THREADS=1` for one thread), and
//! an idle pool thread's brief spinning is counted too.

use envlight::capture::image_file::read_hdr_image;
use envlight::capture::pixel_format::{
    self, BayerPattern, ByteImage, CodeImage, PixelFormat, RawFrame,
};
use envlight::capture::response::{Linearizer, Radiometry, ResponseModel};
use std::time::Instant;

const W: u32 = 1280;
const H: u32 = 960;

/// This process's user + system CPU time in seconds, all threads (Linux).
fn process_cpu_s() -> f64 {
    let stat = std::fs::read_to_string("/proc/self/stat").unwrap_or_default();
    // fields after the parenthesised command name; utime and stime are fields 14 and 15
    let rest = stat.rsplit_once(')').map_or("", |(_, r)| r);
    let f: Vec<f64> = rest
        .split_whitespace()
        .filter_map(|s| s.parse().ok())
        .collect();
    // `rest` starts at field 3 (the state letter is skipped by the parse filter)
    f.get(10)
        .zip(f.get(11))
        .map_or(f64::NAN, |(u, s)| (u + s) / 100.0)
}

fn srgb(x: f32) -> f32 {
    let x = x.clamp(0.0, 1.0);
    if x <= 0.003_130_8 {
        12.92 * x
    } else {
        1.055 * x.powf(1.0 / 2.4) - 0.055
    }
}

/// How a frame is held between the driver's buffer and its linearisation.
#[derive(Clone, Copy)]
enum Path {
    /// A whole-frame image of normalised codes (f32), then the look-up tables.
    CodeImage,
    /// One-byte codes kept as bytes, then 256-entry tables (the camera source's MJPEG path).
    Bytes,
    /// A copy of the buffer, decoded and linearised in one pass over bands of rows (the
    /// camera source's path for the packed formats).
    OnePass,
}

/// The buffers of [`Path`]'s three ways.
#[derive(Default)]
struct Kept {
    codes: CodeImage,
    bytes: ByteImage,
    raw_copy: Vec<u8>,
}

fn main() -> anyhow::Result<()> {
    let n: usize = std::env::args().nth(1).map_or(Ok(100), |s| s.parse())?;
    let img = read_hdr_image(std::path::Path::new("tests/data/rooitou_park_1k.hdr"))?;
    let mut scene = Vec::with_capacity((W * H) as usize);
    for y in 0..H {
        for x in 0..W {
            let p = img.pixels[((y * img.height / H) * img.width + x * img.width / W) as usize];
            scene.push(p.map(|v| (v * 0.05).min(1.0)));
        }
    }
    let y16: Vec<u8> = scene
        .iter()
        .flat_map(|p| ((envlight::frame::luminance(*p) * 65535.0) as u16).to_le_bytes())
        .collect();
    let yuyv: Vec<u8> = scene
        .chunks_exact(2)
        .flat_map(|q| {
            let y = |p: [f32; 3]| (16.0 + 219.0 * srgb(envlight::frame::luminance(p))) as u8;
            [y(q[0]), 128, y(q[1]), 128]
        })
        .collect();
    let rgb: Vec<u8> = scene
        .iter()
        .flat_map(|p| p.map(|v| (srgb(v) * 255.0) as u8))
        .collect();
    let mut mjpeg = Vec::new();
    jpeg_encoder::Encoder::new(&mut mjpeg, 90).encode(
        &rgb,
        W as u16,
        H as u16,
        jpeg_encoder::ColorType::Rgb,
    )?;
    let bayer: Vec<u8> = scene
        .iter()
        .enumerate()
        .flat_map(|(i, p)| {
            let (x, y) = (i % W as usize, i / W as usize);
            ((p[[[0, 1], [1, 2]][y & 1][x & 1]] * 4095.0) as u16).to_le_bytes()
        })
        .collect();
    let rg12 = PixelFormat::Bayer {
        pattern: BayerPattern::Rggb,
        bits: 12,
    };
    // (name, format, buffer, path); the second row of each format is the camera source's path
    let cases = [
        (
            "Y16 via a code image",
            PixelFormat::Grey { bits: 16 },
            &y16,
            Path::CodeImage,
        ),
        (
            "Y16 in one pass",
            PixelFormat::Grey { bits: 16 },
            &y16,
            Path::OnePass,
        ),
        (
            "YUYV via a code image",
            PixelFormat::Yuyv,
            &yuyv,
            Path::CodeImage,
        ),
        ("YUYV in one pass", PixelFormat::Yuyv, &yuyv, Path::OnePass),
        (
            "MJPEG via a code image",
            PixelFormat::Mjpeg,
            &mjpeg,
            Path::CodeImage,
        ),
        ("MJPEG as bytes", PixelFormat::Mjpeg, &mjpeg, Path::Bytes),
        ("Bayer RG12 via a code image", rg12, &bayer, Path::CodeImage),
        ("Bayer RG12 in one pass", rg12, &bayer, Path::OnePass),
    ];
    println!(
        "| format | decode CPU ms/frame | decode + linearise CPU ms/frame (new buffer) | \
         wall | decode + linearise into a recycled buffer | wall |"
    );
    println!("|---|---:|---:|---:|---:|---:|");
    for (name, format, data, path) in cases {
        let raw = RawFrame {
            data,
            format,
            width: W,
            height: H,
            stride: 0,
        };
        let model = if format.is_raw() {
            ResponseModel::Linear
        } else {
            ResponseModel::Srgb
        };
        let lin = Linearizer::new(&model, format.code_max(), &Radiometry::default());
        let mut kept = Kept::default();
        // What the camera source does with the driver's buffer while it holds it.
        let decode = |kept: &mut Kept| -> Result<(), pixel_format::PixelError> {
            match path {
                Path::CodeImage => {
                    pixel_format::decode_into(&raw, Default::default(), &mut kept.codes)
                }
                Path::Bytes => pixel_format::decode_bytes_into_on(&raw, &mut kept.bytes, None),
                Path::OnePass => pixel_format::check(&raw).map(|()| {
                    kept.raw_copy.clear();
                    kept.raw_copy.extend_from_slice(raw.data);
                }),
            }
        };
        let c0 = process_cpu_s();
        for _ in 0..n {
            decode(&mut kept)?;
        }
        let decode_s = (process_cpu_s() - c0) / n as f64;
        // What it does once the exposure is known.
        let linearize = |out: &mut Vec<[f32; 3]>, kept: &Kept| match path {
            Path::CodeImage => {
                lin.linearize_into(&kept.codes, out);
                Ok(())
            }
            Path::Bytes => {
                lin.linearize_bytes_into_on(&kept.bytes, out, None);
                Ok(())
            }
            Path::OnePass => {
                let raw = RawFrame {
                    data: &kept.raw_copy,
                    ..raw
                };
                lin.decode_linearize_into_on(&raw, Default::default(), out, None)
            }
        };
        let (c0, t0) = (process_cpu_s(), Instant::now());
        let mut sum = 0.0f32;
        for _ in 0..n {
            decode(&mut kept)?;
            let mut fresh = Vec::new();
            linearize(&mut fresh, &kept)?;
            sum += fresh[0][0];
        }
        let total = (process_cpu_s() - c0) / n as f64;
        let wall = t0.elapsed().as_secs_f64() / n as f64;
        // As the camera source does when the pipeline hands each frame's buffer back
        // (FrameSource::recycle): the same 15 MB written every frame.
        let mut pixels = Vec::new();
        let (c0, t0) = (process_cpu_s(), Instant::now());
        for _ in 0..n {
            decode(&mut kept)?;
            linearize(&mut pixels, &kept)?;
            sum += pixels[0][0];
        }
        let recycled = (process_cpu_s() - c0) / n as f64;
        let recycled_wall = t0.elapsed().as_secs_f64() / n as f64;
        std::hint::black_box(sum);
        println!(
            "| {name} | {:.1} | {:.1} | {:.1} | {:.1} | {:.1} |",
            decode_s * 1e3,
            total * 1e3,
            wall * 1e3,
            recycled * 1e3,
            recycled_wall * 1e3
        );
    }
    Ok(())
}
