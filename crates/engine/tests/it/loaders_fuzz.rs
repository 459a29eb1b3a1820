//! The file loaders fed mutated documents: the instrument file (`InstrumentFile::parse`), the campaign file as the
//! daemon takes it (`prepare_submitted_campaign`: plan, schedule, materials), and material files
//! (`Material::from_document`). Starting from valid documents, each case changes values to extremes (NaN,
//! infinities, huge and negative numbers, wrong types), removes and adds keys, and cuts, duplicates and garbles
//! lines. Never a panic and never a hang; every refusal names the file and where in it (a line, or the table
//! and key); whatever is accepted can be used (the simulator, the scheduler's models, the BRDF evaluate it).
//!
//! Cases: `GONIO_FUZZ_CASES` (default: a fast tier); e.g. `GONIO_FUZZ_CASES=20000 cargo test --release
//! -p gonio-engine --test it loaders_fuzz` for a large run.

use std::sync::Arc;
use std::time::Duration;

use gonio_brdf::material::Material;
use gonio_brdf::{Brdf, Direction, Wavelength};
use gonio_engine::prepare_submitted_campaign;
use gonio_instrument::{InstrumentFile, SIMULATED_INSTRUMENT_TOML};
use proptest::prelude::*;

fn cases(default: u32) -> u32 {
    std::env::var("GONIO_FUZZ_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

// ---------------------------------------------------------------- mutations

/// One change to a document.
#[derive(Debug, Clone)]
enum Mutation {
    /// Replace the value at the `n`-th leaf (depth first, modulo their number).
    Value(usize, Replacement),
    /// Remove the `n`-th leaf's key (or array element).
    Remove(usize),
    /// Add an unknown key next to the `n`-th leaf.
    AddKey(usize, String),
    /// Text-level: delete, duplicate or garble line `n`, or cut the text at `n`.
    DeleteLine(usize),
    DuplicateLine(usize),
    GarbleLine(usize, Vec<u8>),
    Truncate(usize),
}

#[derive(Debug, Clone)]
enum Replacement {
    Float(f64),
    Int(i64),
    Text(String),
    Bool(bool),
    EmptyArray,
    EmptyTable,
    /// The leaf's array (if it is in one) with its elements repeated.
    Repeat(usize),
}

fn replacement() -> impl Strategy<Value = Replacement> {
    let floats = prop::sample::select(vec![
        f64::NAN,
        f64::INFINITY,
        f64::NEG_INFINITY,
        0.0,
        -0.0,
        -1.0,
        1e-320,
        1e308,
        -1e308,
        0.5,
        90.0,
        180.0,
        360.0,
        1e6,
        -90.0,
    ]);
    let ints = prop::sample::select(vec![
        0i64,
        -1,
        1,
        2,
        6,
        7,
        12,
        13,
        31,
        32,
        99,
        100,
        255,
        256,
        65_536,
        i64::MAX,
        i64::MIN,
    ]);
    let texts = prop_oneof![
        prop::sample::select(vec![
            "",
            "sim",
            "sim-pty",
            "smc100",
            "zaber-ascii",
            "fw102c",
            "pm100",
            "reference",
            "in-plane",
            "full",
            "points",
            "isotropic",
            "light-arm",
            "detector-arm",
            "sample-tilt",
            "sample-rotation",
            "auto",
            "absolute",
            "relative",
            "spectralon",
            "mirror",
            "measured",
            "../../etc/passwd",
            "/dev/null",
            "x.toml",
            "lambertian",
            "plastic",
            "conductor",
            "ggx",
            "beckmann",
            "merl",
            "red",
        ])
        .prop_map(str::to_string),
        "[ -~]{0,12}",
        "\\PC{0,8}",
    ];
    prop_oneof![
        4 => floats.prop_map(Replacement::Float),
        3 => ints.prop_map(Replacement::Int),
        3 => texts.prop_map(Replacement::Text),
        1 => any::<bool>().prop_map(Replacement::Bool),
        1 => Just(Replacement::EmptyArray),
        1 => Just(Replacement::EmptyTable),
        1 => (2usize..2000).prop_map(Replacement::Repeat),
    ]
}

fn mutation() -> impl Strategy<Value = Mutation> {
    let n = any::<usize>();
    prop_oneof![
        8 => (n, replacement()).prop_map(|(n, r)| Mutation::Value(n, r)),
        2 => n.prop_map(Mutation::Remove),
        1 => (n, "[a-z_]{1,12}").prop_map(|(n, k)| Mutation::AddKey(n, k)),
        1 => n.prop_map(Mutation::DeleteLine),
        1 => n.prop_map(Mutation::DuplicateLine),
        1 => (n, proptest::collection::vec(any::<u8>(), 0..12)).prop_map(|(n, b)| Mutation::GarbleLine(n, b)),
        1 => n.prop_map(Mutation::Truncate),
    ]
}

/// Paths to every leaf of a TOML value: keys and array indices.
#[derive(Debug, Clone)]
enum Step {
    Key(String),
    Index(usize),
}

fn leaves(v: &toml::Value, path: &mut Vec<Step>, out: &mut Vec<Vec<Step>>) {
    match v {
        toml::Value::Table(t) => {
            for (k, child) in t {
                path.push(Step::Key(k.clone()));
                leaves(child, path, out);
                path.pop();
            }
        }
        toml::Value::Array(a) if !a.is_empty() => {
            for (i, child) in a.iter().enumerate() {
                path.push(Step::Index(i));
                leaves(child, path, out);
                path.pop();
            }
        }
        _ => out.push(path.clone()),
    }
}

fn at_mut<'a>(v: &'a mut toml::Value, path: &[Step]) -> Option<&'a mut toml::Value> {
    let mut cur = v;
    for step in path {
        cur = match (step, cur) {
            (Step::Key(k), toml::Value::Table(t)) => t.get_mut(k)?,
            (Step::Index(i), toml::Value::Array(a)) => a.get_mut(*i)?,
            _ => return None,
        };
    }
    Some(cur)
}

