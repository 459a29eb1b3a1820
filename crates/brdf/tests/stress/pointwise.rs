//! The pointwise contract of every model (finite, >= 0, 0 below the horizon, reciprocal; delta lobes and samples
//! valid) on the deterministic hostile grid and on random pairs of hostile directions.

use std::f64::consts::{FRAC_PI_2, PI};

use gonio_brdf::{Brdf, Direction};
use gonio_testkit::directions::hostile_directions;

use super::models::models;
use super::{Failures, Rng, WL, large};

/// A random direction of one of the hostile classes.
fn random_direction(r: &mut Rng) -> Direction {
    let phi = r.pick(&[0.0, PI, FRAC_PI_2], |r| r.range(-PI, PI));
    let theta = match r.below(6) {
        0 => r.range(0.0, PI),
        1 | 2 => r.range(0.0, FRAC_PI_2),
        3 => r.pick(&[0.0, 1e-12], |r| r.log_range(1e-16, 1e-4)),
        4 => FRAC_PI_2 - r.pick(&[0.0, 1e-12, -1e-12], |r| r.log_range(1e-16, 1e-4)),
        _ => FRAC_PI_2 + r.log_range(1e-16, 1e-4),
    };
    Direction::from_spherical(theta, phi)
}

/// A random pair: independent directions, or one of the singular relations.
fn random_pair(r: &mut Rng) -> (Direction, Direction) {
    let wi = random_direction(r);
    let wo = match r.below(8) {
        0 => wi,
        1 => wi.reflect_about_normal(),
        2 => wi.neg(),
        // Within 1e-9 rad of the mirror direction (the peak of a sharp lobe).
        3 => wi.reflect_about_normal().rotate_z(r.range(-1e-9, 1e-9)),
        _ => random_direction(r),
    };
    (wi, wo)
}

/// The pointwise contract on one pair: finite, >= 0, 0 below the horizon, reciprocal to 1e-12 relative.
fn check_pair(name: &str, m: &dyn Brdf, wi: &Direction, wo: &Direction, fails: &mut Failures) {
    let (Ok(f), Ok(g)) = (m.eval(wi, wo, WL), m.eval(wo, wi, WL)) else {
        fails.add(format!("{name}: eval errored at {wi:?} {wo:?}"));
        return;
    };
    if !(f.is_finite() && f >= 0.0) {
        fails.add(format!("{name}: f = {f} at wi {wi:?} wo {wo:?}"));
        return;
    }
    if (wi.z() <= 0.0 || wo.z() <= 0.0) && f != 0.0 {
        fails.add(format!(
            "{name}: f = {f} below the horizon at wi {wi:?} wo {wo:?}"
        ));
    }
    let residual = (f - g).abs();
    if residual > 1e-12 * f.max(g) {
        fails.add(format!(
            "{name}: reciprocity {f} vs {g} (rel {:e}) at wi {wi:?} wo {wo:?}",
            residual / f.max(g)
        ));
    }
}

/// The delta lobe and the sampling routine at one incidence: reflectance in [0, 1], unit samples, positive density.
fn check_incidence(name: &str, m: &dyn Brdf, wi: &Direction, u: [f64; 2], fails: &mut Failures) {
    match m.delta_lobe(wi, WL) {
        Ok(Some(d)) if !(d.reflectance.is_finite() && (0.0..=1.0).contains(&d.reflectance)) => {
            fails.add(format!("{name}: delta reflectance {} at {wi:?}", d.reflectance));
        }
        Err(e) => fails.add(format!("{name}: delta_lobe errored {e}")),
        _ => {}
    }
    match m.sample(wi, u, WL) {
        Ok(Some(s)) => {
            let norm = s.wo.x().hypot(s.wo.y()).hypot(s.wo.z());
            if !((norm - 1.0).abs() < 1e-12 && s.pdf_per_sr > 0.0 && !s.pdf_per_sr.is_nan()) {
                fails.add(format!("{name}: sample {s:?} (norm {norm}) at {wi:?} u {u:?}"));
            }
        }
        Ok(None) => {}
        Err(e) => fails.add(format!("{name}: sample errored {e}")),
    }
}

#[test]
fn every_model_survives_the_hostile_grid() {
    let models = models(if large() { 40 } else { 8 }, 1);
    let dirs = hostile_directions();
    let mut fails = Failures::default();
    for (name, m) in &models {
        for wi in &dirs {
            for wo in &dirs {
                check_pair(name, m.as_ref(), wi, wo, &mut fails);
            }
            for wo in [wi.reflect_about_normal(), wi.neg()] {
                check_pair(name, m.as_ref(), wi, &wo, &mut fails);
            }
            for u in [
                [0.0, 0.0],
                [0.5, 0.5],
                [1.0 - f64::EPSILON, 0.999_999],
                [1.0, 1.0],
            ] {
                check_incidence(name, m.as_ref(), wi, u, &mut fails);
            }
        }
    }
    fails.assert_none("hostile grid");
}

#[test]
fn random_geometries_keep_the_pointwise_contract() {
    let pairs: usize = if large() { 10_000_000 } else { 100_000 };
    let models = models(if large() { 40 } else { 8 }, 2);
    let mut r = Rng(3);
    let mut fails = Failures::default();
    for k in 0..pairs {
        let (name, m) = &models[k % models.len()];
        let (wi, wo) = random_pair(&mut r);
        check_pair(name, m.as_ref(), &wi, &wo, &mut fails);
        if k % 16 == 0 {
            let u = [r.unit(), r.unit()];
            check_incidence(name, m.as_ref(), &wi, u, &mut fails);
        }
    }
    fails.assert_none("random geometries");
}
