//! Two refinements of the lights' sample directions before the regions are drawn.
//!
//! **Fine warp inside concentrated sources.** The warp works on the working map, so a point
//! that lands in a concentrated working pixel (a sun, a lamp) would sit anywhere in it with
//! equal density, and the lights sharing the source would split its input pixels along
//! arbitrary Voronoi borders. Instead the point's position inside the working pixel is warped
//! once more, by [`PiecewiseConstant2d`] over the pixel's k×k input pixels weighted by their
//! luminance energy (density ∝ energy, as median cut divides a source). So the lights that
//! share a source sit on its bright input pixels and split it along them. The inner warp maps
//! the pixel's edges onto themselves; where a concentrated pixel borders an ordinary one a point
//! on the shared edge can slide along it by at most one working pixel. Only on the box-filter
//! path (lat-long input whose size is a multiple of the working size), where a working pixel's
//! input pixels form a grid.
//!
//! **One Lloyd step on a coarse map** (the [`super::LightPlacement::Centroid`] placement only).
//! Lloyd's algorithm moves each site to the centroid of its Voronoi region and redraws the
//! regions; its fixed point, a centroidal Voronoi tessellation, is what a light at its region's
//! centroid wants: compact regions around their lights (Du, Faber and Gunzburger 1999,
//! "Centroidal Voronoi tessellations"). One step, computed on the working map box-summed by 4
//! (64×32 for the default 256-wide map) plus the full-resolution input pixels of concentrated
//! sources, costs a sixteenth of the region pass and measured almost all of a full step's gain
//! (docs/quality.md). Steps: (1) the coarse map: each coarse pixel sums the energy of the
//! ordinary working pixels it covers and sits at their luminance centroid; concentrated working
//! pixels are left out and their fine samples are carried over; (2) every coarse pixel and fine
//! sample goes to its nearest site (the nearest-light search of [`super::regions`]); (3) each
//! site moves to its region's luminance-weighted centroid (a site whose region is black stays).
//! Centroids move continuously with the map and the sites, so the step keeps the warp
//! continuous.

use super::regions::{self, BucketGrid};
use super::working_map::{FineSample, WorkingMap};
use super::{PiecewiseConstant2d, Region};
use crate::envmap::Projection;
use glam::DVec3;

/// Coarsening factor of the Lloyd step's map (the largest of 4, 2, 1 that divides both sides).
const COARSE_FACTOR: usize = 4;

/// Maps `p` (in working-pixel units, x ∈ [0, W], y ∈ [0, H]) through the fine warp of its
/// working pixel when that pixel is concentrated and its input pixels form a grid; returns the
/// (possibly) moved position. `scratch` holds the inner distribution between calls.
pub(super) fn fine_warp(
    map: &WorkingMap,
    p: [f64; 2],
    weights: &mut Vec<f64>,
    dist: &mut Option<PiecewiseConstant2d>,
) -> [f64; 2] {
    let k = map.fine_grid;
    if k < 2 || map.fine.is_empty() {
        return p;
    }
    let ix = (p[0].max(0.0) as usize).min(map.width - 1);
    let iy = (p[1].max(0.0) as usize).min(map.height - 1);
    let idx = iy * map.width + ix;
    if !map.concentrated[idx] {
        return p;
    }
    let cells = map.fine_of(idx);
    if cells.len() != k * k {
        return p;
    }
    weights.clear();
    weights.extend(
        cells
            .iter()
            .map(|s| f64::from(crate::frame::luminance(s.energy))),
    );
    let dist = dist.get_or_insert_with(|| PiecewiseConstant2d::new(&[0.0], 1, 1));
    dist.rebuild(weights, k, k);
    if dist.total() <= 0.0 {
        return p;
    }
    let frac = [
        (p[0] - ix as f64).clamp(0.0, 1.0),
        (p[1] - iy as f64).clamp(0.0, 1.0),
    ];
    let q = dist.sample(frac).0;
    [ix as f64 + q[0], iy as f64 + q[1]]
}

/// The coarse map of the Lloyd step and its buffers, kept between frames of one geometry.
#[derive(Default)]
pub(super) struct Relax {
    /// (working width, working height) the coarse map was made for, and the factor.
    made_for: Option<(usize, usize, usize)>,
    coarse: Option<WorkingMap>,
    grid: Option<BucketGrid>,
    scratch: regions::Scratch,
    regions: Vec<Region>,
    sums: CoarseSums,
}

