//! Light regions: the spherical Voronoi cells of the lights' sample directions.
//!
//! Every working pixel gives its energy to the light whose sample direction is nearest on the
//! sphere, so regions are compact (as median cut's are), every light carries its own region's
//! energy and colour, and the lights sum to the map's integral exactly. Regions change
//! continuously as the sample directions move. The input pixels of concentrated working pixels
//! (a sun) are assigned one by one, so the several lights that share a sun split it at full
//! resolution and keep its shape (and so its penumbra).
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

/// A light that may be nearest to some point of a bucket, with an upper bound of its dot
/// product with any direction in the bucket.
#[derive(Clone, Copy, Debug)]
struct Candidate {
    /// The light's direction, kept inline so a scan touches one array.
    dir: Vec3,
    light: u32,
    /// cos(max(0, a − r)) where a is the light's angle from the bucket centre and r the bucket's
    /// radius: no direction in the bucket is closer to the light than that.
    bound: f32,
}

/// Per-bucket candidate lights for one frame, nearest to the bucket centre first.
struct Candidates {
    offsets: Vec<u32>,
    list: Vec<Candidate>,
}

impl Candidates {
    fn new(grid: &BucketGrid, lights: &[Vec3]) -> Self {
        // Structure of arrays, so the dot products vectorise.
        let xs: Vec<f32> = lights.iter().map(|l| l.x).collect();
        let ys: Vec<f32> = lights.iter().map(|l| l.y).collect();
        let zs: Vec<f32> = lights.iter().map(|l| l.z).collect();
        let mut offsets = Vec::with_capacity(grid.centres.len() + 1);
        let mut list = Vec::with_capacity(grid.centres.len() * 16);
        let mut dots = vec![0.0f32; lights.len()];
        offsets.push(0);
        for (c, &r) in grid.centres.iter().zip(&grid.radii) {
            for (((d, x), y), z) in dots.iter_mut().zip(&xs).zip(&ys).zip(&zs) {
                *d = c.x * x + c.y * y + c.z * z;
            }
            let best = dots.iter().copied().fold(-1.0f32, f32::max);
            let reach = best.clamp(-1.0, 1.0).acos() + 2.0 * r;
            let threshold = if reach >= std::f32::consts::PI {
                -2.0
            } else {
                reach.cos() - 1e-6
            };
            let (sin_r, cos_r) = r.sin_cos();
            let start = list.len();
            list.extend(
                dots.iter()
                    .enumerate()
                    .filter(|(_, &d)| d >= threshold)
                    .map(|(i, &d)| {
                        let cos_a = d.clamp(-1.0, 1.0);
                        let bound = if cos_a >= cos_r {
                            1.0
                        } else {
                            // cos(a − r) = cos a cos r + sin a sin r, a ∈ [r, π].
                            cos_a * cos_r + (1.0 - cos_a * cos_a).max(0.0).sqrt() * sin_r
                        };
                        Candidate {
                            dir: lights[i],
                            light: i as u32,
                            bound: bound + 1e-6,
                        }
                    }),
            );
            list[start..].sort_unstable_by(|a, b| b.bound.total_cmp(&a.bound));
            offsets.push(list.len() as u32);
        }
        Self { offsets, list }
    }

    #[inline]
    fn of(&self, bucket: usize) -> &[Candidate] {
        &self.list[self.offsets[bucket] as usize..self.offsets[bucket + 1] as usize]
    }
}

/// The candidate light nearest to `d`. `hint` (any light, typically the previous pixel's) seeds
/// the search; candidates come nearest-to-the-bucket-centre first, so the search stops once no
/// remaining candidate's bound can beat the best dot product found.
#[inline]
fn nearest(candidates: &[Candidate], lights: &[Vec3], d: Vec3, hint: usize) -> usize {
    let mut best_dot = lights[hint].dot(d);
    let mut best = hint;
    for c in candidates {
        if c.bound < best_dot {
            break;
        }
        let dot = c.dir.dot(d);
        if dot > best_dot {
            best_dot = dot;
            best = c.light as usize;
        }
    }
    best
}

/// Adds every working pixel's energy, luminance-weighted direction and solid angle to the
/// region of its nearest light. A concentrated working pixel (a sun, a lamp; see
/// [`WorkingMap::fine`]) is assigned input pixel by input pixel, by exact direction, so the
/// lights that share a sun split it along their Voronoi borders at full resolution.
pub(super) fn accumulate(
    map: &WorkingMap,
    grid: &BucketGrid,
    sample_dirs: &[DVec3],
    regions: &mut [Region],
) {
    debug_assert_eq!((grid.width, grid.height), (map.width, map.height));
    let lights: Vec<Vec3> = sample_dirs.iter().map(|d| d.as_vec3()).collect();
    let candidates = Candidates::new(grid, &lights);
    let bucket_of = |x: usize, y: usize| (y / BUCKET_PIXELS) * grid.cols + x / BUCKET_PIXELS;
    let mut hint = 0;
    let mut add = |bucket: usize, dir: Vec3, energy: [f64; 3], solid_angle: f64| {
        hint = nearest(candidates.of(bucket), &lights, dir, hint);
        let r = &mut regions[hint];
        let lum = luminance_f64(energy);
        for c in 0..3 {
            r.rgb[c] += energy[c];
            r.weighted_dir[c] += lum * f64::from(dir[c]);
        }
        r.solid_angle += solid_angle;
    };
    for sample in &map.fine {
        let (x, y) = (
            sample.pixel as usize % map.width,
            sample.pixel as usize / map.width,
        );
        let energy = sample.energy.map(f64::from);
        add(
            bucket_of(x, y),
            Vec3::from(sample.dir),
            energy,
            sample.solid_angle.into(),
        );
    }
    for y in 0..map.height {
        let row = y * map.width..(y + 1) * map.width;
        let omega = map.row_solid_angle[y];
        let pixels = map.energy[row.clone()]
            .iter()
            .zip(&map.directions[row.clone()]);
        for (x, ((energy, dir), &concentrated)) in pixels.zip(&map.concentrated[row]).enumerate() {
            if !concentrated {
                add(bucket_of(x, y), Vec3::from(*dir), *energy, omega);
            }
        }
    }
}
