//! The error estimate of a sequence of rules of increasing order (module docs of [`super`]): when successive
//! levels agree well enough to accept, and what error to report. Shared by the tensor rules above the horizon and
//! the latitude rules across it, which differ only in the guard.

use super::ApertureFunction;
use super::ConeIntegral;
use super::integrand::Integrand;

/// Extrapolate only after two successive differences have each fallen by this factor or more: steady
/// exponential convergence. A kink in the BRDF (Oren-Nayar has two) makes the differences fall irregularly, and
/// the estimate then stays with the last difference.
const EXTRAPOLATE_BELOW: f64 = 0.05;

/// Safety factor on a plain difference as the error estimate: the finer rule's error has been seen up to 1.4 times
/// the difference when convergence slows between levels.
const PLAIN: f64 = 2.0;

/// Safety factor on the extrapolated error estimate.
const SAFETY: f64 = 10.0;

/// The guarded sequence (across the horizon) never reports an error below this fraction of the previous
/// difference: no faster convergence than 10 times per level is believed, however the last two agree. At 1/100
/// two coarse rules that agreed by chance got through (a Phong tail 16 degrees from its peak, differences 5.2e-5
/// then 3.0e-7, the last rule 6.3e-7 off), and so did a gold lobe near grazing at the last level, 3.2e-6 off with
/// an estimate of 4.6e-7.
const GUARD: f64 = 0.1;

/// A sequence of rules of increasing order, `rule(it, level)` for level = `first..=last`, until the error
/// estimate from successive levels (module docs) meets the tolerance; None if the last level does not. Needs
/// `last >= first + 2`: a result is accepted from the second difference on (the first, unguarded from the centre
/// rule).
///
/// `guarded`: never report less than `GUARD` times the previous difference. Across the horizon two coarse rules have agreed by chance more closely still (a lobe's
/// ridge under-resolved alike, 1e-8 apart and both 2e-5 off).
pub(super) fn converge<F: ApertureFunction>(
    it: &mut Integrand<'_, F>,
    first: usize,
    last: usize,
    tol: f64,
    guarded: bool,
    mut rule: impl FnMut(&mut Integrand<'_, F>, usize) -> f64,
) -> Option<ConeIntegral> {
    let mut prev = rule(it, first);
    // The last two differences, newest first.
    let mut history: [Option<f64>; 2] = [None, None];
    for level in first + 1..=last {
        let value = rule(it, level);
        let d = (value - prev).abs();
        let scale = value.abs();
        let rounding = 64.0 * f64::EPSILON * scale;
        let error = match history {
            // From the centre rule (the BRDF smooth on a scale over 30 times the aperture's), the first
            // difference is the centre rule's second-order error, which the next rule (exact to degree 3)
            // cannot share by chance: it may accept.
            [None, _] if first == 0 && !guarded => (PLAIN * d).max(rounding),
            // Otherwise not before two differences: two rules can agree by chance.
            [None, _] => f64::INFINITY,
            [Some(pd), previous] => {
                let steady = pd > 0.0
                    && d < EXTRAPOLATE_BELOW * pd
                    && previous.is_some_and(|ppd| pd < EXTRAPOLATE_BELOW * ppd);
                // Converging slowly, at a ratio r per level, the rest of a geometric tail is d r / (1 - r):
                // more than d once r > 1/2. Not converging (r >= 1): ten times d, so that only a difference
                // far below the tolerance (rounding noise, typically) is accepted.
                let r = if pd > 0.0 { d / pd } else { 0.0 };
                let tail = if r < 1.0 {
                    (r / (1.0 - r)).clamp(1.0, 10.0)
                } else {
                    10.0
                };
                let plain = PLAIN * d * tail;
                let error = if steady {
                    // The extrapolation decides acceptance; what is reported is never less than the plain
                    // estimate, or the tolerance when that is more: steady convergence has been seen to slow
                    // down (extrapolated 1.3e-12, actual 2.7e-12).
                    (SAFETY * d * (d / pd)).max(plain.min(tol * scale))
                } else {
                    plain
                };
                let floor = if guarded { GUARD } else { 0.0 };
                error.max(floor * pd).max(rounding)
            }
        };
        let all_zero = value == 0.0 && prev == 0.0 && history[0] == Some(0.0);
        if error <= tol * scale || all_zero {
            return Some(ConeIntegral {
                value,
                error: if all_zero { 0.0 } else { error },
                evaluations: it.evaluations,
            });
        }
        prev = value;
        history = [Some(d), history[0]];
    }
    None
}
