use super::*;
use proptest::prelude::*;
use rotorhive_msg::Shapes;
const PACKED_LEN: usize = Shapes::PAPER.packed_len();
const PAPER_ROWS: RowLayout = RowLayout::Transition(Shapes::PAPER);

fn host() -> Host {
    Host {
        name: "w".into(),
        slot: 1,
        envs: 2,
        agents: 3,
        env_offset: 1,
        epoch: 0,
        token: String::new(),
    }
}

fn batch(actor: u32, rows: &[(f32, f32, f32)]) -> (Vec<u8>, Vec<u8>) {
    let obs = vec![0.5f32; Shapes::PAPER.obs_len()];
    let mut words = vec![0u16; rows.len() * PACKED_LEN];
    for (t, &(a, r, d)) in words.chunks_exact_mut(PACKED_LEN).zip(rows) {
        Shapes::PAPER.pack(&obs, &obs, [a, r, d, rotorhive_msg::NO_EXPERT, 0.0], t);
    }
    let h = TransitionHeader { actor, count: rows.len() as u32, seq: 0, weight_version: 0 };
    let link = LinkHeader { epoch: 0, seq: 0 };
    (wire::transition_attachment(&h, &link), wire::payload_bytes(&words).to_vec())
}

#[test]
fn a_transitions_expert_action_and_demonstration_flag_cross_intact() {
    // A demonstration (the teacher flew it) and a labelled student step:
    // the bytes the worker sends pass the head's checks and unpack to
    // the same teacher fields; a forged flag is refused.
    let shapes = Shapes::PAPER;
    let obs = vec![0.25f32; shapes.obs_len()];
    let mut words = vec![0u16; 3 * PACKED_LEN];
    let tails = [[1.0, 3.0, 0.0, 1.0, 1.0], [0.0, 3.0, 0.0, 1.0, 0.0], [0.0, 3.0, 0.0, 0.0, 0.0]];
    for (t, tail) in words.chunks_exact_mut(PACKED_LEN).zip(tails) {
        shapes.pack(&obs, &obs, tail, t);
    }
    let h = TransitionHeader { actor: 1, count: 3, seq: 0, weight_version: 0 };
    let link = LinkHeader { epoch: 0, seq: 0 };
    let (att, bytes) = (wire::transition_attachment(&h, &link), wire::payload_bytes(&words));
    assert!(transitions(&host(), RowLayout::Transition(shapes), Some(&att), &[bytes]).is_ok());
    let mut t = vec![0f32; shapes.transition_len()];
    for (p, tail) in bytes.chunks_exact(PACKED_LEN * 2).zip(tails) {
        let w: Vec<u16> = p.chunks_exact(2).map(|b| u16::from_le_bytes([b[0], b[1]])).collect();
        shapes.unpack(&w, &mut t);
        assert_eq!(t[2 * shapes.obs_len()..], tail);
    }
    shapes.pack(&obs, &obs, [1.0, 3.0, 0.0, 1.0, 0.5], &mut words[..PACKED_LEN]);
    let bytes = wire::payload_bytes(&words);
    assert_eq!(
        transitions(&host(), RowLayout::Transition(shapes), Some(&att), &[bytes]).unwrap_err(),
        Reject::Values(1)
    );
}

