//! The beam's imperfections in the optics (model: crate::imperfections::beam): its pointing in the pose's
//! geometry, its profile in the footprint and the sample's mean, its profile and true divergence where the beam
//! itself reaches the detector (a delta lobe, the direct beam). With no beam truth nothing here runs: the optics
//! take exactly the ideal code path.

use crate::imperfections::BeamTruth;
use crate::imperfections::beam::gaussian_in_disc;
use crate::kinematics::{LabVector, dot};

use super::geometry::Geometry;
use super::{Optics, cap};

/// What the optics precompute from the beam's truth.
#[derive(Debug, Clone, Copy)]
pub(super) struct BeamOptics {
    pub truth: BeamTruth,
    /// Half of the true full divergence (rad).
    pub divergence_half_rad: f64,
    /// The Gaussian's 1/e^2 radius at the sample and at the detector's aperture (mm); `None` for the top hat.
    pub gaussian_mm: Option<(f64, f64)>,
    /// The detector's aperture radius (mm).
    pub aperture_radius_mm: f64,
}

impl BeamOptics {
    pub fn new(truth: BeamTruth, aperture_radius_mm: f64, detector_distance_mm: f64) -> BeamOptics {
        let divergence_half_rad = (0.5 * truth.divergence_deg).to_radians();
        let gaussian_mm = truth.gaussian_mm().map(|w| {
            let spread = detector_distance_mm * divergence_half_rad.tan();
            (w, w.hypot(spread))
        });
        BeamOptics {
            truth,
            divergence_half_rad,
            gaussian_mm,
            aperture_radius_mm,
        }
    }
}

fn unit(v: [f64; 3]) -> [f64; 3] {
    let len = dot(&v, &v).sqrt();
    [v[0] / len, v[1] / len, v[2] / len]
}

impl Optics {
    /// The beam's pointing error applied to geometry `g` (module doc of crate::imperfections::beam): the
    /// incidence direction, the spot and the direction to the detector's aperture change; the field does not.
    pub(super) fn point_beam(&self, g: &mut Geometry) {
        let Some(b) = self.beam.as_ref().filter(|b| b.truth.has_pointing()) else {
            return;
        };
        let frame = g.pose.frame;
        let n = frame.normal_lab;
        let c = g.axis_lab;
        let s = g.pose.source_lab;
        let l = b.truth.source_distance_mm;
        let s_true = b.truth.pointed(&s);
        let origin = [c[0] + l * s[0], c[1] + l * s[1], c[2] + l * s[2]];
        let sn = dot(&s_true, &n);
        if sn == 0.0 {
            return;
        }
        let t = dot(&origin, &n) / sn;
        let p = [
            origin[0] - t * s_true[0],
            origin[1] - t * s_true[1],
            origin[2] - t * s_true[2],
        ];
        let o = g.detector_arm_lab;
        let d = self.detector_distance_mm;
        let viewed = unit([
            c[0] + d * o[0] - p[0],
            c[1] + d * o[1] - p[1],
            c[2] + d * o[2] - p[2],
        ]);
        let to_dir = |v: &LabVector| {
            let x = frame.to_sample(v);
            gonio_brdf::Direction::new(x[0], x[1], x[2]).unwrap_or(gonio_brdf::Direction::NORMAL)
        };
        g.pose.wi = to_dir(&s_true);
        g.pose.wo = to_dir(&viewed);
        g.pose.source_lab = s_true;
        g.pose.detector_lab = viewed;
        let spot = frame.to_sample(&p);
        g.spot_mm = [spot[0], spot[1]];
        g.spot_lab = p;
    }

    /// The fraction of the beam itself (a mirror lobe `g_rad` off the aperture's axis) that enters the aperture,
    /// with the nominal beam (`nominal`) or the true one.
    pub(super) fn lobe_fraction(&self, g_rad: f64, nominal: bool) -> f64 {
        match self.beam.as_ref().filter(|_| !nominal) {
            None => cap::fraction_inside(self.divergence_half_rad, self.aperture_half_rad, g_rad),
            Some(b) => match b.gaussian_mm {
                Some((_, w_det)) => gaussian_in_disc(
                    w_det,
                    b.aperture_radius_mm,
                    self.detector_distance_mm * g_rad.min(std::f64::consts::FRAC_PI_2).sin(),
                ),
                None => cap::fraction_inside(b.divergence_half_rad, self.aperture_half_rad, g_rad),
            },
        }
    }

    /// The direct beam's fraction entering the aperture (no sample) at geometry `g`, `off_axis` the angle
    /// between the detector arm and the beam: the true beam's, and the nominal beam's for the attribution.
    pub(super) fn direct_fraction(&self, g: &Geometry, off_axis: f64) -> (f64, f64) {
        let nominal = cap::fraction_inside(self.divergence_half_rad, self.aperture_half_rad, off_axis);
        let Some(b) = self.beam.as_ref() else {
            return (nominal, nominal);
        };
        let fraction = match b.gaussian_mm {
            None => cap::fraction_inside(b.divergence_half_rad, self.aperture_half_rad, off_axis),
            Some((_, w_det)) => {
                // Distance from the aperture centre D = C + d o to the beam's axis (through the spot P along
                // the source direction s').
                let (c, o, p, s) = (g.axis_lab, g.detector_arm_lab, g.spot_lab, g.pose.source_lab);
                let d = self.detector_distance_mm;
                let r = [
                    c[0] + d * o[0] - p[0],
                    c[1] + d * o[1] - p[1],
                    c[2] + d * o[2] - p[2],
                ];
                let along = dot(&r, &s);
                let offset = (dot(&r, &r) - along * along).max(0.0).sqrt();
                gaussian_in_disc(w_det, b.aperture_radius_mm, offset)
            }
        };
        (fraction, nominal)
    }

    /// The footprint semi-axes over which the sample's non-uniformity is averaged (module doc of
    /// crate::imperfections::beam): the top hat's ellipse, or the Gaussian's equivalent one.
    pub(super) fn footprint_radius_mm(&self) -> f64 {
        match self.beam.as_ref().and_then(|b| b.gaussian_mm) {
            Some((w, _)) => w,
            None => self.beam_radius_mm,
        }
    }
}
