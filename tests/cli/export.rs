//! `gonio export` end to end: CSV and JSON carry every value with its unit and the run's provenance; the MERL
//! export read back through `gonio brdf eval` reproduces the measurement within its interpolation error; a run
//! read from a daemon's store exports the same points; bad input is refused with the file and what is wrong.

use std::io::Write;
use std::path::Path;
use std::process::{Output, Stdio};

use gonio_brdf::geometry::{Direction, IsotropicAngles};
use gonio_testkit::cli::dry_run;
use gonio_testkit::{CampaignText, gonio, text};

/// A dry-run campaign on an isotropic grid; `material` is the `[material]` table's body.
fn campaign(id: &str, bands: &str, theta_i: &str, theta_o: &str, dphi: &str, material: &str) -> String {
    CampaignText::isotropic(id, theta_i, theta_o, dphi)
        .bands(bands)
        .acquisition("averaging = 10")
        .plan_calibration("dark_every_points = 100")
        .material(material)
        .to_string()
}

fn eval(material: &Path, wavelength_nm: f64, geometries: &str) -> Vec<f64> {
    let mut child = gonio()
        .args(["brdf", "eval", "--material"])
        .arg(material)
        .args(["--wavelength", &wavelength_nm.to_string()])
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("gonio brdf eval");
    let mut input = child.stdin.take().expect("stdin");
    let owned = geometries.to_string();
    let writer = std::thread::spawn(move || {
        let _ = input.write_all(owned.as_bytes());
    });
    let out = child.wait_with_output().expect("eval finishes");
    writer.join().expect("writer");
    assert!(out.status.success(), "eval failed: {}", text(&out.stderr));
    text(&out.stdout)
        .lines()
        .map(|l| l.parse::<f64>().expect("a number per line"))
        .collect()
}

/// A valid point of points.csv: geometry (degrees) and value.
#[derive(Debug, Clone, Copy)]
struct Measured {
    angles_deg: [f64; 4],
    f: f64,
}

fn measured(run: &Path) -> Vec<Measured> {
    let csv = std::fs::read_to_string(run.join("points.csv")).expect("points.csv");
    let mut lines = csv.lines();
    let header: Vec<&str> = lines.next().expect("header").split(',').collect();
    let col = |name: &str| header.iter().position(|h| *h == name).expect("column");
    let (ti, pi, to, po, f, flags) = (
        col("theta_i_deg"),
        col("phi_i_deg"),
        col("theta_o_deg"),
        col("phi_o_deg"),
        col("brdf_sr"),
        col("flags"),
    );
    lines
        .filter_map(|l| {
            let r: Vec<&str> = l.split(',').collect();
            if !r[flags].is_empty() || r[f].is_empty() {
                return None;
            }
            let n = |i: usize| r[i].parse::<f64>().expect("number");
            Some(Measured {
                angles_deg: [n(ti), n(pi), n(to), n(po)],
                f: n(f),
            })
        })
        .collect()
}

fn iso(m: &Measured) -> IsotropicAngles {
    let [ti, pi, to, po] = m.angles_deg;
    IsotropicAngles::from_directions(
        &Direction::from_spherical_deg(ti, pi),
        &Direction::from_spherical_deg(to, po),
    )
}

