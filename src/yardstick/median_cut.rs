//! Debevec's median cut: P. Debevec, "A Median Cut Algorithm for Light Probe Sampling",
//! SIGGRAPH 2005 poster / sketch.
//!
//! Steps, on a lat-long frame at full resolution:
//! 1. Luminance energy per pixel, lum·Ω, with Ω the exact solid angle of the pixel's row
//!    ([`Projection::solid_angles`]); a summed-area table of it gives any rectangle's energy in
//!    O(1).
//! 2. Start with the whole map as one region. Split a region along its longer dimension, where
//!    the width is measured in angle with the cos-latitude factor as in the paper
//!    (width·2π/W·sin θ at the region's centre row against height·π/H), at the pixel boundary
//!    that divides the region's energy most evenly into two halves (binary search on the table).
//!    A region one pixel wide is split along its height and vice versa; a zero-energy region is
//!    split in the middle.
//! 3. If n is a power of two, do log2(n) rounds, each splitting every region. Otherwise split the
//!    region with the largest energy (ties: the larger region) until there are n regions.
//!    Regions of a single pixel cannot be split and stay as they are, so a map with fewer than n
//!    pixels (or a round-based split of tiny regions) yields fewer than n lights.
//! 4. Each region becomes a light: direction = normalised Σ d·lum·Ω over the region (falling back
//!    to Σ d·Ω, then to the direction at the region's centre, when that sum vanishes, e.g. for a
//!    black region or one covering the whole sphere), rgb = Σ rgb·Ω (so the lights sum exactly to
//!    the map's integral), solid_angle = Σ Ω; ids 0..n−1 in region order.

use super::{add_scaled, check_latlong, clean, lum, unit_if_significant, YardstickError};
use crate::envmap::Projection;
use crate::frame::HdrFrame;
use crate::light::{Light, LightFrame};
use glam::DVec3;
use std::f64::consts::PI;

/// A half-open pixel rectangle [x0, x1) × [y0, y1).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
struct Region {
    x0: usize,
    y0: usize,
    x1: usize,
    y1: usize,
}

impl Region {
    fn area(&self) -> usize {
        (self.x1 - self.x0) * (self.y1 - self.y0)
    }
}

/// Summed-area table of lum·Ω, (W+1)×(H+1), with the pixel dimensions of the map.
struct EnergyTable {
    width: usize,
    height: usize,
    sat: Vec<f64>,
}

impl EnergyTable {
    fn new(frame: &HdrFrame, omega: &[f64]) -> Self {
        let (w, h) = (frame.width as usize, frame.height as usize);
        let stride = w + 1;
        let mut sat = vec![0.0; stride * (h + 1)];
        for y in 0..h {
            let om = omega[y * w];
            let mut row_sum = 0.0;
            for x in 0..w {
                row_sum += lum(clean(frame.pixels[y * w + x])) * om;
                sat[(y + 1) * stride + x + 1] = sat[y * stride + x + 1] + row_sum;
            }
        }
        Self {
            width: w,
            height: h,
            sat,
        }
    }

    fn energy(&self, r: Region) -> f64 {
        let s = self.width + 1;
        let e = self.sat[r.y1 * s + r.x1] - self.sat[r.y0 * s + r.x1] - self.sat[r.y1 * s + r.x0]
            + self.sat[r.y0 * s + r.x0];
        e.max(0.0)
    }

    /// Splits `r` in two at the most even energy boundary along its longer (angular) side, or
    /// `None` for a single pixel.
    fn split(&self, r: Region) -> Option<(Region, Region)> {
        let (w, h) = (r.x1 - r.x0, r.y1 - r.y0);
        if w * h <= 1 {
            return None;
        }
        let along_x = if w < 2 {
            false
        } else if h < 2 {
            true
        } else {
            let theta = PI * (r.y0 + r.y1) as f64 * 0.5 / self.height as f64;
            let width_angle = w as f64 * 2.0 * PI / self.width as f64 * theta.sin();
            let height_angle = h as f64 * PI / self.height as f64;
            width_angle >= height_angle
        };
        let (lo, hi) = if along_x { (r.x0, r.x1) } else { (r.y0, r.y1) };
        let part = |s: usize| {
            if along_x {
                Region { x1: s, ..r }
            } else {
                Region { y1: s, ..r }
            }
        };
        let total = self.energy(r);
        let cut = if total > 0.0 {
            let half = 0.5 * total;
            // Smallest boundary s in [lo+1, hi-1] whose first part holds at least half.
            let (mut a, mut b) = (lo + 1, hi - 1);
            while a < b {
                let m = a + (b - a) / 2;
                if self.energy(part(m)) >= half {
                    b = m;
                } else {
                    a = m + 1;
                }
            }
            if a > lo + 1
                && (half - self.energy(part(a - 1))).abs() < (self.energy(part(a)) - half).abs()
            {
                a - 1
            } else {
                a
            }
        } else {
            lo + (hi - lo) / 2
        };
        Some(if along_x {
            (Region { x1: cut, ..r }, Region { x0: cut, ..r })
        } else {
            (Region { y1: cut, ..r }, Region { y0: cut, ..r })
        })
    }
}

