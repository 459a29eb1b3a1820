//! The beam's imperfections against their models written out here (module doc of
//! simulator/src/imperfections/beam.rs), each effect switched on alone: a Gaussian profile in the direct
//! beam (`1 - exp(-2 a^2 / w_d^2)`), on a small sample (closed form at normal incidence, a brute-force quadrature
//! when tilted) and in the sample's footprint mean; the pointing error in the true incidence direction and the
//! spot, also with the arms' eccentricity; the true divergence in the direct beam's cone (planar lens formula).

use gonio_instrument::{
    BeamImperfections, BeamProfile, GeometryImperfections, InstrumentFile, SampleImperfections,
};
use gonio_simulator::imperfections::{BeamTruth, HiddenTruth};
use gonio_simulator::optics::Optics;
use gonio_simulator::scene::Scene;

use super::{BAND_550, optics, optics_of_radius, pose};

/// The simulated instrument (config/instruments/simulated.toml): aperture radius and distance (mm), the
/// nominal full divergence (degrees).
const APERTURE_MM: f64 = 2.5;
const DETECTOR_MM: f64 = 250.0;
const DIVERGENCE_DEG: f64 = 0.05;

fn file(beam: BeamImperfections, seed: u64) -> InstrumentFile {
    let mut f = InstrumentFile::simulated();
    f.simulator.seed = seed;
    f.simulator.imperfections.beam = beam;
    f
}

fn gaussian(w_mm: f64) -> BeamImperfections {
    BeamImperfections {
        profile: BeamProfile::Gaussian,
        gaussian_radius_mm: w_mm,
        ..Default::default()
    }
}

fn beam_truth(f: &InstrumentFile) -> BeamTruth {
    HiddenTruth::draw(f).and_then(|h| h.beam).expect("beam truth")
}

#[test]
fn a_gaussian_wider_than_the_aperture_loses_its_tails_in_the_direct_beam() {
    let w = 3.0;
    let f = file(gaussian(w), 31);
    let (ideal, o) = (optics(&InstrumentFile::simulated()), optics(&f));
    ideal.set_sample_mounted(false);
    o.set_sample_mounted(false);
    let p = Optics::direct_beam_pose(-90.0);
    let r0 = ideal.reading(&p, &BAND_550, 5.0).expect("reading");
    let r1 = o.reading(&p, &BAND_550, 5.0).expect("reading");
    assert_eq!(
        r0.intercepted_fraction, 1.0,
        "the top-hat cone lies inside the aperture"
    );
    // At the aperture the Gaussian has spread by the divergence's 1/e^2 half-angle over the distance.
    let spread = DETECTOR_MM * (0.5 * DIVERGENCE_DEG).to_radians().tan();
    let w_d2 = w * w + spread * spread;
    let expected = 1.0 - (-2.0 * APERTURE_MM * APERTURE_MM / w_d2).exp();
    let ratio = r1.power_w / r0.power_w;
    assert!((ratio - expected).abs() < 1e-12, "{ratio} vs {expected}");
    assert!(expected < 0.99, "the tails are lost: {expected}");
    let direct = o.direct_beam_power_w(&BAND_550, 5.0) / ideal.direct_beam_power_w(&BAND_550, 5.0);
    assert!((direct - expected).abs() < 1e-12, "{direct} vs {expected}");
    // The attribution says the same.
    Scene::detector_power_w(&o, &p, &BAND_550, 5.0);
    let rel = o.last_effects().expect("effects").beam_fraction_rel;
    assert!((rel - (expected - 1.0)).abs() < 1e-12, "{rel}");
}

