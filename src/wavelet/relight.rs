//! Relighting a static mesh with wavelet lighting: BRDF slices, per-vertex transport and the
//! per-frame sparse dot product (Ng, Ramamoorthi and Hanrahan 2003/2004; Michiels et al. 2013).
//!
//! # Basis and scale
//!
//! A [`Grid`] is the `side × side` equal-area octahedral map ([`sphere`]) with a
//! basis and a number of levels. A function f on the sphere is represented by its texel values
//! f_t (piecewise constant on texels, solid angle dω = 4π/side² each); its coefficients are
//! `c = W (f_t √dω)` with `W` the orthonormal 2-D transform ([`Grid::project`]). Then
//! `Σ_k c_k(f) c_k(g) = Σ_t f_t g_t dω = ∫ f g dω` exactly (Parseval). Lighting coefficients of a
//! [`WaveletSet`] are those of the texel radiances; [`WaveletSet::sphere_scale`] (= √dω) converts.
//!
//! # Outgoing radiance
//!
//! `B(x, ω_o) = ∫ V(x, ω) L(ω) ρ(x, ω, ω_o) dω`, with ρ the BRDF slice of vertex x (normal n, view
//! ω_o) including the cosine: [`Brdf::slice`] gives `ρ(ω) = f_r(ω, ω_o) · max(0, n·ω)`, where
//! f_r is 1/π for [`Brdf::Lambert`] (albedo applied by the caller) and the energy-normalised Phong
//! lobe `(s+2)/(2π) · max(0, r·ω)^s` around the mirror direction r of ω_o for [`Brdf::Phong`],
//! and the microfacet `D(h) · G2(ω, ω_o) / (4 (n·ω)(n·ω_o))` for [`Brdf::Ggx`] (Trowbridge–Reitz
//! distribution, Smith height-correlated masking-shadowing, F = 1: the caller applies the
//! Fresnel colour, as the ASG balls of docs/asg.md do).
//!
//! # What is precomputed and what is per frame
//!
//! For a static mesh with a fixed BRDF and view, V and ρ are both known in advance, so their
//! product collapses into one **transport** function per vertex, T_x(ω) = V(x, ω) ρ(x, ω). It is
//! built in the pixel domain (visibility bits times the slice), projected with the transform and
//! truncated to its `keep` largest coefficients ([`Transport::precompute`]), stored as one CSR
//! row per vertex (u16 index, f32 value). Per frame only the lighting changes: its sparse
//! coefficients are scattered into a dense table of `side²` RGBA f32 entries (zeros elsewhere;
//! 16 KiB at side 32, 64 KiB at side 64, so it stays in L1/L2), and every vertex computes
//! `B_x = Σ_k T_x[k] · L[k]` over its row: one 4-wide multiply-add per stored entry, vertices
//! split across threads (rayon) ([`Transport::relight`]). The work per frame is
//! `vertices × keep` multiply-adds, independent of how many lighting coefficients are kept.
//! When V, L and ρ are all given in wavelets and ρ changes (a moving view for a glossy BRDF), the
//! full triple product of [`triple`](super::triple) is needed instead.

use super::approx::WaveletSet;
use super::basis::Basis;
use super::sphere::{self, SphereError};
use super::transform::{self, TransformError};
use super::visibility::{MeshError, Visibility};
use glam::{DVec3, Vec3};
use rayon::prelude::*;
use thiserror::Error;

/// Errors of the light-transport modules (relighting, triple products, inverse rendering).
#[derive(Debug, Error, PartialEq)]
pub enum TransportError {
    #[error(transparent)]
    Transform(#[from] TransformError),
    #[error(transparent)]
    Sphere(#[from] SphereError),
    #[error(transparent)]
    Mesh(#[from] MeshError),
    #[error("unsupported wavelet basis {0}")]
    UnsupportedBasis(Basis),
    #[error("{what}: side {side} is above the limit {max}")]
    SideTooLarge {
        what: &'static str,
        side: usize,
        max: usize,
    },
    #[error("{what}: expected {expected} values, got {got}")]
    Length {
        what: &'static str,
        expected: usize,
        got: usize,
    },
    #[error(
        "{what}: grid is side {expected} ({basis_expected}), data is side {got} ({basis_got})"
    )]
    GridMismatch {
        what: &'static str,
        expected: usize,
        basis_expected: String,
        got: usize,
        basis_got: String,
    },
    #[error("Phong exponent must be finite and ≥ 0, got {0}")]
    PhongExponent(f32),
    #[error("GGX roughness α must be in [{MIN_GGX_ALPHA}, 1], got {0}")]
    GgxAlpha(f32),
    #[error("{0}")]
    Invalid(String),
    #[error(
        "relighting {vertices} vertices on a grid of {texels} directions keeping {keep} \
         coefficients each needs up to {:.1} GiB, more than the {:.1} GiB available",
        gib(*.need),
        gib(*.available)
    )]
    Memory {
        vertices: usize,
        texels: usize,
        keep: usize,
        need: u64,
        available: u64,
    },
}

fn gib(bytes: u64) -> f64 {
    bytes as f64 / f64::from(1u32 << 30)
}

/// Largest side for transport (coefficient indices are stored as u16).
pub const MAX_TRANSPORT_SIDE: usize = 256;

/// The equal-area octahedral map with a wavelet basis: texel directions and the projection.
#[derive(Clone, Debug)]
pub struct Grid {
    pub side: usize,
    pub basis: Basis,
    pub levels: u32,
    /// Direction of every texel centre, row-major (`side²`).
    pub dirs: Vec<Vec3>,
    /// The [`horizon_subsamples`]² equal-area points of every texel, texel by texel: made at
    /// the first point-sampled slice and shared by every vertex's (each vertex computed the
    /// same ones again, with the trigonometry of `square_to_sphere`).
    horizon_points: std::sync::OnceLock<Vec<Vec3>>,
}

impl Grid {
    /// A grid of `side` (power of two) with `levels` decomposition levels (`None`: all, down to
    /// one coefficient).
    pub fn new(side: usize, basis: Basis, levels: Option<u32>) -> Result<Self, TransportError> {
        sphere::check_side(side)?;
        if !basis.is_supported() {
            return Err(TransportError::UnsupportedBasis(basis));
        }
        let max = transform::max_levels(side);
        let levels = levels.unwrap_or(max);
        if levels > max {
            return Err(TransformError::TooManyLevels { side, levels, max }.into());
        }
        let s = side as f64;
        let dirs = (0..side * side)
            .map(|t| {
                let (x, y) = (t % side, t / side);
                sphere::square_to_sphere((x as f64 + 0.5) / s, (y as f64 + 0.5) / s).as_vec3()
            })
            .collect();
        Ok(Self {
            side,
            basis,
            levels,
            dirs,
            horizon_points: std::sync::OnceLock::new(),
        })
    }

