//! The stream server: light lists to any number of clients over a Unix domain socket, TCP and
//! WebSocket, in the wire format of [`super::protocol`] (docs/protocol.md).
//!
//! Shaped like mini-redis: [`StreamServer::start`] binds the endpoints and spawns one accept
//! loop per endpoint and one task per connection on the caller's tokio runtime;
//! [`StreamServer::shutdown`] lets the fan-out threads pass what is still unsent, then
//! broadcasts the goodbye, waits (bounded) for the connections to send it, and removes the
//! socket file.
//!
//! A connection:
//! 1. **Handshake.** The client sends one subscribe message within
//!    [`ServerConfig::handshake_timeout`] (binary; on UDS/TCP also one JSON line starting with
//!    `{`; on WebSocket a binary or text message). Anything else, a half-open connection that
//!    never speaks, or a client that vanishes mid-message ends the connection (with an error
//!    message where the client can still read it).
//! 2. **Frames.** A client follows the latest-value channel of the representation it
//!    subscribed to: the pipeline's light lists, or another stage's channel ([`Streams`]: the
//!    ASG stage's sets; a representation the daemon does not produce gets error 6). Each
//!    payload type says how it is encoded ([`Streamed`]), so the connection code is the same for
//!    every representation. Each publication is encoded once per cap and form (binary or JSON),
//!    shared by the clients that ask for the same.
//!    - **Unix socket and TCP:** one pass of non-blocking writes sends each publication to
//!      every client that keeps up (`src/stream/fanout.rs`); no task is woken per client. The
//!      light lists' pass runs on the decompose thread right after publishing when the server
//!      is given a [`PublisherPass`] (the daemon's default, `stream.fanout_on`); otherwise,
//!      and for the other channels and stale re-sends, one `envlight-fanout` thread per
//!      channel, woken once per publication, runs it (the light lists' thread, while the
//!      publisher passes, looks for stale re-sends every 20 ms instead of being woken). A
//!      client whose socket is full goes to its connection task, which finishes the frame,
//!      then sends the newest publication (the ones in between are counted as skipped) and
//!      hands the client back. The task otherwise only reads (input is an error, below) and
//!      waits for the shutdown.
//!    - **WebSocket:** the connection task waits on the channel and writes each new
//!      publication itself.
//!
//!    A client that reads slowly holds up nobody: newer publications replace older ones in the
//!    channel, so when its write completes it gets the newest one. Per client the server holds
//!    at most one encoded frame, so memory stays bounded whatever the client does; a write that
//!    makes no progress for [`ServerConfig::write_timeout`] closes the connection.
//! 3. **Client input after the subscribe** is not expected: any message is answered with an
//!    error and the connection is closed; other clients are not affected. End of input (a
//!    half-closed socket) is fine: the client keeps receiving.
//! 4. **Shutdown** sends a goodbye (code 0) and closes.

use super::fanout::{
    Fanout, FdSocket, Shared, Slot, SlotMetrics, Socket, Stream, Writer, FANOUT_THREAD_NAME,
    PASS_THREAD_NAME,
};
use super::protocol::{
    self, asg_frame_to_json, code as error_code, decode_message, encode_asg_frame, encode_error,
    encode_frame, encode_goodbye, encode_sh_frame, encode_wavelet_frame, frame_to_json,
    goodbye_to_json, sh_frame_to_json, wavelet_frame_to_json, Decoder, Format, Message,
    ProtocolError, Representation, Request, ShFrame, WaveletFrame,
};
use crate::light::{AsgSet, LightFrame};
use crate::metrics::{ClientLabel, EndpointLabel, Metrics};
use crate::pipeline::LatestLights;
use crate::publication::{Latest, Publication};
use futures_util::future::BoxFuture;
use futures_util::{SinkExt, StreamExt};
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, AtomicUsize, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};
use tokio::io::{AsyncRead, AsyncReadExt, AsyncWrite, AsyncWriteExt};
use tokio::net::{TcpListener, UnixListener};
use tokio::sync::{mpsc, watch};
use tokio_tungstenite::tungstenite;

/// The goodbye text sent when the daemon shuts down.
pub const SHUTDOWN_MESSAGE: &str = "envlight shutting down";

/// Longest JSON subscribe line accepted on UDS/TCP.
const MAX_JSON_LINE: usize = protocol::MAX_TEXT_LEN;

/// Settings of the stream server (`[stream]` in the config file).
#[derive(Clone, Debug, PartialEq)]
pub struct ServerConfig {
    /// Unix domain socket path; `None` disables the endpoint.
    pub unix_socket: Option<PathBuf>,
    /// Permission bits of the socket file.
    pub unix_socket_mode: u32,
    /// TCP listen address; `None` disables the endpoint.
    pub tcp: Option<SocketAddr>,
    /// WebSocket listen address; `None` disables the endpoint.
    pub websocket: Option<SocketAddr>,
    /// Connections beyond this many are refused with an error message.
    pub max_clients: usize,
    /// Time a new connection has to send its subscribe message.
    pub handshake_timeout: Duration,
    /// A write that makes no progress for this long closes the connection.
    pub write_timeout: Duration,
    /// Kernel send buffer per connection in bytes (`None` = the system's default). A small
    /// buffer keeps a slow client from being fed seconds of old frames from the kernel's queue:
    /// once it is full, the client skips to the newest frame instead.
    pub send_buffer_bytes: Option<usize>,
    /// Which thread writes each light list to the Unix-socket and TCP clients that keep up.
    /// The daemon wires [`FanoutOn::Publisher`] with a [`PublisherPass`]; the server itself
    /// follows what its [`Streams`] were given.
    pub fanout_on: FanoutOn,
    /// Threads that write each pass to the clients that keep up: the passing thread and
    /// `pass_threads − 1` helpers (`envlight-pass`), each taking a share of at least 8 clients.
    /// Capped at the CPUs the process may use; 1 = the passing thread alone.
    pub pass_threads: usize,
}

/// Default [`ServerConfig::pass_threads`].
pub const DEFAULT_PASS_THREADS: usize = 2;

/// Which thread runs the light lists' fan-out pass (`stream.fanout_on`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum FanoutOn {
    /// The decompose thread, right after publishing ([`PublisherPass`]): no wake-up between a
    /// light list and its clients, and every light list is passed (a starved fan-out thread
    /// would pass only the newest of those published meanwhile).
    #[default]
    Publisher,
    /// The `envlight-fanout` thread, woken by each publication.
    Thread,
}

/// Default Unix socket path.
pub const DEFAULT_UNIX_SOCKET: &str = "/run/envlight/envlight.sock";
/// Default TCP address.
pub const DEFAULT_TCP: &str = "127.0.0.1:7878";
/// Default WebSocket address.
pub const DEFAULT_WEBSOCKET: &str = "127.0.0.1:7879";

/// Default kernel send buffer per connection: 64 KiB (Linux doubles it for bookkeeping).
pub const DEFAULT_SEND_BUFFER_BYTES: usize = 64 * 1024;

impl Default for ServerConfig {
    fn default() -> Self {
        Self {
            unix_socket: Some(PathBuf::from(DEFAULT_UNIX_SOCKET)),
            unix_socket_mode: 0o666,
            tcp: DEFAULT_TCP.parse().ok(),
            websocket: DEFAULT_WEBSOCKET.parse().ok(),
            max_clients: 256,
            handshake_timeout: Duration::from_secs(5),
            write_timeout: Duration::from_secs(10),
            send_buffer_bytes: Some(DEFAULT_SEND_BUFFER_BYTES),
            fanout_on: FanoutOn::default(),
            pass_threads: DEFAULT_PASS_THREADS,
        }
    }
}

