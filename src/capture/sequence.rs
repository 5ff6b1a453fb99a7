//! Recorded EXR/HDR sequences as a frame source ([`SequenceSource`]).
//!
//! Inputs are files, directories (every `.exr`/`.hdr` file directly in them, not recursive) and
//! glob patterns (`frames/*.exr`, `take_[12]/*.hdr`). An entry of a directory or a glob with a
//! frame extension that is no readable regular file (a broken or looping link, a pipe) is an
//! error naming it. The frames found are put in natural order and deduplicated (by canonical
//! path; two names of one file, such as a link and its target, are one frame, at the place of
//! the first name in that order, with a warning naming both). Natural order: by the numbers in
//! the path, compared one after another as numbers — those of its folders, then those of the
//! file name (without extension) — so `frame_2.exr` comes before `frame_10.exr`, a timestamp
//! `12-30-58` before `12-31-00`, `t_0.5` before `t_1.0`, `f_1_v2` before `f_10_v2`, and the
//! frames of `take_1/` before those of `take_2/`. A `-` before a number is its sign after a
//! `.` or `_` or at the start of a name (`shot.-002`, a pre-roll frame, comes before
//! `shot.0000`), not between numbers (`2024-05-01`). A file whose numbers begin another's
//! comes first (`f_1` before `f_1_v2`); files without a number come after the numbered ones,
//! and ties are broken by file name and then full path.
//!
//! Each call of [`FrameSource::next_frame`] reads one file ([`read_hdr_image`]), checks it has
//! the first frame's size, sanitises its pixels ([`HdrFrame::sanitize`], one warning per frame
//! that needed it) and stamps it:
//! - `seq`: 0, 1, 2, … counting delivered frames, continuing across loops;
//! - `time`: the frame's nominal time `seq / fps`. Without an `fps` (as fast as possible) the
//!   time is `seq / NOMINAL_FPS` (30 fps): a recording replays with the same, deterministic
//!   timestamps however fast it is decoded, so time-based filters behave as in a paced replay.
//!
//! Paced mode (`fps` set) sleeps until frame `seq` is due at `start + seq / fps`, where `start`
//! is when the first frame was delivered; due times are computed from that one instant, so
//! sleeping error does not accumulate. A frame that is late is delivered at once (frames are
//! not skipped). Looped mode starts again at the first file forever; otherwise the source
//! returns `Ok(None)` after the last file (and on every call after that).
//!
//! A file that fails to read or has the wrong size returns its error; a caller that calls again
//! goes on with the following file (`seq` is not used up by the failed one). `envlight
//! decompose` does not: a bad frame is fatal there (README.md).

use super::image_file::{read_hdr_image, ImageFormat};
use super::{CaptureError, FrameSource};
use crate::envmap::Projection;
use crate::frame::HdrFrame;
use std::cmp::Ordering;
use std::collections::hash_map::{Entry, HashMap};
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Frame rate used for `HdrFrame::time` when a sequence is replayed as fast as possible.
pub const NOMINAL_FPS: f64 = 30.0;

/// How a [`SequenceSource`] replays its frames.
#[derive(Clone, Debug, Default)]
pub struct SequenceOptions {
    /// Frames per second to pace the replay at; `None` = as fast as possible.
    pub fps: Option<f64>,
    /// Start again at the first frame after the last one, forever.
    pub looped: bool,
    /// How the frames' pixels map to directions.
    pub projection: Projection,
}

/// A recorded sequence of `.exr` / `.hdr` frames. See the module docs.
#[derive(Debug)]
pub struct SequenceSource {
    paths: Vec<PathBuf>,
    options: SequenceOptions,
    /// Index into `paths` of the next file to read.
    next: usize,
    /// Sequence number of the next delivered frame.
    seq: u64,
    first_size: Option<(u32, u32)>,
    /// When the first frame was delivered (paced mode).
    start: Option<Instant>,
    finished: bool,
}

impl SequenceSource {
    /// Collects the frames named by `inputs` (files, directories, glob patterns).
    ///
    /// Errors: `InvalidSettings` for a bad fps or glob pattern, `Io` for a plain path that does
    /// not exist, `Format` for a named file with an unsupported extension, `NoFrames` if nothing
    /// was found.
    pub fn new(inputs: &[String], options: SequenceOptions) -> Result<Self, CaptureError> {
        if let Some(fps) = options.fps {
            super::check_fps(fps)
                .map_err(|message| CaptureError::InvalidSettings(format!("fps {message}")))?;
        }
        let paths = collect_frames(inputs)?;
        if paths.is_empty() {
            return Err(CaptureError::NoFrames(if inputs.is_empty() {
                "(no inputs given)".to_string()
            } else {
                inputs.join(", ")
            }));
        }
        Ok(Self {
            paths,
            options,
            next: 0,
            seq: 0,
            first_size: None,
            start: None,
            finished: false,
        })
    }

