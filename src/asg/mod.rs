//! Anisotropic spherical Gaussians (ASGs): the lobe model, its integral, and closed-form shading.
//!
//! The ASG of Xu et al. 2013 ("Anisotropic spherical Gaussians", ACM TOG 32(6)) with an
//! orthonormal frame (x, y, z), bandwidths λ, μ > 0 and an RGB amplitude c:
//!
//! ```text
//! G(v) = c · max(v·z, 0) · exp(−λ (v·x)² − μ (v·y)²)
//! ```
//!
//! λ controls the spread along x (the lobe is narrow along x when λ is large), μ along y.
//! Radiance units: c is in W/(m²·sr), so ∫G dω is in W/m² like a light's `rgb` (DESIGN.md).
//!
//! # Integral
//!
//! With z as the pole, (v·x)² = sin²θ cos²φ and (v·y)² = sin²θ sin²φ; substituting s = sin²θ
//! turns the hemisphere integral into a single one over φ:
//!
//! ```text
//! ∫G dω / c = ∫₀^{2π} (1 − e^{−a(φ)}) / (2 a(φ)) dφ,    a(φ) = λ cos²φ + μ sin²φ
//!           = π/√(λμ) − ∫₀^{2π} e^{−a(φ)} / (2 a(φ)) dφ.
//! ```
//!
//! [`integral_approx`] is Xu et al.'s closed form π/√(λμ). Since e^{−a} ≤ e^{−min(λ,μ)}, it
//! overestimates by at most e^{−min(λ,μ)} of itself (below 1 % when both bandwidths exceed 4.6;
//! badly for wide lobes: λ = μ = 0.5 overestimates by 65 %). [`integral`] is
//! exact up to rounding: the φ integrand is smooth and periodic, so the trapezoid rule with
//! [`INTEGRAL_NODES`] nodes converges geometrically. `tests/asg.rs` checks it against a dense
//! 2-D quadrature over the sphere for λ, μ ∈ [0.25, 5000] to that quadrature's own accuracy
//! (5·10⁻⁴ relative; measured 1.6·10⁻⁴ at λ = 2000, μ = 5000).
//!
//! # Lambertian shading ([`Asg::irradiance`])
//!
//! E(n) = ∫ G(v) max(n·v, 0) dω. Near its axis an ASG behaves like a spherical Gaussian
//! e^{ν(v·z − 1)} ≈ e^{−ν θ²/2} with ν = 2λ along x and 2μ along y; we use the isotropic
//! equivalent ν = 2√(λμ) and the exact normalised convolution of the isotropic lobe (λ = μ = ν/2):
//!
//! ```text
//! E(n) ≈ ∫G · H(n·z, ν),   H(t, ν) = ∫ g_ν(v) max(n·v, 0) dω / ∫ g_ν dω
//! ```
//!
//! H is tabulated once (129 values of t × 72 of ln ν, each an exact 1-D integral over the lobe's
//! polar angle, since the azimuthal integral of a clamped cosine has the closed form
//! 2(a·acos(−a/b) + √(b² − a²))) and interpolated bilinearly, which gives the derivatives the
//! fit needs. (Hill's fitted formula for SG irradiance, popular in real-time renderers, turns
//! negative for wide lobes, ν < 1, which the fit needs for skies.) It is exact for isotropic
//! lobes up to interpolation and tends to max(n·z, 0)·∫G for narrow lobes. Stated tolerance
//! (tested against numerical integration over the sphere): |E − E_ref| ≤
//! [`IRRADIANCE_TOLERANCE`] · ∫G for every normal and every lobe with λ, μ ≥ [`MIN_BANDWIDTH`]
//! and anisotropy μ/λ ≤ 8.
//!
//! # GGX shading ([`Asg::ggx_specular`])
//!
//! As Xu et al., the specular lobe is replaced by Gaussians. The GGX NDF is
//! D(h) = f(x)/(πα² cos⁴θ_h) with x = tan²θ_h/α² and f(x) = 1/(1 + x)², and f is fitted by two
//! exponentials Σ wᵢ e^{−cᵢx} ([`GGX_NDF_MIXTURE`]; one e^{−x}, Xu et al.'s, until 2026-12-04,
//! lacks GGX's long tail). Each is an isotropic lobe around n in half-vector space, and the
//! reflection l = 2(h·v)h − v warps it into an *anisotropic* lobe around the mirror direction
//! r = 2(n·v)n − v: in the plane of incidence angles double (bandwidth cᵢ/(4α²)), across it they
//! are scaled by 2(n·v) (bandwidth cᵢ/(4α²(n·v)²)), Xu et al.'s ASG warp. The lobe narrows
//! towards grazing views; an isotropic lobe (what this did before 2026-12-04) keeps its width and
//! so reflects 1/(n·v) times too much there. The product of each warped lobe with the ASG is
//! integrated in closed form in two planes and the two blended by the lobes' widths (weight
//! √(λμ)/(√(λμ) + √(b₁b₂)) for the first):
//!
//! - in the ASG's tangent plane (`product_integral`), where the ASG is exact (its max(l·z, 0)
//!   cancels the Jacobian of the plane) and the warped lobe, seen from the ASG's axis at an
//!   angle, is foreshortened:
//!
//!   ```text
//!   ∫ G(l) W(l) dl ≈ c · π/√det(A + B) · exp(−aᵀ A (A + B)⁻¹ B a)
//!   ```
//!
//!   with A = diag(λ, μ), B the warped lobe's form in the ASG's tangent plane and
//!   a = (r·x, r·y); it vanishes when r is at or beyond the ASG's horizon;
//! - in r's tangent plane (`product_integral_at_mirror`), where the warped lobe is exact and the
//!   ASG is linearised, its max(l·z, 0) a ramp whose mean under the product Gaussian is closed
//!   form: right where the ASG is the wider lobe, and non-zero for an ASG whose axis is 90° or
//!   more from r, part of which a rough surface still sees.
//!
//! Xu et al.'s convolution formula, used here before 2026-12-04, multiplies by max(r·z, 0) and
//! leaves the GGX lobe unforeshortened, which makes lobes seen far off their axes reflect far
//! too much: under an environment of wide lobes it reflected up to 2.5 times the exact value
//! (`ggx_specular_of_an_environment_of_wide_lobes` in `tests/asg.rs`; the ASG's plane alone
//! with one Gaussian: within 20 %; now within 12 %), and a gold sphere under a uniform sky of
//! radiance 1 fitted with 16 lobes reached 7.5 at grazing views (now no pixel above 1,
//! docs/rendering.md). The outgoing radiance is the sum over the two Gaussians times
//! F·G₂/(4 n·v) / (πα²) with Smith's height-correlated masking G₂ and F = f₀ (no Fresnel
//! variation: a constant-reflectance metal). Each plane's product is at most π/√(b₁b₂) for a
//! lobe of unit peak (det(A + B) ≥ det B in the first, the ramp's mean ≤ 1 in the second), and
//! Σ wᵢ/cᵢ = 1, so the result never exceeds f₀·G₂·c ≤ f₀·c: no more than a mirror would reflect
//! of the lobe's peak (`tests/asg.rs` checks it down to n·v = 0.01). Tolerance at normal
//! incidence (n = v), for α ∈ [0.1, 1], λ, μ ≥ 2 and lobe axes within 15° of r:
//! |S − S_ref| ≤ [`GGX_TOLERANCE`] (12 %) of the reference response to the same lobe on the
//! reflection axis (`tests/asg.rs`). Measured: wide lobes (λ = 2) 3–8 % too much (16–28 % with
//! one Gaussian), λ ≥ 10 within 5.4 % (the mixture's peak is 0.96 of GGX's, so narrow lobes
//! on rough surfaces come out up to 5 % low; with one Gaussian they were within 3 % for α ≥ 0.6
//! but up to 23 % too much for α = 0.1). Off normal incidence, for n·v ≥ 0.25 and the same
//! lobes, within [`GGX_OFF_NORMAL_TOLERANCE`] (35 %; measured 34 %, at α = 1 and n·v = 0.25, too
//! little; 31 % with one Gaussian, too much, at α = 0.3 and n·v = 0.5): at n·v ≥ 0.5 the errors
//! are within −12 % to +10 % (one Gaussian: −5 % to +31 %). At grazing views rough surfaces
//! (α ≥ 0.6) reflect too little (the lobe is cut by the horizon and n·l is taken as n·v): at
//! n·v = 0.25 up to 34 %; at n·v = 0.1 up to 71 % (two corrections tried: docs/asg.md).
//!
//! # Parameterisation for optimisation (`src/asg/fit.rs`)
//!
//! Frame: a rotation, updated multiplicatively (R ← exp(\[δ\]×)·R); the gradient with respect to a
//! world-space rotation δ at δ = 0 is Σ_{a ∈ {x,y,z}} a × ∂L/∂a. Bandwidths: λ = λ_min + e^{α},
//! μ = λ_min + e^{β}. Amplitude: c = e^{σ} per channel (scale-free steps for HDR values that span
//! six orders of magnitude). [`Asg::gradients`] gives the analytic derivatives of G(v).
//!
//! The fitting (Clausen et al. 2024) is in [`fit`], the per-frame target it fits (resampling,
//! diffuse ground truth, buffers reused from frame to frame) in [`target`], the f32 loss kernel
//! in [`fast`]; ball renderings and the comparison baselines used by `examples/asg_table.rs` in
//! [`eval`].

