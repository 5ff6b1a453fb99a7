//! Light regions: the spherical Voronoi cells of the lights' sample directions.
//!
//! Every working pixel gives its energy to the light whose sample direction is nearest on the
//! sphere, so regions are compact (as median cut's are), every light carries its own region's
//! energy and colour, and the lights sum to the map's integral exactly. Regions change
//! continuously as the sample directions move. A pixel holding a large share of the energy (a
//! sun) is split into sub-samples so the several lights inside it share it.
//!
//! Nearest-light queries use buckets of B×B working pixels: per frame, each bucket keeps the
//! lights that can be nearest to any point in it — those within d_min + 2r of its centre, where
//! d_min is the angle to the nearest light and r the bucket's angular radius (triangle
//! inequality) — so a pixel tests a handful of candidates instead of all N.

use super::working_map::WorkingMap;
use super::{luminance_f64, Region};
use glam::{DVec3, Vec3};

const BUCKET_PIXELS: usize = 8;

/// Per-geometry bucket layout of a working map.
#[derive(Clone, Debug)]
pub struct BucketGrid {
    width: usize,
    height: usize,
    cols: usize,
    centres: Vec<Vec3>,
    /// Angular radius of each bucket (radians), with a small safety margin.
    radii: Vec<f32>,
}

impl BucketGrid {
    pub fn new(width: usize, height: usize) -> Self {
        let cols = width.div_ceil(BUCKET_PIXELS);
        let rows = height.div_ceil(BUCKET_PIXELS);
        let dir = |x: f64, y: f64| {
            crate::envmap::Projection::LatLong
                .pixel_to_direction(width as u32, height as u32, x, y)
                .unwrap_or(DVec3::Y)
        };
        let mut centres = Vec::with_capacity(cols * rows);
        let mut radii = Vec::with_capacity(cols * rows);
        for by in 0..rows {
            for bx in 0..cols {
                let x0 = (bx * BUCKET_PIXELS) as f64;
                let y0 = (by * BUCKET_PIXELS) as f64;
                let x1 = ((bx + 1) * BUCKET_PIXELS).min(width) as f64;
                let y1 = ((by + 1) * BUCKET_PIXELS).min(height) as f64;
                let c = dir(0.5 * (x0 + x1), 0.5 * (y0 + y1));
                // The farthest point of a lat-long rectangle from its centre lies on its border;
                // sample the border densely.
                let mut radius = 0.0f64;
                let steps = 16;
                for k in 0..=steps {
                    let t = k as f64 / steps as f64;
                    for p in [
                        (x0 + t * (x1 - x0), y0),
                        (x0 + t * (x1 - x0), y1),
                        (x0, y0 + t * (y1 - y0)),
                        (x1, y0 + t * (y1 - y0)),
                    ] {
                        radius = radius.max(c.dot(dir(p.0, p.1)).clamp(-1.0, 1.0).acos());
                    }
                }
                centres.push(c.as_vec3());
                radii.push((radius * 1.05 + 1e-4) as f32);
            }
        }
        Self {
            width,
            height,
            cols,
            centres,
            radii,
        }
    }
}

/// Per-bucket candidate lights for one frame.
struct Candidates {
    offsets: Vec<u32>,
    lights: Vec<u32>,
}

impl Candidates {
    /// Candidate lists over the lights not `excluded`.
    fn new(grid: &BucketGrid, lights: &[Vec3], excluded: &[bool]) -> Self {
        let mut offsets = Vec::with_capacity(grid.centres.len() + 1);
        let mut list = Vec::new();
        let mut dots = vec![0.0f32; lights.len()];
        offsets.push(0);
        for (c, r) in grid.centres.iter().zip(&grid.radii) {
            let mut best = -1.0f32;
            for ((d, l), &skip) in dots.iter_mut().zip(lights).zip(excluded) {
                *d = if skip { -3.0 } else { c.dot(*l) };
                best = best.max(*d);
            }
            let reach = best.clamp(-1.0, 1.0).acos() + 2.0 * r;
            let threshold = if reach >= std::f32::consts::PI {
                -2.0
            } else {
                reach.cos() - 1e-6
            };
            list.extend(
                dots.iter()
                    .enumerate()
                    .filter(|(_, &d)| d >= threshold)
                    .map(|(i, _)| i as u32),
            );
            offsets.push(list.len() as u32);
        }
        Self {
            offsets,
            lights: list,
        }
    }

    #[inline]
    fn of(&self, bucket: usize) -> &[u32] {
        &self.lights[self.offsets[bucket] as usize..self.offsets[bucket + 1] as usize]
    }
}

