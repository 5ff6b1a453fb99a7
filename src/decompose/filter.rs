//! Temporal FIR low-pass filtering of every light's trajectory and power, by light id.
//!
//! Havran et al. 2005 filter each light's motion over the sphere and its power with a
//! perception-inspired low-pass FIR filter, because even a local change of the map moves every
//! light a little. For light id i the output is
//! `rgb = Σ_k w_k · rgb_i(t−k)` (and the same for the solid angle) and
//! `dir = normalise(Σ_k w_k · P_i(t−k) · dir_i(t−k))`, with normalised taps w_k (w_0 applies to
//! the newest frame) and P the light's luminance: the direction is the *power-weighted* mean
//! over the window, the temporal counterpart of placing a light at its region's energy
//! centroid. (Where all P are 0, the plain mean of the directions.)
//!
//! Why weighted: a light can change role from one frame to the next — with the row-by-row warp,
//! a point in the sun's row of the map slides from the sun to the sky beside it when the sun
//! dims or crosses the map's seam. An unweighted mean then sends most of the sun's power, still
//! in the power history, towards the sky for several frames, and the shadows it casts sweep.
//! Weighted, the light keeps pointing at the sun while the sun's power fades out of its window.
//! On the built-in sky with the sun in view this lowered the ground-shadow flicker from 0.0132 to
//! 0.0088 (docs/quality.md, "Temporal stability").
//!
//! Default taps: the binomial kernel [1, 6, 15, 20, 15, 6, 1]/64, a Gaussian of σ ≈ 1.22 frames.
//! At 30 frames/s its gain is cos⁶(πf/30): −3 dB at ≈ 3.2 Hz, 1/64 (−36 dB) at 10 Hz. Temporal
//! contrast sensitivity peaks around 8–20 Hz (de Lange curves), so the band where flicker is most
//! visible is removed while slow lighting changes pass. Being symmetric, it delays by exactly
//! (7 − 1)/2 = 3 frames (100 ms at 30 frames/s); [`FirFilter::delay_frames`] reports the group
//! delay Σ k·w_k of any taps.
//!
//! An id that is missing from a frame (a smaller light count, say) loses its history; when it
//! returns, its history restarts from its first new value, so no stale position leaks in. Ids
//! may be any u32: those of a decomposition index a table, larger ones (fading lights' ids fed
//! back into a filter, say) a map that forgets the ids missing from the last frame.
//!
//! **Bright lights** ([`BrightHistory`]). A sun or a lamp of a few input pixels is shared by a
//! few lights, and its pixels change hands between them from frame to frame (light 12 holds
//! pixel p in frame t, light 40 holds it in t+1). A per-id mean then blends two pixels into a
//! direction where the map has nothing, and the hard shadows the lights cast flicker: on the
//! built-in sky with the sun in view, the plain per-id filter flickered 1.8× more than no filter
//! (docs/quality.md, "What the filter's flicker is"). So the window of a light brighter than
//! [`BRIGHT_FACTOR`] × the frame's mean light is first grouped in cones of [`BRIGHT_CONE_DEG`]
//! (less than an input pixel), newest sample first, each sample joining the first group whose
//! power-weighted direction lies within the cone:
//!
//! 1. the group holding the newest sample is the light (its taps' share of rgb, solid angle and
//!    power-weighted direction);
//! 2. each older group — a place the light held before — is, with [`BrightHistory::Fold`] (the
//!    default), added to the light that is nearest to it in this frame (power-weighted
//!    direction, summed rgb and solid angle): the energy stays where it was, ids and count stay
//!    those of the point set; with [`BrightHistory::Fade`] it is sent as an extra light of its
//!    own, id [`FADING_ID_BASE`] + parent id × [`MAX_TAPS`] + (frame of its newest sample mod
//!    [`MAX_TAPS`]), that fades out as its samples leave the window (steadier still, but a few
//!    per cent more lights, with ids outside the point set).
//!
//! Lights at or below the threshold, and all lights with [`BrightHistory::Blend`] (the filter
//! before 2026-12-01), take the per-id mean above. Energy is filtered exactly either way:
//! Σ rgb of the output is Σ_k w_k Σ rgb(t−k) for ids present throughout the window.

use crate::light::Light;
use glam::DVec3;

/// The default taps (binomial, 7 taps, delay 3 frames).
pub const DEFAULT_TAPS: [f64; 7] = [1.0, 6.0, 15.0, 20.0, 15.0, 6.0, 1.0];

/// Most taps accepted.
pub const MAX_TAPS: usize = 64;

/// Ids below this have their histories in a table indexed by id (a decomposition's ids are
/// below [`super::MAX_POINTS`]); larger ones, in a map.
const DENSE_IDS: usize = 1 << 20;

