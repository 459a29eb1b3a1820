//! The alignment on the simulated realistic instrument (tokio's paused clock): each estimate against the
//! simulator's hidden truth, on seeds of our own.

use gonio_engine::align::AlignmentReport;
use gonio_engine::control::Control;
use gonio_engine::motion::Motion;
use gonio_engine::rig::Rig;
use gonio_instrument::{AxisRole, InstrumentFile};
use gonio_scheduler::timing::TimeModel;
use gonio_simulator::imperfections::HiddenTruth;

use crate::common;

const REALISTIC: &str = include_str!("../../../../config/instruments/realistic.toml");

fn realistic(seed: u64) -> InstrumentFile {
    let text = REALISTIC.replace("seed = 16", &format!("seed = {seed}"));
    InstrumentFile::parse(&text, "realistic.toml").expect("valid")
}

/// The alignment with a mirror in the holder; the mirror's seating tilt while it was aligned.
async fn align(file: &InstrumentFile) -> (AlignmentReport, [f64; 2]) {
    try_align(file, "mirror").await.expect("alignment ran")
}

/// (estimate, its u, truth) for the keys compared.
fn compared(
    file: &InstrumentFile,
    r: &AlignmentReport,
    seat: [f64; 2],
) -> Vec<(&'static str, f64, f64, f64)> {
    let hidden = HiddenTruth::draw(file).expect("imperfect");
    let g = hidden.geometry.as_ref().expect("geometry");
    let zero = |role: AxisRole| {
        g.axes
            .iter()
            .find(|a| a.role == role)
            .expect("axis")
            .zero_offset_deg
    };
    let beam = hidden.beam.expect("beam");
    let p1 = beam.pointing_deg[0].to_radians();
    let h = -beam.source_distance_mm * p1.sin();
    let d = file.instrument.detector.distance_mm;
    let line_truth = zero(AxisRole::LightArm) + beam.pointing_deg[0] - (h / d).asin().to_degrees();
    let est = |k: &str| {
        let e = r.get(k).expect(k);
        (e.value, e.u)
    };
    let mut out = vec![];
    let axis = |role: AxisRole| *g.axes.iter().find(|a| a.role == role).expect("axis");
    for (name, at) in [
        ("detector_error_at_30_deg", 30.0),
        ("detector_error_at_90_deg", 90.0),
    ] {
        let (v, u) = r.detector_error_deg(at);
        out.push((name, v, u, axis(AxisRole::DetectorArm).true_deg(at) - at));
    }
    // The tilt's zero read from the report under simulator_truth's keys (axes by role, K and K_u).
    let keyed = r.estimated();
    let tilt = keyed["geometry"]["axes"]
        .as_array()
        .expect("axes")
        .iter()
        .find(|a| a["role"] == "sample-tilt")
        .expect("sample-tilt");
    let (v, u) = (
        tilt["zero_offset_deg"].as_f64().expect("K"),
        tilt["zero_offset_deg_u"].as_f64().expect("K_u"),
    );
    out.push(("tilt_zero_deg", v, u, axis(AxisRole::SampleTilt).true_deg(0.0)));
    let (v, u) = est("sample_tilt_x_deg");
    out.push(("sample_tilt_x_deg", v, u, g.sample_tilt.x_deg + seat[0]));
    let (v, u) = est("sample_tilt_y_deg");
    out.push(("sample_tilt_y_deg", v, u, g.sample_tilt.y_deg + seat[1]));
    let (v, u) = est("eccentricity_x_mm");
    out.push(("eccentricity_x_mm", v, u, g.eccentricity_mm[0]));
    let (v, u) = est("beam_line_deg");
    out.push(("beam_line_deg", v, u, line_truth));
    out
}

/// Five seeds of the realistic instrument: every compared estimate within 3 of its standard uncertainties of
/// the hidden value (or all but one in twenty, the 95 % the issue asks for), and the tilt's zero and the sample's
/// tilt known to 0.005 deg.
#[tokio::test(start_paused = true)]
async fn alignment_finds_the_hidden_geometry_on_several_seeds() {
    let mut lines = Vec::new();
    let (mut cases, mut outside) = (0, 0);
    for seed in [16u64, 3, 101, 2027, 77] {
        let file = realistic(seed);
        let (r, seat) = align(&file).await;
        for (k, v, u, t) in compared(&file, &r, seat) {
            let z = (v - t) / u;
            lines.push(format!(
                "seed {seed} {k}: estimate {v:.5} u {u:.5} truth {t:.5} z {z:.2}"
            ));
            cases += 1;
            if z.abs() > 3.0 {
                outside += 1;
            }
            if k.starts_with("sample_tilt") || k == "tilt_zero_deg" {
                assert!(u <= 0.005, "seed {seed} {k}: u {u}");
            }
        }
        assert!(r.reduced_chi2.is_finite(), "seed {seed}");
        assert!(
            r.unobservable.iter().any(|m| m.starts_with("rotation_zero_deg")),
            "{:?}",
            r.unobservable
        );
    }
    eprintln!("{}", lines.join("\n"));
    assert!(
        outside as f64 <= 0.05 * cases as f64,
        "{outside} of {cases} estimates beyond 3 u:\n{}",
        lines.join("\n")
    );
}

