use super::*;

#[test]
fn the_defaults_are_configs_default_toml() {
    // What `hive train` without a config resolves to, against the file
    // the README trains with and against the built-in defaults.
    let none = Config::load(None, &[]).unwrap().to_toml();
    let file = Config::load(
        Some(
            &std::path::PathBuf::from(env!("CARGO_MANIFEST_DIR"))
                .join("../../configs/default.toml"),
        ),
        &[],
    )
    .unwrap()
    .to_toml();
    assert_eq!(none, file);
    // The file leaves the sized keys at 0, as the defaults do; parsing
    // sizes them for this machine.
    let mut d = Config::default();
    d.sized = d.size(Sizing::machine_cores());
    assert_eq!(d.sized, SIZED_KEYS);
    assert_eq!(d.to_toml(), none, "Config::default() and configs/default.toml disagree");
}

#[test]
fn defaults_validate_and_round_trip() {
    let mut c = Config::default();
    c.validate().unwrap_err();
    c.size(Sizing::machine_cores());
    c.validate().unwrap();
    let back: Config = toml::from_str(&c.to_toml()).unwrap();
    assert_eq!(back.to_toml(), c.to_toml());
}

#[test]
fn overrides_apply_and_bad_values_are_named() {
    let c = Config::load(
        None,
        &["sim.agents=7".into(), "learner.lr=0.01".into(), "sim.observation_mode=batched".into()],
    )
    .unwrap();
    assert_eq!(c.sim.agents, 7);
    assert_eq!(c.learner.lr, 0.01);
    assert_eq!(c.sim.observation_mode, ObservationMode::Batched);
    let e =
        format!("{:#}", Config::load(None, &["sim.observation_mode=sideways".into()]).unwrap_err());
    assert!(e.contains("sim.observation_mode"), "{e}");
    let e = format!("{:#}", Config::load(None, &["sim.agents=0".into()]).unwrap_err());
    assert!(e.contains("sim.agents"), "{e}");
    let e = format!("{:#}", Config::load(None, &["sim.agnets=3".into()]).unwrap_err());
    assert!(e.contains("agnets"), "{e}");
    let e = format!("{:#}", Config::load(None, &["replay.batch=300000".into()]).unwrap_err());
    assert!(e.contains("replay.batch"), "{e}");
    // The task's keys and sections, named when wrong.
    let c = Config::load(
        None,
        &[
            "sim.forward_speed=2.0".into(),
            "sim.generator.spacing=3.0".into(),
            "sim.noise.dropout=0.02".into(),
        ],
    )
    .unwrap();
    assert_eq!(
        (
            c.sim_config().forward_speed,
            c.gen_params().unwrap().spacing,
            c.sim_config().noise.dropout
        ),
        (2.0, 3.0, 0.02)
    );
    for (set, key) in [
        ("sim.generator.per_row=9", "sim.generator.per_row"),
        ("sim.generator.spacnig=3", "spacnig"),
        ("sim.noise.dropout=0.9", "sim.noise.dropout"),
        ("sim.randomize.mass=-1", "sim.randomize.mass"),
        ("sim.lateral_step=0", "sim.lateral_step"),
        ("sim.frames=0", "sim.frames"),
        ("sim.frames=9", "sim.frames"),
        ("sim.frame_stride=0", "sim.frame_stride"),
        ("sim.frame_stride=9", "sim.frame_stride"),
        ("sim.reward_collision=nan", "sim.reward_collision"),
    ] {
        let e = format!("{:#}", Config::load(None, &[set.into()]).unwrap_err());
        assert!(e.contains(key), "{set}: {e}");
    }
    // Randomised dynamics live on the direct path only.
    let e = format!(
        "{:#}",
        Config::load(None, &["sim.physics=\"rapier\"".into(), "sim.randomize.wind=0.5".into()])
            .unwrap_err()
    );
    assert!(e.contains("direct"), "{e}");
    // A curriculum ramps a generator key between stages.
    let c = Config::load(
        None,
        &[
            "sim.generator.spacing=3.0".into(),
            "sim.curriculum.key=\"spacing\"".into(),
            "sim.curriculum.from=6.0".into(),
            "sim.curriculum.over_env_steps=100000".into(),
            "sim.curriculum.stages=3".into(),
        ],
    )
    .unwrap();
    let at = |s| c.generator_at_stage(s).unwrap().spacing;
    assert_eq!((at(0), at(1), at(3)), (6.0, 5.0, 3.0));
    assert_eq!(
        (c.curriculum_stage(0), c.curriculum_stage(40_000), c.curriculum_stage(10_000_000)),
        (0, 1, 3)
    );
    let e = format!(
        "{:#}",
        Config::load(
            None,
            &[
                "sim.generator.spacing=3.0".into(),
                "sim.curriculum.key=\"colour\"".into(),
                "sim.curriculum.from=1".into(),
                "sim.curriculum.over_env_steps=5".into()
            ]
        )
        .unwrap_err()
    );
    assert!(e.contains("colour"), "{e}");
    let e = format!("{:#}", Config::load(None, &["sim.agents=\"many\"".into()]).unwrap_err());
    assert!(e.contains("agents") || e.contains("invalid type"), "{e}");
}

