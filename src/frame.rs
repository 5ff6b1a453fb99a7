//! `HdrFrame`: one environment-map frame as linear RGB radiance plus its projection and timing.

use crate::envmap::Projection;

/// The largest radiance a frame keeps ([`HdrFrame::sanitize`] clamps larger finite values to
/// it): some twenty orders of magnitude above the sun's, and small enough that the whole
/// sphere's integral, 4π × 10³⁰, is far inside f32's range, so no light's power overflows.
pub const MAX_RADIANCE: f32 = 1e30;

/// Rec. 709 / sRGB-primaries luminance weights.
pub const LUMINANCE_WEIGHTS: [f32; 3] = [0.2126, 0.7152, 0.0722];

/// Rec. 709 luminance of a linear RGB triple.
#[inline]
pub fn luminance(rgb: [f32; 3]) -> f32 {
    LUMINANCE_WEIGHTS[0] * rgb[0] + LUMINANCE_WEIGHTS[1] * rgb[1] + LUMINANCE_WEIGHTS[2] * rgb[2]
}

/// One HDR environment-map frame: linear RGB radiance (W/(m²·sr) per channel), row-major,
/// row 0 at the top of the image.
#[derive(Clone, Debug, PartialEq)]
pub struct HdrFrame {
    pub width: u32,
    pub height: u32,
    /// `width * height` linear RGB pixels, row-major.
    pub pixels: Vec<[f32; 3]>,
    /// How pixels map to directions.
    pub projection: Projection,
    /// Capture time in seconds since the source started.
    pub time: f64,
    /// Sequence number assigned by the source, starting at 0.
    pub seq: u64,
}

impl HdrFrame {
    /// A frame from its pixels. Returns `None` if `pixels.len() != width * height` or a side is 0.
    pub fn new(
        width: u32,
        height: u32,
        pixels: Vec<[f32; 3]>,
        projection: Projection,
    ) -> Option<Self> {
        if width == 0 || height == 0 || pixels.len() != width as usize * height as usize {
            return None;
        }
        Some(Self {
            width,
            height,
            pixels,
            projection,
            time: 0.0,
            seq: 0,
        })
    }

    /// The pixel at column `x`, row `y`.
    #[inline]
    pub fn pixel(&self, x: u32, y: u32) -> [f32; 3] {
        self.pixels[y as usize * self.width as usize + x as usize]
    }

    /// The frame with every row rotated left by `shift` columns: pixel x of the result is pixel
    /// (x + shift) mod width of `self`. For a lat-long map that is the environment turned about
    /// the vertical axis by `shift` pixels (what a camera panning by that much would see).
    pub fn turned_columns(&self, shift: usize) -> HdrFrame {
        let w = self.width as usize;
        // A frame built through its public fields may be 0 wide (`new` refuses it).
        if w == 0 {
            return self.clone();
        }
        let s = shift % w;
        let mut pixels = Vec::with_capacity(self.pixels.len());
        for row in self.pixels.chunks_exact(w) {
            pixels.extend_from_slice(&row[s..]);
            pixels.extend_from_slice(&row[..s]);
        }
        HdrFrame {
            width: self.width,
            height: self.height,
            pixels,
            projection: self.projection,
            time: self.time,
            seq: self.seq,
        }
    }

    /// As [`HdrFrame::turned_columns`] for a shift that need not be whole: pixel x of the result
    /// is (1 − t)·pixel(x + s) + t·pixel(x + s + 1) of `self`, with s = ⌊shift⌋ and
    /// t = shift − s, columns wrapping around (linear interpolation). So no frame of a slow pan
    /// is an exact pixel shift of another, as with a real camera. A shift that is not finite
    /// is read as 0.
    pub fn turned_by(&self, shift: f64) -> HdrFrame {
        let shift = if shift.is_finite() { shift } else { 0.0 };
        let w = self.width as usize;
        if w == 0 {
            return self.clone();
        }
        let whole = shift.floor();
        let t = (shift - whole) as f32;
        let s = whole.rem_euclid(w as f64) as usize % w;
        let mut pixels = Vec::with_capacity(self.pixels.len());
        for row in self.pixels.chunks_exact(w) {
            for x in 0..w {
                let (a, b) = (row[(x + s) % w], row[(x + s + 1) % w]);
                pixels.push(std::array::from_fn(|c| (1.0 - t) * a[c] + t * b[c]));
            }
        }
        HdrFrame {
            pixels,
            ..self.clone()
        }
    }

