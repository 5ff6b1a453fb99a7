//! Live capture from a V4L2 camera ([`V4l2Source`]) and device listing ([`list_devices`]).
//!
//! Opening a camera:
//! 1. the device is `/dev/videoN` (a path) or a name matched case-insensitively against the
//!    names of the `/dev/video*` nodes (`/sys/class/video4linux/videoN/name`);
//! 2. format negotiation: the first format of the preference list that the device enumerates is
//!    requested at the configured size (`VIDIOC_S_FMT`); the driver's answer (size, stride) is
//!    used as it comes, and a driver that substitutes another pixel format is rejected;
//!    With `yuv_matrix = "auto"`, the Y'CbCr formats use the matrix V4L2 implies for the colorspace the
//!    driver reports ([`yuv_matrix_for`]: BT.709 for Rec. 709, BT.2020 for Rec. 2020, BT.601 for sRGB/SMPTE 170M/JPEG,
//!    which covers most UVC webcams), and the frame-size rule only if it reports none;
//! 3. the frame rate is requested (`VIDIOC_S_PARM`); exposure is set to manual with the
//!    configured time when the config gives one (`V4L2_CID_EXPOSURE_AUTO` = manual,
//!    `V4L2_CID_EXPOSURE_ABSOLUTE` in 100 µs units);
//! 4. memory-mapped streaming with 4 buffers and a dequeue timeout
//!    ([`super::v4l2_stream::MmapStream`], envlight's own: it never panics when the device
//!    goes away).
//!
//! A node that captures only through the multi-planar API ([`CaptureApi::MultiPlanar`]: SoC
//! camera pipelines) takes the same steps through [`super::v4l2_mplane`], which hands each
//! frame on in the one-buffer layout, so everything after the dequeue is shared.
//!
//! Every frame: dequeue → the buffer checked and kept ([`FrameConverter::keep`]) → radiance
//! ([`FrameConverter::radiance`]: decoding and the response's [`super::response::Linearizer`])
//! with the exposure time read back from the camera's exposure control (so auto exposure is
//! folded in),
//! the gain (from the config, or the gain control divided by `gain_unity`), white balance and
//! scale → [`HdrFrame`] with the configured projection. The frame's time is the driver's
//! timestamp (`v4l2_buffer.timestamp`, CLOCK_MONOTONIC on current drivers) relative to the
//! first frame. With `convert_threads` > 1, decoding and linearisation convert bands of rows in
//! parallel: the capture thread and `convert_threads` − 1 helpers of the source's own
//! (`envlight-convert-N`; at most the machine's cores in all; src/parallel.rs), so no other
//! stage's rayon work can delay a frame; with 1 the capture thread converts alone. The result
//! is the same to the bit either way.
//!
//! With bracketing, each frame is a bracket set: for every configured exposure the control is
//! set, `settle_frames` frames are dropped (drivers apply controls a frame or two late), one
//! frame is kept; the set is merged by [`bracket::merge_brackets`].
//!
//! Single bad frames (flagged corrupt by the driver, empty, or not decodable, as a damaged MJPEG
//! frame) are skipped with a warning; [`MAX_BAD_FRAMES`] in a row are an error.
//!
//! Errors (EIO after an unplug, ENODEV, dequeue timeouts) are returned as [`CaptureError::Io`]
//! naming the device; [`super::resilient::ResilientSource`] reopens. The `v4l` crate unwraps on
//! some malformed driver answers; those calls run under `catch_unwind` and become errors.

use super::bracket::{self, Bracket, MergeLimits};
use super::convert::{Calibration, FrameConverter, StreamFormat};
use super::pixel_format::{self, PixelFormat, YuvMatrix};
use super::response::ResponseModel;
use super::v4l2_controls::{self, ControlDesc};
use super::v4l2_mplane;
use super::v4l2_stream::{kernel_string, MmapStream};
use super::{CaptureError, FrameSource};
use crate::envmap::Projection;
use crate::frame::HdrFrame;
use std::fmt;
use std::io;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::{Path, PathBuf};
use std::time::Duration;
use v4l::video::Capture;

/// Consecutive corrupt or undecodable frames tolerated before the source reports an error.
pub const MAX_BAD_FRAMES: usize = 10;

/// `V4L2_CID_EXPOSURE_AUTO` (menu; 1 = manual).
pub const CID_EXPOSURE_AUTO: u32 = 0x009a_0901;
/// `V4L2_CID_EXPOSURE_ABSOLUTE` (100 µs units).
pub const CID_EXPOSURE_ABSOLUTE: u32 = 0x009a_0902;
/// `V4L2_CID_GAIN`.
pub const CID_GAIN: u32 = 0x0098_0913;

/// Everything needed to open and read a camera (validated `[camera]` config).
#[derive(Clone, Debug, PartialEq)]
pub struct CameraSettings {
    /// `/dev/videoN` or a device name.
    pub device: String,
    /// Pixel formats in order of preference.
    pub formats: Vec<PixelFormat>,
    pub width: u32,
    pub height: u32,
    pub fps: Option<f64>,
    pub yuv_matrix: YuvMatrix,
    pub response: ResponseModel,
    /// Manual exposure time in seconds; `None` = leave the camera's exposure as it is and read
    /// it back every frame.
    pub exposure_s: Option<f64>,
    /// Linear gain; `None` = read `V4L2_CID_GAIN` / `gain_unity` if `gain_unity` is set, else 1.
    pub gain: Option<f64>,
    /// Gain-control value that means unity gain.
    pub gain_unity: Option<f64>,
    pub white_balance: [f64; 3],
    pub scale: f64,
    /// Exposure times of a bracket set (seconds); empty = no bracketing.
    pub bracket_exposures_s: Vec<f64>,
    /// Frames dropped after each exposure change.
    pub settle_frames: u32,
    pub merge_limits: MergeLimits,
    /// Dequeue timeout.
    pub timeout: Duration,
    /// Reconnection after device loss.
    pub retry: super::resilient::RetryPolicy,
    /// How pixels map to directions.
    pub projection: Projection,
    /// Threads that decode and linearise each frame, the capture thread included (bands of
    /// rows in parallel; 1 = the capture thread converts alone; at most the machine's cores).
    pub convert_threads: usize,
}

