//! Decomposition of environment-map frames into temporally stable directional lights.
//!
//! The method of Havran et al. 2005 ("Interactive system for dynamic scene lighting using
//! captured video environment maps"), made exact in energy. For every frame:
//! 1. **Working map** ([`working_map`]): the frame is resampled to a small lat-long map of
//!    per-pixel energy (radiance × exact solid angle, f64), whatever its projection. Working
//!    pixels holding more than 1/(4N) of the energy (suns, lamps) also keep their input pixels.
//! 2. **PDF and warp** ([`distribution`]): luminance^γ per solid angle is a 2D density on the
//!    map ([`DecomposeSettings::pdf_exponent`]; γ = 1 is the paper's, the default 0.75 spreads
//!    lights a little more evenly and measures better in docs/quality.md).
//!    [`PiecewiseConstant2d`] maps the unit square onto it continuously (conditional CDFs
//!    blended across rows, so a point never jumps from one row band to another).
//! 3. **Fixed progressive point set** ([`point_set`]): Halton points, Lloyd-relaxed so that every
//!    2^k prefix is well stratified, computed once and reused by every frame. Light i sits where
//!    point i warps to, and a light count N uses the first N points.
//! 4. **Regions and lights** (`regions`): light i owns the spherical Voronoi cell of its sample
//!    direction; every working pixel (or, for concentrated ones, every input pixel) gives its
//!    energy to its nearest light. So each light carries the energy and colour of its own
//!    compact region, and the lights sum exactly to the map's integral. The light points at the
//!    luminance-weighted centroid of its region ([`LightPlacement::Centroid`], default) or at its
//!    sample direction (`SamplePoint`, the paper's). The lights holding concentrated sources
//!    then move to their regions' centroids and the sources' input pixels go again to their
//!    nearest light ([`DecomposeSettings::refine_concentrated`], on by default: a k-means step
//!    on the suns and lamps only). Optionally ([`DecomposeSettings::concentrated_lloyd`]) they
//!    take a full Lloyd step instead (regions redrawn where they can reach).
//! 5. **Temporal filter** ([`filter`]): a FIR low-pass on each light's power and direction by
//!    id (the direction as the power-weighted mean over the window); the windows of bright
//!    lights (suns, lamps) are first grouped in 0.1° cones, so the pixels a sun's lights trade
//!    between frames are not blended ([`DecomposeSettings::bright_history`]). It restarts when
//!    the light count changes. Optionally, the **split** ([`split`], off by default): the
//!    lights of bright lamps and suns become several pieces and the weakest lights merge into
//!    their neighbours ([`DecomposeSettings::split_factor`]), planned on the unfiltered lights
//!    of step 4 and applied to the filtered ones.
//! 6. **Merge** ([`merge`], off by default): lights crowding a concentrated source become one
//!    light that records the source's spread (solid angle).

pub mod distribution;
pub mod filter;
pub mod hierarchical;
pub mod merge;
pub mod point_set;
mod regions;
pub mod split;
pub mod working_map;

pub use distribution::PiecewiseConstant2d;
pub use filter::{BrightHistory, FirFilter};
pub use hierarchical::HierarchicalWarp;
pub use point_set::MAX_POINTS;

use crate::envmap::Projection;
use crate::frame::HdrFrame;
use crate::light::{Light, LightFrame};
use working_map::Resampler;

/// Smallest and largest working-map width.
pub const WORKING_WIDTH_RANGE: std::ops::RangeInclusive<u32> = 16..=4096;

/// A working pixel holding more than this share of the energy, divided by the light count, is a
/// concentrated source: its input pixels are assigned to lights one by one.
const CONCENTRATED_SHARE: f64 = 0.25;

/// Default exponent γ of the sampling density (luminance^γ).
pub const DEFAULT_PDF_EXPONENT: f64 = 0.75;

/// How the unit square is warped onto the sampling density.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Warp {
    /// Row-by-row inverse CDF with conditional CDFs blended across rows
    /// ([`PiecewiseConstant2d`]): continuous in the point, but a bright source moving within
    /// its rows slides points far along them.
    #[default]
    Rows,
    /// k-d tree of mass splits ([`HierarchicalWarp`]): a change of the map moves only the
    /// points whose tree paths see it, so lights are much steadier under moving sources
    /// (docs/quality.md), but a point that crosses a split jumps to the neighbouring node.
    Hierarchical,
}

/// The warp of one frame.
enum Sampler<'a> {
    Rows(&'a PiecewiseConstant2d),
    Hierarchical(HierarchicalWarp),
}

/// Where a light points within its region.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum LightPlacement {
    /// The luminance-weighted centroid of the light's region (default: most accurate).
    #[default]
    Centroid,
    /// The warped sample point itself, as in Havran et al. 2005.
    SamplePoint,
}

