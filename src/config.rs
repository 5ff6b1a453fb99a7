//! Configuration file (`config/envlight.toml`): raw TOML → validated [`Config`].
//!
//! Two stages, as ripgrep does it: [`RawConfig`] is exactly what the file says (every key
//! optional, unknown keys rejected by `#[serde(deny_unknown_fields)]`), and
//! [`RawConfig::validate`] turns it into a [`Config`] of library types with every default filled
//! in, or a [`ConfigError`] that names the key and the value at fault. Nothing here panics on
//! input. The command line applies its flags to a `RawConfig` before validating, so flags
//! override the file and are checked by the same code.

use crate::capture::sky::SkyOptions;
use crate::decompose::filter::FirFilter;
use crate::decompose::{
    BrightHistory, DecomposeSettings, LightPlacement, Warp, MAX_POINTS, WORKING_WIDTH_RANGE,
};
use crate::envmap::{FisheyeCalibration, FisheyeModel, Projection};
use crate::stream::{FanoutOn, ServerConfig};
use serde::Deserialize;
use std::net::SocketAddr;

mod camera;
pub use camera::RawCamera;
use std::path::{Path, PathBuf};
use std::time::Duration;

/// Errors of reading and validating a configuration.
#[derive(Debug, thiserror::Error)]
pub enum ConfigError {
    #[error("cannot read config file {}: {source}", path.display())]
    Read {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// TOML syntax error, unknown key or wrong type (the message names the key and line).
    #[error("config file {}: {message}", path.display())]
    Parse { path: PathBuf, message: String },
    /// A key has a value of the right type that is not allowed.
    #[error("{key} = {value}: {message}")]
    Invalid {
        key: &'static str,
        value: String,
        message: String,
    },
}

/// Fails when two of the TCP, WebSocket and metrics endpoints would listen on one port of one
/// address (an unspecified address such as 0.0.0.0 takes the port on every address): the
/// second would fail to bind at start.
fn check_endpoints_apart(config: &Config) -> Result<(), ConfigError> {
    let endpoints = [
        ("stream.tcp", config.stream.tcp),
        ("stream.websocket", config.stream.websocket),
        ("metrics.listen", config.metrics.listen),
    ];
    for (i, &(key_a, a)) in endpoints.iter().enumerate() {
        for &(key_b, b) in &endpoints[i + 1..] {
            let (Some(a), Some(b)) = (a, b) else {
                continue;
            };
            let same_ip = a.ip() == b.ip() || a.ip().is_unspecified() || b.ip().is_unspecified();
            if a.port() != 0 && a.port() == b.port() && same_ip {
                return Err(invalid(
                    key_b,
                    b.to_string(),
                    format!("takes the port of {key_a} = \"{a}\"; give each endpoint its own"),
                ));
            }
        }
    }
    Ok(())
}

/// The largest config file read: 1 MiB (the documented config with every key is under 20 KB).
pub const MAX_CONFIG_BYTES: u64 = 1 << 20;

/// `x` as a message shows it: plain when that is short (`30`, `0.5`), in scientific notation
/// when it is very large or small (`1e300`, not three hundred digits; `1e-300`, not three
/// hundred zeros).
pub fn shown_number(x: f64) -> String {
    let magnitude = x.abs();
    if x.is_finite() && x != 0.0 && !(1e-5..1e16).contains(&magnitude) {
        format!("{x:e}")
    } else {
        format!("{x}")
    }
}

/// The largest rendered image side, in `render.width` / `render.height` and `render --size`
/// (a GPU may allow less; the renderer then says so).
pub const MAX_RENDER_SIDE: u32 = 16384;

/// Deserialises an optional array of exactly `N` numbers: serde's fixed-size arrays stop after
/// `N` values and silently drop the rest, so `[1, 2, 3]` for a centre read as `[1, 2]`.
pub(crate) fn exactly<'de, D, const N: usize>(deserializer: D) -> Result<Option<[f64; N]>, D::Error>
where
    D: serde::Deserializer<'de>,
{
    use serde::de::Error;
    let values: Option<Vec<f64>> = Option::deserialize(deserializer)?;
    values
        .map(|v| {
            <[f64; N]>::try_from(v.as_slice())
                .map_err(|_| D::Error::custom(format!("expected {N} numbers, got {}", v.len())))
        })
        .transpose()
}

fn invalid(
    key: &'static str,
    value: impl std::fmt::Debug,
    message: impl Into<String>,
) -> ConfigError {
    ConfigError::Invalid {
        key,
        value: shortened(format!("{value:?}")),
        message: message.into(),
    }
}

/// A value as an error shows it: whole up to [`SHOWN_VALUE_CHARS`] characters, else its start
/// and its length (`--taps` of 10,001 numbers put 50 KB before the reason).
fn shortened(value: String) -> String {
    let chars = value.chars().count();
    if chars <= SHOWN_VALUE_CHARS {
        return value;
    }
    let start: String = value.chars().take(SHOWN_VALUE_CHARS / 2).collect();
    format!("{start}… ({chars} characters)")
}

/// `line` whole up to `max` characters, else its first `max` and "…".
fn shortened_line(line: &str, max: usize) -> String {
    match line.char_indices().nth(max) {
        Some((cut, _)) => format!("{}…", &line[..cut]),
        None => line.to_string(),
    }
}

/// The longest value an error shows whole.
const SHOWN_VALUE_CHARS: usize = 80;

/// An integer from `key`: `default` when the key is absent, the value when it lies in `range`,
/// otherwise an error naming the key, "must be LO..=HI" and then `note` (a unit or what the key
/// counts; may be empty).
fn integer_in<T>(
    key: &'static str,
    value: Option<T>,
    default: T,
    range: std::ops::RangeInclusive<T>,
    note: &str,
) -> Result<T, ConfigError>
where
    T: Copy + PartialOrd + std::fmt::Display + std::fmt::Debug,
{
    match value {
        None => Ok(default),
        Some(n) if range.contains(&n) => Ok(n),
        Some(n) => Err(invalid(
            key,
            n,
            format!("must be {}..={}{note}", range.start(), range.end()),
        )),
    }
}

// ------------------------------------------------------------------------------------------------
// Raw stage

/// The file as written: every key optional.
#[derive(Clone, Debug, Default, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct RawConfig {
    #[serde(default)]
    pub source: RawSource,
    #[serde(default)]
    pub sky: RawSky,
    #[serde(default)]
    pub decompose: RawDecompose,
    #[serde(default)]
    pub camera: RawCamera,
    #[serde(default)]
    pub pipeline: RawPipeline,
    #[serde(default)]
    pub stream: RawStream,
    #[serde(default)]
    pub metrics: RawMetrics,
    #[serde(default)]
    pub daemon: RawDaemon,
    #[serde(default)]
    pub render: RawRender,
    #[serde(default)]
    pub asg: RawAsg,
    #[serde(default)]
    pub wavelet: RawWavelet,
    #[serde(default)]
    pub sh: RawSh,
}

/// `[sh]`: the daemon's spherical-harmonics stage (the newest frames' radiance projected onto
/// the real SH basis, streamed as representation `sh`).
#[derive(Clone, Debug, Default, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct RawSh {
    pub enabled: Option<bool>,
    pub degree: Option<usize>,
    pub filter: Option<bool>,
}

/// `[wavelet]`: the daemon's wavelet stage (sparse wavelet coefficient sets of the newest
/// frames, streamed as representation `wavelet`).
#[derive(Clone, Debug, Default, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct RawWavelet {
    pub enabled: Option<bool>,
    pub basis: Option<String>,
    pub side: Option<usize>,
    pub coefficients: Option<usize>,
    pub filter: Option<bool>,
}

/// `[asg]`: the daemon's ASG stage (fits anisotropic spherical Gaussians to the newest frames).
#[derive(Clone, Debug, Default, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct RawAsg {
    pub enabled: Option<bool>,
    pub lobes: Option<usize>,
    pub fit_height: Option<u32>,
    pub iterations: Option<usize>,
    pub warm_iterations: Option<usize>,
    pub learning_rate: Option<f64>,
    pub warm_learning_rate: Option<f64>,
    pub diffuse_weight: Option<f64>,
    pub temporal_weight: Option<f64>,
    pub diffuse_normals: Option<usize>,
    pub threads: Option<usize>,
    pub first_subset: Option<usize>,
    pub warm_subset: Option<usize>,
    pub warm_centroid: Option<bool>,
    pub filter: Option<bool>,
}

/// `[pipeline]`.
#[derive(Clone, Debug, Default, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct RawPipeline {
    pub queue_capacity: Option<usize>,
}

/// `[stream]`: the light-list endpoints. An empty string disables an endpoint.
#[derive(Clone, Debug, Default, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct RawStream {
    pub unix_socket: Option<String>,
    pub unix_socket_mode: Option<u32>,
    pub tcp: Option<String>,
    pub websocket: Option<String>,
    pub max_clients: Option<usize>,
    pub handshake_timeout_s: Option<f64>,
    pub write_timeout_s: Option<f64>,
    pub send_buffer_bytes: Option<usize>,
    pub fanout_on: Option<String>,
    pub pass_threads: Option<usize>,
}

/// `[metrics]`: the HTTP endpoint for Prometheus metrics and the health check.
#[derive(Clone, Debug, Default, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct RawMetrics {
    pub listen: Option<String>,
    pub max_frame_age_s: Option<f64>,
}

/// `[render]`: the daemon's render thread.
#[derive(Clone, Debug, Default, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct RawRender {
    pub enabled: Option<bool>,
    pub width: Option<u32>,
    pub height: Option<u32>,
    pub scene: Option<String>,
    pub shadow_resolution: Option<u32>,
    pub supersample: Option<u32>,
    pub fxaa: Option<bool>,
    pub culling: Option<bool>,
    pub shadow_catcher: Option<bool>,
    pub shadow_raster: Option<String>,
    pub budget_ms: Option<f64>,
    pub latest_png: Option<String>,
    pub lighting: Option<String>,
    pub eye: Option<Vec<f64>>,
    pub look_at: Option<Vec<f64>>,
    pub fov_deg: Option<f64>,
    pub ortho_height: Option<f64>,
    pub animation: Option<String>,
}

/// `[daemon]`.
#[derive(Clone, Debug, Default, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct RawDaemon {
    pub shutdown_grace_s: Option<f64>,
    pub serve_threads: Option<usize>,
}

