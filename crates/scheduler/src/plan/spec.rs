//! The records: the `[plan]` schema as deserialised (specs) and the built plan it describes.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use super::PlanError;
use crate::constraints::Reason;
use crate::kinematics::{Geometry, Pose};

/// What the scheduler needs to know about the sample's material.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct SampleTraits {
    pub isotropic: bool,
    pub spectrally_flat: bool,
}

/// `[plan]`.
#[derive(Debug, Clone, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct PlanSpec {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub bands_nm: Option<Vec<f64>>,
    #[serde(default = "one")]
    pub repeats: u32,
    #[serde(default = "yes")]
    pub reciprocity: bool,
    #[serde(default)]
    pub rotation_deg: f64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub grid: Option<GridSpec>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub adaptive: Option<AdaptiveSpec>,
    #[serde(default)]
    pub calibration: CalibrationSpec,
    /// `[[plan.sweeps]]` (see `crate::sweep`).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub sweeps: Vec<SweepSpec>,
    /// The bands the sweeps are swept in, among `bands_nm` (default: all of them): sweeps in one band beside
    /// points in several, which lend the sweeps their spectrum (the filters' leak corrected).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sweep_bands_nm: Option<Vec<f64>>,
}

impl Default for PlanSpec {
    /// What an empty `[plan]` table reads as (a plan still needs a grid or an adaptive table to validate).
    fn default() -> PlanSpec {
        PlanSpec {
            bands_nm: None,
            repeats: one(),
            reciprocity: yes(),
            rotation_deg: 0.0,
            grid: None,
            adaptive: None,
            calibration: CalibrationSpec::default(),
            sweeps: Vec::new(),
            sweep_bands_nm: None,
        }
    }
}

fn one() -> u32 {
    1
}
fn yes() -> bool {
    true
}

#[derive(Debug, Clone, Copy, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "kebab-case")]
pub enum GridKind {
    Full,
    Isotropic,
    InPlane,
    Points,
}

/// `[plan.grid]`. Angle keys take a list or `{ from, to, step }`.
#[derive(Debug, Clone, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct GridSpec {
    pub kind: GridKind,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub theta_i_deg: Option<toml::Value>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub phi_i_deg: Option<toml::Value>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub theta_o_deg: Option<toml::Value>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub phi_o_deg: Option<toml::Value>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub delta_phi_deg: Option<toml::Value>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub plane_phi_deg: Option<toml::Value>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub points: Option<Vec<[f64; 4]>>,
}

impl GridSpec {
    /// A grid of `kind` with no angle given yet (set the keys the kind needs).
    pub fn new(kind: GridKind) -> GridSpec {
        GridSpec {
            kind,
            theta_i_deg: None,
            phi_i_deg: None,
            theta_o_deg: None,
            phi_o_deg: None,
            delta_phi_deg: None,
            plane_phi_deg: None,
            points: None,
        }
    }

    /// An angle key's `{ from, to, step }` form (degrees).
    pub fn range_deg(from: f64, to: f64, step: f64) -> toml::Value {
        let mut t = toml::Table::new();
        t.insert("from".into(), toml::Value::Float(from));
        t.insert("to".into(), toml::Value::Float(to));
        t.insert("step".into(), toml::Value::Float(step));
        toml::Value::Table(t)
    }

    /// An angle key's list form (degrees).
    pub fn list_deg(values: &[f64]) -> toml::Value {
        toml::Value::Array(values.iter().map(|v| toml::Value::Float(*v)).collect())
    }
}

/// `[plan.calibration]`.
#[derive(Debug, Clone, Default, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct CalibrationSpec {
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub dark_every_points: Option<u32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub dark_every_s: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reference_every_points: Option<u32>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reference_every_s: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reference_pose_deg: Option<BTreeMap<String, f64>>,
    /// Not a key of `[plan.calibration]`: the relative method's reference geometry (`[calibration]
    /// reference_geometry_deg`, set by the campaign loader). Reference readings are then taken on the
    /// reference sample at this geometry instead of the direct beam at `reference_pose_deg`.
    #[serde(skip)]
    pub reference_geometry: Option<Geometry>,
}

