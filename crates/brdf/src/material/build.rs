//! Building the model from a parsed description: the keys the model requires, each refusal located.

use super::*;

/// Checks the keys the model requires and builds it; `locate` maps a key to where it was written.
pub(super) fn build(
    spec: &MaterialSpec,
    base_dir: &Path,
    locate: &dyn Fn(&str) -> Location,
) -> Result<Material, MaterialError> {
    let model = spec.model;
    let missing = |key: &str, message: &str| MaterialError::Missing {
        at: locate("model"),
        key: key.to_string(),
        message: format!("model \"{}\" needs it ({message})", model.name()),
    };
    let value_err = |e: ParamError| MaterialError::Value {
        at: locate(e.key),
        key: e.key.to_string(),
        message: e.message,
    };
    let spectral = |v: &Option<Spectral>, key: &str, what: &str| v.clone().ok_or_else(|| missing(key, what));
    let number = |v: Option<f64>, key: &str, what: &str| v.ok_or_else(|| missing(key, what));
    let microfacet = || -> Result<(Distribution, Masking, f64, f64), MaterialError> {
        let distribution = spec
            .distribution
            .ok_or_else(|| missing("distribution", "\"ggx\" or \"beckmann\""))?;
        let masking = spec
            .masking
            .ok_or_else(|| missing("masking", "\"separable\" or \"height-correlated\""))?;
        let (ax, ay) = match (spec.alpha, spec.alpha_x, spec.alpha_y) {
            (Some(a), None, None) => (a, a),
            (None, Some(ax), Some(ay)) => (ax, ay),
            (None, None, None) => {
                return Err(missing(
                    "alpha",
                    "the roughness, or alpha_x and alpha_y for an anisotropic surface",
                ));
            }
            (None, Some(_), None) => {
                return Err(missing(
                    "alpha_y",
                    "alpha_x is given, so the surface is anisotropic",
                ));
            }
            (None, None, Some(_)) => {
                return Err(missing(
                    "alpha_x",
                    "alpha_y is given, so the surface is anisotropic",
                ));
            }
            (Some(_), _, _) => {
                let key = if spec.alpha_x.is_some() {
                    "alpha_x"
                } else {
                    "alpha_y"
                };
                return Err(MaterialError::Value {
                    at: locate(key),
                    key: key.to_string(),
                    message: "give either alpha (isotropic) or alpha_x and alpha_y (anisotropic), not both"
                        .into(),
                });
            }
        };
        Ok((distribution, masking, ax, ay))
    };
    Ok(match model {
        ModelKind::Lambertian => Material::Lambertian(
            Lambertian::new(spectral(&spec.albedo, "albedo", "the reflectance in [0, 1]")?)
                .map_err(value_err)?,
        ),
        ModelKind::OrenNayar => Material::OrenNayar(
            OrenNayar::new(
                spectral(&spec.albedo, "albedo", "the reflectance in [0, 1]")?,
                number(spec.sigma_deg, "sigma_deg", "the roughness in degrees")?,
            )
            .map_err(value_err)?,
        ),
        ModelKind::Phong => Material::Phong(
            Phong::new(
                spectral(&spec.diffuse, "diffuse", "the diffuse reflectance")?,
                spectral(&spec.specular, "specular", "the specular reflectance")?,
                number(spec.exponent, "exponent", "the lobe exponent")?,
            )
            .map_err(value_err)?,
        ),
        ModelKind::Conductor => {
            let (d, m, ax, ay) = microfacet()?;
            Material::Conductor(
                Conductor::new(
                    d,
                    m,
                    ax,
                    ay,
                    spectral(&spec.eta, "eta", "the real part of the refractive index")?,
                    spectral(&spec.k, "k", "the extinction coefficient")?,
                )
                .map_err(value_err)?,
            )
        }
        ModelKind::Plastic => {
            let (d, m, ax, ay) = microfacet()?;
            Material::Plastic(
                Plastic::new(
                    d,
                    m,
                    ax,
                    ay,
                    spectral(&spec.ior, "ior", "the coat's refractive index")?,
                    spectral(&spec.albedo, "albedo", "the base's reflectance in [0, 1]")?,
                )
                .map_err(value_err)?,
            )
        }
        ModelKind::Mirror => Material::Mirror(
            Mirror::new(
                spectral(&spec.eta, "eta", "the real part of the refractive index")?,
                spectral(&spec.k, "k", "the extinction coefficient")?,
            )
            .map_err(value_err)?,
        ),
        ModelKind::Measured => {
            let file = spec
                .file
                .as_ref()
                .ok_or_else(|| missing("file", "the path of the data file"))?;
            let format = spec
                .format
                .ok_or_else(|| missing("format", "\"merl\" or \"rgl\""))?;
            let path = if file.is_absolute() {
                file.clone()
            } else {
                base_dir.join(file)
            };
            let table = match format {
                MeasuredFormat::Merl => {
                    let channel = spec
                        .channel
                        .ok_or_else(|| missing("channel", "\"red\", \"green\" or \"blue\""))?;
                    let brdf = MeasuredBrdf::from_merl_file(&path, channel).map_err(|source| {
                        MaterialError::Measured {
                            at: locate("file"),
                            source,
                        }
                    })?;
                    MeasuredTable::Merl {
                        brdf: Arc::new(brdf),
                        channel,
                    }
                }
                MeasuredFormat::Rgl => {
                    if spec.channel.is_some() {
                        return Err(MaterialError::Value {
                            at: locate("channel"),
                            key: "channel".into(),
                            message: "applies to MERL files only: an RGL file is spectral".into(),
                        });
                    }
                    let brdf = RglBrdf::from_file(&path).map_err(|source| MaterialError::Rgl {
                        at: locate("file"),
                        source,
                    })?;
                    MeasuredTable::Rgl(Arc::new(brdf))
                }
            };
            Material::Measured(MeasuredMaterial { table, file: path })
        }
    })
}
