//! FW102C: the noise of a freshly opened port, speed and sensors set before the first turn, deadlines that
//! follow from the configured speed.

use std::sync::{Arc, Mutex};

use gonio_driver::FilterWheel;
use gonio_driver::fw102c::Fw102c;
use gonio_driver::transport::LinePort;

use crate::common::{sim_file, sim_port, trace};
use crate::scripted::peer;

/// A wheel saved in slow mode with its sensors on (2 s a position until `speed=1`), whose port starts with NUL
/// bytes and `CMD_NOT_DEFINED` before the first answer. Returns the stream and the commands it saw.
fn real_wheel() -> (tokio::io::DuplexStream, Arc<Mutex<Vec<String>>>) {
    let seen = Arc::new(Mutex::new(Vec::new()));
    let s = Arc::clone(&seen);
    let mut state = (1u8, 0u8, 1u8, true); // position, speed, sensors, noise pending
    let (stream, _) = peer(b'\r', move |line| {
        s.lock().unwrap().push(line.to_string());
        let mut out = Vec::new();
        if std::mem::take(&mut state.3) {
            out.push((0, "\0\0\0Command error CMD_NOT_DEFINED\r> ".to_string()));
        }
        let echo = format!("{line}\r");
        match line {
            "pcount?" => out.extend([(0, echo), (0, "6\r> ".into())]),
            "pos?" => out.extend([(0, echo), (0, format!("{}\r> ", state.0))]),
            "sensors?" => out.extend([(0, echo), (0, format!("{}\r> ", state.2))]),
            "speed=1" | "speed=0" => {
                state.1 = u8::from(line == "speed=1");
                out.extend([(0, echo), (0, "> ".into())]);
            }
            "sensors=0" => {
                state.2 = 0;
                out.extend([(0, echo), (0, "> ".into())]);
            }
            l if l.starts_with("pos=") => {
                let n: u8 = l[4..].parse().unwrap_or(1);
                let apart = n.abs_diff(state.0);
                let steps = u64::from(apart.min(6 - apart));
                let per_ms = if state.1 == 1 { 1000 } else { 2000 };
                state.0 = n;
                out.extend([(0, echo), (steps * per_ms, "> ".into())]);
            }
            _ => out.extend([(0, echo), (0, "Command error CMD_NOT_DEFINED\r> ".into())]),
        }
        out
    });
    (stream, seen)
}

#[tokio::test(start_paused = true)]
async fn noise_at_open_is_skipped_and_speed_and_sensors_are_set_before_turning() {
    trace();
    let (stream, seen) = real_wheel();
    let wheel = Fw102c::new(
        "wheel",
        Arc::new(LinePort::from_stream("wheel", Box::new(stream))),
        1.0,
    );
    let t0 = tokio::time::Instant::now();
    wheel.go_to(4).await.expect("turned despite the noise");
    // Three positions at speed 1: 3 s (a wheel left in slow mode would take 6 s).
    let took = t0.elapsed().as_secs_f64();
    assert!((3.0..4.0).contains(&took), "{took} s");
    assert_eq!(wheel.position().await.expect("pos"), 4);
    let sensors = wheel
        .exchange("sensors?", std::time::Duration::from_secs(1), true)
        .await;
    assert_eq!(sensors.expect("sensors?"), ["0"], "the position sensors are off");
    let log = seen.lock().unwrap().clone();
    let first_turn = log.iter().position(|l| l == "pos=4").expect("turned");
    assert!(log[..first_turn].contains(&"speed=1".to_string()), "{log:?}");
    assert!(log[..first_turn].contains(&"sensors=0".to_string()), "{log:?}");
    // Once per opening: not again for the next turn.
    wheel.go_to(1).await.expect("turned back");
    let log = seen.lock().unwrap().clone();
    assert_eq!(
        log.iter().filter(|l| l.as_str() == "speed=1").count(),
        1,
        "{log:?}"
    );
    assert_eq!(log.last().map(String::as_str), Some("pos?"));
    assert_eq!(
        log.iter().filter(|l| l.as_str() == "sensors=0").count(),
        1,
        "{log:?}"
    );
}

#[tokio::test(start_paused = true)]
async fn slow_mode_deadline_follows_the_configured_speed() {
    trace();
    // Against the emulator in slow mode: 2 s a position; half a turn takes 6 s, which a deadline computed from
    // the fast-mode time (2 x 1 s x 3 + 2 s = 8 s) would barely hold, and from the old 0.4 s not at all.
    let sim = sim_file(
        |f| {
            let w = f.instrument.filter_wheel.as_mut().expect("wheel");
            w.speed = 0;
            w.seconds_per_position = 2.0;
        },
        1.0,
    );
    let wheel = Fw102c::new("wheel", sim_port(&sim, "wheel"), 2.0).with_speed(0);
    let t0 = tokio::time::Instant::now();
    wheel.go_to(4).await.expect("half a turn in slow mode");
    let took = t0.elapsed().as_secs_f64();
    assert!((6.0..7.0).contains(&took), "{took} s");
    // And at speed 1 with the vendor's 1 s a position.
    let sim = sim_file(|f| f.simulator.quirks.fw102c_noise_at_open = true, 1.0);
    let wheel = Fw102c::new("wheel", sim_port(&sim, "wheel"), 1.0).with_speed(1);
    let t0 = tokio::time::Instant::now();
    wheel.go_to(4).await.expect("half a turn in fast mode");
    let took = t0.elapsed().as_secs_f64();
    assert!((3.0..4.0).contains(&took), "{took} s");
    assert_eq!(wheel.position().await.expect("pos"), 4);
}

#[tokio::test(start_paused = true)]
async fn turns_with_and_without_noise_at_open_and_after_reopening() {
    trace();
    for noise in [false, true] {
        let sim = sim_file(|f| f.simulator.quirks.fw102c_noise_at_open = noise, 1.0);
        let wheel = Fw102c::new("wheel", sim_port(&sim, "wheel"), 1.0).with_speed(1);
        wheel
            .go_to(4)
            .await
            .unwrap_or_else(|e| panic!("noise {noise}: {e}"));
        assert_eq!(wheel.position().await.expect("pos"), 4, "noise {noise}");
        // A reopened port starts with the noise again (when the wheel makes it): still read past.
        wheel
            .reconnect()
            .await
            .unwrap_or_else(|e| panic!("noise {noise}: reopen: {e}"));
        wheel
            .go_to(2)
            .await
            .unwrap_or_else(|e| panic!("noise {noise}: after reopening: {e}"));
        assert_eq!(wheel.position().await.expect("pos"), 2, "noise {noise}");
    }
}
