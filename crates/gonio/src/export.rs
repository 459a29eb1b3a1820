//! `gonio export RUN --format csv|json|merl|zemax|astm|rgl [--out FILE]`: a run for other tools.
//!
//! RUN is a run directory (`gonio run --out DIR` writes DIR/points.csv and DIR/run.json) or a points CSV; or,
//! instead of RUN, `--data DIR --campaign ID` reads a campaign from a daemon's store (read only). This module
//! also holds that shared loading ([`RunSource`]) for `gonio fit` and `gonio plot`.
//!
//! A run's sweep readings (`[[plan.sweeps]]`: its sweeps.csv, or the store's) are exported as points after the
//! run's own in csv, json and astm unless `--points-only` (merl, zemax and rgl build their grids from the plan's
//! angles and leave them out, saying so); `gonio fit` fits them likewise.
//!
//! csv, json and astm go to stdout unless `--out` names a file; merl needs `--out` (a binary file) and writes a
//! material file beside it (`<stem>.material.toml`, `model = "measured"`) that `gonio brdf eval --material`
//! and the simulator's `[material]` read; zemax needs `--out` and writes one file per band; rgl needs `--out`. Every format carries
//! the run's provenance ([`gonio_results::provenance_summary`]), with the instrument and calibration facts
//! read here from the run's stored instrument and campaign texts ([`export_setup`]).

use std::path::{Path, PathBuf};

use gonio_campaign::{self as campaign, Method, Range, Sources};
use gonio_engine::align::file::{CalibrationFile, CalibrationFileError};
use gonio_engine::store::{CampaignRecord, STORE_FILE, Store};
use gonio_instrument::InstrumentFile;
use gonio_results::export::{self, ExportContext};
use gonio_results::provenance_summary::{ExportSetup, provenance_lines};
use gonio_results::run::Run;
use gonio_results::sweeps::SweepReading;
use gonio_results::{astm, merl_export, rgl, zemax};
use serde_json::{Value, json};

use crate::CliError;

/// Where a run comes from: a run directory (or points CSV), or a daemon's store.
#[derive(Debug, clap::Args)]
pub struct RunSource {
    /// A run directory (points.csv and run.json, as written by `gonio run --out DIR`) or a points CSV file.
    #[arg(required_unless_present = "data", conflicts_with = "data")]
    pub run: Option<PathBuf>,
    /// Read the run from a daemon's store instead: its data directory (`gonio daemon --data DIR`); read only.
    #[arg(long, requires = "campaign")]
    pub data: Option<PathBuf>,
    /// With --data: the campaign, by id (a number) or by name (the latest campaign of that name).
    #[arg(long, requires = "data")]
    pub campaign: Option<String>,
}

impl RunSource {
    /// Loads the run.
    pub fn load(&self) -> Result<Run, CliError> {
        match (&self.run, &self.data, &self.campaign) {
            (Some(path), _, _) => Run::load(path).map_err(|e| CliError::input(e.to_string())),
            (None, Some(dir), Some(campaign)) => load_from_store(dir, campaign),
            _ => Err(CliError::input(
                "give a run directory (RUN), or --data DIR --campaign ID to read from a daemon's store",
            )),
        }
    }

    /// Loads the run with its sweep readings joined to its points (gonio_results::sweeps::with_readings): the
    /// `sweeps.csv` beside the points CSV, or the store's; `points_only` leaves them out. Also returns how many
    /// readings joined.
    pub fn load_with_sweeps(&self, points_only: bool) -> Result<(Run, usize), CliError> {
        let run = self.load()?;
        if points_only {
            return Ok((run, 0));
        }
        let readings = self.sweep_readings()?;
        let n = readings.len();
        Ok((gonio_results::sweeps::with_readings(run, &readings), n))
    }

