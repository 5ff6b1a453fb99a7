//! Spherical harmonics: the environment's radiance projected onto the real SH basis up to a
//! degree L ((L + 1)² coefficients per channel), the representation engines use for ambient and
//! diffuse light (three.js `SphericalHarmonics3`, light probes) — 27 numbers at L = 2 instead
//! of hundreds of lights.
//!
//! **Basis.** Real, orthonormal over the sphere, *without* the Condon–Shortley phase, in
//! envlight's own axes (right-handed, +Y up; the polar axis of the formulas is +Z):
//!
//! ```text
//! Y_l^0  = K_l^0 · P_l^0(z)
//! Y_l^m  = √2 K_l^m · P_l^m(z) / sin^m θ · Re (x + iy)^m     (m > 0)
//! Y_l^−m = √2 K_l^m · P_l^m(z) / sin^m θ · Im (x + iy)^m
//! K_l^m  = √((2l + 1)/(4π) · (l − m)!/(l + m)!)
//! ```
//!
//! with P_l^m the associated Legendre functions without the (−1)^m factor. Coefficient
//! `l² + l + m` holds Y_l^m. Up to degree 2 these are the nine polynomials of
//! Sloan's "Stupid Spherical Harmonics Tricks" with the signs taken positive, exactly those
//! of three.js: 0.282095; 0.488603 y, 0.488603 z, 0.488603 x; 1.092548 xy, 1.092548 yz,
//! 0.315392 (3z² − 1), 1.092548 xz, 0.546274 (x² − y²).
//!
//! **Evaluation** ([`Basis`]): Re and Im of (x + iy)^m by the complex product, and
//! P_l^m / sin^m θ — a polynomial in z — by the standard three-term recurrence in l, so no
//! trigonometry and no division by sin θ at the poles.
//!
//! **Projection** of a frame ([`Projector`]): L_lm = ∫ L(ω) Y_lm(ω) dω ≈ Σ_pixels rgb ·
//! Y_lm(centre) · Ω, with each pixel's exact solid angle ([`Projection::solid_angles`]) and
//! centre direction, summed in f64 (a sun 10⁴× the sky is not lost); non-finite and negative
//! pixels count as 0 (the decomposition warns about them). What depends on the frame's shape
//! is a plan built once; a lat-long frame is summed separably, row by row through Fourier
//! sums in φ, any other through per-pixel weights Y_lm · Ω kept in the plan. The pixels are
//! summed in fixed bands, so the result does not depend on the number of threads. A fisheye
//! sees only the upper hemisphere: the lower one counts as black, as for the lights.
//!
//! **Irradiance** (Ramamoorthi & Hanrahan 2001, "An Efficient Representation for Irradiance
//! Environment Maps"): the clamped cosine is zonal, so E(n) = Σ_l Â_l Σ_m L_lm Y_lm(n) with
//! Â_0 = π, Â_1 = 2π/3, Â_2 = π/4, Â_odd>1 = 0 ([`cosine_lobe_factor`]). Degree 2 holds the
//! irradiance of real maps to 1–7.5 % (relative RMS; the larger errors with a sun), where a few
//! dozen lights do better on sunny maps (docs/sh.md measures both).

use crate::decompose::distribution::dot;
use crate::envmap::Projection;
use crate::frame::HdrFrame;
use crate::light::Light;
use glam::DVec3;
use rayon::prelude::*;
use std::f64::consts::PI;

/// The highest degree envlight computes (256 coefficients per channel).
pub const MAX_DEGREE: usize = 15;

/// Number of coefficients per channel of a set of degree `degree`: (degree + 1)².
pub const fn coefficient_count(degree: usize) -> usize {
    (degree + 1) * (degree + 1)
}

/// The degree L of a list of `count` coefficients: `Some(L)` when `count` is (L + 1)² with
/// L ≤ [`MAX_DEGREE`].
pub fn degree_of(count: usize) -> Option<usize> {
    (0..=MAX_DEGREE).find(|&l| coefficient_count(l) == count)
}

/// Position of Y_l^m in a coefficient list: l² + l + m (|m| ≤ l).
pub const fn index(l: usize, m: isize) -> usize {
    (l * l + l).wrapping_add_signed(m)
}

