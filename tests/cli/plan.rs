//! `gonio plan` end to end: the real binary on the demo campaign and on a small campaign written here, and
//! against `gonio run` on every shipped campaign (the same campaigns accepted, the same predicted duration).

use gonio_testkit::gonio;
use std::path::{Path, PathBuf};

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
    // The band: 2 % either side of the prediction, and the operator steps the model does not time.
    let seconds = |line: &str, label: &str| -> f64 {
        line.split(label)
            .nth(1)
            .and_then(|r| r.split_whitespace().next())
            .and_then(|w| w.parse().ok())
            .unwrap_or_else(|| panic!("no number after {label:?} in {line:?}"))
    };
    let predicted_line = stdout
        .lines()
        .find(|l| l.starts_with("predicted duration:"))
        .expect("prediction");
    let predicted = seconds(predicted_line, "predicted duration:");
    let band = stdout
        .lines()
        .find(|l| l.starts_with("expected between"))
        .expect("a band line");
    let (low, high) = (seconds(band, "between"), seconds(band, "and"));
    assert!(
        (low - 0.98 * predicted).abs() < 0.1 && (high - 1.02 * predicted).abs() < 0.1,
        "{band}"
    );
    assert!(
        band.contains("operator steps") && band.contains("retries"),
        "{band}"
    );
    let text = std::fs::read_to_string(&csv).expect("csv written");
    let mut lines = text.lines();
    assert_eq!(
        lines.next(),
        Some(
            "index,band_nm,theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,light_deg,detector_deg,tilt_deg,rotation_deg,move_s,\
             motion_s,settle_s,wheel_s,reading_s,end_s"
        )
    );
    let rows: Vec<&str> = lines.collect();
    assert_eq!(rows.len(), kept);
    let mut previous_end = 0.0;
    for (i, row) in rows.iter().enumerate() {
        let cols: Vec<&str> = row.split(',').collect();
        assert_eq!(cols.len(), 16, "{row}");
        assert_eq!(cols[0], i.to_string());
        assert!(["450", "550", "650"].contains(&cols[1]), "{row}");
        // Gold is isotropic: the sample rotation never moves.
        assert_eq!(cols[9].parse::<f64>().expect("rotation"), 0.0, "{row}");
        let num = |k: usize| cols[k].parse::<f64>().expect("a number");
        let (move_s, motion_s, settle_s, wheel_s, reading_s, end_s) =
            (num(10), num(11), num(12), num(13), num(14), num(15));
        assert!(
            move_s >= 0.0 && motion_s >= 0.0 && settle_s >= 0.0 && wheel_s >= 0.0,
            "{row}"
        );
        assert!(
            (move_s - motion_s - settle_s).abs() < 2e-6,
            "the move is its motion and settle: {row}"
        );
        assert!(reading_s > 0.0, "every step reads: {row}");
        // The step ends after the previous one by at least its own move, filter change and reading (more when a
        // calibration step came between them).
        assert!(
            end_s - previous_end >= move_s + wheel_s + reading_s - 4e-6,
            "{row}"
        );
        previous_end = end_s;
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

/// `gonio plan CAMPAIGN`'s prediction for the whole campaign (s), or its error.
fn plan_prediction(campaign: &Path) -> Result<f64, String> {
    let out = gonio()
        .arg("plan")
        .arg(campaign)
        .output()
        .expect("run gonio plan");
    let stdout = String::from_utf8_lossy(&out.stdout);
    if !out.status.success() {
        return Err(String::from_utf8_lossy(&out.stderr).into_owned());
    }
    stdout
        .lines()
        .find_map(|l| l.strip_prefix("predicted duration: "))
        .and_then(|rest| rest.split(" s").next())
        .and_then(|n| n.trim().parse().ok())
        .ok_or_else(|| format!("no prediction in\n{stdout}"))
}

/// `gonio run CAMPAIGN` to completion: its run.json's predicted instrument time (s), or its error.
fn run_prediction(campaign: &Path, out: &Path) -> Result<f64, String> {
    let run = gonio()
        .arg("run")
        .arg(campaign)
        .arg("--out")
        .arg(out)
        .arg("--quiet")
        .output()
        .expect("run gonio run");
    if !run.status.success() {
        return Err(String::from_utf8_lossy(&run.stderr).into_owned());
    }
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("run.json")).expect("run.json"))
            .expect("json");
    json.pointer("/timing/predicted_instrument_s")
        .and_then(serde_json::Value::as_f64)
        .ok_or_else(|| "run.json without timing.predicted_instrument_s".to_string())
}

