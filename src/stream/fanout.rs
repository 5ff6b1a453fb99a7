//! Fan-out of publications to the Unix-socket and TCP clients without a task wake-up per client.
//!
//! With one tokio task per client, every publication woke 64 tasks for 64 clients, and each
//! looked up the encoding, armed a write timer and wrote: on 2 cores shared with the
//! decomposition and the clients, those hops made up much of the end-to-end latency (docs/
//! performance.md, "Streaming"). Here one pass writes the frame (encoded once per cap and form)
//! to every client whose socket has room, with non-blocking writes. For the light lists the
//! pass runs by default on the thread that publishes them, right after publishing
//! ([`super::server::PublisherPass`], `stream.fanout_on = "publisher"`); one named thread per
//! served channel (`envlight-fanout`), woken once per publication (or, for a channel whose
//! publisher passes, looking every 20 ms), runs it for everything
//! else (stale re-sends, the ASG and wavelet channels) and, with `fanout_on = "thread"`, for
//! the light lists too. With 16 or more clients a pass is shared: the passing thread writes
//! one share of the clients and each `envlight-pass` thread (`stream.pass_threads − 1` per
//! channel) another at the same time ([`Fanout::pass`]; a busy one's share is written by the
//! passing thread, so nothing queues).
//!
//! Each client has a [`Slot`] shared by the fan-out thread and the client's connection task,
//! which says who writes to the socket now ([`Writer`]):
//! - **Fan-out** (a client that keeps up): the pass writes the whole frame in one `write`. If
//!   the socket takes only part of it, or none (its buffer is full: the client reads slowly), the
//!   slot goes to the task with what is left of the frame and the task is notified.
//! - **Task**: the connection task finishes the unfinished frame (with the write timeout), then
//!   takes the newest publication if it has not sent it (newest-frame-wins: the publications in
//!   between are counted as skipped), and so on until it has sent the newest one; then it hands
//!   the slot back to the fan-out. A slow client therefore never holds up the pass (its writes
//!   are non-blocking) and holds at most one encoded frame.
//! - **Closed**: the task has ended the connection; the pass leaves it alone.
//!
//! Who writes is decided under the slot's lock, and the task reads the newest publication while
//! holding it, so no publication falls between the two: either the pass finds the slot handed
//! back and writes it, or the task finds it in the channel. A new client starts with the task,
//! which sends the newest publication at once.
//!
//! The connection task keeps reading the socket (client input is an error; end of input is
//! fine) and waits for a hand-over, the shutdown broadcast, or the end of the stream, which the
//! fan-out thread announces to every slot ([`Fanout::end`]).

use super::server::{Encoding, Frame};
use prometheus_client::metrics::counter::Counter;
use prometheus_client::metrics::gauge::Gauge;
use prometheus_client::metrics::histogram::Histogram;
use std::io::{self, Read, Write};
use std::os::fd::{AsFd, AsRawFd, BorrowedFd, OwnedFd, RawFd};
use std::pin::Pin;
use std::sync::{Arc, Mutex, MutexGuard};
use std::task::{ready, Context, Poll};
use std::time::Instant;
use tokio::io::unix::AsyncFd;
use tokio::io::{AsyncRead, AsyncWrite, Interest, ReadBuf};
use tokio::sync::Notify;

/// Name of the fan-out threads.
pub const FANOUT_THREAD_NAME: &str = "envlight-fanout";

/// A connected stream socket shared by a connection task (reads, the slow path, the closing
/// message) and the fan-out thread (non-blocking writes).
pub(super) trait Socket: Send + Sync + 'static {
    /// A non-blocking write from any thread; `WouldBlock` when the send buffer is full.
    fn try_write(&self, buf: &[u8]) -> io::Result<usize>;
    /// Reads, waiting on the runtime's reactor.
    fn poll_read(&self, cx: &mut Context<'_>, buf: &mut ReadBuf<'_>) -> Poll<io::Result<()>>;
    /// Writes, waiting on the runtime's reactor for room.
    fn poll_write(&self, cx: &mut Context<'_>, buf: &[u8]) -> Poll<io::Result<usize>>;
    /// The task has stopped writing: stop watching for room (see [`FdSocket`]).
    fn write_done(&self);
    /// Shuts the writing direction down (the client reads end of stream).
    fn shutdown_write(&self) -> io::Result<()>;
}

/// A Unix-socket or TCP connection in non-blocking mode.
pub(super) enum Stream {
    Unix(std::os::unix::net::UnixStream),
    Tcp(std::net::TcpStream),
}

impl AsFd for Stream {
    fn as_fd(&self) -> BorrowedFd<'_> {
        match self {
            Stream::Unix(s) => s.as_fd(),
            Stream::Tcp(s) => s.as_fd(),
        }
    }
}

