use super::*;
use crate::setup::SoakInstrument;

#[test]
fn angles_between_directions_follow_the_spherical_law_of_cosines() {
    for (a, b) in [
        ((10.0, 0.0), (10.0, 90.0)),
        ((30.0, 180.0), (30.3, 180.2)),
        ((0.0, 0.0), (0.05, 270.0)),
        ((60.0, 10.0), (20.0, 200.0)),
    ] {
        let ((ta, pa), (tb, pb)): ((f64, f64), (f64, f64)) = (a, b);
        let (ta, pa, tb, pb) = (ta.to_radians(), pa.to_radians(), tb.to_radians(), pb.to_radians());
        let expected = (ta.cos() * tb.cos() + ta.sin() * tb.sin() * (pa - pb).cos())
            .clamp(-1.0, 1.0)
            .acos()
            .to_degrees();
        let got = angle_deg(a.0, a.1, b.0, b.1);
        assert!((got - expected).abs() < 1e-6, "{a:?} {b:?}: {got} vs {expected}");
    }
    // At normal incidence the azimuth means nothing: no angle.
    assert!(angle_deg(0.0, 0.0, 0.0, 123.0).abs() < 1e-9);
}

fn effects(rel: &[(&str, f64)], intercepted: f64, true_dirs: [f64; 4]) -> String {
    let relative: serde_json::Map<String, Value> =
        rel.iter().map(|(k, v)| (k.to_string(), (*v).into())).collect();
    serde_json::json!({
        "relative": relative,
        "optics": {
            "true_theta_i_deg": true_dirs[0],
            "true_phi_i_deg": true_dirs[1],
            "true_theta_o_deg": true_dirs[2],
            "true_phi_o_deg": true_dirs[3],
            "intercepted_fraction": intercepted,
        },
    })
    .to_string()
}

#[test]
fn a_points_allowance_compounds_the_magnitudes_of_its_attributed_effects() {
    let json = effects(
        &[
            ("geometry", -0.01),
            ("sample", 0.002),
            ("source_slow", -0.004),
            ("source_flicker", 0.0003),
            ("saturation", -0.0001),
            ("meter", 0.0015),
            ("ambient", 0.0002),
            ("stray", 0.2),
        ],
        0.99,
        [30.0, 0.0, 40.0, 180.0],
    );
    let nominal = [30.0, 0.0, 40.0, 180.0];
    // No reference reading's share, the ambient light wholly left by the dark reading.
    let bare = Tolerance {
        imperfect: true,
        ambient_residual: 1.0,
        ..Tolerance::default()
    };
    let (allowance, pose) = point_allowance(&json, nominal, &bare, 3600.0).expect("readable");
    // Written out: each magnitude, stray light as s / (1 - s) of the rest, the missed beam as 1 - 0.99.
    let expected = 1.01 * 1.002 * 1.004 * 1.0003 * 1.0001 * 1.0015 * 1.0002 * (1.0 + 0.2 / 0.8) * 1.01 - 1.0;
    assert!((allowance - expected).abs() < 1e-12, "{allowance} vs {expected}");
    assert!(pose.abs() < 1e-9);
    // With a 1 % warm-up and no walk, the reference's slow factor lies in [0.99, 1]: the point's 0.996 over it is
    // at most 0.996 / 0.99 - 1; half the ambient light remains; the reference's other share is 0.2 %.
    let tol = Tolerance {
        imperfect: true,
        reference_rel: 0.002,
        warmup_fraction: 0.01,
        walk_per_rthour: 0.0,
        ambient_residual: 0.5,
        pose_deg: 1.0,
    };
    let (allowance, _) = point_allowance(&json, nominal, &tol, 3600.0).expect("readable");
    let expected = 1.01
        * 1.002
        * (0.996 / 0.99)
        * 1.0003
        * 1.0001
        * 1.0015
        * (1.0 + 0.0002 * 0.5)
        * (1.0 + 0.2 / 0.8)
        * 1.01
        * 1.002
        - 1.0;
    assert!((allowance - expected).abs() < 1e-12, "{allowance} vs {expected}");
    assert!(point_allowance("{\"relative\":{}}", [0.0; 4], &tol, 0.0).is_err());
    assert!(point_allowance("not json", [0.0; 4], &tol, 0.0).is_err());
}

