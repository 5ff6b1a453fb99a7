//! How accurate is the ground-shadow yardstick's reference? A study behind docs/quality.md
//! ("How exact the ground-shadow reference is").
//!
//! ```text
//! cargo run --release --example reference_accuracy
//! cargo run --release --example reference_accuracy -- 64,256 4
//! ```
//!
//! The yardstick's reference ([`ReferenceMap`], width 256) sums the map as points: a coarse
//! block at its luminance centroid, or, for the bright blocks, every full-resolution pixel at
//! its centre. A pixel is an area, though: a lamp of four pixels casts four soft-edged shadows,
//! not four hard ones. This study integrates the map's ground irradiance (the shadow scene of
//! [`envlight::yardstick::ground_shadow_error`]: a unit sphere resting on the plane y = 0, the
//! 480 [`ground_points`]) more finely: every full-resolution pixel of the upper hemisphere split
//! into s × s sub-pixels (s = 1, 2, 4, 8 by default; the largest is the best estimate),
//! each at its own centre direction with its exact lat-long solid angle and the pixel's
//! radiance (box reconstruction). It prints
//! 1. how far the yardstick's reference is from each finer sum (relative RMS on luminance,
//!    as the yardstick measures), and
//! 2. the ground-shadow errors of median cut and of the default decomposition at each light
//!    count, against the yardstick's reference and against the finest sum.
//!
//! Arguments: light counts (comma-separated, default `64,256`), then the finest split s
//! (a power of two, default 8). Maps: docs/quality.md's table (tests/data).
#[path = "../tests/test_data/mod.rs"]
mod test_data;
use anyhow::{ensure, Context, Result};
use envlight::capture::image_file::read_hdr_image;
use envlight::decompose::{DecomposeSettings, Decomposer};
use envlight::envmap::Projection;
use envlight::yardstick::{ground_points, median_cut, ReferenceMap, SPHERE_CENTRE};
use envlight::{HdrFrame, Light};
use glam::DVec3;
use std::f64::consts::PI;

/// Rec. 709 luminance.
fn luminance(rgb: [f64; 3]) -> f64 {
    0.2126 * rgb[0] + 0.7152 * rgb[1] + 0.0722 * rgb[2]
}

/// Point sources: direction and luminance energy (Σ L·Ω). Only those above the horizon can
/// light the ground.
struct Points {
    dirs: Vec<DVec3>,
    energy: Vec<f64>,
}

impl Points {
    fn new() -> Self {
        Self {
            dirs: Vec::new(),
            energy: Vec::new(),
        }
    }

    fn push(&mut self, dir: DVec3, energy: f64) {
        if dir.y > 0.0 && energy > 0.0 {
            self.dirs.push(dir);
            self.energy.push(energy);
        }
    }

    fn from_lights(lights: &[Light]) -> Self {
        let mut points = Self::new();
        for light in lights {
            let dir = DVec3::from_array(light.dir.map(f64::from)).normalize_or_zero();
            points.push(dir, luminance(light.rgb.map(f64::from)));
        }
        points
    }

    /// Shadowed ground irradiance (luminance) at each of [`ground_points`]: the same sum as the
    /// yardstick's, E(p) = Σ e·max(0, d.y)·V(p, d), with V = 0 inside the sphere's cone.
    fn ground(&self) -> Vec<f64> {
        ground_points()
            .iter()
            .map(|&p| {
                let to_centre = SPHERE_CENTRE - p;
                let dist2 = to_centre.length_squared();
                let cos_half = (1.0 - 1.0 / dist2.max(1.0)).sqrt();
                let axis = to_centre / dist2.sqrt();
                self.dirs
                    .iter()
                    .zip(&self.energy)
                    .filter(|(d, _)| d.dot(axis) <= cos_half)
                    .map(|(d, e)| e * d.y)
                    .sum()
            })
            .collect()
    }
}

/// ‖a − b‖ / ‖b‖.
fn relative_rms(a: &[f64], b: &[f64]) -> f64 {
    let num: f64 = a.iter().zip(b).map(|(x, y)| (x - y) * (x - y)).sum();
    let den: f64 = b.iter().map(|y| y * y).sum();
    (num / den).sqrt()
}

