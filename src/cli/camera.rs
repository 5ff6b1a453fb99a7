//! The camera subcommands of the command line: `devices`, `calibrate-response`,
//! `calibrate-fisheye`, and opening the camera for `decompose`. Only argument handling and
//! printing; the work is in `envlight::capture` and `envlight::envmap::fisheye_detect`.

use anyhow::{anyhow, Context, Result};
use clap::{Args, ValueEnum};
use envlight::capture::bracket::{read_bracket_image, recover_response, Bracket, SolveSettings};
use envlight::capture::image_file::{read_hdr_image, ImageFormat};
use envlight::capture::v4l2::{
    device_info, list_devices, resolve_device, CameraSettings, V4l2Source,
};
use envlight::capture::FrameSource;
use envlight::envmap::fisheye_detect::detect_image_circle;
use envlight::envmap::{FisheyeCalibration, FisheyeModel};
use std::path::{Path, PathBuf};

#[derive(Args, Debug)]
pub struct CalibrateResponseArgs {
    /// Bracketed 8- or 16-bit PNG images of a static scene (one per exposure).
    #[arg(value_name = "IMAGE", required_unless_present = "device")]
    images: Vec<PathBuf>,

    /// Exposure time of each image (or of each bracket captured with --device), seconds.
    #[arg(
        long,
        value_name = "T,T,…",
        value_delimiter = ',',
        num_args = 1,
        required = true
    )]
    exposures: Vec<f64>,

    /// Capture the brackets from this V4L2 camera instead of reading IMAGEs.
    #[arg(long, value_name = "DEVICE", conflicts_with = "images")]
    device: Option<String>,

    /// With --device: the config file whose [camera] table opens the camera (formats, size,
    /// rate; the device is --device's). [default: the built-in [camera] defaults]
    #[arg(long, value_name = "FILE")]
    config: Option<PathBuf>,

    /// Where to write the curve file.
    #[arg(long, short = 'o', value_name = "FILE")]
    out: PathBuf,

    /// Code levels of the curve (256 for 8-bit data), 4..=4096. [default: 256]
    #[arg(long, value_name = "N")]
    levels: Option<usize>,

    /// Smoothness weight λ, in (0, 1e6]. [default: 100]
    #[arg(long, value_name = "L")]
    lambda: Option<f64>,

    /// Number of sample pixels, 2..=5000. [default: 300]
    #[arg(long, value_name = "N")]
    samples: Option<usize>,
}

#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum ModelArg {
    Equidistant,
    Equisolid,
    Stereographic,
    Orthographic,
}

#[derive(Args, Debug)]
pub struct CalibrateFisheyeArgs {
    /// A frame of the fisheye camera (.exr, .hdr or .png), the surround dark.
    #[arg(value_name = "IMAGE", required_unless_present = "device")]
    image: Option<PathBuf>,

    /// Capture the frame from this V4L2 camera instead of reading IMAGE (its fifth frame, so
    /// that the camera's auto exposure has settled).
    #[arg(long, value_name = "DEVICE", conflicts_with = "image")]
    device: Option<String>,

    /// With --device: the config file whose [camera] table opens the camera (formats, size,
    /// response, exposure; the device is --device's). [default: the built-in [camera] defaults]
    #[arg(long, value_name = "FILE")]
    config: Option<PathBuf>,

    /// Lens model to write (not detectable from the circle). [default: equidistant]
    #[arg(long, value_enum)]
    model: Option<ModelArg>,

    /// Field of view to write, degrees (not detectable from the circle). [default: 180]
    #[arg(long, value_name = "DEG")]
    fov: Option<f64>,
}

#[derive(Args, Debug)]
pub struct DevicesArgs {
    /// Only these cameras: paths (/dev/video3) or names matched case-insensitively, as
    /// `[camera] device` takes them. Without any, every /dev/video* node is listed.
    #[arg(value_name = "DEVICE")]
    devices: Vec<String>,
}

