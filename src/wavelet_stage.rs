//! The daemon's wavelet stage (`[wavelet]`): the newest frames as sparse wavelet coefficient
//! sets ([`crate::wavelet`], issue 7), computed on their own thread and published on a
//! latest-value channel for the stream server (representation 2, docs/protocol.md).
//!
//! ```text
//! envlight-decompose ──FrameFeed (one slot, newest wins)──► envlight-wavelet ──watch──► stream server
//!   (after publishing its lights)                          (WaveletTransformer)  Latest<WaveletFrame>
//! ```
//!
//! Per frame, the steps of [`WaveletTransformer::transform`]:
//! 1. **Resample** the frame onto the `side × side` equal-area octahedral map
//!    ([`crate::wavelet::sphere::Resampler`], energy-preserving splats). The resampling plan
//!    (per source pixel, the texels it reaches and their weights) is built once per frame
//!    size and projection and reused for every later frame of that shape; a frame of another
//!    shape builds a new one ([`WaveletStats::plans`] counts them).
//!    With [`WaveletSettings::filter_taps`] (the daemon passes `[decompose]`'s taps unless
//!    `[wavelet] filter = false`) the map is then filtered in time with the lights' FIR taps
//!    ([`crate::set_filter`]; frames the stage skipped are interpolated): the transform is
//!    linear, so the set describes the same moment as the lights of the same seq, with their
//!    delay (3 frames by default).
//! 2. **Transform** each channel with the orthonormal 2-D wavelet transform of `basis`, full
//!    pyramid (log2(side) levels, periodic boundary; [`crate::wavelet::transform`]), with one
//!    reused workspace.
//! 3. **Keep the K largest** coefficients by RGB norm ([`Coefficients::truncate`]: by Parseval
//!    the best K-term approximation in RGB L2), in index order, as a [`WaveletFrame`] with the
//!    frame's seq and time.
//!
//! Every step is deterministic, so the set of a frame does not depend on timing: what a client
//! receives equals [`crate::wavelet::approximate`] on
//! [`crate::wavelet::sphere::OctahedralMap::from_frame`] of the same frame (of the filtered
//! maps, when filtered), bit for bit.
//!
//! The thread is the generic runner of [`crate::slow_stage`], shared with the ASG stage
//! ([`crate::asg_stage`]): the decompose thread offers each
//! frame after publishing its lights, a live feed keeps only the newest (skips counted), a
//! lossless feed (replay) makes every frame transformed in order so a replay reproduces the
//! stream; a set the wire format would reject ([`validate_wavelet_set`]; a non-finite value from
//! a non-finite frame, say) or a frame that cannot be resampled is logged and counted
//! ([`WaveletStats::errors`]); [`DaemonStage::reconfigure`] (SIGHUP) swaps the settings before
//! the next frame; [`DaemonStage::join`] turns a panic into an error.

use crate::frame::HdrFrame;
use crate::publication::{Latest, StaleHandle};
use crate::set_filter::StageFilter;
use crate::slow_stage::{
    DaemonStage, PublishHook, SetStageStats, StageKind, StageStatsHandle, StageWorker,
};
use crate::stream::protocol::{validate_wavelet_set, WaveletFrame, MAX_FRAME_COEFFICIENTS};
use crate::wavelet::approx::{ApproxError, Coefficients};
use crate::wavelet::sphere::{Resampler, SphereError, MAX_SIDE};
use crate::wavelet::transform::{max_levels, Workspace};
use crate::wavelet::Basis;

/// Name of the wavelet thread.
pub const WAVELET_THREAD_NAME: &str = "envlight-wavelet";

/// Default basis: Haar. At the stage's coefficient budget (a few hundred) Haar is as good as
/// or better than the high-order bases on maps with a sun or lamps (docs/wavelets.md: up to 4×
/// fewer coefficients for the same error at K = 64 on sunny maps; the high-order bases win
/// from about K = 1024), its 2 taps make the cheapest transform, and a truncated Haar set does
/// not ring around a bright, compact source.
pub const DEFAULT_BASIS: Basis = Basis::Haar;
/// Default side of the octahedral map: 64 (4,096 texels of 3.1·10⁻³ sr, about 3.6° across).
pub const DEFAULT_SIDE: usize = 64;
/// Default number of coefficients kept per frame.
pub const DEFAULT_COEFFICIENTS: usize = 256;
/// Smallest side the stage accepts.
pub const MIN_SIDE: usize = 8;

