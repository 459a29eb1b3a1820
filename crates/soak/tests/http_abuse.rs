//! CI-sized HTTP abuse: slow, idle and body-trickling clients beyond the daemon's connection limit and oversized
//! bodies while it runs a campaign; the daemon answers every status request, refuses every oversized body, closes
//! the slow connections, and the campaign completes with every point.

use gonio_daemon::store::CampaignState;
use gonio_soak::http_abuse::{HttpAbuseConfig, run_http_abuse};

#[test]
fn hostile_clients_cannot_stop_the_daemon_or_its_campaign() {
    let dir = tempfile::tempdir().expect("tempdir");
    let cfg = HttpAbuseConfig::quick(30, 4, dir.path().join("data"));
    let slow = cfg.header_tricklers + cfg.body_tricklers + cfg.idle;
    assert!(
        slow > cfg.api.max_connections,
        "more slow clients than the daemon admits"
    );
    let r = run_http_abuse(&cfg).expect("the soak runs");
    eprintln!(
        "probes {} (slowest {:.3} s), header {:?}, body {:?}, idle {:?}, oversized {:?}, campaign {:.1} s",
        r.probes(),
        r.latency_quantile_s(1.0),
        r.header_tricklers,
        r.body_tricklers,
        r.idle,
        r.oversized,
        r.campaign_wall_s
    );
    assert_eq!(r.violations(), Vec::<String>::new());
    assert_eq!(r.data_lost(), 0);
    assert!(r.probe_failures.is_empty(), "{:?}", r.probe_failures);
    assert!(r.probes() >= 2, "the status was asked more than once");
    // Every oversized body refused; the announced ones with 413 before any byte of the body was sent.
    let announced = &r.oversized[0];
    assert!(
        announced.sent > 0 && announced.refused_413 == announced.sent,
        "{announced:?}"
    );
    for o in &r.oversized {
        assert!(o.sent > 0 && o.refused_413 + o.closed == o.sent, "{o:?}");
    }
    // The daemon closed slow connections (evicted for newcomers, or past the header deadline).
    assert!(
        r.header_tricklers.ended_by_daemon() > 0,
        "{:?}",
        r.header_tricklers
    );
    assert!(r.idle.ended_by_daemon() > 0, "{:?}", r.idle);
    // A body within the limit is waited for, never refused at once: only evictions and the body deadline (408)
    // end a trickled body.
    assert!(r.body_tricklers.ended_by_daemon() > 0, "{:?}", r.body_tricklers);
    assert!(
        r.body_tricklers.answers.keys().all(|s| *s == 408),
        "{:?}",
        r.body_tricklers
    );
    assert_eq!(r.final_state, Some(CampaignState::Completed));
    assert_eq!(r.rows, 30);
    assert!(r.indices_in_order);
    assert_eq!(r.points.valid, 30);
}
