//! Candidate lists for the region pass's nearest-light queries (the parent module has the
//! pass).
//!
//! Nearest-light queries use buckets of B×B working pixels: per frame, each bucket keeps the
//! lights that can be nearest to any point in it — those within d_min + 2r of its centre, where
//! d_min is the angle to the nearest light and r the bucket's angular radius (triangle
//! inequality) — so a pixel tests a handful of candidates instead of all N.
//!
//! The candidate lists are built with a margin δ ([`REUSE_MARGIN`]): as if every light could
//! move by up to δ, i.e. with bucket radius r + δ in both the reach and the bounds. By the
//! triangle inequality, a light that has moved by at most δ from where the lists were built and
//! is nearest to some point of the bucket is within d_min + 2r + 2δ of the centre, and no point
//! of the bucket is nearer to it than a − r − δ (a: its built angle from the centre). So the
//! lists stay valid, and the labels exact, while every light stays within δ of its direction at
//! the last build: the lists are then reused (only their copies of the light directions are
//! refreshed) and rebuilt in full as soon as one light has strayed further. A pixel's label is
//! the candidate with the largest dot product whatever the list, so the lights do not depend on
//! when the lists were built — except at an exact f32 tie of two lights' dot products, which
//! goes to the one earlier in the list. The lists are ordered as lists without margin are, so a
//! frame whose lists were built for it is labelled exactly as without the margin; a reused
//! list keeps the order of its build, so a tie could go the other way than in a fresh build
//! (none did in the tests' sequences; rooitou_park has one tied working pixel).
//! Where the lights move further than δ every frame (the margin then only costs: about 6% more
//! instructions per frame on rooitou_park), a build whose lists served one frame only is
//! followed by builds without margin, with the margin tried again every 16th build.
//! Where they drift slowly (a sun crossing the sky), the lists are rebuilt in stages rather
//! than all in one frame: once a light has moved 0.7 δ, new lists are built for the lights'
//! places then, a quarter of the buckets per frame, each bucket keeping its old list (valid for
//! the old places) until its new one is built ([`Candidates::update`]); a full build costs
//! about as much as the rest of the region pass, so this keeps it out of any single frame.
//!
//! The input pixels of a concentrated working pixel search a list of that pixel's own
//! ([`PixelCandidates`]), drawn from its bucket's where that is long. [`nearest`] is the scan
//! of a list that the per-pixel searches share.

use crate::decompose::working_map::WorkingMap;
use glam::{DVec3, Vec3};

pub(super) const BUCKET_PIXELS: usize = 8;

/// Working pixels per bucket.
pub(super) const CELLS: usize = BUCKET_PIXELS * BUCKET_PIXELS;

/// Margin δ (radians, about 1°) of the candidate lists: they are reused while no light has
/// moved further than this since they were built.
pub(in crate::decompose) const REUSE_MARGIN: f32 = 0.0175;

/// Buckets per super-bucket side: candidate lists are found for 4×4 buckets at once first.
const SUPER_BUCKETS: usize = 4;

/// Per-geometry bucket layout of a working map.
#[derive(Clone, Debug)]
pub struct BucketGrid {
    pub(super) width: usize,
    pub(super) height: usize,
    pub(super) cols: usize,
    pub(super) centres: Vec<Vec3>,
    /// Angular radius of each bucket (radians), with a small safety margin.
    pub(super) radii: Vec<f32>,
    /// Index of each bucket's super-bucket.
    super_of: Vec<u32>,
    super_centres: Vec<Vec3>,
    super_radii: Vec<f32>,
    /// Per bucket column, (sin φ, cos φ) of its pixels tiled over the bucket's 64 lanes (lane
    /// r·8 + k holds column k); columns past the map's edge repeat the last one.
    pub(super) column_tiles: Vec<[[f32; CELLS]; 2]>,
    /// Per bucket row, (sin θ, cos θ) of its pixels tiled over the 64 lanes (lane r·8 + k holds
    /// row r); rows past the map's edge repeat the last one.
    pub(super) row_tiles: Vec<[[f32; CELLS]; 2]>,
}

impl BucketGrid {
    /// The buckets of `map`'s geometry.
    pub fn new(map: &WorkingMap) -> Self {
        let (width, height) = (map.width, map.height);
        let tile = |trig: &[(f32, f32)], start: usize, lane: fn(usize) -> usize| {
            let at = |i: usize| trig[(start + lane(i)).min(trig.len() - 1)];
            [
                std::array::from_fn(|i| at(i).0),
                std::array::from_fn(|i| at(i).1),
            ]
        };
        let column_tiles = (0..width.div_ceil(BUCKET_PIXELS))
            .map(|bx| tile(&map.column_trig, bx * BUCKET_PIXELS, |i| i % BUCKET_PIXELS))
            .collect();
        let row_tiles = (0..height.div_ceil(BUCKET_PIXELS))
            .map(|by| tile(&map.row_trig, by * BUCKET_PIXELS, |i| i / BUCKET_PIXELS))
            .collect();
        let cols = width.div_ceil(BUCKET_PIXELS);
        let rows = height.div_ceil(BUCKET_PIXELS);
        let cap = |x0: usize, y0: usize, x1: usize, y1: usize| {
            bounding_cap(width, height, (x0, y0), (x1.min(width), y1.min(height)))
        };
        let (mut centres, mut radii, mut super_of) = (Vec::new(), Vec::new(), Vec::new());
        let super_cols = cols.div_ceil(SUPER_BUCKETS);
        for by in 0..rows {
            for bx in 0..cols {
                let (c, r) = cap(
                    bx * BUCKET_PIXELS,
                    by * BUCKET_PIXELS,
                    (bx + 1) * BUCKET_PIXELS,
                    (by + 1) * BUCKET_PIXELS,
                );
                centres.push(c);
                radii.push(r);
                super_of.push(((by / SUPER_BUCKETS) * super_cols + bx / SUPER_BUCKETS) as u32);
            }
        }
        let (mut super_centres, mut super_radii) = (Vec::new(), Vec::new());
        let span = SUPER_BUCKETS * BUCKET_PIXELS;
        for sy in 0..rows.div_ceil(SUPER_BUCKETS) {
            for sx in 0..super_cols {
                let (c, r) = cap(sx * span, sy * span, (sx + 1) * span, (sy + 1) * span);
                super_centres.push(c);
                super_radii.push(r);
            }
        }
        Self {
            width,
            height,
            cols,
            centres,
            radii,
            super_of,
            super_centres,
            super_radii,
            column_tiles,
            row_tiles,
        }
    }
}