#[test]
fn memory_is_named_and_sized_and_refused_where_it_does_not_work_yet() {
    let load =
        |sets: &[&str]| Config::load(None, &sets.iter().map(|s| s.to_string()).collect::<Vec<_>>());
    let plain = load(&[]).unwrap();
    assert_eq!((plain.memory(), plain.steps_per_row()), (None, 1));
    assert_eq!(plain.row_len(), plain.shapes().packed_len());
    assert_eq!(plain.replay_rows(), (plain.replay.capacity, plain.replay.min_fill));
    let gru = load(&["learner.memory=\"gru:64\""]).unwrap();
    assert_eq!((gru.memory(), gru.steps_per_row()), (Some(64), 14));
    let layout = gru.seq_layout().unwrap();
    assert_eq!((layout.steps, layout.width), (22, 64));
    assert_eq!(gru.row_len(), layout.packed_len());
    assert_eq!(gru.replay_rows(), (200_000 / 14, 15_000 / 14));
    assert_eq!(
        gru.num_params(),
        rotorhive_model::PolicyNet::new(
            gru.shapes(),
            gru.layers(),
            Some(64),
            0,
            &rotorhive_model::Device::Cpu
        )
        .unwrap()
        .num_params()
    );
    for (sets, needle) in [
        (&["learner.memory=\"lstm:64\""][..], "learner.memory"),
        (&["learner.memory=\"gru:0\""], "learner.memory"),
        (&["learner.memory=\"gru:64\"", "learner.burn_in=22"], "learner.burn_in"),
        (&["learner.memory=\"gru:64\"", "learner.sequence_steps=1"], "learner.sequence_steps"),
        // A key that changes nothing in this run is refused by name.
        (&["learner.sequence_steps=40"], "`learner.sequence_steps` = 40 changes nothing"),
        (&["learner.burn_in=4"], "`learner.burn_in` = 4 changes nothing without memory"),
    ] {
        let e = format!("{:#}", load(sets).unwrap_err());
        assert!(e.contains(needle), "{sets:?}: {e}");
    }
    // The teacher with memory: its demonstrations' reservoir counts
    // sequences as the memory does.
    let taught = load(&["learner.memory=\"gru:64\"", "teacher.policy=\"planner\""]).unwrap();
    assert!(taught.teacher.demos() && taught.memory() == Some(64));
    // The keys a run does not use are named (for its log).
    assert_eq!(
        plain.unused_keys(),
        ["learner.sequence_steps", "learner.burn_in", "teacher.* (but teacher.policy)"]
    );
    assert!(taught.unused_keys().is_empty());
}

