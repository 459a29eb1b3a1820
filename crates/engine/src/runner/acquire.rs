//! A campaign's acquisition: the filter wheel, one reading of the detector, one measured point with the
//! measurement equation ([`crate::acquisition`]), committed to the store.

use gonio_brdf::{Direction, Wavelength};

use super::*;
use crate::acquisition::{self, EquationInputs, Normalisation, brdf_of_reading, flag_for};
use crate::budget;
use crate::characterise::correction::{FLAG_BELOW_NEBRDF, FLAG_NEAR_BEAM, SignatureAt};
use crate::characterise::ranges::near_range_boundary;
use crate::characterise::signature::alpha_between_deg;
use crate::motion::MotionError;
use gonio_campaign::Range;
use gonio_results::budget::Budget;

/// The flag of a point whose calibrated pose no safe move reaches.
pub const FLAG_UNREACHABLE: &str = "unreachable";

/// A sample reading with its uncertainty in parts (W).
#[derive(Debug, Clone, Copy)]
pub(super) struct SampleReading {
    pub power_w: f64,
    /// The reading's own noise and resolution.
    pub noise_w: f64,
    /// The range's gain: the characterisation's correction's uncertainty, else the instrument file's.
    pub range_u_w: f64,
    pub overload: bool,
    /// Index into the instrument's `ranges_w`.
    pub range: Option<usize>,
}

impl<'a> Run<'a> {
    pub(super) async fn wheel_to(&mut self, position: u8) -> Result<(), Interrupt> {
        if self.wheel_at == Some(position) {
            return Ok(());
        }
        if let Some(w) = self.rig.wheel() {
            self.motion
                .device(
                    Device::Wheel,
                    &format!("filter wheel to position {position}"),
                    || w.go_to(position),
                )
                .await?;
        }
        self.wheel_at = Some(position);
        Ok(())
    }

    pub(super) fn blank_position(&self) -> Option<u8> {
        self.file
            .instrument
            .filter_wheel
            .as_ref()?
            .positions
            .iter()
            .find(|p| p.blank)
            .map(|p| p.position)
    }

    pub(super) fn band_position(&self, nm: f64) -> Option<u8> {
        self.file
            .instrument
            .filter_wheel
            .as_ref()?
            .positions
            .iter()
            .find(|p| !p.blank && p.band_nm == Some(nm))
            .map(|p| p.position)
    }

    /// One dark or normalisation reading at wavelength `nm`, averaging the campaign's `calibration_averaging`
    /// samples: (value, standard uncertainty, overload).
    pub(super) async fn read_calibration(&mut self, nm: f64) -> Result<(f64, f64, bool), Interrupt> {
        let averaging = self.c.campaign.acquisition.calibration_averaging;
        let r = self.read_parts(nm, averaging).await?;
        Ok((r.power_w, r.noise_w.hypot(r.range_u_w), r.overload))
    }

    /// One detector reading at wavelength `nm` averaging `averaging` samples, with its uncertainty in parts. A
    /// count other than the points' leaves the meter to be configured again for the next point.
    async fn read_parts(&mut self, nm: f64, averaging: u32) -> Result<SampleReading, Interrupt> {
        let mut acquisition = self.c.campaign.acquisition;
        acquisition.averaging = averaging;
        if self.configured_averaging != Some(averaging) {
            self.configured_nm = None;
        }
        let mut r = acquisition::read(&self.motion, nm, &acquisition, &mut self.configured_nm).await?;
        self.configured_averaging = Some(averaging);
        // A characterised meter under auto-range: a reading within 1 % of a range's full scale may have been
        // taken on either range, whose corrections differ; it is read again on the upper range, fixed.
        let ranges_w = &self.file.instrument.detector.ranges_w;
        if let (Some(d), Range::Auto) = (&self.detector, self.c.campaign.acquisition.range)
            && d.calibration.ranges.is_some()
            && !r.overload
            && let Some(upper) = near_range_boundary(r.power_w, ranges_w)
        {
            let mut fixed = acquisition;
            fixed.range = Range::FixedW(ranges_w[upper]);
            let mut configured = None;
            r = acquisition::read(&self.motion, nm, &fixed, &mut configured).await?;
            // Back to auto-range at the next reading.
            self.configured_nm = None;
        }
        Ok(self.characterised(&r, nm, averaging))
    }

