//! Stream latency benchmark: time from a frame's arrival at the decomposition to the last byte of
//! its light list read by a client, with many clients at 60 frames/s; and the largest client
//! count served at 60 frames/s without loss for clients that keep up.
//!
//! Not a criterion benchmark (latency percentiles under a paced load are not what criterion
//! measures); run it with `cargo bench --bench stream_latency` (add `-- --quick` for a short
//! run; other options after `--`: `--clients=1,64,…`, `--transport=uds|tcp|both`,
//! `--harness=threads|events|both`, `--sender=daemon|floor|both`,
//! `--fanout=publisher|thread|both` (which thread runs the daemon's fan-out pass: the
//! decompose thread right after publishing, as the daemon does by default, or the
//! `envlight-fanout` thread), `--pass-threads=1,2,…` (the threads that write each pass:
//! `stream.pass_threads`, the daemon's default 2 unless given), `--seconds=S`,
//! `--decode=in-place|buffered|both` (how the clients decode, below),
//! `--repeat=N` (each repeat runs every sender once, back to back),
//! `--spin-idle=off|on|both` (below); an unknown value stops the run; docs/performance.md
//! "Streaming"). The whole chain runs
//! in this process so one clock serves both ends: the built-in sky at 60 frames/s → pipeline
//! (256 lights) → stream server (UDS or TCP, binary frames) → N clients (one blocking thread
//! each, or one event loop), each stamping the moment a frame's last byte has been read.
//!
//! The clients decode every frame in full with the library's [`Decoder`], as a Rust client
//! does: by default straight from the read buffer (`Decoder::feed`), handing each light list
//! back for the next (`Decoder::recycle`); `--decode=buffered` copies every read into the
//! decoder first (`push` + `next_message`) and allocates each list, as before round 4 (for A/B
//! runs of the client path; `both` alternates them within each repeat).
//!
//! `--sender=floor` replaces the daemon by the least a sender can do: one plain thread that
//! writes the same pre-encoded 256-light frame to every client socket in turn with blocking
//! writes, 60 times a second. Its "fan-out" is what the harness (the client threads, the
//! kernel's socket path) costs by itself on this machine; the daemon's fan-out minus that is
//! the server's own share.
//!
//! Besides the latencies, each row gives per frame: when the first copy was read after the
//! publication (the hop to the fan-out, one write, one reader's wake-up) and how long after it
//! the last copy was (the rest of the pass and the readers' turns on the CPUs); the CPU time of
//! the decompose thread, of the serving threads (the tokio workers and, if any, the fan-out
//! thread; the floor's sender thread) and of all client threads together, from the scheduler's
//! per-thread run time (`/proc/self/task/*/schedstat`); how long the decompose and serving
//! threads were runnable but waiting for a CPU (schedstat) and how often the serving threads
//! were preempted (`nonvoluntary_ctxt_switches`); and the load average when the row ended. On
//! a shared machine the wall-clock figures are noisy, the CPU times much less so.
//!
//! `--spin-idle=on` keeps every CPU from going idle during the row: one thread per CPU, pinned
//! to it, at the `SCHED_IDLE` policy (it runs only when nothing else wants that CPU and gives
//! way at once to any woken thread), spinning. It is not something the daemon does; it measures
//! how much of the latency is the wake-up of an idle (halted) CPU, which on a virtual machine
//! is an exit to the hypervisor and a wait for the host to run the virtual CPU again (what
//! `idle=poll`, or `/dev/cpu_dma_latency` where a cpuidle driver is loaded, avoids on a rig).
//! Its threads' CPU time is counted nowhere in the row, but the load average includes them
//! (about +1 per CPU). `both` runs each row without and then with them.

use envlight::capture::sky::{render_sky, SkyOptions};
use envlight::capture::{CaptureError, FrameSource};
use envlight::decompose::{DecomposeSettings, Decomposer};
use envlight::metrics::Metrics;
use envlight::pipeline::{Pipeline, PipelineOptions, PublishHook};
use envlight::stream::client::Endpoint;
use envlight::stream::protocol::{encode_frame, encode_request};
use envlight::stream::{
    Decoder, Format, Message, PublisherPass, Request, ServerConfig, StreamServer, Streams,
};
use envlight::{HdrFrame, LightFrame};
use std::collections::HashMap;
use std::io::{Read, Write};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};
use tokio::io::{AsyncReadExt, AsyncWriteExt};

/// Per frame seq: arrival at the decomposition, publication, decomposition time.
type Stamps = (Instant, Instant, Duration);

