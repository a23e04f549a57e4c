//! The evaluator: greedy flights of the newest published weights beside
//! training, on a thread of the supervisor with its own iceoryx2 node; the
//! best weights are the run's result (`checkpoints/best.safetensors`).
//!
//! Choosing the best of many noisy scores picks, on average, a score
//! that is too high (the winner's curse: the true rate of a policy that
//! scored 90 % once is often lower). So every evaluation is a screening on
//! the same spawns (comparable over the run), and one that may beat the
//! best so far is confirmed on `eval.confirm_episodes` fresh spawns; only
//! confirmed scores, independent of the choice, are compared and kept.

use std::io::Write;
use std::path::PathBuf;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::mpsc;
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use anyhow::{Context, Result};
use rotorhive_model::PolicyNet;
use rotorhive_msg::WeightsHeader;
use rotorhive_records::rows::{self, EvalRow};
use rotorhive_roles::Config;
use rotorhive_transport::Service;
use rotorhive_transport::{Channel, Hub};

/// One greedy evaluation during training.
#[derive(Debug, Clone, Copy)]
pub(super) struct EvalPoint {
    pub(super) wall: f64,
    pub(super) updates: u64,
    /// Agent-steps of the run when the weights were taken (unknown in
    /// tables of older runs).
    pub(super) env_steps: Option<u64>,
    /// The screening: success rate and mean reward on the fixed spawns.
    pub(super) success: f64,
    pub(super) mean_reward: f64,
    /// The confirmation on fresh spawns (success, mean reward), when the
    /// screening made these weights a candidate.
    pub(super) confirmed: Option<(f64, f64)>,
}

impl EvalPoint {
    /// Its row of `evals.csv`: the weights' `version`, the screening's
    /// `episodes`, whether it became the best, the confirmation's episodes.
    fn row(&self, version: u64, episodes: usize, best: bool, confirm_episodes: usize) -> EvalRow {
        EvalRow {
            wall_s: rows::round(self.wall, 3),
            updates: self.updates,
            version,
            episodes: episodes as u64,
            success_rate: rows::round(self.success, 4),
            mean_reward: rows::round(self.mean_reward, 2),
            best: best as u8,
            confirmed_episodes: self.confirmed.map(|_| confirm_episodes as u64),
            confirmed_success_rate: self.confirmed.map(|c| rows::round(c.0, 4)),
            confirmed_mean_reward: self.confirmed.map(|c| rows::round(c.1, 2)),
            env_steps: self.env_steps,
        }
    }

    /// The score the run's result is chosen by: the confirmation where
    /// confirmations are made, else the screening.
    pub(super) fn score(&self, confirming: bool) -> Option<(f64, f64)> {
        if confirming { self.confirmed } else { Some((self.success, self.mean_reward)) }
    }
}

/// The evaluations of `evals.csv` (none when it does not exist); a row that
/// does not parse names the file, the line and the column.
fn read_evals(path: &std::path::Path) -> Result<Vec<EvalPoint>> {
    let rows: Vec<EvalRow> = rotorhive_records::rows::read(path)?;
    Ok(rows
        .into_iter()
        .map(|r| EvalPoint {
            wall: r.wall_s,
            updates: r.updates,
            env_steps: r.env_steps,
            success: r.success_rate,
            mean_reward: r.mean_reward,
            confirmed: r.confirmed_success_rate.zip(r.confirmed_mean_reward),
        })
        .collect())
}

/// The best evaluation by score: highest success rate, then highest mean
/// reward (the earliest of equals, as the evaluator keeps it).
fn best_of(evals: &[EvalPoint], confirming: bool) -> Option<EvalPoint> {
    evals
        .iter()
        .copied()
        .filter(|e| e.score(confirming).is_some())
        .reduce(|a, b| if b.score(confirming) > a.score(confirming) { b } else { a })
}

/// How far below the best confirmed success a screening may fall and still
/// be confirmed: about two standard errors of a 100-episode screening near
/// 90 %, so that a better policy that screened unluckily is not passed over.
const CANDIDATE_SLACK: f64 = 0.06;

/// The run's clocks as the evaluator reads them: its start, and the
/// agent-steps the supervisor last counted.
struct Clocks {
    start: Instant,
    steps: Arc<AtomicU64>,
}

/// When the evaluator flies next: every `eval.every_s` seconds, every
/// `eval.every_env_steps` agent-steps, or both (a clock whose setting is 0
/// is not used).
struct Cadence {
    every: Option<Duration>,
    next: Option<Instant>,
    every_steps: Option<u64>,
    next_steps: Option<u64>,
}

impl Cadence {
    fn new(cfg: &Config) -> Self {
        let every = (cfg.eval.every_s > 0.0).then(|| Duration::from_secs_f64(cfg.eval.every_s));
        let every_steps = (cfg.eval.every_env_steps > 0).then_some(cfg.eval.every_env_steps);
        Self {
            every,
            next: every.map(|e| Instant::now() + e),
            every_steps,
            next_steps: every_steps,
        }
    }

