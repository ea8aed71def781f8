//! Reading the files a user names (configuration, parameters, scenarios, data), bounded and
//! without blocking, and quoting them in errors without flooding the terminal (issue 22).
//!
//! - Only a regular file is read: a FIFO without a writer would block `open(2)` forever, a
//!   device such as `/dev/zero` would never end. The type is checked with `metadata` before the
//!   file is opened, and again on the open descriptor (`O_NONBLOCK`, so even a FIFO swapped in
//!   between the two cannot block the open).
//! - At most a stated number of bytes is read ([`CONFIG_MAX_BYTES`], [`DATA_MAX_BYTES`]); a
//!   larger file is refused with the bound in the message.
//! - An error quotes at most [`MAX_QUOTED_CHARS`] characters of the input.

use std::fs::File;
use std::io::Read;
use std::os::unix::fs::{FileTypeExt, OpenOptionsExt};
use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};

/// Largest configuration, parameter, scenario or io file read (16 MiB): the largest real one,
/// a dVRK sawRobotIO1394 JSON, is about 30 kB.
pub const CONFIG_MAX_BYTES: u64 = 16 << 20;

/// Largest calibration or dynamics data file read (1 GiB): an hour of 1 kHz dynamics samples
/// is about 300 MB; the 2017 clamp recordings are 200 kB.
pub const DATA_MAX_BYTES: u64 = 1 << 30;

/// Longest piece of the input an error message quotes (characters).
pub const MAX_QUOTED_CHARS: usize = 200;

/// What a non-regular file is, for the error that refuses it.
pub fn kind(ft: std::fs::FileType) -> &'static str {
    if ft.is_dir() {
        "a directory"
    } else if ft.is_fifo() {
        "a named pipe (FIFO)"
    } else if ft.is_char_device() {
        "a character device"
    } else if ft.is_block_device() {
        "a block device"
    } else if ft.is_socket() {
        "a socket"
    } else {
        "not a regular file"
    }
}

fn mib(bytes: u64) -> u64 {
    bytes >> 20
}

/// Opens `path` for reading if it is a regular file (symbolic links followed) of at most
/// `max_bytes`; anything else is refused, naming the path and what it is.
pub fn open_regular(path: &Path, max_bytes: u64) -> Result<Bounded> {
    let meta =
        std::fs::metadata(path).with_context(|| format!("cannot read {}", path.display()))?;
    if !meta.file_type().is_file() {
        bail!(
            "{} is {}; only a regular file is read",
            path.display(),
            kind(meta.file_type())
        );
    }
    let file = std::fs::OpenOptions::new()
        .read(true)
        .custom_flags(libc::O_NONBLOCK)
        .open(path)
        .with_context(|| format!("cannot open {}", path.display()))?;
    let meta = file
        .metadata()
        .with_context(|| format!("cannot read {}", path.display()))?;
    if !meta.file_type().is_file() {
        bail!(
            "{} is {}; only a regular file is read",
            path.display(),
            kind(meta.file_type())
        );
    }
    if meta.len() > max_bytes {
        bail!(
            "{} is {} bytes, more than the {} MiB read from such a file",
            path.display(),
            meta.len(),
            mib(max_bytes)
        );
    }
    Ok(Bounded {
        file,
        left: max_bytes,
        max_bytes,
        path: path.to_path_buf(),
    })
}

/// Reads a regular text file of at most `max_bytes` (see [`open_regular`]).
pub fn read_text(path: &Path, max_bytes: u64) -> Result<String> {
    let mut s = String::new();
    open_regular(path, max_bytes)?
        .read_to_string(&mut s)
        .with_context(|| format!("cannot read {}", path.display()))?;
    Ok(s)
}

/// A file that fails with an error naming it once more than its bound is read (a file that
/// grows after it was opened).
pub struct Bounded {
    file: File,
    left: u64,
    max_bytes: u64,
    path: PathBuf,
}

impl Read for Bounded {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        // One byte past the bound tells a file of exactly the bound from a larger one.
        let want = buf
            .len()
            .min(usize::try_from(self.left + 1).unwrap_or(usize::MAX));
        let n = self.file.read(&mut buf[..want])?;
        if n as u64 > self.left {
            return Err(std::io::Error::other(format!(
                "{} is larger than the {} MiB read from such a file",
                self.path.display(),
                mib(self.max_bytes)
            )));
        }
        self.left -= n as u64;
        Ok(n)
    }
}

/// `s` cut to [`MAX_QUOTED_CHARS`] characters, saying how much was left out.
pub fn quote(s: &str) -> String {
    quote_around(s, 0)
}