/// Default [`CameraSettings::convert_threads`].
pub const DEFAULT_CONVERT_THREADS: usize = 2;

impl Default for CameraSettings {
    fn default() -> Self {
        Self {
            device: "/dev/video0".into(),
            formats: pixel_format::DEFAULT_PREFERENCE.to_vec(),
            width: 1280,
            height: 960,
            fps: None,
            yuv_matrix: YuvMatrix::Auto,
            response: ResponseModel::Srgb,
            exposure_s: None,
            gain: None,
            gain_unity: None,
            white_balance: [1.0; 3],
            scale: 1.0,
            bracket_exposures_s: Vec::new(),
            settle_frames: 2,
            merge_limits: MergeLimits::default(),
            timeout: Duration::from_secs(2),
            retry: super::resilient::RetryPolicy::default(),
            projection: Projection::default(),
            convert_threads: DEFAULT_CONVERT_THREADS,
        }
    }
}

fn io_err(path: &Path, source: io::Error) -> CaptureError {
    CaptureError::Io {
        path: path.to_path_buf(),
        source,
    }
}

fn guarded<T>(
    path: &Path,
    what: &str,
    f: impl FnOnce() -> io::Result<T>,
) -> Result<T, CaptureError> {
    match catch_unwind(AssertUnwindSafe(f)) {
        Ok(r) => r.map_err(|e| io_err(path, io::Error::new(e.kind(), format!("{what}: {e}")))),
        Err(_) => Err(CaptureError::Format {
            path: path.to_path_buf(),
            message: format!("{what}: the driver's answer could not be parsed"),
        }),
    }
}

/// What `VIDIOC_QUERYCAP` says about a node.
struct NodeCaps {
    driver: String,
    card: String,
    bus: String,
    /// The node's own capabilities (`device_caps`; the device's where the driver gives no
    /// per-node ones).
    capabilities: v4l::capability::Flags,
}

/// VIDIOC_QUERYCAP, with the names read lossily ([`kernel_string`]: the `v4l` crate's
/// `query_caps` unwrapped a name cut in the middle of a character into a panic, so such a
/// camera could not be opened). A file that does not know the ioctl (ENOTTY: `/dev/null`, a regular file)
/// is no V4L2 device and never will be: that is a settings error, which the device-loss
/// wrapper does not retry, where other errors may be a camera that comes back.
fn query_caps(path: &Path, device: &v4l::Device) -> Result<NodeCaps, CaptureError> {
    /// `V4L2_CAP_DEVICE_CAPS`: `device_caps` is filled in.
    const DEVICE_CAPS: u32 = 0x8000_0000;
    // SAFETY: all-zero is a valid v4l2_capability (bytes and integers).
    let mut caps: v4l::v4l_sys::v4l2_capability = unsafe { std::mem::zeroed() };
    // SAFETY: VIDIOC_QUERYCAP writes a v4l2_capability.
    let answer = unsafe {
        super::v4l2_stream::ioctl(
            &device.handle(),
            v4l::v4l2::vidioc::VIDIOC_QUERYCAP,
            &mut caps,
        )
    };
    match answer {
        Ok(()) => Ok(NodeCaps {
            driver: kernel_string(&caps.driver),
            card: kernel_string(&caps.card),
            bus: kernel_string(&caps.bus_info),
            capabilities: v4l::capability::Flags::from(if caps.capabilities & DEVICE_CAPS != 0 {
                caps.device_caps
            } else {
                caps.capabilities
            }),
        }),
        Err(e) if e.raw_os_error() == Some(libc::ENOTTY) => {
            Err(CaptureError::InvalidSettings(format!(
                "{} is not a V4L2 device (it does not answer VIDIOC_QUERYCAP); cameras are \
                 /dev/videoN (`envlight devices` lists them)",
                path.display()
            )))
        }
        Err(e) => Err(io_err(
            path,
            super::v4l2_stream::named("VIDIOC_QUERYCAP", e),
        )),
    }
}

/// Which of V4L2's two video capture APIs a node streams through.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CaptureApi {
    /// `V4L2_BUF_TYPE_VIDEO_CAPTURE`: a frame is one buffer (UVC webcams, most USB cameras).
    SinglePlanar,
    /// `V4L2_BUF_TYPE_VIDEO_CAPTURE_MPLANE`: a frame is a buffer of planes (SoC camera
    /// pipelines; [`super::v4l2_mplane`]).
    MultiPlanar,
}

impl CaptureApi {
    /// Its buffer type: `V4L2_BUF_TYPE_VIDEO_CAPTURE` or `_CAPTURE_MPLANE`.
    pub fn buffer_type(self) -> u32 {
        match self {
            CaptureApi::SinglePlanar => super::v4l2_stream::CAPTURE,
            CaptureApi::MultiPlanar => super::v4l2_stream::CAPTURE_MPLANE,
        }
    }

    /// The pixel format a fourcc the node enumerates stands for (on a multi-planar node the
    /// separate-plane codes, such as `NM12`, stand for their one-buffer twins).
    pub fn pixel_format(self, code: [u8; 4]) -> Option<PixelFormat> {
        match self {
            CaptureApi::SinglePlanar => PixelFormat::from_fourcc(code),
            CaptureApi::MultiPlanar => v4l2_mplane::pixel_format(code),
        }
    }
}

