//! A xorshift64 generator: tiny, fixed-seed, reproducible, no dependency.

/// xorshift64 (13, 7, 17). The seed must be nonzero (zero is its only fixed point); [`XorShift::new`] maps 0
/// to 1.
#[derive(Debug, Clone)]
pub struct XorShift(u64);

impl XorShift {
    pub fn new(seed: u64) -> XorShift {
        XorShift(seed.max(1))
    }

    pub fn next_u64(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }

    /// Uniform in [0, 1), 53 bits.
    pub fn uniform(&mut self) -> f64 {
        (self.next_u64() >> 11) as f64 / (1u64 << 53) as f64
    }

    /// The generator as a closure of uniform draws in [0, 1), for code written against `FnMut() -> f64`.
    pub fn into_uniform(mut self) -> impl FnMut() -> f64 {
        move || self.uniform()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn draws_are_reproducible_and_in_the_unit_interval() {
        let a: Vec<f64> = {
            let mut r = XorShift::new(42);
            (0..1000).map(|_| r.uniform()).collect()
        };
        let mut u = XorShift::new(42).into_uniform();
        let b: Vec<f64> = (0..1000).map(|_| u()).collect();
        assert_eq!(a, b);
        assert!(a.iter().all(|x| (0.0..1.0).contains(x)));
        let mean = a.iter().sum::<f64>() / a.len() as f64;
        assert!((mean - 0.5).abs() < 0.05, "{mean}");
        assert_eq!(XorShift::new(0).next_u64(), XorShift::new(1).next_u64());
    }
}
