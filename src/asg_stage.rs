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
//! - **Thread** `envlight-asg` runs an [`AsgFitter`]: the first frame is fitted from scratch,
//!   every later one is warm-started from the previous lobes (skipped frames simply are not
//!   part of that chain). Each result is published as a [`PublishedAsg`] (a
//!   [`crate::publication::Publication`], numbered like the lights', so a consumer can count
//!   what it skipped) with its fit time. A frame that cannot be fitted, or whose fit has a lobe the wire format rejects
//!   ([`crate::stream::protocol::validate_lobe`]), is logged and counted
//!   ([`AsgStats::fit_errors`]); the stage goes on with the next one.
//! - **Reconfiguration** ([`AsgStage::reconfigure`], SIGHUP) swaps in a new fitter before the
//!   next frame (the warm-start chain restarts).
//! - **End.** Closing the feed ([`AsgFeed::close`]; the pipeline does it when its decompose
//!   thread ends) lets the stage fit the frame still waiting and end; [`AsgStage::join`] waits
//!   for it. A panic in the thread becomes an error of `join`, never a panic in the caller.

use crate::asg::fit::{AsgFitter, FitSettings};
use crate::asg::AsgError;
pub use crate::frame_feed::CloseOnDrop;
use crate::frame_feed::FrameFeed;
use crate::light::AsgSet;
use crate::publication::{publish, Latest, Publication};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};
use tokio::sync::watch;

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

/// Errors of the ASG stage.
#[derive(Debug, thiserror::Error)]
pub enum AsgStageError {
    #[error("invalid [asg] settings: {0}")]
    Settings(#[from] AsgError),
    #[error("cannot start thread {ASG_THREAD_NAME}: {0}")]
    Spawn(#[source] std::io::Error),
    #[error("thread {ASG_THREAD_NAME} panicked: {0}")]
    Panicked(String),
}

/// The hand-off from the decompose thread to the ASG stage (see [`FrameFeed`]).
pub type AsgFeed = FrameFeed;

/// Called on the ASG thread after each published set (metrics).
pub type AsgHook = Arc<dyn Fn(&PublishedAsg) + Send + Sync>;

#[derive(Default)]
struct Shared {
    fits: AtomicU64,
    fit_errors: AtomicU64,
    last_fit_nanos: AtomicU64,
    pending: Mutex<Option<AsgFitter>>,
}

/// The running ASG stage. See the module documentation.
pub struct AsgStage {
    feed: AsgFeed,
    shared: Arc<Shared>,
    tx: Arc<watch::Sender<LatestAsg>>,
    rx: watch::Receiver<LatestAsg>,
    handle: JoinHandle<()>,
}

impl AsgStage {
    /// Validates `settings` and starts the `envlight-asg` thread, fed by a new feed
    /// (`lossless` as in [`AsgFeed::new`]). `on_publish` runs on the thread after each set.
    pub fn start(
        settings: FitSettings,
        lossless: bool,
        on_publish: Option<AsgHook>,
    ) -> Result<AsgStage, AsgStageError> {
        let mut fitter = AsgFitter::new(settings)?;
        let feed = AsgFeed::new(lossless);
        let shared = Arc::new(Shared::default());
        let (tx, rx) = watch::channel::<LatestAsg>(None);
        let tx = Arc::new(tx);
        let (thread_feed, thread_shared, thread_tx) =
            (feed.clone(), Arc::clone(&shared), Arc::clone(&tx));
        tracing::info!(
            lobes = fitter.settings().lobes,
            height = fitter.settings().height,
            iterations = fitter.settings().iterations,
            warm_iterations = fitter.settings().warm_iterations,
            lossless,
            "starting the ASG stage"
        );
        let handle = std::thread::Builder::new()
            .name(ASG_THREAD_NAME.to_owned())
            .spawn(move || {
                // If this thread dies, the feed must not make a lossless sender wait forever.
                let _close = CloseOnDrop(thread_feed.clone());
                while let Some((frame, arrived)) = thread_feed.take() {
                    if let Some(new) = thread_shared
                        .pending
                        .lock()
                        .unwrap_or_else(std::sync::PoisonError::into_inner)
                        .take()
                    {
                        fitter = new;
                    }
                    let started = Instant::now();
                    let result = fitter.fit_frame(&frame);
                    let elapsed = started.elapsed();
                    let result = match result {
                        Ok(result) => result,
                        Err(error) => {
                            thread_shared.fit_errors.fetch_add(1, Ordering::AcqRel);
                            tracing::warn!(seq = frame.seq, %error, "ASG fit failed; skipping the frame");
                            continue;
                        }
                    };
                    let set = AsgSet::from_fit(frame.seq, frame.time, &result.lobes);
                    // Never publish what a client's decoder would reject (and close on).
                    let invalid = set.lobes.iter().enumerate().find_map(|(i, lobe)| {
                        crate::stream::protocol::validate_lobe(i, lobe).err()
                    });
                    if let Some(error) = invalid {
                        thread_shared.fit_errors.fetch_add(1, Ordering::AcqRel);
                        tracing::warn!(seq = frame.seq, %error, "ASG fit produced an invalid lobe; skipping the frame");
                        continue;
                    }
                    let set = Arc::new(set);
                    let nanos = u64::try_from(elapsed.as_nanos()).unwrap_or(u64::MAX);
                    thread_shared
                        .last_fit_nanos
                        .store(nanos, Ordering::Release);
                    thread_shared.fits.fetch_add(1, Ordering::AcqRel);
                    publish(&thread_tx, set, Some(arrived), elapsed);
                    if let Some(hook) = &on_publish {
                        if let Some(published) = thread_tx.borrow().as_ref() {
                            hook(published);
                        }
                    }
                }
            })
            .map_err(AsgStageError::Spawn)?;
        Ok(AsgStage {
            feed,
            shared,
            tx,
            rx,
            handle,
        })
    }

    /// The feed to hand frames to (give it to the pipeline).
    pub fn feed(&self) -> AsgFeed {
        self.feed.clone()
    }

    /// A receiver of the newest ASG set; a set published already shows as changed.
    pub fn subscribe(&self) -> watch::Receiver<LatestAsg> {
        self.rx.clone()
    }

    /// A snapshot of the counters.
    pub fn stats(&self) -> AsgStats {
        stats(&self.feed, &self.shared)
    }

    /// A handle that reads the counters from anywhere (the metrics endpoint).
    pub fn stats_handle(&self) -> AsgStatsHandle {
        AsgStatsHandle(self.feed.clone(), Arc::clone(&self.shared))
    }

    /// Replaces the fit settings from the next frame on (a new fitter: the next frame is
    /// fitted from scratch). Invalid settings are rejected and change nothing.
    pub fn reconfigure(&self, settings: FitSettings) -> Result<(), AsgError> {
        let fitter = AsgFitter::new(settings)?;
        *self
            .shared
            .pending
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner) = Some(fitter);
        Ok(())
    }

    /// Marks the newest set stale (the source is lost) or live again, re-publishing it on a
    /// change. Returns whether anything was published.
    pub fn set_stale(&self, stale: bool) -> bool {
        self.stale_handle().set_stale(stale)
    }

    /// A handle for [`AsgStage::set_stale`] from another thread.
    pub fn stale_handle(&self) -> AsgStaleHandle {
        AsgStaleHandle::new(Arc::clone(&self.tx))
    }

    /// Whether the thread has ended (the feed was closed and drained).
    pub fn is_finished(&self) -> bool {
        self.handle.is_finished()
    }

    /// Closes the feed (the stage fits the frame still waiting, then ends).
    pub fn stop(&self) {
        self.feed.close();
    }

    /// Closes the feed, waits for the thread and returns the final counters.
    pub fn join(self) -> Result<AsgStats, AsgStageError> {
        self.feed.close();
        let joined = self.handle.join();
        if let Err(payload) = joined {
            let message = payload
                .downcast_ref::<&str>()
                .map(|s| (*s).to_owned())
                .or_else(|| payload.downcast_ref::<String>().cloned())
                .unwrap_or_else(|| "non-string panic payload".to_owned());
            return Err(AsgStageError::Panicked(message));
        }
        Ok(stats(&self.feed, &self.shared))
    }
}

fn stats(feed: &AsgFeed, shared: &Shared) -> AsgStats {
    AsgStats {
        frames_offered: feed.offered(),
        frames_skipped: feed.skipped(),
        fits: shared.fits.load(Ordering::Acquire),
        fit_errors: shared.fit_errors.load(Ordering::Acquire),
        last_fit_time: Duration::from_nanos(shared.last_fit_nanos.load(Ordering::Acquire)),
    }
}

/// Reads the stage's counters; valid after the stage has ended.
#[derive(Clone)]
pub struct AsgStatsHandle(AsgFeed, Arc<Shared>);

impl AsgStatsHandle {
    /// A snapshot of the counters.
    pub fn stats(&self) -> AsgStats {
        stats(&self.0, &self.1)
    }
}

/// Marks the newest ASG set stale or live; see [`AsgStage::set_stale`].
pub type AsgStaleHandle = crate::publication::StaleHandle<AsgSet>;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::envmap::Projection;
    use crate::frame::HdrFrame;

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

