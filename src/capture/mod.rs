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
