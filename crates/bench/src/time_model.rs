//! Issue 39's time-model table: the prediction against the dry-run, campaign by campaign, on both instrument
//! files. Every run goes through the release binary as a lab would run it (`gonio run FILE --instrument INST`):
//! its run.json gives the prediction it stored (`timing.predicted_instrument_s`, what `gonio plan` prints), the
//! run's instrument time (`timing.actual_instrument_s`: until the run ended, its closing calibration and last
//! wheel turn included) and the points; the wall time is the process's.
//!
//! Campaigns: every file in config/campaigns that runs as a dry-run (template.toml names no sample: it is run with
//! a `[material]` added), the demo's grid at 10, 5 and 2.5 degree steps, and campaigns that are not in the
//! repository ([`OFF_REPO`]: other densities, bands, averaging, repeats, settling, the relative method, an
//! adaptive plan on another material). With `--before BINARY` (a gonio built from an earlier commit) every
//! campaign also runs through that binary, side by side: its instrument time per point and its wall time.
//!
//! A third instrument file is realistic.toml as a lab would bring it up: its dynamics measured by `gonio selftest
//! --write` ([`self_tested`]). The simulated hardware behind it must stay the same (the simulator draws its
//! hidden imperfections about the file's claims), so the bench, which may know the simulator's truth, pins it
//! with `[simulator.actual]` from a dry-run's run.json: the same hardware, its file as measured.

use std::path::{Path, PathBuf};

/// The target: every row within this fraction.
const TARGET: f64 = 0.02;

/// The demo's grid at a theta step (degrees; the azimuth difference at twice the step).
fn demo_grid(demo: &str, step_deg: f64) -> String {
    demo.replace("step = 15.0 }", &format!("step = {step_deg} }}"))
        .replace(
            "to = 180.0, step = 45.0",
            &format!("to = 180.0, step = {}", 2.0 * step_deg),
        )
        .replace("id = \"demo\"", &format!("id = \"demo-grid-{step_deg}\""))
}

/// Campaigns not in the repository: (label, campaign text).
fn off_repo(demo: &str, relative: &str, adaptive: &str) -> Vec<(String, String)> {
    let set = |text: &str, from: &str, to: &str| {
        // A pattern the shipped file no longer has would leave a campaign that is not what its label says.
        debug_assert!(text.contains(from), "{from:?} is not in the campaign any more");
        text.replace(from, to)
    };
    vec![
        (
            "demo grid at 7.5 deg, one band, averaging 1".into(),
            set(
                &set(&demo_grid(demo, 7.5), "averaging = 10 ", "averaging = 1 "),
                "bands_nm = [450.0, 550.0, 650.0]",
                "bands_nm = [550.0]",
            ),
        ),
        (
            "demo grid at 10 deg, two bands, averaging 100".into(),
            set(
                &set(&demo_grid(demo, 10.0), "averaging = 10 ", "averaging = 100 "),
                "bands_nm = [450.0, 550.0, 650.0]",
                "bands_nm = [450.0, 650.0]",
            ),
        ),
        (
            "demo grid at 12 deg, 2 repeats, settle 0.1 s, darks every 40".into(),
            set(
                &set(
                    &set(&demo_grid(demo, 12.0), "repeats = 1\n", "repeats = 2\n"),
                    "settle_s = 0.0 ",
                    "settle_s = 0.1 ",
                ),
                "dark_every_points = 100",
                "dark_every_points = 40",
            ),
        ),
        (
            "relative method, theta_o every 2.5 deg, reference every 50".into(),
            set(
                &set(relative, "step = 5.0 }", "step = 2.5 }"),
                "reference_every_points = 100",
                "reference_every_points = 50",
            ),
        ),
        (
            "adaptive, 150 points in passes of 25, white styrofoam".into(),
            set(
                &set(
                    &set(adaptive, "budget_points = 300", "budget_points = 150"),
                    "batch_points = 40",
                    "batch_points = 25",
                ),
                "preset = \"gold\"",
                "preset = \"white-styrofoam\"",
            ),
        ),
    ]
}

