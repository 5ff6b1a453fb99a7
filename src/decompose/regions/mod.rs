//! Light regions: the spherical Voronoi cells of the lights' sample directions.
//!
//! Every working pixel gives its energy to the light whose sample direction is nearest on the
//! sphere, so regions are compact (as median cut's are), every light carries its own region's
//! energy and colour, and the lights sum to the map's integral exactly. Regions change
//! continuously as the sample directions move. The input pixels of concentrated working pixels
//! (a sun) are assigned one by one, so the several lights that share a sun split it at full
//! resolution and keep its shape (and so its penumbra).
//!
//! Nearest-light queries go through per-bucket candidate lists, kept between frames while the
//! lights move little ([`candidates`], whose doc has the bounds and when the lists are rebuilt).
//!
//! Steps per frame: (1) candidate lists per bucket (or the last frame's); (2) the input pixels
//! of concentrated working pixels go to their nearest light one by one (searching a list of
//! their working pixel's own, drawn from the bucket's, where the bucket's is long); (3) every
//! other working pixel is labelled with its nearest light, a bucket at a time, with dot products
//! computed from separable row and column terms (vectorised, eight pixels per vector); (4) each
//! row is summed run by run (consecutive pixels of one light, in f64) and each run is added to
//! its light's region; (5) by default, the refinement: the lights holding concentrated input
//! pixels move to their regions' centroids and those input pixels go again to their nearest
//! light (a k-means step on the concentrated sources; [`accumulate`]).

mod candidates;

use super::working_map::{FineSample, WorkingMap};
use super::{luminance_f64, Region};
pub use candidates::BucketGrid;
use candidates::{nearest, Candidate, Candidates, PixelCandidates, BUCKET_PIXELS, CELLS};
use glam::{DVec3, Vec3};

/// Scratch buffers of the region pass, kept between frames.
#[derive(Default)]
pub(super) struct Scratch {
    /// The nearest light of every working pixel, row-major.
    labels: Vec<u32>,
    lights: Vec<Vec3>,
    candidates: Candidates,
    /// Lights holding input pixels of concentrated sources.
    holds_concentrated: Vec<bool>,
    /// The light each concentrated input pixel (`WorkingMap::fine`) went to (kept up to date
    /// by the refinement and the Lloyd step).
    fine_labels: Vec<u32>,
    /// Per light, how many working pixels and input pixels its region holds.
    members: Vec<u32>,
    /// The lights after the Lloyd step, and the moved ones.
    new_lights: Vec<Vec3>,
    moved: Vec<Vec3>,
    /// Candidate lists for the lights after the Lloyd step (reused between frames as the
    /// first pass's are: in a static scene the step moves the lights to the same places).
    lloyd_candidates: Candidates,
    /// Per bucket, whether the Lloyd step relabels it.
    affected: Vec<bool>,
    /// The candidates of one concentrated working pixel (see [`assign_fine`]).
    pixel_candidates: PixelCandidates,
    /// The refinement's exact lists of the buckets holding concentrated pixels among all
    /// lights ([`Candidates::begin_exact`]; see [`refine_fine`]), and per bucket the range of
    /// its list if it has one.
    refine_candidates: Candidates,
    refine_list_of: Vec<Option<(u32, u32)>>,
}

impl Scratch {
    /// Allows (the default) or forbids reusing the candidate lists between frames.
    pub(super) fn set_candidate_reuse(&mut self, on: bool) {
        self.candidates.no_reuse = !on;
        self.lloyd_candidates.no_reuse = !on;
    }

    /// How many times the candidate lists have been built in full.
    pub(super) fn candidate_builds(&self) -> u64 {
        self.candidates.builds
    }

    /// How many times the candidate lists have been begun in stages.
    pub(super) fn candidate_staged_builds(&self) -> u64 {
        self.candidates.staged_builds
    }