/// `[source]`.
#[derive(Clone, Debug, Default, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct RawSource {
    pub kind: Option<String>,
    pub paths: Option<Vec<String>>,
    pub fps: Option<f64>,
    pub frames: Option<u64>,
    #[serde(rename = "loop")]
    pub looped: Option<bool>,
    pub projection: Option<String>,
    #[serde(default)]
    pub fisheye: RawFisheye,
}

/// `[source.fisheye]`.
#[derive(Clone, Debug, Default, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct RawFisheye {
    pub model: Option<String>,
    #[serde(default, deserialize_with = "exactly")]
    pub center: Option<[f64; 2]>,
    pub radius: Option<f64>,
    pub fov_deg: Option<f64>,
    pub rotation_deg: Option<f64>,
}

/// `[sky]`.
#[derive(Clone, Debug, Default, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct RawSky {
    pub width: Option<u32>,
    pub height: Option<u32>,
    pub turbidity: Option<f64>,
    pub sun_start_elevation_deg: Option<f64>,
    pub sun_start_azimuth_deg: Option<f64>,
    pub sun_speed_deg_per_s: Option<f64>,
    pub clouds: Option<bool>,
    pub cloud_cover: Option<f64>,
    pub wind_speed: Option<f64>,
    pub ground_albedo: Option<f64>,
    pub seed: Option<u64>,
}

/// `[decompose]`.
#[derive(Clone, Debug, Default, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct RawDecompose {
    pub lights: Option<usize>,
    pub working_width: Option<u32>,
    pub placement: Option<String>,
    pub warp: Option<String>,
    pub filter: Option<bool>,
    pub filter_taps: Option<Vec<f64>>,
    pub merge: Option<bool>,
    pub merge_spacing_fraction: Option<f64>,
    pub pdf_exponent: Option<f64>,
    pub concentrated_lloyd: Option<bool>,
    pub refine_concentrated: Option<bool>,
    pub bright_history: Option<String>,
    pub split: Option<bool>,
    pub split_factor: Option<f64>,
    pub resample_threads: Option<usize>,
}

impl RawConfig {
    /// Parses TOML text; `path` is only used in error messages.
    pub fn parse(text: &str, path: &Path) -> Result<Self, ConfigError> {
        toml::from_str(text).map_err(|e| ConfigError::Parse {
            path: path.to_path_buf(),
            // The parser quotes the line at fault: a long one is cut, like a long value.
            message: e
                .to_string()
                .trim_end()
                .lines()
                .map(|line| {
                    // Only the quote of the file ("2 | taps = …") and its caret line: the
                    // reason (with the list of valid keys) is kept whole.
                    let quote = line
                        .trim_start()
                        .split_once('|')
                        .is_some_and(|(number, _)| {
                            number.trim().chars().all(|c| c.is_ascii_digit())
                        });
                    if quote {
                        shortened_line(line, 2 * SHOWN_VALUE_CHARS)
                    } else {
                        line.to_string()
                    }
                })
                .collect::<Vec<_>>()
                .join("\n"),
        })
    }

    /// Reads and parses a file (not yet validated). A file over [`MAX_CONFIG_BYTES`] or one
    /// that is not a regular file (a FIFO, which would block; `/dev/zero`, which never ends)
    /// is an error.
    pub fn from_file(path: &Path) -> Result<Self, ConfigError> {
        let text = crate::read_file::read_regular_text(
            path,
            MAX_CONFIG_BYTES,
            "a config file (a few kilobytes)",
        )
        .map_err(|source| ConfigError::Read {
            path: path.to_path_buf(),
            source,
        })?;
        let mut raw = Self::parse(&text, path)?;
        if let Some(folder) = path.parent().filter(|p| !p.as_os_str().is_empty()) {
            raw.resolve_relative_paths(folder);
        }
        Ok(raw)
    }

    /// Makes the relative paths of the file (`source.paths`, `camera.curve`,
    /// `stream.unix_socket`, `render.scene`, `render.latest_png`) relative to `folder`, the
    /// file's own: a config means the same from any working directory (a service runs from
    /// `/`). A glob pattern in `source.paths` stays a pattern under `folder` (the folder's own
    /// `*?[` escaped).
    pub fn resolve_relative_paths(&mut self, folder: &Path) {
        let Some(folder_text) = folder.to_str() else {
            // Not expressible as the UTF-8 text the keys hold: left as written.
            return;
        };
        let resolve = |value: &mut String, pattern: bool| {
            if value.is_empty() || Path::new(value.as_str()).is_absolute() {
                return;
            }
            let is_pattern = pattern && value.contains(['*', '?', '[']);
            let base = if is_pattern && folder_text.contains(['*', '?', '[']) {
                glob::Pattern::escape(folder_text)
            } else {
                folder_text.to_owned()
            };
            *value = Path::new(&base).join(value.as_str()).display().to_string();
        };
        // A `v4l2:` entry stays as written, for validation to name it.
        for value in (self.source.paths.iter_mut().flatten()).filter(|v| !v.starts_with("v4l2:")) {
            resolve(value, true);
        }
        for value in [
            &mut self.camera.curve,
            &mut self.stream.unix_socket,
            &mut self.render.scene,
            &mut self.render.latest_png,
        ]
        .into_iter()
        .flatten()
        {
            resolve(value, false);
        }
    }

    /// Checks every value and fills in the defaults.
    pub fn validate(&self) -> Result<Config, ConfigError> {
        let source = self.source.validate()?;
        let decompose = self.decompose.validate()?;
        let lights_taps = decompose.filter_taps.as_deref();
        Ok(Config {
            camera: self.camera.validate(source.projection)?,
            source,
            sky: self.sky.validate()?,
            pipeline: self.pipeline.validate()?,
            stream: self.stream.validate()?,
            metrics: self.metrics.validate()?,
            daemon: self.daemon.validate()?,
            render: self.render.validate()?,
            asg: self.asg.validate(lights_taps)?,
            wavelet: self.wavelet.validate(lights_taps)?,
            sh: self.sh.validate(lights_taps)?,
            decompose,
        })
        .and_then(|config: Config| {
            check_endpoints_apart(&config)?;
            if config.render.enabled {
                let missing = match config.render.lighting {
                    Lighting::Asg if !config.asg.enabled => Some(("asg", "ASG", "[asg]")),
                    Lighting::Sh if !config.sh.enabled => Some(("sh", "SH", "[sh]")),
                    _ => None,
                };
                if let Some((value, stage, section)) = missing {
                    return Err(invalid(
                        "render.lighting",
                        value,
                        format!("needs the {stage} stage: set {section} enabled = true"),
                    ));
                }
            }
            Ok(config)
        })
    }
}

// ------------------------------------------------------------------------------------------------
// Validated stage

/// Where frames come from.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum SourceKind {
    /// The built-in analytic sky.
    #[default]
    Sky,
    /// Recorded `.exr` / `.hdr` files.
    Sequence,
    /// A V4L2 camera (`[camera]`).
    V4l2,
}

/// Validated `[source]`.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct SourceConfig {
    pub kind: SourceKind,
    /// Files, directories or glob patterns (kind = sequence).
    pub paths: Vec<String>,
    /// Pacing in frames per second; `None` = as fast as possible.
    pub fps: Option<f64>,
    /// Frames to process: `None` = the source's default (sky: [`DEFAULT_SKY_FRAMES`]; sequence:
    /// every file once, endless when looped), `Some(0)` = no limit.
    pub frames: Option<u64>,
    /// Replay a sequence forever.
    pub looped: bool,
    /// How the sequence's pixels map to directions (the sky is always lat-long).
    pub projection: Projection,
    /// The `[source.fisheye]` keys set to other than their defaults while the projection is
    /// not "fisheye": a calibration that is not used, said in a warning when the source opens
    /// and by `check-config` (not an error: the shipped config sets the section's defaults,
    /// and a calibration may stay in a file while another projection is tried).
    pub ignored_fisheye: Vec<&'static str>,
}

/// Number of sky frames when neither the config nor the command line says.
pub const DEFAULT_SKY_FRAMES: u64 = 60;

/// The whole validated configuration; `Config::default()` is what an empty file gives.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Config {
    pub source: SourceConfig,
    /// The built-in sky; its pacing (`fps`, `frames`) comes from `[source]` when it is used.
    pub sky: SkyOptions,
    pub decompose: DecomposeSettings,
    /// The camera (used with `source.kind = "v4l2"`).
    pub camera: crate::capture::v4l2::CameraSettings,
    pub pipeline: PipelineConfig,
    pub stream: ServerConfig,
    pub metrics: MetricsConfig,
    pub daemon: DaemonConfig,
    pub render: RenderConfig,
    pub asg: AsgConfig,
    pub wavelet: WaveletConfig,
    pub sh: ShConfig,
}

/// Validated `[sh]`: the daemon's SH stage. Default: disabled; when enabled, degree 2 (nine
/// coefficients per channel), filtered in time with the lights' taps.
#[derive(Clone, Debug, PartialEq)]
pub struct ShConfig {
    pub enabled: bool,
    /// `[sh] filter`: filter the sets with the lights' taps (when the lights are filtered);
    /// [`ShConfig::settings`]`.filter_taps` holds the outcome.
    pub filter: bool,
    /// What the stage computes.
    pub settings: crate::sh_stage::ShSettings,
}

impl Default for ShConfig {
    /// Disabled; filtered with the lights' default taps.
    fn default() -> Self {
        Self {
            enabled: false,
            filter: true,
            settings: crate::sh_stage::ShSettings::default(),
        }
    }
}

impl Default for WaveletConfig {
    /// Disabled; filtered with the lights' default taps.
    fn default() -> Self {
        Self {
            enabled: false,
            filter: true,
            settings: crate::wavelet_stage::WaveletSettings::default(),
        }
    }
}

/// A daemon stage's validated section (`[asg]`, `[wavelet]`, `[sh]`), as a SIGHUP reload reads
/// it.
pub trait StageConfig: Clone + PartialEq {
    /// What the stage is started or reconfigured with.
    type Settings;
    /// The section's `enabled`.
    fn enabled(&self) -> bool;
    /// The stage's settings.
    fn settings(&self) -> Self::Settings;
}

