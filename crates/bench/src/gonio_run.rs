//! One campaign through the release binary as a lab runs it (`gonio run FILE --instrument INST --out DIR
//! --quiet`), in a directory of its own that is removed when the run is dropped.

use std::path::{Path, PathBuf};
use std::time::Instant;

use gonio_results::sweeps::{SweepReading, parse_sweeps_csv};

/// A finished run and where its files are.
pub struct GonioRun {
    dir: PathBuf,
    /// The run's output directory (points.csv, sweeps.csv, run.json).
    pub out: PathBuf,
    /// The process's wall time (start-up, planning, the run, the completion, the files), s.
    pub wall_s: f64,
}

impl Drop for GonioRun {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.dir);
    }
}

impl GonioRun {
    /// The run's run.json.
    pub fn run_json(&self) -> Result<serde_json::Value, String> {
        std::fs::read_to_string(self.out.join("run.json"))
            .map_err(|e| e.to_string())
            .and_then(|t| serde_json::from_str(&t).map_err(|e| e.to_string()))
    }

    /// The run's instrument time (run.json `timing.actual_instrument_s`), s.
    pub fn instrument_s(&self) -> Result<f64, String> {
        self.run_json()?["timing"]["actual_instrument_s"]
            .as_f64()
            .ok_or_else(|| "run.json has no timing.actual_instrument_s".to_string())
    }

    /// The run's sweep readings (sweeps.csv).
    pub fn sweeps(&self) -> Result<Vec<SweepReading>, String> {
        let path = self.out.join("sweeps.csv");
        let text = std::fs::read_to_string(&path).map_err(|e| format!("{}: {e}", path.display()))?;
        parse_sweeps_csv(&text, &path.display().to_string()).map_err(|e| e.to_string())
    }
}

/// Run campaign `text` through `binary` on `instrument` (None: the binary's embedded simulated instrument) in a
/// fresh directory.
pub fn gonio_run(binary: &Path, text: &str, instrument: Option<&Path>) -> Result<GonioRun, String> {
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos());
    let dir = std::env::temp_dir().join(format!("gonio-bench-run-{}-{nanos}", std::process::id()));
    std::fs::create_dir_all(&dir).map_err(|e| e.to_string())?;
    let mut run = GonioRun {
        out: dir.join("out"),
        dir,
        wall_s: 0.0,
    };
    let campaign = run.dir.join("campaign.toml");
    std::fs::write(&campaign, text).map_err(|e| e.to_string())?;
    let start = Instant::now();
    let mut command = std::process::Command::new(binary);
    command
        .arg("run")
        .arg(&campaign)
        .arg("--out")
        .arg(&run.out)
        .arg("--quiet");
    if let Some(i) = instrument {
        command.arg("--instrument").arg(i);
    }
    let o = command
        .output()
        .map_err(|e| format!("cannot run {}: {e}", binary.display()))?;
    if !o.status.success() {
        // The last line that says something (a message may end with a blank line), without the table's bars,
        // short enough for a table's cell.
        let stderr = String::from_utf8_lossy(&o.stderr);
        let why = stderr
            .lines()
            .rev()
            .map(str::trim)
            .find(|l| !l.is_empty())
            .unwrap_or("no message")
            .replace('|', "/");
        let short: String = why.chars().take(100).collect();
        let more = if short.len() < why.len() { "..." } else { "" };
        return Err(format!("gonio run failed: {short}{more}"));
    }
    run.wall_s = start.elapsed().as_secs_f64();
    Ok(run)
}
