//! The `[plan]` table of a campaign file, and the plan it describes: which geometries and bands to measure,
//! what was skipped and why. Ordering and timing are `crate::schedule`'s job.
//!
//! # Schema (all angles in degrees, wavelengths in nm; see `config/campaigns/plan-examples.toml`)
//! ```toml
//! [plan]
//! bands_nm = [450.0, 550.0, 650.0] # bands of the instrument's filter wheel; default: all of them
//! repeats = 1                      # passes over the whole plan (each pass runs the previous one backwards)
//! reciprocity = true               # measure (i, o) OR (o, i), never both; default true
//! rotation_deg = 0.0               # sample rotation held for isotropic samples; default 0
//!
//! [plan.grid]                      # exactly one of [plan.grid] and [plan.adaptive]
//! kind = "isotropic"               # "full" | "isotropic" | "in-plane" | "points"
//! theta_i_deg = { from = 0.0, to = 60.0, step = 15.0 } # a range (both ends included) or a list [0.0, 30.0]
//! theta_o_deg = [0.0, 20.0, 40.0, 60.0]
//! delta_phi_deg = { from = 0.0, to = 180.0, step = 45.0 }
//! # kind = "full":     theta_i_deg, phi_i_deg, theta_o_deg, phi_o_deg
//! # kind = "in-plane": theta_i_deg, theta_o_deg (signed: > 0 on the specular side, phi_o = plane + 180;
//! #                    < 0 on the source's side, phi_o = plane), plane_phi_deg (default [0.0])
//! # kind = "points":   points = [[theta_i, phi_i, theta_o, phi_o], ...]
//!
//! [plan.calibration]               # optional; no calibration steps without it
//! dark_every_points = 200          # a dark reading (wheel on its blank) every N measured points...
//! dark_every_s = 1800.0            # ...and/or every T seconds of instrument time; plus one at start and end
//! reference_every_points = 200     # direct-beam readings (every band), same rules
//! reference_every_s = 1800.0
//! reference_pose_deg = { light = -90.0, detector = 90.0 } # axis name -> physical angle; others stay put
//!
//! [plan.adaptive]                  # see crate::adaptive
//! budget_points = 400
//! ```
//! Skips, counted per (geometry, band) so that kept + skipped = requested: `duplicate`, `isotropic` (same
//! theta_i, theta_o, delta_phi as another point of an isotropic sample: absolute phi is never swept),
//! `reciprocity`, `spectrally-flat`, and the constraint names of `crate::constraints`.

use std::collections::{BTreeMap, HashMap};

use gonio_brdf::geometry::Direction;
use gonio_instrument::{GeometryKind, Instrument};
use serde::{Deserialize, Serialize};

use crate::adaptive::AdaptiveSpec;
use crate::constraints::{Constraints, Reason};
use crate::kinematics::{Geometry, Kinematics, KinematicsError, Pose};
use crate::timing::TimeModel;

/// A plan that cannot be built; the message names the key.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum PlanError {
    #[error("campaign file {origin}: {message}")]
    Parse { origin: String, message: String },
    #[error("[plan{table}] {key}: {message}")]
    Invalid {
        table: String,
        key: String,
        message: String,
    },
}

/// Geometries a grid may enumerate at most. Enumerating, de-duplicating and checking a larger one would take the
/// validation minutes and gigabytes (a denial of service through one submitted file), and a campaign of this size
/// would already run for weeks.
pub const MAX_GRID_GEOMETRIES: usize = 1_000_000;

/// (geometry, band, repeat) readings a plan may hold at most (see [`MAX_GRID_GEOMETRIES`]).
pub const MAX_PLANNED_READINGS: usize = 5_000_000;

/// Refuse a grid of more than [`MAX_GRID_GEOMETRIES`] before enumerating it.
fn check_grid_size(keys: &str, lens: &[usize]) -> Result<(), PlanError> {
    let n = lens
        .iter()
        .try_fold(1usize, |acc, l| acc.checked_mul(*l))
        .unwrap_or(usize::MAX);
    if n > MAX_GRID_GEOMETRIES {
        return Err(invalid(
            "grid",
            keys,
            format!(
                "the grid has {} geometries, more than the {MAX_GRID_GEOMETRIES} a plan may hold: use larger steps",
                if n == usize::MAX {
                    "too many".to_string()
                } else {
                    n.to_string()
                }
            ),
        ));
    }
    Ok(())
}