macro_rules! stage_config {
    ($($config:ty => $settings:ty),* $(,)?) => {$(
        impl StageConfig for $config {
            type Settings = $settings;
            fn enabled(&self) -> bool {
                self.enabled
            }
            fn settings(&self) -> $settings {
                self.settings.clone()
            }
        }
    )*};
}

stage_config!(
    AsgConfig => crate::asg_stage::AsgSettings,
    WaveletConfig => crate::wavelet_stage::WaveletSettings,
    ShConfig => crate::sh_stage::ShSettings,
);

/// A stage's filter taps: the lights' (`[decompose]`'s, `None` when the lights are not
/// filtered) unless the stage's `filter = false`.
pub(crate) fn stage_taps(filter: bool, lights_taps: Option<&[f64]>) -> Option<Vec<f64>> {
    lights_taps.filter(|_| filter).map(<[f64]>::to_vec)
}

impl RawSh {
    /// `lights_taps`: the validated `[decompose]` filter taps.
    fn validate(&self, lights_taps: Option<&[f64]>) -> Result<ShConfig, ConfigError> {
        use crate::sh_stage::{ShSettings, ShStageError};
        let settings = ShSettings {
            degree: self.degree.unwrap_or(crate::sh_stage::DEFAULT_DEGREE),
            filter_taps: stage_taps(self.filter.unwrap_or(true), lights_taps),
        };
        if let Err(ShStageError::Settings { value, rule, .. }) = settings.validate() {
            return Err(ConfigError::Invalid {
                key: "sh.degree",
                value,
                message: format!("must be {rule}"),
            });
        }
        Ok(ShConfig {
            enabled: self.enabled.unwrap_or(false),
            filter: self.filter.unwrap_or(true),
            settings,
        })
    }
}

/// Validated `[wavelet]`: the daemon's wavelet stage. Default: disabled; when enabled, the 256
/// largest Haar coefficients of a 64×64 octahedral map per frame, the map filtered in time with
/// the lights' taps.
#[derive(Clone, Debug, PartialEq)]
pub struct WaveletConfig {
    pub enabled: bool,
    /// `[wavelet] filter`: filter the maps with the lights' taps (when the lights are
    /// filtered); [`WaveletConfig::settings`]`.filter_taps` holds the outcome.
    pub filter: bool,
    /// What the stage computes.
    pub settings: crate::wavelet_stage::WaveletSettings,
}

impl RawWavelet {
    /// `lights_taps`: the validated `[decompose]` filter taps.
    fn validate(&self, lights_taps: Option<&[f64]>) -> Result<WaveletConfig, ConfigError> {
        use crate::wavelet_stage::{WaveletSettings, WaveletStageError};
        let d = WaveletSettings::default();
        let basis = match &self.basis {
            None => d.basis,
            Some(name) => crate::wavelet::Basis::parse(name).map_err(|e| {
                invalid(
                    "wavelet.basis",
                    name,
                    format!("{e} (default \"{}\")", d.basis),
                )
            })?,
        };
        let settings = WaveletSettings {
            basis,
            side: self.side.unwrap_or(d.side),
            coefficients: self.coefficients.unwrap_or(d.coefficients),
            filter_taps: stage_taps(self.filter.unwrap_or(true), lights_taps),
        };
        if let Err(WaveletStageError::Settings { field, value, rule }) = settings.validate() {
            let key = match field {
                "side" => "wavelet.side",
                "coefficients" => "wavelet.coefficients",
                _ => "wavelet.basis",
            };
            return Err(ConfigError::Invalid {
                key,
                value,
                message: format!("must be {rule}"),
            });
        }
        Ok(WaveletConfig {
            enabled: self.enabled.unwrap_or(false),
            filter: self.filter.unwrap_or(true),
            settings,
        })
    }
}

/// Validated `[asg]`: the daemon's ASG stage. Default: disabled; when enabled, 16 lobes fitted
/// at 64×128 (first frame 8,000 iterations on 1/4 subsets, then 8 warm-started ones per frame,
/// also on 1/4 subsets) on one thread: the fitter's own defaults; the lobes filtered in time
/// with the lights' taps.
#[derive(Clone, Debug, PartialEq)]
pub struct AsgConfig {
    pub enabled: bool,
    /// `[asg] filter`: filter the lobes with the lights' taps (when the lights are filtered);
    /// [`AsgConfig::settings`]`.filter_taps` holds the outcome.
    pub filter: bool,
    /// The fitter's settings and the lobes' filter taps.
    pub settings: crate::asg_stage::AsgSettings,
}

/// Default `[asg] fit_height`: a 64×128 fit map, 16 times fewer pixels per iteration than the
/// fitter's own default (256×512, the paper's); the daemon trades detail for rate.
pub const DEFAULT_ASG_FIT_HEIGHT: u32 = 64;

/// Why an orthographic fisheye calibration may not have a field of view above 180°.
pub const ORTHOGRAPHIC_FOV_LIMIT: &str =
    "an orthographic lens images at most 180° (r = f·sin θ turns back at θ = 90°); use fov_deg ≤ 180 or another model";

impl Default for AsgConfig {
    fn default() -> Self {
        Self {
            enabled: false,
            filter: true,
            settings: crate::asg_stage::AsgSettings {
                fit: crate::asg::fit::FitSettings {
                    height: DEFAULT_ASG_FIT_HEIGHT,
                    threads: 1,
                    ..crate::asg::fit::FitSettings::default()
                },
                ..crate::asg_stage::AsgSettings::default()
            },
        }
    }
}

impl RawAsg {
    /// `lights_taps`: the validated `[decompose]` filter taps.
    fn validate(&self, lights_taps: Option<&[f64]>) -> Result<AsgConfig, ConfigError> {
        let d = AsgConfig::default().settings.fit;
        let int = |key, v, default, range| integer_in(key, v, default, range, "");
        let real =
            |key: &'static str, v: Option<f64>, default: f64, positive: bool, max: f64| match v {
                None => Ok(default),
                Some(x)
                    if x.is_finite() && x <= max && (if positive { x > 0.0 } else { x >= 0.0 }) =>
                {
                    Ok(x)
                }
                Some(x) => Err(invalid(
                    key,
                    x,
                    if positive {
                        format!("must be in (0, {max}]")
                    } else {
                        format!("must be in [0, {max}]")
                    },
                )),
            };
        let fit_height = integer_in(
            "asg.fit_height",
            self.fit_height,
            d.height,
            4..=1024,
            " (the fit map is 2·fit_height wide)",
        )?;
        let fit = crate::asg::fit::FitSettings {
            lobes: int(
                "asg.lobes",
                self.lobes,
                d.lobes,
                1..=crate::asg::fit::MAX_LOBES,
            )?,
            height: fit_height,
            iterations: int(
                "asg.iterations",
                self.iterations,
                d.iterations,
                0..=10_000_000,
            )?,
            warm_iterations: int(
                "asg.warm_iterations",
                self.warm_iterations,
                d.warm_iterations,
                0..=10_000_000,
            )?,
            learning_rate: real(
                "asg.learning_rate",
                self.learning_rate,
                d.learning_rate,
                true,
                1.0,
            )?,
            warm_learning_rate: real(
                "asg.warm_learning_rate",
                self.warm_learning_rate,
                d.warm_learning_rate,
                true,
                1.0,
            )?,
            diffuse_weight: real(
                "asg.diffuse_weight",
                self.diffuse_weight,
                d.diffuse_weight,
                false,
                1e6,
            )?,
            temporal_weight: real(
                "asg.temporal_weight",
                self.temporal_weight,
                d.temporal_weight,
                false,
                1e6,
            )?,
            diffuse_normals: int(
                "asg.diffuse_normals",
                self.diffuse_normals,
                d.diffuse_normals,
                16..=4096,
            )?,
            threads: int("asg.threads", self.threads, d.threads, 0..=64)?,
            first_subset: int(
                "asg.first_subset",
                self.first_subset,
                d.first_subset,
                1..=16,
            )?,
            warm_subset: int("asg.warm_subset", self.warm_subset, d.warm_subset, 1..=16)?,
            warm_centroid: self.warm_centroid.unwrap_or(d.warm_centroid),
            ..d
        };
        // The fitter's own check, as a backstop (the keys above cover every rule it has).
        fit.validate().map_err(|e| {
            invalid(
                "asg",
                e.to_string(),
                "the ASG fitter rejects these settings",
            )
        })?;
        let filter = self.filter.unwrap_or(true);
        Ok(AsgConfig {
            enabled: self.enabled.unwrap_or(false),
            filter,
            settings: crate::asg_stage::AsgSettings {
                fit,
                // The lights' taps, already checked.
                filter_taps: stage_taps(filter, lights_taps),
            },
        })
    }
}

/// What the daemon's render thread shades with (`[render] lighting`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Lighting {
    /// The directional lights, with shadows (the default).
    #[default]
    Lights,
    /// The ASG stage's lobes, in closed form, each shadowed along its axis.
    Asg,
    /// The SH stage's coefficients, in closed form, unshadowed.
    Sh,
}

/// Parses a `--lighting` / `render.lighting` value.
pub fn parse_lighting(s: &str) -> Option<Lighting> {
    match s {
        "lights" => Some(Lighting::Lights),
        "asg" => Some(Lighting::Asg),
        "sh" => Some(Lighting::Sh),
        _ => None,
    }
}

/// Validated `[pipeline]`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct PipelineConfig {
    /// Capture → decompose queue capacity in frames (1..=64).
    pub queue_capacity: usize,
}

impl Default for PipelineConfig {
    fn default() -> Self {
        Self { queue_capacity: 2 }
    }
}

/// Validated `[metrics]`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MetricsConfig {
    /// HTTP listen address for `/metrics` and `/health`; `None` disables it.
    pub listen: Option<SocketAddr>,
    /// `/health` reports unhealthy when the newest light list is older than this.
    pub max_frame_age: Duration,
}

/// Default metrics address.
pub const DEFAULT_METRICS_LISTEN: &str = "127.0.0.1:9898";

impl Default for MetricsConfig {
    fn default() -> Self {
        Self {
            listen: DEFAULT_METRICS_LISTEN.parse().ok(),
            max_frame_age: Duration::from_secs(5),
        }
    }
}

