//! Fisheye projections of the upper hemisphere and Debevec's angular map, with exact per-pixel
//! solid angles.
//!
//! # Fisheye (camera looking at the zenith, +Y)
//!
//! The image circle has centre c = (cx, cy) (default: the image centre (W/2, H/2)) and radius R
//! pixels (default: min(W, H)/2). The full field of view `fov_deg` (0 < fov < 360, default 180)
//! puts θ_max = fov/2 on the circle r = R, where θ is the angle from +Y and r = |p − c| the image
//! radius of the continuous pixel position p. The lens model ([`FisheyeModel`]) gives r(θ), with
//! the focal length f chosen so that r(θ_max) = R:
//!
//! | model          | r(θ)          | θ(r) with ρ = r/f   |
//! |----------------|---------------|---------------------|
//! | equidistant    | f·θ           | ρ                   |
//! | equisolid      | 2f·sin(θ/2)   | 2·asin(ρ/2)         |
//! | stereographic  | 2f·tan(θ/2)   | 2·atan(ρ/2)         |
//! | orthographic   | f·sin θ       | asin(ρ)             |
//!
//! The orthographic model cannot image beyond θ = 90° (r(θ) turns back). For fov > 180° the
//! mapping is clamped: it behaves exactly as fov = 180° (f = R, the circle is θ = 90°) and
//! directions below the horizon give `None`; but [`FisheyeCalibration::validate`] and the config
//! reject such a calibration, so a user's field of view is never silently changed.
//!
//! Azimuth: with `rotation_deg` = 0 the image offset (dx, dy) = (x − cx, y − cy) (dy grows down
//! the image) looks along the horizontal unit vector h₀ = (−dx, 0, dy)/r: image up = −Z (the
//! lat-long map's u = 0 direction), image down = +Z, image right = −X. That is what a camera
//! looking up sees: its right is forward × up = (+Y) × (−Z) = −X, so the image is the sky seen
//! from below, the mirror image of a map (lying on your back with your head to the north, east
//! is on your left). `rotation_deg` = ψ rotates every direction right-handedly about +Y
//! (counter-clockwise seen from above, which is clockwise on the image as displayed):
//! h = R_y(ψ)·h₀ with h.x = h₀.x cos ψ + h₀.z sin ψ, h.z = −h₀.x sin ψ + h₀.z cos ψ. So at ψ = 90°
//! image right looks along +Z and image down along +X; in lat-long terms a pixel's azimuth
//! φ = atan2(d.x, −d.z) decreases by ψ. The direction is d = (sin θ·h.x, cos θ, sin θ·h.z).
//! Positions with r > R, and directions with θ > θ_max, give `None`; the centre gives +Y.
//!
//! # Angular map (Debevec)
//!
//! The inscribed disc of the image: centre (W/2, H/2), radius R = min(W, H)/2. With normalised
//! offsets (u, v) = (x − cx, y − cy)/R and ρ = |(u, v)| ≤ 1, θ' = πρ is the angle from −Z (the
//! image centre looks forward, along −Z), image right = +X, image up = +Y:
//! d = (sin θ'·u/ρ, −sin θ'·v/ρ, −cos θ'). The rim ρ = 1 is straight back (+Z); +Z itself is
//! mapped to the rim point below the centre. Radially it is an equidistant fisheye with
//! θ_max = π, so it shares the solid-angle code.
//!
//! # Exact solid angles
//!
//! For a radially symmetric map with θ(r) the solid angle inside radius r is
//! Ω(r) = 2π·G(r) with G(r) = 1 − cos θ(r), and the solid angle per unit image area is
//! g(r) = sin θ·θ'(r)/r = G'(r)/r. With H(r) = G(r)/r² the field F = H(r)·(x, y) has
//! div F = (1/r)·d(r²H)/dr = g, so by Green's theorem the solid angle of a region is the flux
//! ∮ H(r)(x dy − y dx) through its boundary (counter-clockwise in the (dx, dy) plane). A pixel's
//! region is its square clipped to the image disc; its boundary consists of
//!
//! - pieces of the square's edges inside the disc: along A + t(B − A) the integrand is
//!   (A × B)·H(|A + t(B − A)|) dt. H depends on r², which is a quadratic in t, and is smooth
//!   (analytic for all models but the orthographic one at the 90° rim), so an adaptive 7-point
//!   Gauss–Kronrod rule (3-point Gauss for the error estimate, relative tolerance 1e-13) is
//!   essentially exact. Where an edge ends on the circle, the substitution t ∝ u² (or u²(3 − 2u)
//!   for both ends) removes the √ singularity of the orthographic G at the rim. Every edge is
//!   integrated once and shared by its two pixels, so interior edges cancel exactly in the sum;
//! - arcs of the circle: there (x dy − y dx)/r² = dα, so an arc adds G(R)·Δα. The total sweep
//!   Δα is the angle the region subtends at the centre minus the angles subtended by its straight
//!   pieces (atan2(P × Q, P·Q) for piece P→Q), where the region subtends 2π if it contains the
//!   centre, π if the centre lies on an edge, π/2 at a corner, 0 otherwise. Pieces through the
//!   centre subtend nothing (and have A × B = 0).
//!
//! Hence a pixel's solid angle is exact to ≈1e-13 relative, including pixels crossed by the
//! circle or containing the centre, and the image total is 2π(1 − cos θ_max) (4π for the angular
//! map) to rounding when the whole disc lies inside the image. Only pixels within the disc's
//! bounding box are visited; the cost is about 2 edge quadratures (7 evaluations each) per pixel,
//! in bands of rows on rayon's threads (the result does not depend on how many there are). It is
//! a once-per-geometry cost: 1280×960 took 61–198 ms on one thread and 33–101 ms on two, by
//! model (`cargo bench --bench decompose -- solid_angles`; docs/camera.md). Since then the
//! equidistant model's and the angular map's integrand, sin²(ρ/2)/ρ², is a series in ρ² (no
//! square root, no sine, [`sinc_of_square`]): 230–260 → 139–156 ms on one thread, measured
//! side by side (docs/performance.md, "A camera's frames").

use crate::config::shown_number;
use glam::DVec3;
use rayon::prelude::*;
use std::f64::consts::{FRAC_PI_2, PI, TAU};

/// Radial lens model: how the angle θ from the optical axis maps to the image radius r.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum FisheyeModel {
    /// r = f·θ
    #[default]
    Equidistant,
    /// r = 2f·sin(θ/2)
    Equisolid,
    /// r = 2f·tan(θ/2)
    Stereographic,
    /// r = f·sin θ
    Orthographic,
}

impl FisheyeModel {
    /// All models, for tests and command-line help.
    pub const ALL: [FisheyeModel; 4] = [
        FisheyeModel::Equidistant,
        FisheyeModel::Equisolid,
        FisheyeModel::Stereographic,
        FisheyeModel::Orthographic,
    ];

    /// Short name used in logs and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            FisheyeModel::Equidistant => "equidistant",
            FisheyeModel::Equisolid => "equisolid",
            FisheyeModel::Stereographic => "stereographic",
            FisheyeModel::Orthographic => "orthographic",
        }
    }

    /// Largest θ the model can image: π/2 for orthographic, π otherwise.
    fn theta_limit(self) -> f64 {
        match self {
            FisheyeModel::Orthographic => FRAC_PI_2,
            _ => PI,
        }
    }

    /// ρ(θ) = r/f.
    fn rho(self, theta: f64) -> f64 {
        match self {
            FisheyeModel::Equidistant => theta,
            FisheyeModel::Equisolid => 2.0 * (0.5 * theta).sin(),
            FisheyeModel::Stereographic => 2.0 * (0.5 * theta).tan(),
            FisheyeModel::Orthographic => theta.sin(),
        }
    }

    /// θ(ρ), the inverse of [`Self::rho`] (ρ ≥ 0).
    fn theta(self, rho: f64) -> f64 {
        match self {
            FisheyeModel::Equidistant => rho,
            FisheyeModel::Equisolid => 2.0 * (0.5 * rho).min(1.0).asin(),
            FisheyeModel::Stereographic => 2.0 * (0.5 * rho).atan(),
            FisheyeModel::Orthographic => rho.min(1.0).asin(),
        }
    }

    /// (1 − cos θ(ρ))/ρ² as a function of ρ², finite at ρ = 0 (limit 1/2).
    fn cap_ratio(self, rho2: f64) -> f64 {
        match self {
            // 1 − cos ρ = 2 sin²(ρ/2)
            FisheyeModel::Equidistant => {
                let s = sinc_of_square(0.25 * rho2);
                0.5 * s * s
            }
            // cos θ = 1 − ρ²/2
            FisheyeModel::Equisolid => 0.5,
            // cos θ = (1 − ρ²/4)/(1 + ρ²/4)
            FisheyeModel::Stereographic => 0.5 / (1.0 + 0.25 * rho2),
            // 1 − √(1 − ρ²) = ρ²/(1 + √(1 − ρ²))
            FisheyeModel::Orthographic => 1.0 / (1.0 + (1.0 - rho2).max(0.0).sqrt()),
        }
    }
}

