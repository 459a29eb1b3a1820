use super::*;
use gonio_brdf::radiometry::projected_solid_angle_sr;

fn white() -> Material {
    Material::from_document(
        "[material]\nmodel = \"lambertian\"\nalbedo = 1.0\n",
        "test",
        std::path::Path::new("."),
    )
    .expect("lambertian")
}

#[test]
fn the_reference_and_the_fixed_rule_clip_a_cone_at_the_horizon_exactly() {
    // f = 1/pi: the integral is the cone's projected solid angle above the horizon over pi, which the
    // clipped-cap formula gives in closed form.
    let m = white();
    let wi = Direction::NORMAL;
    for (theta_deg, beta) in [(30.0, 0.1), (87.0, 0.1), (89.9, 0.05), (88.0, 0.0523)] {
        let axis = Direction::from_spherical_deg(theta_deg, 20.0);
        let exact = projected_solid_angle_sr(&axis, beta) / PI;
        let brute = brute_cone(&m, &wi, &axis, beta, 400, 400);
        assert!(
            (brute - exact).abs() <= 1e-9 * exact,
            "{theta_deg}: {brute} vs {exact}"
        );
        // The fixed rule converges to it (slowly across the horizon: the ring integral has a kink there).
        let fixed = fixed_rule(&m, &wi, &axis, beta, 64);
        assert!(
            (fixed - exact).abs() <= 1e-5 * exact,
            "{theta_deg}: {fixed} vs {exact}"
        );
    }
}

#[test]
fn the_visible_arc_is_where_the_ring_is_above_the_horizon() {
    let axis = Direction::from_spherical_deg(88.0, 0.0);
    let a = [axis.x(), axis.y(), axis.z()];
    let (e1, e2) = basis(&axis);
    let rho = 0.06f64;
    let (sr, cr) = rho.sin_cos();
    let Arc::Part { phi0, half } = visible_arc(&a, &e1, &e2, sr, cr) else {
        panic!("the ring crosses the horizon");
    };
    let height = |phi: f64| cr * a[2] + sr * (phi.cos() * e1[2] + phi.sin() * e2[2]);
    assert!(height(phi0) > 0.0 && height(phi0 + half * 0.999) > 0.0);
    assert!(height(phi0 + half * 1.001) < 0.0 && height(phi0 + PI) < 0.0);
    assert!(height(phi0 + half).abs() < 1e-15);
    // A small ring near the axis is whole; a cone below the horizon has nothing.
    let (s, c) = 0.01f64.sin_cos();
    assert_eq!(visible_arc(&a, &e1, &e2, s, c), Arc::Full);
    let down = [a[0], a[1], -a[2]];
    assert_eq!(visible_arc(&down, &e1, &e2, s, c), Arc::Empty);
}
