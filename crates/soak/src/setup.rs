//! The soak campaigns and the faulty simulated instrument.
//!
//! A soak campaign measures an exact number of points: random geometries (seeded) in a `kind = "points"` grid,
//! two bands each, with darks and direct-beam readings at the cadence of the demo campaign. The scheduler skips
//! geometries it cannot measure (retro-reflection, arm collision), so the number of geometries is found by
//! bisection on what the engine's own validation counts.
//!
//! The instrument is a [`SoakInstrument`]: `config/instruments/simulated.toml` (the ideal one, embedded) or
//! `config/instruments/realistic.toml` (the imperfect one of issue 16, embedded too), or any instrument file,
//! with keys appended to its `[simulator.faults]` table, so that the stored instrument text keeps the file's
//! comments and units, its `[simulator.quirks]` and its `[simulator.imperfections]`. Every soak runs under the
//! recorded real-device variants, each the one that demands the most of a host: realistic.toml takes them, and
//! the ideal file, whose own quirks are the manuals' behaviour, gets them written into its `[simulator.quirks]`
//! table ([`recorded_quirks`]), so the soaks keep testing the drivers against what real devices were recorded
//! doing.

use std::path::Path;

use gonio_campaign::{AcquisitionSection, CalibrationSection, CampaignFile};
use gonio_engine::prepare_campaign;
use gonio_instrument::{Faults, InstrumentFile, Quirks, SIMULATED_INSTRUMENT_TOML};
use gonio_scheduler::plan::{GridKind, GridSpec, PlanSpec, SweepSpec, SweptArm};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

use crate::SoakError;

/// `config/instruments/realistic.toml`: the simulated instrument with the imperfections of issue 16.
pub const REALISTIC_INSTRUMENT_TOML: &str = include_str!("../../../config/instruments/realistic.toml");

/// The instrument file a soak runs on: what the report calls it, and its text.
#[derive(Debug, Clone, PartialEq)]
pub struct SoakInstrument {
    /// The name the report gives it (the file name).
    pub name: String,
    /// The file's text.
    pub text: String,
}

impl Default for SoakInstrument {
    fn default() -> SoakInstrument {
        SoakInstrument::simulated()
    }
}

impl SoakInstrument {
    /// The ideal simulated instrument, `config/instruments/simulated.toml`, under the recorded real-device
    /// variants ([`recorded_quirks`]).
    pub fn simulated() -> SoakInstrument {
        SoakInstrument {
            name: "simulated.toml".into(),
            text: with_quirks_table(SIMULATED_INSTRUMENT_TOML, &recorded_quirks()),
        }
    }

    /// The imperfect one, `config/instruments/realistic.toml`.
    pub fn realistic() -> SoakInstrument {
        SoakInstrument {
            name: "realistic.toml".into(),
            text: REALISTIC_INSTRUMENT_TOML.into(),
        }
    }

    /// An instrument file on disk (it must have a `[simulator]` section and a `[simulator.faults]` table).
    pub fn load(path: &Path) -> Result<SoakInstrument, SoakError> {
        let text = std::fs::read_to_string(path).map_err(SoakError::io(path.display().to_string()))?;
        let name = path.file_name().map_or_else(
            || path.display().to_string(),
            |n| n.to_string_lossy().into_owned(),
        );
        let soak = SoakInstrument { name, text };
        soak.file()?;
        Ok(soak)
    }

    /// The parsed file.
    pub fn file(&self) -> Result<InstrumentFile, SoakError> {
        InstrumentFile::parse(&self.text, &self.name).map_err(|e| SoakError::Setup(e.to_string()))
    }

    /// The file has imperfections switched on (its points carry a per-point attribution of them).
    pub fn is_imperfect(&self) -> bool {
        self.file()
            .ok()
            .is_some_and(|f| !f.simulator.imperfections.is_ideal())
    }
}

/// Bands measured at every geometry.
pub const BANDS_NM: [f64; 2] = [450.0, 650.0];

/// A campaign file and what the engine plans for it.
#[derive(Debug, Clone)]
pub struct SoakCampaign {
    /// The campaign id (`[campaign] id`).
    pub name: String,
    /// The campaign file text.
    pub text: String,
    /// Points the engine plans (validated by [`prepare_campaign`]).
    pub total_points: u64,
    /// Sweep segments it plans after the points (each a store transaction of readings; 0 without sweeps).
    pub sweep_segments: u64,
    /// Instrument time the time model predicts (s).
    pub predicted_s: f64,
}

