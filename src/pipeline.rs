//! The capture → decompose pipeline: two named threads joined by a bounded queue, publishing
//! light lists on a latest-value channel.
//!
//! ```text
//! envlight-capture ──bounded(queue_capacity)──► envlight-decompose ──watch──► consumers
//!  (FrameSource)        crossbeam-channel          (Decomposer)        Option<Arc<LightFrame>>
//! ```
//!
//! - **Capture thread** (`envlight-capture`) pulls [`HdrFrame`]s from the [`FrameSource`] and
//!   pushes them into a bounded crossbeam channel (capacity [`PipelineOptions::queue_capacity`],
//!   2 by default).
//! - **Drop-oldest policy.** Capture never waits for a slow decomposition: when the queue is full,
//!   the capture thread takes the *oldest* queued frame out itself (it holds a clone of the
//!   receiver), counts it in [`PipelineStats::frames_dropped`] and retries, so the queue always
//!   holds the newest frames. Every captured frame is therefore either decomposed or dropped:
//!   once both threads have finished, `frames_captured == frames_decomposed + frames_dropped`.
//! - **Decompose thread** (`envlight-decompose`) receives frames, runs the [`Decomposer`] and
//!   publishes each result as `Some(Arc<LightFrame>)` on a [`tokio::sync::watch`] channel (a plain
//!   thread can send on it; no runtime is needed). Consumers ([`Pipeline::subscribe`]) always read
//!   the newest light list; a slow consumer skips frames and never holds the pipeline back.
//!   Each publication is a [`Published`]: the lights, a running index (so a consumer can count
//!   what it skipped), a stale flag and when the frame reached the decomposition (for latency
//!   figures). Once the pipeline is joined or dropped, `watch::Receiver::changed` reports the
//!   end of the stream.
//! - **Replay** uses [`QueuePolicy::Block`]: capture waits for the decomposition instead of
//!   dropping, so every recorded frame reaches the temporal filter and the stream is reproduced.
//! - **Recording** taps the decompose thread ([`PipelineOptions::tap`]): every decomposed frame
//!   and its lights go to the recorder, which the decompose thread waits for (nothing recorded
//!   is lost; a slow disk shows up as dropped capture frames, which are counted).
//! - **Slower stages** (the ASG fits, [`crate::asg_stage`]; the wavelet transforms,
//!   [`crate::wavelet_stage`]). With [`PipelineOptions::stage_feeds`], the decompose thread
//!   hands every frame to each stage's [`FrameFeed`] after publishing its lights — newest frame
//!   wins, so a slow stage never delays the lights (lossless in replay) — and closes the feeds
//!   when it ends.
//! - **Live changes.** [`Pipeline::reconfigure`] swaps in a new [`Decomposer`] before the next
//!   frame (SIGHUP); [`Pipeline::mark_stale`] re-publishes the newest lights marked stale while
//!   a lost camera is being reconnected (the next decomposed frame is live again).
//! - **Source errors.** A [`CaptureError`] is logged (`tracing::warn`), counted in
//!   [`PipelineStats::capture_errors`] and ends the capture: the error is kept and
//!   [`Pipeline::join`] returns it as [`PipelineError::Capture`], so nothing is lost silently.
//!   (Retrying a flaky camera is the source's business, not the pipeline's.)
//! - **Shutdown.** The capture thread ends when the source is exhausted (`Ok(None)`), on a source
//!   error, or after [`Pipeline::stop`] (checked before every frame, so an endless source stops
//!   after at most the frame it is waiting for). Ending capture closes the queue; the decompose
//!   thread drains what is still queued and ends. If the decompose thread ends early (a panic),
//!   capture stops too. [`Pipeline::join`] joins both threads; a panicked thread becomes
//!   [`PipelineError::ThreadPanicked`], never a panic in the caller.

use crate::capture::{CaptureError, FrameSource};
use crate::decompose::{DecomposeError, DecomposeSettings, Decomposer};
use crate::frame::HdrFrame;
use crate::frame_feed::{CloseOnDrop, FrameFeed};
use crate::light::LightFrame;
use crate::publication::{publish, Latest, Publication};
use crossbeam_channel::{Receiver, Sender, TrySendError};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};
use tokio::sync::watch;

/// Name of the capture thread.
pub const CAPTURE_THREAD_NAME: &str = "envlight-capture";
/// Name of the decompose thread.
pub const DECOMPOSE_THREAD_NAME: &str = "envlight-decompose";

/// One publication on the lights' latest-value channel: the light list is the
/// [`Publication::payload`], [`Publication::compute_time`] the decomposition time.
pub type Published = Publication<LightFrame>;

/// What consumers receive: the newest publication, `None` until the first one.
pub type LatestLights = Latest<LightFrame>;

/// What a full capture → decompose queue does with a new frame.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum QueuePolicy {
    /// Drop the oldest queued frame and count it: a live source never waits (the default).
    #[default]
    DropOldest,
    /// Wait until the decomposition takes a frame: nothing is dropped. For replaying recorded
    /// sessions, where every frame must reach the temporal filter to reproduce the stream.
    Block,
}

