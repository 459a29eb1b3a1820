//! The benchmark report of issue 7: `cargo run --release -p gonio-bench` (from the workspace root).
//!
//! Sections: (1) simulator readings, time against actual error versus a brute-force reference, and the adaptive
//! integrator against a fixed rule ([`readings`]); (2) campaigns: plan strategies per seed material, predicted
//! instrument time against BRDF error on a dense validation set ([`campaigns`]), and the ordered plan against
//! raster order with a lower bound ([`ordering`]); (3) end-to-end dry-run throughput through the engine and the
//! drivers, in process and over pseudo-terminals, and a 10,000-point `gonio run` ([`throughput`]); (4)
//! micro-benchmarks: `gonio brdf eval` streaming (the release binary, built beforehand with
//! `cargo build --release -p gonio`; skipped and said so when absent), BRDF evaluation per model, ordering 10,000
//! poses, and the latest criterion results ([`criterion_summary`]); (5) the large stress tier's last record
//! ([`stress`]; `--stress-large` runs it first).
//!
//! Writes `BENCHMARKS.md` at the workspace root and SVG plots under `docs/bench/`. Every number is measured by
//! this run (criterion's and the large stress tier's are read from their own last run, and say so); nothing is
//! edited by hand. `--quick` shrinks every section (for a smoke run; noisier, smaller plans).
//! (6) the time model: predicted against dry-run instrument time for every shipped campaign, the demo's grid at
//! three densities and campaigns not in the repository, on both instrument files ([`time_model`]; `--before
//! BINARY` also runs each through a gonio built from an earlier commit, side by side).
//! `--accuracy` writes ACCURACY.md instead (issue 29's accuracy table, crate::accuracy).
//! (7) sweeps against stop-and-go per seed material on both instrument files ([`sweeps`]).
//! `--only <readings|campaigns|throughput|budget|timing|sweeps|follow|curves>` prints one section and leaves BENCHMARKS.md alone; `--only stress-large` runs
//! the large stress tier and records it (docs/bench/stress-large.txt) without writing the report.

mod accuracy;
mod campaigns;
mod criterion_summary;
mod curves;
mod error_budget;
mod follow;
mod gonio_run;
mod ordering;
mod plot;
mod readings;
mod stress;
mod sweeps;
mod throughput;
mod time_model;

use std::fmt::Write as _;
use std::hint::black_box;
use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Instant;

use gonio_brdf::{Brdf, Direction, Material, Wavelength};
use gonio_instrument::InstrumentFile;
use gonio_scheduler::plan::{self, BuildContext, PlanSpec, SampleTraits};
use gonio_scheduler::timing::TimeModel;

use readings::{FixedComparison, ReadingPoint, time_us};

mod bring_up;
mod measure;
mod section_campaigns;
mod section_micro;
mod section_readings;

use measure::{
    EvalRate, ThroughputRuns, eval_ns_per_model, eval_throughput, load_average, ordering_time, rustc_version,
    throughput_section,
};
use section_campaigns::campaign_section;
use section_micro::{criterion_markdown, stress_markdown, throughput_markdown};
use section_readings::readings_section;