/// One dry-run through a binary.
#[derive(Debug, Clone, Copy)]
pub struct Run {
    pub points: u64,
    pub predicted_s: f64,
    pub actual_s: f64,
    pub wall_s: f64,
}

impl Run {
    pub fn s_per_point(&self) -> f64 {
        self.actual_s / self.points.max(1) as f64
    }

    pub fn difference(&self) -> f64 {
        self.actual_s / self.predicted_s - 1.0
    }
}

/// `gonio run` of `text` on `instrument` (None: the embedded simulated instrument) through `binary`.
pub fn dry_run(binary: &Path, text: &str, instrument: Option<&Path>) -> Result<Run, String> {
    let run = crate::gonio_run::gonio_run(binary, text, instrument)?;
    let v = run.run_json()?;
    let number =
        |x: &serde_json::Value, what: &str| x.as_f64().ok_or_else(|| format!("run.json has no {what}"));
    Ok(Run {
        points: v["campaign"]["points_done"]
            .as_u64()
            .ok_or("run.json has no campaign.points_done")?,
        predicted_s: number(
            &v["timing"]["predicted_instrument_s"],
            "timing.predicted_instrument_s",
        )?,
        actual_s: number(&v["timing"]["actual_instrument_s"], "timing.actual_instrument_s")?,
        wall_s: run.wall_s,
    })
}

/// Instrument-file keys added after the `--before` binary was built, which it refuses as unknown: uncertainties,
/// priors, the simulator's hidden flicker, when a controller takes the position it reports (which dates sweep
/// readings), and a controller's reply latency (which the earlier binary's time model did not know: it runs
/// on the same simulated hardware and predicts as it did).
const KEYS_SINCE_BEFORE: [&str; 12] = [
    "reply_latency_ms",
    "position_sampled_ms",
    "signature_u_sr",
    "aperture_radius_sd_mm",
    "detector_distance_sd_mm",
    "reseat_u_deg",
    "centring_u_mm",
    "tilt_u_deg",
    "flicker_rel",
    "offset_u_mm",
    "pointing_u_deg",
    "bandwidth_u_nm",
];

/// Keys added since that the earlier binary knows in another table: removed only under this one (the
/// head's amplifier noise as the lab states it; the simulator's hidden one it knows).
const TABLE_KEYS_SINCE_BEFORE: [(&str, &str); 1] = [("[instrument.detector]", "amplifier_noise_a_per_rthz")];

/// Keys added since that may also sit inside an inline table (a filter-wheel position's `{ ... }`; `gonio
/// selftest --write` writes the positions as tables, one key a line).
const INLINE_KEYS_SINCE_BEFORE: [&str; 1] = ["bandwidth_u_nm"];

/// Campaign keys added after the `--before` binary was built, which it refuses as unknown: without them it runs
/// the campaign as it did (its darks and normalisation readings at the points' averaging).
const CAMPAIGN_KEYS_SINCE_BEFORE: [&str; 1] = ["calibration_averaging"];

/// A campaign's text for the `--before` binary: without [`CAMPAIGN_KEYS_SINCE_BEFORE`].
fn campaign_for_before(text: &str) -> String {
    let kept: Vec<&str> = text
        .lines()
        .filter(|l| {
            !CAMPAIGN_KEYS_SINCE_BEFORE
                .iter()
                .any(|k| l.trim_start().starts_with(k))
        })
        .collect();
    kept.join("\n") + "\n"
}

