//! Fixed cases of the safety soak, beside its random ones: the campaign the regressions are written against
//! ([`fixed_case`]), and sabotage ([`Sabotage`]): controllers reset behind the engine's back, before it starts or
//! at a chosen moment of the run, so that recovery homing is checked by the same record and the same rules.

use gonio_simulator::scene::Pose;
use gonio_simulator::{SerialStream, SimInstrument};
use tokio::io::AsyncWriteExt;

use super::{Case, FaultLevel, Interruption};

impl FaultLevel {
    /// No injected fault.
    pub const NONE: FaultLevel = FaultLevel {
        seed: 0,
        stall_rate: 0.0,
        garble_rate: 0.0,
        drop_rate: 0.0,
    };
}

/// The campaign the fixed cases start from: a small isotropic grid, one band, darks and direct-beam readings
/// often. Kept byte for byte: the regressions written against it reproduce what they guard only with it.
pub const FIXED_CAMPAIGN: &str = r#"[campaign]
id = "safety"
[sample]
radius_mm = 12.5
[plan]
bands_nm = [650.0]
repeats = 1
reciprocity = false
[plan.grid]
kind = "isotropic"
theta_i_deg = { from = 0.0, to = 60.0, step = 10 }
theta_o_deg = [20.0, 50.0]
delta_phi_deg = { from = 0.0, to = 180.0, step = 20 }

[plan.calibration]
dark_every_points = 1
reference_every_points = 2
reference_pose_deg = { light = -81, detector = 99 }
[calibration]
method = "absolute"
simulate_operator = true
[acquisition]
averaging = 1
settle_s = 0
[material]
preset = "spectralon"
"#;

/// The `[plan.grid]` table of [`FIXED_CAMPAIGN`], for edits that replace it.
pub const FIXED_GRID: &str = "kind = \"isotropic\"\ntheta_i_deg = { from = 0.0, to = 60.0, step = 10 }\n\
                              theta_o_deg = [20.0, 50.0]\ndelta_phi_deg = { from = 0.0, to = 180.0, step = 20 }\n";

/// [`FIXED_CAMPAIGN`] with each `(from, to)` of `campaign_edit` replaced, under `faults` and `interruptions`.
/// `Err` names an edit that did not apply (its `from` is not in the campaign by then).
pub fn fixed_case(
    campaign_edit: &[(&str, &str)],
    faults: FaultLevel,
    interruptions: Vec<Interruption>,
) -> Result<Case, String> {
    let mut campaign = FIXED_CAMPAIGN.to_string();
    for (from, to) in campaign_edit {
        if !campaign.contains(from) {
            return Err(format!("the edit of {from:?} does not apply to\n{campaign}"));
        }
        campaign = campaign.replace(from, to);
    }
    Ok(Case {
        campaign,
        interruptions,
        faults,
    })
}

/// A campaign whose points put the detector arm beyond the light arm on one side (theta_i 20..30 deg with the
/// detector at theta_o 50..70 deg on the same side: light at +-20..30 deg, detector at +-50..70 deg); no faults,
/// no interruptions. Its four points: [`BEHIND_LIGHT_POINTS`].
pub fn behind_light_case() -> Case {
    let grid = format!("kind = \"points\"\npoints = {BEHIND_LIGHT_POINTS}\n");
    Case {
        campaign: FIXED_CAMPAIGN.replace(FIXED_GRID, &grid),
        interruptions: Vec::new(),
        faults: FaultLevel::NONE,
    }
}

/// The points of [`behind_light_case`].
pub const BEHIND_LIGHT_POINTS: &str =
    "[[30.0, 0.0, 60.0, 0.0], [30.0, 0.0, 70.0, 0.0], [20.0, 0.0, 50.0, 0.0], [20.0, 180.0, 50.0, 0.0]]";

/// Controller resets behind the engine's back: `<addr>RS` on the arms' chain makes an SMC100 stop dead and
/// forget its reference, as a brown-out of the controller does; the engine meets it as a lost reference.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Sabotage {
    /// Before the engine starts: raw SMC100 commands on the arms' chain, each followed by a wait (simulated s).
    pub setup: Vec<(&'static str, f64)>,
    /// During the run: reset the detector arm's controller once the light arm sits still between the detector
    /// and the detector's home (0 deg), so that homing it there would sweep it through the light arm.
    pub reset_detector_behind_light: bool,
}

