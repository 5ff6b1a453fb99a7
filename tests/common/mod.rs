//! Helpers shared by the daemon's end-to-end tests (tests/daemon.rs, tests/asg_stream.rs,
//! tests/wavelet_stream.rs): configs on loopback port 0, waiting with a deadline, named client
//! threads, the metrics endpoint, a short recorded sky session, and a daemon whose render thread
//! has drawn a few frames.

// Each test binary uses its own subset of these helpers.
#![allow(dead_code)]

use envlight::config::{Config, RawConfig};
use envlight::daemon::{Daemon, DaemonOptions};
use std::io::{Read, Write};
use std::net::TcpStream;
use std::path::Path;
use std::time::{Duration, Instant};

/// A cheap live source for the daemon tests: the built-in sky at 32×16, endless at 30
/// frames/s, decomposed into 8 lights.
pub const SMALL_SKY: &str = "[source]\nfps = 30.0\nframes = 0\n[sky]\nwidth = 32\nheight = 16\n\
                             [decompose]\nlights = 8\nworking_width = 16\n";

/// How long a test waits for anything (a frame, a thread, an HTTP answer) before failing.
pub const TIMEOUT: Duration = Duration::from_secs(30);

/// Starts the daemon of `config`, whose render thread writes `png` (`render.latest_png`),
/// waits until it has rendered three frames and returns it with the newest image. A daemon
/// that cannot start fails with the install hint for a graphics adapter.
pub fn render_three_frames(config: Config, png: &Path) -> (Daemon, image::RgbaImage) {
    let daemon = Daemon::start(config, DaemonOptions::default()).unwrap_or_else(|e| {
        panic!(
            "the render thread needs a graphics adapter; without a GPU install Mesa's \
             lavapipe (apt-get install mesa-vulkan-drivers libvulkan1): {e}"
        )
    });
    let http = daemon.addresses().metrics.unwrap();
    wait_until("rendered frames", || {
        let text = http_get(http, "/metrics").1;
        metric_value(&text, "envlight_frames_rendered_total") >= 3.0
    });
    let image = image::open(png).unwrap().to_rgba8();
    (daemon, image)
}

/// Starts a named thread (clippy bans unnamed ones).
pub fn spawn<T: Send + 'static>(
    name: &str,
    f: impl FnOnce() -> T + Send + 'static,
) -> std::thread::JoinHandle<T> {
    std::thread::Builder::new()
        .name(name.to_owned())
        .spawn(f)
        .unwrap()
}

/// A config from TOML text `extra` with every endpoint on loopback port 0 or in `dir`, the
/// given handshake timeout, and metrics on.
pub fn config(dir: &Path, handshake_timeout_s: f64, extra: &str) -> Config {
    config_with_stream(dir, handshake_timeout_s, "", extra)
}

/// As [`config`], with more `[stream]` keys (TOML lines) in `stream`.
pub fn config_with_stream(
    dir: &Path,
    handshake_timeout_s: f64,
    stream: &str,
    extra: &str,
) -> Config {
    let text = format!(
        "[stream]\nunix_socket = \"{}\"\ntcp = \"127.0.0.1:0\"\nwebsocket = \"127.0.0.1:0\"\n\
         handshake_timeout_s = {handshake_timeout_s:?}\n{stream}[metrics]\nlisten = \"127.0.0.1:0\"\n\
         {extra}",
        dir.join("envlight.sock").display()
    );
    RawConfig::parse(&text, Path::new("test.toml"))
        .unwrap()
        .validate()
        .unwrap()
}

/// Polls `done` every 5 ms until it holds; fails after [`TIMEOUT`].
pub fn wait_until(what: &str, mut done: impl FnMut() -> bool) {
    let deadline = Instant::now() + TIMEOUT;
    while !done() {
        assert!(Instant::now() < deadline, "timed out waiting for {what}");
        std::thread::sleep(Duration::from_millis(5));
    }
}

