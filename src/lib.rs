//! reframe: a CPU renderer for camera animations that reuses each frame's primary hits in its
//! neighbouring frames ("Reusing frames in camera animation", Méndez-Feliu, Sbert,
//! Szirmay-Kalos 2006), measured against an independent path tracer.
//!
//! The architecture, one concept per module: `camera`, `scene` (loading, materials, lights),
//! `bsdf`, `sampling`, `embree` (the only unsafe module besides the image bridge), `image` (film
//! output through OpenImageIO), `integrator` (the independent tracer and its first-hit record), `reuse` (the frame-reuse methods),
//! `render` (the driver: frame loop, tiles, progress, files), `bench` (the cost model's terms),
//! `compare` (reference, errors, flicker, equal-error speed-ups) and `chart` (SVG and PNG charts).
pub mod bench;
pub mod bsdf;
pub mod camera;
pub mod chart;
pub mod checkpoint;
pub mod compare;
pub mod embree;
pub mod image;
pub mod integrator;
pub mod merge;
pub mod render;
pub mod reuse;
pub mod sampling;
pub mod scene;