struct Run {
    /// Arrival at the decomposition → last byte read by a client.
    latencies: Vec<Duration>,
    /// Publication (decomposition done) → last byte read by a client.
    fan_out: Vec<Duration>,
    /// Decomposition times.
    decompose: Vec<Duration>,
    /// Frames published while all clients were connected.
    published: u64,
    /// Per client: frames missed among those published while it was connected.
    missed: Vec<u64>,
    /// CPU time per published frame of the serving threads (or the floor's sender).
    serve_cpu: Duration,
    /// CPU time per published frame of all client threads together.
    client_cpu: Duration,
    /// Per frame: publication → the first client's last byte (the hop to the fan-out, one
    /// write, one reader's wake-up).
    first_copy: Vec<Duration>,
    /// Per frame: the first client's last byte → the last client's (the rest of the pass and
    /// the readers' turns on the CPUs).
    spread: Vec<Duration>,
    /// CPU time per published frame of the decompose thread (with the fan-out pass when it
    /// runs there).
    decompose_cpu: Duration,
    /// Per published frame: run-queue wait (runnable, not running) of the decompose thread.
    decompose_wait: Duration,
    /// Per published frame: run-queue wait of the serving threads (or the floor's sender).
    serve_wait: Duration,
    /// Per published frame: involuntary context switches (preemptions) of the serving threads.
    serve_preempted: f64,
}

/// A client that gets nothing for this long gives up.
const READ_TIMEOUT: Duration = Duration::from_secs(10);

/// The measurement window ends this long before the clients stop.
const WINDOW_END: Duration = Duration::from_millis(300);

/// Name (as the kernel keeps it, at most 15 bytes) of the decompose thread.
const DECOMPOSE_THREADS: &[&str] = &["envlight-decomp"];
/// Names (as the kernel keeps them, at most 15 bytes) of the threads counted as serving.
const SERVING_THREADS: &[&str] = &[
    "envlight-serve",
    "envlight-fanout",
    "envlight-pass",
    "bench sender",
];
/// Name of the client threads (thread per client, or the one event loop).
const CLIENT_THREADS: &[&str] = &["bench client", "bench clients"];

/// What the scheduler counts for a thread: `/proc/self/task/*/schedstat` (run time, time
/// runnable but waiting for a CPU) and `status` (involuntary context switches: preemptions).
#[derive(Clone, Copy, Default)]
struct SchedStats {
    run_ns: u64,
    wait_ns: u64,
    preempted: u64,
}

/// The scheduler's counters of this process's threads, summed by thread name.
fn thread_stats() -> HashMap<String, SchedStats> {
    let mut stats: HashMap<String, SchedStats> = HashMap::new();
    let Ok(tasks) = std::fs::read_dir("/proc/self/task") else {
        return stats;
    };
    for task in tasks.flatten() {
        let dir = task.path();
        let (Ok(name), Ok(stat), Ok(status)) = (
            std::fs::read_to_string(dir.join("comm")),
            std::fs::read_to_string(dir.join("schedstat")),
            std::fs::read_to_string(dir.join("status")),
        ) else {
            continue;
        };
        let mut fields = stat
            .split_whitespace()
            .map(|t| t.parse::<u64>().unwrap_or(0));
        let preempted = status
            .lines()
            .find_map(|l| l.strip_prefix("nonvoluntary_ctxt_switches:"))
            .and_then(|v| v.trim().parse().ok())
            .unwrap_or(0);
        let entry = stats.entry(name.trim_end().to_owned()).or_default();
        entry.run_ns += fields.next().unwrap_or(0);
        entry.wait_ns += fields.next().unwrap_or(0);
        entry.preempted += preempted;
    }
    stats
}

/// A counter of the threads named in `names`, per frame, between two snapshots.
fn per_frame(
    before: &HashMap<String, SchedStats>,
    after: &HashMap<String, SchedStats>,
    names: &[&str],
    frames: u64,
    counter: fn(&SchedStats) -> u64,
) -> f64 {
    let total: u64 = names
        .iter()
        .map(|name| {
            let a = after.get(*name).map_or(0, counter);
            let b = before.get(*name).map_or(0, counter);
            a.saturating_sub(b)
        })
        .sum();
    total as f64 / frames.max(1) as f64
}

/// A time counter (nanoseconds) of the threads named in `names`, per frame.
fn time_per_frame(
    before: &HashMap<String, SchedStats>,
    after: &HashMap<String, SchedStats>,
    names: &[&str],
    frames: u64,
    counter: fn(&SchedStats) -> u64,
) -> Duration {
    Duration::from_nanos(per_frame(before, after, names, frames, counter) as u64)
}

/// The 1-minute load average.
fn load_average() -> String {
    std::fs::read_to_string("/proc/loadavg")
        .ok()
        .and_then(|l| l.split_whitespace().next().map(str::to_owned))
        .unwrap_or_else(|| "?".to_owned())
}

