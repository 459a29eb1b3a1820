//! PM100USB over USBTMC: the documented byte vector, bTag checks, multi-transfer replies, clear and abort
//! sequences, halted endpoints, and the reading physics (responsivity at the SET wavelength, averaging time,
//! overload).

use crate::common;

use std::time::Duration;

use common::meter::{out_msg, query, request_in, value};
use common::sim_with;
use gonio_simulator::UsbSimError;
use gonio_simulator::pm100::*;

const T: Duration = Duration::from_secs(1);

fn quiet() -> gonio_simulator::SimInstrument {
    sim_with(|f| f.instrument.detector.noise = false)
}

#[tokio::test(start_paused = true)]
async fn documented_meas_pow_byte_vector_and_reply_framing() {
    let sim = quiet();
    let dev = sim.usb_device("meter").expect("open");
    assert_eq!((dev.vendor_id(), dev.product_id()), (0x1313, 0x8072));
    let out: [u8; 24] = [
        0x01, 0x01, 0xFE, 0x00, 0x0A, 0x00, 0x00, 0x00, 0x01, 0x00, 0x00, 0x00, 0x4D, 0x45, 0x41, 0x53, 0x3A,
        0x50, 0x4F, 0x57, 0x3F, 0x0A, 0x00, 0x00,
    ];
    assert_eq!(
        out_msg(1, "MEAS:POW?\n"),
        out.to_vec(),
        "our builder agrees with the reference vector"
    );
    assert_eq!(dev.bulk_out(BULK_OUT_EP, &out, T).await, Ok(24));
    let req: [u8; 12] = [
        0x02, 0x02, 0xFD, 0x00, 0x00, 0x04, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00,
    ];
    dev.bulk_out(BULK_OUT_EP, &req, T).await.expect("request");
    let t0 = sim.now_s();
    let reply = dev.bulk_in(BULK_IN_EP, 1024 + 12, T).await.expect("reply");
    // Averaging 10 samples of 3 ms: the reply is ready 30 ms of simulated time later.
    assert!(sim.now_s() - t0 >= 10.0 * SAMPLE_S - 1e-9, "{}", sim.now_s() - t0);
    assert_eq!(&reply[..4], &[0x02, 0x02, 0xFD, 0x00]);
    let n = u32::from_le_bytes([reply[4], reply[5], reply[6], reply[7]]) as usize;
    assert_eq!(reply[8], 0x01, "EOM");
    assert_eq!(reply.len() % 4, 0, "padded to 4 bytes");
    assert_eq!(reply.len(), 12 + n.div_ceil(4) * 4);
    assert_eq!(reply[12 + n - 1], b'\n');
    assert!(reply[12 + n..].iter().all(|b| *b == 0));
    // Uniform scene 1e-4 W x transmission 0.5 at position 1 (450 nm), read with the responsivity at the power-up
    // wavelength 633 nm: a wrong wavelength gives a realistically wrong reading.
    let r450 = 0.17;
    let r633 = 0.29 + (633.0 - 550.0) / 100.0 * (0.38 - 0.29);
    // (Plus the stray light of the wheel's position sensors, on at power-up.)
    let stray = gonio_simulator::fw102c::SENSOR_STRAY_A;
    let expected = (0.5e-4 * r450 + 5.0e-11 + stray) / r633;
    let got = value(&reply[12..12 + n]);
    assert!((got / expected - 1.0).abs() < 1e-6, "{got} vs {expected}");
    // Set to the band: the reading is right (plus the dark current).
    let (_, data) = query(&dev, 3, "SENS:CORR:WAV 450\nMEAS:POW?\n", 1024).await;
    let got = value(&data);
    assert!(
        (got / (0.5e-4 + (5.0e-11 + stray) / r450) - 1.0).abs() < 1e-6,
        "{got}"
    );
}

#[tokio::test(start_paused = true)]
async fn bad_btag_halts_bulk_out_until_clear_halt() {
    let sim = quiet();
    let dev = sim.usb_device("meter").expect("open");
    let mut bad = out_msg(5, "*IDN?\n");
    bad[2] = 0x00; // wrong inverse
    assert_eq!(
        dev.bulk_out(BULK_OUT_EP, &bad, T).await,
        Err(UsbSimError::Pipe {
            endpoint: BULK_OUT_EP
        })
    );
    assert_eq!(
        dev.bulk_out(BULK_OUT_EP, &out_msg(6, "*IDN?\n"), T).await,
        Err(UsbSimError::Pipe {
            endpoint: BULK_OUT_EP
        }),
        "stays halted"
    );
    dev.clear_halt(BULK_OUT_EP).await.expect("clear halt");
    let (h, data) = query(&dev, 7, "*IDN?\n", 256).await;
    assert_eq!(h[1], 8, "echoes the request's bTag");
    assert!(String::from_utf8_lossy(&data).starts_with("Thorlabs,PM100USB,"));
    // bTag 0 is invalid too.
    assert!(
        dev.bulk_out(BULK_OUT_EP, &out_msg(0, "*IDN?\n"), T)
            .await
            .is_err()
    );
}

