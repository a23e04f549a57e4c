use super::{DemoPlan, Demos, SampleLimit, SeqLog, Stores, demo_rows, sample, store};
use rotorhive_msg::{NO_EXPERT, PICK_WORDS, RowLayout, SeqLayout, Shapes, TAIL, TransitionHeader};
use rotorhive_replay::{Journal, Pick, Replay};

/// Packed rows of `layout` whose (last step's) reward is their number, each
/// a demonstration (expert 1, flag 1 at every step) where `demo(i)`, else
/// the student's.
fn rows(layout: RowLayout, from: u32, n: u32, demo: impl Fn(u32) -> bool) -> Vec<u16> {
    let shapes = layout.shapes();
    let obs = vec![0.5f32; shapes.obs_len()];
    let mut out = vec![0u16; n as usize * layout.packed_len()];
    for (k, r) in out.chunks_exact_mut(layout.packed_len()).enumerate() {
        let i = from + k as u32;
        let tail = if demo(i) {
            [1.0, i as f32, 0.0, 1.0, 1.0]
        } else {
            [0.0, i as f32, 0.0, NO_EXPERT, 0.0]
        };
        match layout {
            RowLayout::Transition(_) => shapes.pack(&obs, &obs, tail, r),
            RowLayout::Sequence(l) => {
                let all = obs.repeat(l.observations());
                l.pack(&all, &vec![tail; l.steps], &vec![0.25; l.width], r)
            }
        }
    }
    out
}

/// A row's (last step's) reward.
fn reward(layout: RowLayout, r: &[u16]) -> f32 {
    match layout {
        RowLayout::Transition(s) => s.packed_scalar(r, 2 * s.scalars + 1),
        RowLayout::Sequence(l) => {
            let mut v = Vec::new();
            l.values(r, &mut v);
            v[l.observations() * l.shapes.scalars + (l.steps - 1) * TAIL + 1]
        }
    }
}

#[test]
fn demonstrations_survive_a_full_replay_and_fill_their_share_of_a_batch() {
    let seq = SeqLayout { shapes: Shapes::PAPER, steps: 4, width: 3 };
    for layout in [RowLayout::Transition(Shapes::PAPER), RowLayout::Sequence(seq)] {
        demonstrations_survive(layout);
    }
}

