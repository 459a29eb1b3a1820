//! `gonio fit` end to end: on dry-runs of the seed's materials (config/materials presets, simulated by the
//! instrument simulator with its noise, drift and finite detector aperture) the fit recovers the parameters the
//! simulator used; gross outliers do not move a robust fit (and do move a plain least-squares one); the
//! material file written is accepted by `gonio brdf eval` and by a campaign's `[material]`.
//!
//! Tolerances: the fit averages the model over the detector aperture as the simulator does, so what is left
//! is noise (about 0.1% per point) and the errors common to all points (the direct-beam calibration's, about
//! 2e-4 relative), which the point-to-point scatter cannot reveal. Each parameter must lie within its stated
//! tolerance (about 1% of its value; 2% for eta and k, which trade off against each other) AND within 5 of its
//! reported standard uncertainties plus 5e-4 relative for the common errors: the uncertainties must be honest.

use std::path::{Path, PathBuf};

use gonio_testkit::{CampaignText, cli, gonio, text};
use serde_json::Value;

/// A dry-run on an isotropic grid (theta_i 0-60 by 20, theta_o 0-80 by 10, delta_phi 0-180 by 45).
fn dry_run(dir: &Path, id: &str, bands: &str, material: &str) -> PathBuf {
    let campaign = CampaignText::isotropic(
        id,
        "{ from = 0.0, to = 60.0, step = 20.0 }",
        "{ from = 0.0, to = 80.0, step = 10.0 }",
        "{ from = 0.0, to = 180.0, step = 45.0 }",
    )
    .bands(bands)
    .acquisition("averaging = 10")
    .plan_calibration("dark_every_points = 200")
    .material(material);
    cli::dry_run(dir, id, &campaign.to_string())
}

/// Runs `gonio fit RUN --model M --json [extra]` and returns the JSON report.
fn fit(run: &Path, model: &str, extra: &[&str]) -> Value {
    let o = gonio()
        .arg("fit")
        .arg(run)
        .args(["--model", model, "--json"])
        .args(extra)
        .output()
        .expect("gonio fit");
    assert!(o.status.success(), "gonio fit {model}: {}", text(&o.stderr));
    serde_json::from_slice(&o.stdout).unwrap_or_else(|e| panic!("fit JSON: {e}: {}", text(&o.stdout)))
}

/// The fitted value (and its standard uncertainty) of `key` (at `band_nm` for a spectral parameter).
fn param(report: &Value, key: &str, band_nm: Option<f64>) -> (f64, f64) {
    let p = report["parameters"]
        .as_array()
        .expect("parameters")
        .iter()
        .find(|p| p["key"] == key && p["band_nm"].as_f64() == band_nm)
        .unwrap_or_else(|| panic!("no parameter {key} at {band_nm:?}: {report}"));
    (
        p["value"].as_f64().expect("value"),
        p["std_uncertainty"].as_f64().unwrap_or(f64::NAN),
    )
}

fn assert_close(report: &Value, key: &str, band_nm: Option<f64>, truth: f64, tol: f64) {
    let (v, u) = param(report, key, band_nm);
    eprintln!(
        "{key} @ {band_nm:?}: fitted {v} +- {u:.2e}, truth {truth}, error {:.2e}",
        v - truth
    );
    assert!(
        (v - truth).abs() <= tol,
        "{key} at {band_nm:?}: fitted {v} (u {u}) vs truth {truth}, tolerance {tol}\n{report:#}"
    );
    assert!(u.is_finite() && u > 0.0, "{key}: uncertainty {u}");
    assert!(
        (v - truth).abs() <= 5.0 * u + 5e-4 * truth.abs(),
        "{key} at {band_nm:?}: error {} is not covered by the reported uncertainty {u}",
        v - truth
    );
}

/// Normal-incidence reflectance of a conductor, `((n-1)^2 + k^2) / ((n+1)^2 + k^2)`.
fn r0(eta: f64, k: f64) -> f64 {
    ((eta - 1.0).powi(2) + k * k) / ((eta + 1.0).powi(2) + k * k)
}

