//! One simulated reading per seed material, on and off the specular lobe, at the default tolerance (1e-6):
//! `cargo bench -p gonio-simulator --bench reading`.

use std::hint::black_box;

use criterion::{Criterion, criterion_group, criterion_main};
use gonio_brdf::Material;
use gonio_instrument::InstrumentFile;
use gonio_simulator::optics::{Optics, SampleSpec};
use gonio_simulator::scene::{Band, Pose};

fn bench(c: &mut Criterion) {
    let inst = InstrumentFile::simulated().instrument;
    let band = Band {
        band_nm: Some(550.0),
        transmission: 0.5,
    };
    let on = Pose {
        light_deg: 30.0,
        detector_deg: -30.0,
        tilt_deg: 0.0,
        rotation_deg: 0.0,
    };
    let off = Pose {
        light_deg: 30.0,
        detector_deg: -60.0,
        tilt_deg: 0.0,
        rotation_deg: 0.0,
    };
    let mut group = c.benchmark_group("simulator_reading");
    for name in [
        "mirror",
        "white-styrofoam",
        "construction-paper",
        "coloured-plastic",
        "gold",
    ] {
        let sample = SampleSpec {
            material: Material::preset(name).expect("preset"),
            radius_mm: 25.0,
            orientation_deg: 0.0,
        };
        let optics = Optics::new(&inst, sample, 1)
            .expect("optics")
            .with_source_noise(false)
            .with_source_drift(false);
        for (label, pose) in [("specular", on), ("off-specular", off)] {
            group.bench_function(format!("{name}/{label}"), |b| {
                b.iter(|| optics.reading(black_box(&pose), &band, 0.0).map(|r| r.power_w))
            });
        }
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
