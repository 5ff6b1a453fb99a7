//! Recording and replay of sessions.
//!
//! A recording is a directory:
//!
//! ```text
//! session.json     {"format": "envlight-recording", "version": 1, "source": "...",
//!                   "decompose": {settings}, "envlight": "0.1.0", "created_unix_s": ...}
//! frames.jsonl     one line per frame: {"seq": 0, "time": 0.0, "file": "frames/000000.exr",
//!                   "projection": ...}
//! frames/NNNNNN.exr  the frame as the decomposition received it: linear RGB, 32-bit float
//! lights.jsonl     the light stream, exactly as `envlight decompose` prints it
//! ```
//!
//! [`Recorder`] runs on its own thread (`envlight-record`) and is fed by the pipeline's tap
//! ([`crate::pipeline::PipelineOptions::tap`]): it stores the frames that reached the
//! decomposition (frames the capture dropped never reached it and are not part of the stream)
//! and the lights made from them. Every line is flushed as it is written, so a recording cut
//! short by a crash is readable up to its last whole frame. An error that stops the recorder
//! (a full disk) is flagged ([`Recorder::has_failed`]); the daemon then shuts down, and
//! what was stored before it replays.
//!
//! [`ReplaySource`] plays a recording back as a [`FrameSource`], at its original timing or as
//! fast as possible. Decomposed with the recorded settings and a lossless queue
//! ([`crate::pipeline::QueuePolicy::Block`]), the replay reproduces the recorded light stream
//! bit for bit: the frames are stored losslessly (f32) and the decomposition is deterministic.

use crate::capture::image_file::read_hdr_image;
use crate::capture::{CaptureError, FrameSource};
use crate::config::shown_number;
use crate::decompose::DecomposeSettings;
use crate::envmap::Projection;
use crate::frame::HdrFrame;
use crate::pipeline::Tapped;
use crossbeam_channel::Receiver;
use serde::{Deserialize, Serialize};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::Instant;

/// Name of the recorder thread.
pub const RECORD_THREAD_NAME: &str = "envlight-record";
/// `format` of `session.json`.
pub const FORMAT_NAME: &str = "envlight-recording";
/// `version` of `session.json`.
pub const FORMAT_VERSION: u32 = 1;
/// The latest frame time a recording's index may hold, in seconds from the session's start
/// (about 31.7 years): a later one is a corrupt index, and replaying it at the original timing
/// would wait past what a clock can hold.
pub const MAX_FRAME_TIME_S: f64 = 1e9;
/// The largest `session.json` a replay reads (the recorder writes about a kilobyte).
pub const MAX_SESSION_FILE_BYTES: u64 = 1 << 20;
/// The largest `frames.jsonl` a replay reads: 4 GiB, about 20 million frames (three days at
/// 60 frames per second).
pub const MAX_INDEX_FILE_BYTES: u64 = 1 << 32;

/// `session.json`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Session {
    pub format: String,
    pub version: u32,
    /// The source that was recorded, for people.
    pub source: String,
    /// The decomposition settings the lights were made with.
    pub decompose: DecomposeSettings,
    /// The envlight version that recorded it.
    pub envlight: String,
    pub created_unix_s: u64,
}

/// One line of `frames.jsonl`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct FrameEntry {
    pub seq: u64,
    /// Capture time, seconds since the source started.
    pub time: f64,
    /// The EXR file, relative to the recording directory.
    pub file: String,
    pub projection: Projection,
}

/// Errors of recording.
#[derive(Debug, thiserror::Error)]
pub enum RecordError {
    #[error("{}: {source}", path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    #[error("recording directory {} is not empty; choose a new directory (a recording is never overwritten)", path.display())]
    NotEmpty { path: PathBuf },
    #[error("cannot write frame {}: {message}", path.display())]
    Exr { path: PathBuf, message: String },
    #[error("recorder thread panicked")]
    Panicked,
}

fn io_error(path: &Path) -> impl FnOnce(std::io::Error) -> RecordError + '_ {
    move |source| RecordError::Io {
        path: path.to_path_buf(),
        source,
    }
}

/// What a finished recording holds.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct RecordSummary {
    pub frames: u64,
}

/// A running recorder. See the module docs.
pub struct Recorder {
    dir: PathBuf,
    /// The outermost folder [`Recorder::start`] created for `dir` (`dir` or one of its
    /// parents), which [`Recorder::discard`] removes again with the folders below it.
    created_dir: Option<PathBuf>,
    thread: JoinHandle<Result<RecordSummary, RecordError>>,
    /// Set by the recorder thread when an error stopped it ([`Recorder::has_failed`]).
    failed: Arc<AtomicBool>,
}