/// sin x / x from y = x², for the solid angles' integrands (millions of evaluations per
/// geometry): for y ≤ (π/2)², which holds everywhere inside a fisheye's image circle and the
/// angular map's disc (x = θ/2 ≤ π/2), the Taylor series Σ (−1)ⁿ yⁿ/(2n + 1)! to n = 12
/// (Estrin's scheme), no square root and no sine; the first term left out is below 1e-21 of the
/// sum there, so it agrees with `sin(x)/x` to rounding. Beyond, [`sinc`].
fn sinc_of_square(y: f64) -> f64 {
    /// (−1)ⁿ/(2n + 1)! for n = 0..=12.
    const COEFFICIENTS: [f64; 13] = {
        let mut c = [0.0; 13];
        let mut factorial = 1.0;
        let mut n = 0;
        while n < 13 {
            if n > 0 {
                factorial *= ((2 * n) * (2 * n + 1)) as f64;
            }
            c[n] = if n % 2 == 0 { 1.0 } else { -1.0 } / factorial;
            n += 1;
        }
        c
    };
    if y > 2.5 || y.is_nan() {
        return sinc(y.sqrt());
    }
    // Estrin's scheme: pairs, then pairs of pairs, so that the multiplications overlap (a
    // Horner chain of twelve waits for each in turn).
    let c = &COEFFICIENTS;
    let (y2, pair) = (y * y, |n: usize| c[n] + c[n + 1] * y);
    let y4 = y2 * y2;
    let low = (pair(0) + pair(2) * y2) + (pair(4) + pair(6) * y2) * y4;
    let high = (pair(8) + pair(10) * y2) + c[12] * y4;
    low + high * (y4 * y4)
}

/// sin x / x, accurate near 0.
fn sinc(x: f64) -> f64 {
    if x.abs() < 1e-4 {
        1.0 - x * x / 6.0
    } else {
        x.sin() / x
    }
}

/// Calibration of a zenith-looking fisheye camera.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct FisheyeCalibration {
    pub model: FisheyeModel,
    /// Image-circle centre in pixels; `None` = the image centre.
    pub center: Option<[f64; 2]>,
    /// Image-circle radius in pixels; `None` = half the shorter image side.
    pub radius: Option<f64>,
    /// Full field of view across the image circle, degrees (180 = the hemisphere).
    pub fov_deg: f64,
    /// Rotation about the zenith, degrees.
    pub rotation_deg: f64,
}

impl Default for FisheyeCalibration {
    fn default() -> Self {
        Self {
            model: FisheyeModel::Equidistant,
            center: None,
            radius: None,
            fov_deg: 180.0,
            rotation_deg: 0.0,
        }
    }
}

/// The narrowest field of view a fisheye calibration accepts, degrees: a lens of under a degree
/// is no fisheye (1e-308 was accepted and mapped the image circle onto a point).
pub const MIN_FOV_DEG: f64 = 1.0;

/// Why a calibration cannot be used for an image.
#[derive(Clone, Copy, Debug, PartialEq, thiserror::Error)]
enum CalibrationError {
    #[error("image size {width}x{height} has no pixels")]
    EmptyImage { width: u32, height: u32 },
    #[error("fisheye fov_deg = {} must be in [1, 360) degrees", shown_number(*.0))]
    FieldOfView(f64),
    #[error("fisheye radius = {} must be a number of pixels in (0, 1e6]", shown_number(*.0))]
    Radius(f64),
    #[error("fisheye center = [{}, {}] must be finite pixel coordinates", shown_number(*.0), shown_number(*.1))]
    Center(f64, f64),
    #[error("fisheye rotation_deg = {} must be finite", shown_number(*.0))]
    Rotation(f64),
}

/// A radially symmetric map resolved for one image size.
#[derive(Clone, Copy, Debug)]
pub(super) struct RadialMap {
    model: FisheyeModel,
    cx: f64,
    cy: f64,
    /// Circle radius R, pixels.
    radius: f64,
    /// θ on the circle (after the orthographic clamp).
    theta_max: f64,
    /// 1/f = ρ(θ_max)/R.
    k: f64,
    /// G(R) = 1 − cos θ_max.
    g_max: f64,
    cos_rot: f64,
    sin_rot: f64,
}

impl RadialMap {
    fn new(model: FisheyeModel, cx: f64, cy: f64, radius: f64, theta_max: f64) -> Self {
        let theta_max = theta_max.min(model.theta_limit());
        Self {
            model,
            cx,
            cy,
            radius,
            theta_max,
            k: model.rho(theta_max) / radius,
            g_max: 1.0 - theta_max.cos(),
            cos_rot: 1.0,
            sin_rot: 0.0,
        }
    }

    /// H(r) = G(r)/r² from r².
    fn cap_density(&self, r2: f64) -> f64 {
        self.k * self.k * self.model.cap_ratio(self.k * self.k * r2)
    }

    /// θ at image radius r ≤ R.
    fn theta_at(&self, r: f64) -> f64 {
        self.model.theta(self.k * r).min(self.theta_max)
    }

    /// Image radius of θ ≤ θ_max.
    fn radius_at(&self, theta: f64) -> f64 {
        (self.model.rho(theta) / self.k).min(self.radius)
    }

    /// Flux of H(r)(x, y) through the part of the segment A→B (relative to the centre) inside the
    /// disc, to `tolerance` (relative), and the angle that part subtends at the centre.
    fn edge(&self, ax: f64, ay: f64, bx: f64, by: f64, tolerance: f64) -> Edge {
        let (dx, dy) = (bx - ax, by - ay);
        // |A + tD|² − R² = a t² + 2 b t + c
        let a = dx * dx + dy * dy;
        let b = ax * dx + ay * dy;
        let c = ax * ax + ay * ay - self.radius * self.radius;
        let disc = b * b - a * c;
        if !(disc > 0.0 && a > 0.0) {
            return Edge::default();
        }
        let q = -(b + b.signum() * disc.sqrt());
        let (r1, r2) = (q / a, c / q);
        let t0 = r1.min(r2).max(0.0);
        let t1 = r1.max(r2).min(1.0);
        if t0.is_nan() || t1.is_nan() || t1 <= t0 {
            return Edge::default();
        }
        let (clip0, clip1) = (t0 > 0.0, t1 < 1.0);
        let (px, py) = if clip0 {
            (ax + t0 * dx, ay + t0 * dy)
        } else {
            (ax, ay)
        };
        let (qx, qy) = if clip1 {
            (ax + t1 * dx, ay + t1 * dy)
        } else {
            (bx, by)
        };
        let cross_ab = ax * by - ay * bx;
        let flux = if cross_ab == 0.0 {
            0.0
        } else {
            let len = t1 - t0;
            let integrand = |u: f64| {
                let (t, jac) = match (clip0, clip1) {
                    (false, false) => (t0 + len * u, len),
                    (true, false) => (t0 + len * u * u, 2.0 * len * u),
                    (false, true) => (t0 + len * u * (2.0 - u), 2.0 * len * (1.0 - u)),
                    (true, true) => (
                        t0 + len * u * u * (3.0 - 2.0 * u),
                        6.0 * len * u * (1.0 - u),
                    ),
                };
                let (x, y) = (ax + t * dx, ay + t * dy);
                jac * self.cap_density(x * x + y * y)
            };
            cross_ab * integrate(integrand, tolerance)
        };
        Edge {
            flux,
            piece: [px, py, qx, qy],
        }
    }

    /// Exact solid angle of every pixel of a `w`×`h` image, row-major.
    fn solid_angles(&self, w: u32, h: u32) -> Vec<f64> {
        let (wu, hu) = (w as usize, h as usize);
        let mut out = vec![0.0; wu * hu];
        let r = self.radius;
        if wu == 0 || hu == 0 || r.is_nan() || r <= 0.0 || !self.k.is_finite() {
            return out;
        }
        let lo = |v: f64, n: u32| (v.floor().clamp(0.0, f64::from(n))) as usize;
        let hi = |v: f64, n: u32| (v.ceil().clamp(0.0, f64::from(n))) as usize;
        let (i0, i1) = (lo(self.cx - r, w), hi(self.cx + r, w));
        let (j0, j1) = (lo(self.cy - r, h), hi(self.cy + r, h));
        if i0 >= i1 || j0 >= j1 {
            return out;
        }
        let xs: Vec<f64> = (i0..=i1).map(|i| i as f64 - self.cx).collect();
        // Bands of rows in parallel: a band computes its own first bottom edges, so every edge
        // is the same function of the same numbers as in one pass, and the result does not
        // depend on the number of threads.
        out[j0 * wu..j1 * wu]
            .par_chunks_mut(ROWS_PER_BAND * wu)
            .enumerate()
            .for_each(|(band, rows)| {
                let first = j0 + band * ROWS_PER_BAND;
                let ys: Vec<f64> = (first..=first + rows.len() / wu)
                    .map(|j| j as f64 - self.cy)
                    .collect();
                let cells = rows.chunks_exact_mut(wu).map(|row| &mut row[i0..i1]);
                self.grid_cells(&xs, &ys, PIXEL_TOLERANCE, cells);
            });
        out
    }

