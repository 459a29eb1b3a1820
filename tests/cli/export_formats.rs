//! `gonio export` to the formats of other communities, checked from the outside: the Zemax BSDF Data Interchange
//! file by a reader written here from the format's specification (R. Rykowski, "BSDF Data Interchange File
//! Format Specification", Radiant Imaging / Zemax knowledge base), not by gonio's writer; the ASTM table by
//! parsing it and comparing every row with the run's points; and the provenance that every format carries. The
//! RGL export is tests/cli/export_rgl.rs (and tests/mitsuba/, Mitsuba 3 itself reading it).

use std::f64::consts::PI;
use std::path::{Path, PathBuf};

use gonio_results::hemispherical::directional_hemispherical;
use gonio_results::iso::{IsoGrid, IsoPoint};
use gonio_results::run::Run;
use gonio_testkit::cli::dry_run;
use gonio_testkit::{CampaignText, gonio, text};

/// A dry-run on an isotropic grid with reciprocity (the campaign's default) of `material` (a `[material]` body).
fn run(dir: &Path, id: &str, bands: &str, theta_i: &str, material: &str) -> PathBuf {
    let campaign = CampaignText::isotropic_export_grid(id, theta_i)
        .bands(bands)
        .material(material)
        .to_string();
    dry_run(dir, id, &campaign)
}

fn export(run: &Path, args: &[&str]) -> std::process::Output {
    let o = gonio()
        .arg("export")
        .arg(run)
        .args(args)
        .output()
        .expect("gonio export runs");
    assert!(o.status.success(), "export {args:?}: {}", text(&o.stderr));
    o
}

/// One block of a BSDF Data Interchange file.
#[derive(Debug)]
struct Block {
    tis: f64,
    /// One row per scatter azimuth, one value per radial angle.
    rows: Vec<Vec<f64>>,
}

/// A BSDF Data Interchange file as the specification lays it out.
#[derive(Debug)]
struct Bsdf {
    comments: Vec<String>,
    header: Vec<(String, String)>,
    sample_rotation: Vec<f64>,
    incidence: Vec<f64>,
    azimuth: Vec<f64>,
    radial: Vec<f64>,
    blocks: Vec<Block>,
}

/// Reads a Monochrome file: lines starting with `#` are comments; then the keyword lines in the specified
/// order, each list keyword followed by its count and a line enumerating that many values; an empty line; the
/// spectral-content indicator; `DataBegin`; per sample rotation and angle of incidence a `TIS` line and one row
/// per azimuth of one value per radial angle; `DataEnd`.
fn read_bsdf(text: &str) -> Bsdf {
    let comments: Vec<String> = text
        .lines()
        .filter(|l| l.starts_with('#'))
        .map(str::to_string)
        .collect();
    let mut lines = text.lines().filter(|l| !l.starts_with('#'));
    let mut next = || lines.next().expect("the file ends early");
    let mut header = Vec::new();
    for key in ["Source", "Symmetry", "SpectralContent", "ScatterType"] {
        let l = next();
        let mut w = l.split_whitespace();
        assert_eq!(w.next(), Some(key), "line {l:?}");
        header.push((key.to_string(), w.next().expect("a value").to_string()));
    }
    let mut list = |key: &str| -> Vec<f64> {
        let l = next();
        let mut w = l.split_whitespace();
        assert_eq!(w.next(), Some(key), "line {l:?}");
        let n: usize = w.next().expect("a count").parse().expect("an integer count");
        let values: Vec<f64> = next()
            .split_whitespace()
            .map(|v| v.parse().expect("a number"))
            .collect();
        assert_eq!(values.len(), n, "{key}: count and enumeration differ");
        values
    };
    let sample_rotation = list("SampleRotation");
    let incidence = list("AngleOfIncidence");
    let azimuth = list("ScatterAzimuth");
    let radial = list("ScatterRadial");
    assert_eq!(next(), "", "an empty line follows the header");
    assert_eq!(next(), "Monochrome");
    assert_eq!(next(), "DataBegin");
    let mut blocks = Vec::new();
    for _ in 0..sample_rotation.len() * incidence.len() {
        let l = next();
        let tis: f64 = l
            .strip_prefix("TIS ")
            .unwrap_or_else(|| panic!("a TIS line, got {l:?}"))
            .trim()
            .parse()
            .expect("TIS is a number");
        let rows = (0..azimuth.len())
            .map(|_| {
                let row: Vec<f64> = next()
                    .split_whitespace()
                    .map(|v| v.parse().expect("a BSDF value"))
                    .collect();
                assert_eq!(row.len(), radial.len(), "one value per radial angle");
                row
            })
            .collect();
        blocks.push(Block { tis, rows });
    }
    assert_eq!(next(), "DataEnd");
    Bsdf {
        comments,
        header,
        sample_rotation,
        incidence,
        azimuth,
        radial,
        blocks,
    }
}

