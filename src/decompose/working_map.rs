//! The working map: any input frame resampled to a small lat-long map of per-pixel energy.
//!
//! The decomposition works on a lat-long grid of a few hundred pixels across, whatever the
//! input's projection and size. Each input pixel's energy (radiance × its exact solid angle)
//! goes to the working pixel that contains its centre direction, so the working map's total
//! equals the input's integral exactly (to rounding, summed in f64). A lat-long input whose size
//! is an integer multiple of the working size takes a fast box-filter path; other inputs use a
//! per-pixel index table built once per input geometry.

use crate::envmap::Projection;
use crate::frame::HdrFrame;
use std::f64::consts::PI;

/// Lat-long map of energy (rgb · solid angle, f64) per working pixel.
#[derive(Clone, Debug)]
pub struct WorkingMap {
    pub width: usize,
    pub height: usize,
    /// Σ rgb·Ω of the input pixels that fall in each working pixel, row-major.
    pub energy: Vec<[f64; 3]>,
    /// Direction of each working pixel: the luminance-weighted mean direction of the input
    /// pixels it gathers (so a sun keeps its full-resolution position), or the pixel centre
    /// when it holds no energy. Row-major, unit length.
    pub directions: Vec<[f32; 3]>,
    /// The working pixels' centre directions.
    pub centre_directions: Vec<[f32; 3]>,
    /// Σ luminance-energy × direction per working pixel (before normalisation).
    weighted_dirs: Vec<[f64; 3]>,
    /// Exact solid angle of the working pixels of each row.
    pub row_solid_angle: Vec<f64>,
}

#[derive(Clone, Debug)]
enum Plan {
    /// Lat-long input, `factor`×`factor` input pixels per working pixel. Directions are
    /// separable: d = (sin θ·sin φ, cos θ, −sin θ·cos φ), so per row and column tables suffice.
    Box {
        factor: usize,
        row_solid_angle: Vec<f64>,
        /// (sin θ, cos θ) of each input row's centre.
        row_theta: Vec<(f64, f64)>,
        /// (sin φ, cos φ) of each input column's centre.
        column_phi: Vec<(f32, f32)>,
    },
    /// Per input pixel: working pixel index (u32::MAX = none), solid angle and direction.
    Table {
        target: Vec<u32>,
        solid_angle: Vec<f32>,
        direction: Vec<[f32; 3]>,
    },
}

/// Resamples frames of one geometry (projection and size) to a working map.
#[derive(Clone, Debug)]
pub struct Resampler {
    projection: Projection,
    src_width: u32,
    src_height: u32,
    plan: Plan,
    map: WorkingMap,
}

impl Resampler {
    /// A resampler for `projection` frames of `src_width`×`src_height`, aiming at a working map
    /// `working_width` wide (never wider than a lat-long input).
    pub fn new(
        projection: Projection,
        src_width: u32,
        src_height: u32,
        working_width: u32,
    ) -> Self {
        let (sw, sh) = (src_width as usize, src_height as usize);
        let target = working_width.max(2) as usize;
        let box_factor = (sw / target).max(1);
        let is_box =
            projection == Projection::LatLong && sw % box_factor == 0 && sh % box_factor == 0;
        let (width, height, plan) = if is_box {
            let omegas = Projection::LatLong.solid_angles(src_width, src_height);
            let row_solid_angle = (0..sh).map(|y| omegas[y * sw]).collect();
            let row_theta = (0..sh)
                .map(|y| (PI * (y as f64 + 0.5) / sh as f64).sin_cos())
                .collect();
            let column_phi = (0..sw)
                .map(|x| {
                    let (s, c) = (2.0 * PI * (x as f64 + 0.5) / sw as f64).sin_cos();
                    (s as f32, c as f32)
                })
                .collect();
            let plan = Plan::Box {
                factor: box_factor,
                row_solid_angle,
                row_theta,
                column_phi,
            };
            (sw / box_factor, sh / box_factor, plan)
        } else {
            let width = if projection == Projection::LatLong {
                target.min(sw)
            } else {
                target
            };
            let height = (width / 2).max(1);
            let omegas = projection.solid_angles(src_width, src_height);
            let mut target_index = Vec::with_capacity(sw * sh);
            let mut solid_angle = Vec::with_capacity(sw * sh);
            let mut direction = Vec::with_capacity(sw * sh);
            for y in 0..sh {
                for x in 0..sw {
                    let omega = omegas[y * sw + x];
                    let dir = projection.pixel_to_direction(
                        src_width,
                        src_height,
                        x as f64 + 0.5,
                        y as f64 + 0.5,
                    );
                    let px = dir.and_then(|d| {
                        Projection::LatLong.direction_to_pixel(width as u32, height as u32, d)
                    });
                    match (px, dir) {
                        (Some((px, py)), Some(d)) if omega > 0.0 => {
                            let ix = (px as usize).min(width - 1);
                            let iy = (py as usize).min(height - 1);
                            target_index.push((iy * width + ix) as u32);
                            solid_angle.push(omega as f32);
                            direction.push(d.as_vec3().to_array());
                        }
                        _ => {
                            target_index.push(u32::MAX);
                            solid_angle.push(0.0);
                            direction.push([0.0; 3]);
                        }
                    }
                }
            }
            (
                width,
                height,
                Plan::Table {
                    target: target_index,
                    solid_angle,
                    direction,
                },
            )
        };
        let omegas = Projection::LatLong.solid_angles(width as u32, height as u32);
        let mut directions = Vec::with_capacity(width * height);
        for y in 0..height {
            for x in 0..width {
                let d = Projection::LatLong
                    .pixel_to_direction(width as u32, height as u32, x as f64 + 0.5, y as f64 + 0.5)
                    .unwrap_or_default();
                directions.push([d.x as f32, d.y as f32, d.z as f32]);
            }
        }
        let map = WorkingMap {
            width,
            height,
            energy: vec![[0.0; 3]; width * height],
            directions: directions.clone(),
            centre_directions: directions,
            weighted_dirs: vec![[0.0; 3]; width * height],
            row_solid_angle: (0..height).map(|y| omegas[y * width]).collect(),
        };
        Self {
            projection,
            src_width,
            src_height,
            plan,
            map,
        }
    }

