//! The positioning component. A point is stored at its nominal geometry, but the axes stop where their
//! controllers put them: within the arrival tolerance, on the stage's step grid (a tilt stage of 1/64 degree
//! steps cannot stop at every hundredth). The read-back pose says where they stopped; through the kinematics
//! (or the calibrated model, when an alignment is applied) it gives the directions the point really measured.
//! The model fitted to the campaign (gonio_results::aperture) evaluated there and at the nominal geometry gives
//! the bias that leaves, with the absolute equation's cos(theta_o), divided by at the nominal angle. The value
//! is corrected by that ratio (crate::budget's completion), and [`U_OF_CORRECTION`] of the correction is the
//! `positioning` component: the ratio is only as good as the model's slope there. In the fault soak on the
//! ideal instrument (2,000 random geometries on the coloured plastic, seed 8), the three points the tilt
//! stage's 1/64 degree steps moved by more than 0.02 % were off their truth by 0.99, 0.99 and 0.76 times the
//! ratio, 5 to 6 of their standard uncertainties before this correction.

use gonio_brdf::{Brdf, Direction, Material, Wavelength};
use gonio_instrument::{AxisRole, Instrument};
use gonio_scheduler::kinematics::{Kinematics, Pose};

use crate::align::correction::PoseCorrection;
use crate::store::{CampaignRecord, PointRecord};

/// The correction's standard uncertainty, as a fraction of it (module doc).
pub(super) const U_OF_CORRECTION: f64 = 0.25;
/// Largest relative correction made (a tenth): beyond it the read-back is not a small error of pointing (a
/// point measured elsewhere), and the model's ratio is no honest correction.
pub(super) const MAX_REL_CORRECTION: f64 = 0.1;

/// Where a campaign's instrument really pointed: the kinematics, the applied alignment's model, and which axis
/// plays which role.
pub(super) struct Pointed {
    kinematics: Kinematics,
    correction: Option<PoseCorrection>,
    roles: Vec<(String, AxisRole)>,
}

impl Pointed {
    pub(super) fn new(record: &CampaignRecord, instrument: &Instrument) -> Pointed {
        let correction = record.alignment_toml.as_deref().and_then(|text| {
            crate::align::file::CalibrationFile::parse(text, "the stored alignment")
                .ok()
                .map(|cal| PoseCorrection::new(instrument, cal.params()))
        });
        Pointed {
            kinematics: Kinematics::new(instrument),
            correction,
            roles: instrument.axes.iter().map(|a| (a.name.clone(), a.role)).collect(),
        }
    }

    /// The sample-frame directions towards the source and the detector at `p`'s read-back pose; `None` without
    /// a read-back of both arms.
    pub(super) fn directions(&self, p: &PointRecord) -> Option<(Direction, Direction)> {
        let mut pose = Pose::new(0.0, 0.0, 0.0, 0.0);
        let mut arms = 0;
        for (name, value) in &p.readback_deg {
            let (_, role) = self.roles.iter().find(|(n, _)| n == name)?;
            if !value.is_finite() {
                return None;
            }
            arms += usize::from(matches!(role, AxisRole::LightArm | AxisRole::DetectorArm));
            pose.set(*role, *value);
        }
        if arms < 2 {
            return None;
        }
        match &self.correction {
            Some(c) => c.directions(&pose),
            None => Some(self.kinematics.forward(&pose)),
        }
    }

    /// The relative change of `p`'s value between its nominal geometry and where the instrument pointed, by
    /// `model`; `absolute`: the value was divided by the nominal cos(theta_o) (the direct-beam equation), so
    /// the detector's real angle enters through its cosine too.
    pub(super) fn relative_deviation(
        &self,
        model: &Material,
        p: &PointRecord,
        absolute: bool,
    ) -> Option<f64> {
        let (wi, wo) = self.directions(p)?;
        let wavelength = Wavelength::from_nm(p.band_nm).ok()?;
        let nominal_i = Direction::from_spherical_deg(p.theta_i_deg, p.phi_i_deg);
        let nominal_o = Direction::from_spherical_deg(p.theta_o_deg, p.phi_o_deg);
        let at_nominal = model.eval(&nominal_i, &nominal_o, wavelength).ok()?;
        let there = model.eval(&wi, &wo, wavelength).ok()?;
        if !(at_nominal > 0.0 && at_nominal.is_finite() && there.is_finite()) {
            return None;
        }
        let cosine = if absolute {
            wo.z() / p.theta_o_deg.to_radians().cos()
        } else {
            1.0
        };
        let rel = there * cosine / at_nominal - 1.0;
        rel.is_finite().then_some(rel)
    }
}