    /// The light each concentrated input pixel (`WorkingMap::fine`) holds after the last
    /// region pass (after the refinement or Lloyd step, if any).
    pub(super) fn fine_labels(&self) -> &[u32] {
        &self.fine_labels
    }
}

/// Labels every pixel of bucket (`bx`, `by`) with its nearest light among the bucket's
/// candidates. Directions are separable, d = (sin θ·sin φ, cos θ, −sin θ·cos φ), so a light's dot
/// product with a pixel is sin θ·(Lx sin φ − Lz cos φ) + Ly cos θ: per candidate one column term
/// per bucket column, then one multiply-add per pixel. Candidates come in falling order of their
/// bound, so the scan stops once no remaining candidate can beat any pixel's best.
#[inline(always)]
fn label_bucket(
    map: &WorkingMap,
    grid: &BucketGrid,
    candidates: &[Candidate],
    (bx, by): (usize, usize),
    labels: &mut [u32],
) {
    let x0 = bx * BUCKET_PIXELS;
    let y0 = by * BUCKET_PIXELS;
    let x1 = (x0 + BUCKET_PIXELS).min(map.width);
    let y1 = (y0 + BUCKET_PIXELS).min(map.height);
    let Some((first, rest)) = candidates.split_first() else {
        return;
    };
    if rest.is_empty() {
        for y in y0..y1 {
            labels[y * map.width + x0..y * map.width + x1].fill(first.light);
        }
        return;
    }
    // Columns and rows past the map's edge repeat the last one; their labels are not stored.
    // So every bucket is a full block of 64 lanes, and the loops below are one fixed-size loop
    // that the compiler vectorises (eight lanes per AVX2 vector).
    let [sin_phi, cos_phi] = &grid.column_tiles[bx];
    let [sin_theta, cos_theta] = &grid.row_tiles[by];
    // d·l = sin θ·(lx sin φ − lz cos φ) + ly cos θ.
    let dot = |l: Vec3, i: usize| {
        sin_theta[i] * (l.x * sin_phi[i] - l.z * cos_phi[i]) + l.y * cos_theta[i]
    };
    let mut best: [f32; CELLS] = std::array::from_fn(|i| dot(first.dir, i));
    let mut best_id = [first.light; CELLS];
    // A lower bound of the lanes' minimum: the lanes only rise, so a minimum found earlier
    // stays a lower bound. Refreshed every fourth candidate only (a refresh costs about as
    // much as a candidate), so the scan may stop up to three candidates later than it could.
    let mut floor = -1.0f32;
    for (k, c) in rest.iter().enumerate() {
        // Every lane's best is at most 1, so a bound ≥ 1 cannot stop the scan: the lanes'
        // minimum is only needed (and only computed) for a bound below 1.
        if c.bound < 1.0 {
            if c.bound < floor {
                break;
            }
            if k % 4 == 0 {
                floor = min_of(&best);
                if c.bound < floor {
                    break;
                }
            }
        }
        // Copied out first: selecting between a load from `c` and a lane makes the compiler
        // select addresses and branch instead of blending.
        let (dir, light) = (c.dir, c.light);
        for i in 0..CELLS {
            let d = dot(dir, i);
            let closer = d > best[i];
            best[i] = if closer { d } else { best[i] };
            best_id[i] = if closer { light } else { best_id[i] };
        }
    }
    for (r, ids) in best_id
        .chunks_exact(BUCKET_PIXELS)
        .enumerate()
        .take(y1 - y0)
    {
        let start = (y0 + r) * map.width + x0;
        labels[start..start + (x1 - x0)].copy_from_slice(&ids[..x1 - x0]);
    }
}

