//! Publications on a latest-value channel: what every producing stage of the daemon (the
//! decomposition's light lists, the ASG stage's sets, the wavelet stage's sets) hands to its
//! consumers.
//!
//! A stage owns a [`tokio::sync::watch`] sender of [`Latest<T>`] (a plain thread can send on it;
//! no runtime is needed) and publishes each result with [`publish`]: a [`Publication`] numbered
//! one more than the previous one, under the channel's lock, so a consumer that last handled
//! index `i` and now reads `j` knows it skipped `j − i − 1`. Consumers always read the newest
//! publication; a slow one skips and never holds the stage back. [`StaleHandle`] re-publishes
//! the newest payload marked stale while a lost source is being reconnected; the next newly
//! computed payload is live again.

use std::sync::Arc;
use std::time::{Duration, Instant};
use tokio::sync::watch;

/// One publication of a stage's payload `T` (a light list, an ASG set, a wavelet set).
#[derive(Debug)]
pub struct Publication<T> {
    /// 1 for the first publication, one more for each later one (stale re-publications
    /// included). A consumer that last handled index `i` and now reads `j` skipped `j − i − 1`.
    pub index: u64,
    /// What was computed.
    pub payload: Arc<T>,
    /// The payload is the last known one and the source is lost (set through a
    /// [`StaleHandle`]; a newly computed payload is never stale).
    pub stale: bool,
    /// When the source frame reached the stage (`None` for a stale re-publication). Latency
    /// measurements start here.
    pub arrived: Option<Instant>,
    /// How long the stage took to compute the payload (decomposition, fit, transform).
    pub compute_time: Duration,
    /// When it was published.
    pub published_at: Instant,
}

// Derived `Clone` would require `T: Clone`; only the `Arc` is cloned.
impl<T> Clone for Publication<T> {
    fn clone(&self) -> Self {
        Self {
            index: self.index,
            payload: Arc::clone(&self.payload),
            stale: self.stale,
            arrived: self.arrived,
            compute_time: self.compute_time,
            published_at: self.published_at,
        }
    }
}

impl<T> Publication<T> {
    /// The publication that follows `previous` (numbered one more), stamped now.
    pub fn after(
        previous: Option<&Publication<T>>,
        payload: Arc<T>,
        stale: bool,
        arrived: Option<Instant>,
        compute_time: Duration,
    ) -> Arc<Self> {
        Arc::new(Self {
            index: previous.map_or(0, |p| p.index) + 1,
            payload,
            stale,
            arrived,
            compute_time,
            published_at: Instant::now(),
        })
    }
}

/// What consumers of a stage receive: the newest publication, `None` until the first one.
pub type Latest<T> = Option<Arc<Publication<T>>>;

/// Publishes a newly computed (live) payload on `tx`, numbering it under the channel's lock.
pub fn publish<T>(
    tx: &watch::Sender<Latest<T>>,
    payload: Arc<T>,
    arrived: Option<Instant>,
    compute_time: Duration,
) {
    tx.send_modify(|latest| {
        *latest = Some(Publication::after(
            latest.as_deref(),
            payload,
            false,
            arrived,
            compute_time,
        ));
    });
}

/// Marks the newest publication of a channel stale (the source is lost), from any thread.
/// Cheap to clone.
pub struct StaleHandle<T>(Arc<watch::Sender<Latest<T>>>);

impl<T> Clone for StaleHandle<T> {
    fn clone(&self) -> Self {
        Self(Arc::clone(&self.0))
    }
}

impl<T> StaleHandle<T> {
    /// A handle for the channel of `tx`.
    pub fn new(tx: Arc<watch::Sender<Latest<T>>>) -> Self {
        Self(tx)
    }

    /// Publishes the newest payload again marked stale, so every consumer learns that the
    /// source is lost; nothing happens before the first publication or when it is stale
    /// already. Returns whether anything was published.
    ///
    /// There is no way back but a newly computed payload ([`publish`]), numbered after the
    /// stale one: publishing the old payload again as live when the source comes back would
    /// pass old results off as fresh, with the same seq as the stale frame, before the fresh
    /// ones (a slow stage such as the ASG fits would do so every time).
    pub fn mark_stale(&self) -> bool {
        self.mark_stale_if(|| true)
    }

    /// [`StaleHandle::mark_stale`] if `lost` still holds when tested under the channel's lock:
    /// a source that came back and whose fresh payload was published between a caller's own
    /// test and this call leaves that payload live (a fresh frame marked stale would stay so
    /// until the next one, at a slow source's rate).
    pub fn mark_stale_if(&self, lost: impl FnOnce() -> bool) -> bool {
        let mut changed = false;
        self.0.send_if_modified(|latest| match latest {
            Some(p) if !p.stale && lost() => {
                let payload = Arc::clone(&p.payload);
                *latest = Some(Publication::after(
                    Some(p),
                    payload,
                    true,
                    None,
                    Duration::ZERO,
                ));
                changed = true;
                true
            }
            _ => false,
        });
        changed
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn publications_are_numbered_and_stale_republishes_the_same_payload() {
        let (tx, mut rx) = watch::channel::<Latest<u32>>(None);
        let tx = Arc::new(tx);
        let stale = StaleHandle::new(Arc::clone(&tx));
        assert!(!stale.mark_stale(), "nothing published yet");
        publish(
            &tx,
            Arc::new(7),
            Some(Instant::now()),
            Duration::from_millis(2),
        );
        let first = rx.borrow_and_update().clone().unwrap();
        assert_eq!((first.index, *first.payload, first.stale), (1, 7, false));
        assert_eq!(first.compute_time, Duration::from_millis(2));
        assert!(!stale.mark_stale_if(|| false), "the source is back");
        assert!(!rx.has_changed().unwrap());
        assert!(stale.mark_stale());
        assert!(!stale.mark_stale(), "already stale");
        let second = rx.borrow_and_update().clone().unwrap();
        assert_eq!(second.index, 2);
        assert!(second.stale && second.arrived.is_none());
        assert!(Arc::ptr_eq(&first.payload, &second.payload));
        publish(&tx, Arc::new(8), None, Duration::ZERO);
        let third = rx.borrow_and_update().clone().unwrap();
        assert_eq!((third.index, *third.payload, third.stale), (3, 8, false));
    }
}