pub mod eval;
pub mod fast;
pub mod fit;
mod splat;
pub mod target;
pub mod temporal;

use glam::{DVec2, DVec3};
use std::f64::consts::PI;

/// Smallest bandwidth λ, μ of a lobe: a λ = 0.25 lobe is flat within 25 % over its hemisphere.
pub const MIN_BANDWIDTH: f64 = 0.25;
/// Largest bandwidth a fit produces (a lobe about 0.5° wide, the size of the sun).
pub const MAX_BANDWIDTH: f64 = 1.0e5;
/// Trapezoid nodes over φ ∈ [0, 2π) used by [`integral`].
pub const INTEGRAL_NODES: usize = 256;
/// Absolute tolerance of [`Asg::irradiance`] relative to the lobe's integral (see module doc).
pub const IRRADIANCE_TOLERANCE: f64 = 0.08;
/// Relative tolerance of [`Asg::ggx_specular`] at normal incidence (see module doc).
pub const GGX_TOLERANCE: f64 = 0.12;
/// Relative tolerance of [`Asg::ggx_specular`] for views with n·v ≥ 0.25 (see module doc).
pub const GGX_OFF_NORMAL_TOLERANCE: f64 = 0.35;

/// One anisotropic spherical Gaussian lobe.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Asg {
    /// Lobe axis z (unit).
    pub axis: [f64; 3],
    /// Tangent x (unit, ⟂ axis): the direction of bandwidth λ.
    pub tangent: [f64; 3],
    /// Bitangent y = z × x (unit): the direction of bandwidth μ.
    pub bitangent: [f64; 3],
    /// Bandwidth along the tangent.
    pub lambda: f64,
    /// Bandwidth along the bitangent.
    pub mu: f64,
    /// Amplitude c, linear RGB radiance.
    pub rgb: [f64; 3],
}

