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
    band_estimates(points, filter, None)
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
    for e in band_estimates(&points, shifted, None) {
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
    let e = band_estimates(&points, filter, Some(&leak));
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
    let bounded = band_estimates(&points, filter, None);
    assert!(bounded.iter().all(|e| e.expect("estimated").shift_sr == 0.0));
}
