//! The report's section on the soaks run again on an imperfect instrument (`config/instruments/realistic.toml`).

use super::*;
use crate::truth_check::PointCheck;

/// The fault, crash, disk and safety soaks on one instrument file.
#[derive(Debug, Clone)]
pub struct InstrumentPass {
    /// The file's name (e.g. `realistic.toml`).
    pub instrument: String,
    pub fault: FaultSoakReport,
    pub crash: CrashSoakReport,
    pub disk: DiskSoakReport,
    pub safety: SafetySoakReport,
}

impl InstrumentPass {
    /// Every broken invariant, each named with its soak and the instrument.
    pub fn violations(&self) -> Vec<String> {
        let on = &self.instrument;
        let mut v = Vec::new();
        for (soak, list) in [
            ("fault soak", self.fault.violations()),
            ("crash soak", self.crash.violations()),
            ("disk soak", self.disk.violations()),
            ("safety", self.safety.violations()),
        ] {
            v.extend(list.into_iter().map(|m| format!("{soak} on {on}: {m}")));
        }
        v
    }

    /// Points lost or wrong, as [`Report::data_lost`] counts them.
    pub fn data_lost(&self) -> u64 {
        self.fault.committed.lost()
            + self.crash.committed.lost()
            + self.crash.sweeps.lost()
            + self.crash.changed.len() as u64
            + self.disk.data_lost()
    }

    pub(super) fn section(&self, m: &mut String) {
        let on = &self.instrument;
        let f = &self.fault;
        let _ = writeln!(m, "## The imperfect instrument ({on})\n");
        let _ = writeln!(
            m,
            "The fault, crash, disk and safety soaks again, with the same seeds, sizes and faults, on \
             `config/instruments/{on}`: the simulated instrument with the imperfections of issue 16 (axis zero \
             offsets, sample tilt and re-seating, eccentricity, encoder error; range gains, nonlinearity, offsets, \
             saturation, amplifier noise, stray light, ambient light; source warm-up, random walk and flicker; an \
             uneven sample; finite filter bands with leakage; a Gaussian, mispointed beam), their hidden values \
             drawn from the file's `[simulator] seed`. The faults combine with the imperfections. Rows, indices, \
             committed rows byte for byte, pauses and every safety rule are checked exactly as on the ideal \
             instrument: they do not depend on the instrument's errors. The safety rules are checked on the \
             motion the controllers executed; the true arms differ from it by the axis zero offsets and encoder \
             error (hundredths of a degree in this file), far inside the margins the summary reports.\n"
        );
        let _ = writeln!(
            m,
            "**Silently wrong, on this instrument** (`crates/soak/src/truth_check.rs`). Here a measured BRDF \
             differs from the simulator's ground truth by the instrument's own errors (1-2 %, more near specular): \
             real, expected, and not data loss. A value is silently wrong only when it lies further from its \
             point's truth than 5 standard uncertainties PLUS everything the imperfections explain, from the \
             point's own attribution (`truth_effects_json`), each effect as a magnitude, compounded: geometry, \
             sample, flicker, saturation, meter, stray light, the finite band (filter), the beam's profile and \
             divergence, the beam outside the field; the ambient light as far as \
             it can have changed since the dark reading that subtracted it (2v/(1-v) of it for a variation v); \
             the source's warm-up and walk as the ratio of the point's factor to the direct-beam reading's, which \
             lies between the warm-up's low and the walk's 5-sigma high; and a bound on the direct-beam reading's \
             other imperfections, which no point records ({:.2} %, from the file's magnitudes at 5 sigma: flicker, \
             range gain, nonlinearity, offset, saturation, stray light). A point measured at another pose is wrong \
             however close its value: its true directions must lie within {:.2} deg of the nominal ones (the \
             file's geometry magnitudes at 5 sigma). The check cannot see a corruption smaller than a point's \
             allowance; the allowances are listed below so that its resolution is plain (the ambient light on the \
             weakest signals makes the largest). A reading from another point or a stale reply generally differs \
             by far more (the soak's random geometries span orders of magnitude of BRDF).\n",
            f.committed.points.reference_rel * 100.0,
            f.committed.points.pose_bound_deg
        );
        let _ = writeln!(
            m,
            "| soak | valued points | valid | silently wrong | without value or reason | largest deviation from truth | allowance: median / largest | largest share of the bound used | largest pose error (deg) |"
        );
        let _ = writeln!(m, "|---|---|---|---|---|---|---|---|---|");
        let row = |m: &mut String, soak: &str, p: &PointCheck| {
            let _ = writeln!(
                m,
                "| {soak} | {} | {} | {} | {} | {:.2} % ({:.1} u) | {:.2} % / {:.2} % | {:.0} % | {:.3} |",
                p.valid + p.wrong.len() as u64,
                p.valid,
                p.wrong.len(),
                p.unexplained.len(),
                p.max_error_rel * 100.0,
                p.max_error_in_u,
                p.allowance_median_rel * 100.0,
                p.allowance_max_rel * 100.0,
                p.max_bound_used * 100.0,
                p.max_pose_deg
            );
        };
        row(m, "fault", &f.committed.points);
        row(m, "crash", &self.crash.committed.points);
        row(m, "disk", &self.disk.committed.points);
        let _ = writeln!(m);
        let _ = writeln!(
            m,
            "Fault soak: campaign ended **{}**, {} rows for {} planned, {} failed with the device's reason ({}), \
             {} flagged ({}), {} operator resumes; injected {} garbled, {} dropped, {} delayed replies, {} stalls \
             drawn, {} outages. Crash soak: {} kills, campaign {}, {} committed rows changed. Disk soak: {} fills, \
             campaign {}, {} committed rows changed. Safety: {} cases, {} move commands, {} violations.\n",
            f.final_state,
            f.committed.rows,
            f.campaign.total_points,
            f.committed.points.failed_total(),
            top(&f.committed.points.failed, 4),
            f.committed.points.flagged_total(),
            top(&f.committed.points.flagged, 4),
            f.pauses.len(),
            f.injected.garbled,
            f.injected.dropped,
            f.injected.delayed,
            f.injected.stalls,
            f.injected.outages,
            self.crash.kills(),
            self.crash
                .final_state
                .map(|s| s.to_string())
                .unwrap_or_else(|| "missing".into()),
            self.crash.changed.len(),
            self.disk.fills.len(),
            self.disk.final_state,
            self.disk.changed.len(),
            self.safety.cases.len(),
            self.safety.move_commands(),
            self.safety.violations().len()
        );
        let _ = writeln!(
            m,
            "Not checked here: whether a row's value matches what the devices answered to the last bit (the \
             signal, dark and direct-beam readings against the meter's own record); the bound above is what tells \
             a corrupted value from the instrument's error.\n"
        );
    }
}