/// Apply the value-level mutations to the parsed document, then the text-level ones to its text.
fn mutate(text: &str, mutations: &[Mutation]) -> String {
    let Ok(table) = text.parse::<toml::Table>() else {
        return text.to_string();
    };
    let mut doc = toml::Value::Table(table);
    for m in mutations {
        let mut all = Vec::new();
        leaves(&doc, &mut Vec::new(), &mut all);
        if all.is_empty() {
            break;
        }
        let pick = |n: usize| all[n % all.len()].clone();
        match m {
            Mutation::Value(n, r) => {
                let path = pick(*n);
                if let Replacement::Repeat(times) = r {
                    if let Some((Step::Index(_), parent)) = path.split_last()
                        && let Some(toml::Value::Array(a)) = at_mut(&mut doc, parent)
                    {
                        let copy = a.clone();
                        for _ in 0..*times {
                            a.extend(copy.iter().cloned());
                            if a.len() > 4000 {
                                break;
                            }
                        }
                    }
                    continue;
                }
                if let Some(slot) = at_mut(&mut doc, &path) {
                    *slot = match r {
                        Replacement::Float(x) => toml::Value::Float(*x),
                        Replacement::Int(i) => toml::Value::Integer(*i),
                        Replacement::Text(s) => toml::Value::String(s.clone()),
                        Replacement::Bool(b) => toml::Value::Boolean(*b),
                        Replacement::EmptyArray => toml::Value::Array(Vec::new()),
                        Replacement::EmptyTable => toml::Value::Table(toml::Table::new()),
                        Replacement::Repeat(_) => continue,
                    };
                }
            }
            Mutation::Remove(n) => {
                let path = pick(*n);
                if let Some((last, parent)) = path.split_last() {
                    match (last, at_mut(&mut doc, parent)) {
                        (Step::Key(k), Some(toml::Value::Table(t))) => {
                            t.remove(k);
                        }
                        (Step::Index(i), Some(toml::Value::Array(a))) if *i < a.len() => {
                            a.remove(*i);
                        }
                        _ => {}
                    }
                }
            }
            Mutation::AddKey(n, key) => {
                let path = pick(*n);
                if let Some((_, parent)) = path.split_last()
                    && let Some(toml::Value::Table(t)) = at_mut(&mut doc, parent)
                {
                    t.insert(key.clone(), toml::Value::Integer(1));
                }
            }
            _ => {}
        }
    }
    let mut text = toml::to_string(&doc).unwrap_or_default();
    for m in mutations {
        let lines: Vec<&str> = text.lines().collect();
        if lines.is_empty() {
            break;
        }
        let mut owned: Vec<String> = lines.iter().map(|l| l.to_string()).collect();
        match m {
            Mutation::DeleteLine(n) => {
                owned.remove(n % lines.len());
            }
            Mutation::DuplicateLine(n) => {
                let l = owned[n % lines.len()].clone();
                owned.insert(n % lines.len(), l);
            }
            Mutation::GarbleLine(n, bytes) => {
                let i = n % lines.len();
                owned[i] = format!("{}{}", owned[i], String::from_utf8_lossy(bytes));
            }
            Mutation::Truncate(n) => {
                let cut = n % (text.len() + 1);
                let cut = (0..=cut).rev().find(|c| text.is_char_boundary(*c)).unwrap_or(0);
                text.truncate(cut);
                continue;
            }
            _ => continue,
        }
        text = owned.join("\n");
    }
    text
}

