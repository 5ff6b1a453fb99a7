//! Resampling a fisheye or angular frame to the ASG fit's lat-long map by bilinear splatting
//! with coverage normalisation.
//!
//! Binning each source pixel whole into the fit pixel of its centre (the decomposition's index
//! table) striped the target where a fit pixel holds a few source pixels: a uniform 1001 × 1001
//! angular frame ranged 0 to 54.5 at height 256, and the fit spent most of its lobes on the
//! stripes as needles at the bandwidth cap (an audit). Here, once per frame geometry
//! ([`SplatTable::new`]):
//! 1. the frame is read in square blocks of b × b pixels, b the largest (≤ [`MAX_BLOCK`]) that
//!    keeps a block of the pixels' mean solid angle within half a fit pixel's side at the
//!    equator (4 for a 2048 × 2048 fisheye at height 256), so the splats are few; a block's
//!    solid angle is its pixels' exact solid angles summed;
//! 2. each block that sees a direction is cut into n × n sub-blocks, n chosen so that a
//!    sub-block's side is at most half the fit pixel's narrower side at its latitude (the
//!    parallel's, at least the pole row's; 1 ≤ n ≤ [`MAX_SPLIT`]), and the block's solid angle
//!    is shared among its sub-blocks whose centres see a direction;
//! 3. each sub-block's centre lands at a continuous position of the fit map and is split among
//!    the four nearest fit-pixel centres with bilinear weights (longitude wraps; within
//!    [`POLE_BAND`] rows of a pole, between the two nearest columns of the row it lands in): a
//!    partition of unity, so no energy is lost or made;
//! 4. the coverage C_p of every fit pixel is the solid angle splatted into it.
//!
//! Per frame ([`SplatTable::resample`]) each block's energy Σ L·Ω is summed over its pixels in
//! one pass over the frame and splatted the same way, and a fit pixel's radiance is E_p / C_p:
//! a uniform frame comes out uniform (to f32 rounding), and the tent weights keep C_p close to
//! the pixel's solid angle, so a one-pixel sun keeps its energy to a few per cent (0.980 to
//! 1.007 where `tests/asg.rs` tries; it moves by at most half a block, a quarter of a fit
//! pixel). A fit pixel nothing reaches takes
//! the radiance of the source pixel seen at its centre, or is 0 where none is (a fisheye's
//! unseen lower hemisphere).

use crate::envmap::Projection;
use crate::frame::HdrFrame;
use std::f64::consts::PI;

/// What a block gives the four fit pixels around where its sub-blocks land: the sub-blocks of
/// one block that land between the same four fit-pixel centres are one splat (their weights
/// summed; near a pole a block has hundreds of sub-blocks and a few splats).
#[derive(Clone, Copy, Debug)]
struct Splat {
    /// Block, row-major.
    block: u32,
    /// Fit column and row of the upper-left of the four fit-pixel centres (the row may be −1
    /// above the first centre, the column wraps).
    x0: u32,
    y0: i32,
    /// Solid angle (steradians) given to (x0, y0), (x0 + 1, y0), (x0, y0 + 1), (x0 + 1,
    /// y0 + 1): the sub-blocks' solid angles times their bilinear weights.
    omegas: [f32; 4],
}

/// The splats of one frame geometry, and the coverage of every fit pixel (module doc).
#[derive(Clone, Debug)]
pub(crate) struct SplatTable {
    projection: Projection,
    source_width: u32,
    source_height: u32,
    width: u32,
    height: u32,
    /// Block side in pixels, and blocks per row.
    block: u32,
    blocks_wide: u32,
    /// Exact solid angle of every source pixel (0 where it sees nothing).
    pixel_omegas: Vec<f32>,
    splats: Vec<Splat>,
    /// 1 / C_p, or 0 where nothing lands.
    inverse_coverage: Vec<f64>,
    /// Fit pixels nothing lands in although the frame sees their centre (source pixels far
    /// larger than fit pixels near a pole, past [`MAX_SPLIT`]), with the source pixel seen
    /// there: they take its radiance.
    point_samples: Vec<(u32, u32)>,
    /// 1 / the solid angle of every block (0 where it sees nothing).
    inverse_block_omega: Vec<f64>,
    /// Per frame: the blocks' energies, then their mean radiance.
    block_energy: Vec<[f64; 3]>,
}

