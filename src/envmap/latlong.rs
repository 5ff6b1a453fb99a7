//! Lat-long (equirectangular) projection in DESIGN.md's convention: pixel (x, y) is the patch
//! around u = (x + 0.5)/W, v = (y + 0.5)/H, θ = πv, φ = 2πu, d = (sin θ sin φ, cos θ,
//! −sin θ cos φ). The axes and column centres are Mitsuba 3's; Mitsuba puts row y at
//! θ = πy/(H − 1) instead (docs/quality.md, "Cross-check with Mitsuba 3").

use glam::DVec3;
use std::f64::consts::PI;

/// Direction at continuous pixel position (x, y).
pub fn pixel_to_direction(width: u32, height: u32, x: f64, y: f64) -> DVec3 {
    let phi = 2.0 * PI * x / f64::from(width);
    let theta = PI * y / f64::from(height);
    let (sin_t, cos_t) = theta.sin_cos();
    let (sin_p, cos_p) = phi.sin_cos();
    DVec3::new(sin_t * sin_p, cos_t, -sin_t * cos_p)
}

/// Continuous pixel position of direction `d`; x in [0, W), y in [0, H].
pub fn direction_to_pixel(width: u32, height: u32, d: DVec3) -> Option<(f64, f64)> {
    let len = d.length();
    if len <= 0.0 || !len.is_finite() {
        return None;
    }
    let d = d / len;
    let theta = d.y.clamp(-1.0, 1.0).acos();
    let mut phi = d.x.atan2(-d.z);
    if phi < 0.0 {
        phi += 2.0 * PI;
    }
    let x = (phi / (2.0 * PI) * f64::from(width)).min(f64::from(width) - 1e-9);
    Some((x.max(0.0), theta / PI * f64::from(height)))
}

/// Exact per-pixel solid angles: (2π/W)(cos θ_top − cos θ_bottom). To second order this is
/// DESIGN.md's (2π/W)(π/H) sin θ_centre; the exact form sums to 4π.
pub fn solid_angles(width: u32, height: u32) -> Vec<f64> {
    let mut out = Vec::with_capacity(width as usize * height as usize);
    for y in 0..height {
        let (x0, y0) = (0.0, f64::from(y));
        let omega = rectangle_solid_angle(width, height, (x0, y0), (x0 + 1.0, y0 + 1.0));
        out.extend(std::iter::repeat_n(omega, width as usize));
    }
    out
}

/// Exact solid angle of the image rectangle from `(x0, y0)` to `(x1, y1)` (continuous pixel
/// positions, clamped to the image): (2π·Δx/W)(cos θ(y0) − cos θ(y1)).
pub fn rectangle_solid_angle(
    width: u32,
    height: u32,
    (x0, y0): (f64, f64),
    (x1, y1): (f64, f64),
) -> f64 {
    let (w, h) = (f64::from(width), f64::from(height));
    let (x0, x1) = (x0.clamp(0.0, w), x1.clamp(0.0, w));
    let (y0, y1) = (y0.clamp(0.0, h), y1.clamp(0.0, h));
    let theta = |y: f64| PI * y / h;
    let omega = 2.0 * PI * (x1 - x0) / w * (theta(y0).cos() - theta(y1).cos());
    omega.max(0.0)
}

/// The intervals two partitions of [0, 1) into `from` and `to` equal parts share, as
/// (source part, target part, overlap length), in order of both parts. A lat-long map's
/// columns (and, by their θ, its rows) are such a partition: the ASG fit's target and the
/// decomposition's working map resample by exact area overlap with it.
pub(crate) fn interval_overlaps(from: u32, to: u32) -> Vec<(usize, usize, f64)> {
    let (from, to) = (from as usize, to as usize);
    let mut pairs = Vec::with_capacity(from + to);
    let (mut i, mut j) = (0usize, 0usize);
    // Exact in integers: part i is [i·to, (i + 1)·to) in units of 1/(from·to).
    while i < from && j < to {
        let lo = (i * to).max(j * from);
        let hi = ((i + 1) * to).min((j + 1) * from);
        if hi > lo {
            pairs.push((i, j, (hi - lo) as f64 / (from * to) as f64));
        }
        if (i + 1) * to <= (j + 1) * from {
            i += 1;
        } else {
            j += 1;
        }
    }
    pairs
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn conventions_of_design_md() {
        let d = pixel_to_direction(4, 2, 0.0, 1.0);
        assert!(
            (d - DVec3::new(0.0, 0.0, -1.0)).length() < 1e-12,
            "u=0 looks along -Z"
        );
        let d = pixel_to_direction(4, 2, 1.0, 1.0);
        assert!((d - DVec3::X).length() < 1e-12, "u=0.25 looks along +X");
        let d = pixel_to_direction(4, 2, 2.0, 1.0);
        assert!((d - DVec3::Z).length() < 1e-12, "u=0.5 looks along +Z");
        assert!(
            (pixel_to_direction(4, 2, 1.0, 0.0) - DVec3::Y).length() < 1e-12,
            "row 0 is +Y"
        );
    }

    #[test]
    fn round_trip_and_total_solid_angle() {
        let (w, h) = (64, 32);
        for y in 0..h {
            for x in 0..w {
                let (px, py) = (f64::from(x) + 0.5, f64::from(y) + 0.5);
                let d = pixel_to_direction(w, h, px, py);
                let (qx, qy) = direction_to_pixel(w, h, d).unwrap();
                assert!((qx - px).abs() < 1e-9 && (qy - py).abs() < 1e-9);
            }
        }
        let total: f64 = solid_angles(w, h).iter().sum();
        assert!((total - 4.0 * PI).abs() < 1e-12);
    }
}
