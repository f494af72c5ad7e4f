//! The OBJ reader: the statements a renderer of triangles needs (`v`, `vn`, `f`, `usemtl`,
//! `mtllib`), read the way production loaders read real exports, with every face keeping its
//! line for messages.
//!
//! Read as usual: any whitespace between words, CRLF line ends, a byte order mark, a statement
//! continued after a `\` at the end of its line. Lenient where a model is still unambiguous,
//! with one counted warning per kind (`Repairs`): lines that are not UTF-8 (read as Latin-1), a
//! zero or non-finite `vn` (the triangles using it are flat-shaded), faces of fewer than three
//! distinct vertices (skipped), points `p` and polylines `l` (ignored), vertex colours
//! (ignored).
//! Texture coordinates (`vt u [v [w]]`, `v` 0 if left out, `w` ignored) are kept for the
//! textures of `map_Kd`, `map_Ks`, `map_Ke` and `map_d`. Statements reframe does not draw (`o`, `g`, `s`,
//! `vp`, curves) are skipped silently. Refused, naming the line: a position that is not finite
//! or is larger than `MAX_COORD`, a texture coordinate that is not finite, a malformed `v`, `vt`,
//! `vn` or face vertex, a face index of 0 or one that refers
//! past the elements defined above it, a face of more than `MAX_CORNERS` corners, and a
//! `usemtl` or `mtllib` without a name.
use super::repairs::{Kind, Repairs};
use super::text::{
    canonical, did_you_mean, joined, latin1_bytes, lines, number, numbers, quote, rest, MAX_COORD,
};
use anyhow::{anyhow, Result};
use glam::{DVec3, Vec2, Vec3};

/// Most corners of one face: no modelling package writes more, and a face's split
/// (`mesh::triangulate`) and checks grow faster than linearly with its corners (ear clipping
/// took 9 s for a circle of 200,000 corners; large faces are now split by a constrained
/// Delaunay triangulation, about n log n).
pub const MAX_CORNERS: usize = 65_536;

pub const BAD_NORMAL: Kind = Kind {
    one: "zero or non-finite normal: its triangles are flat-shaded",
    many: "zero or non-finite normals: their triangles are flat-shaded",
};
pub const SHORT_FACE: Kind = Kind {
    one: "face of fewer than 3 distinct vertices skipped",
    many: "faces of fewer than 3 distinct vertices skipped",
};
pub const POINTS: Kind = Kind {
    one: "points (p) ignored: reframe renders faces only",
    many: "points statements (p) ignored: reframe renders faces only",
};
pub const FREE_FORM: Kind = Kind {
    one: "free-form geometry statement ignored (curves and surfaces are not rendered)",
    many: "free-form geometry statements ignored (curves and surfaces are not rendered)",
};
/// `call`: another OBJ's geometry read in at that point, which reframe does not do.
pub const CALL: Kind = Kind {
    one: "call ignored: the file it names is not read (give its geometry as an [[object]] of \
          the scene)",
    many: "call statements ignored: the files they name are not read (give their geometry as \
           [[object]]s of the scene)",
};
pub const POLYLINES: Kind = Kind {
    one: "polyline (l) ignored: reframe renders faces only",
    many: "polylines (l) ignored: reframe renders faces only",
};
const WEIGHTS: Kind = Kind {
    one: "vertex weight w ignored (it weights rational curves and surfaces, not polygon corners)",
    many:
        "vertex weights w ignored (they weight rational curves and surfaces, not polygon corners)",
};
const NONE_DEFINED_VN: Kind = Kind {
    one: "face with normal indices where no normal (vn) is defined above: they are ignored (the \
          face is shaded flat)",
    many: "faces with normal indices where no normal (vn) is defined above: they are ignored \
           (the faces are shaded flat)",
};
const NONE_DEFINED_VT: Kind = Kind {
    one: "face with texture coordinate indices where none (vt) is defined above: they are \
          ignored",
    many: "faces with texture coordinate indices where none (vt) is defined above: they are \
           ignored",
};
pub const UNKNOWN: Kind = Kind {
    one: "statement the OBJ format does not have: ignored",
    many: "statements the OBJ format does not have: ignored",
};
const COLOURS: Kind = Kind {
    one: "vertex colour ignored",
    many: "vertex colours ignored",
};

/// One corner of a face: a position index and, if given, a texture coordinate index and (if
/// usable) a normal index (0-based).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Corner {
    pub v: u32,
    pub vt: Option<u32>,
    pub vn: Option<u32>,
}

/// A face: its line, the `usemtl` in force (an index into `Obj::usemtl`), its corners.
#[derive(Clone, Debug)]
pub struct Face {
    pub line: usize,
    pub usemtl: Option<u32>,
    pub corners: std::ops::Range<usize>,
}

#[derive(Default, Debug)]
pub struct Obj {
    pub positions: Vec<Vec3>,
    /// Texture coordinates `(u, v)`, as given.
    pub uvs: Vec<Vec2>,
    /// Unit normals; `None` for a zero or non-finite `vn` (already warned about).
    pub normals: Vec<Option<Vec3>>,
    pub corners: Vec<Corner>,
    pub faces: Vec<Face>,
    /// Each `mtllib`: its line and the rest of the line (file names, as bytes).
    pub mtllib: Vec<(usize, Vec<u8>)>,
    /// Each `usemtl`: its line and the material's name.
    pub usemtl: Vec<(usize, String)>,
    /// The point `positions` are given from: zero, or where the file's vertices lie far from
    /// the origin (`scene::render_origin` of their box), the box's centre, subtracted from each
    /// vertex in f64 before it is rounded to f32 (a vertex at 3x10^5 keeps its fraction; f32
    /// there rounds to 1/32 unit).
    pub anchor: DVec3,
}

