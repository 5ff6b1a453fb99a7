//! The sphere on a square: the equal-area octahedral map (Clarberg 2008, "Fast equal-area
//! mapping of the (hemi)sphere using SIMD"; the form of pbrt-v4's `EqualAreaSquareToSphere`),
//! and resampling of any [`HdrFrame`] onto it.
//!
//! # Parameterisation
//!
//! The unit square \[0,1\]² (u right, v down; texel (x, y) covers [x, x+1)/side × [y, y+1)/side)
//! maps onto the sphere with a constant Jacobian: every texel of a `side × side` grid has solid
//! angle exactly 4π/side². The square's centre is the zenith (+Y), its four corners the nadir
//! (−Y), the inscribed diamond |2u−1| + |2v−1| ≤ 1 the upper hemisphere. Seen from above: +X to
//! the right (u = 1, v = ½), −Z at the top (v = 0), +Z at the bottom, like a map of the scene
//! looked at from the sky. (pbrt's (x, y, z) with z up is our (x, z, y).)
//!
//! # Boundary
//!
//! The map's edges fold onto themselves: (u, 0) and (1−u, 0) are the same direction, likewise on
//! each edge, and the four corners are all the nadir. The true neighbour of texel (x, −1) is
//! (side−1−x, 0) ([`OctahedralMap::fold`]), which resampling uses. The wavelet transform instead
//! uses a *periodic* boundary (the left edge next to the right edge): that is not the sphere's
//! neighbourhood, so wavelets straddling an edge mix unrelated directions near the nadir, but it
//! keeps the transform exactly orthonormal and invertible, which is what the approximation and the
//! triple products need. The cost is some extra detail coefficients along the edges (all of which
//! lie in the lower hemisphere, usually the dim ground).
//!
//! # Resampling ([`Resampler`], [`OctahedralMap::from_frame`])
//!
//! Energy-preserving splatting: every source pixel with solid angle Ω > 0 is split into n × n
//! sub-pixels (n chosen so that about 16 sub-pixels land on an average texel: n = ⌈4·side/√P⌉;
//! a lat-long frame of another aspect than 2:1 gets n/√r × n·√r, r = (w/h)/2, `sub_pixels`)
//! for P covered pixels, at least 1, the sub-pixel grid capped at 2^25), each carrying energy
//! rgb·Ω_sub at its centre direction, Ω_sub being the projection's solid angle of the sub-pixel
//! (its `solid_angles` at n× the resolution; they sum to the pixel's Ω). That
//! energy is splatted bilinearly (tent filter) onto the 4 nearest texel centres, folded across the
//! edges. A texel's radiance is its energy divided by 4π/side². Total energy is preserved up to
//! rounding (Σ texel·4π/side² = Σ pixel·Ω; the tests check 1e-6 relative with f32 texels), a small bright source
//! (a 1-pixel sun) lands with all its energy on the 2×2 texels around its direction instead of
//! being missed or aliased, and the tent filter keeps a constant map constant to within 3 % (tested)
//! (uneven sub-pixel density across a texel) — [`OctahedralMap::from_fn`] samples an analytic
//! function instead, S × S stratified points per texel. Non-finite and negative channels count
//! as 0. Directions a projection does not see (below a fisheye's horizon) get no energy.
//! [`Resampler`] computes the sub-pixel directions and splat weights once per projection and
//! frame size (per pixel: the texels it reaches and the solid angle each receives, merged) and
//! then applies them to every frame; [`OctahedralMap::from_frame`] builds one for a single frame.

use crate::envmap::Projection;
use crate::frame::HdrFrame;
use glam::DVec3;
use std::f64::consts::{FRAC_PI_4, PI};

/// Errors of the sphere map.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum SphereError {
    #[error("octahedral map side must be a power of two between 2 and {max}, got {side}")]
    Side { side: usize, max: usize },
    #[error("frame claims {width}x{height} pixels but holds {len}")]
    PixelCount { width: u32, height: u32, len: usize },
    #[error("cannot resample a {width}x{height} frame: empty or too large")]
    FrameSize { width: u32, height: u32 },
    #[error("resampler was built for {expected} frames, got a {got} frame")]
    Mismatch { expected: String, got: String },
    #[error("octahedral map of side {side} needs {expected} texels, got {len}")]
    TexelCount {
        side: usize,
        expected: usize,
        len: usize,
    },
}