/// How a node whose capabilities (`device_caps`) are `caps` captures video, or why it cannot:
/// single-planar where it offers that (also alongside the multi-planar API), multi-planar
/// where that is all it offers. A driver that reports no per-node capabilities (very old ones)
/// is given the benefit of the doubt (single-planar).
fn capture_api(caps: v4l::capability::Flags) -> Result<CaptureApi, &'static str> {
    use v4l::capability::Flags;
    if caps.is_empty() || caps.contains(Flags::VIDEO_CAPTURE) {
        Ok(CaptureApi::SinglePlanar)
    } else if caps.contains(Flags::VIDEO_CAPTURE_MPLANE) {
        Ok(CaptureApi::MultiPlanar)
    } else {
        Err("is not a video capture node (a UVC camera's second node carries its metadata)")
    }
}

/// The `/dev/video*` nodes, by number (`video2` before `video10`).
pub fn device_nodes() -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir("/dev")
        .map(|d| {
            d.filter_map(Result::ok)
                .filter(|e| e.file_name().to_string_lossy().starts_with("video"))
                .map(|e| e.path())
                .collect()
        })
        .unwrap_or_default();
    sort_nodes(&mut v);
    v
}

/// Sorts `/dev/videoN` paths by N (names without a number last, by name).
fn sort_nodes(nodes: &mut [PathBuf]) {
    let number = |p: &PathBuf| -> Option<u64> {
        p.file_name()?.to_str()?.strip_prefix("video")?.parse().ok()
    };
    nodes.sort_by(|a, b| {
        let (na, nb) = (number(a), number(b));
        (na.is_none(), na, a).cmp(&(nb.is_none(), nb, b))
    });
}

/// Whether the node at `path` can be captured from ([`capture_api`]); `false` where
/// it cannot be opened or queried.
fn is_capture_node(path: &Path) -> bool {
    v4l::Device::with_path(path).is_ok_and(|device| {
        query_caps(path, &device).is_ok_and(|caps| capture_api(caps.capabilities).is_ok())
    })
}

/// The sysfs name of a `/dev/videoN` node (read lossily: the kernel cuts it at 32 bytes, which
/// may split a character of a name that is not ASCII).
fn node_name(path: &Path) -> Option<String> {
    let file = path.file_name()?.to_str()?;
    let bytes = std::fs::read(format!("/sys/class/video4linux/{file}/name")).ok()?;
    Some(String::from_utf8_lossy(&bytes).trim().to_string())
}

/// Resolves a device spec (a path, or a name matched case-insensitively) to a node path.
pub fn resolve_device(spec: &str) -> Result<PathBuf, CaptureError> {
    let path = Path::new(spec);
    if spec.starts_with('/') || path.exists() {
        return Ok(path.to_path_buf());
    }
    let nodes = device_nodes();
    let want = spec.to_lowercase();
    let named: Vec<(PathBuf, String)> = nodes
        .iter()
        .filter_map(|p| node_name(p).map(|n| (p.clone(), n)))
        .collect();
    // A camera's nodes share its name (a UVC camera's second node carries metadata): the first
    // matching node that captures video, else the first match (whose error then says why).
    let matching: Vec<&PathBuf> = named
        .iter()
        .filter(|(_, n)| n.to_lowercase().contains(&want))
        .map(|(p, _)| p)
        .collect();
    matching
        .iter()
        .find(|p| is_capture_node(p))
        .or(matching.first())
        .map(|p| (*p).clone())
        .ok_or_else(|| {
            let have: Vec<String> = named
                .iter()
                .map(|(p, n)| format!("{} ({n})", p.display()))
                .collect();
            CaptureError::InvalidSettings(format!(
                "no camera named {spec:?}; found: {}",
                if have.is_empty() {
                    "none".to_string()
                } else {
                    have.join(", ")
                }
            ))
        })
}

/// Picks the first preferred format the device offers, with the code the device offers it
/// under (the first such code).
pub fn choose_format(
    preference: &[PixelFormat],
    offered: &[[u8; 4]],
    api: CaptureApi,
) -> Option<(PixelFormat, [u8; 4])> {
    preference.iter().find_map(|&f| {
        offered
            .iter()
            .find(|&&o| api.pixel_format(o) == Some(f))
            .map(|&o| (f, o))
    })
}

/// What the driver set: the format and its geometry.
struct Negotiated {
    width: u32,
    height: u32,
    /// Bytes between rows of the buffers the stream hands on.
    stride: usize,
    colorspace: v4l::format::Colorspace,
    /// Bytes per line of each plane the driver fills (one on a single-planar node).
    plane_strides: Vec<usize>,
}

/// A streaming V4L2 camera (see the module docs).
pub struct V4l2Source {
    path: PathBuf,
    settings: CameraSettings,
    format: PixelFormat,
    width: u32,
    height: u32,
    // The stream borrows nothing from the device (it holds its own handle); it is declared
    // before the device so it is dropped (streaming stopped, buffers unmapped) first.
    stream: MmapStream,
    device: v4l::Device,
    has_exposure: bool,
    has_exposure_auto: bool,
    has_gain: bool,
    /// The node's controls, for reading back exposure and gain.
    controls: Vec<ControlDesc>,
    first_timestamp: Option<f64>,
    seq: u64,
    card: String,
    /// The last grabbed frame and its conversion to radiance, on the capture thread and the
    /// helpers of `camera.convert_threads` (src/capture/convert.rs).
    converter: FrameConverter,
}