    /// Number of files in the sequence (one loop).
    pub fn frame_count(&self) -> usize {
        self.paths.len()
    }

    /// The files in replay order.
    pub fn paths(&self) -> &[PathBuf] {
        &self.paths
    }

    /// The replay options.
    pub fn options(&self) -> &SequenceOptions {
        &self.options
    }

    fn read_frame(&mut self, path: &Path) -> Result<HdrFrame, CaptureError> {
        let image = read_hdr_image(path)?;
        let (first_width, first_height) =
            *self.first_size.get_or_insert((image.width, image.height));
        if (image.width, image.height) != (first_width, first_height) {
            return Err(CaptureError::SizeMismatch {
                path: path.to_path_buf(),
                width: image.width,
                height: image.height,
                first_width,
                first_height,
            });
        }
        let mut frame = HdrFrame::new(
            image.width,
            image.height,
            image.pixels,
            self.options.projection,
        )
        .ok_or_else(|| CaptureError::Format {
            path: path.to_path_buf(),
            message: "decoded image has an inconsistent pixel count".to_string(),
        })?;
        let bad = frame.sanitize();
        if bad > 0 {
            tracing::warn!(
                file = %path.display(),
                pixels = bad,
                "replaced NaN, infinite or negative values by 0 (and clamped values above \
                 {:e} to it) in {bad} pixels of {}",
                crate::frame::MAX_RADIANCE,
                path.display()
            );
        }
        Ok(frame)
    }
}

impl FrameSource for SequenceSource {
    fn files(&self) -> &[PathBuf] {
        &self.paths
    }

    fn next_frame(&mut self) -> Result<Option<HdrFrame>, CaptureError> {
        if self.finished {
            return Ok(None);
        }
        if self.next >= self.paths.len() {
            if self.options.looped {
                self.next = 0;
            } else {
                self.finished = true;
                return Ok(None);
            }
        }
        let path = self.paths[self.next].clone();
        self.next += 1;
        let mut frame = self.read_frame(&path)?;

        let seq = self.seq;
        self.seq += 1;
        frame.seq = seq;
        let fps = self.options.fps.unwrap_or(NOMINAL_FPS);
        frame.time = seq as f64 / fps;
        if self.options.fps.is_some() {
            let start = *self.start.get_or_insert_with(Instant::now);
            if !super::sleep_until(start, frame.time) {
                return Ok(None);
            }
        }
        Ok(Some(frame))
    }

    fn describe(&self) -> String {
        let first = self.paths.first().map(|p| p.display().to_string());
        let pace = match self.options.fps {
            Some(fps) => format!("at {fps} fps"),
            None => "as fast as possible".to_string(),
        };
        format!(
            "sequence of {} {} from {}, {}{}, {}",
            self.paths.len(),
            if self.paths.len() == 1 {
                "frame"
            } else {
                "frames"
            },
            first.unwrap_or_default(),
            pace,
            if self.options.looped { ", looped" } else { "" },
            self.options.projection.name()
        )
    }
}

fn has_supported_extension(path: &Path) -> bool {
    ImageFormat::from_path(path).is_some()
}

/// A directory's or a glob's entry as a frame file: `None` for entries without a frame
/// extension and for directories; an error for one with a frame extension that cannot be read
/// as a file (a broken or looping link: it names a frame that would be silently missing).
fn frame_file(path: PathBuf) -> Result<Option<PathBuf>, CaptureError> {
    if !has_supported_extension(&path) {
        return Ok(None);
    }
    match std::fs::metadata(&path) {
        Ok(meta) if meta.is_file() => Ok(Some(path)),
        Ok(meta) if meta.is_dir() => Ok(None),
        Ok(_) => Err(CaptureError::Format {
            path,
            message: "not a regular file (a pipe, socket or device)".to_string(),
        }),
        Err(source) => Err(CaptureError::Io { path, source }),
    }
}

fn is_glob_pattern(input: &str) -> bool {
    input.contains(['*', '?', '['])
}