/// Removes what [`Recorder::start`] and its thread wrote into `dir`: `session.json`, the two
/// JSON Lines files, the recorded `frames/NNNNNN.exr` and the `frames` folder — and the
/// folders from `dir` up to `created_dir` when the recorder created them (each only if empty).
/// Anything else found there is left.
fn remove_recording(dir: &Path, created_dir: Option<&Path>) {
    for name in ["session.json", "frames.jsonl", "lights.jsonl"] {
        let _ = std::fs::remove_file(dir.join(name));
    }
    let frames = dir.join("frames");
    if let Ok(entries) = std::fs::read_dir(&frames) {
        for entry in entries.flatten() {
            let name = entry.file_name();
            let name = name.to_string_lossy();
            let recorded = name
                .strip_suffix(".exr")
                .is_some_and(|stem| stem.len() >= 6 && stem.bytes().all(|b| b.is_ascii_digit()));
            if recorded {
                let _ = std::fs::remove_file(entry.path());
            }
        }
    }
    let _ = std::fs::remove_dir(&frames);
    if let Some(top) = created_dir {
        for folder in dir.ancestors() {
            if std::fs::remove_dir(folder).is_err() || folder == top {
                break;
            }
        }
    }
}

/// One of the recording's JSON Lines files. A line is written with one `write_all` on the
/// file (no buffer that a later drop could flush), and a failed write is cut back to the last
/// whole line, so a recording stopped by a full disk still reads to its last whole frame.
struct LinesFile {
    file: std::fs::File,
    path: PathBuf,
    /// Bytes of whole lines written.
    len: u64,
}

impl LinesFile {
    fn create(path: PathBuf) -> Result<Self, RecordError> {
        let file = std::fs::File::create(&path).map_err(io_error(&path))?;
        Ok(Self { file, path, len: 0 })
    }

    fn append(&mut self, line: &[u8]) -> Result<(), RecordError> {
        match self.file.write_all(line) {
            Ok(()) => {
                self.len += line.len() as u64;
                Ok(())
            }
            Err(source) => {
                self.cut_to(self.len);
                Err(RecordError::Io {
                    path: self.path.clone(),
                    source,
                })
            }
        }
    }

    /// Cuts the file back to `len` bytes (best effort: the write already failed).
    fn cut_to(&mut self, len: u64) {
        use std::io::Seek;
        if self.file.set_len(len).is_ok() && self.file.seek(std::io::SeekFrom::Start(len)).is_ok() {
            self.len = len;
        }
    }
}

impl Recorder {
    /// Creates the recording directory (it must be new or empty), writes `session.json` and
    /// starts the recorder thread on `frames`.
    pub fn start(
        dir: &Path,
        source: &str,
        settings: &DecomposeSettings,
        frames: Receiver<Tapped>,
    ) -> Result<Recorder, RecordError> {
        // The outermost folder of `dir` that does not exist yet: create_dir_all makes it and
        // everything below, all of which a discard removes again.
        let created_dir = dir
            .ancestors()
            .take_while(|a| !a.as_os_str().is_empty() && !a.exists())
            .last()
            .map(Path::to_path_buf);
        if dir.exists() && !dir.is_dir() {
            return Err(RecordError::Io {
                path: dir.to_path_buf(),
                source: std::io::Error::new(
                    std::io::ErrorKind::AlreadyExists,
                    "a file, not a directory; a recording is a new or empty directory",
                ),
            });
        }
        std::fs::create_dir_all(dir).map_err(io_error(dir))?;
        // Creating `frames` claims the directory: of two recorders started on the same empty
        // directory only one creates it, and the other leaves without removing anything (the
        // cleanup below would delete the first one's files).
        let frames_dir = dir.join("frames");
        let not_empty = || RecordError::NotEmpty {
            path: dir.to_path_buf(),
        };
        match std::fs::create_dir(&frames_dir) {
            Err(e) if e.kind() == std::io::ErrorKind::AlreadyExists => return Err(not_empty()),
            result => result.map_err(io_error(&frames_dir))?,
        }
        let claimed_empty =
            std::fs::read_dir(dir)
                .map_err(io_error(dir))
                .and_then(|mut entries| {
                    let only_frames = entries.all(|e| e.is_ok_and(|e| e.file_name() == "frames"));
                    if only_frames {
                        Ok(())
                    } else {
                        Err(not_empty())
                    }
                });
        if let Err(error) = claimed_empty {
            let _ = std::fs::remove_dir(&frames_dir);
            return Err(error);
        }
        // From here on a failure removes what was created (a full disk leaves the directory
        // as it was, and the same command can be run again).
        Self::start_in(dir, source, settings, frames, created_dir.clone()).inspect_err(|_| {
            remove_recording(dir, created_dir.as_deref());
        })
    }