/// Turns the stamps of the measured frames (`first_seq..=last_seq`) into a [`Run`].
fn analyse(
    arrivals: &HashMap<u64, Stamps>,
    received: &[Received],
    first_seq: u64,
    last_seq: u64,
    cpu: (&HashMap<String, SchedStats>, &HashMap<String, SchedStats>),
) -> Run {
    let mut latencies = Vec::new();
    let mut fan_out = Vec::new();
    let mut missed = Vec::new();
    let mut decompose: Vec<Duration> = (first_seq..=last_seq)
        .filter_map(|seq| arrivals.get(&seq).map(|a| a.2))
        .collect();
    decompose.sort();
    // Per frame: when its first and its last copy were read.
    let mut copies: HashMap<u64, (Instant, Instant)> = HashMap::new();
    for frames in received {
        let mut seen = 0u64;
        for &(seq, at) in frames {
            if (first_seq..=last_seq).contains(&seq) {
                seen += 1;
                let entry = copies.entry(seq).or_insert((at, at));
                entry.0 = entry.0.min(at);
                entry.1 = entry.1.max(at);
                if let Some((arrived, published, _)) = arrivals.get(&seq) {
                    latencies.push(at.saturating_duration_since(*arrived));
                    fan_out.push(at.saturating_duration_since(*published));
                }
            }
        }
        missed.push((last_seq + 1).saturating_sub(first_seq) - seen);
    }
    latencies.sort();
    fan_out.sort();
    let mut first_copy = Vec::new();
    let mut spread = Vec::new();
    for (seq, (first, last)) in &copies {
        if let Some((_, published, _)) = arrivals.get(seq) {
            first_copy.push(first.saturating_duration_since(*published));
            spread.push(last.saturating_duration_since(*first));
        }
    }
    first_copy.sort();
    spread.sort();
    let published = (last_seq + 1).saturating_sub(first_seq);
    let (before, after) = cpu;
    Run {
        latencies,
        fan_out,
        decompose,
        published,
        missed,
        serve_cpu: time_per_frame(before, after, SERVING_THREADS, published, |s| s.run_ns),
        client_cpu: time_per_frame(before, after, CLIENT_THREADS, published, |s| s.run_ns),
        first_copy,
        spread,
        decompose_cpu: time_per_frame(before, after, DECOMPOSE_THREADS, published, |s| s.run_ns),
        decompose_wait: time_per_frame(before, after, DECOMPOSE_THREADS, published, |s| s.wait_ns),
        serve_wait: time_per_frame(before, after, SERVING_THREADS, published, |s| s.wait_ns),
        serve_preempted: per_frame(before, after, SERVING_THREADS, published, |s| s.preempted),
    }
}

fn run(
    transport: Transport,
    (harness, decode): (Harness, Decode),
    clients: usize,
    seconds: f64,
    pass_on: PassOn,
    pass_threads: usize,
) -> Run {
    let sky = PrerenderedSky::new(60.0);
    let arrivals: Arc<Mutex<HashMap<u64, Stamps>>> = Arc::default();
    let hook_arrivals = Arc::clone(&arrivals);
    let stamps = PublishHook(Arc::new(move |published| {
        if let Some(arrived) = published.arrived {
            hook_arrivals.lock().unwrap().insert(
                published.payload.seq,
                (arrived, published.published_at, published.compute_time),
            );
        }
    }));
    let publisher_pass = (pass_on == PassOn::Publisher).then(PublisherPass::new);
    let on_publish = match &publisher_pass {
        // As the daemon wires it: the pass first, then the rest.
        Some(pass) => pass.hook().then(stamps),
        None => stamps,
    };
    let options = PipelineOptions {
        on_publish: Some(on_publish),
        ..PipelineOptions::new()
    };
    let pipeline =
        Pipeline::start(Box::new(sky), bench_settings(LIGHTS), options).expect("pipeline");
    let runtime = tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .thread_name("envlight-serve")
        .enable_all()
        .build()
        .expect("runtime");
    let socket_dir = tempfile::tempdir().expect("socket dir");
    let config = ServerConfig {
        unix_socket: (transport == Transport::Unix).then(|| socket_dir.path().join("bench.sock")),
        tcp: (transport == Transport::Tcp).then(|| "127.0.0.1:0".parse().expect("address")),
        websocket: None,
        max_clients: 100_000,
        pass_threads,
        ..ServerConfig::default()
    };
    let mut streams = Streams::new(pipeline.subscribe());
    if let Some(pass) = publisher_pass {
        streams = streams.with_publisher_pass(pass);
    }
    let server = runtime
        .block_on(StreamServer::start_streams(
            &config,
            streams,
            Arc::new(Metrics::new()),
        ))
        .expect("server");
    let endpoint = match transport {
        Transport::Tcp => Endpoint::Tcp(server.bound().tcp.expect("tcp").to_string()),
        Transport::Unix => Endpoint::Unix(server.bound().unix_socket.clone().expect("uds")),
    };
    let request = Request {
        format: Format::Binary,
        ..Request::default()
    };
    let deadline = Instant::now() + Duration::from_secs_f64(seconds + 1.0);
    let handles = start_clients(harness, decode, &endpoint, &request, clients, deadline);
    // Measure only while every client is connected: from one second in until the deadline.
    std::thread::sleep(Duration::from_secs(1));
    let newest = || {
        pipeline
            .subscribe()
            .borrow()
            .as_ref()
            .map_or(0, |p| p.payload.seq)
    };
    let first_seq = newest() + 2;
    let cpu_before = thread_stats();
    // The window ends a little before the clients stop (their threads must still be there
    // for their CPU time to be read).
    std::thread::sleep((deadline - WINDOW_END).saturating_duration_since(Instant::now()));
    let cpu_after = thread_stats();
    let last_seq = newest().saturating_sub(2);
    let received: Vec<_> = handles
        .into_iter()
        .flat_map(|h| h.join().expect("client"))
        .collect();
    pipeline.stop();
    runtime.block_on(server.shutdown("bench done", Duration::from_millis(200)));
    let _ = pipeline.join();
    let arrivals = arrivals.lock().unwrap();
    analyse(
        &arrivals,
        &received,
        first_seq,
        last_seq,
        (&cpu_before, &cpu_after),
    )
}

