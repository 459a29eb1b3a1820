//! The power meter's own noise (Thorlabs PM100USB with a photodiode head): the figures its simulation
//! (simulator/src/pm100/physics.rs) draws each sample's noise with and the self-test subtracts from the
//! direct beam's spread (crates/engine/src/selftest/noise.rs). One sample every [`SAMPLE_S`]; the
//! transimpedance amplifier reaches [`FULL_SCALE_V`] at the range's full-scale current; a 16-bit converter
//! over the range.

/// The meter's time per sample (s): about 3 ms.
pub const SAMPLE_S: f64 = 0.003;
/// Full-scale voltage of the transimpedance amplifier (sets the feedback resistor of each range).
pub const FULL_SCALE_V: f64 = 2.0;
/// The converter's counts over a range.
pub const ADC_COUNTS: f64 = 65_536.0;
const ELEMENTARY_CHARGE_C: f64 = 1.602_176_634e-19;
const BOLTZMANN_J_K: f64 = 1.380_649e-23;
const TEMPERATURE_K: f64 = 295.0;

/// The noise bandwidth of one sample (Hz).
pub fn bandwidth_hz() -> f64 {
    1.0 / (2.0 * SAMPLE_S)
}

/// Shot noise of a photocurrent `current_a` in one sample (A^2).
pub fn shot_a2(current_a: f64) -> f64 {
    2.0 * ELEMENTARY_CHARGE_C * current_a.abs() * bandwidth_hz()
}

/// Johnson noise of the feedback resistor of a range of full-scale current `full_scale_a`, in one sample (A^2).
pub fn johnson_a2(full_scale_a: f64) -> f64 {
    4.0 * BOLTZMANN_J_K * TEMPERATURE_K * bandwidth_hz() * full_scale_a / FULL_SCALE_V
}

/// An amplifier's excess current noise of density `a_per_rthz` (A/sqrt(Hz)) in one sample (A^2).
pub fn amplifier_a2(a_per_rthz: f64) -> f64 {
    a_per_rthz * a_per_rthz * bandwidth_hz()
}

/// One count of the converter on a range of full scale `full_scale` (in the range's unit).
pub fn lsb(full_scale: f64) -> f64 {
    full_scale / ADC_COUNTS
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_noise_terms_scale_with_current_and_range() {
        // 1 mA: sqrt(2 e I B) = 0.231 nA over 167 Hz.
        assert!((shot_a2(1e-3).sqrt() / 2.311e-10 - 1.0).abs() < 0.01);
        assert_eq!(shot_a2(-1e-3), shot_a2(1e-3));
        assert!((johnson_a2(2e-3) / johnson_a2(1e-3) - 2.0).abs() < 1e-12);
        assert_eq!(lsb(65_536.0), 1.0);
    }
}
