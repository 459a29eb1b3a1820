//! A reading through a finite filter band (model: crate::imperfections::filters).
//!
//! For each filter the band's weight `W(lambda) = S tau R / ∫ S tau_nominal R` is integrated once, finely
//! (Simpson's rule, 0.05 nm steps over the photodiode's range), onto a coarse set of nodes: every twelfth of a
//! width across the passband (+-1.5 widths) and every 50 nm elsewhere. Node `k` gets `w_k = ∫ W h_k`, `h_k` the
//! piecewise-linear hat on the nodes, so `Σ w_k g(lambda_k)` is the exact integral of `W` times `g` interpolated
//! linearly between the nodes, and `Σ w_k = ∫ W` exactly (to the fine rule). A reading then costs one BRDF
//! evaluation per node (about 50), not one aperture integral per node: the aperture integral is computed at the
//! band's centre and scaled by the point BRDF's spectrum at the pose, `∫ W c ≈ c(c_k) Σ w_k f(lambda_k) /
//! f(c_k)` (the regular part), and likewise the delta lobe by its reflectance. The total `∫ W` joins the
//! filter's transmission (the beam, the stray light and the direct beam carry it); the rest is the band's mean
//! of the sample's spectrum relative to its centre value. That assumes the lobe's angular
//! shape does not change across the band; over a 10 nm band it changes far less than the error budget resolves,
//! and the far leakage is itself a fraction of a percent. A material whose spectral table does not reach a node
//! is held at its value at the nearest node it does reach (what its data says, extrapolated flat).

use std::sync::{Arc, OnceLock};

use crate::imperfections::{FilterTruth, FiltersTruth};
use crate::responsivity::Responsivity;
/// Planck's law, as the instrument file's leakage estimate weights a band (one formula for both).
pub use gonio_instrument::leakage::planck_relative;

use gonio_brdf::{Brdf, Direction};

use super::resolved::Resolved;
use super::{Optics, OpticsError};

/// Fine step of the weights' integration (nm).
const FINE_STEP_NM: f64 = 0.05;
/// Spacing of the nodes away from the passband (nm).
const FAR_NODE_STEP_NM: f64 = 50.0;

/// An N-cavity passband relative to its peak, centred on `centre_nm` with full width at half maximum `width_nm`.
pub fn passband(nm: f64, centre_nm: f64, width_nm: f64, cavities: u32) -> f64 {
    let x = 2.0 * (nm - centre_nm) / width_nm;
    1.0 / (1.0 + x.powi(2 * cavities as i32))
}

/// One filter's band as the optics integrate it.
#[derive(Debug)]
pub(crate) struct SpectralBand {
    /// The position's nominal centre (what the wheel reports), nm.
    pub nominal_nm: f64,
    /// `∫ W`: the power through the actual filter relative to the nominal single-wavelength band.
    pub total: f64,
    /// Nodes (nm), increasing, and their weights (`Σ = total`).
    pub nodes_nm: Vec<f64>,
    pub weights: Vec<f64>,
    /// The sample's material at each node, resolved on first use (crate::optics::resolved).
    pub materials: OnceLock<Vec<Arc<Resolved>>>,
}

impl SpectralBand {
    /// The band of `filter`, or `None` when it lies outside the photodiode's range (it then stays a single
    /// wavelength) or a value is not finite.
    pub fn new(
        truth: &FiltersTruth,
        filter: &FilterTruth,
        responsivity: &Responsivity,
    ) -> Option<SpectralBand> {
        let [lo, hi] = truth.leakage_range_nm;
        let n = truth.cavities;
        let t = truth.source_temperature_k;
        let floor = if filter.transmission > 0.0 {
            truth.out_of_band_transmission / filter.transmission
        } else {
            0.0
        };
        let (c, b) = (filter.centre_nm, filter.bandwidth_nm);
        let light = |nm: f64| planck_relative(nm, t) * responsivity.at(nm);
        let actual = |nm: f64| light(nm) * (passband(nm, c, b, n) + floor);
        let nominal = |nm: f64| light(nm) * passband(nm, filter.nominal_nm, filter.nominal_bandwidth_nm, n);

        let steps = (((hi - lo) / FINE_STEP_NM).ceil() as usize).max(2) & !1;
        let h = (hi - lo) / steps as f64;
        let simpson = |i: usize| -> f64 {
            let w = if i == 0 || i == steps {
                1.0
            } else if i % 2 == 1 {
                4.0
            } else {
                2.0
            };
            w * h / 3.0
        };
        let norm: f64 = (0..=steps).map(|i| simpson(i) * nominal(lo + i as f64 * h)).sum();
        if !(norm.is_finite() && norm > 0.0) {
            return None;
        }

        let nodes_nm = nodes(lo, hi, c, b);
        let mut weights = vec![0.0; nodes_nm.len()];
        let mut k = 0;
        for i in 0..=steps {
            let nm = lo + i as f64 * h;
            let mass = simpson(i) * actual(nm) / norm;
            while k + 2 < nodes_nm.len() && nm > nodes_nm[k + 1] {
                k += 1;
            }
            // Split between the two nodes around nm, linearly (the hats).
            let (a, z) = (nodes_nm[k], nodes_nm[k + 1]);
            let u = ((nm - a) / (z - a)).clamp(0.0, 1.0);
            weights[k] += mass * (1.0 - u);
            weights[k + 1] += mass * u;
        }
        let total: f64 = weights.iter().sum();
        total.is_finite().then(|| SpectralBand {
            nominal_nm: filter.nominal_nm,
            total,
            nodes_nm,
            weights,
            materials: OnceLock::new(),
        })
    }

