//! Paths in campaign files (issues #6, #8): a local campaign names files relative to its own directory and is
//! stored with the materials they resolved to, so that running and resuming read no file; a campaign submitted
//! to the daemon may only name presets or files inside its data directory (no `..`, no absolute path or symbolic
//! link leading outside), refused with a 400 and a message naming file, line and key.

use crate::common;

use std::path::Path;
use std::sync::{Arc, Mutex};

use axum::http::StatusCode;
use gonio_engine::store::{CampaignState, Store};
use gonio_engine::{Control, Event, Rig, prepare_campaign, prepare_submitted_campaign, run_campaign};
use gonio_instrument::{InstrumentFile, SIMULATED_INSTRUMENT_TOML};

const WHITE: &str = "[material]\nmodel = \"lambertian\"\nalbedo = 0.95\n";

/// A small relative dry-run naming `reference`; `[material]` as given.
fn campaign(reference: &str, material: &str) -> String {
    format!(
        r#"[campaign]
id = "paths"

[sample]
radius_mm = 12.5

[plan]
bands_nm = [550.0]
reciprocity = false

[plan.grid]
kind = "in-plane"
theta_i_deg = [30.0]
theta_o_deg = {{ from = 10.0, to = 60.0, step = 10.0 }}

[calibration]
method = "relative"
reference = "{reference}"
simulate_operator = true

[acquisition]
averaging = 2

[material]
{material}
"#
    )
}

fn write(dir: &Path, name: &str, text: &str) {
    let p = dir.join(name);
    std::fs::create_dir_all(p.parent().expect("parent")).expect("mkdir");
    std::fs::write(p, text).expect("write");
}

fn line(text: &str, needle: &str) -> usize {
    text.lines().position(|l| l.contains(needle)).expect("needle") + 1
}

#[tokio::test(start_paused = true)]
async fn a_local_campaign_resolves_its_files_once_and_resumes_without_them() {
    let file = InstrumentFile::simulated();
    let campaign_dir = tempfile::tempdir().expect("tempdir");
    write(campaign_dir.path(), "standards/white.toml", WHITE);
    let text = campaign("standards/white.toml", "preset = \"gold\"");
    // The process's directory (the crate) has no standards/: the name resolves against the campaign's.
    assert!(!Path::new("standards/white.toml").exists());
    let prepared = prepare_campaign(&text, "paths.toml", campaign_dir.path(), &file).expect("valid");
    let new = prepared.new_campaign(&text, SIMULATED_INSTRUMENT_TOML);
    assert!(
        new.campaign_toml.starts_with(&text),
        "the file's text is kept as written"
    );
    assert!(
        new.campaign_toml.contains("[resolved.reference]") && new.campaign_toml.contains("albedo = 0.95"),
        "{}",
        new.campaign_toml
    );
    assert!(new.campaign_toml.contains("[resolved.material]"));

    let data = tempfile::tempdir().expect("tempdir");
    let mut store = Store::open(data.path()).expect("store");
    let id = store.create_campaign(&new).expect("create");
    let store = Arc::new(Mutex::new(store));
    // The reference file goes away (and with it the whole directory): the stored campaign does not need it.
    drop(campaign_dir);

    let rig = Rig::connect_with_time_scale(&file, None, 1.0).await.expect("rig");
    let control = Control::new();
    let mut rx = control.subscribe();
    let task = {
        let (store, rig, control) = (Arc::clone(&store), rig.clone(), control.clone());
        tokio::spawn(async move { run_campaign(store, id, &rig, control).await })
    };
    loop {
        if let Event::Point { point, .. } = rx.recv().await.expect("event")
            && point.index >= 1
        {
            break;
        }
    }
    control.pause();
    assert_eq!(task.await.expect("join").expect("run"), CampaignState::Paused);
    let first = store.lock().expect("lock").points(id).expect("points");
    assert!(!first.is_empty() && (first.len() as u64) < prepared.total_points);

    let state = run_campaign(Arc::clone(&store), id, &rig, Control::new())
        .await
        .expect("resume reads no file");
    assert_eq!(state, CampaignState::Completed);
    // As committed: a completed campaign's corrections are read apart from the rows (gonio_engine::budget).
    let all = store.lock().expect("lock").committed_points(id).expect("points");
    assert_eq!(all.len() as u64, prepared.total_points);
    assert_eq!(
        &all[..first.len()],
        &first[..],
        "points before the pause are untouched"
    );
    for p in all.iter().filter(|p| p.flags.is_empty()) {
        let (f, u, t) = (
            p.brdf_sr.expect("f"),
            p.brdf_u_sr.expect("u"),
            p.truth_aperture_sr.expect("truth"),
        );
        // The reference's 0.5 % calibration uncertainty is in u.
        assert!((f - t).abs() <= 3.0 * u, "point {}: {f} vs {t} (u {u})", p.index);
    }
}

