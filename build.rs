//! Build script: locates the Embree 4 runtime (the system's, or the one `setup.sh` unpacked into
//! `.deps/`) for `embree4-sys`, and compiles the C++ half of the OpenImageIO bridge (`ffi/`).
use std::path::{Path, PathBuf};
use std::process::Command;

fn main() {
    println!("cargo:rerun-if-changed=build.rs");
    println!("cargo:rerun-if-env-changed=REFRAME_EMBREE_LIB_DIR");
    link_embree();
    locate_oidn();
    build_oiio_bridge();
}

/// `embree4-sys` asks for `-lembree4` but says nothing about where it is: give the linker the
/// folder and an rpath so that the binary and the tests find the runtime without LD_LIBRARY_PATH.
fn link_embree() {
    let manifest = PathBuf::from(std::env::var("CARGO_MANIFEST_DIR").unwrap());
    let local = manifest.join(".deps/embree4/lib");
    println!("cargo:rerun-if-changed={}", local.display());
    let mut candidates: Vec<PathBuf> = Vec::new();
    if let Ok(dir) = std::env::var("REFRAME_EMBREE_LIB_DIR") {
        candidates.push(dir.into());
    }
    candidates.extend(
        [
            "/usr/lib/x86_64-linux-gnu",
            "/usr/lib64",
            "/usr/lib",
            "/usr/local/lib",
        ]
        .iter()
        .map(PathBuf::from),
    );
    candidates.push(local);
    let found = candidates.iter().find(|d| d.join("libembree4.so").exists());
    let Some(dir) = found else {
        panic!(
            "Embree 4 not found (no libembree4.so in {:?}). Run ./setup.sh first, or set \
             REFRAME_EMBREE_LIB_DIR to the folder that holds libembree4.so.",
            candidates
        );
    };
    println!("cargo:rustc-link-search=native={}", dir.display());
    if !is_default_lib_dir(dir) {
        println!("cargo:rustc-link-arg=-Wl,-rpath,{}", dir.display());
    }
}

/// Open Image Denoise is opened at run time (`image::oidn`), not linked: tell the code where
/// `setup.sh` unpacked it, if it did.
fn locate_oidn() {
    let manifest = PathBuf::from(std::env::var("CARGO_MANIFEST_DIR").unwrap());
    let dir = manifest.join(".deps/oidn/lib");
    println!("cargo:rerun-if-changed={}", dir.display());
    if dir.join("libOpenImageDenoise.so.2").exists() {
        println!("cargo:rustc-env=REFRAME_OIDN_DIR={}", dir.display());
    }
}

fn is_default_lib_dir(dir: &Path) -> bool {
    ["/usr/lib/x86_64-linux-gnu", "/usr/lib64", "/usr/lib"]
        .iter()
        .any(|d| dir == Path::new(d))
}

fn build_oiio_bridge() {
    println!("cargo:rerun-if-changed=ffi/oiio.cpp");
    println!("cargo:rerun-if-changed=ffi/oiio.h");
    println!("cargo:rerun-if-changed=src/image/bridge.rs");
    let cflags = pkg_config(&["--cflags", "OpenImageIO"]);
    let libs = pkg_config(&["--libs", "OpenImageIO"]);
    let mut build = cxx_build::bridge("src/image/bridge.rs");
    build
        .file("ffi/oiio.cpp")
        .std("c++17")
        .flag_if_supported("-Wno-deprecated-declarations");
    for f in cflags.split_whitespace() {
        if let Some(inc) = f.strip_prefix("-I") {
            build.include(inc);
        } else {
            build.flag(f);
        }
    }
    build.compile("reframe_oiio");
    for f in libs.split_whitespace() {
        if let Some(dir) = f.strip_prefix("-L") {
            println!("cargo:rustc-link-search=native={dir}");
        } else if let Some(lib) = f.strip_prefix("-l") {
            println!("cargo:rustc-link-lib={lib}");
        }
    }
    // OIIO's pkg-config file names only OpenImageIO; the util library holds ustring & co.
    println!("cargo:rustc-link-lib=OpenImageIO_Util");
}

fn pkg_config(args: &[&str]) -> String {
    let out = Command::new("pkg-config")
        .args(args)
        .output()
        .unwrap_or_else(|e| panic!("pkg-config not runnable ({e}); run ./setup.sh first"));
    if !out.status.success() {
        panic!(
            "pkg-config {:?} failed: {}. OpenImageIO missing? Run ./setup.sh first.",
            args,
            String::from_utf8_lossy(&out.stderr).trim()
        );
    }
    String::from_utf8(out.stdout).unwrap()
}
