//! Progress reports and the ETA: the predicted time left, scaled by how the instrument keeps to the prediction.

use super::*;

/// Predicted seconds of steps measured before the ETA follows the instrument's own pace ([`Run::eta_pace`]).
const ETA_PACE_AFTER_S: f64 = 30.0;

impl Run<'_> {
    /// Report progress with the ETA: the predicted time left (the rest of this pass, then the rest of an
    /// adaptive plan's budget), scaled by how this run has kept to the prediction so far ([`Run::eta_pace`]).
    /// `next_start_s`: the predicted start of the pass's next step; None at the end of a pass.
    pub(super) fn progress(&mut self, next_start_s: Option<f64>) {
        let later = self.total.saturating_sub(self.pass_end) as f64 * self.s_per_point;
        // Only a measured point anchors the pace: a report at the start of a run or of a pass has none behind it.
        let predicted_now = self.pass_start_s + next_start_s.unwrap_or(self.pass_total_s);
        let pace = if next_start_s.is_some() || self.eta_anchor.is_some() {
            self.eta_pace(predicted_now)
        } else {
            1.0
        };
        let eta_s = match next_start_s {
            Some(s) => Some(pace * ((self.pass_total_s - s).max(0.0) + later)),
            // The end of an adaptive plan's pass: the passes to come (none when it has stopped).
            None if self.c.adaptive.is_some() && self.s_per_point > 0.0 => Some(pace * later),
            None => None,
        };
        self.control.emit(Event::Progress {
            campaign: self.id,
            done: self.done,
            total: self.total,
            eta_s,
        });
    }

    /// How many seconds the instrument has taken per predicted second since this run's first point (1 until
    /// [`ETA_PACE_AFTER_S`] of predicted steps are behind it), within [0.5, 2]: a real instrument slower or faster
    /// than its file, or a dry-run of hardware that differs from it, corrects its ETA as it goes. A resumed run
    /// learns afresh (its own steps are what it knows of the instrument today).
    fn eta_pace(&mut self, predicted_now_s: f64) -> f64 {
        let now = self.t();
        let Some((t0, p0)) = self.eta_anchor else {
            self.eta_anchor = Some((now, predicted_now_s));
            return 1.0;
        };
        let span = predicted_now_s - p0;
        if span < ETA_PACE_AFTER_S {
            return 1.0;
        }
        ((now - t0) / span).clamp(0.5, 2.0)
    }
}
