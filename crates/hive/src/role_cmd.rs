//! `hive sim|actor|replay|learner`: one role of a run as a process of its
//! own over iceoryx2's `ipc` service, started by `hive train` or by hand.

use std::path::PathBuf;
use std::time::Duration;

use anyhow::{Context, Result};
use clap::Args;
use rotorhive_msg::RoleKind;
use rotorhive_roles::{Config, Ctx};
use rotorhive_transport::{Hub, Ipc};

/// A config file and overrides, shared by `train` and the roles.
#[derive(Args, Debug, Clone)]
pub struct ConfigArgs {
    /// Config file (TOML); the built-in defaults when absent.
    pub config: Option<PathBuf>,
    /// Override a config key, e.g. `--set sim.agents=10` (repeatable).
    #[arg(long = "set", value_name = "KEY=VALUE")]
    pub set: Vec<String>,
}

/// What every role needs to find its run.
#[derive(Args, Debug, Clone)]
pub struct RoleArgs {
    #[command(flatten)]
    pub cfg: ConfigArgs,
    /// Service-name prefix of the run (every service of a run starts with it).
    #[arg(long)]
    pub prefix: String,
    /// Run directory (checkpoints are written here).
    #[arg(long)]
    pub run_dir: Option<PathBuf>,
}

/// Runs role `role` number `index` of the run `args` name. SIGHUP stops it
/// as SIGTERM does, and it stops when the supervisor of its run goes (see
/// [`watch_supervisor`]).
pub fn run(args: &RoleArgs, role: RoleKind, index: usize) -> Result<()> {
    let cfg = Config::load(args.cfg.config.as_deref(), &args.cfg.set)?;
    if matches!(role, RoleKind::Sim | RoleKind::Actor) && index >= cfg.sim.envs {
        anyhow::bail!(
            "--env {index} is out of range: the config has {} environments",
            cfg.sim.envs
        );
    }
    let node = rotorhive_roles::node_name(role, index);
    rotorhive_transport::handle_hangup();
    let hub = Hub::<Ipc>::new(&args.prefix, &node).with_context(|| format!("role {node}"))?;
    watch_supervisor(&args.prefix, &node)?;
    Ok(rotorhive_roles::run_role(
        Ctx { hub: &hub, cfg: &cfg, run_dir: args.run_dir.as_deref() },
        role,
        index,
    )?)
}

/// The environment variable through which `hive train` tells its roles its
/// process id.
pub const SUPERVISOR_PID_ENV: &str = "ROTORHIVE_SUPERVISOR_PID";

/// How long a role whose supervisor is gone has to stop cleanly before it
/// exits at once (the whole run is down within 2 s of its supervisor).
const ORPHAN_GRACE: Duration = Duration::from_millis(1500);

/// Stops this role when its run's supervisor is gone, however it went
/// (SIGKILL, the OOM killer): a thread checks every 200 ms whether the
/// supervisor that started it is still its parent, and whether the
/// supervisor's iceoryx2 node (once seen) is alive, which also covers roles
/// started by hand with `--prefix`. It then asks the role to stop, and ends
/// the process if it has not stopped within [`ORPHAN_GRACE`]. (`hive train`
/// also sets `PR_SET_PDEATHSIG`, which signals at once.)
fn watch_supervisor(prefix: &str, node: &str) -> Result<()> {
    let parent: Option<i32> = std::env::var(SUPERVISOR_PID_ENV).ok().and_then(|v| v.parse().ok());
    let supervisor = rotorhive_transport::supervisor_node_name(prefix);
    let node = node.to_string();
    std::thread::Builder::new()
        .name("supervisor-watch".into())
        .spawn(move || {
            let mut seen = false;
            loop {
                std::thread::sleep(Duration::from_millis(200));
                let ppid = rustix::process::getppid().map(|p| p.as_raw_pid());
                let orphaned = parent.is_some_and(|p| ppid != Some(p));
                let state = rotorhive_transport::node_alive(&supervisor);
                seen |= state == Some(true);
                if orphaned || (seen && state != Some(true)) {
                    tracing::warn!("{node}: the supervisor of this run is gone; stopping");
                    rotorhive_transport::request_stop();
                    std::thread::sleep(ORPHAN_GRACE);
                    let _ = std::io::Write::write_fmt(
                        &mut std::io::stderr(),
                        format_args!("{node}: did not stop within {ORPHAN_GRACE:?} of its supervisor's end; exiting\n"),
                    );
                    // Shared memory is cleaned by the next start.
                    std::process::exit(3);
                }
            }
        })
        .context("cannot start the supervisor watch")?;
    Ok(())
}
