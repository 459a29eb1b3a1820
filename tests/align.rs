//! `gonio align` through the binary on the simulated instruments, with standard input closed (the simulated
//! operator does the operator's steps): it completes, prints a line per value, and writes a calibration file that
//! names the instrument and its SHA-256 and gives every value with its standard uncertainty; the JSON report
//! has every scan. A sample with no mirror reflection in place of the mirror is refused with the scan that failed.

use std::process::Stdio;

use gonio_testkit::{gonio, text};
use serde_json::Value;

#[test]
fn align_writes_a_calibration_that_names_its_instrument() {
    let dir = tempfile::tempdir().expect("tempdir");
    let (cal, json) = (dir.path().join("cal.toml"), dir.path().join("report.json"));
    let instrument = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../config/instruments/realistic.toml"
    );
    let out = gonio()
        .args(["align", "--instrument", instrument, "--out"])
        .arg(&cal)
        .arg("--json")
        .arg(&json)
        .stdin(Stdio::null())
        .output()
        .expect("run gonio align");
    assert!(
        out.status.success(),
        "{} {}",
        text(&out.stdout),
        text(&out.stderr)
    );
    let printed = text(&out.stdout);
    assert!(
        printed.contains("tilt_zero_deg") && printed.contains("not observable"),
        "{printed}"
    );

    let written: toml::Value = toml::from_str(&std::fs::read_to_string(&cal).expect("read")).expect("toml");
    let header = &written["calibration"];
    assert_eq!(header["instrument"].as_str(), Some("realistic"));
    let text_of_file = std::fs::read(instrument).expect("instrument");
    assert_eq!(
        header["instrument_sha256"].as_str(),
        Some(gonio_results::provenance_summary::sha256_hex(&text_of_file).as_str())
    );
    let values = written["values"].as_array().expect("values");
    let tilt = values
        .iter()
        .find(|v| v["name"].as_str() == Some("sample_tilt_x_deg"))
        .expect("sample tilt");
    assert!(tilt["u"].as_float().expect("u") > 0.0 && tilt["u"].as_float().expect("u") < 0.005);

    let report: Value = serde_json::from_str(&std::fs::read_to_string(&json).expect("json")).expect("parse");
    assert!(report["scans"].as_array().expect("scans").len() >= 10, "{report}");

    let out = gonio()
        .args([
            "align",
            "--material",
            "spectralon",
            "--instrument",
            instrument,
            "--out",
        ])
        .arg(dir.path().join("no.toml"))
        .stdin(Stdio::null())
        .output()
        .expect("run gonio align");
    assert!(!out.status.success());
    assert!(
        text(&out.stderr).contains("mirror, detector scan"),
        "{}",
        text(&out.stderr)
    );
    assert!(
        !dir.path().join("no.toml").exists(),
        "a refused alignment writes nothing"
    );
}
