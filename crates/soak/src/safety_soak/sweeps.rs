//! The random sweeps of the safety soak's cases (`[[plan.sweeps]]`, issue 41), drawn from a stream of their own.

use gonio_scheduler::plan::{SweepSpec, SweptArm};
use rand::Rng;
use rand_chacha::ChaCha8Rng;

use super::round1;

/// A random sweep (its own stream: the cases without sweeps are drawn as before sweeps existed): either arm, an
/// arc of 20 to 150 degrees with the other arm held, one plane, 0.5 to 15 deg/s (below every arm's top speed).
fn random_sweep(rng: &mut ChaCha8Rng) -> SweepSpec {
    let arc = |rng: &mut ChaCha8Rng| {
        let from = round1(rng.random_range(-80.0..0.0f64));
        let to = round1((from + rng.random_range(20.0..150.0f64)).min(80.0));
        toml::Value::Table(toml::Table::from_iter([
            ("from".to_string(), toml::Value::Float(from)),
            ("to".to_string(), toml::Value::Float(to)),
        ]))
    };
    let held = |rng: &mut ChaCha8Rng, max: f64| {
        toml::Value::Array(vec![toml::Value::Float(round1(rng.random_range(0.0..max)))])
    };
    let arm = if rng.random_bool(0.5) {
        SweptArm::Detector
    } else {
        SweptArm::Light
    };
    let (theta_i_deg, theta_o_deg) = match arm {
        SweptArm::Detector => (held(rng, 60.0), arc(rng)),
        SweptArm::Light => (arc(rng), held(rng, 70.0)),
    };
    SweepSpec {
        arm,
        theta_i_deg,
        theta_o_deg,
        plane_phi_deg: Some(toml::Value::Array(vec![toml::Value::Float(round1(
            rng.random_range(0.0..180.0f64),
        ))])),
        speed_deg_s: round1(rng.random_range(0.5..15.0f64)),
        averaging: rng.random_range(1..4u32),
        follow: None,
        isotropic: false,
    }
}

/// The sweeps of a case, if it has any, and whether it has no points: a stream of its own.
pub(super) fn random_sweeps(rng: &mut ChaCha8Rng) -> (Vec<SweepSpec>, bool) {
    if rng.random_range(0..3u32) != 0 {
        return (Vec::new(), false);
    }
    let n = rng.random_range(1..3usize);
    let sweeps = (0..n).map(|_| random_sweep(rng)).collect();
    (sweeps, rng.random_bool(0.5))
}
