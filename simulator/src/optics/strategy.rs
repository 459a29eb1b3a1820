//! How to integrate over the aperture for a given material and geometry: the plan (flat, tensor sequence or
//! adaptive rule) and the features the rules adapt to (a lobe's peak and widths, kinks cut exactly), from what
//! the model is and where its lobe and kinks lie relative to the aperture cone.

use std::f64::consts::FRAC_PI_2;

use gonio_brdf::Direction;

use crate::kinematics;

use super::Optics;
use super::aperture::{Cone, Features, Peak, Plan};
use super::resolved::{Kinks, RegularPart};

impl Optics {
    /// Choose the integration strategy from what the model is and where its features lie.
    ///
    /// The BRDF's length scale near the aperture: smooth models without a lobe vary on the scale of a radian; a
    /// lobe of width alpha (in slope) is about 2 alpha wide in outgoing directions around the mirror direction,
    /// and at an angular distance D from its peak a microfacet tail (~ D^-4) varies on the scale D/4; a kink at
    /// distance K from the axis limits the scale to K. The ratio q = beta / scale decides: a kink within 2 beta,
    /// a feature narrower than the aperture (q > 1) or tabulated data go to the adaptive rule (seeded with the
    /// lobe's peak); otherwise the tensor sequence, from the coarsest rule when the aperture is tiny compared
    /// with the scale.
    ///
    /// A cone across the horizon: the integrator works on its part above the horizon in latitude coordinates,
    /// where the horizon is no kink, Oren-Nayar's kinks are coordinate lines cut exactly (theta_o = theta_i, a
    /// circle of latitude: `kink_theta`; cos(phi_o - phi_i) = 0, a meridian: `kink_azimuth`), so they do not count
    /// as kinks here, and a narrow lobe is mapped out (its peak, its width across the plane of incidence, and
    /// where its ridge crosses the cone's rim): Oren-Nayar and a smooth model there always take the tensor
    /// sequence, which falls back to the adaptive rule by itself if it does not converge. Above the horizon the
    /// adaptive rule is told of the Oren-Nayar plane too (`kink_azimuth`) and starts cut along its trace.
    pub(super) fn plan(&self, regular: RegularPart, wi_m: &Direction, cone: &Cone) -> (Plan, Features) {
        let beta = cone.half_angle;
        let across_horizon = !cone.above_horizon();
        let mirror = wi_m.reflect_about_normal();
        let peak = self.lobe_width.filter(|w| *w > 0.0).map(|w| {
            let width = 2.0 * w;
            // A microfacet lobe is a function of the half vector, which turns by 1 / (cos theta_i + cos theta_o)
            // per unit of out-of-plane angle: narrower across than along near grazing. Phong's is symmetric
            // about the mirror direction.
            let across = match regular {
                RegularPart::Kinked(Kinks::Phong) => (width, 0.0),
                _ => (w * wi_m.z().max(0.0), w),
            };
            Peak {
                direction: mirror,
                width,
                across,
            }
        });
        let mut features = Features {
            peak,
            kink_theta: None,
            kink_azimuth: None,
        };
        let mut scale: f64 = 1.0;
        if let Some(p) = peak {
            let distance = (mirror.angle_to(&cone.axis) - beta).max(0.0);
            scale = scale.min(p.width.max(distance / 4.0));
        }
        match regular {
            RegularPart::Tabulated => return (Plan::Adaptive, features),
            RegularPart::Kinked(k) => {
                let loci = kink_loci(k, wi_m, &cone.axis);
                let mut d = loci.other;
                if let Some((theta, distance)) = loci.latitude {
                    if !across_horizon {
                        d = d.min(distance);
                    } else if distance < 2.0 * beta {
                        features.kink_theta = Some(theta);
                    }
                }
                if let Some(azimuth) = loci.meridian {
                    if loci.other < 2.0 * beta {
                        features.kink_azimuth = Some(azimuth);
                    }
                    // A vertical plane through the normal is a meridian in latitude coordinates, cut exactly
                    // there; above the horizon it stays a kink for the adaptive rule (cut along its trace).
                    if across_horizon {
                        d = f64::INFINITY;
                    }
                }
                if d < 2.0 * beta {
                    return (Plan::Adaptive, features);
                }
                scale = scale.min(d);
            }
            _ => {}
        }
        let q = beta / scale;
        let plan = if q > 1.0 && !across_horizon {
            Plan::Adaptive
        } else if q < 0.03 {
            Plan::Tensor { start: 0 }
        } else if q < 0.3 {
            Plan::Tensor { start: 1 }
        } else {
            Plan::Tensor { start: 3 }
        };
        (plan, features)
    }
}

/// Where a model's kinks lie relative to a cone's axis.
#[derive(Debug, Clone, Copy, PartialEq)]
struct KinkLoci {
    /// Angular distance (rad) from the axis to the nearest kink that is not a circle of latitude.
    other: f64,
    /// When that kink is a vertical plane through the normal: its azimuth (rad) on the axis's side.
    meridian: Option<f64>,
    /// A kink along the circle of latitude theta (rad) that matters near the axis, and its angular distance
    /// from the axis.
    latitude: Option<(f64, f64)>,
}

/// The kink loci of the model near a cone's axis.
fn kink_loci(kinks: Kinks, wi_m: &Direction, axis: &Direction) -> KinkLoci {
    let a = [axis.x(), axis.y(), axis.z()];
    match kinks {
        Kinks::OrenNayar => {
            // Both terms vanish with sin(theta_i) (the azimuth of wi is then meaningless): no kink.
            let s = wi_m.sin_theta();
            if s == 0.0 {
                return KinkLoci {
                    other: f64::INFINITY,
                    meridian: None,
                    latitude: None,
                };
            }
            let n = [wi_m.x() / s, wi_m.y() / s, 0.0];
            let along = kinematics::dot(&a, &n);
            let to_plane = along.abs().min(1.0).asin();
            // Where the axis lies on the side cos(phi_o - phi_i) < 0, the max(0, .) factor is 0 up to the plane,
            // so the theta_o = theta_i kink is invisible there.
            let latitude = (along >= 0.0).then(|| (wi_m.theta(), (axis.theta() - wi_m.theta()).abs()));
            // The plane cos(phi_o - phi_i) = 0 is at the azimuths phi_i +- pi/2: the one the axis lies nearer.
            let across = kinematics::dot(&a, &[-n[1], n[0], 0.0]);
            let meridian = wi_m.phi() + if across >= 0.0 { FRAC_PI_2 } else { -FRAC_PI_2 };
            KinkLoci {
                other: to_plane,
                meridian: Some(meridian),
                latitude,
            }
        }
        Kinks::Phong => {
            let r = wi_m.reflect_about_normal();
            KinkLoci {
                other: kinematics::dot(&a, &[r.x(), r.y(), r.z()]).abs().min(1.0).asin(),
                meridian: None,
                latitude: None,
            }
        }
    }
}