/// Rows from a pole (to the centre of the third row) where a sub-block goes to the row it lands
/// in, not shared with the next by a tent: there the rows' solid angles grow with each row
/// (∝ 2k + 1), so a tent gave the pole row about 11 % more coverage than its solid angle (a
/// sun at the zenith lost 10 % of its energy), while the sub-blocks are small against the rows
/// (their size follows the narrow parallel), so taking the row of each does not alias.
const POLE_BAND: f64 = 2.5;

/// The largest block side (pixels).
const MAX_BLOCK: u32 = 16;

/// The most sub-blocks a side of a block is cut into. (Near a pole they are many, but few
/// blocks are near a pole.)
const MAX_SPLIT: u32 = 128;

/// Adds to `splats` the sub-blocks of `block` that land at `landings` (continuous positions in
/// the `2·height × height` fit map), each of solid angle `share`: its bilinear weights (module
/// doc, step 3), summed into one splat per four fit-pixel centres.
fn add_splats(
    splats: &mut Vec<Splat>,
    block: u32,
    landings: &[(f64, f64)],
    share: f64,
    height: u32,
) {
    let (width, rows) = (2 * i64::from(height), f64::from(height));
    let first = splats.len();
    for &(u, v) in landings {
        let fx = (u - 0.5).floor();
        let tx = u - 0.5 - fx;
        // Near a pole, the row of the landing point itself.
        let (y0, ty) = if v < POLE_BAND || v > rows - POLE_BAND {
            ((v.floor() as i32).clamp(0, height as i32 - 1), 0.0)
        } else {
            let fy = (v - 0.5).floor();
            (fy as i32, v - 0.5 - fy)
        };
        let x0 = (fx as i64).rem_euclid(width) as u32;
        let weights = [
            (1.0 - tx) * (1.0 - ty),
            tx * (1.0 - ty),
            (1.0 - tx) * ty,
            tx * ty,
        ];
        let index = match splats[first..]
            .iter()
            .position(|s| s.x0 == x0 && s.y0 == y0)
        {
            Some(at) => first + at,
            None => {
                splats.push(Splat {
                    block,
                    x0,
                    y0,
                    omegas: [0.0; 4],
                });
                splats.len() - 1
            }
        };
        for (o, w) in splats[index].omegas.iter_mut().zip(weights) {
            *o += (w * share) as f32;
        }
    }
}