    /// The run's sweep readings: the `sweeps.csv` beside the points CSV, or the store's; none without.
    pub fn sweep_readings(&self) -> Result<Vec<SweepReading>, CliError> {
        Ok(match (&self.run, &self.data, &self.campaign) {
            (Some(path), _, _) => {
                let dir = if path.is_dir() {
                    path.clone()
                } else {
                    path.parent().map(Path::to_path_buf).unwrap_or_default()
                };
                let csv = dir.join("sweeps.csv");
                if csv.is_file() {
                    let text = std::fs::read_to_string(&csv)
                        .map_err(|e| CliError::io(format!("cannot read {}", csv.display()), e))?;
                    gonio_results::sweeps::parse_sweeps_csv(&text, &csv.display().to_string())
                        .map_err(|e| CliError::input(e.to_string()))?
                } else {
                    Vec::new()
                }
            }
            (None, Some(dir), Some(campaign)) => {
                let origin = dir.join(STORE_FILE).display().to_string();
                let store = Store::open(dir).map_err(|e| store_err(&origin, e))?;
                let record = find_campaign(&store, &origin, campaign)?;
                gonio_engine::export::sweep_readings(&store, record.id).map_err(|e| store_err(&origin, e))?
            }
            _ => Vec::new(),
        })
    }

    /// A directory to write derived files into by default: the run directory (or the CSV's), else the current
    /// directory (never the daemon's data directory).
    pub fn default_dir(&self) -> PathBuf {
        match &self.run {
            Some(p) if p.is_dir() => p.clone(),
            Some(p) => p.parent().map(Path::to_path_buf).unwrap_or_default(),
            None => PathBuf::from("."),
        }
    }
}

/// The software that exports.
pub fn exported_by() -> String {
    gonio_engine::software_version()
}

fn store_err(origin: &str, e: impl std::fmt::Display) -> CliError {
    CliError::input(format!("{origin}: {e}"))
}

/// A campaign of a daemon's store as a run: the same points and provenance as `gonio run` writes (both come
/// from `gonio_engine::export::run_record`).
fn load_from_store(dir: &Path, campaign: &str) -> Result<Run, CliError> {
    let db = dir.join(STORE_FILE);
    if !db.is_file() {
        return Err(CliError::input(format!(
            "{}: no daemon store here (expected {}; `gonio daemon --data DIR` creates it)",
            dir.display(),
            db.display()
        )));
    }
    let origin = db.display().to_string();
    let store = Store::open(dir).map_err(|e| store_err(&origin, e))?;
    let record = find_campaign(&store, &origin, campaign)?;
    gonio_engine::export::run_of(&store, &record, &origin).map_err(|e| store_err(&origin, e))
}

/// A campaign of a store by id (a number) or by name (the latest of that name).
fn find_campaign(store: &Store, origin: &str, campaign: &str) -> Result<CampaignRecord, CliError> {
    let campaigns = store.campaigns().map_err(|e| store_err(origin, e))?;
    match campaign.trim().parse::<i64>() {
        Ok(id) => campaigns.into_iter().find(|c| c.id.0 == id),
        Err(_) => campaigns.into_iter().rfind(|c| c.name == campaign.trim()),
    }
    .ok_or_else(|| {
        CliError::input(format!(
            "{origin}: no campaign {campaign:?} (give its id or its name; `gonio ctl status` lists them)"
        ))
    })
}

/// How the materials a stored campaign text names resolve: a text stored by gonio carries them (a `[resolved]`
/// table); an older one names them and they resolve against the run's directory.
fn sources_for(campaign_toml: &str, base_dir: &Path) -> Sources {
    if campaign_toml
        .lines()
        .any(|l| l.trim_start().starts_with("[resolved"))
    {
        Sources::Stored
    } else {
        Sources::Local(base_dir.to_path_buf())
    }
}

