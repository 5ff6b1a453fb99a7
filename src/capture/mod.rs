//! Frame sources: everything that produces [`HdrFrame`]s for the capture thread.
//!
//! - [`sequence::SequenceSource`]: a recorded `.exr` / `.hdr` sequence (directory or glob),
//!   ordered by the number in the file names, paced or as fast as possible, optionally looped.
//! - [`sky::SkySource`]: the built-in analytic sky with a moving sun and passing clouds; the
//!   default when no input is given.

pub mod bracket;
pub mod convert;
pub mod image_file;
pub mod pixel_format;
pub mod resilient;
pub mod response;
pub mod sequence;
pub mod sky;
pub mod v4l2;
pub mod v4l2_controls;
pub mod v4l2_mplane;
pub mod v4l2_stream;

use crate::frame::HdrFrame;
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

/// Errors of frame sources. Every variant names the file or source it is about.
#[derive(Debug, thiserror::Error)]
pub enum CaptureError {
    #[error("{}: {source}", path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// The file exists but cannot be used: truncated, corrupt, unsupported layout.
    #[error("{}: {message}", path.display())]
    Format { path: PathBuf, message: String },
    #[error("{}: frame is {width}x{height} but the sequence started at {first_width}x{first_height}", path.display())]
    SizeMismatch {
        path: PathBuf,
        width: u32,
        height: u32,
        first_width: u32,
        first_height: u32,
    },
    #[error("no .exr or .hdr frames found in {0}")]
    NoFrames(String),
    #[error("invalid source settings: {0}")]
    InvalidSettings(String),
}

/// A producer of environment-map frames.
pub trait FrameSource: Send {
    /// The next frame, `Ok(None)` once a finite source is exhausted. A paced source blocks until
    /// the frame is due. Frames have sanitised pixels (no NaN, ±Inf or negative values).
    fn next_frame(&mut self) -> Result<Option<HdrFrame>, CaptureError>;

    /// A short human-readable description for logs.
    fn describe(&self) -> String;

    /// Shared health of a source that can lose its device (see [`resilient::ResilientSource`]);
    /// `None` for sources that cannot.
    fn health(&self) -> Option<Arc<SourceHealth>> {
        None
    }

    /// The pixel buffer of a frame this source made, handed back once its consumer is done
    /// with it (the pipeline does so when the decomposition was the frame's last use, and for
    /// frames it drops from a full queue). A source that fills a new buffer every frame may
    /// fill this one instead: its length is the frame's, its contents stale. The default
    /// drops it.
    fn recycle(&mut self, pixels: Vec<[f32; 3]>) {
        drop(pixels);
    }

    /// The files this source reads frames from (a recorded sequence's), so that a command can
    /// refuse to write its output over one of them; empty for sources that read no files.
    fn files(&self) -> &[std::path::PathBuf] {
        &[]
    }
}

/// Health of a live source, shared with the pipeline (stream and metrics) through an `Arc`.
#[derive(Debug, Default)]
pub struct SourceHealth {
    stale: AtomicBool,
    reconnect_attempts: AtomicU64,
    failures_total: AtomicU64,
    stop: AtomicBool,
    last_error: Mutex<String>,
}

impl SourceHealth {
    /// Whether the device is lost: the lights being served are the last ones before the loss.
    pub fn is_stale(&self) -> bool {
        self.stale.load(Ordering::Acquire)
    }

    /// Consecutive failed attempts since the last good frame (0 while healthy).
    pub fn reconnect_attempts(&self) -> u64 {
        self.reconnect_attempts.load(Ordering::Acquire)
    }

    /// Failures since the source was created.
    pub fn failures_total(&self) -> u64 {
        self.failures_total.load(Ordering::Acquire)
    }

    /// The text of the most recent error ("" if none yet).
    pub fn last_error(&self) -> String {
        self.last_error
            .lock()
            .map(|s| s.clone())
            .unwrap_or_else(|p| p.into_inner().clone())
    }

    /// Asks a retrying source to give up: its `next_frame` returns `Ok(None)` soon.
    pub fn request_stop(&self) {
        self.stop.store(true, Ordering::Release);
    }

    /// Whether [`Self::request_stop`] was called.
    pub fn stop_requested(&self) -> bool {
        self.stop.load(Ordering::Acquire)
    }

    /// Records a failure (marks stale).
    pub fn mark_failure(&self, error: &str) {
        match self.last_error.lock() {
            Ok(mut s) => *s = error.to_string(),
            Err(p) => *p.into_inner() = error.to_string(),
        }
        self.failures_total.fetch_add(1, Ordering::AcqRel);
        self.reconnect_attempts.fetch_add(1, Ordering::AcqRel);
        self.stale.store(true, Ordering::Release);
    }

    /// Records a good frame (clears stale and the attempt count; keeps the last error text).
    pub fn mark_ok(&self) {
        self.reconnect_attempts.store(0, Ordering::Release);
        self.stale.store(false, Ordering::Release);
    }
}

/// The slowest pace a paced source accepts: one frame every 10,000 s (2.8 hours), for time
/// lapses. Slower rates are almost certainly a mistake (a period typed for a rate), and frame
/// times beyond what a clock can hold would follow from absurd ones.
pub const MIN_FPS: f64 = 1e-4;

/// Checks a paced source's frame rate: finite and at least [`MIN_FPS`]. The error text says
/// what is expected (the caller names the setting).
pub fn check_fps(fps: f64) -> Result<(), String> {
    if fps.is_finite() && fps >= MIN_FPS {
        Ok(())
    } else {
        Err(format!(
            "must be a finite frame rate of at least {MIN_FPS} frames/s (one frame every {:.0} s), got {}",
            1.0 / MIN_FPS,
            crate::config::shown_number(fps)
        ))
    }
}