/// The direct-beam pose of a plan that names none (`[plan.calibration] reference_pose_deg`): the detector arm
/// facing the light arm at -90 degrees, the stage at zero.
pub const DEFAULT_DIRECT_BEAM_POSE: Pose = Pose {
    light_deg: -90.0,
    detector_deg: 90.0,
    tilt_deg: 0.0,
    rotation_deg: 0.0,
};

/// Validated calibration settings.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Calibration {
    pub dark_every_points: Option<u32>,
    pub dark_every_s: Option<f64>,
    pub reference_every_points: Option<u32>,
    pub reference_every_s: Option<f64>,
    /// Physical angles overriding the current pose for direct-beam readings, per role.
    pub reference_overrides: Vec<(gonio_instrument::AxisRole, f64)>,
    /// The relative method: reference readings on the reference sample at a geometry (none: the direct beam).
    pub reference_at: Option<ReferenceAt>,
}

/// Where the relative method reads its reference sample: a geometry, reached by the cheapest of its poses.
#[derive(Debug, Clone)]
pub struct ReferenceAt {
    pub geometry: Geometry,
    pub(crate) kinematics: crate::kinematics::Kinematics,
}

impl PartialEq for ReferenceAt {
    /// The kinematics is the plan's instrument's, the same on both sides of any comparison of one plan.
    fn eq(&self, other: &ReferenceAt) -> bool {
        self.geometry == other.geometry
    }
}

impl Calibration {
    /// The time cadence of sweeps' calibrations (s): the shorter of `dark_every_s` and `reference_every_s`. A
    /// sweep reads no point, so the point counts do not apply; a calibration falls due between arcs.
    pub fn sweep_every_s(&self) -> Option<f64> {
        match (self.dark_every_s, self.reference_every_s) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        }
    }

    pub fn darks(&self) -> bool {
        self.dark_every_points.is_some() || self.dark_every_s.is_some()
    }
    pub fn references(&self) -> bool {
        self.reference_every_points.is_some() || self.reference_every_s.is_some()
    }
    /// Where the next reference reading is taken from `current`: the reference geometry's pose cheapest to reach
    /// (the relative method; `None` when no safe move reaches any), else the direct-beam pose. The schedule
    /// predicts, and the daemon moves, by this one rule.
    pub fn reference_target(&self, current: &Pose, time: &crate::timing::TimeModel) -> Option<Pose> {
        let Some(at) = &self.reference_at else {
            return Some(self.reference_pose(current));
        };
        let (wi, wo) = at.geometry.directions();
        at.kinematics
            .solutions(&wi, &wo, current)
            .ok()?
            .into_iter()
            .map(|p| (time.move_cost_s(current, &p), p))
            .filter(|(cost, _)| cost.is_finite())
            .min_by(|a, b| a.0.total_cmp(&b.0))
            .map(|(_, p)| p)
    }

    /// Where the calibration that opens every start and resume reads its normalisation from `current`: the
    /// reference geometry (relative method), the plan's direct-beam pose, or [`DEFAULT_DIRECT_BEAM_POSE`] when
    /// the plan gives none (the plan builder puts it in the overrides where the arms reach it). The engine moves
    /// there; the time model predicts the same move. `None` where no pose is known that the arms reach.
    pub fn preamble_target(&self, current: &Pose, time: &crate::timing::TimeModel) -> Option<Pose> {
        if self.reference_at.is_some() || !self.reference_overrides.is_empty() {
            self.reference_target(current, time)
        } else {
            None
        }
    }

    /// The direct-beam pose reached from `current`.
    pub fn reference_pose(&self, current: &Pose) -> Pose {
        let mut p = *current;
        for (role, v) in &self.reference_overrides {
            p.set(*role, *v);
        }
        p
    }
}