    /// Number of texels (= number of coefficients).
    pub fn len(&self) -> usize {
        self.side * self.side
    }

    /// Whether the grid is empty (never: side ≥ 2).
    pub fn is_empty(&self) -> bool {
        self.side == 0
    }

    /// Solid angle of every texel, 4π/side².
    pub fn d_omega(&self) -> f64 {
        sphere::texel_solid_angle(self.side)
    }

    /// Coefficients of a function given by its texel values: `W (f √dω)`.
    pub fn project(&self, values: &[f64]) -> Result<Vec<f64>, TransportError> {
        if values.len() != self.len() {
            return Err(TransportError::Length {
                what: "texel values",
                expected: self.len(),
                got: values.len(),
            });
        }
        let s = self.d_omega().sqrt();
        let mut c: Vec<f64> = values.iter().map(|v| v * s).collect();
        transform::forward_2d(&mut c, self.side, self.basis, self.levels)?;
        Ok(c)
    }

    /// Texel values of a function from its coefficients (inverse of [`Grid::project`]).
    pub fn reconstruct(&self, coeffs: &[f64]) -> Result<Vec<f64>, TransportError> {
        if coeffs.len() != self.len() {
            return Err(TransportError::Length {
                what: "coefficients",
                expected: self.len(),
                got: coeffs.len(),
            });
        }
        let mut v = coeffs.to_vec();
        transform::inverse_2d(&mut v, self.side, self.basis, self.levels)?;
        let s = 1.0 / self.d_omega().sqrt();
        v.iter_mut().for_each(|x| *x *= s);
        Ok(v)
    }

    /// The BRDF slice of a vertex (normal, view) on this grid: one value per texel, the
    /// slice's *average* over the texel (so `Σ_t value_t · dω` is the slice's integral, the
    /// surface's directional albedo for F = 1). Lobes at least [`POINT_SAMPLED_LOBE_TEXELS`]
    /// texels wide where narrowest ([`Brdf::lobe_width`]) are sampled at the texel centres ([`Brdf::slice`]), which is accurate there.
    /// A narrower lobe would fall between the centres and lose its energy (GGX α = 0.01 at side
    /// 32 kept 22 % of its albedo, Phong 10000 almost nothing), so its texel integrals are
    /// estimated by importance sampling instead: [`LOBE_SAMPLES`] directions per texel² of the
    /// lobe's width (up to [`MAX_LOBE_SAMPLES`]) drawn from the lobe with a fixed Hammersley set
    /// (the same for every vertex and run), each adding f_r·cos / pdf to the texel it falls in.
    pub fn brdf_slice(&self, brdf: Brdf, normal: Vec3, view: Vec3) -> Vec<f64> {
        let texel = self.d_omega().sqrt();
        match brdf.lobe_width(f64::from(normal.dot(view))) {
            Some(width) if width < POINT_SAMPLED_LOBE_TEXELS * texel => {
                let mut values = vec![0.0f64; self.len()];
                let texels = (width / texel).max(1.0);
                let n = ((LOBE_SAMPLES as f64 * texels * texels) as usize).min(MAX_LOBE_SAMPLES);
                let scale = 1.0 / (n as f64 * self.d_omega());
                brdf.sample_lobe(normal, view, n, |dir, weight| {
                    let (x, y) = sphere::texel_of(self.side, dir);
                    values[y * self.side + x] += weight * scale;
                });
                values
            }
            _ => {
                let mut values = brdf.slice(normal, view, &self.dirs);
                self.average_over_horizon_texels(brdf, normal, view, &mut values);
                values
            }
        }
    }

    /// Replaces the centre samples of the texels that the tangent plane of `normal` cuts
    /// (those within 1.5·√dω of it, the visibility's reach) by the slice's average over
    /// [`horizon_subsamples`]² equal-area points of the texel. The cosine's cut at the horizon
    /// is no linear function over such a texel, and its centre sample was far off on coarse
    /// grids: a quad of albedo 0.8 under a uniform environment came out 0 at side 2 (every
    /// centre on the horizon), 0.600 at 4, 0.750 at 8, 0.788 at 16 and 0.797 at 32 (an audit).
    fn average_over_horizon_texels(
        &self,
        brdf: Brdf,
        normal: Vec3,
        view: Vec3,
        values: &mut [f64],
    ) {
        let reach = (1.5 * self.d_omega().sqrt())
            .min(std::f64::consts::FRAC_PI_2)
            .sin();
        let k = horizon_subsamples(self.side);
        let points = self.horizon_points.get_or_init(|| {
            let s = self.side as f64;
            let mut points = Vec::with_capacity(self.len() * k * k);
            for t in 0..self.len() {
                let (x, y) = ((t % self.side) as f64, (t / self.side) as f64);
                for j in 0..k {
                    for i in 0..k {
                        let u = (x + (i as f64 + 0.5) / k as f64) / s;
                        let v = (y + (j as f64 + 0.5) / k as f64) / s;
                        points.push(sphere::square_to_sphere(u, v).as_vec3());
                    }
                }
            }
            points
        });
        for ((d, value), texel_points) in self
            .dirs
            .iter()
            .zip(values.iter_mut())
            .zip(points.chunks_exact(k * k))
        {
            if f64::from(normal.dot(*d)).abs() >= reach {
                continue;
            }
            let sum: f64 = texel_points
                .iter()
                .map(|&p| brdf.eval(normal, view, p))
                .sum();
            *value = sum / (k * k) as f64;
        }
    }

    /// Checks that a wavelet set was made on this grid.
    pub fn check_set(&self, set: &WaveletSet) -> Result<(), TransportError> {
        if set.side as usize != self.side || set.basis != self.basis || set.levels != self.levels {
            return Err(TransportError::GridMismatch {
                what: "wavelet set",
                expected: self.side,
                basis_expected: format!("{} with {} levels", self.basis, self.levels),
                got: set.side as usize,
                basis_got: format!("{} with {} levels", set.basis, set.levels),
            });
        }
        set.validate()
            .map_err(|e| TransportError::Invalid(format!("wavelet set: {e}")))
    }
}

