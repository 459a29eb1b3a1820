//! Issue 41's third target: on gold and the coloured plastic, sweeps whose speed follows the BRDF reach a
//! smearing tolerance in at most a third of the time of constant-speed sweeps. Every run goes through the release
//! binary (`gonio run`), on both instrument files:
//!
//! Both materials are isotropic and the campaigns say so (`isotropic = true`): the arc's stretch beyond the
//! light arm is measured turned about the normal with the sample held, so that only the light arm changes sides
//! between the stretches (3.5 s from reading to reading on the simulated instrument, where turning the sample half
//! a turn took 6.5 s, in every run alike: crates/engine/tests/it/sweeps.rs prints both).
//!
//! 1. A first pass: the detector through the plane of incidence at 30 deg incidence, -80 to 80 deg, at
//!    [`FIRST_PASS_DEG_S`] with one meter sample a reading (one band, 550 nm). Its readings make the profile; its
//!    `brdf_true_sr` column (the simulator's BRDF at each reading's nominal geometry, every 0.016 deg) is the truth
//!    the smearing is measured against. A first pass at the top speed (one reading every 0.08 deg, five times
//!    fewer per bin) measures the BRDF's bend through more noise: its profiles came out slower, and following
//!    was then no faster than a constant speed at these tolerances (tried: ratios 0.35-1.09 against 0.31-0.88).
//! 2. The same arc with `follow = { first_pass, tolerance_rel, relative_to }` at a top speed of 20 deg/s (the
//!    arms' largest) with 30 samples a reading.
//! 3. Constant-speed sweeps of the arc with 30 samples a reading, at the fastest speed that meets the same
//!    tolerance: started at the profile's slowest speed, then raised by the measured smearing
//!    (smearing grows as the speed squared) and run again, keeping the fastest run that met it.
//!
//! The smearing of a reading: the truth averaged over the arc it covered (`arc_from_deg..arc_to_deg`, by the
//! midpoint rule on the first pass's truth, linearly interpolated) against the truth at the arc's middle,
//! relative to that (tolerance relative to each reading) or to the arc's largest truth (relative to the peak).
//! Time: from the first reading to the last (the sweeping; the opening calibration and the closing one are the
//! same for both), and the same with the first pass's own sweeping added.

use std::fmt::Write as _;
use std::path::Path;

use gonio_results::sweeps::SweepReading;

use crate::gonio_run::gonio_run;

const MATERIALS: [&str; 2] = ["coloured-plastic", "gold"];
const TOP_SPEED_DEG_S: f64 = 20.0;
const FIRST_PASS_DEG_S: f64 = 4.0;
const AVERAGING: u32 = 30;
/// (what the tolerance is relative to, the tolerance).
const CASES: [(&str, f64); 4] = [
    ("reading", 1e-4),
    ("reading", 2e-5),
    ("peak", 1e-4),
    ("peak", 2e-5),
];
const RATIO_TARGET: f64 = 1.0 / 3.0;
/// Runs at a constant speed, at most, to find the fastest that meets the tolerance.
const CONSTANT_TRIES: usize = 4;
/// The widest gap between the first pass's readings the truth is interpolated across (deg): they are 0.016 deg
/// apart along a stretch.
const TRUTH_GAP_DEG: f64 = 0.1;
/// The step of the fastest speed law's integration along the arc (deg): [`Truth::fastest_law_s`].
const BOUND_STEP_DEG: f64 = 0.05;

fn campaign(id: &str, material: &str, speed_deg_s: f64, averaging: u32, follow: &str) -> String {
    format!(
        "[campaign]\nid = \"{id}\"\n[sample]\nradius_mm = 12.5\n[plan]\nbands_nm = [550.0]\n[[plan.sweeps]]\n\
         theta_i_deg = [30.0]\ntheta_o_deg = {{ from = -80.0, to = 80.0 }}\nspeed_deg_s = {speed_deg_s}\n\
         averaging = {averaging}\nisotropic = true\n{follow}\n[calibration]\nmethod = \"absolute\"\nsimulate_operator = true\n\
         [material]\npreset = \"{material}\"\n"
    )
}

