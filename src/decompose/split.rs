//! Splitting the lights of bright lamps and suns (optional: [`super::DecomposeSettings::split_factor`]).
//!
//! The density luminance^γ with γ < 1 gives a small bright source fewer lights than its share
//! of the energy, so a lamp of a few input pixels holding 3% of the map can end up in one
//! light. As a point, that light casts one hard shadow edge where the lamp's pixels cast several
//! (docs/quality.md, "Why the five rows lost": median cut splits such a lamp down to its bright
//! pixels because its regions hold at most 1/N of the energy). This step gives such lights
//! more pieces and takes them from the weakest lights, so the count stays N. The plan is made
//! on each frame's unfiltered lights (ids 0..N) and applied after the temporal filter, so the
//! filter keeps following every light of the point set by its id:
//!
//! 1. A light is *bright* if its region holds at least two input pixels of a concentrated
//!    source ([`super::working_map::WorkingMap::fine`]) and more than `factor` × the mean
//!    light's energy (luminance). It asks for ⌈energy / (factor × mean)⌉ pieces, at most
//!    [`MAX_PIECES`] and at most its count of concentrated input pixels; the brightest lights
//!    are served first and at most N/8 extra pieces are made in all ([`MAX_EXTRA_FRACTION`]).
//! 2. A bright light's concentrated input pixels are split by luminance-weighted k-means on
//!    the sphere (seeds: the brightest input pixel, then farthest-point choice weighted by
//!    luminance; eight iterations); the rest of its region (its working pixels) goes whole to
//!    the piece nearest to its centroid. Every piece points at its luminance centroid. The
//!    pieces, in order of their azimuth about the light, keep the light's id (the first) or
//!    take [`SPLIT_ID_BASE`] + id × [`MAX_PIECES`] + j (j = 1…7).
//! 3. For every extra piece, the weakest of the unsplit lights (least energy, then lowest id)
//!    is removed: it goes whole to the nearest remaining unsplit light.
//! 4. After the filter (`SplitPlan::apply`): removed lights are added to their neighbours
//!    (energy and solid angle add, the direction is the luminance-weighted mean), and a split
//!    light's filtered energy and solid angle are shared among its pieces as the unfiltered
//!    ones were, the pieces keeping their offsets from the light.
//!
//! So the lights still sum to the map's integral. Measured in docs/quality.md ("The split of
//! bright lights, 2026-12-02"): 71 of the 72 rows against 69, but with the filter on, up to
//! 18% more ground flicker on the temporal table's sequences (the merged lights), so it is off
//! by default.

use super::filter::{light_dir, Group};
use super::working_map::FineSample;
use super::{luminance_f64, Region};
use crate::light::Light;
use glam::DVec3;

/// First id of the extra pieces of a split light: piece j (1…7) of light i has id
/// `SPLIT_ID_BASE + i × MAX_PIECES + j`. Above every sample id (< 2^14) and below the filter's
/// fading ids ([`super::filter::FADING_ID_BASE`], 2^24).
pub const SPLIT_ID_BASE: u32 = 1 << 23;

/// Most pieces one light splits into.
pub const MAX_PIECES: usize = 8;

/// At most this fraction of the light count is removed to make pieces.
pub const MAX_EXTRA_FRACTION: f64 = 0.125;

/// Default `factor`: a light holding a concentrated source and more than 3.5 × the mean
/// light's energy splits (docs/quality.md has the sweep).
pub const DEFAULT_SPLIT_FACTOR: f64 = 3.5;

/// k-means iterations per split light.
const KMEANS_ITERATIONS: usize = 8;

/// What the split does to one frame's lights, found on the unfiltered lights (ids 0..n) and
/// applied after the temporal filter ([`SplitPlan::apply`]), so the filter keeps following
/// every light of the point set by its id whatever the split does from frame to frame.
#[derive(Clone, Debug, Default, PartialEq)]
pub(super) struct SplitPlan {
    /// Per split light: its unfiltered light and its pieces (final ids, in order of azimuth;
    /// the first keeps the light's id). The pieces' energies sum to the light's.
    splits: Vec<(Light, Vec<Light>)>,
    /// (removed light's id, id of the light it goes to).
    merges: Vec<(u32, u32)>,
}

