//! Random and mutated inputs through the public wire parsers and file loaders, counted: no panic (each call runs
//! under `catch_unwind`), and every refusal of a file loader a message that names the file.
//!
//! This is the cheap, reproducible census for `RELIABILITY.md`, not the fuzzing itself (that is the hardening
//! work of issue 8, with its own harnesses): a seeded stream of inputs, a quarter random bytes and the rest
//! mutations (flipped, inserted, deleted, duplicated bytes, truncations, special tokens) of valid samples.

use std::panic::{AssertUnwindSafe, catch_unwind};
use std::path::Path;
use std::time::Instant;

use gonio_brdf::material::Material;
use gonio_driver::{fw102c, pm100, smc100, usbtmc, zaber};
use gonio_engine::prepare_campaign;
use gonio_instrument::{InstrumentFile, SIMULATED_INSTRUMENT_TOML};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// The census of one parser or loader.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct InputStats {
    /// What was exercised (a function or a loader).
    pub name: String,
    pub tried: u64,
    pub accepted: u64,
    pub rejected: u64,
    pub panics: u64,
    /// Refusals whose message is empty or does not name the input (file loaders only).
    pub unclear: u64,
    /// The slowest single input (microseconds of wall time): a hang would show here first.
    pub slowest_us: u64,
}

/// What one call gave.
enum Outcome {
    Accepted,
    Rejected,
    /// Refused with a message that is empty or does not name the input.
    Unclear,
}

fn run_one(stats: &mut InputStats, f: impl FnOnce() -> Outcome) {
    let t = Instant::now();
    let r = catch_unwind(AssertUnwindSafe(f));
    stats.slowest_us = stats.slowest_us.max(t.elapsed().as_micros() as u64);
    stats.tried += 1;
    match r {
        Ok(Outcome::Accepted) => stats.accepted += 1,
        Ok(Outcome::Rejected) => stats.rejected += 1,
        Ok(Outcome::Unclear) => {
            stats.rejected += 1;
            stats.unclear += 1;
        }
        Err(_) => stats.panics += 1,
    }
}

fn opt<T>(v: Option<T>) -> Outcome {
    if v.is_some() {
        Outcome::Accepted
    } else {
        Outcome::Rejected
    }
}

/// A refusal is clear when its message is not empty and names `origin`.
fn named<T, E: std::fmt::Display>(r: Result<T, E>, origin: &str) -> Outcome {
    match r {
        Ok(_) => Outcome::Accepted,
        Err(e) => {
            let m = e.to_string();
            if m.trim().is_empty() || !m.contains(origin) {
                Outcome::Unclear
            } else {
                Outcome::Rejected
            }
        }
    }
}

/// Byte-level mutations of a seed, or random bytes.
fn mutate(rng: &mut ChaCha8Rng, seeds: &[&[u8]], max_random: usize) -> Vec<u8> {
    const TOKENS: [&[u8]; 12] = [
        b"9.9E37",
        b"nan",
        b"inf",
        b"-",
        b"\r\n",
        b"\n",
        b"\"",
        b"[",
        b"=",
        b"1e999",
        b"\0",
        b"\xff\xfe",
    ];
    if seeds.is_empty() || rng.random_range(0..4) == 0 {
        let n = rng.random_range(0..=max_random);
        return (0..n).map(|_| rng.random()).collect();
    }
    let mut v = seeds[rng.random_range(0..seeds.len())].to_vec();
    for _ in 0..rng.random_range(1..=4) {
        let len = v.len();
        match rng.random_range(0..7) {
            0 if len > 0 => {
                let i = rng.random_range(0..len);
                v[i] = rng.random();
            }
            1 => {
                let i = rng.random_range(0..=len);
                v.insert(i, rng.random());
            }
            2 if len > 0 => {
                v.remove(rng.random_range(0..len));
            }
            3 if len > 0 => v.truncate(rng.random_range(0..len)),
            4 if len > 0 => {
                let a = rng.random_range(0..len);
                let b = rng.random_range(a..=len.min(a + 32));
                let slice = v[a..b].to_vec();
                let at = rng.random_range(0..=v.len());
                v.splice(at..at, slice);
            }
            5 => {
                let t = TOKENS[rng.random_range(0..TOKENS.len())];
                let at = rng.random_range(0..=len);
                v.splice(at..at, t.iter().copied());
            }
            _ if len > 0 => {
                // Flip a digit to another digit: the garble a parser cannot see, kept valid-looking.
                let i = rng.random_range(0..len);
                if v[i].is_ascii_digit() {
                    v[i] = b'0' + rng.random_range(0..10u8);
                }
            }
            _ => {}
        }
    }
    v
}

fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

/// Run `per_parser` inputs through each wire parser and `per_loader` through each file loader.
pub fn run_inputs(seed: u64, per_parser: u64, per_loader: u64) -> Vec<InputStats> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed ^ 0x1a7e_5ca1_e000_0001);
    let mut out = Vec::new();
    let mut census =
        |name: &str, n: u64, rng: &mut ChaCha8Rng, mut f: Box<dyn FnMut(&mut ChaCha8Rng) -> Outcome>| {
            let mut s = InputStats {
                name: name.to_string(),
                ..InputStats::default()
            };
            for _ in 0..n {
                run_one(&mut s, || f(rng));
            }
            out.push(s);
        };

    // Wire parsers (driver side), seeded with the replies the devices really send.
    let smc: [&[u8]; 6] = [
        b"1TS000033",
        b"2TP12.50000",
        b"1TE@",
        b"1PT0.48126",
        b"2TS00003D",
        b"1TH-5.0",
    ];
    census(
        "SMC100 reply line (smc100::parse_reply, parse_ts, parse_number, parse_te)",
        per_parser,
        &mut rng,
        Box::new(move |rng| {
            let line = mutate(rng, &smc, 24);
            match smc100::parse_reply(&line) {
                Some((_, cc, value)) => {
                    let ok = match &cc {
                        b"TS" => smc100::parse_ts(value).is_some(),
                        b"TE" => smc100::parse_te(value).is_some(),
                        _ => smc100::parse_number(value).is_some(),
                    };
                    if ok { Outcome::Accepted } else { Outcome::Rejected }
                }
                None => Outcome::Rejected,
            }
        }),
    );
    let zab: [&[u8]; 5] = [
        b"@01 1 37 OK IDLE -- 47790",
        b"@01 2 12 OK BUSY -- 0",
        b"!01 1 IDLE --",
        b"#01 1 12 comm.alert 1",
        b"@01 0 5 RJ IDLE WR BADCOMMAND:4F",
    ];
    census(
        "Zaber ASCII message (zaber::parse_message)",
        per_parser,
        &mut rng,
        Box::new(move |rng| match zaber::parse_message(&mutate(rng, &zab, 48)) {
            Ok(_) => Outcome::Accepted,
            Err(e) if e.to_string().is_empty() => Outcome::Unclear,
            Err(_) => Outcome::Rejected,
        }),
    );
    let fw: [&[u8]; 4] = [
        b"pos?\r3\r",
        b"pos=2\r",
        b"pcount?\r6\r",
        b"pos?\rCMD_NOT_DEFINED\r",
    ];
    census(
        "FW102C answer (fw102c::parse_answer, parse_int)",
        per_parser,
        &mut rng,
        Box::new(move |rng| {
            let b = mutate(rng, &fw, 24);
            let command = if b.starts_with(b"pcount") {
                "pcount?"
            } else {
                "pos?"
            };
            match fw102c::parse_answer(command, &b) {
                Some(fw102c::Answer::Lines(lines)) => opt(fw102c::parse_int(&lines)),
                Some(_) | None => Outcome::Rejected,
            }
        }),
    );
    let scpi: [&[u8]; 5] = [
        b"+1.234000E-03",
        b"9.9E37",
        b"0,\"No error\"",
        b"-113,\"Undefined header\"",
        b"5.000000E-06",
    ];
    census(
        "PM100 SCPI answer (pm100::parse_scpi_number, parse_scpi_error)",
        per_parser,
        &mut rng,
        Box::new(move |rng| {
            let t = text(&mutate(rng, &scpi, 32));
            opt(pm100::parse_scpi_number(&t)
                .map(|_| ())
                .or(pm100::parse_scpi_error(&t).map(|_| ())))
        }),
    );
    let header = usbtmc::encode_dev_dep_msg_out(7, b"MEAS:POW?\n", true);
    let mut in_header = header.clone();
    if let Some(b) = in_header.first_mut() {
        // DEV_DEP_MSG_IN (2): what a Bulk-IN transfer starts with.
        *b = 2;
    }
    census(
        "USBTMC Bulk-IN header (usbtmc::decode_in_header)",
        per_parser,
        &mut rng,
        Box::new(move |rng| {
            let seeds: [&[u8]; 1] = [&in_header];
            match usbtmc::decode_in_header(&mutate(rng, &seeds, 24)) {
                Ok(_) => Outcome::Accepted,
                Err(e) if e.to_string().is_empty() => Outcome::Unclear,
                Err(_) => Outcome::Rejected,
            }
        }),
    );

    // File loaders: the instrument file, campaign files, material files.
    census(
        "instrument file (InstrumentFile::parse)",
        per_loader,
        &mut rng,
        Box::new(|rng| {
            let seeds: [&[u8]; 1] = [SIMULATED_INSTRUMENT_TOML.as_bytes()];
            named(
                InstrumentFile::parse(&text(&mutate(rng, &seeds, 256)), "fuzz.toml"),
                "fuzz.toml",
            )
        }),
    );
    let instrument = InstrumentFile::simulated();
    let empty = tempfile::tempdir().ok();
    let base = empty
        .as_ref()
        .map(|d| d.path().to_path_buf())
        .unwrap_or_else(|| Path::new("/nonexistent").into());
    let campaigns: [&[u8]; 2] = [
        include_str!("../../../config/campaigns/demo.toml").as_bytes(),
        SMALL_CAMPAIGN.as_bytes(),
    ];
    let b2 = base.clone();
    census(
        "campaign file (engine::prepare_campaign)",
        per_loader,
        &mut rng,
        Box::new(move |rng| {
            named(
                prepare_campaign(
                    &text(&mutate(rng, &campaigns, 256)),
                    "fuzz-campaign.toml",
                    &b2,
                    &instrument,
                ),
                "fuzz-campaign.toml",
            )
        }),
    );
    let materials: [&[u8]; 6] = [
        include_str!("../../../config/materials/coloured-plastic.toml").as_bytes(),
        include_str!("../../../config/materials/construction-paper.toml").as_bytes(),
        include_str!("../../../config/materials/gold.toml").as_bytes(),
        include_str!("../../../config/materials/mirror.toml").as_bytes(),
        include_str!("../../../config/materials/spectralon.toml").as_bytes(),
        include_str!("../../../config/materials/white-styrofoam.toml").as_bytes(),
    ];
    census(
        "material file (Material::from_document)",
        per_loader,
        &mut rng,
        Box::new(move |rng| {
            named(
                Material::from_document(&text(&mutate(rng, &materials, 256)), "fuzz-material.toml", &base),
                "fuzz-material.toml",
            )
        }),
    );
    drop(empty);
    out
}