/// Errors of starting the server.
#[derive(Debug, thiserror::Error)]
pub enum ServerError {
    #[error(
        "cannot listen on {endpoint} {address}: {source}{}",
        bind_hint(endpoint, source)
    )]
    Bind {
        endpoint: &'static str,
        address: String,
        #[source]
        source: std::io::Error,
    },
    #[error("unix socket {}: another process is serving on it (remove it or choose another path)", path.display())]
    SocketInUse { path: PathBuf },
    #[error("unix socket {}: a file that is not a socket is in the way", path.display())]
    NotASocket { path: PathBuf },
    #[error("cannot start the {FANOUT_THREAD_NAME} thread: {0}")]
    Spawn(#[source] std::io::Error),
    #[error("cannot start the {PASS_THREAD_NAME} threads: {0}")]
    SpawnPass(#[source] std::io::Error),
}

/// What to do about the two bind errors a new user meets: a Unix socket directory only root
/// may write (the default /run/envlight) and an address another process listens on.
/// `endpoint`: "uds", "tcp", "websocket" or "metrics".
pub(crate) fn bind_hint(endpoint: &str, source: &std::io::Error) -> String {
    use std::io::ErrorKind;
    let (section, key) = match endpoint {
        "uds" => ("stream", "unix_socket"),
        "metrics" => ("metrics", "listen"),
        other => ("stream", other),
    };
    match (endpoint, source.kind()) {
        ("uds", ErrorKind::PermissionDenied) => "; as an ordinary user, set `unix_socket` in \
             the [stream] section of a --config file to a path you own, or to \"\" to turn the \
             Unix socket off (README, \"The daemon\")"
            .to_string(),
        (_, ErrorKind::AddrInUse) => format!(
            "; another process (another envlight?) listens there: stop it, or set `{key}` in \
             the [{section}] section of a --config file to another address (\"\" turns it off)"
        ),
        _ => String::new(),
    }
}

/// The pass helper threads of every channel ([`ServerConfig::pass_threads`]); told to stop
/// when dropped (joined only by [`StreamServer::shutdown`]).
#[derive(Default)]
struct PassHelpers {
    fanouts: Vec<Arc<Fanout>>,
    threads: Vec<std::thread::JoinHandle<()>>,
}

impl PassHelpers {
    fn stop(&self) {
        for fanout in &self.fanouts {
            fanout.stop_helpers();
        }
    }
}

impl Drop for PassHelpers {
    fn drop(&mut self) {
        self.stop();
    }
}

/// How often the fan-out thread of a channel whose publisher runs the pass looks for stale
/// re-publications and the end of the channel (instead of being woken by every publication).
const PUBLISHER_PASS_POLL: Duration = Duration::from_millis(20);

/// Starts the fan-out thread of `feed`'s channel: woken once per publication, it writes the
/// publication to every client of [`Context::fanout`] that keeps up (`src/stream/fanout.rs`);
/// while the publishing thread passes the live publications itself, it looks every
/// [`PUBLISHER_PASS_POLL`] for the others instead.
/// It ends when `stop` is set, after passing a publication it has not passed yet (so the last
/// one goes out before the clients' goodbye), or once the channel has ended (then it tells the
/// clients).
fn spawn_fanout(
    ctx: &Arc<Context>,
    mut feed: Feed,
    mut stop: watch::Receiver<bool>,
) -> Result<std::thread::JoinHandle<()>, ServerError> {
    let ctx = Arc::clone(ctx);
    std::thread::Builder::new()
        .name(FANOUT_THREAD_NAME.to_owned())
        .spawn(move || {
            let fanout = Arc::clone(ctx.fanout(&feed));
            // Passes the newest publication, unless the publishing thread passes it itself
            // (a live one while it runs the pass).
            let pass_newest = |feed: &mut Feed| {
                if let Some(published) = feed.rx.newest() {
                    if !(published.live() && fanout.publisher_passes()) {
                        fanout.pass(&*published, &|cap, encoding| {
                            ctx.encoded(feed, &*published, cap, encoding)
                        });
                    }
                }
            };
            loop {
                if fanout.publisher_passes() {
                    // The publishing thread passes every live publication. Waiting on the
                    // channel would wake this thread with each of them, just as the pass
                    // starts (a scheduler trace showed two futex wakes by the publisher per
                    // publication, each letting this thread preempt it on its CPU, before the
                    // first write: docs/performance.md "Round 4"); it only has to catch stale
                    // re-publications and the end, so it looks every `PUBLISHER_PASS_POLL`.
                    std::thread::sleep(PUBLISHER_PASS_POLL);
                    let stopping = *stop.borrow();
                    match feed.rx.has_changed() {
                        None => {
                            fanout.end();
                            return;
                        }
                        Some(false) => {}
                        Some(true) => pass_newest(&mut feed),
                    }
                    if stopping {
                        return;
                    }
                    continue;
                }
                // No runtime here: the channels' futures need none, so a plain blocking
                // executor waits on them.
                let changed = pollster::block_on(async {
                    tokio::select! {
                        biased;
                        _ = stop.wait_for(|&stop| stop) => None,
                        changed = feed.rx.changed() => Some(changed),
                    }
                });
                match changed {
                    None => {
                        // Stopping: a publication not passed yet still goes out, before the
                        // clients get their goodbye.
                        if feed.rx.has_changed() == Some(true) {
                            pass_newest(&mut feed);
                        }
                        return;
                    }
                    Some(false) => {
                        fanout.end();
                        return;
                    }
                    Some(true) => pass_newest(&mut feed),
                }
            }
        })
        .map_err(ServerError::Spawn)
}

/// The addresses the endpoints are bound to (with port 0 resolved).
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct BoundAddresses {
    pub unix_socket: Option<PathBuf>,
    pub tcp: Option<SocketAddr>,
    pub websocket: Option<SocketAddr>,
}

/// State shared by all connections.
struct Context {
    config: ServerConfig,
    metrics: Arc<Metrics>,
    clients: AtomicUsize,
    next_client: AtomicU64,
    /// The latest-value channels served, one per representation the daemon produces, each with
    /// its newest publication's encodings.
    sources: Vec<Source>,
}

/// A payload the server can stream: the representation clients subscribe to for it and its
/// encodings. Streaming a new representation is an implementation of this trait (with a frame
/// layout in [`protocol`]) and one more [`Streams::with`].
pub trait Streamed: Send + Sync + 'static {
    /// The representation of this payload.
    const REPRESENTATION: Representation;
    /// Whether delivering it is observed in the delivery-latency histogram (the lights are).
    const OBSERVE_DELIVERY: bool = false;
    /// Appends the binary frame message with at most `cap` records.
    fn encode_binary(&self, cap: Option<usize>, stale: bool, out: &mut Vec<u8>);
    /// The JSON form with at most `cap` records.
    fn to_json(&self, cap: Option<usize>, stale: bool) -> String;
}

impl Streamed for LightFrame {
    const REPRESENTATION: Representation = Representation::Lights;
    const OBSERVE_DELIVERY: bool = true;
    fn encode_binary(&self, cap: Option<usize>, stale: bool, out: &mut Vec<u8>) {
        encode_frame(self, cap, stale, out);
    }
    fn to_json(&self, cap: Option<usize>, stale: bool) -> String {
        frame_to_json(self, cap, stale)
    }
}

impl Streamed for AsgSet {
    const REPRESENTATION: Representation = Representation::Asg;
    fn encode_binary(&self, cap: Option<usize>, stale: bool, out: &mut Vec<u8>) {
        encode_asg_frame(self, cap, stale, out);
    }
    fn to_json(&self, cap: Option<usize>, stale: bool) -> String {
        asg_frame_to_json(self, cap, stale)
    }
}

impl Streamed for WaveletFrame {
    const REPRESENTATION: Representation = Representation::Wavelet;
    fn encode_binary(&self, cap: Option<usize>, stale: bool, out: &mut Vec<u8>) {
        encode_wavelet_frame(self, cap, stale, out);
    }
    fn to_json(&self, cap: Option<usize>, stale: bool) -> String {
        wavelet_frame_to_json(self, cap, stale)
    }
}

impl Streamed for ShFrame {
    const REPRESENTATION: Representation = Representation::Sh;
    fn encode_binary(&self, cap: Option<usize>, stale: bool, out: &mut Vec<u8>) {
        encode_sh_frame(self, cap, stale, out);
    }
    fn to_json(&self, cap: Option<usize>, stale: bool) -> String {
        sh_frame_to_json(self, cap, stale)
    }
}

/// One publication of any representation, as a connection (and the fan-out) sees it.
pub(super) trait Frame: Send + Sync {
    /// The publication's index on its channel.
    fn index(&self) -> u64;
    /// Where the delivery latency of this frame starts, if it is observed.
    fn delivery_start(&self) -> Option<Instant>;
    /// The frame encoded with at most `cap` records.
    fn encode(&self, cap: Option<usize>, encoding: Encoding) -> Vec<u8>;
    /// Newly computed by its stage (not a stale re-publication): the publisher runs the pass
    /// of such a publication itself when a [`PublisherPass`] is wired.
    fn live(&self) -> bool {
        false
    }
}

impl<T: Streamed> Frame for Publication<T> {
    fn index(&self) -> u64 {
        self.index
    }

    fn delivery_start(&self) -> Option<Instant> {
        self.arrived.filter(|_| T::OBSERVE_DELIVERY)
    }

    fn live(&self) -> bool {
        !self.stale && self.arrived.is_some()
    }

    fn encode(&self, cap: Option<usize>, encoding: Encoding) -> Vec<u8> {
        match encoding {
            Encoding::Binary => {
                let mut out = Vec::new();
                self.payload.encode_binary(cap, self.stale, &mut out);
                out
            }
            Encoding::JsonLine | Encoding::JsonText => {
                let mut out = self.payload.to_json(cap, self.stale).into_bytes();
                if encoding == Encoding::JsonLine {
                    out.push(b'\n');
                }
                out
            }
        }
    }
}

/// A latest-value channel of any representation, as a connection follows it.
trait FeedRx: Send + Sync {
    /// Waits for a new publication; `false` once the stream has ended.
    fn changed(&mut self) -> BoxFuture<'_, bool>;
    /// Whether there is a publication not yet seen, without waiting; `None` once the stream
    /// has ended.
    fn has_changed(&self) -> Option<bool>;
    /// The newest publication, marked seen.
    fn newest(&mut self) -> Option<Arc<dyn Frame>>;
    /// Another receiver of the same channel, in the same state.
    fn boxed_clone(&self) -> Box<dyn FeedRx>;
}

impl<T: Streamed> FeedRx for watch::Receiver<Latest<T>> {
    fn changed(&mut self) -> BoxFuture<'_, bool> {
        Box::pin(async move { watch::Receiver::changed(self).await.is_ok() })
    }

    fn has_changed(&self) -> Option<bool> {
        watch::Receiver::has_changed(self).ok()
    }

    fn newest(&mut self) -> Option<Arc<dyn Frame>> {
        let newest = self.borrow_and_update().clone()?;
        Some(newest)
    }

    fn boxed_clone(&self) -> Box<dyn FeedRx> {
        Box::new(self.clone())
    }
}

/// One channel the server serves.
struct Source {
    representation: Representation,
    /// Never marked as seen: each clone handed to a connection starts with the newest
    /// publication unseen.
    rx: Box<dyn FeedRx>,
    /// The newest publication's encodings, shared by the clients that ask for the same form.
    cache: std::sync::Mutex<EncodeCache>,
    /// The Unix-socket and TCP clients of this channel, written by its fan-out thread.
    fanout: Arc<Fanout>,
}

/// What a [`StreamServer`] serves: the light lists, and the other representations the daemon
/// produces, each on its own latest-value channel.
pub struct Streams {
    sources: Vec<Source>,
    publisher_pass: Option<PublisherPass>,
}

/// The light lists' fan-out pass, run on the thread that publishes them (the decomposition)
/// instead of on an `envlight-fanout` thread woken for it: one wake-up fewer between a light
/// list and its clients. Wire it both ways: to the pipeline as (part of) its
/// [`PipelineOptions::on_publish`](crate::pipeline::PipelineOptions::on_publish) hook
/// ([`PublisherPass::hook`]) and to the server with [`Streams::with_publisher_pass`]; the
/// server installs the pass when it starts and removes it at shutdown. The fan-out thread then
/// only passes what the publisher does not: stale re-publications (a lost source).
#[derive(Clone, Default)]
pub struct PublisherPass {
    pass: Arc<std::sync::Mutex<Option<PassFn>>>,
}

/// A fan-out pass for one publication of the light lists.
type PassFn = Arc<dyn Fn(&crate::pipeline::Published) + Send + Sync>;

