//! Intel Open Image Denoise (OIDN 2.x), loaded at run time: the library is opened when a render
//! asks for `--denoise` (before its first ray), so the binary runs without it and a missing or
//! broken library is one line at start. This module holds the FFI and its unsafe code; the rest
//! of reframe sees `Denoiser::load` and `Denoiser::denoise`.
//!
//! Where the library is looked for, first found wins: `$REFRAME_OIDN_LIB` (a path to
//! `libOpenImageDenoise.so.2`), the runtime `setup.sh` unpacked into `.deps/oidn/lib` (its path
//! is fixed at build time), then the system's loader path.
use crate::util::input::{open_input_or_missing, InputError};
use anyhow::{anyhow, bail, Context, Result};
use libloading::Library;
use std::ffi::{c_char, c_void, CStr, CString};
use std::path::PathBuf;

type Handle = *mut c_void;

/// `OIDN_DEVICE_TYPE_CPU`.
const DEVICE_TYPE_CPU: i32 = 1;
/// `OIDN_FORMAT_FLOAT3`.
const FORMAT_FLOAT3: i32 = 3;
/// `OIDN_ERROR_NONE`.
const ERROR_NONE: i32 = 0;

/// The OIDN 2 C API functions reframe calls (oidn.h), resolved from the loaded library.
struct Api {
    new_device: unsafe extern "C" fn(i32) -> Handle,
    set_device_int: unsafe extern "C" fn(Handle, *const c_char, i32),
    set_device_bool: unsafe extern "C" fn(Handle, *const c_char, bool),
    commit_device: unsafe extern "C" fn(Handle),
    get_device_error: unsafe extern "C" fn(Handle, *mut *const c_char) -> i32,
    release_device: unsafe extern "C" fn(Handle),
    new_filter: unsafe extern "C" fn(Handle, *const c_char) -> Handle,
    #[allow(clippy::type_complexity)]
    set_shared_filter_image: unsafe extern "C" fn(
        Handle,
        *const c_char,
        *mut c_void,
        i32,
        usize,
        usize,
        usize,
        usize,
        usize,
    ),
    set_filter_bool: unsafe extern "C" fn(Handle, *const c_char, bool),
    set_filter_int: unsafe extern "C" fn(Handle, *const c_char, i32),
    commit_filter: unsafe extern "C" fn(Handle),
    execute_filter: unsafe extern "C" fn(Handle),
    release_filter: unsafe extern "C" fn(Handle),
}

/// The most scratch memory a filter may take, in MB (OIDN's `maxMemoryMB`; its default grows
/// with the frame).
pub const MAX_SCRATCH_MB: i32 = 1024;

/// Bytes per pixel a denoised frame holds besides the render's own: the filter's colour,
/// albedo, normal and output images and the traced guides (RGB f32 each), and the colour
/// handed to the filter.
pub const BYTES_PER_PIXEL: u64 = 7 * 12;

/// An OIDN CPU device, ready to denoise frames. Filters are made per frame (a frame's size may
/// differ from the last one's); the device and its threads are made once.
pub struct Denoiser {
    api: Api,
    device: Handle,
    /// Where the library was loaded from (for messages and `--stats`).
    pub library: PathBuf,
    /// The filters of the last frame size.
    filters: Option<Filters>,
    // Keeps the library mapped while `api`'s pointers are in use; dropped last.
    _lib: Library,
}

// The device handle is used by one thread at a time (`&mut self`), and OIDN's API is
// thread-safe.
unsafe impl Send for Denoiser {}

/// The noisy frame and its guides, each `width * height` RGB triples, row-major.
pub struct DenoiseInput<'a> {
    pub width: usize,
    pub height: usize,
    pub color: &'a [f32],
    /// The first surface's reflectance per pixel, in [0, 1].
    pub albedo: &'a [f32],
    /// The first surface's shading normal per pixel, in [-1, 1] (0 where a ray escaped).
    pub normal: &'a [f32],
}

