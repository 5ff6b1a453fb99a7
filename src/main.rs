//! envlight command line: parse arguments, build the configuration, call the library, and map
//! errors to exit codes (2: usage error, reported by clap or, for options that do not go
//! together, as a [`UsageError`]; 1: runtime error; 0: success, also when the reader of stdout
//! goes away, as with `| head`).

use anyhow::{anyhow, bail, Context, Result};
use clap::{Args, Parser, Subcommand, ValueEnum};
use envlight::capture::sequence::{SequenceOptions, SequenceSource};
use envlight::capture::sky::{SkyOptions, SkySource};
use envlight::capture::FrameSource;
use envlight::config::{Config, ConfigError, RawConfig, SourceKind};
use envlight::daemon::{Daemon, DaemonOptions};
use envlight::decompose::{BrightHistory, Decomposer};
use envlight::envmap::Projection;
use envlight::record::Pacing;
use std::io::{IsTerminal, Write};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::time::{Duration, Instant};

mod camera_cli;
mod cli_output;
mod wavelet_cli;
mod wavelet_transport_cli;

/// Parses an INPUT argument (a file, directory or glob pattern), refusing one that is not
/// UTF-8 with its name (glob patterns and config paths are UTF-8 text; clap's own message
/// did not say which argument it was). A file with such a name is still read when its
/// directory is given.
#[derive(Clone)]
struct Utf8Input;

impl clap::builder::TypedValueParser for Utf8Input {
    type Value = String;

    fn parse_ref(
        &self,
        cmd: &clap::Command,
        _arg: Option<&clap::Arg>,
        value: &std::ffi::OsStr,
    ) -> std::result::Result<String, clap::Error> {
        value.to_str().map(str::to_owned).ok_or_else(|| {
            clap::Error::raw(
                clap::error::ErrorKind::InvalidUtf8,
                format!(
                    "INPUT {:?} is not valid UTF-8; rename the file or give its directory \
                     (every .exr/.hdr in it is read)\n",
                    value.to_string_lossy()
                ),
            )
            .with_cmd(cmd)
        })
    }
}

/// A misuse of the command line that clap's parsing cannot see (options that do not go
/// together, an option that the chosen mode would ignore): exit status 2, like clap's own.
#[derive(Debug, thiserror::Error)]
#[error("{0}")]
pub(crate) struct UsageError(pub(crate) String);

/// Returns a [`UsageError`] from the enclosing function.
macro_rules! usage_error {
    ($($arg:tt)*) => {
        return Err(crate::UsageError(format!($($arg)*)).into())
    };
}
pub(crate) use usage_error;

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

const DECOMPOSE_LONG_ABOUT: &str = "\
Decompose frames into directional lights and print them as JSON Lines, one object per frame:

  {\"seq\":0,\"time\":0.0,\"lights\":[{\"id\":3,\"dir\":[0.71,0.60,-0.35],\"rgb\":[812.1,790.4,701.9],\"solid_angle\":0.0021}]}

seq: frame number; time: frame time in seconds; id: the light's index in the fixed point set
(stable across frames); dir: unit direction towards the light (+Y up); rgb: integrated radiance
(W/m² at normal incidence); solid_angle: size of the light's region or merged source (sr).

Without INPUT the built-in sky is rendered (60 frames unless --frames says otherwise).
Logs go to stderr (RUST_LOG overrides the level, e.g. RUST_LOG=debug).";

const RENDER_LONG_ABOUT: &str = "\
Render a scene (glTF 2.0 / OBJ via --scene, or the built-in spheres on a ground plane) under
directional lights with per-light PCF shadows, on the best graphics adapter (a GPU, else Mesa's
lavapipe). Lights come from --lights (the JSON Lines of `envlight decompose`), from INPUT frames
decomposed in-process, or from the built-in sky (1 frame unless --frames says otherwise).
Writes OUT/frame_NNNNN.png (tone-mapped sRGB, RGBA), OUT/frame_NNNNN.exr (linear, premultiplied
RGBA) and OUT/stats.jsonl (lights, shadow maps and time of every frame).
--catcher makes the ground a shadow catcher (RGBA to composite over a camera image);
--background composites over the environment map (not with --lights).
--budget-ms holds a frame time by rendering a prefix of the progressive light set.
--lighting asg shades instead with ASG lobes fitted to each INPUT frame (or sky frame), in closed
form (Lambert + GGX, no shadows; --lobes, --fit-height).";

#[derive(Args, Debug)]
struct RenderArgs {
    /// .exr/.hdr frames to decompose in-process. None (and no --lights): the built-in sky.
    #[arg(value_name = "INPUT", conflicts_with = "lights", value_parser = Utf8Input)]
    inputs: Vec<String>,
    /// Light list: JSON Lines as written by `envlight decompose`.
    #[arg(long, value_name = "FILE")]
    lights: Option<PathBuf>,
    /// Scene file (.gltf, .glb, .obj). [default: built-in spheres on a ground plane]
    #[arg(long, value_name = "FILE")]
    scene: Option<PathBuf>,
    /// Image size, 1..=16384 a side (the GPU's own limit applies too: 16384 on most).
    #[arg(long, value_name = "WxH", value_parser = parse_render_size, default_value = "640x360")]
    size: (u32, u32),
    /// Output folder (created if missing). Required unless --window.
    #[arg(long, value_name = "DIR", required_unless_present = "window")]
    out: Option<PathBuf>,
    /// Lights per frame when decomposing INPUT or the sky (1..=16384). [default: 256]
    #[arg(long, short = 'n', value_name = "N")]
    light_count: Option<usize>,
    /// Frames to render; 0 = every frame (the sky: until stopped). [default: every frame of
    /// --lights or INPUT; 1 for the sky]
    #[arg(long, value_name = "N")]
    frames: Option<u64>,
    /// Shadow-map side in texels (16..=8192). [default: 512]
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u32).range(16..=8192))]
    shadow_res: Option<u32>,
    /// How the shadow maps are drawn: `pipeline`, a depth-only render pass per light, or
    /// `compute`, compute shaders (faster where the raster pipeline is a small part of the GPU,
    /// as on an H200), or `auto`: compute on a GPU, pipeline on a CPU rasteriser such as
    /// lavapipe (docs/rendering.md). [default: auto]
    #[arg(long, value_name = "HOW", value_parser = parse_shadow_raster)]
    shadow_raster: Option<envlight::render::ShadowRaster>,
    /// No shadows.
    #[arg(long)]
    no_shadows: bool,
    /// No per-pixel light culling (every light takes the full path).
    #[arg(long)]
    no_culling: bool,
    /// The ground plane catches shadows: RGBA output to composite over a camera image.
    #[arg(long)]
    catcher: bool,
    /// Composite over the environment map (INPUT frames or the sky).
    #[arg(long, conflicts_with = "lights")]
    background: bool,
    /// Frame-time budget in ms: render the prefix of the light set (by id) that holds it.
    #[arg(long, value_name = "MS")]
    budget_ms: Option<f64>,
    /// Exposure scale before tone mapping. [default: from the first frame's median]
    #[arg(long, value_name = "X", value_parser = parse_finite_f32)]
    exposure: Option<f32>,
    /// Show the frames in a window instead of writing files (needs the `window` feature).
    #[arg(long, conflicts_with = "background")]
    window: bool,
    /// Shade with the decomposed lights (shadow maps) or with ASG lobes fitted to each frame
    /// (closed-form Lambert + GGX, no shadows; warm-started from frame to frame; not with
    /// --lights, --window, --budget-ms or --light-count).
    #[arg(long, value_enum, default_value = "lights")]
    lighting: LightingArg,
    /// ASG lobes per frame with --lighting asg (1..=64). [default: 16]
    #[arg(long, value_name = "K")]
    lobes: Option<usize>,
    /// Fit-map height with --lighting asg (width is twice; 4..=1024). [default: 64]
    #[arg(long, value_name = "H")]
    fit_height: Option<u32>,
}

/// `render --shadow-res` when not given.
const DEFAULT_SHADOW_RES: u32 = 512;

