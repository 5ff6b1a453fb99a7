//! A frame source that survives device loss ([`ResilientSource`]).
//!
//! It wraps an *opener* (a closure that opens the real source, e.g. a V4L2 camera) and:
//! 1. opens the source on the first call of `next_frame`;
//! 2. on any error (open failure, EIO after an unplug, a dequeue timeout) logs it, drops the
//!    source, marks the shared [`SourceHealth`] stale, records the error text and the attempt,
//!    sleeps with exponential backoff (initial, doubling, capped at the maximum) and reopens;
//! 3. on the first frame after a recovery clears `stale`, resets the backoff and logs the
//!    resumption.
//!
//! A settings error ([`CaptureError::InvalidSettings`]: no camera of that name, no usable
//! format) before the source has ever opened is returned at once: it is a configuration
//! mistake, not a lost device. After the first open every error is retried.
//!
//! Frame sequence numbers continue across reconnects, and frame times are rebased so that they
//! never decrease.
//!
//! Meanwhile `next_frame` does not return, so the pipeline keeps serving the last lights; the
//! daemon reads [`SourceHealth::is_stale`] to mark them stale in the stream and metrics.
//! [`SourceHealth::request_stop`] ends the retries (`next_frame` returns `Ok(None)`), and
//! `max_attempts` bounds them (the last error is returned).

use super::{CaptureError, FrameSource, SourceHealth};
use crate::frame::HdrFrame;
use std::sync::Arc;
use std::time::Duration;

/// Retry policy.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RetryPolicy {
    pub initial_backoff: Duration,
    pub max_backoff: Duration,
    /// Consecutive failed attempts before giving up; `None` = retry forever.
    pub max_attempts: Option<u64>,
}

impl Default for RetryPolicy {
    fn default() -> Self {
        Self {
            initial_backoff: Duration::from_millis(500),
            max_backoff: Duration::from_secs(30),
            max_attempts: None,
        }
    }
}

impl RetryPolicy {
    /// The wait before retry number `attempt` (1-based): initial · 2^(attempt−1), capped.
    pub fn backoff(&self, attempt: u64) -> Duration {
        let factor = 2u32.saturating_pow(attempt.saturating_sub(1).min(31) as u32);
        self.initial_backoff
            .saturating_mul(factor)
            .min(self.max_backoff)
    }
}

type Opener = Box<dyn FnMut() -> Result<Box<dyn FrameSource>, CaptureError> + Send>;

/// See the module docs.
pub struct ResilientSource {
    open: Opener,
    name: String,
    inner: Option<Box<dyn FrameSource>>,
    policy: RetryPolicy,
    health: Arc<SourceHealth>,
    /// Consecutive failures since the last good frame.
    failures: u64,
    /// Sequence numbers continue across reconnects.
    next_seq: u64,
    start: std::time::Instant,
    /// (seconds since `start` when the current inner source opened, its first frame's time):
    /// frame times are rebased so they keep increasing across reconnects.
    epoch: Option<(f64, Option<f64>)>,
    /// Time of the last frame returned.
    last_time: f64,
    /// Whether the source has been opened once (settings errors are fatal before that).
    opened_once: bool,
}

impl ResilientSource {
    /// `name` describes the source in logs before it is open.
    pub fn new(
        name: impl Into<String>,
        policy: RetryPolicy,
        open: impl FnMut() -> Result<Box<dyn FrameSource>, CaptureError> + Send + 'static,
    ) -> Self {
        Self {
            open: Box::new(open),
            name: name.into(),
            inner: None,
            policy,
            health: Arc::new(SourceHealth::default()),
            failures: 0,
            next_seq: 0,
            start: std::time::Instant::now(),
            epoch: None,
            last_time: 0.0,
            opened_once: false,
        }
    }

    /// Sleeps `d` in short steps, returning early (false) when a stop is requested.
    fn wait(&self, d: Duration) -> bool {
        let step = Duration::from_millis(20);
        let end = std::time::Instant::now() + d;
        loop {
            if self.health.stop_requested() {
                return false;
            }
            let now = std::time::Instant::now();
            if now >= end {
                return true;
            }
            std::thread::sleep(step.min(end - now));
        }
    }

    fn fail(&mut self, err: CaptureError) -> Result<(), CaptureError> {
        self.inner = None;
        self.failures += 1;
        self.health.mark_failure(&err.to_string());
        if let Some(max) = self.policy.max_attempts {
            if self.failures >= max {
                tracing::error!("{}: giving up after {max} attempts: {err}", self.name);
                return Err(err);
            }
        }
        let wait = self.policy.backoff(self.failures);
        // Before the first frame there are no lights to serve: the source is awaited.
        let meanwhile = if self.next_seq > 0 {
            "serving the last lights (stale)"
        } else {
            "no frame yet, waiting for it"
        };
        tracing::warn!(
            "{}: {err}; {meanwhile}, retry {} in {:.1} s",
            self.name,
            self.failures,
            wait.as_secs_f64()
        );
        self.wait(wait);
        Ok(())
    }
}

impl FrameSource for ResilientSource {
    fn next_frame(&mut self) -> Result<Option<HdrFrame>, CaptureError> {
        loop {
            if self.health.stop_requested() {
                return Ok(None);
            }
            if self.inner.is_none() {
                match (self.open)() {
                    Ok(src) => {
                        tracing::info!("{}: opened {}", self.name, src.describe());
                        self.inner = Some(src);
                        self.opened_once = true;
                        let now = self.start.elapsed().as_secs_f64();
                        self.epoch = Some((now.max(self.last_time), None));
                    }
                    Err(e @ CaptureError::InvalidSettings(_)) if !self.opened_once => {
                        // a wrong name or format is a configuration error, not a lost device
                        self.health.mark_failure(&e.to_string());
                        return Err(e);
                    }
                    Err(e) => {
                        self.fail(e)?;
                        continue;
                    }
                }
            }
            let Some(src) = self.inner.as_mut() else {
                continue;
            };
            match src.next_frame() {
                Ok(Some(mut frame)) => {
                    if self.failures > 0 {
                        tracing::info!(
                            "{}: resumed after {} failed attempts",
                            self.name,
                            self.failures
                        );
                    }
                    self.failures = 0;
                    self.health.mark_ok();
                    frame.seq = self.next_seq;
                    self.next_seq += 1;
                    let (opened, first) = self.epoch.get_or_insert((0.0, None));
                    let first = *first.get_or_insert(frame.time);
                    frame.time = if frame.time.is_finite() && first.is_finite() {
                        *opened + (frame.time - first).max(0.0)
                    } else {
                        self.start.elapsed().as_secs_f64()
                    }
                    .max(self.last_time);
                    self.last_time = frame.time;
                    return Ok(Some(frame));
                }
                Ok(None) => return Ok(None),
                Err(e) => self.fail(e)?,
            }
        }
    }

    fn recycle(&mut self, pixels: Vec<[f32; 3]>) {
        if let Some(src) = self.inner.as_mut() {
            src.recycle(pixels);
        }
    }

    fn describe(&self) -> String {
        match &self.inner {
            Some(s) => format!("{} (reconnecting on loss)", s.describe()),
            None => format!("{} (not open)", self.name),
        }
    }

    fn health(&self) -> Option<Arc<SourceHealth>> {
        Some(self.health.clone())
    }
}