    /// What a `width`×`height` image in `projection` sees of this frame: each pixel takes the
    /// pixel of `self` its centre's direction falls in (nearest sample, no filtering); pixels
    /// with no direction (outside a fisheye's image circle) and directions `self` does not cover
    /// are 0. Time and sequence number are kept. For tests, benchmarks and tools that need a
    /// camera's view of a lat-long map; `None` for an empty size.
    pub fn reprojected(&self, projection: Projection, width: u32, height: u32) -> Option<HdrFrame> {
        let mut pixels = Vec::with_capacity(width as usize * height as usize);
        for y in 0..height {
            for x in 0..width {
                let centre = (f64::from(x) + 0.5, f64::from(y) + 0.5);
                let source = projection
                    .pixel_to_direction(width, height, centre.0, centre.1)
                    .and_then(|d| {
                        self.projection
                            .direction_to_pixel(self.width, self.height, d)
                    });
                pixels.push(match source {
                    Some((sx, sy)) if sx >= 0.0 && sy >= 0.0 => {
                        let sx = (sx as u32).min(self.width.saturating_sub(1));
                        let sy = (sy as u32).min(self.height.saturating_sub(1));
                        self.pixels
                            .get(sy as usize * self.width as usize + sx as usize)
                            .copied()
                            .unwrap_or([0.0; 3])
                    }
                    _ => [0.0; 3],
                });
            }
        }
        let mut frame = HdrFrame::new(width, height, pixels, projection)?;
        frame.time = self.time;
        frame.seq = self.seq;
        Some(frame)
    }

