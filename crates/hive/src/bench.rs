//! System benchmarks (`hive bench NAME`). Each prints a readable table and,
//! with `--json`, one JSON object as the last line of stdout.

use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Result, bail};
use clap::Subcommand;
use serde_json::json;

use rotorhive_sim::{Arena, SimConfig, VecEnv};

#[derive(Subcommand, Debug)]
pub enum BenchCmd {
    /// Agent-steps per second of the simulator (physics + rendering + reward).
    Sim {
        /// Agents in the environment; a comma list runs each in turn.
        #[arg(long, default_value = "50", value_delimiter = ',')]
        agents: Vec<usize>,
        /// Measured steps (after 3 warm-up steps).
        #[arg(long, default_value_t = 40)]
        steps: usize,
        /// Rendering threads.
        #[arg(long, default_value_t = 1)]
        threads: usize,
        /// Arena file.
        #[arg(long, default_value = "configs/arenas/train.toml")]
        arena: PathBuf,
        /// Print one JSON object as the last line.
        #[arg(long)]
        json: bool,
    },
    /// Learner updates per second and actor inference latency.
    Learner {
        /// Threads for candle's CPU kernels.
        #[arg(long, default_value_t = 1)]
        threads: usize,
        /// Minibatch size.
        #[arg(long, default_value_t = 32)]
        batch: usize,
        /// Measured updates.
        #[arg(long, default_value_t = 100)]
        updates: usize,
        /// Also measure the generic path of stock candle ops, side by side.
        #[arg(long)]
        compare: bool,
        /// Print one JSON object as the last line.
        #[arg(long)]
        json: bool,
    },
}

pub fn run(cmd: BenchCmd) -> Result<()> {
    match cmd {
        BenchCmd::Sim { agents, steps, threads, arena, json } => bench_sim(&agents, steps, threads, &arena, json),
        BenchCmd::Learner { threads, batch, updates, compare, json } => crate::roles::learner::bench(threads, batch, updates, compare, json),
    }
}

fn bench_sim(agents: &[usize], steps: usize, threads: usize, arena: &std::path::Path, json: bool) -> Result<()> {
    if agents.iter().any(|n| *n == 0) || steps == 0 || threads == 0 {
        bail!("--agents, --steps and --threads must be positive");
    }
    let arena = Arena::load(arena)?;
    let mut rows = Vec::new();
    println!("{:>7} {:>16} {:>12} {:>11} {:>11} {:>11} {:>14}", "agents", "agent-steps/s", "step ms", "physics ms", "render ms", "reset ms", "render µs/agent");
    for &n in agents {
        let mut env = VecEnv::new(SimConfig { agents: n, render_threads: threads, ..SimConfig::default() }, arena.clone(), 1);
        // A fixed pseudo-random action pattern: agents crash and reset as in training.
        let actions = |t: usize| -> Vec<u8> { (0..n).map(|i| (((t * 31 + i * 17) >> 2) % 2) as u8).collect() };
        for t in 0..3 {
            env.step(&actions(t));
        }
        let (mut phys, mut rend, mut reset) = (0u64, 0u64, 0u64);
        let start = Instant::now();
        for t in 0..steps {
            env.step(&actions(t + 3));
            let tm = env.timing();
            phys += tm.physics_ns;
            rend += tm.render_ns;
            reset += tm.reset_ns;
        }
        let wall = start.elapsed().as_secs_f64();
        let per = |ns: u64| ns as f64 / 1e6 / steps as f64;
        let sps = (n * steps) as f64 / wall;
        println!(
            "{:>7} {:>16.0} {:>12.3} {:>11.3} {:>11.3} {:>11.3} {:>14.2}",
            n,
            sps,
            wall * 1e3 / steps as f64,
            per(phys),
            per(rend),
            per(reset),
            per(rend) * 1e3 / n as f64
        );
        rows.push(json!({
            "agents": n,
            "agent_steps_per_s": sps,
            "step_ms": wall * 1e3 / steps as f64,
            "stage_ms": { "physics": per(phys), "render": per(rend), "reset": per(reset) },
            "render_us_per_agent": per(rend) * 1e3 / n as f64,
        }));
    }
    if json {
        let out = if rows.len() == 1 { rows.remove(0) } else { json!({ "threads": threads, "rows": rows }) };
        println!("{out}");
    }
    Ok(())
}