/// A refusal names the file and where: a line (`origin:N` or "line N"), or the table and key (`[table] key`).
fn names_file_and_place(message: &str, origin: &str) -> bool {
    message.contains(origin)
        && (message.contains("line") || message.contains('[') || message.contains(&format!("{origin}:")))
}

/// Run `f` on its own thread; a hang (past `limit`) fails the case instead of blocking the test run.
fn within<T: Send + 'static>(
    limit: Duration,
    f: impl FnOnce() -> T + Send + 'static,
) -> Result<T, TestCaseError> {
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::spawn(move || {
        let _ = tx.send(f());
    });
    rx.recv_timeout(limit)
        .map_err(|_| TestCaseError::fail(format!("no answer within {limit:?}: a hang")))
}

// ---------------------------------------------------------------- instrument files

fn check_usable_instrument(file: &InstrumentFile) -> Result<(), TestCaseError> {
    // Whatever validates can be built into the simulator and the scheduler's models without a panic.
    let inst = &file.instrument;
    let _ = gonio_scheduler::timing::TimeModel::new(inst);
    let _ = gonio_scheduler::kinematics::Kinematics::new(inst);
    let c = gonio_scheduler::constraints::Constraints::new(inst, None);
    // The safety limits the constraints enforce are real limits.
    prop_assert!(
        c.min_arm_separation_deg >= 0.0,
        "min_arm_separation_deg {}",
        c.min_arm_separation_deg
    );
    prop_assert!(c.retro_block_deg >= 0.0, "retro_block_deg {}", c.retro_block_deg);
    let scene = Arc::new(gonio_simulator::scene::UniformScene { power_w: 1e-6 });
    let _ = gonio_simulator::SimInstrument::new(file, scene, 1.0);
    Ok(())
}

proptest! {
    #![proptest_config(ProptestConfig { cases: cases(600), failure_persistence: None, ..ProptestConfig::default() })]

    #[test]
    fn mutated_instrument_files_are_refused_with_a_place_or_usable(
        mutations in proptest::collection::vec(mutation(), 1..4),
    ) {
        let text = mutate(SIMULATED_INSTRUMENT_TOML, &mutations);
        match InstrumentFile::parse(&text, "fuzz-instrument.toml") {
            Ok(file) => check_usable_instrument(&file)?,
            Err(e) => {
                let m = e.to_string();
                prop_assert!(names_file_and_place(&m, "fuzz-instrument.toml"), "{}", m);
            }
        }
    }

    #[test]
    fn random_text_as_an_instrument_file_is_refused_with_a_place(text in "\\PC{0,300}") {
        if let Err(e) = InstrumentFile::parse(&text, "fuzz-instrument.toml") {
            let m = e.to_string();
            prop_assert!(names_file_and_place(&m, "fuzz-instrument.toml"), "{}", m);
        }
    }
}

// ---------------------------------------------------------------- campaign files (as the daemon takes them)

const CAMPAIGN: &str = r#"[campaign]
id = "fuzz"
description = "mutated"

[sample]
radius_mm = 12.5

[plan]
bands_nm = [450.0, 550.0]
repeats = 1
reciprocity = true