impl PublisherPass {
    /// Not installed yet: the hook does nothing until a server starts with it.
    pub fn new() -> Self {
        Self::default()
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Option<PassFn>> {
        self.pass
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    /// Runs the pass of `published` (nothing before the server has started or after it has
    /// shut down).
    pub fn run(&self, published: &crate::pipeline::Published) {
        let pass = self.lock().clone();
        if let Some(pass) = pass {
            pass(published);
        }
    }

    /// The pipeline hook that runs [`PublisherPass::run`].
    pub fn hook(&self) -> crate::pipeline::PublishHook {
        let this = self.clone();
        crate::pipeline::PublishHook(Arc::new(move |published| this.run(published)))
    }
}

impl Streams {
    /// The light lists only.
    pub fn new(lights: watch::Receiver<LatestLights>) -> Self {
        Self {
            sources: Vec::new(),
            publisher_pass: None,
        }
        .with(lights)
    }

    /// The pipeline runs the light lists' fan-out pass on its publishing thread through
    /// `pass` (which must also be wired into its `on_publish` hook, see [`PublisherPass`]).
    pub fn with_publisher_pass(mut self, pass: PublisherPass) -> Self {
        self.publisher_pass = Some(pass);
        self
    }

    /// Also serves `rx` to the clients that subscribe to `T`'s representation (replacing an
    /// earlier channel of the same representation).
    pub fn with<T: Streamed>(mut self, rx: watch::Receiver<Latest<T>>) -> Self {
        self.sources
            .retain(|s| s.representation != T::REPRESENTATION);
        self.sources.push(Source {
            representation: T::REPRESENTATION,
            rx: Box::new(rx),
            cache: std::sync::Mutex::default(),
            fanout: Arc::default(),
        });
        self
    }

    /// [`Streams::with`] if `rx` is there.
    pub fn with_optional<T: Streamed>(self, rx: Option<watch::Receiver<Latest<T>>>) -> Self {
        match rx {
            Some(rx) => self.with(rx),
            None => self,
        }
    }

    /// The representations served, in the order they were added.
    pub fn representations(&self) -> Vec<Representation> {
        self.sources.iter().map(|s| s.representation).collect()
    }
}

/// The channel a subscribed connection follows.
struct Feed {
    rx: Box<dyn FeedRx>,
    /// Its position in [`Context::sources`].
    source: usize,
}

/// How a frame is encoded for a client.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Encoding {
    /// A binary frame message.
    Binary,
    /// The JSON form and a newline (UDS/TCP JSON lines).
    JsonLine,
    /// The JSON form (a WebSocket text message).
    JsonText,
}

/// Encodings of one publication, so that 64 clients asking for the same cap and form cost one
/// encoding, not 64.
#[derive(Default)]
struct EncodeCache {
    index: u64,
    entries: Vec<(Option<usize>, Encoding, Arc<Vec<u8>>)>,
}

/// At most this many (cap, form) variants are kept per publication; more are encoded per client.
const ENCODE_CACHE_ENTRIES: usize = 16;

impl Context {
    /// The fan-out of the channel `feed` follows.
    fn fanout(&self, feed: &Feed) -> &Arc<Fanout> {
        &self.sources[feed.source].fanout
    }

    /// The publication `published` of `feed` encoded for a client with `cap` in `encoding`.
    fn encoded(
        &self,
        feed: &Feed,
        published: &dyn Frame,
        cap: Option<usize>,
        encoding: Encoding,
    ) -> Arc<Vec<u8>> {
        self.encoded_at(feed.source, published, cap, encoding)
    }

    /// As [`Context::encoded`], for the channel at `source` in [`Context::sources`].
    fn encoded_at(
        &self,
        source: usize,
        published: &dyn Frame,
        cap: Option<usize>,
        encoding: Encoding,
    ) -> Arc<Vec<u8>> {
        let cache = &self.sources[source].cache;
        let lock = || {
            cache
                .lock()
                .unwrap_or_else(std::sync::PoisonError::into_inner)
        };
        let index = published.index();
        {
            let cache = lock();
            if cache.index == index {
                if let Some((_, _, bytes)) = cache
                    .entries
                    .iter()
                    .find(|(c, e, _)| *c == cap && *e == encoding)
                {
                    return Arc::clone(bytes);
                }
            }
        }
        let bytes = Arc::new(published.encode(cap, encoding));
        let mut cache = lock();
        if index > cache.index {
            cache.index = index;
            cache.entries.clear();
        }
        if cache.index == index && cache.entries.len() < ENCODE_CACHE_ENTRIES {
            cache.entries.push((cap, encoding, Arc::clone(&bytes)));
        }
        bytes
    }
}

/// A running stream server.
pub struct StreamServer {
    bound: BoundAddresses,
    shutdown_tx: watch::Sender<Option<String>>,
    /// Every accept loop and connection holds a clone; all gone = all finished.
    done_tx: mpsc::Sender<()>,
    done_rx: mpsc::Receiver<()>,
    accept_tasks: Vec<tokio::task::JoinHandle<()>>,
    /// The fan-out threads, and their stop signal: set at shutdown before the clients' goodbye.
    fanout_threads: Vec<std::thread::JoinHandle<()>>,
    fanout_stop: watch::Sender<bool>,
    /// The threads that share the passes; stopped after the fan-out threads.
    pass_helpers: PassHelpers,
    /// The light lists' pass on the publishing thread, if wired; removed at shutdown.
    publisher_pass: Option<PublisherPass>,
}

impl StreamServer {
    /// Binds every configured endpoint and starts serving `lights` on the current runtime.
    pub async fn start(
        config: &ServerConfig,
        lights: watch::Receiver<LatestLights>,
        metrics: Arc<Metrics>,
    ) -> Result<StreamServer, ServerError> {
        Self::start_streams(config, Streams::new(lights), metrics).await
    }

    /// As [`StreamServer::start`], serving every channel of `streams` to the clients that
    /// subscribe to its representation; other representations get error 6.
    pub async fn start_streams(
        config: &ServerConfig,
        streams: Streams,
        metrics: Arc<Metrics>,
    ) -> Result<StreamServer, ServerError> {
        let publisher_pass = streams.publisher_pass;
        let ctx = Arc::new(Context {
            config: config.clone(),
            metrics,
            clients: AtomicUsize::new(0),
            next_client: AtomicU64::new(1),
            sources: streams.sources,
        });
        let (shutdown_tx, _) = watch::channel(None::<String>);
        let (fanout_stop, _) = watch::channel(false);
        let (done_tx, done_rx) = mpsc::channel(1);
        let mut bound = BoundAddresses::default();
        let mut accept_tasks = Vec::new();

        // Bind everything first, so a failure leaves nothing running (and no socket file:
        // the guard removes the one bound here unless the server starts).
        let unix = match &config.unix_socket {
            Some(path) => Some((bind_unix(path, config.unix_socket_mode)?, path.clone())),
            None => None,
        };
        let mut socket_file = SocketFileGuard(unix.as_ref().map(|(_, path)| path.clone()));
        let tcp = match config.tcp {
            Some(addr) => Some(bind_tcp("tcp", addr).await?),
            None => None,
        };
        let websocket = match config.websocket {
            Some(addr) => Some(bind_tcp("websocket", addr).await?),
            None => None,
        };
        let mut fanout_threads = Vec::new();
        for (source, served) in ctx.sources.iter().enumerate() {
            let feed = Feed {
                rx: served.rx.boxed_clone(),
                source,
            };
            match spawn_fanout(&ctx, feed, fanout_stop.subscribe()) {
                Ok(thread) => fanout_threads.push(thread),
                Err(e) => {
                    fanout_stop.send_replace(true);
                    for thread in fanout_threads {
                        let _ = thread.join();
                    }
                    return Err(e);
                }
            }
        }

        let helpers_per_channel = config
            .pass_threads
            .min(crate::parallel::cores())
            .saturating_sub(1);
        let mut pass_helpers = PassHelpers::default();
        if helpers_per_channel > 0 {
            for served in &ctx.sources {
                let threads = served.fanout.start_helpers(
                    helpers_per_channel,
                    &ctx.metrics.pass_shares,
                    &ctx.metrics.pass_shares_returned,
                );
                pass_helpers.fanouts.push(Arc::clone(&served.fanout));
                match threads {
                    Ok(threads) => pass_helpers.threads.extend(threads),
                    Err(e) => {
                        fanout_stop.send_replace(true);
                        pass_helpers.stop();
                        for thread in fanout_threads
                            .into_iter()
                            .chain(pass_helpers.threads.drain(..))
                        {
                            let _ = thread.join();
                        }
                        return Err(ServerError::SpawnPass(e));
                    }
                }
            }
        }

        if let Some(pass) = &publisher_pass {
            if let Some(source) = ctx
                .sources
                .iter()
                .position(|s| s.representation == Representation::Lights)
            {
                let pass_ctx = Arc::clone(&ctx);
                *pass.lock() = Some(Arc::new(move |published: &crate::pipeline::Published| {
                    let frame: &dyn Frame = published;
                    pass_ctx.sources[source]
                        .fanout
                        .pass(frame, &|cap, encoding| {
                            pass_ctx.encoded_at(source, frame, cap, encoding)
                        });
                }));
                ctx.sources[source].fanout.set_publisher_passes(true);
            }
        }

        socket_file.keep();
        if let Some((listener, path)) = unix {
            tracing::info!(path = %path.display(), "serving light lists on a unix socket");
            bound.unix_socket = Some(path.clone());
            let accept = Acceptor::new(&ctx, "uds", &shutdown_tx, &done_tx);
            accept_tasks.push(tokio::spawn(accept.unix(listener, path)));
        }
        if let Some(listener) = tcp {
            let addr = listener.local_addr().ok();
            tracing::info!(address = %shown(addr), "serving light lists over tcp");
            bound.tcp = addr;
            let accept = Acceptor::new(&ctx, "tcp", &shutdown_tx, &done_tx);
            accept_tasks.push(tokio::spawn(accept.tcp(listener, false)));
        }
        if let Some(listener) = websocket {
            let addr = listener.local_addr().ok();
            tracing::info!(address = %shown(addr), "serving light lists over websocket");
            bound.websocket = addr;
            let accept = Acceptor::new(&ctx, "websocket", &shutdown_tx, &done_tx);
            accept_tasks.push(tokio::spawn(accept.tcp(listener, true)));
        }
        Ok(StreamServer {
            bound,
            shutdown_tx,
            done_tx,
            done_rx,
            accept_tasks,
            fanout_threads,
            fanout_stop,
            pass_helpers,
            publisher_pass,
        })
    }

