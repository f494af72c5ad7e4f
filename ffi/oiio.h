// The C++ half of reframe's OpenImageIO bridge; the Rust half is `src/image/bridge.rs` and the
// safe API on top is `src/image/mod.rs`. Usage, from Rust only:
//
//     bridge::ffi::write_f32("frame.exr", &desc, &pixels, &attrs)?;
//
// Functions that can fail throw std::runtime_error carrying OIIO's own message; they are declared
// returning Result on the Rust side, so cxx turns the exception into an Err at the boundary.
#pragma once

#include <atomic>
#include <memory>
#include <mutex>

#include <OpenImageIO/imageio.h>
#include <OpenImageIO/texture.h>
#include <unordered_map>
#include <unordered_set>
#include <vector>

#include "rust/cxx.h"

namespace reframe {

// Shared types, defined by the cxx-generated header that oiio.cpp includes.
struct Attribute;
struct ImageDesc;
struct ImageInfo;

// Owns an open ImageInput. A class of its own (not a bare ImageInput) so that the Rust side sees
// one opaque type with exactly the operations it needs.
class ImageReader {
public:
    ImageReader(std::unique_ptr<OIIO::ImageInput> in, int subimages);
    ImageInfo info() const;
    rust::Vec<Attribute> attributes() const;
    void read_f32(uint32_t chbegin, uint32_t chend, rust::Slice<float> out);

private:
    std::unique_ptr<OIIO::ImageInput> in_;
    OIIO::ImageSpec spec_;
    int subimages_ = 1;
};

// A private OIIO::TextureSystem (its own image cache) and the textures a scene uses, each by
// index. Lookups are thread-safe (the TextureSystem keeps per-thread state of its own).
class TextureSet {
public:
    TextureSet();
    ~TextureSet();
    TextureSet(const TextureSet&) = delete;
    TextureSet& operator=(const TextureSet&) = delete;
    // Opens `path` through the cache and returns its index. `chbegin..chend`: the channels
    // `texels` fetches (those the caller takes its colour from).
    uint32_t add(rust::Slice<const uint8_t> path, uint32_t chbegin, uint32_t chend);
    // The 2 x 2 texels whose top-left one is column `x`, row `y` (row 0 the image's top; both
    // wrapped into the image, as is the second column and row), finest level, through the
    // cache: `out` holds them row by row, each its channels. False (and `out` filled with 0)
    // if the texture system failed.
    bool texels(uint32_t id, int64_t x, int64_t y, rust::Slice<float> out) const;
    // What the textures added hold in the cache when all of it is in memory (their pixels in
    // the files' own channel formats; a file added twice, as a colour and as a mask, once),
    // and the cache's limit in MB (1024 at first).
    uint64_t cache_bytes() const;
    void set_cache_mb(float mb);

private:
    struct Texture {
        OIIO::TextureSystem::TextureHandle* handle;
        int x, y, width, height;  // the data window
        int chbegin, chend;
    };
    // This set's own per-thread state of the texture system, made for each thread on its first
    // lookup and destroyed with the set (`thread_info`). The texture system's implicit per-thread
    // state lives in thread-local storage that outlives the set: it holds cache tiles, and a
    // thread that looked up texels of a set since destroyed released them when it ended, into
    // the freed cache (OpenImageIO aborted: "decr_tiles: Assertion 'm_mem_used >= 0' failed").
    OIIO::TextureSystem::Perthread* thread_info() const;
    OIIO::TextureSystem* ts_;
    uint64_t id_;  // unique in the process, never reused (the key of `thread_info`'s cache)
    mutable std::mutex threads_mutex_;
    mutable std::vector<OIIO::TextureSystem::Perthread*> threads_;
    std::vector<Texture> textures_;
    std::unordered_set<OIIO::TextureSystem::TextureHandle*> counted_;
    uint64_t cache_bytes_ = 0;
};

std::unique_ptr<TextureSet> new_texture_set();

rust::String oiio_version();
void set_threads(int32_t n);
void check_output_format(rust::Slice<const uint8_t> path);
void probe_output(rust::Slice<const uint8_t> path, rust::Slice<const uint8_t> probe,
                  const ImageDesc& desc);
std::unique_ptr<std::vector<uint8_t>> write_f32(rust::Slice<const uint8_t> path,
                                                const ImageDesc& desc,
                                                rust::Slice<const float> pixels,
                                                rust::Slice<const Attribute> attrs);
std::unique_ptr<std::vector<uint8_t>> write_u8(rust::Slice<const uint8_t> path,
                                               const ImageDesc& desc,
                                               rust::Slice<const uint8_t> pixels,
                                               rust::Slice<const Attribute> attrs);
std::unique_ptr<ImageReader> open_reader(rust::Slice<const uint8_t> path);

}  // namespace reframe