/// The harness floor: one plain thread writes a pre-encoded 256-light frame to every client
/// socket in turn (blocking writes, the daemon's socket options) at 60 frames/s. Publication
/// and arrival are both the moment before the first write.
fn run_floor(
    transport: Transport,
    (harness, decode): (Harness, Decode),
    clients: usize,
    seconds: f64,
) -> Run {
    let frame = sample_light_frame();
    let socket_dir = tempfile::tempdir().expect("socket dir");
    let defaults = ServerConfig::default();
    let send_buffer = defaults.send_buffer_bytes;
    let (endpoint, listener): (Endpoint, Box<dyn FnMut() -> Box<dyn Write + Send> + Send>) =
        match transport {
            Transport::Unix => {
                let path = socket_dir.path().join("floor.sock");
                let listener = std::os::unix::net::UnixListener::bind(&path).expect("bind uds");
                (
                    Endpoint::Unix(path),
                    Box::new(move || {
                        let (stream, _) = listener.accept().expect("accept uds");
                        if let Some(bytes) = send_buffer {
                            let _ = socket2::SockRef::from(&stream).set_send_buffer_size(bytes);
                        }
                        Box::new(stream)
                    }),
                )
            }
            Transport::Tcp => {
                let listener = std::net::TcpListener::bind("127.0.0.1:0").expect("bind tcp");
                let addr = listener.local_addr().expect("tcp address");
                (
                    Endpoint::Tcp(addr.to_string()),
                    Box::new(move || {
                        let (stream, _) = listener.accept().expect("accept tcp");
                        let _ = stream.set_nodelay(true);
                        if let Some(bytes) = send_buffer {
                            let _ = socket2::SockRef::from(&stream).set_send_buffer_size(bytes);
                        }
                        Box::new(stream)
                    }),
                )
            }
        };
    let arrivals: Arc<Mutex<HashMap<u64, Stamps>>> = Arc::default();
    let newest = Arc::new(AtomicU64::new(0));
    let deadline = Instant::now() + Duration::from_secs_f64(seconds + 1.0);
    let sender = {
        let arrivals = Arc::clone(&arrivals);
        let newest = Arc::clone(&newest);
        let mut accept = listener;
        std::thread::Builder::new()
            .name("bench sender".to_owned())
            .spawn(move || {
                let mut sockets: Vec<_> = (0..clients).map(|_| accept()).collect();
                let start = Instant::now();
                let mut out = Vec::new();
                for seq in 1u64.. {
                    let due = start + Duration::from_secs_f64(seq as f64 / 60.0);
                    if due >= deadline {
                        break;
                    }
                    std::thread::sleep(due.saturating_duration_since(Instant::now()));
                    let frame = LightFrame {
                        seq,
                        ..frame.clone()
                    };
                    out.clear();
                    encode_frame(&frame, None, false, &mut out);
                    let now = Instant::now();
                    arrivals
                        .lock()
                        .unwrap()
                        .insert(seq, (now, now, Duration::ZERO));
                    for socket in &mut sockets {
                        let _ = socket.write_all(&out);
                    }
                    newest.store(seq, Ordering::Release);
                }
            })
            .expect("sender thread")
    };
    let request = Request {
        format: Format::Binary,
        ..Request::default()
    };
    let handles = start_clients(harness, decode, &endpoint, &request, clients, deadline);
    std::thread::sleep(Duration::from_secs(1));
    let first_seq = newest.load(Ordering::Acquire) + 2;
    let cpu_before = thread_stats();
    // The window ends a little before the clients stop (their threads must still be there
    // for their CPU time to be read).
    std::thread::sleep((deadline - WINDOW_END).saturating_duration_since(Instant::now()));
    let cpu_after = thread_stats();
    let last_seq = newest.load(Ordering::Acquire).saturating_sub(2);
    sender.join().expect("sender");
    let received: Vec<_> = handles
        .into_iter()
        .flat_map(|h| h.join().expect("client"))
        .collect();
    let arrivals = arrivals.lock().unwrap();
    analyse(
        &arrivals,
        &received,
        first_seq,
        last_seq,
        (&cpu_before, &cpu_after),
    )
}

