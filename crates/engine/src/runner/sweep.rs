//! A campaign's sweeps (`[[plan.sweeps]]`, `gonio_scheduler::sweep`), after its points: one arm turns over an
//! arc at the sweep's speed while the meter reads back to back; each reading is attributed to where the arm was
//! on average while it integrated (the middle of the arc it covered at cruise) and goes through the same
//! measurement equation as a point.
//!
//! Per sweep: move to the arc's start (a planned, collision-safe move, as for a point), turn the wheel to the
//! band, then the pass (crate::motion::sweep): the swept axis's speed set (`set_speed`, the instrument file's
//! acceleration), the move to the arc's end commanded and the meter read until the axis has arrived. The axis's
//! own speed (`max_speed_deg_s`) is set back before anything else moves and when the sweeps end, not between
//! the pieces of a chain (a speed profile's, each starting where the last ended): the next sets its own.
//! The meter is configured for the sweep's averaging for the sweep and for the campaign's again after it.
//!
//! Where a reading was: the commanded trapezoidal profile (start at the move command's reply, the set speed,
//! the axis's acceleration), shifted in time by the median lag of the controller's position reports taken while
//! the arm cruises (one after every [`POSITION_EVERY`] readings, more often in a short sweep, concurrently with
//! the next: the controller's line and the meter's are separate; a single position query each, dated between
//! its request's arrival and its reply's start on the line, where the instrument file's `position_sampled_ms`
//! says or else in the window's middle: `crate::motion::sweep::ReportDating`); a sweep with no
//! report on its cruise takes the axis's lag from its last sweep that had one. A
//! reading integrates from its request for `averaging x 3 ms`; the time it is stamped with is the middle of that
//! window, the angle it is attributed to the profile's mean position over it (`Trapezoid::mean_over`: in the
//! ramps the arm spends longer at the slower end of the arc). What remains uncertain is when within its exchange
//! the controller took a report when the file does not say (the window between the request's arrival and the
//! reply's start: the controller's execution, about 10 ms for an SMC100 position query, none for the
//! simulator's; `speed x window` of arc), which each segment records as its timing uncertainty
//! ([`timing_u_s`]), and the spread of the reports' lags, in the log.
//!
//! What a segment (one sweep of one arc in one band) stores is committed in one transaction with all its
//! readings (crate::store::sweeps): a sweep interrupted (pause, crash) is swept again whole on resume, and no
//! reading is stored twice. Each reading takes the characterisation's corrections as a point does (the ranges'
//! gains, the darks' noise as its least, the signature subtracted or else the instrument file's in its
//! uncertainty, the NEBRDF flag; crate::runner::acquire), except that a reading within 1 % of a range's full
//! scale cannot be read again on the range above while the arm moves. The completion corrects the readings (the
//! dark, the drift, aperture, smearing: crate::budget::sweeps). The run writes them to `sweeps.csv`; the exports,
//! fits and plots read them from there or from the store.

use gonio_brdf::{Direction, Wavelength};
use gonio_instrument::AxisRole;
use gonio_scheduler::kinematics::Pose;
use gonio_scheduler::sweep::{SweepArc, SweepStep, swept_role};
use gonio_scheduler::timing::DETECTOR_SAMPLE_S;

use super::*;
use crate::acquisition::{self, brdf_of_reading, flag_for};
use crate::budget;
use crate::store::SweepSegmentRecord;
use gonio_results::sweeps::SweepReading;

use crate::motion::sweep::{ReportDating, load_offset_deg, restore_speed, sweep_axis};
use gonio_scheduler::timing::Trapezoid;

/// A position report every this many readings during a sweep (more often in short sweeps: [`report_every`]).
pub const POSITION_EVERY: usize = 8;

/// Position reports a sweep aims for while it cruises: fewer and a short sweep (a piece of a sweep that follows
/// the BRDF) could end without a report on its cruise, its readings then placed by the commanded profile alone.
const REPORTS_PER_CRUISE: usize = 4;

