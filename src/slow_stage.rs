//! The thread behind every slow stage of the daemon (the ASG fits of [`crate::asg_stage`], the
//! wavelet sets of [`crate::wavelet_stage`], the SH sets of [`crate::sh_stage`]): take the
//! newest frame from a [`FrameFeed`], run a [`StageWorker`] on it, publish the result on a
//! latest-value channel. [`DaemonStage`] is the stage as the daemon holds it: built from its
//! settings ([`StageKind`]), each stage module supplying only its worker, settings, counters
//! and errors.
//!
//! ```text
//! envlight-decompose ──FrameFeed (one slot, newest wins)──► named thread ──watch──► stream server
//!   (after publishing its lights)                          (StageWorker)      Latest<W::Output>
//! ```
//!
//! Per frame, on the stage's own thread:
//! 1. **Reconfigure** first if [`SlowStage::replace_worker`] (SIGHUP) left a new worker: it
//!    replaces the old one before this frame, so a warm-start chain or a resampling plan starts
//!    afresh.
//! 2. **Compute** with [`StageWorker::process`], timed, after telling the worker the frame's
//!    number in the feed ([`StageWorker::frame_number`]: what a temporal filter needs to fill
//!    in the frames the stage skipped).
//! 3. **Publish** a [`crate::publication::Publication`] numbered one more than the last (so a
//!    consumer can count what it skipped), stamped with the frame's arrival and the compute
//!    time, then run the stage's hook (metrics) on it.
//!
//! A frame the worker rejects is logged with the thread's name and counted
//! ([`StageCounters::errors`]); the stage goes on with the next one. Frames replaced in the feed
//! before the thread took them are counted by the feed ([`StageCounters::skipped`]); a lossless
//! feed (replay) makes every frame processed in order. Closing the feed lets the thread process
//! the frame still waiting and end; [`SlowStage::abandon`] (a signal's shutdown) ends it
//! without: the waiting frame is dropped and a worker that watches the flag gives up the
//! frame in progress; [`SlowStage::join`] waits for it and turns a panic on the
//! thread into an error, never a panic in the caller. If the thread dies, its feed is closed, so
//! a lossless sender is never left waiting.

use crate::frame::HdrFrame;
pub use crate::frame_feed::CloseOnDrop;
use crate::frame_feed::{FedFrame, FrameFeed};
use crate::publication::{publish, Latest, Publication, StaleHandle};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};
use tokio::sync::watch;

/// What a slow stage computes from each frame.
pub trait StageWorker: Send + 'static {
    /// The published result.
    type Output: Send + Sync + 'static;
    /// Why a frame gave no result (logged and counted; the stage goes on).
    type Error: std::fmt::Display;
    /// The result for `frame`.
    fn process(&mut self, frame: &HdrFrame) -> Result<Self::Output, Self::Error>;
    /// Set-up work done so far that depends on the frames' shape (resampling plans); 0 for a
    /// worker that has none. The stage sums it over the workers it ran.
    fn plans(&self) -> u64 {
        0
    }
    /// Gives the worker the stage's abandon flag ([`SlowStage::abandon`]): a worker whose
    /// computation is long (an ASG fit of many iterations) checks it and gives up early,
    /// returning an error (which the stage, seeing the flag, neither logs nor counts as one).
    /// The default ignores it: the computation in progress runs to its end.
    fn watch_abandon(&mut self, _flag: Arc<AtomicBool>) {}
    /// Tells the worker the number of the frame it is about to process
    /// ([`crate::frame_feed::FedFrame::number`]): a worker that filters its sets in time fills
    /// in the frames skipped since the last one ([`crate::set_filter`]). The default ignores it.
    fn frame_number(&mut self, _number: u64) {}
    /// Hands over to `new`, a worker built from new settings (a reconfiguration), before the
    /// next frame. The default replaces this worker whole (its plans and any warm-start chain
    /// start afresh); a worker may keep what the new settings leave unchanged (the ASG worker
    /// keeps its warm-started fitter when only its filter changes).
    fn take_over(&mut self, new: Self)
    where
        Self: Sized,
    {
        *self = new;
    }
}

