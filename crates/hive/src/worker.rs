//! `hive worker`: a host that lends its cores to a run on another host. It
//! joins the head (`hive train --listen`), takes the run's resolved config
//! and arena from it, runs E sims × N agents with their actors as processes
//! over this host's shared memory (started, logged and restarted by the
//! head's launcher), and its link, in this process, carries their
//! transitions to the head and the head's weights back.

use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use anyhow::{Context, Result, bail};
use clap::Args;
use rotorhive_link::{Hello, SentLog, Worker, WorkerEnd, WorkerStats};
use rotorhive_roles::{Config, env_role_names, roles_of};
use rotorhive_transport::{Hub, Ipc};

use crate::supervisor::Members;

/// `hive worker` arguments.
#[derive(Args, Debug)]
pub struct WorkerArgs {
    /// The head's endpoint, as it listens: quic/ADDR:PORT (or tls/, tcp/).
    #[arg(long, value_name = "quic/ADDR:PORT")]
    pub connect: String,
    /// Environments (sims) on this host.
    #[arg(long, default_value_t = 1)]
    pub envs: u32,
    /// Agents per environment (default: the head's `sim.agents`).
    #[arg(long)]
    pub agents: Option<u32>,
    /// This host's name in the run's records (default: the machine's name,
    /// with the domain when one is given).
    #[arg(long)]
    pub name: Option<String>,
    /// Where the worker keeps its join token, the config and arena it was
    /// sent and its roles' logs (default `runs/worker-<name>`).
    #[arg(long)]
    pub run_dir: Option<PathBuf>,
    /// How long to keep asking the head to join (s).
    #[arg(long, default_value_t = 60.0)]
    pub join_timeout: f64,
    #[command(flatten)]
    pub link: crate::link_args::LinkArgs,
}

pub fn run(a: WorkerArgs) -> Result<()> {
    if a.envs == 0 || a.agents == Some(0) {
        bail!("--envs and --agents must be at least 1");
    }
    if !(a.join_timeout.is_finite() && a.join_timeout > 0.0) {
        bail!("--join-timeout must be positive, got {}", a.join_timeout);
    }
    a.link.check(&a.connect)?;
    rotorhive_transport::handle_hangup();
    // What a killed worker of this domain left in shared memory (its roles
    // stopped within 2 s of it, but their nodes may remain).
    let cleaned = rotorhive_transport::cleanup_dead_nodes();
    if cleaned > 0 {
        tracing::info!("cleaned {cleaned} dead node(s) left in this domain");
    }
    let (name, run_dir) = name_and_dir(&a)?;
    let token = join_token(&run_dir)?;
    let sent_log = run_dir.join("link-sent");
    let hello = Hello {
        layout: rotorhive_link::layout(rotorhive_model::num_params(
            rotorhive_msg::Shapes::PAPER,
            rotorhive_model::Layers::DEFAULT,
        )),
        envs: a.envs,
        agents: a.agents.unwrap_or(0),
        host: name.clone(),
        token,
        earlier: SentLog::read(&sent_log),
    };
    let mut link = Worker::join(
        &a.connect,
        &hello,
        Duration::from_secs_f64(a.join_timeout),
        &a.link.worker_options(),
        rotorhive_transport::stop_requested,
    )?;
    let (cfg, cfg_path) = worker_config(&link, &run_dir, a.envs as usize, a.agents)?;
    link.reconnect = Duration::from_secs_f64(cfg.cluster.reconnect_s);
    link.sent_log = Some(sent_log);
    println!(
        "joined the run at {} as worker {} ({name}): {} × {} agents, environments {}..{}",
        a.connect,
        link.slot,
        cfg.sim.envs,
        cfg.sim.agents,
        link.env_offset,
        link.env_offset as usize + cfg.sim.envs
    );
    let mut stats = WorkerStats::default();
    let mut restarts = 0u32;
    let end = serve(&link, &cfg, &cfg_path, &run_dir, &name, &mut stats, &mut restarts);
    println!(
        "worker {name}: {} transitions sent ({} acknowledged, {} sent again, {} never acknowledged), weights version {} ({} received, {} rejected), {} messages dropped, {restarts} role restarts",
        stats.transitions,
        stats.acknowledged,
        stats.resent,
        stats.unacknowledged(),
        stats.weight_version,
        stats.weights,
        stats.rejected,
        stats.dropped
    );
    match end? {
        WorkerEnd::RunEnded => {
            println!("the head ended the run");
            Ok(())
        }
        WorkerEnd::Stopped => Ok(()),
    }
}

/// This host's name in the run and its run directory (created): one
/// directory per host name, so that a worker started again under its name
/// finds its join token and what the killed one sent.
fn name_and_dir(a: &WorkerArgs) -> Result<(String, PathBuf)> {
    let name =
        a.name.clone().unwrap_or_else(|| match std::env::var(rotorhive_transport::DOMAIN_ENV) {
            Ok(d) if !d.is_empty() => format!("{}/{d}", crate::supervisor::host_name()),
            _ => crate::supervisor::host_name(),
        });
    let safe: String = name
        .chars()
        .map(|c| if c.is_ascii_alphanumeric() || c == '-' || c == '.' { c } else { '_' })
        .collect();
    let run_dir =
        a.run_dir.clone().unwrap_or_else(|| PathBuf::from("runs").join(format!("worker-{safe}")));
    std::fs::create_dir_all(&run_dir)
        .with_context(|| format!("cannot create {}", run_dir.display()))?;
    Ok((name, run_dir.canonicalize()?))
}