/// Derivatives of the scalar shape g(v) = max(v·z,0)·exp(−λ(v·x)² − μ(v·y)²) at one direction.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ShapeGradient {
    /// g(v).
    pub value: f64,
    /// ∂g/∂x, ∂g/∂y, ∂g/∂z (frame vectors treated as free).
    pub d_x: DVec3,
    pub d_y: DVec3,
    pub d_z: DVec3,
    /// ∂g/∂λ, ∂g/∂μ.
    pub d_lambda: f64,
    pub d_mu: f64,
}

impl Asg {
    /// A lobe from an axis and a tangent hint (projected to ⟂ axis; any ⟂ vector if parallel).
    /// Returns `None` for a zero or non-finite axis, or non-finite bandwidths or amplitude.
    pub fn new(
        axis: DVec3,
        tangent_hint: DVec3,
        lambda: f64,
        mu: f64,
        rgb: [f64; 3],
    ) -> Option<Self> {
        let (x, y, z) = orthonormal_frame(axis, tangent_hint)?;
        if !(lambda.is_finite() && mu.is_finite() && lambda > 0.0 && mu > 0.0)
            || rgb.iter().any(|c| !c.is_finite())
        {
            return None;
        }
        Some(Self {
            axis: z.to_array(),
            tangent: x.to_array(),
            bitangent: y.to_array(),
            lambda,
            mu,
            rgb,
        })
    }

    /// The frame (x, y, z).
    #[inline]
    pub fn frame(&self) -> (DVec3, DVec3, DVec3) {
        (
            DVec3::from_array(self.tangent),
            DVec3::from_array(self.bitangent),
            DVec3::from_array(self.axis),
        )
    }

    /// The scalar shape g(v) = max(v·z,0)·exp(−λ(v·x)² − μ(v·y)²) for a unit `v`.
    #[inline]
    pub fn shape(&self, v: DVec3) -> f64 {
        let (x, y, z) = self.frame();
        let s = v.dot(z);
        if s <= 0.0 {
            return 0.0;
        }
        let (a, b) = (v.dot(x), v.dot(y));
        s * (-self.lambda * a * a - self.mu * b * b).exp()
    }

    /// G(v), radiance towards unit direction `v`.
    #[inline]
    pub fn eval(&self, v: DVec3) -> [f64; 3] {
        let g = self.shape(v);
        self.rgb.map(|c| c * g)
    }

    /// The shape g(v) and its analytic derivatives.
    pub fn gradients(&self, v: DVec3) -> ShapeGradient {
        let (x, y, z) = self.frame();
        let s = v.dot(z);
        if s <= 0.0 {
            return ShapeGradient {
                value: 0.0,
                d_x: DVec3::ZERO,
                d_y: DVec3::ZERO,
                d_z: DVec3::ZERO,
                d_lambda: 0.0,
                d_mu: 0.0,
            };
        }
        let (a, b) = (v.dot(x), v.dot(y));
        let e = (-self.lambda * a * a - self.mu * b * b).exp();
        let g = s * e;
        ShapeGradient {
            value: g,
            d_x: v * (-2.0 * self.lambda * a * g),
            d_y: v * (-2.0 * self.mu * b * g),
            d_z: v * e,
            d_lambda: -a * a * g,
            d_mu: -b * b * g,
        }
    }

    /// ∫G dω per channel (exact, [`integral`]).
    pub fn integral(&self) -> [f64; 3] {
        let i = integral(self.lambda, self.mu);
        self.rgb.map(|c| c * i)
    }

    /// Irradiance at a surface with unit normal `n` (Lambertian convolution, module doc).
    pub fn irradiance(&self, n: DVec3) -> [f64; 3] {
        let (_, _, z) = self.frame();
        let nu = 2.0 * (self.lambda * self.mu).sqrt();
        let h = cosine_convolution(n.dot(z), nu).0;
        let i = integral(self.lambda, self.mu) * h;
        self.rgb.map(|c| c * i)
    }