/// A position report every this many readings: [`POSITION_EVERY`], or often enough for
/// [`REPORTS_PER_CRUISE`] reports over a cruise of `cruise_s` with a reading every `period_s`.
fn report_every(cruise_s: f64, period_s: f64) -> usize {
    let readings = if period_s > 0.0 && cruise_s > 0.0 {
        (cruise_s / period_s).floor() as usize
    } else {
        0
    };
    (readings / REPORTS_PER_CRUISE).clamp(1, POSITION_EVERY)
}

/// How well the time of a sweep's readings is known for placing them along the arc (s, standard uncertainty):
/// the meter's exchange ([`budget::TIMING_U_S`]) and where the controller took its position reports within
/// their widest dating window (`crate::motion::sweep::ReportDating`; none when the file says when), anywhere
/// alike: `window / sqrt(12)`. The lag taken from the reports carries that uncertainty to every reading.
fn timing_u_s(widest_window_s: f64) -> f64 {
    let window = if widest_window_s.is_finite() {
        widest_window_s.max(0.0)
    } else {
        0.0
    };
    budget::TIMING_U_S.hypot(window / 12f64.sqrt())
}

/// The meter as a campaign's sweep reads it: the readings of the measurement equation (failures as messages).
struct SweepMeter<'m, 'r> {
    motion: &'m crate::motion::Motion<'r>,
    band_nm: f64,
    acquisition: &'m gonio_campaign::Acquisition,
    configured_nm: &'m mut Option<f64>,
}

impl crate::motion::sweep::Reader for SweepMeter<'_, '_> {
    type Reading = Result<acquisition::MeterReading, String>;
    async fn read(&mut self) -> Self::Reading {
        acquisition::read(self.motion, self.band_nm, self.acquisition, self.configured_nm)
            .await
            .map_err(|e| e.to_string())
    }
    fn integration_s(&self) -> f64 {
        f64::from(self.acquisition.averaging) * DETECTOR_SAMPLE_S
    }
}