const COMMAND: &str = "cargo build --release -p gonio && cargo run --release -p gonio-bench";
/// The criterion benches the report summarises (run them before the report to refresh the numbers).
const CRITERION: &str = "cargo bench -p gonio-brdf --bench eval && cargo bench -p gonio-scheduler --bench kinematics \
                         && cargo bench -p gonio-simulator --bench reading";

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let quick = args.iter().any(|a| a == "--quick");
    if args.iter().any(|a| a == "--accuracy") {
        write_accuracy(&args, quick);
        return;
    }
    if let Some(only) = args.iter().skip_while(|a| *a != "--only").nth(1) {
        run_only(only, quick);
        return;
    }
    let started = Instant::now();
    let min_s = if quick { 0.005 } else { 0.05 };
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..");
    let target = target_dir();
    let load_start = load_average();
    let inst = InstrumentFile::simulated().instrument;
    let docs = root.join("docs/bench");
    if let Err(e) = std::fs::create_dir_all(&docs) {
        eprintln!("cannot create {}: {e}", docs.display());
    }
    let mut loads: Vec<(&'static str, String)> = Vec::new();

    if args.iter().any(|a| a == "--stress-large") {
        eprintln!("(5) large stress tier (cargo test --release)...");
        stress::run_and_record(&root, &load_start);
    }

    eprintln!("(1) simulator readings...");
    loads.push(("1 readings", load_average()));
    let (points, fixed) = readings::run(&inst, min_s);
    let apriori = readings::run_apriori(&inst, min_s);

    eprintln!("(2) campaigns...");
    loads.push(("2 campaigns", load_average()));
    let t = Instant::now();
    let sizes = campaigns::Sizes::new(quick);
    let setup = campaigns::Setup::new(&inst, sizes.validation_points);
    let rec = campaigns::reconstructor(&inst);
    let mut campaign_points = Vec::new();
    for m in readings::MATERIALS {
        eprintln!("    {m}...");
        campaign_points.extend(campaigns::run_material(&setup, &sizes, m, &rec));
    }
    let campaigns_s = t.elapsed().as_secs_f64();
    let orderings: Vec<Result<ordering::OrderingResult, String>> =
        ["config/campaigns/demo.toml", "config/campaigns/plan-demo.toml"]
            .iter()
            .map(|c| ordering::run(&InstrumentFile::simulated(), &root.join(c)))
            .collect();

    eprintln!("(3) end-to-end throughput...");
    loads.push(("3 throughput", load_average()));
    let through = throughput_section(&target, quick);

    eprintln!("(5) the realistic instrument's error budget...");
    loads.push(("5 realistic error budget", load_average()));
    let budget_md = budget_section(&root, &target, quick);

    eprintln!("(6) the time model against dry-runs...");
    loads.push(("6 time model", load_average()));
    let timing_md = timing_section(&root, &target, before_binary(&args).as_deref(), quick);

    eprintln!("(7) sweeps against stop-and-go...");
    loads.push(("7 sweeps", load_average()));
    let sweeps_md = sweeps_section(&root, &target, quick);

    eprintln!("(4) micro-benchmarks...");
    loads.push(("4 micro-benchmarks", load_average()));
    let eval_rate = eval_throughput(&root, if quick { 200_000 } else { 2_000_000 });
    let per_model = eval_ns_per_model(min_s);
    let ordering_10k = ordering_time(&inst);
    let criterion = criterion_summary::read(&target.join("criterion"));
    let load_end = load_average();

    for (file, result) in [
        (
            "reading_time_vs_error.svg",
            plot::reading_time_vs_error(&docs.join("reading_time_vs_error.svg"), &points),
        ),
        (
            "adaptive_vs_fixed.svg",
            plot::adaptive_vs_fixed(&docs.join("adaptive_vs_fixed.svg"), &fixed),
        ),
    ] {
        if let Err(e) = result {
            eprintln!("plot {file}: {e}");
        }
    }
    for m in readings::MATERIALS {
        let mine: Vec<campaigns::CampaignPoint> = campaign_points
            .iter()
            .filter(|p| p.material == m)
            .cloned()
            .collect();
        let file = format!("campaign_{m}.svg");
        if let Err(e) = plot::campaign(&docs.join(&file), m, &mine) {
            eprintln!("plot {file}: {e}");
        }
    }
    let mut report = report(
        &points,
        &fixed,
        &apriori,
        &eval_rate,
        &per_model,
        &ordering_10k,
        &load_start,
        &load_end,
        quick,
    );
    let campaigns_md = campaign_section(
        &campaign_points,
        &sizes,
        setup.validation.len(),
        campaigns_s,
        &orderings,
    );
    let through_md = throughput_markdown(&through);
    let criterion_md = criterion_markdown(&criterion);
    let stress_md = stress_markdown(&root);
    // Splice the new sections into the report at their places.
    report = report.replace("<!-- CAMPAIGNS -->", &campaigns_md);
    report = report.replace("<!-- THROUGHPUT -->", &through_md);
    report = report.replace("<!-- CRITERION -->", &criterion_md);
    report = report.replace("<!-- STRESS -->", &stress_md);
    report.push('\n');
    report.push_str(&budget_md);
    report.push('\n');
    report.push_str(&timing_md);
    report.push('\n');
    report.push_str(&sweeps_md);
    let mut load_lines = String::new();
    for (section, load) in &loads {
        let _ = writeln!(
            load_lines,
            "- load average when section {section} started: {load}"
        );
    }
    report = report.replace("<!-- LOADS -->", &load_lines);
    report = report.replace(
        "<!-- DURATION -->",
        &format!(
            "- this run took {:.0} s{}",
            started.elapsed().as_secs_f64(),
            if quick { " (--quick)" } else { "" }
        ),
    );
    let path = root.join("BENCHMARKS.md");
    match std::fs::write(&path, report) {
        Ok(()) => eprintln!("wrote {} and docs/bench/*.svg", path.display()),
        Err(e) => eprintln!("cannot write {}: {e}", path.display()),
    }
}