/// Largest supported side (1024² texels).
pub const MAX_SIDE: usize = 1024;

/// Direction (unit vector) of the point (u, v) ∈ \[0,1\]² of the equal-area octahedral map.
pub fn square_to_sphere(u: f64, v: f64) -> DVec3 {
    let (a, b) = (2.0 * u - 1.0, 2.0 * v - 1.0);
    let (ap, bp) = (a.abs(), b.abs());
    let signed_distance = 1.0 - (ap + bp);
    let r = 1.0 - signed_distance.abs();
    let phi = if r == 0.0 { 1.0 } else { (bp - ap) / r + 1.0 } * FRAC_PI_4;
    let z = (1.0 - r * r).copysign(signed_distance);
    let (sin_phi, cos_phi) = phi.sin_cos();
    let s = r * (2.0 - r * r).max(0.0).sqrt();
    let (px, py) = (cos_phi.copysign(a) * s, sin_phi.copysign(b) * s);
    // pbrt (x, y, z), z up → ours (x, z, y), +Y up.
    DVec3::new(px, z, py)
}

/// The point (u, v) ∈ \[0,1\]² of direction `d` (need not be normalised; the zero or a
/// non-finite vector gives the zenith's (½, ½)).
pub fn sphere_to_square(d: DVec3) -> (f64, f64) {
    let len = d.length();
    if !(len.is_finite() && len > 0.0) {
        return (0.5, 0.5);
    }
    let d = d / len;
    let (x, y, z) = (d.x, d.z, d.y);
    let (ax, ay, az) = (x.abs(), y.abs(), z.abs().min(1.0));
    let r = (1.0 - az).max(0.0).sqrt();
    let (hi, lo) = (ax.max(ay), ax.min(ay));
    let ratio = if hi == 0.0 { 0.0 } else { lo / hi };
    let mut phi = ratio.atan() * 2.0 / PI;
    if ax < ay {
        phi = 1.0 - phi;
    }
    let mut v = phi * r;
    let mut u = r - v;
    if z < 0.0 {
        std::mem::swap(&mut u, &mut v);
        u = 1.0 - u;
        v = 1.0 - v;
    }
    let u = u.copysign(x);
    let v = v.copysign(y);
    (0.5 * (u + 1.0), 0.5 * (v + 1.0))
}

/// Checks a map side: a power of two in 2..=[`MAX_SIDE`].
pub fn check_side(side: usize) -> Result<(), SphereError> {
    if (2..=MAX_SIDE).contains(&side) && side.is_power_of_two() {
        Ok(())
    } else {
        Err(SphereError::Side {
            side,
            max: MAX_SIDE,
        })
    }
}

/// An RGB radiance map on the equal-area octahedral square, `side × side`, row-major.
#[derive(Clone, Debug, PartialEq)]
pub struct OctahedralMap {
    side: usize,
    texels: Vec<[f32; 3]>,
}

impl OctahedralMap {
    /// A map from its texels (`side²`, row-major, radiance per channel).
    pub fn new(side: usize, texels: Vec<[f32; 3]>) -> Result<Self, SphereError> {
        check_side(side)?;
        if texels.len() != side * side {
            return Err(SphereError::TexelCount {
                side,
                expected: side * side,
                len: texels.len(),
            });
        }
        Ok(Self { side, texels })
    }

    /// Side of the square.
    pub fn side(&self) -> usize {
        self.side
    }

    /// The texels, row-major.
    pub fn texels(&self) -> &[[f32; 3]] {
        &self.texels
    }

    /// Consumes the map, returning its texels.
    pub fn into_texels(self) -> Vec<[f32; 3]> {
        self.texels
    }

    /// Solid angle of every texel: 4π/side².
    pub fn texel_solid_angle(&self) -> f64 {
        texel_solid_angle(self.side)
    }

    /// Direction of the continuous texel position (x, y) ∈ [0, side]².
    pub fn direction(&self, x: f64, y: f64) -> DVec3 {
        let s = self.side as f64;
        square_to_sphere(x / s, y / s)
    }

    /// Direction of the centre of texel (x, y).
    pub fn texel_direction(&self, x: usize, y: usize) -> DVec3 {
        self.direction(x as f64 + 0.5, y as f64 + 0.5)
    }

