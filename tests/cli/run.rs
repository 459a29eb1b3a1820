//! `gonio run` end to end on the simulated instrument: values against the simulator's ground truth, the CSV
//! and run.json contracts, resuming after `kill -9` at random moments, and refused campaign files.

use std::path::{Path, PathBuf};
use std::process::Stdio;
use std::time::Duration;

use gonio_engine::store::{PointRecord, Store};
use gonio_testkit::cli::quiet_run;
use gonio_testkit::gonio;
use rand::{Rng, SeedableRng};

/// A small dry-run campaign (about 60 points, 2 bands, darks and a mid-run direct-beam reading).
const SMALL: &str = r#"
[campaign]
id = "small"
[sample]
radius_mm = 12.5
[plan]
bands_nm = [450.0, 650.0]
[plan.grid]
kind = "isotropic"
theta_i_deg = { from = 0.0, to = 75.0, step = 25.0 }
theta_o_deg = { from = 0.0, to = 75.0, step = 25.0 }
delta_phi_deg = { from = 0.0, to = 180.0, step = 60.0 }
[plan.calibration]
dark_every_points = 20
reference_every_s = 20.0
[acquisition]
averaging = 10
[material]
preset = "coloured-plastic"
"#;

fn write_campaign(dir: &Path, text: &str) -> PathBuf {
    let p = dir.join("campaign.toml");
    std::fs::write(&p, text).expect("write campaign");
    p
}

fn run_json(out: &Path) -> serde_json::Value {
    serde_json::from_str(&std::fs::read_to_string(out.join("run.json")).expect("run.json")).expect("json")
}

#[test]
fn dry_run_matches_ground_truth_and_writes_csv_and_json() {
    let dir = tempfile::tempdir().expect("tempdir");
    let campaign = write_campaign(dir.path(), SMALL);
    let out = dir.path().join("out");
    let o = quiet_run(&campaign, &out).output().expect("run");
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "gonio run failed: {stderr}");
    assert_eq!(
        String::from_utf8_lossy(&o.stdout).trim(),
        out.display().to_string()
    );

    let json = run_json(&out);
    let total = json["campaign"]["total_points"].as_u64().expect("total_points");
    assert!(total > 20, "{total} points");
    for key in [
        "software_version",
        "devices",
        "calibrations",
        "timing",
        "truth",
        "config",
    ] {
        assert!(!json[key].is_null(), "run.json lacks {key}");
    }
    // Instrument time only: run.json holds what the store holds (the wall time is in the summary on stderr).
    let actual = json["timing"]["actual_instrument_s"].as_f64().expect("actual");
    let predicted = json["timing"]["predicted_instrument_s"]
        .as_f64()
        .expect("predicted");
    assert!(
        actual > 0.0 && (actual - predicted).abs() <= 0.1 * predicted,
        "actual {actual} s, predicted {predicted} s"
    );
    assert!(json["timing"]["wall_s"].is_null());
    assert!(stderr.contains("wall time"), "{stderr}");
    assert!(
        json["config"]["campaign_toml"]
            .as_str()
            .is_some_and(|t| t.contains("coloured-plastic"))
    );
    assert!(
        json["calibrations"]
            .as_array()
            .is_some_and(|c| c.iter().any(|c| c["kind"] == "direct-beam"))
    );

    let csv = std::fs::read_to_string(out.join("points.csv")).expect("csv");
    let mut lines = csv.lines();
    assert_eq!(
        lines.next(),
        Some(
            "index,band_nm,theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,signal_w,dark_w,incident_w,brdf_sr,brdf_u_sr,\
             flags,t_s,light_deg,detector_deg,tilt_deg,rotation_deg,brdf_aperture_sr,brdf_u_indep_sr,budget,\
             brdf_true_sr,brdf_true_aperture_sr"
        )
    );
    let rows: Vec<Vec<&str>> = lines.map(|l| l.split(',').collect()).collect();
    assert_eq!(rows.len() as u64, total);
    let mut valid = 0;
    for (i, r) in rows.iter().enumerate() {
        assert_eq!(r.len(), 22, "row {i}");
        assert_eq!(r[0], i.to_string());
        if !r[11].is_empty() {
            // A flagged point has no value.
            assert_eq!(r[9], "", "flagged row {i} has a BRDF");
            continue;
        }
        let f: f64 = r[9].parse().expect("brdf");
        let u: f64 = r[10].parse().expect("u");
        // brdf_true_sr: a completed campaign's values are the BRDF at the nominal geometry.
        let truth: f64 = r[20].parse().expect("truth");
        assert_budget_columns(i, r, u);
        // Noise and drift are the simulator's; the uncertainty claims to cover them: 5 u plus a floor for the
        // optics' integration tolerance (1e-6 relative).
        assert!(
            u > 0.0 && u < 0.05 * f.abs().max(1e-3),
            "row {i}: u {u} for f {f}"
        );
        assert!(
            (f - truth).abs() <= 5.0 * u + 1e-6 * truth.abs(),
            "row {i}: f {f} truth {truth} u {u}"
        );
        valid += 1;
    }
    assert!(valid as u64 * 2 > total, "only {valid} of {total} valid");
}