/// A light brighter than this × the frame's mean light has its window grouped in cones
/// ([`BrightHistory`]). Measured on the temporal table's four sequences, factors 4 to 30 gave the
/// same flicker, and 2 on the sky sequences too; 0.5 groups many sky lights, whose largest
/// moves per frame then triple (docs/quality.md).
pub const BRIGHT_FACTOR: f64 = 10.0;

/// The cone of a bright light's groups, in degrees: less than an input pixel of a 1024-wide map
/// (0.35°), so samples that held different pixels of a sun stay apart. On the built-in sky's
/// sequences (512 wide, 0.70° pixels) 0.03° to 0.3° measured the same; 1° gives the per-id
/// mean's flicker (docs/quality.md).
pub const BRIGHT_CONE_DEG: f64 = 0.1;

/// Ids of [`BrightHistory::Fade`]'s extra lights start here, above every point-set index.
pub const FADING_ID_BASE: u32 = 1 << 24;

/// What the filter does with the window of a light brighter than [`BRIGHT_FACTOR`] × the frame's
/// mean light (the module doc has the steps).
#[derive(Clone, Copy, Debug, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum BrightHistory {
    /// The per-id power-weighted mean, as for every other light (the filter before
    /// 2026-12-01; recordings made before then read as this).
    Blend,
    /// Grouped in cones; the light keeps the group of its newest sample and each older group
    /// goes to the light nearest to it now. Ids and count stay those of the point set.
    Fold,
    /// Grouped in cones; the light keeps the group of its newest sample and each older group is
    /// an extra light with an id from [`FADING_ID_BASE`] that fades out over the window.
    Fade,
}

impl BrightHistory {
    /// Every value.
    pub const ALL: [BrightHistory; 3] = [Self::Blend, Self::Fold, Self::Fade];

    /// The name used in configs and on the command line.
    pub fn name(self) -> &'static str {
        match self {
            Self::Blend => "blend",
            Self::Fold => "fold",
            Self::Fade => "fade",
        }
    }
}

/// A light's power for weighting its direction: Rec. 709 luminance, negative parts as 0.
fn luminance(rgb: [f64; 3]) -> f64 {
    (0.2126 * rgb[0] + 0.7152 * rgb[1] + 0.0722 * rgb[2]).max(0.0)
}

#[derive(Clone, Copy, Debug, Default)]
struct Sample {
    dir: DVec3,
    rgb: [f64; 3],
    solid_angle: f64,
    /// [`luminance`] of `rgb`, the weight of `dir`: computed once, when the sample arrives.
    power: f64,
}

#[derive(Clone, Debug, Default)]
struct History {
    /// Ring of the last `taps.len()` samples; `head` is the newest.
    ring: Vec<Sample>,
    head: usize,
    /// Frame counter value when this id was last seen.
    last_seen: Option<u64>,
}

/// Tap-weighted sums over some of a window's samples: a whole window for the per-id mean, one
/// cone of it for a bright light.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct Group {
    /// Σ w·P·dir.
    power_weighted_dir: DVec3,
    /// Σ w·dir: the direction where the group has no power.
    plain_dir: DVec3,
    rgb: [f64; 3],
    solid_angle: f64,
    /// Position in the window (0: this frame) of the group's newest sample.
    newest: usize,
}

impl Group {
    fn add(&mut self, w: f64, s: &Sample) {
        self.power_weighted_dir += (w * s.power) * s.dir;
        self.plain_dir += w * s.dir;
        for (sum, c) in self.rgb.iter_mut().zip(s.rgb) {
            *sum += w * c;
        }
        self.solid_angle += w * s.solid_angle;
    }

    /// Adds another group's sums (its taps' weights already applied).
    fn add_folded(&mut self, other: &Group) {
        self.power_weighted_dir += other.power_weighted_dir;
        self.plain_dir += other.plain_dir;
        for (sum, c) in self.rgb.iter_mut().zip(other.rgb) {
            *sum += c;
        }
        self.solid_angle += other.solid_angle;
    }

    /// The power-weighted mean direction; without power in the group (or with an overflow),
    /// the plain mean; `None` where the directions cancel.
    fn direction(&self) -> Option<DVec3> {
        self.power_weighted_dir
            .try_normalize()
            .or_else(|| self.plain_dir.try_normalize())
    }

    pub(super) fn add_light(&mut self, l: &Light) {
        let rgb = l.rgb.map(f64::from);
        self.add(
            1.0,
            &Sample {
                dir: light_dir(l),
                rgb,
                solid_angle: l.solid_angle.into(),
                power: luminance(rgb),
            },
        );
    }

    /// The group as a light with `id` (`fallback` where its direction is undefined).
    pub(super) fn to_light(self, id: u32, fallback: DVec3) -> Light {
        let dir = self.direction().unwrap_or(fallback);
        Light {
            id,
            dir: [dir.x as f32, dir.y as f32, dir.z as f32],
            rgb: self.rgb.map(|c| crate::light::saturating_f32(c.max(0.0))),
            solid_angle: self.solid_angle.max(0.0) as f32,
        }
    }
}

