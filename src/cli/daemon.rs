//! `envlight run`, `envlight record` and `envlight check-config`: the daemon's command line
//! (the daemon itself is `envlight::daemon`).

use super::{on_off, split_description, usage_error, Utf8Input};
use anyhow::{anyhow, Context, Result};
use clap::Args;
use envlight::config::{Config, ConfigError};
use envlight::daemon::{Daemon, DaemonOptions};
use envlight::record::Pacing;
use std::path::{Path, PathBuf};

pub(crate) const RUN_LONG_ABOUT: &str = "\
Run envlight as a daemon: a capture thread feeds frames to a decomposition thread, whose light
lists are served to any number of clients over a Unix domain socket, TCP and WebSocket
(docs/protocol.md), with Prometheus metrics and a health check over HTTP.

Endpoints and every other setting come from --config (see config/envlight.toml); without it the
built-in sky is served on the defaults: unix:/run/envlight/envlight.sock, tcp:127.0.0.1:7878,
ws://127.0.0.1:7879/ and http://127.0.0.1:9898/metrics (and /health). A daemon's sky runs until
stopped, at 30 frames/s, unless [source] sets `frames` or `fps` (envlight decompose's sky: 60
frames, as fast as possible).

Signals: SIGTERM / SIGINT shut down gracefully (clients get a goodbye, the socket file is
removed); SIGHUP reloads --config: [decompose], [asg], [wavelet] and [sh] apply from the next
frame (turning a stage on or off needs a restart), other changed sections are reported as
needing a restart, and a bad file changes nothing. Under systemd
(Type=notify) it reports READY, RELOADING and STOPPING and feeds the watchdog.

--replay DIR plays a recording (envlight record) at its original timing (--fast: as fast as
possible) with the recording's decomposition settings and no dropped frames, reproducing the
recorded light stream. A finite source ends the daemon once it has been served.";

pub(crate) const RECORD_LONG_ABOUT: &str = "\
Run the daemon (as `envlight run`) and record the session into --out DIR, which must be new or
empty: session.json (source, decomposition settings), frames.jsonl (seq, capture time, file and
projection of every frame that reached the decomposition), frames/NNNNNN.exr (32-bit float
linear RGB, 12 bytes per pixel: 47 MB/s for the 512x256 sky at 30 frames/s) and lights.jsonl
(the emitted light stream, as `envlight decompose` prints it). It records until SIGINT/SIGTERM
(Ctrl-C) or the end of a finite source; the built-in sky, unless [source] sets `frames`, runs
until stopped. Replay with `envlight run --replay DIR`.";

#[derive(Args, Debug)]
struct DaemonArgs {
    /// Config file (TOML; see config/envlight.toml). Reloaded on SIGHUP.
    #[arg(long, value_name = "FILE")]
    config: Option<PathBuf>,
    /// Input frames instead of the configured source: .exr/.hdr files, directories or globs;
    /// or one `v4l2:DEVICE`, a camera with the config's [camera] settings.
    #[arg(value_name = "INPUT", value_parser = Utf8Input)]
    inputs: Vec<String>,
}

#[derive(Args, Debug)]
pub(crate) struct RunArgs {
    #[command(flatten)]
    daemon: DaemonArgs,
    /// Replay a recording made by `envlight record` instead of the configured source.
    #[arg(long, value_name = "DIR", conflicts_with = "inputs")]
    replay: Option<PathBuf>,
    /// With --replay: as fast as possible instead of at the original timing.
    #[arg(long, requires = "replay")]
    fast: bool,
    /// Also record the session into DIR (new or empty).
    #[arg(long, value_name = "DIR")]
    record: Option<PathBuf>,
}

#[derive(Args, Debug)]
pub(crate) struct RecordArgs {
    #[command(flatten)]
    daemon: DaemonArgs,
    /// The recording directory (created; must be new or empty).
    #[arg(long, value_name = "DIR")]
    out: PathBuf,
}

#[derive(Args, Debug)]
pub(crate) struct CheckConfigArgs {
    /// The config file; without it the built-in defaults are checked and shown.
    #[arg(value_name = "FILE")]
    file: Option<PathBuf>,
    /// The config file, as the other subcommands take it (the same as FILE).
    #[arg(long = "config", value_name = "FILE", conflicts_with = "file")]
    config: Option<PathBuf>,
}

