//! `gonio plan`: build, check and order a campaign's plan, print the summary, optionally write the points as CSV.
//!
//! CSV columns: `index,band_nm,theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg`, then `<axis>_deg` per instrument
//! axis in file order (CONTROLLER positions, i.e. after zero offset and direction: what the daemon commands),
//! then `move_s`: the predicted move time into the point from the previous step, settle included; then its parts
//! and the rest of the step: `motion_s`, `settle_s`, `wheel_s` (the filter change), `reading_s`, and `end_s`, the
//! predicted instrument time at which the step's reading ends (seconds from the start of the run, calibration
//! steps included: what a run's points.csv records as `t_s`, so the two compare step by step). One row per
//! measurement step in run order (calibration steps are not rows); with `repeats = N` every point appears N times.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use gonio_brdf::Brdf;
use gonio_campaign::{Prepared, Sources};
use gonio_instrument::InstrumentFile;
use gonio_scheduler::plan;
use gonio_scheduler::schedule::{BandMode, Schedule, StepKind};
use gonio_scheduler::timing::TimeModel;

use crate::CliError;

#[derive(Debug, clap::Args)]
pub struct PlanArgs {
    /// Campaign file (TOML with [campaign] and [plan]).
    pub campaign: PathBuf,
    /// Instrument file (default: the embedded simulated instrument).
    #[arg(long)]
    pub instrument: Option<PathBuf>,
    /// Write the ordered points as CSV to this file.
    #[arg(long)]
    pub points: Option<PathBuf>,
}

pub fn run(args: PlanArgs) -> Result<(), CliError> {
    let file = match &args.instrument {
        Some(p) => InstrumentFile::load(p).map_err(|e| CliError::input(e.to_string()))?,
        None => InstrumentFile::simulated(),
    };
    let origin = args.campaign.display().to_string();
    let text = std::fs::read_to_string(&args.campaign)
        .map_err(|e| CliError::io(format!("cannot read campaign file {origin}"), e))?;
    let base_dir = args.campaign.parent().map(Path::to_path_buf).unwrap_or_default();
    // The same loader and the same prepare as `gonio run` and the daemon: the same plan and prediction.
    let prepared = gonio_campaign::load_and_prepare(&text, &origin, &Sources::Local(base_dir), &file)
        .map_err(|e| CliError::input(e.to_string()))?;
    let out = summary(&prepared, &file);
    print!("{out}");
    if let Some(path) = &args.points {
        let csv = points_csv(&prepared.schedule, &prepared.time);
        std::fs::write(path, csv).map_err(|e| CliError::io(format!("cannot write {}", path.display()), e))?;
    }
    Ok(())
}

