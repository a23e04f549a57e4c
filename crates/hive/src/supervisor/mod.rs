//! `hive train`: the main job, and its supervisor. Validates the config,
//! creates the run directory, starts every role (the [`launcher`]), watches
//! episodes ([`records`]) and telemetry ([`monitor`]) over shared memory,
//! evaluates greedy policies beside training ([`evaluator`]), shows
//! progress, stops at the threshold, the step or time budget (or a
//! signal), stops the roles and writes `summary.json`, `metrics.csv`,
//! `telemetry.csv`, `evals.csv`, the plots and `profile.md`.

mod board;
mod evaluator;
mod launcher;
mod monitor;
mod records;
mod setup;

use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use clap::Args;
use indicatif::{ProgressBar, ProgressStyle};
use rotorhive_msg::{EpisodeHeader, RoleKind, Telemetry};
use rotorhive_records::Summary;
use rotorhive_roles::schedule::Schedule;
use rotorhive_roles::{Config, episodes_channel, roles_of};
use rotorhive_transport::Service;
use rotorhive_transport::{
    Channel, Hub, Ipc, Local, Receiver, cleanup_dead_nodes, services_of_run,
};
use setup::{replay_fits, resolve_config, resolve_paths, sizing_json, sizing_line};

use crate::role_cmd::ConfigArgs;
use board::Board;
use evaluator::Evaluator;
pub(crate) use launcher::Members;
pub use launcher::host_name;
use launcher::{lock_run_dir, timestamp};
use monitor::Monitor;
use records::{Counts, EpisodeOrder, Progress};

#[derive(Args, Debug)]
pub struct TrainArgs {
    #[command(flatten)]
    pub cfg: ConfigArgs,
    /// Run directory (default `runs/<timestamp>`).
    #[arg(long)]
    pub run_dir: Option<PathBuf>,
    /// Wall-clock budget in seconds (overrides `max_seconds`).
    #[arg(long)]
    pub max_seconds: Option<f64>,
    /// No progress bar (for logs and tests).
    #[arg(long)]
    pub quiet: bool,
    /// Serial mode, for debugging: every role as a thread of this process
    /// over iceoryx2's `local` service (no restarts), same run directory.
    #[arg(long)]
    pub serial: bool,
    /// Size the run for N cores (sets `cores`; 0 = all of the machine's):
    /// environments and threads left at 0 in the config follow.
    #[arg(long, value_name = "N")]
    pub cores: Option<usize>,
    /// Continue a stopped run in RUN_DIR: its config (plus any --set), the
    /// learner's saved state and the replay memory's snapshot.
    #[arg(long, value_name = "RUN_DIR", conflicts_with = "run_dir")]
    pub resume: Option<PathBuf>,
    /// Head of a run across hosts: listen for workers (`hive worker
    /// --connect`) on this endpoint, e.g. quic/0.0.0.0:7447 with --tls;
    /// `[cluster] workers` says how many the run waits for.
    #[arg(long, value_name = "quic/ADDR:PORT")]
    pub listen: Option<String>,
    #[command(flatten)]
    pub link: crate::link_args::LinkArgs,
}

/// The head's link to its worker hosts, with the texts it hands them.
type HeadLink = Option<(rotorhive_link::Head, (String, String))>;

