//! The latitude coordinates against their definition: rows spanning the cone rim to rim, pieces of sigma covering
//! it continuously, and the cuts and maps that the features call for.

use super::super::{Features, Peak};
use super::adapt::Focus;
use super::*;

#[test]
fn latitude_rows_span_the_cone_exactly() {
    // The row at sigma lies at elevation e_axis + beta cos(sigma), its ends (tau = +-1) on the rim, its
    // middle inside; the horizon row is at elevation 0. Cones above, on and below the horizon, at any azimuth,
    // with and without the maps onto a lobe.
    for (beta, frac, phi) in [
        (0.01, 0.5, 0.3),
        (0.1, 0.0, 2.0),
        (0.3, -0.7, -1.0),
        (0.05, 0.99, 3.1),
    ] {
        let axis = Direction::from_spherical(FRAC_PI_2 - frac * beta, phi);
        let lat = Latitude::new(beta, frac * beta, phi).expect("across the horizon");
        let horizon = lat.point(&lat.row(lat.sigma_max), 0.0).map(|(d, _)| d.z());
        assert!(horizon.is_none_or(|z| z.abs() < 1e-15), "{horizon:?}");
        let peak = Peak {
            direction: Direction::from_spherical(FRAC_PI_2 - 0.2 * beta, phi + 0.1 * beta),
            width: 0.05 * beta,
            across: (0.01 * beta, 0.0),
        };
        let features = Features {
            peak: Some(peak),
            kink_theta: None,
            kink_azimuth: None,
        };
        for lat in [lat, lat.adapted_to(&features)] {
            for k in 1..20 {
                let sigma = lat.sigma_max * k as f64 / 20.0;
                let row = lat.row(sigma);
                let e = frac * beta + beta * sigma.cos();
                for (tau, inside) in [(-1.0, false), (1.0, false), (0.3, true)] {
                    let (d, jacobian) = lat.point(&row, tau).expect("a direction");
                    assert!((d.z() - e.sin()).abs() < 1e-15, "elevation at sigma {sigma}");
                    assert!(jacobian > 0.0);
                    let rho = d.angle_to(&axis);
                    if inside {
                        assert!(rho < beta, "sigma {sigma}: inside at {rho}");
                    } else {
                        assert!(
                            (rho - beta).abs() < 1e-12 * beta.max(1.0),
                            "sigma {sigma}: {rho} vs {beta}"
                        );
                    }
                }
            }
        }
    }
}

/// v runs over [0, total] continuously: sigma is continuous and increasing across the pieces, from 0 to
/// sigma_max, with each focus where its map puts it.
fn assert_pieces_cover_sigma(lat: &Latitude) {
    let pieces = lat.pieces();
    assert_eq!(pieces[0][0], 0.0);
    for w in pieces.windows(2) {
        assert_eq!(w[0][1], w[1][0], "{pieces:?}");
        let (below, _) = lat.sigma(w[0][1] - 1e-12);
        let (above, _) = lat.sigma(w[1][0] + 1e-12);
        assert!((above - below).abs() < 1e-9, "{below} {above}");
    }
    let last = pieces[pieces.len() - 1][1];
    assert!(lat.sigma(0.0).0.abs() < 1e-12);
    assert!((lat.sigma(last).0 - lat.sigma_max).abs() < 1e-12 * lat.sigma_max);
    let mut previous = -1.0;
    for k in 0..=1000 {
        let (sigma, jacobian) = lat.sigma(last * k as f64 / 1000.0);
        assert!(sigma > previous && jacobian > 0.0, "{sigma} after {previous}");
        previous = sigma;
    }
}