    /// Radiance reflected towards unit `view` (pointing away from the surface) by a GGX surface
    /// with unit normal `n`, roughness α (= perceptual roughness²) and constant reflectance
    /// `f0`, lit by this lobe (spherical-Gaussian approximation, module doc). Zero when the
    /// view is below the surface.
    pub fn ggx_specular(&self, n: DVec3, view: DVec3, alpha: f64, f0: f64) -> [f64; 3] {
        let n_v = n.dot(view);
        if n_v <= 1e-6 {
            return [0.0; 3];
        }
        let alpha = alpha.max(1e-3);
        let a2 = alpha * alpha;
        let r = (2.0 * n_v * n - view).normalize();
        let (x, y, z) = self.frame();
        let warp = ggx_warp(n, r, n_v, a2);
        let lobe_width = (self.lambda * self.mu).sqrt();
        let mut conv = 0.0;
        for (weight, scale) in GGX_NDF_MIXTURE {
            let term = warp.map(|(e, b)| (e, b * scale));
            // The plane of the narrower lobe is the better one; blend by the widths.
            let term_width = (term[0].1 * term[1].1).sqrt();
            let in_lobe_plane = lobe_width / (lobe_width + term_width);
            let product = in_lobe_plane
                * product_integral((self.lambda, self.mu), (x, y, z), r, term)
                + (1.0 - in_lobe_plane)
                    * product_integral_at_mirror((self.lambda, self.mu), (x, y, z), r, term);
            conv += weight * product;
        }
        // Light along r: n·l = n·v; Smith height-correlated G2 / (4 n·l n·v), times n·l.
        let n_l = n_v;
        let lambda_v = ((1.0 + a2 * (1.0 / (n_v * n_v) - 1.0)).sqrt() - 1.0) / 2.0;
        let g2 = 1.0 / (1.0 + 2.0 * lambda_v);
        let k = conv / (PI * a2) * f0 * g2 / (4.0 * n_v * n_l) * n_l;
        self.rgb.map(|c| c * k)
    }
}

/// The GGX lobe warped from half vectors to light directions around the mirror direction `r`
/// (module doc): its two axes ⟂ r with their bandwidths — 1/(4α²) in the plane of incidence,
/// 1/(4α²(n·v)²) across it (`a2` = α²).
fn ggx_warp(n: DVec3, r: DVec3, n_v: f64, a2: f64) -> [(DVec3, f64); 2] {
    let across = n.cross(r);
    let across = if across.length_squared() > 1e-18 {
        across.normalize()
    } else {
        // n = v: the lobe is isotropic and any frame will do.
        r.any_orthonormal_vector()
    };
    let along = r.cross(across);
    let bandwidth = 1.0 / (4.0 * a2);
    let n_v = n_v.max(MIN_WARP_COSINE);
    [(across, bandwidth / (n_v * n_v)), (along, bandwidth)]
}

/// ∫ max(l·z, 0) · exp(−λ(l·x)² − μ(l·y)²) · exp(−Σₖ bₖ (l·eₖ)²) dl: the product of a lobe with
/// frame (x, y, z) and bandwidths (λ, μ) and a second lobe around `r` whose orthonormal axes
/// e₁, e₂ ⟂ r have bandwidths b₁, b₂, integrated in the first lobe's tangent plane. In the
/// coordinates u = (l·x, l·y) of the first lobe's hemisphere dl = du/(l·z), which cancels its
/// max(l·z, 0), so it is the Gaussian uᵀAu with A = diag(λ, μ). The second, linearised about
/// u = a = (r·x, r·y) (where l = r), is (u − a)ᵀB(u − a) with B = Σ bₖ gₖgₖᵀ and gₖ the gradient
/// of l·eₖ in u: gₖ = (eₖ·x, eₖ·y) − (eₖ·z/s)·a, s = r·z (a lobe seen at an angle from z is
/// foreshortened: it is narrower in u). Two Gaussians multiply into one: the integral over the
/// plane is π/√det(A + B) · exp(−aᵀ A (A + B)⁻¹ B a). In closed form: det B = b₁b₂/s²,
/// gₖ·a = −eₖ·z/s so aᵀBa = Σ bₖ(eₖ·z)²/s², det(A + B) = λμ + λB_yy + μB_xx + det B and
/// aᵀA(A + B)⁻¹Ba = (λμ·aᵀBa + det B·aᵀAa) / det(A + B): sums of non-negative terms, without
/// the cancellation of a 2×2 inverse (the shader does this in f32). Zero for s below
/// [`MIN_PRODUCT_COSINE`]: the result is at most π·s/√(b₁b₂) (det(A + B) ≥ det B) and the
/// terms in 1/s² would leave f32's range.
fn product_integral(
    (lambda, mu): (f64, f64),
    (x, y, z): (DVec3, DVec3, DVec3),
    r: DVec3,
    second: [(DVec3, f64); 2],
) -> f64 {
    let s = r.dot(z);
    if s < MIN_PRODUCT_COSINE {
        return 0.0;
    }
    let (ax, ay) = (r.dot(x), r.dot(y));
    let (mut b_xx, mut b_yy, mut b_zz) = (0.0, 0.0, 0.0);
    for (e, b) in second {
        let ez = e.dot(z) / s;
        b_xx += b * (e.dot(x) - ez * ax).powi(2);
        b_yy += b * (e.dot(y) - ez * ay).powi(2);
        b_zz += b * ez * ez;
    }
    let det_b = second[0].1 * second[1].1 / (s * s);
    let det = lambda * mu + lambda * b_yy + mu * b_xx + det_b;
    let quad = (lambda * mu * b_zz + det_b * (lambda * ax * ax + mu * ay * ay)) / det;
    PI / det.sqrt() * (-quad).exp()
}

