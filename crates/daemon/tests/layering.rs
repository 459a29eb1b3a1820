//! The dependency rule of ARCHITECTURE.md: a dry-run looks like hardware to the engine. Only the rig
//! (crates/daemon/src/rig.rs and crates/daemon/src/rig/) may name the simulator; the engine, the store, the
//! service and the API reach a dry-run only through the rig's small interface (`rig::SampleHolder`,
//! `rig::InstrumentClock`), so the engine cannot use what the simulator knows and the instrument would not tell.

use std::path::{Path, PathBuf};

fn sources(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).expect("read src") {
        let path = entry.expect("entry").path();
        if path.is_dir() {
            sources(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

#[test]
fn only_the_rig_names_the_simulator() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut files = Vec::new();
    sources(&src, &mut files);
    let rig = [src.join("rig.rs"), src.join("rig")];
    let engine: Vec<&PathBuf> = files
        .iter()
        .filter(|f| !rig.iter().any(|r| f.starts_with(r)))
        .collect();
    // The engine's files are there to be checked (the walk found them).
    for part in ["runner.rs", "engine.rs", "store.rs", "service.rs"] {
        assert!(
            engine.iter().any(|f| f.ends_with(part)),
            "{part} not found under {}",
            src.display()
        );
    }
    assert!(engine.iter().any(|f| f.starts_with(src.join("runner"))));
    let offenders: Vec<String> = engine
        .iter()
        .filter(|f| {
            let text = std::fs::read_to_string(f).expect("read");
            text.contains("gonio_simulator") || text.contains("gonio-simulator")
        })
        .map(|f| f.display().to_string())
        .collect();
    assert!(
        offenders.is_empty(),
        "these files name the simulator; reach a dry-run through crate::rig instead: {offenders:?}"
    );
}
