//! The architecture as a test: every module of `src/` may use only the modules below it, so that
//! there is no import cycle and the estimators cannot reach up to the driver's options, files or
//! progress bar (README, "Layout"). Reads the sources and checks every `crate::` path.
use std::path::Path;

/// The layers, bottom first; a module may use modules of a lower rank only.
const RANKS: &[(&str, u32)] = &[
    ("sys", 0),
    ("util", 1),
    ("sampling", 2),
    ("embree", 3),
    ("image", 3),
    ("bsdf", 3),
    ("camera", 3),
    ("scene", 4),
    ("integrator", 5),
    ("film", 6),
    ("reuse", 7),
    ("state", 8),
    ("driver", 9),
    ("eval", 10),
];

fn rank(module: &str) -> Option<u32> {
    RANKS.iter().find(|(m, _)| *m == module).map(|(_, r)| *r)
}

fn sources(dir: &Path, out: &mut Vec<std::path::PathBuf>) {
    for e in std::fs::read_dir(dir).unwrap().flatten() {
        let p = e.path();
        if p.is_dir() {
            sources(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

/// The names `crate::NAME` that `text` refers to, including `use crate::{a, b::c}`.
fn crate_refs(text: &str) -> Vec<String> {
    let mut refs = Vec::new();
    for (i, _) in text.match_indices("crate::") {
        let rest = &text[i + "crate::".len()..];
        if let Some(group) = rest.strip_prefix('{') {
            let end = group.find('}').unwrap_or(group.len());
            for part in group[..end].split(',') {
                let name: String = part
                    .trim()
                    .chars()
                    .take_while(|c| c.is_alphanumeric() || *c == '_')
                    .collect();
                refs.push(name);
            }
        } else {
            refs.push(
                rest.chars()
                    .take_while(|c| c.is_alphanumeric() || *c == '_')
                    .collect(),
            );
        }
    }
    refs
}

#[test]
fn modules_use_only_the_layers_below_them() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut files = Vec::new();
    sources(&src, &mut files);
    let mut checked = 0;
    let mut wrong = Vec::new();
    for f in &files {
        let rel = f.strip_prefix(&src).unwrap();
        let top = rel
            .components()
            .next()
            .unwrap()
            .as_os_str()
            .to_string_lossy();
        let module = top.trim_end_matches(".rs").to_string();
        let Some(own) = rank(&module) else {
            // lib.rs, main.rs, cli.rs: the top, which may use anything.
            assert!(
                ["lib", "main", "cli"].contains(&module.as_str()),
                "{}: a module missing from RANKS",
                rel.display()
            );
            continue;
        };
        let text = std::fs::read_to_string(f).unwrap();
        for r in crate_refs(&text) {
            if r == module || r.is_empty() {
                continue;
            }
            let Some(theirs) = rank(&r) else {
                wrong.push(format!("{}: crate::{r} is not a module", rel.display()));
                continue;
            };
            checked += 1;
            if theirs >= own {
                wrong.push(format!(
                    "{} (layer {own}) uses crate::{r} (layer {theirs})",
                    rel.display()
                ));
            }
        }
    }
    assert!(
        checked > 50,
        "only {checked} references found: the parser is broken"
    );
    assert!(wrong.is_empty(), "{}", wrong.join("\n"));
}
