use super::*;
use crate::truth_check::{Tolerance, check_points, reason_class};
use gonio_engine::store::PointRecord;

#[test]
fn error_classes_follow_the_driver_messages() {
    assert_eq!(
        error_class("move light to 30.0000 deg: arms/1: no reply to \"1TS\" within 300 ms (attempt 1 of 3)"),
        "timeout"
    );
    assert_eq!(
        error_class(
            "read the detector: meter: the connection is lost (USB device gone); reconnect and re-verify before use"
        ),
        "disconnected"
    );
    assert_eq!(
        error_class("move tilt to 3 deg: stage/1: move to 3 deg failed: stopped at 1.2 deg"),
        "motion fault"
    );
    assert_eq!(error_class("x: bad reply to \"pos?\": \"7\""), "bad reply");
}

#[test]
fn reason_classes_drop_numbers() {
    assert_eq!(
        reason_class("failed: arms/1: move to 30.25 deg failed: stopped at -1.5e-3 deg"),
        "failed: arms/#: move to # deg failed: stopped at # deg"
    );
}

fn point(index: u64, value: Option<f64>, flags: &[&str]) -> PointRecord {
    PointRecord {
        index,
        band_nm: 550.0,
        theta_i_deg: 0.0,
        phi_i_deg: 0.0,
        theta_o_deg: 30.0,
        phi_o_deg: 180.0,
        signal_w: 1e-6,
        dark_w: 0.0,
        incident_w: 1e-3,
        brdf_sr: value,
        brdf_u_sr: value.map(|_| 0.001),
        flags: flags.iter().map(|s| s.to_string()).collect(),
        t_s: 1.0,
        readback_deg: Vec::new(),
        truth_point_sr: Some(0.1),
        truth_aperture_sr: Some(0.1),
        truth_effects_json: None,
        brdf_aperture_sr: None,
        budget: Default::default(),
    }
}

#[test]
fn a_value_beyond_five_sigma_is_silently_wrong_and_a_bare_gap_unexplained() {
    let c = check_points(
        &[
            point(0, Some(0.1004), &[]),
            point(1, Some(0.1060), &[]),
            point(2, None, &["failed: meter: no reply"]),
            point(3, None, &["overfilled"]),
            point(4, None, &[]),
            point(5, Some(0.1), &["saturated"]),
        ],
        &Tolerance::ideal(),
    );
    assert_eq!(c.valid, 1);
    assert_eq!(c.wrong.len(), 1, "{:?}", c.wrong);
    assert!(c.wrong[0].starts_with("point 1 "));
    assert_eq!(c.failed_total(), 1);
    assert_eq!(c.flagged_total(), 1);
    assert_eq!(c.unexplained.len(), 2, "{:?}", c.unexplained);
}

#[test]
fn only_a_zaber_stall_counts_as_a_zaber_stall_fault() {
    let mut t = EventTally::default();
    let fault = |message: &str| Event::Fault {
        campaign: gonio_engine::store::CampaignId(1),
        message: message.to_string(),
    };
    t.observe(fault(
        "move tilt to -3.2099 deg: tilt (stage/1.1): move to -3.2099 deg failed: FS (stalled and stopped), NI \
         (command interrupted); stopped at -3.97 deg (attempt 1 of 3)",
    ));
    t.observe(fault(
        "move detector to 52.8 deg: detector (arms/2): move to 52.8 deg failed: DISABLE from moving (3D); \
         positioner errors 0020: following error (attempt 1 of 3)",
    ));
    assert_eq!(t.faults.get("motion fault").copied(), Some(2));
    assert_eq!(t.zaber_stall_faults, 1);
}