/// Trapezoid-rule weights (radians) of ascending nodes given in degrees.
fn trapezoid(nodes_deg: &[f64]) -> Vec<f64> {
    (0..nodes_deg.len())
        .map(|k| {
            let lo = if k > 0 {
                nodes_deg[k] - nodes_deg[k - 1]
            } else {
                0.0
            };
            let hi = if k + 1 < nodes_deg.len() {
                nodes_deg[k + 1] - nodes_deg[k]
            } else {
                0.0
            };
            0.5 * (lo + hi).to_radians()
        })
        .collect()
}

/// (integral of BSDF cos(theta_s) d omega, integral of cos(theta_s) d omega where the BSDF is positive) over a
/// block. The radial angle r is measured from the specular direction and the azimuth a about it, 0 pointing
/// towards the sample normal, so the scatter direction's cosine to the normal is
/// cos r cos(AOI) + sin r sin(AOI) cos a; d omega = sin r dr da; the azimuths of a PlaneSymmetrical file cover
/// one half, the other is its mirror image.
fn integrals(file: &Bsdf, block: &Block, aoi_deg: f64) -> (f64, f64) {
    let (wa, wr) = (trapezoid(&file.azimuth), trapezoid(&file.radial));
    let t = aoi_deg.to_radians();
    let (mut tis, mut covered) = (0.0, 0.0);
    for (row, (a, wa)) in block.rows.iter().zip(file.azimuth.iter().zip(&wa)) {
        for (f, (r, wr)) in row.iter().zip(file.radial.iter().zip(&wr)) {
            let (r, a) = (r.to_radians(), a.to_radians());
            let cos_s = r.cos() * t.cos() + r.sin() * t.sin() * a.cos();
            if cos_s <= 0.0 {
                assert_eq!(*f, 0.0, "a value below the horizon (AOI {aoi_deg}, r {r}, a {a})");
                continue;
            }
            let w = 2.0 * cos_s * r.sin() * wa * wr;
            tis += f * w;
            if *f > 0.0 {
                covered += w;
            }
        }
    }
    (tis, covered)
}

/// The run's measured incidences (degrees) and its interpolant, for one band, through gonio's library.
fn gonio_view(run_dir: &Path, band: f64) -> (Vec<f64>, IsoGrid) {
    let r = Run::load(run_dir).expect("the run loads");
    let points: Vec<IsoPoint> = r
        .points
        .iter()
        .filter(|p| (p.band_nm - band).abs() < 0.5)
        .filter_map(IsoPoint::from_point)
        .collect();
    let mut incidences: Vec<f64> = points.iter().map(|p| p.angles.theta_i.to_degrees()).collect();
    incidences.sort_by(f64::total_cmp);
    incidences.dedup_by(|a, b| (*a - *b).abs() < 0.01);
    (incidences, IsoGrid::build(&points))
}

/// The table integral may differ from gonio's hemispherical integral by this share: the table samples a function
/// that stops at the edge of the measured region and of the holes (the retro-reflection), and the trapezoid rule
/// over 1-degree radial and 5-degree azimuth cells errs by up to half a cell along those edges (about 1 % at
/// normal incidence, where the retro hole sits at the specular direction; 0.1 % elsewhere).
const TABLE_TOLERANCE: f64 = 0.02;

