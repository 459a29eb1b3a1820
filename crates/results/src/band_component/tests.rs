//! The band component's tests: the slope, the passband, the centroid and the leak, worked out by hand.

use super::*;

fn point(index: u64, band_nm: f64, theta_o: f64, f: f64) -> Point {
    Point {
        index,
        ..Point::at(band_nm, [30.0, 0.0, theta_o, 180.0], f)
    }
}

fn filters(nm: f64) -> Option<FilterBand> {
    (nm != 700.0).then_some(FilterBand {
        band_nm: nm,
        centre_u_nm: 1.0,
        leakage: 0.0,
        leakage_u_rel: 0.0,
        passband_variance_nm2: 0.0,
        centroid_offset_nm: 0.0,
    })
}

/// The band components without a leak spectrum.
fn band_components(points: &[Point], filter: impl Fn(f64) -> Option<FilterBand>) -> Vec<Option<f64>> {
    band_estimates(points, &[], filter, None)
        .into_iter()
        .map(|e| e.map(|e| e.u_sr))
        .collect()
}

#[test]
fn a_linear_spectrum_gives_slope_times_the_centre_uncertainty() {
    // f = 0.1 + 0.001 (nm - 450) at two geometries, three bands each; a lone band elsewhere.
    let mut points = Vec::new();
    for (g, theta_o) in [10.0, 40.0].into_iter().enumerate() {
        for (b, nm) in [450.0, 550.0, 650.0].into_iter().enumerate() {
            let f = 0.1 + 0.001 * (nm - 450.0);
            points.push(point((g * 3 + b) as u64, nm, theta_o, f));
        }
    }
    points.push(point(6, 550.0, 70.0, 0.3));
    let u = band_components(&points, filters);
    for v in &u[..6] {
        // Slope 0.001 per nm, 1 nm: 0.001; no curvature.
        assert!((v.expect("estimated") - 0.001).abs() < 1e-12, "{u:?}");
    }
    assert_eq!(u[6], None, "one band tells nothing of the spectrum");
}

#[test]
fn leakage_adds_the_largest_relative_difference_to_the_other_bands() {
    // A red sample: 0.05 at 450, 0.1 at 550, 0.5 at 650 nm; 2 % leaks at 450, nothing elsewhere.
    let points: Vec<Point> = [(450.0, 0.05), (550.0, 0.1), (650.0, 0.5)]
        .into_iter()
        .enumerate()
        .map(|(k, (nm, f))| point(k as u64, nm, 20.0, f))
        .collect();
    let leaky = |nm: f64| {
        Some(FilterBand {
            band_nm: nm,
            centre_u_nm: 0.0,
            leakage: if nm == 450.0 { 0.02 } else { 0.0 },
            leakage_u_rel: 0.1,
            passband_variance_nm2: 0.0,
            centroid_offset_nm: 0.0,
        })
    };
    let u = band_components(&points, leaky);
    // 0.05 x 0.02 x (0.5 / 0.05 - 1) = 0.009: the blue value could be 18 % high.
    assert!((u[0].expect("450") - 0.009).abs() < 1e-12, "{u:?}");
    assert_eq!((u[1], u[2]), (Some(0.0), Some(0.0)));
}

#[test]
fn a_geometry_within_the_tolerance_across_a_bucket_edge_is_one_geometry() {
    // Two points 0.6 tolerances apart in theta_o on either side of a bucket edge (one tolerance wide, from
    // 0), in two bands; a third geometry 2.7 tolerances away stays apart.
    let edge = 20.0 + SAME_GEOMETRY_DEG;
    let points = vec![
        point(0, 450.0, edge - 0.3 * SAME_GEOMETRY_DEG, 0.1),
        point(1, 550.0, edge + 0.3 * SAME_GEOMETRY_DEG, 0.2),
        point(2, 550.0, edge + 3.0 * SAME_GEOMETRY_DEG, 0.2),
    ];
    let u = band_components(&points, filters);
    // Slope 0.1 / 100 nm, times 1 nm, for both points of the pair; the lone band has none.
    assert!((u[0].expect("paired") - 1e-3).abs() < 1e-12, "{u:?}");
    assert!((u[1].expect("paired") - 1e-3).abs() < 1e-12, "{u:?}");
    assert_eq!(u[2], None, "{u:?}");
}

