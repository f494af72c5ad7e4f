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
/// exit 101 after a render had written its frames.
#[macro_export]
macro_rules! outln {
    ($($arg:tt)*) => {{
        use std::io::Write as _;
        let _ = writeln!(std::io::stdout(), $($arg)*);
    }};
}

/// `eprintln!` that does not panic when standard error is closed (see `outln!`), written to
/// standard error as the process started with it (`sys::write_stderr`).
#[macro_export]
macro_rules! errln {
    ($($arg:tt)*) => {{
        let mut line = format!($($arg)*);
        line.push('\n');
        let _ = $crate::sys::write_stderr(line.as_bytes());
    }};
}
