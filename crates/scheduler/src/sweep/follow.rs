//! Speed that follows the BRDF (issue 41): fast where the BRDF is smooth, slow where it bends.
//!
//! A sweep reading integrates the BRDF along the arc the arm travels during the reading's integration time `T`:
//! at speed `v` that arc is `L = v T` long, and the reading, attributed to the arc's middle, differs from the
//! BRDF there by `f'' L^2 / 24` to leading order (the mean of a parabola over an interval against its value at
//! the middle). For a relative smearing tolerance `eps`, the fastest speed at angle `s` is therefore
//! `v(s) = sqrt(24 eps f(s) / |f''(s)|) / T`, held between the request's top speed and a floor; each speed is
//! sized for [`SMEARING_MARGIN`] of the tolerance.
//!
//! [`speed_profile`] turns samples of the BRDF along an arc (from a first pass at the top speed, or from a
//! model) into pieces of constant speed: each sample's speed is the slowest any reading near it needs (the
//! curvature's largest magnitude within half a reading's arc around it, the arc at that speed); each piece is
//! swept at the slowest speed any of its samples allows, and the arc is cut where the pieces sweep it soonest
//! (dynamic programming over the cuts between samples), each piece costing its motion with its ramps and the
//! exchanges around it, none shorter than `min_piece_deg`. Each piece carries the largest smearing predicted for
//! its readings.
//! [`profile_time_s`] is the time to sweep the pieces one after the other, each a move of its own.

/// A stretch of an arc swept at one speed.
#[derive(Debug, Clone, Copy, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct FollowPiece {
    /// The stretch, in the arc's signed degrees (`from_deg < to_deg`).
    pub from_deg: f64,
    pub to_deg: f64,
    pub speed_deg_s: f64,
    /// The largest relative smearing predicted for a reading in the piece (`|f''| (v T)^2 / (24 f)`, with the
    /// arc's peak for `f` when the tolerance is relative to it).
    pub smearing_rel: f64,
}

/// What a profile is asked for.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FollowRequest {
    /// The meter's integration time per reading (s): `averaging` x the detector's sample time.
    pub integration_s: f64,
    /// The largest relative smearing allowed per reading.
    pub tolerance_rel: f64,
    /// The request's speed, used where the BRDF is smooth (deg/s).
    pub top_speed_deg_s: f64,
    /// The slowest speed used (deg/s); where even it smears more than the tolerance, the piece says by how much.
    pub min_speed_deg_s: f64,
    /// The shortest piece (deg): a piece is a move of its own, with its ramps.
    pub min_piece_deg: f64,
    /// What the tolerance is relative to: each reading's own value, or the largest value along the arc (in the
    /// same band): the smearing of a reading is then held within `tolerance_rel x` the arc's peak, which lets
    /// the low tails of a lobe go fast.
    pub relative_to: RelativeTo,
    /// The swept axis's acceleration (deg/s^2) and what each piece costs besides its motion (s: its speed set
    /// and restored, its start and stop seen, what it waits for after its motion): what the cut into pieces weighs
    /// against sweeping a stretch slower than it needs.
    pub accel_deg_s2: f64,
    pub per_piece_s: f64,
}

/// What a smearing tolerance is relative to (`relative_to` in `follow = { ... }`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, serde::Serialize, serde::Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum RelativeTo {
    /// Each reading's own value: every reading within the tolerance of itself.
    #[default]
    Reading,
    /// The largest value along the arc: the smearing of every reading within the tolerance of the peak.
    Peak,
}

use crate::timing::trapezoid_time_s;

/// The share of the tolerance each piece's speed is sized for. The bend comes from a first pass's readings,
/// binned and through their noise, and `f'' L^2 / 24` is the smearing's leading order only: sized for the whole
/// tolerance, following smeared up to 5 % over it on the bench's gold and plastic (BENCHMARKS.md section 7).
/// Sized for 80 %, the largest smearing on the sixteen rows there was 0.78 to 0.85 of the tolerance (6.3 %
/// over the share at most: gold, ideal, 2e-5 of the peak), the time given up to the margin 3 to 6 %; at 90 %,
/// 0.88 to 0.95 of it, each row's time 2.5 to 5.6 % shorter. Twice the largest overshoot seen is still left.
pub const SMEARING_MARGIN: f64 = 0.9;

