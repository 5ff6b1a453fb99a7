//! Automatic image-circle detection for fisheye frames ([`detect_image_circle`]), and a renderer
//! of synthetic fisheye frames from lat-long maps ([`render_fisheye`]) to test it with.
//!
//! Detection steps:
//! 1. Luminance Y per pixel. Background level b = the 5th percentile of Y (the corners outside
//!    a circular fisheye's circle; the 1st, else the 0.25th, where that finds no contrast: a
//!    circle cropped by the frame leaves its corners only), inside level l = the 60th
//!    percentile, threshold T = b + 0.05·(l − b).
//! 2. Coarse circle from the mask Y > T: centroid, and radius √(area/π).
//! 3. Sub-pixel edge points. Where the rim is closer to vertical (|y − cy| < 0.7 R) each row is
//!    scanned from both ends for the first pixel above T; a window of 4 pixels straddling it
//!    gives the coverage c_i = clamp((Y_i − b)/(Y_in − b), 0, 1) of each pixel, with Y_in the
//!    median of the 3 pixels just inside the window. A straight boundary crossing the row is
//!    then exactly at x_window_end − Σ c_i (the covered area of the row band), so the edge
//!    point is (that, y + ½). Columns do the same where |x − cx| < 0.7 R. Windows touching the
//!    image border are skipped (a circle cut by the frame has no edge there).
//! 4. Robust fit: algebraic (Kåsa) circle fit, then Gauss–Newton on the geometric residuals
//!    |p − c| − R, rejecting points whose residual exceeds max(3·1.4826·MAD, 0.25 px), five
//!    rounds, the point selection of step 3 redone with each new centre.
//! 5. Plausibility: the centre must lie in the frame, the radius be at most the frame's diagonal
//!    and the RMS residual at most 2% of the radius (0.5 px for small circles); otherwise the
//!    edge is no image circle (a half-lit frame, a bright rectangle) and detection fails.
//!
//! When the circle covers less than 40% of the frame, the 60th percentile of step 1 is the
//! surround's level; the inside level is then the 60th percentile of the pixels above
//! b + 0.05·(99th percentile − b).
//!
//! On the synthetic frames of `tests/camera.rs` (rendered with 4×4 super-sampling from the
//! shared HDRIs, with noise) the centre and radius come out well within a pixel.

use super::FisheyeCalibration;
use super::Projection;

/// A detected image circle.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ImageCircle {
    /// Centre in continuous pixel coordinates (pixel (x, y) covers [x, x+1) × [y, y+1)).
    pub center: [f64; 2],
    pub radius: f64,
    /// Edge points used in the final fit.
    pub points: usize,
    /// RMS geometric residual of those points, pixels.
    pub rms_residual: f64,
}

/// Why no circle was found.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum DetectError {
    #[error("image {width}x{height} is too small or has the wrong pixel count")]
    Size { width: u32, height: u32 },
    #[error(
        "no image circle: the image has no contrast between a dark surround and the circle (its \
         darkest 0.25% is as bright as the rest)"
    )]
    NoContrast,
    #[error("no image circle: only {0} edge points found (is the circle inside the frame?)")]
    TooFewPoints(usize),
    /// The edge found is no image circle of this frame.
    #[error(
        "no image circle: the edge found is not one (centre [{:.1}, {:.1}], radius {:.1} px, rms \
         residual {:.2} px); {reason}", center[0], center[1], radius, rms_residual
    )]
    NotACircle {
        center: [f64; 2],
        radius: f64,
        rms_residual: f64,
        reason: &'static str,
    },
}

fn percentile(sorted: &[f32], q: f64) -> f32 {
    sorted[((q * (sorted.len() - 1) as f64).round() as usize).min(sorted.len() - 1)]
}

