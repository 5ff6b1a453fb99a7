//! Quality yardsticks for light lists, measured against the environment map itself (DESIGN.md),
//! and Debevec's median cut (2005) as the peer method ([`median_cut()`]).
//!
//! # Reference map
//!
//! [`ReferenceMap::new`] takes a lat-long [`HdrFrame`] and box-downsamples it by an integer factor
//! (the smallest one that brings the width to at most `max_width`; the last block of a row or
//! column may be partial when the size is not divisible). The downsampling preserves energy: each
//! coarse pixel keeps Σ rgb·Ω of the fine pixels it covers (exact solid angles from
//! [`Projection::solid_angles`]) and its solid angle Σ Ω. Its direction is the luminance centroid
//! of the block (normalised Σ d·lum·Ω; the block's centre when it is black): with plain block
//! centres a sun inside a block would move by up to half a coarse pixel, and at 256×128 that bias
//! dominated the errors of good light lists on sunny maps. For the same reason a block holding
//! more than [`REFINE_SHARE`] (0.1 %) of the map's luminance energy is kept as its full-resolution
//! pixels: a low sun seen as one point casts a hard shadow whose edge flips whole rows of ground
//! points. (Median cut, 256 lights, rooitou_park, reference width 256: ground-shadow error 0.042
//! with block centres and no refinement, 0.009 against a full-resolution reference.)
//! All ground-truth quantities below are sums over these coarse pixels, computed once per map
//! ([`ReferenceMap::truth`], cached) because a table evaluates several light lists per map.
//! [`ReferenceMap::with_areal_bright_pixels`] reads the kept full-resolution pixels as areas
//! (s × s sub-pixels each) instead of points: the temporal table's fairer truth for lights that
//! do not sit at a sun pixel's centre.
//!
//! # Yardsticks
//!
//! Each yardstick is a relative RMS error over a fixed, deterministic set of evaluation points,
//! computed on Rec. 709 luminance:
//! `sqrt(Σ (approx − truth)²) / sqrt(Σ truth²)`.
//! When the truth is zero everywhere the error is 0 if the lights give zero too, and +∞ otherwise.
//!
//! - [`diffuse_irradiance_error`]: Lambertian irradiance E(n) = Σ rgb·max(0, n·d) at the 1024
//!   normals of a Fibonacci sphere ([`evaluation_directions`]).
//! - [`glossy_error`]: the normalised Phong convolution
//!   G(r) = Σ L·Ω·(k+1)/(2π)·max(0, r·d)^k at the same 1024 directions (reported for k = 16 and
//!   k = 128). Higher exponents resolve the angular placement of the lights more finely.
//! - [`ground_shadow_error`]: irradiance on the ground plane y = 0 under a unit sphere centred at
//!   (0, 1, 0) that rests on it: E(p) = Σ rgb·max(0, d.y)·V(p, d), with V = 0 when the ray from p
//!   along d hits the sphere. Seen from p the sphere is a cone around c − p of half-angle
//!   asin(1/|c − p|), which is the test used. The points are a polar grid around the contact
//!   point ([`ground_points`]: 20 log-spaced radii from 0.05 to 3 × 24 azimuths), covering the
//!   shadow and the lit ground around it.
//! - [`energy_error`]: |Σ light luminance − ∫L dω luminance| / ∫L dω luminance.
//!
//! [`evaluate`] returns all of them as a [`QualityReport`]. Over a sequence, [`flicker`] measures
//! how much a light stream's irradiance changes from frame to frame beyond the truth's change;
//! [`low_passed`] gives the truth a temporal filter's stream should be compared with.

mod median_cut;

pub use median_cut::median_cut;

use crate::decompose::luminance_f64 as lum;
use crate::envmap::Projection;
use crate::frame::HdrFrame;
use crate::light::Light;
use glam::DVec3;
use std::f64::consts::PI;
use std::sync::OnceLock;

