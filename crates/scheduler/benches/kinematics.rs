//! Inverse kinematics per geometry, and ordering a 10,000-point plan (target < 5 s):
//! `cargo bench -p gonio-scheduler --bench kinematics`.

use std::hint::black_box;

use criterion::{Criterion, criterion_group, criterion_main};
use gonio_instrument::InstrumentFile;
use gonio_scheduler::kinematics::{Geometry, Kinematics, Pose};
use gonio_scheduler::order;
use gonio_scheduler::timing::TimeModel;

fn bench(c: &mut Criterion) {
    let inst = InstrumentFile::simulated().instrument;
    let kin = Kinematics::new(&inst);
    let hint = Pose::new(0.0, 0.0, 0.0, 0.0);
    let (wi, wo) = Geometry::new(35.0, 20.0, 50.0, 170.0).directions();
    c.bench_function("inverse_kinematics", |b| {
        b.iter(|| {
            kin.solutions(black_box(&wi), black_box(&wo), &hint)
                .map(|v| v.len())
        })
    });
    // 10,000 poses on a lattice of reachable arm and stage angles.
    let poses: Vec<Pose> = (0..10_000)
        .map(|k| {
            let (a, b, c, d) = (k % 10, (k / 10) % 10, (k / 100) % 10, k / 1000);
            Pose::new(
                -80.0 + 16.0 * a as f64,
                -75.0 + 15.0 * b as f64,
                -60.0 + 12.0 * c as f64,
                -170.0 + 34.0 * d as f64,
            )
        })
        .collect();
    let time = TimeModel::new(&inst);
    let mut group = c.benchmark_group("order");
    group.sample_size(10);
    group.bench_function("order_10k", |b| {
        b.iter(|| order::order(black_box(&poses), None, &time).len())
    });
    group.finish();
}

criterion_group!(benches, bench);
criterion_main!(benches);
