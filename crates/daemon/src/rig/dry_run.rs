//! What only a dry-run has, as the engine sees it: a sample holder that the (simulated) operator's actions
//! change, the ground truth of the sample in it, and the instrument's clock. The engine (crates/daemon/src/runner)
//! drives a dry-run through these alone and never names the simulator, so a dry-run looks like hardware to it
//! (checked by crates/daemon/tests/layering.rs). What the simulator knows and the instrument would not tell (the
//! true BRDF) leaves here only as [`SampleHolder::truth`], which the engine stores beside each point for tests
//! and run.json and never uses in a measurement.

use std::sync::Arc;

use gonio_brdf::material::Material;
use gonio_brdf::{Direction, Wavelength};
use gonio_simulator::clock::SimClock;
use gonio_simulator::optics::{Optics, SampleSpec};

use super::Rig;
use crate::engine::EngineError;

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

    /// Ground truth of the campaign's sample at a geometry: the point BRDF and the BRDF averaged over the
    /// detector's aperture (1/sr), where the simulator can tell them.
    fn truth(&self, wi: &Direction, wo: &Direction, wavelength: Wavelength) -> (Option<f64>, Option<f64>);
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

    fn truth(&self, wi: &Direction, wo: &Direction, wavelength: Wavelength) -> (Option<f64>, Option<f64>) {
        (
            self.sample.truth(wi, wo, wavelength).ok(),
            self.sample
                .truth_aperture(wi, wo, wavelength)
                .ok()
                .map(|a| a.average_sr),
        )
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
        let spec = |material: &Material| SampleSpec {
            material: material.clone(),
            radius_mm,
            orientation_deg: 0.0,
        };
        let sample = self.mount_sample(spec(sample), seed)?;
        let reference = reference.map(|r| self.build_optics(spec(r), seed)).transpose()?;
        Ok(Some(Arc::new(SimulatedHolder {
            rig: self.clone(),
            sample,
            reference,
        })))
    }
}