#[tokio::test(start_paused = true)]
async fn long_reply_spans_several_transfers_and_split_commands_are_joined() {
    let sim = quiet();
    let dev = sim.usb_device("meter").expect("open");
    // The command's payload arrives in two bulk_out calls (header announces 6 bytes).
    let full = out_msg(1, "*IDN?\n");
    dev.bulk_out(BULK_OUT_EP, &full[..14], T)
        .await
        .expect("first part");
    dev.bulk_out(BULK_OUT_EP, &full[14..], T)
        .await
        .expect("second part");
    let mut text = Vec::new();
    let mut btag = 2u8;
    loop {
        dev.bulk_out(BULK_OUT_EP, &request_in(btag, 8), T)
            .await
            .expect("request");
        let t = dev.bulk_in(BULK_IN_EP, 64, T).await.expect("in");
        assert_eq!((t[1], t[2]), (btag, !btag));
        let n = u32::from_le_bytes([t[4], t[5], t[6], t[7]]) as usize;
        assert!(n <= 8);
        text.extend_from_slice(&t[12..12 + n]);
        btag += 1;
        if t[8] & 1 == 1 {
            break;
        }
        assert!(btag < 40, "no EOM");
    }
    assert!(btag > 3, "several transfers");
    assert_eq!(
        String::from_utf8_lossy(&text),
        "Thorlabs,PM100USB,P2000001,1.7.0\n"
    );
    // A bulk_in smaller than the transfer returns its first part; the rest follows.
    dev.bulk_out(BULK_OUT_EP, &out_msg(50, "*IDN?\n"), T)
        .await
        .expect("out");
    dev.bulk_out(BULK_OUT_EP, &request_in(51, 1024), T)
        .await
        .expect("request");
    let a = dev.bulk_in(BULK_IN_EP, 16, T).await.expect("part 1");
    let b = dev.bulk_in(BULK_IN_EP, 1024, T).await.expect("part 2");
    assert_eq!(a.len(), 16);
    assert_eq!(&[a, b].concat()[12..44], b"Thorlabs,PM100USB,P2000001,1.7.0");
}

#[tokio::test(start_paused = true)]
async fn nothing_to_read_times_out_and_queues_query_unterminated() {
    let sim = quiet();
    let dev = sim.usb_device("meter").expect("open");
    assert_eq!(
        dev.bulk_in(BULK_IN_EP, 64, Duration::from_millis(100)).await,
        Err(UsbSimError::Timeout { transferred: 0 })
    );
    dev.bulk_out(BULK_OUT_EP, &request_in(1, 64), T)
        .await
        .expect("request");
    assert_eq!(
        dev.bulk_in(BULK_IN_EP, 64, Duration::from_millis(100)).await,
        Err(UsbSimError::Timeout { transferred: 0 })
    );
    // Abort that Bulk-IN request: wrong bTag, then the right one.
    let r = dev
        .control_in(0xA2, INITIATE_ABORT_BULK_IN, 9, u16::from(BULK_IN_EP), 2, T)
        .await
        .expect("abort");
    assert_eq!(r, vec![STATUS_TRANSFER_NOT_IN_PROGRESS, 9]);
    let r = dev
        .control_in(0xA2, INITIATE_ABORT_BULK_IN, 1, u16::from(BULK_IN_EP), 2, T)
        .await
        .expect("abort");
    assert_eq!(r, vec![STATUS_SUCCESS, 1]);
    let r = dev
        .control_in(0xA2, CHECK_ABORT_BULK_IN_STATUS, 0, u16::from(BULK_IN_EP), 8, T)
        .await
        .expect("check");
    assert_eq!(r[0], STATUS_SUCCESS);
    let r = dev
        .control_in(0xA2, INITIATE_ABORT_BULK_IN, 1, u16::from(BULK_IN_EP), 2, T)
        .await
        .expect("abort");
    assert_eq!(r, vec![STATUS_FAILED, 1], "nothing in progress any more");
    let (_, data) = query(&dev, 2, "SYST:ERR?\n", 256).await;
    assert_eq!(String::from_utf8_lossy(&data), "-420,\"Query UNTERMINATED\"\n");
}

