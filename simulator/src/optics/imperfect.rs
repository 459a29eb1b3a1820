//! The optics on an imperfect instrument: the hidden truth they were given, the sample's current mounting, and
//! the true geometry of a pose (crate::imperfections::geometry). On the ideal instrument none of this runs: the
//! pose goes through crate::kinematics exactly as before, so the readings are bit for bit those of an instrument
//! without `[simulator.imperfections]`.

use std::sync::Arc;
use std::sync::atomic::Ordering;

use gonio_brdf::radiometry::{aperture_half_angle_rad, aperture_solid_angle_sr};

use crate::imperfections::{HiddenTruth, Tilt};
use crate::kinematics::{self, LabVector, PoseGeometry};
use crate::scene::Pose;

use super::Optics;
use super::geometry::Geometry;

/// The sample's current mounting: its index (0 the first) and its tilt.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub(super) struct Seating {
    pub index: u64,
    pub tilt: Tilt,
}

impl Optics {
    /// Give the optics the instrument's hidden truth (`None`: the ideal instrument, the default). The sample
    /// starts in its first mounting.
    pub fn with_hidden_truth(mut self, truth: Option<&HiddenTruth>) -> Optics {
        self.hidden = truth.cloned().map(Arc::new);
        self.signature = truth
            .and_then(|t| t.detector.as_ref())
            .map(|d| d.signature)
            .filter(|s| !s.is_zero());
        self.source
            .set_imperfections(truth.and_then(|t| t.source.clone()));
        self.spectral = truth
            .and_then(|t| t.filters.as_ref())
            .map(|f| {
                f.filters
                    .iter()
                    .filter_map(|filter| super::spectral::SpectralBand::new(f, filter, &self.responsivity))
                    .map(Arc::new)
                    .collect()
            })
            .unwrap_or_default();
        // The aperture as it really is: the solid angle the absolute equation takes from the file is off by
        // what its radius and distance are.
        let [mut aperture_radius_mm, mut distance_mm] = self.nominal_aperture_mm;
        if let Some(g) = truth.and_then(|t| t.geometry.as_ref()) {
            aperture_radius_mm += g.aperture_radius_error_mm;
            distance_mm += g.detector_distance_error_mm;
        }
        self.detector_distance_mm = distance_mm;
        self.aperture_half_rad = aperture_half_angle_rad(aperture_radius_mm, distance_mm);
        self.aperture_sr = aperture_solid_angle_sr(aperture_radius_mm, distance_mm);
        self.beam = truth
            .and_then(|t| t.beam)
            .map(|b| super::beam::BeamOptics::new(b, aperture_radius_mm, self.detector_distance_mm));
        let tilt = self.seating_tilt(0);
        *self.seating.get_mut().unwrap_or_else(|e| e.into_inner()) = Seating { index: 0, tilt };
        self
    }

    /// The holder object of an alignment mirror: its mountings seat it in their own way.
    pub const ALIGNMENT_MIRROR: u64 = 1;

    /// Make these optics the alignment mirror, a different object on the holder from the sample (its own
    /// seatings), starting in its first mounting.
    pub fn as_alignment_mirror(mut self) -> Optics {
        self.object = Optics::ALIGNMENT_MIRROR;
        let tilt = self.seating_tilt(0);
        *self.seating.get_mut().unwrap_or_else(|e| e.into_inner()) = Seating { index: 0, tilt };
        self
    }

    /// The hidden truth these optics compute with (for tests and run.json; never for a measurement).
    pub fn hidden_truth(&self) -> Option<&HiddenTruth> {
        self.hidden.as_deref()
    }

    /// Which mounting the sample is in (0: the first) and its tilt (hidden truth, for tests).
    pub fn seating(&self) -> (u64, Tilt) {
        let s = *self.seating.read().unwrap_or_else(|e| e.into_inner());
        (s.index, s.tilt)
    }

    /// The true geometry of the pose the controllers believe (hidden truth, for tests); the nominal geometry
    /// on the ideal instrument. The geometry group's only: a reading then applies the beam's pointing
    /// (crate::imperfections::beam) to it.
    pub fn true_geometry(&self, pose: &Pose) -> Option<crate::imperfections::TrueGeometry> {
        let g = self.hidden.as_ref()?.geometry.as_ref()?;
        Some(g.true_geometry(pose, &self.seating().1, self.detector_distance_mm))
    }

    pub(super) fn seating_tilt(&self, index: u64) -> Tilt {
        self.hidden
            .as_ref()
            .and_then(|h| h.geometry.as_ref())
            .map(|g| g.object_seating_tilt(self.object, index))
            .unwrap_or_default()
    }

    /// Record a mounting change: putting the sample back (unmounted -> mounted) starts a new seating.
    pub(super) fn note_mounted(&self, was_mounted: bool, mounted: bool) {
        if mounted && !was_mounted {
            let mut s = self.seating.write().unwrap_or_else(|e| e.into_inner());
            let index = s.index + 1;
            *s = Seating {
                index,
                tilt: self.seating_tilt(index),
            };
        }
    }