/// The GGX NDF as two Gaussians: D(h) = f(x)/(πα² cos⁴θ_h) with f(x) = 1/(1 + x)² and
/// x = tan²θ_h/α², and f ≈ Σ wᵢ e^{−cᵢx} as (wᵢ, cᵢ). Least squares over x ∈ [0, 400] in the
/// measure dx, which is D's own (∫ D (n·h) dω_h = ∫₀^∞ f dx = 1), with Σ wᵢ/cᵢ = 1 so the mixture
/// keeps GGX's energy (and so the mirror bound, module doc); L2 error 0.026, peak Σ wᵢ = 0.96.
/// The single Gaussian e^{−x} used before 2026-12-04 lacks GGX's long tail (L2 error 0.135 for
/// the best single one): a wide lobe on the mirror direction was reflected a third too strongly
/// and a lobe 90° from it not at all (docs/asg.md).
pub const GGX_NDF_MIXTURE: [(f64, f64); 2] = [
    (0.815_789_309_535_954_3, 1.776_386_570_058_499),
    (0.143_770_736_188_865_5, 0.265_868_346_110_414_7),
];

/// ∫ max(l·z, 0) · exp(−λ(l·x)² − μ(l·y)²) · exp(−Σₖ bₖ (l·eₖ)²) dl as [`product_integral`], but
/// in the tangent plane of the mirror direction r, where the second lobe is exact and the first
/// is linearised: with l ≈ r + v₁e₁ + v₂e₂, l·w ≈ r·w + gᵥᵀv (g_w = (e₁·w, e₂·w)), the two
/// exponentials are one Gaussian exp(−(vᵀMv + 2hᵀv + q)), M = diag(b₁, b₂) + λg_xg_xᵀ + μg_yg_yᵀ,
/// h = λ(r·x)g_x + μ(r·y)g_y, q = λ(r·x)² + μ(r·y)², whose integral is
/// π/√det M · exp(hᵀM⁻¹h − q), times the mean of the ramp max(r·z + g_zᵀv, 0) under it (v normal
/// with mean −M⁻¹h and covariance M⁻¹/2: μΦ(μ/σ) + σφ(μ/σ)), at most 1 as l·z is. Better than
/// the lobe's plane where the lobe is the wider one, and it does not vanish when r is at or
/// beyond the lobe's horizon (r·z ≤ 0), where a rough surface still sees part of the lobe.
fn product_integral_at_mirror(
    (lambda, mu): (f64, f64),
    (x, y, z): (DVec3, DVec3, DVec3),
    r: DVec3,
    second: [(DVec3, f64); 2],
) -> f64 {
    let [(e1, b1), (e2, b2)] = second;
    let tangent = |w: DVec3| DVec2::new(e1.dot(w), e2.dot(w));
    let (gx, gy, gz) = (tangent(x), tangent(y), tangent(z));
    let (ax, ay) = (r.dot(x), r.dot(y));
    let m00 = b1 + lambda * gx.x * gx.x + mu * gy.x * gy.x;
    let m11 = b2 + lambda * gx.y * gx.y + mu * gy.y * gy.y;
    let m01 = lambda * gx.x * gx.y + mu * gy.x * gy.y;
    // det M ≥ b₁b₂ (M is diag(b₁, b₂) plus a positive semi-definite part); the bound keeps
    // the shader's f32 cancellation from reaching zero when the lobe is sharp.
    let det = (m00 * m11 - m01 * m01).max(b1 * b2);
    let solve = |v: DVec2| DVec2::new(m11 * v.x - m01 * v.y, m00 * v.y - m01 * v.x) / det;
    let h = lambda * ax * gx + mu * ay * gy;
    let m_inv_h = solve(h);
    let exponent = (h.dot(m_inv_h) - (lambda * ax * ax + mu * ay * ay)).min(0.0);
    let spread = (0.5 * gz.dot(solve(gz))).max(0.0).sqrt();
    let mean = r.dot(z) - gz.dot(m_inv_h);
    PI / det.sqrt() * exponent.exp() * ramp_mean(mean, spread)
}