/// Options of a [`Pipeline`].
#[derive(Clone, Debug, Default)]
pub struct PipelineOptions {
    /// Capacity of the capture → decompose queue, at least 1 (default 2).
    pub queue_capacity: usize,
    /// What a full queue does.
    pub queue_policy: QueuePolicy,
    /// Every decomposed frame with its lights, for a recorder. The decompose thread waits for
    /// room on this channel (a recording loses nothing; a slow recorder shows up as dropped
    /// capture frames instead). If the receiver is gone, tapping stops with a warning.
    pub tap: Option<Sender<Tapped>>,
    /// Called on the decompose thread after each decomposed frame is published, before the
    /// frame goes to the stages (metrics; the stream server's fan-out pass when it runs on
    /// the publishing thread, [`crate::stream::server::PublisherPass`]).
    pub on_publish: Option<PublishHook>,
    /// Every decomposed frame is offered to each of these stages (ASG, wavelet) after its
    /// lights are published, in this order; the feeds are closed when the decompose thread
    /// ends.
    pub stage_feeds: Vec<FrameFeed>,
}

/// A callback run on the decompose thread for every decomposed frame.
#[derive(Clone)]
pub struct PublishHook(pub Arc<dyn Fn(&Published) + Send + Sync>);

impl PublishHook {
    /// A hook that runs this one, then `next`.
    pub fn then(self, next: PublishHook) -> PublishHook {
        PublishHook(Arc::new(move |published| {
            (self.0)(published);
            (next.0)(published);
        }))
    }
}

impl std::fmt::Debug for PublishHook {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("PublishHook")
    }
}

impl PipelineOptions {
    /// The defaults: a queue of 2 frames that drops the oldest, no tap.
    pub fn new() -> Self {
        Self {
            queue_capacity: 2,
            ..Self::default()
        }
    }
}

/// A decomposed frame and its lights, as handed to [`PipelineOptions::tap`].
#[derive(Debug)]
pub struct Tapped {
    pub frame: HdrFrame,
    pub lights: Arc<LightFrame>,
}

/// Errors of the pipeline.
#[derive(Debug, thiserror::Error)]
pub enum PipelineError {
    #[error("invalid decomposition settings: {0}")]
    Decompose(#[from] DecomposeError),
    #[error("invalid pipeline option queue_capacity = {0}: it must be at least 1")]
    QueueCapacity(usize),
    #[error("cannot start thread {thread}: {source}")]
    Spawn {
        thread: &'static str,
        #[source]
        source: std::io::Error,
    },
    #[error("frame source failed: {0}")]
    Capture(#[source] CaptureError),
    #[error("thread {thread} panicked: {message}")]
    ThreadPanicked {
        thread: &'static str,
        message: String,
    },
}

/// Counters of a running or finished pipeline.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct PipelineStats {
    /// Frames the source delivered.
    pub frames_captured: u64,
    /// Frames dropped (oldest first) because the queue was full.
    pub frames_dropped: u64,
    /// Frames decomposed and published.
    pub frames_decomposed: u64,
    /// Duration of the most recent decomposition.
    pub last_decompose_time: Duration,
    /// Errors returned by the source.
    pub capture_errors: u64,
    /// Number of lights in the most recent light list.
    pub light_count: u64,
}

/// A decomposition step: a [`Decomposer`] in the daemon, anything in tests.
type Step = Box<dyn FnMut(&HdrFrame) -> LightFrame + Send>;

/// Shared counters and flags.
#[derive(Default)]
struct Shared {
    shutdown: AtomicBool,
    frames_captured: AtomicU64,
    frames_dropped: AtomicU64,
    frames_decomposed: AtomicU64,
    last_decompose_nanos: AtomicU64,
    capture_errors: AtomicU64,
    light_count: AtomicU64,
    /// The source error that ended the capture, handed to [`Pipeline::join`].
    capture_error: Mutex<Option<CaptureError>>,
    /// A replacement decomposition step, taken by the decompose thread before its next frame.
    pending_step: Mutex<Option<Step>>,
}

impl Shared {
    fn stats(&self) -> PipelineStats {
        PipelineStats {
            frames_captured: self.frames_captured.load(Ordering::Acquire),
            frames_dropped: self.frames_dropped.load(Ordering::Acquire),
            frames_decomposed: self.frames_decomposed.load(Ordering::Acquire),
            last_decompose_time: Duration::from_nanos(
                self.last_decompose_nanos.load(Ordering::Acquire),
            ),
            capture_errors: self.capture_errors.load(Ordering::Acquire),
            light_count: self.light_count.load(Ordering::Acquire),
        }
    }
}

/// A running capture → decompose pipeline. See the module documentation.
pub struct Pipeline {
    shared: Arc<Shared>,
    /// The sending side, also used by [`Pipeline::mark_stale`].
    lights_tx: Arc<watch::Sender<LatestLights>>,
    /// Never marked as seen, so each clone handed out starts with the newest value unseen.
    lights: watch::Receiver<LatestLights>,
    capture: JoinHandle<()>,
    decompose: JoinHandle<()>,
}

impl Pipeline {
    /// Validates `settings` and `options` and starts the capture and decompose threads.
    pub fn start(
        source: Box<dyn FrameSource>,
        settings: DecomposeSettings,
        options: PipelineOptions,
    ) -> Result<Pipeline, PipelineError> {
        let mut decomposer = Decomposer::new(settings)?;
        Self::start_with(source, options, move |frame| decomposer.decompose(frame))
    }

