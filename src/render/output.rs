//! Writing frames: a tone-mapped 8-bit sRGB PNG (RGBA, premultiplied alpha un-premultiplied for
//! the file) and a linear 32-bit float EXR, plus mixed-reality compositing over a background.
//!
//! Tone mapping: exposure scale, then Narkowicz's fitted ACES curve, then the sRGB transfer
//! function. [`auto_exposure`] picks a scale that maps the median luminance of the opaque
//! pixels to 0.18; a sequence should fix it from its first frame so frames do not flicker.

use super::Image;
use std::path::{Path, PathBuf};
use thiserror::Error;

/// Why an image could not be written.
#[derive(Debug, Error)]
pub enum OutputError {
    #[error("cannot write {path}: {message}")]
    Write { path: PathBuf, message: String },
}

/// Narkowicz's ACES fit, clamped to [0, 1]. Its input is held at [`ACES_INPUT_MAX`], where it
/// is 1 already: above about 10¹⁹ the products overflowed to ∞/∞ = NaN, and NaN cast to u8 is 0,
/// so the brightest pixels came out black (found by an audit; `present.wgsl` does the same).
fn aces(x: f32) -> f32 {
    let x = x.min(ACES_INPUT_MAX);
    let (a, b, c, d, e) = (2.51, 0.03, 2.43, 0.59, 0.14);
    ((x * (a * x + b)) / (x * (c * x + d) + e)).clamp(0.0, 1.0)
}

/// Where the tone curve is held: 1 there (2.51/2.43 > 1 before the clamp), and far from f32's
/// overflow.
const ACES_INPUT_MAX: f32 = 1.0e4;

/// The sRGB encoding (IEC 61966-2-1) of a linear value in [0, 1].
pub(crate) fn srgb_oetf(x: f32) -> f32 {
    if x <= 0.003_130_8 {
        12.92 * x
    } else {
        1.055 * x.powf(1.0 / 2.4) - 0.055
    }
}

/// Its inverse: an sRGB-encoded value in [0, 1] to linear.
pub(crate) fn srgb_eotf(v: f32) -> f32 {
    if v <= 0.04045 {
        v / 12.92
    } else {
        ((v + 0.055) / 1.055).powf(2.4)
    }
}

/// Linear value → 8-bit sRGB after exposure and tone curve.
pub fn tone_map(x: f32, exposure: f32) -> u8 {
    let v = if x.is_finite() { x.max(0.0) } else { 0.0 };
    (srgb_oetf(aces(v * exposure)) * 255.0 + 0.5) as u8
}

/// Exposure that maps the median luminance of the opaque lit pixels to 0.18; `None` for an
/// image without one (a frame with no lights), from which no exposure can be told.
pub fn auto_exposure(image: &Image) -> Option<f32> {
    let mut lum: Vec<f32> = image
        .rgba
        .chunks_exact(4)
        .filter(|p| p[3] >= 0.999)
        .map(|p| 0.2126 * p[0] + 0.7152 * p[1] + 0.0722 * p[2])
        .filter(|l| l.is_finite() && *l > 0.0)
        .collect();
    if lum.is_empty() {
        return None;
    }
    let mid = lum.len() / 2;
    let (_, m, _) = lum.select_nth_unstable_by(mid, f32::total_cmp);
    Some(0.18 / *m)
}

/// 8-bit RGBA after tone mapping (colour un-premultiplied by alpha).
pub fn to_rgba8(image: &Image, exposure: f32) -> Vec<u8> {
    image
        .rgba
        .chunks_exact(4)
        .flat_map(|p| {
            let a = p[3].clamp(0.0, 1.0);
            let un = |c: f32| if a > 1e-6 { c / a } else { 0.0 };
            [
                tone_map(un(p[0]), exposure),
                tone_map(un(p[1]), exposure),
                tone_map(un(p[2]), exposure),
                (a * 255.0 + 0.5) as u8,
            ]
        })
        .collect()
}

