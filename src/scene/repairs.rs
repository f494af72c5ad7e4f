//! What loading repaired or left out, so that a real model still renders and the user hears
//! about each kind of repair once: "vase.obj: 12 degenerate (zero-area) triangles skipped
//! (first at line 40: 'f 1 2 9')", never a line per face. Under strict loading the first
//! repair is an error instead, naming the file and the line like every other loading error.
use anyhow::{bail, Result};

/// A kind of repair, in the singular and the plural ("degenerate triangle skipped", ...).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Kind {
    pub one: &'static str,
    pub many: &'static str,
}

/// The first occurrence of a kind in a file, and how many there were.
struct Seen {
    file: String,
    kind: Kind,
    count: usize,
    line: usize,
    detail: String,
}

/// The repairs of one scene, in the order first seen.
pub struct Repairs {
    strict: bool,
    seen: Vec<Seen>,
}

impl Repairs {
    pub fn new(strict: bool) -> Repairs {
        Repairs {
            strict,
            seen: Vec::new(),
        }
    }

    /// Record one repair of `kind` at `line` of `file`; `detail` (the statement quoted, or the
    /// values changed) is built only for the first of its kind. An error under strict loading.
    pub fn note(
        &mut self,
        file: &str,
        line: usize,
        kind: Kind,
        detail: impl FnOnce() -> String,
    ) -> Result<()> {
        if self.strict {
            bail!(
                "{file}: line {line}: {}: {} (refused: strict loading)",
                detail(),
                kind.one
            );
        }
        if let Some(s) = self
            .seen
            .iter_mut()
            .find(|s| s.kind == kind && s.file == file)
        {
            s.count += 1;
        } else {
            self.seen.push(Seen {
                file: file.to_string(),
                kind,
                count: 1,
                line,
                detail: detail(),
            });
        }
        Ok(())
    }

    /// The warning about the first repair of one of `kinds`, if any (to explain a later error).
    pub fn first_of(&self, kinds: &[Kind]) -> Option<String> {
        self.first_in(None, kinds)
    }

    /// `first_of`, among the repairs of file `file` only, where one is given.
    pub fn first_in(&self, file: Option<&str>, kinds: &[Kind]) -> Option<String> {
        let s = self
            .seen
            .iter()
            .find(|s| kinds.contains(&s.kind) && file.is_none_or(|f| s.file == f))?;
        Some(format!(
            "{}: line {}: {}: {}",
            s.file, s.line, s.detail, s.kind.one
        ))
    }

    /// One line per kind and file, for `Scene::warnings`; a kind seen in more than
    /// `MAX_FILES_APART` files is one line for all of them (a kit of 40 props, each with its
    /// own MTL from one exporter, said the same 40 times).
    pub fn into_warnings(self) -> Vec<String> {
        // Per kind (by its text): the files it was seen in, and how many times in all.
        let mut per_kind: std::collections::HashMap<&str, (usize, usize)> = Default::default();
        for s in &self.seen {
            let e = per_kind.entry(s.kind.one).or_default();
            *e = (e.0 + 1, e.1 + s.count);
        }
        let mut said = std::collections::HashSet::new();
        let mut out = Vec::new();
        for s in &self.seen {
            let (files, total) = per_kind[s.kind.one];
            if files <= MAX_FILES_APART {
                out.push(match s.count {
                    1 => format!("{}: line {}: {}: {}", s.file, s.line, s.detail, s.kind.one),
                    n => format!(
                        "{}: {n} {} (first at line {}: {})",
                        s.file, s.kind.many, s.line, s.detail
                    ),
                });
            } else if said.insert(s.kind.one) {
                // Said once, at its first file.
                out.push(format!(
                    "{total} {} in {files} files (first in {} at line {}: {})",
                    s.kind.many, s.file, s.line, s.detail
                ));
            }
        }
        out
    }
}

/// The most files a kind of repair is said for one by one (`Repairs::into_warnings`).
const MAX_FILES_APART: usize = 3;

#[cfg(test)]
mod tests {
    use super::*;

    const K: Kind = Kind {
        one: "degenerate triangle skipped",
        many: "degenerate triangles skipped",
    };

    #[test]
    fn one_line_per_kind_with_a_count() {
        let mut r = Repairs::new(false);
        r.note("a.obj", 40, K, || "'f 1 2 9'".into()).unwrap();
        r.note("a.obj", 41, K, || unreachable!("built once"))
            .unwrap();
        r.note("b.obj", 3, K, || "'f 1 1 2'".into()).unwrap();
        assert_eq!(
            r.into_warnings(),
            [
                "a.obj: 2 degenerate triangles skipped (first at line 40: 'f 1 2 9')",
                "b.obj: line 3: 'f 1 1 2': degenerate triangle skipped",
            ]
        );
        // In more than three files: one line for them all.
        let mut r = Repairs::new(false);
        for k in 0..40 {
            let file = format!("p{k}/prop.mtl");
            r.note(&file, 4, K, || format!("'f {k}'")).unwrap();
            r.note(&file, 5, K, || unreachable!("built once")).unwrap();
        }
        assert_eq!(
            r.into_warnings(),
            ["80 degenerate triangles skipped in 40 files (first in p0/prop.mtl at line 4: 'f 0')"]
        );
        let e = Repairs::new(true)
            .note("a.obj", 40, K, || "'f 1 2 9'".into())
            .unwrap_err()
            .to_string();
        assert_eq!(
            e,
            "a.obj: line 40: 'f 1 2 9': degenerate triangle skipped (refused: strict loading)"
        );
    }
}