/// A plain HTTP/1.1 GET: (status, body).
pub fn http_get(addr: std::net::SocketAddr, path: &str) -> (u16, String) {
    let (status, _, body) = http_request(addr, "GET", path);
    (status, body)
}

/// A plain HTTP/1.1 request: (status, header lines in lower case, body).
pub fn http_request(addr: std::net::SocketAddr, method: &str, path: &str) -> (u16, String, String) {
    let mut stream = TcpStream::connect(addr).unwrap();
    stream.set_read_timeout(Some(TIMEOUT)).unwrap();
    write!(
        stream,
        "{method} {path} HTTP/1.1\r\nHost: x\r\nConnection: close\r\n\r\n"
    )
    .unwrap();
    let mut text = String::new();
    stream.read_to_string(&mut text).unwrap();
    let status = text[9..12].parse().unwrap();
    let (head, body) = text.split_once("\r\n\r\n").unwrap_or((&text, ""));
    (status, head.to_lowercase(), body.to_owned())
}

/// The value of the unlabelled metric `name` in Prometheus text.
pub fn metric_value(text: &str, name: &str) -> f64 {
    text.lines()
        .find_map(|l| l.strip_prefix(name)?.strip_prefix(' ')?.parse().ok())
        .unwrap_or_else(|| panic!("no {name} in\n{text}"))
}

/// The daemon of `config` replaying `recording` at its original timing (so that clients
/// connected right after the start see it from its first frames).
pub fn start_replay(
    config: envlight::config::Config,
    recording: &Path,
) -> envlight::daemon::Daemon {
    let options = envlight::daemon::DaemonOptions {
        replay: Some((recording.to_path_buf(), envlight::record::Pacing::Original)),
        record: None,
        source_paths: None,
    };
    envlight::daemon::Daemon::start(config, options).unwrap()
}

/// Records `frames` small sky frames (64×32; frame times 1/30 s apart) into `dir` with no
/// stage but the decomposition; returns how many were recorded: all, since the sky is made as
/// fast as possible (no `fps`), so capture waits for the decomposition. (Paced at 30 fps, a
/// starved CI machine once dropped 2 of 12, and the SH test, which took the seqs to be
/// 0..n, failed.)
pub fn record_sky(dir: &Path, frames: u64) -> u64 {
    let none =
        "[stream]\nunix_socket = \"\"\ntcp = \"\"\nwebsocket = \"\"\n[metrics]\nlisten = \"\"\n";
    let text = format!(
        "{none}[source]\nframes = {frames}\n[sky]\nwidth = 64\nheight = 32\n\
         sun_speed_deg_per_s = 30.0\n[decompose]\nlights = 16\nworking_width = 32\n"
    );
    let config = RawConfig::parse(&text, Path::new("t.toml"))
        .unwrap()
        .validate()
        .unwrap();
    record_to_the_end(config, dir, None)
        .recorded
        .unwrap()
        .frames
}

/// Runs a daemon on `config` (its source replaced by the INPUT files `source_paths`, if
/// given), recording into `recording`, until its source ends; returns its summary.
pub fn record_to_the_end(
    config: Config,
    recording: &Path,
    source_paths: Option<Vec<String>>,
) -> envlight::daemon::DaemonSummary {
    let daemon = Daemon::start(
        config,
        DaemonOptions {
            replay: None,
            record: Some(recording.to_path_buf()),
            source_paths,
        },
    )
    .unwrap();
    wait_until("the source's end", || daemon.source_finished());
    daemon.shutdown().unwrap()
}

/// Fails the test with an install hint when python3 is missing (the example client is tested,
/// not skipped).
pub fn require_python3() {
    let found = std::process::Command::new("python3")
        .arg("--version")
        .output()
        .is_ok_and(|o| o.status.success());
    assert!(
        found,
        "python3 is not installed; the example client's tests need it \
         (Debian: apt-get install python3, as .ci/run does)"
    );
}

