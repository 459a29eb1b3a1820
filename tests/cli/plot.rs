//! `gonio plot` end to end: the SVG is well-formed XML (parsed by roxmltree) and holds the expected panels and
//! series: one polar panel per band with one curve per incidence angle, one heat map per incidence, and with a
//! model its curves and a measured-against-model panel. Checked through the SVG's text and elements, not its
//! pixels.

use std::path::{Path, PathBuf};

use gonio_testkit::{CampaignText, cli, gonio, text};

/// `gonio report`'s tests share this target and its dry-run.
mod report;

/// A dry-run of coloured plastic at two bands on an isotropic grid (3 incidences, 6 outgoing angles, 3 azimuths).
fn dry_run(dir: &Path) -> PathBuf {
    let campaign = CampaignText::isotropic(
        "plotted",
        "[0.0, 30.0, 60.0]",
        "{ from = 0.0, to = 75.0, step = 15.0 }",
        "[0.0, 90.0, 180.0]",
    )
    .bands("[450.0, 650.0]")
    .acquisition("averaging = 10");
    cli::dry_run(dir, "plotted", &campaign.to_string())
}

/// All text content of the SVG, one string per <text> element; panics unless it is well-formed SVG.
fn svg_texts(svg: &str) -> (Vec<String>, usize, usize) {
    let doc = roxmltree::Document::parse(svg).unwrap_or_else(|e| panic!("not well-formed XML: {e}"));
    let root = doc.root_element();
    assert_eq!(root.tag_name().name(), "svg");
    let texts = root
        .descendants()
        .filter(|n| n.has_tag_name("text"))
        .map(|n| {
            let t: String = n
                .descendants()
                .filter(|d| d.is_text())
                .filter_map(|d| d.text())
                .collect();
            t.trim().to_string()
        })
        .collect();
    let polylines = root.descendants().filter(|n| n.has_tag_name("polyline")).count();
    let circles = root.descendants().filter(|n| n.has_tag_name("circle")).count();
    (texts, polylines, circles)
}

#[test]
fn svg_is_well_formed_and_holds_every_series() {
    let dir = tempfile::tempdir().expect("tempdir");
    let run = dry_run(dir.path());
    let o = gonio().arg("plot").arg(&run).output().expect("plot");
    assert!(o.status.success(), "{}", text(&o.stderr));
    let path = run.join("plot.svg");
    assert_eq!(text(&o.stdout).trim(), path.display().to_string());
    let svg = std::fs::read_to_string(&path).expect("plot.svg");
    let (texts, polylines, circles) = svg_texts(&svg);
    let has = |s: &str| texts.iter().any(|t| t == s);
    // Incidences: the planned 0, 30, 60 and, by reciprocity, every theta_o measured at an incidence (15..75).
    let incidences = [0, 15, 30, 45, 60, 75];
    for band in [450, 650] {
        assert!(has(&format!("in-plane slices, {band} nm (plotted)")), "{texts:?}");
    }
    for ti in incidences {
        // A legend entry per incidence in each of the two polar panels.
        let label = format!("theta_i = {ti} deg");
        assert_eq!(
            texts.iter().filter(|t| **t == label).count(),
            2,
            "{label}: {texts:?}"
        );
        // A heat map per incidence, in the band nearest 550 nm (450 and 650 are as near: the first).
        assert!(
            texts
                .iter()
                .any(|t| t.starts_with(&format!("theta_i = {ti} deg, 450 nm: BRDF "))),
            "heat map {ti}: {texts:?}"
        );
    }
    assert!(has("phi_o - phi_i (deg)") && has("theta_o (deg)"));
    // Every heat map has its colour scale: a labelled bar whose ticks are BRDF values within the map's range.
    assert_eq!(
        texts.iter().filter(|t| *t == "BRDF (1/sr)").count(),
        incidences.len(),
        "{texts:?}"
    );
    for ti in incidences {
        let caption = texts
            .iter()
            .find(|t| t.starts_with(&format!("theta_i = {ti} deg, 450 nm: BRDF ")))
            .expect("caption");
        // "... BRDF 1.23e-2..4.56e1 1/sr (log colour)"
        let range = caption
            .split("BRDF ")
            .nth(1)
            .and_then(|r| r.split(' ').next())
            .expect("range");
        let (lo, hi) = range.split_once("..").expect("lo..hi");
        let (lo, hi): (f64, f64) = (lo.parse().expect("lo"), hi.parse().expect("hi"));
        assert!(lo > 0.0 && hi >= lo, "{caption}");
    }
    let ticks: Vec<f64> = texts
        .iter()
        .filter(|t| t.contains('e') && t.parse::<f64>().is_ok())
        .filter_map(|t| t.parse().ok())
        .collect();
    assert!(ticks.len() >= 2 * incidences.len(), "colour-bar ticks: {texts:?}");
    assert!(ticks.iter().all(|v| *v > 0.0 && v.is_finite()), "{ticks:?}");
    // Each curve is a polyline (plus the rings and spokes of the polar grids); each measured node a circle.
    assert!(polylines >= 2 * incidences.len(), "{polylines} polylines");
    assert!(circles >= 2 * 20, "{circles} circles");
    assert!(!texts.iter().any(|t| t.contains("model")), "no model requested");

    // With a model: its curves, one legend entry for them per band, and the comparison panel; compared with the
    // same plot without the model (the heat maps' colour bars have ticks, so the band must be the same).
    let base = dir.path().join("band-650.svg");
    let o = gonio()
        .arg("plot")
        .arg(&run)
        .args(["--band", "650", "--out"])
        .arg(&base)
        .output()
        .expect("plot at 650 nm");
    assert!(o.status.success(), "{}", text(&o.stderr));
    let (_, polylines, _) = svg_texts(&std::fs::read_to_string(&base).expect("svg"));
    let out = dir.path().join("with-model.svg");
    let o = gonio()
        .arg("plot")
        .arg(&run)
        .args(["--model", "coloured-plastic", "--band", "650", "--out"])
        .arg(&out)
        .output()
        .expect("plot with model");
    assert!(o.status.success(), "{}", text(&o.stderr));
    let svg = std::fs::read_to_string(&out).expect("svg");
    let (texts, polylines_m, _) = svg_texts(&svg);
    let has = |s: &str| texts.iter().any(|t| t == s);
    assert_eq!(
        texts.iter().filter(|t| *t == "model (lines)").count(),
        2,
        "{texts:?}"
    );
    assert!(has("measured vs model (coloured-plastic)") && has("1:1") && has("450 nm") && has("650 nm"));
    assert!(
        texts
            .iter()
            .any(|t| t.starts_with("theta_i = 30 deg, 650 nm: BRDF ")),
        "--band 650: {texts:?}"
    );
    assert!(
        polylines_m >= polylines + 2 * incidences.len(),
        "{polylines_m} vs {polylines}"
    );
}