#[test]
fn a_ridge_crossing_the_rim_gets_a_piece_mapped_onto_the_crossing() {
    // A narrow ridge (0.001 rad across) on the meridian 0.016 rad from the axis's, peak above the cone's top;
    // the axis 0.042 rad below the horizon, half-angle 0.05 rad: the meridian leaves the part above through
    // the rim at one elevation, where the map centres a piece.
    let (beta, elevation, azimuth) = (0.05, -0.0424, 0.656);
    let lat = Latitude::new(beta, elevation, azimuth).expect("across");
    let peak = Peak {
        direction: Direction::from_spherical(FRAC_PI_2 - 0.0239, azimuth - 0.016),
        width: 0.06,
        across: (0.0007, 0.03),
    };
    let features = Features {
        peak: Some(peak),
        kink_theta: Some(FRAC_PI_2 - 0.002),
        kink_azimuth: None,
    };
    let mapped = lat.adapted_to(&features);
    assert_pieces_cover_sigma(&mapped);
    let foci: Vec<(f64, f64)> = mapped.pieces_in_use().iter().filter_map(|p| p.map).collect();
    assert!(!foci.is_empty(), "{mapped:?}");
    // Every focus is a rim crossing: W(sigma) = |offset| there.
    for (sigma, scale) in &foci {
        let w = mapped.row(*sigma).half_width;
        assert!((w - 0.016).abs() < 1e-9, "W {w} at {sigma}");
        assert!(*scale > 0.0 && *scale < 0.1 * mapped.sigma_max, "{scale}");
    }
    // The kink's row is a cut too: two pieces with the same map.
    assert_eq!(mapped.pieces().len(), 2, "{mapped:?}");
    // Without a ridge (a lobe as wide as the cone), one piece and no map.
    let wide = Features {
        peak: Some(Peak {
            across: (0.2, 0.0),
            width: 0.2,
            ..peak
        }),
        kink_theta: None,
        kink_azimuth: None,
    };
    let plain = lat.adapted_to(&wide);
    assert_pieces_cover_sigma(&plain);
    assert_eq!(plain.pieces().len(), 1);
}

#[test]
fn a_kink_along_a_meridian_cuts_the_rows_at_tau_zero_and_sigma_where_it_meets_the_rim() {
    // The axis 0.02 rad below the horizon, half-angle 0.05: the meridian 0.02 rad from the axis's crosses
    // the rim once above the horizon. Rows wider than 0.02 have the kink at tau = 0; narrower rows are
    // linear in tau; sigma is cut where W(sigma) = 0.02, with and without a lobe's maps.
    let (beta, elevation, azimuth) = (0.05, -0.02, 1.0);
    let lat = Latitude::new(beta, elevation, azimuth).expect("across");
    let kink = Features {
        peak: None,
        kink_theta: None,
        kink_azimuth: Some(azimuth + 0.02),
    };
    let lobe = Features {
        peak: Some(Peak {
            direction: Direction::from_spherical(FRAC_PI_2 - 0.01, azimuth - 0.01),
            width: 0.02,
            across: (0.002, 0.0),
        }),
        ..kink
    };
    for features in [kink, lobe] {
        let cut = lat.adapted_to(&features);
        assert!(cut.rows_cut());
        assert_pieces_cover_sigma(&cut);
        let bounds: Vec<f64> = cut.pieces().iter().map(|p| cut.sigma(p[0]).0).collect();
        let crossings: Vec<f64> = bounds
            .iter()
            .copied()
            .filter(|&s| (cut.row(s).half_width - 0.02).abs() < 1e-9)
            .collect();
        assert_eq!(crossings.len(), 1, "{bounds:?}");
        for k in 1..40 {
            let sigma = cut.sigma_max * k as f64 / 40.0;
            let row = cut.row(sigma);
            let (d, _) = cut.point(&row, 0.0).expect("a direction");
            let dphi = wrap(d.phi() - azimuth);
            if row.half_width > 0.02 {
                assert!((dphi - 0.02).abs() < 1e-12, "sigma {sigma}: the kink at {dphi}");
            } else if features.peak.is_none() {
                assert!(dphi.abs() < 1e-12, "sigma {sigma}: the middle at {dphi}");
            }
            // The two halves still span the row, rim to rim.
            for tau in [-1.0, 1.0] {
                let (d, _) = cut.point(&row, tau).expect("a direction");
                assert!((wrap(d.phi() - azimuth).abs() - row.half_width).abs() < 1e-12);
            }
        }
    }
}

#[test]
fn more_pieces_than_room_still_cover_the_whole_range() {
    let mut lat = Latitude::new(0.1, 0.02, 0.0).expect("across");
    let m = lat.sigma_max;
    let foci: Vec<Focus> = (1..=5)
        .map(|k| Focus {
            sigma: m * k as f64 / 6.0,
            scale: 0.01,
        })
        .collect();
    let cuts: Vec<f64> = (1..=5).map(|k| m * (k as f64 + 0.5) / 6.0).collect();
    lat.set_pieces(&foci, &cuts);
    assert_eq!(lat.pieces().len(), MAX_PIECES);
    assert_pieces_cover_sigma(&lat);
}