/// Debevec's median cut of a lat-long frame into (at most) `n` directional lights; see the module
/// docs for the steps. Errors for other projections, inconsistent frames and `n == 0`.
pub fn median_cut(frame: &HdrFrame, n: usize) -> Result<LightFrame, YardstickError> {
    check_latlong(frame)?;
    if n == 0 {
        return Err(YardstickError::NoLights);
    }
    let omega = Projection::LatLong.solid_angles(frame.width, frame.height);
    let table = EnergyTable::new(frame, &omega);
    let whole = Region {
        x0: 0,
        y0: 0,
        x1: table.width,
        y1: table.height,
    };
    let mut regions = vec![whole];
    if n.is_power_of_two() {
        for _ in 0..n.trailing_zeros() {
            let mut next = Vec::with_capacity(regions.len() * 2);
            for &r in &regions {
                match table.split(r) {
                    Some((a, b)) => next.extend([a, b]),
                    None => next.push(r),
                }
            }
            if next.len() == regions.len() {
                break;
            }
            regions = next;
        }
    } else {
        // Energies cached beside the regions; single pixels are never candidates.
        let mut energies = vec![table.energy(whole)];
        while regions.len() < n {
            let best = (0..regions.len())
                .filter(|&i| regions[i].area() > 1)
                .max_by(|&i, &j| {
                    energies[i]
                        .total_cmp(&energies[j])
                        .then(regions[i].area().cmp(&regions[j].area()))
                        .then(j.cmp(&i))
                });
            let Some(i) = best else { break };
            let Some((a, b)) = table.split(regions[i]) else {
                break;
            };
            regions[i] = a;
            energies[i] = table.energy(a);
            regions.push(b);
            energies.push(table.energy(b));
        }
    }

    // Per-column and per-row direction factors: d = (sinθ sinφ, cosθ, −sinθ cosφ).
    let (w, h) = (table.width, table.height);
    let cols: Vec<(f64, f64)> = (0..w)
        .map(|x| (2.0 * PI * (x as f64 + 0.5) / w as f64).sin_cos())
        .collect();
    let rows: Vec<(f64, f64)> = (0..h)
        .map(|y| (PI * (y as f64 + 0.5) / h as f64).sin_cos())
        .collect();
    let lights = regions
        .iter()
        .enumerate()
        .map(|(id, &r)| {
            let mut rgb = [0.0f64; 3];
            let mut solid_angle = 0.0;
            let mut lum_dir = DVec3::ZERO;
            let mut omega_dir = DVec3::ZERO;
            for y in r.y0..r.y1 {
                let om = omega[y * w];
                let (sin_t, cos_t) = rows[y];
                let row = &frame.pixels[y * w + r.x0..y * w + r.x1];
                for (&(sin_p, cos_p), &pixel) in cols[r.x0..r.x1].iter().zip(row) {
                    let d = DVec3::new(sin_t * sin_p, cos_t, -sin_t * cos_p);
                    let p = clean(pixel);
                    add_scaled(&mut rgb, p, om);
                    lum_dir += d * (lum(p) * om);
                    omega_dir += d * om;
                    solid_angle += om;
                }
            }
            let lum_total = lum(rgb);
            let dir = [(lum_dir, lum_total), (omega_dir, solid_angle)]
                .into_iter()
                .find_map(|(v, weight)| unit_if_significant(v, weight))
                .unwrap_or_else(|| {
                    latlong_dir(w, h, (r.x0 + r.x1) as f64 * 0.5, (r.y0 + r.y1) as f64 * 0.5)
                });
            Light {
                id: id as u32,
                dir: dir.as_vec3().to_array(),
                rgb: rgb.map(|c| c as f32),
                solid_angle: solid_angle as f32,
            }
        })
        .collect();
    Ok(LightFrame {
        seq: frame.seq,
        time: frame.time,
        lights,
    })
}

fn latlong_dir(w: usize, h: usize, x: f64, y: f64) -> DVec3 {
    Projection::LatLong
        .pixel_to_direction(w as u32, h as u32, x, y)
        .unwrap_or(DVec3::Y)
}
