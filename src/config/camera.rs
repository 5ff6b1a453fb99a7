//! `[camera]`: the V4L2 camera (used when `source.kind = "v4l2"`), raw → validated
//! [`CameraSettings`]. Every key is optional; errors name the key and the value.

use super::{check_finite, integer_in, invalid, seconds, ConfigError};
use crate::capture::bracket::MergeLimits;
use crate::capture::pixel_format::{PixelFormat, YuvMatrix};
use crate::capture::resilient::RetryPolicy;
use crate::capture::response::{ResponseCurve, ResponseModel};
use crate::capture::v4l2::CameraSettings;
use crate::capture::v4l2_mplane::SEPARATE_PLANE_FOURCCS;
use crate::envmap::Projection;
use serde::Deserialize;
use std::path::Path;
use std::sync::Arc;

/// Most frames `camera.settle_frames` may drop after an exposure change (at 30 frames/s, over
/// three seconds per bracket): a larger value stalled bracketed capture without end.
pub const MAX_SETTLE_FRAMES: u32 = 100;

/// `[camera]` as written.
#[derive(Clone, Debug, Default, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct RawCamera {
    pub device: Option<String>,
    pub formats: Option<Vec<String>>,
    pub width: Option<u32>,
    pub height: Option<u32>,
    pub fps: Option<f64>,
    pub yuv_matrix: Option<String>,
    pub response: Option<String>,
    pub gamma: Option<f64>,
    pub log_a: Option<f64>,
    pub log_b: Option<f64>,
    pub curve: Option<String>,
    pub exposure_s: Option<f64>,
    pub gain: Option<f64>,
    pub gain_unity: Option<f64>,
    #[serde(default, deserialize_with = "super::exactly")]
    pub white_balance: Option<[f64; 3]>,
    pub scale: Option<f64>,
    pub bracket_exposures_s: Option<Vec<f64>>,
    pub settle_frames: Option<u32>,
    pub dark: Option<f64>,
    pub saturated: Option<f64>,
    pub timeout_s: Option<f64>,
    pub retry_initial_s: Option<f64>,
    pub retry_max_s: Option<f64>,
    pub convert_threads: Option<usize>,
}

/// The camera's times (timeout, retry backoff), in seconds: at least a millisecond (a timeout
/// of 1e-300 s timed every frame out), at most a day.
const CAMERA_SECONDS: std::ops::RangeInclusive<f64> = 0.001..=86_400.0;

/// `v` within `lo..=hi` (`unit` follows the bounds in the message): the camera's factors are
/// bounded so that radiance = X · scale / (exposure · gain) stays finite (1e308 / 1e-300
/// overflowed to infinity).
fn in_range(key: &'static str, v: f64, lo: f64, hi: f64, unit: &str) -> Result<f64, ConfigError> {
    if v.is_finite() && (lo..=hi).contains(&v) {
        Ok(v)
    } else {
        Err(invalid(key, v, format!("must be {lo:e}..={hi:e}{unit}")))
    }
}