/// How many points the store holds now (0 when it does not exist yet).
fn committed_count(out: &Path) -> usize {
    let Ok(store) = Store::open(out) else {
        return 0;
    };
    match store.campaigns().ok().and_then(|c| c.first().map(|c| c.id)) {
        Some(id) => store.next_index(id).map(|n| n as usize).unwrap_or(0),
        None => 0,
    }
}

/// The committed rows as committed (a completed campaign's corrected values are read apart from them, and
/// never rewrite them: crate::budget::complete).
fn snapshot(out: &Path) -> Vec<PointRecord> {
    let Ok(store) = Store::open(out) else {
        return Vec::new();
    };
    match store.campaigns().ok().and_then(|c| c.first().map(|c| c.id)) {
        Some(id) => store.committed_points(id).unwrap_or_default(),
        None => Vec::new(),
    }
}

#[test]
fn kill_9_at_random_moments_then_resume_loses_and_repeats_nothing() {
    let dir = tempfile::tempdir().expect("tempdir");
    // The demo campaign (a few hundred points): long enough to be killed several times.
    let campaign = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config/campaigns/demo.toml");
    let out = dir.path().join("out");
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(6);
    let mut kills = 0;
    let mut kills_mid_run = 0;
    let mut before: Vec<PointRecord> = Vec::new();
    for round in 0..40 {
        let mut child = quiet_run(&campaign, &out)
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("spawn");
        // Where to kill: the first two rounds at a random instant during start-up and calibration (before or
        // around the first commit); the next rounds after a random number of newly committed points, so that
        // kills land mid-run however fast this machine is; then let the run finish.
        let kill_after_points = match round {
            0 | 1 => None,
            2..=6 => Some(before.len() + rng.random_range(1..25)),
            _ => Some(usize::MAX),
        };
        let start_ms = rng.random_range(0..40);
        let deadline = std::time::Instant::now() + Duration::from_secs(120);
        let started = std::time::Instant::now();
        let status = loop {
            if let Some(s) = child.try_wait().expect("wait") {
                break Some(s);
            }
            let due = match kill_after_points {
                None => started.elapsed() >= Duration::from_millis(start_ms),
                Some(target) => committed_count(&out) >= target,
            };
            if due {
                break None;
            }
            assert!(
                std::time::Instant::now() < deadline,
                "gonio run neither finished nor progressed"
            );
            std::thread::sleep(Duration::from_millis(2));
        };
        match status {
            Some(s) => {
                assert!(s.success(), "gonio run exited with {s}");
                break;
            }
            None => {
                child.kill().expect("kill -9");
                let _ = child.wait();
                kills += 1;
            }
        }
        let now = snapshot(&out);
        if status.is_none() && !now.is_empty() {
            kills_mid_run += 1;
        }
        assert!(now.len() >= before.len());
        assert_eq!(
            &now[..before.len()],
            &before[..],
            "committed points changed after kill {kills}"
        );
        before = now;
    }
    eprintln!("kills: {kills}, of which after the first commit: {kills_mid_run}");
    assert!(kills >= 3, "only {kills} kills landed before the end");
    assert!(
        kills_mid_run >= 3,
        "no kill landed after the first committed point"
    );
    let all = snapshot(&out);
    assert_eq!(&all[..before.len()], &before[..]);
    let json = run_json(&out);
    let total = json["campaign"]["total_points"].as_u64().expect("total");
    assert_eq!(all.len() as u64, total);
    for (i, p) in all.iter().enumerate() {
        assert_eq!(p.index, i as u64);
    }
    let csv = std::fs::read_to_string(out.join("points.csv")).expect("csv");
    assert_eq!(csv.lines().count() as u64, total + 1);
}

