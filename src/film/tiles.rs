//! The image plane in tiles: the unit of parallel work of every pass over a frame, placed back
//! by index so that frames do not depend on the order tiles finish in.

/// Side of a square tile, in pixels.
pub const TILE: u32 = 16;

/// A tile as (x0, y0, x1, y1), half-open.
pub type Tile = (u32, u32, u32, u32);

/// The tiles of a `w` x `h` image, row by row.
pub fn tiles(w: u32, h: u32) -> Vec<Tile> {
    tiles_of(w, h, TILE)
}

/// The tiles of side `side` of a `w` x `h` image, row by row.
pub fn tiles_of(w: u32, h: u32, side: u32) -> Vec<Tile> {
    let mut v = Vec::new();
    for y0 in (0..h).step_by(side as usize) {
        for x0 in (0..w).step_by(side as usize) {
            v.push((x0, y0, (x0 + side).min(w), (y0 + side).min(h)));
        }
    }
    v
}

/// Copy a tile's values (row by row, as `tiles` gives them) into their place in a `w`-wide frame.
pub fn place_tile<T: Copy>(frame: &mut [T], w: u32, (x0, y0, x1, _): Tile, values: &[T]) {
    let tw = (x1 - x0) as usize;
    for (row, v) in values.chunks(tw).enumerate() {
        let start = ((y0 + row as u32) * w + x0) as usize;
        frame[start..start + tw].copy_from_slice(v);
    }
}