/// Room for one more element of `v` (`util::mem::grow`): the reader's lists are the first large
/// allocations of a large scene, and one that fails aborts the process (a 26 MB OBJ under a
/// tight `ulimit -v` ended in a backtrace, exit 134), where this is an error naming the line.
#[inline]
fn room<T>(v: &mut Vec<T>, label: &str, n: usize) -> Result<()> {
    if !crate::util::mem::grow(v) {
        return Err(anyhow!(
            "{label}: line {n}: reading the OBJ needs more memory than is left ({} held for its \
             lists so far){}",
            crate::util::mem::size((v.capacity() * std::mem::size_of::<T>()) as u64),
            crate::util::mem::address_space_note()
        ));
    }
    Ok(())
}

/// Read an OBJ file; `label` names it in errors ("label: line N: 'statement': why") and repairs.
pub fn parse(label: &str, bytes: &[u8], repairs: &mut Repairs) -> Result<Obj> {
    let mut out = Obj::default();
    // Elements defined so far: positions, texture coordinates, normals.
    let mut count = [0usize; 3];
    let mut usemtl = None;
    // The smoothing group in force (`s 1`; 0 for `s off` or `s 0`), and each face's.
    let mut smooth = 0u32;
    let mut face_smooth: Vec<u32> = Vec::new();
    // The vertices f32 rounds by more than 10^-4 (a coordinate from `ROUNDS_FROM`), read in f64
    // too, by index: for `Obj::anchor`.
    let mut exact: Vec<(u32, DVec3)> = Vec::new();
    for line in joined(lines(bytes).map_err(|e| anyhow!("{label}: {e}"))?) {
        let (n, text) = (line.n, line.text.as_ref());
        let err = |msg: String| anyhow!("{label}: line {n}: '{}': {msg}", quote(text));
        let Some((key, args)) = line.statement(label, repairs)? else {
            continue;
        };
        let key = canonical(key, &KEYS);
        match key {
            "v" => {
                let shape = "expected 'v x y z', 'v x y z w' or 'v x y z r g b'";
                let p = numbers::<3>(&args).ok_or_else(|| err(shape.into()))?;
                match args.len() {
                    3 => {}
                    // The weight of a rational curve or surface's control point (the OBJ
                    // format's own definition); a polygon's corner is at x, y, z whatever it
                    // says, as other OBJ readers take it (dividing by it moved every corner).
                    4 => {
                        let w = number(args[3]).ok_or_else(|| err(shape.into()))?;
                        if w != 1.0 {
                            repairs.note(label, n, WEIGHTS, || format!("'{}'", quote(text)))?;
                        }
                    }
                    // A colour of red, green and blue, or with alpha (MeshLab, photogrammetry).
                    6 | 7 => {
                        numbers::<3>(&args[3..])
                            .ok_or_else(|| err("the vertex colour must be three numbers".into()))?;
                        repairs.note(label, n, COLOURS, || format!("'{}'", quote(text)))?;
                    }
                    _ => return Err(err(shape.into())),
                }
                count[0] += 1;
                if !p.iter().all(|c| c.is_finite()) {
                    let why = super::text::beyond_f32(p.iter().copied());
                    return Err(err(format!("vertex {} is not finite{why}", count[0])));
                }
                if let Some(c) = p.iter().find(|c| c.abs() > MAX_COORD) {
                    return Err(err(format!(
                        "vertex {}: coordinate {c:e} is too large (at most {MAX_COORD:e})",
                        count[0]
                    )));
                }
                if p.iter().any(|c| c.abs() >= ROUNDS_FROM) {
                    let e = DVec3::from(numbers64::<3>(&args).unwrap_or(p.map(f64::from)));
                    exact.push((out.positions.len() as u32, e));
                }
                room(&mut out.positions, label, n)?;
                out.positions.push(Vec3::from(p));
            }
            "vt" => {
                // `v` and `w` are optional; `w` (3D textures) is not used.
                let t: Option<Vec<f32>> = args.iter().map(|a| number(a)).collect();
                let t = match t {
                    Some(t) if (1..=3).contains(&t.len()) => t,
                    _ => return Err(err("expected 'vt u [v [w]]'".into())),
                };
                count[1] += 1;
                if !t.iter().all(|c| c.is_finite()) {
                    return Err(err(format!(
                        "texture coordinate {} is not finite",
                        count[1]
                    )));
                }
                room(&mut out.uvs, label, n)?;
                out.uvs
                    .push(Vec2::new(t[0], t.get(1).copied().unwrap_or(0.0)));
            }
            "vn" => {
                let v = numbers::<3>(&args).ok_or_else(|| err("expected 'vn x y z'".into()))?;
                count[2] += 1;
                // In f64: a finite normal of huge components still has a direction.
                let d = glam::DVec3::new(v[0] as f64, v[1] as f64, v[2] as f64);
                let len = d.length();
                room(&mut out.normals, label, n)?;
                if len.is_finite() && len > 0.0 {
                    out.normals.push(Some((d / len).as_vec3()));
                } else {
                    repairs.note(label, n, BAD_NORMAL, || {
                        format!("'{}' (normal {})", quote(text), count[2])
                    })?;
                    out.normals.push(None);
                }
            }
            // `fo` is the format's older name for a face.
            "f" | "fo" => {
                if args.len() > MAX_CORNERS {
                    return Err(err(format!(
                        "a face of {} corners: at most {MAX_CORNERS} (split it into smaller \
                         faces)",
                        args.len()
                    )));
                }
                let start = out.corners.len();
                let mut none_defined = [false; 2];
                for r in &args {
                    let (c, ignored) = corner(r, &count, &out.normals).map_err(&err)?;
                    none_defined[0] |= ignored[0];
                    none_defined[1] |= ignored[1];
                    room(&mut out.corners, label, n)?;
                    out.corners.push(c);
                }
                for (kind, ignored) in [NONE_DEFINED_VT, NONE_DEFINED_VN]
                    .into_iter()
                    .zip(none_defined)
                {
                    if ignored {
                        repairs.note(label, n, kind, || format!("'{}'", quote(text)))?;
                    }
                }
                // A polygon that comes back to the vertex it left (or stays on one) has fewer
                // sides than it has corners.
                let face = &mut out.corners[start..];
                let mut distinct: Vec<u32> = face.iter().map(|c| c.v).collect();
                distinct.sort_unstable();
                distinct.dedup();
                if distinct.len() < 3 {
                    out.corners.truncate(start);
                    repairs.note(label, n, SHORT_FACE, || format!("'{}'", quote(text)))?;
                    continue;
                }
                room(&mut out.faces, label, n)?;
                out.faces.push(Face {
                    line: n,
                    usemtl,
                    corners: start..out.corners.len(),
                });
                room(&mut face_smooth, label, n)?;
                face_smooth.push(smooth);
            }
            "p" => repairs.note(label, n, POINTS, || format!("'{}'", quote(text)))?,
            "l" => repairs.note(label, n, POLYLINES, || format!("'{}'", quote(text)))?,
            // Geometry from another file: lost without a word when it was passed over.
            "call" => repairs.note(label, n, CALL, || format!("'{}'", quote(text)))?,
            // Free-form geometry (Rhino, Maya exports; `bsp`, `bzp`, `cdc` and `cdp` are the
            // format's older patches): curves and surfaces are not tessellated.
            "cstype" | "deg" | "bmat" | "step" | "curv" | "curv2" | "surf" | "parm" | "trim"
            | "hole" | "scrv" | "sp" | "end" | "con" | "vp" | "bsp" | "bzp" | "cdc" | "cdp" => {
                repairs.note(label, n, FREE_FORM, || format!("'{}'", quote(text)))?
            }
            "usemtl" | "mtllib" => {
                let name = rest(text);
                // An empty material name is a name: Blender 2.61 wrote `usemtl` and `newmtl`
                // with none for a material it had not named, and other readers match the two.
                if name.is_empty() && key == "mtllib" {
                    return Err(err("expected 'mtllib file'".into()));
                }
                if key == "usemtl" {
                    usemtl = Some(out.usemtl.len() as u32);
                    out.usemtl.push((n, name.to_string()));
                } else {
                    let bytes = if line.latin1 {
                        latin1_bytes(name)
                    } else {
                        name.as_bytes().to_vec()
                    };
                    out.mtllib.push((n, bytes));
                }
            }
            // A smoothing group: its faces' corners without normals get the group's
            // (`smoothing_normals`). `off`, 0, or a word that is no number: none.
            "s" => smooth = smoothing_group(&args),
            // Groups, merging groups and display and rendering attributes: nothing reframe
            // renders differently.
            k if PASSED_OVER.contains(&k) => {}
            // Anything else is no OBJ statement: a misspelt `usemtl` (its faces kept the
            // material before it, and the scene lost its light without a word), another
            // format's line.
            _ => repairs.note(label, n, UNKNOWN, || {
                let hint = did_you_mean(key, KEYS.iter().chain(&PASSED_OVER).copied());
                format!("'{}'{hint}", quote(text))
            })?,
        }
    }
    // The box of the vertices the faces use, in f64: an unused vertex (a stray `v 0 0 0` left
    // by an exporter) must not keep a far scene from being moved (it lost 6.5% of its light).
    let mut used = vec![false; out.positions.len()];
    for c in &out.corners {
        used[c.v as usize] = true;
    }
    let (mut lo, mut hi) = (DVec3::INFINITY, DVec3::NEG_INFINITY);
    let mut far = exact.iter().peekable();
    for (i, p) in out.positions.iter().enumerate() {
        let e = match far.next_if(|(j, _)| *j as usize == i) {
            Some((_, e)) => *e,
            None => p.as_dvec3(),
        };
        if used[i] {
            (lo, hi) = (lo.min(e), hi.max(e));
        }
    }
    out.anchor = super::render_origin(lo, hi);
    if out.anchor != DVec3::ZERO {
        for p in out.positions.iter_mut() {
            *p = (p.as_dvec3() - out.anchor).as_vec3();
        }
        for (i, e) in exact {
            out.positions[i as usize] = (e - out.anchor).as_vec3();
        }
    }
    // From the positions as rendered (near the origin: far out, f32 rounds them to half a unit
    // at 5e6, and the normals came out of that rounding).
    smoothing_normals(&mut out, &face_smooth, label)?;
    Ok(out)
}