impl PlanSpec {
    /// The `[plan]` table of a TOML document, other tables ignored. Campaign files are read by
    /// `gonio-campaign` (the one loader, which validates every table); this is for plans on their own (the
    /// scheduler's tests, examples and benchmarks).
    pub fn from_toml(text: &str, origin: &str) -> Result<PlanSpec, PlanError> {
        #[derive(Deserialize)]
        struct PlanOnly {
            plan: PlanSpec,
        }
        toml::from_str::<PlanOnly>(text)
            .map(|d| d.plan)
            .map_err(|e| PlanError::Parse {
                origin: origin.to_string(),
                message: e.to_string(),
            })
    }
}

/// A kept geometry with its valid axis solutions.
#[derive(Debug, Clone, PartialEq)]
pub struct PlannedGeometry {
    /// As requested (isotropic grids: canonical phi_i = 0).
    pub requested: Geometry,
    /// Valid poses, each with the geometry it measures (differs from `requested` only by a turn about the
    /// normal, for isotropic samples).
    pub candidates: Vec<(Pose, Geometry)>,
}

/// A requested geometry measured through another one.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Served {
    pub requested: Geometry,
    /// Index into [`Plan::geometries`].
    pub by: usize,
    /// True when the result must be mirrored (source and detector exchanged).
    pub reciprocal: bool,
    pub reason: Reason,
}

/// A built plan, before ordering.
#[derive(Debug, Clone, PartialEq)]
pub struct Plan {
    /// Kept geometries in request (raster) order.
    pub geometries: Vec<PlannedGeometry>,
    pub bands_nm: Vec<f64>,
    pub repeats: u32,
    /// (geometry, band) pairs requested.
    pub requested: usize,
    /// (geometry, band) pairs skipped, by reason.
    pub skipped: BTreeMap<Reason, usize>,
    pub served: Vec<Served>,
    pub calibration: Calibration,
    /// Pose the candidates were made consistent with (arms on one side), if any.
    pub anchor: Option<Pose>,
}

impl Plan {
    /// (geometry, band) pairs kept.
    pub fn kept(&self) -> usize {
        self.geometries.len() * self.bands_nm.len()
    }
    pub fn skipped_total(&self) -> usize {
        self.skipped.values().sum()
    }
}

/// `[plan.adaptive]`.
#[derive(Debug, Clone, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct AdaptiveSpec {
    /// Points to measure in all (first pass included).
    pub budget_points: u32,
    /// Instrument time after which to stop (s); none by default.
    #[serde(default)]
    pub budget_s: Option<f64>,
    /// Points per batch after the first pass.
    #[serde(default = "default_batch")]
    pub batch_points: u32,
    /// Stop when the largest local error estimate is below this (ln(1 + f) units).
    #[serde(default = "default_target")]
    pub target_error: f64,
    #[serde(default = "default_first_step")]
    pub first_pass_step_deg: f64,
    /// Incidence angles of the first pass; default [0, 30, 60].
    #[serde(default)]
    pub first_pass_theta_i_deg: Option<toml::Value>,
    /// Candidate grid step in theta (delta_phi uses twice this).
    #[serde(default = "default_resolution")]
    pub resolution_deg: f64,
    /// A first pass of sweeps instead of points: the detector sweeps the plane of incidence at each first-pass
    /// incidence (`crate::adaptive`'s module doc).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub first_pass_sweeps: Option<FirstPassSweeps>,
}

/// `first_pass_sweeps = { speed_deg_s, averaging }` in `[plan.adaptive]`: how the first pass sweeps.
#[derive(Debug, Clone, Copy, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct FirstPassSweeps {
    /// The detector arm's speed at cruise (deg/s).
    pub speed_deg_s: f64,
    /// Meter samples per sweep reading; default 1.
    #[serde(default = "one")]
    pub averaging: u32,
}