/// Finds the image circle of a fisheye frame (see the module docs).
pub fn detect_image_circle(
    pixels: &[[f32; 3]],
    width: u32,
    height: u32,
) -> Result<ImageCircle, DetectError> {
    let (w, h) = (width as usize, height as usize);
    if w < 16 || h < 16 || pixels.len() != w * h {
        return Err(DetectError::Size { width, height });
    }
    let lum: Vec<f32> = pixels
        .iter()
        .map(|&p| {
            let y = crate::frame::luminance(p);
            if y.is_finite() {
                y.max(0.0)
            } else {
                0.0
            }
        })
        .collect();
    let mut sorted = lum.clone();
    sorted.sort_by(f32::total_cmp);
    let levels = |background_share: f64| {
        let bg = percentile(&sorted, background_share);
        let mut level = percentile(&sorted, 0.60);
        if !(level > bg && level.is_finite()) {
            // A circle covering less than 40% of the frame: the 60th percentile is surround.
            // Take the level among the pixels clearly above it (5% of the way to the 99th
            // percentile).
            let top = percentile(&sorted, 0.99);
            let above = bg + 0.05 * (top - bg);
            let start = sorted.partition_point(|&y| y <= above);
            if start < sorted.len() {
                level = percentile(&sorted[start..], 0.60);
            }
        }
        (bg, level)
    };
    // The surround's level is the 5th percentile, or, where the circle leaves less than 5% of
    // the frame dark (a circle cropped by the frame's top and bottom, its corners dark), the
    // 1st or the 0.25th: a circle of radius 350 in a 640×480 frame leaves 3.7% dark, and the
    // 5th percentile fell inside it ("no contrast"; an audit).
    let (bg, level) = [0.05, 0.01, 0.0025]
        .into_iter()
        .map(levels)
        .find(|&(bg, level)| level > bg && level.is_finite())
        .ok_or(DetectError::NoContrast)?;
    // 5% of the way from the surround to the image, but clear of the surround's noise: with a
    // sensor's 1–3 codes of dark noise, 5% of the way lay within it and the first and last
    // pixels above it on a row were noise, not the rim. The noise is measured on the pixels
    // below half way (the surround, and dark parts of the image): their median plus six
    // robust standard deviations (1.4826 × the median absolute deviation).
    let half = bg + 0.5 * (level - bg);
    let dark = &sorted[..sorted.partition_point(|&y| y < half)];
    let noise_floor = if dark.len() >= 16 {
        let median = percentile(dark, 0.5);
        let mut deviations: Vec<f32> = dark.iter().map(|&y| (y - median).abs()).collect();
        deviations.sort_by(f32::total_cmp);
        median + 6.0 * 1.4826 * percentile(&deviations, 0.5)
    } else {
        bg
    };
    let thr = (bg + 0.05 * (level - bg)).max(noise_floor.min(half));
    // coarse circle from the mask
    let (mut sx, mut sy, mut n) = (0.0f64, 0.0f64, 0usize);
    for y in 0..h {
        for x in 0..w {
            if lum[y * w + x] > thr {
                sx += x as f64 + 0.5;
                sy += y as f64 + 0.5;
                n += 1;
            }
        }
    }
    if n < 16 {
        return Err(DetectError::NoContrast);
    }
    let mut circle = (
        sx / n as f64,
        sy / n as f64,
        (n as f64 / std::f64::consts::PI).sqrt(),
    );
    let mut used = 0;
    let mut rms = f64::NAN;
    let at = |x: usize, y: usize| lum[y * w + x];
    for _round in 0..5 {
        let (cx, cy, r) = circle;
        let mut points: Vec<(f64, f64)> = Vec::new();
        // rows
        for y in 0..h {
            if ((y as f64 + 0.5) - cy).abs() >= 0.7 * r {
                continue;
            }
            let line: Vec<f32> = (0..w).map(|x| at(x, y)).collect();
            points.extend(
                line_edges(&line, bg, thr)
                    .into_iter()
                    .map(|e| (e, y as f64 + 0.5)),
            );
        }
        // columns
        for x in 0..w {
            if ((x as f64 + 0.5) - cx).abs() >= 0.7 * r {
                continue;
            }
            let line: Vec<f32> = (0..h).map(|y| at(x, y)).collect();
            points.extend(
                line_edges(&line, bg, thr)
                    .into_iter()
                    .map(|e| (x as f64 + 0.5, e)),
            );
        }
        if points.len() < 8 {
            return Err(DetectError::TooFewPoints(points.len()));
        }
        // keep points near the current circle (drops edges of bright objects inside it)
        let near: Vec<(f64, f64)> = points
            .iter()
            .copied()
            .filter(|&(x, y)| ((x - cx).hypot(y - cy) - r).abs() < 0.1 * r + 3.0)
            .collect();
        let pts = if near.len() >= 8 { near } else { points };
        let mut fit = kasa_fit(&pts).unwrap_or(circle);
        let mut inliers = pts.clone();
        for _ in 0..4 {
            let res: Vec<f64> = pts
                .iter()
                .map(|&(x, y)| (x - fit.0).hypot(y - fit.1) - fit.2)
                .collect();
            let mut abs: Vec<f64> = res.iter().map(|r| r.abs()).collect();
            abs.sort_by(f64::total_cmp);
            let mad = abs[abs.len() / 2];
            let cut = (3.0 * 1.4826 * mad).max(0.25);
            inliers = pts
                .iter()
                .zip(&res)
                .filter(|(_, r)| r.abs() <= cut)
                .map(|(p, _)| *p)
                .collect();
            if inliers.len() < 8 {
                return Err(DetectError::TooFewPoints(inliers.len()));
            }
            fit = geometric_fit(&inliers, fit);
        }
        used = inliers.len();
        rms = (inliers
            .iter()
            .map(|&(x, y)| ((x - fit.0).hypot(y - fit.1) - fit.2).powi(2))
            .sum::<f64>()
            / used as f64)
            .sqrt();
        circle = fit;
    }
    if !(circle.0.is_finite() && circle.1.is_finite() && circle.2.is_finite() && circle.2 > 0.0) {
        return Err(DetectError::TooFewPoints(0));
    }
    // A half-bright frame fits a huge circle far outside it, a bright rectangle a circle its
    // corners miss by pixels: a fisheye's circle is centred in the frame, no larger than its
    // diagonal, and its edge points lie on it to within 2% of the radius (half a pixel for
    // small circles).
    let not_a_circle = |reason| DetectError::NotACircle {
        center: [circle.0, circle.1],
        radius: circle.2,
        rms_residual: rms,
        reason,
    };
    if !((0.0..=w as f64).contains(&circle.0) && (0.0..=h as f64).contains(&circle.1)) {
        return Err(not_a_circle("its centre is outside the frame"));
    }
    if circle.2 > (w as f64).hypot(h as f64) {
        return Err(not_a_circle("it is larger than the frame's diagonal"));
    }
    if rms.is_nan() || rms > (0.02 * circle.2).max(0.5) {
        return Err(not_a_circle(
            "the edge points are not on a circle (more than 2% of the radius off it)",
        ));
    }
    Ok(ImageCircle {
        center: [circle.0, circle.1],
        radius: circle.2,
        points: used,
        rms_residual: rms,
    })
}