    /// A meter's reading at wavelength `nm` averaging `averaging` samples, as the characterisation corrects it:
    /// the reading as the true signal (crate::characterise::ranges), the correction's own uncertainty apart (it is
    /// the range's, shared by the readings on it), and the darks' measured noise the least the reading has (the
    /// meter's model knows the shot, Johnson and quantisation noise, not the head's amplifier). An
    /// uncharacterised meter: the reading as the meter gives it, its range's gain as uncertain as the instrument
    /// file says.
    pub(super) fn characterised(
        &self,
        r: &acquisition::MeterReading,
        nm: f64,
        averaging: u32,
    ) -> SampleReading {
        let (power_w, range_u_w) = match &self.detector {
            Some(d) if !r.overload && d.calibration.ranges.is_some() => d.reading(r.power_w, r.range),
            _ => (
                r.power_w,
                r.power_w.abs() * self.file.instrument.detector.range_gain_u(),
            ),
        };
        let floor_w = self
            .detector
            .as_ref()
            .and_then(|d| d.noise_floor_w(nm, averaging))
            .unwrap_or(0.0);
        SampleReading {
            power_w,
            noise_w: r.std_w.max(floor_w),
            range_u_w,
            overload: r.overload,
            range: r.range,
        }
    }

    /// The instrument signature in a value viewed from `wo` with the light from `wi` at polar angle
    /// `theta_o_deg`, for readings averaging `averaging` samples: a characterised instrument's subtracted (the
    /// value flagged where it was not measured or is below three NEBRDF, crate::characterise::correction), else
    /// the instrument file's `signature_u_sr` as an uncertainty (gonio_instrument::signature). Returns the value
    /// and the signature's uncertainty in it.
    pub(super) fn less_signature(
        &self,
        value: f64,
        (wi, wo): (&Direction, &Direction),
        theta_o_deg: f64,
        (band_nm, averaging): (f64, u32),
        flags: &mut Vec<String>,
    ) -> (f64, budget::StrayLight) {
        let alpha = alpha_between_deg(wi, wo);
        let cos = theta_o_deg.to_radians().cos();
        // What the file knows of the signature, over the equation's cosine (none is divided at grazing angles).
        let unmeasured = budget::StrayLight::Unmeasured(if cos > 0.0 {
            self.signature_u.at(alpha) / cos
        } else {
            0.0
        });
        let Some(d) = &self.detector else {
            return (value, unmeasured);
        };
        let (value, u_stray) = match d.signature(band_nm, alpha, theta_o_deg) {
            SignatureAt::Subtract { brdf_sr, u_sr } => {
                (value - brdf_sr, budget::StrayLight::Subtracted(u_sr))
            }
            SignatureAt::NearBeam => {
                flags.push(FLAG_NEAR_BEAM.to_string());
                (value, unmeasured)
            }
            SignatureAt::Unknown => (value, unmeasured),
        };
        if d.below_nebrdf(value, band_nm, averaging, theta_o_deg) {
            flags.push(FLAG_BELOW_NEBRDF.to_string());
        }
        (value, u_stray)
    }

    /// The measurement equation's sensitivity to a value's dark (1/sr per W; crate::budget::DarkSensitivity):
    /// the equation is linear in the net signal, so it is the value of a net signal of a thousandth of the
    /// normalisation, over that signal.
    pub(super) fn dark_per_w(&self, v: &crate::budget::Darkened) -> Option<f64> {
        let [ti, pi, to, po] = v.geometry_deg;
        let inputs = self.equation_inputs(
            v.band_nm,
            Direction::from_spherical_deg(ti, pi),
            Direction::from_spherical_deg(to, po),
        );
        let signal_w = 1e-3 * v.incident_w;
        let value = brdf_of_reading(
            &inputs,
            Reading::exact(signal_w),
            Reading::exact(0.0),
            Reading::exact(v.incident_w),
        )
        .ok()?
        .value_per_sr;
        let per_w = value / signal_w;
        (per_w.is_finite() && per_w > 0.0).then_some(per_w)
    }

