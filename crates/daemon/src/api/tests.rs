//! Unit tests of the API: the token rule and constant-time comparison.

use super::*;

#[test]
fn constant_time_eq_matches_plain_equality() {
    let cases: [(&[u8], &[u8]); 6] = [
        (b"", b""),
        (b"secret", b"secret"),
        (b"secret", b"secreT"),
        (b"secret", b"Secret"),
        (b"secret", b"secret!"),
        (b"s", b""),
    ];
    for (a, b) in cases {
        assert_eq!(constant_time_eq(a, b), a == b, "{a:?} vs {b:?}");
    }
}

#[test]
fn token_rule() {
    let loopback: SocketAddr = "127.0.0.1:7878".parse().expect("addr");
    let loopback6: SocketAddr = "[::1]:7878".parse().expect("addr");
    let any: SocketAddr = "0.0.0.0:7878".parse().expect("addr");
    let lan: SocketAddr = "192.0.2.10:7878".parse().expect("addr");
    assert!(check_listen(loopback, None).is_ok());
    assert!(check_listen(loopback6, None).is_ok());
    assert!(matches!(
        check_listen(any, None),
        Err(ListenError::TokenRequired(_))
    ));
    assert!(matches!(
        check_listen(lan, None),
        Err(ListenError::TokenRequired(_))
    ));
    assert!(check_listen(any, Some("t0k3n")).is_ok());
    assert!(matches!(
        check_listen(any, Some("")),
        Err(ListenError::EmptyToken)
    ));
    let message = check_listen(any, None).expect_err("refused").to_string();
    assert!(
        message.contains("0.0.0.0:7878") && message.contains("--token"),
        "{message}"
    );
}
