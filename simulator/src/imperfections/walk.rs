//! The source's random walk as a pure function of the seed and the instant, drawn only where it is asked for.
//!
//! # The walk
//! Knots every [`WALK_STEP_S`]; the steps between knots are independent normal draws of standard deviation
//! `sigma = s sqrt(step / 1 h)` (`s` the configured `random_walk_per_rthour`), so `Var W(t) = s^2 t / 1 h` at
//! every knot; between knots the walk is interpolated linearly.
//!
//! # Why a tree of sums (Lévy's construction, discrete)
//! Summing the steps from 0 to the knot asked for costs time linear in the instant (a week of steps at start-up,
//! as an earlier version drew them), and caching them ties the values to the order of the questions. Here the
//! knots are grouped in blocks of 2^[`LEVELS`] steps (about two years at the minute step). Each block's total is
//! one normal draw of variance `2^LEVELS sigma^2`; a node's total is split between its two halves by the exact
//! conditional law of a sum of two independent normals, `left = T/2 + sigma sqrt(2^L) / 2 z` (`z` a standard
//! normal drawn for that node): given the total, the left half is normal with mean `T/2` and half the variance
//! of one half. Descending from a block to the knot asked for takes [`LEVELS`] draws, each keyed by
//! (level, node index) in the counter-based generator, so:
//! - the joint law of the steps is exactly that of independent normal steps (the construction is a change of
//!   variables, not an approximation), hence the same statistics as summing them;
//! - the value at an instant is the same whatever was asked before, in order or not, and costs the same at start-up
//!   as a week later;
//! - blocks follow one another as a walk of their totals, so the walk never stops. Beyond [`MAX_BLOCKS`] blocks
//!   (thousands of years of simulated time) it holds its value, which bounds the work for any input.

use super::draw::Draws;

/// Knot spacing of the random walk (s).
pub const WALK_STEP_S: f64 = 60.0;
/// Levels of the tree in one block: a block holds 2^LEVELS steps.
pub const LEVELS: u32 = 20;
/// Blocks the walk runs through before it holds its value (2^20 minutes each: about 4000 years in all).
pub const MAX_BLOCKS: u64 = 2048;

const LABEL_BLOCK: &str = "source-walk-block";
const LABEL_SPLIT: &str = "source-walk-split";

/// One instrument's walk: its seed and step size.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Walk {
    draws: Draws,
    /// Standard deviation of one knot-to-knot step (relative).
    step_sd: f64,
}

impl Walk {
    /// The walk of `seed` with `random_walk_per_rthour` = `s` (relative per sqrt(hour)).
    pub fn new(per_rthour: f64, seed: u64) -> Walk {
        Walk {
            draws: Draws::new(seed),
            step_sd: per_rthour * (WALK_STEP_S / 3600.0).sqrt(),
        }
    }

    /// Total of the steps of block `b` (the first `2^LEVELS` steps are block 0).
    fn block_total(&self, b: u64) -> f64 {
        self.step_sd * f64::from(1u32 << LEVELS).sqrt() * self.draws.normal_pair(LABEL_BLOCK, b).0
    }

    /// The walk's value at knot `n` and the step from it to knot `n + 1`: `(W_n, W_{n+1} - W_n)`.
    pub fn knot(&self, n: u64) -> (f64, f64) {
        let last = MAX_BLOCKS << LEVELS;
        if n >= last {
            // Held: the value at the last knot, no further step.
            let (w, step) = self.knot(last - 1);
            return (w + step, 0.0);
        }
        let block = n >> LEVELS;
        let mut start: f64 = (0..block).map(|b| self.block_total(b)).sum();
        let mut total = self.block_total(block);
        // Node index at the current level, counted over the whole walk (block b's root is node b at the top).
        let mut node = block;
        for level in (1..=LEVELS).rev() {
            let half_sd = 0.5 * self.step_sd * f64::from(1u32 << level).sqrt();
            // The key joins level and node index; node < MAX_BLOCKS 2^(LEVELS - level) < 2^32 fits beside it.
            let z = self
                .draws
                .normal_pair(LABEL_SPLIT, (node << 5) | u64::from(level))
                .0;
            let left = 0.5 * total + half_sd * z;
            if (n >> (level - 1)) & 1 == 0 {
                total = left;
                node <<= 1;
            } else {
                start += left;
                total -= left;
                node = (node << 1) | 1;
            }
        }
        (start, total)
    }

