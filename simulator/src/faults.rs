//! Fault injection from `[simulator.faults]`: everything off by default, every draw from a seeded RNG.
//!
//! A fault shows up exactly as the real device would show it (a corrupted or missing reply, a late reply, a
//! move that stops short in the controller's own error state, a port that vanishes, a detector in overload).
//! The simulator never hides what it did: every injected fault is logged with `tracing` and counted, and
//! [`FaultCounts`] lets tests assert on it.
//!
//! Each device gets its own random stream (seeded from the fault seed and the device name), so that the faults a
//! device sees do not depend on how the tasks of other devices interleave.

use std::sync::{Arc, Mutex};

use gonio_instrument::Faults;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// How many faults of each kind were injected so far.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct FaultCounts {
    /// Replies with one byte corrupted.
    pub garbled: u64,
    /// Replies never sent.
    pub dropped: u64,
    /// Replies sent late (`delay_ms`).
    pub delayed: u64,
    /// Moves stopped short by a stall.
    pub stalls: u64,
    /// Open connections cut when the device vanished (one per open connection and outage).
    pub disconnects: u64,
    /// Outages (link-down windows) that some host noticed, by a cut connection or a refused open.
    pub outages: u64,
    /// Opens refused while the device was gone.
    pub refused_opens: u64,
    /// Readings forced into overload (`saturate`).
    pub saturated_readings: u64,
}

/// The fault settings plus the shared counters.
#[derive(Debug)]
pub struct FaultInjector {
    cfg: Faults,
    counts: Mutex<FaultCounts>,
    /// The last outage (window index) counted in [`FaultCounts::outages`].
    last_outage: Mutex<Option<u64>>,
}

/// What happens to one reply.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ReplyFate {
    /// Send these bytes (possibly garbled).
    Send(Vec<u8>),
    /// The reply is lost.
    Drop,
}

/// A `[simulator.faults]` value out of its range; the message names the key.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
#[error("{0}")]
pub struct InvalidFaults(pub String);

impl FaultInjector {
    pub fn new(cfg: Faults) -> FaultInjector {
        FaultInjector {
            cfg,
            counts: Mutex::new(FaultCounts::default()),
            last_outage: Mutex::new(None),
        }
    }

    /// Check the rates and times; the message names the key.
    pub fn validate(cfg: &Faults) -> Result<(), InvalidFaults> {
        Self::check(cfg).map_err(InvalidFaults)
    }

