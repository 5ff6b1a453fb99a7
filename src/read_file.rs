//! Reading a whole file a user named — a frame, a scene and its buffers or material libraries,
//! a response curve, a recording's index — without trusting it to be a file of sane size.
//!
//! `std::fs::read` follows a path to anything: a FIFO blocks the process forever, a device such
//! as `/dev/zero` never ends and grows memory until the process is killed, and a sparse file of
//! a terabyte makes it ask for a terabyte at once (an allocation failure aborts, it does not
//! return an error). [`read_regular_file`] reads only regular files (after following links) of
//! at most a given size, and says which of those it was in an [`std::io::Error`] that the
//! callers' errors wrap with the path.
//!
//! The outputs replaced whole every frame (`--latest`, `render.latest_png`) are written to a
//! temporary file and renamed over the path: [`check_replaceable`] refuses a path that is a
//! device, a pipe, a socket or a directory, which the rename would replace (run as root,
//! `--latest /dev/null` turned `/dev/null` into a regular file).
//!
//! No output may be one of the inputs ([`InputFiles`], used by the one-shot commands and the
//! daemon alike): creating or replacing it would destroy the input before or while it is read.

use std::io::{Error, ErrorKind, Read};
use std::os::unix::fs::MetadataExt;
use std::path::{Path, PathBuf};

/// Reads the regular file at `path` if it holds at most `max_bytes` bytes; `what` names the
/// kind of file in the error ("a scene", "a response curve", …). Also an error if the file
/// grows past the limit while it is read.
pub fn read_regular_file(path: &Path, max_bytes: u64, what: &str) -> std::io::Result<Vec<u8>> {
    let metadata = regular_file_metadata(path, what)?;
    let too_large = |size: u64| {
        Error::new(
            ErrorKind::InvalidData,
            format!("{size} bytes, more than the {max_bytes} that {what} may have"),
        )
    };
    if metadata.len() > max_bytes {
        return Err(too_large(metadata.len()));
    }
    let mut bytes = Vec::with_capacity(metadata.len() as usize);
    // At most one byte past the limit, should the file grow after the stat.
    (std::fs::File::open(path)?)
        .take(max_bytes + 1)
        .read_to_end(&mut bytes)?;
    if bytes.len() as u64 > max_bytes {
        return Err(too_large(bytes.len() as u64));
    }
    Ok(bytes)
}

/// The metadata of `path` (links followed) if it is a regular file; else an error that says
/// `what` must be one. Stat before opening: opening a FIFO blocks until something writes to it.
fn regular_file_metadata(path: &Path, what: &str) -> std::io::Result<std::fs::Metadata> {
    let metadata = std::fs::metadata(path)?;
    if !metadata.is_file() {
        return Err(Error::new(
            ErrorKind::InvalidInput,
            format!(
                "not a regular file (a directory, pipe, socket or device); {what} must be a file"
            ),
        ));
    }
    Ok(metadata)
}

/// Opens `path` for reading if it is a regular file (links followed), for readers that stream
/// a file and bound what they read themselves (an image decoder that checks the declared size
/// first). `what` names the kind of file in the error.
pub fn open_regular_file(path: &Path, what: &str) -> std::io::Result<std::fs::File> {
    regular_file_metadata(path, what)?;
    std::fs::File::open(path)
}

/// [`read_regular_file`] for a text file: an error also if it is not UTF-8.
pub fn read_regular_text(path: &Path, max_bytes: u64, what: &str) -> std::io::Result<String> {
    String::from_utf8(read_regular_file(path, max_bytes, what)?).map_err(|e| {
        Error::new(
            ErrorKind::InvalidData,
            format!(
                "not UTF-8 text (byte {} is not valid UTF-8); {what} is text",
                e.utf8_error().valid_up_to()
            ),
        )
    })
}

/// The files a command reads, identified by device and inode once (at construction), so that
/// checking an output against them costs one `stat` of the output, however many inputs a
/// sequence has (`render` checks two outputs per frame). Outputs already opened can be added
/// ([`InputFiles::protect_output`]): a second output on the same file would overwrite the
/// first.
pub struct InputFiles {
    /// (device, inode) → the path and, for an output, its option.
    by_id: std::collections::HashMap<(u64, u64), (PathBuf, Option<String>)>,
}

impl InputFiles {
    /// The inputs `paths`; a path that cannot be read is left out (it cannot be overwritten
    /// through another name either).
    pub fn new(paths: &[PathBuf]) -> Self {
        let mut by_id = std::collections::HashMap::with_capacity(paths.len());
        for path in paths {
            if let Ok(meta) = std::fs::metadata(path) {
                by_id
                    .entry((meta.dev(), meta.ino()))
                    .or_insert_with(|| (path.clone(), None));
            }
        }
        Self { by_id }
    }

    /// Adds the output `path` (given with `option`), once created, to the files no later
    /// output may be.
    pub fn protect_output(&mut self, path: &Path, option: &str) {
        if let Ok(meta) = std::fs::metadata(path) {
            self.by_id
                .entry((meta.dev(), meta.ino()))
                .or_insert_with(|| (path.to_path_buf(), Some(option.to_owned())));
        }
    }

    /// Fails when `output` (given with `option`) is one of the inputs (or a protected output):
    /// the same file (device and inode), whatever names or links lead to it. A path that does
    /// not exist yet is no input.
    pub fn refuse(&self, output: &Path, option: &str) -> std::io::Result<()> {
        let Ok(out) = std::fs::metadata(output) else {
            return Ok(());
        };
        match self.by_id.get(&(out.dev(), out.ino())) {
            Some((input, None)) => Err(Error::new(
                ErrorKind::InvalidInput,
                format!(
                    "{option} {} is the input file {}: writing it would destroy the input; \
                     choose another output path",
                    output.display(),
                    input.display()
                ),
            )),
            Some((other, Some(other_option))) => Err(Error::new(
                ErrorKind::InvalidInput,
                format!(
                    "{option} {} is also the {other_option} output {}: the two outputs would \
                     overwrite each other; choose another output path",
                    output.display(),
                    other.display()
                ),
            )),
            None => Ok(()),
        }
    }
}