    /// Starts the pipeline with any decomposition step (the tests use slow or panicking ones).
    pub fn start_with<F>(
        mut source: Box<dyn FrameSource>,
        options: PipelineOptions,
        decompose: F,
    ) -> Result<Pipeline, PipelineError>
    where
        F: FnMut(&HdrFrame) -> LightFrame + Send + 'static,
    {
        if options.queue_capacity == 0 {
            return Err(PipelineError::QueueCapacity(options.queue_capacity));
        }
        let mut step: Step = Box::new(decompose);
        let shared = Arc::new(Shared::default());
        let (frame_tx, frame_rx) = crossbeam_channel::bounded::<HdrFrame>(options.queue_capacity);
        // Pixel buffers going back to the source (FrameSource::recycle) from the decompose
        // thread, when the decomposition was a frame's last use.
        let (recycle_tx, recycle_rx) = crossbeam_channel::bounded::<Vec<[f32; 3]>>(2);
        let (lights_tx, lights_rx) = watch::channel::<LatestLights>(None);
        let lights_tx = Arc::new(lights_tx);
        tracing::info!(
            source = %source.describe(),
            queue_capacity = options.queue_capacity,
            queue_policy = ?options.queue_policy,
            "starting pipeline"
        );

        let decompose_shared = Arc::clone(&shared);
        let decompose_rx = frame_rx.clone();
        let decompose_tx = Arc::clone(&lights_tx);
        let mut tap = options.tap;
        let on_publish = options.on_publish;
        let stage_feeds = options.stage_feeds;
        let decompose_handle = std::thread::Builder::new()
            .name(DECOMPOSE_THREAD_NAME.to_owned())
            .spawn(move || {
                // However this thread ends (drained queue or panic), capture must stop too.
                let _stop_capture = StopOnDrop(Arc::clone(&decompose_shared));
                let _close_stages: Vec<CloseOnDrop> =
                    stage_feeds.iter().cloned().map(CloseOnDrop).collect();
                for frame in decompose_rx.iter() {
                    let arrived = Instant::now();
                    if let Some(new_step) = decompose_shared
                        .pending_step
                        .lock()
                        .unwrap_or_else(std::sync::PoisonError::into_inner)
                        .take()
                    {
                        step = new_step;
                    }
                    let lights = Arc::new(step(&frame));
                    let elapsed = arrived.elapsed();
                    let nanos = u64::try_from(elapsed.as_nanos()).unwrap_or(u64::MAX);
                    let s = &decompose_shared;
                    s.last_decompose_nanos.store(nanos, Ordering::Release);
                    s.light_count
                        .store(lights.lights.len() as u64, Ordering::Release);
                    s.frames_decomposed.fetch_add(1, Ordering::AcqRel);
                    publish(&decompose_tx, Arc::clone(&lights), Some(arrived), elapsed);
                    if let Some(PublishHook(hook)) = &on_publish {
                        // Out of the channel's lock first: a hook may take a while (the stream
                        // server's fan-out pass, when it runs here) and must not hold up
                        // readers or a stale re-publication.
                        let published = decompose_tx.borrow().clone();
                        if let Some(published) = published {
                            hook(&published);
                        }
                    }
                    // The lights are out: the stages may have the frame now (copies only where
                    // another stage or the recorder needs it too).
                    let mut frame = Some(frame);
                    for (i, feed) in stage_feeds.iter().enumerate() {
                        let last = i + 1 == stage_feeds.len() && tap.is_none();
                        match frame.take() {
                            Some(f) if last => feed.offer(f),
                            Some(f) => {
                                feed.offer(f.clone());
                                frame = Some(f);
                            }
                            None => {}
                        }
                    }
                    let unused = match (&tap, frame) {
                        (Some(tx), Some(frame)) => {
                            if tx.send(Tapped { frame, lights }).is_err() {
                                tracing::warn!(
                                    "the recorder is gone; frames are no longer recorded"
                                );
                                tap = None;
                            }
                            None
                        }
                        (_, frame) => frame,
                    };
                    // Nothing else needs the frame: its buffer goes back to the source (or,
                    // when two are waiting already, to the allocator).
                    if let Some(frame) = unused {
                        let _ = recycle_tx.try_send(frame.pixels);
                    }
                }
            })
            .map_err(|source| PipelineError::Spawn {
                thread: DECOMPOSE_THREAD_NAME,
                source,
            })?;

        let capture_shared = Arc::clone(&shared);
        let policy = options.queue_policy;
        let capture_handle = std::thread::Builder::new()
            .name(CAPTURE_THREAD_NAME.to_owned())
            .spawn(move || {
                let stop_flag = Arc::clone(&capture_shared);
                crate::capture::interrupt_sleeps_when(move || {
                    stop_flag.shutdown.load(Ordering::Acquire)
                });
                capture_loop(
                    source.as_mut(),
                    &frame_tx,
                    &frame_rx,
                    &recycle_rx,
                    policy,
                    &capture_shared,
                )
            });
        let capture_handle = match capture_handle {
            Ok(handle) => handle,
            Err(source) => {
                // The capture closure (and with it the queue's sender) is gone, so the decompose
                // thread sees a closed, empty queue and ends.
                let _ = decompose_handle.join();
                return Err(PipelineError::Spawn {
                    thread: CAPTURE_THREAD_NAME,
                    source,
                });
            }
        };

        Ok(Pipeline {
            shared,
            lights_tx,
            lights: lights_rx,
            capture: capture_handle,
            decompose: decompose_handle,
        })
    }

