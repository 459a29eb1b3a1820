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
use crate::align::model::{GeometryParams, PARAM_NAMES};
use crate::store::PointRecord;

/// The correction's standard uncertainty, as a fraction of it (module doc).
pub(super) const U_OF_CORRECTION: f64 = 0.25;
/// Largest relative correction made (a tenth): beyond it the read-back is not a small error of pointing (a
/// point measured elsewhere), and the model's ratio is no honest correction.
pub(super) const MAX_REL_CORRECTION: f64 = 0.1;

/// Where a campaign's instrument really pointed: the kinematics, the applied alignment's model, and which axis
/// plays which role.
pub(super) struct Pointed {
    kinematics: Kinematics,
    /// Whether an alignment was applied: `base` is then its model, the directions the values stand for.
    aligned: bool,
    /// The model the uncertainties are propagated through: the applied alignment's, else the nominal one.
    base: PoseCorrection,
    /// The applied alignment's model with one parameter moved by its standard uncertainty, one per parameter
    /// the alignment measured, with the parameter's name; without an alignment the nominal model moved by the
    /// instrument file's priors ([`Pointed::pointing_shifts`]).
    perturbed: Vec<(&'static str, PoseCorrection)>,
    /// The base model with the sample's tilt moved by the holder's re-seating uncertainty, one per tilt
    /// component ([`Pointed::reseat_shifts`]); empty when the file states a holder that repeats exactly.
    reseated: Vec<(&'static str, PoseCorrection)>,
    roles: Vec<(String, AxisRole)>,
}

impl Pointed {
    /// `alignment_toml`: the calibration applied to the campaign (`gonio align`'s file), if one was.
    pub(super) fn new(alignment_toml: Option<&str>, instrument: &Instrument) -> Pointed {
        let cal = alignment_toml
            .and_then(|text| crate::align::file::CalibrationFile::parse(text, "the stored alignment").ok());
        let params = cal.as_ref().map(|c| c.params(instrument)).unwrap_or_default();
        let moved = |k: usize, by: f64| {
            let mut x = params.to_vec();
            x[k] += by;
            (
                PARAM_NAMES[k].0,
                PoseCorrection::new(instrument, GeometryParams::from_slice(&x)),
            )
        };
        // An alignment's uncertainties, else what the instrument file says the geometry is uncertain by before
        // one (crate::align::priors), each parameter moved from its nominal 0.
        let perturbed = match &cal {
            Some(c) => c
                .perturbations(instrument)
                .into_iter()
                .map(|(name, p)| (name, PoseCorrection::new(instrument, p)))
                .collect(),
            None => {
                let prior = crate::align::priors::prior_u(instrument);
                (0..prior.len())
                    .filter(|&k| prior[k] > 0.0 && prior[k].is_finite())
                    .map(|k| moved(k, prior[k]))
                    .collect()
            }
        };
        let reseat_u = instrument.sample_holder.reseat_u_deg();
        let reseated = if reseat_u > 0.0 && reseat_u.is_finite() {
            ["sample_tilt_x_deg", "sample_tilt_y_deg"]
                .iter()
                .filter_map(|name| PARAM_NAMES.iter().position(|(n, _)| n == name))
                .map(|k| moved(k, reseat_u))
                .collect()
        } else {
            Vec::new()
        };
        Pointed {
            kinematics: Kinematics::new(instrument),
            aligned: cal.is_some(),
            base: PoseCorrection::new(instrument, params),
            perturbed,
            reseated,
            roles: instrument.axes.iter().map(|a| (a.name.clone(), a.role)).collect(),
        }
    }

    /// Whether there are geometric uncertainties for [`Pointed::pointing_shifts`] to propagate: an applied
    /// alignment's, or the instrument file's priors without one.
    pub(super) fn has_pointing_u(&self) -> bool {
        !self.perturbed.is_empty()
    }

    /// What the geometry's uncertainty does to `p`'s value, parameter by parameter: each parameter of the
    /// applied alignment (or, without one, of the nominal geometry, by the instrument file's priors:
    /// crate::align::priors) moved by its standard uncertainty, the signed relative change of `model`'s value
    /// (with the absolute equation's cos(theta_o) when `absolute`) between the directions the model gives at
    /// the read-back pose with and without the move, with the parameter's name. Each moves only the angles it
    /// acts on, where one angle uncertainty for every angle (their root sum of squares) counted them all on
    /// each. One parameter's error is the same for every point of the campaign, so the sign matters: it says
    /// which way that error moves this point against the others (crate::budget's shared components; a fit
    /// propagates them). The parameters are taken as independent of each other (the calibration file keeps no
    /// covariance). `None` without a read-back or a model value.
    pub(super) fn pointing_shifts(
        &self,
        model: &Material,
        p: &PointRecord,
        absolute: bool,
    ) -> Option<Vec<(&'static str, f64)>> {
        self.shifts_through(&self.perturbed, model, p, absolute)
    }

    /// What the sample's re-seating does to `p`'s value: its tilt moved by the holder's repeatability
    /// (`[instrument.sample_holder] reseat_u_deg`), one component at a time, as [`Pointed::pointing_shifts`]
    /// moves the alignment's parameters (signed; shared by one mounting's points: super::complete::mountings).
    /// `None` for a holder that repeats exactly, without a read-back or a model value.
    pub(super) fn reseat_shifts(
        &self,
        model: &Material,
        p: &PointRecord,
        absolute: bool,
    ) -> Option<Vec<(&'static str, f64)>> {
        if self.reseated.is_empty() {
            return None;
        }
        self.shifts_through(&self.reseated, model, p, absolute)
    }

    /// `model`'s signed relative change at `p`'s read-back pose from the base model's directions to each of
    /// `moved`'s, with its name.
    fn shifts_through(
        &self,
        moved: &[(&'static str, PoseCorrection)],
        model: &Material,
        p: &PointRecord,
        absolute: bool,
    ) -> Option<Vec<(&'static str, f64)>> {
        self.shifts_at(moved, model, &self.pose(p)?, p.band_nm, absolute)
    }

    /// The geometry's uncertainty and the holder's re-seating, every parameter of both, through `model` at
    /// `pose` in band `band_nm` (as [`Pointed::pointing_shifts`] and [`Pointed::reseat_shifts`] for a point):
    /// for a sweep reading, whose pose is the one the nominal geometry asks for ([`Pointed::pose_for`]).
    pub(super) fn all_shifts_at(
        &self,
        model: &Material,
        pose: &Pose,
        band_nm: f64,
        absolute: bool,
    ) -> Option<Vec<(&'static str, f64)>> {
        let mut out = self.shifts_at(&self.perturbed, model, pose, band_nm, absolute)?;
        if !self.reseated.is_empty() {
            out.extend(self.shifts_at(&self.reseated, model, pose, band_nm, absolute)?);
        }
        Some(out)
    }

    /// The pose that measures `(wi, wo)` on the nominal geometry (the first solution within the axes' limits,
    /// the arms' branch nearest the rest pose); `None` where none does.
    pub(super) fn pose_for(&self, wi: &Direction, wo: &Direction) -> Option<Pose> {
        let rest = Pose::new(0.0, 0.0, 0.0, 0.0);
        self.kinematics.solutions(wi, wo, &rest).ok()?.into_iter().next()
    }

    fn shifts_at(
        &self,
        moved: &[(&'static str, PoseCorrection)],
        model: &Material,
        pose: &Pose,
        band_nm: f64,
        absolute: bool,
    ) -> Option<Vec<(&'static str, f64)>> {
        let wavelength = Wavelength::from_nm(band_nm).ok()?;
        let (wi, wo) = self.base.directions(pose)?;
        let weighted = |wi: &Direction, wo: &Direction| -> Option<f64> {
            let f = model.eval(wi, wo, wavelength).ok()?;
            let v = if absolute { f * wo.z() } else { f };
            v.is_finite().then_some(v)
        };
        let at = weighted(&wi, &wo).filter(|v| *v > 0.0)?;
        moved
            .iter()
            .map(|(name, c)| {
                let (wi_k, wo_k) = c.directions(pose)?;
                Some((*name, weighted(&wi_k, &wo_k)? / at - 1.0))
            })
            .collect()
    }

    /// The sample-frame directions towards the source and the detector at `p`'s read-back pose; `None` without
    /// a read-back of both arms.
    pub(super) fn directions(&self, p: &PointRecord) -> Option<(Direction, Direction)> {
        let pose = self.pose(p)?;
        if self.aligned {
            self.base.directions(&pose)
        } else {
            Some(self.kinematics.forward(&pose))
        }
    }

    /// `p`'s read-back pose; `None` without a read-back of both arms.
    fn pose(&self, p: &PointRecord) -> Option<Pose> {
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
        (arms >= 2).then_some(pose)
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

#[cfg(test)]
mod tests {
    use super::*;

    fn lambertian() -> Material {
        Material::from_document(
            "[material]\nmodel = \"lambertian\"\nalbedo = 0.8",
            "test",
            std::path::Path::new("."),
        )
        .expect("valid material")
    }

    /// A calibration whose only measured parameter is the detector arm's zero: 0 +- `u_deg`.
    fn calibration(u_deg: f64) -> String {
        format!(
            "[calibration]\ninstrument = \"simulated.toml\"\ninstrument_sha256 = \"0\"\nsoftware = \"test\"\n\
             created_utc = \"2026-12-05T00:00:00Z\"\ndry_run = true\nmethod = \"test\"\n\n[[values]]\n\
             name = \"detector_zero_deg\"\nvalue = 0.0\nu = {u_deg}\nunit = \"deg\"\nobservable = true\n"
        )
    }

    fn point_at(pose: &Pose, instrument: &Instrument) -> PointRecord {
        let role = |r: AxisRole| {
            let a = instrument.axes.iter().find(|a| a.role == r).expect("axis");
            (a.name.clone(), pose.get(r))
        };
        PointRecord {
            readback_deg: [
                AxisRole::LightArm,
                AxisRole::DetectorArm,
                AxisRole::SampleTilt,
                AxisRole::SampleRotation,
            ]
            .map(role)
            .to_vec(),
            ..super::super::drift::tests::point_at(0.0, 550.0)
        }
    }

    #[test]
    fn an_alignments_detector_zero_moves_a_diffuse_value_by_tan_theta_o() {
        let instrument = gonio_instrument::InstrumentFile::simulated().instrument;
        let u_deg = 0.01;
        let text = calibration(u_deg);
        let pointed = Pointed::new(Some(&text), &instrument);
        assert!(pointed.has_pointing_u());
        let mut signs = Vec::new();
        for pose in [Pose::new(-30.0, 60.0, 0.0, 0.0), Pose::new(-20.0, 75.0, 0.0, 0.0)] {
            let p = point_at(&pose, &instrument);
            let (_, wo) = pointed.directions(&p).expect("directions");
            let theta_o = wo.z().acos();
            // A Lambertian value read by the absolute equation moves only through the detector's cosine.
            let expected = theta_o.tan() * u_deg.to_radians();
            let shifts = pointed
                .pointing_shifts(&lambertian(), &p, true)
                .expect("propagated");
            // The one parameter the file measured, by name, signed: the same error moves every point with the
            // detector on this side the same way.
            assert_eq!(shifts.len(), 1, "{shifts:?}");
            let (name, rel) = shifts[0];
            assert_eq!(name, "detector_zero_deg");
            assert!(rel != 0.0);
            assert!(
                (rel.abs() - expected).abs() < 0.01 * expected,
                "{rel} vs {expected}"
            );
            signs.push(rel.signum());
            // Normalised by a reference at the same geometry, the cosine cancels: nothing moves it.
            let relative = pointed
                .pointing_shifts(&lambertian(), &p, false)
                .expect("propagated");
            assert!(relative[0].1.abs() < 1e-9, "{relative:?}");
        }
        assert_eq!(
            signs[0], signs[1],
            "one detector zero moves both values the same way"
        );
        // Without an applied alignment the file's priors move the nominal geometry (crate::align::priors): the
        // detector's zero by alignment_u_deg, the sample's tilt and centring, the beam, each by name. (The ideal
        // file states none: give it a lab's.)
        let mut instrument = instrument;
        instrument.alignment_u_deg = Some(0.05);
        instrument.source.offset_u_mm = Some(0.07);
        instrument.sample_holder.centring_u_mm = Some(0.1);
        let none = Pointed::new(None, &instrument);
        assert!(none.has_pointing_u());
        let pose = Pose::new(-30.0, 60.0, 0.0, 0.0);
        let p = point_at(&pose, &instrument);
        let shifts = none.pointing_shifts(&lambertian(), &p, true).expect("priors");
        let names: Vec<&str> = shifts.iter().map(|(n, _)| *n).collect();
        for name in [
            "beam_deg",
            "detector_zero_deg",
            "sample_tilt_x_deg",
            "eccentricity_x_mm",
        ] {
            assert!(names.contains(&name), "{name} in {names:?}");
        }
        let (_, wo) = none.directions(&p).expect("directions");
        let expected = wo.z().acos().tan() * instrument.alignment_u_deg().to_radians();
        let (_, zero) = shifts
            .iter()
            .find(|(n, _)| *n == "detector_zero_deg")
            .expect("the zero");
        assert!(
            (zero.abs() - expected).abs() < 0.01 * expected,
            "{zero} vs {expected}"
        );
        // This file's holder repeats exactly.
        assert_eq!(none.reseat_shifts(&lambertian(), &p, true), None);
        // The ideal file's own priors are all 0: nothing to propagate.
        let ideal = gonio_instrument::InstrumentFile::simulated().instrument;
        assert!(!Pointed::new(None, &ideal).has_pointing_u());
    }

    #[test]
    fn a_reseated_sample_tilts_a_diffuse_value_by_tan_theta_o() {
        let mut instrument = gonio_instrument::InstrumentFile::simulated().instrument;
        let u_deg = 0.01;
        instrument.sample_holder.reseat_u_deg = Some(u_deg);
        let pointed = Pointed::new(None, &instrument);
        for pose in [Pose::new(-30.0, 60.0, 0.0, 0.0), Pose::new(-10.0, 40.0, 0.0, 0.0)] {
            let p = point_at(&pose, &instrument);
            let (_, wo) = pointed.directions(&p).expect("directions");
            // A tilt in the plane of incidence turns theta_o by the tilt; one across it, to second order only.
            let expected = wo.z().acos().tan() * u_deg.to_radians();
            let shifts = pointed
                .reseat_shifts(&lambertian(), &p, true)
                .expect("propagated");
            let names: Vec<&str> = shifts.iter().map(|(n, _)| *n).collect();
            assert_eq!(names, ["sample_tilt_x_deg", "sample_tilt_y_deg"]);
            let rel = shifts.iter().map(|(_, r)| r * r).sum::<f64>().sqrt();
            assert!((rel - expected).abs() < 0.05 * expected, "{rel} vs {expected}");
        }
    }
}