/// The pieces of constant speed for an arc whose BRDF is sampled at `samples` ((signed angle in degrees,
/// value) on a uniform, increasing grid of at least three points; values positive). Empty when the samples
/// cannot make a profile (fewer than three, not increasing, a value not positive and finite, a request not
/// positive).
pub fn speed_profile(samples: &[(f64, f64)], req: &FollowRequest) -> Vec<FollowPiece> {
    speed_profile_curves(std::slice::from_ref(&samples.to_vec()), req)
}

/// As [`speed_profile`] for several curves on one grid (the bands of one arc): each sample's speed is the
/// slowest any curve needs there. Empty when the curves do not share their grid.
pub fn speed_profile_curves(curves: &[Vec<(f64, f64)>], req: &FollowRequest) -> Vec<FollowPiece> {
    let Some(samples) = curves.first() else {
        return Vec::new();
    };
    let ok = samples.len() >= 3
        && samples.windows(2).all(|w| w[1].0 > w[0].0)
        && curves.iter().all(|c| {
            c.len() == samples.len()
                && c.iter().zip(samples).all(|(a, b)| a.0 == b.0)
                && c.iter().all(|(s, f)| s.is_finite() && f.is_finite() && *f > 0.0)
        })
        && [
            req.integration_s,
            req.tolerance_rel,
            req.top_speed_deg_s,
            req.min_speed_deg_s,
        ]
        .iter()
        .all(|x| x.is_finite() && *x > 0.0)
        && req.min_speed_deg_s <= req.top_speed_deg_s
        && req.min_piece_deg.is_finite();
    if !ok {
        return Vec::new();
    }
    let n = samples.len();
    let h = (samples[n - 1].0 - samples[0].0) / (n - 1) as f64;
    // |f''| / f at each sample (per degree squared), or |f''| over the curve's peak, the ends taking their
    // neighbours', the largest over the curves.
    let scales: Vec<Option<f64>> = curves
        .iter()
        .map(|c| match req.relative_to {
            RelativeTo::Reading => None,
            RelativeTo::Peak => Some(c.iter().map(|p| p.1).fold(0.0, f64::max)),
        })
        .collect();
    let bend: Vec<f64> = (0..n)
        .map(|i| {
            let i = i.clamp(1, n - 2);
            curves
                .iter()
                .zip(&scales)
                .map(|(c, peak)| {
                    let (a, b, d) = (c[i - 1].1, c[i].1, c[i + 1].1);
                    ((a - 2.0 * b + d) / (h * h)).abs() / peak.unwrap_or(b)
                })
                .fold(0.0, f64::max)
        })
        .collect();
    // A reading at speed v spans v T of arc: the one over a sample smears with the worst bend within half that
    // around it (and the next sample: the bend's stencil), `reach(v)` samples either side. The window of each
    // sample is its own speed's: at a lobe's peak a reading at the slow speed there spans a tenth of a degree,
    // and the bend a degree away (the window at the top speed) is not its business. `widest[k][i]`: the worst
    // bend within k samples of i, for k up to the top speed's reach.
    let reach = |v: f64| ((v * req.integration_s / 2.0) / h).ceil() as usize + 1;
    let top_reach = reach(req.top_speed_deg_s);
    let mut widest: Vec<Vec<f64>> = vec![bend.clone()];
    for k in 1..=top_reach {
        let prev = &widest[k - 1];
        let next: Vec<f64> = (0..n)
            .map(|i| {
                let below = i.checked_sub(k).map_or(0.0, |j| bend[j]);
                let above = bend.get(i + k).copied().unwrap_or(0.0);
                prev[i].max(below).max(above)
            })
            .collect();
        widest.push(next);
    }
    let smearing = |v: f64, bend: f64| bend * (v * req.integration_s).powi(2) / 24.0;
    // The fastest speed each sample allows, between the floor and the top speed: the fastest over the windows
    // k of a speed whose reach is at most k and that the worst bend within k allows.
    let allowed = |b: f64| {
        if b <= 0.0 {
            f64::INFINITY
        } else {
            (24.0 * SMEARING_MARGIN * req.tolerance_rel / b).sqrt() / req.integration_s
        }
    };
    let need: Vec<f64> = (0..n)
        .map(|i| {
            let v = (1..=top_reach)
                .map(|k| {
                    let within = if k == top_reach {
                        req.top_speed_deg_s
                    } else {
                        2.0 * (k - 1) as f64 * h / req.integration_s
                    };
                    allowed(widest[k][i]).min(within)
                })
                .fold(0.0, f64::max);
            v.clamp(req.min_speed_deg_s, req.top_speed_deg_s)
        })
        .collect();
    // Each sample's worst bend: within its own speed's reach (what its piece's smearing is predicted from).
    let bend: Vec<f64> = (0..n).map(|i| widest[reach(need[i]).min(top_reach)][i]).collect();
    // The cut into pieces that sweeps the arc soonest, by dynamic programming over the cuts between samples: a
    // piece of samples a..=b runs at the slowest speed any of them allows, and costs its motion (a trapezoid:
    // its ramps) and `per_piece_s` (its exchanges); no piece is shorter than `min_piece_deg` unless the arc is.
    // Cutting only ever lets a stretch go faster than its slowest sample, never faster than its own samples
    // allow, so every reading stays within the tolerance whatever the cut.
    let from_of = |a: usize| {
        if a == 0 {
            samples[0].0
        } else {
            samples[a].0 - h / 2.0
        }
    };
    let to_of = |b: usize| {
        if b == n - 1 {
            samples[n - 1].0
        } else {
            samples[b].0 + h / 2.0
        }
    };
    let ramps = req.accel_deg_s2 > 0.0 && req.accel_deg_s2.is_finite();
    let piece_s = |length: f64, v: f64| {
        let motion = if ramps {
            trapezoid_time_s(length, v, req.accel_deg_s2)
        } else {
            length / v
        };
        motion + req.per_piece_s.max(0.0)
    };
    let whole = samples[n - 1].0 - samples[0].0;
    // best[b + 1]: the least time to sweep samples 0..=b, with the first sample of its last piece.
    let mut best: Vec<(f64, usize)> = vec![(f64::INFINITY, 0); n + 1];
    best[0] = (0.0, 0);
    for b in 0..n {
        let mut slowest = f64::INFINITY;
        for a in (0..=b).rev() {
            slowest = slowest.min(need[a]);
            let length = to_of(b) - from_of(a);
            let allowed = length >= req.min_piece_deg || (a == 0 && b == n - 1) || whole < req.min_piece_deg;
            if !allowed || !best[a].0.is_finite() {
                continue;
            }
            let t = best[a].0 + piece_s(length, slowest);
            if t < best[b + 1].0 {
                best[b + 1] = (t, a);
            }
        }
    }
    // The pieces as (first sample, last sample), from the end back; one piece when no cut meets the shortest.
    let mut runs: Vec<(usize, usize)> = Vec::new();
    let mut b = n;
    while b > 0 && best[b].0.is_finite() {
        let a = best[b].1;
        runs.push((a, b - 1));
        b = a;
    }
    if b > 0 || runs.is_empty() {
        runs = vec![(0, n - 1)];
    }
    runs.reverse();
    let speed = |r: &(usize, usize)| need[r.0..=r.1].iter().copied().fold(f64::INFINITY, f64::min);
    runs.iter()
        .map(|r| {
            let (a, b) = (r.0, r.1);
            let v = speed(r);
            let worst = bend[a..=b].iter().copied().fold(0.0, f64::max);
            FollowPiece {
                // Pieces meet half-way between their samples; the arc's ends are its first and last samples.
                from_deg: from_of(a),
                to_deg: to_of(b),
                speed_deg_s: v,
                smearing_rel: smearing(v, worst),
            }
        })
        .collect()
}