#[test]
fn the_realistic_files_bounds_follow_its_magnitudes() {
    let file = SoakInstrument::realistic().file().expect("valid");
    let tol = Tolerance::of(&file);
    assert!(tol.imperfect && !Tolerance::of(&SoakInstrument::simulated().file().expect("valid")).imperfect);
    // realistic.toml: flicker 2e-4, range gain 1e-3, nonlinearity 5e-4, offset 5e-5 of full scale (at a tenth
    // of it: 5e-4), saturation of 1 mW at 1 A/W against 2.5 A, stray 1e-2 1/sr over a 2.5 mm aperture at 250 mm;
    // each at 5 sigma except the saturation.
    let expected = 5.0 * 2e-4
        + 5.0 * (1e-3 + 5e-4)
        + 5.0 * 5e-4
        + 1e-3 / (1e-3 + 2.5)
        + 1e-2 * std::f64::consts::PI * 1e-4;
    assert!(
        (tol.reference_rel - expected).abs() < 1e-9,
        "{}",
        tol.reference_rel
    );
    // Warm-up 1 %, and the walk, 5e-4 per sqrt(hour) at 5 sigma over 4 hours.
    let (lo, hi) = tol.reference_slow_range(4.0 * 3600.0);
    assert!((lo - (1.0 - 0.01 - 5.0 * 5e-4 * 2.0)).abs() < 1e-12, "{lo}");
    assert!((hi - (1.0 + 5.0 * 5e-4 * 2.0)).abs() < 1e-12, "{hi}");
    // Ambient light varying by 20 %: a dark reading leaves at most 2 x 0.2 / 0.8 of it.
    assert!((tol.ambient_residual - 0.5).abs() < 1e-12);
    // Pose: 5 x (2 x 0.02 + 2 x 0.05 + 2 x 0.01 + atan(0.2 / 250) in deg) + 2 x 0.005 + 0.01.
    let pose = 5.0 * (0.04 + 0.1 + 0.02 + (0.2f64 / 250.0).atan().to_degrees()) + 0.01 + 0.01;
    assert!((tol.pose_deg - pose).abs() < 1e-9, "{}", tol.pose_deg);
}

fn point(index: u64, value: f64, truth: f64, json: Option<String>) -> PointRecord {
    PointRecord {
        index,
        band_nm: 550.0,
        theta_i_deg: 30.0,
        phi_i_deg: 0.0,
        theta_o_deg: 40.0,
        phi_o_deg: 180.0,
        signal_w: 1e-6,
        dark_w: 0.0,
        incident_w: 1e-3,
        brdf_sr: Some(value),
        brdf_u_sr: Some(1e-4),
        flags: Vec::new(),
        t_s: 100.0,
        readback_deg: Vec::new(),
        truth_point_sr: Some(truth),
        truth_aperture_sr: Some(truth),
        truth_effects_json: json,
        brdf_aperture_sr: None,
        budget: Default::default(),
    }
}

#[test]
fn on_an_imperfect_instrument_only_what_the_attribution_cannot_explain_is_wrong() {
    let tol = Tolerance {
        imperfect: true,
        reference_rel: 0.005,
        pose_deg: 1.0,
        ..Tolerance::default()
    };
    let nominal = [30.0, 0.0, 40.0, 180.0];
    let geometry = |g: f64| Some(effects(&[("geometry", g)], 1.0, nominal));
    let c = check_points(
        &[
            // 3 % low, the geometry explains 3 %: the instrument's error, valid.
            point(0, 0.097, 0.1, geometry(-0.03)),
            // 3 % low, only 1 % explained (+0.5 % for the direct beam, + 5 u = 0.5 %): silently wrong.
            point(1, 0.097, 0.1, geometry(-0.01)),
            // Within the noise but read at another pose (2 deg off): wrong.
            point(2, 0.1, 0.1, Some(effects(&[], 1.0, [32.0, 0.0, 40.0, 180.0]))),
            // A value without the attribution an imperfect instrument records: wrong.
            point(3, 0.1, 0.1, None),
        ],
        &tol,
    );
    assert_eq!(c.valid, 1, "{:?}", c.wrong);
    assert_eq!(c.wrong.len(), 3, "{:?}", c.wrong);
    assert!(c.wrong[0].starts_with("point 1 "), "{:?}", c.wrong);
    assert!(
        c.wrong[1].starts_with("point 2 ") && c.wrong[1].contains("deg"),
        "{:?}",
        c.wrong
    );
    // The allowance of point 0: 3 % and the direct beam's 0.5 %, compounded.
    assert!(
        (c.allowance_max_rel - (1.03 * 1.005 - 1.0)).abs() < 1e-12,
        "{}",
        c.allowance_max_rel
    );
    // The same 3 % on the ideal instrument is wrong.
    let ideal = check_points(&[point(0, 0.097, 0.1, None)], &Tolerance::ideal());
    assert_eq!((ideal.valid, ideal.wrong.len()), (0, 1));
}