impl V4l2Source {
    /// Opens and configures the camera and starts streaming.
    pub fn open(settings: &CameraSettings) -> Result<Self, CaptureError> {
        let path = resolve_device(&settings.device)?;
        let p = path.as_path();
        let device = v4l::Device::with_path(p).map_err(|e| {
            // A directory (or a path through a file) is no camera and never will be: a
            // settings error, not retried as a camera that may come back.
            if matches!(e.raw_os_error(), Some(libc::EISDIR | libc::ENOTDIR)) {
                CaptureError::InvalidSettings(format!(
                    "{} is not a V4L2 device ({e}); cameras are /dev/videoN (`envlight \
                     devices` lists them)",
                    p.display()
                ))
            } else {
                io_err(p, e)
            }
        })?;
        let caps = query_caps(p, &device)?;
        let api = capture_api(caps.capabilities).map_err(|problem| {
            CaptureError::InvalidSettings(format!(
                "{} ({}) {problem}; `envlight devices` lists the nodes and what they offer",
                p.display(),
                caps.card
            ))
        })?;
        let offered: Vec<[u8; 4]> = offered_formats(&device, Ok(api))
            .map_err(|e| io_err(p, e))?
            .into_iter()
            .map(|(code, _)| code)
            .collect();
        let (format, code) = choose_format(&settings.formats, &offered, api).ok_or_else(|| {
            let names: Vec<String> = offered
                .iter()
                .map(|c| String::from_utf8_lossy(c).trim_end().to_string())
                .collect();
            CaptureError::InvalidSettings(format!(
                "{}: none of the configured formats is offered; the camera has {}",
                p.display(),
                names.join(", ")
            ))
        })?;
        let negotiated = Self::set_format(p, &device, api, format, code, settings)?;
        let yuv_matrix = match settings.yuv_matrix {
            YuvMatrix::Auto => yuv_matrix_for(negotiated.colorspace),
            m => m,
        };
        if let Some(fps) = settings.fps {
            if let Err(e) = v4l2_mplane::set_frame_rate(&device.handle(), api, fps) {
                tracing::warn!("{}: {e} (keeping the driver's frame rate)", p.display());
            }
        }
        let controls = v4l2_controls::query_controls(&device.handle()).unwrap_or_else(|e| {
            tracing::warn!("{}: {e}; the camera's controls are not used", p.display());
            Vec::new()
        });
        let has = |id: u32| controls.iter().any(|c| c.id == id);
        let (has_exposure, has_gain) = (has(CID_EXPOSURE_ABSOLUTE), has(CID_GAIN));
        let has_exposure_auto = has(CID_EXPOSURE_AUTO);
        if let Some(t) = settings.exposure_s {
            if has_exposure_auto {
                set_control(&device, p, CID_EXPOSURE_AUTO, 1)?;
            }
            if has_exposure {
                set_control(&device, p, CID_EXPOSURE_ABSOLUTE, exposure_units(t))?;
            } else {
                tracing::warn!(
                    "{}: no exposure control; using exposure_s = {t} as given",
                    p.display()
                );
            }
        }
        if !settings.bracket_exposures_s.is_empty() && !has_exposure {
            return Err(CaptureError::InvalidSettings(format!(
                "{}: bracketing needs an exposure control (V4L2_CID_EXPOSURE_ABSOLUTE)",
                p.display()
            )));
        }
        let size = (negotiated.width, negotiated.height);
        let strides = negotiated.plane_strides.clone();
        let mut stream = MmapStream::new(device.handle(), api, format, size, strides, 4)
            .map_err(|e| io_err(p, e))?;
        stream.set_timeout(settings.timeout);
        let Negotiated {
            width,
            height,
            stride,
            ..
        } = negotiated;
        tracing::info!(
            "{} ({}): {format}{} {width}x{height} stride {stride}",
            p.display(),
            caps.card,
            match (api, negotiated.plane_strides.len()) {
                (_, planes @ 2..) => {
                    format!(" in {planes} planes ({})", String::from_utf8_lossy(&code))
                }
                (CaptureApi::MultiPlanar, _) => " (multi-planar API)".to_string(),
                (CaptureApi::SinglePlanar, _) => String::new(),
            }
        );
        let convert_pool =
            crate::parallel::helper_pool(settings.convert_threads, "envlight-convert").map_err(
                |e| CaptureError::Io {
                    path: path.clone(),
                    source: io::Error::other(format!("starting the conversion threads: {e}")),
                },
            )?;
        let stream_format = StreamFormat {
            format,
            width,
            height,
            stride,
        };
        let calibration = Calibration {
            response: settings.response.clone(),
            yuv_matrix,
            white_balance: settings.white_balance,
            scale: settings.scale,
        };
        let merges_brackets = !settings.bracket_exposures_s.is_empty();
        Ok(Self {
            converter: FrameConverter::new(
                stream_format,
                calibration,
                merges_brackets,
                convert_pool,
            ),
            path,
            settings: CameraSettings {
                yuv_matrix,
                ..settings.clone()
            },
            format,
            width,
            height,
            stream,
            device,
            has_exposure,
            has_exposure_auto,
            has_gain,
            controls,
            first_timestamp: None,
            seq: 0,
            card: caps.card,
        })
    }

    /// Sets `format`, offered as `code`, at the configured size through the node's API; a
    /// driver that substitutes another pixel format is an error.
    fn set_format(
        p: &Path,
        device: &v4l::Device,
        api: CaptureApi,
        format: PixelFormat,
        code: [u8; 4],
        settings: &CameraSettings,
    ) -> Result<Negotiated, CaptureError> {
        let (chosen, negotiated) = match api {
            CaptureApi::SinglePlanar => {
                let mut fmt = guarded(p, "VIDIOC_G_FMT", || device.format())?;
                fmt.width = settings.width;
                fmt.height = settings.height;
                fmt.fourcc = v4l::FourCC::new(&code);
                let fmt = guarded(p, "VIDIOC_S_FMT", || device.set_format(&fmt))?;
                let negotiated = Negotiated {
                    width: fmt.width,
                    height: fmt.height,
                    stride: fmt.stride as usize,
                    colorspace: fmt.colorspace,
                    plane_strides: vec![fmt.stride as usize],
                };
                (fmt.fourcc.repr, negotiated)
            }
            CaptureApi::MultiPlanar => {
                let fmt = v4l2_mplane::set_format(
                    &device.handle(),
                    code,
                    settings.width,
                    settings.height,
                )
                .map_err(|e| io_err(p, e))?;
                let negotiated = Negotiated {
                    width: fmt.width,
                    height: fmt.height,
                    stride: fmt.stride(format),
                    colorspace: v4l::format::Colorspace::try_from(fmt.colorspace)
                        .unwrap_or(v4l::format::Colorspace::Default),
                    plane_strides: fmt.strides,
                };
                (fmt.fourcc, negotiated)
            }
        };
        if api.pixel_format(chosen) != Some(format) {
            return Err(CaptureError::InvalidSettings(format!(
                "{}: asked for {format}, the driver chose {}",
                p.display(),
                String::from_utf8_lossy(&chosen)
            )));
        }
        Ok(negotiated)
    }

