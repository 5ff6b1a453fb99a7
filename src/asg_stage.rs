//! The daemon's ASG stage (`[asg]`): fits anisotropic spherical Gaussians ([`crate::asg::fit`])
//! to the newest frames on its own thread and publishes each set on a latest-value channel.
//!
//! ```text
//! envlight-decompose ──AsgFeed (one slot, newest wins)──► envlight-asg ──watch──► stream server
//!   (after publishing its lights)                           (AsgFitter)      Option<Arc<PublishedAsg>>
//! ```
//!
//! - **Never slows the lights.** A fit takes far longer than a decomposition. The decompose
//!   thread hands each frame to the stage *after* publishing its lights ([`AsgFeed::offer`]):
//!   the feed is a single slot, and a frame that is still waiting when a newer one arrives is
//!   replaced and counted in [`AsgStats::frames_skipped`]. The decompose thread never waits
//!   (live sources).
//! - **Replay is lossless.** With [`AsgFeed::new`]`(true)` (the daemon's replay mode, like the
//!   pipeline's [`crate::pipeline::QueuePolicy::Block`]) `offer` waits until the slot is free,
//!   so every frame is fitted in order and the ASG stream of a recording is reproducible (the
//!   fit is deterministic: its sums are split in fixed bands, independent of the thread count).
//!   The lights then advance at the fit's pace.
//! - **Thread** `envlight-asg` (the generic runner of [`crate::slow_stage`]) runs an
//!   [`AsgFitter`]: the first frame is fitted from scratch,
//!   every later one is warm-started from the previous lobes (skipped frames simply are not
//!   part of that chain).
//! - **In time.** With [`AsgSettings::filter_taps`] (the daemon passes `[decompose]`'s taps
//!   unless `[asg] filter = false`) the fitted lobes are then filtered by id with the lights'
//!   FIR taps ([`crate::asg::temporal`]), so that the set of seq s describes the same moment as
//!   the lights of seq s (both lag the frames by the filter's delay, 3 frames by default)
//!   instead of leading them. Frames the stage skipped are filled in from the feed's frame
//!   numbers ([`crate::frame_feed::FedFrame::number`]) so the delay stays the lights' in
//!   frames. The fitter's warm starts go on from its own, unfiltered lobes.
//! - **Publication.** Each result is published as a [`PublishedAsg`] (a
//!   [`crate::publication::Publication`], numbered like the lights', so a consumer can count
//!   what it skipped) with its fit time. A frame that cannot be fitted, or whose fit has a
//!   lobe the wire format rejects ([`crate::stream::protocol::validate_lobe`]), is logged and
//!   counted
//!   ([`AsgStats::fit_errors`]); the stage goes on with the next one.
//! - **Reconfiguration** ([`AsgStage::reconfigure`], SIGHUP) swaps in a new fitter before the
//!   next frame (the warm-start chain restarts); new filter taps alone, or a restart of the
//!   filter with the lights', keep the fitter and its chain ([`StageWorker::take_over`]).
//! - **End.** Closing the feed ([`AsgFeed::close`]; the pipeline does it when its decompose
//!   thread ends) lets the stage fit the frame still waiting and end; [`AsgStage::join`] waits
//!   for it. A panic in the thread becomes an error of `join`, never a panic in the caller.

use crate::asg::fit::{AsgFitter, FitSettings};
use crate::asg::temporal::LobeFilter;
use crate::asg::AsgError;
use crate::frame::HdrFrame;
pub use crate::frame_feed::CloseOnDrop;
use crate::frame_feed::FrameFeed;
use crate::light::AsgSet;
use crate::publication::{Latest, Publication};
use crate::slow_stage::{
    DaemonStage, PublishHook, StageCounters, StageKind, StageStatsHandle, StageWorker,
};
use std::sync::Arc;
use std::time::Duration;

/// Name of the ASG thread.
pub const ASG_THREAD_NAME: &str = "envlight-asg";

/// One publication of the ASG stage: the fitted set is the [`Publication::payload`],
/// [`Publication::compute_time`] the fit time.
pub type PublishedAsg = Publication<AsgSet>;

/// What ASG consumers receive: the newest publication, `None` until the first one.
pub type LatestAsg = Latest<AsgSet>;