impl BucketGrid {
    /// The bucket of working pixel `pixel` (row-major index).
    pub(super) fn bucket_of(&self, pixel: usize) -> usize {
        let (x, y) = (pixel % self.width, pixel / self.width);
        (y / BUCKET_PIXELS) * self.cols + x / BUCKET_PIXELS
    }
}

/// Centre direction and angular radius (with a small safety margin) of the lat-long pixel
/// rectangle [x0, x1) × [y0, y1). The farthest point of such a rectangle from its centre lies
/// on its border, which is sampled densely.
fn bounding_cap(
    width: usize,
    height: usize,
    (x0, y0): (usize, usize),
    (x1, y1): (usize, usize),
) -> (Vec3, f32) {
    let dir = |x: f64, y: f64| {
        crate::envmap::Projection::LatLong
            .pixel_to_direction(width as u32, height as u32, x, y)
            .unwrap_or(DVec3::Y)
    };
    let (x0, y0, x1, y1) = (x0 as f64, y0 as f64, x1 as f64, y1 as f64);
    let c = dir(0.5 * (x0 + x1), 0.5 * (y0 + y1));
    let mut radius = 0.0f64;
    let steps = 32;
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
    (c.as_vec3(), (radius * 1.05 + 1e-4) as f32)
}

/// Directions as three coordinate arrays plus their light ids, so that the dot products of
/// one direction with all of them vectorise.
#[derive(Default)]
struct DirSet {
    x: Vec<f32>,
    y: Vec<f32>,
    z: Vec<f32>,
    id: Vec<u32>,
}

impl DirSet {
    fn clear(&mut self) {
        self.x.clear();
        self.y.clear();
        self.z.clear();
        self.id.clear();
    }

    fn push(&mut self, id: u32, d: Vec3) {
        self.x.push(d.x);
        self.y.push(d.y);
        self.z.push(d.z);
        self.id.push(id);
    }

    fn len(&self) -> usize {
        self.id.len()
    }
}

/// `dots[i] = centre · set[range][i]` and the reach threshold: the dot product of `centre` with
/// a light at (nearest angle + 2·radius), i.e. the smallest dot product of a light that can be
/// nearest to some point of the cap (triangle inequality).
#[inline(always)]
fn reach(
    centre: Vec3,
    radius: f32,
    set: &DirSet,
    range: std::ops::Range<usize>,
    dots: &mut Vec<f32>,
) -> f32 {
    dots.clear();
    let (x, y, z) = (&set.x[range.clone()], &set.y[range.clone()], &set.z[range]);
    dots.extend(
        x.iter()
            .zip(y)
            .zip(z)
            .map(|((x, y), z)| centre.x * x + centre.y * y + centre.z * z),
    );
    // Eight running maxima (so the loop vectorises), then their maximum.
    let mut m = [-1.0f32; 8];
    let chunks = dots.chunks_exact(8);
    for &d in chunks.remainder() {
        m[0] = m[0].max(d);
    }
    for chunk in chunks {
        for (m, &d) in m.iter_mut().zip(chunk) {
            *m = if d > *m { d } else { *m };
        }
    }
    reach_threshold(m.into_iter().fold(-1.0f32, f32::max), radius)
}

/// The reach threshold of a cap of angular radius `radius` whose nearest light has dot product
/// `best` with its centre: the dot product of a light at (nearest angle + 2·radius), with a
/// little slack (−2 when that reaches the whole sphere).
#[inline(always)]
fn reach_threshold(best: f32, radius: f32) -> f32 {
    let reach = best.clamp(-1.0, 1.0).acos() + 2.0 * radius;
    if reach >= std::f32::consts::PI {
        -2.0
    } else {
        reach.cos() - 1e-6
    }
}

/// The bound of a [`Candidate`] of a cap of angular radius `radius`, from its dot product `d`
/// with the cap's centre: cos(max(0, a − r)) for a = acos d, plus a little slack.
#[inline(always)]
fn cap_bound(radius: f32) -> impl Fn(f32) -> f32 {
    let (sin_r, cos_r) = radius.sin_cos();
    move |d: f32| {
        let cos_a = d.clamp(-1.0, 1.0);
        // cos(a − r) = cos a cos r + sin a sin r for a ∈ [r, π]; 1 within the cap.
        let b = cos_a * cos_r + (1.0 - cos_a * cos_a).max(0.0).sqrt() * sin_r;
        (if cos_a >= cos_r { 1.0 } else { b }) + 1e-6
    }
}