/// Number of evaluation directions (normals for diffuse, reflection directions for glossy).
pub const EVALUATION_DIRECTIONS: usize = 1024;
/// Phong exponents reported in [`QualityReport`].
pub const GLOSSY_EXPONENTS: [u32; 2] = [16, 128];
/// Centre of the unit sphere of the ground-shadow scene; it touches the ground at the origin.
pub const SPHERE_CENTRE: DVec3 = DVec3::new(0.0, 1.0, 0.0);

/// A coarse block holding more than this share of the map's luminance energy is kept at full
/// resolution in a [`ReferenceMap`].
pub const REFINE_SHARE: f64 = 1e-3;

const GROUND_RADII: usize = 20;
const GROUND_AZIMUTHS: usize = 24;
const GROUND_MIN_RADIUS: f64 = 0.05;
const GROUND_MAX_RADIUS: f64 = 3.0;

/// Errors of the yardsticks and of median cut.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum YardstickError {
    #[error("only lat-long frames are supported here, got a {0} frame")]
    NotLatLong(&'static str),
    #[error("frame claims {width}x{height} pixels but holds {len}")]
    PixelCount { width: u32, height: u32, len: usize },
    #[error("median cut needs at least one light")]
    NoLights,
}

/// Checks that `frame` is a consistent lat-long frame.
fn check_latlong(frame: &HdrFrame) -> Result<(), YardstickError> {
    if frame.projection != Projection::LatLong {
        return Err(YardstickError::NotLatLong(frame.projection.name()));
    }
    let expected = frame.width as usize * frame.height as usize;
    if frame.width == 0 || frame.height == 0 || frame.pixels.len() != expected {
        return Err(YardstickError::PixelCount {
            width: frame.width,
            height: frame.height,
            len: frame.pixels.len(),
        });
    }
    Ok(())
}

/// A pixel as non-negative finite f64 radiance (NaN, ±Inf and negative channels count as 0).
#[inline]
fn clean(rgb: [f32; 3]) -> [f64; 3] {
    rgb.map(|c| {
        if c.is_finite() && c > 0.0 {
            f64::from(c)
        } else {
            0.0
        }
    })
}

/// `v / |v|` if `v` is a meaningful mean direction of weights summing to `weight` (its length is
/// not lost in rounding), else `None`.
fn unit_if_significant(v: DVec3, weight: f64) -> Option<DVec3> {
    let len = v.length();
    (len.is_finite() && len > 0.0 && len > 1e-9 * weight).then(|| v / len)
}

#[inline]
fn add_scaled(acc: &mut [f64; 3], rgb: [f64; 3], s: f64) {
    acc[0] += rgb[0] * s;
    acc[1] += rgb[1] * s;
    acc[2] += rgb[2] * s;
}

/// The 1024 directions of a Fibonacci sphere, deterministic and nearly uniform.
pub fn evaluation_directions() -> Vec<DVec3> {
    let n = EVALUATION_DIRECTIONS;
    let golden_angle = PI * (3.0 - 5f64.sqrt());
    (0..n)
        .map(|i| {
            let y = 1.0 - (2.0 * i as f64 + 1.0) / n as f64;
            let r = (1.0 - y * y).max(0.0).sqrt();
            let (s, c) = (golden_angle * i as f64).sin_cos();
            DVec3::new(r * c, y, r * s)
        })
        .collect()
}

/// The ground points of the shadow yardstick: a polar grid around the contact point (origin),
/// 20 radii spaced geometrically from 0.05 to 3 (dense near the contact, where the shadow is)
/// × 24 azimuths, rings rotated by half a step in turn. All have y = 0.
pub fn ground_points() -> Vec<DVec3> {
    let ratio = GROUND_MAX_RADIUS / GROUND_MIN_RADIUS;
    let mut points = Vec::with_capacity(GROUND_RADII * GROUND_AZIMUTHS);
    for i in 0..GROUND_RADII {
        let r = GROUND_MIN_RADIUS * ratio.powf(i as f64 / (GROUND_RADII - 1) as f64);
        let offset = if i % 2 == 0 { 0.0 } else { 0.5 };
        for j in 0..GROUND_AZIMUTHS {
            let phi = 2.0 * PI * (j as f64 + offset) / GROUND_AZIMUTHS as f64;
            points.push(DVec3::new(r * phi.cos(), 0.0, r * phi.sin()));
        }
    }
    points
}