/// E[max(X, 0)] for X normal with mean `mean` and standard deviation `spread`, at most 1 (the
/// ramp stands for a cosine).
fn ramp_mean(mean: f64, spread: f64) -> f64 {
    let value = if spread > 0.0 {
        let t = mean / spread;
        mean * normal_cdf(t) + spread * (-0.5 * t * t).exp() / (2.0 * PI).sqrt()
    } else {
        mean
    };
    value.clamp(0.0, 1.0)
}

/// Φ(t), the standard normal distribution function, from erf by Abramowitz and Stegun 7.1.26
/// (absolute error ≤ 1.5·10⁻⁷; the shader uses the same polynomial).
fn normal_cdf(t: f64) -> f64 {
    let u = t.abs() / std::f64::consts::SQRT_2;
    let k = 1.0 / (1.0 + 0.327_591_1 * u);
    let poly = ((((1.061_405_429 * k - 1.453_152_027) * k + 1.421_413_741) * k - 0.284_496_736)
        * k
        + 0.254_829_592)
        * k;
    let erf = 1.0 - poly * (-u * u).exp();
    0.5 * (1.0 + erf.copysign(t))
}

/// Below this cosine between the mirror direction and a lobe's axis the lobe reflects nothing
/// ([`product_integral`]).
const MIN_PRODUCT_COSINE: f64 = 1e-4;

/// Smallest n·v the warp of the GGX lobe uses ([`ggx_warp`]): it keeps the warped bandwidth, and
/// the shader's f32 sums, finite at views grazing the surface.
const MIN_WARP_COSINE: f64 = 1e-3;

/// Right-handed orthonormal frame (x, y, z) with z along `axis`, x along `hint` projected ⟂ z
/// (any ⟂ vector when the hint is parallel or zero). `None` for a zero or non-finite axis.
pub fn orthonormal_frame(axis: DVec3, hint: DVec3) -> Option<(DVec3, DVec3, DVec3)> {
    let len = axis.length();
    if !(len.is_finite() && len > 0.0) {
        return None;
    }
    let z = axis / len;
    let mut x = hint - z * hint.dot(z);
    if !(x.length_squared() > 1e-20 && x.is_finite()) {
        x = z.any_orthonormal_vector();
    }
    let x = x.normalize();
    let y = z.cross(x);
    Some((x, y, z))
}

/// ∫ max(v·z,0)·exp(−λ(v·x)² − μ(v·y)²) dω, exact (trapezoid over φ, module doc).
pub fn integral(lambda: f64, mu: f64) -> f64 {
    integral_with_derivatives(lambda, mu).0
}

/// Xu et al.'s closed form π/√(λμ); relative error ≤ e^{−min(λ, μ)} (an overestimate).
pub fn integral_approx(lambda: f64, mu: f64) -> f64 {
    PI / (lambda * mu).sqrt()
}

/// The exact integral and its derivatives with respect to λ and μ.
pub fn integral_with_derivatives(lambda: f64, mu: f64) -> (f64, f64, f64) {
    // f(a) = (1 − e^{−a}) / (2a), f'(a) = (a e^{−a} − (1 − e^{−a})) / (2a²); integrand is
    // symmetric under φ → −φ and φ → π − φ, so a quarter period with the trapezoid rule
    // (midpoints) suffices.
    let n = INTEGRAL_NODES / 4;
    let h = (PI / 2.0) / n as f64;
    let (mut v, mut dl, mut dm) = (0.0, 0.0, 0.0);
    for i in 0..n {
        let phi = (i as f64 + 0.5) * h;
        let (s, c) = phi.sin_cos();
        let (c2, s2) = (c * c, s * s);
        let a = lambda * c2 + mu * s2;
        let (f, df) = if a < 1e-4 {
            // Series: f ≈ 1/2 − a/4 + a²/12, f' ≈ −1/4 + a/6.
            (0.5 - a / 4.0 + a * a / 12.0, -0.25 + a / 6.0)
        } else {
            let em = (-a).exp_m1(); // e^{−a} − 1
            let f = -em / (2.0 * a);
            let df = (a * (em + 1.0) + em) / (2.0 * a * a);
            (f, df)
        };
        v += f;
        dl += df * c2;
        dm += df * s2;
    }
    let w = 4.0 * h;
    (v * w, dl * w, dm * w)
}

/// Nodes of the cosine-convolution table over t = n·z ∈ [−1, 1] (odd: t = 0 is a node).
const TABLE_T: usize = 129;
/// Nodes over ln ν ∈ [ln 0.5, ln 4·10⁵].
const TABLE_NU: usize = 72;
const TABLE_NU_MIN: f64 = 0.5;
const TABLE_NU_MAX: f64 = 4.0e5;