/// Section 7: sweeps against stop-and-go through the release binary (crate::sweeps).
fn sweeps_section(root: &Path, target: &Path, quick: bool) -> String {
    let binary = target.join("release/gonio");
    if !binary.exists() {
        return format!(
            "## 7. Sweeps against stop-and-go\n\nNot measured: no release binary at {} (build it with `cargo build \
             --release -p gonio`).\n",
            binary.display()
        );
    }
    sweeps::section(root, &binary, quick)
        + &follow::section(root, &binary, quick)
        + &curves::section(root, &binary, quick)
}

/// Section 5: the realistic instrument's error budget and its throughput beside the ideal one's.
/// `--before BINARY`: a gonio built from an earlier commit, for the time model's side-by-side columns.
fn before_binary(args: &[String]) -> Option<PathBuf> {
    args.iter()
        .skip_while(|a| *a != "--before")
        .nth(1)
        .map(PathBuf::from)
}

/// Section 6: the time model against dry-runs through the release binary (crate::time_model).
fn timing_section(root: &Path, target: &Path, before: Option<&Path>, quick: bool) -> String {
    let binary = target.join("release/gonio");
    let mut s = String::from("## 6. The time model: predicted against dry-run instrument time\n\n");
    if !binary.exists() {
        s.push_str(&format!(
            "Not measured: no release binary at {} (build it with `cargo build --release -p gonio`).\n",
            binary.display()
        ));
        return s;
    }
    s.push_str(&time_model::section(root, &binary, before, quick));
    s.push('\n');
    match before {
        Some(b) => s.push_str(&format!(
            "The before columns: the same campaigns through `{}` (passed as `--before`), a gonio built from an \
             earlier commit (its run.json's instrument time ends at its last reading).\n",
            b.file_name().map_or_else(|| b.display().to_string(), |n| n.to_string_lossy().into_owned())
        )),
        None => s.push_str(
            "No before columns: `-- --before BINARY` (a gonio built from an earlier commit) adds them.\n",
        ),
    }
    s
}

fn budget_section(root: &Path, target: &Path, quick: bool) -> String {
    /// Issue 16's target for an in-process dry-run on the realistic instrument.
    const TARGET_PPS: f64 = 2000.0;
    let variants = match error_budget::budget(root) {
        Ok(v) => v,
        Err(e) => return format!("## 5. The realistic instrument: error budget\n\nFAILED: {e}\n"),
    };
    let text = throughput::campaign_text("bench-realistic", if quick { 10.0 } else { 5.0 }, &[550.0]);
    let runs = error_budget::throughput_runs(root, &text).unwrap_or_else(|e| {
        eprintln!("realistic throughput: {e}");
        Vec::new()
    });
    let seeds = if quick {
        &bring_up::SEEDS[..2]
    } else {
        &bring_up::SEEDS[..]
    };
    let pairs = bring_up::bring_up(root, &target.join("release/gonio"), seeds);
    format!(
        "{}\n{}",
        error_budget::markdown(&variants, &runs, TARGET_PPS),
        bring_up::markdown(&pairs, variants.first())
    )
}