    fn start_in(
        dir: &Path,
        source: &str,
        settings: &DecomposeSettings,
        frames: Receiver<Tapped>,
        created_dir: Option<PathBuf>,
    ) -> Result<Recorder, RecordError> {
        let session = Session {
            format: FORMAT_NAME.to_owned(),
            version: FORMAT_VERSION,
            source: source.to_owned(),
            decompose: settings.clone(),
            envlight: env!("CARGO_PKG_VERSION").to_owned(),
            created_unix_s: std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map_or(0, |d| d.as_secs()),
        };
        let session_path = dir.join("session.json");
        let text = serde_json::to_string_pretty(&session).unwrap_or_default();
        std::fs::write(&session_path, text + "\n").map_err(io_error(&session_path))?;
        let mut index = LinesFile::create(dir.join("frames.jsonl"))?;
        let mut lights = LinesFile::create(dir.join("lights.jsonl"))?;
        let root = dir.to_path_buf();
        let failed = Arc::new(AtomicBool::new(false));
        let failed_flag = Arc::clone(&failed);
        let thread = std::thread::Builder::new()
            .name(RECORD_THREAD_NAME.to_owned())
            .spawn(move || {
                let mut summary = RecordSummary::default();
                let mut previous = None;
                for tapped in frames.iter() {
                    let result = write_frame(&root, &tapped, previous, &mut index, &mut lights);
                    previous = Some((tapped.frame.seq, tapped.frame.time));
                    if let Err(error) = result {
                        tracing::error!(%error, "recording failed; the recording stops here");
                        failed_flag.store(true, Ordering::Release);
                        return Err(error);
                    }
                    summary.frames += 1;
                }
                Ok(summary)
            })
            .map_err(io_error(dir))?;
        Ok(Recorder {
            dir: dir.to_path_buf(),
            created_dir,
            thread,
            failed,
        })
    }

    /// Whether an error (a full disk, a frame file that cannot be written) has stopped the
    /// recorder: it stores nothing more, and [`Recorder::finish`] returns the error. The
    /// daemon then shuts down rather than go on with a recording that silently ends.
    pub fn has_failed(&self) -> bool {
        self.failed.load(Ordering::Acquire)
    }

    /// The recording directory.
    pub fn dir(&self) -> &Path {
        &self.dir
    }

    /// Waits for the recorder to store everything it was sent (the pipeline must have ended,
    /// closing the tap) and reports what it stored or the error that stopped it.
    pub fn finish(self) -> Result<RecordSummary, RecordError> {
        self.thread.join().unwrap_or(Err(RecordError::Panicked))
    }

    /// Ends a recording of a session that failed to start: once the tap is closed, removes
    /// what [`Recorder::start`] created — the frames recorded in the moments before the
    /// failure included (they are logged) — so the directory is as it was and the same
    /// command can be run again.
    pub fn discard(self) {
        let (dir, created_dir) = (self.dir.clone(), self.created_dir.clone());
        if let Ok(summary) = self.finish() {
            if summary.frames > 0 {
                tracing::warn!(
                    dir = %dir.display(),
                    "the session failed to start; removing the {} frames recorded meanwhile",
                    summary.frames
                );
            }
        }
        remove_recording(&dir, created_dir.as_deref());
    }
}

/// The order a recording's frames keep, which its replay checks in the index and the recorder
/// as it writes: a time in 0..=[`MAX_FRAME_TIME_S`] and, after the frame before
/// (`previous`: its seq and time), a larger seq and a time that does not go back. The
/// problem, if any.
fn frame_order_problem(seq: u64, time: f64, previous: Option<(u64, f64)>) -> Option<String> {
    if !(time.is_finite() && (0.0..=MAX_FRAME_TIME_S).contains(&time)) {
        return Some(format!(
            "time {} s is not in 0..={MAX_FRAME_TIME_S} s (frame times count from the \
             session's start)",
            shown_number(time)
        ));
    }
    match previous {
        Some((previous_seq, previous_time)) if seq <= previous_seq || time < previous_time => {
            Some(format!(
                "frame seq {seq} at {} s does not follow seq {previous_seq} at {} s",
                shown_number(time),
                shown_number(previous_time)
            ))
        }
        _ => None,
    }
}