/// Â_l: the clamped cosine max(cos θ, 0) convolved with band l, so that irradiance is
/// E(n) = Σ_l Â_l Σ_m L_lm Y_lm(n). π, 2π/3, π/4, 0, −π/24, 0, π/64, …; 0 for odd l > 1.
pub fn cosine_lobe_factor(l: usize) -> f64 {
    match l {
        0 => PI,
        1 => 2.0 * PI / 3.0,
        _ if l % 2 == 1 => 0.0,
        _ => {
            // 2π (−1)^(l/2 − 1) / ((l + 2)(l − 1)) · l! / (2^l ((l/2)!)²); the last factor is
            // the central binomial coefficient over 2^l, built up as a product.
            let half = l / 2;
            let mut central = 1.0f64;
            for k in 1..=half {
                central *= (half + k) as f64 / k as f64 / 4.0;
            }
            let sign = if half % 2 == 1 { 1.0 } else { -1.0 };
            2.0 * PI * sign * central / ((l + 2) as f64 * (l - 1) as f64)
        }
    }
}

/// g_l ≈ exp(−l(l + 1)/(2λ)): band l of a spherical Gaussian lobe exp(λ(cos θ − 1))
/// normalised to integral 1, relative to band 0 (the lobe's convolution factor, as Â_l is the
/// clamped cosine's). The heat-kernel form of the exact ratio i_l(λ)/i_0(λ) of modified
/// spherical Bessel functions: within 1.5 % of it for λ ≥ 10 at l = 1 and 2, but 13 % above it
/// at λ = 2 (α = 0.5 as a GGX lobe) and 17 % at λ = 1, where it blurs less than the lobe does.
/// 1 for l = 0; 0 for a sharpness that is not positive (a uniform lobe).
pub fn gaussian_lobe_factor(l: usize, sharpness: f64) -> f64 {
    if l == 0 {
        return 1.0;
    }
    if sharpness.is_nan() || sharpness <= 0.0 {
        return 0.0;
    }
    (-((l * (l + 1)) as f64) / (2.0 * sharpness)).exp()
}

/// The real SH basis up to a degree, with its normalisation constants computed once.
#[derive(Clone, Debug)]
pub struct Basis {
    degree: usize,
    /// K_l^m (×√2 for m > 0) at `l * (l + 1) / 2 + m`, m ≥ 0.
    norm: Vec<f64>,
}

impl Basis {
    /// The basis up to `degree` (at most [`MAX_DEGREE`]; larger degrees are clamped to it).
    pub fn new(degree: usize) -> Self {
        let degree = degree.min(MAX_DEGREE);
        let mut norm = Vec::with_capacity((degree + 1) * (degree + 2) / 2);
        for l in 0..=degree {
            for m in 0..=l {
                // (l − m)!/(l + m)! as the product of 1/k for k in l − m + 1 ..= l + m.
                let ratio: f64 = ((l - m + 1)..=(l + m)).map(|k| 1.0 / k as f64).product();
                let k = ((2 * l + 1) as f64 / (4.0 * PI) * ratio).sqrt();
                norm.push(if m == 0 {
                    k
                } else {
                    k * std::f64::consts::SQRT_2
                });
            }
        }
        Self { degree, norm }
    }

    /// The degree L.
    pub fn degree(&self) -> usize {
        self.degree
    }

    /// K_l^m (×√2 for m > 0) at `l * (l + 1) / 2 + m`, m ≥ 0: the constants
    /// [`Basis::evaluate`] multiplies the recurrences' polynomials by.
    pub fn norms(&self) -> &[f64] {
        &self.norm
    }

    /// Number of coefficients, (L + 1)².
    pub fn len(&self) -> usize {
        coefficient_count(self.degree)
    }

    /// Always false: a basis has at least Y_0^0.
    pub fn is_empty(&self) -> bool {
        false
    }