impl SplitPlan {
    /// The plan for lights `lights` (ids 0..n, light i from `regions[i]`): bright
    /// concentrated lights in pieces, as many of the weakest lights merged into their
    /// neighbours. `fine_labels[j]` is the light of concentrated input pixel `fine[j]` after
    /// the region pass. Empty when no light is bright.
    pub(super) fn new(
        lights: &[Light],
        regions: &[Region],
        fine: &[FineSample],
        fine_labels: &[u32],
        factor: f64,
    ) -> Self {
        let n = lights.len();
        if n < 2 || regions.len() != n || fine.is_empty() || fine_labels.len() != fine.len() {
            return Self::default();
        }
        let energy: Vec<f64> = regions.iter().map(|r| luminance_f64(r.rgb)).collect();
        let total: f64 = energy.iter().sum();
        let mean = total / n as f64;
        if !(mean > 0.0 && mean.is_finite()) {
            return Self::default();
        }

        // 1. Bright lights and their piece counts, brightest first, within the budget.
        let mut fine_count = vec![0usize; n];
        for &l in fine_labels {
            if let Some(c) = fine_count.get_mut(l as usize) {
                *c += 1;
            }
        }
        let mut bright: Vec<usize> = (0..n)
            .filter(|&i| fine_count[i] >= 2 && energy[i] > factor * mean)
            .collect();
        if bright.is_empty() {
            return Self::default();
        }
        bright.sort_by(|&a, &b| energy[b].total_cmp(&energy[a]).then(a.cmp(&b)));
        // At least one unsplit light stays to take the removed ones.
        let mut budget =
            ((n as f64 * MAX_EXTRA_FRACTION) as usize).min((n - bright.len()).saturating_sub(1));
        let mut pieces = vec![1usize; n];
        for &i in &bright {
            let wanted = (energy[i] / (factor * mean)).ceil() as usize;
            let wanted = wanted.min(MAX_PIECES).min(fine_count[i]).max(1);
            let extra = (wanted - 1).min(budget);
            pieces[i] = 1 + extra;
            budget -= extra;
        }
        if pieces.iter().all(|&k| k == 1) {
            return Self::default();
        }

        // 2. The bright lights' pieces (fewer than asked where the k-means leaves a part empty).
        let mut of_light: Vec<Vec<usize>> = vec![Vec::new(); n];
        for (j, &l) in fine_labels.iter().enumerate() {
            let l = l as usize;
            if l < n && pieces[l] > 1 {
                of_light[l].push(j);
            }
        }
        let mut splits = Vec::with_capacity(bright.len());
        for i in 0..n {
            if pieces[i] < 2 {
                continue;
            }
            let mut parts = split_samples(fine, &of_light[i], pieces[i]);
            if parts.len() < 2 {
                pieces[i] = 1;
                continue;
            }
            pieces[i] = parts.len();
            // The rest of the region (its working pixels) goes to the nearest piece.
            let mut rest = regions[i];
            for p in &parts {
                sub_region(&mut rest, p);
            }
            rest.rgb = rest.rgb.map(|c| c.max(0.0));
            rest.solid_angle = rest.solid_angle.max(0.0);
            let to = rest.centroid().map_or(0, |d| nearest_part(&parts, d));
            add_region(&mut parts[to], &rest);
            let parent = lights[i];
            let centre = light_dir(&parent);
            order_around(&mut parts, centre);
            let lights_of_parts = parts
                .iter()
                .enumerate()
                .map(|(j, p)| {
                    let id = if j == 0 {
                        parent.id
                    } else {
                        SPLIT_ID_BASE + (parent.id as usize * MAX_PIECES + j) as u32
                    };
                    p.to_light(id, p.centroid().unwrap_or(centre))
                })
                .collect();
            splits.push((parent, lights_of_parts));
        }
        let extra: usize = pieces.iter().map(|&k| k - 1).sum();
        if extra == 0 {
            return Self::default();
        }

        // 3. The weakest unsplit lights go to their nearest remaining unsplit neighbours.
        let mut weakest: Vec<usize> = (0..n).filter(|&i| pieces[i] == 1).collect();
        weakest.sort_by(|&a, &b| energy[a].total_cmp(&energy[b]).then(a.cmp(&b)));
        let mut removed = vec![false; n];
        for &i in weakest.iter().take(extra) {
            removed[i] = true;
        }
        let keepers: Vec<usize> = (0..n).filter(|&i| pieces[i] == 1 && !removed[i]).collect();
        let mut merges = Vec::with_capacity(extra);
        if !keepers.is_empty() {
            let keeper_lights: Vec<Light> = keepers.iter().map(|&i| lights[i]).collect();
            let search = super::filter::NearestLight::new(&keeper_lights, extra);
            for i in (0..n).filter(|&i| removed[i]) {
                let to = keepers[search.nearest(light_dir(&lights[i]))];
                merges.push((lights[i].id, lights[to].id));
            }
        }
        Self { splits, merges }
    }