pub(super) fn light_dir(l: &Light) -> DVec3 {
    DVec3::new(l.dir[0].into(), l.dir[1].into(), l.dir[2].into())
}

/// The nearest light to a direction, among one frame's lights: the largest dot product, ties
/// to the later light. By a plain scan for a few queries; for many (a large light count with
/// many bright lights) through the lights sorted by y, looking only as far from the query's y
/// as the best match so far allows (|Δy| ≤ |d − l|, and |d − l|² = 2 − 2 d·l for unit
/// vectors). Both give the same light.
pub(super) struct NearestLight {
    dirs: Vec<DVec3>,
    /// (y, position), sorted; empty for the plain scan.
    by_y: Vec<(f64, usize)>,
}

impl NearestLight {
    /// Queries × lights above which the lights are sorted by y.
    const SORT_ABOVE: usize = 1 << 15;

    /// Room for the f32 rounding of the lights' directions (|l|² = 1 ± 4·10⁻⁷) in the bound.
    const SLACK: f64 = 1e-6;

    pub(super) fn new(lights: &[Light], queries: usize) -> Self {
        let dirs: Vec<DVec3> = lights.iter().map(light_dir).collect();
        let mut by_y = Vec::new();
        if queries.saturating_mul(lights.len()) > Self::SORT_ABOVE {
            by_y = dirs.iter().enumerate().map(|(i, d)| (d.y, i)).collect();
            by_y.sort_unstable_by(|a, b| a.0.total_cmp(&b.0).then(a.1.cmp(&b.1)));
        }
        Self { dirs, by_y }
    }

    /// Position of the light nearest to the unit vector `d` (0 if there is none).
    pub(super) fn nearest(&self, d: DVec3) -> usize {
        let mut best = (f64::NEG_INFINITY, 0usize);
        let consider = |best: &mut (f64, usize), i: usize| {
            let cos = self.dirs[i].dot(d);
            if cos > best.0 || (cos == best.0 && i > best.1) {
                *best = (cos, i);
            }
        };
        if self.by_y.is_empty() {
            for i in 0..self.dirs.len() {
                consider(&mut best, i);
            }
            return best.1;
        }
        let start = self.by_y.partition_point(|(y, _)| *y < d.y);
        let (mut up, mut down) = (start, start);
        loop {
            let reach = 2.0 - 2.0 * best.0 + Self::SLACK;
            let open = |k: usize| (self.by_y[k].0 - d.y).powi(2) <= reach;
            let go_up = up < self.by_y.len() && open(up);
            let go_down = down > 0 && open(down - 1);
            if !(go_up || go_down) {
                return best.1;
            }
            if go_up {
                consider(&mut best, self.by_y[up].1);
                up += 1;
            }
            if go_down {
                down -= 1;
                consider(&mut best, self.by_y[down].1);
            }
        }
    }
}

/// Group delay at low frequencies, in frames, of normalised `taps` (newest first): Σ k·w_k.
pub fn group_delay(taps: &[f64]) -> f64 {
    taps.iter().enumerate().map(|(k, w)| k as f64 * w).sum()
}

/// Per-id FIR filter over light lists.
#[derive(Clone, Debug)]
pub struct FirFilter {
    taps: Vec<f64>,
    /// Histories of ids below [`DENSE_IDS`], indexed by id (a decomposition's ids).
    histories: Vec<History>,
    /// Histories of larger ids (fading lights' ids fed back, say): pruned of ids not seen in
    /// the last frame, so memory stays bounded whatever ids arrive.
    sparse: std::collections::HashMap<u32, History>,
    frame: u64,
    bright: BrightHistory,
    /// Scratch: the cone groups of one bright light's window.
    groups: Vec<Group>,
    /// Scratch: this frame's older groups, with the position of the light they came from.
    older: Vec<(usize, Group)>,
}

impl FirFilter {
    /// A filter with the given taps (newest first). They must be 1..=64 finite, non-negative
    /// numbers, not all 0; they are normalised to sum to 1. Negative taps are refused: a
    /// light's power is a weighted sum of its history, and a negative weight makes energy (an
    /// overshoot that does not average out: taps −1,2 gave a still map 56% more power) and turns the
    /// direction average of a bright light's cone groups inside out.
    pub fn new(taps: &[f64]) -> Result<Self, String> {
        if taps.is_empty() || taps.len() > MAX_TAPS {
            return Err(format!("need 1..={MAX_TAPS} taps, got {}", taps.len()));
        }
        if let Some(bad) = taps.iter().find(|t| !t.is_finite()) {
            return Err(format!("tap {bad} is not a finite number"));
        }
        if let Some(bad) = taps.iter().find(|&&t| t < 0.0) {
            return Err(format!(
                "tap {bad} is negative; taps are non-negative weights"
            ));
        }
        // Scaled by the largest first, so taps near f64::MAX sum without overflow.
        let largest = taps.iter().fold(0.0f64, |m, &t| m.max(t));
        if largest <= 0.0 {
            return Err("taps are all 0; at least one must be positive".to_string());
        }
        let sum: f64 = taps.iter().map(|t| t / largest).sum();
        Ok(Self {
            taps: taps.iter().map(|t| t / largest / sum).collect(),
            histories: Vec::new(),
            sparse: std::collections::HashMap::new(),
            frame: 0,
            bright: BrightHistory::Fold,
            groups: Vec::new(),
            older: Vec::new(),
        })
    }