    /// The negotiated format and size.
    pub fn format(&self) -> (PixelFormat, u32, u32) {
        (self.format, self.width, self.height)
    }

    fn control(&self, id: u32) -> Option<i64> {
        let control = self.controls.iter().find(|c| c.id == id)?;
        v4l2_controls::read_control(&self.device.handle(), control)
            .ok()
            .flatten()
    }

    /// Exposure (s) and gain in force, for the radiometry.
    fn exposure_and_gain(&self) -> (f64, f64) {
        let t = if self.has_exposure {
            self.control(CID_EXPOSURE_ABSOLUTE)
                .map(|v| v as f64 * 1e-4)
                .filter(|t| *t > 0.0)
                .or(self.settings.exposure_s)
        } else {
            self.settings.exposure_s
        };
        let gain = match (self.settings.gain, self.settings.gain_unity) {
            (Some(g), _) => g,
            (None, Some(unity)) if self.has_gain => self
                .control(CID_GAIN)
                .map(|v| v as f64 / unity)
                .filter(|g| *g > 0.0)
                .unwrap_or(1.0),
            _ => 1.0,
        };
        (t.unwrap_or(1.0), gain)
    }

    /// Dequeues buffers until one decodes to code values; returns its driver timestamp (s).
    /// Buffers the driver flags as corrupt (`V4L2_BUF_FLAG_ERROR`), empty ones and ones that do
    /// not decode (a damaged MJPEG frame) are skipped with a warning; only
    /// [`MAX_BAD_FRAMES`] of them in a row are an error (and so a reconnect).
    fn grab(&mut self) -> Result<f64, CaptureError> {
        let p = self.path.clone();
        let mut last_problem = String::new();
        for _ in 0..MAX_BAD_FRAMES {
            let (data, meta) = self.stream.next_frame().map_err(|e| io_err(&p, e))?;
            let problem = match data {
                // Checked and kept while the driver lends the buffer; converted once the
                // exposure is known.
                Ok(bytes) => match self.converter.keep(bytes) {
                    Ok(()) => {
                        return Ok(meta.timestamp.sec as f64 + meta.timestamp.usec as f64 * 1e-6)
                    }
                    Err(e) => e.to_string(),
                },
                Err(problem) => problem,
            };
            tracing::warn!(
                "{}: frame {} skipped: {problem}",
                p.display(),
                meta.sequence
            );
            last_problem = problem;
        }
        Err(CaptureError::Format {
            path: p,
            message: format!("{MAX_BAD_FRAMES} bad frames in a row; the last: {last_problem}"),
        })
    }

    /// Captures one frame per exposure time (seconds), dropping `settle_frames` frames after
    /// each change; returns the code images with the exposure and gain read back, and the
    /// driver timestamp of the first. Needs an exposure control.
    pub fn capture_brackets(
        &mut self,
        exposures_s: &[f64],
    ) -> Result<(Vec<Bracket>, f64), CaptureError> {
        if !self.has_exposure {
            return Err(CaptureError::InvalidSettings(format!(
                "{}: bracketing needs an exposure control (V4L2_CID_EXPOSURE_ABSOLUTE)",
                self.path.display()
            )));
        }
        if self.has_exposure_auto {
            // manual exposure, or the camera would override the bracket times
            set_control(&self.device, &self.path, CID_EXPOSURE_AUTO, 1)?;
        }
        let mut brackets = Vec::new();
        let mut first_ts = None;
        for &t in exposures_s {
            set_control(
                &self.device,
                &self.path,
                CID_EXPOSURE_ABSOLUTE,
                exposure_units(t),
            )?;
            for _ in 0..self.settings.settle_frames {
                self.grab()?;
            }
            let ts = self.grab()?;
            first_ts.get_or_insert(ts);
            let (t_read, g) = self.exposure_and_gain();
            let image = self
                .converter
                .codes()
                .map_err(|e| CaptureError::Format {
                    path: self.path.clone(),
                    message: e.to_string(),
                })?
                .clone();
            brackets.push(Bracket {
                image,
                exposure_s: t_read,
                gain: g,
            });
        }
        Ok((brackets, first_ts.unwrap_or(0.0)))
    }
}

/// The Y'CbCr matrix V4L2 implies for a colorspace (`V4L2_MAP_YCBCR_ENC_DEFAULT`): BT.709 for
/// Rec. 709 and DCI-P3, BT.601 for SMPTE 170M, NTSC, EBU, sRGB, JPEG and opRGB; `Auto` (by frame
/// size) when the driver says nothing useful.
pub fn yuv_matrix_for(colorspace: v4l::format::Colorspace) -> YuvMatrix {
    use v4l::format::Colorspace as C;
    match colorspace {
        C::Rec709 | C::DCIP3 => YuvMatrix::Bt709,
        C::Rec2020 => YuvMatrix::Bt2020,
        C::SMPTE170M | C::NTSC | C::EBUTech3212 | C::SRGB | C::JPEG | C::OPRGB => YuvMatrix::Bt601,
        _ => YuvMatrix::Auto,
    }
}

