//! The filters' finite bands: what a filter position really passes.
//!
//! # Model (magnitudes from `[simulator.imperfections.filters]`)
//! The ideal instrument treats a filter position as one wavelength, its `band_nm`. A real bandpass filter passes
//! a band: position `k` (nominal centre `c_k`, full width at half maximum `B_k` = its `bandwidth_nm`, peak
//! transmission `T_k`) transmits, relative to its peak,
//!
//! `tau_k(lambda) = 1 / (1 + x^(2N)) + t_oob / T_k` on the leakage range, `1 / (1 + x^(2N))` elsewhere,
//!
//! with `x = 2 (lambda - c'_k) / B'_k`: an N-cavity (Butterworth-like) passband whose actual centre
//! `c'_k = c_k + N(0, centre_sd_nm)` and width `B'_k = B_k (1 + N(0, bandwidth_sd))` are drawn per position, plus
//! the blocking's floor `t_oob` (absolute) wherever the photodiode is sensitive (`leakage_range_nm`). The passband
//! shape: N = 3, the usual three-cavity filter, has its 1 % points at 2.15 half-widths; Knight Optical give 1.99 for
//! their standard three-cavity range ("1%BW/HBW = 1.99", their interference-filter glossary), and describe the
//! centre moving by about 0.1 nm/K with temperature (not modelled).
//!
//! The source's spectrum `S(lambda)` is Planck's at `source_temperature_k`; the photodiode's responsivity `R` is
//! the instrument file's table (crate::responsivity; constant beyond its ends). A reading through position `k`
//! then carries, instead of the ideal `P T f(c_k)`, the power `P T ∫ W_k(lambda) c(lambda) d lambda` with
//!
//! `W_k = S tau_k R / ∫ S tau_k,nominal R`,
//!
//! `tau_k,nominal` the nominal passband (centre `c_k`, width `B_k`, no leakage) and `c(lambda)` what the sample
//! returns into the aperture at `lambda`. The meter, which converts with `R(c_k)` (the wavelength it is set to),
//! then reports exactly what this photocurrent means: with the nominal filter and a grey sample, `∫ W_k = 1` and the
//! reading is the ideal one. What changes a reading:
//! - the sample's spectrum across the band: a reading is a weighted mean of `f(lambda)`, not `f(c_k)`;
//! - the band's actual centre and width and its leakage change `∫ W_k`, the power through the filter: a
//!   direct-beam or reference reading through the same filter divides it out again, an absolute power does not;
//! - leakage adds the sample's reflectance far from the band (weighted by a halogen lamp's and a silicon
//!   photodiode's red-heavy spectra, so the blue bands leak most).
//!
//! Magnitudes (config/instruments/realistic.toml): Thorlabs' hard-coated bandpass filters specify out-of-band
//! blocking ODabs > 5 (355-694 nm centres; Thorlabs product page "Hard-Coated UV/VIS Bandpass Filters"); centre
//! and width tolerances of +-2 nm for 10 nm filters are the common catalogue figure (recalled, not re-checked).
//!
//! The band's integral is computed in crate::optics::spectral. Only what the file describes is drawn: a position
//! without `bandwidth_nm` (or 0) stays a single wavelength.

use gonio_instrument::{FilterImperfections, InstrumentFile};
use serde::Serialize;

use super::draw::Draws;

/// The hidden actual bands of one instrument's filters.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct FiltersTruth {
    /// Cavities of the passband shape (N).
    pub cavities: u32,
    /// Colour temperature of the source's Planck spectrum (K).
    pub source_temperature_k: f64,
    /// Absolute transmission outside the passband, over `leakage_range_nm`.
    pub out_of_band_transmission: f64,
    pub leakage_range_nm: [f64; 2],
    /// One per wheel position with a band and a width.
    pub filters: Vec<FilterTruth>,
}

/// One filter: its nominal band (as the instrument file states it) and its actual one.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct FilterTruth {
    pub position: u8,
    pub nominal_nm: f64,
    pub nominal_bandwidth_nm: f64,
    /// Peak transmission (the file's `transmission`).
    pub transmission: f64,
    /// The actual centre and full width at half maximum (nm).
    pub centre_nm: f64,
    pub bandwidth_nm: f64,
}