/// Every full-resolution pixel of the upper hemisphere as s × s sub-pixels, each at its centre
/// direction with its exact solid angle Δφ·(cos θ₀ − cos θ₁) and the pixel's radiance.
fn subdivided(frame: &HdrFrame, s: usize) -> Points {
    let (w, h) = (frame.width as usize, frame.height as usize);
    let (sw, sh) = (w * s, h * s);
    let d_phi = 2.0 * PI / sw as f64;
    let mut points = Points::new();
    for sy in 0..sh / 2 {
        let (t0, t1) = (PI * sy as f64 / sh as f64, PI * (sy + 1) as f64 / sh as f64);
        let omega = d_phi * (t0.cos() - t1.cos());
        let theta = 0.5 * (t0 + t1);
        let (sin_t, cos_t) = theta.sin_cos();
        let row = &frame.pixels[(sy / s) * w..(sy / s + 1) * w];
        for sx in 0..sw {
            let l = luminance(row[sx / s].map(|c| {
                if c.is_finite() {
                    f64::from(c.max(0.0))
                } else {
                    0.0
                }
            }));
            let (sin_p, cos_p) = (2.0 * PI * (sx as f64 + 0.5) / sw as f64).sin_cos();
            points.push(DVec3::new(sin_t * sin_p, cos_t, -sin_t * cos_p), l * omega);
        }
    }
    points
}

fn main() -> Result<()> {
    let mut args = std::env::args().skip(1);
    let counts: Vec<usize> = args
        .next()
        .unwrap_or_else(|| "64,256".into())
        .split(',')
        .map(|n| n.parse().with_context(|| format!("light count {n:?}")))
        .collect::<Result<_>>()?;
    let finest: usize = args.next().map_or(Ok(8), |s| s.parse())?;
    ensure!(
        finest.is_power_of_two(),
        "the finest split must be a power of two, got {finest}"
    );
    let splits: Vec<usize> = (0..=finest.trailing_zeros()).map(|k| 1 << k).collect();

    println!("Ground irradiance of the yardstick's reference (width 256) against finer sums");
    println!("(relative RMS on luminance; s × s sub-pixels per full-resolution pixel):\n");
    let header: Vec<String> = splits.iter().map(|s| format!("s = {s}")).collect();
    println!("| map | {} |", header.join(" | "));
    println!("|---|{}", "---:|".repeat(splits.len()));
    let mut tables = Vec::new();
    for name in test_data::QUALITY_MAPS {
        let path = test_data::data(name);
        let image = read_hdr_image(&path).with_context(|| format!("{}", path.display()))?;
        let mut frame = HdrFrame::new(image.width, image.height, image.pixels, Projection::LatLong)
            .with_context(|| format!("{}: no pixels", path.display()))?;
        frame.sanitize();
        let reference = ReferenceMap::new(&frame, 256)?;
        let mut reference_points = Points::new();
        for (&dir, &rgb) in reference.directions().iter().zip(reference.energies()) {
            reference_points.push(dir, luminance(rgb));
        }
        let reference_ground = reference_points.ground();
        let finer: Vec<Vec<f64>> = splits
            .iter()
            .map(|&s| subdivided(&frame, s).ground())
            .collect();
        let best = finer.last().context("no split")?;
        let cells: Vec<String> = finer
            .iter()
            .map(|g| format!("{:.4}", relative_rms(&reference_ground, g)))
            .collect();
        println!(
            "| {} | {} |",
            name.trim_end_matches("_1k.hdr"),
            cells.join(" | ")
        );

        for &n in &counts {
            let mc = Points::from_lights(&median_cut(&frame, n)?.lights).ground();
            let settings = DecomposeSettings {
                lights: n,
                ..DecomposeSettings::default()
            };
            let el =
                Points::from_lights(&Decomposer::new(settings)?.decompose(&frame).lights).ground();
            tables.push(format!(
                "| {} | {n} | {:.4} | {:.4} | {:.4} | {:.4} |",
                name.trim_end_matches("_1k.hdr"),
                relative_rms(&el, &reference_ground),
                relative_rms(&mc, &reference_ground),
                relative_rms(&el, best),
                relative_rms(&mc, best),
            ));
        }
    }
    println!("\nGround-shadow error against the yardstick's reference and against the finest sum (s = {finest}):\n");
    println!("| map | N | envlight, reference | median cut, reference | envlight, finest | median cut, finest |");
    println!("|---|---:|---:|---:|---:|---:|");
    for row in tables {
        println!("{row}");
    }
    Ok(())
}