/// Called on the stage's thread after each publication (metrics).
pub type PublishHook<T> = Arc<dyn Fn(&Publication<T>) + Send + Sync>;

/// Counters of a slow stage.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct StageCounters {
    /// Frames offered to the stage.
    pub offered: u64,
    /// Frames replaced by a newer one before the stage took them.
    pub skipped: u64,
    /// Results computed and published.
    pub published: u64,
    /// Frames that gave no result.
    pub errors: u64,
    /// [`StageWorker::plans`], summed over the workers the stage ran.
    pub plans: u64,
    /// Duration of the most recent computation.
    pub last_time: Duration,
}

struct Shared<W> {
    published: AtomicU64,
    errors: AtomicU64,
    plans: AtomicU64,
    last_nanos: AtomicU64,
    pending: Mutex<Option<W>>,
    /// Set by [`SlowStage::abandon`]: no further frame is processed.
    abandon: Arc<AtomicBool>,
}

/// Reads a stage's counters from anywhere (the metrics endpoint); valid after the stage ended.
pub struct CountersHandle<W> {
    feed: FrameFeed,
    shared: Arc<Shared<W>>,
}

// Derived `Clone` would require `W: Clone`.
impl<W> Clone for CountersHandle<W> {
    fn clone(&self) -> Self {
        Self {
            feed: self.feed.clone(),
            shared: Arc::clone(&self.shared),
        }
    }
}

impl<W> CountersHandle<W> {
    /// A snapshot of the counters.
    pub fn counters(&self) -> StageCounters {
        let shared = &self.shared;
        StageCounters {
            offered: self.feed.offered(),
            skipped: self.feed.skipped(),
            published: shared.published.load(Ordering::Acquire),
            errors: shared.errors.load(Ordering::Acquire),
            plans: shared.plans.load(Ordering::Acquire),
            last_time: Duration::from_nanos(shared.last_nanos.load(Ordering::Acquire)),
        }
    }
}

/// A running slow stage. See the module documentation.
pub struct SlowStage<W: StageWorker> {
    counters: CountersHandle<W>,
    tx: Arc<watch::Sender<Latest<W::Output>>>,
    rx: watch::Receiver<Latest<W::Output>>,
    handle: JoinHandle<()>,
}

impl<W: StageWorker> SlowStage<W> {
    /// Starts the thread `name` running `worker`, fed by a new feed (`lossless` as in
    /// [`FrameFeed::new`]). `on_publish` runs on the thread after each publication.
    pub fn start(
        name: &str,
        worker: W,
        lossless: bool,
        on_publish: Option<PublishHook<W::Output>>,
    ) -> std::io::Result<Self> {
        let feed = FrameFeed::new(lossless);
        let shared = Arc::new(Shared {
            published: AtomicU64::new(0),
            errors: AtomicU64::new(0),
            plans: AtomicU64::new(0),
            last_nanos: AtomicU64::new(0),
            pending: Mutex::new(None),
            abandon: Arc::new(AtomicBool::new(false)),
        });
        let (tx, rx) = watch::channel::<Latest<W::Output>>(None);
        let tx = Arc::new(tx);
        let (thread_feed, thread_shared, thread_tx) =
            (feed.clone(), Arc::clone(&shared), Arc::clone(&tx));
        let thread_name = name.to_owned();
        let handle = std::thread::Builder::new()
            .name(name.to_owned())
            .spawn(move || {
                run(
                    &thread_name,
                    worker,
                    &thread_feed,
                    &thread_shared,
                    &thread_tx,
                    on_publish,
                )
            })?;
        Ok(Self {
            counters: CountersHandle { feed, shared },
            tx,
            rx,
            handle,
        })
    }

    /// The feed to hand frames to (give it to the pipeline).
    pub fn feed(&self) -> FrameFeed {
        self.counters.feed.clone()
    }