pub fn devices(args: &DevicesArgs) -> Result<()> {
    if args.devices.is_empty() {
        let devices = list_devices();
        if devices.is_empty() {
            super::print_to_stderr(format_args!("no /dev/video* devices found"));
        }
        let mut text = String::new();
        for (path, info) in devices {
            match info {
                Ok(info) => text += &info.to_string(),
                Err(e) => text += &format!("{}: cannot query: {e}\n", path.display()),
            }
        }
        return crate::cli::output::print(&text);
    }
    // Named cameras: each one listed if it can be, and the exit status says whether all could.
    let mut text = String::new();
    let mut failed = Vec::new();
    for spec in &args.devices {
        match resolve_device(spec).and_then(|path| device_info(&path)) {
            Ok(info) => text += &info.to_string(),
            // The error names the path, or the name that matched nothing.
            Err(e) => failed.push(e.to_string()),
        }
    }
    crate::cli::output::print(&text)?;
    if failed.is_empty() {
        Ok(())
    } else {
        Err(anyhow!("cannot query {}", failed.join("; ")))
    }
}

pub fn calibrate_response(args: &CalibrateResponseArgs) -> Result<()> {
    refuse_config_without_device(args.config.is_some(), args.device.is_some())?;
    // Checked before the brackets are read and solved: --out replaced an input image.
    crate::cli::output::check_output_path(&args.out, "--out")?;
    crate::cli::output::InputFiles::new(&args.images).refuse(&args.out, "--out")?;
    // Checked before the images are read (each option's name is its field's).
    let d = SolveSettings::default();
    let settings = SolveSettings {
        levels: args.levels.unwrap_or(d.levels),
        lambda: args.lambda.unwrap_or(d.lambda),
        samples: args.samples.unwrap_or(d.samples),
    };
    settings.check().map_err(|p| {
        crate::cli::usage(format!(
            "invalid --{} {}: {}",
            p.field, p.value, p.requirement
        ))
    })?;
    let brackets: Vec<Bracket> = if let Some(dev) = &args.device {
        let settings = camera_settings(dev, args.config.as_deref())?;
        let mut cam = V4l2Source::open(&settings).context("cannot open the camera")?;
        cam.capture_brackets(&args.exposures)
            .context("cannot capture the brackets")?
            .0
    } else {
        if args.images.len() != args.exposures.len() {
            crate::cli::usage_error!(
                "{} images but {} --exposures: give one exposure time per image",
                args.images.len(),
                args.exposures.len()
            );
        }
        args.images
            .iter()
            .zip(&args.exposures)
            .map(|(p, &t)| {
                Ok(Bracket {
                    image: read_bracket_image(p)?,
                    exposure_s: t,
                    gain: 1.0,
                })
            })
            .collect::<Result<_>>()?
    };
    let curve = recover_response(&brackets, settings).map_err(|e| {
        // The error numbers the brackets; name their files.
        let files: Vec<String> = (args.images.iter().enumerate())
            .map(|(i, p)| format!("{} = {}", i + 1, p.display()))
            .collect();
        if files.is_empty() {
            anyhow!(e)
        } else {
            anyhow!("{e} (brackets {})", files.join(", "))
        }
    })?;
    let comment = format!(
        "recovered by envlight calibrate-response from {} brackets (exposures {:?} s), \
         levels {}, lambda {}, samples {}",
        brackets.len(),
        args.exposures,
        settings.levels,
        settings.lambda,
        settings.samples
    );
    curve.write(&args.out, &comment)?;
    super::print_to_stderr(format_args!(
        "wrote {} ({} levels); use it with [camera] response = \"curve\", curve = {:?}",
        args.out.display(),
        settings.levels,
        args.out.display().to_string()
    ));
    Ok(())
}

fn read_any_image(path: &Path) -> Result<(u32, u32, Vec<[f32; 3]>)> {
    if ImageFormat::from_path(path).is_some() {
        let img = read_hdr_image(path)?;
        Ok((img.width, img.height, img.pixels))
    } else {
        let img = read_bracket_image(path)?;
        Ok((img.width, img.height, img.pixels))
    }
}