/// A BRDF whose slice (fixed normal and view) is projected into the wavelet basis.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Brdf {
    /// f_r = 1/π (albedo is applied by the caller).
    Lambert,
    /// Energy-normalised Phong lobe (s+2)/(2π) · max(0, r·ω)^s around the mirror direction.
    Phong { exponent: f32 },
    /// GGX microfacet specular with roughness α (= perceptual roughness²), F = 1: D(h) · G2 /
    /// (4 n·ω n·ω_o), Smith height-correlated G2. Zero where the view is below the surface.
    Ggx { alpha: f32 },
}

/// Smallest GGX α accepted.
pub const MIN_GGX_ALPHA: f32 = 1e-3;

/// Lobes at least this many texels wide are point-sampled at the texel centres
/// ([`Grid::brdf_slice`]); narrower ones are importance-sampled.
pub const POINT_SAMPLED_LOBE_TEXELS: f64 = 3.0;

/// Points along each side of a texel that the tangent plane cuts, averaged for the
/// point-sampled slices ([`Grid::brdf_slice`]) of a `side × side` grid: 32/side, at least 4 and
/// at most 16 (the map is equal-area, so equal sub-squares are equal solid angles). A quad of
/// albedo 0.8 under a uniform environment: 0.797 at sides 2 and 4, 0.803 at 8, 0.802 at 16,
/// 0.801 at 32. The built-in scene's precomputation (with the visibility's horizon rays) takes
/// 0.47 s at side 32 (0.4 s before; 8 × 8 points there took 1.1–1.3 s, and 4 × 4 points made
/// anew for every vertex 0.65 s) and 1.6 s at side 64 (1.35 s).
pub fn horizon_subsamples(side: usize) -> usize {
    (32 / side.max(1)).clamp(4, 16)
}

/// Directions drawn per vertex from a lobe narrower than [`POINT_SAMPLED_LOBE_TEXELS`] texels,
/// per texel² of the lobe's width (at least this many; [`MAX_LOBE_SAMPLES`] at most): the
/// samples per texel it covers stay about the same, and so does the noise of its texel values.
pub const LOBE_SAMPLES: usize = 4096;

/// Most directions drawn per vertex from one lobe.
pub const MAX_LOBE_SAMPLES: usize = 65536;

/// Smith's Λ of a direction at cosine `c` to the normal, for GGX with α² = `a2`: G1 = 1/(1 + Λ),
/// height-correlated G2 = 1/(1 + Λ(v) + Λ(l)).
pub(crate) fn smith_lambda(c: f64, a2: f64) -> f64 {
    ((1.0 + a2 * (1.0 / (c * c) - 1.0)).sqrt() - 1.0) * 0.5
}

/// Point `i` of the `n`-point Hammersley set in the unit square.
fn hammersley(i: usize, n: usize) -> (f64, f64) {
    let radical_inverse = (i as u32).reverse_bits() as f64 / 4_294_967_296.0;
    ((i as f64 + 0.5) / n as f64, radical_inverse)
}

/// An orthonormal frame (t, b, a) around unit `a`.
fn frame_around(a: DVec3) -> (DVec3, DVec3, DVec3) {
    let t = a.any_orthonormal_vector();
    (t, a.cross(t), a)
}

impl Brdf {
    /// Checks the parameters.
    pub fn validate(self) -> Result<(), TransportError> {
        match self {
            Brdf::Lambert => Ok(()),
            Brdf::Phong { exponent } if exponent.is_finite() && exponent >= 0.0 => Ok(()),
            Brdf::Phong { exponent } => Err(TransportError::PhongExponent(exponent)),
            Brdf::Ggx { alpha } if (MIN_GGX_ALPHA..=1.0).contains(&alpha) => Ok(()),
            Brdf::Ggx { alpha } => Err(TransportError::GgxAlpha(alpha)),
        }
    }

    /// `f_r(ω, ω_o) · max(0, n·ω)` for unit `normal`, unit `view` (towards the viewer) and `dir`.
    pub fn eval(self, normal: Vec3, view: Vec3, dir: Vec3) -> f64 {
        let cos = normal.dot(dir);
        if cos <= 0.0 {
            return 0.0;
        }
        let cos = f64::from(cos);
        match self {
            Brdf::Lambert => cos * std::f64::consts::FRAC_1_PI,
            Brdf::Phong { exponent } => {
                let r = 2.0 * normal.dot(view) * normal - view;
                let rd = f64::from(r.dot(dir)).max(0.0);
                let s = f64::from(exponent);
                (s + 2.0) / std::f64::consts::TAU * rd.powf(s) * cos
            }
            Brdf::Ggx { alpha } => {
                let n_v = f64::from(normal.dot(view));
                if n_v <= 0.0 {
                    return 0.0;
                }
                let h = (view + dir).normalize_or_zero();
                let n_h = f64::from(normal.dot(h)).max(0.0);
                let a2 = f64::from(alpha).powi(2);
                let d = n_h * n_h * (a2 - 1.0) + 1.0;
                let ndf = a2 / (std::f64::consts::PI * d * d);
                // Smith height-correlated: G2 = 1 / (1 + Λ(v) + Λ(l)).
                let lambda = |c: f64| smith_lambda(c, a2);
                let g2 = 1.0 / (1.0 + lambda(n_v) + lambda(cos));
                // f_r · cos = D G2 / (4 n·ω n·ω_o) · n·ω.
                ndf * g2 / (4.0 * n_v)
            }
        }
    }

    /// The slice in the pixel domain: one value per texel direction (point samples; a grid's
    /// texel averages are [`Grid::brdf_slice`]).
    pub fn slice(self, normal: Vec3, view: Vec3, dirs: &[Vec3]) -> Vec<f64> {
        dirs.iter().map(|d| self.eval(normal, view, *d)).collect()
    }

    /// The angular width of the lobe in radians for a view at `n_v` = n·ω_o (about its
    /// half-maximum diameter where it is narrowest): `None` for Lambert.
    pub fn lobe_width(self, n_v: f64) -> Option<f64> {
        match self {
            Brdf::Lambert => None,
            // cos^s θ = 1/2 at θ ≈ √(2 ln 2 / s).
            Brdf::Phong { exponent } => {
                Some(2.0 * (2.0 * std::f64::consts::LN_2 / f64::from(exponent).max(1e-6)).sqrt())
            }
            // D(h) halves at tan θ_h ≈ 0.64 α; reflected directions turn twice as far in the
            // plane of incidence and 2·n·v times as far across it, where a grazing view's lobe
            // is narrow.
            Brdf::Ggx { alpha } => Some(4.0 * 0.64 * f64::from(alpha) * n_v.clamp(0.0, 1.0)),
        }
    }