/// Validated `[render]`: a render thread in the daemon that shades the scene under every new
/// light list (docs/daemon.md). The default is disabled, 640×360, the built-in scene.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RenderConfig {
    pub enabled: bool,
    pub settings: crate::render::RenderSettings,
    /// glTF or OBJ scene; `None` = the built-in scene.
    pub scene: Option<PathBuf>,
    /// Hold this frame time by adapting the light count; `None` = always every light.
    pub budget_ms: Option<f64>,
    /// Write the newest image here (tone-mapped PNG, replaced atomically); `None` = no file.
    pub latest_png: Option<PathBuf>,
    /// Shade with the lights (shadowed) or with the ASG stage's lobes.
    pub lighting: Lighting,
    /// The camera's eye, look-at point and field of view where given, over the scene's own
    /// (a glTF's camera, or one fitted to the scene).
    pub camera: crate::render::scene::CameraOverride,
    /// The glTF animation played on the frames' capture times (the scene's first by default).
    pub animation: crate::render::scene::AnimationChoice,
}

impl RawRender {
    fn validate(&self) -> Result<RenderConfig, ConfigError> {
        let d = RenderConfig::default();
        // As `render --size`; the GPU's own limit applies too (16384 on lavapipe and most).
        let size = |key, v, default| integer_in(key, v, default, 1..=MAX_RENDER_SIDE, "");
        let settings = crate::render::RenderSettings {
            width: size("render.width", self.width, d.settings.width)?,
            height: size("render.height", self.height, d.settings.height)?,
            shadow_resolution: integer_in(
                "render.shadow_resolution",
                self.shadow_resolution,
                d.settings.shadow_resolution,
                16..=8192,
                "",
            )?,
            supersample: integer_in(
                "render.supersample",
                self.supersample,
                d.settings.supersample,
                1..=crate::render::supersample::MAX_SUPERSAMPLE,
                "",
            )?,
            fxaa: self.fxaa.unwrap_or(d.settings.fxaa),
            shadows: true,
            culling: self.culling.unwrap_or(d.settings.culling),
            shadow_catcher: self.shadow_catcher.unwrap_or(d.settings.shadow_catcher),
            shadow_raster: match self.shadow_raster.as_deref() {
                None => d.settings.shadow_raster,
                Some(s) => crate::render::ShadowRaster::parse(s).ok_or_else(|| {
                    invalid(
                        "render.shadow_raster",
                        s,
                        "must be \"auto\", \"pipeline\" or \"compute\"",
                    )
                })?,
            },
            ..crate::render::RenderSettings::default()
        };
        if settings.fxaa && settings.supersample > 1 {
            return Err(invalid(
                "render.fxaa",
                true,
                format!(
                    "cannot be combined with render.supersample = {} (FXAA would blur the \
                     resolved edges); choose one",
                    settings.supersample
                ),
            ));
        }
        if let Some(ms) = self.budget_ms {
            if !(ms.is_finite() && ms > 0.0) {
                return Err(invalid(
                    "render.budget_ms",
                    ms,
                    "must be a positive number of milliseconds",
                ));
            }
        }
        let path = |v: &Option<String>| v.as_deref().filter(|p| !p.is_empty()).map(PathBuf::from);
        let lighting = match self.lighting.as_deref() {
            None => Lighting::default(),
            Some(s) => parse_lighting(s).ok_or_else(|| {
                invalid(
                    "render.lighting",
                    s,
                    "must be \"lights\", \"asg\" or \"sh\"",
                )
            })?,
        };
        if let (Some(ms), Lighting::Asg | Lighting::Sh) = (self.budget_ms, lighting) {
            // The closed-form passes have no light count to hold a budget with.
            return Err(invalid(
                "render.budget_ms",
                ms,
                "applies to lighting = \"lights\" (a prefix of the light set); ASG and SH \
                 lighting draw every lobe or coefficient",
            ));
        }
        let enabled = self.enabled.unwrap_or(false);
        let (scene, latest_png) = (path(&self.scene), path(&self.latest_png));
        // The paths are checked where the render thread will use them (when it is enabled), so
        // that check-config and a reload catch them rather than the thread after start-up.
        if enabled {
            if let Some(scene) = &scene {
                if !scene.is_file() {
                    return Err(invalid(
                        "render.scene",
                        scene.display(),
                        "must be an existing .gltf, .glb or .obj file",
                    ));
                }
            }
            if let Some(png) = &latest_png {
                let folder = png.parent().filter(|p| !p.as_os_str().is_empty());
                if folder.is_some_and(|f| !f.is_dir()) {
                    return Err(invalid(
                        "render.latest_png",
                        png.display(),
                        "its folder does not exist",
                    ));
                }
                crate::read_file::check_replaceable(png, "render.latest_png")
                    .map_err(|e| invalid("render.latest_png", png.display(), e.to_string()))?;
            }
        }
        let point = |key: &'static str, v: &Option<Vec<f64>>| -> Result<_, ConfigError> {
            match v.as_deref() {
                None => Ok(None),
                Some(&[x, y, z])
                    if [x, y, z]
                        .iter()
                        .all(|c| c.is_finite() && c.abs() <= f64::from(f32::MAX)) =>
                {
                    Ok(Some(glam::Vec3::new(x as f32, y as f32, z as f32)))
                }
                Some(other) => Err(invalid(
                    key,
                    other,
                    "must be three finite numbers [x, y, z]",
                )),
            }
        };
        let fov_range = crate::render::scene::CameraOverride::FOV_DEG;
        let fov_deg = match self.fov_deg {
            None => None,
            Some(f) if f.is_finite() && fov_range.contains(&(f as f32)) => Some(f as f32),
            Some(f) => {
                return Err(invalid(
                    "render.fov_deg",
                    f,
                    format!(
                        "must be a vertical field of view in {}..={} degrees",
                        fov_range.start(),
                        fov_range.end()
                    ),
                ))
            }
        };
        let ortho_range = crate::render::scene::CameraOverride::ORTHO_HEIGHT;
        let ortho_height = match self.ortho_height {
            None => None,
            Some(h) if fov_deg.is_some() => {
                return Err(invalid(
                    "render.ortho_height",
                    h,
                    "cannot be combined with render.fov_deg (a camera is perspective or \
                     orthographic)",
                ))
            }
            Some(h) if h.is_finite() && ortho_range.contains(&(h as f32)) => Some(h as f32),
            Some(h) => {
                return Err(invalid(
                    "render.ortho_height",
                    h,
                    format!(
                        "must be a positive height in scene units ({}..={:e})",
                        ortho_range.start(),
                        ortho_range.end()
                    ),
                ))
            }
        };
        let camera = crate::render::scene::CameraOverride {
            eye: point("render.eye", &self.eye)?,
            look_at: point("render.look_at", &self.look_at)?,
            fov_deg,
            ortho_height,
        };
        if let (Some(eye), Some(target)) = (camera.eye, camera.look_at) {
            if eye == target {
                return Err(invalid(
                    "render.look_at",
                    [target.x, target.y, target.z],
                    "is render.eye: the camera must look somewhere else",
                ));
            }
        }
        Ok(RenderConfig {
            enabled,
            settings,
            scene,
            budget_ms: self.budget_ms,
            latest_png,
            lighting,
            camera,
            // Whether the scene has the clip is known once it is loaded (the render thread's
            // start and check-config name the clips it has); here only an empty name is
            // refused.
            animation: match self.animation.as_deref() {
                None => crate::render::scene::AnimationChoice::First,
                Some("") => {
                    return Err(invalid(
                        "render.animation",
                        "",
                        "must name a clip (its index or name) or be \"none\"; leave it out \
                         for the scene's first",
                    ))
                }
                Some(clip) => crate::render::scene::AnimationChoice::parse(clip),
            },
        })
    }
}

/// Validated `[daemon]`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DaemonConfig {
    /// How long shutdown waits for clients to take their goodbye.
    pub shutdown_grace: Duration,
    /// Worker threads of the serving runtime (1..=64).
    pub serve_threads: usize,
}

impl Default for DaemonConfig {
    fn default() -> Self {
        Self {
            shutdown_grace: Duration::from_secs(2),
            serve_threads: 2,
        }
    }
}

impl Config {
    /// Reads, parses and validates a config file.
    pub fn from_file(path: &Path) -> Result<Self, ConfigError> {
        RawConfig::from_file(path)?.validate()
    }
}

/// A duration in seconds from `key`, within `range`.
fn seconds(
    key: &'static str,
    value: Option<f64>,
    default: Duration,
    range: std::ops::RangeInclusive<f64>,
) -> Result<Duration, ConfigError> {
    match value {
        None => Ok(default),
        Some(v) if v.is_finite() && range.contains(&v) => Ok(Duration::from_secs_f64(v)),
        Some(v) => Err(invalid(
            key,
            v,
            format!(
                "must be a number of seconds in {}..={}",
                range.start(),
                range.end()
            ),
        )),
    }
}

/// A listen address from `key`: `None` when the value is empty (endpoint disabled).
fn listen_address(
    key: &'static str,
    value: Option<&str>,
    default: Option<SocketAddr>,
) -> Result<Option<SocketAddr>, ConfigError> {
    match value {
        None => Ok(default),
        Some("") => Ok(None),
        Some(text) => text.parse().map(Some).map_err(|_| {
            invalid(
                key,
                text,
                "must be IP:PORT (e.g. \"127.0.0.1:7878\", \"[::1]:7878\", \"0.0.0.0:7878\"), or \"\" to disable",
            )
        }),
    }
}

impl RawPipeline {
    fn validate(&self) -> Result<PipelineConfig, ConfigError> {
        let queue_capacity = integer_in(
            "pipeline.queue_capacity",
            self.queue_capacity,
            2,
            1..=64,
            " frames",
        )?;
        Ok(PipelineConfig { queue_capacity })
    }
}