/// The time to sweep `pieces` one after the other (s), each a move of its own from rest to rest at its speed
/// with acceleration `accel_deg_s2` (a trapezoid, or a triangle when the piece is too short to cruise), plus
/// `per_piece_s` for the exchanges that set its speed and start it.
pub fn profile_time_s(pieces: &[FollowPiece], accel_deg_s2: f64, per_piece_s: f64) -> f64 {
    pieces
        .iter()
        .map(|p| trapezoid_time_s(p.to_deg - p.from_deg, p.speed_deg_s, accel_deg_s2) + per_piece_s)
        .sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn request() -> FollowRequest {
        FollowRequest {
            // Ten meter samples a reading.
            integration_s: 3e-2,
            tolerance_rel: 1e-3,
            top_speed_deg_s: 20.0,
            min_speed_deg_s: 0.05,
            min_piece_deg: 1.0,
            relative_to: RelativeTo::Reading,
            accel_deg_s2: 80.0,
            per_piece_s: 0.0,
        }
    }

    fn sampled(f: impl Fn(f64) -> f64, from: f64, to: f64, h: f64) -> Vec<(f64, f64)> {
        let n = ((to - from) / h).round() as usize;
        (0..=n)
            .map(|i| {
                let s = from + i as f64 * h;
                (s, f(s))
            })
            .collect()
    }

    /// A gloss lobe a degree wide on a diffuse floor 50 times lower.
    fn lobe(s: f64) -> f64 {
        1.0 + 50.0 * (-s * s).exp()
    }

    /// The reading a sweep at `v` takes around `s`: the mean of `f` over the arc travelled, by Simpson's rule
    /// on 200 intervals (independent of the profile's finite differences).
    fn reading(f: &impl Fn(f64) -> f64, s: f64, v: f64, t: f64) -> f64 {
        let l = v * t;
        let n = 200;
        let h = l / n as f64;
        let mut sum = f(s - l / 2.0) + f(s + l / 2.0);
        for i in 1..n {
            let x = s - l / 2.0 + i as f64 * h;
            sum += if i % 2 == 1 { 4.0 } else { 2.0 } * f(x);
        }
        sum * h / 3.0 / l
    }

    #[test]
    fn a_smooth_brdf_is_swept_whole_at_the_top_speed() {
        let pieces = speed_profile(&sampled(|s| 2.0 + 0.01 * s, -80.0, 80.0, 0.1), &request());
        assert_eq!(pieces.len(), 1);
        assert_eq!(pieces[0].speed_deg_s, 20.0);
        assert!((pieces[0].from_deg + 80.0).abs() < 1e-9 && (pieces[0].to_deg - 80.0).abs() < 1e-9);
        assert!(pieces[0].smearing_rel < 1e-9);
    }

    #[test]
    fn a_sample_near_a_narrow_lobe_is_held_to_the_bend_its_own_readings_cross() {
        // A lobe 0.3 deg wide, readings 90 ms long: 1.8 deg of arc at the top speed, the tolerance relative to
        // the peak. A reading over the lobe's shoulder at the shoulder's speed spans a fraction of that, short
        // of the peak's bend: the shoulder goes several times faster than the peak (the window of the top speed
        // held it to the peak's speed).
        let narrow = |s: f64| 1.0 + 50.0 * (-(s / 0.3).powi(2)).exp();
        let req = FollowRequest {
            integration_s: 0.09,
            tolerance_rel: 1e-4,
            min_piece_deg: 0.0,
            relative_to: RelativeTo::Peak,
            ..request()
        };
        let pieces = speed_profile(&sampled(narrow, -10.0, 10.0, 0.01), &req);
        let at = |s: f64| pieces.iter().find(|p| p.from_deg <= s && s <= p.to_deg).unwrap();
        let peak = at(0.0).speed_deg_s;
        assert!(at(0.8).speed_deg_s > 3.0 * peak, "{pieces:#?}");
        for p in &pieces {
            let mut s = p.from_deg;
            while s <= p.to_deg {
                let r = reading(&narrow, s, p.speed_deg_s, req.integration_s);
                let e = (r - narrow(s)).abs() / narrow(0.0);
                assert!(e <= 1.2 * req.tolerance_rel, "at {s}: {e:.2e} in {p:?}");
                s += 0.005;
            }
        }
    }

    #[test]
    fn every_reading_of_a_lobe_smears_within_the_tolerance() {
        let req = request();
        let pieces = speed_profile(&sampled(lobe, -80.0, 80.0, 0.05), &req);
        assert!(pieces.len() >= 3, "{pieces:?}");
        // Contiguous, covering the arc, slower near the lobe than away from it.
        assert!((pieces[0].from_deg + 80.0).abs() < 1e-9);
        assert!((pieces.last().unwrap().to_deg - 80.0).abs() < 1e-9);
        for w in pieces.windows(2) {
            assert!((w[0].to_deg - w[1].from_deg).abs() < 1e-9, "{w:?}");
        }
        let at = |s: f64| pieces.iter().find(|p| p.from_deg <= s && s <= p.to_deg).unwrap();
        assert!(at(0.0).speed_deg_s < at(40.0).speed_deg_s / 4.0);
        assert_eq!(at(40.0).speed_deg_s, req.top_speed_deg_s);
        // The smearing of each reading, by integration, within the tolerance (1.2 x: the leading order).
        for p in &pieces {
            // A piece at the speed that just meets the tolerance smears it, to rounding.
            assert!(
                p.smearing_rel <= SMEARING_MARGIN * req.tolerance_rel * (1.0 + 1e-12),
                "{p:?}"
            );
            let mut s = p.from_deg;
            while s <= p.to_deg {
                let r = reading(&lobe, s, p.speed_deg_s, req.integration_s);
                let e = (r / lobe(s) - 1.0).abs();
                assert!(e <= 1.2 * req.tolerance_rel, "at {s}: {e:.2e} in {p:?}");
                s += 0.01;
            }
        }
    }

    #[test]
    fn following_the_lobe_takes_a_fraction_of_the_constant_speed_that_meets_the_same_tolerance() {
        let req = request();
        let pieces = speed_profile(&sampled(lobe, -80.0, 80.0, 0.05), &req);
        let slowest = pieces.iter().map(|p| p.speed_deg_s).fold(f64::INFINITY, f64::min);
        let constant = [FollowPiece {
            from_deg: -80.0,
            to_deg: 80.0,
            speed_deg_s: slowest,
            smearing_rel: 0.0,
        }];
        let (a, overhead) = (80.0, 0.05);
        let followed = profile_time_s(&pieces, a, overhead);
        let steady = profile_time_s(&constant, a, overhead);
        eprintln!(
            "{} pieces, slowest {slowest:.2} deg/s: followed {followed:.1} s, constant {steady:.1} s",
            pieces.len()
        );
        assert!(
            followed < steady / 3.0,
            "followed {followed:.1} s, constant {steady:.1} s"
        );
        // The time of a piece: cruise plus one ramp's worth (v / a), or a triangle when it cannot cruise.
        let one = FollowPiece {
            from_deg: 0.0,
            to_deg: 10.0,
            speed_deg_s: 5.0,
            smearing_rel: 0.0,
        };
        assert!((profile_time_s(&[one], 80.0, 0.0) - (2.0 + 5.0 / 80.0)).abs() < 1e-12);
        let short = FollowPiece { to_deg: 0.1, ..one };
        assert!((profile_time_s(&[short], 80.0, 0.0) - 2.0 * (0.1f64 / 80.0).sqrt()).abs() < 1e-12);
    }

    #[test]
    fn a_tolerance_relative_to_the_peak_lets_the_tails_go_fast_and_holds_every_reading_to_the_peak() {
        // A lobe whose Gaussian tails bend more and more relative to themselves.
        let glossy = |s: f64| 1e-3 + 50.0 * (-(s / 3.0).powi(2)).exp();
        let samples = sampled(glossy, -40.0, 40.0, 0.05);
        let req = request();
        let own = speed_profile(&samples, &req);
        let peak_req = FollowRequest {
            relative_to: RelativeTo::Peak,
            ..req
        };
        let peak = speed_profile(&samples, &peak_req);
        let time = |p: &[FollowPiece]| profile_time_s(p, 80.0, 0.3);
        let at = |p: &[FollowPiece], s: f64| {
            p.iter()
                .find(|q| q.from_deg <= s && s <= q.to_deg)
                .unwrap()
                .speed_deg_s
        };
        // The tails (8 deg out: the lobe 1e-3 of its peak) slow down relative to themselves, not to the peak.
        assert!(at(&own, 8.0) < req.top_speed_deg_s / 4.0, "{own:?}");
        assert_eq!(at(&peak, 8.0), req.top_speed_deg_s, "{peak:?}");
        assert!(
            time(&peak) < 0.6 * time(&own),
            "{} against {}",
            time(&peak),
            time(&own)
        );
        // Each reading's smearing, by integration, within the tolerance of the peak (1.2 x: leading order).
        for p in &peak {
            let mut s = p.from_deg;
            while s <= p.to_deg {
                let r = reading(&glossy, s, p.speed_deg_s, req.integration_s);
                let e = (r - glossy(s)).abs() / 50.001;
                assert!(e <= 1.2 * req.tolerance_rel, "at {s}: {e:.2e} in {p:?}");
                s += 0.01;
            }
        }
    }

    #[test]
    fn the_cut_into_pieces_is_the_fastest_of_every_cut_and_no_piece_is_faster_than_its_samples_allow() {
        // Thirteen samples across a lobe: every cut between them (4,096) tried by hand.
        let samples = sampled(|s| 1.0 + 50.0 * (-s * s / 4.0).exp(), -3.0, 3.0, 0.5);
        let n = samples.len();
        let h = 0.5;
        // Each sample's own speed: the profile when a piece costs nothing (no exchanges, no ramps, no shortest).
        let free = FollowRequest {
            min_piece_deg: 0.0,
            accel_deg_s2: f64::INFINITY,
            ..request()
        };
        let fine = speed_profile(&samples, &free);
        let need: Vec<f64> = samples
            .iter()
            .map(|(s, _)| {
                fine.iter()
                    .find(|p| p.from_deg - 1e-9 <= *s && *s <= p.to_deg + 1e-9)
                    .map(|p| p.speed_deg_s)
                    .expect("every sample in a piece")
            })
            .collect();
        assert!(fine.len() >= 3, "{fine:?}");
        let costly = FollowRequest {
            per_piece_s: 0.2,
            min_piece_deg: 1.0,
            ..request()
        };
        let cut = speed_profile(&samples, &costly);
        let cut_s = profile_time_s(&cut, costly.accel_deg_s2, costly.per_piece_s);
        let edge = |k: usize| {
            if k == 0 {
                samples[0].0
            } else if k == n {
                samples[n - 1].0
            } else {
                samples[k].0 - h / 2.0
            }
        };
        let mut fastest = f64::INFINITY;
        for mask in 0u32..(1 << (n - 1)) {
            // Bit i: a cut between samples i and i + 1.
            let mut bounds = vec![0];
            bounds.extend((0..n - 1).filter(|i| mask & (1 << i) != 0).map(|i| i + 1));
            bounds.push(n);
            let pieces: Option<Vec<FollowPiece>> = bounds
                .windows(2)
                .map(|w| {
                    let (from_deg, to_deg) = (edge(w[0]), edge(w[1]));
                    (to_deg - from_deg >= costly.min_piece_deg).then(|| FollowPiece {
                        from_deg,
                        to_deg,
                        speed_deg_s: need[w[0]..w[1]].iter().copied().fold(f64::INFINITY, f64::min),
                        smearing_rel: 0.0,
                    })
                })
                .collect();
            if let Some(p) = pieces {
                fastest = fastest.min(profile_time_s(&p, costly.accel_deg_s2, costly.per_piece_s));
            }
        }
        assert!(
            (cut_s - fastest).abs() < 1e-9,
            "{cut_s} against {fastest} by hand: {cut:?}"
        );
        assert!(cut.len() < fine.len(), "{cut:?}");
        // No stretch faster than its own samples allow, none predicted over the tolerance.
        for (s, v) in samples.iter().zip(&need) {
            let p = cut
                .iter()
                .find(|p| p.from_deg - 1e-9 <= s.0 && s.0 <= p.to_deg + 1e-9)
                .expect("covered");
            assert!(p.speed_deg_s <= *v, "{p:?} over {v} at {}", s.0);
            assert!(p.smearing_rel <= costly.tolerance_rel * (1.0 + 1e-12));
        }
    }

    #[test]
    fn neighbouring_pieces_never_share_a_speed() {
        let pieces = speed_profile(&sampled(lobe, -80.0, 80.0, 0.05), &request());
        for w in pieces.windows(2) {
            assert_ne!(w[0].speed_deg_s, w[1].speed_deg_s, "{pieces:?}");
        }
    }

    #[test]
    fn where_even_the_floor_smears_too_much_the_piece_says_so() {
        let req = FollowRequest {
            min_speed_deg_s: 10.0,
            ..request()
        };
        let pieces = speed_profile(&sampled(lobe, -10.0, 10.0, 0.05), &req);
        let worst = pieces.iter().map(|p| p.smearing_rel).fold(0.0, f64::max);
        assert!(worst > req.tolerance_rel, "{pieces:?}");
        assert!(pieces.iter().all(|p| p.speed_deg_s >= 10.0));
    }

    #[test]
    fn bad_samples_or_requests_give_no_profile() {
        let good = sampled(lobe, -5.0, 5.0, 0.5);
        assert!(!speed_profile(&good, &request()).is_empty());
        assert!(speed_profile(&good[..2], &request()).is_empty());
        let mut reversed = good.clone();
        reversed.reverse();
        assert!(speed_profile(&reversed, &request()).is_empty());
        let mut zero = good.clone();
        zero[3].1 = 0.0;
        assert!(speed_profile(&zero, &request()).is_empty());
        let slow_top = FollowRequest {
            top_speed_deg_s: 0.01,
            ..request()
        };
        assert!(speed_profile(&good, &slow_top).is_empty());
    }
}
