//! envlight command line: parse arguments, run the subcommand (each in its module of [`cli`]),
//! and map errors to exit codes (2: usage error, reported by clap or, for options that do not
//! go together, as a [`UsageError`]; 1: runtime error; 0: success, also when the reader of
//! stdout goes away, as with `| head`).

use clap::{Parser, Subcommand};
use cli::{
    camera, daemon, decompose, fit_asg, print_to_stderr, render, sh, subscribe, wavelet, UsageError,
};
use std::io::IsTerminal;
use std::process::ExitCode;

mod cli;

const LONG_ABOUT: &str = "\
envlight turns HDR environment maps (a recorded .exr/.hdr sequence, or a built-in analytic sky)
into a few hundred temporally stable directional lights per frame, by inverse-transform sampling
of the luminance (Havran et al. 2005).

Coordinates: right-handed, +Y up. In a lat-long map row 0 is the zenith and the left edge
(u = 0) looks along -Z, u = 0.25 along +X, u = 0.5 along +Z (Mitsuba 3's axes); pixel (x, y)
is centred at u = (x + 0.5)/W, v = (y + 0.5)/H.

Units: a light's `rgb` is the environment radiance integrated over the light's region of the
sphere (W/m² at normal incidence, per channel), so the lights of a frame sum to the map's
integral; `solid_angle` is in steradians.";

#[derive(Parser, Debug)]
#[command(
    name = "envlight",
    version,
    about = "Real-time lighting from HDR environment maps: frames in, directional lights out",
    long_about = LONG_ABOUT,
    arg_required_else_help = true
)]
struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Decompose HDR frames (files or the built-in sky) into directional lights (JSON Lines).
    #[command(long_about = decompose::LONG_ABOUT)]
    Decompose(Box<decompose::DecomposeArgs>),
    /// Run the daemon: capture, decompose, and serve light lists over UDS, TCP and WebSocket.
    #[command(long_about = daemon::RUN_LONG_ABOUT)]
    Run(daemon::RunArgs),
    /// Run the daemon and record the session (input frames as EXR, timestamps, light stream).
    #[command(long_about = daemon::RECORD_LONG_ABOUT)]
    Record(daemon::RecordArgs),
    /// Validate a config file without running anything.
    CheckConfig(daemon::CheckConfigArgs),
    /// Fit anisotropic spherical Gaussians to HDR frames (files or the built-in sky), JSON Lines.
    #[command(long_about = fit_asg::LONG_ABOUT)]
    FitAsg(fit_asg::FitAsgArgs),
    /// Connect to a running daemon and print its light stream (or ASG, wavelet or SH sets).
    #[command(long_about = subscribe::LONG_ABOUT)]
    Subscribe(subscribe::SubscribeArgs),
    /// List V4L2 cameras (all, or the ones named) with their formats, frame sizes, rates and
    /// controls.
    Devices(camera::DevicesArgs),
    /// Recover a camera's response curve from bracketed exposures (Debevec & Malik 1997) and
    /// write the curve file for `[camera] response = "curve"`.
    CalibrateResponse(camera::CalibrateResponseArgs),
    /// Find a fisheye image circle automatically and print the `[source.fisheye]` lines.
    CalibrateFisheye(camera::CalibrateFisheyeArgs),
    /// Render a scene under the lights: one tone-mapped PNG and one linear EXR per frame.
    #[command(long_about = render::LONG_ABOUT)]
    Render(render::RenderArgs),
    /// Wavelet lighting: sparse wavelet sets of HDR frames (`approx`), relighting a mesh
    /// (`relight`) and recovering lighting from observations (`recover`).
    Wavelet(wavelet::WaveletArgs),
    /// Spherical-harmonic coefficients of HDR frames (files or the built-in sky), JSON Lines.
    #[command(long_about = sh::LONG_ABOUT)]
    Sh(sh::ShArgs),
}