fn met(ok: bool) -> &'static str {
    if ok { "met" } else { "NOT met" }
}

fn is_diffuse(material: &str) -> bool {
    matches!(material, "white-styrofoam" | "construction-paper")
}

#[allow(clippy::too_many_arguments)]
fn report(
    points: &[ReadingPoint],
    fixed: &[FixedComparison],
    apriori: &readings::APriori,
    throughput: &EvalRate,
    per_model: &[(String, f64, f64)],
    ordering: &Result<(f64, usize), String>,
    load_start: &str,
    load_end: &str,
    quick: bool,
) -> String {
    let mut s = String::new();
    let cores = std::thread::available_parallelism().map_or(0, |n| n.get());
    let _ = writeln!(s, "# Benchmarks\n");
    let _ = writeln!(
        s,
        "Written by `{COMMAND}`{} (issue 7). Every number below was measured by that run, except the criterion \
         table (read from criterion's last run: `{CRITERION}` beforehand refreshes it) and the large stress tier's \
         record (`-- --stress-large` reruns it first); none is edited by hand. The run takes about 5 minutes on \
         an idle 2-core machine (section 6 runs every campaign once more with `-- --before BINARY`, a gonio built \
         from an earlier commit, for its before columns) and much longer under load (its duration is under \
         Machine); `-- --quick` is a one-minute smoke run with smaller plans and shorter windows.\n",
        if quick {
            " -- --quick (smaller plans, short timing windows: noisier)"
        } else {
            ""
        }
    );
    let _ = writeln!(s, "## Machine\n");
    let _ = writeln!(s, "- cores: {cores}");
    let _ = writeln!(
        s,
        "- load average (1, 5, 15 min) at start: {load_start}; at end: {load_end}"
    );
    let _ = writeln!(s, "- {}", rustc_version());
    let _ = writeln!(
        s,
        "- The machine is shared: other builds ran during the measurement, so times are upper bounds of what an \
         idle machine gives."
    );
    let _ = writeln!(s, "<!-- LOADS --><!-- DURATION -->\n");

    s.push_str(&readings_section(points, fixed, apriori, quick));

    let _ = writeln!(s, "<!-- CAMPAIGNS -->");
    let _ = writeln!(s, "<!-- THROUGHPUT -->");

    // (b)-(d)
    let _ = writeln!(s, "## 4. Micro-benchmarks\n");
    let _ = writeln!(
        s,
        "Measured by this command. BRDF evaluation: 256 random pairs per call batch, timed in 20 windows of {:.1} ms \
         each; the fastest window (the least disturbed by the other jobs on the machine) and the median are shown, \
         the verdict uses the fastest. `gonio brdf eval`: the release binary as one process over generated input, \
         best of three runs (all shown). Wall-clock numbers on a loaded machine are inflated (see Machine).\n",
        if quick { 1.25 } else { 12.5 }
    );
    let _ = writeln!(s, "| benchmark | measured | target | result |");
    let _ = writeln!(s, "|---|---|---|---|");
    match throughput {
        Ok((rate, lines, runs)) => {
            let runs: Vec<String> = runs.iter().map(|r| format!("{:.2}", r / 1e6)).collect();
            let _ = writeln!(
                s,
                "| `gonio brdf eval --material gold`, {lines} generated lines through the release binary | best {:.2} M lines/s (runs: {}) | >= 2 M lines/s | {} |",
                rate / 1e6,
                runs.join(", "),
                met(*rate >= 2e6)
            );
        }
        Err(why) => {
            let _ = writeln!(
                s,
                "| `gonio brdf eval` streaming | not measured: {why} | >= 2 M lines/s | not measured |"
            );
        }
    }
    for (name, ns, median) in per_model {
        let (target, result) = if name.starts_with("GGX") || name == "preset gold" {
            ("<= 50 ns (GGX conductor)", met(*ns <= 50.0).to_string())
        } else {
            ("-", "-".to_string())
        };
        let _ = writeln!(
            s,
            "| BRDF eval, {name}, at_wavelength(550 nm) | {ns:.1} ns/call (median {median:.1}) | {target} | {result} |"
        );
    }
    match ordering {
        Ok((secs, n)) => {
            let _ = writeln!(
                s,
                "| order {n} poses (plan of examples/order_10k.rs) | {secs:.2} s | < 5 s | {} |",
                met(*secs < 5.0)
            );
        }
        Err(why) => {
            let _ = writeln!(
                s,
                "| order 10k poses | not measured: {why} | < 5 s | not measured |"
            );
        }
    }
    let _ = writeln!(
        s,
        "\nLoad average at start {load_start} on {cores} cores (see Machine): when it exceeds the core count, \
         CPU-bound timings here are inflated relative to an idle machine (by up to load/cores), which can decide \
         a target near its limit (BRDF eval, streaming throughput). The verdicts above are for this run, as \
         measured.\n\n\
"
    );
    let _ = writeln!(s, "<!-- CRITERION -->");

    let _ = writeln!(s, "## Numerical stability stress suite\n");
    let _ = writeln!(
        s,
        "Fast tier (in CI, seconds): `cargo test -p gonio-brdf --test stress`, `cargo test -p gonio-simulator --test it \
         stress`, `cargo test -p gonio-scheduler --test it stress`.\n\
         Large tier (10,000,000 random model/geometry pairs, 40 random models per kind, albedo integrals for 12 per \
         kind): `GONIO_STRESS=large cargo test --release -p gonio-brdf --test stress`.\n\
         What they check is written at the top of each suite.\n"
    );
    let _ = writeln!(s, "<!-- STRESS -->");
    s
}