/// What the stage computes.
#[derive(Clone, Debug, PartialEq)]
pub struct WaveletSettings {
    /// The wavelet basis.
    pub basis: Basis,
    /// Side of the octahedral map, a power of two in [`MIN_SIDE`]..=[`MAX_SIDE`].
    pub side: usize,
    /// Coefficients kept per frame, 1..=min(side², [`MAX_FRAME_COEFFICIENTS`]).
    pub coefficients: usize,
    /// FIR taps (newest first) that filter the octahedral maps in time, the lights' taps
    /// ([`crate::decompose::DecomposeSettings::filter_taps`]); `None`: each frame's own map.
    pub filter_taps: Option<Vec<f64>>,
}

impl Default for WaveletSettings {
    /// Haar, side 64, 256 coefficients, filtered with the lights' default taps.
    fn default() -> Self {
        Self {
            basis: DEFAULT_BASIS,
            side: DEFAULT_SIDE,
            coefficients: DEFAULT_COEFFICIENTS,
            filter_taps: Some(crate::decompose::filter::DEFAULT_TAPS.to_vec()),
        }
    }
}

impl WaveletSettings {
    /// Decomposition levels: the full pyramid, log2(side).
    pub fn levels(&self) -> u32 {
        max_levels(self.side)
    }

    /// Checks every field (the error names the field and the value).
    pub fn validate(&self) -> Result<(), WaveletStageError> {
        let bad = |field: &'static str, value: String, rule: String| {
            Err(WaveletStageError::Settings { field, value, rule })
        };
        if !self.basis.is_supported() {
            return bad(
                "basis",
                format!("{:?}", self.basis),
                "haar, db2..db10 or coif1..coif5".into(),
            );
        }
        if !(MIN_SIDE..=MAX_SIDE).contains(&self.side) || !self.side.is_power_of_two() {
            return bad(
                "side",
                self.side.to_string(),
                format!("a power of two in {MIN_SIDE}..={MAX_SIDE}"),
            );
        }
        let max = (self.side * self.side).min(MAX_FRAME_COEFFICIENTS);
        if !(1..=max).contains(&self.coefficients) {
            return bad(
                "coefficients",
                self.coefficients.to_string(),
                format!(
                    "1..={max} (at most side² = {} and what one frame message carries, {MAX_FRAME_COEFFICIENTS})",
                    self.side * self.side
                ),
            );
        }
        self.filter()?;
        Ok(())
    }

    /// The temporal filter the settings ask for.
    fn filter(&self) -> Result<StageFilter<f32>, WaveletStageError> {
        StageFilter::new(self.filter_taps.as_deref()).map_err(|rule| WaveletStageError::Settings {
            field: "filter_taps",
            value: format!("{:?}", self.filter_taps.as_deref().unwrap_or_default()),
            rule,
        })
    }
}

/// Errors of the wavelet stage.
#[derive(Debug, thiserror::Error)]
pub enum WaveletStageError {
    #[error("invalid [wavelet] setting {field} = {value}: must be {rule}")]
    Settings {
        field: &'static str,
        value: String,
        rule: String,
    },
    #[error("frame {seq}: cannot resample onto the octahedral map: {source}")]
    Resample {
        seq: u64,
        #[source]
        source: SphereError,
    },
    #[error("frame {seq}: wavelet transform failed: {source}")]
    Transform {
        seq: u64,
        #[source]
        source: ApproxError,
    },
    #[error("frame {seq}: the wavelet set would not be accepted on the wire: {source}")]
    Invalid {
        seq: u64,
        #[source]
        source: crate::stream::ProtocolError,
    },
    #[error("cannot start thread {WAVELET_THREAD_NAME}: {0}")]
    Spawn(#[source] std::io::Error),
    #[error("thread {WAVELET_THREAD_NAME} panicked: {0}")]
    Panicked(String),
}

/// Frames to wavelet sets, with the resampling plan and the transform's scratch space kept
/// from frame to frame. See the module documentation for the steps.
pub struct WaveletTransformer {
    settings: WaveletSettings,
    resampler: Option<Resampler>,
    workspace: Workspace,
    plans: u64,
    filter: StageFilter<f32>,
}

impl WaveletTransformer {
    /// A transformer with validated `settings`.
    pub fn new(settings: WaveletSettings) -> Result<Self, WaveletStageError> {
        settings.validate()?;
        let filter = settings.filter()?;
        Ok(Self {
            settings,
            resampler: None,
            workspace: Workspace::new(),
            plans: 0,
            filter,
        })
    }

