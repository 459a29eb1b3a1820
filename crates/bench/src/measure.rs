//! The measurements behind sections (3) and (4): dry-run throughput runs, `gonio brdf eval` streaming, BRDF
//! evaluation per model, ordering 10,000 poses, and the compiler's version for the record.

use super::*;

/// Section (3)'s measurements.
pub(super) struct ThroughputRuns {
    pub(super) in_process: Result<throughput::Throughput, String>,
    pub(super) in_process_tmpfs: Option<Result<throughput::Throughput, String>>,
    pub(super) ptys: Result<throughput::Throughput, String>,
    pub(super) gonio_run: Result<(u64, f64), String>,
    pub(super) campaign_points_step_deg: f64,
    pub(super) pty_step_deg: f64,
    pub(super) run_step_deg: f64,
}

pub(super) fn throughput_section(target: &Path, quick: bool) -> ThroughputRuns {
    let step = if quick { 10.0 } else { 5.0 };
    let text = throughput::campaign_text("bench-throughput", step, &[550.0]);
    let in_process = throughput::in_process(&text);
    // The same run with the store on a RAM file system: what the store's disk writes still cost.
    let in_process_tmpfs = Path::new("/dev/shm")
        .is_dir()
        .then(|| throughput::in_process_in(&text, Path::new("/dev/shm")));
    let pty_step = if quick { 20.0 } else { 10.0 };
    let ptys = throughput::over_ptys(&throughput::campaign_text("bench-pty", pty_step, &[550.0]));
    // At least 10,000 points: three bands on an isotropic grid (4.5 deg gives 9,267).
    let run_step = if quick { 10.0 } else { 4.25 };
    let binary = target.join("release/gonio");
    let gonio_run = if binary.exists() {
        throughput::gonio_run(
            &binary,
            &throughput::campaign_text("bench-10k", run_step, &[450.0, 550.0, 650.0]),
        )
    } else {
        Err(format!(
            "{} not found: build it with `cargo build --release -p gonio`",
            binary.display()
        ))
    };
    ThroughputRuns {
        in_process,
        in_process_tmpfs,
        ptys,
        gonio_run,
        campaign_points_step_deg: step,
        pty_step_deg: pty_step,
        run_step_deg: run_step,
    }
}

pub(crate) fn load_average() -> String {
    std::fs::read_to_string("/proc/loadavg")
        .map(|s| s.split_whitespace().take(3).collect::<Vec<_>>().join(" "))
        .unwrap_or_else(|_| "unknown".into())
}

pub(super) fn rustc_version() -> String {
    Command::new("rustc")
        .arg("--version")
        .output()
        .ok()
        .and_then(|o| String::from_utf8(o.stdout).ok())
        .map(|s| s.trim().to_string())
        .unwrap_or_else(|| "unknown".into())
}

/// (b) Lines per second through the release `gonio brdf eval`, or why it was not measured.
/// (best lines/s, lines, every run's lines/s).
pub(super) type EvalRate = Result<(f64, usize, Vec<f64>), String>;

pub(super) fn eval_throughput(root: &Path, lines: usize) -> EvalRate {
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
    // Best of three runs: the machine is shared, and the least disturbed run is the closest to the program's own
    // speed (all three are reported).
    let mut rates = Vec::new();
    for _ in 0..3 {
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
        rates.push(lines as f64 / elapsed);
    }
    let best = rates.iter().copied().fold(0.0, f64::max);
    Ok((best, lines, rates))
}

/// (c) ns per `eval` call for each preset and a GGX conductor, resolved at 550 nm.
/// (name, fastest window ns/call, median window ns/call): 20 windows of `min_s / 4` each.
pub(super) fn eval_ns_per_model(min_s: f64) -> Vec<(String, f64, f64)> {
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
        let mut windows: Vec<f64> = (0..20)
            .map(|_| {
                time_us(min_s / 4.0, || {
                    let mut sum = 0.0;
                    for (wi, wo) in &pairs {
                        sum += m.eval(black_box(wi), black_box(wo), wl).unwrap_or(0.0);
                    }
                    black_box(sum);
                }) * 1e3
                    / pairs.len() as f64
            })
            .collect();
        windows.sort_by(f64::total_cmp);
        out.push((name, windows[0], windows[windows.len() / 2]));
    }
    out
}

/// (d) Build the 10,000-point plan of `crates/scheduler/examples/order_10k.rs` and time the ordering alone.
pub(super) fn ordering_time(inst: &gonio_instrument::Instrument) -> Result<(f64, usize), String> {
    let text = "[plan]\nbands_nm = [550.0]\n[plan.grid]\nkind = \"full\"\n\
                theta_i_deg = { from = 0.0, to = 80.0, step = 10.0 }\nphi_i_deg = { from = 0.0, to = 340.0, step = 20.0 }\n\
                theta_o_deg = { from = 0.0, to = 80.0, step = 10.0 }\nphi_o_deg = { from = 0.0, to = 340.0, step = 20.0 }\n";
    let spec = PlanSpec::from_toml(text, "bench").map_err(|e| e.to_string())?;
    let ctx = BuildContext {
        instrument: inst,
        traits: SampleTraits {
            isotropic: false,
            spectrally_flat: true,
        },
        sample_radius_mm: None,
        start: None,
    };
    let plan = plan::build(&spec, &ctx).map_err(|e| e.to_string())?;
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