    fn check(cfg: &Faults) -> Result<(), String> {
        for (key, v) in [
            ("garble_rate", cfg.garble_rate),
            ("drop_rate", cfg.drop_rate),
            ("stall_rate", cfg.stall_rate),
        ] {
            if !(0.0..=1.0).contains(&v) {
                return Err(format!("[simulator.faults] {key} must be in [0, 1], got {v}"));
            }
        }
        for (key, v) in [
            ("delay_ms", cfg.delay_ms),
            ("delay_jitter_ms", cfg.delay_jitter_ms),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(format!("[simulator.faults] {key} must be >= 0, got {v}"));
            }
        }
        for (key, v) in [
            ("disconnect_after_s", cfg.disconnect_after_s),
            ("reconnect_after_s", cfg.reconnect_after_s),
        ] {
            if let Some(v) = v
                && !(v.is_finite() && v >= 0.0)
            {
                return Err(format!("[simulator.faults] {key} must be >= 0, got {v}"));
            }
        }
        if let Some(every) = cfg.disconnect_every_s {
            let Some(back) = cfg.reconnect_after_s else {
                return Err(
                    "[simulator.faults] disconnect_every_s needs reconnect_after_s (a device that never comes \
                     back cannot vanish again)"
                        .into(),
                );
            };
            if cfg.disconnect_after_s.is_none() {
                return Err("[simulator.faults] disconnect_every_s needs disconnect_after_s".into());
            }
            if !(every.is_finite() && every > back) {
                return Err(format!(
                    "[simulator.faults] disconnect_every_s must be finite and greater than reconnect_after_s \
                     ({back} s), got {every}"
                ));
            }
        }
        Ok(())
    }

    pub fn settings(&self) -> &Faults {
        &self.cfg
    }

    pub fn counts(&self) -> FaultCounts {
        *self.counts.lock().unwrap_or_else(|e| e.into_inner())
    }

    fn count(&self, f: impl FnOnce(&mut FaultCounts)) {
        f(&mut self.counts.lock().unwrap_or_else(|e| e.into_inner()));
    }

    /// A per-device handle with its own deterministic random stream.
    pub fn for_device(self: &Arc<Self>, device: &str) -> DeviceFaults {
        // FNV-1a over the name, mixed with the seed: stable across runs and platforms.
        let mut h: u64 = 0xcbf2_9ce4_8422_2325;
        for b in device.bytes() {
            h ^= u64::from(b);
            h = h.wrapping_mul(0x0000_0100_0000_01b3);
        }
        let rng = ChaCha8Rng::seed_from_u64(self.cfg.seed ^ h);
        DeviceFaults {
            injector: Arc::clone(self),
            device: device.to_string(),
            rng: Arc::new(Mutex::new(rng)),
        }
    }

    /// The latest outage that began at or before `t_s`: (its index, its start time), if any. Outages begin at
    /// `disconnect_after_s`, then every `disconnect_every_s` when that is set.
    fn latest_outage(&self, t_s: f64) -> Option<(u64, f64)> {
        let after = self.cfg.disconnect_after_s?;
        if t_s < after {
            return None;
        }
        match self.cfg.disconnect_every_s {
            None => Some((0, after)),
            Some(every) => {
                // `validate` guarantees every > 0; the float floor may land one period high at a boundary.
                let mut k = ((t_s - after) / every).floor().max(0.0);
                if after + k * every > t_s && k >= 1.0 {
                    k -= 1.0;
                }
                Some((k as u64, after + k * every))
            }
        }
    }

    /// When the latest outage at or before `t_s` began (a handle opened before it is dead), if any.
    pub fn latest_outage_start_s(&self, t_s: f64) -> Option<f64> {
        self.latest_outage(t_s).map(|(_, start)| start)
    }

    /// Is the device link (port or USB) present at simulated time `t_s`?
    pub fn link_up(&self, t_s: f64) -> bool {
        match self.latest_outage(t_s) {
            None => true,
            Some((_, start)) => match self.cfg.reconnect_after_s {
                Some(back) => t_s >= start + back,
                None => false,
            },
        }
    }

    /// The first simulated time at or after `t_s` at which the link goes down, if any.
    pub fn next_disconnect_s(&self, t_s: f64) -> Option<f64> {
        let after = self.cfg.disconnect_after_s?;
        match self.cfg.disconnect_every_s {
            None => Some(after).filter(|after| *after >= t_s),
            Some(_) if t_s <= after => Some(after),
            Some(every) => {
                let mut k = ((t_s - after) / every).ceil();
                if after + k * every < t_s {
                    k += 1.0;
                }
                Some(after + k * every)
            }
        }
    }

    /// Count the outage in force at `t_s` once, however many hosts notice it.
    fn count_outage(&self, t_s: f64) {
        let Some((k, _)) = self.latest_outage(t_s) else {
            return;
        };
        let mut last = self.last_outage.lock().unwrap_or_else(|e| e.into_inner());
        if last.is_none_or(|l| k > l) {
            *last = Some(k);
            drop(last);
            self.count(|c| c.outages += 1);
        }
    }

    pub fn note_disconnect(&self, device: &str, t_s: f64) {
        tracing::warn!(
            device,
            t_s,
            "fault injected: device disconnected, connection closed"
        );
        self.count(|c| c.disconnects += 1);
        self.count_outage(t_s);
    }

    pub fn note_refused_open(&self, device: &str, t_s: f64) {
        tracing::warn!(
            device,
            t_s,
            "fault injected: open refused, device is disconnected"
        );
        self.count(|c| c.refused_opens += 1);
        self.count_outage(t_s);
    }

    /// Whether readings are forced into overload; counts one saturated reading when true.
    pub fn saturate_reading(&self, device: &str) -> bool {
        if self.cfg.saturate {
            tracing::warn!(device, "fault injected: detector overload");
            self.count(|c| c.saturated_readings += 1);
        }
        self.cfg.saturate
    }
}

/// Fault decisions for one device.
#[derive(Debug, Clone)]
pub struct DeviceFaults {
    injector: Arc<FaultInjector>,
    device: String,
    rng: Arc<Mutex<ChaCha8Rng>>,
}

impl DeviceFaults {
    pub fn injector(&self) -> &Arc<FaultInjector> {
        &self.injector
    }

    fn chance(&self, p: f64) -> bool {
        if p <= 0.0 {
            return false;
        }
        self.rng.lock().unwrap_or_else(|e| e.into_inner()).random::<f64>() < p
    }