    /// Where the endpoints listen.
    pub fn bound(&self) -> &BoundAddresses {
        &self.bound
    }

    /// Sends `message` as a goodbye to every client, stops accepting, waits up to `grace` for
    /// the connections to close, and removes the socket file. Returns whether every connection
    /// closed in time (the rest are abandoned with the runtime).
    pub async fn shutdown(self, message: &str, grace: Duration) -> bool {
        let StreamServer {
            bound,
            shutdown_tx,
            done_tx,
            mut done_rx,
            accept_tasks,
            fanout_threads,
            fanout_stop,
            mut pass_helpers,
            publisher_pass,
        } = self;
        if let Some(pass) = publisher_pass {
            *pass.lock() = None;
        }
        // The fan-out threads pass what is still unsent and end (within a pass, or their
        // poll interval); only then do the clients get their goodbye, so that a publication
        // made before the shutdown reaches every client that keeps up.
        // The helpers end after them, each after the share it is writing.
        fanout_stop.send_replace(true);
        let _ = tokio::task::spawn_blocking(move || {
            for thread in fanout_threads {
                if thread.join().is_err() {
                    tracing::error!("a fan-out thread panicked");
                }
            }
            pass_helpers.stop();
            for thread in pass_helpers.threads.drain(..) {
                if thread.join().is_err() {
                    tracing::error!("a pass thread panicked");
                }
            }
        })
        .await;
        shutdown_tx.send_replace(Some(message.to_owned()));
        drop(done_tx);
        let all_closed = tokio::time::timeout(grace, done_rx.recv()).await.is_ok();
        for task in accept_tasks {
            task.abort();
        }
        if let Some(path) = &bound.unix_socket {
            remove_socket_file(path);
        }
        all_closed
    }
}

/// Removes the socket file it holds when dropped, unless [`keep`](Self::keep) was called: a
/// server that fails to start after binding its Unix socket leaves no file behind.
struct SocketFileGuard(Option<PathBuf>);

impl SocketFileGuard {
    fn keep(&mut self) {
        self.0 = None;
    }
}

impl Drop for SocketFileGuard {
    fn drop(&mut self) {
        if let Some(path) = &self.0 {
            remove_socket_file(path);
        }
    }
}

fn remove_socket_file(path: &Path) {
    match std::fs::remove_file(path) {
        Ok(()) => tracing::debug!(path = %path.display(), "removed the socket file"),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
        Err(e) => {
            tracing::warn!(path = %path.display(), error = %e, "cannot remove the socket file")
        }
    }
}

/// Binds a Unix socket, replacing a stale socket file left by a crashed daemon but never one
/// that another process still serves on.
fn bind_unix(path: &Path, mode: u32) -> Result<UnixListener, ServerError> {
    use std::os::unix::fs::{FileTypeExt, PermissionsExt};
    let bind_error = |source| ServerError::Bind {
        endpoint: "uds",
        address: path.display().to_string(),
        source,
    };
    if let Ok(meta) = std::fs::symlink_metadata(path) {
        if !meta.file_type().is_socket() {
            return Err(ServerError::NotASocket {
                path: path.to_path_buf(),
            });
        }
        if std::os::unix::net::UnixStream::connect(path).is_ok() {
            return Err(ServerError::SocketInUse {
                path: path.to_path_buf(),
            });
        }
        tracing::info!(path = %path.display(), "removing a stale socket file");
        std::fs::remove_file(path).map_err(bind_error)?;
    }
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir).map_err(|error| {
            // "File exists" when a regular file stands where a directory should: name it.
            let blocker = dir
                .ancestors()
                .find(|a| std::fs::metadata(a).is_ok_and(|m| !m.is_dir()));
            bind_error(match blocker {
                Some(file) => std::io::Error::new(
                    std::io::ErrorKind::NotADirectory,
                    format!("{} is not a directory", file.display()),
                ),
                None => error,
            })
        })?;
    }
    // Bound under a temporary name beside `path`, given its mode, and linked to `path` only
    // then: a client that finds the file can connect, and never while the file still has the
    // umask's mode. (bind() makes the file before listen() makes it accept; a test that
    // connected in between, on a loaded machine, was refused.) link() fails where `path`
    // exists, so a daemon that bound it meanwhile is not replaced. Where the temporary name
    // does not fit a socket address, or the file system cannot link, `path` is bound directly.
    let temporary = path.with_file_name(format!(".envlight-{}.sock", std::process::id()));
    if temporary.as_os_str().len() < SOCKET_PATH_MAX {
        let _ = std::fs::remove_file(&temporary);
        if let Ok(listener) = UnixListener::bind(&temporary) {
            let mode_set =
                std::fs::set_permissions(&temporary, std::fs::Permissions::from_mode(mode));
            let linked = mode_set.and_then(|()| std::fs::hard_link(&temporary, path));
            let _ = std::fs::remove_file(&temporary);
            match linked {
                Ok(()) => return Ok(listener),
                Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => {
                    return Err(ServerError::SocketInUse {
                        path: path.to_path_buf(),
                    });
                }
                Err(e) => {
                    tracing::debug!(error = %e, "cannot link the socket into place; binding it directly")
                }
            }
        }
    }
    let listener = UnixListener::bind(path).map_err(bind_error)?;
    std::fs::set_permissions(path, std::fs::Permissions::from_mode(mode)).map_err(bind_error)?;
    Ok(listener)
}

/// The longest path a Unix socket address holds (`sun_path` is 108 bytes on Linux, with its
/// terminating NUL).
const SOCKET_PATH_MAX: usize = 108;

async fn bind_tcp(endpoint: &'static str, addr: SocketAddr) -> Result<TcpListener, ServerError> {
    TcpListener::bind(addr)
        .await
        .map_err(|source| ServerError::Bind {
            endpoint,
            address: addr.to_string(),
            source,
        })
}

/// What an accept loop needs to start connections.
struct Acceptor {
    ctx: Arc<Context>,
    endpoint: &'static str,
    shutdown: watch::Receiver<Option<String>>,
    done: mpsc::Sender<()>,
}

impl Acceptor {
    fn new(
        ctx: &Arc<Context>,
        endpoint: &'static str,
        shutdown: &watch::Sender<Option<String>>,
        done: &mpsc::Sender<()>,
    ) -> Self {
        Self {
            ctx: Arc::clone(ctx),
            endpoint,
            shutdown: shutdown.subscribe(),
            done: done.clone(),
        }
    }

    async fn unix(self, listener: UnixListener, path: PathBuf) {
        let mut shutdown = self.shutdown.clone();
        loop {
            let accepted = tokio::select! {
                _ = shutdown.wait_for(Option::is_some) => break,
                accepted = listener.accept() => accepted,
            };
            match accepted {
                Ok((stream, _)) => {
                    self.limit_send_buffer(socket2::SockRef::from(&stream));
                    let peer = path.display().to_string();
                    let socket = stream.into_std().map(Stream::Unix);
                    self.serve(peer, socket);
                }
                Err(e) => accept_failed(self.endpoint, &e).await,
            }
        }
    }

    async fn tcp(self, listener: TcpListener, websocket: bool) {
        let mut shutdown = self.shutdown.clone();
        loop {
            let accepted = tokio::select! {
                _ = shutdown.wait_for(Option::is_some) => break,
                accepted = listener.accept() => accepted,
            };
            match accepted {
                Ok((stream, peer)) => {
                    let _ = stream.set_nodelay(true);
                    self.limit_send_buffer(socket2::SockRef::from(&stream));
                    if websocket {
                        let conn = self.connection(peer.to_string());
                        tokio::spawn(conn.serve_websocket(stream));
                    } else {
                        let socket = stream.into_std().map(Stream::Tcp);
                        self.serve(peer.to_string(), socket);
                    }
                }
                Err(e) => accept_failed(self.endpoint, &e).await,
            }
        }
    }

    /// Starts a Unix-socket or TCP connection's task.
    fn serve(&self, peer: String, stream: std::io::Result<Stream>) {
        match stream.and_then(FdSocket::new) {
            Ok(socket) => {
                tokio::spawn(self.connection(peer).serve_stream(Arc::new(socket)));
            }
            Err(error) => {
                tracing::warn!(endpoint = self.endpoint, %error, "cannot serve a connection");
            }
        }
    }

    fn limit_send_buffer(&self, socket: socket2::SockRef<'_>) {
        if let Some(bytes) = self.ctx.config.send_buffer_bytes {
            if let Err(error) = socket.set_send_buffer_size(bytes) {
                tracing::debug!(%error, "cannot set the send buffer size");
            }
        }
    }

    /// A new connection's state, counted as a client (the count drops with it).
    fn connection(&self, peer: String) -> Connection {
        let id = self.ctx.next_client.fetch_add(1, Ordering::Relaxed);
        let name = format!("{} {} #{}", self.endpoint, peer, id);
        let previous = self.ctx.clients.fetch_add(1, Ordering::AcqRel);
        let guard = ClientGuard {
            ctx: Arc::clone(&self.ctx),
            endpoint: self.endpoint,
            label: ClientLabel {
                client: name.clone(),
            },
            since: Instant::now(),
            subscribed: AtomicBool::new(false),
        };
        let label = EndpointLabel {
            endpoint: self.endpoint,
        };
        self.ctx
            .metrics
            .clients_connected
            .get_or_create(&label)
            .inc();
        let max = self.ctx.config.max_clients;
        let over_limit = previous >= max;
        let handshake_timeout = if over_limit {
            self.ctx.config.handshake_timeout.min(OVER_LIMIT_HANDSHAKE)
        } else {
            self.ctx.config.handshake_timeout
        };
        tracing::debug!(client = %name, "client connected");
        Connection {
            ctx: Arc::clone(&self.ctx),
            endpoint: self.endpoint,
            name,
            shutdown: self.shutdown.clone(),
            over_limit,
            refuse_unread: previous >= refused_unread(max),
            handshake_timeout,
            guard,
            written: Arc::new(WriteProgress::new()),
            _done: self.done.clone(),
        }
    }
}