#[test]
fn a_sequence_crosses_with_its_state_and_teacher_fields_exact() {
    // With memory a row is a sequence (R2D2's stored state at its end):
    // the worker's bytes pass the head's checks and unpack to the same
    // state, labels and flags; a state that is not finite is refused,
    // and so are more sequences than the worker has agents.
    let layout = rotorhive_msg::SeqLayout { shapes: Shapes::PAPER, steps: 4, width: 3 };
    let rows = RowLayout::Sequence(layout);
    let obs: Vec<f32> = (0..5 * Shapes::PAPER.obs_len()).map(|i| (i % 7) as f32 / 7.0).collect();
    let tails = [
        [1.0, 0.5, 0.0, 1.0, 1.0],
        [0.0, -1.0, 1.0, rotorhive_msg::NO_EXPERT, 0.0],
        [1.0, 0.0, 0.0, 0.0, 0.0],
        [0.0, 2.0, 0.0, 1.0, 0.0],
    ];
    let state = [0.125, -0.75, 1.5e-3];
    let mut words = vec![0u16; 2 * layout.packed_len()];
    for w in words.chunks_exact_mut(layout.packed_len()) {
        layout.pack(&obs, &tails, &state, w);
    }
    let h = TransitionHeader { actor: 1, count: 2, seq: 0, weight_version: 0 };
    let link = LinkHeader { epoch: 0, seq: 0 };
    let (att, bytes) = (wire::transition_attachment(&h, &link), wire::payload_bytes(&words));
    assert!(transitions(&host(), rows, Some(&att), &[bytes]).is_ok());
    let (a, b) = bytes.split_at(bytes.len() / 2 + 5);
    assert!(transitions(&host(), rows, Some(&att), &[a, b]).is_ok());
    let back: Vec<u16> = bytes.chunks_exact(2).map(|b| u16::from_le_bytes([b[0], b[1]])).collect();
    let mut u = rotorhive_msg::Unpacked::default();
    for w in back.chunks_exact(layout.packed_len()) {
        layout.unpack_into(w, &mut u);
    }
    assert_eq!(u.states, [state, state].concat());
    assert_eq!(u.experts[..4], tails.map(|t| t[3]));
    assert_eq!(u.actions[..4], [1, 0, 1, 0]);
    assert!(rows.is_demo(&back[..layout.packed_len()]) == (tails[3][4] == 1.0));
    // A transition-sized reading of the same bytes does not pass.
    assert!(transitions(&host(), PAPER_ROWS, Some(&att), &[bytes]).is_err());
    layout.pack(&obs, &tails, &[0.0, f32::NAN, 0.0], &mut words[..layout.packed_len()]);
    let bytes = wire::payload_bytes(&words);
    assert_eq!(transitions(&host(), rows, Some(&att), &[bytes]).unwrap_err(), Reject::Values(1));
    let many = TransitionHeader { count: 4, ..h };
    let att = wire::transition_attachment(&many, &link);
    assert_eq!(transitions(&host(), rows, Some(&att), &[bytes]).unwrap_err(), Reject::Count(4));
}

#[test]
fn transitions_are_checked_for_length_sender_and_values_in_any_fragments() {
    let good = [(1.0, 3.0, 0.0), (0.0, -100.0, 1.0)];
    let (h, p) = batch(2, &good);
    // Whole, and in fragments cut anywhere (also inside a scalar).
    assert!(transitions(&host(), PAPER_ROWS, Some(&h), &[&p]).is_ok());
    for cut in [1, 7, Shapes::PAPER.packed_depth() * 2 + 3, p.len() - 1] {
        let (a, b) = p.split_at(cut);
        assert!(transitions(&host(), PAPER_ROWS, Some(&h), &[a, b]).is_ok(), "cut at {cut}");
    }
    assert_eq!(
        transitions(&host(), PAPER_ROWS, Some(&h), &[&p[1..]]).unwrap_err(),
        Reject::Length { got: p.len() - 1, want: p.len() }
    );
    let odd = [&p[..], &[0u8][..]].concat();
    assert!(matches!(
        transitions(&host(), PAPER_ROWS, Some(&h), &[&odd]),
        Err(Reject::Length { .. })
    ));
    assert_eq!(transitions(&host(), PAPER_ROWS, Some(&h[1..]), &[&p]).unwrap_err(), Reject::Header);
    assert_eq!(transitions(&host(), PAPER_ROWS, None, &[&p]).unwrap_err(), Reject::Header);
    // Environment 0 is the head's and 3 is past this host's two.
    for actor in [0, 3, u32::MAX] {
        let (h, p) = batch(actor, &good);
        assert_eq!(
            transitions(&host(), PAPER_ROWS, Some(&h), &[&p]).unwrap_err(),
            Reject::Actor(actor)
        );
    }
    let (h, p) = batch(1, &[(1.0, f32::NAN, 0.0), (2.0, 1.0, 0.0), (0.0, 1.0, 0.5)]);
    let (a, b) = p.split_at(Shapes::PAPER.packed_depth() * 2 + 1);
    assert_eq!(transitions(&host(), PAPER_ROWS, Some(&h), &[a, b]).unwrap_err(), Reject::Values(3));
    // With the hold action, action 2 is one of the run's.
    let hold = Shapes::task(rotorhive_msg::FRAMES, false, true);
    assert_eq!(
        transitions(&host(), RowLayout::Transition(hold), Some(&h), &[a, b]).unwrap_err(),
        Reject::Values(2)
    );
    let (h, _) = batch(1, &[]);
    assert_eq!(transitions(&host(), PAPER_ROWS, Some(&h), &[]).unwrap_err(), Reject::Count(0));
}