impl RenderArgs {
    /// The options that the chosen lighting or light source would ignore are usage errors.
    fn check_usage(&self) -> Result<()> {
        if self.lighting == LightingArg::Asg {
            let with = [
                (self.lights.is_some(), "--lights"),
                (self.window, "--window"),
                (self.budget_ms.is_some(), "--budget-ms"),
                (self.light_count.is_some(), "--light-count"),
                (self.shadow_res.is_some(), "--shadow-res"),
                (self.no_shadows, "--no-shadows"),
                (self.shadow_raster.is_some(), "--shadow-raster"),
                (self.no_culling, "--no-culling"),
            ];
            if let Some((_, flag)) = with.iter().find(|(given, _)| *given) {
                usage_error!(
                    "--lighting asg fits lobes to INPUT frames or the sky; {flag} applies to directional lights"
                );
            }
        } else if self.lobes.is_some() || self.fit_height.is_some() {
            usage_error!("--lobes and --fit-height apply to --lighting asg");
        }
        if self.no_shadows && self.shadow_res.is_some() {
            usage_error!("--shadow-res sizes the shadow maps; with --no-shadows there are none");
        }
        if self.no_shadows && self.shadow_raster.is_some() {
            usage_error!("--shadow-raster draws the shadow maps; with --no-shadows there are none");
        }
        if self.lights.is_some() && self.light_count.is_some() {
            usage_error!(
                "--light-count sets the lights of frames decomposed here (INPUT or the sky); --lights renders every light of each frame in the file"
            );
        }
        Ok(())
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
enum LightingArg {
    /// Directional lights from the decomposition, with shadow maps.
    Lights,
    /// Anisotropic spherical Gaussians fitted to each frame, in closed form.
    Asg,
}

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
    #[command(long_about = DECOMPOSE_LONG_ABOUT)]
    Decompose(Box<DecomposeArgs>),
    /// Run the daemon: capture, decompose, and serve light lists over UDS, TCP and WebSocket.
    #[command(long_about = RUN_LONG_ABOUT)]
    Run(RunArgs),
    /// Run the daemon and record the session (input frames as EXR, timestamps, light stream).
    #[command(long_about = RECORD_LONG_ABOUT)]
    Record(RecordArgs),
    /// Validate a config file without running anything.
    CheckConfig(CheckConfigArgs),
    /// Fit anisotropic spherical Gaussians to HDR frames (files or the built-in sky), JSON Lines.
    FitAsg(FitAsgArgs),
    /// Connect to a running daemon and print its light stream (or ASG or wavelet sets).
    #[command(long_about = SUBSCRIBE_LONG_ABOUT)]
    Subscribe(SubscribeArgs),
    /// List V4L2 cameras with their formats, frame sizes, rates and controls.
    Devices,
    /// Recover a camera's response curve from bracketed exposures (Debevec & Malik 1997) and
    /// write the curve file for `[camera] response = "curve"`.
    CalibrateResponse(camera_cli::CalibrateResponseArgs),
    /// Find a fisheye image circle automatically and print the `[source.fisheye]` lines.
    CalibrateFisheye(camera_cli::CalibrateFisheyeArgs),
    /// Render a scene under the lights: one tone-mapped PNG and one linear EXR per frame.
    #[command(long_about = RENDER_LONG_ABOUT)]
    Render(RenderArgs),
    /// Wavelet lighting: sparse wavelet sets of HDR frames (`approx`), relighting a mesh
    /// (`relight`) and recovering lighting from observations (`recover`).
    Wavelet(wavelet_cli::WaveletArgs),
}

const RUN_LONG_ABOUT: &str = "\
Run envlight as a daemon: a capture thread feeds frames to a decomposition thread, whose light
lists are served to any number of clients over a Unix domain socket, TCP and WebSocket
(docs/protocol.md), with Prometheus metrics and a health check over HTTP.

Endpoints and every other setting come from --config (see config/envlight.toml); without it the
built-in sky is served on the defaults: unix:/run/envlight/envlight.sock, tcp:127.0.0.1:7878,
ws://127.0.0.1:7879/ and http://127.0.0.1:9898/metrics (and /health). A daemon's sky runs until
stopped, at 30 frames/s, unless [source] sets `frames` or `fps` (envlight decompose's sky: 60
frames, as fast as possible).

Signals: SIGTERM / SIGINT shut down gracefully (clients get a goodbye, the socket file is
removed); SIGHUP reloads --config: [decompose] applies from the next frame, other changed
sections are reported as needing a restart, and a bad file changes nothing. Under systemd
(Type=notify) it reports READY, RELOADING and STOPPING and feeds the watchdog.

--replay DIR plays a recording (envlight record) at its original timing (--fast: as fast as
possible) with the recording's decomposition settings and no dropped frames, reproducing the
recorded light stream. A finite source ends the daemon once it has been served.";

const RECORD_LONG_ABOUT: &str = "\
Run the daemon (as `envlight run`) and record the session into --out DIR, which must be new or
empty: session.json (source, decomposition settings), frames.jsonl (seq, capture time, file and
projection of every frame that reached the decomposition), frames/NNNNNN.exr (32-bit float
linear RGB, 12 bytes per pixel: 47 MB/s for the 512x256 sky at 30 frames/s) and lights.jsonl
(the emitted light stream, as `envlight decompose` prints it). It records until SIGINT/SIGTERM
(Ctrl-C) or the end of a finite source; the built-in sky, unless [source] sets `frames`, runs
until stopped. Replay with `envlight run --replay DIR`.";

const SUBSCRIBE_LONG_ABOUT: &str = "\
Connect to a running envlight daemon and print the light lists it streams, until the daemon
says goodbye (or --frames have arrived).

ADDR is unix:PATH (or a path), tcp:HOST:PORT (or HOST:PORT), or ws://HOST:PORT/.
With --json every frame is printed as one JSON line (docs/protocol.md's JSON form); otherwise
one summary line per frame. --representation asg prints the ASG sets of a daemon whose [asg]
stage is enabled (--max-lights then caps the lobes); --representation wavelet the wavelet
coefficient sets of a daemon whose [wavelet] stage is enabled (--max-lights then caps the
coefficients: the scaling coefficient first, then the largest; the summary line's total rgb is
∫L dω from the scaling coefficient).";

#[derive(Args, Debug)]
struct DaemonArgs {
    /// Config file (TOML; see config/envlight.toml). Reloaded on SIGHUP.
    #[arg(long, value_name = "FILE")]
    config: Option<PathBuf>,
    /// Input frames instead of the configured source: .exr/.hdr files, directories or globs.
    #[arg(value_name = "INPUT", value_parser = Utf8Input)]
    inputs: Vec<String>,
}

#[derive(Args, Debug)]
struct RunArgs {
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
struct RecordArgs {
    #[command(flatten)]
    daemon: DaemonArgs,
    /// The recording directory (created; must be new or empty).
    #[arg(long, value_name = "DIR")]
    out: PathBuf,
}

#[derive(Args, Debug)]
struct CheckConfigArgs {
    /// The config file; without it the built-in defaults are checked and shown.
    #[arg(value_name = "FILE")]
    file: Option<PathBuf>,
}

#[derive(Args, Debug)]
struct SubscribeArgs {
    /// Where the daemon listens: unix:PATH, tcp:HOST:PORT, HOST:PORT or ws://HOST:PORT/.
    #[arg(value_name = "ADDR")]
    address: envlight::stream::client::Endpoint,
    /// Print every frame as a JSON line.
    #[arg(long)]
    json: bool,
    /// Ask for at most N lights per frame (the brightest); 0 = all.
    #[arg(long, value_name = "N", default_value_t = 0)]
    max_lights: u32,
    /// Stop after N frames (0: no limit, as without it).
    #[arg(long, value_name = "N")]
    frames: Option<u64>,
    /// Fail when the daemon sends nothing for this many seconds (the connection and its
    /// upgrade included). [default: wait for ever: a daemon paced slowly, replaying a pause or
    /// waiting for its camera may be silent for long]
    #[arg(long, value_name = "SECONDS", value_parser = parse_timeout)]
    timeout: Option<f64>,
    /// What to receive: directional lights, ASG sets (the daemon needs [asg] enabled) or
    /// wavelet coefficient sets (needs [wavelet] enabled); --max-lights then caps the lobes or
    /// the coefficients (the largest are kept).
    #[arg(long, value_enum, default_value = "lights")]
    representation: RepresentationArg,
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, ValueEnum)]
enum RepresentationArg {
    /// Directional lights.
    Lights,
    /// Anisotropic spherical Gaussians.
    Asg,
    /// Sparse wavelet coefficients of the environment (equal-area octahedral map).
    Wavelet,
}

#[derive(Clone, Copy, Debug, ValueEnum)]
enum ProjectionArg {
    /// Equirectangular (lat-long), row 0 = zenith.
    Latlong,
    /// Zenith-looking fisheye; see --fisheye-model, --center, --radius, --fov, --rotation.
    Fisheye,
    /// Light-probe angular map.
    Angular,
}

#[derive(Clone, Copy, Debug, ValueEnum)]
enum FisheyeModelArg {
    /// r = f·θ
    Equidistant,
    /// r = 2f·sin(θ/2)
    Equisolid,
    /// r = 2f·tan(θ/2)
    Stereographic,
    /// r = f·sin θ
    Orthographic,
}

#[derive(Clone, Copy, Debug, ValueEnum)]
enum WarpArg {
    /// Row-by-row inverse CDF, continuous in the point (default).
    Rows,
    /// k-d tree of mass splits: steadier lights when bright sources move.
    Hierarchical,
}

#[derive(Clone, Copy, Debug, ValueEnum)]
enum BrightHistoryArg {
    /// Group the window in 0.1° cones; older groups go to the light nearest to them now
    /// (default; ids and count stay those of the point set).
    Fold,
    /// Group the window in 0.1° cones; older groups are extra lights (ids from 2^24) that fade
    /// out over the window.
    Fade,
    /// The plain per-id mean (the filter before 2026-12-01).
    Blend,
}

#[derive(Clone, Copy, Debug, ValueEnum)]
enum PlacementArg {
    /// Luminance-weighted centroid of the light's region (most accurate).
    Centroid,
    /// The warped sample point (Havran et al. 2005).
    SamplePoint,
}

#[derive(Args, Debug)]
struct DecomposeArgs {
    /// .exr/.hdr files, directories or glob patterns (quote globs). None: the built-in sky.
    #[arg(value_name = "INPUT", value_parser = Utf8Input)]
    inputs: Vec<String>,

    /// TOML config file (see config/envlight.toml); flags override its values.
    #[arg(long, value_name = "FILE")]
    config: Option<PathBuf>,

    /// Number of lights per frame (1..=16384; merging may leave fewer). [default: 256]
    #[arg(long, short = 'n', value_name = "N")]
    lights: Option<usize>,

    /// Frames to process; 0 = no limit. [default: 60 for the sky, every file for a sequence]
    #[arg(long, value_name = "N")]
    frames: Option<u64>,

    /// Pace frames at F frames per second (at least 0.0001). [default: as fast as possible]
    #[arg(long, value_name = "F")]
    fps: Option<f64>,

    /// Replay the input sequence forever (stop with --frames or Ctrl-C).
    #[arg(long = "loop")]
    looped: bool,

    /// How input pixels map to directions. [default: latlong]
    #[arg(long, value_enum)]
    projection: Option<ProjectionArg>,

    /// Fisheye lens model. [default: equidistant]
    #[arg(long, value_enum, value_name = "MODEL")]
    fisheye_model: Option<FisheyeModelArg>,

    /// Fisheye image-circle centre in pixels. [default: image centre]
    #[arg(long, value_name = "X,Y", value_parser = parse_pair)]
    center: Option<[f64; 2]>,

    /// Fisheye image-circle radius in pixels, in (0, 1e6]. [default: half the shorter side]
    #[arg(long, value_name = "R")]
    radius: Option<f64>,

    /// Fisheye full field of view in degrees, in [1, 360). [default: 180]
    #[arg(long, value_name = "DEG")]
    fov: Option<f64>,

    /// Fisheye rotation about the zenith in degrees. [default: 0]
    #[arg(long, value_name = "DEG")]
    rotation: Option<f64>,

    /// Disable the temporal FIR filter.
    #[arg(long, conflicts_with = "taps")]
    no_filter: bool,

    /// FIR filter taps, newest frame first: non-negative weights, normalised to sum to 1.
    /// [default: 1,6,15,20,15,6,1]
    #[arg(
        long,
        value_name = "W,W,…",
        value_delimiter = ',',
        num_args = 1,
        value_parser = parse_tap
    )]
    taps: Option<Vec<f64>>,

