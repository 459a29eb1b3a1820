//! `gonio export --format rgl` from the outside: the tensor file read by a reader written here from the layout
//! Mitsuba 3's and pbrt-v4's readers parse, with the field structure they check and the values of gonio's
//! interpolant; read back as a material (`[material] model = "measured"`, `format = "rgl"`) it reproduces the
//! run's interpolant; and used as a dry-run's sample and exported again, it round-trips. (Mitsuba 3 itself
//! reading the file, and gonio's reader agreeing with Mitsuba's on a file with a non-identity warp:
//! tests/mitsuba/.)

use std::f64::consts::PI;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::Stdio;

use gonio_brdf::geometry::IsotropicAngles;
use gonio_results::iso::{IsoGrid, IsoPoint};
use gonio_results::run::Run;
use gonio_testkit::cli::dry_run;
use gonio_testkit::rng::XorShift;
use gonio_testkit::{CampaignText, gonio, text};

/// A dry-run on an isotropic grid of `material` (a `[material]` body).
fn run(dir: &Path, id: &str, bands: &str, theta_i: &str, material: &str) -> PathBuf {
    let campaign = CampaignText::isotropic_export_grid(id, theta_i)
        .bands(bands)
        .material(material)
        .to_string();
    dry_run(dir, id, &campaign)
}

/// `gonio export RUN --format rgl --out OUT`.
fn export_rgl(run: &Path, out: &Path) {
    let o = gonio()
        .arg("export")
        .arg(run)
        .args(["--format", "rgl", "--out"])
        .arg(out)
        .output()
        .expect("gonio export runs");
    assert!(o.status.success(), "export rgl: {}", text(&o.stderr));
}

/// One band's interpolant of a run, through gonio's library.
fn interpolant(run_dir: &Path, band: f64) -> IsoGrid {
    let r = Run::load(run_dir).expect("the run loads");
    let points: Vec<IsoPoint> = r
        .points
        .iter()
        .filter(|p| (p.band_nm - band).abs() < 0.5)
        .filter_map(IsoPoint::from_point)
        .collect();
    IsoGrid::build(&points)
}

/// A field of a tensor file: type code, shape, data bytes.
struct TensorField {
    dtype: u8,
    shape: Vec<usize>,
    data: Vec<u8>,
}

/// Reads a tensor file as Mitsuba 3's and pbrt-v4's readers do: `tensor_file\0`, version 1.0, a u32 field
/// count, then per field a u16 name length, the name, u16 rank, u8 type, u64 offset and u64 extents.
fn read_tensor_file(bytes: &[u8]) -> std::collections::HashMap<String, TensorField> {
    assert_eq!(&bytes[..12], b"tensor_file\0");
    assert_eq!(&bytes[12..14], &[1, 0], "version 1.0");
    let mut at = 14;
    let mut take = |n: usize| {
        let s = &bytes[at..at + n];
        at += n;
        s
    };
    let u = |s: &[u8]| s.iter().rev().fold(0u64, |acc, b| (acc << 8) | u64::from(*b));
    let count = u(take(4));
    let mut fields = std::collections::HashMap::new();
    for _ in 0..count {
        let name_len = u(take(2)) as usize;
        let name = String::from_utf8(take(name_len).to_vec()).expect("a UTF-8 name");
        let ndim = u(take(2)) as usize;
        let dtype = take(1)[0];
        let offset = u(take(8)) as usize;
        let shape: Vec<usize> = (0..ndim).map(|_| u(take(8)) as usize).collect();
        let size = match dtype {
            1 => 1,
            10 => 4,
            other => panic!("{name}: unexpected type {other}"),
        } * shape.iter().product::<usize>();
        fields.insert(
            name,
            TensorField {
                dtype,
                shape,
                data: bytes[offset..offset + size].to_vec(),
            },
        );
    }
    fields
}