fn candidates() -> Vec<PathBuf> {
    let mut c = Vec::new();
    // Set but empty counts as unset: an empty name would make the loader return the program
    // itself.
    if let Some(p) = std::env::var_os("REFRAME_OIDN_LIB").filter(|p| !p.is_empty()) {
        // A bare name that is a file in the current folder is that file, checked as one (the
        // loader would search its library path for it instead: a FIFO of that name was "No such
        // file"); one that is not there is left to the loader's search (`libm.so.6`).
        let p = PathBuf::from(p);
        let bare = p.components().count() == 1 && p.is_relative();
        c.push(if bare && std::fs::symlink_metadata(&p).is_ok() {
            std::path::Path::new(".").join(p)
        } else {
            p
        });
        return c;
    }
    if let Some(dir) = option_env!("REFRAME_OIDN_DIR") {
        c.push(PathBuf::from(dir).join("libOpenImageDenoise.so.2"));
    }
    c.push(PathBuf::from("libOpenImageDenoise.so.2"));
    c
}

/// `lib` and the files beside it that OIDN loads with it (its core and device libraries, and
/// TBB), where they are there.
fn libraries_beside(lib: &std::path::Path) -> Vec<PathBuf> {
    let mut out = vec![lib.to_path_buf()];
    let dir = lib.parent().unwrap_or(std::path::Path::new("."));
    if let Ok(entries) = std::fs::read_dir(dir) {
        for e in entries.flatten() {
            let name = e.file_name().to_string_lossy().into_owned();
            let ours = name.starts_with("libOpenImageDenoise") || name.starts_with("libtbb");
            if ours && name.contains(".so") && e.path() != lib {
                out.push(e.path());
            }
        }
    }
    out
}

/// Whether the 64-bit little-endian ELF file at `path` holds everything its headers say it
/// has: its program headers, the bytes its segments map from the file, and its section
/// headers. `Err`: what is wrong, naming the file.
fn elf_whole(path: &std::path::Path) -> std::result::Result<(), String> {
    use std::os::unix::fs::FileExt;
    let bad = |why: &str| format!("{}: {why}", path.display());
    let f = crate::util::fs::open_regular(path).map_err(|e| bad(&e.to_string()))?;
    let size = f.metadata().map_err(|e| bad(&e.to_string()))?.len();
    let mut h = [0u8; 64];
    f.read_exact_at(&mut h, 0)
        .map_err(|_| bad("cut short: not even an ELF header (a copy interrupted?)"))?;
    if &h[..4] != b"\x7fELF" || h[4] != 2 || h[5] != 1 {
        return Err(bad("not a 64-bit little-endian ELF shared library"));
    }
    let u16_at = |b: &[u8], o: usize| u16::from_le_bytes([b[o], b[o + 1]]) as u64;
    let u64_at = |b: &[u8], o: usize| u64::from_le_bytes(b[o..o + 8].try_into().unwrap());
    let (phoff, phentsize, phnum) = (u64_at(&h, 0x20), u16_at(&h, 0x36), u16_at(&h, 0x38));
    let (shoff, shentsize, shnum) = (u64_at(&h, 0x28), u16_at(&h, 0x3a), u16_at(&h, 0x3c));
    let mut end = phoff.saturating_add(phentsize * phnum);
    if shoff > 0 {
        end = end.max(shoff.saturating_add(shentsize * shnum));
    }
    if phentsize >= 40 && phoff.saturating_add(phentsize * phnum) <= size {
        let mut ph = vec![0u8; (phentsize * phnum) as usize];
        f.read_exact_at(&mut ph, phoff)
            .map_err(|e| bad(&e.to_string()))?;
        for e in ph.chunks_exact(phentsize as usize) {
            // p_offset at 8, p_filesz at 32.
            end = end.max(u64_at(e, 8).saturating_add(u64_at(e, 32)));
        }
    }
    if end > size {
        return Err(bad(&format!(
            "cut short: its headers reach byte {end}, the file has {size} (a copy or an \
             unpacking interrupted? run ./setup.sh again)"
        )));
    }
    Ok(())
}

/// The largest side of an image Open Image Denoise filters: 65537 pixels and more fail when the
/// filter is set up ("image size is too large"), which was after the first frame's rendering.
pub const MAX_SIDE: u32 = 65536;