impl RawStream {
    fn validate(&self) -> Result<ServerConfig, ConfigError> {
        let d = ServerConfig::default();
        let unix_socket = match self.unix_socket.as_deref() {
            None => d.unix_socket,
            Some("") => None,
            Some(path) => {
                // sun_path holds 108 bytes including the terminating NUL.
                if path.len() > 107 {
                    return Err(invalid(
                        "stream.unix_socket",
                        path,
                        "is longer than the 107 bytes a Unix socket path may have",
                    ));
                }
                if path.contains('\0') {
                    return Err(invalid(
                        "stream.unix_socket",
                        path.escape_default(),
                        "a path cannot hold a NUL character",
                    ));
                }
                Some(PathBuf::from(path))
            }
        };
        let unix_socket_mode = self.unix_socket_mode.unwrap_or(d.unix_socket_mode);
        if unix_socket_mode > 0o777 {
            return Err(invalid(
                "stream.unix_socket_mode",
                format!("{unix_socket_mode:#o}"),
                "must be permission bits, 0o000..=0o777 (write it as 0o666)",
            ));
        }
        let max_clients = integer_in(
            "stream.max_clients",
            self.max_clients,
            d.max_clients,
            1..=100_000,
            "",
        )?;
        let send_buffer_bytes = match self.send_buffer_bytes {
            None => d.send_buffer_bytes,
            Some(0) => None,
            Some(n) if (4096..=64 << 20).contains(&n) => Some(n),
            Some(n) => {
                return Err(invalid(
                    "stream.send_buffer_bytes",
                    n,
                    "must be 0 (the system default) or 4096..=67108864 bytes",
                ))
            }
        };
        let fanout_on =
            match self.fanout_on.as_deref() {
                None => d.fanout_on,
                Some("publisher") => FanoutOn::Publisher,
                Some("thread") => FanoutOn::Thread,
                Some(other) => return Err(invalid(
                    "stream.fanout_on",
                    other,
                    "must be \"publisher\" (the decompose thread writes each light list to the \
                     Unix-socket and TCP clients) or \"thread\" (an envlight-fanout thread does)",
                )),
            };
        let pass_threads = integer_in(
            "stream.pass_threads",
            self.pass_threads,
            d.pass_threads,
            1..=16,
            " (threads that write each light list to the clients)",
        )?;
        Ok(ServerConfig {
            send_buffer_bytes,
            fanout_on,
            pass_threads,
            unix_socket,
            unix_socket_mode,
            tcp: listen_address("stream.tcp", self.tcp.as_deref(), d.tcp)?,
            websocket: listen_address("stream.websocket", self.websocket.as_deref(), d.websocket)?,
            max_clients,
            handshake_timeout: seconds(
                "stream.handshake_timeout_s",
                self.handshake_timeout_s,
                d.handshake_timeout,
                0.01..=3600.0,
            )?,
            write_timeout: seconds(
                "stream.write_timeout_s",
                self.write_timeout_s,
                d.write_timeout,
                0.01..=3600.0,
            )?,
        })
    }
}

impl RawMetrics {
    fn validate(&self) -> Result<MetricsConfig, ConfigError> {
        let d = MetricsConfig::default();
        Ok(MetricsConfig {
            listen: listen_address("metrics.listen", self.listen.as_deref(), d.listen)?,
            max_frame_age: seconds(
                "metrics.max_frame_age_s",
                self.max_frame_age_s,
                d.max_frame_age,
                0.01..=86400.0,
            )?,
        })
    }
}

impl RawDaemon {
    fn validate(&self) -> Result<DaemonConfig, ConfigError> {
        let d = DaemonConfig::default();
        let serve_threads = integer_in(
            "daemon.serve_threads",
            self.serve_threads,
            d.serve_threads,
            1..=64,
            "",
        )?;
        Ok(DaemonConfig {
            shutdown_grace: seconds(
                "daemon.shutdown_grace_s",
                self.shutdown_grace_s,
                d.shutdown_grace,
                0.0..=600.0,
            )?,
            serve_threads,
        })
    }
}

/// The spellings of `--placement` / `decompose.placement`.
const PLACEMENTS: [(&str, LightPlacement); 2] = [
    ("centroid", LightPlacement::Centroid),
    ("sample-point", LightPlacement::SamplePoint),
];

/// The spellings of `--warp` / `decompose.warp`.
const WARPS: [(&str, Warp); 2] = [("rows", Warp::Rows), ("hierarchical", Warp::Hierarchical)];

/// The spellings of `source.kind`.
const SOURCE_KINDS: [(&str, SourceKind); 3] = [
    ("sky", SourceKind::Sky),
    ("sequence", SourceKind::Sequence),
    ("v4l2", SourceKind::V4l2),
];

/// The value spelled `s` in `table`.
fn spelled<T: Copy>(table: &[(&str, T)], s: &str) -> Option<T> {
    table.iter().find(|(name, _)| *name == s).map(|&(_, v)| v)
}

/// How `value` is spelled in `table` (every variant is in its table).
fn spelling<T: PartialEq>(table: &[(&'static str, T)], value: &T) -> &'static str {
    table
        .iter()
        .find(|(_, v)| v == value)
        .map_or("?", |(name, _)| name)
}

/// Parses a `--placement` / `decompose.placement` value.
pub fn parse_placement(s: &str) -> Option<LightPlacement> {
    spelled(&PLACEMENTS, s)
}

/// How a placement is spelled in the config and on the command line.
pub fn placement_name(placement: LightPlacement) -> &'static str {
    spelling(&PLACEMENTS, &placement)
}

/// Parses a `--warp` / `decompose.warp` value.
pub fn parse_warp(s: &str) -> Option<Warp> {
    spelled(&WARPS, s)
}

/// How a warp is spelled in the config and on the command line.
pub fn warp_name(warp: Warp) -> &'static str {
    spelling(&WARPS, &warp)
}

impl SourceKind {
    /// How the kind is spelled in `source.kind`.
    pub fn name(self) -> &'static str {
        spelling(&SOURCE_KINDS, &self)
    }
}

/// Parses a `--bright-history` / `decompose.bright_history` value.
pub fn parse_bright_history(s: &str) -> Option<BrightHistory> {
    BrightHistory::ALL.into_iter().find(|b| b.name() == s)
}

/// Parses a fisheye model name (`equidistant`, `equisolid`, `stereographic`, `orthographic`).
pub fn parse_fisheye_model(s: &str) -> Option<FisheyeModel> {
    FisheyeModel::ALL.into_iter().find(|m| m.name() == s)
}

fn check_finite(key: &'static str, v: f64) -> Result<f64, ConfigError> {
    if v.is_finite() {
        Ok(v)
    } else {
        Err(invalid(key, v, "must be a finite number"))
    }
}

impl RawSource {
    fn validate(&self) -> Result<SourceConfig, ConfigError> {
        let kind = self.kind.as_deref().unwrap_or("sky");
        let kind = spelled(&SOURCE_KINDS, kind).ok_or_else(|| {
            invalid(
                "source.kind",
                kind,
                "must be \"sky\", \"sequence\" or \"v4l2\"",
            )
        })?;
        let paths = self.paths.clone().unwrap_or_default();
        if paths.iter().any(|p| p.trim().is_empty()) {
            return Err(invalid(
                "source.paths",
                &paths,
                "an empty path names no file",
            ));
        }
        if let Some(camera) = paths.iter().find(|p| p.starts_with("v4l2:")) {
            return Err(invalid(
                "source.paths",
                camera,
                "a camera is not a path: set source.kind = \"v4l2\" and camera.device",
            ));
        }
        match kind {
            SourceKind::Sequence if paths.is_empty() => {
                return Err(invalid(
                    "source.paths",
                    &paths,
                    "kind = \"sequence\" needs at least one file, directory or glob pattern",
                ))
            }
            SourceKind::Sky | SourceKind::V4l2 if !paths.is_empty() => {
                return Err(invalid(
                    "source.paths",
                    &paths,
                    "is only used with kind = \"sequence\"",
                ))
            }
            _ => {}
        }
        if let Some(fps) = self.fps {
            crate::capture::check_fps(fps)
                .map_err(|message| invalid("source.fps", fps, message))?;
        }
        let projection = match self.projection.as_deref().unwrap_or("latlong") {
            "latlong" => Projection::LatLong,
            "angular" => Projection::AngularMap,
            "fisheye" => Projection::Fisheye(self.fisheye.validate()?),
            other => {
                return Err(invalid(
                    "source.projection",
                    other,
                    "must be \"latlong\", \"fisheye\" or \"angular\"",
                ))
            }
        };
        // Check the fisheye section even when it is not used, so a typo does not hide.
        self.fisheye.validate()?;
        if kind == SourceKind::Sky && self.looped == Some(true) {
            return Err(invalid(
                "source.loop",
                true,
                "the built-in sky never ends; loop applies to a sequence of files",
            ));
        }
        if kind == SourceKind::Sky && projection != Projection::LatLong {
            return Err(invalid(
                "source.projection",
                projection.name(),
                "the built-in sky is always \"latlong\"; projections apply to sequences",
            ));
        }
        let ignored_fisheye = if matches!(projection, Projection::Fisheye(_)) {
            Vec::new()
        } else {
            self.fisheye.set_apart_from_defaults()
        };
        Ok(SourceConfig {
            kind,
            paths,
            fps: self.fps,
            frames: self.frames,
            looped: self.looped.unwrap_or(false),
            projection,
            ignored_fisheye,
        })
    }
}

impl RawFisheye {
    /// The keys (full names) whose values differ from the defaults.
    fn set_apart_from_defaults(&self) -> Vec<&'static str> {
        let d = FisheyeCalibration::default();
        let model = self.model.as_deref().and_then(parse_fisheye_model);
        [
            ("source.fisheye.model", model.is_some_and(|m| m != d.model)),
            ("source.fisheye.center", self.center.is_some()),
            ("source.fisheye.radius", self.radius.is_some()),
            (
                "source.fisheye.fov_deg",
                self.fov_deg.is_some_and(|f| f != d.fov_deg),
            ),
            (
                "source.fisheye.rotation_deg",
                self.rotation_deg.is_some_and(|r| r != d.rotation_deg),
            ),
        ]
        .into_iter()
        .filter_map(|(key, set)| set.then_some(key))
        .collect()
    }

    fn validate(&self) -> Result<FisheyeCalibration, ConfigError> {
        let d = FisheyeCalibration::default();
        let model = match self.model.as_deref() {
            None => d.model,
            Some(s) => parse_fisheye_model(s).ok_or_else(|| {
                invalid(
                    "source.fisheye.model",
                    s,
                    "must be \"equidistant\", \"equisolid\", \"stereographic\" or \"orthographic\"",
                )
            })?,
        };
        let fov_deg = self.fov_deg.unwrap_or(d.fov_deg);
        if !(crate::envmap::MIN_FOV_DEG..360.0).contains(&fov_deg) {
            return Err(invalid(
                "source.fisheye.fov_deg",
                fov_deg,
                "must be in [1, 360) degrees",
            ));
        }
        if model == FisheyeModel::Orthographic && fov_deg > 180.0 {
            return Err(invalid(
                "source.fisheye.fov_deg",
                fov_deg,
                ORTHOGRAPHIC_FOV_LIMIT,
            ));
        }
        if let Some(r) = self.radius {
            if !(r > 0.0 && r <= crate::envmap::MAX_RADIUS_PX) {
                return Err(invalid(
                    "source.fisheye.radius",
                    r,
                    "must be a number of pixels in (0, 1e6]",
                ));
            }
        }
        if let Some(c) = self.center {
            if !c.iter().all(|v| v.is_finite()) {
                return Err(invalid(
                    "source.fisheye.center",
                    c,
                    "must be finite pixel coordinates [x, y]",
                ));
            }
        }
        let rotation_deg = check_finite(
            "source.fisheye.rotation_deg",
            self.rotation_deg.unwrap_or(d.rotation_deg),
        )?;
        Ok(FisheyeCalibration {
            model,
            center: self.center,
            radius: self.radius,
            fov_deg,
            rotation_deg,
        })
    }
}