/// What `gonio plan` prints.
fn summary(p: &Prepared, file: &InstrumentFile) -> String {
    let instrument = &file.instrument;
    let c = &p.campaign;
    let (plan, sched) = (&p.plan, &p.schedule);
    let mut out = String::new();
    let _ = writeln!(
        out,
        "campaign {} on instrument {} ({})",
        c.id,
        instrument.name,
        plan::geometry_kind_name(instrument.geometry)
    );
    let _ = writeln!(
        out,
        "{}",
        match &c.material {
            Some(m) => format!(
                "material: {} ({}, {})",
                m.model().name(),
                iso_word(m.is_isotropic()),
                flat_word(m.is_spectrally_flat())
            ),
            None => "material: none given (treated as anisotropic and spectrally varying)".to_string(),
        }
    );
    if let Some(a) = &p.adaptive {
        let first = if p.sweeps_first() {
            "first pass: the sweeps below; every pass of points is placed at run time from their readings and \
             the points measured"
        } else {
            "first pass below, each later pass is placed at run time from the points measured"
        };
        let _ = writeln!(
            out,
            "adaptive plan: budget {} points ({} per geometry); {} reachable candidates; {first}",
            a.budget_points(),
            a.points_per_geometry(),
            a.planner().candidate_count()
        );
    }
    if plan.requested == 0 && p.sweeps.is_some() {
        // Sweeps alone, or an adaptive plan's first pass of sweeps: no point block.
        if let Some(sweeps) = &p.sweeps {
            sweep_lines(&mut out, sweeps);
            follow_lines(&mut out, &p.campaign.sweep_profiles);
        }
        match p.rehearsal() {
            Some(r) => {
                let _ = writeln!(
                    out,
                    "predicted duration: {:.1} s ({}), the sweeps and {} points, {}",
                    p.predicted_s(),
                    hms(p.predicted_s()),
                    r.points,
                    rehearsed(p, &r)
                );
            }
            None => {
                let _ = writeln!(
                    out,
                    "predicted duration: {:.1} s ({})",
                    p.predicted_s(),
                    hms(p.predicted_s())
                );
            }
        }
        let _ = writeln!(out, "{}", band_line(p));
        out.push_str(&latency_note(file));
        out.push_str(&leak_note(p, file));
        if let Some(sweeps) = &p.sweeps {
            out.push_str(&sampling_note(file, sweeps));
        }
        return out;
    }
    let geometries = plan.geometries.len();
    let _ = writeln!(
        out,
        "points requested: {} ({} bands: {})",
        plan.requested,
        plan.bands_nm.len().max(1),
        plan.bands_nm
            .iter()
            .map(|b| format!("{b} nm"))
            .collect::<Vec<_>>()
            .join(", ")
    );
    let _ = writeln!(
        out,
        "points kept: {} ({geometries} geometries x {} bands)",
        plan.kept(),
        plan.bands_nm.len()
    );
    if plan.repeats > 1 {
        let _ = writeln!(
            out,
            "repeats: {} passes, {} readings",
            plan.repeats,
            plan.kept() * plan.repeats as usize
        );
    }
    let _ = writeln!(out, "points skipped: {}", plan.skipped_total() + sched.dropped);
    for (reason, n) in &plan.skipped {
        let _ = writeln!(out, "  {:<24} {n}", reason.name());
    }
    if sched.dropped > 0 {
        let _ = writeln!(
            out,
            "  {:<24} {} (no safe move found while ordering)",
            "arm-separation", sched.dropped
        );
    }
    if let Some(r) = p.rehearsal() {
        let _ = writeln!(
            out,
            "predicted duration: {:.1} s ({}) for {} points, {}",
            p.predicted_s(),
            hms(p.predicted_s()),
            r.points,
            rehearsed(p, &r)
        );
    }
    let label = match (&p.adaptive, &p.sweeps) {
        (Some(_), _) => "first pass duration",
        (None, Some(_)) => "points duration",
        (None, None) => "predicted duration",
    };
    print_times(&mut out, sched, label);
    if let Some(sweeps) = &p.sweeps {
        sweep_lines(&mut out, sweeps);
        follow_lines(&mut out, &p.campaign.sweep_profiles);
        let _ = writeln!(
            out,
            "predicted duration: {:.1} s ({}), points and sweeps",
            p.predicted_s(),
            hms(p.predicted_s())
        );
    }
    let _ = writeln!(out, "{}", band_line(p));
    out.push_str(&latency_note(file));
    out.push_str(&leak_note(p, file));
    out.push_str(&drift_note(p, file));
    if let Some(sweeps) = &p.sweeps {
        out.push_str(&sampling_note(file, sweeps));
    }
    out
}

/// A line naming the real motion controllers whose file does not say how long they take to answer a query
/// (`reply_latency_ms`): the prediction counts none, while an SMC100 takes about 10 ms a query (the demo then
/// runs about 7 % longer than predicted). Empty for the simulator and for a file that says it.
fn latency_note(file: &InstrumentFile) -> String {
    let inst = &file.instrument;
    let silent: Vec<&str> = inst
        .devices
        .iter()
        .filter(|d| !d.is_simulated() && d.reply_latency_ms.is_none())
        .filter(|d| inst.axes.iter().any(|a| a.device == d.name))
        .map(|d| d.name.as_str())
        .collect();
    if silent.is_empty() {
        return String::new();
    }
    format!(
        "note: the instrument file does not say how long {} take to answer a query (reply_latency_ms): the \
         prediction counts none, a real SMC100 takes about 10 ms a query; `gonio selftest --write` measures it\n",
        silent.join(" and ")
    )
}