std::thread_local! {
    /// The calling thread's stop test for [`sleep_until`] ([`interrupt_sleeps_when`]).
    static SLEEP_STOP: std::cell::RefCell<Option<Box<dyn Fn() -> bool>>> =
        const { std::cell::RefCell::new(None) };
}

/// Makes every later wait of a paced source (`sleep_until`) on the calling thread end early
/// once `stop()` is true (checked every [`SLEEP_SLICE`]). The pipeline's capture thread sets
/// this to its shutdown flag, so a paced source waiting long for its next frame (a slow sky, a
/// replay's gap) does not hold up a shutdown.
pub fn interrupt_sleeps_when(stop: impl Fn() -> bool + 'static) {
    SLEEP_STOP.with(|slot| *slot.borrow_mut() = Some(Box::new(stop)));
}

/// The longest single sleep of `sleep_until` on a thread with a stop test.
pub const SLEEP_SLICE: std::time::Duration = std::time::Duration::from_millis(50);

/// Sleeps until `time_s` seconds after `start` (no sleep when that has passed), or until the
/// thread's stop test ([`interrupt_sleeps_when`]) is true. A time that no
/// [`Instant`](std::time::Instant) can hold — only reachable with a rate below [`MIN_FPS`] or
/// after centuries of frames — is treated as due now rather than panicking. Returns whether
/// the time came: `false` when the stop test ended the wait first, and the frame waited for
/// is then not to be delivered (it would carry a capture time still in the future).
#[must_use]
pub(crate) fn sleep_until(start: std::time::Instant, time_s: f64) -> bool {
    let due = std::time::Duration::try_from_secs_f64(time_s)
        .ok()
        .and_then(|offset| start.checked_add(offset));
    let Some(due) = due else {
        return true;
    };
    SLEEP_STOP.with(|slot| {
        let stop = slot.borrow();
        while let Some(wait) = due.checked_duration_since(std::time::Instant::now()) {
            match stop.as_ref() {
                None => std::thread::sleep(wait),
                Some(stop) if stop() => return false,
                Some(_) => std::thread::sleep(wait.min(SLEEP_SLICE)),
            }
        }
        true
    })
}

/// Opens the frame source a validated [`Config`](crate::config::Config) describes: the
/// built-in sky (its `[source]` fps and frame count applied) or a recorded sequence, limited to
/// `source.frames` frames and with a fisheye calibration checked against the frames' size.
pub fn open(config: &crate::config::Config) -> Result<Box<dyn FrameSource>, CaptureError> {
    use crate::config::{SourceKind, DEFAULT_SKY_FRAMES};
    let src = &config.source;
    if !src.ignored_fisheye.is_empty() {
        tracing::warn!(
            "{} set, but source.projection is \"{}\": the fisheye calibration is not used",
            src.ignored_fisheye.join(", "),
            src.projection.name()
        );
    }
    let inner: Box<dyn FrameSource> = match src.kind {
        SourceKind::Sky => {
            let frames = match src.frames {
                None => Some(DEFAULT_SKY_FRAMES),
                Some(0) => None,
                Some(n) => Some(n),
            };
            let options = sky::SkyOptions {
                fps: src.fps,
                frames,
                ..config.sky.clone()
            };
            Box::new(sky::SkySource::new(options)?)
        }
        SourceKind::Sequence => {
            let options = sequence::SequenceOptions {
                fps: src.fps,
                looped: src.looped,
                projection: src.projection,
            };
            Box::new(sequence::SequenceSource::new(&src.paths, options)?)
        }
        SourceKind::V4l2 => {
            // Device loss is retried with backoff; meanwhile the source reports itself stale.
            let settings = config.camera.clone();
            Box::new(resilient::ResilientSource::new(
                format!("camera {}", settings.device),
                settings.retry,
                move || Ok(Box::new(v4l2::V4l2Source::open(&settings)?) as Box<dyn FrameSource>),
            ))
        }
    };
    Ok(Box::new(Checked {
        inner,
        remaining: src.frames.filter(|&n| n > 0),
        checked_size: None,
    }))
}

/// A source limited to a number of frames, whose fisheye calibration is checked against the
/// size of its frames (once per size).
struct Checked {
    inner: Box<dyn FrameSource>,
    remaining: Option<u64>,
    checked_size: Option<(u32, u32)>,
}

impl FrameSource for Checked {
    fn files(&self) -> &[std::path::PathBuf] {
        self.inner.files()
    }

    fn next_frame(&mut self) -> Result<Option<HdrFrame>, CaptureError> {
        if self.remaining == Some(0) {
            return Ok(None);
        }
        let Some(frame) = self.inner.next_frame()? else {
            return Ok(None);
        };
        if let Some(n) = &mut self.remaining {
            *n -= 1;
        }
        if self.checked_size != Some((frame.width, frame.height)) {
            if let crate::envmap::Projection::Fisheye(cal) = frame.projection {
                cal.validate(frame.width, frame.height).map_err(|e| {
                    CaptureError::InvalidSettings(format!(
                        "fisheye calibration (--center, --radius, --fov, --rotation or \
                         [source.fisheye]) does not fit the {}x{} frames: {e}",
                        frame.width, frame.height
                    ))
                })?;
            }
            self.checked_size = Some((frame.width, frame.height));
        }
        Ok(Some(frame))
    }

    fn health(&self) -> Option<Arc<SourceHealth>> {
        self.inner.health()
    }

    fn describe(&self) -> String {
        match self.remaining {
            Some(n) => format!("{} (at most {n} more frames)", self.inner.describe()),
            None => self.inner.describe(),
        }
    }
}
