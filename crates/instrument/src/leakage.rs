//! What a filter leaks outside its band: the part of a band's reading that comes from elsewhere in the
//! spectrum, from the instrument file's own figures.
//!
//! A bandpass filter blocks the rest of the spectrum to its `out_of_band_transmission` (absolute; a datasheet's
//! optical density 5 is 1e-5), not to zero, and the detector (silicon: `sensor_wavelength_nm`, 400-1100 nm) sees
//! all of it. With the source a black body at `colour_temperature_k` (`S`) and the photodiode's responsivity `R`
//! (the file's table, constant beyond its ends), the leaked photocurrent relative to the band's own is
//!
//! `L = (t_oob / T) ∫ S R d lambda / (S(c) R(c) B)`
//!
//! over the detector's range, `T` the filter's peak transmission, `c` its centre and `B` its width (FWHM): the
//! band as a top hat. A halogen lamp and a silicon photodiode are both red-heavy, so blue bands leak most
//! (about 2 % at 450 nm through OD 5 from a 3000 K lamp). A grey sample leaks as the direct beam does and the
//! ratio cancels it; a sample whose reflectance differs outside the band by `rho_far / rho - 1` is off by `L`
//! times that (gonio_results::band_component).

use crate::responsivity::Responsivity;
use crate::{FilterPosition, Instrument};

/// Second radiation constant `h c / k_B` (nm K), CODATA 2018: 1.438 776 877e-2 m K.
const C2_NM_K: f64 = 1.438_776_877e7;
/// Integration step over the detector's range (nm).
const STEP_NM: f64 = 1.0;

/// Planck's spectral radiance at `nm` and `temperature_k`, up to a constant (the simulated optics weight a
/// filter band with it too).
pub fn planck_relative(nm: f64, temperature_k: f64) -> f64 {
    1.0 / (nm.powi(5) * (C2_NM_K / (nm * temperature_k)).exp_m1())
}

/// The light the detector sees from the source at `nm`, up to a constant: Planck's spectrum at the file's
/// colour temperature times the photodiode's responsivity; `None` without a usable responsivity.
fn light(instrument: &Instrument) -> Option<impl Fn(f64) -> f64 + use<>> {
    let responsivity = Responsivity::from_detector(&instrument.detector).ok()?;
    let t = instrument.source.colour_temperature_k();
    Some(move |nm: f64| planck_relative(nm, t) * responsivity.at(nm))
}

/// `light` over the detector's range every [`STEP_NM`], each sample times its trapezoid weight and step (so
/// that they sum to the integral: the integrand is smooth and the step a tenth of any feature in it); `None`
/// for a range that is empty or reversed.
fn light_samples(instrument: &Instrument, light: impl Fn(f64) -> f64) -> Option<Vec<(f64, f64)>> {
    let [lo, hi] = instrument.detector.sensor_wavelength_nm;
    if hi.partial_cmp(&lo) != Some(std::cmp::Ordering::Greater) {
        return None;
    }
    let steps = ((hi - lo) / STEP_NM).ceil().max(2.0) as usize;
    let h = (hi - lo) / steps as f64;
    Some(
        (0..=steps)
            .map(|i| {
                let nm = lo + i as f64 * h;
                let w = if i == 0 || i == steps { 0.5 } else { 1.0 };
                (nm, w * h * light(nm))
            })
            .collect(),
    )
}

/// The leaked fraction `L` of the wheel's filter for `band_nm` (within 1e-6 nm) on `instrument`
/// ([`out_of_band_fraction`]); `None` without such a filter or a finite answer.
pub fn band_leakage(instrument: &Instrument, band_nm: f64) -> Option<f64> {
    instrument
        .filter_wheel
        .iter()
        .flat_map(|w| &w.positions)
        .filter(|p| p.band_nm.is_some_and(|b| (b - band_nm).abs() <= 1e-6))
        .find_map(|p| out_of_band_fraction(instrument, p))
}

/// The leaked fraction `L` of `position`'s band on `instrument` (module doc); `None` for a position without a
/// band and a width, a blank, or figures that give no finite answer.
pub fn out_of_band_fraction(instrument: &Instrument, position: &FilterPosition) -> Option<f64> {
    let (c, b) = (position.band_nm?, position.bandwidth_nm?);
    if position.blank || !(position.transmission > 0.0 && b > 0.0) {
        return None;
    }
    let light = light(instrument)?;
    let band = light(c) * b;
    let total: f64 = light_samples(instrument, light)?.iter().map(|s| s.1).sum();
    let l = position.out_of_band_transmission() / position.transmission * total / band;
    (l.is_finite() && l >= 0.0).then_some(l)
}

