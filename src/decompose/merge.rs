//! Merging lights that crowd a concentrated source (the sun) into one light.
//!
//! Inverse-transform sampling puts many lights where the energy is concentrated: a sun holding
//! 70% of a map's energy attracts 70% of the points. Havran et al. 2005 cluster such lights to
//! save shadow maps. Steps:
//! 1. The merge radius is `spacing_fraction` × the mean spacing of N uniformly spread lights,
//!    √(4π/N) radians: lights that close together sit much denser than the map's average.
//! 2. Visit lights by decreasing luminance (ties by id); each unvisited light seeds a cluster of
//!    all unvisited lights within the radius of it. The lights within the radius are found among
//!    those whose y lies within the radius's chord of the seed's (lights sorted by y, a binary
//!    search), not by a scan of all N; the members found are then taken in index order, so the
//!    sums are the brute-force scan's bit for bit (`windowed_search_equals_the_full_scan`).
//! 3. A cluster becomes one light: id = its smallest member id (stable while the membership is;
//!    the result is ordered by id, with no sort where the ids rise along the input),
//!    rgb = the sum (energy is kept), dir = the luminance-weighted mean direction, and
//!    solid_angle = the sum of the members' regions — the spread of the merged source, which a
//!    renderer turns into a softer shadow.

use crate::light::Light;
use glam::DVec3;