    /// The solid angles of the cells of the grid with column edges `xs` and row edges `ys`
    /// (relative to the centre, increasing), row by row into `rows` (one slice of
    /// `xs.len()` − 1 cells each); each edge is integrated once, to `tolerance`, for the two
    /// cells that share it.
    fn grid_cells<'r>(
        &self,
        xs: &[f64],
        ys: &[f64],
        tolerance: f64,
        rows: impl IntoIterator<Item = &'r mut [f64]>,
    ) {
        let horizontal = |y: f64| -> Vec<Edge> {
            xs.windows(2)
                .map(|p| self.edge(p[0], y, p[1], y, tolerance))
                .collect()
        };
        let Some(&first) = ys.first() else { return };
        let mut edges_lo = horizontal(first);
        for (band, row) in ys.windows(2).zip(rows) {
            let (y0, y1) = (band[0], band[1]);
            let edges_hi = horizontal(y1);
            let verticals: Vec<Edge> = xs
                .iter()
                .map(|&x| self.edge(x, y0, x, y1, tolerance))
                .collect();
            for ((n, x), cell) in xs.windows(2).enumerate().zip(row.iter_mut()) {
                let (x0, x1) = (x[0], x[1]);
                // counter-clockwise in the (dx, dy) plane: y0 (+x), x1 (+y), y1 (−x), x0 (−y)
                *cell = if x0 < x1 && y0 < y1 {
                    let edges = [edges_lo[n], verticals[n + 1], edges_hi[n], verticals[n]];
                    self.omega_from_edges(edges, (x0, x1), (y0, y1))
                } else {
                    0.0
                };
            }
            edges_lo = edges_hi;
        }
    }
}

impl RadialMap {
    /// The solid angle of the rectangle [x0, x1] × [y0, y1] (relative to the centre) from its
    /// edges (bottom y0, right x1, top y1, left x0; [`RadialMap::edge`]): the flux through
    /// them, plus G(R) times the angle the rim sweeps inside the rectangle where it reaches it.
    fn omega_from_edges(
        &self,
        edges: [Edge; 4],
        (x0, x1): (f64, f64),
        (y0, y1): (f64, f64),
    ) -> f64 {
        let [bottom, right, top, left] = edges;
        let mut omega = bottom.flux + right.flux - top.flux - left.flux;
        let far = x0.abs().max(x1.abs()).powi(2) + y0.abs().max(y1.abs()).powi(2);
        if far > self.radius * self.radius {
            let pieces = bottom.angle() + right.angle() - top.angle() - left.angle();
            let sweep = subtended_by_square(x0, x1, y0, y1) - pieces;
            omega += self.g_max * sweep;
        }
        omega.max(0.0)
    }

    /// The point of the image rectangle [x0, x1] × [y0, y1] nearest the circle's centre, where
    /// it is inside the circle (it is wherever any point of the rectangle is).
    pub(super) fn nearest_point_inside(
        &self,
        (x0, y0): (f64, f64),
        (x1, y1): (f64, f64),
    ) -> Option<(f64, f64)> {
        let p = (self.cx.clamp(x0, x1), self.cy.clamp(y0, y1));
        ((p.0 - self.cx).hypot(p.1 - self.cy) <= self.radius).then_some(p)
    }

    /// Exact solid angle of the image rectangle [x0, x1] × [y0, y1] (pixels; any size, inside
    /// the image circle or not): what [`RadialMap::solid_angles`] gives a pixel.
    pub(super) fn rectangle_solid_angle(&self, (x0, y0): (f64, f64), (x1, y1): (f64, f64)) -> f64 {
        let (x0, x1, y0, y1) = (x0 - self.cx, x1 - self.cx, y0 - self.cy, y1 - self.cy);
        if !(x0 < x1 && y0 < y1) {
            return 0.0;
        }
        let edges = [
            self.edge(x0, y0, x1, y0, RECTANGLE_TOLERANCE),
            self.edge(x1, y0, x1, y1, RECTANGLE_TOLERANCE),
            self.edge(x0, y1, x1, y1, RECTANGLE_TOLERANCE),
            self.edge(x0, y0, x0, y1, RECTANGLE_TOLERANCE),
        ];
        self.omega_from_edges(edges, (x0, x1), (y0, y1))
    }

    /// [`RadialMap::rectangle_solid_angle`] of every cell of the grid with column edges `xs`
    /// and row edges `ys` (image pixels, finite), row-major, appended to `out`: the same
    /// numbers, each edge integrated once for the two cells that share it.
    pub(super) fn grid_solid_angles(&self, xs: &[f64], ys: &[f64], out: &mut Vec<f64>) {
        let columns = xs.len().saturating_sub(1);
        if columns == 0 {
            return;
        }
        let xs: Vec<f64> = xs.iter().map(|x| x - self.cx).collect();
        let ys: Vec<f64> = ys.iter().map(|y| y - self.cy).collect();
        let start = out.len();
        out.resize(start + columns * ys.len().saturating_sub(1), 0.0);
        let rows = out[start..].chunks_exact_mut(columns);
        self.grid_cells(&xs, &ys, RECTANGLE_TOLERANCE, rows);
    }
}

/// The resolved map of a fisheye calibration for a `w`×`h` image (exact solid angles of its
/// rectangles, [`crate::envmap::RectangleSolidAngles`]): `None` where it does not resolve
/// (its error type stays private to this module).
pub(super) fn fisheye_map(cal: &FisheyeCalibration, w: u32, h: u32) -> Option<RadialMap> {
    cal.resolve(w, h).ok()
}

/// The same for the angular map.
pub(super) fn angular_map(w: u32, h: u32) -> Option<RadialMap> {
    let (cx, cy, radius) = angular_disc(w, h)?;
    Some(RadialMap::new(
        FisheyeModel::Equidistant,
        cx,
        cy,
        radius,
        PI,
    ))
}

/// Rows of pixels one parallel task computes in [`RadialMap::solid_angles`]; a band computes
/// its first row's bottom edges again, so this is 1/16 more horizontal edges than one pass.
const ROWS_PER_BAND: usize = 16;

/// A square edge's contribution: the flux through its part inside the disc, and that part's
/// ends P→Q (relative to the centre; all zero when no part is inside).
#[derive(Clone, Copy, Debug, Default)]
struct Edge {
    flux: f64,
    piece: [f64; 4],
}

impl Edge {
    /// The angle the part inside the disc subtends at the centre, atan2(P × Q, P·Q). Only the
    /// pixels the circle crosses need it, so it is not computed for the others.
    fn angle(&self) -> f64 {
        let [px, py, qx, qy] = self.piece;
        let (cr, dot) = (px * qy - py * qx, px * qx + py * qy);
        if cr == 0.0 && dot <= 0.0 {
            0.0 // the piece passes through the centre, or there is none
        } else {
            cr.atan2(dot)
        }
    }
}

/// Angle the square [x0, x1]×[y0, y1] (relative to the centre) subtends at the centre: 2π inside,
/// π on an edge, π/2 at a corner, 0 outside.
fn subtended_by_square(x0: f64, x1: f64, y0: f64, y1: f64) -> f64 {
    if x0 > 0.0 || x1 < 0.0 || y0 > 0.0 || y1 < 0.0 {
        return 0.0;
    }
    match [x0, x1, y0, y1].iter().filter(|&&v| v == 0.0).count() {
        0 => TAU,
        1 => PI,
        _ => FRAC_PI_2,
    }
}

/// Kronrod nodes on [−1, 1] (≥ 0 half) of the 7-point Gauss–Kronrod rule extending 3-point Gauss.
const GK7_NODES: [f64; 4] = [
    0.0,
    0.434_243_749_346_802_6,
    0.774_596_669_241_483_4,
    0.960_491_268_708_020_3,
];
const GK7_KRONROD_WEIGHTS: [f64; 4] = [
    0.450_916_538_658_474_1,
    0.401_397_414_775_962_2,
    0.268_488_089_868_333_4,
    0.104_656_226_026_467_3,
];
/// 3-point Gauss weights at nodes 0 and ±√(3/5).
const G3_WEIGHTS: [f64; 2] = [8.0 / 9.0, 5.0 / 9.0];

/// (Kronrod, Gauss) estimates of ∫ f over [a, b].
fn gauss_kronrod7(f: &impl Fn(f64) -> f64, a: f64, b: f64) -> (f64, f64) {
    let (mid, half) = (0.5 * (a + b), 0.5 * (b - a));
    let f0 = f(mid);
    let mut kronrod = GK7_KRONROD_WEIGHTS[0] * f0;
    let mut gauss = G3_WEIGHTS[0] * f0;
    for n in 1..4 {
        let pair = f(mid - half * GK7_NODES[n]) + f(mid + half * GK7_NODES[n]);
        kronrod += GK7_KRONROD_WEIGHTS[n] * pair;
        if n == 2 {
            gauss += G3_WEIGHTS[1] * pair;
        }
    }
    (kronrod * half, gauss * half)
}

/// How closely (relative) the fluxes of pixels' edges are integrated: their solid angles sum
/// to the image's to rounding.
const PIXEL_TOLERANCE: f64 = 1e-13;

/// How closely (relative) the fluxes of [`RadialMap::rectangle_solid_angle`]'s edges are
/// integrated: the rectangles (sub-pixels, pieces of pixels) share their pixel's exact solid
/// angle in proportion to theirs, which needs no more. Near an orthographic lens's rim, where
/// the solid angle per pixel area grows without bound, 1e-13 made a 1280×960 orthographic
/// frame's first frame 1.55 s instead of 0.86 s (docs/performance.md).
const RECTANGLE_TOLERANCE: f64 = 1e-9;

