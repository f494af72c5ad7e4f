//! Small services below every other layer: content hashes (`hash`), atomic file writes and
//! temporary names (`fs`), the one way to open an input file (`input`), and the process's memory
//! figures (`mem`). Nothing here knows a scene,
//! a method or a render.
pub mod fs;
pub mod hash;
pub mod input;
pub mod mem;
