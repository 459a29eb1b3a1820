//! The dark's drift between dark readings, with hindsight.
//!
//! While a campaign runs, each value is net of its band's last dark reading (crate::calibration::Darks): the
//! only dark known then. Room light leaking past the baffles is in every dark and every reading, and it is not
//! constant: on realistic.toml it varies by 20 % over half an hour, so a dark taken a minute before a point is
//! off by a few 1e-12 W by the time of the point, more than the signal of a mirror away from its specular
//! direction. Those values came out a few 1e-5 1/sr from a truth of zero, many of their stated uncertainties
//! away (issue 29). Once the campaign has completed (it ends with a dark), the dark after each point is known
//! too: the point's dark becomes the straight line between its band's darks before and after it
//! ([`redark`]), whose own uncertainty is the two readings' through the interpolation and what a straight line
//! still misses, the drift's curvature, from the neighbouring darks' second difference:
//! `|D''| (t - t_k) (t_k+1 - t) / 2` (as the source's drift, super::drift). The two readings' errors are the
//! same for every value between them, so they are kept apart from the curvature ([`Redarked::readings_u_w`]):
//! the budget shares them by dark reading (a campaign on the ideal instrument has only a band's first and last
//! darks, and their noise moved the fitted albedo of a dark sample at 450 nm by several of its independent
//! uncertainties while it was counted as scatter).
//!
//! A value moves by `-dv/dD` times the change of its dark: the measurement equation's sensitivity to the dark
//! at the value's geometry, band and normalisation, which the run works out ([`DarkSensitivity`]).

use std::collections::BTreeMap;

use crate::store::CalibrationRecord;

/// A dark reading: instrument time (s), value and standard uncertainty (W).
#[derive(Debug, Clone, Copy, PartialEq)]
struct Dark {
    t_s: f64,
    value_w: f64,
    u_w: f64,
}

/// What the re-darkening needs of a value: its band, its time (s), the dark it was net of while running (W;
/// `None`: the band's last dark before it, as the run took it) and what the equation's sensitivity needs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Darkened {
    pub band_nm: f64,
    pub t_s: f64,
    pub dark_w: Option<f64>,
    /// theta_i, phi_i, theta_o, phi_o (deg).
    pub geometry_deg: [f64; 4],
    /// The normalisation it was divided by (W).
    pub incident_w: f64,
}

/// How much a value moves per watt of its dark (1/sr per W, positive: the dark lowers it), by the measurement
/// equation the run took it with; `None` where the equation refuses the value's geometry.
pub type DarkSensitivity<'a> = dyn Fn(&Darkened) -> Option<f64> + 'a;

/// One value's dark, with hindsight.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Redarked {
    /// The dark it was net of while running (W).
    pub used_w: f64,
    /// That dark's standard uncertainty as read (W).
    pub used_u_w: f64,
    /// The dark interpolated to its time (W).
    pub dark_w: f64,
    /// The two dark readings it is interpolated between, each by its position in its band's darks (in time
    /// order) and its standard uncertainty times its weight in the interpolation (W). Every value between the
    /// same two darks takes the same two readings' errors: shared, not scatter.
    pub readings_u_w: [(usize, f64); 2],
    /// What a straight line between them still misses, the drift's curvature (W): each value's own.
    pub curvature_u_w: f64,
}

impl Redarked {
    /// The interpolated dark's standard uncertainty (W): the two readings' and the drift's curvature.
    pub fn u_w(&self) -> f64 {
        let [(_, a), (_, b)] = self.readings_u_w;
        a.hypot(b).hypot(self.curvature_u_w)
    }
}

/// Each band's dark readings, in time order.
fn series(records: &[CalibrationRecord]) -> BTreeMap<u64, Vec<Dark>> {
    let mut out: BTreeMap<u64, Vec<Dark>> = BTreeMap::new();
    for r in records.iter().filter(|r| r.kind == "dark") {
        let Some(nm) = r.band_nm else { continue };
        if r.t_s.is_finite() && r.value_w.is_finite() && r.u_w.is_finite() {
            out.entry(nm.to_bits()).or_default().push(Dark {
                t_s: r.t_s,
                value_w: r.value_w,
                u_w: r.u_w,
            });
        }
    }
    for list in out.values_mut() {
        list.sort_by(|a, b| a.t_s.total_cmp(&b.t_s));
    }
    out
}