#[test]
fn imitation_and_its_td_weight_are_named_and_checked() {
    let set = |s: &[&str]| Config::load(None, &s.iter().map(|x| x.to_string()).collect::<Vec<_>>());
    let e = format!("{:#}", set(&["learner.td_weight=0.5"]).unwrap_err());
    assert!(e.contains("learner.td_weight") && e.contains("imitation"), "{e}");
    let e = format!("{:#}", set(&["learner.td_weight=1.5"]).unwrap_err());
    assert!(e.contains("learner.td_weight"), "{e}");
    let e = format!("{:#}", set(&["teacher.policy=planner", "teacher.temperature=0"]).unwrap_err());
    assert!(e.contains("teacher.temperature"), "{e}");
    let e = format!("{:#}", set(&["teacher.loss=cloning"]).unwrap_err());
    assert!(e.contains("teacher.loss") || e.contains("cloning"), "{e}");
    let c = set(&[
        "teacher.policy=planner",
        "teacher.loss=imitation",
        "teacher.labels=graded",
        "learner.td_weight=0.25",
    ])
    .unwrap();
    let t = &c.teacher;
    assert_eq!(t.labels, crate::TeacherLabels::Graded);
    // The TD loss at its weight beside full imitation, handed back as the
    // teacher fades; the margin loss is the default's.
    let full = t.teaching(1.0, 0.25);
    assert_eq!((full.td, full.margin, full.imitation, full.temperature), (0.25, 0.0, 1.0, 0.2));
    let half = t.teaching(0.5, 0.25);
    assert_eq!((half.td, half.imitation), (0.625, 0.5));
    assert_eq!(t.teaching(0.0, 0.25).td, 1.0);
    let margin = Config::default().teacher;
    assert_eq!(margin.teaching(1.0, 1.0), rotorhive_model::Teaching::default(), "no teacher");
}

#[test]
fn the_networks_widths_are_keys_checked_by_name() {
    let set = |s: &[&str]| Config::load(None, &s.iter().map(|x| x.to_string()).collect::<Vec<_>>());
    assert_eq!(Config::default().layers(), rotorhive_model::Layers::DEFAULT);
    let c = set(&["learner.conv_channels=[24, 48]", "learner.hidden=[256, 128]"]).unwrap();
    assert_eq!(c.layers().name(), "conv:24,48 hidden:256,128");
    // The weights channel carries the wider network's floats, with or
    // without memory.
    let shapes = c.shapes();
    assert_eq!(c.num_params(), rotorhive_model::num_params(shapes, c.layers()));
    assert!(c.num_params() > Config::default().num_params() * 4);
    let gru = set(&["learner.hidden=[32]", "learner.memory=gru:16"]).unwrap();
    let net = rotorhive_model::PolicyNet::new(
        gru.shapes(),
        gru.layers(),
        gru.memory(),
        0,
        &rotorhive_model::Device::Cpu,
    )
    .unwrap();
    assert_eq!(gru.layers().out(), 32);
    assert_eq!(
        format!("{net:?}"),
        format!(
            "PolicyNet {{ shapes: {:?}, layers: conv:16,32 hidden:32, memory: Some(16) }}",
            gru.shapes()
        )
    );
    for (bad, says) in [
        ("learner.hidden=[]", "hidden has 0 entries"),
        ("learner.hidden=[64, 64, 64, 64]", "hidden has 4 entries"),
        ("learner.conv_channels=[16]", "two convolutions"),
        ("learner.conv_channels=[16, 0]", "a width of 0"),
        ("learner.hidden=[5000]", "a width of 5000"),
    ] {
        let e = format!("{:#}", set(&[bad]).unwrap_err());
        assert!(e.contains("learner.conv_channels") && e.contains(says), "{bad}: {e}");
    }
}

