//! The finite filter band's part of a point's value and budget ([`crate::budget::components::BAND`]).
//!
//! **The centre.** A band's value is the sample's reflectance averaged over the filter's passband and quoted at
//! the band's nominal centre, but the filter's true centre is off its nominal one by up to its catalogue
//! tolerance (the instrument file's `centre_u_nm`, a standard uncertainty). The value moves by the sample's
//! spectral slope times that offset: `u = |df/dlambda| u_lambda`, the slope estimated from the neighbouring
//! bands measured at the same geometry (the data, not a model of the sample): a central difference between the
//! bands on either side, one-sided at the ends. Bands closer than [`crate::run::BAND_TOLERANCE_NM`] are one
//! band. A geometry measured in one band has no spectral information: its points get no band component.
//!
//! **The leak, corrected.** A filter passes a fraction `L` of light from outside its band (the file's blocking,
//! the source's colour temperature and the detector's responsivity: gonio_instrument::leakage), spread over the
//! detector's range as the source's spectrum times the responsivity ([`LeakSpectrum`], mostly red and near
//! infrared). The direct beam through the same filter carries the same fraction, so a band's measured value is
//! `m = (f + L fbar) / (1 + L)`, `fbar` the sample's value averaged over the leak's spectrum. A grey sample
//! cancels it; a blue band on gold or paper reads several per cent high, on a blue plastic low. The completion
//! solves for `f = m + L (m - fbar)`, with `fbar` from the bands measured at the same geometry, corrected
//! themselves (the sample's spectrum taken as linear between the bands and flat beyond the first and the last:
//! the same rule the simulator's material tables follow beyond their ends, and the one thing a lab cannot
//! measure without a band further out). The correction's uncertainty:
//! - the spectrum beyond the measured bands: within one band step of the outermost band's value (rectangular,
//!   `|f_n - f_n-1| / sqrt 3`), times the share of the leak out there;
//! - the leaked fraction itself: `L` is reckoned against the band's width, so its relative uncertainty is the
//!   width's (`bandwidth_u_nm / bandwidth_nm`); a real passband's shoulders, which the file's top-hat band
//!   leaves out, are well inside it (about 5 % for a three-cavity filter).
//!
//! The band's error is the filter's, the same for every point of the band: the component is shared by the
//! band's points (group `band-<nm>`). Not included, and why (measured with `gonio-bench --accuracy` and a
//! three-band dry-run of construction paper, whose reflectance rises sevenfold between 550 and 650 nm): the
//! passband's width (averaging a curved spectrum, about `f'' sigma^2 / 2`): the curvature from bands 100 nm
//! apart put it at 0.6 % of the value at 550 nm, where the ideal instrument, on which it is the only band
//! effect, measures within 0.01 %: that estimate would only pad the budget.
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
    /// The relative standard uncertainty of `leakage` (the band width's).
    pub leakage_u_rel: f64,
}

/// Where the leaked light falls: `(nm, share)` samples of the source's spectrum times the detector's
/// responsivity, the shares summing to 1 (gonio_instrument::leakage::leak_spectrum).
#[derive(Debug, Clone, PartialEq)]
pub struct LeakSpectrum {
    samples: Vec<(f64, f64)>,
}

/// How the leak divides among the wavelengths a sample was measured at ([`LeakSpectrum::weights`]).
#[derive(Debug, Clone, PartialEq)]
pub struct LeakWeights {
    /// One weight per node, the flat ends included; they sum to 1.
    pub nodes: Vec<f64>,
    /// The leak's share below the first node and above the last: where the spectrum is extrapolated.
    pub below: f64,
    pub above: f64,
}

impl LeakSpectrum {
    /// From `(nm, share)` samples in ascending wavelength (normalised here to a sum of 1); `None` when they do
    /// not sum to a finite positive number.
    pub fn new(mut samples: Vec<(f64, f64)>) -> Option<LeakSpectrum> {
        let total: f64 = samples.iter().map(|s| s.1).sum();
        if !(total.is_finite() && total > 0.0) {
            return None;
        }
        for s in &mut samples {
            s.1 /= total;
        }
        Some(LeakSpectrum { samples })
    }