/// Smallest value of the lanes (which are never NaN).
#[inline(always)]
fn min_of(lanes: &[f32; CELLS]) -> f32 {
    // A select is one `vminps`; `f32::min` adds a NaN test and a blend per vector.
    let min = |a: f32, b: f32| if b < a { b } else { a };
    let mut m = [f32::INFINITY; BUCKET_PIXELS];
    for row in lanes.chunks_exact(BUCKET_PIXELS) {
        for (m, &v) in m.iter_mut().zip(row) {
            *m = min(*m, v);
        }
    }
    // Halving folds: vector minima, not a serial chain.
    let m4: [f32; 4] = std::array::from_fn(|k| min(m[k], m[k + 4]));
    let m2: [f32; 2] = std::array::from_fn(|k| min(m4[k], m4[k + 2]));
    min(m2[0], m2[1])
}

/// The region pass's arguments, run through [`pulp::Arch::dispatch`] so that the pass is
/// compiled for the CPU's vector unit (`with_simd` and everything it calls are inlined into the
/// target-feature function).
pub(super) struct Accumulate<'a> {
    pub map: &'a WorkingMap,
    pub grid: &'a BucketGrid,
    pub sample_dirs: &'a [DVec3],
    pub regions: &'a mut [Region],
    pub scratch: &'a mut Scratch,
    /// One Lloyd step for the lights holding concentrated sources (see [`accumulate`]).
    pub concentrated_lloyd: bool,
    /// The concentrated input pixels go again to their nearest light once the lights holding
    /// them have moved to their regions' centroids (see [`accumulate`]); implied by
    /// `concentrated_lloyd`.
    pub refine_concentrated: bool,
}

impl pulp::WithSimd for Accumulate<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _simd: S) {
        accumulate(self);
    }
}