/// ∫₀¹ f for a non-negative f, adaptive bisection to ≈`tolerance` relative.
fn integrate(f: impl Fn(f64) -> f64, tolerance: f64) -> f64 {
    fn adapt(f: &impl Fn(f64) -> f64, a: f64, b: f64, k: f64, g: f64, tol: f64, depth: u32) -> f64 {
        if (k - g).abs() <= tol || depth == 0 || !k.is_finite() {
            return k;
        }
        let m = 0.5 * (a + b);
        let (k0, g0) = gauss_kronrod7(f, a, m);
        let (k1, g1) = gauss_kronrod7(f, m, b);
        adapt(f, a, m, k0, g0, 0.5 * tol, depth - 1) + adapt(f, m, b, k1, g1, 0.5 * tol, depth - 1)
    }
    let (k, g) = gauss_kronrod7(&f, 0.0, 1.0);
    adapt(&f, 0.0, 1.0, k, g, tolerance * k.abs() + 1e-300, 40)
}

/// The largest image-circle radius accepted, in pixels: no sensor is two million pixels wide,
/// and far beyond it (about 1e150) every pixel's solid angle underflows to 0.
pub const MAX_RADIUS_PX: f64 = 1e6;

impl FisheyeCalibration {
    /// The circle and lens resolved for a `w`×`h` image.
    fn resolve(&self, w: u32, h: u32) -> Result<RadialMap, CalibrationError> {
        if w == 0 || h == 0 {
            return Err(CalibrationError::EmptyImage {
                width: w,
                height: h,
            });
        }
        if !(MIN_FOV_DEG..360.0).contains(&self.fov_deg) {
            return Err(CalibrationError::FieldOfView(self.fov_deg));
        }
        if !self.rotation_deg.is_finite() {
            return Err(CalibrationError::Rotation(self.rotation_deg));
        }
        let radius = self.radius.unwrap_or(0.5 * f64::from(w.min(h)));
        if !(radius > 0.0 && radius <= MAX_RADIUS_PX) {
            return Err(CalibrationError::Radius(radius));
        }
        let [cx, cy] = self
            .center
            .unwrap_or([0.5 * f64::from(w), 0.5 * f64::from(h)]);
        if !(cx.is_finite() && cy.is_finite()) {
            return Err(CalibrationError::Center(cx, cy));
        }
        let mut map = RadialMap::new(self.model, cx, cy, radius, self.fov_deg.to_radians() / 2.0);
        (map.sin_rot, map.cos_rot) = self.rotation_deg.to_radians().sin_cos();
        Ok(map)
    }

    /// Checks the calibration for a `w`×`h` image; the error names the bad field and its value.
    /// Besides invalid values it rejects an image circle that does not overlap the image.
    pub fn validate(&self, w: u32, h: u32) -> Result<(), String> {
        let map = self.resolve(w, h).map_err(|e| e.to_string())?;
        if self.model == FisheyeModel::Orthographic && self.fov_deg > 180.0 {
            return Err(format!(
                "fov_deg = {}: {}",
                shown_number(self.fov_deg),
                crate::config::ORTHOGRAPHIC_FOV_LIMIT
            ));
        }
        // distance from the centre to the image rectangle
        let gap_x = (0.0 - map.cx).max(map.cx - f64::from(w)).max(0.0);
        let gap_y = (0.0 - map.cy).max(map.cy - f64::from(h)).max(0.0);
        if gap_x.hypot(gap_y) >= map.radius {
            return Err(format!(
                "fisheye image circle (center [{}, {}], radius {}) does not overlap the {w}x{h} image",
                map.cx, map.cy, map.radius
            ));
        }
        // A circle between pixel centres sees nothing: every pixel's solid angle is 0.
        let nearest_centre =
            |c: f64, size: u32| (c.floor() + 0.5).clamp(0.5, f64::from(size) - 0.5);
        let (px, py) = (nearest_centre(map.cx, w), nearest_centre(map.cy, h));
        if (px - map.cx).hypot(py - map.cy) > map.radius {
            return Err(format!(
                "fisheye image circle (center [{}, {}], radius {}) contains no pixel centre of \
                 the {w}x{h} image",
                map.cx, map.cy, map.radius
            ));
        }
        Ok(())
    }

    /// Direction (unit) seen at continuous pixel position (x, y), or `None` outside the image
    /// circle, for non-finite positions, or for an invalid calibration.
    pub fn pixel_to_direction(&self, w: u32, h: u32, x: f64, y: f64) -> Option<DVec3> {
        let map = self.resolve(w, h).ok()?;
        let (dx, dy) = (x - map.cx, y - map.cy);
        let r = dx.hypot(dy);
        if r.is_nan() || r > map.radius {
            return None; // also NaN / infinite positions
        }
        if r == 0.0 {
            return Some(DVec3::Y);
        }
        let (sin_t, cos_t) = map.theta_at(r).sin_cos();
        // Image right is −X: the camera looks up, so it sees the sky mirrored from a map.
        let (h0x, h0z) = (-dx / r, dy / r);
        let hx = h0x * map.cos_rot + h0z * map.sin_rot;
        let hz = -h0x * map.sin_rot + h0z * map.cos_rot;
        Some(DVec3::new(sin_t * hx, cos_t, sin_t * hz))
    }

    /// Continuous pixel position of direction `d` (need not be normalised), or `None` for
    /// θ > θ_max, zero or non-finite `d`, or an invalid calibration.
    pub fn direction_to_pixel(&self, w: u32, h: u32, d: DVec3) -> Option<(f64, f64)> {
        let map = self.resolve(w, h).ok()?;
        let d = normalized(d)?;
        let horizontal = d.x.hypot(d.z);
        let theta = horizontal.atan2(d.y);
        if theta > map.theta_max + 1e-12 {
            return None;
        }
        if horizontal == 0.0 {
            return Some((map.cx, map.cy));
        }
        let r = map.radius_at(theta.min(map.theta_max));
        let (hx, hz) = (d.x / horizontal, d.z / horizontal);
        let h0x = hx * map.cos_rot - hz * map.sin_rot;
        let h0z = hx * map.sin_rot + hz * map.cos_rot;
        Some((map.cx - r * h0x, map.cy + r * h0z))
    }

    /// Exact solid angle (steradians) of every pixel, row-major; 0 outside the image circle and
    /// everywhere for an invalid calibration. See the module doc for the method.
    pub fn solid_angles(&self, w: u32, h: u32) -> Vec<f64> {
        match self.resolve(w, h) {
            Ok(map) => map.solid_angles(w, h),
            Err(_) => vec![0.0; w as usize * h as usize],
        }
    }
}

/// `d` scaled to unit length, or `None` if it is zero or not finite.
fn normalized(d: DVec3) -> Option<DVec3> {
    if !d.is_finite() {
        return None;
    }
    let scale = d.abs().max_element();
    if scale <= 0.0 {
        return None;
    }
    let d = d / scale; // no overflow in length() for huge components
    Some(d / d.length())
}

/// The angular map's disc: centre and radius in pixels.
fn angular_disc(w: u32, h: u32) -> Option<(f64, f64, f64)> {
    if w == 0 || h == 0 {
        return None;
    }
    Some((
        0.5 * f64::from(w),
        0.5 * f64::from(h),
        0.5 * f64::from(w.min(h)),
    ))
}

/// Debevec angular map: direction at continuous pixel position (x, y), `None` outside the disc.
pub fn angular_pixel_to_direction(w: u32, h: u32, x: f64, y: f64) -> Option<DVec3> {
    let (cx, cy, radius) = angular_disc(w, h)?;
    let (u, v) = ((x - cx) / radius, (y - cy) / radius);
    let rho = u.hypot(v);
    if rho.is_nan() || rho > 1.0 {
        return None;
    }
    if rho == 0.0 {
        return Some(DVec3::NEG_Z);
    }
    let (sin_t, cos_t) = (PI * rho).sin_cos();
    Some(DVec3::new(sin_t * u / rho, -sin_t * v / rho, -cos_t))
}

/// Debevec angular map: continuous pixel position of direction `d` (need not be normalised);
/// `None` for zero or non-finite `d`. +Z maps to the rim point below the centre.
pub fn angular_direction_to_pixel(w: u32, h: u32, d: DVec3) -> Option<(f64, f64)> {
    let (cx, cy, radius) = angular_disc(w, h)?;
    let d = normalized(d)?;
    let lateral = d.x.hypot(d.y);
    if lateral == 0.0 {
        return Some(if d.z < 0.0 {
            (cx, cy)
        } else {
            (cx, cy + radius)
        });
    }
    let rho = lateral.atan2(-d.z) / PI;
    let s = radius * rho / lateral;
    Some((cx + s * d.x, cy - s * d.y))
}

/// Debevec angular map: exact solid angle of every pixel, row-major (0 outside the disc).
pub fn angular_solid_angles(w: u32, h: u32) -> Vec<f64> {
    angular_map(w, h).map_or_else(Vec::new, |map| map.solid_angles(w, h))
}

#[cfg(test)]
mod tests {
    use super::*;

    const MODELS: [FisheyeModel; 4] = FisheyeModel::ALL;

