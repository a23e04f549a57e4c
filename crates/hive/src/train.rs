//! `hive train`: the main job. Validates the config, creates the run
//! directory, spawns every role as a child process of this binary, watches
//! episodes and telemetry over shared memory, samples CPU and memory, shows
//! progress, stops at the reward threshold or the time budget (or Ctrl-C),
//! stops the children and writes `summary.json`, `metrics.csv`,
//! `telemetry.csv` and `reward.png`.

use std::collections::{BTreeMap, VecDeque};
use std::fs::File;
use std::io::Write;
use std::path::PathBuf;
use std::process::{Child, Command, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use clap::Args;
use iceoryx2::service::Service;
use indicatif::{ProgressBar, ProgressStyle};
use rotorhive_model::{Device, QNet};
use rotorhive_msg::{RoleKind, Telemetry, WeightsHeader};
use rotorhive_transport::{Channel, Hub, Ipc, Local, cleanup_dead_nodes, services_of_run};
use serde_json::json;
use sysinfo::{Pid, ProcessesToUpdate, System};

use crate::ConfigArgs;
use rotorhive_msg::EpisodeHeader;
use rotorhive_roles::{Config, episodes_channel, roles_of};

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
    /// Continue a stopped run in RUN_DIR: its config (plus any --set), the
    /// learner's saved state and the replay memory's snapshot.
    #[arg(long, value_name = "RUN_DIR", conflicts_with = "run_dir")]
    pub resume: Option<PathBuf>,
    /// Head of a run across hosts: listen for workers (`hive worker
    /// --connect`) on this endpoint, e.g. tcp/0.0.0.0:7447; `[cluster]
    /// workers` says how many the run waits for.
    #[arg(long, value_name = "tcp/ADDR:PORT")]
    pub listen: Option<String>,
}

struct Role {
    name: String,
    args: Vec<String>,
    child: Child,
    /// When this role was restarted, for the give-up rule.
    restarts: VecDeque<Instant>,
}

/// How a role process is started (again).
struct Launcher {
    exe: PathBuf,
    cfg_path: PathBuf,
    prefix: String,
    run_dir: PathBuf,
    logs: PathBuf,
}

impl Launcher {
    fn spawn(&self, name: &str, args: &[String], append: bool) -> Result<Child> {
        use std::os::unix::process::CommandExt;
        let path = self.logs.join(format!("{name}.log"));
        // A role that keeps restarting keeps its log bounded: past
        // MAX_LOG_BYTES the log moves to `.log.1` (one old log kept).
        if append && std::fs::metadata(&path).is_ok_and(|m| m.len() > MAX_LOG_BYTES) {
            let _ = std::fs::rename(&path, path.with_extension("log.1"));
        }
        let supervisor = std::process::id();
        let mut cmd = Command::new(&self.exe);
        // Roles get a process group of their own, so a terminal's SIGINT and
        // SIGHUP reach the supervisor alone, which stops them in order; and
        // they die with the supervisor however it dies (PR_SET_PDEATHSIG,
        // plus the supervisor watch of every role).
        cmd.process_group(0).env(crate::role_cmd::SUPERVISOR_PID_ENV, supervisor.to_string());
        // SAFETY: prctl(2), getppid(2) and raise(3) are async-signal-safe, as
        // a pre_exec hook needs; nothing is allocated.
        unsafe {
            cmd.pre_exec(move || {
                if libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGTERM) != 0 {
                    return Err(std::io::Error::last_os_error());
                }
                // The supervisor may have died before the prctl took effect.
                if libc::getppid() as u32 != supervisor {
                    libc::raise(libc::SIGTERM);
                }
                Ok(())
            });
        }
        let log = std::fs::OpenOptions::new()
            .create(true)
            .append(append)
            .write(true)
            .truncate(!append)
            .open(&path)
            .with_context(|| format!("cannot open {}", path.display()))?;
        cmd.args(args)
            .arg(&self.cfg_path)
            .args(["--prefix", &self.prefix, "--run-dir"])
            .arg(&self.run_dir)
            // Roles size their own parallelism from the config (learner and
            // actor threads, render threads); candle's pools stay
            // single-threaded (idle spinning workers would steal the cores
            // the other roles need).
            .env("RAYON_NUM_THREADS", "1")
            .env("CANDLE_NUM_THREADS", "1")
            .stdin(Stdio::null())
            .stdout(log.try_clone()?)
            .stderr(log)
            .spawn()
            .with_context(|| format!("cannot start role {name}"))
    }
}

/// Size past which a role's log is moved aside when the role restarts.
const MAX_LOG_BYTES: u64 = 16 << 20;

/// A role that dies more often than this within `RESTART_WINDOW` stops the run.
const MAX_RESTARTS: usize = 3;
const RESTART_WINDOW: Duration = Duration::from_secs(60);

/// The children of a run; stopping them is also done on drop, so an early
/// error never leaves processes (or their shared memory) behind.
struct Children {
    roles: Vec<Role>,
}

impl Children {
    fn stop(&mut self) {
        for r in &self.roles {
            // SAFETY: plain kill(2) on our own child's pid.
            unsafe { libc::kill(r.child.id() as i32, libc::SIGTERM) };
        }
        let deadline = Instant::now() + Duration::from_secs(10);
        for r in &mut self.roles {
            loop {
                match r.child.try_wait() {
                    Ok(Some(_)) => break,
                    Ok(None) if Instant::now() < deadline => std::thread::sleep(Duration::from_millis(20)),
                    _ => {
                        let _ = r.child.kill();
                        let _ = r.child.wait();
                        break;
                    }
                }
            }
        }
        self.roles.clear();
        cleanup_dead_nodes();
    }
}

impl Drop for Children {
    fn drop(&mut self) {
        self.stop();
    }
}