impl SplatTable {
    /// The table of `projection` frames of `source_width × source_height` pixels for a
    /// `2·height × height` fit map.
    pub(crate) fn new(
        projection: Projection,
        source_width: u32,
        source_height: u32,
        height: u32,
    ) -> Self {
        let width = 2 * height;
        let omegas = projection.solid_angles(source_width, source_height);
        // A fit pixel's side (radians) along the meridian; along the parallel it is that
        // times sin θ.
        let fit_side = PI / f64::from(height);
        let pole_sin = (0.5 * PI / f64::from(height)).sin();
        let seen = omegas.iter().filter(|&&o| o > 0.0).count().max(1);
        let mean_side = (omegas.iter().sum::<f64>() / seen as f64).sqrt();
        let block = ((0.5 * fit_side / mean_side).floor() as u32).clamp(1, MAX_BLOCK);
        let blocks_wide = source_width.div_ceil(block);
        let blocks_high = source_height.div_ceil(block);
        let mut splats = Vec::new();
        let mut subs = Vec::new();
        let mut inverse_block_omega = vec![0.0; (blocks_wide * blocks_high) as usize];
        for by in 0..blocks_high {
            for bx in 0..blocks_wide {
                let (x0, y0) = (bx * block, by * block);
                let (x1, y1) = (
                    (x0 + block).min(source_width),
                    (y0 + block).min(source_height),
                );
                // Summed as the frames' energies are (f32 along a block row, f64 across rows),
                // so that a uniform block's mean radiance is its pixels' to f32 rounding.
                let omega: f64 = (y0..y1)
                    .map(|y| {
                        let row = (y * source_width) as usize;
                        let sum: f32 = (x0..x1).map(|x| omegas[row + x as usize] as f32).sum();
                        f64::from(sum)
                    })
                    .sum();
                if omega <= 0.0 || omega.is_nan() {
                    continue;
                }
                inverse_block_omega[(by * blocks_wide + bx) as usize] = 1.0 / omega;
                let (bw, bh) = (f64::from(x1 - x0), f64::from(y1 - y0));
                let centre = projection.pixel_to_direction(
                    source_width,
                    source_height,
                    f64::from(x0) + 0.5 * bw,
                    f64::from(y0) + 0.5 * bh,
                );
                // Sub-blocks at most half the fit pixel's narrower side at this latitude
                // (along the parallel, at least the pole row's): where blocks are wider than
                // fit columns near a pole, whole blocks would alias the coverage. A block
                // whose centre sees nothing (on a fisheye's rim) is cut into its pixels.
                let split = match centre {
                    Some(c) => {
                        let sin_theta = (1.0 - c.y * c.y).max(0.0).sqrt();
                        let narrow_side = fit_side * sin_theta.max(pole_sin);
                        (2.0 * omega.sqrt() / narrow_side)
                            .ceil()
                            .clamp(1.0, f64::from(MAX_SPLIT)) as u32
                    }
                    None => block,
                };
                subs.clear();
                for j in 0..split {
                    for i in 0..split {
                        let sx = f64::from(x0) + (f64::from(i) + 0.5) / f64::from(split) * bw;
                        let sy = f64::from(y0) + (f64::from(j) + 0.5) / f64::from(split) * bh;
                        let landing = projection
                            .pixel_to_direction(source_width, source_height, sx, sy)
                            .and_then(|d| Projection::LatLong.direction_to_pixel(width, height, d));
                        if let Some(at) = landing {
                            subs.push(at);
                        }
                    }
                }
                if subs.is_empty() {
                    continue;
                }
                let share = omega / subs.len() as f64;
                add_splats(&mut splats, by * blocks_wide + bx, &subs, share, height);
            }
        }
        // (In block order, so the per-frame pass reads the blocks in turn; sorting them by
        // landing row measured no faster: 15.6 ms against 14.2 ms per refill.)
        let mut table = SplatTable {
            projection,
            source_width,
            source_height,
            width,
            height,
            block,
            blocks_wide,
            pixel_omegas: omegas.iter().map(|&o| o as f32).collect(),
            splats,
            inverse_coverage: Vec::new(),
            point_samples: Vec::new(),
            inverse_block_omega,
            block_energy: vec![[0.0; 3]; (blocks_wide * blocks_high) as usize],
        };
        let mut coverage = vec![0.0f64; width as usize * height as usize];
        table.for_each_target(|_, target, omega| coverage[target] += omega);
        table.inverse_coverage = coverage
            .iter()
            .map(|&c| if c > 0.0 { 1.0 / c } else { 0.0 })
            .collect();
        for (p, _) in coverage.iter().enumerate().filter(|(_, &c)| c <= 0.0) {
            let (x, y) = ((p % width as usize) as f64, (p / width as usize) as f64);
            let direction = Projection::LatLong.pixel_to_direction(width, height, x + 0.5, y + 0.5);
            let seen = direction
                .and_then(|d| projection.direction_to_pixel(source_width, source_height, d));
            if let Some((sx, sy)) = seen {
                let sx = (sx.floor().max(0.0) as u32).min(source_width - 1);
                let sy = (sy.floor().max(0.0) as u32).min(source_height - 1);
                let source = sy * source_width + sx;
                if omegas[source as usize] > 0.0 {
                    table.point_samples.push((p as u32, source));
                }
            }
        }
        table
    }

