//! What a run is given before it starts: its config resolved (`--resume`,
//! `--set`, `--max-seconds`), its paths made absolute, the replay checked to
//! fit the machine, and its sizing as it is printed and recorded.

use std::path::Path;

use anyhow::{Context, Result, bail};
use rotorhive_roles::Config;

use super::TrainArgs;

/// Refuses a replay memory that would not fit this machine's memory (its
/// capacity and reservoir of packed transitions, which a larger camera
/// makes larger), naming its size.
pub(super) fn replay_fits(cfg: &Config) -> Result<()> {
    let per = 2 * cfg.shapes().packed_len() as u64;
    let rows = cfg.replay.capacity as u64
        + if cfg.teacher.demos() { cfg.teacher.demo_capacity as u64 } else { 0 };
    let need = per * rows;
    // What the machine has (none known: nothing refused).
    let have = sysinfo::System::new().map_or(0, |mut sys| {
        sys.refresh_memory();
        sys.total_memory()
    });
    if have > 0 && need > have / 10 * 8 {
        let demos = if rows > cfg.replay.capacity as u64 {
            format!(" and {} of the teacher's reservoir", rows - cfg.replay.capacity as u64)
        } else {
            String::new()
        };
        bail!(
            "key `replay.capacity` = {}{demos}: transitions of {per} bytes need {:.1} GB; this \
             machine has {:.1} GB (a smaller capacity or camera)",
            cfg.replay.capacity,
            need as f64 / 1e9,
            have as f64 / 1e9
        );
    }
    Ok(())
}

/// The run's config: the given file (or, with `--resume`, the run's own)
/// plus `--set` and `--max-seconds`, with its arena checked.
pub(super) fn resolve_config(a: &TrainArgs) -> Result<Config> {
    let mut sets = a.cfg.set.clone();
    sets.extend(a.cores.map(|n| format!("cores={n}")));
    let mut cfg = match &a.resume {
        Some(dir) => {
            if a.cfg.config.is_some() {
                bail!(
                    "--resume takes the config of the run it continues; drop the CONFIG argument (use --set to change keys)"
                );
            }
            let state = dir.join("checkpoints/learner-state.safetensors");
            if !state.exists() {
                bail!(
                    "--resume {}: no learner state ({}) to continue from",
                    dir.display(),
                    state.display()
                );
            }
            Config::load(Some(&dir.join("config.toml")), &sets)
                .with_context(|| format!("--resume {}", dir.display()))?
        }
        None => Config::load(a.cfg.config.as_deref(), &sets)?,
    };
    if let Some(s) = a.max_seconds {
        if !(s.is_finite() && s > 0.0) {
            bail!("--max-seconds must be positive, got {s}");
        }
        cfg.max_seconds = s;
    }
    // Fail on a bad arena or generator before anything starts.
    if !cfg.sim.arena.as_os_str().is_empty() {
        cfg.arena()?;
    }
    cfg.gen_params()?;
    Ok(cfg)
}

/// Roles read the arenas relative to their working directory: resolve them.
pub(super) fn resolve_paths(cfg: &mut Config) -> Result<()> {
    if !cfg.sim.arena.as_os_str().is_empty() {
        cfg.sim.arena = cfg
            .sim
            .arena
            .canonicalize()
            .with_context(|| format!("arena {}", cfg.sim.arena.display()))?;
    }
    for t in &mut cfg.eval.test_arenas {
        *t =
            t.canonicalize().with_context(|| format!("key `eval.test_arenas`: {}", t.display()))?;
    }
    if !cfg.eval.arena.is_empty() {
        cfg.eval.arena = Path::new(&cfg.eval.arena)
            .canonicalize()
            .with_context(|| format!("key `eval.arena`: {}", cfg.eval.arena))?
            .display()
            .to_string();
        cfg.eval_arenas()?;
    }
    Ok(())
}

/// The run's sizing as `hive train` prints it at the start.
pub(super) fn sizing_line(cfg: &Config) -> String {
    let s = cfg.sizing();
    let sized = if cfg.sized.is_empty() {
        "all set by the config".to_string()
    } else {
        format!("sized: {}", cfg.sized.join(", "))
    };
    format!(
        "sizing: {} cores (of {}): {} environment(s) of {} agents, {} render thread(s) each, {} actor thread(s) each, {} learner thread(s) ({sized})",
        s.cores,
        s.cores_available,
        s.envs,
        cfg.sim.agents,
        s.render_threads,
        s.actor_threads,
        s.learner_threads,
    )
}

/// The run's sizing as `summary.json` holds it, with the keys it filled.
pub(super) fn sizing_json(cfg: &Config) -> Option<serde_json::Value> {
    let mut v = serde_json::to_value(cfg.sizing()).ok()?;
    v["sized"] = serde_json::json!(cfg.sized);
    Some(v)
}
