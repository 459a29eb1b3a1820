//! The typed campaign file both ways: every example campaign read as a value, written back with `to_toml`, reads
//! to the same value and prepares to the same plan; a campaign built as a value in code is what the loader
//! reads from its text.

use std::path::{Path, PathBuf};

use gonio_campaign::{AcquisitionSection, CampaignFile, Sources, load_and_prepare};
use gonio_instrument::InstrumentFile;
use gonio_scheduler::plan::AdaptiveSpec;
use gonio_scheduler::plan::{GridKind, GridSpec, PlanSpec};

fn campaigns_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config/campaigns")
}

#[test]
fn every_example_campaign_round_trips_through_the_typed_model() {
    let dir = campaigns_dir();
    let file = InstrumentFile::simulated();
    let sources = Sources::Local(dir.clone());
    let mut seen = 0;
    let mut entries: Vec<PathBuf> = std::fs::read_dir(&dir)
        .expect("config/campaigns")
        .map(|e| e.expect("entry").path())
        .filter(|p| p.extension().is_some_and(|x| x == "toml"))
        .collect();
    entries.sort();
    for path in entries {
        let text = std::fs::read_to_string(&path).expect("readable");
        let value = CampaignFile::parse(&text).expect("typed");
        let written = value.to_toml().expect("serialises");
        let again = CampaignFile::parse(&written).expect("reads back");
        assert_eq!(again, value, "{}", path.display());
        // The written text plans the same campaign as the original (where the original prepares at all:
        // template.toml has no sample material and still prepares, as `gonio plan` does).
        let origin = path.display().to_string();
        match (
            load_and_prepare(&text, &origin, &sources, &file),
            load_and_prepare(&written, &origin, &sources, &file),
        ) {
            (Ok(a), Ok(b)) => {
                assert_eq!(a.total_points(), b.total_points(), "{origin}");
                assert_eq!(a.predicted_s(), b.predicted_s(), "{origin}");
                assert_eq!(a.plan.geometries, b.plan.geometries, "{origin}");
            }
            (Err(a), Err(b)) => assert_eq!(a.to_string(), b.to_string(), "{origin}"),
            (a, b) => panic!("{origin}: original {:?}, written {:?}", a.err(), b.err()),
        }
        seen += 1;
    }
    assert!(seen >= 6, "only {seen} example campaigns");
}

#[test]
fn a_campaign_built_as_a_value_is_what_its_text_says() {
    let mut grid = GridSpec::new(GridKind::Isotropic);
    grid.theta_i_deg = Some(GridSpec::list_deg(&[0.0, 30.0]));
    grid.theta_o_deg = Some(GridSpec::range_deg(0.0, 60.0, 20.0));
    grid.delta_phi_deg = Some(GridSpec::range_deg(0.0, 180.0, 90.0));
    let plan = PlanSpec {
        bands_nm: Some(vec![450.0, 650.0]),
        grid: Some(grid),
        ..PlanSpec::default()
    };
    let built = CampaignFile::new("built", 10.0, plan)
        .with_material_preset("gold")
        .with_acquisition(AcquisitionSection {
            averaging: Some(20),
            ..AcquisitionSection::default()
        });
    let text = r#"
[campaign]
id = "built"
[sample]
radius_mm = 10.0
[plan]
bands_nm = [450.0, 650.0]
[plan.grid]
kind = "isotropic"
theta_i_deg = [0.0, 30.0]
theta_o_deg = { from = 0.0, to = 60.0, step = 20.0 }
delta_phi_deg = { from = 0.0, to = 180.0, step = 90.0 }
[acquisition]
averaging = 20
[material]
preset = "gold"
"#;
    assert_eq!(CampaignFile::parse(text).expect("typed"), built);
    let file = InstrumentFile::simulated();
    let sources = Sources::Local(campaigns_dir());
    let a = load_and_prepare(text, "text", &sources, &file).expect("text prepares");
    let b =
        load_and_prepare(&built.to_toml().expect("toml"), "value", &sources, &file).expect("value prepares");
    assert_eq!(a.total_points(), b.total_points());
    assert_eq!(a.predicted_s(), b.predicted_s());
    assert_eq!(a.campaign.acquisition.averaging, 20);
}