/// A line for a campaign measured in one band through a filter that leaks light from outside it, with no
/// geometry measured in several bands: the completion corrects the leak with the sample's spectrum, which such a
/// campaign does not measure, so its values keep the leak, outside their uncertainty (a few per cent on a
/// coloured sample: construction paper's 550 nm band on realistic.toml reads 3-5 % high). Points in every band
/// beside sweeps in one (`sweep_bands_nm`) lend the sweeps their spectrum. Empty otherwise, and for a sample the
/// campaign's [material] says is spectrally flat (the leak cancels on a grey sample).
fn leak_note(p: &Prepared, file: &InstrumentFile) -> String {
    let points_bands = if p.plan.kept() > 0 || p.adaptive.is_some() {
        p.plan.bands_nm.as_slice()
    } else {
        &[]
    };
    let sweep_bands = p.sweeps.as_ref().map_or(&[][..], |s| s.plan.bands_nm.as_slice());
    let flat = p
        .campaign
        .material
        .as_ref()
        .is_some_and(|m| m.is_spectrally_flat());
    if flat || points_bands.len() >= 2 || sweep_bands.len() >= 2 {
        return String::new();
    }
    let Some(&band) = points_bands.first().or(sweep_bands.first()) else {
        return String::new();
    };
    let leak = gonio_instrument::leakage::band_leakage(&file.instrument, band).unwrap_or(0.0);
    if leak <= 0.0 {
        return String::new();
    }
    format!(
        "note: measured in one band ({band} nm) through a filter that passes {:.2} % of its light from outside \
         its band (the file's blocking): with no geometry measured in other bands the sample's spectrum is \
         unknown, so the leak is neither corrected nor in the values' uncertainty (a few per cent on a coloured \
         sample); measure a few points in every band (beside sweeps: sweep_bands_nm) and the completion corrects \
         it\n",
        100.0 * leak
    )
}

/// How long a campaign may run on its opening normalisation alone before [`drift_note`] speaks (s).
const DRIFT_NOTE_AFTER_S: f64 = 300.0;

/// A line for a campaign that takes no normalisation reading after its opening one (no reference cadence in
/// `[plan.calibration]`) and runs longer than [`DRIFT_NOTE_AFTER_S`]: every value is normalised by that reading
/// carried forward, the lamp's drift since covered only by the file's `source.drift_per_hour`, and a lamp still
/// warming up drifts far faster. Measured by hand while this was built (no test repeats it): realistic.toml's
/// simulated lamp (1 % low at switch-on, settling in 15 minutes) under a 20-minute in-plane grid of white
/// styrofoam (theta_i 15-60 deg, theta_o every 0.078125 deg, 550 nm, `gonio run` against `brdf_true_sr`) read its
/// last values 0.57 % high, k = 2 coverage 64 % over the run; with one reading at the end (`reference_every_s`
/// longer than the campaign) the values in between are interpolated and covered: 100 %, rms z 0.82. Empty
/// otherwise.
fn drift_note(p: &Prepared, file: &InstrumentFile) -> String {
    let duration_s = p.predicted_s();
    // A duration that is not a number (nothing rehearsed) says nothing either.
    if p.plan.calibration.references() || duration_s.is_nan() || duration_s <= DRIFT_NOTE_AFTER_S {
        return String::new();
    }
    let per_hour = file.instrument.source.drift_per_hour.abs();
    format!(
        "note: no normalisation reading after the opening one: values up to {:.0} min later are normalised by \
         it, the lamp's drift since covered only by the instrument file's source.drift_per_hour ({:.2} %/h, at \
         most {:.3} % by the end); a lamp still warming up drifts far faster. `[plan.calibration] \
         reference_every_s` brackets them (one longer than the campaign: a reading at its end only); each \
         reading takes its operator steps\n",
        duration_s / 60.0,
        100.0 * per_hour,
        100.0 * per_hour * duration_s / 3600.0
    )
}

