//! The fitted parameters: their transforms (linear, log, log(1 + n)), the parameters of each model, and the
//! material they make, per band and as spectral tables.

use super::*;

#[derive(Debug, Clone, Copy)]
pub(super) enum Transform {
    Linear,
    Log,
    Log1p,
}

impl Transform {
    pub(super) fn to_internal(self, v: f64) -> f64 {
        match self {
            Transform::Linear => v,
            Transform::Log => v.ln(),
            Transform::Log1p => v.ln_1p(),
        }
    }
    pub(super) fn to_natural(self, x: f64) -> f64 {
        match self {
            Transform::Linear => x,
            Transform::Log => x.exp(),
            Transform::Log1p => x.exp_m1(),
        }
    }
    /// d natural / d internal.
    pub(super) fn derivative(self, x: f64) -> f64 {
        match self {
            Transform::Linear => 1.0,
            Transform::Log | Transform::Log1p => x.exp(),
        }
    }
}

#[derive(Debug, Clone, Copy)]
pub(super) struct ParamDef {
    pub(super) key: &'static str,
    pub(super) band: Option<usize>,
    pub(super) transform: Transform,
    pub(super) lo: f64,
    pub(super) hi: f64,
}

/// Smallest roughness fitted: below 1e-3 the models switch to a delta lobe, which has no pointwise value.
const ALPHA_MIN: f64 = 1.5e-3;

pub(super) fn param_defs(model: FitModel, bands: usize) -> Vec<ParamDef> {
    let shared = |key, transform, lo, hi| ParamDef {
        key,
        band: None,
        transform,
        lo,
        hi,
    };
    let mut defs = Vec::new();
    let spectral: &[(&'static str, Transform, f64, f64)] = match model {
        FitModel::Lambertian => &[("albedo", Transform::Linear, 0.0, 1.0)],
        FitModel::OrenNayar => {
            defs.push(shared("sigma_deg", Transform::Linear, 0.0, 90.0));
            &[("albedo", Transform::Linear, 0.0, 1.0)]
        }
        FitModel::Phong => {
            defs.push(shared("exponent", Transform::Log1p, 0.0, 1e6));
            &[
                ("diffuse", Transform::Linear, 0.0, 1.0),
                ("specular", Transform::Linear, 0.0, 1.0),
            ]
        }
        FitModel::Conductor => {
            defs.push(shared("alpha", Transform::Log, ALPHA_MIN, 1.0));
            &[
                ("eta", Transform::Log, 0.01, 10.0),
                ("k", Transform::Linear, 0.0, 20.0),
            ]
        }
        FitModel::Plastic => {
            defs.push(shared("alpha", Transform::Log, ALPHA_MIN, 1.0));
            defs.push(shared("ior", Transform::Linear, 1.0, 4.0));
            &[("albedo", Transform::Linear, 0.0, 1.0)]
        }
    };
    for &(key, transform, lo, hi) in spectral {
        for b in 0..bands {
            defs.push(ParamDef {
                key,
                band: Some(b),
                transform,
                lo,
                hi,
            });
        }
    }
    defs
}

/// The natural value of parameter `key` for band `b` (or the shared one).
fn get(defs: &[ParamDef], natural: &[f64], key: &str, b: usize) -> f64 {
    defs.iter()
        .zip(natural)
        .find(|(d, _)| d.key == key && d.band.is_none_or(|db| db == b))
        .map(|(_, v)| *v)
        .unwrap_or(f64::NAN)
}

/// The model for one band (spectral parameters as constants); `None` when the constructor refuses them.
pub(super) fn band_model(
    opts: &FitOptions,
    defs: &[ParamDef],
    natural: &[f64],
    b: usize,
) -> Option<Material> {
    let v = |key: &str| get(defs, natural, key, b);
    let c = Spectral::Constant;
    Some(match opts.model {
        FitModel::Lambertian => Material::Lambertian(Lambertian::new(c(v("albedo"))).ok()?),
        FitModel::OrenNayar => Material::OrenNayar(OrenNayar::new(c(v("albedo")), v("sigma_deg")).ok()?),
        FitModel::Phong => {
            let (d, s) = phong_split(v("diffuse"), v("specular"));
            Material::Phong(Phong::new(c(d), c(s), v("exponent")).ok()?)
        }
        FitModel::Conductor => {
            let a = v("alpha");
            Material::Conductor(
                Conductor::new(opts.distribution, opts.masking, a, a, c(v("eta")), c(v("k"))).ok()?,
            )
        }
        FitModel::Plastic => {
            let a = v("alpha");
            Material::Plastic(
                Plastic::new(opts.distribution, opts.masking, a, a, c(v("ior")), c(v("albedo"))).ok()?,
            )
        }
    })
}

/// Phong needs diffuse + specular <= 1: a pair beyond is scaled back onto the boundary.
pub(super) fn phong_split(d: f64, s: f64) -> (f64, f64) {
    let sum = d + s;
    if sum > 1.0 { (d / sum, s / sum) } else { (d, s) }
}

/// The fitted material with spectral tables over the bands (constants for one band).
pub(super) fn final_material(
    opts: &FitOptions,
    defs: &[ParamDef],
    natural: &[f64],
    bands: &[f64],
) -> Option<Material> {
    let spectral = |key: &str| -> Option<Spectral> {
        let values: Vec<(f64, f64)> = bands
            .iter()
            .enumerate()
            .map(|(b, nm)| (*nm, get(defs, natural, key, b)))
            .collect();
        if values.len() == 1 {
            values.first().map(|(_, v)| Spectral::Constant(*v))
        } else {
            Spectral::table(values).ok()
        }
    };
    let shared = |key: &str| get(defs, natural, key, 0);
    Some(match opts.model {
        FitModel::Lambertian => Material::Lambertian(Lambertian::new(spectral("albedo")?).ok()?),
        FitModel::OrenNayar => {
            Material::OrenNayar(OrenNayar::new(spectral("albedo")?, shared("sigma_deg")).ok()?)
        }
        FitModel::Phong => {
            let mut d = Vec::new();
            let mut s = Vec::new();
            for (b, nm) in bands.iter().enumerate() {
                let (db, sb) = phong_split(
                    get(defs, natural, "diffuse", b),
                    get(defs, natural, "specular", b),
                );
                d.push((*nm, db));
                s.push((*nm, sb));
            }
            let table = |t: Vec<(f64, f64)>| {
                if t.len() == 1 {
                    t.first().map(|(_, v)| Spectral::Constant(*v))
                } else {
                    Spectral::table(t).ok()
                }
            };
            Material::Phong(Phong::new(table(d)?, table(s)?, shared("exponent")).ok()?)
        }
        FitModel::Conductor => {
            let a = shared("alpha");
            Material::Conductor(
                Conductor::new(
                    opts.distribution,
                    opts.masking,
                    a,
                    a,
                    spectral("eta")?,
                    spectral("k")?,
                )
                .ok()?,
            )
        }
        FitModel::Plastic => {
            let a = shared("alpha");
            Material::Plastic(
                Plastic::new(
                    opts.distribution,
                    opts.masking,
                    a,
                    a,
                    Spectral::Constant(shared("ior")),
                    spectral("albedo")?,
                )
                .ok()?,
            )
        }
    })
}