    /// The texel (x, y) that holds direction `d`.
    pub fn texel_of(&self, d: DVec3) -> (usize, usize) {
        texel_of(self.side, d)
    }

    /// Radiance in direction `d` (the texel holding it; no interpolation).
    pub fn lookup(&self, d: DVec3) -> [f32; 3] {
        let (x, y) = self.texel_of(d);
        self.texels[y * self.side + x]
    }

    /// The texel that is the sphere's neighbour of the possibly out-of-range texel (x, y) with
    /// x, y ∈ −1..=side: folded across the square's edges (see the module documentation).
    pub fn fold(side: usize, x: isize, y: isize) -> (usize, usize) {
        let s = side as isize;
        let (mut x, mut y) = (x, y);
        if x < 0 {
            x = 0;
            y = s - 1 - y;
        } else if x >= s {
            x = s - 1;
            y = s - 1 - y;
        }
        if y < 0 {
            y = 0;
            x = s - 1 - x;
        } else if y >= s {
            y = s - 1;
            x = s - 1 - x;
        }
        (x.clamp(0, s - 1) as usize, y.clamp(0, s - 1) as usize)
    }

    /// ∫L dω per channel: Σ texel · 4π/side².
    pub fn integral(&self) -> [f64; 3] {
        let omega = self.texel_solid_angle();
        let mut sum = [0.0; 3];
        for t in &self.texels {
            for c in 0..3 {
                sum[c] += f64::from(t[c]);
            }
        }
        sum.map(|s| s * omega)
    }

    /// Samples `f(direction)` at `samples × samples` stratified points per texel (their mean).
    pub fn from_fn(
        side: usize,
        samples: usize,
        f: impl Fn(DVec3) -> [f64; 3],
    ) -> Result<Self, SphereError> {
        check_side(side)?;
        let n = samples.max(1);
        let s = side as f64;
        let mut texels = Vec::with_capacity(side * side);
        for y in 0..side {
            for x in 0..side {
                let mut acc = [0.0; 3];
                for j in 0..n {
                    for i in 0..n {
                        let u = (x as f64 + (i as f64 + 0.5) / n as f64) / s;
                        let v = (y as f64 + (j as f64 + 0.5) / n as f64) / s;
                        let rgb = f(square_to_sphere(u, v));
                        for c in 0..3 {
                            acc[c] += rgb[c];
                        }
                    }
                }
                let inv = 1.0 / (n * n) as f64;
                texels.push(acc.map(|a| (a * inv) as f32));
            }
        }
        Ok(Self { side, texels })
    }

    /// Resamples a frame of any projection onto a `side × side` map, preserving energy (see the
    /// module documentation).
    pub fn from_frame(frame: &HdrFrame, side: usize) -> Result<Self, SphereError> {
        Resampler::new(frame.projection, frame.width, frame.height, side)?.resample(frame)
    }

    /// Every texel as a directional light (rgb = radiance · 4π/side², at the texel centre),
    /// skipping black texels; `id` is the texel index.
    pub fn to_lights(&self) -> Vec<crate::Light> {
        let omega = self.texel_solid_angle();
        let mut lights = Vec::new();
        for y in 0..self.side {
            for x in 0..self.side {
                let t = self.texels[y * self.side + x];
                if t == [0.0; 3] {
                    continue;
                }
                let d = self.texel_direction(x, y);
                lights.push(crate::Light {
                    id: (y * self.side + x) as u32,
                    dir: [d.x as f32, d.y as f32, d.z as f32],
                    rgb: t.map(|c| (f64::from(c) * omega) as f32),
                    solid_angle: omega as f32,
                });
            }
        }
        lights
    }
}

