//! Deterministic draws for the hidden imperfections: a counter-based generator, so that each hidden value is a
//! pure function of (seed, what it is, which one). Switching one effect on or off never changes another's value,
//! and the k-th re-seating is the same whether or not the (k-1)-th was asked for.

use std::f64::consts::PI;

/// SplitMix64's finaliser: a bijective mix of 64 bits (Steele, Lea, Flood 2014).
fn mix(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^ (z >> 31)
}

/// FNV-1a of a label: the stream a value belongs to ("zero/light-arm", "seating").
fn label_hash(label: &str) -> u64 {
    label.bytes().fold(0xCBF2_9CE4_8422_2325u64, |h, b| {
        (h ^ u64::from(b)).wrapping_mul(0x0100_0000_01B3)
    })
}

/// The draws of one instrument seed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Draws {
    seed: u64,
}

impl Draws {
    pub fn new(seed: u64) -> Draws {
        Draws { seed }
    }

    /// 64 random bits for (`label`, `index`, `k`).
    fn bits(&self, label: &str, index: u64, k: u64) -> u64 {
        mix(mix(mix(self.seed ^ label_hash(label)) ^ index) ^ k)
    }

    /// Uniform in (0, 1), never 0 (53 bits).
    pub fn uniform(&self, label: &str, index: u64, k: u64) -> f64 {
        ((self.bits(label, index, k) >> 11) as f64 + 0.5) / (1u64 << 53) as f64
    }

    /// A pair of independent standard normal draws (Box-Muller).
    pub fn normal_pair(&self, label: &str, index: u64) -> (f64, f64) {
        let u1 = self.uniform(label, index, 0);
        let u2 = self.uniform(label, index, 1);
        let r = (-2.0 * u1.ln()).sqrt();
        let (s, c) = (2.0 * PI * u2).sin_cos();
        (r * c, r * s)
    }

    /// A uniform angle in [0, 360) degrees.
    pub fn phase_deg(&self, label: &str, index: u64) -> f64 {
        360.0 * self.uniform(label, index, 2)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn normal_draws_have_unit_spread_and_depend_on_seed_and_label() {
        let d = Draws::new(7);
        let n = 20_000u64;
        let (mut s1, mut s2) = (0.0, 0.0);
        for i in 0..n {
            let (a, b) = d.normal_pair("t", i);
            s1 += a + b;
            s2 += a * a + b * b;
        }
        let mean = s1 / (2 * n) as f64;
        let var = s2 / (2 * n) as f64 - mean * mean;
        assert!(mean.abs() < 0.02 && (var - 1.0).abs() < 0.03, "{mean} {var}");
        assert_eq!(d.normal_pair("t", 3), Draws::new(7).normal_pair("t", 3));
        assert_ne!(d.normal_pair("t", 3), Draws::new(8).normal_pair("t", 3));
        assert_ne!(d.normal_pair("t", 3), d.normal_pair("u", 3));
    }
}