    /// Draws `n` directions from the lobe (Hammersley points; Phong: cos^s around the mirror
    /// direction; GGX: visible normals) and calls `f(direction, f_r·cos / pdf)` for
    /// each; directions below the surface, or with a view below it, get weight 0 and are
    /// skipped. The weights' mean estimates the slice's integral. Lambert draws nothing.
    pub fn sample_lobe(self, normal: Vec3, view: Vec3, n: usize, mut f: impl FnMut(DVec3, f64)) {
        let (normal, view) = (normal.as_dvec3(), view.as_dvec3());
        let n_v = normal.dot(view);
        if n_v <= 0.0 {
            return;
        }
        match self {
            Brdf::Lambert => {}
            Brdf::Phong { exponent } => {
                let s = f64::from(exponent);
                let (t, b, r) = frame_around(2.0 * n_v * normal - view);
                for i in 0..n {
                    let (u1, u2) = hammersley(i, n);
                    let cos = u1.powf(1.0 / (s + 1.0));
                    let sin = (1.0 - cos * cos).max(0.0).sqrt();
                    let phi = std::f64::consts::TAU * u2;
                    let dir = r * cos + (t * phi.cos() + b * phi.sin()) * sin;
                    let n_l = normal.dot(dir);
                    if n_l > 0.0 {
                        // f_r·cos / pdf = (s+2)/(s+1) · n·l.
                        f(dir, (s + 2.0) / (s + 1.0) * n_l);
                    }
                }
            }
            Brdf::Ggx { alpha } => {
                // Visible normals (Heitz 2018, "Sampling the GGX distribution of visible
                // normals"): pdf(l) = G1(v)·D(h) / (4 n·v), so f_r·cos / pdf = G2 / G1(v) ≤ 1,
                // an estimate that never exceeds 1 even at grazing views.
                let alpha = f64::from(alpha);
                let a2 = alpha * alpha;
                let lambda = |c: f64| smith_lambda(c, a2);
                let (t, b, z) = frame_around(normal);
                let local = |d: DVec3| DVec3::new(d.dot(t), d.dot(b), d.dot(z));
                let v = local(view);
                // The view in the hemisphere configuration of a unit-roughness surface.
                let vh = DVec3::new(alpha * v.x, alpha * v.y, v.z).normalize();
                let len2 = vh.x * vh.x + vh.y * vh.y;
                let t1 = if len2 > 0.0 {
                    DVec3::new(-vh.y, vh.x, 0.0) / len2.sqrt()
                } else {
                    DVec3::X
                };
                let t2 = vh.cross(t1);
                let lambda_v = lambda(n_v);
                let s = 0.5 * (1.0 + vh.z);
                for i in 0..n {
                    let (u1, u2) = hammersley(i, n);
                    let r = u1.sqrt();
                    let phi = std::f64::consts::TAU * u2;
                    let p1 = r * phi.cos();
                    let p2 = (1.0 - s) * (1.0 - p1 * p1).max(0.0).sqrt() + s * r * phi.sin();
                    let nh = t1 * p1 + t2 * p2 + vh * (1.0 - p1 * p1 - p2 * p2).max(0.0).sqrt();
                    let Some(m) =
                        DVec3::new(alpha * nh.x, alpha * nh.y, nh.z.max(0.0)).try_normalize()
                    else {
                        continue;
                    };
                    let h = t * m.x + b * m.y + z * m.z;
                    let h_v = h.dot(view);
                    if h_v <= 0.0 {
                        continue;
                    }
                    let dir = 2.0 * h_v * h - view;
                    let n_l = normal.dot(dir);
                    if n_l <= 0.0 {
                        continue;
                    }
                    f(dir, (1.0 + lambda_v) / (1.0 + lambda_v + lambda(n_l)));
                }
            }
        }
    }
}

/// Texel values of a vertex's visibility (1 visible, 0 blocked or below the tangent plane).
pub fn visibility_texels(vis: &Visibility, vertex: usize) -> Vec<f64> {
    (0..vis.texels)
        .map(|t| if vis.get(vertex, t) { 1.0 } else { 0.0 })
        .collect()
}

/// Indices of the `k` largest |values| (ties: lower index), sorted by index.
pub fn largest_indices(values: &[f64], k: usize) -> Vec<usize> {
    let mut order: Vec<usize> = (0..values.len()).collect();
    let k = k.min(values.len());
    if k < values.len() {
        order.select_nth_unstable_by(k, |&a, &b| {
            values[b].abs().total_cmp(&values[a].abs()).then(a.cmp(&b))
        });
        order.truncate(k);
    }
    order.sort_unstable();
    order
}

/// Per-vertex transport in the wavelet basis, truncated per vertex: one CSR row per vertex.
#[derive(Clone, Debug)]
pub struct Transport {
    pub side: usize,
    pub basis: Basis,
    pub levels: u32,
    offsets: Vec<u32>,
    index: Vec<u16>,
    value: Vec<f32>,
}

/// How a vertex's view direction is chosen for glossy transport.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum View {
    /// Every vertex looks at this point (a camera position).
    Eye(Vec3),
    /// The same direction (towards the viewer) for every vertex.
    Direction(Vec3),
}

impl View {
    /// The unit direction towards the viewer from point `p`.
    pub fn at(self, p: Vec3) -> Vec3 {
        match self {
            View::Eye(e) => (e - p).normalize_or(Vec3::Y),
            View::Direction(d) => d.normalize_or(Vec3::Y),
        }
    }
}

/// An upper bound on the bytes the precomputation holds at its peak for `vertices` vertices,
/// a grid of `texels` directions and `keep` coefficients kept per vertex: the visibility bits
/// ([`super::visibility::vertex_visibility`], one bit a texel), every vertex's row as
/// [`Transport::precompute`] computes it (8 bytes an entry and a `Vec` header) and the packed
/// transport (6 bytes an entry, 4 an offset). Rows whose coefficients are exactly 0 are not
/// stored, so the real figure is lower: the built-in scene (3,703 vertices) at side 64
/// keeping all 4,096 peaked at 124 MiB resident, the whole process, against 204 MiB from
/// this bound.
pub fn precompute_bytes(vertices: usize, texels: usize, keep: usize) -> u64 {
    let keep = keep.min(texels) as u64;
    let visibility = texels.div_ceil(64).max(1) as u64 * 8;
    let rows = keep * 8 + 24;
    let packed = keep * 6 + 4;
    (vertices as u64).saturating_mul(visibility + rows + packed)
}