#[test]
fn zemax_export_follows_the_format_and_its_tis_is_the_hemispherical_integral() {
    let dir = tempfile::tempdir().expect("tempdir");
    // A glossy sample in two bands: one file per band.
    let plastic = run(
        dir.path(),
        "zplastic",
        "[450.0, 650.0]",
        "[0.0, 30.0, 60.0]",
        "preset = \"coloured-plastic\"",
    );
    let out = dir.path().join("plastic.bsdf");
    let o = gonio()
        .arg("export")
        .arg(&plastic)
        .args(["--format", "zemax", "--out"])
        .arg(&out)
        .output()
        .expect("export");
    assert!(o.status.success(), "{}", text(&o.stderr));
    let written: Vec<String> = text(&o.stdout).lines().map(str::to_string).collect();
    let files = [
        dir.path().join("plastic-450nm.bsdf"),
        dir.path().join("plastic-650nm.bsdf"),
    ];
    assert_eq!(
        written,
        files.iter().map(|f| f.display().to_string()).collect::<Vec<_>>()
    );
    for (file, band) in files.iter().zip([450.0, 650.0]) {
        let bsdf = read_bsdf(&std::fs::read_to_string(file).expect("written"));
        let h = |k: &str| {
            bsdf.header
                .iter()
                .find(|(key, _)| key == k)
                .map(|(_, v)| v.as_str())
        };
        assert_eq!(h("Source"), Some("Measured"));
        assert_eq!(h("Symmetry"), Some("PlaneSymmetrical"));
        assert_eq!(h("SpectralContent"), Some("Monochrome"));
        assert_eq!(h("ScatterType"), Some("BRDF"));
        assert_eq!(bsdf.sample_rotation, vec![0.0]);
        // Plane symmetry: the azimuths span 0 to 180 degrees; the radial angles start at the specular direction.
        assert_eq!(
            (bsdf.azimuth[0], *bsdf.azimuth.last().expect("azimuths")),
            (0.0, 180.0)
        );
        assert_eq!(bsdf.radial[0], 0.0);
        for list in [&bsdf.azimuth, &bsdf.radial, &bsdf.incidence] {
            assert!(list.windows(2).all(|w| w[1] > w[0]), "ascending: {list:?}");
        }
        let (incidences, grid) = gonio_view(&plastic, band);
        assert_eq!(bsdf.incidence.len(), incidences.len());
        for (written, measured) in bsdf.incidence.iter().zip(&incidences) {
            assert!(
                (written - measured).abs() < 1e-4,
                "{written} vs the measured {measured}"
            );
        }
        assert!(bsdf.comments.iter().any(|c| c.contains("NOT MEASURED")));

        for ((block, &aoi), measured) in bsdf.blocks.iter().zip(&bsdf.incidence).zip(&incidences) {
            let (table, covered) = integrals(&bsdf, block, aoi);
            let gonio = directional_hemispherical(&grid, measured.to_radians());
            eprintln!(
                "{band} nm, AOI {aoi}: TIS {} | table integral {table:.6} | gonio {:.6} +- {:.1e} | covered {:.3} sr",
                block.tis, gonio.reflectance.value, gonio.reflectance.error, covered
            );
            assert!(
                (block.tis - table).abs() <= TABLE_TOLERANCE * block.tis,
                "{band} nm, AOI {aoi}: TIS {} but the block integrates to {table}",
                block.tis
            );
            assert!(
                (block.tis - gonio.reflectance.value).abs() <= 1e-6 + gonio.reflectance.error,
                "{band} nm, AOI {aoi}: TIS {} against gonio's hemispherical integral {:?}",
                block.tis,
                gonio.reflectance
            );
            assert!(covered > 0.7 * PI && covered < PI, "covered {covered} sr");
            // The geometry of the angles: the lobe is at radial 0; at AOI 60 the azimuth-0 row (towards the
            // normal) passes the normal at r = 60 and stays above the horizon, the azimuth-180 row leaves the
            // hemisphere at r = 30.
            let peak = block
                .rows
                .iter()
                .flat_map(|row| row.iter().enumerate())
                .max_by(|a, b| a.1.total_cmp(b.1))
                .map(|(k, _)| bsdf.radial[k])
                .expect("values");
            if aoi > 0.0 {
                assert!(peak <= 5.0, "AOI {aoi}: peak at radial {peak}");
            }
            if aoi == 60.0 {
                let at = |a: f64, r: f64| {
                    let i = bsdf.azimuth.iter().position(|x| *x == a).expect("azimuth");
                    let k = bsdf.radial.iter().position(|x| *x == r).expect("radial");
                    block.rows[i][k]
                };
                assert!(at(0.0, 60.0) > 0.0, "the normal is measured");
                assert!(at(180.0, 15.0) > 0.0 && at(180.0, 31.0) == 0.0);
            }
        }
    }

    // A Lambertian sample: the TIS is the albedo times the covered share of the projected solid angle.
    let lambert = run(
        dir.path(),
        "zlambert",
        "[550.0]",
        "[20.0, 50.0]",
        "model = \"lambertian\"\nalbedo = 0.5",
    );
    let out = dir.path().join("lambert.bsdf");
    export(
        &lambert,
        &["--format", "zemax", "--out", out.to_str().expect("utf8")],
    );
    let bsdf = read_bsdf(&std::fs::read_to_string(&out).expect("one band: the named file"));
    for (block, aoi) in bsdf.blocks.iter().zip(&bsdf.incidence) {
        let (table, covered) = integrals(&bsdf, block, *aoi);
        let want = 0.5 / PI * covered;
        eprintln!(
            "lambertian AOI {aoi}: TIS {} table {table} albedo x covered {want}",
            block.tis
        );
        assert!(
            (block.tis - want).abs() < 0.02 * want,
            "AOI {aoi}: {} vs {want}",
            block.tis
        );
    }
}