impl AsRawFd for Stream {
    fn as_raw_fd(&self) -> RawFd {
        self.as_fd().as_raw_fd()
    }
}

impl Stream {
    fn read(&self, buf: &mut [u8]) -> io::Result<usize> {
        match self {
            Stream::Unix(s) => (&*s).read(buf),
            Stream::Tcp(s) => (&*s).read(buf),
        }
    }

    fn write(&self, buf: &[u8]) -> io::Result<usize> {
        match self {
            Stream::Unix(s) => (&*s).write(buf),
            Stream::Tcp(s) => (&*s).write(buf),
        }
    }
}

/// A [`Stream`] registered with the runtime's reactor for **reading only**. Registered for
/// writing too (as a tokio `UnixStream` or `TcpStream` is), every read by a client that frees
/// room in the send buffer woke a serving thread from `epoll_wait` (some 24 wake-ups per frame
/// with 64 clients, measured with `perf stat`), for nothing: the fan-out writes without
/// waiting. Interest in room is registered (on a duplicate descriptor) only while the
/// connection task writes, and dropped when it hands the client back to the fan-out.
pub(super) struct FdSocket {
    stream: AsyncFd<Stream>,
    writable: Mutex<Option<AsyncFd<OwnedFd>>>,
}

impl FdSocket {
    /// Registers `stream` (made non-blocking) with the current runtime.
    pub fn new(stream: Stream) -> io::Result<Self> {
        match &stream {
            Stream::Unix(s) => s.set_nonblocking(true)?,
            Stream::Tcp(s) => s.set_nonblocking(true)?,
        }
        // SAFETY: `Stream` owns its descriptor, which stays open and the same until the
        // `AsyncFd` is dropped (the stream is never swapped out).
        let stream = unsafe { AsyncFd::register_with_interest(stream, Interest::READABLE) }
            .map_err(io::Error::from)?;
        Ok(Self {
            stream,
            writable: Mutex::new(None),
        })
    }
}

impl Socket for FdSocket {
    fn try_write(&self, buf: &[u8]) -> io::Result<usize> {
        self.stream.get_ref().write(buf)
    }

    fn poll_read(&self, cx: &mut Context<'_>, buf: &mut ReadBuf<'_>) -> Poll<io::Result<()>> {
        loop {
            let mut guard = ready!(self.stream.poll_read_ready(cx))?;
            match guard.try_io(|s| s.get_ref().read(buf.initialize_unfilled())) {
                Ok(Ok(n)) => {
                    buf.advance(n);
                    return Poll::Ready(Ok(()));
                }
                Ok(Err(e)) => return Poll::Ready(Err(e)),
                // Stale readiness, now cleared: poll again (and wait).
                Err(_would_block) => continue,
            }
        }
    }

    fn poll_write(&self, cx: &mut Context<'_>, buf: &[u8]) -> Poll<io::Result<usize>> {
        let mut writable = self
            .writable
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        let registration = match &mut *writable {
            Some(registration) => registration,
            empty @ None => {
                let fd = self.stream.get_ref().as_fd().try_clone_to_owned()?;
                // SAFETY: the `OwnedFd` (a duplicate of the stream's descriptor) stays open and
                // the same until the `AsyncFd` that owns it is dropped.
                let registration =
                    unsafe { AsyncFd::register_with_interest(fd, Interest::WRITABLE) }
                        .map_err(io::Error::from)?;
                empty.insert(registration)
            }
        };
        loop {
            let mut guard = ready!(registration.poll_write_ready(cx))?;
            match guard.try_io(|_| self.stream.get_ref().write(buf)) {
                Ok(written) => return Poll::Ready(written),
                Err(_would_block) => continue,
            }
        }
    }

    fn write_done(&self) {
        *self
            .writable
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner) = None;
    }

    fn shutdown_write(&self) -> io::Result<()> {
        match self.stream.get_ref() {
            Stream::Unix(s) => s.shutdown(std::net::Shutdown::Write),
            Stream::Tcp(s) => s.shutdown(std::net::Shutdown::Write),
        }
    }
}

/// A shared socket as an [`AsyncRead`] + [`AsyncWrite`] for the connection task (the handshake,
/// the slow path and the closing message), while the fan-out thread writes through another
/// clone.
pub(super) struct Shared(pub Arc<dyn Socket>);

impl AsyncRead for Shared {
    fn poll_read(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        self.0.poll_read(cx, buf)
    }
}