/// Refuses a precomputation whose memory bound ([`precompute_bytes`]) exceeds `available`
/// bytes (no check with `None`): a failed allocation aborts the process, after the ray
/// casting of every vertex has run.
pub fn check_precompute_memory(
    vertices: usize,
    texels: usize,
    keep: usize,
    available: Option<u64>,
) -> Result<(), TransportError> {
    let need = precompute_bytes(vertices, texels, keep);
    match available {
        Some(available) if need > available => Err(TransportError::Memory {
            vertices,
            texels,
            keep: keep.min(texels),
            need,
            available,
        }),
        _ => Ok(()),
    }
}

impl Transport {
    /// `T_x = W((V_x · ρ_x) √dω)` for every vertex x, keeping the `keep` largest coefficients
    /// (`keep ≥ side²` keeps all). Vertices in parallel.
    pub fn precompute(
        grid: &Grid,
        positions: &[Vec3],
        normals: &[Vec3],
        vis: &Visibility,
        brdf: Brdf,
        view: View,
        keep: usize,
    ) -> Result<Self, TransportError> {
        brdf.validate()?;
        if grid.side > MAX_TRANSPORT_SIDE {
            return Err(TransportError::SideTooLarge {
                what: "transport",
                side: grid.side,
                max: MAX_TRANSPORT_SIDE,
            });
        }
        if vis.texels != grid.len() || vis.vertices() != positions.len() {
            return Err(TransportError::Length {
                what: "visibility (texels × vertices)",
                expected: grid.len() * positions.len(),
                got: vis.texels * vis.vertices(),
            });
        }
        if normals.len() != positions.len() {
            return Err(TransportError::Length {
                what: "normals",
                expected: positions.len(),
                got: normals.len(),
            });
        }
        let rows: Vec<Result<Vec<(u16, f32)>, TransportError>> = (0..positions.len())
            .into_par_iter()
            .map(|v| {
                let slice = grid.brdf_slice(brdf, normals[v], view.at(positions[v]));
                let values: Vec<f64> = slice
                    .iter()
                    .enumerate()
                    .map(|(t, r)| if vis.get(v, t) { *r } else { 0.0 })
                    .collect();
                let c = grid.project(&values)?;
                Ok(largest_indices(&c, keep)
                    .into_iter()
                    .filter(|&k| c[k] != 0.0)
                    .map(|k| (k as u16, c[k] as f32))
                    .collect())
            })
            .collect();
        Self::from_rows(grid, rows.into_iter().collect::<Result<Vec<_>, _>>()?)
    }

    /// Builds transport from explicit rows (index, value) per vertex; indices must be < side².
    pub fn from_rows(
        grid: &Grid,
        rows: impl IntoIterator<Item = Vec<(u16, f32)>>,
    ) -> Result<Self, TransportError> {
        let mut offsets = vec![0u32];
        let mut index = Vec::new();
        let mut value = Vec::new();
        for row in rows {
            for (k, c) in row {
                if k as usize >= grid.len() || !c.is_finite() {
                    return Err(TransportError::Invalid(format!(
                        "transport row {}: entry ({k}, {c}) out of range or not finite",
                        offsets.len() - 1
                    )));
                }
                index.push(k);
                value.push(c);
            }
            // u32 offsets: more entries would wrap them, and a wrapped row would be read
            // backwards (a panic) or as another vertex's.
            let end = u32::try_from(index.len()).map_err(|_| {
                TransportError::Invalid(format!(
                    "transport of more than {} stored coefficients (at row {}); keep fewer \
                     coefficients per vertex or use a smaller mesh",
                    u32::MAX,
                    offsets.len() - 1
                ))
            })?;
            offsets.push(end);
        }
        Ok(Self {
            side: grid.side,
            basis: grid.basis,
            levels: grid.levels,
            offsets,
            index,
            value,
        })
    }

    /// Number of vertices.
    pub fn vertices(&self) -> usize {
        self.offsets.len() - 1
    }

    /// Stored coefficients over all vertices.
    pub fn entries(&self) -> usize {
        self.index.len()
    }

    /// Vertex `v`'s row: (coefficient index, value).
    pub fn row(&self, v: usize) -> impl Iterator<Item = (usize, f32)> + '_ {
        let (a, b) = (self.offsets[v] as usize, self.offsets[v + 1] as usize);
        self.index[a..b]
            .iter()
            .zip(&self.value[a..b])
            .map(|(&k, &c)| (k as usize, c))
    }

    /// Outgoing radiance of every vertex under `light` into `out` (one RGB per vertex).
    pub fn relight(
        &self,
        light: &DenseLighting,
        out: &mut [[f32; 3]],
    ) -> Result<(), TransportError> {
        if light.side != self.side || light.basis != self.basis || light.levels != self.levels {
            return Err(TransportError::GridMismatch {
                what: "lighting",
                expected: self.side,
                basis_expected: format!("{} with {} levels", self.basis, self.levels),
                got: light.side,
                basis_got: format!("{} with {} levels", light.basis, light.levels),
            });
        }
        if out.len() != self.vertices() {
            return Err(TransportError::Length {
                what: "relight output",
                expected: self.vertices(),
                got: out.len(),
            });
        }
        const CHUNK: usize = 512;
        out.par_chunks_mut(CHUNK)
            .enumerate()
            .for_each(|(ci, chunk)| {
                let v0 = ci * CHUNK;
                for (i, o) in chunk.iter_mut().enumerate() {
                    let v = v0 + i;
                    let (a, b) = (self.offsets[v] as usize, self.offsets[v + 1] as usize);
                    let acc = dot_row(&self.index[a..b], &self.value[a..b], &light.table);
                    *o = [acc[0], acc[1], acc[2]];
                }
            });
        Ok(())
    }
}

/// Σ `value[i] · table[index[i]]` with four independent accumulators (RGBA lanes).
#[inline]
fn dot_row(index: &[u16], value: &[f32], table: &[[f32; 4]]) -> [f32; 4] {
    let mut acc = [[0.0f32; 4]; 2];
    let mut ic = index.chunks_exact(2);
    let mut vc = value.chunks_exact(2);
    for (i2, v2) in (&mut ic).zip(&mut vc) {
        for lane in 0..2 {
            let l = table.get(i2[lane] as usize).copied().unwrap_or([0.0; 4]);
            for c in 0..4 {
                acc[lane][c] += v2[lane] * l[c];
            }
        }
    }
    for (&i, &v) in ic.remainder().iter().zip(vc.remainder()) {
        let l = table.get(i as usize).copied().unwrap_or([0.0; 4]);
        for c in 0..4 {
            acc[0][c] += v * l[c];
        }
    }
    std::array::from_fn(|c| acc[0][c] + acc[1][c])
}