    /// Merge lights crowding a concentrated source (the sun) into one light that records the
    /// source's spread in `solid_angle`. Off by default.
    #[arg(long)]
    merge: bool,

    /// Disable merging (overrides the config file).
    #[arg(long, conflicts_with_all = ["merge_fraction", "merge"])]
    no_merge: bool,

    /// Merge radius as a fraction of the mean light spacing, in (0, 2]; implies --merge.
    /// [default: 0.1]
    #[arg(long, value_name = "F")]
    merge_fraction: Option<f64>,

    /// Width of the internal lat-long working map in pixels (16..=4096). [default: 256]
    #[arg(long, value_name = "W")]
    working_width: Option<u32>,

    /// Threads that resample each frame that is not a lat-long map of a multiple of the working
    /// size (a fisheye camera's, an angular map's) to the working map, 1..=64, at most the
    /// machine's cores; the lights are the same with any number. [default: 2]
    #[arg(long, value_name = "N")]
    resample_threads: Option<usize>,

    /// Lights are placed with density ∝ luminance^γ, γ in (0, 1]; 1 is Havran et al.'s pure
    /// inverse-transform sampling. [default: 0.75]
    #[arg(long, value_name = "GAMMA")]
    pdf_exponent: Option<f64>,

    /// Where a light points within its region. [default: centroid]
    #[arg(long, value_enum)]
    placement: Option<PlacementArg>,

    /// How the fixed point set is warped onto the density: `rows` (continuous) or
    /// `hierarchical` (steadier under moving sources; see docs/quality.md). [default: rows]
    #[arg(long, value_enum)]
    warp: Option<WarpArg>,

    /// One Lloyd step for the lights holding lamps and suns (sharper shadows of small bright
    /// sources, about a third more time per frame; docs/quality.md). Off by default.
    #[arg(long)]
    concentrated_lloyd: bool,

    /// Leave out the refinement of lamps and suns: by default the lights holding them move to
    /// their regions' centroids and the sources' full-resolution pixels go again to their
    /// nearest light (69 rows of docs/quality.md's 72 beat median cut instead of 68, for about
    /// 7–10% more time per frame on the benchmark's map).
    #[arg(long)]
    no_refine_concentrated: bool,

    /// Split the lights of bright lamps and suns: a light holding a concentrated source and
    /// more than 3.5× the mean light's energy splits into up to 8 pieces, taken from the
    /// weakest lights (sharper lamp shadows, 71 of docs/quality.md's 72 rows against 69; with
    /// the filter on, 16–18% more ground flicker on two of its four sequences). Off by default.
    #[arg(long)]
    split: bool,

    /// Do not split bright lights (overrides the config file).
    #[arg(long, conflicts_with_all = ["split", "split_factor"])]
    no_split: bool,

    /// Energy, as a multiple (≥ 1) of the mean light's, above which a light holding a
    /// concentrated source splits; implies --split. [default: 3.5]
    #[arg(long, value_name = "F")]
    split_factor: Option<f64>,

    /// What the filter does with the window of a light brighter than 10× the frame's mean light
    /// (a sun's or a lamp's, whose few pixels change hands between lights): see
    /// docs/quality.md, "Temporal stability". [default: fold]
    #[arg(long, value_enum, value_name = "HOW")]
    bright_history: Option<BrightHistoryArg>,

    /// Size of the built-in sky map in pixels, at most 16384 a side and 16384x8192 in all
    /// (about 68 bytes a pixel). [default: 512x256]
    #[arg(long, value_name = "WxH", value_parser = parse_size)]
    sky_size: Option<(u32, u32)>,

    /// Render the built-in sky without clouds.
    #[arg(long)]
    no_clouds: bool,

    /// Seed of the sky's clouds. [default: 2]
    #[arg(long)]
    seed: Option<u64>,

    /// Capture from a V4L2 camera (path or name; see `envlight devices` and `[camera]`).
    /// INPUT `v4l2:DEVICE` does the same.
    #[arg(long, value_name = "DEVICE", conflicts_with = "inputs")]
    device: Option<String>,

    /// Write the JSON lines to FILE (created or truncated) instead of stdout.
    #[arg(long, short = 'o', value_name = "FILE")]
    out: Option<PathBuf>,

    /// Also keep FILE holding only the newest frame's JSON, replaced atomically (written to
    /// FILE.tmp, then renamed) after every frame: bounded output for a long-running service.
    #[arg(long, value_name = "FILE")]
    latest: Option<PathBuf>,
}

