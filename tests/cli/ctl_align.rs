//! `gonio ctl align` and `gonio ctl calibrations` against a running `gonio daemon` on the realistic simulated
//! instrument: the alignment followed to its end with its calibration summarised, kept in the daemon's store as
//! the current calibration, fetched as the file `gonio align` writes, and given to the campaign submitted next;
//! and on the real-hardware path (a separate `gonio sim`, every device opened by path), each operator step
//! waiting for its confirmation (`gonio ctl align --confirm`) while the operator works on the simulator.

use std::io::{BufRead, BufReader};
use std::process::Stdio;
use std::time::Duration;

use gonio_engine::align::file::CalibrationFile;
use gonio_testkit::daemon::{Daemon, ctl, start_daemon_on};
use gonio_testkit::sim::start_sim_links;
use gonio_testkit::{gonio, text};

fn ok(daemon: &Daemon, args: &[&str]) -> String {
    let out = ctl(daemon, args, &[]);
    assert!(
        out.status.success(),
        "gonio ctl {args:?}: {} {}",
        text(&out.stdout),
        text(&out.stderr)
    );
    text(&out.stdout)
}

#[test]
fn ctl_aligns_through_the_daemon_and_lists_its_calibrations() {
    let dir = tempfile::tempdir().expect("tempdir");
    let instrument = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../config/instruments/realistic.toml"
    );
    let instrument_text = std::fs::read_to_string(instrument).expect("realistic.toml");
    // 200 simulated seconds a second: the alignment's minutes of instrument time take a few seconds.
    let daemon = start_daemon_on(
        &dir.path().join("data"),
        "200",
        &[],
        Some(std::path::Path::new(instrument)),
    );
    assert_eq!(ok(&daemon, &["calibrations"]).trim(), "no calibrations");
    let refused = ctl(&daemon, &["align", "--confirm"], &[]);
    assert!(!refused.status.success());
    assert!(
        text(&refused.stderr).contains("not waiting for the operator"),
        "{}",
        text(&refused.stderr)
    );

    let out = ok(&daemon, &["align"]);
    assert!(out.contains("alignment started (dry-run"), "{out}");
    assert!(
        out.contains("alignment: scans through the mirror's reflection"),
        "{out}"
    );
    assert!(out.contains("calibration 1 of"), "{out}");
    let value_lines = out.lines().filter(|l| l.contains(" +- ")).count();
    assert!(value_lines >= 10, "{out}");
    assert!(out.contains("detector_zero_deg"), "{out}");

    let list = ok(&daemon, &["calibrations"]);
    let lines: Vec<&str> = list.lines().collect();
    assert_eq!(lines.len(), 1, "{list}");
    assert!(
        lines[0].trim_start().starts_with("1 ")
            && lines[0].contains("current")
            && lines[0].contains("alignment by the daemon"),
        "{list}"
    );
    // The stored file is `gonio align`'s format, made for this instrument file, with every value of the summary.
    let file = ok(&daemon, &["calibrations", "1"]);
    let cal = CalibrationFile::parse(&file, "calibration 1").expect("a calibration file");
    cal.check_instrument(&instrument_text, "calibration 1")
        .expect("made for the daemon's instrument file");
    assert_eq!(cal.values.len(), value_lines, "{out}");
    assert!(ok(&daemon, &["align", "--status"]).contains("alignment: completed; step: done; calibration 1"));

    // The campaign submitted next is given it.
    let demo = concat!(env!("CARGO_MANIFEST_DIR"), "/../../config/campaigns/demo.toml");
    ok(&daemon, &["submit", demo]);
    let status = ok(&daemon, &["status", "1"]);
    assert!(status.contains("calibration 1 applied"), "{status}");
    ok(&daemon, &["abort", "1"]);
}

/// The real-hardware path end to end: each of `gonio ctl align`'s operator prompts read from its output, done on
/// the simulator and confirmed with `gonio ctl align --confirm`, as a person at the instrument does.
#[test]
#[ignore = "about 3 minutes: on the hardware path the daemon waits in real time; \
            cargo test -p gonio --test cli ctl_align -- --ignored"]
fn on_the_hardware_path_each_operator_step_waits_for_its_confirmation() {
    let dir = tempfile::tempdir().expect("tempdir");
    // The mirror is the simulator's sample: the operator takes it out and puts it back on its stdin.
    let mut sim = start_sim_links(&dir.path().join("ports"), "mirror", "50");
    let instrument = dir.path().join("lab.toml");
    std::fs::write(
        &instrument,
        sim.instrument_text(gonio_instrument::SIMULATED_INSTRUMENT_TOML),
    )
    .expect("write instrument");
    let daemon = start_daemon_on(&dir.path().join("data"), "50", &[], Some(&instrument));
    let mut align = gonio()
        .args(["ctl", "--url", &daemon.url, "align"])
        .env_remove("GONIO_TOKEN")
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("start gonio ctl align");
    // Its output line by line, each within a deadline.
    let (tx, lines) = std::sync::mpsc::channel();
    let stdout = align.stdout.take().expect("stdout");
    std::thread::spawn(move || {
        for line in BufReader::new(stdout).lines().map_while(Result::ok) {
            if tx.send(line).is_err() {
                break;
            }
        }
    });
    let mut out = Vec::new();
    let mut done = Vec::new();
    while let Ok(line) = lines.recv_timeout(Duration::from_secs(600)) {
        out.push(line.clone());
        let Some(prompt) = line.strip_prefix("operator: ") else {
            continue;
        };
        let command = if prompt.contains("remove everything") {
            "sample out"
        } else if prompt.contains("mount the alignment mirror") {
            "sample in"
        } else {
            panic!("unexpected operator prompt {prompt:?}");
        };
        assert_eq!(
            sim.operator(command),
            format!("{{\"sample_mounted\":{}}}", command == "sample in")
        );
        ok(&daemon, &["align", "--confirm"]);
        done.push(command);
    }
    let status = align.wait().expect("wait");
    let out = out.join("\n");
    assert!(status.success(), "{out}");
    assert_eq!(done, ["sample out", "sample in"], "{out}");
    assert!(out.starts_with("alignment started\n"), "not a dry-run: {out}");
    assert!(out.contains("calibration 1 of"), "{out}");
    let cal =
        CalibrationFile::parse(&ok(&daemon, &["calibrations", "1"]), "calibration 1").expect("calibration");
    assert!(!cal.calibration.dry_run, "made on the hardware path");
    assert!(ok(&daemon, &["calibrations"]).contains("current"));
}