pub fn run(a: TrainArgs) -> Result<()> {
    if let Some(ep) = &a.listen {
        a.link.check_listen(ep)?;
    }
    let mut cfg = resolve_config(&a)?;
    replay_fits(&cfg)?;
    let run_dir = a
        .resume
        .clone()
        .or_else(|| a.run_dir.clone())
        .unwrap_or_else(|| PathBuf::from("runs").join(timestamp()));
    std::fs::create_dir_all(&run_dir)
        .with_context(|| format!("cannot create run directory {}", run_dir.display()))?;
    let run_dir = run_dir.canonicalize()?;
    // Nothing of the run directory is written before its lock is held.
    let _lock = lock_run_dir(&run_dir)?;
    resolve_paths(&mut cfg)?;
    say(&sizing_line(&cfg));
    let prefix = rotorhive_transport::unique_prefix("run");
    rotorhive_transport::handle_hangup();
    // The head's environments come first in the run.
    cfg.cluster.env_offset = 0;
    let head = match &a.listen {
        Some(ep) => {
            let opts = a.link.head_options(cfg.cluster.workers);
            Some(gather_workers(ep, &prefix, &mut cfg, &opts)?)
        }
        None if cfg.cluster.workers > 0 => bail!(
            "key `cluster.workers` = {} needs --listen tcp/ADDR:PORT for the workers to join",
            cfg.cluster.workers
        ),
        None => {
            cfg.cluster.envs_elsewhere = 0;
            cfg.cluster.agents_elsewhere = 0;
            None
        }
    };
    let unused = cfg.unused_keys();
    if !unused.is_empty() {
        tracing::info!("keys this run does not use: {}", unused.join(", "));
    }
    let cfg_path = run_dir.join("config.toml");
    std::fs::write(&cfg_path, cfg.to_toml())
        .with_context(|| format!("cannot write {}", cfg_path.display()))?;
    let link = match head {
        Some(mut head) => {
            // The workers get the config every role of this run reads, and the arena.
            // (No arena file: the lanes are all generated, and none is sent.)
            let arena = if cfg.sim.arena.as_os_str().is_empty() {
                String::new()
            } else {
                std::fs::read_to_string(&cfg.sim.arena)
                    .with_context(|| format!("arena {}", cfg.sim.arena.display()))?
            };
            let text = (cfg.to_toml(), arena);
            let t = text.clone();
            head.admit(move |_| t.clone());
            Some((head, text))
        }
        None => None,
    };
    // Resources of crashed earlier runs would otherwise linger in /dev/shm.
    let stale = cleanup_dead_nodes();
    if stale > 0 {
        tracing::info!("cleaned {stale} dead iceoryx2 nodes of earlier runs");
    }
    if a.serial {
        // Candle's pools stay single-threaded, as in the role processes
        // (`main` set them: `TrainArgs::thread_env`).
        supervise::<Local>(&a, cfg, &run_dir, &cfg_path, prefix, link)
    } else {
        supervise::<Ipc>(&a, cfg, &run_dir, &cfg_path, prefix, link)
    }
}

impl TrainArgs {
    /// The environment the process must start with (set by `main` before
    /// any thread): with `--serial`, candle's pools single-threaded, as in
    /// the role processes.
    pub fn thread_env(&self) -> Vec<(&'static str, String)> {
        if self.serial {
            vec![("RAYON_NUM_THREADS", "1".into()), ("CANDLE_NUM_THREADS", "1".into())]
        } else {
            Vec::new()
        }
    }
}

/// Listens on `ep` and waits for `cluster.workers` worker hosts; their
/// environments and agents go into `cfg.cluster`.
fn gather_workers(
    ep: &str,
    prefix: &str,
    cfg: &mut Config,
    opts: &rotorhive_link::LinkOptions,
) -> Result<rotorhive_link::Head> {
    let mut head = rotorhive_link::Head::listen(
        ep,
        prefix,
        rotorhive_link::layout(rotorhive_model::num_params(
            rotorhive_msg::Shapes::PAPER,
            rotorhive_model::Layers::DEFAULT,
        )),
        opts,
    )?;
    let wanted = cfg.cluster.workers;
    if wanted > 0 {
        say(&format!(
            "listening on {ep}: waiting for {wanted} worker host(s), at most {:.0} s",
            cfg.cluster.join_timeout_s
        ));
    }
    let timeout = Duration::from_secs_f64(cfg.cluster.join_timeout_s);
    let limits = rotorhive_link::JoinLimits {
        default_agents: cfg.sim.agents as u32,
        n_step: cfg.learner.n_step as u32,
    };
    let hosts =
        head.gather(wanted, cfg.sim.envs, limits, timeout, rotorhive_transport::stop_requested)?;
    cfg.cluster.envs_elsewhere = hosts.iter().map(|h| h.envs as usize).sum();
    cfg.cluster.agents_elsewhere = hosts.iter().map(|h| h.envs as usize * h.agents as usize).sum();
    for h in &hosts {
        say(&format!(
            "worker {} joined: {} × {} agents (environments {}..{})",
            h.name,
            h.envs,
            h.agents,
            h.env_offset,
            h.env_offset + h.envs
        ));
    }
    Ok(head)
}