/// A campaign with what `gonio run` and `gonio plan` predicted for it (or their errors).
type Compared = (PathBuf, Result<f64, String>, Result<f64, String>);

/// Every shipped campaign, and the demo with slow acquisition settings (which the time model must see): what
/// `gonio run` accepts, `gonio plan` accepts, with the same predicted duration (plan prints 0.1 s).
#[test]
fn plan_accepts_every_campaign_run_accepts_and_predicts_the_same_duration() {
    let dir = tempfile::tempdir().expect("temp dir");
    let demo = std::fs::read_to_string(repo_root().join("config/campaigns/demo.toml")).expect("demo");
    let slow = demo
        .replace("averaging = 10 ", "averaging = 1000 ")
        .replace("settle_s = 0.0 ", "settle_s = 2.0 ");
    assert_ne!(slow, demo, "the demo's acquisition settings moved");
    let slow_path = dir.path().join("slow-demo.toml");
    std::fs::write(&slow_path, &slow).expect("write");
    let mut campaigns: Vec<PathBuf> = std::fs::read_dir(repo_root().join("config/campaigns"))
        .expect("config/campaigns")
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "toml"))
        .collect();
    campaigns.sort();
    campaigns.push(slow_path.clone());
    // Two at a time: the runs are independent processes.
    let results: Vec<Compared> = campaigns
        .chunks(2)
        .flat_map(|pair| {
            let handles: Vec<_> = pair
                .iter()
                .enumerate()
                .map(|(k, c)| {
                    let c = c.clone();
                    let out = dir.path().join(format!(
                        "out-{}-{k}",
                        c.file_stem()
                            .map(|s| s.to_string_lossy().into_owned())
                            .unwrap_or_default()
                    ));
                    std::thread::spawn(move || {
                        let run = run_prediction(&c, &out);
                        (c.clone(), run, plan_prediction(&c))
                    })
                })
                .collect();
            handles
                .into_iter()
                .map(|h| h.join().expect("thread"))
                .collect::<Vec<_>>()
        })
        .collect();
    let mut compared = 0;
    for (campaign, run, plan) in &results {
        let Ok(run_s) = run else { continue };
        let plan_s = plan.as_ref().unwrap_or_else(|e| {
            panic!(
                "{}: gonio run accepts it, gonio plan refuses it: {e}",
                campaign.display()
            )
        });
        assert!(
            (plan_s - run_s).abs() <= 0.051,
            "{}: gonio plan predicts {plan_s} s, gonio run {run_s} s",
            campaign.display()
        );
        compared += 1;
    }
    assert!(compared >= 6, "only {compared} campaigns ran: {results:?}");
    // The shipped adaptive campaign (target error 0) places its whole budget in `gonio run`: 300 points, one band.
    let adaptive_out = dir.path().join("out-adaptive-0");
    let adaptive_out = if adaptive_out.exists() {
        adaptive_out
    } else {
        dir.path().join("out-adaptive-1")
    };
    let csv = std::fs::read_to_string(adaptive_out.join("points.csv")).expect("adaptive points.csv");
    assert_eq!(csv.lines().count() - 1, 300, "rows of {}", adaptive_out.display());
    // The slow settings are in the prediction (the demo has 213 points: 1000 samples and 2 s more settling
    // each are minutes).
    let prediction = |p: &Path| {
        results
            .iter()
            .find(|r| r.0 == p)
            .and_then(|r| r.2.clone().ok())
            .expect("predicted")
    };
    let (fast, slow) = (
        prediction(&repo_root().join("config/campaigns/demo.toml")),
        prediction(&slow_path),
    );
    assert!(slow > fast + 300.0, "demo {fast} s, slow demo {slow} s");
}

