// The C++ half of reframe's OpenImageIO bridge: thin wrappers that turn OIIO's bool-and-geterror
// failure style into std::runtime_error, which cxx catches at the boundary and hands to Rust as
// an Err. Nothing here decides policy (formats, sRGB, dithering, atomic renames): that is all in
// src/image/mod.rs. Usage, from Rust only:
//
//     let reader = bridge::ffi::open_reader("frame.exr")?;
#include "reframe/ffi/oiio.h"

#include <fcntl.h>
#include <unistd.h>

#include <algorithm>
#include <cctype>
#include <cstdio>
#include <mutex>
#include <stdexcept>
#include <OpenImageIO/filesystem.h>
#include <string>
#include <vector>

#include "reframe/src/image/bridge.rs.h"

namespace reframe {

namespace {

// A path as the Rust side holds it: the bytes of the file name, which on Unix need not be
// UTF-8 (an asset unpacked from a Latin-1 archive), passed to the OS unchanged.
std::string path_string(rust::Slice<const uint8_t> path) {
    return std::string(reinterpret_cast<const char*>(path.data()), path.size());
}

// Messages carry no path of their own: the Rust caller prefixes the path the user asked for, and
// OIIO's messages already name the file actually opened (e.g. the temporary one).
//
// OIIO keeps its global error message per thread, so this must run on the thread whose call
// failed, right after the failure: i.e. inside the failing bridged function, never later.
// Some of the codec libraries under OIIO print their own complaint about a damaged file to
// stderr (libpng's "libpng error: ...", libjpeg's "Corrupt JPEG data ...") besides handing it to
// OIIO, whose message the caller reports; reframe's errors are one line. While a file is being
// opened or read, stderr goes to /dev/null, one reader at a time. This is process-wide: inputs
// are read while loading, before any render thread prints, but a frame that its format's
// writer wrote itself (TIFF) is read back on the frame writer's thread while the workers
// render, and for those milliseconds a progress bar's redraw is lost (reframe's own messages
// and a panic's go to a copy of stderr made at start, `sys::keep_stderr`, and are not).
class QuietStderr {
public:
    QuietStderr() : lock_(mutex()) {
        std::fflush(stderr);
        saved_ = ::dup(2);
        int null = ::open("/dev/null", O_WRONLY | O_CLOEXEC);
        if (saved_ >= 0 && null >= 0) {
            ::dup2(null, 2);
        }
        if (null >= 0) {
            ::close(null);
        }
    }
    ~QuietStderr() {
        std::fflush(stderr);
        if (saved_ >= 0) {
            ::dup2(saved_, 2);
            ::close(saved_);
        }
    }
    QuietStderr(const QuietStderr&) = delete;
    QuietStderr& operator=(const QuietStderr&) = delete;

private:
    static std::mutex& mutex() {
        static std::mutex m;
        return m;
    }
    std::lock_guard<std::mutex> lock_;
    int saved_ = -1;
};

[[noreturn]] void throw_global_error(const std::string& context) {
    std::string msg = OIIO::geterror();
    if (msg.empty()) {
        msg = "OpenImageIO gave no reason";
    }
    throw std::runtime_error(context + ": " + msg);
}

[[noreturn]] void throw_output_error(OIIO::ImageOutput& out, const std::string& context) {
    std::string msg = out.geterror();
    if (msg.empty()) {
        // Some writers report through the global channel instead of the object.
        msg = OIIO::geterror();
    }
    if (msg.empty()) {
        msg = "OpenImageIO's writer gave no reason";
    }
    throw std::runtime_error(context + ": " + msg);
}

[[noreturn]] void throw_input_error(OIIO::ImageInput& in, const std::string& context) {
    std::string msg = in.geterror();
    if (msg.empty()) {
        msg = OIIO::geterror();
    }
    if (msg.empty()) {
        // Some readers fail a file cut short without a word (PNM, DPX).
        msg = "OpenImageIO's reader gave no reason (the file may be cut short or damaged)";
    }
    throw std::runtime_error(context + ": " + msg);
}

OIIO::TypeDesc to_typedesc(PixelType t) {
    switch (t) {
        case PixelType::U8: return OIIO::TypeDesc::UINT8;
        case PixelType::Half: return OIIO::TypeDesc::HALF;
        case PixelType::Float: return OIIO::TypeDesc::FLOAT;
    }
    throw std::runtime_error("invalid PixelType");
}

OIIO::ImageSpec make_spec(const ImageDesc& desc, size_t n_values,
                          rust::Slice<const Attribute> attrs) {
    const size_t nch = desc.channels.size();
    if (desc.width == 0 || desc.height == 0 || nch == 0) {
        throw std::runtime_error("image has no pixels or no channels");
    }
    if (size_t(desc.width) * size_t(desc.height) * nch != n_values) {
        throw std::runtime_error("pixel buffer size does not match width * height * channels");
    }
    OIIO::ImageSpec spec(int(desc.width), int(desc.height), int(nch), to_typedesc(desc.store_as));
    spec.channelnames.clear();
    spec.alpha_channel = -1;
    spec.z_channel = -1;
    for (size_t c = 0; c < nch; ++c) {
        std::string name(desc.channels[c]);
        // The constructor guessed alpha from the channel count; with caller-chosen names the
        // names are the only reliable signal (an "A" channel must not be premultiplied-treated
        // when it is really, say, a sample count).
        if (name == "A") {
            spec.alpha_channel = int(c);
        } else if (name == "Z") {
            spec.z_channel = int(c);
        }
        spec.channelnames.push_back(std::move(name));
    }
    for (const Attribute& a : attrs) {
        const std::string name(a.name);
        switch (a.kind) {
            case AttrKind::Int: spec.attribute(name, a.int_value); break;
            case AttrKind::Float: spec.attribute(name, a.float_value); break;
            case AttrKind::Text: spec.attribute(name, std::string(a.text)); break;
            case AttrKind::Matrix: spec.attribute(name, OIIO::TypeMatrix44, a.matrix.data()); break;
            default:
                throw std::runtime_error("attribute " + name +
                                         " has a kind that cannot be written");
        }
    }
    return spec;
}

// Why the image file `path`, just written at `width` x `height`, does not read back: its
// pixels read as floats, all of them (`whole`, checking for an error the reader left set too) or
// its last row; empty where it reads back.
std::string read_back_fault(const std::string& path, int width, int height, bool whole) {
    QuietStderr quiet;
    auto in = OIIO::ImageInput::open(path);
    if (!in) {
        const std::string msg = OIIO::geterror();
        return msg.empty() ? "it does not open" : msg;
    }
    const OIIO::ImageSpec& s = in->spec();
    if (s.width != width || s.height != height) {
        return "it reads back at another size";
    }
    const size_t row = size_t(std::max(s.width, 1)) * size_t(std::max(s.nchannels, 1));
    // The last row, or in a tiled file (Maya IFF) the last band of tiles, which holds it.
    const bool tiled = s.tile_width > 0;
    const int band = tiled ? std::max(1, s.tile_height) : 1;
    const int last = tiled ? ((height - 1) / band) * band : height - 1;
    std::vector<float> back(whole ? row * size_t(s.height) : row * size_t(band));
    bool ok;
    if (whole) {
        ok = in->read_image(0, 0, 0, s.nchannels, OIIO::TypeDesc::FLOAT, back.data()) &&
             !in->has_error();
    } else if (tiled) {
        ok = in->read_tiles(0, 0, s.x, s.x + s.width, s.y + last, s.y + height, s.z, s.z + 1, 0,
                            s.nchannels, OIIO::TypeDesc::FLOAT, back.data());
    } else {
        ok = in->read_scanline(s.y + height - 1, 0, OIIO::TypeDesc::FLOAT, back.data());
    }
    if (!ok) {
        const std::string msg = in->geterror();
        return msg.empty() ? "it does not read back" : msg;
    }
    return "";
}

// Encodes the frame in memory where the format's writer takes an IOProxy (nearly all do) and
// returns the file's bytes, for the caller to write, check and sync: OIIO 2.4's writers ignore
// a failed write to disk (a full disk gave empty EXR, PNG and HDR frames with close() reporting
// success, and libjpeg ended the process). Otherwise writes `path` itself and returns nothing.
std::unique_ptr<std::vector<uint8_t>> write_pixels(const std::string& path,
                                                   const OIIO::ImageSpec& spec,
                                                   OIIO::TypeDesc in_type, const void* pixels) {
    auto bytes = std::make_unique<std::vector<uint8_t>>();
    OIIO::Filesystem::IOVecOutput memory(*bytes);
    auto out = OIIO::ImageOutput::create(path);
    if (!out) {
        throw_global_error("no image writer");
    }
    // OIIO 2.4's TIFF writer, given an IOProxy, leaves out the ImageLength tag (an unreadable
    // file); libtiff reports a failed write to disk itself.
    const bool in_memory = out->supports("ioproxy") && std::string(out->format_name()) != "tiff" &&
                           out->set_ioproxy(&memory);
    if (!out->open(path, spec)) {
        throw_output_error(*out, "cannot open for writing");
    }
    if (!out->write_image(in_type, pixels)) {
        // Keep the writer's message before close() can overwrite it; the caller deletes the
        // partial file.
        std::string msg = out->geterror();
        out->close();
        throw std::runtime_error("cannot write pixels: " +
                                 (msg.empty() ? std::string("OpenImageIO's writer gave no reason") : msg));
    }
    // Writers flush and compress on close; some report a failure only as an error left set
    // (TIFF's "failed TIFFWriteDirectory()" with close() true).
    if (!out->close() || out->has_error()) {
        throw_output_error(*out, "cannot finish writing");
    }
    if (in_memory && bytes->empty()) {
        throw std::runtime_error("the image writer produced no bytes");
    }
    if (!in_memory) {
        // Written to disk by the writer, which may not notice a failed write at all (SGI and
        // FITS left 512-byte files under a full disk and reported success): read back whole.
        bytes->clear();
        const std::string fault = read_back_fault(path, spec.width, spec.height, true);
        if (!fault.empty()) {
            throw std::runtime_error("the written file does not read back whole: " + fault);
        }
    }
    return bytes;
}

}  // namespace

rust::String oiio_version() {
    const int v = OIIO::openimageio_version();
    return rust::String(std::to_string(v / 10000) + "." + std::to_string(v / 100 % 100) + "." +
                        std::to_string(v % 100));
}

void set_threads(int32_t n) {
    // OIIO's own pool, and the one OpenEXR compresses and decompresses blocks in (a separate
    // setting: "exr_threads"); both default to the machine's cores, whatever the process may use.
    OIIO::attribute("threads", static_cast<int>(n));
    OIIO::attribute("exr_threads", static_cast<int>(n));
}

void check_output_format(rust::Slice<const uint8_t> path) {
    const std::string p = path_string(path);
    // create() only looks the writer up by extension; it neither opens nor creates the file.
    auto out = OIIO::ImageOutput::create(p);
    if (!out) {
        throw_global_error("no image writer");
    }
}

void probe_output(rust::Slice<const uint8_t> path, rust::Slice<const uint8_t> probe,
                  const ImageDesc& desc) {
    const std::string p = path_string(path);
    auto out = OIIO::ImageOutput::create(p);
    if (!out) {
        throw_global_error("no image writer");
    }
    // OpenImageIO's pseudo-formats: `null` writes nothing (and fails a frame's write), `term`
    // draws on the terminal.
    const std::string format = out->format_name();
    if (format == "null" || format == "term") {
        throw std::runtime_error("'" + format + "' is not an image file format");
    }
    // The formats frames are written in hold any RGB frame reframe renders: not probed (a
    // PNG closed without its pixels has libpng print to stderr).
    for (const char* whole : {"openexr", "png", "jpeg", "tiff", "hdr", "targa", "bmp"}) {
        if (format == whole) {
            return;
        }
    }
    // Another writer's own checks of a frame's size and channels are made as it opens a file;
    // a black frame is written row by row so that it closes as a whole file.
    OIIO::ImageSpec spec(int(desc.width), int(desc.height), int(desc.channels.size()),
                         to_typedesc(desc.store_as));
    const std::string q = path_string(probe);
    bool opened = out->open(q, spec);
    std::string msg = opened ? std::string() : out->geterror();
    std::string writer_said;
    if (opened) {
        // A tiled-only writer (Maya IFF) takes no scanlines: a band of tiles at a time (the
        // probe failed it, "the writer gives no reason", though frames write whole).
        const size_t channels = desc.channels.size();
        const bool tiled = out->spec().tile_width > 0;
        const int band = tiled ? std::max(1, out->spec().tile_height) : 1;
        const std::vector<float> rows(size_t(desc.width) * channels * size_t(band), 0.0f);
        for (int y = 0; y < int(desc.height) && opened; y += band) {
            if (tiled) {
                const int end = std::min(y + band, int(desc.height));
                opened = out->write_tiles(0, int(desc.width), y, end, 0, 1,
                                          OIIO::TypeDesc::FLOAT, rows.data());
            } else {
                opened = out->write_scanline(y, 0, OIIO::TypeDesc::FLOAT, rows.data());
            }
        }
        if (!opened) {
            msg = out->geterror();
        }
        // The writer's own complaint, if any, says why a file will not read back.
        if (!out->close() || out->has_error()) {
            writer_said = out->geterror();
        }
    }
    // What was written must read back: this OpenImageIO's JPEG 2000 writer wrote empty .j2k
    // files and .jp2 files its own reader refuses.
    std::string unreadable;
    if (opened) {
        // The last row: a file cut short fails there, and a frame's whole would be gigabytes.
        unreadable = read_back_fault(q, int(desc.width), int(desc.height), false);
        if (!unreadable.empty() && !writer_said.empty()) {
            unreadable = writer_said + "; reading it back: " + unreadable;
        }
    }
    std::remove(q.c_str());
    if (!opened) {
        throw std::runtime_error("this format cannot hold the frames (" +
                                 std::to_string(desc.width) + "x" + std::to_string(desc.height) +
                                 ", " + std::to_string(desc.channels.size()) + " channels): " +
                                 (msg.empty() ? std::string("the writer gives no reason; choose "
                                                            "another format")
                                              : msg));
    }
    while (!unreadable.empty() && std::isspace(static_cast<unsigned char>(unreadable.back()))) {
        unreadable.pop_back();
    }
    if (!unreadable.empty()) {
        throw std::runtime_error("a test frame written as " + format +
                                 " does not read back (" + unreadable +
                                 "): the disk may be full, or this OpenImageIO cannot read its "
                                 "own " + format + " files at this size; choose another format");
    }
}

std::unique_ptr<std::vector<uint8_t>> write_f32(rust::Slice<const uint8_t> path,
                                                const ImageDesc& desc,
                                                rust::Slice<const float> pixels,
                                                rust::Slice<const Attribute> attrs) {
    const OIIO::ImageSpec spec = make_spec(desc, pixels.size(), attrs);
    return write_pixels(path_string(path), spec, OIIO::TypeDesc::FLOAT, pixels.data());
}

std::unique_ptr<std::vector<uint8_t>> write_u8(rust::Slice<const uint8_t> path,
                                               const ImageDesc& desc,
                                               rust::Slice<const uint8_t> pixels,
                                               rust::Slice<const Attribute> attrs) {
    const OIIO::ImageSpec spec = make_spec(desc, pixels.size(), attrs);
    return write_pixels(path_string(path), spec, OIIO::TypeDesc::UINT8, pixels.data());
}

ImageReader::ImageReader(std::unique_ptr<OIIO::ImageInput> in, int subimages)
    : in_(std::move(in)), spec_(in_->spec()), subimages_(subimages) {}

namespace {

// The images the file at `p` holds, counted up to 65, for the formats whose first image may
// not be the one meant: OIIO names them (`oiio:subimages`) for OpenEXR only, and a multi-page
// TIFF or an animated GIF shows its second image only to a seek. (A layered PSD's first image
// is its composite, the image meant.) The seeks go through a reader of their own: some readers
// (WebP's) cannot decode their first image again after a seek past their last.
int count_subimages(const std::string& p, const OIIO::ImageSpec& config, const char* format) {
    const std::string f(format);
    if (f != "tiff" && f != "gif") {
        return 1;
    }
    QuietStderr quiet;
    std::unique_ptr<OIIO::ImageInput> probe = OIIO::ImageInput::open(p, &config);
    if (!probe) {
        (void)OIIO::geterror();
        return 1;
    }
    int n = 1;
    while (n < 65 && probe->seek_subimage(n, 0)) {
        ++n;
    }
    (void)probe->geterror();
    return n;
}

}  // namespace

std::unique_ptr<ImageReader> open_reader(rust::Slice<const uint8_t> path) {
    const std::string p = path_string(path);
    // Colours as the file stores them: OIIO would multiply a PNG's or TGA's colour by its
    // alpha (associate it), darkening a texture wherever it is partly transparent, and a mask
    // read from a colour channel with it.
    OIIO::ImageSpec config;
    config.attribute("oiio:UnassociatedAlpha", 1);
    std::unique_ptr<OIIO::ImageInput> in;
    {
        QuietStderr quiet;
        in = OIIO::ImageInput::open(p, &config);
    }
    if (!in) {
        throw_global_error("cannot open");
    }
    const OIIO::ImageSpec& spec = in->spec();
    // Said as what each is: a deep image (samples at several depths per pixel) needs
    // flattening, a volume (depth above 1) is no picture.
    if (spec.deep) {
        throw std::runtime_error("a deep image (several samples at depths per pixel), not a flat "
                                 "one: flatten it first (oiiotool --flatten, or a compositor)");
    }
    if (spec.depth > 1) {
        throw std::runtime_error("a volume of " + std::to_string(spec.depth) +
                                 " slices, not a flat 2D image");
    }
    if (spec.width <= 0 || spec.height <= 0 || spec.nchannels <= 0) {
        throw std::runtime_error("not a flat 2D image (no pixels or no channels)");
    }
    const int subimages = count_subimages(p, config, in->format_name());
    return std::make_unique<ImageReader>(std::move(in), subimages);
}

namespace {

// Whether an OpenEXR file's data window (the pixels it stores) differs from its display window
// (the image it means: an EXR cropped to its non-empty pixels, an overscan render, a Nuke bbox).
// The image is then its display window, zero where nothing is stored, as other renderers read
// it. Only OpenEXR: another format's offset (a PNG's oFFs chunk, which ImageMagick writes after
// a crop) is not a window other readers honour, and its pixels are the image.
bool windowed(const OIIO::ImageSpec& s, const std::string& format) {
    return format == "openexr" && s.full_width > 0 && s.full_height > 0 &&
           (s.x != s.full_x || s.y != s.full_y || s.width != s.full_width ||
            s.height != s.full_height);
}

}  // namespace

ImageInfo ImageReader::info() const {
    ImageInfo info;
    const bool w = windowed(spec_, in_->format_name());
    info.width = uint32_t(w ? spec_.full_width : spec_.width);
    info.height = uint32_t(w ? spec_.full_height : spec_.height);
    for (int c = 0; c < spec_.nchannels; ++c) {
        info.channels.push_back(rust::String::lossy(std::string(spec_.channel_name(c))));
    }
    info.stored_width = uint32_t(spec_.width);
    info.stored_height = uint32_t(spec_.height);
    // In 64 bits: a window's corner plus its size may pass the int range.
    auto apart = [](int64_t a, int64_t a_size, int64_t b, int64_t b_size) {
        return a >= b + b_size || a + a_size <= b;
    };
    info.stored_outside = w && (apart(spec_.x, spec_.width, spec_.full_x, spec_.full_width) ||
                                apart(spec_.y, spec_.height, spec_.full_y, spec_.full_height));
    // The stored pixels inside the image: the two windows' overlap, column by row.
    auto overlap = [](int64_t a, int64_t a_size, int64_t b, int64_t b_size) {
        return std::max<int64_t>(0, std::min(a + a_size, b + b_size) - std::max(a, b));
    };
    info.stored_inside =
        w ? uint64_t(overlap(spec_.x, spec_.width, spec_.full_x, spec_.full_width) *
                     overlap(spec_.y, spec_.height, spec_.full_y, spec_.full_height))
          : uint64_t(info.width) * uint64_t(info.height);
    info.format_name = rust::String::lossy(in_->format_name());
    info.codes = spec_.format == OIIO::TypeDesc::UINT8 || spec_.format == OIIO::TypeDesc::UINT16;
    info.images = uint32_t(subimages_);
    info.tile_width = uint32_t(std::max(spec_.tile_width, 0));
    info.tile_height = uint32_t(std::max(spec_.tile_height, 0));
    return info;
}

// Metadata from arbitrary files need not be UTF-8, and these functions are not allowed to throw,
// hence the lossy conversions.
rust::Vec<Attribute> ImageReader::attributes() const {
    rust::Vec<Attribute> result;
    for (const OIIO::ParamValue& p : spec_.extra_attribs) {
        Attribute a;
        a.name = rust::String::lossy(p.name().string());
        a.int_value = 0;
        a.float_value = 0.0f;
        a.matrix.fill(0.0f);
        const OIIO::TypeDesc t = p.type();
        if (t == OIIO::TypeInt) {
            a.kind = AttrKind::Int;
            a.int_value = p.get_int();
        } else if (t == OIIO::TypeFloat) {
            a.kind = AttrKind::Float;
            a.float_value = p.get_float();
        } else if (t == OIIO::TypeString) {
            a.kind = AttrKind::Text;
            a.text = rust::String::lossy(p.get_string());
        } else if (t == OIIO::TypeMatrix44) {
            a.kind = AttrKind::Matrix;
            const float* m = static_cast<const float*>(p.data());
            for (int i = 0; i < 16; ++i) {
                a.matrix[i] = m[i];
            }
        } else {
            a.kind = AttrKind::Other;
            a.text = rust::String::lossy(p.get_string());
        }
        result.push_back(std::move(a));
    }
    return result;
}

void ImageReader::read_f32(uint32_t chbegin, uint32_t chend, rust::Slice<float> out) {
    if (chbegin >= chend || int(chend) > spec_.nchannels) {
        throw std::runtime_error("channels out of the image's range");
    }
    const int cb = int(chbegin), ce = int(chend);
    const size_t nch = size_t(ce - cb);
    const bool w = windowed(spec_, in_->format_name());
    const size_t n = size_t(w ? spec_.full_width : spec_.width) *
                     size_t(w ? spec_.full_height : spec_.height) * nch;
    if (out.size() != n) {
        throw std::runtime_error("output buffer size does not match the image");
    }
    bool ok = true;
    if (!w) {
        QuietStderr quiet;
        ok = in_->read_image(0, 0, cb, ce, OIIO::TypeDesc::FLOAT, out.data());
    } else {
        // The stored rows that fall inside the display window, one at a time, each placed
        // where it belongs (rows and columns outside it are not kept: an overscan frame's
        // margin, or a hostile file's huge data window, costs one row of memory).
        std::fill(out.begin(), out.end(), 0.0f);
        // The stored columns inside the display window: `x0..x1` of the file's.
        const int x0 = std::max(spec_.x, spec_.full_x);
        const int x1 = std::min(spec_.x + spec_.width, spec_.full_x + spec_.full_width);
        QuietStderr quiet;
        if (spec_.tile_width > 0 && spec_.tile_height > 0) {
            // A tiled file has no scanlines to read: a band of tiles at a time, over the tiles'
            // columns that meet the display window (a band is a tile high).
            const int tw = spec_.tile_width, th = spec_.tile_height;
            const int xb = spec_.x + (std::max(x0 - spec_.x, 0) / tw) * tw;
            const int xe = std::min(spec_.x + ((x1 - spec_.x + tw - 1) / tw) * tw,
                                    spec_.x + spec_.width);
            if (x0 >= x1 || xb >= xe) {
                return;
            }
            std::vector<float> band(size_t(xe - xb) * size_t(th) * nch);
            for (int y0 = spec_.y; y0 < spec_.y + spec_.height && ok; y0 += th) {
                const int y1 = std::min(y0 + th, spec_.y + spec_.height);
                if (y1 <= spec_.full_y || y0 >= spec_.full_y + spec_.full_height) {
                    continue;
                }
                ok = in_->read_tiles(0, 0, xb, xe, y0, y1, spec_.z, spec_.z + std::max(spec_.depth, 1),
                                     cb, ce, OIIO::TypeDesc::FLOAT, band.data());
                for (int y = y0; y < y1 && ok; ++y) {
                    const int dy = y - spec_.full_y;
                    if (dy < 0 || dy >= spec_.full_height) {
                        continue;
                    }
                    const float* src = band.data() + (size_t(y - y0) * size_t(xe - xb) + size_t(x0 - xb)) * nch;
                    std::copy(src, src + size_t(x1 - x0) * nch,
                              out.data() + (size_t(dy) * spec_.full_width + (x0 - spec_.full_x)) * nch);
                }
            }
            if (!ok || in_->has_error()) {
                throw_input_error(*in_, "cannot read pixels");
            }
            return;
        }
        std::vector<float> row(size_t(spec_.width) * nch);
        for (int y = 0; y < spec_.height && ok; ++y) {
            const int dy = spec_.y + y - spec_.full_y;
            if (dy < 0 || dy >= spec_.full_height) {
                continue;
            }
            ok = in_->read_scanlines(0, 0, spec_.y + y, spec_.y + y + 1, spec_.z, cb, ce,
                                     OIIO::TypeDesc::FLOAT, row.data());
            if (ok && x0 < x1) {
                std::copy(row.data() + size_t(x0 - spec_.x) * nch,
                          row.data() + size_t(x1 - spec_.x) * nch,
                          out.data() + (size_t(dy) * spec_.full_width + (x0 - spec_.full_x)) * nch);
            }
        }
    }
    // A reader may fill what it could not read (a TIFF strip cut off reads as zeros, a JPEG cut
    // short as grey: "Premature end of JPEG file") and still report success, leaving only its
    // error message set: that is a damaged file too.
    if (!ok || in_->has_error()) {
        throw_input_error(*in_, "cannot read pixels");
    }
}

}  // namespace reframe