/// Normalised irradiance H(t, ν) of the isotropic lobe λ = μ = ν/2, tabulated on first use.
fn cosine_table() -> &'static [f64] {
    static TABLE: std::sync::OnceLock<Vec<f64>> = std::sync::OnceLock::new();
    TABLE.get_or_init(|| {
        let mut out = vec![0.0; TABLE_T * TABLE_NU];
        let dl = (TABLE_NU_MAX / TABLE_NU_MIN).ln() / (TABLE_NU - 1) as f64;
        for j in 0..TABLE_NU {
            let lambda = 0.5 * TABLE_NU_MIN * (dl * j as f64).exp();
            // The lobe is negligible beyond sin²θ' = 50/λ.
            let theta_max = if lambda > 50.0 {
                (50.0 / lambda).sqrt().asin()
            } else {
                PI / 2.0
            };
            const NODES: usize = 512;
            let h = theta_max / NODES as f64;
            let samples: Vec<(f64, f64, f64)> = (0..NODES)
                .map(|k| {
                    let th = (k as f64 + 0.5) * h;
                    let (s, c) = th.sin_cos();
                    (c * (-lambda * s * s).exp() * s * h, s, c)
                })
                .collect();
            let total: f64 = samples.iter().map(|x| x.0).sum::<f64>() * 2.0 * PI;
            for i in 0..TABLE_T {
                let t = -1.0 + 2.0 * i as f64 / (TABLE_T - 1) as f64;
                let sg = (1.0 - t * t).max(0.0).sqrt();
                let mut e = 0.0;
                for &(w, s, c) in &samples {
                    let a = t * c;
                    let b = sg * s;
                    let ring = if b <= a.abs() {
                        if a > 0.0 {
                            2.0 * PI * a
                        } else {
                            0.0
                        }
                    } else {
                        2.0 * (a * (-a / b).clamp(-1.0, 1.0).acos() + (b * b - a * a).sqrt())
                    };
                    e += w * ring;
                }
                out[j * TABLE_T + i] = e / total;
            }
        }
        out
    })
}

/// Normalised cosine convolution H(t, ν) of a lobe of isotropic-equivalent sharpness ν at
/// t = n·axis, with ∂H/∂t and ∂H/∂ν (bilinear in t and ln ν on a precomputed exact table).
pub fn cosine_convolution(t: f64, nu: f64) -> (f64, f64, f64) {
    let table = cosine_table();
    let dt = 2.0 / (TABLE_T - 1) as f64;
    let dl = (TABLE_NU_MAX / TABLE_NU_MIN).ln() / (TABLE_NU - 1) as f64;
    let ut = ((t.clamp(-1.0, 1.0) + 1.0) / dt).clamp(0.0, (TABLE_T - 1) as f64);
    let raw = (nu.max(1e-300) / TABLE_NU_MIN).ln() / dl;
    let inside = raw > 0.0 && raw < (TABLE_NU - 1) as f64;
    let un = raw.clamp(0.0, (TABLE_NU - 1) as f64);
    let (i, j) = (
        (ut.floor() as usize).min(TABLE_T - 2),
        (un.floor() as usize).min(TABLE_NU - 2),
    );
    let (ft, fn_) = (ut - i as f64, un - j as f64);
    let at = |i: usize, j: usize| table[j * TABLE_T + i];
    let (h00, h10, h01, h11) = (at(i, j), at(i + 1, j), at(i, j + 1), at(i + 1, j + 1));
    let h0 = h00 + (h10 - h00) * ft;
    let h1 = h01 + (h11 - h01) * ft;
    let h = h0 + (h1 - h0) * fn_;
    let dh_t = ((h10 - h00) * (1.0 - fn_) + (h11 - h01) * fn_) / dt;
    let dh_nu = if inside { (h1 - h0) / (dl * nu) } else { 0.0 };
    (h, dh_t, dh_nu)
}

/// Rotates `v` by the rotation vector `w` (axis × angle, Rodrigues).
pub fn rotate(v: DVec3, w: DVec3) -> DVec3 {
    let angle = w.length();
    if angle < 1e-300 {
        return v;
    }
    let k = w / angle;
    let (s, c) = angle.sin_cos();
    v * c + k.cross(v) * s + k * k.dot(v) * (1.0 - c)
}