/// Sub-pixels per pixel (across, down) for resampling: enough for about 16 sub-pixels per
/// texel (n = ⌈4·side/√covered⌉ on each side of a pixel), at least 1, and at most what keeps
/// the sub-pixel grid under [`MAX_SUB_PIXELS`]. A lat-long frame whose aspect `r` = (w/h)/2 is
/// not 1 has pixels that are not square on the sphere: n/√r across and n·√r down, so a frame
/// of 4000×40 pixels gets rows of sub-pixels closer than a texel (with n × n its rows were
/// 4.5° apart, more than a 64-side map's texels, and a constant map came out 7.7% off).
fn sub_pixels(side: usize, covered: usize, w: u32, h: u32, latlong: bool) -> (usize, usize) {
    let n = 4.0 * side as f64 / (covered as f64).sqrt();
    let aspect = if latlong {
        (f64::from(w) / f64::from(h.max(1)) / 2.0).sqrt()
    } else {
        1.0
    };
    let (mut across, mut down) = (n / aspect, n * aspect);
    let pixels = (w as usize * h as usize).max(1);
    let room = (MAX_SUB_PIXELS / pixels) as f64;
    let want = across.ceil().max(1.0) * down.ceil().max(1.0);
    if want > room {
        let shrink = (room / want).sqrt();
        (across, down) = (across * shrink, down * shrink);
    }
    // At most 1024 a side (the grid as a whole is capped above): 64 left holes between the
    // sub-pixels of a tiny frame (a 1×1 frame at side 128: 4,096 sub-pixels for 16,384
    // texels, a reconstruction from 0 to 5.6 of a constant 1) and rows of a 2000×2 frame's
    // sub-pixels 1.4° apart (0.972–1.041; an audit).
    let count = |v: f64| (v.ceil().max(1.0) as usize).min(1024);
    let (across, down) = (count(across), count(down));
    if across * down > room.max(1.0) as usize {
        return (1, 1);
    }
    (across, down)
}

/// Upper bound on the sub-pixel grid of one resampling (its solid angles are held in memory).
pub const MAX_SUB_PIXELS: usize = 1 << 25;

/// Solid angle of a texel of a `side × side` map: 4π/side².
pub fn texel_solid_angle(side: usize) -> f64 {
    4.0 * PI / (side * side).max(1) as f64
}

/// The texel (x, y) of a `side × side` map that holds direction `d`.
pub fn texel_of(side: usize, d: DVec3) -> (usize, usize) {
    let (u, v) = sphere_to_square(d);
    let s = side as f64;
    let x = ((u * s) as usize).min(side.saturating_sub(1));
    let y = ((v * s) as usize).min(side.saturating_sub(1));
    (x, y)
}

/// DESIGN.md's lat-long direction (the same as `Projection::LatLong`, without the `Option`).
#[inline]
fn latlong_direction(w: u32, h: u32, x: f64, y: f64) -> DVec3 {
    let phi = 2.0 * PI * x / f64::from(w);
    let theta = PI * y / f64::from(h);
    let (sin_t, cos_t) = theta.sin_cos();
    let (sin_p, cos_p) = phi.sin_cos();
    DVec3::new(sin_t * sin_p, cos_t, -sin_t * cos_p)
}

/// The 4 (texel index, weight) pairs of a bilinear (tent) splat at continuous texel-centre
/// coordinates (fx, fy) (texel (x, y) has its centre at (x, y)), neighbours outside the square
/// folded across its edges. The weights sum to 1.
#[inline]
fn splat_weights(side: usize, fx: f64, fy: f64) -> [(u32, f64); 4] {
    let (x0, y0) = (fx.floor(), fy.floor());
    let (tx, ty) = (fx - x0, fy - y0);
    let (x0, y0) = (x0 as isize, y0 as isize);
    let s = side as isize;
    let mut out = [(0u32, 0.0f64); 4];
    let mut k = 0;
    for (dy, wy) in [(0, 1.0 - ty), (1, ty)] {
        for (dx, wx) in [(0, 1.0 - tx), (1, tx)] {
            let (x, y) = (x0 + dx, y0 + dy);
            let (x, y) = if (0..s).contains(&x) && (0..s).contains(&y) {
                (x as usize, y as usize)
            } else {
                OctahedralMap::fold(side, x, y)
            };
            out[k] = ((y * side + x) as u32, wx * wy);
            k += 1;
        }
    }
    out
}

/// A resampling plan from frames of one projection and size onto a `side × side` octahedral map
/// (the method of the module documentation), built once and applied to every frame: per source
/// pixel, the texels its energy goes to and the solid angle each receives. Applying it is a
/// scatter of a few multiply-adds per pixel; building it costs the directions and the map.
#[derive(Clone, Debug)]
pub struct Resampler {
    projection: Projection,
    width: u32,
    height: u32,
    side: usize,
    /// Per pixel, the range of its entries in `entries` (`offsets.len() = pixels + 1`).
    offsets: Vec<u32>,
    /// (texel index, solid angle Ω·weight in sr) for each pixel, duplicates merged.
    entries: Vec<(u32, f32)>,
}