/// A glob pattern matches names as UTF-8 text, so frame files whose names are not UTF-8 are
/// left out by `dir/*.exr` although `dir` itself reads them: said in a warning, per directory
/// the pattern's directory part names, with the way to read them.
fn warn_of_names_a_pattern_cannot_match(pattern: &str) {
    let parent = match Path::new(pattern).parent() {
        Some(p) if p.as_os_str().is_empty() => Path::new("."),
        Some(p) => p,
        None => return,
    };
    let directories: Vec<PathBuf> = match parent.to_str() {
        Some(p) if is_glob_pattern(p) => glob::glob(p)
            .map(|paths| paths.flatten().filter(|d| d.is_dir()).collect())
            .unwrap_or_default(),
        _ => vec![parent.to_path_buf()],
    };
    for directory in directories {
        let Ok(entries) = std::fs::read_dir(&directory) else {
            continue;
        };
        let unmatched: Vec<PathBuf> = entries
            .flatten()
            .map(|e| e.path())
            .filter(|p| p.file_name().is_some_and(|n| n.to_str().is_none()))
            .filter(|p| has_supported_extension(p))
            .collect();
        if let Some(first) = unmatched.first() {
            tracing::warn!(
                "{pattern}: {} frame file(s) in {} have names that are not UTF-8, which a \
                 pattern cannot match (among them {}); give the directory to read them",
                unmatched.len(),
                directory.display(),
                first.display()
            );
        }
    }
}

/// Files named by `inputs`, deduplicated and in natural order.
fn collect_frames(inputs: &[String]) -> Result<Vec<PathBuf>, CaptureError> {
    let mut found: Vec<PathBuf> = Vec::new();
    let mut matched_nothing: Vec<&str> = Vec::new();
    for input in inputs {
        let before = found.len();
        let path = Path::new(input);
        match std::fs::metadata(path) {
            Ok(meta) if meta.is_dir() => {
                let io_err = |source| CaptureError::Io {
                    path: path.to_path_buf(),
                    source,
                };
                for entry in std::fs::read_dir(path).map_err(io_err)? {
                    let entry_path = entry.map_err(io_err)?.path();
                    if let Some(frame) = frame_file(entry_path)? {
                        found.push(frame);
                    }
                }
            }
            Ok(_) => {
                if !has_supported_extension(path) {
                    return Err(CaptureError::Format {
                        path: path.to_path_buf(),
                        message: "unsupported file type; supported extensions are .exr, .hdr"
                            .to_string(),
                    });
                }
                found.push(path.to_path_buf());
            }
            Err(_) if is_glob_pattern(input) => {
                let matches = glob::glob(input).map_err(|e| {
                    CaptureError::InvalidSettings(format!("bad glob pattern {input:?}: {e}"))
                })?;
                for entry in matches {
                    let entry_path = entry.map_err(|e| CaptureError::Io {
                        path: e.path().to_path_buf(),
                        source: e.into(),
                    })?;
                    if let Some(frame) = frame_file(entry_path)? {
                        found.push(frame);
                    }
                }
                warn_of_names_a_pattern_cannot_match(input);
            }
            Err(_) if input.starts_with("v4l2:") => {
                return Err(CaptureError::InvalidSettings(format!(
                    "{input}: a camera is INPUT v4l2:DEVICE only as the one INPUT of envlight \
                     decompose (or its --device); envlight run and record take it from the \
                     config (source.kind = \"v4l2\", camera.device)"
                )))
            }
            Err(source) => {
                return Err(CaptureError::Io {
                    path: path.to_path_buf(),
                    source,
                })
            }
        }
        if found.len() == before {
            matched_nothing.push(input);
        }
    }
    // With frames from other inputs, an input with none would be lost without a word.
    if !found.is_empty() {
        for input in matched_nothing {
            tracing::warn!("{input}: no .exr or .hdr frames (an empty directory or a pattern that matches none)");
        }
    }

    // In natural order first, so that of two names of one file the first in the sequence is
    // kept (the directory's listing order kept `f2` of links f1, f2, f3, f10 to one file).
    found.sort_by_cached_key(|path| frame_order_key(path));
    let mut seen = HashMap::new();
    let mut unique = Vec::with_capacity(found.len());
    let (mut repeated, mut first_repeated) = (0usize, None);
    for path in found {
        let key = std::fs::canonicalize(&path).unwrap_or_else(|_| path.clone());
        match seen.entry(key) {
            Entry::Vacant(entry) => {
                entry.insert(path.clone());
                unique.push(path);
            }
            Entry::Occupied(first) if *first.get() != path => tracing::warn!(
                "{} is the same file as {}: read once",
                path.display(),
                first.get().display()
            ),
            Entry::Occupied(_) => {
                repeated += 1;
                first_repeated.get_or_insert(path);
            }
        }
    }
    // Named twice (the same file twice, or a directory and a pattern that overlap): a frame
    // is read once, and the user hears of it, since `a.hdr a.hdr` might mean two frames.
    if let Some(first) = first_repeated {
        tracing::warn!(
            "{} named more than once (among them {}): each file is read once",
            if repeated == 1 {
                "1 frame file was".to_owned()
            } else {
                format!("{repeated} frame files were")
            },
            first.display()
        );
    }
    Ok(unique)
}

