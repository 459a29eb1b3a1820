//! The centre of a scan through a beam: the mid-point of its two half-height edges.
//!
//! Every profile the alignment scans (the direct beam or a mirror's reflection crossing the detector's aperture)
//! is symmetric about its centre whatever its shape (a Gaussian beam, a top hat, cut by a round aperture), so
//! the mid-point of the two edges at the same height is its centre without a model of the profile. The edges
//! are steep where the beam crosses the aperture's rim, so each is located far more precisely than the top of
//! a flat profile would be. Each edge: a straight line fitted to the readings between 15 % and 85 % of the
//! plateau, crossed with half of the plateau; its uncertainty from the line's residual scatter.

/// Why a scan has no centre.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum CentreError {
    #[error("no beam: the largest reading ({max_w:.3e} W) is not above the scan's baseline and noise")]
    NoBeam { max_w: f64 },
    #[error("the profile runs off the {side} end of the scan: widen the scan or check the nominal position")]
    NotInside { side: &'static str },
    #[error("too few readings on the {side} edge ({count}) to fit it: use a finer step")]
    FewEdgePoints { side: &'static str, count: usize },
    #[error(
        "no specular peak: the reflection varies by {contrast_percent:.1} % over the scan with no maximum to fit \
         (a diffuse sample cannot be aligned on; align on the mirror only)"
    )]
    NoSpecularPeak { contrast_percent: f64 },
}

/// An edge or a centre, with its standard uncertainty (same unit as the positions).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Located {
    pub value: f64,
    pub u: f64,
}

/// Readings at positions, sorted by position (those that are not numbers left out).
pub(crate) fn sorted(samples: &[(f64, f64)]) -> Vec<(f64, f64)> {
    let mut s: Vec<(f64, f64)> = samples
        .iter()
        .copied()
        .filter(|(x, p)| x.is_finite() && p.is_finite())
        .collect();
    s.sort_by(|a, b| a.0.total_cmp(&b.0));
    s
}

/// The profile's plateau (the mean of readings within 2 % of the largest) and the baseline (the smaller end).
pub fn plateau_and_base(samples: &[(f64, f64)]) -> Option<(f64, f64)> {
    let s = sorted(samples);
    let max = s.iter().map(|v| v.1).fold(f64::NEG_INFINITY, f64::max);
    if !max.is_finite() {
        return None;
    }
    let top: Vec<f64> = s.iter().map(|v| v.1).filter(|p| *p >= 0.98 * max).collect();
    let plateau = top.iter().sum::<f64>() / top.len() as f64;
    let base = s.first()?.1.min(s.last()?.1);
    Some((plateau, base))
}

/// Where the coarse profile crosses `level` on each side of its top (linear interpolation): the edges' rough
/// positions.
pub fn rough_edges(samples: &[(f64, f64)], level: f64) -> Result<(f64, f64), CentreError> {
    let s = sorted(samples);
    let Some(top) = (0..s.len()).max_by(|&a, &b| s[a].1.total_cmp(&s[b].1)) else {
        return Err(CentreError::NoBeam { max_w: 0.0 });
    };
    let cross = |i: usize, j: usize| {
        let (x0, p0) = s[i];
        let (x1, p1) = s[j];
        if p1 == p0 {
            0.5 * (x0 + x1)
        } else {
            x0 + (level - p0) * (x1 - x0) / (p1 - p0)
        }
    };
    let left = (1..=top)
        .rev()
        .find(|&i| s[i - 1].1 < level && s[i].1 >= level)
        .map(|i| cross(i - 1, i))
        .ok_or(CentreError::NotInside { side: "low" })?;
    let right = (top..s.len() - 1)
        .find(|&i| s[i].1 >= level && s[i + 1].1 < level)
        .map(|i| cross(i, i + 1))
        .ok_or(CentreError::NotInside { side: "high" })?;
    Ok((left, right))
}