fn parse_pair(s: &str) -> Result<[f64; 2], String> {
    let (x, y) = s
        .split_once(',')
        .ok_or_else(|| format!("expected X,Y (two numbers), got {s:?}"))?;
    let num = |v: &str| {
        v.trim()
            .parse::<f64>()
            .map_err(|e| format!("{v:?} is not a number: {e}"))
    };
    Ok([num(x)?, num(y)?])
}

fn parse_shadow_raster(s: &str) -> Result<envlight::render::ShadowRaster, String> {
    envlight::render::ShadowRaster::parse(s)
        .ok_or_else(|| format!("expected \"auto\", \"pipeline\" or \"compute\", got {s:?}"))
}

fn parse_size(s: &str) -> Result<(u32, u32), String> {
    let (w, h) = s
        .split_once(['x', 'X'])
        .ok_or_else(|| format!("expected WIDTHxHEIGHT, got {s:?}"))?;
    let num = |v: &str| {
        v.trim()
            .parse::<u32>()
            .map_err(|e| format!("{v:?} is not a pixel count: {e}"))
    };
    Ok((num(w)?, num(h)?))
}

/// A number an option holds as f32: one beyond f32's range (`1e39`) is an error naming it,
/// not infinity (which later checks reported as "got inf", without the value given).
pub(crate) fn parse_finite_f32(s: &str) -> Result<f32, String> {
    let x: f64 = (s.trim().parse()).map_err(|_| format!("{s:?} is not a number"))?;
    if x.is_finite() && x.abs() <= f64::from(f32::MAX) {
        Ok(x as f32)
    } else {
        Err(format!(
            "{s} is not a finite number of single precision (at most 3.4e38)"
        ))
    }
}

/// One weight of `--taps` (spaces around it allowed, as in `--taps "1, 2, 1"`).
fn parse_tap(s: &str) -> Result<f64, String> {
    s.trim()
        .parse()
        .map_err(|_| format!("{s:?} is not a number"))
}

/// `render --size`: [`parse_size`] within 1..=[`envlight::config::MAX_RENDER_SIDE`] a side, as
/// `render.width` and `render.height` are.
fn parse_render_size(s: &str) -> Result<(u32, u32), String> {
    let (w, h) = parse_size(s)?;
    let max = envlight::config::MAX_RENDER_SIDE;
    if (1..=max).contains(&w) && (1..=max).contains(&h) {
        Ok((w, h))
    } else {
        Err(format!("{w}x{h}: each side must be 1..={max} pixels"))
    }
}

impl DecomposeArgs {
    /// Applies the flags to the raw configuration. Returns, for each config key a flag set,
    /// the flag's name (so validation errors can name the flag).
    fn apply(&self, raw: &mut RawConfig) -> Result<Vec<(&'static str, &'static str)>> {
        let mut set = Vec::new();
        let mut note = |key, flag| set.push((key, flag));
        let device = self
            .device
            .clone()
            .or_else(|| match self.inputs.as_slice() {
                [one] => one.strip_prefix("v4l2:").map(str::to_string),
                _ => None,
            });
        if let Some(dev) = device {
            raw.source.kind = Some("v4l2".into());
            raw.camera.device = Some(dev);
        }
        let src = &mut raw.source;
        if !self.inputs.is_empty() && src.kind.as_deref() != Some("v4l2") {
            src.kind = Some("sequence".into());
            src.paths = Some(self.inputs.clone());
            note("source.paths", "INPUT");
        }
        if let Some(v) = self.frames {
            src.frames = Some(v);
        }
        if let Some(v) = self.fps {
            src.fps = Some(v);
            note("source.fps", "--fps");
        }
        if self.looped {
            if src.kind.as_deref().unwrap_or("sky") == "sky" {
                usage_error!(
                    "--loop replays INPUT files; the built-in sky is endless with --frames 0"
                );
            }
            src.looped = Some(true);
        }
        if let Some(p) = self.projection {
            let name = match p {
                ProjectionArg::Latlong => "latlong",
                ProjectionArg::Fisheye => "fisheye",
                ProjectionArg::Angular => "angular",
            };
            if name != "latlong" && src.kind.as_deref().unwrap_or("sky") == "sky" {
                usage_error!(
                    "--projection {name} maps INPUT files or a camera; the built-in sky is always \
                     lat-long"
                );
            }
            src.projection = Some(name.into());
            note("source.projection", "--projection");
        }
        let fisheye_flags = self.fisheye_model.is_some()
            || self.center.is_some()
            || self.radius.is_some()
            || self.fov.is_some()
            || self.rotation.is_some();
        let is_fisheye = src.projection.as_deref() == Some("fisheye");
        if fisheye_flags && !is_fisheye {
            usage_error!("--fisheye-model, --center, --radius, --fov and --rotation need --projection fisheye");
        }
        let fe = &mut src.fisheye;
        if let Some(m) = self.fisheye_model {
            fe.model = Some(
                match m {
                    FisheyeModelArg::Equidistant => "equidistant",
                    FisheyeModelArg::Equisolid => "equisolid",
                    FisheyeModelArg::Stereographic => "stereographic",
                    FisheyeModelArg::Orthographic => "orthographic",
                }
                .into(),
            );
        }
        if let Some(c) = self.center {
            fe.center = Some(c);
            note("source.fisheye.center", "--center");
        }
        if let Some(r) = self.radius {
            fe.radius = Some(r);
            note("source.fisheye.radius", "--radius");
        }
        if let Some(f) = self.fov {
            fe.fov_deg = Some(f);
            note("source.fisheye.fov_deg", "--fov");
        }
        if let Some(r) = self.rotation {
            fe.rotation_deg = Some(r);
            note("source.fisheye.rotation_deg", "--rotation");
        }

        let sky_flags = self.sky_size.is_some() || self.no_clouds || self.seed.is_some();
        if sky_flags && !self.inputs.is_empty() {
            usage_error!(
                "--sky-size, --no-clouds and --seed apply to the built-in sky, not to INPUT files"
            );
        }
        if let Some((w, h)) = self.sky_size {
            raw.sky.width = Some(w);
            raw.sky.height = Some(h);
            note("sky.width", "--sky-size");
            note("sky.height", "--sky-size");
        }
        if self.no_clouds {
            raw.sky.clouds = Some(false);
        }
        if let Some(s) = self.seed {
            raw.sky.seed = Some(s);
        }

        let dec = &mut raw.decompose;
        if let Some(n) = self.lights {
            dec.lights = Some(n);
            note("decompose.lights", "--lights");
        }
        if let Some(g) = self.pdf_exponent {
            dec.pdf_exponent = Some(g);
            note("decompose.pdf_exponent", "--pdf-exponent");
        }
        if let Some(w) = self.working_width {
            dec.working_width = Some(w);
            note("decompose.working_width", "--working-width");
        }
        if let Some(n) = self.resample_threads {
            dec.resample_threads = Some(n);
            note("decompose.resample_threads", "--resample-threads");
        }
        if let Some(w) = self.warp {
            dec.warp = Some(
                match w {
                    WarpArg::Rows => "rows",
                    WarpArg::Hierarchical => "hierarchical",
                }
                .into(),
            );
            note("decompose.warp", "--warp");
        }
        if self.concentrated_lloyd {
            dec.concentrated_lloyd = Some(true);
            note("decompose.concentrated_lloyd", "--concentrated-lloyd");
        }
        if self.no_refine_concentrated {
            dec.refine_concentrated = Some(false);
            note("decompose.refine_concentrated", "--no-refine-concentrated");
        }
        if self.split {
            dec.split = Some(true);
            note("decompose.split", "--split");
        }
        if self.no_split {
            dec.split = Some(false);
            note("decompose.split", "--no-split");
        }
        if let Some(f) = self.split_factor {
            dec.split = Some(true);
            dec.split_factor = Some(f);
            note("decompose.split", "--split-factor");
            note("decompose.split_factor", "--split-factor");
        }
        if let Some(b) = self.bright_history {
            dec.bright_history = Some(
                match b {
                    BrightHistoryArg::Fold => BrightHistory::Fold,
                    BrightHistoryArg::Fade => BrightHistory::Fade,
                    BrightHistoryArg::Blend => BrightHistory::Blend,
                }
                .name()
                .into(),
            );
        }
        if let Some(p) = self.placement {
            dec.placement = Some(
                match p {
                    PlacementArg::Centroid => "centroid",
                    PlacementArg::SamplePoint => "sample-point",
                }
                .into(),
            );
            note("decompose.placement", "--placement");
        }
        if self.no_filter {
            dec.filter = Some(false);
        }
        if let Some(taps) = &self.taps {
            dec.filter = Some(true);
            dec.filter_taps = Some(taps.clone());
            note("decompose.filter_taps", "--taps");
        }
        if self.merge {
            dec.merge = Some(true);
        }
        if self.no_merge {
            dec.merge = Some(false);
        }
        if let Some(f) = self.merge_fraction {
            dec.merge = Some(true);
            dec.merge_spacing_fraction = Some(f);
            note("decompose.merge_spacing_fraction", "--merge-fraction");
        }
        Ok(set)
    }
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
        Command::Decompose(args) => decompose(&args),
        Command::Run(args) => run_daemon(
            &args.daemon,
            DaemonOptions {
                replay: args.replay.map(|dir| {
                    let pacing = if args.fast {
                        Pacing::AsFastAsPossible
                    } else {
                        Pacing::Original
                    };
                    (dir, pacing)
                }),
                record: args.record,
                source_paths: source_paths(&args.daemon),
            },
        ),
        Command::Record(args) => run_daemon(
            &args.daemon,
            DaemonOptions {
                replay: None,
                record: Some(args.out),
                source_paths: source_paths(&args.daemon),
            },
        ),
        Command::CheckConfig(args) => check_config(&args),
        Command::Subscribe(args) => subscribe(&args),
        Command::Devices => camera_cli::devices(),
        Command::CalibrateResponse(args) => camera_cli::calibrate_response(&args),
        Command::CalibrateFisheye(args) => camera_cli::calibrate_fisheye(&args),
        Command::Render(args) => render(&args),
        Command::FitAsg(args) => fit_asg(&args),
        Command::Wavelet(args) => wavelet_cli::run(&args),
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(err) if err.downcast_ref::<UsageError>().is_some() => {
            eprintln!("error: {err}\n\nFor more information, try '--help'.");
            ExitCode::from(2)
        }
        Err(err) => {
            tracing::debug!("{err:?}");
            eprintln!("error: {err}");
            // Library errors often show their source in their own message too; print each
            // cause only when it adds something.
            let mut previous = err.to_string();
            for cause in err.chain().skip(1) {
                let text = cause.to_string();
                if !previous.contains(&text) {
                    eprintln!("  caused by: {text}");
                }
                previous = text;
            }
            ExitCode::FAILURE
        }
    }
}