/// Adds every working pixel's energy, luminance-weighted direction and solid angle to the
/// region of its nearest light. A concentrated working pixel (a sun, a lamp; see
/// [`WorkingMap::fine`]) is assigned input pixel by input pixel, by exact direction, so the
/// lights that share a sun split it along their Voronoi borders at full resolution.
///
/// Two passes: every working pixel is labelled with its nearest light (bucket by bucket, see
/// [`label_bucket`]); then each row is summed run by run (consecutive pixels of one light, f64)
/// and each run is added to its light's region once.
///
/// With `concentrated_lloyd`, one Lloyd step follows for the lights that hold input pixels of
/// concentrated sources: each moves to its region's luminance centroid and the regions are
/// redrawn. Only the buckets the moved lights can reach are labelled again (a bucket none of
/// whose candidates moved, and which no moved light's new direction passes the bucket's reach
/// threshold for, keeps its labels), with candidate lists of their own for the moved lights
/// (kept between frames like the first pass's: a static scene moves the lights to the same
/// places every frame). Only the working and input pixels whose light changed move, each from
/// its old region to its new one; a region left with no pixel is emptied exactly (the
/// subtractions would leave rounding), and no region keeps a negative energy.
///
/// With `refine_concentrated` alone, the same step is taken by the concentrated input pixels
/// only (a k-means step on the suns and lamps at full resolution): the lights holding them move
/// to their regions' centroids, each concentrated input pixel goes to its nearest light after
/// the move, and the working pixels keep their labels. The lights that share a sun then split
/// it by their actual positions rather than by their sample points, at the cost of a few
/// candidate lists (the buckets that hold concentrated pixels) per frame.
#[inline(always)]
fn accumulate(args: Accumulate<'_>) {
    let Accumulate {
        map,
        grid,
        sample_dirs,
        regions,
        scratch,
        concentrated_lloyd,
        refine_concentrated,
    } = args;
    debug_assert_eq!((grid.width, grid.height), (map.width, map.height));
    scratch.lights.clear();
    scratch
        .lights
        .extend(sample_dirs.iter().map(|d| d.as_vec3()));
    scratch.candidates.update(grid, &scratch.lights);
    scratch.holds_concentrated.clear();
    scratch.holds_concentrated.resize(sample_dirs.len(), false);
    scratch.members.clear();
    scratch.members.resize(sample_dirs.len(), 0);
    scratch.fine_labels.clear();
    assign_fine(map, grid, scratch, regions);

    let labels = &mut scratch.labels;
    labels.resize(map.width * map.height, 0);
    let rows = map.height.div_ceil(BUCKET_PIXELS);
    for by in 0..rows {
        for bx in 0..grid.cols {
            label_bucket(
                map,
                grid,
                scratch.candidates.of(by * grid.cols + bx),
                (bx, by),
                labels,
            );
        }
    }
    sum_runs(map, labels, regions, &mut scratch.members);
    if !(concentrated_lloyd || refine_concentrated) || !scratch.holds_concentrated.contains(&true) {
        return;
    }
    if !concentrated_lloyd {
        refine_fine(map, grid, scratch, regions);
        empty_regions_exactly(regions, &scratch.members);
        return;
    }

    // The Lloyd step on the concentrated sources' lights.
    let Scratch {
        labels,
        candidates,
        holds_concentrated,
        fine_labels,
        members,
        new_lights,
        moved,
        lloyd_candidates,
        affected,
        ..
    } = scratch;
    move_to_centroids(&scratch.lights, holds_concentrated, regions, new_lights);
    moved.clear();
    moved.extend(
        new_lights
            .iter()
            .zip(holds_concentrated.iter())
            .filter_map(|(&l, &holds)| holds.then_some(l)),
    );
    affected.clear();
    affected.extend((0..grid.centres.len()).map(|b| {
        // Built with the margin, possibly frames ago: the reach it encodes (d_min + 2r + 2δ at
        // the build) is at least today's d_min + 2r, so the test stays conservative. A light
        // dropped from the list as dominated (`prune_dominated`) has a dominator in it that
        // did not move, or the bucket is affected through that dominator.
        let (centre, threshold) = (grid.centres[b], candidates.threshold(b));
        candidates
            .of(b)
            .iter()
            .any(|c| holds_concentrated[c.light as usize])
            || moved.iter().any(|&l| centre.dot(l) >= threshold)
    }));
    if affected.contains(&true) {
        lloyd_candidates.update(grid, new_lights);
    }
    let local_of = |b: usize| affected[b].then(|| lloyd_candidates.of(b));
    // Only the pixels whose light changed move from one region to the other: elsewhere the
    // nearest light is the same (no candidate moved and no moved light reaches the bucket).
    let mut before = [0u32; CELLS];
    for by in 0..rows {
        for bx in 0..grid.cols {
            let Some(list) = local_of(by * grid.cols + bx) else {
                continue;
            };
            let (x0, y0) = (bx * BUCKET_PIXELS, by * BUCKET_PIXELS);
            let (x1, y1) = (
                (x0 + BUCKET_PIXELS).min(map.width),
                (y0 + BUCKET_PIXELS).min(map.height),
            );
            for y in y0..y1 {
                let row = y * map.width;
                before[(y - y0) * BUCKET_PIXELS..][..x1 - x0]
                    .copy_from_slice(&labels[row + x0..row + x1]);
            }
            label_bucket(map, grid, list, (bx, by), labels);
            for y in y0..y1 {
                let (sin_t, cos_t) = map.row_trig_f64[y];
                let omega = map.row_solid_angle[y];
                for x in x0..x1 {
                    let p = y * map.width + x;
                    let (from, to) = (before[(y - y0) * BUCKET_PIXELS + x - x0], labels[p]);
                    if from == to || map.concentrated[p] {
                        continue;
                    }
                    let lum = f64::from(map.luminance[p]);
                    let (sin_p, cos_p) = map.column_trig_f64[x];
                    let dir = [sin_t * (lum * sin_p), cos_t * lum, -(sin_t * (lum * cos_p))];
                    move_member(
                        regions,
                        members,
                        (from, to),
                        map.energy[p].map(f64::from),
                        dir,
                        omega,
                    );
                }
            }
        }
    }
    for (sample, from) in map.fine.iter().zip(fine_labels.iter_mut()) {
        let Some(list) = local_of(grid.bucket_of(sample.pixel as usize)) else {
            continue;
        };
        let to = nearest(list, new_lights, Vec3::from(sample.dir), *from as usize) as u32;
        if to != *from {
            let (energy, weighted_dir, omega) = fine_contribution(sample);
            move_member(regions, members, (*from, to), energy, weighted_dir, omega);
            *from = to;
        }
    }
    empty_regions_exactly(regions, members);
}

