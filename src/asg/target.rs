//! The fit target of a frame ([`FitTarget`]): the frame resampled to the fit map, its
//! ground-truth diffuse map, and the buffers that are reused from frame to frame (step 1 of the
//! fitting, `fit` module doc; Clausen et al. 2024).
//!
//! Steps for a frame:
//! 1. **Resample** ([`resample_latlong`]) to a `2h × h` lat-long map that keeps the frame's
//!    integral (exactly for a lat-long frame; a fisheye or angular frame's locally to a few
//!    per cent, uniform areas staying uniform): an exact box filter when the source is
//!    lat-long and an integer multiple of the size; another lat-long size by exact area overlap (`latlong_by_overlap`); a fisheye or
//!    angular frame by bilinear splatting of sub-pixels with coverage normalisation
//!    (`src/asg/splat.rs`; its table built once per frame geometry and kept by the target).
//!    Non-finite and negative values count as 0.
//! 2. **Integral and mean** radiance: ∫L dω per channel over the pixels' exact solid angles.
//! 3. **Diffuse ground truth** D_GT(n) = Σ_p L_p max(n·d_p, 0) Ω_p, by direct convolution of a
//!    ≤ 64×128 box-downsampled copy (cells: the solid-angle-weighted sums of the pixels' radiance,
//!    at the normalised solid-angle-weighted mean of their directions) at the normals of a
//!    Fibonacci sphere. The sums run over the normals in blocks of 8 f64 lanes (one cell at a
//!    time, all 8 normals), with a branch-free clamp, so the compiler vectorises them; on
//!    x86-64 with AVX2 the same code is compiled a second time with AVX2 enabled and chosen at
//!    run time. Each normal's sum still adds the cells in order, without fused multiply-adds,
//!    so the result is bit for bit the scalar loop's.
//! 4. **Reuse**: everything that depends only on the map size and the number of normals — pixel
//!    directions, solid angles and weights, the normals, the coarse cells' directions, and the
//!    fast kernel's tiles ([`super::fast::Pixels`]) — is made once by [`FitTarget::from_latlong`]
//!    / [`FitTarget::from_frame`]; [`FitTarget::refill`] recomputes only steps 1–3 and the
//!    tiles' radiance, into the same buffers (no allocation once warm). `AsgFitter` keeps its
//!    target from frame to frame this way. A refilled target is equal, field for field, to one
//!    made from scratch from the same frame (`tests/asg.rs`).

use super::fast::Pixels;
use super::splat::SplatTable;
use super::{Asg, AsgError, MAX_BANDWIDTH, MIN_BANDWIDTH};
use crate::envmap::Projection;
use crate::frame::HdrFrame;
use glam::DVec3;
use std::f64::consts::PI;
use std::sync::Arc;

/// Lanes (normals) per block of the diffuse ground truth (step 3).
const NORMAL_LANES: usize = 8;
/// Largest number of rows of the coarse copy the diffuse ground truth is computed from.
const COARSE_ROWS: u32 = 64;

/// One frame resampled for fitting, with its ground-truth diffuse map.
#[derive(Clone, Debug)]
pub struct FitTarget {
    pub width: u32,
    pub height: u32,
    /// Pixel-centre directions, row-major.
    pub directions: Vec<DVec3>,
    /// Radiance per pixel (non-negative, finite).
    pub radiance: Vec<[f64; 3]>,
    /// Solid angle / 4π per pixel (sums to 1).
    pub weights: Vec<f64>,
    /// Diffuse-comparison normals (Fibonacci sphere).
    pub normals: Vec<DVec3>,
    /// D_GT at `normals` (irradiance).
    pub diffuse: Vec<[f64; 3]>,
    /// Mean radiance M = (1/4π)∫ Σ_c L dω.
    pub mean: f64,
    /// ∫ L dω per channel.
    pub integral: [f64; 3],
    /// The pixels tiled for the fast kernel, made on first use and refilled by
    /// [`FitTarget::refill`] (a target is not meant to be changed otherwise).
    tiled: std::sync::OnceLock<Pixels>,
    /// What depends only on the size (step 4).
    geometry: Arc<Geometry>,
    /// Per-frame scratch of the diffuse ground truth: cell energies, then the cells with
    /// energy as (direction, energy) rows.
    energy: Vec<[f64; 3]>,
    cells: Vec<[f64; 6]>,
    /// The splat table of the frames' geometry when they are fisheye or angular frames.
    table: TableCache,
}

