//! `[[plan.sweeps]]` as written in a campaign file, and its validation into one request per swept arc.

use crate::kinematics::Geometry;
use crate::plan::{FollowSpec, PlanError, SweepSpec, SweptArm, angle_list};

/// Sweeps a plan may request at most (held angles x planes, all entries together): each is a few seconds to a
/// few minutes of instrument time, so this is far beyond any campaign and keeps a submitted file from asking
/// the path check for unbounded work.
pub const MAX_SWEEPS: usize = 10_000;

/// Pieces shorter than this are not swept (degrees): they hold too few readings to be worth a move.
pub const MIN_PIECE_DEG: f64 = 0.1;

/// The fastest sweep speed accepted (deg/s) whatever the axis allows: beyond it a reading of a few milliseconds
/// smears over degrees.
pub const MAX_SWEEP_SPEED_DEG_S: f64 = 100.0;

/// One arc to sweep, before the path check: a held angle in one plane and the signed range of the swept angle.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SweepRequest {
    /// Index of the `[[plan.sweeps]]` entry it comes from.
    pub entry: usize,
    pub arm: SweptArm,
    /// theta_i (detector sweeps) or theta_o (light sweeps), degrees in [0, 90).
    pub held_deg: f64,
    pub plane_phi_deg: f64,
    /// The swept angle's range, signed (module doc of `crate::sweep`), `from < to`.
    pub from_deg: f64,
    pub to_deg: f64,
    pub speed_deg_s: f64,
    pub averaging: u32,
    /// The sample is declared isotropic (`isotropic = true`): the path check may measure stretches of the arc
    /// turned half a turn about the normal ([`SweepRequest::turned`]).
    pub isotropic: bool,
}

impl SweepRequest {
    /// The same arc turned half a turn about the sample normal (its plane's azimuth + 180 degrees): every swept
    /// angle keeps its theta_i, theta_o and the azimuths' difference, so on an isotropic sample it measures the
    /// same BRDF values.
    pub fn turned(&self) -> SweepRequest {
        let p = self.plane_phi_deg + 180.0;
        SweepRequest {
            plane_phi_deg: if p >= 180.0 { p - 360.0 } else { p },
            ..*self
        }
    }

    /// [`SweepRequest::turned`] when `turned`, else the request itself.
    pub fn turned_if(&self, turned: bool) -> SweepRequest {
        if turned { self.turned() } else { *self }
    }

    /// The geometry at signed swept angle `s` (degrees): the in-plane convention of `[plan.grid] kind =
    /// "in-plane"`. Detector sweeps: `s > 0` on the specular side (phi_o = plane + 180), `s < 0` on the source's
    /// side (phi_o = plane). Light sweeps: the detector held at phi_o = plane + 180; `s > 0` puts the source
    /// opposite it (phi_i = plane, the specular arrangement at s = theta_o), `s < 0` on its side.
    pub fn geometry_at(&self, s: f64) -> Geometry {
        let (p, back) = (self.plane_phi_deg, self.plane_phi_deg + 180.0);
        match self.arm {
            SweptArm::Detector => {
                if s >= 0.0 {
                    Geometry::new(self.held_deg, p, s, back)
                } else {
                    Geometry::new(self.held_deg, p, -s, p)
                }
            }
            SweptArm::Light => {
                if s >= 0.0 {
                    Geometry::new(s, p, self.held_deg, back)
                } else {
                    Geometry::new(-s, back, self.held_deg, back)
                }
            }
        }
    }

    /// Length of the requested arc (degrees).
    pub fn length_deg(&self) -> f64 {
        self.to_deg - self.from_deg
    }
}

fn invalid(entry: usize, key: &str, message: impl Into<String>) -> PlanError {
    PlanError::Invalid {
        table: format!(".sweeps #{}", entry + 1),
        key: key.to_string(),
        message: message.into(),
    }
}

/// The swept arc `{ from, to }` (signed degrees, within (-90, 90)).
fn arc(entry: usize, key: &str, value: &toml::Value) -> Result<(f64, f64), PlanError> {
    let num = |v: &toml::Value| v.as_float().or_else(|| v.as_integer().map(|i| i as f64));
    let toml::Value::Table(t) = value else {
        return Err(invalid(
            entry,
            key,
            "the swept angle is an arc { from, to } (signed degrees)",
        ));
    };
    if let Some(k) = t.keys().find(|k| !["from", "to"].contains(&k.as_str())) {
        return Err(invalid(
            entry,
            key,
            format!("unknown key {k:?} in the swept arc, expected from and to"),
        ));
    }
    let get = |k: &str| {
        t.get(k)
            .and_then(num)
            .ok_or_else(|| invalid(entry, key, format!("the swept arc needs a number `{k}`")))
    };
    let (from, to) = (get("from")?, get("to")?);
    if !(from.is_finite() && to.is_finite() && from < to && from > -90.0 && to < 90.0) {
        return Err(invalid(
            entry,
            key,
            format!("expected -90 < from < to < 90 degrees, got from = {from}, to = {to}"),
        ));
    }
    Ok((from, to))
}

