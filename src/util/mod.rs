//! Small services below every other layer: content hashes (`hash`), atomic file writes and
//! temporary names (`fs`), and the process's memory figures (`mem`). Nothing here knows a scene,
//! a method or a render.
pub mod fs;
pub mod hash;
pub mod mem;
