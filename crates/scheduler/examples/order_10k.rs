//! Measures how long ordering a 10,000-point plan takes (run in release):
//! `cargo run --release -p gonio-scheduler --example order_10k`

use std::time::Instant;

use gonio_instrument::InstrumentFile;
use gonio_scheduler::plan::{self, BuildContext, PlanSpec, SampleTraits};
use gonio_scheduler::schedule;
use gonio_scheduler::timing::TimeModel;

fn main() {
    let instrument = InstrumentFile::simulated().instrument;
    // Anisotropic full grid: 9 x 18 x 9 x 18 = 26,244 requests, about 10,000 kept after the reductions.
    let text = "[plan]\nbands_nm = [550.0]\n[plan.grid]\nkind = \"full\"\n\
                theta_i_deg = { from = 0.0, to = 80.0, step = 10.0 }\nphi_i_deg = { from = 0.0, to = 340.0, step = 20.0 }\n\
                theta_o_deg = { from = 0.0, to = 80.0, step = 10.0 }\nphi_o_deg = { from = 0.0, to = 340.0, step = 20.0 }\n";
    let spec = PlanSpec::from_toml(text, "order_10k").expect("campaign");
    let ctx = BuildContext {
        instrument: &instrument,
        traits: SampleTraits {
            isotropic: false,
            spectrally_flat: true,
        },
        sample_radius_mm: None,
        start: None,
    };
    let t0 = Instant::now();
    let plan = plan::build(&spec, &ctx).expect("plan");
    let t1 = Instant::now();
    let time = TimeModel::new(&instrument);
    let poses: Vec<_> = plan.geometries.iter().map(|g| g.candidates[0].0).collect();
    let t_order = Instant::now();
    let tour = gonio_scheduler::order::order(&poses, None, &time);
    println!(
        "order alone: {:.2} s for {} poses",
        t_order.elapsed().as_secs_f64(),
        tour.len()
    );
    let t_sched = Instant::now();
    let sched = schedule::schedule(&plan, &time, None);
    let t2 = Instant::now();
    let (o, r) = (&sched.breakdown, &sched.raster);
    println!(
        "kept {} geometries ({} requested)",
        plan.geometries.len(),
        plan.requested
    );
    println!(
        "build {:.2} s, order+schedule {:.2} s",
        (t1 - t0).as_secs_f64(),
        (t2 - t_sched).as_secs_f64()
    );
    println!(
        "ordered {:.0} s, raster {:.0} s, lower bound {:.0} s; motion+settle ratio {:.3}",
        o.total_s(),
        r.total_s(),
        sched.lower_bound_s,
        (o.motion_s + o.settle_s) / (r.motion_s + r.settle_s)
    );
}