impl RawSky {
    fn validate(&self) -> Result<SkyOptions, ConfigError> {
        let d = SkyOptions::default();
        let options = SkyOptions {
            width: self.width.unwrap_or(d.width),
            height: self.height.unwrap_or(d.height),
            turbidity: self.turbidity.unwrap_or(d.turbidity),
            sun_start_elevation_deg: self
                .sun_start_elevation_deg
                .unwrap_or(d.sun_start_elevation_deg),
            sun_start_azimuth_deg: self
                .sun_start_azimuth_deg
                .unwrap_or(d.sun_start_azimuth_deg),
            sun_speed_deg_per_s: self.sun_speed_deg_per_s.unwrap_or(d.sun_speed_deg_per_s),
            clouds: self.clouds.unwrap_or(d.clouds),
            cloud_cover: self.cloud_cover.unwrap_or(d.cloud_cover),
            wind_speed: self.wind_speed.unwrap_or(d.wind_speed),
            ground_albedo: self.ground_albedo.unwrap_or(d.ground_albedo),
            seed: self.seed.unwrap_or(d.seed),
            fps: None,
            frames: None,
        };
        options.check().map_err(|e| ConfigError::Invalid {
            key: sky_key(e.field),
            value: e.value,
            message: format!("must be {}", e.expected),
        })?;
        Ok(options)
    }
}

/// The config key of a `[sky]` field.
fn sky_key(field: &str) -> &'static str {
    match field {
        "width" => "sky.width",
        "height" => "sky.height",
        "turbidity" => "sky.turbidity",
        "sun_start_elevation_deg" => "sky.sun_start_elevation_deg",
        "sun_start_azimuth_deg" => "sky.sun_start_azimuth_deg",
        "sun_speed_deg_per_s" => "sky.sun_speed_deg_per_s",
        "cloud_cover" => "sky.cloud_cover",
        "wind_speed" => "sky.wind_speed",
        "ground_albedo" => "sky.ground_albedo",
        _ => "sky",
    }
}

