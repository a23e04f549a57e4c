//! The run's records as it goes: the tables of the run directory
//! (`metrics.csv`, `telemetry.csv`) with bounded size, the episode
//! bookkeeping (rolling reward, threshold, curve) and the bounded series the
//! plots are drawn from. `summary.json` is written at the end through
//! `rotorhive_records::Summary`.

use std::collections::BTreeMap;
use std::fs::File;
use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use rotorhive_msg::{DoneKind, EPISODE_FIELDS, EpisodeHeader};
use rotorhive_records::Rolling;
use rotorhive_records::rows::{self, METRICS_HEADER, MetricsKind, MetricsRow};
use rotorhive_roles::Config;

/// A CSV table of the run directory; a failed write (a full disk, a
/// directory gone) names the file. Past `TABLE_CAP` bytes it moves to
/// `NAME.1` (replacing an older one) and starts afresh with its header, so
/// a run of any length keeps at most twice the cap per table on disk.
pub(super) struct Table {
    path: PathBuf,
    file: File,
    header: String,
    written: u64,
    cap: u64,
}

/// Bytes a table grows to before it is rotated (hours of a default run:
/// `metrics.csv` grew by 12.5 MB an hour in a default run, `telemetry.csv` by 1.5).
const TABLE_CAP: u64 = 256 << 20;

impl Table {
    /// Opens `RUN_DIR/name`: appended to when `append` and it exists,
    /// otherwise created with `header`.
    pub(super) fn open(dir: &Path, name: &str, header: &str, append: bool) -> Result<Self> {
        let path = dir.join(name);
        let append = append && path.exists();
        let file = std::fs::OpenOptions::new()
            .create(true)
            .append(append)
            .write(true)
            .truncate(!append)
            .open(&path)
            .with_context(|| format!("cannot write {}", path.display()))?;
        let written = if append { file.metadata().map(|m| m.len()).unwrap_or(0) } else { 0 };
        let mut t = Self { path, file, header: header.to_string(), written, cap: TABLE_CAP };
        if !append {
            writeln!(t, "{header}")?;
        }
        Ok(t)
    }

    /// What `writeln!` calls: one row, whose failure names the file.
    pub(super) fn write_fmt(&mut self, line: std::fmt::Arguments) -> Result<()> {
        if self.written > self.cap {
            self.rotate()?;
        }
        let row = line.to_string();
        self.written += row.len() as u64;
        self.file
            .write_all(row.as_bytes())
            .with_context(|| format!("cannot write {}", self.path.display()))
    }

    /// Writes one typed row (`rotorhive_records::rows`).
    pub(super) fn row<R: serde::Serialize>(&mut self, row: &R) -> Result<()> {
        let line = rows::line(row)?;
        write!(self, "{line}")
    }

    fn rotate(&mut self) -> Result<()> {
        let old = self.path.with_extension("csv.1");
        std::fs::rename(&self.path, &old)
            .with_context(|| format!("cannot move {} to {}", self.path.display(), old.display()))?;
        self.file = File::create(&self.path)
            .with_context(|| format!("cannot write {}", self.path.display()))?;
        self.written = 0;
        let header = self.header.clone();
        writeln!(self, "{header}")
    }
}

/// Most points a time series of the supervisor keeps (plots need no more).
const MAX_POINTS: usize = 4096;

/// A time series whose memory stays bounded however long the run: when it
/// reaches `MAX_POINTS`, every other point goes and from then on only every
/// other sample is kept (and so on), so it always spans the whole run.
#[derive(Default)]
pub(super) struct Series {
    /// The kept points.
    pub(super) points: Vec<(f64, f64)>,
    stride: usize,
    seen: usize,
}

impl Series {
    pub(super) fn push(&mut self, p: (f64, f64)) {
        self.stride = self.stride.max(1);
        self.seen += 1;
        if !(self.seen - 1).is_multiple_of(self.stride) {
            return;
        }
        self.points.push(p);
        if self.points.len() >= MAX_POINTS {
            let kept: Vec<_> = self.points.iter().copied().step_by(2).collect();
            self.points = kept;
            self.stride *= 2;
            self.seen = 0;
        }
    }
}

/// A running mean (and maximum) that keeps no samples.
#[derive(Default, Clone, Copy)]
pub(super) struct Mean {
    sum: f64,
    n: u64,
    pub(super) max: f64,
}

impl Mean {
    pub(super) fn add(&mut self, v: f64) {
        self.sum += v;
        self.n += 1;
        self.max = if self.n == 1 { v } else { self.max.max(v) };
    }

    pub(super) fn mean(&self) -> Option<f64> {
        (self.n > 0).then(|| self.sum / self.n as f64)
    }
}