fn invalid(table: &str, key: &str, message: impl Into<String>) -> PlanError {
    let table = if table.is_empty() {
        String::new()
    } else {
        format!(".{table}")
    };
    PlanError::Invalid {
        table,
        key: key.to_string(),
        message: message.into(),
    }
}

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
}

/// Validated calibration settings.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Calibration {
    pub dark_every_points: Option<u32>,
    pub dark_every_s: Option<f64>,
    pub reference_every_points: Option<u32>,
    pub reference_every_s: Option<f64>,
    /// Physical angles overriding the current pose for direct-beam readings, per role.
    pub reference_overrides: Vec<(gonio_instrument::AxisRole, f64)>,
}

impl Calibration {
    pub fn darks(&self) -> bool {
        self.dark_every_points.is_some() || self.dark_every_s.is_some()
    }
    pub fn references(&self) -> bool {
        self.reference_every_points.is_some() || self.reference_every_s.is_some()
    }
    /// The reference pose reached from `current`.
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

/// Angles from a list or a `{ from, to, step }` range.
pub fn angle_list(table: &str, key: &str, value: &toml::Value) -> Result<Vec<f64>, PlanError> {
    let num = |v: &toml::Value| v.as_float().or_else(|| v.as_integer().map(|i| i as f64));
    match value {
        toml::Value::Array(items) => {
            let mut out = Vec::with_capacity(items.len());
            for (i, v) in items.iter().enumerate() {
                let x = num(v).ok_or_else(|| invalid(table, key, format!("item {i} is not a number")))?;
                out.push(x);
            }
            if out.is_empty() {
                return Err(invalid(table, key, "expected at least one angle"));
            }
            Ok(out)
        }
        toml::Value::Table(t) => {
            for k in t.keys() {
                if !["from", "to", "step"].contains(&k.as_str()) {
                    return Err(invalid(
                        table,
                        key,
                        format!("unknown range key {k:?}, expected from, to, step"),
                    ));
                }
            }
            let get = |k: &str| -> Result<f64, PlanError> {
                t.get(k).and_then(num).ok_or_else(|| {
                    invalid(
                        table,
                        key,
                        format!("a range needs a number `{k}` (from, to, step)"),
                    )
                })
            };
            let (from, to, step) = (get("from")?, get("to")?, get("step")?);
            if !(step.is_finite() && step > 0.0 && from.is_finite() && to.is_finite() && to >= from) {
                return Err(invalid(
                    table,
                    key,
                    format!("expected from <= to and step > 0, got {from}, {to}, {step}"),
                ));
            }
            let n = ((to - from) / step + 1e-9).floor() as usize;
            if n > 100_000 {
                return Err(invalid(
                    table,
                    key,
                    // `n` saturates for ranges wider than any float step covers (e.g. from -1e308 to 1e308).
                    format!("range gives {} angles; at most 100000", n.saturating_add(1)),
                ));
            }
            Ok((0..=n).map(|k| from + step * k as f64).collect())
        }
        _ => Err(invalid(
            table,
            key,
            "expected a list of angles or { from, to, step }",
        )),
    }
}

fn required(grid: &GridSpec, key: &str, v: &Option<toml::Value>) -> Result<Vec<f64>, PlanError> {
    let v = v.as_ref().ok_or_else(|| {
        invalid(
            "grid",
            key,
            format!("kind = {:?} needs this key", grid_kind_name(grid.kind)),
        )
    })?;
    angle_list("grid", key, v)
}

fn grid_kind_name(k: GridKind) -> &'static str {
    match k {
        GridKind::Full => "full",
        GridKind::Isotropic => "isotropic",
        GridKind::InPlane => "in-plane",
        GridKind::Points => "points",
    }
}

fn check_range(key: &str, values: &[f64], lo: f64, hi: f64) -> Result<(), PlanError> {
    match values.iter().find(|v| !(v.is_finite() && (lo..=hi).contains(*v))) {
        Some(v) => Err(invalid("grid", key, format!("{v} is outside [{lo}, {hi}]"))),
        None => Ok(()),
    }
}

/// A requested geometry, and whether its absolute azimuth is free (isotropic grid on an isotropic sample).
#[derive(Debug, Clone, Copy)]
struct Request {
    geometry: Geometry,
    iso_free: bool,
}

