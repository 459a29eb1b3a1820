//! Every reply parser fed arbitrary bytes: never a panic, and never a value out of a malformed reply.

use gonio_driver::fw102c::{Answer, parse_answer, parse_int};
use gonio_driver::pm100::{parse_scpi_error, parse_scpi_number};
use gonio_driver::smc100::{parse_number, parse_reply, parse_te, parse_ts};
use gonio_driver::usbtmc::decode_in_header;
use gonio_driver::zaber::{Message, checksum, parse_message};
use proptest::prelude::*;

proptest! {
    #![proptest_config(ProptestConfig { cases: 2000, ..ProptestConfig::default() })]

    #[test]
    fn smc100_parsers_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..40)) {
        if let Some((addr, cc, value)) = parse_reply(&bytes) {
            // Whatever was accepted really has the documented shape.
            prop_assert!((1..=31).contains(&addr));
            prop_assert!(cc.iter().all(u8::is_ascii_uppercase));
            let text = std::str::from_utf8(&bytes).expect("accepted lines are text");
            prop_assert!(text.starts_with(&addr.to_string()));
            prop_assert!(text.ends_with(value));
            if let Some(ts) = parse_ts(value) {
                prop_assert_eq!(value.len(), 6);
                let _ = ts.state.describe();
            }
            if let Some(x) = parse_number(value) { prop_assert!(x.is_finite()); }
            if let Some(c) = parse_te(value) { prop_assert_eq!(value.len(), 1); prop_assert!(c == '@' || c.is_ascii_uppercase()); }
        }
    }

    #[test]
    fn smc100_ts_rejects_all_but_six_hex_digits(s in "[0-9A-Fa-f]{0,8}|.{0,8}") {
        let hex = s.len() == 6 && s.bytes().all(|b| b.is_ascii_hexdigit());
        if !hex {
            prop_assert!(parse_ts(&s).is_none());
        }
    }

    #[test]
    fn zaber_parser_never_panics_and_checks_checksums(bytes in proptest::collection::vec(any::<u8>(), 0..60)) {
        if let Ok(Message::Reply(r)) = parse_message(&bytes) {
            prop_assert!(!r.data.is_empty());
            let text = std::str::from_utf8(&bytes).expect("accepted lines are text");
            prop_assert!(text.starts_with('@'));
        }
    }

    #[test]
    fn zaber_single_byte_corruption_of_a_checksummed_reply_is_caught(pos in 1usize..20, byte in 0x20u8..0x7f) {
        let body = "01 1 42 OK IDLE -- 12345";
        let line = format!("@{body}:{:02X}", checksum(body.as_bytes()));
        let mut bytes = line.into_bytes();
        let at = pos.min(body.len());
        prop_assume!(bytes[at] != byte);
        bytes[at] = byte;
        // Either the line no longer parses, or (never) it parses to the same values: a flipped byte is never
        // accepted as a valid reply.
        prop_assert!(parse_message(&bytes).is_err());
    }

    #[test]
    fn usbtmc_header_never_panics(bytes in proptest::collection::vec(any::<u8>(), 0..32)) {
        if let Ok(h) = decode_in_header(&bytes) {
            prop_assert!(bytes.len() >= 12);
            prop_assert_eq!(bytes[0], 2);
            prop_assert!(h.btag != 0);
            prop_assert_eq!(bytes[2], !bytes[1]);
        }
    }

    #[test]
    fn scpi_and_wheel_parsers_never_panic(s in ".{0,40}", bytes in proptest::collection::vec(any::<u8>(), 0..40)) {
        if let Some(x) = parse_scpi_number(&s) { prop_assert!(x.is_finite()); }
        let _ = parse_scpi_error(&s);
        match parse_answer("pos?", &bytes) {
            Some(Answer::Lines(lines)) => {
                if let Some(n) = parse_int(&lines) { prop_assert!(n < 1000); }
            }
            Some(Answer::Error(_)) | None => {}
        }
    }
}
