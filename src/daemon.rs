//! The daemon (`envlight run`): capture → decompose threads, the stream server, the metrics
//! endpoint, an optional recorder, and the process lifecycle.
//!
//! ```text
//! envlight-capture ─bounded─► envlight-decompose ─watch─► stream server (tokio: UDS, TCP, WebSocket)
//!                                   │                     metrics + health (HTTP)
//!                                   ├─watch─► envlight-render (optional: wgpu, frame budget)
//!                                   ├─tap─► envlight-record (optional)
//!                                   ├─feed─► envlight-asg (optional, [asg]) ─watch─► stream server
//!                                   │                                              envlight-render
//!                                   ├─feed─► envlight-wavelet (optional, [wavelet]) ─watch─► stream server
//!                                   └─feed─► envlight-sh (optional, [sh]) ─watch─► stream server
//! ```
//!
//! The ASG stage ([`crate::asg_stage`]) gets each frame after its lights are published and
//! fits the newest one whenever it is free (skipping, and counting, the frames in between), so
//! it never slows the lights; in a replay it fits every frame. Clients subscribe to it with
//! representation `asg`; `[render] lighting = "asg"` shades the render thread's scene with its
//! lobes. The wavelet stage ([`crate::wavelet_stage`]) and the spherical-harmonics stage
//! ([`crate::sh_stage`]) are fed the same way and serve representations `wavelet` and `sh`.
//! `/health` is about the lights only.
//!
//! - A daemon reads `[source]` as a service: the built-in sky, when the config leaves its frame
//!   count unset, runs until stopped, at [`DAEMON_SKY_FPS`] frames per second unless `fps` says
//!   otherwise, as a camera would ([`daemon_source_defaults`]); `envlight decompose` keeps the
//!   one-shot defaults (60 frames, as fast as possible).
//! - [`Daemon::start`] builds everything from a validated [`Config`]: a tokio runtime with
//!   `daemon.serve_threads` workers named `envlight-serve` (tokio lives only in serving), the
//!   pipeline ([`crate::pipeline`]), the stream server ([`crate::stream::server`]) and the HTTP
//!   endpoint. A replay ([`DaemonOptions::replay`]) decomposes with the recording's settings and
//!   a lossless queue, so it reproduces the recorded stream.
//! - [`Daemon::run`] is the service's main loop: it tells systemd `READY=1`, pings the watchdog
//!   while the pipeline is alive, reloads the config on SIGHUP (what cannot change live is
//!   reported), and shuts down on SIGTERM/SIGINT or when a finite source has been fully served.
//! - [`Daemon::shutdown`] stops capture, sends every client a goodbye, removes the socket file,
//!   joins the threads and finishes the recording. It returns the pipeline's counters or the
//!   error that ended the pipeline (a failed source), so nothing is lost silently.
//!
//! HTTP endpoint (`metrics.listen`): `GET /metrics` (Prometheus text format, see
//! [`crate::metrics`]) and `GET /health` (200 with a JSON status while fresh lights are being
//! published; 503 while there are none yet, they are stale, or older than
//! `metrics.max_frame_age_s`).

use crate::asg_stage::{AsgStage, AsgStageError, AsgStaleHandle, AsgStatsHandle, LatestAsg};
use crate::capture::{self, CaptureError, FrameSource, SourceHealth};
use crate::config::{Config, ConfigError, RawConfig};
use crate::metrics::Metrics;
use crate::pipeline::{
    LatestLights, Pipeline, PipelineError, PipelineOptions, PipelineStats, PublishHook,
    QueuePolicy, StaleHandle, StatsHandle,
};
use crate::record::{Pacing, RecordError, RecordSummary, Recorder, ReplaySource};
use crate::sh_stage::{ShHook, ShStage, ShStageError, ShStaleHandle, ShStats, ShStatsHandle};
use crate::stream::server::{ServerError, Streams, SHUTDOWN_MESSAGE};
use crate::stream::{BoundAddresses, FanoutOn, PublisherPass, StreamServer};
use crate::wavelet_stage::{
    WaveletHook, WaveletStage, WaveletStageError, WaveletStaleHandle, WaveletStats,
    WaveletStatsHandle,
};
use std::net::SocketAddr;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::time::{Duration, Instant};
use tokio::sync::watch;

/// Name of the serving runtime's worker threads.
pub const SERVE_THREAD_NAME: &str = "envlight-serve";

/// Frame rate of the built-in sky in a daemon whose config sets no `source.fps`: the rate the
/// sky's frame times assume anyway ([`crate::capture::sky::UNPACED_FRAME_RATE`]), so the sun
/// moves in real time.
pub const DAEMON_SKY_FPS: f64 = crate::capture::sky::UNPACED_FRAME_RATE;

/// The daemon's reading of `[source]`: a sky source whose `frames` is unset runs until stopped
/// (`frames = 0`), and one that sets neither `frames` nor `fps` is also paced at
/// [`DAEMON_SKY_FPS`]. Without this a service on the built-in sky would render its 60 default
/// frames as fast as it could and exit within a second. A config that sets `frames` but not
/// `fps` keeps the sky unpaced, so `frames = 0` alone still means "until stopped, as fast as
/// possible". Other sources and explicit values are left as they are.
pub fn daemon_source_defaults(mut config: Config) -> Config {
    let source = &mut config.source;
    if source.kind == crate::config::SourceKind::Sky && source.frames.is_none() {
        source.frames = Some(0);
        source.fps.get_or_insert(DAEMON_SKY_FPS);
    }
    config
}

/// What `envlight run` adds to the config.
#[derive(Clone, Debug, Default)]
pub struct DaemonOptions {
    /// Replay this recording instead of the configured source.
    pub replay: Option<(PathBuf, Pacing)>,
    /// Record the session into this (new or empty) directory.
    pub record: Option<PathBuf>,
    /// Frame files given on the command line (INPUT): they replace `[source]` with a sequence
    /// of these paths (or, for one `v4l2:DEVICE`, with that camera) when the config is read, at
    /// start and on every reload ([`read_config`]).
    pub source_paths: Option<Vec<String>>,
}

/// Reads and validates the daemon's config: the file at `path` (the defaults without one), its
/// `[source]` replaced by a sequence of `source_paths` when INPUT files were given, or by the
/// camera DEVICE when the one INPUT is `v4l2:DEVICE` (as `envlight decompose` takes it).
pub fn read_config(
    path: Option<&Path>,
    source_paths: Option<&[String]>,
) -> Result<Config, ConfigError> {
    let mut raw = match path {
        Some(path) => RawConfig::from_file(path)?,
        None => RawConfig::default(),
    };
    if let Some(device) = source_paths.and_then(camera_input) {
        raw.source.kind = Some("v4l2".to_owned());
        raw.source.paths = None;
        raw.camera.device = Some(device.to_owned());
    } else if let Some(paths) = source_paths {
        raw.source.kind = Some("sequence".to_owned());
        raw.source.paths = Some(paths.to_vec());
    }
    raw.validate()
}

/// The camera of INPUT when it is one `v4l2:DEVICE`: DEVICE.
pub fn camera_input(inputs: &[String]) -> Option<&str> {
    match inputs {
        [one] => one.strip_prefix("v4l2:"),
        _ => None,
    }
}

/// `text` on one line: its lines trimmed, the empty ones dropped, joined by " | ".
pub fn one_line(text: &str) -> String {
    text.lines()
        .map(str::trim)
        .filter(|l| !l.is_empty())
        .collect::<Vec<_>>()
        .join(" | ")
}