impl Sabotage {
    pub fn any(&self) -> bool {
        self.reset_detector_behind_light || !self.setup.is_empty()
    }
}

/// The reset of a running saboteur: when (simulated s), the pose then, and the connection it used (kept open).
pub(super) type Reset = (f64, Pose, SerialStream);

/// Send a raw line to a simulated serial device on a connection of its own; the connection is returned so that
/// it stays open.
pub(super) async fn send_raw(sim: &SimInstrument, device: &str, line: &str) -> Result<SerialStream, String> {
    let mut port = sim
        .serial_port(device)
        .map_err(|e| format!("open {device}: {e}"))?;
    port.write_all(format!("{line}\r\n").as_bytes())
        .await
        .map_err(|e| format!("write to {device}: {e}"))?;
    Ok(port)
}

/// Run the setup commands of `sabotage` (before the engine starts); the connections they used.
pub(super) async fn set_up(sim: &SimInstrument, sabotage: &Sabotage) -> Result<Vec<SerialStream>, String> {
    let mut ports = Vec::new();
    for (line, wait_s) in &sabotage.setup {
        ports.push(send_raw(sim, "arms", line).await?);
        sim.clock().sleep_s(*wait_s).await;
    }
    Ok(ports)
}

/// The saboteur of the run, if `sabotage` has one: a task that watches the arms every 20 ms (simulated) and resets
/// the detector's controller once the light arm sits still between it and its home.
pub(super) fn spawn_saboteur(
    sim: &SimInstrument,
    sabotage: &Sabotage,
) -> Option<tokio::task::JoinHandle<Result<Reset, String>>> {
    sabotage.reset_detector_behind_light.then(|| {
        let sim = sim.clone();
        tokio::spawn(async move {
            let clock = sim.clock();
            let mut before = sim.pose();
            loop {
                clock.sleep_s(0.02).await;
                let now = sim.pose();
                if light_between_detector_and_home(&before, &now) {
                    let at = sim.now_s();
                    return send_raw(&sim, "arms", "2RS").await.map(|port| (at, now, port));
                }
                before = now;
            }
        })
    })
}

/// Light arm still (from `a` to `b`) and strictly between the detector arm and 0, the detector clear of it.
fn light_between_detector_and_home(a: &Pose, b: &Pose) -> bool {
    let still = (a.light_deg - b.light_deg).abs() < 1e-9 && (a.detector_deg - b.detector_deg).abs() < 1e-9;
    let (l, d) = (b.light_deg, b.detector_deg);
    still && l.signum() == d.signum() && l.abs() >= 5.0 && d.abs() >= l.abs() + 10.0
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pose(light_deg: f64, detector_deg: f64) -> Pose {
        Pose {
            light_deg,
            detector_deg,
            ..Pose::default()
        }
    }

    #[test]
    fn the_saboteur_strikes_only_with_the_light_arm_still_between_the_detector_and_home() {
        let at = |l, d| light_between_detector_and_home(&pose(l, d), &pose(l, d));
        assert!(at(30.0, 60.0) && at(-20.0, -50.0));
        // Opposite sides, the light arm too close to home or to the detector, the detector nearer home.
        assert!(!at(-30.0, 60.0) && !at(2.0, 60.0) && !at(30.0, 35.0) && !at(60.0, 30.0));
        // Moving.
        assert!(!light_between_detector_and_home(
            &pose(29.0, 60.0),
            &pose(30.0, 60.0)
        ));
    }

    #[test]
    fn fixed_cases_edit_the_fixed_campaign_or_say_why_not() {
        let c = fixed_case(
            &[("bands_nm = [650.0]", "bands_nm = [450.0]")],
            FaultLevel::NONE,
            Vec::new(),
        )
        .expect("applies");
        assert!(c.campaign.contains("bands_nm = [450.0]") && !c.campaign.contains("650.0"));
        assert!(fixed_case(&[("no such text", "x")], FaultLevel::NONE, Vec::new()).is_err());
        assert!(behind_light_case().campaign.contains(BEHIND_LIGHT_POINTS));
        assert!(!behind_light_case().campaign.contains(FIXED_GRID));
    }
}