namespace reframe {

namespace {
std::atomic<uint64_t> next_texture_set_id{1};
}

TextureSet::TextureSet()
    : ts_(OIIO::TextureSystem::create(/*shared=*/false)), id_(next_texture_set_id++) {
    if (ts_ == nullptr) {
        throw std::runtime_error("could not create an OpenImageIO texture system");
    }
    // Scanline files (PNG, JPEG, plain EXR) are read whole into the cache; tiled, MIP-mapped
    // files (.tx, tiled EXR) a tile at a time.
    ts_->attribute("accept_untiled", 1);
    // As `open_reader` reads them: colours not multiplied by alpha.
    ts_->attribute("unassociatedalpha", 1);
    ts_->attribute("max_memory_MB", 1024.0f);
}

TextureSet::~TextureSet() {
    // With statistics asked for (OPENIMAGEIO_IMAGECACHE_OPTIONS=statistics:level=1), the cache
    // prints them as it goes, reading every per-thread record, and OpenImageIO 2.4 leaves an
    // empty slot where `destroy_thread_info` took one: printed here first, then turned off (the
    // process crashed at exit).
    int level = 0;
    ts_->getattribute("statistics:level", level);
    if (level > 0) {
        std::fputs(ts_->getstats(level).c_str(), stdout);
        ts_->attribute("statistics:level", 0);
    }
    {
        std::lock_guard<std::mutex> lock(threads_mutex_);
        for (auto* t : threads_) {
            ts_->destroy_thread_info(t);
        }
        threads_.clear();
    }
    OIIO::TextureSystem::destroy(ts_, /*teardown_imagecache=*/true);
}

OIIO::TextureSystem::Perthread* TextureSet::thread_info() const {
    // The last set this thread used, then every set it used (keyed by id, never by address: a
    // set made where a destroyed one was must not find that one's state).
    thread_local uint64_t last_id = 0;
    thread_local OIIO::TextureSystem::Perthread* last = nullptr;
    thread_local std::unordered_map<uint64_t, OIIO::TextureSystem::Perthread*> used;
    if (last_id == id_) {
        return last;
    }
    auto found = used.find(id_);
    OIIO::TextureSystem::Perthread* t;
    if (found != used.end()) {
        t = found->second;
    } else {
        t = ts_->create_thread_info();
        {
            std::lock_guard<std::mutex> lock(threads_mutex_);
            threads_.push_back(t);
        }
        used.emplace(id_, t);
    }
    last_id = id_;
    last = t;
    return t;
}

uint32_t TextureSet::add(rust::Slice<const uint8_t> path, uint32_t chbegin, uint32_t chend) {
    OIIO::ustring name{path_string(path)};
    OIIO::TextureSystem::TextureHandle* handle;
    const OIIO::ImageSpec* spec = nullptr;
    {
        QuietStderr quiet;
        handle = ts_->get_texture_handle(name, thread_info());
        if (handle != nullptr && ts_->good(handle)) {
            spec = ts_->imagespec(handle, thread_info(), 0);
        }
    }
    if (spec == nullptr) {
        std::string msg = ts_->geterror();
        throw std::runtime_error(msg.empty() ? "the texture system could not open it" : msg);
    }
    if (spec->width <= 0 || spec->height <= 0 || int(chend) > spec->nchannels || chbegin >= chend) {
        throw std::runtime_error("the texture system sees other pixels or channels than the file");
    }
    // Over its display window (see `windowed`): texels outside the data window read as zero.
    std::string format;
    {
        OIIO::ustring name;
        if (ts_->get_texture_info(handle, thread_info(), 0, OIIO::ustring("fileformat"),
                                  OIIO::TypeDesc::STRING, &name)) {
            format = name.string();
        }
    }
    // The cache holds a file once, however many times it is added.
    if (counted_.insert(handle).second) {
        cache_bytes_ += uint64_t(spec->width) * uint64_t(spec->height) *
                        uint64_t(spec->nchannels) * uint64_t(spec->format.size());
    }
    if (windowed(*spec, format)) {
        textures_.push_back(Texture{handle, spec->full_x, spec->full_y, spec->full_width,
                                    spec->full_height, int(chbegin), int(chend)});
    } else {
        textures_.push_back(Texture{handle, spec->x, spec->y, spec->width, spec->height,
                                    int(chbegin), int(chend)});
    }
    return static_cast<uint32_t>(textures_.size() - 1);
}

uint64_t TextureSet::cache_bytes() const { return cache_bytes_; }

void TextureSet::set_cache_mb(float mb) { ts_->attribute("max_memory_MB", mb); }

bool TextureSet::texels(uint32_t id, int64_t x, int64_t y, rust::Slice<float> out) const {
    const Texture& t = textures_[id];
    const int n = t.chend - t.chbegin;
    auto wrap = [](int64_t v, int64_t size) { return int(((v % size) + size) % size); };
    const int x0 = wrap(x, t.width), x1 = wrap(x0 + 1, t.width);
    const int y0 = wrap(y, t.height), y1 = wrap(y0 + 1, t.height);
    OIIO::TextureOpt opt;
    OIIO::TextureSystem::Perthread* thread = thread_info();
    bool ok = true;
    if (x1 == x0 + 1 && y1 == y0 + 1) {
        // The usual case, the four in one block of the cache.
        ok = ts_->get_texels(t.handle, thread, opt, 0, t.x + x0, t.x + x0 + 2, t.y + y0,
                             t.y + y0 + 2, 0, 1, t.chbegin, t.chend, OIIO::TypeFloat, out.data());
    } else {
        // At the right or bottom edge the block wraps: one texel at a time.
        const int xs[2] = {x0, x1}, ys[2] = {y0, y1};
        for (int k = 0; k < 4 && ok; ++k) {
            int px = t.x + xs[k % 2], py = t.y + ys[k / 2];
            ok = ts_->get_texels(t.handle, thread, opt, 0, px, px + 1, py, py + 1, 0, 1,
                                 t.chbegin, t.chend, OIIO::TypeFloat, out.data() + k * n);
        }
    }
    if (!ok) {
        (void)ts_->geterror();  // clear this thread's message; the caller counts the failure
        for (size_t c = 0; c < out.size(); ++c) {
            out[c] = 0.0f;
        }
    }
    return ok;
}

std::unique_ptr<TextureSet> new_texture_set() { return std::make_unique<TextureSet>(); }

}  // namespace reframe