    /// A receiver of the newest result; a result published already shows as changed.
    pub fn subscribe(&self) -> watch::Receiver<Latest<W::Output>> {
        self.rx.clone()
    }

    /// A snapshot of the counters.
    pub fn counters(&self) -> StageCounters {
        self.counters.counters()
    }

    /// A handle that reads the counters from anywhere.
    pub fn counters_handle(&self) -> CountersHandle<W> {
        self.counters.clone()
    }

    /// Replaces the worker before the next frame.
    pub fn replace_worker(&self, worker: W) {
        *self
            .counters
            .shared
            .pending
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner) = Some(worker);
    }

    /// A handle that marks the newest result stale (the source is lost).
    pub fn stale_handle(&self) -> StaleHandle<W::Output> {
        StaleHandle::new(Arc::clone(&self.tx))
    }

    /// Whether the thread has ended (the feed was closed and drained).
    pub fn is_finished(&self) -> bool {
        self.handle.is_finished()
    }

    /// Closes the feed (the stage processes the frame still waiting, then ends).
    pub fn stop(&self) {
        self.counters.feed.close();
    }

    /// Closes the feed and gives up the work in progress (a signal's shutdown, which must not
    /// wait for a long fit): the frame still waiting is not processed, the computation in
    /// progress ends early where the worker watches for it ([`StageWorker::watch_abandon`];
    /// a result finished all the same is still published).
    pub fn abandon(&self) {
        self.counters.shared.abandon.store(true, Ordering::Release);
        self.counters.feed.close();
    }

    /// Closes the feed, waits for the thread and returns the final counters, or the message
    /// of the panic that ended the thread.
    pub fn join(self) -> Result<StageCounters, String> {
        self.counters.feed.close();
        if let Err(payload) = self.handle.join() {
            return Err(payload
                .downcast_ref::<&str>()
                .map(|s| (*s).to_owned())
                .or_else(|| payload.downcast_ref::<String>().cloned())
                .unwrap_or_else(|| "non-string panic payload".to_owned()));
        }
        Ok(self.counters.counters())
    }
}

/// The stage's thread: the steps of the module documentation until the feed ends.
fn run<W: StageWorker>(
    name: &str,
    mut worker: W,
    feed: &FrameFeed,
    shared: &Shared<W>,
    tx: &watch::Sender<Latest<W::Output>>,
    on_publish: Option<PublishHook<W::Output>>,
) {
    // If this thread dies, the feed must not make a lossless sender wait forever.
    let _close = CloseOnDrop(feed.clone());
    worker.watch_abandon(Arc::clone(&shared.abandon));
    let abandoned = || shared.abandon.load(Ordering::Acquire);
    let mut plans_counted = worker.plans();
    shared.plans.fetch_add(plans_counted, Ordering::AcqRel);
    while let Some(FedFrame {
        frame,
        arrived,
        number,
    }) = feed.take()
    {
        let replacement = shared
            .pending
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .take();
        if let Some(new) = replacement {
            worker.take_over(new);
            worker.watch_abandon(Arc::clone(&shared.abandon));
            // Counted already, if the worker kept its plans (and with them their count).
            plans_counted = worker.plans();
        }
        if abandoned() {
            tracing::info!(
                stage = name,
                seq = frame.seq,
                "shutting down: frame not processed"
            );
            break;
        }
        tracing::debug!(stage = name, seq = frame.seq, "processing the frame");
        let started = Instant::now();
        worker.frame_number(number);
        let result = worker.process(&frame);
        let elapsed = started.elapsed();
        let plans = worker.plans();
        shared
            .plans
            .fetch_add(plans.saturating_sub(plans_counted), Ordering::AcqRel);
        plans_counted = plans;
        let output = match result {
            Ok(output) => Arc::new(output),
            Err(_) if abandoned() => {
                tracing::info!(
                    stage = name,
                    seq = frame.seq,
                    "shutting down: frame abandoned"
                );
                break;
            }
            Err(error) => {
                shared.errors.fetch_add(1, Ordering::AcqRel);
                tracing::warn!(stage = name, seq = frame.seq, %error, "skipping the frame");
                continue;
            }
        };
        let nanos = u64::try_from(elapsed.as_nanos()).unwrap_or(u64::MAX);
        shared.last_nanos.store(nanos, Ordering::Release);
        shared.published.fetch_add(1, Ordering::AcqRel);
        publish(tx, output, Some(arrived), elapsed);
        if let Some(hook) = &on_publish {
            if let Some(published) = tx.borrow().as_ref() {
                hook(published);
            }
        }
    }
}