[plan.grid]
kind = "isotropic"
theta_i_deg = { from = 0.0, to = 60.0, step = 30.0 }
theta_o_deg = [10.0, 40.0, 70.0]
delta_phi_deg = { from = 0.0, to = 180.0, step = 90.0 }

[plan.calibration]
dark_every_points = 20
reference_every_s = 1800.0
reference_pose_deg = { light = -90.0, detector = 90.0 }

[calibration]
method = "absolute"
simulate_operator = true

[acquisition]
averaging = 4
range = "auto"
settle_s = 0.1
retries = 2

[material]
model = "plastic"
distribution = "ggx"
masking = "height-correlated"
alpha = 0.1
ior = 1.49
albedo = { 450 = 0.10, 550 = 0.15, 650 = 0.60 }
"#;

fn campaign_base() -> impl Strategy<Value = String> {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
    let mut texts = vec![CAMPAIGN.to_string()];
    for f in ["config/campaigns/demo.toml", "config/campaigns/plan-demo.toml"] {
        if let Ok(t) = std::fs::read_to_string(root.join(f)) {
            texts.push(t);
        }
    }
    prop::sample::select(texts)
}

fn prepare(text: String) -> Result<Result<u64, String>, TestCaseError> {
    within(Duration::from_secs(120), move || {
        let dir = tempfile::tempdir().expect("tempdir");
        prepare_submitted_campaign(
            &text,
            "fuzz-campaign.toml",
            dir.path(),
            &InstrumentFile::simulated(),
        )
        .map(|p| p.total_points)
        .map_err(|e| e.to_string())
    })
}

proptest! {
    #![proptest_config(ProptestConfig { cases: cases(600) / 3 + 1, failure_persistence: None, ..ProptestConfig::default() })]

    #[test]
    fn mutated_campaigns_are_refused_with_a_place_or_planned(
        base in campaign_base(),
        mutations in proptest::collection::vec(mutation(), 1..4),
    ) {
        let text = mutate(&base, &mutations);
        match prepare(text)? {
            Ok(points) => prop_assert!(points > 0),
            Err(m) => prop_assert!(names_file_and_place(&m, "fuzz-campaign.toml"), "{}", m),
        }
    }
}

#[test]
fn plans_too_large_to_validate_are_refused_at_once() {
    // Regression: a grid's size was not bounded, so one submitted file made the daemon enumerate 10^12+
    // geometries (minutes, then gigabytes, then the kernel's OOM killer). Now the grid's size is checked before
    // anything is enumerated, and so is geometries x bands x repeats.
    let huge_grid = CAMPAIGN.replace(
        "kind = \"isotropic\"\ntheta_i_deg = { from = 0.0, to = 60.0, step = 30.0 }\ntheta_o_deg = [10.0, 40.0, 70.0]\n\
         delta_phi_deg = { from = 0.0, to = 180.0, step = 90.0 }",
        "kind = \"full\"\ntheta_i_deg = { from = 0.0, to = 80.0, step = 0.001 }\n\
         phi_i_deg = { from = 0.0, to = 359.0, step = 0.01 }\ntheta_o_deg = { from = 0.0, to = 80.0, step = 0.001 }\n\
         phi_o_deg = { from = 0.0, to = 359.0, step = 0.01 }",
    );
    assert_ne!(huge_grid, CAMPAIGN, "the grid was replaced");
    let m = prepare(huge_grid)
        .expect("an answer in time")
        .expect_err("refused");
    assert!(
        m.contains("fuzz-campaign.toml") && m.contains("grid") && m.contains("geometries"),
        "{m}"
    );
    // Regression: a range wider than any step covers overflowed the angle count (a panic in debug builds).
    let wide = CAMPAIGN.replace(
        "theta_o_deg = [10.0, 40.0, 70.0]",
        "theta_o_deg = { from = -1e308, to = 1e308, step = 1.0 }",
    );
    assert_ne!(wide, CAMPAIGN);
    let m = prepare(wide).expect("an answer in time").expect_err("refused");
    assert!(m.contains("theta_o_deg") && m.contains("at most 100000"), "{m}");
    let huge_repeats = CAMPAIGN.replace("repeats = 1", "repeats = 4000000000");
    let m = prepare(huge_repeats)
        .expect("an answer in time")
        .expect_err("refused");
    assert!(m.contains("repeats") && m.contains("readings"), "{m}");
}

