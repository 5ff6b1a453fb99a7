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

use envlight::capture::convert::{Calibration, FrameConverter, StreamFormat};
use envlight::capture::image_file::read_hdr_image;
use envlight::capture::pixel_format::{
    self, BayerPattern, CodeImage, PackedYuv, PixelError, PixelFormat, RawFrame, YuvMatrix,
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

/// The two ways a frame goes from the driver's buffer to radiance.
enum Way {
    /// A whole-frame image of normalised codes (f32), then the look-up tables.
    CodeImage { lin: Linearizer, codes: CodeImage },
    /// The camera source's way ([`FrameConverter`]: MJPEG kept as bytes, the packed formats'
    /// buffer copied, then decoded and linearised in one pass).
    Camera(Box<FrameConverter>),
}

impl Way {
    /// What is done while the driver lends the buffer.
    fn keep(&mut self, raw: &RawFrame<'_>) -> Result<(), PixelError> {
        match self {
            Way::CodeImage { codes, .. } => {
                pixel_format::decode_into(raw, Default::default(), codes)
            }
            Way::Camera(converter) => converter.keep(raw.data),
        }
    }

    /// What is done once the exposure is known, into `recycled` where it holds a frame.
    fn radiance(&mut self, recycled: Vec<[f32; 3]>) -> Result<Vec<[f32; 3]>, PixelError> {
        match self {
            Way::CodeImage { lin, codes } => {
                let mut out = recycled;
                lin.linearize_into(codes, &mut out);
                Ok(out)
            }
            Way::Camera(converter) => {
                converter.recycle(recycled);
                converter.radiance(1.0, 1.0)
            }
        }
    }
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
    // (name, format, buffer, the camera source's way or a code image)
    let cases = [
        (
            "Y16 via a code image",
            PixelFormat::Grey { bits: 16 },
            &y16,
            false,
        ),
        (
            "Y16 in one pass",
            PixelFormat::Grey { bits: 16 },
            &y16,
            true,
        ),
        (
            "YUYV via a code image",
            PixelFormat::PackedYuv(PackedYuv::Yuyv),
            &yuyv,
            false,
        ),
        (
            "YUYV in one pass",
            PixelFormat::PackedYuv(PackedYuv::Yuyv),
            &yuyv,
            true,
        ),
        ("MJPEG via a code image", PixelFormat::Mjpeg, &mjpeg, false),
        ("MJPEG as bytes", PixelFormat::Mjpeg, &mjpeg, true),
        ("Bayer RG12 via a code image", rg12, &bayer, false),
        ("Bayer RG12 in one pass", rg12, &bayer, true),
    ];
    println!(
        "| format | decode CPU ms/frame | decode + linearise CPU ms/frame (new buffer) | \
         wall | decode + linearise into a recycled buffer | wall |"
    );
    println!("|---|---:|---:|---:|---:|---:|");
    for (name, format, data, camera) in cases {
        let raw = RawFrame {
            data,
            format,
            width: W,
            height: H,
            stride: 0,
        };
        let response = if format.is_raw() {
            ResponseModel::Linear
        } else {
            ResponseModel::Srgb
        };
        let mut way = if camera {
            let stream = StreamFormat {
                format,
                width: W,
                height: H,
                stride: 0,
            };
            let calibration = Calibration {
                response,
                yuv_matrix: YuvMatrix::default(),
                white_balance: [1.0; 3],
                scale: 1.0,
            };
            Way::Camera(Box::new(FrameConverter::new(
                stream,
                calibration,
                false,
                None,
            )))
        } else {
            Way::CodeImage {
                lin: Linearizer::new(&response, format.code_max(), &Radiometry::default()),
                codes: CodeImage::default(),
            }
        };
        let c0 = process_cpu_s();
        for _ in 0..n {
            way.keep(&raw)?;
        }
        let decode_s = (process_cpu_s() - c0) / n as f64;
        let (c0, t0) = (process_cpu_s(), Instant::now());
        let mut sum = 0.0f32;
        for _ in 0..n {
            way.keep(&raw)?;
            let fresh = way.radiance(Vec::new())?;
            sum += fresh[0][0];
        }
        let total = (process_cpu_s() - c0) / n as f64;
        let wall = t0.elapsed().as_secs_f64() / n as f64;
        // As the camera source does when the pipeline hands each frame's buffer back
        // (FrameSource::recycle): the same 15 MB written every frame.
        let mut pixels = Vec::new();
        let (c0, t0) = (process_cpu_s(), Instant::now());
        for _ in 0..n {
            way.keep(&raw)?;
            pixels = way.radiance(pixels)?;
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
