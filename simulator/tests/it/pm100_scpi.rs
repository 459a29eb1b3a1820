//! PM100 conformance with the vendor's SCPI references and recorded real-meter behaviour: `MIN`/`MAX`
//! queries answer the sensor's limits, the IEEE 488.2 common commands and status registers, the measurement
//! functions besides power, the signed `+0,"No error"`.

use crate::common;

use common::meter::{Host, request_in};
use common::sim_with;
use gonio_simulator::pm100::BULK_OUT_EP;

fn num(s: &str) -> f64 {
    s.parse().unwrap_or_else(|_| panic!("not a number: {s:?}"))
}

fn quiet() -> gonio_simulator::SimInstrument {
    sim_with(|f| f.instrument.detector.noise = false)
}

#[tokio::test(start_paused = true)]
async fn min_max_queries_answer_the_sensor_limits_not_the_current_value() {
    let sim = sim_with(|f| {
        f.instrument.detector.noise = false;
        f.instrument.detector.sensor_wavelength_nm = [350.0, 1100.0];
    });
    let mut h = Host::new(&sim);
    assert_eq!(num(&h.ask("SENS:CORR:WAV?").await), 633.0);
    assert_eq!(num(&h.ask("SENS:CORR:WAV? MIN").await), 350.0);
    assert_eq!(num(&h.ask("SENS:CORR:WAV? MAX").await), 1100.0);
    assert_eq!(num(&h.ask("sense:correction:wavelength? maximum").await), 1100.0);
    // The limits come from the sensor: 360 nm is inside this one, 1200 nm is not.
    h.write("SENS:CORR:WAV 360").await;
    assert_eq!(num(&h.ask("SENS:CORR:WAV?").await), 360.0);
    h.write("SENS:CORR:WAV 1200").await;
    assert_eq!(h.ask("SYST:ERR?").await, "-222,\"Data out of range\"");
    h.write("SENS:CORR:WAV MAX").await;
    assert_eq!(num(&h.ask("SENS:CORR:WAV?").await), 1100.0);
    assert_eq!(num(&h.ask("SENS:POW:RANG? MIN").await), 5.0e-8);
    assert_eq!(num(&h.ask("SENS:POW:RANG? MAX").await), 5.0e-3);
    assert_eq!(num(&h.ask("SENS:AVER? MIN").await), 1.0);
    assert!(num(&h.ask("SENS:AVER:COUN? MAX").await) > 1000.0);
    assert_eq!(
        num(&h.ask("SENS:AVER:COUN?").await),
        10.0,
        "the current value without an argument"
    );
    // A number where a limit keyword belongs is an illegal parameter.
    h.write("SENS:CORR:WAV? 500").await;
    assert_eq!(h.ask("SYST:ERR?").await, "-224,\"Illegal parameter value\"");
    // The current range follows the responsivity at the set wavelength.
    h.write("SENS:CORR:WAV 550").await;
    let i_max = num(&h.ask("SENS:CURR:RANG? MAX").await);
    assert!((i_max - 5.0e-3 * 0.29).abs() < 1e-12, "{i_max}");
}

#[tokio::test(start_paused = true)]
async fn ieee_488_2_common_commands_and_status_byte() {
    let sim = quiet();
    let mut h = Host::new(&sim);
    assert!(h.ask("*IDN?").await.starts_with("Thorlabs,PM100USB,"));
    assert_eq!(h.ask("*TST?").await, "0");
    // Power-on (bit 7) is in the event register after power-up; reading it clears it.
    assert_eq!(h.ask("*ESR?").await, "128");
    assert_eq!(h.ask("*ESR?").await, "0");
    h.write("*ESE 60").await;
    assert_eq!(h.ask("*ESE?").await, "60");
    h.write("*SRE 255").await;
    assert_eq!(h.ask("*SRE?").await, "191", "bit 6 cannot be enabled");
    assert_eq!(h.ask("*STB?").await, "0");
    // A command error: CME (bit 5) in the event register, error queue (bit 2), event summary (bit 5) and the
    // master summary (bit 6) in the status byte.
    h.write("BOGUS").await;
    assert_eq!(h.ask("*STB?").await, (4 + 32 + 64).to_string());
    assert_eq!(h.ask("*ESR?").await, "32");
    assert_eq!(
        h.ask("*STB?").await,
        (4 + 64).to_string(),
        "the error is still queued"
    );
    h.write("*CLS").await;
    assert_eq!(h.ask("*STB?").await, "0");
    assert_eq!(h.ask("SYST:ERR?").await, "+0,\"No error\"");
    // *OPC sets operation complete (bit 0); *OPC? answers 1; *WAI is accepted.
    h.write("*OPC;*WAI").await;
    assert_eq!(h.ask("*ESR?").await, "1");
    assert_eq!(h.ask("*OPC?").await, "1");
    // A query error (-4xx) sets QYE (bit 2): a read with nothing to read.
    let b = h.tag();
    h.dev
        .bulk_out(BULK_OUT_EP, &request_in(b, 64), std::time::Duration::from_secs(1))
        .await
        .expect("request");
    assert_eq!(h.ask("*ESR?").await, "4");
    // *RST restores the settings, not the status registers.
    h.write("SENS:CORR:WAV 500;*ESE 1;*RST").await;
    assert_eq!(num(&h.ask("SENS:CORR:WAV?").await), 633.0);
    assert_eq!(h.ask("*ESE?").await, "1");
}