/// A bound address as logs show it (`127.0.0.1:7878`; `unknown` if the socket could not say).
pub(crate) fn shown(address: Option<std::net::SocketAddr>) -> String {
    address.map_or_else(|| "unknown".to_owned(), |a| a.to_string())
}

/// How long a client past `max_clients` has to send its subscribe (to be refused in its form).
const OVER_LIMIT_HANDSHAKE: Duration = Duration::from_secs(1);

/// From how many connections on a new one is refused without reading its subscribe: twice
/// `max_clients` and 16 more (clients past the limit are waited for at most
/// [`OVER_LIMIT_HANDSHAKE`] each, so only a flood gets this far).
fn refused_unread(max_clients: usize) -> usize {
    max_clients.saturating_mul(2).saturating_add(16)
}

/// An accept error (out of file descriptors, typically): logged, and a short pause so a
/// persistent error does not spin.
async fn accept_failed(endpoint: &str, error: &std::io::Error) {
    tracing::warn!(endpoint, %error, "accepting a connection failed");
    tokio::time::sleep(Duration::from_millis(100)).await;
}

/// Waits for the shutdown broadcast and returns the goodbye text.
async fn shutdown_message(shutdown: &mut watch::Receiver<Option<String>>) -> String {
    match shutdown.wait_for(Option::is_some).await {
        Ok(message) => message.clone().unwrap_or_default(),
        // The server is gone without a broadcast: say the usual.
        Err(_) => SHUTDOWN_MESSAGE.to_owned(),
    }
}

/// What woke a subscribed connection's task.
enum Event<T> {
    /// A new publication of the subscribed representation (false: the stream ended).
    Lights(bool),
    /// The daemon is shutting down, with this goodbye.
    Shutdown(String),
    /// Input from the client.
    Input(T),
}

/// What woke a Unix-socket or TCP connection's task while the fan-out writes its frames.
enum StreamEvent<T> {
    /// The daemon is shutting down, with this goodbye.
    Shutdown(String),
    /// Input from the client.
    Input(T),
}

/// What woke a connection's task during the handshake.
enum HandshakeEvent<T> {
    Input(T),
    Shutdown(String),
    /// The handshake deadline passed.
    Timeout,
}

/// Counts a client while it is connected, and says when a subscribed one leaves.
struct ClientGuard {
    ctx: Arc<Context>,
    endpoint: &'static str,
    label: ClientLabel,
    /// When the connection was accepted.
    since: Instant,
    /// Whether the client subscribed: its leaving is then logged at info, with how long it
    /// stayed and how many frames it skipped (a connection that never subscribed was logged
    /// when it was closed, if at all).
    subscribed: AtomicBool,
}

impl Drop for ClientGuard {
    fn drop(&mut self) {
        self.ctx.clients.fetch_sub(1, Ordering::AcqRel);
        let label = EndpointLabel {
            endpoint: self.endpoint,
        };
        self.ctx
            .metrics
            .clients_connected
            .get_or_create(&label)
            .dec();
        if self.subscribed.load(Ordering::Relaxed) {
            let skipped = self
                .ctx
                .metrics
                .client_skipped
                .get(&self.label)
                .map_or(0, |g| g.get());
            tracing::info!(
                client = %self.label.client,
                connected_s = format_args!("{:.1}", self.since.elapsed().as_secs_f64()),
                skipped_frames = skipped,
                "client left"
            );
        } else {
            tracing::debug!(client = %self.label.client, "client disconnected");
        }
        self.ctx.metrics.client_skipped.remove(&self.label);
    }
}

/// Why a connection ends: sent to the client where it can still read it.
enum Close {
    /// Quietly: the client went away, or the write stalled.
    Quiet,
    /// The WebSocket client sent a close frame: the server's reply (queued by tungstenite)
    /// is flushed, nothing else is sent.
    ClosedByPeer,
    /// With an error message.
    Error(u16, String),
    /// With a goodbye.
    Goodbye(String),
}

impl From<ProtocolError> for Close {
    fn from(e: ProtocolError) -> Self {
        Close::Error(e.code(), e.to_string())
    }
}

/// One client connection.
struct Connection {
    ctx: Arc<Context>,
    endpoint: &'static str,
    name: String,
    shutdown: watch::Receiver<Option<String>>,
    /// Past `max_clients`: refused after its subscribe (in the subscribe's form).
    over_limit: bool,
    /// So far past `max_clients` ([`refused_unread`]) that it is refused at once without
    /// reading anything (in binary; on the WebSocket port with HTTP 503): a flood of silent
    /// connections holds nothing for long.
    refuse_unread: bool,
    /// How long the client has to subscribe: `handshake_timeout`, at most
    /// [`OVER_LIMIT_HANDSHAKE`] past the limit.
    handshake_timeout: Duration,
    guard: ClientGuard,
    /// When the connection task last wrote bytes: the write timeout measures a stall from it.
    written: Arc<WriteProgress>,
    _done: mpsc::Sender<()>,
}

/// When a connection task's writer last made progress (wrote at least one byte), so that the
/// write timeout closes a connection that accepts nothing for that long, not one whose large
/// frame takes longer than that to read at a steady pace.
struct WriteProgress {
    since: Instant,
    /// Milliseconds from `since` to the last progress (or to the connection's start).
    last_ms: AtomicU64,
}

impl WriteProgress {
    fn new() -> Self {
        Self {
            since: Instant::now(),
            last_ms: AtomicU64::new(0),
        }
    }

    fn mark(&self) {
        let ms = u64::try_from(self.since.elapsed().as_millis()).unwrap_or(u64::MAX);
        self.last_ms.fetch_max(ms, Ordering::Relaxed);
    }

    fn last(&self) -> Instant {
        self.since + Duration::from_millis(self.last_ms.load(Ordering::Relaxed))
    }
}

/// A connection's reader-writer that stamps its [`WriteProgress`] whenever a write takes bytes,
/// and that reads `replay` (bytes already read from `inner`: a WebSocket upgrade request that
/// was checked first) before `inner`.
struct Stamped<T> {
    inner: T,
    progress: Arc<WriteProgress>,
    replay: Vec<u8>,
}

impl<T> Stamped<T> {
    fn new(inner: T, progress: Arc<WriteProgress>) -> Self {
        Self {
            inner,
            progress,
            replay: Vec::new(),
        }
    }
}

impl<T: AsyncRead + Unpin> AsyncRead for Stamped<T> {
    fn poll_read(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
        buf: &mut tokio::io::ReadBuf<'_>,
    ) -> std::task::Poll<std::io::Result<()>> {
        if !self.replay.is_empty() {
            let n = buf.remaining().min(self.replay.len());
            buf.put_slice(&self.replay[..n]);
            self.replay.drain(..n);
            return std::task::Poll::Ready(Ok(()));
        }
        std::pin::Pin::new(&mut self.inner).poll_read(cx, buf)
    }
}

/// Reads an HTTP request's head (through the blank line) and whatever followed it in the same
/// reads; errors when the peer closes first or the head exceeds [`MAX_UPGRADE_REQUEST`].
async fn read_upgrade_request<R: AsyncRead + Unpin>(reader: &mut R) -> Result<Vec<u8>, String> {
    let mut request = Vec::new();
    let mut buf = [0u8; 2048];
    loop {
        let n = reader
            .read(&mut buf)
            .await
            .map_err(|e| format!("reading the upgrade request: {e}"))?;
        if n == 0 {
            return Err("the client closed before its upgrade request ended".to_owned());
        }
        let searched_from = request.len().saturating_sub(2);
        request.extend_from_slice(&buf[..n]);
        // The head ends at an empty line; bare-LF line ends are accepted, as httparse (and
        // so tungstenite) accepts them.
        let tail = &request[searched_from..];
        if tail.windows(2).any(|w| w == b"\n\n") || tail.windows(3).any(|w| w == b"\n\r\n") {
            return Ok(request);
        }
        if request.len() > MAX_UPGRADE_REQUEST {
            return Err(format!(
                "upgrade request longer than {MAX_UPGRADE_REQUEST} bytes"
            ));
        }
    }
}

/// How a WebSocket upgrade ended: accepted, or refused with an HTTP status and the reason.
enum Upgrade<S> {
    Accepted(Box<tokio_tungstenite::WebSocketStream<S>>),
    Refused(S, u16, String),
}

/// Answers a refused upgrade with its status and the reason as a plain-text body (426 names
/// the WebSocket version spoken; 503 is a server past its client limit), then closes the
/// connection.
async fn answer_refused_upgrade<S: AsyncWrite + Unpin>(mut stream: S, status: u16, reason: &str) {
    let phrase = match status {
        426 => "Upgrade Required\r\nSec-WebSocket-Version: 13",
        503 => "Service Unavailable",
        _ => "Bad Request",
    };
    let body = format!("{reason}\n");
    let response = format!(
        "HTTP/1.1 {status} {phrase}\r\nContent-Type: text/plain; charset=utf-8\r\n\
         Content-Length: {}\r\nConnection: close\r\n\r\n{body}",
        body.len()
    );
    let _ = tokio::time::timeout(
        Duration::from_secs(1),
        stream.write_all(response.as_bytes()),
    )
    .await;
    let _ = stream.shutdown().await;
}

/// The longest WebSocket upgrade request read (request line and headers).
const MAX_UPGRADE_REQUEST: usize = 16 * 1024;