/// Sub-pixel positions (continuous coordinate along the line) of the first rising and the last
/// falling edge of a line of luminances.
fn line_edges(line: &[f32], bg: f32, thr: f32) -> Vec<f64> {
    let n = line.len();
    let mut out = Vec::with_capacity(2);
    let Some(first) = line.iter().position(|&v| v > thr) else {
        return out;
    };
    let last = line.iter().rposition(|&v| v > thr).unwrap_or(first);
    const WIN: usize = 4;
    let median3 = |a: f32, b: f32, c: f32| a.max(b).min(a.min(b).max(c));
    let coverage = |v: f32, inside: f32| f64::from(((v - bg) / (inside - bg)).clamp(0.0, 1.0));
    // rising edge: window [first − 1, first + 3), inside = the next 3 pixels
    if first >= 1 && first + WIN + 2 < n && last > first + 2 * WIN + 3 {
        let s = first - 1;
        let inside = median3(line[s + WIN], line[s + WIN + 1], line[s + WIN + 2]);
        if inside > thr {
            let covered: f64 = (s..s + WIN).map(|i| coverage(line[i], inside)).sum();
            out.push((s + WIN) as f64 - covered);
        }
    }
    // falling edge: window (last − 3 ..= last + 1], inside = the 3 pixels before it
    if last + 2 <= n && last >= WIN + 2 && last > first + 2 * WIN + 3 {
        let s = last + 2 - WIN; // window [s, last + 2)
        let inside = median3(line[s - 1], line[s - 2], line[s - 3]);
        if inside > thr {
            let covered: f64 = (s..s + WIN).map(|i| coverage(line[i], inside)).sum();
            out.push(s as f64 + covered);
        }
    }
    out
}