/// Runs `examples/client.py` with `args`, asserts it exited successfully and returns its
/// stdout lines.
pub fn python_client(args: &[&str]) -> Vec<String> {
    let out = std::process::Command::new("python3")
        .arg("examples/client.py")
        .args(args)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "client.py {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout)
        .lines()
        .map(str::to_owned)
        .collect()
}

/// [`python_client`] with `args` reading binary frames, then JSON lines (`--json`): each
/// form's name and stdout lines.
pub fn python_client_both_forms(args: &[&str]) -> [(&'static str, Vec<String>); 2] {
    let json: Vec<&str> = args.iter().copied().chain(["--json"]).collect();
    [
        ("binary", python_client(args)),
        ("json", python_client(&json)),
    ]
}

/// Runs a Python `script` (`python3 -c`), asserts it exited successfully and returns its
/// stdout.
pub fn python_script(script: &str) -> String {
    let out = std::process::Command::new("python3")
        .args(["-c", script])
        .output()
        .unwrap();
    let (text, err) = (
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr),
    );
    assert!(out.status.success(), "{text}{err}");
    text.into_owned()
}

/// Asserts that the daemon at `tcp` answers a subscription to `representation` (binary and
/// JSON) with error 6 whose message contains `hint` (the config section that enables it).
pub fn assert_unsupported(
    tcp: std::net::SocketAddr,
    representation: envlight::stream::Representation,
    hint: &str,
) {
    use envlight::stream::client::{Client, Endpoint};
    use envlight::stream::protocol::code;
    use envlight::stream::{Format, Message, Request};
    for format in [Format::Binary, Format::Json] {
        let request = Request {
            representation,
            format,
            ..Request::default()
        };
        let mut client =
            Client::connect(&Endpoint::Tcp(tcp.to_string()), &request, Some(TIMEOUT)).unwrap();
        match client.next_message().unwrap() {
            Some(Message::Error { code: c, message }) => {
                assert_eq!(c, code::UNSUPPORTED_REPRESENTATION);
                assert!(message.contains(hint), "{message}");
            }
            other => panic!("expected error 6, got {other:?}"),
        }
    }
}

/// A test client's subscription: where, in which format, with which cap (0: no cap).
pub type Subscription = (
    envlight::stream::client::Endpoint,
    envlight::stream::Format,
    u32,
);

/// One client of each transport and both formats — UDS binary, TCP JSON, WebSocket binary,
/// WebSocket JSON — with `caps` in that order.
pub fn every_transport(
    stream: &envlight::stream::server::BoundAddresses,
    caps: [u32; 4],
) -> [Subscription; 4] {
    use envlight::stream::client::Endpoint;
    use envlight::stream::Format;
    let ws = format!("ws://{}/", stream.websocket.expect("a WebSocket endpoint"));
    [
        (
            Endpoint::Unix(stream.unix_socket.clone().expect("a Unix socket")),
            Format::Binary,
            caps[0],
        ),
        (
            Endpoint::Tcp(stream.tcp.expect("a TCP endpoint").to_string()),
            Format::Json,
            caps[1],
        ),
        (Endpoint::WebSocket(ws.clone()), Format::Binary, caps[2]),
        (Endpoint::WebSocket(ws), Format::Json, caps[3]),
    ]
}

/// Connects one client per subscription asking for `representation`; each is read by `read`
/// on its own thread (joined for the result).
pub fn subscribe_all<T: Send + 'static>(
    subscriptions: &[Subscription],
    representation: envlight::stream::Representation,
    read: fn(envlight::stream::client::Client) -> T,
) -> Vec<std::thread::JoinHandle<T>> {
    use envlight::stream::client::Client;
    use envlight::stream::Request;
    subscriptions
        .iter()
        .map(|(endpoint, format, cap)| {
            let request = Request {
                max_lights: *cap,
                representation,
                format: *format,
            };
            let client = Client::connect(endpoint, &request, Some(TIMEOUT)).unwrap();
            spawn("test-client", move || read(client))
        })
        .collect()
}

