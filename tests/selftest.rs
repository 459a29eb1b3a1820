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
        .map(|w| w.seconds_per_position)
        .expect("wheel");
    assert!((sps - measured).abs() < 1e-9, "{sps}");
    assert!(
        std::fs::read_to_string(&written)
            .expect("text")
            .starts_with("# Written by gonio selftest")
    );
}