/// Takes from each region the solid angle of its working pixels that the frame does not see
/// ([`WorkingMap::unseen`]: below a fisheye's field of view), so that a light's `solid_angle`
/// is the part of the sphere its energy comes from (the sum of the input's shares in its
/// working pixels); a concentrated working pixel's input pixels carry their own (seen) solid
/// angles already. Run after the region pass, on its final labels.
pub(super) fn remove_unseen(map: &WorkingMap, scratch: &Scratch, regions: &mut [Region]) {
    for &(pixel, unseen) in &map.unseen {
        let pixel = pixel as usize;
        if !map.concentrated[pixel] {
            let region = &mut regions[scratch.labels[pixel] as usize];
            region.solid_angle = (region.solid_angle - unseen).max(0.0);
        }
    }
}

/// A region that lost every pixel is empty, not the rounding left by the subtractions of
/// [`move_member`]; one that kept some keeps no negative energy from them.
#[inline(always)]
fn empty_regions_exactly(regions: &mut [Region], members: &[u32]) {
    for (region, &count) in regions.iter_mut().zip(members) {
        if count == 0 {
            *region = Region::default();
        } else {
            region.rgb = region.rgb.map(|c| c.max(0.0));
            region.solid_angle = region.solid_angle.max(0.0);
        }
    }
}

/// The refinement of [`accumulate`] (`refine_concentrated`): the lights holding concentrated
/// input pixels move to their regions' luminance centroids, then every concentrated input pixel
/// goes to its nearest light (moved or not) and, if that changed, from its old region to its
/// new one. The nearest light is found among exact candidate lists (no margin): per bucket that
/// holds concentrated pixels among all lights, then per pixel among its bucket's
/// ([`PixelCandidates`]).
#[inline(always)]
fn refine_fine(map: &WorkingMap, grid: &BucketGrid, scratch: &mut Scratch, regions: &mut [Region]) {
    let Scratch {
        lights,
        holds_concentrated,
        fine_labels,
        members,
        new_lights,
        pixel_candidates,
        refine_candidates: candidates,
        refine_list_of: list_of,
        ..
    } = scratch;
    move_to_centroids(lights, holds_concentrated, regions, new_lights);
    // Two levels, as the first pass's lists: the buckets that hold concentrated pixels get
    // exact lists among all lights (the vectorised reach test of the first pass's lists), then
    // each concentrated pixel its own among its bucket's.
    candidates.begin_exact(new_lights);
    list_of.clear();
    list_of.resize(grid.centres.len(), None);
    let mut first = 0;
    for group in map.fine.chunk_by(|a, b| a.pixel == b.pixel) {
        let pixel = group[0].pixel as usize;
        let bucket = grid.bucket_of(pixel);
        let range =
            *list_of[bucket].get_or_insert_with(|| candidates.exact_list(grid, bucket, new_lights));
        let bucket_list = candidates.exact(range);
        let list = pixel_candidates.of(map, pixel, bucket_list, new_lights);
        let labels = &mut fine_labels[first..first + group.len()];
        first += group.len();
        for (sample, label) in group.iter().zip(labels) {
            let from = *label;
            let to = nearest(list, new_lights, Vec3::from(sample.dir), from as usize) as u32;
            if to != from {
                let (energy, weighted_dir, omega) = fine_contribution(sample);
                move_member(regions, members, (from, to), energy, weighted_dir, omega);
                *label = to;
            }
        }
    }
}

