//! `hive eval`: flies a checkpoint's greedy policy, or the scripted
//! reactive rule, on held-out layouts (a level's test set or the arenas
//! given) with the sim settings of the level or of the run that wrote the
//! checkpoint, and reports the success rate per layout and pooled, with
//! 95 % Wilson intervals.

use std::path::{Path, PathBuf};

use anyhow::{Result, bail};
use clap::{Args, ValueEnum};
use rotorhive_model::{Layers, PolicyNet, Shapes};
use rotorhive_roles::Config;
use rotorhive_roles::evaluation::{
    Agreement, EpisodeLog, EvalStats, LogSpec, NEAR_M, Near, Pilot, agreement, fly_layouts_logged,
    layout_spread,
};
use rotorhive_sim::{Arena, Sight, SimConfig};

/// Who flies in `hive eval`.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum PolicyKind {
    /// The checkpoint's greedy action.
    Greedy,
    /// The scripted reactive rule on the same depth images and velocity
    /// (no checkpoint): the floor a learned policy must beat.
    Reactive,
    /// A search that knows where every obstacle is and will be (no
    /// checkpoint; privileged, no drone could fly it): a floor under the
    /// share of episodes that can be flown at all.
    Planner,
}

/// `--sight`'s and `--agree`'s values: every [`Sight`] by its name, each
/// with what it knows in `--help`.
fn sight_parser() -> impl clap::builder::TypedValueParser<Value = Sight> {
    use clap::builder::{PossibleValue, PossibleValuesParser, TypedValueParser};
    let values = Sight::EVERY.map(|s| PossibleValue::new(s.name()).help(s.what()));
    PossibleValuesParser::new(values).try_map(|s| s.parse::<Sight>())
}

impl PolicyKind {
    /// Its name on the command line and in JSON.
    fn name(self) -> &'static str {
        match self {
            PolicyKind::Greedy => "greedy",
            PolicyKind::Reactive => "reactive",
            PolicyKind::Planner => "planner",
        }
    }
}

#[derive(Args, Debug)]
pub struct EvalArgs {
    /// Weights (safetensors) written by `hive train`.
    #[arg(long, required_unless_present = "policy")]
    pub checkpoint: Option<PathBuf>,
    /// Who flies: the checkpoint's greedy policy or the reactive rule.
    #[arg(long, value_enum)]
    pub policy: Option<PolicyKind>,
    /// What the planner knows (with `--policy planner`).
    #[arg(long, value_parser = sight_parser(), default_value = "all")]
    pub sight: Sight,
    /// How long (s) a `--sight view-memory` planner remembers: a mover
    /// whose half cycle is longer is never known (default: the episode).
    #[arg(long, value_name = "S")]
    pub memory_s: Option<u16>,
    /// Rays a side that a `--sight pixels` or `pixels-memory` planner
    /// casts to learn what the camera shows (default: the camera's 32): what
    /// a camera of more pixels would tell it.
    #[arg(long, value_name = "N", value_parser = clap::value_parser!(u16).range(4..=512))]
    pub rays: Option<u16>,
    /// A level (`configs/levels/NAME.toml`): its sim settings and its
    /// held-out test layouts (a checkpoint's stacked frames and their
    /// stride taken from its header). Without it: the settings of the run
    /// that wrote the checkpoint (its `config.toml`), else the defaults.
    #[arg(long)]
    pub level: Option<String>,
    /// Arenas to fly in, instead of the test layouts (repeatable).
    #[arg(long)]
    pub arena: Vec<PathBuf>,
    /// Fly the layouts this run trained on (`RUN_DIR/config.toml`'s lanes
    /// of every environment) instead of the test layouts, with the run's
    /// settings (unless `--level` is given): the generalisation gap beside
    /// the held-out result.
    #[arg(long, value_name = "RUN_DIR", conflicts_with = "arena")]
    pub training_layouts: Option<PathBuf>,
    /// Fly the config's validation layouts (`eval.validation_arenas`
    /// generated, neither trained on nor held out for the test) instead of
    /// the test layouts: where a setting is chosen before the test set
    /// judges it.
    #[arg(long, conflicts_with_all = ["arena", "training_layouts"])]
    pub validation_layouts: bool,
    /// Write the failure map into DIR: every episode that did not reach
    /// its end (`failures.csv`: layout, end point, last actions, trap; its
    /// last observations in `last-observations.npy`), one picture per
    /// layout from above (the paths and crash points, and the planner's
    /// paths from the same spawns), and count the traps.
    #[arg(long, value_name = "DIR")]
    pub failures: Option<PathBuf>,
    /// The agreement audit: a planner of this sight judges every action
    /// the policy takes (the actions that keep a way clear, ties kept);
    /// reports how often the policy's is one of them, over all steps, the
    /// decisive ones and the last five before each crash.
    #[arg(long, value_parser = sight_parser(), value_name = "SIGHT")]
    pub agree: Option<Sight>,
    /// Episodes in all, shared evenly among the layouts.
    #[arg(long, default_value_t = 500)]
    pub episodes: usize,
    /// Seed of the spawn positions.
    #[arg(long, default_value_t = 12345)]
    pub seed: u64,
    /// Overrides of the config's keys (`sim.noise.dropout=0.05`), repeatable.
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
    /// Print one JSON object as the last line.
    #[arg(long)]
    pub json: bool,
}