    /// Extra latency for a reply (simulated seconds): `delay_ms` plus a uniform draw in [0, `delay_jitter_ms`];
    /// counts a delayed reply when non-zero.
    pub fn reply_delay_s(&self) -> f64 {
        let jitter = self.injector.cfg.delay_jitter_ms;
        let mut d = self.injector.cfg.delay_ms;
        if jitter > 0.0 {
            d += jitter * self.rng.lock().unwrap_or_else(|e| e.into_inner()).random::<f64>();
        }
        if d > 0.0 {
            tracing::info!(device = %self.device, delay_ms = d, "fault injected: reply delayed");
            self.injector.count(|c| c.delayed += 1);
        }
        d / 1000.0
    }

    /// Decide the fate of one reply. Garbling replaces one byte that is not a line terminator with a different
    /// printable character (never XON/XOFF), so the framing survives but the content is wrong.
    pub fn reply(&self, mut bytes: Vec<u8>) -> ReplyFate {
        if bytes.is_empty() {
            return ReplyFate::Send(bytes);
        }
        if self.chance(self.injector.cfg.drop_rate) {
            tracing::warn!(device = %self.device, reply = %String::from_utf8_lossy(&bytes).escape_debug(),
                "fault injected: reply dropped");
            self.injector.count(|c| c.dropped += 1);
            return ReplyFate::Drop;
        }
        if self.chance(self.injector.cfg.garble_rate) {
            let candidates: Vec<usize> = bytes
                .iter()
                .enumerate()
                .filter(|(_, b)| **b != b'\r' && **b != b'\n')
                .map(|(i, _)| i)
                .collect();
            if !candidates.is_empty() {
                let mut rng = self.rng.lock().unwrap_or_else(|e| e.into_inner());
                let i = candidates[rng.random_range(0..candidates.len())];
                let original = bytes[i];
                let mut replacement = original;
                while replacement == original {
                    replacement = rng.random_range(0x21u8..0x7f);
                }
                bytes[i] = replacement;
                drop(rng);
                tracing::warn!(device = %self.device, index = i, from = original, to = replacement,
                    "fault injected: reply byte garbled");
                self.injector.count(|c| c.garbled += 1);
            }
        }
        ReplyFate::Send(bytes)
    }

