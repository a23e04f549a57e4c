use super::*;

#[test]
fn per_actor_epsilons_follow_ape_x() {
    // Ape-X's N = 50: from 0.4 down to 0.4^8, the median about 0.016.
    let e: Vec<f64> = (0..50).map(|i| per_actor_epsilon(0.4, 7.0, i, 50)).collect();
    assert!((e[0] - 0.4).abs() < 1e-12 && (e[49] - 0.4f64.powi(8)).abs() < 1e-12);
    assert!(e.windows(2).all(|w| w[1] < w[0]));
    let mut cfg = Config::default();
    cfg.actor.exploration = crate::Exploration::PerActor;
    cfg.sim.envs = 2;
    cfg.sim.agents = 25;
    let mut out = vec![0.0; 25];
    // Before min_fill every agent explores at eps_start.
    agent_epsilons(&cfg, 1, 10, &mut out);
    assert!(out.iter().all(|v| *v == 1.0));
    // Then environment 1's agents are the run's agents 25..50.
    agent_epsilons(&cfg, 1, 1_000_000, &mut out);
    assert_eq!(out, e[25..]);
    // A worker's environments come after the head's.
    cfg.cluster.env_offset = 1;
    cfg.sim.envs = 1;
    cfg.cluster.envs_elsewhere = 1;
    cfg.cluster.agents_elsewhere = 25;
    agent_epsilons(&cfg, 0, 1_000_000, &mut out);
    assert_eq!(out, e[25..]);
    // The one schedule gives every agent the same rate.
    cfg.actor.exploration = crate::Exploration::Decay;
    agent_epsilons(&cfg, 0, 1_000_000, &mut out);
    assert!(out.iter().all(|v| (*v - cfg.actor.eps_end).abs() < 1e-12), "{out:?}");
}

/// The student's own steps, unlabelled.
fn student(actions: &[u8]) -> Taken<'_> {
    const NONE: [f32; 2] = [NO_EXPERT; 2];
    Taken { actions, experts: &NONE[..actions.len()], flown: &[false; 2][..actions.len()] }
}

#[test]
fn n_step_transitions_carry_the_teachers_action_of_their_first_step() {
    let len = Shapes::PAPER.obs_len();
    let mut s = NStep::new(2, 0.5, 2, len);
    s.store(&vec![0.0; 2 * len]);
    // Agent 0 is flown by the teacher (action 1, its own); agent 1 is
    // the student's, labelled 0 where it took 1.
    let step = |s: &mut NStep, e: [f32; 2], done: f32| {
        s.push(
            Taken { actions: &[1, 1], experts: &e, flown: &[true, false] },
            &[3.0, 3.0],
            &[done, done],
        );
        s.out.iter().map(|t| (t.agent, t.expert, t.demo)).collect::<Vec<_>>()
    };
    assert!(step(&mut s, [1.0, 0.0], 0.0).is_empty());
    s.store(&vec![1.0; 2 * len]);
    // The next step's labels do not leak into the first transition.
    assert_eq!(step(&mut s, [0.0, NO_EXPERT], 0.0), vec![(0, 1.0, true), (1, 0.0, false)]);
    s.store(&vec![2.0; 2 * len]);
    assert_eq!(
        step(&mut s, [1.0, 1.0], 1.0),
        vec![(0, 0.0, true), (0, 1.0, true), (1, NO_EXPERT, false), (1, 1.0, false)]
    );
}

#[test]
fn n_step_returns_and_episode_ends() {
    let len = Shapes::PAPER.obs_len();
    let mut s = NStep::new(3, 0.5, 1, len);
    let obs = |v: f32| vec![v; len];
    s.store(&obs(0.0));
    // Steps with rewards 1, 2, 4: the first transition leaves with
    // 1 + 0.5·2 + 0.25·4 = 3, from observation 0, not done.
    let mut left = Vec::new();
    for (k, r) in [1.0, 2.0, 4.0].into_iter().enumerate() {
        s.push(student(&[k as u8 % 2]), &[r], &[0.0]);
        left.extend(s.out.iter().map(|t| (s.obs(t.slot, 0)[0], t.action, t.ret, t.done)));
        s.store(&obs(k as f32 + 1.0));
    }
    assert_eq!(left, vec![(0.0, 0, 3.0, false)]);
    // The episode ends with reward −8: the two pending steps and this
    // one leave as done: 2 + 0.5·4 + 0.25·(−8) = 2, 4 − 4 = 0, −8.
    s.push(student(&[1]), &[-8.0], &[1.0]);
    let got: Vec<_> = s.out.iter().map(|t| (s.obs(t.slot, 0)[0], t.ret, t.done)).collect();
    assert_eq!(got, vec![(1.0, 2.0, true), (2.0, 0.0, true), (3.0, -8.0, true)]);
    // One-step returns are the plain transitions.
    let mut one = NStep::new(1, 0.99, 2, len);
    one.store(&[obs(5.0), obs(6.0)].concat());
    one.push(student(&[0, 1]), &[3.0, -100.0], &[0.0, 1.0]);
    let got: Vec<_> =
        one.out.iter().map(|t| (t.agent, one.obs(t.slot, t.agent)[0], t.ret, t.done)).collect();
    assert_eq!(got, vec![(0, 5.0, 3.0, false), (1, 6.0, -100.0, true)]);
}
