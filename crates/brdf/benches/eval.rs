//! BRDF evaluation per model, each resolved at one wavelength (`at_wavelength`), over a fixed set of 256 random
//! upper-hemisphere pairs: `cargo bench -p gonio-brdf --bench eval`. Target (issue 7): <= 50 ns per call for a
//! GGX conductor.

use std::hint::black_box;

use criterion::{Criterion, Throughput, criterion_group, criterion_main};
use gonio_brdf::{Brdf, Direction, Material, Wavelength};

fn pairs() -> Vec<(Direction, Direction)> {
    // A fixed LCG: reproducible directions without a dependency.
    let mut s: u64 = 7;
    let mut unit = move || {
        s = s
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (s >> 11) as f64 / (1u64 << 53) as f64
    };
    (0..256)
        .map(|_| {
            let wi = Direction::from_spherical(unit() * 1.5, unit() * std::f64::consts::TAU);
            let wo = Direction::from_spherical(unit() * 1.5, unit() * std::f64::consts::TAU);
            (wi, wo)
        })
        .collect()
}

fn bench(c: &mut Criterion) {
    let wl = Wavelength::DEFAULT;
    let pairs = pairs();
    let mut group = c.benchmark_group("brdf_eval");
    group.throughput(Throughput::Elements(pairs.len() as u64));
    for name in [
        "gold",
        "coloured-plastic",
        "white-styrofoam",
        "spectralon",
        "mirror",
    ] {
        let m = Material::preset(name)
            .expect("preset")
            .at_wavelength(wl)
            .expect("550 nm");
        group.bench_function(name, |b| {
            b.iter(|| {
                let mut sum = 0.0;
                for (wi, wo) in &pairs {
                    sum += m.eval(black_box(wi), black_box(wo), wl).unwrap_or(0.0);
                }
                sum
            })
        });
    }
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
