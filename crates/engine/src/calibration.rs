//! Calibration bookkeeping without a campaign or a store: the darks per band, and the normalisation readings
//! per band (net direct beam for the absolute method, net reference signal for the relative one) with the
//! source's drift extrapolated in time. A campaign's run loop keeps them between its calibration steps; a
//! console can keep its own. (Taking the readings is [`crate::acquisition::read`] with the wheel on the blank or
//! the band; the operator protocol, removing and swapping samples, is a campaign state and stays in the run
//! loop.)

use std::collections::BTreeMap;

use gonio_brdf::measurement::Reading;

/// Normalisation readings closer in time than this are not used to extrapolate drift (s): over a shorter
/// base, the readings' own noise would dominate the slope.
pub const MIN_DRIFT_BASE_S: f64 = 30.0;

/// Bands are keyed by their wavelength's exact bits: a band is the very value the plan names.
fn band_key(nm: f64) -> u64 {
    nm.to_bits()
}

/// The last dark reading of each band (W).
#[derive(Debug, Clone, Default)]
pub struct Darks {
    last: BTreeMap<u64, (f64, Reading)>,
}

impl Darks {
    /// Keep `reading` as band `nm`'s dark, taken at instrument time `t_s`.
    pub fn keep(&mut self, nm: f64, t_s: f64, reading: Reading) {
        self.last.insert(band_key(nm), (t_s, reading));
    }

    /// Band `nm`'s last dark; zero, exactly, when none was taken (an instrument without a blank position).
    pub fn of(&self, nm: f64) -> Reading {
        self.last
            .get(&band_key(nm))
            .map(|d| d.1)
            .unwrap_or(Reading::exact(0.0))
    }
}

/// `raw - dark`, the uncertainties added in quadrature.
pub fn net_of_dark(raw: Reading, dark: Reading) -> Reading {
    Reading::new(raw.value_w - dark.value_w, raw.std_w.hypot(dark.std_w))
}

/// The net normalisation readings of each band, in time order.
#[derive(Debug, Clone, Default)]
pub struct Normalisations {
    series: BTreeMap<u64, Vec<(f64, Reading)>>,
}

impl Normalisations {
    /// Keep band `nm`'s net normalisation reading taken at instrument time `t_s`.
    pub fn keep(&mut self, nm: f64, t_s: f64, net: Reading) {
        self.series.entry(band_key(nm)).or_default().push((t_s, net));
    }

    /// Band `nm`'s normalisation at instrument time `t_s`: the last reading, carried along the straight line
    /// through the last two when they are at least [`MIN_DRIFT_BASE_S`] apart (source drift). The
    /// uncertainty is that of the extrapolation, `u2 (1 + x)` and `u1 x` in quadrature with
    /// `x = (t - t2) / (t2 - t1)`. None before the band's first reading.
    pub fn at(&self, nm: f64, t_s: f64) -> Option<Reading> {
        let list = self.series.get(&band_key(nm))?;
        let (t2, r2) = *list.last()?;
        if list.len() >= 2
            && let Some((t1, r1)) = list.get(list.len() - 2).copied()
            && t2 - t1 >= MIN_DRIFT_BASE_S
        {
            let slope = (r2.value_w - r1.value_w) / (t2 - t1);
            let x = (t_s - t2) / (t2 - t1);
            let value = r2.value_w + slope * (t_s - t2);
            let std = (r2.std_w * (1.0 + x)).hypot(r1.std_w * x);
            return Some(Reading::new(value, std));
        }
        Some(r2)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_band_without_a_dark_has_an_exact_zero_dark() {
        let mut d = Darks::default();
        assert_eq!(d.of(550.0), Reading::exact(0.0));
        d.keep(550.0, 3.0, Reading::new(2e-9, 1e-10));
        assert_eq!(d.of(550.0), Reading::new(2e-9, 1e-10));
        assert_eq!(d.of(650.0), Reading::exact(0.0));
    }

    #[test]
    fn the_net_reading_adds_uncertainties_in_quadrature() {
        let n = net_of_dark(Reading::new(5e-6, 3e-9), Reading::new(1e-8, 4e-9));
        assert!((n.value_w - 4.99e-6).abs() < 1e-18);
        assert!((n.std_w - 5e-9).abs() < 1e-21);
    }

    #[test]
    fn drift_is_extrapolated_along_the_last_two_readings_far_enough_apart() {
        let mut n = Normalisations::default();
        assert_eq!(n.at(550.0, 0.0), None);
        n.keep(550.0, 100.0, Reading::new(1.000e-3, 1e-7));
        // One reading: carried as it is.
        assert_eq!(n.at(550.0, 500.0), Some(Reading::new(1.000e-3, 1e-7)));
        // Too close for a slope: the last one.
        n.keep(550.0, 110.0, Reading::new(1.010e-3, 1e-7));
        assert_eq!(n.at(550.0, 500.0), Some(Reading::new(1.010e-3, 1e-7)));
        // 600 s apart (110 s and 710 s), +1e-5 W: at t = 1010 s (x = 0.5), half a step further, 1.025e-3 W.
        n.keep(550.0, 710.0, Reading::new(1.020e-3, 2e-7));
        let r = n.at(550.0, 1010.0).expect("a reading");
        assert!((r.value_w - 1.025e-3).abs() < 1e-15, "{r:?}");
        let x: f64 = 0.5;
        let expected_std = ((2e-7 * (1.0 + x)).powi(2) + (1e-7 * x).powi(2)).sqrt();
        assert!((r.std_w - expected_std).abs() < 1e-18, "{r:?}");
        // Another band is its own series.
        assert_eq!(n.at(650.0, 1010.0), None);
    }
}
