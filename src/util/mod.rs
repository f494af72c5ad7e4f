//! Small services below every other layer: content hashes (`hash`), atomic file writes and
//! temporary names (`fs`), the one way to open an input file (`input`), and the process's memory
//! figures (`mem`), text from input made safe to print (`text`). Nothing here knows a scene,
//! a method or a render.
pub mod fs;
pub mod hash;
pub mod input;
pub mod mem;
pub mod text;