    /// The band's mean of a spectrum relative to its value `at_centre` at the band's centre, from its weighted
    /// sum over the nodes `Σ w_k g_k`: `Σ w_k g_k / (g_c Σ w_k)`; 1 when `g_c` is 0 (nothing to scale).
    pub fn mean_ratio(&self, weighted_sum: f64, at_centre: f64) -> f64 {
        if at_centre == 0.0 || !at_centre.is_finite() || self.total == 0.0 {
            return 1.0;
        }
        weighted_sum / (at_centre * self.total)
    }
}

/// How a finite band changes what the sample returns beyond its total weight (which the transmission carries):
/// the band's mean of the point BRDF's and of the delta lobe's spectra relative to their values at the centre
/// (both 1 when the band is a single wavelength or the sample is grey).
#[derive(Debug, Clone, Copy, PartialEq)]
pub(super) struct BandRatios {
    pub regular: f64,
    pub delta: f64,
}

impl Optics {
    /// The finite band of the filter whose nominal centre is `band_nm`; `None` on the ideal instrument.
    pub(super) fn spectral_band(&self, band_nm: f64) -> Option<&SpectralBand> {
        self.spectral
            .iter()
            .find(|b| b.nominal_nm == band_nm)
            .map(|b| b.as_ref())
    }

    /// The sample's material at each node of `band`, resolved once; a node its spectral tables do not reach
    /// takes the nearest node that they do (module doc), or the centre's material `centre` if none does.
    fn node_materials<'a>(&self, band: &'a SpectralBand, centre: &Arc<Resolved>) -> &'a [Arc<Resolved>] {
        band.materials.get_or_init(|| {
            let found: Vec<Option<Arc<Resolved>>> =
                band.nodes_nm.iter().map(|&nm| self.resolved(nm).ok()).collect();
            (0..found.len())
                .map(|i| {
                    let nearest = (0..found.len()).filter(|&j| found[j].is_some()).min_by(|&a, &b| {
                        let d = |j: usize| (band.nodes_nm[j] - band.nodes_nm[i]).abs();
                        d(a).total_cmp(&d(b))
                    });
                    nearest
                        .and_then(|j| found[j].clone())
                        .unwrap_or_else(|| Arc::clone(centre))
                })
                .collect()
        })
    }

    /// The band's factors on the sample's light at the material-frame directions `wi_m`, `wo_m`, `centre` the
    /// material at the band's nominal centre.
    pub(super) fn band_ratios(
        &self,
        band: &SpectralBand,
        centre: &Arc<Resolved>,
        wi_m: &Direction,
        wo_m: &Direction,
    ) -> Result<BandRatios, OpticsError> {
        let materials = self.node_materials(band, centre);
        let err = |band_nm, source| OpticsError::Spectrum { band_nm, source };
        let point = |r: &Resolved| {
            r.material
                .eval(wi_m, wo_m, r.wavelength)
                .map_err(|e| err(r.band_nm, e))
        };
        let delta = |r: &Resolved| {
            r.material
                .delta_lobe(wi_m, r.wavelength)
                .map(|l| l.map_or(0.0, |l| l.reflectance))
                .map_err(|e| err(r.band_nm, e))
        };
        // Per reading: the weighted sums straight from the node materials, no buffer.
        let weighted = |at: &dyn Fn(&Resolved) -> Result<f64, OpticsError>| -> Result<f64, OpticsError> {
            let mut sum = 0.0;
            for (w, m) in band.weights.iter().zip(materials) {
                sum += w * at(m)?;
            }
            Ok(sum)
        };
        let (f_centre, d_centre) = (point(centre)?, delta(centre)?);
        let regular = band.mean_ratio(weighted(&point)?, f_centre);
        let delta_ratio = if d_centre != 0.0 {
            band.mean_ratio(weighted(&delta)?, d_centre)
        } else {
            1.0
        };
        Ok(BandRatios {
            regular,
            delta: delta_ratio,
        })
    }
}

