//! The dependency rules of ARCHITECTURE.md for the engine:
//! - a dry-run looks like hardware to the engine. Only the rig (crates/engine/src/rig.rs and
//!   crates/engine/src/rig/) may name the simulator; the run loop, motion, acquisition, calibration and the store
//!   reach a dry-run only through the rig's small interface (`rig::SampleHolder`, `rig::InstrumentClock`), so the
//!   engine cannot use what the simulator knows and the instrument would not tell;
//! - the service (crates/daemon) never names the simulator either: it has the engine's rig;
//! - the engine cannot reach up into the service: its manifest names no gonio-daemon (nor the binary).

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
    for part in ["runner.rs", "prepare.rs", "store.rs", "motion.rs"] {
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

fn names_the_simulator(file: &Path) -> bool {
    let text = std::fs::read_to_string(file).expect("read");
    text.contains("gonio_simulator") || text.contains("gonio-simulator")
}

#[test]
fn the_service_names_no_simulator() {
    let daemon = Path::new(env!("CARGO_MANIFEST_DIR")).join("../daemon");
    let mut files = Vec::new();
    sources(&daemon.join("src"), &mut files);
    assert!(
        files.iter().any(|f| f.ends_with("service.rs")),
        "the daemon's sources were found"
    );
    files.push(daemon.join("Cargo.toml"));
    let offenders: Vec<String> = files
        .iter()
        .filter(|f| names_the_simulator(f))
        .map(|f| f.display().to_string())
        .collect();
    assert!(
        offenders.is_empty(),
        "the service names the simulator; it has the engine's rig: {offenders:?}"
    );
}

#[test]
fn the_engine_depends_on_no_service_code() {
    let manifest = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("Cargo.toml"))
        .expect("read the engine's manifest");
    let table: toml::Table = toml::from_str(&manifest).expect("the manifest parses");
    let mut named = Vec::new();
    for section in ["dependencies", "dev-dependencies", "build-dependencies"] {
        if let Some(deps) = table.get(section).and_then(|d| d.as_table()) {
            named.extend(deps.keys().map(|k| format!("{section}.{k}")));
        }
    }
    assert!(
        named.iter().any(|n| n == "dependencies.gonio-driver"),
        "{named:?}"
    );
    let upward: Vec<&String> = named
        .iter()
        .filter(|n| n.ends_with(".gonio-daemon") || n.ends_with(".gonio"))
        .collect();
    assert!(
        upward.is_empty(),
        "the engine names the service above it: {upward:?}"
    );
}
