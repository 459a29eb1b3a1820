//! What the instrument must not be asked to do, each rule with a name that skip reports use.
//!
//! Static rules depend on the geometry alone and are checked in this order (the first failing one is THE
//! reason a point is dropped): below-horizon, grazing-limit, sample-overfill, field-of-view-overfill,
//! retro-block, arm-separation; then the kinematic ones: out-of-plane, axis-limits. The arm separation is also
//! checked during every move, over the whole simultaneous trapezoidal motion (see `crate::timing`).
//!
//! The spot rules use the same shapes as the simulator's optics (all in the sample plane, centred): the beam
//! footprint `|p|^2 - (p . wi)^2 <= r_b^2` (an ellipse with semi-axes `r_b`, `r_b / cos theta_i`), the sample disc
//! of radius `R`, and the detector's field `|p|^2 - (p . wo)^2 <= r_f^2` (`field_radius_mm` is measured
//! perpendicular to the detector's axis). A centred ellipse `p^T A p <= 1` lies inside `p^T B p <= 1` iff
//! `A - B` is positive semi-definite, which for 2x2 matrices is `trace >= 0 and det >= 0`.

use std::fmt;

use gonio_brdf::geometry::Direction;
use gonio_instrument::Instrument;

/// Angles within this of a limit count as on it (rounding of degree <-> radian conversions).
pub const ANGLE_TOLERANCE_DEG: f64 = 1e-9;

/// Why a point is not measured (constraint rules and the plan's own reductions).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Reason {
    /// A direction at or below the sample's horizon.
    BelowHorizon,
    /// A direction beyond `safety.grazing_limit_deg`.
    GrazingLimit,
    /// The illuminated spot is larger than the sample.
    SampleOverfill,
    /// The illuminated spot is not inside the detector's field of view.
    FieldOfViewOverfill,
    /// The detector would be within `safety.retro_block_deg` of the source direction and block the beam.
    RetroBlock,
    /// The arms would come closer than `safety.min_arm_separation_deg`, at the point or during the move to it.
    ArmSeparation,
    /// The in-plane instrument cannot reach an out-of-plane geometry.
    OutOfPlane,
    /// Every axis solution lies outside some axis's limits.
    AxisLimits,
    /// Same geometry as another requested point (e.g. several phi at the pole).
    Duplicate,
    /// Equivalent to another point for an isotropic sample (same theta_i, theta_o, delta_phi).
    Isotropic,
    /// The reciprocal (source and detector exchanged) of a measured point.
    Reciprocity,
    /// A band the material declares spectrally flat: one band tells all.
    SpectrallyFlat,
}

impl Reason {
    /// The name used in summaries and reports.
    pub fn name(&self) -> &'static str {
        match self {
            Reason::BelowHorizon => "below-horizon",
            Reason::GrazingLimit => "grazing-limit",
            Reason::SampleOverfill => "sample-overfill",
            Reason::FieldOfViewOverfill => "field-of-view-overfill",
            Reason::RetroBlock => "retro-block",
            Reason::ArmSeparation => "arm-separation",
            Reason::OutOfPlane => "out-of-plane",
            Reason::AxisLimits => "axis-limits",
            Reason::Duplicate => "duplicate",
            Reason::Isotropic => "isotropic",
            Reason::Reciprocity => "reciprocity",
            Reason::SpectrallyFlat => "spectrally-flat",
        }
    }

    /// True for the reasons that mean "cannot be measured" rather than "need not be measured".
    pub fn is_constraint(&self) -> bool {
        !matches!(
            self,
            Reason::Duplicate | Reason::Isotropic | Reason::Reciprocity | Reason::SpectrallyFlat
        )
    }
}

impl fmt::Display for Reason {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.name())
    }
}

/// The numbers the rules use, from the instrument and the campaign's sample.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Constraints {
    pub min_arm_separation_deg: f64,
    pub retro_block_deg: f64,
    pub grazing_limit_deg: f64,
    pub beam_radius_mm: f64,
    pub sample_radius_mm: f64,
    pub field_radius_mm: f64,
}

impl Constraints {
    /// `sample_radius_mm`: the campaign's sample; the holder's maximum when not given.
    pub fn new(instrument: &Instrument, sample_radius_mm: Option<f64>) -> Constraints {
        Constraints {
            min_arm_separation_deg: instrument.safety.min_arm_separation_deg,
            retro_block_deg: instrument.safety.retro_block_deg,
            grazing_limit_deg: instrument.safety.grazing_limit_deg,
            beam_radius_mm: instrument.source.beam_radius_mm,
            sample_radius_mm: sample_radius_mm.unwrap_or(instrument.sample_holder.max_sample_radius_mm),
            field_radius_mm: instrument.detector.field_radius_mm,
        }
    }

    /// The static rules, in the documented order; `Err` names the first that fails.
    pub fn check_directions(&self, wi: &Direction, wo: &Direction) -> Result<(), Reason> {
        for w in [wi, wo] {
            if !w.is_above_horizon() {
                return Err(Reason::BelowHorizon);
            }
        }
        for w in [wi, wo] {
            if w.theta().to_degrees() > self.grazing_limit_deg + ANGLE_TOLERANCE_DEG {
                return Err(Reason::GrazingLimit);
            }
        }
        if !self.beam_inside_sample(wi) {
            return Err(Reason::SampleOverfill);
        }
        if !self.beam_inside_field(wi, wo) {
            return Err(Reason::FieldOfViewOverfill);
        }
        let separation_deg = wi.angle_to(wo).to_degrees();
        if separation_deg < self.retro_block_deg - ANGLE_TOLERANCE_DEG {
            return Err(Reason::RetroBlock);
        }
        if separation_deg < self.min_arm_separation_deg - ANGLE_TOLERANCE_DEG {
            return Err(Reason::ArmSeparation);
        }
        Ok(())
    }

    /// Largest semi-axis of the footprint, r_b / cos theta_i, within the sample radius.
    pub fn beam_inside_sample(&self, wi: &Direction) -> bool {
        self.beam_radius_mm <= self.sample_radius_mm * wi.cos_theta() * (1.0 + 1e-12)
    }

    /// The beam footprint ellipse inside the detector's field ellipse (Loewner order test, module doc).
    pub fn beam_inside_field(&self, wi: &Direction, wo: &Direction) -> bool {
        // A = (I - w w^T) / r_b^2, B = (I - u u^T) / r_f^2 with w, u the in-plane parts of wi, wo.
        let (a, b) = (
            1.0 / (self.beam_radius_mm * self.beam_radius_mm),
            1.0 / (self.field_radius_mm * self.field_radius_mm),
        );
        let m11 = a * (1.0 - wi.x() * wi.x()) - b * (1.0 - wo.x() * wo.x());
        let m22 = a * (1.0 - wi.y() * wi.y()) - b * (1.0 - wo.y() * wo.y());
        let m12 = -a * wi.x() * wi.y() + b * wo.x() * wo.y();
        let scale = a.max(b);
        let tol = 1e-12 * scale;
        m11 + m22 >= -tol && m11 * m22 - m12 * m12 >= -tol * scale
    }

    /// The arm separation at a pose (physical degrees), with the shared tolerance.
    pub fn separation_ok(&self, separation_deg: f64) -> bool {
        separation_deg >= self.min_arm_separation_deg - ANGLE_TOLERANCE_DEG
    }
}