/// The episodes of a run as `metrics.csv` records them: counts, the
/// rolling window of returns and successes, the threshold crossing and the
/// reward curve.
pub(super) struct Progress {
    metrics: Table,
    rolling: Rolling,
    /// Episodes finished.
    pub(super) episodes: u64,
    /// The exploration rate the actors last reported.
    pub(super) epsilon: f64,
    /// Rolling reward against wall time, for `reward.png`.
    pub(super) curve: Series,
    /// When the rolling reward first reached the threshold.
    pub(super) time_to_threshold: Option<f64>,
    /// The agent-steps, learner updates and exploration rate then.
    pub(super) at_threshold: Option<(u64, u64, f64)>,
}

/// The exploration rate at or below which an episode counts in the rolling
/// window: with Ape-X's per-agent rates, the old schedule's floor
/// (`actor.eps_end`), so that "time to 300" keeps its meaning; with the one
/// schedule, every episode.
pub(super) fn rolling_floor(cfg: &Config) -> Option<f32> {
    (cfg.actor.exploration == rotorhive_roles::Exploration::PerActor)
        .then_some(cfg.actor.eps_end as f32)
}

/// The counters an episode row carries: agent-steps, learner updates and
/// replay size, from the telemetry or (a deterministic run) its schedule.
pub(super) type Counts = (u64, u64, i64);

impl Progress {
    /// Opens `metrics.csv` (appended to, with a `resume` row, when resumed).
    pub(super) fn open(run_dir: &Path, cfg: &Config, resumed: bool) -> Result<Self> {
        let mut metrics = Table::open(run_dir, "metrics.csv", METRICS_HEADER, resumed)?;
        if resumed {
            metrics.row(&MetricsRow::mark(MetricsKind::Resume, 0.0))?;
        }
        Ok(Self {
            metrics,
            rolling: Rolling::new(cfg.rolling_window, cfg.threshold, rolling_floor(cfg)),
            episodes: 0,
            epsilon: cfg.actor.eps_start,
            curve: Series::default(),
            time_to_threshold: None,
            at_threshold: None,
        })
    }

    /// Mean return of the rolling window (NaN before any episode).
    pub(super) fn rolling(&self) -> f64 {
        self.rolling.mean()
    }

    /// Share of the rolling window's episodes that reached the goal.
    pub(super) fn success_rate(&self) -> Option<f64> {
        self.rolling.success_rate()
    }

    /// Records one episodes message (records of `EPISODE_FIELDS`: return,
    /// length, done, the agent's epsilon); true when the rolling reward has
    /// just reached the threshold. The `epsilon` column is the episode's own.
    pub(super) fn record(
        &mut self,
        h: &EpisodeHeader,
        payload: &[f32],
        counts: Counts,
        wall: f64,
    ) -> Result<bool> {
        self.epsilon = h.epsilon_micro as f64 / 1e6;
        let mut crossed = false;
        for e in payload.chunks_exact(EPISODE_FIELDS) {
            self.episodes += 1;
            crossed |= self.rolling.push(wall, e[0], e[2] == DoneKind::Goal as u8 as f32, e[3]);
            self.metrics.row(&MetricsRow {
                kind: MetricsKind::Episode,
                episode_reward: Some(e[0]),
                epsilon: Some(rows::round(e[3] as f64, 4)),
                ..self.counters(wall, counts)
            })?;
        }
        self.time_to_threshold = self.rolling.crossed_at;
        if crossed && self.at_threshold.is_none() {
            self.at_threshold = Some((counts.0, counts.1, self.epsilon));
        }
        Ok(crossed)
    }

    /// The once-a-second `tick` row, and a point of the curve.
    pub(super) fn tick(&mut self, wall: f64, counts: Counts) -> Result<()> {
        let roll = self.rolling();
        self.curve.push((wall, roll));
        let counters = self.counters(wall, counts);
        self.metrics.row(&counters)
    }

    /// A `tick` row of the run's counters now (an episode row starts from it).
    fn counters(&self, wall: f64, (env_steps, updates, replay_size): Counts) -> MetricsRow {
        MetricsRow {
            kind: MetricsKind::Tick,
            wall_s: rows::round(wall, 3),
            env_steps: Some(env_steps),
            episodes: Some(self.episodes),
            episode_reward: None,
            rolling_reward: Some(rows::round(self.rolling(), 3)),
            epsilon: Some(rows::round(self.epsilon, 4)),
            updates: Some(updates),
            replay_size: Some(replay_size),
        }
    }

    /// A `restart` row: a role died and was started again.
    pub(super) fn restart(&mut self, wall: f64) -> Result<()> {
        self.metrics.row(&MetricsRow::mark(MetricsKind::Restart, wall))
    }
}
/// One episodes message: its header and its (return, length, done) triples.
pub(super) type Reported = (EpisodeHeader, Vec<f32>);