#[test]
fn episodes_telemetry_and_weights_are_checked() {
    let eh = |actor, count| EpisodeHeader { actor, count, epsilon_micro: 100_000, step: 0 };
    let rec = |r: [f32; 4]| r.iter().flat_map(|v| v.to_le_bytes()).collect::<Vec<u8>>();
    let good = rec([450.0, 150.0, 2.0, 0.1]);
    assert!(episodes(&host(), Some(wire::header_bytes(&eh(1, 1))), &good).is_ok());
    assert_eq!(
        episodes(&host(), Some(wire::header_bytes(&eh(0, 1))), &good).unwrap_err(),
        Reject::Actor(0)
    );
    assert!(matches!(
        episodes(&host(), Some(wire::header_bytes(&eh(1, 2))), &good),
        Err(Reject::Length { .. })
    ));
    assert!(matches!(
        episodes(&host(), Some(wire::header_bytes(&eh(1, 1))), &good[..15]),
        Err(Reject::Length { .. })
    ));
    for bad in [
        [f32::INFINITY, 150.0, 2.0, 0.1],
        [1.0, 0.0, 2.0, 0.1],
        [1.0, 1.5, 2.0, 0.1],
        [1.0, 9.0, 0.0, 0.1],
        [1.0, 9.0, 2.0, 1.5],
    ] {
        assert_eq!(
            episodes(&host(), Some(wire::header_bytes(&eh(1, 1))), &rec(bad)).unwrap_err(),
            Reject::Values(1),
            "{bad:?}"
        );
    }
    let t = |role: RoleKind, index| Telemetry { role: role as u32, index, ..Telemetry::default() };
    assert!(telemetry(&host(), Some(wire::header_bytes(&t(RoleKind::Sim, 2))), 0).is_ok());
    assert!(telemetry(&host(), Some(wire::header_bytes(&t(RoleKind::Link, 1))), 0).is_ok());
    for (role, index) in [
        (RoleKind::Sim, 0),
        (RoleKind::Actor, 3),
        (RoleKind::Learner, 0),
        (RoleKind::Replay, 0),
        (RoleKind::Link, 2),
    ] {
        assert!(
            matches!(
                telemetry(&host(), Some(wire::header_bytes(&t(role, index))), 0),
                Err(Reject::Role { .. })
            ),
            "{role:?} {index}"
        );
    }
    let mut nan = t(RoleKind::Actor, 1);
    nan.learning.eps_max = f32::NAN;
    assert_eq!(
        telemetry(&host(), Some(wire::header_bytes(&nan)), 0).unwrap_err(),
        Reject::Values(1)
    );
    let wh = WeightsHeader { version: 1, len: 3, ..WeightsHeader::default() };
    let w = rec([1.0, 2.0, 3.0, 0.0]);
    assert!(weights(3, Some(wire::header_bytes(&wh)), &w[..12]).is_ok());
    assert!(matches!(
        weights(4, Some(wire::header_bytes(&wh)), &w[..12]),
        Err(Reject::Length { .. })
    ));
    let w = rec([1.0, f32::NAN, 3.0, 0.0]);
    assert_eq!(weights(3, Some(wire::header_bytes(&wh)), &w[..12]).unwrap_err(), Reject::Values(1));
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2000))]
    /// Arbitrary bytes never panic a decoder or a check.
    #[test]
    fn arbitrary_bytes_are_refused_or_read_never_a_panic(att in proptest::collection::vec(any::<u8>(), 0..200), p in proptest::collection::vec(any::<u8>(), 0..20_000), cut in 0usize..20_000) {
        let cut = cut.min(p.len());
        let (a, b) = p.split_at(cut);
        let _ = transitions(&host(), PAPER_ROWS, Some(&att), &[a, b]);
        let _ = episodes(&host(), Some(&att), &p);
        let _ = telemetry(&host(), Some(&att), p.len());
        let _ = weights(3, Some(&att), &p);
        let _ = wire::Hello::decode(&p);
        let _ = wire::Welcome::decode(&p);
        let _ = crate::head::host::slot_of(&String::from_utf8_lossy(&p), "r", "transitions");
    }

    /// A header that fits, with arbitrary counts, indexes and payloads.
    #[test]
    fn arbitrary_headers_with_arbitrary_payloads(actor in any::<u32>(), count in any::<u32>(), p in proptest::collection::vec(any::<u8>(), 0..40_000)) {
        let h = TransitionHeader { actor, count, seq: 0, weight_version: 0 };
        let att = wire::transition_attachment(&h, &LinkHeader::default());
        let r = transitions(&host(), PAPER_ROWS, Some(&att), &[&p]);
        prop_assert!(r.is_err() || p.len() == count as usize * PACKED_LEN * 2);
        let e = EpisodeHeader { actor, count, epsilon_micro: 0, step: 0 };
        let r = episodes(&host(), Some(wire::header_bytes(&e)), &p);
        prop_assert!(r.is_err() || p.len() == count as usize * EPISODE_FIELDS * 4);
    }
}
