//! envlight: a real-time mixed-reality lighting daemon.
//!
//! HDR environment-map frames (a fisheye camera, a recorded EXR/HDR sequence or the built-in sky)
//! are decomposed into temporally stable directional lights by inverse-transform sampling
//! (Havran et al. 2005). See `DESIGN.md` in the shared folder for the whole pipeline.
//!
//! The CPU math (`envmap`, `decompose`, `yardstick`) has no async, no GPU and no I/O; `capture`
//! reads frames; `stream` holds the wire format for light lists; the binary (`main.rs` and `cli/`) is only
//! the command line.

// Per-channel loops `for c in 0..3` over rgb triples read better than zipped iterators.
#![allow(clippy::needless_range_loop)]

pub mod asg;
pub mod asg_stage;
pub mod capture;
pub mod config;
pub mod daemon;
pub mod decompose;
pub mod envmap;
pub mod frame;
pub mod frame_feed;
pub mod light;
pub mod metrics;
pub mod parallel;
pub mod pipeline;
pub mod publication;
pub mod read_file;
pub mod record;
pub mod render;
pub mod set_filter;
pub mod sh;
pub mod sh_stage;
pub mod slow_stage;
pub mod stream;
pub mod wavelet;
pub mod wavelet_stage;
pub mod yardstick;

pub use frame::HdrFrame;
pub use light::{Light, LightFrame};