/// The config of the run that wrote `checkpoint`: `config.toml` in its
/// directory or the one above (`RUN_DIR/checkpoints/best.safetensors`).
fn run_config(checkpoint: &Path) -> Option<PathBuf> {
    checkpoint.ancestors().skip(1).take(2).map(|d| d.join("config.toml")).find(|p| p.is_file())
}

/// The camera's map and the seen movers a checkpoint reads (`[sim.map]`
/// and `[sim.tracks]` of the run that wrote it): none of either the
/// network does not read; refused by name when its run's `config.toml` is
/// not beside it or names another size. The header and the config are
/// each read once.
pub(crate) fn memory_of(
    checkpoint: &Path,
) -> Result<(Option<rotorhive_sim::MapSpec>, Option<rotorhive_sim::TrackSpec>)> {
    let shapes = rotorhive_model::checkpoint_shapes(checkpoint)?;
    let parts = [("the camera's map", shapes.map), ("the seen movers", shapes.tracks)];
    let Some(&(what, floats)) = parts.iter().find(|(_, floats)| *floats > 0) else {
        return Ok((None, None));
    };
    let Some(path) = run_config(checkpoint) else {
        bail!(
            "{}: the network reads {floats} floats of {what}, whose settings are in its \
             run's config.toml, not found beside it",
            checkpoint.display(),
        );
    };
    let sim = Config::load(Some(&path), &[])?.sim;
    for ((what, floats), named) in parts.into_iter().zip([sim.map.floats(), sim.tracks.floats()]) {
        if floats > 0 && named != floats {
            bail!(
                "{}: the network reads {floats} floats of {what}, {} names {named}",
                checkpoint.display(),
                path.display(),
            );
        }
    }
    Ok(((shapes.map > 0).then_some(sim.map), (shapes.tracks > 0).then_some(sim.tracks)))
}

/// `--set` keys that give a config the seen movers `t`.
pub(crate) fn tracks_sets(t: &rotorhive_sim::TrackSpec) -> Vec<String> {
    vec![
        format!("sim.tracks.count={}", t.count),
        format!("sim.tracks.keep_s={:?}", t.keep_s),
        format!("sim.tracks.band={}", t.band),
        format!("sim.tracks.unseen_reach_m={:?}", t.unseen_reach_m),
    ]
}

/// `--set` keys that give a config the camera's map `m`.
pub(crate) fn map_sets(m: &rotorhive_sim::MapSpec) -> Vec<String> {
    vec![
        format!("sim.map.encoding=\"{}\"", m.encoding.name()),
        format!("sim.map.cell_m={:?}", m.cell_m),
        format!("sim.map.window={}", m.window),
        format!("sim.map.rays={}", m.rays),
        format!("sim.map.ray_range_m={:?}", m.ray_range_m),
        format!("sim.map.keep_s={:?}", m.keep_s),
        format!("sim.map.band={}", m.band),
        format!("sim.map.movers_ahead_s={:?}", m.movers_ahead_s),
    ]
}

