//! Materials: the `[material]` TOML table, parsed with its line numbers, into one of the concrete models.
//!
//! Schema (all keys of the `[material]` table; wavelength-dependent ones are [`Spectral`]: a number or a table
//! `{ 450 = 0.2, 650 = 0.8 }` in nm):
//!
//! | model         | keys                                                                                  |
//! |---------------|---------------------------------------------------------------------------------------|
//! | `lambertian`  | `albedo` (Spectral, [0, 1])                                                           |
//! | `oren-nayar`  | `albedo` (Spectral, [0, 1]), `sigma_deg` (number, [0, 90])                            |
//! | `phong`       | `diffuse`, `specular` (Spectral, [0, 1], sum <= 1), `exponent` (number, [0, 1e6])      |
//! | `conductor`   | `distribution` (`ggx`/`beckmann`), `masking` (`separable`/`height-correlated`),       |
//! |               | `alpha` or `alpha_x` + `alpha_y` (number, (0, 1]), `eta` (Spectral, (0, 1000]),       |
//! |               | `k` (Spectral, [0, 1000])                                                             |
//! | `plastic`     | `distribution`, `masking`, `alpha` or `alpha_x` + `alpha_y`, `ior` (Spectral, [1, 4]),|
//! |               | `albedo` (Spectral, [0, 1])                                                           |
//! | `mirror`      | `eta` (Spectral, (0, 1000]), `k` (Spectral, [0, 1000])                                |
//! | `measured`    | `file` (path, relative to the TOML file's directory), `format` (`merl` or `rgl`),     |
//! |               | `channel` (`red`/`green`/`blue`; MERL only: an RGL file is spectral)                  |
//!
//! The optical constants `eta` and `k` (the complex refractive index `eta + i k` of a conductor or mirror) are
//! capped at [`crate::models::MAX_OPTICAL_CONSTANT`] = 1000 at every wavelength of the table: real metals in the
//! visible and near infrared stay below about 100, and much larger values would overflow the squares in the
//! Fresnel factor into a NaN reflectance. A value above the cap is refused like any other out-of-range value
//! (the error names the key and the value).
//!
//! Every key listed for the model is required; any other key is an error. Errors name the origin (file path
//! or preset), the line and the key. The same table is embedded in campaign files: [`Material::from_document`]
//! reads the `[material]` table out of a whole document and ignores the other tables.

use std::fmt;
use std::path::{Path, PathBuf};
use std::sync::Arc;

use serde::{Deserialize, Serialize};
use toml::de::{DeTable, DeValue};

use crate::brdf::{Brdf, DeltaLobe, DirectionSample};
use crate::geometry::Direction;
use crate::measured::MeasuredBrdf;
use crate::merl::{MerlChannel, MerlError};
use crate::microfacet::{Distribution, Masking};
use crate::models::{Conductor, Lambertian, Mirror, OrenNayar, ParamError, Phong, Plastic};
use crate::presets;
use crate::rgl::{RglBrdf, RglError};
use crate::spectrum::{Spectral, SpectrumError, Wavelength};

mod build;
mod measured;
mod parse;

use build::build;
pub use measured::{MeasuredMaterial, MeasuredTable};
use parse::{line_of, not_applicable, parse_table};

/// Which model a `[material]` table describes.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum ModelKind {
    Lambertian,
    OrenNayar,
    Phong,
    Conductor,
    Plastic,
    Mirror,
    Measured,
}

const MODEL_NAMES: &[(&str, ModelKind)] = &[
    ("lambertian", ModelKind::Lambertian),
    ("oren-nayar", ModelKind::OrenNayar),
    ("phong", ModelKind::Phong),
    ("conductor", ModelKind::Conductor),
    ("plastic", ModelKind::Plastic),
    ("mirror", ModelKind::Mirror),
    ("measured", ModelKind::Measured),
];

impl ModelKind {
    pub fn name(&self) -> &'static str {
        MODEL_NAMES
            .iter()
            .find(|(_, k)| k == self)
            .map(|(n, _)| *n)
            .unwrap_or("?")
    }

    /// The keys this model takes, besides `model` (alpha_x/alpha_y are alternatives to alpha).
    fn keys(&self) -> &'static [&'static str] {
        match self {
            ModelKind::Lambertian => &["albedo"],
            ModelKind::OrenNayar => &["albedo", "sigma_deg"],
            ModelKind::Phong => &["diffuse", "specular", "exponent"],
            ModelKind::Conductor => &[
                "distribution",
                "masking",
                "alpha",
                "alpha_x",
                "alpha_y",
                "eta",
                "k",
            ],
            ModelKind::Plastic => &[
                "distribution",
                "masking",
                "alpha",
                "alpha_x",
                "alpha_y",
                "ior",
                "albedo",
            ],
            ModelKind::Mirror => &["eta", "k"],
            ModelKind::Measured => &["file", "format", "channel"],
        }
    }
}

