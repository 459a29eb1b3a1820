//! `gonio selftest` through the binary on the simulated instrument: it passes on the ideal instrument, and on
//! hardware slower than its file (`[simulator.actual]`) exits 1 naming the key; `--json` writes the report and
//! `--write` an instrument file that loads, with the measured value.

use gonio_instrument::{InstrumentFile, SIMULATED_INSTRUMENT_TOML};
use gonio_testkit::{gonio, text};
use serde_json::Value;

#[test]
fn selftest_passes_on_the_ideal_instrument_and_names_what_the_hardware_contradicts() {
    let out = gonio().arg("selftest").output().expect("run gonio selftest");
    assert!(
        out.status.success(),
        "{} {}",
        text(&out.stdout),
        text(&out.stderr)
    );
    let report = text(&out.stdout);
    assert!(
        report.contains("axes.detector.max_speed_deg_s") && report.contains(" ok"),
        "{report}"
    );

    let dir = tempfile::tempdir().expect("tempdir");
    let slow = dir.path().join("slow.toml");
    std::fs::write(
        &slow,
        format!("{SIMULATED_INSTRUMENT_TOML}\n[simulator.actual.filter_wheel]\nseconds_per_position = 2.0\n"),
    )
    .expect("write");
    let (json, written) = (dir.path().join("report.json"), dir.path().join("measured.toml"));
    let out = gonio()
        .args(["selftest", "--instrument"])
        .arg(&slow)
        .arg("--json")
        .arg(&json)
        .arg("--write")
        .arg(&written)
        .output()
        .expect("run gonio selftest");
    assert_eq!(
        out.status.code(),
        Some(1),
        "{} {}",
        text(&out.stdout),
        text(&out.stderr)
    );
    let err = text(&out.stderr);
    assert!(err.contains("filter_wheel.seconds_per_position"), "{err}");
    assert!(!err.contains("max_speed_deg_s"), "only the wheel differs: {err}");

    let report: Value = serde_json::from_str(&std::fs::read_to_string(&json).expect("json")).expect("JSON");
    let line = report["checks"]
        .as_array()
        .and_then(|c| c.iter().find(|c| c["key"] == "filter_wheel.seconds_per_position"))
        .expect("the wheel's line");
    assert_eq!(line["verdict"], "fail");
    let measured = line["measured"].as_f64().expect("measured");
    assert!((measured - 2.0).abs() < 0.02, "{measured}");

    let file = InstrumentFile::load(&written).expect("the written file loads");
    let sps = file
        .instrument
        .filter_wheel
        .as_ref()
        .map(|w| w.seconds_per_position)
        .expect("wheel");
    assert!((sps - measured).abs() < 1e-9, "{sps}");
    // The settle times and backlash measured are written too, none below zero (the tilt has no play: its
    // measured backlash is zero give or take the measurement's noise).
    let tilt = file
        .instrument
        .axes
        .iter()
        .find(|a| a.name == "tilt")
        .expect("tilt");
    let report_line = |key: &str| {
        report["checks"]
            .as_array()
            .and_then(|c| c.iter().find(|c| c["key"] == key))
            .and_then(|c| c["measured"].as_f64())
            .expect("the line")
    };
    assert_eq!(tilt.backlash_deg, report_line("axes.tilt.backlash_deg").max(0.0));
    assert_eq!(tilt.settle_s, report_line("axes.tilt.settle_s").max(0.0));
    // The noise figures measured are written too: the dark (with whatever ambient light reaches the head) and
    // the source's white relative noise, each as the report has it.
    assert_eq!(
        file.instrument.detector.dark_current_a,
        report_line("detector.dark_current_a")
    );
    assert_eq!(
        file.instrument.source.relative_noise,
        report_line("source.relative_noise")
    );
    // When the arms' controller takes its reported positions (the simulator's: as the query is sent), as
    // measured (a hair either side of zero).
    let arms = file.instrument.device("arms").expect("arms");
    assert_eq!(
        arms.position_sampled_ms,
        Some(report_line("devices.arms.position_sampled_ms"))
    );
    assert!(
        arms.position_sampled_ms.is_some_and(|ms| ms.abs() < 0.3),
        "{arms:?}"
    );
    assert!(
        std::fs::read_to_string(&written)
            .expect("text")
            .starts_with("# Written by gonio selftest")
    );
}

#[test]
fn a_settle_time_four_times_the_claim_or_more_backlash_fails_naming_the_key() {
    let dir = tempfile::tempdir().expect("tempdir");
    for (extra, key) in [
        (
            "[simulator.actual.axes.light]\nsettle_s = 0.2\n",
            "axes.light.settle_s",
        ),
        (
            "[simulator.actual.axes.detector]\nbacklash_deg = 0.03\n",
            "axes.detector.backlash_deg",
        ),
    ] {
        let path = dir.path().join("actual.toml");
        std::fs::write(&path, format!("{SIMULATED_INSTRUMENT_TOML}\n{extra}")).expect("write");
        let out = gonio()
            .args(["selftest", "--instrument"])
            .arg(&path)
            .output()
            .expect("run gonio selftest");
        let (report, err) = (text(&out.stdout), text(&out.stderr));
        assert_eq!(out.status.code(), Some(1), "{extra}: {report} {err}");
        assert!(err.contains(key), "{extra}: {err}");
        assert!(
            !err.contains("max_speed_deg_s") && !err.contains("seconds_per_position"),
            "{extra}: only {key} differs: {err}"
        );
        let line = report
            .lines()
            .find(|l| l.trim_start().starts_with(key))
            .unwrap_or_else(|| panic!("{key} in {report}"));
        assert!(line.ends_with("FAIL"), "{line}");
        // The simulated operator's steps are said.
        assert!(
            err.contains("simulated operator: remove everything")
                && err.contains("simulated operator: mount"),
            "{err}"
        );
    }
}
