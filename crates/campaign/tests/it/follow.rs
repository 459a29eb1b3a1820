//! A campaign whose sweeps follow the BRDF: the first pass read from an earlier run's sweeps.csv (the file or
//! its run directory) when the campaign is loaded, its profiles kept in the `[resolved]` table of a stored
//! campaign (so that resuming never reads the first pass again), and the errors that name the file and key.

use gonio_campaign::sources::resolved_trailer;
use gonio_campaign::{Sources, load_and_prepare};
use gonio_instrument::InstrumentFile;
use gonio_results::sweeps::{SweepReading, write_sweeps_csv};

const CAMPAIGN: &str = "[campaign]\nid = \"follow\"\n\n[plan]\nbands_nm = [450.0, 650.0]\n\n\
     [[plan.sweeps]]\ntheta_i_deg = [30.0]\ntheta_o_deg = { from = -70.0, to = 70.0 }\nspeed_deg_s = 16.0\n\
     averaging = 10\nfollow = { first_pass = \"first\", tolerance_rel = 1e-4 }\n\n[material]\npreset = \"coloured-plastic\"\n";

/// A lobe at the specular direction, a few degrees wide, on a diffuse floor.
fn lobe(s: f64) -> f64 {
    0.1 + 5.0 * (-((s - 30.0) / 3.0).powi(2)).exp()
}

/// A first pass over the detector arc at 30 deg incidence: readings every 0.02 deg in both bands.
fn first_pass() -> String {
    let mut readings = Vec::new();
    for band_nm in [450.0, 650.0] {
        for i in 0..=7000u32 {
            let s = -70.0 + f64::from(i) * 0.02;
            let phi_o = if s >= 0.0 { 180.0 } else { 0.0 };
            readings.push(SweepReading {
                segment: 0,
                k: i,
                band_nm,
                t_s: f64::from(i) * 0.001,
                integration_s: 0.003,
                theta_i_deg: 30.0,
                phi_i_deg: 0.0,
                theta_o_deg: s.abs(),
                phi_o_deg: phi_o,
                arc_from_deg: s - 0.005,
                arc_to_deg: s + 0.005,
                signal_w: Some(1e-6 * lobe(s)),
                incident_w: Some(1e-3),
                brdf_sr: Some(lobe(s)),
                brdf_u_sr: Some(1e-3),
                brdf_aperture_sr: None,
                flags: Vec::new(),
                truth_point_sr: None,
            });
        }
    }
    write_sweeps_csv(&readings, false)
}

#[test]
fn the_first_pass_is_read_once_and_the_stored_campaign_keeps_its_profiles() {
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path().join("first");
    std::fs::create_dir(&run).unwrap();
    std::fs::write(run.join("sweeps.csv"), first_pass()).unwrap();
    let file = InstrumentFile::simulated();
    let sources = Sources::Local(dir.path().to_path_buf());
    // The run directory or the file itself.
    let prepared = load_and_prepare(CAMPAIGN, "follow.toml", &sources, &file).unwrap();
    let by_file = CAMPAIGN.replace("first_pass = \"first\"", "first_pass = \"first/sweeps.csv\"");
    let same = load_and_prepare(&by_file, "follow.toml", &sources, &file).unwrap();
    assert_eq!(prepared.campaign.sweep_profiles, same.campaign.sweep_profiles);
    let profiles = &prepared.campaign.sweep_profiles;
    assert_eq!(profiles.len(), 1);
    let sweeps = prepared.sweeps.as_ref().expect("sweeps");
    let speeds: Vec<f64> = sweeps.plan.arcs.iter().map(|a| a.request.speed_deg_s).collect();
    assert!(speeds.contains(&16.0), "{speeds:?}");
    assert!(speeds.iter().any(|v| *v < 4.0), "{speeds:?}");
    // Each arc once per band.
    assert_eq!(sweeps.schedule.steps.len(), 2 * sweeps.plan.arcs.len());

    // Stored: the trailer carries the profiles; read back, the first pass is not read again (it is gone).
    let stored = format!("{CAMPAIGN}{}", resolved_trailer(&prepared.campaign.resolved));
    assert!(stored.contains("sweep_profiles"), "{stored}");
    std::fs::remove_dir_all(&run).unwrap();
    let back = load_and_prepare(&stored, "stored", &Sources::Stored, &file).unwrap();
    assert_eq!(&back.campaign.sweep_profiles, profiles);
    assert_eq!(back.sweeps.unwrap().schedule.steps, sweeps.schedule.steps);
    // ... while loading the file again needs it.
    let err = load_and_prepare(CAMPAIGN, "follow.toml", &sources, &file)
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("follow.toml:") && err.contains("[plan.sweeps #1] follow"),
        "{err}"
    );
    assert!(err.contains("cannot read the first pass"), "{err}");
}

#[test]
fn a_first_pass_of_other_arcs_is_refused_with_the_arc_it_lacks() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(dir.path().join("other.csv"), first_pass()).unwrap();
    let file = InstrumentFile::simulated();
    let sources = Sources::Local(dir.path().to_path_buf());
    let text = CAMPAIGN
        .replace("theta_i_deg = [30.0]", "theta_i_deg = [30.0, 45.0]")
        .replace("first_pass = \"first\"", "first_pass = \"other.csv\"");
    let err = load_and_prepare(&text, "follow.toml", &sources, &file)
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("no readings along the detector sweep at 45 deg"),
        "{err}"
    );
    assert!(err.contains("(first pass other.csv)"), "{err}");
    let garbage = dir.path().join("garbage.csv");
    std::fs::write(&garbage, "not,a,sweeps,file\n1,2\n").unwrap();
    let text = CAMPAIGN.replace("first_pass = \"first\"", "first_pass = \"garbage.csv\"");
    let err = load_and_prepare(&text, "follow.toml", &sources, &file)
        .unwrap_err()
        .to_string();
    assert!(err.contains("garbage.csv"), "{err}");
}

#[test]
fn a_campaign_submitted_to_the_daemon_reads_its_first_pass_inside_the_data_directory_only() {
    let data = tempfile::tempdir().unwrap();
    let outside = tempfile::tempdir().unwrap();
    std::fs::create_dir(data.path().join("first")).unwrap();
    std::fs::write(data.path().join("first/sweeps.csv"), first_pass()).unwrap();
    std::fs::write(outside.path().join("sweeps.csv"), first_pass()).unwrap();
    let file = InstrumentFile::simulated();
    let confined = Sources::Confined(data.path().to_path_buf());
    // The run directory or its file, inside the data directory.
    for name in ["first", "first/", "first/sweeps.csv"] {
        let text = CAMPAIGN.replace("first_pass = \"first\"", &format!("first_pass = \"{name}\""));
        let p =
            load_and_prepare(&text, "submitted", &confined, &file).unwrap_or_else(|e| panic!("{name}: {e}"));
        assert_eq!(p.campaign.sweep_profiles.len(), 1, "{name}");
    }
    // Outside it: refused, with the rule.
    for name in [
        "../first/sweeps.csv".to_string(),
        outside.path().join("sweeps.csv").display().to_string(),
    ] {
        let text = CAMPAIGN.replace("first_pass = \"first\"", &format!("first_pass = \"{name}\""));
        let err = load_and_prepare(&text, "submitted", &confined, &file)
            .unwrap_err()
            .to_string();
        assert!(err.contains("[plan.sweeps #1] follow"), "{err}");
        assert!(err.contains("data directory"), "{name}: {err}");
    }
}