    /// Y_lm(d) for every coefficient into `out` (at least [`Basis::len`] long). `d` must be a
    /// unit vector (the formulas are polynomials in its components).
    pub fn evaluate(&self, d: DVec3, out: &mut [f64]) {
        let (x, y, z) = (d.x, d.y, d.z);
        // Re, Im of (x + iy)^m, and Q_m^m = (2m − 1)!! (P_m^m / sin^m θ).
        let (mut re, mut im) = (1.0f64, 0.0f64);
        let mut q_diagonal = 1.0f64;
        for m in 0..=self.degree {
            if m > 0 {
                (re, im) = (re * x - im * y, re * y + im * x);
                q_diagonal *= (2 * m - 1) as f64;
            }
            // Q_l^m for l = m, m + 1, …: Q_{m+1}^m = (2m + 1) z Q_m^m,
            // Q_l^m = ((2l − 1) z Q_{l−1}^m − (l + m − 1) Q_{l−2}^m) / (l − m).
            let (mut q_before, mut q) = (0.0f64, q_diagonal);
            for l in m..=self.degree {
                if l > m {
                    let next = ((2 * l - 1) as f64 * z * q - (l + m - 1) as f64 * q_before)
                        / (l - m) as f64;
                    (q_before, q) = (q, next);
                }
                let nq = self.norm[l * (l + 1) / 2 + m] * q;
                let mi = m as isize;
                if m == 0 {
                    out[index(l, 0)] = nq;
                } else {
                    out[index(l, mi)] = nq * re;
                    out[index(l, -mi)] = nq * im;
                }
            }
        }
    }
}

/// Radiance SH coefficients of one environment, per channel (W/(m²·sr) · sr^½ … in short: the
/// projection of radiance, so Σ_lm L_lm Y_lm(ω) approximates L(ω)).
#[derive(Clone, Debug, PartialEq)]
pub struct ShCoefficients {
    degree: usize,
    rgb: Vec<[f64; 3]>,
}

impl ShCoefficients {
    /// All zero, of degree `degree` (clamped to [`MAX_DEGREE`]).
    pub fn zero(degree: usize) -> Self {
        let degree = degree.min(MAX_DEGREE);
        Self {
            degree,
            rgb: vec![[0.0; 3]; coefficient_count(degree)],
        }
    }

    /// From a coefficient list whose length is a square (L + 1)² with L ≤ [`MAX_DEGREE`];
    /// `None` otherwise.
    pub fn from_rgb(rgb: Vec<[f64; 3]>) -> Option<Self> {
        let degree = degree_of(rgb.len())?;
        Some(Self { degree, rgb })
    }

    /// The projection of a light list: each light a point of energy `rgb` at `dir`, so
    /// L_lm = Σ rgb · Y_lm(dir). Lights with a non-unit or non-finite direction are skipped.
    pub fn from_lights(lights: &[Light], degree: usize) -> Self {
        let mut set = Self::zero(degree);
        let basis = Basis::new(set.degree);
        let mut y = vec![0.0; basis.len()];
        for light in lights {
            let d = DVec3::from(light.dir.map(f64::from));
            if !d.is_finite() || (d.length() - 1.0).abs() > 1e-3 {
                continue;
            }
            basis.evaluate(d.normalize(), &mut y);
            for (coefficient, &yi) in set.rgb.iter_mut().zip(&y) {
                for c in 0..3 {
                    coefficient[c] += f64::from(light.rgb[c]) * yi;
                }
            }
        }
        set
    }

    /// The degree L.
    pub fn degree(&self) -> usize {
        self.degree
    }

    /// The (L + 1)² coefficients, at [`index`]`(l, m)`.
    pub fn rgb(&self) -> &[[f64; 3]] {
        &self.rgb
    }

    /// The coefficients as one flat slice (r, g, b of coefficient 0, then of 1, …), to change
    /// in place (a temporal filter, [`crate::set_filter`]).
    pub fn values_mut(&mut self) -> &mut [f64] {
        bytemuck::cast_slice_mut(&mut self.rgb)
    }

    /// The coefficients up to degree `degree` (all of them if it is not lower).
    pub fn truncated(&self, degree: usize) -> Self {
        let degree = degree.min(self.degree);
        Self {
            degree,
            rgb: self.rgb[..coefficient_count(degree)].to_vec(),
        }
    }

    /// ∫ L dω per channel (W/m², the counterpart of the sum of a light list's `rgb`):
    /// L_00 · √(4π), since Y_0^0 = 1/√(4π). Exact for a projected map, whatever the degree.
    pub fn integral(&self) -> [f64; 3] {
        self.rgb[0].map(|v| v * (4.0 * PI).sqrt())
    }

    /// The band-limited radiance Σ L_lm Y_lm(d) towards unit direction `d`.
    pub fn radiance(&self, d: DVec3) -> [f64; 3] {
        self.weighted_sum(d, |_| 1.0)
    }

    /// Irradiance at a surface of unit normal `n` (W/m², per channel), from the coefficients
    /// convolved with the clamped cosine ([`cosine_lobe_factor`]).
    pub fn irradiance(&self, n: DVec3) -> [f64; 3] {
        self.weighted_sum(n, cosine_lobe_factor)
    }

