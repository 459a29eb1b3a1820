//! The engine shared by both rules: radial panels (split and warped at horizon tangencies), the exact arc above
//! the horizon on each ring, compensated sums at two resolutions.

use super::*;

#[derive(Debug, Clone, Copy)]
pub(super) struct Partial {
    pub(super) sum: f64,
    /// Neumaier compensation of `sum`.
    pub(super) compensation: f64,
    pub(super) abs_sum: f64,
    pub(super) evaluations: usize,
}

impl Partial {
    pub(super) fn add(&mut self, term: f64) {
        let t = self.sum + term;
        if self.sum.abs() >= term.abs() {
            self.compensation += (self.sum - t) + term;
        } else {
            self.compensation += (term - t) + self.sum;
        }
        self.sum = t;
        self.abs_sum += term.abs();
        self.evaluations += 1;
    }

    pub(super) fn value(&self) -> f64 {
        self.sum + self.compensation
    }
}

pub(super) fn combine(fine: &Partial, coarse: &Partial) -> Estimate {
    let rounding = 8.0 * f64::EPSILON * fine.abs_sum;
    let value = fine.value();
    Estimate {
        value,
        error: (value - coarse.value()).abs().max(rounding),
    }
}

/// Radial variable of a rule.
#[derive(Debug, Clone, Copy, PartialEq)]
enum Radial {
    /// u = 1 - cos(psi); d omega = du d chi.
    OneMinusCos,
    /// psi itself; d omega = sin(psi) d psi d chi.
    Angle,
}

#[derive(Debug, Clone, Copy)]
struct Panel {
    lo: f64,
    hi: f64,
    warp_lo: bool,
    warp_hi: bool,
}

/// The orthonormal frame (axis, e1, e2) of the polar coordinates; e1 points towards the normal.
struct Frame {
    a: [f64; 3],
    e1: [f64; 3],
    e2: [f64; 3],
    cos_axis: f64,
    sin_axis: f64,
}

impl Frame {
    pub(super) fn new(axis: &Direction) -> Frame {
        let a = [axis.x(), axis.y(), axis.z()];
        let s = axis.sin_theta();
        let e1 = if s > 1e-300 {
            [-a[2] * a[0] / s, -a[2] * a[1] / s, s]
        } else {
            [1.0, 0.0, 0.0]
        };
        let e2 = [
            a[1] * e1[2] - a[2] * e1[1],
            a[2] * e1[0] - a[0] * e1[2],
            a[0] * e1[1] - a[1] * e1[0],
        ];
        Frame {
            a,
            e1,
            e2,
            cos_axis: a[2],
            sin_axis: s,
        }
    }

    pub(super) fn point(&self, cos_psi: f64, sin_psi: f64, cos_chi: f64, sin_chi: f64) -> Option<Direction> {
        let c1 = sin_psi * cos_chi;
        let c2 = sin_psi * sin_chi;
        Direction::new(
            cos_psi * self.a[0] + c1 * self.e1[0] + c2 * self.e2[0],
            cos_psi * self.a[1] + c1 * self.e1[1] + c2 * self.e2[1],
            cos_psi * self.a[2] + c1 * self.e1[2] + c2 * self.e2[2],
        )
    }
}

/// Radial panels in psi (radians), with the ends where a ring is tangent to the horizon flagged for warping.
fn panels(region: &Region, frame: &Frame, rule: &Rule) -> Vec<Panel> {
    let beta = if region.half_angle_rad.is_nan() {
        0.0
    } else {
        region.half_angle_rad.clamp(0.0, PI)
    };
    let mut lo = 0.0;
    let mut hi = beta;
    let mut singular: Vec<f64> = Vec::new();
    if region.clip_to_upper_hemisphere {
        let theta_a = frame.sin_axis.atan2(frame.cos_axis);
        // Rings with psi < theta_a - pi/2 or psi > theta_a + pi/2 lie entirely below the horizon.
        if theta_a - FRAC_PI_2 > lo {
            lo = theta_a - FRAC_PI_2;
            singular.push(lo);
        }
        if theta_a + FRAC_PI_2 < hi {
            hi = theta_a + FRAC_PI_2;
            singular.push(hi);
        }
        // The first ring that touches the horizon from above.
        let tangent = FRAC_PI_2 - theta_a;
        if tangent > lo && tangent < hi {
            singular.push(tangent);
        } else if tangent <= 0.0 && lo == 0.0 {
            // Axis on the horizon: the rings are clipped from psi = 0 on, and the ring integral is odd in
            // sin(psi) (a square root in 1 - cos psi). The quadratic warp at 0 makes it smooth again.
            singular.push(0.0);
        }
    }
    if hi <= lo {
        return Vec::new();
    }
    let mut breaks = vec![lo, hi];
    breaks.extend(singular.iter().copied().filter(|&b| b > lo && b < hi));
    if let Rule::LobeAdapted { lobe_width_rad, .. } = *rule {
        if lobe_width_rad.is_finite() && lobe_width_rad > 0.0 {
            let mut b = lobe_width_rad;
            while b < hi {
                // A grading break right next to a tangency would leave the square root at the end of an
                // unwarped panel: skip it (the tangency break takes its place).
                let near_singular = singular.iter().any(|&s| (b - s).abs() < 0.25 * b);
                if b > lo && !near_singular {
                    breaks.push(b);
                }
                b *= 2.0;
            }
        }
    }
    breaks.sort_by(f64::total_cmp);
    breaks.dedup();
    let is_singular = |x: f64| singular.contains(&x);
    breaks
        .windows(2)
        .filter(|w| w[1] > w[0])
        .map(|w| Panel {
            lo: w[0],
            hi: w[1],
            warp_lo: is_singular(w[0]),
            warp_hi: is_singular(w[1]),
        })
        .collect()
}