#[test]
fn the_slope_is_the_monotone_cubic_s_and_unknown_or_invalid_bands_get_none() {
    // f = 1e-5 (nm - 550)^2 + 0.2 at 450, 550, 650 and 700 nm: 0.3, 0.2, 0.3, 0.425; secants -1e-3, 1e-3
    // and 2.5e-3 per nm.
    let f = |nm: f64| 1e-5 * (nm - 550.0).powi(2) + 0.2;
    let mut points: Vec<Point> = [450.0, 550.0, 650.0, 700.0]
        .into_iter()
        .enumerate()
        .map(|(k, nm)| point(k as u64, nm, 20.0, f(nm)))
        .collect();
    let mut failed = point(4, 500.0, 20.0, 0.0);
    failed.flags = vec!["failed: timeout".into()];
    points.push(failed);
    let u = band_components(&points, filters);
    // At 550, a trough (the secants change sign): 0.
    assert_eq!(u[1], Some(0.0), "{u:?}");
    // At 450, the three-point end estimate ((2 h0 + h1) d0 - h0 d1) / (h0 + h1) = (-0.3 - 0.1) / 200.
    assert!((u[0].expect("450") - 2e-3).abs() < 1e-12, "{u:?}");
    // At 650, the weighted harmonic mean: h 100 and 50, weights 2*50 + 100 = 200 and 50 + 2*100 = 250,
    // 450 / (200 / 1e-3 + 250 / 2.5e-3) = 1.5e-3.
    assert!((u[2].expect("650") - 1.5e-3).abs() < 1e-12, "{u:?}");
    // 700 nm is not a filter of the file; a failed reading has no value.
    assert_eq!((u[3], u[4]), (None, None));
}

#[test]
fn a_sharp_edge_beyond_a_band_is_not_its_slope() {
    // Construction paper's bands: 0.06, 0.07, 0.52. A central difference at 550 would be the edge's rise,
    // (0.52 - 0.06) / 200 = 2.3e-3 per nm; the cubic's slope is the harmonic mean of 1e-4 and 4.5e-3.
    let points: Vec<Point> = [(450.0, 0.06), (550.0, 0.07), (650.0, 0.52)]
        .into_iter()
        .enumerate()
        .map(|(k, (nm, f))| point(k as u64, nm, 20.0, f))
        .collect();
    let u = band_components(&points, filters);
    let harmonic = 2.0 * 1e-4 * 4.5e-3 / (1e-4 + 4.5e-3);
    assert!((u[1].expect("550") - harmonic).abs() < 1e-12, "{u:?}");
    assert!(u[1].expect("550") < 2.5e-4, "{u:?}");
    // At 450 the end estimate (3 x 1e-4 - 4.5e-3) / 2 turns against the first secant: 0.
    assert_eq!(u[0], Some(0.0), "{u:?}");
}