/// The occluding cone of the sphere seen from ground point `p`: its unit axis and the cosine of
/// its half-angle. Direction d is blocked iff d·axis > cos_half.
#[inline]
fn occluder_cone(p: DVec3) -> (DVec3, f64) {
    let to_centre = SPHERE_CENTRE - p;
    let dist2 = to_centre.length_squared();
    // dist ≥ 1 for points on the ground (the sphere touches it); guard the contact point.
    let cos_half = (1.0 - 1.0 / dist2.max(1.0)).sqrt();
    (to_centre / dist2.sqrt(), cos_half)
}

/// Ground-truth quantities of a [`ReferenceMap`] (per channel; errors use their luminance).
#[derive(Clone, Debug)]
pub struct Truth {
    /// ∫L dω per channel.
    pub integral: [f64; 3],
    /// E(n) at each of [`evaluation_directions`].
    pub diffuse: Vec<[f64; 3]>,
    /// G(r) for exponent 16 at each of [`evaluation_directions`].
    pub glossy16: Vec<[f64; 3]>,
    /// G(r) for exponent 128 at each of [`evaluation_directions`].
    pub glossy128: Vec<[f64; 3]>,
    /// Shadowed ground irradiance at each of [`ground_points`].
    pub ground: Vec<[f64; 3]>,
}

/// A lat-long environment map at a working resolution, as the ground truth for the yardsticks.
#[derive(Debug)]
pub struct ReferenceMap {
    width: u32,
    height: u32,
    factor: u32,
    /// How many coarse blocks were kept at full resolution.
    refined_blocks: usize,
    /// Direction of each sample (see [`ReferenceMap::directions`]).
    dirs: Vec<DVec3>,
    /// Σ rgb·Ω of each sample.
    energy: Vec<[f64; 3]>,
    /// Solid angle of each sample.
    solid_angle: Vec<f64>,
    truth: OnceLock<Truth>,
}

impl ReferenceMap {
    /// Builds the reference from a lat-long frame, box-downsampled by the smallest integer factor
    /// that makes the width ≤ `max_width` (`max_width` 0 counts as 1). Energy-preserving: each
    /// coarse pixel holds the Σ rgb·Ω of its block (non-finite and negative values count as 0)
    /// and points at the block's luminance centroid; blocks holding more than [`REFINE_SHARE`]
    /// of the luminance energy are kept as their full-resolution pixels.
    pub fn new(frame: &HdrFrame, max_width: u32) -> Result<Self, YardstickError> {
        Self::with_areal_bright_pixels(frame, max_width, 1)
    }

