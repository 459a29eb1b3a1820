//! The project's check of ARCHITECTURE.md's rule that files import in one direction only: if a.rs uses b.rs,
//! nothing b.rs uses (directly or through others) uses a.rs. [`import_loops`] reads every source file of every
//! crate in a workspace and returns each loop with the names that tie it; crates/testkit/tests/it/no_import_loops.rs
//! runs it on this workspace.
//!
//! What counts as an edge from a file to another file of the same crate:
//! - every leaf of a `use` tree (groups flattened, `pub use` and `pub(crate) use` alike) and every path written
//!   in code, when it starts at `crate`, `self`, `super` or a child module the file declares (`mod x;` then
//!   `x::Y`) or a module the file imported by name (`use crate::rig;` then `rig::sim_link::X`);
//! - to the file of the path's longest prefix that is a module file, so `crate::Foo` names lib.rs; a name that
//!   file re-exports (`pub use rig::Rig;`) is followed on to where it comes from, so a module using back, through
//!   the crate root, what another module it feeds re-exports is the loop it is, and a re-export hides none.
//!
//! Not edges: `mod x;` itself, text in comments and literals, a file's paths to itself, paths into other crates
//! (Cargo forbids crate cycles), test code (`#[cfg(test)]` items and test module files, which may use their
//! parent freely), and a path up into one of the file's own enclosing modules (`super::X`, `crate::parent::X`
//! for an item defined there). An inline `mod x { }` counts as its file.
//!
//! Why a child may use its ancestors: Rust makes a module and its children one unit (a child sees its parent's
//! private items by design, and a parent's `pub use child::X` is the module's face), so a parent file and its
//! own sub-module files are read together. Everything else is held to the rule: siblings, cousins, and any
//! loop that leaves the module and comes back (motion.rs -> its child supervise.rs -> rig.rs -> motion.rs).
//! The scan is lexical, not rustc's name resolution: names a glob import brings into scope do not start
//! paths, and a glob re-export (`pub use a::*;`) is not followed.
//!
//! Inside: `lexer` (source to tokens, comments and literals gone), `scan` (one file's paths and child modules),
//! `tree` (crates and their files' module paths), `graph` (resolution and the loops, Tarjan), `report`
//! ([`Loop`] and its `Display`), `error` ([`ImportScanError`]).

mod error;
mod graph;
mod lexer;
mod report;
mod scan;
mod tree;

use std::collections::HashSet;
use std::fs;
use std::path::Path;

pub use error::ImportScanError;
pub use report::{Loop, Tie};

/// Every import loop among the files of the crates under `workspace_root`, sorted by their files; empty when
/// the rule holds. Errors only when a directory, manifest or source file cannot be read, or when no crate is
/// found (a wrong root must not pass as a clean one).
pub fn import_loops(workspace_root: &Path) -> Result<Vec<Loop>, ImportScanError> {
    let crates = tree::find_crates(workspace_root)?;
    if crates.is_empty() {
        return Err(ImportScanError::NoCrates(workspace_root.to_path_buf()));
    }
    let mut nodes = Vec::new();
    for (index, dir) in crates.iter().enumerate() {
        let src = dir.join("src");
        let mut scanned = Vec::new();
        for (path, comps) in tree::source_files(&src)? {
            let text = fs::read_to_string(&path).map_err(|source| ImportScanError::Read {
                path: path.clone(),
                source,
            })?;
            scanned.push((path, comps, scan::scan(&lexer::tokens(&text))));
        }
        // With both a lib.rs and a main.rs, a top-level module is the binary's only if main.rs declares it.
        let has_lib = src.join("lib.rs").is_file();
        let main_mods: HashSet<String> = scanned
            .iter()
            .filter(|(_, comps, _)| comps.len() == 1 && comps[0] == "main.rs")
            .flat_map(|(_, _, scan)| scan.children.iter().filter(|c| c.inline.is_empty()))
            .map(|c| c.name.clone())
            .collect();
        for (path, comps, scan) in scanned {
            let place = tree::place(&comps, |first| !has_lib || main_mods.contains(first));
            let rel = path.strip_prefix(workspace_root).unwrap_or(&path);
            let rel = rel
                .components()
                .map(|c| c.as_os_str().to_string_lossy())
                .collect::<Vec<_>>()
                .join("/");
            nodes.push(graph::Node {
                rel,
                unit: (index, place.root),
                module: place.module,
                scan,
            });
        }
    }
    Ok(graph::loops(&nodes))
}
