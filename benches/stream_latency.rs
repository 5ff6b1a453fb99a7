//! Stream latency benchmark: time from a frame's arrival at the decomposition to the last byte of
//! its light list read by a client, with many clients at 60 frames/s; and the largest client
//! count served at 60 frames/s without loss for clients that keep up.
//!
//! Not a criterion benchmark (latency percentiles under a paced load are not what criterion
//! measures); run it with `cargo bench --bench stream_latency` (add `-- --quick` for a short
//! run). The whole chain runs in this process so one clock serves both ends: the built-in sky
//! at 60 frames/s → pipeline (256 lights) → stream server (TCP, binary frames) → N client
//! threads, each reading with blocking I/O and stamping the moment a frame is complete.

use envlight::capture::sky::{SkyOptions, SkySource};
use envlight::decompose::DecomposeSettings;
use envlight::metrics::Metrics;
use envlight::pipeline::{Pipeline, PipelineOptions, PublishHook};
use envlight::stream::client::{Client, Endpoint};
use envlight::stream::{Format, Message, Request, ServerConfig, StreamServer};
use std::collections::HashMap;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

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

fn run(clients: usize, seconds: f64, lights: usize) -> Run {
    let sky = SkySource::new(SkyOptions {
        width: 256,
        height: 128,
        fps: Some(60.0),
        frames: None,
        ..SkyOptions::default()
    })
    .expect("sky");
    let arrivals: Arc<Mutex<HashMap<u64, Stamps>>> = Arc::default();
    let hook_arrivals = Arc::clone(&arrivals);
    let options = PipelineOptions {
        on_publish: Some(PublishHook(Arc::new(move |published| {
            if let Some(arrived) = published.arrived {
                hook_arrivals.lock().unwrap().insert(
                    published.lights.seq,
                    (arrived, published.published_at, published.decompose_time),
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
    let config = ServerConfig {
        unix_socket: None,
        tcp: "127.0.0.1:0".parse().ok(),
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
    let endpoint = Endpoint::Tcp(server.bound().tcp.expect("tcp").to_string());
    let request = Request {
        format: Format::Binary,
        ..Request::default()
    };
    let deadline = Instant::now() + Duration::from_secs_f64(seconds + 1.0);
    let handles: Vec<_> = (0..clients)
        .map(|_| {
            let mut client = Client::connect(&endpoint, &request, Some(Duration::from_secs(10)))
                .expect("connect");
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
                    received
                })
                .expect("client thread")
        })
        .collect();
    // Measure only while every client is connected: from one second in until the deadline.
    std::thread::sleep(Duration::from_secs(1));
    let first_seq = pipeline
        .subscribe()
        .borrow()
        .as_ref()
        .map_or(0, |p| p.lights.seq)
        + 2;
    std::thread::sleep(deadline.saturating_duration_since(Instant::now()));
    let last_seq = pipeline
        .subscribe()
        .borrow()
        .as_ref()
        .map_or(0, |p| p.lights.seq)
        .saturating_sub(2);
    let received: Vec<_> = handles
        .into_iter()
        .map(|h| h.join().expect("client"))
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

fn percentile(sorted: &[Duration], p: f64) -> Duration {
    if sorted.is_empty() {
        return Duration::ZERO;
    }
    let i = ((sorted.len() - 1) as f64 * p).round() as usize;
    sorted[i]
}

fn main() {
    let quick = std::env::args().any(|a| a == "--quick");
    let seconds = if quick { 3.0 } else { 10.0 };
    println!("stream latency: sky 256x128 at 60 frames/s, 256 lights, TCP binary frames");
    println!(
        "arrival at the decomposition → last byte at a client (end to end), and its two parts"
    );
    println!(
        "| clients | frames | decompose p50 | fan-out p50 | fan-out p99 | end-to-end p50 | end-to-end p99 | end-to-end max | clients with loss | frames missed |"
    );
    println!("|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|");
    let counts: &[usize] = if quick {
        &[64, 256]
    } else {
        &[1, 64, 128, 256, 512, 1024]
    };
    for &clients in counts {
        let r = run(clients, seconds, 256);
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
