//! Output files and stdout for the one-shot commands (`decompose`, `fit-asg`, `wavelet …`,
//! `calibrate-fisheye`):
//! - an output path that names one of the command's input files is refused before it is
//!   created ([`refuse_input`]): creating it would truncate the input before it is read;
//! - EXR maps are encoded in memory and then written to the path ([`write_rgb_exr`]), so a
//!   failed write reports the path and leaves it in place (the `exr` crate's own file writer
//!   deletes the path on a write error, which removed a symbolic link, or a device node when
//!   the output was `/dev/full`);
//! - stdout closed by its reader (`| head`) ends a command quietly, with exit status 0; any
//!   other write error names what was written to ([`print`], [`is_broken_pipe`]).

use anyhow::{Context, Result};
use std::io::Write;
use std::os::unix::fs::MetadataExt;
use std::path::{Path, PathBuf};

/// Whether a write failed because the reader went away (`| head`): not an error for a command
/// whose output is a stream.
pub fn is_broken_pipe(err: &std::io::Error) -> bool {
    err.kind() == std::io::ErrorKind::BrokenPipe
}

/// Fails when `output` (given with `option`) is one of `inputs`: the same file (device and
/// inode), whatever names or links lead to it. A path that does not exist yet is no input.
pub fn refuse_input(output: &Path, option: &str, inputs: &[PathBuf]) -> Result<()> {
    let Ok(out) = std::fs::metadata(output) else {
        return Ok(());
    };
    for input in inputs {
        let Ok(meta) = std::fs::metadata(input) else {
            continue;
        };
        if (meta.dev(), meta.ino()) == (out.dev(), out.ino()) {
            anyhow::bail!(
                "{option} {} is the input file {}: writing it would destroy the input; choose \
                 another output path",
                output.display(),
                input.display()
            );
        }
    }
    Ok(())
}

/// Creates (or truncates) the output file `path` given with `option`, after checking it is none
/// of `inputs`.
pub fn create(path: &Path, option: &str, inputs: &[PathBuf]) -> Result<std::fs::File> {
    refuse_input(path, option, inputs)?;
    std::fs::File::create(path)
        .with_context(|| format!("cannot create output file {} ({option})", path.display()))
}

/// The output stream: the file `out` (given with `option`, checked against `inputs`), or
/// stdout.
pub fn open_output(out: Option<&Path>, option: &str, inputs: &[PathBuf]) -> Result<Box<dyn Write>> {
    Ok(match out {
        Some(path) => Box::new(create(path, option, inputs)?),
        None => Box::new(std::io::stdout().lock()),
    })
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
    inputs: &[PathBuf],
    (width, height): (usize, usize),
    pixel: impl Sync + Fn(usize, usize) -> [f32; 3],
) -> Result<()> {
    use exr::prelude::{Image, SpecificChannels, Vec2, WritableImage};
    refuse_input(path, option, inputs)?;
    let channels = SpecificChannels::rgb(|Vec2(x, y)| {
        let [r, g, b] = pixel(x, y);
        (r, g, b)
    });
    let mut bytes = std::io::Cursor::new(Vec::new());
    Image::from_channels((width, height), channels)
        .write()
        .to_buffered(&mut bytes)
        .with_context(|| format!("cannot encode the EXR image for {}", path.display()))?;
    std::fs::write(path, bytes.into_inner())
        .with_context(|| format!("cannot write {} ({option})", path.display()))
}