/// The config an evaluation flies with, and where it came from: a
/// checkpoint flies with the camera its header names (a `--set` or a
/// config of another camera is refused by name).
fn config(a: &EvalArgs) -> Result<(Config, String)> {
    use rotorhive_roles::config::camera::{camera_name, checkpoint_camera};
    let camera = a.checkpoint.as_deref().map(checkpoint_camera).transpose()?;
    let (cfg, source) = chosen_config(a, camera)?;
    if let (Some(c), Some(theirs)) = (&a.checkpoint, camera)
        && cfg.camera() != theirs
    {
        bail!(
            "{} was trained with the camera {}; {source} (with the --set keys) gives {}",
            c.display(),
            camera_name(&theirs),
            camera_name(&cfg.camera())
        );
    }
    Ok((cfg, source))
}

/// The `--set` keys a checkpoint brings to a config of no run of its own:
/// its frames, their stride, its camera (`camera`, read from its header)
/// and the camera's map and seen movers its run built.
fn checkpoint_sets(c: &Path, camera: rotorhive_sim::CameraSpec) -> Result<Vec<String>> {
    let shapes = rotorhive_model::checkpoint_shapes(c)?;
    let mut set = vec![
        format!("sim.frames={}", shapes.frames),
        format!("sim.frame_stride={}", shapes.stride),
    ];
    if camera != rotorhive_sim::CameraSpec::default() {
        set.extend(rotorhive_roles::config::camera::camera_sets(&camera));
    }
    // A network that reads no map (or no tracks) flies a level that has
    // them without (an evaluation flies no teacher: see [`flying`]).
    let (map, tracks) = memory_of(c)?;
    match &map {
        Some(m) => set.extend(map_sets(m)),
        None => set.push("sim.map.encoding=\"none\"".into()),
    }
    match &tracks {
        Some(t) => set.extend(tracks_sets(t)),
        None => set.push("sim.tracks.count=0".into()),
    }
    Ok(set)
}

/// The `--set` keys an evaluation loads a config with: `set` after the
/// teacher turned off. An evaluation flies no teacher, so a level whose
/// teacher reads the camera's map (L4's) is not refused with the map
/// turned off (`--set sim.map.encoding='"none"'`).
fn flying(set: &[String]) -> Vec<String> {
    std::iter::once(rotorhive_roles::config::NO_TEACHER.to_string())
        .chain(set.iter().cloned())
        .collect()
}

/// [`config`] before the camera's check (`camera`: the checkpoint's).
fn chosen_config(
    a: &EvalArgs,
    camera: Option<rotorhive_sim::CameraSpec>,
) -> Result<(Config, String)> {
    if let (Some(run), None) = (&a.training_layouts, &a.level) {
        let path = run.join("config.toml");
        if !path.is_file() {
            bail!(
                "--training-layouts {}: no config.toml there (a run directory of `hive train`)",
                run.display()
            );
        }
        return Ok((Config::load(Some(&path), &flying(&a.set))?, path.display().to_string()));
    }
    if let Some(path) = a.checkpoint.as_deref().and_then(run_config)
        && a.level.is_none()
    {
        return Ok((Config::load(Some(&path), &flying(&a.set))?, path.display().to_string()));
    }
    // A checkpoint sees as it was trained to: its frames, their stride and
    // its camera come from its header (a `--set` of them still wins, and
    // one that contradicts the camera is refused).
    let mut set = flying(&[]);
    if let (Some(c), Some(camera)) = (&a.checkpoint, camera) {
        set.extend(checkpoint_sets(c, camera)?);
    }
    set.extend(a.set.iter().cloned());
    match &a.level {
        Some(level) => Ok((Config::level(level, &set)?, format!("level {level}"))),
        None => Ok((Config::load(None, &set)?, "the defaults".into())),
    }
}

