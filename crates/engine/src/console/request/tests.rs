use super::*;

fn simulated() -> InstrumentFile {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../../config/instruments/simulated.toml"
    );
    InstrumentFile::load(std::path::Path::new(path)).expect("simulated.toml")
}

fn refused_rule<T: std::fmt::Debug>(r: Result<T, ConsoleError>) -> String {
    match r {
        Err(ConsoleError::Refused { rule, .. }) => rule,
        other => panic!("expected a refusal, got {other:?}"),
    }
}

#[test]
fn targets_within_travel_and_apart_are_accepted_and_others_name_their_rule() {
    let file = simulated();
    let here = Pose::new(-30.0, 30.0, 0.0, 0.0);
    let p = target_pose(&file, &here, &[("detector".into(), 50.0), ("tilt".into(), 5.0)]).expect("safe");
    assert_eq!(p, Pose::new(-30.0, 50.0, 5.0, 0.0));
    assert_eq!(
        refused_rule(target_pose(&file, &here, &[("detector".into(), 101.0)])),
        "axes.detector.max_deg"
    );
    assert_eq!(
        refused_rule(target_pose(&file, &here, &[("rotation".into(), -181.0)])),
        "axes.rotation.min_deg"
    );
    // 5 degrees apart where the file asks for 10.
    assert_eq!(
        refused_rule(target_pose(&file, &here, &[("detector".into(), -25.0)])),
        "safety.min_arm_separation_deg"
    );
    assert!(matches!(
        target_pose(&file, &here, &[("elbow".into(), 1.0)]),
        Err(ConsoleError::Invalid(m)) if m.contains("light, detector, tilt, rotation")
    ));
    assert!(matches!(
        target_pose(&file, &here, &[("light".into(), f64::NAN)]),
        Err(ConsoleError::Invalid(_))
    ));
    assert!(matches!(
        target_pose(&file, &here, &[]),
        Err(ConsoleError::Invalid(_))
    ));
}

#[test]
fn a_geometry_reaches_a_pose_that_measures_it_or_names_the_static_rule() {
    let file = simulated();
    let inst = &file.instrument;
    let here = Pose::new(-30.0, 30.0, 0.0, 0.0);
    let g = Geometry::new(30.0, 0.0, 30.0, 180.0);
    let poses = geometry_poses(inst, &here, &g).expect("specular at 30 deg");
    let pose = poses[0];
    let back = Kinematics::new(inst).forward_geometry(&pose);
    assert!(
        back.max_direction_angle_deg(&g) < 1e-9,
        "the pose {pose:?} measures {back:?}, not {g:?}"
    );
    assert!(poses.iter().all(|p| check_separation(inst, p).is_ok()));
    let grazing = Geometry::new(88.0, 0.0, 30.0, 180.0);
    assert_eq!(
        refused_rule(geometry_poses(inst, &here, &grazing)),
        "safety.grazing_limit_deg"
    );
    let retro = Geometry::new(30.0, 0.0, 31.0, 0.0);
    assert_eq!(
        refused_rule(geometry_poses(inst, &here, &retro)),
        "safety.retro_block_deg"
    );
    assert!(matches!(
        geometry_poses(inst, &here, &Geometry::new(f64::INFINITY, 0.0, 0.0, 0.0)),
        Err(ConsoleError::Invalid(_))
    ));
}

#[test]
fn filters_are_chosen_by_position_or_band() {
    let file = simulated();
    let inst = &file.instrument;
    assert_eq!(parse_filter_choice("3"), Ok(FilterChoice::Position(3)));
    assert_eq!(parse_filter_choice("550nm"), Ok(FilterChoice::BandNm(550.0)));
    assert_eq!(parse_filter_choice(" 450.0 "), Ok(FilterChoice::BandNm(450.0)));
    assert!(parse_filter_choice("green").is_err());
    assert!(parse_filter_choice("-5nm").is_err());
    let wheel = inst.filter_wheel.as_ref().expect("a wheel");
    let first_band = wheel
        .positions
        .iter()
        .find(|f| f.band_nm.is_some())
        .expect("a band filter");
    let nm = first_band.band_nm.unwrap_or_default();
    assert_eq!(
        filter_position(inst, FilterChoice::BandNm(nm + 0.3)),
        Ok(first_band.position)
    );
    assert_eq!(
        filter_position(inst, FilterChoice::Position(first_band.position)),
        Ok(first_band.position)
    );
    match filter_position(inst, FilterChoice::BandNm(1234.0)) {
        Err(ConsoleError::Invalid(m)) => assert!(m.contains("its positions"), "{m}"),
        other => panic!("{other:?}"),
    }
    assert!(filter_position(inst, FilterChoice::Position(99)).is_err());
}