/// One edge from fine readings across it: where the straight line through those between 15 % and 85 % of the
/// way from `base` to `plateau` crosses their mid-height.
pub fn edge(
    samples: &[(f64, f64)],
    plateau: f64,
    base: f64,
    side: &'static str,
) -> Result<Located, CentreError> {
    let span = plateau - base;
    let pts: Vec<(f64, f64)> = sorted(samples)
        .into_iter()
        .filter(|(_, p)| {
            let f = (p - base) / span;
            (0.15..=0.85).contains(&f)
        })
        .collect();
    if pts.len() < 3 {
        return Err(CentreError::FewEdgePoints {
            side,
            count: pts.len(),
        });
    }
    let n = pts.len() as f64;
    let mx = pts.iter().map(|p| p.0).sum::<f64>() / n;
    let my = pts.iter().map(|p| p.1).sum::<f64>() / n;
    let sxx: f64 = pts.iter().map(|p| (p.0 - mx).powi(2)).sum();
    let sxy: f64 = pts.iter().map(|p| (p.0 - mx) * (p.1 - my)).sum();
    let slope = sxy / sxx;
    if !(slope.is_finite() && slope != 0.0) {
        return Err(CentreError::FewEdgePoints {
            side,
            count: pts.len(),
        });
    }
    let level = base + 0.5 * span;
    let value = mx + (level - my) / slope;
    let rss: f64 = pts
        .iter()
        .map(|p| (p.1 - (my + slope * (p.0 - mx))).powi(2))
        .sum();
    // The residual scatter, with a floor of a part in 10^5 of the plateau so that a noiseless simulation does
    // not claim a perfect edge (the straight line is itself an approximation of the edge's curve).
    let sigma = (rss / (n - 2.0).max(1.0)).sqrt().max(1e-5 * span.abs());
    // Variance of x at the level: (sigma / slope)^2 (1/n + (x - mx)^2 / sxx).
    let u = (sigma / slope.abs()) * (1.0 / n + (value - mx).powi(2) / sxx).sqrt();
    Ok(Located { value, u })
}

/// The centre from the two edges.
pub fn centre(left: Located, right: Located) -> Located {
    Located {
        value: 0.5 * (left.value + right.value),
        u: 0.5 * left.u.hypot(right.u),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A flat-topped symmetric profile: a smoothed box of half-width 0.4 about `c`.
    fn profile(x: f64, c: f64) -> f64 {
        let e = |t: f64| 0.5 * (1.0 + (t / 0.03).tanh());
        1e-4 * e(x - (c - 0.4)) * e((c + 0.4) - x) + 1e-9
    }

    #[test]
    fn the_centre_of_a_symmetric_profile_is_found_off_grid() {
        let c = 0.123_456;
        let coarse: Vec<(f64, f64)> = (-30..=30)
            .map(|k| {
                let x = f64::from(k) * 0.05;
                (x, profile(x, c))
            })
            .collect();
        let (plateau, base) = plateau_and_base(&coarse).unwrap();
        let (l, r) = rough_edges(&coarse, base + 0.5 * (plateau - base)).unwrap();
        let fine = |x0: f64| -> Vec<(f64, f64)> {
            (-8..=8)
                .map(|k| {
                    let x = x0 + f64::from(k) * 0.005;
                    (x, profile(x, c))
                })
                .collect()
        };
        let left = edge(&fine(l), plateau, base, "low").unwrap();
        let right = edge(&fine(r), plateau, base, "high").unwrap();
        let got = centre(left, right);
        // The line fitted to a curved edge sampled off-centre leaves a small bias, well inside the uncertainty.
        assert!(
            (got.value - c).abs() < 1e-4 && (got.value - c).abs() < 3.0 * got.u,
            "{got:?}"
        );
        assert!(got.u > 0.0 && got.u < 1e-3, "{got:?}");
    }

    #[test]
    fn a_profile_that_leaves_the_scan_or_a_missing_beam_is_refused() {
        let off: Vec<(f64, f64)> = (-10..=10)
            .map(|k| {
                let x = f64::from(k) * 0.05;
                (x, profile(x, 0.45))
            })
            .collect();
        let (plateau, base) = plateau_and_base(&off).unwrap();
        assert_eq!(
            rough_edges(&off, base + 0.5 * (plateau - base)),
            Err(CentreError::NotInside { side: "high" })
        );
        let flat: Vec<(f64, f64)> = (0..5).map(|k| (f64::from(k), 1e-9)).collect();
        assert!(edge(&flat, 1e-9, 1e-9, "low").is_err());
    }
}