    /// Decide whether a move stalls: `Some(fraction of the distance covered before the stall)`.
    pub fn stall(&self, axis: &str) -> Option<f64> {
        if !self.chance(self.injector.cfg.stall_rate) {
            return None;
        }
        let fraction = self
            .rng
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .random_range(0.2..0.8);
        tracing::warn!(device = %self.device, axis, fraction, "fault injected: move will stall");
        self.injector.count(|c| c.stalls += 1);
        Some(fraction)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn faults(f: impl FnOnce(&mut Faults)) -> Arc<FaultInjector> {
        let mut cfg = Faults {
            seed: 42,
            ..Faults::default()
        };
        f(&mut cfg);
        Arc::new(FaultInjector::new(cfg))
    }

    #[test]
    fn all_off_by_default_changes_nothing() {
        let inj = faults(|_| {});
        let dev = inj.for_device("arms");
        for _ in 0..1000 {
            assert_eq!(
                dev.reply(b"1TS000032\r\n".to_vec()),
                ReplyFate::Send(b"1TS000032\r\n".to_vec())
            );
            assert_eq!(dev.stall("light"), None);
        }
        assert_eq!(dev.reply_delay_s(), 0.0);
        assert!(inj.link_up(1e9));
        assert_eq!(inj.counts(), FaultCounts::default());
    }

    #[test]
    fn garbling_changes_exactly_one_non_terminator_byte_and_is_seeded() {
        let run = || {
            let inj = faults(|c| c.garble_rate = 1.0);
            let dev = inj.for_device("arms");
            let out: Vec<ReplyFate> = (0..20).map(|_| dev.reply(b"1TP12.5\r\n".to_vec())).collect();
            (out, inj.counts())
        };
        let (a, counts) = run();
        let (b, _) = run();
        assert_eq!(a, b, "same seed, same faults");
        assert_eq!(counts.garbled, 20);
        for fate in a {
            let ReplyFate::Send(bytes) = fate else {
                panic!("garble must not drop")
            };
            let diff = bytes.iter().zip(b"1TP12.5\r\n").filter(|(x, y)| x != y).count();
            assert_eq!(diff, 1);
            assert!(bytes.ends_with(b"\r\n"));
            assert!(!bytes.contains(&0x11) && !bytes.contains(&0x13));
        }
    }

    #[test]
    fn drop_rate_one_drops_every_reply() {
        let inj = faults(|c| c.drop_rate = 1.0);
        let dev = inj.for_device("wheel");
        assert_eq!(dev.reply(b"pos?\r".to_vec()), ReplyFate::Drop);
        assert_eq!(inj.counts().dropped, 1);
    }

    #[test]
    fn link_goes_down_and_comes_back() {
        let inj = faults(|c| {
            c.disconnect_after_s = Some(10.0);
            c.reconnect_after_s = Some(5.0);
        });
        assert!(inj.link_up(9.9));
        assert!(!inj.link_up(10.0));
        assert!(!inj.link_up(14.9));
        assert!(inj.link_up(15.0));
        let forever = faults(|c| c.disconnect_after_s = Some(1.0));
        assert!(!forever.link_up(1e6));
    }

    #[test]
    fn periodic_disconnects_repeat_and_are_counted_once_each() {
        let inj = faults(|c| {
            c.disconnect_after_s = Some(100.0);
            c.reconnect_after_s = Some(5.0);
            c.disconnect_every_s = Some(60.0);
        });
        // Down in [100, 105), [160, 165), [220, 225), ...; up elsewhere.
        for (t, up) in [
            (99.9, true),
            (100.0, false),
            (104.9, false),
            (105.0, true),
            (159.9, true),
            (160.0, false),
            (164.9, false),
            (165.0, true),
            (3700.0, false),
            (3705.0, true),
        ] {
            assert_eq!(inj.link_up(t), up, "t = {t}");
        }
        assert_eq!(inj.next_disconnect_s(0.0), Some(100.0));
        assert_eq!(inj.next_disconnect_s(100.0), Some(100.0));
        assert_eq!(inj.next_disconnect_s(100.5), Some(160.0));
        assert_eq!(inj.next_disconnect_s(160.0), Some(160.0));
        assert_eq!(inj.latest_outage_start_s(99.0), None);
        assert_eq!(inj.latest_outage_start_s(170.0), Some(160.0));
        // Three devices notice the first outage, one the second: two outages.
        inj.note_disconnect("arms", 100.0);
        inj.note_disconnect("stage", 100.0);
        inj.note_refused_open("arms", 101.0);
        inj.note_disconnect("arms", 160.0);
        let c = inj.counts();
        assert_eq!((c.outages, c.disconnects, c.refused_opens), (2, 3, 1));
        // Without a period there is one outage only (the original behaviour).
        let once = faults(|c| {
            c.disconnect_after_s = Some(100.0);
            c.reconnect_after_s = Some(5.0);
        });
        assert!(once.link_up(160.0));
        assert_eq!(once.next_disconnect_s(100.5), None);
    }

    #[test]
    fn jitter_delays_every_reply_within_its_bounds() {
        let inj = faults(|c| {
            c.delay_ms = 2.0;
            c.delay_jitter_ms = 10.0;
        });
        let dev = inj.for_device("arms");
        let delays: Vec<f64> = (0..500).map(|_| dev.reply_delay_s()).collect();
        assert!(delays.iter().all(|d| (0.002..=0.012).contains(d)), "{delays:?}");
        let mean = delays.iter().sum::<f64>() / 500.0;
        assert!((mean - 0.007).abs() < 0.001, "mean {mean}");
        assert_eq!(inj.counts().delayed, 500);
    }

    #[test]
    fn periodic_disconnect_settings_are_checked() {
        let base = Faults {
            disconnect_after_s: Some(10.0),
            reconnect_after_s: Some(5.0),
            disconnect_every_s: Some(60.0),
            ..Faults::default()
        };
        assert_eq!(FaultInjector::validate(&base), Ok(()));
        for (cfg, key) in [
            (
                Faults {
                    disconnect_every_s: Some(5.0),
                    ..base.clone()
                },
                "disconnect_every_s",
            ),
            (
                Faults {
                    reconnect_after_s: None,
                    ..base.clone()
                },
                "reconnect_after_s",
            ),
            (
                Faults {
                    delay_jitter_ms: -1.0,
                    ..Faults::default()
                },
                "delay_jitter_ms",
            ),
        ] {
            let msg = FaultInjector::validate(&cfg).expect_err("refused").0;
            assert!(msg.contains(key), "{msg}");
        }
    }

    #[test]
    fn validation_names_the_key() {
        let cfg = Faults {
            drop_rate: 1.5,
            ..Faults::default()
        };
        let msg = FaultInjector::validate(&cfg).expect_err("out of range").0;
        assert!(msg.contains("drop_rate"), "{msg}");
    }
}