/// The facts of the run's instrument and campaign files every export's provenance and the ASTM header need;
/// `None` without provenance or when the stored texts no longer parse (the exports then say "unknown").
pub fn export_setup(run: &Run, base_dir: &Path) -> Option<ExportSetup> {
    let config = run.config()?;
    let file = InstrumentFile::parse(&config.instrument_toml, "<run's instrument file>").ok()?;
    let sources = sources_for(&config.campaign_toml, base_dir);
    let campaign = campaign::load(&config.campaign_toml, "<run's campaign file>", &sources, &file).ok()?;
    let instrument = &file.instrument;
    let bandwidths_nm = instrument
        .filter_wheel
        .iter()
        .flat_map(|w| w.positions.iter())
        .filter_map(|p| p.band_nm.map(|b| (b, p.bandwidth_nm)))
        .chain(instrument.source.wavelength_nm.map(|b| (b, None)))
        .collect();
    // The alignment the run applied, read once for what the provenance and the ASTM header say of it.
    let calibration = config
        .alignment_toml
        .as_deref()
        .map(|text| CalibrationFile::parse(text, "<run's calibration>"));
    let method = &campaign.calibration;
    Some(ExportSetup {
        instrument_name: instrument.name.clone(),
        detector_aperture_radius_mm: instrument.detector.aperture_radius_mm,
        detector_distance_mm: instrument.detector.distance_mm,
        bandwidths_nm,
        calibration_method: match method.method {
            Method::Absolute => "absolute".into(),
            Method::Relative => "relative".into(),
        },
        calibration_reference: method.reference.as_ref().map(|r| r.name.clone()),
        // The instrument description has no polariser on either arm.
        polarisation: "unpolarised".into(),
        signature: calibration
            .as_ref()
            .and_then(|c| c.as_ref().ok())
            .and_then(signature_words),
        alignment: calibration.as_ref().map(alignment_words),
    })
}

/// What every export's provenance says of the alignment the run applied (read from the run record): the
/// calibration file's date and what it corrected.
fn alignment_words(calibration: &Result<CalibrationFile, CalibrationFileError>) -> String {
    let Ok(cal) = calibration else {
        return "applied (its file is in the run record, but no longer parses)".into();
    };
    let mut corrected =
        vec!["every pose (the fitted zeros, tilt, eccentricity and encoder terms)".to_string()];
    if cal.detector.is_some() {
        corrected.push(
            "every reading (each range's gain, nonlinearity and offset; the instrument signature subtracted)"
                .into(),
        );
    }
    format!(
        "gonio align calibration of {} ({}{}): corrected {}",
        cal.calibration.created_utc,
        cal.calibration.instrument,
        if cal.calibration.dry_run {
            ", simulated"
        } else {
            ""
        },
        corrected.join("; ")
    )
}

/// What the ASTM header says of the instrument signature: the characterisation the run applied measured it
/// (`gonio align`, the holder empty) and every value had it subtracted; `None` (the export's "not measured")
/// when no calibration with a signature was applied.
fn signature_words(cal: &CalibrationFile) -> Option<String> {
    let signature = &cal.detector.as_ref()?.signature;
    if signature.is_empty() {
        return None;
    }
    let bands: Vec<String> = signature.iter().map(|b| format!("{}", b.band_nm)).collect();
    let (lowest, highest) = signature
        .iter()
        .flat_map(|b| b.brdf_sr.iter().copied())
        .filter(|v| v.is_finite())
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(lo, hi), v| {
            (lo.min(v), hi.max(v))
        });
    Some(format!(
        "measured by gonio align on {} with the sample holder empty, in the bands {} nm ({:.2e} to {:.2e} 1/sr \
         over the arm angles measured), and subtracted from every value; its uncertainty is each point's \
         stray-light component",
        cal.calibration.created_utc,
        bands.join(", "),
        lowest,
        highest
    ))
}

