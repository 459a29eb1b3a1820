//! The sample's non-uniformity in the budget (gonio_engine::budget's completion, issue 29): a campaign that
//! states how much its sample's reflectance changes from centre to edge gets a `sample` entry per value that
//! grows with the footprint towards grazing incidence, and the values' errors follow exactly that pattern when
//! the simulated sample really is uneven (its rim 20 % off, the simulator's hidden truth).

use gonio_engine::store::CampaignState;
use gonio_instrument::InstrumentFile;

fn campaign(non_uniformity: &str) -> String {
    let mut points = Vec::new();
    for ti in [0.0, 20.0, 40.0, 55.0, 65.0] {
        for to in [10.0, 30.0] {
            points.push(format!("[{ti}, 0.0, {to}, 90.0]"));
        }
    }
    format!(
        "[campaign]\nid = \"uniformity\"\n[sample]\nradius_mm = 8.0\n{non_uniformity}[plan]\nbands_nm = [550.0]\n\
         reciprocity = false\n[plan.grid]\nkind = \"points\"\npoints = [{}]\n[calibration]\nsimulate_operator = \
         true\n[material]\npreset = \"spectralon\"\n",
        points.join(", ")
    )
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_stated_non_uniformity_covers_an_uneven_sample_in_the_pattern_it_makes() {
    let mut file = InstrumentFile::simulated();
    file.simulator.imperfections.sample.radial_sd = 0.2;
    let beam = file.instrument.source.beam_radius_mm;
    let dir = tempfile::tempdir().expect("tempdir");
    let (store, id, state) =
        crate::common::run_campaign_text(dir.path(), &campaign("non_uniformity = 0.2\n"), &file).await;
    assert_eq!(state, CampaignState::Completed);
    let points = store.lock().expect("store").points(id).expect("points");
    let mut ratios = Vec::new();
    for p in &points {
        let (Some(v), Some(truth)) = (p.brdf_sr, p.truth_point_sr) else {
            continue;
        };
        let rim = p
            .budget
            .entries
            .iter()
            .find(|e| e.component == "sample" && e.shared.as_deref() == Some("non-uniformity-rim"))
            .unwrap_or_else(|| panic!("point {}: {:?}", p.index, p.budget))
            .u_sr;
        // 0.2 x (a^2 + b^2) / 4 / R^2, a = r / cos(theta_i), b = r; no centring term on this file.
        let a = beam / p.theta_i_deg.to_radians().cos();
        let expected = 0.2 * (a * a + beam * beam) / 4.0 / 64.0;
        assert!(
            (rim / v - expected).abs() <= 1e-9 + 1e-6 * expected,
            "point {}: {} against {expected}",
            p.index,
            rim / v
        );
        ratios.push((v / truth - 1.0) / (rim / v));
    }
    // Ten geometries; one at 65 degrees spills off the 8 mm sample (flagged, no value).
    assert!(ratios.len() >= 8, "{ratios:?}");
    // One sample, one rim: every value off by the same multiple of its entry (the hidden q over 0.2), from
    // normal incidence, where the footprint is smallest, to 65 degrees.
    let first = ratios[0];
    assert!(first.abs() > 0.05, "the simulated sample is uneven: {ratios:?}");
    for r in &ratios {
        assert!((r - first).abs() <= 0.02 * first.abs() + 0.01, "{ratios:?}");
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn no_statement_no_entry_and_nonsense_is_refused() {
    let file = InstrumentFile::simulated();
    let dir = tempfile::tempdir().expect("tempdir");
    let (store, id, state) = crate::common::run_campaign_text(dir.path(), &campaign(""), &file).await;
    assert_eq!(state, CampaignState::Completed);
    let points = store.lock().expect("store").points(id).expect("points");
    assert!(points.iter().all(|p| p.budget.entries.iter().all(|e| {
        !e.shared
            .as_deref()
            .is_some_and(|g| g.starts_with("non-uniformity"))
    })));
    let bad = gonio_campaign::load(
        &campaign("non_uniformity = -0.1\n"),
        "bad.toml",
        &gonio_campaign::Sources::Local(dir.path().to_path_buf()),
        &file,
    );
    let e = bad.expect_err("refused").to_string();
    assert!(e.contains("non_uniformity"), "{e}");
}