/// INPUT files of `envlight run`/`record`, which replace `[source]`.
fn source_paths(args: &DaemonArgs) -> Option<Vec<String>> {
    (!args.inputs.is_empty()).then(|| args.inputs.clone())
}

/// Loads the config (defaults without --config) with INPUT as the source.
fn daemon_config(args: &DaemonArgs) -> Result<Config> {
    crate::cli::refuse_camera_among_files(&args.inputs)?;
    let paths = source_paths(args);
    envlight::daemon::read_config(args.config.as_deref(), paths.as_deref()).map_err(|e| match &e {
        // INPUT replaced source.paths: a bad one is the command line's, not the file's.
        ConfigError::Invalid {
            key: "source.paths",
            value,
            message,
        } if paths.is_some() => crate::cli::usage(format!("invalid INPUT {value}: {message}")),
        _ => naming_the_file(e, args.config.as_deref()),
    })
}

/// A config error that names `path`: an invalid value names only its key (read and parse
/// errors name the file already).
pub(crate) fn naming_the_file(e: ConfigError, path: Option<&Path>) -> anyhow::Error {
    match (path, &e) {
        (Some(path), ConfigError::Invalid { .. }) => {
            anyhow!(e).context(format!("invalid setting in {}", path.display()))
        }
        _ => anyhow!(e),
    }
}

fn run_daemon(args: &DaemonArgs, options: DaemonOptions) -> Result<()> {
    let config = daemon_config(args)?;
    // The config file is an input too (the daemon checks the frames and the scene).
    if let (true, Some(png), Some(file)) = (
        config.render.enabled,
        &config.render.latest_png,
        &args.config,
    ) {
        envlight::daemon::refuse_latest_png_over(png, std::slice::from_ref(file))?;
    }
    envlight::daemon::hold_stop_signals();
    let daemon = Daemon::start(config, options)?;
    let addresses = daemon.addresses().clone();
    if let Some(path) = &addresses.stream.unix_socket {
        tracing::info!("clients: envlight subscribe unix:{}", path.display());
    }
    if let Some(addr) = addresses.stream.tcp {
        tracing::info!("clients: envlight subscribe tcp:{addr}");
    }
    if let Some(addr) = addresses.stream.websocket {
        tracing::info!("clients: envlight subscribe ws://{addr}/");
    }
    if let Some(addr) = addresses.metrics {
        tracing::info!("metrics: http://{addr}/metrics, health: http://{addr}/health");
    }
    let (_reason, summary) = daemon.run(args.config.as_deref())?;
    if let Some(recorded) = summary.recorded {
        tracing::info!("recorded {} frames", recorded.frames);
    }
    Ok(())
}