    /// As [`ReferenceMap::new`], but the full-resolution pixels of the bright blocks are read
    /// as areas rather than points: each is split into `split` × `split` sub-pixels at their
    /// own centres, with their exact lat-long solid angles and the pixel's radiance (box
    /// reconstruction). `split` 0 or 1 is [`ReferenceMap::new`].
    ///
    /// Why: the plain reference sums a sun pixel as one point at its centre, so its shadow is
    /// hard-edged at exactly that direction, and an unfiltered light that holds exactly one sun
    /// pixel sits there and matches it exactly, while a light anywhere else inside the pixel
    /// (a temporally filtered one, say) is charged for the difference. The areal reference is
    /// the better estimate of a real sun's penumbra (examples/reference_accuracy.rs splits the
    /// whole hemisphere this way) and does not favour lights at pixel centres. The temporal
    /// table (docs/quality.md) measures flicker against both.
    pub fn with_areal_bright_pixels(
        frame: &HdrFrame,
        max_width: u32,
        split: u32,
    ) -> Result<Self, YardstickError> {
        check_latlong(frame)?;
        let split = split.max(1) as usize;
        let (fw, fh) = (frame.width as usize, frame.height as usize);
        let factor = frame.width.div_ceil(max_width.max(1)).max(1);
        let f = factor as usize;
        let (cw, ch) = (fw.div_ceil(f), fh.div_ceil(f));
        let fine_omega = Projection::LatLong.solid_angles(frame.width, frame.height);
        let cols: Vec<(f64, f64)> = (0..fw)
            .map(|x| (2.0 * PI * (x as f64 + 0.5) / fw as f64).sin_cos())
            .collect();
        let rows: Vec<(f64, f64)> = (0..fh)
            .map(|y| (PI * (y as f64 + 0.5) / fh as f64).sin_cos())
            .collect();
        let fine_dir = |x: usize, y: usize| {
            let ((sin_p, cos_p), (sin_t, cos_t)) = (cols[x], rows[y]);
            DVec3::new(sin_t * sin_p, cos_t, -sin_t * cos_p)
        };

        let mut energy = vec![[0.0f64; 3]; cw * ch];
        let mut solid_angle = vec![0.0f64; cw * ch];
        let mut lum_dir = vec![DVec3::ZERO; cw * ch];
        for y in 0..fh {
            let omega = fine_omega[y * fw];
            let row = &frame.pixels[y * fw..(y + 1) * fw];
            let crow = (y / f) * cw;
            for (x, &p) in row.iter().enumerate() {
                let c = crow + x / f;
                let p = clean(p);
                add_scaled(&mut energy[c], p, omega);
                solid_angle[c] += omega;
                let l = lum(p) * omega;
                if l > 0.0 {
                    lum_dir[c] += fine_dir(x, y) * l;
                }
            }
        }

        let total: f64 = energy.iter().map(|&e| lum(e)).sum();
        let mut map = Self {
            width: cw as u32,
            height: ch as u32,
            factor,
            refined_blocks: 0,
            dirs: Vec::with_capacity(cw * ch),
            energy: Vec::with_capacity(cw * ch),
            solid_angle: Vec::with_capacity(cw * ch),
            truth: OnceLock::new(),
        };
        for cy in 0..ch {
            let (y0, y1) = (cy * f, ((cy + 1) * f).min(fh));
            for cx in 0..cw {
                let (x0, x1) = (cx * f, ((cx + 1) * f).min(fw));
                let c = cy * cw + cx;
                let block_lum = lum(energy[c]);
                if f > 1 && block_lum > REFINE_SHARE * total {
                    // A bright block (a sun, a lamp) keeps its full-resolution pixels.
                    map.refined_blocks += 1;
                    for y in y0..y1 {
                        let omega = fine_omega[y * fw];
                        for x in x0..x1 {
                            let radiance = clean(frame.pixels[y * fw + x]);
                            if split == 1 {
                                let mut e = [0.0; 3];
                                add_scaled(&mut e, radiance, omega);
                                map.dirs.push(fine_dir(x, y));
                                map.energy.push(e);
                                map.solid_angle.push(omega);
                                continue;
                            }
                            let s = split as f64;
                            let theta = |j: f64| PI * (y as f64 + j / s) / fh as f64;
                            for j in 0..split {
                                let (top, bottom) = (theta(j as f64), theta(j as f64 + 1.0));
                                let sub_omega =
                                    2.0 * PI / (fw as f64 * s) * (top.cos() - bottom.cos());
                                let (sin_t, cos_t) = theta(j as f64 + 0.5).sin_cos();
                                for i in 0..split {
                                    let phi =
                                        2.0 * PI * (x as f64 + (i as f64 + 0.5) / s) / fw as f64;
                                    let (sin_p, cos_p) = phi.sin_cos();
                                    let mut e = [0.0; 3];
                                    add_scaled(&mut e, radiance, sub_omega);
                                    map.dirs
                                        .push(DVec3::new(sin_t * sin_p, cos_t, -sin_t * cos_p));
                                    map.energy.push(e);
                                    map.solid_angle.push(sub_omega);
                                }
                            }
                        }
                    }
                    continue;
                }
                let centre = || {
                    Projection::LatLong
                        .pixel_to_direction(
                            frame.width,
                            frame.height,
                            (x0 + x1) as f64 * 0.5,
                            (y0 + y1) as f64 * 0.5,
                        )
                        .unwrap_or(DVec3::Y)
                };
                map.dirs
                    .push(unit_if_significant(lum_dir[c], block_lum).unwrap_or_else(centre));
                map.energy.push(energy[c]);
                map.solid_angle.push(solid_angle[c]);
            }
        }
        Ok(map)
    }