/// `line` without `, key = value` for each of [`INLINE_KEYS_SINCE_BEFORE`] (the value ends at the next `,` or `}`).
fn without_inline_keys(line: &str) -> String {
    let mut out = line.to_string();
    for key in INLINE_KEYS_SINCE_BEFORE {
        let pattern = format!(", {key} =");
        while let Some(start) = out.find(&pattern) {
            let rest = &out[start + pattern.len()..];
            // The value up to the next `,` or `}`, less the space before that.
            let len = rest[..rest.find([',', '}']).unwrap_or(rest.len())]
                .trim_end()
                .len();
            out.replace_range(start..start + pattern.len() + len, "");
        }
    }
    out
}

/// `path` without [`KEYS_SINCE_BEFORE`] and [`INLINE_KEYS_SINCE_BEFORE`], written under `dir` for the earlier
/// binary.
fn for_before(path: &Path, dir: &Path, name: &str) -> Result<PathBuf, String> {
    let text = std::fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))?;
    // A key as `key = ...`, or as a table of its own (`[instrument.detector.key]`, as `gonio selftest --write`
    // writes one) up to the next header.
    let mut in_removed_table = false;
    let mut table = "";
    let kept: Vec<String> = text
        .lines()
        .filter(|l| {
            let t = l.trim_start();
            if t.starts_with('[') {
                table = t.trim_end();
                in_removed_table = KEYS_SINCE_BEFORE
                    .iter()
                    .any(|k| t.trim_end().trim_end_matches(']').ends_with(&format!(".{k}")));
                return !in_removed_table;
            }
            let added_here = TABLE_KEYS_SINCE_BEFORE
                .iter()
                .any(|(in_table, k)| *in_table == table && t.starts_with(k));
            !in_removed_table && !added_here && !KEYS_SINCE_BEFORE.iter().any(|k| t.starts_with(k))
        })
        .map(without_inline_keys)
        .collect();
    let out = dir.join(format!("before-{}.toml", name.replace([' ', ','], "-")));
    std::fs::write(&out, kept.join("\n") + "\n").map_err(|e| format!("{}: {e}", out.display()))?;
    Ok(out)
}

/// realistic.toml with the dynamics `gonio selftest --write` measured on its simulated hardware, that hardware
/// pinned by `[simulator.actual]` (module doc). Written under `dir`.
fn self_tested(binary: &Path, root: &Path, dir: &Path) -> Result<PathBuf, String> {
    let realistic = root.join("config/instruments/realistic.toml");
    let measured = dir.join("realistic-self-tested.toml");
    let o = std::process::Command::new(binary)
        .arg("selftest")
        .arg("--instrument")
        .arg(&realistic)
        .arg("--write")
        .arg(&measured)
        .output()
        .map_err(|e| format!("cannot run gonio selftest: {e}"))?;
    if !measured.exists() {
        return Err(format!(
            "gonio selftest wrote no file: {}",
            String::from_utf8_lossy(&o.stderr).lines().last().unwrap_or("")
        ));
    }
    // The hardware's truth, from a dry-run's run.json.
    let demo = std::fs::read_to_string(root.join("config/campaigns/demo.toml")).map_err(|e| e.to_string())?;
    let campaign = dir.join("demo.toml");
    std::fs::write(&campaign, demo).map_err(|e| e.to_string())?;
    let out = dir.join("truth");
    let o = std::process::Command::new(binary)
        .arg("run")
        .arg(&campaign)
        .arg("--instrument")
        .arg(&realistic)
        .arg("--out")
        .arg(&out)
        .arg("--quiet")
        .output()
        .map_err(|e| format!("cannot run gonio: {e}"))?;
    if !o.status.success() {
        return Err(format!(
            "the dry-run for the truth failed: {}",
            String::from_utf8_lossy(&o.stderr).lines().last().unwrap_or("")
        ));
    }
    let run: serde_json::Value = std::fs::read_to_string(out.join("run.json"))
        .map_err(|e| format!("no run.json for the truth: {e}"))
        .and_then(|t| serde_json::from_str(&t).map_err(|e| e.to_string()))?;
    let actual = &run["simulator_truth"]["actual"];
    let mut pinned = std::fs::read_to_string(&measured).map_err(|e| e.to_string())?;
    if pinned.contains("[simulator.actual") {
        // Appending a second table of the same name would not parse; and the file would pin its own hardware.
        return Err("realistic.toml states [simulator.actual] itself: nothing to pin".into());
    }
    if let Some(w) = actual["wheel_seconds_per_position"].as_f64() {
        pinned.push_str(&format!(
            "\n[simulator.actual.filter_wheel]\nseconds_per_position = {w:?}\n"
        ));
    }
    for axis in actual["axes"].as_array().into_iter().flatten() {
        let name = axis["name"].as_str().ok_or("an axis of the truth has no name")?;
        pinned.push_str(&format!("\n[simulator.actual.axes.{name}]\n"));
        for key in ["max_speed_deg_s", "accel_deg_s2", "settle_s", "backlash_deg"] {
            if let Some(v) = axis[key].as_f64() {
                pinned.push_str(&format!("{key} = {v:?}\n"));
            }
        }
    }
    std::fs::write(&measured, pinned).map_err(|e| e.to_string())?;
    Ok(measured)
}

