//! The benchmark report of issue 7: `cargo run --release -p gonio-bench` (from the workspace root).
//!
//! Measures (a) simulator readings: time against actual error versus a brute-force reference per seed material,
//! on and off the specular lobe, over tolerances 1e-2..1e-8, and the adaptive integrator against a fixed
//! high-order rule at equal error; (b) `gonio brdf eval` streaming throughput with the release binary (built
//! beforehand with `cargo build --release -p gonio`; skipped and said so when absent); (c) BRDF evaluation ns per
//! call per model; (d) ordering time for a 10,000-point plan. Writes `BENCHMARKS.md` at the workspace root and
//! SVG plots under `docs/bench/`. Every number is measured by this run; nothing is edited by hand.
//! `--quick` shortens every timing window (for a smoke run; the numbers are then noisier).

mod plot;
mod readings;

use std::fmt::Write as _;
use std::hint::black_box;
use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Instant;

use gonio_brdf::{Brdf, Direction, Material, Wavelength};
use gonio_instrument::InstrumentFile;
use gonio_scheduler::plan::{self, BuildContext, CampaignDoc, SampleTraits};
use gonio_scheduler::timing::TimeModel;

use readings::{FixedComparison, ReadingPoint, time_us};

const COMMAND: &str = "cargo build --release -p gonio && cargo run --release -p gonio-bench";

fn main() {
    let quick = std::env::args().any(|a| a == "--quick");
    let min_s = if quick { 0.005 } else { 0.05 };
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../..");
    let load_start = load_average();
    let inst = InstrumentFile::simulated().instrument;

    eprintln!("(a) simulator readings...");
    let (points, fixed) = readings::run(&inst, min_s);
    eprintln!("(b) gonio brdf eval throughput...");
    let throughput = eval_throughput(&root, if quick { 200_000 } else { 2_000_000 });
    eprintln!("(c) BRDF evaluation per model...");
    let per_model = eval_ns_per_model(min_s);
    eprintln!("(d) ordering 10,000 points...");
    let ordering = ordering_time(&inst);
    let load_end = load_average();

    let docs = root.join("docs/bench");
    if let Err(e) = std::fs::create_dir_all(&docs) {
        eprintln!("cannot create {}: {e}", docs.display());
    }
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
    let report = report(
        &points,
        &fixed,
        &throughput,
        &per_model,
        &ordering,
        &load_start,
        &load_end,
        quick,
    );
    let path = root.join("BENCHMARKS.md");
    match std::fs::write(&path, report) {
        Ok(()) => eprintln!("wrote {} and docs/bench/*.svg", path.display()),
        Err(e) => eprintln!("cannot write {}: {e}", path.display()),
    }
}

fn load_average() -> String {
    std::fs::read_to_string("/proc/loadavg")
        .map(|s| s.split_whitespace().take(3).collect::<Vec<_>>().join(" "))
        .unwrap_or_else(|_| "unknown".into())
}

fn rustc_version() -> String {
    Command::new("rustc")
        .arg("--version")
        .output()
        .ok()
        .and_then(|o| String::from_utf8(o.stdout).ok())
        .map(|s| s.trim().to_string())
        .unwrap_or_else(|| "unknown".into())
}