    /// Width of the coarse grid in pixels.
    pub fn width(&self) -> u32 {
        self.width
    }

    /// Height of the coarse grid in pixels.
    pub fn height(&self) -> u32 {
        self.height
    }

    /// The downsampling factor from the source frame.
    pub fn factor(&self) -> u32 {
        self.factor
    }

    /// How many coarse blocks were bright enough to be kept at full resolution.
    pub fn refined_blocks(&self) -> usize {
        self.refined_blocks
    }

    /// The samples the truth sums over are the coarse pixels in row-major order, except that a
    /// refined block is replaced, in place, by its full-resolution pixels. This is each sample's
    /// direction (a coarse pixel's luminance centroid, a fine pixel's centre).
    pub fn directions(&self) -> &[DVec3] {
        &self.dirs
    }

    /// Σ rgb·Ω of each sample (see [`ReferenceMap::directions`]).
    pub fn energies(&self) -> &[[f64; 3]] {
        &self.energy
    }

    /// Solid angle of each sample (they sum to 4π).
    pub fn solid_angles(&self) -> &[f64] {
        &self.solid_angle
    }

    /// ∫L dω per channel.
    pub fn integral(&self) -> [f64; 3] {
        let mut sum = [0.0; 3];
        for &e in &self.energy {
            add_scaled(&mut sum, e, 1.0);
        }
        sum
    }

    /// The ground-truth quantities, computed on first use and cached.
    pub fn truth(&self) -> &Truth {
        self.truth.get_or_init(|| self.compute_truth())
    }

    /// The map as point sources: (direction, energy) of every pixel with non-zero energy.
    fn sources(&self) -> Vec<(DVec3, [f64; 3])> {
        self.dirs
            .iter()
            .zip(&self.energy)
            .filter(|(_, e)| e.iter().any(|&c| c > 0.0))
            .map(|(&d, &e)| (d, e))
            .collect()
    }

    fn compute_truth(&self) -> Truth {
        let sources = self.sources();
        let (diffuse, glossy16, glossy128) = directional_sums(&sources);
        Truth {
            integral: self.integral(),
            diffuse,
            glossy16,
            glossy128,
            ground: ground_sums(&sources),
        }
    }
}

/// Diffuse, Phong-16 and Phong-128 sums of point sources at the evaluation directions.
#[allow(clippy::type_complexity)]
fn directional_sums(
    sources: &[(DVec3, [f64; 3])],
) -> (Vec<[f64; 3]>, Vec<[f64; 3]>, Vec<[f64; 3]>) {
    let dirs = evaluation_directions();
    let k16 = 17.0 / (2.0 * PI);
    let k128 = 129.0 / (2.0 * PI);
    let mut diffuse = vec![[0.0; 3]; dirs.len()];
    let mut glossy16 = vec![[0.0; 3]; dirs.len()];
    let mut glossy128 = vec![[0.0; 3]; dirs.len()];
    for (i, &n) in dirs.iter().enumerate() {
        let (mut e, mut g16, mut g128) = ([0.0; 3], [0.0; 3], [0.0; 3]);
        for &(d, rgb) in sources {
            let c = n.dot(d);
            if c <= 0.0 {
                continue;
            }
            add_scaled(&mut e, rgb, c);
            let c2 = c * c;
            let c4 = c2 * c2;
            let c8 = c4 * c4;
            let c16 = c8 * c8;
            if c16 > 0.0 {
                add_scaled(&mut g16, rgb, c16);
                let c32 = c16 * c16;
                let c64 = c32 * c32;
                add_scaled(&mut g128, rgb, c64 * c64);
            }
        }
        diffuse[i] = e;
        glossy16[i] = g16.map(|v| v * k16);
        glossy128[i] = g128.map(|v| v * k128);
    }
    (diffuse, glossy16, glossy128)
}

