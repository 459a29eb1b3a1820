//! The finite filter band's part of a point's budget ([`crate::budget::components::BAND`]): a band's value is
//! the sample's reflectance averaged over the filter's passband and quoted at the band's nominal centre, but
//! the filter's true centre is off its nominal one by up to its catalogue tolerance (the instrument file's
//! `centre_u_nm`, a standard uncertainty). The value moves by the sample's spectral slope times that offset:
//! `u = |df/dlambda| u_lambda`, the slope estimated from the neighbouring bands measured at the same geometry
//! (the data, not a model of the sample): a central difference between the bands on either side, one-sided at
//! the ends. Bands closer than [`crate::run::BAND_TOLERANCE_NM`] are one band. A geometry measured in one band
//! has no spectral information: its points get no band component. The error is the filter's, the same for
//! every point of the band: it is shared by the band's points (group `band-<nm>`).
//!
//! Out-of-band leakage joins it: the filter passes a fraction `L` of light from outside its band
//! (gonio_instrument::leakage, from the file's blocking, the source's colour temperature and the detector's
//! responsivity), which the direct beam divides out for a grey sample but not for one whose reflectance outside
//! the band differs by `rho_far / rho - 1`. The measured bands at the same geometry bound that ratio: the
//! largest `|f_j / f - 1|` over them (the spectrum beyond the reddest band taken as no further from this band's
//! value than the bands measured: the leak is mostly red and near infrared). The component is
//! `hypot(|f'| u_lambda, f L max |f_j / f - 1|)`.
//!
//! Not included, and why (measured with `gonio-bench --accuracy` and a three-band dry-run of construction
//! paper, whose reflectance rises sevenfold between 550 and 650 nm): the passband's width (averaging a curved
//! spectrum, about `f'' sigma^2 / 2`): the curvature from bands 100 nm apart put it at 0.6 % of the value at
//! 550 nm, where the ideal instrument, on which it is the only band effect, measures within 0.01 %: that
//! estimate would only pad the budget.
//!
//! Neighbouring bands 100 nm apart see a sharp spectral edge as a gentler slope than it has at the edge itself:
//! the estimate is only as good as the band spacing allows.

use crate::points::Point;
use crate::run::BAND_TOLERANCE_NM;

/// What the instrument file says of one band's filter.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FilterBand {
    pub band_nm: f64,
    /// Standard uncertainty of the filter's centre wavelength (nm).
    pub centre_u_nm: f64,
    /// The light the filter leaks outside its band, relative to the band's own (gonio_instrument::leakage).
    pub leakage: f64,
}

/// Geometries closer than this (degrees) are the same geometry seen in another band.
const SAME_GEOMETRY_DEG: f64 = 1e-6;

fn same_geometry(a: &Point, b: &Point) -> bool {
    (a.theta_i_deg - b.theta_i_deg).abs() < SAME_GEOMETRY_DEG
        && (a.phi_i_deg - b.phi_i_deg).abs() < SAME_GEOMETRY_DEG
        && (a.theta_o_deg - b.theta_o_deg).abs() < SAME_GEOMETRY_DEG
        && (a.phi_o_deg - b.phi_o_deg).abs() < SAME_GEOMETRY_DEG
}

