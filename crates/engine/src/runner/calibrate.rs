//! Calibration: darks, the normalisation readings (direct beam or reference sample), and the operator protocol
//! (remove or swap the sample; the simulated operator in dry-runs).

use gonio_brdf::Wavelength;

use crate::calibration::net_of_dark;
use gonio_scheduler::kinematics::Pose;

use super::*;

impl<'a> Run<'a> {
    /// Dark readings (wheel on the blank) at every band's wavelength setting.
    pub(super) async fn darks_all(&mut self, bands: &[f64]) -> Result<(), Interrupt> {
        let Some(blank) = self.blank_position() else {
            // No blank: darks are zero with no uncertainty (the instrument file says there is no way to take one).
            for b in bands {
                let t = self.t();
                self.darks.keep(*b, t, Reading::exact(0.0));
            }
            return Ok(());
        };
        self.wheel_to(blank).await.map_err(calibration_failure)?;
        for b in bands {
            let (v, u, overload) = self.read_calibration(*b).await.map_err(calibration_failure)?;
            if overload {
                return Err(Interrupt::Pause(format!(
                    "dark reading at {b} nm overloads the detector"
                )));
            }
            let t = self.t();
            self.darks.keep(*b, t, Reading::new(v, u));
            let rec = CalibrationRecord {
                kind: "dark".into(),
                band_nm: Some(*b),
                t_s: t,
                value_w: v,
                u_w: u,
            };
            self.st(|s| s.record_calibration(self.id, &rec))?;
        }
        Ok(())
    }

    /// Ask the operator to do something and wait for the confirmation; in dry-runs the simulated sample holder
    /// then holds `holder` (at once with the simulated operator).
    pub(super) async fn operator(&mut self, message: &str, holder: Holder) -> Result<(), Interrupt> {
        let simulated = self.holder.is_some() && self.c.campaign.calibration.simulate_operator;
        if !simulated {
            // A confirmation given before the question does not count: dropped before the question is announced,
            // since an operator (or a script) may answer as soon as it is, before this task runs again.
            let _ = self.control.take_confirm();
            self.st(|s| s.set_state(self.id, CampaignState::WaitingOperator, None))?;
            self.st(|s| s.set_operator_message(self.id, Some(message)))?;
            self.emit_state(CampaignState::WaitingOperator, Some(message.to_string()));
            loop {
                let n = self.control.notified();
                tokio::pin!(n);
                n.as_mut().enable();
                if self.control.take_confirm() {
                    break;
                }
                if self.control.estop_requested() {
                    return Err(Interrupt::Estop);
                }
                if self.control.abort_requested() {
                    return Err(Interrupt::Abort);
                }
                if self.control.pause_requested() {
                    return Err(Interrupt::PauseRequested("paused while waiting for the operator"));
                }
                n.await;
            }
            self.st(|s| s.set_operator_message(self.id, None))?;
            // A pause requested at this very moment is already on its way: say so rather than `running`.
            let state = if self.control.pause_requested() {
                CampaignState::Pausing
            } else {
                CampaignState::Running
            };
            self.st(|s| s.set_state(self.id, state, None))?;
            self.emit_state(state, None);
        }
        self.simulated_holder(holder);
        Ok(())
    }

    /// Dry-runs: put `holder` in the simulated sample holder, as the operator just did.
    pub(super) fn simulated_holder(&self, holder: Holder) {
        if let Some(h) = &self.holder {
            h.hold(holder);
        }
    }

    /// The normalisation readings of `bands` for the campaign's method: direct beam (at `pose`, else the plan's
    /// reference pose) or reference sample (at the reference geometry).
    pub(super) async fn normalise(&mut self, bands: &[f64], pose: Option<Pose>) -> Result<(), Interrupt> {
        match self.c.campaign.calibration.method {
            Method::Absolute => self.direct_beam(bands, pose).await,
            Method::Relative => self.reference_sample(bands).await,
        }
    }