    /// The temporal filter's delay in frames (0 without one).
    pub fn delay_frames(&self) -> f64 {
        self.filter.delay_frames()
    }

    /// The settings.
    pub fn settings(&self) -> &WaveletSettings {
        &self.settings
    }

    /// Resampling plans built so far (one per frame shape met, again after a shape change).
    pub fn plans(&self) -> u64 {
        self.plans
    }

    /// The set of `frame`: resample, filter in time if the settings ask (frames are taken to
    /// follow one another unless [`StageWorker::frame_number`] says how many were skipped),
    /// transform, keep the largest coefficients.
    pub fn transform(&mut self, frame: &HdrFrame) -> Result<WaveletFrame, WaveletStageError> {
        let seq = frame.seq;
        let side = self.settings.side;
        let resample_error = |source| WaveletStageError::Resample { seq, source };
        let resampler = match self.resampler.take() {
            Some(plan) if plan.fits(frame) => plan,
            _ => {
                self.plans += 1;
                Resampler::new(frame.projection, frame.width, frame.height, side)
                    .map_err(resample_error)?
            }
        };
        let map = resampler.resample(frame);
        self.resampler = Some(resampler);
        let mut texels = map.map_err(resample_error)?.into_texels();
        self.filter.apply(bytemuck::cast_slice_mut(&mut texels));
        let coefficients = Coefficients::analyze_with(
            &texels,
            side,
            self.settings.basis,
            self.settings.levels(),
            &mut self.workspace,
        )
        .map_err(|source| WaveletStageError::Transform { seq, source })?;
        let set = coefficients.truncate(self.settings.coefficients);
        validate_wavelet_set(&set).map_err(|source| WaveletStageError::Invalid { seq, source })?;
        Ok(WaveletFrame {
            seq,
            time: frame.time,
            set,
        })
    }
}

impl StageWorker for WaveletTransformer {
    type Output = WaveletFrame;
    type Error = WaveletStageError;

    fn process(&mut self, frame: &HdrFrame) -> Result<WaveletFrame, WaveletStageError> {
        self.transform(frame)
    }

    fn plans(&self) -> u64 {
        self.plans
    }

    fn frame_number(&mut self, number: u64) {
        self.filter.set_next_number(number);
    }

    /// New settings keep the resampling plan when the side is unchanged (it depends on the
    /// frame's shape and the side alone: at 1024×512 a new one takes about 0.2 s, during which
    /// the stage skips frames); everything else, the filter included, is the new worker's.
    fn take_over(&mut self, new: Self) {
        let plan = self
            .resampler
            .take()
            .filter(|plan| plan.side() == new.settings.side);
        let plans = self.plans;
        *self = new;
        self.resampler = plan;
        self.plans = plans;
    }
}

impl StageKind for WaveletTransformer {
    type Settings = WaveletSettings;
    type Stats = WaveletStats;
    type SettingsError = WaveletStageError;
    type StageError = WaveletStageError;
    const THREAD_NAME: &'static str = WAVELET_THREAD_NAME;

    fn from_settings(settings: WaveletSettings) -> Result<Self, WaveletStageError> {
        Self::new(settings)
    }

    fn log_start(&self, lossless: bool) {
        let settings = &self.settings;
        tracing::info!(
            basis = %settings.basis,
            side = settings.side,
            levels = settings.levels(),
            coefficients = settings.coefficients,
            filter_delay_frames = self.delay_frames(),
            lossless,
            "starting the wavelet stage"
        );
    }

    fn spawn_error(error: std::io::Error) -> WaveletStageError {
        WaveletStageError::Spawn(error)
    }

