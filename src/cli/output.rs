//! Output files and stdout for the one-shot commands (`decompose`, `fit-asg`, `wavelet …`,
//! `calibrate-fisheye`):
//! - an output path that names one of the command's input files is refused before it is
//!   created ([`InputFiles::refuse`], shared with the daemon): creating it would truncate the
//!   input before it is read;
//! - EXR maps are encoded in memory and then written to the path ([`write_rgb_exr`]), so a
//!   failed write reports the path and leaves it in place (the `exr` crate's own file writer
//!   deletes the path on a write error, which removed a symbolic link, or a device node when
//!   the output was `/dev/full`);
//! - stdout closed by its reader (`| head`) ends a command quietly, with exit status 0; any
//!   other write error names what was written to ([`print`], [`is_broken_pipe`]).

use anyhow::{Context, Result};
use std::io::Write;
use std::os::unix::fs::MetadataExt;
use std::path::Path;

pub use envlight::read_file::InputFiles;

/// Whether a write failed because the reader went away (`| head`): not an error for a command
/// whose output is a stream.
pub fn is_broken_pipe(err: &std::io::Error) -> bool {
    err.kind() == std::io::ErrorKind::BrokenPipe
}

/// Whether the paths `a` and `b` name the same file, whether or not it exists yet: the same
/// device and inode if both exist, else the same name in the same folder (by device and
/// inode: `.`, `..` and links to the folder are seen through).
pub fn same_file(a: &Path, b: &Path) -> bool {
    let id = |p: &Path| std::fs::metadata(p).ok().map(|m| (m.dev(), m.ino()));
    match (id(a), id(b)) {
        (Some(a), Some(b)) => a == b,
        (None, None) => {
            let folder = |p: &Path| {
                let parent = p.parent().filter(|p| !p.as_os_str().is_empty());
                id(parent.unwrap_or(Path::new(".")))
            };
            a.file_name().is_some()
                && a.file_name() == b.file_name()
                && folder(a).is_some()
                && folder(a) == folder(b)
        }
        _ => false,
    }
}

/// Fails early, before the work whose result it will hold, when the output file `path` (given
/// with `option`) cannot be written there: it is a directory, or its folder does not exist.
pub fn check_output_path(path: &Path, option: &str) -> Result<()> {
    if path.is_dir() {
        anyhow::bail!(
            "{option} {} is a directory; give a file path",
            path.display()
        );
    }
    let parent = path.parent().filter(|p| !p.as_os_str().is_empty());
    if let Some(parent) = parent.filter(|p| !p.is_dir()) {
        anyhow::bail!(
            "{option} {}: the folder {} does not exist",
            path.display(),
            parent.display()
        );
    }
    Ok(())
}

/// Fails when the output `path` (given with `option`), which receives OpenEXR data, does not
/// end in `.exr`: a `.png` or `.hdr` name would hold EXR data that later readers (envlight's own
/// among them) take for the format the name says.
pub fn require_exr_name(path: &Path, option: &str) -> Result<()> {
    let exr = path
        .extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("exr"));
    if !exr {
        anyhow::bail!(
            "{option} {}: the file is written as OpenEXR; give a path ending in .exr",
            path.display()
        );
    }
    Ok(())
}

/// Creates (or truncates) the output file `path` given with `option`, after checking it is none
/// of `inputs`.
pub fn create(path: &Path, option: &str, inputs: &InputFiles) -> Result<std::fs::File> {
    inputs.refuse(path, option)?;
    std::fs::File::create(path)
        .with_context(|| format!("cannot create output file {} ({option})", path.display()))
}

/// The output stream: the file `out` (given with `option`, checked against `inputs`), or
/// stdout.
pub fn open_output(
    out: Option<&Path>,
    option: &str,
    inputs: &InputFiles,
) -> Result<Box<dyn Write>> {
    Ok(match out {
        Some(path) => Box::new(create(path, option, inputs)?),
        None => Box::new(std::io::stdout().lock()),
    })
}

/// The JSON Lines output of a one-shot command (`wavelet approx`, `sh`): the file given with
/// an option, or stdout. A write error names the output; stdout closed by its reader (`| head`)
/// ends the command quietly ([`JsonLines::line`] returns `false`).
pub struct JsonLines {
    writer: std::io::BufWriter<Box<dyn Write>>,
    /// The file's path, or "stdout".
    name: String,
    to_stdout: bool,
}

impl JsonLines {
    /// Opens `out` (given with `option`, checked against `inputs`, and then protected among
    /// them so that no later output of the command replaces it), or stdout.
    pub fn open(out: Option<&Path>, option: &str, inputs: &mut InputFiles) -> Result<Self> {
        let writer = std::io::BufWriter::new(open_output(out, option, inputs)?);
        if let Some(path) = out {
            inputs.protect_output(path, option);
        }
        Ok(Self {
            writer,
            name: out.map_or("stdout".to_owned(), |p| p.display().to_string()),
            to_stdout: out.is_none(),
        })
    }

    /// Writes one line; `false` when stdout's reader has gone away (stop, successfully).
    pub fn line(&mut self, text: &str) -> Result<bool> {
        match writeln!(self.writer, "{text}") {
            Err(e) if self.to_stdout && is_broken_pipe(&e) => Ok(false),
            r => r
                .map(|()| true)
                .with_context(|| format!("cannot write to {}", self.name)),
        }
    }

    /// Flushes what is buffered.
    pub fn finish(mut self) -> Result<()> {
        match self.writer.flush() {
            Err(e) if self.to_stdout && is_broken_pipe(&e) => Ok(()),
            r => r.with_context(|| format!("cannot write to {}", self.name)),
        }
    }
}

/// Writes `text` to stdout and flushes it. A closed stdout (`| head`) is not an error: the
/// reader has what it wanted.
pub fn print(text: &str) -> Result<()> {
    let mut stdout = std::io::stdout().lock();
    match stdout
        .write_all(text.as_bytes())
        .and_then(|()| stdout.flush())
    {
        Err(e) if is_broken_pipe(&e) => Ok(()),
        r => r.context("cannot write to stdout"),
    }
}

/// Writes a `width × height` linear RGB image, `pixel(x, y)`, as a 32-bit float EXR at `path`
/// (checked against `inputs`): encoded in memory first, so a failed write names the path and
/// leaves whatever is there in place.
pub fn write_rgb_exr(
    path: &Path,
    option: &str,
    inputs: &InputFiles,
    (width, height): (usize, usize),
    pixel: impl Sync + Fn(usize, usize) -> [f32; 3],
) -> Result<()> {
    use exr::prelude::{Image, SpecificChannels, Vec2, WritableImage};
    inputs.refuse(path, option)?;
    let channels = SpecificChannels::rgb(|Vec2(x, y)| {
        let [r, g, b] = pixel(x, y);
        (r, g, b)
    });
    let mut bytes = std::io::Cursor::new(Vec::new());
    Image::from_encoded_channels(
        (width, height),
        envlight::capture::image_file::WRITE_ENCODING,
        channels,
    )
    .write()
    .to_buffered(&mut bytes)
    .with_context(|| format!("cannot encode the EXR image for {}", path.display()))?;
    std::fs::write(path, bytes.into_inner())
        .with_context(|| format!("cannot write {} ({option})", path.display()))
}