#[test]
fn an_adaptive_plan_built_with_its_defaults_matches_an_empty_table() {
    let text = "[campaign]\nid = \"a\"\n[plan]\nbands_nm = [550.0]\n[plan.adaptive]\nbudget_points = 120\n";
    let read = CampaignFile::parse(text).expect("typed");
    let plan = PlanSpec {
        bands_nm: Some(vec![550.0]),
        adaptive: Some(AdaptiveSpec::with_budget(120)),
        ..PlanSpec::default()
    };
    assert_eq!(read.plan, plan);
}

#[test]
fn the_relative_method_schedules_its_references_at_the_reference_geometry() {
    use gonio_scheduler::kinematics::{Geometry, Kinematics};
    use gonio_scheduler::schedule::StepKind;
    let dir = campaigns_dir();
    let file = InstrumentFile::simulated();
    let text = std::fs::read_to_string(dir.join("relative.toml")).expect("relative.toml");
    let p = load_and_prepare(&text, "relative.toml", &Sources::Local(dir), &file).expect("prepares");
    // relative.toml reads its Spectralon at 0/45.
    let (wi_r, wo_r) = Geometry::new(0.0, 0.0, 45.0, 180.0).directions();
    let kin = Kinematics::new(&file.instrument);
    let references: Vec<_> = p
        .schedule
        .steps
        .iter()
        .filter(|s| s.kind == StepKind::Reference)
        .collect();
    assert!(references.len() >= 6, "{} reference readings", references.len());
    for step in references {
        let (wi, wo) = kin.forward(&step.pose);
        assert!(
            wi.angle_to(&wi_r).to_degrees() < 1e-6 && wo.angle_to(&wo_r).to_degrees() < 1e-6,
            "a reference reading at {:?} does not read 0/45",
            step.pose
        );
    }
}

/// An adaptive campaign on gold whose first pass sweeps (`extra` appended to its text).
fn swept_first(extra: &str) -> String {
    format!(
        "[campaign]\nid = \"s\"\n[sample]\nradius_mm = 12.5\n[material]\npreset = \"gold\"\n[plan]\n\
         bands_nm = [550.0]\n[plan.adaptive]\nbudget_points = 100\nfirst_pass_theta_i_deg = [20.0, 50.0]\n\
         first_pass_sweeps = {{ speed_deg_s = 5.0 }}\n{extra}"
    )
}

#[test]
fn a_first_pass_of_sweeps_prepares_as_sweeps_before_a_plan_of_no_point() {
    let file = InstrumentFile::simulated();
    let sources = Sources::Local(campaigns_dir());
    let p = load_and_prepare(&swept_first(""), "s.toml", &sources, &file).expect("prepares");
    assert!(p.sweeps_first());
    assert_eq!(
        p.schedule.measure_steps().count(),
        0,
        "no point before the sweeps"
    );
    assert_eq!(p.total_points(), 100, "the budget counts points");
    let sweeps = p.sweeps.as_ref().expect("sweeps");
    // Two incidences, each arc cut where the source blocks the view into at most two pieces.
    assert_eq!(sweeps.plan.requested, 2);
    assert!(
        (2..=4).contains(&sweeps.plan.arcs.len()),
        "{} arcs",
        sweeps.plan.arcs.len()
    );
    // The run goes on after the sweeps: their schedule does not close the beam, and the prediction counts
    // their time once (in the rehearsal), with the points after them.
    assert_eq!(sweeps.schedule.breakdown.closing_s, 0.0);
    let r = p.rehearsal().expect("rehearsed");
    assert_eq!(r.points, 100);
    assert_eq!(p.predicted_s(), r.mean_s);
    assert!(r.mean_s > sweeps.schedule.breakdown.total_s() + 50.0);

    // No other sweeps beside it; a speed the arm cannot reach is named where the campaign asked for it.
    let beside = swept_first(
        "[[plan.sweeps]]\ntheta_i_deg = [30.0]\ntheta_o_deg = { from = -60.0, to = 60.0 }\nspeed_deg_s = 2.0\n",
    );
    let e = load_and_prepare(&beside, "s.toml", &sources, &file).expect_err("refused");
    assert!(e.to_string().contains("first_pass_sweeps"), "{e}");
    let fast = swept_first("").replace("speed_deg_s = 5.0", "speed_deg_s = 99.0");
    let e = load_and_prepare(&fast, "s.toml", &sources, &file).expect_err("refused");
    assert!(
        e.to_string().contains("first_pass_sweeps") && e.to_string().contains("speed_deg_s"),
        "{e}"
    );
}