/// Counters of the ASG stage.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct AsgStats {
    /// Frames offered to the stage.
    pub frames_offered: u64,
    /// Frames replaced by a newer one before the stage took them.
    pub frames_skipped: u64,
    /// Sets fitted and published.
    pub fits: u64,
    /// Frames whose fit failed.
    pub fit_errors: u64,
    /// Duration of the most recent fit.
    pub last_fit_time: Duration,
}

impl From<StageCounters> for AsgStats {
    fn from(c: StageCounters) -> Self {
        Self {
            frames_offered: c.offered,
            frames_skipped: c.skipped,
            fits: c.published,
            fit_errors: c.errors,
            last_fit_time: c.last_time,
        }
    }
}

/// What the stage computes: the fit, and the lobes' filter in time.
#[derive(Clone, Debug, PartialEq)]
pub struct AsgSettings {
    /// The fitter's settings.
    pub fit: FitSettings,
    /// FIR taps (newest first) that filter the lobes in time ([`crate::asg::temporal`]), the
    /// lights' taps ([`crate::decompose::DecomposeSettings::filter_taps`]); `None`: each
    /// frame's own fit.
    pub filter_taps: Option<Vec<f64>>,
}

impl Default for AsgSettings {
    /// The fitter's defaults, filtered with the lights' default taps.
    fn default() -> Self {
        Self {
            fit: FitSettings::default(),
            filter_taps: Some(crate::decompose::filter::DEFAULT_TAPS.to_vec()),
        }
    }
}

impl AsgSettings {
    /// The lobes' filter in time the settings ask for.
    pub fn filter(&self) -> Result<LobeFilter, AsgStageError> {
        LobeFilter::new(self.filter_taps.as_deref()).map_err(|rule| AsgStageError::FilterTaps {
            value: format!("{:?}", self.filter_taps.as_deref().unwrap_or_default()),
            rule,
        })
    }
}