    /// A receiver of the newest light list. If a list has been published already, the receiver
    /// sees it as changed. `changed()` returns an error once the decompose thread has ended
    /// and the pipeline is dropped.
    pub fn subscribe(&self) -> watch::Receiver<LatestLights> {
        self.lights.clone()
    }

    /// A snapshot of the counters.
    pub fn stats(&self) -> PipelineStats {
        self.shared.stats()
    }

    /// A handle that reads the counters from anywhere (the metrics endpoint).
    pub fn stats_handle(&self) -> StatsHandle {
        StatsHandle(Arc::clone(&self.shared))
    }

    /// Replaces the decomposition settings from the next frame on (a new [`Decomposer`]: its
    /// temporal filter starts afresh). Invalid settings are rejected and change nothing.
    pub fn reconfigure(&self, settings: DecomposeSettings) -> Result<(), DecomposeError> {
        let mut decomposer = Decomposer::new(settings)?;
        *self
            .shared
            .pending_step
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner) =
            Some(Box::new(move |frame: &HdrFrame| {
                decomposer.decompose(frame)
            }));
        Ok(())
    }

    /// Marks the newest light list stale (the source is lost): the newest lights are published
    /// again with the flag, so every consumer learns of it; a newly decomposed frame is always
    /// live. Returns whether anything was published (not when already stale).
    pub fn mark_stale(&self) -> bool {
        self.stale_handle().mark_stale()
    }

    /// A handle that marks the lights stale from another thread (the daemon's source
    /// health monitor; the capture thread itself is busy reconnecting).
    pub fn stale_handle(&self) -> StaleHandle {
        StaleHandle::new(Arc::clone(&self.lights_tx))
    }

    /// Asks the capture thread to stop before its next frame; queued frames are still
    /// decomposed. Returns at once; use [`Pipeline::join`] to wait.
    pub fn stop(&self) {
        self.shared.shutdown.store(true, Ordering::Release);
    }

    /// Whether both threads have finished.
    pub fn is_finished(&self) -> bool {
        self.capture.is_finished() && self.decompose.is_finished()
    }

    /// Waits for both threads and returns the final counters, or the error that ended the
    /// pipeline: a panicked thread (decompose first, since its panic also ends capture), then
    /// the source error that ended the capture.
    pub fn join(self) -> Result<PipelineStats, PipelineError> {
        let capture = self.capture.join();
        let decompose = self.decompose.join();
        if let Err(payload) = decompose {
            return Err(panicked(DECOMPOSE_THREAD_NAME, payload.as_ref()));
        }
        if let Err(payload) = capture {
            return Err(panicked(CAPTURE_THREAD_NAME, payload.as_ref()));
        }
        let error = self
            .shared
            .capture_error
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
            .take();
        match error {
            Some(error) => Err(PipelineError::Capture(error)),
            None => Ok(self.shared.stats()),
        }
    }
}

/// Marks a pipeline's newest lights stale; see [`Pipeline::mark_stale`].
pub type StaleHandle = crate::publication::StaleHandle<LightFrame>;

/// Reads a pipeline's counters; cheap to clone, valid after the pipeline has ended.
#[derive(Clone)]
pub struct StatsHandle(Arc<Shared>);

impl StatsHandle {
    /// A snapshot of the counters.
    pub fn stats(&self) -> PipelineStats {
        self.0.stats()
    }
}

/// Sets the shutdown flag when dropped (also during a panic).
struct StopOnDrop(Arc<Shared>);

impl Drop for StopOnDrop {
    fn drop(&mut self) {
        self.0.shutdown.store(true, Ordering::Release);
    }
}

/// The body of the capture thread. Before each frame the source gets back the pixel buffers
/// the decompose thread is done with (`recycled`).
fn capture_loop(
    source: &mut dyn FrameSource,
    tx: &Sender<HdrFrame>,
    oldest: &Receiver<HdrFrame>,
    recycled: &Receiver<Vec<[f32; 3]>>,
    policy: QueuePolicy,
    shared: &Shared,
) {
    while !shared.shutdown.load(Ordering::Acquire) {
        for pixels in recycled.try_iter() {
            source.recycle(pixels);
        }
        match source.next_frame() {
            Ok(Some(frame)) => {
                shared.frames_captured.fetch_add(1, Ordering::AcqRel);
                match policy {
                    QueuePolicy::DropOldest => {
                        if let Some(dropped) = push_drop_oldest(tx, oldest, frame, shared) {
                            source.recycle(dropped.pixels);
                        }
                    }
                    QueuePolicy::Block => push_blocking(tx, frame, shared),
                }
            }
            Ok(None) => {
                tracing::info!(source = %source.describe(), "frame source finished");
                break;
            }
            Err(error) => {
                tracing::warn!(source = %source.describe(), %error, "frame source failed; stopping capture");
                shared.capture_errors.fetch_add(1, Ordering::AcqRel);
                *shared
                    .capture_error
                    .lock()
                    .unwrap_or_else(std::sync::PoisonError::into_inner) = Some(error);
                break;
            }
        }
    }
}