/// The truth along the arc: (signed angle, BRDF), increasing, from a dense first pass.
struct Truth {
    along: Vec<(f64, f64)>,
    peak: f64,
}

impl Truth {
    fn of(first: &[SweepReading]) -> Truth {
        let mut along: Vec<(f64, f64)> = first
            .iter()
            .filter_map(|r| Some((0.5 * (r.arc_from_deg + r.arc_to_deg), r.truth_point_sr?)))
            .filter(|(s, f)| s.is_finite() && f.is_finite())
            .collect();
        along.sort_by(|a, b| a.0.total_cmp(&b.0));
        along.dedup_by(|a, b| a.0 == b.0);
        let peak = along.iter().map(|p| p.1).fold(0.0, f64::max);
        Truth { along, peak }
    }

    /// The truth at `s`, linear between the first pass's readings; none past its ends or inside a gap between
    /// them wider than [`TRUTH_GAP_DEG`] (the arc's stretches end at the retro-reflection block: a line across
    /// it is no truth, and a reading reaching into it would seem to smear by the line's kink).
    fn at(&self, s: f64) -> Option<f64> {
        let i = self.along.partition_point(|(x, _)| *x < s);
        let (l, r) = (self.along.get(i.checked_sub(1)?)?, self.along.get(i)?);
        (r.0 - l.0 <= TRUTH_GAP_DEG).then(|| l.1 + (r.1 - l.1) * (s - l.0) / (r.0 - l.0))
    }

    /// The smearing of a reading over `[a, b]` (module doc); `None` outside the truth.
    fn smearing(&self, a: f64, b: f64, to_peak: bool) -> Option<f64> {
        let n = 200;
        let (lo, hi) = (a.min(b), a.max(b));
        let mut sum = 0.0;
        for k in 0..n {
            sum += self.at(lo + (hi - lo) * (f64::from(k) + 0.5) / f64::from(n))?;
        }
        let mid = self.at(0.5 * (a + b))?;
        let scale = if to_peak { self.peak } else { mid };
        (scale > 0.0).then(|| (sum / f64::from(n) - mid).abs() / scale)
    }

    /// The least time any speed law could take over the truth's arc with readings of `reading_s` each: at every
    /// place (a step of [`BOUND_STEP_DEG`]) the longest arc a reading centred there may cover within `tolerance`
    /// (by bisection; smearing grows with the arc), as a speed, at most `top_deg_s`, and the time of the arc at
    /// those speeds, as if the arm changed speed at once (no acceleration, no pieces): a bound on what
    /// following can reach, set by the BRDF, the tolerance, the reading's length and the top speed alone.
    fn fastest_law_s(&self, reading_s: f64, top_deg_s: f64, tolerance: f64, to_peak: bool) -> Option<f64> {
        let (&(first, _), &(last, _)) = (self.along.first()?, self.along.last()?);
        let top_arc = top_deg_s * reading_s;
        if !(top_arc > 0.0 && last > first) {
            return None;
        }
        let mut total_s = 0.0;
        let mut at = first;
        while at < last {
            let step = BOUND_STEP_DEG.min(last - at);
            let centre = at + 0.5 * step;
            let meets = |arc: f64| {
                self.smearing(centre - 0.5 * arc, centre + 0.5 * arc, to_peak)
                    // Past the truth's ends: nothing to smear against, as the runs' readings there.
                    .is_none_or(|e| e <= tolerance)
            };
            let arc = if meets(top_arc) {
                top_arc
            } else {
                let (mut lo, mut hi) = (0.0, top_arc);
                for _ in 0..40 {
                    let mid = 0.5 * (lo + hi);
                    if meets(mid) { lo = mid } else { hi = mid }
                }
                lo
            };
            if arc <= 0.0 {
                return None;
            }
            total_s += step / (arc / reading_s);
            at += step;
        }
        Some(total_s)
    }