/// The statements reframe reads, read in any case (`V`, `VT`, `F`, `Usemtl`: old exporters
/// write capitals, which were unknown statements and the file's geometry lost;
/// `text::canonical`).
const KEYS: [&str; 11] = [
    "v", "vt", "vn", "f", "fo", "usemtl", "mtllib", "s", "l", "p", "call",
];

/// Statements passed over without a word: groups, merging groups, and display and rendering
/// attributes, nothing reframe renders differently.
const PASSED_OVER: [&str; 15] = [
    "o",
    "g",
    "mg",
    "bevel",
    "c_interp",
    "d_interp",
    "lod",
    "shadow_obj",
    "trace_obj",
    "usemap",
    "maplib",
    "ctech",
    "stech",
    "csh",
    "res",
];

/// The smoothing group an `s` statement names: 0 for `off` and 0 (none), its number for a
/// whole number from 1 (one written `1.0` too), 1 for `on` or a number past u32 (a group all
/// the same), and 0 for anything else (no number), as before groups were read.
fn smoothing_group(args: &[&str]) -> u32 {
    let Some(a) = args.first() else { return 0 };
    if a.eq_ignore_ascii_case("on") {
        return 1;
    }
    match a.parse::<f64>() {
        Ok(x) if x >= 1.0 && x.fract() == 0.0 => {
            if x <= u32::MAX as f64 {
                x as u32
            } else {
                1
            }
        }
        _ => 0,
    }
}