    /// Whether `frame` has this table's geometry.
    pub(crate) fn fits(&self, frame: &HdrFrame, height: u32) -> bool {
        self.projection == frame.projection
            && self.source_width == frame.width
            && self.source_height == frame.height
            && self.height == height
    }

    /// Calls `f(block, fit pixel, solid angle)` for each of the four fit pixels of every
    /// splat.
    fn for_each_target(&self, mut f: impl FnMut(usize, usize, f64)) {
        let (w, h) = (self.width as usize, self.height as i32);
        for splat in &self.splats {
            let x1 = (splat.x0 as usize + 1) % w;
            // Rows above the first centre or below the last fold onto the pole rows.
            let row = |y: i32| y.clamp(0, h - 1) as usize * w;
            let (r0, r1) = (row(splat.y0), row(splat.y0 + 1));
            let block = splat.block as usize;
            let [a, b, c, d] = splat.omegas.map(f64::from);
            f(block, r0 + splat.x0 as usize, a);
            f(block, r0 + x1, b);
            f(block, r1 + splat.x0 as usize, c);
            f(block, r1 + x1, d);
        }
    }

    /// Appends the fit map's radiance for `frame` (of this table's geometry) to `out`
    /// (module doc). Non-finite and negative values count as 0.
    pub(crate) fn resample(&mut self, frame: &HdrFrame, out: &mut Vec<[f64; 3]>) {
        use super::target::{clean, clean_f32};
        // The blocks' energies, one pass over the frame's rows.
        let (sw, block) = (self.source_width as usize, self.block as usize);
        self.block_energy.fill([0.0; 3]);
        for (y, (row, omegas)) in frame
            .pixels
            .chunks_exact(sw)
            .zip(self.pixel_omegas.chunks_exact(sw))
            .enumerate()
        {
            let blocks = &mut self.block_energy[(y / block) * self.blocks_wide as usize..];
            for ((pixels, omegas), e) in row
                .chunks(block)
                .zip(omegas.chunks(block))
                .zip(blocks.iter_mut())
            {
                // A block row's few pixels summed in f32 (a relative error of about 10⁻⁷ of
                // their sum), then added to the block in f64. Unseen pixels have ω = 0 and
                // clean values, so they add 0.
                let mut sum = [0.0f32; 3];
                for (p, &omega) in pixels.iter().zip(omegas) {
                    for c in 0..3 {
                        sum[c] += clean_f32(p[c]) * omega;
                    }
                }
                for c in 0..3 {
                    e[c] += f64::from(sum[c]);
                }
            }
        }
        // A sub-block carries its share of the block's energy, ω_sub / Ω_block: the block's
        // mean radiance times ω_sub.
        for (e, inverse) in self.block_energy.iter_mut().zip(&self.inverse_block_omega) {
            *e = e.map(|v| v * inverse);
        }
        let start = out.len();
        out.resize(start + self.inverse_coverage.len(), [0.0; 3]);
        let energy = &mut out[start..];
        let block_energy = &self.block_energy;
        self.for_each_target(|block, target, omega| {
            let e = block_energy[block];
            for c in 0..3 {
                energy[target][c] += e[c] * omega;
            }
        });
        for (e, inverse) in energy.iter_mut().zip(&self.inverse_coverage) {
            *e = e.map(|v| v * inverse);
        }
        for &(target, source) in &self.point_samples {
            let p = frame.pixels[source as usize];
            energy[target as usize] = p.map(clean);
        }
    }
}
