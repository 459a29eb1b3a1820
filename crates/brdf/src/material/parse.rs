//! Reading the `[material]` table: each key with its line, values checked for their type (choices, numbers,
//! spectral tables).

use super::*;

/// 1-based line of a byte offset.
pub(super) fn line_of(text: &str, offset: usize) -> usize {
    let end = offset.min(text.len());
    text.as_bytes()[..end].iter().filter(|&&b| b == b'\n').count() + 1
}

/// A parsed table: the description plus the line of each key.
pub(super) struct Parsed {
    pub(super) spec: MaterialSpec,
    pub(super) lines: Vec<(&'static str, usize)>,
}

impl Parsed {
    pub(super) fn location(&self, key: &str, origin: &str, header_line: usize) -> Location {
        let find = |k: &str| self.lines.iter().find(|(name, _)| *name == k).map(|&(_, l)| l);
        // A roughness error reported as `alpha` may come from alpha_x/alpha_y written out.
        let line = find(key)
            .or_else(|| if key == "alpha" { find("alpha_x") } else { None })
            .unwrap_or(header_line);
        Location {
            origin: origin.to_string(),
            line: Some(line),
        }
    }
}

pub(super) fn parse_table(
    table: &DeTable<'_>,
    text: &str,
    origin: &str,
    header_line: usize,
) -> Result<Parsed, MaterialError> {
    let at = |offset: usize| Location {
        origin: origin.to_string(),
        line: Some(line_of(text, offset)),
    };
    let value_err = |offset: usize, key: &str, message: String| MaterialError::Value {
        at: at(offset),
        key: key.to_string(),
        message,
    };

    // The model first: it decides which keys are allowed.
    let Some((model_key, model_value)) = table.iter().find(|(k, _)| k.get_ref() == "model") else {
        return Err(MaterialError::Missing {
            at: Location {
                origin: origin.to_string(),
                line: Some(header_line),
            },
            key: "model".into(),
            message: format!(
                "one of {}",
                MODEL_NAMES
                    .iter()
                    .map(|(n, _)| format!("\"{n}\""))
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
        });
    };
    let model = parse_choice(model_value.get_ref(), MODEL_NAMES)
        .map_err(|m| value_err(model_key.span().start, "model", m))?;
    let mut spec = MaterialSpec::empty(model);
    let mut lines = Vec::new();

    for (key, value) in table.iter() {
        let name = key.get_ref().as_ref();
        let offset = key.span().start;
        let Some(&known) = ALL_KEYS.iter().find(|k| **k == name) else {
            return Err(MaterialError::Value {
                at: at(offset),
                key: name.to_string(),
                message: format!(
                    "unknown key; the keys of model \"{}\" are: model, {}",
                    model.name(),
                    model.keys().join(", ")
                ),
            });
        };
        if known != "model" && !model.keys().contains(&known) {
            return Err(not_applicable(known, model, at(offset)));
        }
        lines.push((known, line_of(text, offset)));
        let v = value.get_ref();
        let err = |m: String| value_err(offset, known, m);
        match known {
            "model" => {}
            "distribution" => {
                spec.distribution = Some(
                    parse_choice(
                        v,
                        &[("ggx", Distribution::Ggx), ("beckmann", Distribution::Beckmann)],
                    )
                    .map_err(err)?,
                )
            }
            "masking" => {
                spec.masking = Some(
                    parse_choice(
                        v,
                        &[
                            ("separable", Masking::Separable),
                            ("height-correlated", Masking::HeightCorrelated),
                        ],
                    )
                    .map_err(err)?,
                )
            }
            "alpha" => spec.alpha = Some(parse_number(v).map_err(err)?),
            "alpha_x" => spec.alpha_x = Some(parse_number(v).map_err(err)?),
            "alpha_y" => spec.alpha_y = Some(parse_number(v).map_err(err)?),
            "sigma_deg" => spec.sigma_deg = Some(parse_number(v).map_err(err)?),
            "exponent" => spec.exponent = Some(parse_number(v).map_err(err)?),
            "eta" => spec.eta = Some(parse_spectral(v, text, origin, known, offset)?),
            "k" => spec.k = Some(parse_spectral(v, text, origin, known, offset)?),
            "ior" => spec.ior = Some(parse_spectral(v, text, origin, known, offset)?),
            "albedo" => spec.albedo = Some(parse_spectral(v, text, origin, known, offset)?),
            "diffuse" => spec.diffuse = Some(parse_spectral(v, text, origin, known, offset)?),
            "specular" => spec.specular = Some(parse_spectral(v, text, origin, known, offset)?),
            "file" => match v {
                DeValue::String(s) => spec.file = Some(PathBuf::from(s.as_ref())),
                other => {
                    return Err(err(format!(
                        "must be a string (a path), found {}",
                        other.type_str()
                    )));
                }
            },
            "format" => {
                spec.format = Some(
                    parse_choice(v, &[("merl", MeasuredFormat::Merl), ("rgl", MeasuredFormat::Rgl)])
                        .map_err(err)?,
                )
            }
            "channel" => {
                spec.channel = Some(
                    parse_choice(
                        v,
                        &[
                            ("red", MerlChannel::Red),
                            ("green", MerlChannel::Green),
                            ("blue", MerlChannel::Blue),
                        ],
                    )
                    .map_err(err)?,
                )
            }
            _ => {}
        }
    }
    Ok(Parsed { spec, lines })
}

pub(super) fn not_applicable(key: &str, model: ModelKind, at: Location) -> MaterialError {
    MaterialError::Value {
        at,
        key: key.to_string(),
        message: format!(
            "does not apply to model \"{}\" (its keys are: model, {})",
            model.name(),
            model.keys().join(", ")
        ),
    }
}

fn parse_choice<T: Copy>(v: &DeValue<'_>, choices: &[(&str, T)]) -> Result<T, String> {
    let list = || {
        choices
            .iter()
            .map(|(n, _)| format!("\"{n}\""))
            .collect::<Vec<_>>()
            .join(", ")
    };
    match v {
        DeValue::String(s) => choices
            .iter()
            .find(|(n, _)| *n == s.as_ref())
            .map(|&(_, t)| t)
            .ok_or_else(|| format!("\"{s}\" is not one of {}", list())),
        other => Err(format!(
            "must be a string, one of {}; found {}",
            list(),
            other.type_str()
        )),
    }
}

fn parse_number(v: &DeValue<'_>) -> Result<f64, String> {
    let x = match v {
        DeValue::Integer(i) => i64::from_str_radix(i.as_str(), i.radix())
            .map(|n| n as f64)
            .map_err(|e| e.to_string())?,
        DeValue::Float(f) => f.as_str().parse::<f64>().map_err(|e| e.to_string())?,
        other => return Err(format!("must be a number, found {}", other.type_str())),
    };
    if x.is_finite() {
        Ok(x)
    } else {
        Err(format!("must be a finite number, got {x}"))
    }
}

fn parse_spectral(
    v: &DeValue<'_>,
    text: &str,
    origin: &str,
    key: &str,
    offset: usize,
) -> Result<Spectral, MaterialError> {
    let err = |offset: usize, message: String| MaterialError::Value {
        at: Location {
            origin: origin.to_string(),
            line: Some(line_of(text, offset)),
        },
        key: key.to_string(),
        message,
    };
    match v {
        DeValue::Integer(_) | DeValue::Float(_) => parse_number(v)
            .map(Spectral::Constant)
            .map_err(|m| err(offset, m)),
        DeValue::Table(t) => {
            let mut entries = Vec::with_capacity(t.len());
            for (k, val) in t.iter() {
                let nm: f64 = k.get_ref().trim().parse().map_err(|_| {
                    err(
                        k.span().start,
                        format!("table key \"{}\" is not a wavelength in nm", k.get_ref()),
                    )
                })?;
                if !(nm.is_finite() && nm > 0.0) {
                    return Err(err(
                        k.span().start,
                        format!("table key \"{}\" is not a positive wavelength in nm", k.get_ref()),
                    ));
                }
                let x = parse_number(val.get_ref())
                    .map_err(|m| err(k.span().start, format!("value at {nm} nm {m}")))?;
                entries.push((nm, x));
            }
            Spectral::table(entries).map_err(|e| err(offset, e.to_string()))
        }
        other => Err(err(
            offset,
            format!(
                "must be a number or a table of wavelength (nm) = value, e.g. {{ 450 = 0.2, 650 = 0.8 }}; found {}",
                other.type_str()
            ),
        )),
    }
}
