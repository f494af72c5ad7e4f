//! The process's own FFI: the C library calls Rust's standard library does not offer.
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

/// Ignore SIGXFSZ, so that a write past the file size limit (`ulimit -f`, which Slurm passes
/// on to jobs) fails with EFBIG and takes the error path that names the file and removes the
/// temporaries, as a full disk does; its default action killed the process silently (exit
/// 153), leaving temporaries, locks and an empty checkpoint folder.
pub fn ignore_file_size_signal() {
    // SAFETY: setting a signal's disposition to "ignore" runs no handler and touches no Rust
    // state.
    unsafe { libc::signal(libc::SIGXFSZ, libc::SIG_IGN) };
}

/// Let the C library's allocator keep at most `n` arenas. Each arena a thread opens reserves
/// 64 MB of address space up front (glibc), and with one per thread of Embree's, rayon's and
/// OpenImageIO's pools the address space a run maps moves by hundreds of megabytes with the
/// threads' timing: under `ulimit -v` that made a small render fit in one run and fail in the
/// next. Call it before any thread starts.
pub fn limit_malloc_arenas(n: i32) {
    // SAFETY: `mallopt` sets an allocator parameter; it touches no Rust state.
    unsafe { libc::mallopt(libc::M_ARENA_MAX, n) };
}

/// Standard error as the process started with it: a copy of descriptor 2 (`keep_stderr`), made
/// before any reader quiets descriptor 2 (`QuietStderr` in `ffi/oiio.cpp` points it at
/// /dev/null while a codec may print), or -1.
static STDERR: std::sync::OnceLock<i32> = std::sync::OnceLock::new();

/// Keep a copy of standard error for `write_stderr`; call first thing.
pub fn keep_stderr() {
    // SAFETY: `fcntl` duplicates a descriptor (or fails with -1); nothing else is touched.
    STDERR.get_or_init(|| unsafe { libc::fcntl(2, libc::F_DUPFD_CLOEXEC, 3) });
}

/// Write `bytes` to standard error as the process started with it: reframe's own lines, so that
/// one written while a reader has quieted descriptor 2 (an interrupt's, from the signal thread,
/// while textures load) is not lost. Without `keep_stderr`, to descriptor 2.
pub fn write_stderr(bytes: &[u8]) -> std::io::Result<()> {
    use std::os::fd::FromRawFd;
    match STDERR.get() {
        Some(&fd) if fd >= 0 => {
            // SAFETY: `fd` is our own copy, open for the life of the process; the `File` is
            // never dropped, so it is never closed.
            let f = std::mem::ManuallyDrop::new(unsafe { std::fs::File::from_raw_fd(fd) });
            (&*f).write_all(bytes)
        }
        _ => std::io::stderr().write_all(bytes),
    }
}

/// The line to print if the process aborts while a file is being read (`reading`): a pointer to
/// its bytes (leaked, never freed, so that a handler running at any moment reads valid memory)
/// and their length; null while no file is being read.
static CRASH_LINE: std::sync::atomic::AtomicPtr<u8> =
    std::sync::atomic::AtomicPtr::new(std::ptr::null_mut());
static CRASH_LINE_LEN: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);

/// While held, an abort (SIGABRT) names the file being read. OpenImageIO 2.4 aborts on some
/// files (a tiled CMYK TIFF with JPEG tiles corrupted its heap; a PSD its reader could not open
/// made the RLA reader assert), and the process ended with status 134 and nothing said.
pub struct Reading(());

impl Drop for Reading {
    fn drop(&mut self) {
        CRASH_LINE.store(std::ptr::null_mut(), std::sync::atomic::Ordering::SeqCst);
    }
}

/// `line` is what an abort prints until the guard is dropped (`say_aborts` installs the
/// handler; the caller words it, naming the file).
pub fn reading(line: String) -> Reading {
    let bytes: &'static mut [u8] = Box::leak(line.into_bytes().into_boxed_slice());
    CRASH_LINE.store(std::ptr::null_mut(), std::sync::atomic::Ordering::SeqCst);
    CRASH_LINE_LEN.store(bytes.len(), std::sync::atomic::Ordering::SeqCst);
    CRASH_LINE.store(bytes.as_mut_ptr(), std::sync::atomic::Ordering::SeqCst);
    Reading(())
}

