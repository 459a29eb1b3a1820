//! Each geometric imperfection alone, against the reference geometry written out here: the sample frame at tilt
//! t and rotation r is `n = (cos t, 0, sin t)`, `y = (-sin t, 0, cos t)`, `x = (0, 1, 0)`, then
//! `x' = cos r x + sin r y`, `y' = -sin r x + cos r y`; an arm at angle a points along `(cos a, sin a, 0)`
//! (crates/instrument/src/lib.rs). A Lambertian sample fully lit sends `P_i T (albedo / pi) pi sin^2(beta)
//! cos(theta_o)` into the aperture cone, so an effect that moves the detector's true direction scales the reading
//! by `cos(theta_o true) / cos(theta_o nominal)` exactly.

use gonio_brdf::Direction;
use gonio_instrument::{AxisRole, GeometryImperfections};

use super::{BAND_550, file_with, geometry_truth, optics, optics_of_radius, pose};

type V = [f64; 3];

fn dot(a: &V, b: &V) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn arm(a_deg: f64) -> V {
    let (s, c) = a_deg.to_radians().sin_cos();
    [c, s, 0.0]
}

/// (x', y', n) of the stage at tilt and rotation (degrees).
fn stage(t_deg: f64, r_deg: f64) -> [V; 3] {
    let (st, ct) = t_deg.to_radians().sin_cos();
    let (sr, cr) = r_deg.to_radians().sin_cos();
    let (x, y, n) = ([0.0, 1.0, 0.0], [-st, 0.0, ct], [ct, 0.0, st]);
    let xp = [
        cr * x[0] + sr * y[0],
        cr * x[1] + sr * y[1],
        cr * x[2] + sr * y[2],
    ];
    let yp = [
        -sr * x[0] + cr * y[0],
        -sr * x[1] + cr * y[1],
        -sr * x[2] + cr * y[2],
    ];
    [xp, yp, n]
}

fn comps(v: &V, f: &[V; 3]) -> V {
    [dot(v, &f[0]), dot(v, &f[1]), dot(v, &f[2])]
}

fn assert_dir(d: &Direction, v: V, tol: f64, what: &str) {
    let got = [d.x(), d.y(), d.z()];
    assert!(
        (0..3).all(|k| (got[k] - v[k]).abs() < tol),
        "{what}: got {got:?}, expected {v:?}"
    );
}

/// The normal of a sample tilted by (tx, ty) degrees in the stage frame `f`, from the model's definition:
/// tipped by tau = |t| towards azimuth alpha = atan2(ty, tx).
fn tilted_normal(f: &[V; 3], tx_deg: f64, ty_deg: f64) -> V {
    let tau = tx_deg.hypot(ty_deg).to_radians();
    let alpha = ty_deg.atan2(tx_deg);
    let (st, ct) = tau.sin_cos();
    let (sa, ca) = alpha.sin_cos();
    [0, 1, 2].map(|k| ct * f[2][k] + st * (ca * f[0][k] + sa * f[1][k]))
}

/// Power of a reading on the imperfect optics over the same reading on the ideal ones.
fn power_ratio(file: &gonio_instrument::InstrumentFile, p: &gonio_simulator::scene::Pose) -> f64 {
    let ideal = optics(&file_with(GeometryImperfections::default(), 1));
    let a = optics(file).reading(p, &BAND_550, 0.0).expect("reading");
    let b = ideal.reading(p, &BAND_550, 0.0).expect("reading");
    a.power_w / b.power_w
}

#[test]
fn zero_offsets_alone_turn_every_axis_by_its_hidden_offset() {
    let file = file_with(
        GeometryImperfections {
            zero_offset_sd_deg: 0.05,
            ..Default::default()
        },
        11,
    );
    let truth = geometry_truth(&file);
    let delta = |role| {
        truth
            .axes
            .iter()
            .find(|a| a.role == role)
            .expect("axis")
            .zero_offset_deg
    };
    let o = optics(&file);
    for (l, d, t, r) in [
        (30.0, -40.0, 0.0, 0.0),
        (20.0, -50.0, 15.0, 30.0),
        (-35.0, 25.0, -20.0, 170.0),
    ] {
        let (lt, dt) = (l + delta(AxisRole::LightArm), d + delta(AxisRole::DetectorArm));
        let f = stage(
            t + delta(AxisRole::SampleTilt),
            r + delta(AxisRole::SampleRotation),
        );
        let reading = o.reading(&pose(l, d, t, r), &BAND_550, 0.0).expect("reading");
        let (wi, wo) = (comps(&arm(lt), &f), comps(&arm(dt), &f));
        assert_dir(&reading.wi, wi, 1e-12, "wi");
        assert_dir(&reading.wo, wo, 1e-12, "wo");
        let nominal_cos_o = comps(&arm(d), &stage(t, r))[2];
        let ratio = power_ratio(&file, &pose(l, d, t, r));
        assert!((ratio - wo[2] / nominal_cos_o).abs() < 1e-9, "ratio {ratio}");
        assert!((ratio - 1.0).abs() > 1e-6, "the offsets change the reading");
    }
}