/// Why an HTTP request is no WebSocket upgrade this server accepts (RFC 6455 §4.2.1), as the
/// status to answer with and the reason; `None` when it is one (tungstenite then completes
/// the handshake). Version mismatches get 426 with the version spoken (§4.2.2).
fn upgrade_problem(request: &str) -> Option<(u16, String)> {
    // The head only, up to the empty line (CRLF or bare-LF line ends).
    let head: Vec<&str> = request
        .split('\n')
        .map(|line| line.strip_suffix('\r').unwrap_or(line))
        .take_while(|line| !line.is_empty())
        .collect();
    let request_line = head.first().copied().unwrap_or_default();
    let mut parts = request_line.split(' ');
    let (method, version) = (parts.next().unwrap_or_default(), parts.nth(1));
    if method != "GET" || version != Some("HTTP/1.1") {
        return Some((
            400,
            format!("expected a GET HTTP/1.1 WebSocket upgrade, got {request_line:?}"),
        ));
    }
    let header = |name: &str| {
        head.iter().skip(1).find_map(|line| {
            let (key, value) = line.split_once(':')?;
            key.trim()
                .eq_ignore_ascii_case(name)
                .then(|| value.trim().to_owned())
        })
    };
    let has_token = |name: &str, token: &str| {
        header(name).is_some_and(|v| v.split(',').any(|t| t.trim().eq_ignore_ascii_case(token)))
    };
    if !has_token("Upgrade", "websocket") || !has_token("Connection", "upgrade") {
        return Some((
            400,
            "this is envlight's WebSocket endpoint: send an upgrade (Upgrade: websocket, \
             Connection: Upgrade); metrics and health are served on [metrics] listen"
                .to_owned(),
        ));
    }
    if header("Sec-WebSocket-Key").is_none() {
        return Some((400, "the upgrade has no Sec-WebSocket-Key".to_owned()));
    }
    match header("Sec-WebSocket-Version") {
        Some(v) if v == "13" => None,
        other => Some((
            426,
            format!("WebSocket version {other:?} is not spoken here; use 13"),
        )),
    }
}

impl<T: AsyncWrite + Unpin> AsyncWrite for Stamped<T> {
    fn poll_write(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
        buf: &[u8],
    ) -> std::task::Poll<std::io::Result<usize>> {
        let polled = std::pin::Pin::new(&mut self.inner).poll_write(cx, buf);
        if matches!(polled, std::task::Poll::Ready(Ok(n)) if n > 0) {
            self.progress.mark();
        }
        polled
    }

    fn poll_flush(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
    ) -> std::task::Poll<std::io::Result<()>> {
        std::pin::Pin::new(&mut self.inner).poll_flush(cx)
    }

    fn poll_shutdown(
        mut self: std::pin::Pin<&mut Self>,
        cx: &mut std::task::Context<'_>,
    ) -> std::task::Poll<std::io::Result<()>> {
        std::pin::Pin::new(&mut self.inner).poll_shutdown(cx)
    }
}

/// How a stream client speaks: binary messages or JSON lines.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Dialect {
    Binary,
    JsonLines,
}

/// Per-client bookkeeping of what was sent.
#[derive(Default)]
struct Progress {
    last_index: u64,
    skipped: u64,
}

impl Connection {
    fn label(&self) -> EndpointLabel {
        EndpointLabel {
            endpoint: self.endpoint,
        }
    }

    /// Logs the subscription and marks the client as subscribed, so that its leaving is
    /// logged too ([`ClientGuard`]).
    fn log_subscribed(&self, request: &Request) {
        tracing::info!(
            client = %self.name,
            max_lights = request.max_lights,
            representation = request.representation.name(),
            format = request.format.name(),
            "client subscribed"
        );
        self.guard.subscribed.store(true, Ordering::Relaxed);
    }

    fn count_error(&self, why: &str) {
        tracing::info!(client = %self.name, reason = why, "closing connection");
        self.ctx
            .metrics
            .client_errors
            .get_or_create(&self.label())
            .inc();
    }

    /// Counts and logs the error `text` and closes the connection with it (`code`).
    fn refused(&self, code: u16, text: String) -> Close {
        self.count_error(&text);
        Close::Error(code, text)
    }

    fn too_many_clients(&self) -> Close {
        let message = format!(
            "too many clients (limit {}); try again later",
            self.ctx.config.max_clients
        );
        self.refused(error_code::INTERNAL, message)
    }

    /// The request if this daemon produces its representation, with the feed to follow.
    fn check_request(&self, request: Request) -> Result<(Request, Feed), Close> {
        let sources = &self.ctx.sources;
        if let Some(source) = sources
            .iter()
            .position(|s| s.representation == request.representation)
        {
            let rx = sources[source].rx.boxed_clone();
            return Ok((request, Feed { rx, source }));
        }
        let produced: Vec<&str> = sources.iter().map(|s| s.representation.name()).collect();
        let name = request.representation.name();
        let text = format!(
            "representation {name} is not produced by this daemon (it produces: {}; {name} \
             needs [{name}] enabled = true)",
            produced.join(", ")
        );
        Err(self.refused(error_code::UNSUPPORTED_REPRESENTATION, text))
    }

    /// Takes the newest publication if it is new to this client, counting skipped ones.
    fn take_newest(&self, feed: &mut Feed, progress: &mut Progress) -> Option<Arc<dyn Frame>> {
        let published = feed.rx.newest()?;
        let index = published.index();
        if index <= progress.last_index {
            return None;
        }
        if progress.last_index != 0 && index > progress.last_index + 1 {
            let skipped = index - progress.last_index - 1;
            progress.skipped += skipped;
            self.ctx
                .metrics
                .frames_skipped
                .get_or_create(&self.label())
                .inc_by(skipped);
            self.ctx
                .metrics
                .client_skipped
                .get_or_create(&self.guard.label)
                .set(i64::try_from(progress.skipped).unwrap_or(i64::MAX));
        }
        progress.last_index = index;
        Some(published)
    }

    /// Writes one frame within the write timeout, giving up at shutdown (a client stuck
    /// mid-frame cannot take a goodbye). `None`: written; otherwise why the connection ends.
    async fn write_frame<E>(
        &self,
        write: impl std::future::Future<Output = Result<(), E>>,
        shutdown: &mut watch::Receiver<Option<String>>,
        published: &dyn Frame,
    ) -> Option<Close> {
        let close = self.write_timed(write, shutdown).await;
        if close.is_none() {
            self.delivered(published);
        }
        close
    }

    /// Writes through the connection's [`Stamped`] writer, giving up at shutdown or when the
    /// write makes no progress (not a byte taken) for the write timeout; a client that reads a
    /// large frame slowly but steadily is not cut off. `None`: written; otherwise why the
    /// connection ends.
    async fn write_timed<E>(
        &self,
        write: impl std::future::Future<Output = Result<(), E>>,
        shutdown: &mut watch::Receiver<Option<String>>,
    ) -> Option<Close> {
        let timeout = self.ctx.config.write_timeout;
        let started = Instant::now();
        tokio::pin!(write);
        loop {
            let deadline = started.max(self.written.last()) + timeout;
            tokio::select! {
                written = &mut write => {
                    return match written {
                        Ok(()) => None,
                        Err(_) => Some(Close::Quiet),
                    };
                }
                _ = tokio::time::sleep_until(deadline.into()) => {
                    if started.max(self.written.last()) + timeout <= Instant::now() {
                        self.count_error("write stalled");
                        return Some(Close::Quiet);
                    }
                }
                _ = shutdown.wait_for(Option::is_some) => return Some(Close::Quiet),
            }
        }
    }

    /// This client's metric handles, for its fan-out slot.
    fn slot_metrics(&self) -> SlotMetrics {
        let metrics = &self.ctx.metrics;
        SlotMetrics {
            sent: metrics.frames_sent.get_or_create(&self.label()).clone(),
            skipped: metrics.frames_skipped.get_or_create(&self.label()).clone(),
            client_skipped: metrics
                .client_skipped
                .get_or_create(&self.guard.label)
                .clone(),
            delivery: metrics.delivery_seconds.clone(),
        }
    }

    fn delivered(&self, published: &dyn Frame) {
        self.ctx
            .metrics
            .frames_sent
            .get_or_create(&self.label())
            .inc();
        if let Some(arrived) = published.delivery_start() {
            self.ctx
                .metrics
                .delivery_seconds
                .observe(arrived.elapsed().as_secs_f64());
        }
    }

    // --------------------------------------------------------------------------------------
    // Unix socket and TCP

    async fn serve_stream(self, socket: Arc<dyn Socket>) {
        // The task reads and writes through one clone, the fan-out thread writes through
        // another.
        let mut reader = Shared(Arc::clone(&socket));
        let mut writer = Stamped::new(Shared(Arc::clone(&socket)), Arc::clone(&self.written));
        let mut dialect = Dialect::Binary;
        let close = self
            .stream_session(&mut reader, &mut writer, &socket, &mut dialect)
            .await;
        let mut out = Vec::new();
        match (&close, dialect) {
            (Close::Quiet | Close::ClosedByPeer, _) => {}
            (Close::Error(code, text), Dialect::Binary) => encode_error(*code, text, &mut out),
            (Close::Goodbye(text), Dialect::Binary) => encode_goodbye(text, &mut out),
            (Close::Error(code, text), Dialect::JsonLines) => {
                out.extend(protocol::error_to_json(*code, text).as_bytes());
                out.push(b'\n');
            }
            (Close::Goodbye(text), Dialect::JsonLines) => {
                out.extend(goodbye_to_json(text).as_bytes());
                out.push(b'\n');
            }
        }
        if !out.is_empty() {
            // A client that does not read its closing message within a second loses it.
            let _ = tokio::time::timeout(Duration::from_secs(1), async {
                writer.write_all(&out).await?;
                writer.shutdown().await
            })
            .await;
        }
    }

