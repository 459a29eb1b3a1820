//! Sections (3) to (5) of BENCHMARKS.md: end-to-end throughput, micro-benchmarks (criterion's latest results
//! included) and the large stress tier's last record.

use super::*;

/// Section (3).
pub(super) fn throughput_markdown(t: &ThroughputRuns) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "## 3. End-to-end dry-run throughput\n");
    let _ = writeln!(
        s,
        "Through the real engine (`gonio_engine::run_campaign`), the real drivers (SMC100, Zaber, FW102C, PM100) \
         and the simulator, a stored campaign run to `completed`: an isotropic one-band grid on coloured plastic \
         (theta 0-80 at {} deg, delta phi at twice that), darks every 200 points, direct-beam references with the \
         simulated operator, every point committed to the SQLite store in its own transaction (WAL; dry-runs commit \
         with synchronous = NORMAL: a point survives a crash of the process, not of the OS; campaigns on the real \
         instrument fsync every point). Steady state: from the first point's event to the last (start-up \
         excluded: homing, the first calibration). Details: crates/bench/src/throughput.rs.\n",
        t.campaign_points_step_deg
    );
    let _ = writeln!(
        s,
        "| run | points | wall (s) | points/s overall | steady points/s | steady ms/point | instrument time (s) | target | result |"
    );
    let _ = writeln!(s, "|---|---|---|---|---|---|---|---|---|");
    let row =
        |s: &mut String, name: &str, r: &Result<throughput::Throughput, String>, target: Option<f64>| match r
        {
            Ok(r) => {
                let (tt, res) = match target {
                    Some(x) => (
                        format!(">= {x:.0} points/s"),
                        met(r.steady_points_per_s() >= x).to_string(),
                    ),
                    None => ("-".into(), "-".into()),
                };
                let _ = writeln!(
                    s,
                    "| {name} | {} | {:.2} | {:.0} | {:.0} | {:.3} | {:.0} | {tt} | {res} |",
                    r.points,
                    r.wall_s,
                    r.points_per_s(),
                    r.steady_points_per_s(),
                    r.steady_ms_per_point(),
                    r.instrument_s
                );
            }
            Err(e) => {
                let _ = writeln!(s, "| {name} | not measured: {e} | | | | | | | |");
            }
        };
    row(
        &mut s,
        "in process, paused clock, store on disk (ext4 temp dir)",
        &t.in_process,
        Some(5000.0),
    );
    if let Some(r) = &t.in_process_tmpfs {
        row(
            &mut s,
            "in process, paused clock, store on tmpfs (/dev/shm)",
            r,
            None,
        );
    }
    row(
        &mut s,
        &format!(
            "serial devices on pseudo-terminals, real clock, time scale {:.0e} ({} deg grid)",
            throughput::PTY_TIME_SCALE,
            t.pty_step_deg
        ),
        &t.ptys,
        Some(500.0),
    );
    // Overhead per point with device time excluded: the paused-clock steady state.
    let overhead =
        |r: &Result<throughput::Throughput, String>| r.as_ref().ok().map(|r| r.steady_ms_per_point());
    let _ = writeln!(s, "\n### Daemon overhead per point, device time excluded\n");
    let _ = writeln!(
        s,
        "Under the paused clock no device time passes in wall time, so the steady wall time per point is the \
         overhead of the engine, the drivers' protocol handling, the in-process simulator (device emulation and \
         optics: about 5 us of the reading, section 1) and the store. Target: <= 0.2 ms per point.\n"
    );
    let _ = writeln!(s, "| store | ms/point | target | result |");
    let _ = writeln!(s, "|---|---|---|---|");
    if let Some(o) = overhead(&t.in_process) {
        let _ = writeln!(
            s,
            "| disk (as shipped for dry-runs) | {o:.3} | <= 0.2 ms | {} |",
            met(o <= 0.2)
        );
    }
    if let Some(Some(o)) = t.in_process_tmpfs.as_ref().map(overhead) {
        let _ = writeln!(
            s,
            "| tmpfs (no disk writes) | {o:.3} | <= 0.2 ms | {} |",
            met(o <= 0.2)
        );
    }
    let _ = writeln!(s, "\n### A 10,000-point campaign through `gonio run`\n");
    match &t.gonio_run {
        Ok((n, wall)) => {
            let _ = writeln!(
                s,
                "`gonio run` (release binary, dry-run on the paused clock) of a {n}-point campaign (the grid above at \
                 {} deg, bands 450, 550 and 650 nm): {wall:.1} s wall, {:.0} points/s, planning included. Issue 3 \
                 says such a campaign \"dry-runs in seconds\".\n",
                t.run_step_deg,
                *n as f64 / wall
            );
        }
        Err(e) => {
            let _ = writeln!(s, "not measured: {e}\n");
        }
    }
    let _ = writeln!(
        s,
        "Where the time goes (a perf profile of the in-process run with the store on disk, taken while \
         developing this benchmark, not by this run): about 41 device exchanges per point (status polls while \
         the axes move are most of them: 13 SMC100 `TS`, 8 Zaber `get pos`; since then the drivers no longer \
         read where a move starts when the last move's read-back says where the axis came to rest, two `TP` \
         fewer before each SMC100 `PA` and one `get pos` before each Zaber `move abs`), each costing \
         microseconds in the \
         driver, in the emulated device and in tokio's timers: drivers 26 %, device emulation 26 %, tokio timers \
         and parking 20 %, SQLite 9 %, engine and store 8 % (about 0.07 ms per point), BRDF evaluation 2.5 %. \
         The in-process targets are missed because of that exchange count, which is what the real devices need \
         (a status poll at most every 50 ms while a move runs, so that a stall is seen in time), not because of \
         the engine. Over pseudo-terminals, each exchange is a real system call pair on each side; the emulated \
         devices send each reply once its bytes would have crossed the serial line (about 2 ms at 57600 baud, \
         simulated), written at once when that is under 50 us of real time at the chosen time scale.\n"
    );
    s
}

