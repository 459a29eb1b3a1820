//! The report's sections on the disk, HTTP abuse and safety soaks, and the rows of the summary table.

use super::*;

impl Report {
    /// The summary table's row of the HTTP abuse soak.
    pub(super) fn http_row(&self, m: &mut String) {
        let h = &self.http;
        let slow = h.header_tricklers.clients + h.body_tricklers.clients + h.idle.clients;
        let sent: u64 = h.oversized.iter().map(|o| o.sent).sum();
        let refused: u64 = h.oversized.iter().map(|o| o.refused_413 + o.closed).sum();
        let _ = writeln!(
            m,
            "| HTTP abuse | a {}-point campaign on the daemon, {} wall, {} timed status requests | {} slow or idle clients against a limit of {} connections ({} connections opened), {} oversized bodies | {} of {} status requests answered within {} s (slowest {:.0} ms), {} of {} oversized bodies refused, campaign {} with {} rows |",
            h.campaign.total_points,
            secs(h.campaign_wall_s),
            h.probes(),
            slow,
            h.max_connections,
            h.header_tricklers.connections + h.body_tricklers.connections + h.idle.connections,
            sent,
            h.probe_latencies_s.len(),
            h.probes(),
            h.deadline_s,
            h.latency_quantile_s(1.0) * 1e3,
            refused,
            sent,
            h.final_state
                .map(|s| s.to_string())
                .unwrap_or_else(|| "missing".into()),
            h.committed.rows
        );
    }

    pub(super) fn disk_section(&self, m: &mut String) {
        let d = &self.disk;
        let _ = writeln!(m, "## Disk trouble\n");
        let _ = writeln!(
            m,
            "A {}-point dry-run campaign (the soak campaign of `crates/soak/src/setup.rs`, no device faults) through \
             the real engine and drivers on a paused tokio clock (`crates/soak/src/disk_soak.rs`). {} times, at \
             random points (seeded), the store is made full: capped at the pages it holds (`Store::set_max_pages`, \
             SQLite's `max_page_count`), so the next write that needs a page fails with SQLite's own SQLITE_FULL, as \
             on a full disk. The soak then waits {:.0} s of instrument time, checks that nothing moved (the pose, \
             and the simulator's record of every motion command), lifts the cap and resumes the campaign as an \
             operator would. The rows committed before each fill are read with SQLite directly and compared byte for \
             byte at the pause and at the end.\n",
            d.campaign.total_points,
            d.fills.len(),
            d.config.hold_s
        );
        let _ = writeln!(
            m,
            "| # | capped after row | cap (pages) | the run ended | reason (state event; store record) | rows at the pause | move commands while paused | largest pose change | committed rows at the pause |"
        );
        let _ = writeln!(m, "|---|---|---|---|---|---|---|---|---|");
        let first_reason = d.fills.first().and_then(|f| f.reason.clone());
        for (i, f) in d.fills.iter().enumerate() {
            let reason = match &f.reason {
                None => "NONE".to_string(),
                Some(r) if i > 0 && Some(r) == first_reason.as_ref() => "as #1".to_string(),
                Some(r) => format!("`{}`", r.replace('|', "/")),
            };
            let _ = writeln!(
                m,
                "| {} | {} | {} | {} | {}; {} | {} | {} over {:.0} s | {} deg | {} |",
                i + 1,
                f.rows_at_cap,
                f.cap_pages,
                f.ended,
                reason,
                if f.record_agrees { "the same" } else { "DIFFERENT" },
                f.rows_at_pause,
                f.moves_while_paused,
                f.paused_s,
                f.pose_change_deg,
                f.changed_at_pause
                    .as_deref()
                    .map(|c| format!("CHANGED: {c}"))
                    .unwrap_or_else(|| "unchanged".into())
            );
        }
        let _ = writeln!(
            m,
            "\nThe store fills when SQLite needs a new page, so the engine commits a few more points into the \
             pages' free space before the first write fails (rows at the pause >= rows at the cap); the point whose \
             commit failed is measured again after the resume.\n\nCampaign ended **{}**, {} rows for {} planned \
             points (indices in order: {}; each planned point exactly once), **{} committed rows changed or lost** by the end; {} points valid against the ground \
             truth, {} silently wrong, {} without value or reason; {:.0} s of instrument time, {} wall.\n",
            d.final_state,
            d.committed.rows,
            d.campaign.total_points,
            d.committed.indices_in_order,
            d.changed.len(),
            d.committed.points.valid,
            d.committed.points.wrong.len(),
            d.committed.points.unexplained.len(),
            d.instrument_s,
            secs(d.wall_s)
        );
    }

