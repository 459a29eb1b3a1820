//! What a person may ask of the console, and the rules a request must pass before anything moves. Pure: the
//! checks take the instrument file and the pose the axes are at, so each refusal can be tested without hardware.

use gonio_instrument::{Axis, Instrument, InstrumentFile};
use gonio_scheduler::constraints::{Constraints, Reason};
use gonio_scheduler::kinematics::{Geometry, Kinematics, Pose};

/// Why the console did not do what it was asked.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ConsoleError {
    /// The request breaks a rule of the instrument file: nothing moved. `rule` is the instrument file's key (or
    /// the rule's name) so that a person can look it up.
    #[error("refused by {rule}: {message}; nothing moved")]
    Refused { rule: String, message: String },
    /// The request names something the instrument does not have (an axis, a filter) or is malformed.
    #[error("{0}")]
    Invalid(String),
    /// The instrument's motion layer failed while doing it (a device's reason, an emergency stop).
    #[error("{0}")]
    Motion(String),
}

impl ConsoleError {
    fn refused(rule: &str, message: impl Into<String>) -> ConsoleError {
        ConsoleError::Refused {
            rule: rule.to_string(),
            message: message.into(),
        }
    }
}

/// Which filter to turn the wheel to.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum FilterChoice {
    /// A wheel position (1-based), as the instrument file numbers them.
    Position(u8),
    /// The position whose band is this centre wavelength (nm), within [`BAND_MATCH_NM`].
    BandNm(f64),
}

/// A band asked for by wavelength matches a filter whose centre is this close (nm).
pub const BAND_MATCH_NM: f64 = 0.5;

/// Parse a filter argument as the command line and the API take it: `3` is a position, `550nm` or `550.0` (any
/// number above the wheel's largest position) a band.
pub fn parse_filter_choice(text: &str) -> Result<FilterChoice, ConsoleError> {
    let t = text.trim();
    let (number, is_band) = match t.strip_suffix("nm") {
        Some(n) => (n.trim(), true),
        None => (t, false),
    };
    if !is_band && let Ok(p) = number.parse::<u8>() {
        return Ok(FilterChoice::Position(p));
    }
    match number.parse::<f64>() {
        Ok(nm) if nm.is_finite() && nm > 0.0 => Ok(FilterChoice::BandNm(nm)),
        _ => Err(ConsoleError::Invalid(format!(
            "filter {text:?}: expected a wheel position (1, 2, ...) or a band in nm (550nm)"
        ))),
    }
}

/// The wheel position `choice` names on this instrument.
pub fn filter_position(instrument: &Instrument, choice: FilterChoice) -> Result<u8, ConsoleError> {
    let Some(wheel) = &instrument.filter_wheel else {
        return Err(ConsoleError::Invalid(
            "this instrument has no filter wheel".into(),
        ));
    };
    let found = match choice {
        FilterChoice::Position(p) => wheel.positions.iter().find(|f| f.position == p),
        FilterChoice::BandNm(nm) => wheel
            .positions
            .iter()
            .find(|f| f.band_nm.is_some_and(|b| (b - nm).abs() <= BAND_MATCH_NM)),
    };
    match found {
        Some(f) => Ok(f.position),
        None => {
            let listed: Vec<String> = wheel
                .positions
                .iter()
                .map(|f| match f.band_nm {
                    Some(b) => format!("{} ({b} nm)", f.position),
                    None => format!("{} (blank)", f.position),
                })
                .collect();
            Err(ConsoleError::Invalid(format!(
                "no filter {} on the wheel; its positions: {}",
                match choice {
                    FilterChoice::Position(p) => format!("at position {p}"),
                    FilterChoice::BandNm(nm) => format!("for {nm} nm"),
                },
                listed.join(", ")
            )))
        }
    }
}

/// The axis of the instrument file named `name`.
pub fn axis_named<'f>(file: &'f InstrumentFile, name: &str) -> Result<&'f Axis, ConsoleError> {
    file.instrument
        .axes
        .iter()
        .find(|a| a.name == name)
        .ok_or_else(|| {
            let names: Vec<&str> = file.instrument.axes.iter().map(|a| a.name.as_str()).collect();
            ConsoleError::Invalid(format!(
                "no axis named {name:?}; the instrument's axes are {}",
                names.join(", ")
            ))
        })
}