/// Loads the config (defaults without --config) with INPUT as the source.
/// INPUT files of `envlight run`/`record`, which replace `[source]`.
fn source_paths(args: &DaemonArgs) -> Option<Vec<String>> {
    (!args.inputs.is_empty()).then(|| args.inputs.clone())
}

fn daemon_config(args: &DaemonArgs) -> Result<Config> {
    let paths = source_paths(args);
    envlight::daemon::read_config(args.config.as_deref(), paths.as_deref())
        .map_err(|e| naming_the_file(e, args.config.as_deref()))
}

/// A config error that names `path`: an invalid value names only its key (read and parse
/// errors name the file already).
fn naming_the_file(e: ConfigError, path: Option<&Path>) -> anyhow::Error {
    match (path, &e) {
        (Some(path), ConfigError::Invalid { .. }) => {
            anyhow!(e).context(format!("invalid setting in {}", path.display()))
        }
        _ => anyhow!(e),
    }
}

fn run_daemon(args: &DaemonArgs, options: DaemonOptions) -> Result<()> {
    let config = daemon_config(args)?;
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

fn check_config(args: &CheckConfigArgs) -> Result<()> {
    let (config, name) = match &args.file {
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
        (Some(0), _) | (None, envlight::config::SourceKind::V4l2) => "until stopped".to_owned(),
        (Some(n), _) => format!("{n} frames"),
        (None, _) if daemon_source.looped => "looped until stopped".to_owned(),
        (None, _) => "every file once".to_owned(),
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
    let paths = match daemon_source.kind {
        envlight::config::SourceKind::Sequence => {
            let found = envlight::capture::sequence::SequenceSource::new(
                &daemon_source.paths,
                envlight::capture::sequence::SequenceOptions::default(),
            )
            .with_context(|| format!("{name}: source.paths"))?;
            format!(" {:?} ({} files)", daemon_source.paths, found.frame_count())
        }
        _ => String::new(),
    };
    writeln!(
        text,
        "  source: {}{paths}, in envlight run {frames}, {pacing}",
        daemon_source.kind.name()
    )?;
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
    if config.asg.enabled {
        writeln!(
            text,
            "  asg: {} lobes on a {}x{} fit map, {} + {} warm iterations, {}",
            config.asg.fit.lobes,
            2 * config.asg.fit.height,
            config.asg.fit.height,
            config.asg.fit.iterations,
            config.asg.fit.warm_iterations,
            match config.asg.fit.threads {
                0 => "a thread per core".to_string(),
                n => format!("{n} thread(s)"),
            }
        )?;
    } else {
        writeln!(text, "  asg: off")?;
    }
    if config.wavelet.enabled {
        let w = &config.wavelet.settings;
        writeln!(
            text,
            "  wavelet: {} largest {} coefficients of a {}x{} octahedral map ({} levels)",
            w.coefficients,
            w.basis,
            w.side,
            w.side,
            w.levels()
        )?;
    } else {
        writeln!(text, "  wavelet: off")?;
    }
    cli_output::print(&text)
}

/// `--timeout SECONDS` of `subscribe`: from a millisecond to a day.
fn parse_timeout(text: &str) -> Result<f64, String> {
    let seconds: f64 = text
        .parse()
        .map_err(|_| format!("{text:?} is not a number of seconds"))?;
    if (0.001..=86_400.0).contains(&seconds) {
        Ok(seconds)
    } else {
        Err(format!("{text} s: must be in 0.001..=86400"))
    }
}

fn subscribe(args: &SubscribeArgs) -> Result<()> {
    use envlight::stream::client::Client;
    use envlight::stream::{Format, Message, Representation, Request};
    let request = Request {
        max_lights: args.max_lights,
        format: if args.json {
            Format::Json
        } else {
            Format::Binary
        },
        representation: match args.representation {
            RepresentationArg::Lights => Representation::Lights,
            RepresentationArg::Asg => Representation::Asg,
            RepresentationArg::Wavelet => Representation::Wavelet,
        },
    };
    let timeout = args.timeout.map(std::time::Duration::from_secs_f64);
    let timed_out = |e: envlight::stream::client::ClientError| {
        if e.is_timeout() {
            anyhow!(
                "{}: no message within {} s (--timeout)",
                args.address,
                args.timeout.unwrap_or_default()
            )
        } else {
            anyhow!(e)
        }
    };
    let mut client = Client::connect(&args.address, &request, timeout).map_err(timed_out)?;
    let mut stdout = std::io::stdout().lock();
    let mut frames = 0u64;
    // --frames 0 is no limit, as for every command (it stopped at once, printing nothing).
    let limit = args.frames.filter(|&n| n > 0);
    while limit.is_none_or(|n| frames < n) {
        let Some(message) = client.next_message().map_err(timed_out)? else {
            bail!("{}: the daemon closed the connection", args.address);
        };
        let line = match message {
            Message::Frame(frame) => {
                frames += 1;
                if args.json {
                    let stale = frame.stale;
                    envlight::stream::protocol::frame_to_json(
                        &frame.into_light_frame(),
                        None,
                        stale,
                    )
                } else {
                    let total = frame.lights.iter().fold([0.0f64; 3], |s, l| {
                        [0, 1, 2].map(|c| s[c] + f64::from(l.rgb[c]))
                    });
                    format!(
                        "seq {} time {:.3} s: {} lights, total rgb [{:.4}, {:.4}, {:.4}]{}",
                        frame.seq,
                        frame.time,
                        frame.lights.len(),
                        total[0],
                        total[1],
                        total[2],
                        if frame.stale { " (stale)" } else { "" }
                    )
                }
            }
            Message::Asg(frame) => {
                frames += 1;
                if args.json {
                    let stale = frame.stale;
                    envlight::stream::protocol::asg_frame_to_json(
                        &frame.into_asg_set(),
                        None,
                        stale,
                    )
                } else {
                    let total = frame.lobes.iter().fold([0.0f64; 3], |s, l| {
                        [0, 1, 2].map(|c| s[c] + f64::from(l.rgb[c]) * f64::from(l.integral))
                    });
                    format!(
                        "seq {} time {:.3} s: {} ASG lobes, total rgb [{:.4}, {:.4}, {:.4}]{}",
                        frame.seq,
                        frame.time,
                        frame.lobes.len(),
                        total[0],
                        total[1],
                        total[2],
                        if frame.stale { " (stale)" } else { "" }
                    )
                }
            }
            Message::Wavelet(frame) => {
                frames += 1;
                let stale = frame.stale;
                let frame = frame.into_wavelet_frame();
                if args.json {
                    envlight::stream::protocol::wavelet_frame_to_json(&frame, None, stale)
                } else {
                    let total = frame.integral();
                    let set = &frame.set;
                    format!(
                        "seq {} time {:.3} s: {} wavelet coefficients ({} on {}², {} levels), \
                         total rgb [{:.4}, {:.4}, {:.4}]{}",
                        frame.seq,
                        frame.time,
                        set.coefficients.len(),
                        set.basis,
                        set.side,
                        set.levels,
                        total[0],
                        total[1],
                        total[2],
                        if stale { " (stale)" } else { "" }
                    )
                }
            }
            Message::Goodbye { message } => {
                tracing::info!("the daemon said goodbye: {message}");
                return Ok(());
            }
            Message::Error { code, message } => {
                bail!(
                    "{}: the daemon reported error {code}: {message}",
                    args.address
                )
            }
            Message::Subscribe(_) => {
                bail!("{}: unexpected subscribe from the daemon", args.address)
            }
        };
        let written = writeln!(stdout, "{line}").and_then(|()| stdout.flush());
        match written {
            Err(e) if cli_output::is_broken_pipe(&e) => return Ok(()),
            r => r.context("cannot write to stdout")?,
        }
    }
    Ok(())
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
        .compact();
    if std::env::var_os("JOURNAL_STREAM").is_some() {
        builder.without_time().init();
    } else {
        builder.init();
    }
}

fn decompose(args: &DecomposeArgs) -> Result<()> {
    let (mut raw, config_name) = match &args.config {
        Some(path) => (
            RawConfig::from_file(path)?,
            format!("config file {}", path.display()),
        ),
        None => (RawConfig::default(), "the built-in defaults".to_string()),
    };
    let flags = args.apply(&mut raw)?;
    let config = raw.validate().map_err(|e| match &e {
        // A value from a flag: name the flag, not the config key.
        ConfigError::Invalid {
            key,
            value,
            message,
        } => match flags.iter().find(|(k, _)| k == key) {
            // A switch (--split) has no value to show.
            Some((_, flag)) if value == "true" || value == "false" => {
                anyhow!("invalid {flag}: {message}")
            }
            Some((_, flag)) => anyhow!("invalid {flag} {value}: {message}"),
            None => anyhow!(e).context(format!("invalid setting in {config_name}")),
        },
        _ => anyhow!(e),
    })?;
    // The config file and the response curve it names are inputs too: no output may be them.
    let read: Vec<PathBuf> = (args.config.iter().cloned())
        .chain(raw.camera.curve.iter().map(PathBuf::from))
        .collect();
    run_decompose(&config, &read, args.out.as_deref(), args.latest.as_deref())
}

/// The configured frame source (sky, sequence or camera), limited to `source.frames` and with a
/// fisheye calibration checked against the frames: [`envlight::capture::open`].
fn open_source(config: &Config) -> Result<Box<dyn FrameSource>> {
    let context = match config.source.kind {
        SourceKind::Sky => "cannot set up the built-in sky",
        SourceKind::Sequence => "cannot open the input frames",
        SourceKind::V4l2 => "cannot open the camera",
    };
    envlight::capture::open(config).context(context)
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

/// Replaces `path` with `contents` atomically: readers see the old or the new file, never half.
fn replace_file(path: &Path, contents: &[u8]) -> std::io::Result<()> {
    // Again at each frame: a device or pipe may have taken the path since the start.
    envlight::read_file::check_replaceable(path, "--latest")?;
    let tmp = latest_tmp(path);
    std::fs::write(&tmp, contents)?;
    std::fs::rename(&tmp, path)
}

/// The temporary file `path` + `.tmp` through which [`replace_file`] replaces `path`.
fn latest_tmp(path: &Path) -> PathBuf {
    let mut tmp = path.as_os_str().to_owned();
    tmp.push(".tmp");
    PathBuf::from(tmp)
}

/// Decomposes `config`'s source into `out` (stdout when `None`) and `latest`; `read` lists the
/// files other than the frames that the command read (the config file, a response curve),
/// which no output may overwrite either.
fn run_decompose(
    config: &Config,
    read: &[PathBuf],
    out: Option<&Path>,
    latest: Option<&Path>,
) -> Result<()> {
    let mut source = open_source(config)?;
    let mut decomposer =
        Decomposer::new(config.decompose.clone()).context("invalid decomposition settings")?;
    let inputs = cli_output::InputFiles::new(&[source.files(), read].concat());
    if let Some(path) = latest {
        cli_output::check_output_path(path, "--latest")?;
        envlight::read_file::check_replaceable(path, "--latest")
            .with_context(|| format!("--latest {}", path.display()))?;
        inputs.refuse(path, "--latest")?;
        // --latest is replaced through LATEST.tmp: neither may be the --out file.
        if let Some(out) = out {
            for (file, what) in [
                (path.to_path_buf(), "--latest"),
                (latest_tmp(path), "--latest's temporary file"),
            ] {
                if cli_output::same_file(out, &file) {
                    bail!(
                        "--out {} is also {what} {}: the newest frame would replace the \
                         stream; choose another output path",
                        out.display(),
                        file.display()
                    );
                }
            }
        }
    }
    let mut writer = std::io::BufWriter::new(cli_output::open_output(out, "--out", &inputs)?);
    let out_name = out.map_or("stdout".to_string(), |p| p.display().to_string());

    tracing::info!("source: {}", source.describe());
    let d = &config.decompose;
    tracing::info!(
        "decomposing into {} lights (working width {}, placement {}, warp {}, density \
         exponent {}, refinement of concentrated sources {}, concentrated Lloyd step {}, split \
         of bright lights {}, filter {}, merge {})",
        d.lights,
        d.working_width,
        envlight::config::placement_name(d.placement),
        envlight::config::warp_name(d.warp),
        d.pdf_exponent,
        on_off(d.refine_concentrated),
        on_off(d.concentrated_lloyd),
        split_description(d.split_factor),
        d.filter_taps
            .as_ref()
            .map_or("off".to_string(), |t| format!(
                "{t:?}, bright lights: {}",
                d.bright_history.name()
            )),
        d.merge_spacing_fraction
            .map_or("off".to_string(), |f| format!("at {f} of the spacing")),
    );
    tracing::info!(
        "temporal filter delay: {} frames",
        decomposer.filter_delay_frames()
    );

    let mut frames = 0u64;
    let mut lights_total = 0u64;
    let mut decompose_time = Duration::ZERO;
    let mut line = Vec::with_capacity(64 * 1024);
    loop {
        let Some(frame) = source.next_frame().context("cannot read a frame")? else {
            break;
        };
        let start = Instant::now();
        let lights = decomposer.decompose(&frame);
        decompose_time += start.elapsed();
        frames += 1;
        lights_total += lights.lights.len() as u64;

        line.clear();
        serde_json::to_writer(&mut line, &lights).context("cannot serialise a light frame")?;
        line.push(b'\n');
        if let Some(path) = latest {
            replace_file(path, &line)
                .with_context(|| format!("cannot write the newest frame to {}", path.display()))?;
        }
        // Flush every frame: a consumer tailing the output sees whole frames as they come.
        let written = writer.write_all(&line).and_then(|()| writer.flush());
        match written {
            Err(e) if out.is_none() && cli_output::is_broken_pipe(&e) => {
                tracing::debug!("stdout closed after {frames} frames; stopping");
                return Ok(());
            }
            r => r.with_context(|| format!("cannot write to {out_name}"))?,
        }
    }
    match writer.flush() {
        Err(e) if out.is_none() && cli_output::is_broken_pipe(&e) => return Ok(()),
        r => r.with_context(|| format!("cannot write to {out_name}"))?,
    }

    let per_frame = |total: f64| {
        if frames > 0 {
            total / frames as f64
        } else {
            0.0
        }
    };
    tracing::info!(
        "done: {frames} frames, {:.1} lights/frame on average, {:.2} ms mean decomposition time per frame",
        per_frame(lights_total as f64),
        per_frame(decompose_time.as_secs_f64() * 1e3),
    );
    Ok(())
}

/// The frames of `render --lights`, read as they are rendered.
struct LightFileFrames {
    /// The first frame, read before rendering starts.
    first: Option<envlight::LightFrame>,
    reader: envlight::light::JsonLinesReader,
    /// The seqs rendered so far.
    seen: std::collections::HashSet<u64>,
}

impl LightFileFrames {
    /// The next frame, or the error of its line; a seq seen before is an error (each frame's
    /// images are named by its seq, so a repeat would overwrite them).
    fn next_frame(&mut self) -> Result<Option<envlight::LightFrame>> {
        let frame = match self.first.take() {
            Some(frame) => frame,
            None => match self.reader.next().transpose()? {
                Some(frame) => frame,
                None => return Ok(None),
            },
        };
        if !self.seen.insert(frame.seq) {
            bail!(
                "{}: frame seq {} appears more than once; the images of a frame are named by \
                 its seq (frame_NNNNN), so a repeat would overwrite them",
                self.reader.path().display(),
                frame.seq
            );
        }
        Ok(Some(frame))
    }
}

fn render(args: &RenderArgs) -> Result<()> {
    use envlight::render::{self, budget, output, scene::Scene, RenderSettings, Renderer};
    args.check_usage()?;
    if let Some(b) = args.budget_ms.filter(|b| !(b.is_finite() && *b > 0.0)) {
        bail!("invalid --budget-ms {b}: must be a positive number of milliseconds");
    }
    if args.exposure.is_some_and(|e| !(e.is_finite() && e > 0.0)) {
        bail!("invalid --exposure: must be a positive number");
    }
    let scene = match &args.scene {
        Some(path) => Scene::load(path, true)?,
        None => Scene::default_scene(),
    };
    let asg_lighting = args.lighting == LightingArg::Asg;
    let mut fitter = if asg_lighting {
        let settings = envlight::asg::fit::FitSettings {
            lobes: args.lobes.unwrap_or(envlight::asg::fit::DEFAULT_LOBES),
            height: args
                .fit_height
                .unwrap_or(envlight::config::DEFAULT_ASG_FIT_HEIGHT),
            ..envlight::asg::fit::FitSettings::default()
        };
        Some(
            envlight::asg::fit::AsgFitter::new(settings)
                .context("invalid --lobes or --fit-height")?,
        )
    } else {
        None
    };
    // Lights: a JSON Lines file, or frames decomposed here (INPUT or the sky).
    let mut from_file = None;
    let mut source = None;
    // The files read, which no output may overwrite.
    let mut inputs: Vec<PathBuf> = args.lights.iter().cloned().collect();
    if let Some(path) = &args.lights {
        // Read a frame at a time (a long session is gigabytes of JSON); the first frame is read
        // here, so an empty or unreadable file is refused before the GPU is set up.
        let mut reader = envlight::light::JsonLinesReader::open(path)?;
        let Some(first) = reader.next().transpose()? else {
            bail!(
                "{}: no light frames in it (expected the JSON Lines of `envlight decompose`)",
                path.display()
            );
        };
        from_file = Some(LightFileFrames {
            first: Some(first),
            reader,
            seen: std::collections::HashSet::new(),
        });
    } else {
        let mut raw = RawConfig::default();
        if !args.inputs.is_empty() {
            raw.source.kind = Some("sequence".into());
            raw.source.paths = Some(args.inputs.clone());
        }
        raw.source.frames = Some(args.frames.unwrap_or(u64::from(args.inputs.is_empty())));
        raw.decompose.lights = args.light_count;
        let config = raw.validate().map_err(|e| match &e {
            ConfigError::Invalid {
                key: "decompose.lights",
                value,
                message,
            } => anyhow!("invalid --light-count {value}: {message}"),
            _ => anyhow!(e).context("invalid INPUT"),
        })?;
        let src = open_source(&config)?;
        inputs.extend_from_slice(src.files());
        let dec =
            Decomposer::new(config.decompose.clone()).context("invalid decomposition settings")?;
        source = Some((src, dec));
    }
    let settings = RenderSettings {
        width: args.size.0,
        height: args.size.1,
        shadow_resolution: args.shadow_res.unwrap_or(DEFAULT_SHADOW_RES),
        shadows: !args.no_shadows,
        culling: !args.no_culling,
        shadow_catcher: args.catcher,
        shadow_raster: args.shadow_raster.unwrap_or_default(),
    };
    let mut next_frame =
        move || -> Result<Option<(envlight::LightFrame, Option<envlight::HdrFrame>)>> {
            if let Some(frames) = &mut from_file {
                return Ok(frames.next_frame()?.map(|f| (f, None)));
            }
            let Some((src, dec)) = &mut source else {
                return Ok(None);
            };
            Ok(src
                .next_frame()
                .context("cannot read a frame")?
                .map(|frame| {
                    // ASG lighting fits the frame itself; the lights are not needed.
                    let lights = if asg_lighting {
                        envlight::LightFrame {
                            seq: frame.seq,
                            time: frame.time,
                            lights: Vec::new(),
                        }
                    } else {
                        dec.decompose(&frame)
                    };
                    (lights, Some(frame))
                }))
        };
    let Some(out) = args.out.as_ref().filter(|_| !args.window) else {
        #[cfg(feature = "window")]
        {
            let source = Box::new(move || {
                next_frame()
                    .map(|f| f.map(|(l, _)| l.lights))
                    .map_err(|e| format!("{e:#}"))
            });
            let exposure = args.exposure.unwrap_or(0.02);
            render::window::run(scene, settings, exposure, args.budget_ms, source)?;
            return Ok(());
        }
        #[cfg(not(feature = "window"))]
        bail!("--window needs envlight built with `--features window`");
    };
    // --out is a folder of frame_NNNNN.png/.exr and stats.jsonl; `--out frame.png` would make
    // a folder of that name.
    let image_extension = out.extension().and_then(|e| e.to_str()).is_some_and(|e| {
        ["png", "exr", "hdr", "jpg", "jpeg"].contains(&e.to_ascii_lowercase().as_str())
    });
    if image_extension && !out.is_dir() {
        usage_error!(
            "--out {} looks like an image file, but --out is the folder the frames \
             (frame_00000.png, .exr) and stats.jsonl are written to; give a folder",
            out.display()
        );
    }
    let inputs = cli_output::InputFiles::new(&inputs);
    let mut renderer = Renderer::new(scene, settings)?;
    tracing::info!(
        "adapter: {}; shadow maps: {}",
        renderer.gpu().describe(),
        renderer.settings().shadow_raster.name()
    );
    std::fs::create_dir_all(out)
        .with_context(|| format!("cannot create output folder {}", out.display()))?;
    let stats_path = out.join("stats.jsonl");
    let mut stats_file =
        std::io::BufWriter::new(cli_output::create(&stats_path, "--out", &inputs)?);
    let mut controller = None;
    let mut warned_budget_cap = false;
    let mut exposure = args.exposure;
    let limit = args.frames.filter(|&n| n > 0);
    let mut done = 0u64;
    while limit.is_none_or(|n| done < n) {
        let Some((lights, env)) = next_frame()? else {
            break;
        };
        let all = render::light_prefix(&lights.lights, usize::MAX);
        // The controller's range is every light a list can hold, not the first frame's count
        // (which capped every later frame: a first frame of one light left one of 70 at one).
        let ctl = controller.get_or_insert_with(|| {
            args.budget_ms.map(|ms| {
                let settings = budget::BudgetSettings::new(ms, envlight::decompose::MAX_POINTS);
                budget::BudgetController::new(settings, all.len())
            })
        });
        let count = ctl.as_ref().map_or(all.len(), |c| c.count());
        if ctl.is_some() && all.len() > envlight::decompose::MAX_POINTS && !warned_budget_cap {
            warned_budget_cap = true;
            tracing::warn!(
                "frame {} has {} lights; --budget-ms draws at most {} of them (the first by id, \
                 a prefix of the progressive set; without --budget-ms every light is drawn)",
                lights.seq,
                all.len(),
                envlight::decompose::MAX_POINTS
            );
        }
        let (mut image, stats) = match (&mut fitter, &env) {
            (Some(fitter), Some(frame)) => {
                let fit = fitter
                    .fit_frame(frame)
                    .with_context(|| format!("cannot fit ASG lobes to frame {}", frame.seq))?;
                renderer.render_asg(&fit.lobes)?
            }
            _ => renderer.render(&all[..count.min(all.len())])?,
        };
        if let Some(c) = ctl.as_mut() {
            c.update(stats.frame_ms());
        }
        if let (true, Some(env)) = (args.background, &env) {
            let rays: Vec<_> = (0..image.height)
                .flat_map(|y| (0..image.width).map(move |x| (x, y)))
                .map(|(x, y)| renderer.pixel_ray(x as f32, y as f32))
                .collect();
            let w = image.width;
            output::composite_background(&mut image, |x, y| {
                let d = rays[(y * w + x) as usize].as_dvec3();
                env.projection
                    .direction_to_pixel(env.width, env.height, d)
                    .map_or([0.0; 3], |(px, py)| {
                        env.pixel(
                            (px as u32).min(env.width - 1),
                            (py as u32).min(env.height - 1),
                        )
                    })
            });
        }
        let saturated = output::saturate(&mut image);
        if saturated.infinite > 0 {
            tracing::warn!(
                "frame {}: {} pixel values beyond f32's range (lights too bright to sum) \
                 written as the largest f32",
                lights.seq,
                saturated.infinite
            );
        }
        if saturated.nan > 0 {
            tracing::warn!(
                "frame {}: {} pixel values not a number (a shading fault; please report it \
                 with the light list) written as 0",
                lights.seq,
                saturated.nan
            );
        }
        let exp = *exposure.get_or_insert_with(|| output::auto_exposure(&image));
        let stem = out.join(format!("frame_{:05}", lights.seq));
        for extension in ["png", "exr"] {
            inputs.refuse(&stem.with_extension(extension), "--out")?;
        }
        output::write_png(&stem.with_extension("png"), &image, exp)?;
        output::write_exr(&stem.with_extension("exr"), &image)?;
        let line = serde_json::json!({
            "seq": lights.seq, "lights": stats.lights, "shadow_maps": stats.shadow_maps,
            "gpu_ms": stats.gpu_ms, "shadow_gpu_ms": stats.shadow_gpu_ms,
            "cpu_ms": stats.cpu_ms, "frame_ms": stats.frame_ms(),
        });
        writeln!(stats_file, "{line}")
            .with_context(|| format!("cannot write {}", stats_path.display()))?;
        tracing::info!(
            "frame {}: {} lights, {} shadow maps, {:.2} ms ({})",
            lights.seq,
            stats.lights,
            stats.shadow_maps,
            stats.frame_ms(),
            if stats.gpu_ms.is_some() {
                "GPU timestamps"
            } else {
                "CPU time"
            }
        );
        done += 1;
    }
    stats_file
        .flush()
        .with_context(|| format!("cannot write {}", stats_path.display()))?;
    tracing::info!("rendered {done} frames into {}", out.display());
    Ok(())
}

/// `fit-asg`: one JSON line per frame,
/// {"seq","time","lobes":[{"axis","tangent","bitangent","lambda","mu","rgb"}],"loss"}.
#[derive(Args, Debug)]
struct FitAsgArgs {
    /// .exr/.hdr lat-long files, directories or glob patterns. None: the built-in sky.
    #[arg(value_name = "INPUT", value_parser = Utf8Input)]
    inputs: Vec<String>,
    /// Number of lobes K (1..=64).
    #[arg(long, default_value_t = envlight::asg::fit::DEFAULT_LOBES)]
    lobes: usize,
    /// Adam iterations of the first frame at full size, each taking its gradient on a rotating
    /// quarter of the map (the default, about 2,000 whole-map iterations, converges); at most
    /// 10^7. 0 keeps the greedy peak-picking initialisation as the fit.
    #[arg(long, default_value_t = envlight::asg::fit::FitSettings::default().iterations)]
    iterations: usize,
    /// Adam iterations of each warm-started frame (after a centroid step for narrow lobes;
    /// continuing the previous frame's Adam state; L_T applied as a proximal step); at most
    /// 10^7. 0 keeps the previous frame's lobes, only narrow ones (min(λ, μ) ≥ 100) moved by
    /// the centroid step.
    #[arg(long, default_value_t = envlight::asg::fit::FitSettings::default().warm_iterations)]
    warm_iterations: usize,
    /// Fit-map height (width is twice), 4..=1024.
    #[arg(long, default_value_t = envlight::asg::fit::DEFAULT_HEIGHT)]
    height: u32,
    /// Weight of the temporal loss L_T (0 disables it).
    #[arg(long, default_value_t = envlight::asg::fit::FitSettings::default().temporal_weight)]
    temporal_weight: f64,
    /// Frames to fit; 0 = every frame (the sky: endless). [default: 10 for the sky, every
    /// file for INPUT]
    #[arg(long, value_name = "N")]
    frames: Option<u64>,
    /// Output file (JSON Lines). [default: stdout]
    #[arg(long, value_name = "FILE")]
    out: Option<PathBuf>,
}

fn fit_asg(args: &FitAsgArgs) -> Result<()> {
    use envlight::asg::fit::{AsgFitter, FitSettings};
    let settings = FitSettings {
        lobes: args.lobes,
        iterations: args.iterations,
        warm_iterations: args.warm_iterations,
        height: args.height,
        temporal_weight: args.temporal_weight,
        // Every line reports its frame's loss.
        warm_loss: true,
        ..FitSettings::default()
    };
    // Name the option a setting came from (the fitter names its field).
    let mut fitter = AsgFitter::new(settings).map_err(|e| {
        use envlight::asg::AsgError;
        let flag = match &e {
            AsgError::LobeCount(_) => "--lobes",
            AsgError::MapSize { .. } => "--height",
            AsgError::Setting { name, .. } => match *name {
                "iterations" => "--iterations",
                "warm_iterations" => "--warm-iterations",
                "temporal_weight" => "--temporal-weight",
                _ => "",
            },
            _ => "",
        };
        if flag.is_empty() {
            anyhow!(e).context("invalid fit-asg options")
        } else {
            anyhow!("invalid {flag}: {e}")
        }
    })?;
    let mut source: Box<dyn FrameSource> = if args.inputs.is_empty() {
        let options = SkyOptions {
            frames: args.frames.map_or(Some(10), |n| (n > 0).then_some(n)),
            ..SkyOptions::default()
        };
        Box::new(SkySource::new(options).context("cannot set up the built-in sky")?)
    } else {
        let options = SequenceOptions {
            fps: None,
            looped: false,
            projection: Projection::LatLong,
        };
        Box::new(wavelet_cli::Limited {
            inner: SequenceSource::new(&args.inputs, options)
                .context("cannot open the input frames")?,
            left: args.frames.filter(|&n| n > 0),
        })
    };
    let mut writer = std::io::BufWriter::new(cli_output::open_output(
        args.out.as_deref(),
        "--out",
        &cli_output::InputFiles::new(source.files()),
    )?);
    while let Some(frame) = source.next_frame().context("cannot read a frame")? {
        let result = fitter
            .fit_frame(&frame)
            .with_context(|| format!("cannot fit frame {}", frame.seq))?;
        #[derive(serde::Serialize)]
        struct Line<'a> {
            seq: u64,
            time: f64,
            lobes: &'a [envlight::asg::Asg],
            loss: Option<f64>,
        }
        let line = Line {
            seq: frame.seq,
            time: frame.time,
            lobes: &result.lobes,
            loss: result.loss.map(|l| l.total),
        };
        let line = serde_json::to_string(&line).context("cannot encode a frame")?;
        match writeln!(writer, "{line}") {
            Err(e) if cli_output::is_broken_pipe(&e) => return Ok(()),
            r => r.context("cannot write the output")?,
        }
    }
    match writer.flush() {
        Err(e) if cli_output::is_broken_pipe(&e) => Ok(()),
        r => r.context("cannot write the output"),
    }
}

/// "on" or "off", for the settings in log lines and `check-config`.
/// "above F× the mean light" or "off", for the split of bright lights.
fn split_description(factor: Option<f64>) -> String {
    factor.map_or("off".to_string(), |f| format!("above {f}× the mean light"))
}

fn on_off(on: bool) -> &'static str {
    if on {
        "on"
    } else {
        "off"
    }
}