/// Fails if `path` exists and is neither a regular file nor a symbolic link (which a rename
/// replaces, leaving its target alone): renaming a new file over it would replace a device,
/// a pipe or a socket; a directory cannot be renamed over at all. `what` names the output.
pub fn check_replaceable(path: &Path, what: &str) -> std::io::Result<()> {
    match std::fs::symlink_metadata(path) {
        Err(e) if e.kind() == ErrorKind::NotFound => Ok(()),
        Err(e) => Err(e),
        Ok(m) if m.is_file() || m.file_type().is_symlink() => Ok(()),
        Ok(m) => Err(Error::new(
            ErrorKind::InvalidInput,
            format!(
                "{what} is replaced by renaming a new file over it, but this path is {}; give \
                 the path of a regular file",
                if m.is_dir() {
                    "a directory"
                } else {
                    "a device, pipe or socket"
                }
            ),
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// An output is refused under every name that leads to an input (the path itself, a
    /// symbolic link, a hard link), the input named in the message; other files and paths that
    /// do not exist yet pass.
    #[test]
    fn inputs_are_found_under_any_name() {
        let dir = tempfile::tempdir().unwrap();
        let input = dir.path().join("frame_0001.exr");
        let other = dir.path().join("other.exr");
        std::fs::write(&input, b"input").unwrap();
        std::fs::write(&other, b"other").unwrap();
        let symlink = dir.path().join("symlink.exr");
        std::os::unix::fs::symlink(&input, &symlink).unwrap();
        let hard_link = dir.path().join("hard.exr");
        std::fs::hard_link(&input, &hard_link).unwrap();
        let missing = dir.path().join("missing.exr");
        let inputs = InputFiles::new(&[missing.clone(), input.clone()]);
        for output in [&input, &symlink, &hard_link] {
            let err = inputs.refuse(output, "--out").unwrap_err().to_string();
            let names_input = format!("is the input file {}", input.display());
            assert!(
                err.starts_with("--out") && err.contains(&names_input),
                "{err}"
            );
        }
        inputs.refuse(&other, "--out").unwrap();
        inputs.refuse(&dir.path().join("new.exr"), "--out").unwrap();
        assert_eq!(std::fs::read(&input).unwrap(), b"input");
    }

    #[test]
    fn reads_a_file_within_the_limit_and_refuses_one_beyond_it() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.txt");
        std::fs::write(&path, b"12345").unwrap();
        assert_eq!(read_regular_file(&path, 5, "a test").unwrap(), b"12345");
        let e = read_regular_file(&path, 4, "a test").unwrap_err();
        assert_eq!(e.kind(), ErrorKind::InvalidData);
        assert!(e.to_string().contains("5 bytes, more than the 4"), "{e}");
    }

    #[test]
    fn a_sparse_terabyte_is_refused_before_it_is_read() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("big.bin");
        let file = std::fs::File::create(&path).unwrap();
        file.set_len(1 << 40).unwrap();
        let e = read_regular_file(&path, 1 << 30, "a buffer").unwrap_err();
        assert!(e.to_string().contains("1099511627776 bytes"), "{e}");
    }

    #[test]
    fn devices_directories_and_fifos_are_not_read() {
        let dir = tempfile::tempdir().unwrap();
        for path in [Path::new("/dev/zero"), dir.path()] {
            let e = read_regular_file(path, 1 << 20, "a scene").unwrap_err();
            assert!(
                e.to_string().contains("not a regular file"),
                "{}: {e}",
                path.display()
            );
        }
        let fifo = dir.path().join("pipe.hdr");
        let made = std::process::Command::new("mkfifo")
            .arg(&fifo)
            .status()
            .unwrap();
        assert!(made.success());
        let e = read_regular_file(&fifo, 1 << 20, "a frame").unwrap_err();
        assert!(e.to_string().contains("not a regular file"), "{e}");
        let e = open_regular_file(&fifo, "a bracket").unwrap_err();
        assert!(e.to_string().contains("a bracket must be a file"), "{e}");
        assert!(open_regular_file(Path::new("/dev/zero"), "an image").is_err());
        let link = dir.path().join("zero.obj");
        std::os::unix::fs::symlink("/dev/zero", &link).unwrap();
        assert!(read_regular_file(&link, 1 << 20, "a scene").is_err());
    }

    #[test]
    fn only_regular_files_links_and_new_paths_are_replaceable() {
        let dir = tempfile::tempdir().unwrap();
        let file = dir.path().join("a.json");
        assert!(check_replaceable(&file, "--latest").is_ok());
        std::fs::write(&file, b"{}").unwrap();
        assert!(check_replaceable(&file, "--latest").is_ok());
        let link = dir.path().join("link.json");
        std::os::unix::fs::symlink("/dev/null", &link).unwrap();
        assert!(check_replaceable(&link, "--latest").is_ok());
        for path in [Path::new("/dev/null"), dir.path()] {
            let e = check_replaceable(path, "--latest").unwrap_err().to_string();
            assert!(e.contains("--latest is replaced by renaming"), "{e}");
        }
    }

    #[test]
    fn text_must_be_utf8() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.txt");
        std::fs::write(&path, b"ab\xffcd").unwrap();
        let e = read_regular_text(&path, 100, "a curve").unwrap_err();
        assert!(e.to_string().contains("byte 2"), "{e}");
    }
}