#[test]
fn a_curved_spectrum_adds_half_its_curvature_times_the_passband_variance() {
    // f = 1e-5 (nm - 550)^2 + 0.2 at 450, 550, 650 nm: f'' = 2e-5 per nm^2, and the cubic through the
    // three bands bends by exactly that at 550 (slope 0 there, 2e-3 at 650: 6 x 0.1 / 100^2 - 2 x 2e-3 /
    // 100). No centre uncertainty: the passband alone, 0.5 x 2e-5 x 12.5.
    let f = |nm: f64| 1e-5 * (nm - 550.0).powi(2) + 0.2;
    let points: Vec<Point> = [450.0, 550.0, 650.0]
        .into_iter()
        .enumerate()
        .map(|(k, nm)| point(k as u64, nm, 20.0, f(nm)))
        .collect();
    let wide = |nm: f64| {
        Some(FilterBand {
            centre_u_nm: 0.0,
            // A three-cavity 10 nm filter's (gonio_instrument::passband::variance_nm2).
            passband_variance_nm2: 12.5,
            ..filters(nm)?
        })
    };
    let u = band_components(&points, wide);
    assert!((u[1].expect("550") - 1.25e-4).abs() < 1e-15, "{u:?}");
    // A straight spectrum does not bend: no passband term anywhere.
    let line: Vec<Point> = [450.0, 550.0, 650.0]
        .into_iter()
        .enumerate()
        .map(|(k, nm)| point(k as u64, nm, 20.0, 0.1 + 1e-3 * (nm - 450.0)))
        .collect();
    for v in band_components(&line, wide) {
        assert!(v.expect("estimated").abs() < 1e-15);
    }
}

#[test]
fn the_light_s_centroid_widens_the_centre_s_uncertainty_and_moves_no_value() {
    // A straight spectrum, slope 1e-3 per nm; the light 0.2 nm above the centre: the centre's 1 nm becomes
    // sqrt(1 + 0.04) nm, and nothing is corrected.
    let points: Vec<Point> = [450.0, 550.0, 650.0]
        .into_iter()
        .enumerate()
        .map(|(k, nm)| point(k as u64, nm, 20.0, 0.1 + 1e-3 * (nm - 450.0)))
        .collect();
    let shifted = |nm: f64| {
        Some(FilterBand {
            centroid_offset_nm: 0.2,
            ..filters(nm)?
        })
    };
    for e in band_estimates(&points, &[], shifted, None) {
        let e = e.expect("estimated");
        assert!((e.u_sr - 1e-3 * 1.04f64.sqrt()).abs() < 1e-15, "{e:?}");
        assert_eq!(e.shift_sr, 0.0);
    }
}

/// A leak spread evenly from 400 to 1000 nm, in 1 nm samples.
fn even_leak() -> LeakSpectrum {
    LeakSpectrum::new((400..=1000).map(|nm| (f64::from(nm), 1.0)).collect()).expect("leak")
}

#[test]
fn the_leak_weights_interpolate_between_the_bands_and_hold_flat_beyond() {
    let leak = even_leak();
    let w = leak.weights(&[450.0, 550.0, 650.0]).expect("weights");
    assert!((w.nodes.iter().sum::<f64>() - 1.0).abs() < 1e-12, "{w:?}");
    // 51 of 601 samples at or below 450 nm, 351 at or above 650 nm.
    assert!(
        (w.below - 51.0 / 601.0).abs() < 1e-12 && (w.above - 351.0 / 601.0).abs() < 1e-12,
        "{w:?}"
    );
    // Exact for a spectrum linear between the nodes and flat beyond them.
    let f = |nm: f64| 0.1 + 1e-3 * (nm.clamp(450.0, 650.0) - 450.0);
    let direct: f64 = (400..=1000).map(|nm| f(f64::from(nm))).sum::<f64>() / 601.0;
    let weighted: f64 = w
        .nodes
        .iter()
        .zip([450.0, 550.0, 650.0])
        .map(|(w, nm)| w * f(nm))
        .sum();
    assert!((direct - weighted).abs() < 1e-12, "{direct} {weighted}");
    let one = leak.weights(&[550.0]).expect("one node");
    assert!((one.nodes[0] - 1.0).abs() < 1e-12);
    assert_eq!(leak.weights(&[]), None);
    assert_eq!(leak.weights(&[550.0, 450.0]), None);
    assert_eq!(LeakSpectrum::new(vec![(500.0, 0.0)]), None);
}