/// `follow = { ... }` within its bounds (`speed_deg_s` is the top speed).
fn check_follow(entry: usize, f: &FollowSpec, top_deg_s: f64) -> Result<(), PlanError> {
    let bad = |what: &str, expected: &str, got: f64| {
        invalid(entry, "follow", format!("{what}: expected {expected}, got {got}"))
    };
    if f.first_pass.trim().is_empty() {
        return Err(invalid(
            entry,
            "follow",
            "first_pass: expected the sweeps.csv of an earlier run (or its directory)",
        ));
    }
    if !(f.tolerance_rel.is_finite() && f.tolerance_rel > 0.0 && f.tolerance_rel <= 0.5) {
        return Err(bad(
            "tolerance_rel",
            "a relative smearing in (0, 0.5]",
            f.tolerance_rel,
        ));
    }
    if let Some(v) = f.min_speed_deg_s
        && !(v.is_finite() && v > 0.0 && v <= top_deg_s)
    {
        return Err(bad(
            "min_speed_deg_s",
            &format!("deg/s in (0, {top_deg_s}] (speed_deg_s)"),
            v,
        ));
    }
    if let Some(d) = f.min_piece_deg
        && !(d.is_finite() && (MIN_PIECE_DEG..=90.0).contains(&d))
    {
        return Err(bad(
            "min_piece_deg",
            &format!("degrees in [{MIN_PIECE_DEG}, 90]"),
            d,
        ));
    }
    if let Some(d) = f.resolution_deg
        && !(d.is_finite() && (0.05..=5.0).contains(&d))
    {
        return Err(bad("resolution_deg", "degrees in [0.05, 5]", d));
    }
    Ok(())
}

/// Validate every entry and expand it into one request per (plane, held angle), in file order.
pub fn requests(
    specs: &[SweepSpec],
    max_speed_deg_s: impl Fn(SweptArm) -> Option<f64>,
) -> Result<Vec<SweepRequest>, PlanError> {
    let mut out = Vec::new();
    for (entry, spec) in specs.iter().enumerate() {
        let (held_key, swept_key, held_value, swept_value) = match spec.arm {
            SweptArm::Detector => ("theta_i_deg", "theta_o_deg", &spec.theta_i_deg, &spec.theta_o_deg),
            SweptArm::Light => ("theta_o_deg", "theta_i_deg", &spec.theta_o_deg, &spec.theta_i_deg),
        };
        let table = format!("sweeps #{}", entry + 1);
        let held = angle_list(&table, held_key, held_value)?;
        if let Some(h) = held.iter().find(|h| !(h.is_finite() && (0.0..90.0).contains(*h))) {
            return Err(invalid(
                entry,
                held_key,
                format!("expected degrees in [0, 90), got {h}"),
            ));
        }
        let (from, to) = arc(entry, swept_key, swept_value)?;
        let planes = match &spec.plane_phi_deg {
            Some(v) => angle_list(&table, "plane_phi_deg", v)?,
            None => vec![0.0],
        };
        if let Some(p) = planes.iter().find(|p| !p.is_finite()) {
            return Err(invalid(
                entry,
                "plane_phi_deg",
                format!("expected degrees, got {p}"),
            ));
        }
        let top = max_speed_deg_s(spec.arm).ok_or_else(|| {
            invalid(
                entry,
                "arm",
                format!("the instrument has no {} arm axis to sweep", spec.arm.name()),
            )
        })?;
        let limit = top.min(MAX_SWEEP_SPEED_DEG_S);
        if !(spec.speed_deg_s.is_finite() && spec.speed_deg_s > 0.0 && spec.speed_deg_s <= limit) {
            return Err(invalid(
                entry,
                "speed_deg_s",
                format!(
                    "expected deg/s in (0, {limit}] (the {} arm's max_speed_deg_s, at most {MAX_SWEEP_SPEED_DEG_S}), got {}",
                    spec.arm.name(),
                    spec.speed_deg_s
                ),
            ));
        }
        if let Some(f) = &spec.follow {
            check_follow(entry, f, spec.speed_deg_s)?;
        }
        if !(1..=10_000).contains(&spec.averaging) {
            return Err(invalid(
                entry,
                "averaging",
                format!("expected 1 to 10000 samples, got {}", spec.averaging),
            ));
        }
        for plane in &planes {
            for h in &held {
                if out.len() == MAX_SWEEPS {
                    return Err(invalid(
                        entry,
                        held_key,
                        format!("the sweeps ask for more than {MAX_SWEEPS} arcs"),
                    ));
                }
                out.push(SweepRequest {
                    entry,
                    arm: spec.arm,
                    held_deg: *h,
                    plane_phi_deg: *plane,
                    from_deg: from,
                    to_deg: to,
                    speed_deg_s: spec.speed_deg_s,
                    averaging: spec.averaging,
                    isotropic: spec.isotropic,
                });
            }
        }
    }
    Ok(out)
}