#[test]
fn the_periodic_encoder_error_alone_follows_its_harmonic() {
    let (amplitude, harmonic) = (0.01, 3);
    let file = file_with(
        GeometryImperfections {
            encoder_error_amplitude_deg: amplitude,
            encoder_error_harmonic: harmonic,
            ..Default::default()
        },
        12,
    );
    let truth = geometry_truth(&file);
    let err = |role, a_deg: f64| {
        let axis = truth.axes.iter().find(|a| a.role == role).expect("axis");
        assert_eq!(axis.zero_offset_deg, 0.0);
        amplitude
            * (f64::from(harmonic) * a_deg + axis.encoder_phase_deg)
                .to_radians()
                .sin()
    };
    let o = optics(&file);
    let mut moved = 0.0f64;
    for (l, d, t, r) in [
        (30.0, -40.0, 0.0, 0.0),
        (10.0, -60.0, 25.0, 45.0),
        (-50.0, 15.0, -10.0, -120.0),
    ] {
        let lt = l + err(AxisRole::LightArm, l);
        let dt = d + err(AxisRole::DetectorArm, d);
        let f = stage(
            t + err(AxisRole::SampleTilt, t),
            r + err(AxisRole::SampleRotation, r),
        );
        let reading = o.reading(&pose(l, d, t, r), &BAND_550, 0.0).expect("reading");
        assert_dir(&reading.wi, comps(&arm(lt), &f), 1e-12, "wi");
        assert_dir(&reading.wo, comps(&arm(dt), &f), 1e-12, "wo");
        moved = moved.max((dt - d).abs());
    }
    assert!(moved > 0.1 * amplitude, "the error is felt: {moved}");
}

#[test]
fn a_tilted_sample_alone_wobbles_as_it_rotates() {
    let file = file_with(
        GeometryImperfections {
            sample_tilt_sd_deg: 0.2,
            ..Default::default()
        },
        13,
    );
    let tilt = geometry_truth(&file).sample_tilt;
    let o = optics(&file);
    let (l, d, t) = (30.0, -40.0, 20.0);
    let mut cos_i = Vec::new();
    for r in [0.0, 45.0, 90.0, 135.0, 180.0, 225.0, 270.0, 315.0] {
        let f = stage(t, r);
        let n = tilted_normal(&f, tilt.x_deg, tilt.y_deg);
        let reading = o.reading(&pose(l, d, t, r), &BAND_550, 0.0).expect("reading");
        assert!(
            (reading.wi.z() - dot(&arm(l), &n)).abs() < 1e-12,
            "cos theta_i at rotation {r}"
        );
        assert!(
            (reading.wo.z() - dot(&arm(d), &n)).abs() < 1e-12,
            "cos theta_o at rotation {r}"
        );
        let ratio = power_ratio(&file, &pose(l, d, t, r));
        assert!((ratio - dot(&arm(d), &n) / comps(&arm(d), &f)[2]).abs() < 1e-9);
        cos_i.push(reading.wi.z());
    }
    // The normal precesses about the rotation axis: theta_i changes with the rotation although the stage's own
    // normal (tilt 20 at every rotation) does not.
    let spread =
        cos_i.iter().cloned().fold(f64::MIN, f64::max) - cos_i.iter().cloned().fold(f64::MAX, f64::min);
    assert!(spread > 1e-4, "spread {spread}");
}