/// Errors of ASG fitting and evaluation. Each names the input it is about.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum AsgError {
    #[error("lobe count {0} is outside 1..=64")]
    LobeCount(usize),
    #[error(
        "fit map size {width}x{height} is invalid (a fit takes heights 4..=1024, a fit target \
         1..=4096; width = 2 × height)"
    )]
    MapSize { width: u32, height: u32 },
    #[error("frame claims {width}x{height} pixels but holds {len}")]
    PixelCount { width: u32, height: u32, len: usize },
    #[error("invalid fit setting {name} = {value}: {message}")]
    Setting {
        name: &'static str,
        value: String,
        message: &'static str,
    },
    #[error("the warm start has {got} lobes but the fit asks for {expected}")]
    WarmStart { got: usize, expected: usize },
    #[error("lobe {index} is invalid: {message}")]
    Lobe { index: usize, message: &'static str },
    #[error("the fit was cancelled (shutting down)")]
    Cancelled,
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn integral_approaches_xu_for_narrow_lobes_and_bounds_hold() {
        for &(l, m) in &[
            (5.0, 5.0),
            (10.0, 40.0),
            (100.0, 3.0),
            (0.3, 0.5),
            (1e4, 2e4),
        ] {
            let exact = integral(l, m);
            let approx = integral_approx(l, m);
            assert!(approx >= exact, "Xu's form overestimates ({l}, {m})");
            let rel = (approx - exact) / approx;
            assert!(
                rel <= (-f64::min(l, m)).exp() * (1.0 + 1e-9),
                "bound ({l}, {m}): {rel}"
            );
        }
        // λ = μ → 0: the clamped cosine, ∫ max(v·z,0) dω = π.
        assert!((integral(1e-9, 1e-9) - PI).abs() < 1e-6);
    }

    #[test]
    fn integral_derivatives_match_finite_differences() {
        for &(l, m) in &[(0.3, 2.0), (5.0, 7.0), (60.0, 1.0)] {
            let (_, dl, dm) = integral_with_derivatives(l, m);
            let h = 1e-6;
            let fl = (integral(l * (1.0 + h), m) - integral(l * (1.0 - h), m)) / (2.0 * h * l);
            let fm = (integral(l, m * (1.0 + h)) - integral(l, m * (1.0 - h))) / (2.0 * h * m);
            assert!((dl - fl).abs() < 1e-6 * fl.abs().max(1e-3), "{dl} vs {fl}");
            assert!((dm - fm).abs() < 1e-6 * fm.abs().max(1e-3), "{dm} vs {fm}");
        }
    }

    #[test]
    fn cosine_convolution_limits_and_derivatives() {
        // Narrow lobes: H → max(t, 0).
        for &t in &[-0.5, 0.0, 0.3, 1.0] {
            assert!(
                (cosine_convolution(t, 3.0e5).0 - f64::max(t, 0.0)).abs() < 0.01,
                "{t}"
            );
        }
        // Derivatives of the interpolant, away from the nodes.
        for &nu in &[0.7, 3.3, 47.0, 900.0] {
            for i in 0..20 {
                let t = -0.97 + 0.0971 * i as f64;
                let (_, dt, dn) = cosine_convolution(t, nu);
                let e = 1e-7;
                let ft =
                    (cosine_convolution(t + e, nu).0 - cosine_convolution(t - e, nu).0) / (2.0 * e);
                let fnu = (cosine_convolution(t, nu * (1.0 + e)).0
                    - cosine_convolution(t, nu * (1.0 - e)).0)
                    / (2.0 * e * nu);
                assert!(
                    (dt - ft).abs() < 1e-5 * ft.abs().max(1.0),
                    "dt at t={t} nu={nu}: {dt} vs {ft}"
                );
                assert!(
                    (dn - fnu).abs() < 1e-5 * fnu.abs().max(1e-3),
                    "dnu at t={t} nu={nu}: {dn} vs {fnu}"
                );
            }
        }
    }

    #[test]
    fn new_rejects_bad_input() {
        assert!(Asg::new(DVec3::ZERO, DVec3::X, 1.0, 1.0, [1.0; 3]).is_none());
        assert!(Asg::new(DVec3::Y, DVec3::X, f64::NAN, 1.0, [1.0; 3]).is_none());
        assert!(Asg::new(DVec3::Y, DVec3::X, 1.0, 1.0, [f64::INFINITY, 0.0, 0.0]).is_none());
        let g = Asg::new(DVec3::Y, DVec3::Y, 1.0, 2.0, [1.0; 3]).expect("parallel hint is fine");
        let (x, y, z) = g.frame();
        assert!((x.cross(y) - z).length() < 1e-12);
    }

    #[test]
    fn shape_gradients_match_finite_differences() {
        let g = Asg::new(DVec3::new(0.3, 0.8, -0.2), DVec3::X, 3.0, 11.0, [1.0; 3]).unwrap();
        let v = DVec3::new(0.4, 0.85, -0.1).normalize();
        let gr = g.gradients(v);
        let h = 1e-6;
        let (x, y, z) = g.frame();
        let raw = |x: DVec3, y: DVec3, z: DVec3, l: f64, m: f64| {
            let s = v.dot(z);
            s.max(0.0) * (-l * v.dot(x).powi(2) - m * v.dot(y).powi(2)).exp()
        };
        for k in 0..3 {
            let mut e = DVec3::ZERO;
            e[k] = h;
            let fx = (raw(x + e, y, z, 3.0, 11.0) - raw(x - e, y, z, 3.0, 11.0)) / (2.0 * h);
            let fy = (raw(x, y + e, z, 3.0, 11.0) - raw(x, y - e, z, 3.0, 11.0)) / (2.0 * h);
            let fz = (raw(x, y, z + e, 3.0, 11.0) - raw(x, y, z - e, 3.0, 11.0)) / (2.0 * h);
            assert!((gr.d_x[k] - fx).abs() < 1e-7);
            assert!((gr.d_y[k] - fy).abs() < 1e-7);
            assert!((gr.d_z[k] - fz).abs() < 1e-7);
        }
        let fl = (raw(x, y, z, 3.0 + h, 11.0) - raw(x, y, z, 3.0 - h, 11.0)) / (2.0 * h);
        assert!((gr.d_lambda - fl).abs() < 1e-7);
        assert!((gr.value - g.shape(v)).abs() < 1e-15);
    }
}