/// Writes a tone-mapped PNG.
pub fn write_png(path: &Path, image: &Image, exposure: f32) -> Result<(), OutputError> {
    let bytes = to_rgba8(image, exposure);
    image::save_buffer_with_format(
        path,
        &bytes,
        image.width,
        image.height,
        image::ExtendedColorType::Rgba8,
        image::ImageFormat::Png,
    )
    .map_err(|e| OutputError::Write {
        path: path.to_path_buf(),
        message: e.to_string(),
    })
}

/// The non-finite values [`saturate`] replaced.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Saturated {
    /// ±∞: very bright lights summed past f32's range; written as ±`f32::MAX`.
    pub infinite: usize,
    /// NaN (a shading fault); written as 0.
    pub nan: usize,
}

/// Replaces the values a render cannot hold — +∞ where very bright lights summed past f32's
/// range, NaN — by `f32::MAX` (−∞ by `-f32::MAX`) and 0, and counts each kind, so the EXR and
/// PNG written hold finite numbers only.
pub fn saturate(image: &mut Image) -> Saturated {
    let mut count = Saturated::default();
    for v in &mut image.rgba {
        if v.is_nan() {
            *v = 0.0;
            count.nan += 1;
        } else if v.is_infinite() {
            *v = f32::MAX.copysign(*v);
            count.infinite += 1;
        }
    }
    count
}

/// Writes the linear image as a 32-bit float RGBA EXR (premultiplied, as EXR expects).
pub fn write_exr(path: &Path, image: &Image) -> Result<(), OutputError> {
    use exr::prelude::{SpecificChannels, Vec2, WritableImage};
    let w = image.width as usize;
    let channels = SpecificChannels::rgba(|Vec2(x, y)| {
        let i = 4 * (y * w + x);
        let p = &image.rgba[i..i + 4];
        (p[0], p[1], p[2], p[3])
    });
    exr::prelude::Image::from_encoded_channels(
        (w, image.height as usize),
        crate::capture::image_file::WRITE_ENCODING,
        channels,
    )
    .write()
    .to_file(path)
    .map_err(|e| OutputError::Write {
        path: path.to_path_buf(),
        message: e.to_string(),
    })
}