    /// The same filter treating bright lights' windows as `bright` says (default
    /// [`BrightHistory::Fold`]).
    pub fn with_bright_history(mut self, bright: BrightHistory) -> Self {
        self.bright = bright;
        self
    }

    /// How bright lights' windows are treated.
    pub fn bright_history(&self) -> BrightHistory {
        self.bright
    }

    /// The filter with [`DEFAULT_TAPS`].
    pub fn with_default_taps() -> Self {
        Self::new(&DEFAULT_TAPS).unwrap_or_else(|_| unreachable!("default taps are valid"))
    }

    /// The normalised taps, newest first.
    pub fn taps(&self) -> &[f64] {
        &self.taps
    }

    /// Group delay at low frequencies, in frames: Σ k·w_k. (T−1)/2 for symmetric taps.
    pub fn delay_frames(&self) -> f64 {
        group_delay(&self.taps)
    }

    /// Forgets all histories.
    pub fn reset(&mut self) {
        self.histories.clear();
        self.sparse.clear();
    }

    /// Filters one frame's lights (matched by id). With [`BrightHistory::Fade`], extra fading
    /// lights are appended, in id order, after the others; otherwise the list keeps its ids and
    /// length. Fading lights are only made when every id is below [`FADING_ID_BASE`] (always
    /// so for a [`super::Decomposer`]'s lights); otherwise their groups are folded.
    pub fn apply(&mut self, lights: &mut Vec<Light>) {
        let frame = self.frame;
        self.frame += 1;
        let n = self.taps.len();
        let bright_above = match self.bright {
            BrightHistory::Blend => f64::INFINITY,
            BrightHistory::Fold | BrightHistory::Fade => {
                let total: f64 = lights.iter().map(|l| luminance(l.rgb.map(f64::from))).sum();
                BRIGHT_FACTOR * total / lights.len().max(1) as f64
            }
        };
        let cone_cos = BRIGHT_CONE_DEG.to_radians().cos();
        let Self {
            taps,
            histories,
            sparse,
            groups,
            older,
            ..
        } = self;
        older.clear();
        for (position, light) in lights.iter_mut().enumerate() {
            let id = light.id as usize;
            if id < DENSE_IDS && id >= histories.len() {
                histories.resize_with(id + 1, History::default);
            }
            let rgb = light.rgb.map(f64::from);
            let sample = Sample {
                dir: light_dir(light),
                rgb,
                solid_angle: light.solid_angle.into(),
                power: luminance(rgb),
            };
            let h = match histories.get_mut(id) {
                Some(h) => h,
                None => sparse.entry(light.id).or_default(),
            };
            let continuing = frame > 0 && h.last_seen == Some(frame - 1);
            if !continuing {
                h.ring.clear();
                h.ring.resize(n, sample);
                h.head = 0;
            } else {
                h.head = (h.head + 1) % n;
                h.ring[h.head] = sample;
            }
            h.last_seen = Some(frame);

            // Newest first: head, head − 1, …, 0, then n − 1, …, head + 1.
            let (recent, earlier) = h.ring.split_at(h.head + 1);
            let newest_first = || recent.iter().rev().chain(earlier.iter().rev());

            if sample.power <= bright_above {
                // The per-id mean: the window as one group.
                let mut window = Group::default();
                for (w, s) in taps.iter().zip(newest_first()) {
                    window.add(*w, s);
                }
                *light = window.to_light(light.id, sample.dir);
                continue;
            }
            // A bright light: one group per cone, the first holding the newest sample.
            groups.clear();
            for (k, (w, s)) in taps.iter().zip(newest_first()).enumerate() {
                let joins = groups
                    .iter()
                    .position(|g| g.direction().unwrap_or(s.dir).dot(s.dir) >= cone_cos);
                let g = match joins {
                    Some(i) => &mut groups[i],
                    None => {
                        groups.push(Group {
                            newest: k,
                            ..Group::default()
                        });
                        let last = groups.len() - 1;
                        &mut groups[last]
                    }
                };
                g.add(*w, s);
            }
            *light = groups[0].to_light(light.id, sample.dir);
            older.extend(groups[1..].iter().map(|g| (position, *g)));
        }
        if sparse.len() > 2 * lights.len() {
            sparse.retain(|_, h| h.last_seen == Some(frame));
        }
        if older.is_empty() {
            return;
        }
        let fade =
            self.bright == BrightHistory::Fade && lights.iter().all(|l| l.id < FADING_ID_BASE);
        if fade {
            let first = lights.len();
            for &(parent, g) in older.iter() {
                // The frame of the group's newest sample, mod MAX_TAPS: distinct for the groups
                // of one window, and the same in every frame the group lives through.
                let slot = frame.wrapping_sub(g.newest as u64) % MAX_TAPS as u64;
                // parent id < 2^24, slot < 64: the id stays below 2^31.
                let id = FADING_ID_BASE + lights[parent].id * MAX_TAPS as u32 + slot as u32;
                let fallback = light_dir(&lights[parent]);
                lights.push(g.to_light(id, fallback));
            }
            lights[first..].sort_unstable_by_key(|l| l.id);
        } else {
            // Fold: each older group joins the light nearest to it now.
            let search = NearestLight::new(lights, older.len());
            let mut folded: Vec<(usize, Group)> = older
                .iter()
                .map(|&(parent, g)| {
                    // A group without a direction (its samples cancel) stays with its light.
                    let nearest = g.direction().map_or(parent, |d| search.nearest(d));
                    (nearest, g)
                })
                .collect();
            // Stable: a light's groups are added in the order they came.
            folded.sort_by_key(|(i, _)| *i);
            let mut sums: Vec<(usize, Group)> = Vec::new();
            for (i, g) in folded {
                match sums.last_mut() {
                    Some((last, sum)) if *last == i => sum.add_folded(&g),
                    _ => {
                        let mut sum = Group::default();
                        sum.add_light(&lights[i]);
                        sum.add_folded(&g);
                        sums.push((i, sum));
                    }
                }
            }
            for (i, sum) in sums {
                let fallback = light_dir(&lights[i]);
                lights[i] = sum.to_light(lights[i].id, fallback);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn light(id: u32, dir: [f32; 3], power: f32) -> Light {
        Light {
            id,
            dir,
            rgb: [power; 3],
            solid_angle: 0.01,
        }
    }

    #[test]
    fn constant_input_stays_constant() {
        let mut f = FirFilter::with_default_taps();
        for _ in 0..20 {
            let mut lights = vec![
                light(0, [0.0, 1.0, 0.0], 5.0),
                light(3, [0.6, 0.0, 0.8], 2.0),
            ];
            f.apply(&mut lights);
            assert!((lights[0].rgb[0] - 5.0).abs() < 1e-5);
            assert!((lights[1].dir[0] - 0.6).abs() < 1e-6 && (lights[1].dir[2] - 0.8).abs() < 1e-6);
        }
    }

    #[test]
    fn step_passes_with_the_stated_delay() {
        let mut f = FirFilter::with_default_taps();
        assert_eq!(f.delay_frames(), 3.0);
        let mut out = Vec::new();
        for t in 0..20 {
            let power = if t < 10 { 0.0 } else { 1.0 };
            let mut lights = vec![light(1, [0.0, 1.0, 0.0], power)];
            f.apply(&mut lights);
            out.push(lights[0].rgb[0]);
        }
        // Symmetric taps: the output reaches half the step exactly `delay` frames after it,
        // rises monotonically and settles at the new value once all taps see it.
        let half = 10 + f.delay_frames() as usize;
        assert!(
            out[half - 1] < 0.5 && out[half] >= 0.5 && out[half + 1] > 0.5,
            "{out:?}"
        );
        assert!(out.windows(2).all(|w| w[1] >= w[0]));
        assert_eq!(out[9], 0.0);
        assert!((out[16] - 1.0).abs() < 1e-6);
    }

    #[test]
    fn returning_id_restarts_from_its_new_value() {
        let mut f = FirFilter::with_default_taps();
        for _ in 0..10 {
            f.apply(&mut vec![light(7, [1.0, 0.0, 0.0], 1.0)]);
        }
        f.apply(&mut vec![light(2, [0.0, 1.0, 0.0], 1.0)]); // id 7 missing this frame
        let mut back = vec![light(7, [0.0, 0.0, 1.0], 9.0)];
        f.apply(&mut back);
        assert_eq!(back[0].dir, [0.0, 0.0, 1.0]);
        assert_eq!(back[0].rgb, [9.0; 3]);
    }

    #[test]
    fn direction_motion_is_smoothed_on_the_sphere() {
        let mut f = FirFilter::with_default_taps();
        let mut max_step = 0.0f32;
        let mut prev: Option<[f32; 3]> = None;
        for t in 0..30 {
            // The raw direction jitters by ±10° every frame.
            let a = if t % 2 == 0 { 0.17f32 } else { -0.17 };
            let mut l = vec![light(0, [a.sin(), a.cos(), 0.0], 1.0)];
            f.apply(&mut l);
            let d = l[0].dir;
            let len = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            assert!((len - 1.0).abs() < 1e-5);
            if let (Some(p), true) = (prev, t > 8) {
                max_step = max_step.max((p[0] - d[0]).abs());
            }
            prev = Some(d);
        }
        assert!(max_step < 0.02, "residual jitter {max_step}");
    }

    /// A light that leaves a bright source for a dim place keeps pointing at the source while
    /// the source's power fades out of its window (the direction is power-weighted); a plain
    /// mean of the directions would swing it halfway within three frames.
    #[test]
    fn a_light_leaving_a_bright_source_keeps_its_direction_while_its_power_fades() {
        let mut f = FirFilter::with_default_taps();
        let sun = [0.0, 0.6, -0.8];
        let sky = [0.8, 0.6, 0.0];
        for _ in 0..10 {
            f.apply(&mut vec![light(4, sun, 1000.0)]);
        }
        let mut powers = Vec::new();
        for t in 0..7 {
            let mut l = vec![light(4, sky, 1.0)];
            f.apply(&mut l);
            let cos_to_sun: f32 = l[0].dir.iter().zip(sun).map(|(a, b)| a * b).sum();
            powers.push(l[0].rgb[0]);
            // While the sun's power is in the window it dominates the direction: in the
            // sixth frame only the oldest tap (1/64) still holds it, 16 against 0.98.
            if t < 5 {
                assert!(cos_to_sun > 0.9999, "frame {t}: {:?}", l[0].dir);
            } else if t == 5 {
                assert!(cos_to_sun > 0.99, "frame {t}: {:?}", l[0].dir);
            } else {
                let cos_to_sky: f32 = l[0].dir.iter().zip(sky).map(|(a, b)| a * b).sum();
                assert!(cos_to_sky > 0.9999, "frame {t}: {:?}", l[0].dir);
            }
        }
        assert!(powers.windows(2).all(|w| w[1] < w[0]), "{powers:?}");
        // All powers 0: the plain mean of the directions.
        let mut dark = FirFilter::with_default_taps();
        let mut l = vec![light(1, sky, 0.0)];
        dark.apply(&mut l);
        assert_eq!(l[0].dir, sky);
    }

    /// A frame of a sun whose two pixels `a` and `b` (power 1000 each) are held by lights 0 and
    /// 1, which trade them every frame, beside 30 dim lights (power 1) elsewhere.
    fn traded_sun(t: usize, a: [f32; 3], b: [f32; 3]) -> Vec<Light> {
        let (first, second) = if t.is_multiple_of(2) { (a, b) } else { (b, a) };
        let mut lights = vec![light(0, first, 1000.0), light(1, second, 1000.0)];
        for i in 0..30u32 {
            let phi = i as f32 * 0.2;
            lights.push(light(2 + i, [phi.cos() * 0.6, -0.8, phi.sin() * 0.6], 1.0));
        }
        lights
    }

    fn angle_deg(a: [f32; 3], b: [f32; 3]) -> f64 {
        let dot: f64 = a
            .iter()
            .zip(b)
            .map(|(x, y)| f64::from(*x) * f64::from(y))
            .sum();
        dot.clamp(-1.0, 1.0).acos().to_degrees()
    }

    /// Two pixels of a sun, 0.3° apart, trade hands every frame. The per-id mean (`blend`)
    /// points both lights between them, where the map has nothing; `fold` keeps a light on each
    /// pixel with exactly that pixel's power, frame after frame (the older group of each light
    /// goes to the light that holds its pixel now); `fade` keeps the same directions and power
    /// at each pixel, spread over the lights and their fading extras.
    #[test]
    fn sun_pixels_that_change_hands_are_not_blended() {
        let half = 0.15f32.to_radians();
        let a = [half.sin(), half.cos(), 0.0];
        let b = [-half.sin(), half.cos(), 0.0];
        let power_at = |lights: &[Light], p: [f32; 3]| -> f32 {
            lights
                .iter()
                .filter(|l| angle_deg(l.dir, p) < 0.05)
                .map(|l| l.rgb[0])
                .sum()
        };
        for bright in BrightHistory::ALL {
            let mut f = FirFilter::with_default_taps().with_bright_history(bright);
            for t in 0..30 {
                let mut lights = traded_sun(t, a, b);
                f.apply(&mut lights);
                if t < 7 {
                    continue;
                }
                let total: f32 = lights.iter().map(|l| l.rgb[0]).sum();
                assert!(
                    (total - 2030.0).abs() < 0.01,
                    "{bright:?} frame {t}: Σ {total}"
                );
                let off_sun = lights[..2]
                    .iter()
                    .map(|l| angle_deg(l.dir, a).min(angle_deg(l.dir, b)))
                    .fold(0.0, f64::max);
                match bright {
                    BrightHistory::Blend => {
                        // 15/64 of the window on the other pixel: 0.3° × (1 − 2·29/64)·½.
                        assert!(off_sun > 0.01, "frame {t}: {off_sun}°");
                        assert_eq!(lights.len(), 32);
                    }
                    BrightHistory::Fold | BrightHistory::Fade => {
                        assert!(off_sun < 1e-4, "{bright:?} frame {t}: {off_sun}°");
                        for p in [a, b] {
                            let at = power_at(&lights, p);
                            assert!((at - 1000.0).abs() < 0.01, "{bright:?} frame {t}: {at}");
                        }
                        let extra = if bright == BrightHistory::Fade { 2 } else { 0 };
                        assert_eq!(lights.len(), 32 + extra, "{bright:?}");
                    }
                }
            }
        }
    }

    /// `fade`: a light that moves from one sun pixel to another leaves an extra light at the old
    /// pixel, with an id from FADING_ID_BASE that stays the same while it fades out over the
    /// window and carries the old samples' taps; Σ power is the filtered Σ throughout.
    #[test]
    fn a_fading_light_keeps_its_id_and_fades_out() {
        let half = 0.15f32.to_radians();
        let a = [half.sin(), half.cos(), 0.0];
        let b = [-half.sin(), half.cos(), 0.0];
        let mut f = FirFilter::with_default_taps().with_bright_history(BrightHistory::Fade);
        let mut fading = Vec::new();
        for t in 0..20 {
            // Light 0 holds pixel a until frame 9, pixel b from frame 10 on; light 1 the other.
            let mut lights = traded_sun(if t < 10 { 0 } else { 1 }, a, b);
            f.apply(&mut lights);
            assert!(lights.windows(2).all(|w| w[0].id < w[1].id));
            let extras: Vec<Light> = lights[32..].to_vec();
            assert!(extras.iter().all(|l| l.id >= FADING_ID_BASE));
            if (10..16).contains(&t) {
                // Light 0's group at a and light 1's at b, both last seen in frame 9.
                let ids: Vec<u32> = extras.iter().map(|l| l.id).collect();
                let slot = 9 % MAX_TAPS as u32;
                let want = vec![
                    FADING_ID_BASE + slot,
                    FADING_ID_BASE + MAX_TAPS as u32 + slot,
                ];
                assert_eq!(ids, want, "frame {t}");
                assert!(angle_deg(extras[0].dir, a) < 1e-4 && angle_deg(extras[1].dir, b) < 1e-4);
                fading.push(extras[0].rgb[0]);
            } else {
                assert!(extras.is_empty(), "frame {t}: {extras:?}");
            }
            let total: f32 = lights.iter().map(|l| l.rgb[0]).sum();
            assert!((total - 2030.0).abs() < 0.01, "frame {t}: Σ {total}");
        }
        // The old pixel's share: the taps the old samples still hold, 63/64 down to 1/64.
        let sum: f64 = DEFAULT_TAPS.iter().sum();
        for (k, got) in fading.iter().enumerate() {
            let want = 1000.0 * DEFAULT_TAPS[k + 1..].iter().sum::<f64>() / sum;
            assert!(
                (f64::from(*got) - want).abs() < 1e-3,
                "{k}: {got} against {want}"
            );
        }
    }

    /// Whatever the bright lights do, every mode filters the frame's energy exactly: Σ rgb of the
    /// output is Σ_k w_k Σ rgb(t − k), lights are finite and unit-length, and the ids of `fold`
    /// and `blend` are the input's.
    #[test]
    fn every_mode_filters_the_energy_exactly() {
        let mut next = super::super::xorshift_unit(0x9e37_79b9_7f4a_7c15);
        let frames: Vec<Vec<Light>> = (0..40)
            .map(|_| {
                (0..43u32)
                    .map(|id| {
                        // Four sun pixels shared by ids 0–2 (bright: more than 10× the mean
                        // light, about 70), sky for the rest.
                        let (pick, power) = if id < 3 {
                            (next() * 4.0, 500.0 + 1000.0 * next())
                        } else {
                            (100.0 + next() * 600.0, next() * 2.0)
                        };
                        let a = (pick.floor() * 0.003) as f32;
                        light(id, [a.sin(), a.cos(), 0.0], power as f32)
                    })
                    .collect()
            })
            .collect();
        let sum: f64 = DEFAULT_TAPS.iter().sum();
        let totals: Vec<f64> = frames
            .iter()
            .map(|l| l.iter().map(|l| f64::from(l.rgb[0])).sum())
            .collect();
        for bright in BrightHistory::ALL {
            let mut f = FirFilter::with_default_taps().with_bright_history(bright);
            let mut most = 0;
            for (t, frame) in frames.iter().enumerate() {
                let mut lights = frame.clone();
                f.apply(&mut lights);
                most = most.max(lights.len());
                let want: f64 = (0..7)
                    .map(|k| DEFAULT_TAPS[k] / sum * totals[t.saturating_sub(k)])
                    .sum();
                let got: f64 = lights.iter().map(|l| f64::from(l.rgb[0])).sum();
                assert!(
                    (got - want).abs() < 1e-5 * want,
                    "{bright:?} {t}: {got} {want}"
                );
                for l in &lights {
                    let len = l.dir.iter().map(|c| c * c).sum::<f32>().sqrt();
                    assert!((len - 1.0).abs() < 1e-5, "{bright:?} {l:?}");
                }
                if bright != BrightHistory::Fade {
                    let ids: Vec<u32> = lights.iter().map(|l| l.id).collect();
                    assert_eq!(ids, (0..43).collect::<Vec<_>>());
                }
            }
            if bright == BrightHistory::Fade {
                assert!(most > 43, "no fading light was made");
            }
        }
    }

    /// The y-sorted search finds the same light as the plain scan, ties (duplicate directions)
    /// and the poles included.
    #[test]
    fn sorted_nearest_search_equals_the_plain_scan() {
        let mut next = super::super::xorshift_unit(0x2545_f491_4f6c_dd1d);
        for n in [1usize, 2, 7, 300, 5000] {
            let mut lights: Vec<Light> = (0..n)
                .map(|i| {
                    let z = 2.0 * next() - 1.0;
                    let phi = std::f64::consts::TAU * next();
                    let r = (1.0 - z * z).sqrt();
                    let d = DVec3::new(r * phi.cos(), z, r * phi.sin()).as_vec3();
                    light(i as u32, d.to_array(), 1.0)
                })
                .collect();
            // Duplicates (ties go to the later light) and the poles.
            for k in 0..n / 10 {
                let copy = lights[k].dir;
                lights[n - 1 - k].dir = copy;
            }
            if n > 2 {
                lights[0].dir = [0.0, 1.0, 0.0];
                lights[1].dir = [0.0, -1.0, 0.0];
            }
            let plain = NearestLight::new(&lights, 0);
            let sorted = NearestLight::new(&lights, usize::MAX);
            assert!(plain.by_y.is_empty() && sorted.by_y.len() == n);
            let mut queries: Vec<DVec3> = lights.iter().take(50).map(light_dir).collect();
            queries.extend([DVec3::Y, -DVec3::Y, DVec3::X]);
            for _ in 0..200 {
                let q = DVec3::new(2.0 * next() - 1.0, 2.0 * next() - 1.0, 2.0 * next() - 1.0);
                queries.extend(q.try_normalize());
            }
            for q in queries {
                let q = q.normalize();
                assert_eq!(plain.nearest(q), sorted.nearest(q), "n {n}, query {q}");
            }
        }
    }

    /// Any u32 id is filtered as a small one (no table the size of the id), and the histories
    /// of large ids that stop coming are dropped, so memory stays bounded.
    #[test]
    fn large_ids_are_filtered_like_small_ones_in_bounded_memory() {
        let mut small = FirFilter::with_default_taps();
        let mut large = FirFilter::with_default_taps();
        for t in 0..20 {
            let a = t as f32 * 0.05;
            let frame = |ids: [u32; 3]| -> Vec<Light> {
                ids.iter()
                    .enumerate()
                    .map(|(k, &id)| light(id, [a.sin(), a.cos(), 0.0], 1.0 + k as f32 + a))
                    .collect()
            };
            let mut s = frame([1, 2, 3]);
            let mut l = frame([5, 1 << 30, u32::MAX]);
            small.apply(&mut s);
            large.apply(&mut l);
            for (a, b) in s.iter().zip(&l) {
                assert_eq!((a.dir, a.rgb), (b.dir, b.rgb), "frame {t}");
            }
        }
        assert!(large.histories.len() <= 6 && large.sparse.len() == 2);
        // A stream of ever-new large ids (fading ids fed back, say).
        for t in 0..1000u32 {
            large.apply(&mut vec![light(DENSE_IDS as u32 + t, [0.0, 1.0, 0.0], 1.0)]);
        }
        assert!(large.sparse.len() <= 3, "{}", large.sparse.len());
    }

    #[test]
    fn bad_taps_are_rejected() {
        assert!(FirFilter::new(&[]).is_err());
        assert!(FirFilter::new(&[1.0, f64::NAN]).is_err());
        assert!(FirFilter::new(&[1.0, -1.0]).is_err());
        assert!(FirFilter::new(&[1.0; 65]).is_err());
        assert!(FirFilter::new(&[0.0, 0.0]).is_err());
        // A positive sum does not make negative taps acceptable.
        let negative = FirFilter::new(&[-1.0, 2.0]).err().unwrap_or_default();
        assert!(negative.contains("tap -1 is negative"), "{negative}");
        assert_eq!(
            FirFilter::new(&[2.0, 2.0]).map(|f| f.taps().to_vec()),
            Ok(vec![0.5, 0.5])
        );
        // Taps whose sum overflows f64 are still normalised (they once all became 0).
        assert_eq!(
            FirFilter::new(&[1e308, 1e308, 0.0]).map(|f| f.taps().to_vec()),
            Ok(vec![0.5, 0.5, 0.0])
        );
    }
}