pub fn run(a: EvalArgs) -> Result<()> {
    if a.episodes == 0 {
        bail!("--episodes must be positive");
    }
    let policy = a.policy.unwrap_or(PolicyKind::Greedy);
    let remembers = a.sight.remembers();
    if a.memory_s.is_some() && (policy != PolicyKind::Planner || !remembers) {
        bail!("--memory-s is for --policy planner --sight view-memory or pixels-memory");
    }
    let pixels = a.sight.pixels();
    if a.rays.is_some() && (policy != PolicyKind::Planner || !pixels) {
        bail!("--rays is for --policy planner --sight pixels or pixels-memory");
    }
    match (policy, &a.checkpoint) {
        (PolicyKind::Greedy, None) => bail!("--policy greedy needs --checkpoint"),
        (PolicyKind::Reactive | PolicyKind::Planner, Some(_)) => {
            bail!("--policy {} flies no checkpoint: leave out --checkpoint", policy.name())
        }
        _ => {}
    }
    let (cfg, source) = config(&a)?;
    let judged_by_map =
        a.agree == Some(Sight::Map) || (policy == PolicyKind::Planner && a.sight == Sight::Map);
    if judged_by_map && !cfg.sim.map.enabled() {
        bail!(
            "the sight `map` needs the camera's map: {source} has no [sim.map] (add \
             --set sim.map.encoding=\"rays\", or fly a checkpoint that reads one)"
        );
    }
    // The task's network: a checkpoint of other shapes is refused by name;
    // one whose header names a memory flies as a recurrent network.
    let net = match (policy, &a.checkpoint) {
        (PolicyKind::Greedy, Some(c)) => {
            let memory = rotorhive_model::checkpoint_memory(c)?;
            let layers = rotorhive_model::checkpoint_layers(c)?;
            let dev = rotorhive_model::Device::Cpu;
            let net = PolicyNet::new(cfg.shapes(), layers, memory, 0, &dev)?;
            net.load_checkpoint(c)?;
            Some(net)
        }
        _ => None,
    };
    let layouts: Vec<Arena> = match (&a.training_layouts, a.arena.is_empty()) {
        (Some(run), _) => training_layouts(run, &cfg)?,
        (None, true) if a.validation_layouts => cfg.eval_arenas()?,
        (None, true) => cfg.test_arenas()?,
        (None, false) => a.arena.iter().map(|p| Arena::load(p)).collect::<Result<_, _>>()?,
    };
    let pilot = match (&net, policy) {
        (Some(net), _) => Pilot::Net(net),
        (None, PolicyKind::Planner) => Pilot::Planner(a.sight.with_memory(a.memory_s)),
        (None, _) => Pilot::Reactive,
    };
    let spec = (a.failures.is_some() || a.agree.is_some())
        .then_some(LogSpec { audit: a.agree, horizon: AUDIT_HORIZON });
    let sim = SimConfig { sight_rays: a.rays.map_or(0, usize::from), ..cfg.sim_config() };
    let flown = fly_layouts_logged(pilot, &sim, &layouts, a.episodes, a.seed, spec)?;
    let (stats, logs): (Vec<EvalStats>, Vec<Vec<EpisodeLog>>) = flown.into_iter().unzip();
    let found = Found {
        failures: match &a.failures {
            Some(dir) => {
                Some(crate::failures::write(dir, &cfg, (&layouts, &stats, &logs), a.seed)?)
            }
            None => None,
        },
        agreement: a.agree.map(|_| agreement(&logs.concat())),
    };
    let net = net.as_ref().map(|n| (n.memory(), n.layers()));
    let settings = (source.as_str(), &cfg.camera());
    report(&a, (policy, net), settings, cfg.shapes(), (&layouts, &stats), &found);
    Ok(())
}

/// Actions the agreement audit's searches look ahead (the teacher's
/// `label_horizon` default).
const AUDIT_HORIZON: usize = 10;

/// What `--failures` and `--agree` found, for the report.
struct Found {
    failures: Option<crate::failures::Traps>,
    agreement: Option<Agreement>,
}