#[tokio::test(start_paused = true)]
async fn clear_sequence_discards_pending_output() {
    let sim = quiet();
    let dev = sim.usb_device("meter").expect("open");
    dev.bulk_out(BULK_OUT_EP, &out_msg(1, "MEAS:POW?\n"), T)
        .await
        .expect("out");
    assert_eq!(
        dev.control_in(0xA1, INITIATE_CLEAR, 0, 0, 1, T).await,
        Ok(vec![STATUS_SUCCESS])
    );
    let mut polls = 0;
    loop {
        let r = dev
            .control_in(0xA1, CHECK_CLEAR_STATUS, 0, 0, 2, T)
            .await
            .expect("check");
        polls += 1;
        if r[0] == STATUS_PENDING {
            sim.clock().sleep_s(0.0005).await;
            continue;
        }
        assert_eq!(r, vec![STATUS_SUCCESS, 0]);
        break;
    }
    assert!(polls >= 2, "the clear takes a little time: PENDING first");
    dev.clear_halt(BULK_OUT_EP).await.expect("clear halt");
    dev.bulk_out(BULK_OUT_EP, &request_in(2, 64), T)
        .await
        .expect("request");
    assert_eq!(
        dev.bulk_in(BULK_IN_EP, 64, Duration::from_millis(100)).await,
        Err(UsbSimError::Timeout { transferred: 0 })
    );
    let caps = dev
        .control_in(0xA1, GET_CAPABILITIES, 0, 0, 0x18, T)
        .await
        .expect("caps");
    assert_eq!(caps.len(), 0x18);
    assert_eq!(
        (caps[0], caps[2], caps[3]),
        (STATUS_SUCCESS, 0x00, 0x01),
        "bcdUSBTMC 1.00"
    );
    assert_eq!(
        dev.control_in(0x80, 0x06, 0x0100, 0, 18, T).await,
        Err(UsbSimError::Pipe { endpoint: 0 })
    );
}

#[tokio::test(start_paused = true)]
async fn scpi_forms_error_queue_and_settings() {
    let sim = quiet();
    let dev = sim.usb_device("meter").expect("open");
    let (_, d) = query(&dev, 1, "sense:correction:wavelength 550;:SENS:CORR:WAV?\n", 256).await;
    assert_eq!(String::from_utf8_lossy(&d), "5.500000E+02\n");
    let (_, d) = query(&dev, 3, "SENS:AVER:COUN 3;SENS:AVER:COUN?\n", 256).await;
    assert_eq!(String::from_utf8_lossy(&d), "3\n");
    dev.bulk_out(BULK_OUT_EP, &out_msg(5, "BOGUS:CMD 1\nSENS:CORR:WAV 5000\n"), T)
        .await
        .expect("out");
    let (_, d) = query(&dev, 6, "SYST:ERR?;SYST:ERR?;SYST:ERR?\n", 256).await;
    assert_eq!(
        String::from_utf8_lossy(&d),
        "-113,\"Undefined header\";-222,\"Data out of range\";+0,\"No error\"\n"
    );
    let (_, d) = query(&dev, 8, "SYST:SENS:IDN?\n", 256).await;
    assert!(String::from_utf8_lossy(&d).starts_with("S120C,"));
}

#[tokio::test(start_paused = true)]
async fn overload_on_a_small_manual_range_and_when_saturate_is_forced() {
    let sim = quiet();
    let dev = sim.usb_device("meter").expect("open");
    // 5e-5 W on the 5e-8 W range: overload, answered as the PM100D2/PM101/PM103/PM400 references show.
    let (_, d) = query(&dev, 1, "SENS:CORR:WAV 450;:SENS:POW:RANG 5e-8;:MEAS:POW?\n", 256).await;
    assert_eq!(String::from_utf8_lossy(&d), "INFINITY\n");
    let (_, d) = query(&dev, 3, "STAT:QUES:COND?\n", 256).await;
    assert_eq!(String::from_utf8_lossy(&d), "8\n", "bit 3: power over range");
    let (_, d) = query(&dev, 3, "SENS:POW:RANG:AUTO ON;:MEAS:POW?\n", 256).await;
    assert!(value(&d) < 1e-3);
    let sat = sim_with(|f| f.simulator.faults.saturate = true);
    let dev = sat.usb_device("meter").expect("open");
    let (_, d) = query(&dev, 1, "MEAS:POW?\n", 256).await;
    assert_eq!(String::from_utf8_lossy(&d), "INFINITY\n");
    assert_eq!(sat.fault_counts().saturated_readings, 1);
    // The older variant: SCPI's overflow value.
    let old = sim_with(|f| {
        f.instrument.detector.noise = false;
        f.simulator.quirks.pm100_overrange = gonio_instrument::Pm100Overrange::ScpiOverflow;
    });
    let dev = old.usb_device("meter").expect("open");
    let (_, d) = query(&dev, 1, "SENS:CORR:WAV 450;:SENS:POW:RANG 5e-8;:MEAS:POW?\n", 256).await;
    assert_eq!(value(&d), OVERLOAD_W);
}