/// The parts of a target that depend only on its size and number of normals (module doc,
/// step 4).
#[derive(Debug)]
struct Geometry {
    /// Solid angle of every pixel (steradians), row-major.
    omegas: Vec<f64>,
    /// Pixels per side of a coarse cell, and the coarse copy's width in cells.
    factor: u32,
    cells_wide: u32,
    /// Normalised direction of every coarse cell, row-major.
    cell_directions: Vec<DVec3>,
    /// The normals in blocks of [`NORMAL_LANES`] (x, y, z lanes; the last block padded with
    /// zero normals, whose sums are dropped).
    normal_blocks: Vec<[[f64; NORMAL_LANES]; 3]>,
}

impl Geometry {
    /// The geometry of a map with these pixel directions and solid angles.
    fn new(
        width: u32,
        height: u32,
        directions: &[DVec3],
        omegas: Vec<f64>,
        normals: &[DVec3],
    ) -> Self {
        let factor = (height / COARSE_ROWS).max(1);
        let (cw, ch) = (width.div_ceil(factor), height.div_ceil(factor));
        let mut sums = vec![DVec3::ZERO; cw as usize * ch as usize];
        for y in 0..height {
            for x in 0..width {
                let i = (y * width + x) as usize;
                sums[((y / factor) * cw + x / factor) as usize] += directions[i] * omegas[i];
            }
        }
        let cell_directions = sums.into_iter().map(|d| d.normalize_or(DVec3::Y)).collect();
        let normal_blocks = normals
            .chunks(NORMAL_LANES)
            .map(|chunk| {
                let mut b = [[0.0; NORMAL_LANES]; 3];
                for (l, n) in chunk.iter().enumerate() {
                    b[0][l] = n.x;
                    b[1][l] = n.y;
                    b[2][l] = n.z;
                }
                b
            })
            .collect();
        Self {
            omegas,
            factor,
            cells_wide: cw,
            cell_directions,
            normal_blocks,
        }
    }
}

/// `n` directions of a Fibonacci sphere.
pub fn fibonacci_sphere(n: usize) -> Vec<DVec3> {
    let golden = PI * (3.0 - 5f64.sqrt());
    (0..n)
        .map(|i| {
            let y = 1.0 - (2.0 * i as f64 + 1.0) / n as f64;
            let r = (1.0 - y * y).max(0.0).sqrt();
            let (s, c) = (golden * i as f64).sin_cos();
            DVec3::new(r * c, y, r * s)
        })
        .collect()
}

/// [`clean`] kept in f32 (for sums of a few values before they go to f64).
#[inline]
pub(super) fn clean_f32(c: f32) -> f32 {
    // NaN and +∞ fail the comparison; −∞ and negative values go to 0 by the max.
    if c < f32::INFINITY {
        c.max(0.0)
    } else {
        0.0
    }
}

#[inline]
pub(super) fn clean(c: f32) -> f64 {
    if c.is_finite() && c > 0.0 {
        f64::from(c)
    } else {
        0.0
    }
}

/// Resamples `frame` (any projection) to a `2h × h` lat-long map of radiance (module doc,
/// step 1).
pub fn resample_latlong(frame: &HdrFrame, height: u32) -> Result<Vec<[f64; 3]>, AsgError> {
    let mut out = Vec::new();
    resample_latlong_into(frame, height, &mut out)?;
    Ok(out)
}

/// As [`resample_latlong`], into `out` (replaced; its allocation is reused). On error `out`
/// is left unchanged.
pub fn resample_latlong_into(
    frame: &HdrFrame,
    height: u32,
    out: &mut Vec<[f64; 3]>,
) -> Result<(), AsgError> {
    resample_latlong_cached(frame, height, out, &mut None)
}

/// The splat table of a fisheye or angular frame geometry, kept from frame to frame by
/// [`FitTarget`].
type TableCache = Option<Box<SplatTable>>;