#[inline]
fn nearest(candidates: &[u32], lights: &[Vec3], d: Vec3) -> usize {
    let mut best = (f32::NEG_INFINITY, 0usize);
    for &i in candidates {
        let dot = lights[i as usize].dot(d);
        if dot > best.0 {
            best = (dot, i as usize);
        }
    }
    best.1
}

/// Adds every working pixel's energy, luminance-weighted direction and solid angle to the
/// region of its nearest light.
///
/// Concentrated sources come first: a pixel holding more than 1/(4N) of the luminance energy
/// (a sun, a lamp) is split among the lights nearest to its sub-samples, and those lights then
/// keep only such pixels — the ordinary pixels around them go to the nearest other light. So a
/// sun light carries the sun and not the bright sky around it, and casts the sun's shadow.
pub(super) fn accumulate(
    map: &WorkingMap,
    grid: &BucketGrid,
    sample_dirs: &[DVec3],
    regions: &mut [Region],
) {
    debug_assert_eq!((grid.width, grid.height), (map.width, map.height));
    let lights: Vec<Vec3> = sample_dirs.iter().map(|d| d.as_vec3()).collect();
    let mut owns_source = vec![false; lights.len()];
    let all = Candidates::new(grid, &lights, &owns_source);
    let n = lights.len() as f64;
    let total: f64 = map.energy.iter().map(|e| luminance_f64(*e)).sum();
    let split_above = if total > 0.0 {
        total / (4.0 * n)
    } else {
        f64::INFINITY
    };
    let (w, h) = (map.width, map.height);

    // Pass 1: concentrated sources.
    for y in 0..h {
        let omega = map.row_solid_angle[y];
        let bucket_row = (y / BUCKET_PIXELS) * grid.cols;
        for x in 0..w {
            let idx = y * w + x;
            let energy = map.energy[idx];
            let lum = luminance_f64(energy);
            if lum > split_above {
                let cands = all.of(bucket_row + x / BUCKET_PIXELS);
                split_pixel(
                    map,
                    (x, y),
                    omega,
                    total,
                    n,
                    cands,
                    &lights,
                    regions,
                    &mut owns_source,
                );
            }
        }
    }

    // Pass 2: every other pixel goes to its nearest light that owns no source (if there is one).
    let rest = if owns_source.iter().all(|&o| o) {
        all
    } else {
        Candidates::new(grid, &lights, &owns_source)
    };
    for y in 0..h {
        let omega = map.row_solid_angle[y];
        let bucket_row = (y / BUCKET_PIXELS) * grid.cols;
        for x in 0..w {
            let idx = y * w + x;
            let energy = map.energy[idx];
            let lum = luminance_f64(energy);
            if lum > split_above {
                continue;
            }
            let d = Vec3::from(map.directions[idx]);
            let r = &mut regions[nearest(rest.of(bucket_row + x / BUCKET_PIXELS), &lights, d)];
            for c in 0..3 {
                r.rgb[c] += energy[c];
                r.weighted_dir[c] += lum * f64::from(d[c]);
            }
            r.solid_angle += omega;
        }
    }
}

/// Splits a concentrated-source pixel among the lights nearest to its k×k sub-samples.
#[allow(clippy::too_many_arguments)]
fn split_pixel(
    map: &WorkingMap,
    (x, y): (usize, usize),
    omega: f64,
    total: f64,
    n: f64,
    cands: &[u32],
    lights: &[Vec3],
    regions: &mut [Region],
    owns_source: &mut [bool],
) {
    let (w, h) = (map.width, map.height);
    let idx = y * w + x;
    let energy = map.energy[idx];
    let lum = luminance_f64(energy);
    // Sub-samples over the pixel decide which lights share it; they all point at the pixel's
    // energy centroid.
    let k = ((4.0 * lum / total * n).sqrt().ceil() as usize).clamp(2, 32);
    let share = 1.0 / (k * k) as f64;
    let centroid = map.directions[idx];
    for j in 0..k {
        for i in 0..k {
            let sx = x as f64 + (i as f64 + 0.5) / k as f64;
            let sy = y as f64 + (j as f64 + 0.5) / k as f64;
            let d = crate::envmap::Projection::LatLong
                .pixel_to_direction(w as u32, h as u32, sx, sy)
                .unwrap_or(DVec3::Y);
            let nearest_light = nearest(cands, lights, d.as_vec3());
            owns_source[nearest_light] = true;
            let r = &mut regions[nearest_light];
            for c in 0..3 {
                r.rgb[c] += energy[c] * share;
                r.weighted_dir[c] += lum * share * f64::from(centroid[c]);
            }
            r.solid_angle += omega * share;
        }
    }
}
