//! `hive eval`: flies a checkpoint's greedy policy, or the scripted
//! reactive rule, on held-out layouts (a level's test set or the arenas
//! given) with the sim settings of the level or of the run that wrote the
//! checkpoint, and reports the success rate per layout and pooled, with
//! 95 % Wilson intervals.

use std::path::{Path, PathBuf};

use anyhow::{Result, bail};
use clap::{Args, ValueEnum};
use rotorhive_model::Shapes;
use rotorhive_roles::Config;
use rotorhive_roles::eval::{EvalStats, Network, Pilot, fly_layouts};
use rotorhive_sim::{Arena, Sight};

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

/// What `--policy planner` knows (`rotorhive_sim::Sight`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum SightArg {
    /// Every obstacle, and where each moving one will be.
    All,
    /// What the camera shows now (depth range and field of view, and what
    /// is beside the drone), with the moving ones' future.
    View,
    /// What the camera shows now, each moving one guessed to keep its
    /// present velocity for 3 s and turn back.
    ViewVelocity,
    /// What the camera shows now, each moving one standing over its whole
    /// track (where it goes, not when).
    ViewTrack,
    /// What the camera shows now, each moving one known once it has been
    /// in view for half its cycle, over its whole track until then.
    ViewMemory,
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

impl SightArg {
    /// What the planner is told (`memory_s`: how long a
    /// [`SightArg::ViewMemory`] planner remembers).
    fn sight(self, memory_s: Option<u16>) -> Sight {
        match self {
            SightArg::All => Sight::All,
            SightArg::View => Sight::View,
            SightArg::ViewVelocity => Sight::ViewVelocity,
            SightArg::ViewTrack => Sight::ViewTrack,
            SightArg::ViewMemory => Sight::ViewMemory(memory_s),
        }
    }

    /// Its name on the command line and in JSON, and what it means.
    fn name(self) -> (&'static str, &'static str) {
        match self {
            SightArg::All => ("all", "every obstacle's motion"),
            SightArg::View => ("view", "what the camera shows, with the movers' future"),
            SightArg::ViewVelocity => {
                ("view-velocity", "what the camera shows, the movers' velocity kept 3 s")
            }
            SightArg::ViewTrack => {
                ("view-track", "what the camera shows, each mover over its whole track")
            }
            SightArg::ViewMemory => (
                "view-memory",
                "what the camera shows, each mover known once watched for half its cycle",
            ),
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
    #[arg(long, value_enum, default_value_t = SightArg::All)]
    pub sight: SightArg,
    /// How long (s) a `--sight view-memory` planner remembers: a mover
    /// whose half cycle is longer is never known (default: the episode).
    #[arg(long, value_name = "S")]
    pub memory_s: Option<u16>,
    /// A level (`configs/levels/NAME.toml`): its sim settings and its
    /// held-out test layouts (a checkpoint's stacked frames and their
    /// stride taken from its header). Without it: the settings of the run
    /// that wrote the checkpoint (its `config.toml`), else the defaults.
    #[arg(long)]
    pub level: Option<String>,
    /// Arenas to fly in, instead of the test layouts (repeatable).
    #[arg(long)]
    pub arena: Vec<PathBuf>,
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

/// The config an evaluation flies with, and where it came from.
fn config(a: &EvalArgs) -> Result<(Config, String)> {
    if let Some(level) = &a.level {
        // A checkpoint sees as it was trained to: its frames and their
        // stride come from its header (a `--set` of them still wins).
        let mut set = Vec::new();
        if let Some(c) = &a.checkpoint {
            let shapes = rotorhive_model::checkpoint_shapes(c)?;
            set.push(format!("sim.frames={}", shapes.frames));
            set.push(format!("sim.frame_stride={}", shapes.stride));
        }
        set.extend(a.set.iter().cloned());
        return Ok((Config::level(level, &set)?, format!("level {level}")));
    }
    if let Some(path) = a.checkpoint.as_deref().and_then(run_config) {
        return Ok((Config::load(Some(&path), &a.set)?, path.display().to_string()));
    }
    Ok((Config::load(None, &a.set)?, "the defaults".into()))
}

pub fn run(a: EvalArgs) -> Result<()> {
    if a.episodes == 0 {
        bail!("--episodes must be positive");
    }
    let policy = a.policy.unwrap_or(PolicyKind::Greedy);
    if a.memory_s.is_some() && (policy != PolicyKind::Planner || a.sight != SightArg::ViewMemory) {
        bail!("--memory-s is for --policy planner --sight view-memory");
    }
    let (cfg, source) = config(&a)?;
    // The task's network: a checkpoint of other shapes is refused by name;
    // one whose header names a memory flies as a recurrent network.
    let net = match (policy, &a.checkpoint) {
        (PolicyKind::Greedy, Some(c)) => {
            let net = Network::new(cfg.shapes(), rotorhive_model::checkpoint_memory(c)?)?;
            net.load_checkpoint(c)?;
            Some(net)
        }
        (PolicyKind::Greedy, None) => bail!("--policy greedy needs --checkpoint"),
        (_, Some(_)) => {
            bail!("--policy {} flies no checkpoint: leave out --checkpoint", policy.name())
        }
        (PolicyKind::Reactive | PolicyKind::Planner, None) => None,
    };
    let layouts: Vec<Arena> = if a.arena.is_empty() {
        cfg.test_arenas()?
    } else {
        a.arena.iter().map(|p| Arena::load(p)).collect::<Result<_, _>>()?
    };
    let per_layout = a.episodes.div_ceil(layouts.len());
    let pilot = match (&net, policy) {
        (Some(net), _) => net.pilot(),
        (None, PolicyKind::Planner) => Pilot::Planner(a.sight.sight(a.memory_s)),
        (None, _) => Pilot::Reactive,
    };
    let stats = fly_layouts(pilot, &cfg.sim_config(), &layouts, per_layout, a.seed)?;
    let memory = net.as_ref().and_then(Network::memory);
    report(&a, (policy, memory), &source, cfg.shapes(), &layouts, &stats);
    Ok(())
}

/// Prints what an evaluation found: per layout and pooled, and with
/// `--json` one object as the last line.
fn report(
    a: &EvalArgs,
    (policy, memory): (PolicyKind, Option<usize>),
    source: &str,
    shapes: Shapes,
    layouts: &[Arena],
    stats: &[EvalStats],
) {
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
            format!("the planner (privileged), knowing {}{memory}", a.sight.name().1)
        }
    };
    println!(
        "{who}, settings of {source} ({} depth frames, {} action period(s) apart):",
        shapes.frames, shapes.stride
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
    if a.json {
        print_json(a, policy, source, shapes, (layouts, stats), (&pooled, memory));
    }
}

/// `hive eval --json`'s last line: the pooled result, per layout, and what
/// flew.
fn print_json(
    a: &EvalArgs,
    policy: PolicyKind,
    source: &str,
    shapes: Shapes,
    (layouts, stats): (&[Arena], &[EvalStats]),
    (pooled, memory): (&EvalStats, Option<usize>),
) {
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
            "sight": planner.then(|| a.sight.name().0),
            "memory_s": a.memory_s,
            "memory": (policy == PolicyKind::Greedy).then(|| rotorhive_model::memory_name(memory)),
            "layouts": layouts_json,
            "policy": policy.name(),
            "level": a.level,
            "settings": source,
            "frames": shapes.frames,
            "frame_stride": shapes.stride,
        })
    );
}
