//! A filter's passband as a band's value sees it: its variance about the centre, and where the light through it
//! is centred.
//!
//! A catalogue interference bandpass filter (Thorlabs' and Edmund's hard-coated ones are three-cavity or more)
//! transmits close to a Butterworth response of order six about its centre `c`, `T(x) = 1 / (1 + (2x / B)^6)`
//! for `x = lambda - c` and `B` its full width at half maximum: squarer than a Gaussian, with skirts a top hat
//! lacks. A band's value is the ratio of two readings through the same filter (the sample's and the direct
//! beam's), so it is the sample's spectrum averaged with the weight `w = T S R`, `S` the source's spectrum (a
//! black body at the file's `colour_temperature_k`) and `R` the photodiode's responsivity:
//! - its **variance** makes the value differ from the spectrum at the centre by about `f'' sigma^2 / 2`
//!   (gonio_results::band_component counts it);
//! - its **centroid** is not the filter's centre: `S R` rises across the band (a 3000 K lamp and silicon both
//!   favour the red), so the light through a 10 nm filter is centred 0.24 nm above a 450 nm centre, 0.13 nm above
//!   550 and 0.07 nm above 650 (the file's responsivity table). The value is the spectrum there
//!   (gonio_results::band_component counts it with the centre's tolerance).
//!
//! A band of no width (the ideal instrument's filters, `bandwidth_nm = 0`) is a single wavelength: neither.

use crate::leakage::planck_relative;
use crate::responsivity::Responsivity;
use crate::{FilterPosition, Instrument};

/// The Butterworth order of a three-cavity filter's transmission (twice the cavities).
const ORDER: i32 = 6;

/// The variance (nm^2) of a three-cavity passband of full width at half maximum `bandwidth_nm`:
/// `(B/2)^2 sin(pi/6) / sin(3 pi/6) = B^2 / 8` (the integrals `∫ x^m / (1 + x^n) dx = pi / (n sin((m + 1) pi / n))`
/// over the half line), 12.5 nm^2 for a 10 nm band, half again a top hat's `B^2 / 12`. 0 for a band of no
/// width or none stated.
pub fn variance_nm2(bandwidth_nm: Option<f64>) -> f64 {
    bandwidth_nm
        .filter(|b| b.is_finite() && *b > 0.0)
        .map_or(0.0, |b| b * b / 8.0)
}

/// The filter's transmission at `x` nm from its centre, relative to its peak.
fn transmission(x: f64, bandwidth_nm: f64) -> f64 {
    1.0 / (1.0 + (2.0 * x / bandwidth_nm).powi(ORDER))
}

/// How far (nm) the light a band passes (source x responsivity x passband) is centred above the filter's
/// centre (module doc); 0 for a band of no width, `None` for the blank, a position without a band, or figures
/// that give no finite answer.
pub fn centroid_offset_nm(instrument: &Instrument, position: &FilterPosition) -> Option<f64> {
    let c = position.band_nm?;
    if position.blank {
        return None;
    }
    let b = match position.bandwidth_nm {
        Some(b) if b > 0.0 => b,
        _ => return Some(0.0),
    };
    let responsivity = Responsivity::from_detector(&instrument.detector).ok()?;
    let t = instrument.source.colour_temperature_k();
    // Out to 20 widths either side in steps of a two-hundredth of a width: the skirts fall as x^-6, so what
    // lies beyond moves the centroid by less than 1e-5 nm.
    let (steps, h) = (8000, b / 200.0);
    let (mut m0, mut m1) = (0.0, 0.0);
    for i in -steps..=steps {
        let x = f64::from(i) * h;
        let w = planck_relative(c + x, t) * responsivity.at(c + x) * transmission(x, b);
        m0 += w;
        m1 += w * x;
    }
    let offset = m1 / m0;
    offset.is_finite().then_some(offset)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::InstrumentFile;

    #[test]
    fn a_three_cavity_passband_has_a_variance_of_an_eighth_of_its_width_squared() {
        // Numerically, the order-six response of a 10 nm band to +-2000 nm in 0.01 nm steps.
        let b = 10.0;
        let (mut m0, mut m2) = (0.0, 0.0);
        for i in -200_000..=200_000 {
            let x = f64::from(i) * 0.01;
            m0 += transmission(x, b);
            m2 += x * x * transmission(x, b);
        }
        assert!(
            (m2 / m0 / variance_nm2(Some(b)) - 1.0).abs() < 1e-3,
            "{}",
            m2 / m0
        );
        assert_eq!(variance_nm2(Some(b)), 12.5);
        assert_eq!(variance_nm2(None), 0.0);
        assert_eq!(variance_nm2(Some(0.0)), 0.0);
        assert_eq!(variance_nm2(Some(f64::NAN)), 0.0);
        // Half maximum at half the width.
        assert!((transmission(b / 2.0, b) - 0.5).abs() < 1e-15);
    }

    #[test]
    fn the_light_through_a_band_is_centred_to_the_red_and_less_so_further_red() {
        let file = InstrumentFile::simulated();
        let inst = file.instrument;
        let mut wheel = inst.filter_wheel.clone().expect("wheel");
        let at = |positions: &[FilterPosition], nm: f64| {
            let p = positions.iter().find(|p| p.band_nm == Some(nm)).expect("band");
            centroid_offset_nm(&inst, p).expect("offset")
        };
        // The ideal file's filters pass a single wavelength.
        assert_eq!(at(&wheel.positions, 550.0), 0.0);
        wheel.set_bandwidths_nm(10.0);
        let positions = wheel.positions;
        let (blue, green, red) = (
            at(&positions, 450.0),
            at(&positions, 550.0),
            at(&positions, 650.0),
        );
        // About sigma^2 d ln(S R) / d lambda: 12.5 nm^2 times (Planck's slope at 3000 K plus the responsivity's).
        let ln_slope = |nm: f64| {
            let r = Responsivity::from_detector(&inst.detector).expect("responsivity");
            let f = |x: f64| (planck_relative(x, 3000.0) * r.at(x)).ln();
            (f(nm + 0.5) - f(nm - 0.5)) / 1.0
        };
        assert!((green / (12.5 * ln_slope(550.0)) - 1.0).abs() < 0.1, "{green}");
        assert!(blue > green && green > red && red > 0.0, "{blue} {green} {red}");
        assert!(blue < 0.5, "a fraction of the 1 nm centre tolerance: {blue}");
        let blank = positions.iter().find(|p| p.blank).expect("blank");
        assert_eq!(centroid_offset_nm(&inst, blank), None);
    }
}