    pub(super) fn http_section(&self, m: &mut String) {
        let h = &self.http;
        let _ = writeln!(m, "## HTTP abuse\n");
        let _ = writeln!(
            m,
            "The daemon in process as `gonio daemon` runs it (store, simulated instrument at time scale {} on the \
             real clock, `Service` and `api::run_daemon` on a loopback port, on its own runtime), running a \
             {}-point campaign submitted over HTTP, while hostile clients on another runtime press on it over real \
             TCP connections (`crates/soak/src/http_abuse/`). The daemon's limits: {} connections at most (the \
             oldest idle one is closed to admit a newcomer), {} s to send request headers, {} s to send a body, \
             bodies of {} bytes at most. Each hostile client reconnects shortly after the daemon closes it. A status \
             client asks `GET /api/campaigns/{{id}}` on a new connection every 100 ms until the campaign is final; \
             deadline {} s per answer.\n",
            h.time_scale,
            h.campaign.total_points,
            h.max_connections,
            h.header_read_timeout_s,
            h.body_read_timeout_s,
            h.body_limit_bytes,
            h.deadline_s
        );
        let _ = writeln!(
            m,
            "| hostile clients | clients | connections opened | closed by the daemon without an answer | answered by the daemon before closing |"
        );
        let _ = writeln!(m, "|---|---|---|---|---|");
        for (name, a) in [
            ("slowloris: headers, one byte at a time", &h.header_tricklers),
            (
                format!(
                    "slow body: a {}-byte campaign announced, sent one byte at a time",
                    crate::http_abuse::slow_body_bytes(h.body_limit_bytes)
                )
                .as_str(),
                &h.body_tricklers,
            ),
            ("idle: connect, send nothing", &h.idle),
        ] {
            let answers = if a.answers.is_empty() {
                "none".to_string()
            } else {
                a.answers
                    .iter()
                    .map(|(s, n)| format!("{n} × {s}"))
                    .collect::<Vec<_>>()
                    .join(", ")
            };
            let _ = writeln!(
                m,
                "| {name} | {} | {} | {} | {answers} |",
                a.clients, a.connections, a.closed_without_answer
            );
        }
        let _ = writeln!(
            m,
            "\n| oversized body | sent | refused with 413 | connection closed before the body was taken | other answers | neither answered nor closed within {} s |",
            h.deadline_s
        );
        let _ = writeln!(m, "|---|---|---|---|---|---|");
        for (name, o) in [
            format!("announced: `Content-Length` of {} bytes", 10 * h.body_limit_bytes),
            format!("chunked: {} bytes", 2 * h.body_limit_bytes + 1),
            format!(
                "streamed: {} bytes under `Content-Length`",
                2 * h.body_limit_bytes + 1
            ),
        ]
        .iter()
        .zip(&h.oversized)
        {
            let _ = writeln!(
                m,
                "| {name} | {} | {} | {} | {} | {} |",
                o.sent,
                o.refused_413,
                o.closed,
                if o.other.is_empty() {
                    "none".to_string()
                } else {
                    format!("{:?}", o.other)
                },
                o.hung
            );
        }
        let _ = writeln!(
            m,
            "\nStatus requests: {} sent, {} answered 200 within {} s; latency median {:.1} ms, 99th percentile \
             {:.1} ms, slowest {:.1} ms (wall clock, on a machine shared with other jobs).{}\n",
            h.probes(),
            h.probe_latencies_s.len(),
            h.deadline_s,
            h.latency_quantile_s(0.5) * 1e3,
            h.latency_quantile_s(0.99) * 1e3,
            h.latency_quantile_s(1.0) * 1e3,
            if h.probe_failures.is_empty() {
                String::new()
            } else {
                format!(" Failures: {}.", h.probe_failures.join("; "))
            }
        );
        let _ = writeln!(
            m,
            "Campaign ended **{}**, {} rows for {} planned points (indices in order: {}), {} valid against the \
             ground truth, {} silently wrong, {} without value or reason; {} under attack.\n",
            h.final_state
                .map(|s| s.to_string())
                .unwrap_or_else(|| "missing".into()),
            h.committed.rows,
            h.campaign.total_points,
            h.committed.indices_in_order,
            h.committed.points.valid,
            h.committed.points.wrong.len(),
            h.committed.points.unexplained.len(),
            secs(h.campaign_wall_s)
        );
    }