/// The SIGABRT handler: the line of the file being read, if any, to standard error as the
/// process started with it, then the default action (the process ends by SIGABRT, as it
/// would have). Only async-signal-safe calls: atomic loads, `write`, `signal`, `raise`.
extern "C" fn on_abort(sig: libc::c_int) {
    let p = CRASH_LINE.load(std::sync::atomic::Ordering::SeqCst);
    if !p.is_null() {
        let n = CRASH_LINE_LEN.load(std::sync::atomic::Ordering::SeqCst);
        let fd = STDERR.get().copied().filter(|&fd| fd >= 0).unwrap_or(2);
        // SAFETY: `p` points to `n` leaked bytes that are never freed; `write`, `signal` and
        // `raise` are async-signal-safe.
        unsafe { libc::write(fd, p as *const libc::c_void, n) };
    }
    // SAFETY: as above.
    unsafe {
        libc::signal(sig, libc::SIG_DFL);
        libc::raise(sig);
    }
}

/// The faults a library's decoder can end the process with while it reads a damaged file
/// (OpenImageIO 2.4's Softimage PIC and Maya IFF readers read and write out of bounds), and
/// the action each had before `say_aborts` (Rust's own: the stack overflow report).
const FAULTS: [libc::c_int; 4] = [libc::SIGSEGV, libc::SIGBUS, libc::SIGFPE, libc::SIGILL];
static mut PREVIOUS: [std::mem::MaybeUninit<libc::sigaction>; 4] =
    [std::mem::MaybeUninit::uninit(); 4];

/// The handler of a fault (`FAULTS`): while a file is read, its line (as `on_abort`), then the
/// default action; otherwise the action there was before, restored, so that the fault, which
/// happens again as the handler returns, is handled as it would have been. Only
/// async-signal-safe calls.
extern "C" fn on_fault(sig: libc::c_int, _: *mut libc::siginfo_t, _: *mut libc::c_void) {
    let p = CRASH_LINE.load(std::sync::atomic::Ordering::SeqCst);
    if !p.is_null() {
        on_abort(sig);
        return;
    }
    if let Some(k) = FAULTS.iter().position(|&f| f == sig) {
        // SAFETY: `PREVIOUS[k]` was written by `sigaction` before this handler was installed
        // for `sig`, and is never written again; `sigaction` is async-signal-safe.
        unsafe {
            let previous = (*std::ptr::addr_of!(PREVIOUS))[k].as_ptr();
            libc::sigaction(sig, previous, std::ptr::null_mut());
        }
    }
}

/// Install the handlers that name the file being read when a library aborts or faults while
/// reading it (`reading`).
pub fn say_aborts() {
    let handler = on_abort as extern "C" fn(libc::c_int) as libc::sighandler_t;
    // SAFETY: `on_abort` makes only async-signal-safe calls.
    unsafe { libc::signal(libc::SIGABRT, handler) };
    for (k, &sig) in FAULTS.iter().enumerate() {
        // SAFETY: called once, at start, before any other thread runs; `PREVIOUS[k]` is written
        // by `sigaction` before the handler that reads it is installed. On the alternate signal
        // stack (`SA_ONSTACK`), where Rust runs its own, so that a stack overflow still reaches
        // Rust's report.
        unsafe {
            let mut action: libc::sigaction = std::mem::zeroed();
            action.sa_sigaction = on_fault
                as extern "C" fn(libc::c_int, *mut libc::siginfo_t, *mut libc::c_void)
                as libc::sighandler_t;
            action.sa_flags = libc::SA_SIGINFO | libc::SA_ONSTACK;
            libc::sigemptyset(&mut action.sa_mask);
            let previous = (*std::ptr::addr_of_mut!(PREVIOUS))[k].as_mut_ptr();
            if libc::sigaction(sig, std::ptr::null(), previous) == 0 {
                libc::sigaction(sig, &action, std::ptr::null_mut());
            }
        }
    }
}
