//! The `gonio` binary under test, and dry-runs through it.

use std::path::{Path, PathBuf};
use std::process::Command;

/// The `gonio` executable Cargo built for the running test: `CARGO_BIN_EXE_gonio` when Cargo sets it in the
/// environment, else the file Cargo puts beside the test executables' `deps/` directory (where the binary's
/// own integration tests find it).
pub fn gonio_exe() -> PathBuf {
    if let Some(p) = std::env::var_os("CARGO_BIN_EXE_gonio") {
        return PathBuf::from(p);
    }
    let test = std::env::current_exe().expect("the test's own path");
    let profile_dir = test
        .parent()
        .and_then(Path::parent)
        .expect("a test executable lives in <target>/<profile>/deps");
    let exe = profile_dir.join(format!("gonio{}", std::env::consts::EXE_SUFFIX));
    assert!(
        exe.is_file(),
        "{} does not exist: only the gonio package's integration tests have the binary built",
        exe.display()
    );
    exe
}

/// A command running the `gonio` binary.
pub fn gonio() -> Command {
    Command::new(gonio_exe())
}

/// Output bytes as text, for messages.
pub fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

/// `gonio run CAMPAIGN --out OUT --quiet`, not yet started.
pub fn quiet_run(campaign: &Path, out: &Path) -> Command {
    let mut c = gonio();
    c.arg("run").arg(campaign).arg("--out").arg(out).arg("--quiet");
    c
}

/// Writes `campaign` to `dir/<id>.toml` and runs it to completion into `dir/<id>`; returns that run directory.
/// Panics with gonio's message when the run fails.
pub fn dry_run(dir: &Path, id: &str, campaign: &str) -> PathBuf {
    let file = dir.join(format!("{id}.toml"));
    std::fs::write(&file, campaign).expect("write the campaign file");
    let out = dir.join(id);
    let o = quiet_run(&file, &out).output().expect("start gonio run");
    assert!(o.status.success(), "gonio run {id} failed: {}", text(&o.stderr));
    out
}