/// A light that may be nearest to some point of a bucket, with an upper bound of its dot
/// product with any direction in the bucket.
#[derive(Clone, Copy, Debug)]
pub(super) struct Candidate {
    /// The light's direction, kept inline so a scan touches one array.
    pub(super) dir: Vec3,
    pub(super) light: u32,
    /// cos(max(0, a − r)) where a is the light's angle from the bucket centre and r the bucket's
    /// radius: no direction in the bucket is closer to the light than that.
    pub(super) bound: f32,
}

/// Per-bucket candidate lights for one frame, nearest to the bucket centre first. The buffers
/// are kept between frames.
#[derive(Default)]
pub(super) struct Candidates {
    offsets: Vec<u32>,
    list: Vec<Candidate>,
    /// Every light, then the candidates of each super-bucket (`super_offsets`).
    all: DirSet,
    supers: DirSet,
    super_offsets: Vec<usize>,
    dots: Vec<f32>,
    /// Positions (in the set searched) of the bucket's candidates that pass the reach test.
    passing: Vec<u32>,
    /// Sort keys of a bucket's candidates: falling bound, then rising position.
    keys: Vec<u64>,
    /// Per bucket, the reach threshold of its candidates: a light whose dot product with the
    /// bucket's centre is below it cannot be nearest to any point of the bucket.
    thresholds: Vec<f32>,
    /// The lights and the grid size (width, height) the lists were built for.
    built_lights: Vec<Vec3>,
    /// The lights whose directions the candidates hold (those of the last frame).
    dirs_of: Vec<Vec3>,
    built_grid: (usize, usize),
    /// Whether lists may be reused between frames (off: rebuilt every frame).
    pub(super) no_reuse: bool,
    /// Full builds so far.
    pub(super) builds: u64,
    /// Staged rebuilds begun so far, and those whose last buckets had to be built at once
    /// (the previous lists' lights strayed before the stages were through).
    pub(super) staged_builds: u64,
    stages_cut_short: u64,
    /// The margin of the last build (0 or [`REUSE_MARGIN`]), the frames that reused it, and
    /// the number of builds in a row without margin.
    margin: f32,
    reuses: u32,
    bare_builds: u32,
    /// During a staged rebuild: the buckets `0..converted` have lists in `list` (built for
    /// `built_lights`), the others still those of the previous build in `prev_list` (built for
    /// `prev_built_lights`). Otherwise every bucket's list is in `list` (`converted` is the
    /// bucket count).
    converted: usize,
    prev_list: Vec<Candidate>,
    prev_offsets: Vec<u32>,
    prev_thresholds: Vec<f32>,
    prev_built_lights: Vec<Vec3>,
}

/// After a build whose lists were not reused even once, the next lists are built without margin
/// (the margin costs about 6% more instructions per frame in longer lists and looser bounds),
/// and stay so for this many builds before the margin is tried again.
const BARE_BUILDS: u32 = 15;

/// A staged rebuild begins once some light has moved this share of the margin from where the
/// lists were built (while every light is still within the margin of it).
const STAGE_START: f32 = 0.7;

/// A staged rebuild builds the buckets' lists in this many frames.
const STAGES: usize = 4;

impl Candidates {
    /// Makes the lists valid for `lights`: the last frame's lists when every light is within
    /// the margin of their build of where it was then (on the same grid), else new ones. Lists
    /// built without margin are reused only for exactly the same lights. When lights move
    /// further than the margin every frame (a turning map), the margin would only cost, so
    /// after a build that served a single frame the lists are built without it for
    /// [`BARE_BUILDS`] builds.
    ///
    /// So that no single frame pays for a whole build while the lights drift slowly (a sun
    /// crossing the sky; a full build costs about as much as the rest of the region pass), the
    /// lists are rebuilt in stages: once some light has moved [`STAGE_START`] of the margin
    /// from where the lists were built, new lists are built for the lights where they are
    /// then, a [`STAGES`]th of the buckets per frame, while the other buckets keep their old
    /// lists. Each list is valid while every light stays within the margin of the places it
    /// was built for, which is checked for both sets of places every frame; if the old ones
    /// fail first, the rest of the buckets are built at once; if the new ones fail (lights
    /// moving fast), everything is built afresh.
    #[inline(always)]
    pub(super) fn update(&mut self, grid: &BucketGrid, lights: &[Vec3]) {
        // Checked with 90% of the margin: the f32 dot products of nearly equal directions are
        // not exact.
        let cos_check = if self.margin > 0.0 {
            (0.9 * self.margin).cos()
        } else {
            f32::INFINITY
        };
        let within = |built: &[Vec3], cos: f32| {
            lights
                .iter()
                .zip(built)
                .all(|(l, b)| l == b || l.dot(*b) >= cos)
        };
        let buckets = grid.centres.len();
        let comparable = !self.no_reuse
            && self.built_grid == (grid.width, grid.height)
            && self.built_lights.len() == lights.len();
        if comparable && within(&self.built_lights, cos_check) {
            let staging = self.converted < buckets;
            if staging && !within(&self.prev_built_lights, cos_check) {
                self.build_stage(grid, buckets);
                self.stages_cut_short += 1;
            } else if staging {
                self.build_stage(grid, self.converted + buckets.div_ceil(STAGES));
            } else if self.margin > 0.0
                && !within(&self.built_lights, (STAGE_START * self.margin).cos())
            {
                self.begin_stages(grid, lights);
                self.build_stage(grid, buckets.div_ceil(STAGES));
            }
            // The lists' copies of the directions, unless they are this frame's already (a
            // static scene: the same lights every frame).
            if self.dirs_of != lights {
                for c in self.list.iter_mut().chain(&mut self.prev_list) {
                    c.dir = lights[c.light as usize];
                }
                self.dirs_of.clear();
                self.dirs_of.extend_from_slice(lights);
            }
            self.reuses += 1;
            return;
        }
        let bare = self.builds > 0 && self.reuses == 0 && self.bare_builds < BARE_BUILDS;
        self.bare_builds = if bare { self.bare_builds + 1 } else { 0 };
        self.margin = if bare { 0.0 } else { REUSE_MARGIN };
        self.build(grid, lights, self.margin);
        self.converted = buckets;
        self.prev_list.clear();
        self.built_lights.clear();
        self.built_lights.extend_from_slice(lights);
        self.dirs_of.clear();
        self.dirs_of.extend_from_slice(lights);
        self.built_grid = (grid.width, grid.height);
        self.builds += 1;
        self.reuses = 0;
    }