    /// What the measurement equation needs besides the readings, for a reading in `band_nm` at (wi, wo): the
    /// same for points and sweep readings.
    pub(super) fn equation_inputs(&self, band_nm: f64, wi: Direction, wo: Direction) -> EquationInputs<'_> {
        EquationInputs {
            instrument: &self.file.instrument,
            sample_radius_mm: self.c.campaign.sample_radius_mm,
            normalisation: match &self.reference {
                Some(r) => Normalisation::Relative {
                    transfer: &r.transfer,
                    reference_brdf_rel_std: self.c.campaign.calibration.reference_rel_std,
                },
                None => Normalisation::Absolute,
            },
            band_nm,
            wi,
            wo,
        }
    }

    pub(super) async fn measure(&mut self, step: &Step, next_start_s: Option<f64>) -> Result<(), Interrupt> {
        let index = self.done;
        let Some(g) = step.geometry else {
            return Err(Interrupt::Fatal(EngineError::NotRunnable {
                id: self.id,
                message: format!("measure step for point {index} has no geometry"),
            }));
        };
        let band_nm = step
            .band_nm
            .or(self.file.instrument.source.wavelength_nm)
            .unwrap_or(f64::NAN);
        // A calibrated instrument: the pose at which the beam and the detector truly make the planned
        // directions (crate::align::correction); the point keeps its planned geometry.
        let pose = match &self.correction {
            Some(c) => c.correct(&step.pose),
            None => step.pose,
        };
        // The planner checked the planned pose, not the corrected one: a correction may carry a pose at the edge
        // of the safe region (the arms' separation, an axis limit) out of it. Such a point cannot be measured
        // on this instrument: it is flagged, nothing moves, and the instrument is not blamed for it (a run of
        // such points does not pause the campaign as failing devices do).
        let unreachable = match (&self.correction, self.motion.safe_move(&pose)) {
            (Some(_), Err(MotionError::Impossible(reason))) => Some(reason),
            _ => None,
        };
        let acquired = match unreachable {
            Some(reason) => Err(reason),
            None => Ok(async {
                self.motion.move_to(&pose).await?;
                if let Some(p) = step.wheel_position {
                    self.wheel_to(p).await?;
                }
                self.read_parts(band_nm, self.c.campaign.acquisition.averaging)
                    .await
            }
            .await),
        };
        let mut flags = Vec::new();
        let reading = match acquired {
            Err(reason) => {
                flags.push(format!("{FLAG_UNREACHABLE}: the calibrated pose: {reason}"));
                None
            }
            Ok(Ok(r)) => Some(r),
            Ok(Err(Interrupt::Fatal(EngineError::Device(reason)))) => {
                self.failed_in_row += 1;
                if self.failed_in_row >= MAX_FAILED_IN_ROW {
                    return Err(Interrupt::Pause(format!(
                        "{MAX_FAILED_IN_ROW} points in a row failed; last: {reason}"
                    )));
                }
                flags.push(format!("failed: {reason}"));
                // Where the axes are now is uncertain after a failure: ask them.
                let _ = self.motion.read_positions().await;
                None
            }
            Ok(Err(other)) => return Err(other),
        };
        let signal = reading.map_or(f64::NAN, |r| r.power_w);
        let t = self.t();
        let dark = self.dark(band_nm);
        let incident = self.normalisation(band_nm, t).unwrap_or(Reading::exact(f64::NAN));
        let wi = Direction::from_spherical_deg(g.theta_i_deg, g.phi_i_deg);
        let wo = Direction::from_spherical_deg(g.theta_o_deg, g.phi_o_deg);
        let (mut brdf, mut brdf_u, mut budget) = (None, None, Budget::default());
        if let Some(r) = reading {
            self.failed_in_row = 0;
            if r.overload {
                flags.push("saturated".to_string());
            } else {
                let inputs = self.equation_inputs(band_nm, wi, wo);
                match brdf_of_reading(&inputs, Reading::new(signal, r.noise_w), dark, incident) {
                    Ok(v) => {
                        let (value, u_stray) = self.less_signature(
                            v.value_per_sr,
                            (&wi, &wo),
                            g.theta_o_deg,
                            (band_nm, self.c.campaign.acquisition.averaging),
                            &mut flags,
                        );
                        let parts = budget::Parts {
                            equation: &v,
                            relative: self.reference.is_some(),
                            band_nm,
                            range: r.range,
                            range_rel: if r.power_w != 0.0 {
                                r.range_u_w / r.power_w.abs()
                            } else {
                                0.0
                            },
                            stray_light: u_stray,
                        };
                        budget = budget::of_point(&parts);
                        brdf = Some(value);
                        brdf_u = Some(budget.total_sr());
                    }
                    Err(e) => flags.push(flag_for(&e)),
                }
            }
        }
        let truth = match (&self.holder, Wavelength::from_nm(band_nm)) {
            (Some(h), Ok(wl)) => h.truth(&wi, &wo, wl),
            _ => Default::default(),
        };
        let point = PointRecord {
            index,
            band_nm,
            theta_i_deg: g.theta_i_deg,
            phi_i_deg: g.phi_i_deg,
            theta_o_deg: g.theta_o_deg,
            phi_o_deg: g.phi_o_deg,
            signal_w: signal,
            dark_w: dark.value_w,
            incident_w: incident.value_w,
            brdf_sr: brdf,
            brdf_u_sr: brdf_u,
            flags,
            t_s: t,
            readback_deg: self
                .axis_names
                .iter()
                .cloned()
                .zip(self.motion.readback_deg().iter().copied())
                .collect(),
            truth_point_sr: truth.point_sr,
            truth_aperture_sr: truth.aperture_sr,
            truth_effects_json: truth.effects_json,
            brdf_aperture_sr: None,
            budget,
        };
        self.st(|s| s.commit_point(self.id, &point))?;
        self.done += 1;
        self.control.emit(Event::Point {
            campaign: self.id,
            point: Box::new(point),
        });
        self.progress(next_start_s);
        Ok(())
    }
}