#[test]
fn re_seating_alone_draws_a_fresh_tilt_each_time_the_sample_goes_back() {
    let file = file_with(
        GeometryImperfections {
            reseat_tilt_sd_deg: 0.05,
            ..Default::default()
        },
        14,
    );
    let truth = geometry_truth(&file);
    let o = optics(&file);
    let p = pose(30.0, -40.0, 10.0, 25.0);
    let f = stage(10.0, 25.0);
    let check = |index: u64| {
        let (k, tilt) = o.seating();
        assert_eq!(k, index);
        assert_eq!(tilt, truth.seating_tilt(index));
        let n = tilted_normal(&f, tilt.x_deg, tilt.y_deg);
        let reading = o.reading(&p, &BAND_550, 0.0).expect("reading");
        assert!((reading.wi.z() - dot(&arm(30.0), &n)).abs() < 1e-12);
        assert!((reading.wo.z() - dot(&arm(-40.0), &n)).abs() < 1e-12);
        reading.wo.z()
    };
    let first = check(0);
    // Saying "mounted" again does not re-seat it: only taking it out and putting it back does.
    o.set_sample_mounted(true);
    assert_eq!(check(0), first);
    o.set_sample_mounted(false);
    o.set_sample_mounted(true);
    let second = check(1);
    assert_ne!(first, second, "a new mounting, a new tilt");
    o.set_sample_mounted(false);
    o.set_sample_mounted(true);
    check(2);
    assert_ne!(truth.seating_tilt(1), truth.seating_tilt(2));
}

#[test]
fn eccentricity_alone_moves_the_spot_and_the_viewing_direction() {
    let file = file_with(
        GeometryImperfections {
            eccentricity_sd_mm: 0.5,
            ..Default::default()
        },
        15,
    );
    let c_xy = geometry_truth(&file).eccentricity_mm;
    let c = [c_xy[0], c_xy[1], 0.0];
    assert!(c_xy[0].hypot(c_xy[1]) > 0.05, "a visible offset: {c_xy:?}");
    let distance_mm = file.instrument.detector.distance_mm;
    let o = optics(&file);
    for (l, d, t, r) in [
        (30.0, -40.0, 0.0, 0.0),
        (20.0, -50.0, 15.0, 30.0),
        (-60.0, 10.0, -25.0, 100.0),
    ] {
        let f = stage(t, r);
        let n = f[2];
        let (s, od) = (arm(l), arm(d));
        // The beam through C along s meets the sample plane (through the origin, normal n) at P.
        let k = dot(&c, &n) / dot(&s, &n);
        let spot = [0, 1, 2].map(|i| c[i] - k * s[i]);
        // The aperture centre sits at C + distance * o; the sample sees it from P.
        let to_det = [0, 1, 2].map(|i| c[i] + distance_mm * od[i] - spot[i]);
        let len = dot(&to_det, &to_det).sqrt();
        let w = to_det.map(|v| v / len);
        let reading = o.reading(&pose(l, d, t, r), &BAND_550, 0.0).expect("reading");
        assert_dir(
            &reading.wi,
            comps(&s, &f),
            1e-15,
            "the incidence direction is unchanged",
        );
        assert_dir(&reading.wo, comps(&w, &f), 1e-12, "wo");
        let spot_s = comps(&spot, &f);
        assert!(
            (reading.spot_mm[0] - spot_s[0]).abs() < 1e-12 && (reading.spot_mm[1] - spot_s[1]).abs() < 1e-12
        );
        assert!((spot_s[2]).abs() < 1e-12, "the spot lies on the sample plane");
        let ratio = power_ratio(&file, &pose(l, d, t, r));
        assert!(
            (ratio - comps(&w, &f)[2] / comps(&od, &f)[2]).abs() < 1e-9,
            "ratio {ratio}"
        );
    }
    // With no sample the detector faces the beam along the same line through C: the direct beam is unchanged.
    let ideal = optics(&file_with(GeometryImperfections::default(), 1));
    o.set_sample_mounted(false);
    ideal.set_sample_mounted(false);
    let p = pose(-90.0, 90.0, 0.0, 0.0);
    assert_eq!(
        o.reading(&p, &BAND_550, 0.0).expect("reading").power_w,
        ideal.reading(&p, &BAND_550, 0.0).expect("reading").power_w
    );
}

/// Fraction of a beam (radius rb along unit lab `s`, through the spot P) landing on a sample disc of radius `rs`
/// inside the field (radius rf along the detector arm `od` through Q), by counting cells of a fine grid on the
/// sample plane (sample x, y): the footprint of a uniform beam, from the model's definition.
#[allow(clippy::too_many_arguments)]
fn counted_fraction(rb: f64, rs: f64, rf: f64, s: V, od: V, p: [f64; 2], q: [f64; 2], n: usize) -> f64 {
    let extent = rb / s[2];
    let h = 2.0 * extent / n as f64;
    let (mut beam, mut kept) = (0u64, 0u64);
    for i in 0..n {
        let x = p[0] - extent + (i as f64 + 0.5) * h;
        for j in 0..n {
            let y = p[1] - extent + (j as f64 + 0.5) * h;
            // Distance from the beam's axis: |d|^2 - (d . s)^2 with d in the plane.
            let (dx, dy) = (x - p[0], y - p[1]);
            let along = dx * s[0] + dy * s[1];
            if dx * dx + dy * dy - along * along > rb * rb {
                continue;
            }
            beam += 1;
            let (fx, fy) = (x - q[0], y - q[1]);
            let along_f = fx * od[0] + fy * od[1];
            if x * x + y * y <= rs * rs && fx * fx + fy * fy - along_f * along_f <= rf * rf {
                kept += 1;
            }
        }
    }
    kept as f64 / beam as f64
}

