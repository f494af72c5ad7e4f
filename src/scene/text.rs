//! Line-by-line checks of a scene's OBJ and MTL text, run before tobj reads it.
//!
//! tobj 4.0.5 reports errors without a line number ("face parse error"), panics on a colour
//! with fewer than three numbers, and quietly accepts things that would break a render later
//! (faces of two vertices, an unknown `usemtl`). So every statement reframe relies on is
//! checked here first, the way tobj will read it, and a failure names its line. What passes
//! here, tobj loads; what tobj ignores (`s`, `vp`, unknown MTL statements), this ignores too.
//!
//! Beyond tobj, refused: a face index of 0 or one that refers past the elements defined above
//! it, a face with fewer than three vertices or a repeated vertex, a polyline of more than two
//! vertices (tobj would fill it as a face), vertex colours on some vertices only, a non-finite
//! or huge coordinate, a zero normal, a material statement before any `newmtl`, a material
//! defined twice in one file, and a negative or non-finite `Kd`, `Ks`, `Ke` or `Ns`.
use anyhow::{anyhow, bail, Result};
use std::collections::HashMap;

/// Largest coordinate accepted for a vertex or the camera: products of two edge vectors (areas,
/// squared distances) must stay finite in f32, and 4 * (2e18)^2 < 3.4e38.
pub const MAX_COORD: f32 = 1e18;

/// `bytes` as text, or an error naming the line of the first byte that is not text.
pub fn as_text(bytes: &[u8]) -> Result<&str> {
    let text = std::str::from_utf8(bytes).map_err(|e| {
        anyhow!(
            "line {}: not UTF-8 text (a binary file?)",
            line_at(bytes, e.valid_up_to())
        )
    })?;
    let control = |b: u8| (b < 0x20 && !matches!(b, b'\t' | b'\n' | b'\r' | 0x0c)) || b == 0x7f;
    if let Some(i) = bytes.iter().position(|&b| control(b)) {
        bail!(
            "line {}: control character 0x{:02x} (a binary file?)",
            line_at(bytes, i),
            bytes[i]
        );
    }
    Ok(text)
}

/// 1-based line of the byte at `offset`.
pub fn line_at(bytes: &[u8], offset: usize) -> usize {
    let offset = offset.min(bytes.len());
    bytes[..offset].iter().filter(|&&b| b == b'\n').count() + 1
}

/// A line as it appears in an error message: trimmed, and cut short if long.
pub fn quote(line: &str) -> String {
    let line = line.trim();
    match line.char_indices().nth(60) {
        Some((i, _)) => format!("{} ...", &line[..i]),
        None => line.to_string(),
    }
}

/// What the OBJ check learns on its way, for the messages of later checks.
#[derive(Default, Debug)]
pub struct ObjLines {
    /// The line of each triangle tobj will emit, in its order (a polygon of n vertices is a fan
    /// of n - 2 triangles).
    pub tri_line: Vec<usize>,
    /// The line of each `mtllib`, in the order tobj calls the material loader.
    pub mtllib: Vec<usize>,
    /// Each `usemtl`: its line and the material's name (as tobj reads it).
    pub usemtl: Vec<(usize, String)>,
}

