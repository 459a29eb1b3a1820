//! The import-loop check on small fixture crates written to a temporary directory: each kind of edge it must
//! see makes a loop it must find, and each thing that is not an edge (a declaration, a comment, a string, test
//! code) must not make one.

use std::fs;
use std::path::Path;

use gonio_testkit::imports::{ImportScanError, Loop, import_loops};
use tempfile::TempDir;

/// A workspace root holding the given files (paths relative to the root); a crate is a directory with a
/// `Cargo.toml` that has a `[package]`.
fn workspace(files: &[(&str, &str)]) -> TempDir {
    let dir = tempfile::tempdir().expect("temporary directory");
    for (path, text) in files {
        let path = dir.path().join(path);
        fs::create_dir_all(path.parent().expect("a file has a parent")).expect("fixture directory");
        fs::write(&path, text).expect("fixture file");
    }
    dir
}

const PACKAGE: &str = "[package]\nname = \"fixture\"\nversion = \"0.1.0\"\n";

/// A single-crate workspace: `Cargo.toml` plus the given files under `src/`.
fn crate_with(files: &[(&str, &str)]) -> TempDir {
    let mut all = vec![("Cargo.toml".to_string(), PACKAGE.to_string())];
    all.extend(files.iter().map(|(p, t)| (format!("src/{p}"), t.to_string())));
    let refs: Vec<(&str, &str)> = all.iter().map(|(p, t)| (p.as_str(), t.as_str())).collect();
    workspace(&refs)
}

fn loops_in(dir: &TempDir) -> Vec<Loop> {
    import_loops(dir.path()).expect("the fixture can be scanned")
}

fn report(loops: &[Loop]) -> String {
    loops.iter().map(ToString::to_string).collect()
}

/// The one loop expected, with its files (under `src/`) and each edge's tying names.
fn assert_one_loop(loops: &[Loop], files: &[&str], ties: &[(&str, &str, &[&str])]) {
    assert_eq!(loops.len(), 1, "expected one loop, found:\n{}", report(loops));
    let found = &loops[0];
    let expected: Vec<String> = files.iter().map(|f| format!("src/{f}")).collect();
    assert_eq!(found.files, expected, "{found}");
    assert_eq!(found.ties.len(), ties.len(), "{found}");
    for (from, to, names) in ties {
        let tie = found.tie(&format!("src/{from}"), &format!("src/{to}"));
        let tie = tie.unwrap_or_else(|| panic!("no edge {from} -> {to} in:\n{found}"));
        assert_eq!(tie.names, *names, "{found}");
    }
}

#[test]
fn a_two_file_loop_is_found_and_named() {
    let dir = crate_with(&[
        ("lib.rs", "mod a;\nmod b;\n"),
        ("a.rs", "use crate::b::X;\npub struct Y;\n"),
        ("b.rs", "use super::a::Y;\npub struct X;\n"),
    ]);
    let loops = loops_in(&dir);
    assert_one_loop(
        &loops,
        &["a.rs", "b.rs"],
        &[("a.rs", "b.rs", &["X"]), ("b.rs", "a.rs", &["Y"])],
    );
    let text = loops[0].to_string();
    assert!(
        text.contains("import loop of 2 files: src/a.rs, src/b.rs"),
        "{text}"
    );
    assert!(text.contains("src/b.rs -> src/a.rs: Y"), "{text}");
}

#[test]
fn a_three_file_loop_through_a_grouped_use_is_found() {
    let dir = crate_with(&[
        ("lib.rs", "mod m;\nmod other;\n"),
        ("other.rs", "pub struct O;\n"),
        ("m/mod.rs", "mod a;\nmod b;\nmod c;\n"),
        (
            "m/a.rs",
            "use crate::{m::{b::{B, f}}, other::O};\npub struct A;\n",
        ),
        (
            "m/b.rs",
            "pub(crate) use crate::m::c::C;\npub struct B;\npub fn f() {}\n",
        ),
        ("m/c.rs", "use super::super::m::a::A as Renamed;\npub struct C;\n"),
    ]);
    assert_one_loop(
        &loops_in(&dir),
        &["m/a.rs", "m/b.rs", "m/c.rs"],
        &[
            ("m/a.rs", "m/b.rs", &["B", "f"]),
            ("m/b.rs", "m/c.rs", &["C"]),
            ("m/c.rs", "m/a.rs", &["A"]),
        ],
    );
}

