//! Merging lights that crowd a concentrated source (the sun) into one light.
//!
//! Inverse-transform sampling puts many lights where the energy is concentrated: a sun holding
//! 70% of a map's energy attracts 70% of the points. Havran et al. 2005 cluster such lights to
//! save shadow maps. Steps:
//! 1. The merge radius is `spacing_fraction` × the mean spacing of N uniformly spread lights,
//!    √(4π/N) radians: lights that close together sit much denser than the map's average.
//! 2. Visit lights by decreasing luminance (ties by id); each unvisited light seeds a cluster of
//!    all unvisited lights within the radius of it.
//! 3. A cluster becomes one light: id = its smallest member id (stable while the membership is),
//!    rgb = the sum (energy is kept), dir = the luminance-weighted mean direction, and
//!    solid_angle = the sum of the members' regions — the spread of the merged source, which a
//!    renderer turns into a softer shadow.

use crate::light::Light;
use glam::DVec3;

/// Default merge radius as a fraction of the mean light spacing.
pub const DEFAULT_SPACING_FRACTION: f64 = 0.1;

fn dvec(d: [f32; 3]) -> DVec3 {
    DVec3::new(d[0].into(), d[1].into(), d[2].into())
}

/// Merges crowded lights; the result is ordered by id.
pub fn merge_crowded(lights: &[Light], spacing_fraction: f64) -> Vec<Light> {
    let n = lights.len();
    if n < 2 || spacing_fraction.is_nan() || spacing_fraction <= 0.0 {
        return lights.to_vec();
    }
    let radius = spacing_fraction * (4.0 * std::f64::consts::PI / n as f64).sqrt();
    let cos_radius = radius.min(std::f64::consts::PI).cos();
    let dirs: Vec<DVec3> = lights.iter().map(|l| dvec(l.dir)).collect();
    let mut order: Vec<usize> = (0..n).collect();
    order.sort_by(|&a, &b| {
        lights[b]
            .luminance()
            .total_cmp(&lights[a].luminance())
            .then(lights[a].id.cmp(&lights[b].id))
    });
    let mut taken = vec![false; n];
    let mut out = Vec::with_capacity(n);
    for &seed in &order {
        if taken[seed] {
            continue;
        }
        taken[seed] = true;
        let mut id = lights[seed].id;
        let mut rgb = lights[seed].rgb.map(f64::from);
        let mut solid_angle = f64::from(lights[seed].solid_angle);
        let seed_weight = f64::from(lights[seed].luminance()).max(0.0);
        let mut weighted_dir = dirs[seed] * seed_weight;
        let mut members = 1;
        for j in 0..n {
            if taken[j] || dirs[seed].dot(dirs[j]) < cos_radius {
                continue;
            }
            taken[j] = true;
            members += 1;
            id = id.min(lights[j].id);
            for (c, v) in rgb.iter_mut().zip(lights[j].rgb) {
                *c += f64::from(v);
            }
            solid_angle += f64::from(lights[j].solid_angle);
            weighted_dir += dirs[j] * f64::from(lights[j].luminance()).max(0.0);
        }
        let dir = if members == 1 {
            dirs[seed]
        } else {
            weighted_dir.try_normalize().unwrap_or(dirs[seed])
        };
        out.push(Light {
            id,
            dir: [dir.x as f32, dir.y as f32, dir.z as f32],
            rgb: rgb.map(|c| c as f32),
            solid_angle: solid_angle as f32,
        });
    }
    out.sort_by_key(|l| l.id);
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn light(id: u32, dir: DVec3, power: f32) -> Light {
        let d = dir.normalize();
        Light {
            id,
            dir: [d.x as f32, d.y as f32, d.z as f32],
            rgb: [power; 3],
            solid_angle: 0.001,
        }
    }

    #[test]
    fn sun_cluster_merges_and_keeps_energy() {
        let mut lights: Vec<Light> = (0..200)
            .map(|i| {
                // Spread lights around the sphere (Fibonacci).
                let y = 1.0 - 2.0 * (i as f64 + 0.5) / 200.0;
                let r = (1.0 - y * y).sqrt();
                let phi = i as f64 * 2.399963;
                light(i + 10, DVec3::new(r * phi.cos(), y, r * phi.sin()), 1.0)
            })
            .collect();
        let sun = DVec3::new(0.3, 0.8, 0.2).normalize();
        for i in 0..10 {
            let jitter = DVec3::new(0.001 * i as f64, 0.0, -0.001 * i as f64);
            lights.push(light(i, sun + jitter, 50.0));
        }
        let merged = merge_crowded(&lights, DEFAULT_SPACING_FRACTION);
        let total = |ls: &[Light]| ls.iter().map(|l| f64::from(l.rgb[0])).sum::<f64>();
        assert!((total(&merged) - total(&lights)).abs() < 1e-3 * total(&lights));
        let sun_light = merged
            .iter()
            .find(|l| l.id == 0)
            .expect("merged sun keeps the lowest id");
        assert!(sun_light.rgb[0] >= 500.0);
        assert!(
            (sun_light.solid_angle - 0.01).abs() < 2e-3,
            "spread is the members' total"
        );
        assert!(dvec(sun_light.dir).dot(sun) > 0.9999);
        // The evenly spread lights are not merged with each other.
        assert!(merged.len() >= 195, "{} lights left", merged.len());
        assert!(merged.windows(2).all(|w| w[0].id < w[1].id));
    }

    #[test]
    fn nothing_to_merge_returns_the_input() {
        let lights = vec![light(0, DVec3::X, 1.0), light(1, DVec3::Y, 1.0)];
        assert_eq!(merge_crowded(&lights, DEFAULT_SPACING_FRACTION), lights);
        assert_eq!(merge_crowded(&[], 0.25), vec![]);
    }
}