/// Algebraic circle fit: minimises Σ (x² + y² + D x + E y + F)².
fn kasa_fit(pts: &[(f64, f64)]) -> Option<(f64, f64, f64)> {
    let n = pts.len() as f64;
    let (mx, my) = pts
        .iter()
        .fold((0.0, 0.0), |a, p| (a.0 + p.0 / n, a.1 + p.1 / n));
    let (mut suu, mut svv, mut suv, mut suuu, mut svvv, mut suvv, mut svuu) =
        (0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
    for &(x, y) in pts {
        let (u, v) = (x - mx, y - my);
        suu += u * u;
        svv += v * v;
        suv += u * v;
        suuu += u * u * u;
        svvv += v * v * v;
        suvv += u * v * v;
        svuu += v * u * u;
    }
    let det = suu * svv - suv * suv;
    if det.abs() < 1e-12 {
        return None;
    }
    let (b1, b2) = (0.5 * (suuu + suvv), 0.5 * (svvv + svuu));
    let uc = (b1 * svv - b2 * suv) / det;
    let vc = (suu * b2 - suv * b1) / det;
    let r = (uc * uc + vc * vc + (suu + svv) / n).sqrt();
    Some((uc + mx, vc + my, r))
}

/// Gauss–Newton on the geometric residuals, from `start`.
fn geometric_fit(pts: &[(f64, f64)], start: (f64, f64, f64)) -> (f64, f64, f64) {
    let (mut cx, mut cy, mut r) = start;
    for _ in 0..20 {
        let mut jtj = [[0.0f64; 3]; 3];
        let mut jtr = [0.0f64; 3];
        for &(x, y) in pts {
            let d = (x - cx).hypot(y - cy).max(1e-12);
            let res = d - r;
            let j = [-(x - cx) / d, -(y - cy) / d, -1.0];
            for a in 0..3 {
                jtr[a] += j[a] * res;
                for b in 0..3 {
                    jtj[a][b] += j[a] * j[b];
                }
            }
        }
        let Some(step) = solve3(jtj, jtr) else {
            break;
        };
        cx -= step[0];
        cy -= step[1];
        r -= step[2];
        if step.iter().map(|s| s.abs()).fold(0.0, f64::max) < 1e-9 {
            break;
        }
    }
    (cx, cy, r)
}

fn solve3(a: [[f64; 3]; 3], b: [f64; 3]) -> Option<[f64; 3]> {
    let det = |m: [[f64; 3]; 3]| {
        m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
            - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
            + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
    };
    let d = det(a);
    if !(d.abs() > 1e-300 && d.is_finite()) {
        return None;
    }
    let mut x = [0.0; 3];
    for (k, xk) in x.iter_mut().enumerate() {
        let mut m = a;
        for i in 0..3 {
            m[i][k] = b[i];
        }
        *xk = det(m) / d;
    }
    Some(x)
}

/// Renders a `width`×`height` fisheye frame of a lat-long map (`lw`×`lh` pixels, DESIGN.md's
/// convention) through `calibration`, averaging `supersample`² sub-pixel samples per pixel
/// (nearest lat-long pixel each). Sub-samples outside the image circle are black, so rim pixels
/// are partially covered, as with a real lens.
pub fn render_fisheye(
    latlong: &[[f32; 3]],
    lw: u32,
    lh: u32,
    calibration: &FisheyeCalibration,
    width: u32,
    height: u32,
    supersample: u32,
) -> Vec<[f32; 3]> {
    let s = supersample.max(1);
    let mut out = vec![[0.0f32; 3]; width as usize * height as usize];
    if latlong.len() != lw as usize * lh as usize || lw == 0 || lh == 0 {
        return out;
    }
    let proj = Projection::Fisheye(*calibration);
    let inv = 1.0 / f64::from(s * s);
    for y in 0..height {
        for x in 0..width {
            let mut sum = [0.0f64; 3];
            for j in 0..s {
                for i in 0..s {
                    let px = f64::from(x) + (f64::from(i) + 0.5) / f64::from(s);
                    let py = f64::from(y) + (f64::from(j) + 0.5) / f64::from(s);
                    let Some(d) = proj.pixel_to_direction(width, height, px, py) else {
                        continue;
                    };
                    let Some((u, v)) = Projection::LatLong.direction_to_pixel(lw, lh, d) else {
                        continue;
                    };
                    let ui = (u.floor() as i64).rem_euclid(i64::from(lw)) as usize;
                    let vi = (v.floor().max(0.0) as usize).min(lh as usize - 1);
                    let p = latlong[vi * lw as usize + ui];
                    for c in 0..3 {
                        sum[c] += f64::from(p[c]);
                    }
                }
            }
            out[(y * width + x) as usize] = sum.map(|v| (v * inv) as f32);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fits_recover_exact_circles() {
        let pts: Vec<(f64, f64)> = (0..40)
            .map(|k| {
                let a = k as f64 * 0.3;
                (10.0 + 5.0 * a.cos(), -3.0 + 5.0 * a.sin())
            })
            .collect();
        let (cx, cy, r) = kasa_fit(&pts).unwrap();
        assert!((cx - 10.0).abs() < 1e-9 && (cy + 3.0).abs() < 1e-9 && (r - 5.0).abs() < 1e-9);
        let (cx, cy, r) = geometric_fit(&pts, (9.0, -2.0, 4.0));
        assert!((cx - 10.0).abs() < 1e-9 && (cy + 3.0).abs() < 1e-9 && (r - 5.0).abs() < 1e-9);
    }

    #[test]
    fn flat_and_tiny_images_are_errors() {
        assert!(detect_image_circle(&[[1.0; 3]; 64 * 64], 64, 64).is_err());
        assert!(detect_image_circle(&[[1.0; 3]; 4], 2, 2).is_err());
        assert!(detect_image_circle(&[[1.0; 3]; 10], 64, 64).is_err());
        let nan = vec![[f32::NAN; 3]; 32 * 32];
        assert!(detect_image_circle(&nan, 32, 32).is_err());
    }

    #[test]
    fn uniform_disc_edges_are_sub_pixel() {
        let cal = FisheyeCalibration {
            center: Some([40.3, 33.6]),
            radius: Some(27.7),
            ..Default::default()
        };
        let img = render_fisheye(&[[1.0; 3]; 8], 4, 2, &cal, 80, 64, 8);
        let c = detect_image_circle(&img, 80, 64).unwrap();
        assert!((c.center[0] - 40.3).abs() < 0.05, "{c:?}");
        assert!((c.center[1] - 33.6).abs() < 0.05, "{c:?}");
        assert!((c.radius - 27.7).abs() < 0.05, "{c:?}");
    }

    /// A surround with a sensor's dark noise (black level 16 of 255, σ = 1, 2 and 3 codes,
    /// quantised; the image circle at 100 codes) is found within 0.1 pixel: the threshold
    /// lay inside the noise, and rows began and ended at noise pixels (rms residual 5 px).
    #[test]
    fn a_noisy_surround_is_not_the_rim() {
        let (w, h, centre, radius) = (320u32, 240u32, (161.3, 118.7), 100.2);
        let mut state = 3u64;
        let mut gauss = || {
            // Box–Muller on a SplitMix-like generator
            let mut uniform = || {
                state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
                let mut z = state;
                z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
                z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
                ((z ^ (z >> 31)) >> 11) as f64 / (1u64 << 53) as f64
            };
            let (u, v) = (uniform().max(1e-12), uniform());
            (-2.0 * u.ln()).sqrt() * (std::f64::consts::TAU * v).cos()
        };
        for sigma in [1.0, 2.0, 3.0] {
            let img: Vec<[f32; 3]> = (0..w * h)
                .map(|i| {
                    let (x, y) = (f64::from(i % w), f64::from(i / w));
                    // coverage of the pixel by the disc, 4×4 samples
                    let inside = (0..16)
                        .filter(|k| {
                            let (sx, sy) = (
                                x + (f64::from(k % 4) + 0.5) / 4.0,
                                y + (f64::from(k / 4) + 0.5) / 4.0,
                            );
                            (sx - centre.0).hypot(sy - centre.1) < radius
                        })
                        .count() as f64
                        / 16.0;
                    let code = (16.0 + inside * 84.0 + sigma * gauss())
                        .round()
                        .clamp(0.0, 255.0);
                    [(code / 255.0) as f32; 3]
                })
                .collect();
            let c = detect_image_circle(&img, w, h).unwrap_or_else(|e| panic!("σ {sigma}: {e}"));
            assert!((c.center[0] - centre.0).abs() < 0.1, "σ {sigma}: {c:?}");
            assert!((c.center[1] - centre.1).abs() < 0.1, "σ {sigma}: {c:?}");
            assert!((c.radius - radius).abs() < 0.1, "σ {sigma}: {c:?}");
        }
    }

    /// A disc of 0.7 on a 0.01 surround, `w`×`h`, pixel centres within `radius` of `centre`.
    fn disc(w: u32, h: u32, centre: (f64, f64), radius: f64) -> Vec<[f32; 3]> {
        (0..w * h)
            .map(|i| {
                let (x, y) = (f64::from(i % w) + 0.5, f64::from(i / w) + 0.5);
                let inside = (x - centre.0).hypot(y - centre.1) <= radius;
                [if inside { 0.7 } else { 0.01 }; 3]
            })
            .collect()
    }

    /// A circle covering less than 40% of the frame is found (the 60th percentile was the
    /// surround, and detection said "no contrast").
    #[test]
    fn small_circles_are_found() {
        for radius in [20.0, 30.0, 38.0] {
            let img = disc(128, 96, (64.0, 48.0), radius);
            let c = detect_image_circle(&img, 128, 96).unwrap();
            assert!((c.radius - radius).abs() < 1.0, "{radius}: {c:?}");
            assert!((c.center[0] - 64.0).abs() < 0.5 && (c.center[1] - 48.0).abs() < 0.5);
        }
    }

    /// A circle cropped by the frame's top and bottom, whose dark corners are under 5% of the
    /// frame, is found (the 5th percentile lay inside it: "no contrast"; an audit): radius 350
    /// and 380 in 640×480 leave 3.7% and 1.4% dark. A frame with no dark part at all still
    /// has no contrast.
    #[test]
    fn circles_cropped_by_the_frame_are_found() {
        let (w, h) = (640u32, 480u32);
        for radius in [350.0, 380.0] {
            let img = disc(w, h, (320.0, 240.0), radius);
            let dark = img.iter().filter(|p| p[0] < 0.5).count() as f64 / img.len() as f64;
            assert!(dark < 0.05, "{radius}: {dark}");
            let c = detect_image_circle(&img, w, h).unwrap_or_else(|e| panic!("{radius}: {e}"));
            assert!((c.radius - radius).abs() < 0.5, "{radius}: {c:?}");
            assert!((c.center[0] - 320.0).abs() < 0.5 && (c.center[1] - 240.0).abs() < 0.5);
        }
        let full = disc(w, h, (320.0, 240.0), 1000.0);
        assert_eq!(
            detect_image_circle(&full, w, h),
            Err(DetectError::NoContrast)
        );
    }

    /// Edges that are no image circle: a half-lit frame (its straight edge fitted a circle of
    /// radius 139,000 centred far outside) and a bright rectangle.
    #[test]
    fn edges_that_are_no_circle_are_errors() {
        let (w, h) = (64u32, 48u32);
        let half: Vec<[f32; 3]> = (0..w * h)
            .map(|i| [if i % w < w / 2 { 1.0 } else { 0.0 }; 3])
            .collect();
        let e = detect_image_circle(&half, w, h).unwrap_err();
        assert!(matches!(e, DetectError::NotACircle { .. }), "{e}");
        let rect: Vec<[f32; 3]> = (0..w * h)
            .map(|i| {
                let (x, y) = (i % w, i / w);
                [if (16..48).contains(&x) && (8..40).contains(&y) {
                    1.0
                } else {
                    0.0
                }; 3]
            })
            .collect();
        let e = detect_image_circle(&rect, w, h).unwrap_err();
        assert!(e.to_string().contains("not on a circle"), "{e}");
    }
}
