//! Frame sources: everything that produces [`HdrFrame`]s for the capture thread.
//!
//! - [`sequence::SequenceSource`]: a recorded `.exr` / `.hdr` sequence (directory or glob),
//!   ordered by the number in the file names, paced or as fast as possible, optionally looped.
//! - [`sky::SkySource`]: the built-in analytic sky with a moving sun and passing clouds; the
//!   default when no input is given.

pub mod image_file;
pub mod sequence;
pub mod sky;

use crate::frame::HdrFrame;
use std::path::PathBuf;

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
}

/// Opens the frame source a validated [`Config`](crate::config::Config) describes: the
/// built-in sky (its `[source]` fps and frame count applied) or a recorded sequence, limited to
/// `source.frames` frames and with a fisheye calibration checked against the frames' size.
pub fn open(config: &crate::config::Config) -> Result<Box<dyn FrameSource>, CaptureError> {
    use crate::config::{SourceKind, DEFAULT_SKY_FRAMES};
    let src = &config.source;
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

    fn describe(&self) -> String {
        match self.remaining {
            Some(n) => format!("{} (at most {n} more frames)", self.inner.describe()),
            None => self.inner.describe(),
        }
    }
}