    fn panic_error(message: String) -> WaveletStageError {
        WaveletStageError::Panicked(message)
    }
}

/// One publication of the wavelet stage: the set is the
/// [`Publication::payload`](crate::publication::Publication::payload),
/// `compute_time` the time of the three steps.
pub type PublishedWavelet = crate::publication::Publication<WaveletFrame>;

/// What wavelet consumers receive: the newest publication, `None` until the first one.
pub type LatestWavelet = Latest<WaveletFrame>;

/// Marks the newest wavelet set stale; see [`DaemonStage::mark_stale`].
pub type WaveletStaleHandle = StaleHandle<WaveletFrame>;

/// Called on the wavelet thread after each published set (metrics).
pub type WaveletHook = PublishHook<WaveletFrame>;

/// Counters of the wavelet stage (errors: resampling failed, invalid values; plans: resampling
/// plans, one per frame size and projection met; `last_time`: the most recent set — resample,
/// transform, selection).
pub type WaveletStats = SetStageStats;

/// The running wavelet stage ([`DaemonStage`]: start, feed, subscribe, reconfigure, join).
/// See the module documentation.
pub type WaveletStage = DaemonStage<WaveletTransformer>;

/// Reads the stage's counters; valid after the stage has ended.
pub type WaveletStatsHandle = StageStatsHandle<WaveletTransformer>;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::envmap::Projection;
    use crate::frame_feed::CloseOnDrop;
    use crate::set_filter::SetFilter;
    use crate::wavelet::sphere::OctahedralMap;
    use std::sync::Arc;

    fn frame(seq: u64, width: u32) -> HdrFrame {
        let height = width / 2;
        let pixels = (0..width * height)
            .map(|i| {
                let v = 0.1 + ((i * 13 + seq as u32 * 5) % 17) as f32;
                [v, 0.5 * v, 0.25 * v]
            })
            .collect();
        let mut f = HdrFrame::new(width, height, pixels, Projection::LatLong).unwrap();
        f.seq = seq;
        f.time = seq as f64 / 30.0;
        f
    }

    fn settings() -> WaveletSettings {
        WaveletSettings {
            basis: Basis::Daubechies(2),
            side: 16,
            coefficients: 40,
            filter_taps: None,
        }
    }

    fn filtered() -> WaveletSettings {
        WaveletSettings {
            filter_taps: Some(crate::decompose::filter::DEFAULT_TAPS.to_vec()),
            ..settings()
        }
    }

    #[test]
    fn the_transformer_equals_the_library_and_plans_once_per_shape() {
        let mut t = WaveletTransformer::new(settings()).unwrap();
        for (seq, width) in [(0, 32), (1, 32), (2, 32), (3, 64), (4, 64)] {
            let f = frame(seq, width);
            let got = t.transform(&f).unwrap();
            let map = OctahedralMap::from_frame(&f, 16).unwrap();
            let want =
                crate::wavelet::approximate(map.texels(), 16, Basis::Daubechies(2), 4, 40).unwrap();
            assert_eq!(got.set, want, "seq {seq}");
            assert_eq!((got.seq, got.time), (seq, f.time));
        }
        assert_eq!(t.plans(), 2, "one plan per frame size");
    }

    /// New settings of the same side keep the resampling plan (a reload rebuilt it every
    /// time, about 0.2 s at 1024×512); a new side makes a new one. Each set is the new
    /// settings' all the same.
    #[test]
    fn a_reconfiguration_keeps_the_plan_while_the_side_stays() {
        let mut t = WaveletTransformer::new(settings()).unwrap();
        t.transform(&frame(0, 32)).unwrap();
        let fewer = WaveletSettings {
            coefficients: 10,
            ..filtered()
        };
        t.take_over(WaveletTransformer::new(fewer.clone()).unwrap());
        let got = t.transform(&frame(1, 32)).unwrap();
        let mut fresh = WaveletTransformer::new(fewer).unwrap();
        assert_eq!(got, fresh.transform(&frame(1, 32)).unwrap());
        assert_eq!(t.plans(), 1, "the plan kept");
        let larger = WaveletSettings {
            side: 32,
            ..settings()
        };
        t.take_over(WaveletTransformer::new(larger.clone()).unwrap());
        let got = t.transform(&frame(2, 32)).unwrap();
        let mut fresh = WaveletTransformer::new(larger).unwrap();
        assert_eq!(got, fresh.transform(&frame(2, 32)).unwrap());
        assert_eq!(t.plans(), 2, "a new plan for the new side");
    }

