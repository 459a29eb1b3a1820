//! `gonio ctl`'s console commands against a running `gonio daemon` on the simulated instrument: state (text and
//! JSON), home, move by axis and by geometry, jog, filter, read (counted and streamed), refusals that name
//! their rule and move nothing, and refusal while a campaign runs.

use gonio_testkit::daemon::{Daemon, ctl, start_daemon};
use gonio_testkit::text;
use serde_json::Value;

fn ok(daemon: &Daemon, args: &[&str]) -> String {
    let out = ctl(daemon, args, &[]);
    assert!(
        out.status.success(),
        "gonio ctl {args:?}: {} {}",
        text(&out.stdout),
        text(&out.stderr)
    );
    text(&out.stdout)
}

fn refused(daemon: &Daemon, args: &[&str]) -> String {
    let out = ctl(daemon, args, &[]);
    assert!(
        !out.status.success(),
        "gonio ctl {args:?} should fail: {}",
        text(&out.stdout)
    );
    text(&out.stderr)
}

fn position(state: &Value, axis: &str) -> f64 {
    state["axes"]
        .as_array()
        .and_then(|a| a.iter().find(|a| a["name"] == axis))
        .and_then(|a| a["position_deg"].as_f64())
        .unwrap_or_else(|| panic!("no {axis} in {state}"))
}

fn state_json(daemon: &Daemon) -> Value {
    serde_json::from_str(&ok(daemon, &["state", "--json"])).expect("one JSON object")
}

#[test]
fn ctl_drives_the_console_of_a_running_daemon() {
    let dir = tempfile::tempdir().expect("tempdir");
    // 50 simulated seconds a second: the demo campaign below runs for seconds, long enough to meet it running.
    let daemon = start_daemon(&dir.path().join("data"), "50", &[]);

    let err = refused(&daemon, &["move", "detector=40"]);
    assert!(err.contains("not referenced"), "{err}");
    ok(&daemon, &["home"]);
    let s = state_json(&daemon);
    assert_eq!(s["axes"].as_array().map(Vec::len), Some(4), "{s}");

    let out = ok(&daemon, &["move", "light=-30", "detector=40"]);
    assert!(out.contains("detector 40.0"), "{out}");
    let s = state_json(&daemon);
    assert!(
        (position(&s, "light") + 30.0).abs() < 0.01 && (position(&s, "detector") - 40.0).abs() < 0.01,
        "{s}"
    );

    let out = ok(&daemon, &["jog", "detector", "-5"]);
    assert!(out.contains("detector 35.0"), "{out}");
    ok(&daemon, &["move", "--geometry", "40,0,20,180"]);

    // Refusals name the instrument file's key; nothing moves.
    let before = state_json(&daemon)["axes"].clone();
    let err = refused(&daemon, &["move", "detector=150"]);
    assert!(
        err.contains("axes.detector.max_deg") && err.contains("nothing moved"),
        "{err}"
    );
    let err = refused(&daemon, &["move", "--geometry", "89,0,30,180"]);
    assert!(err.contains("safety.grazing_limit_deg"), "{err}");
    let err = refused(&daemon, &["move", "elbow=3"]);
    assert!(err.contains("no axis named"), "{err}");
    assert_eq!(state_json(&daemon)["axes"], before, "refusals moved nothing");

    let out = ok(&daemon, &["filter", "550nm"]);
    assert!(out.contains("position"), "{out}");
    assert_eq!(state_json(&daemon)["wheel"]["band_nm"].as_f64(), Some(550.0));
    let text_state = ok(&daemon, &["state"]);
    assert!(
        text_state.contains("550 nm") && text_state.contains("axis detector"),
        "{text_state}"
    );

    let out = ok(&daemon, &["read", "--count", "3"]);
    assert_eq!(out.lines().filter(|l| l.contains(" W ")).count(), 3, "{out}");
    let out = ok(
        &daemon,
        &["read", "--count", "2", "--stream", "--interval-ms", "50"],
    );
    assert_eq!(out.lines().filter(|l| l.contains(" W ")).count(), 2, "{out}");
    assert!(out.contains("550 nm"), "{out}");

    // While a campaign owns the instrument the console is refused, naming it.
    let demo = concat!(env!("CARGO_MANIFEST_DIR"), "/../../config/campaigns/demo.toml");
    ok(&daemon, &["submit", demo]);
    let mut seen_refusal = false;
    for _ in 0..200 {
        let out = ctl(&daemon, &["jog", "tilt", "1"], &[]);
        if !out.status.success() {
            let err = text(&out.stderr);
            assert!(err.contains("campaign 1") && err.contains("demo"), "{err}");
            seen_refusal = true;
            break;
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    assert!(
        seen_refusal,
        "the console was never refused while the campaign ran"
    );
    ok(&daemon, &["abort", "1"]);
}