/// The command line, parsed so that a value starting with '-' reaches its option's parser and
/// checks: `--fps -5` then reports the option's own range (clap would otherwise take `-5` for
/// an unknown flag and suggest `-- -5`, which does not help). An option whose values are
/// numbers (or pairs, sizes or lists of them) takes any value that starts with '-' (`-inf`,
/// `-1x-1`, `-0.01,0.1`; a flag given where its value should be is then a value its parser
/// refuses, naming the option); the other options take negative numbers (clap's test: `-5`,
/// `-0.5`, `-1e3`), so a missing path value is still reported as missing.
fn parse_command_line() -> Cli {
    fn allow_negative_values(command: clap::Command) -> clap::Command {
        use std::any::TypeId;
        let numeric = [
            TypeId::of::<f64>(),
            TypeId::of::<f32>(),
            TypeId::of::<u64>(),
            TypeId::of::<u32>(),
            TypeId::of::<u16>(),
            TypeId::of::<u8>(),
            TypeId::of::<usize>(),
            TypeId::of::<(u32, u32)>(),
            TypeId::of::<[f64; 2]>(),
            TypeId::of::<glam::Vec3>(),
        ];
        command
            .mut_args(|arg| {
                if arg.is_positional() || !arg.get_action().takes_values() {
                    arg
                } else if numeric
                    .iter()
                    .any(|&t| arg.get_value_parser().type_id() == t)
                {
                    arg.allow_hyphen_values(true)
                } else {
                    arg.allow_negative_numbers(true)
                }
            })
            .mut_subcommands(allow_negative_values)
    }
    let mut command = allow_negative_values(<Cli as clap::CommandFactory>::command());
    let matches = command.get_matches_mut();
    // As `Cli::parse` does: an error is formatted with the command's usage before it exits.
    <Cli as clap::FromArgMatches>::from_arg_matches(&matches)
        .unwrap_or_else(|err| err.format(&mut command).exit())
}

fn main() -> ExitCode {
    quiet_vulkan_device_select();
    let cli = parse_command_line();
    init_tracing();
    let result = match cli.command {
        Command::Decompose(args) => decompose::run(&args),
        Command::Run(args) => daemon::run(args),
        Command::Record(args) => daemon::record(args),
        Command::CheckConfig(args) => daemon::check_config(&args),
        Command::Subscribe(args) => subscribe::run(&args),
        Command::Devices(args) => camera::devices(&args),
        Command::CalibrateResponse(args) => camera::calibrate_response(&args),
        Command::CalibrateFisheye(args) => camera::calibrate_fisheye(&args),
        Command::Render(args) => render::run(&args),
        Command::FitAsg(args) => fit_asg::run(&args),
        Command::Wavelet(args) => wavelet::run(&args),
        Command::Sh(args) => sh::run(&args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(err) if err.downcast_ref::<UsageError>().is_some() => {
            print_to_stderr(format_args!(
                "error: {err}\n\nFor more information, try '--help'."
            ));
            ExitCode::from(2)
        }
        Err(err) => {
            tracing::debug!("{err:?}");
            print_to_stderr(format_args!("error: {err}"));
            // Library errors often show their source in their own message too; print each
            // cause only when it adds something.
            let mut previous = err.to_string();
            for cause in err.chain().skip(1) {
                let text = cause.to_string();
                if !previous.contains(&text) {
                    print_to_stderr(format_args!("  caused by: {text}"));
                }
                previous = text;
            }
            ExitCode::FAILURE
        }
    }
}

/// Logs to stderr: info by default (`RUST_LOG` overrides), compact, colours only on a terminal,
/// no timestamps under systemd (journald adds its own).
fn init_tracing() {
    use tracing_subscriber::filter::{EnvFilter, LevelFilter};
    let filter = EnvFilter::builder()
        .with_default_directive(LevelFilter::INFO.into())
        .from_env_lossy();
    let builder = tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .with_ansi(std::io::stderr().is_terminal())
        // A write error is dropped: by default the subscriber reported it with `eprintln!`,
        // which panicked on the same broken stderr (`envlight run 2>&1 | head` exited 101).
        .log_internal_errors(false)
        .compact();
    if std::env::var_os("JOURNAL_STREAM").is_some() {
        builder.without_time().init();
    } else {
        builder.init();
    }
}

/// Turns off Mesa's Vulkan device-selection layer where there is no session (no
/// `XDG_RUNTIME_DIR`: a service, a container, ssh without a login session): the layer probes
/// for a Wayland display and libwayland printed `error: XDG_RUNTIME_DIR is invalid or not set
/// in the environment.` twice on every render, which read as a failure. envlight chooses its
/// adapter itself (`ENVLIGHT_ADAPTER`, docs/rendering.md). An explicit `NODEVICE_SELECT` is
/// kept. Called first in `main`, before any thread exists.
fn quiet_vulkan_device_select() {
    if std::env::var_os("XDG_RUNTIME_DIR").is_none()
        && std::env::var_os("NODEVICE_SELECT").is_none()
    {
        std::env::set_var("NODEVICE_SELECT", "1");
    }
}
