//! What a fit reports: residual statistics, Phong's parameters as the model uses them, and the report's text,
//! JSON and material file.

use super::*;

/// Phong parameters as written to the file: diffuse + specular scaled back onto <= 1 as the model uses them.
pub(super) fn fix_phong_params(
    opts: &FitOptions,
    mut params: Vec<FittedParam>,
    bands: &[f64],
) -> Vec<FittedParam> {
    if opts.model != FitModel::Phong {
        return params;
    }
    for nm in bands {
        let find =
            |ps: &[FittedParam], key: &str| ps.iter().position(|q| q.key == key && q.band_nm == Some(*nm));
        if let (Some(i), Some(j)) = (find(&params, "diffuse"), find(&params, "specular")) {
            let (d, s) = phong_split(params[i].value, params[j].value);
            params[i].value = d;
            params[j].value = s;
        }
    }
    params
}

/// What a chi2/dof says, in a few words.
pub fn chi2_meaning(chi2_per_dof: f64) -> &'static str {
    if !chi2_per_dof.is_finite() {
        "undefined"
    } else if chi2_per_dof < 0.5 {
        "the uncertainties are larger than the scatter: they are conservative, or padded"
    } else if chi2_per_dof <= 2.0 {
        "the model describes the points to within their uncertainties"
    } else {
        "the model misses structure in the data, or the uncertainties are too small"
    }
}

/// `chi2_whole`: the sum of squares against the whole budget (super::shared::chi2_whole_budget), when known.
pub(super) fn residual_stats(obs: &[Obs], m: &[f64], p: usize, chi2_whole: Option<f64>) -> ResidualStats {
    let (mut num, mut den, mut log2, mut max_rel, mut chi2) = (0.0, 0.0, 0.0, 0.0f64, 0.0);
    for (o, m) in obs.iter().zip(m) {
        num += ((m - o.f) * o.cos_i).powi(2);
        den += (o.f * o.cos_i).powi(2);
        log2 += ((1.0 + m * o.cos_i).max(1e-300).ln() - (1.0 + o.f * o.cos_i).max(1e-300).ln()).powi(2);
        if o.f > 0.0 {
            max_rel = max_rel.max((m - o.f).abs() / o.f);
        }
        chi2 += ((m - o.f) / o.u).powi(2);
    }
    let n = obs.len();
    let dof = (n.saturating_sub(p)).max(1) as f64;
    ResidualStats {
        points: n,
        cos_weighted_relative_rms: if den > 0.0 { (num / den).sqrt() } else { f64::NAN },
        log_rms: (log2 / n.max(1) as f64).sqrt(),
        max_relative: max_rel,
        chi2_per_dof: chi2_whole.unwrap_or(f64::NAN) / dof,
        chi2_per_dof_independent: chi2 / dof,
    }
}

impl FitReport {
    /// A parameter's label: `albedo @ 550 nm`, `sigma_deg`.
    pub fn label(p: &FittedParam) -> String {
        match p.band_nm {
            Some(nm) => format!("{} @ {nm} nm", p.key),
            None => p.key.to_string(),
        }
    }

