//! The relative calibration method end to end on the simulated instrument (tokio's paused clock): a campaign
//! normalised by a reference sample read at the reference geometry reproduces the simulator's ground truth; the
//! operator is asked to swap the reference in and out (and the simulated holder changes on each confirmation);
//! the reference is read again during the run; and bad references are refused with file, line and key.

use std::sync::{Arc, Mutex};

use gonio_brdf::{Direction, Wavelength};
use gonio_engine::store::{CampaignState, Store};
use gonio_engine::{Control, Event, Rig, prepare_campaign, run_campaign};
use gonio_instrument::{InstrumentFile, SIMULATED_INSTRUMENT_TOML};
use gonio_results::provenance::{against_aperture_truth, truth_errors};

/// The reference sample's material file, written next to the campaign (config/materials/spectralon.toml).
const WHITE: &str = r#"
[material]
model = "lambertian"
albedo = { 400 = 0.980, 450 = 0.988, 500 = 0.990, 550 = 0.990, 600 = 0.990, 650 = 0.989, 700 = 0.987 }
"#;

const CAMPAIGN: &str = r#"[campaign]
id = "relative-test"

[sample]
radius_mm = 12.5

[plan]
bands_nm = [450.0, 650.0]
reciprocity = false

[plan.grid]
kind = "in-plane"
theta_i_deg = [20.0, 40.0]
theta_o_deg = { from = -60.0, to = 60.0, step = 20.0 }

[plan.calibration]
dark_every_points = 1000
reference_every_points = 10

[calibration]
method = "relative"
reference = "standards/white.toml"
reference_rel_std = 0.0
simulate_operator = false

[acquisition]
averaging = 4

[material]
preset = "coloured-plastic"
"#;

fn write(dir: &std::path::Path, name: &str, text: &str) -> std::path::PathBuf {
    let p = dir.join(name);
    if let Some(parent) = p.parent() {
        std::fs::create_dir_all(parent).expect("mkdir");
    }
    std::fs::write(&p, text).expect("write");
    p
}

/// f of the mounted simulated sample at the 0/45 reference geometry, 550 nm: tells which sample is in the holder.
fn mounted_f_0_45(rig: &Rig) -> f64 {
    let wi = Direction::from_spherical_deg(0.0, 0.0);
    let wo = Direction::from_spherical_deg(45.0, 180.0);
    rig.optics()
        .expect("dry-run optics")
        .truth(&wi, &wo, Wavelength::from_nm(550.0).expect("wl"))
        .expect("truth")
}

#[tokio::test(start_paused = true)]
async fn relative_dry_run_reproduces_ground_truth_with_operator_swaps() {
    tokio::time::timeout(std::time::Duration::from_secs(24 * 3600), relative_run())
        .await
        .expect("no hang");
}

