//! The models under stress: every preset, a tabulated model, and random models of every kind with their
//! parameters pushed to the extremes (roughness at the clamp and the delta switch-over, k >> eta, albedo 0 and 1).

use gonio_brdf::measured::MeasuredBrdf;
use gonio_brdf::microfacet::{ALPHA_DELTA, ALPHA_MIN, Distribution, Masking};
use gonio_brdf::models::{Conductor, Lambertian, Mirror, OrenNayar, Phong, Plastic};
use gonio_brdf::{Brdf, Material};

use super::{Rng, WL, c};

fn dist(r: &mut Rng) -> Distribution {
    if r.below(2) == 0 {
        Distribution::Ggx
    } else {
        Distribution::Beckmann
    }
}

fn mask(r: &mut Rng) -> Masking {
    if r.below(2) == 0 {
        Masking::Separable
    } else {
        Masking::HeightCorrelated
    }
}

/// Roughness: log-uniform over [1e-6, 1] with the clamp, the switch-over and the extremes as special values.
fn alpha(r: &mut Rng) -> f64 {
    r.pick(&[1e-6, ALPHA_MIN, ALPHA_DELTA, 1.0], |r| r.log_range(1e-6, 1.0))
}

/// A random model of the given kind (0..6), parameters pushed to their extremes.
pub(super) fn random_model(kind: usize, r: &mut Rng) -> (String, Material) {
    match kind {
        0 => {
            let rho = r.pick(&[0.0, 1.0], |r| r.unit());
            (
                format!("lambertian rho {rho}"),
                Material::Lambertian(Lambertian::new(c(rho)).expect("valid")),
            )
        }
        1 => {
            let rho = r.pick(&[0.0, 1.0], |r| r.unit());
            let sigma = r.pick(&[0.0, 11.4, 17.4, 90.0], |r| r.range(0.0, 90.0));
            (
                format!("oren-nayar rho {rho} sigma {sigma}"),
                Material::OrenNayar(OrenNayar::new(c(rho), sigma).expect("valid")),
            )
        }
        2 => {
            let d = r.pick(&[0.0, 1.0], |r| r.unit());
            let s = (1.0 - d) * r.pick(&[0.0, 1.0], |r| r.unit());
            let n = r.pick(&[0.0, 1.0, 1e6], |r| r.log_range(1.0, 1e5));
            (
                format!("phong kd {d} ks {s} n {n}"),
                Material::Phong(Phong::new(c(d), c(s), n).expect("valid")),
            )
        }
        3 => {
            let (dd, mm) = (dist(r), mask(r));
            let ax = alpha(r);
            // Isotropic or strongly anisotropic (any ratio within [1e-6, 1]).
            let ay = if r.below(2) == 0 { ax } else { alpha(r) };
            let eta = r.pick(&[0.05, 0.2], |r| r.range(0.05, 3.0));
            let k = r.pick(&[0.0, 20.0, 100.0], |r| r.range(0.0, 8.0));
            (
                format!("conductor {dd:?} {mm:?} alpha {ax}x{ay} eta {eta} k {k}"),
                Material::Conductor(Conductor::new(dd, mm, ax, ay, c(eta), c(k)).expect("valid")),
            )
        }
        4 => {
            let (dd, mm) = (dist(r), mask(r));
            let ax = alpha(r);
            let ratio = r.pick(&[1.0, 10.0, 0.1], |r| r.log_range(0.1, 10.0));
            // Anisotropy ratio within the accepted 10; capped at alpha 1 (which only reduces the ratio).
            let ay = (ax * ratio).min(1.0);
            let ior = r.pick(&[1.0, 4.0], |r| r.range(1.0, 4.0));
            let rho = r.pick(&[0.0, 1.0], |r| r.unit());
            (
                format!("plastic {dd:?} {mm:?} alpha {ax}x{ay} ior {ior} rho {rho}"),
                Material::Plastic(Plastic::new(dd, mm, ax, ay, c(ior), c(rho)).expect("valid")),
            )
        }
        _ => {
            let eta = r.pick(&[0.05], |r| r.range(0.05, 3.0));
            let k = r.pick(&[0.0, 20.0], |r| r.range(0.0, 8.0));
            (
                format!("mirror eta {eta} k {k}"),
                Material::Mirror(Mirror::new(c(eta), c(k)).expect("valid")),
            )
        }
    }
}

/// The presets resolved at 550 nm, one tabulated (MERL-grid) model, and `per_kind` random models of each kind.
pub(super) fn models(per_kind: usize, seed: u64) -> Vec<(String, Box<dyn Brdf>)> {
    let mut out: Vec<(String, Box<dyn Brdf>)> = Vec::new();
    for name in Material::preset_names() {
        let m = Material::preset(name)
            .expect("preset")
            .resolved(WL)
            .expect("550 nm");
        out.push((format!("preset {name}"), Box::new(m)));
    }
    let plastic = Plastic::new(
        Distribution::Ggx,
        Masking::HeightCorrelated,
        0.1,
        0.1,
        c(1.5),
        c(0.5),
    )
    .expect("valid");
    out.push((
        "measured (tabulated plastic)".into(),
        Box::new(MeasuredBrdf::tabulate(&plastic, WL).expect("flat")),
    ));
    let mut r = Rng(seed);
    for kind in 0..6 {
        for _ in 0..per_kind {
            let (name, m) = random_model(kind, &mut r);
            out.push((name, Box::new(m)));
        }
    }
    out
}