#[test]
fn a_loop_through_a_declared_child_and_a_sibling_is_found() {
    // motion.rs -> its child supervise.rs (`use supervise::Device`), which uses rig.rs, which uses motion.rs.
    let dir = crate_with(&[
        ("lib.rs", "pub mod motion;\npub mod rig;\n"),
        (
            "motion.rs",
            "mod supervise;\nuse supervise::Device;\npub struct Motion;\n\
             fn f() { let _ = supervise::open(); }\n",
        ),
        (
            "motion/supervise.rs",
            "use super::Motion;\nuse crate::rig::Rig;\npub struct Device;\npub fn open() {}\n",
        ),
        ("rig.rs", "pub struct Rig;\nfn m(_: crate::motion::Motion) {}\n"),
    ]);
    assert_one_loop(
        &loops_in(&dir),
        &["motion.rs", "motion/supervise.rs", "rig.rs"],
        &[
            ("motion.rs", "motion/supervise.rs", &["Device", "open"]),
            ("motion/supervise.rs", "rig.rs", &["Rig"]),
            ("rig.rs", "motion.rs", &["Motion"]),
        ],
    );
}

#[test]
fn a_child_using_its_parent_while_the_parent_uses_it_is_one_module_not_a_loop() {
    // The parent's face re-exports and calls its child; the child uses what its parent defines (`super::`,
    // `crate::motion::`): Rust makes a module and its children one unit, so this pair is no loop.
    let dir = crate_with(&[
        ("lib.rs", "pub mod motion;\n"),
        (
            "motion.rs",
            "mod supervise;\npub use supervise::Device;\npub struct Motion;\n\
             fn f() { let _ = supervise::open(); }\n",
        ),
        (
            "motion/supervise.rs",
            "use super::Motion;\npub struct Device(crate::motion::Motion);\npub fn open() {}\n",
        ),
    ]);
    assert!(loops_in(&dir).is_empty());
}

#[test]
fn a_path_through_a_module_imported_by_name_reaches_the_longest_prefix() {
    // `use crate::rig as r;` then `r::sim_link::SimPipe` is sim_link.rs's, not rig.rs's.
    let dir = crate_with(&[
        ("lib.rs", "mod engine;\nmod rig;\n"),
        ("rig.rs", "pub mod sim_link;\n"),
        (
            "rig/sim_link.rs",
            "use crate::engine::Engine;\npub struct SimPipe;\n",
        ),
        (
            "engine.rs",
            "use crate::rig as r;\npub struct Engine;\nfn pipe(_: r::sim_link::SimPipe) {}\n",
        ),
    ]);
    assert_one_loop(
        &loops_in(&dir),
        &["engine.rs", "rig/sim_link.rs"],
        &[
            ("engine.rs", "rig/sim_link.rs", &["SimPipe"]),
            ("rig/sim_link.rs", "engine.rs", &["Engine"]),
        ],
    );
}

#[test]
fn a_loop_through_a_re_export_in_lib_rs_is_found() {
    // rig.rs takes `run` through the crate root, which re-exports it from runner.rs, and runner.rs takes `Rig`
    // the same way: a loop rig.rs <-> runner.rs behind lib.rs's re-exports.
    let dir = crate_with(&[
        (
            "lib.rs",
            "mod rig;\nmod runner;\npub use rig::Rig;\npub use runner::{run, Runner as R};\n",
        ),
        ("runner.rs", "pub struct Runner(crate::Rig);\npub fn run() {}\n"),
        (
            "rig.rs",
            "pub struct Rig;\nfn go() { crate::run() }\nfn r(_: crate::R) {}\n",
        ),
    ]);
    assert_one_loop(
        &loops_in(&dir),
        &["rig.rs", "runner.rs"],
        &[
            ("rig.rs", "runner.rs", &["Runner", "run"]),
            ("runner.rs", "rig.rs", &["Rig"]),
        ],
    );
}