/// The run's configuration as the campaign parser resolves it (defaults applied, presets expanded into model
/// parameters), from the texts stored in its provenance. `None` without provenance; an `error` entry when the
/// stored texts no longer parse (e.g. a material file named relative to a campaign file that moved).
pub fn resolved_config(run: &Run, base_dir: &Path) -> Option<Value> {
    let config = run.config()?;
    let (campaign_toml, instrument_toml) = (config.campaign_toml.as_str(), config.instrument_toml.as_str());
    let file = match InstrumentFile::parse(instrument_toml, "<run's instrument file>") {
        Ok(f) => f,
        Err(e) => return Some(json!({ "error": e.to_string() })),
    };
    let sources = sources_for(campaign_toml, base_dir);
    // Parsed, not prepared: the plan's size and the time model's prediction are the run record's, computed once
    // when the run was recorded, not planned and ordered again here.
    let c = match campaign::load(campaign_toml, "<run's campaign file>", &sources, &file) {
        Ok(c) => c,
        Err(e) => return Some(json!({ "error": e.to_string() })),
    };
    let record = run.provenance.as_ref()?;
    let spec = |m: &gonio_brdf::Material| serde_json::to_value(m.spec()).unwrap_or(Value::Null);
    Some(json!({
        "campaign_id": c.id,
        "description": c.description,
        "instrument": file.instrument.name,
        "sample_radius_mm": c.sample_radius_mm,
        "dry_run": c.dry_run,
        "total_points": record.campaign.total_points,
        "predicted_instrument_s": record.timing.predicted_instrument_s,
        "material": c.material.as_ref().map(spec),
        "calibration": {
            "method": match c.calibration.method { Method::Absolute => "absolute", Method::Relative => "relative" },
            "reference": c.calibration.reference.as_ref().map(|r| json!({"name": r.name, "material": spec(&r.material)})),
            "reference_rel_std": c.calibration.reference_rel_std,
            "simulate_operator": c.calibration.simulate_operator,
        },
        "acquisition": {
            "averaging": c.acquisition.averaging,
            "range": match c.acquisition.range { Range::Auto => json!("auto"), Range::FixedW(w) => json!({"full_scale_w": w}) },
            "extra_settle_s": c.acquisition.extra_settle_s,
            "retries": c.acquisition.retries,
        },
    }))
}

#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum Format {
    /// The points with units and provenance as `#` comment lines.
    Csv,
    /// One JSON object: units, conventions, provenance, resolved configuration, points.
    Json,
    /// MERL binary (isotropic, resampled onto the MERL grid), plus a material file beside it.
    Merl,
    /// BSDF Data Interchange text (Zemax OpticStudio, LightTools): one file per band, about the specular direction.
    Zemax,
    /// A BRDF table after ASTM E1392 / E2387: every measurement with geometry, band, polarisation, uncertainty.
    Astm,
    /// RGL material (`.bsdf` tensor file) for Mitsuba 3's and pbrt-v4's `measured` BSDF, every band.
    Rgl,
}

impl Format {
    /// The name `--format` takes.
    pub fn name(self) -> &'static str {
        match self {
            Format::Csv => "csv",
            Format::Json => "json",
            Format::Merl => "merl",
            Format::Zemax => "zemax",
            Format::Astm => "astm",
            Format::Rgl => "rgl",
        }
    }
}

#[derive(Debug, clap::Args)]
pub struct ExportArgs {
    #[command(flatten)]
    pub source: RunSource,
    /// Output format.
    #[arg(long, value_enum)]
    pub format: Format,
    /// Output file (csv, json and astm: default stdout; merl and zemax: required; zemax writes
    /// `<stem>-<band>nm.<ext>` per band when the run has several and no --wavelength is given).
    #[arg(long)]
    pub out: Option<PathBuf>,
    /// zemax: export only this band (nm).
    #[arg(long)]
    pub wavelength: Option<f64>,
    /// merl: the measured bands (nm) for the red, green and blue channels, e.g. `--channels 650,550,450`
    /// (default: the bands nearest to 650, 550 and 450 nm).
    #[arg(long, value_delimiter = ',', num_args = 1)]
    pub channels: Option<Vec<f64>>,
    /// Leave the run's sweep readings out (by default csv, json and astm export them as points after the run's
    /// own, their geometry the middle of the arc each covered; sweeps.csv keeps their arcs).
    #[arg(long)]
    pub points_only: bool,
}

