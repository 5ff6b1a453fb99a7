//! Evaluation of lighting representations against the full map (Clausen et al. 2024, §Results):
//! GGX balls, map PSNR, energy error, and the spherical-harmonics baseline.
//!
//! - [`render_ball`]: an orthographic view (from +Z, looking along −Z) of a unit sphere with a
//!   GGX microfacet surface (roughness α used directly as the GGX α, F = 1, Smith
//!   height-correlated masking), lit by a lat-long radiance map; the CPU reference integrates
//!   the map pixel by pixel: L_o = Σ_p L_p Ω_p · D G₂ / (4 n·v) (n·l cancels with the BRDF's).
//!   A representation is rendered by reconstructing its map at the same pixels, so the balls
//!   compare lighting, not shading approximations.
//! - [`relative_rms`]: √(Σ(Δ lum)²) / √(Σ lum²) over ball pixels.
//! - [`map_psnr`]: PSNR of the map after exposing both maps so the truth's mean luminance is
//!   0.18 and clamping to [0, 1] (display-referred; HDR peaks such as the sun would otherwise
//!   dominate), solid-angle-weighted mean squared error over the RGB channels.
//! - [`ShProjection`]: real spherical harmonics of order 2 (l ≤ 1, 4 coefficients per channel)
//!   or 3 (l ≤ 2, 9), projected by summing over the map's pixels.

use crate::decompose::luminance_f64 as lum;
use crate::envmap::Projection;
use glam::DVec3;
use std::f64::consts::PI;

/// A lat-long radiance map with its pixel directions and solid angles.
#[derive(Clone, Debug)]
pub struct LatLongMap {
    pub width: u32,
    pub height: u32,
    pub radiance: Vec<[f64; 3]>,
    pub directions: Vec<DVec3>,
    pub solid_angles: Vec<f64>,
}

impl LatLongMap {
    /// A map of `width × height` pixels whose radiance is `f(direction)`.
    pub fn from_fn(width: u32, height: u32, f: impl Fn(DVec3) -> [f64; 3]) -> Self {
        let directions = directions(width, height);
        let radiance = directions.iter().map(|&d| f(d)).collect();
        Self {
            width,
            height,
            radiance,
            directions,
            solid_angles: Projection::LatLong.solid_angles(width, height),
        }
    }

    /// A map from radiance values (row-major, `width × height`); `None` if the count is wrong.
    pub fn new(width: u32, height: u32, radiance: Vec<[f64; 3]>) -> Option<Self> {
        (radiance.len() == width as usize * height as usize && width > 0 && height > 0).then(|| {
            Self {
                width,
                height,
                radiance,
                directions: directions(width, height),
                solid_angles: Projection::LatLong.solid_angles(width, height),
            }
        })
    }

    /// Box-downsamples by `factor` (both sides must divide), preserving Σ L·Ω.
    pub fn downsample(&self, factor: u32) -> Option<Self> {
        let f = factor.max(1);
        if !self.width.is_multiple_of(f) || !self.height.is_multiple_of(f) {
            return None;
        }
        let (w, h) = (self.width / f, self.height / f);
        let mut acc = vec![([0.0; 3], 0.0); w as usize * h as usize];
        for y in 0..self.height {
            for x in 0..self.width {
                let i = (y * self.width + x) as usize;
                let o = self.solid_angles[i];
                let cell = &mut acc[((y / f) * w + x / f) as usize];
                for c in 0..3 {
                    cell.0[c] += self.radiance[i][c] * o;
                }
                cell.1 += o;
            }
        }
        Self::new(
            w,
            h,
            acc.into_iter().map(|(e, o)| e.map(|v| v / o)).collect(),
        )
    }

    /// ∫ L dω per channel.
    pub fn integral(&self) -> [f64; 3] {
        let mut s = [0.0; 3];
        for (p, o) in self.radiance.iter().zip(&self.solid_angles) {
            for c in 0..3 {
                s[c] += p[c] * o;
            }
        }
        s
    }
}

fn directions(width: u32, height: u32) -> Vec<DVec3> {
    let mut out = Vec::with_capacity(width as usize * height as usize);
    for y in 0..height {
        for x in 0..width {
            out.push(
                Projection::LatLong
                    .pixel_to_direction(width, height, f64::from(x) + 0.5, f64::from(y) + 0.5)
                    .unwrap_or(DVec3::Y),
            );
        }
    }
    out
}