/// A step that cannot succeed refuses with the cause: no beam (the source dark), a sample with no mirror
/// reflection asked to stand in for the mirror, a detector saturated by the direct beam.
#[tokio::test(start_paused = true)]
async fn a_step_that_cannot_see_what_it_needs_refuses_with_the_cause() {
    let dark = REALISTIC.replace("power_w = 1.0e-3", "power_w = 1.0e-15");
    let file = InstrumentFile::parse(&dark, "dark.toml").expect("valid");
    let err = try_align(&file, "mirror").await.expect_err("no beam");
    assert!(err.contains("direct beam") && err.contains("no beam"), "{err}");
    let err = try_align(&realistic(16), "spectralon")
        .await
        .expect_err("no mirror reflection");
    assert!(err.contains("mirror, detector scan"), "{err}");
    // 10 W on a meter whose largest range is 5 mW.
    let bright = REALISTIC.replace("power_w = 1.0e-3", "power_w = 10.0");
    let file = InstrumentFile::parse(&bright, "bright.toml").expect("valid");
    let err = try_align(&file, "mirror").await.expect_err("saturated");
    assert!(err.contains("direct beam") && err.contains("saturated"), "{err}");
}

/// The alignment with `material` (a preset) standing in for the mirror: the report and the seating tilt of
/// that mounting, or the refusal's message.
async fn try_align(file: &InstrumentFile, material: &str) -> Result<(AlignmentReport, [f64; 2]), String> {
    let (rig, report) = common::dry_run_alignment(file, material, None, Default::default()).await;
    let report = report?;
    let seat = rig.optics().expect("optics").seating().1;
    Ok((report, [seat.x_deg, seat.y_deg]))
}

/// The console's move by geometry goes through the alignment when it has one: it stands where the calibrated
/// model makes the asked directions, which is not the nominal pose.
#[tokio::test(start_paused = true)]
async fn the_consoles_move_by_geometry_goes_through_the_alignment() {
    use gonio_engine::align::correction::PoseCorrection;
    use gonio_engine::align::model::GeometryParams;
    use gonio_engine::console::Console;
    use gonio_scheduler::kinematics::Geometry;

    let file = InstrumentFile::simulated();
    let rig = Rig::connect_with_time_scale(&file, None, 1.0).await.expect("rig");
    let params = GeometryParams {
        detector_zero_deg: 0.05,
        sample_tilt_x_deg: 0.04,
        ..Default::default()
    };
    let correction = PoseCorrection::new(&file.instrument, params);
    let geometry = Geometry::new(30.0, 0.0, 40.0, 180.0);
    let at = |positions: &[gonio_engine::console::AxisPosition]| {
        let get = |name: &str| {
            positions
                .iter()
                .find(|p| p.name == name)
                .map(|p| p.position_deg)
                .expect(name)
        };
        gonio_scheduler::kinematics::Pose::new(get("light"), get("detector"), get("tilt"), get("rotation"))
    };
    let plain = {
        let motion = Motion::new(&rig, TimeModel::new(&file.instrument), 2, Control::new());
        let mut console = Console::new(motion);
        console.home(None).await.expect("homed");
        at(&console.move_geometry(&geometry).await.expect("moved"))
    };
    let aligned = {
        let motion = Motion::new(&rig, TimeModel::new(&file.instrument), 2, Control::new());
        let mut console = Console::new(motion).with_correction(Some(correction.clone()));
        at(&console.move_geometry(&geometry).await.expect("moved"))
    };
    // The normal tipped 0.04 deg in the arms' plane turns both arms by 0.04 deg; the detector's zero takes 0.05
    // deg off it. The console stands at the correction of the nominal pose, to the axes' resolution.
    assert!(
        (aligned.light_deg - plain.light_deg - 0.04).abs() < 0.002,
        "{plain:?} -> {aligned:?}"
    );
    assert!(
        (aligned.detector_deg - plain.detector_deg + 0.01).abs() < 0.002,
        "{plain:?} -> {aligned:?}"
    );
    let expected = correction.correct(&plain);
    for (a, b) in [
        (aligned.light_deg, expected.light_deg),
        (aligned.detector_deg, expected.detector_deg),
        (aligned.tilt_deg, expected.tilt_deg),
        (aligned.rotation_deg, expected.rotation_deg),
    ] {
        assert!((a - b).abs() < 0.002, "{aligned:?} vs {expected:?}");
    }
}