    /// The weights that average a spectrum known at `nodes_nm` (ascending) over the leak, the spectrum taken
    /// as linear between the nodes and flat beyond them; `None` for no nodes or nodes out of order.
    pub fn weights(&self, nodes_nm: &[f64]) -> Option<LeakWeights> {
        let (&first, &last) = (nodes_nm.first()?, nodes_nm.last()?);
        if nodes_nm
            .windows(2)
            .any(|w| w[1].partial_cmp(&w[0]) != Some(std::cmp::Ordering::Greater))
        {
            return None;
        }
        let n = nodes_nm.len();
        let mut out = LeakWeights {
            nodes: vec![0.0; n],
            below: 0.0,
            above: 0.0,
        };
        for &(nm, w) in &self.samples {
            if nm <= first {
                out.nodes[0] += w;
                out.below += w;
            } else if nm >= last {
                out.nodes[n - 1] += w;
                out.above += w;
            } else {
                // Between nodes k and k + 1: the hat functions of linear interpolation.
                let k = nodes_nm.partition_point(|&x| x <= nm) - 1;
                let t = (nm - nodes_nm[k]) / (nodes_nm[k + 1] - nodes_nm[k]);
                out.nodes[k] += w * (1.0 - t);
                out.nodes[k + 1] += w * t;
            }
        }
        Some(out)
    }
}

/// A point's band estimate: the leak's correction to its value (`value + shift_sr`) and the band component of
/// the corrected value.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BandEstimate {
    /// What the leak correction adds to the point's value (1/sr).
    pub shift_sr: f64,
    /// How the correction scales the value's own errors (`1 + L`).
    pub scale: f64,
    /// The band component of the corrected value (1/sr, k = 1).
    pub u_sr: f64,
}

/// Geometries closer than this (degrees) are the same geometry seen in another band.
const SAME_GEOMETRY_DEG: f64 = 1e-6;

/// Iterations of the leak's correction: each shrinks what is left by the leaked fraction (a few per cent).
const LEAK_ITERATIONS: usize = 8;

fn same_geometry(a: &Point, b: &Point) -> bool {
    (a.theta_i_deg - b.theta_i_deg).abs() < SAME_GEOMETRY_DEG
        && (a.phi_i_deg - b.phi_i_deg).abs() < SAME_GEOMETRY_DEG
        && (a.theta_o_deg - b.theta_o_deg).abs() < SAME_GEOMETRY_DEG
        && (a.phi_o_deg - b.phi_o_deg).abs() < SAME_GEOMETRY_DEG
}

/// The valid points grouped by geometry, in index order within each group: a point joins the first group (in
/// creation order) whose first point is at its geometry.
fn geometry_groups(points: &[Point]) -> Vec<Vec<usize>> {
    // The groups are found through buckets of theta_o one tolerance wide (a group at this geometry sits in this
    // bucket or a neighbour), so a campaign of thousands of points is not compared with every group
    // (quadratic: a fifth of a 6,000-point completion's time).
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
    groups
}

/// One band at one geometry: its wavelength, the mean of its values and the points they came from.
struct Band {
    nm: f64,
    mean: f64,
    members: Vec<usize>,
}