/// Prints a line to stdout; a closed terminal (SIGHUP) makes this fail, which
/// must not stop the run from writing its records.
fn say(line: &str) {
    let _ = writeln!(std::io::stdout(), "{line}");
}

/// How the supervision loop ended.
#[derive(Default)]
struct Ending {
    /// Wall seconds when the loop ended (before the roles were stopped).
    wall: f64,
    interrupted: bool,
    failure: Option<String>,
}

/// The supervisor's node and ports on the iceoryx2 service `S` (`ipc` for
/// role processes, `local` for serial mode); dropped before the run checks
/// that none of its shared memory is left.
struct Ports<S: Service> {
    hub: Hub<S>,
    episodes_rx: Receiver<S, f32, EpisodeHeader>,
    telemetry_rx: Receiver<S, u8, Telemetry>,
}

/// One run under supervision.
struct Supervisor<'a> {
    a: &'a TrainArgs,
    cfg: Config,
    run_dir: &'a Path,
    members: Members,
    link: Option<rotorhive_link::HeadLink>,
    progress: Progress,
    monitor: Monitor,
    evaluator: Evaluator,
    board: Option<Board>,
    schedule: Option<Schedule>,
    order: EpisodeOrder,
    bar: ProgressBar,
    start: Instant,
    restarts: u64,
    /// The run's agent-steps, for the evaluator's agent-step clock.
    steps: Arc<AtomicU64>,
}

/// Supervises the run `prefix` until it ends, then writes its records.
fn supervise<S: Service>(
    a: &TrainArgs,
    cfg: Config,
    run_dir: &Path,
    cfg_path: &Path,
    prefix: String,
    link: HeadLink,
) -> Result<()> {
    let hub = Hub::<S>::new(&prefix, &rotorhive_transport::supervisor_node_name(&prefix))?;
    let episodes_rx = hub.receiver::<f32, EpisodeHeader>(&episodes_channel(cfg.sim.envs))?;
    let telemetry_rx = hub.receiver::<u8, Telemetry>(&Channel::telemetry(roles_of(&cfg)))?;
    let mut ports = Ports { hub, episodes_rx, telemetry_rx };
    let members = Members::start(
        &cfg,
        a.serial,
        &prefix,
        run_dir,
        cfg_path,
        rotorhive_roles::role_names(&cfg),
    )?;
    let link = match link {
        Some((head, text)) => Some(head.with_rows(cfg.rows()).bridge::<S>(
            prefix.clone(),
            cfg.sim.envs,
            roles_of(&cfg),
            Arc::new(AtomicBool::new(false)),
            Box::new(move |_| text.clone()),
        )?),
        None => None,
    };
    // A resumed run appends to its tables (wall time starts again at 0).
    let resumed = a.resume.is_some();
    let bar = if a.quiet { ProgressBar::hidden() } else { ProgressBar::new_spinner() };
    bar.set_style(
        ProgressStyle::with_template("{spinner} [{elapsed_precise}] {msg}")
            .expect("valid template"),
    );
    bar.enable_steady_tick(Duration::from_millis(200));
    let start = Instant::now();
    let steps = Arc::new(AtomicU64::new(0));
    let mut s = Supervisor {
        progress: Progress::open(run_dir, &cfg, resumed)?,
        monitor: Monitor::open(run_dir, resumed)?,
        evaluator: Evaluator::start::<S>(&cfg, &prefix, run_dir, (start, steps.clone()), resumed)?,
        steps,
        board: if cfg.tensorboard {
            Some(Board::open(run_dir, &launcher::host_name())?)
        } else {
            None
        },
        schedule: cfg.deterministic.then(|| Schedule::new(&cfg)),
        order: EpisodeOrder::new(cfg.sim.envs, cfg.deterministic),
        a,
        cfg,
        run_dir,
        members,
        link,
        bar,
        start,
        restarts: 0,
    };
    // Any error of the loop (a table that cannot be written, a role that
    // cannot be started again) stops the run as a failure: the roles are
    // stopped and the records written all the same.
    let mut ending = Ending::default();
    if let Err(e) = s.watch(&mut ports, &mut ending) {
        ending.failure = Some(format!("{e:#}"));
    }
    ending.wall = s.wall();
    let hosts = s.stop(&mut ports, &mut ending)?;
    drop(ports);
    s.finish(ending, hosts, services_of_run::<S>(&prefix))
}