/// Errors of the daemon.
#[derive(Debug, thiserror::Error)]
pub enum DaemonError {
    #[error("cannot open the frame source: {0}")]
    Source(#[source] CaptureError),
    #[error(transparent)]
    Pipeline(#[from] PipelineError),
    #[error(transparent)]
    Server(#[from] ServerError),
    #[error("recording: {0}")]
    Record(#[from] RecordError),
    #[error("cannot start the serving runtime: {0}")]
    Runtime(#[source] std::io::Error),
    #[error(
        "cannot listen on metrics {address}: {source}{}",
        crate::stream::server::bind_hint("metrics", source)
    )]
    Metrics {
        address: SocketAddr,
        #[source]
        source: std::io::Error,
    },
    #[error("cannot install the signal handlers: {0}")]
    Signals(#[source] std::io::Error),
    #[error("render thread: {0}")]
    Render(String),
    /// `render.latest_png` would replace an input (the message names the key).
    #[error("{0}")]
    LatestPng(#[source] std::io::Error),
    #[error("ASG stage: {0}")]
    Asg(#[from] AsgStageError),
    #[error("wavelet stage: {0}")]
    Wavelet(#[from] WaveletStageError),
    #[error("SH stage: {0}")]
    Sh(#[from] ShStageError),
}

/// Where the daemon listens.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct DaemonAddresses {
    pub stream: BoundAddresses,
    pub metrics: Option<SocketAddr>,
}

/// What a SIGHUP reload did.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct ReloadReport {
    /// Sections applied live.
    pub applied: Vec<String>,
    /// Sections that changed but need a restart (with the reason).
    pub needs_restart: Vec<String>,
}

/// Why [`Daemon::run`] returned.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum StopReason {
    /// SIGTERM or SIGINT.
    Signal,
    /// A finite source was fully decomposed and served.
    SourceFinished,
    /// The recording (`--record`, `envlight record`) stopped with an error; the daemon's
    /// shutdown returns that error.
    RecordingFailed,
}

/// What the daemon did, returned by [`Daemon::shutdown`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct DaemonSummary {
    pub pipeline: PipelineStats,
    /// The ASG stage's counters, if it ran.
    pub asg: Option<crate::asg_stage::AsgStats>,
    /// The wavelet stage's counters, if it ran.
    pub wavelet: Option<WaveletStats>,
    /// The SH stage's counters, if it ran.
    pub sh: Option<ShStats>,
    pub recorded: Option<RecordSummary>,
    /// Whether every client took its goodbye within the grace period.
    pub clients_closed_in_time: bool,
}

/// A running daemon. See the module docs.
pub struct Daemon {
    config: Config,
    replaying: bool,
    /// INPUT files that replace `[source]` on every reload ([`DaemonOptions::source_paths`]).
    source_paths: Option<Vec<String>>,
    runtime: tokio::runtime::Runtime,
    pipeline: Pipeline,
    server: StreamServer,
    http: Option<(tokio::task::JoinHandle<()>, watch::Sender<bool>)>,
    metrics: Arc<Metrics>,
    recorder: Option<Recorder>,
    addresses: DaemonAddresses,
    /// Health of a source that can lose its device (a camera).
    health: Option<Arc<SourceHealth>>,
    /// The render thread and its stop flag (`[render] enabled`).
    render_thread: Option<RenderHandle>,
    /// The ASG stage (`[asg] enabled`).
    asg: Option<AsgStage>,
    /// The wavelet stage (`[wavelet] enabled`).
    wavelet: Option<WaveletStage>,
    /// The SH stage (`[sh] enabled`).
    sh: Option<ShStage>,
}

/// The lights' temporal filter's delay in frames under `settings` (0 without a filter).
fn filter_delay(settings: &crate::decompose::DecomposeSettings) -> f64 {
    settings
        .filter_taps
        .as_deref()
        .and_then(|taps| crate::decompose::filter::FirFilter::new(taps).ok())
        .map_or(0.0, |f| f.delay_frames())
}

/// Applies a stage's reloaded section: new settings go to the running stage live; a stage
/// started or stopped needs a restart; a stage whose section did not change restarts its
/// temporal filter when the lights' filter restarted (`lights_filter_restarted`), so that it
/// keeps describing the lights' moment. `name`: `[asg]`, `[wavelet]`, `[sh]`; `new`: the
/// reloaded section (its filter taps already the lights' as they run); `running`: the section
/// the daemon runs with, replaced by `new` where it applies.
fn reload_stage<W, C>(
    name: &str,
    new: &C,
    running: &mut C,
    stage: Option<&crate::slow_stage::DaemonStage<W>>,
    lights_filter_restarted: bool,
    report: &mut ReloadReport,
) where
    W: crate::slow_stage::StageKind,
    W::SettingsError: std::fmt::Display,
    C: crate::config::StageConfig<Settings = W::Settings>,
{
    if new != running {
        match stage {
            Some(stage) if new.enabled() => match stage.reconfigure(new.settings()) {
                Ok(()) => {
                    report.applied.push(name.to_owned());
                    *running = new.clone();
                }
                Err(e) => report.needs_restart.push(format!("{name} ({e})")),
            },
            // Disabled before and after: nothing runs, nothing to apply.
            None if !new.enabled() => *running = new.clone(),
            _ => report.needs_restart.push(format!(
                "{name} enabled (restart envlight to start or stop the stage)"
            )),
        }
    } else if let Some(stage) = stage.filter(|_| lights_filter_restarted) {
        if stage.reconfigure(running.settings()).is_ok() {
            report.applied.push(format!(
                "{name} (its temporal filter restarts with the lights')"
            ));
        }
    }
}

/// Waits for the slow stages that started before a later part of the start failed.
fn join_started(asg: Option<AsgStage>, wavelet: Option<WaveletStage>, sh: Option<ShStage>) {
    if let Some(asg) = asg {
        let _ = asg.join();
    }
    if let Some(wavelet) = wavelet {
        let _ = wavelet.join();
    }
    if let Some(sh) = sh {
        let _ = sh.join();
    }
}

/// How [`Daemon::start_parts`] runs its source: the decomposition settings, what a full
/// capture queue does, and whether it is a replay (its settings fixed, its slower stages
/// waited for).
struct StartParts {
    settings: crate::decompose::DecomposeSettings,
    policy: QueuePolicy,
    replaying: bool,
}

/// What a full capture queue does with the configured source's frames: a file sequence or a
/// sky made as fast as possible (no `source.fps`, after [`daemon_source_defaults`]) has no
/// clock to keep, so capture waits for the decomposition and every frame is decomposed,
/// served and recorded (dropping the oldest lost most of a recorded take: 13 of 16 files, and
/// 7 of the 10 frames of a `frames = 10` sky); a paced sequence or sky and a camera keep
/// their rate and drop the oldest frame.
fn live_source_policy(source: &crate::config::SourceConfig) -> QueuePolicy {
    use crate::config::SourceKind;
    let clockless = matches!(source.kind, SourceKind::Sequence | SourceKind::Sky);
    if clockless && source.fps.is_none() {
        QueuePolicy::Block
    } else {
        QueuePolicy::DropOldest
    }
}

impl Daemon {
    /// Opens the source, binds every endpoint and starts the threads.
    /// A sky source gets the daemon's defaults ([`daemon_source_defaults`]).
    pub fn start(config: Config, options: DaemonOptions) -> Result<Daemon, DaemonError> {
        let mut config = daemon_source_defaults(config);
        let (source, settings, policy): (Box<dyn FrameSource>, _, _) = match &options.replay {
            Some((dir, pacing)) => {
                let replay = ReplaySource::open(dir, *pacing).map_err(DaemonError::Source)?;
                let settings = replay.session().decompose.clone();
                tracing::info!(
                    "replaying with the recording's decomposition settings ({} lights)",
                    settings.lights
                );
                (Box::new(replay), settings, QueuePolicy::Block)
            }
            None => (
                capture::open(&config).map_err(DaemonError::Source)?,
                config.decompose.clone(),
                live_source_policy(&config.source),
            ),
        };
        if config.render.enabled {
            if let Some(png) = &config.render.latest_png {
                let scene = config.render.scene.iter().cloned();
                let inputs: Vec<PathBuf> = source.files().iter().cloned().chain(scene).collect();
                refuse_latest_png_over(png, &inputs)?;
            }
        }
        let replaying = options.replay.is_some();
        if replaying {
            // What follows the lights' settings follows the recording's, not the config's:
            // the stages' temporal filters share the lights' taps (so that every set describes
            // the lights' moment), and the metrics report their delay. A replay used the
            // config's taps for them, which the recorded lights were not made with.
            let taps = settings.filter_taps.as_deref();
            config.asg.settings.filter_taps = crate::config::stage_taps(config.asg.filter, taps);
            config.wavelet.settings.filter_taps =
                crate::config::stage_taps(config.wavelet.filter, taps);
            config.sh.settings.filter_taps = crate::config::stage_taps(config.sh.filter, taps);
            config.decompose = settings.clone();
        }
        let parts = StartParts {
            settings,
            policy,
            replaying,
        };
        let mut daemon = Self::start_parts(config, source, parts, options.record.as_deref())?;
        daemon.source_paths = options.source_paths;
        Ok(daemon)
    }

    /// Starts the daemon on a frame source of the caller's (a custom camera, a test source)
    /// with the configured decomposition settings.
    pub fn start_with_source(
        config: Config,
        source: Box<dyn FrameSource>,
        record: Option<&Path>,
    ) -> Result<Daemon, DaemonError> {
        // The source is the caller's; read [source] as `start` does all the same, so that a
        // reload compares like with like.
        let config = daemon_source_defaults(config);
        let parts = StartParts {
            settings: config.decompose.clone(),
            policy: QueuePolicy::DropOldest,
            replaying: false,
        };
        Self::start_parts(config, source, parts, record)
    }

    fn start_parts(
        config: Config,
        source: Box<dyn FrameSource>,
        parts: StartParts,
        record: Option<&Path>,
    ) -> Result<Daemon, DaemonError> {
        let StartParts {
            settings,
            policy,
            replaying,
        } = parts;
        let runtime = tokio::runtime::Builder::new_multi_thread()
            .worker_threads(config.daemon.serve_threads)
            .thread_name(SERVE_THREAD_NAME)
            .enable_all()
            .build()
            .map_err(DaemonError::Runtime)?;
        let description = source.describe();
        let health = source.health();

        let metrics = Arc::new(Metrics::new());
        metrics.set_filter_delay(filter_delay(&config.decompose));
        let hook_metrics = Arc::clone(&metrics);
        let observe = PublishHook(Arc::new(move |published| {
            hook_metrics.observe_decompose(published.compute_time);
        }));
        // The light lists' fan-out pass runs on the decompose thread, first (docs/daemon.md).
        let publisher_pass =
            (config.stream.fanout_on == FanoutOn::Publisher).then(PublisherPass::new);
        let on_publish = match &publisher_pass {
            Some(pass) => pass.hook().then(observe),
            None => observe,
        };
        // The renderer is built before anything starts, so a missing GPU adapter or a bad scene
        // is a clear start-up error.
        let renderer = if config.render.enabled {
            Some(build_renderer(&config.render)?)
        } else {
            None
        };
        let asg = if config.asg.enabled {
            let hook_metrics = Arc::clone(&metrics);
            let hook: crate::asg_stage::AsgHook = Arc::new(move |published| {
                hook_metrics
                    .asg_fit_seconds
                    .observe(published.compute_time.as_secs_f64());
            });
            Some(AsgStage::start(
                config.asg.settings.clone(),
                replaying,
                Some(hook),
            )?)
        } else {
            None
        };
        let wavelet = if config.wavelet.enabled {
            let hook_metrics = Arc::clone(&metrics);
            let hook: WaveletHook = Arc::new(move |published| {
                hook_metrics
                    .wavelet_seconds
                    .observe(published.compute_time.as_secs_f64());
            });
            match WaveletStage::start(config.wavelet.settings.clone(), replaying, Some(hook)) {
                Ok(stage) => Some(stage),
                Err(error) => {
                    join_started(asg, None, None);
                    return Err(error.into());
                }
            }
        } else {
            None
        };
        let sh = if config.sh.enabled {
            let hook_metrics = Arc::clone(&metrics);
            let hook: ShHook = Arc::new(move |published| {
                hook_metrics
                    .sh_seconds
                    .observe(published.compute_time.as_secs_f64());
            });
            match ShStage::start(config.sh.settings.clone(), replaying, Some(hook)) {
                Ok(stage) => Some(stage),
                Err(error) => {
                    join_started(asg, wavelet, None);
                    return Err(error.into());
                }
            }
        } else {
            None
        };
        let stage_feeds = asg
            .as_ref()
            .map(AsgStage::feed)
            .into_iter()
            .chain(wavelet.as_ref().map(WaveletStage::feed))
            .chain(sh.as_ref().map(ShStage::feed))
            .collect();
        // The recording is started last before the pipeline, and removed again if the start
        // fails, so a failed start leaves the directory as it was.
        let (tap, recorder) = match record {
            Some(dir) => {
                let (tx, rx) = crossbeam_channel::bounded(4);
                match Recorder::start(dir, &description, &settings, rx) {
                    Ok(recorder) => {
                        tracing::info!(dir = %dir.display(), "recording the session");
                        (Some(tx), Some(recorder))
                    }
                    Err(error) => {
                        join_started(asg, wavelet, sh);
                        return Err(error.into());
                    }
                }
            }
            None => (None, None),
        };
        let pipeline_options = PipelineOptions {
            queue_capacity: config.pipeline.queue_capacity,
            queue_policy: policy,
            tap,
            on_publish: Some(on_publish),
            stage_feeds,
        };
        let pipeline = match Pipeline::start(source, settings, pipeline_options) {
            Ok(pipeline) => pipeline,
            Err(error) => {
                join_started(asg, wavelet, sh);
                if let Some(recorder) = recorder {
                    recorder.discard();
                }
                return Err(error.into());
            }
        };
        let wavelet_rx = wavelet.as_ref().map(WaveletStage::subscribe);
        let sh_rx = sh.as_ref().map(ShStage::subscribe);
        let asg_rx: Option<watch::Receiver<LatestAsg>> = asg.as_ref().map(AsgStage::subscribe);

        // Endpoints: if one cannot be bound, stop what was started and report it.
        let started = runtime.block_on(async {
            let mut streams = Streams::new(pipeline.subscribe())
                .with_optional(asg_rx.clone())
                .with_optional(wavelet_rx)
                .with_optional(sh_rx.clone());
            if let Some(pass) = publisher_pass {
                streams = streams.with_publisher_pass(pass);
            }
            // The metrics endpoint is bound first: a port in use fails the start before the
            // stream server has bound (and would have to remove) its socket file.
            let metrics_listener = match config.metrics.listen {
                Some(address) => Some(
                    tokio::net::TcpListener::bind(address)
                        .await
                        .map_err(|source| DaemonError::Metrics { address, source })?,
                ),
                None => None,
            };
            let server =
                StreamServer::start_streams(&config.stream, streams, Arc::clone(&metrics)).await?;
            let http = match metrics_listener {
                Some(listener) => {
                    let bound = listener.local_addr().ok();
                    let (stop_tx, stop_rx) = watch::channel(false);
                    let state = Arc::new(HttpState {
                        health: health.clone(),
                        metrics: Arc::clone(&metrics),
                        stats: pipeline.stats_handle(),
                        lights: pipeline.subscribe(),
                        max_frame_age: config.metrics.max_frame_age,
                        asg: asg.as_ref().map(AsgStage::stats_handle),
                        wavelet: wavelet.as_ref().map(WaveletStage::stats_handle),
                        sh: sh.as_ref().map(ShStage::stats_handle),
                    });
                    tracing::info!(
                        address = %crate::stream::server::shown(bound),
                        "serving metrics and health over http"
                    );
                    let task = tokio::spawn(serve_http(listener, state, stop_rx));
                    Some((task, stop_tx, bound))
                }
                None => None,
            };
            if let Some(health) = &health {
                tokio::spawn(monitor_health(
                    Arc::clone(health),
                    pipeline.stale_handle(),
                    SlowStaleHandles {
                        asg: asg.as_ref().map(AsgStage::stale_handle),
                        wavelet: wavelet.as_ref().map(WaveletStage::stale_handle),
                        sh: sh.as_ref().map(ShStage::stale_handle),
                    },
                ));
            }
            Ok::<_, DaemonError>((server, http))
        });
        let (server, http) = match started {
            Ok(started) => started,
            Err(error) => {
                pipeline.stop();
                let _ = pipeline.join();
                join_started(asg, wavelet, sh);
                if let Some(recorder) = recorder {
                    recorder.discard();
                }
                return Err(error);
            }
        };
        let render_thread = match renderer {
            None => None,
            Some(renderer) => {
                let stop = Arc::new(std::sync::atomic::AtomicBool::new(false));
                let thread = RenderThread {
                    renderer,
                    config: config.render.clone(),
                    lights: pipeline.subscribe(),
                    asg: asg_rx.clone(),
                    sh: sh_rx.clone(),
                    stop: Arc::clone(&stop),
                    metrics: Arc::clone(&metrics),
                    runtime: runtime.handle().clone(),
                };
                let handle = std::thread::Builder::new()
                    .name(RENDER_THREAD_NAME.to_owned())
                    .spawn(move || thread.run())
                    .map_err(|e| DaemonError::Render(format!("cannot start the thread: {e}")))?;
                Some((handle, stop))
            }
        };
        let addresses = DaemonAddresses {
            stream: server.bound().clone(),
            metrics: http.as_ref().and_then(|(_, _, bound)| *bound),
        };
        Ok(Daemon {
            config,
            replaying,
            source_paths: None,
            runtime,
            pipeline,
            server,
            http: http.map(|(task, stop, _)| (task, stop)),
            metrics,
            recorder,
            addresses,
            health,
            render_thread,
            asg,
            wavelet,
            sh,
        })
    }

    /// Where the endpoints listen (ports resolved).
    pub fn addresses(&self) -> &DaemonAddresses {
        &self.addresses
    }

    /// The daemon's metrics.
    pub fn metrics(&self) -> &Arc<Metrics> {
        &self.metrics
    }

    /// The pipeline (to subscribe in-process or read its counters).
    pub fn pipeline(&self) -> &Pipeline {
        &self.pipeline
    }

    /// Whether a finite source has been fully decomposed (and, with an ASG, wavelet or SH
    /// stage, its last frame fitted, transformed or projected).
    pub fn source_finished(&self) -> bool {
        self.pipeline.is_finished()
            && self.asg.as_ref().is_none_or(AsgStage::is_finished)
            && self.wavelet.as_ref().is_none_or(WaveletStage::is_finished)
            && self.sh.as_ref().is_none_or(ShStage::is_finished)
    }

    /// The ASG stage, if `[asg]` enabled it.
    pub fn asg(&self) -> Option<&AsgStage> {
        self.asg.as_ref()
    }

    /// The wavelet stage, if `[wavelet]` enabled it.
    pub fn wavelet(&self) -> Option<&WaveletStage> {
        self.wavelet.as_ref()
    }

    /// The SH stage, if `[sh]` enabled it.
    pub fn sh(&self) -> Option<&ShStage> {
        self.sh.as_ref()
    }

    /// Applies a new configuration: the decomposition settings change live (from the next
    /// frame; the temporal filter restarts); every other section that changed is reported as
    /// needing a restart and keeps its running value.
    pub fn reload(&mut self, new: Config) -> ReloadReport {
        // Read as at start, so an unchanged file reports no change of [source].
        let new = daemon_source_defaults(new);
        let mut report = ReloadReport::default();
        // Whether the lights' temporal filter restarts: the wavelet and SH stages' filters,
        // which share its taps, restart with it so that all describe the same moment.
        let mut lights_filter_restarted = false;
        if new.decompose != self.config.decompose {
            if self.replaying {
                report
                    .needs_restart
                    .push("[decompose] (a replay uses the recording's settings)".to_owned());
            } else if self.recorder.is_some() {
                report.needs_restart.push(
                    "[decompose] (not changed while recording: the recording keeps one set of \
                     settings, so that its replay makes the recorded lights)"
                        .to_owned(),
                );
            } else {
                match self.pipeline.reconfigure(new.decompose.clone()) {
                    Ok(()) => {
                        report.applied.push("[decompose]".to_owned());
                        self.config.decompose = new.decompose.clone();
                        self.metrics.set_filter_delay(filter_delay(&new.decompose));
                        lights_filter_restarted = true;
                    }
                    Err(e) => report.needs_restart.push(format!("[decompose] ({e})")),
                }
            }
        }
        // The stages' taps are the lights' as they now run (a [decompose] that could not
        // change live keeps its taps for them too).
        let mut new = new;
        let lights_taps = self.config.decompose.filter_taps.as_deref();
        new.asg.settings.filter_taps = crate::config::stage_taps(new.asg.filter, lights_taps);
        new.wavelet.settings.filter_taps =
            crate::config::stage_taps(new.wavelet.filter, lights_taps);
        new.sh.settings.filter_taps = crate::config::stage_taps(new.sh.filter, lights_taps);
        reload_stage(
            "[asg]",
            &new.asg,
            &mut self.config.asg,
            self.asg.as_ref(),
            lights_filter_restarted,
            &mut report,
        );
        reload_stage(
            "[wavelet]",
            &new.wavelet,
            &mut self.config.wavelet,
            self.wavelet.as_ref(),
            lights_filter_restarted,
            &mut report,
        );
        reload_stage(
            "[sh]",
            &new.sh,
            &mut self.config.sh,
            self.sh.as_ref(),
            lights_filter_restarted,
            &mut report,
        );
        let old = &self.config;
        let sections = [
            ("[source]", new.source != old.source),
            ("[source] / [sky]", new.sky != old.sky),
            ("[camera]", new.camera != old.camera),
            ("[pipeline]", new.pipeline != old.pipeline),
            ("[stream]", new.stream != old.stream),
            ("[metrics]", new.metrics != old.metrics),
            ("[daemon]", new.daemon != old.daemon),
            ("[render]", new.render != old.render),
        ];
        for (name, changed) in sections {
            if changed {
                // A replay reads its recording whatever the source sections say.
                let source_section = matches!(name, "[source]" | "[source] / [sky]" | "[camera]");
                let why = if self.replaying && source_section {
                    "a replay reads its recording, not this section"
                } else {
                    "restart envlight to apply"
                };
                report.needs_restart.push(format!("{name} ({why})"));
            }
        }
        report
    }

    /// Reads, validates and applies a config file; a bad file changes nothing.
    pub fn reload_file(&mut self, path: &Path) -> Result<ReloadReport, ConfigError> {
        let config = read_config(Some(path), self.source_paths.as_deref())?;
        Ok(self.reload(config))
    }

    /// Runs until SIGTERM/SIGINT or the end of a finite source, handling SIGHUP (reload of
    /// `config_path`, if any) and the systemd notifications, then shuts down.
    pub fn run(
        mut self,
        config_path: Option<&Path>,
    ) -> Result<(StopReason, DaemonSummary), DaemonError> {
        use tokio::signal::unix::{signal, SignalKind};
        let signals = self.runtime.block_on(async {
            Ok::<_, std::io::Error>((
                signal(SignalKind::terminate())?,
                signal(SignalKind::interrupt())?,
                signal(SignalKind::hangup())?,
            ))
        });
        let (mut term, mut int, mut hup) = signals.map_err(DaemonError::Signals)?;
        // Signals that came during the start ([`hold_stop_signals`]) are handled from here.
        set_stop_signal_mask(libc::SIG_UNBLOCK);
        notify(&[
            sd_notify::NotifyState::Ready,
            sd_notify::NotifyState::Status("serving light lists"),
        ]);
        let watchdog = sd_notify::watchdog_enabled();
        let tick = watchdog.map_or(Duration::from_millis(250), |w| {
            (w / 2).min(Duration::from_millis(250))
        });
        let mut last_progress = (0u64, Instant::now());
        let reason = loop {
            enum Wake {
                Stop(&'static str),
                Reload,
                Tick,
            }
            let wake = self.runtime.block_on(async {
                tokio::select! {
                    _ = term.recv() => Wake::Stop("SIGTERM"),
                    _ = int.recv() => Wake::Stop("SIGINT"),
                    _ = hup.recv() => Wake::Reload,
                    _ = tokio::time::sleep(tick) => Wake::Tick,
                }
            });
            match wake {
                Wake::Stop(signal) => {
                    tracing::info!("{signal}: shutting down");
                    self.abandon_slow_work();
                    break StopReason::Signal;
                }
                Wake::Reload => self.handle_reload(config_path),
                Wake::Tick => {
                    // A recording asked for is not allowed to end unnoticed while the lights
                    // go on: every frame from here on would be missing from it.
                    if self.recorder.as_ref().is_some_and(Recorder::has_failed) {
                        tracing::error!(
                            "the recording has stopped with an error; shutting down (what it \
                             stored so far replays)"
                        );
                        self.abandon_slow_work();
                        break StopReason::RecordingFailed;
                    }
                    if self.source_finished() {
                        tracing::info!("the source has ended; shutting down");
                        break StopReason::SourceFinished;
                    }
                    // The watchdog is fed while the threads are alive; a hung decomposition
                    // (no new frame while frames are being captured) stops feeding it.
                    let stats = self.pipeline.stats();
                    let moving = stats.frames_decomposed != last_progress.0
                        || stats.frames_captured == stats.frames_decomposed + stats.frames_dropped;
                    if stats.frames_decomposed != last_progress.0 {
                        last_progress = (stats.frames_decomposed, Instant::now());
                    }
                    let hung = !moving && last_progress.1.elapsed() > Duration::from_secs(10);
                    if watchdog.is_some() && !hung {
                        notify(&[sd_notify::NotifyState::Watchdog]);
                    }
                }
            }
        };
        notify(&[sd_notify::NotifyState::Stopping]);
        let summary = self.shutdown()?;
        Ok((reason, summary))
    }

    /// A stop that does not wait for slow work: a first ASG fit of many iterations held a
    /// signal's shutdown up for seconds (or minutes), clients without a frame or a goodbye
    /// meanwhile.
    fn abandon_slow_work(&self) {
        if let Some(asg) = &self.asg {
            asg.abandon();
        }
        if let Some(wavelet) = &self.wavelet {
            wavelet.abandon();
        }
        if let Some(sh) = &self.sh {
            sh.abandon();
        }
    }

    fn handle_reload(&mut self, config_path: Option<&Path>) {
        let Some(path) = config_path else {
            tracing::warn!("SIGHUP: no config file was given (--config); nothing to reload");
            return;
        };
        if let Ok(now) = sd_notify::NotifyState::monotonic_usec_now() {
            notify(&[sd_notify::NotifyState::Reloading, now]);
        }
        match self.reload_file(path) {
            Err(error) => {
                // One line per event (journald): TOML's caret snippets span several.
                let error = one_line(&error.to_string());
                tracing::error!(
                    path = %path.display(),
                    %error,
                    "SIGHUP: config reload failed; keeping the running configuration"
                )
            }
            Ok(report) => {
                if report.applied.is_empty() && report.needs_restart.is_empty() {
                    tracing::info!(path = %path.display(), "SIGHUP: config reloaded; nothing changed");
                }
                for section in &report.applied {
                    tracing::info!("SIGHUP: applied {section}");
                }
                for section in &report.needs_restart {
                    tracing::warn!("SIGHUP: not applied: {section}");
                }
            }
        }
        notify(&[sd_notify::NotifyState::Ready]);
    }

    /// Stops capture, says goodbye to every client, removes the socket file, joins the threads
    /// and finishes the recording.
    pub fn shutdown(self) -> Result<DaemonSummary, DaemonError> {
        let Daemon {
            config,
            runtime,
            pipeline,
            server,
            http,
            recorder,
            health,
            render_thread,
            asg,
            wavelet,
            sh,
            ..
        } = self;
        let rendered = render_thread.map(|(handle, stop)| {
            stop.store(true, std::sync::atomic::Ordering::Release);
            handle
                .join()
                .unwrap_or_else(|_| Err("the render thread panicked".to_owned()))
        });
        // A camera that is being reconnected stops retrying.
        if let Some(health) = &health {
            health.request_stop();
        }
        pipeline.stop();
        // The pipeline decomposes what is queued and closes the stages' feeds; the stages fit
        // what is waiting and publish it; then the server sends what was published and only
        // then the goodbye, so nothing computed is lost to the clients. The channels stay open
        // until the goodbye: a channel that closes tells its clients that the stream ended,
        // not that the daemon is shutting down.
        let channels_open = (
            pipeline.stale_handle(),
            asg.as_ref().map(AsgStage::stale_handle),
            wavelet.as_ref().map(WaveletStage::stale_handle),
            sh.as_ref().map(ShStage::stale_handle),
        );
        let stats = pipeline.join();
        let asg_stats = asg.map(AsgStage::join).transpose();
        let wavelet_stats = wavelet.map(WaveletStage::join).transpose();
        let sh_stats = sh.map(ShStage::join).transpose();
        let clients_closed_in_time = runtime.block_on(async {
            if let Some((task, stop)) = http {
                stop.send_replace(true);
                let _ = tokio::time::timeout(Duration::from_secs(1), task).await;
            }
            server
                .shutdown(SHUTDOWN_MESSAGE, config.daemon.shutdown_grace)
                .await
        });
        drop(channels_open);
        let recorded = recorder.map(Recorder::finish).transpose();
        runtime.shutdown_timeout(Duration::from_secs(1));
        let stats = stats?;
        let asg_stats = asg_stats?;
        let wavelet_stats = wavelet_stats?;
        let sh_stats = sh_stats?;
        let recorded = recorded?;
        if let Some(rendered) = rendered {
            let frames = rendered.map_err(DaemonError::Render)?;
            tracing::info!(frames, "render thread finished");
        }
        tracing::info!(
            frames_captured = stats.frames_captured,
            frames_dropped = stats.frames_dropped,
            frames_decomposed = stats.frames_decomposed,
            "stopped"
        );
        Ok(DaemonSummary {
            pipeline: stats,
            asg: asg_stats,
            wavelet: wavelet_stats,
            sh: sh_stats,
            recorded,
            clients_closed_in_time,
        })
    }
}

/// Holds SIGTERM, SIGINT and SIGHUP pending on the calling thread and every thread it starts
/// from now on, until [`Daemon::run`] handles them: call it before [`Daemon::start`], on the
/// main thread. Without it a signal that came while the daemon started (seconds, with many
/// lights) killed it with the default action: no goodbye, the socket file and a half-made
/// recording left behind, a SIGHUP fatal.
pub fn hold_stop_signals() {
    set_stop_signal_mask(libc::SIG_BLOCK);
    tracing::debug!("stop signals held until the start is done");
}

/// Blocks (`SIG_BLOCK`) or unblocks (`SIG_UNBLOCK`) SIGTERM, SIGINT and SIGHUP on the calling
/// thread.
fn set_stop_signal_mask(how: libc::c_int) {
    // SAFETY: the set is initialised by sigemptyset before use and pthread_sigmask only reads
    // it; neither call keeps the pointer.
    unsafe {
        let mut set: libc::sigset_t = std::mem::zeroed();
        libc::sigemptyset(&mut set);
        for signal in [libc::SIGTERM, libc::SIGINT, libc::SIGHUP] {
            libc::sigaddset(&mut set, signal);
        }
        libc::pthread_sigmask(how, &set, std::ptr::null_mut());
    }
}

/// The render thread (returns frames drawn or its error) and its stop flag.
type RenderHandle = (
    std::thread::JoinHandle<Result<u64, String>>,
    Arc<std::sync::atomic::AtomicBool>,
);

/// Name of the render thread.
pub const RENDER_THREAD_NAME: &str = "envlight-render";

fn build_renderer(
    config: &crate::config::RenderConfig,
) -> Result<crate::render::Renderer, DaemonError> {
    use crate::render::{scene::Scene, Renderer};
    let mut scene = match &config.scene {
        Some(path) => Scene::load(path, true).map_err(|e| DaemonError::Render(e.to_string()))?,
        None => Scene::default_scene(),
    };
    scene.camera = config
        .camera
        .apply(scene.camera)
        .map_err(|m| DaemonError::Render(format!("[render] camera: {m}")))?;
    if config.camera != crate::render::scene::CameraOverride::default() {
        // Placed by hand: an animated camera node no longer moves it.
        scene.hold_camera();
    }
    scene
        .select_animation(&config.animation)
        .map_err(|m| DaemonError::Render(format!("[render] animation: {m}")))?;
    if let Some((index, name, seconds)) = scene.playing_animation() {
        tracing::info!(
            "render animation {index} ({name:?}): {seconds:.3} s, looped over the frames' \
             capture times"
        );
    }
    tracing::info!("render scene: {}", scene.summary());
    tracing::info!("render camera: {}", scene.camera.describe());
    let renderer =
        Renderer::new(scene, config.settings).map_err(|e| DaemonError::Render(e.to_string()))?;
    tracing::info!(
        adapter = %renderer.gpu().describe(),
        width = config.settings.width,
        height = config.settings.height,
        shadow_maps = renderer.settings().shadow_raster.name(),
        "render thread enabled"
    );
    Ok(renderer)
}

/// The render consumer: shades the scene under every new light list (the newest one; a slow
/// renderer skips lists), holding `budget_ms` by using a prefix of the progressive light set;
/// or, with `lighting = "asg"` or `"sh"`, under every new ASG or SH set (closed form, no
/// budget: the cost is one pass over 16-ish lobes or a few dozen coefficients).
struct RenderThread {
    renderer: crate::render::Renderer,
    config: crate::config::RenderConfig,
    lights: watch::Receiver<LatestLights>,
    asg: Option<watch::Receiver<LatestAsg>>,
    sh: Option<watch::Receiver<crate::sh_stage::LatestSh>>,
    stop: Arc<std::sync::atomic::AtomicBool>,
    metrics: Arc<Metrics>,
    runtime: tokio::runtime::Handle,
}

impl RenderThread {
    /// Renders until stopped or the stream ends; returns the number of frames drawn, or the
    /// first GPU or output error (which also ends the thread, logged).
    fn run(mut self) -> Result<u64, String> {
        use crate::render::{budget, light_prefix};
        match self.config.lighting {
            crate::config::Lighting::Lights => {}
            crate::config::Lighting::Asg => return self.run_asg(),
            crate::config::Lighting::Sh => return self.run_sh(),
        }
        let mut controller: Option<budget::BudgetController> = None;
        let mut frames = 0u64;
        while !self.stop.load(std::sync::atomic::Ordering::Acquire) {
            let lights = &mut self.lights;
            let changed = self.runtime.block_on(async {
                tokio::time::timeout(Duration::from_millis(100), lights.changed()).await
            });
            match changed {
                Err(_) => continue,  // nothing new; check the stop flag
                Ok(Err(_)) => break, // the stream ended
                Ok(Ok(())) => {}
            }
            let Some(published) = self.lights.borrow_and_update().clone() else {
                continue;
            };
            let all = published.payload.lights.len();
            let count = match self.config.budget_ms {
                Some(ms) => controller
                    .get_or_insert_with(|| {
                        budget::BudgetController::new(budget::BudgetSettings::new(ms, all), all)
                    })
                    .count(),
                None => all,
            };
            // An animated scene's clock: the frame's capture time.
            self.renderer.set_scene_time(published.payload.time);
            let used = light_prefix(&published.payload.lights, count);
            let result = match &self.config.latest_png {
                Some(path) => self
                    .renderer
                    .render(&used)
                    .and_then(|(image, stats)| write_latest_png(path, &image).map(|()| stats)),
                None => self.renderer.render_timed(&used),
            };
            let stats = match result {
                Ok(stats) => stats,
                Err(error) => {
                    tracing::error!(%error, "rendering failed; the render thread stops");
                    return Err(error.to_string());
                }
            };
            frames += 1;
            self.metrics.frames_rendered.inc();
            self.metrics.render_seconds.observe(stats.frame_ms() / 1e3);
            self.metrics
                .render_lights
                .set(i64::try_from(stats.lights).unwrap_or(i64::MAX));
            if let Some(c) = &mut controller {
                c.update(stats.frame_ms());
            }
        }
        Ok(frames)
    }
}

impl RenderThread {
    /// The ASG loop of [`RenderThread::run`].
    fn run_asg(mut self) -> Result<u64, String> {
        let Some(rx) = self.asg.take() else {
            return Err("lighting = \"asg\" needs the ASG stage ([asg] enabled = true)".into());
        };
        self.run_sets(rx, |renderer, set: &crate::light::AsgSet, image| {
            renderer.set_scene_time(set.time);
            let lobes: Vec<crate::asg::Asg> = set
                .lobes
                .iter()
                .filter_map(crate::light::AsgLobe::to_asg)
                .collect();
            if image {
                renderer.render_asg(&lobes).map(|(i, s)| (Some(i), s))
            } else {
                renderer.render_asg_timed(&lobes).map(|s| (None, s))
            }
        })
    }

    /// The SH loop of [`RenderThread::run`].
    fn run_sh(mut self) -> Result<u64, String> {
        let Some(rx) = self.sh.take() else {
            return Err("lighting = \"sh\" needs the SH stage ([sh] enabled = true)".into());
        };
        self.run_sets(rx, |renderer, set: &crate::stream::ShFrame, image| {
            renderer.set_scene_time(set.time);
            // The stage publishes only squares (validate_sh_set); anything else is no light.
            let sh = set
                .to_coefficients()
                .unwrap_or_else(|| crate::sh::ShCoefficients::zero(0));
            if image {
                renderer.render_sh(&sh).map(|(i, s)| (Some(i), s))
            } else {
                renderer.render_sh_timed(&sh).map(|s| (None, s))
            }
        })
    }

    /// Renders under every new set of `rx` with `draw` (asked for the image when
    /// `latest_png` is set) until stopped or the stream ends.
    fn run_sets<T>(
        self,
        mut rx: watch::Receiver<crate::publication::Latest<T>>,
        mut draw: impl FnMut(
            &mut crate::render::Renderer,
            &T,
            bool,
        ) -> Result<
            (Option<crate::render::Image>, crate::render::FrameStats),
            crate::render::RenderError,
        >,
    ) -> Result<u64, String> {
        let Self {
            mut renderer,
            config,
            stop,
            metrics,
            runtime,
            ..
        } = self;
        let mut frames = 0u64;
        while !stop.load(std::sync::atomic::Ordering::Acquire) {
            let changed = runtime.block_on(async {
                tokio::time::timeout(Duration::from_millis(100), rx.changed()).await
            });
            match changed {
                Err(_) => continue,
                Ok(Err(_)) => break,
                Ok(Ok(())) => {}
            }
            let Some(published) = rx.borrow_and_update().clone() else {
                continue;
            };
            let result = draw(
                &mut renderer,
                &published.payload,
                config.latest_png.is_some(),
            )
            .and_then(|(image, stats)| match (&config.latest_png, image) {
                (Some(path), Some(image)) => write_latest_png(path, &image).map(|()| stats),
                _ => Ok(stats),
            });
            let stats = match result {
                Ok(stats) => stats,
                Err(error) => {
                    tracing::error!(%error, "rendering failed; the render thread stops");
                    return Err(error.to_string());
                }
            };
            frames += 1;
            metrics.frames_rendered.inc();
            metrics.render_seconds.observe(stats.frame_ms() / 1e3);
        }
        Ok(frames)
    }
}

/// The temporary file through which `[render] latest_png` is replaced.
fn latest_png_tmp(path: &Path) -> PathBuf {
    let mut tmp = path.as_os_str().to_owned();
    tmp.push(".tmp.png");
    PathBuf::from(tmp)
}

/// Fails when `[render] latest_png` or its temporary file is one of `inputs` (the frames, the
/// scene, the config file): each frame's PNG would replace it. `run --config rd.toml` with
/// `latest_png` naming rd.toml turned the config into a PNG (found by an audit).
pub fn refuse_latest_png_over(png: &Path, inputs: &[PathBuf]) -> Result<(), DaemonError> {
    let inputs = crate::read_file::InputFiles::new(inputs);
    inputs
        .refuse(png, "render.latest_png")
        .and_then(|()| inputs.refuse(&latest_png_tmp(png), "render.latest_png's temporary file"))
        .map_err(DaemonError::LatestPng)
}

/// Writes a tone-mapped PNG next to `path` and renames it into place.
fn write_latest_png(
    path: &Path,
    image: &crate::render::Image,
) -> Result<(), crate::render::RenderError> {
    use crate::render::output;
    crate::read_file::check_replaceable(path, "render.latest_png")
        .map_err(|e| crate::render::RenderError::Output(format!("{}: {e}", path.display())))?;
    // A frame without lit pixels is black at any exposure.
    let exposure = output::auto_exposure(image).unwrap_or(1.0);
    let tmp = latest_png_tmp(path);
    output::write_png(&tmp, image, exposure)
        .map_err(|e| crate::render::RenderError::Output(e.to_string()))?;
    std::fs::rename(&tmp, path)
        .map_err(|e| crate::render::RenderError::Output(format!("{}: {e}", path.display())))
}

/// Sends a systemd notification; a no-op outside systemd, a logged warning on failure.
fn notify(states: &[sd_notify::NotifyState]) {
    if let Err(error) = sd_notify::notify(states) {
        tracing::warn!(%error, "cannot notify systemd");
    }
}

/// The stale handles of the slow stages that run.
struct SlowStaleHandles {
    asg: Option<AsgStaleHandle>,
    wavelet: Option<WaveletStaleHandle>,
    sh: Option<ShStaleHandle>,
}

/// Marks the lights (and ASG, wavelet and SH sets) stale while the source is lost; the first
/// ones computed after it is back are live (with a higher seq), and logs both changes.
async fn monitor_health(health: Arc<SourceHealth>, stale: StaleHandle, stages: SlowStaleHandles) {
    let mut interval = tokio::time::interval(Duration::from_millis(50));
    let mut was_lost = false;
    loop {
        interval.tick().await;
        let lost = health.is_stale();
        if lost {
            // Every tick: a slow stage may publish a set fitted to a frame from before the loss.
            // The source is tested again under each channel's lock: it is marked healthy
            // before its first fresh frame is published, so that frame is never marked stale.
            let still_lost = || health.is_stale();
            if let Some(asg) = &stages.asg {
                asg.mark_stale_if(still_lost);
            }
            if let Some(wavelet) = &stages.wavelet {
                wavelet.mark_stale_if(still_lost);
            }
            if let Some(sh) = &stages.sh {
                sh.mark_stale_if(still_lost);
            }
            stale.mark_stale_if(still_lost);
        }
        if lost && !was_lost {
            tracing::warn!(
                error = %health.last_error(),
                "the source is lost; serving the last lights marked stale while it reconnects"
            );
        } else if was_lost && !lost {
            tracing::info!("the source is back; fresh lights follow its next frame");
        }
        was_lost = lost;
    }
}

/// What the HTTP endpoint reads.
struct HttpState {
    health: Option<Arc<SourceHealth>>,
    metrics: Arc<Metrics>,
    stats: StatsHandle,
    lights: watch::Receiver<LatestLights>,
    max_frame_age: Duration,
    asg: Option<AsgStatsHandle>,
    wavelet: Option<WaveletStatsHandle>,
    sh: Option<ShStatsHandle>,
}

impl HttpState {
    /// `/health`: status code and JSON body.
    fn health(&self) -> (u16, String) {
        let latest = self.lights.borrow().clone();
        let (healthy, reason, age) = match &latest {
            None => (false, "no light list published yet".to_owned(), None),
            Some(p) => {
                let age = p.published_at.elapsed();
                if p.stale {
                    (
                        false,
                        "the source is lost; serving stale lights".to_owned(),
                        Some(age),
                    )
                } else if age > self.max_frame_age {
                    (
                        false,
                        format!(
                            "the newest light list is {:.1} s old (limit {:.1} s)",
                            age.as_secs_f64(),
                            self.max_frame_age.as_secs_f64()
                        ),
                        Some(age),
                    )
                } else {
                    (true, "ok".to_owned(), Some(age))
                }
            }
        };
        let stats = self.stats.stats();
        let body = serde_json::json!({
            "status": if healthy { "ok" } else { "unhealthy" },
            "reason": reason,
            "newest_age_s": age.map(|a| a.as_secs_f64()),
            "seq": latest.as_ref().map(|p| p.payload.seq),
            "lights": latest.as_ref().map(|p| p.payload.lights.len()),
            "frames_decomposed": stats.frames_decomposed,
            "frames_dropped": stats.frames_dropped,
        });
        (if healthy { 200 } else { 503 }, body.to_string() + "\n")
    }

    fn metrics_text(&self) -> String {
        self.metrics.update_pipeline(&self.stats.stats());
        if let Some(wavelet) = &self.wavelet {
            self.metrics.update_wavelet(&wavelet.stats());
        }
        if let Some(asg) = &self.asg {
            self.metrics.update_asg(&asg.stats());
        }
        if let Some(sh) = &self.sh {
            self.metrics.update_sh(&sh.stats());
        }
        let stale = self.lights.borrow().as_ref().is_some_and(|p| p.stale);
        self.metrics.source_stale.set(i64::from(stale));
        if let Some(health) = &self.health {
            self.metrics
                .update_source(health.failures_total(), health.reconnect_attempts());
        }
        self.metrics.encode()
    }
}

/// The most HTTP connections the metrics endpoint serves at once; more are closed as they
/// come (a scraper and a few people need a handful), so the endpoint cannot use up the file
/// descriptors the light stream's endpoints need.
pub const MAX_HTTP_CONNECTIONS: usize = 64;

/// How long an HTTP client has to send a request's headers before it is cut off (the whole
/// connection is cut off after [`HTTP_CONNECTION_TIMEOUT`]).
pub const HTTP_HEADER_TIMEOUT: Duration = Duration::from_secs(5);

/// The longest an HTTP connection is kept, keep-alive included.
pub const HTTP_CONNECTION_TIMEOUT: Duration = Duration::from_secs(30);

async fn serve_http(
    listener: tokio::net::TcpListener,
    state: Arc<HttpState>,
    mut stop: watch::Receiver<bool>,
) {
    use hyper::service::service_fn;
    use hyper_util::rt::{TokioIo, TokioTimer};
    let slots = Arc::new(tokio::sync::Semaphore::new(MAX_HTTP_CONNECTIONS));
    let mut refused: u64 = 0;
    loop {
        let accepted = tokio::select! {
            _ = stop.wait_for(|s| *s) => break,
            accepted = listener.accept() => accepted,
        };
        let stream = match accepted {
            Ok((stream, _)) => stream,
            Err(error) => {
                tracing::warn!(%error, "metrics endpoint: accept failed");
                tokio::time::sleep(Duration::from_millis(100)).await;
                continue;
            }
        };
        let Ok(slot) = Arc::clone(&slots).try_acquire_owned() else {
            // Closed at once; the first refusal and every 1,000th after it are logged.
            if refused.is_multiple_of(1000) {
                tracing::warn!(
                    refused = refused + 1,
                    "metrics endpoint: {MAX_HTTP_CONNECTIONS} connections open, closing new ones"
                );
            }
            refused += 1;
            drop(stream);
            continue;
        };
        let state = Arc::clone(&state);
        tokio::spawn(async move {
            let service = service_fn(move |request| {
                let state = Arc::clone(&state);
                async move { Ok::<_, std::convert::Infallible>(respond(&state, &request)) }
            });
            let connection = hyper::server::conn::http1::Builder::new()
                .timer(TokioTimer::new())
                .header_read_timeout(HTTP_HEADER_TIMEOUT)
                .serve_connection(TokioIo::new(stream), service);
            // A client that neither finishes nor closes its request is cut off.
            let _ = tokio::time::timeout(HTTP_CONNECTION_TIMEOUT, connection).await;
            drop(slot);
        });
    }
}

fn respond<B>(
    state: &HttpState,
    request: &hyper::Request<B>,
) -> hyper::Response<http_body_util::Full<hyper::body::Bytes>> {
    // HEAD is GET without the body (RFC 9110 §9.3.2: servers support both; `curl -I` health
    // checks use it); anything else is 405 with the methods that are allowed.
    let head = request.method() == hyper::Method::HEAD;
    let (status, content_type, body) = if request.method() != hyper::Method::GET && !head {
        (
            405,
            "text/plain",
            "only GET and HEAD are served\n".to_owned(),
        )
    } else {
        match request.uri().path() {
            "/metrics" => (
                200,
                "application/openmetrics-text; version=1.0.0; charset=utf-8",
                state.metrics_text(),
            ),
            "/health" | "/healthz" => {
                let (status, body) = state.health();
                (status, "application/json", body)
            }
            _ => (
                404,
                "text/plain",
                "not found; envlight serves /metrics and /health\n".to_owned(),
            ),
        }
    };
    let length = body.len();
    let body = if head { String::new() } else { body };
    let mut response = hyper::Response::new(http_body_util::Full::new(body.into()));
    *response.status_mut() =
        hyper::StatusCode::from_u16(status).unwrap_or(hyper::StatusCode::INTERNAL_SERVER_ERROR);
    let headers = response.headers_mut();
    if let Ok(value) = hyper::header::HeaderValue::from_str(content_type) {
        headers.insert(hyper::header::CONTENT_TYPE, value);
    }
    if head {
        // The length the GET would have sent.
        headers.insert(hyper::header::CONTENT_LENGTH, length.into());
    }
    if status == 405 {
        headers.insert(
            hyper::header::ALLOW,
            hyper::header::HeaderValue::from_static("GET, HEAD"),
        );
    }
    response
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::light::LightFrame;
    use crate::publication::{publish, Latest};

    /// A metrics address in use names the key to change; other errors get no hint.
    #[test]
    fn a_metrics_address_in_use_names_its_key() {
        let error = |kind| {
            DaemonError::Metrics {
                address: "127.0.0.1:9898".parse().unwrap(),
                source: std::io::Error::from(kind),
            }
            .to_string()
        };
        let e = error(std::io::ErrorKind::AddrInUse);
        assert!(e.contains("`listen`") && e.contains("[metrics]"), "{e}");
        let e = error(std::io::ErrorKind::PermissionDenied);
        assert!(!e.contains(';'), "{e}");
    }

    /// The health monitor marks the newest lights stale when the source is lost and, when it
    /// is back, leaves them stale until a fresh frame is published: the old lights are never
    /// published again as live (they were, with the stale frame's seq, before the fresh ones).
    #[test]
    fn a_source_that_comes_back_is_not_served_its_old_lights_as_live() {
        // A paused clock: each sleep below lets the monitor's interval tick exactly as often
        // as it says, however loaded the machine.
        let runtime = tokio::runtime::Builder::new_current_thread()
            .enable_all()
            .start_paused(true)
            .build()
            .unwrap();
        runtime.block_on(async {
            let (tx, rx) = watch::channel::<Latest<LightFrame>>(None);
            let tx = Arc::new(tx);
            let health = Arc::new(SourceHealth::default());
            let newest = || rx.borrow().clone().unwrap();
            publish(&tx, Arc::new(LightFrame::default()), None, Duration::ZERO);
            let monitor = tokio::spawn(monitor_health(
                Arc::clone(&health),
                StaleHandle::new(Arc::clone(&tx)),
                SlowStaleHandles {
                    asg: None,
                    wavelet: None,
                    sh: None,
                },
            ));
            health.mark_failure("unplugged");
            let deadline = Instant::now() + Duration::from_secs(10);
            while !newest().stale {
                assert!(Instant::now() < deadline, "never marked stale");
                tokio::time::sleep(Duration::from_millis(5)).await;
            }
            let stale = newest();
            assert_eq!(stale.index, 2);
            health.mark_ok();
            // Six ticks of the monitor: nothing is published until a fresh frame is.
            tokio::time::sleep(Duration::from_millis(300)).await;
            assert!(
                Arc::ptr_eq(&newest(), &stale),
                "the stale lights were re-published"
            );
            publish(&tx, Arc::new(LightFrame::default()), None, Duration::ZERO);
            tokio::time::sleep(Duration::from_millis(150)).await;
            let fresh = newest();
            assert_eq!((fresh.index, fresh.stale), (3, false));
            monitor.abort();
        });
    }
}