/// The geometries a grid asks for, in raster order; `isotropic_request` tells whether the grid is expressed in
/// (theta_i, theta_o, delta_phi).
fn requests(grid: &GridSpec) -> Result<(Vec<Geometry>, bool), PlanError> {
    let unused = |key: &str, v: &Option<toml::Value>| -> Result<(), PlanError> {
        if v.is_some() {
            return Err(invalid(
                "grid",
                key,
                format!("not used by kind = {:?}", grid_kind_name(grid.kind)),
            ));
        }
        Ok(())
    };
    let mut out = Vec::new();
    match grid.kind {
        GridKind::Full => {
            unused("delta_phi_deg", &grid.delta_phi_deg)?;
            unused("plane_phi_deg", &grid.plane_phi_deg)?;
            let ti = required(grid, "theta_i_deg", &grid.theta_i_deg)?;
            let pi = required(grid, "phi_i_deg", &grid.phi_i_deg)?;
            let to = required(grid, "theta_o_deg", &grid.theta_o_deg)?;
            let po = required(grid, "phi_o_deg", &grid.phi_o_deg)?;
            check_range("theta_i_deg", &ti, 0.0, 180.0)?;
            check_range("theta_o_deg", &to, 0.0, 180.0)?;
            check_range("phi_i_deg", &pi, -360.0, 360.0)?;
            check_range("phi_o_deg", &po, -360.0, 360.0)?;
            check_grid_size(
                "theta_i_deg x phi_i_deg x theta_o_deg x phi_o_deg",
                &[ti.len(), pi.len(), to.len(), po.len()],
            )?;
            for a in &ti {
                for b in &pi {
                    for c in &to {
                        for d in &po {
                            out.push(Geometry::new(*a, *b, *c, *d));
                        }
                    }
                }
            }
            Ok((out, false))
        }
        GridKind::Isotropic => {
            unused("phi_i_deg", &grid.phi_i_deg)?;
            unused("phi_o_deg", &grid.phi_o_deg)?;
            unused("plane_phi_deg", &grid.plane_phi_deg)?;
            let ti = required(grid, "theta_i_deg", &grid.theta_i_deg)?;
            let to = required(grid, "theta_o_deg", &grid.theta_o_deg)?;
            let dp = required(grid, "delta_phi_deg", &grid.delta_phi_deg)?;
            check_range("theta_i_deg", &ti, 0.0, 180.0)?;
            check_range("theta_o_deg", &to, 0.0, 180.0)?;
            check_range("delta_phi_deg", &dp, 0.0, 180.0)?;
            check_grid_size(
                "theta_i_deg x theta_o_deg x delta_phi_deg",
                &[ti.len(), to.len(), dp.len()],
            )?;
            for a in &ti {
                for c in &to {
                    for d in &dp {
                        out.push(Geometry::new(*a, 0.0, *c, *d));
                    }
                }
            }
            Ok((out, true))
        }
        GridKind::InPlane => {
            unused("phi_i_deg", &grid.phi_i_deg)?;
            unused("phi_o_deg", &grid.phi_o_deg)?;
            unused("delta_phi_deg", &grid.delta_phi_deg)?;
            let ti = required(grid, "theta_i_deg", &grid.theta_i_deg)?;
            let to = required(grid, "theta_o_deg", &grid.theta_o_deg)?;
            let planes = match &grid.plane_phi_deg {
                Some(v) => angle_list("grid", "plane_phi_deg", v)?,
                None => vec![0.0],
            };
            check_range("theta_i_deg", &ti, 0.0, 180.0)?;
            check_range("theta_o_deg", &to, -180.0, 180.0)?;
            check_range("plane_phi_deg", &planes, -360.0, 360.0)?;
            check_grid_size(
                "plane_phi_deg x theta_i_deg x theta_o_deg",
                &[planes.len(), ti.len(), to.len()],
            )?;
            for p in &planes {
                for a in &ti {
                    for c in &to {
                        let po = if *c >= 0.0 { p + 180.0 } else { *p };
                        out.push(Geometry::new(*a, *p, c.abs(), po));
                    }
                }
            }
            Ok((out, false))
        }
        GridKind::Points => {
            for (key, v) in [
                ("theta_i_deg", &grid.theta_i_deg),
                ("theta_o_deg", &grid.theta_o_deg),
                ("phi_i_deg", &grid.phi_i_deg),
                ("phi_o_deg", &grid.phi_o_deg),
                ("delta_phi_deg", &grid.delta_phi_deg),
                ("plane_phi_deg", &grid.plane_phi_deg),
            ] {
                unused(key, v)?;
            }
            let points = grid
                .points
                .as_ref()
                .ok_or_else(|| invalid("grid", "points", "kind = \"points\" needs this key"))?;
            if points.is_empty() {
                return Err(invalid(
                    "grid",
                    "points",
                    "expected at least one [theta_i, phi_i, theta_o, phi_o]",
                ));
            }
            check_grid_size("points", &[points.len()])?;
            for (i, p) in points.iter().enumerate() {
                if p.iter().any(|x| !x.is_finite())
                    || !(0.0..=180.0).contains(&p[0])
                    || !(0.0..=180.0).contains(&p[2])
                {
                    return Err(invalid(
                        "grid",
                        "points",
                        format!("point {i} {p:?}: thetas must be in [0, 180]"),
                    ));
                }
                out.push(Geometry::new(p[0], p[1], p[2], p[3]));
            }
            Ok((out, false))
        }
    }
}

