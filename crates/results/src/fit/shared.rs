//! What the points of a fit share (crate::budget: a component with a group, fully correlated within it: the
//! solid angle across the campaign, a band's normalisation, a range's gain) moves them together, so it does not
//! show in the residuals and the fit's own covariance cannot see it. Its effect on each parameter is found by
//! moving the group's points by the component's standard uncertainty and fitting again: the parameter's shift
//! is that group's contribution (a linear propagation, by finite difference), and the groups, independent of
//! each other, add in quadrature. Runs without budgets share nothing that is known.

use std::collections::BTreeMap;

use super::{FitOptions, FittedParam, fit_unshared};
use crate::run::Run;

/// Each parameter's shared standard uncertainty (the same order as `params`); `None` for a parameter that no
/// group moves, or when a refit fails. A run whose points carry no shared component gives all `None`.
pub(super) fn shared_uncertainties(run: &Run, opts: &FitOptions, params: &[FittedParam]) -> Vec<Option<f64>> {
    // (component, group) -> the points it moves and by how much.
    let mut groups: BTreeMap<(String, String), Vec<(usize, f64)>> = BTreeMap::new();
    for (i, p) in run.points.iter().enumerate() {
        if p.value().is_none() {
            continue;
        }
        for e in &p.budget.entries {
            if let Some(g) = &e.shared
                && e.u_sr > 0.0
                && e.u_sr.is_finite()
            {
                groups
                    .entry((e.component.clone(), g.clone()))
                    .or_default()
                    .push((i, e.u_sr));
            }
        }
    }
    let mut sum2 = vec![0.0f64; params.len()];
    let mut moved = vec![false; params.len()];
    for members in groups.values() {
        let mut shifted = run.clone();
        for &(i, u) in members {
            if let Some(f) = shifted.points[i].brdf_sr.as_mut() {
                *f += u;
            }
        }
        let Ok(refit) = fit_unshared(&shifted, opts) else {
            return vec![None; params.len()];
        };
        for (k, p) in params.iter().enumerate() {
            let Some(q) = refit
                .params
                .iter()
                .find(|q| q.key == p.key && q.band_nm == p.band_nm)
            else {
                continue;
            };
            let d = q.value - p.value;
            if d.is_finite() && d != 0.0 {
                sum2[k] += d * d;
                moved[k] = true;
            }
        }
    }
    sum2.iter()
        .zip(&moved)
        .map(|(s, m)| m.then(|| s.sqrt()))
        .collect()
}