/// Shadowed ground irradiance of point sources at the ground points.
fn ground_sums(sources: &[(DVec3, [f64; 3])]) -> Vec<[f64; 3]> {
    ground_points()
        .into_iter()
        .map(|p| {
            let (axis, cos_half) = occluder_cone(p);
            let mut e = [0.0; 3];
            for &(d, rgb) in sources {
                if d.y > 0.0 && d.dot(axis) <= cos_half {
                    add_scaled(&mut e, rgb, d.y);
                }
            }
            e
        })
        .collect()
}

/// Lights as point sources with unit f64 directions; lights without a usable direction are left
/// out (they still count in [`energy_error`]).
fn light_sources(lights: &[Light]) -> Vec<(DVec3, [f64; 3])> {
    lights
        .iter()
        .filter_map(|l| {
            let d = DVec3::from_array(l.dir.map(f64::from));
            let len = d.length();
            (len.is_finite() && len > 0.0).then(|| (d / len, l.rgb.map(f64::from)))
        })
        .collect()
}

/// Relative RMS error on luminance: sqrt(Σ (approx − truth)²) / sqrt(Σ truth²); 0 when both are
/// zero everywhere, +∞ when only the truth is.
pub fn relative_rms(approx: &[[f64; 3]], truth: &[[f64; 3]]) -> f64 {
    let (mut num, mut den) = (0.0, 0.0);
    for (&a, &t) in approx.iter().zip(truth) {
        let (a, t) = (lum(a), lum(t));
        num += (a - t) * (a - t);
        den += t * t;
    }
    ratio(num.sqrt(), den.sqrt())
}

fn ratio(num: f64, den: f64) -> f64 {
    if den > 0.0 {
        num / den
    } else if num == 0.0 {
        0.0
    } else {
        f64::INFINITY
    }
}

/// Relative RMS error of the diffuse irradiance E(n) over the 1024 evaluation normals.
pub fn diffuse_irradiance_error(map: &ReferenceMap, lights: &[Light]) -> f64 {
    let (diffuse, _, _) = directional_sums(&light_sources(lights));
    relative_rms(&diffuse, &map.truth().diffuse)
}

/// Relative RMS error of the normalised Phong convolution with `exponent` over the 1024
/// evaluation directions. Exponents 16 and 128 use the cached truth; others compute
/// theirs on the spot.
pub fn glossy_error(map: &ReferenceMap, lights: &[Light], exponent: u32) -> f64 {
    let sources = light_sources(lights);
    match exponent {
        16 => relative_rms(&directional_sums(&sources).1, &map.truth().glossy16),
        128 => relative_rms(&directional_sums(&sources).2, &map.truth().glossy128),
        _ => relative_rms(
            &phong_sums(&sources, exponent),
            &phong_sums(&map.sources(), exponent),
        ),
    }
}

/// Phong sums for one exponent.
fn phong_sums(sources: &[(DVec3, [f64; 3])], exponent: u32) -> Vec<[f64; 3]> {
    let k = (f64::from(exponent) + 1.0) / (2.0 * PI);
    let e = i32::try_from(exponent).unwrap_or(i32::MAX);
    evaluation_directions()
        .into_iter()
        .map(|r| {
            let mut g = [0.0; 3];
            for &(d, rgb) in sources {
                let c = r.dot(d);
                if c > 0.0 {
                    add_scaled(&mut g, rgb, c.powi(e) * k);
                }
            }
            g
        })
        .collect()
}

/// Relative RMS error of the shadowed ground irradiance over the ground points.
pub fn ground_shadow_error(map: &ReferenceMap, lights: &[Light]) -> f64 {
    relative_rms(&ground_sums(&light_sources(lights)), &map.truth().ground)
}