impl AsyncWrite for Shared {
    fn poll_write(
        self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<io::Result<usize>> {
        self.0.poll_write(cx, buf)
    }

    fn poll_flush(self: Pin<&mut Self>, _: &mut Context<'_>) -> Poll<io::Result<()>> {
        Poll::Ready(Ok(()))
    }

    fn poll_shutdown(self: Pin<&mut Self>, _: &mut Context<'_>) -> Poll<io::Result<()>> {
        Poll::Ready(self.0.shutdown_write())
    }
}

/// Who writes a client's frames.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Writer {
    /// The fan-out pass, with non-blocking writes.
    Fanout,
    /// The connection task (a new client, or one whose socket was full).
    Task,
    /// Nobody: the connection is closing.
    Closed,
}

/// A frame the pass began and could not finish.
pub(super) struct Unfinished {
    /// The encoded frame.
    pub bytes: Arc<Vec<u8>>,
    /// How many of its bytes are written.
    pub written: usize,
    /// Where its delivery latency starts.
    pub delivery_start: Option<Instant>,
}

/// The metric handles of one client, taken once at subscription.
pub(super) struct SlotMetrics {
    /// Frames written, for this client's endpoint.
    pub sent: Counter,
    /// Frames skipped, for this client's endpoint.
    pub skipped: Counter,
    /// Frames this client skipped so far.
    pub client_skipped: Gauge,
    /// Delivery latency (from arrival at the decomposition).
    pub delivery: Histogram,
}

struct SlotState {
    writer: Writer,
    /// Index of the newest publication sent (or being sent) to this client.
    last_index: u64,
    /// Publications skipped so far.
    skipped: u64,
    unfinished: Option<Unfinished>,
}

/// A client as the fan-out and its connection task share it.
pub(super) struct Slot {
    socket: Arc<dyn Socket>,
    cap: Option<usize>,
    encoding: Encoding,
    state: Mutex<SlotState>,
    /// Notified when the slot goes to the task (socket full) or the stream ends.
    handover: Notify,
    metrics: SlotMetrics,
}

impl Slot {
    /// A new client's slot; the task writes first (the newest publication, at once).
    pub fn new(
        socket: Arc<dyn Socket>,
        cap: Option<usize>,
        encoding: Encoding,
        metrics: SlotMetrics,
    ) -> Self {
        Self {
            socket,
            cap,
            encoding,
            state: Mutex::new(SlotState {
                writer: Writer::Task,
                last_index: 0,
                skipped: 0,
                unfinished: None,
            }),
            handover: Notify::new(),
            metrics,
        }
    }

    fn lock(&self) -> MutexGuard<'_, SlotState> {
        self.state
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    /// Who writes now.
    pub fn writer(&self) -> Writer {
        self.lock().writer
    }

    /// Notes that publication `index` goes to this client, counting the ones skipped since the
    /// last; `false` if it was sent already.
    fn claim(&self, state: &mut SlotState, index: u64) -> bool {
        if index <= state.last_index {
            return false;
        }
        if state.last_index != 0 && index > state.last_index + 1 {
            let skipped = index - state.last_index - 1;
            state.skipped += skipped;
            self.metrics.skipped.inc_by(skipped);
            self.metrics
                .client_skipped
                .set(i64::try_from(state.skipped).unwrap_or(i64::MAX));
        }
        state.last_index = index;
        true
    }

    /// Counts a frame written in full.
    pub fn delivered(&self, delivery_start: Option<Instant>) {
        self.metrics.sent.inc();
        if let Some(start) = delivery_start {
            self.metrics.delivery.observe(start.elapsed().as_secs_f64());
        }
    }

    /// The pass: writes publication `index` (its bytes from `bytes`, in this client's cap and
    /// form) if the fan-out writes for this client and has not sent it; hands the slot to the
    /// task if the socket does not take all of it.
    fn offer(
        &self,
        index: u64,
        delivery_start: Option<Instant>,
        bytes: impl FnOnce(Option<usize>, Encoding) -> Arc<Vec<u8>>,
    ) {
        let mut state = self.lock();
        if state.writer != Writer::Fanout || !self.claim(&mut state, index) {
            return;
        }
        let bytes = bytes(self.cap, self.encoding);
        match self.socket.try_write(&bytes) {
            Ok(n) if n == bytes.len() => {
                drop(state);
                self.delivered(delivery_start);
                return;
            }
            Ok(n) if n > 0 => {
                state.unfinished = Some(Unfinished {
                    bytes,
                    written: n,
                    delivery_start,
                });
            }
            // Nothing written (full buffer, or an error the task's write will meet again):
            // the task sends the newest publication when the socket has room.
            _ => state.last_index = index - 1,
        }
        state.writer = Writer::Task;
        drop(state);
        self.handover.notify_one();
    }