/// GGX NDF D(n·h) for roughness α.
#[inline]
pub fn ggx_d(n_h: f64, alpha: f64) -> f64 {
    let a2 = alpha * alpha;
    let t = n_h * n_h * (a2 - 1.0) + 1.0;
    a2 / (PI * t * t)
}

/// Smith height-correlated Λ(cos) for GGX.
#[inline]
fn smith_lambda(cos: f64, a2: f64) -> f64 {
    let c2 = (cos * cos).max(1e-12);
    ((1.0 + a2 * (1.0 / c2 - 1.0)).sqrt() - 1.0) / 2.0
}

/// Radiance reflected towards `view` at normal `n` by a GGX surface (F = 1) lit by `map`:
/// Σ_p L_p Ω_p D G₂ / (4 n·v), the CPU reference.
pub fn ggx_reference(map: &LatLongMap, n: DVec3, view: DVec3, alpha: f64) -> [f64; 3] {
    let n_v = n.dot(view);
    if n_v <= 0.0 {
        return [0.0; 3];
    }
    let a2 = alpha * alpha;
    let lv = smith_lambda(n_v, a2);
    let mut acc = [0.0; 3];
    for ((l, p), o) in map
        .directions
        .iter()
        .zip(&map.radiance)
        .zip(&map.solid_angles)
    {
        let n_l = n.dot(*l);
        if n_l <= 0.0 {
            continue;
        }
        let h = (*l + view).normalize_or_zero();
        let d = ggx_d(n.dot(h), alpha);
        let g2 = 1.0 / (1.0 + lv + smith_lambda(n_l, a2));
        let k = d * g2 / (4.0 * n_v) * o;
        for c in 0..3 {
            acc[c] += p[c] * k;
        }
    }
    acc
}

/// Renders a `res × res` ball (module doc) under `map`; pixels off the ball are `None`.
pub fn render_ball(map: &LatLongMap, alpha: f64, res: u32) -> Vec<Option<[f64; 3]>> {
    let view = DVec3::Z;
    let mut out = Vec::with_capacity(res as usize * res as usize);
    for j in 0..res {
        for i in 0..res {
            let x = 2.0 * (f64::from(i) + 0.5) / f64::from(res) - 1.0;
            let y = 1.0 - 2.0 * (f64::from(j) + 0.5) / f64::from(res);
            let r2 = x * x + y * y;
            if r2 >= 1.0 {
                out.push(None);
                continue;
            }
            let n = DVec3::new(x, y, (1.0 - r2).sqrt());
            out.push(Some(ggx_reference(map, n, view, alpha)));
        }
    }
    out
}

/// √(Σ(Δ lum)²) / √(Σ lum²) over the pixels both images have.
pub fn relative_rms(approx: &[Option<[f64; 3]>], truth: &[Option<[f64; 3]>]) -> f64 {
    let (mut num, mut den) = (0.0, 0.0);
    for (a, t) in approx.iter().zip(truth) {
        if let (Some(a), Some(t)) = (a, t) {
            let (la, lt) = (lum(*a), lum(*t));
            num += (la - lt) * (la - lt);
            den += lt * lt;
        }
    }
    if den > 0.0 {
        (num / den).sqrt()
    } else if num > 0.0 {
        f64::INFINITY
    } else {
        0.0
    }
}

/// Display-referred PSNR (dB) of `approx` against `truth` (module doc); +∞ when identical.
pub fn map_psnr(approx: &LatLongMap, truth: &LatLongMap) -> f64 {
    let total: f64 = truth.solid_angles.iter().sum();
    let mean_lum: f64 = truth
        .radiance
        .iter()
        .zip(&truth.solid_angles)
        .map(|(p, o)| lum(*p) * o)
        .sum::<f64>()
        / total;
    let exposure = if mean_lum > 0.0 { 0.18 / mean_lum } else { 1.0 };
    let mut mse = 0.0;
    for ((a, t), o) in approx
        .radiance
        .iter()
        .zip(&truth.radiance)
        .zip(&truth.solid_angles)
    {
        for c in 0..3 {
            let d = (a[c] * exposure).clamp(0.0, 1.0) - (t[c] * exposure).clamp(0.0, 1.0);
            mse += d * d * o;
        }
    }
    mse /= 3.0 * total;
    if mse > 0.0 {
        -10.0 * mse.log10()
    } else {
        f64::INFINITY
    }
}

