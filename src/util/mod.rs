//! Small services below every other layer: content hashes (`hash`), atomic file writes and
//! temporary names (`fs`), the one way to open an input file (`input`), and the process's memory
//! figures (`mem`), text from input made safe to print (`text`). Nothing here knows a scene,
//! a method or a render.
pub mod fs;
pub mod hash;
pub mod input;
pub mod mem;
pub mod text;

/// `println!` that does not panic when standard output is closed (piped into `head`, a log
/// shipper that exited): the line is dropped and the work goes on. `println!` panicked with
/// exit 101 after a render had written its frames. Any other failure (a full disk under
/// `> file`) is kept for `stdout_error`.
#[macro_export]
macro_rules! outln {
    ($($arg:tt)*) => {{
        let mut line = format!($($arg)*);
        line.push('\n');
        $crate::util::write_stdout($crate::util::text::screen_safe(&line).as_bytes());
    }};
}

/// The first failure to write standard output other than a closed pipe (see `outln!`).
static STDOUT_ERROR: std::sync::Mutex<Option<String>> = std::sync::Mutex::new(None);

/// `bytes` to standard output, flushed; a closed pipe is ignored, another failure kept.
pub fn write_stdout(bytes: &[u8]) {
    use std::io::Write;
    let mut out = std::io::stdout().lock();
    if let Err(e) = out.write_all(bytes).and_then(|()| out.flush()) {
        stdout_failed(e);
    }
}

/// A failure to write standard output (by `write_stdout`, or by a library that writes there
/// itself: clap's `--help`), kept for `stdout_error` unless it is a closed pipe.
pub fn stdout_failed(e: std::io::Error) {
    if e.kind() != std::io::ErrorKind::BrokenPipe {
        let mut first = STDOUT_ERROR.lock().unwrap_or_else(|p| p.into_inner());
        first.get_or_insert(e.to_string());
    }
}

/// Why standard output could not be written, if it could not (not a closed pipe): the command
/// line then exits non-zero, since what it printed (a `bench` table sent to a file) is lost.
pub fn stdout_error() -> Option<String> {
    STDOUT_ERROR
        .lock()
        .unwrap_or_else(|p| p.into_inner())
        .clone()
}

/// `eprintln!` that does not panic when standard error is closed (see `outln!`), written to
/// standard error as the process started with it (`sys::write_stderr`).
#[macro_export]
macro_rules! errln {
    ($($arg:tt)*) => {{
        let mut line = format!($($arg)*);
        line.push('\n');
        let _ = $crate::sys::write_stderr($crate::util::text::screen_safe(&line).as_bytes());
    }};
}