/// Normals for the corners without one of faces in a smoothing group (`smooth[f]`, 0 for
/// none), as the format means `s 1` and as Blender's importer and Mitsuba 3 (which smooths every
/// face without `vn`) read it: each vertex of a group gets the sum of the unit normals of the
/// group's faces around it, each weighted by the face's angle at that vertex (Thürmer and
/// Wüthrich's weights, Mitsuba's and Blender's), normalised. A low-poly sphere exported with
/// `s 1` and no `vn` rendered faceted, without a word. A face's normal is Newell's, from its
/// corners in order (the side its counter-clockwise winding faces, as the triangles' own).
/// Where the sum nearly cancels (below a millionth of its weights: a surface made two-sided by a
/// reversed copy on the same vertices) the corner stays flat-shaded, as it does where a face
/// has no area; faces outside any group, and corners with a `vn`, are as they were.
///
/// The sums are kept per vertex for the first group met there, and in a map for any other
/// group at that vertex (rare but for files that give every face a group of its own), so that a
/// mesh of millions of faces in one group costs two arrays the size of its vertices.
fn smoothing_normals(out: &mut Obj, smooth: &[u32], label: &str) -> Result<()> {
    use std::collections::HashMap;
    let needs = |o: &Obj, f: usize| {
        smooth[f] != 0
            && o.corners[o.faces[f].corners.clone()]
                .iter()
                .any(|c| c.vn.is_none())
    };
    if !(0..out.faces.len()).any(|f| needs(out, f)) {
        return Ok(());
    }
    let nv = out.positions.len();
    let fallible = |what: &str| {
        anyhow!(
            "{label}: the smooth normals of {nv} vertices need more memory than is left ({what}){}",
            crate::util::mem::address_space_note()
        )
    };
    // Per vertex: the first group met (0: none yet), its weighted sum and its total weight.
    let mut first: Vec<u32> = Vec::new();
    let mut sum: Vec<(DVec3, f64)> = Vec::new();
    first
        .try_reserve_exact(nv)
        .map_err(|_| fallible("groups"))?;
    sum.try_reserve_exact(nv).map_err(|_| fallible("sums"))?;
    first.resize(nv, 0);
    sum.resize(nv, (DVec3::ZERO, 0.0));
    let mut other: HashMap<(u32, u32), (DVec3, f64)> = HashMap::new();
    for (f, face) in out.faces.iter().enumerate() {
        if !needs(out, f) {
            continue;
        }
        let cs = &out.corners[face.corners.clone()];
        let p = |i: usize| out.positions[cs[i % cs.len()].v as usize].as_dvec3();
        let mut n = DVec3::ZERO;
        for i in 0..cs.len() {
            let (a, b) = (p(i), p(i + 1));
            n += DVec3::new(
                (a.y - b.y) * (a.z + b.z),
                (a.z - b.z) * (a.x + b.x),
                (a.x - b.x) * (a.y + b.y),
            );
        }
        let Some(n) = n.try_normalize() else {
            continue;
        };
        let g = smooth[f];
        for (i, c) in cs.iter().enumerate() {
            if c.vn.is_some() {
                continue;
            }
            let (e1, e2) = (p(i + 1) - p(i), p(i + cs.len() - 1) - p(i));
            let angle = e1.cross(e2).length().atan2(e1.dot(e2));
            let v = c.v as usize;
            if first[v] == 0 {
                first[v] = g;
            }
            let s = if first[v] == g {
                &mut sum[v]
            } else {
                other.entry((c.v, g)).or_default()
            };
            s.0 += angle * n;
            s.1 += angle;
        }
    }
    // The normal of a sum, if it does not (nearly) cancel.
    let unit = |(s, w): (DVec3, f64)| (s.length() > 1e-6 * w).then(|| s.normalize().as_vec3());
    // Normals added in the order of the vertices, then of the other groups by vertex (not the
    // map's order), so that a file loads the same every time.
    let mut index: Vec<u32> = Vec::new();
    index
        .try_reserve_exact(nv)
        .map_err(|_| fallible("indices"))?;
    let most = first.iter().filter(|&&g| g != 0).count() + other.len();
    out.normals
        .try_reserve(most)
        .map_err(|_| fallible("normals"))?;
    for v in 0..nv {
        let i = match (first[v] != 0).then(|| unit(sum[v])).flatten() {
            Some(n) => {
                out.normals.push(Some(n));
                out.normals.len() as u32 - 1
            }
            None => u32::MAX,
        };
        index.push(i);
    }
    let mut others: Vec<((u32, u32), (DVec3, f64))> = other.into_iter().collect();
    others.sort_unstable_by_key(|(k, _)| *k);
    let mut other_index: HashMap<(u32, u32), u32> = HashMap::with_capacity(others.len());
    for (k, s) in others {
        if let Some(n) = unit(s) {
            out.normals.push(Some(n));
            other_index.insert(k, out.normals.len() as u32 - 1);
        }
    }
    for (f, face) in out.faces.iter().enumerate() {
        let g = smooth[f];
        if g == 0 {
            continue;
        }
        for c in &mut out.corners[face.corners.clone()] {
            if c.vn.is_none() {
                let v = c.v as usize;
                c.vn = if first[v] == g {
                    Some(index[v]).filter(|&i| i != u32::MAX)
                } else {
                    other_index.get(&(c.v, g)).copied()
                };
            }
        }
    }
    Ok(())
}