/// The fraction of a Gaussian (1/e^2 radius `w`) arriving at `theta` on a centred disc of radius `r_s`, by
/// brute force in the sample plane: intensity `2 / (pi w^2) exp(-2 rho^2 / w^2)` across the beam, with
/// `rho^2 = x^2 cos^2 theta + y^2` (x along the plane of incidence), times `cos theta` per unit area of the plane.
fn gaussian_on_disc(w: f64, r_s: f64, theta: f64) -> f64 {
    let (nr, np) = (1500, 1500);
    let c = theta.cos();
    let mut sum = 0.0;
    for i in 0..nr {
        let r = (i as f64 + 0.5) * r_s / nr as f64;
        for j in 0..np {
            let phi = (j as f64 + 0.5) * std::f64::consts::TAU / np as f64;
            let (x, y) = (r * phi.cos(), r * phi.sin());
            let rho2 = x * x * c * c + y * y;
            sum += (-2.0 * rho2 / (w * w)).exp() * r;
        }
    }
    sum * (r_s / nr as f64) * (std::f64::consts::TAU / np as f64) * 2.0 / (std::f64::consts::PI * w * w) * c
}

#[test]
fn a_gaussian_beam_overfills_a_small_sample_by_its_weight_beyond_the_edge() {
    let (w, r_s) = (1.5, 2.0);
    let f = file(gaussian(w), 31);
    let (ideal, o) = (
        optics_of_radius(&InstrumentFile::simulated(), r_s),
        optics_of_radius(&f, r_s),
    );
    // Normal incidence: the disc's share of a centred circular Gaussian, 1 - exp(-2 R^2 / w^2).
    let p = pose(0.0, -30.0, 0.0, 0.0);
    let r0 = ideal.reading(&p, &BAND_550, 5.0).expect("reading");
    let r1 = o.reading(&p, &BAND_550, 5.0).expect("reading");
    let expected = 1.0 - (-2.0 * r_s * r_s / (w * w)).exp();
    assert_eq!(r0.intercepted_fraction, 1.0);
    assert!((r1.power_w / r0.power_w - expected).abs() < 1e-12, "{r1:?}");
    assert!(r1.overfilled_sample && !r0.overfilled_sample);
    // 60 degrees: the footprint stretches by 2 along the plane of incidence.
    let p = pose(60.0, -20.0, 0.0, 0.0);
    let r0 = ideal.reading(&p, &BAND_550, 5.0).expect("reading");
    let r1 = o.reading(&p, &BAND_550, 5.0).expect("reading");
    let expected = gaussian_on_disc(w, r_s, 60f64.to_radians());
    assert!(
        (r1.intercepted_fraction - expected).abs() < 1e-5,
        "{} vs {expected}",
        r1.intercepted_fraction
    );
    let ratio = r1.power_w / r0.power_w;
    let fractions = r1.intercepted_fraction / r0.intercepted_fraction;
    assert!(
        (ratio - fractions).abs() < 1e-12,
        "only the footprint changes: {ratio} vs {fractions}"
    );
}

#[test]
fn the_sample_s_footprint_mean_is_weighted_by_the_gaussian() {
    // Not the nominal top hat's 1.5 mm, so that the weighting shows.
    let w = 1.2;
    let uneven = SampleImperfections {
        gradient_sd: 0.02,
        radial_sd: 0.05,
    };
    let mut both = file(gaussian(w), 21);
    both.simulator.imperfections.sample = uneven;
    let (o, gaussian_only) = (optics(&both), optics(&file(gaussian(w), 21)));
    let s = HiddenTruth::draw(&both)
        .and_then(|h| h.sample)
        .expect("sample truth");
    for theta_i in [0.0f64, 50.0, 80.0] {
        let p = pose(theta_i, -(theta_i - 30.0).abs().max(10.0), 0.0, 0.0);
        let r0 = gaussian_only.reading(&p, &BAND_550, 5.0).expect("reading");
        let r1 = o.reading(&p, &BAND_550, 5.0).expect("reading");
        // Second moments of the Gaussian footprint: w^2 / (4 cos^2) along the plane of incidence, w^2 / 4
        // across; the spot is the centre (no pointing, no eccentricity), so only the radial term acts.
        let c = theta_i.to_radians().cos();
        let second = w * w / (4.0 * c * c) + w * w / 4.0;
        let expected = 1.0 + s.radial * second / (25.0 * 25.0);
        let ratio = r1.power_w / r0.power_w;
        assert!(
            (ratio - expected).abs() < 1e-12,
            "{theta_i}: {ratio} vs {expected}"
        );
    }
}