/// Runs the link (a thread of this process) and, once it takes their
/// batches, this host's sims and actors as processes of its domain,
/// launched and restarted as the head's roles are; until the link ends
/// (the head's end, a stop, a lost head) or a role keeps dying.
fn serve(
    link: &Worker,
    cfg: &Config,
    cfg_path: &Path,
    run_dir: &Path,
    name: &str,
    stats: &mut WorkerStats,
    restarts: &mut u32,
) -> Result<WorkerEnd> {
    let prefix = rotorhive_transport::unique_prefix("worker");
    let stop = Arc::new(AtomicBool::new(false));
    std::thread::scope(|s| -> Result<WorkerEnd> {
        let (ready_tx, ready_rx) = std::sync::mpsc::channel();
        let bridge = s.spawn(|| -> Result<WorkerEnd> {
            let hub = Hub::<Ipc>::new(&prefix, "link")?.with_stop(stop.clone());
            Ok(link.bridge(
                &hub,
                cfg.sim.envs,
                roles_of(cfg),
                cfg.num_params(),
                stats,
                move || {
                    let _ = ready_tx.send(());
                },
            )?)
        });
        let give_up = |why: anyhow::Error| {
            stop.store(true, Ordering::SeqCst);
            why
        };
        // Dropping `members` stops them.
        let mut members = match ready_rx.recv() {
            Ok(()) => Some(
                Members::start(cfg, false, &prefix, run_dir, cfg_path, env_role_names(cfg))
                    .map_err(give_up)?,
            ),
            Err(_) => None,
        };
        while !bridge.is_finished() {
            if let Some(m) = members.as_mut() {
                let shutting_down =
                    || stop.load(Ordering::SeqCst) || rotorhive_transport::stop_requested();
                let gave_up = m.check(&shutting_down, &mut |what| {
                    *restarts += 1;
                    eprintln!("worker {name}: {what}");
                    Ok(())
                });
                match gave_up {
                    Ok(None) => {}
                    Ok(Some(why)) => return Err(give_up(anyhow::anyhow!(why))),
                    Err(e) => return Err(give_up(e)),
                }
            }
            std::thread::sleep(Duration::from_millis(50));
        }
        if let Some(m) = members.as_mut() {
            m.stop();
        }
        bridge.join().map_err(|_| anyhow::anyhow!("the link panicked"))?
    })
}

/// This host's join token: `RUN_DIR/join-token` (readable by its owner
/// only), made from the OS's random source on first use. A head takes a
/// host back under its name only with the token it first joined with.
fn join_token(run_dir: &std::path::Path) -> Result<String> {
    use std::os::unix::fs::OpenOptionsExt;
    let path = run_dir.join("join-token");
    match std::fs::read_to_string(&path) {
        Ok(t) if !t.trim().is_empty() && t.trim().len() <= rotorhive_link::wire::MAX_TOKEN => {
            return Ok(t.trim().to_string());
        }
        Ok(_) => bail!("{}: not a join token (delete it to make a new one)", path.display()),
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => {}
        Err(e) => return Err(e).with_context(|| format!("cannot read {}", path.display())),
    }
    let token = format!("{:032x}", rand::random::<u128>());
    let mut f = std::fs::OpenOptions::new()
        .write(true)
        .create_new(true)
        .mode(0o600)
        .open(&path)
        .with_context(|| format!("cannot create {}", path.display()))?;
    std::io::Write::write_all(&mut f, token.as_bytes())
        .with_context(|| format!("cannot write {}", path.display()))?;
    Ok(token)
}

/// This host's config: the head's, with this host's environments and
/// agents, its own seeds, and the arena it was sent.
fn worker_config(
    link: &Worker,
    run_dir: &std::path::Path,
    envs: usize,
    agents: Option<u32>,
) -> Result<(Config, PathBuf)> {
    let head_cfg = run_dir.join("head-config.toml");
    std::fs::write(&head_cfg, &link.config)
        .with_context(|| format!("cannot write {}", head_cfg.display()))?;
    // An empty arena: the head's lanes are all generated.
    let arena = if link.arena.is_empty() { PathBuf::new() } else { run_dir.join("arena.toml") };
    if !link.arena.is_empty() {
        std::fs::write(&arena, &link.arena)
            .with_context(|| format!("cannot write {}", arena.display()))?;
    }
    let head = Config::load(Some(&head_cfg), &[]).context("the config the head sent")?;
    let agents = agents.map_or(head.sim.agents, |n| n as usize);
    let (Some(envs_elsewhere), Some(agents_elsewhere)) = (
        head.envs_total().checked_sub(envs),
        envs.checked_mul(agents).and_then(|mine| head.agents_total().checked_sub(mine)),
    ) else {
        bail!(
            "the head's run has {} environments and {} agents, fewer than this host's {envs} × {agents}",
            head.envs_total(),
            head.agents_total()
        );
    };
    let mut cfg = head;
    cfg.sim.envs = envs;
    cfg.sim.agents = agents;
    cfg.sim.arena = arena;
    // Seeded as these environments of a one-host run would be.
    cfg.cluster.env_offset = link.env_offset as usize;
    cfg.cluster.workers = 0;
    cfg.cluster.envs_elsewhere = envs_elsewhere;
    cfg.cluster.agents_elsewhere = agents_elsewhere;
    cfg.validate().context("this worker's config")?;
    let path = run_dir.join("config.toml");
    std::fs::write(&path, cfg.to_toml())
        .with_context(|| format!("cannot write {}", path.display()))?;
    Ok((cfg, path))
}