/// Storage format of a measured material.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum MeasuredFormat {
    Merl,
    /// The RGL material database's tensor file ([`crate::rgl`]).
    Rgl,
}

/// Every key a `[material]` table may hold.
const ALL_KEYS: &[&str] = &[
    "model",
    "distribution",
    "masking",
    "alpha",
    "alpha_x",
    "alpha_y",
    "eta",
    "k",
    "ior",
    "albedo",
    "sigma_deg",
    "diffuse",
    "specular",
    "exponent",
    "file",
    "format",
    "channel",
];

/// The description of a material: the `[material]` table's content, serialisable (a run stores the resolved
/// description of its sample with it). Only the keys of the model are `Some`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct MaterialSpec {
    pub model: ModelKind,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub distribution: Option<Distribution>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub masking: Option<Masking>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub alpha: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub alpha_x: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub alpha_y: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub eta: Option<Spectral>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub k: Option<Spectral>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ior: Option<Spectral>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub albedo: Option<Spectral>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub sigma_deg: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub diffuse: Option<Spectral>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub specular: Option<Spectral>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub exponent: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub file: Option<PathBuf>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub format: Option<MeasuredFormat>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub channel: Option<MerlChannel>,
}

impl MaterialSpec {
    fn empty(model: ModelKind) -> MaterialSpec {
        MaterialSpec {
            model,
            distribution: None,
            masking: None,
            alpha: None,
            alpha_x: None,
            alpha_y: None,
            eta: None,
            k: None,
            ior: None,
            albedo: None,
            sigma_deg: None,
            diffuse: None,
            specular: None,
            exponent: None,
            file: None,
            format: None,
            channel: None,
        }
    }

    fn has(&self, key: &str) -> bool {
        match key {
            "model" => true,
            "distribution" => self.distribution.is_some(),
            "masking" => self.masking.is_some(),
            "alpha" => self.alpha.is_some(),
            "alpha_x" => self.alpha_x.is_some(),
            "alpha_y" => self.alpha_y.is_some(),
            "eta" => self.eta.is_some(),
            "k" => self.k.is_some(),
            "ior" => self.ior.is_some(),
            "albedo" => self.albedo.is_some(),
            "sigma_deg" => self.sigma_deg.is_some(),
            "diffuse" => self.diffuse.is_some(),
            "specular" => self.specular.is_some(),
            "exponent" => self.exponent.is_some(),
            "file" => self.file.is_some(),
            "format" => self.format.is_some(),
            "channel" => self.channel.is_some(),
            _ => false,
        }
    }

    /// This description as a TOML document with a `[material]` table (readable by [`Material::from_document`]).
    pub fn to_toml(&self) -> String {
        #[derive(Serialize)]
        struct Doc<'a> {
            material: &'a MaterialSpec,
        }
        toml::to_string(&Doc { material: self }).unwrap_or_default()
    }
}

/// Where something was read from: a file or preset name, and a line (1-based) when known.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Location {
    pub origin: String,
    pub line: Option<usize>,
}

impl fmt::Display for Location {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.line {
            Some(line) => write!(f, "{}, line {}", self.origin, line),
            None => write!(f, "{}", self.origin),
        }
    }
}

/// Everything that can be wrong with a material description. Each message is one paragraph saying what and
/// where.
#[derive(Debug, thiserror::Error)]
pub enum MaterialError {
    #[error("cannot read material file {}: {source}", path.display())]
    Read { path: PathBuf, source: std::io::Error },
    #[error("{at}: not valid TOML: {message}")]
    Toml { at: Location, message: String },
    #[error("{at}: there is no [material] table (a material file needs one, with at least a `model` key)")]
    NoTable { at: Location },
    #[error("{at}: [material] key `{key}`: {message}")]
    Value {
        at: Location,
        key: String,
        message: String,
    },
    #[error("{at}: [material] is missing the key `{key}`: {message}")]
    Missing {
        at: Location,
        key: String,
        message: String,
    },
    #[error("unknown material preset `{name}` (and no such file); the presets are: {known}")]
    UnknownPreset { name: String, known: String },
    #[error("{at}: [material] key `file`: cannot load the measured data: {source}")]
    Measured { at: Location, source: MerlError },
    #[error("{at}: [material] key `file`: cannot load the measured data: {source}")]
    Rgl { at: Location, source: RglError },
    #[error("material {model}: {source}")]
    Wavelength { model: String, source: SpectrumError },
}