    /// Whether either clock has come round, at `steps` agent-steps.
    fn due(&self, steps: u64) -> bool {
        self.next.is_some_and(|t| Instant::now() >= t)
            || self.next_steps.is_some_and(|s| steps >= s)
    }

    /// No new weights to fly: the wall clock tries again in half a
    /// second (the agent-step clock stays due).
    fn retry_soon(&mut self) {
        self.next = self.every.map(|_| Instant::now() + Duration::from_millis(500));
    }

    /// An evaluation was flown at `steps` agent-steps.
    fn flown(&mut self, steps: u64) {
        self.next = self.every.map(|e| Instant::now() + e);
        if let (Some(e), Some(s)) = (self.every_steps, self.next_steps)
            && steps >= s
        {
            // The next multiple of the cadence past the steps now.
            self.next_steps = Some((steps / e + 1).saturating_mul(e));
        }
    }
}

/// What the evaluator thread is given: the run, its clocks, the stop flag,
/// the channel that asks for an evaluation now and the one that reports
/// them, and a resumed run's best score.
struct Job {
    prefix: String,
    cfg: Config,
    run_dir: PathBuf,
    clocks: Clocks,
    stop: Arc<AtomicBool>,
    now: mpsc::Receiver<()>,
    out: mpsc::Sender<EvalPoint>,
    resumed: bool,
    prior_best: Option<(f64, f64)>,
}

/// Flies the newest published weights greedily every `eval.every_s` seconds,
/// every `eval.every_env_steps` agent-steps (or when asked through `now`),
/// on its own iceoryx2 node, and keeps the best weights as
/// `checkpoints/best.safetensors`. Every evaluation uses the same spawn
/// positions, so they compare.
fn fly<S: Service>(job: Job) -> Result<()> {
    let cfg = &job.cfg;
    let hub = Hub::<S>::new(&job.prefix, "eval")?;
    let mut rx = hub.receiver::<f32, WeightsHeader>(&Channel::weights(cfg.sim.envs))?;
    let net = rotorhive_roles::evaluation::network_for(cfg)?;
    let mut judge = Judge { arenas: cfg.eval_arenas()?, confirmations: 0 };
    let mut cadence = Cadence::new(cfg);
    // A resumed run goes on from its best score (so `best.safetensors` only
    // ever improves) and appends to its table.
    let mut best: Option<(f64, f64)> = job.prior_best;
    let mut csv = open_table(&job.run_dir.join("evals.csv"), job.resumed)?;
    let ckpt_dir = job.run_dir.join("checkpoints");
    std::fs::create_dir_all(&ckpt_dir)?;
    while !job.stop.load(Ordering::Relaxed) {
        let asked = job.now.try_recv().is_ok();
        let steps = job.clocks.steps.load(Ordering::Relaxed);
        if !asked && !cadence.due(steps) {
            std::thread::sleep(Duration::from_millis(50));
            continue;
        }
        let Some(m) = rx.latest().context("reading weights to evaluate")? else {
            // Nothing new since the last evaluation: look again soon.
            cadence.retry_soon();
            std::thread::sleep(Duration::from_millis(50));
            continue;
        };
        let h = *m.user_header();
        net.load_flat(m.payload()).context("loading weights to evaluate")?;
        drop(m);
        let (st, confirmed) = judge.fly(&net, cfg, best)?;
        let k = cfg.eval.confirm_episodes;
        let (success, mean_reward) = (st.success_rate(), st.mean_reward);
        let score = if k > 0 { confirmed } else { Some((success, mean_reward)) };
        let better = score.is_some_and(|s| best.is_none_or(|b| s > b));
        if better {
            best = score;
            // Atomically: `QNet::save_with` goes through `rotorhive_msg::durable`.
            net.save(&ckpt_dir.join("best.safetensors"), &cfg.checkpoint_tags())?;
        }
        let wall = job.clocks.start.elapsed().as_secs_f64();
        let env_steps = Some(steps);
        let point =
            EvalPoint { wall, updates: h.updates, env_steps, success, mean_reward, confirmed };
        csv.write_all(rows::line(&point.row(h.version, st.episodes, better, k))?.as_bytes())?;
        csv.flush()?;
        let _ = job.out.send(point);
        cadence.flown(steps);
    }
    Ok(())
}

/// `evals.csv`, appended to where a resumed run has one, else new with its
/// header.
fn open_table(path: &std::path::Path, resumed: bool) -> Result<std::fs::File> {
    let append = resumed && path.exists();
    let mut csv = std::fs::OpenOptions::new()
        .create(true)
        .append(append)
        .write(true)
        .truncate(!append)
        .open(path)?;
    if !append {
        writeln!(csv, "{}", rows::EVALS_HEADER)?;
    }
    Ok(csv)
}

/// The evaluation arenas and the confirmations flown so far.
struct Judge {
    arenas: Vec<rotorhive_sim::Arena>,
    confirmations: u64,
}

