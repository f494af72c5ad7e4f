//! What identifies a render's state: the settings its pixels depend on (`RunKey`), the chunks a
//! render is split into (`Chunk`), and where its checkpoint and partial files live.
use crate::scene::Scene;
use crate::util::hash::{hash_exe, Fnv};
use anyhow::{bail, Result};
use serde::{Deserialize, Serialize};
use std::path::{Path, PathBuf};

/// Everything about a scene that changes a rendered pixel: geometry, materials, camera path,
/// environment light.
pub fn hash_scene(f: &mut Fnv, scene: &Scene) {
    f.f32s(scene.positions.iter().flat_map(|p| p.to_array()));
    f.f32s(scene.normals.iter().flat_map(|p| p.to_array()));
    for t in &scene.triangles {
        f.bytes(&t.map(u32::to_le_bytes).concat());
    }
    for m in &scene.tri_material {
        f.bytes(&m.to_le_bytes());
    }
    f.bytes(format!("{:?}{:?}", scene.materials, scene.cameras).as_bytes());
    f.bytes(&scene.frames.to_le_bytes());
    // Nothing for a scene without one, so that its hash stays what it was.
    if let Some(e) = &scene.environment {
        let (w, h, rot, texels) = e.identity();
        f.bytes(b"environment");
        f.bytes(&[w.to_le_bytes(), h.to_le_bytes()].concat());
        f.f32s(rot);
        f.f32s(texels.iter().flat_map(|t| t.to_array()));
    }
    // Likewise nothing for a scene without texture coordinates or textures.
    if !scene.uvs.is_empty() {
        f.bytes(b"uvs");
        f.f32s(scene.uvs.iter().flat_map(|t| t.to_array()));
    }
    for p in &scene.prototypes {
        f.bytes(b"prototype");
        f.f32s(p.positions.iter().flat_map(|v| v.to_array()));
        f.f32s(p.normals.iter().flat_map(|v| v.to_array()));
        f.f32s(p.uvs.iter().flat_map(|v| v.to_array()));
        for t in &p.triangles {
            f.bytes(&t.map(u32::to_le_bytes).concat());
        }
        for m in &p.tri_material {
            f.bytes(&m.to_le_bytes());
        }
    }
    for i in &scene.instances {
        f.bytes(&i.proto.to_le_bytes());
        f.f32s(i.rows());
    }
    if let Some(t) = &scene.textures {
        f.bytes(format!("textures{:?}{:?}", scene.texture_maps(), t.digests()).as_bytes());
    }
    // The positions and cameras above are given from it: a far scene moved by a whole number
    // of units would otherwise hash the same (its frames' camera matrices differ). Nothing for a
    // scene at the origin.
    if scene.origin != glam::DVec3::ZERO {
        f.bytes(b"origin");
        f.bytes(&scene.origin.to_array().map(f64::to_le_bytes).concat());
    }
}

/// The hex hashes of `scene` and of this build, as a run key and a reference key carry them.
pub fn scene_and_build_hashes(scene: &Scene) -> Result<(String, String)> {
    let mut f = Fnv::default();
    hash_scene(&mut f, scene);
    Ok((f.hex(), build_hash()?))
}

/// The hash of this build of reframe (its executable), as run keys hold it.
pub fn build_hash() -> Result<String> {
    let mut b = Fnv::default();
    hash_exe(&mut b)?;
    Ok(b.hex())
}