/// Lighting coefficients (basis of [`Grid::project`]) scattered into a dense RGBA table.
#[derive(Clone, Debug)]
pub struct DenseLighting {
    pub side: usize,
    pub basis: Basis,
    pub levels: u32,
    table: Vec<[f32; 4]>,
}

impl DenseLighting {
    /// All zeros.
    pub fn new(grid: &Grid) -> Self {
        Self {
            side: grid.side,
            basis: grid.basis,
            levels: grid.levels,
            table: vec![[0.0; 4]; grid.len()],
        }
    }

    /// Replaces the table with a wavelet set's coefficients (scaled by its sphere scale); this
    /// is the per-frame update.
    pub fn set(&mut self, grid: &Grid, set: &WaveletSet) -> Result<(), TransportError> {
        grid.check_set(set)?;
        let s = set.sphere_scale() as f32;
        self.table.iter_mut().for_each(|e| *e = [0.0; 4]);
        for &(i, rgb) in &set.coefficients {
            self.table[i as usize] = [rgb[0] * s, rgb[1] * s, rgb[2] * s, 0.0];
        }
        Ok(())
    }

    /// From dense per-channel coefficients (already in the basis of [`Grid::project`]).
    pub fn from_planes(grid: &Grid, planes: &[Vec<f64>; 3]) -> Result<Self, TransportError> {
        for p in planes {
            if p.len() != grid.len() {
                return Err(TransportError::Length {
                    what: "lighting plane",
                    expected: grid.len(),
                    got: p.len(),
                });
            }
        }
        let mut l = Self::new(grid);
        for (k, e) in l.table.iter_mut().enumerate() {
            *e = [
                planes[0][k] as f32,
                planes[1][k] as f32,
                planes[2][k] as f32,
                0.0,
            ];
        }
        Ok(l)
    }

    /// Number of nonzero coefficients.
    pub fn nonzero(&self) -> usize {
        self.table.iter().filter(|e| e[..3] != [0.0; 3]).count()
    }
}

/// Brute-force outgoing radiance of one vertex: Σ_t V_t L_t ρ_t dω over all texels.
pub fn brute_force(
    grid: &Grid,
    vis: &Visibility,
    vertex: usize,
    slice: &[f64],
    light: &[[f64; 3]],
) -> [f64; 3] {
    let mut acc = [0.0; 3];
    for t in 0..grid.len().min(slice.len()).min(light.len()) {
        if vis.get(vertex, t) {
            for c in 0..3 {
                acc[c] += slice[t] * light[t][c];
            }
        }
    }
    acc.map(|a| a * grid.d_omega())
}

#[cfg(test)]
mod tests {
    use super::super::approx::Coefficients;
    use super::super::visibility::{vertex_visibility, Bvh, Mesh};
    use super::*;

    /// A sky with a sun, smooth gradient and a dark ground.
    pub(crate) fn test_light(d: Vec3) -> [f64; 3] {
        let sun = Vec3::new(0.5, 0.7, -0.5).normalize();
        let s = f64::from(d.dot(sun)).max(0.0).powi(60) * 50.0;
        let sky = if d.y > 0.0 { 1.0 + f64::from(d.y) } else { 0.2 };
        [sky + s, sky * 0.9 + s, sky * 0.7 + 0.8 * s]
    }

    #[test]
    fn projection_is_orthonormal_on_the_sphere() {
        let grid = Grid::new(16, Basis::Daubechies(3), None).unwrap();
        let f: Vec<f64> = grid
            .dirs
            .iter()
            .map(|d| f64::from(d.x + 2.0 * d.y))
            .collect();
        let g: Vec<f64> = grid.dirs.iter().map(|d| f64::from(d.z * d.z)).collect();
        let (cf, cg) = (grid.project(&f).unwrap(), grid.project(&g).unwrap());
        let coeff: f64 = cf.iter().zip(&cg).map(|(a, b)| a * b).sum();
        let texel: f64 = f.iter().zip(&g).map(|(a, b)| a * b).sum::<f64>() * grid.d_omega();
        assert!((coeff - texel).abs() < 1e-12 * texel.abs().max(1.0));
        let back = grid.reconstruct(&cf).unwrap();
        for (a, b) in back.iter().zip(&f) {
            assert!((a - b).abs() < 1e-12);
        }
        assert!(grid.project(&f[1..]).is_err());
    }

    /// The point-sampled slices average the texels the horizon cuts: Lambert's albedo is 1 to
    /// within 2 % on every grid, the coarsest included (its centre samples gave 0 at side 2,
    /// 0.75 at 4, 0.94 at 8; an audit measured the same on a quad), for any normal.
    #[test]
    fn the_lambert_slice_integrates_the_cosine_on_coarse_grids() {
        for normal in [Vec3::Y, Vec3::new(0.3, 0.9, 0.1).normalize(), Vec3::X] {
            for side in [2usize, 4, 8, 16, 32, 64] {
                let grid = Grid::new(side, Basis::Haar, None).unwrap();
                let albedo = grid
                    .brdf_slice(Brdf::Lambert, normal, normal)
                    .iter()
                    .sum::<f64>()
                    * grid.d_omega();
                assert!(
                    (albedo - 1.0).abs() < 0.02,
                    "side {side}, {normal}: {albedo}"
                );
            }
        }
    }

    /// A mirror-like floor seen at a grazing angle reflects its whole albedo: the texels that
    /// hold its reflection straddle the horizon with their centres below it, and were left
    /// invisible (0.33 of a flat quad's albedo at eye height 0.3 of 5, 0.003 at 0.1; an audit).
    #[test]
    fn a_grazing_reflection_is_not_lost_below_the_horizon_texel_centres() {
        let quad = Mesh::ground_grid(0.0, 1.0, 1);
        let bvh = Bvh::build(&quad).unwrap();
        for (side, eye_height) in [(32usize, 0.3f32), (32, 0.1), (8, 1.5)] {
            let grid = Grid::new(side, Basis::Haar, None).unwrap();
            let vis = vertex_visibility(&quad, &bvh, &grid.dirs);
            let one = grid.project(&vec![1.0; grid.len()]).unwrap();
            let light =
                DenseLighting::from_planes(&grid, &[one.clone(), one.clone(), one]).unwrap();
            let view = View::Eye(Vec3::new(5.0, eye_height, 0.0));
            let tr = Transport::precompute(
                &grid,
                &quad.positions,
                &quad.normals,
                &vis,
                Brdf::Ggx { alpha: 0.001 },
                view,
                usize::MAX,
            )
            .unwrap();
            let mut out = vec![[0.0f32; 3]; quad.positions.len()];
            tr.relight(&light, &mut out).unwrap();
            for (v, o) in out.iter().enumerate() {
                assert!(
                    (o[0] - 1.0).abs() < 0.02,
                    "side {side}, eye height {eye_height}, vertex {v}: {}",
                    o[0]
                );
            }
        }
    }