/// Unit vector.
fn unit(v: [f64; 3]) -> [f64; 3] {
    let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    [v[0] / n, v[1] / n, v[2] / n]
}

/// The pointed beam of the module doc at tilt 0, rotation 0 (sample x' = lab Y, y' = lab Z, normal = lab X),
/// with the arms' axis through `c` (lab): (wi, spot, wo) in the sample frame.
fn pointed(t: &BeamTruth, light_deg: f64, detector_deg: f64, c: [f64; 3]) -> ([f64; 3], [f64; 2], [f64; 3]) {
    let a = light_deg.to_radians();
    let s = [a.cos(), a.sin(), 0.0];
    let e1 = [-a.sin(), a.cos(), 0.0];
    let (t1, t2) = (
        t.pointing_deg[0].to_radians().tan(),
        t.pointing_deg[1].to_radians().tan(),
    );
    let sp = unit([s[0] + t1 * e1[0], s[1] + t1 * e1[1], t2]);
    let l = t.source_distance_mm;
    let origin = [c[0] + l * s[0], c[1] + l * s[1], c[2]];
    // The beam meets the plane X = 0.
    let k = origin[0] / sp[0];
    let p = [
        origin[0] - k * sp[0],
        origin[1] - k * sp[1],
        origin[2] - k * sp[2],
    ];
    let d = detector_deg.to_radians();
    let aperture = [c[0] + DETECTOR_MM * d.cos(), c[1] + DETECTOR_MM * d.sin(), c[2]];
    let wo = unit([aperture[0] - p[0], aperture[1] - p[1], aperture[2] - p[2]]);
    ([sp[1], sp[2], sp[0]], [p[1], p[2]], [wo[1], wo[2], wo[0]])
}

fn assert_close(got: [f64; 3], want: [f64; 3], tol: f64) {
    assert!(
        (0..3).all(|k| (got[k] - want[k]).abs() < tol),
        "{got:?} vs {want:?}"
    );
}

#[test]
fn the_pointing_error_turns_the_incidence_by_the_drawn_angle_and_moves_the_spot() {
    let beam = BeamImperfections {
        pointing_sd_deg: 0.2,
        source_distance_mm: 400.0,
        ..Default::default()
    };
    let f = file(beam, 11);
    let t = beam_truth(&f);
    assert!(
        t.pointing_deg[0].abs() > 0.02 && t.pointing_deg[1].abs() > 0.02,
        "{t:?}"
    );
    let o = optics(&f);
    let (light, detector) = (40.0, -10.0);
    let r = o
        .reading(&pose(light, detector, 0.0, 0.0), &BAND_550, 5.0)
        .expect("reading");
    let (wi, spot, wo) = pointed(&t, light, detector, [0.0; 3]);
    assert_close([r.wi.x(), r.wi.y(), r.wi.z()], wi, 1e-12);
    assert_close([r.wo.x(), r.wo.y(), r.wo.z()], wo, 1e-12);
    assert!(
        (r.spot_mm[0] - spot[0]).abs() < 1e-9 && (r.spot_mm[1] - spot[1]).abs() < 1e-9,
        "{r:?}"
    );
    // The specular direction turns with the beam: theta_i is the arm's angle plus the in-plane pointing (to
    // second order in the vertical one), and the spot moved by about L times the angle.
    let theta_i = r.wi.theta().to_degrees();
    assert!(
        (theta_i - (light + t.pointing_deg[0])).abs() < 2e-3,
        "{theta_i} {t:?}"
    );
    assert!(spot[0].hypot(spot[1]) > 400.0 * 0.02f64.to_radians());
}

