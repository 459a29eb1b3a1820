//! The store's campaigns as results: its records turned into gonio-results' points and run record, so that the
//! points CSV (`gonio run`'s points.csv, the API's `/api/campaigns/{id}/points.csv`) and the provenance
//! (`gonio run`'s run.json, `gonio export --data DIR --campaign ID`) come from one place each. gonio-results
//! owns the formats (the CSV's columns and writer, the typed run.json); this module only reads the store.

use gonio_instrument::InstrumentFile;
use gonio_results::Run;
use gonio_results::error::ResultsError;
use gonio_results::fit::FitModel;
use gonio_results::points::{self, Point, PointsTable};
use gonio_results::provenance::{CalibrationReading, DeviceIdentity, RunConfig, RunRecord, StoredCampaign};
use gonio_results::report::{PlanCoverage, ReportInput, ReportSummary};
use gonio_results::sweeps::SweepReading;

use crate::store::{CampaignRecord, PointRecord, Store, StoreError};
use gonio_campaign::{self as campaign, Sources};

/// The read-back axes of a stored campaign, in the CSV's column order: the axes of the instrument file stored
/// with it (so that an export after an instrument change still names the right columns); when that no longer
/// parses, the axes its points name, in the order first seen.
pub fn axis_names(record: &CampaignRecord, points: &[PointRecord]) -> Vec<String> {
    match InstrumentFile::parse(&record.instrument_toml, "<stored instrument file>") {
        Ok(file) => file.instrument.axes.iter().map(|a| a.name.clone()).collect(),
        Err(_) => {
            let mut names: Vec<String> = Vec::new();
            for p in points {
                for (n, _) in &p.readback_deg {
                    if !names.contains(n) {
                        names.push(n.clone());
                    }
                }
            }
            names
        }
    }
}

/// One stored point as a result point: a value that is not finite (a failed reading) is missing, read-backs
/// follow `axis_names`.
pub fn point(p: &PointRecord, axis_names: &[String]) -> Point {
    let finite = |v: f64| Some(v).filter(|v| v.is_finite());
    Point {
        index: p.index,
        band_nm: p.band_nm,
        theta_i_deg: p.theta_i_deg,
        phi_i_deg: p.phi_i_deg,
        theta_o_deg: p.theta_o_deg,
        phi_o_deg: p.phi_o_deg,
        signal_w: finite(p.signal_w),
        dark_w: finite(p.dark_w),
        incident_w: finite(p.incident_w),
        brdf_sr: p.brdf_sr.and_then(finite),
        brdf_u_sr: p.brdf_u_sr.and_then(finite),
        flags: p.flags.clone(),
        t_s: finite(p.t_s),
        readback_deg: axis_names
            .iter()
            .map(|a| {
                let v = p.readback_deg.iter().find(|(n, _)| n == a).map(|(_, v)| *v);
                (a.clone(), v.and_then(finite))
            })
            .collect(),
        brdf_aperture_sr: p.brdf_aperture_sr.and_then(finite),
        budget: p.budget.clone(),
        truth_point_sr: p.truth_point_sr.and_then(finite),
        truth_aperture_sr: p.truth_aperture_sr.and_then(finite),
    }
}

/// A stored campaign's points as a table.
pub fn points_table(record: &CampaignRecord, points: &[PointRecord]) -> PointsTable {
    let axis_names = axis_names(record, points);
    PointsTable {
        points: points.iter().map(|p| point(p, &axis_names)).collect(),
        axis_names,
        dry_run: record.dry_run,
    }
}

/// A stored campaign's points CSV (header included).
pub fn points_csv(record: &CampaignRecord, points: &[PointRecord]) -> String {
    points::write_points_csv(&points_table(record, points))
}

/// A stored campaign's points and run record, everything read from `store`: the one source of run.json for
/// `gonio run` and of the provenance of a campaign exported from a daemon's store.
pub fn run_record(store: &Store, record: &CampaignRecord) -> Result<(PointsTable, RunRecord), StoreError> {
    let id = record.id;
    let stored_points = store.points(id)?;
    let table = points_table(record, &stored_points);
    let calibrations: Vec<CalibrationReading> = store
        .calibrations(id)?
        .into_iter()
        .map(|c| CalibrationReading {
            kind: c.kind,
            band_nm: c.band_nm,
            t_s: c.t_s,
            value_w: c.value_w,
            u_w: c.u_w,
        })
        .collect();
    // The engine records the identity of every device it connected (ordered by name in the store).
    let devices = store
        .devices(id)?
        .into_iter()
        .map(|(name, identity)| DeviceIdentity { name, identity })
        .collect();
    let stored = StoredCampaign {
        id: id.0,
        name: record.name.clone(),
        state: record.state.to_string(),
        last_error: record.last_error.clone(),
        dry_run: record.dry_run,
        total_points: record.total_points,
        points_done: record.points_done,
        created_unix_s: record.created_unix_s,
        software_version: record.software_version.clone(),
        config: RunConfig {
            campaign_toml: record.campaign_toml.clone(),
            instrument_toml: record.instrument_toml.clone(),
            alignment_toml: record.alignment_toml.clone(),
        },
        devices,
        // Recorded when the campaign was prepared; campaigns stored before that are prepared once more here.
        predicted_instrument_s: record.predicted_instrument_s.or_else(|| predicted_s(record)),
        ended_instrument_s: record.ended_instrument_s,
        // A function of the stored instrument file, like everything else here; absent on the ideal instrument.
        simulator_truth: crate::rig::simulator_truth(
            &record.instrument_toml,
            record.dry_run,
            calibrations.len(),
        ),
        calibrations,
    };
    let run = RunRecord::assemble(stored, &table.points);
    Ok((table, run))
}