impl FiltersTruth {
    /// Draw the actual bands of `file`'s filter wheel; `None` when the finite band is off or no position has a
    /// band with a width.
    pub fn draw(settings: &FilterImperfections, file: &InstrumentFile) -> Option<FiltersTruth> {
        if settings.is_ideal() || settings.cavities == 0 {
            return None;
        }
        let draws = Draws::new(file.simulator.seed);
        let positions = file.instrument.filter_wheel.as_ref()?.positions.iter();
        let filters: Vec<FilterTruth> = positions
            .filter(|p| !p.blank && p.transmission > 0.0)
            .filter_map(|p| {
                let (nominal_nm, nominal_bandwidth_nm) = (p.band_nm?, p.bandwidth_nm?);
                if !(nominal_bandwidth_nm > 0.0 && nominal_nm > 0.0) {
                    return None;
                }
                let (dc, dw) = draws.normal_pair("filter-band", u64::from(p.position));
                Some(FilterTruth {
                    position: p.position,
                    nominal_nm,
                    nominal_bandwidth_nm,
                    transmission: p.transmission,
                    centre_nm: nominal_nm + settings.centre_sd_nm * dc,
                    // A width cannot turn negative: at the validated 0.5 sd that needs a 2-sigma draw, floored.
                    bandwidth_nm: nominal_bandwidth_nm * (1.0 + settings.bandwidth_sd * dw).max(0.1),
                })
            })
            .collect();
        (!filters.is_empty()).then_some(FiltersTruth {
            cavities: settings.cavities,
            source_temperature_k: settings.source_temperature_k,
            out_of_band_transmission: settings.out_of_band_transmission,
            leakage_range_nm: settings.leakage_range_nm,
            filters,
        })
    }

    /// The filter whose nominal centre is `band_nm` (the wheel reports its position's nominal band).
    pub fn filter_at(&self, band_nm: f64) -> Option<&FilterTruth> {
        self.filters.iter().find(|f| f.nominal_nm == band_nm)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The simulated instrument, its filters given catalogue 10 nm bands (the ideal file's pass a single
    /// wavelength).
    fn file(seed: u64) -> InstrumentFile {
        let mut f = InstrumentFile::simulated();
        if let Some(w) = f.instrument.filter_wheel.as_mut() {
            w.set_bandwidths_nm(10.0);
        }
        f.simulator.seed = seed;
        f
    }

    fn settings() -> FilterImperfections {
        FilterImperfections {
            cavities: 3,
            centre_sd_nm: 1.0,
            bandwidth_sd: 0.1,
            source_temperature_k: 3000.0,
            ..Default::default()
        }
    }

    #[test]
    fn every_band_with_a_width_is_drawn_and_the_seed_fixes_it() {
        let a = FiltersTruth::draw(&settings(), &file(3)).expect("drawn");
        let wheel = file(3).instrument.filter_wheel.expect("wheel");
        let with_width = wheel
            .positions
            .iter()
            .filter(|p| !p.blank && p.bandwidth_nm.is_some_and(|b| b > 0.0))
            .count();
        assert_eq!(a.filters.len(), with_width);
        assert_eq!(Some(a.clone()), FiltersTruth::draw(&settings(), &file(3)));
        assert_ne!(Some(a), FiltersTruth::draw(&settings(), &file(4)));
        let off = FilterImperfections::default();
        assert_eq!(FiltersTruth::draw(&off, &file(3)), None);
    }

    #[test]
    fn centres_and_widths_spread_as_the_magnitudes_say() {
        let (mut c2, mut w2, mut n) = (0.0, 0.0, 0.0);
        for seed in 0..400 {
            let t = FiltersTruth::draw(&settings(), &file(seed)).expect("drawn");
            for f in &t.filters {
                c2 += (f.centre_nm - f.nominal_nm).powi(2);
                w2 += (f.bandwidth_nm / f.nominal_bandwidth_nm - 1.0).powi(2);
                n += 1.0;
            }
        }
        let (c_sd, w_sd) = ((c2 / n).sqrt(), (w2 / n).sqrt());
        assert!((c_sd - 1.0).abs() < 0.05, "centre sd {c_sd}");
        assert!((w_sd - 0.1).abs() < 0.005, "width sd {w_sd}");
    }
}