/// The magnitude from which f32 rounds a coordinate by more than 10^-4 (its step is 1.2x10^-4
/// from 1024): an OBJ's vertices there are read in f64 too, for `Obj::anchor`.
const ROUNDS_FROM: f32 = 1024.0;

/// `numbers` in f64.
fn numbers64<const N: usize>(words: &[&str]) -> Option<[f64; N]> {
    let mut v = [0.0; N];
    for (x, w) in v.iter_mut().zip(words.get(..N)?) {
        *x = w.parse().ok()?;
    }
    Some(v)
}

/// One face vertex `v`, `v/vt`, `v//vn` or `v/vt/vn`, checked against the elements defined
/// above it (`count`: positions, texture coordinates, normals). A normal that is not usable
/// (`normals[i]` is `None`) is left out, so its triangles are flat-shaded.
///
/// A texture coordinate or normal index where the file has defined none of them above
/// (OpenSubdiv's and some scanners' `f v/vt/vn` with no `vn` lines) is ignored, as other OBJ
/// readers ignore it: the second value says so, for a warning, of the texture coordinate and
/// of the normal (the warning said both were, where the texture coordinates were used). One
/// beyond those defined is damage, and refused.
fn corner(
    r: &str,
    count: &[usize; 3],
    normals: &[Option<Vec3>],
) -> Result<(Corner, [bool; 2]), String> {
    let shape = || format!("'{r}': expected v, v/vt, v//vn or v/vt/vn (1-based indices)");
    let parts: Vec<&str> = r.split('/').collect();
    if parts.len() > 3 || parts[0].is_empty() {
        return Err(shape());
    }
    let mut c = Corner {
        v: 0,
        vt: None,
        vn: None,
    };
    let mut ignored = [false; 2];
    for (k, p) in parts.iter().enumerate() {
        if p.is_empty() {
            continue;
        }
        let x: i64 = p.parse().map_err(|_| shape())?;
        let (what, n) = (["vertex", "texture coordinate", "normal"][k], count[k]);
        if k > 0 && n == 0 && x != 0 {
            ignored[k - 1] = true;
            continue;
        }
        let i = match x {
            0 => return Err(format!("{what} index 0: OBJ indices start at 1")),
            x if x > 0 && (x as u64) <= n as u64 => x as usize - 1,
            x if x < 0 && x.unsigned_abs() <= n as u64 => n - x.unsigned_abs() as usize,
            x if x > 0 => {
                return Err(format!(
                    "{what} index {x} is out of range: {n} defined above this line"
                ))
            }
            x => {
                return Err(format!(
                    "{what} index {x} reaches back before the first: {n} defined above this line"
                ))
            }
        };
        match k {
            0 => c.v = i as u32,
            1 => c.vt = Some(i as u32),
            _ => c.vn = normals[i].map(|_| i as u32),
        }
    }
    Ok((c, ignored))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn parse_ok(text: &str) -> (Obj, Vec<String>) {
        let mut r = Repairs::new(false);
        let o = parse("a.obj", text.as_bytes(), &mut r).unwrap();
        (o, r.into_warnings())
    }

    /// A unit cube's 8 corners and its 6 faces, wound counter-clockwise seen from outside, each
    /// face after the line `groups[k]` (`s 1`, `s off`, ...).
    fn cube(groups: [&str; 6]) -> String {
        let mut t = String::new();
        for z in [-1, 1] {
            for y in [-1, 1] {
                for x in [-1, 1] {
                    t += &format!("v {x} {y} {z}\n");
                }
            }
        }
        // Vertex (x, y, z) is 1 + (x > 0) + 2 (y > 0) + 4 (z > 0).
        let faces = [
            "1 3 4 2", "5 6 8 7", "1 2 6 5", "3 7 8 4", "1 5 7 3", "2 4 8 6",
        ];
        for (g, f) in groups.iter().zip(faces) {
            t += &format!("{g}\nf {f}\n");
        }
        t
    }

    /// The normal of each corner of face `f`, `None` where it has none.
    fn corner_normals(o: &Obj, f: usize) -> Vec<Option<Vec3>> {
        o.corners[o.faces[f].corners.clone()]
            .iter()
            .map(|c| c.vn.and_then(|i| o.normals[i as usize]))
            .collect()
    }

    #[test]
    fn smoothing_groups_give_faces_without_normals_smooth_ones() {
        // One group: each corner is on three faces, at right angles: the diagonal outwards.
        let (o, warnings) = parse_ok(&cube(["s 1"; 6]));
        assert!(warnings.is_empty(), "{warnings:?}");
        for f in 0..6 {
            for (c, n) in o.corners[o.faces[f].corners.clone()]
                .iter()
                .zip(corner_normals(&o, f))
            {
                let want = o.positions[c.v as usize].normalize();
                let n = n.expect("a normal");
                assert!((n - want).length() < 1e-6, "face {f}: {n} against {want}");
            }
        }
        // A group per face: each face its own flat normal, outwards.
        let groups = ["s 1", "s 2", "s 3", "s 4", "s 5", "s 6"];
        let (o, _) = parse_ok(&cube(groups));
        let outwards = [-Vec3::Z, Vec3::Z, -Vec3::Y, Vec3::Y, -Vec3::X, Vec3::X];
        for (f, want) in outwards.into_iter().enumerate() {
            for n in corner_normals(&o, f) {
                assert!((n.unwrap() - want).length() < 1e-6, "face {f}: {n:?}");
            }
        }
        // Off (or 0), and faces before any `s`: no normals, flat-shaded as before; a `vn`
        // given stays the one given.
        let (o, _) = parse_ok(&cube(["", "s off", "s 0", "s 1", "s 1", "s 1"]));
        for f in 0..3 {
            assert!(
                corner_normals(&o, f).iter().all(Option::is_none),
                "face {f}"
            );
        }
        assert!(corner_normals(&o, 3).iter().all(Option::is_some));
        let text = cube(["s 1"; 6]).replace("f 1 3 4 2", "f 1//1 3//1 4//1 2//1");
        let (o, _) = parse_ok(&format!("vn 0 0 1\n{text}"));
        assert!(corner_normals(&o, 0).iter().all(|n| *n == Some(Vec3::Z)));
        // `on`, `1.0` and a number past u32 are groups; words that are no number are not.
        for (s, smooth) in [("s on", true), ("s 1.0", true), ("s 4294967296", true)] {
            let (o, _) = parse_ok(&cube([s; 6]));
            assert_eq!(corner_normals(&o, 0)[0].is_some(), smooth, "{s}");
        }
        let (o, _) = parse_ok(&cube(["s x"; 6]));
        assert!(corner_normals(&o, 0).iter().all(Option::is_none));
    }

    #[test]
    fn statements_in_capitals_are_read() {
        // Old exporters write capitals: the geometry and its material were unknown statements.
        let (o, warnings) = parse_ok("MTLLIB s.mtl\nV 0 0 0\nV 1 0 0\nVT 0 1\nVn 0 0 1\nV 0 1 0\nUSEMTL m\nF 1/1/1 2/1/1 3/1/1\n");
        assert!(warnings.is_empty(), "{warnings:?}");
        assert_eq!((o.positions.len(), o.uvs.len(), o.faces.len()), (3, 1, 1));
        assert_eq!(o.usemtl, vec![(7, "m".to_string())]);
        assert_eq!(o.mtllib, vec![(1, b"s.mtl".to_vec())]);
    }

    #[test]
    fn smooth_normals_are_of_the_positions_as_rendered_and_flat_where_they_cancel() {
        // The cube 5e6 units out, where f32 steps are half a unit: moved to the origin first
        // (`Obj::anchor`), its normals are the diagonals to the float, as at the origin.
        let far: String = cube(["s 1"; 6])
            .lines()
            .map(|l| match l.strip_prefix("v ") {
                Some(p) => {
                    let c: Vec<f64> = p.split(' ').map(|x| x.parse().unwrap()).collect();
                    format!("v {} {} {}\n", c[0] + 5e6, c[1] - 5e6, c[2] + 5e6)
                }
                None => format!("{l}\n"),
            })
            .collect();
        let (o, _) = parse_ok(&far);
        assert_ne!(o.anchor, DVec3::ZERO);
        for f in 0..6 {
            for (c, n) in o.corners[o.faces[f].corners.clone()]
                .iter()
                .zip(corner_normals(&o, f))
            {
                let want = o.positions[c.v as usize].normalize();
                assert!(
                    (n.unwrap() - want).length() < 1e-6,
                    "face {f}: {n:?} against {want}"
                );
            }
        }
        // A quad made two-sided by a reversed copy on the same vertices: its normals cancel,
        // and it stays flat-shaded (a rounding remainder was a normal pointing anywhere).
        let quad = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\ns 1\nf 1 2 3 4\nf 4 3 2 1\n";
        let (o, _) = parse_ok(quad);
        for f in 0..2 {
            assert!(
                corner_normals(&o, f).iter().all(Option::is_none),
                "face {f}"
            );
        }
    }

    #[test]
    fn microsoft_non_finite_numbers_are_read_as_non_finite() {
        // Old 3ds Max exports: a normal of `-1.#IND00` is a normal that is not finite (its
        // triangles flat-shaded, with the usual warning), not a malformed statement.
        let obj = "v 0 0 0\nv 1 0 0\nv 0 1 0\nvn -1.#IND00 -1.#IND00 -1.#IND00\n\
                   vn 0 0 1\nf 1//1 2//2 3//2\n";
        let (o, w) = parse_ok(obj);
        assert_eq!(o.normals, vec![None, Some(Vec3::Z)]);
        assert_eq!(w.len(), 1, "{w:?}");
        assert!(
            w[0].contains("'vn -1.#IND00 -1.#IND00 -1.#IND00' (normal 1)"),
            "{w:?}"
        );
        assert_eq!(number("1.#INF00"), Some(f32::INFINITY));
        assert_eq!(number("-1.#INF"), Some(f32::NEG_INFINITY));
        assert!(number("1.#QNAN0").unwrap().is_nan());
        assert!(number("-1.#SNAN").unwrap().is_nan());
        assert!(number("-1.#IND").unwrap().is_nan());
        assert_eq!(number("1.5"), Some(1.5));
        // Visual Studio 2015 and later (the Universal CRT: instant-ngp's marching-cubes OBJs
        // hold `vn -nan(ind) -nan(ind) -nan(ind)`), and the C standard's `nan(chars)`.
        for nan in [
            "-nan(ind)",
            "nan(ind)",
            "nan(snan)",
            "-NAN(IND)",
            "+nan(0x7fc)",
            "nan()",
        ] {
            assert!(number(nan).is_some_and(f32::is_nan), "{nan}");
        }
        let (o, w) = parse_ok(&obj.replace("-1.#IND00", "-nan(ind)"));
        assert_eq!(o.normals, vec![None, Some(Vec3::Z)]);
        assert_eq!(w.len(), 1, "{w:?}");
        for bad in [
            "#IND",
            "1.#",
            "1.#FOO",
            "x.#INF",
            "1#2",
            "nan(",
            "nan(a b)",
            "nan(-)",
            "--nan(ind)",
            "nanx)",
        ] {
            assert_eq!(number(bad), None, "{bad}");
        }
    }

    #[test]
    fn a_vertex_weight_leaves_the_corner_where_it_is() {
        // tinyobjloader's cube with weights: dividing by w had stretched it into a sliver.
        let (o, w) = parse_ok("v 0 2 2 0.1\nv 1 0 0 1\nv 0 1 0 1.0\nv 3 4 5 0\nf 1 2 3\n");
        assert_eq!(o.positions[0], Vec3::new(0.0, 2.0, 2.0));
        assert_eq!(o.positions[3], Vec3::new(3.0, 4.0, 5.0));
        // One warning, for the weights other than 1.
        assert_eq!(w.len(), 1, "{w:?}");
        assert!(
            w[0].starts_with("a.obj: 2 vertex weights w ignored"),
            "{w:?}"
        );
        assert!(w[0].ends_with("(first at line 1: 'v 0 2 2 0.1')"), "{w:?}");
    }

    #[test]
    fn indices_of_what_no_line_defines_are_ignored() {
        // OpenSubdiv writes `f v/vt/vn` with neither `vt` nor `vn` lines.
        let obj = "v 0 0 0\nv 1 0 0\nv 1 1 0\nf 1/1/1 2/2/2 3/3/3\nvt 0 0\nf 1/1/1 2/1 3\n";
        let (o, w) = parse_ok(obj);
        assert_eq!(o.faces.len(), 2);
        let first = &o.corners[o.faces[0].corners.clone()];
        assert!(
            first.iter().all(|c| c.vt.is_none() && c.vn.is_none()),
            "{first:?}"
        );
        assert_eq!(first.iter().map(|c| c.v).collect::<Vec<_>>(), [0, 1, 2]);
        // Once a `vt` is defined, its index is read; the normal's still is not.
        let second = &o.corners[o.faces[1].corners.clone()];
        assert_eq!(second[0].vt, Some(0));
        assert_eq!(second[0].vn, None);
        // Said of each kind apart: the texture coordinates of the first face only, the
        // normals of both.
        assert_eq!(w.len(), 2, "{w:?}");
        assert!(
            w[0].starts_with(
                "a.obj: line 4: 'f 1/1/1 2/2/2 3/3/3': face with texture coordinate indices \
                 where none (vt) is defined above"
            ),
            "{w:?}"
        );
        assert!(
            w[1].starts_with("a.obj: 2 faces with normal indices where no normal (vn) is defined"),
            "{w:?}"
        );
    }

    #[test]
    fn faces_relative_indices_and_refusals() {
        let obj = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n# quad\nf 1 2 3 4\nf -4 -3 -2\n";
        let (o, w) = parse_ok(obj);
        assert!(w.is_empty(), "{w:?}");
        assert_eq!(o.faces.len(), 2);
        assert_eq!(o.faces[0].line, 6);
        assert_eq!(o.corners[o.faces[1].corners.clone()][0].v, 0);
        for (bad, want) in [
            (
                "f 1 2 5",
                "line 8: 'f 1 2 5': vertex index 5 is out of range: 4 defined",
            ),
            ("f -5 1 2", "index -5 reaches back before the first"),
            ("f 0 1 2", "index 0"),
            (
                "vt 0 0\nf 1/2 2 3",
                "texture coordinate index 2 is out of range: 1 defined",
            ),
            ("f 1 2 x", "'x': expected v"),
            ("v 1 nan 0", "vertex 5 is not finite"),
            (
                "v 1 1e39 0",
                "vertex 5 is not finite (infinite: an infinity as written, inf or 1.#INF, or a \
                 number beyond single precision",
            ),
            (
                "v 1.#INF 0 -1",
                "vertex 5 is not finite (infinite: an infinity as written",
            ),
            ("v 1 2", "expected 'v x y z'"),
            ("v 1 2 3 w", "expected 'v x y z'"),
            ("v 1e30 0 0", "too large"),
            ("vt", "expected 'vt u [v [w]]'"),
            ("mtllib  ", "expected 'mtllib file'"),
            (
                &format!("f{}", " 1 2 3".repeat(30_000)),
                "a face of 90000 corners",
            ),
        ] {
            let mut r = Repairs::new(false);
            let e = parse("a.obj", format!("{obj}{bad}\n").as_bytes(), &mut r)
                .unwrap_err()
                .to_string();
            assert!(e.contains(want), "{bad}: {e}");
        }
    }

    #[test]
    fn exporters_dialects_are_read() {
        // Classic Mac OS line ends (CR alone), comments after numbers, `fo` faces, colours with
        // alpha; free-form geometry said once.
        let obj = "v 0 0 0 # origin\rv 1 0 0\rv 1 1 0 0.2 0.3 0.4 1.0\rv 0 1 0\r\
                   fo 1 2 3 4 # a quad\rcstype bspline\rdeg 3\rcurv 0 1 1 2 3 4\rend\r";
        let mut r = Repairs::new(false);
        let o = parse("a.obj", obj.as_bytes(), &mut r).unwrap();
        assert_eq!((o.positions.len(), o.faces.len()), (4, 1));
        assert_eq!((o.faces[0].line, o.faces[0].corners.len()), (5, 4));
        let w = r.into_warnings();
        assert_eq!(w.len(), 2, "{w:?}");
        assert!(
            w[0].starts_with("a.obj: line 3: 'v 1 1 0 0.2 0.3 0.4 1.0': vertex colour"),
            "{w:?}"
        );
        assert!(
            w[1].starts_with("a.obj: 4 free-form geometry statements ignored"),
            "{w:?}"
        );
    }

    #[test]
    fn long_lines_go_on_after_a_backslash() {
        let obj =
            "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n# C:\\models\\\nf 1 2 \\\r\n  3 \\\n4\nf 1 2 3 \\";
        let (o, w) = parse_ok(obj);
        assert!(w.is_empty(), "{w:?}");
        assert_eq!(o.faces.len(), 2);
        assert_eq!((o.faces[0].line, o.faces[0].corners.len()), (6, 4));
        assert_eq!((o.faces[1].line, o.faces[1].corners.len()), (9, 3));
    }

    #[test]
    fn real_model_habits_are_repaired_once_each() {
        let obj: &[u8] = b"v\t0 0 0\nv  1 0 0\nv 1 1 0 0.5 0.5 0.5\nvn 0 0 0\nvn 0 0 1\nvt 0.5\n\
                   usemtl\tmy  stone\nf 1//1 2//2 3//2\nf 1 2 1\nf 1 1 1\nl 1 2 3\np 1\n\
                   # caf\xe9\no caf\xe9\n";
        let mut r = Repairs::new(false);
        let o = parse("a.obj", obj, &mut r).unwrap();
        assert_eq!(o.usemtl, [(7, "my  stone".to_string())]);
        assert_eq!(o.faces.len(), 1);
        // The zero normal is left out; the good one kept.
        assert_eq!(o.corners[0].vn, None);
        assert_eq!(o.corners[1].vn, Some(1));
        let w = r.into_warnings();
        assert_eq!(
            w,
            [
                "a.obj: line 3: 'v 1 1 0 0.5 0.5 0.5': vertex colour ignored",
                "a.obj: line 4: 'vn 0 0 0' (normal 1): zero or non-finite normal: its triangles \
                 are flat-shaded",
                "a.obj: 2 faces of fewer than 3 distinct vertices skipped (first at line 9: \
                 'f 1 2 1')",
                "a.obj: line 11: 'l 1 2 3': polyline (l) ignored: reframe renders faces only",
                "a.obj: line 12: 'p 1': points (p) ignored: reframe renders faces only",
                "a.obj: line 14: 'o caf\u{e9}': line is not UTF-8, read as Latin-1",
            ]
        );
        let e = parse("a.obj", obj, &mut Repairs::new(true))
            .unwrap_err()
            .to_string();
        assert!(
            e.ends_with("vertex colour ignored (refused: strict loading)"),
            "{e}"
        );
    }
}
