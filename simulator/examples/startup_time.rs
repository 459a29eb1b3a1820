//! How long the simulated instrument takes to start: the hidden truth drawn from the file, the optics given it,
//! and the instrument built, for the ideal file (config/instruments/simulated.toml) and the realistic one
//! (config/instruments/realistic.toml). A measurement to read, not a test: run it in release mode,
//! `cargo run --release -p gonio-simulator --example startup_time`.

use std::path::Path;
use std::sync::Arc;
use std::time::Instant;

use gonio_instrument::InstrumentFile;
use gonio_simulator::SimInstrument;
use gonio_simulator::imperfections::HiddenTruth;
use gonio_simulator::optics::{Optics, SampleSpec};
use gonio_simulator::scene::UniformScene;

/// Repetitions per file; the median is printed, so one slow start (a page fault, the other builds on the
/// machine) does not decide the figure.
const RUNS: usize = 21;

fn median_ms(mut samples: Vec<f64>) -> f64 {
    samples.sort_by(f64::total_cmp);
    samples[samples.len() / 2]
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    for name in ["simulated", "realistic"] {
        let path = root.join(format!("config/instruments/{name}.toml"));
        let file = InstrumentFile::load(&path)?;
        let material = gonio_brdf::material::Material::preset("spectralon")?;
        let (mut truth_ms, mut optics_ms, mut instrument_ms) = (Vec::new(), Vec::new(), Vec::new());
        for _ in 0..RUNS {
            let t0 = Instant::now();
            let hidden = HiddenTruth::draw(&file);
            let t1 = Instant::now();
            let sample = SampleSpec {
                material: material.clone(),
                radius_mm: file.instrument.sample_holder.max_sample_radius_mm,
                orientation_deg: 0.0,
            };
            let optics = Optics::new(&file.instrument, sample, file.simulator.seed)?
                .with_hidden_truth(hidden.as_ref());
            let t2 = Instant::now();
            let sim = SimInstrument::new(&file, Arc::new(UniformScene { power_w: 1e-4 }), 1.0)?;
            let t3 = Instant::now();
            std::hint::black_box((&optics, &sim));
            truth_ms.push((t1 - t0).as_secs_f64() * 1e3);
            optics_ms.push((t2 - t1).as_secs_f64() * 1e3);
            instrument_ms.push((t3 - t2).as_secs_f64() * 1e3);
        }
        println!(
            "{name:>10}: hidden truth {:.3} ms, optics {:.3} ms, instrument {:.3} ms (median of {RUNS})",
            median_ms(truth_ms),
            median_ms(optics_ms),
            median_ms(instrument_ms)
        );
    }
    Ok(())
}