/// The layouts the run in `run` trained on: every environment's lanes, as
/// its config builds them (at the curriculum stage it ended at).
fn training_layouts(run: &Path, cfg: &Config) -> Result<Vec<Arena>> {
    let summary = rotorhive_records::Summary::read(run).ok();
    let envs = summary.as_ref().map_or(cfg.sim.envs, |s| s.envs).max(1);
    let stage = cfg.curriculum_stage(summary.as_ref().map_or(0, |s| s.env_steps));
    let mut all = Vec::new();
    for env in 0..envs {
        for mut lane in cfg.lane_arenas_at(env, stage)? {
            lane.name = format!("env-{env}-{}", lane.name);
            all.push(lane);
        }
    }
    Ok(all)
}

/// Prints what an evaluation found: per layout and pooled, and with
/// `--json` one object as the last line.
fn report(
    a: &EvalArgs,
    (policy, net): (PolicyKind, Option<(Option<usize>, Layers)>),
    (source, camera): (&str, &rotorhive_sim::CameraSpec),
    shapes: Shapes,
    (layouts, stats): (&[Arena], &[EvalStats]),
    found: &Found,
) {
    let memory = net.and_then(|n| n.0);
    let pooled = EvalStats::pooled(stats);
    let pct = |s: &EvalStats| {
        let [lo, hi] = s.wilson();
        format!("{:.1} % [{:.1}, {:.1}]", s.success_rate() * 100.0, lo * 100.0, hi * 100.0)
    };
    let planner = policy == PolicyKind::Planner;
    let who = match policy {
        PolicyKind::Greedy => a.checkpoint.as_ref().map_or(String::new(), |c| match memory {
            Some(w) => format!("{} (memory: a GRU of {w})", c.display()),
            None => c.display().to_string(),
        }),
        PolicyKind::Reactive => "the reactive rule".into(),
        PolicyKind::Planner => {
            let memory = a.memory_s.map_or(String::new(), |s| format!(", remembering {s} s"));
            let rays = a.rays.map_or(String::new(), |n| format!(", {n} x {n} rays"));
            format!("the planner (privileged), knowing {}{memory}{rays}", a.sight.what())
        }
    };
    println!(
        "{who}, settings of {source} ({} depth frames of {} x {}, {} action period(s) apart):",
        shapes.frames, shapes.depth[0], shapes.depth[1], shapes.stride
    );
    for (l, s) in layouts.iter().zip(stats) {
        println!(
            "  {}: {} episodes, success {}, collisions {}, mean reward {:.1}",
            l.name,
            s.episodes,
            pct(s),
            s.collisions,
            s.mean_reward
        );
    }
    println!(
        "pooled: {} episodes on {} layouts, success {}, collisions {}, mean reward {:.1}",
        pooled.episodes,
        layouts.len(),
        pct(&pooled),
        pooled.collisions,
        pooled.mean_reward
    );
    if planner {
        println!(
            "  no way through from the spawn (in the planner's model): {} of {} episodes",
            pooled.hopeless, pooled.episodes
        );
    }
    report_found(a, (layouts, stats), found);
    if a.json {
        print_json(a, policy, (source, camera), shapes, (layouts, stats), (&pooled, net), found);
    }
}

/// Prints the spread over layouts, the failure map's traps and the
/// agreement audit.
fn report_found(a: &EvalArgs, (layouts, stats): (&[Arena], &[EvalStats]), found: &Found) {
    let ([q1, q2, q3], under) = layout_spread(stats);
    println!(
        "  per layout: quartiles {:.1} / {:.1} / {:.1} %, {under} of {} layouts under 50 %",
        q1 * 100.0,
        q2 * 100.0,
        q3 * 100.0,
        layouts.len()
    );
    if let Some(t) = &found.failures {
        println!(
            "  failures: {} episodes, {} traps holding {:.1} % of them (map in {})",
            t.failures,
            t.traps,
            t.share() * 100.0,
            t.dir.display()
        );
    }
    if let (Some(g), Some(s)) = (&found.agreement, a.agree) {
        let pct = |p| Agreement::share(p).map_or("-".into(), |x| format!("{:.1} %", x * 100.0));
        println!(
            "  agreement with the planner ({}): all steps {} of {}, decisive {} of {}, last {} before a crash {} of {}; no way at {} steps",
            s.name(),
            pct(g.all),
            g.all.1,
            pct(g.decisive),
            g.decisive.1,
            rotorhive_roles::evaluation::LAST_STEPS,
            pct(g.before_crash),
            g.before_crash.1,
            g.no_way
        );
        // Where movers came near: the decisive steps by what the drone's
        // tracker held of the nearest one.
        if g.decisive_near[1..].iter().any(|p| p.1 > 0) {
            let parts: Vec<String> = Near::ALL
                .iter()
                .zip(g.decisive_near)
                .map(|(n, p)| format!("{} {} of {}", n.name(), pct(p), p.1))
                .collect();
            println!(
                "  decisive steps by the nearest mover within {NEAR_M} m (as its track stood): {}",
                parts.join(", ")
            );
        }
    }
}