#[test]
fn lambertian_recovers_spectralon_albedo() {
    let dir = tempfile::tempdir().expect("tempdir");
    let run = dry_run(
        dir.path(),
        "spectralon",
        "[450.0, 650.0]",
        "preset = \"spectralon\"",
    );
    let r = fit(&run, "lambertian", &[]);
    assert_close(&r, "albedo", Some(450.0), 0.988, 0.001);
    assert_close(&r, "albedo", Some(650.0), 0.989, 0.001);
    assert!(r["residuals"]["cos_weighted_relative_rms"].as_f64().expect("rms") < 0.01);
}

#[test]
fn oren_nayar_recovers_styrofoam_and_paper() {
    let dir = tempfile::tempdir().expect("tempdir");
    let run = dry_run(dir.path(), "foam", "[550.0]", "preset = \"white-styrofoam\"");
    let r = fit(&run, "oren-nayar", &["--wavelength", "550"]);
    assert_close(&r, "sigma_deg", None, 25.0, 0.1);
    assert_close(&r, "albedo", Some(550.0), 0.9, 0.001);

    let run = dry_run(
        dir.path(),
        "paper",
        "[450.0, 650.0]",
        "preset = \"construction-paper\"",
    );
    let r = fit(&run, "oren-nayar", &[]);
    assert_close(&r, "sigma_deg", None, 30.0, 0.1);
    assert_close(&r, "albedo", Some(450.0), 0.06, 0.0005);
    assert_close(&r, "albedo", Some(650.0), 0.52, 0.002);
}

#[test]
fn conductor_recovers_gold() {
    let dir = tempfile::tempdir().expect("tempdir");
    let run = dry_run(dir.path(), "gold", "[450.0, 650.0]", "preset = \"gold\"");
    let r = fit(&run, "conductor", &[]);
    assert_close(&r, "alpha", None, 0.08, 0.0008);
    // eta and k trade off against each other at the angles measured; the reflectance they make is what the
    // data determine: check it at normal incidence, and eta, k themselves loosely.
    for (nm, eta, k) in [(450.0, 1.509, 1.879), (650.0, 0.168, 3.138)] {
        let (fe, _) = param(&r, "eta", Some(nm));
        let (fk, _) = param(&r, "k", Some(nm));
        let (got, want) = (r0(fe, fk), r0(eta, k));
        eprintln!("R0 @ {nm} nm: fitted {got}, truth {want}");
        assert!(
            (got - want).abs() < 0.002,
            "R0 at {nm} nm: {got} vs {want}\n{r:#}"
        );
        assert_close(&r, "eta", Some(nm), eta, 0.02 * eta);
        assert_close(&r, "k", Some(nm), k, 0.02 * k);
    }
}

