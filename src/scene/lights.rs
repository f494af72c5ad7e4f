//! Area lights: the emitting triangles of a scene as lights (one per emitting material), their
//! tables for picking a triangle in proportion to its power (an emission map's triangle through
//! a grid of parts, docs/light-sampling.md), and the point sampled on a picked triangle.
use super::mesh::Mesh;
use crate::bsdf::luminance;
use crate::embree::Ray;
use crate::image::Textures;
use crate::sampling::uniform_triangle;
use anyhow::{anyhow, Result};
use glam::{Vec2, Vec3};
use std::collections::HashMap;

/// Emitting triangles, sampled in proportion to their power (area times luminance of `Ke`),
/// with a share `LIGHT_UNIFORM` of the picks even between lights (`light_groups`).
/// A triangle with an emission map (`map_Ke`) is sampled through a regular subdivision of it
/// into `n^2` equal parts, each picked in proportion to the map's radiance over it, so that the
/// bright texels of a map get the samples (docs/light-sampling.md).
pub struct Lights {
    /// Triangle index of each light.
    pub tris: Vec<u32>,
    /// Per entry of `table`, the CDF of picking it.
    pub(super) cdf: Vec<f32>,
    /// Per triangle of the scene: probability of choosing it divided by its area (0 if not a
    /// light), i.e. the area density of light sampling on it; negative for a subdivided one,
    /// whose densities are in `grids[-pdf_area - 1]`.
    pub(super) pdf_area: Vec<f32>,
    /// Per part of a light (a whole triangle, or a part of a subdivided one), what sampling a
    /// point on it reads, in one place (`Scene::area_inputs`).
    pub(super) table: Vec<LightTriangle>,
    pub(super) grids: Vec<LightGrid>,
    /// Triangles whose material has a positive `Ke` but an emission map black in every texel:
    /// they emit nothing, and are not lights.
    pub black_maps: usize,
}

/// The subdivision of a light triangle with an emission map: `n` parts along each edge, the
/// part holding barycentrics `(b1, b2)` found by `LightGrid::part`, and the area density of
/// each part (`2 n^2` slots, the unused ones 0).
pub(super) struct LightGrid {
    pub(super) n: u32,
    pub(super) corners: [Vec3; 3],
    pub(super) pdf_area: Vec<f32>,
}

impl LightGrid {
    /// The part of an `n`-grid holding barycentrics `(b1, b2)`: slot `2 (i n + j) + d` for the
    /// cell `(i, j)` (`i + j < n`) and its lower (`d` 0: corners `(i, j), (i+1, j), (i, j+1)`)
    /// or upper triangle (`d` 1: `(i+1, j), (i+1, j+1), (i, j+1)`, where `i + j < n - 1`).
    pub(super) fn part(n: u32, b1: f32, b2: f32) -> usize {
        let nf = n as f32;
        let (s, t) = (b1.clamp(0.0, 1.0) * nf, b2.clamp(0.0, 1.0) * nf);
        let i = (s.floor() as u32).min(n - 1);
        let j = (t.floor() as u32).min(n - 1 - i);
        let upper = (s - i as f32) + (t - j as f32) > 1.0 && i + j + 1 < n;
        2 * (i * n + j) as usize + upper as usize
    }

    /// Whether slot `k` of an `n`-grid is a part (an upper triangle exists only inside).
    pub(super) fn exists(n: u32, k: usize) -> bool {
        let cell = (k / 2) as u32;
        let (i, j) = (cell / n, cell % n);
        i + j + ((k % 2) as u32) < n
    }

    /// The barycentrics `(b1, b2)` of the corners of slot `k`'s part.
    pub(super) fn corners_of(n: u32, k: usize) -> [Vec2; 3] {
        let (cell, upper) = ((k / 2) as u32, k % 2 == 1);
        let (i, j) = ((cell / n) as f32, (cell % n) as f32);
        let nf = n as f32;
        let b = |a: f32, c: f32| Vec2::new(a / nf, c / nf);
        if upper {
            [b(i + 1.0, j), b(i + 1.0, j + 1.0), b(i, j + 1.0)]
        } else {
            [b(i, j), b(i + 1.0, j), b(i, j + 1.0)]
        }
    }