#[tokio::test(start_paused = true)]
async fn noise_is_seeded_and_shows_on_the_dark_reading_of_the_lowest_range() {
    let run = |seed: u64, cmd: &'static str| async move {
        let sim = sim_with(|f| f.simulator.seed = seed);
        let mut wheel = common::Port::open(&sim, "wheel");
        // Position sensors off (they add stray light), then the blank.
        wheel.send(b"sensors=0\rpos=6\r").await;
        assert!(
            wheel
                .read_until(b"pos=6\r> ", Duration::from_secs(10))
                .await
                .is_some()
        );
        let dev = sim.usb_device("meter").expect("open");
        let mut v = Vec::new();
        for k in 0..20u8 {
            let (_, d) = query(&dev, 2 * k + 1, cmd, 256).await;
            v.push(value(&d));
        }
        v
    };
    let dark = "SENS:CORR:WAV 450;:SENS:POW:RANG 5e-8;:MEAS:POW?\n";
    let a = run(7, dark).await;
    assert_eq!(a, run(7, dark).await, "same seed, same readings");
    assert_ne!(a, run(8, dark).await);
    assert!(
        a.iter().any(|x| *x != a[0]),
        "Johnson noise shows on the lowest range: {a:?}"
    );
    let mean = a.iter().sum::<f64>() / a.len() as f64;
    let expected = 5.0e-11 / 0.17;
    assert!((mean / expected - 1.0).abs() < 0.02, "{mean} vs {expected}");
}

#[tokio::test(start_paused = true)]
async fn blank_position_gives_the_dark_reading() {
    let sim = quiet();
    let mut wheel = common::Port::open(&sim, "wheel");
    wheel.send(b"pos=6\r").await;
    assert!(
        wheel
            .read_until(b"pos=6\r> ", Duration::from_secs(10))
            .await
            .is_some()
    );
    let dev = sim.usb_device("meter").expect("open");
    // The wheel powers up with its position sensors on: their light reaches the detector.
    let (_, d) = query(&dev, 1, "SENS:CORR:WAV 450;:MEAS:POW?\n", 256).await;
    let stray = gonio_simulator::fw102c::SENSOR_STRAY_A;
    assert!(
        (value(&d) - (5.0e-11 + stray) / 0.17).abs() < 1e-15,
        "dark current and the sensors' stray light: {}",
        value(&d)
    );
    wheel.send(b"sensors=0\r").await;
    assert!(
        wheel
            .read_until(b"sensors=0\r> ", Duration::from_secs(1))
            .await
            .is_some()
    );
    let (_, d) = query(&dev, 3, "MEAS:POW?\n", 256).await;
    assert!(
        (value(&d) - 5.0e-11 / 0.17).abs() < 1e-15,
        "dark current only: {}",
        value(&d)
    );
}

/// The gadget's hooks: a power cycle (the gadget unbound) forgets every setting, as a bus-powered meter that lost
/// its cable does; a delayed reply is ready that much simulated time later, once.
#[tokio::test(start_paused = true)]
async fn a_power_cycle_restores_power_up_settings_and_a_delay_applies_to_one_reply() {
    let sim = quiet();
    let dev = sim.usb_device("meter").expect("open");
    let (_, before) = query(&dev, 1, "SENS:CORR:WAV 550;SENS:CORR:WAV?\n", 256).await;
    assert_eq!(value(&before), 550.0);
    dev.power_cycle();
    let (_, after) = query(&dev, 3, "SENS:CORR:WAV?\n", 256).await;
    assert_eq!(value(&after), 633.0, "power-up wavelength");

    dev.delay_next_reply(2.0);
    dev.bulk_out(BULK_OUT_EP, &out_msg(5, "*IDN?\n"), T)
        .await
        .expect("out");
    dev.bulk_out(BULK_OUT_EP, &request_in(6, 256), T)
        .await
        .expect("request");
    let t0 = sim.now_s();
    assert_eq!(
        dev.bulk_in(BULK_IN_EP, 512, T).await,
        Err(UsbSimError::Timeout { transferred: 0 }),
        "past a 1 s timeout"
    );
    dev.bulk_in(BULK_IN_EP, 512, Duration::from_secs(5))
        .await
        .expect("the late reply");
    let late = sim.now_s() - t0;
    assert!(
        (2.0..2.1).contains(&late),
        "the delayed reply came after {late} s"
    );
    let t1 = sim.now_s();
    let _ = query(&dev, 7, "*IDN?\n", 256).await;
    let next = sim.now_s() - t1;
    assert!(next < 0.1, "only one reply is delayed, the next took {next} s");
}