/// SIGINT in the middle of a dry-run (which runs its paused clock without an I/O driver, its signal handlers on a
/// thread of their own): all motion stops, the exit says so and how to resume, and the resumed run completes with
/// every point once.
#[test]
fn sigint_stops_a_dry_run_and_the_rerun_resumes_it() {
    let dir = tempfile::tempdir().expect("tempdir");
    // Over 1,000 points: about a second of wall time, so the signal lands long before the end on any machine.
    let big = SMALL
        .replace("id = \"small\"", "id = \"sigint\"")
        .replace("bands_nm = [450.0, 650.0]", "bands_nm = [650.0]")
        .replace("step = 25.0 }\ntheta_o_deg", "step = 5.0 }\ntheta_o_deg")
        .replace(
            "theta_o_deg = { from = 0.0, to = 75.0, step = 25.0 }",
            "theta_o_deg = { from = 0.0, to = 75.0, step = 5.0 }",
        )
        .replace("step = 60.0 }", "step = 20.0 }");
    let campaign = write_campaign(dir.path(), &big);
    let out = dir.path().join("out");
    let child = quiet_run(&campaign, &out)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("spawn");
    let deadline = std::time::Instant::now() + Duration::from_secs(120);
    while committed_count(&out) < 1 {
        assert!(std::time::Instant::now() < deadline, "no point committed");
        std::thread::sleep(Duration::from_millis(2));
    }
    nix::sys::signal::kill(
        nix::unistd::Pid::from_raw(child.id() as i32),
        nix::sys::signal::Signal::SIGINT,
    )
    .expect("SIGINT");
    let o = child.wait_with_output().expect("wait");
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(!o.status.success(), "{stderr}");
    assert!(
        o.status.code().is_some(),
        "exited by itself, not by the signal: {:?}",
        o.status
    );
    assert!(
        stderr.contains("signal received: stopping all motion")
            && stderr.contains("interrupted: motion stopped")
            && stderr.contains("to resume"),
        "{stderr}"
    );
    let total = run_json(&out)["campaign"]["total_points"]
        .as_u64()
        .expect("total");
    let stopped_at = snapshot(&out);
    assert!(total > 1000, "{total} points planned");
    assert!(
        !stopped_at.is_empty() && (stopped_at.len() as u64) < total,
        "stopped after {} of {total} points",
        stopped_at.len()
    );

    let o = quiet_run(&campaign, &out).output().expect("resume");
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let all = snapshot(&out);
    assert_eq!(
        &all[..stopped_at.len()],
        &stopped_at[..],
        "committed points unchanged"
    );
    assert_eq!(all.len() as u64, total);
    for (i, p) in all.iter().enumerate() {
        assert_eq!(p.index, i as u64);
    }
}

/// Without `[plan.calibration]` there is no reference pose in the plan: the direct-beam readings taken at the
/// start must still find a safe pose (the engine's default, detector facing the source), never "stay where the
/// arms are" (both at 0 deg after power-up, which no safe move can reach).
#[test]
fn a_campaign_without_calibration_settings_runs_to_completion() {
    let dir = tempfile::tempdir().expect("tempdir");
    let text = SMALL.replace(
        "[plan.calibration]\ndark_every_points = 20\nreference_every_s = 20.0\n",
        "",
    );
    assert!(!text.contains("plan.calibration"));
    let campaign = write_campaign(dir.path(), &text);
    let out = dir.path().join("out");
    let o = quiet_run(&campaign, &out).output().expect("run");
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "gonio run failed: {stderr}");
    let json = run_json(&out);
    let total = json["campaign"]["total_points"].as_u64().expect("total");
    let csv = std::fs::read_to_string(out.join("points.csv")).expect("csv");
    assert!(total > 0);
    assert_eq!(csv.lines().count() as u64, total + 1, "{stderr}");
}