    /// Whether the plan changes nothing.
    pub(super) fn is_empty(&self) -> bool {
        self.splits.is_empty() && self.merges.is_empty()
    }

    /// Applies the plan to `lights` (sorted by id; the unfiltered lights the plan was made
    /// from, or the filter's output for them): each removed light is added to its neighbour
    /// (energies and solid angles add, the direction is the luminance-weighted mean); each
    /// split light becomes its pieces, which share its energy per channel and its solid angle
    /// as the unfiltered pieces share the unfiltered light's, and keep their offsets from it
    /// (rotated with it). So the lights' total energy is unchanged. Lights not in the plan (a
    /// fading light of the filter) are kept; the result is sorted by id.
    pub(super) fn apply(&self, lights: &mut Vec<Light>) {
        if self.is_empty() {
            return;
        }
        let position = |lights: &[Light], id: u32| lights.binary_search_by_key(&id, |l| l.id).ok();
        let mut gone = vec![false; lights.len()];
        for &(from, to) in &self.merges {
            let (Some(f), Some(t)) = (position(lights, from), position(lights, to)) else {
                continue;
            };
            lights[t] = merged(&lights[t], &lights[f]);
            gone[f] = true;
        }
        let mut extra = Vec::new();
        for (raw_parent, raw_pieces) in &self.splits {
            let Some(p) = position(lights, raw_parent.id) else {
                continue;
            };
            let now = lights[p];
            let pieces = follow(raw_parent, raw_pieces, &now);
            let mut pieces = pieces.into_iter();
            if let Some(first) = pieces.next() {
                lights[p] = first;
            }
            extra.extend(pieces);
        }
        let mut kept: Vec<Light> = lights
            .iter()
            .zip(&gone)
            .filter_map(|(l, &g)| (!g).then_some(*l))
            .collect();
        kept.extend(extra);
        kept.sort_by_key(|l| l.id);
        *lights = kept;
    }
}

/// `raw_pieces` of `raw_parent`, moved onto `now` (the parent after the filter): each piece
/// takes the share of `now`'s energy (per channel) and solid angle that it had of the raw
/// parent's, and its direction turns with the parent's.
fn follow(raw_parent: &Light, raw_pieces: &[Light], now: &Light) -> Vec<Light> {
    let from = light_dir(raw_parent);
    let to = light_dir(now);
    let turn = match (from.try_normalize(), to.try_normalize()) {
        (Some(a), Some(b)) => glam::DQuat::from_rotation_arc(a, b),
        _ => glam::DQuat::IDENTITY,
    };
    let raw_lum = f64::from(raw_parent.luminance());
    let k = raw_pieces.len().max(1) as f64;
    let share = |piece: f64, whole: f64, piece_lum: f64| {
        if whole > 0.0 {
            piece / whole
        } else if raw_lum > 0.0 {
            piece_lum / raw_lum
        } else {
            1.0 / k
        }
    };
    raw_pieces
        .iter()
        .map(|piece| {
            let piece_lum = f64::from(piece.luminance());
            let mut rgb = [0.0f32; 3];
            for c in 0..3 {
                let f = share(
                    f64::from(piece.rgb[c]),
                    f64::from(raw_parent.rgb[c]),
                    piece_lum,
                );
                rgb[c] = (f64::from(now.rgb[c]) * f) as f32;
            }
            let sa = f64::from(now.solid_angle)
                * share(
                    f64::from(piece.solid_angle),
                    f64::from(raw_parent.solid_angle),
                    piece_lum,
                );
            let dir = (turn * light_dir(piece)).try_normalize().unwrap_or(to);
            Light {
                id: piece.id,
                dir: [dir.x as f32, dir.y as f32, dir.z as f32],
                rgb,
                solid_angle: sa as f32,
            }
        })
        .collect()
}

/// `a` and `b` as one light with `a`'s id: energies and solid angles add, the direction is
/// the filter's luminance-weighted mean ([`super::filter::Group`]; `a`'s where it is undefined).
fn merged(a: &Light, b: &Light) -> Light {
    let mut group = Group::default();
    group.add_light(a);
    group.add_light(b);
    group.to_light(a.id, light_dir(a))
}