    /// Reference-sample readings of `bands` (relative method): the operator swaps the reference in, one reading
    /// per band at the reference geometry, and the sample goes back.
    pub(super) async fn reference_sample(&mut self, bands: &[f64]) -> Result<(), Interrupt> {
        let Some(name) = self.reference.as_ref().map(|r| r.name.clone()) else {
            return Err(Interrupt::Fatal(EngineError::NotRunnable {
                id: self.id,
                message: "the relative method needs a reference, and the stored campaign has none".into(),
            }));
        };
        // Close the beam while the operator works.
        if let Some(blank) = self.blank_position() {
            self.wheel_to(blank).await.map_err(calibration_failure)?;
        }
        self.operator(
            &format!(
                "Reference calibration: take the sample out of the holder and mount the reference sample \
                 ({name}) in its place, then confirm."
            ),
            Holder::Reference,
        )
        .await?;
        let result = async {
            let current = *self.motion.current();
            let pose = self.c.plan.calibration.reference_target(&current, &self.c.time);
            let pose = pose.ok_or_else(|| {
                let geometry = self.reference.as_ref().map(|r| r.geometry);
                Interrupt::Pause(format!("no safe move from {current:?} to the reference geometry {geometry:?}"))
            })?;
            self.motion.move_to(&pose).await?;
            let angle_std_rad = self.file.instrument.arrival_u_deg().to_radians();
            for b in bands {
                if let Some(p) = self.band_position(*b) {
                    self.wheel_to(p).await?;
                }
                let (v, u, overload) = self.read_calibration(*b).await?;
                if overload {
                    return Err(Interrupt::Pause(format!(
                        "the reference sample at {b} nm overloads the detector: choose a larger range"
                    )));
                }
                let dark = self.dark(*b);
                let net_w = v - dark.value_w;
                if net_w <= 0.0 {
                    return Err(Interrupt::Pause(format!(
                        "no signal from the reference sample at {b} nm ({v} W read, dark {} W): is it mounted, \
                         the source on and the path clear?",
                        dark.value_w
                    )));
                }
                let positioning = match (Wavelength::from_nm(*b), &self.reference) {
                    (Ok(wl), Some(r)) => r.transfer.positioning_rel_std(wl, angle_std_rad) * net_w,
                    _ => 0.0,
                };
                let net = Reading::new(net_w, u.hypot(dark.std_w).hypot(positioning));
                self.keep_normalisation("reference", *b, net, v, u)?;
            }
            Ok(())
        }
        .await;
        self.end_normalisation(
            result,
            "Reference calibration done: take the reference sample out and mount the sample again, then confirm.",
        )
        .await
    }

    /// Direct-beam readings of `bands`: sample out, detector facing the source, one reading per band.
    pub(super) async fn direct_beam(&mut self, bands: &[f64], pose: Option<Pose>) -> Result<(), Interrupt> {
        // No step says where: the plan's direct-beam pose, else the default (the rule the time model follows).
        let pose = match pose {
            Some(p) => p,
            None => self
                .c
                .plan
                .calibration
                .preamble_target(self.motion.current(), &self.c.time)
                .unwrap_or(gonio_scheduler::plan::DEFAULT_DIRECT_BEAM_POSE),
        };
        // Close the beam while the operator works.
        if let Some(blank) = self.blank_position() {
            self.wheel_to(blank).await.map_err(calibration_failure)?;
        }
        self.operator(
            "Direct-beam calibration: remove the sample from the holder, then confirm.",
            Holder::Empty,
        )
        .await?;
        let result = async {
            self.motion.move_to(&pose).await?;
            for b in bands {
                let pos = self.band_position(*b);
                if let Some(p) = pos {
                    self.wheel_to(p).await?;
                }
                let (v, u, overload) = self.read_calibration(*b).await?;
                if overload {
                    return Err(Interrupt::Pause(format!(
                        "the direct beam at {b} nm overloads the detector: choose a larger range or attenuate"
                    )));
                }
                let dark = self.dark(*b);
                let net = net_of_dark(Reading::new(v, u), dark);
                if net.value_w <= 0.0 {
                    return Err(Interrupt::Pause(format!(
                        "no direct beam at {b} nm ({v} W read, dark {} W): is the source on and the path clear?",
                        dark.value_w
                    )));
                }
                self.keep_normalisation("direct-beam", *b, net, v, u)?;
            }
            Ok(())
        }
        .await;
        self.end_normalisation(
            result,
            "Direct-beam calibration done: mount the sample again, then confirm.",
        )
        .await
    }

    /// The last dark reading of band `nm` (zero, exactly, when none was taken).
    pub(super) fn dark(&self, nm: f64) -> Reading {
        self.darks.of(nm)
    }

    /// Keep a band's net normalisation reading for the drift extrapolation, and store the raw one as `kind`.
    pub(super) fn keep_normalisation(
        &mut self,
        kind: &str,
        nm: f64,
        net: Reading,
        value_w: f64,
        u_w: f64,
    ) -> Result<(), Interrupt> {
        let t = self.t();
        self.norm.keep(nm, t, net);
        let rec = CalibrationRecord {
            kind: kind.into(),
            band_nm: Some(nm),
            t_s: t,
            value_w,
            u_w,
        };
        self.st(|s| s.record_calibration(self.id, &rec))
    }

    /// The end of a normalisation sequence: its failure is a calibration failure; then the beam is closed and
    /// the operator puts the sample back (`message`).
    pub(super) async fn end_normalisation(
        &mut self,
        result: Result<(), Interrupt>,
        message: &str,
    ) -> Result<(), Interrupt> {
        result.map_err(calibration_failure)?;
        if let Some(blank) = self.blank_position() {
            self.wheel_to(blank).await.map_err(calibration_failure)?;
        }
        self.operator(message, Holder::Sample).await
    }

    /// The normalisation reading (net direct beam, or net reference signal) at time `t` for a band, with the
    /// source's drift extrapolated ([`crate::calibration::Normalisations::at`]).
    pub(super) fn normalisation(&self, nm: f64, t: f64) -> Option<Reading> {
        self.norm.at(nm, t)
    }
}

/// A device failure during calibration pauses the campaign (there is no valid normalisation without it).
pub(super) fn calibration_failure(i: Interrupt) -> Interrupt {
    match i {
        Interrupt::Fatal(EngineError::Device(reason)) => Interrupt::Pause(format!("calibration: {reason}")),
        other => other,
    }
}