    /// The human-readable report.
    pub fn summary(&self) -> String {
        let mut s = format!(
            "fit of {} to {} (campaign {}): {} points at {}, loss {}, {} LM iterations\n",
            self.model.name(),
            self.origin,
            self.campaign,
            self.residuals.points,
            list_nm(&self.bands_nm),
            self.options.loss.name(),
            self.iterations
        );
        if matches!(self.model, FitModel::Conductor | FitModel::Plastic) {
            s.push_str(&format!(
                "microfacet: {} distribution, {} masking (chosen, not fitted)\n",
                self.options.distribution.name(),
                self.options.masking.name()
            ));
        }
        match self.options.aperture_half_angle_rad {
            Some(a) => s.push_str(&format!(
                "model averaged over the detector aperture ({:.3} deg half-angle), as the instrument measures\n",
                a.to_degrees()
            )),
            None => s.push_str("model taken at the point (the detector aperture is unknown)\n"),
        }
        s.push_str(&format!(
            "{:<22} {:>14} {:>14} {:>14}\n",
            "parameter", "value", "u independent", "u shared"
        ));
        for p in &self.params {
            let u = p
                .std_uncertainty
                .map(|u| format!("{u:.3e}"))
                .unwrap_or_else(|| "undetermined".into());
            let shared = p
                .shared_uncertainty
                .map(|u| format!("{u:.3e}"))
                .unwrap_or_else(|| "-".into());
            s.push_str(&format!(
                "{:<22} {:>14.6} {:>14} {:>14}{}\n",
                FitReport::label(p),
                p.value,
                u,
                shared,
                if p.at_bound { "  (at its bound)" } else { "" }
            ));
        }
        s.push_str(
            "(standard uncertainties, k = 1: independent from the points' scatter about the model; shared from what \
             the points have in common (solid angle, a band's normalisation, a range's gain, a dark reading, an \
             alignment parameter), which moves them together; combine them in quadrature for the total)\n",
        );
        let r = &self.residuals;
        s.push_str(&format!(
            "residuals: cos-weighted relative RMS {:.3e}, log RMS {:.3e}, max relative {:.3e}, chi2/dof {:.3} \
             against the points' whole budget, what they share with its correlations ({}); {:.3} against the \
             points' independent uncertainties alone; {} points down-weighted as outliers",
            r.cos_weighted_relative_rms,
            r.log_rms,
            r.max_relative,
            r.chi2_per_dof,
            chi2_meaning(r.chi2_per_dof),
            r.chi2_per_dof_independent,
            self.downweighted
        ));
        s
    }

    /// The report as JSON (for scripts): parameters, residuals, material.
    pub fn to_json(&self) -> Value {
        json!({
            "model": self.model.name(),
            "source": self.origin,
            "campaign": self.campaign,
            "bands_nm": self.bands_nm,
            "loss": self.options.loss.name(),
            "iterations": self.iterations,
            "parameters": self.params.iter().map(|p| json!({
                "key": p.key,
                "band_nm": p.band_nm,
                "value": p.value,
                "std_uncertainty": p.std_uncertainty,
                "shared_uncertainty": p.shared_uncertainty,
                "at_bound": p.at_bound,
            })).collect::<Vec<_>>(),
            "residuals": {
                "points": self.residuals.points,
                "cos_weighted_relative_rms": self.residuals.cos_weighted_relative_rms,
                "log_rms": self.residuals.log_rms,
                "max_relative": self.residuals.max_relative,
                "chi2_per_dof": self.residuals.chi2_per_dof,
                "chi2_per_dof_independent": self.residuals.chi2_per_dof_independent,
                "downweighted": self.downweighted,
            },
            "material": serde_json::to_value(self.material.spec()).unwrap_or(Value::Null),
        })
    }

    /// The material file: the summary as comments, then the `[material]` table (the schema of
    /// config/materials/*.toml).
    pub fn material_toml(&self) -> String {
        let mut s = String::from("# Fitted by `gonio fit`; uncertainties are standard (k = 1).\n");
        for line in self.summary().lines() {
            s.push_str("# ");
            s.push_str(line);
            s.push('\n');
        }
        if self.bands_nm.len() > 1 {
            s.push_str(&format!(
                "# Spectral parameters are tables over the fitted bands: the material is defined from {} to {} nm.\n",
                self.bands_nm.first().copied().unwrap_or(0.0),
                self.bands_nm.last().copied().unwrap_or(0.0)
            ));
        } else {
            s.push_str(
                "# One band fitted: its parameters are written as constants (valid at every wavelength).\n",
            );
        }
        s.push('\n');
        s.push_str(&self.material.spec().to_toml());
        s
    }
}
