use super::*;

#[test]
fn seeds_and_arms_parse_and_bad_ones_are_named() {
    assert_eq!(parse_seeds("1-4").unwrap(), vec![1, 2, 3, 4]);
    assert_eq!(parse_seeds("3,1,9").unwrap(), vec![3, 1, 9]);
    assert!(parse_seeds("4-1").is_err() && parse_seeds("x").is_err());
    let arm = parse_arm("fast:learner.n_step=3, learner.gamma=0.95").unwrap();
    assert_eq!(
        (arm.name.as_str(), arm.set),
        ("fast", vec!["learner.n_step=3".to_string(), "learner.gamma=0.95".to_string()])
    );
    assert!(parse_arm("old").unwrap().set.is_empty());
    assert!(parse_arm(":a=1").unwrap_err().to_string().contains("name"));
    assert!(parse_arm("x:nonsense").unwrap_err().to_string().contains("key=value"));
}

#[test]
fn iqm_median_and_the_probability_of_improvement() {
    // scipy.stats.trim_mean([1..8], 0.25) = mean(3, 4, 5, 6) = 4.5.
    assert_eq!(iqm(&[8.0, 1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0]), 4.5);
    // Fewer than four values: nothing is cut.
    assert_eq!(iqm(&[1.0, 2.0, 9.0]), 4.0);
    assert_eq!(median(&[3.0, 1.0, 2.0, 10.0]), 2.5);
    // b is faster in 3 of 4 pairs and ties in none.
    assert_eq!(prob_lower(&[10.0, 20.0], &[5.0, 15.0]), 0.75);
    assert_eq!(prob_lower(&[1.0], &[1.0]), 0.5);
    let mut rng = Pcg64Mcg::seed_from_u64(1);
    let a: Vec<f64> = (0..20).map(|i| 100.0 + i as f64).collect();
    let b: Vec<f64> = (0..20).map(|i| 50.0 + i as f64).collect();
    let [lo, hi] = bootstrap(&[&a, &b], 500, &mut rng, |d| prob_lower(&d[0], &d[1]));
    assert!(lo > 0.9 && hi <= 1.0, "[{lo}, {hi}]");
    let [lo, hi] = bootstrap(&[&a], 500, &mut rng, |d| iqm(&d[0]));
    assert!(lo < iqm(&a) && iqm(&a) < hi, "[{lo}, {hi}]");
}

#[test]
fn the_threshold_time_is_recomputed_with_the_runs_own_clock() {
    let dir = std::env::temp_dir().join(format!("rotorhive-seeds-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let mut cfg = Config { rolling_window: 2, ..Config::default() };
    cfg.actor.exploration = Exploration::PerActor;
    std::fs::write(dir.join("config.toml"), cfg.to_toml()).unwrap();
    let rows = "kind,wall_s,env_steps,episodes,episode_reward,rolling_reward,epsilon,updates,replay_size\n\
        episode,1.0,0,1,444,444,0.05,0,0\n\
        tick,1.5,0,1,,444,0.05,0,0\n\
        episode,2.0,0,2,-100,172,0.4,0,0\n\
        episode,3.0,0,3,400,422,0.01,0,0\n";
    std::fs::write(dir.join("metrics.csv"), rows).unwrap();
    // The exploring agent's collision does not count: the window of the
    // two greedy episodes is full at 3 s.
    let (t, curve) = threshold_time(&dir).unwrap();
    assert_eq!((t, curve), (Some(3.0), vec![(1.5, 444.0)]));
    cfg.actor.exploration = Exploration::Decay;
    std::fs::write(dir.join("config.toml"), cfg.to_toml()).unwrap();
    assert_eq!(threshold_time(&dir).unwrap().0, None, "with one schedule every episode counts");
    let _ = std::fs::remove_dir_all(&dir);
}
