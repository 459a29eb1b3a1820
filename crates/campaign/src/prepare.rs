//! The one `prepare`: a validated [`Campaign`] to what runs it and what predicts it: the plan, its order
//! (schedule) and the time model built from the campaign's own acquisition settings, and for an adaptive plan
//! the first pass and the [`AdaptivePlan`] that places every later pass. `gonio plan`, `gonio run`, the daemon,
//! the exports and the benchmarks all prepare campaigns here, so they plan and predict the same.

use gonio_brdf::Brdf;
use gonio_brdf::material::Material;
use gonio_instrument::{Instrument, InstrumentFile};
use gonio_scheduler::plan::{self, BuildContext, Plan, SampleTraits};
use gonio_scheduler::schedule::{self, Schedule};
use gonio_scheduler::sweep::{SweepCalibration, SweepPlan, SweepSchedule, build_sweeps, schedule_sweeps};
use gonio_scheduler::timing::TimeModel;

use crate::error::CampaignError;
use crate::load::{Campaign, load};
use crate::materials::check_reference;
use crate::passes::AdaptivePlan;
use crate::rehearsal::{Deferred, Rehearsal};
use crate::sources::Sources;

/// A campaign ready to run: settings, plan, schedule and time model.
#[derive(Debug, Clone)]
pub struct Prepared {
    pub campaign: Campaign,
    /// The plan: the whole grid, or the first pass of an adaptive plan.
    pub plan: Plan,
    /// The plan in run order with its predicted times.
    pub schedule: Schedule,
    /// The time model, with the campaign's averaging and extra settling.
    pub time: TimeModel,
    /// An adaptive plan's later passes, placed at run time from the points measured.
    pub adaptive: Option<AdaptivePlan>,
    /// An adaptive plan's rehearsal on a stand-in sample, made when first asked for ([`Prepared::rehearsal`]).
    rehearsal: Deferred,
    /// The plan's `[[plan.sweeps]]`, after its points; or an adaptive plan's first pass of sweeps, before them.
    pub sweeps: Option<Sweeps>,
}

/// A plan's sweeps: the arcs the path check kept, and their order and times from where the points leave the
/// instrument.
#[derive(Debug, Clone)]
pub struct Sweeps {
    pub plan: SweepPlan,
    pub schedule: SweepSchedule,
    /// An adaptive plan's first pass (`first_pass_sweeps`): swept before any point, and the planner places
    /// every pass of points from their readings (`crate::passes`).
    pub first: bool,
}

impl Prepared {
    /// Points (measure steps) the campaign measures: the schedule's, or an adaptive plan's budget (its upper
    /// bound: it may stop earlier at its target error).
    pub fn total_points(&self) -> u64 {
        match &self.adaptive {
            Some(a) => a.budget_points(),
            None => self.schedule.measure_steps().count() as u64,
        }
    }

    /// Predicted instrument time (s): the schedule's; for an adaptive plan, every pass as rehearsed on a stand-in
    /// sample (the later passes are placed at run time from the values measured); then the sweeps'.
    pub fn predicted_s(&self) -> f64 {
        let points = match self.rehearsal() {
            Some(r) => r.mean_s,
            None => self.schedule.breakdown.total_s(),
        };
        // A first pass of sweeps is in the rehearsal already.
        points
            + self
                .sweeps
                .as_ref()
                .filter(|s| !s.first)
                .map_or(0.0, |s| s.schedule.breakdown.total_s())
    }

    /// An adaptive plan rehearsed on a stand-in sample ([`crate::rehearsal::rehearse`]): the predicted instrument
    /// time of all its passes, its spread, and the points they measure; made on the first call (a second or two
    /// of work). None for a fixed plan.
    pub fn rehearsal(&self) -> Option<Rehearsal> {
        let adaptive = self.adaptive.as_ref()?;
        *self.rehearsal.made.get_or_init(|| {
            let swept = self
                .sweeps
                .as_ref()
                .filter(|s| s.first)
                .map(|s| (&s.plan, &s.schedule));
            Some(crate::rehearsal::rehearse(
                adaptive,
                &self.schedule,
                swept,
                self.campaign.material.as_ref(),
                self.rehearsal.noise,
            ))
        })
    }