/// The sweeps the crash soak adds after its points (issue 41): the detector swept through the plane of incidence
/// at two incidences, at 10 deg/s and two meter samples a reading, so that a segment (one arc in one band) is a
/// few seconds of instrument time and hundreds of readings, and a kill from outside lands inside one.
pub fn soak_sweeps() -> Vec<SweepSpec> {
    let arc = toml::Table::from_iter([
        ("from".to_string(), toml::Value::Float(-70.0)),
        ("to".to_string(), toml::Value::Float(70.0)),
    ]);
    vec![SweepSpec {
        arm: SweptArm::Detector,
        theta_i_deg: toml::Value::Array(vec![toml::Value::Float(20.0), toml::Value::Float(45.0)]),
        theta_o_deg: toml::Value::Table(arc),
        plane_phi_deg: None,
        speed_deg_s: 10.0,
        averaging: 2,
        follow: None,
        isotropic: false,
    }]
}

/// The campaign text for these geometries `[theta_i, phi_i, theta_o, phi_o]` (degrees), then these sweeps.
pub fn campaign_text(name: &str, geometries: &[[f64; 4]], sweeps: &[SweepSpec]) -> String {
    let mut grid = GridSpec::new(GridKind::Points);
    grid.points = Some(
        geometries
            .iter()
            .map(|g| g.map(|a| (a * 10.0).round() / 10.0))
            .collect(),
    );
    let mut plan = PlanSpec {
        bands_nm: Some(BANDS_NM.to_vec()),
        reciprocity: false,
        grid: Some(grid),
        sweeps: sweeps.to_vec(),
        ..PlanSpec::default()
    };
    plan.calibration.dark_every_points = Some(100);
    plan.calibration.reference_every_s = Some(600.0);
    plan.calibration.reference_pose_deg = Some(
        [("light".to_string(), -90.0), ("detector".to_string(), 90.0)]
            .into_iter()
            .collect(),
    );
    let file = CampaignFile::new(name, 12.5, plan)
        .with_description("reliability soak (issue 8)")
        .with_calibration(CalibrationSection::default())
        .with_acquisition(AcquisitionSection {
            averaging: Some(10),
            range: Some(toml::Value::String("auto".into())),
            retries: Some(2),
            ..AcquisitionSection::default()
        })
        .with_material_preset("coloured-plastic");
    format!(
        "# Generated by gonio-soak (crates/soak/src/setup.rs): random geometries, two bands each.\n{}",
        file.to_toml()
            .expect("a campaign of numbers and names serialises")
    )
}

/// Random geometries: incidence up to 60 degrees, exitance up to 70, any azimuth of the detector.
fn geometries(seed: u64, n: usize) -> Vec<[f64; 4]> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..n)
        .map(|_| {
            let ti: f64 = rng.random_range(0.0..60.0);
            let to: f64 = rng.random_range(0.0..70.0);
            let po: f64 = rng.random_range(0.0..360.0);
            // Rounded as the text writes them, so that the text and this list agree.
            [
                (ti * 10.0).round() / 10.0,
                0.0,
                (to * 10.0).round() / 10.0,
                (po * 10.0).round() / 10.0,
            ]
        })
        .collect()
}

/// A campaign of exactly `points` points when reachable (the bands come in pairs: else the largest total
/// below), on `instrument`.
pub fn build_campaign(
    name: &str,
    points: u64,
    seed: u64,
    instrument: &InstrumentFile,
) -> Result<SoakCampaign, SoakError> {
    build_campaign_with_sweeps(name, points, seed, instrument, &[])
}