    /// The radiance around unit direction `r` averaged under a normalised spherical Gaussian
    /// lobe exp(λ(r·ω − 1)) of sharpness `sharpness` = λ > 0: Σ_l g_l Σ_m L_lm Y_lm(r) with
    /// g_l = [`gaussian_lobe_factor`]`(l, λ)` — a glossy reflection's prefiltered radiance.
    pub fn prefiltered_radiance(&self, r: DVec3, sharpness: f64) -> [f64; 3] {
        self.weighted_sum(r, |l| gaussian_lobe_factor(l, sharpness))
    }

    fn weighted_sum(&self, d: DVec3, band_factor: impl Fn(usize) -> f64) -> [f64; 3] {
        let basis = Basis::new(self.degree);
        let mut y = vec![0.0; basis.len()];
        basis.evaluate(d, &mut y);
        let mut sum = [0.0; 3];
        for l in 0..=self.degree {
            let factor = band_factor(l);
            for i in l * l..coefficient_count(l) {
                for c in 0..3 {
                    sum[c] += factor * self.rgb[i][c] * y[i];
                }
            }
        }
        sum
    }
}

/// Rows summed together by one task of [`Projector::project`]: a fixed split, so the f64 sums
/// (and the coefficients, bit for bit) do not depend on the number of threads.
const ROWS_PER_BAND: usize = 8;

/// The most numbers a lat-long plan's per-row tables may hold (f64: 64 MiB); a larger degree
/// and height take the per-pixel path instead.
const MAX_ROW_TABLE: usize = 8 << 20;

/// The most basis weights a per-pixel plan may keep (f32: 96 MiB, a 1280 × 960 fisheye to
/// degree 4); beyond, the basis is evaluated at every pixel of every frame.
const MAX_WEIGHTS: usize = 24 << 20;

/// Pixels summed together by one task of the weights path (fixed, as [`ROWS_PER_BAND`]).
const PIXELS_PER_BAND: usize = 8192;

/// Projects frames of one shape (size and projection) onto the SH basis, with what depends
/// only on the shape computed once.
///
/// Two paths, the same sums up to rounding:
/// - **lat-long** (separable): along a row θ is fixed and φ = 2π(x + ½)/W, and every Y_lm of
///   degree ≤ L is a trigonometric polynomial of degree ≤ L in φ there. So per row the pixels
///   are first summed against cos kφ and sin kφ, k ≤ L (2L + 1 sums per channel, from a table
///   per column), and the coefficients follow from those sums and each row's Fourier
///   coefficients of the Y_lm — found once per plan from 2L + 1 samples of each Y_lm along
///   the row, exact for such polynomials. 15 multiply-adds a pixel at degree 2 instead of a
///   basis evaluation;
/// - **any projection** (fisheye, angular map, or a lat-long plan whose row tables would
///   exceed 64 MiB): per pixel that sees something, Y_lm at its centre times its solid angle,
///   kept as f32 weights when they fit in 96 MiB (a 1280 × 960 fisheye's 0.72 million seen
///   pixels: 26 MB at degree 2, 72 MB at degree 4) and multiplied with the pixel's radiance
///   each frame; beyond that the basis is evaluated at each pixel's centre direction every
///   frame, 64 pixels at a time so that the recurrences vectorise across pixels.
#[derive(Clone, Debug)]
pub struct Projector {
    basis: Basis,
    width: u32,
    height: u32,
    projection: Projection,
    summation: Summation,
}