/// [`resample_latlong_into`], keeping the splat table of a fisheye or angular geometry in
/// `cache`.
fn resample_latlong_cached(
    frame: &HdrFrame,
    height: u32,
    out: &mut Vec<[f64; 3]>,
    cache: &mut TableCache,
) -> Result<(), AsgError> {
    let (sw, sh) = (frame.width, frame.height);
    if sw == 0 || sh == 0 || frame.pixels.len() != sw as usize * sh as usize {
        return Err(AsgError::PixelCount {
            width: sw,
            height: sh,
            len: frame.pixels.len(),
        });
    }
    if !(1..=4096).contains(&height) {
        return Err(AsgError::MapSize {
            width: height.saturating_mul(2),
            height,
        });
    }
    let (w, h) = (2 * height, height);
    out.clear();
    out.reserve(w as usize * h as usize);
    let exact = frame.projection == Projection::LatLong && sw % w == 0 && sh % h == 0;
    if exact {
        let (fx, fy) = (sw / w, sh / h);
        let (fx, fy, sw) = (fx as usize, fy as usize, sw as usize);
        let sines: Vec<f64> = (0..sh)
            .map(|sy| (PI * (f64::from(sy) + 0.5) / f64::from(sh)).sin())
            .collect();
        // Per output row, the fy source rows are added one after the other into a row of
        // sums: each pixel's sum takes its sub-samples in the same order as a per-pixel loop
        // (rows, then columns), and the weight sum is the same for the whole row.
        let mut sums = vec![[0.0f64; 3]; w as usize];
        for y in 0..h as usize {
            sums.fill([0.0; 3]);
            let mut wsum = 0.0;
            for sy in y * fy..(y + 1) * fy {
                let sin_t = sines[sy];
                wsum += sin_t * fx as f64;
                let row = &frame.pixels[sy * sw..(sy + 1) * sw];
                if fx == 1 {
                    for (acc, p) in sums.iter_mut().zip(row) {
                        for c in 0..3 {
                            acc[c] += clean(p[c]) * sin_t;
                        }
                    }
                    continue;
                }
                for (acc, px) in sums.iter_mut().zip(row.chunks_exact(fx)) {
                    for p in px {
                        for c in 0..3 {
                            acc[c] += clean(p[c]) * sin_t;
                        }
                    }
                }
            }
            out.extend(sums.iter().map(|acc| acc.map(|a| a / wsum)));
        }
        return Ok(());
    }
    if frame.projection == Projection::LatLong {
        latlong_by_overlap(frame, w, h, out);
        return Ok(());
    }
    // Another projection: bilinear splatting of sub-pixels with coverage normalisation
    // (src/asg/splat.rs). (Point samples, at most 8 × 8 per fit pixel, missed a one-pixel sun
    // or counted it several times over, by where it lay; each source pixel whole to the fit
    // pixel of its centre striped the map.)
    let table = match cache {
        Some(table) if table.fits(frame, height) => table,
        _ => cache.insert(Box::new(SplatTable::new(frame.projection, sw, sh, height))),
    };
    table.resample(frame, out);
    Ok(())
}

