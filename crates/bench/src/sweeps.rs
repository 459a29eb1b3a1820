//! Issue 41's table: sweeps against stop-and-go, per seed material on both instrument files. Every run goes
//! through the release binary as a lab would run it (`gonio run FILE --instrument INST`): the demo's grid
//! (config/campaigns/demo.toml, stop-and-go) and config/campaigns/sweeps.toml (detector sweeps at three
//! incidences, three bands), each with the material swapped. From each run: its instrument time (run.json), its
//! values (points.csv, sweeps.csv) and, against the simulator's truth at each value's nominal geometry, the
//! cosine-weighted relative RMS error and the share of values whose k=2 interval holds the truth; the wall time
//! is the process's (start-up, planning, the run, the completion and the files).
//!
//! Speed that follows the BRDF against constant speed: crate::follow. Not here yet: curves of instrument time
//! against error on a common validation set for the four strategies (grid, adaptive, constant-speed and
//! BRDF-following sweeps).

use std::fmt::Write as _;
use std::path::Path;

use crate::gonio_run::{GonioRun, gonio_run};
use crate::readings::MATERIALS;

/// The targets: values per instrument hour against stop-and-go, and k=2 coverage.
const VALUES_RATIO_TARGET: f64 = 100.0;
const COVERAGE_TARGET: f64 = 0.90;

/// What one run gave.
struct Outcome {
    values: usize,
    instrument_s: f64,
    wall_s: f64,
    cos_rms: Option<f64>,
    coverage: Option<f64>,
}

impl Outcome {
    fn per_hour(&self) -> f64 {
        3600.0 * self.values as f64 / self.instrument_s.max(1e-9)
    }
}

/// Run `text` through `binary` on `instrument` and read `csv` (points.csv or sweeps.csv) of its results.
fn run(binary: &Path, text: &str, instrument: &Path, csv: &str) -> Result<Outcome, String> {
    let run = gonio_run(binary, text, Some(instrument))?;
    read(&run, csv)
}

fn read(run: &GonioRun, csv: &str) -> Result<Outcome, String> {
    let instrument_s = run.instrument_s()?;
    let wall_s = run.wall_s;
    let text = std::fs::read_to_string(run.out.join(csv)).map_err(|e| format!("{csv}: {e}"))?;
    let mut lines = text.lines();
    let header: Vec<&str> = lines.next().ok_or("empty csv")?.split(',').collect();
    let col = |name: &str| {
        header
            .iter()
            .position(|h| *h == name)
            .ok_or(format!("{csv} has no {name}"))
    };
    let (f_col, u_col, t_col, ti_col) = (
        col("brdf_sr")?,
        col("brdf_u_sr")?,
        col("brdf_true_sr")?,
        col("theta_i_deg")?,
    );
    let (mut values, mut n, mut covered, mut num, mut den) = (0usize, 0usize, 0usize, 0.0, 0.0);
    for line in lines {
        let cells: Vec<&str> = line.split(',').collect();
        let get = |i: usize| cells.get(i).and_then(|c| c.parse::<f64>().ok());
        let Some(f) = get(f_col) else { continue };
        values += 1;
        let (Some(u), Some(t), Some(ti)) = (get(u_col), get(t_col), get(ti_col)) else {
            continue;
        };
        let c = ti.to_radians().cos();
        n += 1;
        covered += usize::from((f - t).abs() <= 2.0 * u);
        num += ((f - t) * c).powi(2);
        den += (t * c).powi(2);
    }
    Ok(Outcome {
        values,
        instrument_s,
        wall_s,
        cos_rms: (den > 0.0).then(|| (num / den).sqrt()),
        coverage: (n > 0).then(|| covered as f64 / n as f64),
    })
}

fn with_material(text: &str, material: &str) -> String {
    text.replace(
        "preset = \"coloured-plastic\"",
        &format!("preset = \"{material}\""),
    )
}

/// Section 7 (module doc).
pub fn section(root: &Path, binary: &Path, quick: bool) -> String {
    let read =
        |name: &str| std::fs::read_to_string(root.join("config/campaigns").join(name)).unwrap_or_default();
    let (demo, sweeps) = (read("demo.toml"), read("sweeps.toml"));
    let materials: &[&str] = if quick { &MATERIALS[3..4] } else { &MATERIALS };
    let mut s = String::from("## 7. Sweeps against stop-and-go\n\n");
    let _ = writeln!(
        s,
        "Per seed material and instrument file: the demo's grid (stop-and-go) and config/campaigns/sweeps.toml, each \
         through `gonio run` with the material swapped (crates/bench/src/sweeps.rs). Values: valid points, or valid \
         sweep readings; per hour: per hour of instrument time. Error: cosine-weighted relative RMS against the \
         simulator's BRDF at each value's nominal geometry; k=2: the share of values whose k=2 interval holds it. \
         Readings/s: the sweeps run's readings over its process's wall time (start-up, planning, the run, the \
         completion, the files). Targets: at least {VALUES_RATIO_TARGET:.0}x the values per hour, k=2 at least \
         {:.0} %.\n",
        100.0 * COVERAGE_TARGET
    );
    s.push_str(
        "| material | instrument | grid: values, instrument s, per hour, error, k=2 | sweeps: values, instrument s, \
         per hour, error, k=2 | values per hour, sweeps / grid | readings/s (wall) | targets |\n|---|---|---|---|---|---|---|\n",
    );
    let cell = |o: &Outcome| {
        format!(
            "{}, {:.0} s, {:.0}, {}, {}",
            o.values,
            o.instrument_s,
            o.per_hour(),
            o.cos_rms.map_or("-".into(), |r| format!("{r:.2e}")),
            o.coverage.map_or("-".into(), |c| format!("{:.1} %", 100.0 * c))
        )
    };
    for material in materials {
        for (label, instrument) in [
            ("ideal", root.join("config/instruments/simulated.toml")),
            ("realistic", root.join("config/instruments/realistic.toml")),
        ] {
            eprintln!("    sweeps: {material}, {label}...");
            let grid = run(binary, &with_material(&demo, material), &instrument, "points.csv");
            let swept = run(
                binary,
                &with_material(&sweeps, material),
                &instrument,
                "sweeps.csv",
            );
            match (grid, swept) {
                (Ok(g), Ok(w)) => {
                    let ratio = w.per_hour() / g.per_hour().max(1e-9);
                    let coverage_met = w.coverage.is_some_and(|c| c >= COVERAGE_TARGET);
                    let _ = writeln!(
                        s,
                        "| {material} | {label} | {} | {} | {ratio:.0}x | {:.0} | values {}, k=2 {} |",
                        cell(&g),
                        cell(&w),
                        w.values as f64 / w.wall_s.max(1e-9),
                        if ratio >= VALUES_RATIO_TARGET {
                            "met"
                        } else {
                            "NOT met"
                        },
                        if coverage_met { "met" } else { "NOT met" },
                    );
                }
                (g, w) => {
                    let err = |r: Result<Outcome, String>| r.err().unwrap_or_default();
                    let _ = writeln!(
                        s,
                        "| {material} | {label} | FAILED: {} | FAILED: {} | | | |",
                        err(g),
                        err(w)
                    );
                }
            }
        }
    }
    s.push_str(
        "\nTime against error on one validation set for the grid, adaptive plans, constant-speed sweeps and sweeps \
         whose speed follows the BRDF: *Instrument time against error* below.\n",
    );
    s
}