/// The settings a state file was made with; resuming or merging needs them all equal.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct RunKey {
    pub scene: String,
    pub scene_hash: String,
    pub build_hash: String,
    pub method: String,
    pub spp: u32,
    pub window: u32,
    pub first_frame: u32,
    pub last_frame: u32,
    pub width: u32,
    pub height: u32,
    pub seed: u64,
    pub max_depth: u32,
    pub visibility: String,
    /// Primary rays: "packet" or "single" (hits may differ in their last bits, so a resume must
    /// not mix them).
    #[serde(default)]
    pub primary: String,
    /// The rays after the primary hit: "packet" or "single" (as `primary`).
    #[serde(default)]
    pub paths: String,
    pub aov: bool,
    /// `--adaptive` target, 0 when off.
    pub adaptive: f32,
    /// EXR pixels as float: a resume or a merge must not mix half and float frames.
    pub exr_float: bool,
    /// What one unit of a reuse film's sums is worth (`reuse::radiance_unit`), which a merge
    /// checks its records against; 1 for the independent tracer.
    #[serde(default = "one")]
    pub radiance_unit: f32,
    /// `--denoise`: "off", "rgb" or "rgb+layers" (a resume must not mix denoised frames with
    /// raw ones).
    #[serde(default)]
    pub denoise: String,
}

fn one() -> f32 {
    1.0
}

impl RunKey {
    /// The first setting that differs from `o`, as "key: ours vs theirs".
    pub fn difference(&self, o: &RunKey) -> Option<String> {
        let (a, b) = (
            serde_json::to_value(self).ok()?,
            serde_json::to_value(o).ok()?,
        );
        let (a, b) = (a.as_object()?, b.as_object()?);
        // Text as itself, not JSON-quoted; the scene's hash said for what it is.
        let show = |v: &serde_json::Value| v.as_str().map_or_else(|| v.to_string(), str::to_string);
        // `radiance_unit` follows from other settings (the seed's pilot, the scene, the
        // samples): looked at last, so that the setting the user changed is the one named (a
        // changed `--seed` was said as "radiance_unit: 1.0 vs 0.5"; the map is alphabetical).
        let derived = "radiance_unit";
        let fields = a.iter().filter(|(k, _)| k.as_str() != derived);
        fields.chain(a.get_key_value(derived)).find_map(|(k, v)| {
            let (v, w) = (show(v), show(&b[k]));
            (v != w).then(|| match k.as_str() {
                "scene_hash" => format!("the scene's files differ: content hash {v} vs {w}"),
                "build_hash" => format!("another build of reframe: {v} vs {w}"),
                _ => format!("{k}: {v} vs {w}"),
            })
        })
    }
}

/// Every unit of work of a run of frames `first..=last`: the groups of `window` frames sliding
/// by one (group `g` is frames `g..g + window`), or the frames themselves for `window` 1. A
/// chunk renders a share of them (`Chunk::share`).
pub fn run_units(first: u32, last: u32, window: u32) -> std::ops::RangeInclusive<u32> {
    first..=last + 1 - window
}

/// `K/N` of `--chunk`, 1-based.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct Chunk {
    pub k: u32,
    pub n: u32,
}

impl Chunk {
    /// This chunk's share of `units` (groups, or frames for the independent tracer): contiguous
    /// and as even as integer division makes them.
    pub fn share(
        &self,
        units: std::ops::RangeInclusive<u32>,
    ) -> Result<std::ops::RangeInclusive<u32>> {
        let (a, count) = (*units.start(), units.end() - units.start() + 1);
        if self.n > count {
            bail!(
                "--chunk {}/{}: only {count} {} to split; use at most {count} {}",
                self.k,
                self.n,
                if count == 1 { "unit" } else { "units" },
                if count == 1 { "chunk" } else { "chunks" }
            );
        }
        let lo = (self.k - 1) as u64 * count as u64 / self.n as u64;
        let hi = self.k as u64 * count as u64 / self.n as u64;
        Ok(a + lo as u32..=a + hi as u32 - 1)
    }
}

impl std::fmt::Display for Chunk {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}/{}", self.k, self.n)
    }
}

