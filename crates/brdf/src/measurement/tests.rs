use super::*;

/// A reference that is not Lambertian: f = (a + b cos theta_i cos theta_o) / pi.
#[derive(Debug)]
struct ShapedReference;
impl Brdf for ShapedReference {
    fn eval(&self, wi: &Direction, wo: &Direction, _w: Wavelength) -> Result<f64, SpectrumError> {
        if wi.cos_theta() <= 0.0 || wo.cos_theta() <= 0.0 {
            return Ok(0.0);
        }
        Ok((0.8 + 0.2 * wi.cos_theta() * wo.cos_theta()) / std::f64::consts::PI)
    }
    fn is_isotropic(&self) -> bool {
        true
    }
    fn is_spectrally_flat(&self) -> bool {
        true
    }
}

fn geometry(theta_i_deg: f64, theta_o_deg: f64) -> MeasurementGeometry {
    MeasurementGeometry {
        wi: Direction::from_spherical_deg(theta_i_deg, 0.0),
        wo: Direction::from_spherical_deg(theta_o_deg, 180.0),
        angle_std_rad: 1e-3,
    }
}

fn footprint() -> Footprint {
    Footprint {
        beam_radius_mm: 2.0,
        sample_radius_mm: 25.0,
        detector_field_radius_mm: Some(10.0),
    }
}

fn absolute_readings(f_true: f64, g: &MeasurementGeometry, omega: f64) -> AbsoluteReadings {
    // Synthetic readings produced by the forward model P_s = P_i f Omega cos(theta_o), plus darks.
    let p_i = 2.5e-3;
    let dark = 1.0e-9;
    let direct_dark = 3.0e-9;
    AbsoluteReadings {
        signal: Reading::new(p_i * f_true * omega * g.wo.cos_theta() + dark, 2e-10),
        signal_dark: Reading::new(dark, 1e-10),
        direct_beam: Reading::new(p_i + direct_dark, 1e-7),
        direct_beam_dark: Reading::new(direct_dark, 5e-9),
        detector_solid_angle_sr: omega,
        detector_solid_angle_std_sr: omega * 1e-3,
    }
}

#[test]
fn absolute_recovers_a_known_brdf() {
    let g = geometry(30.0, 45.0);
    let f_true = 0.9 / std::f64::consts::PI;
    let r = absolute_readings(f_true, &g, 1e-3);
    let v = absolute_brdf(&r, &g, &footprint(), &ValidityLimits::default()).expect("valid geometry");
    assert!((v.value_per_sr - f_true).abs() < 1e-12 * f_true, "{v:?}");
    assert!(v.std_per_sr > 0.0 && v.std_per_sr < 0.01 * f_true);
}

#[test]
fn absolute_uncertainty_matches_finite_differences() {
    let g = geometry(20.0, 60.0);
    let f_true = 0.3;
    let r = absolute_readings(f_true, &g, 2e-3);
    let fp = footprint();
    let lim = ValidityLimits::default();
    let v = absolute_brdf(&r, &g, &fp, &lim).expect("valid");
    let f = |r: &AbsoluteReadings, g: &MeasurementGeometry| {
        absolute_brdf(r, g, &fp, &lim).expect("valid").value_per_sr
    };
    // Independent check: perturb each input by +-u and take the central difference.
    let mut contributions = Vec::new();
    let perturb = |field: usize, sign: f64| {
        let mut q = r;
        match field {
            0 => q.signal.value_w += sign * r.signal.std_w,
            1 => q.signal_dark.value_w += sign * r.signal_dark.std_w,
            2 => q.direct_beam.value_w += sign * r.direct_beam.std_w,
            3 => q.direct_beam_dark.value_w += sign * r.direct_beam_dark.std_w,
            _ => q.detector_solid_angle_sr += sign * r.detector_solid_angle_std_sr,
        }
        q
    };
    for field in 0..5 {
        contributions.push((f(&perturb(field, 1.0), &g) - f(&perturb(field, -1.0), &g)) / 2.0);
    }
    let (theta_o, phi_o) = g.wo.to_spherical();
    let tilt = |d: f64| MeasurementGeometry {
        wo: Direction::from_spherical(theta_o + d, phi_o),
        ..g
    };
    // The angle enters only through cos(theta_o) in the equation (readings fixed).
    contributions.push((f(&r, &tilt(g.angle_std_rad)) - f(&r, &tilt(-g.angle_std_rad))) / 2.0);
    let fd_total = contributions.iter().map(|c| c * c).sum::<f64>().sqrt();
    assert!(
        (v.std_per_sr - fd_total).abs() < 1e-4 * fd_total,
        "{} vs {fd_total}",
        v.std_per_sr
    );
    let b = v.budget;
    let analytic = [
        b.signal_per_sr,
        b.signal_dark_per_sr,
        b.normalisation_per_sr,
        b.normalisation_dark_per_sr,
        b.scale_per_sr,
        b.angles_per_sr,
    ];
    for (a, c) in analytic.iter().zip(&contributions) {
        assert!((a - c.abs()).abs() < 1e-4 * a.max(1e-30), "{a} vs {c}");
    }
}

