//! The source's drift between references, with hindsight.
//!
//! While a campaign runs, each point is normalised by its band's last normalisation readings carried forward
//! along their straight line (crate::calibration::Normalisations): the only estimate available then. A lamp
//! warming up or wandering does not follow that line: on realistic.toml the points of the first quarter hour
//! came out +0.2 % high, far outside their uncertainty. Once the campaign has completed, the reference after
//! each point is known too: the point is normalised again by the straight line between the readings before and
//! after it ([`renormalise`]), and what a straight line still misses, the drift's curvature, is estimated from
//! the neighbouring readings' second difference and added to the budget as an independent `normalisation`
//! component: `|N''| (t - t_k) (t_k+1 - t) / 2`, linear interpolation's error for a curvature `N''`.
//!
//! The lamp also flickers (`source.flicker_rel` in the instrument file, measured by `gonio selftest`): its power at
//! the moment a value was read stands off the straight line by that much (independent per point), and so does
//! each normalisation reading's, which moves every value interpolated from it together ([`Flicker`]). The
//! second differences the curvature is estimated from hold the flicker too, and are taken net of it.
//!
//! A value after its band's last reading keeps the normalisation it was given while running, carried forward
//! from that reading, and nothing after it says how far the lamp went since: the instrument file bounds its
//! drift rate (`source.drift_per_hour`, which the characterisation measures), so the lamp may have moved by up
//! to that rate times the time since the reading, taken as rectangular (`rate dt / sqrt 3`) and shared, like
//! the reading's own noise, by every value carried from it. Measured by hand while this was built (no test
//! repeats it): on the ideal instrument (seed 4) a sweep run of 12 minutes with no closing reading came out up
//! to 1.1e-4 low at its end, rms z 2.6 over its last sweeps; 1.0 with this.
//!
//! The readings are the campaign's stored calibration records (`direct-beam` or `reference`, net of the band's
//! last dark before them, as the run loop took them).

/// What the lamp does between its readings, as the instrument file states it.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Lamp {
    /// Relative standard uncertainty of the lamp's power at any one moment about its slow course
    /// (`source.flicker_rel`).
    pub flicker_rel: f64,
    /// The most its power drifts, relative, per hour (`source.drift_per_hour`).
    pub drift_per_hour: f64,
}

impl Lamp {
    pub fn of(source: &gonio_instrument::Source) -> Lamp {
        Lamp {
            flicker_rel: source.flicker_rel,
            drift_per_hour: source.drift_per_hour.abs(),
        }
    }

    /// The relative standard uncertainty of its power `dt_s` after a reading with nothing after it (module doc).
    fn carried_rel(&self, dt_s: f64) -> f64 {
        let d = self.drift_per_hour * dt_s.max(0.0) / 3600.0 / 3f64.sqrt();
        if d.is_finite() { d } else { 0.0 }
    }
}

use std::collections::BTreeMap;

use crate::store::{CalibrationRecord, PointRecord};

/// One point's renormalisation.
#[derive(Debug, Clone, PartialEq)]
pub struct Renormalised {
    /// The value's factor: the normalisation used while running over the interpolated one.
    pub factor: f64,
    /// The interpolation's remaining relative standard uncertainty (the drift's curvature).
    pub curvature_rel: f64,
    /// The noise of the normalisation readings the value was interpolated from (the index of each among its
    /// band's readings, in time order), relative, weighted by the interpolation: shared by every value
    /// interpolated from that reading, as their flicker is ([`Flicker::readings_rel`]). After the band's last
    /// reading: that reading's noise and [`Renormalised::carried_rel`] in quadrature.
    pub readings_rel: Vec<(usize, f64)>,
    /// After the band's last reading: the lamp's drift since it (module doc), relative; 0 between readings.
    pub carried_rel: f64,
    pub flicker: Flicker,
}

/// The source's flicker in one value (module doc), relative standard uncertainties.
#[derive(Debug, Clone, PartialEq)]
pub struct Flicker {
    /// At the moment the value was read: independent.
    pub own_rel: f64,
    /// In the normalisation readings it was interpolated from (the index of each among its band's readings, in
    /// time order), weighted by the interpolation: shared by every value interpolated from that reading.
    pub readings_rel: Vec<(usize, f64)>,
}