/// The band estimate of each point (module doc), `None` where it cannot be made (no valid value, one band at
/// the geometry, or a band the filters do not describe). `filter` looks a band up in the instrument file;
/// `leak` is where the filters' leaked light falls (`None`: no correction, the leak only bounded by the
/// measured bands' spread).
pub fn band_estimates(
    points: &[Point],
    filter: impl Fn(f64) -> Option<FilterBand>,
    leak: Option<&LeakSpectrum>,
) -> Vec<Option<BandEstimate>> {
    let mut out = vec![None; points.len()];
    // The leak's weights depend only on the bands measured, the same at most geometries.
    let mut weights_for: Vec<(Vec<f64>, Option<LeakWeights>)> = Vec::new();
    for g in geometry_groups(points) {
        // One value per band (repeats averaged), ascending in wavelength.
        let mut bands: Vec<Band> = Vec::new();
        for &i in &g {
            let p = &points[i];
            let f = p.value().unwrap_or(f64::NAN);
            match bands
                .iter_mut()
                .find(|b| (b.nm - p.band_nm).abs() <= BAND_TOLERANCE_NM)
            {
                Some(b) => {
                    b.mean += f;
                    b.members.push(i);
                }
                None => bands.push(Band {
                    nm: p.band_nm,
                    mean: f,
                    members: vec![i],
                }),
            }
        }
        if bands.len() < 2 {
            continue;
        }
        for b in &mut bands {
            b.mean /= b.members.len() as f64;
        }
        bands.sort_by(|a, b| a.nm.total_cmp(&b.nm));
        let filters: Vec<Option<FilterBand>> = bands.iter().map(|b| filter(b.nm)).collect();
        let nodes: Vec<f64> = bands.iter().map(|b| b.nm).collect();
        let weights = match weights_for.iter().find(|(n, _)| *n == nodes) {
            Some((_, w)) => w.clone(),
            None => {
                let w = leak.and_then(|l| l.weights(&nodes));
                weights_for.push((nodes.clone(), w.clone()));
                w
            }
        };
        let leaked = |k: usize| filters[k].map_or(0.0, |f| f.leakage);
        let measured: Vec<f64> = bands.iter().map(|b| b.mean).collect();
        // The spectrum net of the leak and the leak's mean of it, solved by iteration (module doc).
        let (spectrum, fbar) = match &weights {
            Some(w) => {
                let mut f = measured.clone();
                let mut fbar = 0.0;
                for _ in 0..LEAK_ITERATIONS {
                    fbar = w.nodes.iter().zip(&f).map(|(w, f)| w * f).sum::<f64>();
                    for (k, fk) in f.iter_mut().enumerate() {
                        *fk = measured[k] + leaked(k) * (measured[k] - fbar);
                    }
                }
                (f, Some(fbar))
            }
            None => (measured.clone(), None),
        };
        let nm_spectrum: Vec<(f64, f64)> = nodes.iter().copied().zip(spectrum.iter().copied()).collect();
        // The leak's mean beyond the measured bands: within one band step of the outermost value.
        let n = spectrum.len();
        let fbar_u = weights.as_ref().map(|w| {
            let step = |a: usize, b: usize| (spectrum[a] - spectrum[b]).abs() / 3f64.sqrt();
            (w.above * step(n - 1, n - 2)).hypot(w.below * step(0, 1))
        });
        for (k, band) in bands.iter().enumerate() {
            let Some(filter) = filters[k] else {
                continue;
            };
            let centre = slope(&nm_spectrum, k).abs() * filter.centre_u_nm;
            let l = filter.leakage;
            let (u, fbar) = match (fbar, fbar_u) {
                (Some(fbar), Some(fbar_u)) => {
                    let of_l = l * filter.leakage_u_rel * (measured[k] - fbar).abs();
                    (centre.hypot(of_l).hypot(l * fbar_u), fbar)
                }
                _ => {
                    // No spectrum for the leak: bounded by the largest relative difference from this band's
                    // value among the bands measured.
                    let value = measured[k];
                    let far = measured
                        .iter()
                        .map(|f| (f / value - 1.0).abs())
                        .fold(0.0f64, f64::max);
                    (centre.hypot(value.abs() * l * far), f64::NAN)
                }
            };
            if !u.is_finite() {
                continue;
            }
            for &i in &band.members {
                let shift_sr = if fbar.is_finite() {
                    l * (points[i].value().unwrap_or(f64::NAN) - fbar)
                } else {
                    0.0
                };
                if shift_sr.is_finite() {
                    out[i] = Some(BandEstimate {
                        shift_sr,
                        scale: if fbar.is_finite() { 1.0 + l } else { 1.0 },
                        u_sr: u,
                    });
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
            leakage_u_rel: 0.0,
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
}
