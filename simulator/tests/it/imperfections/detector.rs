//! The detector's imperfections, one at a time, against the models written out here (module doc of
//! simulator/src/imperfections/detector.rs): the meter read over USBTMC on the ideal simulated instrument
//! and on the same instrument with one detector effect on, the prediction made from the ideal reading and the
//! hidden values (public accessor), not by the simulator's code.

use std::sync::Arc;

use gonio_instrument::{DetectorImperfections, InstrumentFile};
use gonio_simulator::SimInstrument;
use gonio_simulator::optics::Optics;
use gonio_simulator::scene::UniformScene;

use super::common::meter::Host;
use super::{BAND_550, optics, pose};

/// The filter in the beam at power-up (position 1: 450 nm, T = 0.5) and the sensor's responsivity there (A/W,
/// config/instruments/simulated.toml).
const R_450: f64 = 0.17;
const RANGES_W: [f64; 6] = [5.0e-8, 5.0e-7, 5.0e-6, 5.0e-5, 5.0e-4, 5.0e-3];

/// The simulated instrument, noise off, uniform scene of `scene_w`, with `detector` as its only imperfection.
fn sim(detector: DetectorImperfections, scene_w: f64, noise: bool) -> SimInstrument {
    let mut file = InstrumentFile::simulated();
    file.instrument.detector.noise = noise;
    file.simulator.seed = 11;
    file.simulator.imperfections.detector = detector;
    SimInstrument::new(&file, Arc::new(UniformScene { power_w: scene_w }), 1.0).expect("instrument")
}

/// One `MEAS:POW?` at 450 nm on the manual range `range_w` (None: auto-range), in watts.
async fn read_w(host: &mut Host, range_w: Option<f64>) -> f64 {
    let range = match range_w {
        Some(r) => format!("SENS:POW:RANG:AUTO OFF;:SENS:POW:RANG {r:e}"),
        None => "SENS:POW:RANG:AUTO ON".to_string(),
    };
    let reply = host.ask(&format!("SENS:CORR:WAV 450;:{range};:MEAS:POW?")).await;
    reply
        .parse()
        .unwrap_or_else(|_| panic!("not a number: {reply:?}"))
}

fn close(a: f64, b: f64, rel: f64) -> bool {
    (a - b).abs() <= rel * b.abs().max(f64::MIN_POSITIVE)
}

#[tokio::test(start_paused = true)]
async fn range_gain_nonlinearity_and_offset_follow_the_meter_transfer() {
    let on = DetectorImperfections {
        range_gain_sd: 0.01,
        nonlinearity_sd: 0.01,
        offset_sd_fs: 1e-3,
        ..Default::default()
    };
    // 1e-6 W at the wheel: 5e-7 W through the filter, readable on the four largest ranges.
    let (ideal, imperfect) = (sim(Default::default(), 1e-6, false), sim(on, 1e-6, false));
    let truth = imperfect
        .hidden_truth()
        .and_then(|h| h.detector.clone())
        .expect("detector truth");
    let (mut a, mut b) = (Host::new(&ideal), Host::new(&imperfect));
    let mut readings = Vec::new();
    for (index, &range_w) in RANGES_W.iter().enumerate().skip(2) {
        let w0 = read_w(&mut a, Some(range_w)).await;
        let w1 = read_w(&mut b, Some(range_w)).await;
        // The model written out: I (1 + g) (1 + b I / I_fs) + o I_fs, with I the ideal meter's current.
        let r = truth.ranges[index];
        let i = w0 * R_450;
        let i_fs = range_w * R_450;
        let predicted = (i * (1.0 + r.gain) * (1.0 + r.nonlinearity * i / i_fs) + r.offset_fs * i_fs) / R_450;
        assert!(
            close(w1, predicted, 2e-6),
            "range {range_w:e}: read {w1:e}, predicted {predicted:e} (ideal {w0:e})"
        );
        readings.push(w1);
    }
    // Adjacent ranges disagree on the same light: the gain mismatch a range change shows.
    let spread = readings
        .iter()
        .fold(0.0f64, |m, &w| m.max((w / readings[0] - 1.0).abs()));
    assert!(spread > 1e-3, "ranges agree to {spread:e}");
}

#[tokio::test(start_paused = true)]
async fn saturation_compresses_the_photocurrent() {
    let on = DetectorImperfections {
        saturation_current_a: 1e-4,
        ..Default::default()
    };
    let (ideal, imperfect) = (sim(Default::default(), 1e-4, false), sim(on, 1e-4, false));
    let w0 = read_w(&mut Host::new(&ideal), None).await;
    let w1 = read_w(&mut Host::new(&imperfect), None).await;
    let i = w0 * R_450;
    let predicted = i / (1.0 + i / 1e-4) / R_450;
    assert!(close(w1, predicted, 2e-6), "read {w1:e}, predicted {predicted:e}");
    assert!(w1 < 0.95 * w0, "8.5 uA against 100 uA saturation: about 8 % low");
}