    pub(super) fn safety_section(&self, m: &mut String) {
        let s = &self.safety;
        let [pauses, aborts, estops] = s.acts();
        let lat = s.estop_latencies_s();
        let [completed, aborted, paused, not_run] = s.final_states();
        let _ = writeln!(m, "## Safety under random plans and interruptions\n");
        let _ = writeln!(
            m,
            "{} random campaigns (seeded: explicit geometries with tilt and rotation, in-plane sweeps, isotropic \
             grids; one or two bands, repeats, darks and direct-beam readings at random cadences; a third of them \
             with stalled moves and garbled or lost replies; {} of them with one or two sweeps of either arm at \
             0.5 to 15 deg/s (`[[plan.sweeps]]`), half of those with no points, and one more emergency stop 20 to \
             120 s after the others, so that the interruptions land in sweeps too), each interrupted by up to five random requests (pause, \
             abort, emergency stop, at random instants, resumed after a random wait), run by the real engine on the \
             simulated instrument on a paused clock (`crates/soak/src/safety_soak/`, also run by the tests in \
             `crates/soak/tests/safety_soak.rs`). Every check reads the simulator's record of what reached each \
             device over the wire and of each axis's exact trajectory (quadratic pieces, motor and load with \
             backlash).\n",
            s.cases.len(),
            s.sweep_cases()
        );
        let (axis, target, limit) = s
            .extreme_command()
            .unwrap_or_else(|| ("none".into(), f64::NAN, f64::NAN));
        let median = lat.get(lat.len() / 2).copied().unwrap_or(f64::NAN);
        let _ = writeln!(m, "| rule | measured (cases where it held) | bound | result |");
        let _ = writeln!(m, "|---|---|---|---|");
        let ok = |rule: Rule| match s.broke(rule) {
            0 => "held".to_string(),
            k => format!("**BROKEN in {k} cases** (see Verdict)"),
        };
        let _ = writeln!(
            m,
            "| arm separation at every instant once apart; before that, only growing | closest once apart: motors {:.3} deg, loads (backlash) {:.3} deg | >= {} deg | {} |",
            s.closest_motor_deg(),
            s.closest_load_deg(),
            s.min_separation_deg,
            ok(Rule::Separation)
        );
        let _ = writeln!(
            m,
            "| commanded targets and trajectories within the limits | nearest commanded target: {axis} to {target:.3} deg (limit {limit} deg), {:.3} deg inside; nearest trajectory {:.3} deg inside | >= 0 deg | {} |",
            s.command_margin_deg(),
            s.trajectory_margin_deg(),
            ok(Rule::Limits)
        );
        let _ = writeln!(
            m,
            "| emergency stop: request to stop command at each axis (simulated clock), then no move before the resume | {} stops: median {:.2} ms, slowest {:.2} ms | <= {:.0} ms | {} |",
            lat.len(),
            median * 1e3,
            lat.last().copied().unwrap_or(f64::NAN) * 1e3,
            ESTOP_DEADLINE_S * 1e3,
            ok(Rule::Estop)
        );
        let in_sweeps = s.estops_in_sweeps_s();
        let _ = writeln!(
            m,
            "| of which requested while a sweep's arm cruised (at the sweep's speed): request to stop at the last axis | {} stops: slowest {:.2} ms | <= {:.0} ms | {} |",
            in_sweeps.len(),
            in_sweeps.last().copied().unwrap_or(f64::NAN) * 1e3,
            ESTOP_DEADLINE_S * 1e3,
            ok(Rule::Estop)
        );
        let _ = writeln!(
            m,
            "| measured points: read-back pose allowed by the scheduler's constraints; sweep readings: their geometry allowed | {} points, {} sweep readings | — | {} |",
            s.cases.iter().map(|c| c.points).sum::<u64>(),
            s.sweep_readings(),
            ok(Rule::MeasuredPose)
        );
        let _ = writeln!(
            m,
            "\nThe simulated clock is tokio's paused clock: it advances only while every task waits, so the \
             emergency-stop latency counts the waits between the request and the stop on the wire (a reply awaited, \
             a port held by an exchange in flight), not the host's computing time; 0 ms means the stop went out \
             without waiting for anything."
        );
        let _ = writeln!(
            m,
            "\nRequests made: {pauses} pauses, {aborts} aborts, {estops} emergency stops; {} move and home \
             commands checked. Campaigns ended: {completed} completed, {aborted} aborted, {paused} paused by \
             device faults after the soak's resumes ran out (the motion checks apply all the same), {not_run} did \
             not run; {} wall.\n",
            s.move_commands(),
            secs(s.wall_s)
        );
        let _ = writeln!(
            m,
            "| case | faults | pauses / aborts / estops | ended | points | moves | closest arms, motors / loads (deg) | slowest estop (ms) |"
        );
        let _ = writeln!(m, "|---|---|---|---|---|---|---|---|");
        for c in &s.cases {
            let slowest = c.estop_latencies_s.iter().copied().fold(f64::NAN, f64::max);
            let _ = writeln!(
                m,
                "| {} | {} | {} / {} / {} | {} | {} of {} | {} | {} / {} | {} |",
                c.index,
                if c.faults { "yes" } else { "no" },
                c.acts[0],
                c.acts[1],
                c.acts[2],
                c.final_state
                    .map(|s| s.to_string())
                    .unwrap_or_else(|| "did not run".into()),
                c.points,
                c.planned_points,
                c.move_commands,
                deg_or_broken(c.closest_motor_deg),
                deg_or_broken(c.closest_load_deg),
                if slowest.is_nan() {
                    "—".to_string()
                } else {
                    format!("{:.2}", slowest * 1e3)
                }
            );
        }
        let _ = writeln!(m);
    }
}