    /// The geometry a reading computes with: the true one on an imperfect instrument, the nominal kinematics on
    /// the ideal one (the same code path as without imperfections).
    pub(super) fn geometry_of(&self, pose: &Pose) -> Geometry {
        let mut g = self.geometry_of_arms(pose);
        if self.beam.is_some() {
            self.point_beam(&mut g);
        }
        g
    }

    /// [`Optics::geometry_of`] before the beam's pointing: the axes, the sample and the arms' axis.
    fn geometry_of_arms(&self, pose: &Pose) -> Geometry {
        match self.true_geometry(pose) {
            Some(t) => Geometry {
                pose: PoseGeometry {
                    wi: t.wi,
                    wo: t.wo,
                    source_lab: t.source_lab,
                    detector_lab: t.detector_lab,
                    frame: t.frame,
                },
                detector_arm_lab: t.detector_arm_lab,
                spot_mm: t.spot_mm,
                field_centre_mm: t.field_centre_mm,
                spot_lab: t.frame.to_lab(&[t.spot_mm[0], t.spot_mm[1], 0.0]),
                axis_lab: self
                    .hidden
                    .as_ref()
                    .and_then(|h| h.geometry.as_ref())
                    .map_or([0.0; 3], |g| [g.eccentricity_mm[0], g.eccentricity_mm[1], 0.0]),
            },
            None => {
                let pose = kinematics::forward(pose);
                Geometry {
                    detector_arm_lab: pose.detector_lab,
                    pose,
                    spot_mm: [0.0, 0.0],
                    field_centre_mm: [0.0, 0.0],
                    spot_lab: [0.0; 3],
                    axis_lab: [0.0; 3],
                }
            }
        }
    }

    /// The beam's footprint: the closed form when the spot and the field are centred (always on the ideal
    /// instrument), the off-centre integration otherwise.
    pub(super) fn footprint_of(&self, g: &Geometry) -> super::footprint::Footprint {
        if let Some((w, _)) = self.beam.as_ref().and_then(|b| b.gaussian_mm) {
            let a = g.pose.frame.to_sample(&g.detector_arm_lab);
            let view = gonio_brdf::Direction::new(a[0], a[1], a[2]).unwrap_or(gonio_brdf::Direction::NORMAL);
            return super::footprint_gaussian::footprint_gaussian(
                w,
                self.sample_radius_mm,
                self.field_radius_mm,
                &g.pose.wi,
                &view,
                g.spot_mm,
                g.field_centre_mm,
            );
        }
        self.footprint_top_hat(g)
    }

    /// The top hat's footprint (the ideal beam's, also for the beam's attribution).
    pub(super) fn footprint_top_hat(&self, g: &Geometry) -> super::footprint::Footprint {
        if g.spot_mm == [0.0, 0.0] && g.field_centre_mm == [0.0, 0.0] {
            return super::footprint::footprint(
                self.beam_radius_mm,
                self.sample_radius_mm,
                self.field_radius_mm,
                &g.pose.wi,
                &g.pose.wo,
            );
        }
        // The field is a cylinder about the detector arm's own axis (through the arms' axis), not about the
        // direction from the spot to the aperture.
        let a = g.pose.frame.to_sample(&g.detector_arm_lab);
        let view = gonio_brdf::Direction::new(a[0], a[1], a[2]).unwrap_or(gonio_brdf::Direction::NORMAL);
        super::footprint_offset::footprint_offset(
            self.beam_radius_mm,
            self.sample_radius_mm,
            self.field_radius_mm,
            &g.pose.wi,
            &view,
            g.spot_mm,
            g.field_centre_mm,
        )
    }

    /// The fraction of the beam that reaches the detector by stray paths with the detector arm along
    /// `detector_arm_lab` and the source along `source_lab` (lab, from the sample): `Omega_d f_sig(alpha)`,
    /// alpha the angle between the detector arm and the undeviated beam (crate::imperfections::detector).
    pub(super) fn stray_fraction(&self, detector_arm_lab: &LabVector, source_lab: &LabVector) -> f64 {
        let Some(sig) = self.signature else {
            return 0.0;
        };
        let beam = [-source_lab[0], -source_lab[1], -source_lab[2]];
        let alpha = kinematics::angle_between(detector_arm_lab, &beam);
        self.aperture_sr * sig.at(alpha)
    }

    /// The sample's reflectance factor over the beam's footprint at geometry `g` (crate::imperfections::sample):
    /// exactly 1 on an even sample.
    pub(super) fn sample_factor(&self, g: &Geometry) -> f64 {
        let Some(s) = self.hidden.as_ref().and_then(|h| h.sample.as_ref()) else {
            return 1.0;
        };
        let cos_i = g.pose.wi.z();
        if cos_i <= 0.0 {
            return 1.0;
        }
        let r = self.footprint_radius_mm();
        s.footprint_mean(g.spot_mm, r / cos_i, r, self.sample_radius_mm)
    }

    /// Whether the sample is in the holder (kept with the seating so both change together).
    pub(super) fn swap_mounted(&self, mounted: bool) -> bool {
        self.sample_mounted.swap(mounted, Ordering::Relaxed)
    }
}