    /// Filtered, the stage's set is the library's set of the octahedral maps through the
    /// lights' FIR taps, with the frames the stage skipped (a gap in the feed's numbers)
    /// filled in.
    #[test]
    fn the_filtered_transformer_is_the_library_on_filtered_maps() {
        let mut t = WaveletTransformer::new(filtered()).unwrap();
        assert_eq!(t.delay_frames(), 3.0);
        let mut reference = SetFilter::<f32>::new(&crate::decompose::filter::DEFAULT_TAPS).unwrap();
        let mut differs = false;
        for number in [0u64, 1, 2, 4, 5, 9, 10, 11] {
            let f = frame(number, 32);
            t.frame_number(number);
            let got = t.transform(&f).unwrap();
            let mut texels = OctahedralMap::from_frame(&f, 16).unwrap().into_texels();
            let approximate = |texels: &[[f32; 3]]| {
                crate::wavelet::approximate(texels, 16, Basis::Daubechies(2), 4, 40).unwrap()
            };
            let unfiltered = approximate(&texels);
            reference.apply(number, bytemuck::cast_slice_mut(&mut texels));
            assert_eq!(got.set, approximate(&texels), "frame {number}");
            differs |= got.set != unfiltered;
        }
        assert!(
            differs,
            "the frames change, so filtering must change the sets"
        );
    }

    #[test]
    fn settings_are_checked_field_by_field() {
        for (bad, field) in [
            (
                WaveletSettings {
                    side: 48,
                    ..settings()
                },
                "side",
            ),
            (
                WaveletSettings {
                    side: 4,
                    ..settings()
                },
                "side",
            ),
            (
                WaveletSettings {
                    coefficients: 0,
                    ..settings()
                },
                "coefficients",
            ),
            (
                WaveletSettings {
                    coefficients: 257,
                    ..settings()
                },
                "coefficients",
            ),
            (
                WaveletSettings {
                    basis: Basis::Daubechies(11),
                    ..settings()
                },
                "basis",
            ),
            (
                WaveletSettings {
                    filter_taps: Some(vec![0.0; 3]),
                    ..settings()
                },
                "filter_taps",
            ),
        ] {
            match WaveletStage::start(bad.clone(), false, None) {
                Err(WaveletStageError::Settings { field: f, .. }) => assert_eq!(f, field),
                other => panic!("{bad:?}: {:?}", other.err()),
            }
        }
        assert!(WaveletSettings::default().validate().is_ok());
    }

    #[test]
    fn lossless_stage_transforms_every_frame_and_stale_republishes() {
        let stage = WaveletStage::start(filtered(), true, None).unwrap();
        let mut rx = stage.subscribe();
        let feed = stage.feed();
        let sender = std::thread::Builder::new()
            .name("test-feeder".into())
            .spawn(move || {
                let _close = CloseOnDrop(feed.clone());
                for seq in 0..6 {
                    feed.offer(frame(seq, 32));
                }
            })
            .unwrap();
        let mut seen = Vec::new();
        let rt = tokio::runtime::Builder::new_current_thread()
            .build()
            .unwrap();
        rt.block_on(async {
            while rx.changed().await.is_ok() {
                let p = rx.borrow_and_update().clone().unwrap();
                let last = p.payload.seq == 5;
                seen.push(p);
                if last {
                    break;
                }
            }
        });
        sender.join().unwrap();
        let live = stage.subscribe().borrow().clone().unwrap();
        assert!(stage.mark_stale());
        let stale = stage.subscribe().borrow().clone().unwrap();
        assert!(stale.stale && Arc::ptr_eq(&stale.payload, &live.payload));
        let stats = stage.join().unwrap();
        assert_eq!(
            (stats.frames_offered, stats.frames_skipped, stats.sets),
            (6, 0, 6)
        );
        assert_eq!((stats.errors, stats.plans), (0, 1));
        // Every frame in order through a transformer of its own (filtered: each set depends on
        // the frames before it), compared where the receiver looked (it may skip sets).
        let mut t = WaveletTransformer::new(filtered()).unwrap();
        let want: Vec<WaveletFrame> = (0..6)
            .map(|seq| t.transform(&frame(seq, 32)).unwrap())
            .collect();
        for p in &seen {
            assert_eq!(*p.payload, want[p.payload.seq as usize]);
        }
        assert_eq!(live.index, 6, "every set was published");
    }
}