pub fn run(args: ExportArgs) -> Result<(), CliError> {
    let (mut run, readings) = args.source.load_with_sweeps(args.points_only)?;
    if readings > 0 {
        let own = run.points.len() - readings;
        if matches!(args.format, Format::Csv | Format::Json | Format::Astm) {
            eprintln!(
                "gonio: {readings} sweep readings exported as points after the run's {own} (--points-only leaves \
                 them out)"
            );
        } else {
            // The gridded formats build their grids from the plan's angles: a hundred thousand readings, each
            // at its own angle, are not a grid.
            run.points.truncate(own);
            eprintln!(
                "gonio: the run's {readings} sweep readings are not in {} exports (their grids come from the plan's \
                 angles); --format csv, json or astm carry them",
                args.format.name()
            );
        }
    }
    let base_dir = args.source.default_dir();
    let setup = export_setup(&run, &base_dir);
    match args.format {
        Format::Csv | Format::Json => {
            let ctx = ExportContext {
                exported_by: exported_by(),
                resolved: resolved_config(&run, &base_dir),
                setup,
            };
            let text = if args.format == Format::Csv {
                export::to_csv(&run, &ctx)
            } else {
                let mut t = serde_json::to_string_pretty(&export::to_json(&run, &ctx))
                    .map_err(|e| CliError::input(format!("cannot encode the JSON export: {e}")))?;
                t.push('\n');
                t
            };
            write_text(args.out.as_deref(), &text)
        }
        Format::Astm => write_text(
            args.out.as_deref(),
            &astm::write(&run, &exported_by(), setup.as_ref()),
        ),
        Format::Merl => export_merl(&run, &args, setup),
        Format::Zemax => export_zemax(&run, &args, setup.as_ref()),
        Format::Rgl => export_rgl(&run, &args, setup.as_ref()),
    }
}

fn export_rgl(run: &Run, args: &ExportArgs, setup: Option<&ExportSetup>) -> Result<(), CliError> {
    let Some(out) = &args.out else {
        return Err(CliError::input(
            "--format rgl writes a binary file: give it with --out FILE (e.g. --out sample.bsdf)",
        ));
    };
    let exported = rgl::to_rgl(run).map_err(|e| CliError::input(e.to_string()))?;
    let provenance = provenance_lines(run, &exported_by(), setup);
    let bytes = exported.to_bytes(&rgl::description(&exported, run, &provenance));
    std::fs::write(out, bytes).map_err(|e| CliError::io(format!("cannot write {}", out.display()), e))?;
    eprintln!(
        "gonio: {} incidences x {} band(s) on a {n} x {n} half-vector grid; {:.1}% of the nodes measured, {:.1}% \
         the guard band beside them (the nearest measured value), the rest 0",
        exported.theta_i.len(),
        exported.bands_nm.len(),
        100.0 * exported.covered,
        100.0 * exported.guard,
        n = rgl::RESOLUTION
    );
    println!("{}", out.display());
    Ok(())
}

/// Writes a text export to `out`, or to stdout without it.
fn write_text(out: Option<&Path>, text: &str) -> Result<(), CliError> {
    match out {
        Some(path) => std::fs::write(path, text)
            .map_err(|e| CliError::io(format!("cannot write {}", path.display()), e)),
        None => {
            use std::io::Write;
            std::io::stdout()
                .write_all(text.as_bytes())
                .map_err(|e| CliError::io("writing to stdout", e))
        }
    }
}

/// `<stem>-<band>nm.<ext>` beside `out` (the extension `bsdf` when `out` has none).
fn per_band_path(out: &Path, band_nm: f64) -> PathBuf {
    let stem = out
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "export".into());
    let ext = out
        .extension()
        .map(|e| e.to_string_lossy().into_owned())
        .unwrap_or_else(|| "bsdf".into());
    out.with_file_name(format!("{stem}-{band_nm}nm.{ext}"))
}