/// The counters of a stage that publishes sets (the wavelet and SH stages), as
/// [`StageCounters`] under the names the metrics use.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct SetStageStats {
    /// Frames offered to the stage.
    pub frames_offered: u64,
    /// Frames replaced by a newer one before the stage took them.
    pub frames_skipped: u64,
    /// Sets computed and published.
    pub sets: u64,
    /// Frames that gave no set.
    pub errors: u64,
    /// Plans built (resampling or projection tables; one per frame size and projection met).
    pub plans: u64,
    /// Duration of the most recent set.
    pub last_time: Duration,
}

impl From<StageCounters> for SetStageStats {
    fn from(c: StageCounters) -> Self {
        Self {
            frames_offered: c.offered,
            frames_skipped: c.skipped,
            sets: c.published,
            errors: c.errors,
            plans: c.plans,
            last_time: c.last_time,
        }
    }
}

/// A [`StageWorker`] that a daemon stage builds from its section of the config: what
/// [`DaemonStage`] needs to start it on its own named thread, swap it on SIGHUP and report it.
pub trait StageKind: StageWorker + Sized {
    /// The stage's section of the config.
    type Settings;
    /// The stage's counters, named for what it publishes (fits, sets).
    type Stats: From<StageCounters>;
    /// What [`StageKind::from_settings`] gives for invalid settings.
    type SettingsError;
    /// Every error of the stage: invalid settings, a thread that cannot start or panicked.
    type StageError: From<Self::SettingsError>;
    /// The thread's name (`envlight-…`), in logs, `ps` and panic messages.
    const THREAD_NAME: &'static str;
    /// A worker for `settings`, which it validates (the error names the field and the value).
    fn from_settings(settings: Self::Settings) -> Result<Self, Self::SettingsError>;
    /// Logs the stage's start with its settings (one line, on the caller's thread).
    fn log_start(&self, lossless: bool);
    /// The error for a thread that could not be started.
    fn spawn_error(error: std::io::Error) -> Self::StageError;
    /// The error for a thread that panicked, with the panic's message.
    fn panic_error(message: String) -> Self::StageError;
}

/// A running daemon stage (the ASG, wavelet and SH stages): a [`SlowStage`] built from its
/// settings, reconfigurable from new settings, reporting its own counters
/// ([`StageKind::Stats`]) and errors ([`StageKind::StageError`]).
pub struct DaemonStage<W: StageKind>(SlowStage<W>);

impl<W: StageKind> DaemonStage<W> {
    /// Validates `settings` and starts the stage's thread ([`StageKind::THREAD_NAME`]), fed
    /// by a new feed (`lossless` as in [`FrameFeed::new`]). `on_publish` runs on the thread
    /// after each publication.
    pub fn start(
        settings: W::Settings,
        lossless: bool,
        on_publish: Option<PublishHook<W::Output>>,
    ) -> Result<Self, W::StageError> {
        let worker = W::from_settings(settings)?;
        worker.log_start(lossless);
        SlowStage::start(W::THREAD_NAME, worker, lossless, on_publish)
            .map(DaemonStage)
            .map_err(W::spawn_error)
    }

    /// The feed to hand frames to (give it to the pipeline).
    pub fn feed(&self) -> FrameFeed {
        self.0.feed()
    }