/// The frame of a camera (counting from 1) that `calibrate-fisheye --device` measures: the
/// first frames of a camera are often still dark or bright while its auto exposure settles.
const FISHEYE_SETTLE_FRAMES: usize = 5;

/// The `[camera]` settings of `config` (the built-in defaults without one) with `device`.
fn camera_settings(device: &str, config: Option<&Path>) -> Result<CameraSettings> {
    let camera = match config {
        Some(path) => {
            envlight::daemon::read_config(Some(path), None)
                .map_err(|e| super::daemon::naming_the_file(e, Some(path)))?
                .camera
        }
        None => CameraSettings::default(),
    };
    Ok(CameraSettings {
        device: device.to_string(),
        ..camera
    })
}

/// `--config` opens the camera of `--device`; with IMAGE files it would be read by nobody
/// (clap's `requires` does not hold once the IMAGEs, which conflict with --device, are given).
fn refuse_config_without_device(config: bool, device: bool) -> Result<()> {
    if config && !device {
        crate::cli::usage_error!(
            "--config FILE opens the camera of --device (its [camera] table); IMAGE files need \
             no config"
        );
    }
    Ok(())
}

pub fn calibrate_fisheye(args: &CalibrateFisheyeArgs) -> Result<()> {
    refuse_config_without_device(args.config.is_some(), args.device.is_some())?;
    let (source, (w, h, pixels)) = match (&args.device, &args.image) {
        (Some(device), _) => {
            let settings = camera_settings(device, args.config.as_deref())?;
            let mut camera = V4l2Source::open(&settings).context("cannot open the camera")?;
            let mut next_frame = || -> Result<_> {
                camera
                    .next_frame()
                    .context("cannot capture a frame")?
                    .ok_or_else(|| anyhow!("{device}: the camera gave no frame"))
            };
            for _ in 1..FISHEYE_SETTLE_FRAMES {
                next_frame()?;
            }
            let frame = next_frame()?;
            let name = format!("{} ({})", device, camera.describe());
            (name, (frame.width, frame.height, frame.pixels))
        }
        (None, Some(image)) => (image.display().to_string(), read_any_image(image)?),
        (None, None) => crate::cli::usage_error!("give a fisheye IMAGE or --device"),
    };
    let circle = detect_image_circle(&pixels, w, h)
        .with_context(|| format!("{source}: no image circle found"))?;
    let (model, model_kind) = match args.model.unwrap_or(ModelArg::Equidistant) {
        ModelArg::Equidistant => ("equidistant", FisheyeModel::Equidistant),
        ModelArg::Equisolid => ("equisolid", FisheyeModel::Equisolid),
        ModelArg::Stereographic => ("stereographic", FisheyeModel::Stereographic),
        ModelArg::Orthographic => ("orthographic", FisheyeModel::Orthographic),
    };
    let fov = args.fov.unwrap_or(180.0);
    // The lines printed must pass check-config: the same checks as a config's [source.fisheye].
    let calibration = FisheyeCalibration {
        model: model_kind,
        center: Some(circle.center),
        radius: Some(circle.radius),
        fov_deg: fov,
        rotation_deg: 0.0,
    };
    calibration
        .validate(w, h)
        .map_err(|e| crate::cli::usage(format!("invalid --fov or --model: {e}")))?;
    let text = format!(
        "# envlight calibrate-fisheye {}: {w}x{h}, {} edge points, rms residual {:.3} px\n\
         # model and fov_deg are as given (--model, --fov); rotation_deg is not detected:\n\
         # set it so that a known direction (the sun, a landmark) lands where it should.\n\
         [source.fisheye]\n\
         model = \"{model}\"\n\
         center = [{:.3}, {:.3}]\n\
         radius = {:.3}\n\
         fov_deg = {fov:?}\n\
         rotation_deg = 0.0\n",
        source,
        circle.points,
        circle.rms_residual,
        circle.center[0],
        circle.center[1],
        circle.radius,
    );
    crate::cli::output::print(&text)
}
