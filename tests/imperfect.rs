//! The realistic simulated instrument end to end (config/instruments/realistic.toml): a dry-run on it completes,
//! its run.json carries the instrument's hidden imperfections under `simulator_truth` (drawn from the file's
//! seed, the same on every run), and the ideal instrument's run.json has no such key. The relative method runs
//! too (its reference swaps re-seat the sample).

use std::path::{Path, PathBuf};

use gonio_testkit::cli::quiet_run;
use gonio_testkit::{CampaignText, text};

fn realistic() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config/instruments/realistic.toml")
}

/// Runs `campaign` (on `instrument`, or the embedded ideal one) into `dir/<id>` and returns run.json.
fn run(dir: &Path, id: &str, campaign: &str, instrument: Option<&Path>) -> serde_json::Value {
    let file = dir.join(format!("{id}.toml"));
    std::fs::write(&file, campaign).expect("write the campaign");
    let out = dir.join(id);
    let mut cmd = quiet_run(&file, &out);
    if let Some(i) = instrument {
        cmd.arg("--instrument").arg(i);
    }
    let o = cmd.output().expect("start gonio run");
    assert!(o.status.success(), "gonio run {id} failed: {}", text(&o.stderr));
    let json = std::fs::read_to_string(out.join("run.json")).expect("run.json");
    serde_json::from_str(&json).expect("run.json is JSON")
}

#[test]
fn a_realistic_dry_run_records_the_hidden_truth_and_an_ideal_one_does_not() {
    let dir = tempfile::tempdir().expect("tempdir");
    let campaign = CampaignText::in_plane("imperfect", 6).to_string();
    let real = run(dir.path(), "real", &campaign, Some(&realistic()));
    let again = run(dir.path(), "again", &campaign, Some(&realistic()));
    let ideal = run(dir.path(), "ideal", &campaign, None);

    assert_eq!(real["campaign"]["state"], "completed");
    assert_eq!(real["campaign"]["valid_points"], real["campaign"]["total_points"]);
    let truth = &real["simulator_truth"];
    assert_eq!(truth["seed"], 16, "realistic.toml's seed");
    let g = &truth["geometry"];
    let axes = g["axes"].as_array().expect("axes");
    assert_eq!(axes.len(), 4);
    for a in axes {
        assert!(
            a["zero_offset_deg"]
                .as_f64()
                .is_some_and(|v| v != 0.0 && v.abs() < 0.2),
            "{a}"
        );
        assert_eq!(a["encoder_amplitude_deg"], 0.005);
    }
    for key in [
        "sample_tilt_x_deg",
        "sample_tilt_y_deg",
        "eccentricity_x_mm",
        "eccentricity_y_mm",
    ] {
        assert!(g[key].as_f64().is_some_and(|v| v != 0.0), "{key}: {g}");
    }
    assert!(!g["seatings"].as_array().expect("seatings").is_empty());
    assert_eq!(
        truth, &again["simulator_truth"],
        "the seed fixes the hidden values"
    );

    assert!(
        ideal.get("simulator_truth").is_none(),
        "the ideal instrument has no hidden values"
    );
    // The imperfections are felt: the realistic run is further from the ground truth than the ideal one.
    let err = |j: &serde_json::Value| {
        j["truth"]["against_aperture_average"]["cos_weighted_relative_rms"]
            .as_f64()
            .expect("truth errors")
    };
    assert!(
        err(&real) > 2.0 * err(&ideal),
        "{} vs {}",
        err(&real),
        err(&ideal)
    );
}

#[test]
fn the_relative_method_runs_on_the_realistic_instrument() {
    // config/campaigns/relative.toml as shipped: the reference swaps take the sample out and put it back.
    let dir = tempfile::tempdir().expect("tempdir");
    let campaign = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config/campaigns/relative.toml");
    let out = dir.path().join("relative");
    let o = quiet_run(&campaign, &out)
        .arg("--instrument")
        .arg(realistic())
        .output()
        .expect("start gonio run");
    assert!(o.status.success(), "gonio run failed: {}", text(&o.stderr));
    let j: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("run.json")).expect("run.json"))
            .expect("JSON");
    assert_eq!(j["campaign"]["state"], "completed");
    assert_eq!(j["campaign"]["valid_points"], j["campaign"]["total_points"]);
    assert!(
        j["simulator_truth"]["geometry"]["seatings"]
            .as_array()
            .is_some_and(|s| s.len() > 1)
    );
}