    /// The area density of light sampling at point `y` of the triangle.
    pub(super) fn pdf_at(&self, y: Vec3) -> f32 {
        // In f64: the determinant grows as an edge's fourth power (past f32 for edges of 4e9,
        // below its range for edges of 1e-10, both within the coordinates a scene may have).
        let [c0, c1, c2] = self.corners.map(|c| c.as_dvec3());
        let (e1, e2, d) = (c1 - c0, c2 - c0, y.as_dvec3() - c0);
        let (d11, d12, d22) = (e1.dot(e1), e1.dot(e2), e2.dot(e2));
        let (d1, d2) = (d.dot(e1), d.dot(e2));
        let det = d11 * d22 - d12 * d12;
        if det <= 0.0 {
            return 0.0;
        }
        let b1 = (d22 * d1 - d12 * d2) / det;
        let b2 = (d11 * d2 - d12 * d1) / det;
        self.pdf_area[Self::part(self.n, b1 as f32, b2 as f32)]
    }
}

/// The most parts one textured light triangle is cut into per edge, and in all.
pub(super) const MAX_GRID_SIDE: u32 = 64;
pub(super) const MAX_GRID_PARTS: u64 = 1 << 18;

/// A light triangle (or part of one) as `Scene::sample_light` reads it: its corners and
/// normal, its area density, its share `[lo, lo + width)` of the CDF, its index among the
/// scene's triangles, and for a part the barycentrics of its corners in the whole triangle.
#[derive(Clone, Copy, Debug)]
pub(super) struct LightTriangle {
    pub(super) corners: [Vec3; 3],
    pub(super) n: Vec3,
    pub(super) pdf_area: f32,
    pub(super) lo: f32,
    pub(super) width: f32,
    pub(super) tri: u32,
    pub(super) part_of: Option<[Vec2; 3]>,
}

/// A point sampled on a light, seen from a shading point (for the environment: a direction, with
/// `dist` infinite).
#[derive(Clone, Copy, Debug)]
pub struct LightSample {
    pub p: Vec3,
    pub n: Vec3,
    pub wi: Vec3,
    pub dist: f32,
    /// Emitted radiance towards the shading point (zero from the back of the light).
    pub le: Vec3,
    /// Solid-angle density at the shading point.
    pub pdf: f32,
}

/// The light `Scene::sample_light` picks with its 2D number.
#[derive(Clone, Copy, Debug)]
pub(super) enum LightPick {
    /// The environment, with the number stretched back to [0, 1)^2.
    Environment(Vec2),
    Area(AreaPick),
}

/// The area light `light` (an index into `Lights::table`), picked by `u.x` in its share of
/// the CDF.
#[derive(Clone, Copy, Debug)]
pub(super) struct AreaPick {
    pub(super) light: u32,
    pub(super) u: Vec2,
}

/// What the arithmetic of an area light's sample reads (`area_sample`): the pick's number and
/// share, the triangle's corners and normal, its area density times the probability of
/// picking an area light, and the shading point.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct AreaInputs {
    pub(super) u: Vec2,
    pub(super) lo: f32,
    pub(super) width: f32,
    pub(super) corners: [Vec3; 3],
    pub(super) n: Vec3,
    pub(super) pdf_area: f32,
    pub(super) x: Vec3,
}

/// What it gives: the barycentrics and the point, the unit direction, distance and the cosine
/// at the light towards `x`, and the solid-angle density.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct AreaSample {
    pub(super) b1: f32,
    pub(super) b2: f32,
    pub(super) p: Vec3,
    pub(super) wi: Vec3,
    pub(super) dist: f32,
    pub(super) cos_l: f32,
    pub(super) pdf: f32,
}

/// The part `[lo, lo + p)` of [0, 1) in which `v` picked a light, stretched back to [0, 1)
/// (docs/sampler.md, "Picking a light with the same 2D point").
#[inline(always)]
pub(super) fn stretch(v: f32, lo: f32, p: f32) -> f32 {
    ((v - lo) / p).clamp(0.0, 1.0 - f32::EPSILON)
}