/// `new_lights` = `lights`, but the lights that hold concentrated input pixels (`holds`) at
/// their regions' luminance centroids.
#[inline(always)]
fn move_to_centroids(
    lights: &[Vec3],
    holds: &[bool],
    regions: &[Region],
    new_lights: &mut Vec<Vec3>,
) {
    new_lights.clear();
    new_lights.extend(
        lights
            .iter()
            .zip(holds)
            .zip(regions)
            .map(|((&l, &holds), r)| {
                let centroid = holds.then(|| r.centroid());
                centroid.flatten().map_or(l, |d| d.as_vec3())
            }),
    );
}

/// What a concentrated input pixel adds to its light's region: energy, luminance-weighted
/// direction and solid angle.
#[inline(always)]
fn fine_contribution(sample: &FineSample) -> ([f64; 3], [f64; 3], f64) {
    let energy = sample.energy.map(f64::from);
    let lum = luminance_f64(energy);
    let weighted_dir = sample.dir.map(|d| lum * f64::from(d));
    (energy, weighted_dir, f64::from(sample.solid_angle))
}

/// Moves one pixel (its energy, luminance-weighted direction and solid angle) from region
/// `from` to region `to`.
#[inline(always)]
fn move_member(
    regions: &mut [Region],
    members: &mut [u32],
    (from, to): (u32, u32),
    energy: [f64; 3],
    weighted_dir: [f64; 3],
    solid_angle: f64,
) {
    let (from, to) = (from as usize, to as usize);
    for c in 0..3 {
        regions[from].rgb[c] -= energy[c];
        regions[from].weighted_dir[c] -= weighted_dir[c];
        regions[to].rgb[c] += energy[c];
        regions[to].weighted_dir[c] += weighted_dir[c];
    }
    regions[from].solid_angle -= solid_angle;
    regions[to].solid_angle += solid_angle;
    members[from] -= 1;
    members[to] += 1;
}

/// Assigns the input pixels of concentrated working pixels to their nearest lights (among the
/// first pass's candidates), marking the lights that receive any (`holds_concentrated`),
/// recording each input pixel's light (`fine_labels`) and counting the regions' members.
#[inline(always)]
fn assign_fine(map: &WorkingMap, grid: &BucketGrid, scratch: &mut Scratch, regions: &mut [Region]) {
    let Scratch {
        candidates,
        lights,
        holds_concentrated: holds,
        fine_labels: labels,
        members,
        pixel_candidates,
        ..
    } = scratch;
    let mut hint = 0;
    for group in map.fine.chunk_by(|a, b| a.pixel == b.pixel) {
        let pixel = group[0].pixel as usize;
        let bucket_list = candidates.of(grid.bucket_of(pixel));
        let list = pixel_candidates.of(map, pixel, bucket_list, lights);
        for sample in group {
            hint = nearest(list, lights, Vec3::from(sample.dir), hint);
            holds[hint] = true;
            labels.push(hint as u32);
            members[hint] += 1;
            let r = &mut regions[hint];
            let (energy, weighted_dir, omega) = fine_contribution(sample);
            for c in 0..3 {
                r.rgb[c] += energy[c];
                r.weighted_dir[c] += weighted_dir[c];
            }
            r.solid_angle += omega;
        }
    }
}