/// The band component of each point (1/sr, k = 1), `None` where it cannot be estimated (no valid value, one band
/// at the geometry, or a band the filters do not describe). `filter` looks a band up in the instrument file.
pub fn band_components(points: &[Point], filter: impl Fn(f64) -> Option<FilterBand>) -> Vec<Option<f64>> {
    // The valid points grouped by geometry, in index order within each group: a point joins the first group
    // (in creation order) whose first point is at its geometry. The groups are found through buckets of
    // theta_o one tolerance wide (a group at this geometry sits in this bucket or a neighbour), so a campaign
    // of thousands of points is not compared with every group (quadratic: a fifth of a 6,000-point
    // completion's time).
    let bucket = |p: &Point| (p.theta_o_deg / SAME_GEOMETRY_DEG).floor() as i64;
    let mut by_bucket: std::collections::HashMap<i64, Vec<usize>> = std::collections::HashMap::new();
    let mut groups: Vec<Vec<usize>> = Vec::new();
    for (i, p) in points.iter().enumerate() {
        if p.value().is_none() {
            continue;
        }
        let b = bucket(p);
        let found = (b.saturating_sub(1)..=b.saturating_add(1))
            .filter_map(|k| by_bucket.get(&k))
            .flatten()
            .copied()
            .filter(|&g| same_geometry(&points[groups[g][0]], p))
            .min();
        match found {
            Some(g) => groups[g].push(i),
            None => {
                by_bucket.entry(b).or_default().push(groups.len());
                groups.push(vec![i]);
            }
        }
    }
    let mut out = vec![None; points.len()];
    for g in groups {
        // One value per band (repeats averaged), ascending in wavelength.
        let mut bands: Vec<(f64, f64, Vec<usize>)> = Vec::new();
        for &i in &g {
            let p = &points[i];
            let f = p.value().unwrap_or(f64::NAN);
            match bands
                .iter_mut()
                .find(|(nm, _, _)| (nm - p.band_nm).abs() <= BAND_TOLERANCE_NM)
            {
                Some((_, sum, members)) => {
                    *sum += f;
                    members.push(i);
                }
                None => bands.push((p.band_nm, f, vec![i])),
            }
        }
        if bands.len() < 2 {
            continue;
        }
        let spectrum: Vec<(f64, f64)> = {
            let mut s: Vec<(f64, f64)> = bands
                .iter()
                .map(|(nm, sum, members)| (*nm, sum / members.len() as f64))
                .collect();
            s.sort_by(|a, b| a.0.total_cmp(&b.0));
            s
        };
        for (nm, _, members) in &bands {
            let Some(k) = spectrum.iter().position(|(b, _)| b == nm) else {
                continue;
            };
            let Some(filter) = filter(*nm) else {
                continue;
            };
            let centre = slope(&spectrum, k).abs() * filter.centre_u_nm;
            // The leak, as far as the measured bands tell the spectrum outside this one: the largest relative
            // difference from this band's value.
            let value = spectrum[k].1;
            let far = spectrum
                .iter()
                .map(|(_, f)| (f / value - 1.0).abs())
                .fold(0.0f64, f64::max);
            let u = centre.hypot(value.abs() * filter.leakage * far);
            if u.is_finite() {
                for &i in members {
                    out[i] = Some(u);
                }
            }
        }
    }
    out
}

/// The spectral slope (per nm) at `spectrum[k]`: central between its neighbours, one-sided at the ends.
fn slope(spectrum: &[(f64, f64)], k: usize) -> f64 {
    let n = spectrum.len();
    let (lo, hi) = match (k, n) {
        (0, _) => (0, 1),
        (k, n) if k + 1 == n => (k - 1, k),
        (k, _) => (k - 1, k + 1),
    };
    (spectrum[hi].1 - spectrum[lo].1) / (spectrum[hi].0 - spectrum[lo].0)
}

#[cfg(test)]
mod tests {
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
        })
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
    fn the_slope_is_central_inside_and_one_sided_at_the_ends_and_unknown_or_invalid_bands_get_none() {
        // f = 1e-5 (nm - 550)^2 + 0.2 at 450, 550, 650 and 700 nm.
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
        // At 550 the central slope over 450..650 is 0.
        assert_eq!(u[1], Some(0.0), "{u:?}");
        // At 450: one-sided, (f(550) - f(450)) / 100 nm = -1e-3 per nm, times 1 nm.
        assert!((u[0].expect("450") - 1e-3).abs() < 1e-12, "{u:?}");
        // At 650: central over 550..700.
        assert!(
            (u[2].expect("650") - (f(700.0) - f(550.0)) / 150.0).abs() < 1e-12,
            "{u:?}"
        );
        // 700 nm is not a filter of the file; a failed reading has no value.
        assert_eq!((u[3], u[4]), (None, None));
    }
}