    /// True when sweeps run before the points: an adaptive plan's first pass of sweeps.
    pub fn sweeps_first(&self) -> bool {
        self.sweeps.as_ref().is_some_and(|s| s.first)
    }

    /// The bands measured (nm).
    pub fn bands_nm(&self) -> &[f64] {
        &self.plan.bands_nm
    }

    /// A dry-run measures a simulated sample: it needs one (`[material]`). Planning does not.
    pub fn require_sample(&self, instrument: &Instrument) -> Result<(), CampaignError> {
        let c = &self.campaign;
        if c.dry_run && c.material.is_none() {
            return Err(c.located().plain(format!(
                "the instrument {:?} is simulated, so the campaign is a dry-run and needs a [material] table \
                 (the simulated sample: a material table or `preset = \"gold\"`)",
                instrument.name
            )));
        }
        Ok(())
    }
}

/// What the scheduler needs to know of a sample: unknown materials are planned for as anisotropic and spectrally
/// varying (nothing may be skipped on their account).
pub fn sample_traits(material: Option<&Material>) -> SampleTraits {
    match material {
        Some(m) => SampleTraits {
            isotropic: m.is_isotropic(),
            spectrally_flat: m.is_spectrally_flat(),
        },
        None => SampleTraits {
            isotropic: false,
            spectrally_flat: false,
        },
    }
}

/// The time model a campaign runs to: the instrument's, with the campaign's averaging (not the instrument file's
/// default) and its extra settling after every move, as the engine does.
pub fn campaign_time_model(campaign: &Campaign, instrument: &Instrument) -> TimeModel {
    let mut time = TimeModel::new(instrument);
    time.reading_s = gonio_scheduler::timing::reading_time_s(campaign.acquisition.averaging);
    time.calibration_reading_s =
        gonio_scheduler::timing::reading_time_s(campaign.acquisition.calibration_averaging);
    for axis in time.axes.iter_mut().flatten() {
        axis.settle_s += campaign.acquisition.extra_settle_s;
    }
    time
}

