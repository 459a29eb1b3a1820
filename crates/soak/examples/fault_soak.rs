//! One fault soak with its full report on stdout, for investigating a failure:
//! `cargo run -p gonio-soak --example fault_soak -- POINTS SEED [stressed]`
//! (the warnings log goes to `fault-soak.log` in the current directory).

fn main() {
    let mut args = std::env::args().skip(1);
    let points: u64 = args.next().and_then(|a| a.parse().ok()).unwrap_or(300);
    let seed: u64 = args.next().and_then(|a| a.parse().ok()).unwrap_or(8);
    let stressed = args.next().is_some_and(|a| a == "stressed");
    let dir = match tempfile::tempdir() {
        Ok(d) => d,
        Err(e) => {
            eprintln!("cannot create a temporary directory: {e}");
            std::process::exit(2);
        }
    };
    let data = dir.path().to_path_buf();
    let mut cfg = if stressed {
        gonio_soak::fault_soak::FaultSoakConfig::stressed(points, seed, data)
    } else {
        gonio_soak::fault_soak::FaultSoakConfig::issue_8(points, seed, data)
    };
    cfg.log_file = Some("fault-soak.log".into());
    match gonio_soak::fault_soak::run_fault_soak(&cfg) {
        Ok(r) => {
            println!(
                "{:#?}\n{:#?}\n{:#?}\n{:#?}",
                r.committed.points, r.injected, r.log, r.events
            );
            println!(
                "state {} {:?}, pauses {:?}, rows {}, instrument {:.0} s, sim clock {:.0} s, wall {:.1} s",
                r.final_state,
                r.last_error,
                r.pauses,
                r.committed.rows,
                r.instrument_s,
                r.sim_clock_s,
                r.wall_s
            );
            println!("violations: {:#?}", r.violations());
        }
        Err(e) => {
            eprintln!("fault soak: {e}");
            std::process::exit(2);
        }
    }
}