fn export_zemax(run: &Run, args: &ExportArgs, setup: Option<&ExportSetup>) -> Result<(), CliError> {
    let Some(out) = &args.out else {
        return Err(CliError::input(
            "--format zemax writes one file per band: give it with --out FILE (e.g. --out sample.bsdf)",
        ));
    };
    let bands = match args.wavelength {
        Some(nm) => vec![run.band(nm).map_err(|e| CliError::input(e.to_string()))?],
        None => run.bands_nm(),
    };
    if bands.is_empty() {
        return Err(CliError::input(format!(
            "{}: no valid points to export",
            run.origin
        )));
    }
    for &band in &bands {
        let exported = zemax::to_zemax(run, band).map_err(|e| CliError::input(e.to_string()))?;
        let path = if bands.len() == 1 {
            out.clone()
        } else {
            per_band_path(out, band)
        };
        write_text(Some(&path), &zemax::write(&exported, run, &exported_by(), setup))?;
        for b in &exported.blocks {
            eprintln!(
                "gonio: {band} nm, incidence {:.4} deg: TIS {:.5} (+- {:.1e}), covered {:.1}% of the projected \
                 solid angle, the rest written as 0",
                b.theta_i_deg,
                b.integrals.reflectance.value,
                b.integrals.reflectance.error,
                100.0 * b.integrals.covered_projected_sr.value / std::f64::consts::PI
            );
        }
        println!("{}", path.display());
    }
    Ok(())
}

fn export_merl(run: &Run, args: &ExportArgs, setup: Option<ExportSetup>) -> Result<(), CliError> {
    let Some(out) = &args.out else {
        return Err(CliError::input(
            "--format merl writes a binary file: give it with --out FILE (e.g. --out sample.binary)",
        ));
    };
    let channels = match &args.channels {
        None => None,
        Some(v) => match v.as_slice() {
            [r, g, b] => Some([*r, *g, *b]),
            _ => {
                return Err(CliError::input(format!(
                    "--channels takes three bands in nm (red,green,blue), got {}",
                    v.len()
                )));
            }
        },
    };
    let exported = merl_export::to_merl(run, channels).map_err(|e| CliError::input(e.to_string()))?;
    exported
        .data
        .write(out)
        .map_err(|e| CliError::input(e.to_string()))?;
    let stem = out
        .file_stem()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_else(|| "export".into());
    let material_path = out.with_file_name(format!("{stem}.material.toml"));
    let file_name = out
        .file_name()
        .map(|s| s.to_string_lossy().into_owned())
        .unwrap_or_default();
    // The companion material reads the channel whose band is nearest the middle of the visible.
    let channel = exported
        .channels
        .iter()
        .min_by(|a, b| (a.band_nm - 550.0).abs().total_cmp(&(b.band_nm - 550.0).abs()))
        .map(|c| c.channel)
        .unwrap_or(gonio_brdf::merl::MerlChannel::Green);
    let provenance = provenance_lines(run, &exported_by(), setup.as_ref());
    let toml = merl_export::material_toml(&exported, run, &file_name, channel, &provenance);
    std::fs::write(&material_path, toml)
        .map_err(|e| CliError::io(format!("cannot write {}", material_path.display()), e))?;
    for (i, c) in exported.channels.iter().enumerate() {
        eprintln!(
            "gonio: {} channel = {} nm: {} of {} cells above the horizon covered ({:.1}%), the rest marked -1",
            c.channel.name(),
            c.band_nm,
            c.covered_cells,
            exported.cells_above_horizon,
            100.0 * exported.coverage(i)
        );
        if exported.azimuth_nodes[i] < 3 {
            eprintln!(
                "gonio: note: {} nm has {} measured azimuth difference(s): the table interpolates linearly between them",
                c.band_nm, exported.azimuth_nodes[i]
            );
        }
    }
    println!("{}", out.display());
    println!("{}", material_path.display());
    Ok(())
}