#[tokio::test(start_paused = true)]
async fn ambient_light_adds_its_slowly_varying_current() {
    let on = DetectorImperfections {
        ambient_a: 1e-8,
        ambient_variation: 0.3,
        ambient_period_s: 600.0,
        ..Default::default()
    };
    // 1e-8 W at the wheel (1e-9 A of light), so that the 1e-8 A of ambient light is most of the reading.
    let (ideal, imperfect) = (sim(Default::default(), 1e-8, false), sim(on, 1e-8, false));
    let truth = imperfect
        .hidden_truth()
        .and_then(|h| h.detector.clone())
        .expect("detector truth");
    let (mut a, mut b) = (Host::new(&ideal), Host::new(&imperfect));
    let (mut lo, mut hi) = (f64::MAX, f64::MIN);
    for _ in 0..24 {
        let t = imperfect.now_s();
        let extra_a = (read_w(&mut b, None).await - read_w(&mut a, None).await) * R_450;
        // A (1 + v sin(2 pi t / T + phi)), the reading's instant known to its 30 ms window.
        let predicted = 1e-8
            * (1.0 + 0.3 * (std::f64::consts::TAU * t / 600.0 + truth.ambient_phase_deg.to_radians()).sin());
        assert!(
            (extra_a - predicted).abs() < 2e-3 * 1e-8,
            "t {t:.1} s: ambient {extra_a:e} A, predicted {predicted:e} A"
        );
        lo = lo.min(extra_a);
        hi = hi.max(extra_a);
        tokio::time::sleep(std::time::Duration::from_secs(25)).await;
    }
    // Over one period it swings by about 2 v A.
    assert!(hi - lo > 1.8 * 0.3 * 1e-8, "swing {:e}", hi - lo);
}

#[tokio::test(start_paused = true)]
async fn amplifier_noise_spreads_readings_by_its_density() {
    // The file's own noise off: only the amplifier's. 1e-9 W at the wheel keeps the smallest range (LSB 1.3e-13
    // A), far below the noise of one averaged reading.
    let density = 1e-11;
    let on = DetectorImperfections {
        amplifier_noise_a_per_rthz: density,
        ..Default::default()
    };
    let (ideal, imperfect) = (sim(Default::default(), 1e-9, false), sim(on, 1e-9, false));
    let (mut a, mut b) = (Host::new(&ideal), Host::new(&imperfect));
    let n = 300;
    let (mut s1, mut s2, mut ideal_spread) = (0.0, 0.0, 0.0f64);
    let first = read_w(&mut a, None).await;
    for _ in 0..n {
        let w = read_w(&mut b, None).await;
        s1 += w;
        s2 += w * w;
        ideal_spread = ideal_spread.max((read_w(&mut a, None).await - first).abs());
    }
    let mean = s1 / f64::from(n);
    let sd_w = (s2 / f64::from(n) - mean * mean).sqrt();
    // Per 3 ms sample: density^2 over the sample's noise bandwidth 1/(2 x 3 ms); ten samples averaged.
    let predicted_w = density * (1.0 / (2.0 * 0.003) / 10.0_f64).sqrt() / R_450;
    assert!(
        (sd_w / predicted_w - 1.0).abs() < 0.12,
        "spread {sd_w:e} W, predicted {predicted_w:e} W"
    );
    assert_eq!(ideal_spread, 0.0, "the ideal quiet meter repeats exactly");
}

#[test]
fn stray_light_adds_the_signature_of_the_beam_at_the_arms_angle() {
    let on = DetectorImperfections {
        stray_peak_sr: 1e-2,
        stray_width_deg: 2.0,
        stray_floor_sr: 1e-5,
        ..Default::default()
    };
    let mut file = InstrumentFile::simulated();
    let ideal: Optics = optics(&file);
    file.simulator.imperfections.detector = on;
    let imperfect = optics(&file);
    // Beam power at the sample (1 mW through T = 0.5) and the aperture's solid angle (2.5 mm at 250 mm).
    let p_beam = 1e-3 * 0.5;
    let omega = std::f64::consts::TAU * (1.0 - (2.5f64 / 250.0).atan().cos());
    let signature = |alpha_deg: f64| 1e-2 / (1.0 + (alpha_deg / 2.0).powi(2)) + 1e-5;
    for (light, detector) in [(30.0, -30.0), (60.0, -10.0), (80.0, -85.0), (-45.0, 20.0)] {
        let p = pose(light, detector, 0.0, 0.0);
        // The undeviated beam leaves the sample at light + 180 degrees in the arms' plane.
        let d = (detector - (light + 180.0f64)).rem_euclid(360.0);
        let alpha = d.min(360.0 - d);
        let expected = p_beam * omega * signature(alpha);
        for mounted in [true, false] {
            ideal.set_sample_mounted(mounted);
            imperfect.set_sample_mounted(mounted);
            let r0 = ideal.reading(&p, &BAND_550, 10.0).expect("reading");
            let r1 = imperfect.reading(&p, &BAND_550, 10.0).expect("reading");
            let extra = r1.power_w - r0.power_w;
            assert!(
                (extra - expected).abs() <= 1e-9 * expected + 1e-18,
                "pose {light}/{detector} mounted {mounted}: stray {extra:e} W, predicted {expected:e} W"
            );
        }
    }
}
