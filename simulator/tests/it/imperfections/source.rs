//! The source's imperfections, one at a time, against the models written out here (module doc of
//! simulator/src/imperfections/source.rs): the beam power at the sample on the ideal instrument (the
//! file's own drift and noise off) and with one source effect on.

use gonio_instrument::{InstrumentFile, SourceImperfections};

use super::{BAND_550, optics};

/// Beam power at the sample with the filter at T = 0.5 (W).
const P_BEAM_W: f64 = 1e-3 * 0.5;

fn file_with(source: SourceImperfections, seed: u64) -> InstrumentFile {
    let mut file = InstrumentFile::simulated();
    file.simulator.seed = seed;
    file.simulator.imperfections.source = source;
    file
}

#[test]
fn warm_up_approaches_the_settled_power_exponentially() {
    let o = optics(&file_with(
        SourceImperfections {
            warmup_fraction: 0.02,
            warmup_time_s: 600.0,
            ..Default::default()
        },
        3,
    ));
    for t in [0.0, 60.0, 600.0, 1800.0, 7200.0] {
        let expected = P_BEAM_W * (1.0 - 0.02 * (-t / 600.0f64).exp());
        let p = o.incident_power_w(&BAND_550, t);
        assert!(
            (p / expected - 1.0).abs() < 1e-12,
            "t {t}: {p:e} W, expected {expected:e} W"
        );
    }
}

#[test]
fn the_random_walk_spreads_as_the_square_root_of_time_across_instruments() {
    let s = 1e-3;
    let n = 300u32;
    let (mut var_1h, mut var_4h) = (0.0, 0.0);
    for seed in 0..n {
        let o = optics(&file_with(
            SourceImperfections {
                random_walk_per_rthour: s,
                ..Default::default()
            },
            u64::from(seed),
        ));
        assert_eq!(
            o.incident_power_w(&BAND_550, 0.0),
            P_BEAM_W,
            "the walk starts at 0"
        );
        var_1h += (o.incident_power_w(&BAND_550, 3600.0) / P_BEAM_W - 1.0).powi(2);
        var_4h += (o.incident_power_w(&BAND_550, 4.0 * 3600.0) / P_BEAM_W - 1.0).powi(2);
    }
    // Var W(t) = s^2 t / 1 h; 300 instruments estimate a variance to about +-8 % (1 sigma).
    let (r1, r4) = (
        var_1h / f64::from(n) / (s * s),
        var_4h / f64::from(n) / (4.0 * s * s),
    );
    assert!(
        (r1 - 1.0).abs() < 0.25 && (r4 - 1.0).abs() < 0.25,
        "variance ratios {r1} {r4}"
    );
}

#[test]
fn flicker_has_its_rms_and_a_one_over_f_spectrum() {
    let r = 1e-3;
    let o = optics(&file_with(
        SourceImperfections {
            flicker_rms: r,
            ..Default::default()
        },
        5,
    ));
    // 1000 s at the meter's 3 ms samples.
    let samples: Vec<f64> = (0..333_333)
        .map(|k| o.incident_power_w(&BAND_550, f64::from(k) * 0.003) / P_BEAM_W - 1.0)
        .collect();
    let rms = (samples.iter().map(|x| x * x).sum::<f64>() / samples.len() as f64).sqrt();
    assert!((rms / r - 1.0).abs() < 0.1, "rms {rms:e}");
    // 1/f: most of the power is slow, so one-second means keep most of the rms (about sqrt(17/31) of it, the
    // lines below 0.5 Hz); white noise of the same rms would keep 1/sqrt(333) of it.
    let means: Vec<f64> = samples
        .chunks(333)
        .map(|c| c.iter().sum::<f64>() / c.len() as f64)
        .collect();
    let rms_1s = (means.iter().map(|x| x * x).sum::<f64>() / means.len() as f64).sqrt();
    assert!(
        rms_1s > 0.6 * r && rms_1s < 0.9 * r,
        "rms of 1 s means {rms_1s:e}"
    );
}