    /// Begins a staged rebuild for `lights`: the current lists become the previous ones and
    /// the super-buckets' candidates are found for `lights` (they serve every stage).
    fn begin_stages(&mut self, grid: &BucketGrid, lights: &[Vec3]) {
        std::mem::swap(&mut self.list, &mut self.prev_list);
        std::mem::swap(&mut self.offsets, &mut self.prev_offsets);
        std::mem::swap(&mut self.thresholds, &mut self.prev_thresholds);
        std::mem::swap(&mut self.built_lights, &mut self.prev_built_lights);
        self.built_lights.clear();
        self.built_lights.extend_from_slice(lights);
        self.list.clear();
        self.offsets.clear();
        self.thresholds.clear();
        self.offsets.push(0);
        self.converted = 0;
        let built = std::mem::take(&mut self.built_lights);
        self.build_supers(grid, &built, self.margin);
        self.built_lights = built;
        self.staged_builds += 1;
    }

    /// Builds the lists of the buckets `converted..until` (capped at the bucket count) for
    /// `built_lights`; when the last bucket is built, the previous lists are dropped.
    #[inline(always)]
    fn build_stage(&mut self, grid: &BucketGrid, until: usize) {
        let until = until.min(grid.centres.len());
        let built = std::mem::take(&mut self.built_lights);
        for b in self.converted..until {
            let s = grid.super_of[b] as usize;
            let range = self.super_offsets[s]..self.super_offsets[s + 1];
            let threshold =
                self.bucket_list(grid.centres[b], grid.radii[b], self.margin, range, &built);
            self.thresholds.push(threshold);
            self.offsets.push(self.list.len() as u32);
        }
        self.built_lights = built;
        self.converted = until;
        if until == grid.centres.len() {
            self.prev_list.clear();
        }
        // The new lists hold the places they were built for: refresh every copy.
        self.dirs_of.clear();
    }

    /// Candidate lists of every bucket: first per super-bucket among all lights, then per bucket
    /// among its super-bucket's candidates (a bucket lies inside its super-bucket, so its
    /// candidates are among those). Inlined into the region pass, so compiled for its vector
    /// unit.
    #[inline(always)]
    fn build(&mut self, grid: &BucketGrid, lights: &[Vec3], margin: f32) {
        self.build_supers(grid, lights, margin);
        self.offsets.clear();
        self.list.clear();
        self.thresholds.clear();
        self.offsets.push(0);
        for ((&c, &r), &s) in grid.centres.iter().zip(&grid.radii).zip(&grid.super_of) {
            let range = self.super_offsets[s as usize]..self.super_offsets[s as usize + 1];
            let threshold = self.bucket_list(c, r, margin, range, lights);
            self.thresholds.push(threshold);
            self.offsets.push(self.list.len() as u32);
        }
    }

    /// The candidates of every super-bucket among all `lights` (with the margin).
    #[inline(always)]
    fn build_supers(&mut self, grid: &BucketGrid, lights: &[Vec3], margin: f32) {
        self.all.clear();
        for (i, &l) in lights.iter().enumerate() {
            self.all.push(i as u32, l);
        }
        self.supers.clear();
        self.super_offsets.clear();
        self.super_offsets.push(0);
        // Every radius is widened by the margin (see the module doc).
        for (&c, &r) in grid.super_centres.iter().zip(&grid.super_radii) {
            let r = r + margin;
            let threshold = reach(c, r, &self.all, 0..self.all.len(), &mut self.dots);
            for (i, &d) in self.dots.iter().enumerate() {
                if d >= threshold {
                    self.supers.push(self.all.id[i], lights[i]);
                }
            }
            self.super_offsets.push(self.supers.len());
        }
    }

    /// Appends the candidates of the cap (`centre`, `radius` + `margin`) among the lights
    /// `range` of `self.supers` to `self.list` and returns the reach threshold. Their bounds are
    /// those of the widened cap; their order is that of falling bounds of the cap without the
    /// margin (the same order of distance from the centre, so the widened bounds fall along the
    /// list too),
    /// which is the order a list without margin has: an exact tie of two lights' dot products
    /// at a pixel goes to the same light with or without the margin.
    #[inline(always)]
    fn bucket_list(
        &mut self,
        centre: Vec3,
        radius: f32,
        margin: f32,
        range: std::ops::Range<usize>,
        lights: &[Vec3],
    ) -> f32 {
        let Candidates {
            supers,
            dots,
            passing,
            keys,
            list,
            ..
        } = self;
        let set = &*supers;
        let threshold = reach(centre, radius + margin, set, range.clone(), dots);
        // The candidates that pass (branch-free compaction: every index is written, the count
        // moves on for those that pass, which ones do being unpredictable), then their bounds:
        // typically a third of the super-bucket's candidates pass.
        passing.resize(dots.len(), 0);
        let mut count = 0;
        for (k, &d) in dots.iter().enumerate() {
            passing[count] = k as u32;
            count += usize::from(d >= threshold);
        }
        passing.truncate(count);
        let (order_bound, bound) = (cap_bound(radius), cap_bound(radius + margin));
        keys.clear();
        keys.extend(
            passing
                .iter()
                .map(|&k| falling_key(order_bound(dots[k as usize]), k as usize)),
        );
        // Sorting the 8-byte keys (branch-free small-sort networks in the standard library)
        // gives the order of a stable sort by falling bound.
        keys.sort_unstable();
        let start = list.len();
        for &key in keys.iter() {
            let k = key as u32 as usize;
            let i = set.id[range.start + k];
            list.push(Candidate {
                dir: lights[i as usize],
                light: i,
                bound: bound(dots[k]),
            });
        }
        prune_dominated(list, start, centre, radius, margin);
        threshold
    }