/// Stores one frame and its lights; `previous` is the (seq, time) of the frame stored last.
fn write_frame(
    root: &Path,
    tapped: &Tapped,
    previous: Option<(u64, f64)>,
    index: &mut LinesFile,
    lights: &mut LinesFile,
) -> Result<(), RecordError> {
    let frame = &tapped.frame;
    let file = format!("frames/{:06}.exr", frame.seq);
    let path = root.join(&file);
    // A frame that breaks the replay's order would make it refuse the recording from that
    // line on (a time of NaN, written as `null`, the whole recording), and a repeated seq
    // would overwrite an earlier frame's file. The built-in sources keep the order; a library
    // caller's own source might not.
    if let Some(problem) = frame_order_problem(frame.seq, frame.time, previous) {
        return Err(RecordError::Exr {
            path,
            message: format!("{problem}; a replay would refuse the frame"),
        });
    }
    // A frame the replay could not read is not stored: the recording would end there.
    let pixels = u64::from(frame.width) * u64::from(frame.height);
    if pixels > crate::capture::image_file::MAX_PIXELS {
        return Err(RecordError::Exr {
            path,
            message: format!(
                "the frame is {}x{}, more than the {} pixels a replay reads; record at a \
                 smaller size",
                frame.width,
                frame.height,
                crate::capture::image_file::MAX_PIXELS
            ),
        });
    }
    let width = frame.width as usize;
    let channels = exr::prelude::SpecificChannels::rgb(|exr::prelude::Vec2(x, y)| {
        let [r, g, b] = frame.pixels[y * width + x];
        (r, g, b)
    });
    let image = exr::prelude::Image::from_encoded_channels(
        (width, frame.height as usize),
        crate::capture::image_file::WRITE_ENCODING,
        channels,
    );
    exr::prelude::WritableImage::write(&image)
        .to_file(&path)
        .map_err(|e| RecordError::Exr {
            path: path.clone(),
            message: e.to_string(),
        })?;
    let entry = FrameEntry {
        seq: frame.seq,
        time: frame.time,
        file,
        projection: frame.projection,
    };
    let mut line = serde_json::to_vec(&entry).unwrap_or_default();
    line.push(b'\n');
    let index_len = index.len;
    index.append(&line)?;
    let mut line = serde_json::to_vec(tapped.lights.as_ref()).unwrap_or_default();
    line.push(b'\n');
    // A frame is in both files or in neither.
    lights
        .append(&line)
        .inspect_err(|_| index.cut_to(index_len))
}

/// How a replay is paced.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Pacing {
    /// At the recorded capture times (the default).
    #[default]
    Original,
    /// As fast as the decomposition takes them.
    AsFastAsPossible,
}

/// A gap between recorded frames longer than this is warned of when a replay at the original
/// timing opens.
const LONG_REPLAY_GAP_S: f64 = 10.0;

/// A recording played back as a frame source. See the module docs.
pub struct ReplaySource {
    dir: PathBuf,
    session: Session,
    entries: Vec<FrameEntry>,
    /// The recording's files (the frames, the index and the session), which no output may
    /// replace ([`FrameSource::files`]).
    files: Vec<PathBuf>,
    next: usize,
    pacing: Pacing,
    started: Option<(Instant, f64)>,
}

impl ReplaySource {
    /// Opens a recording: reads `session.json` and the frame index (the frames themselves are
    /// read as they are replayed).
    pub fn open(dir: &Path, pacing: Pacing) -> Result<ReplaySource, CaptureError> {
        let session_path = dir.join("session.json");
        let io = |path: &Path| {
            let path = path.to_path_buf();
            move |source| CaptureError::Io { path, source }
        };
        if !session_path.exists() {
            return Err(CaptureError::Format {
                path: dir.to_path_buf(),
                message: if dir.is_dir() {
                    "not a recording (no session.json); envlight record --out DIR makes one"
                        .to_owned()
                } else if std::fs::symlink_metadata(dir).is_err() {
                    "no such directory (a recording is a directory made by envlight record --out \
                     DIR)"
                        .to_owned()
                } else {
                    "not a recording directory (made by envlight record --out DIR)".to_owned()
                },
            });
        }
        let text = crate::read_file::read_regular_text(
            &session_path,
            MAX_SESSION_FILE_BYTES,
            "a session file",
        )
        .map_err(io(&session_path))?;
        let session: Session = serde_json::from_str(&text).map_err(|e| CaptureError::Format {
            path: session_path.clone(),
            message: format!("not an envlight session file: {e}"),
        })?;
        if session.format != FORMAT_NAME || session.version != FORMAT_VERSION {
            return Err(CaptureError::Format {
                path: session_path.clone(),
                message: format!(
                    "format {:?} version {} (this envlight reads {FORMAT_NAME:?} version {FORMAT_VERSION})",
                    session.format, session.version
                ),
            });
        }
        session
            .decompose
            .validate()
            .map_err(|e| CaptureError::Format {
                path: session_path,
                message: format!("invalid decomposition settings: {e}"),
            })?;
        let index_path = dir.join("frames.jsonl");
        let text =
            crate::read_file::read_regular_text(&index_path, MAX_INDEX_FILE_BYTES, "a frame index")
                .map_err(io(&index_path))?;
        // A last line without its newline was cut short (the recorder stopped mid-write, e.g.
        // killed): the recording is read up to its last whole frame.
        let cut_short = !text.is_empty() && !text.ends_with('\n');
        let line_count = text.lines().count();
        let mut entries: Vec<FrameEntry> = Vec::new();
        for (number, line) in text.lines().enumerate() {
            if line.trim().is_empty() {
                continue;
            }
            let entry: FrameEntry = match serde_json::from_str(line) {
                Ok(entry) => entry,
                Err(e) if cut_short && number + 1 == line_count => {
                    tracing::warn!(
                        "{}: line {} is cut short ({e}); replaying the {} whole frames before it",
                        index_path.display(),
                        number + 1,
                        entries.len()
                    );
                    break;
                }
                Err(e) => {
                    // serde names the projection's enum variants only in its own terms.
                    let hint = if e.to_string().contains("variant") {
                        " (a projection is \"lat-long\", \"angular-map\" or {\"fisheye\": \
                         {\"model\", \"center\", \"radius\", \"fov_deg\", \"rotation_deg\"}})"
                    } else {
                        ""
                    };
                    return Err(CaptureError::Format {
                        path: index_path.clone(),
                        message: format!("line {}: {e}{hint}", number + 1),
                    });
                }
            };
            let bad = |message: String| CaptureError::Format {
                path: index_path.clone(),
                message: format!("line {}: {message}", number + 1),
            };
            let previous = entries.last().map(|e| (e.seq, e.time));
            if let Some(problem) = frame_order_problem(entry.seq, entry.time, previous) {
                return Err(bad(problem));
            }
            let relative = Path::new(&entry.file);
            if relative.is_absolute()
                || relative
                    .components()
                    .any(|c| matches!(c, std::path::Component::ParentDir))
            {
                return Err(bad(format!(
                    "file {:?} must be a path inside the recording",
                    entry.file
                )));
            }
            entries.push(entry);
        }
        if entries.is_empty() {
            return Err(CaptureError::Format {
                path: index_path.clone(),
                message: "the recording holds no frame (its index is empty)".to_owned(),
            });
        }
        // At the original timing a long gap is a long silent wait (a time edited to 10⁹ s
        // waited 31 years without a word; an audit): the longest is said at the start.
        let longest_gap = entries
            .windows(2)
            .map(|w| (w[1].time - w[0].time, w[1].seq))
            .max_by(|a, b| a.0.total_cmp(&b.0));
        if let (Pacing::Original, Some((gap, seq))) = (pacing, longest_gap) {
            if gap > LONG_REPLAY_GAP_S {
                tracing::warn!(
                    "{}: frame seq {seq} is due {} s after the frame before it; at the \
                     original timing the replay waits that long (--fast replays as fast as \
                     possible)",
                    index_path.display(),
                    shown_number(gap)
                );
            }
        }
        let files = entries
            .iter()
            .map(|e| dir.join(&e.file))
            .chain([index_path.clone(), dir.join("session.json")])
            .collect();
        Ok(ReplaySource {
            dir: dir.to_path_buf(),
            session,
            entries,
            files,
            next: 0,
            pacing,
            started: None,
        })
    }