/// The summary table's row of a fault soak.
pub(super) fn fault_row(m: &mut String, label: &str, f: &FaultSoakReport) {
    let _ = writeln!(
        m,
        "| {label} | {} points, {:.2} instrument hours, {} wall | {} garbled and {} dropped replies, {} stalled moves, {} disconnects of every device, {} replies delayed | {} valid, {} failed with a reason, {} silently wrong, campaign {} |",
        f.committed.rows,
        f.instrument_s / 3600.0,
        secs(f.wall_s),
        f.injected.garbled,
        f.injected.dropped,
        f.log.stalls_manifested,
        f.injected.outages,
        f.injected.delayed,
        f.committed.points.valid,
        f.committed.points.failed_total(),
        f.committed.points.wrong.len(),
        f.final_state
    );
}

/// The summary table's row of a crash soak.
pub(super) fn crash_row(m: &mut String, label: &str, c: &CrashSoakReport) {
    let _ = writeln!(
        m,
        "| {label} | {} points and {} sweep segments ({} sweep readings), {:.2} instrument hours, {} wall | {} × `kill -9` ({} mid-move, {} mid-commit, {} mid-sweep, {} start-up, {} random), {} restarts | {} rows for {} planned, {} sweep segments for {} planned with all their readings and none twice, {} committed rows changed, {} silently wrong, campaign {} |",
        c.committed.rows,
        c.sweeps.segments,
        c.sweeps.readings,
        c.instrument_s / 3600.0,
        secs(c.wall_s),
        c.kills(),
        c.kills_of("mid-move"),
        c.kills_of("mid-commit"),
        c.kills_of("mid-sweep"),
        c.kills_of("start-up"),
        c.kills_of("random"),
        c.rounds.len().saturating_sub(1),
        c.committed.rows,
        c.campaign.total_points,
        c.sweeps.segments - c.sweeps.incomplete.len() as u64,
        c.campaign.sweep_segments,
        c.changed.len(),
        c.committed.points.wrong.len(),
        c.final_state
            .map(|s| s.to_string())
            .unwrap_or_else(|| "missing".into())
    );
}