/// A column of a CSV header.
fn col(header: &[&str], name: &str) -> usize {
    header
        .iter()
        .position(|h| *h == name)
        .unwrap_or_else(|| panic!("no column {name} in {header:?}"))
}

#[test]
fn astm_table_has_every_measurement_and_the_header_the_conventions_ask_for() {
    let dir = tempfile::tempdir().expect("tempdir");
    let plastic = run(
        dir.path(),
        "astm",
        "[450.0, 650.0]",
        "[30.0]",
        "preset = \"coloured-plastic\"",
    );
    let table = text(&export(&plastic, &["--format", "astm"]).stdout);
    let header: Vec<&str> = table.lines().filter(|l| l.starts_with("# ")).collect();
    let value = |key: &str| -> &str {
        header
            .iter()
            .find_map(|l| l.strip_prefix("# ").and_then(|l| l.strip_prefix(key)))
            .and_then(|rest| rest.strip_prefix(": "))
            .unwrap_or_else(|| panic!("no {key} in the header: {header:#?}"))
    };
    assert!(value("sample_coordinate_system").contains("z is the surface normal"));
    // The simulated instrument's detector: a 2.5 mm radius aperture at 250 mm.
    let omega: f64 = value("receiver_solid_angle_sr")
        .split_whitespace()
        .next()
        .expect("a value")
        .parse()
        .expect("a number");
    let want = 2.0 * PI * (1.0 - 250.0 / (250.0f64.powi(2) + 2.5f64.powi(2)).sqrt());
    assert!((omega - want).abs() < 1e-6 * want, "{omega} vs {want}");
    assert!(value("calibration_method").starts_with("absolute"));
    assert!(value("instrument_signature").starts_with("not measured"));
    assert!(value("polarisation").starts_with("unpolarised"));
    assert!(value("uncertainty").contains("k = 2"));
    assert!(value("brdf_definition").contains("1/sr"));

    let rows: Vec<&str> = table.lines().filter(|l| !l.starts_with('#')).collect();
    let cols: Vec<&str> = rows[0].split(',').collect();
    let points = std::fs::read_to_string(plastic.join("points.csv")).expect("points.csv");
    let mut plines = points.lines();
    let pcols: Vec<&str> = plines.next().expect("header").split(',').collect();
    let valid: Vec<Vec<&str>> = plines
        .map(|l| l.split(',').collect::<Vec<_>>())
        .filter(|r| r[col(&pcols, "flags")].is_empty() && !r[col(&pcols, "brdf_sr")].is_empty())
        .collect();
    assert_eq!(rows.len() - 1, valid.len(), "one row per valid measurement");
    let n = |s: &str| s.parse::<f64>().unwrap_or_else(|_| panic!("not a number: {s:?}"));
    for (row, point) in rows[1..].iter().zip(&valid) {
        let r: Vec<&str> = row.split(',').collect();
        assert_eq!(r.len(), cols.len());
        let same =
            |ours: &str, theirs: &str| assert_eq!(n(r[col(&cols, ours)]), n(point[col(&pcols, theirs)]));
        same("index", "index");
        same("theta_i_deg", "theta_i_deg");
        same("phi_i_deg", "phi_i_deg");
        same("theta_r_deg", "theta_o_deg");
        same("phi_r_deg", "phi_o_deg");
        same("wavelength_nm", "band_nm");
        same("brdf_sr", "brdf_sr");
        same("u_brdf_sr", "brdf_u_sr");
        assert_eq!(n(r[col(&cols, "U_brdf_sr")]), 2.0 * n(r[col(&cols, "u_brdf_sr")]));
        // The filter's width as the instrument file states it: the ideal instrument's pass a single wavelength.
        let stated = gonio_instrument::InstrumentFile::simulated()
            .instrument
            .filter_wheel
            .iter()
            .flat_map(|w| &w.positions)
            .find(|p| p.band_nm == Some(n(point[col(&pcols, "band_nm")])))
            .and_then(|p| p.bandwidth_nm);
        assert_eq!(Some(n(r[col(&cols, "bandwidth_nm")])), stated);
        assert_eq!(r[col(&cols, "polarisation")], "unpolarised");
    }
}

