//! An adaptive plan's rehearsals (gonio_campaign::rehearsal): the mean of draws with a reading's noise, the same
//! every time, one draw where the instrument file states no noise.

use std::path::Path;

use gonio_campaign::rehearsal::{DRAWS, reading_noise};
use gonio_campaign::{Sources, load_and_prepare};
use gonio_instrument::InstrumentFile;

/// config/campaigns/adaptive.toml on white styrofoam, 150 points in passes of 25.
fn styrofoam() -> String {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config/campaigns");
    let text = std::fs::read_to_string(dir.join("adaptive.toml")).expect("adaptive.toml");
    let text = text
        .replace("budget_points = 300", "budget_points = 150")
        .replace("batch_points = 40", "batch_points = 25")
        .replace("preset = \"gold\"", "preset = \"white-styrofoam\"");
    assert!(text.contains("white-styrofoam") && text.contains("budget_points = 150"));
    text
}

#[test]
fn the_rehearsals_are_the_mean_of_noisy_draws_the_same_every_time() {
    let file = InstrumentFile::simulated();
    let text = styrofoam();
    let a = load_and_prepare(&text, "s.toml", &Sources::Stored, &file).expect("prepares");
    let b = load_and_prepare(&text, "s.toml", &Sources::Stored, &file).expect("prepares");
    let (ra, rb) = (
        a.rehearsal().expect("rehearsed"),
        b.rehearsal().expect("rehearsed"),
    );
    assert_eq!(ra, rb, "deterministic draws");
    assert_eq!(ra.draws, DRAWS);
    assert_eq!(ra.points, 150);
    assert_eq!(a.predicted_s(), ra.mean_s);
    // The draws differ, but only in where the passes fall: by seconds, not tens of them.
    assert!(
        ra.spread_s > 0.0 && ra.spread_s < 0.03 * ra.mean_s,
        "spread {} s of {} s",
        ra.spread_s,
        ra.mean_s
    );
    // The noise is the file's: the source's relative noise over the square root of the averaging (10 here).
    let noise = reading_noise(&file.instrument, 10);
    assert!((noise - file.instrument.source.relative_noise / 10f64.sqrt()).abs() < 1e-15);

    // An instrument file that states no noise: every draw would be the same, one is made.
    let mut quiet = InstrumentFile::simulated();
    quiet.instrument.source.relative_noise = 0.0;
    let q = load_and_prepare(&text, "s.toml", &Sources::Stored, &quiet).expect("prepares");
    let rq = q.rehearsal().expect("rehearsed");
    assert_eq!((rq.draws, rq.spread_s, rq.points), (1, 0.0, 150));
    assert!(
        (rq.mean_s - ra.mean_s).abs() < 0.05 * ra.mean_s,
        "exact values {} s, noisy draws {} s",
        rq.mean_s,
        ra.mean_s
    );
}

#[test]
fn a_fixed_plan_has_no_rehearsal() {
    let file = InstrumentFile::simulated();
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../config/campaigns");
    let text = std::fs::read_to_string(dir.join("demo.toml")).expect("demo.toml");
    let p = load_and_prepare(&text, "demo.toml", &Sources::Local(dir), &file).expect("prepares");
    assert!(p.rehearsal().is_none());
    assert_eq!(p.predicted_s(), p.schedule.breakdown.total_s());
}