/// Each band's net normalisation readings (time s, W, its standard uncertainty W: the reading's and its dark's
/// noise), in time order.
fn series(records: &[CalibrationRecord]) -> BTreeMap<u64, Vec<Sample>> {
    let mut darks: BTreeMap<u64, (f64, f64)> = BTreeMap::new();
    let mut out: BTreeMap<u64, Vec<Sample>> = BTreeMap::new();
    let mut ordered: Vec<&CalibrationRecord> = records.iter().collect();
    ordered.sort_by(|a, b| a.t_s.total_cmp(&b.t_s));
    for r in ordered {
        let Some(nm) = r.band_nm else { continue };
        let key = nm.to_bits();
        match r.kind.as_str() {
            "dark" => {
                darks.insert(key, (r.value_w, r.u_w));
            }
            "direct-beam" | "reference" => {
                let (dark_w, dark_u_w) = darks.get(&key).copied().unwrap_or((0.0, 0.0));
                let net = r.value_w - dark_w;
                let u_w = r.u_w.hypot(dark_u_w);
                if net > 0.0 && net.is_finite() && r.t_s.is_finite() && u_w.is_finite() {
                    out.entry(key).or_default().push((r.t_s, net, u_w));
                }
            }
            _ => {}
        }
    }
    out
}

/// A reading for the curvature: time (s), value and its standard uncertainty (W).
pub(super) type Sample = (f64, f64, f64);

/// The second derivative through three readings (W/s^2), net of what the readings' own noise puts in it: the
/// root of its square less the noise's variance (0 when the noise explains it all). A straight drift read
/// with noise has second differences as large as the noise makes them; taken whole, that noise would be
/// counted twice (the readings' uncertainties are already in the interpolation). `None` when two share a time.
fn second_derivative(a: Sample, b: Sample, c: Sample) -> Option<f64> {
    let (d1, d2, span) = (b.0 - a.0, c.0 - b.0, c.0 - a.0);
    if !(d1 > 0.0 && d2 > 0.0) {
        return None;
    }
    let raw = 2.0 * ((c.1 - b.1) / d2 - (b.1 - a.1) / d1) / span;
    let (wa, wb, wc) = (
        2.0 / (d1 * span),
        2.0 * (1.0 / d1 + 1.0 / d2) / span,
        2.0 / (d2 * span),
    );
    let noise = (wa * a.2).powi(2) + (wb * b.2).powi(2) + (wc * c.2).powi(2);
    Some((raw * raw - noise).max(0.0).sqrt())
}

/// The drift's curvature about the readings `s[k]` and `s[k + 1]` (`at`: a reading's time s, value and
/// uncertainty W): the larger second derivative's magnitude through them and the reading before or after
/// (W/s^2), net of the readings' noise, 0 without either. What a straight line between the two misses (the
/// source's drift here, the dark's in super::dark).
pub(super) fn bracket_curvature<T>(s: &[T], k: usize, at: impl Fn(&T) -> Sample) -> f64 {
    let (Some(a), Some(b)) = (s.get(k).map(&at), s.get(k + 1).map(&at)) else {
        return 0.0;
    };
    [
        k.checked_sub(1).and_then(|j| second_derivative(at(&s[j]), a, b)),
        s.get(k + 2).and_then(|c| second_derivative(a, b, at(c))),
    ]
    .into_iter()
    .flatten()
    .fold(0.0f64, f64::max)
}

/// What the renormalisation needs of a value: its band, whether it has a value, the normalisation it was
/// divided by while running (W) and its time (s).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Normalised {
    pub band_nm: f64,
    pub has_value: bool,
    pub incident_w: f64,
    pub t_s: f64,
}

impl From<&PointRecord> for Normalised {
    fn from(p: &PointRecord) -> Normalised {
        Normalised {
            band_nm: p.band_nm,
            has_value: p.brdf_sr.is_some_and(f64::is_finite),
            incident_w: p.incident_w,
            t_s: p.t_s,
        }
    }
}

/// The renormalisation of each point (module doc), in the points' order: `None` for a point that keeps its
/// value (no reading after it, no normalisation, no value).
pub fn renormalise(
    records: &[CalibrationRecord],
    points: &[PointRecord],
    lamp: Lamp,
) -> Vec<Option<Renormalised>> {
    let values: Vec<Normalised> = points.iter().map(Normalised::from).collect();
    renormalise_values(records, &values, lamp)
}