/// Settings of a [`Decomposer`].
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DecomposeSettings {
    /// Number of lights, 1..=[`MAX_POINTS`].
    pub lights: usize,
    /// Width of the lat-long working map (height = width/2). A lat-long input is box-filtered by
    /// the largest integer factor that keeps the width ≥ this when its size allows; concentrated
    /// sources keep their full input resolution.
    pub working_width: u32,
    pub placement: LightPlacement,
    /// FIR taps, newest frame first; `None` disables temporal filtering.
    pub filter_taps: Option<Vec<f64>>,
    /// Merge radius as a fraction of the mean light spacing; `None` (the default) disables
    /// merging. Merging saves shadow maps but turns a sun's lights into one point with a
    /// recorded spread, which point-light consumers see as a hard shadow (docs/quality.md).
    pub merge_spacing_fraction: Option<f64>,
    /// γ in (0, 1]: lights are placed with density ∝ luminance^γ. 1 is Havran et al.'s pure
    /// inverse-transform sampling; smaller values spread lights more evenly over dim regions
    /// (each light still carries exactly its region's energy).
    pub pdf_exponent: f64,
    /// How the fixed points are warped onto the density.
    pub warp: Warp,
    /// One Lloyd step for the lights that hold input pixels of concentrated sources (lamps,
    /// suns): they move to their regions' luminance centroids and the regions they can reach
    /// are redrawn. Off by default: it wins 70 of docs/quality.md's 72 rows against median cut
    /// (the default 69) for 8–40% more instructions per frame (docs/performance.md, round 7).
    #[serde(default)]
    pub concentrated_lloyd: bool,
    /// After the regions are drawn, the lights holding concentrated sources move to their
    /// regions' luminance centroids and the sources' input pixels go again to their nearest
    /// light (a k-means step at full resolution on the suns and lamps only; the working
    /// pixels keep their regions). Implied by `concentrated_lloyd`. On by default; a recording
    /// whose stored settings lack it was made before it existed, so it reads as off and the
    /// replay makes the recorded lights.
    #[serde(default)]
    pub refine_concentrated: bool,
    /// What the temporal filter does with the window of a light brighter than
    /// [`filter::BRIGHT_FACTOR`] × the frame's mean light (a sun's, a lamp's): the
    /// [`filter`] module doc has the steps. [`BrightHistory::Fold`] by default; a recording
    /// whose stored settings lack it was made before it existed and reads as
    /// [`BrightHistory::Blend`], the filter of that time.
    #[serde(default = "bright_history_before_it_existed")]
    pub bright_history: BrightHistory,
    /// Lights holding concentrated input pixels (lamps, suns) and more than this × the mean
    /// light's energy split into pieces, taken from the weakest lights, so the count stays N
    /// ([`split`] has the steps; [`split::DEFAULT_SPLIT_FACTOR`] is the measured choice).
    /// `None` (the default) leaves it out: it wins 71 of docs/quality.md's 72 rows against
    /// the default's 69, but the filtered lights flicker up to 18% more on the temporal table's
    /// sequences. A recording whose stored settings lack it reads as off. Needs
    /// [`LightPlacement::Centroid`] ([`DecomposeError::SplitPlacement`] otherwise).
    #[serde(default)]
    pub split_factor: Option<f64>,
    /// Threads that resample a frame which is not a lat-long map of a multiple of the working
    /// size (a camera's fisheye, the angular map, odd sizes), 1..=[`MAX_RESAMPLE_THREADS`],
    /// at most the machine's cores; 1 resamples on the calling thread. The lights are the same
    /// bits with any number (docs/performance.md, "A camera's frames"). A recording whose
    /// stored settings lack it reads as the default.
    #[serde(default = "default_resample_threads")]
    pub resample_threads: usize,
}

/// Default of [`DecomposeSettings::resample_threads`]: two threads take a 1280×960 fisheye
/// frame into 256 lights from 2.2–2.8 ms to 1.5–1.7 ms on the development VM
/// (docs/performance.md, "A camera's frames"), as `camera.convert_threads` speeds its
/// conversion.
pub const DEFAULT_RESAMPLE_THREADS: usize = 2;

/// Most threads [`DecomposeSettings::resample_threads`] may ask for.
pub const MAX_RESAMPLE_THREADS: usize = 64;

fn default_resample_threads() -> usize {
    DEFAULT_RESAMPLE_THREADS
}

/// The filter's treatment of bright lights before [`DecomposeSettings::bright_history`] existed.
fn bright_history_before_it_existed() -> BrightHistory {
    BrightHistory::Blend
}

impl Default for DecomposeSettings {
    fn default() -> Self {
        Self {
            lights: 256,
            working_width: 256,
            placement: LightPlacement::Centroid,
            filter_taps: Some(filter::DEFAULT_TAPS.to_vec()),
            merge_spacing_fraction: None,
            pdf_exponent: DEFAULT_PDF_EXPONENT,
            warp: Warp::Rows,
            concentrated_lloyd: false,
            refine_concentrated: true,
            bright_history: BrightHistory::Fold,
            split_factor: None,
            resample_threads: DEFAULT_RESAMPLE_THREADS,
        }
    }
}

/// Errors of the decomposition. Each names the setting or input at fault.
#[derive(Debug, thiserror::Error, PartialEq)]
pub enum DecomposeError {
    #[error("light count {0} is out of range: it must be between 1 and {MAX_POINTS}")]
    LightCount(usize),
    #[error("working width {0} is out of range: it must be between 16 and 4096")]
    WorkingWidth(u32),
    #[error("filter taps: {0}")]
    FilterTaps(String),
    #[error("merge spacing fraction {0} must be a finite number in (0, 2]")]
    MergeFraction(f64),
    #[error("pdf exponent {0} must be a number in (0, 1]")]
    PdfExponent(f64),
    #[error("split factor {0} must be a finite number of at least 1")]
    SplitFactor(f64),
    #[error("the split of bright lights needs the centroid placement (its pieces are centroids)")]
    SplitPlacement,
    #[error(
        "resample threads {0} is out of range: it must be between 1 and {MAX_RESAMPLE_THREADS}"
    )]
    ResampleThreads(usize),
}

/// Per-light accumulator of a region's integrals.
#[derive(Clone, Copy, Debug, Default)]
struct Region {
    rgb: [f64; 3],
    /// Σ luminance-energy × direction.
    weighted_dir: [f64; 3],
    solid_angle: f64,
}

impl Region {
    /// The luminance-weighted centroid direction; `None` where the weights cancel.
    fn centroid(&self) -> Option<glam::DVec3> {
        glam::DVec3::from(self.weighted_dir).try_normalize()
    }

    /// The region as light `id` pointing along `dir`.
    fn to_light(self, id: u32, dir: glam::DVec3) -> Light {
        Light {
            id,
            dir: [dir.x as f32, dir.y as f32, dir.z as f32],
            rgb: self.rgb.map(crate::light::saturating_f32),
            solid_angle: self.solid_angle as f32,
        }
    }
}