/// A number in a path: its sign and its ASCII digits without leading zeros ("" for zero).
#[derive(Clone, Debug, PartialEq, Eq)]
struct PathNumber {
    negative: bool,
    digits: String,
}

impl Ord for PathNumber {
    fn cmp(&self, other: &Self) -> Ordering {
        let magnitude =
            || (self.digits.len(), &self.digits).cmp(&(other.digits.len(), &other.digits));
        match (self.negative, other.negative) {
            (false, false) => magnitude(),
            (true, true) => magnitude().reverse(),
            (negative, _) => {
                if negative {
                    Ordering::Less
                } else {
                    Ordering::Greater
                }
            }
        }
    }
}

impl PartialOrd for PathNumber {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}

/// The runs of ASCII digits in `name`, as numbers (see the module docs for the sign). Found in
/// the bytes: a run may follow a character of several bytes (`é1`, `frame—2`, the U+FFFD of a
/// name that is not UTF-8), and digits are ASCII, so every run is a slice on character
/// boundaries. A zero, "-0" included, is not negative.
fn numbers_in(name: &str, out: &mut Vec<PathNumber>) {
    let bytes = name.as_bytes();
    let mut i = 0;
    while i < bytes.len() {
        if !bytes[i].is_ascii_digit() {
            i += 1;
            continue;
        }
        let start = i;
        while i < bytes.len() && bytes[i].is_ascii_digit() {
            i += 1;
        }
        let signed = start >= 1
            && bytes[start - 1] == b'-'
            && (start == 1 || matches!(bytes[start - 2], b'.' | b'_'));
        let digits = name[start..i].trim_start_matches('0').to_owned();
        out.push(PathNumber {
            negative: signed && !digits.is_empty(),
            digits,
        });
    }
}

/// The numbers of a frame file's path: those of its folders, then those of its file name
/// without the extension.
fn path_numbers(path: &Path) -> Vec<PathNumber> {
    let mut numbers = Vec::new();
    if let Some(parent) = path.parent() {
        for part in parent.components() {
            numbers_in(&part.as_os_str().to_string_lossy(), &mut numbers);
        }
    }
    if let Some(stem) = path.file_stem() {
        numbers_in(&stem.to_string_lossy(), &mut numbers);
    }
    numbers
}

