//! The hand-off of frames from the decompose thread to a slower stage (the ASG fits, the
//! wavelet transforms): a single slot where the newest frame wins.
//!
//! - **Never slows the lights.** The decompose thread offers each frame *after* publishing its
//!   lights ([`FrameFeed::offer`]); a frame still waiting when a newer one arrives is replaced
//!   and counted ([`FrameFeed::skipped`]). The decompose thread never waits (live sources).
//! - **Replay is lossless.** With [`FrameFeed::new`]`(true)` (the daemon's replay mode, like the
//!   pipeline's [`crate::pipeline::QueuePolicy::Block`]) `offer` waits until the slot is free,
//!   so the stage sees every frame in order and its stream of a recording is reproducible.
//! - **End.** Closing the feed ([`FrameFeed::close`], or dropping a [`CloseOnDrop`]) lets the
//!   stage take the frame still waiting and then see the end ([`FrameFeed::take`] → `None`).

use crate::frame::HdrFrame;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Condvar, Mutex, MutexGuard};
use std::time::Instant;

#[derive(Default)]
struct Slot {
    frame: Option<FedFrame>,
    closed: bool,
}

/// A frame as the stage takes it from the feed.
#[derive(Debug)]
pub struct FedFrame {
    pub frame: HdrFrame,
    /// When it was offered.
    pub arrived: Instant,
    /// Its place among the frames offered to the feed (0 for the first): the decompose
    /// thread's count, so a gap between two frames a stage takes is the number it skipped
    /// (what a temporal filter of the stage's sets fills in, [`crate::set_filter`]).
    pub number: u64,
}

#[derive(Default)]
struct FeedInner {
    slot: Mutex<Slot>,
    /// Signalled when a frame is put in the slot, taken out of it, or the feed closes.
    changed: Condvar,
    lossless: bool,
    offered: AtomicU64,
    skipped: AtomicU64,
}

/// The hand-off from the decompose thread to a stage: one slot, newest frame wins (or,
/// lossless, the sender waits for the slot). Cheap to clone.
#[derive(Clone, Default)]
pub struct FrameFeed(Arc<FeedInner>);

impl std::fmt::Debug for FrameFeed {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FrameFeed")
            .field("lossless", &self.0.lossless)
            .finish_non_exhaustive()
    }
}

impl FrameFeed {
    /// An open feed; `lossless` makes [`FrameFeed::offer`] wait for a free slot instead of
    /// replacing the waiting frame.
    pub fn new(lossless: bool) -> Self {
        Self(Arc::new(FeedInner {
            lossless,
            ..FeedInner::default()
        }))
    }

    fn lock(&self) -> MutexGuard<'_, Slot> {
        self.0
            .slot
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    /// Hands a frame to the stage. Live: replaces a frame still waiting (counted as skipped)
    /// and returns at once. Lossless: waits while a frame is waiting. A closed feed drops it.
    pub fn offer(&self, frame: HdrFrame) {
        let mut slot = self.lock();
        if slot.closed {
            return;
        }
        let number = self.0.offered.fetch_add(1, Ordering::AcqRel);
        if self.0.lossless {
            while slot.frame.is_some() && !slot.closed {
                slot = self
                    .0
                    .changed
                    .wait(slot)
                    .unwrap_or_else(std::sync::PoisonError::into_inner);
            }
            if slot.closed {
                return;
            }
        }
        let fed = FedFrame {
            frame,
            arrived: Instant::now(),
            number,
        };
        if slot.frame.replace(fed).is_some() {
            self.0.skipped.fetch_add(1, Ordering::AcqRel);
        }
        drop(slot);
        self.0.changed.notify_all();
    }

    /// Frames offered so far (closed feeds excepted).
    pub fn offered(&self) -> u64 {
        self.0.offered.load(Ordering::Acquire)
    }

    /// Frames replaced by a newer one before the stage took them.
    pub fn skipped(&self) -> u64 {
        self.0.skipped.load(Ordering::Acquire)
    }

    /// No more frames: the stage processes the one still waiting (if any) and ends.
    pub fn close(&self) {
        self.lock().closed = true;
        self.0.changed.notify_all();
    }

    /// The next frame, waiting for one; `None` once the feed is closed and empty.
    pub fn take(&self) -> Option<FedFrame> {
        let mut slot = self.lock();
        loop {
            if let Some(frame) = slot.frame.take() {
                drop(slot);
                self.0.changed.notify_all();
                return Some(frame);
            }
            if slot.closed {
                return None;
            }
            slot = self
                .0
                .changed
                .wait(slot)
                .unwrap_or_else(std::sync::PoisonError::into_inner);
        }
    }
}

/// Closes the feed when dropped (the end of the thread that feeds it, a panic included).
pub struct CloseOnDrop(pub FrameFeed);

impl Drop for CloseOnDrop {
    fn drop(&mut self) {
        self.0.close();
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::envmap::Projection;

    fn frame(seq: u64) -> HdrFrame {
        let mut f = HdrFrame::new(2, 1, vec![[1.0; 3]; 2], Projection::LatLong).unwrap();
        f.seq = seq;
        f
    }

    #[test]
    fn live_feed_keeps_the_newest_frame_and_counts_skips() {
        let feed = FrameFeed::new(false);
        feed.offer(frame(0));
        feed.offer(frame(1));
        feed.offer(frame(2));
        let taken = feed.take().unwrap();
        assert_eq!((taken.frame.seq, taken.number), (2, 2));
        assert_eq!(feed.skipped(), 2);
        assert_eq!(feed.offered(), 3);
        feed.offer(frame(3));
        feed.close();
        // The waiting frame is still delivered after close; later offers are dropped.
        feed.offer(frame(4));
        let taken = feed.take().unwrap();
        assert_eq!((taken.frame.seq, taken.number), (3, 3));
        assert!(feed.take().is_none());
    }
}