/// The criterion results, read from their last run.
/// The criterion results (read from the target directory's `criterion/`, named relatively: the report is
/// committed, and the machine's own paths stay out of it).
pub(super) fn criterion_markdown(results: &[criterion_summary::CriterionResult]) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "### Criterion micro-benchmarks (their last run)\n");
    if results.is_empty() {
        let _ = writeln!(
            s,
            "No criterion results under the target directory's `criterion/`: run `{CRITERION}` first (they are \
             not run by this command: each takes minutes of statistics).\n"
        );
        return s;
    }
    let _ = writeln!(
        s,
        "Read from the target directory's `criterion/` (written by `{CRITERION}`, run before this report). Time \
         per iteration: criterion's typical estimate with its 95% interval; per element when the benchmark declares \
         a throughput (the BRDF benches evaluate 256 direction pairs per iteration).\n"
    );
    let _ = writeln!(
        s,
        "| benchmark | per iteration | 95% interval | per element | target | result |"
    );
    let _ = writeln!(s, "|---|---|---|---|---|---|");
    let fmt = |ns: f64| {
        if ns >= 1e9 {
            format!("{:.2} s", ns / 1e9)
        } else if ns >= 1e6 {
            format!("{:.2} ms", ns / 1e6)
        } else if ns >= 1e3 {
            format!("{:.2} us", ns / 1e3)
        } else {
            format!("{ns:.1} ns")
        }
    };
    for r in results {
        let (target, result) = if r.id == "brdf_eval/gold" {
            (
                "<= 50 ns (GGX conductor)",
                met(r.per_element_ns() <= 50.0).to_string(),
            )
        } else if r.id.contains("order_10k") {
            ("< 5 s", met(r.typical_ns < 5e9).to_string())
        } else {
            ("-", "-".to_string())
        };
        let _ = writeln!(
            s,
            "| {} | {} | {} .. {} | {} | {target} | {result} |",
            r.id,
            fmt(r.typical_ns),
            fmt(r.lower_ns),
            fmt(r.upper_ns),
            fmt(r.per_element_ns())
        );
    }
    s.push('\n');
    s
}

/// The large stress tier's last record.
pub(super) fn stress_markdown(root: &Path) -> String {
    let mut s = String::new();
    let _ = writeln!(s, "### Large tier: last record\n");
    match stress::last_record(root) {
        Some(record) => {
            let _ = writeln!(
                s,
                "Written by `cargo run --release -p gonio-bench -- --only stress-large` (or `--stress-large` before a \
                 full report) into {} and quoted here:\n\n```\n{}```\n",
                stress::RECORD,
                record
            );
        }
        None => {
            let _ = writeln!(
                s,
                "Not run yet: `cargo run --release -p gonio-bench -- --only stress-large` runs `{}` and records it.\n",
                stress::COMMAND
            );
        }
    }
    s
}