// ---------------------------------------------------------------- material files

fn material_base() -> impl Strategy<Value = String> {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config/materials");
    let mut texts = Vec::new();
    if let Ok(entries) = std::fs::read_dir(&dir) {
        for e in entries.flatten() {
            if let Ok(t) = std::fs::read_to_string(e.path()) {
                texts.push(t);
            }
        }
    }
    texts.sort();
    assert!(!texts.is_empty(), "no material files in {}", dir.display());
    prop::sample::select(texts)
}

proptest! {
    #![proptest_config(ProptestConfig { cases: cases(600), failure_persistence: None, ..ProptestConfig::default() })]

    #[test]
    fn mutated_materials_are_refused_with_a_place_or_evaluate(
        base in material_base(),
        mutations in proptest::collection::vec(mutation(), 1..4),
    ) {
        let text = mutate(&base, &mutations);
        let dir = tempfile::tempdir().map_err(|e| TestCaseError::fail(e.to_string()))?;
        match Material::from_document(&text, "fuzz-material.toml", dir.path()) {
            Ok(m) => {
                // Accepted: it evaluates to finite, non-negative values at every band and a few geometries.
                for nm in [400.0, 550.0, 700.0] {
                    let Ok(wl) = Wavelength::from_nm(nm) else { continue };
                    for (ti, to, dp) in [(0.0, 0.0, 0.0), (30.0, 30.0, 180.0), (60.0, 10.0, 90.0), (80.0, 85.0, 180.0)] {
                        let wi = Direction::from_spherical_deg(ti, 0.0);
                        let wo = Direction::from_spherical_deg(to, dp);
                        // A wavelength outside a spectral table is an error, not a value.
                        if let Ok(f) = m.eval(&wi, &wo, wl) {
                            prop_assert!(f.is_finite() && f >= 0.0, "f = {} at {} nm for {:?}", f, nm, text);
                        }
                    }
                }
            }
            Err(e) => {
                let m = e.to_string();
                prop_assert!(
                    names_file_and_place(&m, "fuzz-material.toml") || m.contains("unknown material preset"),
                    "{}", m
                );
            }
        }
    }
}

#[test]
fn safety_limits_that_would_disable_the_collision_checks_are_refused() {
    // Regression: a negative (or NaN) min_arm_separation_deg or retro_block_deg used to validate, and with it
    // every arm separation passed the scheduler's and the engine's checks.
    for (key, bad) in [
        ("min_arm_separation_deg = 10.0", "min_arm_separation_deg = -1.0"),
        ("min_arm_separation_deg = 10.0", "min_arm_separation_deg = nan"),
        ("retro_block_deg = 5.0", "retro_block_deg = -5.0"),
        ("retro_block_deg = 5.0", "retro_block_deg = inf"),
    ] {
        let text = SIMULATED_INSTRUMENT_TOML.replacen(key, bad, 1);
        assert_ne!(text, SIMULATED_INSTRUMENT_TOML, "{key} is in the file");
        let e = InstrumentFile::parse(&text, "lab.toml")
            .expect_err(bad)
            .to_string();
        let name = key.split(' ').next().unwrap_or_default();
        assert!(
            e.contains("lab.toml") && e.contains("[instrument.safety]") && e.contains(name),
            "{e}"
        );
    }
}

#[test]
fn optical_constants_no_material_has_are_refused() {
    // Regression (found by the material fuzzing): a conductor with k = 1e308 validated, and its Fresnel factor,
    // hence its BRDF, was NaN at every geometry.
    let gold = std::fs::read_to_string(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config/materials/gold.toml"),
    )
    .expect("gold preset");
    for (from, to, key) in [
        ("700 = 3.964", "700 = 1e308", "k"),
        ("700 = 0.161", "700 = 1e200", "eta"),
    ] {
        let text = gold.replacen(from, to, 1);
        assert_ne!(text, gold, "{from} is in the preset");
        let dir = tempfile::tempdir().expect("tempdir");
        let e = Material::from_document(&text, "gold-edit.toml", dir.path())
            .expect_err(to)
            .to_string();
        assert!(
            e.contains("gold-edit.toml") && e.contains(&format!("`{key}`")),
            "{e}"
        );
    }
}