/// Errors of the ASG stage.
#[derive(Debug, thiserror::Error)]
pub enum AsgStageError {
    #[error("invalid [asg] settings: {0}")]
    Settings(#[from] AsgError),
    #[error("invalid [asg] setting filter_taps = {value}: must be {rule}")]
    FilterTaps { value: String, rule: String },
    #[error("frame {seq}: ASG fit failed: {source}")]
    Fit {
        seq: u64,
        #[source]
        source: AsgError,
    },
    #[error("frame {seq}: the fit has a lobe the wire format rejects: {source}")]
    InvalidLobe {
        seq: u64,
        #[source]
        source: crate::stream::ProtocolError,
    },
    #[error("cannot start thread {ASG_THREAD_NAME}: {0}")]
    Spawn(#[source] std::io::Error),
    #[error("thread {ASG_THREAD_NAME} panicked: {0}")]
    Panicked(String),
}

/// The hand-off from the decompose thread to the ASG stage (see [`FrameFeed`]).
pub type AsgFeed = FrameFeed;

/// Called on the ASG thread after each published set (metrics).
pub type AsgHook = PublishHook<AsgSet>;

/// The stage's work per frame: a warm-started fit, filtered in time when the settings ask,
/// checked against the wire format.
pub struct AsgWorker {
    fitter: AsgFitter,
    filter: LobeFilter,
}

impl AsgWorker {
    /// A worker for `settings` (checked: the error names the setting).
    pub fn new(settings: AsgSettings) -> Result<Self, AsgStageError> {
        let filter = settings.filter()?;
        Ok(Self {
            fitter: AsgFitter::new(settings.fit)?,
            filter,
        })
    }

    /// The filter's delay in frames (0 without one).
    pub fn delay_frames(&self) -> f64 {
        self.filter.delay_frames()
    }
}

impl StageWorker for AsgWorker {
    type Output = AsgSet;
    type Error = AsgStageError;

    fn process(&mut self, frame: &HdrFrame) -> Result<AsgSet, AsgStageError> {
        let seq = frame.seq;
        let mut lobes = self
            .fitter
            .fit_frame(frame)
            .map_err(|source| AsgStageError::Fit { seq, source })?
            .lobes;
        // The fitter keeps its own (unfiltered) lobes for the next warm start.
        self.filter.apply(&mut lobes);
        let set = AsgSet::from_fit(seq, frame.time, &lobes);
        // Never publish what a client's decoder would reject (and close on).
        for (i, lobe) in set.lobes.iter().enumerate() {
            crate::stream::protocol::validate_lobe(i, lobe)
                .map_err(|source| AsgStageError::InvalidLobe { seq, source })?;
        }
        Ok(set)
    }

    fn watch_abandon(&mut self, flag: Arc<std::sync::atomic::AtomicBool>) {
        self.fitter.watch_cancel(flag);
    }

    fn frame_number(&mut self, number: u64) {
        self.filter.set_next_number(number);
    }

    /// New fit settings start a new fitter (the warm-start chain restarts); a new filter alone
    /// (the lights' filter restarted, or new taps) keeps the fitter and its chain.
    fn take_over(&mut self, new: Self) {
        if new.fitter.settings() == self.fitter.settings() {
            self.filter = new.filter;
        } else {
            *self = new;
        }
    }
}

impl StageKind for AsgWorker {
    type Settings = AsgSettings;
    type Stats = AsgStats;
    type SettingsError = AsgStageError;
    type StageError = AsgStageError;
    const THREAD_NAME: &'static str = ASG_THREAD_NAME;

    fn from_settings(settings: AsgSettings) -> Result<Self, AsgStageError> {
        Self::new(settings)
    }

    fn log_start(&self, lossless: bool) {
        let settings = self.fitter.settings();
        tracing::info!(
            lobes = settings.lobes,
            height = settings.height,
            iterations = settings.iterations,
            warm_iterations = settings.warm_iterations,
            filter_delay_frames = self.delay_frames(),
            lossless,
            "starting the ASG stage"
        );
    }

    fn spawn_error(error: std::io::Error) -> AsgStageError {
        AsgStageError::Spawn(error)
    }

    fn panic_error(message: String) -> AsgStageError {
        AsgStageError::Panicked(message)
    }
}

/// The running ASG stage ([`DaemonStage`]: start, feed, subscribe, reconfigure, join). See
/// the module documentation.
pub type AsgStage = DaemonStage<AsgWorker>;

/// Reads the stage's counters; valid after the stage has ended.
pub type AsgStatsHandle = StageStatsHandle<AsgWorker>;

/// Marks the newest ASG set stale; see [`DaemonStage::mark_stale`].
pub type AsgStaleHandle = crate::publication::StaleHandle<AsgSet>;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::envmap::Projection;
    use crate::frame::HdrFrame;
    use std::sync::Arc;

    fn frame(seq: u64) -> HdrFrame {
        let (w, h) = (32u32, 16u32);
        let pixels = (0..w * h)
            .map(|i| {
                let v = 0.2 + ((i * 7 + seq as u32) % 11) as f32;
                [v, 0.5 * v, 0.25 * v]
            })
            .collect();
        let mut f = HdrFrame::new(w, h, pixels, Projection::LatLong).unwrap();
        f.seq = seq;
        f.time = seq as f64 / 30.0;
        f
    }

    fn fit_settings() -> FitSettings {
        FitSettings {
            lobes: 3,
            height: 8,
            iterations: 10,
            warm_iterations: 3,
            diffuse_normals: 16,
            threads: 1,
            ..FitSettings::default()
        }
    }

    fn settings() -> AsgSettings {
        AsgSettings {
            fit: fit_settings(),
            ..AsgSettings::default()
        }
    }

    #[test]
    fn lossless_stage_fits_every_frame_like_a_plain_fitter() {
        let stage = AsgStage::start(settings(), true, None).unwrap();
        let mut rx = stage.subscribe();
        let feed = stage.feed();
        let sender = std::thread::Builder::new()
            .name("test-feeder".into())
            .spawn(move || {
                let _close = CloseOnDrop(feed.clone());
                for seq in 0..5 {
                    feed.offer(frame(seq));
                }
            })
            .unwrap();
        let mut seen = Vec::new();
        let rt = tokio::runtime::Builder::new_current_thread()
            .enable_time()
            .build()
            .unwrap();
        rt.block_on(async {
            while rx.changed().await.is_ok() {
                let p = rx.borrow_and_update().clone().unwrap();
                seen.push(p);
                if seen.last().unwrap().payload.seq == 4 {
                    break;
                }
            }
        });
        sender.join().unwrap();
        let stats = stage.join().unwrap();
        assert_eq!(stats.frames_skipped, 0);
        assert_eq!(stats.fits, 5);
        assert_eq!(stats.frames_offered, 5);
        // Same lobes as a fitter run over the same frames in order, through the lobes'
        // filter with the lights' default taps.
        let mut fitter = AsgFitter::new(fit_settings()).unwrap();
        let mut filter = LobeFilter::new(Some(&crate::decompose::filter::DEFAULT_TAPS)).unwrap();
        let mut want = Vec::new();
        let mut filtering_changed_a_set = false;
        for seq in 0..5 {
            let fitted = fitter.fit_frame(&frame(seq)).unwrap().lobes;
            let mut lobes = fitted.clone();
            filter.apply(&mut lobes);
            filtering_changed_a_set |= lobes != fitted;
            want.push(AsgSet::from_fit(seq, seq as f64 / 30.0, &lobes));
        }
        assert!(
            filtering_changed_a_set,
            "the fits change, so filtering must change them"
        );
        let last = seen.last().unwrap();
        assert_eq!(*last.payload, want[4]);
        assert_eq!(last.index, 5, "every fit was published");
        for p in &seen {
            assert_eq!(*p.payload, want[p.payload.seq as usize]);
        }
    }

    /// New taps alone keep the fitter's warm-start chain; new fit settings start a new one.
    #[test]
    fn a_new_filter_keeps_the_warm_start_chain_and_new_fit_settings_restart_it() {
        let mut worker = AsgWorker::new(settings()).unwrap();
        let mut chain = AsgFitter::new(fit_settings()).unwrap();
        for seq in 0..2 {
            worker.process(&frame(seq)).unwrap();
            chain.fit_frame(&frame(seq)).unwrap();
        }
        let unfiltered = AsgSettings {
            filter_taps: None,
            ..settings()
        };
        worker.take_over(AsgWorker::new(unfiltered.clone()).unwrap());
        assert_eq!(worker.delay_frames(), 0.0);
        let warm = chain.fit_frame(&frame(2)).unwrap().lobes;
        let got = worker.process(&frame(2)).unwrap();
        assert_eq!(
            got,
            AsgSet::from_fit(2, frame(2).time, &warm),
            "the chain went on"
        );

        let other_fit = AsgSettings {
            fit: FitSettings {
                warm_iterations: 2,
                ..fit_settings()
            },
            ..unfiltered
        };
        worker.take_over(AsgWorker::new(other_fit.clone()).unwrap());
        let fresh = AsgFitter::new(other_fit.fit)
            .unwrap()
            .fit_frame(&frame(3))
            .unwrap()
            .lobes;
        let got = worker.process(&frame(3)).unwrap();
        assert_eq!(
            got,
            AsgSet::from_fit(3, frame(3).time, &fresh),
            "a new chain"
        );
    }

    #[test]
    fn bad_settings_are_rejected_and_stale_republishes() {
        let bad = AsgSettings {
            fit: FitSettings {
                lobes: 0,
                ..fit_settings()
            },
            ..settings()
        };
        assert!(matches!(
            AsgStage::start(bad.clone(), false, None),
            Err(AsgStageError::Settings(_))
        ));
        let bad_taps = AsgSettings {
            filter_taps: Some(vec![1.0, -2.0]),
            ..settings()
        };
        let e = AsgStage::start(bad_taps, false, None).err().unwrap();
        assert!(e.to_string().contains("filter_taps = [1.0, -2.0]"), "{e}");
        let stage = AsgStage::start(settings(), false, None).unwrap();
        assert!(stage.reconfigure(bad).is_err());
        assert!(!stage.mark_stale(), "nothing published yet");
        stage.feed().offer(frame(0));
        while stage.stats().fits == 0 {
            std::thread::sleep(Duration::from_millis(1));
        }
        let live = stage.subscribe().borrow().clone().unwrap();
        assert!(stage.mark_stale());
        let stale = stage.subscribe().borrow().clone().unwrap();
        assert!(stale.stale && Arc::ptr_eq(&stale.payload, &live.payload));
        assert_eq!(stale.index, live.index + 1);
        let stats = stage.join().unwrap();
        assert_eq!(stats.fits, 1);
    }
}