#[test]
fn every_export_carries_the_provenance() {
    let dir = tempfile::tempdir().expect("tempdir");
    let r = run(
        dir.path(),
        "prov19",
        "[550.0]",
        "[30.0]",
        "preset = \"white-styrofoam\"",
    );
    let record: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(r.join("run.json")).expect("run.json")).expect("json");
    let instrument_hash = sha256_hex(
        record["config"]["instrument_toml"]
            .as_str()
            .expect("instrument text")
            .as_bytes(),
    );
    let campaign_hash = sha256_hex(
        record["config"]["campaign_toml"]
            .as_str()
            .expect("campaign text")
            .as_bytes(),
    );
    let version = record["software_version"].as_str().expect("version").to_string();
    let run_id = format!("store campaign {}", record["campaign"]["id"]);
    let wants = [
        "prov19".to_string(),
        run_id,
        "simulated".to_string(),
        instrument_hash,
        campaign_hash,
        "absolute, against direct-beam readings".to_string(),
        version,
        "run_created_utc".to_string(),
        // No alignment applied, and every format says so.
        "none applied".to_string(),
    ];
    let check = |format: &str, text: &str| {
        for w in &wants {
            assert!(text.contains(w.as_str()), "{format}: no {w:?} in the provenance");
        }
    };
    for format in ["csv", "astm"] {
        check(format, &text(&export(&r, &["--format", format]).stdout));
    }
    let json: serde_json::Value =
        serde_json::from_slice(&export(&r, &["--format", "json"]).stdout).expect("json");
    check("json", &json["provenance_summary"].to_string());
    let zemax = dir.path().join("p.bsdf");
    export(&r, &["--format", "zemax", "--out", zemax.to_str().expect("utf8")]);
    check("zemax", &std::fs::read_to_string(&zemax).expect("zemax file"));
    let rgl = dir.path().join("p-rgl.bsdf");
    export(&r, &["--format", "rgl", "--out", rgl.to_str().expect("utf8")]);
    check(
        "rgl (description)",
        &String::from_utf8_lossy(&std::fs::read(&rgl).expect("rgl file")),
    );
    let merl = dir.path().join("p.binary");
    export(&r, &["--format", "merl", "--out", merl.to_str().expect("utf8")]);
    check(
        "merl (material file)",
        &std::fs::read_to_string(dir.path().join("p.material.toml")).expect("material file"),
    );
}

/// SHA-256 as lowercase hex, from the sha2 crate (not gonio's code).
fn sha256_hex(data: &[u8]) -> String {
    use sha2::Digest;
    sha2::Sha256::digest(data)
        .iter()
        .map(|b| format!("{b:02x}"))
        .collect()
}