    /// Replaces NaN, ±Inf and negative channel values by 0, clamps finite values above
    /// [`MAX_RADIANCE`] to it, and returns how many pixels had one of these. Radiance is
    /// non-negative and finite, and the clamp keeps every sum of a frame's radiance over solid
    /// angle (a light's power, the map's integral: at most 4π × [`MAX_RADIANCE`]) finite in
    /// f32; callers report the count (one warning per frame).
    pub fn sanitize(&mut self) -> usize {
        let mut bad = 0;
        for p in &mut self.pixels {
            let mut pixel_bad = false;
            for c in p.iter_mut() {
                if !(*c >= 0.0 && *c <= MAX_RADIANCE) {
                    *c = if c.is_finite() && *c > 0.0 {
                        MAX_RADIANCE
                    } else {
                        0.0
                    };
                    pixel_bad = true;
                }
            }
            bad += usize::from(pixel_bad);
        }
        bad
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reprojected_sees_the_same_sky() {
        // A lat-long sky of radiance 1 above the horizon, 0 below, with a marked pixel.
        let (w, h) = (64u32, 32u32);
        let mut pixels: Vec<[f32; 3]> = (0..w * h)
            .map(|i| if i / w < h / 2 { [1.0; 3] } else { [0.0; 3] })
            .collect();
        pixels[5 * w as usize + 9] = [7.0, 0.0, 0.0];
        let mut sky = HdrFrame::new(w, h, pixels, Projection::LatLong).unwrap();
        sky.seq = 3;
        // Onto itself: the same frame.
        assert_eq!(sky.reprojected(Projection::LatLong, w, h).unwrap(), sky);
        // Through a hemispherical fisheye: the sky's integral, 2π less the marked pixel's
        // share, to the nearest-sample error at the rim; nothing outside the image circle.
        let fisheye = Projection::Fisheye(crate::envmap::FisheyeCalibration::default());
        let seen = sky.reprojected(fisheye, 200, 160).unwrap();
        assert_eq!((seen.seq, seen.projection), (3, fisheye));
        let omega = fisheye.solid_angles(200, 160);
        let green: f64 = seen
            .pixels
            .iter()
            .zip(&omega)
            .map(|(p, o)| f64::from(p[1]) * o)
            .sum();
        assert!(
            (green / std::f64::consts::TAU - 1.0).abs() < 0.01,
            "{green}"
        );
        assert!(seen.pixels.iter().any(|p| p[0] == 7.0));
        assert_eq!(seen.pixel(0, 0), [0.0; 3]);
        assert!(sky.reprojected(fisheye, 0, 10).is_none());
    }

    #[test]
    fn turned_columns_rotates_every_row() {
        let pixels = (0..12).map(|i| [i as f32, 0.0, 0.0]).collect();
        let mut frame = HdrFrame::new(4, 3, pixels, Projection::LatLong).unwrap();
        frame.seq = 7;
        let turned = frame.turned_columns(1);
        let red: Vec<f32> = turned.pixels.iter().map(|p| p[0]).collect();
        assert_eq!(red, [1., 2., 3., 0., 5., 6., 7., 4., 9., 10., 11., 8.]);
        assert_eq!((turned.width, turned.height, turned.seq), (4, 3, 7));
        assert_eq!(frame.turned_columns(4), frame);
        assert_eq!(frame.turned_columns(5), turned);
        // A frame 0 wide (only through the public fields) turns into itself, as with
        // turned_by, instead of dividing by zero.
        let empty = HdrFrame {
            width: 0,
            height: 0,
            pixels: Vec::new(),
            ..frame
        };
        assert_eq!(empty.turned_columns(3), empty);
        assert_eq!(empty.turned_by(1.5), empty);
    }

    #[test]
    fn turned_by_interpolates_between_whole_turns() {
        let pixels = (0..12).map(|i| [i as f32, 1.0, 0.0]).collect();
        let frame = HdrFrame::new(4, 3, pixels, Projection::LatLong).unwrap();
        for whole in [0usize, 1, 3, 4, 7] {
            assert_eq!(frame.turned_by(whole as f64), frame.turned_columns(whole));
        }
        assert_eq!(frame.turned_by(-1.0), frame.turned_columns(3));
        let half = frame.turned_by(1.5);
        let red: Vec<f32> = half.pixels.iter().map(|p| p[0]).collect();
        // Row 0 turned by 1 is [1, 2, 3, 0], by 2 is [2, 3, 0, 1]: halfway between.
        assert_eq!(red[..4], [1.5, 2.5, 1.5, 0.5]);
        assert!(half.pixels.iter().all(|p| p[1] == 1.0));
        assert_eq!(frame.turned_by(f64::NAN), frame);
    }

    #[test]
    fn sanitize_zeroes_and_counts_bad_pixels() {
        let pixels = vec![
            [1.0, 2.0, 3.0],
            [f32::NAN, 1.0, 1.0],
            [-1.0, f32::INFINITY, 0.0],
            [0.5; 3],
        ];
        let mut frame = HdrFrame::new(2, 2, pixels, Projection::LatLong).unwrap();
        assert_eq!(frame.sanitize(), 2);
        assert_eq!(frame.pixels[1], [0.0, 1.0, 1.0]);
        assert_eq!(frame.pixels[2], [0.0, 0.0, 0.0]);
        assert_eq!(frame.pixels[3], [0.5; 3]);
    }

    #[test]
    fn sanitize_clamps_huge_finite_values() {
        let pixels = vec![[1e35, 1.0, f32::MAX], [MAX_RADIANCE; 3]];
        let mut frame = HdrFrame::new(2, 1, pixels, Projection::LatLong).unwrap();
        assert_eq!(frame.sanitize(), 1);
        assert_eq!(frame.pixels[0], [MAX_RADIANCE, 1.0, MAX_RADIANCE]);
        assert_eq!(frame.pixels[1], [MAX_RADIANCE; 3]);
        // The whole sphere at the clamp stays far inside f32.
        assert!((4.0 * std::f64::consts::PI * f64::from(MAX_RADIANCE)) < f64::from(f32::MAX));
    }

    #[test]
    fn new_rejects_wrong_pixel_count() {
        assert!(HdrFrame::new(2, 2, vec![[0.0; 3]; 3], Projection::LatLong).is_none());
        assert!(HdrFrame::new(0, 2, vec![], Projection::LatLong).is_none());
    }
}
