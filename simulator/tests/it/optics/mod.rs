//! The simulated optics against independent expectations: closed forms (Lambertian, mirror, gold's R0), brute-force
//! references written here from scratch (aperture integrals by a fine Simpson x trapezoid rule, footprint areas by
//! counting grid cells), and the reproducibility of the source model.
//!
//! One module per part of the optics: closed forms (`closed_forms`), the beam on the sample (`footprint`), the
//! aperture integral against brute force (`aperture`) and its own error estimate (`estimates`), the source over
//! time (`source`), and the sample itself (`sample`). The shared set-up and brute-force references are here.

mod aperture;
mod closed_forms;
mod estimates;
mod footprint;
mod sample;
mod source;

use std::f64::consts::PI;
use std::path::Path;

use gonio_brdf::{Direction, Material, Wavelength};
use gonio_instrument::{Instrument, InstrumentFile};
use gonio_simulator::optics::{Optics, SampleSpec};
use gonio_simulator::scene::{Band, Pose};

const BAND_550: Band = Band {
    band_nm: Some(550.0),
    transmission: 0.5,
};

fn instrument() -> Instrument {
    InstrumentFile::simulated().instrument
}

fn material(toml: &str) -> Material {
    Material::from_document(toml, "test", Path::new(".")).expect("valid material")
}

fn sample(material: Material, radius_mm: f64) -> SampleSpec {
    SampleSpec {
        material,
        radius_mm,
        orientation_deg: 0.0,
    }
}

/// Optics with drift and noise off: readings are then exactly the physics.
fn quiet(instrument: &Instrument, s: SampleSpec) -> Optics {
    Optics::new(instrument, s, 1)
        .expect("optics")
        .with_source_noise(false)
        .with_source_drift(false)
}

fn pose(light_deg: f64, detector_deg: f64, tilt_deg: f64, rotation_deg: f64) -> Pose {
    Pose {
        light_deg,
        detector_deg,
        tilt_deg,
        rotation_deg,
    }
}

fn wl(nm: f64) -> Wavelength {
    Wavelength::from_nm(nm).expect("wavelength")
}

/// Brute-force `∫_cone g(w) d omega` over the cone about `axis` of half-angle `beta`: composite Simpson in
/// u = 1 - cos(rho) (d omega = du dphi, no Jacobian) times the trapezoid rule in phi. Directions below the horizon
/// contribute nothing (only used here for cones above it).
fn brute_cone(
    axis: &Direction,
    beta: f64,
    nu: usize,
    nphi: usize,
    g: &mut dyn FnMut(&Direction) -> f64,
) -> f64 {
    let a = [axis.x(), axis.y(), axis.z()];
    // A perpendicular pair, built differently from the simulator's.
    let helper = if a[2].abs() < 0.9 {
        [0.0, 0.0, 1.0]
    } else {
        [0.0, 1.0, 0.0]
    };
    let mut e1 = [
        a[1] * helper[2] - a[2] * helper[1],
        a[2] * helper[0] - a[0] * helper[2],
        a[0] * helper[1] - a[1] * helper[0],
    ];
    let n = (e1[0] * e1[0] + e1[1] * e1[1] + e1[2] * e1[2]).sqrt();
    e1 = [e1[0] / n, e1[1] / n, e1[2] / n];
    let e2 = [
        a[1] * e1[2] - a[2] * e1[1],
        a[2] * e1[0] - a[0] * e1[2],
        a[0] * e1[1] - a[1] * e1[0],
    ];
    let umax = 2.0 * (beta / 2.0).sin().powi(2);
    let h = umax / nu as f64;
    let mut total = 0.0;
    for i in 0..=nu {
        let u = i as f64 * h;
        let simpson = if i == 0 || i == nu {
            1.0
        } else if i % 2 == 1 {
            4.0
        } else {
            2.0
        };
        let (cr, sr) = (1.0 - u, (u * (2.0 - u)).max(0.0).sqrt());
        let mut ring = 0.0;
        for j in 0..nphi {
            let phi = (j as f64 + 0.25) * 2.0 * PI / nphi as f64;
            let (sp, cp) = phi.sin_cos();
            let w = [0, 1, 2].map(|k| cr * a[k] + sr * (cp * e1[k] + sp * e2[k]));
            if w[2] <= 0.0 {
                continue;
            }
            let d = Direction::new(w[0], w[1], w[2]).expect("unit");
            ring += g(&d);
        }
        total += simpson * ring * 2.0 * PI / nphi as f64;
    }
    total * h / 3.0
}

fn beta_of(instrument: &Instrument) -> f64 {
    (instrument.detector.aperture_radius_mm / instrument.detector.distance_mm).atan()
}

/// A random (wi, wo) above the horizon for a cone of half-angle beta: wi up to 80 deg; wo anywhere up to
/// 85 deg - beta, or, `near_mirror`, within 3 beta of wi's mirror direction, where the lobes are.
fn random_geometry(
    uniform: &mut impl FnMut() -> f64,
    beta: f64,
    near_mirror: bool,
) -> (Direction, Direction) {
    let wi = Direction::from_spherical(uniform() * 80f64.to_radians(), uniform() * 2.0 * PI);
    let max_theta_o = 85f64.to_radians() - beta;
    let wo = if near_mirror {
        let m = wi.reflect_about_normal();
        let theta = (m.theta() + (uniform() - 0.5) * 6.0 * beta).clamp(0.0, max_theta_o);
        Direction::from_spherical(theta, m.phi() + (uniform() - 0.5) * 6.0 * beta)
    } else {
        Direction::from_spherical(uniform() * max_theta_o, uniform() * 2.0 * PI)
    };
    (wi, wo)
}