/// (b) Lines per second through the release `gonio brdf eval`, or why it was not measured.
fn eval_throughput(root: &Path, lines: usize) -> Result<(f64, usize), String> {
    let target = std::env::var_os("CARGO_TARGET_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| root.join("target"));
    let binary = target.join("release/gonio");
    if !binary.exists() {
        return Err(format!(
            "{} not found: build it with `cargo build --release -p gonio`",
            binary.display()
        ));
    }
    // Generated input: reproducible angles over the whole hemisphere, one geometry per line.
    let mut input = String::with_capacity(lines * 32);
    let mut s: u64 = 11;
    for _ in 0..lines {
        let mut next = || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (s >> 11) as f64 / (1u64 << 53) as f64
        };
        let (a, b, c, d) = (next() * 89.0, next() * 360.0, next() * 89.0, next() * 360.0);
        let _ = writeln!(input, "{a:.3} {b:.3} {c:.3} {d:.3}");
    }
    let start = Instant::now();
    let mut child = Command::new(&binary)
        .args(["brdf", "eval", "--material", "gold"])
        .stdin(Stdio::piped())
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .map_err(|e| format!("cannot run {}: {e}", binary.display()))?;
    if let Some(mut stdin) = child.stdin.take() {
        stdin
            .write_all(input.as_bytes())
            .map_err(|e| format!("writing to gonio: {e}"))?;
    }
    let status = child.wait().map_err(|e| format!("waiting for gonio: {e}"))?;
    let elapsed = start.elapsed().as_secs_f64();
    if !status.success() {
        return Err(format!("gonio brdf eval exited with {status}"));
    }
    Ok((lines as f64 / elapsed, lines))
}

/// (c) ns per `eval` call for each preset and a GGX conductor, resolved at 550 nm.
fn eval_ns_per_model(min_s: f64) -> Vec<(String, f64)> {
    let wl = Wavelength::DEFAULT;
    let mut s: u64 = 7;
    let mut unit = move || {
        s = s
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (s >> 11) as f64 / (1u64 << 53) as f64
    };
    let pairs: Vec<(Direction, Direction)> = (0..256)
        .map(|_| {
            (
                Direction::from_spherical(unit() * 1.5, unit() * std::f64::consts::TAU),
                Direction::from_spherical(unit() * 1.5, unit() * std::f64::consts::TAU),
            )
        })
        .collect();
    let mut out = Vec::new();
    let mut models: Vec<(String, Material)> = Material::preset_names()
        .iter()
        .map(|n| (format!("preset {n}"), Material::preset(n).expect("preset")))
        .collect();
    let ggx = "[material]\nmodel = \"conductor\"\ndistribution = \"ggx\"\nmasking = \"separable\"\nalpha = 0.2\neta = 0.35\nk = 2.714\n";
    let phong = "[material]\nmodel = \"phong\"\ndiffuse = 0.3\nspecular = 0.5\nexponent = 50\n";
    for (name, text) in [("GGX conductor (separable)", ggx), ("phong", phong)] {
        models.push((
            name.into(),
            Material::from_document(text, name, Path::new(".")).expect("material"),
        ));
    }
    for (name, m) in models {
        let m = m.at_wavelength(wl).expect("550 nm");
        let t = time_us(min_s, || {
            let mut sum = 0.0;
            for (wi, wo) in &pairs {
                sum += m.eval(black_box(wi), black_box(wo), wl).unwrap_or(0.0);
            }
            black_box(sum);
        });
        out.push((name, t * 1e3 / pairs.len() as f64));
    }
    out
}