    /// Whether `bucket`'s list is in `list` (built for `built_lights`), not in `prev_list`: it
    /// is unless a staged rebuild has not reached it yet. (A `Candidates` whose lists are
    /// only ever built by `bucket_list`, as the refinement's are, has no previous lists.)
    #[inline]
    fn is_current(&self, bucket: usize) -> bool {
        bucket < self.converted || self.prev_list.is_empty()
    }

    #[inline]
    pub(super) fn of(&self, bucket: usize) -> &[Candidate] {
        let (list, offsets) = if self.is_current(bucket) {
            (&self.list, &self.offsets)
        } else {
            (&self.prev_list, &self.prev_offsets)
        };
        &list[offsets[bucket] as usize..offsets[bucket + 1] as usize]
    }

    /// The reach threshold of `bucket`'s list (see `thresholds`).
    #[inline]
    pub(super) fn threshold(&self, bucket: usize) -> f32 {
        if self.is_current(bucket) {
            self.thresholds[bucket]
        } else {
            self.prev_thresholds[bucket]
        }
    }

    /// Starts exact lists (no margin, not kept between frames) drawn among all of `lights` on
    /// demand, one bucket at a time ([`Self::exact_list`]): the refinement's, which needs
    /// lists only for the buckets that hold concentrated pixels.
    pub(super) fn begin_exact(&mut self, lights: &[Vec3]) {
        self.supers.clear();
        for (i, &l) in lights.iter().enumerate() {
            self.supers.push(i as u32, l);
        }
        self.list.clear();
    }

    /// Appends the exact list of `bucket` among the lights of [`Self::begin_exact`] (the same
    /// `lights`) and returns where it lies, for [`Self::exact`].
    #[inline(always)]
    pub(super) fn exact_list(
        &mut self,
        grid: &BucketGrid,
        bucket: usize,
        lights: &[Vec3],
    ) -> (u32, u32) {
        let start = self.list.len();
        let all = 0..self.supers.len();
        self.bucket_list(grid.centres[bucket], grid.radii[bucket], 0.0, all, lights);
        (start as u32, self.list.len() as u32)
    }

    /// An exact list made by [`Self::exact_list`].
    #[inline]
    pub(super) fn exact(&self, (start, end): (u32, u32)) -> &[Candidate] {
        &self.list[start as usize..end as usize]
    }
}

/// How many of a list's first candidates (those nearest the bucket's centre) are tried as
/// dominators of the others in [`prune_dominated`].
const DOMINATORS: usize = 8;

/// Lists of at most this many candidates are not pruned: their labelling is cheap already.
const PRUNE_FROM: usize = 16;

/// Drops from `list[start..]` the candidates that cannot be nearest to any direction of the cap
/// (`centre`, `radius`) because a candidate among the first [`DOMINATORS`] is nearer to every
/// direction of it, by at least T = 2·`margin` + 10⁻⁵ in dot product.
///
/// The reach test alone keeps every light within d_min + 2r of the centre. Where a dense group
/// of lights (the lamps of a studio) lies just beyond the nearest light, that is the whole group
/// (up to 130 candidates per bucket on studio_small_03), although only its side facing the bucket
/// can be nearest to any of its pixels. Light L is dominated by M when p·(M − L) ≥ T for every p
/// in the cap; with v = M − L at angle α from the centre, the smallest p·v over the cap is
/// |v|·cos(α + r) = (c·v)·cos r − √(|v|² − (c·v)²)·sin r. T keeps the test true while both
/// lights move by up to the margin (each dot product changes by at most the margin) and covers
/// the rounding of the labelling's f32 dot products, so a dropped light is never a pixel's
/// nearest nor tied with it, and the labels are those of the unpruned list. A dominator dropped
/// itself is dominated by an earlier one, which then dominates what it dominated (with 2T).
/// Order is kept, so the lists still come in falling order of their bounds.
#[inline(always)]
fn prune_dominated(
    list: &mut Vec<Candidate>,
    start: usize,
    centre: Vec3,
    radius: f32,
    margin: f32,
) {
    if list.len() - start <= PRUNE_FROM {
        return;
    }
    let (sin_r, cos_r) = radius.sin_cos();
    let slack = 2.0 * margin + 1e-5;
    let dominators: [Vec3; DOMINATORS] = std::array::from_fn(|k| list[start + k].dir);
    let mut write = start;
    for read in start..list.len() {
        let candidate = list[read];
        let earlier = (read - start).min(DOMINATORS);
        let dominated = dominators[..earlier].iter().any(|&m| {
            let v = m - candidate.dir;
            let cv = centre.dot(v);
            let head = cv * cos_r - slack;
            head > 0.0 && head * head >= sin_r * sin_r * (v.length_squared() - cv * cv).max(0.0)
        });
        if !dominated {
            list[write] = candidate;
            write += 1;
        }
    }
    list.truncate(write);
}

