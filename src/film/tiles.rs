//! The image plane in tiles: the unit of parallel work of every pass over a frame, placed back
//! by index so that frames do not depend on the order tiles finish in.

/// Side of a square tile, in pixels.
pub const TILE: u32 = 16;

/// A tile as (x0, y0, x1, y1), half-open.
pub type Tile = (u32, u32, u32, u32);

/// The tiles of a `w` x `h` image, row by row.
pub fn tiles(w: u32, h: u32) -> Vec<Tile> {
    tiles_in((0, 0, w, h), TILE)
}

/// The tiles of side `side` of the area `(x0, y0, x1, y1)` (an image, or a block of tiles),
/// row by row; those at its right and bottom edges are cut to it.
pub fn tiles_in((x0, y0, x1, y1): Tile, side: u32) -> Vec<Tile> {
    let mut v = Vec::new();
    for ty in (y0..y1).step_by(side as usize) {
        for tx in (x0..x1).step_by(side as usize) {
            v.push((tx, ty, (tx + side).min(x1), (ty + side).min(y1)));
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