/// The pose `current` with each named axis set to its target (physical degrees). Every target must be finite
/// and within the axis's travel (`min_deg`..`max_deg` of the instrument file).
pub fn target_pose(
    file: &InstrumentFile,
    current: &Pose,
    targets: &[(String, f64)],
) -> Result<Pose, ConsoleError> {
    if targets.is_empty() {
        return Err(ConsoleError::Invalid("no axis to move".into()));
    }
    let mut pose = *current;
    for (name, deg) in targets {
        let axis = axis_named(file, name)?;
        if !deg.is_finite() {
            return Err(ConsoleError::Invalid(format!("{name}: {deg} is not an angle")));
        }
        if *deg < axis.min_deg || *deg > axis.max_deg {
            let key = if *deg < axis.min_deg { "min_deg" } else { "max_deg" };
            return Err(ConsoleError::refused(
                &format!("axes.{name}.{key}"),
                format!(
                    "{name} to {deg} deg is outside its travel {} .. {} deg",
                    axis.min_deg, axis.max_deg
                ),
            ));
        }
        pose.set(axis.role, *deg);
    }
    check_separation(&file.instrument, &pose)?;
    Ok(pose)
}

/// The arms must keep `safety.min_arm_separation_deg` at the target (the motion layer keeps it along the way).
pub fn check_separation(instrument: &Instrument, pose: &Pose) -> Result<(), ConsoleError> {
    let constraints = Constraints::new(instrument, None);
    let separation = pose.arm_separation_deg();
    if constraints.separation_ok(separation) {
        Ok(())
    } else {
        Err(ConsoleError::refused(
            "safety.min_arm_separation_deg",
            format!(
                "the arms would be {separation:.3} deg apart at the target, closer than {} deg",
                instrument.safety.min_arm_separation_deg
            ),
        ))
    }
}

/// The poses that measure `geometry` (degrees, the sample's frame) through the instrument's kinematics, with the
/// arms apart, nearest to `current` first (smallest largest axis travel). The static rules of a campaign's points apply: above
/// the horizon, within `safety.grazing_limit_deg`, the beam on the sample and in the detector's field, clear of
/// `safety.retro_block_deg` and `safety.min_arm_separation_deg`.
pub fn geometry_poses(
    instrument: &Instrument,
    current: &Pose,
    geometry: &Geometry,
) -> Result<Vec<Pose>, ConsoleError> {
    for (what, deg) in [
        ("theta_i", geometry.theta_i_deg),
        ("phi_i", geometry.phi_i_deg),
        ("theta_o", geometry.theta_o_deg),
        ("phi_o", geometry.phi_o_deg),
    ] {
        if !deg.is_finite() {
            return Err(ConsoleError::Invalid(format!("{what}: {deg} is not an angle")));
        }
    }
    let (wi, wo) = geometry.directions();
    let constraints = Constraints::new(instrument, None);
    if let Err(reason) = constraints.check_directions(&wi, &wo) {
        return Err(ConsoleError::refused(
            rule_key(reason),
            format!("the geometry {}: {reason}", geometry_text(geometry)),
        ));
    }
    let kinematics = Kinematics::new(instrument);
    let solutions = kinematics
        .solutions(&wi, &wo, current)
        .map_err(|e| ConsoleError::refused("axes (min_deg, max_deg)", e.to_string()))?;
    let travel = |p: &Pose| -> f64 {
        [
            (p.light_deg - current.light_deg).abs(),
            (p.detector_deg - current.detector_deg).abs(),
            (p.tilt_deg - current.tilt_deg).abs(),
            (p.rotation_deg - current.rotation_deg).abs(),
        ]
        .into_iter()
        .fold(0.0, f64::max)
    };
    let mut poses: Vec<Pose> = solutions
        .into_iter()
        .filter(|p| check_separation(instrument, p).is_ok())
        .collect();
    poses.sort_by(|a, b| travel(a).total_cmp(&travel(b)));
    if poses.is_empty() {
        return Err(ConsoleError::refused(
            "safety.min_arm_separation_deg",
            format!(
                "every pose that measures {} brings the arms too close",
                geometry_text(geometry)
            ),
        ));
    }
    Ok(poses)
}

/// A geometry as a person reads it.
pub fn geometry_text(g: &Geometry) -> String {
    format!(
        "(theta_i {}, phi_i {}, theta_o {}, phi_o {}) deg",
        g.theta_i_deg, g.phi_i_deg, g.theta_o_deg, g.phi_o_deg
    )
}

/// The instrument file's key behind a static rule, so that a refusal names what a person can look up.
fn rule_key(reason: Reason) -> &'static str {
    match reason {
        Reason::GrazingLimit => "safety.grazing_limit_deg",
        Reason::RetroBlock => "safety.retro_block_deg",
        Reason::ArmSeparation => "safety.min_arm_separation_deg",
        Reason::SampleOverfill => "source.beam_radius_mm (the beam overfills the sample)",
        Reason::FieldOfViewOverfill => "detector.field_radius_mm (the spot leaves the detector's field)",
        Reason::AxisLimits => "axes (min_deg, max_deg)",
        other => other.name(),
    }
}

#[cfg(test)]
mod tests;