/// |lum(approx) − lum(truth)| / lum(truth) of two integrals.
pub fn energy_error(approx: [f64; 3], truth: [f64; 3]) -> f64 {
    let t = lum(truth);
    if t > 0.0 {
        (lum(approx) - t).abs() / t
    } else {
        lum(approx).abs()
    }
}

/// Real spherical harmonics Y_lm for l ≤ 2 at unit `d` (9 values, l-major).
pub fn sh_basis(d: DVec3) -> [f64; 9] {
    let (x, y, z) = (d.x, d.y, d.z);
    [
        0.282_094_791_773_878_1,
        0.488_602_511_902_919_9 * y,
        0.488_602_511_902_919_9 * z,
        0.488_602_511_902_919_9 * x,
        1.092_548_430_592_079_2 * x * y,
        1.092_548_430_592_079_2 * y * z,
        0.315_391_565_252_520_05 * (3.0 * z * z - 1.0),
        1.092_548_430_592_079_2 * x * z,
        0.546_274_215_296_039_6 * (x * x - y * y),
    ]
}

/// A spherical-harmonics projection of a map: `order` 2 (4 coefficients) or 3 (9).
#[derive(Clone, Debug, PartialEq)]
pub struct ShProjection {
    pub order: usize,
    pub coefficients: Vec<[f64; 3]>,
}

impl ShProjection {
    /// Projects `map` onto the SH basis of `order` (clamped to 1..=3).
    pub fn project(map: &LatLongMap, order: usize) -> Self {
        let order = order.clamp(1, 3);
        let n = order * order;
        let mut coefficients = vec![[0.0; 3]; n];
        for ((d, p), o) in map
            .directions
            .iter()
            .zip(&map.radiance)
            .zip(&map.solid_angles)
        {
            let y = sh_basis(*d);
            for k in 0..n {
                for c in 0..3 {
                    coefficients[k][c] += p[c] * y[k] * o;
                }
            }
        }
        Self {
            order,
            coefficients,
        }
    }

    /// Radiance towards `d`.
    pub fn eval(&self, d: DVec3) -> [f64; 3] {
        let y = sh_basis(d);
        let mut out = [0.0; 3];
        for (k, c3) in self.coefficients.iter().enumerate() {
            for c in 0..3 {
                out[c] += c3[c] * y[k];
            }
        }
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ggx_reference_of_a_white_furnace_is_the_directional_albedo() {
        // Under uniform radiance 1 the reflected radiance is the directional albedo: for α = 0.3
        // at normal incidence 0.87736 (a 4000-node 1-D integral over the polar angle).
        let map = LatLongMap::from_fn(512, 256, |_| [1.0; 3]);
        let r = ggx_reference(&map, DVec3::Z, DVec3::Z, 0.3)[0];
        assert!((r - 0.87736).abs() < 2e-3, "{r}");
    }

    #[test]
    fn sh_projection_reproduces_a_linear_function() {
        let map = LatLongMap::from_fn(128, 64, |d| [1.0 + 0.5 * d.y, 1.0, 1.0 - 0.3 * d.x]);
        let sh = ShProjection::project(&map, 2);
        let d = DVec3::new(0.3, 0.5, -0.81).normalize();
        let v = sh.eval(d);
        assert!((v[0] - (1.0 + 0.5 * d.y)).abs() < 1e-3, "{v:?}");
        assert!((v[2] - (1.0 - 0.3 * d.x)).abs() < 1e-3, "{v:?}");
    }

    #[test]
    fn psnr_is_infinite_for_identical_maps_and_finite_otherwise() {
        let a = LatLongMap::from_fn(16, 8, |d| [d.y.max(0.0); 3]);
        assert!(map_psnr(&a, &a).is_infinite());
        let b = LatLongMap::from_fn(16, 8, |d| [d.y.max(0.0) * 0.5; 3]);
        assert!(map_psnr(&b, &a).is_finite());
    }
}