/// A small valid campaign: a seed that parses quickly and plans few points.
const SMALL_CAMPAIGN: &str = r#"[campaign]
id = "fuzz"
[sample]
radius_mm = 12.5
[plan]
bands_nm = [550.0]
[plan.grid]
kind = "isotropic"
theta_i_deg = { from = 0.0, to = 60.0, step = 30.0 }
theta_o_deg = [10.0, 40.0]
delta_phi_deg = [0.0, 90.0]
[calibration]
simulate_operator = true
[acquisition]
averaging = 10
[material]
preset = "spectralon"
"#;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_census_counts_every_input_and_the_seeds_are_accepted() {
        let stats = run_inputs(1, 200, 5);
        assert_eq!(stats.len(), 8);
        for s in &stats {
            assert_eq!(s.tried, s.accepted + s.rejected + s.panics, "{s:?}");
            assert!(s.rejected > 0, "random inputs are refused: {s:?}");
        }
        assert!(
            stats[0].accepted > 0,
            "mutations keep some SMC100 replies valid: {:?}",
            stats[0]
        );
    }

    #[test]
    fn a_refusal_must_name_the_input() {
        assert!(matches!(
            named::<(), _>(Err("bad value"), "x.toml"),
            Outcome::Unclear
        ));
        assert!(matches!(
            named::<(), _>(Err("x.toml:3: bad value"), "x.toml"),
            Outcome::Rejected
        ));
        let mut s = InputStats::default();
        run_one(&mut s, || panic!("boom"));
        assert_eq!((s.tried, s.panics), (1, 1));
    }
}