/// Refuse, before anything is rendered, a frame of `w` x `h` that the denoiser cannot filter.
pub fn check_size(flag: &str, (w, h): (u32, u32)) -> anyhow::Result<()> {
    if w > MAX_SIDE || h > MAX_SIDE {
        anyhow::bail!(
            "{flag}: Open Image Denoise filters images of at most {MAX_SIDE} pixels a side, and \
             the frames are {w}x{h}: render smaller frames, or leave the denoiser out"
        );
    }
    Ok(())
}

impl Denoiser {
    /// Open the library and make a CPU device with `threads` threads (0: OIDN's choice).
    pub fn load(threads: usize, what: &str) -> Result<Denoiser> {
        let mut tried = Vec::new();
        let mut found = None;
        for path in candidates() {
            // A bare name goes to the system's loader; a path must be a regular file, as every
            // input (the loader would wait forever on a FIFO, and read a device).
            if path.components().count() > 1 {
                match open_input_or_missing(&path, "library", u64::MAX) {
                    Ok(_) => {}
                    Err(InputError::NotFound(_)) => {
                        tried.push(format!("{}: no such file", path.display()));
                        continue;
                    }
                    Err(e) => {
                        tried.push(e.to_string());
                        continue;
                    }
                }
            }
            // A shared library cut short (a copy or an unpacking interrupted) is mapped as if
            // whole, and the first page past its end kills the process with SIGBUS, without a
            // word: the library and the ones beside it that it loads are checked first.
            if path.components().count() > 1 {
                if let Err(why) = libraries_beside(&path)
                    .iter()
                    .try_for_each(|l| elf_whole(l))
                {
                    tried.push(why);
                    continue;
                }
            }
            // SAFETY: loading OIDN runs its initialisers, which only register its devices.
            match unsafe { Library::new(&path) } {
                Ok(lib) => {
                    found = Some((lib, path));
                    break;
                }
                Err(e) => tried.push(format!("{}: {e}", path.display())),
            }
        }
        let Some((lib, library)) = found else {
            bail!(
                "{what}: cannot load Open Image Denoise ({}); run ./setup.sh, or set \
                 REFRAME_OIDN_LIB to libOpenImageDenoise.so.2",
                tried.join("; ")
            );
        };
        let api = resolve(&lib).with_context(|| {
            format!("{what}: {} is not Open Image Denoise 2", library.display())
        })?;
        // SAFETY: the functions were resolved from the library with oidn.h's signatures.
        let device = unsafe { (api.new_device)(DEVICE_TYPE_CPU) };
        if device.is_null() {
            bail!(
                "{what}: Open Image Denoise ({}) made no CPU device",
                library.display()
            );
        }
        let d = Denoiser {
            api,
            device,
            library,
            filters: None,
            _lib: lib,
        };
        // SAFETY: a live device; names are NUL-terminated.
        unsafe {
            (d.api.set_device_int)(
                d.device,
                c"numThreads".as_ptr(),
                threads.min(i32::MAX as usize) as i32,
            );
            // Pinning threads would fight rayon's workers for the cores.
            (d.api.set_device_bool)(d.device, c"setAffinity".as_ptr(), false);
            (d.api.commit_device)(d.device);
        }
        d.check("making the CPU device")?;
        Ok(d)
    }

    /// The device's pending error, if any, as an error naming `what`.
    fn check(&self, what: &str) -> Result<()> {
        let mut msg: *const c_char = std::ptr::null();
        // SAFETY: a live device; OIDN writes a pointer to a string it owns (or null).
        let code = unsafe { (self.api.get_device_error)(self.device, &mut msg) };
        if code == ERROR_NONE {
            return Ok(());
        }
        let text = if msg.is_null() {
            String::from("no message")
        } else {
            // SAFETY: OIDN's message is NUL-terminated and valid until the next call.
            unsafe { CStr::from_ptr(msg) }
                .to_string_lossy()
                .into_owned()
        };
        Err(anyhow!(
            "Open Image Denoise failed {what} (error {code}): {text}"
        ))
    }