impl DecomposeSettings {
    /// Checks every setting as [`Decomposer::new`] does, without building anything: the error
    /// names the first bad one.
    pub fn validate(&self) -> Result<(), DecomposeError> {
        let settings = self;
        validate_light_count(settings.lights)?;
        if !WORKING_WIDTH_RANGE.contains(&settings.working_width) {
            return Err(DecomposeError::WorkingWidth(settings.working_width));
        }
        if let Some(f) = settings.merge_spacing_fraction {
            if !(f > 0.0 && f <= 2.0) {
                return Err(DecomposeError::MergeFraction(f));
            }
        }
        if !(settings.pdf_exponent > 0.0 && settings.pdf_exponent <= 1.0) {
            return Err(DecomposeError::PdfExponent(settings.pdf_exponent));
        }
        if let Some(f) = settings.split_factor {
            if !(f.is_finite() && f >= 1.0) {
                return Err(DecomposeError::SplitFactor(f));
            }
            if settings.placement != LightPlacement::Centroid {
                return Err(DecomposeError::SplitPlacement);
            }
        }
        if !(1..=MAX_RESAMPLE_THREADS).contains(&settings.resample_threads) {
            return Err(DecomposeError::ResampleThreads(settings.resample_threads));
        }
        if let Some(taps) = &settings.filter_taps {
            FirFilter::new(taps).map_err(DecomposeError::FilterTaps)?;
        }
        Ok(())
    }
}

/// Turns frames into light lists; holds the point set, the per-geometry resampler and buckets,
/// and the temporal filter state, so one `Decomposer` serves one stream of frames.
pub struct Decomposer {
    settings: DecomposeSettings,
    resampler: Option<Resampler>,
    /// The helpers of the table path's resampling (`envlight-resample-N`,
    /// `resample_threads` − 1 of them: the decomposition thread is the other); `None` with one
    /// thread or before a frame needs them.
    resample_pool: Option<rayon::ThreadPool>,
    /// Whether `resample_pool` has been started (or found not to be needed, or failed to
    /// start, with a warning): it is tried once per decomposer.
    resample_pool_tried: bool,
    buckets: Option<regions::BucketGrid>,
    region_scratch: regions::Scratch,
    /// The rows warp of the last frame (its buffers are reused).
    rows_warp: Option<PiecewiseConstant2d>,
    /// The CPU's vector unit, detected once: hot loops are compiled for it.
    arch: pulp::Arch,
    filter: Option<FirFilter>,
    /// The density image of the hierarchical warp (the rows warp takes the density straight
    /// into its prefix sums).
    weights: Vec<f64>,
    regions: Vec<Region>,
    last_count: Option<usize>,
    /// The first `n` points of the progressive set for the last light count n.
    points: std::sync::Arc<[[f64; 2]]>,
    /// Where the points warp to in the last frame (the buffer is reused).
    sample_dirs: Vec<glam::DVec3>,
    /// The split of the last frame's bright lights, applied after the filter.
    split_plan: split::SplitPlan,
}

impl Decomposer {
    /// Validates `settings` and prepares the point set for `settings.lights` lights.
    pub fn new(settings: DecomposeSettings) -> Result<Self, DecomposeError> {
        settings.validate()?;
        let filter = match &settings.filter_taps {
            Some(taps) => Some(
                FirFilter::new(taps)
                    .map_err(DecomposeError::FilterTaps)?
                    .with_bright_history(settings.bright_history),
            ),
            None => None,
        };
        point_set::progressive_points(settings.lights);
        Ok(Self {
            settings,
            resampler: None,
            resample_pool: None,
            resample_pool_tried: false,
            buckets: None,
            region_scratch: regions::Scratch::default(),
            rows_warp: None,
            arch: pulp::Arch::new(),
            filter,
            weights: Vec::new(),
            regions: Vec::new(),
            last_count: None,
            points: std::sync::Arc::from(Vec::new()),
            sample_dirs: Vec::new(),
            split_plan: split::SplitPlan::default(),
        })
    }

    pub fn settings(&self) -> &DecomposeSettings {
        &self.settings
    }

    /// Allows (the default) or forbids reusing the region pass's candidate lists between frames
    /// while the lights stay within `REUSE_MARGIN` (src/decompose/regions/candidates.rs) of
    /// where the lists were built. The lights are the same either way; forbidding it measures
    /// the cost of a full build every frame.
    pub fn set_candidate_reuse(&mut self, on: bool) {
        self.region_scratch.set_candidate_reuse(on);
    }

    /// How many times the region pass has built its candidate lists in full (the other frames
    /// reused the last ones, or built them in stages).
    pub fn candidate_builds(&self) -> u64 {
        self.region_scratch.candidate_builds()
    }

    /// How many times the region pass has begun building its candidate lists in stages (a few
    /// buckets per frame, while the lights drift slowly: src/decompose/regions/candidates.rs).
    pub fn candidate_staged_builds(&self) -> u64 {
        self.region_scratch.candidate_staged_builds()
    }

    /// Delay of the temporal filter in frames (0 without filter).
    pub fn filter_delay_frames(&self) -> f64 {
        self.filter.as_ref().map_or(0.0, FirFilter::delay_frames)
    }

    /// Decomposes `frame` into `settings.lights` lights (more with
    /// [`BrightHistory::Fade`]: its fading lights follow, ids from [`filter::FADING_ID_BASE`]).
    pub fn decompose(&mut self, frame: &HdrFrame) -> LightFrame {
        let n = self.settings.lights;
        self.decompose_with_count(frame, n)
            .unwrap_or_else(|_| unreachable!("validated count"))
    }

    /// Decomposes `frame` into `n` lights (the first n of the progressive set, and any fading
    /// lights of [`BrightHistory::Fade`]): the light count may change every frame.
    pub fn decompose_with_count(
        &mut self,
        frame: &HdrFrame,
        n: usize,
    ) -> Result<LightFrame, DecomposeError> {
        validate_light_count(n)?;
        let mut lights = self.raw_lights(frame, n);
        if let Some(filter) = &mut self.filter {
            // A new light count reshapes every region, so a light's history no longer matches
            // what it now represents: restart the filter rather than blend (energy stays exact).
            if self.last_count.is_some_and(|last| last != n) {
                filter.reset();
            }
            filter.apply(&mut lights);
        }
        self.split_plan.apply(&mut lights);
        self.last_count = Some(n);
        if let Some(fraction) = self.settings.merge_spacing_fraction {
            lights = merge::merge_crowded(&lights, fraction);
        }
        Ok(LightFrame {
            seq: frame.seq,
            time: frame.time,
            lights,
        })
    }

