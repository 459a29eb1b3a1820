//! What the scan reports: each import loop with the files in it and, for each of its edges, the names that tie
//! one file to the next, which is what someone breaking the loop needs to see.

use std::fmt;

/// One import loop: files of one crate that reach each other through their `use`s and paths (a strongly
/// connected component of the file graph with more than one file).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Loop {
    /// Paths relative to the workspace root, `/`-separated, sorted.
    pub files: Vec<String>,
    /// Every edge between two files of the loop, sorted by file.
    pub ties: Vec<Tie>,
}

/// `from` names something in `to`: `names` are the first path segments after `to`'s module (`EngineError`
/// for `crate::engine::EngineError`), `*` for a glob, the module's own name for a path to the module itself.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Tie {
    pub from: String,
    pub to: String,
    pub names: Vec<String>,
}

impl Loop {
    /// The loop's edge `from -> to`, if it has one (paths as in [`Loop::files`]).
    pub fn tie(&self, from: &str, to: &str) -> Option<&Tie> {
        self.ties.iter().find(|t| t.from == from && t.to == to)
    }
}

impl fmt::Display for Tie {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} -> {}: {}", self.from, self.to, self.names.join(", "))
    }
}

impl fmt::Display for Loop {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(
            f,
            "import loop of {} files: {}",
            self.files.len(),
            self.files.join(", ")
        )?;
        for tie in &self.ties {
            writeln!(f, "    {tie}")?;
        }
        Ok(())
    }
}
