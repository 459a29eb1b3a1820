//! Acquisition: the filter wheel, one reading of the detector with its configuration, one measured point with
//! the measurement equation, committed to the store.

use super::*;

impl<'a> Run<'a> {
    pub(super) async fn wheel_to(&mut self, position: u8) -> Result<(), Interrupt> {
        if self.wheel_at == Some(position) {
            return Ok(());
        }
        if let Some(w) = self.rig.wheel() {
            self.device(
                Dev::Wheel,
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

    /// One detector reading at wavelength `nm`: (value, standard uncertainty, overload).
    pub(super) async fn read(&mut self, nm: f64) -> Result<(f64, f64, bool), Interrupt> {
        let det = self.rig.detector();
        if self.configured_nm != Some(nm) {
            let config = DetectorConfig {
                wavelength_nm: nm,
                averaging: self.c.campaign.acquisition.averaging,
                range: match self.c.campaign.acquisition.range {
                    Range::Auto => PowerRange::Auto,
                    Range::FixedW(w) => PowerRange::Fixed { full_scale_w: w },
                },
            };
            self.device(Dev::Detector, "configure the detector", || det.configure(config))
                .await?;
            self.configured_nm = Some(nm);
        }
        let r = self
            .device(Dev::Detector, "read the detector", || async {
                let r = det.read_power().await;
                if let Err(e) = &r
                    && matches!(e.kind(), ErrorKind::Disconnected | ErrorKind::Unavailable)
                {
                    // After a reconnect the meter is back at its defaults.
                    det.configure(config_for(nm, &self.c)).await?;
                }
                r
            })
            .await?;
        // Under auto-range the meter may report its largest range; the resolution is that of the smallest range
        // holding the reading, which is what auto-ranging settles on.
        let range_w = match self.c.campaign.acquisition.range {
            Range::Auto => self
                .file
                .instrument
                .detector
                .ranges_w
                .iter()
                .copied()
                .find(|fs| *fs > r.power_w.abs())
                .unwrap_or(r.range_w)
                .min(r.range_w),
            Range::FixedW(_) => r.range_w,
        };
        let u = ((range_w * READING_RANGE_STD).powi(2) + (r.power_w * READING_REL_STD).powi(2)).sqrt();
        Ok((r.power_w, u, r.overload))
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
        let acquired = async {
            self.move_to(&step.pose).await?;
            if let Some(p) = step.wheel_position {
                self.wheel_to(p).await?;
            }
            self.read(band_nm).await
        }
        .await;
        let mut flags = Vec::new();
        let (signal, u_signal, overload) = match acquired {
            Ok(r) => r,
            Err(Interrupt::Fatal(EngineError::Device(reason))) => {
                self.failed_in_row += 1;
                if self.failed_in_row >= MAX_FAILED_IN_ROW {
                    return Err(Interrupt::Pause(format!(
                        "{MAX_FAILED_IN_ROW} points in a row failed; last: {reason}"
                    )));
                }
                flags.push(format!("failed: {reason}"));
                // Where the axes are now is uncertain after a failure: ask them.
                let _ = self.read_positions().await;
                (f64::NAN, f64::NAN, false)
            }
            Err(other) => return Err(other),
        };
        let t = self.t();
        let dark = self.dark(band_nm);
        let incident = self.normalisation(band_nm, t).unwrap_or(Reading::exact(f64::NAN));
        let wi = Direction::from_spherical_deg(g.theta_i_deg, g.phi_i_deg);
        let wo = Direction::from_spherical_deg(g.theta_o_deg, g.phi_o_deg);
        let (mut brdf, mut brdf_u) = (None, None);
        if flags.is_empty() {
            self.failed_in_row = 0;
            if overload {
                flags.push("saturated".to_string());
            } else {
                match self.equation(signal, u_signal, dark, incident, band_nm, wi, wo) {
                    Ok(v) => {
                        brdf = Some(v.value_per_sr);
                        brdf_u = Some(v.std_per_sr);
                    }
                    Err(e) => flags.push(flag_for(&e)),
                }
            }
        }
        let (truth_point_sr, truth_aperture_sr) = match (&self.holder, Wavelength::from_nm(band_nm)) {
            (Some(h), Ok(wl)) => h.truth(&wi, &wo, wl),
            _ => (None, None),
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
                .zip(self.readback.iter().copied())
                .collect(),
            truth_point_sr,
            truth_aperture_sr,
        };
        self.st(|s| s.commit_point(self.id, &point))?;
        self.done += 1;
        self.control.emit(Event::Point {
            campaign: self.id,
            point,
        });
        self.progress(next_start_s);
        Ok(())
    }

    /// The measurement equation of the campaign's method; `norm` is the normalisation reading (net direct beam,
    /// or net reference signal) at the time of the reading.
    #[allow(clippy::too_many_arguments)]
    pub(super) fn equation(
        &self,
        signal: f64,
        u_signal: f64,
        dark: Reading,
        norm: Reading,
        band_nm: f64,
        wi: Direction,
        wo: Direction,
    ) -> Result<gonio_brdf::measurement::BrdfValue, MeasurementError> {
        let inst = &self.file.instrument;
        // Positioning: the arms' arrival tolerance as a uniform distribution.
        let tol_deg = inst.axes.iter().map(|a| a.tolerance_deg).fold(0.0f64, f64::max);
        let geometry = MeasurementGeometry {
            wi,
            wo,
            angle_std_rad: tol_deg.to_radians() / 3f64.sqrt(),
        };
        let footprint = Footprint {
            beam_radius_mm: inst.source.beam_radius_mm,
            sample_radius_mm: self.c.campaign.sample_radius_mm,
            detector_field_radius_mm: Some(inst.detector.field_radius_mm),
        };
        let limits = ValidityLimits {
            min_cos_theta_o: inst.safety.grazing_limit_deg.to_radians().cos(),
        };
        if let Some(r) = &self.reference {
            let wavelength = Wavelength::from_nm(band_nm).map_err(MeasurementError::Reference)?;
            return relative_brdf(
                &RelativeReadings {
                    signal: Reading::new(signal, u_signal),
                    signal_dark: dark,
                    reference: norm,
                    reference_dark: Reading::exact(0.0),
                    reference_brdf_rel_std: self.c.campaign.calibration.reference_rel_std,
                },
                &r.transfer,
                wavelength,
                &geometry,
                &footprint,
                &limits,
            );
        }
        let omega = gonio_brdf::radiometry::aperture_solid_angle_sr(
            inst.detector.aperture_radius_mm,
            inst.detector.distance_mm,
        );
        absolute_brdf(
            &AbsoluteReadings {
                signal: Reading::new(signal, u_signal),
                signal_dark: dark,
                direct_beam: norm,
                direct_beam_dark: Reading::exact(0.0),
                detector_solid_angle_sr: omega,
                detector_solid_angle_std_sr: omega * SOLID_ANGLE_REL_STD,
            },
            &geometry,
            &footprint,
            &limits,
        )
    }
}

pub(super) fn config_for(nm: f64, c: &Prepared) -> DetectorConfig {
    DetectorConfig {
        wavelength_nm: nm,
        averaging: c.campaign.acquisition.averaging,
        range: match c.campaign.acquisition.range {
            Range::Auto => PowerRange::Auto,
            Range::FixedW(w) => PowerRange::Fixed { full_scale_w: w },
        },
    }
}

/// The flag for a refused measurement.
pub(super) fn flag_for(e: &MeasurementError) -> String {
    match e {
        MeasurementError::OverfillsSample { .. } | MeasurementError::OverfillsDetectorField { .. } => {
            "overfilled".into()
        }
        MeasurementError::GrazingDetector { .. } => "grazing".into(),
        MeasurementError::SourceBelowHorizon { .. } => "below-horizon".into(),
        MeasurementError::NoDirectBeam { .. } => "no-direct-beam".into(),
        MeasurementError::NoReferenceSignal { .. } => "no-reference-signal".into(),
        other => format!("invalid: {other}"),
    }
}