/// [`renormalise`] of values of any kind (points, sweep readings).
pub fn renormalise_values(
    records: &[CalibrationRecord],
    values: &[Normalised],
    lamp: Lamp,
) -> Vec<Option<Renormalised>> {
    let flicker_rel = lamp.flicker_rel;
    let series = series(records);
    values
        .iter()
        .map(|p| {
            let s = series.get(&p.band_nm.to_bits())?;
            if !p.has_value {
                return None;
            }
            if !(p.incident_w > 0.0 && p.incident_w.is_finite()) {
                return None;
            }
            // The readings around the point: k at or before it, k + 1 after it.
            let Some(k1) = s.iter().position(|(t, _, _)| *t > p.t_s) else {
                // After the band's last reading the value keeps the normalisation it was given while running,
                // carried forward from the last reading (its weight taken as one), and the lamp's drift since
                // (module doc).
                let last = s.len().checked_sub(1)?;
                let (t, n, u) = s[last];
                let carried_rel = lamp.carried_rel(p.t_s - t);
                return Some(Renormalised {
                    factor: 1.0,
                    curvature_rel: 0.0,
                    readings_rel: vec![(last, (u / n).hypot(carried_rel))],
                    carried_rel,
                    flicker: Flicker {
                        own_rel: flicker_rel,
                        readings_rel: vec![(last, flicker_rel)],
                    },
                });
            };
            let k = k1.checked_sub(1)?;
            let ((t0, n0, u0), (t1, n1, u1)) = (s[k], s[k1]);
            let x = (p.t_s - t0) / (t1 - t0);
            let interpolated = n0 + (n1 - n0) * x;
            if !(interpolated > 0.0 && interpolated.is_finite()) {
                return None;
            }
            // The readings' flicker is in their second differences too: not curvature.
            let curvature = bracket_curvature(s, k, |&(t, v, u)| (t, v, u.hypot(flicker_rel * v)));
            Some(Renormalised {
                factor: p.incident_w / interpolated,
                curvature_rel: curvature * (p.t_s - t0) * (t1 - p.t_s) / 2.0 / interpolated,
                readings_rel: vec![(k, u0 * (1.0 - x) / interpolated), (k1, u1 * x / interpolated)],
                carried_rel: 0.0,
                flicker: Flicker {
                    own_rel: flicker_rel,
                    readings_rel: vec![
                        (k, flicker_rel * n0 * (1.0 - x) / interpolated),
                        (k1, flicker_rel * n1 * x / interpolated),
                    ],
                },
            })
        })
        .collect()
}

#[cfg(test)]
pub(super) mod tests {
    use super::*;

    /// A lamp that flickers by `flicker_rel` and does not drift.
    fn flicker(flicker_rel: f64) -> Lamp {
        Lamp {
            flicker_rel,
            drift_per_hour: 0.0,
        }
    }

    fn record(kind: &str, t_s: f64, value_w: f64) -> CalibrationRecord {
        CalibrationRecord {
            kind: kind.into(),
            band_nm: Some(550.0),
            t_s,
            value_w,
            u_w: 0.0,
        }
    }

    /// A point with a value at `t_s` in `band_nm`, no read-back: the budget's tests build theirs from it.
    pub(in crate::budget) fn point_at(t_s: f64, band_nm: f64) -> PointRecord {
        PointRecord {
            index: 0,
            band_nm,
            theta_i_deg: 30.0,
            phi_i_deg: 0.0,
            theta_o_deg: 30.0,
            phi_o_deg: 180.0,
            signal_w: 1e-7,
            dark_w: 0.0,
            incident_w: 1e-3,
            brdf_sr: Some(0.1),
            brdf_u_sr: Some(1e-4),
            flags: Vec::new(),
            t_s,
            readback_deg: Vec::new(),
            truth_point_sr: None,
            truth_aperture_sr: None,
            truth_effects_json: None,
            brdf_aperture_sr: None,
            budget: Default::default(),
        }
    }

