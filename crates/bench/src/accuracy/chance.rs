//! What a handful of instruments can tell of a fitted parameter's coverage: how often a fit whose k = 2
//! intervals are right would still miss issue 29's rule (within k = 2 on at least 93 % of instruments) by chance.
//!
//! A right k = 2 interval (a normal z) leaves the truth outside 4.55 % of the time, so over 16 instruments it
//! leaves it outside twice or more (87.5 %, a miss of the rule) 16 % of the time: among thirty parameter rows
//! about five such misses are expected from chance alone. A miss says something only when so many instruments
//! are outside that a right interval would rarely leave as many: the binomial tail below.

use std::fmt::Write as _;

/// How often a right k = 2 interval leaves the truth outside (two-sided normal tail beyond 2).
pub const OUTSIDE_K2: f64 = 0.045_500_263_896_358_4;

/// Below this tail probability a row's misses are not put down to chance.
const SIGNIFICANT: f64 = 0.05;

/// The rule's share (issue 29): within k = 2 on at least this share of instruments.
const RULE_SHARE: f64 = 0.93;

/// P(X >= m) for X ~ Binomial(n, p), p in [0, 1).
pub fn binomial_tail(n: usize, m: usize, p: f64) -> f64 {
    if m == 0 {
        return 1.0;
    }
    if m > n || !(0.0..1.0).contains(&p) {
        return 0.0;
    }
    // The probabilities of k = 0..n by their ratios, summed from m on.
    let mut pmf = (1.0 - p).powf(n as f64);
    let mut below = 0.0;
    for k in 0..m {
        below += pmf;
        pmf *= (n - k) as f64 / (k + 1) as f64 * p / (1.0 - p);
    }
    (1.0 - below).clamp(0.0, 1.0)
}

/// One parameter of one material on one set-up: instruments whose fit left the truth outside its k = 2
/// interval, of how many.
pub struct ParameterRow {
    pub label: String,
    pub outside: usize,
    pub instruments: usize,
}

impl ParameterRow {
    /// Whether the row misses the rule.
    fn misses(&self) -> bool {
        let within = self.instruments - self.outside.min(self.instruments);
        (within as f64) < RULE_SHARE * self.instruments as f64
    }

    /// The fewest outside that miss the rule.
    fn first_miss(&self) -> usize {
        (0..=self.instruments)
            .find(|&m| ((self.instruments - m) as f64) < RULE_SHARE * self.instruments as f64)
            .unwrap_or(self.instruments + 1)
    }
}

/// The paragraph under the fits' table: misses expected by chance against misses seen, and which misses a right
/// interval would rarely show.
pub fn paragraph(rows: &[ParameterRow]) -> String {
    let mut s = String::new();
    if rows.is_empty() {
        return s;
    }
    let expected: f64 = rows
        .iter()
        .map(|r| binomial_tail(r.instruments, r.first_miss(), OUTSIDE_K2))
        .sum();
    // Rows that right intervals put below the significance level by chance: each row's chance of reaching
    // its first count whose tail is below it.
    let false_alarms: f64 = rows
        .iter()
        .map(|r| {
            (0..=r.instruments)
                .map(|m| binomial_tail(r.instruments, m, OUTSIDE_K2))
                .find(|&t| t < SIGNIFICANT)
                .unwrap_or(0.0)
        })
        .sum();
    let missed: Vec<&ParameterRow> = rows.iter().filter(|r| r.misses()).collect();
    let outside: usize = rows.iter().map(|r| r.outside).sum();
    let total: usize = rows.iter().map(|r| r.instruments).sum();
    let _ = write!(
        s,
        "\nWhat {} instruments can tell (crates/bench/src/accuracy/chance.rs): a right k = 2 interval leaves the \
         truth outside {:.2} % of the time, so even right intervals miss the 93 % rule on some rows by chance: on \
         these {} parameter rows about {:.1} misses are expected, {} are seen. Over every row, {} of {} fitted \
         values are outside their k = 2 interval ({:.2} %).",
        rows.iter().map(|r| r.instruments).max().unwrap_or(0),
        100.0 * OUTSIDE_K2,
        rows.len(),
        expected,
        missed.len(),
        outside,
        total,
        100.0 * outside as f64 / total.max(1) as f64,
    );
    if missed.is_empty() {
        s.push('\n');
        return s;
    }
    let _ = write!(
        s,
        " Each miss, with how often right intervals leave as many instruments outside or more (below 5 %: not \
         chance; among {} rows right intervals would still put about {:.1} below it):\n\n",
        rows.len(),
        false_alarms
    );
    for r in missed {
        let tail = binomial_tail(r.instruments, r.outside, OUTSIDE_K2);
        let _ = writeln!(
            s,
            "- {}: {} of {} outside, {:.1} %{}",
            r.label,
            r.outside,
            r.instruments,
            100.0 * tail,
            if tail < SIGNIFICANT {
                ": not chance"
            } else {
                ": chance can explain it"
            }
        );
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The tail against sums of the binomial's terms written out (n = 16, p = 0.0455).
    #[test]
    fn the_binomial_tail_is_the_sum_of_its_terms() {
        let (n, p) = (16usize, OUTSIDE_K2);
        let choose = |n: usize, k: usize| (0..k).fold(1.0, |c, i| c * (n - i) as f64 / (i + 1) as f64);
        let term = |k: usize| choose(n, k) * p.powi(k as i32) * (1.0 - p).powi((n - k) as i32);
        for m in 0..=n {
            let want: f64 = (m..=n).map(term).sum();
            assert!((binomial_tail(n, m, p) - want).abs() < 1e-12, "m = {m}");
        }
        // Two or more of 16 outside, the chance of a right interval missing the rule: 16.3 % (Python's
        // math.comb summed the same way gives 0.163255); four or more: 0.50 %.
        assert!(
            (binomial_tail(16, 2, p) - 0.163_255).abs() < 1e-6,
            "{}",
            binomial_tail(16, 2, p)
        );
        assert!(
            (binomial_tail(16, 4, p) - 0.005_019).abs() < 1e-6,
            "{}",
            binomial_tail(16, 4, p)
        );
        assert_eq!(binomial_tail(16, 17, p), 0.0);
        assert_eq!(binomial_tail(16, 0, p), 1.0);
    }

    #[test]
    fn a_row_misses_the_rule_below_93_percent_within() {
        let row = |outside| ParameterRow {
            label: String::new(),
            outside,
            instruments: 16,
        };
        assert!(!row(1).misses()); // 93.75 %
        assert!(row(2).misses()); // 87.5 %
        assert_eq!(row(0).first_miss(), 2);
        let text = paragraph(&[row(4), row(0)]);
        assert!(text.contains("4 of 16 outside"), "{text}");
        assert!(text.contains("not chance"), "{text}");
    }
}
