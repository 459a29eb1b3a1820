//! End-to-end tests of `gonio brdf eval`: the built binary, fed on stdin.

use std::f64::consts::PI;
use std::io::Write;
use std::process::{Output, Stdio};

use gonio_testkit::gonio;

fn eval(args: &[&str], stdin: &str) -> Output {
    let mut child = gonio()
        .args(["brdf", "eval"])
        .args(args)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("the gonio binary runs");
    let mut input = child.stdin.take().expect("stdin");
    let text = stdin.to_string();
    // Write from a thread so that a large input cannot deadlock against a full stdout pipe.
    let writer = std::thread::spawn(move || {
        let _ = input.write_all(text.as_bytes());
    });
    let out = child.wait_with_output().expect("the gonio binary finishes");
    writer.join().expect("writer");
    out
}

fn values(out: &Output) -> Vec<f64> {
    String::from_utf8(out.stdout.clone())
        .expect("utf8")
        .lines()
        .map(|l| l.parse::<f64>().unwrap_or_else(|_| panic!("not a number: {l:?}")))
        .collect()
}

fn stderr(out: &Output) -> String {
    String::from_utf8_lossy(&out.stderr).into_owned()
}

fn material_file(dir: &tempfile::TempDir, name: &str, text: &str) -> String {
    let path = dir.path().join(name);
    std::fs::write(&path, text).expect("write material");
    path.to_str().expect("utf8 path").to_string()
}

#[test]
fn lambertian_value_is_rho_over_pi_and_below_horizon_is_zero() {
    let dir = tempfile::tempdir().expect("tempdir");
    let file = material_file(
        &dir,
        "white.toml",
        "[material]\nmodel = \"lambertian\"\nalbedo = 0.8\n",
    );
    let out = eval(
        &["--material", &file],
        "# theta_i phi_i theta_o phi_o\n0 0 0 0\n\n  30 10 60 200\n90 0 10 0\n10 0 90 0\n120 0 10 0\n10 0 95 45\n",
    );
    assert!(out.status.success(), "{}", stderr(&out));
    let v = values(&out);
    assert_eq!(v.len(), 6, "one value per data line");
    assert_eq!(v[0], 0.8 / PI);
    assert_eq!(v[1], 0.8 / PI);
    assert_eq!(&v[2..], &[0.0, 0.0, 0.0, 0.0]);
}

#[test]
fn output_round_trips_as_f64() {
    // Conductor values are irrational-looking: each printed value must parse back to the exact f64 the
    // library computes for the same geometry.
    use gonio_brdf::{Brdf, Direction, Material, Wavelength};
    let geometries = [
        (10.0, 0.0, 10.0, 180.0),
        (45.0, 30.0, 50.0, 200.0),
        (70.0, 0.0, 20.0, 90.0),
        (0.0, 0.0, 89.999, 3.0),
    ];
    let input: String = geometries
        .iter()
        .map(|g| format!("{} {} {} {}\n", g.0, g.1, g.2, g.3))
        .collect();
    let out = eval(&["--material", "gold", "--wavelength", "600"], &input);
    assert!(out.status.success(), "{}", stderr(&out));
    let printed = values(&out);
    let gold = Material::preset("gold").expect("preset");
    let wl = Wavelength::from_nm(600.0).expect("wl");
    for (g, p) in geometries.iter().zip(&printed) {
        let f = gold
            .eval(
                &Direction::from_spherical_deg(g.0, g.1),
                &Direction::from_spherical_deg(g.2, g.3),
                wl,
            )
            .expect("in range");
        assert_eq!(f.to_bits(), p.to_bits(), "{g:?}: {f} printed as {p}");
    }
    assert!(
        printed[0] > 1.0,
        "the specular peak of gold is bright: {}",
        printed[0]
    );
}

#[test]
fn malformed_line_names_its_number_and_fails() {
    let out = eval(&["--material", "spectralon"], "0 0 0 0\n# ok\n10 0 abc 0\n");
    assert!(!out.status.success());
    let err = stderr(&out);
    assert!(err.contains("line 3"), "{err}");
    assert!(err.contains("theta_o"), "{err}");
    let out = eval(&["--material", "spectralon"], "0 0 0 0\n1 2 3\n");
    assert!(!out.status.success());
    assert!(stderr(&out).contains("line 2"), "{}", stderr(&out));
}

#[test]
fn missing_file_and_unknown_preset_are_clear_errors() {
    let out = eval(&["--material", "/nonexistent/sample.toml"], "0 0 0 0\n");
    assert!(!out.status.success());
    let err = stderr(&out);
    assert!(
        err.contains("/nonexistent/sample.toml") && err.contains("cannot read"),
        "{err}"
    );
    assert!(!err.contains("panicked"), "{err}");

    let out = eval(&["--material", "velvet"], "0 0 0 0\n");
    assert!(!out.status.success());
    let err = stderr(&out);
    assert!(
        err.contains("velvet") && err.contains("gold") && err.contains("spectralon"),
        "{err}"
    );
}

#[test]
fn bad_material_file_names_line_and_key() {
    let dir = tempfile::tempdir().expect("tempdir");
    let file = material_file(
        &dir,
        "bad.toml",
        "[material]\nmodel = \"lambertian\"\nalbedo = 1.5\n",
    );
    let out = eval(&["--material", &file], "0 0 0 0\n");
    assert!(!out.status.success());
    let err = stderr(&out);
    assert!(
        err.contains("bad.toml") && err.contains("line 3") && err.contains("`albedo`"),
        "{err}"
    );
}

#[test]
fn wavelength_outside_a_table_is_an_error() {
    let out = eval(&["--material", "gold", "--wavelength", "900"], "0 0 0 0\n");
    assert!(!out.status.success());
    let err = stderr(&out);
    assert!(
        err.contains("900") && err.contains("400") && err.contains("700"),
        "{err}"
    );
}

#[test]
fn mirror_prints_zero_and_a_note() {
    let out = eval(&["--material", "mirror"], "30 0 30 180\n0 0 0 0\n");
    assert!(out.status.success(), "{}", stderr(&out));
    assert_eq!(values(&out), vec![0.0, 0.0]);
    let err = stderr(&out);
    assert_eq!(err.matches("note").count(), 1, "{err}");
}

#[test]
fn streams_many_lines() {
    // 200k lines: the output has exactly as many values, each equal to the Lambertian constant.
    let input = "12.5 0 47.25 180\n".repeat(200_000);
    let out = eval(&["--material", "spectralon", "--wavelength", "550"], &input);
    assert!(out.status.success(), "{}", stderr(&out));
    let v = values(&out);
    assert_eq!(v.len(), 200_000);
    assert!(v.iter().all(|&x| x == 0.99 / PI));
}