/// [`build_campaign`], with `sweeps` after the points.
pub fn build_campaign_with_sweeps(
    name: &str,
    points: u64,
    seed: u64,
    instrument: &InstrumentFile,
    sweeps: &[SweepSpec],
) -> Result<SoakCampaign, SoakError> {
    let per_geometry = BANDS_NM.len() as u64;
    let count = |n: usize| -> Result<(u64, f64, String), SoakError> {
        let text = campaign_text(name, &geometries(seed, n), sweeps);
        let p = prepare_campaign(&text, &format!("{name}.toml"), Path::new("."), instrument)?;
        Ok((p.total_points, p.predicted_s, text))
    };
    let want = points.max(per_geometry);
    // Bisection on the number of geometries: the total never decreases when a geometry is added.
    let mut lo = usize::try_from(want / per_geometry).unwrap_or(usize::MAX).max(1);
    let mut hi = lo;
    while count(hi)?.0 < want {
        lo = hi;
        hi = hi.saturating_mul(2);
        if hi > 1_000_000 {
            return Err(SoakError::Setup(format!(
                "cannot plan {want} points: the scheduler skips too many random geometries"
            )));
        }
    }
    while hi - lo > 1 {
        let mid = lo + (hi - lo) / 2;
        if count(mid)?.0 >= want {
            hi = mid;
        } else {
            lo = mid;
        }
    }
    let (lo_total, lo_s, lo_text) = count(lo)?;
    let (hi_total, hi_s, hi_text) = count(hi)?;
    let (total_points, predicted_s, text) = if hi_total == want || lo_total > want {
        (hi_total, hi_s, hi_text)
    } else {
        (lo_total, lo_s, lo_text)
    };
    let sweep_segments =
        prepare_campaign(&text, &format!("{name}.toml"), Path::new("."), instrument)?.sweep_segments;
    Ok(SoakCampaign {
        name: name.to_string(),
        text,
        total_points,
        sweep_segments,
        predicted_s,
    })
}

/// The instrument `base` with `faults` written into its `[simulator.faults]` table, everything else as in the
/// file (its `[simulator.quirks]`: the recorded real-device variants; its imperfections): (the parsed file, its
/// text).
pub fn instrument_with_faults(
    base: &SoakInstrument,
    faults: &Faults,
) -> Result<(InstrumentFile, String), SoakError> {
    let header = "[simulator.faults]";
    let src = base.text.as_str();
    let Some(at) = src.find(header) else {
        return Err(SoakError::Setup(format!(
            "{} has no [simulator.faults] table",
            base.name
        )));
    };
    let body = at + header.len();
    // The faults table ends where the next table starts (or with the file).
    let end = src[body..].find("\n[").map_or(src.len(), |i| body + i + 1);
    let mut text = src[..body].to_string();
    text.push_str("\n# Written by gonio-soak (crates/soak/src/setup.rs).\n");
    text.push_str(&faults_toml(faults));
    text.push('\n');
    text.push_str(&src[end..]);
    let file =
        InstrumentFile::parse(&text, "<soak instrument>").map_err(|e| SoakError::Setup(e.to_string()))?;
    if file.simulator.faults != *faults {
        return Err(SoakError::Setup(format!(
            "the fault settings did not survive the instrument file: {:?} became {:?}",
            faults, file.simulator.faults
        )));
    }
    let original = base.file()?;
    if file.simulator.quirks != original.simulator.quirks
        || file.simulator.imperfections != original.simulator.imperfections
    {
        return Err(SoakError::Setup(format!(
            "{}'s quirks or imperfections did not survive: {:?}",
            base.name, file.simulator.quirks
        )));
    }
    Ok((file, text))
}

/// The recorded real-device variants the soaks run under, each the one that demands the most of a host: the
/// same as config/instruments/realistic.toml's `[simulator.quirks]` (a unit test holds them equal), where each
/// is justified by the report it comes from.
pub fn recorded_quirks() -> Quirks {
    Quirks {
        smc100_min_command_gap_ms: 60.0,
        smc100_drop_first_ts: true,
        fw102c_noise_at_open: true,
        ..Quirks::default()
    }
}

/// `text` (an instrument file) with its `[simulator.quirks]` table's body replaced by `quirks`; the table is
/// appended when the file has none.
fn with_quirks_table(text: &str, quirks: &Quirks) -> String {
    let header = "[simulator.quirks]";
    let body = format!(
        "\n# Written by gonio-soak (crates/soak/src/setup.rs): the recorded real-device variants.\n{}",
        quirks_toml(quirks)
    );
    match text.find(header) {
        Some(at) => {
            let start = at + header.len();
            // The table ends where the next one starts (or with the file).
            let end = text[start..].find("\n[").map_or(text.len(), |i| start + i + 1);
            let tail = &text[end..];
            let sep = if tail.is_empty() { "" } else { "\n" };
            format!("{}{body}{sep}{tail}", &text[..start])
        }
        None => format!("{text}\n{header}{body}"),
    }
}

/// The `[simulator.quirks]` table in force, one `key = value` line each, as TOML writes them.
pub fn quirks_toml(q: &Quirks) -> String {
    let value = toml::Value::try_from(q).map_err(|e| e.to_string());
    match value {
        Ok(toml::Value::Table(t)) => t.iter().map(|(k, v)| format!("{k} = {v}\n")).collect(),
        other => format!("# unprintable: {other:?}\n"),
    }
}

