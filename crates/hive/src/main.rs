//! `hive`: the rotorhive command line. One binary with a subcommand per role
//! (`sim`, `actor`, `replay`, `learner`), the main job (`train`), evaluation,
//! pictures and system benchmarks.

mod certs;
mod draw;
mod eval;
mod export;
mod failures;
mod gpu_monitor;
mod link_args;
mod play;
mod role_cmd;
mod supervisor;
mod worker;

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Parser, Subcommand};
use role_cmd::RoleArgs;
use rotorhive_msg::RoleKind;

/// Trains simulated quadrotors to fly through obstacle fields from depth
/// images, with every process talking through zero-copy shared memory.
#[derive(Parser, Debug)]
#[command(name = "hive", version, about)]
struct Cli {
    /// Shared-memory domain: processes in different domains cannot see each
    /// other's shared memory, as if on different hosts (default: the
    /// machine's shared domain). Role processes inherit it.
    #[arg(long, global = true, value_name = "NAME")]
    domain: Option<String>,
    #[command(subcommand)]
    command: Command,
}

#[derive(Subcommand, Debug)]
enum Command {
    /// Train: start every role as a child process and supervise them.
    Train(supervisor::TrainArgs),
    /// Run one simulator (environment E) as its own process.
    Sim {
        #[command(flatten)]
        role: RoleArgs,
        /// Environment index.
        #[arg(long, default_value_t = 0)]
        env: usize,
    },
    /// Run the actor paired with simulator E.
    Actor {
        #[command(flatten)]
        role: RoleArgs,
        /// Environment index.
        #[arg(long, default_value_t = 0)]
        env: usize,
    },
    /// Run the replay memory.
    Replay {
        #[command(flatten)]
        role: RoleArgs,
    },
    /// Run the learner.
    Learner {
        #[command(flatten)]
        role: RoleArgs,
    },
    /// Join a run on another host (`hive train --listen`): run its sims and
    /// actors here, and their link; ends when the head's run ends.
    Worker(worker::WorkerArgs),
    /// Make the certificates of a run across hosts over mutual TLS: a CA and
    /// one directory per host for its `--tls`.
    Certs(certs::CertsArgs),
    /// Evaluate a checkpoint with the greedy policy.
    Eval(eval::EvalArgs),
    /// Watch a checkpoint's greedy policy fly: an animated GIF of the arena
    /// from above and one drone's depth frames, Q-values and actions.
    Play(play::PlayArgs),
    /// Write a checkpoint as an ONNX model (inputs `depth` and `velocity`,
    /// output `q`).
    Export(export::ExportArgs),
    /// Where a run's time went: CPU and wall-time shares per role and stage,
    /// and the bottleneck (also written to RUN_DIR/profile.md).
    Profile {
        /// A run directory written by `hive train`.
        run_dir: PathBuf,
    },
    /// System benchmarks; each prints one JSON line with --json.
    #[command(subcommand)]
    Bench(rotorhive_bench::BenchCmd),
    /// Draw an arena from above, optionally with random-policy trajectories.
    RenderArena(draw::RenderArenaArgs),
    /// Write one agent's two depth frames as a PNG.
    ShowDepth(draw::ShowDepthArgs),
    /// Generate a random arena file.
    GenArena(draw::GenArenaArgs),
}

fn main() -> ExitCode {
    let cli = match Cli::try_parse() {
        Ok(c) => c,
        Err(e) => {
            // Help and version go to stdout with success; usage errors exit 2.
            let _ = e.print();
            return if e.use_stderr() { ExitCode::from(2) } else { ExitCode::SUCCESS };
        }
    };
    tracing_subscriber::fmt()
        .with_env_filter(
            tracing_subscriber::EnvFilter::try_from_env("HIVE_LOG")
                .unwrap_or_else(|_| "info,wgpu_core=warn,wgpu_hal=warn,naga=warn,iceoryx2=warn,zenoh=error,zenoh_transport=error".into()),
        )
        .with_writer(std::io::stderr)
        .init();
    // Keep freed tensor buffers in the heap instead of returning them to the
    // kernel: without this every update maps fresh pages and page-faults on
    // them (a fifth of the learner's time).
    // SAFETY: mallopt only tunes glibc's allocator; called before any thread.
    unsafe {
        libc::mallopt(libc::M_MMAP_THRESHOLD, 32 << 20);
        libc::mallopt(libc::M_TRIM_THRESHOLD, 256 << 20);
    }
    let mut env = match &cli.command {
        Command::Train(a) => a.thread_env(),
        Command::Bench(b) => b.thread_env(),
        _ => Vec::new(),
    };
    if let Some(d) = &cli.domain {
        if let Err(e) = rotorhive_transport::check_domain(d) {
            eprintln!("error: --domain: {e}");
            return ExitCode::from(2);
        }
        // Role processes inherit it.
        env.push((rotorhive_transport::DOMAIN_ENV, d.clone()));
    }
    for (k, v) in env {
        // SAFETY: the only place this program sets its environment, in
        // `main` before any thread has started (tracing's subscriber and
        // clap start none).
        unsafe { std::env::set_var(k, v) };
    }
    // iceoryx2 warns about running without a config file; only errors matter here.
    iceoryx2::prelude::set_log_level(iceoryx2::prelude::LogLevel::Error);
    let result = match cli.command {
        Command::Train(a) => supervisor::run(a),
        Command::Sim { role, env } => role_cmd::run(&role, RoleKind::Sim, env),
        Command::Actor { role, env } => role_cmd::run(&role, RoleKind::Actor, env),
        Command::Replay { role } => role_cmd::run(&role, RoleKind::Replay, 0),
        Command::Learner { role } => role_cmd::run(&role, RoleKind::Learner, 0),
        Command::Worker(a) => worker::run(a),
        Command::Certs(a) => certs::run(a),
        Command::Eval(a) => eval::run(a),
        Command::Play(a) => play::run(a),
        Command::Export(a) => export::run(a),
        Command::Bench(b) => rotorhive_bench::run(b).map_err(Into::into),
        Command::RenderArena(a) => draw::render_arena(a),
        Command::ShowDepth(a) => draw::show_depth(a),
        Command::GenArena(a) => draw::gen_arena(a),
        Command::Profile { run_dir } => {
            rotorhive_records::profile::run(&run_dir).map_err(Into::into)
        }
    };
    match result {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            // Not eprintln!: on a full disk (stderr redirected to a role's
            // log) it would panic instead of exiting with the error.
            use std::io::Write;
            let _ = writeln!(std::io::stderr(), "error: {e:#}");
            ExitCode::FAILURE
        }
    }
}