/// A point on a triangle light, uniform by area, seen from `x`: the arithmetic of the sample,
/// with no branch and no memory access, so that `light_lanes` runs it across SIMD lanes and
/// gives `Scene::sample_light`'s bits. Where the point coincides with `x` (distance 0) the
/// direction is not finite, and `Scene::finish_area` drops the sample.
#[inline(always)]
pub(super) fn area_sample(a: &AreaInputs) -> AreaSample {
    let ux = stretch(a.u.x, a.lo, a.width);
    let (b1, b2) = uniform_triangle(Vec2::new(ux, a.u.y));
    let [c0, c1, c2] = a.corners;
    let p = c0 * (1.0 - b1 - b2) + c1 * b1 + c2 * b2;
    let d = p - a.x;
    let dist2 = d.length_squared();
    let dist = dist2.sqrt();
    let wi = d / dist;
    let cos_l = a.n.dot(-wi);
    AreaSample {
        b1,
        b2,
        p,
        wi,
        dist,
        cos_l,
        pdf: a.pdf_area * dist2 / cos_l.abs(),
    }
}

impl LightSample {
    /// The shadow ray from surface point `p` (geometric normal `ng`) to the sampled point, or
    /// out to infinity along `wi` for the environment.
    #[inline]
    pub fn shadow_ray(&self, p: Vec3, ng: Vec3, floor: f32) -> Ray {
        if self.dist.is_infinite() {
            Ray::spawn(p, ng, self.wi, floor)
        } else {
            Ray::between(p, ng, self.p, self.n, floor)
        }
    }
}