#[test]
fn a_name_the_crate_root_re_exports_from_a_third_file_makes_no_loop() {
    // rig.rs takes EngineError through the crate root, which re-exports it from error.rs and re-exports rig's
    // Rig: the edge runs to error.rs, where the name comes from, and nothing runs back.
    let dir = crate_with(&[
        (
            "lib.rs",
            "mod error;\nmod rig;\npub use error::EngineError;\npub use rig::Rig;\n",
        ),
        ("error.rs", "pub struct EngineError;\n"),
        (
            "rig.rs",
            "pub struct Rig;\nfn fail() -> crate::EngineError { crate::EngineError }\n",
        ),
    ]);
    assert!(loops_in(&dir).is_empty());
}

#[test]
fn paths_in_comments_and_literals_make_no_edge() {
    let dir = crate_with(&[
        ("lib.rs", "mod a;\nmod b;\n"),
        ("a.rs", "use crate::b::X;\npub struct Y;\n"),
        (
            "b.rs",
            r####"//! Uses `crate::a::Y` in prose only.
// use crate::a::Y;
/// super::a::Y
/* block /* nested crate::a::Y */ still a comment: super::a::Y */
pub struct X;
const S: &str = "crate::a::Y \" super::a::Y";
const R: &str = r#"super::a::Y "quoted" crate::a::Y"#;
const B: &[u8] = br##"crate::a::Y"# "##;
const Q: char = '"';
const E: char = '\'';
fn f<'a>(s: &'a str) -> &'a str { let _ = "crate::a::Y"; s }
"####,
        ),
    ]);
    let loops = loops_in(&dir);
    assert!(loops.is_empty(), "{}", report(&loops));
}

#[test]
fn a_parent_declaring_a_child_that_uses_super_is_not_a_loop() {
    let dir = crate_with(&[
        ("lib.rs", "pub mod motion;\n"),
        (
            "motion.rs",
            "mod supervise;\npub mod homing;\npub struct Motion;\n",
        ),
        (
            "motion/supervise.rs",
            "use super::Motion;\nfn f() -> super::Motion { super::Motion }\n",
        ),
        (
            "motion/homing/mod.rs",
            "use super::super::motion::Motion;\nuse crate::motion::*;\n",
        ),
    ]);
    let loops = loops_in(&dir);
    assert!(loops.is_empty(), "{}", report(&loops));
}

#[test]
fn test_modules_using_their_parent_are_not_loops() {
    // Without the cfg(test) exclusions each of these would close a loop: a.rs -> a/tests.rs through its test-only
    // helper call, a/tests.rs -> a.rs; a.rs -> b.rs, b's inline test module -> a.rs.
    let dir = crate_with(&[
        ("lib.rs", "mod a;\nmod b;\n"),
        (
            "a.rs",
            "use crate::b::B;\npub fn f() {}\n#[cfg(test)]\nmod tests;\n\
             #[cfg(test)]\n#[allow(dead_code)]\nfn helper_user() { tests::helper(); }\n",
        ),
        ("a/tests.rs", "use super::*;\npub fn helper() { f(); }\n"),
        (
            "b.rs",
            "pub struct B;\n#[cfg(test)]\nmod tests {\n    use crate::a::f;\n}\n",
        ),
    ]);
    let loops = loops_in(&dir);
    assert!(loops.is_empty(), "{}", report(&loops));
}

#[test]
fn a_clean_tree_has_no_loops() {
    let dir = crate_with(&[
        (
            "lib.rs",
            "mod a;\nmod b;\nmod c;\npub use a::A;\nuse std::fmt;\nuse ::serde::Serialize;\n",
        ),
        // `super` inside an inline module is a.rs itself, not the crate root: no edge back to lib.rs.
        (
            "a.rs",
            "use crate::b::B;\npub struct A;\nmod inner {\n    use super::A;\n    use self::deep::D;\n}\n",
        ),
        (
            "b.rs",
            "use crate::c::{self, C};\nuse gonio_x::b::Thing;\npub struct B;\nfn r#type() -> c::C { C }\n",
        ),
        (
            "c.rs",
            "pub struct C;\nfn f() -> std::io::Result<()> { Ok(()) }\n",
        ),
    ]);
    let loops = loops_in(&dir);
    assert!(loops.is_empty(), "{}", report(&loops));
}