impl AdaptiveSpec {
    /// A budget of `budget_points` points with every other setting at its default.
    pub fn with_budget(budget_points: u32) -> AdaptiveSpec {
        AdaptiveSpec {
            budget_points,
            budget_s: None,
            batch_points: default_batch(),
            target_error: default_target(),
            first_pass_step_deg: default_first_step(),
            first_pass_theta_i_deg: None,
            resolution_deg: default_resolution(),
            first_pass_sweeps: None,
        }
    }
}

fn default_batch() -> u32 {
    40
}
fn default_target() -> f64 {
    0.02
}
fn default_first_step() -> f64 {
    10.0
}
fn default_resolution() -> f64 {
    2.5
}

/// Which arm sweeps.
#[derive(Debug, Clone, Copy, Deserialize, Serialize, PartialEq, Eq, Hash, PartialOrd, Ord)]
#[serde(rename_all = "kebab-case")]
pub enum SweptArm {
    /// The detector arm sweeps theta_o through the plane of incidence; the incidence is held.
    Detector,
    /// The light arm sweeps theta_i through the plane; the detector is held.
    Light,
}

impl SweptArm {
    pub fn name(&self) -> &'static str {
        match self {
            SweptArm::Detector => "detector",
            SweptArm::Light => "light",
        }
    }
}

fn detector() -> SweptArm {
    SweptArm::Detector
}

/// One `[[plan.sweeps]]` entry (schema and validation in `crate::sweep`).
#[derive(Debug, Clone, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct SweepSpec {
    #[serde(default = "detector")]
    pub arm: SweptArm,
    /// Detector sweeps: the held incidences (a list or a range). Light sweeps: the swept arc `{ from, to }`.
    pub theta_i_deg: toml::Value,
    /// Detector sweeps: the swept arc `{ from, to }`, signed. Light sweeps: the held exitances.
    pub theta_o_deg: toml::Value,
    /// Planes of incidence (sample azimuths); default [0.0].
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub plane_phi_deg: Option<toml::Value>,
    /// Speed of the swept arm at cruise (deg/s).
    pub speed_deg_s: f64,
    /// Meter samples averaged into one sweep reading.
    #[serde(default = "one")]
    pub averaging: u32,
    /// Speed that follows the BRDF (`crate::sweep::follow`): `speed_deg_s` is then the top speed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub follow: Option<FollowSpec>,
    /// The sample is isotropic (its BRDF depends on the azimuths through their difference only): a stretch of
    /// the arc that would need the sample turned half a turn is measured with the arc turned about the normal
    /// instead, the sample held (its readings' geometry is the one measured). Default false.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub isotropic: bool,
}

/// `follow = { ... }` in a `[[plan.sweeps]]` entry: the arc is swept in pieces of constant speed, each as fast as
/// the BRDF measured by an earlier sweep of the same arcs (the first pass) allows for the smearing tolerance.
#[derive(Debug, Clone, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct FollowSpec {
    /// The first pass: the `sweeps.csv` of an earlier run (or its run directory) that swept these arcs.
    pub first_pass: String,
    /// The largest relative smearing allowed per reading (e.g. 0.002).
    pub tolerance_rel: f64,
    /// The slowest speed used (deg/s); default `speed_deg_s` / 64.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub min_speed_deg_s: Option<f64>,
    /// The shortest piece of one speed (degrees; a piece is a move of its own); default 2.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub min_piece_deg: Option<f64>,
    /// The first pass's readings are averaged in bins this wide before the BRDF's bend is taken (degrees);
    /// default 0.5.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub resolution_deg: Option<f64>,
    /// What `tolerance_rel` is relative to: `"reading"` (each reading's value, the default) or `"peak"` (the
    /// largest value along the arc).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub relative_to: Option<crate::sweep::follow::RelativeTo>,
}
