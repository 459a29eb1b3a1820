//! `[simulator.imperfections.filters]`: the filters' finite bands. The model is documented in
//! simulator/src/imperfections/filters.rs.
//!
//! On the ideal instrument a filter position is one wavelength, its `band_nm`. With this group on, each position
//! with a `bandwidth_nm` passes a band of that full width at half maximum (its actual centre and width drawn
//! about the nominal ones), plus a little light everywhere else the photodiode is sensitive (out-of-band
//! leakage), and a reading integrates BRDF x filter transmission x source spectrum x detector responsivity over
//! all of it.

use serde::{Deserialize, Serialize};

use super::{ImperfectionsError, check};

/// `[simulator.imperfections.filters]`: every key 0 (or absent) is the ideal single-wavelength band.
#[derive(Debug, Clone, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct FilterImperfections {
    /// Cavities of the interference filters: the passband is `1 / (1 + x^(2N))`, `x` the distance from the
    /// centre in half-widths (N = 1 a single Lorentzian-like cavity; N = 3 the usual squarer three-cavity
    /// bandpass). 0: the finite band is off.
    #[serde(default)]
    pub cavities: u32,
    /// Standard deviation of each filter's actual centre wavelength from its `band_nm` (nm).
    #[serde(default)]
    pub centre_sd_nm: f64,
    /// Standard deviation of each filter's actual width relative to its `bandwidth_nm` (fraction).
    #[serde(default)]
    pub bandwidth_sd: f64,
    /// Absolute transmission outside the passband (the blocking: 1e-4 for OD 4, 1e-5 for OD 5) over
    /// `leakage_range_nm`; 0: perfect blocking.
    #[serde(default)]
    pub out_of_band_transmission: f64,
    /// Where the photodiode sees the leakage (nm): a silicon photodiode from about 400 to 1100 nm.
    #[serde(default = "default_leakage_range_nm")]
    pub leakage_range_nm: [f64; 2],
    /// Colour temperature of the source (K): its spectrum is Planck's at this temperature (a quartz-tungsten-
    /// halogen lamp runs at about 2800-3400 K). Needed when the finite band is on.
    #[serde(default)]
    pub source_temperature_k: f64,
}

fn default_leakage_range_nm() -> [f64; 2] {
    [400.0, 1100.0]
}

impl Default for FilterImperfections {
    /// Off: single-wavelength bands (the leakage range keeps its default).
    fn default() -> FilterImperfections {
        FilterImperfections {
            cavities: 0,
            centre_sd_nm: 0.0,
            bandwidth_sd: 0.0,
            out_of_band_transmission: 0.0,
            leakage_range_nm: default_leakage_range_nm(),
            source_temperature_k: 0.0,
        }
    }
}

impl FilterImperfections {
    pub fn is_ideal(&self) -> bool {
        self.cavities == 0
            && self.centre_sd_nm == 0.0
            && self.bandwidth_sd == 0.0
            && self.out_of_band_transmission == 0.0
    }

    pub fn validate(&self) -> Result<(), ImperfectionsError> {
        const G: &str = "filters";
        check(
            G,
            "centre_sd_nm",
            self.centre_sd_nm,
            10.0,
            "a filter that far off is another filter",
        )?;
        check(
            G,
            "bandwidth_sd",
            self.bandwidth_sd,
            0.5,
            "the band would often be twice as wide",
        )?;
        check(
            G,
            "out_of_band_transmission",
            self.out_of_band_transmission,
            0.01,
            "a filter that leaks 1 % everywhere does not select a band",
        )?;
        check(
            G,
            "cavities",
            f64::from(self.cavities),
            8.0,
            "interference filters have 1 to about 6",
        )?;
        check(
            G,
            "source_temperature_k",
            self.source_temperature_k,
            10_000.0,
            "hotter than any lamp",
        )?;
        let [lo, hi] = self.leakage_range_nm;
        for (key, value) in [("leakage_range_nm[0]", lo), ("leakage_range_nm[1]", hi)] {
            check(G, key, value, 3000.0, "beyond any photodiode's sensitivity")?;
        }
        if lo >= hi {
            return Err(ImperfectionsError::Range {
                group: G,
                key: "leakage_range_nm",
                lo,
                hi,
            });
        }
        if self.is_ideal() {
            return Ok(());
        }
        // Any key on asks for the finite band, which needs a passband shape and a source spectrum.
        for (key, value) in [
            ("cavities", f64::from(self.cavities)),
            ("source_temperature_k", self.source_temperature_k),
        ] {
            if value <= 0.0 {
                return Err(ImperfectionsError::Needed {
                    group: G,
                    key,
                    needed_by: "the finite band (any filters key)",
                    value,
                });
            }
        }
        Ok(())
    }
}