    /// A receiver of the newest result; a result published already shows as changed.
    pub fn subscribe(&self) -> watch::Receiver<Latest<W::Output>> {
        self.0.subscribe()
    }

    /// A snapshot of the counters.
    pub fn stats(&self) -> W::Stats {
        self.0.counters().into()
    }

    /// A handle that reads the counters from anywhere (the metrics endpoint).
    pub fn stats_handle(&self) -> StageStatsHandle<W> {
        StageStatsHandle(self.0.counters_handle())
    }

    /// Replaces the settings from the next frame on, with a new worker (its plans and any
    /// warm-start chain start afresh). Invalid settings are rejected and change nothing.
    pub fn reconfigure(&self, settings: W::Settings) -> Result<(), W::SettingsError> {
        self.0.replace_worker(W::from_settings(settings)?);
        Ok(())
    }

    /// Marks the newest result stale (the source is lost), re-publishing it unless it is
    /// stale already; the next computed result is live. Returns whether anything was
    /// published.
    pub fn mark_stale(&self) -> bool {
        self.stale_handle().mark_stale()
    }

    /// A handle for [`DaemonStage::mark_stale`] from another thread.
    pub fn stale_handle(&self) -> StaleHandle<W::Output> {
        self.0.stale_handle()
    }

    /// Whether the thread has ended (the feed was closed and drained).
    pub fn is_finished(&self) -> bool {
        self.0.is_finished()
    }

    /// Closes the feed (the stage processes the frame still waiting, then ends).
    pub fn stop(&self) {
        self.0.stop();
    }

    /// Closes the feed and drops the frame still waiting (a signal's shutdown). A worker that
    /// watches the flag ([`StageWorker::watch_abandon`]: the ASG fit, within one iteration)
    /// gives up the computation in progress; the others finish and publish it
    /// ([`SlowStage::abandon`]).
    pub fn abandon(&self) {
        self.0.abandon();
    }

    /// Closes the feed, waits for the thread and returns the final counters.
    pub fn join(self) -> Result<W::Stats, W::StageError> {
        self.0.join().map(W::Stats::from).map_err(W::panic_error)
    }
}

/// Reads a daemon stage's counters; valid after the stage has ended.
pub struct StageStatsHandle<W>(CountersHandle<W>);

// Derived `Clone` would require `W: Clone`.
impl<W> Clone for StageStatsHandle<W> {
    fn clone(&self) -> Self {
        Self(self.0.clone())
    }
}

