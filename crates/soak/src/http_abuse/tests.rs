use super::*;

#[test]
fn the_state_is_read_from_a_status_answer() {
    assert_eq!(
        state_of(r#"{"id":1,"state":"completed","points_done":3}"#),
        Some(CampaignState::Completed)
    );
    assert_eq!(state_of(r#"{"state":"no-such-state"}"#), None);
    assert_eq!(state_of("not json"), None);
}