    /// The walk's relative value at `t_s` (0 at and before 0, linear between knots).
    pub fn at(&self, t_s: f64) -> f64 {
        if t_s.is_nan() || t_s <= 0.0 || self.step_sd == 0.0 {
            return 0.0;
        }
        let x = t_s / WALK_STEP_S;
        let k = x.floor();
        // `as` saturates: an instant past the last knot (or infinite) lands on the held value, where there is
        // nothing to interpolate (and `x - k` would be NaN for an infinite instant).
        let (w, step) = self.knot(k as u64);
        if step == 0.0 { w } else { w + (x - k) * step }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Knot-to-knot steps over many seeds and across the tree's splits (within one block's halves, quarters,
    /// ..., and across the boundary between blocks) have variance sigma^2 and are uncorrelated with their
    /// neighbours: the law of independent steps.
    #[test]
    fn steps_are_independent_with_the_configured_variance() {
        let s = 1e-3;
        let sigma2 = s * s * WALK_STEP_S / 3600.0;
        let block = 1u64 << LEVELS;
        // Knots where the deepest splits and the block boundary meet, and some in between.
        let knots = [
            0,
            1,
            2,
            3,
            511,
            512,
            513,
            block / 2 - 1,
            block / 2,
            block - 1,
            block,
            block + 1,
        ];
        let seeds = 2000u64;
        let (mut sum2, mut cross, mut count) = (0.0, 0.0, 0.0);
        for seed in 0..seeds {
            let w = Walk::new(s, seed);
            for &n in &knots {
                let (_, a) = w.knot(n);
                let (_, b) = w.knot(n + 1);
                sum2 += a * a;
                cross += a * b;
                count += 1.0;
            }
        }
        let var_ratio = sum2 / count / sigma2;
        let corr = cross / sum2;
        // 24 000 squared normals: the mean is 1 within 0.02 at 2 sigma; the correlation within 0.013.
        assert!((var_ratio - 1.0).abs() < 0.03, "variance ratio {var_ratio}");
        assert!(corr.abs() < 0.03, "correlation of neighbouring steps {corr}");
    }

    /// Var W(t) = s^2 t / 1 h over many instruments, at an instant inside the first block and at one in the second
    /// (about two years in, where the block totals add).
    #[test]
    fn the_walk_spreads_as_sqrt_time() {
        let s = 1e-3;
        let seeds = 2000u64;
        for t_s in [4.0 * 3600.0, 1.5 * 3600.0 * f64::from(1u32 << LEVELS) / 60.0] {
            let var = (0..seeds)
                .map(|seed| Walk::new(s, seed).at(t_s).powi(2))
                .sum::<f64>()
                / seeds as f64;
            let ratio = var / (s * s * t_s / 3600.0);
            // 2000 dof: +-6.3 % at 2 sigma.
            assert!((ratio - 1.0).abs() < 0.1, "t {t_s} s: variance ratio {ratio}");
        }
    }

    /// The value at an instant does not depend on what was asked before: a sweep forwards and the same sweep
    /// backwards give the same values, bit for bit; and a knot's value plus its step is the next knot's value.
    #[test]
    fn the_same_seed_gives_the_same_walk_in_any_order() {
        let w = Walk::new(5e-4, 42);
        let times: Vec<f64> = (0..500).map(|k| f64::from(k) * 1234.5).collect();
        let forward: Vec<f64> = times.iter().map(|&t| w.at(t)).collect();
        let backward: Vec<f64> = times.iter().rev().map(|&t| Walk::new(5e-4, 42).at(t)).collect();
        assert!(forward.iter().eq(backward.iter().rev()));
        for n in [0u64, 7, 1 << 19, (1 << LEVELS) - 1, 3 << LEVELS] {
            let (a, step) = w.knot(n);
            let (b, _) = w.knot(n + 1);
            assert!((a + step - b).abs() < 1e-15, "knot {n}: {a} + {step} vs {b}");
        }
        assert_ne!(Walk::new(5e-4, 43).at(3600.0), w.at(3600.0));
    }

    #[test]
    fn starts_at_zero_interpolates_and_holds_at_the_end() {
        let w = Walk::new(1e-3, 3);
        assert_eq!(w.at(0.0), 0.0);
        assert_eq!(w.at(-5.0), 0.0);
        assert_eq!(w.at(f64::NAN), 0.0);
        let mid = w.at(1.5 * WALK_STEP_S);
        assert!((mid - 0.5 * (w.at(WALK_STEP_S) + w.at(2.0 * WALK_STEP_S))).abs() < 1e-15);
        let end = w.at(1e30);
        assert!(end.is_finite());
        assert_eq!(end, w.at(f64::INFINITY));
        assert_eq!(Walk::new(0.0, 3).at(1e6), 0.0);
    }
}