async fn relative_run() {
    let file = InstrumentFile::simulated();
    let campaign_dir = tempfile::tempdir().expect("tempdir");
    write(campaign_dir.path(), "standards/white.toml", WHITE);
    let prepared = prepare_campaign(CAMPAIGN, "relative.toml", campaign_dir.path(), &file).expect("valid");
    let data = tempfile::tempdir().expect("tempdir");
    let mut store = Store::open(data.path()).expect("store");
    let id = store
        .create_campaign(&prepared.new_campaign(CAMPAIGN, SIMULATED_INSTRUMENT_TOML))
        .expect("create");
    let store = Arc::new(Mutex::new(store));
    let rig = Rig::connect_with_time_scale(&file, None, 1.0).await.expect("rig");
    let control = Control::new();
    let mut rx = control.subscribe();
    let mut task = {
        let (store, rig, control) = (Arc::clone(&store), rig.clone(), control.clone());
        tokio::spawn(async move { run_campaign(store, id, &rig, control).await })
    };

    let white_f = 0.990 / std::f64::consts::PI;
    let mut sample_f = None;
    let (mut swaps_in, mut swaps_out) = (0, 0);
    // What the last prompt asked for, checked at the `running` that follows its confirmation.
    let mut expect_after_confirm: Option<&str> = None;
    let state = loop {
        tokio::select! {
            joined = &mut task => break joined.expect("join").expect("run"),
            event = rx.recv() => {
                let Ok(Event::State { state, message, .. }) = event else { continue };
                match state {
                    CampaignState::WaitingOperator => {
                        let message = message.unwrap_or_default();
                        let now = mounted_f_0_45(&rig);
                        if message.contains("mount the reference sample") {
                            assert!(message.contains("standards/white.toml"), "{message}");
                            // Nothing changes before the confirmation: the campaign's sample is in.
                            let s = *sample_f.get_or_insert(now);
                            assert_eq!(now, s);
                            assert!((s - white_f).abs() > 0.05 * white_f, "the sample must differ from the reference");
                            swaps_in += 1;
                            expect_after_confirm = Some("reference");
                        } else if message.contains("mount the sample again") {
                            assert!((now - white_f).abs() < 1e-12, "the reference is still in: {now}");
                            swaps_out += 1;
                            expect_after_confirm = Some("sample");
                        } else {
                            panic!("unexpected operator prompt: {message}");
                        }
                        control.confirm();
                    }
                    CampaignState::Running => {
                        match expect_after_confirm.take() {
                            Some("reference") => assert!((mounted_f_0_45(&rig) - white_f).abs() < 1e-12,
                                "the simulated holder must hold the reference after the confirmation"),
                            Some(_) => assert_eq!(Some(mounted_f_0_45(&rig)), sample_f),
                            None => {}
                        }
                    }
                    _ => {}
                }
            }
        }
    };
    assert_eq!(state, CampaignState::Completed);
    assert_eq!(swaps_in, swaps_out);

    let s = store.lock().expect("lock");
    let points = s.points(id).expect("points");
    assert_eq!(points.len() as u64, prepared.total_points);
    let cals = s.calibrations(id).expect("calibrations");
    assert!(
        cals.iter().all(|c| c.kind == "reference" || c.kind == "dark"),
        "{cals:?}"
    );
    let references = cals.iter().filter(|c| c.kind == "reference").count();
    // One session per start plus the plan's every 10 points; each reads both bands.
    assert_eq!(references, 2 * swaps_in);
    assert!(
        swaps_in > (prepared.total_points as usize - 1) / 10,
        "{swaps_in} reference sessions for {} points",
        prepared.total_points
    );

    let valid: Vec<_> = points.iter().filter(|p| p.flags.is_empty()).collect();
    assert!(valid.len() >= 16, "{} valid points", valid.len());
    for p in &valid {
        // The aperture average, before the completed campaign's correction to the nominal geometry.
        let f = p.brdf_aperture_sr.or(p.brdf_sr).expect("value");
        let u = p.brdf_u_sr.expect("uncertainty");
        let t = p.truth_aperture_sr.expect("truth");
        // The reference's known f is its point value, its reading an aperture average: for a Lambertian
        // reference the result is the sample's aperture average times 2 / (1 + cos beta), beta the aperture's
        // half-angle (atan(2.5 / 250)): 2.5e-5 relative.
        let beta = (2.5f64 / 250.0).atan();
        let expected = t * 2.0 / (1.0 + beta.cos());
        assert!(
            (f - expected).abs() <= 4.0 * u,
            "point {} ({} nm, {}/{}): {f} vs {expected} (u {u})",
            p.index,
            p.band_nm,
            p.theta_i_deg,
            p.theta_o_deg
        );
        // The uncertainty stays small, so that the comparison above means something.
        assert!(u < 1e-2 * f.abs(), "point {}: u {u} for {f}", p.index);
        assert!(
            p.incident_w > 0.0,
            "the net reference signal is stored as the normalisation"
        );
    }
    let record = s.campaign(id).expect("campaign");
    let table = gonio_engine::export::points_table(&record, &points);
    let errors = truth_errors(&table.points, against_aperture_truth).expect("errors");
    eprintln!("relative dry-run against truth: {errors:?}");
    assert!(
        errors.cos_weighted_relative_rms.is_some_and(|e| e < 5e-4),
        "{errors:?}"
    );
}

/// A campaign text with `[calibration]` replaced.
fn with_calibration(calibration: &str) -> String {
    let start = CAMPAIGN.find("[calibration]").expect("table");
    let end = CAMPAIGN.find("[acquisition]").expect("table");
    format!("{}{calibration}\n\n{}", &CAMPAIGN[..start], &CAMPAIGN[end..])
}

/// The 1-based line of `needle` in `text`.
fn line(text: &str, needle: &str) -> usize {
    text.lines().position(|l| l.contains(needle)).expect("needle") + 1
}