impl RawCamera {
    /// Validated settings; `projection` comes from `[source]`.
    pub fn validate(&self, projection: Projection) -> Result<CameraSettings, ConfigError> {
        let d = CameraSettings::default();
        let formats = match &self.formats {
            None => d.formats,
            Some(names) if names.is_empty() => {
                return Err(invalid(
                    "camera.formats",
                    names,
                    "needs at least one format",
                ))
            }
            Some(names) => names
                .iter()
                .map(|n| {
                    PixelFormat::parse(n).ok_or_else(|| {
                        let supported: Vec<String> =
                            PixelFormat::all().iter().map(|f| f.to_string()).collect();
                        let separate: Vec<String> = SEPARATE_PLANE_FOURCCS
                            .iter()
                            .map(|(c, _)| String::from_utf8_lossy(c).into_owned())
                            .collect();
                        invalid(
                            "camera.formats",
                            n,
                            format!(
                                "is not a supported format (one of {}; I420 for YU12; on a \
                                 multi-planar node also {})",
                                supported.join(", "),
                                separate.join(", ")
                            ),
                        )
                    })
                })
                .collect::<Result<_, _>>()?,
        };
        let width = integer_in("camera.width", self.width, d.width, 1..=16384, " pixels")?;
        let height = integer_in("camera.height", self.height, d.height, 1..=16384, " pixels")?;
        let fps = (self.fps)
            .map(|f| in_range("camera.fps", f, 1e-4, 1e4, " frames per second"))
            .transpose()?;
        let yuv_matrix = match self.yuv_matrix.as_deref().unwrap_or("auto") {
            "auto" => YuvMatrix::Auto,
            "bt601" => YuvMatrix::Bt601,
            "bt709" => YuvMatrix::Bt709,
            "bt2020" => YuvMatrix::Bt2020,
            other => {
                return Err(invalid(
                    "camera.yuv_matrix",
                    other,
                    "must be \"auto\", \"bt601\", \"bt709\" or \"bt2020\"",
                ))
            }
        };
        // Checked even when another response is used, so a typo does not hide.
        let gamma = in_range("camera.gamma", self.gamma.unwrap_or(2.2), 0.05, 20.0, "")?;
        let response =
            match self.response.as_deref().unwrap_or("srgb") {
                "srgb" => ResponseModel::Srgb,
                "linear" => ResponseModel::Linear,
                "pq" => ResponseModel::Pq,
                "hlg" => ResponseModel::Hlg,
                "gamma" => ResponseModel::Gamma(gamma),
                "logarithmic" => {
                    let (Some(a), Some(b)) = (self.log_a, self.log_b) else {
                        return Err(invalid(
                            "camera.response",
                            "logarithmic",
                            "needs camera.log_a and camera.log_b (code = log_a·ln(X) + log_b)",
                        ));
                    };
                    let a = check_finite("camera.log_a", a)?;
                    if a == 0.0 {
                        return Err(invalid("camera.log_a", a, "must not be 0"));
                    }
                    ResponseModel::Logarithmic {
                        a,
                        b: check_finite("camera.log_b", b)?,
                    }
                }
                "curve" => {
                    let Some(path) = &self.curve else {
                        return Err(invalid(
                            "camera.response",
                            "curve",
                            "needs camera.curve = \"FILE\" (see envlight calibrate-response)",
                        ));
                    };
                    let curve = ResponseCurve::read(Path::new(path))
                        .map_err(|e| invalid("camera.curve", path, e.to_string()))?;
                    ResponseModel::Curve(Arc::new(curve))
                }
                other => return Err(invalid(
                    "camera.response",
                    other,
                    "must be \"srgb\", \"gamma\", \"linear\", \"pq\", \"hlg\", \"logarithmic\" \
                     or \"curve\"",
                )),
            };
        let exposure_s = (self.exposure_s)
            .map(|v| in_range("camera.exposure_s", v, 1e-9, 3600.0, " seconds"))
            .transpose()?;
        let gain = (self.gain)
            .map(|v| in_range("camera.gain", v, 1e-6, 1e6, ""))
            .transpose()?;
        let gain_unity = (self.gain_unity)
            .map(|v| in_range("camera.gain_unity", v, 1e-6, 1e6, ""))
            .transpose()?;
        let white_balance = self.white_balance.unwrap_or(d.white_balance);
        if !white_balance.iter().all(|v| v.is_finite() && *v > 0.0) {
            return Err(invalid(
                "camera.white_balance",
                white_balance,
                "must be three positive numbers [r, g, b]",
            ));
        }
        let scale = in_range(
            "camera.scale",
            self.scale.unwrap_or(d.scale),
            1e-12,
            1e12,
            "",
        )?;
        let bracket_exposures_s = self.bracket_exposures_s.clone().unwrap_or_default();
        if let Some(bad) = bracket_exposures_s
            .iter()
            .find(|v| !(v.is_finite() && **v > 0.0))
        {
            return Err(invalid(
                "camera.bracket_exposures_s",
                bad,
                "every exposure must be a finite positive number of seconds",
            ));
        }
        if bracket_exposures_s.len() == 1 {
            return Err(invalid(
                "camera.bracket_exposures_s",
                &bracket_exposures_s,
                "needs at least 2 exposures (or none to turn bracketing off)",
            ));
        }
        let merge_limits = MergeLimits {
            dark: self.dark.unwrap_or(f64::from(d.merge_limits.dark)) as f32,
            saturated: self
                .saturated
                .unwrap_or(f64::from(d.merge_limits.saturated)) as f32,
        };
        merge_limits.check().map_err(|m| {
            // The key the file set (the other has its default), or both.
            let key = match (self.dark, self.saturated) {
                (Some(_), None) => "camera.dark",
                (None, Some(_)) => "camera.saturated",
                _ => "camera.dark and camera.saturated",
            };
            invalid(key, [merge_limits.dark, merge_limits.saturated], m)
        })?;
        let timeout = seconds(
            "camera.timeout_s",
            self.timeout_s,
            d.timeout,
            CAMERA_SECONDS,
        )?;
        let r = RetryPolicy::default();
        let retry = RetryPolicy {
            initial_backoff: seconds(
                "camera.retry_initial_s",
                self.retry_initial_s,
                r.initial_backoff,
                CAMERA_SECONDS,
            )?,
            max_backoff: seconds(
                "camera.retry_max_s",
                self.retry_max_s,
                r.max_backoff,
                CAMERA_SECONDS,
            )?,
            max_attempts: None,
        };
        if retry.initial_backoff > retry.max_backoff {
            return Err(invalid(
                "camera.retry_initial_s",
                retry.initial_backoff.as_secs_f64(),
                format!(
                    "must not exceed camera.retry_max_s ({} s)",
                    retry.max_backoff.as_secs_f64()
                ),
            ));
        }
        let device = self.device.clone().unwrap_or(d.device);
        if device.trim().is_empty() || device.contains('\0') {
            return Err(invalid(
                "camera.device",
                &device,
                "must be a device path or a camera name",
            ));
        }
        Ok(CameraSettings {
            device,
            formats,
            width,
            height,
            fps,
            yuv_matrix,
            response,
            exposure_s,
            gain,
            gain_unity,
            white_balance,
            scale,
            bracket_exposures_s,
            settle_frames: integer_in(
                "camera.settle_frames",
                self.settle_frames,
                d.settle_frames,
                0..=MAX_SETTLE_FRAMES,
                " (frames dropped after each exposure change)",
            )?,
            merge_limits,
            timeout,
            retry,
            projection,
            convert_threads: integer_in(
                "camera.convert_threads",
                self.convert_threads,
                d.convert_threads,
                1..=64,
                " (threads that decode and linearise each frame)",
            )?,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const SHIPPED: &str = include_str!("../../config/envlight.toml");

    #[test]
    fn shipped_camera_section_is_the_default_and_names_every_key() {
        let raw = crate::config::RawConfig::parse(SHIPPED, Path::new("envlight.toml")).unwrap();
        assert_eq!(
            raw.camera.validate(Projection::LatLong).unwrap(),
            CameraSettings::default()
        );
        let section = SHIPPED.split("\n[camera]\n").nth(1).unwrap_or_default();
        for key in [
            "device",
            "formats",
            "width",
            "height",
            "fps",
            "yuv_matrix",
            "response",
            "gamma",
            "log_a",
            "log_b",
            "curve",
            "exposure_s",
            "gain",
            "gain_unity",
            "white_balance",
            "scale",
            "bracket_exposures_s",
            "settle_frames",
            "dark",
            "saturated",
            "timeout_s",
            "retry_initial_s",
            "retry_max_s",
        ] {
            assert!(
                section
                    .lines()
                    .map(|l| l.trim_start_matches("# "))
                    .any(|l| l.starts_with(&format!("{key} = "))),
                "camera.{key} missing from config/envlight.toml"
            );
        }
    }
}