/// A line naming the real controllers of the swept arms whose file does not say when they take the position they
/// report (`position_sampled_ms`): the sweeps then date each report in the middle of the controller's time to
/// answer, up to half of it off, and carry that in every reading's uncertainty. Empty for the simulator and for a
/// file that says it.
fn sampling_note(file: &InstrumentFile, sweeps: &gonio_campaign::Sweeps) -> String {
    let inst = &file.instrument;
    let mut silent: Vec<&str> = sweeps
        .plan
        .arcs
        .iter()
        .filter_map(|arc| inst.axis(gonio_scheduler::sweep::swept_role(arc.request.arm)))
        .filter_map(|a| inst.device(&a.device))
        .filter(|d| !d.is_simulated() && d.position_sampled_ms.is_none())
        .map(|d| d.name.as_str())
        .collect();
    silent.sort_unstable();
    silent.dedup();
    if silent.is_empty() {
        return String::new();
    }
    format!(
        "note: the instrument file does not say when {} take the position they report (position_sampled_ms): the \
         sweeps date each report in the middle of the controller's answer and widen their readings' uncertainty \
         by it; `gonio selftest --write` measures it\n",
        silent.join(" and ")
    )
}

/// How an adaptive plan's passes were rehearsed (gonio_campaign::rehearsal): on what, how many times, and how
/// far apart the rehearsals came out.
fn rehearsed(p: &Prepared, r: &gonio_campaign::Rehearsal) -> String {
    let on = match &p.campaign.material {
        Some(_) => "the campaign's [material]",
        None => "a glossy plastic (the campaign names no [material])",
    };
    if r.draws > 1 {
        format!(
            "every pass rehearsed on {on}, the mean of {} rehearsals with a reading's noise (their spread {:.1} s)",
            r.draws, r.spread_s
        )
    } else {
        format!("every pass rehearsed on {on}")
    }
}