/// The shipped sweeps campaign: `gonio plan` prints what the path check kept and cut, the readings and the
/// sweeps' duration; `gonio run` sweeps them and writes every reading to sweeps.csv.
#[test]
fn plan_times_the_sweeps_and_run_sweeps_them() {
    let campaign = repo_root().join("config/campaigns/sweeps.toml");
    let out = gonio()
        .arg("plan")
        .arg(&campaign)
        .output()
        .expect("run gonio plan");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    // Three incidences each cut around the source into two pieces, and the slow arc: 7 of 4 requested.
    assert!(stdout.contains("sweeps: 4 arcs requested, 7 swept"), "{stdout}");
    assert!(
        stdout.contains("cut arm-separation") && stdout.contains("cut retro-block"),
        "{stdout}"
    );
    assert!(stdout.contains("21 sweeps"), "{stdout}");
    let sweeping: f64 = stdout
        .lines()
        .find_map(|l| l.trim().strip_prefix("sweeping"))
        .and_then(|r| r.trim().trim_end_matches(" s").trim().parse().ok())
        .unwrap_or_else(|| panic!("{stdout}"));
    // The pieces by hand (10.02 degrees kept from the source at -theta_i): 419.88 degrees at 4 deg/s and 20 at
    // 0.5 deg/s, three bands; the ramps and the drivers' exchanges add under half a second per sweep.
    let cruise = 3.0 * (419.88 / 4.0 + 20.0 / 0.5);
    assert!(
        sweeping >= cruise - 0.1 && sweeping < cruise + 21.0 * 0.5,
        "{sweeping} vs {cruise}"
    );
    // `gonio run` sweeps them: every reading in sweeps.csv, a row per reading of each of the 21 sweeps.
    let dir = tempfile::tempdir().expect("temp dir");
    let out = dir.path().join("out");
    let run = gonio()
        .arg("run")
        .arg(&campaign)
        .arg("--out")
        .arg(&out)
        .arg("--quiet")
        .output()
        .expect("run gonio run");
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let csv = std::fs::read_to_string(out.join("sweeps.csv")).expect("sweeps.csv");
    let header: Vec<&str> = csv.lines().next().expect("header").split(',').collect();
    assert_eq!(header.last(), Some(&"brdf_true_sr"));
    let rows = csv.lines().count() - 1;
    assert!(rows > 90_000, "{rows} readings");
    let segments: std::collections::BTreeSet<&str> =
        csv.lines().skip(1).filter_map(|l| l.split(',').next()).collect();
    assert_eq!(segments.len(), 21);

    // `gonio fit` fits the readings like points: the simulated plastic's roughness and its albedo at 550 nm
    // come back from the sweeps alone (the campaign measures no point).
    let fit = gonio()
        .args([
            "fit",
            "--model",
            "plastic",
            "--wavelength",
            "550",
            "--json",
            "--out",
        ])
        .arg(dir.path().join("fit.toml"))
        .arg(&out)
        .output()
        .expect("run gonio fit");
    assert!(fit.status.success(), "{}", String::from_utf8_lossy(&fit.stderr));
    let report: serde_json::Value = serde_json::from_slice(&fit.stdout).expect("fit JSON");
    let param = |key: &str| {
        report["parameters"]
            .as_array()
            .and_then(|ps| ps.iter().find(|p| p["key"] == key))
            .and_then(|p| p["value"].as_f64())
            .unwrap_or_else(|| panic!("{key} in {report}"))
    };
    assert!((param("alpha") - 0.1).abs() < 1e-3, "{report}");
    assert!(
        report["residuals"]["points"]
            .as_u64()
            .is_some_and(|n| n as usize > rows / 4),
        "{report}"
    );
    // The tabular exports carry them as points, the gridded ones say they leave them out.
    let export = |format: &str, extra: &[&str]| {
        let o = gonio()
            .args(["export", "--format", format])
            .args(extra)
            .arg(&out)
            .output()
            .expect("run gonio export");
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        o
    };
    let data_rows = |o: &std::process::Output| {
        String::from_utf8_lossy(&o.stdout)
            .lines()
            .filter(|l| !l.starts_with('#'))
            .count()
            - 1
    };
    let with = export("csv", &[]);
    assert_eq!(data_rows(&with), rows);
    assert!(String::from_utf8_lossy(&with.stderr).contains(&format!("{rows} sweep readings exported")));
    assert_eq!(data_rows(&export("csv", &["--points-only"])), 0);
    let zemax_out = dir.path().join("sweeps.bsdf");
    let zemax = gonio()
        .args(["export", "--format", "zemax", "--out"])
        .arg(&zemax_out)
        .arg(&out)
        .output()
        .expect("run gonio export");
    assert!(
        String::from_utf8_lossy(&zemax.stderr).contains("sweep readings are not in zemax exports"),
        "{}",
        String::from_utf8_lossy(&zemax.stderr)
    );
}