/// Cargo's target directory (`CARGO_TARGET_DIR`, or the workspace's `target/`).
fn target_dir() -> PathBuf {
    std::env::var_os("CARGO_TARGET_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../target"))
}

/// `--accuracy`: issue 29's accuracy table, written to ACCURACY.md (crate::accuracy). Narrowed by `--bands`,
/// `--materials` or `--setups` (accuracy::Options), it is written to the file `--out` names instead: ACCURACY.md
/// keeps the whole table.
fn write_accuracy(args: &[String], quick: bool) {
    let started = Instant::now();
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..");
    let binary = target_dir().join("release/gonio");
    let options = accuracy::Options::parse(args).unwrap_or_else(|e| {
        eprintln!("accuracy: {e}");
        std::process::exit(2);
    });
    let out = args
        .iter()
        .skip_while(|a| *a != "--out")
        .nth(1)
        .map(PathBuf::from);
    let path = match (&out, options.is_default()) {
        (Some(p), _) => p.clone(),
        (None, true) => root.join("ACCURACY.md"),
        (None, false) => {
            eprintln!("accuracy: a narrowed run (--bands, --materials, --setups, --seeds) needs --out FILE");
            std::process::exit(2);
        }
    };
    let n = if quick { 200 } else { accuracy::GEOMETRIES };
    eprintln!(
        "accuracy: {n} geometries per material, bands {} nm, {} material(s), set-ups {}...",
        options.bands_toml(),
        options.materials.len(),
        options.setups.join(", ")
    );
    match accuracy::run(&root, &binary, n, &options) {
        Ok(runs) => {
            let md = accuracy::markdown(&runs, n, started.elapsed().as_secs_f64(), &options);
            match std::fs::write(&path, md) {
                Ok(()) => eprintln!("wrote {}", path.display()),
                Err(e) => eprintln!("cannot write {}: {e}", path.display()),
            }
        }
        Err(e) => {
            eprintln!("accuracy: {e}");
            std::process::exit(1);
        }
    }
}

