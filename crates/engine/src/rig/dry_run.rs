//! What only a dry-run has, as the engine sees it: a sample holder that the (simulated) operator's actions
//! change, the ground truth of the sample in it, and the instrument's clock. The engine (crates/engine/src/runner)
//! drives a dry-run through these alone and never names the simulator, so a dry-run looks like hardware to it
//! (checked by crates/engine/tests/it/layering.rs). What the simulator knows and the instrument would not tell (the
//! true BRDF) leaves here only as [`SampleHolder::truth`], which the engine stores beside each point for tests
//! and run.json and never uses in a measurement.

use std::sync::Arc;

use gonio_brdf::material::Material;
use gonio_brdf::{Direction, Wavelength};
use gonio_simulator::clock::SimClock;
use gonio_simulator::imperfections::{MeterEffects, OpticsEffects};
use gonio_simulator::optics::{Optics, SampleSpec};

use super::Rig;
use crate::error::EngineError;

/// What lies in the sample holder.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Held {
    /// Nothing: the direct beam reaches the detector.
    Empty,
    /// The campaign's sample.
    Sample,
    /// The relative method's reference sample.
    Reference,
}

/// A dry-run's sample holder.
pub trait SampleHolder: Send + Sync + std::fmt::Debug {
    /// The operator has just left `held` in the holder: from now on the detector sees it.
    fn hold(&self, held: Held);

    /// Ground truth of the campaign's sample at a geometry, asked right after the point's reading: the point
    /// BRDF and the BRDF averaged over the detector's aperture (1/sr), where the simulator can tell them, and
    /// on an imperfect instrument what each imperfection did to that reading.
    fn truth(&self, wi: &Direction, wo: &Direction, wavelength: Wavelength) -> PointTruth;

    /// The point BRDF alone (1/sr): what a sweep reading is compared with, without the aperture's integral.
    fn truth_point(&self, wi: &Direction, wo: &Direction, wavelength: Wavelength) -> Option<f64> {
        self.truth(wi, wo, wavelength).point_sr
    }
}

/// A dry-run point's ground truth (stored beside the point, never used in a measurement).
#[derive(Debug, Clone, Default, PartialEq)]
pub struct PointTruth {
    pub point_sr: Option<f64>,
    pub aperture_sr: Option<f64>,
    /// JSON: what each imperfection did to the reading ([`effects_json`]); `None` on the ideal instrument.
    pub effects_json: Option<String>,
}

/// The attribution record of one reading: the simulator's optical and meter records and the relative effects
/// derived from them, each "what this effect changed, as a fraction of the reading":
/// - `geometry`: the aperture-averaged BRDF at the true geometry over the one at the nominal geometry, - 1;
/// - `stray`: stray-light power over the power on the detector;
/// - `sample`: the sample's reflectance over the footprint against the material's (its non-uniformity);
/// - `beam`: the light reaching the detector with the true beam's profile and divergence against the ideal
///   beam's at the same geometry (the pointing acts through `geometry`, at the true directions);
/// - `source_slow`, `source_flicker`: the source's warm-up and walk, and its flicker, during the reading (the
///   normalisation readings had their own: the BRDF sees the ratio);
/// - `saturation`, `meter`: the photodiode's compression and the range's gain, nonlinearity and offset;
/// - `ambient`: the ambient light's current over the light's;
/// - `filter`: the finite band's mean of the sample's spectrum against its value at the band's centre
///   (`filter_factor / filter_total`, what remains after a direct-beam or reference reading through the same
///   filter divides out the band's power; the record keeps both).
pub fn effects_json(
    optics: &OpticsEffects,
    meter: Option<&MeterEffects>,
    nominal_aperture_sr: Option<f64>,
) -> Option<String> {
    let ratio = |a: f64, b: f64| {
        if b != 0.0 && a.is_finite() && b.is_finite() {
            a / b - 1.0
        } else {
            0.0
        }
    };
    let mut relative = serde_json::json!({
        "geometry": nominal_aperture_sr.map_or(0.0, |n| ratio(optics.true_aperture_sr, n)),
        "stray": if optics.power_w > 0.0 { optics.stray_power_w / optics.power_w } else { 0.0 },
        "sample": optics.sample_factor - 1.0,
        "beam": optics.beam_fraction_rel,
        "source_slow": optics.source_slow_factor - 1.0,
        "source_flicker": optics.source_flicker_factor - 1.0,
        "filter": ratio(optics.filter_factor, optics.filter_total),
    });
    if let (Some(m), Some(map)) = (meter, relative.as_object_mut()) {
        map.insert("saturation".into(), m.saturation_rel.into());
        map.insert("meter".into(), m.meter_rel.into());
        let ambient = if m.light_a > 0.0 {
            m.ambient_a / m.light_a
        } else {
            0.0
        };
        map.insert("ambient".into(), ambient.into());
    }
    serde_json::to_string(&serde_json::json!({
        "relative": relative,
        "optics": optics,
        "meter": meter,
    }))
    .ok()
}

/// The simulator's holder: each sample has its own optics on the same source.
#[derive(Debug)]
struct SimulatedHolder {
    rig: Rig,
    sample: Arc<Optics>,
    reference: Option<Arc<Optics>>,
}

