//! `gonio plan` end to end: the real binary on the demo campaign and on a small campaign written here.

use gonio_testkit::gonio;
use std::path::PathBuf;

fn repo_root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..")
}

fn number_after(text: &str, label: &str) -> usize {
    let line = text
        .lines()
        .find(|l| l.starts_with(label))
        .unwrap_or_else(|| panic!("no line {label:?} in\n{text}"));
    line[label.len()..]
        .split_whitespace()
        .next()
        .and_then(|w| w.parse().ok())
        .unwrap_or_else(|| panic!("{line}"))
}

#[test]
fn plan_demo_prints_a_summary_and_writes_the_csv() {
    let dir = tempfile::tempdir().expect("temp dir");
    let csv = dir.path().join("points.csv");
    let out = gonio()
        .arg("plan")
        .arg(repo_root().join("config/campaigns/plan-demo.toml"))
        .arg("--points")
        .arg(&csv)
        .output()
        .expect("run gonio");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(
        out.status.success(),
        "stderr: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    for needle in [
        "points kept:",
        "points skipped:",
        "reciprocity",
        "predicted duration:",
        "raster order:",
        "lower bound:",
        "motion",
        "settle",
        "filter wheel",
        "integration",
        "calibration steps",
    ] {
        assert!(stdout.contains(needle), "missing {needle:?} in\n{stdout}");
    }
    let kept = number_after(&stdout, "points kept:");
    let requested = number_after(&stdout, "points requested:");
    let skipped = number_after(&stdout, "points skipped:");
    assert_eq!(kept + skipped, requested, "{stdout}");
    let text = std::fs::read_to_string(&csv).expect("csv written");
    let mut lines = text.lines();
    assert_eq!(
        lines.next(),
        Some(
            "index,band_nm,theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,light_deg,detector_deg,tilt_deg,rotation_deg,move_s"
        )
    );
    let rows: Vec<&str> = lines.collect();
    assert_eq!(rows.len(), kept);
    for (i, row) in rows.iter().enumerate() {
        let cols: Vec<&str> = row.split(',').collect();
        assert_eq!(cols.len(), 11, "{row}");
        assert_eq!(cols[0], i.to_string());
        assert!(["450", "550", "650"].contains(&cols[1]), "{row}");
        // Gold is isotropic: the sample rotation never moves.
        assert_eq!(cols[9].parse::<f64>().expect("rotation"), 0.0, "{row}");
        assert!(cols[10].parse::<f64>().expect("move_s") >= 0.0);
    }
}

#[test]
fn plan_errors_name_the_key_and_exit_2() {
    let dir = tempfile::tempdir().expect("temp dir");
    let path = dir.path().join("bad.toml");
    std::fs::write(
        &path,
        "[campaign]\nid = \"bad\"\n[plan]\nbands_nm = [451.0]\n[plan.grid]\nkind = \"in-plane\"\ntheta_i_deg = [30.0]\ntheta_o_deg = [20.0]\n",
    )
    .expect("write");
    let out = gonio().arg("plan").arg(&path).output().expect("run gonio");
    assert_eq!(out.status.code(), Some(2));
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(stderr.contains("bands_nm") && stderr.contains("451"), "{stderr}");
}