    fn worst(&self, readings: &[SweepReading], to_peak: bool) -> f64 {
        readings
            .iter()
            .filter_map(|r| self.smearing(r.arc_from_deg, r.arc_to_deg, to_peak))
            .fold(0.0, f64::max)
    }
}

/// From the first reading to the last (s).
fn sweeping_s(readings: &[SweepReading]) -> f64 {
    let (lo, hi) = readings
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), r| {
            (lo.min(r.t_s), hi.max(r.t_s))
        });
    (hi - lo).max(0.0)
}

/// The time a run spends between its readings besides their rhythm (s): every pause longer than three reading
/// periods (the median), less one period. At a constant speed these are the moves the arc asks for whatever the
/// speed (around the retro-reflection block, back to an arc's other end), which any speed law pays too.
fn pauses_s(readings: &[SweepReading]) -> f64 {
    let mut t: Vec<f64> = readings.iter().map(|r| r.t_s).filter(|t| t.is_finite()).collect();
    t.sort_by(f64::total_cmp);
    let mut gaps: Vec<f64> = t.windows(2).map(|w| w[1] - w[0]).collect();
    let all = gaps.clone();
    gaps.sort_by(f64::total_cmp);
    let Some(&period) = gaps.get(gaps.len() / 2) else {
        return 0.0;
    };
    all.iter()
        .filter(|g| **g > 3.0 * period)
        .map(|g| g - period)
        .sum()
}

/// One row of the table.
struct Row {
    pieces: usize,
    slowest_deg_s: f64,
    follow_s: f64,
    follow_worst: f64,
    constant_deg_s: f64,
    constant_s: f64,
    constant_worst: f64,
    first_s: f64,
    /// The fastest speed law's time over the arc ([`Truth::fastest_law_s`]) with the moves between the arc's
    /// stretches ([`pauses_s`]); `None` where it cannot be had.
    fastest_law_s: Option<f64>,
}

fn one_case(
    binary: &Path,
    instrument: &Path,
    material: &str,
    first_csv: &Path,
    truth: &Truth,
    first_s: f64,
    (relative_to, tolerance): (&str, f64),
) -> Result<Row, String> {
    let to_peak = relative_to == "peak";
    let follow = format!(
        "follow = {{ first_pass = \"{}\", tolerance_rel = {tolerance:e}, relative_to = \"{relative_to}\" }}",
        first_csv.display()
    );
    let text = campaign("follow", material, TOP_SPEED_DEG_S, AVERAGING, &follow);
    // The profile as the campaign loader makes it: pieces and slowest speed.
    let file = gonio_instrument::InstrumentFile::load(instrument).map_err(|e| e.to_string())?;
    let prepared = gonio_campaign::load_and_prepare(
        &text,
        "follow.toml",
        &gonio_campaign::Sources::Local(std::env::temp_dir()),
        &file,
    )
    .map_err(|e| e.to_string())?;
    let profile = prepared
        .campaign
        .sweep_profiles
        .first()
        .ok_or("no speed profile")?;
    let slowest = profile.slowest_deg_s();
    let followed = gonio_run(binary, &text, Some(instrument))?.sweeps()?;
    // How long a reading lasts (s): the meter's integration time the readings carry (the median reading; every
    // run here takes the same samples a reading).
    let mut integrations: Vec<f64> = followed
        .iter()
        .map(|r| r.integration_s)
        .filter(|t| t.is_finite() && *t > 0.0)
        .collect();
    integrations.sort_by(f64::total_cmp);
    let reading_s = integrations.get(integrations.len() / 2).copied();
    // The fastest constant speed that meets the tolerance.
    let (mut speed, mut best): (f64, Option<(f64, f64, f64)>) = (slowest, None);
    // The moves between the arc's stretches that any speed law pays (`pauses_s` of the first constant run).
    let mut pauses = None;
    for _ in 0..CONSTANT_TRIES {
        let readings = gonio_run(
            binary,
            &campaign("constant", material, speed, AVERAGING, ""),
            Some(instrument),
        )?
        .sweeps()?;
        let worst = truth.worst(&readings, to_peak);
        if pauses.is_none() {
            pauses = Some(pauses_s(&readings));
        }
        if worst <= tolerance {
            if best.is_none_or(|b| speed > b.0) {
                best = Some((speed, sweeping_s(&readings), worst));
            }
        } else if best.is_some() {
            break;
        }
        // Smearing grows as the speed squared: the speed that would just meet it, 2 % under.
        let next = (speed * (tolerance / worst.max(1e-300)).sqrt() * 0.98).min(TOP_SPEED_DEG_S);
        let next = (next * 1000.0).floor() / 1000.0;
        if (next - speed).abs() < 1e-3 || next <= 0.0 {
            break;
        }
        speed = next;
    }
    let (constant_deg_s, constant_s, constant_worst) =
        best.ok_or_else(|| format!("no constant speed down to {speed:.3} deg/s met {tolerance:e}"))?;
    Ok(Row {
        pieces: profile.pieces.len(),
        slowest_deg_s: slowest,
        follow_s: sweeping_s(&followed),
        follow_worst: truth.worst(&followed, to_peak),
        constant_deg_s,
        constant_s,
        constant_worst,
        first_s,
        fastest_law_s: reading_s
            .and_then(|t| truth.fastest_law_s(t, TOP_SPEED_DEG_S, tolerance, to_peak))
            .map(|law| law + pauses.unwrap_or(0.0)),
    })
}

