//! PM100: over-range answers of every model, the signed `+0,"No error"`, the sensor's wavelength limits.

use std::sync::Arc;
use std::sync::Mutex;

use gonio_driver::pm100::Pm100;
use gonio_driver::transport::usb::{MemoryPipe, MemoryState};
use gonio_driver::{Detector, DetectorConfig, ErrorKind, PowerRange};
use gonio_instrument::Pm100Overrange;

use crate::common::{sim_file, trace};
use crate::sim::meter;

/// A Bulk-IN DEV_DEP_MSG_IN transfer, built by hand from the USBTMC specification's table.
fn in_frame(btag: u8, data: &[u8]) -> Vec<u8> {
    let mut v = vec![2, btag, !btag, 0];
    v.extend_from_slice(&(data.len() as u32).to_le_bytes());
    v.extend_from_slice(&[1, 0, 0, 0]);
    v.extend_from_slice(data);
    while v.len() % 4 != 0 {
        v.push(0);
    }
    v
}

/// A scripted meter answering the exchanges quoted from the references; `reading` is its `MEAS:POW?` answer.
/// Returns the pipe and the log of SCPI messages it received.
fn scripted(reading: &'static str) -> (MemoryPipe, Arc<Mutex<Vec<String>>>) {
    let log = Arc::new(Mutex::new(Vec::new()));
    let l = Arc::clone(&log);
    let mut pending: Vec<u8> = Vec::new();
    let mut wavelength = String::from("6.330000E+02");
    let pipe = MemoryPipe::new().with_responder(move |out: &[u8], state: &mut MemoryState| {
        let size = u32::from_le_bytes([out[4], out[5], out[6], out[7]]) as usize;
        match out[0] {
            1 => {
                let msg = String::from_utf8_lossy(&out[12..12 + size])
                    .trim_end()
                    .to_string();
                if let Some(nm) = msg.strip_prefix("SENS:CORR:WAV ") {
                    wavelength = nm.to_string();
                }
                let answer = match msg.as_str() {
                    "SYST:ERR?" => "+0,\"No error\"".to_string(),
                    "SENS:CORR:WAV? MIN" => "4.000000E+02".into(),
                    "SENS:CORR:WAV? MAX" => "1.100000E+03".into(),
                    "SENS:CORR:WAV?" => wavelength.clone(),
                    "MEAS:POW?" => reading.into(),
                    "SENS:POW:RANG?" => "5.000000E-03".into(),
                    _ => String::new(),
                };
                if !answer.is_empty() {
                    pending = format!("{answer}\n").into_bytes();
                }
                l.lock().unwrap().push(msg);
            }
            2 => {
                let data = std::mem::take(&mut pending);
                state.in_queue.push_back(Ok(in_frame(out[1], &data)));
            }
            _ => {}
        }
    });
    (pipe, log)
}

const CONFIG: DetectorConfig = DetectorConfig {
    wavelength_nm: 550.0,
    averaging: 1,
    range: PowerRange::Auto,
};

#[tokio::test(start_paused = true)]
async fn infinity_answers_are_overload_not_protocol_errors() {
    trace();
    for reading in ["INFINITY", "-INFINITY", "9.9E37", "+INF"] {
        let (pipe, log) = scripted(reading);
        let m = Pm100::new("meter", Arc::new(pipe), None);
        m.configure(CONFIG).await.expect("configure with +0,\"No error\"");
        let r = m.read_power().await.unwrap_or_else(|e| panic!("{reading}: {e}"));
        assert!(r.overload && r.power_w.is_nan(), "{reading}: {r:?}");
        assert_eq!(r.range_w, 5e-3);
        let log = log.lock().unwrap();
        assert!(log.iter().any(|m| m == "SENS:CORR:WAV? MIN"), "{log:?}");
    }
}

#[tokio::test(start_paused = true)]
async fn a_wavelength_outside_the_sensor_is_refused_before_anything_is_set() {
    trace();
    let (pipe, log) = scripted("1.0E-3");
    let m = Pm100::new("meter", Arc::new(pipe), None);
    let err = m
        .configure(DetectorConfig {
            wavelength_nm: 1200.0,
            ..CONFIG
        })
        .await
        .expect_err("beyond the sensor");
    assert_eq!(err.kind(), ErrorKind::OutOfRange, "{err}");
    assert!(
        !log.lock()
            .unwrap()
            .iter()
            .any(|m| m.starts_with("SENS:CORR:WAV 1200")),
        "nothing set"
    );
}

#[tokio::test(start_paused = true)]
async fn overload_under_both_simulator_variants_and_sensor_limits_from_the_sensor() {
    trace();
    for variant in [Pm100Overrange::Infinity, Pm100Overrange::ScpiOverflow] {
        let sim = sim_file(
            |f| {
                f.simulator.quirks.pm100_overrange = variant;
                f.instrument.detector.sensor_wavelength_nm = [400.0, 700.0];
            },
            1.0,
        );
        let m = meter(&sim);
        m.configure(DetectorConfig {
            wavelength_nm: 550.0,
            averaging: 1,
            range: PowerRange::Fixed { full_scale_w: 5.0e-8 },
        })
        .await
        .expect("configure");
        let r = m.read_power().await.expect("reading");
        assert!(r.overload && r.power_w.is_nan(), "{variant:?}: {r:?}");
        let err = m
            .configure(DetectorConfig {
                wavelength_nm: 800.0,
                ..CONFIG
            })
            .await
            .expect_err("beyond this sensor");
        assert_eq!(err.kind(), ErrorKind::OutOfRange, "{err}");
    }
}