/// Transitions or sequences (`layout`): the demonstrations in their
/// reservoir outlive twenty fills of the memory, fill their rows of a
/// minibatch, and come back from their journal.
fn demonstrations_survive(layout: RowLayout) {
    let w = layout.packed_len();
    let dir = std::env::temp_dir().join(format!("rotorhive-demos-{}-{w}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let (mut mem, mut journal) = Journal::open(&dir.join("replay.bin"), 50, w, 1).unwrap();
    let path = dir.join("replay-demo.bin");
    let (dm, dj) = Journal::open(&path, 20, w, 2).unwrap();
    let mut demos = Demos { mem: dm, journal: Some(dj) };
    // Mixed batches: every fifth row a demonstration, 12 of them.
    let mixed = rows(layout, 0, 60, |i| i % 5 == 0);
    fn stores<'a>(mem: &'a mut Replay, j: &'a mut Journal, d: &'a mut Demos) -> Stores<'a> {
        Stores { mem, journal: Some(j), demos: Some(d) }
    }
    store(stores(&mut mem, &mut journal, &mut demos), layout, &mixed, 3).unwrap();
    assert_eq!((mem.len(), demos.mem.len()), (48, 12));
    // Then the student's rows alone, twenty times the memory's size.
    for k in 0..20 {
        let own = rows(layout, 1000 + 50 * k, 50, |_| false);
        store(stores(&mut mem, &mut journal, &mut demos), layout, &own, 4).unwrap();
    }
    assert_eq!((mem.len(), demos.mem.len()), (50, 12), "the demonstrations are all there");
    // A minibatch of 8 with 3 demonstration rows: those first, drawn
    // from the reservoir, the rest the student's.
    let mut out = vec![0u16; 8 * (w + PICK_WORDS)];
    let mut picks = vec![Pick::default(); 8];
    sample(&mut mem, Some(&mut demos.mem), 3, &mut out, &mut picks, 0.4);
    for (k, r) in out[..8 * w].chunks_exact(w).enumerate() {
        let (demo, reward) = (layout.is_demo(r), reward(layout, r));
        if k < 3 {
            assert!(demo && reward < 60.0 && (reward as u32).is_multiple_of(5), "row {k}");
        } else {
            assert!(!demo && reward >= 1950.0, "row {k}: {reward}");
        }
    }
    // And a replay started again has them from their journal.
    drop(demos);
    let (again, _) = Journal::open(&path, 20, w, 2).unwrap();
    assert_eq!(again.len(), 12);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_replay_started_again_in_its_run_takes_up_its_predecessors_sequence_numbers() {
    let dir = std::env::temp_dir().join(format!("rotorhive-seqlog-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let h = |actor, seq| TransitionHeader { actor, count: 4, seq, weight_version: 0 };
    let log = SeqLog::open(Some(&dir), "run-a", 2);
    let mut t = log.resume();
    for seq in 0..5 {
        assert_eq!(t.observe(0, seq), 0);
        log.record(&h(0, seq));
    }
    // Killed with batches 5 and 6 in its queue; the next one takes up
    // where its predecessor stood.
    drop(log);
    let log = SeqLog::open(Some(&dir), "run-a", 2);
    let mut t = log.resume();
    assert_eq!(t.observe(0, 7), 2, "batches 5 and 6 lost");
    assert_eq!(t.observe(1, 3), 0, "an actor never seen before");
    // Another run's replay in the same directory starts afresh.
    let log = SeqLog::open(Some(&dir), "run-b", 2);
    assert_eq!(log.resume().observe(0, 9), 0);
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn sampling_waits_for_inserts_past_the_buffer() {
    let mut cfg = crate::config::Config::default();
    cfg.replay.samples_per_insert = 1.0;
    let mut lim = SampleLimit::new(&cfg);
    let buffer_batches = (lim.buffer / lim.batch) as u64;
    // Counted from the first minibatch: 15,000 already inserted.
    assert!(lim.allows(0, 15_000));
    assert!(lim.allows(buffer_batches - 1, 15_000));
    assert!(!lim.allows(buffer_batches, 15_000));
    // 320 more transitions pay for 10 more minibatches of 32, not 11.
    assert!(lim.allows(buffer_batches + 9, 15_320));
    assert!(!lim.allows(buffer_batches + 10, 15_320));
    cfg.replay.samples_per_insert = 0.0;
    let mut off = SampleLimit::new(&cfg);
    assert!(off.allows(1_000_000, 0));
}

#[test]
fn the_limit_counts_from_where_the_memory_was_ready() {
    // The replay asks on every loop; questions before min_fill must not fix
    // the start (CI once saw 85 minibatches of 32 out of 1,763 inserted).
    let mut cfg = crate::config::Config::default();
    cfg.replay.samples_per_insert = 1.0;
    let mut lim = SampleLimit::new(&cfg);
    let buffer_batches = (lim.buffer / lim.batch) as u64;
    for inserted in [0, 500, 14_999] {
        assert!(!lim.may_send(false, 0, 0, inserted), "sent before the memory was ready");
    }
    assert!(lim.may_send(true, 0, 0, 15_000));
    assert!(lim.may_send(true, buffer_batches - 1, 0, 15_000));
    assert!(!lim.may_send(true, buffer_batches, 0, 15_000), "counted from before min_fill");
    // Pre-training minibatches go out past the ratio, once ready.
    let mut pre = SampleLimit::new(&cfg);
    assert!(!pre.may_send(false, 0, 1_000, 15_000));
    assert!(pre.may_send(true, 999, 1_000, 15_000));
    assert!(pre.may_send(true, 1_000, 1_000, 15_000), "the first student minibatch");
    assert!(!pre.may_send(true, 1_000 + buffer_batches, 1_000, 15_000));
}

#[test]
fn pre_training_draws_whole_minibatches_of_demonstrations_then_their_share() {
    let mut t = crate::teacher::TeacherSection {
        policy: crate::teacher::TeacherPolicy::Planner,
        ..Default::default()
    };
    let plan = DemoPlan { pretrain: 3, batch: 32 };
    let rows = |t: &crate::teacher::TeacherSection, seq, held, inserted| {
        demo_rows(t, plan, seq, (held, inserted)).0
    };
    // The first three minibatches all demonstrations, then a quarter.
    assert_eq!((0..5).map(|s| rows(&t, s, true, 0)).collect::<Vec<_>>(), [32, 32, 32, 8, 8]);
    // None while the reservoir is empty, pre-training or not.
    assert_eq!((rows(&t, 0, false, 0), rows(&t, 4, false, 0)), (0, 0));
    // Half faded: the share halves, pre-training minibatches stay whole,
    // and the weight says how far the fade went.
    t.fade_env_steps = 1_000;
    assert_eq!((rows(&t, 0, true, 500), rows(&t, 3, true, 500)), (32, 4));
    assert_eq!(demo_rows(&t, plan, 3, (true, 500)).1, 0.5);
}
