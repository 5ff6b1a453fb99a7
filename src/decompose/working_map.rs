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

/// Lat-long map of energy (rgb · solid angle, f64) per working pixel.
#[derive(Clone, Debug)]
pub struct WorkingMap {
    pub width: usize,
    pub height: usize,
    /// Σ rgb·Ω of the input pixels that fall in each working pixel, row-major.
    pub energy: Vec<[f64; 3]>,
    /// Centre direction of each working pixel, row-major.
    pub directions: Vec<[f32; 3]>,
    /// Exact solid angle of the working pixels of each row.
    pub row_solid_angle: Vec<f64>,
}

#[derive(Clone, Debug)]
enum Plan {
    /// Lat-long input, `factor`×`factor` input pixels per working pixel.
    Box {
        factor: usize,
        row_solid_angle: Vec<f64>,
    },
    /// Per input pixel: working pixel index (u32::MAX = none) and solid angle.
    Table {
        target: Vec<u32>,
        solid_angle: Vec<f32>,
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
        let (width, height, plan) =
            if projection == Projection::LatLong && sw % box_factor == 0 && sh % box_factor == 0 {
                let omegas = Projection::LatLong.solid_angles(src_width, src_height);
                let row_solid_angle = (0..sh).map(|y| omegas[y * sw]).collect();
                (
                    sw / box_factor,
                    sh / box_factor,
                    Plan::Box {
                        factor: box_factor,
                        row_solid_angle,
                    },
                )
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
                        match px {
                            Some((px, py)) if omega > 0.0 => {
                                let ix = (px as usize).min(width - 1);
                                let iy = (py as usize).min(height - 1);
                                target_index.push((iy * width + ix) as u32);
                                solid_angle.push(omega as f32);
                            }
                            _ => {
                                target_index.push(u32::MAX);
                                solid_angle.push(0.0);
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
            directions,
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
        let sw = self.src_width as usize;
        match &self.plan {
            Plan::Box {
                factor,
                row_solid_angle,
            } => {
                let f = *factor;
                for (y, row) in frame.pixels.chunks_exact(sw).enumerate() {
                    let omega = row_solid_angle[y];
                    let out_row = &mut map.energy[(y / f) * map.width..(y / f + 1) * map.width];
                    for (out, block) in out_row.iter_mut().zip(row.chunks_exact(f)) {
                        let mut s = [0.0f32; 3];
                        for p in block {
                            s[0] += p[0];
                            s[1] += p[1];
                            s[2] += p[2];
                        }
                        for c in 0..3 {
                            out[c] += f64::from(s[c]) * omega;
                        }
                    }
                }
            }
            Plan::Table {
                target,
                solid_angle,
            } => {
                for ((p, &t), &omega) in frame.pixels.iter().zip(target).zip(solid_angle) {
                    if t == u32::MAX {
                        continue;
                    }
                    let out = &mut map.energy[t as usize];
                    for c in 0..3 {
                        out[c] += f64::from(p[c] * omega);
                    }
                }
            }
        }
        // Bad pixels (NaN, ±Inf, negative) should have been sanitised by the source; if any
        // slipped through, drop them here rather than poison every light.
        for e in &mut map.energy {
            for c in e.iter_mut() {
                if !c.is_finite() || *c < 0.0 {
                    *c = 0.0;
                }
            }
        }
        &self.map
    }
}