/// Where the light a filter leaks falls in the spectrum: `(nm, share)` every [`STEP_NM`] over the detector's
/// range, the source's spectrum times the photodiode's responsivity (the integrand of [`out_of_band_fraction`])
/// with its quadrature weight, normalised to a sum of 1. The same for every filter, the blocking being flat:
/// what the leak adds to a reading is the sample's reflectance averaged with these shares
/// (gonio_results::band_component estimates that average from the bands measured). `None` when the file's
/// figures give no finite, positive light.
pub fn leak_spectrum(instrument: &Instrument) -> Option<Vec<(f64, f64)>> {
    let mut samples = light_samples(instrument, light(instrument)?)?;
    let total: f64 = samples.iter().map(|s| s.1).sum();
    if !(total.is_finite() && total > 0.0) {
        return None;
    }
    for s in &mut samples {
        s.1 /= total;
    }
    Some(samples)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::InstrumentFile;

    /// The simulated instrument: a 3000 K lamp by default and the file's silicon responsivity; its filters
    /// given catalogue 10 nm bands (the ideal file's pass a single wavelength).
    fn wheel() -> (Instrument, Vec<FilterPosition>) {
        let inst = InstrumentFile::simulated().instrument;
        let mut wheel = inst.filter_wheel.clone().expect("wheel");
        wheel.set_bandwidths_nm(10.0);
        (inst, wheel.positions)
    }

    #[test]
    fn blue_bands_leak_most_and_the_blocking_scales_it() {
        let (mut inst, mut positions) = wheel();
        inst.source.colour_temperature_k = None;
        let at = |positions: &[FilterPosition], nm: f64| {
            let p = positions.iter().find(|p| p.band_nm == Some(nm)).expect("band");
            out_of_band_fraction(&inst, p).expect("fraction")
        };
        for p in positions.iter_mut() {
            p.out_of_band_transmission = Some(1e-5);
        }
        let (blue, green, red) = (
            at(&positions, 450.0),
            at(&positions, 550.0),
            at(&positions, 650.0),
        );
        // 3000 K through OD 5 with a 10 nm band at half transmission: about 2 % in the blue.
        assert!((0.005..0.05).contains(&blue), "{blue}");
        assert!(blue > green && green > red, "{blue} {green} {red}");
        for p in positions.iter_mut() {
            p.out_of_band_transmission = Some(1e-6);
        }
        assert!((at(&positions, 450.0) / blue - 0.1).abs() < 1e-9);
        for p in positions.iter_mut() {
            p.out_of_band_transmission = Some(0.0);
        }
        assert_eq!(at(&positions, 450.0), 0.0);
        let blank = positions.iter().find(|p| p.blank).expect("blank");
        assert_eq!(out_of_band_fraction(&inst, blank), None);
    }

    #[test]
    fn a_band_s_leak_is_its_filter_s_and_none_without_one() {
        let (mut inst, _) = wheel();
        // The ideal file's filters pass a single wavelength and block everything else: no leak.
        assert_eq!(band_leakage(&inst, 550.0), None);
        let w = inst.filter_wheel.as_mut().expect("wheel");
        w.set_bandwidths_nm(10.0);
        for p in &mut w.positions {
            p.out_of_band_transmission = Some(1e-5);
        }
        let green = w
            .positions
            .iter()
            .find(|p| p.band_nm == Some(550.0))
            .cloned()
            .expect("550 nm");
        let expected = out_of_band_fraction(&inst, &green).expect("fraction");
        assert!(expected > 0.0);
        assert_eq!(band_leakage(&inst, 550.0), Some(expected));
        assert_eq!(band_leakage(&inst, 551.0), None);
    }

    #[test]
    fn the_leak_falls_mostly_red() {
        let (inst, _) = wheel();
        let leak = leak_spectrum(&inst).expect("spectrum");
        assert!((leak.iter().map(|s| s.1).sum::<f64>() - 1.0).abs() < 1e-12);
        // A 3000 K lamp on silicon: most of the leak lies beyond 650 nm, little below 450.
        let share = |from: f64, to: f64| -> f64 {
            leak.iter()
                .filter(|s| (from..to).contains(&s.0))
                .map(|s| s.1)
                .sum()
        };
        assert!(share(650.0, 2000.0) > 0.6, "{}", share(650.0, 2000.0));
        assert!(share(0.0, 450.0) < 0.05, "{}", share(0.0, 450.0));
    }
}