/// One decomposed sky frame (256 lights), the floor sender's payload.
fn sample_light_frame() -> LightFrame {
    let sky = render_sky(
        &SkyOptions {
            width: 256,
            height: 128,
            // The sky the documented figures were measured on (seed 0, the default until 2026-11-23).
            seed: 0,
            ..SkyOptions::default()
        },
        0.0,
    );
    let mut decomposer = Decomposer::new(bench_settings(LIGHTS)).expect("decomposer");
    decomposer.decompose(&sky)
}

fn bench_settings(lights: usize) -> DecomposeSettings {
    DecomposeSettings {
        lights,
        working_width: 128,
        ..DecomposeSettings::default()
    }
}

fn start_clients(
    harness: Harness,
    decode: Decode,
    endpoint: &Endpoint,
    request: &Request,
    clients: usize,
    deadline: Instant,
) -> Vec<std::thread::JoinHandle<Vec<Received>>> {
    match harness {
        Harness::Threads => thread_clients(endpoint, request, clients, deadline, decode),
        Harness::EventLoop => {
            vec![event_loop_clients(
                endpoint.clone(),
                request,
                clients,
                deadline,
                decode,
            )]
        }
    }
}

/// How the bench's clients read.
#[derive(Clone, Copy, Debug)]
enum Harness {
    /// One OS thread per client, blocking reads.
    Threads,
    /// All clients on one thread: a current-thread tokio runtime, one task per client (how a
    /// load generator reads many sockets; the server sees the same connections).
    EventLoop,
}

/// What writes the frames to the clients.
#[derive(Clone, Copy, Debug)]
enum Sender {
    /// The pipeline and the stream server: what is measured, with the fan-out pass on this
    /// thread, shared by this many threads (`stream.pass_threads`).
    Daemon(PassOn, usize),
    /// One plain thread writing a pre-encoded frame to every socket: the harness's floor.
    Floor,
}

impl Sender {
    fn name(self) -> String {
        let threads = |n: usize| match n {
            1 => String::new(),
            n => format!(", {n} pass threads"),
        };
        match self {
            Sender::Daemon(PassOn::Thread, n) => format!("daemon, fan-out thread{}", threads(n)),
            Sender::Daemon(PassOn::Publisher, n) => {
                format!("daemon, pass on publisher{}", threads(n))
            }
            Sender::Floor => "floor".to_owned(),
        }
    }
}

/// Which thread runs the daemon's fan-out pass of a light list.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum PassOn {
    /// The `envlight-fanout` thread, woken by the publication (`stream.fanout_on = "thread"`).
    Thread,
    /// The decompose thread, right after publishing ([`PublisherPass`]; the daemon's default).
    Publisher,
}

/// Lights per frame.
const LIGHTS: usize = 256;

/// One spinning `SCHED_IDLE` thread per CPU while it lives (`--spin-idle=on`, module doc).
struct IdleSpinners {
    stop: Arc<std::sync::atomic::AtomicBool>,
    threads: Vec<std::thread::JoinHandle<()>>,
}

impl IdleSpinners {
    /// Starts the spinners; panics (this is a bench) if the policy or the pinning is refused.
    fn start() -> Self {
        let stop = Arc::new(std::sync::atomic::AtomicBool::new(false));
        // The CPUs this process may run on (not necessarily 0..n).
        // SAFETY: `allowed` is a zeroed cpu_set_t of the size passed; pid 0 is this thread.
        let cpus: Vec<usize> = unsafe {
            let mut allowed: libc::cpu_set_t = std::mem::zeroed();
            let got = libc::sched_getaffinity(0, std::mem::size_of_val(&allowed), &mut allowed);
            assert_eq!(got, 0, "sched_getaffinity");
            (0..libc::CPU_SETSIZE as usize)
                .filter(|&cpu| libc::CPU_ISSET(cpu, &allowed))
                .collect()
        };
        let threads = cpus
            .into_iter()
            .map(|cpu| {
                let stop = Arc::clone(&stop);
                std::thread::Builder::new()
                    .name("bench idle spin".into())
                    .spawn(move || {
                        // SAFETY: plain libc calls on this thread (pid 0) with initialised
                        // arguments; `set` is a valid cpu_set_t for CPU_SET.
                        unsafe {
                            let mut set: libc::cpu_set_t = std::mem::zeroed();
                            libc::CPU_SET(cpu, &mut set);
                            let pinned =
                                libc::sched_setaffinity(0, std::mem::size_of_val(&set), &set);
                            assert_eq!(pinned, 0, "pinning a spinner to CPU {cpu}");
                            let param = libc::sched_param { sched_priority: 0 };
                            let idle = libc::sched_setscheduler(0, libc::SCHED_IDLE, &param);
                            assert_eq!(idle, 0, "SCHED_IDLE for the spinner of CPU {cpu}");
                        }
                        while !stop.load(Ordering::Relaxed) {
                            std::hint::spin_loop();
                        }
                    })
                    .expect("spinner thread")
            })
            .collect();
        // Let them reach their CPUs before the row starts.
        std::thread::sleep(Duration::from_millis(200));
        IdleSpinners { stop, threads }
    }
}