impl Run<'_> {
    /// The sweeps from the first segment not committed. `calibrated`: darks and normalisation readings were
    /// taken in this session (the points ran before); else they are taken first.
    pub(super) async fn run_sweeps(&mut self, calibrated: bool) -> Result<(), Interrupt> {
        let Some(sweeps) = self.c.sweeps.clone() else {
            return Ok(());
        };
        let first = self.st(|s| s.sweep_segments_done(self.id))? as usize;
        let steps = &sweeps.schedule.steps;
        if first >= steps.len() {
            return Ok(());
        }
        let bands = self.c.plan.bands_nm.clone();
        if !calibrated {
            if first == 0 && self.done == 0 && self.t_base == 0.0 {
                // Sweeps alone, fresh: the instrument to where the schedule starts (its calibration, then its
                // first sweep), then the campaign's clock.
                let (pose, wheel) = sweeps
                    .schedule
                    .start
                    .unwrap_or((steps[0].start_pose, steps[0].wheel_position));
                self.motion.move_to(&pose).await?;
                if let Some(p) = wheel {
                    self.wheel_to(p).await?;
                }
                self.t_clock0 = self.motion.clock().now_s();
            }
            self.darks_all(&bands).await?;
            self.normalise(&bands, None).await?;
        }
        // The axis a sweep left at its sweep speed: its own restored before anything else moves, and on the way
        // out when the sweeps end or a person pauses or aborts them (what follows moves at the file's speeds).
        // Not after an emergency stop or a device in trouble: nothing more is said to the hardware then (the
        // driver knows the speed it set, so later moves keep honest deadlines).
        let mut slow: Option<AxisRole> = None;
        let swept = self.sweep_steps(&sweeps, first, &bands, &mut slow).await;
        if let Err(Interrupt::Pause(_) | Interrupt::Estop | Interrupt::Fatal(_)) = swept {
            return swept;
        }
        let restored = self.restore_swept(&mut slow).await;
        swept?;
        restored?;
        if self.c.plan.calibration.references() {
            self.darks_all(&bands).await?;
            self.normalise(&bands, None).await?;
        }
        Ok(())
    }

    /// The sweeps from step `first` on, each committed (`run_sweeps`); `slow`: the axis left at its sweep speed.
    async fn sweep_steps(
        &mut self,
        sweeps: &gonio_campaign::Sweeps,
        first: usize,
        bands: &[f64],
        slow: &mut Option<AxisRole>,
    ) -> Result<(), Interrupt> {
        let steps = &sweeps.schedule.steps;
        // The calibration cadence between arcs, and the closing calibration: as the schedule predicts them
        // (gonio_scheduler::sweep::schedule_sweeps).
        let every_s = self.c.plan.calibration.sweep_every_s();
        let mut last_calibration = self.t();
        for (k, step) in steps.iter().enumerate().skip(first) {
            self.safe_point()?;
            let Some(arc) = sweeps.plan.arcs.get(step.arc) else {
                return Err(Interrupt::Fatal(EngineError::NotRunnable {
                    id: self.id,
                    message: format!("sweep {k} names arc {} of {}", step.arc, sweeps.plan.arcs.len()),
                }));
            };
            let previous = k.checked_sub(1).and_then(|p| steps.get(p)).filter(|_| k > first);
            let new_arc = previous.is_some_and(|p| p.arc != step.arc);
            if new_arc && every_s.is_some_and(|e| self.t() - last_calibration >= e) {
                self.restore_swept(slow).await?;
                self.darks_all(bands).await?;
                self.normalise(bands, None).await?;
                last_calibration = self.t();
            }
            // The next piece of a chain sets its own speed where the last ended: no move, no restore between.
            let role = swept_role(arc.request.arm);
            let chained = previous.is_some_and(|p| p.end_pose == step.start_pose) && *slow == Some(role);
            if !chained {
                self.restore_swept(slow).await?;
            }
            let index = |n: usize| u32::try_from(n).unwrap_or(u32::MAX);
            // Left at the sweep's speed from its pass on, whatever happens after.
            *slow = Some(role);
            self.sweep((index(k), index(steps.len())), step, arc).await?;
        }
        Ok(())
    }

    /// The axis a sweep left at its sweep speed (if any) set back to its own.
    async fn restore_swept(&mut self, slow: &mut Option<AxisRole>) -> Result<(), Interrupt> {
        let Some(role) = slow.take() else {
            return Ok(());
        };
        if let Some(axis) = self.rig.axes().iter().find(|a| a.config.role == role) {
            restore_speed(&self.motion, axis).await?;
        }
        Ok(())
    }

    /// One sweep, committed as one segment.
    async fn sweep(
        &mut self,
        (segment, segments): (u32, u32),
        step: &SweepStep,
        arc: &SweepArc,
    ) -> Result<(), Interrupt> {
        let role = swept_role(arc.request.arm);
        let correct = |p: &Pose| match &self.correction {
            Some(c) => c.correct(p),
            None => *p,
        };
        let (start, end) = (correct(&step.start_pose), correct(&step.end_pose));
        let (s_start, s_end) = if step.forward {
            (arc.piece.from_deg, arc.piece.to_deg)
        } else {
            (arc.piece.to_deg, arc.piece.from_deg)
        };
        self.motion.move_to(&start).await?;
        if let Some(p) = step.wheel_position {
            self.wheel_to(p).await?;
        }
        let band_nm = step
            .band_nm
            .or(self.file.instrument.source.wavelength_nm)
            .unwrap_or(f64::NAN);
        let Some(axis) = self.rig.axes().iter().find(|a| a.config.role == role) else {
            return Err(Interrupt::Fatal(EngineError::NotRunnable {
                id: self.id,
                message: format!("the instrument has no {role:?} axis to sweep"),
            }));
        };
        let (from_deg, to_deg) = (start.get(role), end.get(role));
        let mut acquisition = self.c.campaign.acquisition;
        acquisition.averaging = arc.request.averaging;
        self.configured_nm = None;
        // The meter set up for the sweep's readings before the arm starts: none of the arc passes meanwhile.
        acquisition::configure(&self.motion, band_nm, &acquisition, &mut self.configured_nm).await?;
        let (speed, accel) = (arc.request.speed_deg_s, axis.config.accel_deg_s2);
        let planned = Trapezoid {
            t0_s: 0.0,
            from_deg,
            to_deg,
            v: speed,
            a: accel,
        };
        let every = report_every(
            planned.duration_s() - 2.0 * planned.ramp_s(),
            gonio_scheduler::sweep::sweep_reading_period_s(arc.request.averaging),
        );
        tracing::info!(campaign = %self.id, segment, axis = %axis.config.name, from_deg, to_deg,
            speed_deg_s = speed, "sweep started");
        let mut meter = SweepMeter {
            motion: &self.motion,
            band_nm,
            acquisition: &acquisition,
            configured_nm: &mut self.configured_nm,
        };
        let dating = ReportDating::of(&self.file, &axis.config);
        let pass = sweep_axis(
            &self.motion,
            axis,
            (from_deg, to_deg),
            speed,
            every,
            dating,
            &mut meter,
        )
        .await?;
        self.configured_nm = None;
        // Only the swept axis moved: its arrival's read-back is where it is (the others are where they were).
        self.motion.arrived(role, pass.arrived_deg);
        let ended = self.t();
        let clock = self.motion.clock();
        let profile = pass.profile;

        // The lag of the arm behind its commanded profile, from the reports taken while it cruised; none
        // measured (a sweep too short to cruise past a report): the axis's lag from its last sweep.
        let (lag, spread) = match pass.lag_s() {
            Some((lag, spread)) => {
                self.sweep_lags.insert(axis.config.name.clone(), lag);
                (lag, spread)
            }
            None => (
                self.sweep_lags.get(&axis.config.name).copied().unwrap_or(0.0),
                0.0,
            ),
        };
        let widest_window_s = pass.unknown_window_s();
        tracing::info!(campaign = %self.id, segment, readings = pass.taken.len(), reports = pass.reports.len(),
            lag_s = lag, lag_spread_s = spread, report_window_s = widest_window_s, "sweep ended");

        let integration_s = f64::from(arc.request.averaging) * DETECTOR_SAMPLE_S;
        let span = to_deg - from_deg;
        let load_offset = load_offset_deg(&axis.config, span);
        let signed = |x: f64| {
            if span == 0.0 {
                s_start
            } else {
                s_start + (x - from_deg) / span * (s_end - s_start)
            }
        };
        let t_offset = self.t() - clock.now_s();
        let readings: Vec<SweepReading> = pass
            .taken
            .iter()
            .enumerate()
            .map(|(k, (requested_s, reading))| {
                let (ta, tb) = (*requested_s, *requested_s + integration_s);
                let (a, b) = (
                    signed(profile.position(ta - lag) + load_offset),
                    signed(profile.position(tb - lag) + load_offset),
                );
                let mid = signed(profile.mean_over(ta - lag, tb - lag) + load_offset);
                self.sweep_reading(
                    segment,
                    k,
                    band_nm,
                    arc,
                    mid,
                    (a, b),
                    reading,
                    0.5 * (ta + tb) + t_offset,
                    integration_s,
                )
            })
            .collect();
        let record = SweepSegmentRecord {
            segment,
            band_nm: step.band_nm,
            // When the move command went out, as before the pass moved to crate::motion::sweep.
            started_s: profile.t0_s + t_offset,
            ended_s: ended,
            readings: u32::try_from(readings.len()).unwrap_or(u32::MAX),
            timing_u_s: Some(timing_u_s(widest_window_s)),
        };
        self.st(|s| s.commit_sweep_segment(self.id, &record, &readings))?;
        self.control.emit(Event::Sweep {
            campaign: self.id,
            segment,
            segments,
            readings: record.readings,
        });
        Ok(())
    }

    /// One reading through the measurement equation, attributed to signed angle `mid` of its arc.
    #[allow(clippy::too_many_arguments)]
    fn sweep_reading(
        &self,
        segment: u32,
        k: usize,
        band_nm: f64,
        arc: &SweepArc,
        mid: f64,
        (from, to): (f64, f64),
        reading: &Result<acquisition::MeterReading, String>,
        t_s: f64,
        integration_s: f64,
    ) -> SweepReading {
        let g = arc.request.geometry_at(mid);
        let wi = Direction::from_spherical_deg(g.theta_i_deg, g.phi_i_deg);
        let wo = Direction::from_spherical_deg(g.theta_o_deg, g.phi_o_deg);
        let mut flags = Vec::new();
        let (mut signal, mut brdf, mut brdf_u, mut incident_w) = (None, None, None, None);
        match reading {
            Err(e) => flags.push(format!("failed: {e}")),
            Ok(r) if r.overload => {
                signal = Some(r.power_w);
                flags.push("saturated".to_string());
            }
            Ok(r) => {
                // As for a point: the characterisation's corrections, the signature.
                let averaging = arc.request.averaging;
                let r = self.characterised(r, band_nm, averaging);
                signal = Some(r.power_w);
                let inputs = self.equation_inputs(band_nm, wi, wo);
                let incident = self
                    .normalisation(band_nm, t_s)
                    .unwrap_or(Reading::exact(f64::NAN));
                incident_w = Some(incident.value_w).filter(|w| w.is_finite());
                match brdf_of_reading(
                    &inputs,
                    Reading::new(r.power_w, r.noise_w),
                    self.dark(band_nm),
                    incident,
                ) {
                    Ok(v) => {
                        let (value, u_stray) = self.less_signature(
                            v.value_per_sr,
                            (&wi, &wo),
                            g.theta_o_deg,
                            (band_nm, averaging),
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
                        brdf = Some(value);
                        brdf_u = Some(budget::of_point(&parts).total_sr());
                    }
                    Err(e) => flags.push(flag_for(&e)),
                }
            }
        }
        let truth_point_sr = match (&self.holder, Wavelength::from_nm(band_nm)) {
            (Some(h), Ok(wl)) => h.truth_point(&wi, &wo, wl),
            _ => None,
        };
        SweepReading {
            segment,
            k: u32::try_from(k).unwrap_or(u32::MAX),
            band_nm,
            t_s,
            integration_s,
            theta_i_deg: g.theta_i_deg,
            phi_i_deg: g.phi_i_deg,
            theta_o_deg: g.theta_o_deg,
            phi_o_deg: g.phi_o_deg,
            arc_from_deg: from,
            arc_to_deg: to,
            signal_w: signal,
            incident_w,
            brdf_sr: brdf,
            brdf_u_sr: brdf_u,
            brdf_aperture_sr: None,
            flags,
            truth_point_sr,
        }
    }
}

