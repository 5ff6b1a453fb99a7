//! The fisheye calibration flags that `decompose` and the `wavelet` subcommands share
//! (`--fisheye-model`, `--center`, `--radius`, `--fov`, `--rotation`), and the checking of a
//! configuration built from flags: a bad value is a usage error that names the flag it came
//! from, not the config key.

use super::{parse_pair, usage_error};
use anyhow::{anyhow, Result};
use clap::{Args, ValueEnum};
use envlight::config::{Config, ConfigError, RawConfig, RawSource};

#[derive(Clone, Copy, Debug, ValueEnum)]
pub(crate) enum FisheyeModelArg {
    /// r = f·θ
    Equidistant,
    /// r = 2f·sin(θ/2)
    Equisolid,
    /// r = 2f·tan(θ/2)
    Stereographic,
    /// r = f·sin θ
    Orthographic,
}

/// The calibration of `--projection fisheye` INPUT files.
#[derive(Args, Debug, Clone)]
pub(crate) struct FisheyeFlags {
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

    /// Fisheye rotation about the zenith in degrees: at 0 image up looks along −Z and image
    /// right along −X; positive turns the directions counter-clockwise about +Y seen from
    /// above (clockwise on the image). [default: 0]
    #[arg(long, value_name = "DEG")]
    rotation: Option<f64>,
}

impl FisheyeFlags {
    /// Whether any of the flags was given.
    pub(crate) fn given(&self) -> bool {
        self.fisheye_model.is_some()
            || self.center.is_some()
            || self.radius.is_some()
            || self.fov.is_some()
            || self.rotation.is_some()
    }

    /// Writes the flags given into `src.fisheye`, noting for each the config key and the flag
    /// (`note(key, flag)`). They need `src.projection` to be "fisheye": a usage error otherwise.
    pub(crate) fn apply(
        &self,
        src: &mut RawSource,
        mut note: impl FnMut(&'static str, &'static str),
    ) -> Result<()> {
        if self.given() && src.projection.as_deref() != Some("fisheye") {
            usage_error!(
                "--fisheye-model, --center, --radius, --fov and --rotation need --projection fisheye"
            );
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
        Ok(())
    }
}

/// Validates `raw`, into which flags were written (`flags`: the config key each flag set, and
/// the flag): an invalid value from a flag is a usage error naming the flag; one from the
/// config file (`config_name`) says so.
pub(crate) fn validate_with_flags(
    raw: &RawConfig,
    flags: &[(&'static str, &'static str)],
    config_name: &str,
) -> Result<Config> {
    raw.validate().map_err(|e| match &e {
        ConfigError::Invalid {
            key,
            value,
            message,
        } => match flags.iter().find(|(k, _)| k == key) {
            // A switch (--split) has no value to show.
            Some((_, flag)) if value == "true" || value == "false" => {
                crate::cli::usage(format!("invalid {flag}: {message}"))
            }
            Some((_, flag)) => crate::cli::usage(format!("invalid {flag} {value}: {message}")),
            None => anyhow!(e).context(format!("invalid setting in {config_name}")),
        },
        _ => anyhow!(e),
    })
}
