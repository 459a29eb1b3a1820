//! `gonio brdf check` end to end: the real binary on a good preset (exit 0), on a material that violates
//! energy conservation (exit 1, report printed), and on bad input (exit 2).
//!
//! The material loader refuses analytic materials that break the laws (e.g. Phong with diffuse + specular > 1),
//! so the violating material is a measured one: a MERL table whose constant value 3/pi 1/sr gives an albedo of 3.

use std::f64::consts::PI;

use gonio_brdf::merl::{CELLS, MerlData};
use gonio_testkit::gonio;

#[test]
fn a_good_preset_passes() {
    let out = gonio()
        .args(["brdf", "check", "--material", "spectralon"])
        .output()
        .expect("run gonio");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert_eq!(
        out.status.code(),
        Some(0),
        "stdout:\n{stdout}\nstderr:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    assert!(stdout.contains("result: PASS"), "{stdout}");
    // The report names the maximum albedo (0.99 for the reference white) and where.
    assert!(stdout.contains("max directional albedo 0.99"), "{stdout}");
    assert!(
        stdout.contains("reciprocity") && stdout.contains("non-finite"),
        "{stdout}"
    );
}

#[test]
fn an_energy_violating_material_fails_with_exit_1() {
    let dir = tempfile::tempdir().expect("temp dir");
    // Stored value s gives f = s / 1500 (red): f = 3 / pi.
    let stored = vec![3.0 / PI * 1500.0; CELLS];
    MerlData::from_stored(stored.clone(), stored.clone(), stored)
        .expect("valid table")
        .write(&dir.path().join("bright.binary"))
        .expect("write MERL");
    let material = dir.path().join("bright.toml");
    std::fs::write(
        &material,
        "[material]\nmodel = \"measured\"\nfile = \"bright.binary\"\nformat = \"merl\"\nchannel = \"red\"\n",
    )
    .expect("write material");
    let out = gonio()
        .args(["brdf", "check", "--material"])
        .arg(&material)
        .output()
        .expect("run gonio");
    let stdout = String::from_utf8_lossy(&out.stdout);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(1), "stdout:\n{stdout}\nstderr:\n{stderr}");
    assert!(stdout.contains("result: FAIL"), "{stdout}");
    assert!(stdout.contains("energy: directional albedo 3.0"), "{stdout}");
    assert!(!stderr.contains("panicked"), "{stderr}");
}

#[test]
fn bad_input_is_exit_2_with_a_message() {
    let out = gonio()
        .args(["brdf", "check", "--material", "no-such-preset"])
        .output()
        .expect("run gonio");
    assert_eq!(out.status.code(), Some(2));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(
        stderr.contains("no-such-preset") && !stderr.contains("panicked"),
        "{stderr}"
    );
    let out = gonio()
        .args(["brdf", "check", "--material", "spectralon", "--wavelength=0"])
        .output()
        .expect("run gonio");
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("--wavelength"));
}