impl Judge {
    /// Screens `net` on the fixed spawns and, when that makes it a candidate
    /// against `best`, confirms it on fresh spawns: the screening and the
    /// confirmation's (success, mean reward).
    fn fly(
        &mut self,
        net: &PolicyNet,
        cfg: &Config,
        best: Option<(f64, f64)>,
    ) -> Result<(rotorhive_roles::evaluation::EvalStats, Option<(f64, f64)>)> {
        let seed = rotorhive_roles::streams::validation(cfg.seed);
        let (pilot, sim) = (rotorhive_roles::evaluation::Pilot::Net(net), cfg.sim_config());
        let st = rotorhive_roles::evaluation::fly(
            pilot,
            sim.clone(),
            &self.arenas,
            cfg.eval.episodes,
            seed,
        )?;
        let k = cfg.eval.confirm_episodes;
        if k == 0 || best.is_some_and(|b| st.success_rate() + CANDIDATE_SLACK < b.0) {
            return Ok((st, None));
        }
        // Fresh spawns for every confirmation.
        self.confirmations += 1;
        let seed = rotorhive_roles::streams::confirmation(cfg.seed, self.confirmations);
        let c = rotorhive_roles::evaluation::fly(pilot, sim, &self.arenas, k, seed)?;
        Ok((st, Some((c.success_rate(), c.mean_reward))))
    }
}

/// The evaluator thread of a run, and the evaluations it has reported.
pub(super) struct Evaluator {
    thread: Option<JoinHandle<Result<()>>>,
    stop: Arc<AtomicBool>,
    now: mpsc::Sender<()>,
    rx: mpsc::Receiver<EvalPoint>,
    /// Every evaluation reported so far.
    pub(super) evals: Vec<EvalPoint>,
    confirming: bool,
}

impl Evaluator {
    /// Starts evaluating every `eval.every_s` seconds and every
    /// `eval.every_env_steps` agent-steps (no thread when both are 0);
    /// `steps` is the run's agent-steps as the supervisor counts them.
    /// A resumed run reads its earlier evaluations back from `evals.csv`:
    /// they count for the result, and a new evaluation becomes
    /// `best.safetensors` only if it beats them.
    pub(super) fn start<S: Service>(
        cfg: &Config,
        prefix: &str,
        run_dir: &std::path::Path,
        (start, steps): (Instant, Arc<AtomicU64>),
        resumed: bool,
    ) -> Result<Self> {
        let stop = Arc::new(AtomicBool::new(false));
        let (now, now_rx) = mpsc::channel();
        let (tx, rx) = mpsc::channel();
        let confirming = cfg.eval.confirm_episodes > 0;
        let evals = if resumed { read_evals(&run_dir.join("evals.csv"))? } else { Vec::new() };
        let prior_best = best_of(&evals, confirming).and_then(|b| b.score(confirming));
        let mut thread = None;
        if cfg.eval.every_s > 0.0 || cfg.eval.every_env_steps > 0 {
            let job = Job {
                prefix: prefix.to_string(),
                cfg: cfg.clone(),
                run_dir: run_dir.to_path_buf(),
                clocks: Clocks { start, steps },
                stop: stop.clone(),
                now: now_rx,
                out: tx,
                resumed,
                prior_best,
            };
            let spawn = std::thread::Builder::new().name("eval".into());
            thread = Some(spawn.spawn(move || fly::<S>(job))?);
        }
        Ok(Self { thread, stop, now, rx, evals, confirming })
    }

    /// Whether evaluations are made at all.
    pub(super) fn on(&self) -> bool {
        self.thread.is_some()
    }

    /// Asks for an evaluation now (the rolling reward crossed the threshold).
    pub(super) fn ask_now(&self) {
        let _ = self.now.send(());
    }

    /// Takes the evaluations reported since the last call.
    pub(super) fn poll(&mut self) {
        self.evals.extend(self.rx.try_iter());
    }

    /// Evaluations so far.
    pub(super) fn count(&self) -> usize {
        self.evals.len()
    }

    /// The best evaluation so far: the run's result.
    pub(super) fn best(&self) -> Option<EvalPoint> {
        best_of(&self.evals, self.confirming)
    }

    /// The result's score (confirmed where confirmations are made).
    pub(super) fn best_score(&self) -> Option<(f64, f64)> {
        self.best().and_then(|b| b.score(self.confirming))
    }

    /// The first screening that reached `target` success.
    pub(super) fn first_at(&self, target: f64) -> Option<EvalPoint> {
        self.evals.iter().find(|e| e.success >= target).copied()
    }

    /// Whether the thread ended before it was asked to (an error).
    pub(super) fn died(&self) -> bool {
        self.thread.as_ref().is_some_and(|h| h.is_finished())
    }

    /// Stops the thread; its error, if it had one.
    pub(super) fn stop(&mut self) -> Option<String> {
        self.stop.store(true, Ordering::Relaxed);
        let err = match self.thread.take().map(|h| h.join()) {
            None | Some(Ok(Ok(()))) => None,
            Some(Ok(Err(e))) => Some(format!("{e:#}")),
            Some(Err(_)) => Some("the evaluator panicked".into()),
        };
        self.poll();
        err
    }
}