/// The agreement as JSON: each share and its step count.
fn agreement_json(g: &Agreement, sight: Sight) -> serde_json::Value {
    let pair = |p: (usize, usize)| (Agreement::share(p), p.1);
    let ((all, n_all), (dec, n_dec), (crash, n_crash)) =
        (pair(g.all), pair(g.decisive), pair(g.before_crash));
    serde_json::json!({
        "sight": sight.name(),
        "all": all, "all_steps": n_all,
        "decisive": dec, "decisive_steps": n_dec,
        "before_crash": crash, "before_crash_steps": n_crash,
        "no_way_steps": g.no_way,
        "decisive_by_nearest_mover": Near::ALL.iter().zip(g.decisive_near).map(|(n, p)| {
            let (share, steps) = pair(p);
            (n.name().to_string(), serde_json::json!({ "share": share, "steps": steps }))
        }).collect::<serde_json::Map<_, _>>(),
        "nearest_mover_m": NEAR_M,
        "horizon": AUDIT_HORIZON,
    })
}

/// `hive eval --json`'s last line: the pooled result, per layout, and what
/// flew.
fn print_json(
    a: &EvalArgs,
    policy: PolicyKind,
    (source, camera): (&str, &rotorhive_sim::CameraSpec),
    shapes: Shapes,
    (layouts, stats): (&[Arena], &[EvalStats]),
    (pooled, net): (&EvalStats, Option<(Option<usize>, Layers)>),
    found: &Found,
) {
    let memory = net.and_then(|n| n.0);
    let (quartiles, under) = layout_spread(stats);
    let planner = policy == PolicyKind::Planner;
    let layouts_json: Vec<serde_json::Value> = layouts
        .iter()
        .zip(stats)
        .map(|(l, s)| serde_json::json!({ "name": l.name, "success_rate": s.success_rate(), "ci": s.wilson(), "episodes": s.episodes, "mean_reward": s.mean_reward }))
        .collect();
    println!(
        "{}",
        serde_json::json!({
            "success_rate": pooled.success_rate(),
            "ci": pooled.wilson(),
            "mean_reward": pooled.mean_reward,
            "episodes": pooled.episodes,
            "collisions": pooled.collisions,
            "hopeless": planner.then_some(pooled.hopeless),
            "sight": planner.then(|| a.sight.name()),
            "memory_s": a.memory_s,
            "rays": a.rays,
            "memory": (policy == PolicyKind::Greedy).then(|| rotorhive_model::memory_name(memory)),
            "layers": net.map(|n| n.1.name()),
            "layouts": layouts_json,
            "policy": policy.name(),
            "level": a.level,
            "settings": source,
            "frames": shapes.frames,
            "frame_stride": shapes.stride,
            "camera": rotorhive_roles::config::camera::camera_name(camera),
            "layout_quartiles": quartiles,
            "layouts_under_half": under,
            "traps": found.failures.as_ref().map(|t| t.traps),
            "trap_share": found.failures.as_ref().map(crate::failures::Traps::share),
            "failures": found.failures.as_ref().map(|t| t.failures),
            "agreement": found.agreement.as_ref().zip(a.agree).map(|(g, s)| agreement_json(g, s)),
            "training_layouts": a.training_layouts.as_ref().map(|p| p.display().to_string()),
            "validation_layouts": a.validation_layouts,
        })
    );
}
