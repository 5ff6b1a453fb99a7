//! How much of a sun near a pole of the fit map do the fitted ASG lobes keep? The study behind
//! docs/asg.md ("Known limit: a sun at a pole of the fit map").
//!
//! ```text
//! cargo run --release --example asg_pole_sun
//! ```
//!
//! For each fit height (64, 256) and each polar angle of the sun (0° = the zenith, a pole of
//! the lat-long fit map, out to the horizon), a black 1024 × 512 lat-long frame gets a sun of
//! radiance 10⁴ in one of two shapes: a disc of the real sun's radius (0.27°: every pixel whose
//! centre lies within it; at the zenith that is the whole top row) or a single source pixel
//! (at the pole a thin wedge of 0.35° × 2.8 arc-minutes). The default fitter (16 lobes) fits
//! it from scratch; the line gives the lobes' integral over the frame's integral (summed over
//! the channels) and the fit's loss.
use anyhow::{Context, Result};
use envlight::asg::fit::{AsgFitter, FitSettings};
use envlight::envmap::Projection;
use envlight::HdrFrame;
use glam::DVec3;
use std::f64::consts::PI;

const WIDTH: u32 = 1024;
const HEIGHT: u32 = 512;
const SUN_RADIANCE: f32 = 1e4;

/// The frame with the sun at polar angle `theta_deg` (azimuth 0.3 rad): a disc of angular
/// radius `radius_deg`, or one pixel when `radius_deg` is 0. Returns the frame and the sun's
/// integral (one channel).
fn sun_frame(theta_deg: f64, radius_deg: f64) -> Result<(HdrFrame, f64)> {
    let (w, h) = (WIDTH as usize, HEIGHT as usize);
    let theta = theta_deg.to_radians();
    let sun = DVec3::new(
        theta.sin() * 0.3f64.cos(),
        theta.cos(),
        theta.sin() * 0.3f64.sin(),
    );
    let mut pixels = vec![[0f32; 3]; w * h];
    let mut lit = Vec::new();
    if radius_deg > 0.0 {
        let cos_r = radius_deg.to_radians().cos();
        for y in 0..h {
            for x in 0..w {
                let d = Projection::LatLong
                    .pixel_to_direction(WIDTH, HEIGHT, x as f64 + 0.5, y as f64 + 0.5)
                    .context("a lat-long pixel without a direction")?;
                if d.dot(sun) >= cos_r {
                    lit.push((x, y));
                }
            }
        }
    } else {
        let y = ((theta / PI * h as f64) as usize).min(h - 1);
        let x = ((0.3 / (2.0 * PI) * w as f64) as usize).min(w - 1);
        lit.push((x, y));
    }
    let mut integral = 0.0;
    for &(x, y) in &lit {
        pixels[y * w + x] = [SUN_RADIANCE; 3];
        let (t0, t1) = (PI * y as f64 / h as f64, PI * (y + 1) as f64 / h as f64);
        integral += f64::from(SUN_RADIANCE) * (2.0 * PI / w as f64) * (t0.cos() - t1.cos());
    }
    let frame =
        HdrFrame::new(WIDTH, HEIGHT, pixels, Projection::LatLong).context("the frame's size")?;
    Ok((frame, integral))
}

fn main() -> Result<()> {
    println!("height  sun          polar°  pixels  lobes/map  loss");
    for height in [64, 256] {
        for (shape, radius) in [("disc 0.27°", 0.27), ("one pixel", 0.0)] {
            for theta in [0.0, 0.5, 1.0, 2.0, 5.0, 90.0] {
                let (frame, integral) = sun_frame(theta, radius)?;
                let lit = frame.pixels.iter().filter(|p| p[0] > 0.0).count();
                let mut fitter = AsgFitter::new(FitSettings {
                    height,
                    ..FitSettings::default()
                })?;
                let fit = fitter.fit_frame(&frame)?;
                let lobes: f64 = fit
                    .lobes
                    .iter()
                    .map(|l| l.integral().iter().sum::<f64>())
                    .sum();
                let loss = fit.loss.map_or(f64::NAN, |l| l.total);
                println!(
                    "{height:>6}  {shape:<11} {theta:>6}  {lit:>6}  {:>9.4}  {loss:.3}",
                    lobes / (3.0 * integral)
                );
            }
        }
    }
    Ok(())
}