/// The sweeps' part of the summary: what the path check kept and cut, the readings, the time.
fn sweep_lines(out: &mut String, sweeps: &gonio_campaign::Sweeps) {
    let (plan, sched) = (&sweeps.plan, &sweeps.schedule);
    let _ = writeln!(
        out,
        "sweeps: {} arcs requested, {} swept ({:.1} of {:.1} degrees per band, in {})",
        plan.requested,
        plan.arcs.len(),
        plan.swept_deg(),
        plan.requested_deg,
        match plan.bands_nm.len() {
            0 => "the source's band".to_string(),
            1 => format!("1 band: {} nm", plan.bands_nm[0]),
            n => format!(
                "{n} bands: {}",
                plan.bands_nm
                    .iter()
                    .map(|b| format!("{b} nm"))
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
        }
    );
    for (reason, deg) in &plan.skipped_deg {
        let _ = writeln!(out, "  cut {:<20} {deg:>10.2} deg", reason.name());
    }
    let smear = |f: fn(f64, f64) -> f64, init: f64| sched.steps.iter().map(|s| s.smear_deg).fold(init, f);
    let period =
        |f: fn(f64, f64) -> f64, init: f64| sched.steps.iter().map(|s| s.reading_period_s).fold(init, f);
    let _ = writeln!(
        out,
        "  {} sweeps, {} readings, one every {:.0}-{:.0} ms, each over {:.4}-{:.4} deg of arc at cruise",
        sched.steps.len(),
        sched.readings,
        1e3 * period(f64::min, f64::INFINITY),
        1e3 * period(f64::max, 0.0),
        smear(f64::min, f64::INFINITY),
        smear(f64::max, 0.0),
    );
    if sched.unreachable > 0 {
        let _ = writeln!(
            out,
            "  {} sweeps no safe move reaches (not measured)",
            sched.unreachable
        );
    }
    let b = &sched.breakdown;
    let _ = writeln!(out, "sweep duration: {:.1} s ({})", b.total_s(), hms(b.total_s()));
    for (name, v) in [
        ("motion", b.motion_s),
        ("settle", b.settle_s),
        ("filter wheel", b.wheel_s),
        ("sweeping", b.sweep_s),
        ("calibration", b.calibration_s),
        ("closing the beam", b.closing_s),
    ] {
        let _ = writeln!(out, "  {name:<18} {v:>10.1} s");
    }
}

/// The speed profiles of the sweeps that follow the BRDF: each arc's pieces (as the first pass gave them,
/// before the path check cuts what may not be swept) with their speed and predicted smearing.
fn follow_lines(out: &mut String, profiles: &[gonio_scheduler::sweep::ArcProfile]) {
    for p in profiles {
        let worst = p.pieces.iter().map(|q| q.smearing_rel).fold(0.0, f64::max);
        let top = p.pieces.iter().map(|q| q.speed_deg_s).fold(0.0, f64::max);
        let _ = writeln!(
            out,
            "  sweep #{} at {} deg (plane {} deg) follows the BRDF: {} pieces, {:.3}-{:.3} deg/s, largest predicted \
             smearing {:.2e} (relative)",
            p.entry + 1,
            p.held_deg,
            p.plane_phi_deg,
            p.pieces.len(),
            p.slowest_deg_s(),
            top,
            worst
        );
        for q in &p.pieces {
            let _ = writeln!(
                out,
                "    {:>7.2} to {:>7.2} deg at {:>7.3} deg/s, smearing {:.2e}",
                q.from_deg, q.to_deg, q.speed_deg_s, q.smearing_rel
            );
        }
    }
}

/// The time model's target against dry-runs (BENCHMARKS.md section 6 lists where it holds and where not: the
/// densest grids on an instrument file its hardware departs from), and what an adaptive campaign's rehearsal on a
/// stand-in sample adds.
const MODEL_BAND: f64 = 0.02;
const REHEARSAL_BAND: f64 = 0.03;

/// The prediction's band: what the model knows to within its benchmark, and what it does not know at all (the
/// operator's own time at each sample change, retries after device faults).
fn band_line(p: &Prepared) -> String {
    let predicted = p.predicted_s();
    // An adaptive plan: the rehearsals' own spread (k = 2) where it is wider than the stand-in's allowance.
    let placement = match p.rehearsal() {
        Some(r) if predicted > 0.0 => REHEARSAL_BAND.max(2.0 * r.spread_s / predicted),
        Some(_) => REHEARSAL_BAND,
        None if p.adaptive.is_some() => REHEARSAL_BAND,
        None => 0.0,
    };
    let rel = MODEL_BAND + placement;
    // Each run of reference readings is one session: the sample out (or the reference in) and back.
    let sessions = p
        .schedule
        .steps
        .windows(2)
        .filter(|w| w[1].kind == StepKind::Reference && w[0].kind != StepKind::Reference)
        .count()
        + usize::from(
            p.schedule
                .steps
                .first()
                .is_some_and(|s| s.kind == StepKind::Reference),
        );
    let operator = match (
        sessions,
        p.campaign.calibration.simulate_operator && p.campaign.dry_run,
    ) {
        (0, _) => "no operator steps".to_string(),
        (n, true) => format!("{} operator steps, done at once by the simulated operator", 2 * n),
        (n, false) => format!(
            "plus {} operator steps ({n} sample changes, out and back) at the operator's own pace",
            2 * n
        ),
    };
    format!(
        "expected between {:.1} s and {:.1} s (±{:.0} %: {}{}); {operator}; plus retries after device faults",
        predicted * (1.0 - rel),
        predicted * (1.0 + rel),
        100.0 * rel,
        if p.adaptive.is_some() {
            "the time model's target, and the later passes placed on the real sample, not the stand-in"
        } else {
            "the time model's target against dry-runs, BENCHMARKS.md section 6 shows where it holds"
        },
        if p.sweeps.is_some() {
            "; the sweeps' model by crates/engine/tests/it/timing.rs"
        } else {
            ""
        }
    )
}

fn iso_word(iso: bool) -> &'static str {
    if iso { "isotropic" } else { "anisotropic" }
}

