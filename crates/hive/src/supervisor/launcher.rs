//! The launcher: starts the roles of a run (child processes, or threads in
//! serial mode), restarts a role process that dies (giving up on one that
//! keeps dying), stops them all, and holds the run directory's lock.

use std::collections::VecDeque;
use std::fs::File;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use anyhow::{Context, Result, bail};
use rotorhive_msg::RoleKind;
use rotorhive_roles::Config;
use rotorhive_transport::cleanup_dead_nodes;
use sysinfo::Pid;

pub(crate) struct Role {
    name: String,
    args: Vec<String>,
    /// Its `RAYON_NUM_THREADS`: the learner's and each actor's `threads`,
    /// 1 for the rest.
    rayon: usize,
    child: Child,
    /// When this role was restarted, for the give-up rule.
    restarts: VecDeque<Instant>,
}

/// How a role process is started (again).
pub(crate) struct Launcher {
    exe: PathBuf,
    cfg_path: PathBuf,
    prefix: String,
    run_dir: PathBuf,
    logs: PathBuf,
}

impl Launcher {
    fn spawn(&self, name: &str, args: &[String], rayon: usize, append: bool) -> Result<Child> {
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
        rotorhive_transport::dies_with_this_process(&mut cmd, rustix::process::Signal::TERM);
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
            // Roles size their own parallelism from the config: the
            // learner's and actors' data-parallel shards run on rayon's
            // global pool, which RAYON_NUM_THREADS sizes, so theirs is their
            // `threads` (at 1 for every role, a learner of 8 threads ran its
            // shards one after another: 107 updates/s in a run on 16 cores
            // against 473 alone, on a 16-core machine); the sims'
            // render threads are a pool of their own. Candle's elementwise
            // pool stays single-threaded (it serialises concurrent callers).
            .env("RAYON_NUM_THREADS", rayon.to_string())
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
pub(crate) struct Children {
    roles: Vec<Role>,
}

impl Children {
    fn stop(&mut self) {
        for r in &mut self.roles {
            terminate(&mut r.child);
        }
        let deadline = Instant::now() + Duration::from_secs(10);
        for r in &mut self.roles {
            loop {
                match r.child.try_wait() {
                    Ok(Some(_)) => break,
                    Ok(None) if Instant::now() < deadline => {
                        std::thread::sleep(Duration::from_millis(20))
                    }
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

pub(super) fn timestamp() -> String {
    let secs = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map(|d| d.as_secs())
        .unwrap_or(0);
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
pub(super) fn lock_run_dir(dir: &Path) -> Result<File> {
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
            f.set_len(0)
                .and_then(|_| writeln!(f, "{}", std::process::id()))
                .with_context(|| format!("cannot write {}", path.display()))?;
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
        Err(std::fs::TryLockError::Error(e)) => {
            Err(e).with_context(|| format!("cannot lock {}", path.display()))
        }
    }
}

/// The last line of a role's log that reports an error, for the message
/// that tells why the role died.
fn last_error(log: &Path) -> Option<String> {
    let text = std::fs::read_to_string(log).ok()?;
    text.lines().rev().find(|l| l.contains("error")).map(|l| l.trim().to_string())
}

/// The roles of a run (or of a worker host): child processes (restarted
/// when they die), or, in serial mode, threads of this process.
pub(crate) enum Members {
    Processes {
        launcher: Launcher,
        children: Children,
    },
    Threads {
        stop: Arc<AtomicBool>,
        threads: Vec<(String, std::thread::JoinHandle<rotorhive_roles::error::Result<()>>)>,
    },
}

impl Members {
    /// Starts `roles` (all of a run's, or a worker host's sims and actors):
    /// threads over `local` in serial mode, else one `hive` process per
    /// role reading `cfg_path`, logging to `run_dir/logs`.
    pub(crate) fn start(
        cfg: &Config,
        serial: bool,
        prefix: &str,
        run_dir: &Path,
        cfg_path: &Path,
        roles: Vec<(String, RoleKind, usize)>,
    ) -> Result<Self> {
        let logs = run_dir.join("logs");
        std::fs::create_dir_all(&logs)
            .with_context(|| format!("cannot create {}", logs.display()))?;
        if serial {
            let stop = Arc::new(AtomicBool::new(false));
            return Ok(Members::Threads {
                threads: rotorhive_roles::spawn_threads(cfg, prefix, run_dir, &stop, roles)?,
                stop,
            });
        }
        let exe = std::env::current_exe().context("cannot find the hive executable")?;
        let launcher = Launcher {
            exe,
            cfg_path: cfg_path.to_path_buf(),
            prefix: prefix.to_string(),
            run_dir: run_dir.to_path_buf(),
            logs,
        };
        let mut children = Children { roles: Vec::new() };
        for (name, role, index) in roles {
            let mut args = vec![role.name().to_string()];
            if matches!(role, RoleKind::Sim | RoleKind::Actor) {
                args.extend(["--env".to_string(), index.to_string()]);
            }
            let rayon = match role {
                RoleKind::Learner => cfg.learner.threads,
                RoleKind::Actor => cfg.actor.threads,
                _ => 1,
            }
            .max(1);
            let child = launcher.spawn(&name, &args, rayon, false)?;
            children.roles.push(Role { name, args, rayon, child, restarts: VecDeque::new() });
        }
        Ok(Members::Processes { launcher, children })
    }

    /// Whether the roles run as processes of their own.
    pub(crate) fn processes(&self) -> bool {
        matches!(self, Members::Processes { .. })
    }

    /// The processes whose CPU and memory are the roles'.
    pub(crate) fn pids(&self) -> Vec<Pid> {
        match self {
            Members::Processes { children, .. } => {
                children.roles.iter().map(|r| Pid::from_u32(r.child.id())).collect()
            }
            Members::Threads { .. } => vec![Pid::from_u32(std::process::id())],
        }
    }

    /// Supervision: a role process that died is cleaned up after and
    /// started again (the learner from its last saved state), and
    /// `restarted` hears of it; one that keeps dying, or a role thread that
    /// ended, stops the run: the reason is returned.
    pub(crate) fn check(
        &mut self,
        shutting_down: &dyn Fn() -> bool,
        restarted: &mut dyn FnMut(String) -> Result<()>,
    ) -> Result<Option<String>> {
        let (launcher, children) = match self {
            // A role thread ends only with an error (or a stop).
            Members::Threads { threads, .. } => {
                return Ok(threads
                    .iter()
                    .find(|(_, h)| h.is_finished())
                    .map(|(name, _)| format!("role {name} stopped")));
            }
            Members::Processes { launcher, children } => (launcher, children),
        };
        for r in &mut children.roles {
            let Some(status) = r.child.try_wait()? else {
                continue;
            };
            if shutting_down() {
                break;
            }
            let log = launcher.logs.join(format!("{}.log", r.name));
            let now = Instant::now();
            while r.restarts.front().is_some_and(|t| now.duration_since(*t) > RESTART_WINDOW) {
                r.restarts.pop_front();
            }
            if r.restarts.len() >= MAX_RESTARTS {
                let why = last_error(&log).map_or(String::new(), |e| format!(": {e}"));
                return Ok(Some(format!(
                    "role {} died {} times within {} s (last: {status}{why}); giving up; see {}",
                    r.name,
                    r.restarts.len() + 1,
                    RESTART_WINDOW.as_secs(),
                    log.display()
                )));
            }
            let cleaned = cleanup_dead_nodes();
            tracing::warn!("role {} exited ({status}); restarting", r.name);
            r.child = launcher.spawn(&r.name, &r.args, r.rayon, true)?;
            r.restarts.push_back(now);
            restarted(format!(
                "role {} exited ({status}); cleaned {cleaned} dead node(s), restarting",
                r.name
            ))?;
        }
        Ok(None)
    }

    /// Stops every role; in serial mode returns the first role's error.
    pub(crate) fn stop(&mut self) -> Option<String> {
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

/// This machine's name.
pub fn host_name() -> String {
    std::fs::read_to_string("/proc/sys/kernel/hostname")
        .map(|s| s.trim().to_string())
        .ok()
        .filter(|s| !s.is_empty())
        .unwrap_or_else(|| "localhost".into())
}

/// Asks a child to stop (SIGTERM), unless it was already reaped: its pid
/// may then belong to another process (while it is not reaped, it cannot).
pub(crate) fn terminate(child: &mut std::process::Child) {
    if matches!(child.try_wait(), Ok(None)) {
        let pid = rustix::process::Pid::from_child(child);
        let _ = rustix::process::kill_process(pid, rustix::process::Signal::TERM);
    }
}