/// Splits the concentrated input pixels `members` (indices into `fine`) into `k` regions by
/// luminance-weighted k-means on their directions. Returns the non-empty parts (at least one).
fn split_samples(fine: &[FineSample], members: &[usize], k: usize) -> Vec<Region> {
    let points: Vec<(DVec3, f64)> = members
        .iter()
        .map(|&j| {
            let s = &fine[j];
            let lum = luminance_f64(s.energy.map(f64::from)).max(0.0);
            (DVec3::from_array(s.dir.map(f64::from)), lum)
        })
        .collect();
    // Seeds: the brightest input pixel, then the one farthest (× its luminance) from all seeds;
    // ties go to the earlier pixel. `gap` is each pixel's 1 − cos to its nearest seed.
    let Some(first) = argmax_first(points.iter().map(|p| p.1)) else {
        return vec![Region::default()];
    };
    let mut centres: Vec<DVec3> = Vec::with_capacity(k);
    let mut gap = vec![f64::INFINITY; points.len()];
    let mut seed = first;
    loop {
        let c = points[seed].0;
        centres.push(c);
        for (g, p) in gap.iter_mut().zip(&points) {
            *g = g.min(1.0 - c.dot(p.0));
        }
        if centres.len() == k {
            break;
        }
        match argmax_first(gap.iter().zip(&points).map(|(g, p)| g * p.1)) {
            Some(j) if gap[j] * points[j].1 > 0.0 => seed = j,
            _ => break,
        }
    }
    let mut label = vec![usize::MAX; points.len()];
    for _ in 0..=KMEANS_ITERATIONS {
        let mut changed = false;
        for (slot, p) in label.iter_mut().zip(&points) {
            let nearest = nearest_dir(&centres, p.0);
            changed |= *slot != nearest;
            *slot = nearest;
        }
        if !changed {
            break;
        }
        let mut sums = vec![DVec3::ZERO; centres.len()];
        for (&c, p) in label.iter().zip(&points) {
            sums[c] += p.0 * p.1;
        }
        for (c, s) in centres.iter_mut().zip(sums) {
            if let Some(d) = s.try_normalize() {
                *c = d;
            }
        }
    }
    let mut parts = vec![Region::default(); centres.len()];
    let mut counts = vec![0usize; centres.len()];
    for (&c, &j) in label.iter().zip(members) {
        let s = &fine[j];
        let energy = s.energy.map(f64::from);
        let l = luminance_f64(energy);
        let r = &mut parts[c];
        for ch in 0..3 {
            r.rgb[ch] += energy[ch];
            r.weighted_dir[ch] += l * f64::from(s.dir[ch]);
        }
        r.solid_angle += f64::from(s.solid_angle);
        counts[c] += 1;
    }
    let parts: Vec<Region> = parts
        .into_iter()
        .zip(counts)
        .filter_map(|(p, c)| (c > 0).then_some(p))
        .collect();
    if parts.is_empty() {
        vec![Region::default()]
    } else {
        parts
    }
}

/// Orders the pieces of a light at `centre` by the azimuth of their centroids about it (from
/// the direction of +Y, or +X for a light near the poles, projected onto the tangent plane), so
/// that a lamp that moves a little keeps its pieces' ids.
fn order_around(parts: &mut [Region], centre: DVec3) {
    let reference = if centre.y.abs() < 0.99 {
        DVec3::Y
    } else {
        DVec3::X
    };
    let e1 = (reference - centre * centre.dot(reference)).normalize_or(DVec3::Z);
    let e2 = centre.cross(e1);
    let azimuth = |p: &Region| {
        let d = DVec3::from(p.weighted_dir);
        d.dot(e2).atan2(d.dot(e1))
    };
    parts.sort_by(|a, b| azimuth(a).total_cmp(&azimuth(b)));
}

/// Position of the largest value, the first of equal ones (`None` if there is none).
fn argmax_first(values: impl Iterator<Item = f64>) -> Option<usize> {
    let mut best: Option<(usize, f64)> = None;
    for (i, v) in values.enumerate() {
        if best.is_none_or(|(_, b)| v > b) {
            best = Some((i, v));
        }
    }
    best.map(|(i, _)| i)
}

