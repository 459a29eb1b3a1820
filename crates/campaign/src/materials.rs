//! The campaign's materials: the simulated sample (`[material]`) and the relative method's reference sample
//! (`[calibration] reference`), resolved under the campaign's [`Sources`], and the checks that the reference can
//! normalise every band where it is read.

use std::path::Path;

use gonio_brdf::material::Material;
use gonio_brdf::{Brdf, Wavelength};
use gonio_scheduler::constraints::Constraints;
use gonio_scheduler::kinematics::{Geometry, Kinematics, Pose};

use crate::error::{CampaignError, Located};
use crate::sources::{self, Sources, is_preset};

/// The relative method's reference sample.
#[derive(Debug, Clone)]
pub struct Reference {
    /// As written in the campaign (`[calibration] reference`): a preset name or a file name.
    pub name: String,
    /// Its BRDF, angular shape included.
    pub material: Material,
    /// Where it is read: a geometry every band's reading of the reference is taken at.
    pub geometry: Geometry,
}

/// The default reference geometry of the relative method: normal incidence, detector at 45 degrees (0/45).
pub const DEFAULT_REFERENCE_GEOMETRY_DEG: [f64; 4] = [0.0, 0.0, 45.0, 180.0];

/// The `[material]` table (the simulated sample), with its names resolved under `sources`.
pub(crate) fn sample_material(
    raw: &toml::Table,
    at: &Located,
    sources: &Sources,
    base: &Path,
) -> Result<Option<Material>, CampaignError> {
    match raw.get("material") {
        None => Ok(None),
        Some(toml::Value::Table(t)) if t.contains_key("preset") => {
            if t.len() != 1 {
                return Err(at.err(
                    "material",
                    "preset",
                    "expected `preset` alone (a preset is a complete material)",
                ));
            }
            let name = t.get("preset").and_then(|v| v.as_str()).unwrap_or_default();
            Ok(Some(
                Material::preset(name).map_err(|e| at.err("material", "preset", e))?,
            ))
        }
        Some(t) => {
            // A measured material reads its data file: check the name against the policy first.
            if let Some(f) = t.get("file").and_then(|v| v.as_str()) {
                sources::file_path(sources, base, f).map_err(|e| at.err("material", "file", e))?;
            }
            Ok(Some(
                Material::from_document(at.text, at.origin, base)
                    .map_err(|e| CampaignError(e.to_string()))?,
            ))
        }
    }
}

/// `[calibration] reference`: a preset name or a material file (whose own data file, for a measured material,
/// resolves against its directory), under `sources`.
pub(crate) fn reference_material(name: &str, sources: &Sources, base: &Path) -> Result<Material, String> {
    let is_file = match sources {
        // Nothing outside the data directory may be probed: a name is a preset, or a path to confine.
        Sources::Confined(_) => !is_preset(name),
        _ => name.ends_with(".toml") || base.join(name).is_file(),
    };
    if !is_file {
        return Material::preset(name).map_err(|e| e.to_string());
    }
    let path = sources::file_path(sources, base, name).map_err(|e| {
        if name.ends_with(".toml") || name.contains(['/', '\\']) {
            e
        } else {
            format!(
                "{e} (nor is it a preset: {})",
                Material::preset_names().join(", ")
            )
        }
    })?;
    let dir = path.parent().map(Path::to_path_buf).unwrap_or_default();
    let text = std::fs::read_to_string(&path)
        .map_err(|e| format!("cannot read the reference material file {}: {e}", path.display()))?;
    if let Some(f) = sources::material_data_file(&text) {
        sources::file_path(sources, &dir, &f)
            .map_err(|e| format!("{}: [material] file: {e}", path.display()))?;
    }
    Material::from_document(&text, &path.display().to_string(), &dir).map_err(|e| e.to_string())
}

/// `[calibration] reference_geometry_deg = [theta_i, phi_i, theta_o, phi_o]`, default 0/45.
pub(crate) fn reference_geometry(v: Option<&toml::Value>) -> Result<Geometry, String> {
    let Some(v) = v else {
        let [ti, pi, to, po] = DEFAULT_REFERENCE_GEOMETRY_DEG;
        return Ok(Geometry::new(ti, pi, to, po));
    };
    let expected = "expected [theta_i, phi_i, theta_o, phi_o] in degrees";
    let items = v.as_array().ok_or_else(|| format!("{expected}, got {v}"))?;
    let numbers: Vec<f64> = items
        .iter()
        .map(|x| x.as_float().or_else(|| x.as_integer().map(|i| i as f64)))
        .collect::<Option<Vec<f64>>>()
        .filter(|n| n.len() == 4 && n.iter().all(|x| x.is_finite()))
        .ok_or_else(|| format!("{expected}, got {v}"))?;
    match numbers.as_slice() {
        [ti, pi, to, po] => Ok(Geometry::new(*ti, *pi, *to, *po)),
        _ => Err(format!("{expected}, got {v}")),
    }
}

/// The reference can be read where it is asked to be, and normalises every band: the geometry passes the
/// instrument's rules and has an axis solution, the material covers every band, and its BRDF there is positive.
/// Err: (key, message).
pub(crate) fn check_reference(
    r: &Reference,
    bands_nm: &[f64],
    instrument: &gonio_instrument::Instrument,
    sample_radius_mm: f64,
) -> Result<(), (&'static str, String)> {
    let (wi, wo) = r.geometry.directions();
    Constraints::new(instrument, Some(sample_radius_mm))
        .check_directions(&wi, &wo)
        .map_err(|reason| {
            (
                "reference_geometry_deg",
                format!(
                    "the reference cannot be read at {:?} on instrument {:?}: {}",
                    r.geometry,
                    instrument.name,
                    reason.name()
                ),
            )
        })?;
    let poses = Kinematics::new(instrument)
        .solutions(&wi, &wo, &Pose::new(0.0, 0.0, 0.0, 0.0))
        .map_err(|e| ("reference_geometry_deg", format!("no axis solution: {e}")))?;
    if poses.is_empty() {
        return Err(("reference_geometry_deg", "no axis solution".into()));
    }
    for nm in bands_nm {
        let wl = Wavelength::from_nm(*nm).map_err(|e| ("reference", e.to_string()))?;
        let f = r
            .material
            .eval(&wi, &wo, wl)
            .map_err(|e| ("reference", format!("{:?} at {nm} nm: {e}", r.name)))?;
        if !(f.is_finite() && f > 0.0) {
            return Err((
                "reference",
                format!(
                    "{:?} has BRDF {f} 1/sr at the reference geometry at {nm} nm: a reference must reflect \
                     there to normalise",
                    r.name
                ),
            ));
        }
    }
    Ok(())
}