#[test]
fn csv_and_json_carry_every_value_units_and_provenance() {
    let dir = tempfile::tempdir().expect("tempdir");
    let run = dry_run(
        dir.path(),
        "prov",
        &campaign(
            "prov",
            "[450.0, 650.0]",
            "[0.0, 40.0]",
            "[20.0, 60.0]",
            "[0.0, 180.0]",
            "preset = \"coloured-plastic\"",
        ),
    );
    let points_csv = std::fs::read_to_string(run.join("points.csv")).expect("points.csv");
    let run_json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(run.join("run.json")).expect("run.json"))
            .expect("json");

    // CSV: comment lines, then exactly the rows of points.csv.
    let out_csv = dir.path().join("export.csv");
    let o = gonio()
        .arg("export")
        .arg(&run)
        .args(["--format", "csv", "--out"])
        .arg(&out_csv)
        .output()
        .expect("export csv");
    assert!(o.status.success(), "{}", text(&o.stderr));
    let exported = std::fs::read_to_string(&out_csv).expect("export.csv");
    let table: Vec<&str> = exported.lines().filter(|l| !l.starts_with('#')).collect();
    let original: Vec<&str> = points_csv.lines().collect();
    assert_eq!(
        table, original,
        "the exported table is the run's points.csv, value for value"
    );
    let comments: Vec<&str> = exported.lines().filter(|l| l.starts_with('#')).collect();
    let has = |s: &str| comments.iter().any(|l| l.contains(s));
    assert!(
        has("brdf_sr [1/sr]") && has("theta_i_deg [degree]") && has("incident_w [W]") && has("band_nm [nm]")
    );
    assert!(has(&format!(
        "# run.software_version = \"{}\"",
        run_json["software_version"].as_str().expect("version")
    )));
    for device in run_json["devices"].as_array().expect("devices") {
        let identity = device["identity"].as_str().expect("identity");
        assert!(
            has(&identity.replace('"', "\\\"")),
            "device {identity} missing from the CSV provenance"
        );
    }
    let calibrations = run_json["calibrations"].as_array().expect("calibrations").len();
    assert_eq!(
        comments
            .iter()
            .filter(|l| l.starts_with("# run.calibrations["))
            .count(),
        calibrations,
        "one provenance line per calibration reading"
    );
    assert!(has("# run.config.campaign_toml:") && has("#   preset = \"coloured-plastic\""));
    assert!(has("# run.config.instrument_toml:"));
    // The resolved configuration: the preset expanded into the model's parameters.
    assert!(
        has("# resolved.material.ior = 1.49") && has("# resolved.material.model = \"plastic\""),
        "{comments:#?}"
    );

    // JSON: the same points, the run's provenance verbatim, units and the resolved material.
    let o = gonio()
        .arg("export")
        .arg(&run)
        .args(["--format", "json"])
        .output()
        .expect("export json");
    assert!(o.status.success(), "{}", text(&o.stderr));
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).expect("valid JSON on stdout");
    assert_eq!(v["format"], "gonio-points");
    assert_eq!(v["provenance"], run_json, "provenance is run.json as written");
    assert_eq!(v["units"]["brdf_u_sr"], "1/sr");
    assert_eq!(v["units"]["detector_deg"], "degree");
    assert_eq!(v["resolved"]["material"]["model"], "plastic");
    assert_eq!(v["resolved"]["material"]["alpha"], 0.1);
    let points = v["points"].as_array().expect("points");
    assert_eq!(points.len(), original.len() - 1);
    // serde_json's default number parser is not correctly rounded (it may be 1 ulp off without its
    // `float_roundtrip` feature): compare to a few ulps.
    let same = |json: &serde_json::Value, csv: &str| match (json.as_f64(), csv.parse::<f64>().ok()) {
        (None, None) => json.is_null() && csv.is_empty(),
        (Some(a), Some(b)) => (a - b).abs() <= 4.0 * f64::EPSILON * b.abs(),
        _ => false,
    };
    for (p, row) in points.iter().zip(&original[1..]) {
        let r: Vec<&str> = row.split(',').collect();
        assert_eq!(p["index"].as_u64().map(|i| i.to_string()).as_deref(), Some(r[0]));
        assert!(
            same(&p["brdf_sr"], r[9]),
            "row {}: {} vs {}",
            r[0],
            p["brdf_sr"],
            r[9]
        );
        assert!(
            same(&p["brdf_u_sr"], r[10]),
            "row {}: {} vs {}",
            r[0],
            p["brdf_u_sr"],
            r[10]
        );
        assert!(same(&p["readback_deg"]["detector"], r[14]), "row {}", r[0]);
    }

    // The same campaign read from the store (`--data DIR --campaign NAME`) exports the same table.
    let o = gonio()
        .arg("export")
        .args(["--data"])
        .arg(&run)
        .args(["--campaign", "prov", "--format", "csv"])
        .output()
        .expect("export from store");
    assert!(o.status.success(), "{}", text(&o.stderr));
    let from_store = text(&o.stdout);
    let table: Vec<&str> = from_store.lines().filter(|l| !l.starts_with('#')).collect();
    assert_eq!(table, original, "the store and points.csv hold the same points");
    assert!(from_store.contains("# run.config.campaign_toml:"));
}

