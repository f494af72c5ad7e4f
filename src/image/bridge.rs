//! The `cxx` declarations of the OpenImageIO bridge (`ffi/oiio.h`, `ffi/oiio.cpp`), private to
//! [`crate::image`], which is the only safe public face of it:
//!
//! ```ignore
//! let reader = bridge::ffi::open_reader("frame.exr")?;
//! let info = reader.info();
//! ```
//!
//! Every C++ function that can fail is declared returning `Result`: `cxx` then catches the
//! `std::runtime_error` the C++ side throws (carrying OIIO's own message) and hands it over as an
//! `Err`, so no C++ exception ever unwinds into Rust.

#[cxx::bridge(namespace = "reframe")]
pub(crate) mod ffi {
    /// How a [`Attribute`] is stored in the file; only the matching value field is meaningful.
    #[derive(Debug, Clone, Copy, PartialEq, Eq)]
    enum AttrKind {
        Int,
        Float,
        Text,
        Matrix,
        /// Read back only: a type the bridge does not model, rendered into `text` by OIIO.
        Other,
    }

    /// One metadata attribute, in both directions. A flat struct rather than an enum with
    /// payloads because `cxx` shared types cannot carry data in their enums.
    #[derive(Debug, Clone)]
    struct Attribute {
        name: String,
        kind: AttrKind,
        int_value: i32,
        float_value: f32,
        text: String,
        /// Imath / EXR layout: row-vector convention, row-major.
        matrix: [f32; 16],
    }

    /// What the pixels are stored as in the file; the caller's data is always f32 or u8.
    #[derive(Debug, Clone, Copy, PartialEq, Eq)]
    enum PixelType {
        U8,
        Half,
        Float,
    }

    #[derive(Debug, Clone)]
    struct ImageDesc {
        width: u32,
        height: u32,
        channels: Vec<String>,
        store_as: PixelType,
    }

    #[derive(Debug, Clone)]
    struct ImageInfo {
        /// The image: its display window (where the file has one that differs from its data
        /// window), else the pixels it stores.
        width: u32,
        height: u32,
        /// The pixels the file stores (its data window).
        stored_width: u32,
        stored_height: u32,
        /// An OpenEXR file whose data window lies wholly outside its display window: not one
        /// stored pixel is in its image.
        stored_outside: bool,
        /// How many of the image's pixels the file stores (all of them, unless its data window
        /// covers only part of its display window).
        stored_inside: u64,
        channels: Vec<String>,
        format_name: String,
        /// Whether the file stores its values as 8- or 16-bit unsigned codes (the forms sRGB
        /// comes in), not as floats or other integers (32-bit or signed: data, not colour codes).
        codes: bool,
        /// The images the file holds (found by seeking: a multi-page TIFF's pages, an
        /// animated GIF's frames; counted up to 65: 65 means more than 64).
        images: u32,
        /// A tiled file's tile size (0 x 0 for a scanline file).
        tile_width: u32,
        tile_height: u32,
    }

    unsafe extern "C++" {
        include!("reframe/ffi/oiio.h");

        /// An open `OIIO::ImageInput`, positioned on its first subimage.
        type ImageReader;

        fn oiio_version() -> String;

        /// Threads OpenImageIO and OpenEXR may use for their own parallel work (an EXR
        /// frame's compression, format conversions); 0 means one per core.
        fn set_threads(n: i32) -> Result<()>;

        /// Succeeds when OIIO has a writer for the file name's extension.
        fn check_output_format(path: &[u8]) -> Result<()>;

        /// Opens a writer for `path`'s format on the file `probe` with a frame's size and
        /// channels, then closes and removes it: fails where the writer refuses the frames
        /// (an icon over 256 pixels, a one-channel format), or for a pseudo-format (`null`,
        /// `term`).
        fn probe_output(path: &[u8], probe: &[u8], desc: &ImageDesc) -> Result<()>;

        /// `pixels` is interleaved, row-major, top row first, `channels.len()` per pixel. The
        /// file's bytes, encoded in memory, for the caller to write to `path` (whose name picks
        /// the format); empty where the format's writer cannot encode in memory and has
        /// written `path` itself.
        fn write_f32(
            path: &[u8],
            desc: &ImageDesc,
            pixels: &[f32],
            attrs: &[Attribute],
        ) -> Result<UniquePtr<CxxVector<u8>>>;
        fn write_u8(
            path: &[u8],
            desc: &ImageDesc,
            pixels: &[u8],
            attrs: &[Attribute],
        ) -> Result<UniquePtr<CxxVector<u8>>>;

        fn open_reader(path: &[u8]) -> Result<UniquePtr<ImageReader>>;

        /// A private `OIIO::TextureSystem` and the textures opened through it.
        type TextureSet;
        fn new_texture_set() -> Result<UniquePtr<TextureSet>>;
        /// Opens `path` through the texture cache; its index. `texels` fetches channels
        /// `chbegin..chend`.
        fn add(self: Pin<&mut TextureSet>, path: &[u8], chbegin: u32, chend: u32) -> Result<u32>;
        /// The 2 x 2 texels from column `x`, row `y` (0: the top row), each wrapped into the
        /// image, finest level, row by row; `out` holds 4 times the texture's channels.
        fn texels(self: &TextureSet, id: u32, x: i64, y: i64, out: &mut [f32]) -> bool;
        /// What the textures added hold in the cache when all of it is in memory.
        fn cache_bytes(self: &TextureSet) -> u64;
        /// The cache's limit (OIIO's `max_memory_MB`; 1024 at first).
        fn set_cache_mb(self: Pin<&mut TextureSet>, mb: f32);
        fn info(self: &ImageReader) -> ImageInfo;
        /// Every attribute of the first subimage's spec.
        fn attributes(self: &ImageReader) -> Vec<Attribute>;
        /// Channels `chbegin..chend`, converted to f32; `out` must hold exactly width * height
        /// * (chend - chbegin) values.
        fn read_f32(
            self: Pin<&mut ImageReader>,
            chbegin: u32,
            chend: u32,
            out: &mut [f32],
        ) -> Result<()>;
    }
}

// SAFETY: an `OIIO::TextureSystem` is made for concurrent lookups from many threads (it keeps
// per-thread state of its own, found by `get_perthread_info`); `lookup` takes `&self` and
// `add` `Pin<&mut>`, so Rust's borrow rules keep `add` from running beside a lookup.
unsafe impl Send for ffi::TextureSet {}
unsafe impl Sync for ffi::TextureSet {}