/// A key identifying a geometry up to rounding; isotropic keys drop the absolute azimuth.
fn key(g: &Geometry, isotropic: bool) -> (i64, i64, i64, i64) {
    let q = |x: f64| (x * 1e6).round() as i64;
    let (wi, wo) = g.directions();
    let g = Geometry::from_directions(&wi, &wo);
    if isotropic {
        (q(g.theta_i_deg), q(g.theta_o_deg), q(g.delta_phi_deg()), 0)
    } else {
        let p = |theta: f64, phi: f64| {
            if q(theta) == 0 {
                0
            } else {
                q(phi.rem_euclid(360.0)) % q(360.0)
            }
        };
        (
            q(g.theta_i_deg),
            p(g.theta_i_deg, g.phi_i_deg),
            q(g.theta_o_deg),
            p(g.theta_o_deg, g.phi_o_deg),
        )
    }
}

/// Everything the builder needs besides the spec.
#[derive(Debug, Clone, Copy)]
pub struct BuildContext<'a> {
    pub instrument: &'a Instrument,
    pub traits: SampleTraits,
    pub sample_radius_mm: Option<f64>,
    /// Where the instrument is; candidates are kept on the arm side reachable from it.
    pub start: Option<Pose>,
}

/// Validate the bands of `[plan]` against the instrument.
pub fn plan_bands(spec: &PlanSpec, instrument: &Instrument) -> Result<Vec<f64>, PlanError> {
    let available = instrument.bands_nm();
    match &spec.bands_nm {
        None => Ok(available),
        Some(list) => {
            if list.is_empty() {
                return Err(invalid("", "bands_nm", "expected at least one band"));
            }
            let mut out: Vec<f64> = Vec::new();
            for b in list {
                if !available.iter().any(|a| (a - b).abs() <= 1e-6) {
                    return Err(invalid(
                        "",
                        "bands_nm",
                        format!(
                            "{b} nm is not a band of instrument {:?}; it has {available:?}",
                            instrument.name
                        ),
                    ));
                }
                if out.iter().any(|o| (o - b).abs() <= 1e-6) {
                    return Err(invalid("", "bands_nm", format!("{b} nm is listed twice")));
                }
                out.push(*b);
            }
            Ok(out)
        }
    }
}