/// Sort key of candidate `k` with bound `bound`: ascending keys are falling bounds, ties in
/// rising `k`.
#[inline(always)]
fn falling_key(bound: f32, k: usize) -> u64 {
    let bits = bound.to_bits();
    // Unsigned order of the float's total order, then reversed.
    let rising = if bits & 0x8000_0000 != 0 {
        !bits
    } else {
        bits | 0x8000_0000
    };
    (u64::from(!rising) << 32) | k as u64
}

/// The candidate light nearest to `d`. `hint` (any light, typically the previous pixel's) seeds
/// the search; candidates come nearest-to-the-bucket-centre first, so the search stops once no
/// remaining candidate's bound can beat the best dot product found.
#[inline]
pub(super) fn nearest(candidates: &[Candidate], lights: &[Vec3], d: Vec3, hint: usize) -> usize {
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

/// Centre direction and angular radius of working pixel `pixel` (row-major). The radius bounds
/// the distance from the centre to any direction of the pixel by the path along the centre's
/// meridian (half the row's height in θ) and then along a parallel (half the column's width in
/// φ times the largest sin θ of the row), with a little slack for f32 rounding.
#[inline(always)]
fn pixel_cap(map: &WorkingMap, pixel: usize) -> (Vec3, f32) {
    let (x, y) = (pixel % map.width, pixel / map.width);
    let (sin_t, cos_t) = map.row_trig[y];
    let (sin_p, cos_p) = map.column_trig[x];
    let half_theta = std::f32::consts::PI / (2 * map.height) as f32;
    let half_phi = std::f32::consts::PI / map.width as f32;
    // sin θ over the row: at most sin θc·cos h + |cos θc|·sin h ≤ sin θc + |cos θc|·h.
    let max_sin = (sin_t + cos_t.abs() * half_theta).min(1.0);
    let radius = (half_theta + half_phi * max_sin) * 1.001 + 1e-5;
    (Vec3::new(sin_t * sin_p, cos_t, -sin_t * cos_p), radius)
}

/// The candidate lights of one concentrated working pixel, for its input pixels' nearest-light
/// searches. A bucket's list is drawn for a cap eight pixels wide; where a lamp's lights crowd
/// inside it, their bounds are all 1 and a search scans the whole list. The pixel's own cap is
/// an eighth as wide, so its list is short: it is searched in full, in the bucket list's order
/// (no bounds, no sort).
#[derive(Default)]
pub(super) struct PixelCandidates {
    ids: Vec<u32>,
    dots: Vec<f32>,
    list: Vec<Candidate>,
}

impl PixelCandidates {
    /// The candidates of concentrated working pixel `pixel` among those of its bucket. Short
    /// lists are searched as they are: the bounds of a bucket with few candidates end the
    /// searches early enough.
    #[inline(always)]
    pub(super) fn of<'a>(
        &'a mut self,
        map: &WorkingMap,
        pixel: usize,
        bucket_list: &'a [Candidate],
        lights: &[Vec3],
    ) -> &'a [Candidate] {
        if bucket_list.len() <= PRUNE_FROM {
            return bucket_list;
        }
        let (centre, radius) = pixel_cap(map, pixel);
        let ids = bucket_list.iter().map(|c| c.light);
        self.gather(centre, radius, ids, lights)
    }

    /// The lights among `ids` that can be nearest to some direction of the cap (`centre`,
    /// `radius`) — those within d_min + 2·radius of the centre, as in [`reach`] — in the order
    /// of `ids`, with bounds that never stop a search.
    #[inline(always)]
    fn gather(
        &mut self,
        centre: Vec3,
        radius: f32,
        ids: impl Iterator<Item = u32>,
        lights: &[Vec3],
    ) -> &[Candidate] {
        self.ids.clear();
        self.ids.extend(ids);
        self.dots.clear();
        self.dots
            .extend(self.ids.iter().map(|&i| centre.dot(lights[i as usize])));
        let best = self.dots.iter().copied().fold(-1.0f32, f32::max);
        let threshold = reach_threshold(best, radius);
        self.list.clear();
        for (&light, &d) in self.ids.iter().zip(&self.dots) {
            if d >= threshold {
                self.list.push(Candidate {
                    dir: lights[light as usize],
                    light,
                    // Above any dot product: the list is not ordered by bound, so
                    // [`nearest`] scans all of it (it is short).
                    bound: 2.0,
                });
            }
        }
        &self.list
    }
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;

    /// A small deterministic generator (xorshift), for reproducible light sets.
    struct Rng(u64);

    impl Rng {
        fn unit(&mut self) -> f32 {
            self.0 ^= self.0 << 13;
            self.0 ^= self.0 >> 7;
            self.0 ^= self.0 << 17;
            (self.0 >> 40) as f32 / (1u64 << 24) as f32
        }

        /// A direction within `angle` radians of `axis`.
        fn near(&mut self, axis: Vec3, angle: f32) -> Vec3 {
            let (u, v) = axis.any_orthonormal_pair();
            let a = angle * self.unit().sqrt();
            let phi = std::f32::consts::TAU * self.unit();
            (axis * a.cos() + (u * phi.cos() + v * phi.sin()) * a.sin()).normalize()
        }
    }

    /// Index of the light with the largest dot product with `p` among `ids` (the first on a tie).
    pub(in crate::decompose::regions) fn argmax(
        lights: &[Vec3],
        ids: impl Iterator<Item = u32>,
        p: Vec3,
    ) -> u32 {
        let mut best = (f32::NEG_INFINITY, u32::MAX);
        for i in ids {
            let d = lights[i as usize].dot(p);
            if d > best.0 {
                best = (d, i);
            }
        }
        best.1
    }

    /// Every direction of a working pixel lies within [`pixel_cap`]'s radius of its centre
    /// (the pixel's border sampled densely, on every row of a small map: the pole rows are the
    /// widest), and the radius is not much larger than the farthest corner (so the lists stay
    /// short).
    #[test]
    fn pixel_caps_hold_their_pixels() {
        use crate::decompose::working_map::Resampler;
        use crate::envmap::Projection;
        let resampler = Resampler::new(Projection::LatLong, 64, 32, 64);
        let map = resampler.map_for_tests();
        let (w, h) = (map.width, map.height);
        for y in 0..h {
            for x in [0, 17, w - 1] {
                let (centre, radius) = pixel_cap(map, y * w + x);
                let mut farthest = 0.0f32;
                for k in 0..=64 {
                    let t = k as f64 / 64.0;
                    for (u, v) in [(t, 0.0), (t, 1.0), (0.0, t), (1.0, t)] {
                        let d = Projection::LatLong
                            .pixel_to_direction(w as u32, h as u32, x as f64 + u, y as f64 + v)
                            .unwrap()
                            .as_vec3();
                        let angle = centre.dot(d).clamp(-1.0, 1.0).acos();
                        farthest = farthest.max(angle);
                    }
                }
                assert!(
                    farthest <= radius,
                    "row {y} column {x}: {farthest} > {radius}"
                );
                assert!(
                    radius <= 1.6 * farthest + 1e-4,
                    "row {y}: {radius} for {farthest}"
                );
            }
        }
    }

    /// A concentrated pixel's own list ([`PixelCandidates::of`]) gives every direction of the
    /// pixel the same nearest light as its bucket's list and as all lights, with lights
    /// crowding the pixel (a lamp's) and a sparse background.
    #[test]
    fn pixel_lists_keep_every_directions_nearest_light() {
        use crate::decompose::working_map::Resampler;
        use crate::envmap::Projection;
        let resampler = Resampler::new(Projection::LatLong, 256, 128, 256);
        let map = resampler.map_for_tests();
        let grid = BucketGrid::new(map);
        let mut rng = Rng(0x2545_f491_4f6c_dd1d);
        let (mut shorter, mut cases) = (0, 0);
        for case in 0..60 {
            let pixel = (rng.unit() * (map.width * map.height) as f32) as usize;
            let (centre, radius) = pixel_cap(map, pixel);
            let mut lights: Vec<Vec3> = (0..100)
                .map(|_| rng.near(Vec3::Y, std::f32::consts::PI))
                .collect();
            lights.extend((0..40).map(|_| rng.near(centre, 8.0 * radius)));
            let bucket = grid.bucket_of(pixel);
            let mut candidates = Candidates::default();
            candidates.begin_exact(&lights);
            let range = candidates.exact_list(&grid, bucket, &lights);
            let bucket_list = candidates.exact(range).to_vec();
            let mut pixel_candidates = PixelCandidates::default();
            let list = pixel_candidates
                .of(map, pixel, &bucket_list, &lights)
                .to_vec();
            cases += 1;
            shorter += usize::from(list.len() < bucket_list.len());
            let (x, y) = (pixel % map.width, pixel / map.width);
            for trial in 0..100 {
                // A direction inside the pixel itself, not inside its cap: a cap too small
                // would lose the nearest light of the pixel's corners.
                let (u, v) = (f64::from(rng.unit()), f64::from(rng.unit()));
                let (w, h) = (map.width as u32, map.height as u32);
                let p = Projection::LatLong
                    .pixel_to_direction(w, h, x as f64 + u, y as f64 + v)
                    .unwrap()
                    .as_vec3();
                let all = argmax(&lights, 0..lights.len() as u32, p) as usize;
                let hint = (trial * 7) % lights.len();
                let found = nearest(&list, &lights, p, hint);
                assert_eq!(
                    lights[all].dot(p),
                    lights[found].dot(p),
                    "case {case} trial {trial}: nearest light {all}, the pixel list's {found}"
                );
            }
        }
        assert!(
            shorter * 2 > cases,
            "{shorter} of {cases} pixel lists shorter"
        );
    }

    /// Studio-like light sets — a dense group of lights just beyond the nearest one from a
    /// bucket — lose most of their candidates to [`prune_dominated`], and the nearest light to
    /// every direction of the bucket stays the same, also after every light has moved by up to
    /// the margin the lists were built with.
    #[test]
    fn pruned_candidates_keep_every_directions_nearest_light() {
        let mut rng = Rng(0x9e37_79b9_7f4a_7c15);
        let (mut kept, mut total) = (0usize, 0usize);
        for case in 0..40 {
            let centre = rng.near(Vec3::Y, std::f32::consts::PI);
            let radius = 0.02 + 0.12 * rng.unit();
            let margin = if case % 2 == 0 { 0.0 } else { REUSE_MARGIN };
            // A sparse background, and a dense group 20-60° away from the bucket.
            let group_axis = {
                let far = rng.near(centre, 1.0);
                let (u, _) = centre.any_orthonormal_pair();
                (centre * (0.35 + 0.7 * rng.unit()).cos() + u * 0.8 + far * 0.1).normalize()
            };
            let mut lights: Vec<Vec3> = (0..60)
                .map(|_| rng.near(Vec3::Y, std::f32::consts::PI))
                .collect();
            lights.extend((0..150).map(|_| rng.near(group_axis, 0.15)));
            let mut candidates = Candidates::default();
            for (i, &l) in lights.iter().enumerate() {
                candidates.supers.push(i as u32, l);
            }
            candidates.bucket_list(centre, radius, margin, 0..lights.len(), &lights);
            let list = &candidates.list;
            // The unpruned list: every light passing the reach threshold.
            let all = 0..lights.len();
            let threshold = reach(
                centre,
                radius + margin,
                &candidates.supers,
                all,
                &mut Vec::new(),
            );
            let reached = lights
                .iter()
                .filter(|l| centre.dot(**l) >= threshold)
                .count();
            assert!(list.len() <= reached, "case {case}");
            (kept, total) = (kept + list.len(), total + reached);
            for trial in 0..200 {
                // After a move of up to 0.9 margin (the reuse check's limit) for every light.
                let moved: Vec<Vec3> = if trial % 2 == 0 {
                    lights.clone()
                } else {
                    lights.iter().map(|&l| rng.near(l, 0.9 * margin)).collect()
                };
                let p = rng.near(centre, radius * 0.999);
                let all = argmax(&moved, 0..lights.len() as u32, p);
                let pruned = argmax(&moved, list.iter().map(|c| c.light), p);
                assert_eq!(
                    moved[all as usize].dot(p),
                    moved[pruned as usize].dot(p),
                    "case {case} trial {trial}: nearest light {all}, pruned list's {pruned}"
                );
            }
        }
        // The group beyond the nearest light is mostly dropped.
        assert!(
            kept * 2 < total,
            "{kept} of {total} reached candidates kept"
        );
    }

    /// Staged rebuilds keep every bucket's list exact: lights drifting on great circles at
    /// speeds that let the stages finish, then at speeds that cut them short (the previous
    /// lists' lights stray before the last stage), one light jumping further than the margin
    /// in a frame (a full build, also mid-stage), and every light moving in two steps and then
    /// standing still while the last stages are built; every frame, every pixel's nearest light
    /// through its bucket's list (at the pixel's centre and four inner points) is the nearest
    /// of all lights, and each path ran.
    #[test]
    fn staged_rebuilds_keep_every_list_exact() {
        use crate::decompose::working_map::Resampler;
        use crate::envmap::Projection;
        let resampler = Resampler::new(Projection::LatLong, 96, 48, 96);
        let map = resampler.map_for_tests();
        let grid = BucketGrid::new(map);
        let mut rng = Rng(0x2545_f491_4f6c_dd1d);
        let n = 150;
        let start: Vec<Vec3> = (0..n)
            .map(|_| rng.near(Vec3::Y, std::f32::consts::PI))
            .collect();
        let axes: Vec<Vec3> = start.iter().map(|s| s.any_orthonormal_vector()).collect();
        let slow: Vec<f32> = (0..n).map(|_| 0.04 * REUSE_MARGIN * rng.unit()).collect();
        let fast: Vec<f32> = (0..n).map(|_| 0.2 * REUSE_MARGIN * rng.unit()).collect();
        let mut angles = vec![0.0f32; n];
        let mut candidates = Candidates::default();
        let (w, h) = (map.width as u32, map.height as u32);
        for frame in 0..150 {
            for (i, a) in angles.iter_mut().enumerate() {
                *a += match frame {
                    0..60 => slow[i],
                    60..110 => fast[i],
                    // Light 0 jumps 3 margins: a full build, also in the middle of stages.
                    _ if i == 0 && frame % 20 == 0 => 3.0 * REUSE_MARGIN,
                    110..120 => slow[i],
                    // After a full build (light 0 at frame 120) and still frames, every light
                    // 0.72 margins (a staged build begins), then 0.1 more (the next stage), then
                    // still: the last stages are built, for places the lights have left, while
                    // nothing moves.
                    130 => 0.72 * REUSE_MARGIN,
                    131 => 0.1 * REUSE_MARGIN,
                    _ => 0.0,
                };
            }
            let lights: Vec<Vec3> = (0..n)
                .map(|i| glam::Quat::from_axis_angle(axes[i], angles[i]) * start[i])
                .collect();
            candidates.update(&grid, &lights);
            for pixel in 0..map.width * map.height {
                let list = candidates.of(grid.bucket_of(pixel));
                let (x, y) = ((pixel % map.width) as f64, (pixel / map.width) as f64);
                for (u, v) in [(0.5, 0.5), (0.1, 0.1), (0.9, 0.1), (0.1, 0.9), (0.9, 0.9)] {
                    let p = Projection::LatLong
                        .pixel_to_direction(w, h, x + u, y + v)
                        .unwrap()
                        .as_vec3();
                    let all = argmax(&lights, 0..n as u32, p) as usize;
                    let found = nearest(list, &lights, p, list[0].light as usize);
                    assert_eq!(
                        lights[all].dot(p),
                        lights[found].dot(p),
                        "frame {frame} pixel {pixel}: nearest light {all}, the list's {found}"
                    );
                }
            }
        }
        let c = &candidates;
        assert!(
            c.staged_builds >= 3 && c.stages_cut_short >= 1 && c.builds >= 2,
            "{} staged ({} cut short), {} full",
            c.staged_builds,
            c.stages_cut_short,
            c.builds
        );
        assert!(
            c.staged_builds > c.stages_cut_short,
            "no staged build finished in stages"
        );
    }
}