    /// Whether this resampler was built for frames like `frame`.
    pub fn fits(&self, frame: &HdrFrame) -> bool {
        self.projection == frame.projection
            && self.src_width == frame.width
            && self.src_height == frame.height
    }

    /// Resamples `frame` (which must fit) and returns the working map. Non-finite or negative
    /// channel values count as 0.
    pub fn resample(&mut self, frame: &HdrFrame) -> &WorkingMap {
        let map = &mut self.map;
        map.energy.iter_mut().for_each(|e| *e = [0.0; 3]);
        map.weighted_dirs.iter_mut().for_each(|e| *e = [0.0; 3]);
        let sw = self.src_width as usize;
        let [wr, wg, wb] = crate::frame::LUMINANCE_WEIGHTS;
        match &self.plan {
            Plan::Box {
                factor,
                row_solid_angle,
                row_theta,
                column_phi,
            } => {
                let f = *factor;
                for (y, row) in frame.pixels.chunks_exact(sw).enumerate() {
                    let omega = row_solid_angle[y];
                    let (sin_t, cos_t) = row_theta[y];
                    let out = (y / f) * map.width..(y / f + 1) * map.width;
                    let blocks = row.chunks_exact(f).zip(column_phi.chunks_exact(f));
                    for ((e, wd), (block, phis)) in map.energy[out.clone()]
                        .iter_mut()
                        .zip(&mut map.weighted_dirs[out])
                        .zip(blocks)
                    {
                        let (mut s, mut lum, mut lum_sin, mut lum_cos) =
                            ([0.0f32; 3], 0.0f32, 0.0f32, 0.0f32);
                        for (p, &(sin_p, cos_p)) in block.iter().zip(phis) {
                            s[0] += p[0];
                            s[1] += p[1];
                            s[2] += p[2];
                            let l = wr * p[0] + wg * p[1] + wb * p[2];
                            lum += l;
                            lum_sin += l * sin_p;
                            lum_cos += l * cos_p;
                        }
                        for c in 0..3 {
                            e[c] += f64::from(s[c]) * omega;
                        }
                        wd[0] += f64::from(lum_sin) * sin_t * omega;
                        wd[1] += f64::from(lum) * cos_t * omega;
                        wd[2] -= f64::from(lum_cos) * sin_t * omega;
                    }
                }
            }
            Plan::Table {
                target,
                solid_angle,
                direction,
            } => {
                for (((p, &t), &omega), d) in frame
                    .pixels
                    .iter()
                    .zip(target)
                    .zip(solid_angle)
                    .zip(direction)
                {
                    if t == u32::MAX {
                        continue;
                    }
                    let e = &mut map.energy[t as usize];
                    for c in 0..3 {
                        e[c] += f64::from(p[c] * omega);
                    }
                    let l = f64::from((wr * p[0] + wg * p[1] + wb * p[2]) * omega);
                    let wd = &mut map.weighted_dirs[t as usize];
                    for c in 0..3 {
                        wd[c] += l * f64::from(d[c]);
                    }
                }
            }
        }
        // Bad pixels (NaN, ±Inf, negative) should have been sanitised by the source; if any
        // slipped through, drop them here rather than poison every light.
        for ((e, wd), (dir, centre)) in map
            .energy
            .iter_mut()
            .zip(&map.weighted_dirs)
            .zip(map.directions.iter_mut().zip(&map.centre_directions))
        {
            if e.iter().any(|c| !c.is_finite() || *c < 0.0) {
                e.iter_mut()
                    .for_each(|c| *c = if c.is_finite() { c.max(0.0) } else { 0.0 });
                *dir = *centre;
                continue;
            }
            *dir = match glam::DVec3::from(*wd).try_normalize() {
                Some(d) => d.as_vec3().to_array(),
                None => *centre,
            };
        }
        &self.map
    }
}
