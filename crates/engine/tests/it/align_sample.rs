//! Alignment on the sample itself (crate::align::sample_tilt) on the simulated realistic instrument: the
//! sample's own tilt as it sat against the simulator's hidden truth (the holder's tilt plus that mounting's
//! seating), and the refusal of a sample with no specular peak.

use gonio_engine::align::{AlignOptions, AlignmentReport};
use gonio_instrument::InstrumentFile;
use gonio_simulator::imperfections::HiddenTruth;

use crate::common;

const REALISTIC: &str = include_str!("../../../../config/instruments/realistic.toml");

/// The alignment on the mirror and then on `sample`; the report and the true tilt of the sample as it sat
/// (the holder's tilt plus its mounting's seating, deg), or the refusal.
async fn align_on(seed: u64, sample: &str) -> Result<(AlignmentReport, [f64; 2]), String> {
    let text = REALISTIC.replace("seed = 16", &format!("seed = {seed}"));
    let file = InstrumentFile::parse(&text, "realistic.toml").expect("valid");
    let options = AlignOptions {
        characterise: None,
        on_sample: true,
    };
    let (rig, report) = common::dry_run_alignment(&file, "mirror", Some(sample), options).await;
    let report = report?;
    // The sample is what the holder shows at the end.
    let seat = rig.optics().expect("optics").seating().1;
    let g = HiddenTruth::draw(&file)
        .expect("imperfect")
        .geometry
        .expect("geometry");
    Ok((
        report,
        [g.sample_tilt.x_deg + seat.x_deg, g.sample_tilt.y_deg + seat.y_deg],
    ))
}

#[tokio::test(start_paused = true)]
async fn aligning_on_the_sample_finds_its_own_tilt_not_the_mirrors() {
    let (mut cases, mut outside) = (0, 0);
    let mut lines = Vec::new();
    for seed in [16u64, 3, 101, 2027, 7] {
        let (r, truth) = align_on(seed, "coloured-plastic").await.expect("aligned");
        for (k, name) in ["sample_own_tilt_x_deg", "sample_own_tilt_y_deg"]
            .iter()
            .enumerate()
        {
            let e = r.get(name).expect(name);
            let z = (e.value - truth[k]) / e.u;
            let mirror = r.get(&name.replace("_own", "")).expect("mirror's").value;
            lines.push(format!(
                "seed {seed} {name}: {:.5} +- {:.5}, truth {:.5} (z {z:.1}); the mirror's {mirror:.5}",
                e.value, e.u, truth[k]
            ));
            assert!(e.u < 0.003, "{}", lines.join("\n"));
            cases += 1;
            if z.abs() > 3.0 {
                outside += 1;
            }
        }
    }
    eprintln!("{}", lines.join("\n"));
    // Ten estimates: at most one beyond 3 u.
    assert!(
        outside <= 1,
        "{outside} of {cases} beyond 3 u:\n{}",
        lines.join("\n")
    );
}

#[tokio::test(start_paused = true)]
async fn a_sample_with_no_specular_peak_is_refused_with_the_cause() {
    let e = align_on(16, "spectralon").await.expect_err("refused");
    assert!(e.contains("no specular peak"), "{e}");
    assert!(e.contains("sample's specular lobe"), "{e}");
}