#[test]
fn eccentricity_alone_moves_the_footprint_across_the_sample_edge() {
    let file = file_with(
        GeometryImperfections {
            eccentricity_sd_mm: 1.0,
            ..Default::default()
        },
        15,
    );
    let c_xy = geometry_truth(&file).eccentricity_mm;
    let c = [c_xy[0], c_xy[1], 0.0];
    let (rb, rf, rs) = (
        file.instrument.source.beam_radius_mm,
        file.instrument.detector.field_radius_mm,
        6.0,
    );
    let o = optics_of_radius(&file, rs);
    let ideal = optics_of_radius(&file_with(GeometryImperfections::default(), 1), rs);
    // Grazing incidence: the 1.5 mm beam's footprint is 1.5 / cos 80 = 8.6 mm long, past the 6 mm sample's edge.
    for (l, d, t, r) in [(80.0, -30.0, 0.0, 0.0), (75.0, -20.0, 10.0, 40.0)] {
        let f = stage(t, r);
        let n = f[2];
        let (s, od) = (arm(l), arm(d));
        let spot = [0, 1, 2].map(|i| c[i] - dot(&c, &n) / dot(&s, &n) * s[i]);
        let field = [0, 1, 2].map(|i| c[i] - dot(&c, &n) / dot(&od, &n) * od[i]);
        let (ps, qs) = (comps(&spot, &f), comps(&field, &f));
        let expect = counted_fraction(
            rb,
            rs,
            rf,
            comps(&s, &f),
            comps(&od, &f),
            [ps[0], ps[1]],
            [qs[0], qs[1]],
            2000,
        );
        let got = o.reading(&pose(l, d, t, r), &BAND_550, 0.0).expect("reading");
        let centred = ideal.reading(&pose(l, d, t, r), &BAND_550, 0.0).expect("reading");
        assert!(got.overfilled_sample && got.intercepted_fraction < 1.0);
        assert!(
            (got.intercepted_fraction - expect).abs() < 3e-4,
            "{} vs counted {expect}",
            got.intercepted_fraction
        );
        assert!(
            (got.intercepted_fraction - centred.intercepted_fraction).abs() > 1e-3,
            "the offset spot spills differently: {} vs {}",
            got.intercepted_fraction,
            centred.intercepted_fraction
        );
    }
}

#[test]
fn the_apertures_size_alone_scales_a_diffuse_reading_by_its_true_solid_angle() {
    let file = file_with(
        GeometryImperfections {
            aperture_radius_sd_mm: 0.01,
            detector_distance_sd_mm: 1.0,
            ..Default::default()
        },
        23,
    );
    let truth = geometry_truth(&file);
    let (dr, dd) = (truth.aperture_radius_error_mm, truth.detector_distance_error_mm);
    assert!(dr != 0.0 && dd != 0.0, "both drawn");
    // The solid angle of a disc of radius r at distance d, written here: 2 pi (1 - d / sqrt(d^2 + r^2)).
    let det = &file.instrument.detector;
    let cap = |r: f64, d: f64| 2.0 * std::f64::consts::PI * (1.0 - d / (d * d + r * r).sqrt());
    let expected =
        cap(det.aperture_radius_mm + dr, det.distance_mm + dd) / cap(det.aperture_radius_mm, det.distance_mm);
    assert!((expected - 1.0).abs() > 1e-4, "a visible change: {expected}");
    // A Lambertian sample fills the aperture evenly: the power scales with the solid angle, not the direction.
    for p in [pose(30.0, -40.0, 0.0, 0.0), pose(-20.0, 60.0, 10.0, 45.0)] {
        let ratio = power_ratio(&file, &p);
        assert!(
            (ratio - expected).abs() < 1e-6 * expected,
            "{ratio} vs {expected}"
        );
    }
}