/// The nodes over `[lo, hi]`: twelfths of a width across `centre +- 1.5 width` (where all but 0.1 % of a
/// three-cavity band's weight lies), every 50 nm elsewhere (at least 25 nm from the passband's nodes), and both
/// ends. At least two. Linear interpolation between nodes `h` apart costs about `h^2 f'' / 8` of a smooth
/// spectrum: 4.7e-5 of a red edge's value at twelfths of a 10 nm band, and across 50 nm of the same edge 7e-4
/// of a reading that leakage doubles (simulator/tests/it/imperfections/filters.rs). The far nodes fall on
/// multiples of 50 nm from the range's start, where the seed materials' tables have their entries.
fn nodes(lo: f64, hi: f64, centre: f64, width: f64) -> Vec<f64> {
    let (band_lo, band_hi) = (centre - 1.5 * width, centre + 1.5 * width);
    let mut v: Vec<f64> = (-18..=18)
        .map(|j| centre + f64::from(j) * width / 12.0)
        .filter(|nm| (lo..=hi).contains(nm))
        .collect();
    let far = ((hi - lo) / FAR_NODE_STEP_NM).ceil() as usize;
    for i in 0..=far {
        let nm = (lo + i as f64 * FAR_NODE_STEP_NM).min(hi);
        let clear = nm < band_lo - 0.5 * FAR_NODE_STEP_NM || nm > band_hi + 0.5 * FAR_NODE_STEP_NM;
        if clear || i == 0 || i == far {
            v.push(nm);
        }
    }
    v.sort_by(f64::total_cmp);
    v.dedup_by(|a, b| (*a - *b).abs() < 1e-9);
    if v.len() < 2 {
        return vec![lo, hi];
    }
    v
}

#[cfg(test)]
mod tests {
    use super::*;

    fn truth(floor: f64) -> (FiltersTruth, FilterTruth) {
        let f = FilterTruth {
            position: 2,
            nominal_nm: 550.0,
            nominal_bandwidth_nm: 10.0,
            transmission: 0.5,
            centre_nm: 550.0,
            bandwidth_nm: 10.0,
        };
        let t = FiltersTruth {
            cavities: 3,
            source_temperature_k: 3000.0,
            out_of_band_transmission: floor,
            leakage_range_nm: [400.0, 1100.0],
            filters: vec![f],
        };
        (t, f)
    }

    #[test]
    fn the_nominal_band_without_leakage_has_unit_weight() {
        let (t, f) = truth(0.0);
        let band = SpectralBand::new(&t, &f, &Responsivity::Constant(0.3)).expect("band");
        assert!((band.total - 1.0).abs() < 1e-12, "{}", band.total);
        assert!(band.nodes_nm.windows(2).all(|w| w[0] < w[1]));
        // A spectrum linear in wavelength is integrated exactly by the hats: its mean over the (nearly
        // symmetric) band is close to its centre value.
        let lin = |nm: f64| 1.0 + (nm - 550.0) / 1000.0;
        let sum: f64 = band
            .weights
            .iter()
            .zip(&band.nodes_nm)
            .map(|(w, &nm)| w * lin(nm))
            .sum();
        let r = band.mean_ratio(sum, lin(550.0));
        assert!((r - 1.0).abs() < 2e-4, "{r}");
    }

    #[test]
    fn the_passband_is_half_at_half_width_and_planck_peaks_where_wien_says() {
        assert!((passband(555.0, 550.0, 10.0, 3) - 0.5).abs() < 1e-15);
        // Wien: lambda_max T = 2.897 771 955e6 nm K.
        let t = 3000.0;
        let peak = 2.897_771_955e6 / t;
        assert!(planck_relative(peak, t) > planck_relative(peak - 1.0, t));
        assert!(planck_relative(peak, t) > planck_relative(peak + 1.0, t));
    }
}