impl Lights {
    /// The emitting triangles of `mesh` (none, if no material emits), those with an emission
    /// map subdivided by it (`textures`). Its tables, a few hundred bytes a light triangle,
    /// are taken fallibly: where they do not fit in the memory left, an error (an allocation
    /// that fails aborts the process: 500 placements of a 20000-triangle lamp under a `ulimit
    /// -v` of 4 GB did, with a backtrace).
    pub(super) fn new(label: &str, mesh: &Mesh, textures: Option<&Textures>) -> Result<Lights> {
        let sides = grid_sides(mesh, textures);
        // An emission map black in every texel makes its triangles emit nothing: not lights.
        let black: Vec<bool> = (0..mesh.materials.len())
            .map(|m| {
                let map = mesh.maps.get(m).and_then(|maps| maps.ke);
                match (map, textures) {
                    (Some(map), Some(tex)) => {
                        (mesh.materials[m].ke * Vec3::from(tex.max_rgb(map.tex))).max_element()
                            <= 0.0
                    }
                    _ => false,
                }
            })
            .collect();
        // The lights, and their parts: a part for a whole triangle, `2 n^2` slots for one cut
        // into an `n`-grid by its emission map (`LightGrid`).
        let grid = |t: usize| match (sides.get(&(t as u32)), textures) {
            (Some(&n), Some(_)) => Some(n),
            _ => None,
        };
        let (mut lights_n, mut slots_n, mut black_maps) = (0usize, 0usize, 0);
        for (t, &m) in mesh.tri_material.iter().enumerate() {
            if mesh.materials[m as usize].ke.max_element() <= 0.0 {
                continue;
            }
            if black[m as usize] {
                black_maps += 1;
                continue;
            }
            lights_n += 1;
            slots_n += grid(t).map_or(1, |n| 2 * (n * n) as usize);
        }
        let no_room = || {
            let bytes = lights_n * (4 + 4 + 4) + slots_n * (8 + 4 + size_of::<LightTriangle>());
            anyhow!(
                "{label}: the light tables of its {lights_n} emitting triangles need about {} \
                 more, and that memory is not left{}",
                crate::util::mem::size(bytes as u64 + 4 * mesh.triangles.len() as u64),
                crate::util::mem::address_space_note()
            )
        };
        let mut tris: Vec<u32> = Vec::new();
        // Per light its grid side (0: whole), and the powers of its parts, one after another.
        let mut grid_of: Vec<u32> = Vec::new();
        let mut powers: Vec<f64> = Vec::new();
        let mut pdf_area: Vec<f32> = Vec::new();
        let room = tris.try_reserve_exact(lights_n).is_ok()
            && grid_of.try_reserve_exact(lights_n).is_ok()
            && powers.try_reserve_exact(slots_n).is_ok()
            && pdf_area.try_reserve_exact(mesh.triangles.len()).is_ok();
        if !room {
            return Err(no_room());
        }
        pdf_area.resize(mesh.triangles.len(), 0.0);
        for (t, &m) in mesh.tri_material.iter().enumerate() {
            let ke = mesh.materials[m as usize].ke;
            if ke.max_element() <= 0.0 || black[m as usize] {
                continue;
            }
            tris.push(t as u32);
            // In f64: an area up to (2e18)^2 times `MAX_KE` is past f32.
            let area = mesh.tri_area[t] as f64;
            match (grid(t), textures) {
                (Some(n), Some(tex)) => {
                    let [i0, i1, i2] = mesh.triangles[t].map(|v| v as usize);
                    let uv = [mesh.uvs[i0], mesh.uvs[i1], mesh.uvs[i2]];
                    // The radiance as shading sees it (capped at `MAX_KE`) over each part, in
                    // the grid's slots (`None`: no part there).
                    let maps = &mesh.maps[m as usize];
                    let radiance: Vec<Option<f64>> = (0..2 * (n * n) as usize)
                        .map(|k| {
                            LightGrid::exists(n, k).then(|| {
                                let b = LightGrid::corners_of(n, k);
                                part_power(&uv, b, |u| maps.ke(ke, tex, u))
                            })
                        })
                        .collect();
                    // Every part keeps a share, a thousandth of the mean (a texel between the
                    // points read may be bright), so the density is positive wherever the map
                    // is; where the points read are all black, a thousandth of a plain light's
                    // weight: never zero, whatever the triangle's size.
                    let parts_n = (n * n) as f64;
                    let mean = radiance.iter().flatten().sum::<f64>() / parts_n;
                    let floor = if mean > 0.0 && mean.is_finite() {
                        1e-3 * mean
                    } else {
                        1e-3 * luminance(ke).max(ke.max_element() * 1e-3) as f64
                    };
                    let part_area = area / parts_n;
                    powers.extend(
                        radiance
                            .iter()
                            .map(|l| l.map_or(0.0, |l| part_area * l.max(floor))),
                    );
                    grid_of.push(n);
                }
                _ => {
                    // Luminance can be zero for a saturated colour; the max keeps it samplable.
                    let l = luminance(ke).max(ke.max_element() * 1e-3) as f64;
                    powers.push(area * l);
                    grid_of.push(0);
                }
            }
        }
        if tris.is_empty() {
            return Ok(Lights {
                tris,
                cdf: Vec::new(),
                pdf_area,
                table: Vec::new(),
                grids: Vec::new(),
                black_maps,
            });
        }
        // The powers of light `i` are `powers[spans[i]..spans[i + 1]]`.
        let span = |n: u32| if n == 0 { 1 } else { 2 * (n * n) as usize };
        // Lights (a material's emitting triangles) picked by power alone starve a small bright
        // lamp beside a large dim one, whose power may be 10^4 times its own though the lamp
        // lights its surroundings more: a share `LIGHT_UNIFORM` of the picks goes to the
        // lights in equal parts (within a light by power), the rest by power
        // (docs/light-sampling.md, "Which light").
        // Only lights of some power count (a material whose triangles all have area 0 after
        // placement has none, and would divide 0 by 0).
        let (light_of, lights) = light_groups(mesh, &tris).ok_or_else(no_room)?;
        let mut group_power = vec![0.0f64; lights];
        let mut at = 0;
        for (&g, &n) in light_of.iter().zip(&grid_of) {
            group_power[g as usize] += powers[at..at + span(n)].iter().sum::<f64>();
            at += span(n);
        }
        let lit = group_power.iter().filter(|&&p| p > 0.0).count();
        if lit > 1 {
            let total: f64 = powers.iter().sum();
            let even = LIGHT_UNIFORM / lit as f64;
            let mut at = 0;
            for (&g, &n) in light_of.iter().zip(&grid_of) {
                let g = g as usize;
                let share = if group_power[g] > 0.0 {
                    even / group_power[g]
                } else {
                    0.0
                };
                for w in powers[at..at + span(n)].iter_mut() {
                    *w = (1.0 - LIGHT_UNIFORM) * (*w / total) + share * *w;
                }
                at += span(n);
            }
        }
        drop(light_of);
        let total: f64 = powers.iter().sum();
        let mut acc = 0.0f64;
        let (mut cdf, mut table) = (Vec::new(), Vec::new());
        let entries = powers.iter().filter(|&&p| p > 0.0).count();
        if cdf.try_reserve_exact(entries).is_err() || table.try_reserve_exact(entries).is_err() {
            return Err(no_room());
        }
        let mut grids = Vec::new();
        // Per grid: its index, its parts' area, and (slot, table entry) of each part.
        type GridParts = (usize, f64, Vec<(usize, usize)>);
        let mut parts_of: Vec<GridParts> = Vec::new();
        let mut at = 0;
        for (&tri, &n) in tris.iter().zip(&grid_of) {
            let t = tri as usize;
            let light_powers = &powers[at..at + span(n)];
            at += span(n);
            let corners = mesh.triangles[t].map(|v| mesh.positions[v as usize]);
            let mut push = |p: f64, area: f64, part_of: Option<[Vec2; 3]>, cdf: &mut Vec<f32>| {
                let lo = cdf.last().copied().unwrap_or(0.0);
                acc += p;
                cdf.push((acc / total) as f32);
                let density = ((p / total) / area) as f32;
                let part_corners = match part_of {
                    None => corners,
                    Some(b) => b.map(|b| {
                        corners[0] * (1.0 - b.x - b.y) + corners[1] * b.x + corners[2] * b.y
                    }),
                };
                table.push(LightTriangle {
                    corners: part_corners,
                    n: mesh.tri_normal[t],
                    pdf_area: density,
                    lo,
                    width: cdf.last().unwrap() - lo,
                    tri,
                    part_of,
                });
                density
            };
            if n == 0 {
                pdf_area[t] = push(light_powers[0], mesh.tri_area[t] as f64, None, &mut cdf);
                continue;
            }
            let part_area = mesh.tri_area[t] as f64 / (n * n) as f64;
            let mut slots = Vec::new();
            for (k, &p) in light_powers.iter().enumerate() {
                if p > 0.0 {
                    slots.push((k, cdf.len()));
                    push(p, part_area, Some(LightGrid::corners_of(n, k)), &mut cdf);
                }
            }
            grids.push(LightGrid {
                n,
                corners,
                pdf_area: vec![0.0; light_powers.len()],
            });
            parts_of.push((grids.len() - 1, part_area, slots));
            pdf_area[t] = -(grids.len() as f32);
        }
        *cdf.last_mut().unwrap() = 1.0;
        if let Some(last) = table.last_mut() {
            last.width = 1.0 - last.lo;
        }
        // A part's density is the share of the CDF that picks it, as f32 holds it, over its
        // area: among up to 2^18 parts a faint one's share can round to nothing (never picked)
        // or to a step of the CDF, and `light_pdf` must say what sampling does.
        for (g, part_area, slots) in parts_of {
            for (k, ti) in slots {
                let d = (table[ti].width as f64 / part_area) as f32;
                table[ti].pdf_area = d;
                grids[g].pdf_area[k] = d;
            }
        }
        Ok(Lights {
            tris,
            cdf,
            pdf_area,
            table,
            grids,
            black_maps,
        })
    }
}