#[test]
fn the_workspace_walk_finds_member_crates_and_skips_build_output_and_tests() {
    let looped = [
        ("src/lib.rs", "mod a;\nmod b;\n"),
        ("src/a.rs", "use crate::b::X;\n"),
        ("src/b.rs", "use crate::a::Y;\n"),
    ];
    let mut files = vec![("Cargo.toml", "[workspace]\nmembers = [\"crates/*\"]\n")];
    let mut owned = Vec::new();
    for base in ["crates/x", "target/debug/build/y", "tests/fixture", ".hidden/z"] {
        owned.push((format!("{base}/Cargo.toml"), PACKAGE.to_string()));
        owned.extend(looped.iter().map(|(p, t)| (format!("{base}/{p}"), t.to_string())));
    }
    // A second crate with the same module names: paths never cross crates.
    owned.push(("crates/w/Cargo.toml".to_string(), PACKAGE.to_string()));
    owned.push(("crates/w/src/lib.rs".to_string(), "mod a;\nmod b;\n".to_string()));
    owned.push(("crates/w/src/a.rs".to_string(), "pub struct Y;\n".to_string()));
    owned.push(("crates/w/src/b.rs".to_string(), "pub struct X;\n".to_string()));
    files.extend(owned.iter().map(|(p, t)| (p.as_str(), t.as_str())));
    let loops = import_loops(workspace(&files).path()).expect("scannable");
    assert_eq!(loops.len(), 1, "{}", report(&loops));
    assert_eq!(loops[0].files, ["crates/x/src/a.rs", "crates/x/src/b.rs"]);
}

#[test]
fn a_binary_beside_a_library_is_its_own_crate() {
    // main.rs declares cli and report, so their `crate::` paths are main.rs's; lib.rs's modules resolve against
    // lib.rs, and bin/tool.rs is a root of its own.
    let dir = crate_with(&[
        ("lib.rs", "mod things;\npub use things::Thing;\n"),
        ("things.rs", "pub struct Thing;\n"),
        (
            "main.rs",
            "mod cli;\nmod report;\nuse cli::Args;\npub struct CliError;\nfn main() {}\n",
        ),
        (
            "cli.rs",
            "use crate::CliError;\nuse crate::report::Table;\npub struct Args;\n",
        ),
        ("report.rs", "pub struct Table(crate::cli::Args);\n"),
        ("bin/tool.rs", "use crate::Thing;\nfn main() {}\n"),
    ]);
    assert_one_loop(
        &loops_in(&dir),
        &["cli.rs", "report.rs"],
        &[
            ("cli.rs", "report.rs", &["Table"]),
            ("report.rs", "cli.rs", &["Args"]),
        ],
    );
}

#[test]
fn unreadable_input_is_a_typed_error_and_odd_syntax_is_not() {
    let empty = tempfile::tempdir().expect("temporary directory");
    assert!(matches!(
        import_loops(empty.path()),
        Err(ImportScanError::NoCrates(_))
    ));
    assert!(matches!(
        import_loops(&empty.path().join("missing")),
        Err(ImportScanError::Read { .. })
    ));

    let odd = crate_with(&[
        ("lib.rs", "mod a;\nuse crate::{{{{a::{;\n\"unterminated"),
        ("a.rs", "use super::super::super::x;\n}}} ) ] #[cfg(test)] r#\n'"),
    ]);
    assert!(loops_in(&odd).is_empty());

    let binary = crate_with(&[("lib.rs", "mod a;\n")]);
    fs::write(binary.path().join("src/a.rs"), [0xff, 0xfe, 0x00]).expect("fixture file");
    let err = import_loops(binary.path()).expect_err("not UTF-8");
    assert!(
        err.to_string()
            .contains(&Path::new("src").join("a.rs").display().to_string()),
        "{err}"
    );
}