/// The file name stem of an output pattern: `out/vase_####.exr` gives `out` and `vase`. What
/// follows the frame number, less the extension, is part of it (`shot-####-L.exr` gives
/// `shot-L`), so that two sequences whose names differ only there (a stereo pair's eyes) have
/// their own checkpoint, partial files and lock.
pub fn output_stem(pattern: &str) -> (PathBuf, String) {
    let p = Path::new(pattern);
    let dir = crate::util::fs::parent_dir(p);
    let name = p
        .file_name()
        .map(|n| n.to_string_lossy())
        .unwrap_or_default();
    let seps = ['_', '.', '-'];
    let stem = match name.find('#') {
        Some(i) => {
            let before = name[..i].trim_end_matches(seps);
            let after = name[i..].trim_start_matches('#');
            // The extension is the last `.` and what follows (none: no extension).
            let after = after.rfind('.').map_or(after, |d| &after[..d]);
            let after = after.trim_matches(seps);
            match (before.is_empty(), after.is_empty()) {
                (_, true) => before.to_string(),
                (true, false) => after.to_string(),
                (false, false) => format!("{before}-{after}"),
            }
        }
        None => Path::new(&*name)
            .file_stem()
            .map(|s| s.to_string_lossy().into_owned())
            .unwrap_or_default(),
    };
    (
        dir,
        if stem.is_empty() {
            "frames".into()
        } else {
            stem
        },
    )
}

/// Why output patterns `theirs` and `ours` share a checkpoint, partial files and a lock, in
/// words for a refusal: they are named by `output_stem`, which the two patterns share.
pub fn shared_names(theirs: &str, ours: &str) -> String {
    let (_, stem) = output_stem(ours);
    let (_, other) = output_stem(theirs);
    if stem == other {
        format!(
            "whose checkpoint, partial files and lock have this one's names ('{stem}': a --out's \
             name less its frame number, the separators around it and its extension)"
        )
    } else {
        format!("whose state names are '{other}', this one's '{stem}'")
    }
}

/// The default checkpoint folder of a render writing `pattern` (see the module note).
pub fn default_checkpoint_dir(pattern: &str, chunk: Option<Chunk>) -> PathBuf {
    let (dir, stem) = output_stem(pattern);
    match chunk {
        Some(c) => dir.join(format!("{stem}.chunk-{}-of-{}.checkpoint", c.k, c.n)),
        None => dir.join(format!("{stem}.checkpoint")),
    }
}

/// How a message names checkpoint folder `d` of a render writing `pattern` (chunk `chunk`):
/// `--checkpoint d`, or where `d` is the default folder, which no flag named, as that (a
/// default folder in the way was blamed on a `--checkpoint` never given).
pub fn checkpoint_named(d: &Path, pattern: &str, chunk: Option<Chunk>) -> String {
    if d == default_checkpoint_dir(pattern, chunk) {
        format!(
            "the checkpoint folder {} (the default beside the frames; --checkpoint DIR names \
             another)",
            d.display()
        )
    } else {
        format!("--checkpoint {}", d.display())
    }
}

/// The partial file chunk `c` of a render writing `pattern` produces.
pub fn partial_path(pattern: &str, c: Chunk) -> PathBuf {
    let (dir, stem) = output_stem(pattern);
    dir.join(format!("{stem}.chunk-{}-of-{}.partial", c.k, c.n))
}