#[test]
fn the_pointing_error_composes_with_the_arms_eccentricity() {
    let beam = BeamImperfections {
        pointing_sd_deg: 0.2,
        source_distance_mm: 400.0,
        ..Default::default()
    };
    let mut f = file(beam, 11);
    f.simulator.imperfections.geometry = GeometryImperfections {
        eccentricity_sd_mm: 1.0,
        ..Default::default()
    };
    let h = HiddenTruth::draw(&f).expect("truth");
    let (t, g) = (h.beam.expect("beam"), h.geometry.expect("geometry"));
    let c = [g.eccentricity_mm[0], g.eccentricity_mm[1], 0.0];
    let o = optics(&f);
    let (light, detector) = (35.0, -25.0);
    let r = o
        .reading(&pose(light, detector, 0.0, 0.0), &BAND_550, 5.0)
        .expect("reading");
    let (wi, spot, wo) = pointed(&t, light, detector, c);
    assert_close([r.wi.x(), r.wi.y(), r.wi.z()], wi, 1e-12);
    assert_close([r.wo.x(), r.wo.y(), r.wo.z()], wo, 1e-12);
    assert!(
        (r.spot_mm[0] - spot[0]).abs() < 1e-9 && (r.spot_mm[1] - spot[1]).abs() < 1e-9,
        "{r:?}"
    );
}

/// The fraction of a disc of radius `r1` inside a disc of radius `r2`, centres `g` apart (planar lens area).
fn lens_fraction(r1: f64, r2: f64, g: f64) -> f64 {
    if g + r1 <= r2 {
        return 1.0;
    }
    if g >= r1 + r2 {
        return 0.0;
    }
    let a1 = ((g * g + r1 * r1 - r2 * r2) / (2.0 * g * r1)).acos();
    let a2 = ((g * g + r2 * r2 - r1 * r1) / (2.0 * g * r2)).acos();
    let k = ((-g + r1 + r2) * (g + r1 - r2) * (g - r1 + r2) * (g + r1 + r2)).sqrt();
    (r1 * r1 * a1 + r2 * r2 * a2 - 0.5 * k) / (std::f64::consts::PI * r1 * r1)
}

#[test]
fn the_true_divergence_sets_how_much_of_the_direct_beam_s_cone_enters_the_aperture() {
    let nominal_deg = 0.2;
    let mut f = file(
        BeamImperfections {
            divergence_sd_deg: 0.1,
            ..Default::default()
        },
        5,
    );
    f.instrument.source.divergence_deg = nominal_deg;
    let mut plain = InstrumentFile::simulated();
    plain.instrument.source.divergence_deg = nominal_deg;
    let t = beam_truth(&f);
    assert!((t.divergence_deg - nominal_deg).abs() > 0.02, "{t:?}");
    let (ideal, o) = (optics(&plain), optics(&f));
    ideal.set_sample_mounted(false);
    o.set_sample_mounted(false);
    // The detector turned off the beam so that the aperture's edge cuts the divergence cone.
    let beta = (APERTURE_MM / DETECTOR_MM).atan();
    let g = beta + 0.25 * nominal_deg.to_radians();
    let p = gonio_simulator::scene::Pose {
        detector_deg: 90.0 + g.to_degrees(),
        ..Optics::direct_beam_pose(-90.0)
    };
    let r0 = ideal.reading(&p, &BAND_550, 5.0).expect("reading");
    let r1 = o.reading(&p, &BAND_550, 5.0).expect("reading");
    let (half_nominal, half_true) = (
        0.5 * nominal_deg.to_radians(),
        0.5 * t.divergence_deg.to_radians(),
    );
    let f0 = lens_fraction(half_nominal, beta, g);
    let f1 = lens_fraction(half_true, beta, g);
    // Planar against spherical caps: relative differences of the order of the angles squared (1e-4).
    assert!(
        (r0.intercepted_fraction / f0 - 1.0).abs() < 1e-3,
        "{} vs {f0}",
        r0.intercepted_fraction
    );
    let ratio = r1.power_w / r0.power_w;
    assert!((ratio / (f1 / f0) - 1.0).abs() < 1e-3, "{ratio} vs {}", f1 / f0);
    assert!(
        (ratio - 1.0).abs() > 0.05,
        "the drawn divergence matters here: {ratio}"
    );
}