fn timestamp() -> String {
    let secs = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.as_secs()).unwrap_or(0);
    // UTC date and time without pulling in a calendar crate.
    let (d, s) = (secs / 86_400, secs % 86_400);
    let (y, m, dd) = civil_from_days(d as i64);
    format!("{y:04}{m:02}{dd:02}-{:02}{:02}{:02}", s / 3600, (s / 60) % 60, s % 60)
}

/// Days since 1970-01-01 to a civil date (Howard Hinnant's algorithm).
fn civil_from_days(z: i64) -> (i64, u32, u32) {
    let z = z + 719_468;
    let era = z.div_euclid(146_097);
    let doe = z.rem_euclid(146_097);
    let yoe = (doe - doe / 1460 + doe / 36_524 - doe / 146_096) / 365;
    let doy = doe - (365 * yoe + yoe / 4 - yoe / 100);
    let mp = (5 * doy + 2) / 153;
    let d = (doy - (153 * mp + 2) / 5 + 1) as u32;
    let m = if mp < 10 { mp + 3 } else { mp - 9 } as u32;
    (yoe + era * 400 + (m <= 2) as i64, m, d)
}

/// The run directory's lock: one owner per run directory. `flock` on
/// `RUN_DIR/run.lock`, held for the life of the run and released by the
/// kernel when its holder dies, so a crashed run never blocks its own
/// `--resume`. The file holds the owner's process id for the refusal message.
fn lock_run_dir(dir: &std::path::Path) -> Result<File> {
    let path = dir.join("run.lock");
    let mut f = std::fs::OpenOptions::new()
        .read(true)
        .write(true)
        .create(true)
        .truncate(false)
        .open(&path)
        .with_context(|| format!("cannot open {}", path.display()))?;
    match f.try_lock() {
        Ok(()) => {
            f.set_len(0).and_then(|_| writeln!(f, "{}", std::process::id())).with_context(|| format!("cannot write {}", path.display()))?;
            Ok(f)
        }
        Err(std::fs::TryLockError::WouldBlock) => {
            let holder = std::fs::read_to_string(&path).unwrap_or_default();
            let holder = holder.trim();
            bail!(
                "run directory {} is in use by another hive train (process {}); wait for it to end or stop it first (it is left untouched)",
                dir.display(),
                if holder.is_empty() { "unknown" } else { holder }
            )
        }
        Err(std::fs::TryLockError::Error(e)) => Err(e).with_context(|| format!("cannot lock {}", path.display())),
    }
}