#[test]
fn a_run_without_valid_points_is_refused() {
    let dir = tempfile::tempdir().expect("tempdir");
    let run = dir.path().join("nothing");
    std::fs::create_dir(&run).expect("mkdir");
    std::fs::write(
        run.join("points.csv"),
        "index,band_nm,theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg,signal_w,dark_w,incident_w,brdf_sr,brdf_u_sr,flags,t_s\n\
         0,550,30,0,30,180,,,,,,failed: timeout,1\n",
    )
    .expect("write");
    let o = gonio().arg("plot").arg(&run).output().expect("plot");
    assert_eq!(o.status.code(), Some(2));
    let err = text(&o.stderr);
    assert!(
        err.contains("nothing") && err.contains("no valid points"),
        "{err}"
    );
    assert!(!run.join("plot.svg").exists());
}

/// A campaign of one sweep alone: coloured plastic at 30 deg incidence, the detector from 0 to 70 deg at
/// 10 deg/s, 550 nm (the plot's and the report's tests).
const SWEPT: &str = "[campaign]\nid = \"swept\"\n[sample]\nradius_mm = 12.5\n[plan]\nbands_nm = [550.0]\n\
                     [[plan.sweeps]]\ntheta_i_deg = [30.0]\ntheta_o_deg = { from = 0.0, to = 70.0 }\n\
                     speed_deg_s = 10.0\n[calibration]\nsimulate_operator = true\n[material]\n\
                     preset = \"coloured-plastic\"\n";

/// A run of sweeps alone: its readings are drawn, averaged along each arc (a few hundred marks, not tens of
/// thousands), as the in-plane curve of their incidence; `--points-only` leaves them out, and with them
/// everything there was to draw.
#[test]
fn sweep_readings_are_drawn_thinned_and_points_only_leaves_them_out() {
    let dir = tempfile::tempdir().expect("tempdir");
    let run = cli::dry_run(dir.path(), "swept", SWEPT);
    let readings = std::fs::read_to_string(run.join("sweeps.csv"))
        .expect("sweeps.csv")
        .lines()
        .count()
        - 1;
    assert!(readings > 1000, "{readings} readings");
    let o = gonio().arg("plot").arg(&run).output().expect("plot");
    assert!(o.status.success(), "{}", text(&o.stderr));
    let stderr = text(&o.stderr);
    assert!(
        stderr.contains(&format!("{readings} sweep readings drawn as ")),
        "{stderr}"
    );
    let svg = std::fs::read_to_string(run.join("plot.svg")).expect("plot.svg");
    let (texts, _, circles) = svg_texts(&svg);
    assert!(
        texts.iter().any(|t| t == "in-plane slices, 550 nm (swept)"),
        "{texts:?}"
    );
    assert!(texts.iter().any(|t| t == "theta_i = 30 deg"), "{texts:?}");
    // One polar panel and one heat map, the sweep's incidence: the readings seen through reciprocity (each its
    // own incidence at one direction) make no curve and no panel of their own.
    assert!(stderr.contains("gonio: 2 panels, 1 curves"), "{stderr}");
    // 70 degrees in bins of half a degree: about 140 marks in the polar panel (and as many heat-map cells).
    assert!((100..2000).contains(&circles), "{circles} circles");
    let o = gonio()
        .arg("plot")
        .arg(&run)
        .arg("--points-only")
        .output()
        .expect("plot --points-only");
    assert!(!o.status.success(), "a run of sweeps alone has no point to draw");
}