/// Points in three bands and a sweep; `extra` in `[plan]`.
fn probed(extra: &str, sweep: bool) -> String {
    let sweep = if sweep {
        "[[plan.sweeps]]\ntheta_i_deg = [30.0]\ntheta_o_deg = { from = -60.0, to = 60.0 }\nspeed_deg_s = 2.0\n"
    } else {
        ""
    };
    format!(
        "[campaign]\nid = \"p\"\n[sample]\nradius_mm = 12.5\n[plan]\nbands_nm = [450.0, 550.0, 650.0]\n{extra}\n\
         [plan.grid]\nkind = \"in-plane\"\ntheta_i_deg = [30.0]\ntheta_o_deg = [0.0, 45.0]\n{sweep}"
    )
}

#[test]
fn sweeps_in_fewer_bands_than_the_points_sweep_those_and_a_wrong_list_is_named() {
    let file = InstrumentFile::simulated();
    let sources = Sources::Local(campaigns_dir());
    let prepare = |text: &str| load_and_prepare(text, "p.toml", &sources, &file);
    // Without the key the sweeps take every band of the plan.
    let all = prepare(&probed("", true)).expect("prepares");
    assert_eq!(
        all.sweeps.as_ref().expect("sweeps").plan.bands_nm,
        vec![450.0, 550.0, 650.0]
    );
    let one = prepare(&probed("sweep_bands_nm = [550.0]", true)).expect("prepares");
    assert_eq!(
        one.bands_nm(),
        &[450.0, 550.0, 650.0],
        "the points keep their bands"
    );
    let sweeps = one.sweeps.as_ref().expect("sweeps");
    assert_eq!(sweeps.plan.bands_nm, vec![550.0]);
    // A third of the sweeping, in time as in readings.
    let all_sweeps = all.sweeps.as_ref().expect("sweeps");
    let ratio = sweeps.schedule.breakdown.total_s() / all_sweeps.schedule.breakdown.total_s();
    assert!(ratio < 0.5, "{ratio}");
    // A spectrally flat sample is measured in one band: the sweeps' (which the points normalise).
    let grey = probed("sweep_bands_nm = [550.0]", true).replace(
        "[plan]\n",
        "[material]\nmodel = \"lambertian\"\nalbedo = 0.5\n[plan]\n",
    );
    let flat = prepare(&grey).expect("prepares");
    assert_eq!(flat.bands_nm(), &[550.0]);
    assert_eq!(flat.sweeps.as_ref().expect("sweeps").plan.bands_nm, vec![550.0]);
    for (extra, sweep, says) in [
        (
            "sweep_bands_nm = [500.0]",
            true,
            "500 nm is not among the bands the plan measures",
        ),
        ("sweep_bands_nm = []", true, "expected at least one band"),
        ("sweep_bands_nm = [550.0, 550.0]", true, "listed twice"),
        (
            "sweep_bands_nm = [550.0]",
            false,
            "sweep_bands_nm without a sweep",
        ),
    ] {
        let e = prepare(&probed(extra, sweep)).expect_err("refused");
        assert!(
            e.to_string().contains(says) && e.to_string().contains("sweep_bands_nm"),
            "{extra}: {e}"
        );
    }
}