pub(crate) fn check_config(args: &CheckConfigArgs) -> Result<()> {
    let file = args.file.as_ref().or(args.config.as_ref());
    let (config, name) = match file {
        Some(path) => (
            Config::from_file(path).map_err(|e| naming_the_file(e, Some(path)))?,
            path.display().to_string(),
        ),
        None => (Config::default(), "the built-in defaults".to_owned()),
    };
    use std::fmt::Write as _;
    let off = |a: Option<String>| a.unwrap_or_else(|| "off".to_owned());
    let mut text = String::new();
    writeln!(text, "{name}: ok")?;
    // As `envlight run` reads it (check-config guards the service's config).
    let daemon_source = envlight::daemon::daemon_source_defaults(config.clone()).source;
    let frames = match (daemon_source.frames, daemon_source.kind) {
        // `frames = 0` lifts the limit; a sequence not looped still ends with its files.
        (Some(0) | None, envlight::config::SourceKind::Sequence) if daemon_source.looped => {
            "looped until stopped".to_owned()
        }
        (Some(0) | None, envlight::config::SourceKind::Sequence) => "every file once".to_owned(),
        (Some(0) | None, _) => "until stopped".to_owned(),
        (Some(n), _) => format!("{n} frames"),
    };
    let pacing = match (daemon_source.kind, daemon_source.fps) {
        (envlight::config::SourceKind::V4l2, _) => match config.camera.fps {
            Some(fps) => format!(
                "{} frames/s requested from the camera",
                envlight::config::shown_number(fps)
            ),
            None => "at the camera driver's rate".to_owned(),
        },
        (_, Some(fps)) => format!("{} frames/s", envlight::config::shown_number(fps)),
        (_, None) => "as fast as possible".to_owned(),
    };
    // The files are looked up as `envlight run` will (a pattern that matches nothing, a
    // missing file or a folder without frames is an error here too).
    let mut source_files: Vec<PathBuf> = Vec::new();
    let paths = match daemon_source.kind {
        envlight::config::SourceKind::Sequence => {
            use envlight::capture::FrameSource as _;
            let found = envlight::capture::sequence::SequenceSource::new(
                &daemon_source.paths,
                envlight::capture::sequence::SequenceOptions::default(),
            )
            .with_context(|| format!("{name}: source.paths"))?;
            source_files = found.files().to_vec();
            let n = found.frame_count();
            format!(
                " {:?} ({n} file{})",
                daemon_source.paths,
                if n == 1 { "" } else { "s" }
            )
        }
        _ => String::new(),
    };
    writeln!(
        text,
        "  source: {}{paths}, projection {}, in envlight run {frames}, {pacing}",
        daemon_source.kind.name(),
        projection_description(&daemon_source.projection)
    )?;
    if !daemon_source.ignored_fisheye.is_empty() {
        writeln!(
            text,
            "  note: {} set, but the projection is not \"fisheye\": the calibration is not used",
            daemon_source.ignored_fisheye.join(", ")
        )?;
    }
    writeln!(
        text,
        "  decompose: {} lights, warp {}, refinement of concentrated sources {}, concentrated \
         Lloyd step {}, split of bright lights {}, filter {} (bright lights: {}), merge {}",
        config.decompose.lights,
        envlight::config::warp_name(config.decompose.warp),
        on_off(config.decompose.refine_concentrated),
        on_off(config.decompose.concentrated_lloyd),
        split_description(config.decompose.split_factor),
        on_off(config.decompose.filter_taps.is_some()),
        config.decompose.bright_history.name(),
        config
            .decompose
            .merge_spacing_fraction
            .map_or("off".to_string(), |f| format!("at {f} of the spacing")),
    )?;
    writeln!(
        text,
        "  stream: unix {}, tcp {}, websocket {}, at most {} clients",
        off(config
            .stream
            .unix_socket
            .as_ref()
            .map(|p| p.display().to_string())),
        off(config.stream.tcp.map(|a| a.to_string())),
        off(config.stream.websocket.map(|a| a.to_string())),
        config.stream.max_clients
    )?;
    writeln!(
        text,
        "  metrics: {}",
        off(config.metrics.listen.map(|a| format!("http://{a}/metrics")))
    )?;
    if config.render.enabled {
        writeln!(
            text,
            "  render: {}",
            render_description(&config, file.map(PathBuf::as_path), &source_files)
                .with_context(|| name.clone())?
        )?;
    } else {
        writeln!(text, "  render: off")?;
    }
    if config.asg.enabled {
        let fit = &config.asg.settings.fit;
        writeln!(
            text,
            "  asg: {} lobes on a {}x{} fit map, {} + {} warm iterations, {}, {}",
            fit.lobes,
            2 * fit.height,
            fit.height,
            fit.iterations,
            fit.warm_iterations,
            match fit.threads {
                0 => "a thread per core".to_string(),
                n => format!("{n} thread(s)"),
            },
            stage_filter(config.asg.filter, config.asg.settings.filter_taps.is_some())
        )?;
    } else {
        writeln!(text, "  asg: off")?;
    }
    if config.wavelet.enabled {
        let w = &config.wavelet.settings;
        writeln!(
            text,
            "  wavelet: {} largest {} coefficients of a {}x{} octahedral map ({} levels), {}",
            w.coefficients,
            w.basis,
            w.side,
            w.side,
            w.levels(),
            stage_filter(config.wavelet.filter, w.filter_taps.is_some())
        )?;
    } else {
        writeln!(text, "  wavelet: off")?;
    }
    if config.sh.enabled {
        let degree = config.sh.settings.degree;
        writeln!(
            text,
            "  sh: spherical harmonics up to degree {degree} ({} coefficients per channel), {}",
            envlight::sh::coefficient_count(degree),
            stage_filter(config.sh.filter, config.sh.settings.filter_taps.is_some())
        )?;
    } else {
        writeln!(text, "  sh: off")?;
    }
    crate::cli::output::print(&text)
}