    /// For the task: the frame the pass could not finish, if any.
    pub fn take_unfinished(&self) -> Option<Unfinished> {
        self.lock().unfinished.take()
    }

    /// For the task: the newest publication (from `newest`, read under the slot's lock) if this
    /// client has not had it, or else `None`, and the fan-out writes from now on.
    pub fn next_for_task(
        &self,
        newest: impl FnOnce() -> Option<Arc<dyn Frame>>,
    ) -> Option<Arc<dyn Frame>> {
        let mut state = self.lock();
        if state.writer != Writer::Task {
            return None;
        }
        match newest() {
            Some(frame) if self.claim(&mut state, frame.index()) => Some(frame),
            _ => {
                state.writer = Writer::Fanout;
                None
            }
        }
    }

    /// For the task: waits until the slot is handed to it (or the stream ends).
    pub async fn handed_over(&self) {
        self.handover.notified().await;
    }

    /// For the task: nobody writes frames any more. Returns whether a frame is left half
    /// written (then no closing message can follow it).
    pub fn close(&self) -> bool {
        let mut state = self.lock();
        state.writer = Writer::Closed;
        state.unfinished.take().is_some()
    }
}

/// Name of the threads that share each pass with the thread that runs it
/// (`stream.pass_threads`).
pub const PASS_THREAD_NAME: &str = "envlight-pass";

/// A pass is shared out only so far that every thread writes to at least this many clients:
/// waking a helper costs about as much as writing to a few clients (docs/performance.md, "The
/// pass shared by two threads").
pub(super) const MIN_CLIENTS_PER_PASS_THREAD: usize = 8;

/// One helper's share of a pass: its clients, each with the publication's bytes in its form.
struct Share {
    index: u64,
    delivery_start: Option<Instant>,
    clients: Vec<(Arc<Slot>, Arc<Vec<u8>>)>,
}

impl Share {
    fn run(self) {
        for (slot, bytes) in self.clients {
            slot.offer(self.index, self.delivery_start, |_, _| bytes);
        }
    }
}

/// A thread that writes a share of each pass ([`PASS_THREAD_NAME`]). Its mailbox holds at most
/// one share: while it is still busy with the last one, the passing thread writes the new
/// share itself, so a starved helper delays no client by more than one pass and holds no
/// queue.
#[derive(Default)]
struct PassHelper {
    mailbox: Mutex<Mailbox>,
    wake: std::sync::Condvar,
    /// Shares this helper wrote (`envlight_pass_shares_total`).
    shares: Counter,
    /// Shares given back because it was busy (`envlight_pass_shares_returned_total`).
    returned: Counter,
}

#[derive(Default)]
struct Mailbox {
    share: Option<Share>,
    closed: bool,
}

impl PassHelper {
    fn mailbox(&self) -> MutexGuard<'_, Mailbox> {
        self.mailbox
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    /// Hands `share` to the helper, or gives it back if the helper is busy or stopped.
    fn give(&self, share: Share) -> Result<(), Share> {
        let mut mailbox = self.mailbox();
        if mailbox.share.is_some() || mailbox.closed {
            if !mailbox.closed {
                self.returned.inc();
            }
            return Err(share);
        }
        mailbox.share = Some(share);
        drop(mailbox);
        self.wake.notify_one();
        Ok(())
    }

    /// The helper thread's loop: runs each share given to it until [`Self::close`].
    fn serve(&self) {
        loop {
            let mut mailbox = self.mailbox();
            while mailbox.share.is_none() && !mailbox.closed {
                mailbox = self
                    .wake
                    .wait(mailbox)
                    .unwrap_or_else(std::sync::PoisonError::into_inner);
            }
            let Some(share) = mailbox.share.take() else {
                return;
            };
            drop(mailbox);
            share.run();
            self.shares.inc();
        }
    }

    fn close(&self) {
        self.mailbox().closed = true;
        self.wake.notify_one();
    }
}

/// The clients of one channel's fan-out.
#[derive(Default)]
pub(super) struct Fanout {
    registry: Mutex<Registry>,
    /// The publishing thread runs the pass of each live publication itself
    /// ([`super::server::PublisherPass`]); the fan-out thread passes only the others.
    publisher_passes: std::sync::atomic::AtomicBool,
    /// The threads that share each pass with the thread that runs it.
    helpers: Mutex<Vec<Arc<PassHelper>>>,
}

#[derive(Default)]
struct Registry {
    slots: Vec<Arc<Slot>>,
    /// The channel has ended: no more publications.
    ended: bool,
}

/// A client's place in a [`Fanout`]; dropping it removes the client.
pub(super) struct Registration {
    fanout: Arc<Fanout>,
    slot: Arc<Slot>,
}