/// An integer whose order is `f32::total_cmp`'s order of `x`.
fn f32_order(x: f32) -> u32 {
    let bits = x.to_bits();
    if bits >> 31 == 1 {
        !bits
    } else {
        bits | 1 << 31
    }
}

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
    // By decreasing luminance, then id, then index: the order a stable sort on (luminance, id)
    // gives, with each key computed once and packed into integers (so the sort compares
    // integers, not a chain of closures).
    let mut keyed: Vec<(u64, u32)> = lights
        .iter()
        .enumerate()
        .map(|(i, l)| {
            let descending = !f32_order(l.luminance());
            ((u64::from(descending) << 32) | u64::from(l.id), i as u32)
        })
        .collect();
    keyed.sort_unstable();
    let order: Vec<usize> = keyed.iter().map(|k| k.1 as usize).collect();
    // Lights by y: a light within the radius of the seed has its y within the chord of it. The
    // slack covers directions a little off unit length (f32), which the dot test below can
    // let in from a hair beyond the radius; the window only has to hold every light it passes.
    let chord = 2.0 * (0.5 * radius.min(std::f64::consts::PI)).sin() + 1e-4;
    let mut by_y: Vec<(f64, usize)> = Vec::with_capacity(n);
    // A direction that is not finite compares as "not farther than the radius" in the test
    // below (NaN < cos_radius is false), so it is a candidate of every seed.
    let mut everywhere = Vec::new();
    for (i, d) in dirs.iter().enumerate() {
        if d.is_finite() {
            by_y.push((d.y, i));
        } else {
            everywhere.push(i);
        }
    }
    // Equal y in any order: the candidates are put in index order below.
    by_y.sort_unstable_by(|a, b| a.0.total_cmp(&b.0));
    let mut taken = vec![false; n];
    let mut near = Vec::new();
    let mut out = Vec::with_capacity(n);
    // With ids rising along the list (a decomposition's lights), a cluster's id is that of its
    // lowest-index member, so the clusters come out in id order by that member's index: no
    // sort. `cluster_at[i]`: the cluster whose lowest-index member is light i.
    let ids_rise = lights.windows(2).all(|w| w[0].id < w[1].id);
    let mut cluster_at = vec![usize::MAX; if ids_rise { n } else { 0 }];
    for &seed in &order {
        if taken[seed] {
            continue;
        }
        taken[seed] = true;
        // The members: the untaken lights within the radius (a non-finite direction fails the
        // `<` test and so joins, as in the scan). Whether a light joins does not depend on the
        // others of this cluster, so the window is filtered first and only the members are put
        // in index order, as a scan of all lights would take them: near a sun the window holds
        // a hundred lights, and sorting it for every seed cost more than the rest of the merge.
        let joins = |j: usize| !(taken[j] || dirs[seed].dot(dirs[j]) < cos_radius);
        near.clear();
        if dirs[seed].is_finite() {
            let y = dirs[seed].y;
            let start = by_y.partition_point(|&(yj, _)| yj < y - chord);
            near.extend(
                by_y[start..]
                    .iter()
                    .take_while(|&&(yj, _)| yj <= y + chord)
                    .map(|&(_, j)| j)
                    .filter(|&j| joins(j)),
            );
            near.extend(everywhere.iter().copied().filter(|&j| joins(j)));
            near.sort_unstable();
        } else {
            // A non-finite seed has no window: it is tested against every light, as before.
            near.extend((0..n).filter(|&j| joins(j)));
        }
        let mut id = lights[seed].id;
        let mut rgb = lights[seed].rgb.map(f64::from);
        let mut solid_angle = f64::from(lights[seed].solid_angle);
        let seed_weight = f64::from(lights[seed].luminance()).max(0.0);
        let mut weighted_dir = dirs[seed] * seed_weight;
        let mut members = 1;
        if ids_rise {
            cluster_at[near.first().map_or(seed, |&j| j.min(seed))] = out.len();
        }
        for &j in &near {
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
            rgb: rgb.map(crate::light::saturating_f32),
            solid_angle: solid_angle as f32,
        });
    }
    if ids_rise {
        return cluster_at
            .into_iter()
            .filter(|&k| k != usize::MAX)
            .map(|k| out[k])
            .collect();
    }
    // Ids are unique in a decomposition's lights; should they repeat, the clusters keep the
    // order they were made in (what a stable sort gives).
    let mut by_id: Vec<(u32, usize)> = out.iter().enumerate().map(|(k, l)| (l.id, k)).collect();
    by_id.sort_unstable();
    by_id.into_iter().map(|(_, k)| out[k]).collect()
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

    /// The scan of every light that `merge_crowded` replaced, as the oracle.
    fn merge_by_full_scan(lights: &[Light], spacing_fraction: f64) -> Vec<Light> {
        let n = lights.len();
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
        let mut out = Vec::new();
        for &seed in &order {
            if taken[seed] {
                continue;
            }
            taken[seed] = true;
            let mut id = lights[seed].id;
            let mut rgb = lights[seed].rgb.map(f64::from);
            let mut solid_angle = f64::from(lights[seed].solid_angle);
            let mut weighted_dir = dirs[seed] * f64::from(lights[seed].luminance()).max(0.0);
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
                rgb: rgb.map(crate::light::saturating_f32),
                solid_angle: solid_angle as f32,
            });
        }
        out.sort_by_key(|l| l.id);
        out
    }

    fn bits(lights: &[Light]) -> Vec<[u32; 8]> {
        lights
            .iter()
            .map(|l| {
                let f = |v: f32| v.to_bits();
                [
                    l.id,
                    f(l.dir[0]),
                    f(l.dir[1]),
                    f(l.dir[2]),
                    f(l.rgb[0]),
                    f(l.rgb[1]),
                    f(l.rgb[2]),
                    f(l.solid_angle),
                ]
            })
            .collect()
    }

    #[test]
    fn windowed_search_equals_the_full_scan() {
        // Seeded xorshift: clusters of crowded lights (suns, lamps, some at the poles, where y
        // bunches up) among lights spread over the sphere, at several counts and radii.
        let mut unit = super::super::xorshift_unit(0x9e37_79b9_7f4a_7c15);
        for case in 0..60 {
            let n = [2, 7, 64, 256, 1024][case % 5];
            let mut lights = Vec::with_capacity(n);
            let centres: Vec<DVec3> = (0..4)
                .map(|k| match k {
                    0 => DVec3::Y,
                    1 => DVec3::NEG_Y,
                    _ => DVec3::new(unit() - 0.5, unit() - 0.5, unit() - 0.5),
                })
                .collect();
            for i in 0..n {
                let dir = if unit() < 0.3 {
                    let c = centres[i % centres.len()];
                    c + DVec3::new(unit() - 0.5, unit() - 0.5, unit() - 0.5) * 0.03
                } else {
                    DVec3::new(unit() - 0.5, unit() - 0.5, unit() - 0.5)
                };
                // Every third set has repeated ids and luminances, to pin the order of ties.
                let (id, power) = if case % 3 == 0 {
                    ((i % 7) as u32, (unit() * 4.0).floor() as f32)
                } else if unit() < 0.1 {
                    (i as u32, 0.0)
                } else {
                    (i as u32, (unit() * 50.0) as f32)
                };
                lights.push(light(id, dir, power));
            }
            for fraction in [0.05, 0.1, 0.5, 2.0] {
                assert_eq!(
                    bits(&merge_crowded(&lights, fraction)),
                    bits(&merge_by_full_scan(&lights, fraction)),
                    "case {case}, {n} lights, fraction {fraction}"
                );
            }
        }
    }

    #[test]
    fn a_light_without_a_finite_direction_is_merged_as_before() {
        for bad in [
            [f32::NAN, 0.0, 0.0],
            [0.0, f32::NAN, 0.0],
            [f32::INFINITY, 0.5, 0.5],
        ] {
            for (at, power) in [(0, 1.0), (2, 1.0), (2, 9.0)] {
                let mut lights = vec![
                    light(0, DVec3::X, 5.0),
                    light(1, DVec3::Y, 1.0),
                    light(3, DVec3::new(0.2, -0.9, 0.1), 2.0),
                ];
                lights.insert(
                    at,
                    Light {
                        id: 2,
                        dir: bad,
                        rgb: [power; 3],
                        solid_angle: 0.001,
                    },
                );
                assert_eq!(
                    bits(&merge_crowded(&lights, 0.1)),
                    bits(&merge_by_full_scan(&lights, 0.1)),
                    "{bad:?} at {at}, power {power}"
                );
            }
        }
    }

    #[test]
    fn nothing_to_merge_returns_the_input() {
        let lights = vec![light(0, DVec3::X, 1.0), light(1, DVec3::Y, 1.0)];
        assert_eq!(merge_crowded(&lights, DEFAULT_SPACING_FRACTION), lights);
        assert_eq!(merge_crowded(&[], 0.25), vec![]);
    }
}