#[tokio::test(start_paused = true)]
async fn message_available_bit_while_an_answer_waits() {
    let sim = quiet();
    let mut h = Host::new(&sim);
    h.write("*IDN?").await;
    // Not read yet: the next message's *STB? sees MAV; both answers come back in order.
    h.write("*STB?").await;
    // Each read takes the oldest answer waiting.
    let idn = h.ask("SYST:VERS?").await;
    assert!(idn.starts_with("Thorlabs,PM100USB,"), "{idn}");
    let stb = h.ask("SYST:ERR?").await;
    assert_eq!(
        stb, "16",
        "message available (bit 4) while the *IDN? answer waited"
    );
    assert_eq!(h.ask("*STB?").await, "1999.0", "then SYST:VERS?'s answer");
}

#[tokio::test(start_paused = true)]
async fn current_power_density_and_the_configured_function() {
    let sim = quiet();
    let mut h = Host::new(&sim);
    h.write("SENS:CORR:WAV 450").await;
    let p = num(&h.ask("MEAS:POW?").await);
    let i = num(&h.ask("MEAS:CURR?").await);
    assert!(
        (i / (p * 0.17) - 1.0).abs() < 1e-6,
        "current = power x responsivity: {i} vs {p}"
    );
    assert_eq!(h.ask("CONF?").await, "CURR");
    assert_eq!(
        num(&h.ask("READ?").await),
        i,
        "READ? follows the configured function"
    );
    h.write("SENS:CORR:BEAM 2").await;
    let d = num(&h.ask("MEAS:PDEN?").await);
    let area_cm2 = std::f64::consts::PI * 0.1 * 0.1;
    assert!((d / (p / area_cm2) - 1.0).abs() < 1e-6, "{d}");
    assert_eq!(h.ask("CONF?").await, "PDEN");
    h.write("CONF:POW").await;
    assert_eq!(h.ask("CONF?").await, "POW");
    assert_eq!(num(&h.ask("FETC?").await), p);
    assert_eq!(num(&h.ask("MEAS:FREQ?").await), 0.0);
    // Energy is a pyroelectric head's function: refused with this photodiode head.
    assert_eq!(h.ask("CONF?").await, "FREQ");
    h.write("CONF:ENER").await;
    assert_eq!(h.ask("SYST:ERR?").await, "-241,\"Hardware missing\"");
    assert_eq!(h.ask("CONF?").await, "FREQ", "unchanged");
    assert!((num(&h.ask("SENS:CORR:POW:PDIO:RESP?").await) - 0.17).abs() < 1e-9);
}

#[tokio::test(start_paused = true)]
async fn questionable_status_latches_overload() {
    let sim = quiet();
    let mut h = Host::new(&sim);
    h.write("STAT:QUES:ENAB 8;*SRE 8").await;
    assert_eq!(h.ask("STAT:QUES:ENAB?").await, "8");
    h.write("SENS:CORR:WAV 450;:SENS:POW:RANG 5e-8").await;
    assert_eq!(h.ask("MEAS:POW?").await, "INFINITY");
    assert_eq!(h.ask("STAT:QUES:COND?").await, "8");
    assert_eq!(h.ask("*STB?").await, (8 + 64).to_string());
    h.write("SENS:POW:RANG:AUTO ON").await;
    assert!(num(&h.ask("MEAS:POW?").await) < 1e-3);
    assert_eq!(
        h.ask("STAT:QUES:COND?").await,
        "0",
        "the condition follows the reading"
    );
    assert_eq!(
        h.ask("STAT:QUES?").await,
        "8",
        "the event stays latched until read"
    );
    assert_eq!(h.ask("STAT:QUES:EVEN?").await, "0");
    h.write("STAT:PRES").await;
    assert_eq!(h.ask("STAT:QUES:ENAB?").await, "0");
}