/// Composites the (premultiplied) image over a background: out = c + (1 − α)·bg, α → 1.
/// `background(x, y)` gives the linear background radiance of a pixel (the camera picture, or
/// the environment map seen along the pixel's ray).
pub fn composite_background(image: &mut Image, mut background: impl FnMut(u32, u32) -> [f32; 3]) {
    let w = image.width;
    for (i, p) in image.rgba.chunks_exact_mut(4).enumerate() {
        let (x, y) = (i as u32 % w, i as u32 / w);
        let a = p[3].clamp(0.0, 1.0);
        if a < 1.0 {
            let bg = background(x, y);
            for c in 0..3 {
                p[c] += (1.0 - a) * bg[c];
            }
        }
        p[3] = 1.0;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The same image gives the same EXR bytes: tiles in increasing order (the parallel
    /// writer's unspecified order gave 4 different files in 6 runs of one render).
    #[test]
    fn an_exr_is_written_the_same_way_every_time() {
        let (width, height) = (300u32, 200u32);
        let image = Image {
            width,
            height,
            rgba: (0..width * height * 4)
                .map(|i| (i % 97) as f32 * 0.25)
                .collect(),
        };
        let dir = tempfile::tempdir().unwrap();
        let files: Vec<Vec<u8>> = (0..3)
            .map(|i| {
                let path = dir.path().join(format!("{i}.exr"));
                write_exr(&path, &image).unwrap();
                std::fs::read(&path).unwrap()
            })
            .collect();
        assert!(files.windows(2).all(|w| w[0] == w[1]));
        let meta = exr::meta::MetaData::read_from_buffered(std::io::Cursor::new(&files[0]), false)
            .unwrap();
        assert_eq!(
            meta.headers[0].line_order,
            exr::prelude::LineOrder::Increasing
        );
    }

    #[test]
    fn saturate_leaves_finite_values_and_counts_the_rest() {
        let mut image = Image {
            width: 2,
            height: 1,
            rgba: vec![
                1.0,
                f32::INFINITY,
                f32::NAN,
                1.0,
                f32::NEG_INFINITY,
                0.5,
                0.25,
                1.0,
            ],
        };
        assert_eq!(
            saturate(&mut image),
            Saturated {
                infinite: 2,
                nan: 1
            }
        );
        assert_eq!(
            image.rgba,
            [1.0, f32::MAX, 0.0, 1.0, -f32::MAX, 0.5, 0.25, 1.0]
        );
    }

    #[test]
    fn tone_curve_is_monotone_and_bounded() {
        let mut last = 0u8;
        for i in 0..1000 {
            let v = tone_map(i as f32 * 0.01, 1.0);
            assert!(v >= last);
            last = v;
        }
        assert_eq!(tone_map(0.0, 1.0), 0);
        assert_eq!(tone_map(1e6, 1.0), 255);
        assert_eq!(tone_map(f32::NAN, 1.0), 0);
        // Exposure × radiance past 10¹⁹ (and past f32's range) is white, not black.
        assert_eq!(tone_map(1.0, 1e20), 255);
        assert_eq!(tone_map(f32::MAX, 10.0), 255);
        assert_eq!(tone_map(f32::INFINITY, 1.0), 0);
    }

    #[test]
    fn compositing_darkens_by_shadow_alpha() {
        // An opaque red pixel, a 25% shadow, and empty background.
        let mut img = Image {
            width: 3,
            height: 1,
            rgba: vec![1.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 0.25, 0.0, 0.0, 0.0, 0.0],
        };
        composite_background(&mut img, |_, _| [2.0, 2.0, 2.0]);
        assert_eq!(img.pixel(0, 0), [1.0, 0.0, 0.0, 1.0]);
        assert_eq!(img.pixel(1, 0), [1.5, 1.5, 1.5, 1.0]);
        assert_eq!(img.pixel(2, 0), [2.0, 2.0, 2.0, 1.0]);
    }

    #[test]
    fn files_round_trip() {
        let dir = tempfile::tempdir().unwrap();
        let img = Image {
            width: 2,
            height: 2,
            rgba: vec![
                0.5, 1.0, 2.0, 1.0, 0.0, 0.0, 0.0, 0.0, 4.0, 0.25, 0.0, 1.0, 0.0, 0.0, 0.0, 0.5,
            ],
        };
        let exr_path = dir.path().join("f.exr");
        write_exr(&exr_path, &img).unwrap();
        let back = exr::prelude::read_first_rgba_layer_from_file(
            &exr_path,
            |res, _| vec![[0f32; 4]; res.width() * res.height()],
            |px: &mut Vec<[f32; 4]>, pos, (r, g, b, a): (f32, f32, f32, f32)| {
                px[pos.y() * 2 + pos.x()] = [r, g, b, a]
            },
        )
        .unwrap();
        let px = &back.layer_data.channel_data.pixels;
        assert_eq!(px[0], [0.5, 1.0, 2.0, 1.0]);
        assert_eq!(px[2], [4.0, 0.25, 0.0, 1.0]);
        let png_path = dir.path().join("f.png");
        write_png(&png_path, &img, 1.0).unwrap();
        let png = image::open(&png_path).unwrap().to_rgba8();
        assert_eq!(png.get_pixel(1, 0)[3], 0);
        assert_eq!(png.get_pixel(1, 1)[3], 128);
        let bad = dir.path().join("no/such/dir/f.png");
        let e = write_png(&bad, &img, 1.0).unwrap_err().to_string();
        assert!(e.contains("f.png"), "{e}");
    }
}