#[test]
fn plan_and_run_an_adaptive_campaign_whose_first_pass_sweeps() {
    let dir = tempfile::tempdir().expect("temp dir");
    let campaign = dir.path().join("swept.toml");
    std::fs::write(
        &campaign,
        "[campaign]\nid = \"swept\"\n[sample]\nradius_mm = 12.5\n[material]\npreset = \"gold\"\n[plan]\n\
         bands_nm = [550.0]\n[plan.adaptive]\nbudget_points = 60\nbatch_points = 20\ntarget_error = 0.0\n\
         first_pass_theta_i_deg = [30.0]\nfirst_pass_sweeps = { speed_deg_s = 20.0 }\n",
    )
    .expect("write");
    let out = gonio()
        .arg("plan")
        .arg(&campaign)
        .output()
        .expect("run gonio plan");
    let stdout = String::from_utf8_lossy(&out.stdout);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    for needle in [
        "adaptive plan: budget 60 points",
        "first pass: the sweeps below",
        "sweeps: 1 arcs requested, 2 swept",
        "the sweeps and 60 points, every pass rehearsed on the campaign's [material], the mean of 8 rehearsals \
         with a reading's noise (their spread",
    ] {
        assert!(stdout.contains(needle), "{needle:?} not in\n{stdout}");
    }
    let run_dir = dir.path().join("out");
    let run = gonio()
        .arg("run")
        .arg(&campaign)
        .arg("--out")
        .arg(&run_dir)
        .arg("--quiet")
        .output()
        .expect("run gonio run");
    assert!(run.status.success(), "{}", String::from_utf8_lossy(&run.stderr));
    let points = std::fs::read_to_string(run_dir.join("points.csv")).expect("points.csv");
    assert_eq!(points.lines().count() - 1, 60, "the budget in points");
    let sweeps = std::fs::read_to_string(run_dir.join("sweeps.csv")).expect("sweeps.csv");
    assert!(
        sweeps.lines().count() > 1000,
        "{} sweep readings",
        sweeps.lines().count() - 1
    );
}

