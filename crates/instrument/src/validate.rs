//! [`Instrument::validate`]: the consistency checks that serde cannot express (unique names, devices and axes
//! that refer to each other, limits, the geometry's required axes, the simulator's terms). Every message names
//! the table and key.

use std::collections::BTreeSet;

use crate::{AxisRole, GeometryKind, Instrument, InvalidInstrument, Protocol};

/// The longest reply latency a device may claim (ms): the drivers' reply timeouts are a few hundred ms.
pub const MAX_REPLY_LATENCY_MS: f64 = 250.0;

impl Instrument {
    /// Consistency checks that serde cannot express. The message names the table and key.
    pub fn validate(&self) -> Result<(), InvalidInstrument> {
        self.check().map_err(InvalidInstrument)
    }

    fn check(&self) -> Result<(), String> {
        let mut names = BTreeSet::new();
        for d in &self.devices {
            if !names.insert(d.name.as_str()) {
                return Err(format!(
                    "[[instrument.devices]]: device name {:?} is used twice",
                    d.name
                ));
            }
            if let Some(ms) = d.reply_latency_ms
                && !(ms.is_finite() && (0.0..=MAX_REPLY_LATENCY_MS).contains(&ms))
            {
                return Err(format!(
                    "[[instrument.devices]] {:?}: reply_latency_ms = {ms} is not between 0 and {MAX_REPLY_LATENCY_MS} ms",
                    d.name
                ));
            }
            // Below zero when the meter starts integrating later after its request than the controller takes
            // its position after its query: what dating the sweeps' readings needs is the difference.
            if let Some(ms) = d.position_sampled_ms
                && !(ms.is_finite() && (-MAX_REPLY_LATENCY_MS..=MAX_REPLY_LATENCY_MS).contains(&ms))
            {
                return Err(format!(
                    "[[instrument.devices]] {:?}: position_sampled_ms = {ms} is not between -{MAX_REPLY_LATENCY_MS} and {MAX_REPLY_LATENCY_MS} ms",
                    d.name
                ));
            }
        }
        let mut roles = BTreeSet::new();
        let mut axis_names = BTreeSet::new();
        for a in &self.axes {
            let at = format!("[[instrument.axes]] {:?}", a.name);
            if !axis_names.insert(a.name.as_str()) {
                return Err(format!("{at}: axis name is used twice"));
            }
            if !roles.insert(a.role) {
                return Err(format!("{at}: role {:?} is given to two axes", a.role));
            }
            let device = self
                .device(&a.device)
                .ok_or_else(|| format!("{at}: device {:?} is not declared", a.device))?;
            match device.protocol {
                Protocol::Smc100 if !(1..=31).contains(&a.address) => {
                    return Err(format!(
                        "{at}: address {} is outside the SMC100 range 1..31",
                        a.address
                    ));
                }
                Protocol::ZaberAscii if !(1..=99).contains(&a.address) => {
                    return Err(format!(
                        "{at}: address {} is outside the Zaber range 1..99",
                        a.address
                    ));
                }
                Protocol::ZaberAscii if !a.microstep_deg.is_some_and(|m| m > 0.0 && m.is_finite()) => {
                    return Err(format!(
                        "{at}: a Zaber axis needs microstep_deg > 0 (degrees per microstep)"
                    ));
                }
                Protocol::Fw102c | Protocol::Pm100 => {
                    return Err(format!("{at}: device {:?} is not a motion controller", a.device));
                }
                _ => {}
            }
            if !(a.min_deg.is_finite() && a.max_deg.is_finite() && a.min_deg < a.max_deg) {
                return Err(format!(
                    "{at}: need min_deg < max_deg, got {} and {}",
                    a.min_deg, a.max_deg
                ));
            }
            for (key, v) in [
                ("max_speed_deg_s", a.max_speed_deg_s),
                ("accel_deg_s2", a.accel_deg_s2),
                ("encoder_resolution_deg", a.encoder_resolution_deg),
                ("tolerance_deg", a.tolerance_deg),
            ] {
                if !(v.is_finite() && v > 0.0) {
                    return Err(format!("{at}: {key} must be > 0, got {v}"));
                }
            }
            for (key, v) in [("backlash_deg", a.backlash_deg), ("settle_s", a.settle_s)] {
                if !(v.is_finite() && v >= 0.0) {
                    return Err(format!("{at}: {key} must be >= 0, got {v}"));
                }
            }
            if a.direction != 1 && a.direction != -1 {
                return Err(format!("{at}: direction must be 1 or -1, got {}", a.direction));
            }
        }
        let needed: &[AxisRole] = match self.geometry {
            GeometryKind::Reference => &[
                AxisRole::LightArm,
                AxisRole::DetectorArm,
                AxisRole::SampleTilt,
                AxisRole::SampleRotation,
            ],
            GeometryKind::InPlane => &[
                AxisRole::LightArm,
                AxisRole::DetectorArm,
                AxisRole::SampleRotation,
            ],
        };
        for role in needed {
            if !roles.contains(role) {
                return Err(format!(
                    "[[instrument.axes]]: the {:?} geometry needs an axis with role {role:?}",
                    self.geometry
                ));
            }
        }
        if self.geometry == GeometryKind::InPlane && roles.contains(&AxisRole::SampleTilt) {
            return Err("[[instrument.axes]]: the in-plane geometry has no sample-tilt axis".into());
        }
        let s = &self.source;
        if !(s.power_w.is_finite() && s.power_w > 0.0) {
            return Err(format!(
                "[instrument.source]: power_w must be > 0, got {}",
                s.power_w
            ));
        }
        if !(s.beam_radius_mm.is_finite() && s.beam_radius_mm > 0.0) {
            return Err(format!(
                "[instrument.source]: beam_radius_mm must be > 0, got {}",
                s.beam_radius_mm
            ));
        }
        let d = &self.detector;
        match self.device(&d.device).map(|dev| dev.protocol) {
            Some(Protocol::Pm100) => {}
            Some(_) => {
                return Err(format!(
                    "[instrument.detector]: device {:?} is not a power meter",
                    d.device
                ));
            }
            None => {
                return Err(format!(
                    "[instrument.detector]: device {:?} is not declared",
                    d.device
                ));
            }
        }
        for (key, v) in [
            ("aperture_radius_mm", d.aperture_radius_mm),
            ("distance_mm", d.distance_mm),
            ("field_radius_mm", d.field_radius_mm),
        ] {
            if !(v.is_finite() && v > 0.0) {
                return Err(format!("[instrument.detector]: {key} must be > 0, got {v}"));
            }
        }
        if d.ranges_w.is_empty() || d.ranges_w.iter().any(|r| !(r.is_finite() && *r > 0.0)) {
            return Err("[instrument.detector]: ranges_w must list positive full-scale powers in W".into());
        }
        if d.ranges_w.windows(2).any(|w| w[0] >= w[1]) {
            return Err("[instrument.detector]: ranges_w must be increasing".into());
        }
        match &self.filter_wheel {
            Some(w) => {
                match self.device(&w.device).map(|dev| dev.protocol) {
                    Some(Protocol::Fw102c) => {}
                    _ => {
                        return Err(format!(
                            "[instrument.filter_wheel]: device {:?} is not a declared fw102c wheel",
                            w.device
                        ));
                    }
                }
                let mut seen = BTreeSet::new();
                for p in &w.positions {
                    if !seen.insert(p.position) || !(1..=12).contains(&p.position) {
                        return Err(format!(
                            "[instrument.filter_wheel]: position {} is repeated or outside 1..12",
                            p.position
                        ));
                    }
                    if p.blank == p.band_nm.is_some() {
                        return Err(format!(
                            "[instrument.filter_wheel]: position {} must be either blank or have band_nm",
                            p.position
                        ));
                    }
                }
            }
            None if s.wavelength_nm.is_none() => {
                return Err("[instrument.source]: without a filter wheel, wavelength_nm is required".into());
            }
            None => {}
        }
        let safety = &self.safety;
        if !(0.0..90.0).contains(&safety.grazing_limit_deg) {
            return Err(format!(
                "[instrument.safety]: grazing_limit_deg must be in [0, 90), got {}",
                safety.grazing_limit_deg
            ));
        }
        // A negative (or NaN) separation or retro-block angle would disable the collision and beam-block checks.
        for (key, v) in [
            ("min_arm_separation_deg", safety.min_arm_separation_deg),
            ("retro_block_deg", safety.retro_block_deg),
        ] {
            if !(0.0..180.0).contains(&v) {
                return Err(format!("[instrument.safety]: {key} must be in [0, 180), got {v}"));
            }
        }
        self.validate_simulation_terms()
    }

