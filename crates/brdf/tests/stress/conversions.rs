//! Direction conversions at hostile angles: spherical angles, half/difference angles and isotropic angles round
//! trip, and antipodal pairs have no half vector.

use gonio_brdf::Direction;
use gonio_brdf::geometry::{HalfDiff, IsotropicAngles};
use gonio_testkit::directions::hostile_directions;

use super::Failures;

#[test]
fn conversions_round_trip_at_hostile_angles() {
    let mut fails = Failures::default();
    let dirs = hostile_directions();
    for d in &dirs {
        let (t, p) = d.to_spherical();
        let back = Direction::from_spherical(t, p);
        if d.angle_to(&back) > 1e-15 {
            fails.add(format!("spherical: {d:?} -> ({t}, {p}) -> {back:?}"));
        }
        let (td, pd) = d.to_spherical_deg();
        let back = Direction::from_spherical_deg(td, pd);
        if d.angle_to(&back) > 1e-15 {
            fails.add(format!("spherical deg: {d:?} -> ({td}, {pd}) -> {back:?}"));
        }
    }
    // Exactly on the horizon and exactly at the pole in degrees.
    assert_eq!(Direction::from_spherical_deg(90.0, 17.0).z(), 0.0);
    assert_eq!(Direction::from_spherical_deg(0.0, 17.0), Direction::NORMAL);
    for wi in &dirs {
        for wo in dirs.iter().chain([wi.reflect_about_normal(), *wi].iter()) {
            // Half/difference angles: exact inverse wherever the half vector is well defined. Its conditioning
            // is 1 / |wi + wo|; pairs closer to antipodal than 1e-6 are out of scope (the half vector is then
            // undefined to the precision of the inputs).
            let s = (wi.x() + wo.x()).hypot(wi.y() + wo.y()).hypot(wi.z() + wo.z());
            if s > 1e-6 {
                let hd = HalfDiff::from_directions(wi, wo).expect("defined");
                let (a, b) = hd.to_directions();
                let tol = 1e-14 / s + 1e-14;
                if wi.angle_to(&a) > tol || wo.angle_to(&b) > tol {
                    fails.add(format!(
                        "half-diff: {wi:?} {wo:?} -> {hd:?} -> errors {:e} {:e}",
                        wi.angle_to(&a),
                        wo.angle_to(&b)
                    ));
                }
            }
            let iso = IsotropicAngles::from_directions(wi, wo);
            let (a, b) = iso.to_directions();
            let back = IsotropicAngles::from_directions(&a, &b);
            let bad = (back.theta_i - iso.theta_i).abs() > 1e-14
                || (back.theta_o - iso.theta_o).abs() > 1e-14
                || (wi.sin_theta() > 1e-6
                    && wo.sin_theta() > 1e-6
                    && (back.delta_phi - iso.delta_phi).abs() > 1e-12);
            if bad {
                fails.add(format!("isotropic: {iso:?} -> {back:?}"));
            }
        }
        // Antipodal: no half vector, reported as None rather than a NaN.
        assert!(HalfDiff::from_directions(wi, &wi.neg()).is_none(), "{wi:?}");
    }
    fails.assert_none("conversions");
}
