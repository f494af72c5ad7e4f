//! Cut-outs: the points of a surface that a `map_d` mask leaves out (leaves, fences, chains
//! modelled as textured quads). Embree asks `MeshCutout::opaque` of every candidate hit on a
//! mesh that has one (`embree::Cutout`), and rays go on through the points it leaves out:
//! camera rays, path rays, shadow rays and the reuse methods' visibility tests alike.
//!
//! A point is kept where the mask, interpolated bilinearly at its texture coordinates as the
//! colours are, is at least `maps::CUTOFF` (one half); it is left out below. The test is a
//! function of the point alone, never of the ray, so that every eye of a reuse group, and a
//! ray traced in a packet or alone, sees one and the same surface: the reuse estimators'
//! visibility terms stay what their derivations take them to be (docs/objects.md, "Cut-outs").
use super::maps::{Map, Maps};
use crate::embree::Cutout;
use crate::image::Textures;
use glam::Vec2;
use std::sync::Arc;

/// The cut-outs of one mesh (the scene's own, or a prototype): for each triangle whose material
/// has a mask, its three texture coordinates and the mask.
pub struct MeshCutout {
    textures: Arc<Textures>,
    /// Per triangle: `1 +` its index in `tris`, or 0 where its material has no mask.
    slot: Vec<u32>,
    /// The masked triangles' texture coordinates and mask.
    tris: Vec<([Vec2; 3], Map)>,
}

impl MeshCutout {
    /// The cut-outs of a mesh with `triangles` (vertex indices), per-vertex texture coordinates
    /// `uvs` (empty: all zero) and per-triangle materials `tri_material`, whose maps are `maps`
    /// (indexed by material; empty: none); `None` where no triangle's material has a mask.
    pub fn new(
        textures: Option<&Arc<Textures>>,
        maps: &[Maps],
        triangles: &[[u32; 3]],
        uvs: &[Vec2],
        tri_material: &[u32],
    ) -> Option<MeshCutout> {
        let textures = textures?;
        let mask = |m: u32| maps.get(m as usize).and_then(|m| m.cutout);
        if !tri_material.iter().any(|&m| mask(m).is_some()) {
            return None;
        }
        let mut slot = Vec::with_capacity(triangles.len());
        let mut tris = Vec::new();
        for (t, &m) in triangles.iter().zip(tri_material) {
            if let Some(map) = mask(m) {
                let uv = t.map(|i| uvs.get(i as usize).copied().unwrap_or(Vec2::ZERO));
                tris.push((uv, map));
                slot.push(tris.len() as u32);
            } else {
                slot.push(0);
            }
        }
        Some(MeshCutout {
            textures: textures.clone(),
            slot,
            tris,
        })
    }
}

impl Cutout for MeshCutout {
    /// Embree's barycentrics: the point is `(1 - u - v) p0 + u p1 + v p2`, as `Scene::surface`
    /// takes them.
    #[inline]
    fn opaque(&self, prim: u32, u: f32, v: f32) -> bool {
        let Some(&s) = self.slot.get(prim as usize) else {
            return true;
        };
        if s == 0 {
            return true;
        }
        let ([t0, t1, t2], mask) = &self.tris[s as usize - 1];
        let uv = *t0 * (1.0 - u - v) + *t1 * u + *t2 * v;
        mask.keeps(&self.textures, uv)
    }
}