impl Drop for Registration {
    fn drop(&mut self) {
        self.fanout
            .lock()
            .slots
            .retain(|s| !Arc::ptr_eq(s, &self.slot));
    }
}

impl Fanout {
    fn lock(&self) -> MutexGuard<'_, Registry> {
        self.registry
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    /// Adds a client; `None` if the channel has ended.
    pub fn register(self: &Arc<Self>, slot: &Arc<Slot>) -> Option<Registration> {
        let mut registry = self.lock();
        if registry.ended {
            return None;
        }
        registry.slots.push(Arc::clone(slot));
        Some(Registration {
            fanout: Arc::clone(self),
            slot: Arc::clone(slot),
        })
    }

    /// Whether the publishing thread runs the pass of live publications.
    pub fn publisher_passes(&self) -> bool {
        self.publisher_passes
            .load(std::sync::atomic::Ordering::Acquire)
    }

    /// The publishing thread runs (`true`) or stops running the pass of live publications.
    pub fn set_publisher_passes(&self, on: bool) {
        self.publisher_passes
            .store(on, std::sync::atomic::Ordering::Release);
    }

    /// Whether the channel has ended.
    pub fn ended(&self) -> bool {
        self.lock().ended
    }

    /// One pass: `frame` to every client the fan-out writes for; `encoded` gives the frame's
    /// bytes for a cap and form (encoded once each per publication).
    ///
    /// With helper threads ([`Fanout::start_helpers`]) and enough clients, the clients are
    /// cut into consecutive shares, at least [`MIN_CLIENTS_PER_PASS_THREAD`] each: the first
    /// is written here, each other one by a helper at the same time (or here, after the first,
    /// if that helper is still busy with the last pass).
    pub fn pass(
        &self,
        frame: &dyn Frame,
        encoded: &dyn Fn(Option<usize>, Encoding) -> Arc<Vec<u8>>,
    ) {
        let slots = self.lock().slots.clone();
        // Too few clients to share: no helper list to look at (and no allocation).
        let helpers = if slots.len() >= 2 * MIN_CLIENTS_PER_PASS_THREAD {
            self.helpers().clone()
        } else {
            Vec::new()
        };
        let mut forms: Vec<(Option<usize>, Encoding, Arc<Vec<u8>>)> = Vec::new();
        let mut memo = |cap: Option<usize>, encoding: Encoding| {
            if let Some((_, _, bytes)) = forms.iter().find(|(c, e, _)| *c == cap && *e == encoding)
            {
                return Arc::clone(bytes);
            }
            let bytes = encoded(cap, encoding);
            forms.push((cap, encoding, Arc::clone(&bytes)));
            bytes
        };
        let (index, delivery_start) = (frame.index(), frame.delivery_start());
        let threads = (1 + helpers.len()).min(slots.len() / MIN_CLIENTS_PER_PASS_THREAD);
        if threads <= 1 {
            for slot in &slots {
                slot.offer(index, delivery_start, &mut memo);
            }
            return;
        }
        let mut shares = slots.chunks(slots.len().div_ceil(threads));
        let own = shares.next().unwrap_or_default();
        let mut returned = Vec::new();
        for (helper, clients) in helpers.iter().zip(shares) {
            let share = Share {
                index,
                delivery_start,
                clients: clients
                    .iter()
                    .map(|slot| (Arc::clone(slot), memo(slot.cap, slot.encoding)))
                    .collect(),
            };
            if let Err(share) = helper.give(share) {
                returned.push(share);
            }
        }
        for slot in own {
            slot.offer(index, delivery_start, &mut memo);
        }
        for share in returned {
            share.run();
        }
    }

    fn helpers(&self) -> MutexGuard<'_, Vec<Arc<PassHelper>>> {
        self.helpers
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    /// Starts `count` helper threads ([`PASS_THREAD_NAME`]) that share each pass from now on,
    /// counting the shares they write and those given back in `shares` and `returned`;
    /// [`Fanout::stop_helpers`] ends them (join the handles after it).
    pub fn start_helpers(
        &self,
        count: usize,
        shares: &Counter,
        returned: &Counter,
    ) -> io::Result<Vec<std::thread::JoinHandle<()>>> {
        let mut threads = Vec::with_capacity(count);
        for _ in 0..count {
            let helper = Arc::new(PassHelper {
                shares: shares.clone(),
                returned: returned.clone(),
                ..PassHelper::default()
            });
            let serving = Arc::clone(&helper);
            match std::thread::Builder::new()
                .name(PASS_THREAD_NAME.to_owned())
                .spawn(move || serving.serve())
            {
                Ok(thread) => {
                    self.helpers().push(helper);
                    threads.push(thread);
                }
                Err(e) => {
                    self.stop_helpers();
                    for thread in threads {
                        let _ = thread.join();
                    }
                    return Err(e);
                }
            }
        }
        Ok(threads)
    }