impl Drop for IdleSpinners {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
    }
}

/// How the clients decode what they read (`--decode=`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Decode {
    /// In place from the read buffer, the light lists recycled (the default).
    InPlace,
    /// Each read copied into the decoder's buffer first.
    Buffered,
}

/// Decodes the frames of one read as a client does (`decode`); each frame's seq goes to
/// `received` with the read's stamp `at`.
fn decode_read(
    decoder: &mut Decoder,
    bytes: &[u8],
    at: Instant,
    received: &mut Received,
    decode: Decode,
) {
    if decode == Decode::Buffered {
        decoder.push(bytes);
        while let Ok(Some(message)) = decoder.next_message() {
            if let Message::Frame(frame) = message {
                received.push((frame.seq, at));
            }
        }
        return;
    }
    let mut input = bytes;
    while let Ok(Some(message)) = decoder.next_from(&mut input) {
        if let Message::Frame(frame) = message {
            received.push((frame.seq, at));
            decoder.recycle(frame.lights);
        }
    }
}

/// A connected client socket of either transport.
trait ClientStream: tokio::io::AsyncRead + tokio::io::AsyncWrite + Unpin + Send {}
impl<T: tokio::io::AsyncRead + tokio::io::AsyncWrite + Unpin + Send> ClientStream for T {}

/// Which endpoint the clients connect to.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Transport {
    /// The Unix domain socket (the default endpoint, for clients on the rig).
    Unix,
    /// TCP over loopback.
    Tcp,
}

/// The built-in sky, 256×128, rendered once for one second of frames (the sun and clouds move)
/// and replayed at `fps` from memory, forwards and back (0, 1, …, 59, 58, …, 1), so the sky
/// moves on continuously as a camera's would (jumping back from the last frame to the first
/// moved the sun 2° in one frame, which made the decomposition rebuild its candidate lists in
/// full once a second: docs/performance.md, "Staged rebuilds"). Rendering the analytic sky
/// live costs about a third of the 2 cores at 60 frames/s, which a camera's capture thread
/// does not; replaying keeps the capture stage from competing with what is measured.
struct PrerenderedSky {
    frames: Vec<HdrFrame>,
    fps: f64,
    seq: u64,
    start: Option<Instant>,
}

impl PrerenderedSky {
    fn new(fps: f64) -> Self {
        let options = SkyOptions {
            width: 256,
            height: 128,
            // The sky the documented figures were measured on (seed 0, the default until 2026-11-23).
            seed: 0,
            ..SkyOptions::default()
        };
        let frames = (0..fps as usize)
            .map(|i| render_sky(&options, i as f64 / fps))
            .collect();
        Self {
            frames,
            fps,
            seq: 0,
            start: None,
        }
    }
}

impl FrameSource for PrerenderedSky {
    fn next_frame(&mut self) -> Result<Option<HdrFrame>, CaptureError> {
        let start = *self.start.get_or_insert_with(Instant::now);
        let due = Duration::from_secs_f64(self.seq as f64 / self.fps);
        let elapsed = start.elapsed();
        if due > elapsed {
            std::thread::sleep(due - elapsed);
        }
        let n = self.frames.len();
        let k = self.seq as usize % (2 * n - 2).max(1);
        let mut frame = self.frames[if k < n { k } else { 2 * n - 2 - k }].clone();
        frame.seq = self.seq;
        self.seq += 1;
        Ok(Some(frame))
    }

    fn describe(&self) -> String {
        "pre-rendered built-in sky".to_owned()
    }
}

/// Frames (seq, moment the frame's last byte was read) received by each client.
type Received = Vec<(u64, Instant)>;

fn thread_clients(
    endpoint: &Endpoint,
    request: &Request,
    clients: usize,
    deadline: Instant,
    decode: Decode,
) -> Vec<std::thread::JoinHandle<Vec<Received>>> {
    let mut subscribe = Vec::new();
    encode_request(request, &mut subscribe);
    (0..clients)
        .map(|_| {
            let mut stream: Box<dyn std::io::Read + Send> = match endpoint {
                Endpoint::Unix(path) => {
                    let mut s = std::os::unix::net::UnixStream::connect(path).expect("uds");
                    s.set_read_timeout(Some(READ_TIMEOUT)).expect("timeout");
                    s.write_all(&subscribe).expect("subscribe");
                    Box::new(s)
                }
                Endpoint::Tcp(addr) => {
                    let mut s = std::net::TcpStream::connect(addr.as_str()).expect("tcp");
                    s.set_nodelay(true).expect("nodelay");
                    s.set_read_timeout(Some(READ_TIMEOUT)).expect("timeout");
                    s.write_all(&subscribe).expect("subscribe");
                    Box::new(s)
                }
                Endpoint::WebSocket(_) => unreachable!("the bench serves TCP and UDS"),
            };
            std::thread::Builder::new()
                .name("bench client".to_owned())
                .stack_size(256 * 1024)
                .spawn(move || {
                    // As the event loop: the stamp is taken when the read that completes a
                    // frame returns, before the frame is decoded (decoded in full all the same).
                    let mut received = Vec::new();
                    let mut decoder = Decoder::new();
                    let mut buf = vec![0u8; 64 * 1024];
                    while Instant::now() < deadline {
                        let n = match stream.read(&mut buf) {
                            Ok(0) | Err(_) => break,
                            Ok(n) => n,
                        };
                        let at = Instant::now();
                        decode_read(&mut decoder, &buf[..n], at, &mut received, decode);
                    }
                    vec![received]
                })
                .expect("client thread")
        })
        .collect()
}