impl Supervisor<'_> {
    /// The supervision loop, until the run ends.
    fn watch<S: Service>(&mut self, p: &mut Ports<S>, ending: &mut Ending) -> Result<()> {
        let mut last_tick = Instant::now();
        loop {
            if p.hub.shutdown_requested() {
                ending.interrupted = true;
                return Ok(());
            }
            self.take_episodes(&mut p.episodes_rx)?;
            self.evaluator.poll();
            self.monitor.receive(&mut p.telemetry_rx)?;
            self.steps.store(self.monitor.counts().0, std::sync::atomic::Ordering::Relaxed);
            if self.done() {
                return Ok(());
            }
            ending.failure = self.trouble(&p.hub)?;
            if ending.failure.is_some() || self.wall() >= self.cfg.max_seconds {
                return Ok(());
            }
            if last_tick.elapsed() >= Duration::from_secs(1) {
                last_tick = Instant::now();
                self.tick()?;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    fn wall(&self) -> f64 {
        self.start.elapsed().as_secs_f64()
    }

    /// Episodes from every actor into `metrics.csv`; a deterministic run's
    /// in (step, environment) order, with its schedule's counts.
    fn take_episodes<S: Service>(
        &mut self,
        rx: &mut Receiver<S, f32, EpisodeHeader>,
    ) -> Result<()> {
        while let Some(m) = rx.try_recv()? {
            self.order.push(*m.user_header(), m.payload());
        }
        for (h, payload) in self.order.ready() {
            let counts: Counts = match &self.schedule {
                Some(s) => {
                    let steps = h.step * self.cfg.agents_total() as u64;
                    (
                        steps,
                        s.minibatches_after(h.step),
                        steps.min(self.cfg.replay.capacity as u64) as i64,
                    )
                }
                None => self.monitor.counts(),
            };
            // At the crossing an evaluation is asked for, unless they run
            // on the agent-step clock (the learning metric must not be
            // timed by the crossing).
            if self.progress.record(&h, &payload, counts, self.wall())?
                && self.cfg.eval.every_env_steps == 0
            {
                self.evaluator.ask_now();
            }
        }
        Ok(())
    }

    /// Whether the run reached its end: a deterministic run's schedule
    /// done, the step budget spent, or the threshold reached (and, with
    /// evaluation, a good enough greedy policy seen or its grace spent).
    fn done(&self) -> bool {
        let learner = self.monitor.sum_work(RoleKind::Learner);
        if let Some(s) = &self.schedule {
            return self.order.through() >= s.rounds() && learner >= s.total_updates();
        }
        if self.cfg.max_env_steps > 0
            && self.monitor.sum_work(RoleKind::Sim) >= self.cfg.max_env_steps
        {
            return true;
        }
        let Some(t) = self.progress.time_to_threshold else {
            return false;
        };
        if !self.cfg.early_stop {
            return false;
        }
        let good = self.evaluator.best_score().is_some_and(|b| b.0 >= self.cfg.eval.target_success);
        !self.evaluator.on() || good || self.wall() - t >= self.cfg.eval.after_threshold_s
    }

    /// What stops the run as a failure: the evaluator or the link gone, or
    /// a role that keeps dying (one that dies once is restarted here).
    fn trouble<S: Service>(&mut self, hub: &Hub<S>) -> Result<Option<String>> {
        if self.evaluator.died() {
            return Ok(Some("the evaluator stopped; see the error below".into()));
        }
        if self.link.as_ref().is_some_and(|l| l.is_finished()) {
            return Ok(Some(match self.link.take().map(|mut l| l.stop()) {
                Some(Err(e)) => format!("the link to the worker hosts stopped: {e}"),
                _ => "the link to the worker hosts stopped".into(),
            }));
        }
        let (bar, progress, start) = (&self.bar, &mut self.progress, self.start);
        let restarts = &mut self.restarts;
        self.members.check(&|| hub.shutdown_requested(), &mut |line| {
            let wall = start.elapsed().as_secs_f64();
            bar.println(format!("[{wall:.1} s] {line}"));
            *restarts += 1;
            progress.restart(wall)
        })
    }

    /// Once a second: telemetry rows, a `tick` row and the progress line.
    fn tick(&mut self) -> Result<()> {
        let wall = self.wall();
        let reading = self.monitor.sample(wall, self.members.pids(), self.members.processes())?;
        let counts = self.monitor.counts();
        self.progress.tick(wall, counts)?;
        if let Some(b) = &mut self.board {
            b.tick(wall, counts, &self.progress, &reading.rows, &self.evaluator.evals)?;
        }
        let (steps, updates, _) = counts;
        // Across hosts: each host's share of the agent-steps.
        let hosts = self.link.as_ref().map_or(String::new(), |l| {
            let mut parts =
                vec![format!("here {}", self.monitor.steps_of(0, self.cfg.sim.envs as u32))];
            parts.extend(l.hosts.iter().map(|h| {
                format!("{} {}", h.name, self.monitor.steps_of(h.env_offset, h.env_offset + h.envs))
            }));
            format!(" | hosts: {}", parts.join(", "))
        });
        self.bar.set_message(format!(
            "steps {steps} ({:.0}/s){hosts} | episodes {} | rolling reward {:.1} | eps {:.3} | updates {updates} ({:.1}/s) | best eval {} | cpu {:.0}%{}",
            steps as f64 / wall.max(1e-9),
            self.progress.episodes,
            self.progress.rolling(),
            self.progress.epsilon,
            updates as f64 / wall.max(1e-9),
            self.evaluator.best().map_or("-".to_string(), |b| format!("{:.0}%", b.success * 100.0)),
            reading.machine_cpu,
            reading.gpu.map_or(String::new(), |g| format!(" | gpu {:.0}% {:.0} W", g.util_pct, g.power_w)),
        ));
        Ok(())
    }

    /// Stops the evaluator, the link and the roles; the run's hosts.
    fn stop<S: Service>(
        &mut self,
        p: &mut Ports<S>,
        ending: &mut Ending,
    ) -> Result<Vec<rotorhive_records::HostSummary>> {
        self.bar.finish_and_clear();
        // Last counters before the roles go.
        self.monitor.receive(&mut p.telemetry_rx)?;
        if let Some(e) = self.evaluator.stop() {
            ending.failure = Some(format!("evaluation failed: {e}"));
        }
        // The workers end with the run: tell them before the roles go.
        let link_stats = self.link.as_ref().map(|l| (l.stats.clone(), l.hosts.clone()));
        if let Some(Err(e)) = self.link.take().map(|mut l| l.stop())
            && ending.failure.is_none()
        {
            ending.failure = Some(format!("link: {e}"));
        }
        if let Some(e) = self.members.stop() {
            ending.failure = Some(match ending.failure.take() {
                Some(f) => format!("{f}: {e}"),
                None => e,
            });
        }
        // And the roles' last word: each sends its counters as it ends
        // (iceoryx2 keeps a gone publisher's samples for the subscriber), so
        // the summary counts what they did to the end, not to their last
        // periodic sample (on a slow machine a second or more before).
        self.monitor.receive(&mut p.telemetry_rx)?;
        Ok(self.monitor.hosts(&self.cfg, link_stats.as_ref()))
    }

    /// Writes the records of the run; its failure, if any, as the error.
    fn finish(
        self,
        ending: Ending,
        hosts: Vec<rotorhive_records::HostSummary>,
        leftover: Vec<String>,
    ) -> Result<()> {
        let wall = ending.wall;
        let summary = self.summary(wall, hosts, &ending, leftover.clone());
        if let Err(e) = summary.write(self.run_dir) {
            let also =
                ending.failure.map_or(String::new(), |f| format!(" (the run had failed: {f})"));
            bail!("{e:#}{also}");
        }
        self.pictures();
        say(&format!(
            "run {}: {} in {wall:.1} s, {} episodes, rolling reward {:.1}, {} agent-steps, {} updates",
            self.run_dir.display(),
            summary
                .time_to_threshold_s
                .map_or("did not converge".to_string(), |t| format!("converged at {t:.1} s")),
            summary.episodes,
            self.progress.rolling(),
            summary.env_steps,
            summary.learner_updates,
        ));
        self.profile();
        if let Some(f) = ending.failure {
            bail!("{f}");
        }
        if !leftover.is_empty() {
            bail!("shared memory left behind after the run: {leftover:?}");
        }
        Ok(())
    }

    /// The run's result (the best greedy policy seen, else the last
    /// weights) and its last weights, where they were written.
    fn checkpoints(&self) -> (Option<PathBuf>, Option<PathBuf>) {
        let final_ckpt = self.run_dir.join("final.safetensors");
        let last = if final_ckpt.exists() {
            Some(final_ckpt)
        } else {
            Some(self.run_dir.join("checkpoints/latest.safetensors")).filter(|p| p.exists())
        };
        let best_ckpt = self.run_dir.join("checkpoints/best.safetensors");
        let checkpoint = if best_ckpt.exists() { Some(best_ckpt) } else { last.clone() };
        (checkpoint, last)
    }

    /// What the run's teacher did, from the roles' telemetry.
    fn teaching(&self) -> rotorhive_records::Teaching {
        let (cfg, tc) = (&self.cfg, self.monitor.teacher());
        let per = |ns: u64, n: u64| (n > 0).then(|| ns as f64 / 1e6 / n as f64);
        rotorhive_records::Teaching {
            teacher: cfg.teacher.on().then(|| serde_json::json!(cfg.teacher)),
            demo_transitions: tc.demo_transitions,
            labelled_transitions: tc.labelled_transitions,
            teacher_ms_per_label: per(tc.label_ns, tc.labels),
            teacher_ms_per_demo_step: per(tc.demo_ns, tc.demo_steps),
            teacher_s: (tc.label_ns + tc.demo_ns) as f64 / 1e9,
        }
    }

    /// `summary.json` of the run.
    fn summary(
        &self,
        wall: f64,
        hosts: Vec<rotorhive_records::HostSummary>,
        ending: &Ending,
        leftover: Vec<String>,
    ) -> Summary {
        let (env_steps, updates) =
            (self.monitor.sum_work(RoleKind::Sim), self.monitor.sum_work(RoleKind::Learner));
        let (checkpoint, last) = self.checkpoints();
        let (m, best, cfg) = (&self.monitor, self.evaluator.best(), &self.cfg);
        let roll = self.progress.rolling();
        let at_target = self.evaluator.first_at(cfg.eval.target_success);
        let mut rejected_by_reason = std::collections::BTreeMap::new();
        for (reason, n) in hosts.iter().flat_map(|h| &h.rejected_by_reason) {
            *rejected_by_reason.entry(reason.clone()).or_insert(0) += n;
        }
        Summary {
            converged: self.progress.time_to_threshold.is_some(),
            threshold: cfg.threshold,
            time_to_threshold_s: self.progress.time_to_threshold,
            wall_s: wall,
            env_steps,
            episodes: self.progress.episodes,
            rolling_reward: roll.is_finite().then_some(roll),
            rolling_success_rate: self.progress.success_rate(),
            learner_updates: updates,
            envs: cfg.sim.envs,
            agents_per_env: cfg.sim.agents,
            agents_total: cfg.agents_total(),
            hosts,
            observation_mode: cfg.sim.observation_mode,
            renderer: records::renderer_of(cfg),
            env_steps_per_s: env_steps as f64 / wall,
            updates_per_s: updates as f64 / wall,
            cpu_util_mean_pct: m.cpu.mean(),
            gpu_util_mean_pct: m.gpu_util.mean(),
            gpu_power_mean_w: m.gpu_power.mean(),
            gpu_mem_peak_mb: m.gpu_mem.mean().map(|_| m.gpu_mem.max),
            peak_rss_mb: m.peak_rss_mb,
            policy_lag_mean: m.policy_lag.mean(),
            restarts: self.restarts,
            lost_messages: m.lost(),
            rejected_by_reason,
            checkpoint: checkpoint.map(|p| p.display().to_string()),
            last_checkpoint: last.map(|p| p.display().to_string()),
            evaluations: self.evaluator.count(),
            best_eval_success_rate: best.map(|b| b.success),
            best_eval_mean_reward: best.map(|b| b.mean_reward),
            best_eval_at_s: best.map(|b| b.wall),
            best_eval_updates: best.map(|b| b.updates),
            time_to_target_success_s: at_target.map(|e| e.wall),
            env_steps_at_threshold: self.progress.at_threshold.map(|a| a.0),
            updates_at_threshold: self.progress.at_threshold.map(|a| a.1),
            epsilon_at_threshold: self.progress.at_threshold.map(|a| a.2),
            env_steps_to_target: at_target.and_then(|e| e.env_steps),
            result_validation_success: self.evaluator.best_score().map(|s| s.0),
            result_validation_episodes: best.map(|_| {
                if cfg.eval.confirm_episodes > 0 {
                    cfg.eval.confirm_episodes
                } else {
                    cfg.eval.episodes
                }
            }),
            final_validation_success: self.evaluator.evals.last().map(|e| e.success),
            skipped_updates: m
                .latest
                .get(&(RoleKind::Learner as u32, 0))
                .map_or(0, |t| t.learning.skipped_updates as u64),
            teaching: self.teaching(),
            sizing: sizing_json(cfg),
            map: records::map_json(cfg),
            tracks: records::tracks_json(cfg),
            interrupted: ending.interrupted,
            resumed: self.a.resume.is_some(),
            failure: ending.failure.clone(),
            leftover_services: leftover,
        }
    }

    /// `utilisation.png` and `reward.png`: a plot that cannot be drawn
    /// costs the picture, not the run's result.
    fn pictures(&self) {
        let series: Vec<(String, Vec<(f64, f64)>)> =
            self.monitor.util.iter().map(|(k, v)| (k.clone(), v.points.clone())).collect();
        if let Err(e) = rotorhive_records::plot::lines_plot(
            "utilisation (% of the machine)",
            "wall time (s)",
            "%",
            &series,
            &self.run_dir.join("utilisation.png"),
        ) {
            tracing::warn!("utilisation.png not written: {e:#}");
        }
        let curve: Vec<(f64, f64)> =
            self.progress.curve.points.iter().copied().filter(|p| p.1.is_finite()).collect();
        let validation: Vec<(f64, f64)> =
            self.evaluator.evals.iter().map(|e| (e.wall, e.success)).collect();
        let result_at = self.evaluator.best().map(|b| b.wall);
        if let Err(e) = rotorhive_records::plot::reward_plot(
            &curve,
            self.cfg.threshold,
            &validation,
            result_at,
            &self.run_dir.join("reward.png"),
        ) {
            tracing::warn!("reward.png not written: {e:#}");
        }
    }

    /// `profile.md`, and its bottleneck line on the terminal.
    fn profile(&self) {
        let profile = rotorhive_records::profile::analyse(self.run_dir)
            .and_then(|p| Ok((p.markdown(self.run_dir)?, p)));
        match profile {
            Ok((r, p)) => {
                let path = self.run_dir.join("profile.md");
                if let Err(e) = std::fs::write(&path, &r) {
                    tracing::warn!("cannot write {}: {e}", path.display());
                }
                if let Some(b) = &p.bottleneck {
                    say(&b.to_string());
                }
            }
            Err(e) => tracing::warn!("no profile: {e:#}"),
        }
    }
}