    fn settings() -> FitSettings {
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
        // Same lobes as a fitter run over the same frames in order.
        let mut fitter = AsgFitter::new(settings()).unwrap();
        let mut want = Vec::new();
        for seq in 0..5 {
            let r = fitter.fit_frame(&frame(seq)).unwrap();
            want.push(AsgSet::from_fit(seq, seq as f64 / 30.0, &r.lobes));
        }
        let last = seen.last().unwrap();
        assert_eq!(*last.payload, want[4]);
        assert_eq!(last.index, 5, "every fit was published");
        for p in &seen {
            assert_eq!(*p.payload, want[p.payload.seq as usize]);
        }
    }

    #[test]
    fn bad_settings_are_rejected_and_stale_republishes() {
        let bad = FitSettings {
            lobes: 0,
            ..settings()
        };
        assert!(matches!(
            AsgStage::start(bad.clone(), false, None),
            Err(AsgStageError::Settings(_))
        ));
        let stage = AsgStage::start(settings(), false, None).unwrap();
        assert!(stage.reconfigure(bad).is_err());
        assert!(!stage.set_stale(true), "nothing published yet");
        stage.feed().offer(frame(0));
        while stage.stats().fits == 0 {
            std::thread::sleep(Duration::from_millis(1));
        }
        let live = stage.subscribe().borrow().clone().unwrap();
        assert!(stage.set_stale(true));
        let stale = stage.subscribe().borrow().clone().unwrap();
        assert!(stale.stale && Arc::ptr_eq(&stale.payload, &live.payload));
        assert_eq!(stale.index, live.index + 1);
        let stats = stage.join().unwrap();
        assert_eq!(stats.fits, 1);
    }
}