/// A material: one of the concrete reflectance models (enum dispatch; implements [`Brdf`]).
#[derive(Debug, Clone)]
pub enum Material {
    Lambertian(Lambertian),
    OrenNayar(OrenNayar),
    Phong(Phong),
    Conductor(Conductor),
    Plastic(Plastic),
    Mirror(Mirror),
    Measured(MeasuredMaterial),
}

macro_rules! dispatch {
    ($self:expr, $m:ident => $e:expr) => {
        match $self {
            Material::Lambertian($m) => $e,
            Material::OrenNayar($m) => $e,
            Material::Phong($m) => $e,
            Material::Conductor($m) => $e,
            Material::Plastic($m) => $e,
            Material::Mirror($m) => $e,
            Material::Measured($m) => $e,
        }
    };
}

impl Brdf for Material {
    fn eval(&self, wi: &Direction, wo: &Direction, wavelength: Wavelength) -> Result<f64, SpectrumError> {
        dispatch!(self, m => m.eval(wi, wo, wavelength))
    }
    fn is_isotropic(&self) -> bool {
        dispatch!(self, m => m.is_isotropic())
    }
    fn is_spectrally_flat(&self) -> bool {
        dispatch!(self, m => m.is_spectrally_flat())
    }
    fn delta_lobe(&self, wi: &Direction, wavelength: Wavelength) -> Result<Option<DeltaLobe>, SpectrumError> {
        dispatch!(self, m => m.delta_lobe(wi, wavelength))
    }
    fn has_delta_lobe(&self) -> bool {
        dispatch!(self, m => m.has_delta_lobe())
    }
    fn sample(
        &self,
        wi: &Direction,
        u: [f64; 2],
        wavelength: Wavelength,
    ) -> Result<Option<DirectionSample>, SpectrumError> {
        dispatch!(self, m => m.sample(wi, u, wavelength))
    }
    fn lobe_width(&self) -> Option<f64> {
        dispatch!(self, m => m.lobe_width())
    }
}

impl Material {
    /// Reads a material file (a TOML document with a `[material]` table). A relative `file` (measured data)
    /// resolves against the directory of `path`.
    pub fn load(path: &Path) -> Result<Material, MaterialError> {
        let text = std::fs::read_to_string(path).map_err(|source| MaterialError::Read {
            path: path.to_path_buf(),
            source,
        })?;
        let base_dir = path.parent().map(Path::to_path_buf).unwrap_or_default();
        Material::from_document(&text, &path.display().to_string(), &base_dir)
    }

    /// A built-in material by name (see [`Material::preset_names`]); the presets are data files in
    /// config/materials/, compiled in.
    pub fn preset(name: &str) -> Result<Material, MaterialError> {
        match presets::preset_text(name) {
            Some(text) => Material::from_document(
                text,
                &format!("preset {name} (config/materials/{name}.toml)"),
                Path::new("."),
            ),
            None => Err(MaterialError::UnknownPreset {
                name: name.to_string(),
                known: Material::preset_names().join(", "),
            }),
        }
    }