/// Sums each row of the labelled working map run by run into the regions.
#[inline(always)]
fn sum_runs(map: &WorkingMap, labels: &[u32], regions: &mut [Region], members: &mut [u32]) {
    for y in 0..map.height {
        let row = y * map.width..(y + 1) * map.width;
        let omega = map.row_solid_angle[y];
        let (sin_t, cos_t) = map.row_trig_f64[y];
        // Per run: [Σ r, Σ g, Σ b, Σ lum], [Σ lum·sin φ, Σ lum·cos φ] and the pixel count, as
        // short arrays whose adds the compiler does as one vector add each.
        let mut run = ([0.0f64; 4], [0.0f64; 2], 0u32);
        let mut current = labels[row.start];
        let mut flush = |light: u32, (sums, trig, count): ([f64; 4], [f64; 2], u32)| {
            if count == 0 {
                return;
            }
            let r = &mut regions[light as usize];
            for c in 0..3 {
                r.rgb[c] += sums[c];
            }
            r.weighted_dir[0] += sin_t * trig[0];
            r.weighted_dir[1] += cos_t * sums[3];
            r.weighted_dir[2] -= sin_t * trig[1];
            r.solid_angle += f64::from(count) * omega;
            members[light as usize] += count;
        };
        let pixels = map.energy[row.clone()]
            .iter()
            .zip(&map.luminance[row.clone()])
            .zip(&labels[row.clone()])
            .zip(&map.concentrated[row])
            .zip(&map.column_trig_f64);
        for ((((energy, &lum), &label), &concentrated), &(sin_p, cos_p)) in pixels {
            if label != current {
                flush(current, std::mem::take(&mut run));
                current = label;
            }
            if concentrated {
                continue;
            }
            let lum = f64::from(lum);
            let pixel = [energy[0], energy[1], energy[2]].map(f64::from);
            let pixel = [pixel[0], pixel[1], pixel[2], lum];
            for (s, v) in run.0.iter_mut().zip(pixel) {
                *s += v;
            }
            let trig = [lum * sin_p, lum * cos_p];
            for (s, v) in run.1.iter_mut().zip(trig) {
                *s += v;
            }
            run.2 += 1;
        }
        flush(current, run);
    }
}

#[cfg(test)]
mod tests {
    use super::candidates::tests::argmax;
    use super::*;

    /// The concentrated Lloyd step updates the regions by moving only the pixels whose light
    /// changed (`move_member`). Its regions must equal the plain sums, over the final labels,
    /// of every working pixel and every input pixel of the concentrated ones (each to the
    /// nearest light after the step), up to the rounding of the subtractions.
    #[test]
    fn lloyd_step_regions_are_the_sums_of_their_final_pixels() {
        use crate::decompose::working_map::Resampler;
        use crate::decompose::{DecomposeSettings, Decomposer};
        let path =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/rooitou_park_1k.hdr");
        let image = crate::capture::image_file::read_hdr_image(&path).unwrap();
        let frame = crate::HdrFrame::new(
            image.width,
            image.height,
            image.pixels,
            crate::envmap::Projection::LatLong,
        )
        .unwrap();
        let n = 256;
        // Sample directions: the default decomposition's lights (some hold the sun).
        let settings = DecomposeSettings {
            lights: n,
            filter_taps: None,
            ..DecomposeSettings::default()
        };
        let working_width = settings.working_width;
        let dirs: Vec<DVec3> = Decomposer::new(settings)
            .unwrap()
            .decompose(&frame)
            .lights
            .iter()
            .map(|l| DVec3::from(l.dir.map(f64::from)))
            .collect();
        let mut resampler =
            Resampler::new(frame.projection, frame.width, frame.height, working_width);
        let map = resampler.resample(&frame, 0.25 / n as f64, None);
        let grid = BucketGrid::new(map);
        let run = |lloyd: bool, refine: bool| {
            let (mut regions, mut scratch) = (vec![Region::default(); n], Scratch::default());
            accumulate(Accumulate {
                map,
                grid: &grid,
                sample_dirs: &dirs,
                regions: &mut regions,
                scratch: &mut scratch,
                concentrated_lloyd: lloyd,
                refine_concentrated: refine,
            });
            (regions, scratch)
        };
        let (_, first_pass) = run(false, false);
        // The full step, then the refinement alone (which keeps the working pixels' labels).
        for (lloyd, refine) in [(true, false), (false, true)] {
            let (regions, scratch) = run(lloyd, refine);
            check_sums(map, &first_pass, &regions, &scratch, lloyd);
        }
    }