    async fn stream_session<R, W>(
        &self,
        reader: &mut R,
        writer: &mut W,
        socket: &Arc<dyn Socket>,
        dialect: &mut Dialect,
    ) -> Close
    where
        R: AsyncRead + Unpin,
        W: AsyncWrite + Unpin,
    {
        if self.refuse_unread {
            return self.too_many_clients();
        }
        let mut decoder = Decoder::new();
        let mut buf = vec![0u8; 4096];
        let (request, followed) = match self
            .stream_handshake(reader, &mut decoder, &mut buf, dialect)
            .await
        {
            Ok(subscribe) => subscribe,
            Err(close) => return close,
        };
        // Frames and the closing message (an error 6 for the representation included) follow
        // the requested format from now on.
        let subscribed_binary = *dialect == Dialect::Binary;
        *dialect = match request.format {
            Format::Binary => Dialect::Binary,
            Format::Json => Dialect::JsonLines,
        };
        // Refused after the subscribe, so that the refusal comes in the client's form (a JSON
        // Lines client could not read a binary error 100).
        if self.over_limit {
            return self.too_many_clients();
        }
        let (request, mut feed) = match self.check_request(request) {
            Ok(r) => r,
            Err(close) => return close,
        };
        self.log_subscribed(&request);
        // Bytes that came with the subscribe are input after it.
        if followed {
            if subscribed_binary {
                return self.unexpected_input(&mut decoder);
            }
            let text = "unexpected bytes after the subscribe line; clients send nothing more";
            return self.refused(error_code::UNEXPECTED_MESSAGE, text.to_owned());
        }
        let encoding = match request.format {
            Format::Binary => Encoding::Binary,
            Format::Json => Encoding::JsonLine,
        };
        let cap = request.cap();
        let slot = Arc::new(Slot::new(
            Arc::clone(socket),
            cap,
            encoding,
            self.slot_metrics(),
        ));
        let fanout = Arc::clone(self.ctx.fanout(&feed));
        let Some(_registration) = fanout.register(&slot) else {
            return Close::Goodbye("the light stream ended".to_owned());
        };
        let mut reading = true;
        let mut shutdown = self.shutdown.clone();
        loop {
            // The task's turn (a new client, or the fan-out found the socket full): finish
            // the frame the fan-out began, then send the newest publication until this client
            // has it; then the fan-out writes again.
            if slot.writer() == Writer::Task {
                if let Some(unfinished) = slot.take_unfinished() {
                    let write = writer.write_all(&unfinished.bytes[unfinished.written..]);
                    if let Some(close) = self.write_timed(write, &mut shutdown).await {
                        slot.close();
                        return close;
                    }
                    slot.delivered(unfinished.delivery_start);
                }
                if let Some(published) = slot.next_for_task(|| feed.rx.newest()) {
                    let out = self.ctx.encoded(&feed, &*published, cap, encoding);
                    let write = writer.write_all(out.as_slice());
                    if let Some(close) = self.write_timed(write, &mut shutdown).await {
                        slot.close();
                        return close;
                    }
                    slot.delivered(published.delivery_start());
                    continue;
                }
                // Handed back: the reactor need not watch for room any more.
                socket.write_done();
            }
            if fanout.ended() {
                // A helper's share of the last pass may have left a frame half written (the
                // socket took part of it): a goodbye after it would read as the frame's body.
                if slot.close() {
                    return Close::Quiet;
                }
                return Close::Goodbye("the light stream ended".to_owned());
            }
            let event = tokio::select! {
                biased;
                _ = slot.handed_over() => continue,
                message = shutdown_message(&mut shutdown) => StreamEvent::Shutdown(message),
                read = reader.read(&mut buf), if reading => StreamEvent::Input(read),
            };
            // From here on nobody writes frames; a frame left half written means no closing
            // message can follow.
            if !matches!(event, StreamEvent::Input(Ok(0))) && slot.close() {
                return Close::Quiet;
            }
            match event {
                StreamEvent::Shutdown(message) => return Close::Goodbye(message),
                StreamEvent::Input(Ok(0)) => reading = false, // half-closed: keep sending
                StreamEvent::Input(Ok(n)) => {
                    if !subscribed_binary {
                        // A JSON client's bytes are no binary header to decode.
                        let text = "unexpected bytes after the subscribe line; clients send \
                                    nothing more"
                            .to_owned();
                        return self.refused(error_code::UNEXPECTED_MESSAGE, text);
                    }
                    decoder.push(&buf[..n]);
                    return self.unexpected_input(&mut decoder);
                }
                StreamEvent::Input(Err(_)) => return Close::Quiet,
            }
        }
    }

    fn handshake_timed_out(&self) -> Close {
        let text = format!(
            "no subscribe message within {:.1} s",
            self.handshake_timeout.as_secs_f64()
        );
        self.refused(error_code::BAD_REQUEST, text)
    }

    /// Input after the subscribe: an error for whatever it is.
    fn unexpected_input(&self, decoder: &mut Decoder) -> Close {
        match decoder.next_message() {
            Err(e) => {
                self.count_error(&e.to_string());
                e.into()
            }
            Ok(message) => {
                let what = match message {
                    Some(Message::Subscribe(_)) => "a second subscribe",
                    Some(
                        Message::Frame(_) | Message::Asg(_) | Message::Wavelet(_) | Message::Sh(_),
                    ) => "a frame",
                    Some(Message::Error { .. }) => "an error message",
                    Some(Message::Goodbye { .. }) => return Close::Quiet,
                    None => "bytes",
                };
                let text =
                    format!("unexpected {what} after the subscribe; clients send nothing more");
                self.refused(error_code::UNEXPECTED_MESSAGE, text)
            }
        }
    }

    /// Reads the subscribe: a binary message, or one JSON line; with whether more bytes came
    /// with it (a binary subscribe leaves them in `decoder`).
    async fn stream_handshake<R: AsyncRead + Unpin>(
        &self,
        reader: &mut R,
        decoder: &mut Decoder,
        buf: &mut [u8],
        dialect: &mut Dialect,
    ) -> Result<(Request, bool), Close> {
        let deadline = tokio::time::Instant::now() + self.handshake_timeout;
        let mut shutdown = self.shutdown.clone();
        let mut line: Vec<u8> = Vec::new();
        let mut first = true;
        loop {
            let event = tokio::select! {
                read = reader.read(buf) => HandshakeEvent::Input(read),
                _ = tokio::time::sleep_until(deadline) => HandshakeEvent::Timeout,
                message = shutdown_message(&mut shutdown) => HandshakeEvent::Shutdown(message),
            };
            let read = match event {
                HandshakeEvent::Input(read) => read,
                HandshakeEvent::Timeout => return Err(self.handshake_timed_out()),
                HandshakeEvent::Shutdown(message) => return Err(Close::Goodbye(message)),
            };
            let n = match read {
                Ok(0) => {
                    if let Err(e) = decoder.finish() {
                        self.count_error(&format!("vanished mid-message: {e}"));
                    } else if !line.is_empty() {
                        self.count_error("vanished mid-line");
                    }
                    return Err(Close::Quiet);
                }
                Ok(n) => n,
                Err(_) => return Err(Close::Quiet),
            };
            let bytes = &buf[..n];
            if first {
                first = false;
                if bytes[0] == b'{' {
                    *dialect = Dialect::JsonLines;
                }
            }
            if *dialect == Dialect::JsonLines {
                let end = bytes.iter().position(|&b| b == b'\n');
                line.extend_from_slice(&bytes[..end.unwrap_or(bytes.len())]);
                // The limit holds however the line arrives (with its newline in one read); a
                // CR at the end may be the line end's, not the line's.
                let content = line.len() - usize::from(line.last() == Some(&b'\r'));
                if content > MAX_JSON_LINE {
                    let text = format!("subscribe line longer than {MAX_JSON_LINE} bytes");
                    return Err(self.refused(error_code::TOO_LARGE, text));
                }
                let Some(end) = end else { continue };
                // Bytes after the line are input after the subscribe, answered in the format
                // it asks for (as when they come in a later packet): the caller is told.
                let followed = end + 1 < bytes.len();
                let Ok(text) = std::str::from_utf8(&line) else {
                    let text = "the subscribe line is not UTF-8".to_owned();
                    return Err(self.refused(error_code::MALFORMED, text));
                };
                return protocol::parse_json_request(text.trim_end_matches('\r'))
                    .map(|request| (request, followed))
                    .map_err(|e| {
                        self.count_error(&e.to_string());
                        e.into()
                    });
            }
            decoder.push(bytes);
            match decoder.next_message() {
                Ok(None) => continue,
                Ok(Some(Message::Subscribe(request))) => {
                    return Ok((request, decoder.buffered() > 0))
                }
                Ok(Some(_)) => {
                    let text = "the first message must be a subscribe".to_owned();
                    return Err(self.refused(error_code::UNEXPECTED_MESSAGE, text));
                }
                Err(e) => {
                    self.count_error(&e.to_string());
                    return Err(e.into());
                }
            }
        }
    }

    // --------------------------------------------------------------------------------------
    // WebSocket

    async fn serve_websocket(self, stream: tokio::net::TcpStream) {
        if self.refuse_unread {
            // Before reading anything, so no WebSocket message can carry it: HTTP 503.
            if let Close::Error(_, text) = self.too_many_clients() {
                answer_refused_upgrade(stream, 503, &text).await;
            }
            return;
        }
        let mut config = tungstenite::protocol::WebSocketConfig::default();
        config.max_message_size = Some(protocol::MAX_MESSAGE_LEN);
        config.max_frame_size = Some(protocol::MAX_MESSAGE_LEN);
        // One deadline for the HTTP upgrade and the subscribe together, as on the other
        // endpoints (each had its own, doubling the time a silent client was kept).
        let deadline = tokio::time::Instant::now() + self.handshake_timeout;
        let mut stamped = Stamped::new(stream, Arc::clone(&self.written));
        // The upgrade request is read and checked here, then replayed to tungstenite: a
        // request that is no upgrade gets an HTTP answer saying why (tungstenite closed it
        // without a word, so `curl` or a browser saw an empty reply).
        let handshake = async {
            let request = read_upgrade_request(&mut stamped.inner).await?;
            if let Some((status, reason)) = upgrade_problem(&String::from_utf8_lossy(&request)) {
                return Ok(Upgrade::Refused(stamped, status, reason));
            }
            stamped.replay.extend(request);
            tokio_tungstenite::accept_async_with_config(stamped, Some(config))
                .await
                .map(|ws| Upgrade::Accepted(Box::new(ws)))
                .map_err(|e| e.to_string())
        };
        let ws = match tokio::time::timeout_at(deadline, handshake).await {
            Ok(Ok(Upgrade::Accepted(ws))) => *ws,
            Ok(Ok(Upgrade::Refused(stamped, status, reason))) => {
                self.count_error(&format!("websocket upgrade refused: {reason}"));
                answer_refused_upgrade(stamped, status, &reason).await;
                return;
            }
            Ok(Err(problem)) => {
                self.count_error(&format!("websocket handshake failed: {problem}"));
                return;
            }
            Err(_) => {
                self.count_error("websocket handshake timed out");
                return;
            }
        };
        let (mut sink, mut source) = ws.split();
        let mut json = true;
        let close = self
            .websocket_session(&mut sink, &mut source, &mut json, deadline)
            .await;
        if matches!(close, Close::ClosedByPeer) {
            // Sends the close frame tungstenite queued in reply to the client's (RFC 6455
            // 5.5.1); a close of our own would be refused after the client's.
            let _ = tokio::time::timeout(Duration::from_secs(1), sink.flush()).await;
            return;
        }
        let lingering = matches!(close, Close::Error(..));
        let message = match close {
            Close::Quiet | Close::ClosedByPeer => None,
            Close::Error(code, text) if json => Some(tungstenite::Message::text(
                protocol::error_to_json(code, &text),
            )),
            Close::Goodbye(text) if json => {
                Some(tungstenite::Message::text(goodbye_to_json(&text)))
            }
            Close::Error(code, text) => {
                let mut out = Vec::new();
                encode_error(code, &text, &mut out);
                Some(tungstenite::Message::binary(out))
            }
            Close::Goodbye(text) => {
                let mut out = Vec::new();
                encode_goodbye(&text, &mut out);
                Some(tungstenite::Message::binary(out))
            }
        };
        let _ = tokio::time::timeout(Duration::from_secs(1), async {
            if let Some(message) = message {
                sink.send(message).await?;
            }
            sink.send(tungstenite::Message::Close(None)).await
        })
        .await;
        if lingering {
            // A lingering close: a client closed for its input (a message over the limit, a
            // broken frame) may still be sending. Closing with its bytes unread would reset
            // the connection and could discard the error message before the client reads it;
            // so the write side is shut and the input read and dropped, for at most 1 s or
            // 4 MiB.
            if let Ok(mut ws) = sink.reunite(source) {
                let socket = &mut ws.get_mut().inner;
                let _ = tokio::time::timeout(Duration::from_secs(1), async {
                    let _ = socket.shutdown().await;
                    let mut buf = vec![0u8; 16384];
                    let mut left: usize = 4 << 20;
                    while left > 0 {
                        match socket.read(&mut buf).await {
                            Ok(0) | Err(_) => break,
                            Ok(n) => left = left.saturating_sub(n),
                        }
                    }
                })
                .await;
            }
        }
    }