/// A CSV table of the run directory; a failed write (a full disk, a
/// directory gone) names the file. Past `TABLE_CAP` bytes it moves to
/// `NAME.1` (replacing an older one) and starts afresh with its header, so
/// a run of any length keeps at most twice the cap per table on disk.
struct Table {
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
    fn open(dir: &std::path::Path, name: &str, header: &str, append: bool) -> Result<Self> {
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
    fn write_fmt(&mut self, line: std::fmt::Arguments) -> Result<()> {
        if self.written > self.cap {
            self.rotate()?;
        }
        let row = line.to_string();
        self.written += row.len() as u64;
        self.file.write_all(row.as_bytes()).with_context(|| format!("cannot write {}", self.path.display()))
    }

    fn rotate(&mut self) -> Result<()> {
        let old = self.path.with_extension("csv.1");
        std::fs::rename(&self.path, &old).with_context(|| format!("cannot move {} to {}", self.path.display(), old.display()))?;
        self.file = File::create(&self.path).with_context(|| format!("cannot write {}", self.path.display()))?;
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
struct Series {
    points: Vec<(f64, f64)>,
    stride: usize,
    seen: usize,
}

impl Series {
    fn push(&mut self, p: (f64, f64)) {
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
struct Mean {
    sum: f64,
    n: u64,
    max: f64,
}

impl Mean {
    fn add(&mut self, v: f64) {
        self.sum += v;
        self.n += 1;
        self.max = if self.n == 1 { v } else { self.max.max(v) };
    }

    fn mean(&self) -> Option<f64> {
        (self.n > 0).then(|| self.sum / self.n as f64)
    }
}

/// Prints a line to stdout; a closed terminal (SIGHUP) makes this fail, which
/// must not stop the run from writing its records.
fn say(line: &str) {
    let _ = writeln!(std::io::stdout(), "{line}");
}

/// The last line of a role's log that reports an error, for the message
/// that tells why the role died.
fn last_error(log: &std::path::Path) -> Option<String> {
    let text = std::fs::read_to_string(log).ok()?;
    text.lines().rev().find(|l| l.contains("error")).map(|l| l.trim().to_string())
}

/// One greedy evaluation during training.
#[derive(Debug, Clone, Copy)]
struct EvalPoint {
    wall: f64,
    updates: u64,
    success: f64,
    mean_reward: f64,
}

/// The role's gauge of a telemetry sample in its own unit: the learner's
/// mean loss over the updates since its previous sample, the actor's
/// epsilon, the replay's size; empty for sims.
fn gauge(t: &Telemetry) -> String {
    match RoleKind::from_code(t.role) {
        Some(RoleKind::Learner) => format!("{:.6}", t.value_milli as f64 / 1e6),
        Some(RoleKind::Actor) => format!("{:.3}", t.value_milli as f64 / 1e3),
        Some(RoleKind::Replay) => t.value_milli.to_string(),
        _ => String::new(),
    }
}

/// The best evaluation: highest success rate, then highest mean reward (the
/// earliest of equals, as the evaluator keeps it).
fn best_of(evals: &[EvalPoint]) -> Option<EvalPoint> {
    evals.iter().copied().reduce(|a, b| if (b.success, b.mean_reward) > (a.success, a.mean_reward) { b } else { a })
}

/// Flies the newest published weights greedily every `eval.every_s` seconds
/// (or when asked through `now`), on its own iceoryx2 node, and keeps the
/// best weights as `checkpoints/best.safetensors`. Every evaluation uses the
/// same spawn positions, so they compare.
fn evaluator<S: Service>(
    prefix: String,
    cfg: Config,
    run_dir: PathBuf,
    start: Instant,
    stop: Arc<AtomicBool>,
    now: mpsc::Receiver<()>,
    out: mpsc::Sender<EvalPoint>,
) -> Result<()> {
    let hub = Hub::<S>::new(&prefix, "eval")?;
    let mut rx = hub.receiver::<f32, WeightsHeader>(&Channel::weights(cfg.sim.envs))?;
    let mut net = QNet::new(0, &Device::Cpu)?;
    net.set_threads(1);
    let arenas = cfg.eval_arenas()?;
    let every = Duration::from_secs_f64(cfg.eval.every_s);
    let mut next = Instant::now() + every;
    let mut best: Option<(f64, f64)> = None;
    let mut csv = File::create(run_dir.join("evals.csv"))?;
    writeln!(csv, "wall_s,updates,version,episodes,success_rate,mean_reward,best")?;
    let ckpt_dir = run_dir.join("checkpoints");
    std::fs::create_dir_all(&ckpt_dir)?;
    while !stop.load(Ordering::Relaxed) {
        let asked = now.try_recv().is_ok();
        if !asked && Instant::now() < next {
            std::thread::sleep(Duration::from_millis(50));
            continue;
        }
        let Some(m) = rx.latest().context("reading weights to evaluate")? else {
            // Nothing new since the last evaluation.
            next = Instant::now() + Duration::from_millis(500);
            continue;
        };
        let h = *m.user_header();
        net.load_flat(m.payload()).context("loading weights to evaluate")?;
        drop(m);
        let st = crate::eval::fly_greedy(&net, cfg.sim_config(), &arenas, cfg.eval.episodes, cfg.seed.wrapping_add(7777))?;
        let (success, mean_reward) = (st.success_rate(), st.mean_reward);
        let better = best.is_none_or(|b| (success, mean_reward) > b);
        if better {
            best = Some((success, mean_reward));
            let path = ckpt_dir.join("best.safetensors");
            let tmp = ckpt_dir.join("best.safetensors.tmp");
            net.save(&tmp)?;
            std::fs::rename(&tmp, &path).with_context(|| format!("cannot write {}", path.display()))?;
        }
        let wall = start.elapsed().as_secs_f64();
        writeln!(csv, "{wall:.3},{},{},{},{success:.4},{mean_reward:.2},{}", h.updates, h.version, st.episodes, better as u8)?;
        let _ = out.send(EvalPoint { wall, updates: h.updates, success, mean_reward });
        next = Instant::now() + every;
    }
    Ok(())
}

pub fn run(a: TrainArgs) -> Result<()> {
    let mut cfg = match &a.resume {
        Some(dir) => {
            if a.cfg.config.is_some() {
                bail!("--resume takes the config of the run it continues; drop the CONFIG argument (use --set to change keys)");
            }
            let state = dir.join("checkpoints/learner-state.safetensors");
            if !state.exists() {
                bail!("--resume {}: no learner state ({}) to continue from", dir.display(), state.display());
            }
            Config::load(Some(&dir.join("config.toml")), &a.cfg.set).with_context(|| format!("--resume {}", dir.display()))?
        }
        None => Config::load(a.cfg.config.as_deref(), &a.cfg.set)?,
    };
    if let Some(s) = a.max_seconds {
        if !(s.is_finite() && s > 0.0) {
            bail!("--max-seconds must be positive, got {s}");
        }
        cfg.max_seconds = s;
    }
    // Fail on a bad arena before anything starts.
    cfg.arena()?;
    let run_dir = a.resume.clone().or_else(|| a.run_dir.clone()).unwrap_or_else(|| PathBuf::from("runs").join(timestamp()));
    std::fs::create_dir_all(&run_dir).with_context(|| format!("cannot create run directory {}", run_dir.display()))?;
    let run_dir = run_dir.canonicalize()?;
    // Nothing of the run directory is written before its lock is held.
    let _lock = lock_run_dir(&run_dir)?;
    // Roles read the arena relative to their working directory: resolve it now.
    cfg.sim.arena = cfg.sim.arena.canonicalize().with_context(|| format!("arena {}", cfg.sim.arena.display()))?;
    if !cfg.eval.arena.is_empty() {
        cfg.eval.arena =
            std::path::Path::new(&cfg.eval.arena).canonicalize().with_context(|| format!("key `eval.arena`: {}", cfg.eval.arena))?.display().to_string();
        cfg.eval_arenas()?;
    }
    let nanos = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map(|d| d.subsec_nanos()).unwrap_or(0);
    let prefix = format!("run-{}-{nanos:x}", std::process::id());
    rotorhive_transport::handle_hangup();
    // The head's environments come first in the run.
    cfg.cluster.env_offset = 0;
    let link = match &a.listen {
        Some(ep) => Some(gather_workers(ep, &prefix, &mut cfg)?),
        None if cfg.cluster.workers > 0 => bail!("key `cluster.workers` = {} needs --listen tcp/ADDR:PORT for the workers to join", cfg.cluster.workers),
        None => {
            cfg.cluster.envs_elsewhere = 0;
            cfg.cluster.agents_elsewhere = 0;
            None
        }
    };
    let cfg_path = run_dir.join("config.toml");
    std::fs::write(&cfg_path, cfg.to_toml()).with_context(|| format!("cannot write {}", cfg_path.display()))?;
    let link = match link {
        Some(mut head) => {
            // The workers get the config every role of this run reads, and the arena.
            let text = (cfg.to_toml(), std::fs::read_to_string(&cfg.sim.arena).with_context(|| format!("arena {}", cfg.sim.arena.display()))?);
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
        // Candle's pools stay single-threaded, as in the role processes.
        // SAFETY: no thread of this process has started yet.
        unsafe {
            std::env::set_var("RAYON_NUM_THREADS", "1");
            std::env::set_var("CANDLE_NUM_THREADS", "1");
        }
        supervise::<Local>(&a, cfg, run_dir, cfg_path, prefix, link)
    } else {
        supervise::<Ipc>(&a, cfg, run_dir, cfg_path, prefix, link)
    }
}

/// `summary.json`'s `hosts`: this host, then every worker host, with the
/// agent-steps their sims reported and the transitions lost on the way.
fn hosts_summary(
    cfg: &Config,
    latest: &BTreeMap<(u32, u32), Telemetry>,
    link: Option<&(Arc<rotorhive_link::HeadStats>, Vec<rotorhive_link::Host>)>,
) -> serde_json::Value {
    let steps = |from: u32, to: u32| latest.values().filter(|t| t.role == RoleKind::Sim as u32 && (from..to).contains(&t.index)).map(|t| t.work).sum::<u64>();
    let lost_here = latest.values().filter(|t| t.role == RoleKind::Replay as u32).map(|t| t.lost).sum::<u64>();
    let envs = cfg.sim.envs as u32;
    let mut out = vec![json!({
        "name": host_name(), "role": "head", "envs": envs, "agents": cfg.sim.agents, "env_steps": steps(0, envs), "lost_transitions": lost_here,
    })];
    if let Some((stats, hosts)) = link {
        let lost = stats.lost_by_env.lock().map(|v| v.clone()).unwrap_or_default();
        for h in hosts {
            let (a, b) = (h.env_offset, h.env_offset + h.envs);
            out.push(json!({
                "name": h.name, "role": "worker", "envs": h.envs, "agents": h.agents, "env_steps": steps(a, b),
                "lost_transitions": lost.get(a as usize..b as usize).map_or(0, |l| l.iter().sum::<u64>()),
            }));
        }
    }
    serde_json::Value::Array(out)
}

/// This machine's name.
pub fn host_name() -> String {
    std::fs::read_to_string("/proc/sys/kernel/hostname").map(|s| s.trim().to_string()).ok().filter(|s| !s.is_empty()).unwrap_or_else(|| "localhost".into())
}

/// Listens on `ep` and waits for `cluster.workers` worker hosts; their
/// environments and agents go into `cfg.cluster`.
fn gather_workers(ep: &str, prefix: &str, cfg: &mut Config) -> Result<rotorhive_link::Head> {
    let mut head = rotorhive_link::Head::listen(ep, prefix, rotorhive_link::layout(rotorhive_model::num_params()))?;
    let wanted = cfg.cluster.workers;
    if wanted > 0 {
        say(&format!("listening on {ep}: waiting for {wanted} worker host(s), at most {:.0} s", cfg.cluster.join_timeout_s));
    }
    let timeout = Duration::from_secs_f64(cfg.cluster.join_timeout_s);
    let hosts = head.gather(wanted, cfg.sim.envs, cfg.sim.agents, timeout, rotorhive_transport::stop_requested)?;
    cfg.cluster.envs_elsewhere = hosts.iter().map(|h| h.envs as usize).sum();
    cfg.cluster.agents_elsewhere = hosts.iter().map(|h| (h.envs * h.agents) as usize).sum();
    for h in &hosts {
        say(&format!("worker {} joined: {} × {} agents (environments {}..{})", h.name, h.envs, h.agents, h.env_offset, h.env_offset + h.envs));
    }
    Ok(head)
}

/// The roles of a run: child processes (restarted when they die), or, in
/// serial mode, threads of this process.
enum Members {
    Processes { launcher: Launcher, children: Children },
    Threads { stop: Arc<AtomicBool>, threads: Vec<(String, std::thread::JoinHandle<Result<()>>)> },
}

impl Members {
    fn pids(&self) -> Vec<Pid> {
        match self {
            Members::Processes { children, .. } => children.roles.iter().map(|r| Pid::from_u32(r.child.id())).collect(),
            Members::Threads { .. } => vec![Pid::from_u32(std::process::id())],
        }
    }

    /// Stops every role; in serial mode returns the first role's error.
    fn stop(&mut self) -> Option<String> {
        match self {
            Members::Processes { children, .. } => {
                children.stop();
                None
            }
            Members::Threads { stop, threads } => {
                stop.store(true, Ordering::SeqCst);
                rotorhive_roles::join_threads(std::mem::take(threads))
            }
        }
    }
}

/// Supervises the run `prefix` over the iceoryx2 service `S` (`ipc` for role
/// processes, `local` for serial mode) until it ends, then writes its records.
fn supervise<S: Service>(
    a: &TrainArgs,
    cfg: Config,
    run_dir: PathBuf,
    cfg_path: PathBuf,
    prefix: String,
    link: Option<(rotorhive_link::Head, (String, String))>,
) -> Result<()> {
    let hub = Hub::<S>::new(&prefix, &rotorhive_transport::supervisor_node_name(&prefix))?;
    let envs = cfg.sim.envs;
    let mut ep_rx = hub.receiver::<f32, EpisodeHeader>(&episodes_channel(envs))?;
    let mut tel_rx = hub.receiver::<u8, Telemetry>(&Channel::telemetry(roles_of(&cfg)))?;

    let logs = run_dir.join("logs");
    std::fs::create_dir_all(&logs)?;
    let mut members = if a.serial {
        let stop = Arc::new(AtomicBool::new(false));
        Members::Threads { threads: rotorhive_roles::spawn_serial(&cfg, &prefix, &run_dir, &stop)?, stop }
    } else {
        let exe = std::env::current_exe().context("cannot find the hive executable")?;
        let launcher = Launcher { exe, cfg_path: cfg_path.clone(), prefix: prefix.clone(), run_dir: run_dir.clone(), logs: logs.clone() };
        let mut children = Children { roles: Vec::new() };
        for (name, role, index) in rotorhive_roles::role_names(&cfg) {
            let mut args = vec![role.name().to_string()];
            if matches!(role, RoleKind::Sim | RoleKind::Actor) {
                args.extend(["--env".to_string(), index.to_string()]);
            }
            let child = launcher.spawn(&name, &args, false)?;
            children.roles.push(Role { name, args, child, restarts: VecDeque::new() });
        }
        Members::Processes { launcher, children }
    };
    let mut restarts = 0u64;
    let mut link = match link {
        Some((head, text)) => {
            Some(head.bridge::<S>(prefix.clone(), envs, roles_of(&cfg), Arc::new(AtomicBool::new(false)), Box::new(move |_| text.clone()))?)
        }
        None => None,
    };

    // A resumed run appends to its tables (wall time starts again at 0).
    let resumed = a.resume.is_some();
    let mut metrics =
        Table::open(&run_dir, "metrics.csv", "kind,wall_s,env_steps,episodes,episode_reward,rolling_reward,epsilon,updates,replay_size", resumed)?;
    if resumed {
        writeln!(metrics, "resume,0,,,,,,,")?;
    }
    let mut telemetry = Table::open(
        &run_dir,
        "telemetry.csv",
        "wall_s,role,index,pid,cpu_pct,rss_mb,machine_cpu_pct,heartbeat,work,work2,weight_version,lost,stage0_ms,stage1_ms,stage2_ms,stage3_ms,gpu_util_pct,gpu_mem_mb,gpu_power_w,value",
        resumed,
    )?;

    let bar = if a.quiet { ProgressBar::hidden() } else { ProgressBar::new_spinner() };
    bar.set_style(ProgressStyle::with_template("{spinner} [{elapsed_precise}] {msg}").expect("valid template"));
    bar.enable_steady_tick(Duration::from_millis(200));

    let start = Instant::now();
    let window = cfg.rolling_window;
    let mut recent: VecDeque<f32> = VecDeque::with_capacity(window);
    let mut episodes = 0u64;
    let mut successes_recent: VecDeque<bool> = VecDeque::with_capacity(window);
    let mut curve = Series::default();
    let mut epsilon = cfg.actor.eps_start;
    let schedule = cfg.deterministic.then(|| rotorhive_roles::schedule::Schedule::new(&cfg));
    let mut order = EpisodeOrder::new(envs, cfg.deterministic);
    let mut latest: BTreeMap<(u32, u32), Telemetry> = BTreeMap::new();
    let mut sys = System::new().map_err(|e| anyhow::anyhow!("cannot read system statistics: {e}"))?;
    let mut cpu_mean = Mean::default();
    let gpu = crate::gpu_monitor::GpuMonitor::new();
    let (mut gpu_util, mut gpu_power, mut gpu_mem) = (Mean::default(), Mean::default(), Mean::default());
    let mut util_series: BTreeMap<String, Series> = BTreeMap::new();
    let mut peak_rss_mb = 0.0f64;
    let mut time_to_threshold: Option<f64> = None;
    let mut last_tick = Instant::now();
    let mut failure: Option<String> = None;
    let mut interrupted = false;
    let rolling = |r: &VecDeque<f32>| if r.is_empty() { f64::NAN } else { r.iter().map(|v| *v as f64).sum::<f64>() / r.len() as f64 };
    let sum_work = |latest: &BTreeMap<(u32, u32), Telemetry>, role: RoleKind| latest.values().filter(|t| t.role == role as u32).map(|t| t.work).sum::<u64>();
    let threshold = cfg.threshold;

    // Greedy evaluation beside training.
    let eval_on = cfg.eval.every_s > 0.0;
    let eval_stop = Arc::new(AtomicBool::new(false));
    let (eval_now, eval_now_rx) = mpsc::channel();
    let (eval_tx, eval_rx) = mpsc::channel();
    let mut evaluator_thread = None;
    if eval_on {
        let (p, c, d, st) = (prefix.clone(), cfg.clone(), run_dir.clone(), eval_stop.clone());
        evaluator_thread = Some(std::thread::Builder::new().name("eval".into()).spawn(move || evaluator::<S>(p, c, d, start, st, eval_now_rx, eval_tx))?);
    }
    let mut evals: Vec<EvalPoint> = Vec::new();

    // Any error of the loop (a table that cannot be written, a role that
    // cannot be started again) stops the run as a failure: the roles are
    // stopped and the records written all the same.
    let mut supervise = || -> Result<()> {
        loop {
            if hub.shutdown_requested() {
                interrupted = true;
                break;
            }
            // Episodes from every actor; a deterministic run's in (step,
            // environment) order, with its schedule's counts.
            while let Some(m) = ep_rx.try_recv()? {
                order.push(*m.user_header(), m.payload());
            }
            for (h, payload) in order.ready() {
                epsilon = h.epsilon_micro as f64 / 1e6;
                let (env_steps, updates, replay_size) = match &schedule {
                    Some(s) => {
                        let steps = h.step * cfg.agents_total() as u64;
                        (steps, s.minibatches_after(h.step), steps.min(cfg.replay.capacity as u64) as i64)
                    }
                    None => (
                        sum_work(&latest, RoleKind::Sim),
                        sum_work(&latest, RoleKind::Learner),
                        latest.get(&(RoleKind::Replay as u32, 0)).map(|t| t.value_milli).unwrap_or(0),
                    ),
                };
                for e in payload.chunks_exact(3) {
                    episodes += 1;
                    if recent.len() == window {
                        recent.pop_front();
                        successes_recent.pop_front();
                    }
                    recent.push_back(e[0]);
                    successes_recent.push_back(e[2] == rotorhive_msg::DoneKind::Goal as u8 as f32);
                    let wall = start.elapsed().as_secs_f64();
                    let roll = rolling(&recent);
                    writeln!(metrics, "episode,{wall:.3},{env_steps},{episodes},{},{roll:.3},{epsilon:.4},{updates},{replay_size}", e[0])?;
                    if recent.len() == window && roll >= threshold && time_to_threshold.is_none() {
                        time_to_threshold = Some(wall);
                        let _ = eval_now.send(());
                    }
                }
            }
            evals.extend(eval_rx.try_iter());
            let best_eval = best_of(&evals);
            while let Some(m) = tel_rx.try_recv()? {
                let t = *m.user_header();
                latest.insert((t.role, t.index), t);
            }
            if let Some(s) = &schedule {
                // A deterministic run ends when its schedule is done: every
                // round reported and the learner through its last update.
                if order.through() >= s.rounds() && sum_work(&latest, RoleKind::Learner) >= s.total_updates() {
                    break;
                }
            } else if cfg.max_env_steps > 0 && sum_work(&latest, RoleKind::Sim) >= cfg.max_env_steps {
                break;
            } else if let Some(t) = time_to_threshold {
                // Without evaluation the run ends at the threshold; with it,
                // training goes on until a greedy evaluation (at any time of the
                // run: the best is the result) is good enough.
                let good = best_eval.is_some_and(|b| b.success >= cfg.eval.target_success);
                if !eval_on || good || start.elapsed().as_secs_f64() - t >= cfg.eval.after_threshold_s {
                    break;
                }
            }
            if let Some(h) = &evaluator_thread
                && h.is_finished()
            {
                failure = Some("the evaluator stopped; see the error below".into());
                break;
            }
            if link.as_ref().is_some_and(|l| l.is_finished()) {
                failure = Some(match link.take().map(|mut l| l.stop()) {
                    Some(Err(e)) => format!("the link to the worker hosts stopped: {e}"),
                    _ => "the link to the worker hosts stopped".into(),
                });
                break;
            }
            // Supervision: a role that dies is cleaned up after and restarted
            // (the learner from its last saved state); one that keeps dying
            // stops the run.
            match &mut members {
                Members::Threads { threads, .. } => {
                    // A role thread ends only with an error (or a stop).
                    if let Some((name, _)) = threads.iter().find(|(_, h)| h.is_finished()) {
                        failure = Some(format!("role {name} stopped"));
                    }
                }
                Members::Processes { launcher, children } => {
                    for r in &mut children.roles {
                        let Some(status) = r.child.try_wait()? else { continue };
                        if hub.shutdown_requested() {
                            break;
                        }
                        let log = logs.join(format!("{}.log", r.name));
                        let now = Instant::now();
                        while r.restarts.front().is_some_and(|t| now.duration_since(*t) > RESTART_WINDOW) {
                            r.restarts.pop_front();
                        }
                        if r.restarts.len() >= MAX_RESTARTS {
                            let why = last_error(&log).map_or(String::new(), |e| format!(": {e}"));
                            failure = Some(format!(
                                "role {} died {} times within {} s (last: {status}{why}); giving up; see {}",
                                r.name,
                                r.restarts.len() + 1,
                                RESTART_WINDOW.as_secs(),
                                log.display()
                            ));
                            break;
                        }
                        let cleaned = cleanup_dead_nodes();
                        let wall = start.elapsed().as_secs_f64();
                        bar.println(format!("[{wall:.1} s] role {} exited ({status}); cleaned {cleaned} dead node(s), restarting", r.name));
                        tracing::warn!("role {} exited ({status}); restarting", r.name);
                        r.child = launcher.spawn(&r.name, &r.args, true)?;
                        r.restarts.push_back(now);
                        restarts += 1;
                        writeln!(metrics, "restart,{wall:.3},,,,,,,")?;
                    }
                }
            }
            if failure.is_some() {
                break;
            }
            let wall = start.elapsed().as_secs_f64();
            if wall >= cfg.max_seconds {
                break;
            }
            if last_tick.elapsed() >= Duration::from_secs(1) {
                last_tick = Instant::now();
                let mut pids = members.pids();
                // The link runs in this process: its telemetry carries this pid.
                pids.push(Pid::from_u32(std::process::id()));
                sys.refresh_cpu_usage();
                sys.refresh_processes(ProcessesToUpdate::Some(&pids), true);
                let machine = sys.global_cpu_usage() as f64;
                cpu_mean.add(machine);
                let g = gpu.read();
                if let Some(g) = g {
                    gpu_util.add(g.util_pct);
                    gpu_power.add(g.power_w);
                    gpu_mem.add(g.mem_mb);
                    util_series.entry("GPU".into()).or_default().push((wall, g.util_pct));
                }
                let gcols = g.map_or(",,".to_string(), |g| format!("{:.1},{:.1},{:.1}", g.util_pct, g.mem_mb, g.power_w));
                util_series.entry("machine CPU".into()).or_default().push((wall, machine));
                let mut rss_total = 0.0;
                for t in latest.values() {
                    let p = sys.process(Pid::from_u32(t.pid));
                    let (cpu, rss) = p.map(|p| (p.cpu_usage() as f64, p.memory() as f64 / 1e6)).unwrap_or((f64::NAN, f64::NAN));
                    if rss.is_finite() {
                        rss_total += rss;
                    }
                    let role = RoleKind::from_code(t.role).map(|r| r.name()).unwrap_or("?");
                    let ms = |i: usize| t.stage_ns[i] as f64 / 1e6;
                    writeln!(
                        telemetry,
                        "{wall:.3},{role},{},{},{cpu:.1},{rss:.1},{machine:.1},{},{},{},{},{},{:.1},{:.1},{:.1},{:.1},{gcols},{}",
                        t.index,
                        t.pid,
                        t.heartbeat,
                        t.work,
                        t.work2,
                        t.weight_version,
                        t.lost,
                        ms(0),
                        ms(1),
                        ms(2),
                        ms(3),
                        gauge(t)
                    )?;
                    if cpu.is_finite() {
                        // Per-process CPU is in % of one core; the plot shows % of the machine.
                        let cores = sys.cpus().len().max(1) as f64;
                        util_series.entry(format!("{role}-{}", t.index)).or_default().push((wall, cpu / cores));
                    }
                }
                // This process's own row (the monitor, the evaluator and, on
                // a head, the link): in serial mode every role is a thread of
                // it, so its CPU is the run's and the row is left out.
                if let (Members::Processes { .. }, Some(p)) = (&members, sys.process(Pid::from_u32(std::process::id()))) {
                    let (cpu, rss) = (p.cpu_usage() as f64, p.memory() as f64 / 1e6);
                    rss_total += rss;
                    writeln!(telemetry, "{wall:.3},supervisor,0,{},{cpu:.1},{rss:.1},{machine:.1},0,0,0,0,0,0.0,0.0,0.0,0.0,{gcols},", std::process::id())?;
                    let cores = sys.cpus().len().max(1) as f64;
                    util_series.entry("supervisor".into()).or_default().push((wall, cpu / cores));
                }
                peak_rss_mb = peak_rss_mb.max(rss_total);
                let roll = rolling(&recent);
                curve.push((wall, roll));
                writeln!(
                    metrics,
                    "tick,{wall:.3},{},{episodes},,{roll:.3},{epsilon:.4},{},{}",
                    sum_work(&latest, RoleKind::Sim),
                    sum_work(&latest, RoleKind::Learner),
                    latest.get(&(RoleKind::Replay as u32, 0)).map(|t| t.value_milli).unwrap_or(0)
                )?;
                let steps = sum_work(&latest, RoleKind::Sim);
                let updates = sum_work(&latest, RoleKind::Learner);
                // Across hosts: each host's share of the agent-steps.
                let hosts = link.as_ref().map_or(String::new(), |l| {
                    let of = |from: u32, to: u32| {
                        latest.values().filter(|t| t.role == RoleKind::Sim as u32 && (from..to).contains(&t.index)).map(|t| t.work).sum::<u64>()
                    };
                    let mut parts = vec![format!("here {}", of(0, envs as u32))];
                    parts.extend(l.hosts.iter().map(|h| format!("{} {}", h.name, of(h.env_offset, h.env_offset + h.envs))));
                    format!(" | hosts: {}", parts.join(", "))
                });
                bar.set_message(format!(
                    "steps {steps} ({:.0}/s){hosts} | episodes {episodes} | rolling reward {roll:.1} | eps {epsilon:.3} | updates {updates} ({:.1}/s) | best eval {} | cpu {machine:.0}%{}",
                    steps as f64 / wall.max(1e-9),
                    updates as f64 / wall.max(1e-9),
                    best_eval.map_or("-".to_string(), |b| format!("{:.0}%", b.success * 100.0)),
                    g.map_or(String::new(), |g| format!(" | gpu {:.0}% {:.0} W", g.util_pct, g.power_w)),
                ));
            }
            std::thread::sleep(Duration::from_millis(20));
        }
        Ok(())
    };
    if let Err(e) = supervise() {
        failure = Some(format!("{e:#}"));
    }
    let wall = start.elapsed().as_secs_f64();
    bar.finish_and_clear();
    // Last counters before the children go.
    while let Some(m) = tel_rx.try_recv()? {
        let t = *m.user_header();
        latest.insert((t.role, t.index), t);
    }
    eval_stop.store(true, Ordering::Relaxed);
    let mut eval_error = None;
    if let Some(h) = evaluator_thread {
        match h.join() {
            Ok(Ok(())) => {}
            Ok(Err(e)) => eval_error = Some(format!("{e:#}")),
            Err(_) => eval_error = Some("the evaluator panicked".into()),
        }
    }
    if let Some(e) = eval_error {
        failure = Some(format!("evaluation failed: {e}"));
    }
    evals.extend(eval_rx.try_iter());
    let best_eval = best_of(&evals);
    // The workers end with the run: tell them before the roles go.
    let link_stats = link.as_ref().map(|l| (l.stats.clone(), l.hosts.clone()));
    if let Some(Err(e)) = link.take().map(|mut l| l.stop())
        && failure.is_none()
    {
        failure = Some(format!("link: {e}"));
    }
    if let Some(e) = members.stop() {
        failure = Some(match failure {
            Some(f) => format!("{f}: {e}"),
            None => e,
        });
    }
    drop(ep_rx);
    drop(tel_rx);
    drop(hub);
    let leftover = services_of_run::<S>(&prefix);

    let env_steps = sum_work(&latest, RoleKind::Sim);
    let updates = sum_work(&latest, RoleKind::Learner);
    let hosts = hosts_summary(&cfg, &latest, link_stats.as_ref());
    let final_ckpt = run_dir.join("final.safetensors");
    let last_checkpoint = if final_ckpt.exists() { Some(final_ckpt) } else { Some(run_dir.join("checkpoints/latest.safetensors")).filter(|p| p.exists()) };
    // The run's result is the best greedy policy seen, else the last weights.
    let best_ckpt = run_dir.join("checkpoints/best.safetensors");
    let checkpoint = if best_ckpt.exists() { Some(best_ckpt) } else { last_checkpoint.clone() };
    let roll = rolling(&recent);
    let summary = json!({
        "converged": time_to_threshold.is_some(),
        "threshold": threshold,
        "time_to_threshold_s": time_to_threshold,
        "wall_s": wall,
        "env_steps": env_steps,
        "episodes": episodes,
        "rolling_reward": if roll.is_finite() { Some(roll) } else { None },
        "rolling_success_rate": if successes_recent.is_empty() { None } else { Some(successes_recent.iter().filter(|s| **s).count() as f64 / successes_recent.len() as f64) },
        "learner_updates": updates,
        "envs": envs,
        "agents_per_env": cfg.sim.agents,
        "agents_total": cfg.agents_total(),
        "hosts": hosts,
        "observation_mode": cfg.sim.observation_mode,
        "renderer": cfg.sim.renderer,
        "env_steps_per_s": env_steps as f64 / wall,
        "updates_per_s": updates as f64 / wall,
        "cpu_util_mean_pct": cpu_mean.mean(),
        "gpu_util_mean_pct": gpu_util.mean(),
        "gpu_power_mean_w": gpu_power.mean(),
        "gpu_mem_peak_mb": gpu_mem.mean().map(|_| gpu_mem.max),
        "peak_rss_mb": peak_rss_mb,
        "restarts": restarts,
        "lost_messages": latest.values().map(|t| t.lost).sum::<u64>(),
        "checkpoint": checkpoint.as_ref().map(|p| p.display().to_string()),
        "last_checkpoint": last_checkpoint.as_ref().map(|p| p.display().to_string()),
        "evaluations": evals.len(),
        "best_eval_success_rate": best_eval.map(|b| b.success),
        "best_eval_mean_reward": best_eval.map(|b| b.mean_reward),
        "best_eval_at_s": best_eval.map(|b| b.wall),
        "best_eval_updates": best_eval.map(|b| b.updates),
        "interrupted": interrupted,
        "resumed": a.resume.is_some(),
        "failure": failure,
        "leftover_services": leftover,
    });
    let summary_path = run_dir.join("summary.json");
    // Through a temporary file: a full disk leaves no half-written summary.
    let tmp_summary = run_dir.join("summary.json.tmp");
    let written = std::fs::write(&tmp_summary, serde_json::to_string_pretty(&summary)? + "\n").and_then(|_| std::fs::rename(&tmp_summary, &summary_path));
    if let Err(e) = written {
        let _ = std::fs::remove_file(&tmp_summary);
        let also = failure.map_or(String::new(), |f| format!(" (the run had failed: {f})"));
        bail!("cannot write {}: {e}{also}", summary_path.display());
    }
    let series: Vec<(String, Vec<(f64, f64)>)> = util_series.into_iter().map(|(k, v)| (k, v.points)).collect();
    // A plot that cannot be drawn costs the picture, not the run's result.
    if let Err(e) = crate::draw::lines_plot("utilisation (% of the machine)", "wall time (s)", "%", &series, &run_dir.join("utilisation.png")) {
        tracing::warn!("utilisation.png not written: {e:#}");
    }
    if let Err(e) =
        crate::draw::reward_plot(&curve.points.iter().copied().filter(|p| p.1.is_finite()).collect::<Vec<_>>(), threshold, &run_dir.join("reward.png"))
    {
        tracing::warn!("reward.png not written: {e:#}");
    }
    say(&format!(
        "run {}: {} in {wall:.1} s, {episodes} episodes, rolling reward {roll:.1}, {env_steps} agent-steps, {updates} updates",
        run_dir.display(),
        match time_to_threshold {
            Some(t) => format!("converged at {t:.1} s"),
            None => "did not converge".to_string(),
        }
    ));
    match crate::profile::report(&run_dir) {
        Ok(r) => {
            let path = run_dir.join("profile.md");
            if let Err(e) = std::fs::write(&path, &r) {
                tracing::warn!("cannot write {}: {e}", path.display());
            }
            if let Some(line) = r.lines().find(|l| l.starts_with("**Bottleneck")) {
                say(&line.replace("**", ""));
            }
        }
        Err(e) => tracing::warn!("no profile: {e:#}"),
    }
    if let Some(f) = failure {
        bail!("{f}");
    }
    if !leftover.is_empty() {
        bail!("shared memory left behind after the run: {leftover:?}");
    }
    Ok(())
}

/// One episodes message: its header and its (return, length, done) triples.
type Reported = (EpisodeHeader, Vec<f32>);

/// Episode messages in the order they are written to `metrics.csv`: as they
/// come, or (a deterministic run) by (step, environment): every actor of
/// such a run reports every step, so once each has reported step `k`,
/// everything up to `k` is known.
struct EpisodeOrder {
    ordered: bool,
    /// Newest step each environment reported.
    latest: Vec<Option<u64>>,
    held: BTreeMap<(u64, u32), Vec<Reported>>,
}

impl EpisodeOrder {
    fn new(envs: usize, ordered: bool) -> Self {
        Self { ordered, latest: vec![None; envs], held: BTreeMap::new() }
    }

    fn push(&mut self, h: EpisodeHeader, payload: &[f32]) {
        if let Some(l) = self.latest.get_mut(h.actor as usize) {
            *l = Some(l.map_or(h.step, |v| v.max(h.step)));
        }
        self.held.entry((if self.ordered { h.step } else { 0 }, if self.ordered { h.actor } else { 0 })).or_default().push((h, payload.to_vec()));
    }

    /// The step every environment has reported (0 before all have).
    fn through(&self) -> u64 {
        self.latest.iter().map(|l| l.unwrap_or(0)).min().unwrap_or(0)
    }

    /// The messages that can be written now, in order.
    fn ready(&mut self) -> Vec<Reported> {
        if !self.ordered {
            return std::mem::take(&mut self.held).into_values().flatten().collect();
        }
        let upto = self.through();
        let later = self.held.split_off(&(upto + 1, 0));
        std::mem::replace(&mut self.held, later).into_values().flatten().collect()
    }
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
        let h = |actor: u32, step: u64| EpisodeHeader { actor, count: 1, transitions: 0, epsilon_micro: 0, step };
        let mut o = EpisodeOrder::new(2, true);
        o.push(h(1, 3), &[1.0, 1.0, 1.0]);
        o.push(h(1, 4), &[2.0, 1.0, 1.0]);
        // Environment 0 has reported nothing yet: nothing can be written.
        assert!(o.ready().is_empty());
        o.push(h(0, 3), &[3.0, 1.0, 1.0]);
        let got: Vec<(u32, u64)> = o.ready().iter().map(|(h, _)| (h.actor, h.step)).collect();
        assert_eq!(got, vec![(0, 3), (1, 3)]);
        assert_eq!(o.through(), 3);
        o.push(h(0, 4), &[]);
        assert_eq!(o.ready().iter().map(|(h, _)| (h.actor, h.step)).collect::<Vec<_>>(), vec![(0, 4), (1, 4)]);
        // Free-running: as they come.
        let mut o = EpisodeOrder::new(2, false);
        o.push(h(1, 9), &[]);
        o.push(h(0, 2), &[]);
        assert_eq!(o.ready().iter().map(|(h, _)| h.actor).collect::<Vec<_>>(), vec![1, 0]);
    }
}
