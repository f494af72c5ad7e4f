//! The process's own FFI: the one C library call Rust's standard library does not offer.
//!
//! `std::process::exit` runs the C library's exit handlers, among them the C++ static
//! destructors of Embree, OpenImageIO and Open Image Denoise. A stop by signal exits while
//! worker threads are still inside those libraries, and a destructor pulled from under a
//! running thread ends the process with "pure virtual method called" and SIGABRT instead of
//! the status that was promised. `_exit` ends the process without running anything.
use std::io::Write;

/// End the process now with `code`, running no exit handler and no destructor; what Rust has
/// buffered for stdout is flushed first (stderr is unbuffered).
pub fn exit_now(code: i32) -> ! {
    let _ = std::io::stdout().flush();
    // SAFETY: `_exit` takes any status and never returns; it touches no Rust state.
    unsafe { libc::_exit(code) }
}