fn floats(f: &TensorField) -> Vec<f32> {
    assert_eq!(f.dtype, 10, "float32");
    f.data
        .chunks_exact(4)
        .map(|c| f32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect()
}

#[test]
fn rgl_export_has_the_fields_the_renderers_check_and_gonio_values() {
    let dir = tempfile::tempdir().expect("tempdir");
    let plastic = run(
        dir.path(),
        "rgl",
        "[450.0, 650.0]",
        "[0.0, 30.0, 60.0]",
        "preset = \"coloured-plastic\"",
    );
    let out = dir.path().join("plastic.bsdf");
    export_rgl(&plastic, &out);
    let fields = read_tensor_file(&std::fs::read(&out).expect("written"));
    let f = |name: &str| fields.get(name).unwrap_or_else(|| panic!("no field {name}"));
    // The structure Mitsuba 3's `measured` plugin and pbrt-v4's MeasuredBRDF::Create require.
    let (theta_i, phi_i, wavelengths) = (floats(f("theta_i")), floats(f("phi_i")), floats(f("wavelengths")));
    assert_eq!((f("description").dtype, f("description").shape.len()), (1, 1));
    assert_eq!((f("jacobian").dtype, f("jacobian").shape.clone()), (1, vec![1]));
    assert_eq!(f("ndf").shape.len(), 2);
    assert_eq!(f("sigma").shape.len(), 2);
    let spectra = f("spectra");
    assert_eq!(spectra.shape.len(), 5);
    assert_eq!(
        spectra.shape[..3],
        [phi_i.len(), theta_i.len(), wavelengths.len()]
    );
    assert_eq!(spectra.shape[3], spectra.shape[4]);
    for name in ["vndf", "luminance"] {
        assert_eq!(f(name).shape[..2], [phi_i.len(), theta_i.len()], "{name}");
        assert_eq!(f(name).shape[2..], spectra.shape[3..], "{name}");
    }
    assert_eq!(phi_i, vec![0.0], "isotropic: one phi_i");
    assert_eq!(wavelengths, vec![450.0, 650.0]);
    assert!(theta_i.windows(2).all(|w| w[1] > w[0]));
    let description = String::from_utf8(f("description").data.clone()).expect("UTF-8 description");
    assert!(description.contains("NOT MEASURED") && description.contains("provenance.instrument: simulated"));

    // The values: f cos(theta_o) of gonio's interpolant at the half-vector nodes,
    // u = (sqrt(theta_m / (pi/2)), (phi_m - phi_i + pi) / (2 pi)), for wi at (theta_i, 0) and wo its mirror
    // image about the half vector; at a node without a value that shares a bilinear cell with one that has a
    // value (the guard band, as the module documents), the interpolant's value at the nearest point of the
    // measured region within 15 degrees of node moves; 0 elsewhere.
    let n = spectra.shape[3];
    let values = floats(spectra);
    let geometry = |ti: f64, x: usize, y: usize| -> Option<(IsotropicAngles, f64)> {
        let wi = [ti.sin(), 0.0, ti.cos()];
        let (ux, uy) = (x as f64 / (n - 1) as f64, y as f64 / (n - 1) as f64);
        let (tm, pm) = (ux * ux * PI / 2.0, (2.0 * uy - 1.0) * PI);
        let m = [tm.sin() * pm.cos(), tm.sin() * pm.sin(), tm.cos()];
        let c: f64 = (0..3).map(|k| wi[k] * m[k]).sum();
        let wo: Vec<f64> = (0..3).map(|k| 2.0 * c * m[k] - wi[k]).collect();
        if c <= 0.0 || wo[2] <= 0.0 {
            return None;
        }
        // The isotropic angles, written out: theta of each, |phi_o - phi_i| folded into [0, pi].
        let angles = IsotropicAngles {
            theta_i: ti,
            theta_o: wo[2].clamp(-1.0, 1.0).acos(),
            delta_phi: wo[1].atan2(wo[0]).abs(),
        };
        Some((angles, wo[2]))
    };
    for (b, band) in [450.0, 650.0].into_iter().enumerate() {
        let grid = interpolant(&plastic, band);
        let (mut measured, mut guard) = (0, 0);
        for (t, ti) in theta_i.iter().enumerate() {
            let ti = f64::from(*ti);
            let strict: Vec<Option<f64>> = (0..n * n)
                .map(|k| {
                    geometry(ti, k % n, k / n).and_then(|(a, cos)| grid.eval(&a).map(|f| f.max(0.0) * cos))
                })
                .collect();
            for (y, x) in (0..n).flat_map(|y| (0..n).map(move |x| (y, x))) {
                let beside = (y.saturating_sub(1)..=(y + 1).min(n - 1)).any(|yy| {
                    (x.saturating_sub(1)..=(x + 1).min(n - 1)).any(|xx| strict[yy * n + xx].is_some())
                });
                let want = match strict[y * n + x] {
                    Some(v) => {
                        measured += 1;
                        v
                    }
                    None if beside => geometry(ti, x, y)
                        .and_then(|(a, cos)| grid.eval_held(&a, 15f64.to_radians()).map(|f| f.max(0.0) * cos))
                        .inspect(|_| guard += 1)
                        .unwrap_or(0.0),
                    None => 0.0,
                };
                let stored = f64::from(values[((t * 2 + b) * n + y) * n + x]);
                assert!(
                    (stored - want).abs() <= 1e-6 * want.abs().max(1e-3),
                    "{band} nm, theta_i {ti}, node ({x}, {y}): {stored} vs {want}"
                );
            }
        }
        assert!(
            measured > 1000 && guard > 100,
            "{band} nm: only {measured} measured and {guard} guard nodes compared"
        );
    }
}

/// `gonio brdf eval` with `source` (`--material FILE` or `--run DIR`) at these geometries (degrees), 550 nm.
fn eval(source: &[&std::ffi::OsStr], geometries: &[[f64; 4]]) -> Vec<f64> {
    let mut child = gonio()
        .args(["brdf", "eval", "--wavelength", "550"])
        .args(source)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("gonio brdf eval");
    let input: String = geometries
        .iter()
        .map(|g| format!("{} {} {} {}\n", g[0], g[1], g[2], g[3]))
        .collect();
    let mut stdin = child.stdin.take().expect("stdin");
    let writer = std::thread::spawn(move || {
        let _ = stdin.write_all(input.as_bytes());
    });
    let out = child.wait_with_output().expect("eval finishes");
    writer.join().expect("writer");
    assert!(out.status.success(), "eval {source:?}: {}", text(&out.stderr));
    text(&out.stdout)
        .lines()
        .map(|l| l.parse::<f64>().expect("a number per line"))
        .collect()
}

/// A material file reading an RGL file.
fn rgl_material(dir: &Path, name: &str, file: &Path) -> PathBuf {
    let path = dir.join(format!("{name}.toml"));
    std::fs::write(
        &path,
        format!(
            "[material]\nmodel = \"measured\"\nformat = \"rgl\"\nfile = \"{}\"\n",
            file.display()
        ),
    )
    .expect("write the material file");
    path
}

/// Sorted relative differences of `b` from `a` where `a` has a positive value.
fn differences(a: &[f64], b: &[f64]) -> Vec<f64> {
    let mut rel: Vec<f64> = a
        .iter()
        .zip(b)
        .filter(|(x, _)| x.is_finite() && **x > 0.0)
        .map(|(x, y)| (y - x).abs() / x)
        .collect();
    rel.sort_by(f64::total_cmp);
    rel
}

fn quantile(sorted: &[f64], q: f64) -> f64 {
    sorted[((q * sorted.len() as f64) as usize).min(sorted.len() - 1)]
}

/// Checks a sorted list of relative differences: its median and 80th percentile. The export's resampling
/// tolerance, as stated in tests/mitsuba/rgl_mitsuba.py, is a median below 1 % and 80 % of the pairs within 3 %
/// (the largest differences sit at the edge of the measured region).
fn within_tolerance(what: &str, rel: &[f64], median_max: f64, q80_max: f64) {
    assert!(rel.len() > 150, "{what}: only {} pairs with a value", rel.len());
    let (median, q80, q95) = (quantile(rel, 0.5), quantile(rel, 0.8), quantile(rel, 0.95));
    eprintln!(
        "{what}: {} pairs, relative difference median {median:.2e}, 80th percentile {q80:.2e}, 95th {q95:.2e}",
        rel.len()
    );
    assert!(
        median <= median_max && q80 <= q80_max,
        "{what}: median {median}, 80th percentile {q80}"
    );
}

#[test]
fn an_rgl_file_read_back_as_a_material_reproduces_the_run_and_round_trips() {
    let dir = tempfile::tempdir().expect("tempdir");
    let first = run(
        dir.path(),
        "first",
        "[550.0]",
        "{ from = 0.0, to = 60.0, step = 10.0 }",
        "preset = \"coloured-plastic\"",
    );
    let a = dir.path().join("first.bsdf");
    export_rgl(&first, &a);
    let material_a = rgl_material(dir.path(), "first-rgl", &a);

    // Random pairs of directions: incidence within the measured 0..60 degrees, outgoing up to 80.
    let mut rng = XorShift::new(19);
    let geometries: Vec<[f64; 4]> = (0..500)
        .map(|_| {
            [
                60.0 * rng.uniform(),
                360.0 * rng.uniform() - 180.0,
                80.0 * rng.uniform(),
                360.0 * rng.uniform() - 180.0,
            ]
        })
        .collect();
    let from_run = eval(&["--run".as_ref(), first.as_os_str()], &geometries);
    let from_a = eval(&["--material".as_ref(), material_a.as_os_str()], &geometries);

    within_tolerance(
        "RGL read back against the run",
        &differences(&from_run, &from_a),
        0.01,
        0.03,
    );
    // At the measured geometries themselves (those a second run measures): there the interpolant has its kinks
    // and the edges of the measured region and of the retro-reflection hole run through them, so this is where
    // the file's bilinear cells differ most from it (before the guard band: 80th percentile 7.7 %, 95th 42 %).
    let nodes: Vec<[f64; 4]> = Run::load(&first)
        .expect("the run loads")
        .points
        .iter()
        .filter(|p| p.brdf_sr.is_some())
        .map(|p| [p.theta_i_deg, p.phi_i_deg, p.theta_o_deg, p.phi_o_deg])
        .collect();
    within_tolerance(
        "RGL read back against the run at the measured geometries",
        &differences(
            &eval(&["--run".as_ref(), first.as_os_str()], &nodes),
            &eval(&["--material".as_ref(), material_a.as_os_str()], &nodes),
        ),
        0.01,
        0.03,
    );

    // The RGL material as a dry-run's sample, measured on the same plan and exported again.
    let second = run(
        dir.path(),
        "second",
        "[550.0]",
        "{ from = 0.0, to = 60.0, step = 10.0 }",
        &format!(
            "model = \"measured\"\nformat = \"rgl\"\nfile = \"{}\"",
            a.display()
        ),
    );
    let b = dir.path().join("second.bsdf");
    export_rgl(&second, &b);
    let material_b = rgl_material(dir.path(), "second-rgl", &b);
    let from_b = eval(&["--material".as_ref(), material_b.as_os_str()], &geometries);
    // The second run measures the first file at the same nodes (aperture-averaged, with the instrument's noise)
    // and its export resamples that again. Measured here: median 0.74 %, 80th percentile 1.6 %, 95th 3.3 %,
    // mostly the first file's bilinear cells smoothing the interpolant's kinks at the nodes the second run
    // measures (checked above); the second run's aperture averaging of the file adds 0.2 % and its noise 0.09 %
    // at the 80th percentile. Before the export's guard band (crates/results/src/rgl.rs) the file was up to 58 %
    // low at measured nodes beside the retro-reflection hole and the round trip missed this tolerance (median
    // 1.1 %, 80th percentile 3.5 %). The export's stated tolerance: median 1 %, 80 % of the pairs within 3 %.
    within_tolerance(
        "RGL re-measured and re-exported against the first",
        &differences(&from_a, &from_b),
        0.01,
        0.03,
    );
}