    /// Make the filters for `width` x `height` frames and run them once on a black frame, so
    /// that a timed first frame does not pay for setting the network up.
    pub fn prepare(&mut self, width: usize, height: usize) -> Result<()> {
        let zeros = vec![0.0f32; width * height * 3];
        self.denoise(&DenoiseInput {
            width,
            height,
            color: &zeros,
            albedo: &zeros,
            normal: &zeros,
        })
        .map(drop)
    }

    /// Denoise `input.color` with OIDN's `RT` filter in HDR mode, guided by the albedo and
    /// normal images, declared noise-free (`cleanAux`): they are averages of first hits, which
    /// vary only across a pixel's footprint (antialiasing), not from sample noise. (Prefiltering
    /// them, OIDN's advice for noisy guides, would take two more passes of the network.)
    pub fn denoise(&mut self, input: &DenoiseInput) -> Result<Vec<f32>> {
        let (w, h) = (input.width, input.height);
        let n = w * h * 3;
        for (name, v) in [
            ("color", input.color),
            ("albedo", input.albedo),
            ("normal", input.normal),
        ] {
            if v.len() != n {
                bail!(
                    "denoise: the {name} image holds {} values, not {n}",
                    v.len()
                );
            }
            if v.iter().any(|x| !x.is_finite()) {
                bail!("denoise: the {name} image has a NaN or infinite value");
            }
        }
        // Filters are expensive to make (their networks are set up for a size): they are kept
        // for the frame size, over buffers whose addresses they hold.
        if self.filters.as_ref().is_none_or(|f| (f.w, f.h) != (w, h)) {
            if let Some(old) = self.filters.take() {
                self.release(old);
            }
            let f = self.make_filters(w, h)?;
            self.filters = Some(f);
        }
        let f = self.filters.as_mut().expect("filters made above");
        let scale = level_scale(input.color);
        if scale == 1.0 {
            f.color.copy_from_slice(input.color);
        } else {
            for (c, &v) in f.color.iter_mut().zip(input.color) {
                *c = v * scale;
            }
        }
        f.albedo.copy_from_slice(input.albedo);
        f.normal.copy_from_slice(input.normal);
        // SAFETY: a committed filter of this device whose images are `f`'s buffers, alive and
        // not moved since they were set (they are never resized).
        unsafe { (self.api.execute_filter)(f.beauty) };
        self.check("denoising the frame")?;
        let output = &self.filters.as_ref().expect("filters made above").output;
        Ok(if scale == 1.0 {
            output.clone()
        } else {
            output.iter().map(|&v| v / scale).collect()
        })
    }

    /// The filter of a `w` x `h` frame over buffers of its own.
    fn make_filters(&mut self, w: usize, h: usize) -> Result<Filters> {
        let n = w * h * 3;
        let mut f = Filters {
            w,
            h,
            color: vec![0.0; n],
            albedo: vec![0.0; n],
            normal: vec![0.0; n],
            output: vec![0.0; n],
            beauty: std::ptr::null_mut(),
        };
        let (pa, pn, pc, po) = (
            f.albedo.as_mut_ptr(),
            f.normal.as_mut_ptr(),
            f.color.as_mut_ptr(),
            f.output.as_mut_ptr(),
        );
        f.beauty = self
            .filter(
                w,
                h,
                &[
                    ("color", pc),
                    ("albedo", pa),
                    ("normal", pn),
                    ("output", po),
                ],
            )
            .context("setting up Open Image Denoise's filter")?;
        Ok(f)
    }