impl Relax {
    /// Moves every direction in `dirs` (the sites) to the luminance-weighted centroid of its
    /// Voronoi region on the coarse map of `map`; see the module docs.
    pub(super) fn step(&mut self, arch: pulp::Arch, map: &WorkingMap, dirs: &mut [DVec3]) {
        let (w, h) = (map.width, map.height);
        let factor = [COARSE_FACTOR, 2, 1]
            .into_iter()
            .find(|k| w % k == 0 && h % k == 0)
            .unwrap_or(1);
        if self.made_for != Some((w, h, factor)) {
            let coarse = WorkingMap::blank(w / factor, h / factor);
            self.grid = Some(BucketGrid::new(&coarse));
            self.coarse = Some(coarse);
            self.made_for = Some((w, h, factor));
        }
        let (Some(coarse), Some(grid)) = (self.coarse.as_mut(), self.grid.as_ref()) else {
            unreachable!("set above")
        };
        coarsen(map, factor, coarse, &mut self.sums);
        self.regions.clear();
        self.regions.resize(dirs.len(), Region::default());
        arch.dispatch(regions::Accumulate {
            map: coarse,
            grid,
            sample_dirs: dirs,
            regions: &mut self.regions,
            scratch: &mut self.scratch,
        });
        for (dir, region) in dirs.iter_mut().zip(&self.regions) {
            if let Some(centroid) = DVec3::from(region.weighted_dir).try_normalize() {
                *dir = centroid;
            }
        }
    }
}

/// Per coarse pixel: Σ energy and Σ luminance × direction of the ordinary working pixels it
/// covers (buffers reused between frames).
#[derive(Default)]
struct CoarseSums {
    energy: Vec<[f64; 3]>,
    moment: Vec<[f64; 3]>,
}

/// Box-sums the ordinary (not concentrated) working pixels of `map` by `factor` into `coarse`:
/// every coarse pixel with energy becomes one sample at its luminance centroid (as the
/// yardsticks' reference map places its coarse pixels; assigning it from its centre measured
/// worse), and the fine samples of concentrated working pixels are carried over, re-indexed to
/// the coarse pixels. The coarse pixels themselves stay black.
fn coarsen(map: &WorkingMap, factor: usize, coarse: &mut WorkingMap, sums: &mut CoarseSums) {
    let (w, cw) = (map.width, coarse.width);
    let cells = coarse.width * coarse.height;
    sums.energy.clear();
    sums.energy.resize(cells, [0.0; 3]);
    sums.moment.clear();
    sums.moment.resize(cells, [0.0; 3]);
    for (y, (row, flags)) in map
        .energy
        .chunks_exact(w)
        .zip(map.concentrated.chunks_exact(w))
        .enumerate()
    {
        let (sin_t, cos_t) = map.row_trig_f64[y];
        let out = (y / factor) * cw..(y / factor + 1) * cw;
        let blocks = row
            .chunks_exact(factor)
            .zip(flags.chunks_exact(factor))
            .zip(map.column_trig_f64.chunks_exact(factor));
        for (((block, block_flags), trig), (energy, moment)) in blocks.zip(
            sums.energy[out.clone()]
                .iter_mut()
                .zip(&mut sums.moment[out]),
        ) {
            // Σ lum·sin φ, Σ lum, Σ lum·cos φ over the block's pixels in this row.
            let mut m = [0.0f64; 3];
            for ((e, &concentrated), &(sin_p, cos_p)) in block.iter().zip(block_flags).zip(trig) {
                if concentrated {
                    continue;
                }
                let lum = super::luminance_f64(*e);
                m[0] += lum * sin_p;
                m[1] += lum;
                m[2] += lum * cos_p;
                energy[0] += e[0];
                energy[1] += e[1];
                energy[2] += e[2];
            }
            moment[0] += sin_t * m[0];
            moment[1] += cos_t * m[1];
            moment[2] -= sin_t * m[2];
        }
    }
    coarse.fine.clear();
    for (idx, (energy, moment)) in sums.energy.iter().zip(&sums.moment).enumerate() {
        let Some(dir) = DVec3::from(*moment).try_normalize() else {
            continue;
        };
        coarse.fine.push(FineSample {
            pixel: idx as u32,
            dir: dir.as_vec3().to_array(),
            energy: energy.map(|c| c as f32),
            solid_angle: 0.0,
        });
    }
    coarse.fine.extend(map.fine.iter().map(|s| {
        let (x, y) = (s.pixel as usize % w, s.pixel as usize / w);
        FineSample {
            pixel: ((y / factor) * cw + x / factor) as u32,
            ..*s
        }
    }));
}

/// The direction of a point `p` in working-pixel units of a `width`×`height` lat-long map.
pub(super) fn direction(width: usize, height: usize, p: [f64; 2]) -> DVec3 {
    Projection::LatLong
        .pixel_to_direction(width as u32, height as u32, p[0], p[1])
        .unwrap_or(DVec3::Y)
}