#[test]
fn bad_campaign_files_are_refused_with_file_line_and_key() {
    let dir = tempfile::tempdir().expect("tempdir");
    let bad = SMALL.replace("averaging = 10", "averaging = 0");
    let p = write_campaign(dir.path(), &bad);
    let o = gonio()
        .arg("run")
        .arg(&p)
        .arg("--out")
        .arg(dir.path().join("o"))
        .output()
        .expect("run");
    assert_eq!(o.status.code(), Some(2));
    let msg = String::from_utf8_lossy(&o.stderr);
    let line = bad
        .lines()
        .position(|l| l.starts_with("averaging"))
        .expect("line")
        + 1;
    assert!(msg.contains(&format!("campaign.toml:{line}")), "{msg}");
    assert!(
        msg.contains("[acquisition] averaging") && msg.contains("expected"),
        "{msg}"
    );

    let unknown = SMALL.replace("[acquisition]", "[acquisiton]");
    let p = write_campaign(dir.path(), &unknown);
    let o = gonio()
        .arg("run")
        .arg(&p)
        .arg("--out")
        .arg(dir.path().join("o2"))
        .output()
        .expect("run");
    let msg = String::from_utf8_lossy(&o.stderr);
    let line = unknown
        .lines()
        .position(|l| l.starts_with("[acquisiton]"))
        .expect("line")
        + 1;
    assert!(
        msg.contains(&format!(":{line}")) && msg.contains("acquisiton"),
        "{msg}"
    );
}

/// Issue #6: `gonio run` with every serial device of the simulated instrument on a real pseudo-terminal
/// (`port = "sim-pty"`), opened by path through the driver's ordinary serial opener; the USB meter in process.
/// The run is on the real clock (sped-up simulator), and every value still matches the ground truth.
#[test]
fn dry_run_with_serial_devices_on_pseudo_terminals_matches_ground_truth() {
    let dir = tempfile::tempdir().expect("tempdir");
    let campaign = write_campaign(dir.path(), SMALL);
    let mut instrument = gonio_instrument::SIMULATED_INSTRUMENT_TOML.to_string();
    for protocol in ["smc100", "zaber-ascii", "fw102c"] {
        let from = format!("protocol = \"{protocol}\"\nport = \"sim\"");
        assert!(
            instrument.contains(&from),
            "simulated.toml layout changed: {from}"
        );
        instrument = instrument.replace(&from, &format!("protocol = \"{protocol}\"\nport = \"sim-pty\""));
    }
    let instrument_path = dir.path().join("sim-pty.toml");
    std::fs::write(&instrument_path, &instrument).expect("write instrument");
    let out = dir.path().join("out");
    let o = gonio()
        .arg("run")
        .arg(&campaign)
        .arg("--instrument")
        .arg(&instrument_path)
        .arg("--out")
        .arg(&out)
        .arg("--quiet")
        .output()
        .expect("run");
    let stderr = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "gonio run failed: {stderr}");

    let json = run_json(&out);
    // The three serial devices really were on pseudo-terminals (the rig records where each device is).
    let devices = json["devices"].to_string();
    assert_eq!(
        devices.matches("on simulated, pseudo-terminal").count(),
        3,
        "devices: {devices}"
    );
    let total = json["campaign"]["total_points"].as_u64().expect("total_points");
    let csv = std::fs::read_to_string(out.join("points.csv")).expect("csv");
    let rows: Vec<Vec<&str>> = csv.lines().skip(1).map(|l| l.split(',').collect()).collect();
    assert_eq!(rows.len() as u64, total);
    for (i, r) in rows.iter().enumerate() {
        assert_eq!(r.len(), 22, "row {i}");
        assert_eq!(r[11], "", "row {i} is flagged: {r:?}");
        let f: f64 = r[9].parse().expect("brdf");
        let u: f64 = r[10].parse().expect("u");
        // brdf_true_sr: a completed campaign's values are the BRDF at the nominal geometry.
        let truth: f64 = r[20].parse().expect("truth");
        assert_budget_columns(i, r, u);
        assert!(
            (f - truth).abs() <= 5.0 * u + 1e-6 * truth.abs(),
            "row {i}: f {f} truth {truth} u {u}"
        );
    }
}

/// A valid row's budget columns (the layout of a dry-run on the ideal instrument: `brdf_u_indep_sr` at 18,
/// `budget` at 19): the budget names its parts (each normalisation reading's noise shared by the values
/// interpolated from it), and its independent part is at most the total `u`.
fn assert_budget_columns(i: usize, r: &[&str], u: f64) {
    assert!(
        r[19].contains("signal-noise=") && r[19].contains("normalisation@normalisation-"),
        "row {i}: budget {}",
        r[19]
    );
    let indep: f64 = r[18].parse().expect("independent u");
    assert!(indep > 0.0 && indep <= u, "row {i}: independent {indep} of {u}");
}