fn nearest_dir(centres: &[DVec3], d: DVec3) -> usize {
    let mut best = (f64::NEG_INFINITY, 0);
    for (i, c) in centres.iter().enumerate() {
        let cos = c.dot(d);
        if cos > best.0 {
            best = (cos, i);
        }
    }
    best.1
}

fn nearest_part(parts: &[Region], d: DVec3) -> usize {
    let centres: Vec<DVec3> = parts.iter().map(|p| p.centroid().unwrap_or(d)).collect();
    nearest_dir(&centres, d)
}

fn add_region(to: &mut Region, from: &Region) {
    for c in 0..3 {
        to.rgb[c] += from.rgb[c];
        to.weighted_dir[c] += from.weighted_dir[c];
    }
    to.solid_angle += from.solid_angle;
}

fn sub_region(to: &mut Region, from: &Region) {
    for c in 0..3 {
        to.rgb[c] -= from.rgb[c];
        to.weighted_dir[c] -= from.weighted_dir[c];
    }
    to.solid_angle -= from.solid_angle;
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::decompose::{frame_integral, DecomposeSettings, Decomposer};
    use crate::envmap::Projection;
    use crate::frame::HdrFrame;

    /// A dim sky over a darker ground with rectangular lamps: (x, y, width, height, radiance).
    fn sky_with_lamps(lamps: &[(u32, u32, u32, u32, f32)]) -> HdrFrame {
        let (w, h) = (512u32, 256u32);
        let mut pixels = Vec::with_capacity((w * h) as usize);
        for y in 0..h {
            for x in 0..w {
                let sky = if y < h / 2 { 1.0 } else { 0.2 };
                let tint = 1.0 + 0.2 * ((x as f32 / w as f32) * std::f32::consts::TAU).sin();
                pixels.push([sky * tint, sky, sky * 1.1]);
            }
        }
        for &(x0, y0, lw, lh, radiance) in lamps {
            for y in y0..y0 + lh {
                for x in x0..x0 + lw {
                    pixels[(y * w + x) as usize] = [radiance, radiance * 0.9, radiance * 0.7];
                }
            }
        }
        HdrFrame::new(w, h, pixels, Projection::LatLong).expect("valid size")
    }

    fn lights_of(frame: &HdrFrame, n: usize, split: Option<f64>) -> Vec<Light> {
        let settings = DecomposeSettings {
            lights: n,
            filter_taps: None,
            merge_spacing_fraction: None,
            split_factor: split,
            ..DecomposeSettings::default()
        };
        Decomposer::new(settings).unwrap().decompose(frame).lights
    }

    fn direction_of_pixel(x: f64, y: f64) -> DVec3 {
        Projection::LatLong
            .pixel_to_direction(512, 256, x, y)
            .unwrap()
    }

    #[test]
    fn split_keeps_the_count_the_energy_and_distinct_sorted_ids() {
        let frame = sky_with_lamps(&[(100, 60, 4, 3, 2000.0), (300, 80, 3, 3, 800.0)]);
        let truth = frame_integral(&frame);
        for n in [16, 64, 256] {
            let lights = lights_of(&frame, n, Some(DEFAULT_SPLIT_FACTOR));
            assert_eq!(lights.len(), n);
            let mut sum = [0.0f64; 3];
            for l in &lights {
                for c in 0..3 {
                    sum[c] += f64::from(l.rgb[c]);
                }
                assert!(l.rgb.iter().all(|c| c.is_finite() && *c >= 0.0), "{l:?}");
                assert!(l.solid_angle >= 0.0, "{l:?}");
            }
            for c in 0..3 {
                assert!(
                    (sum[c] - truth[c]).abs() < 1e-5 * truth[c],
                    "n {n}: {sum:?} {truth:?}"
                );
            }
            assert!(
                lights.windows(2).all(|p| p[0].id < p[1].id),
                "n {n}: ids sorted"
            );
            let pieces: Vec<&Light> = lights.iter().filter(|l| l.id >= SPLIT_ID_BASE).collect();
            assert!(!pieces.is_empty(), "n {n}: the lamps split");
            assert!(pieces.len() <= (n as f64 * MAX_EXTRA_FRACTION) as usize);
            for p in pieces {
                // Every extra piece's parent is in the list too (it keeps the first piece).
                let parent = (p.id - SPLIT_ID_BASE) / MAX_PIECES as u32;
                assert!(
                    lights.iter().any(|l| l.id == parent),
                    "n {n}: parent of {}",
                    p.id
                );
            }
        }
    }

    /// The lamp's energy is shared by more lights, and every piece lies on the lamp.
    #[test]
    fn a_bright_lamp_gets_more_lights_on_it() {
        let frame = sky_with_lamps(&[(100, 60, 6, 4, 2000.0)]);
        let centre = direction_of_pixel(103.0, 62.0);
        let angle = |l: &Light| DVec3::from_array(l.dir.map(f64::from)).angle_between(centre);
        // The lamp spans 4.2° × 2.8°: its pixels are within 2.6° of its centre.
        let on_lamp = |lights: &[Light]| {
            lights
                .iter()
                .filter(|l| angle(l) < 2.6f64.to_radians())
                .count()
        };
        let plain = lights_of(&frame, 64, None);
        let split = lights_of(&frame, 64, Some(3.5));
        assert!(
            on_lamp(&split) > on_lamp(&plain),
            "{} lights on the lamp, {} without",
            on_lamp(&split),
            on_lamp(&plain)
        );
        let pieces: Vec<&Light> = split.iter().filter(|l| l.id >= SPLIT_ID_BASE).collect();
        assert!(!pieces.is_empty());
        for p in pieces {
            assert!(
                angle(p) < 2.6f64.to_radians(),
                "piece {} at {:.2}°",
                p.id,
                angle(p).to_degrees()
            );
        }
    }

    #[test]
    fn without_bright_sources_the_lights_are_unchanged() {
        let frame = sky_with_lamps(&[]);
        for n in [16, 256] {
            let plain = lights_of(&frame, n, None);
            let split = lights_of(&frame, n, Some(DEFAULT_SPLIT_FACTOR));
            assert_eq!(plain, split, "n {n}");
        }
        // A high factor leaves a lamp alone too.
        let frame = sky_with_lamps(&[(100, 60, 4, 3, 2000.0)]);
        assert_eq!(
            lights_of(&frame, 64, None),
            lights_of(&frame, 64, Some(1e9))
        );
    }

    /// Many lamps ask for more pieces than N/8: the brightest are served first and no more than
    /// N/8 lights are merged away.
    #[test]
    fn at_most_an_eighth_of_the_lights_are_merged_away() {
        let lamps: Vec<(u32, u32, u32, u32, f32)> = (0..12)
            .map(|i| {
                (
                    20 + 40 * i,
                    40 + 5 * (i % 4),
                    4,
                    4,
                    3000.0 + 100.0 * i as f32,
                )
            })
            .collect();
        let frame = sky_with_lamps(&lamps);
        let n = 64;
        let lights = lights_of(&frame, n, Some(1.0));
        assert_eq!(lights.len(), n);
        let pieces = lights.iter().filter(|l| l.id >= SPLIT_ID_BASE).count();
        assert_eq!(pieces, n / 8, "the budget is used up, not exceeded");
    }

    /// The same frame gives the same lights (no dependence on hash order or earlier frames).
    #[test]
    fn split_is_deterministic() {
        let frame = sky_with_lamps(&[(100, 60, 4, 3, 2000.0), (300, 80, 3, 3, 800.0)]);
        let settings = DecomposeSettings {
            lights: 64,
            filter_taps: None,
            split_factor: Some(DEFAULT_SPLIT_FACTOR),
            ..DecomposeSettings::default()
        };
        let mut d = Decomposer::new(settings).unwrap();
        let first = d.decompose(&frame).lights;
        let second = d.decompose(&frame).lights;
        assert_eq!(first, second);
        assert_eq!(first, lights_of(&frame, 64, Some(DEFAULT_SPLIT_FACTOR)));
    }

    #[test]
    fn the_split_needs_the_centroid_placement() {
        let settings = DecomposeSettings {
            split_factor: Some(DEFAULT_SPLIT_FACTOR),
            placement: crate::decompose::LightPlacement::SamplePoint,
            ..DecomposeSettings::default()
        };
        assert!(matches!(
            Decomposer::new(settings),
            Err(crate::decompose::DecomposeError::SplitPlacement)
        ));
    }

    #[test]
    fn bad_factors_are_refused() {
        for f in [0.5, f64::NAN, f64::INFINITY, -1.0] {
            let settings = DecomposeSettings {
                split_factor: Some(f),
                ..DecomposeSettings::default()
            };
            assert!(Decomposer::new(settings).is_err(), "{f}");
        }
    }
}