    /// Names of the built-in presets.
    pub fn preset_names() -> &'static [&'static str] {
        presets::NAMES
    }

    /// A path when `arg` names an existing file or ends in `.toml`, else a preset name.
    pub fn from_file_or_preset(arg: &str) -> Result<Material, MaterialError> {
        let path = Path::new(arg);
        if path.is_file() || arg.ends_with(".toml") {
            Material::load(path)
        } else {
            Material::preset(arg)
        }
    }

    /// Reads the `[material]` table out of a whole TOML document (which may hold other tables: campaign files
    /// embed one). `origin` names the document in messages; line numbers are relative to `text`. A relative
    /// `file` resolves against `base_dir`.
    pub fn from_document(text: &str, origin: &str, base_dir: &Path) -> Result<Material, MaterialError> {
        let doc = DeTable::parse(text).map_err(|e| MaterialError::Toml {
            at: Location {
                origin: origin.to_string(),
                line: e.span().map(|s| line_of(text, s.start)),
            },
            message: e.message().trim().to_string(),
        })?;
        let table_at = |line| Location {
            origin: origin.to_string(),
            line: Some(line),
        };
        let Some((_, value)) = doc.get_ref().iter().find(|(k, _)| k.get_ref() == "material") else {
            return Err(MaterialError::NoTable {
                at: Location {
                    origin: origin.to_string(),
                    line: None,
                },
            });
        };
        let header_line = line_of(text, value.span().start);
        let DeValue::Table(table) = value.get_ref() else {
            return Err(MaterialError::Value {
                at: table_at(header_line),
                key: "material".into(),
                message: format!("must be a table, found {}", value.get_ref().type_str()),
            });
        };
        let parsed = parse_table(table, text, origin, header_line)?;
        build(&parsed.spec, base_dir, &|key| {
            parsed.location(key, origin, header_line)
        })
    }

    /// A material from a description (e.g. one stored with a run). Relative `file` paths resolve against
    /// `base_dir`. Errors carry no line number.
    pub fn from_spec(spec: &MaterialSpec, base_dir: &Path) -> Result<Material, MaterialError> {
        let mut unknown = None;
        for key in ALL_KEYS {
            if spec.has(key) && *key != "model" && !spec.model.keys().contains(key) {
                unknown = Some(*key);
            }
        }
        if let Some(key) = unknown {
            return Err(not_applicable(
                key,
                spec.model,
                Location {
                    origin: "material description".into(),
                    line: None,
                },
            ));
        }
        build(spec, base_dir, &|_| Location {
            origin: "material description".into(),
            line: None,
        })
    }

    /// The same material with every spectral parameter resolved at `wavelength` (constants thereafter): for
    /// fast repeated evaluation at one wavelength. Fails when the wavelength is outside one of its tables.
    pub fn at_wavelength(&self, wavelength: Wavelength) -> Result<Material, SpectrumError> {
        Ok(match self {
            Material::Lambertian(m) => Material::Lambertian(m.at_wavelength(wavelength)?),
            Material::OrenNayar(m) => Material::OrenNayar(m.at_wavelength(wavelength)?),
            Material::Phong(m) => Material::Phong(m.at_wavelength(wavelength)?),
            Material::Conductor(m) => Material::Conductor(m.at_wavelength(wavelength)?),
            Material::Plastic(m) => Material::Plastic(m.at_wavelength(wavelength)?),
            Material::Mirror(m) => Material::Mirror(m.at_wavelength(wavelength)?),
            Material::Measured(m) => Material::Measured(m.clone()),
        })
    }

    /// [`Material::at_wavelength`] with the error wrapped in a [`MaterialError`] naming the model.
    pub fn resolved(&self, wavelength: Wavelength) -> Result<Material, MaterialError> {
        self.at_wavelength(wavelength)
            .map_err(|source| MaterialError::Wavelength {
                model: self.model().name().to_string(),
                source,
            })
    }

    pub fn model(&self) -> ModelKind {
        match self {
            Material::Lambertian(_) => ModelKind::Lambertian,
            Material::OrenNayar(_) => ModelKind::OrenNayar,
            Material::Phong(_) => ModelKind::Phong,
            Material::Conductor(_) => ModelKind::Conductor,
            Material::Plastic(_) => ModelKind::Plastic,
            Material::Mirror(_) => ModelKind::Mirror,
            Material::Measured(_) => ModelKind::Measured,
        }
    }

    /// The serialisable description of this material (measured files as resolved paths).
    pub fn spec(&self) -> MaterialSpec {
        let mut s = MaterialSpec::empty(self.model());
        let set_alpha = |s: &mut MaterialSpec, (ax, ay): (f64, f64)| {
            if ax == ay {
                s.alpha = Some(ax);
            } else {
                s.alpha_x = Some(ax);
                s.alpha_y = Some(ay);
            }
        };
        match self {
            Material::Lambertian(m) => s.albedo = Some(m.albedo().clone()),
            Material::OrenNayar(m) => {
                s.albedo = Some(m.albedo().clone());
                s.sigma_deg = Some(m.sigma_deg());
            }
            Material::Phong(m) => {
                s.diffuse = Some(m.diffuse().clone());
                s.specular = Some(m.specular().clone());
                s.exponent = Some(m.exponent());
            }
            Material::Conductor(m) => {
                s.distribution = Some(m.microfacet().distribution());
                s.masking = Some(m.microfacet().masking());
                set_alpha(&mut s, m.alpha());
                s.eta = Some(m.eta().clone());
                s.k = Some(m.k().clone());
            }
            Material::Plastic(m) => {
                s.distribution = Some(m.microfacet().distribution());
                s.masking = Some(m.microfacet().masking());
                set_alpha(&mut s, m.alpha());
                s.ior = Some(m.ior().clone());
                s.albedo = Some(m.albedo().clone());
            }
            Material::Mirror(m) => {
                s.eta = Some(m.eta().clone());
                s.k = Some(m.k().clone());
            }
            Material::Measured(m) => {
                s.file = Some(m.file.clone());
                match &m.table {
                    MeasuredTable::Merl { channel, .. } => {
                        s.format = Some(MeasuredFormat::Merl);
                        s.channel = Some(*channel);
                    }
                    MeasuredTable::Rgl(_) => s.format = Some(MeasuredFormat::Rgl),
                }
            }
        }
        s
    }
}