/// Section 7's table of speed that follows the BRDF (module doc).
pub fn section(root: &Path, binary: &Path, quick: bool) -> String {
    let mut s = String::from("\n### Speed that follows the BRDF\n\n");
    let _ = writeln!(
        s,
        "On the coloured plastic and gold, both instrument files, through `gonio run` (crates/bench/src/follow.rs): \
         a first pass (the detector from -80 to 80 deg at 30 deg incidence, {FIRST_PASS_DEG_S} deg/s, one sample a \
         reading, 550 nm; every campaign with `isotropic = true`: the stretch beyond the light arm measured on the arc turned about the normal, the sample held), then the same arc with `follow` (top speed {TOP_SPEED_DEG_S} deg/s, {AVERAGING} samples a reading: 90 ms, \
         1.8 deg of arc at the top speed), and at the fastest constant speed that meets the same tolerance (found \
         by runs at measured smearing). Smearing: each reading's arc-averaged truth against the truth at its arc's \
         middle (the first pass's truth column, a reading every 0.016 deg), relative to the reading or to the arc's peak; the largest \
         over the readings is listed. Time: from the first reading to the last. Fastest law: the least time any \
         speed law could take with readings as long (the meter's integration time), at every place along the arc the fastest \
         speed whose reading meets the tolerance there (at most the top speed), changed at once, with no \
         acceleration and no pieces, plus the moves between the arc's stretches that the constant-speed run \
         made (around the retro-reflection block: its pauses between readings): what following could reach at \
         best. Target: following takes at most \
         a third of the constant speed's time.\n"
    );
    s.push_str(
        "| material | instrument | tolerance | follow: pieces, slowest deg/s, time, largest smearing | constant: deg/s, \
         time, largest smearing | follow / constant | with the first pass | fastest law / constant | target |\n\
         |---|---|---|---|---|---|---|---|---|\n",
    );
    let cases: &[(&str, f64)] = if quick { &CASES[2..3] } else { &CASES };
    let materials: &[&str] = if quick { &MATERIALS[..1] } else { &MATERIALS };
    let tmp = std::env::temp_dir().join(format!("gonio-bench-follow-{}", std::process::id()));
    // Rows whose target no speed law could meet (the fastest law's ratio over a third), of the rows with one.
    let (mut laws, mut beyond_any_law) = (0usize, Vec::<String>::new());
    for material in materials {
        for (label, instrument) in [
            ("ideal", root.join("config/instruments/simulated.toml")),
            ("realistic", root.join("config/instruments/realistic.toml")),
        ] {
            eprintln!("    follow: {material}, {label}...");
            let first = gonio_run(
                binary,
                &campaign("first", material, FIRST_PASS_DEG_S, 1, ""),
                Some(&instrument),
            )
            .and_then(|r| r.sweeps());
            let first = match first {
                Ok(f) => f,
                Err(e) => {
                    let _ = writeln!(
                        s,
                        "| {material} | {label} | | FAILED: first pass: {e} | | | | | |"
                    );
                    continue;
                }
            };
            let _ = std::fs::create_dir_all(&tmp);
            let first_csv = tmp.join(format!("{material}-{label}.csv"));
            if let Err(e) = std::fs::write(&first_csv, gonio_results::sweeps::write_sweeps_csv(&first, true))
            {
                let _ = writeln!(s, "| {material} | {label} | | FAILED: {e} | | | | | |");
                continue;
            }
            let truth = Truth::of(&first);
            let first_s = sweeping_s(&first);
            for &(relative_to, tolerance) in cases {
                let tol = format!("{tolerance:e} of the {relative_to}");
                match one_case(
                    binary,
                    &instrument,
                    material,
                    &first_csv,
                    &truth,
                    first_s,
                    (relative_to, tolerance),
                ) {
                    Ok(r) => {
                        let ratio = r.follow_s / r.constant_s.max(1e-9);
                        if let Some(b) = r.fastest_law_s {
                            laws += 1;
                            if b / r.constant_s.max(1e-9) > RATIO_TARGET {
                                beyond_any_law.push(format!("{material}, {label}, {tol}"));
                            }
                        }
                        let with_first = (r.follow_s + r.first_s) / r.constant_s.max(1e-9);
                        let _ = writeln!(
                            s,
                            "| {material} | {label} | {tol} | {}, {:.3}, {:.1} s, {:.2e} | {:.3}, {:.1} s, {:.2e} | \
                             {ratio:.2} | {with_first:.2} | {} | {} |",
                            r.pieces,
                            r.slowest_deg_s,
                            r.follow_s,
                            r.follow_worst,
                            r.constant_deg_s,
                            r.constant_s,
                            r.constant_worst,
                            r.fastest_law_s.map_or("-".to_string(), |b| format!(
                                "{:.1} s, {:.2}",
                                b,
                                b / r.constant_s.max(1e-9)
                            )),
                            match (ratio <= RATIO_TARGET, r.follow_worst <= tolerance) {
                                (true, true) => "met",
                                (_, false) => "NOT met: following smeared over the tolerance",
                                (false, true) => "NOT met",
                            }
                        );
                    }
                    Err(e) => {
                        let _ = writeln!(s, "| {material} | {label} | {tol} | FAILED: {e} | | | | | |");
                    }
                }
            }
        }
    }
    let _ = std::fs::remove_dir_all(&tmp);
    if laws > 0 {
        let _ = writeln!(
            s,
            "\nThe fastest law is over a third of the constant speed's time on {} of {laws} rows{}: there no speed \
             law meets the target with readings this long and this top speed (the top speed caps the law where \
             the BRDF is smooth; longer readings would leave less of the arc capped, and sweep all of it \
             slower); on the others following could at best reach the fastest law's ratio, and what it loses to \
             it is the profile's (its pieces at one speed each, each a move with its ramps, the speed sized for \
             part of the tolerance from a noisy first pass).",
            beyond_any_law.len(),
            if beyond_any_law.is_empty() {
                String::new()
            } else {
                format!(" ({})", beyond_any_law.join("; "))
            }
        );
    }
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    fn truth(f: impl Fn(f64) -> f64) -> Truth {
        let along: Vec<(f64, f64)> = (0..=2000)
            .map(|k| -10.0 + 0.01 * f64::from(k))
            .map(|x| (x, f(x)))
            .collect();
        let peak = along.iter().map(|p| p.1).fold(0.0, f64::max);
        Truth { along, peak }
    }

    #[test]
    fn pauses_are_the_moves_between_stretches() {
        let reading = |t_s: f64| SweepReading {
            segment: 0,
            k: 0,
            band_nm: 550.0,
            t_s,
            integration_s: 0.09,
            theta_i_deg: 30.0,
            phi_i_deg: 0.0,
            theta_o_deg: 10.0,
            phi_o_deg: 180.0,
            arc_from_deg: 10.0,
            arc_to_deg: 10.5,
            signal_w: None,
            incident_w: None,
            brdf_sr: None,
            brdf_u_sr: None,
            brdf_aperture_sr: None,
            flags: Vec::new(),
            truth_point_sr: None,
        };
        // Readings every 0.1 s with one 5 s move between two stretches: 4.9 s of pause.
        let mut r: Vec<SweepReading> = (0..50).map(|k| reading(0.1 * f64::from(k))).collect();
        r.extend((0..50).map(|k| reading(9.9 + 0.1 * f64::from(k))));
        assert!((pauses_s(&r) - 4.9).abs() < 1e-9, "{}", pauses_s(&r));
        assert_eq!(pauses_s(&r[..50]), 0.0);
        assert_eq!(pauses_s(&[]), 0.0);
    }

    #[test]
    fn a_reading_reaching_into_the_gap_between_stretches_is_not_judged() {
        // Two stretches of a gently sloped truth with a 20-deg gap between them (the retro-reflection block): a
        // line across the gap has a kink at the stretch's end, which a reading reaching over it would seem to
        // smear by; the truth is not known there.
        let along: Vec<(f64, f64)> = (0..=500)
            .map(|k| -30.0 + 0.01 * f64::from(k))
            .chain((0..=500).map(|k| -5.0 + 0.01 * f64::from(k)))
            .map(|x| (x, 1.0 + 0.01 * (x + 15.0).abs()))
            .collect();
        let t = Truth { along, peak: 1.15 };
        assert_eq!(t.at(-15.0), None);
        assert!(t.smearing(-5.05, -4.9, false).is_none());
        let inside = t.smearing(-4.95, -4.8, false).expect("within a stretch");
        assert!(inside < 1e-9, "{inside}");
    }

    #[test]
    fn the_fastest_law_runs_at_the_top_speed_where_nothing_bends() {
        // A straight line smears nothing: the whole 20 deg at 20 deg/s.
        let t = truth(|x| 2.0 + 0.05 * x);
        let s = t.fastest_law_s(0.09, 20.0, 1e-6, false).expect("a time");
        assert!((s - 1.0).abs() < 1e-6, "{s}");
    }

    #[test]
    fn the_fastest_law_slows_as_the_bend_asks() {
        // f = 10 - c x^2: an arc a centred anywhere averages to f - c a^2 / 12, a smearing of c a^2 / 12 / 10
        // against the peak; the longest arc within tol is sqrt(120 tol / c), the speed that arc over the
        // reading's time.
        let c = 0.02;
        let t = truth(|x| 10.0 - c * x * x);
        let (tol, reading_s) = (1e-4, 0.09);
        let arc = (120.0 * tol / c).sqrt();
        // Within half a top-speed arc of the truth's ends a reading would reach past it: nothing to judge it
        // by (as the runs' readings there), so the top speed.
        let top_arc = 20.0 * reading_s;
        let expected = (20.0 - top_arc) / (arc / reading_s) + top_arc / 20.0;
        let s = t.fastest_law_s(reading_s, 20.0, tol, true).expect("a time");
        assert!((s / expected - 1.0).abs() < 0.01, "{s} against {expected}");
        // Halving the tolerance slows every place by sqrt 2.
        let s2 = t.fastest_law_s(reading_s, 20.0, tol / 2.0, true).expect("a time");
        assert!((s2 / s - 2f64.sqrt()).abs() < 0.02, "{s2} against {s}");
    }
}