fn flat_word(flat: bool) -> &'static str {
    if flat {
        "spectrally flat"
    } else {
        "spectrally varying"
    }
}

fn hms(s: f64) -> String {
    let total = s.round() as u64;
    format!("{}h{:02}m{:02}s", total / 3600, (total / 60) % 60, total % 60)
}

fn print_times(out: &mut String, sched: &Schedule, label: &str) {
    let b = &sched.breakdown;
    let mode = match sched.mode {
        BandMode::PerGeometry => "all bands at each geometry",
        BandMode::PerBand => "one tour per band",
        BandMode::Raster => "raster order (ordering found nothing better)",
    };
    let _ = writeln!(
        out,
        "{label}: {:.1} s ({}), {mode}",
        b.total_s(),
        hms(b.total_s())
    );
    for (name, v) in [
        ("motion", b.motion_s),
        ("settle", b.settle_s),
        ("filter wheel", b.wheel_s),
        ("integration", b.integration_s),
        ("calibration steps", b.calibration_s),
        ("closing the beam", b.closing_s),
    ] {
        let _ = writeln!(out, "  {name:<18} {v:>10.1} s");
    }
    let r = &sched.raster;
    let ratio = |a: f64, b: f64| if b > 0.0 { a / b } else { 1.0 };
    let _ = writeln!(
        out,
        "raster order: {:.1} s ({}); ordered/raster total {:.3}, motion+settle {:.3}",
        r.total_s(),
        hms(r.total_s()),
        ratio(b.total_s(), r.total_s()),
        ratio(b.motion_s + b.settle_s, r.motion_s + r.settle_s)
    );
    let _ = writeln!(
        out,
        "lower bound: {:.1} s (ordered/lower bound {:.3})",
        sched.lower_bound_s,
        ratio(b.total_s(), sched.lower_bound_s)
    );
}

/// The CSV text of the measurement steps.
pub fn points_csv(sched: &Schedule, time: &TimeModel) -> String {
    let mut s = String::from("index,band_nm,theta_i_deg,phi_i_deg,theta_o_deg,phi_o_deg");
    for name in time.axis_names() {
        let _ = write!(s, ",{name}_deg");
    }
    s.push_str(",move_s,motion_s,settle_s,wheel_s,reading_s,end_s\n");
    for (i, step) in sched.measure_steps().enumerate() {
        let Some(g) = step.geometry else { continue };
        let band = step.band_nm.map(|b| b.to_string()).unwrap_or_default();
        let _ = write!(
            s,
            "{i},{band},{:.9},{:.9},{:.9},{:.9}",
            g.theta_i_deg + 0.0,
            g.phi_i_deg + 0.0,
            g.theta_o_deg + 0.0,
            g.phi_o_deg + 0.0
        );
        for c in &step.controller_deg {
            let _ = write!(s, ",{:.9}", c + 0.0);
        }
        let m = &step.movement;
        let end_s = step.start_s + m.total_s() + step.wheel_s + step.reading_s;
        let _ = writeln!(
            s,
            ",{:.6},{:.6},{:.6},{:.6},{:.6},{:.6}",
            m.total_s(),
            m.motion_s,
            m.settle_s,
            step.wheel_s,
            step.reading_s,
            end_s
        );
    }
    s
}