#[test]
fn relative_recovers_a_known_brdf_through_a_shaped_reference() {
    let reference = ShapedReference;
    let wl = Wavelength::DEFAULT;
    let g = geometry(50.0, 70.0);
    let f_sample = 0.123;
    let f_ref = reference.eval(&g.wi, &g.wo, wl).expect("flat");
    // Same incident power and detector for both: readings are proportional to f.
    let k = 4.0e-6;
    let readings = RelativeReadings {
        signal: Reading::new(k * f_sample + 2e-9, 1e-10),
        signal_dark: Reading::new(2e-9, 1e-10),
        reference: Reading::new(k * f_ref + 1e-9, 1e-10),
        reference_dark: Reading::new(1e-9, 1e-10),
        reference_brdf_rel_std: 2e-3,
    };
    let v = relative_brdf(
        &readings,
        &reference,
        wl,
        &g,
        &footprint(),
        &ValidityLimits::default(),
    )
    .expect("valid");
    assert!((v.value_per_sr - f_sample).abs() < 1e-12, "{v:?}");
    // The reference's slope contributes: d f_ref / d theta_o = -0.2 cos_i sin_o / pi (and likewise theta_i).
    let (ci, si) = (g.wi.cos_theta(), g.wi.sin_theta());
    let (co, so) = (g.wo.cos_theta(), g.wo.sin_theta());
    let slope = (0.2 / std::f64::consts::PI) * (ci * so).hypot(si * co);
    let expected_angle = f_sample / f_ref * slope * g.angle_std_rad;
    assert!((v.budget.angles_per_sr - expected_angle).abs() < 1e-6 * expected_angle);
    assert!((v.budget.scale_per_sr - f_sample * 2e-3).abs() < 1e-15);
}

#[test]
fn refuses_invalid_geometries_with_typed_errors() {
    let lim = ValidityLimits::default();
    let ok = geometry(30.0, 45.0);
    let r = absolute_readings(0.2, &ok, 1e-3);
    let fp = footprint();
    // Grazing detector.
    let g = geometry(30.0, 88.0);
    assert!(matches!(
        absolute_brdf(&r, &g, &fp, &lim),
        Err(MeasurementError::GrazingDetector { .. })
    ));
    // Detector exactly on the horizon, even with a zero limit.
    let zero = ValidityLimits { min_cos_theta_o: 0.0 };
    let g = geometry(30.0, 90.0);
    assert!(matches!(
        absolute_brdf(&r, &g, &fp, &zero),
        Err(MeasurementError::GrazingDetector { .. })
    ));
    // Source below the horizon.
    let g = geometry(95.0, 30.0);
    assert!(matches!(
        absolute_brdf(&r, &g, &fp, &lim),
        Err(MeasurementError::SourceBelowHorizon { .. })
    ));
    // Footprint overfills the detector's field (2 / cos 80 = 11.5 mm > 10 mm) and then the sample.
    let g = geometry(80.0, 30.0);
    assert!(matches!(
        absolute_brdf(&r, &g, &fp, &lim),
        Err(MeasurementError::OverfillsDetectorField { .. })
    ));
    let small_sample = Footprint {
        sample_radius_mm: 5.0,
        ..fp
    };
    assert!(matches!(
        absolute_brdf(&r, &g, &small_sample, &lim),
        Err(MeasurementError::OverfillsSample { .. })
    ));
    // No net direct beam.
    let mut bad = r;
    bad.direct_beam_dark.value_w = bad.direct_beam.value_w;
    assert!(matches!(
        absolute_brdf(&bad, &ok, &fp, &lim),
        Err(MeasurementError::NoDirectBeam { .. })
    ));
    // Non-finite inputs and negative uncertainty.
    let mut bad = r;
    bad.signal.value_w = f64::NAN;
    assert!(matches!(
        absolute_brdf(&bad, &ok, &fp, &lim),
        Err(MeasurementError::NonFinite {
            field: "signal.value_w",
            ..
        })
    ));
    let mut bad = r;
    bad.direct_beam.std_w = -1.0;
    assert!(matches!(
        absolute_brdf(&bad, &ok, &fp, &lim),
        Err(MeasurementError::Negative { .. })
    ));
    let mut bad = r;
    bad.detector_solid_angle_sr = 0.0;
    assert!(matches!(
        absolute_brdf(&bad, &ok, &fp, &lim),
        Err(MeasurementError::BadSolidAngle { .. })
    ));
    let nan_beam = Footprint {
        beam_radius_mm: f64::NAN,
        ..fp
    };
    assert!(matches!(
        absolute_brdf(&r, &ok, &nan_beam, &lim),
        Err(MeasurementError::NonFinite { .. })
    ));
    // Relative: no reference signal.
    let readings = RelativeReadings {
        signal: Reading::exact(1.0),
        signal_dark: Reading::exact(0.0),
        reference: Reading::exact(0.5),
        reference_dark: Reading::exact(0.6),
        reference_brdf_rel_std: 0.0,
    };
    assert!(matches!(
        relative_brdf(&readings, &ShapedReference, Wavelength::DEFAULT, &ok, &fp, &lim),
        Err(MeasurementError::NoReferenceSignal { .. })
    ));
}

#[test]
fn errors_name_what_is_wrong() {
    let e = MeasurementError::OverfillsSample {
        footprint_mm: 11.5,
        sample_radius_mm: 10.0,
    };
    let msg = e.to_string();
    assert!(
        msg.contains("overfills the sample") && msg.contains("11.5"),
        "{msg}"
    );
}