/// A lat-long frame of any size resampled to the `w × h` lat-long map by exact area overlap:
/// each fit pixel's radiance is the mean of the source pixels over it, each weighted by the
/// solid angle it shares with the fit pixel (separable: a longitude interval times a
/// latitude band, ∫ sin θ dθ). The map keeps the frame's integral, and a uniform frame stays
/// uniform. (Each source pixel whole to the fit pixel of its centre, as the decomposition's
/// index table does, striped the target where fit pixels hold a few source pixels: a uniform
/// 300 × 150 frame ranged 0.62 to 1.64 at 128 × 64; an audit.)
fn latlong_by_overlap(frame: &HdrFrame, w: u32, h: u32, out: &mut Vec<[f64; 3]>) {
    let (sw, sh) = (frame.width, frame.height);
    let columns = crate::envmap::interval_overlaps(sw, w);
    // Rows: the overlap of two bands in cos θ (the solid angle per radian of longitude).
    let band_edge = |k: u32, n: u32| (PI * f64::from(k) / f64::from(n)).cos();
    let rows: Vec<(usize, usize, f64)> = crate::envmap::interval_overlaps(sh, h)
        .into_iter()
        .map(|(sy, fy, _)| {
            let (sy32, fy32) = (sy as u32, fy as u32);
            let top = band_edge(sy32, sh).min(band_edge(fy32, h));
            let bottom = band_edge(sy32 + 1, sh).max(band_edge(fy32 + 1, h));
            (sy, fy, (top - bottom).max(0.0))
        })
        .collect();
    // Each fit pixel's sums are over its own share: 1/w of the turn times its band in cos θ.
    let own: Vec<f64> = (0..h)
        .map(|fy| (band_edge(fy, h) - band_edge(fy + 1, h)) / f64::from(w))
        .collect();
    let radiance = |s: &[f64; 3], own: f64| s.map(|v| if own > 0.0 { v / own } else { 0.0 });
    if sh >= h && sw as usize <= ROWS_FIRST_MAX_WIDTH {
        overlap_rows_first(frame, &columns, &rows, w as usize, |fy, sums| {
            out.extend(sums.iter().map(|s| radiance(s, own[fy])));
        });
    } else {
        let sums = overlap_columns_first(frame, &columns, &rows, w as usize, h as usize);
        for (row, &own) in sums.chunks_exact(w as usize).zip(&own) {
            out.extend(row.iter().map(|s| radiance(s, own)));
        }
    }
}

/// The widest frame [`latlong_by_overlap`] resamples rows first (its row of sums is 24 bytes
/// per source column).
const ROWS_FIRST_MAX_WIDTH: usize = 1 << 16;

/// Area overlap when each fit row holds at least one source row: the source rows over a fit
/// row's band, each weighted by the band it shares, are added into one row of sums per source
/// column (contiguous, so it vectorises), then that row's columns by their longitude
/// overlaps, and `emit` gets each fit row's sums in order. The row pairs come in order of fit
/// row, and every fit row has at least one. (11.7 ms from 2000 × 1000 to 512 × 256 against
/// 18.1 ms columns first.)
fn overlap_rows_first(
    frame: &HdrFrame,
    columns: &[(usize, usize, f64)],
    rows: &[(usize, usize, f64)],
    w: usize,
    mut emit: impl FnMut(usize, &[[f64; 3]]),
) {
    let sw = frame.width as usize;
    let mut band = vec![[0.0f64; 3]; sw];
    let mut sums = vec![[0.0f64; 3]; w];
    let mut flush = |fy: usize, band: &mut [[f64; 3]]| {
        sums.fill([0.0; 3]);
        for &(sx, fx, share) in columns {
            for c in 0..3 {
                sums[fx][c] += band[sx][c] * share;
            }
        }
        band.fill([0.0; 3]);
        emit(fy, &sums);
    };
    let mut current = 0usize;
    for &(sy, fy, weight) in rows {
        if fy != current {
            flush(current, &mut band);
            current = fy;
        }
        let row: &[f32] = bytemuck::cast_slice(&frame.pixels[sy * sw..(sy + 1) * sw]);
        let flat: &mut [f64] = bytemuck::cast_slice_mut(&mut band);
        for (acc, &p) in flat.iter_mut().zip(row) {
            *acc += clean(p) * weight;
        }
    }
    flush(current, &mut band);
}

/// Area overlap when source rows are fewer than fit rows, or too wide to be held as a row of
/// sums: each source row's columns are squeezed to the fit width once, by their longitude
/// overlaps, and added into every fit row it overlaps, weighted by the band they share. Rows
/// first re-read a whole source row for every fit row over it: a 4,000,000 × 1 frame took
/// 11.6 s at height 256 (an audit). Returns the `w × h` sums.
fn overlap_columns_first(
    frame: &HdrFrame,
    columns: &[(usize, usize, f64)],
    rows: &[(usize, usize, f64)],
    w: usize,
    h: usize,
) -> Vec<[f64; 3]> {
    let sw = frame.width as usize;
    let mut sums = vec![[0.0f64; 3]; w * h];
    let mut squeezed = vec![[0.0f64; 3]; w];
    let mut last_row = usize::MAX;
    for &(sy, fy, weight) in rows {
        if sy != last_row {
            squeezed.fill([0.0; 3]);
            let row = &frame.pixels[sy * sw..(sy + 1) * sw];
            for &(sx, fx, share) in columns {
                for c in 0..3 {
                    squeezed[fx][c] += clean(row[sx][c]) * share;
                }
            }
            last_row = sy;
        }
        for (sum, s) in sums[fy * w..(fy + 1) * w].iter_mut().zip(&squeezed) {
            for c in 0..3 {
                sum[c] += s[c] * weight;
            }
        }
    }
    sums
}