    /// A committed `RT` filter over `images` (name, buffer of `w * h` float triples).
    fn filter(&self, w: usize, h: usize, images: &[(&str, *mut f32)]) -> Result<Handle> {
        // SAFETY: a live device; every buffer holds w * h float triples and lives in the
        // `Filters` that will own the filter (released before the buffers are dropped); names
        // are NUL-terminated.
        unsafe {
            let filter = (self.api.new_filter)(self.device, c"RT".as_ptr());
            if filter.is_null() {
                self.check("making the RT filter")?;
                bail!("Open Image Denoise made no RT filter");
            }
            for (name, buf) in images {
                let cname = CString::new(*name).expect("no NUL in a filter image name");
                (self.api.set_shared_filter_image)(
                    filter,
                    cname.as_ptr(),
                    buf.cast(),
                    FORMAT_FLOAT3,
                    w,
                    h,
                    0,
                    0,
                    0,
                );
            }
            (self.api.set_filter_bool)(filter, c"hdr".as_ptr(), true);
            (self.api.set_filter_bool)(filter, c"cleanAux".as_ptr(), true);
            // Bounded scratch (a large frame is denoised in overlapping tiles), so that the
            // render's memory estimate can count it (`RenderOptions::memory_estimate`).
            (self.api.set_filter_int)(filter, c"maxMemoryMB".as_ptr(), MAX_SCRATCH_MB);
            (self.api.commit_filter)(filter);
            if let Err(e) = self.check("setting up a filter") {
                (self.api.release_filter)(filter);
                return Err(e);
            }
            Ok(filter)
        }
    }

    /// Release `f`'s filters (its buffers go with it).
    fn release(&self, f: Filters) {
        if !f.beauty.is_null() {
            // SAFETY: a filter of this device, released once.
            unsafe { (self.api.release_filter)(f.beauty) };
        }
    }
}

/// The power of two that a frame's colour `color` is multiplied by before it is denoised (and
/// the result divided by after), so that its mean is near 1; 1 where the mean is within
/// `2^-10..2^16` already, or zero. OIDN's auto-exposure (HDR mode) scales a frame by its
/// log-average luminance over the pixels brighter than 1e-8 and filters in half precision: a
/// frame whose pixels are all dimmer than that (a scene lit at 1e-6) came out zero everywhere,
/// without an error. A power of two scales exactly, both ways, short of the float range's ends.
fn level_scale(color: &[f32]) -> f32 {
    let mean = color.iter().map(|&v| v.max(0.0) as f64).sum::<f64>() / color.len().max(1) as f64;
    if mean <= 0.0 || (2f64.powi(-10)..=2f64.powi(16)).contains(&mean) {
        return 1.0;
    }
    // Within f32's normal range both ways (a mean of 1e-38 is scaled by 2^126 at most).
    2f32.powi((-mean.log2().round() as i32).clamp(-126, 126))
}

/// The filters of one frame size and the buffers they read and write.
struct Filters {
    w: usize,
    h: usize,
    color: Vec<f32>,
    albedo: Vec<f32>,
    normal: Vec<f32>,
    output: Vec<f32>,
    beauty: Handle,
}

impl Drop for Denoiser {
    fn drop(&mut self) {
        if let Some(f) = self.filters.take() {
            self.release(f);
        }
        // SAFETY: the device was made by `load` and is released once, after its filters.
        unsafe { (self.api.release_device)(self.device) };
    }
}

/// The API's functions from `lib`.
fn resolve(lib: &Library) -> Result<Api> {
    // SAFETY: each symbol is cast to the signature oidn.h (OIDN 2.x) declares for it.
    unsafe {
        macro_rules! f {
            ($name:literal) => {
                *lib.get($name).map_err(|e| {
                    // The name without the C string's terminating NUL.
                    let name = $name.strip_suffix(b"\0").unwrap_or($name);
                    anyhow!("{}: {e}", String::from_utf8_lossy(name))
                })?
            };
        }
        Ok(Api {
            new_device: f!(b"oidnNewDevice\0"),
            set_device_int: f!(b"oidnSetDeviceInt\0"),
            set_device_bool: f!(b"oidnSetDeviceBool\0"),
            commit_device: f!(b"oidnCommitDevice\0"),
            get_device_error: f!(b"oidnGetDeviceError\0"),
            release_device: f!(b"oidnReleaseDevice\0"),
            new_filter: f!(b"oidnNewFilter\0"),
            set_shared_filter_image: f!(b"oidnSetSharedFilterImage\0"),
            set_filter_bool: f!(b"oidnSetFilterBool\0"),
            set_filter_int: f!(b"oidnSetFilterInt\0"),
            commit_filter: f!(b"oidnCommitFilter\0"),
            execute_filter: f!(b"oidnExecuteFilter\0"),
            release_filter: f!(b"oidnReleaseFilter\0"),
        })
    }
}