    #[test]
    fn a_point_is_renormalised_between_the_readings_around_it_and_curvature_is_in_its_budget() {
        // A source warming up: 1 - 0.01 exp(-t / 900 s), read every 600 s with a dark of 1e-6 W.
        let source = |t: f64| 1e-3 * (1.0 - 0.01 * (-t / 900.0).exp()) + 1e-6;
        let mut records = vec![record("dark", 0.0, 1e-6)];
        for k in 0..5 {
            let t = 600.0 * f64::from(k);
            records.push(record("direct-beam", t + 1.0, source(t + 1.0)));
        }
        let truth = |t: f64| source(t) - 1e-6;
        // A point at 900 s, normalised while running by the line through the readings at 1 s and 601 s.
        let extrapolated = {
            let (a, b) = (truth(1.0), truth(601.0));
            b + (b - a) * (900.0 - 601.0) / 600.0
        };
        let mut p = point_at(900.0, 550.0);
        p.incident_w = extrapolated;
        let r = renormalise(&records, &[p], flicker(0.0));
        let r = r[0].clone().expect("renormalised");
        // The value times `factor` is normalised by the interpolation, which is far closer to the truth.
        let interpolated = extrapolated / r.factor;
        let before = (extrapolated / truth(900.0) - 1.0).abs();
        let after = (interpolated / truth(900.0) - 1.0).abs();
        assert!(before > 5e-4, "{before}");
        assert!(after < before / 4.0, "{after} vs {before}");
        // The curvature term covers what is left, and is not wildly larger.
        assert!(r.curvature_rel >= after, "{} vs {after}", r.curvature_rel);
        assert!(r.curvature_rel < 5.0 * after, "{} vs {after}", r.curvature_rel);
    }

    #[test]
    fn curvature_is_what_the_second_difference_has_beyond_the_readings_noise() {
        // Readings every 600 s with a standard uncertainty of 1e-7 W each: the second difference's noise is
        // 2 sqrt(6) 1e-7 / (600 * 1200) W/s^2 for evenly spaced readings.
        let u = 1e-7;
        let noise = 2.0 * 6f64.sqrt() * u / (600.0 * 1200.0);
        let at = |values: [f64; 3]| {
            let s: Vec<Sample> = values
                .iter()
                .enumerate()
                .map(|(k, v)| (600.0 * k as f64, *v, u))
                .collect();
            bracket_curvature(&s, 0, |&r| r)
        };
        // A straight drift read with noise as large as the readings' uncertainty: no curvature is claimed.
        assert_eq!(at([1e-3, 1e-3 + 1e-7, 1e-3]), 0.0);
        // A real bend ten times the noise: what is left of it is the bend, within the noise's share.
        let bend = 10.0 * noise;
        let second = bend * 600.0 * 1200.0 / 2.0;
        let c = at([1e-3, 1e-3 - second / 2.0, 1e-3]);
        assert!((c - bend).abs() < 0.01 * bend, "{c} vs {bend}");
        // Without uncertainties the second difference is taken whole.
        let s = [(0.0, 1e-3, 0.0), (600.0, 1e-3 + 1e-7, 0.0), (1200.0, 1e-3, 0.0)];
        let whole = bracket_curvature(&s, 0, |&r| r);
        assert!((whole - 2.0 * 2e-7 / (600.0 * 1200.0)).abs() < 1e-20, "{whole}");
    }

    #[test]
    fn a_point_after_the_last_reading_keeps_its_value_and_the_last_readings_flicker() {
        let records = vec![
            record("direct-beam", 0.0, 1e-3),
            record("direct-beam", 600.0, 1e-3),
        ];
        let mut p = point_at(700.0, 550.0);
        p.incident_w = 1e-3;
        let r = renormalise(&records, &[p], flicker(2e-4))[0]
            .clone()
            .expect("the flicker");
        assert_eq!((r.factor, r.curvature_rel), (1.0, 0.0));
        assert_eq!(r.readings_rel, vec![(1, 0.0)], "readings without noise");
        assert_eq!(r.flicker.own_rel, 2e-4);
        assert_eq!(r.flicker.readings_rel, vec![(1, 2e-4)]);
    }

    #[test]
    fn the_flicker_is_the_points_own_and_its_readings_by_nearness() {
        let records: Vec<CalibrationRecord> = (0..3)
            .map(|k| record("direct-beam", 600.0 * f64::from(k), 1e-3))
            .collect();
        let mut p = point_at(750.0, 550.0);
        p.incident_w = 1e-3;
        let r = renormalise(&records, &[p.clone()], flicker(2e-4))[0]
            .clone()
            .expect("renormalised");
        assert_eq!(r.flicker.own_rel, 2e-4);
        // A quarter of the way from the reading at 600 s to the one at 1200 s.
        let [(a, wa), (b, wb)] = r.flicker.readings_rel[..] else {
            panic!("two readings: {:?}", r.flicker.readings_rel)
        };
        assert_eq!((a, b), (1, 2));
        assert!(
            (wa - 1.5e-4).abs() < 1e-12 && (wb - 0.5e-4).abs() < 1e-12,
            "{wa} {wb}"
        );
        // Without flicker in the file, none in the budget, and the same factor.
        let plain = renormalise(&records, &[p], flicker(0.0))[0]
            .clone()
            .expect("renormalised");
        assert_eq!(plain.factor, r.factor);
        assert_eq!(plain.flicker.own_rel, 0.0);
        assert!(plain.flicker.readings_rel.iter().all(|(_, w)| *w == 0.0));
    }