#[test]
fn a_leaky_blue_band_is_corrected_to_the_sample_s_own_value() {
    // A red sample flat beyond its bands (the model's own assumption): 0.05, 0.1, 0.5 at 450, 550, 650 nm.
    // Leaks: 3 % at 450, 1 % at 550, 0.5 % at 650; each measured value (f + L fbar) / (1 + L).
    let leak = even_leak();
    let truth = [(450.0, 0.05), (550.0, 0.1), (650.0, 0.5)];
    let w = leak.weights(&[450.0, 550.0, 650.0]).expect("weights");
    let fbar: f64 = w.nodes.iter().zip(truth).map(|(w, (_, f))| w * f).sum();
    let l = |nm: f64| match nm as u32 {
        450 => 0.03,
        550 => 0.01,
        _ => 0.005,
    };
    let filter = |nm: f64| {
        Some(FilterBand {
            band_nm: nm,
            centre_u_nm: 0.0,
            leakage: l(nm),
            leakage_u_rel: 0.1,
            passband_variance_nm2: 0.0,
            centroid_offset_nm: 0.0,
        })
    };
    let points: Vec<Point> = truth
        .iter()
        .enumerate()
        .map(|(k, &(nm, f))| point(k as u64, nm, 20.0, (f + l(nm) * fbar) / (1.0 + l(nm))))
        .collect();
    let e = band_estimates(&points, &[], filter, Some(&leak));
    for ((p, (nm, f)), e) in points.iter().zip(truth).zip(&e) {
        let e = e.expect("estimated");
        let corrected = p.brdf_sr.expect("value") + e.shift_sr;
        assert!((corrected / f - 1.0).abs() < 1e-12, "{nm}: {corrected} for {f}");
        assert!((e.scale - 1.0 - l(nm)).abs() < 1e-15);
        // The uncertainty: the leaked fraction's tenth of L (m - fbar), and the spectrum beyond 650 nm
        // within one band step (0.4 / sqrt 3) of its value, times the leak's share there.
        let m = p.brdf_sr.expect("value");
        let of_l = l(nm) * 0.1 * (m - fbar).abs();
        let beyond = l(nm) * w.above * 0.4 / 3f64.sqrt();
        let below = l(nm) * w.below * 0.05 / 3f64.sqrt();
        let expected = of_l.hypot(beyond.hypot(below));
        assert!(
            (e.u_sr / expected - 1.0).abs() < 1e-6,
            "{nm}: {} against {expected}",
            e.u_sr
        );
    }
    // The blue band read 20 % high before the correction.
    assert!(points[0].brdf_sr.expect("value") / 0.05 - 1.0 > 0.1);
    // Without a leak spectrum nothing is corrected and the leak is only bounded.
    let bounded = band_estimates(&points, &[], filter, None);
    assert!(bounded.iter().all(|e| e.expect("estimated").shift_sr == 0.0));
}

/// The leak test's filters: 3 % at 450 nm, 1 % at 550 nm, 0.5 % at 650 nm, each known to a tenth.
fn leaky(nm: f64) -> Option<FilterBand> {
    let leakage = match nm as u32 {
        450 => 0.03,
        550 => 0.01,
        _ => 0.005,
    };
    Some(FilterBand {
        band_nm: nm,
        centre_u_nm: 0.0,
        leakage,
        leakage_u_rel: 0.1,
        passband_variance_nm2: 0.0,
        centroid_offset_nm: 0.0,
    })
}

/// What each band of `truth` reads through the leaky filters: `(f + L fbar) / (1 + L)`.
fn measured(truth: &[(f64, f64)], leak: &LeakSpectrum) -> Vec<(f64, f64)> {
    let nodes: Vec<f64> = truth.iter().map(|t| t.0).collect();
    let w = leak.weights(&nodes).expect("weights");
    let fbar: f64 = w.nodes.iter().zip(truth).map(|(w, (_, f))| w * f).sum();
    truth
        .iter()
        .map(|&(nm, f)| {
            let l = leaky(nm).expect("filter").leakage;
            (nm, (f + l * fbar) / (1.0 + l))
        })
        .collect()
}