/// One record of a run, whichever way it is read: `gonio run --out DIR` writes run.json and points.csv from the
/// store it keeps in DIR, and `gonio export --data DIR --campaign NAME` reads that store as a daemon's; both
/// exports of the campaign are the same bytes but for the line naming where they were read from (and the JSON's
/// `source`). A dry-run fills every provenance part: devices, calibrations, timing with a prediction, truth errors.
#[test]
fn a_run_directory_and_its_store_export_byte_identical_provenance() {
    let dir = tempfile::tempdir().expect("tempdir");
    let run = dry_run(
        dir.path(),
        "same",
        &campaign(
            "same",
            "[550.0]",
            "[0.0, 30.0]",
            "[20.0, 50.0]",
            "[0.0, 90.0]",
            "model = \"lambertian\"\nalbedo = 0.5",
        ),
    );
    let export = |source: &[&std::ffi::OsStr], format: &str| -> String {
        let o = gonio()
            .arg("export")
            .args(source)
            .args(["--format", format])
            .output()
            .expect("export");
        assert!(o.status.success(), "{}", text(&o.stderr));
        text(&o.stdout)
    };
    let from_dir = [run.as_os_str()];
    let from_store = [
        std::ffi::OsStr::new("--data"),
        run.as_os_str(),
        std::ffi::OsStr::new("--campaign"),
        std::ffi::OsStr::new("same"),
    ];

    let (a, b) = (export(&from_dir, "csv"), export(&from_store, "csv"));
    let (a_first, a_rest) = a.split_once('\n').expect("lines");
    let (b_first, b_rest) = b.split_once('\n').expect("lines");
    assert!(
        a_first.contains("same") && b_first.contains("gonio.sqlite"),
        "{a_first}\n{b_first}"
    );
    assert_eq!(
        a_rest, b_rest,
        "the CSV exports differ beyond the line naming their source"
    );
    for part in [
        "# run.timing = {\"actual_instrument_s\":",
        "\"predicted_instrument_s\":",
        "# run.truth.against_aperture_average = {\"cos_weighted_relative_rms\":",
        "# run.devices[0] = ",
        "# run.calibrations[0] = ",
        "# run.campaign.created_unix_s = ",
        "#   albedo = 0.5",
    ] {
        assert!(a_rest.contains(part), "the provenance lacks {part:?}:\n{a_rest}");
    }
    assert!(
        !a_rest.contains("wall_s"),
        "wall time is not in the store, so not in run.json"
    );

    let (a, b) = (export(&from_dir, "json"), export(&from_store, "json"));
    let mut a: serde_json::Value = serde_json::from_str(&a).expect("json");
    let mut b: serde_json::Value = serde_json::from_str(&b).expect("json");
    assert_ne!(a["source"], b["source"]);
    a["source"] = serde_json::Value::Null;
    b["source"] = serde_json::Value::Null;
    assert_eq!(
        serde_json::to_string_pretty(&a["provenance"]).expect("text"),
        serde_json::to_string_pretty(&b["provenance"]).expect("text"),
    );
    assert_eq!(a, b, "the JSON exports differ beyond their source");
    // run.json is the record as the store gives it: reading it and writing it again changes no byte.
    let run_json = std::fs::read_to_string(run.join("run.json")).expect("run.json");
    let mut again = serde_json::to_string_pretty(&b["provenance"]).expect("text");
    again.push('\n');
    assert_eq!(run_json, again);
}

