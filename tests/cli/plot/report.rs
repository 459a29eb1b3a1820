//! `gonio report` end to end (a module of the plot test target: one binary less to link): the page holds every
//! section and figure, its inline SVGs are well-formed, nothing in it points outside the file (no script, no
//! link, no source, only in-page anchors, a Content Security Policy that forbids fetching), its numbers are
//! run.json's, and a calibrated run's page shows the alignment and characterisation it used and its largest
//! budget components. The browser tier (tests/browser/report_page.py) opens the page in headless Chromium.

use std::path::Path;
use std::process::Stdio;

use gonio_testkit::{gonio, text};
use serde_json::Value;

/// Runs `gonio report RUN ARGS...` and returns the page.
fn report(run: &Path, args: &[&str]) -> String {
    let o = gonio()
        .arg("report")
        .arg(run)
        .args(args)
        .output()
        .expect("gonio report");
    assert!(o.status.success(), "{}", text(&o.stderr));
    let path = run.join("report.html");
    assert_eq!(text(&o.stdout).trim(), path.display().to_string());
    std::fs::read_to_string(&path).expect("report.html")
}

/// The content of `<section id="ID">`, or a panic naming the section.
fn section<'a>(page: &'a str, id: &str) -> &'a str {
    let start = page
        .find(&format!("<section id=\"{id}\">"))
        .unwrap_or_else(|| panic!("no section {id}"));
    let end = page[start..].find("</section>").expect("section closed") + start;
    &page[start..end]
}

/// Every inline SVG of the page, each checked to be well-formed XML.
fn svgs(page: &str) -> Vec<&str> {
    let mut out = Vec::new();
    let mut rest = page;
    while let Some(i) = rest.find("<svg") {
        let end = rest[i..].find("</svg>").expect("svg closed") + i + "</svg>".len();
        let svg = &rest[i..end];
        roxmltree::Document::parse(svg).unwrap_or_else(|e| panic!("an inline SVG is not well-formed: {e}"));
        out.push(svg);
        rest = &rest[end..];
    }
    out
}

/// Nothing in the page makes a browser fetch: no script, stylesheet link, source, frame, object or CSS url; every
/// href an in-page anchor; a Content Security Policy that forbids every fetch.
fn assert_self_contained(page: &str) {
    let lower = page.to_ascii_lowercase();
    for forbidden in [
        "<script", "<link", "<iframe", "<object", "<embed", "<img", "src=", "url(", "@import", "srcset",
    ] {
        assert!(!lower.contains(forbidden), "the page holds {forbidden:?}");
    }
    for (i, _) in lower.match_indices("href=") {
        let target = &lower[i + "href=".len()..];
        assert!(
            target.starts_with("\"#"),
            "a link leaves the page: {}",
            &page[i..i + 60]
        );
    }
    assert!(
        page.contains("http-equiv=\"Content-Security-Policy\" content=\"default-src 'none'"),
        "no Content Security Policy"
    );
}

#[test]
fn the_report_of_a_dry_run_holds_every_section_and_nothing_leaves_the_file() {
    let dir = tempfile::tempdir().expect("tempdir");
    let run = super::dry_run(dir.path());
    let page = report(&run, &["--models", "lambertian,plastic"]);
    assert_self_contained(&page);
    for id in gonio_results::report::SECTIONS {
        assert!(section(&page, id).len() > 100, "section {id} is empty");
    }
    for figure in ["coverage", "drift", "brdf"] {
        assert!(
            page.contains(&format!("<figure id=\"{figure}\"><svg")),
            "figure {figure}"
        );
    }
    assert_eq!(svgs(&page).len(), 3);

    // Its numbers are run.json's.
    let record: Value =
        serde_json::from_str(&std::fs::read_to_string(run.join("run.json")).expect("run.json"))
            .expect("json");
    let summary = section(&page, "summary");
    let actual = record["timing"]["actual_instrument_s"].as_f64().expect("actual");
    assert!(summary.contains(&format!("{actual:.0} s")), "{summary}");
    let c = &record["campaign"];
    assert!(
        summary.contains(&format!(
            "{} of {} done: {} valid",
            c["points_done"], c["total_points"], c["valid_points"]
        )),
        "{summary}"
    );
    let check = &record["uncertainty"]["against_point_truth"];
    assert!(
        section(&page, "truth").contains(&format!("of {} points", check["points"])),
        "{}",
        section(&page, "truth")
    );
    // The sample is coloured plastic: the plastic model fits best, and is the one plotted.
    let fit = section(&page, "fit");
    let first_row = fit.find("<tbody><tr><td>").expect("fit table") + "<tbody><tr><td>".len();
    assert!(fit[first_row..].starts_with("plastic</td>"), "{fit}");
    assert!(section(&page, "plots").contains("measured vs model (fitted plastic)"));
    // No calibration was applied, and the page says so; the planner's skips are listed.
    assert!(section(&page, "alignment").contains("No alignment or characterisation was applied"));
    assert!(
        section(&page, "plan").contains("need not be measured"),
        "{}",
        section(&page, "plan")
    );
    // A second report of the same run differs only in its date line.
    let again = report(&run, &["--models", "lambertian,plastic"]);
    let strip = |p: &str| {
        p.lines()
            .filter(|l| !l.contains(" written "))
            .collect::<Vec<_>>()
            .join("\n")
    };
    assert_eq!(strip(&page), strip(&again));
}