/// The share of light picks made evenly between lights (`light_groups`), not by power.
pub(super) const LIGHT_UNIFORM: f64 = 0.25;

/// The lights of a scene for picking (`Lights::new`): the emitting triangles of one material
/// are one light (a lamp, a window, a panel), whatever their number. Per emitting triangle (in
/// `Lights::tris`' order), its light; and the number of lights. `None` where the memory for
/// it is not left.
pub(super) fn light_groups(mesh: &Mesh, tris: &[u32]) -> Option<(Vec<u32>, usize)> {
    let mut index: HashMap<u32, u32> = HashMap::new();
    let mut of = Vec::new();
    of.try_reserve_exact(tris.len()).ok()?;
    of.extend(tris.iter().map(|&t| {
        let n = index.len() as u32;
        *index.entry(mesh.tri_material[t as usize]).or_insert(n)
    }));
    Some((of, index.len()))
}

/// The grid side of each emitting triangle with an emission map, by triangle: about two texels
/// of the map per part, at most `MAX_GRID_SIDE` per edge and `MAX_GRID_PARTS` in all (fewer
/// each where the scene's maps would pass that); none where a part would hold the whole map's
/// texels (1 on a side: nothing to pick between) or the triangle has no texture coordinates.
pub(super) fn grid_sides(mesh: &Mesh, textures: Option<&Textures>) -> HashMap<u32, u32> {
    let Some(tex) = textures else {
        return HashMap::new();
    };
    if mesh.uvs.is_empty() {
        return HashMap::new();
    }
    let mut wanted: Vec<(u32, f64)> = Vec::new();
    for (t, &m) in mesh.tri_material.iter().enumerate() {
        let ke = mesh.materials[m as usize].ke;
        let Some(map) = mesh.maps.get(m as usize).and_then(|maps| maps.ke) else {
            continue;
        };
        if ke.max_element() <= 0.0 {
            continue;
        }
        let [a, b, c] = mesh.triangles[t].map(|v| mesh.uvs[v as usize] * map.scale);
        let (w, h) = tex.size(map.tex);
        let texels = 0.5 * ((b - a).perp_dot(c - a) as f64).abs() * w as f64 * h as f64;
        if texels.is_finite() && texels > 8.0 {
            wanted.push((t as u32, (texels / 2.0).sqrt().min(MAX_GRID_SIDE as f64)));
        }
    }
    // Sides rounded down, so that the parts stay within the bound after the shrink.
    let parts: f64 = wanted.iter().map(|(_, n)| n * n).sum();
    let shrink = if parts > MAX_GRID_PARTS as f64 {
        (MAX_GRID_PARTS as f64 / parts).sqrt()
    } else {
        1.0
    };
    wanted
        .into_iter()
        .map(|(t, n)| (t, (n * shrink).floor() as u32))
        .filter(|&(_, n)| n > 1)
        .collect()
}