/// The time model's prediction for a campaign stored before its prediction was (as a resume rebuilds it: from the stored texts
/// and their `[resolved]` materials, no file read); `None` when those no longer parse.
fn predicted_s(record: &CampaignRecord) -> Option<f64> {
    let file = InstrumentFile::parse(&record.instrument_toml, "<stored instrument file>").ok()?;
    let prepared = campaign::load_and_prepare(
        &record.campaign_toml,
        "<stored campaign file>",
        &Sources::Stored,
        &file,
    )
    .ok()?;
    // The same prediction `gonio plan` prints and the run started with (an adaptive plan: its whole budget).
    Some(prepared.predicted_s())
}

/// What the planner kept of a run's campaign and what it skipped, by reason: the stored campaign and instrument
/// texts planned again as a resume plans them (the planner is deterministic); `None` when they no longer plan.
pub fn plan_coverage(config: &RunConfig) -> Option<PlanCoverage> {
    let file = InstrumentFile::parse(&config.instrument_toml, "<stored instrument file>").ok()?;
    let prepared = campaign::load_and_prepare(
        &config.campaign_toml,
        "<stored campaign file>",
        &Sources::Stored,
        &file,
    )
    .ok()?;
    let plan = &prepared.plan;
    let mut skipped: Vec<(String, usize)> = plan
        .skipped
        .iter()
        .map(|(reason, n)| {
            let why = if reason.is_constraint() {
                "cannot be measured"
            } else {
                "need not be measured"
            };
            (format!("{} ({why})", reason.name()), *n)
        })
        .collect();
    if prepared.schedule.dropped > 0 {
        skipped.push((
            "arm-separation (no safe move found while ordering)".into(),
            prepared.schedule.dropped,
        ));
    }
    Some(PlanCoverage {
        requested: plan.requested,
        kept: plan.kept(),
        skipped,
        adaptive: prepared.adaptive.is_some(),
    })
}

/// The detector aperture's half-angle seen from the sample (radians), from a run's instrument file: what a fit
/// averages its model over, as the instrument averages the BRDF. `None` when the file no longer parses.
pub fn aperture_half_angle_rad(instrument_toml: &str) -> Option<f64> {
    let file = InstrumentFile::parse(instrument_toml, "<run's instrument file>").ok()?;
    let d = &file.instrument.detector;
    (d.aperture_radius_mm > 0.0 && d.distance_mm > 0.0).then(|| d.aperture_radius_mm.atan2(d.distance_mm))
}

/// A stored campaign as a run, everything read from `store` (points and run record); `origin` names the store
/// in messages.
pub fn run_of(store: &Store, record: &CampaignRecord, origin: &str) -> Result<Run, StoreError> {
    let (table, provenance) = run_record(store, record)?;
    Ok(Run::from_parts(
        format!("{origin}, campaign {}", record.id),
        record.name.clone(),
        table,
        Some(provenance),
    ))
}

/// A run's measurement report (gonio_results::report), the one way `gonio report` and the daemon make it:
/// `models` fitted as `gonio fit` fits them (averaged over the run's detector aperture, the sweep readings
/// with the points), the plan's coverage planned again from the stored texts, written at Unix time `now_s`.
/// `on_model` hears of each fit as it starts (a fit takes seconds).
pub fn report(
    run: &Run,
    sweeps: &[SweepReading],
    models: &[FitModel],
    now_s: f64,
    on_model: impl FnMut(FitModel),
) -> Result<(String, ReportSummary), ResultsError> {
    let aperture = run
        .config()
        .and_then(|c| aperture_half_angle_rad(&c.instrument_toml));
    let with_sweeps = (!sweeps.is_empty()).then(|| gonio_results::sweeps::with_readings(run.clone(), sweeps));
    let (fits, fit_failures) =
        gonio_results::report::fit_models(with_sweeps.as_ref().unwrap_or(run), models, aperture, on_model);
    let input = ReportInput {
        run,
        sweeps,
        fits,
        fit_failures,
        plan: run.config().and_then(plan_coverage),
        generated_by: crate::software_version(),
        generated_unix_s: now_s,
        reproduce_command: run.config().map(|c| {
            let mut cmd = String::from("gonio run campaign.toml --instrument instrument.toml");
            if c.alignment_toml.is_some() {
                cmd.push_str(" --calibration calibration.toml");
            }
            cmd
        }),
    };
    gonio_results::report::render(&input)
}

/// A campaign's sweep readings (`sweeps.csv`, gonio_results::sweeps), in run order.
pub fn sweep_readings(store: &Store, id: crate::store::CampaignId) -> Result<Vec<SweepReading>, StoreError> {
    store.sweep_readings(id)
}