/// The messages a client received, as picked by `pick`, until the daemon's goodbye (returned)
/// or the end of the stream. A message `pick` hands back, or a client error, fails the test.
pub fn read_until_goodbye<T>(
    mut client: envlight::stream::client::Client,
    pick: impl Fn(envlight::stream::Message) -> Result<T, envlight::stream::Message>,
) -> (Vec<T>, Option<String>) {
    use envlight::stream::Message;
    let mut picked = Vec::new();
    loop {
        match client.next_message() {
            Ok(Some(Message::Goodbye { message })) => return (picked, Some(message)),
            Ok(Some(message)) => match pick(message) {
                Ok(item) => picked.push(item),
                Err(other) => panic!("unexpected {other:?}"),
            },
            Ok(None) => return (picked, None),
            Err(e) => panic!("client error: {e}"),
        }
    }
}

/// A client that read to the end of a shutdown: the goodbye came, the sequence numbers it got
/// strictly increase and end at `last`.
pub fn assert_ordered_to_the_end(what: &str, goodbye: Option<&str>, seqs: &[u64], last: u64) {
    assert_eq!(goodbye, Some("envlight shutting down"), "{what}");
    assert!(seqs.windows(2).all(|w| w[0] < w[1]), "{what}: {seqs:?}");
    assert_eq!(seqs.last(), Some(&last), "{what}: {seqs:?}");
}

/// A lights client of `endpoint`, subscribed now, reading on its own thread until the
/// goodbye: its light frames, and the goodbye's text.
pub fn spawn_lights_reader(
    endpoint: &envlight::stream::client::Endpoint,
) -> std::thread::JoinHandle<(Vec<envlight::LightFrame>, Option<String>)> {
    use envlight::stream::Message;
    let client = envlight::stream::client::Client::connect(
        endpoint,
        &envlight::stream::Request::default(),
        Some(TIMEOUT),
    )
    .unwrap();
    std::thread::Builder::new()
        .name("lights-client".into())
        .spawn(move || {
            read_until_goodbye(client, |message| match message {
                Message::Frame(frame) => Ok(frame.into_light_frame()),
                other => Err(other),
            })
        })
        .unwrap()
}

/// A filtered set stream and the filtered lights describe the same moment: for every light
/// frame a client received, `set_integral(seq)` (the set's ∫L dω) equals the lights' Σ rgb to
/// 2·10⁻⁵ relative, while `own_integral(seq)` (the frame's own, unfiltered) is more than 10⁻³
/// off for some frame, so the check could fail (the frames change).
pub fn assert_sets_follow_the_lights(
    lights: &[envlight::LightFrame],
    set_integral: impl Fn(u64) -> [f64; 3],
    own_integral: impl Fn(u64) -> [f64; 3],
) {
    let mut unfiltered_worst = 0.0f64;
    for frame in lights {
        let integral = set_integral(frame.seq);
        let own = own_integral(frame.seq);
        for c in 0..3 {
            let sum: f64 = frame.lights.iter().map(|l| f64::from(l.rgb[c])).sum();
            let relative = |x: f64| (x - sum).abs() / sum;
            assert!(
                relative(integral[c]) < 2e-5,
                "seq {} channel {c}: set {} vs lights {sum}",
                frame.seq,
                integral[c]
            );
            unfiltered_worst = unfiltered_worst.max(relative(own[c]));
        }
    }
    assert!(lights.len() >= 4, "{} light frames", lights.len());
    assert!(
        unfiltered_worst > 1e-3,
        "the frames' own sets would have matched too ({unfiltered_worst})"
    );
}

/// Waits on a stage's channel for its next publication: each call wants one more than the last
/// (`published` counts them), so a test steps through the sets its changes produce.
pub fn wait_for_next_publication<T>(
    rx: &mut tokio::sync::watch::Receiver<envlight::publication::Latest<T>>,
    published: &mut u64,
    what: &str,
) {
    *published += 1;
    let want = *published;
    wait_until(what, || {
        rx.borrow_and_update()
            .as_ref()
            .is_some_and(|p| p.index >= want)
    });
}
