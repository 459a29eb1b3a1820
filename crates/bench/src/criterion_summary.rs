//! The criterion micro-benchmarks' latest results, read from criterion's own output
//! (`$CARGO_TARGET_DIR/criterion/**/new/{benchmark,estimates}.json`, written by `cargo bench -p <crate>`), so that
//! BENCHMARKS.md summarises them without re-running them.

use std::path::{Path, PathBuf};

use serde_json::Value;

#[derive(Debug, Clone)]
pub struct CriterionResult {
    pub id: String,
    /// Criterion's typical time per iteration (the regression slope, else the mean), ns, with its 95% interval.
    pub typical_ns: f64,
    pub lower_ns: f64,
    pub upper_ns: f64,
    /// Elements per iteration, when the benchmark declares a throughput in elements.
    pub elements: Option<u64>,
}

impl CriterionResult {
    /// ns per element (per iteration when no throughput is declared).
    pub fn per_element_ns(&self) -> f64 {
        self.typical_ns / self.elements.unwrap_or(1).max(1) as f64
    }
}

/// Every result under `dir`, sorted by id; empty when criterion has not run.
pub fn read(dir: &Path) -> Vec<CriterionResult> {
    let mut found = Vec::new();
    collect(dir, &mut found, 0);
    found.sort_by(|a, b| a.id.cmp(&b.id));
    found
}

fn collect(dir: &Path, out: &mut Vec<CriterionResult>, depth: usize) {
    if depth > 8 {
        return;
    }
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    let mut subdirs: Vec<PathBuf> = Vec::new();
    for e in entries.flatten() {
        let p = e.path();
        if p.is_dir() {
            if p.file_name().is_some_and(|n| n == "new") {
                if let Some(r) = parse(&p) {
                    out.push(r);
                }
            } else if p
                .file_name()
                .is_some_and(|n| n != "report" && n != "base" && n != "change")
            {
                subdirs.push(p);
            }
        }
    }
    for d in subdirs {
        collect(&d, out, depth + 1);
    }
}

fn parse(new_dir: &Path) -> Option<CriterionResult> {
    let read = |name: &str| -> Option<Value> {
        serde_json::from_str(&std::fs::read_to_string(new_dir.join(name)).ok()?).ok()
    };
    let bench = read("benchmark.json")?;
    let est = read("estimates.json")?;
    let typical = if est["slope"].is_object() {
        &est["slope"]
    } else {
        &est["mean"]
    };
    Some(CriterionResult {
        id: bench["full_id"].as_str()?.to_string(),
        typical_ns: typical["point_estimate"].as_f64()?,
        lower_ns: typical["confidence_interval"]["lower_bound"].as_f64()?,
        upper_ns: typical["confidence_interval"]["upper_bound"].as_f64()?,
        elements: bench["throughput"]["Elements"].as_u64(),
    })
}