/// Maps a Gauss node t in [-1, 1] to [lo, hi] with a quadratic warp at flagged ends; returns (v, dv/dt).
fn warp(panel_lo: f64, panel_hi: f64, warp_lo: bool, warp_hi: bool, t: f64) -> (f64, f64) {
    let len = panel_hi - panel_lo;
    match (warp_lo, warp_hi) {
        (false, false) => (panel_lo + 0.5 * len * (t + 1.0), 0.5 * len),
        (true, false) => {
            let s = 0.5 * (t + 1.0);
            (panel_lo + len * s * s, len * s)
        }
        (false, true) => {
            let s = 0.5 * (1.0 - t);
            (panel_hi - len * s * s, len * s)
        }
        (true, true) => {
            let (sin, cos) = (0.5 * PI * t).sin_cos();
            (panel_lo + 0.5 * len * (1.0 + sin), 0.25 * PI * len * cos)
        }
    }
}

pub(super) fn apply<E, F>(f: &mut F, region: &Region, rule: &Rule) -> Result<Partial, E>
where
    F: FnMut(&Direction) -> Result<f64, E>,
{
    let frame = Frame::new(&region.axis);
    let radial_kind = match rule {
        Rule::GaussTrapezoid { .. } => Radial::OneMinusCos,
        Rule::LobeAdapted { .. } => Radial::Angle,
    };
    let radial_rule = gauss_legendre(rule.radial_nodes());
    let n_azimuth = rule.azimuth_nodes();
    let arc_rule = gauss_legendre((n_azimuth / 2).max(2));
    // The trapezoid nodes of a full ring, shared by every ring.
    let ring: Vec<(f64, f64)> = (0..n_azimuth)
        .map(|j| (2.0 * PI * j as f64 / n_azimuth as f64).sin_cos())
        .collect();
    let ring_weight = 2.0 * PI / n_azimuth as f64;

    let mut total = Partial {
        sum: 0.0,
        compensation: 0.0,
        abs_sum: 0.0,
        evaluations: 0,
    };
    for panel in panels(region, &frame, rule) {
        // Panel ends in the rule's radial variable (the warp flags stay with the ends).
        let (v_lo, v_hi) = match radial_kind {
            Radial::Angle => (panel.lo, panel.hi),
            Radial::OneMinusCos => (one_minus_cos(panel.lo), one_minus_cos(panel.hi)),
        };
        for node in radial_rule.iter() {
            let (v, dv_dt) = warp(v_lo, v_hi, panel.warp_lo, panel.warp_hi, node.x);
            let (cos_psi, sin_psi, jacobian) = match radial_kind {
                Radial::Angle => {
                    let (s, c) = v.sin_cos();
                    (c, s, s * dv_dt)
                }
                Radial::OneMinusCos => (1.0 - v, (v * (2.0 - v)).max(0.0).sqrt(), dv_dt),
            };
            let radial_weight = node.weight * jacobian;
            if radial_weight == 0.0 {
                continue;
            }
            // The arc of this ring above the horizon: A + B cos(chi) > 0.
            let a_coef = cos_psi * frame.cos_axis;
            let b_coef = sin_psi * frame.sin_axis;
            let full_ring = !region.clip_to_upper_hemisphere || a_coef >= b_coef;
            if full_ring {
                for &(sin_chi, cos_chi) in &ring {
                    if let Some(w) = frame.point(cos_psi, sin_psi, cos_chi, sin_chi) {
                        total.add(radial_weight * ring_weight * f(&w)?);
                    }
                }
            } else if a_coef > -b_coef {
                let chi0 = (-a_coef / b_coef).clamp(-1.0, 1.0).acos();
                for arc_node in arc_rule.iter() {
                    let (sin_chi, cos_chi) = (chi0 * arc_node.x).sin_cos();
                    if let Some(w) = frame.point(cos_psi, sin_psi, cos_chi, sin_chi) {
                        total.add(radial_weight * chi0 * arc_node.weight * f(&w)?);
                    }
                }
            }
        }
    }
    Ok(total)
}

/// 1 - cos(psi) without cancellation near psi = 0.
fn one_minus_cos(psi: f64) -> f64 {
    let s = (0.5 * psi).sin();
    2.0 * s * s
}
