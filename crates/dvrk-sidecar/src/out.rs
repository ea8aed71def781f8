//! Writing a command's output to stdout, where the reader may go away (issue 22:
//! `dvrk-sidecar echo PSM1/measured_js --json | head -1` aborted with SIGABRT: `println!`
//! panics on EPIPE, and release builds abort on panic).
//!
//! Commands write with [`outln!`](crate::outln) to a locked stdout; a write that fails because
//! the reader closed the pipe becomes [`StdoutClosed`], which `main` turns into a clean exit
//! with status 0: the reader took what it wanted, so nothing failed (as `yes | head -1` ends
//! without an error message). Status 0 rather than the shell's 141 (128 + SIGPIPE) keeps
//! `set -o pipefail` scripts such as `dvrk-sidecar echo ... --json | head -1` working, and the
//! command exits as soon as the write fails instead of being killed mid-way. Any other write
//! error is reported as "writing to stdout" with its cause.

use std::io::ErrorKind;

/// The reader of stdout closed it (EPIPE): the command stops and exits with status 0.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StdoutClosed;

impl std::fmt::Display for StdoutClosed {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("stdout was closed by its reader")
    }
}

impl std::error::Error for StdoutClosed {}

/// The error of a failed write to stdout: [`StdoutClosed`] for a closed pipe.
pub fn stdout_error(e: std::io::Error) -> anyhow::Error {
    if e.kind() == ErrorKind::BrokenPipe {
        anyhow::Error::new(StdoutClosed)
    } else {
        anyhow::Error::new(e).context("writing to stdout")
    }
}

/// Whether `e` (or any error it wraps) is [`StdoutClosed`].
pub fn is_stdout_closed(e: &anyhow::Error) -> bool {
    e.chain().any(|c| c.is::<StdoutClosed>())
}

/// `writeln!` to a locked stdout, with the error mapped by [`stdout_error`]:
/// `outln!(out, "x = {x}")?;`.
#[macro_export]
macro_rules! outln {
    ($out:expr, $($arg:tt)*) => {
        ::std::io::Write::write_fmt(&mut $out, format_args!("{}\n", format_args!($($arg)*)))
            .map_err($crate::out::stdout_error)
    };
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_broken_pipe_is_stdout_closed_and_other_errors_are_not() {
        let e = stdout_error(std::io::Error::from(ErrorKind::BrokenPipe));
        assert!(is_stdout_closed(&e.context("echo")));
        let e = stdout_error(std::io::Error::from(ErrorKind::StorageFull));
        assert!(!is_stdout_closed(&e));
        assert!(format!("{e:#}").contains("writing to stdout"), "{e:#}");
    }
}
