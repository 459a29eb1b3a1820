//! Campaign texts for dry-runs on the simulated instrument, built table by table. Values are TOML text
//! (`"[450.0, 650.0]"`, `"{ from = 0.0, to = 60.0, step = 20.0 }"`), so a test states its plan as a campaign
//! file would. Defaults: a 12.5 mm sample, one band at 550 nm, the coloured-plastic preset; a table without
//! lines is left out (the campaign file's own defaults apply).

use std::fmt;

/// A campaign file's text (module doc); `to_string()` gives the TOML.
#[derive(Debug, Clone)]
pub struct CampaignText {
    id: String,
    bands_nm: String,
    plan: Vec<String>,
    grid: Vec<String>,
    plan_calibration: Vec<String>,
    calibration: Vec<String>,
    acquisition: Vec<String>,
    material: String,
}

impl CampaignText {
    fn with_grid(id: &str, grid: Vec<String>) -> CampaignText {
        CampaignText {
            id: id.to_string(),
            bands_nm: "[550.0]".into(),
            plan: Vec::new(),
            grid,
            plan_calibration: Vec::new(),
            calibration: Vec::new(),
            acquisition: Vec::new(),
            material: "preset = \"coloured-plastic\"".into(),
        }
    }

    /// An isotropic grid: incidence, outgoing polar angles and azimuth differences.
    pub fn isotropic(id: &str, theta_i_deg: &str, theta_o_deg: &str, delta_phi_deg: &str) -> CampaignText {
        CampaignText::with_grid(
            id,
            vec![
                "kind = \"isotropic\"".into(),
                format!("theta_i_deg = {theta_i_deg}"),
                format!("theta_o_deg = {theta_o_deg}"),
                format!("delta_phi_deg = {delta_phi_deg}"),
            ],
        )
    }

    /// The export tests' measurement: an isotropic grid at the incidences `theta_i_deg`, theta_o 0-80 by 10,
    /// delta phi 0-180 by 45 (with reciprocity, the default), averaging 4, darks every 200 points.
    pub fn isotropic_export_grid(id: &str, theta_i_deg: &str) -> CampaignText {
        CampaignText::isotropic(
            id,
            theta_i_deg,
            "{ from = 0.0, to = 80.0, step = 10.0 }",
            "{ from = 0.0, to = 180.0, step = 45.0 }",
        )
        .acquisition("averaging = 4")
        .plan_calibration("dark_every_points = 200")
    }

    /// A grid in the plane of incidence: incidence and outgoing polar angles.
    pub fn in_plane_grid(id: &str, theta_i_deg: &str, theta_o_deg: &str) -> CampaignText {
        CampaignText::with_grid(
            id,
            vec![
                "kind = \"in-plane\"".into(),
                format!("theta_i_deg = {theta_i_deg}"),
                format!("theta_o_deg = {theta_o_deg}"),
            ],
        )
    }

    /// `points` outgoing angles in the plane of incidence (10 degrees on, by 5), one incidence at 30 degrees,
    /// no repeats or reciprocal points, calibration readings that never fall due during the run (direct-beam
    /// readings at a pose clear of the sample), averaging 2: a quick campaign whose length the test chooses.
    pub fn in_plane(id: &str, points: usize) -> CampaignText {
        let to = 10.0 + 5.0 * (points.max(1) as f64 - 1.0);
        CampaignText::in_plane_grid(
            id,
            "[30.0]",
            &format!("{{ from = 10.0, to = {to:?}, step = 5.0 }}"),
        )
        .plan("repeats = 1")
        .plan("reciprocity = false")
        .plan_calibration("dark_every_points = 1000")
        .plan_calibration("reference_every_s = 100000.0")
        .plan_calibration("reference_pose_deg = { light = -90.0, detector = 90.0 }")
        .acquisition("averaging = 2")
    }

    /// `[plan] bands_nm`.
    pub fn bands(mut self, bands_nm: &str) -> CampaignText {
        self.bands_nm = bands_nm.to_string();
        self
    }

    /// A further `[plan]` line.
    pub fn plan(mut self, line: &str) -> CampaignText {
        self.plan.push(line.to_string());
        self
    }

    /// A `[plan.calibration]` line.
    pub fn plan_calibration(mut self, line: &str) -> CampaignText {
        self.plan_calibration.push(line.to_string());
        self
    }

    /// A `[calibration]` line.
    pub fn calibration(mut self, line: &str) -> CampaignText {
        self.calibration.push(line.to_string());
        self
    }

    /// An `[acquisition]` line; it replaces an earlier line setting the same key.
    pub fn acquisition(mut self, line: &str) -> CampaignText {
        let key = line.split('=').next().unwrap_or("").trim();
        self.acquisition
            .retain(|l| l.split('=').next().unwrap_or("").trim() != key);
        self.acquisition.push(line.to_string());
        self
    }

    /// The `[material]` table's body, e.g. `preset = "gold"` or a model and its parameters.
    pub fn material(mut self, body: &str) -> CampaignText {
        self.material = body.to_string();
        self
    }
}

impl fmt::Display for CampaignText {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        writeln!(f, "[campaign]\nid = \"{}\"", self.id)?;
        writeln!(f, "[sample]\nradius_mm = 12.5")?;
        writeln!(f, "[plan]\nbands_nm = {}", self.bands_nm)?;
        let tables = [
            ("", &self.plan),
            ("plan.grid", &self.grid),
            ("plan.calibration", &self.plan_calibration),
            ("calibration", &self.calibration),
            ("acquisition", &self.acquisition),
        ];
        for (name, lines) in tables {
            if lines.is_empty() {
                continue;
            }
            if !name.is_empty() {
                writeln!(f, "[{name}]")?;
            }
            for l in lines {
                writeln!(f, "{l}")?;
            }
        }
        writeln!(f, "[material]\n{}", self.material)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tables_come_out_in_order_with_their_lines() {
        let t = CampaignText::isotropic("x", "[0.0]", "[30.0]", "[180.0]")
            .bands("[450.0, 650.0]")
            .plan_calibration("dark_every_points = 100")
            .acquisition("averaging = 3")
            .material("preset = \"gold\"")
            .to_string();
        assert_eq!(
            t,
            "[campaign]\nid = \"x\"\n[sample]\nradius_mm = 12.5\n[plan]\nbands_nm = [450.0, 650.0]\n\
             [plan.grid]\nkind = \"isotropic\"\ntheta_i_deg = [0.0]\ntheta_o_deg = [30.0]\ndelta_phi_deg = [180.0]\n\
             [plan.calibration]\ndark_every_points = 100\n[acquisition]\naveraging = 3\n\
             [material]\npreset = \"gold\"\n"
        );
        let p = CampaignText::in_plane("y", 5).to_string();
        assert!(
            p.contains("repeats = 1\nreciprocity = false\n[plan.grid]")
                && p.contains("to = 30.0,")
                && p.contains("averaging = 2\n")
                && !p.contains("averaging = 10"),
            "{p}"
        );
    }
}