#[test]
fn fresh_layouts_are_checked_and_never_a_held_out_or_trained_layout() {
    let over = |s: &[&str]| s.iter().map(|x| x.to_string()).collect::<Vec<_>>();
    let c = Config::level("dense", &over(&["sim.fresh_layouts=200"])).unwrap();
    let off = Config::level("dense", &over(&["sim.fresh_layouts=0"])).unwrap();
    assert!(off.fresh_layouts(0).unwrap().is_none());
    assert_eq!(Config::level("dense", &[]).unwrap().sim.fresh_layouts, 50, "L1 trains so");
    let (first, mut make) = c.fresh_layouts(0).unwrap().expect("fresh layouts are on");
    assert_eq!(first, 0, "the level trains on generated lanes alone");
    let held: Vec<_> = c
        .test_arenas()
        .unwrap()
        .into_iter()
        .chain(c.eval_arenas().unwrap())
        .chain(c.lane_arenas(0).unwrap())
        .chain(c.lane_arenas(1).unwrap())
        .map(|a| a.obstacles)
        .collect();
    let fresh: Vec<_> = (0..20).map(|n| make(n).obstacles).collect();
    for (n, f) in fresh.iter().enumerate() {
        assert!(!held.contains(f), "fresh layout {n} is a test, validation or lane layout");
        assert!(!fresh[..n].contains(f), "fresh layout {n} repeats one");
    }
    // Another environment's are others.
    let (_, mut other) = c.fresh_layouts(1).unwrap().unwrap();
    assert_ne!(other(0).obstacles, fresh[0]);
    for (bad, says) in [
        (&["sim.fresh_layouts=10", "sim.physics=rapier"][..], "sim.physics"),
        (
            &[
                "sim.fresh_layouts=10",
                "sim.generated_lanes=0",
                "sim.arena=configs/arenas/train.toml",
            ],
            "generated_lanes",
        ),
    ] {
        let e = format!("{:#}", Config::level("dense", &over(bad)).unwrap_err());
        assert!(e.contains("sim.fresh_layouts") && e.contains(says), "{bad:?}: {e}");
    }
}

#[test]
fn the_teachers_sight_is_the_planners_by_name_and_remembers_its_key() {
    use rotorhive_sim::Sight;
    let set = |s: &[&str]| Config::load(None, &s.iter().map(|x| x.to_string()).collect::<Vec<_>>());
    for sight in Sight::EVERY {
        let c = set(&["teacher.policy=planner", &format!("teacher.sight=\"{sight}\"")]);
        let c = match sight {
            // The map's planner needs the map (refused without it, by name).
            Sight::Map => {
                let e = format!("{:#}", c.unwrap_err());
                assert!(e.contains("teacher.sight") && e.contains("sim.map"), "{e}");
                continue;
            }
            _ => c.unwrap(),
        };
        assert_eq!(c.teacher.sight, sight);
        // What a run writes as its config.toml reads back the same.
        let again: Config = toml::from_str(&toml::to_string(&c).unwrap()).unwrap();
        assert_eq!(again.teacher.sight, sight);
    }
    let c =
        set(&["teacher.policy=planner", "teacher.sight=\"pixels-memory\"", "teacher.memory_s=5"]);
    assert_eq!(c.unwrap().teacher.planner_sight(), Sight::PixelsMemory(Some(5)));
    let e = format!("{:#}", set(&["teacher.sight=\"psychic\""]).unwrap_err());
    assert!(e.contains("teacher.sight") && e.contains("pixels-memory"), "{e}");
}

#[test]
fn the_rays_through_the_movers_ahead_need_the_maps_rays_and_the_tracks() {
    let load =
        |sets: &[&str]| Config::load(None, &sets.iter().map(|s| s.to_string()).collect::<Vec<_>>());
    let ahead = "sim.map.movers_ahead_s=[0.0, 1.0]";
    let rays = "sim.map.encoding=\"rays\"";
    let c = load(&[rays, "sim.tracks.count=5", ahead]).unwrap();
    assert_eq!(c.shapes().map, (2 + 2) * 36, "the map's two sets, then one a time ahead");
    for (sets, needle) in [
        (&[rays, ahead][..], "`sim.map.movers_ahead_s` casts rays through the seen movers"),
        (&["sim.map.encoding=\"grid\"", "sim.tracks.count=5", ahead], "sim.map.movers_ahead_s"),
        (&[rays, "sim.tracks.count=5", "sim.map.movers_ahead_s=[-1.0]"], "sim.map.movers_ahead_s"),
    ] {
        let e = format!("{:#}", load(sets).unwrap_err());
        assert!(e.contains(needle), "{sets:?}: {e}");
    }
    // Without a map they are read by nothing: no floats, no refusal (an
    // evaluation turns L4's map and tracks off so).
    let off = load(&["sim.map.encoding=\"none\"", ahead]).unwrap();
    assert_eq!(off.shapes().map, 0);
}