impl Resampler {
    /// The plan for `width × height` frames in `projection` onto a `side × side` map.
    pub fn new(
        projection: Projection,
        width: u32,
        height: u32,
        side: usize,
    ) -> Result<Self, SphereError> {
        check_side(side)?;
        let (w, h) = (width, height);
        let pixels = w as usize * h as usize;
        // Entries: 4 per sub-pixel at most, and the sub-pixel grid is capped (n = 1 above it).
        let max_entries = pixels.saturating_mul(4).saturating_add(4 * MAX_SUB_PIXELS);
        if w == 0 || h == 0 || u32::try_from(max_entries).is_err() {
            return Err(SphereError::FrameSize {
                width: w,
                height: h,
            });
        }
        let omegas = projection.solid_angles(w, h);
        let covered = omegas.iter().filter(|&&o| o > 0.0).count().max(1);
        let latlong = projection == Projection::LatLong;
        let (nx, ny) = sub_pixels(side, covered, w, h, latlong);
        let split = nx * ny > 1;
        // Sub-pixel solid angles: the projection's own at nx × ny the resolution, so the energy
        // of a pixel is shared as the sphere is (near a lat-long pole the sub-pixels differ a
        // lot).
        let fine = if split {
            // nx = ny but for lat-long frames, whose solid angles depend on no pixel size.
            projection
                .magnified(nx as u32)
                .solid_angles(w * nx as u32, h * ny as u32)
        } else {
            Vec::new()
        };
        let fine_w = w as usize * nx;
        let s = side as f64;
        let mut offsets = Vec::with_capacity(pixels + 1);
        let mut entries: Vec<(u32, f32)> = Vec::with_capacity(pixels * 4);
        let mut local: Vec<(u32, f64)> = Vec::with_capacity(4 * nx * ny);
        offsets.push(0u32);
        for py in 0..h {
            for px in 0..w {
                let idx = py as usize * w as usize + px as usize;
                local.clear();
                if omegas[idx] > 0.0 {
                    for j in 0..ny {
                        for i in 0..nx {
                            let omega = if split {
                                fine[(py as usize * ny + j) * fine_w + px as usize * nx + i]
                            } else {
                                omegas[idx]
                            };
                            if omega <= 0.0 {
                                continue;
                            }
                            let sx = f64::from(px) + (i as f64 + 0.5) / nx as f64;
                            let sy = f64::from(py) + (j as f64 + 0.5) / ny as f64;
                            let d = if latlong {
                                Some(latlong_direction(w, h, sx, sy))
                            } else {
                                projection.pixel_to_direction(w, h, sx, sy)
                            };
                            let Some(d) = d else { continue };
                            let (u, v) = sphere_to_square(d);
                            for (t, wt) in splat_weights(side, u * s - 0.5, v * s - 0.5) {
                                if wt > 0.0 {
                                    local.push((t, wt * omega));
                                }
                            }
                        }
                    }
                    local.sort_unstable_by_key(|e| e.0);
                    let mut last: Option<(u32, f64)> = None;
                    for &(t, wt) in &local {
                        match &mut last {
                            Some((lt, lw)) if *lt == t => *lw += wt,
                            _ => {
                                if let Some((lt, lw)) = last {
                                    entries.push((lt, lw as f32));
                                }
                                last = Some((t, wt));
                            }
                        }
                    }
                    if let Some((lt, lw)) = last {
                        entries.push((lt, lw as f32));
                    }
                }
                offsets.push(entries.len() as u32);
            }
        }
        Ok(Self {
            projection,
            width,
            height,
            side,
            offsets,
            entries,
        })
    }

    /// Side of the maps this plan makes.
    pub fn side(&self) -> usize {
        self.side
    }

    /// Whether this plan fits `frame` (projection and size).
    pub fn fits(&self, frame: &HdrFrame) -> bool {
        frame.projection == self.projection
            && frame.width == self.width
            && frame.height == self.height
    }

