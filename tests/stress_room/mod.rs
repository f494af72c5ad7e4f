//! The numbers of the stress room (`occluders`, `fast-pan`, `cut`), shared by the generator that
//! writes its geometry (`examples/make_scenes.rs`) and by the test that predicts its reuse losses
//! in plan (`tests/stress.rs`), so that the two cannot drift apart.
#![allow(dead_code)]

/// The room: x in [X0, X1], y in [0, Y1], z in [Z0, Z1] (metres).
pub const X0: f64 = -9.0;
pub const X1: f64 = 9.0;
pub const Y1: f64 = 3.0;
pub const Z0: f64 = -3.0;
pub const Z1: f64 = 7.0;
/// Side of the square, floor-to-ceiling pillars.
pub const PILLAR: f64 = 0.3;

/// A row of pillars: the first centre's x, how many (one metre apart), the row's z.
pub struct Row {
    pub first_x: f64,
    pub count: usize,
    pub z: f64,
}

/// Pillars in front of the back wall (z = Z0) and of the front wall (z = Z1).
pub const BACK_PILLARS: Row = Row {
    first_x: -8.5,
    count: 18,
    z: -1.0,
};
pub const FRONT_PILLARS: Row = Row {
    first_x: -8.0,
    count: 17,
    z: 5.0,
};

impl Row {
    /// The pillars' centres (x, z).
    pub fn centres(&self) -> impl Iterator<Item = (f64, f64)> + '_ {
        (0..self.count).map(|k| (self.first_x + k as f64, self.z))
    }
}