#[test]
fn plastic_recovers_coloured_plastic_and_the_material_file_is_accepted() {
    let dir = tempfile::tempdir().expect("tempdir");
    let run = dry_run(
        dir.path(),
        "plastic",
        "[450.0, 650.0]",
        "preset = \"coloured-plastic\"",
    );
    let r = fit(&run, "plastic", &[]);
    assert_close(&r, "alpha", None, 0.1, 0.001);
    assert_close(&r, "ior", None, 1.49, 0.005);
    assert_close(&r, "albedo", Some(450.0), 0.45, 0.002);
    assert_close(&r, "albedo", Some(650.0), 0.04, 0.0005);

    // The material file: `gonio brdf eval` reads it and agrees with the preset it was measured from.
    let file = PathBuf::from(r["material_file"].as_str().expect("material_file"));
    assert_eq!(file, run.join("fit-plastic.toml"));
    let eval = |material: &str, nm: &str| -> f64 {
        let mut child = gonio()
            .args(["brdf", "eval", "--material", material, "--wavelength", nm])
            .stdin(std::process::Stdio::piped())
            .stdout(std::process::Stdio::piped())
            .spawn()
            .expect("eval");
        use std::io::Write;
        child
            .stdin
            .take()
            .expect("stdin")
            .write_all(b"30 180 30 0\n30 0 50 60\n")
            .expect("write");
        let o = child.wait_with_output().expect("eval output");
        assert!(o.status.success());
        let v: Vec<f64> = text(&o.stdout)
            .lines()
            .map(|l| l.parse().expect("number"))
            .collect();
        v[0] + v[1]
    };
    let path = file.to_str().expect("utf8");
    for nm in ["450", "650"] {
        let (fitted, truth) = (eval(path, nm), eval("coloured-plastic", nm));
        assert!(
            (fitted - truth).abs() <= 0.03 * truth,
            "{nm} nm: {fitted} vs {truth}"
        );
    }
    // A campaign accepts the file's [material] table as its simulated sample.
    let material = std::fs::read_to_string(&file).expect("material file");
    let table = material.split("[material]").nth(1).expect("a [material] table");
    let campaign = format!(
        "[campaign]\nid = \"refit\"\n[sample]\nradius_mm = 12.5\n[plan]\nbands_nm = [450.0]\n[plan.grid]\n\
         kind = \"points\"\npoints = [[30.0, 180.0, 30.0, 0.0]]\n[material]{table}"
    );
    let cfile = dir.path().join("refit.toml");
    std::fs::write(&cfile, campaign).expect("write");
    let o = gonio()
        .arg("run")
        .arg(&cfile)
        .arg("--out")
        .arg(dir.path().join("refit"))
        .arg("--quiet")
        .output()
        .expect("run");
    assert!(
        o.status.success(),
        "the fitted material in a campaign: {}",
        text(&o.stderr)
    );
}

#[test]
fn phong_recovers_its_parameters() {
    let dir = tempfile::tempdir().expect("tempdir");
    let material = "model = \"phong\"\ndiffuse = 0.3\nspecular = 0.4\nexponent = 60.0";
    let run = dry_run(dir.path(), "phong", "[550.0]", material);
    let r = fit(&run, "phong", &[]);
    assert_close(&r, "diffuse", Some(550.0), 0.3, 0.002);
    assert_close(&r, "specular", Some(550.0), 0.4, 0.004);
    assert_close(&r, "exponent", None, 60.0, 0.6);
}

/// Copies a run directory, multiplying the BRDF of every `every`-th valid point by `factor` (its value and the
/// aperture average beside it: a reading that was wrong is wrong in both, and a fit reads the average).
fn corrupt(run: &Path, to: &Path, every: usize, factor: f64) -> usize {
    std::fs::create_dir_all(to).expect("mkdir");
    std::fs::copy(run.join("run.json"), to.join("run.json")).expect("copy run.json");
    let csv = std::fs::read_to_string(run.join("points.csv")).expect("points.csv");
    let mut out = String::new();
    let mut n = 0;
    let mut changed = 0;
    for (i, line) in csv.lines().enumerate() {
        let mut r: Vec<String> = line.split(',').map(str::to_string).collect();
        if i > 0 && r[11].is_empty() && !r[9].is_empty() {
            if n % every == 0 {
                for column in [9, 17] {
                    if let Some(f) = r.get(column).and_then(|v| v.parse::<f64>().ok()) {
                        r[column] = format!("{}", f * factor);
                    }
                }
                changed += 1;
            }
            n += 1;
        }
        out.push_str(&r.join(","));
        out.push('\n');
    }
    std::fs::write(to.join("points.csv"), out).expect("write");
    changed
}

#[test]
fn outliers_do_not_pull_a_robust_fit() {
    let dir = tempfile::tempdir().expect("tempdir");
    let run = dry_run(dir.path(), "foam", "[550.0]", "preset = \"white-styrofoam\"");
    let bad = dir.path().join("foam-outliers");
    // One point in ten reads five times too high (a stray reflection, a mis-set range).
    let changed = corrupt(&run, &bad, 10, 5.0);
    assert!(changed >= 5, "{changed} outliers");
    let robust = fit(&bad, "oren-nayar", &[]);
    assert_close(&robust, "sigma_deg", None, 25.0, 0.1);
    assert_close(&robust, "albedo", Some(550.0), 0.9, 0.001);
    let down = robust["residuals"]["downweighted"]
        .as_u64()
        .expect("downweighted") as usize;
    assert!(down >= changed, "only {down} of {changed} outliers down-weighted");
    // The same data by plain least squares: the outliers drag the albedo up (the test can fail).
    let plain = fit(&bad, "oren-nayar", &["--loss", "none"]);
    let (albedo, _) = param(&plain, "albedo", Some(550.0));
    assert!(
        albedo > 0.95,
        "plain least squares should be pulled by the outliers: albedo {albedo}"
    );
}