#[test]
fn submitted_campaigns_name_only_presets_or_files_inside_the_data_directory() {
    let file = InstrumentFile::simulated();
    let data = tempfile::tempdir().expect("tempdir");
    let outside = tempfile::tempdir().expect("tempdir");
    write(data.path(), "standards/white.toml", WHITE);
    write(outside.path(), "white.toml", WHITE);
    let submit = |text: &str| prepare_submitted_campaign(text, "submitted.toml", data.path(), &file);

    // Inside: by a relative name, by an absolute one, and presets.
    submit(&campaign("standards/white.toml", "preset = \"gold\"")).expect("inside");
    let abs = data.path().join("standards/white.toml").display().to_string();
    submit(&campaign(&abs, "preset = \"gold\"")).expect("absolute, inside");
    submit(&campaign("spectralon", "preset = \"gold\"")).expect("a preset");

    let refused = |text: &str, key_line: &str, key: &str| {
        let e = submit(text).expect_err(text).to_string();
        let at = format!("submitted.toml:{}: {key}:", line(text, key_line));
        assert!(e.starts_with(&at), "expected {at:?} in {e}");
        assert!(e.contains("data directory"), "{e}");
        e
    };
    let text = campaign("../outside/white.toml", "preset = \"gold\"");
    let e = refused(&text, "reference =", "[calibration] reference");
    assert!(e.contains("`..`"), "{e}");
    let abs_outside = outside.path().join("white.toml").display().to_string();
    let text = campaign(&abs_outside, "preset = \"gold\"");
    refused(&text, "reference =", "[calibration] reference");
    // A name that is neither a preset nor a file inside.
    let text = campaign("whiteish", "preset = \"gold\"");
    let e = refused(&text, "reference =", "[calibration] reference");
    assert!(e.contains("nor is it a preset"), "{e}");
    #[cfg(unix)]
    {
        std::os::unix::fs::symlink(outside.path().join("white.toml"), data.path().join("link.toml"))
            .expect("symlink");
        let text = campaign("link.toml", "preset = \"gold\"");
        let e = refused(&text, "reference =", "[calibration] reference");
        assert!(e.contains("symbolic link"), "{e}");
        // A directory link that leads out, with the file named through it.
        std::os::unix::fs::symlink(outside.path(), data.path().join("elsewhere")).expect("symlink");
        let text = campaign("elsewhere/white.toml", "preset = \"gold\"");
        refused(&text, "reference =", "[calibration] reference");
    }
    // A measured material's data file: checked before anything is read.
    let measured = format!(
        "model = \"measured\"\nfile = \"{}\"\nformat = \"merl\"\nchannel = \"red\"",
        outside.path().join("gold.binary").display()
    );
    let text = campaign("spectralon", &measured);
    refused(&text, "file =", "[material] file");
    // ... also when the file naming it is inside (a reference material file pointing out).
    write(
        data.path(),
        "standards/measured.toml",
        "[material]\nmodel = \"measured\"\nfile = \"../../x.binary\"\nformat = \"merl\"\nchannel = \"red\"\n",
    );
    let text = campaign("standards/measured.toml", "preset = \"gold\"");
    let e = refused(&text, "reference =", "[calibration] reference");
    assert!(e.contains("measured.toml: [material] file"), "{e}");
    // `[resolved]` is gonio's own: a submission may not bring it (it would name files unchecked).
    let text = format!(
        "{}\n[resolved.material]\nmodel = \"lambertian\"\nalbedo = 0.5\n",
        campaign("spectralon", "preset = \"gold\"")
    );
    let e = submit(&text).expect_err("resolved").to_string();
    assert!(
        e.starts_with(&format!("submitted.toml:{}:", line(&text, "[resolved"))) && e.contains("resolved"),
        "{e}"
    );
}

#[tokio::test(start_paused = true)]
async fn the_daemon_refuses_paths_outside_its_data_directory_with_a_400() {
    let data = tempfile::tempdir().expect("tempdir");
    write(data.path(), "standards/white.toml", WHITE);
    let app = common::app(data).await;

    let text = campaign("../../etc/passwd", "preset = \"gold\"");
    let (status, body) = app.json("POST", "/api/campaigns", &text).await;
    assert_eq!(status, StatusCode::BAD_REQUEST, "{body}");
    let message = body["error"].as_str().expect("error");
    assert!(
        message.contains(&format!(
            ":{}: [calibration] reference",
            line(&text, "reference =")
        )),
        "{message}"
    );
    assert!(
        message.contains("`..`") && message.contains("data directory"),
        "{message}"
    );

    // Inside the data directory: accepted and run to completion.
    let (status, body) = app
        .json(
            "POST",
            "/api/campaigns",
            &campaign("standards/white.toml", "preset = \"gold\""),
        )
        .await;
    assert_eq!(status, StatusCode::CREATED, "{body}");
    let id = body["id"].as_u64().expect("id");
    for _ in 0..3600 {
        if app.state(id).await == "completed" {
            break;
        }
        tokio::time::sleep(std::time::Duration::from_secs(1)).await;
    }
    assert_eq!(app.state(id).await, "completed");
    assert!(app.rig.optics().is_some());
}