#[cfg(test)]
mod tests {
    #[test]
    fn a_wider_report_window_makes_the_readings_times_less_certain() {
        use super::timing_u_s;
        // A simulator answers at once: the meter's exchange alone.
        assert_eq!(timing_u_s(0.0), crate::budget::TIMING_U_S);
        assert_eq!(timing_u_s(f64::NAN), crate::budget::TIMING_U_S);
        // A controller taking 10 ms to answer (the SMC100 manual's execution time for TP): 2.9 ms more.
        let u = timing_u_s(0.010);
        assert!((u - 0.001f64.hypot(0.010 / 12f64.sqrt())).abs() < 1e-15, "{u}");
        assert!(u > 0.003 && u < 0.0031, "{u}");
    }

    #[test]
    fn short_sweeps_ask_for_their_position_more_often() {
        use super::{POSITION_EVERY, report_every};
        // 10 s of cruise at a reading every 4 ms: the usual cadence.
        assert_eq!(report_every(10.0, 0.004), POSITION_EVERY);
        // Half a second at a reading every 91 ms: 5 readings, a report with each.
        assert_eq!(report_every(0.5, 0.091), 1);
        // 16 readings: four reports.
        assert_eq!(report_every(16.0 * 0.091, 0.091), 4);
        assert_eq!(report_every(0.0, 0.091), 1);
        assert_eq!(report_every(-1.0, 0.0), 1);
    }
}