impl RawDecompose {
    fn validate(&self) -> Result<DecomposeSettings, ConfigError> {
        let d = DecomposeSettings::default();
        let lights = self.lights.unwrap_or(d.lights);
        if !(1..=MAX_POINTS).contains(&lights) {
            return Err(invalid(
                "decompose.lights",
                lights,
                format!("must be between 1 and {MAX_POINTS}"),
            ));
        }
        let working_width = self.working_width.unwrap_or(d.working_width);
        if !WORKING_WIDTH_RANGE.contains(&working_width) {
            return Err(invalid(
                "decompose.working_width",
                working_width,
                format!(
                    "must be between {} and {}",
                    WORKING_WIDTH_RANGE.start(),
                    WORKING_WIDTH_RANGE.end()
                ),
            ));
        }
        let placement = match self.placement.as_deref() {
            None => d.placement,
            Some(s) => parse_placement(s).ok_or_else(|| {
                invalid(
                    "decompose.placement",
                    s,
                    "must be \"centroid\" or \"sample-point\"",
                )
            })?,
        };
        let warp = match self.warp.as_deref() {
            None => d.warp,
            Some(s) => parse_warp(s).ok_or_else(|| {
                invalid("decompose.warp", s, "must be \"rows\" or \"hierarchical\"")
            })?,
        };
        let bright_history = match self.bright_history.as_deref() {
            None => d.bright_history,
            Some(s) => parse_bright_history(s).ok_or_else(|| {
                invalid(
                    "decompose.bright_history",
                    s,
                    "must be \"fold\", \"fade\" or \"blend\"",
                )
            })?,
        };
        let taps = match &self.filter_taps {
            None => d.filter_taps.clone().unwrap_or_default(),
            Some(taps) => {
                FirFilter::new(taps)
                    .map_err(|message| invalid("decompose.filter_taps", taps, message))?;
                taps.clone()
            }
        };
        let filter_taps = self.filter.unwrap_or(true).then_some(taps);
        let fraction = self
            .merge_spacing_fraction
            .or(d.merge_spacing_fraction)
            .or(Some(crate::decompose::merge::DEFAULT_SPACING_FRACTION))
            .unwrap_or_default();
        if !(fraction.is_finite() && fraction > 0.0 && fraction <= 2.0) {
            return Err(invalid(
                "decompose.merge_spacing_fraction",
                fraction,
                "must be a number in (0, 2]",
            ));
        }
        let merge = self.merge.unwrap_or(d.merge_spacing_fraction.is_some());
        let merge_spacing_fraction = merge.then_some(fraction);
        let pdf_exponent = self.pdf_exponent.unwrap_or(d.pdf_exponent);
        if !(pdf_exponent.is_finite() && pdf_exponent > 0.0 && pdf_exponent <= 1.0) {
            return Err(invalid(
                "decompose.pdf_exponent",
                pdf_exponent,
                "must be a number in (0, 1]",
            ));
        }
        let split_factor = self
            .split_factor
            .or(d.split_factor)
            .or(Some(crate::decompose::split::DEFAULT_SPLIT_FACTOR))
            .unwrap_or_default();
        if !(split_factor.is_finite() && split_factor >= 1.0) {
            return Err(invalid(
                "decompose.split_factor",
                split_factor,
                "must be a number of at least 1",
            ));
        }
        let split = self.split.unwrap_or(d.split_factor.is_some());
        if split && placement != LightPlacement::Centroid {
            return Err(invalid(
                "decompose.split",
                true,
                "needs placement = \"centroid\" (the pieces are centroids)",
            ));
        }
        Ok(DecomposeSettings {
            lights,
            working_width,
            placement,
            filter_taps,
            merge_spacing_fraction,
            pdf_exponent,
            warp,
            concentrated_lloyd: self.concentrated_lloyd.unwrap_or(d.concentrated_lloyd),
            refine_concentrated: self.refine_concentrated.unwrap_or(d.refine_concentrated),
            bright_history,
            split_factor: split.then_some(split_factor),
            resample_threads: integer_in(
                "decompose.resample_threads",
                self.resample_threads,
                d.resample_threads,
                1..=crate::decompose::MAX_RESAMPLE_THREADS,
                " (threads that resample a fisheye or other non-lat-long frame)",
            )?,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const SHIPPED: &str = include_str!("../config/envlight.toml");

    fn parse(text: &str) -> Result<Config, ConfigError> {
        RawConfig::parse(text, Path::new("test.toml"))?.validate()
    }

    /// `render.animation` names a clip by index or name, or `none`; absent, the first.
    #[test]
    fn render_animation_is_an_index_a_name_or_none() {
        use crate::render::scene::AnimationChoice;
        for (text, choice) in [
            ("", AnimationChoice::First),
            ("animation = \"none\"", AnimationChoice::None),
            ("animation = \"1\"", AnimationChoice::Index(1)),
            ("animation = \"walk\"", AnimationChoice::Name("walk".into())),
        ] {
            let config = parse(&format!("[render]\n{text}")).unwrap();
            assert_eq!(config.render.animation, choice, "{text}");
        }
    }

    /// Each stage's filter takes the lights' taps as validated, none with `filter = false` or
    /// when the lights are not filtered.
    #[test]
    fn the_stages_filter_with_the_lights_taps() {
        let taps = |c: &Config| {
            [
                c.asg.settings.filter_taps.clone(),
                c.wavelet.settings.filter_taps.clone(),
                c.sh.settings.filter_taps.clone(),
            ]
        };
        let defaults = parse("").unwrap();
        let lights = crate::decompose::filter::DEFAULT_TAPS.to_vec();
        assert_eq!(taps(&defaults), [0, 1, 2].map(|_| Some(lights.clone())));
        assert!(defaults.asg.filter && defaults.wavelet.filter && defaults.sh.filter);
        let custom = parse("[decompose]\nfilter_taps = [1, 2, 1]\n").unwrap();
        let custom_taps = custom.decompose.filter_taps.clone();
        assert_eq!(custom_taps.as_deref().map(<[f64]>::len), Some(3));
        assert_eq!(taps(&custom), [0, 1, 2].map(|_| custom_taps.clone()));
        let off = parse("[asg]\nfilter = false\n[sh]\nfilter = false\n").unwrap();
        assert_eq!(taps(&off), [None, Some(lights), None]);
        let unfiltered_lights = parse("[decompose]\nfilter = false\n").unwrap();
        assert_eq!(taps(&unfiltered_lights), [None, None, None]);
        let e = parse("[asg]\nfilter = 1\n").unwrap_err().to_string();
        assert!(e.contains("filter") && e.contains("bool"), "{e}");
    }

    /// A long value is shown by its start and length, so the reason is not lost behind it
    /// (`--taps` of 10,001 numbers printed 50 KB first).
    #[test]
    fn long_values_are_shortened_in_errors() {
        let taps = vec![1.0; 10_001];
        let e = parse(&format!("[decompose]\nfilter_taps = {taps:?}\n"))
            .unwrap_err()
            .to_string();
        assert!(e.len() < 200, "{}", &e[..e.len().min(2000)]);
        assert!(
            e.contains("… (50005 characters)") && e.ends_with("need 1..=64 taps, got 10001"),
            "{e}"
        );
        // The parser's quote of a long line at fault is cut too.
        let e = parse(&format!("[decompose]\nfilter_taps = {taps:?}x\n"))
            .unwrap_err()
            .to_string();
        assert!(
            e.len() < 1000 && e.contains("line 2"),
            "{}",
            &e[..e.len().min(2000)]
        );
        // The reason, with the valid keys, is whole (it was cut at 160 characters).
        let e = parse("[decompose]\nlightz = 1\n").unwrap_err().to_string();
        assert!(e.contains("lightz") && e.contains("filter_taps"), "{e}");
        let short = parse("[decompose]\nlights = 0\n").unwrap_err().to_string();
        assert!(short.starts_with("decompose.lights = 0:"), "{short}");
    }

    fn error(text: &str) -> String {
        parse(text).expect_err(text).to_string()
    }

    /// A fisheye calibration under another projection is kept in the config's note of what is
    /// not used (it was checked and then dropped without a word); the defaults the shipped
    /// config writes out are not a calibration.
    #[test]
    fn a_fisheye_calibration_under_another_projection_is_noted() {
        let section = "[source.fisheye]\nmodel = \"equidistant\"\nradius = 20.0\nfov_deg = 200.0\n";
        for projection in ["", "projection = \"angular\"\n"] {
            let text = format!(
                "[source]\nkind = \"sequence\"\npaths = [\"a.exr\"]\n{projection}{section}"
            );
            assert_eq!(
                parse(&text).unwrap().source.ignored_fisheye,
                ["source.fisheye.radius", "source.fisheye.fov_deg"]
            );
        }
        let text = format!(
            "[source]\nkind = \"sequence\"\npaths = [\"a.exr\"]\nprojection = \"fisheye\"\n{section}"
        );
        assert!(parse(&text).unwrap().source.ignored_fisheye.is_empty());
        let defaults =
            "[source.fisheye]\nmodel = \"equidistant\"\nfov_deg = 180.0\nrotation_deg = 0.0\n";
        assert!(parse(defaults).unwrap().source.ignored_fisheye.is_empty());
    }

    #[test]
    fn shipped_config_equals_the_defaults() {
        let config = parse(SHIPPED).unwrap();
        assert_eq!(config, Config::default());
        assert_eq!(parse("").unwrap(), Config::default());
        assert_eq!(config.decompose, DecomposeSettings::default());
    }

    #[test]
    fn shipped_config_sets_every_key() {
        // Every key of the raw config appears in the shipped file (optional ones commented).
        let uncommented: String = SHIPPED
            .lines()
            .map(|l| l.trim_start().trim_start_matches("# "))
            .collect::<Vec<_>>()
            .join("\n");
        for key in [
            "kind",
            "paths",
            "fps",
            "frames",
            "loop",
            "projection",
            "model",
            "center",
            "radius",
            "fov_deg",
            "rotation_deg",
            "width",
            "height",
            "turbidity",
            "sun_start_elevation_deg",
            "sun_start_azimuth_deg",
            "sun_speed_deg_per_s",
            "clouds",
            "cloud_cover",
            "wind_speed",
            "ground_albedo",
            "seed",
            "lights",
            "working_width",
            "placement",
            "filter",
            "filter_taps",
            "merge",
            "merge_spacing_fraction",
            "pdf_exponent",
            "warp",
            "concentrated_lloyd",
            "refine_concentrated",
            "bright_history",
            "split",
            "split_factor",
            "resample_threads",
            "enabled",
            "lobes",
            "fit_height",
            "iterations",
            "warm_iterations",
            "learning_rate",
            "warm_learning_rate",
            "diffuse_weight",
            "temporal_weight",
            "diffuse_normals",
            "threads",
            "first_subset",
            "warm_subset",
            "warm_centroid",
            "lighting",
            "shadow_raster",
            "scene",
            "shadow_resolution",
            "supersample",
            "fxaa",
            "culling",
            "shadow_catcher",
            "budget_ms",
            "latest_png",
            "eye",
            "look_at",
            "fov_deg",
            "basis",
            "side",
            "coefficients",
        ] {
            assert!(
                uncommented
                    .lines()
                    .any(|l| l.starts_with(&format!("{key} = "))),
                "{key} missing from config/envlight.toml"
            );
        }
    }

    #[test]
    fn unknown_keys_are_named() {
        let e = error("[decompose]\nlightz = 3\n");
        assert!(e.contains("lightz"), "{e}");
        let e = error("[nonsense]\n");
        assert!(e.contains("nonsense"), "{e}");
        let e = error("[source.fisheye]\nfocal = 3.0\n");
        assert!(e.contains("focal"), "{e}");
    }

    #[test]
    fn arrays_of_the_wrong_length_are_errors() {
        // serde's fixed-size arrays read the first N values and dropped the rest.
        for (text, key) in [
            ("[source.fisheye]\ncenter = [1.0, 2.0, 3.0]", "center"),
            ("[source.fisheye]\ncenter = [1.0]", "center"),
            (
                "[camera]\nwhite_balance = [1.0, 1.0, 1.0, 5.0]",
                "white_balance",
            ),
        ] {
            let e = error(text);
            assert!(e.contains(key) && e.contains("expected"), "{text}: {e}");
        }
        let e = error("[source.fisheye]\ncenter = [1.0, 2.0, \"x\"]");
        assert!(e.contains("center"), "{e}");
        parse("[source.fisheye]\ncenter = [1.0, 2.0]").unwrap();
    }

    #[test]
    fn settings_that_would_be_ignored_or_collide_are_errors() {
        for (text, expected) in [
            ("[source]\nloop = true", "source.loop = true"),
            // Checked even when another response is used, like [source.fisheye].
            ("[camera]\ngamma = nan", "camera.gamma"),
            (
                "[stream]\ntcp = \"127.0.0.1:7000\"\nwebsocket = \"127.0.0.1:7000\"",
                "stream.websocket = \"127.0.0.1:7000\": takes the port of stream.tcp",
            ),
            (
                "[stream]\ntcp = \"0.0.0.0:7000\"\n[metrics]\nlisten = \"127.0.0.1:7000\"",
                "metrics.listen = \"127.0.0.1:7000\": takes the port of stream.tcp",
            ),
            ("[stream]\nunix_socket = \"/tmp/a\\u0000b\"", "NUL"),
        ] {
            let e = error(text);
            assert!(e.contains(expected), "{text}: {e}");
        }
        // Port 0 (any free port) twice, and one port on two addresses, are fine.
        for text in [
            "[stream]\ntcp = \"127.0.0.1:0\"\nwebsocket = \"127.0.0.1:0\"",
            "[stream]\ntcp = \"127.0.0.1:7000\"\nwebsocket = \"127.0.0.2:7000\"",
        ] {
            parse(text).expect(text);
        }
    }

    #[test]
    fn a_config_file_past_the_size_limit_is_an_error() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("big.toml");
        let comment = "#".repeat(MAX_CONFIG_BYTES as usize + 1);
        std::fs::write(&path, comment).unwrap();
        let e = RawConfig::from_file(&path).err().unwrap().to_string();
        assert!(e.contains("big.toml") && e.contains("more than the"), "{e}");
        // Nor is one that is not a regular file: a FIFO without a writer would block.
        let fifo = dir.path().join("pipe.toml");
        let made = std::process::Command::new("mkfifo").arg(&fifo).status();
        assert!(made.unwrap().success());
        let e = RawConfig::from_file(&fifo).err().unwrap().to_string();
        assert!(
            e.contains("pipe.toml") && e.contains("not a regular file"),
            "{e}"
        );
    }

    #[test]
    fn integer_keys_out_of_range_name_the_key_the_value_and_the_range() {
        for (text, expected) in [
            (
                "[pipeline]\nqueue_capacity = 0",
                "pipeline.queue_capacity = 0: must be 1..=64 frames",
            ),
            (
                "[pipeline]\nqueue_capacity = 65",
                "pipeline.queue_capacity = 65: must be 1..=64 frames",
            ),
            (
                "[stream]\nmax_clients = 100001",
                "stream.max_clients = 100001: must be 1..=100000",
            ),
            (
                "[stream]\npass_threads = 17",
                "stream.pass_threads = 17: must be 1..=16 (threads",
            ),
            (
                "[daemon]\nserve_threads = 0",
                "daemon.serve_threads = 0: must be 1..=64",
            ),
            ("[render]\nwidth = 0", "render.width = 0: must be 1..=16384"),
            (
                "[render]\nheight = 16385",
                "render.height = 16385: must be 1..=16384",
            ),
            (
                "[render]\nshadow_resolution = 8193",
                "render.shadow_resolution = 8193: must be 16..=8192",
            ),
            (
                "[render]\nshadow_resolution = 1",
                "render.shadow_resolution = 1: must be 16..=8192",
            ),
            (
                "[render]\nsupersample = 5",
                "render.supersample = 5: must be 1..=4",
            ),
            (
                "[render]\neye = [1, 2]",
                "render.eye = [1.0, 2.0]: must be three finite numbers",
            ),
            (
                "[render]\nfov_deg = 180",
                "render.fov_deg = 180.0: must be a vertical field of view in 1..=179 degrees",
            ),
            (
                "[render]\northo_height = 0",
                "render.ortho_height = 0.0: must be a positive height in scene units",
            ),
            (
                "[render]\nfov_deg = 30\northo_height = 2",
                "render.ortho_height = 2.0: cannot be combined with render.fov_deg",
            ),
            (
                "[render]\neye = [1, 2, 3]\nlook_at = [1, 2, 3]",
                "render.look_at = [1.0, 2.0, 3.0]: is render.eye",
            ),
            (
                "[render]\nanimation = \"\"",
                "render.animation = \"\": must name a clip",
            ),
            (
                "[render]\nsupersample = 2\nfxaa = true",
                "render.fxaa = true: cannot be combined with render.supersample = 2",
            ),
            (
                "[asg]\nfit_height = 1025",
                "asg.fit_height = 1025: must be 4..=1024 (the fit map",
            ),
            (
                "[asg]\niterations = 10000001",
                "asg.iterations = 10000001: must be 0..=10000000",
            ),
            (
                "[camera]\nheight = 16385",
                "camera.height = 16385: must be 1..=16384 pixels",
            ),
            (
                "[camera]\nconvert_threads = 0",
                "camera.convert_threads = 0: must be 1..=64 (threads",
            ),
            (
                "[decompose]\nresample_threads = 65",
                "decompose.resample_threads = 65: must be 1..=64 (threads",
            ),
        ] {
            let e = error(text);
            assert!(e.contains(expected), "{text}: {e}");
        }
        // The ends of each range are accepted.
        for text in [
            "[pipeline]\nqueue_capacity = 64",
            "[stream]\npass_threads = 16",
            "[daemon]\nserve_threads = 1",
            "[asg]\nfit_height = 4",
            "[camera]\nwidth = 16384",
        ] {
            parse(text).expect(text);
        }
    }

    #[test]
    fn invalid_values_name_the_key() {
        for (text, key, value) in [
            ("[decompose]\nlights = 0", "decompose.lights", "0"),
            // The merge limits are checked together; the error names the key that was set.
            ("[camera]\nsaturated = 1.5", "camera.saturated", "1.5"),
            ("[camera]\ndark = 0.99", "camera.dark", "0.99"),
            (
                "[decompose]\nlights = 100000000",
                "decompose.lights",
                "100000000",
            ),
            (
                "[decompose]\nfilter_taps = []",
                "decompose.filter_taps",
                "[]",
            ),
            (
                "[decompose]\nfilter_taps = [0, 0]",
                "decompose.filter_taps",
                "0.0",
            ),
            (
                "[decompose]\nworking_width = 8",
                "decompose.working_width",
                "8",
            ),
            (
                "[decompose]\nplacement = \"middle\"",
                "decompose.placement",
                "middle",
            ),
            (
                "[decompose]\nmerge_spacing_fraction = 3.0",
                "decompose.merge_spacing_fraction",
                "3",
            ),
            (
                "[source.fisheye]\nfov_deg = 400",
                "source.fisheye.fov_deg",
                "400",
            ),
            (
                "[source.fisheye]\nradius = -2",
                "source.fisheye.radius",
                "-2",
            ),
            (
                "[source.fisheye]\nmodel = \"pinhole\"",
                "source.fisheye.model",
                "pinhole",
            ),
            ("[source]\nkind = \"camera\"", "source.kind", "camera"),
            ("[source]\nkind = \"sequence\"", "source.paths", "[]"),
            (
                "[source]\nkind = \"sequence\"\npaths = [\"\"]",
                "source.paths",
                "an empty path",
            ),
            (
                "[camera]\nretry_initial_s = 100\nretry_max_s = 1",
                "camera.retry_initial_s",
                "must not exceed camera.retry_max_s",
            ),
            ("[camera]\nfps = 1e-300", "camera.fps", "1e-300"),
            ("[camera]\nexposure_s = 1e308", "camera.exposure_s", "1e308"),
            ("[camera]\ngain = 1e-300", "camera.gain", "1e-300"),
            ("[camera]\nscale = 1e308", "camera.scale", "1e308"),
            ("[camera]\ngamma = 1e-300", "camera.gamma", "1e-300"),
            ("[camera]\ntimeout_s = 1e-300", "camera.timeout_s", "1e-300"),
            ("[camera]\ndevice = \"\"", "camera.device", "device path"),
            ("[source]\nfps = 0", "source.fps", "0"),
            ("[source]\nfps = 1e-30", "source.fps", "1e-30"),
            (
                "[source.fisheye]\nmodel = \"orthographic\"\nfov_deg = 200",
                "source.fisheye.fov_deg",
                "200",
            ),
            (
                "[source]\nprojection = \"cube\"",
                "source.projection",
                "cube",
            ),
            ("[sky]\nwidth = 0", "sky.width", "0"),
            (
                "[sky]\nwidth = 16384\nheight = 16384",
                "sky.width",
                "16384 (height 16384)",
            ),
            (
                "[camera]\nsettle_frames = 4294967295",
                "camera.settle_frames",
                "4294967295",
            ),
            ("[asg]\nlobes = 0", "asg.lobes", "0"),
            ("[asg]\nlobes = 65", "asg.lobes", "65"),
            ("[asg]\nfit_height = 2", "asg.fit_height", "2"),
            ("[asg]\nlearning_rate = 0", "asg.learning_rate", "0"),
            ("[asg]\ntemporal_weight = -1", "asg.temporal_weight", "-1"),
            ("[asg]\ndiffuse_normals = 8", "asg.diffuse_normals", "8"),
            ("[asg]\nwarm_subset = 0", "asg.warm_subset", "0"),
            ("[asg]\nfirst_subset = 17", "asg.first_subset", "17"),
            ("[asg]\nthreads = 1000", "asg.threads", "1000"),
            (
                "[render]\nlighting = \"ambient\"",
                "render.lighting",
                "ambient",
            ),
            (
                "[render]\nlighting = \"sh\"\nbudget_ms = 16.0",
                "render.budget_ms",
                "16",
            ),
            (
                "[render]\nenabled = true\nlighting = \"sh\"",
                "render.lighting",
                "sh",
            ),
            (
                "[render]\nshadow_raster = \"raster\"",
                "render.shadow_raster",
                "raster",
            ),
            (
                "[render]\nenabled = true\nlighting = \"asg\"",
                "render.lighting",
                "asg",
            ),
            ("[sky]\ncloud_cover = 2", "sky.cloud_cover", "2"),
            ("[wavelet]\nside = 48", "wavelet.side", "48"),
            ("[wavelet]\nside = 2048", "wavelet.side", "2048"),
            ("[wavelet]\ncoefficients = 0", "wavelet.coefficients", "0"),
            (
                "[wavelet]\nside = 8\ncoefficients = 65",
                "wavelet.coefficients",
                "65",
            ),
            ("[wavelet]\nbasis = \"db42\"", "wavelet.basis", "db42"),
            ("[sh]\ndegree = 16", "sh.degree", "16"),
            (
                "[decompose]\nconcentrated_lloyd = \"yes\"",
                "concentrated_lloyd",
                "yes",
            ),
            (
                "[decompose]\nrefine_concentrated = 1",
                "refine_concentrated",
                "1",
            ),
            (
                "[decompose]\nsplit = true\nplacement = \"sample-point\"",
                "decompose.split",
                "centroid",
            ),
            (
                "[decompose]\nsplit_factor = 0.5",
                "decompose.split_factor",
                "0.5",
            ),
            (
                "[decompose]\nbright_history = \"merge\"",
                "decompose.bright_history",
                "merge",
            ),
            (
                "[render]\nenabled = true\nlatest_png = \"/nonexistent/x.png\"",
                "render.latest_png",
                "its folder does not exist",
            ),
            (
                "[render]\nenabled = true\nlatest_png = \"/dev/null\"",
                "render.latest_png",
                "a device, pipe or socket",
            ),
            (
                "[render]\nenabled = true\nscene = \"/nonexistent/s.glb\"",
                "render.scene",
                "must be an existing",
            ),
        ] {
            let e = error(text);
            assert!(e.contains(key) && e.contains(value), "{text}: {e}");
        }
    }

    /// A camera among a config file's `source.paths` is named as such (it was made relative to
    /// the config's folder and reported as a missing file).
    #[test]
    fn a_camera_in_source_paths_is_named() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("cam.toml");
        let text = "[source]\nkind = \"sequence\"\npaths = [\"v4l2:/dev/video0\"]\n";
        std::fs::write(&path, text).unwrap();
        let e = Config::from_file(&path).err().unwrap().to_string();
        assert!(
            e.contains("source.paths = \"v4l2:/dev/video0\"") && e.contains("camera.device"),
            "{e}"
        );
    }

    #[test]
    fn numbers_are_shown_short() {
        assert_eq!(shown_number(30.0), "30");
        assert_eq!(shown_number(0.5), "0.5");
        assert_eq!(shown_number(1e300), "1e300");
        assert_eq!(shown_number(-2.5e-300), "-2.5e-300");
        assert_eq!(shown_number(f64::NAN), "NaN");
        assert_eq!(shown_number(0.0), "0");
    }

    /// Every placement, warp and source kind is spelled as its parser reads it (check-config
    /// and the logs print these names).
    #[test]
    fn names_are_the_spellings_the_parsers_read() {
        for (name, placement) in PLACEMENTS {
            assert_eq!(
                parse_placement(placement_name(placement)),
                Some(placement),
                "{name}"
            );
        }
        for (name, warp) in WARPS {
            assert_eq!(parse_warp(warp_name(warp)), Some(warp), "{name}");
        }
        for kind in [SourceKind::Sky, SourceKind::Sequence, SourceKind::V4l2] {
            assert_eq!(spelled(&SOURCE_KINDS, kind.name()), Some(kind));
        }
        assert_eq!(warp_name(Warp::Hierarchical), "hierarchical");
    }

    #[test]
    fn values_override_defaults() {
        let c = parse(
            "[source]\nkind = \"sequence\"\npaths = [\"a/*.exr\"]\nloop = true\nfps = 30\n\
             projection = \"fisheye\"\n[source.fisheye]\nmodel = \"equisolid\"\nfov_deg = 190\n\
             center = [10.0, 12.0]\n[decompose]\nlights = 64\nfilter = false\nmerge = false\n\
             placement = \"sample-point\"\nconcentrated_lloyd = true\n\
             refine_concentrated = false\nbright_history = \"fade\"\n",
        )
        .unwrap();
        assert_eq!(c.source.kind, SourceKind::Sequence);
        assert!(c.source.looped);
        assert_eq!(c.source.fps, Some(30.0));
        let Projection::Fisheye(cal) = c.source.projection else {
            panic!("not fisheye")
        };
        assert_eq!(cal.model, FisheyeModel::Equisolid);
        assert_eq!(cal.fov_deg, 190.0);
        assert_eq!(cal.center, Some([10.0, 12.0]));
        assert_eq!(c.decompose.lights, 64);
        assert_eq!(c.decompose.filter_taps, None);
        assert_eq!(c.decompose.merge_spacing_fraction, None);
        assert_eq!(c.decompose.placement, LightPlacement::SamplePoint);
        assert!(c.decompose.concentrated_lloyd);
        assert!(!c.decompose.refine_concentrated);
        assert_eq!(c.decompose.bright_history, BrightHistory::Fade);
    }

    #[test]
    fn missing_file_is_named() {
        let e = Config::from_file(Path::new("/nonexistent/envlight.toml")).unwrap_err();
        assert!(e.to_string().contains("/nonexistent/envlight.toml"));
    }
}