/// Validate `[plan.calibration]`.
pub fn calibration(spec: &CalibrationSpec, instrument: &Instrument) -> Result<Calibration, PlanError> {
    let t = "calibration";
    for (key, v) in [
        ("dark_every_points", spec.dark_every_points),
        ("reference_every_points", spec.reference_every_points),
    ] {
        if v == Some(0) {
            return Err(invalid(t, key, "expected at least 1"));
        }
    }
    for (key, v) in [
        ("dark_every_s", spec.dark_every_s),
        ("reference_every_s", spec.reference_every_s),
    ] {
        if let Some(s) = v
            && !(s.is_finite() && s > 0.0)
        {
            return Err(invalid(t, key, format!("expected seconds > 0, got {s}")));
        }
    }
    let mut cal = Calibration {
        dark_every_points: spec.dark_every_points,
        dark_every_s: spec.dark_every_s,
        reference_every_points: spec.reference_every_points,
        reference_every_s: spec.reference_every_s,
        reference_overrides: Vec::new(),
    };
    if cal.darks()
        && instrument
            .filter_wheel
            .as_ref()
            .is_none_or(|w| !w.positions.iter().any(|p| p.blank))
    {
        return Err(invalid(
            t,
            "dark_every_points",
            "dark readings need a blank position on the filter wheel",
        ));
    }
    let pose = match &spec.reference_pose_deg {
        Some(p) => p.clone(),
        None if cal.references() => {
            let mut m = BTreeMap::new();
            for (role, v) in [
                (gonio_instrument::AxisRole::LightArm, -90.0),
                (gonio_instrument::AxisRole::DetectorArm, 90.0),
            ] {
                if let Some(a) = instrument.axis(role) {
                    m.insert(a.name.clone(), v);
                }
            }
            m
        }
        None => BTreeMap::new(),
    };
    for (name, v) in &pose {
        let axis = instrument.axes.iter().find(|a| &a.name == name).ok_or_else(|| {
            invalid(
                t,
                "reference_pose_deg",
                format!("no axis named {name:?} on instrument {:?}", instrument.name),
            )
        })?;
        if !(v.is_finite() && (axis.min_deg..=axis.max_deg).contains(v)) {
            return Err(invalid(
                t,
                "reference_pose_deg",
                format!(
                    "{name} = {v} is outside the axis limits [{}, {}]",
                    axis.min_deg, axis.max_deg
                ),
            ));
        }
        cal.reference_overrides.push((axis.role, *v));
    }
    if cal.references() {
        let arms: Vec<_> = cal
            .reference_overrides
            .iter()
            .filter(|(r, _)| {
                matches!(
                    r,
                    gonio_instrument::AxisRole::LightArm | gonio_instrument::AxisRole::DetectorArm
                )
            })
            .collect();
        if arms.len() != 2 {
            return Err(invalid(
                t,
                "reference_pose_deg",
                "must give both arm angles for direct-beam readings",
            ));
        }
        let probe = cal.reference_pose(&Pose::new(0.0, 0.0, 0.0, 0.0));
        if probe.arm_separation_deg() < instrument.safety.min_arm_separation_deg {
            return Err(invalid(
                t,
                "reference_pose_deg",
                "the arms are closer than safety.min_arm_separation_deg",
            ));
        }
    }
    Ok(cal)
}

/// Build the plan of a `[plan.grid]`: enumerate, reduce, check constraints, pick bands.
pub fn build(spec: &PlanSpec, ctx: &BuildContext) -> Result<Plan, PlanError> {
    if spec.repeats == 0 {
        return Err(invalid("", "repeats", "expected at least 1"));
    }
    if !spec.rotation_deg.is_finite() {
        return Err(invalid("", "rotation_deg", "expected a number of degrees"));
    }
    if let Some(r) = ctx.sample_radius_mm
        && !(r.is_finite() && r > 0.0)
    {
        return Err(PlanError::Invalid {
            table: String::new(),
            key: "[sample] radius_mm".into(),
            message: format!("expected mm > 0, got {r}"),
        });
    }
    let grid = match (&spec.grid, &spec.adaptive) {
        (Some(g), None) => g,
        (None, Some(_)) => {
            return Err(invalid(
                "",
                "grid",
                "this is an adaptive plan: use crate::adaptive to get its batches",
            ));
        }
        _ => {
            return Err(invalid(
                "",
                "grid",
                "expected exactly one of [plan.grid] and [plan.adaptive]",
            ));
        }
    };
    let (geometries, iso_grid) = requests(grid)?;
    build_from_geometries(spec, ctx, &geometries, iso_grid)
}

