//! Building a [`Plan`] from a spec: bands and calibration checked against the instrument, then every requested
//! geometry reduced (duplicates, isotropy, reciprocity, flat bands, constraints) and solved to axis poses.

use std::collections::{BTreeMap, HashMap};

use gonio_brdf::geometry::Direction;
use gonio_instrument::{AxisRole, GeometryKind, Instrument};

use super::grid::{Request, key, requests};
use super::{
    Calibration, CalibrationSpec, DEFAULT_DIRECT_BEAM_POSE, MAX_PLANNED_READINGS, Plan, PlanError, PlanSpec,
    PlannedGeometry, ReferenceAt, SampleTraits, Served, invalid,
};
use crate::constraints::{Constraints, Reason};
use crate::kinematics::{Geometry, Kinematics, KinematicsError, Pose};
use crate::timing::TimeModel;

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

/// The bands the sweeps are swept in: `[plan] sweep_bands_nm`, each among `requested` (the plan's
/// `bands_nm`, [`plan_bands`]), or all of `measured` without it. `measured`: the bands the plan measures, which
/// for a spectrally flat sample is one (step 5 of [`build`]: the sweeps' first): the sweeps keep those of their
/// bands the points measure, so that every swept band is normalised.
pub fn sweep_bands(spec: &PlanSpec, requested: &[f64], measured: &[f64]) -> Result<Vec<f64>, PlanError> {
    let Some(list) = &spec.sweep_bands_nm else {
        return Ok(measured.to_vec());
    };
    if list.is_empty() {
        return Err(invalid("", "sweep_bands_nm", "expected at least one band"));
    }
    let mut out: Vec<f64> = Vec::new();
    for b in list {
        if !requested.iter().any(|a| (a - b).abs() <= 1e-6) {
            return Err(invalid(
                "",
                "sweep_bands_nm",
                format!("{b} nm is not among the bands the plan measures, {requested:?}"),
            ));
        }
        if out.iter().any(|o| (o - b).abs() <= 1e-6) {
            return Err(invalid("", "sweep_bands_nm", format!("{b} nm is listed twice")));
        }
        out.push(*b);
    }
    out.retain(|b| measured.iter().any(|a| (a - b).abs() <= 1e-6));
    if out.is_empty() {
        return Err(invalid(
            "",
            "sweep_bands_nm",
            format!("none of {list:?} nm is among the bands the plan measures, {measured:?}"),
        ));
    }
    Ok(out)
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
        reference_at: None,
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
    if let Some(geometry) = spec.reference_geometry {
        // The relative method: no direct-beam pose to validate (the campaign loader refuses one).
        cal.reference_at = Some(ReferenceAt {
            geometry,
            kinematics: Kinematics::new(instrument),
        });
        return Ok(cal);
    }
    // The default direct-beam pose: checked against the limits when the plan asks for normalisation readings;
    // otherwise only the preamble that opens every start reads there, and it is taken when the arms can reach it
    // (an instrument whose arms cannot has no default direct-beam pose: `Calibration::preamble_target`).
    let d = DEFAULT_DIRECT_BEAM_POSE;
    let arms = [
        (AxisRole::LightArm, d.light_deg),
        (AxisRole::DetectorArm, d.detector_deg),
    ];
    let stage = [
        (AxisRole::SampleTilt, d.tilt_deg),
        (AxisRole::SampleRotation, d.rotation_deg),
    ];
    // The instrument's axes among `roles`, by name, at their default angles.
    let named = |roles: &[(AxisRole, f64)]| -> BTreeMap<String, f64> {
        roles
            .iter()
            .filter_map(|(role, v)| instrument.axis(*role).map(|a| (a.name.clone(), *v)))
            .collect()
    };
    let pose = match &spec.reference_pose_deg {
        Some(p) => p.clone(),
        None if cal.references() => named(&arms),
        None => {
            // The whole default pose, the stage's axes included, as the engine has always moved there.
            let m = named(&[arms, stage].concat());
            let reachable = named(&arms).len() == 2
                && m.iter().all(|(name, v)| {
                    instrument
                        .axes
                        .iter()
                        .any(|a| &a.name == name && (a.min_deg..=a.max_deg).contains(v))
                });
            if reachable { m } else { BTreeMap::new() }
        }
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

    // Anchor: the start pose, else the direct-beam pose fixes which side each arm is on. (A relative method's
    // reference geometry has poses on both sides: the side that keeps more points is chosen, and the reference is
    // then read from that side.)
    let default_hint = Pose::new(0.0, 0.0, 0.0, spec.rotation_deg);
    let anchor = ctx.start.or_else(|| {
        (calibration.references() && calibration.reference_at.is_none())
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

    // 5. Spectrally flat materials: one band tells all; the sweeps' first band when they name theirs (the
    //    sweeps are normalised with the points' bands).
    let bands_nm = if ctx.traits.spectrally_flat && n_bands > 1 {
        *skipped.entry(Reason::SpectrallyFlat).or_default() += kept.len() * (n_bands - 1);
        let swept = spec
            .sweep_bands_nm
            .as_ref()
            .and_then(|s| s.first())
            .and_then(|b| bands_all.iter().position(|a| (a - b).abs() <= 1e-6))
            .unwrap_or(0);
        vec![bands_all[swept]]
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