/// Exposure time in V4L2's 100 µs units (at least 1).
pub fn exposure_units(seconds: f64) -> i64 {
    (seconds * 1e4).round().clamp(1.0, i32::MAX as f64) as i64
}

fn set_control(device: &v4l::Device, path: &Path, id: u32, value: i64) -> Result<(), CaptureError> {
    guarded(path, &format!("VIDIOC_S_CTRL {id:#x}"), || {
        device.set_control(v4l::control::Control {
            id,
            value: v4l::control::Value::Integer(value),
        })
    })
}

impl FrameSource for V4l2Source {
    fn next_frame(&mut self) -> Result<Option<HdrFrame>, CaptureError> {
        let code_max = self.format.code_max();
        let (pixels, timestamp) = if self.settings.bracket_exposures_s.is_empty() {
            let ts = self.grab()?;
            let (t, g) = self.exposure_and_gain();
            // The tables are rebuilt only when the exposure or gain changes (auto exposure);
            // every pixel of a recycled buffer is overwritten.
            let pixels = self
                .converter
                .radiance(t, g)
                .map_err(|e| CaptureError::Format {
                    path: self.path.clone(),
                    message: e.to_string(),
                })?;
            (pixels, ts)
        } else {
            let exposures = self.settings.bracket_exposures_s.clone();
            let (brackets, first_ts) = self.capture_brackets(&exposures)?;
            let merged = bracket::merge_brackets(
                &brackets,
                &self.settings.response,
                code_max,
                &self.converter.radiometry(1.0, 1.0),
                self.settings.merge_limits,
            )
            .map_err(|e| CaptureError::Format {
                path: self.path.clone(),
                message: e.to_string(),
            })?;
            (merged, first_ts)
        };
        let first = *self.first_timestamp.get_or_insert(timestamp);
        let Some(mut frame) =
            HdrFrame::new(self.width, self.height, pixels, self.settings.projection)
        else {
            return Err(CaptureError::Format {
                path: self.path.clone(),
                message: "frame has no pixels".into(),
            });
        };
        frame.time = (timestamp - first).max(0.0);
        frame.seq = self.seq;
        self.seq += 1;
        let bad = frame.sanitize();
        if bad > 0 {
            tracing::warn!(
                "{}: {bad} pixels with invalid values set to 0",
                self.path.display()
            );
        }
        Ok(Some(frame))
    }

    fn recycle(&mut self, pixels: Vec<[f32; 3]>) {
        self.converter.recycle(pixels);
    }

    fn describe(&self) -> String {
        format!(
            "V4L2 camera {} ({}), {} {}x{}, response {}{}",
            self.path.display(),
            self.card,
            self.format,
            self.width,
            self.height,
            self.settings.response.name(),
            if self.settings.bracket_exposures_s.is_empty() {
                String::new()
            } else {
                format!(", {} brackets", self.settings.bracket_exposures_s.len())
            }
        )
    }
}

/// One format a device offers.
#[derive(Clone, Debug, PartialEq)]
pub struct FormatInfo {
    pub fourcc: String,
    pub description: String,
    /// Whether envlight converts it.
    pub supported: bool,
    /// Frame sizes, each with its frame rates (as text: discrete or stepwise).
    pub sizes: Vec<(String, Vec<String>)>,
}

/// One control of a device.
#[derive(Clone, Debug, PartialEq)]
pub struct ControlInfo {
    pub id: u32,
    pub name: String,
    pub minimum: i64,
    pub maximum: i64,
    pub step: u64,
    pub default: i64,
    pub value: Option<i64>,
}

/// What `envlight devices` prints for one camera.
#[derive(Clone, Debug, PartialEq)]
pub struct DeviceInfo {
    pub path: PathBuf,
    pub card: String,
    pub driver: String,
    pub bus: String,
    /// Whether it captures through the multi-planar API only.
    pub multi_planar: bool,
    /// Why envlight cannot capture from this node, if it cannot (a metadata node).
    pub unusable: Option<String>,
    pub formats: Vec<FormatInfo>,
    pub controls: Vec<ControlInfo>,
}

/// The formats a node offers through its API (a node that is no capture node is asked as a
/// single-planar one), with their descriptions.
fn offered_formats(
    device: &v4l::Device,
    api: Result<CaptureApi, &str>,
) -> io::Result<Vec<([u8; 4], String)>> {
    v4l2_mplane::enum_formats(&device.handle(), api.unwrap_or(CaptureApi::SinglePlanar))
}

/// Queries one device.
pub fn device_info(path: &Path) -> Result<DeviceInfo, CaptureError> {
    let device = v4l::Device::with_path(path).map_err(|e| io_err(path, e))?;
    let caps = query_caps(path, &device)?;
    let api = capture_api(caps.capabilities);
    let offered = offered_formats(&device, api).map_err(|e| io_err(path, e))?;
    let mut formats = Vec::new();
    for (code, description) in offered {
        let fourcc = v4l::FourCC::new(&code);
        let mut sizes = Vec::new();
        let sz = guarded(path, "VIDIOC_ENUM_FRAMESIZES", || {
            device.enum_framesizes(fourcc)
        })
        .unwrap_or_default();
        for s in sz {
            match s.size {
                v4l::framesize::FrameSizeEnum::Discrete(ds) => {
                    let rates = guarded(path, "VIDIOC_ENUM_FRAMEINTERVALS", || {
                        device.enum_frameintervals(fourcc, ds.width, ds.height)
                    })
                    .unwrap_or_default()
                    .iter()
                    .map(|i| match &i.interval {
                        v4l::frameinterval::FrameIntervalEnum::Discrete(f) if f.numerator > 0 => {
                            format!(
                                "{:.2} fps",
                                f64::from(f.denominator) / f64::from(f.numerator)
                            )
                        }
                        other => other.to_string(),
                    })
                    .collect();
                    sizes.push((format!("{}x{}", ds.width, ds.height), rates));
                }
                other => sizes.push((other.to_string(), Vec::new())),
            }
        }
        formats.push(FormatInfo {
            fourcc: String::from_utf8_lossy(&code).trim_end().to_string(),
            description,
            supported: api
                .unwrap_or(CaptureApi::SinglePlanar)
                .pixel_format(code)
                .is_some(),
            sizes,
        });
    }
    let handle = device.handle();
    let controls = v4l2_controls::query_controls(&handle)
        .unwrap_or_default()
        .into_iter()
        .map(|c| {
            let value = v4l2_controls::read_control(&handle, &c).ok().flatten();
            ControlInfo {
                id: c.id,
                name: c.name,
                minimum: c.minimum,
                maximum: c.maximum,
                step: c.step,
                default: c.default,
                value,
            }
        })
        .collect();
    Ok(DeviceInfo {
        path: path.to_path_buf(),
        card: caps.card,
        driver: caps.driver,
        bus: caps.bus,
        multi_planar: api == Ok(CaptureApi::MultiPlanar),
        unusable: api.err().map(str::to_string),
        formats,
        controls,
    })
}

