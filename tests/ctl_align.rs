//! `gonio ctl align` and `gonio ctl calibrations` against a running `gonio daemon` on the realistic simulated
//! instrument: the alignment followed to its end with its calibration summarised, kept in the daemon's store as
//! the current calibration, fetched as the file `gonio align` writes, and given to the campaign submitted next.

use gonio_engine::align::file::CalibrationFile;
use gonio_testkit::daemon::{Daemon, ctl, start_daemon_on};
use gonio_testkit::text;

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