    /// The remaining numbers the scheduler and the simulator compute with: finite and in their physical range.
    fn validate_simulation_terms(&self) -> Result<(), String> {
        let r = self.sample_holder.max_sample_radius_mm;
        if !(r.is_finite() && r > 0.0) {
            return Err(format!(
                "[instrument.sample_holder]: max_sample_radius_mm must be > 0, got {r}"
            ));
        }
        let s = &self.source;
        for (key, v) in [
            ("divergence_deg", s.divergence_deg),
            ("drift_per_hour", s.drift_per_hour),
            ("relative_noise", s.relative_noise),
            ("flicker_rel", s.flicker_rel),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(format!("[instrument.source]: {key} must be >= 0, got {v}"));
            }
        }
        for (key, v, limit) in [
            ("pointing_u_deg", s.pointing_u_deg, 10.0),
            ("offset_u_mm", s.offset_u_mm, 10.0),
        ] {
            if let Some(v) = v
                && !(v.is_finite() && (0.0..=limit).contains(&v))
            {
                return Err(format!(
                    "[instrument.source]: {key} is a standard uncertainty in [0, {limit}], got {v}"
                ));
            }
        }
        if let Some(nm) = s.wavelength_nm
            && !(nm.is_finite() && nm > 0.0)
        {
            return Err(format!(
                "[instrument.source]: wavelength_nm must be > 0, got {nm}"
            ));
        }
        if let Some(u) = self.alignment_u_deg
            && !(u.is_finite() && (0.0..=10.0).contains(&u))
        {
            return Err(format!(
                "[instrument]: alignment_u_deg is a standard uncertainty in degrees, in [0, 10], got {u}"
            ));
        }
        let h = &self.sample_holder;
        for (key, v, unit, limit) in [
            ("reseat_u_deg", h.reseat_u_deg, "degrees", 5.0),
            ("tilt_u_deg", h.tilt_u_deg, "degrees", 10.0),
            ("centring_u_mm", h.centring_u_mm, "millimetres", 10.0),
        ] {
            if let Some(u) = v
                && !(u.is_finite() && (0.0..=limit).contains(&u))
            {
                return Err(format!(
                    "[instrument.sample_holder]: {key} is a standard uncertainty in {unit}, in [0, {limit}], got {u}"
                ));
            }
        }
        if let Some(t) = s.colour_temperature_k
            && !(t.is_finite() && (500.0..=20_000.0).contains(&t))
        {
            return Err(format!(
                "[instrument.source]: colour_temperature_k must be between 500 and 20000 (K), got {t}"
            ));
        }
        let d = &self.detector;
        for (key, value) in [
            ("range_gain_u", d.range_gain_u),
            ("solid_angle_u", d.solid_angle_u),
        ] {
            if let Some(u) = value
                && !(u.is_finite() && (0.0..1.0).contains(&u))
            {
                return Err(format!(
                    "[instrument.detector]: {key} is a relative standard uncertainty in [0, 1), got {u}"
                ));
            }
        }
        crate::signature::SignatureUncertainty::from_detector(d).map_err(|e| e.0)?;
        if !(d.dark_current_a.is_finite() && d.dark_current_a >= 0.0) {
            return Err(format!(
                "[instrument.detector]: dark_current_a must be >= 0, got {}",
                d.dark_current_a
            ));
        }
        if !(d.amplifier_noise_a_per_rthz.is_finite() && (0.0..1e-6).contains(&d.amplifier_noise_a_per_rthz))
        {
            return Err(format!(
                "[instrument.detector]: amplifier_noise_a_per_rthz is a current noise density in A/sqrt(Hz), in \
                 [0, 1e-6), got {}",
                d.amplifier_noise_a_per_rthz
            ));
        }
        if d.averaging == 0 {
            return Err("[instrument.detector]: averaging must be at least 1".into());
        }
        let [lo, hi] = d.sensor_wavelength_nm;
        if !(lo.is_finite() && hi.is_finite() && lo > 0.0 && lo < hi) {
            return Err(format!(
                "[instrument.detector]: sensor_wavelength_nm must be [min, max] with 0 < min < max, got [{lo}, {hi}]"
            ));
        }
        if let Some(w) = &self.filter_wheel {
            if w.speed > 1 {
                return Err(format!(
                    "[instrument.filter_wheel]: speed must be 0 (slow) or 1 (fast), got {}",
                    w.speed
                ));
            }
            if !(w.seconds_per_position.is_finite() && w.seconds_per_position >= 0.0) {
                return Err(format!(
                    "[instrument.filter_wheel]: seconds_per_position must be >= 0, got {}",
                    w.seconds_per_position
                ));
            }
            for p in &w.positions {
                if !(0.0..=1.0).contains(&p.transmission) {
                    return Err(format!(
                        "[instrument.filter_wheel]: position {}: transmission must be in [0, 1], got {}",
                        p.position, p.transmission
                    ));
                }
                if let Some(nm) = p.band_nm
                    && !(nm.is_finite() && nm > 0.0)
                {
                    return Err(format!(
                        "[instrument.filter_wheel]: position {}: band_nm must be > 0, got {nm}",
                        p.position
                    ));
                }
                if let Some(bw) = p.bandwidth_nm
                    && !(bw.is_finite() && bw >= 0.0)
                {
                    return Err(format!(
                        "[instrument.filter_wheel]: position {}: bandwidth_nm must be >= 0, got {bw}",
                        p.position
                    ));
                }
                for (key, value) in [
                    ("centre_u_nm", p.centre_u_nm),
                    ("bandwidth_u_nm", p.bandwidth_u_nm),
                ] {
                    if let Some(u) = value
                        && !(u.is_finite() && u >= 0.0)
                    {
                        return Err(format!(
                            "[instrument.filter_wheel]: position {}: {key} must be >= 0 (nm), got {u}",
                            p.position
                        ));
                    }
                }
                if let Some(t) = p.out_of_band_transmission
                    && !(t.is_finite() && (0.0..1.0).contains(&t))
                {
                    return Err(format!(
                        "[instrument.filter_wheel]: position {}: out_of_band_transmission must be in [0, 1) \
                         (absolute: optical density 5 is 1e-5), got {t}",
                        p.position
                    ));
                }
            }
        }
        Ok(())
    }
}
