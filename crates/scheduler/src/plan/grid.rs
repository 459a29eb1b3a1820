//! Grid expansion: a `[plan.grid]` (ranges or lists of angles, or explicit points) into the requested geometries,
//! with the size and range checks that keep a submitted file from enumerating an unbounded grid.

use super::{GridKind, GridSpec, MAX_GRID_GEOMETRIES, PlanError, invalid};
use crate::kinematics::Geometry;

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
pub(super) struct Request {
    pub(super) geometry: Geometry,
    pub(super) iso_free: bool,
}

/// The geometries a grid asks for, in raster order; `isotropic_request` tells whether the grid is expressed in
/// (theta_i, theta_o, delta_phi).
pub(super) fn requests(grid: &GridSpec) -> Result<(Vec<Geometry>, bool), PlanError> {
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
pub(super) fn key(g: &Geometry, isotropic: bool) -> (i64, i64, i64, i64) {
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