/// A probe: every band of `truth` (scaled by `scale`) measured at theta_o.
fn probe(index: u64, theta_o: f64, truth: &[(f64, f64)], scale: f64, leak: &LeakSpectrum) -> Vec<Point> {
    let scaled: Vec<(f64, f64)> = truth.iter().map(|&(nm, f)| (nm, f * scale)).collect();
    measured(&scaled, leak)
        .into_iter()
        .enumerate()
        .map(|(k, (nm, m))| point(index + k as u64, nm, theta_o, m))
        .collect()
}

const PAPER: [(f64, f64); 3] = [(450.0, 0.06), (550.0, 0.07), (650.0, 0.52)];

#[test]
fn one_band_borrows_the_nearest_probe_s_shape_and_is_corrected_to_its_own_value() {
    let leak = even_leak();
    // Three probes of paper's shape (at other scales: its BRDF varies with the geometry), and the 550 nm band
    // alone at theta_o = 32, where the sample is 0.9 times the table.
    let mut points = probe(0, 20.0, &PAPER, 1.0, &leak);
    points.extend(probe(3, 40.0, &PAPER, 0.8, &leak));
    points.extend(probe(6, 60.0, &PAPER, 0.5, &leak));
    let alone = measured(&PAPER.map(|(nm, f)| (nm, 0.9 * f)), &leak)[1].1;
    points.push(point(9, 550.0, 32.0, alone));
    // Read 2.8 % high through the leak before the correction.
    assert!(alone / (0.9 * 0.07) - 1.0 > 0.025, "{alone}");
    let e = band_estimates(&points, &points, leaky, Some(&leak));
    let lone = e[9].expect("borrowed");
    let corrected = alone + lone.shift_sr;
    assert!((corrected / (0.9 * 0.07) - 1.0).abs() < 1e-12, "{corrected}");
    // The probes' shapes agree: the borrowed shape adds nothing, and the component is what the three bands
    // measured at theta_o = 32 would have given.
    let mut at_32 = probe(20, 32.0, &PAPER, 0.9, &leak);
    at_32.push(point(30, 550.0, 70.0, 1.0));
    let own = band_estimates(&at_32, &[], leaky, Some(&leak))[1].expect("three bands");
    assert!(
        (lone.u_sr / own.u_sr - 1.0).abs() < 1e-9,
        "{} against {}",
        lone.u_sr,
        own.u_sr
    );
    assert!((lone.scale - 1.01).abs() < 1e-15);
    // Without the probes the lone band tells nothing of the spectrum.
    assert_eq!(band_estimates(&points, &[], leaky, Some(&leak))[9], None);
}