/// Defines `$dispatch(&self, …)`, which runs `$body` compiled for AVX2 (as `$avx2`) where the
/// CPU has it and as built otherwise: the same code, so the same sums, in both. `$body` is
/// `#[inline(always)]` so that it is compiled into each.
macro_rules! avx2_dispatch {
    (
        $(#[$doc:meta])*
        fn $dispatch:ident / $avx2:ident => $body:ident($($arg:ident: $ty:ty),* $(,)?) -> $ret:ty
    ) => {
        $(#[$doc])*
        fn $dispatch(&self, $($arg: $ty),*) -> $ret {
            #[cfg(target_arch = "x86_64")]
            {
                if std::arch::is_x86_feature_detected!("avx2") {
                    // SAFETY: the CPU supports AVX2 (checked just above).
                    return unsafe { self.$avx2($($arg),*) };
                }
            }
            self.$body($($arg),*)
        }

        #[cfg(target_arch = "x86_64")]
        #[target_feature(enable = "avx2")]
        fn $avx2(&self, $($arg: $ty),*) -> $ret {
            self.$body($($arg),*)
        }
    };
}

#[derive(Clone, Debug)]
enum Summation {
    LatLong {
        /// Term-major: for each of the 2L + 1 functions 1, cos φ, sin φ, cos 2φ, sin 2φ, …
        /// its value at every column.
        trig: Vec<f64>,
        /// Per row, its pixels' solid angle times the (L + 1)² × (2L + 1) Fourier coefficients
        /// of the Y_lm along it, in the order of `trig`.
        rows: Vec<f64>,
    },
    Weights {
        /// The pixels that see something (index in the frame), in row-major order.
        pixels: Vec<u32>,
        /// Per such pixel, Y_lm(centre) · Ω for each coefficient.
        weights: Vec<f32>,
    },
    PerPixel {
        /// Per pixel, row-major: unit centre direction and solid angle (0 where the image sees
        /// nothing, outside a fisheye's circle).
        samples: Vec<([f64; 3], f64)>,
    },
}

impl Projector {
    /// The plan for `width` × `height` frames of `projection`, up to `degree` (clamped to
    /// [`MAX_DEGREE`]).
    pub fn new(degree: usize, width: u32, height: u32, projection: Projection) -> Self {
        let basis = Basis::new(degree);
        let terms = 2 * basis.degree() + 1;
        let summation = if projection == Projection::LatLong
            && (height as usize)
                .saturating_mul(basis.len())
                .saturating_mul(terms)
                <= MAX_ROW_TABLE
        {
            Self::latlong_path(&basis, width, height)
        } else {
            let per_pixel = Self::per_pixel_path(width, height, projection);
            Self::weights_path(&basis, per_pixel)
        };
        Self {
            basis,
            width,
            height,
            projection,
            summation,
        }
    }

    fn latlong_path(basis: &Basis, width: u32, height: u32) -> Summation {
        let degree = basis.degree();
        let terms = 2 * degree + 1;
        let harmonics = |phi: f64, out: &mut [f64]| {
            out[0] = 1.0;
            for k in 1..=degree {
                let (sin, cos) = (k as f64 * phi).sin_cos();
                out[2 * k - 1] = cos;
                out[2 * k] = sin;
            }
        };
        let mut trig = vec![0.0; width as usize * terms];
        let mut values = vec![0.0; terms];
        for x in 0..width as usize {
            harmonics(2.0 * PI * (x as f64 + 0.5) / f64::from(width), &mut values);
            for (t, &v) in values.iter().enumerate() {
                trig[t * width as usize + x] = v;
            }
        }
        let count = basis.len();
        let solid_angles = Projection::LatLong.solid_angles(width, 1.max(height));
        let mut rows = vec![0.0; height as usize * count * terms];
        let mut y = vec![0.0; count];
        let mut samples = vec![0.0; terms];
        for (row, table) in rows.chunks_exact_mut(count * terms).enumerate() {
            let omega = solid_angles[row * width as usize];
            // Y_lm at 2L + 1 equally spaced φ along the row, then their discrete Fourier
            // coefficients: exact for trigonometric polynomials of degree ≤ L.
            for j in 0..terms {
                let phi = 2.0 * PI * j as f64 / terms as f64;
                let d = Projection::LatLong
                    .pixel_to_direction(
                        width,
                        height,
                        phi / (2.0 * PI) * f64::from(width),
                        row as f64 + 0.5,
                    )
                    .unwrap_or(DVec3::Y);
                basis.evaluate(d, &mut y);
                harmonics(phi, &mut samples);
                for i in 0..count {
                    for t in 0..terms {
                        let weight = if t == 0 { 1.0 } else { 2.0 };
                        table[i * terms + t] += omega * weight / terms as f64 * y[i] * samples[t];
                    }
                }
            }
        }
        Summation::LatLong { trig, rows }
    }

    fn per_pixel_path(width: u32, height: u32, projection: Projection) -> Summation {
        let solid_angles = projection.solid_angles(width, height);
        let samples = solid_angles
            .iter()
            .enumerate()
            .map(|(i, &omega)| {
                let (x, y) = (i % width as usize, i / width as usize);
                match projection.pixel_to_direction(width, height, x as f64 + 0.5, y as f64 + 0.5) {
                    Some(d) if omega > 0.0 && d.is_finite() => (d.normalize().to_array(), omega),
                    _ => ([0.0, 1.0, 0.0], 0.0),
                }
            })
            .collect();
        Summation::PerPixel { samples }
    }

    /// The per-pixel plan as f32 weights, if they fit in [`MAX_WEIGHTS`].
    fn weights_path(basis: &Basis, per_pixel: Summation) -> Summation {
        let Summation::PerPixel { samples } = &per_pixel else {
            return per_pixel;
        };
        let seen = samples.iter().filter(|(_, omega)| *omega > 0.0).count();
        if seen.saturating_mul(basis.len()) > MAX_WEIGHTS || samples.len() > u32::MAX as usize {
            return per_pixel;
        }
        let mut pixels = Vec::with_capacity(seen);
        let mut weights = Vec::with_capacity(seen * basis.len());
        let mut y = vec![0.0; basis.len()];
        for (i, &(dir, omega)) in samples.iter().enumerate() {
            if omega > 0.0 {
                basis.evaluate(DVec3::from(dir), &mut y);
                pixels.push(i as u32);
                weights.extend(y.iter().map(|&v| (v * omega) as f32));
            }
        }
        Summation::Weights { pixels, weights }
    }

    /// The same plan forced onto the per-pixel path (to check the separable one against it).
    #[cfg(test)]
    fn per_pixel(degree: usize, width: u32, height: u32, projection: Projection) -> Self {
        Self {
            basis: Basis::new(degree),
            width,
            height,
            projection,
            summation: Self::per_pixel_path(width, height, projection),
        }
    }

    /// Whether `frame` has the shape this plan was built for.
    pub fn fits(&self, frame: &HdrFrame) -> bool {
        frame.width == self.width
            && frame.height == self.height
            && frame.projection == self.projection
    }

    /// The degree of the coefficients it computes.
    pub fn degree(&self) -> usize {
        self.basis.degree()
    }

    /// The coefficients of `frame`, or `None` if the frame's shape is not the plan's
    /// ([`Projector::fits`]).
    pub fn project(&self, frame: &HdrFrame) -> Option<ShCoefficients> {
        if !self.fits(frame) {
            return None;
        }
        let width = self.width as usize;
        let band_pixels = width * ROWS_PER_BAND;
        let partial_sums: Vec<Vec<[f64; 3]>> = match &self.summation {
            Summation::LatLong { trig, rows } => {
                let table_len = rows.len() / self.height.max(1) as usize;
                frame
                    .pixels
                    .par_chunks(band_pixels)
                    .zip(rows.par_chunks(table_len * ROWS_PER_BAND))
                    .map(|(pixels, tables)| self.latlong_band_dispatch(pixels, tables, trig))
                    .collect()
            }
            Summation::Weights { pixels, weights } => pixels
                .par_chunks(PIXELS_PER_BAND)
                .zip(weights.par_chunks(PIXELS_PER_BAND * self.basis.len()))
                .map(|(indices, weights)| {
                    self.weights_band_dispatch(&frame.pixels, indices, weights)
                })
                .collect(),
            Summation::PerPixel { samples } => frame
                .pixels
                .par_chunks(band_pixels)
                .zip(samples.par_chunks(band_pixels))
                .map(|(pixels, samples)| self.per_pixel_band_dispatch(pixels, samples))
                .collect(),
        };
        let mut set = ShCoefficients::zero(self.basis.degree());
        for sums in partial_sums {
            for (total, part) in set.rgb.iter_mut().zip(sums) {
                for c in 0..3 {
                    total[c] += part[c];
                }
            }
        }
        Some(set)
    }

    avx2_dispatch! {
        /// [`Projector::latlong_band`] compiled for AVX2 where the CPU has it (the same sums, bit
        /// for bit: [`dot`] keeps four running sums whatever the vector width).
        fn latlong_band_dispatch / latlong_band_avx2 => latlong_band(
            pixels: &[[f32; 3]],
            tables: &[f64],
            trig: &[f64],
        ) -> Vec<[f64; 3]>
    }

    /// The sums of a band of lat-long rows: per row its Fourier sums, then the coefficients.
    #[inline(always)]
    fn latlong_band(&self, pixels: &[[f32; 3]], tables: &[f64], trig: &[f64]) -> Vec<[f64; 3]> {
        let count = self.basis.len();
        let terms = 2 * self.basis.degree() + 1;
        let width = self.width as usize;
        let mut sums = vec![[0.0f64; 3]; count];
        let mut fourier = vec![[0.0f64; 3]; terms];
        // The row's radiance, one channel after another, for contiguous dot products.
        let mut channels = vec![0.0f64; 3 * width];
        for (row, table) in pixels
            .chunks_exact(width)
            .zip(tables.chunks_exact(count * terms))
        {
            for (x, rgb) in row.iter().enumerate() {
                for c in 0..3 {
                    channels[c * width + x] = clean(rgb[c]);
                }
            }
            for (f, harmonic) in fourier.iter_mut().zip(trig.chunks_exact(width)) {
                for c in 0..3 {
                    f[c] = dot(&channels[c * width..(c + 1) * width], harmonic);
                }
            }
            for (sum, weights) in sums.iter_mut().zip(table.chunks_exact(terms)) {
                for (f, &w) in fourier.iter().zip(weights) {
                    for c in 0..3 {
                        sum[c] += f[c] * w;
                    }
                }
            }
        }
        sums
    }

    avx2_dispatch! {
        /// [`Projector::weights_band`] compiled for AVX2 where the CPU has it (the same sums).
        fn weights_band_dispatch / weights_band_avx2 => weights_band(
            frame: &[[f32; 3]],
            indices: &[u32],
            weights: &[f32],
        ) -> Vec<[f64; 3]>
    }

    /// The sums of a band of seen pixels against their weights, one channel's sums beside
    /// another's so that the loop over the coefficients is a vector operation.
    #[inline(always)]
    fn weights_band(&self, frame: &[[f32; 3]], indices: &[u32], weights: &[f32]) -> Vec<[f64; 3]> {
        let count = self.basis.len();
        let mut channels = vec![0.0f64; 3 * count];
        let (red, rest) = channels.split_at_mut(count);
        let (green, blue) = rest.split_at_mut(count);
        for (&index, weights) in indices.iter().zip(weights.chunks_exact(count)) {
            // The plan fits the frame, so every index is in it.
            let Some(rgb) = frame.get(index as usize) else {
                continue;
            };
            let [r, g, b] = rgb.map(clean);
            if [r, g, b] == [0.0; 3] {
                continue;
            }
            for (((sr, sg), sb), &w) in red.iter_mut().zip(&mut *green).zip(&mut *blue).zip(weights)
            {
                let w = f64::from(w);
                *sr += r * w;
                *sg += g * w;
                *sb += b * w;
            }
        }
        (0..count)
            .map(|i| [channels[i], channels[count + i], channels[2 * count + i]])
            .collect()
    }

    avx2_dispatch! {
        /// [`Projector::per_pixel_band`] compiled for AVX2 where the CPU has it (the same sums).
        fn per_pixel_band_dispatch / per_pixel_band_avx2 => per_pixel_band(
            pixels: &[[f32; 3]],
            samples: &[([f64; 3], f64)],
        ) -> Vec<[f64; 3]>
    }

    /// The per-pixel path's sums over one band: the pixels that see something and hold light
    /// are gathered [`LANES`] at a time and their basis values computed lane by lane
    /// ([`Projector::accumulate_lanes`]), so the compiler vectorises across pixels.
    #[inline(always)]
    fn per_pixel_band(&self, pixels: &[[f32; 3]], samples: &[([f64; 3], f64)]) -> Vec<[f64; 3]> {
        let mut sums = vec![[0.0f64; 3]; self.basis.len()];
        let mut lanes = Lanes::empty();
        for (rgb, &(dir, omega)) in pixels.iter().zip(samples) {
            if omega == 0.0 {
                continue;
            }
            let energy = rgb.map(|v| clean(v) * omega);
            if energy == [0.0; 3] {
                continue;
            }
            lanes.push(dir, energy);
            if lanes.len == LANES {
                self.accumulate_lanes(&lanes, &mut sums);
                lanes = Lanes::empty();
            }
        }
        if lanes.len > 0 {
            // The unused lanes hold no energy: they add nothing.
            self.accumulate_lanes(&lanes, &mut sums);
        }
        sums
    }

    /// Adds Σ_pixels energy · Y_lm(direction) of every lane to `sums`: the recurrences of
    /// [`Basis::evaluate`] run for all lanes at once — Re, Im of (x + iy)^m by complex
    /// products, Q_l^m by the three-term recurrence in l from the diagonal (2m − 1)!!, the
    /// same for every pixel — and each (l, m) is summed over the lanes in a fixed order (the
    /// same sums whatever the vector width).
    #[inline(always)]
    fn accumulate_lanes(&self, lanes: &Lanes, sums: &mut [[f64; 3]]) {
        let degree = self.basis.degree();
        let (x, y, z) = (&lanes.x, &lanes.y, &lanes.z);
        let mut re = [1.0f64; LANES];
        let mut im = [0.0f64; LANES];
        let mut energy_re = lanes.energy;
        let mut energy_im = [[0.0f64; LANES]; 3];
        let mut q_diagonal = 1.0f64;
        let mut q_before = [0.0f64; LANES];
        let mut q = [0.0f64; LANES];
        for m in 0..=degree {
            if m > 0 {
                for p in 0..LANES {
                    (re[p], im[p]) = (re[p] * x[p] - im[p] * y[p], re[p] * y[p] + im[p] * x[p]);
                }
                for c in 0..3 {
                    for p in 0..LANES {
                        energy_re[c][p] = lanes.energy[c][p] * re[p];
                        energy_im[c][p] = lanes.energy[c][p] * im[p];
                    }
                }
                q_diagonal *= (2 * m - 1) as f64;
            }
            q_before.fill(0.0);
            q.fill(q_diagonal);
            for l in m..=degree {
                // Step the recurrence (past the diagonal) and sum the six products
                // energy_{re,im}[c] · Q_l^m in one pass, eight running sums each: 48
                // independent additions, so the sums do not wait on one another.
                let (a, b) = if l > m {
                    (
                        (2 * l - 1) as f64 / (l - m) as f64,
                        (l + m - 1) as f64 / (l - m) as f64,
                    )
                } else {
                    (0.0, 0.0)
                };
                let mut acc = [[0.0f64; 8]; 6];
                for p8 in (0..LANES).step_by(8) {
                    for k in 0..8 {
                        let p = p8 + k;
                        if l > m {
                            let next = a * z[p] * q[p] - b * q_before[p];
                            q_before[p] = q[p];
                            q[p] = next;
                        }
                        let t = q[p];
                        for c in 0..3 {
                            acc[c][k] += energy_re[c][p] * t;
                            acc[3 + c][k] += energy_im[c][p] * t;
                        }
                    }
                }
                let total =
                    |s: [f64; 8]| ((s[0] + s[1]) + (s[2] + s[3])) + ((s[4] + s[5]) + (s[6] + s[7]));
                let norm = self.basis.norm[l * (l + 1) / 2 + m];
                let mi = m as isize;
                for c in 0..3 {
                    sums[index(l, mi)][c] += norm * total(acc[c]);
                    if m > 0 {
                        sums[index(l, -mi)][c] += norm * total(acc[3 + c]);
                    }
                }
            }
        }
    }
}

/// Pixels gathered for [`Projector::accumulate_lanes`].
const LANES: usize = 64;

/// Up to [`LANES`] pixels' unit directions and energies (radiance × solid angle, per channel),
/// structure of arrays; the lanes past `len` hold no energy.
struct Lanes {
    x: [f64; LANES],
    y: [f64; LANES],
    z: [f64; LANES],
    energy: [[f64; LANES]; 3],
    len: usize,
}

impl Lanes {
    fn empty() -> Self {
        Self {
            x: [0.0; LANES],
            y: [1.0; LANES],
            z: [0.0; LANES],
            energy: [[0.0; LANES]; 3],
            len: 0,
        }
    }

    fn push(&mut self, dir: [f64; 3], energy: [f64; 3]) {
        let p = self.len;
        (self.x[p], self.y[p], self.z[p]) = (dir[0], dir[1], dir[2]);
        for c in 0..3 {
            self.energy[c][p] = energy[c];
        }
        self.len += 1;
    }
}

/// A pixel value as radiance: non-finite and negative values count as 0.
#[inline(always)]
fn clean(v: f32) -> f64 {
    if v.is_finite() && v > 0.0 {
        f64::from(v)
    } else {
        0.0
    }
}

/// The coefficients of one frame: [`Projector::project`] with a plan built for it.
pub fn project(frame: &HdrFrame, degree: usize) -> ShCoefficients {
    let projector = Projector::new(degree, frame.width, frame.height, frame.projection);
    projector
        .project(frame)
        .unwrap_or_else(|| ShCoefficients::zero(degree))
}

#[cfg(test)]
mod tests;