/// D_GT at the normal blocks from the cells with energy (module doc, step 3).
#[inline(always)]
fn diffuse_sums(blocks: &[[[f64; NORMAL_LANES]; 3]], cells: &[[f64; 6]], out: &mut [[f64; 3]]) {
    for (nb, out) in blocks.iter().zip(out.chunks_mut(NORMAL_LANES)) {
        let (nx, ny, nz) = (&nb[0], &nb[1], &nb[2]);
        let mut r = [0.0f64; NORMAL_LANES];
        let mut g = [0.0f64; NORMAL_LANES];
        let mut b = [0.0f64; NORMAL_LANES];
        for cell in cells {
            let (dx, dy, dz, e0, e1, e2) = (cell[0], cell[1], cell[2], cell[3], cell[4], cell[5]);
            for l in 0..NORMAL_LANES {
                // n·d as `DVec3::dot` computes it; max(·, 0) without a branch. Energies are
                // finite and ≥ 0, so a clamped 0 adds exactly nothing.
                let t = nx[l] * dx + ny[l] * dy + nz[l] * dz;
                let t = if t > 0.0 { t } else { 0.0 };
                r[l] += e0 * t;
                g[l] += e1 * t;
                b[l] += e2 * t;
            }
        }
        for (l, o) in out.iter_mut().enumerate() {
            *o = [r[l], g[l], b[l]];
        }
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
fn diffuse_sums_avx2(
    blocks: &[[[f64; NORMAL_LANES]; 3]],
    cells: &[[f64; 6]],
    out: &mut [[f64; 3]],
) {
    diffuse_sums(blocks, cells, out);
}

fn diffuse_sums_dispatch(
    blocks: &[[[f64; NORMAL_LANES]; 3]],
    cells: &[[f64; 6]],
    out: &mut [[f64; 3]],
) {
    #[cfg(target_arch = "x86_64")]
    {
        if std::arch::is_x86_feature_detected!("avx2") {
            // SAFETY: the CPU supports AVX2 (checked just above).
            unsafe { diffuse_sums_avx2(blocks, cells, out) };
            return;
        }
    }
    diffuse_sums(blocks, cells, out);
}

impl FitTarget {
    /// The target of `frame` at fit-map height `height` with `normals` diffuse normals.
    pub fn from_frame(frame: &HdrFrame, height: u32, normals: usize) -> Result<Self, AsgError> {
        let mut radiance = Vec::new();
        let mut table = None;
        resample_latlong_cached(frame, height, &mut radiance, &mut table)?;
        let mut target = Self::from_latlong(2 * height, height, radiance, normals)?;
        target.table = table;
        Ok(target)
    }

    /// The target of a `width × height` lat-long radiance map (width = 2 × height).
    pub fn from_latlong(
        width: u32,
        height: u32,
        radiance: Vec<[f64; 3]>,
        normals: usize,
    ) -> Result<Self, AsgError> {
        if height < 1 || width != 2 * height {
            return Err(AsgError::MapSize { width, height });
        }
        if radiance.len() != width as usize * height as usize {
            return Err(AsgError::PixelCount {
                width,
                height,
                len: radiance.len(),
            });
        }
        let mut radiance = radiance;
        for p in &mut radiance {
            *p = p.map(|c| if c.is_finite() && c > 0.0 { c } else { 0.0 });
        }
        let omegas = Projection::LatLong.solid_angles(width, height);
        let weights: Vec<f64> = omegas.iter().map(|o| o / (4.0 * PI)).collect();
        // Pixel centres as `Projection::LatLong.pixel_to_direction` gives them (the same
        // arithmetic, with the sines and cosines of each row and column computed once).
        let rows: Vec<(f64, f64)> = (0..height)
            .map(|y| (PI * (f64::from(y) + 0.5) / f64::from(height)).sin_cos())
            .collect();
        let cols: Vec<(f64, f64)> = (0..width)
            .map(|x| (2.0 * PI * (f64::from(x) + 0.5) / f64::from(width)).sin_cos())
            .collect();
        let mut directions = Vec::with_capacity(radiance.len());
        for &(sin_t, cos_t) in &rows {
            for &(sin_p, cos_p) in &cols {
                directions.push(DVec3::new(sin_t * sin_p, cos_t, -sin_t * cos_p));
            }
        }
        let normals = fibonacci_sphere(normals);
        let geometry = Geometry::new(width, height, &directions, omegas, &normals);
        let mut target = Self {
            width,
            height,
            directions,
            radiance,
            weights,
            diffuse: Vec::new(),
            normals,
            mean: 0.0,
            integral: [0.0; 3],
            tiled: std::sync::OnceLock::new(),
            geometry: Arc::new(geometry),
            energy: Vec::new(),
            cells: Vec::new(),
            table: None,
        };
        target.update();
        Ok(target)
    }

    /// Makes this target the target of `frame` (module doc, step 4): resamples it into the
    /// radiance buffer and recomputes the integral, the mean, the diffuse ground truth and the
    /// tiles' radiance, reusing everything that depends only on the size. The result equals
    /// `FitTarget::from_frame(frame, self.height, self.normals.len())`. On error the target is
    /// unchanged.
    pub fn refill(&mut self, frame: &HdrFrame) -> Result<(), AsgError> {
        // The resampled radiance is finite and ≥ 0 already: no cleaning pass.
        resample_latlong_cached(frame, self.height, &mut self.radiance, &mut self.table)?;
        self.update();
        Ok(())
    }

    /// Steps 2 and 3 of the module doc from `self.radiance` (finite and ≥ 0), and the tiles'
    /// radiance if they were made.
    fn update(&mut self) {
        let g = &*self.geometry;
        // One pass: the integral and the coarse copy's per-cell sums of radiance × solid
        // angle, pixels in row-major order.
        let mut integral = [0.0; 3];
        self.energy.clear();
        self.energy.resize(g.cell_directions.len(), [0.0; 3]);
        let w = self.width as usize;
        let factor = g.factor as usize;
        for (y, (row, orow)) in self
            .radiance
            .chunks_exact(w)
            .zip(g.omegas.chunks_exact(w))
            .enumerate()
        {
            let base = y / factor * g.cells_wide as usize;
            let cells = &mut self.energy[base..];
            for (x, (p, o)) in row.iter().zip(orow).enumerate() {
                let cell = &mut cells[x / factor];
                for c in 0..3 {
                    let e = p[c] * o;
                    integral[c] += e;
                    cell[c] += e;
                }
            }
        }
        self.integral = integral;
        self.mean = integral.iter().sum::<f64>() / (4.0 * PI);
        // Cells without energy add nothing: left out.
        self.cells.clear();
        self.cells.extend(
            g.cell_directions
                .iter()
                .zip(&self.energy)
                .filter(|(_, e)| e.iter().any(|&c| c > 0.0))
                .map(|(d, e)| [d.x, d.y, d.z, e[0], e[1], e[2]]),
        );
        self.diffuse.clear();
        self.diffuse.resize(self.normals.len(), [0.0; 3]);
        diffuse_sums_dispatch(&g.normal_blocks, &self.cells, &mut self.diffuse);
        let (radiance, mean) = (&self.radiance, self.mean);
        if let Some(px) = self.tiled.get_mut() {
            px.refill(radiance, mean);
        }
    }

    /// The pixels tiled for the fast kernel ([`super::fast`]).
    pub fn tiled(&self) -> &Pixels {
        self.tiled.get_or_init(|| Pixels::new(self))
    }

    /// This target at half the resolution (`height / 2`, at least 2): 2×2 pixels averaged
    /// with their solid angles; the diffuse ground truth, mean and integral are kept (they
    /// describe the same frame). `None` when the height is odd or below 4.
    pub fn half(&self) -> Option<Self> {
        if self.height < 4 || !self.height.is_multiple_of(2) {
            return None;
        }
        let (w, h) = (self.width / 2, self.height / 2);
        let mut radiance = vec![[0.0; 3]; (w * h) as usize];
        let mut weights = vec![0.0; (w * h) as usize];
        let mut directions = vec![DVec3::ZERO; (w * h) as usize];
        for y in 0..self.height {
            for x in 0..self.width {
                let i = (y * self.width + x) as usize;
                let o = ((y / 2) * w + x / 2) as usize;
                let wt = self.weights[i];
                weights[o] += wt;
                directions[o] += self.directions[i] * wt;
                for c in 0..3 {
                    radiance[o][c] += self.radiance[i][c] * wt;
                }
            }
        }
        for ((r, d), wt) in radiance.iter_mut().zip(directions.iter_mut()).zip(&weights) {
            if *wt > 0.0 {
                *r = r.map(|v| v / wt);
            }
            *d = d.normalize_or(DVec3::Y);
        }
        // The half map's own geometry, so a refill of it stays consistent.
        let omegas = weights.iter().map(|wt| wt * (4.0 * PI)).collect();
        let geometry = Geometry::new(w, h, &directions, omegas, &self.normals);
        Some(Self {
            width: w,
            height: h,
            directions,
            radiance,
            weights,
            normals: self.normals.clone(),
            diffuse: self.diffuse.clone(),
            mean: self.mean,
            integral: self.integral,
            tiled: std::sync::OnceLock::new(),
            geometry: Arc::new(geometry),
            energy: Vec::new(),
            cells: Vec::new(),
            table: None,
        })
    }

    /// Largest bandwidth a fit on this map may use: λ ≤ 1/(2Δθ²) with Δθ = π/height, so a lobe's
    /// standard deviation is at least one pixel. Narrower lobes would be fitted through the
    /// pixel centres alone, whose values say nothing of the lobe's integral (a sun fitted as a
    /// needle at one pixel centre keeps its peak but loses most of its energy).
    pub fn max_bandwidth(&self) -> f64 {
        let dt = PI / f64::from(self.height);
        (0.5 / (dt * dt)).clamp(4.0 * MIN_BANDWIDTH, MAX_BANDWIDTH)
    }

    /// Map reconstructed from `lobes` at this target's pixels.
    pub fn reconstruct(&self, lobes: &[Asg]) -> Vec<[f64; 3]> {
        self.directions
            .iter()
            .map(|&d| {
                let mut acc = [0.0; 3];
                for l in lobes {
                    let g = l.shape(d);
                    for c in 0..3 {
                        acc[c] += l.rgb[c] * g;
                    }
                }
                acc
            })
            .collect()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The two orders of the area-overlap resampling give the same map (to rounding) on a
    /// frame of varied values, downsampled and upsampled.
    #[test]
    fn rows_first_and_columns_first_agree() {
        for (sw, sh, h) in [(300u32, 150u32, 64u32), (1000, 500, 37), (77, 40, 16)] {
            let pixels: Vec<[f32; 3]> = (0..sw * sh)
                .map(|i| {
                    let v = ((i.wrapping_mul(2_654_435_761) >> 7) % 1000) as f32 / 100.0;
                    [v, 0.5 * v + 1.0, (i % 7) as f32]
                })
                .collect();
            let frame = HdrFrame::new(sw, sh, pixels, Projection::LatLong).unwrap();
            let w = 2 * h;
            let columns = crate::envmap::interval_overlaps(sw, w);
            // Rows weighted by their share of the latitude range (the orders do not care).
            let rows = crate::envmap::interval_overlaps(sh, h);
            let mut by_rows = Vec::new();
            overlap_rows_first(&frame, &columns, &rows, w as usize, |_, s| {
                by_rows.extend_from_slice(s)
            });
            let by_columns = overlap_columns_first(&frame, &columns, &rows, w as usize, h as usize);
            assert_eq!(by_rows.len(), by_columns.len());
            for (a, b) in by_rows.iter().zip(&by_columns) {
                for c in 0..3 {
                    assert!(
                        (a[c] - b[c]).abs() <= 1e-12 * a[c].abs().max(1e-3),
                        "{a:?} {b:?}"
                    );
                }
            }
        }
    }
}