/// Queues `frame`, waiting for room, but gives up (counting the frame as dropped) when the
/// pipeline is stopped meanwhile.
fn push_blocking(tx: &Sender<HdrFrame>, mut frame: HdrFrame, shared: &Shared) {
    loop {
        match tx.send_timeout(frame, Duration::from_millis(50)) {
            Ok(()) => return,
            Err(crossbeam_channel::SendTimeoutError::Timeout(back)) => {
                if shared.shutdown.load(Ordering::Acquire) {
                    shared.frames_dropped.fetch_add(1, Ordering::AcqRel);
                    return;
                }
                frame = back;
            }
            Err(crossbeam_channel::SendTimeoutError::Disconnected(_)) => {
                shared.frames_dropped.fetch_add(1, Ordering::AcqRel);
                return;
            }
        }
    }
}

/// Queues `frame` without blocking: while the queue is full, takes out the oldest frame and
/// counts it as dropped. Returns the last frame dropped, if any (its buffer can be reused).
fn push_drop_oldest(
    tx: &Sender<HdrFrame>,
    oldest: &Receiver<HdrFrame>,
    mut frame: HdrFrame,
    shared: &Shared,
) -> Option<HdrFrame> {
    let mut last_dropped = None;
    loop {
        match tx.try_send(frame) {
            Ok(()) => return last_dropped,
            Err(TrySendError::Full(back)) => {
                frame = back;
                // The decompose thread may have emptied a slot meanwhile: then nothing is dropped.
                if let Ok(dropped) = oldest.try_recv() {
                    shared.frames_dropped.fetch_add(1, Ordering::AcqRel);
                    tracing::debug!(seq = dropped.seq, "queue full: dropped the oldest frame");
                    last_dropped = Some(dropped);
                }
            }
            // Unreachable while `oldest` lives, but dropping is the only sensible answer.
            Err(TrySendError::Disconnected(_)) => {
                shared.frames_dropped.fetch_add(1, Ordering::AcqRel);
                return last_dropped;
            }
        }
    }
}

