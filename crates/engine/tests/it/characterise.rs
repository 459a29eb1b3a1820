//! The characterisation (the meter's ranges, the instrument signature, the source's warm-up) on the simulated
//! realistic instrument with every effect, on seeds of our own: each estimate against the simulator's hidden
//! truth, which only this test reads.

use gonio_engine::align::{AlignOptions, AlignmentReport};
use gonio_engine::characterise::CharacteriseOptions;
use gonio_instrument::InstrumentFile;
use gonio_simulator::imperfections::HiddenTruth;

use crate::common;

const REALISTIC: &str = include_str!("../../../../config/instruments/realistic.toml");

fn realistic(seed: u64) -> InstrumentFile {
    let text = REALISTIC.replace("seed = 16", &format!("seed = {seed}"));
    InstrumentFile::parse(&text, "realistic.toml").expect("valid")
}

/// The alignment with the characterisation, the mirror and then `sample` in the holder.
async fn characterise(file: &InstrumentFile, sample: &str) -> AlignmentReport {
    let options = AlignOptions {
        characterise: Some(CharacteriseOptions::default()),
        on_sample: false,
    };
    common::dry_run_alignment(file, "mirror", Some(sample), options)
        .await
        .1
        .expect("alignment and characterisation ran")
}

/// (what, estimate, its u, truth) for every characterisation estimate the simulator has a truth for.
fn compared(file: &InstrumentFile, r: &AlignmentReport) -> Vec<(String, f64, f64, f64)> {
    let hidden = HiddenTruth::draw(file).expect("imperfect");
    let det = hidden.detector.expect("detector truth");
    let c = r.characterisation.as_ref().expect("characterised");
    let ranges = c.detector.ranges.as_ref().expect("ranges fitted");
    let top = ranges.reference_range;
    let fs0 = ranges.ranges[0].full_scale_w;
    let mut out = Vec::new();
    for rc in &ranges.ranges {
        let t = det.ranges[rc.index];
        if rc.observable && rc.index != top {
            let relative_gain = (1.0 + t.gain) / (1.0 + det.ranges[top].gain) - 1.0;
            out.push((format!("gain {}", rc.index), rc.gain, rc.gain_u, relative_gain));
            out.push((
                format!("nonlinearity {}", rc.index),
                rc.nonlinearity,
                rc.nonlinearity_u,
                t.nonlinearity,
            ));
        }
        if rc.index > 0 {
            // Offsets are relative to range 0's, which a campaign's dark takes with it.
            let truth = t.offset_fs * rc.full_scale_w - det.ranges[0].offset_fs * fs0;
            out.push((format!("offset {}", rc.index), rc.offset_w, rc.offset_w_u, truth));
        }
    }
    for s in &c.detector.signature {
        for ((a, f), u) in s.alpha_deg.iter().zip(&s.brdf_sr).zip(&s.u_sr) {
            let truth = det.signature.at(a.to_radians());
            out.push((format!("signature {} nm at {a:.1} deg", s.band_nm), *f, *u, truth));
        }
    }
    let source = hidden.source.expect("source truth");
    let d = c.source.as_ref().expect("drift fitted");
    // The deficit at the first reading: the simulated source was switched on when the session started.
    let truth = source.warmup_fraction * (-d.first_s / source.warmup_time_s).exp();
    out.push((
        "warm-up deficit".into(),
        d.warmup_deficit,
        d.warmup_deficit_u,
        truth,
    ));
    out
}

#[tokio::test(start_paused = true)]
async fn the_characterisation_finds_the_hidden_detector_and_source_on_several_seeds() {
    let mut all = Vec::new();
    for seed in [16, 3, 101, 2027, 7] {
        let file = realistic(seed);
        let report = characterise(&file, "coloured-plastic").await;
        let c = report.characterisation.as_ref().expect("characterised");
        // Every range but the reference's nonlinearity is seen: the overlaps reach the smallest range on the
        // sample's reflection.
        let ranges = c.detector.ranges.as_ref().expect("ranges");
        let unseen: Vec<usize> = ranges
            .ranges
            .iter()
            .filter(|r| !r.observable && r.index != ranges.reference_range)
            .map(|r| r.index)
            .collect();
        assert!(unseen.is_empty(), "seed {seed}: ranges {unseen:?} not observable");
        assert!(
            c.sample_overlaps > 20,
            "seed {seed}: {} overlaps on the sample",
            c.sample_overlaps
        );
        assert_eq!(c.detector.signature.len(), 5, "a signature per open band");
        for (what, v, u, t) in compared(&file, &report) {
            assert!(u.is_finite() && u > 0.0, "seed {seed} {what}: u = {u}");
            all.push((seed, what, (v - t) / u));
        }
    }
    let within = all.iter().filter(|(_, _, z)| z.abs() <= 3.0).count();
    let outside: Vec<String> = all
        .iter()
        .filter(|(_, _, z)| z.abs() > 3.0)
        .map(|(s, w, z)| format!("seed {s} {w}: {z:.1} u"))
        .collect();
    eprintln!(
        "{within} of {} estimates within 3 u of the hidden value; outside: {outside:?}",
        all.len()
    );
    assert!(
        within as f64 >= 0.95 * all.len() as f64,
        "{within} of {} within 3 u; outside: {outside:?}",
        all.len()
    );
}

/// A meter whose every range is perfect and a source without warm-up: the characterisation says so within its
/// uncertainties (nothing invented).
#[tokio::test(start_paused = true)]
async fn an_ideal_meter_characterises_as_ideal() {
    let text = include_str!("../../../../config/instruments/simulated.toml");
    let file = InstrumentFile::parse(text, "simulated.toml").expect("valid");
    let report = characterise(&file, "coloured-plastic").await;
    let c = report.characterisation.as_ref().expect("characterised");
    let ranges = c.detector.ranges.as_ref().expect("ranges");
    for r in ranges.ranges.iter().filter(|r| r.observable) {
        assert!(r.gain.abs() <= 3.0 * r.gain_u.max(1e-6), "{r:?}");
        assert!(r.nonlinearity.abs() <= 3.0 * r.nonlinearity_u.max(1e-6), "{r:?}");
    }
    for s in &c.detector.signature {
        for (f, u) in s.brdf_sr.iter().zip(&s.u_sr) {
            assert!(
                f.abs() <= 3.0 * u.max(1e-9) + 1e-9,
                "{} nm: {f} +- {u}",
                s.band_nm
            );
        }
    }
}