    /// The regions after a Lloyd step or a refinement equal plain sums over their final pixels:
    /// the working pixels by their labels, the concentrated input pixels by their nearest
    /// light after the move. Some lights must have moved and some pixels changed light (a
    /// working pixel for the full step, an input pixel for the refinement).
    fn check_sums(
        map: &WorkingMap,
        first_pass: &Scratch,
        regions: &[Region],
        scratch: &Scratch,
        full_step: bool,
    ) {
        let n = regions.len();
        let moved = scratch.holds_concentrated.iter().filter(|&&m| m).count();
        let relabelled = first_pass
            .labels
            .iter()
            .zip(&scratch.labels)
            .zip(&map.concentrated)
            .filter(|((a, b), &c)| a != b && !c)
            .count();
        if full_step {
            assert!(
                moved > 0 && relabelled > 0,
                "{moved} lights moved, {relabelled} pixels relabelled"
            );
        } else {
            assert!(moved > 0, "no light moved");
            assert_eq!(relabelled, 0, "the refinement relabelled working pixels");
        }

        let mut sums = vec![Region::default(); n];
        let mut add = |light: usize, energy: [f64; 3], dir: [f64; 3], omega: f64| {
            let lum = luminance_f64(energy);
            for c in 0..3 {
                sums[light].rgb[c] += energy[c];
                sums[light].weighted_dir[c] += lum * dir[c];
            }
            sums[light].solid_angle += omega;
        };
        for y in 0..map.height {
            let (sin_t, cos_t) = map.row_trig_f64[y];
            for x in 0..map.width {
                let p = y * map.width + x;
                if !map.concentrated[p] {
                    let (sin_p, cos_p) = map.column_trig_f64[x];
                    let dir = [sin_t * sin_p, cos_t, -sin_t * cos_p];
                    add(
                        scratch.labels[p] as usize,
                        map.energy[p].map(f64::from),
                        dir,
                        map.row_solid_angle[y],
                    );
                }
            }
        }
        let mut changed = 0;
        let labels = first_pass.fine_labels.iter().zip(&scratch.fine_labels);
        for (sample, (&first, &last)) in map.fine.iter().zip(labels) {
            // The nearest light after the step; at an exact f32 tie with the light the first
            // pass chose (rooitou_park has one such input pixel), that light, as the step keeps
            // a pixel's light unless another is strictly nearer.
            let d = Vec3::from(sample.dir);
            let best = argmax(&scratch.new_lights, 0..n as u32, d) as usize;
            let first = first as usize;
            let tied = scratch.new_lights[first].dot(d) == scratch.new_lights[best].dot(d);
            let nearest = if tied { first } else { best };
            changed += usize::from(nearest != first);
            assert_eq!(last as usize, nearest, "the input pixel's recorded light");
            let energy = sample.energy.map(f64::from);
            let dir = sample.dir.map(f64::from);
            add(nearest, energy, dir, f64::from(sample.solid_angle));
        }
        assert!(changed > 0, "no concentrated input pixel changed light");
        let total: f64 = sums.iter().map(|r| luminance_f64(r.rgb)).sum();
        let sphere: f64 = sums.iter().map(|r| r.solid_angle).sum();
        for (i, (got, want)) in regions.iter().zip(&sums).enumerate() {
            for c in 0..3 {
                assert!(
                    (got.rgb[c] - want.rgb[c]).abs() <= 1e-9 * total,
                    "light {i} rgb: {:?}, sums {:?}",
                    got.rgb,
                    want.rgb
                );
                let dir_error = (got.weighted_dir[c] - want.weighted_dir[c]).abs();
                assert!(dir_error <= 1e-9 * total, "light {i} direction");
            }
            assert!(
                (got.solid_angle - want.solid_angle).abs() <= 1e-9 * sphere,
                "light {i}"
            );
        }
    }
}