/// Check an OBJ file's statements; errors read "line N: 'statement': what is wrong".
pub fn check_obj(text: &str) -> Result<ObjLines> {
    let mut out = ObjLines::default();
    // Elements defined so far: positions, texture coordinates, normals.
    let mut count = [0usize; 3];
    // First line of a vertex with a colour, and of one without.
    let mut coloured: [Option<usize>; 2] = [None, None];
    for (i, line) in text.lines().enumerate() {
        let n = i + 1;
        let err = |msg: String| anyhow!("line {n}: '{}': {msg}", quote(line));
        let mut words = line.split_whitespace();
        let Some(key) = words.next() else { continue };
        let args: Vec<&str> = words.collect();
        match key {
            "v" => {
                let shape = "expected 'v x y z', 'v x y z w' or 'v x y z r g b'";
                let xyz = numbers::<3>(&args).ok_or_else(|| err(shape.into()))?;
                let mut p = xyz;
                let has_colour = match args.len() {
                    3 => false,
                    4 => {
                        let w: f32 = args[3].parse().map_err(|_| err(shape.into()))?;
                        if w == 0.0 {
                            return Err(err("w = 0 (tobj divides x, y, z by w)".into()));
                        }
                        p = p.map(|c| c / w);
                        false
                    }
                    6 => {
                        numbers::<3>(&args[3..])
                            .ok_or_else(|| err("the vertex colour must be three numbers".into()))?;
                        true
                    }
                    _ => return Err(err(shape.into())),
                };
                coloured[usize::from(!has_colour)].get_or_insert(n);
                count[0] += 1;
                if !p.iter().all(|c| c.is_finite()) {
                    return Err(err(format!("vertex {} is not finite", count[0])));
                }
                if let Some(c) = p.iter().find(|c| c.abs() > MAX_COORD) {
                    return Err(err(format!(
                        "vertex {}: coordinate {c:e} is too large (at most {MAX_COORD:e})",
                        count[0]
                    )));
                }
            }
            "vt" => {
                numbers::<2>(&args).ok_or_else(|| err("expected 'vt u v'".into()))?;
                count[1] += 1;
            }
            "vn" => {
                let v = numbers::<3>(&args).ok_or_else(|| err("expected 'vn x y z'".into()))?;
                count[2] += 1;
                let len2: f32 = v.iter().map(|c| c * c).sum();
                if !v.iter().all(|c| c.is_finite()) || len2 == 0.0 || !len2.is_finite() {
                    return Err(err(format!(
                        "normal {} is zero or not finite (or too large)",
                        count[2]
                    )));
                }
            }
            "f" | "l" => {
                let mut verts = Vec::with_capacity(args.len());
                for r in &args {
                    verts.push(vertex_ref(r, &count).map_err(&err)?);
                }
                if key == "l" {
                    // tobj ignores lines of one or two vertices but fills longer ones as faces.
                    if args.len() > 2 {
                        return Err(err(format!(
                            "a polyline of {} vertices: reframe renders faces only ('f')",
                            args.len()
                        )));
                    }
                    continue;
                }
                if args.len() < 3 {
                    return Err(err(format!(
                        "a face needs at least 3 vertices, not {}",
                        args.len()
                    )));
                }
                for (a, &v) in verts.iter().enumerate() {
                    if verts[..a].contains(&v) {
                        return Err(err(format!(
                            "vertex {} appears twice: the face is degenerate",
                            v + 1
                        )));
                    }
                }
                out.tri_line.extend(std::iter::repeat_n(n, args.len() - 2));
            }
            // tobj takes the rest of the line after the first space as the name.
            "usemtl" | "mtllib" => {
                let name = line.split_once(' ').unwrap_or_default().1.trim();
                if name.is_empty() || args.is_empty() {
                    let what = if key == "usemtl" { "name" } else { "file" };
                    return Err(err(format!("expected '{key} {what}'")));
                }
                if key == "usemtl" {
                    out.usemtl.push((n, name.to_string()));
                } else {
                    out.mtllib.push(n);
                }
            }
            _ => {}
        }
    }
    if let [Some(a), Some(b)] = coloured {
        bail!(
            "line {a} gives a vertex a colour and line {b} does not: tobj needs colours on all \
             vertices or none"
        );
    }
    Ok(out)
}

/// The first `N` words as numbers, as tobj parses them (extra words are not looked at).
fn numbers<const N: usize>(words: &[&str]) -> Option<[f32; N]> {
    let mut v = [0.0; N];
    for (x, w) in v.iter_mut().zip(words.get(..N)?) {
        *x = w.parse().ok()?;
    }
    Some(v)
}