/// At most [`MAX_QUOTED_CHARS`] characters of `s` around character `at` (a window that starts
/// up to half the budget before it), marking what was cut on either side.
fn quote_around(s: &str, at: usize) -> String {
    let total = s.chars().count();
    if total <= MAX_QUOTED_CHARS {
        return s.to_owned();
    }
    let start = at
        .saturating_sub(MAX_QUOTED_CHARS / 2)
        .min(total - MAX_QUOTED_CHARS);
    let end = start + MAX_QUOTED_CHARS;
    let mut out = String::new();
    if start > 0 {
        out.push_str(&format!("[{start} characters cut]…"));
    }
    out.extend(s.chars().skip(start).take(MAX_QUOTED_CHARS));
    if end < total {
        out.push_str(&format!("…[{} characters cut]", total - end));
    }
    out
}

/// A TOML parse or schema error as one bounded message: `line L, column C: <message>` and the
/// offending line, where both the message (which may quote a value) and the line are cut to
/// [`MAX_QUOTED_CHARS`] characters. The `toml` crate's own `Display` quotes the whole line, and
/// a message that quotes a value quotes it again: a 50 MB line became 100 MB on stderr.
pub fn toml_error(text: &str, mut e: toml::de::Error) -> anyhow::Error {
    let span = e.span();
    // Without the input, `Display` is the message and the key path (`in `joint.index``).
    e.set_input(None);
    let full = e.to_string();
    let one_line = |s: &str| s.split_whitespace().collect::<Vec<_>>().join(" ");
    // The message and the key path are cut apart, so that a long value in the message does not
    // push the field's name out.
    let keys = full.strip_prefix(e.message()).unwrap_or_default();
    let message = format!(
        "{} {}",
        quote(&one_line(e.message())),
        quote(&one_line(keys))
    );
    let message = message.trim_end();
    let Some(span) = span else {
        return anyhow::anyhow!("{message}");
    };
    let mut start = span.start.min(text.len());
    while !text.is_char_boundary(start) {
        start -= 1;
    }
    let line_start = text[..start].rfind('\n').map_or(0, |i| i + 1);
    let line_end = text[start..].find('\n').map_or(text.len(), |i| start + i);
    let line_no = text[..line_start].bytes().filter(|&b| b == b'\n').count() + 1;
    let column = text[line_start..start].chars().count();
    let line = text[line_start..line_end].trim_end_matches('\r');
    anyhow::anyhow!(
        "line {line_no}, column {}: {message}\n    {line_no} | {}",
        column + 1,
        quote_around(line, column)
    )
}

/// Parses TOML text into `T` with a bounded error (see [`toml_error`]).
pub fn from_toml<T: serde::de::DeserializeOwned>(text: &str) -> Result<T> {
    toml::from_str(text).map_err(|e| toml_error(text, e))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn scratch(name: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("dvrk-files-{}-{name}", std::process::id()));
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    #[test]
    fn a_fifo_a_directory_and_a_device_are_refused_without_blocking() {
        let d = scratch("kinds");
        let fifo = d.join("fifo.toml");
        let c = std::ffi::CString::new(fifo.as_os_str().as_encoded_bytes()).unwrap();
        // SAFETY: mkfifo(3) with a valid NUL-terminated path.
        assert_eq!(unsafe { libc::mkfifo(c.as_ptr(), 0o600) }, 0);
        // Without the check, this read blocks forever (no writer): the test would hang.
        let e = read_text(&fifo, CONFIG_MAX_BYTES).unwrap_err().to_string();
        assert!(e.contains("fifo.toml") && e.contains("named pipe"), "{e}");
        let e = read_text(&d, CONFIG_MAX_BYTES).unwrap_err().to_string();
        assert!(e.contains("is a directory"), "{e}");
        let e = read_text(Path::new("/dev/zero"), CONFIG_MAX_BYTES)
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("/dev/zero") && e.contains("character device"),
            "{e}"
        );
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[test]
    fn a_file_over_the_bound_is_refused_naming_the_bound() {
        let d = scratch("big");
        let f = d.join("big.csv");
        std::fs::write(&f, vec![b'x'; 2 << 20]).unwrap();
        let e = read_text(&f, 1 << 20).unwrap_err().to_string();
        assert!(e.contains("big.csv") && e.contains("1 MiB"), "{e}");
        assert_eq!(read_text(&f, 2 << 20).unwrap().len(), 2 << 20);
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[test]
    fn a_huge_bad_line_is_quoted_once_and_cut() {
        #[derive(Debug, serde::Deserialize)]
        #[allow(dead_code)]
        struct T {
            a: f64,
        }
        let huge = "x".repeat(1_000_000);
        let text = format!("a = \"{huge}\"\n");
        let e = format!("{:#}", from_toml::<T>(&text).unwrap_err());
        assert!(e.len() < 5 * MAX_QUOTED_CHARS, "{} bytes: {e}", e.len());
        assert!(
            e.contains("line 1") && e.contains("characters cut") && e.contains("in `a`"),
            "{e}"
        );
        // A short error keeps its line whole.
        let e = format!("{:#}", from_toml::<T>("\n\na = [1.0]\n").unwrap_err());
        assert!(e.contains("line 3") && e.contains("a = [1.0]"), "{e}");
    }
}