    /// Steps 1–4: unfiltered, unmerged, unsplit lights, ids 0..n; sets the split plan.
    fn raw_lights(&mut self, frame: &HdrFrame, n: usize) -> Vec<Light> {
        if !self.resampler.as_ref().is_some_and(|r| r.fits(frame)) {
            self.resampler = Some(Resampler::new(
                frame.projection,
                frame.width,
                frame.height,
                self.settings.working_width,
            ));
            self.buckets = None;
        }
        let table = self.resampler.as_ref().is_some_and(Resampler::uses_table);
        if table && !self.resample_pool_tried {
            // Started with the first frame that needs it (a lat-long map of a multiple of the
            // working size never does). The decomposition thread sums bands too, so the pool
            // holds the others.
            self.resample_pool_tried = true;
            match crate::parallel::helper_pool(self.settings.resample_threads, "envlight-resample")
            {
                Ok(pool) => self.resample_pool = pool,
                // The calling thread resamples alone: the same lights, only slower.
                Err(e) => tracing::warn!(
                    "starting the resampling threads: {e}; resampling on the decomposition thread"
                ),
            }
        }
        let Some(resampler) = self.resampler.as_mut() else {
            unreachable!("set above")
        };
        let map = resampler.resample(
            frame,
            CONCENTRATED_SHARE / n as f64,
            self.resample_pool.as_ref(),
        );
        let buckets = self
            .buckets
            .get_or_insert_with(|| regions::BucketGrid::new(map));

        // The sampling density: luminance radiance to the power γ, per solid angle. It only
        // places the lights (their energies are summed separately, in f64), so f32 suffices.
        // The rows warp takes it straight into its prefix sums (no weight image in between).
        let (arch, gamma) = (self.arch, self.settings.pdf_exponent);
        let warp = match self.settings.warp {
            Warp::Rows => {
                let dist = self
                    .rows_warp
                    .get_or_insert_with(|| PiecewiseConstant2d::new(&[0.0], 1, 1));
                arch.dispatch(Density {
                    map,
                    gamma,
                    out: DensityOut::RowsWarp(dist),
                });
                Sampler::Rows(dist)
            }
            Warp::Hierarchical => {
                self.weights.resize(map.width * map.height, 0.0);
                arch.dispatch(Density {
                    map,
                    gamma,
                    out: DensityOut::Weights(&mut self.weights),
                });
                Sampler::Hierarchical(HierarchicalWarp::new(&self.weights, map.width, map.height))
            }
        };

        // Light i sits where point i warps to.
        if self.points.len() != n {
            self.points = point_set::progressive_points(n);
        }
        let points = &self.points;
        let sample_dirs = &mut self.sample_dirs;
        sample_dirs.clear();
        sample_dirs.extend(points.iter().map(|u| {
            let p = match &warp {
                Sampler::Rows(dist) => dist.sample(*u).0,
                Sampler::Hierarchical(tree) => tree.sample(*u),
            };
            Projection::LatLong
                .pixel_to_direction(
                    map.width as u32,
                    map.height as u32,
                    p[0] * map.width as f64,
                    p[1] * map.height as f64,
                )
                .unwrap_or(glam::DVec3::Y)
        }));
        let sample_dirs = &self.sample_dirs;

        self.regions.clear();
        self.regions.resize(n, Region::default());
        self.arch.dispatch(regions::Accumulate {
            map,
            grid: buckets,
            sample_dirs,
            regions: &mut self.regions,
            scratch: &mut self.region_scratch,
            concentrated_lloyd: self.settings.concentrated_lloyd,
            refine_concentrated: self.settings.refine_concentrated,
        });
        regions::remove_unseen(map, &self.region_scratch, &mut self.regions);

        let placement = self.settings.placement;
        let lights: Vec<Light> = sample_dirs
            .iter()
            .zip(&self.regions)
            .enumerate()
            .map(|(id, (sample_dir, region))| {
                let dir = match placement {
                    LightPlacement::Centroid => region.centroid().unwrap_or(*sample_dir),
                    LightPlacement::SamplePoint => *sample_dir,
                };
                region.to_light(id as u32, dir)
            })
            .collect();
        self.split_plan = match self.settings.split_factor {
            Some(factor) => split::SplitPlan::new(
                &lights,
                &self.regions,
                &map.fine,
                self.region_scratch.fine_labels(),
                factor,
            ),
            None => split::SplitPlan::default(),
        };
        lights
    }
}

/// The sampling density of a working map, run through [`pulp::Arch::dispatch`] so that it is
/// compiled for the CPU's vector unit.
struct Density<'a> {
    map: &'a working_map::WorkingMap,
    gamma: f64,
    out: DensityOut<'a>,
}

/// Where the density goes.
enum DensityOut<'a> {
    /// Straight into the rows warp, which it rebuilds.
    RowsWarp(&'a mut PiecewiseConstant2d),
    /// A weight image (row-major, one weight per working pixel).
    Weights(&'a mut [f64]),
}

impl pulp::WithSimd for Density<'_> {
    type Output = ();

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _simd: S) {
        let Density { map, gamma, out } = self;
        let g = gamma as f32;
        // One branch per frame, not per pixel: the common exponents have cheap exact forms.
        if gamma == 1.0 {
            density(map, out, |r| r);
        } else if gamma == 0.75 {
            density(map, out, |r| {
                let root = r.sqrt();
                root * root.sqrt()
            });
        } else if gamma == 0.5 {
            density(map, out, f32::sqrt);
        } else {
            density(map, out, |r| r.powf(g));
        }
    }
}

/// weight = power(luminance / Ω) · Ω for every working pixel, into `out`.
#[inline(always)]
fn density(map: &working_map::WorkingMap, out: DensityOut<'_>, power: impl Fn(f32) -> f32) {
    let row = |y: usize, weights: &mut [f64]| {
        let omega = map.row_solid_angle[y];
        let (inv_omega, omega) = ((1.0 / omega) as f32, omega as f32);
        let luminance = &map.luminance[y * map.width..(y + 1) * map.width];
        for (w, &lum) in weights.iter_mut().zip(luminance) {
            // Clamped: a radiance at the edge of f32's range must not become ∞ (a weight of 0).
            let radiance = (lum * inv_omega).min(f32::MAX);
            *w = f64::from(power(radiance) * omega);
        }
    };
    match out {
        DensityOut::RowsWarp(dist) => dist.rebuild_rows_inline(map.width, map.height, row),
        DensityOut::Weights(weights) => {
            for (y, out) in weights.chunks_exact_mut(map.width).enumerate() {
                row(y, out);
            }
        }
    }
}