    #[test]
    fn the_readings_noise_is_shared_by_nearness() {
        // Readings of 1e-3 W every 600 s, each known to 3e-8 W (3e-5 of it), and a dark before them.
        let mut records = vec![record("dark", 0.0, 0.0)];
        records.extend((0..3).map(|k| CalibrationRecord {
            u_w: 3e-8,
            ..record("direct-beam", 1.0 + 600.0 * f64::from(k), 1e-3)
        }));
        let mut p = point_at(751.0, 550.0);
        p.incident_w = 1e-3;
        let r = renormalise(&records, &[p], flicker(0.0))[0]
            .clone()
            .expect("renormalised");
        let [(a, wa), (b, wb)] = r.readings_rel[..] else {
            panic!("two readings: {:?}", r.readings_rel)
        };
        assert_eq!((a, b), (1, 2));
        assert!(
            (wa - 0.75 * 3e-5).abs() < 1e-12 && (wb - 0.25 * 3e-5).abs() < 1e-12,
            "{wa} {wb}"
        );
    }

    #[test]
    fn a_value_after_the_last_reading_carries_the_lamp_s_drift_since() {
        // One reading of 1e-3 W known to 3e-8 W (3e-5 of it) at 1 s; a lamp whose file bounds its drift at
        // 0.2 % an hour. A value 1 s after the reading carries little more than the reading's noise; one 30
        // minutes later up to 1e-3 of drift, 1e-3 / sqrt 3 as a standard uncertainty, shared with the reading.
        let records = vec![
            record("dark", 0.0, 0.0),
            CalibrationRecord {
                u_w: 3e-8,
                ..record("direct-beam", 1.0, 1e-3)
            },
        ];
        let lamp = Lamp {
            flicker_rel: 0.0,
            drift_per_hour: 2e-3,
        };
        let at = |t: f64| {
            let mut p = point_at(t, 550.0);
            p.incident_w = 1e-3;
            renormalise(&records, &[p], lamp)[0].clone().expect("carried")
        };
        let soon = at(2.0);
        assert_eq!(soon.factor, 1.0);
        let [(k, w)] = soon.readings_rel[..] else {
            panic!("one reading: {:?}", soon.readings_rel)
        };
        assert_eq!(k, 0);
        assert!((w - 3e-5).abs() < 1e-8, "{w}");
        let late = at(1801.0);
        let [(_, w)] = late.readings_rel[..] else {
            panic!("one reading: {:?}", late.readings_rel)
        };
        let drift = 1e-3 / 3f64.sqrt();
        assert!((w - drift.hypot(3e-5)).abs() < 1e-12, "{w}");
        assert!((late.carried_rel - drift).abs() < 1e-15);
        // A lamp the file says does not drift: the reading's noise alone, however late.
        let steady = renormalise(
            &records,
            &[{
                let mut p = point_at(1801.0, 550.0);
                p.incident_w = 1e-3;
                p
            }],
            flicker(0.0),
        )[0]
        .clone()
        .expect("carried");
        assert!((steady.readings_rel[0].1 - 3e-5).abs() < 1e-12);
    }

    #[test]
    fn flicker_in_the_readings_is_not_taken_for_curvature() {
        // Readings of a steady lamp that flickers by 2e-4: the second difference is that flicker's, not a bend.
        let values = [1e-3, 1e-3 * (1.0 + 1e-4), 1e-3 * (1.0 - 1e-4), 1e-3];
        let records: Vec<CalibrationRecord> = values
            .iter()
            .enumerate()
            .map(|(k, v)| record("direct-beam", 600.0 * k as f64, *v))
            .collect();
        let mut p = point_at(900.0, 550.0);
        p.incident_w = 1e-3;
        let blind = renormalise(&records, &[p.clone()], flicker(0.0))[0]
            .clone()
            .expect("renormalised");
        let told = renormalise(&records, &[p], flicker(2e-4))[0]
            .clone()
            .expect("renormalised");
        // Blind to it: (3e-4 of 1e-3 W over (600 s)^2) x 300 s x 300 s / 2 = 3.75e-5 of the value.
        assert!(
            (blind.curvature_rel - 3.75e-5).abs() < 1e-9,
            "{}",
            blind.curvature_rel
        );
        assert_eq!(told.curvature_rel, 0.0);
    }
}