/// One row: a campaign on an instrument, now and (optionally) before.
struct Row {
    campaign: String,
    instrument: &'static str,
    now: Result<Run, String>,
    before: Option<Result<Run, String>>,
}

/// The campaigns of the table: (label, text, in the repository).
fn campaigns(root: &Path, quick: bool) -> Vec<(String, String, bool)> {
    let read =
        |name: &str| std::fs::read_to_string(root.join("config/campaigns").join(name)).unwrap_or_default();
    let demo = read("demo.toml");
    let mut out = Vec::new();
    for name in [
        "demo.toml",
        "plan-demo.toml",
        "relative.toml",
        "adaptive.toml",
        "plan-examples.toml",
    ] {
        out.push((name.to_string(), read(name), true));
    }
    out.push((
        "template.toml (with a [material])".into(),
        format!(
            "{}\n[material]\npreset = \"coloured-plastic\"\n",
            read("template.toml")
        ),
        true,
    ));
    let steps: &[f64] = if quick { &[10.0] } else { &[10.0, 5.0, 2.5] };
    for step in steps {
        out.push((format!("demo grid at {step} deg"), demo_grid(&demo, *step), true));
    }
    if !quick {
        for (label, text) in off_repo(&demo, &read("relative.toml"), &read("adaptive.toml")) {
            out.push((label, text, false));
        }
    }
    out
}

/// The section's markdown.
pub fn section(root: &Path, binary: &Path, before: Option<&Path>, quick: bool) -> String {
    let scratch = std::env::temp_dir().join(format!("gonio-bench-selftest-{}", std::process::id()));
    let _ = std::fs::create_dir_all(&scratch);
    let mut instruments: Vec<(&'static str, Option<PathBuf>)> = vec![
        ("simulated", None),
        ("realistic", Some(root.join("config/instruments/realistic.toml"))),
    ];
    let mut notes = String::new();
    match self_tested(binary, root, &scratch) {
        Ok(path) => instruments.push(("realistic, self-tested", Some(path))),
        Err(e) => notes.push_str(&format!("realistic, self-tested: not measured ({e}).\n")),
    }
    // The earlier binary reads the same instrument files without the keys added since.
    let before_instruments: Vec<Option<PathBuf>> = instruments
        .iter()
        .map(|(name, path)| {
            let path = path.as_deref()?;
            Some(for_before(path, &scratch, name).unwrap_or_else(|_| path.to_path_buf()))
        })
        .collect();
    let mut rows = Vec::new();
    for (label, text, shipped) in campaigns(root, quick) {
        let label = if shipped { label } else { format!("{label} *") };
        for ((name, path), before_path) in instruments.iter().zip(&before_instruments) {
            let name: &'static str = name;
            eprintln!("    {label} on {name}...");
            rows.push(Row {
                campaign: label.clone(),
                instrument: name,
                now: dry_run(binary, &text, path.as_deref()),
                before: before.map(|b| dry_run(b, &campaign_for_before(&text), before_path.as_deref())),
            });
        }
    }
    let _ = std::fs::remove_dir_all(&scratch);
    let mut md = markdown(&rows, before.is_some());
    md.push_str(&notes);
    md
}