/// The natural-order key of a frame file (see the module docs): files with numbers first, by
/// their numbers, then by file name and full path. Made once per file
/// (`sort_by_cached_key`), not once per comparison.
fn frame_order_key(path: &Path) -> (bool, Vec<PathNumber>, std::ffi::OsString, PathBuf) {
    let numbers = path_numbers(path);
    let name = path
        .file_name()
        .map(|s| s.to_os_string())
        .unwrap_or_default();
    (numbers.is_empty(), numbers, name, path.to_path_buf())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn numbers_in_finds_every_digit_run_and_its_sign() {
        let shown = |name: &str| {
            let mut numbers = Vec::new();
            numbers_in(name, &mut numbers);
            numbers
                .iter()
                .map(|n| format!("{}{}", if n.negative { "-" } else { "" }, n.digits))
                .collect::<Vec<_>>()
                .join(" ")
        };
        assert_eq!(shown("frame_10"), "10");
        assert_eq!(shown("take3_frame_0007"), "3 7");
        assert_eq!(shown("multipart.0001"), "1");
        assert_eq!(shown("f000"), "");
        assert_eq!(shown("sky"), "");
        assert_eq!(shown("12"), "12");
        assert_eq!(shown("é1"), "1");
        assert_eq!(shown("frame—02"), "2");
        assert_eq!(shown("f_\u{fffd}5"), "5");
        assert_eq!(shown("7日"), "7");
        assert_eq!(shown("cam_2024-05-01_12-30-58"), "2024 5 1 12 30 58");
        assert_eq!(shown("shot.-002"), "-2");
        assert_eq!(shown("f_-1"), "-1");
        assert_eq!(shown("-3x"), "-3");
        assert_eq!(shown("render-0004"), "4");
        assert_eq!(shown("shot.-000"), "");
    }

    #[test]
    fn natural_order() {
        let mut paths: Vec<PathBuf> = [
            "b/sky.exr",
            "a/frame_10.exr",
            "a/frame_2.exr",
            "a/frame_0002.hdr",
            "a/frame_1.exr",
            "a/alpha.exr",
            "a/frame_99999999999999999999999999999.exr",
            "c/frame_2.exr",
        ]
        .iter()
        .map(PathBuf::from)
        .collect();
        paths.sort_by_cached_key(|path| frame_order_key(path));
        // Names the last number alone ordered wrongly (an audit): each list is in order.
        for ordered in [
            &[
                "cam_2024-05-01_12-30-58.hdr",
                "cam_2024-05-01_12-30-59.hdr",
                "cam_2024-05-01_12-31-00.hdr",
                "cam_2024-05-01_12-31-01.hdr",
            ][..],
            &["t_0.5.exr", "t_1.0.exr", "t_1.5.exr", "t_2.0.exr"],
            &[
                "shot.-002.exr",
                "shot.-001.exr",
                "shot.0000.exr",
                "shot.0001.exr",
            ],
            &["frame_1_v2.exr", "frame_2_v2.exr", "frame_10_v2.exr"],
            &["f_1.exr", "f_1_v2.exr", "f_2.exr"],
            &[
                "take_1/f_0001.hdr",
                "take_1/f_0002.hdr",
                "take_2/f_0001.hdr",
                "take_2/f_0002.hdr",
            ],
        ] {
            let mut shuffled: Vec<PathBuf> = ordered.iter().rev().map(PathBuf::from).collect();
            shuffled.sort_by_cached_key(|path| frame_order_key(path));
            let expected: Vec<PathBuf> = ordered.iter().map(PathBuf::from).collect();
            assert_eq!(shuffled, expected);
        }
        let expected: Vec<PathBuf> = [
            "a/frame_1.exr",
            "a/frame_0002.hdr",
            "a/frame_2.exr",
            "c/frame_2.exr",
            "a/frame_10.exr",
            "a/frame_99999999999999999999999999999.exr",
            "a/alpha.exr",
            "b/sky.exr",
        ]
        .iter()
        .map(PathBuf::from)
        .collect();
        assert_eq!(paths, expected);
    }

    #[test]
    fn rejects_bad_fps() {
        for fps in [0.0, -1.0, f64::NAN, f64::INFINITY, 1e-30, 0.99e-4] {
            let options = SequenceOptions {
                fps: Some(fps),
                ..Default::default()
            };
            let err = SequenceSource::new(&["x.exr".to_string()], options).unwrap_err();
            assert!(matches!(err, CaptureError::InvalidSettings(_)), "{err}");
        }
    }

    #[test]
    fn no_inputs_is_no_frames() {
        let err = SequenceSource::new(&[], SequenceOptions::default()).unwrap_err();
        assert!(matches!(err, CaptureError::NoFrames(_)), "{err}");
    }

    #[test]
    fn missing_plain_path_is_io_error_naming_it() {
        let err = SequenceSource::new(
            &["/nonexistent/dir/frame_1.exr".to_string()],
            SequenceOptions::default(),
        )
        .unwrap_err();
        assert!(matches!(err, CaptureError::Io { .. }), "{err}");
        assert!(err.to_string().contains("/nonexistent/dir/frame_1.exr"));
    }

    /// `v4l2:DEVICE` among sequence inputs (any command but decompose's one INPUT) says where
    /// a camera is chosen instead of "No such file or directory".
    #[test]
    fn a_camera_input_outside_decompose_says_where_cameras_are_chosen() {
        let err = SequenceSource::new(
            &["v4l2:/dev/video7".to_string()],
            SequenceOptions::default(),
        )
        .unwrap_err();
        let text = err.to_string();
        assert!(
            text.contains("v4l2:/dev/video7") && text.contains("camera.device"),
            "{text}"
        );
    }

    /// A file named twice (directly, or through a directory and a pattern) is one frame.
    #[test]
    fn a_file_named_twice_is_read_once() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("f1.hdr");
        std::fs::write(&file, b"not read here").unwrap();
        let name = file.to_str().unwrap().to_owned();
        let folder = dir.path().to_str().unwrap().to_owned();
        let source =
            SequenceSource::new(&[name.clone(), name, folder], SequenceOptions::default()).unwrap();
        assert_eq!(source.frame_count(), 1);
    }

    #[test]
    fn glob_without_matches_is_no_frames() {
        let err = SequenceSource::new(
            &["/nonexistent/dir/*.exr".to_string()],
            SequenceOptions::default(),
        )
        .unwrap_err();
        assert!(
            matches!(err, CaptureError::NoFrames(ref s) if s.contains("*.exr")),
            "{err}"
        );
    }
}