fn event_loop_clients(
    endpoint: Endpoint,
    request: &Request,
    clients: usize,
    deadline: Instant,
    decode: Decode,
) -> std::thread::JoinHandle<Vec<Received>> {
    let mut subscribe = Vec::new();
    encode_request(request, &mut subscribe);
    let (ready_tx, ready_rx) = std::sync::mpsc::sync_channel(1);
    let handle = std::thread::Builder::new()
        .name("bench clients".to_owned())
        .spawn(move || {
            let runtime = tokio::runtime::Builder::new_current_thread()
                .enable_all()
                .build()
                .expect("client runtime");
            runtime.block_on(async move {
                let mut streams = Vec::new();
                for _ in 0..clients {
                    let mut stream: Box<dyn ClientStream> = match &endpoint {
                        Endpoint::Tcp(addr) => {
                            let stream = tokio::net::TcpStream::connect(addr).await.expect("tcp");
                            stream.set_nodelay(true).expect("nodelay");
                            Box::new(stream)
                        }
                        Endpoint::Unix(path) => {
                            Box::new(tokio::net::UnixStream::connect(path).await.expect("uds"))
                        }
                        Endpoint::WebSocket(_) => unreachable!("the bench serves TCP and UDS"),
                    };
                    stream.write_all(&subscribe).await.expect("subscribe");
                    streams.push(stream);
                }
                ready_tx.send(()).expect("ready");
                let tasks: Vec<_> = streams
                    .into_iter()
                    .map(|mut stream| {
                        tokio::spawn(async move {
                            let mut received = Vec::new();
                            let mut decoder = Decoder::new();
                            let mut buf = vec![0u8; 64 * 1024];
                            let until = tokio::time::Instant::from_std(deadline);
                            loop {
                                let read = tokio::time::timeout_at(until, stream.read(&mut buf));
                                let Ok(Ok(n)) = read.await else { break };
                                if n == 0 {
                                    break;
                                }
                                let at = Instant::now();
                                decode_read(&mut decoder, &buf[..n], at, &mut received, decode);
                            }
                            received
                        })
                    })
                    .collect();
                let mut all = Vec::new();
                for task in tasks {
                    all.push(task.await.expect("client task"));
                }
                all
            })
        })
        .expect("client thread");
    ready_rx.recv().expect("clients connected");
    handle
}