fn mirror_optics(f: &InstrumentFile) -> Optics {
    let material = gonio_brdf::Material::from_document(
        "[material]\nmodel = \"mirror\"\neta = 1.5\nk = 0.0\n",
        "test",
        std::path::Path::new("."),
    )
    .expect("valid material");
    Optics::new(
        &f.instrument,
        gonio_simulator::optics::SampleSpec {
            material,
            radius_mm: 25.0,
            orientation_deg: 0.0,
        },
        f.simulator.seed,
    )
    .expect("optics")
    .with_source_noise(false)
    .with_source_drift(false)
    .with_hidden_truth(HiddenTruth::draw(f).as_ref())
}

/// A Gaussian's (1/e^2 radius `w`) power through a disc of radius `a` whose centre is `s` from the beam's axis,
/// by brute force in polar coordinates about the disc's centre.
fn gaussian_through(w: f64, a: f64, s: f64) -> f64 {
    let (nr, np) = (800, 800);
    let mut sum = 0.0;
    for i in 0..nr {
        let r = (i as f64 + 0.5) * a / nr as f64;
        for j in 0..np {
            let phi = (j as f64 + 0.5) * std::f64::consts::TAU / np as f64;
            let (x, y) = (r * phi.cos() + s, r * phi.sin());
            sum += (-2.0 * (x * x + y * y) / (w * w)).exp() * r;
        }
    }
    sum * (a / nr as f64) * (std::f64::consts::TAU / np as f64) * 2.0 / (std::f64::consts::PI * w * w)
}

#[test]
fn a_mirror_s_reflected_gaussian_loses_the_same_tails_as_the_direct_beam() {
    let w = 3.0;
    let f = file(gaussian(w), 31);
    let (ideal, o) = (mirror_optics(&InstrumentFile::simulated()), mirror_optics(&f));
    let spread = DETECTOR_MM * (0.5 * DIVERGENCE_DEG).to_radians().tan();
    let w_d = w.hypot(spread);
    // At the mirror direction and 0.3 degrees off it: the reflected beam's axis passes d sin(g) from the
    // aperture's centre. The ideal top-hat cone (0.025 deg) lies wholly inside the aperture (0.57 deg) at both.
    for g_deg in [0.0f64, 0.3] {
        let p = pose(30.0, -30.0 - g_deg, 0.0, 0.0);
        let r0 = ideal.reading(&p, &BAND_550, 5.0).expect("reading");
        let r1 = o.reading(&p, &BAND_550, 5.0).expect("reading");
        let expected = gaussian_through(w_d, APERTURE_MM, DETECTOR_MM * g_deg.to_radians().sin());
        let ratio = r1.power_w / r0.power_w;
        assert!((ratio - expected).abs() < 2e-6, "{g_deg}: {ratio} vs {expected}");
        assert_eq!(
            r1.truth_aperture_sr, r0.truth_aperture_sr,
            "the truth is the nominal beam's"
        );
    }
    // The calibration sees the same loss: mirror reading over direct beam is the mirror's reflectance.
    let p = pose(30.0, -30.0, 0.0, 0.0);
    let reflectance = |o: &Optics| {
        let on_mirror = o.reading(&p, &BAND_550, 5.0).expect("reading").power_w;
        on_mirror / o.direct_beam_power_w(&BAND_550, 5.0)
    };
    let (a, b) = (reflectance(&ideal), reflectance(&o));
    assert!((a / b - 1.0).abs() < 1e-12, "{a} vs {b}");
}