    /// Lobes narrower than a texel keep their energy on coarse grids (texel integrals by
    /// importance sampling, [`Grid::brdf_slice`]): at normal incidence normalised Phong reflects
    /// exactly 1 and smooth GGX just under 1; the brightest texel holds the mirror direction
    /// off normal incidence; and the albedo does not jump where the slice switches from
    /// sampling the lobe to sampling the texel centres.
    #[test]
    fn narrow_lobes_keep_their_energy_on_coarse_grids() {
        let n = Vec3::new(0.3, 0.9, 0.1).normalize();
        let tangent = n.any_orthonormal_vector();
        let oblique = (n * 0.5 + tangent * 0.75f32.sqrt()).normalize();
        for side in [16usize, 32, 64] {
            let grid = Grid::new(side, Basis::Haar, None).unwrap();
            let albedo = |brdf: Brdf, view: Vec3| {
                grid.brdf_slice(brdf, n, view).iter().sum::<f64>() * grid.d_omega()
            };
            for exponent in [100.0f32, 1000.0, 1e4, 1e5] {
                let a = albedo(Brdf::Phong { exponent }, n);
                assert!((a - 1.0).abs() < 0.01, "side {side} Phong {exponent}: {a}");
            }
            for alpha in [0.05f32, 0.01, 0.001] {
                let a = albedo(Brdf::Ggx { alpha }, n);
                assert!(
                    a > 0.98 && a <= 1.0 + 1e-9,
                    "side {side} GGX α={alpha}: {a}"
                );
            }
            for brdf in [Brdf::Phong { exponent: 1e4 }, Brdf::Ggx { alpha: 0.001 }] {
                let slice = grid.brdf_slice(brdf, n, oblique);
                let brightest = largest_indices(&slice, 1)[0];
                let mirror = (2.0 * n.dot(oblique) * n - oblique).as_dvec3();
                let (x, y) = sphere::texel_of(side, mirror);
                assert_eq!(brightest, y * side + x, "side {side} {brdf:?}");
            }
            // Either side of the switch from sampling the lobe to sampling the texel centres,
            // the albedo is that of a fine grid's centres (side 256: lobes ≥ 18 texels wide).
            let fine = Grid::new(256, Basis::Haar, None).unwrap();
            let texel = grid.d_omega().sqrt();
            let switch = (POINT_SAMPLED_LOBE_TEXELS * texel / (4.0 * 0.64)) as f32;
            for alpha in [0.9 * switch, 1.1 * switch] {
                let ggx = Brdf::Ggx { alpha };
                let fine_slice = ggx.slice(n, n, &fine.dirs);
                let want = fine_slice.iter().sum::<f64>() * fine.d_omega();
                let got = albedo(ggx, n);
                // Texel by texel: each texel of the grid is a block of the fine grid's.
                let block = 256 / side;
                let mut fine_texels = vec![0.0f64; grid.len()];
                for (t, v) in fine_slice.iter().enumerate() {
                    let (x, y) = (t % 256 / block, t / 256 / block);
                    fine_texels[y * side + x] += v * fine.d_omega() / grid.d_omega();
                }
                let l1: f64 = grid
                    .brdf_slice(ggx, n, n)
                    .iter()
                    .zip(&fine_texels)
                    .map(|(a, b)| (a - b).abs())
                    .sum::<f64>()
                    * grid.d_omega();
                eprintln!("side {side} α {alpha}: albedo {got} vs {want}, texel L1 {l1}");
                assert!(
                    (got - want).abs() < 0.02 * want,
                    "side {side} GGX α={alpha}: albedo {got}, {want} on a fine grid"
                );
                assert!(l1 < 0.04 * want, "side {side} GGX α={alpha}: texel L1 {l1}");
            }
        }
        // A grazing view: the GGX lobe is narrow across the plane of incidence and is sampled,
        // so the surface reflects no more than it receives (centre samples of a lobe judged by
        // its width in the plane of incidence gave 1.44 at side 128).
        for side in [16usize, 32, 64, 128] {
            let grid = Grid::new(side, Basis::Haar, None).unwrap();
            for (normal, tangent) in [(n, tangent), (Vec3::Y, Vec3::Z)] {
                for n_v in [0.1f32, 0.01, 0.0001, 0.00002] {
                    let view = (normal * n_v + tangent * (1.0 - n_v * n_v).sqrt()).normalize();
                    for alpha in [0.05f32, 0.1, 0.2] {
                        let slice = grid.brdf_slice(Brdf::Ggx { alpha }, normal, view);
                        let a = slice.iter().sum::<f64>() * grid.d_omega();
                        assert!(a <= 1.0, "side {side} GGX α={alpha} n·v={n_v}: albedo {a}");
                    }
                }
            }
        }
    }