fn percentile(sorted: &[Duration], p: f64) -> Duration {
    if sorted.is_empty() {
        return Duration::ZERO;
    }
    let i = ((sorted.len() - 1) as f64 * p).round() as usize;
    sorted[i]
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let quick = args.iter().any(|a| a == "--quick");
    let option = |name: &str| {
        args.iter()
            .find_map(|a| a.strip_prefix(name).map(str::to_owned))
    };
    let harnesses: Vec<Harness> = match option("--harness=").as_deref() {
        Some("events") => vec![Harness::EventLoop],
        Some("both") => vec![Harness::Threads, Harness::EventLoop],
        None | Some("threads") => vec![Harness::Threads],
        Some(other) => panic!("--harness=threads|events|both, not {other}"),
    };
    let transports: Vec<Transport> = match option("--transport=").as_deref() {
        Some("uds") => vec![Transport::Unix],
        Some("tcp") => vec![Transport::Tcp],
        None | Some("both") => vec![Transport::Unix, Transport::Tcp],
        Some(other) => panic!("--transport=uds|tcp|both, not {other}"),
    };
    // As the daemon by default: the pass on the decompose thread.
    let daemon_passes: Vec<PassOn> = match option("--fanout=").as_deref() {
        Some("thread") => vec![PassOn::Thread],
        Some("both") => vec![PassOn::Thread, PassOn::Publisher],
        None | Some("publisher") => vec![PassOn::Publisher],
        Some(other) => panic!("--fanout=publisher|thread|both, not {other}"),
    };
    let pass_threads: Vec<usize> = match option("--pass-threads=") {
        Some(list) => list
            .split(',')
            .map(|n| n.parse().expect("--pass-threads=N,M,…"))
            .collect(),
        None => vec![ServerConfig::default().pass_threads],
    };
    let daemons = daemon_passes.iter().flat_map(|&p| {
        pass_threads
            .iter()
            .map(move |&threads| Sender::Daemon(p, threads))
    });
    // Each repeat runs every sender once, back to back (A/B pairs on a noisy machine).
    let senders: Vec<Sender> = match option("--sender=").as_deref() {
        Some("floor") => vec![Sender::Floor],
        Some("both") => daemons.chain([Sender::Floor]).collect(),
        None | Some("daemon") => daemons.collect(),
        Some(other) => panic!("--sender=daemon|floor|both, not {other}"),
    };
    let counts: Vec<usize> = match option("--clients=") {
        Some(list) => list
            .split(',')
            .map(|n| n.parse().expect("--clients=N,M,…"))
            .collect(),
        None if quick => vec![64, 256],
        None => vec![1, 64, 128, 256, 512, 1024],
    };
    let seconds = match option("--seconds=") {
        Some(s) => s.parse().expect("--seconds=S"),
        None if quick => 3.0,
        None => 10.0,
    };
    let repeat: usize = option("--repeat=").map_or(1, |n| n.parse().expect("--repeat=N"));
    let decodes = match option("--decode=").as_deref() {
        Some("buffered") => vec![Decode::Buffered],
        Some("both") => vec![Decode::InPlace, Decode::Buffered],
        None | Some("in-place") => vec![Decode::InPlace],
        Some(other) => panic!("--decode=in-place|buffered|both, not {other}"),
    };
    let spin_modes: Vec<bool> = match option("--spin-idle=").as_deref() {
        Some("on") => vec![true],
        Some("both") => vec![false, true],
        None | Some("off") => vec![false],
        Some(other) => panic!("--spin-idle=off|on|both, not {other}"),
    };
    println!("stream latency: sky 256x128 at 60 frames/s, 256 lights, binary frames");
    println!(
        "arrival at the decomposition → last byte at a client (end to end), and its two parts; \
         CPU per frame: serving threads / all client threads"
    );
    for transport in transports {
        for &harness in &harnesses {
            println!();
            println!("endpoint: {transport:?}; clients: {harness:?}");
            println!(
                "| sender | clients | frames | decompose p50 | fan-out p50 | fan-out p99 | end-to-end p50 | end-to-end p99 | end-to-end max | clients with loss | frames missed | first copy p50 | first→last p50 | first→last p99 | decompose CPU/frame | serve CPU/frame | client CPU/frame | decompose wait/frame | serve wait/frame | serve preempted/frame | load |"
            );
            println!(
                "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|"
            );
            for &clients in &counts {
                for _ in 0..repeat {
                    for ((&sender, &decode), &spin) in senders
                        .iter()
                        .flat_map(|s| decodes.iter().map(move |d| (s, d)))
                        .flat_map(|sd| spin_modes.iter().map(move |m| (sd, m)))
                    {
                        let client_setup = (harness, decode);
                        let spinners = spin.then(IdleSpinners::start);
                        let r = match sender {
                            Sender::Daemon(pass_on, threads) => {
                                run(transport, client_setup, clients, seconds, pass_on, threads)
                            }
                            Sender::Floor => run_floor(transport, client_setup, clients, seconds),
                        };
                        drop(spinners);
                        let lossy = r.missed.iter().filter(|&&m| m > 0).count();
                        let missed: u64 = r.missed.iter().sum();
                        let ms = |d: Duration| d.as_secs_f64() * 1e3;
                        println!(
                            "| {}{}{} | {clients} | {} | {:.3} | {:.3} | {:.3} | {:.3} | {:.3} | {:.3} | {lossy} | {missed} | {:.3} | {:.3} | {:.3} | {:.3} | {:.3} | {:.3} | {:.3} | {:.3} | {:.1} | {} |",
                            sender.name(),
                            if decode == Decode::Buffered {
                                ", buffered decode"
                            } else {
                                ""
                            },
                            if spin { ", idle CPUs spinning" } else { "" },
                            r.published,
                            ms(percentile(&r.decompose, 0.5)),
                            ms(percentile(&r.fan_out, 0.5)),
                            ms(percentile(&r.fan_out, 0.99)),
                            ms(percentile(&r.latencies, 0.5)),
                            ms(percentile(&r.latencies, 0.99)),
                            ms(percentile(&r.latencies, 1.0)),
                            ms(percentile(&r.first_copy, 0.5)),
                            ms(percentile(&r.spread, 0.5)),
                            ms(percentile(&r.spread, 0.99)),
                            ms(r.decompose_cpu),
                            ms(r.serve_cpu),
                            ms(r.client_cpu),
                            ms(r.decompose_wait),
                            ms(r.serve_wait),
                            r.serve_preempted,
                            load_average(),
                        );
                    }
                }
            }
        }
    }
}