#[test]
fn the_borrowed_shape_s_uncertainty_is_the_nearest_probes_spread_or_the_whole_correction() {
    let leak = even_leak();
    let alone = |f: f64| point(9, 550.0, 32.0, f);
    // One probe: nothing says how the shape varies; the whole correction is added to the component.
    let mut one = probe(0, 20.0, &PAPER, 1.0, &leak);
    let m = measured(&PAPER, &leak)[1].1;
    one.push(alone(m));
    let e = band_estimates(&one, &one, leaky, Some(&leak));
    let (lone, own) = (e[3].expect("borrowed"), e[1].expect("probe"));
    assert!((lone.shift_sr - own.shift_sr).abs() < 1e-15);
    let expected = own.u_sr.hypot(own.shift_sr);
    assert!(
        (lone.u_sr / expected - 1.0).abs() < 1e-12,
        "{} against {expected}",
        lone.u_sr
    );
    // Probes of other shapes: the nearest lends its shape (a redder one at theta_o = 30, a greyer one further
    // off), and the largest difference of the leak's means among the three nearest counts.
    let redder = [(450.0, 0.06), (550.0, 0.07), (650.0, 0.70)];
    let greyer = [(450.0, 0.06), (550.0, 0.07), (650.0, 0.30)];
    let mut mixed = probe(0, 30.0, &redder, 1.0, &leak);
    mixed.extend(probe(3, 45.0, &PAPER, 1.0, &leak));
    mixed.extend(probe(6, 60.0, &greyer, 1.0, &leak));
    mixed.extend(probe(
        10,
        75.0,
        &[(450.0, 0.06), (550.0, 0.07), (650.0, 5.0)],
        1.0,
        &leak,
    ));
    let m = measured(&redder, &leak)[1].1;
    mixed.push(alone(m));
    let e = band_estimates(&mixed, &mixed, leaky, Some(&leak));
    let lone = e[12].expect("borrowed");
    let nearest = e[1].expect("probe at 30");
    assert!((lone.shift_sr - nearest.shift_sr).abs() < 1e-15);
    // Each probe's leak mean from its 550 nm band's correction, `L (m - fbar)`, scaled to this value (the
    // correction is linear in the spectrum); the greyer probe's is furthest from the nearest's, and the far one
    // (650 nm at 5.0) is not among the three nearest.
    let fbar_at = |k: usize| {
        let own = mixed[k].brdf_sr.expect("value");
        (own - e[k].expect("probe").shift_sr / 0.01) * m / own
    };
    let expected = nearest.u_sr.hypot(0.01 * (fbar_at(7) - fbar_at(1)));
    assert!(
        (lone.u_sr / expected - 1.0).abs() < 1e-9,
        "{} against {expected}",
        lone.u_sr
    );
    assert!((fbar_at(10) - fbar_at(1)).abs() > (fbar_at(7) - fbar_at(1)).abs());
    // No probe measured in the band: nothing to borrow.
    let other = vec![point(0, 450.0, 20.0, 0.06), point(1, 650.0, 20.0, 0.5), alone(m)];
    assert_eq!(band_estimates(&other, &other, leaky, Some(&leak))[2], None);
}

#[test]
fn a_probe_at_its_noise_lends_no_shape() {
    let leak = even_leak();
    // The nearest probe (theta_o = 30) is within three of its uncertainties (a mirror's away from its specular
    // direction: its bands' ratios are the noise's); the further one (theta_o = 60) lends its shape instead.
    let mut noisy = probe(
        0,
        30.0,
        &[(450.0, 0.001), (550.0, 0.001), (650.0, 0.02)],
        1.0,
        &leak,
    );
    for p in &mut noisy {
        p.brdf_u_sr = Some(0.001);
    }
    let mut points = noisy.clone();
    points.extend(probe(3, 60.0, &PAPER, 1.0, &leak));
    let m = measured(&PAPER, &leak)[1].1;
    points.push(point(9, 550.0, 32.0, m));
    let e = band_estimates(&points, &points, leaky, Some(&leak));
    let lone = e[6].expect("borrowed from the far probe");
    let far = e[4].expect("probe at 60");
    assert!((lone.shift_sr - far.shift_sr).abs() < 1e-15, "{lone:?} {far:?}");
    // Alone, the noisy probe lends nothing.
    noisy.push(point(9, 550.0, 32.0, m));
    assert_eq!(band_estimates(&noisy, &noisy, leaky, Some(&leak))[3], None);
    // Well above its noise it lends.
    for p in &mut noisy {
        p.brdf_u_sr = Some(1e-5);
    }
    assert!(band_estimates(&noisy, &noisy, leaky, Some(&leak))[3].is_some());
}

#[test]
fn a_lone_band_at_its_noise_borrows_nothing() {
    let leak = even_leak();
    let mut points = probe(0, 20.0, &PAPER, 1.0, &leak);
    let mut lone = point(3, 550.0, 32.0, 0.002);
    lone.brdf_u_sr = Some(0.001);
    points.push(lone);
    assert_eq!(band_estimates(&points, &points, leaky, Some(&leak))[3], None);
    points[3].brdf_u_sr = Some(1e-4);
    assert!(band_estimates(&points, &points, leaky, Some(&leak))[3].is_some());
}
