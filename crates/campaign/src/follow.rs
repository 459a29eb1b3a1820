//! Sweeps whose speed follows the BRDF (`follow = { first_pass = ... }` in `[[plan.sweeps]]`): the first pass's
//! readings read once, when the campaign is loaded, and turned into the speed profile of every arc that follows
//! (`gonio_scheduler::sweep::profile`). A stored campaign keeps the profiles in its `[resolved]` table, so that
//! resuming never reads the first pass again.

use std::path::Path;

use gonio_instrument::Instrument;
use gonio_results::sweeps::{SweepReading, parse_sweeps_csv};
use gonio_scheduler::kinematics::Geometry;
use gonio_scheduler::plan::PlanSpec;
use gonio_scheduler::sweep::{ArcProfile, PassReading, arc_profile, requests, swept_role};
use gonio_scheduler::timing::TimeModel;

use crate::error::{CampaignError, Located};
use crate::sources::{self, Sources};

/// The file a run writes its sweep readings to: a run directory names it.
pub const SWEEPS_CSV: &str = "sweeps.csv";

/// A first-pass reading as the profile needs it: the arc's middle, the band and the value (the BRDF, or the
/// signal when the reading has none).
fn pass_reading(r: &SweepReading) -> Option<PassReading> {
    let value = r.brdf_sr.or(r.signal_w)?;
    Some(PassReading {
        geometry: Geometry::new(r.theta_i_deg, r.phi_i_deg, r.theta_o_deg, r.phi_o_deg),
        s_deg: (r.arc_from_deg + r.arc_to_deg) / 2.0,
        band_nm: r.band_nm,
        value,
    })
}

/// Read one first pass (a `sweeps.csv` or the run directory holding it).
fn read_first_pass(path: &Path) -> Result<Vec<PassReading>, String> {
    let file = if path.is_dir() {
        path.join(SWEEPS_CSV)
    } else {
        path.to_path_buf()
    };
    let text = std::fs::read_to_string(&file)
        .map_err(|e| format!("cannot read the first pass {}: {e}", file.display()))?;
    let readings = parse_sweeps_csv(&text, &file.display().to_string()).map_err(|e| e.to_string())?;
    Ok(readings.iter().filter_map(pass_reading).collect())
}

/// The speed profile of every arc whose `[[plan.sweeps]]` entry follows the BRDF, from the first passes the
/// entries name (each file read once). Empty when no entry follows.
pub(crate) fn profiles(
    plan: &PlanSpec,
    instrument: &Instrument,
    at: &Located<'_>,
    sources: &Sources,
    base: &Path,
) -> Result<Vec<ArcProfile>, CampaignError> {
    if plan.sweeps.iter().all(|s| s.follow.is_none()) {
        return Ok(Vec::new());
    }
    let reqs = requests(&plan.sweeps, |arm| {
        instrument.axis(swept_role(arm)).map(|a| a.max_speed_deg_s)
    })
    .map_err(|e| at.plan(&e))?;
    let time = TimeModel::new(instrument);
    let mut read: Vec<(String, Vec<PassReading>)> = Vec::new();
    let mut out = Vec::new();
    for r in &reqs {
        let Some(follow) = plan.sweeps.get(r.entry).and_then(|s| s.follow.as_ref()) else {
            continue;
        };
        let key = || format!("sweeps #{}", r.entry + 1);
        let located = |message: String| at.err(&format!("plan.{}", key()), "follow", message);
        if !read.iter().any(|(name, _)| *name == follow.first_pass) {
            // The file, or the run directory holding it (a daemon's policy admits files only: its sweeps.csv).
            let path = sources::file_path(sources, base, &follow.first_pass)
                .or_else(|e| {
                    let in_dir = format!("{}/{SWEEPS_CSV}", follow.first_pass.trim_end_matches('/'));
                    sources::file_path(sources, base, &in_dir).map_err(|_| e)
                })
                .map_err(located)?;
            let readings = read_first_pass(&path).map_err(located)?;
            read.push((follow.first_pass.clone(), readings));
        }
        let readings = read
            .iter()
            .find(|(name, _)| *name == follow.first_pass)
            .map(|(_, r)| r.as_slice())
            .unwrap_or_default();
        out.push(
            arc_profile(r, readings, follow, &time)
                .map_err(|e| located(format!("{e} (first pass {})", follow.first_pass)))?,
        );
    }
    Ok(out)
}