/// The dark of each value (module doc), in their order: `None` for a value whose band has no dark after it,
/// or whose dark is not the band's last one before it (a value not net of a stored dark).
pub fn redark(records: &[CalibrationRecord], values: &[Darkened]) -> Vec<Option<Redarked>> {
    let series = series(records);
    values
        .iter()
        .map(|v| {
            let s = series.get(&v.band_nm.to_bits())?;
            let k1 = s.iter().position(|d| d.t_s > v.t_s)?;
            let k = k1.checked_sub(1)?;
            let (before, after) = (s[k], s[k1]);
            // The value must be net of the dark before it (ties in time go to the dark kept last).
            if v.dark_w.is_some_and(|d| d != before.value_w) {
                return None;
            }
            let x = (v.t_s - before.t_s) / (after.t_s - before.t_s);
            let dark_w = before.value_w + (after.value_w - before.value_w) * x;
            let curvature = super::drift::bracket_curvature(s, k, |d| (d.t_s, d.value_w, d.u_w));
            let curvature_w = curvature * (v.t_s - before.t_s) * (after.t_s - v.t_s) / 2.0;
            dark_w.is_finite().then_some(Redarked {
                used_w: before.value_w,
                used_u_w: before.u_w,
                dark_w,
                readings_u_w: [(k, before.u_w * (1.0 - x)), (k1, after.u_w * x)],
                curvature_u_w: curvature_w.abs(),
            })
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn dark(t_s: f64, value_w: f64) -> CalibrationRecord {
        CalibrationRecord {
            kind: "dark".into(),
            band_nm: Some(550.0),
            t_s,
            value_w,
            u_w: 2e-13,
        }
    }

    fn at(t_s: f64, dark_w: Option<f64>) -> Darkened {
        Darkened {
            band_nm: 550.0,
            t_s,
            dark_w,
            geometry_deg: [30.0, 0.0, 50.0, 0.0],
            incident_w: 1e-3,
        }
    }

    /// Room light on a 30-minute cycle: 2e-11 W, 20 % of it varying.
    fn ambient(t: f64) -> f64 {
        2e-10 + 4e-12 * (std::f64::consts::TAU * t / 1800.0).sin()
    }

    #[test]
    fn a_value_takes_the_dark_interpolated_to_its_time_and_curvature_covers_the_rest() {
        let records: Vec<_> = (0..8)
            .map(|k| dark(60.0 * f64::from(k), ambient(60.0 * f64::from(k))))
            .collect();
        for t in [70.0, 150.0, 239.0, 400.0] {
            let used = records
                .iter()
                .rev()
                .find(|r| r.t_s <= t)
                .map(|r| r.value_w)
                .unwrap_or(0.0);
            let v = at(t, Some(used));
            let r = redark(&records, &[v])[0].expect("between two darks");
            assert_eq!(r.used_w, used);
            let before = (used - ambient(t)).abs();
            let after = (r.dark_w - ambient(t)).abs();
            assert!(before > 1e-13, "{t}: {before}");
            assert!(after < before / 5.0, "{t}: {after} vs {before}");
            // The uncertainty covers what is left and stays near the readings' own.
            assert!(r.u_w() >= after, "{t}: {} vs {after}", r.u_w());
            assert!(r.u_w() < 3e-13, "{t}: {}", r.u_w());
            // The two readings it lies between, by their place in the band's darks, weighted by nearness.
            let k = (t / 60.0).floor() as usize;
            let x = t / 60.0 - k as f64;
            let [(a, ua), (b, ub)] = r.readings_u_w;
            assert_eq!((a, b), (k, k + 1));
            assert!((ua - 2e-13 * (1.0 - x)).abs() < 1e-25 && (ub - 2e-13 * x).abs() < 1e-25);
        }
    }

    #[test]
    fn a_value_after_the_last_dark_or_of_another_dark_is_left_alone() {
        let records = vec![dark(0.0, 1e-10), dark(60.0, 1.1e-10)];
        let late = at(90.0, Some(1.1e-10));
        let other_band = Darkened {
            band_nm: 650.0,
            ..late
        };
        let not_that_dark = at(30.0, Some(0.0));
        assert_eq!(
            redark(&records, &[late, other_band, not_that_dark]),
            vec![None, None, None]
        );
        // Without its dark named, a value takes the band's last before it.
        let r = redark(&records, &[at(30.0, None)])[0].expect("between two darks");
        assert_eq!(r.used_w, 1e-10);
        assert!((r.dark_w - 1.05e-10).abs() < 1e-22, "{}", r.dark_w);
    }
}