/// What `gonio plan CAMPAIGN` prints on the instrument file `text` (written into `dir`); it must succeed.
fn plan_on(dir: &std::path::Path, campaign: &std::path::Path, text: &str) -> String {
    let path = dir.join("lab.toml");
    std::fs::write(&path, text).expect("write");
    let out = gonio()
        .arg("plan")
        .arg(campaign)
        .arg("--instrument")
        .arg(&path)
        .output()
        .expect("run gonio");
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// The simulated instrument's file with the arms on a real port (`gonio plan` opens no port), and that file.
fn simulated_and_real_arms() -> (String, String) {
    let simulated =
        std::fs::read_to_string(repo_root().join("config/instruments/simulated.toml")).expect("read");
    let real = simulated.replace(
        "name = \"arms\"\nprotocol = \"smc100\"\nport = \"sim\"\n",
        "name = \"arms\"\nprotocol = \"smc100\"\nport = \"/dev/ttyUSB0\"\n",
    );
    assert_ne!(real, simulated);
    (simulated, real)
}

/// On real hardware whose file does not say how long its motion controllers take to answer, `gonio plan` says
/// that the prediction counts none; on the simulator, or once the file says it, nothing.
#[test]
fn plan_says_when_the_file_does_not_give_the_controllers_reply_latency() {
    let demo = repo_root().join("config/campaigns/demo.toml");
    let dir = tempfile::tempdir().expect("temp dir");
    let (simulated, real) = simulated_and_real_arms();
    assert!(!plan_on(dir.path(), &demo, &simulated).contains("reply_latency_ms"));
    let printed = plan_on(dir.path(), &demo, &real);
    assert!(
        printed.contains("does not say how long arms take to answer a query (reply_latency_ms)"),
        "{printed}"
    );
    let said = real.replace("name = \"arms\"\n", "name = \"arms\"\nreply_latency_ms = 10.0\n");
    assert!(!plan_on(dir.path(), &demo, &said).contains("does not say"));
}

/// On real controllers whose file does not say when they take the position they report, `gonio plan` of a
/// campaign with sweeps says so; on the simulator, or once the file says it, nothing.
#[test]
fn plan_says_when_the_file_does_not_give_when_the_swept_arms_controller_takes_its_positions() {
    let sweeps = repo_root().join("config/campaigns/sweeps.toml");
    let dir = tempfile::tempdir().expect("temp dir");
    let (simulated, real) = simulated_and_real_arms();
    assert!(!plan_on(dir.path(), &sweeps, &simulated).contains("position_sampled_ms"));
    let printed = plan_on(dir.path(), &sweeps, &real);
    assert!(
        printed.contains("does not say when arms take the position they report (position_sampled_ms)"),
        "{printed}"
    );
    let said = real.replace(
        "name = \"arms\"\n",
        "name = \"arms\"\nposition_sampled_ms = 1.0\n",
    );
    assert!(!plan_on(dir.path(), &sweeps, &said).contains("position_sampled_ms"));
}

/// A campaign measured in one band through filters that leak (realistic.toml's) has no spectrum to correct the
/// leak with: `gonio plan` says so, for points or sweeps in one band, and says nothing once points measure every
/// band beside the sweeps (`sweep_bands_nm`), for a spectrally flat [material], or on filters that do not leak
/// (simulated.toml's pass a single wavelength).
#[test]
fn plan_says_when_one_band_through_a_leaking_filter_has_no_spectrum_to_correct_the_leak_with() {
    let dir = tempfile::tempdir().expect("temp dir");
    let realistic =
        std::fs::read_to_string(repo_root().join("config/instruments/realistic.toml")).expect("read");
    let simulated =
        std::fs::read_to_string(repo_root().join("config/instruments/simulated.toml")).expect("read");
    let sweep = "[[plan.sweeps]]\ntheta_i_deg = [30.0]\ntheta_o_deg = { from = -60.0, to = 60.0 }\nspeed_deg_s = 4.0\n";
    let grid = "[plan.grid]\nkind = \"in-plane\"\ntheta_i_deg = [30.0]\ntheta_o_deg = [0.0, 45.0]\n";
    let campaign = |plan: &str, material: &str| {
        let path = dir.path().join("c.toml");
        std::fs::write(
            &path,
            format!(
                "[campaign]\nid = \"c\"\n[sample]\nradius_mm = 12.5\n[material]\n{material}\n[plan]\n{plan}"
            ),
        )
        .expect("write");
        path
    };
    let note = "measured in one band (550 nm) through a filter that passes";
    for (plan, said) in [
        (format!("bands_nm = [550.0]\n{sweep}"), true),
        (format!("bands_nm = [550.0]\n{grid}"), true),
        (format!("bands_nm = [550.0]\n{grid}{sweep}"), true),
        (
            format!("bands_nm = [450.0, 550.0, 650.0]\nsweep_bands_nm = [550.0]\n{grid}{sweep}"),
            false,
        ),
        (format!("bands_nm = [450.0, 550.0, 650.0]\n{sweep}"), false),
    ] {
        let printed = plan_on(
            dir.path(),
            &campaign(&plan, "preset = \"construction-paper\""),
            &realistic,
        );
        assert_eq!(printed.contains(note), said, "{plan}\n{printed}");
        let ideal = plan_on(
            dir.path(),
            &campaign(&plan, "preset = \"construction-paper\""),
            &simulated,
        );
        assert!(!ideal.contains("through a filter that passes"), "{ideal}");
    }
    // A grey Lambertian sample (one albedo at every wavelength): the leak cancels.
    let grey = "model = \"lambertian\"\nalbedo = 0.5";
    let flat = plan_on(
        dir.path(),
        &campaign(&format!("bands_nm = [550.0]\n{grid}"), grey),
        &realistic,
    );
    assert!(!flat.contains("through a filter that passes"), "{flat}");
}

/// A campaign that runs for minutes on its opening normalisation alone says that the lamp's drift since is
/// covered only by the file's bound; with any later reading (a reference cadence, or one longer than the
/// campaign: a reading at its end), or when short, nothing.
#[test]
fn plan_says_when_a_long_campaign_has_no_normalisation_after_its_opening_one() {
    let dir = tempfile::tempdir().expect("temp dir");
    let simulated =
        std::fs::read_to_string(repo_root().join("config/instruments/simulated.toml")).expect("read");
    let campaign = |step: f64, calibration: &str| {
        let path = dir.path().join("c.toml");
        std::fs::write(
            &path,
            format!(
                "[campaign]\nid = \"c\"\n[sample]\nradius_mm = 12.5\n[plan]\nbands_nm = [550.0]\n\
                 [plan.grid]\nkind = \"in-plane\"\ntheta_i_deg = [15.0, 30.0, 45.0, 60.0]\n\
                 theta_o_deg = {{ from = -80.0, to = 80.0, step = {step} }}\n{calibration}\
                 [material]\npreset = \"white-styrofoam\"\n"
            ),
        )
        .expect("write");
        path
    };
    let note = "no normalisation reading after the opening one";
    let long = plan_on(dir.path(), &campaign(0.3125, ""), &simulated);
    let minutes: f64 = long
        .split("values up to ")
        .nth(1)
        .and_then(|rest| rest.split_whitespace().next())
        .and_then(|w| w.parse().ok())
        .unwrap_or_else(|| panic!("no minutes in the note:\n{long}"));
    assert!(long.contains(note) && minutes >= 5.0, "{long}");
    assert!(long.contains("source.drift_per_hour"), "{long}");
    let closed = "[plan.calibration]\nreference_every_s = 1.0e9\n";
    assert!(!plan_on(dir.path(), &campaign(0.3125, closed), &simulated).contains(note));
    let short = plan_on(dir.path(), &campaign(5.0, ""), &simulated);
    assert!(!short.contains(note), "{short}");
}