/// The summary table's row of a disk soak.
pub(super) fn disk_row(m: &mut String, label: &str, d: &DiskSoakReport) {
    let paused = d
        .fills
        .iter()
        .filter(|f| f.ended == gonio_engine::store::CampaignState::Paused)
        .count();
    let moves: u64 = d.fills.iter().map(|f| f.moves_while_paused).sum();
    let _ = writeln!(
        m,
        "| {label} | {} points, {:.2} instrument hours, {} wall | the store full (SQLITE_FULL) {} times, {:.0} s of instrument time each before room came back | paused {} of {} times with the store's path and SQLite's reason, {} move commands while paused, {} rows for {} planned, {} committed rows changed, campaign {} |",
        d.committed.rows,
        d.instrument_s / 3600.0,
        secs(d.wall_s),
        d.fills.len(),
        d.config.hold_s,
        paused,
        d.fills.len(),
        moves,
        d.committed.rows,
        d.campaign.total_points,
        d.changed.len(),
        d.final_state
    );
}

/// The summary table's row of a safety soak.
pub(super) fn safety_row(m: &mut String, label: &str, s: &SafetySoakReport) {
    let [pauses, aborts, estops] = s.acts();
    let lat = s.estop_latencies_s();
    let n = s.cases.len();
    let held = |rule: Rule| match s.broke(rule) {
        0 => format!("held in all {n} cases"),
        k => format!("**BROKEN in {k} of {n} cases**"),
    };
    let _ = writeln!(
        m,
        "| {label} | {} random campaigns ({} with sweeps: {} sweep readings), {} move commands, {} wall | {} pauses, {} aborts, {} emergency stops ({} during a sweep); device faults in {} cases | arm separation {} (closest once apart {:.3} deg, minimum {} deg); limits {} (closest commanded target {:.3} deg inside); emergency stop {} (slowest {:.1} ms, {:.1} ms during a sweep, deadline {:.0} ms) |",
        n,
        s.sweep_cases(),
        s.sweep_readings(),
        s.move_commands(),
        secs(s.wall_s),
        pauses,
        aborts,
        estops,
        s.estops_in_sweeps_s().len(),
        s.cases.iter().filter(|c| c.faults).count(),
        held(Rule::Separation),
        s.closest_motor_deg().min(s.closest_load_deg()),
        s.min_separation_deg,
        held(Rule::Limits),
        s.command_margin_deg(),
        held(Rule::Estop),
        lat.last().copied().unwrap_or(f64::NAN) * 1e3,
        s.estops_in_sweeps_s().last().copied().unwrap_or(f64::NAN) * 1e3,
        ESTOP_DEADLINE_S * 1e3
    );
}
