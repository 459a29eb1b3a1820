//! A quiet first run: the README's main command, `gonio run config/campaigns/demo.toml`, on the ideal simulated
//! instrument with every fault off, prints no WARN or ERROR line (a warning must mean something an operator
//! should look at). With `[simulator.faults]` on, the warnings are still there: the quiet is not a muted log.

use std::path::{Path, PathBuf};
use std::process::Output;

use gonio_testkit::{gonio, text};

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../..")
}

/// `gonio run CAMPAIGN --out OUT [--instrument FILE]` as a user types it: no `--quiet`, no RUST_LOG (the
/// binary's default filter, warnings and errors), from the repository root.
fn run_as_a_user(campaign: &Path, out: &Path, instrument: Option<&Path>) -> Output {
    let mut c = gonio();
    c.current_dir(repo())
        .arg("run")
        .arg(campaign)
        .arg("--out")
        .arg(out);
    if let Some(file) = instrument {
        c.arg("--instrument").arg(file);
    }
    c.env_remove("RUST_LOG").output().expect("start gonio run")
}

/// The lines of stdout and stderr that a tracing WARN or ERROR event printed (terminal colour codes, were
/// there any, taken out first: the level is matched as a word).
fn alarms(o: &Output) -> Vec<String> {
    let all = format!("{}\n{}", text(&o.stdout), text(&o.stderr));
    all.lines()
        .map(strip_ansi)
        .filter(|l| l.split_whitespace().any(|w| w == "WARN" || w == "ERROR"))
        .collect()
}

/// `line` without ANSI escape sequences (`ESC [ ... letter`).
fn strip_ansi(line: &str) -> String {
    let mut out = String::with_capacity(line.len());
    let mut chars = line.chars();
    while let Some(c) = chars.next() {
        if c == '\u{1b}' {
            // Skip to the sequence's final letter.
            for d in chars.by_ref() {
                if d.is_ascii_alphabetic() {
                    break;
                }
            }
        } else {
            out.push(c);
        }
    }
    out
}

#[test]
fn the_readme_demo_on_the_ideal_instrument_prints_no_warning_or_error() {
    let dir = tempfile::tempdir().expect("tempdir");
    let out = dir.path().join("demo");
    let o = run_as_a_user(Path::new("config/campaigns/demo.toml"), &out, None);
    assert!(o.status.success(), "the demo failed: {}", text(&o.stderr));
    assert!(out.join("points.csv").is_file(), "the demo wrote its points");
    let alarms = alarms(&o);
    assert!(alarms.is_empty(), "the first run warned:\n{}", alarms.join("\n"));
}

#[test]
fn with_faults_on_the_warnings_remain() {
    let dir = tempfile::tempdir().expect("tempdir");
    let ideal = std::fs::read_to_string(repo().join("config/instruments/simulated.toml"))
        .expect("read simulated.toml");
    // Dropped replies on every serial line: retries an operator should see.
    let faulty = ideal.replace(
        "[simulator.faults]\n",
        "[simulator.faults]\nseed = 7\ndrop_rate = 0.05\n",
    );
    assert_ne!(
        faulty, ideal,
        "simulated.toml has a [simulator.faults] table to fill"
    );
    let instrument = dir.path().join("faulty.toml");
    std::fs::write(&instrument, faulty).expect("write the instrument file");
    let campaign = dir.path().join("small.toml");
    std::fs::write(
        &campaign,
        gonio_testkit::CampaignText::in_plane("faulty-first-run", 12).to_string(),
    )
    .expect("write the campaign");
    let o = run_as_a_user(&campaign, &dir.path().join("out"), Some(&instrument));
    let alarms = alarms(&o);
    assert!(
        alarms.iter().any(|l| l.contains(" WARN ")),
        "dropped replies left no warning (exit {:?}):\n{}",
        o.status.code(),
        text(&o.stderr)
    );
}