fn markdown(rows: &[Row], with_before: bool) -> String {
    use std::fmt::Write as _;
    let mut s = String::new();
    let _ = writeln!(
        s,
        "Predicted: what `gonio plan` prints and run.json keeps (`timing.predicted_instrument_s`). Dry-run: the run's \
         instrument time in run.json (`timing.actual_instrument_s`: from the end of homing until the run ended, its \
         closing calibration and last wheel turn included). Instrument files: simulated.toml (the ideal \
         instrument) and realistic.toml (its hardware a few per cent slower or faster than the file claims: the \
         prediction uses the file), and realistic.toml as `gonio selftest --write` measured it on the same \
         simulated hardware (realistic, self-tested: the model then uses the measured speeds, accelerations, \
         settle times and wheel). Campaigns marked * are not in the repository (crates/bench/src/time_model.rs \
         writes them). Target: every row within {:.0} %.",
        100.0 * TARGET
    );
    let _ = writeln!(s);
    let mut head = String::from(
        "| campaign | instrument | points | predicted (s) | dry-run (s) | difference | instrument time per point (s) | wall (s) |",
    );
    let mut rule = String::from("|---|---|---|---|---|---|---|---|");
    if with_before {
        head.push_str(" before: instrument time per point (s) | before: wall (s) | wall before / now |");
        rule.push_str("---|---|---|");
    }
    head.push_str(" within 2 % |");
    rule.push_str("---|");
    let _ = writeln!(s, "{head}\n{rule}");
    let (mut met, mut measured) = (0, 0);
    let mut worst: Option<(f64, String)> = None;
    for r in rows {
        let mut line = format!("| {} | {} |", r.campaign, r.instrument);
        match &r.now {
            Ok(run) => {
                measured += 1;
                let d = run.difference();
                let ok = d.abs() <= TARGET;
                met += usize::from(ok);
                if worst.as_ref().is_none_or(|(w, _)| d.abs() > *w) {
                    worst = Some((d.abs(), format!("{} on {}", r.campaign, r.instrument)));
                }
                let _ = write!(
                    line,
                    " {} | {:.1} | {:.1} | {:+.2} % | {:.3} | {:.2} |",
                    run.points,
                    run.predicted_s,
                    run.actual_s,
                    100.0 * d,
                    run.s_per_point(),
                    run.wall_s
                );
                if with_before {
                    match &r.before {
                        Some(Ok(b)) => {
                            let _ = write!(
                                line,
                                " {:.3} | {:.2} | {:.2} |",
                                b.s_per_point(),
                                b.wall_s,
                                b.wall_s / run.wall_s
                            );
                        }
                        Some(Err(e)) => {
                            let _ = write!(line, " not run: {e} | - | - |");
                        }
                        None => line.push_str(" - | - | - |"),
                    }
                }
                let _ = write!(line, " {} |", if ok { "met" } else { "NOT met" });
            }
            Err(e) => {
                let _ = write!(line, " not run: {e} | | | | | |");
                if with_before {
                    line.push_str(" | | |");
                }
                line.push_str(" - |");
            }
        }
        let _ = writeln!(s, "{line}");
    }
    let _ = writeln!(s);
    let _ = writeln!(
        s,
        "{met} of {measured} runs within {:.0} %{}.",
        100.0 * TARGET,
        worst.map_or(String::new(), |(w, what)| format!(
            "; the largest difference {:.2} % ({what})",
            100.0 * w
        ))
    );
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_earlier_binary_gets_the_campaign_without_the_keys_added_since() {
        let text =
            "[acquisition]\naveraging = 10\ncalibration_averaging = 100   # read longer\nrange = \"auto\"\n";
        assert_eq!(
            campaign_for_before(text),
            "[acquisition]\naveraging = 10\nrange = \"auto\"\n"
        );
    }

    #[test]
    fn the_earlier_binary_gets_the_files_without_the_keys_added_since() {
        let dir = tempfile::tempdir().expect("tempdir");
        let inline = dir.path().join("inline.toml");
        std::fs::write(
            &inline,
            "[instrument.detector]\nsolid_angle_u = 1e-3\nsignature_u_sr = { 3 = 5e-3 }\naveraging = 10\n",
        )
        .expect("write");
        let table = dir.path().join("table.toml");
        std::fs::write(
            &table,
            "[instrument.detector]\naveraging = 10\n[instrument.detector.signature_u_sr]\n3 = 5e-3\n90 = 1.5e-5\n\
             [instrument.source]\npower_w = 1e-3\n",
        )
        .expect("write");
        let read = |p: PathBuf| std::fs::read_to_string(p).expect("read");
        let a = read(for_before(&inline, dir.path(), "inline").expect("written"));
        assert_eq!(a, "[instrument.detector]\nsolid_angle_u = 1e-3\naveraging = 10\n");
        let b = read(for_before(&table, dir.path(), "table").expect("written"));
        assert_eq!(
            b,
            "[instrument.detector]\naveraging = 10\n[instrument.source]\npower_w = 1e-3\n"
        );
        // The amplifier's noise leaves the lab's table and stays in the simulator's, which the earlier binary
        // knows.
        let amplifier = dir.path().join("amplifier.toml");
        std::fs::write(
            &amplifier,
            "[instrument.detector]\namplifier_noise_a_per_rthz = 2e-14\naveraging = 10\n\
             [simulator.imperfections.detector]\namplifier_noise_a_per_rthz = 2e-14\n",
        )
        .expect("write");
        let c = read(for_before(&amplifier, dir.path(), "amplifier").expect("written"));
        assert_eq!(
            c,
            "[instrument.detector]\naveraging = 10\n[simulator.imperfections.detector]\n\
             amplifier_noise_a_per_rthz = 2e-14\n"
        );
    }

    #[test]
    fn a_key_inside_an_inline_table_is_taken_out_with_its_value() {
        let line = "    { position = 1, band_nm = 450.0, bandwidth_u_nm = 1.0, transmission = 0.5 },";
        assert_eq!(
            without_inline_keys(line),
            "    { position = 1, band_nm = 450.0, transmission = 0.5 },"
        );
        let last = "{ position = 2, bandwidth_u_nm = 2 }";
        assert_eq!(without_inline_keys(last), "{ position = 2 }");
        assert_eq!(without_inline_keys("positions = []"), "positions = []");
    }

    #[test]
    fn the_demo_grid_changes_only_its_steps_and_name() {
        let demo = include_str!("../../../config/campaigns/demo.toml");
        let g = demo_grid(demo, 5.0);
        assert!(
            g.contains("theta_i_deg = { from = 0.0, to = 60.0, step = 5 }"),
            "{g}"
        );
        assert!(
            g.contains("theta_o_deg = { from = 0.0, to = 75.0, step = 5 }"),
            "{g}"
        );
        assert!(
            g.contains("delta_phi_deg = { from = 0.0, to = 180.0, step = 10 }"),
            "{g}"
        );
        assert!(g.contains("id = \"demo-grid-5\""), "{g}");
        // Every campaign not in the repository differs from the file it started from.
        let relative = include_str!("../../../config/campaigns/relative.toml");
        let adaptive = include_str!("../../../config/campaigns/adaptive.toml");
        for (label, text) in off_repo(demo, relative, adaptive) {
            assert!(
                text != demo && text != relative && text != adaptive,
                "{label} is a shipped file"
            );
        }
    }
}