/// One face vertex `v`, `v/vt`, `v//vn` or `v/vt/vn`, checked against the elements defined
/// above it (`count`: positions, texture coordinates, normals); the 0-based position index.
fn vertex_ref(r: &str, count: &[usize; 3]) -> Result<usize, String> {
    let shape = || format!("'{r}': expected v, v/vt, v//vn or v/vt/vn (1-based indices)");
    let parts: Vec<&str> = r.split('/').collect();
    if parts.len() > 3 || parts[0].is_empty() {
        return Err(shape());
    }
    let mut pos = 0;
    for (k, p) in parts.iter().enumerate() {
        if p.is_empty() {
            continue;
        }
        let x: isize = p.parse().map_err(|_| shape())?;
        let (what, n) = (["vertex", "texture coordinate", "normal"][k], count[k]);
        let i = match x {
            0 => return Err(format!("{what} index 0: OBJ indices start at 1")),
            x if x > 0 && (x as usize) <= n => x as usize - 1,
            x if x < 0 && x.unsigned_abs() <= n => n - x.unsigned_abs(),
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
        if k == 0 {
            pos = i;
        }
    }
    Ok(pos)
}

/// The statements tobj reads from an MTL file, and how many words each needs.
fn mtl_shape(key: &str) -> Option<(usize, &'static str)> {
    Some(match key {
        "Ka" | "Kd" | "Ks" | "Ke" => (3, "r g b"),
        "Ns" | "Ni" | "d" => (1, "value"),
        "illum" => (1, "model (0 to 255)"),
        "map_Ka" | "map_Kd" | "map_Ks" | "map_Bump" | "map_bump" | "map_Ns" | "map_ns"
        | "map_NS" | "bump" | "map_d" => (1, "file"),
        _ => return None,
    })
}

/// Check an MTL file's statements; returns the line of each `newmtl`, by material name.
pub fn check_mtl(text: &str) -> Result<HashMap<String, usize>> {
    let mut names: HashMap<String, usize> = HashMap::new();
    let mut current = false;
    for (i, line) in text.lines().enumerate() {
        let n = i + 1;
        let err = |msg: String| anyhow!("line {n}: '{}': {msg}", quote(line));
        let mut words = line.split_whitespace();
        let Some(key) = words.next() else { continue };
        let args: Vec<&str> = words.collect();
        if key == "newmtl" {
            // As tobj reads it: the trimmed line after the keyword.
            let name = line.trim()[6..].trim();
            if name.is_empty() {
                return Err(err("expected 'newmtl name'".into()));
            }
            if let Some(first) = names.insert(name.to_string(), n) {
                return Err(err(format!(
                    "material '{name}' is already defined at line {first}"
                )));
            }
            current = true;
            continue;
        }
        let Some((want, shape)) = mtl_shape(key) else {
            continue;
        };
        if !current {
            return Err(err(format!("'{key}' before any newmtl")));
        }
        let expected = || err(format!("expected '{key} {shape}'"));
        match want {
            3 => {
                let c = numbers::<3>(&args).ok_or_else(expected)?;
                if key != "Ka" && !c.iter().all(|x| x.is_finite() && *x >= 0.0) {
                    return Err(err(format!("{key} must be finite and non-negative")));
                }
            }
            _ if key == "illum" => {
                args.first()
                    .and_then(|w| w.parse::<u8>().ok())
                    .ok_or_else(expected)?;
            }
            _ if shape == "file" => {
                if args.is_empty() {
                    return Err(expected());
                }
            }
            _ => {
                let [x] = numbers::<1>(&args).ok_or_else(expected)?;
                if key == "Ns" && (!x.is_finite() || x < 0.0) {
                    return Err(err("Ns must be finite and non-negative".into()));
                }
            }
        }
    }
    Ok(names)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn obj_lines_of_triangles_and_relative_indices() {
        let obj = "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\n# quad\nf 1 2 3 4\nf -4 -3 -2\n";
        let l = check_obj(obj).unwrap();
        assert_eq!(l.tri_line, vec![6, 6, 7]);
        for (bad, want) in [
            (
                "f 1 2 5",
                "line 8: 'f 1 2 5': vertex index 5 is out of range: 4 defined",
            ),
            ("f -5 1 2", "index -5 reaches back before the first"),
            ("f 0 1 2", "index 0"),
            ("f 1 2", "at least 3 vertices"),
            ("f 1 2 2", "vertex 2 appears twice"),
            (
                "f 1/1 2 3",
                "texture coordinate index 1 is out of range: 0 defined",
            ),
            ("f 1 2 x", "'x': expected v"),
            ("v 1 nan 0", "vertex 5 is not finite"),
            ("v 1 2", "expected 'v x y z'"),
            ("v 1 2 3 0", "w = 0"),
            ("v 1e30 0 0", "too large"),
            ("vn 0 0 0", "normal 1 is zero"),
            ("usemtl", "expected 'usemtl name'"),
            ("l 1 2 3", "polyline"),
        ] {
            let e = check_obj(&format!("{obj}{bad}\n")).unwrap_err().to_string();
            assert!(e.contains(want), "{bad}: {e}");
        }
        let e = check_obj("v 0 0 0 1 1 1\nv 1 0 0\n")
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("line 1 gives a vertex a colour and line 2 does not"),
            "{e}"
        );
    }

    #[test]
    fn mtl_statements() {
        let ok = "# c\nnewmtl a\nKd 0.5 0.5 0.5\nillum 2\nnewmtl b\nKe 1 1 1\n";
        assert_eq!(check_mtl(ok).unwrap()["b"], 5);
        for (bad, want) in [
            ("Kd 0.5 0.5", "line 7: 'Kd 0.5 0.5': expected 'Kd r g b'"),
            ("Ks 1 x 1", "expected 'Ks r g b'"),
            ("Ke -1 0 0", "Ke must be finite and non-negative"),
            ("Kd nan 0 0", "Kd must be finite"),
            ("Ns", "expected 'Ns value'"),
            ("illum two", "expected 'illum model"),
            ("map_Kd", "expected 'map_Kd file'"),
            ("newmtl a", "material 'a' is already defined at line 2"),
            ("newmtl ", "expected 'newmtl name'"),
        ] {
            let e = check_mtl(&format!("{ok}{bad}\n")).unwrap_err().to_string();
            assert!(e.contains(want), "{bad}: {e}");
        }
        let e = check_mtl("Kd 1 1 1\nnewmtl a\n").unwrap_err().to_string();
        assert!(e.contains("before any newmtl"), "{e}");
    }

    #[test]
    fn text_names_the_line_of_binary_data() {
        assert_eq!(as_text(b"a\nb\n").unwrap(), "a\nb\n");
        let e = as_text(b"a\nb\n\xff\xfe").unwrap_err().to_string();
        assert!(e.starts_with("line 3: not UTF-8"), "{e}");
        let e = as_text(b"a\n\0").unwrap_err().to_string();
        assert!(e.starts_with("line 2: control character 0x00"), "{e}");
    }
}