/// The MERL export read back with `model = "measured"` reproduces the measurement.
///
/// Two interpolations stand between a measured value and what `gonio brdf eval` returns at its geometry: the
/// export's, piecewise linear between measured nodes, and the format's own, trilinear between MERL cell
/// centres. Both form convex combinations, so the read-back value at a measured geometry must lie within the
/// range of the measured values around it (the point's node and its neighbours in theta_i, theta_o and
/// delta_phi, reciprocal images included): that bound is checked point by point. Beyond it, the relative
/// error is quantified: for a smooth material it is the grid's interpolation error over a MERL cell (a fraction
/// of a percent); at a sharp specular peak it grows with the slope of the lobe across a cell.
#[test]
fn merl_round_trip_reproduces_the_measurement() {
    let dir = tempfile::tempdir().expect("tempdir");
    let cases = [
        ("foam", "preset = \"white-styrofoam\"", 0.01),
        ("plastic", "preset = \"coloured-plastic\"", 0.15),
    ];
    for (id, material, max_rel_allowed) in cases {
        let run = dry_run(
            dir.path(),
            id,
            &campaign(
                id,
                "[550.0]",
                "{ from = 0.0, to = 60.0, step = 20.0 }",
                "{ from = 0.0, to = 80.0, step = 20.0 }",
                "{ from = 0.0, to = 180.0, step = 45.0 }",
                material,
            ),
        );
        let binary = dir.path().join(format!("{id}.binary"));
        let o = gonio()
            .arg("export")
            .arg(&run)
            .args(["--format", "merl", "--out"])
            .arg(&binary)
            .output()
            .expect("export merl");
        assert!(o.status.success(), "{}", text(&o.stderr));
        // The MERL file: header and size of the format, and uncovered cells marked negative.
        let bytes = std::fs::read(&binary).expect("binary");
        assert_eq!(bytes.len(), 12 + 3 * 90 * 90 * 180 * 8);
        assert_eq!(&bytes[..12], &[90, 0, 0, 0, 90, 0, 0, 0, 180, 0, 0, 0]);
        let data = gonio_brdf::merl::MerlData::from_bytes(&bytes, &binary).expect("a valid MERL file");
        let green = data.stored(gonio_brdf::merl::MerlChannel::Green);
        let invalid = green.iter().filter(|v| **v < 0.0).count();
        assert!(invalid > 0 && invalid < green.len(), "{invalid} invalid cells");
        let material = dir.path().join(format!("{id}.material.toml"));
        assert!(material.is_file(), "the companion material file is written");

        let points = measured(&run);
        let geometries: String = points
            .iter()
            .map(|m| {
                format!(
                    "{} {} {} {}\n",
                    m.angles_deg[0], m.angles_deg[1], m.angles_deg[2], m.angles_deg[3]
                )
            })
            .collect();
        let back = eval(&material, 550.0, &geometries);
        assert_eq!(back.len(), points.len());

        // Neighbourhood bound.
        let step = |deg: f64| deg.to_radians() + 1e-6;
        let mut rel = Vec::new();
        for (m, b) in points.iter().zip(&back) {
            let a = iso(m);
            let near = |x: &IsotropicAngles| {
                let pole = a.theta_i < 1e-6 || a.theta_o < 1e-6 || x.theta_i < 1e-6 || x.theta_o < 1e-6;
                (x.theta_i - a.theta_i).abs() <= step(20.0)
                    && (x.theta_o - a.theta_o).abs() <= step(20.0)
                    && (pole || (x.delta_phi - a.delta_phi).abs() <= step(45.0))
            };
            let (lo, hi) = points
                .iter()
                .filter(|n| {
                    let x = iso(n);
                    near(&x) || near(&x.swapped())
                })
                .fold((f64::INFINITY, 0.0f64), |(lo, hi), n| (lo.min(n.f), hi.max(n.f)));
            assert!(
                *b >= lo * (1.0 - 1e-9) && *b <= hi * (1.0 + 1e-9),
                "{id}: read-back {b} at {:?} outside the measured range [{lo}, {hi}] around it (measured {})",
                m.angles_deg,
                m.f
            );
            rel.push((b - m.f).abs() / m.f);
        }
        rel.sort_by(f64::total_cmp);
        let median = rel[rel.len() / 2];
        let max = rel[rel.len() - 1];
        eprintln!(
            "{id}: MERL round trip over {} points: median relative error {median:.2e}, max {max:.2e}",
            rel.len()
        );
        assert!(
            max <= max_rel_allowed,
            "{id}: max relative error {max} above {max_rel_allowed}"
        );
        assert!(
            median <= max_rel_allowed / 5.0,
            "{id}: median relative error {median}"
        );

        // Outside the measured region (theta_o = 85 > 80 degrees) there is no data: the material gives 0.
        let outside = eval(&material, 550.0, "30 180 85 0\n");
        assert_eq!(outside, vec![0.0]);
    }
}

#[test]
fn bad_input_is_refused_with_the_file_and_the_problem() {
    let dir = tempfile::tempdir().expect("tempdir");
    let run = dir.path().join("broken");
    std::fs::create_dir(&run).expect("mkdir");
    std::fs::write(
        run.join("points.csv"),
        "index,band_nm,theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,signal_w,dark_w,incident_w,brdf_sr,brdf_u_sr,flags,t_s\n\
         0,550,30,0,30,180,1,0,1,0.3,0.001,,1\n\
         1,550,30,0,45,180,1,0,1,zero point two,0.001,,2\n",
    )
    .expect("write");
    let check = |args: &[&str], wants: &[&str]| {
        let o: Output = gonio().args(args).output().expect("runs");
        let err = text(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{args:?}: {err}");
        assert!(!err.contains("panicked"), "{err}");
        for w in wants {
            assert!(err.contains(w), "{args:?}: {err:?} lacks {w:?}");
        }
    };
    let run_s = run.to_str().expect("utf8");
    check(
        &["export", run_s, "--format", "csv"],
        &["points.csv, line 3", "brdf_sr", "\"zero point two\""],
    );
    std::fs::write(
        run.join("points.csv"),
        "index,band_nm,theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,signal_w,dark_w,incident_w,brdf_sr,brdf_u_sr,flags,t_s\n\
         0,550,30,0,30,180,1,0,1,0.3,0.001,,1\n",
    )
    .expect("write");
    std::fs::write(run.join("run.json"), "{\"campaign\": [").expect("write");
    check(
        &["export", run_s, "--format", "json"],
        &["run.json", "not valid JSON"],
    );
    std::fs::remove_file(run.join("run.json")).expect("rm");
    check(&["export", run_s, "--format", "merl"], &["--out"]);
    check(
        &["export", "--data", run_s, "--campaign", "1", "--format", "csv"],
        &["no daemon store"],
    );
    let empty = dir.path().join("empty");
    std::fs::create_dir(&empty).expect("mkdir");
    check(
        &["export", empty.to_str().expect("utf8"), "--format", "csv"],
        &["no points.csv"],
    );
}