/// (d) Build the 10,000-point plan of `crates/scheduler/examples/order_10k.rs` and time the ordering alone.
fn ordering_time(inst: &gonio_instrument::Instrument) -> Result<(f64, usize), String> {
    let text = "[plan]\nbands_nm = [550.0]\n[plan.grid]\nkind = \"full\"\n\
                theta_i_deg = { from = 0.0, to = 80.0, step = 10.0 }\nphi_i_deg = { from = 0.0, to = 340.0, step = 20.0 }\n\
                theta_o_deg = { from = 0.0, to = 80.0, step = 10.0 }\nphi_o_deg = { from = 0.0, to = 340.0, step = 20.0 }\n";
    let doc = CampaignDoc::parse(text, "bench").map_err(|e| e.to_string())?;
    let ctx = BuildContext {
        instrument: inst,
        traits: SampleTraits {
            isotropic: false,
            spectrally_flat: true,
        },
        sample_radius_mm: None,
        start: None,
    };
    let plan = plan::build(&doc.plan, &ctx).map_err(|e| e.to_string())?;
    let poses: Vec<_> = plan
        .geometries
        .iter()
        .filter_map(|g| g.candidates.first().map(|c| c.0))
        .collect();
    let time = TimeModel::new(inst);
    let start = Instant::now();
    let tour = gonio_scheduler::order::order(&poses, None, &time);
    Ok((start.elapsed().as_secs_f64(), tour.len()))
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
    throughput: &Result<(f64, usize), String>,
    per_model: &[(String, f64)],
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
        "Written by `{COMMAND}`{} (issue 7). Every number below was measured by that run; none is edited by hand.\n",
        if quick {
            " --quick (short timing windows: noisier)"
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
         idle machine gives.\n"
    );

    // (a)
    let _ = writeln!(s, "## 1. Simulator readings: time against error\n");
    let _ = writeln!(
        s,
        "Simulated instrument (aperture half-angle 0.01 rad), band 550 nm, light arm at 30 deg, detector at -30 deg \
         (specular) or -60 deg (off-specular), no tilt. Reference: the aperture integral by composite Simpson x \
         trapezoid (1000 x 1000) plus the delta lobe. Time is per `Optics::reading` (mean over a {:.0} ms window).\n",
        if quick { 5.0 } else { 50.0 }
    );
    let _ = writeln!(
        s,
        "| material | geometry | tolerance | time/reading (us) | actual rel. error | evaluations |"
    );
    let _ = writeln!(s, "|---|---|---|---|---|---|");
    for p in points {
        let _ = writeln!(
            s,
            "| {} | {} | {:.0e} | {:.3} | {:.2e} | {} |",
            p.material, p.geometry, p.tolerance, p.time_us, p.rel_error, p.evaluations
        );
    }
    let _ = writeln!(
        s,
        "\n![time against error](docs/bench/reading_time_vs_error.svg)\n"
    );
    let _ = writeln!(s, "### Targets at tolerance 1e-6\n");
    let _ = writeln!(s, "| case | measured | target | result |");
    let _ = writeln!(s, "|---|---|---|---|");
    for p in points.iter().filter(|p| p.tolerance == 1e-6) {
        let target = if is_diffuse(p.material) {
            Some(2.0)
        } else if p.material == "gold" && p.geometry == "specular" {
            Some(50.0)
        } else {
            None
        };
        if let Some(t) = target {
            let ok = p.time_us <= t && p.rel_error <= 1e-6;
            let why = if ok {
                String::new()
            } else if p.rel_error > 1e-6 {
                format!(" (error {:.1e} > 1e-6)", p.rel_error)
            } else {
                format!(" ({:.2} us > {t} us)", p.time_us)
            };
            let _ = writeln!(
                s,
                "| {} {} | {:.3} us, error {:.1e} | <= {t} us at 1e-6 | {}{why} |",
                p.material,
                p.geometry,
                p.time_us,
                p.rel_error,
                met(ok)
            );
        }
    }
    let _ = writeln!(
        s,
        "\n### Adaptive against a fixed high-order rule at equal error\n"
    );
    let _ = writeln!(
        s,
        "Fixed rule: Gauss-Legendre (n nodes) in the angle from the aperture axis x trapezoid (2n nodes) in azimuth, \
         timed alone (no reading overhead), n = 1..64. Equal error: the cheapest n whose actual error is at most the \
         adaptive reading's at tolerance 1e-6 (the adaptive time includes the whole reading). Target: >= 20x cheaper.\n"
    );
    let _ = writeln!(
        s,
        "| material | geometry | adaptive (us, error) | fixed at equal error (n, us, error) | ratio | result |"
    );
    let _ = writeln!(s, "|---|---|---|---|---|---|");
    for c in fixed {
        match &c.equal_error {
            Some(f) => {
                let ratio = f.time_us / c.adaptive_time_us;
                let _ = writeln!(
                    s,
                    "| {} | {} | {:.3}, {:.1e} | {}, {:.3}, {:.1e} | {:.1}x | {} |",
                    c.material,
                    c.geometry,
                    c.adaptive_time_us,
                    c.adaptive_error,
                    f.n,
                    f.time_us,
                    f.rel_error,
                    ratio,
                    met(ratio >= 20.0)
                );
            }
            None => {
                let _ = writeln!(
                    s,
                    "| {} | {} | {:.3}, {:.1e} | not reached by n <= 64 | > {:.1}x | met (fixed rule never reaches it) |",
                    c.material,
                    c.geometry,
                    c.adaptive_time_us,
                    c.adaptive_error,
                    c.curve.last().map_or(0.0, |p| p.time_us / c.adaptive_time_us)
                );
            }
        }
    }
    let _ = writeln!(
        s,
        "\nReading this table: actual errors below about 1e-10 are at the accuracy of the brute-force reference \
         itself (Simpson 1000 x 1000), so they mean \"exact to the reference\". On this instrument's 0.01 rad \
         aperture every seed material is smooth across the aperture (gold's lobe, alpha 0.08, is 16 times wider \
         than the aperture), so a fixed rule of 2 to 6 radial nodes is already as accurate as the adaptive \
         reading, and the adaptive integrator cannot be 20x cheaper than so small a rule: the >= 20x target is \
         not met here, by the measured ratios above. The adaptive rule's advantage is where a fixed rule must be \
         sized for the worst case (lobes narrower than the aperture, kinks across it, cones crossing the \
         horizon), which these seed geometries do not exercise; the plot shows the whole fixed-rule curves.\n"
    );
    let _ = writeln!(s, "![adaptive vs fixed](docs/bench/adaptive_vs_fixed.svg)\n");

    // Campaigns: not measured.
    let _ = writeln!(
        s,
        "## 2. Campaigns and 3. end-to-end throughput: NOT MEASURED YET\n"
    );
    let _ = writeln!(
        s,
        "Issue 7 items 2 (plan strategies: predicted instrument time against BRDF error on a dense validation set; \
         adaptive vs uniform grid, ordered vs raster motion time) and 3 (points/s through the real drivers in process \
         and over pseudo-terminals, daemon overhead per point) need the daemon, which is being written in \
         crates/daemon. They are not measured by this command yet; no number here stands for them.\n"
    );

    // (b)-(d)
    let _ = writeln!(s, "## 4. Micro-benchmarks\n");
    let _ = writeln!(s, "| benchmark | measured | target | result |");
    let _ = writeln!(s, "|---|---|---|---|");
    match throughput {
        Ok((rate, lines)) => {
            let _ = writeln!(
                s,
                "| `gonio brdf eval --material gold`, {lines} generated lines through the release binary | {:.2} M lines/s | >= 2 M lines/s | {} |",
                rate / 1e6,
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
    for (name, ns) in per_model {
        let (target, result) = if name.starts_with("GGX") {
            ("<= 50 ns", met(*ns <= 50.0).to_string())
        } else {
            ("-", "-".to_string())
        };
        let _ = writeln!(
            s,
            "| BRDF eval, {name}, at_wavelength(550 nm) | {ns:.1} ns/call | {target} | {result} |"
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
         Criterion micro-benchmarks (statistics, not written here): `cargo bench -p gonio-brdf --bench eval`, \
         `cargo bench -p gonio-simulator --bench reading`, `cargo bench -p gonio-scheduler --bench kinematics` \
         (inverse kinematics and ordering 10,000 poses).\n"
    );

    let _ = writeln!(s, "## Numerical stability stress suite\n");
    let _ = writeln!(
        s,
        "Fast tier (in CI, seconds): `cargo test -p gonio-brdf --test stress`, `cargo test -p gonio-simulator --test \
         stress`, `cargo test -p gonio-scheduler --test stress`.\n\
         Large tier (10,000,000 random model/geometry pairs, 40 random models per kind, albedo integrals for 12 per \
         kind): `GONIO_STRESS=large cargo test --release -p gonio-brdf --test stress`.\n\
         What they check is written at the top of each file."
    );
    s
}
