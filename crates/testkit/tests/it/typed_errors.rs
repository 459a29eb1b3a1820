//! ARCHITECTURE.md's rule that libraries return typed errors, checked on this workspace's sources: no public
//! function of a library crate returns `Result<_, String>` (the binary, the bench, the soaks and this testkit
//! turn errors into messages and may).

use std::path::{Path, PathBuf};

/// Crates whose public functions may return `String` errors: they are programs or test helpers, not seams.
const NOT_LIBRARIES: [&str; 4] = ["gonio", "bench", "soak", "testkit"];

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for e in entries.flatten() {
        let p = e.path();
        if p.is_dir() {
            rust_files(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

/// The public functions of `source` whose return type is `Result<_, String>`: each `pub fn` (or `pub async
/// fn`) signature, from `fn` to its body or `;`, with its whitespace collapsed.
fn string_error_functions(source: &str) -> Vec<String> {
    let mut found = Vec::new();
    let mut rest = source;
    while let Some(at) = rest.find("pub ") {
        let after = &rest[at + 4..];
        let after = after.strip_prefix("async ").unwrap_or(after);
        rest = &rest[at + 4..];
        let Some(signature) = after.strip_prefix("fn ") else {
            continue;
        };
        let end = signature.find(['{', ';']).unwrap_or(signature.len());
        let signature: String = signature[..end].split_whitespace().collect::<Vec<_>>().join(" ");
        let Some((_, returns)) = signature.rsplit_once("->") else {
            continue;
        };
        let returns = returns.split(" where ").next().unwrap_or(returns).trim();
        if returns.starts_with("Result<") && returns.replace(' ', "").ends_with(",String>") {
            found.push(signature);
        }
    }
    found
}

#[test]
fn no_library_function_returns_a_string_error() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let mut dirs: Vec<PathBuf> = std::fs::read_dir(root.join("crates"))
        .expect("the crates directory")
        .flatten()
        .map(|e| e.path())
        .filter(|p| !NOT_LIBRARIES.iter().any(|n| p.ends_with(n)))
        .map(|p| p.join("src"))
        .collect();
    dirs.push(root.join("simulator/src"));
    let mut offenders = Vec::new();
    let mut files = 0;
    for dir in dirs {
        let mut sources = Vec::new();
        rust_files(&dir, &mut sources);
        for file in sources {
            files += 1;
            let text = std::fs::read_to_string(&file).expect("read a source file");
            for f in string_error_functions(&text) {
                offenders.push(format!("{}: fn {f}", file.display()));
            }
        }
    }
    assert!(files > 100, "only {files} source files scanned");
    assert!(
        offenders.is_empty(),
        "public functions returning Result<_, String> (give them a thiserror type):\n{}",
        offenders.join("\n")
    );
}

#[test]
fn the_scan_finds_string_errors_across_lines_and_leaves_typed_ones() {
    let source = "pub fn a(x: u8) -> Result<u8, String> { }\n\
                  pub async fn b(\n    x: u8,\n) -> Result<Vec<String>, String>;\n\
                  pub fn c() -> Result<String, MyError> {}\n\
                  fn d() -> Result<(), String> {}\n\
                  pub(crate) fn e() -> Result<(), String> {}\n";
    let found = string_error_functions(source);
    assert_eq!(
        found,
        [
            "a(x: u8) -> Result<u8, String>",
            "b( x: u8, ) -> Result<Vec<String>, String>"
        ]
    );
}