/// Plan, order and time a validated campaign (deterministic: the same campaign always gives the same points in
/// the same order, which is what resuming relies on).
pub fn prepare(campaign: Campaign, instrument: &Instrument) -> Result<Prepared, CampaignError> {
    let at = campaign.located();
    let traits = sample_traits(campaign.material.as_ref());
    let ctx = BuildContext {
        instrument,
        traits,
        sample_radius_mm: Some(campaign.sample_radius_mm),
        start: None,
    };
    let time = campaign_time_model(&campaign, instrument);
    let spec = &campaign.plan_spec;
    let (plan, schedule, adaptive) = match &spec.adaptive {
        Some(adaptive_spec) => {
            let adaptive_plan =
                AdaptivePlan::new(adaptive_spec, spec, &ctx, time.clone()).map_err(|e| at.plan(&e))?;
            let plan = adaptive_plan.first_plan(&ctx).map_err(|e| at.plan(&e))?;
            let schedule = schedule::schedule_continuing(&plan, &time, None, None);
            (plan, schedule, Some(adaptive_plan))
        }
        // Sweeps alone: a plan of no point.
        None if spec.grid.is_none() && !spec.sweeps.is_empty() => {
            let plan = plan::build_from_geometries(spec, &ctx, &[], false).map_err(|e| at.plan(&e))?;
            let schedule = schedule::schedule(&plan, &time, None);
            (plan, schedule, None)
        }
        None => {
            let plan = plan::build(spec, &ctx).map_err(|e| at.plan(&e))?;
            let schedule = schedule::schedule(&plan, &time, None);
            (plan, schedule, None)
        }
    };
    // An adaptive plan's first pass of sweeps takes the place of `[[plan.sweeps]]`.
    let first_pass_sweeps = adaptive.as_ref().and_then(|a| a.planner().first_pass_sweeps());
    if first_pass_sweeps.is_some() && !spec.sweeps.is_empty() {
        return Err(CampaignError(format!(
            "{}: [[plan.sweeps]] beside [plan.adaptive] first_pass_sweeps: an adaptive plan whose first pass \
             sweeps takes no other sweeps for now; remove one of them",
            at.at("plan", None)
        )));
    }
    let sweep_specs = first_pass_sweeps.as_deref().unwrap_or(&spec.sweeps);
    if sweep_specs.is_empty() && spec.sweep_bands_nm.is_some() {
        return Err(CampaignError(format!(
            "{}: sweep_bands_nm without a sweep: it says which bands [[plan.sweeps]] are swept in; remove it \
             or add the sweeps",
            at.at("plan", Some("sweep_bands_nm"))
        )));
    }
    let first = first_pass_sweeps.is_some();
    let sweeps = if sweep_specs.is_empty() {
        None
    } else {
        // The arms stay on the side the points chose, so that the instrument goes from one to the other.
        let side = plan
            .anchor
            .or_else(|| {
                plan.geometries
                    .first()
                    .and_then(|g| g.candidates.first())
                    .map(|c| c.0)
            })
            .map(|p| p.light_deg < p.detector_deg);
        let requested = plan::plan_bands(spec, instrument).map_err(|e| at.plan(&e))?;
        let sweep_bands = plan::sweep_bands(spec, &requested, &plan.bands_nm).map_err(|e| at.plan(&e))?;
        let sweep_plan = build_sweeps(
            sweep_specs,
            instrument,
            &time,
            Some(campaign.sample_radius_mm),
            &sweep_bands,
            side,
            &campaign.sweep_profiles,
        )
        .map_err(|e| at.plan(&first_pass_error(e, first)))?;
        if sweep_plan.arcs.is_empty() {
            let table = if first {
                "[plan.adaptive] first_pass_sweeps"
            } else {
                "[[plan.sweeps]]"
            };
            return Err(CampaignError(format!(
                "{}: {table}: no arc can be swept on instrument {:?} (degrees cut by rule: {:?})",
                at.at("plan", None),
                instrument.name,
                sweep_plan.skipped_deg
            )));
        }
        let start = schedule.steps.last().map(|s| (s.pose, schedule.end.wheel));
        // Without points before them, the sweeps open the session with its calibration.
        let calibration = SweepCalibration {
            plan: &plan,
            opening: schedule.measure_steps().next().is_none(),
            last: !first,
        };
        let sweep_schedule = schedule_sweeps(&sweep_plan, &time, start, Some(calibration));
        Some(Sweeps {
            plan: sweep_plan,
            schedule: sweep_schedule,
            first,
        })
    };
    if schedule.measure_steps().next().is_none() && sweeps.is_none() {
        return Err(CampaignError(format!(
            "{}: [plan]: no point of the plan can be measured on instrument {:?} (all were skipped: {:?})",
            at.at("plan", None),
            instrument.name,
            plan.skipped
        )));
    }
    if let Some(r) = &campaign.calibration.reference {
        let mut bands = plan.bands_nm.clone();
        if bands.is_empty() {
            bands.extend(instrument.source.wavelength_nm);
        }
        check_reference(r, &bands, instrument, campaign.sample_radius_mm)
            .map_err(|(key, e)| at.err("calibration", key, e))?;
    }
    let rehearsal = Deferred::new(crate::rehearsal::reading_noise(
        instrument,
        campaign.acquisition.averaging,
    ));
    Ok(Prepared {
        campaign,
        plan,
        schedule,
        time,
        adaptive,
        rehearsal,
        sweeps,
    })
}

/// A first pass of sweeps is built from `[[plan.sweeps]]` entries the planner wrote: what is wrong with one is
/// named where the campaign file asked for it.
fn first_pass_error(e: plan::PlanError, first: bool) -> plan::PlanError {
    match e {
        plan::PlanError::Invalid { key, message, .. } if first => plan::PlanError::Invalid {
            table: ".adaptive".into(),
            key: "first_pass_sweeps".into(),
            message: format!("{key}: {message}"),
        },
        e => e,
    }
}

/// [`load`] then [`prepare`]: a campaign's text to a prepared campaign.
pub fn load_and_prepare(
    text: &str,
    origin: &str,
    sources: &Sources,
    file: &InstrumentFile,
) -> Result<Prepared, CampaignError> {
    prepare(load(text, origin, sources, file)?, &file.instrument)
}