/// Episode messages in the order they are written to `metrics.csv`: as they
/// come, or (a deterministic run) by (step, environment): every actor of
/// such a run reports every step, so once each has reported step `k`,
/// everything up to `k` is known.
pub(super) struct EpisodeOrder {
    ordered: bool,
    /// Newest step each environment reported.
    latest: Vec<Option<u64>>,
    held: BTreeMap<(u64, u32), Vec<Reported>>,
}

impl EpisodeOrder {
    pub(super) fn new(envs: usize, ordered: bool) -> Self {
        Self { ordered, latest: vec![None; envs], held: BTreeMap::new() }
    }

    pub(super) fn push(&mut self, h: EpisodeHeader, payload: &[f32]) {
        if let Some(l) = self.latest.get_mut(h.actor as usize) {
            *l = Some(l.map_or(h.step, |v| v.max(h.step)));
        }
        self.held
            .entry((if self.ordered { h.step } else { 0 }, if self.ordered { h.actor } else { 0 }))
            .or_default()
            .push((h, payload.to_vec()));
    }

    /// The step every environment has reported (0 before all have).
    pub(super) fn through(&self) -> u64 {
        self.latest.iter().map(|l| l.unwrap_or(0)).min().unwrap_or(0)
    }

    /// The messages that can be written now, in order.
    pub(super) fn ready(&mut self) -> Vec<Reported> {
        if !self.ordered {
            return std::mem::take(&mut self.held).into_values().flatten().collect();
        }
        let upto = self.through();
        let later = self.held.split_off(&(upto + 1, 0));
        std::mem::replace(&mut self.held, later).into_values().flatten().collect()
    }
}

/// The renderer as `summary.json` names it.
pub(super) fn renderer_of(cfg: &Config) -> rotorhive_records::Renderer {
    match cfg.sim.renderer {
        rotorhive_sim::RendererKind::Cpu => rotorhive_records::Renderer::Cpu,
        rotorhive_sim::RendererKind::Wgpu => rotorhive_records::Renderer::Wgpu,
    }
}

/// The run's seen movers as `summary.json` holds them, with their floats
/// (none without tracks).
pub(super) fn tracks_json(cfg: &Config) -> Option<serde_json::Value> {
    cfg.sim.tracks.enabled().then(|| {
        let mut v = serde_json::json!(cfg.sim.tracks);
        v["floats"] = cfg.sim.tracks.floats().into();
        v
    })
}

/// The run's camera map as `summary.json` holds it, with its floats (none
/// without a map).
pub(super) fn map_json(cfg: &Config) -> Option<serde_json::Value> {
    cfg.sim.map.enabled().then(|| {
        let mut v = serde_json::json!(cfg.sim.map);
        v["floats"] = cfg.sim.map.floats().into();
        v
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_table_past_its_cap_moves_aside_and_starts_again_with_its_header() {
        let dir = std::env::temp_dir().join(format!("rotorhive-table-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let mut t = Table::open(&dir, "metrics.csv", "a,b", false).unwrap();
        t.cap = 100;
        for i in 0..40 {
            writeln!(t, "{i},{}", i * 2).unwrap();
        }
        let now = std::fs::read_to_string(dir.join("metrics.csv")).unwrap();
        let old = std::fs::read_to_string(dir.join("metrics.csv.1")).unwrap();
        assert!(now.starts_with("a,b\n") && old.starts_with("a,b\n"), "{now:?} {old:?}");
        assert!(now.len() <= 120 && old.len() <= 120, "{} {}", now.len(), old.len());
        assert!(now.ends_with("39,78\n"), "{now:?}");
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn a_deterministic_run_writes_episodes_by_step_then_environment() {
        let h = |actor: u32, step: u64| EpisodeHeader { actor, count: 1, epsilon_micro: 0, step };
        let mut o = EpisodeOrder::new(2, true);
        o.push(h(1, 3), &[1.0, 1.0, 1.0, 0.1]);
        o.push(h(1, 4), &[2.0, 1.0, 1.0, 0.1]);
        // Environment 0 has reported nothing yet: nothing can be written.
        assert!(o.ready().is_empty());
        o.push(h(0, 3), &[3.0, 1.0, 1.0, 0.1]);
        let got: Vec<(u32, u64)> = o.ready().iter().map(|(h, _)| (h.actor, h.step)).collect();
        assert_eq!(got, vec![(0, 3), (1, 3)]);
        assert_eq!(o.through(), 3);
        o.push(h(0, 4), &[]);
        assert_eq!(
            o.ready().iter().map(|(h, _)| (h.actor, h.step)).collect::<Vec<_>>(),
            vec![(0, 4), (1, 4)]
        );
        // Free-running: as they come.
        let mut o = EpisodeOrder::new(2, false);
        o.push(h(1, 9), &[]);
        o.push(h(0, 2), &[]);
        assert_eq!(o.ready().iter().map(|(h, _)| h.actor).collect::<Vec<_>>(), vec![1, 0]);
    }
}
