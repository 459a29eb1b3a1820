//! ARCHITECTURE.md's rule, checked on this workspace: no import loops between files. The failure lists every
//! loop with the names that tie each edge, which is where breaking it starts.

use std::path::Path;

use gonio_testkit::imports::import_loops;

#[test]
fn the_workspace_has_no_import_loops() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let loops = import_loops(&root).expect("the workspace's sources can be read");
    let report: String = loops
        .iter()
        .map(ToString::to_string)
        .collect::<Vec<_>>()
        .join("\n");
    // Printed as well as asserted: `cargo test -- --nocapture` shows the list while it is being worked down.
    println!("{} import loop(s)\n{report}", loops.len());
    assert!(
        loops.is_empty(),
        "{} import loop(s) between files (ARCHITECTURE.md):\n{report}",
        loops.len()
    );
}