    /// The bands of rows are computed on rayon's threads; the solid angles must be the same to
    /// the bit on one thread and on several (a band recomputes its first bottom edges).
    #[test]
    fn solid_angles_do_not_depend_on_the_number_of_threads() {
        let on = |threads: usize, c: &FisheyeCalibration| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .expect("a thread pool")
                .install(|| c.solid_angles(97, 75))
        };
        for model in MODELS {
            let c = FisheyeCalibration {
                model,
                center: Some([45.3, 40.1]),
                radius: Some(41.7),
                fov_deg: 190.0,
                ..Default::default()
            };
            let one = on(1, &c);
            assert!(one.iter().sum::<f64>() > 1.0, "{model:?}");
            for threads in [2, 5] {
                let many = on(threads, &c);
                assert!(
                    one.iter()
                        .zip(&many)
                        .all(|(a, b)| a.to_bits() == b.to_bits()),
                    "{model:?} on {threads} threads"
                );
            }
        }
    }

    fn cal(model: FisheyeModel, fov_deg: f64) -> FisheyeCalibration {
        FisheyeCalibration {
            model,
            fov_deg,
            ..Default::default()
        }
    }

    /// Angle from +Y.
    fn theta_of(d: DVec3) -> f64 {
        d.x.hypot(d.z).atan2(d.y)
    }

    /// Lat-long azimuth φ = atan2(d.x, −d.z) (DESIGN.md).
    fn phi_of(d: DVec3) -> f64 {
        d.x.atan2(-d.z)
    }

    fn wrap_angle(a: f64) -> f64 {
        (a + PI).rem_euclid(TAU) - PI
    }

    /// Calibrations exercising every model, several fields of view, rotations and centres.
    fn calibrations() -> Vec<FisheyeCalibration> {
        let mut out = Vec::new();
        for model in MODELS {
            for fov in [90.0, 150.0, 180.0, 200.0, 300.0] {
                for (rot, center, radius) in [
                    (0.0, None, None),
                    (37.0, Some([30.3, 22.7]), Some(20.1)),
                    (-200.0, Some([33.0, 20.0]), Some(19.5)),
                ] {
                    out.push(FisheyeCalibration {
                        model,
                        center,
                        radius,
                        fov_deg: fov,
                        rotation_deg: rot,
                    });
                }
            }
        }
        out
    }

    /// The series agrees with sin(x)/x to a few ulps over the whole range the solid angles use
    /// (x up to π/2) and a little past it, and beyond its range falls back to the sine.
    #[test]
    fn sinc_series_equals_the_sine_quotient() {
        let mut worst = 0.0f64;
        for i in 0..=20_000 {
            let x = 1.6 * f64::from(i) / 20_000.0;
            let want = if x == 0.0 { 1.0 } else { x.sin() / x };
            let got = sinc_of_square(x * x);
            worst = worst.max((got - want).abs() / want);
        }
        assert!(worst < 1e-15, "worst relative difference {worst:e}");
        assert_eq!(sinc_of_square(9.0), 3.0f64.sin() / 3.0);
        assert!(sinc_of_square(f64::NAN).is_nan());
    }

    #[test]
    fn gauss_kronrod_rule_integrates_polynomials_exactly() {
        // 7-point Kronrod: exact to degree 11 (symmetric); 3-point Gauss: to degree 5.
        for deg in 0..=11 {
            let exact = if deg % 2 == 1 {
                0.0
            } else {
                2.0 / f64::from(deg + 1)
            };
            let (k, g) = gauss_kronrod7(&|x: f64| x.powi(deg), -1.0, 1.0);
            assert!(
                (k - exact).abs() < 1e-15,
                "Kronrod degree {deg}: {k} vs {exact}"
            );
            if deg <= 5 {
                assert!(
                    (g - exact).abs() < 1e-15,
                    "Gauss degree {deg}: {g} vs {exact}"
                );
            }
        }
        let v = integrate(|t: f64| t.sqrt(), PIXEL_TOLERANCE);
        assert!((v - 2.0 / 3.0).abs() < 1e-12, "adaptive sqrt: {v}");
    }

    #[test]
    fn round_trip_pixel_direction_pixel_every_model() {
        let (w, h) = (64, 48);
        for c in calibrations() {
            let mut inside = 0;
            for j in 0..4 * h {
                for i in 0..4 * w {
                    let (x, y) = ((f64::from(i) + 0.37) / 4.0, (f64::from(j) + 0.61) / 4.0);
                    let Some(d) = c.pixel_to_direction(w, h, x, y) else {
                        continue;
                    };
                    inside += 1;
                    assert!((d.length() - 1.0).abs() < 1e-12);
                    let (qx, qy) = c
                        .direction_to_pixel(w, h, d)
                        .unwrap_or_else(|| panic!("{c:?} ({x}, {y}) → {d} → None"));
                    assert!(
                        (qx - x).abs() < 1e-8 && (qy - y).abs() < 1e-8,
                        "{c:?} ({x}, {y}) → {d} → ({qx}, {qy})"
                    );
                    let e = c.pixel_to_direction(w, h, qx, qy).unwrap_or(DVec3::ZERO);
                    assert!((e - d).length() < 1e-9);
                }
            }
            assert!(inside > 1000, "{c:?}: only {inside} samples inside");
        }
    }

    #[test]
    fn round_trip_direction_pixel_direction_every_model() {
        let (w, h) = (64, 48);
        for c in calibrations() {
            let theta_max = (c.fov_deg / 2.0).to_radians().min(c.model.theta_limit());
            for n in 0..500 {
                // a spiral over the sphere
                let z = 1.0 - 2.0 * (f64::from(n) + 0.5) / 500.0;
                let phi = f64::from(n) * 2.399_963_229_728_653;
                let s = (1.0 - z * z).sqrt();
                let d = DVec3::new(s * phi.cos(), z, s * phi.sin());
                let p = c.direction_to_pixel(w, h, 3.0 * d);
                if theta_of(d) > theta_max + 1e-9 {
                    assert!(p.is_none(), "{c:?}: {d} below the field of view → {p:?}");
                    continue;
                }
                let (x, y) = p.unwrap_or_else(|| panic!("{c:?}: {d} → None"));
                let e = c.pixel_to_direction(w, h, x, y).unwrap_or(DVec3::ZERO);
                assert!((e - d).length() < 1e-9, "{c:?}: {d} → ({x}, {y}) → {e}");
            }
        }
    }

    #[test]
    fn round_trip_angular_map() {
        for (w, h) in [(63, 63), (64, 48), (40, 70)] {
            let mut inside = 0;
            for j in 0..3 * h {
                for i in 0..3 * w {
                    let (x, y) = ((f64::from(i) + 0.41) / 3.0, (f64::from(j) + 0.53) / 3.0);
                    let Some(d) = angular_pixel_to_direction(w, h, x, y) else {
                        continue;
                    };
                    inside += 1;
                    assert!((d.length() - 1.0).abs() < 1e-12);
                    let (qx, qy) = angular_direction_to_pixel(w, h, d).unwrap_or((-1.0, -1.0));
                    assert!(
                        (qx - x).abs() < 1e-8 && (qy - y).abs() < 1e-8,
                        "{w}x{h} ({x}, {y}) → {d} → ({qx}, {qy})"
                    );
                }
            }
            assert!(inside > 1000);
            for n in 0..300 {
                let z = 1.0 - 2.0 * (f64::from(n) + 0.5) / 300.0;
                let phi = f64::from(n) * 2.399_963_229_728_653;
                let s = (1.0 - z * z).sqrt();
                let d = DVec3::new(s * phi.cos(), s * phi.sin(), z);
                let (x, y) = angular_direction_to_pixel(w, h, d).unwrap_or((-1.0, -1.0));
                let e = angular_pixel_to_direction(w, h, x, y).unwrap_or(DVec3::ZERO);
                assert!((e - d).length() < 1e-9, "{d} → ({x}, {y}) → {e}");
            }
        }
    }

    #[test]
    fn zenith_at_circle_centre() {
        for c in calibrations() {
            let map = c.resolve(64, 48).unwrap_or_else(|e| panic!("{e}"));
            let d = c.pixel_to_direction(64, 48, map.cx, map.cy);
            assert_eq!(d, Some(DVec3::Y), "{c:?}");
            let (x, y) = c
                .direction_to_pixel(64, 48, DVec3::Y)
                .unwrap_or((-1.0, -1.0));
            assert!((x - map.cx).abs() < 1e-12 && (y - map.cy).abs() < 1e-12);
            // and just off the centre, still (nearly) the zenith
            let d = c
                .pixel_to_direction(64, 48, map.cx + 1e-9, map.cy)
                .unwrap_or(DVec3::ZERO);
            assert!((d - DVec3::Y).length() < 1e-9);
        }
        // default centre of an odd-sized image is (W/2, H/2), not a pixel centre
        let d = FisheyeCalibration::default().pixel_to_direction(63, 63, 31.5, 31.5);
        assert_eq!(d, Some(DVec3::Y));
    }

    #[test]
    fn theta_max_lands_on_the_circle() {
        for c in calibrations() {
            let map = c.resolve(64, 48).unwrap_or_else(|e| panic!("{e}"));
            let theta_max = (c.fov_deg / 2.0).to_radians().min(c.model.theta_limit());
            for n in 0..16 {
                let phi = f64::from(n) * TAU / 16.0 + 0.1;
                let on = DVec3::new(
                    theta_max.sin() * phi.sin(),
                    theta_max.cos(),
                    -theta_max.sin() * phi.cos(),
                );
                let (x, y) = c
                    .direction_to_pixel(64, 48, on)
                    .unwrap_or((f64::NAN, f64::NAN));
                let r = (x - map.cx).hypot(y - map.cy);
                assert!((r - map.radius).abs() < 1e-9, "{c:?}: r = {r}");
                let beyond = theta_max + 1e-6;
                let below = DVec3::new(
                    beyond.sin() * phi.sin(),
                    beyond.cos(),
                    -beyond.sin() * phi.cos(),
                );
                assert_eq!(c.direction_to_pixel(64, 48, below), None, "{c:?}");
                // just outside the circle sees nothing
                let (ux, uy) = ((x - map.cx) / r, (y - map.cy) / r);
                let out = map.radius + 1e-6;
                assert_eq!(
                    c.pixel_to_direction(64, 48, map.cx + out * ux, map.cy + out * uy),
                    None
                );
            }
        }
    }

    #[test]
    fn known_values_equidistant_180() {
        let c = FisheyeCalibration::default();
        let (w, h) = (100, 80); // centre (50, 40), R = 40
        let d = c
            .pixel_to_direction(w, h, 70.0, 40.0)
            .unwrap_or(DVec3::ZERO);
        assert!((theta_of(d) - PI / 4.0).abs() < 1e-12, "r = R/2 → 45°");
        let right = c
            .pixel_to_direction(w, h, 90.0, 40.0)
            .unwrap_or(DVec3::ZERO);
        assert!(
            (right - DVec3::NEG_X).length() < 1e-12,
            "image right → −X (the camera looks up): {right}"
        );
        let down = c
            .pixel_to_direction(w, h, 50.0, 80.0)
            .unwrap_or(DVec3::ZERO);
        assert!(
            (down - DVec3::Z).length() < 1e-12,
            "image down → +Z: {down}"
        );
        let up = c.pixel_to_direction(w, h, 50.0, 0.0).unwrap_or(DVec3::ZERO);
        assert!((up - DVec3::NEG_Z).length() < 1e-12, "image up → −Z: {up}");
        // same as the lat-long map's u = 0 column
        let latlong = super::super::latlong::pixel_to_direction(4, 2, 0.0, 1.0);
        assert!((up - latlong).length() < 1e-12);
        assert_eq!(c.pixel_to_direction(w, h, 90.01, 40.0), None);
        // the other models at r = R/2
        let at_half = |model: FisheyeModel, fov: f64| {
            theta_of(
                cal(model, fov)
                    .pixel_to_direction(w, h, 70.0, 40.0)
                    .unwrap_or(DVec3::ZERO),
            )
        };
        let expect = |v: f64, want: f64| assert!((v - want).abs() < 1e-12, "{v} vs {want}");
        expect(
            at_half(FisheyeModel::Equisolid, 180.0),
            2.0 * (0.5 * 0.5f64.sqrt()).asin(),
        );
        expect(
            at_half(FisheyeModel::Stereographic, 180.0),
            2.0 * 0.5f64.atan(),
        );
        expect(at_half(FisheyeModel::Orthographic, 180.0), PI / 6.0);
        expect(
            at_half(FisheyeModel::Equidistant, 200.0),
            50f64.to_radians(),
        );
    }

    /// docs/camera.md's rule for setting the rotation: a landmark at angle α on the image
    /// (counter-clockwise from image up) lies at azimuth ψ − α, counted from −Z
    /// counter-clockwise about +Y seen from above, i.e. along R_y(ψ − α)·(−Z).
    #[test]
    fn a_landmark_at_image_angle_alpha_lies_at_azimuth_psi_minus_alpha() {
        let (w, h) = (100, 80);
        for psi in [0.0, 35.0, -120.0, 270.0] {
            let c = FisheyeCalibration {
                rotation_deg: psi,
                ..Default::default()
            };
            for alpha in [0.0, 30.0, 90.0, 200.0] {
                let a = f64::to_radians(alpha);
                let (x, y) = (50.0 - 20.0 * a.sin(), 40.0 - 20.0 * a.cos());
                let d = c.pixel_to_direction(w, h, x, y).unwrap_or(DVec3::ZERO);
                let beta = f64::to_radians(psi - alpha);
                let horizontal = DVec3::new(d.x, 0.0, d.z).normalize_or_zero();
                let want = DVec3::new(-beta.sin(), 0.0, -beta.cos());
                assert!(
                    (horizontal - want).length() < 1e-12,
                    "ψ = {psi}, α = {alpha}: {d} vs {want}"
                );
            }
        }
    }

    #[test]
    fn rotation_is_counter_clockwise_seen_from_above() {
        let (w, h) = (100, 80);
        let rotated = FisheyeCalibration {
            rotation_deg: 90.0,
            ..Default::default()
        };
        let right = rotated
            .pixel_to_direction(w, h, 90.0, 40.0)
            .unwrap_or(DVec3::ZERO);
        assert!(
            (right - DVec3::Z).length() < 1e-12,
            "ψ = 90°: image right → +Z: {right}"
        );
        let down = rotated
            .pixel_to_direction(w, h, 50.0, 80.0)
            .unwrap_or(DVec3::ZERO);
        assert!(
            (down - DVec3::X).length() < 1e-12,
            "ψ = 90°: image down → +X: {down}"
        );
        for psi in [-170.0, -30.0, 15.0, 90.0, 400.0] {
            let c = FisheyeCalibration {
                rotation_deg: psi,
                ..Default::default()
            };
            for (x, y) in [(71.0, 33.0), (30.0, 60.0), (55.0, 10.0)] {
                let d0 = FisheyeCalibration::default()
                    .pixel_to_direction(w, h, x, y)
                    .unwrap_or(DVec3::ZERO);
                let d = c.pixel_to_direction(w, h, x, y).unwrap_or(DVec3::ZERO);
                // same elevation, lat-long azimuth decreased by ψ (right-handed about +Y)
                assert!((d.y - d0.y).abs() < 1e-12);
                let dphi = wrap_angle(phi_of(d) - phi_of(d0) + psi.to_radians());
                assert!(dphi.abs() < 1e-12, "ψ = {psi}: Δφ error {dphi}");
                let expect = glam::DQuat::from_rotation_y(psi.to_radians()) * d0;
                assert!((d - expect).length() < 1e-12);
            }
        }
    }

    #[test]
    fn angular_map_known_values() {
        let (w, h) = (64, 48); // disc centre (32, 24), radius 24
        let at = |x: f64, y: f64| angular_pixel_to_direction(w, h, x, y).unwrap_or(DVec3::ZERO);
        assert!(
            (at(32.0, 24.0) - DVec3::NEG_Z).length() < 1e-12,
            "centre → −Z"
        );
        assert!(
            (at(44.0, 24.0) - DVec3::X).length() < 1e-12,
            "θ' = π/2 right → +X"
        );
        assert!(
            (at(32.0, 12.0) - DVec3::Y).length() < 1e-12,
            "θ' = π/2 up → +Y"
        );
        assert!((at(20.0, 24.0) - DVec3::NEG_X).length() < 1e-12);
        assert!(
            (at(56.0, 24.0) - DVec3::Z).length() < 1e-12,
            "right edge of the disc → +Z"
        );
        assert!(
            (at(32.0, 0.0) - DVec3::Z).length() < 1e-12,
            "top of the disc → +Z"
        );
        let d = at(32.0 + 12.0 * 0.5f64.sqrt(), 24.0 - 12.0 * 0.5f64.sqrt());
        assert!((d - DVec3::new(1.0, 1.0, 0.0).normalize()).length() < 1e-12);
        assert_eq!(angular_pixel_to_direction(w, h, 56.001, 24.0), None);
        assert_eq!(angular_pixel_to_direction(w, h, 2.0, 2.0), None);
        let (x, y) = angular_direction_to_pixel(w, h, DVec3::Z).unwrap_or((-1.0, -1.0));
        assert!(
            ((x - 32.0).hypot(y - 24.0) - 24.0).abs() < 1e-12,
            "+Z on the rim"
        );
        assert_eq!(
            angular_direction_to_pixel(w, h, DVec3::NEG_Z),
            Some((32.0, 24.0))
        );
    }

    fn relative(a: f64, b: f64) -> f64 {
        (a - b).abs() / b.abs()
    }

    #[test]
    fn fisheye_total_solid_angle() {
        let mut worst: f64 = 0.0;
        for model in MODELS {
            for fov in [90.0, 150.0, 180.0, 200.0, 330.0] {
                let theta_max = (fov / 2.0f64).to_radians().min(model.theta_limit());
                let exact = TAU * (1.0 - theta_max.cos());
                for (w, h, center, radius) in [
                    (63, 63, None, None),
                    (64, 48, None, None),
                    (64, 48, Some([30.3, 22.7]), Some(20.1)),
                    (50, 41, Some([20.0, 21.0]), Some(17.0)),
                    (7, 9, Some([3.2, 4.9]), Some(1.3)),
                    (5, 5, Some([2.0, 2.0]), Some(0.4)),
                    (5, 5, Some([2.3, 2.6]), Some(0.2)),
                ] {
                    let c = FisheyeCalibration {
                        model,
                        center,
                        radius,
                        fov_deg: fov,
                        rotation_deg: 12.0,
                    };
                    let omega = c.solid_angles(w, h);
                    assert_eq!(omega.len(), (w * h) as usize);
                    assert!(omega.iter().all(|&o| o >= 0.0 && o.is_finite()));
                    let total: f64 = omega.iter().sum();
                    let err = relative(total, exact);
                    worst = worst.max(err);
                    assert!(err < 1e-10, "{c:?} {w}x{h}: {total} vs {exact}");
                }
            }
        }
        eprintln!("worst relative error of the fisheye total: {worst:e}");
    }

    #[test]
    fn angular_total_solid_angle() {
        for (w, h) in [(63, 63), (64, 48), (33, 80), (1, 1), (2, 3)] {
            let omega = angular_solid_angles(w, h);
            let total: f64 = omega.iter().sum();
            assert!(relative(total, 4.0 * PI) < 1e-10, "{w}x{h}: {total}");
            assert!(omega.iter().all(|&o| o >= 0.0));
        }
    }

    #[test]
    fn image_border_clips_the_circle_consistently() {
        // A circle partly outside the image: each pixel equals the same pixel of a padded image.
        for model in MODELS {
            let c = FisheyeCalibration {
                model,
                center: Some([5.5, 40.25]),
                radius: Some(30.0),
                fov_deg: 180.0,
                rotation_deg: 0.0,
            };
            let padded = FisheyeCalibration {
                center: Some([5.5 + 40.0, 40.25 + 3.0]),
                ..c
            };
            let small = c.solid_angles(50, 60);
            let big = padded.solid_angles(100, 80);
            for j in 0..60 {
                for i in 0..50 {
                    let (a, b) = (small[j * 50 + i], big[(j + 3) * 100 + i + 40]);
                    assert!(
                        (a - b).abs() <= 1e-12 * b.max(1e-12),
                        "{model:?} ({i}, {j}): {a} vs {b}"
                    );
                }
            }
            let total: f64 = big.iter().sum();
            assert!(relative(total, TAU) < 1e-10);
        }
    }

    #[test]
    fn equisolid_pixels_inside_the_circle_are_equal() {
        // equal-area lens: g(r) = 1/f², constant
        let c = cal(FisheyeModel::Equisolid, 180.0);
        let omega = c.solid_angles(64, 48);
        let f = 24.0 / 2.0f64.sqrt();
        assert!(relative(omega[24 * 64 + 32], 1.0 / (f * f)) < 1e-13);
        assert!(relative(omega[10 * 64 + 40], 1.0 / (f * f)) < 1e-13);
    }

    /// θ at continuous pixel (x, y) from the public API.
    fn theta_at(c: &FisheyeCalibration, w: u32, h: u32, x: f64, y: f64) -> Option<f64> {
        c.pixel_to_direction(w, h, x, y).map(theta_of)
    }

    /// Brute force: n×n midpoint sub-samples of g(r) = sin θ·θ'(r)/r, with θ from the public
    /// API and θ' by central differences along the radius.
    fn brute_force(c: &FisheyeCalibration, w: u32, h: u32, px: u32, py: u32, n: u32) -> f64 {
        let map = c.resolve(w, h).unwrap_or_else(|e| panic!("{e}"));
        let mut sum = 0.0;
        let eps = 1e-5;
        for j in 0..n {
            for i in 0..n {
                let x = f64::from(px) + (f64::from(i) + 0.5) / f64::from(n);
                let y = f64::from(py) + (f64::from(j) + 0.5) / f64::from(n);
                let (dx, dy) = (x - map.cx, y - map.cy);
                let r = dx.hypot(dy);
                let (ux, uy) = (dx / r, dy / r);
                let (Some(t), Some(t0), Some(t1)) = (
                    theta_at(c, w, h, x, y),
                    theta_at(c, w, h, x - eps * ux, y - eps * uy),
                    theta_at(c, w, h, x + eps * ux, y + eps * uy),
                ) else {
                    continue;
                };
                sum += t.sin() * (t1 - t0) / (2.0 * eps) / r;
            }
        }
        sum / f64::from(n * n)
    }

    #[test]
    fn interior_pixels_match_brute_force_sub_sampling() {
        let (w, h) = (64, 48);
        let mut worst: f64 = 0.0;
        for model in MODELS {
            for fov in [150.0, 180.0] {
                let c = FisheyeCalibration {
                    model,
                    fov_deg: fov,
                    rotation_deg: 30.0,
                    ..Default::default()
                };
                let omega = c.solid_angles(w, h);
                for (px, py) in [(40, 20), (33, 30), (12, 24), (45, 33)] {
                    let exact = omega[py as usize * w as usize + px as usize];
                    let brute = brute_force(&c, w, h, px, py, 200);
                    let err = relative(exact, brute);
                    worst = worst.max(err);
                    assert!(err < 1e-4, "{c:?} ({px}, {py}): {exact} vs {brute}");
                }
            }
        }
        eprintln!("worst relative difference to 200×200 brute force: {worst:e}");
    }

    /// Independent reference in polar coordinates about the circle centre: the pixel's solid
    /// angle is ∫ [G(r_out(α)) − G(r_in(α))] dα over the rays α that cross it, with
    /// G = 1 − cos θ from the public API (midpoint rule in α, ray–box clipping in r). Exact in r,
    /// so it handles the rim (and the orthographic rim singularity) and the centre. `g_rim` is
    /// 1 − cos θ_max, G on the circle.
    fn polar_reference(
        dir: &dyn Fn(f64, f64) -> Option<DVec3>,
        axis: DVec3,
        g_rim: f64,
        (cx, cy, radius): (f64, f64, f64),
        px: u32,
        py: u32,
        n: u32,
    ) -> f64 {
        let (x0, x1) = (f64::from(px) - cx, f64::from(px) + 1.0 - cx);
        let (y0, y1) = (f64::from(py) - cy, f64::from(py) + 1.0 - cy);
        let g = |r: f64, a: f64| {
            if r >= radius {
                return g_rim; // rounding may put the rim point just outside the circle
            }
            dir(cx + r * a.cos(), cy + r * a.sin()).map_or(f64::NAN, |d| 1.0 - d.dot(axis))
        };
        let (a_lo, a_hi) = if x0 < 0.0 && x1 > 0.0 && y0 < 0.0 && y1 > 0.0 {
            (0.0, TAU)
        } else {
            let mid = (0.5 * (y0 + y1)).atan2(0.5 * (x0 + x1));
            let rel: Vec<f64> = [(x0, y0), (x1, y0), (x0, y1), (x1, y1)]
                .iter()
                .map(|&(x, y)| wrap_angle(y.atan2(x) - mid))
                .collect();
            let lo = rel.iter().copied().fold(f64::INFINITY, f64::min);
            let hi = rel.iter().copied().fold(f64::NEG_INFINITY, f64::max);
            (mid + lo, mid + hi)
        };
        let step = (a_hi - a_lo) / f64::from(n);
        let mut sum = 0.0;
        for k in 0..n {
            let a = a_lo + (f64::from(k) + 0.5) * step;
            let (ux, uy) = (a.cos(), a.sin());
            // slab clipping of the ray t·u, t ≥ 0
            let (mut t_in, mut t_out) = (0.0f64, radius);
            for (lo, hi, u) in [(x0, x1, ux), (y0, y1, uy)] {
                if u.abs() < 1e-300 {
                    if lo > 0.0 || hi < 0.0 {
                        t_out = -1.0;
                    }
                    continue;
                }
                let (ta, tb) = (lo / u, hi / u);
                t_in = t_in.max(ta.min(tb));
                t_out = t_out.min(ta.max(tb));
            }
            if t_out > t_in {
                sum += g(t_out, a) - if t_in > 0.0 { g(t_in, a) } else { 0.0 };
            }
        }
        sum * step
    }

    #[test]
    fn pixels_match_polar_reference_at_rim_centre_and_inside() {
        let mut worst: f64 = 0.0;
        for model in MODELS {
            for (fov, w, h, center, radius) in [
                (180.0, 64, 48, None, None),
                (200.0, 63, 63, Some([30.3, 33.7]), Some(27.2)),
                (120.0, 64, 48, Some([33.0, 25.0]), Some(21.6)),
            ] {
                let c = FisheyeCalibration {
                    model,
                    center,
                    radius,
                    fov_deg: fov,
                    rotation_deg: -50.0,
                };
                let map = c.resolve(w, h).unwrap_or_else(|e| panic!("{e}"));
                let omega = c.solid_angles(w, h);
                let dir = |x: f64, y: f64| c.pixel_to_direction(w, h, x, y);
                let mut checked = 0;
                for py in 0..h {
                    for px in 0..w {
                        // every pixel on the row, the column and a diagonal through the centre
                        let (rx, ry) = (px as i64 - map.cx as i64, py as i64 - map.cy as i64);
                        if !(rx == 0 || ry == 0 || rx == ry) {
                            continue;
                        }
                        let exact = omega[(py * w + px) as usize];
                        let theta_max = (fov / 2.0f64).to_radians().min(model.theta_limit());
                        let reference = polar_reference(
                            &dir,
                            DVec3::Y,
                            1.0 - theta_max.cos(),
                            (map.cx, map.cy, map.radius),
                            px,
                            py,
                            20_000,
                        );
                        if exact == 0.0 {
                            assert!(reference.abs() < 1e-14, "{c:?} ({px}, {py}) {reference}");
                            continue;
                        }
                        checked += 1;
                        let err = relative(exact, reference);
                        worst = worst.max(err);
                        assert!(err < 1e-6, "{c:?} ({px}, {py}): {exact} vs {reference}");
                    }
                }
                assert!(checked > 50);
            }
        }
        eprintln!("worst relative difference to the polar reference: {worst:e}");
    }

    #[test]
    fn angular_pixels_match_polar_reference() {
        let (w, h) = (64, 48);
        let omega = angular_solid_angles(w, h);
        let dir = |x: f64, y: f64| angular_pixel_to_direction(w, h, x, y);
        let mut worst: f64 = 0.0;
        for (px, py) in [
            (32, 24),
            (31, 23),
            (40, 30),
            (55, 24),
            (8, 24),
            (32, 0),
            (48, 7),
            (20, 44),
        ] {
            let exact = omega[py * w as usize + px];
            let reference = polar_reference(
                &dir,
                DVec3::NEG_Z,
                2.0,
                (32.0, 24.0, 24.0),
                px as u32,
                py as u32,
                20_000,
            );
            let err = relative(exact, reference);
            worst = worst.max(err);
            assert!(err < 1e-6, "({px}, {py}): {exact} vs {reference}");
        }
        eprintln!("worst relative difference (angular map): {worst:e}");
    }

    #[test]
    fn orthographic_beyond_90_degrees_is_clamped() {
        let wide = cal(FisheyeModel::Orthographic, 250.0);
        let half = cal(FisheyeModel::Orthographic, 180.0);
        for (x, y) in [(40.0, 30.0), (60.0, 24.0), (32.0, 1.0)] {
            assert_eq!(
                wide.pixel_to_direction(64, 48, x, y),
                half.pixel_to_direction(64, 48, x, y)
            );
        }
        let below = DVec3::new(1.0, -0.1, 0.0);
        assert_eq!(wide.direction_to_pixel(64, 48, below), None);
        assert_eq!(wide.solid_angles(64, 48), half.solid_angles(64, 48));
        // The mapping clamps, but a user's calibration is not silently changed: rejected.
        assert!(wide.validate(64, 48).is_err());
    }

    #[test]
    fn bad_inputs_do_not_panic() {
        let (w, h) = (64, 48);
        let mut all: Vec<FisheyeCalibration> = calibrations();
        for bad in [
            FisheyeCalibration {
                fov_deg: 0.0,
                ..Default::default()
            },
            FisheyeCalibration {
                fov_deg: 360.0,
                ..Default::default()
            },
            FisheyeCalibration {
                fov_deg: f64::NAN,
                ..Default::default()
            },
            FisheyeCalibration {
                radius: Some(0.0),
                ..Default::default()
            },
            FisheyeCalibration {
                radius: Some(-3.0),
                ..Default::default()
            },
            FisheyeCalibration {
                radius: Some(f64::INFINITY),
                ..Default::default()
            },
            FisheyeCalibration {
                center: Some([f64::NAN, 1.0]),
                ..Default::default()
            },
            FisheyeCalibration {
                rotation_deg: f64::INFINITY,
                ..Default::default()
            },
        ] {
            assert_eq!(bad.pixel_to_direction(w, h, 32.0, 24.0), None);
            assert_eq!(bad.direction_to_pixel(w, h, DVec3::Y), None);
            assert!(bad.solid_angles(w, h).iter().all(|&o| o == 0.0));
            assert!(bad.validate(w, h).is_err());
            all.push(bad);
        }
        let weird_points = [
            (f64::NAN, 1.0),
            (1.0, f64::NAN),
            (f64::INFINITY, 0.0),
            (f64::NEG_INFINITY, f64::INFINITY),
            (1e300, -1e300),
            (-5.0, 1e18),
        ];
        let weird_dirs = [
            DVec3::ZERO,
            DVec3::splat(f64::NAN),
            DVec3::new(f64::INFINITY, 0.0, 0.0),
            DVec3::new(1e300, 1e300, -1e300),
            DVec3::new(1e-300, 1e-300, 0.0),
            DVec3::new(0.0, -0.0, 0.0),
        ];
        for c in &all {
            for (x, y) in weird_points {
                assert_eq!(c.pixel_to_direction(w, h, x, y), None);
            }
            for d in weird_dirs {
                if let Some((x, y)) = c.direction_to_pixel(w, h, d) {
                    assert!(x.is_finite() && y.is_finite());
                }
            }
            assert!(c.direction_to_pixel(w, h, DVec3::ZERO).is_none());
            assert!(c.solid_angles(0, 0).is_empty());
            assert!(c.pixel_to_direction(0, 5, 0.0, 0.0).is_none());
        }
        for (x, y) in weird_points {
            assert_eq!(angular_pixel_to_direction(w, h, x, y), None);
        }
        for d in weird_dirs {
            if let Some((x, y)) = angular_direction_to_pixel(w, h, d) {
                assert!(x.is_finite() && y.is_finite());
            }
        }
        assert_eq!(angular_direction_to_pixel(w, h, DVec3::ZERO), None);
        assert_eq!(angular_pixel_to_direction(0, 0, 0.0, 0.0), None);
        assert!(angular_solid_angles(0, 7).is_empty());
        let huge = DVec3::new(1e300, 1e300, -1e300);
        let (x, y) = angular_direction_to_pixel(w, h, huge).unwrap_or((f64::NAN, f64::NAN));
        let d = angular_pixel_to_direction(w, h, x, y).unwrap_or(DVec3::ZERO);
        // huge components are rescaled, not overflowed: same pixel as the unit direction
        assert!(
            (d - DVec3::new(1.0, 1.0, -1.0) / 3f64.sqrt()).length() < 1e-12,
            "{d}"
        );
        let c = FisheyeCalibration::default();
        let p = c.direction_to_pixel(w, h, DVec3::new(1e300, 1e300, -1e300));
        let q = c.direction_to_pixel(w, h, DVec3::new(1.0, 1.0, -1.0));
        assert!(p.is_some() && p == q, "{p:?} vs {q:?}");
    }

    #[test]
    fn validate_names_the_bad_field() {
        let ok = FisheyeCalibration::default();
        assert_eq!(ok.validate(64, 48), Ok(()));
        let msg = |c: FisheyeCalibration| c.validate(64, 48).err().unwrap_or_default();
        let m = msg(FisheyeCalibration {
            fov_deg: 400.0,
            ..ok
        });
        assert!(m.contains("fov_deg") && m.contains("400"), "{m}");
        let m = msg(FisheyeCalibration {
            radius: Some(-2.5),
            ..ok
        });
        assert!(m.contains("radius") && m.contains("-2.5"), "{m}");
        let m = msg(FisheyeCalibration {
            center: Some([f64::INFINITY, 3.0]),
            ..ok
        });
        assert!(m.contains("center") && m.contains("inf"), "{m}");
        let m = msg(FisheyeCalibration {
            rotation_deg: f64::NAN,
            ..ok
        });
        assert!(m.contains("rotation_deg") && m.contains("NaN"), "{m}");
        let m = msg(FisheyeCalibration {
            model: FisheyeModel::Orthographic,
            fov_deg: 200.0,
            ..ok
        });
        assert!(m.contains("fov_deg") && m.contains("orthographic"), "{m}");
        assert_eq!(
            FisheyeCalibration {
                model: FisheyeModel::Orthographic,
                ..ok
            }
            .validate(64, 48),
            Ok(())
        );
        let m = msg(FisheyeCalibration {
            center: Some([200.0, 24.0]),
            radius: Some(10.0),
            ..ok
        });
        assert!(m.contains("does not overlap"), "{m}");
        // Inside the image but between pixel centres: every pixel's solid angle would be 0.
        let m = msg(FisheyeCalibration {
            center: Some([32.0, 24.0]),
            radius: Some(0.6),
            ..ok
        });
        assert!(m.contains("contains no pixel centre"), "{m}");
        for radius in [0.71, 1e6] {
            let fits = FisheyeCalibration {
                center: Some([32.0, 24.0]),
                radius: Some(radius),
                ..ok
            };
            assert_eq!(fits.validate(64, 48), Ok(()), "radius {radius}");
        }
        // Far beyond any sensor (and at 1e300 every solid angle underflowed to 0).
        for radius in [1.1e6, 1e300] {
            let m = msg(FisheyeCalibration {
                radius: Some(radius),
                ..ok
            });
            assert!(m.contains("radius") && m.contains("1e6"), "{m}");
        }
        let m = ok.validate(0, 48).err().unwrap_or_default();
        assert!(m.contains("0x48"), "{m}");
        // circle partly outside the image is fine
        assert_eq!(
            FisheyeCalibration {
                center: Some([70.0, 24.0]),
                radius: Some(10.0),
                ..ok
            }
            .validate(64, 48),
            Ok(())
        );
    }
}