/// Relative error of the total luminance: |Σ light luminance − ∫L dω luminance| / ∫.
pub fn energy_error(map: &ReferenceMap, lights: &[Light]) -> f64 {
    let total: f64 = lights.iter().map(|l| lum(l.rgb.map(f64::from))).sum();
    let truth = lum(map.truth().integral);
    ratio((total - truth).abs(), truth)
}

/// A light list's diffuse irradiance E(n) at [`evaluation_directions`] and its shadowed ground
/// irradiance at [`ground_points`], per channel: what the yardsticks compare with [`Truth`].
pub fn light_irradiance(lights: &[Light]) -> (Vec<[f64; 3]>, Vec<[f64; 3]>) {
    let sources = light_sources(lights);
    (directional_sums(&sources).0, ground_sums(&sources))
}

/// Temporal flicker over a sequence (DESIGN.md): how much the approximation changes from frame
/// to frame *beyond* the change of the truth, relative to the truth,
/// sqrt(Σ_t Σ_i (Δapprox − Δtruth)²) / sqrt(Σ_t Σ_i truth²) on luminance, where Δ is the change
/// from frame t−1 to t at evaluation point i. 0 for a still sequence decomposed identically.
pub fn flicker(approx: &[Vec<[f64; 3]>], truth: &[Vec<[f64; 3]>]) -> f64 {
    let (mut num, mut den) = (0.0, 0.0);
    for t in 1..approx.len().min(truth.len()) {
        let points = approx[t]
            .iter()
            .zip(&approx[t - 1])
            .zip(truth[t].iter().zip(&truth[t - 1]));
        for ((&a, &a_prev), (&tr, &tr_prev)) in points {
            let excess = (lum(a) - lum(a_prev)) - (lum(tr) - lum(tr_prev));
            num += excess * excess;
            den += lum(tr) * lum(tr);
        }
    }
    ratio(num.sqrt(), den.sqrt())
}

/// A series of per-point values (one `Vec` per frame) passed through FIR `taps` (newest first,
/// normalised to sum to 1): Σ_k w_k x(t−k), the first frame repeating before the start as
/// [`crate::decompose::FirFilter`] starts. The truth a filtered light stream should be compared
/// with when the filter is not to be charged for its lag or for smoothing the truth's own
/// changes (docs/quality.md, "Temporal stability"). Taps that do not sum to a positive finite
/// number leave the series as it is.
pub fn low_passed(series: &[Vec<[f64; 3]>], taps: &[f64]) -> Vec<Vec<[f64; 3]>> {
    let sum: f64 = taps.iter().sum();
    if !(sum.is_finite() && sum > 0.0) {
        return series.to_vec();
    }
    (0..series.len())
        .map(|t| {
            let mut acc = vec![[0.0; 3]; series[t].len()];
            for (k, w) in taps.iter().enumerate() {
                for (a, x) in acc.iter_mut().zip(&series[t.saturating_sub(k)]) {
                    add_scaled(a, *x, w / sum);
                }
            }
            acc
        })
        .collect()
}

/// All yardsticks of one light list (relative errors on luminance; 0 is perfect).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct QualityReport {
    pub diffuse: f64,
    pub glossy16: f64,
    pub glossy128: f64,
    pub ground_shadow: f64,
    pub energy: f64,
}

/// Evaluates every yardstick of `lights` against `map`.
pub fn evaluate(map: &ReferenceMap, lights: &[Light]) -> QualityReport {
    let truth = map.truth();
    let sources = light_sources(lights);
    let (diffuse, glossy16, glossy128) = directional_sums(&sources);
    QualityReport {
        diffuse: relative_rms(&diffuse, &truth.diffuse),
        glossy16: relative_rms(&glossy16, &truth.glossy16),
        glossy128: relative_rms(&glossy128, &truth.glossy128),
        ground_shadow: relative_rms(&ground_sums(&sources), &truth.ground),
        energy: energy_error(map, lights),
    }
}

#[cfg(test)]
mod tests;