/// The keys of a `[simulator.faults]` table (only those that differ from the default).
pub fn faults_toml(f: &Faults) -> String {
    let mut out = String::new();
    let mut num = |key: &str, v: f64, unit: &str| {
        if v != 0.0 {
            out.push_str(&format!("{key} = {}{unit}\n", fmt_f64(v)));
        }
    };
    num("garble_rate", f.garble_rate, "");
    num("drop_rate", f.drop_rate, "");
    num("delay_ms", f.delay_ms, "");
    num("delay_jitter_ms", f.delay_jitter_ms, "");
    num("stall_rate", f.stall_rate, "");
    for (key, v) in [
        ("disconnect_after_s", f.disconnect_after_s),
        ("reconnect_after_s", f.reconnect_after_s),
        ("disconnect_every_s", f.disconnect_every_s),
    ] {
        if let Some(v) = v {
            out.push_str(&format!("{key} = {}\n", fmt_f64(v)));
        }
    }
    if f.saturate {
        out.push_str("saturate = true\n");
    }
    if f.seed != 0 {
        out.push_str(&format!("seed = {}\n", f.seed));
    }
    out
}

/// A float as TOML writes it (always with a decimal point or exponent).
fn fmt_f64(v: f64) -> String {
    let s = format!("{v:?}");
    if s.contains(['.', 'e', 'E']) || !v.is_finite() {
        s
    } else {
        format!("{s}.0")
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn faults_round_trip_through_the_instrument_text() {
        let f = Faults {
            seed: 9,
            garble_rate: 0.01,
            drop_rate: 0.005,
            delay_ms: 1.0,
            delay_jitter_ms: 20.0,
            stall_rate: 1.0 / 900.0,
            disconnect_after_s: Some(120.0),
            reconnect_after_s: Some(4.0),
            disconnect_every_s: Some(240.0),
            saturate: false,
        };
        let (file, text) = instrument_with_faults(&SoakInstrument::simulated(), &f).expect("valid");
        assert_eq!(file.simulator.faults, f);
        assert!(text.contains("garble_rate = 0.01\n"), "{text}");
        assert!(text.starts_with("# The simulated gonioreflectometer"));
        // The realistic instrument keeps its imperfections (and its hidden values' seed) beside the faults.
        let realistic = SoakInstrument::realistic();
        let (file, text) = instrument_with_faults(&realistic, &f).expect("valid");
        assert_eq!(file.simulator.faults, f);
        assert!(realistic.is_imperfect() && !SoakInstrument::simulated().is_imperfect());
        assert_eq!(
            file.simulator.imperfections,
            realistic.file().expect("valid").simulator.imperfections
        );
        assert!(text.contains("[simulator.imperfections.detector]"), "{text}");
    }

    /// Every soak runs under the recorded variants: realistic.toml's own, and the same written into the ideal
    /// file, whose other settings stay as they are.
    #[test]
    fn both_soak_instruments_run_under_the_recorded_variants() {
        let realistic = SoakInstrument::realistic().file().expect("valid");
        assert_eq!(realistic.simulator.quirks, recorded_quirks());
        let ideal = SoakInstrument::simulated().file().expect("valid");
        assert_eq!(ideal.simulator.quirks, recorded_quirks());
        assert_ne!(InstrumentFile::simulated().simulator.quirks, recorded_quirks());
        let mut expected = InstrumentFile::simulated();
        expected.simulator.quirks = recorded_quirks();
        assert_eq!(ideal, expected);
        // A file without the table gets it appended; the table's body is replaced wherever it stands.
        let text = with_quirks_table("[simulator]\nseed = 1\n", &recorded_quirks());
        assert!(
            text.contains("[simulator.quirks]\n# Written by gonio-soak"),
            "{text}"
        );
        let text = with_quirks_table(
            "[a]\n[simulator.quirks]\nsmc100_drop_first_ts = false\n\n[b]\nx = 1\n",
            &recorded_quirks(),
        );
        assert!(
            !text.contains("smc100_drop_first_ts = false") && text.ends_with("\n[b]\nx = 1\n"),
            "{text}"
        );
    }

    #[test]
    fn a_campaign_has_exactly_the_points_asked_for() {
        let file = InstrumentFile::simulated();
        let c = build_campaign("exact", 40, 3, &file).expect("campaign");
        assert_eq!(c.total_points, 40);
        let p = prepare_campaign(&c.text, "exact.toml", Path::new("."), &file).expect("valid");
        assert_eq!(p.total_points, 40);
        assert!(c.predicted_s > 0.0);
    }
}