/// `--only <section>`: one section, printed (BENCHMARKS.md is not touched). For working on one section.
fn run_only(section: &str, quick: bool) {
    let inst = InstrumentFile::simulated().instrument;
    match section {
        "sweeps" => {
            let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..");
            print!("{}", sweeps_section(&root, &target_dir(), quick));
        }
        "curves" => {
            let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..");
            print!(
                "{}",
                curves::section(&root, &target_dir().join("release/gonio"), quick)
            );
        }
        "follow" => {
            let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..");
            print!(
                "{}",
                follow::section(&root, &target_dir().join("release/gonio"), quick)
            );
        }
        "readings" => {
            let min_s = if quick { 0.005 } else { 0.05 };
            let t = Instant::now();
            let (points, fixed) = readings::run(&inst, min_s);
            let apriori = readings::run_apriori(&inst, min_s);
            print!("{}", readings_section(&points, &fixed, &apriori, quick));
            eprintln!("readings: {:.1} s", t.elapsed().as_secs_f64());
        }
        "campaigns" => {
            let sizes = campaigns::Sizes::new(quick);
            let setup = campaigns::Setup::new(&inst, sizes.validation_points);
            let rec = campaigns::reconstructor(&inst);
            let filter = std::env::var("BENCH_MATERIALS").unwrap_or_default();
            for m in readings::MATERIALS {
                if !filter.is_empty() && !filter.split(',').any(|f| f == m) {
                    continue;
                }
                let t = Instant::now();
                for p in campaigns::run_material(&setup, &sizes, m, &rec) {
                    println!(
                        "{:<20} {:<30} {:<16} {:>6} pts {:>9.1} s  rel {:>9}  log {:.5}  dropped {}",
                        p.material,
                        p.strategy.name(),
                        p.label,
                        p.points,
                        p.predicted_s,
                        p.rel_rms.map_or("n/a".into(), |r| format!("{r:.5}")),
                        p.log_rms,
                        p.dropped
                    );
                }
                eprintln!("{m}: {:.1} s", t.elapsed().as_secs_f64());
            }
        }
        "throughput" => {
            let step: f64 = std::env::var("BENCH_STEP")
                .ok()
                .and_then(|v| v.parse().ok())
                .unwrap_or(5.0);
            let text = throughput::campaign_text("bench-throughput", step, &[550.0]);
            let mut runs = vec![("in process", throughput::in_process(&text))];
            if std::env::var_os("BENCH_SKIP_PTY").is_none() {
                runs.push(("ptys", throughput::over_ptys(&text)));
            }
            for (name, r) in runs {
                match r {
                    Ok(t) => println!(
                        "{name}: {} points in {:.3} s wall ({:.0} points/s, {:.3} ms/point), steady {:.0} points/s ({:.3} ms/point), instrument {:.0} s",
                        t.points,
                        t.wall_s,
                        t.points_per_s(),
                        t.ms_per_point(),
                        t.steady_points_per_s(),
                        t.steady_ms_per_point(),
                        t.instrument_s
                    ),
                    Err(e) => println!("{name}: {e}"),
                }
            }
        }
        "budget" => print!(
            "{}",
            budget_section(
                &PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../.."),
                &target_dir(),
                quick
            )
        ),
        "timing" => {
            let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..");
            let args: Vec<String> = std::env::args().collect();
            print!(
                "{}",
                timing_section(&root, &target_dir(), before_binary(&args).as_deref(), quick)
            );
        }
        "stress-large" => {
            let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..");
            print!("{}", stress::run_and_record(&root, &load_average()));
        }
        other => eprintln!("unknown section {other:?}"),
    }
}
