//! Intel Open Image Denoise (OIDN 2.x), loaded at run time: the library is opened when a render
//! asks for `--denoise` (before its first ray), so the binary runs without it and a missing or
//! broken library is one line at start. This module holds the FFI and its unsafe code; the rest
//! of reframe sees `Denoiser::load` and `Denoiser::denoise`.
//!
//! Where the library is looked for, first found wins: `$REFRAME_OIDN_LIB` (a path to
//! `libOpenImageDenoise.so.2`), the runtime `setup.sh` unpacked into `.deps/oidn/lib` (its path
//! is fixed at build time), then the system's loader path.
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
    commit_filter: unsafe extern "C" fn(Handle),
    execute_filter: unsafe extern "C" fn(Handle),
    release_filter: unsafe extern "C" fn(Handle),
}

/// An OIDN CPU device, ready to denoise frames. Filters are made per frame (a frame's size may
/// differ from the last one's); the device and its threads are made once.
pub struct Denoiser {
    api: Api,
    device: Handle,
    /// Where the library was loaded from (for messages and `--stats`).
    pub library: PathBuf,
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
    if let Some(p) = std::env::var_os("REFRAME_OIDN_LIB") {
        c.push(PathBuf::from(p));
        return c;
    }
    if let Some(dir) = option_env!("REFRAME_OIDN_DIR") {
        c.push(PathBuf::from(dir).join("libOpenImageDenoise.so.2"));
    }
    c.push(PathBuf::from("libOpenImageDenoise.so.2"));
    c
}

impl Denoiser {
    /// Open the library and make a CPU device with `threads` threads (0: OIDN's choice).
    pub fn load(threads: usize) -> Result<Denoiser> {
        let mut tried = Vec::new();
        let mut found = None;
        for path in candidates() {
            // A bare name goes to the system's loader; a path must exist.
            if path.components().count() > 1 && !path.exists() {
                tried.push(format!("{}: no such file", path.display()));
                continue;
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
                "--denoise: cannot load Open Image Denoise ({}); run ./setup.sh, or set \
                 REFRAME_OIDN_LIB to libOpenImageDenoise.so.2",
                tried.join("; ")
            );
        };
        let api = resolve(&lib).with_context(|| {
            format!(
                "--denoise: {} is not Open Image Denoise 2",
                library.display()
            )
        })?;
        // SAFETY: the functions were resolved from the library with oidn.h's signatures.
        let device = unsafe { (api.new_device)(DEVICE_TYPE_CPU) };
        if device.is_null() {
            bail!(
                "--denoise: Open Image Denoise ({}) made no CPU device",
                library.display()
            );
        }
        let d = Denoiser {
            api,
            device,
            library,
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

    /// Denoise `input.color` with OIDN's `RT` filter in HDR mode, guided by the albedo and
    /// normal images, which are first denoised themselves (`cleanAux`: OIDN's recommended use
    /// when the guides are noisy, as a few samples' average of first hits is at edges).
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
        // OIDN filters in place where input and output are the same buffer; the inputs are
        // copied so that the caller's stay as they were.
        let mut albedo = input.albedo.to_vec();
        let mut normal = input.normal.to_vec();
        let mut color = input.color.to_vec();
        let mut out = vec![0.0f32; n];
        self.run_filter(w, h, &mut [("albedo", &mut albedo)], None, false)
            .context("denoising the albedo guide")?;
        self.run_filter(w, h, &mut [("normal", &mut normal)], None, false)
            .context("denoising the normal guide")?;
        self.run_filter(
            w,
            h,
            &mut [
                ("color", &mut color),
                ("albedo", &mut albedo),
                ("normal", &mut normal),
            ],
            Some(&mut out),
            true,
        )
        .context("denoising the frame")?;
        Ok(out)
    }

    /// One `RT` filter over `images` (the first is also the output when `output` is `None`).
    fn run_filter(
        &mut self,
        w: usize,
        h: usize,
        images: &mut [(&str, &mut Vec<f32>)],
        output: Option<&mut Vec<f32>>,
        beauty: bool,
    ) -> Result<()> {
        // SAFETY: a live device and filter; every image is a live, exclusively borrowed buffer
        // of w * h float triples that outlives the filter's execution (the filter is released
        // before this function returns); names are NUL-terminated.
        unsafe {
            let filter = (self.api.new_filter)(self.device, c"RT".as_ptr());
            if filter.is_null() {
                self.check("making the RT filter")?;
                bail!("Open Image Denoise made no RT filter");
            }
            let set = |name: &str, buf: *mut f32| {
                let cname = CString::new(name).expect("no NUL in a filter image name");
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
            };
            for (name, buf) in images.iter_mut() {
                set(name, buf.as_mut_ptr());
            }
            match output {
                Some(o) => set("output", o.as_mut_ptr()),
                None => set("output", images[0].1.as_mut_ptr()),
            }
            if beauty {
                (self.api.set_filter_bool)(filter, c"hdr".as_ptr(), true);
                (self.api.set_filter_bool)(filter, c"cleanAux".as_ptr(), true);
            }
            (self.api.commit_filter)(filter);
            let committed = self.check("setting up the filter");
            if committed.is_ok() {
                (self.api.execute_filter)(filter);
            }
            (self.api.release_filter)(filter);
            committed?;
        }
        self.check("filtering")
    }
}

impl Drop for Denoiser {
    fn drop(&mut self) {
        // SAFETY: the device was made by `load` and is released once.
        unsafe { (self.api.release_device)(self.device) };
    }
}

/// The API's functions from `lib`.
fn resolve(lib: &Library) -> Result<Api> {
    // SAFETY: each symbol is cast to the signature oidn.h (OIDN 2.x) declares for it.
    unsafe {
        macro_rules! f {
            ($name:literal) => {
                *lib.get($name)
                    .map_err(|e| anyhow!("{}: {e}", String::from_utf8_lossy($name)))?
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
            commit_filter: f!(b"oidnCommitFilter\0"),
            execute_filter: f!(b"oidnExecuteFilter\0"),
            release_filter: f!(b"oidnReleaseFilter\0"),
        })
    }
}