#[test]
fn bad_requests_are_refused_with_reasons() {
    let dir = tempfile::tempdir().expect("tempdir");
    let run = dry_run(dir.path(), "one", "[550.0]", "preset = \"white-styrofoam\"");
    let o = gonio()
        .arg("fit")
        .arg(&run)
        .args(["--model", "lambertian", "--wavelength", "700"])
        .output()
        .expect("fit");
    assert_eq!(o.status.code(), Some(2));
    let err = text(&o.stderr);
    assert!(
        err.contains("no valid points at 700 nm") && err.contains("550 nm"),
        "{err}"
    );
    let o = gonio()
        .arg("fit")
        .arg(&run)
        .args(["--model", "mirror"])
        .output()
        .expect("fit");
    assert_eq!(o.status.code(), Some(2));
    assert!(text(&o.stderr).contains("mirror"));
}

/// What the points share is propagated apart (gonio_results::fit's shared module): spectralon on the ideal
/// instrument with its solid angle stated to 0.1 % (`solid_angle_u`), an error every point of the campaign
/// shares, and each band's normalisation. The points' scatter alone pins the albedo to a few parts per million;
/// the shared part is the solid angle's 0.1 % of the albedo, and the truth lies within the combined k = 2
/// interval.
#[test]
fn the_shared_uncertainty_covers_what_the_scatter_cannot_see() {
    let dir = tempfile::tempdir().expect("tempdir");
    let instrument = dir.path().join("instrument.toml");
    let stated =
        gonio_instrument::SIMULATED_INSTRUMENT_TOML.replace("solid_angle_u = 0.0", "solid_angle_u = 1.0e-3");
    assert!(stated.contains("solid_angle_u = 1.0e-3"));
    std::fs::write(&instrument, stated).expect("instrument");
    let campaign = CampaignText::isotropic(
        "spectralon",
        "{ from = 0.0, to = 60.0, step = 20.0 }",
        "{ from = 0.0, to = 80.0, step = 10.0 }",
        "{ from = 0.0, to = 180.0, step = 45.0 }",
    )
    .bands("[550.0]")
    .acquisition("averaging = 10")
    .material("preset = \"spectralon\"");
    let file = dir.path().join("spectralon.toml");
    std::fs::write(&file, campaign.to_string()).expect("campaign");
    let run = dir.path().join("spectralon");
    let o = cli::quiet_run(&file, &run)
        .arg("--instrument")
        .arg(&instrument)
        .output()
        .expect("gonio run");
    assert!(o.status.success(), "{}", text(&o.stderr));
    let report = fit(&run, "lambertian", &[]);
    let p = &report["parameters"][0];
    assert_eq!(p["key"], "albedo");
    let (v, u) = (
        p["value"].as_f64().expect("value"),
        p["std_uncertainty"].as_f64().expect("u"),
    );
    let shared = p["shared_uncertainty"].as_f64().expect("a shared uncertainty");
    eprintln!("albedo {v} +- {u:.2e} (independent) +- {shared:.2e} (shared)");
    assert!((0.0008..0.0015).contains(&(shared / v)), "shared {shared} of {v}");
    assert!(shared > 20.0 * u, "the shared part dominates: {shared} vs {u}");
    assert!((v - 0.99).abs() <= 2.0 * u.hypot(shared), "{v} vs 0.99");
    // The chi2 is against the independent part only, and says what it means.
    let o = gonio()
        .arg("fit")
        .arg(&run)
        .args(["--model", "lambertian"])
        .output()
        .expect("fit");
    let printed = text(&o.stdout);
    assert!(
        printed.contains("u shared") && printed.contains("against the points' independent"),
        "{printed}"
    );
}
