//! The large tier of the numerical stress suite (10,000,000 random model/geometry pairs and the rest, see
//! crates/brdf/tests/stress/): `--stress-large` (before the report) or `--only stress-large` (alone) runs it
//! through cargo and records its output and duration in `docs/bench/stress-large.txt`; every run of the report
//! quotes the last record.

use std::path::Path;
use std::process::Command;
use std::time::Instant;

pub const RECORD: &str = "docs/bench/stress-large.txt";
pub const COMMAND: &str = "GONIO_STRESS=large cargo test --release -p gonio-brdf --test stress";

/// Run the large tier and write the record; returns the record's text.
pub fn run_and_record(root: &Path, load_before: &str) -> String {
    let cargo = std::env::var_os("CARGO").unwrap_or_else(|| "cargo".into());
    let start = Instant::now();
    let output = Command::new(cargo)
        .current_dir(root)
        .env("GONIO_STRESS", "large")
        .args(["test", "--release", "-p", "gonio-brdf", "--test", "stress"])
        .output();
    let elapsed = start.elapsed().as_secs_f64();
    let load_after = crate::load_average();
    let record = match output {
        Ok(o) => {
            let text = String::from_utf8_lossy(&o.stdout);
            let errs = String::from_utf8_lossy(&o.stderr);
            let lines: Vec<&str> = text
                .lines()
                .chain(errs.lines())
                .filter(|l| {
                    l.starts_with("test ")
                        || l.starts_with("test result")
                        || l.contains("panicked")
                        || l.contains("failures")
                        || l.contains("Finished")
                })
                .collect();
            format!(
                "command: {COMMAND}\nexit: {}\nwall time (build included when anything was rebuilt): {elapsed:.1} s\n\
                 load average before: {load_before}; after: {load_after}\n\n{}\n",
                o.status,
                lines.join("\n")
            )
        }
        Err(e) => format!("command: {COMMAND}\ncould not run cargo: {e}\n"),
    };
    if let Err(e) = std::fs::write(root.join(RECORD), &record) {
        eprintln!("cannot write {RECORD}: {e}");
    }
    record
}

/// The last record, if any.
pub fn last_record(root: &Path) -> Option<String> {
    std::fs::read_to_string(root.join(RECORD)).ok()
}