/// The power per unit area of a part of a triangle with corner texture coordinates `uv`, the
/// part's corners at barycentrics `b`, as far as the radiance `le` at seven points tells (its
/// corners, edge midpoints and centre): the mean of their luminance and the largest, halved,
/// so that a bright texel between the points still draws samples.
pub(super) fn part_power(uv: &[Vec2; 3], b: [Vec2; 3], le: impl Fn(Vec2) -> Vec3) -> f64 {
    let at = |w: Vec2| uv[0] * (1.0 - w.x - w.y) + uv[1] * w.x + uv[2] * w.y;
    let centre = (b[0] + b[1] + b[2]) / 3.0;
    let points = [
        b[0],
        b[1],
        b[2],
        (b[0] + b[1]) * 0.5,
        (b[1] + b[2]) * 0.5,
        (b[2] + b[0]) * 0.5,
        centre,
    ];
    let (mut sum, mut max) = (0.0f64, 0.0f64);
    for w in points {
        let l = luminance(le(at(w))).max(0.0) as f64;
        sum += l;
        max = max.max(l);
    }
    0.5 * (sum / points.len() as f64 + max)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every part of a light's grid holds its own corners' centre and points near its corners
    /// (`LightGrid::part` finds the part `corners_of` made), the parts tile the triangle (their
    /// count is n^2), and a point outside its barycentric range is clamped to a part.
    #[test]
    fn a_light_grid_finds_the_part_it_made() {
        for n in [2u32, 3, 7, 64] {
            let mut parts = 0;
            for k in 0..2 * (n * n) as usize {
                if !LightGrid::exists(n, k) {
                    continue;
                }
                parts += 1;
                let c = LightGrid::corners_of(n, k);
                let centre = (c[0] + c[1] + c[2]) / 3.0;
                assert_eq!(LightGrid::part(n, centre.x, centre.y), k, "n {n}, part {k}");
                for corner in c {
                    let near = corner + (centre - corner) * 0.01;
                    assert_eq!(LightGrid::part(n, near.x, near.y), k, "n {n}, part {k}");
                }
            }
            assert_eq!(parts, n * n);
            assert!(LightGrid::exists(n, LightGrid::part(n, 2.0, -1.0)));
            assert!(LightGrid::exists(n, LightGrid::part(n, 0.7, 0.7)));
        }
    }
}