    #[test]
    fn brdf_slices_integrate_as_expected() {
        let grid = Grid::new(64, Basis::Haar, None).unwrap();
        let n = Vec3::new(0.3, 0.9, 0.1).normalize();
        // ∫ cos/π dω = 1 over the hemisphere; normalised Phong at normal incidence integrates
        // to (s+2)/(s+3)·... ≤ 1: check Lambert exactly and Phong's albedo is in (0.5, 1].
        let lambert: f64 =
            Brdf::Lambert.slice(n, n, &grid.dirs).iter().sum::<f64>() * grid.d_omega();
        assert!((lambert - 1.0).abs() < 0.01, "{lambert}");
        let phong: f64 = Brdf::Phong { exponent: 16.0 }
            .slice(n, n, &grid.dirs)
            .iter()
            .sum::<f64>()
            * grid.d_omega();
        assert!(phong > 0.5 && phong <= 1.02, "{phong}");
        assert!(Brdf::Phong { exponent: f32::NAN }.validate().is_err());
        // GGX (F = 1) at normal incidence: the single-scattering albedo is just under 1 for a
        // smooth surface and falls as α grows (the energy multiple scattering would return;
        // Kulla and Conty 2017). At α = 1, D = 1/π and G2 = 2 n·ω / (1 + n·ω), so the albedo
        // is ∫₀¹ c/(1+c) dc = 1 − ln 2 exactly. Side 128 resolves α ≥ 0.1.
        let fine = Grid::new(128, Basis::Haar, None).unwrap();
        let albedo = |alpha: f32| {
            let ggx = Brdf::Ggx { alpha };
            ggx.validate().unwrap();
            ggx.slice(n, n, &fine.dirs).iter().sum::<f64>() * fine.d_omega()
        };
        let smooth = albedo(0.1);
        assert!(
            smooth > 0.97 && smooth <= 1.01,
            "GGX α=0.1: albedo {smooth}"
        );
        let rough = albedo(1.0);
        let exact = 1.0 - std::f64::consts::LN_2;
        assert!(
            (rough - exact).abs() < 0.01 * exact,
            "GGX α=1: {rough} vs {exact}"
        );
        let mut previous = smooth;
        for alpha in [0.3f32, 0.6, 1.0] {
            let a = albedo(alpha);
            assert!(
                a < previous,
                "GGX α={alpha}: albedo {a} not below {previous}"
            );
            previous = a;
        }
        for alpha in [0.0, -0.5, 1.5, f32::NAN, f32::INFINITY] {
            assert!(Brdf::Ggx { alpha }.validate().is_err(), "{alpha}");
        }
        // Reciprocal: f_r(ω, ω_o) = f_r(ω_o, ω), so eval/cos is symmetric in its two directions.
        let (a, b) = (
            Vec3::new(0.5, 0.8, 0.2).normalize(),
            Vec3::new(-0.1, 0.7, 0.6).normalize(),
        );
        let ggx = Brdf::Ggx { alpha: 0.4 };
        let fa = ggx.eval(n, a, b) / f64::from(n.dot(b));
        let fb = ggx.eval(n, b, a) / f64::from(n.dot(a));
        assert!((fa - fb).abs() <= 1e-5 * fa, "{fa} vs {fb}");
        // The view below the surface sees nothing.
        assert_eq!(ggx.eval(n, -n, n), 0.0);
    }

    /// The memory bound covers what the precomputation keeps (visibility bits and packed
    /// transport), and the check refuses past the available bytes, with no overflow.
    #[test]
    fn the_precompute_memory_bound_covers_the_transport_and_is_checked() {
        let grid = Grid::new(8, Basis::Haar, None).unwrap();
        let mesh = Mesh::sphere_on_plane(8, 4);
        let bvh = Bvh::build(&mesh).unwrap();
        let vis = vertex_visibility(&mesh, &bvh, &grid.dirs);
        let (n, texels) = (mesh.positions.len(), grid.len());
        let tr = Transport::precompute(
            &grid,
            &mesh.positions,
            &mesh.normals,
            &vis,
            Brdf::Lambert,
            View::Direction(Vec3::Y),
            usize::MAX,
        )
        .unwrap();
        assert!(tr.entries() > n, "{} entries", tr.entries());
        let kept = (tr.entries() * 6 + tr.offsets.len() * 4 + n * texels.div_ceil(64) * 8) as u64;
        let bound = precompute_bytes(n, texels, usize::MAX);
        assert!(bound >= kept + tr.entries() as u64 * 8, "{bound} < {kept}");
        assert_eq!(bound, precompute_bytes(n, texels, texels));
        assert!(check_precompute_memory(n, texels, texels, Some(bound)).is_ok());
        assert!(check_precompute_memory(n, texels, texels, None).is_ok());
        let e = check_precompute_memory(n, texels, texels, Some(bound - 1)).unwrap_err();
        assert!(
            matches!(e, TransportError::Memory { need, keep: 64, .. } if need == bound),
            "{e}"
        );
        assert!(e.to_string().contains(&format!("{n} vertices")), "{e}");
        assert_eq!(precompute_bytes(usize::MAX, 1 << 14, 1 << 14), u64::MAX);
    }

    #[test]
    fn relight_with_all_coefficients_matches_brute_force() {
        let grid = Grid::new(16, Basis::Coiflet(1), None).unwrap();
        let mesh = Mesh::sphere_on_plane(16, 6);
        let bvh = Bvh::build(&mesh).unwrap();
        let vis = vertex_visibility(&mesh, &bvh, &grid.dirs);
        let light: Vec<[f64; 3]> = grid.dirs.iter().map(|d| test_light(*d)).collect();
        let pixels: Vec<[f32; 3]> = light.iter().map(|l| l.map(|c| c as f32)).collect();
        let coeffs = Coefficients::analyze(&pixels, grid.side, grid.basis, grid.levels).unwrap();
        let set = coeffs.truncate(grid.len());
        let mut dense = DenseLighting::new(&grid);
        dense.set(&grid, &set).unwrap();
        let view = View::Eye(Vec3::new(0.0, 2.0, 4.0));
        for brdf in [
            Brdf::Lambert,
            Brdf::Phong { exponent: 8.0 },
            Brdf::Ggx { alpha: 0.3 },
        ] {
            let tr = Transport::precompute(
                &grid,
                &mesh.positions,
                &mesh.normals,
                &vis,
                brdf,
                view,
                usize::MAX,
            )
            .unwrap();
            let mut out = vec![[0.0f32; 3]; mesh.positions.len()];
            tr.relight(&dense, &mut out).unwrap();
            let mut worst = 0.0f64;
            for v in 0..mesh.positions.len() {
                let slice = grid.brdf_slice(brdf, mesh.normals[v], view.at(mesh.positions[v]));
                let b = brute_force(&grid, &vis, v, &slice, &light);
                for c in 0..3 {
                    let err = (f64::from(out[v][c]) - b[c]).abs() / b[c].abs().max(1e-3);
                    worst = worst.max(err);
                }
            }
            assert!(worst < 1e-3, "{brdf:?}: worst relative error {worst}");
        }
    }

    #[test]
    fn mismatched_lighting_is_an_error() {
        let grid = Grid::new(8, Basis::Haar, None).unwrap();
        let other = Grid::new(8, Basis::Daubechies(2), None).unwrap();
        let tr = Transport::from_rows(&grid, [vec![(0u16, 1.0f32)]]).unwrap();
        let mut out = vec![[0.0; 3]; 1];
        assert!(tr.relight(&DenseLighting::new(&other), &mut out).is_err());
        assert!(tr
            .relight(&DenseLighting::new(&grid), &mut out[..0])
            .is_err());
        assert!(Transport::from_rows(&grid, [vec![(64u16, 1.0f32)]]).is_err());
    }
}
