//! `gonio daemon` and `gonio ctl` end to end: the real binary on an ephemeral loopback port, a dry-run campaign
//! on the simulated instrument, driven through the command-line client. Every child process is killed at the
//! end of its test, even on failure (a guard with Drop), and every wait is bounded.

use std::path::Path;
use std::time::{Duration, Instant};

use gonio_testkit::daemon::{ctl, start_daemon, start_daemon_on};
use gonio_testkit::{CampaignText, gonio, text};
use rand::{Rng, SeedableRng};

/// A small dry-run campaign on the simulated instrument: `points` outgoing angles.
fn campaign(id: &str, points: usize) -> String {
    CampaignText::in_plane(id, points).to_string()
}

#[test]
fn ctl_submits_watches_and_downloads_a_campaign_from_a_running_daemon() {
    let dir = tempfile::tempdir().expect("tempdir");
    let daemon = start_daemon(&dir.path().join("data"), "1000", &[]);
    let file = dir.path().join("small.toml");
    std::fs::write(&file, campaign("small", 5)).expect("write campaign");

    let out = ctl(&daemon, &["submit", file.to_str().expect("path")], &[]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert!(
        text(&out.stdout).starts_with("submitted campaign 1"),
        "{}",
        text(&out.stdout)
    );

    let out = ctl(&daemon, &["watch", "1"], &[]);
    assert!(
        out.status.success(),
        "watch: {} {}",
        text(&out.stdout),
        text(&out.stderr)
    );
    let watched = text(&out.stdout);
    assert!(
        watched.lines().last().is_some_and(|l| l.contains("completed")),
        "{watched}"
    );

    let out = ctl(&daemon, &["status"], &[]);
    assert!(out.status.success());
    let status = text(&out.stdout);
    assert!(
        status.contains("completed") && status.contains("5/5") && status.contains("small"),
        "{status}"
    );
    let out = ctl(&daemon, &["status", "1"], &[]);
    assert!(text(&out.stdout).contains("points: 5/5"), "{}", text(&out.stdout));

    let csv_path = dir.path().join("points.csv");
    let out = ctl(
        &daemon,
        &["points", "1", "--out", csv_path.to_str().expect("path")],
        &[],
    );
    assert!(out.status.success(), "{}", text(&out.stderr));
    let csv = std::fs::read_to_string(&csv_path).expect("csv");
    let mut lines = csv.lines();
    assert!(
        lines
            .next()
            .is_some_and(|h| h.starts_with("index,band_nm,theta_i_deg")),
        "{csv}"
    );
    assert_eq!(lines.count(), 5);

    // Errors: the server's message and a non-zero exit.
    let out = ctl(&daemon, &["pause", "99"], &[]);
    assert!(!out.status.success());
    assert!(
        text(&out.stderr).contains("no campaign with id 99"),
        "{}",
        text(&out.stderr)
    );
    let out = ctl(&daemon, &["confirm", "1"], &[]);
    assert!(!out.status.success());
    assert!(text(&out.stderr).contains("409"), "{}", text(&out.stderr));
    let bad = dir.path().join("bad.toml");
    std::fs::write(&bad, "[campaign]\nid = \"bad\"\nspeed = 3\n").expect("write");
    let out = ctl(&daemon, &["submit", bad.to_str().expect("path")], &[]);
    assert!(!out.status.success());
    let err = text(&out.stderr);
    assert!(err.contains("400") && err.contains("bad.toml"), "{err}");
}

#[test]
fn listening_beyond_loopback_without_a_token_is_refused() {
    let dir = tempfile::tempdir().expect("tempdir");
    // The refusal comes before any socket is opened.
    let out = gonio()
        .args(["daemon", "--listen", "0.0.0.0:0", "--data"])
        .arg(dir.path())
        .env_remove("GONIO_TOKEN")
        .output()
        .expect("run gonio daemon");
    assert!(!out.status.success());
    let err = text(&out.stderr);
    assert!(err.contains("0.0.0.0:0") && err.contains("token"), "{err}");
    assert!(
        !dir.path().join("gonio.sqlite").exists(),
        "refused before opening the store"
    );
}

#[test]
fn with_a_token_ctl_needs_the_same_token() {
    let dir = tempfile::tempdir().expect("tempdir");
    let daemon = start_daemon(dir.path(), "1000", &[("GONIO_TOKEN", "e2e-token-123")]);
    let out = ctl(&daemon, &["status"], &[]);
    assert!(!out.status.success());
    assert!(text(&out.stderr).contains("401"), "{}", text(&out.stderr));
    let out = ctl(&daemon, &["--token", "wrong", "status"], &[]);
    assert!(!out.status.success());
    assert!(text(&out.stderr).contains("401"), "{}", text(&out.stderr));
    let out = ctl(&daemon, &["--token", "e2e-token-123", "status"], &[]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert!(text(&out.stdout).contains("no campaigns"));
    let out = ctl(&daemon, &["status"], &[("GONIO_TOKEN", "e2e-token-123")]);
    assert!(out.status.success(), "{}", text(&out.stderr));
}

#[test]
fn sigterm_stops_the_daemon_cleanly_and_the_campaign_resumes_on_restart() {
    let dir = tempfile::tempdir().expect("tempdir");
    let data = dir.path().join("data");
    let file = dir.path().join("long.toml");
    std::fs::write(&file, campaign("long", 14)).expect("write");
    let mut daemon = start_daemon(&data, "20", &[]);
    let out = ctl(&daemon, &["submit", file.to_str().expect("path")], &[]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    // Wait until it is running, then stop the daemon.
    let start = Instant::now();
    loop {
        let out = ctl(&daemon, &["status", "1"], &[]);
        let s = text(&out.stdout);
        if s.contains("state:  running") {
            break;
        }
        assert!(start.elapsed() < Duration::from_secs(60), "never ran: {s}");
        assert!(!s.contains("completed"), "too fast to interrupt: {s}");
        std::thread::sleep(Duration::from_millis(50));
    }
    let pid = nix::unistd::Pid::from_raw(i32::try_from(daemon.child.id()).expect("pid"));
    nix::sys::signal::kill(pid, nix::sys::signal::Signal::SIGTERM).expect("SIGTERM");
    let start = Instant::now();
    let status = loop {
        if let Some(status) = daemon.child.try_wait().expect("wait") {
            break status;
        }
        assert!(
            start.elapsed() < Duration::from_secs(30),
            "the daemon did not stop on SIGTERM"
        );
        std::thread::sleep(Duration::from_millis(20));
    };
    assert!(status.success(), "{status:?}");
    let last = daemon
        .stdout
        .recv_timeout(Duration::from_secs(5))
        .expect("a last line");
    assert_eq!(last, "gonio daemon stopped");
    drop(daemon);

    // Restarted, it resumes the interrupted campaign first and finishes it.
    let daemon = start_daemon(&data, "1000", &[]);
    let out = ctl(&daemon, &["watch", "1"], &[]);
    assert!(
        out.status.success(),
        "{} {}",
        text(&out.stdout),
        text(&out.stderr)
    );
    let csv = ctl(&daemon, &["points", "1"], &[]);
    let indices: Vec<String> = text(&csv.stdout)
        .lines()
        .skip(1)
        .filter_map(|l| l.split(',').next().map(str::to_string))
        .collect();
    assert_eq!(
        indices,
        (0..14).map(|i| i.to_string()).collect::<Vec<_>>(),
        "each point exactly once"
    );
}

/// An adaptive campaign: gold, one band, a budget of 120 points in passes of 20.
const ADAPTIVE: &str = r#"[campaign]
id = "adaptive"
[sample]
radius_mm = 12.5
[material]
preset = "gold"
[plan]
bands_nm = [550.0]
[plan.adaptive]
budget_points = 120
batch_points = 20
target_error = 0.0
first_pass_step_deg = 15.0
[plan.calibration]
dark_every_points = 50
reference_every_s = 60.0
reference_pose_deg = { light = -90.0, detector = 90.0 }
[acquisition]
averaging = 2
"#;

/// The embedded simulated instrument without noise and drift: every reading is the same function of the
/// geometry whenever it is taken, so an interrupted run must measure exactly what an uninterrupted one does.
fn noiseless_instrument(dir: &Path) -> std::path::PathBuf {
    let text = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config/instruments/simulated.toml"),
    )
    .expect("simulated.toml");
    let quiet = text
        .replace("drift_per_hour = 0.002", "drift_per_hour = 0.0")
        .replace("relative_noise = 1.0e-4", "relative_noise = 0.0")
        .replace("noise = true", "noise = false");
    assert_eq!(
        quiet.matches("= 0.0\n").count() - text.matches("= 0.0\n").count(),
        2,
        "{quiet}"
    );
    assert!(quiet.contains("noise = false"));
    let path = dir.join("noiseless.toml");
    std::fs::write(&path, quiet).expect("write");
    path
}

/// The committed points of campaign 1 in a daemon's store: (index, band, geometry) with the values' bits.
fn committed(data: &Path) -> Vec<(u64, u64, [u64; 4], Option<u64>)> {
    let Ok(store) = gonio_engine::store::Store::open(data) else {
        return Vec::new();
    };
    store
        .points(gonio_engine::store::CampaignId(1))
        .unwrap_or_default()
        .iter()
        .map(|p| {
            (
                p.index,
                p.band_nm.to_bits(),
                [p.theta_i_deg, p.phi_i_deg, p.theta_o_deg, p.phi_o_deg].map(f64::to_bits),
                p.brdf_sr.map(f64::to_bits),
            )
        })
        .collect()
}

/// Submit `ADAPTIVE` and wait for it to complete; the daemon is killed with SIGKILL once the store holds each of
/// `kills` points (ascending) and started again.
fn run_adaptive(data: &Path, instrument: &Path, kills: &[usize]) -> Vec<(u64, u64, [u64; 4], Option<u64>)> {
    let campaign = data.with_extension("toml");
    std::fs::write(&campaign, ADAPTIVE).expect("write");
    let mut daemon = start_daemon_on(data, "40", &[], Some(instrument));
    let out = ctl(&daemon, &["submit", campaign.to_str().expect("path")], &[]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    for &at in kills {
        let start = Instant::now();
        while committed(data).len() < at {
            assert!(
                start.elapsed() < Duration::from_secs(120),
                "never reached {at} points: {}",
                committed(data).len()
            );
            std::thread::sleep(Duration::from_millis(5));
        }
        let pid = nix::unistd::Pid::from_raw(i32::try_from(daemon.child.id()).expect("pid"));
        nix::sys::signal::kill(pid, nix::sys::signal::Signal::SIGKILL).expect("SIGKILL");
        let _ = daemon.child.wait();
        drop(daemon);
        daemon = start_daemon_on(data, "40", &[], Some(instrument));
    }
    let out = ctl(&daemon, &["watch", "1"], &[]);
    assert!(
        out.status.success(),
        "{} {}",
        text(&out.stdout),
        text(&out.stderr)
    );
    let status = text(&ctl(&daemon, &["status", "1"], &[]).stdout);
    assert!(status.contains("completed"), "{status}");
    committed(data)
}

#[test]
fn an_adaptive_campaign_killed_5_times_resumes_to_the_points_of_an_uninterrupted_run() {
    let dir = tempfile::tempdir().expect("tempdir");
    let instrument = noiseless_instrument(dir.path());
    let whole = run_adaptive(&dir.path().join("whole"), &instrument, &[]);
    // The whole budget is placed, beyond the first pass (22 geometries at a 15 degree step).
    assert_eq!(whole.len(), 120, "{whole:?}");
    assert!(whole.iter().all(|p| p.3.is_some()), "every point has a value");
    // Five kills at random moments (seeded), in the first pass and in later passes.
    let mut rng = rand::rngs::StdRng::seed_from_u64(15);
    let mut kills: Vec<usize> = (0..5).map(|_| rng.random_range(5..115)).collect();
    kills.sort_unstable();
    kills.dedup();
    let killed = run_adaptive(&dir.path().join("killed"), &instrument, &kills);
    // 0 lost, 0 duplicated (indices 0..n, each once), and the very same points: each pass was derived from the
    // committed points, as the uninterrupted run derived it.
    let indices: Vec<u64> = killed.iter().map(|p| p.0).collect();
    assert_eq!(indices, (0..killed.len() as u64).collect::<Vec<_>>());
    assert_eq!(killed.len(), whole.len(), "kills at {kills:?}");
    for (a, b) in whole.iter().zip(&killed) {
        assert_eq!(a, b, "kills at {kills:?}: the runs differ at point {}", a.0);
    }
}