#[test]
fn bad_references_are_refused_with_file_line_and_key() {
    let file = InstrumentFile::simulated();
    let dir = tempfile::tempdir().expect("tempdir");
    write(
        dir.path(),
        "standards/bad.toml",
        "[material]\nmodel = \"lambertian\"\nalbedo = 1.5\n",
    );
    let refuse = |calibration: &str| {
        let text = with_calibration(calibration);
        let e = prepare_campaign(&text, "c.toml", dir.path(), &file)
            .expect_err(calibration)
            .to_string();
        (text, e)
    };

    let (text, e) = refuse("[calibration]\nmethod = \"relative\"\nreference = \"no-such-white\"");
    let at = format!("c.toml:{}: [calibration] reference:", line(&text, "reference ="));
    assert!(e.starts_with(&at) && e.contains("spectralon"), "{e}");

    let (text, e) = refuse("[calibration]\nmethod = \"relative\"\nreference = \"standards/bad.toml\"");
    assert!(
        e.starts_with(&format!(
            "c.toml:{}: [calibration] reference:",
            line(&text, "reference =")
        )),
        "{e}"
    );
    // ... and the material error inside names the reference file, its line and key.
    assert!(e.contains("bad.toml, line 3") && e.contains("albedo"), "{e}");

    let (text, e) = refuse("[calibration]\nmethod = \"relative\"\nreference = \"standards/missing.toml\"");
    assert!(
        e.starts_with(&format!(
            "c.toml:{}: [calibration] reference:",
            line(&text, "reference =")
        )),
        "{e}"
    );

    let (text, e) = refuse("[calibration]\nmethod = \"relative\"");
    assert!(
        e.starts_with(&format!(
            "c.toml:{}: [calibration] method:",
            line(&text, "method =")
        )),
        "{e}"
    );

    // A mirror has no diffuse reflection at 0/45: it cannot normalise there.
    let (_, e) = refuse("[calibration]\nmethod = \"relative\"\nreference = \"mirror\"");
    assert!(
        e.contains("[calibration] reference:") && e.contains("must reflect"),
        "{e}"
    );

    // A reference geometry beyond the grazing limit, and a malformed one.
    let (text, e) = refuse(
        "[calibration]\nmethod = \"relative\"\nreference = \"spectralon\"\nreference_geometry_deg = [0.0, 0.0, 88.0, 180.0]",
    );
    assert!(
        e.starts_with(&format!(
            "c.toml:{}: [calibration] reference_geometry_deg:",
            line(&text, "reference_geometry_deg")
        )) && e.contains("grazing"),
        "{e}"
    );
    let (_, e) = refuse(
        "[calibration]\nmethod = \"relative\"\nreference = \"spectralon\"\nreference_geometry_deg = [0.0, 45.0]",
    );
    assert!(
        e.contains("[calibration] reference_geometry_deg: expected [theta_i"),
        "{e}"
    );

    // The absolute method's keys do not mix with the relative method's.
    let (_, e) =
        refuse("[calibration]\nmethod = \"absolute\"\nreference_geometry_deg = [0.0, 0.0, 45.0, 180.0]");
    assert!(
        e.contains("[calibration] reference_geometry_deg: only used with"),
        "{e}"
    );
    let text = CAMPAIGN.replace(
        "reference_every_points = 10",
        "reference_every_points = 10\nreference_pose_deg = { light = -90.0, detector = 90.0 }",
    );
    write(dir.path(), "standards/white.toml", WHITE);
    let e = prepare_campaign(&text, "c.toml", dir.path(), &file)
        .expect_err("direct-beam pose with the relative method")
        .to_string();
    assert!(
        e.starts_with(&format!(
            "c.toml:{}: [plan.calibration] reference_pose_deg:",
            line(&text, "reference_pose_deg")
        )),
        "{e}"
    );
    // The same file with the reference present is accepted.
    prepare_campaign(CAMPAIGN, "c.toml", dir.path(), &file).expect("valid");
}

#[test]
fn the_relative_example_campaign_validates() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config/campaigns");
    let text = std::fs::read_to_string(dir.join("relative.toml")).expect("example");
    let prepared =
        prepare_campaign(&text, "relative.toml", &dir, &InstrumentFile::simulated()).expect("valid");
    assert!(prepared.total_points > 100, "{}", prepared.total_points);
    assert!(prepared.resolved_toml.contains("[resolved.reference]"));
}
