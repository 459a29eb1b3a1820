//! The workspace's crates and their source files, each file placed in a module tree by where it lies: the
//! layout rustc itself follows for `mod name;` (`a.rs` or `a/mod.rs` is `a`, `a/b.rs` is `a::b`), so a file's
//! module path is known without following every declaration from the root.

use std::fs;
use std::path::{Path, PathBuf};

use super::error::ImportScanError;

/// Directories that hold no workspace crate's library or binary sources: build output, integration tests,
/// benchmarks, examples, and hidden directories (`.git`, editors' state).
const SKIPPED_DIRS: [&str; 4] = ["target", "tests", "benches", "examples"];

/// Which compilation root of a crate a file belongs to. A crate with both `lib.rs` and `main.rs` is two crates
/// to rustc, and each `src/bin/` binary is one more: a path such as `crate::x` means a different file in each.
#[derive(Debug, Clone, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub(crate) enum Root {
    Lib,
    Main,
    Bin(String),
}

/// Where one source file lies: its root and its module path under that root (empty for the root file).
#[derive(Debug, Clone, PartialEq, Eq)]
pub(crate) struct Place {
    pub root: Root,
    pub module: Vec<String>,
}

/// Every directory under `root` (the root included) whose `Cargo.toml` has a `[package]` and whose `src/` has
/// a `lib.rs` or `main.rs`, in path order. A virtual manifest (`[workspace]` only) is not a crate.
pub(crate) fn find_crates(root: &Path) -> Result<Vec<PathBuf>, ImportScanError> {
    let mut found = Vec::new();
    let mut pending = vec![root.to_path_buf()];
    while let Some(dir) = pending.pop() {
        let manifest = dir.join("Cargo.toml");
        if manifest.is_file() {
            let text = fs::read_to_string(&manifest).map_err(|source| ImportScanError::Read {
                path: manifest.clone(),
                source,
            })?;
            let package = text.lines().any(|l| l.trim() == "[package]");
            let src = dir.join("src");
            if package && (src.join("lib.rs").is_file() || src.join("main.rs").is_file()) {
                found.push(dir.clone());
            }
        }
        for (path, is_dir) in entries(&dir)? {
            let name = path.file_name().and_then(|n| n.to_str()).unwrap_or("");
            if is_dir && !name.starts_with('.') && !SKIPPED_DIRS.contains(&name) {
                pending.push(path);
            }
        }
    }
    found.sort();
    Ok(found)
}

/// Every `.rs` file under `src_dir` (hidden directories skipped), with its path components below `src_dir`.
pub(crate) fn source_files(src_dir: &Path) -> Result<Vec<(PathBuf, Vec<String>)>, ImportScanError> {
    let mut files = Vec::new();
    let mut pending = vec![(src_dir.to_path_buf(), Vec::<String>::new())];
    while let Some((dir, comps)) = pending.pop() {
        for (path, is_dir) in entries(&dir)? {
            // A file name that is not UTF-8 cannot be a module's name, so it cannot be imported either.
            let Some(name) = path.file_name().and_then(|n| n.to_str()).map(str::to_string) else {
                continue;
            };
            let mut sub = comps.clone();
            sub.push(name.clone());
            if is_dir && !name.starts_with('.') {
                pending.push((path, sub));
            } else if !is_dir && name.ends_with(".rs") {
                files.push((path, sub));
            }
        }
    }
    files.sort();
    Ok(files)
}

/// A directory's entries with whether each is a directory; symbolic links are not followed (a link back up
/// the tree would make the walk endless).
fn entries(dir: &Path) -> Result<Vec<(PathBuf, bool)>, ImportScanError> {
    let err = |source| ImportScanError::Read {
        path: dir.to_path_buf(),
        source,
    };
    let mut out = Vec::new();
    for entry in fs::read_dir(dir).map_err(err)? {
        let entry = entry.map_err(err)?;
        let kind = entry.file_type().map_err(err)?;
        if !kind.is_symlink() {
            out.push((entry.path(), kind.is_dir()));
        }
    }
    Ok(out)
}

/// The root and module path of a file from its components under `src/`. `main_owns(first)` says whether a
/// top-level file or directory named `first` belongs to `main.rs` (which declares `mod first;`) rather than to
/// `lib.rs`; the caller knows from the two roots' declarations.
pub(crate) fn place(comps: &[String], main_owns: impl Fn(&str) -> bool) -> Place {
    let module = |rest: &[String]| -> Vec<String> {
        let mut m: Vec<String> = rest
            .iter()
            .map(|c| c.trim_end_matches(".rs").to_string())
            .collect();
        if m.last().is_some_and(|l| l == "mod") {
            m.pop();
        }
        m
    };
    match comps {
        [only] if only == "lib.rs" => Place {
            root: Root::Lib,
            module: Vec::new(),
        },
        [only] if only == "main.rs" => Place {
            root: Root::Main,
            module: Vec::new(),
        },
        [bin, file] if bin == "bin" => Place {
            root: Root::Bin(file.trim_end_matches(".rs").to_string()),
            module: Vec::new(),
        },
        [bin, name, rest @ ..] if bin == "bin" => {
            let module = if rest.len() == 1 && rest[0] == "main.rs" {
                Vec::new()
            } else {
                module(rest)
            };
            Place {
                root: Root::Bin(name.clone()),
                module,
            }
        }
        _ => {
            let module = module(comps);
            let first = module.first().map(String::as_str).unwrap_or("");
            let root = if main_owns(first) { Root::Main } else { Root::Lib };
            Place { root, module }
        }
    }
}