fn panicked(thread: &'static str, payload: &(dyn std::any::Any + Send)) -> PipelineError {
    let message = payload
        .downcast_ref::<&str>()
        .map(|s| (*s).to_owned())
        .or_else(|| payload.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "non-string panic payload".to_owned());
    PipelineError::ThreadPanicked { thread, message }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::decompose::LightPlacement;
    use crate::envmap::Projection;
    use std::path::PathBuf;

    /// A test source: `count` tiny 16×8 lat-long frames (`None` = endless), optionally paced,
    /// optionally failing after the frames, recording the name of the thread it runs on.
    struct FakeSource {
        next_seq: u64,
        count: Option<u64>,
        pace: Duration,
        fail_at_end: bool,
        thread_name: Arc<Mutex<Option<String>>>,
        finished_at: Arc<Mutex<Option<Instant>>>,
        /// A buffer handed back by the pipeline: the next frame is written into it.
        spare: Option<Vec<[f32; 3]>>,
        /// Lengths of the buffers handed back, in order.
        recycled: Arc<Mutex<Vec<usize>>>,
    }

    impl FakeSource {
        fn new(count: Option<u64>, pace: Duration) -> Self {
            Self {
                next_seq: 0,
                count,
                pace,
                fail_at_end: false,
                thread_name: Arc::default(),
                finished_at: Arc::default(),
                spare: None,
                recycled: Arc::default(),
            }
        }
    }

    #[test]
    fn chained_publish_hooks_run_in_order_on_every_publication() {
        let calls: Arc<Mutex<Vec<(&'static str, u64)>>> = Arc::default();
        let hook = |name: &'static str| {
            let calls = Arc::clone(&calls);
            PublishHook(Arc::new(move |p: &Published| {
                calls.lock().unwrap().push((name, p.index));
            }))
        };
        let options = PipelineOptions {
            on_publish: Some(hook("pass").then(hook("metrics"))),
            queue_policy: QueuePolicy::Block,
            ..PipelineOptions::new()
        };
        let source = FakeSource::new(Some(3), Duration::ZERO);
        let pipeline = Pipeline::start_with(Box::new(source), options, |frame| LightFrame {
            seq: frame.seq,
            time: 0.0,
            lights: Vec::new(),
        })
        .unwrap();
        pipeline.join().unwrap();
        let calls = calls.lock().unwrap().clone();
        let expected: Vec<_> = (1..=3)
            .flat_map(|i| [("pass", i), ("metrics", i)])
            .collect();
        assert_eq!(calls, expected);
    }

    /// Pixel i of frame `seq`.
    fn tiny_pixel(seq: u64, i: usize) -> [f32; 3] {
        let v = 0.1 + (i % 7) as f32 + seq as f32 * 0.01;
        [v, v * 0.5, v * 0.25]
    }

    /// A tiny 16×8 lat-long frame number `seq`, written into `pixels` (whatever it held).
    fn tiny_frame_in(seq: u64, mut pixels: Vec<[f32; 3]>) -> HdrFrame {
        let (w, h) = (16u32, 8u32);
        pixels.resize((w * h) as usize, [0.0; 3]);
        for (i, p) in pixels.iter_mut().enumerate() {
            *p = tiny_pixel(seq, i);
        }
        let mut frame = HdrFrame::new(w, h, pixels, Projection::LatLong).unwrap();
        frame.seq = seq;
        frame.time = seq as f64 / 60.0;
        frame
    }

    impl FrameSource for FakeSource {
        fn next_frame(&mut self) -> Result<Option<HdrFrame>, CaptureError> {
            *self.thread_name.lock().unwrap() = std::thread::current().name().map(str::to_owned);
            if self.count.is_some_and(|n| self.next_seq >= n) {
                *self.finished_at.lock().unwrap() = Some(Instant::now());
                if self.fail_at_end {
                    return Err(CaptureError::Format {
                        path: PathBuf::from("fake/frame.exr"),
                        message: "truncated".to_owned(),
                    });
                }
                return Ok(None);
            }
            if !self.pace.is_zero() {
                std::thread::sleep(self.pace);
            }
            let frame = tiny_frame_in(self.next_seq, self.spare.take().unwrap_or_default());
            self.next_seq += 1;
            Ok(Some(frame))
        }

        fn recycle(&mut self, pixels: Vec<[f32; 3]>) {
            self.recycled.lock().unwrap().push(pixels.len());
            self.spare = Some(pixels);
        }

        fn describe(&self) -> String {
            "fake source".to_owned()
        }
    }

    fn small_settings() -> DecomposeSettings {
        DecomposeSettings {
            lights: 16,
            working_width: 16,
            placement: LightPlacement::Centroid,
            filter_taps: None,
            merge_spacing_fraction: None,
            pdf_exponent: 1.0,
            ..DecomposeSettings::default()
        }
    }

    /// Reads the watch channel until a frame with seq ≥ `last_seq` shows up (the poll may miss
    /// frames that are replaced quickly); returns the seqs seen.
    fn collect_until(rx: &mut watch::Receiver<LatestLights>, last_seq: u64) -> Vec<u64> {
        let deadline = Instant::now() + Duration::from_secs(20);
        let mut seen = Vec::new();
        loop {
            let latest = rx.borrow_and_update().clone();
            if let Some(published) = latest {
                let frame = &published.payload;
                if seen.last() != Some(&frame.seq) {
                    seen.push(frame.seq);
                }
                if frame.seq >= last_seq {
                    return seen;
                }
            }
            assert!(Instant::now() < deadline, "timed out; seen {seen:?}");
            std::thread::sleep(Duration::from_micros(200));
        }
    }

    #[test]
    fn finite_paced_source_is_fully_decomposed_in_order() {
        let source = FakeSource::new(Some(20), Duration::from_millis(5));
        // A queue that holds every frame: on a loaded machine the decomposition may fall
        // behind the 5 ms pacing, and this test is about order and completeness, not dropping.
        let options = PipelineOptions {
            queue_capacity: 32,
            ..PipelineOptions::new()
        };
        let pipeline = Pipeline::start(Box::new(source), small_settings(), options).unwrap();
        let mut rx = pipeline.subscribe();
        let seen = collect_until(&mut rx, 19);
        assert!(seen.windows(2).all(|w| w[0] < w[1]), "seqs {seen:?}");
        let stats = pipeline.join().unwrap();
        assert_eq!(stats.frames_captured, 20);
        assert_eq!(stats.frames_decomposed, 20);
        assert_eq!(stats.frames_dropped, 0);
        assert_eq!(stats.capture_errors, 0);
        assert!(stats.last_decompose_time > Duration::ZERO);
        // The senders are gone with the pipeline: the stream reports its end.
        assert!(rx.has_changed().is_err());
        let last = rx.borrow().clone().unwrap().payload.clone();
        assert_eq!(last.seq, 19);
        assert_eq!(last.lights.len(), 16);
    }

    /// A decomposition step that checks each frame holds its own pixels (a recycled buffer
    /// is fully overwritten) and returns no lights.
    fn checking_step(frame: &HdrFrame) -> LightFrame {
        for (i, p) in frame.pixels.iter().enumerate() {
            assert_eq!(
                *p,
                tiny_pixel(frame.seq, i),
                "frame {} pixel {i}",
                frame.seq
            );
        }
        LightFrame {
            seq: frame.seq,
            time: frame.time,
            lights: Vec::new(),
        }
    }

    #[test]
    fn decomposed_frames_hand_their_buffers_back_to_the_source() {
        const N: u64 = 30;
        // Paced, so each frame's buffer is back before the next one is made.
        let source = FakeSource::new(Some(N), Duration::from_millis(2));
        let recycled = Arc::clone(&source.recycled);
        let options = PipelineOptions {
            queue_policy: QueuePolicy::Block,
            ..PipelineOptions::new()
        };
        let pipeline = Pipeline::start_with(Box::new(source), options, checking_step).unwrap();
        let stats = pipeline.join().unwrap();
        assert_eq!(stats.frames_decomposed, N);
        let recycled = recycled.lock().unwrap().clone();
        assert!(recycled.len() >= 2, "{recycled:?}");
        assert!(recycled.iter().all(|&n| n == 16 * 8), "{recycled:?}");
    }

    #[test]
    fn a_frame_the_recorder_takes_is_not_handed_back() {
        const N: u64 = 10;
        let source = FakeSource::new(Some(N), Duration::from_millis(2));
        let recycled = Arc::clone(&source.recycled);
        let (tap_tx, tap_rx) = crossbeam_channel::bounded(N as usize);
        let options = PipelineOptions {
            queue_policy: QueuePolicy::Block,
            tap: Some(tap_tx),
            ..PipelineOptions::new()
        };
        let pipeline = Pipeline::start_with(Box::new(source), options, checking_step).unwrap();
        pipeline.join().unwrap();
        assert!(recycled.lock().unwrap().is_empty());
        let tapped: Vec<Tapped> = tap_rx.try_iter().collect();
        assert_eq!(tapped.len(), N as usize);
        for t in &tapped {
            checking_step(&t.frame);
        }
    }

    #[test]
    fn slow_decomposition_drops_oldest_without_blocking_capture() {
        const N: u64 = 200;
        let source = FakeSource::new(Some(N), Duration::ZERO);
        let finished_at = Arc::clone(&source.finished_at);
        let recycled = Arc::clone(&source.recycled);
        let started = Instant::now();
        let pipeline = Pipeline::start_with(
            Box::new(source),
            PipelineOptions::new(),
            |frame: &HdrFrame| {
                std::thread::sleep(Duration::from_millis(2));
                LightFrame {
                    seq: frame.seq,
                    time: frame.time,
                    lights: Vec::new(),
                }
            },
        )
        .unwrap();
        let mut rx = pipeline.subscribe();
        // The newest frame is never dropped, so the last one is always published.
        let seen = collect_until(&mut rx, N - 1);
        assert!(seen.windows(2).all(|w| w[0] < w[1]), "seqs {seen:?}");
        let stats = pipeline.join().unwrap();
        // Capture ran through all frames far faster than 200 × 2 ms of decomposition.
        let capture_time = finished_at.lock().unwrap().unwrap() - started;
        assert!(
            capture_time < Duration::from_millis(200),
            "capture took {capture_time:?}"
        );
        assert_eq!(stats.frames_captured, N);
        assert!(stats.frames_dropped > 0, "{stats:?}");
        // Dropped frames' buffers went back to the source at once.
        assert!(!recycled.lock().unwrap().is_empty());
        assert_eq!(
            stats.frames_captured,
            stats.frames_decomposed + stats.frames_dropped,
            "{stats:?}"
        );
    }

    #[test]
    fn stop_ends_an_endless_source_promptly() {
        let source = FakeSource::new(None, Duration::from_millis(1));
        let pipeline =
            Pipeline::start(Box::new(source), small_settings(), PipelineOptions::new()).unwrap();
        let mut rx = pipeline.subscribe();
        collect_until(&mut rx, 3);
        let stopped = Instant::now();
        pipeline.stop();
        let stats = pipeline.join().unwrap();
        assert!(stopped.elapsed() < Duration::from_secs(1));
        assert!(stats.frames_captured >= 4);
        assert_eq!(
            stats.frames_captured,
            stats.frames_decomposed + stats.frames_dropped
        );
    }

    #[test]
    fn source_error_is_returned_by_join() {
        let mut source = FakeSource::new(Some(3), Duration::ZERO);
        source.fail_at_end = true;
        let pipeline =
            Pipeline::start(Box::new(source), small_settings(), PipelineOptions::new()).unwrap();
        let stats_probe = pipeline.subscribe();
        match pipeline.join() {
            Err(PipelineError::Capture(CaptureError::Format { path, message })) => {
                assert_eq!(path, PathBuf::from("fake/frame.exr"));
                assert_eq!(message, "truncated");
            }
            other => panic!("expected the capture error, got {other:?}"),
        }
        // Frames before the error were still processed.
        assert_eq!(
            stats_probe.borrow().as_ref().map(|p| p.payload.seq),
            Some(2)
        );
    }

    #[test]
    fn blocking_queue_decomposes_every_frame() {
        const N: u64 = 60;
        let source = FakeSource::new(Some(N), Duration::ZERO);
        let (tap_tx, tap_rx) = crossbeam_channel::bounded(2);
        let options = PipelineOptions {
            queue_policy: QueuePolicy::Block,
            tap: Some(tap_tx),
            ..PipelineOptions::new()
        };
        let pipeline = Pipeline::start_with(Box::new(source), options, |frame: &HdrFrame| {
            std::thread::sleep(Duration::from_micros(300));
            LightFrame {
                seq: frame.seq,
                time: frame.time,
                lights: Vec::new(),
            }
        })
        .unwrap();
        let tapped: Vec<u64> = tap_rx.iter().map(|t| t.frame.seq).collect();
        let stats = pipeline.join().unwrap();
        assert_eq!(stats.frames_dropped, 0);
        assert_eq!(stats.frames_decomposed, N);
        assert_eq!(tapped, (0..N).collect::<Vec<_>>());
    }

    #[test]
    fn stale_flag_republishes_the_newest_lights() {
        let source = FakeSource::new(Some(3), Duration::ZERO);
        let pipeline =
            Pipeline::start(Box::new(source), small_settings(), PipelineOptions::new()).unwrap();
        let mut rx = pipeline.subscribe();
        collect_until(&mut rx, 2);
        while !pipeline.is_finished() {
            std::thread::sleep(Duration::from_millis(1));
        }
        let live = rx.borrow_and_update().clone().unwrap();
        assert!(!live.stale);
        assert!(pipeline.mark_stale());
        let stale = rx.borrow_and_update().clone().unwrap();
        assert!(stale.stale);
        assert_eq!(stale.index, live.index + 1);
        assert!(Arc::ptr_eq(&stale.payload, &live.payload));
        assert!(!pipeline.mark_stale(), "already stale: nothing to publish");
        assert!(!rx.has_changed().unwrap());
        pipeline.join().unwrap();
    }

    #[test]
    fn reconfigure_applies_from_the_next_frame_and_rejects_bad_settings() {
        let source = FakeSource::new(None, Duration::from_millis(2));
        let pipeline =
            Pipeline::start(Box::new(source), small_settings(), PipelineOptions::new()).unwrap();
        let mut rx = pipeline.subscribe();
        collect_until(&mut rx, 1);
        let bad = DecomposeSettings {
            lights: 0,
            ..small_settings()
        };
        assert!(pipeline.reconfigure(bad).is_err());
        let eight = DecomposeSettings {
            lights: 8,
            ..small_settings()
        };
        pipeline.reconfigure(eight).unwrap();
        let deadline = Instant::now() + Duration::from_secs(20);
        loop {
            let latest = rx.borrow_and_update().clone().unwrap();
            if latest.payload.lights.len() == 8 {
                break;
            }
            assert_eq!(latest.payload.lights.len(), 16);
            assert!(Instant::now() < deadline, "the new settings never applied");
            std::thread::sleep(Duration::from_millis(1));
        }
        assert_eq!(pipeline.stats().light_count, 8);
        pipeline.stop();
        pipeline.join().unwrap();
    }

    #[test]
    fn threads_are_named() {
        let source = FakeSource::new(Some(2), Duration::ZERO);
        let capture_name = Arc::clone(&source.thread_name);
        let decompose_name = Arc::new(Mutex::new(None::<String>));
        let recorder = Arc::clone(&decompose_name);
        let pipeline = Pipeline::start_with(
            Box::new(source),
            PipelineOptions::new(),
            move |frame: &HdrFrame| {
                *recorder.lock().unwrap() = std::thread::current().name().map(str::to_owned);
                LightFrame {
                    seq: frame.seq,
                    ..LightFrame::default()
                }
            },
        )
        .unwrap();
        pipeline.join().unwrap();
        assert_eq!(
            capture_name.lock().unwrap().as_deref(),
            Some(CAPTURE_THREAD_NAME)
        );
        assert_eq!(
            decompose_name.lock().unwrap().as_deref(),
            Some(DECOMPOSE_THREAD_NAME)
        );
    }

    #[test]
    fn decompose_panic_becomes_an_error_and_stops_capture() {
        let source = FakeSource::new(None, Duration::from_millis(1));
        // A lossless queue: with the default drop-oldest queue a loaded machine can drop frame 5
        // and the panic would come at a later frame.
        let options = PipelineOptions {
            queue_policy: QueuePolicy::Block,
            ..PipelineOptions::new()
        };
        let pipeline = Pipeline::start_with(Box::new(source), options, |frame: &HdrFrame| {
            assert!(frame.seq < 5, "boom at {}", frame.seq);
            LightFrame::default()
        })
        .unwrap();
        match pipeline.join() {
            Err(PipelineError::ThreadPanicked { thread, message }) => {
                assert_eq!(thread, DECOMPOSE_THREAD_NAME);
                assert!(message.contains("boom at 5"), "{message}");
            }
            other => panic!("expected a panic error, got {other:?}"),
        }
    }

    #[test]
    fn invalid_options_and_settings_are_rejected() {
        let source = FakeSource::new(Some(1), Duration::ZERO);
        let err = Pipeline::start(
            Box::new(source),
            small_settings(),
            PipelineOptions {
                queue_capacity: 0,
                ..PipelineOptions::new()
            },
        )
        .err()
        .unwrap();
        assert!(matches!(err, PipelineError::QueueCapacity(0)));
        let source = FakeSource::new(Some(1), Duration::ZERO);
        let settings = DecomposeSettings {
            lights: 0,
            ..small_settings()
        };
        let err = Pipeline::start(Box::new(source), settings, PipelineOptions::new())
            .err()
            .unwrap();
        assert!(matches!(err, PipelineError::Decompose(_)));
    }
}
