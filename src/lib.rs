//! reframe: a CPU renderer for camera animations that reuses each frame's primary hits in its
//! neighbouring frames ("Reusing frames in camera animation", Méndez-Feliu, Sbert,
//! Szirmay-Kalos 2006), measured against an independent path tracer.
//!
//! The architecture, one concept per module, with arrows pointing down only:
//!
//! ```text
//! main.rs, cli.rs        the command line: clap structs, summaries, dispatch
//! eval/                  bench, reference, errors and fits, compare, charts
//! driver/                options and their validation, the frame loops, runs and signals,
//!                        frame files, --stats, merge
//! state/                 the state-file format, run key and chunks, checkpoints
//! reuse/                 the method registry, the weights (each equation once), the kernel,
//!                        visibility, adaptive counts
//! film/                  fixed-point sums, frame accumulators, develop, tiles
//! integrator             the path tracer and its first-hit record
//! scene/                 loading, materials, lights, surface points
//! camera, bsdf, sampling, embree, image     the leaves (embree and image hold the unsafe FFI)
//! util/                  hashes, atomic files, memory figures
//! sys                    the process's exit without destructors (the one libc call)
//! ```
// First: its macros (`outln!`, `errln!`) are used by the modules after it.
#[macro_use]
pub mod util;
pub mod bsdf;
pub mod camera;
pub mod driver;
pub mod embree;
pub mod eval;
pub mod film;
pub mod image;
pub mod integrator;
pub mod reuse;
pub mod sampling;
pub mod scene;
pub mod state;
pub mod sys;