/// Every `/dev/video*` node with its description (or why it could not be queried).
pub fn list_devices() -> Vec<(PathBuf, Result<DeviceInfo, CaptureError>)> {
    device_nodes()
        .into_iter()
        .map(|p| {
            let info = device_info(&p);
            (p, info)
        })
        .collect()
}

impl fmt::Display for DeviceInfo {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "{}: {} (driver {}, bus {}{})",
            self.path.display(),
            self.card,
            self.driver,
            self.bus,
            if self.multi_planar {
                ", multi-planar"
            } else {
                ""
            }
        )?;
        if let Some(problem) = &self.unusable {
            writeln!(f, "  not usable: this node {problem}")?;
        } else if self.formats.is_empty() {
            writeln!(f, "  no capture formats (metadata or output node)")?;
        }
        for fm in &self.formats {
            writeln!(
                f,
                "  format {} ({}){}",
                fm.fourcc,
                fm.description,
                if fm.supported {
                    ""
                } else {
                    " [not supported by envlight]"
                }
            )?;
            for (size, rates) in &fm.sizes {
                writeln!(f, "    {size}: {}", rates.join(", "))?;
            }
        }
        if !self.controls.is_empty() {
            writeln!(f, "  controls:")?;
        }
        for c in &self.controls {
            let value = c.value.map_or("?".to_string(), |v| v.to_string());
            writeln!(
                f,
                "    {:#010x} {}: {value} (min {}, max {}, step {}, default {})",
                c.id, c.name, c.minimum, c.maximum, c.step, c.default
            )?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn format_choice_follows_the_preference() {
        let single = |pref: &[PixelFormat], offered: &[[u8; 4]]| {
            choose_format(pref, offered, CaptureApi::SinglePlanar).map(|(f, _)| f)
        };
        let offered = [*b"YUYV", *b"MJPG", *b"Y16 "];
        let pref = pixel_format::DEFAULT_PREFERENCE;
        assert_eq!(
            single(&pref, &offered),
            Some(PixelFormat::Grey { bits: 16 })
        );
        assert_eq!(
            single(
                &[
                    PixelFormat::Mjpeg,
                    PixelFormat::PackedYuv(pixel_format::PackedYuv::Yuyv)
                ],
                &offered
            ),
            Some(PixelFormat::Mjpeg)
        );
        assert_eq!(single(&[PixelFormat::Rgb24], &offered), None);
        // 4:2:0 comes after YUYV and before MJPEG; a fourcc envlight does not convert is
        // never chosen.
        let nv12 = PixelFormat::PlanarYuv(pixel_format::PlanarYuv::Nv12);
        assert_eq!(single(&pref, &[*b"MJPG", *b"NV12", *b"YU12"]), Some(nv12));
        assert_eq!(
            single(&pref, &[*b"NV12", *b"YUYV"]),
            Some(PixelFormat::PackedYuv(pixel_format::PackedYuv::Yuyv))
        );
        assert_eq!(single(&pref, &[*b"Y444"]), None);
        // Y'CbCr of 10 bits and more comes before 8-bit Y'CbCr and RGB.
        assert_eq!(
            single(&pref, &[*b"YUYV", *b"RGB3", *b"P010", *b"MJPG"]),
            Some(PixelFormat::PlanarYuv(pixel_format::PlanarYuv::P010))
        );
        assert_eq!(
            single(&pref, &[*b"P010", *b"Y210"]),
            Some(PixelFormat::PackedYuv(pixel_format::PackedYuv::Y210))
        );
        // Packed 4:4:4 comes after packed 4:2:2 and before planar 4:4:4.
        assert_eq!(
            single(&pref, &[*b"NV24", *b"VUYA", *b"UYVY"]),
            Some(PixelFormat::PackedYuv(pixel_format::PackedYuv::Uyvy))
        );
        assert_eq!(
            single(&pref, &[*b"NV24", *b"VUYA"]),
            Some(PixelFormat::PackedYuv(pixel_format::PackedYuv::Vuya32))
        );
        // 4:2:2 (a chroma row per row) comes before 4:2:0, and 4:4:4 (a pair per pixel)
        // before both.
        assert_eq!(
            single(&pref, &[*b"NV12", *b"NV16"]),
            Some(PixelFormat::PlanarYuv(pixel_format::PlanarYuv::Nv16))
        );
        assert_eq!(
            single(&pref, &[*b"NV12", *b"NV16", *b"NV42"]),
            Some(PixelFormat::PlanarYuv(pixel_format::PlanarYuv::Nv42))
        );
        // A multi-planar node offers NV12 in two planes as NM12: chosen for NV12, and asked
        // for under its own code. A single-planar node knows no NM12.
        let mplane = [*b"Y444", *b"NM12"];
        assert_eq!(
            choose_format(&pref, &mplane, CaptureApi::MultiPlanar),
            Some((nv12, *b"NM12"))
        );
        assert_eq!(single(&pref, &mplane), None);
        // The three-plane layouts without a one-buffer code (YVU 4:2:2, 4:4:4) are their own.
        assert_eq!(
            choose_format(&pref, &[*b"NM12", *b"YM61"], CaptureApi::MultiPlanar),
            Some((
                PixelFormat::PlanarYuv(pixel_format::PlanarYuv::Yvu422p),
                *b"YM61"
            ))
        );
        assert_eq!(
            choose_format(&pref, &[*b"YM61", *b"YM42"], CaptureApi::MultiPlanar),
            Some((
                PixelFormat::PlanarYuv(pixel_format::PlanarYuv::Yvu444p),
                *b"YM42"
            ))
        );
    }

    #[test]
    fn nodes_sort_by_number() {
        let mut nodes: Vec<PathBuf> = ["/dev/video10", "/dev/video2", "/dev/videox", "/dev/video0"]
            .iter()
            .map(PathBuf::from)
            .collect();
        sort_nodes(&mut nodes);
        assert_eq!(
            nodes,
            ["/dev/video0", "/dev/video2", "/dev/video10", "/dev/videox"].map(PathBuf::from)
        );
    }

    #[test]
    fn video_capture_nodes_are_opened_through_their_api() {
        use v4l::capability::Flags;
        let streaming = Flags::STREAMING;
        let single = Ok(CaptureApi::SinglePlanar);
        assert_eq!(capture_api(Flags::VIDEO_CAPTURE | streaming), single);
        assert_eq!(capture_api(Flags::empty()), single);
        let both = Flags::VIDEO_CAPTURE | Flags::VIDEO_CAPTURE_MPLANE | streaming;
        assert_eq!(capture_api(both), single);
        assert_eq!(
            capture_api(Flags::VIDEO_CAPTURE_MPLANE | streaming),
            Ok(CaptureApi::MultiPlanar)
        );
        let metadata = capture_api(Flags::META_CAPTURE | streaming).unwrap_err();
        assert!(metadata.contains("not a video capture node"), "{metadata}");
        // `envlight devices` says why such a node is of no use.
        let info = DeviceInfo {
            path: PathBuf::from("/dev/video1"),
            card: "Cam".into(),
            driver: "uvcvideo".into(),
            bus: "usb-1".into(),
            multi_planar: false,
            unusable: Some(metadata.to_string()),
            formats: Vec::new(),
            controls: Vec::new(),
        };
        let text = info.to_string();
        assert!(
            text.contains("not usable: this node is not a video capture node"),
            "{text}"
        );
        assert!(!text.contains("no capture formats"), "{text}");
        // A multi-planar node says so, and its separate-plane formats are usable.
        let isp = DeviceInfo {
            path: PathBuf::from("/dev/video3"),
            card: "rkisp_mainpath".into(),
            driver: "rkisp1".into(),
            bus: "platform:rkisp1".into(),
            multi_planar: true,
            unusable: None,
            formats: vec![FormatInfo {
                fourcc: "NM12".into(),
                description: "Y/UV 4:2:0 (N-C)".into(),
                supported: CaptureApi::MultiPlanar.pixel_format(*b"NM12").is_some(),
                sizes: Vec::new(),
            }],
            controls: Vec::new(),
        };
        let text = isp.to_string();
        assert!(
            text.contains("bus platform:rkisp1, multi-planar)"),
            "{text}"
        );
        assert!(text.contains("format NM12 (Y/UV 4:2:0 (N-C))\n"), "{text}");
    }

    #[test]
    fn yuv_matrix_follows_the_driver_colorspace() {
        use v4l::format::Colorspace as C;
        assert_eq!(yuv_matrix_for(C::Rec709), YuvMatrix::Bt709);
        assert_eq!(yuv_matrix_for(C::Rec2020), YuvMatrix::Bt2020);
        assert_eq!(yuv_matrix_for(C::SRGB), YuvMatrix::Bt601);
        assert_eq!(yuv_matrix_for(C::SMPTE170M), YuvMatrix::Bt601);
        assert_eq!(yuv_matrix_for(C::Default), YuvMatrix::Auto);
    }

    #[test]
    fn exposure_units_are_100_microseconds() {
        assert_eq!(exposure_units(0.01), 100);
        assert_eq!(exposure_units(1e-6), 1);
        assert_eq!(exposure_units(f64::INFINITY), i32::MAX as i64);
    }

    #[test]
    fn unknown_device_names_are_errors_naming_the_spec() {
        let e = resolve_device("no-such-camera-xyz").unwrap_err();
        assert!(e.to_string().contains("no-such-camera-xyz"), "{e}");
        let e = V4l2Source::open(&CameraSettings {
            device: "/nonexistent/video9".into(),
            ..Default::default()
        })
        .err()
        .map(|e| e.to_string())
        .unwrap_or_default();
        assert!(e.contains("/nonexistent/video9"), "{e}");
    }

    /// A file that is not a V4L2 device (`/dev/null`, a regular file, a directory, a path
    /// through a file) is a settings error, which the device-loss wrapper does not retry, not
    /// an I/O error to wait out.
    #[test]
    fn a_file_that_is_no_v4l2_device_is_a_settings_error() {
        let file = tempfile::NamedTempFile::new().unwrap();
        let dir = tempfile::tempdir().unwrap();
        let through_file = file.path().join("video0");
        for path in [
            Path::new("/dev/null"),
            file.path(),
            dir.path(),
            through_file.as_path(),
        ] {
            let e = V4l2Source::open(&CameraSettings {
                device: path.display().to_string(),
                ..Default::default()
            })
            .err()
            .unwrap();
            assert!(matches!(e, CaptureError::InvalidSettings(_)), "{e}");
            assert!(e.to_string().contains("not a V4L2 device"), "{e}");
        }
    }
}