    /// Ends the helper threads (each after the share it is writing); passes from now on are
    /// written by the passing thread alone.
    pub fn stop_helpers(&self) {
        for helper in std::mem::take(&mut *self.helpers()) {
            helper.close();
        }
    }

    /// The channel has ended: every client's task is told.
    pub fn end(&self) {
        let mut registry = self.lock();
        registry.ended = true;
        for slot in &registry.slots {
            slot.handover.notify_one();
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::VecDeque;

    /// A socket whose writes take what the test says (all of it by default).
    #[derive(Default)]
    struct FakeSocket {
        /// Per write: at most this many bytes are taken (`None`: would block).
        takes: Mutex<VecDeque<Option<usize>>>,
        written: Mutex<Vec<u8>>,
    }

    impl FakeSocket {
        fn then_take(&self, take: Option<usize>) {
            self.takes.lock().unwrap().push_back(take);
        }
        fn written(&self) -> Vec<u8> {
            self.written.lock().unwrap().clone()
        }
    }

    impl Socket for FakeSocket {
        fn try_write(&self, buf: &[u8]) -> io::Result<usize> {
            let take = self
                .takes
                .lock()
                .unwrap()
                .pop_front()
                .unwrap_or(Some(usize::MAX));
            let Some(take) = take else {
                return Err(io::ErrorKind::WouldBlock.into());
            };
            let n = take.min(buf.len());
            self.written.lock().unwrap().extend_from_slice(&buf[..n]);
            Ok(n)
        }
        fn poll_read(&self, _: &mut Context<'_>, _: &mut ReadBuf<'_>) -> Poll<io::Result<()>> {
            Poll::Pending
        }
        fn poll_write(&self, _: &mut Context<'_>, _: &[u8]) -> Poll<io::Result<usize>> {
            Poll::Pending
        }
        fn write_done(&self) {}
        fn shutdown_write(&self) -> io::Result<()> {
            Ok(())
        }
    }

    /// Publication `.0`, encoded as four bytes of its index.
    struct TestFrame(u64);

    impl Frame for TestFrame {
        fn index(&self) -> u64 {
            self.0
        }
        fn delivery_start(&self) -> Option<Instant> {
            None
        }
        fn encode(&self, _: Option<usize>, _: Encoding) -> Vec<u8> {
            bytes_of(self.0)
        }
    }

    fn frame(index: u64) -> Option<Arc<dyn Frame>> {
        Some(Arc::new(TestFrame(index)))
    }

    fn bytes_of(index: u64) -> Vec<u8> {
        vec![index as u8; 4]
    }

    fn encode(frame: &TestFrame) -> impl Fn(Option<usize>, Encoding) -> Arc<Vec<u8>> + '_ {
        move |_, _| Arc::new(bytes_of(frame.0))
    }

    struct Client {
        socket: Arc<FakeSocket>,
        slot: Arc<Slot>,
        sent: Counter,
        skipped: Gauge,
        _registration: Registration,
    }

    /// A registered client, handed to the fan-out (as its task does when there is nothing to
    /// send yet).
    fn client(fanout: &Arc<Fanout>) -> Client {
        let socket = Arc::new(FakeSocket::default());
        let (sent, skipped) = (Counter::default(), Gauge::default());
        let metrics = SlotMetrics {
            sent: sent.clone(),
            skipped: Counter::default(),
            client_skipped: skipped.clone(),
            delivery: Histogram::new([1.0]),
        };
        let shared: Arc<dyn Socket> = socket.clone();
        let slot = Arc::new(Slot::new(shared, None, Encoding::Binary, metrics));
        let registration = fanout.register(&slot).expect("registered");
        assert!(slot.next_for_task(|| None).is_none());
        assert_eq!(slot.writer(), Writer::Fanout);
        Client {
            socket,
            slot,
            sent,
            skipped,
            _registration: registration,
        }
    }

    fn pass(fanout: &Fanout, index: u64) {
        let frame = TestFrame(index);
        fanout.pass(&frame, &encode(&frame));
    }

    /// A helper with no thread behind it: a share given to it stays in its mailbox.
    fn idle_helper(fanout: &Fanout) -> Arc<PassHelper> {
        let helper = Arc::new(PassHelper::default());
        fanout.helpers().push(Arc::clone(&helper));
        helper
    }

    #[test]
    fn few_clients_are_not_shared_out() {
        let fanout = Arc::new(Fanout::default());
        let helper = idle_helper(&fanout);
        let clients: Vec<_> = (0..2 * MIN_CLIENTS_PER_PASS_THREAD - 1)
            .map(|_| client(&fanout))
            .collect();
        pass(&fanout, 1);
        assert!(helper.mailbox().share.is_none(), "a share was given");
        for c in &clients {
            assert_eq!(c.socket.written(), bytes_of(1));
        }
    }

    #[test]
    fn a_busy_helpers_share_is_written_by_the_passing_thread() {
        let fanout = Arc::new(Fanout::default());
        let helper = idle_helper(&fanout);
        let clients: Vec<_> = (0..2 * MIN_CLIENTS_PER_PASS_THREAD)
            .map(|_| client(&fanout))
            .collect();
        // Frame 1: the second half goes to the helper, which does not run.
        pass(&fanout, 1);
        let share = helper
            .mailbox()
            .share
            .take()
            .expect("a share for the helper");
        assert_eq!(share.clients.len(), MIN_CLIENTS_PER_PASS_THREAD);
        let (own, shared) = clients.split_at(MIN_CLIENTS_PER_PASS_THREAD);
        assert!(own.iter().all(|c| c.socket.written() == bytes_of(1)));
        assert!(shared.iter().all(|c| c.socket.written().is_empty()));
        // The helper is still busy (its mailbox full): frame 2 goes to every client from here.
        helper.mailbox().share = Some(share);
        pass(&fanout, 2);
        assert_eq!(helper.returned.get(), 1);
        for c in own {
            assert_eq!(c.socket.written(), [bytes_of(1), bytes_of(2)].concat());
        }
        for c in shared {
            assert_eq!(c.socket.written(), bytes_of(2));
        }
        // The late share of frame 1 finds frame 2 sent and writes nothing.
        helper.mailbox().share.take().expect("the old share").run();
        for c in shared {
            assert_eq!(c.socket.written(), bytes_of(2));
        }
    }

    #[test]
    fn a_pass_shared_with_helper_threads_reaches_every_client_in_order() {
        let fanout = Arc::new(Fanout::default());
        let (shares, returned) = (Counter::default(), Counter::default());
        let threads = fanout
            .start_helpers(3, &shares, &returned)
            .expect("helper threads");
        let clients: Vec<_> = (0..50).map(|_| client(&fanout)).collect();
        let frames = 30;
        for index in 1..=frames {
            pass(&fanout, index);
            std::thread::sleep(std::time::Duration::from_millis(1));
        }
        fanout.stop_helpers();
        for thread in threads {
            thread.join().expect("helper thread");
        }
        for c in &clients {
            // Each frame at most once, in order, the last one always (a frame is skipped only
            // if a helper fell a whole pass behind; then it is counted). Frames before a
            // client's first are not skips: a client starts with the newest frame, so on a
            // loaded machine, where a helper may not have run before frame 2 is passed, a
            // client of its share can start with frame 2 (CI run of 2026-12-02 23:09).
            let written = c.socket.written();
            let indices: Vec<u8> = written.chunks(4).map(|b| b[0]).collect();
            assert!(indices.windows(2).all(|w| w[0] < w[1]), "{indices:?}");
            assert_eq!(indices.last(), Some(&(frames as u8)));
            assert_eq!(c.sent.get() as usize, indices.len());
            let before_first = i64::from(indices[0]) - 1;
            assert_eq!(
                indices.len() as i64 + c.skipped.get(),
                frames as i64 - before_first,
                "{indices:?}"
            );
        }
        // 3 shares a pass, each written by its helper or, if it was busy, by the passing thread.
        assert_eq!(shares.get() + returned.get(), 3 * frames);
        // Stopped helpers take no more shares: the passing thread writes to everyone.
        pass(&fanout, frames + 1);
        for c in &clients {
            assert!(c.socket.written().ends_with(&bytes_of(frames + 1)));
        }
    }

    #[test]
    fn clients_that_keep_up_get_every_frame_from_the_pass() {
        let fanout = Arc::new(Fanout::default());
        let clients: Vec<_> = (0..3).map(|_| client(&fanout)).collect();
        for index in 1..=3 {
            pass(&fanout, index);
        }
        let expected: Vec<u8> = (1..=3).flat_map(bytes_of).collect();
        for c in &clients {
            assert_eq!(c.socket.written(), expected);
            assert_eq!(c.sent.get(), 3);
            assert_eq!(c.slot.writer(), Writer::Fanout);
        }
        // A publication the client has already had is not sent again.
        pass(&fanout, 3);
        assert_eq!(clients[0].socket.written(), expected);
    }

    #[test]
    fn a_full_socket_goes_to_the_task_with_the_rest_of_the_frame_and_never_stalls_the_others() {
        let fanout = Arc::new(Fanout::default());
        let slow = client(&fanout);
        let fast = client(&fanout);
        slow.socket.then_take(Some(1));
        pass(&fanout, 1);
        assert_eq!(slow.slot.writer(), Writer::Task);
        assert!(slow.slot.handed_over().now_or_never_ready());
        let unfinished = slow.slot.take_unfinished().expect("a frame half written");
        assert_eq!(unfinished.written, 1);
        assert_eq!(&unfinished.bytes[1..], &bytes_of(1)[1..]);
        assert_eq!(slow.sent.get(), 0);
        // While the task writes, the pass leaves the slow client alone and serves the other.
        pass(&fanout, 2);
        pass(&fanout, 3);
        assert_eq!(slow.socket.written(), bytes_of(1)[..1].to_vec());
        let all: Vec<u8> = (1..=3).flat_map(bytes_of).collect();
        assert_eq!(fast.socket.written(), all);
        // The task then takes the newest (3), skipping 2, and hands the slot back once it has
        // sent it.
        let newest = slow.slot.next_for_task(|| frame(3));
        assert_eq!(newest.map(|f| f.index()), Some(3));
        assert_eq!(slow.skipped.get(), 1);
        assert!(slow.slot.next_for_task(|| frame(3)).is_none());
        assert_eq!(slow.slot.writer(), Writer::Fanout);
        pass(&fanout, 4);
        assert_eq!(&slow.socket.written()[1..], bytes_of(4).as_slice());
    }

    #[test]
    fn a_socket_that_takes_nothing_leaves_the_same_frame_to_the_task() {
        let fanout = Arc::new(Fanout::default());
        let c = client(&fanout);
        c.socket.then_take(None);
        pass(&fanout, 1);
        assert_eq!(c.slot.writer(), Writer::Task);
        assert!(c.slot.take_unfinished().is_none());
        // Frame 1 was not sent: it is still new to this client, and nothing was skipped.
        let next = c.slot.next_for_task(|| frame(1));
        assert_eq!(next.map(|f| f.index()), Some(1));
        assert_eq!(c.skipped.get(), 0);
    }

    #[test]
    fn a_publication_during_the_hand_back_is_not_lost() {
        let fanout = Arc::new(Fanout::default());
        let c = client(&fanout);
        c.socket.then_take(None);
        pass(&fanout, 1);
        // The task sends 1; publication 2 appears while it writes (the pass skips the slot).
        assert!(c.slot.next_for_task(|| frame(1)).is_some());
        pass(&fanout, 2);
        assert!(c.socket.written().is_empty());
        // Reading the channel under the slot's lock, the task finds 2 and keeps the slot.
        let next = c.slot.next_for_task(|| frame(2));
        assert_eq!(next.map(|f| f.index()), Some(2));
        assert_eq!(c.slot.writer(), Writer::Task);
    }

    #[test]
    fn closed_and_removed_clients_are_left_alone() {
        let fanout = Arc::new(Fanout::default());
        let closed = client(&fanout);
        closed.socket.then_take(Some(2));
        pass(&fanout, 1);
        assert!(closed.slot.close(), "a frame was left half written");
        pass(&fanout, 2);
        assert_eq!(closed.socket.written(), bytes_of(1)[..2].to_vec());
        assert_eq!(closed.slot.writer(), Writer::Closed);
        let gone = client(&fanout);
        let socket = Arc::clone(&gone.socket);
        drop(gone);
        pass(&fanout, 3);
        assert!(socket.written().is_empty());
    }

    #[test]
    fn the_end_of_the_stream_reaches_every_task_and_later_clients() {
        let fanout = Arc::new(Fanout::default());
        let c = client(&fanout);
        assert!(!c.slot.handed_over().now_or_never_ready());
        fanout.end();
        assert!(fanout.ended());
        assert!(c.slot.handed_over().now_or_never_ready());
        let socket: Arc<dyn Socket> = Arc::new(FakeSocket::default());
        let metrics = SlotMetrics {
            sent: Counter::default(),
            skipped: Counter::default(),
            client_skipped: Gauge::default(),
            delivery: Histogram::new([1.0]),
        };
        let late = Arc::new(Slot::new(socket, None, Encoding::Binary, metrics));
        assert!(fanout.register(&late).is_none());
    }

    trait NowOrNever {
        /// Whether the future is ready at its first poll.
        fn now_or_never_ready(self) -> bool;
    }

    impl<F: std::future::Future> NowOrNever for F {
        fn now_or_never_ready(self) -> bool {
            futures_util::FutureExt::now_or_never(self).is_some()
        }
    }
}