    /// The recording's `session.json`: replay decomposes with its settings.
    pub fn session(&self) -> &Session {
        &self.session
    }

    /// Number of frames in the recording.
    pub fn len(&self) -> usize {
        self.entries.len()
    }

    /// Whether the recording has no frames (never true for an opened recording).
    pub fn is_empty(&self) -> bool {
        self.entries.is_empty()
    }
}

impl FrameSource for ReplaySource {
    fn next_frame(&mut self) -> Result<Option<HdrFrame>, CaptureError> {
        let Some(entry) = self.entries.get(self.next) else {
            return Ok(None);
        };
        self.next += 1;
        let path = self.dir.join(&entry.file);
        let image = read_hdr_image(&path)?;
        let mut frame = HdrFrame::new(image.width, image.height, image.pixels, entry.projection)
            .ok_or_else(|| CaptureError::Format {
                path: path.clone(),
                message: "empty image".to_owned(),
            })?;
        // The index's projection was not checked against a size until now: a fisheye
        // calibration edited to radius 0 made every light black without a word.
        if let Projection::Fisheye(calibration) = &entry.projection {
            calibration
                .validate(image.width, image.height)
                .map_err(|problem| CaptureError::Format {
                    path: self.dir.join("frames.jsonl"),
                    message: format!(
                        "frame seq {}: invalid fisheye projection for its {}x{} image: {problem}",
                        entry.seq, image.width, image.height
                    ),
                })?;
        }
        frame.seq = entry.seq;
        frame.time = entry.time;
        if self.pacing == Pacing::Original {
            let (start, first_time) = *self.started.get_or_insert((Instant::now(), entry.time));
            if !crate::capture::sleep_until(start, (entry.time - first_time).max(0.0)) {
                // Stopped while waiting: the frame is not due yet and is not replayed.
                return Ok(None);
            }
        }
        Ok(Some(frame))
    }

    fn files(&self) -> &[PathBuf] {
        &self.files
    }