/// Build from explicit geometries (used by grids and by the adaptive planner's batches).
pub fn build_from_geometries(
    spec: &PlanSpec,
    ctx: &BuildContext,
    geometries: &[Geometry],
    iso_grid: bool,
) -> Result<Plan, PlanError> {
    let instrument = ctx.instrument;
    let bands_all = plan_bands(spec, instrument)?;
    let readings = geometries
        .len()
        .saturating_mul(bands_all.len())
        .saturating_mul(spec.repeats as usize);
    if readings > MAX_PLANNED_READINGS {
        return Err(invalid(
            "",
            "repeats",
            format!(
                "{} geometries x {} bands x {} repeats = {readings} readings, more than the {MAX_PLANNED_READINGS} a \
                 plan may hold",
                geometries.len(),
                bands_all.len(),
                spec.repeats
            ),
        ));
    }
    let calibration = calibration(&spec.calibration, instrument)?;
    let kin = Kinematics::new(instrument);
    let time = TimeModel::new(instrument);
    let constraints = Constraints::new(instrument, ctx.sample_radius_mm);
    let iso = ctx.traits.isotropic;
    let requests: Vec<Request> = geometries
        .iter()
        .map(|g| Request {
            geometry: *g,
            iso_free: iso,
        })
        .collect();
    let n_bands = bands_all.len();
    let mut skipped: BTreeMap<Reason, usize> = BTreeMap::new();

    // Anchor: the start pose, else the reference pose fixes which side each arm is on.
    let default_hint = Pose::new(0.0, 0.0, 0.0, spec.rotation_deg);
    let anchor = ctx.start.or_else(|| {
        calibration
            .references()
            .then(|| calibration.reference_pose(&default_hint))
    });
    let hint = anchor.unwrap_or(default_hint);

    // 1. Exact and isotropic duplicates: the first occurrence stands for the others.
    let mut first_by_key: HashMap<(i64, i64, i64, i64), usize> = HashMap::new();
    let mut unique: Vec<usize> = Vec::new();
    // fate[i]: Ok(unique index) if i is unique, or Err((twin request index, reason)).
    let mut twin: Vec<Option<(usize, Reason)>> = vec![None; requests.len()];
    for (i, r) in requests.iter().enumerate() {
        let exact = key(&r.geometry, iso_grid);
        if let Some(&j) = first_by_key.get(&exact) {
            twin[i] = Some((j, Reason::Duplicate));
            continue;
        }
        if r.iso_free && !iso_grid {
            let k = key(&r.geometry, true);
            let k = (k.0, k.1, k.2, i64::MIN);
            if let Some(&j) = first_by_key.get(&k) {
                twin[i] = Some((j, Reason::Isotropic));
                continue;
            }
            first_by_key.insert(k, i);
        }
        first_by_key.insert(exact, i);
        unique.push(i);
    }

    // 2. Constraints and kinematics for each unique request.
    let mut verdict: HashMap<usize, Result<Vec<(Pose, Geometry)>, Reason>> = HashMap::new();
    for &i in &unique {
        let r = requests[i];
        let (wi, wo) = r.geometry.directions();
        verdict.insert(
            i,
            solve(&kin, &constraints, &time, &wi, &wo, &r, spec.rotation_deg, &hint),
        );
    }

    // Which side the arms are on: the anchor's, else the side that keeps more points.
    let side = |p: &Pose| p.light_deg < p.detector_deg;
    let chosen_side = match anchor {
        Some(a) => side(&a),
        None => {
            let (mut lower, mut upper) = (0usize, 0usize);
            for v in verdict.values().flatten() {
                lower += usize::from(v.iter().any(|(p, _)| side(p)));
                upper += usize::from(v.iter().any(|(p, _)| !side(p)));
            }
            lower >= upper
        }
    };
    let margin = time.arm_overshoot_margin_deg();
    for v in verdict.values_mut() {
        if let Ok(c) = v {
            c.retain(|(p, _)| side(p) == chosen_side);
            // Room for the backlash overshoots (see TimeModel::arm_overshoot_margin_deg).
            c.retain(|(p, _)| constraints.separation_ok(p.arm_separation_deg() - margin));
            if let Some(a) = anchor {
                c.retain(|(p, _)| time.plan_move(&a, p).is_ok());
            }
            if c.is_empty() {
                *v = Err(Reason::ArmSeparation);
            }
        }
    }

    // 3. Reciprocity: of (i, o) and (o, i), measure one; prefer a valid one, then the smaller theta_i.
    let mut fate: HashMap<usize, Result<(), (usize, Reason, bool)>> = HashMap::new();
    if spec.reciprocity {
        let mut by_key: HashMap<(i64, i64, i64, i64), usize> = HashMap::new();
        for &i in &unique {
            let r = requests[i];
            by_key.insert(key(&r.geometry, iso_grid || r.iso_free), i);
        }
        for &i in &unique {
            if fate.contains_key(&i) {
                continue;
            }
            let r = requests[i];
            let rk = key(&r.geometry.reciprocal(), iso_grid || r.iso_free);
            let Some(&j) = by_key.get(&rk) else { continue };
            if j == i || fate.contains_key(&j) {
                continue;
            }
            let (vi, vj) = (verdict[&i].is_ok(), verdict[&j].is_ok());
            let keep_i = match (vi, vj) {
                (true, false) => true,
                (false, true) => false,
                (false, false) => continue,
                (true, true) => r.geometry.theta_i_deg <= requests[j].geometry.theta_i_deg,
            };
            let (keep, drop) = if keep_i { (i, j) } else { (j, i) };
            fate.insert(keep, Ok(()));
            fate.insert(drop, Err((keep, Reason::Reciprocity, true)));
        }
    }

    // 4. Assemble kept geometries in raster order and count the skips.
    let mut kept_index: HashMap<usize, usize> = HashMap::new();
    let mut kept: Vec<PlannedGeometry> = Vec::new();
    for &i in &unique {
        if matches!(fate.get(&i), Some(Err(_))) {
            continue;
        }
        if let Ok(c) = &verdict[&i] {
            kept_index.insert(i, kept.len());
            kept.push(PlannedGeometry {
                requested: requests[i].geometry,
                candidates: c.clone(),
            });
        }
    }
    let mut served = Vec::new();
    for (i, r) in requests.iter().enumerate() {
        // Resolve to the unique request standing for i.
        let (u, dup_reason) = match twin[i] {
            Some((j, reason)) => (j, Some(reason)),
            None => (i, None),
        };
        let (target, reciprocal, own_reason) = match fate.get(&u) {
            Some(Err((keep, reason, rec))) => (*keep, *rec, Some(*reason)),
            _ => (u, false, None),
        };
        let reason = match (kept_index.get(&target), dup_reason, own_reason) {
            (Some(_), None, None) => continue, // kept itself
            (Some(_), Some(d), _) => d,
            (Some(_), None, Some(o)) => o,
            (None, _, _) => match &verdict.get(&target) {
                Some(Err(reason)) => *reason,
                _ => Reason::Duplicate,
            },
        };
        *skipped.entry(reason).or_default() += n_bands;
        if let Some(&by) = kept_index.get(&target) {
            served.push(Served {
                requested: r.geometry,
                by,
                reciprocal,
                reason,
            });
        }
    }

    // 5. Spectrally flat materials: one band tells all.
    let bands_nm = if ctx.traits.spectrally_flat && n_bands > 1 {
        *skipped.entry(Reason::SpectrallyFlat).or_default() += kept.len() * (n_bands - 1);
        bands_all[..1].to_vec()
    } else {
        bands_all
    };

    Ok(Plan {
        geometries: kept,
        bands_nm,
        repeats: spec.repeats,
        requested: requests.len() * n_bands,
        skipped,
        served,
        calibration,
        anchor,
    })
}

/// Static constraints, then the axis solutions.
#[allow(clippy::too_many_arguments)]
fn solve(
    kin: &Kinematics,
    constraints: &Constraints,
    _time: &TimeModel,
    wi: &Direction,
    wo: &Direction,
    r: &Request,
    rotation_deg: f64,
    hint: &Pose,
) -> Result<Vec<(Pose, Geometry)>, Reason> {
    constraints.check_directions(wi, wo)?;
    let map = |e: KinematicsError| match e {
        KinematicsError::OutOfPlane { .. } => Reason::OutOfPlane,
        KinematicsError::AxisLimits { .. } => Reason::AxisLimits,
    };
    if r.iso_free {
        kin.isotropic_solutions(wi, wo, rotation_deg, hint).map_err(map)
    } else {
        let g = r.geometry;
        Ok(kin
            .solutions(wi, wo, hint)
            .map_err(map)?
            .into_iter()
            .map(|p| (p, g))
            .collect())
    }
}

/// The instrument's geometry kind, for messages.
pub fn geometry_kind_name(k: GeometryKind) -> &'static str {
    match k {
        GeometryKind::Reference => "reference",
        GeometryKind::InPlane => "in-plane",
    }
}