impl SampleHolder for SimulatedHolder {
    fn hold(&self, held: Held) {
        // Whatever leaves the holder is unmounted, so that putting it back is a new mounting (with its own
        // re-seating tilt on an imperfect instrument).
        match (held, &self.reference) {
            (Held::Reference, Some(r)) => {
                self.sample.set_sample_mounted(false);
                r.set_sample_mounted(true);
                self.rig.show_optics(Arc::clone(r));
            }
            // No reference optics: nothing to swap in (the relative method always builds them).
            (Held::Reference, None) => {}
            (Held::Empty | Held::Sample, _) => {
                if let Some(r) = &self.reference {
                    r.set_sample_mounted(false);
                }
                self.rig.show_optics(Arc::clone(&self.sample));
                self.sample.set_sample_mounted(held == Held::Sample);
            }
        }
    }

    fn truth_point(&self, wi: &Direction, wo: &Direction, wavelength: Wavelength) -> Option<f64> {
        self.sample.truth(wi, wo, wavelength).ok()
    }

    fn truth(&self, wi: &Direction, wo: &Direction, wavelength: Wavelength) -> PointTruth {
        let point_sr = self.sample.truth(wi, wo, wavelength).ok();
        let aperture_sr = self
            .sample
            .truth_aperture(wi, wo, wavelength)
            .ok()
            .map(|a| a.average_sr);
        // The reading just taken left its records in the sample's optics and the meter (imperfect instrument).
        let effects = self.sample.last_effects().and_then(|optics| {
            let meter = self
                .rig
                .sim()
                .and_then(|s| s.last_meter_effects(&self.rig.file().instrument.detector.device));
            effects_json(&optics, meter.as_ref(), aperture_sr)
        });
        PointTruth {
            point_sr,
            aperture_sr,
            effects_json: effects,
        }
    }
}

/// The instrument's clock: the simulator's in dry-runs (its time is the simulated devices' time), the
/// runtime's otherwise.
#[derive(Debug, Clone, Copy)]
pub struct InstrumentClock(Clock);

#[derive(Debug, Clone, Copy)]
enum Clock {
    Sim(SimClock),
    Tokio(tokio::time::Instant),
}

impl InstrumentClock {
    /// Seconds since the clock's start.
    pub fn now_s(&self) -> f64 {
        match self.0 {
            Clock::Sim(c) => c.now_s(),
            Clock::Tokio(t0) => t0.elapsed().as_secs_f64(),
        }
    }

    /// Wait `s` seconds of instrument time (nothing for a non-finite or non-positive `s`; at most an hour).
    pub async fn sleep_s(&self, s: f64) {
        if !(s.is_finite() && s > 0.0) {
            return;
        }
        match self.0 {
            Clock::Sim(c) => c.sleep_s(s).await,
            Clock::Tokio(_) => tokio::time::sleep(std::time::Duration::from_secs_f64(s.min(3600.0))).await,
        }
    }
}

impl Rig {
    /// The instrument's clock, starting now.
    pub fn clock(&self) -> InstrumentClock {
        InstrumentClock(match self.sim() {
            Some(s) => Clock::Sim(s.clock()),
            None => Clock::Tokio(tokio::time::Instant::now()),
        })
    }

    /// A dry-run's sample holder with `sample` mounted (and `reference`, the relative method's reference
    /// sample, ready to be swapped in), each `radius_mm` in radius, on the instrument's seed (so that every
    /// sample sees the same source). None on an instrument with real devices: there the holder is a person's.
    pub fn sample_holder(
        &self,
        sample: &Material,
        reference: Option<&Material>,
        radius_mm: f64,
    ) -> Result<Option<Arc<dyn SampleHolder>>, EngineError> {
        if !self.is_dry_run() {
            return Ok(None);
        }
        let seed = self.file().simulator.seed;
        let spec = |material: &Material| sample_spec(material, radius_mm);
        let sample = self.mount_sample(spec(sample), seed)?;
        let reference = reference.map(|r| self.build_optics(spec(r), seed)).transpose()?;
        Ok(Some(Arc::new(SimulatedHolder {
            rig: self.clone(),
            sample,
            reference,
        })))
    }

    /// A dry-run's holder for the alignment: `mirror` (radius `radius_mm`) is the alignment mirror, an object of
    /// its own on the holder (its seatings are not the sample's: crate::align cannot learn the sample's from
    /// it). None on an instrument with real devices.
    ///
    /// `sample` (the sample to be measured, same radius), when given, waits in the holder's second place:
    /// [`Held::Reference`] mounts it (the characterisation reads its reflection: crate::characterise::sample).
    pub fn alignment_holder(
        &self,
        mirror: &Material,
        sample: Option<&Material>,
        radius_mm: f64,
    ) -> Result<Option<Arc<dyn SampleHolder>>, EngineError> {
        if !self.is_dry_run() {
            return Ok(None);
        }
        let seed = self.file().simulator.seed;
        let spec = |material: &Material| sample_spec(material, radius_mm);
        let optics = Arc::new(self.unshared_optics(spec(mirror), seed)?.as_alignment_mirror());
        self.show_optics(Arc::clone(&optics));
        let sample = sample.map(|m| self.build_optics(spec(m), seed)).transpose()?;
        Ok(Some(Arc::new(SimulatedHolder {
            rig: self.clone(),
            sample: optics,
            reference: sample,
        })))
    }
}

/// A sample of `material`, `radius_mm` in radius, as mounted (no orientation).
fn sample_spec(material: &Material, radius_mm: f64) -> SampleSpec {
    SampleSpec {
        material: material.clone(),
        radius_mm,
        orientation_deg: 0.0,
    }
}
