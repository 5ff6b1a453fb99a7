//! Stream latency benchmark: time from a frame's arrival at the decomposition to the last byte of
//! its light list read by a client, with many clients at 60 frames/s; and the largest client
//! count served at 60 frames/s without loss for clients that keep up.
//!
//! Not a criterion benchmark (latency percentiles under a paced load are not what criterion
//! measures); run it with `cargo bench --bench stream_latency` (add `-- --quick` for a short
//! run). The whole chain runs in this process so one clock serves both ends: the built-in sky
//! at 60 frames/s → pipeline (256 lights) → stream server (TCP, binary frames) → N client
//! threads, each reading with blocking I/O and stamping the moment a frame is complete.

use envlight::capture::sky::{render_sky, SkyOptions};
use envlight::capture::{CaptureError, FrameSource};
use envlight::decompose::DecomposeSettings;
use envlight::metrics::Metrics;
use envlight::pipeline::{Pipeline, PipelineOptions, PublishHook};
use envlight::stream::client::{Client, Endpoint};
use envlight::stream::protocol::encode_request;
use envlight::stream::{Decoder, Format, Message, Request, ServerConfig, StreamServer};
use envlight::HdrFrame;
use std::collections::HashMap;
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
}

fn run(transport: Transport, harness: Harness, clients: usize, seconds: f64, lights: usize) -> Run {
    let sky = PrerenderedSky::new(60.0);
    let arrivals: Arc<Mutex<HashMap<u64, Stamps>>> = Arc::default();
    let hook_arrivals = Arc::clone(&arrivals);
    let options = PipelineOptions {
        on_publish: Some(PublishHook(Arc::new(move |published| {
            if let Some(arrived) = published.arrived {
                hook_arrivals.lock().unwrap().insert(
                    published.payload.seq,
                    (arrived, published.published_at, published.compute_time),
                );
            }
        }))),
        ..PipelineOptions::new()
    };
    let settings = DecomposeSettings {
        lights,
        working_width: 128,
        ..DecomposeSettings::default()
    };
    let pipeline = Pipeline::start(Box::new(sky), settings, options).expect("pipeline");
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
        ..ServerConfig::default()
    };
    let server = runtime
        .block_on(StreamServer::start(
            &config,
            pipeline.subscribe(),
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
    let handles = match harness {
        Harness::Threads => thread_clients(&endpoint, &request, clients, deadline),
        Harness::EventLoop => {
            vec![event_loop_clients(
                endpoint.clone(),
                &request,
                clients,
                deadline,
            )]
        }
    };
    // Measure only while every client is connected: from one second in until the deadline.
    std::thread::sleep(Duration::from_secs(1));
    let first_seq = pipeline
        .subscribe()
        .borrow()
        .as_ref()
        .map_or(0, |p| p.payload.seq)
        + 2;
    std::thread::sleep(deadline.saturating_duration_since(Instant::now()));
    let last_seq = pipeline
        .subscribe()
        .borrow()
        .as_ref()
        .map_or(0, |p| p.payload.seq)
        .saturating_sub(2);
    let received: Vec<_> = handles
        .into_iter()
        .flat_map(|h| h.join().expect("client"))
        .collect();
    pipeline.stop();
    runtime.block_on(server.shutdown("bench done", Duration::from_millis(200)));
    let _ = pipeline.join();
    let arrivals = arrivals.lock().unwrap();
    let mut latencies = Vec::new();
    let mut fan_out = Vec::new();
    let mut missed = Vec::new();
    let mut decompose: Vec<Duration> = (first_seq..=last_seq)
        .filter_map(|seq| arrivals.get(&seq).map(|a| a.2))
        .collect();
    decompose.sort();
    for frames in &received {
        let mut seen = 0u64;
        for &(seq, at) in frames {
            if (first_seq..=last_seq).contains(&seq) {
                seen += 1;
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
    Run {
        latencies,
        fan_out,
        decompose,
        published: (last_seq + 1).saturating_sub(first_seq),
        missed,
    }
}

/// How the bench's clients read.
#[derive(Clone, Copy, Debug)]
enum Harness {
    /// One OS thread per client, blocking reads (`envlight::stream::client::Client`).
    Threads,
    /// All clients on one thread: a current-thread tokio runtime, one task per client (how a
    /// load generator reads many sockets; the server sees the same connections).
    EventLoop,
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
/// and replayed at `fps` from memory. Rendering the analytic sky live costs about a third of
/// the 2 cores at 60 frames/s, which a camera's capture thread does not; replaying keeps the
/// capture stage from competing with what is measured.
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
        let mut frame = self.frames[self.seq as usize % self.frames.len()].clone();
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
) -> Vec<std::thread::JoinHandle<Vec<Received>>> {
    (0..clients)
        .map(|_| {
            let mut client =
                Client::connect(endpoint, request, Some(Duration::from_secs(10))).expect("connect");
            std::thread::Builder::new()
                .name("bench client".to_owned())
                .stack_size(256 * 1024)
                .spawn(move || {
                    let mut received = Vec::new();
                    while Instant::now() < deadline {
                        match client.next_message() {
                            Ok(Some(Message::Frame(frame))) => {
                                received.push((frame.seq, Instant::now()))
                            }
                            _ => break,
                        }
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
                                decoder.push(&buf[..n]);
                                let at = Instant::now();
                                while let Ok(Some(message)) = decoder.next_message() {
                                    if let Message::Frame(frame) = message {
                                        received.push((frame.seq, at));
                                    }
                                }
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
        _ => vec![Harness::Threads],
    };
    let transports: Vec<Transport> = match option("--transport=").as_deref() {
        Some("uds") => vec![Transport::Unix],
        Some("tcp") => vec![Transport::Tcp],
        _ => vec![Transport::Unix, Transport::Tcp],
    };
    let counts: Vec<usize> = match option("--clients=") {
        Some(list) => list
            .split(',')
            .map(|n| n.parse().expect("--clients=N,M,…"))
            .collect(),
        None if quick => vec![64, 256],
        None => vec![1, 64, 128, 256, 512, 1024],
    };
    let seconds = if quick { 3.0 } else { 10.0 };
    println!("stream latency: sky 256x128 at 60 frames/s, 256 lights, binary frames");
    println!(
        "arrival at the decomposition → last byte at a client (end to end), and its two parts"
    );
    for transport in transports {
        for &harness in &harnesses {
            println!();
            println!("endpoint: {transport:?}; clients: {harness:?}");
            println!(
                "| clients | frames | decompose p50 | fan-out p50 | fan-out p99 | end-to-end p50 | end-to-end p99 | end-to-end max | clients with loss | frames missed |"
            );
            println!("|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
            for &clients in &counts {
                let r = run(transport, harness, clients, seconds, 256);
                let lossy = r.missed.iter().filter(|&&m| m > 0).count();
                let missed: u64 = r.missed.iter().sum();
                let ms = |d: Duration| d.as_secs_f64() * 1e3;
                println!(
                    "| {clients} | {} | {:.3} | {:.3} | {:.3} | {:.3} | {:.3} | {:.3} | {lossy} | {missed} |",
                    r.published,
                    ms(percentile(&r.decompose, 0.5)),
                    ms(percentile(&r.fan_out, 0.5)),
                    ms(percentile(&r.fan_out, 0.99)),
                    ms(percentile(&r.latencies, 0.5)),
                    ms(percentile(&r.latencies, 0.99)),
                    ms(percentile(&r.latencies, 1.0)),
                );
            }
        }
    }
}