#[test]
fn the_report_of_a_calibrated_run_shows_its_alignment_characterisation_and_budget() {
    let dir = tempfile::tempdir().expect("tempdir");
    let instrument = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../config/instruments/realistic.toml"
    );
    let cal = dir.path().join("cal.toml");
    let o = gonio()
        .args(["align", "--instrument", instrument, "--out"])
        .arg(&cal)
        .stdin(Stdio::null())
        .output()
        .expect("gonio align");
    assert!(o.status.success(), "{}", text(&o.stderr));
    let campaign = dir.path().join("campaign.toml");
    std::fs::write(
        &campaign,
        gonio_testkit::CampaignText::isotropic(
            "calibrated",
            "[0.0, 30.0, 60.0]",
            "{ from = 0.0, to = 75.0, step = 15.0 }",
            "[0.0, 90.0, 180.0]",
        )
        .bands("[550.0]")
        .to_string(),
    )
    .expect("campaign");
    let out = dir.path().join("run");
    let o = gonio()
        .args(["run", "--quiet", "--instrument", instrument, "--calibration"])
        .arg(&cal)
        .arg("--out")
        .arg(&out)
        .arg(&campaign)
        .output()
        .expect("gonio run");
    assert!(o.status.success(), "{}", text(&o.stderr));
    let page = report(&out, &["--no-fit"]);
    assert_self_contained(&page);
    let alignment = section(&page, "alignment");
    for expected in [
        "sample_tilt_x_deg",
        "detector_zero_deg",
        "no (not applied)",
        "corrected by the meter ranges",
        "subtracted from every value",
        "warmup_time_s",
    ] {
        assert!(alignment.contains(expected), "{expected}: {alignment}");
    }
    let uncertainty = section(&page, "uncertainty");
    for component in ["solid-angle", "signal-noise", "range", "stray-light"] {
        assert!(
            uncertainty.contains(&format!("<td>{component}</td>")),
            "{component}: {uncertainty}"
        );
    }
    assert!(section(&page, "reproduce").contains("--calibration calibration.toml"));
    // The realistic instrument's hidden values are in the truth section, folded, as run.json has them.
    assert!(section(&page, "truth").contains("hidden imperfections"));
    assert!(section(&page, "fit").contains("No model was fitted"));
    // The ASTM export of the same run says the signature was measured and subtracted (not "not measured").
    let astm = dir.path().join("run.astm.csv");
    let o = gonio()
        .args(["export"])
        .arg(&out)
        .args(["--format", "astm", "--out"])
        .arg(&astm)
        .output()
        .expect("gonio export");
    assert!(o.status.success(), "{}", text(&o.stderr));
    let table = std::fs::read_to_string(&astm).expect("astm");
    let line = table
        .lines()
        .find(|l| l.contains("instrument_signature:"))
        .expect("the signature line");
    assert!(
        line.contains("measured by gonio align") && line.contains("subtracted from every value"),
        "{line}"
    );
    // And its provenance says what the calibration corrected, as every export's does.
    let alignment = table
        .lines()
        .find(|l| l.contains("alignment:") || l.contains("alignment ="))
        .expect("the alignment line");
    assert!(
        alignment.contains("gonio align calibration of")
            && alignment.contains("every pose")
            && alignment.contains("signature subtracted"),
        "{alignment}"
    );
}

/// A run of sweeps alone: the page's sweeps section counts sweeps.csv's readings by band with their k = 2
/// coverage of the truth, the plots draw them averaged along the arc, and the fit takes them (a plastic at
/// 550 nm); `--points-only` leaves them out and the section says the page has none.
#[test]
fn the_report_of_a_sweeps_run_has_a_section_on_them_and_draws_and_fits_them() {
    let dir = tempfile::tempdir().expect("tempdir");
    let run = gonio_testkit::cli::dry_run(dir.path(), "swept", super::SWEPT);
    let csv = std::fs::read_to_string(run.join("sweeps.csv")).expect("sweeps.csv");
    let readings = csv.lines().count() - 1;
    assert!(readings > 1000, "{readings} readings");
    let page = report(&run, &["--models", "lambertian,plastic"]);
    assert_self_contained(&page);
    let sweeps = section(&page, "sweeps");
    assert!(
        sweeps.contains(&format!("{readings} readings in 1 sweeps")),
        "{sweeps}"
    );
    // One row, 550 nm: every reading, its arc, and in a dry-run the truth's coverage.
    let row = sweeps.find("<tbody><tr><td>550</td>").expect("the 550 nm row");
    let cells: Vec<&str> = sweeps[row..]
        .split("<td>")
        .skip(1)
        .map(|c| c.split("</td>").next().unwrap_or(""))
        .collect();
    assert_eq!(cells[2], readings.to_string(), "{cells:?}");
    assert!(cells[5].ends_with(" to 70"), "{cells:?}");
    assert!(cells[7].ends_with('%'), "{cells:?}");
    // Drawn thinned: the BRDF figure exists and is far smaller than a mark per reading would make it.
    assert!(page.contains("<figure id=\"brdf\"><svg"));
    assert!(
        page.len() < 200 * readings,
        "{} bytes for {readings} readings",
        page.len()
    );
    // Fitted: the plastic fits best.
    let fit = section(&page, "fit");
    let first_row = fit.find("<tbody><tr><td>").expect("fit table") + "<tbody><tr><td>".len();
    assert!(fit[first_row..].starts_with("plastic</td>"), "{fit}");

    let page = report(&run, &["--no-fit", "--points-only"]);
    assert!(section(&page, "sweeps").contains("No sweeps"));
}