    /// Resamples `frame` (which must have this plan's projection and size).
    pub fn resample(&self, frame: &HdrFrame) -> Result<OctahedralMap, SphereError> {
        let pixels = self.width as usize * self.height as usize;
        if !self.fits(frame) || frame.pixels.len() != pixels {
            return Err(SphereError::Mismatch {
                expected: format!("{}x{} {}", self.width, self.height, self.projection.name()),
                got: format!(
                    "{}x{} {} with {} pixels",
                    frame.width,
                    frame.height,
                    frame.projection.name(),
                    frame.pixels.len()
                ),
            });
        }
        let side = self.side;
        let mut energy = vec![[0.0f64; 3]; side * side];
        for (i, p) in frame.pixels.iter().enumerate() {
            let rgb = p.map(|c| {
                if c.is_finite() && c > 0.0 {
                    f64::from(c)
                } else {
                    0.0
                }
            });
            if rgb == [0.0; 3] {
                continue;
            }
            let range = self.offsets[i] as usize..self.offsets[i + 1] as usize;
            for &(t, omega) in &self.entries[range] {
                let e = &mut energy[t as usize];
                let omega = f64::from(omega);
                e[0] += rgb[0] * omega;
                e[1] += rgb[1] * omega;
                e[2] += rgb[2] * omega;
            }
        }
        let inv_omega = 1.0 / texel_solid_angle(side);
        let texels = energy
            .into_iter()
            .map(|e| e.map(|c| (c * inv_omega) as f32))
            .collect();
        Ok(OctahedralMap { side, texels })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn landmarks() {
        let close = |a: DVec3, b: DVec3| (a - b).length() < 1e-12;
        assert!(
            close(square_to_sphere(0.5, 0.5), DVec3::Y),
            "centre is the zenith"
        );
        for (u, v) in [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0)] {
            assert!(
                close(square_to_sphere(u, v), -DVec3::Y),
                "corners are the nadir"
            );
        }
        assert!(close(square_to_sphere(1.0, 0.5), DVec3::X));
        assert!(close(square_to_sphere(0.0, 0.5), -DVec3::X));
        assert!(close(square_to_sphere(0.5, 0.0), -DVec3::Z));
        assert!(close(square_to_sphere(0.5, 1.0), DVec3::Z));
    }

    #[test]
    fn round_trip() {
        let n = 97;
        for j in 0..n {
            for i in 0..n {
                let (u, v) = ((i as f64 + 0.5) / n as f64, (j as f64 + 0.5) / n as f64);
                let d = square_to_sphere(u, v);
                assert!((d.length() - 1.0).abs() < 1e-12);
                let (u2, v2) = sphere_to_square(d);
                assert!(
                    (u - u2).abs() < 1e-9 && (v - v2).abs() < 1e-9,
                    "({u}, {v}) → {d} → ({u2}, {v2})"
                );
            }
        }
    }

    #[test]
    fn edges_fold_onto_themselves() {
        for t in [0.1, 0.3, 0.45] {
            for (a, b) in [
                ((t, 0.0), (1.0 - t, 0.0)),
                ((t, 1.0), (1.0 - t, 1.0)),
                ((0.0, t), (0.0, 1.0 - t)),
                ((1.0, t), (1.0, 1.0 - t)),
            ] {
                let (da, db) = (square_to_sphere(a.0, a.1), square_to_sphere(b.0, b.1));
                assert!((da - db).length() < 1e-12, "{a:?} vs {b:?}");
            }
        }
        let side = 8;
        assert_eq!(OctahedralMap::fold(side, 2, -1), (5, 0));
        assert_eq!(OctahedralMap::fold(side, -1, 2), (0, 5));
        assert_eq!(OctahedralMap::fold(side, 8, 2), (7, 5));
        assert_eq!(OctahedralMap::fold(side, 2, 8), (5, 7));
        assert_eq!(OctahedralMap::fold(side, -1, -1), (7, 7));
    }

    #[test]
    fn jacobian_is_constant() {
        // |∂d/∂u × ∂d/∂v| = 4π everywhere off the fold lines (total area 4π over the unit square).
        let h = 1e-6;
        let n = 41;
        for j in 0..n {
            for i in 0..n {
                let (u, v) = ((i as f64 + 0.37) / n as f64, (j as f64 + 0.61) / n as f64);
                let du = (square_to_sphere(u + h, v) - square_to_sphere(u - h, v)) / (2.0 * h);
                let dv = (square_to_sphere(u, v + h) - square_to_sphere(u, v - h)) / (2.0 * h);
                let jac = du.cross(dv).length();
                assert!(
                    (jac - 4.0 * PI).abs() < 1e-4 * 4.0 * PI,
                    "({u}, {v}): {jac}"
                );
            }
        }
    }
}