fn validate_light_count(n: usize) -> Result<(), DecomposeError> {
    if (1..=MAX_POINTS).contains(&n) {
        Ok(())
    } else {
        Err(DecomposeError::LightCount(n))
    }
}

/// Rec. 709 luminance of an f64 rgb triple.
#[inline]
pub fn luminance_f64(e: [f64; 3]) -> f64 {
    let w = crate::frame::LUMINANCE_WEIGHTS;
    f64::from(w[0]) * e[0] + f64::from(w[1]) * e[1] + f64::from(w[2]) * e[2]
}

/// Total radiance integral of a frame (Σ rgb·Ω over its pixels, f64): what the lights sum to.
pub fn frame_integral(frame: &HdrFrame) -> [f64; 3] {
    let omegas = frame.projection.solid_angles(frame.width, frame.height);
    let mut sum = [0.0f64; 3];
    for (p, omega) in frame.pixels.iter().zip(omegas) {
        for c in 0..3 {
            if p[c].is_finite() && p[c] > 0.0 {
                sum[c] += f64::from(p[c]) * omega;
            }
        }
    }
    sum
}

/// The unit tests' seeded xorshift generator: uniform numbers in [0, 1), the same sequence for
/// the same seed.
#[cfg(test)]
pub(crate) fn xorshift_unit(mut state: u64) -> impl FnMut() -> f64 {
    move || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 11) as f64 / (1u64 << 53) as f64
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Settings stored by a build without the refinement (a recording's session.json) read
    /// with it off, so a replay makes the lights that were recorded; today's settings store it.
    #[test]
    fn stored_settings_without_the_refinement_read_as_off() {
        let today = serde_json::to_value(DecomposeSettings::default()).unwrap();
        assert_eq!(today["refine_concentrated"], serde_json::Value::Bool(true));
        let mut old = today.clone();
        old.as_object_mut().unwrap().remove("refine_concentrated");
        let read: DecomposeSettings = serde_json::from_value(old).unwrap();
        assert!(!read.refine_concentrated);
        let read: DecomposeSettings = serde_json::from_value(today).unwrap();
        assert_eq!(read, DecomposeSettings::default());
    }

    /// Likewise, stored settings from before the filter treated bright lights apart read as
    /// `blend` (that filter); today's store `fold`.
    #[test]
    fn stored_settings_without_bright_history_read_as_blend() {
        let today = serde_json::to_value(DecomposeSettings::default()).unwrap();
        assert_eq!(today["bright_history"], serde_json::json!("fold"));
        let mut old = today.clone();
        old.as_object_mut().unwrap().remove("bright_history");
        let read: DecomposeSettings = serde_json::from_value(old).unwrap();
        assert_eq!(read.bright_history, BrightHistory::Blend);
        let mut fade = today;
        fade["bright_history"] = serde_json::json!("fade");
        let read: DecomposeSettings = serde_json::from_value(fade).unwrap();
        assert_eq!(read.bright_history, BrightHistory::Fade);
    }

    /// Stored settings from before the split of bright lights read as without it; a stored
    /// factor reads back.
    #[test]
    fn stored_settings_without_split_factor_read_as_off() {
        let mut today = serde_json::to_value(DecomposeSettings::default()).unwrap();
        assert_eq!(today["split_factor"], serde_json::Value::Null);
        today["split_factor"] = serde_json::json!(split::DEFAULT_SPLIT_FACTOR);
        let read: DecomposeSettings = serde_json::from_value(today.clone()).unwrap();
        assert_eq!(read.split_factor, Some(split::DEFAULT_SPLIT_FACTOR));
        today.as_object_mut().unwrap().remove("split_factor");
        let read: DecomposeSettings = serde_json::from_value(today).unwrap();
        assert_eq!(read.split_factor, None);
    }

    fn sky_with_sun(w: u32, h: u32, sun: (u32, u32), sun_power: f32) -> HdrFrame {
        let mut pixels = Vec::with_capacity((w * h) as usize);
        for y in 0..h {
            for x in 0..w {
                let sky = if y < h / 2 {
                    1.0 + 0.5 * (y as f32 / h as f32)
                } else {
                    0.2
                };
                let tint = 1.0 + 0.3 * ((x as f32 / w as f32) * std::f32::consts::TAU).sin();
                pixels.push([sky * tint, sky, sky * 1.2]);
            }
        }
        pixels[(sun.1 * w + sun.0) as usize] = [sun_power, sun_power * 0.9, sun_power * 0.8];
        HdrFrame::new(w, h, pixels, Projection::LatLong).expect("valid size")
    }

    fn raw_settings(n: usize) -> DecomposeSettings {
        DecomposeSettings {
            lights: n,
            filter_taps: None,
            merge_spacing_fraction: None,
            ..DecomposeSettings::default()
        }
    }

    #[test]
    fn lights_sum_to_the_integral() {
        let frame = sky_with_sun(512, 256, (100, 60), 1e5);
        let truth = frame_integral(&frame);
        for n in [1, 16, 100, 256, 1024] {
            for (merge, concentrated_lloyd) in [(None, false), (Some(0.25), false), (None, true)] {
                let settings = DecomposeSettings {
                    merge_spacing_fraction: merge,
                    concentrated_lloyd,
                    ..raw_settings(n)
                };
                let lights = Decomposer::new(settings).unwrap().decompose(&frame);
                let sum = lights.total_rgb();
                for c in 0..3 {
                    assert!(
                        (sum[c] - truth[c]).abs() < 1e-4 * truth[c],
                        "n={n} c={c} lloyd={concentrated_lloyd}"
                    );
                }
            }
        }
    }

    #[test]
    fn lights_have_their_regions_colour() {
        // Left half red, right half blue: lights on each side carry that side's colour (not an
        // equal share of the map's).
        let (w, h) = (128u32, 64u32);
        let pixels = (0..w * h)
            .map(|i| {
                if i % w < w / 2 {
                    [1.0, 0.0, 0.0]
                } else {
                    [0.0, 0.0, 3.0]
                }
            })
            .collect();
        let frame = HdrFrame::new(w, h, pixels, Projection::LatLong).unwrap();
        let lights = Decomposer::new(raw_settings(64)).unwrap().decompose(&frame);
        // Only lights whose regions straddle the border (the plane x = 0: φ = 0 and π) may mix
        // the colours: those within one mean region width, √(4π/64) rad ≈ 25°, of it. Measured
        // at the default working width: 19 mixed, the farthest 21.4° from the border.
        let region_width = (4.0 * std::f32::consts::PI / 64.0).sqrt().to_degrees();
        let mixed: Vec<f32> = lights
            .lights
            .iter()
            .filter(|l| l.rgb[0] != 0.0 && l.rgb[2] != 0.0)
            .map(|l| l.dir[0].abs().asin().to_degrees())
            .collect();
        assert!(mixed.len() <= 24, "{} of 64 lights are mixed", mixed.len());
        assert!(
            mixed.iter().all(|&from_border| from_border < region_width),
            "mixed lights this far (degrees) from the border: {mixed:?}"
        );
    }

    fn sun_energy_near(lights: &LightFrame, sun: glam::DVec3, max_angle_deg: f64) -> f64 {
        let cos_max = max_angle_deg.to_radians().cos();
        lights
            .lights
            .iter()
            .filter(|l| {
                let d = glam::DVec3::new(l.dir[0].into(), l.dir[1].into(), l.dir[2].into());
                d.dot(sun) > cos_max
            })
            .map(|l| f64::from(l.rgb[0]))
            .sum()
    }

    #[test]
    fn sun_energy_lands_on_the_sun() {
        let frame = sky_with_sun(256, 128, (40, 30), 1e6);
        let sun = Projection::LatLong
            .pixel_to_direction(256, 128, 40.5, 30.5)
            .unwrap();
        let sun_energy = 1e6 * Projection::LatLong.solid_angles(256, 128)[30 * 256];
        for placement in [LightPlacement::Centroid, LightPlacement::SamplePoint] {
            let settings = DecomposeSettings {
                placement,
                ..raw_settings(256)
            };
            let lights = Decomposer::new(settings).unwrap().decompose(&frame);
            let near = sun_energy_near(&lights, sun, 1.0);
            assert!(
                near > 0.9 * sun_energy,
                "{placement:?}: {near} of {sun_energy} within 1°"
            );
        }
    }

    #[test]
    fn merged_sun_becomes_one_light() {
        // A sun of 6×6 input pixels (2° across) in a 1024×512 map: several lights share it.
        let mut frame = sky_with_sun(1024, 512, (160, 120), 1.0);
        for y in 120..126 {
            for x in 160..166 {
                frame.pixels[y * 1024 + x] = [1e5; 3];
            }
        }
        let omegas = Projection::LatLong.solid_angles(1024, 512);
        let sun_energy: f64 = (120..126).map(|y| 6.0 * 1e5 * omegas[y * 1024]).sum();
        let settings = |merge| DecomposeSettings {
            merge_spacing_fraction: merge,
            ..raw_settings(256)
        };
        let raw = Decomposer::new(settings(None)).unwrap().decompose(&frame);
        let on_sun = |lights: &LightFrame| {
            lights
                .lights
                .iter()
                .filter(|l| f64::from(l.rgb[0]) > 0.01 * sun_energy)
                .count()
        };
        assert!(
            on_sun(&raw) > 1,
            "the sun should be shared by several lights"
        );
        let merged = Decomposer::new(settings(Some(0.25)))
            .unwrap()
            .decompose(&frame);
        assert_eq!(on_sun(&merged), 1, "the sun's lights merge into one");
        let sun = merged
            .lights
            .iter()
            .max_by(|a, b| a.luminance().total_cmp(&b.luminance()))
            .unwrap();
        assert!(
            f64::from(sun.rgb[0]) > 0.95 * sun_energy,
            "{} vs {sun_energy}",
            sun.rgb[0]
        );
        // Its recorded spread covers the sun's 36 input pixels.
        let sun_solid_angle = sun_energy / 1e5;
        assert!(f64::from(sun.solid_angle) >= 0.9 * sun_solid_angle);
    }

    #[test]
    fn black_frame_gives_zero_lights_without_nan() {
        let frame = HdrFrame::new(64, 32, vec![[0.0; 3]; 64 * 32], Projection::LatLong).unwrap();
        for settings in [raw_settings(16), DecomposeSettings::default()] {
            let lights = Decomposer::new(settings).unwrap().decompose(&frame);
            for l in &lights.lights {
                assert_eq!(l.rgb, [0.0; 3]);
                assert!(l.dir.iter().all(|c| c.is_finite()));
                assert!(l.solid_angle.is_finite());
            }
        }
    }

    #[test]
    fn bad_pixels_count_as_zero_and_spare_their_neighbours() {
        // 64×32 takes the box-filter path (4×4 input pixels per working pixel at width 16);
        // 63×32 the index-table path.
        for (w, h) in [(64u32, 32u32), (63, 32)] {
            let mut frame = sky_with_sun(w, h, (10, 10), 100.0);
            frame.pixels[5] = [f32::NAN, f32::INFINITY, -3.0];
            frame.pixels[w as usize * 20 + 7] = [-1e4, 1.0, 1.0];
            frame.pixels[w as usize * 3 + 40] = [1.0, f32::NEG_INFINITY, 1.0];
            // Small enough that its working pixel's sum stays positive.
            frame.pixels[w as usize * 25 + 30] = [1.0, -0.5, 1.0];
            let mut clean = frame.clone();
            clean.sanitize();
            let truth = frame_integral(&clean);
            let settings = DecomposeSettings {
                working_width: 16,
                ..raw_settings(16)
            };
            let lights = Decomposer::new(settings).unwrap().decompose(&frame);
            assert!(lights.lights.iter().all(|l| l
                .rgb
                .iter()
                .chain(&l.dir)
                .all(|c| c.is_finite())));
            let sum = lights.total_rgb();
            for c in 0..3 {
                assert!(
                    (sum[c] - truth[c]).abs() < 1e-5 * truth[c],
                    "{w}x{h} channel {c}"
                );
            }
        }
    }

    /// Finite pixels near f32::MAX in a frame that was not sanitised: the lights' f64 sums
    /// pass f32's range, and each light saturates at f32::MAX instead of becoming ∞ (written
    /// as `null` in JSON), with the filter and the merge on as well.
    #[test]
    fn huge_finite_pixels_give_finite_lights() {
        let (w, h) = (32u32, 16u32);
        let frame =
            HdrFrame::new(w, h, vec![[3e38; 3]; (w * h) as usize], Projection::LatLong).unwrap();
        let with_filter_and_merge = DecomposeSettings {
            lights: 4,
            working_width: 16,
            ..DecomposeSettings::default()
        };
        for settings in [raw_settings(4), with_filter_and_merge] {
            let mut decomposer = Decomposer::new(settings).unwrap();
            for _ in 0..3 {
                let lights = decomposer.decompose(&frame);
                assert!(!lights.lights.is_empty());
                for light in &lights.lights {
                    assert!(
                        light.rgb.iter().all(|c| c.is_finite() && *c > 0.0),
                        "{light:?}"
                    );
                }
                assert!(lights.lights.iter().any(|l| l.rgb[0] == f32::MAX));
            }
        }
    }

    #[test]
    fn many_bad_pixels_stay_out_of_the_lights() {
        // 34×17 takes the index-table path. Five poisoned working pixels and one light: none of
        // them may be mistaken for a finite bright pixel (a NaN clamped to f32::MAX once was,
        // and its NaN energy reached the light).
        let (w, h) = (34u32, 17u32);
        let mut frame = sky_with_sun(w, h, (5, 5), 50.0);
        for i in [3usize, 100, 200, 301, 450] {
            frame.pixels[i] = [f32::NAN, f32::INFINITY, -2.0];
        }
        let mut clean = frame.clone();
        clean.sanitize();
        let truth = frame_integral(&clean);
        for n in [1, 4] {
            let settings = DecomposeSettings {
                working_width: 16,
                ..raw_settings(n)
            };
            let lights = Decomposer::new(settings).unwrap().decompose(&frame);
            let sum = lights.total_rgb();
            for c in 0..3 {
                assert!(
                    (sum[c] - truth[c]).abs() < 1e-5 * truth[c],
                    "n={n} channel {c}: {} vs {}",
                    sum[c],
                    truth[c]
                );
            }
        }
    }

    /// Every field's bits, so that lights compare exactly.
    fn light_bits(frame: &LightFrame) -> Vec<[u32; 8]> {
        frame
            .lights
            .iter()
            .map(|l| {
                let [x, y, z] = l.dir.map(f32::to_bits);
                let [r, g, b] = l.rgb.map(f32::to_bits);
                [l.id, x, y, z, r, g, b, l.solid_angle.to_bits()]
            })
            .collect()
    }

    #[test]
    fn reused_candidate_lists_give_the_lights_of_rebuilt_ones() {
        let path =
            std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/rooitou_park_1k.hdr");
        let image = crate::capture::image_file::read_hdr_image(&path).unwrap();
        let park =
            HdrFrame::new(image.width, image.height, image.pixels, Projection::LatLong).unwrap();
        // Turning a pixel per frame, then back (a jump of 20 pixels).
        let turning: Vec<HdrFrame> = (0..24).map(|i| park.turned_columns(i % 20)).collect();
        // Turning by a twentieth of a pixel per frame (blending with the map turned a pixel):
        // the sun's lights move less than the margin, so the lists are reused, and the sun's
        // concentrated pixels make the Lloyd step run on reused lists.
        let next = park.turned_columns(1);
        let creeping: Vec<HdrFrame> = (0..20)
            .map(|i| {
                let t = i as f32 / 20.0;
                let pixels = park
                    .pixels
                    .iter()
                    .zip(&next.pixels)
                    .map(|(a, b)| std::array::from_fn(|c| (1.0 - t) * a[c] + t * b[c]))
                    .collect();
                HdrFrame::new(park.width, park.height, pixels, park.projection).unwrap()
            })
            .collect();
        let options = crate::capture::sky::SkyOptions {
            width: 256,
            height: 128,
            ..Default::default()
        };
        let sky: Vec<HdrFrame> = (0..30)
            .map(|i| crate::capture::sky::render_sky(&options, f64::from(i) / 30.0))
            .collect();
        // Turning the map moves every point of the rows warp by more than the margin (the mass
        // that crosses the seam shifts every row's CDF), so its lists are rebuilt every frame;
        // on the sky and the creeping map the lights move slowly, so both paths must run there.
        for (name, frames, working_width, concentrated_lloyd, must_reuse) in [
            ("rooitou turning", &turning, 256, false, false),
            ("rooitou turning, Lloyd step", &turning, 256, true, false),
            ("sky", &sky, 128, false, true),
            ("rooitou creeping, Lloyd step", &creeping, 256, true, true),
        ] {
            let settings = DecomposeSettings {
                working_width,
                concentrated_lloyd,
                ..raw_settings(256)
            };
            let mut reusing = Decomposer::new(settings.clone()).unwrap();
            let mut rebuilding = Decomposer::new(settings).unwrap();
            rebuilding.set_candidate_reuse(false);
            for (i, frame) in frames.iter().enumerate() {
                assert_eq!(
                    light_bits(&reusing.decompose(frame)),
                    light_bits(&rebuilding.decompose(frame)),
                    "{name}: frame {i}"
                );
            }
            let (builds, staged) = (
                reusing.candidate_builds(),
                reusing.candidate_staged_builds(),
            );
            assert_eq!(rebuilding.candidate_builds(), frames.len() as u64);
            assert_eq!(rebuilding.candidate_staged_builds(), 0);
            if must_reuse {
                // Built again after the first frame (in full or in stages), and reused.
                assert!(
                    builds + staged > 1 && builds < frames.len() as u64,
                    "{name}: {builds} full and {staged} staged builds in {} frames",
                    frames.len()
                );
            }
        }
    }

    #[test]
    fn light_count_is_validated() {
        let bad = |n| Decomposer::new(raw_settings(n)).err();
        assert_eq!(bad(0), Some(DecomposeError::LightCount(0)));
        assert_eq!(
            bad(MAX_POINTS + 1),
            Some(DecomposeError::LightCount(MAX_POINTS + 1))
        );
        let frame = sky_with_sun(32, 16, (1, 1), 10.0);
        let mut d = Decomposer::new(raw_settings(8)).unwrap();
        assert!(d.decompose_with_count(&frame, 0).is_err());
        assert_eq!(d.decompose_with_count(&frame, 5).unwrap().lights.len(), 5);
        assert_eq!(d.decompose_with_count(&frame, 40).unwrap().lights.len(), 40);
    }

    #[test]
    fn resample_thread_count_is_validated() {
        for threads in [0, MAX_RESAMPLE_THREADS + 1] {
            let settings = DecomposeSettings {
                resample_threads: threads,
                ..DecomposeSettings::default()
            };
            assert_eq!(
                Decomposer::new(settings).err(),
                Some(DecomposeError::ResampleThreads(threads))
            );
        }
    }

    /// A fisheye camera's frames (the table path) give the same lights, bit for bit, whether
    /// they are resampled on the calling thread or on a pool of 2 or 3 threads (3 on a 2-core
    /// machine is capped at 2: the pool then differs from 1 only where there are 2 cores).
    #[test]
    fn lights_do_not_depend_on_the_resample_threads() {
        let projection = Projection::Fisheye(crate::envmap::FisheyeCalibration::default());
        // A sun that moves by a few pixels a frame over a sky with structure, seen by a 200×150
        // fisheye (a few bands of input rows).
        let frames: Vec<HdrFrame> = (0..4)
            .map(|t| {
                sky_with_sun(128, 64, (40 + 3 * t, 12), 500.0)
                    .reprojected(projection, 200, 150)
                    .unwrap()
            })
            .collect();
        let lights_with = |threads: usize| {
            let settings = DecomposeSettings {
                lights: 64,
                resample_threads: threads,
                ..DecomposeSettings::default()
            };
            let mut d = Decomposer::new(settings).unwrap();
            let lights: Vec<_> = frames.iter().map(|f| light_bits(&d.decompose(f))).collect();
            assert!(lights.iter().all(|l| l.len() == 64));
            lights
        };
        let one = lights_with(1);
        assert_eq!(lights_with(2), one);
        assert_eq!(lights_with(3), one);
    }

    /// Inputs whose pixels are larger than a working pixel (tiny frames, the rim of a
    /// stereographic lens near 360°): the lights' regions still tile the sphere (solid angles
    /// summing to 4π, not more), every light of a uniform map gets its share of power (none is
    /// left empty beside a lump), the lights sum to the integral, and a sun in such a frame
    /// keeps the sums. Large pixels are cut into sub-pixels (`working_map::PixelPart`) and a
    /// concentrated working pixel's input pixels share its solid angle.
    #[test]
    fn large_input_pixels_keep_solid_angles_and_power() {
        use crate::envmap::{FisheyeCalibration, FisheyeModel};
        let stereo = Projection::Fisheye(FisheyeCalibration {
            model: FisheyeModel::Stereographic,
            fov_deg: 350.0,
            ..FisheyeCalibration::default()
        });
        let fisheye = Projection::Fisheye(FisheyeCalibration::default());
        let stereo_359 = Projection::Fisheye(FisheyeCalibration {
            model: FisheyeModel::Stereographic,
            fov_deg: 359.0,
            ..FisheyeCalibration::default()
        });
        // Lat-long inputs narrower than the working width (256) are cut into sub-pixels too.
        let cases = [
            (Projection::AngularMap, 1, 1),
            (stereo_359, 64, 64),
            (Projection::AngularMap, 16, 16),
            (fisheye, 16, 16),
            (fisheye, 50, 50),
            (fisheye, 200, 200),
            (stereo, 16, 16),
            (stereo, 64, 64),
            (stereo, 200, 200),
            (Projection::LatLong, 1, 1),
            (Projection::LatLong, 17, 9),
            (Projection::LatLong, 64, 32),
            (Projection::LatLong, 200, 100),
            // Pixels long one way only: cut along that axis (split_factor).
            (Projection::LatLong, 2048, 1),
            (Projection::LatLong, 1024, 2),
            (Projection::LatLong, 1, 512),
        ];
        for (projection, width, height) in cases {
            let uniform = HdrFrame::new(
                width,
                height,
                vec![[1.0, 0.5, 0.25]; (width * height) as usize],
                projection,
            )
            .unwrap();
            // Suns at the zenith (where the working pixels are narrow wedges) and on the
            // horizon (a fisheye's rim).
            let sun = |row: u32| {
                sky_with_sun(64, 32, (20, row), 1e5)
                    .reprojected(projection, width, height)
                    .unwrap()
            };
            let frames = [
                ("uniform", uniform),
                ("zenith sun", sun(0)),
                ("rim sun", sun(15)),
            ];
            for (name, frame) in &frames {
                let what = format!("{name} {projection:?} {width}x{height}");
                let mut d = Decomposer::new(DecomposeSettings {
                    lights: 256,
                    filter_taps: None,
                    ..DecomposeSettings::default()
                })
                .unwrap();
                let lights = d.decompose(frame).lights;
                // The lights' regions cover the sphere the frame sees (a fisheye's field of
                // view), not the unseen rest.
                let solid_angle: f64 = lights.iter().map(|l| f64::from(l.solid_angle)).sum();
                let seen: f64 = projection.solid_angles(width, height).iter().sum();
                assert!(
                    (solid_angle - seen).abs() < 1e-5 * 4.0 * std::f64::consts::PI,
                    "{what}: solid angles sum to {solid_angle}, the frame sees {seen}"
                );
                let truth = frame_integral(frame);
                for c in 0..3 {
                    let sum: f64 = lights.iter().map(|l| f64::from(l.rgb[c])).sum();
                    assert!(
                        (sum - truth[c]).abs() <= 1e-5 * truth[c],
                        "{what}: {sum} {truth:?}"
                    );
                }
                if *name == "uniform" {
                    let dark = lights.iter().filter(|l| l.rgb[0] <= 0.0).count();
                    assert_eq!(dark, 0, "{what}: {dark} lights without power");
                }
            }
        }
    }
}