    /// A WebSocket read error: a message over the size limit is answered with error 4, a
    /// broken frame (reserved bits or opcodes, a bad close frame, invalid UTF-8 in a text
    /// message) with error 1, each counted and logged as on the other endpoints; a connection
    /// that is already gone ends quietly.
    fn websocket_error(&self, error: tungstenite::Error) -> Close {
        use tungstenite::error::ProtocolError as WsProtocol;
        use tungstenite::Error as Ws;
        let (code, text) = match error {
            Ws::ConnectionClosed
            | Ws::AlreadyClosed
            | Ws::Io(_)
            | Ws::Protocol(WsProtocol::ResetWithoutClosingHandshake) => return Close::Quiet,
            Ws::Capacity(e) => (
                error_code::TOO_LARGE,
                format!(
                    "websocket message too large ({e}; the limit is {} bytes)",
                    protocol::MAX_MESSAGE_LEN
                ),
            ),
            e => (error_code::MALFORMED, format!("websocket: {e}")),
        };
        self.refused(code, text)
    }

    async fn websocket_session<K, S>(
        &self,
        sink: &mut K,
        source: &mut S,
        json: &mut bool,
        deadline: tokio::time::Instant,
    ) -> Close
    where
        K: futures_util::Sink<tungstenite::Message, Error = tungstenite::Error> + Unpin,
        S: futures_util::Stream<Item = Result<tungstenite::Message, tungstenite::Error>> + Unpin,
    {
        let mut shutdown = self.shutdown.clone();
        let request = loop {
            let event = tokio::select! {
                next = source.next() => HandshakeEvent::Input(next),
                _ = tokio::time::sleep_until(deadline) => HandshakeEvent::Timeout,
                message = shutdown_message(&mut shutdown) => HandshakeEvent::Shutdown(message),
            };
            let next = match event {
                HandshakeEvent::Input(next) => next,
                HandshakeEvent::Timeout => return self.handshake_timed_out(),
                HandshakeEvent::Shutdown(message) => return Close::Goodbye(message),
            };
            let parsed = match next {
                None => return Close::Quiet,
                Some(Err(e)) => return self.websocket_error(e),
                Some(Ok(tungstenite::Message::Close(_))) => return Close::ClosedByPeer,
                Some(Ok(tungstenite::Message::Text(text))) => {
                    *json = true;
                    protocol::parse_json_message(text.as_str())
                }
                Some(Ok(tungstenite::Message::Binary(bytes))) => {
                    *json = false;
                    decode_message(&bytes)
                }
                Some(Ok(_)) => continue, // ping, pong
            };
            match parsed {
                Ok(Message::Subscribe(request)) => break request,
                Ok(_) => {
                    let text = "the first message must be a subscribe".to_owned();
                    return self.refused(error_code::UNEXPECTED_MESSAGE, text);
                }
                Err(e) => {
                    self.count_error(&e.to_string());
                    return e.into();
                }
            }
        };
        // After the subscribe, so that the refusal comes in its form (as on the stream ports).
        if self.over_limit {
            return self.too_many_clients();
        }
        let (request, mut feed) = match self.check_request(request) {
            Ok(r) => r,
            Err(close) => return close,
        };
        self.log_subscribed(&request);
        let mut progress = Progress::default();
        loop {
            let event = tokio::select! {
                biased;
                changed = feed.rx.changed() => Event::Lights(changed),
                message = shutdown_message(&mut shutdown) => Event::Shutdown(message),
                next = source.next() => Event::Input(next),
            };
            match event {
                Event::Lights(false) => {
                    return Close::Goodbye("the light stream ended".to_owned());
                }
                Event::Lights(true) => {
                    let Some(published) = self.take_newest(&mut feed, &mut progress) else {
                        continue;
                    };
                    let message = match request.format {
                        Format::Binary => {
                            let out = self.ctx.encoded(
                                &feed,
                                &*published,
                                request.cap(),
                                Encoding::Binary,
                            );
                            tungstenite::Message::binary(out.as_slice().to_vec())
                        }
                        Format::Json => {
                            let out = self.ctx.encoded(
                                &feed,
                                &*published,
                                request.cap(),
                                Encoding::JsonText,
                            );
                            match String::from_utf8(out.as_slice().to_vec()) {
                                Ok(text) => tungstenite::Message::text(text),
                                Err(_) => {
                                    return Close::Error(
                                        error_code::INTERNAL,
                                        "frame encoding produced invalid UTF-8".to_owned(),
                                    )
                                }
                            }
                        }
                    };
                    let write = sink.send(message);
                    if let Some(close) = self.write_frame(write, &mut shutdown, &*published).await {
                        return close;
                    }
                }
                Event::Shutdown(message) => return Close::Goodbye(message),
                Event::Input(next) => match next {
                    None => return Close::Quiet,
                    Some(Err(e)) => return self.websocket_error(e),
                    Some(Ok(tungstenite::Message::Close(_))) => return Close::ClosedByPeer,
                    Some(Ok(tungstenite::Message::Ping(_) | tungstenite::Message::Pong(_))) => {}
                    Some(Ok(_)) => {
                        let text =
                            "unexpected message after the subscribe; clients send nothing more"
                                .to_owned();
                        return self.refused(error_code::UNEXPECTED_MESSAGE, text);
                    }
                },
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn bind(path: &Path) -> Result<UnixListener, ServerError> {
        let runtime = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .unwrap();
        runtime.block_on(async { bind_unix(path, 0o600) })
    }

    /// What stands in a socket path's way is named: a file at the path, or a file where a
    /// directory above it should be (that was "File exists").
    #[test]
    fn files_in_a_sockets_way_are_named() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("plain");
        std::fs::write(&file, b"x").unwrap();
        let e = bind(&file).unwrap_err().to_string();
        assert!(e.contains("not a socket is in the way"), "{e}");
        let below = file.join("sub").join("envlight.sock");
        let e = bind(&below).unwrap_err().to_string();
        assert!(
            e.contains(&format!("{} is not a directory", file.display())),
            "{e}"
        );
        assert!(bind(&dir.path().join("new").join("envlight.sock")).is_ok());
    }

    /// The two bind errors a new user meets say what to change: an address in use names the
    /// config key of its endpoint; a Unix socket directory the user may not write (root can,
    /// so that error is built here) points to `unix_socket`.
    #[test]
    fn bind_errors_say_what_to_change() {
        let runtime = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .unwrap();
        runtime.block_on(async {
            let taken = TcpListener::bind("127.0.0.1:0").await.unwrap();
            let addr = taken.local_addr().unwrap();
            for (endpoint, key) in [("tcp", "`tcp`"), ("websocket", "`websocket`")] {
                let e = bind_tcp(endpoint, addr).await.unwrap_err().to_string();
                assert!(
                    e.contains(&format!("cannot listen on {endpoint} {addr}")),
                    "{e}"
                );
                assert!(e.contains("another process") && e.contains(key), "{e}");
            }
        });
        let e = ServerError::Bind {
            endpoint: "uds",
            address: "/run/envlight/envlight.sock".into(),
            source: std::io::Error::from(std::io::ErrorKind::PermissionDenied),
        }
        .to_string();
        assert!(e.contains("`unix_socket`") && e.contains("[stream]"), "{e}");
        let e = ServerError::Bind {
            endpoint: "tcp",
            address: "127.0.0.1:7878".into(),
            source: std::io::Error::from(std::io::ErrorKind::PermissionDenied),
        }
        .to_string();
        assert!(!e.contains(';'), "no hint for other errors: {e}");
    }

    /// The socket file appears already listening and with its mode, and nothing else is left
    /// beside it; a second daemon on the same path is refused.
    #[test]
    fn the_socket_file_appears_listening_with_its_mode() {
        use std::os::unix::fs::PermissionsExt;
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("envlight.sock");
        let runtime = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .build()
            .unwrap();
        let _listener = runtime.block_on(async { bind_unix(&path, 0o640) }).unwrap();
        let mode = std::fs::metadata(&path).unwrap().permissions().mode() & 0o777;
        assert_eq!(mode, 0o640);
        assert!(std::os::unix::net::UnixStream::connect(&path).is_ok());
        let names: Vec<_> = std::fs::read_dir(dir.path())
            .unwrap()
            .map(|e| e.unwrap().file_name())
            .collect();
        assert_eq!(names, ["envlight.sock"]);
        let e = runtime
            .block_on(async { bind_unix(&path, 0o640) })
            .unwrap_err();
        assert!(matches!(e, ServerError::SocketInUse { .. }), "{e}");
    }
}