impl<W: StageKind> StageStatsHandle<W> {
    /// A snapshot of the counters.
    pub fn stats(&self) -> W::Stats {
        self.0.counters().into()
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::envmap::Projection;

    /// Sums a frame's red channel; fails on frames whose seq is odd; one plan per new width.
    struct Summer {
        width: Option<u32>,
        plans: u64,
        offset: f32,
    }

    impl StageWorker for Summer {
        type Output = (u64, f32);
        type Error = String;
        fn process(&mut self, frame: &HdrFrame) -> Result<(u64, f32), String> {
            if self.width != Some(frame.width) {
                self.width = Some(frame.width);
                self.plans += 1;
            }
            if frame.seq % 2 == 1 {
                return Err(format!("frame {} is odd", frame.seq));
            }
            let sum: f32 = frame.pixels.iter().map(|p| p[0]).sum();
            Ok((frame.seq, sum + self.offset))
        }
        fn plans(&self) -> u64 {
            self.plans
        }
    }

    fn summer(offset: f32) -> Summer {
        Summer {
            width: None,
            plans: 0,
            offset,
        }
    }

    fn frame(seq: u64, width: u32) -> HdrFrame {
        let mut f = HdrFrame::new(
            width,
            1,
            vec![[1.0; 3]; width as usize],
            Projection::LatLong,
        )
        .unwrap();
        f.seq = seq;
        f
    }

    /// Offers `frames` from a feeder thread and collects every publication up to `last_seq`.
    fn collect(
        stage: &SlowStage<Summer>,
        frames: Vec<HdrFrame>,
        last_seq: u64,
    ) -> Vec<Arc<Publication<(u64, f32)>>> {
        let mut rx = stage.subscribe();
        let feed = stage.feed();
        let feeder = std::thread::Builder::new()
            .name("test-feeder".into())
            .spawn(move || {
                for f in frames {
                    feed.offer(f);
                }
            })
            .unwrap();
        let rt = tokio::runtime::Builder::new_current_thread()
            .build()
            .unwrap();
        let mut seen = Vec::new();
        rt.block_on(async {
            while rx.changed().await.is_ok() {
                let p = rx.borrow_and_update().clone().unwrap();
                let last = p.payload.0 == last_seq;
                seen.push(p);
                if last {
                    break;
                }
            }
        });
        feeder.join().unwrap();
        seen
    }

    #[test]
    fn a_lossless_stage_publishes_every_good_frame_counts_errors_and_plans() {
        // The hook runs for every publication (a watch receiver may see only the newest).
        let hooked = Arc::new(Mutex::new(Vec::new()));
        let record = Arc::clone(&hooked);
        let hook: PublishHook<(u64, f32)> = Arc::new(move |p| {
            let entry = (
                p.index,
                p.payload.0,
                p.payload.1,
                p.stale,
                p.arrived.is_some(),
            );
            record.lock().unwrap().push(entry);
        });
        let stage = SlowStage::start("test-stage", summer(0.0), true, Some(hook)).unwrap();
        let frames = [(0, 4), (1, 4), (2, 4), (3, 8), (4, 8)]
            .map(|(seq, width)| frame(seq, width))
            .to_vec();
        let seen = collect(&stage, frames, 4);
        assert_eq!(seen.last().unwrap().index, 3);
        let counters = stage.join().unwrap();
        assert_eq!(
            *hooked.lock().unwrap(),
            vec![
                (1, 0, 4.0, false, true),
                (2, 2, 4.0, false, true),
                (3, 4, 8.0, false, true)
            ]
        );
        assert_eq!(
            (
                counters.offered,
                counters.skipped,
                counters.published,
                counters.errors,
                counters.plans
            ),
            (5, 0, 3, 2, 2)
        );
    }

    #[test]
    fn a_replaced_worker_takes_over_before_the_next_frame_and_stale_republishes() {
        let stage = SlowStage::start("test-stage", summer(0.0), true, None).unwrap();
        let first = collect(&stage, vec![frame(0, 4)], 0);
        assert_eq!(first.last().unwrap().payload.1, 4.0);
        stage.replace_worker(summer(100.0));
        let second = collect(&stage, vec![frame(2, 4)], 2);
        let live = second.last().unwrap().clone();
        assert_eq!((live.index, live.payload.1), (2, 104.0));
        let stale = stage.stale_handle();
        assert!(stale.mark_stale());
        let republished = stage.subscribe().borrow().clone().unwrap();
        assert!(republished.stale && Arc::ptr_eq(&republished.payload, &live.payload));
        assert_eq!(republished.index, 3);
        let counters = stage.join().unwrap();
        // The new worker built its own plan for the same width.
        assert_eq!((counters.published, counters.plans), (2, 2));
    }

    struct Panicker;

    impl StageWorker for Panicker {
        type Output = ();
        type Error = String;
        fn process(&mut self, _: &HdrFrame) -> Result<(), String> {
            panic!("worker exploded")
        }
    }

    #[test]
    fn a_panic_on_the_thread_is_an_error_of_join_and_closes_the_feed() {
        let stage = SlowStage::start("test-stage", Panicker, true, None).unwrap();
        let feed = stage.feed();
        feed.offer(frame(0, 4));
        while !stage.is_finished() {
            std::thread::sleep(Duration::from_millis(1));
        }
        // The closed feed drops this frame instead of waiting for a slot forever.
        feed.offer(frame(1, 4));
        assert_eq!(stage.join().unwrap_err(), "worker exploded");
    }
}