/// The partial files of chunks `1..=n` of `pattern` that are in its folder, in chunk order:
/// found by listing the folder, so that the cost follows what is there, not `n`.
pub fn chunk_partials(pattern: &str, n: u32) -> Vec<PathBuf> {
    let (dir, stem) = output_stem(pattern);
    let Ok(entries) = std::fs::read_dir(&dir) else {
        return Vec::new();
    };
    let (head, tail) = (format!("{stem}.chunk-"), format!("-of-{n}.partial"));
    let mut found: Vec<(u32, PathBuf)> = entries
        .flatten()
        .filter_map(|e| {
            let name = e.file_name();
            let k: u32 = name
                .to_str()?
                .strip_prefix(&head)?
                .strip_suffix(&tail)?
                .parse()
                .ok()?;
            let p = partial_path(pattern, Chunk { k, n });
            ((1..=n).contains(&k) && p.file_name() == Some(name.as_os_str())).then_some((k, p))
        })
        .collect();
    found.sort();
    found.into_iter().map(|(_, p)| p).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The partials of the chunks asked for, in chunk order; names of other counts, of chunks
    /// out of range, or written with leading zeros are not theirs.
    #[test]
    fn chunk_partials_are_found_in_the_folder() {
        let dir = tempfile::tempdir().unwrap();
        let pattern = dir.path().join("f_####.exr").display().to_string();
        for name in [
            "f.chunk-3-of-3.partial",
            "f.chunk-1-of-3.partial",
            "f.chunk-01-of-3.partial",
            "f.chunk-4-of-3.partial",
            "f.chunk-0-of-3.partial",
            "f.chunk-2-of-4.partial",
            "g.chunk-2-of-3.partial",
        ] {
            std::fs::write(dir.path().join(name), b"").unwrap();
        }
        let found = chunk_partials(&pattern, 3);
        let want: Vec<PathBuf> = [1, 3]
            .map(|k| partial_path(&pattern, Chunk { k, n: 3 }))
            .to_vec();
        assert_eq!(found, want);
        assert!(chunk_partials(&pattern, u32::MAX).is_empty());
    }

    /// The setting a user changed is named, not one that follows from it.
    #[test]
    fn a_difference_names_the_setting_given() {
        let a = RunKey {
            seed: 0,
            radiance_unit: 1.0,
            ..RunKey::default()
        };
        let b = RunKey {
            seed: 1,
            radiance_unit: 0.5,
            ..a.clone()
        };
        assert_eq!(a.difference(&b).unwrap(), "seed: 0 vs 1");
        let c = RunKey {
            radiance_unit: 0.5,
            ..a.clone()
        };
        assert_eq!(a.difference(&c).unwrap(), "radiance_unit: 1.0 vs 0.5");
        assert_eq!(a.difference(&a), None);
    }

    #[test]
    fn chunks_split_units_contiguously_and_evenly() {
        for count in 1..20u32 {
            for n in 1..=count {
                let shares: Vec<_> = (1..=n)
                    .map(|k| Chunk { k, n }.share(5..=4 + count).unwrap())
                    .collect();
                assert_eq!(*shares[0].start(), 5);
                assert_eq!(*shares.last().unwrap().end(), 4 + count);
                for w in shares.windows(2) {
                    assert_eq!(*w[0].end() + 1, *w[1].start());
                }
                let sizes: Vec<u32> = shares.iter().map(|s| s.end() + 1 - s.start()).collect();
                assert!(sizes.iter().max().unwrap() - sizes.iter().min().unwrap() <= 1);
            }
            assert!(Chunk { k: 1, n: count + 1 }.share(0..=count - 1).is_err());
        }
    }

    #[test]
    fn stems_and_paths() {
        assert_eq!(
            output_stem("out/vase_####.exr"),
            ("out".into(), "vase".into())
        );
        assert_eq!(output_stem("x.png"), (".".into(), "x".into()));
        assert_eq!(output_stem("a/####.exr"), ("a".into(), "frames".into()));
        // What follows the frame number tells sequences apart (a stereo pair's eyes).
        for (pattern, stem) in [
            ("s/shot-####-L.exr", "shot-L"),
            ("s/shot-####-R.exr", "shot-R"),
            ("s/shot.####.left.exr", "shot-left"),
            ("s/####_beauty.exr", "beauty"),
            ("s/shot_####.exr", "shot"),
            ("s/shot_####", "shot"),
        ] {
            assert_eq!(output_stem(pattern), ("s".into(), stem.into()), "{pattern}");
        }
        assert_eq!(
            partial_path("r/f_####.exr", Chunk { k: 2, n: 3 }),
            PathBuf::from("r/f.chunk-2-of-3.partial")
        );
        assert_eq!(
            default_checkpoint_dir("r/f_####.exr", None),
            PathBuf::from("r/f.checkpoint")
        );
    }
}