/// How an ASG, wavelet or SH stage is filtered in time: `filter` as configured, `filtered` in effect
/// (the lights' taps, when the lights are filtered).
fn stage_filter(filter: bool, filtered: bool) -> &'static str {
    match (filter, filtered) {
        (_, true) => "filtered with the lights' taps",
        (true, false) => "not filtered (the lights are not)",
        (false, false) => "not filtered (filter = false)",
    }
}

/// `check-config`'s line for an enabled `[render]`, after the checks `envlight run` makes
/// when the render thread starts: the scene is loaded (a file of an unknown format or that
/// does not parse fails here, not at start), and `latest_png` may be none of the inputs (the
/// source's files, the scene, the config file).
fn render_description(
    config: &Config,
    config_file: Option<&Path>,
    source_files: &[PathBuf],
) -> Result<String> {
    let render = &config.render;
    let scene = match &render.scene {
        Some(path) => {
            let mut scene = envlight::render::scene::Scene::load(path, true)
                .with_context(|| "render.scene".to_owned())?;
            scene
                .select_animation(&render.animation)
                .map_err(|m| anyhow::anyhow!("render.animation: {m}"))?;
            let triangles = scene.caster_indices / 3;
            let animation = match scene.playing_animation() {
                Some((index, name, seconds)) => {
                    format!(", animation {index} ({name:?}, {seconds:.3} s) played")
                }
                None => String::new(),
            };
            format!(
                "scene {} ({triangles} triangle{} casting shadows{animation})",
                path.display(),
                if triangles == 1 { "" } else { "s" }
            )
        }
        None => "the built-in scene".to_owned(),
    };
    let png = match &render.latest_png {
        Some(png) => {
            let inputs: Vec<PathBuf> = source_files
                .iter()
                .chain(&render.scene)
                .chain(config_file.map(Path::to_path_buf).as_ref())
                .cloned()
                .collect();
            envlight::daemon::refuse_latest_png_over(png, &inputs)?;
            format!("newest image to {}", png.display())
        }
        None => "no image file".to_owned(),
    };
    let lighting = match render.lighting {
        envlight::config::Lighting::Lights => "the lights with shadows".to_owned(),
        envlight::config::Lighting::Asg => "the ASG lobes".to_owned(),
        envlight::config::Lighting::Sh => "the SH coefficients (unshadowed)".to_owned(),
    };
    let budget = render.budget_ms.map_or("every light".to_owned(), |ms| {
        format!(
            "light count held to {} ms a frame",
            envlight::config::shown_number(ms)
        )
    });
    Ok(format!(
        "{}x{}, {scene}, lit by {lighting}, {budget}, {png}",
        render.settings.width, render.settings.height
    ))
}

/// `envlight run`: the daemon, or the replay of a recording (`--replay DIR`).
pub(crate) fn run(args: RunArgs) -> Result<()> {
    // clap's `requires` on --fast is not enforced once INPUT is given.
    if args.fast && args.replay.is_none() {
        usage_error!("--fast paces a replay (--replay DIR); INPUT files are paced by [source] fps");
    }
    let replay = args.replay.map(|dir| {
        let pacing = if args.fast {
            Pacing::AsFastAsPossible
        } else {
            Pacing::Original
        };
        (dir, pacing)
    });
    let options = DaemonOptions {
        replay,
        record: args.record,
        source_paths: source_paths(&args.daemon),
    };
    run_daemon(&args.daemon, options)
}

/// `envlight record`: the daemon, recording its session into `--out DIR`.
pub(crate) fn record(args: RecordArgs) -> Result<()> {
    let options = DaemonOptions {
        replay: None,
        record: Some(args.out),
        source_paths: source_paths(&args.daemon),
    };
    run_daemon(&args.daemon, options)
}

/// A projection as `check-config` shows it: its config name, and a fisheye's calibration.
fn projection_description(projection: &envlight::envmap::Projection) -> String {
    use envlight::config::shown_number;
    match projection {
        envlight::envmap::Projection::Fisheye(c) => {
            let center = c.center.map_or("the image centre".to_owned(), |[x, y]| {
                format!("[{}, {}]", shown_number(x), shown_number(y))
            });
            let radius = c.radius.map_or("half the shorter side".to_owned(), |r| {
                format!("{} px", shown_number(r))
            });
            format!(
                "fisheye ({}, field of view {}°, centre {center}, radius {radius}, rotation {}°)",
                c.model.name(),
                shown_number(c.fov_deg),
                shown_number(c.rotation_deg)
            )
        }
        other => other.name().to_owned(),
    }
}