    fn describe(&self) -> String {
        format!(
            "recording {} ({} frames of {}, {})",
            self.dir.display(),
            self.entries.len(),
            self.session.source,
            match self.pacing {
                Pacing::Original => "at the original timing",
                Pacing::AsFastAsPossible => "as fast as possible",
            }
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Frames out of the replay's order are refused as they come, naming the frame (a NaN
    /// time was written as `null`, and the replay refused the whole recording); the frames
    /// before stay and replay.
    #[test]
    fn frames_the_replay_would_refuse_stop_the_recording() {
        for (times, seqs, expected) in [
            ([0.0, f64::NAN], [0, 1], "000001.exr: time NaN s is not in"),
            (
                [1.0, 0.5],
                [0, 1],
                "000001.exr: frame seq 1 at 0.5 s does not follow seq 0 at 1 s",
            ),
            (
                [0.0, 0.1],
                [3, 3],
                "000003.exr: frame seq 3 at 0.1 s does not follow seq 3 at 0 s",
            ),
            (
                [0.0, 2e9],
                [0, 1],
                "000001.exr: time 2000000000 s is not in",
            ),
        ] {
            let dir = tempfile::tempdir().unwrap();
            let recording = dir.path().join("rec");
            let (tx, rx) = crossbeam_channel::bounded(4);
            let recorder =
                Recorder::start(&recording, "test", &DecomposeSettings::default(), rx).unwrap();
            for (time, seq) in times.into_iter().zip(seqs) {
                let mut frame =
                    HdrFrame::new(4, 2, vec![[1.0; 3]; 8], Projection::LatLong).unwrap();
                (frame.seq, frame.time) = (seq, time);
                let lights = std::sync::Arc::new(crate::light::LightFrame {
                    seq,
                    time,
                    lights: Vec::new(),
                });
                tx.send(Tapped { frame, lights }).unwrap();
            }
            drop(tx);
            let e = recorder.finish().unwrap_err().to_string();
            assert!(e.contains(expected), "{e}");
            let replay = ReplaySource::open(&recording, Pacing::AsFastAsPossible).unwrap();
            assert_eq!(replay.len(), 1, "{expected}");
        }
    }

    /// A recording directory with a valid `session.json` and the given `frames.jsonl`.
    fn recording_with_index(index: &str) -> tempfile::TempDir {
        let dir = tempfile::tempdir().unwrap();
        let session = Session {
            format: FORMAT_NAME.into(),
            version: FORMAT_VERSION,
            source: "test".into(),
            decompose: DecomposeSettings::default(),
            envlight: env!("CARGO_PKG_VERSION").into(),
            created_unix_s: 0,
        };
        std::fs::write(
            dir.path().join("session.json"),
            serde_json::to_string(&session).unwrap(),
        )
        .unwrap();
        std::fs::write(dir.path().join("frames.jsonl"), index).unwrap();
        dir
    }

    fn line(seq: u64, time: &str, file: &str) -> String {
        format!(
            "{{\"seq\":{seq},\"time\":{time},\"file\":\"{file}\",\"projection\":{}}}\n",
            serde_json::to_string(&Projection::LatLong).unwrap()
        )
    }

    #[test]
    fn an_index_of_good_lines_opens() {
        let index = line(0, "0.0", "frames/000000.exr") + &line(1, "1e8", "frames/000001.exr");
        let dir = recording_with_index(&index);
        let replay = ReplaySource::open(dir.path(), Pacing::Original).unwrap();
        assert_eq!(replay.len(), 2);
    }

    /// An empty index is a recording without frames, said as such (it was reported as a
    /// sequence: "no .exr or .hdr frames found in …/frames.jsonl").
    #[test]
    fn an_empty_index_is_a_recording_without_frames() {
        let dir = recording_with_index("");
        let error = ReplaySource::open(dir.path(), Pacing::Original)
            .err()
            .unwrap()
            .to_string();
        assert!(
            error.contains("frames.jsonl") && error.contains("holds no frame"),
            "{error}"
        );
    }

    #[test]
    fn bad_index_lines_are_errors_naming_the_file_and_line() {
        for (second, expected) in [
            (line(1, "1e20", "frames/1.exr"), "time 1e20 s"),
            (line(1, "-1", "frames/1.exr"), "time -1 s"),
            (line(1, "1e9", "frames/1.exr"), ""),
            (line(0, "1", "frames/1.exr"), "does not follow"),
            (line(1, "1", "../1.exr"), "inside the recording"),
            ("{\"seq\":1}\n".to_string(), "missing field"),
        ] {
            let index = line(0, "0.5", "frames/0.exr") + &second;
            let dir = recording_with_index(&index);
            match ReplaySource::open(dir.path(), Pacing::Original) {
                Ok(_) => assert!(expected.is_empty(), "{second:?} was accepted"),
                Err(e) => {
                    let text = e.to_string();
                    assert!(!expected.is_empty(), "{second:?}: {text}");
                    assert!(
                        text.contains("frames.jsonl") && text.contains("line 2"),
                        "{text}"
                    );
                    assert!(text.contains(expected), "{second:?}: {text}");
                }
            }
        }
    }

    /// A frame larger than a replay reads is not stored (the recording could not be replayed
    /// past it): an error naming its size, and nothing written. (Its fields are set directly:
    /// the check comes before the pixels are read.)
    #[test]
    fn a_frame_too_large_to_replay_is_not_recorded() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::create_dir(dir.path().join("frames")).unwrap();
        let tapped = Tapped {
            frame: HdrFrame {
                width: 16384,
                height: 16384,
                pixels: Vec::new(),
                projection: Projection::LatLong,
                time: 0.0,
                seq: 0,
            },
            lights: std::sync::Arc::new(crate::light::LightFrame::default()),
        };
        let mut index = LinesFile::create(dir.path().join("frames.jsonl")).unwrap();
        let mut lights = LinesFile::create(dir.path().join("lights.jsonl")).unwrap();
        let e = write_frame(dir.path(), &tapped, None, &mut index, &mut lights).unwrap_err();
        assert!(e.to_string().contains("16384x16384"), "{e}");
        assert_eq!((index.len, lights.len), (0, 0));
        assert!(!dir.path().join("frames/000000.exr").exists());
    }

    /// A folder that is no recording, or no folder, says so (it said "session.json: No such
    /// file or directory"); recording into a file says the file is in the way (it said
    /// "recording directory …: File exists").
    #[test]
    fn what_is_no_recording_is_named_as_such() {
        let dir = tempfile::tempdir().unwrap();
        for (path, needle) in [
            (
                dir.path().to_path_buf(),
                "not a recording (no session.json)",
            ),
            (dir.path().join("missing"), "no such directory"),
            (
                {
                    let file = dir.path().join("file");
                    std::fs::write(&file, b"x").unwrap();
                    file
                },
                "not a recording directory",
            ),
        ] {
            let e = ReplaySource::open(&path, Pacing::Original).err().unwrap();
            let text = e.to_string();
            assert!(
                text.contains(needle) && text.contains(&*path.to_string_lossy()),
                "{text}"
            );
        }
        let file = dir.path().join("f1.hdr");
        std::fs::write(&file, b"x").unwrap();
        let (_tx, rx) = crossbeam_channel::bounded(1);
        let e = Recorder::start(&file, "test", &DecomposeSettings::default(), rx)
            .err()
            .unwrap();
        assert!(e.to_string().contains("a file, not a directory"), "{e}");
        assert_eq!(std::fs::read(&file).unwrap(), b"x");
    }

    /// A recording's `session.json` or `frames.jsonl` that is a device or a pipe is an error
    /// naming it (read whole, `/dev/zero` grew memory without end and a pipe blocked).
    #[test]
    fn an_index_or_session_that_is_no_file_is_an_error() {
        let dir = recording_with_index(&line(0, "0.0", "frames/000000.exr"));
        let index = dir.path().join("frames.jsonl");
        std::fs::remove_file(&index).unwrap();
        std::os::unix::fs::symlink("/dev/zero", &index).unwrap();
        let e = ReplaySource::open(dir.path(), Pacing::Original)
            .err()
            .unwrap();
        let text = e.to_string();
        assert!(
            text.contains("frames.jsonl") && text.contains("not a regular file"),
            "{text}"
        );
        let session = dir.path().join("session.json");
        std::fs::remove_file(&session).unwrap();
        let made = std::process::Command::new("mkfifo")
            .arg(&session)
            .status()
            .unwrap();
        assert!(made.success());
        let e = ReplaySource::open(dir.path(), Pacing::Original)
            .err()
            .unwrap();
        let text = e.to_string();
        assert!(
            text.contains("session.json") && text.contains("not a regular file"),
            "{text}"
        );
    }

    /// A last line without its newline (the recorder stopped mid-write: killed, a full disk)
    /// is left out with a warning, and the whole frames before it replay; the same broken
    /// text on a line that ends is an error as before.
    #[test]
    fn an_index_cut_short_replays_its_whole_frames() {
        let whole = line(0, "0.0", "frames/000000.exr") + &line(1, "0.1", "frames/000001.exr");
        let cut = r#"{"seq":2,"time":0.2,"file":"fr"#;
        let dir = recording_with_index(&(whole.clone() + cut));
        assert_eq!(
            ReplaySource::open(dir.path(), Pacing::Original)
                .unwrap()
                .len(),
            2
        );
        let dir = recording_with_index(&(whole + cut + "\n"));
        let e = ReplaySource::open(dir.path(), Pacing::Original)
            .err()
            .unwrap();
        assert!(e.to_string().contains("line 3"), "{e}");
        // Nothing but a cut line: no frames.
        let dir = recording_with_index(cut);
        assert!(ReplaySource::open(dir.path(), Pacing::Original).is_err());
    }

    /// A fisheye calibration in the index is checked against its frame's size: radius 0
    /// replayed as black lights without a word.
    /// A fisheye projection without its calibration, and a projection of another name, say
    /// what a projection is (serde said "invalid type: unit variant, expected newtype
    /// variant"); a time out of range is shown as a number of a few digits.
    #[test]
    fn index_lines_with_a_bad_projection_or_time_say_what_is_expected() {
        for (index, needle) in [
            (
                "{\"seq\":0,\"time\":0,\"file\":\"frames/000000.exr\",\"projection\":\"fisheye\"}\n",
                "line 1: ",
            ),
            (
                "{\"seq\":0,\"time\":0,\"file\":\"frames/000000.exr\",\"projection\":\"mercator\"}\n",
                "line 1: ",
            ),
        ] {
            let dir = recording_with_index(index);
            let e = ReplaySource::open(dir.path(), Pacing::AsFastAsPossible)
                .err()
                .unwrap()
                .to_string();
            assert!(
                e.contains(needle) && e.contains("a projection is \"lat-long\""),
                "{e}"
            );
        }
        let dir = recording_with_index(&line(0, "1e300", "frames/000000.exr"));
        let e = ReplaySource::open(dir.path(), Pacing::AsFastAsPossible)
            .err()
            .unwrap()
            .to_string();
        assert!(e.contains("time 1e300 s is not in"), "{e}");
    }

    #[test]
    fn an_invalid_projection_in_the_index_is_an_error() {
        let projection = Projection::Fisheye(crate::envmap::FisheyeCalibration {
            radius: Some(0.0),
            ..Default::default()
        });
        let index = format!(
            "{{\"seq\":0,\"time\":0,\"file\":\"frames/000000.exr\",\"projection\":{}}}\n",
            serde_json::to_string(&projection).unwrap()
        );
        let dir = recording_with_index(&index);
        std::fs::create_dir(dir.path().join("frames")).unwrap();
        exr::prelude::write_rgb_file(dir.path().join("frames/000000.exr"), 8, 8, |_, _| {
            (1.0f32, 1.0f32, 1.0f32)
        })
        .unwrap();
        let mut replay = ReplaySource::open(dir.path(), Pacing::AsFastAsPossible).unwrap();
        let e = replay.next_frame().err().unwrap().to_string();
        assert!(
            e.contains("frames.jsonl") && e.contains("frame seq 0") && e.contains("radius"),
            "{e}"
        );
    }

    /// Of recorders started together on one empty directory one records, and the others
    /// fail as on a directory that is not empty without removing the first one's files.
    #[test]
    fn recorders_started_together_on_one_directory_leave_the_winner_alone() {
        const RECORDERS: usize = 8;
        let parent = tempfile::tempdir().unwrap();
        for round in 0..20 {
            let dir = parent.path().join(format!("rec_{round}"));
            let barrier = std::sync::Barrier::new(RECORDERS);
            let started: Vec<_> = std::thread::scope(|scope| {
                let starts: Vec<_> = (0..RECORDERS)
                    .map(|_| {
                        scope.spawn(|| {
                            let (_tx, rx) = crossbeam_channel::bounded(1);
                            barrier.wait();
                            Recorder::start(&dir, "test", &DecomposeSettings::default(), rx)
                        })
                    })
                    .collect();
                starts.into_iter().map(|s| s.join().unwrap()).collect()
            });
            let mut winners = 0;
            for result in started {
                match result {
                    Ok(recorder) => {
                        winners += 1;
                        for name in ["session.json", "frames.jsonl", "lights.jsonl", "frames"] {
                            assert!(dir.join(name).exists(), "round {round}: {name} removed");
                        }
                        assert_eq!(recorder.finish().unwrap().frames, 0);
                    }
                    Err(error) => assert!(
                        matches!(error, RecordError::NotEmpty { .. }),
                        "round {round}: {error}"
                    ),
                }
            }
            assert_eq!(winners, 1, "round {round}");
        }
    }

    /// A session that failed to start leaves its directory as it was: the frames recorded
    /// meanwhile are removed with the rest (they were kept, and the same command then failed
    /// on a directory that was not empty), and the folders the recorder created go too.
    #[test]
    fn a_discarded_recording_leaves_the_directory_as_it_was() {
        let parent = tempfile::tempdir().unwrap();
        for existed in [true, false] {
            // A new recording goes two folders deep: all three are the recorder's.
            let top = parent.path().join(format!("rec_{existed}"));
            let dir = if existed {
                top.clone()
            } else {
                top.join("a/b")
            };
            if existed {
                std::fs::create_dir(&dir).unwrap();
            }
            let (tx, rx) = crossbeam_channel::bounded(4);
            let recorder =
                Recorder::start(&dir, "test", &DecomposeSettings::default(), rx).unwrap();
            for seq in 0..2 {
                let mut frame =
                    HdrFrame::new(4, 2, vec![[1.0; 3]; 8], Projection::LatLong).unwrap();
                frame.seq = seq;
                let lights = std::sync::Arc::new(crate::light::LightFrame {
                    seq,
                    time: 0.0,
                    lights: Vec::new(),
                });
                tx.send(Tapped { frame, lights }).unwrap();
            }
            drop(tx);
            recorder.discard();
            assert_eq!(top.exists(), existed);
            if existed {
                assert_eq!(std::fs::read_dir(&dir).unwrap().count(), 0);
            }
        }
    }
}
