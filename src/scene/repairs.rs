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
        let s = self.seen.iter().find(|s| kinds.contains(&s.kind))?;
        Some(format!(
            "{}: line {}: {}: {}",
            s.file, s.line, s.detail, s.kind.one
        ))
    }

    /// One line per kind and file, for `Scene::warnings`.
    pub fn into_warnings(self) -> Vec<String> {
        self.seen
            .into_iter()
            .map(|s| match s.count {
                1 => format!("{}: line {}: {}: {}", s.file, s.line, s.detail, s.kind.one),
                n => format!(
                    "{}: {n} {} (first at line {}: {})",
                    s.file, s.kind.many, s.line, s.detail
                ),
            })
            .collect()
    }
}

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
