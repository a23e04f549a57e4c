//! System benchmarks (`hive bench NAME`). Each prints a readable table and,
//! with `--json`, one JSON object as the last line of stdout. They call the
//! public APIs of the simulator, model, replay, transport, link and roles,
//! and start `hive` processes (the running executable) where a benchmark
//! needs two sides. Criterion micro-benchmarks live beside their crate
//! (`crates/sim/benches/sim.rs`: `cargo bench -p rotorhive-sim`).
//!
//! | command | measures |
//! |---|---|
//! | `hive bench sim --agents 1,10,50,200` | agent-steps/s of the simulator and its stages |
//! | `hive bench render --renderer cpu\|wgpu` | ms per step to gather all agents' depth, batched against non-batched (the paper's figure 5a) |
//! | `hive bench learner --threads 2 --compare` | learner updates/s (fused CPU path against stock candle), inference at batch 1 and 50 |
//! | `hive bench ipc` | obs, transition and weights messages between two processes: iceoryx2 against msgpack over loopback TCP |
//! | `hive bench replay --producers 2` | transitions inserted/s and minibatches sampled/s by the replay process |
//! | `hive bench link` | transition batches between two hosts' links over Zenoh against raw TCP |
//! | `hive bench table --config FILE` | the paper's agent table: `hive train` per cell |
//! | `hive bench seeds --seeds 1-10 --arm A:k=v --arm B:k=v` | arms of a training config over seeds, interleaved, with bootstrap intervals |

use std::path::PathBuf;
use std::time::Instant;

use crate::error::{BenchError, Result, failed, usage};
use clap::Subcommand;
use serde_json::json;

use rotorhive_sim::{Arena, PhysicsKind, RendererKind, SimConfig, VecEnv};

pub mod error;
mod ipc;
mod learner;
mod link;
mod replay;
pub mod seeds;
pub mod stats;
mod table;

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
        /// Rendering threads (the physics shares them).
        #[arg(long, default_value_t = 1)]
        threads: usize,
        /// Flight computation: `direct`, `rapier`, or both as a comma list
        /// (each agent count runs on each, side by side).
        #[arg(long, default_value = "direct", value_delimiter = ',', value_parser = parse_physics)]
        physics: Vec<PhysicsKind>,
        /// Arena file.
        #[arg(long, default_value = "configs/arenas/train.toml")]
        arena: PathBuf,
        /// Measure this config's simulator instead (a level's, say): its
        /// training lanes, speeds, noise and randomisation.
        #[arg(long, conflicts_with = "arena")]
        config: Option<PathBuf>,
        /// With --config: also measure its lanes renewed with fresh layouts
        /// every this many finished episodes (`sim.fresh_layouts`), side by
        /// side with the fixed ones.
        #[arg(long, requires = "config")]
        fresh_layouts: Option<usize>,
        /// With --config: a config key to change, as `hive train --set`
        /// takes it (repeatable). A config with the camera's map
        /// (`sim.map`) or seen movers (`sim.tracks`) is measured without
        /// them too, side by side.
        #[arg(long = "set", value_name = "KEY=VALUE", requires = "config")]
        set: Vec<String>,
        /// Print one JSON object as the last line.
        #[arg(long)]
        json: bool,
    },
    /// Milliseconds per step to gather all agents' depth observations,
    /// batched against non-batched, side by side (the paper's figure 5a).
    Render {
        /// Agent counts to measure.
        #[arg(long, default_value = "1,10,25,50,100,200", value_delimiter = ',')]
        agents: Vec<usize>,
        /// Renderer: cpu or wgpu.
        #[arg(long, default_value = "cpu")]
        renderer: String,
        /// Measured steps per cell (after 2 warm-up steps).
        #[arg(long, default_value_t = 20)]
        steps: usize,
        /// Threads of the CPU ray caster, the same in both modes (0: one per
        /// core). A batched call spreads its cameras over them; a
        /// non-batched call cuts its one camera into bands of rows. Either
        /// way a call is one submission to them and one synchronisation.
        #[arg(long, default_value_t = 0)]
        threads: usize,
        /// Arena file.
        #[arg(long, default_value = "configs/arenas/train.toml")]
        arena: PathBuf,
        /// Plot of both curves against the agent count (its folder made).
        #[arg(long, default_value = "runs/render-bench.png")]
        plot: PathBuf,
        /// The camera of this config (`[sim.camera]`; the defaults' without one).
        #[arg(long)]
        config: Option<PathBuf>,
        /// A config key to change, as `hive train --set` takes it
        /// (repeatable): `sim.camera.width=64`.
        #[arg(long = "set", value_name = "KEY=VALUE")]
        set: Vec<String>,
        /// Print one JSON object as the last line.
        #[arg(long)]
        json: bool,
    },
    /// Observation batch, transition batch and weights between two processes:
    /// shared memory against msgpack over loopback TCP (the paper's RPC).
    Ipc {
        /// Messages per kind and path.
        #[arg(long, default_value_t = 300)]
        iters: usize,
        /// Print one JSON object as the last line.
        #[arg(long)]
        json: bool,
    },
    /// Transition batches across hosts: two processes in two shared-memory
    /// domains joined by their links over Zenoh on TCP loopback, against
    /// msgpack over TCP with the same batches, side by side.
    Link {
        /// Seconds per path.
        #[arg(long, default_value_t = 5.0)]
        seconds: f64,
        /// Transitions per batch (an actor's batch: one per agent).
        #[arg(long, default_value_t = 50)]
        batch: usize,
        /// Also both links over mutual TLS, on TCP (`tls/`) and on QUIC
        /// (`quic/`), with certificates made for the run.
        #[arg(long)]
        tls: bool,
        /// Print one JSON object as the last line.
        #[arg(long)]
        json: bool,
    },
    /// One side of `bench link` (started by it).
    #[command(hide = true)]
    LinkSide {
        #[arg(long)]
        side: String,
        #[arg(long)]
        endpoint: String,
        #[arg(long)]
        seconds: f64,
        #[arg(long)]
        batch: usize,
        /// This side's TLS directory (a `tls/` endpoint).
        #[arg(long)]
        tls: Option<std::path::PathBuf>,
    },
    /// The far side of `bench ipc` (started by it).
    #[command(hide = true)]
    IpcPeer {
        #[arg(long)]
        prefix: String,
    },
    /// Transitions inserted and minibatches sampled per second by the replay
    /// process, fed by producer processes over shared memory.
    Replay {
        /// Producer processes (actors).
        #[arg(long, default_value_t = 2)]
        producers: usize,
        /// Seconds of the sampling phases.
        #[arg(long, default_value_t = 3.0)]
        seconds: f64,
        /// Print one JSON object as the last line.
        #[arg(long)]
        json: bool,
    },
    /// A producer of `bench replay` (started by it).
    #[command(hide = true)]
    ReplayProducer {
        #[arg(long)]
        prefix: String,
        #[arg(long)]
        index: usize,
        #[arg(long)]
        producers: usize,
        #[arg(long)]
        batches: usize,
    },
    /// An experiment over seeds: every seed of every arm (a config plus
    /// overrides), interleaved, free-running to a wall budget; time to the
    /// threshold, validation and test success, with bootstrap intervals and
    /// the probability that one arm beats another.
    Seeds(crate::seeds::SeedsArgs),
    /// The paper's Table II: training time, CPU and GPU use for 1, 25, 50 and
    /// 2×37 agents, batched and non-batched.
    Table {
        /// Grid, budget and seeds.
        #[arg(long, default_value = "configs/bench/agent-table.toml")]
        config: PathBuf,
        /// The training config of every cell (a level's, say), instead of
        /// the table config's `config`.
        #[arg(long)]
        train_config: Option<PathBuf>,
        /// Where the runs and the table go.
        #[arg(long, default_value = "runs/agent-table")]
        out: PathBuf,
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
        /// The network's convolution channels (as `learner.conv_channels`).
        #[arg(long, value_delimiter = ',', default_value = "16,32")]
        conv_channels: Vec<usize>,
        /// The network's hidden widths (as `learner.hidden`).
        #[arg(long, value_delimiter = ',', default_value = "64")]
        hidden: Vec<usize>,
        /// Where the update runs: "cpu" (the fused path), or "cuda" (the
        /// generic path on GPU 0, in a build with `--features cuda`).
        #[arg(long, default_value = "cpu", value_parser = ["cpu", "cuda"])]
        device: String,
        /// The observation of this config (its camera, frames, goal, map;
        /// the defaults' without one).
        #[arg(long)]
        config: Option<PathBuf>,
        /// A config key to change, as `hive train --set` takes it
        /// (repeatable): `sim.camera.width=64`.
        #[arg(long = "set", value_name = "KEY=VALUE")]
        set: Vec<String>,
        /// Print one JSON object as the last line.
        #[arg(long)]
        json: bool,
    },
}

impl BenchCmd {
    /// The environment a benchmark's process must start with (set by the
    /// binary's `main` before any thread): the learner bench's candle and
    /// rayon pools. The fused path shards over `threads` threads itself;
    /// candle's elementwise pool must stay single-threaded (it serialises
    /// concurrent callers), its GEMMs (generic path) use `RAYON_NUM_THREADS`.
    pub fn thread_env(&self) -> Vec<(&'static str, String)> {
        match self {
            BenchCmd::Learner { threads, .. } => vec![
                ("RAYON_NUM_THREADS", threads.to_string()),
                ("CANDLE_NUM_THREADS", "1".to_string()),
            ],
            _ => Vec::new(),
        }
    }
}

/// A config for a bench that flies no teacher (the simulator's, the
/// renderer's): its teacher is turned off before the user's `--set`s, so
/// that `--set sim.map.encoding='"none"'` on a level whose teacher reads
/// the map (L4) measures the simulator without the map, not a refusal.
fn without_teacher(
    config: Option<&std::path::Path>,
    set: &[String],
) -> Result<rotorhive_roles::Config> {
    let mut sets = vec![rotorhive_config::NO_TEACHER.to_string()];
    sets.extend_from_slice(set);
    Ok(rotorhive_roles::Config::load(config, &sets)?)
}

pub fn run(cmd: BenchCmd) -> Result<()> {
    match cmd {
        BenchCmd::Sim {
            agents,
            steps,
            threads,
            physics,
            arena,
            config,
            fresh_layouts,
            set,
            json,
        } => {
            let world = match config {
                Some(c) => SimWorld::Config(Box::new(without_teacher(Some(&c), &set)?)),
                None => SimWorld::Arena(Arena::load(&arena)?),
            };
            run_sim(&agents, (steps, threads), &physics, world, fresh_layouts, json)
        }
        BenchCmd::Render { agents, renderer, steps, threads, arena, plot, config, set, json } => {
            let camera = without_teacher(config.as_deref(), &set)?.camera();
            let setup = (renderer.as_str(), steps, threads, camera);
            bench_render(&agents, setup, &arena, &plot, json)
        }
        BenchCmd::Ipc { iters, json } => crate::ipc::run(iters, json),
        BenchCmd::IpcPeer { prefix } => crate::ipc::peer(&prefix),
        BenchCmd::Link { seconds, batch, tls, json } => crate::link::run(seconds, batch, tls, json),
        BenchCmd::LinkSide { side, endpoint, seconds, batch, tls } => {
            crate::link::side(&side, &endpoint, seconds, batch, tls)
        }
        BenchCmd::Replay { producers, seconds, json } => {
            crate::replay::run(producers, seconds, json)
        }
        BenchCmd::ReplayProducer { prefix, index, producers, batches } => {
            crate::replay::producer(&prefix, index, producers, batches)
        }
        BenchCmd::Table { config, train_config, out, json } => {
            crate::table::run(&config, train_config.as_deref(), &out, json)
        }
        BenchCmd::Seeds(args) => crate::seeds::run(&args),
        BenchCmd::Learner {
            threads,
            batch,
            updates,
            compare,
            conv_channels,
            hidden,
            device,
            config,
            set,
            json,
        } => {
            let layers = rotorhive_model::Layers::new(&conv_channels, &hidden).map_err(|e| {
                crate::error::BenchError::Usage(format!("--conv-channels, --hidden: {e}"))
            })?;
            let shapes = rotorhive_roles::Config::load(config.as_deref(), &set)?.shapes();
            let sizes = (threads, batch, updates);
            crate::learner::bench(sizes, (shapes, layers), (compare, device == "cuda"), json)
        }
    }
}

/// `hive bench sim` of `world`: its fixed lanes, and renewed ones where
/// asked or its config renews them; a config with the camera's map also
/// without it, side by side.
fn run_sim(
    agents: &[usize],
    (steps, threads): (usize, usize),
    physics: &[PhysicsKind],
    world: SimWorld,
    fresh_layouts: Option<usize>,
    json: bool,
) -> Result<()> {
    if fresh_layouts == Some(0) {
        usage!("--fresh-layouts must be positive");
    }
    // A config that renews its lanes is measured both ways too.
    let fresh_layouts = fresh_layouts.or(match &world {
        SimWorld::Config(c) if c.sim.fresh_layouts > 0 => Some(c.sim.fresh_layouts),
        _ => None,
    });
    let lanes: Vec<Option<usize>> = std::iter::once(None).chain(fresh_layouts.map(Some)).collect();
    // The memory's cost: the same config without its map and tracks,
    // beside it.
    let mut worlds = vec![world];
    if let SimWorld::Config(c) = &worlds[0]
        && (c.sim.map.enabled() || c.sim.tracks.enabled())
    {
        let mut bare = (**c).clone();
        bare.sim.map = rotorhive_sim::MapSpec::default();
        bare.sim.tracks = rotorhive_sim::TrackSpec::default();
        worlds.push(SimWorld::Config(Box::new(bare)));
    }
    bench_sim(agents, (steps, threads), (physics, &lanes), &worlds, json)
}

fn parse_physics(s: &str) -> std::result::Result<PhysicsKind, String> {
    match s {
        "direct" => Ok(PhysicsKind::Direct),
        "rapier" => Ok(PhysicsKind::Rapier),
        other => Err(format!("unknown physics `{other}` (direct or rapier)")),
    }
}

fn physics_name(p: PhysicsKind) -> &'static str {
    match p {
        PhysicsKind::Direct => "direct",
        PhysicsKind::Rapier => "rapier",
    }
}

/// What `hive bench sim` flies in: one arena with the default settings, or
/// a config's training lanes with its settings.
enum SimWorld {
    Arena(Arena),
    Config(Box<rotorhive_roles::Config>),
}

impl SimWorld {
    /// The encoding of its camera's map (`none` without one), and `+tK`
    /// with K seen movers.
    fn map_name(&self) -> String {
        match self {
            SimWorld::Config(c) if c.sim.tracks.enabled() => {
                format!("{}+t{}", c.sim.map.encoding.name(), c.sim.tracks.count)
            }
            SimWorld::Config(c) => c.sim.map.encoding.name().to_string(),
            SimWorld::Arena(_) => "none".to_string(),
        }
    }

    /// The environment of `n` agents with `threads` and `physics`, its
    /// lanes renewed every `fresh` finished episodes where that is given.
    fn env(
        &self,
        n: usize,
        threads: usize,
        physics: PhysicsKind,
        fresh: Option<usize>,
    ) -> Result<VecEnv> {
        Ok(match self {
            SimWorld::Arena(a) => VecEnv::new(
                SimConfig { agents: n, render_threads: threads, physics, ..SimConfig::default() },
                a.clone(),
                1,
            )?,
            SimWorld::Config(c) => {
                let sim =
                    SimConfig { agents: n, render_threads: threads, physics, ..c.sim_config() };
                let arenas = c.lane_arenas(0)?;
                let mut env = VecEnv::new_lanes(sim, &arenas, 1)?;
                if let Some(every) = fresh {
                    let mut renewing = (**c).clone();
                    renewing.sim.fresh_layouts = every;
                    renewing.validate()?;
                    if let Some((first, make)) = renewing.fresh_layouts(0)? {
                        env.renew_lanes(every, first, arenas, make)?;
                    }
                }
                env
            }
        })
    }
}

/// The column heads of `hive bench sim`'s table.
fn print_sim_header() {
    println!(
        "{:>7} {:>8} {:>9} {:>6} {:>16} {:>12} {:>11} {:>11} {:>11} {:>15} {:>14}",
        "agents",
        "physics",
        "lanes",
        "map",
        "agent-steps/s",
        "step ms",
        "physics ms",
        "render ms",
        "reset ms",
        "physics µs/agent",
        "render µs/agent"
    );
}

fn bench_sim(
    agents: &[usize],
    (steps, threads): (usize, usize),
    (physics, lanes): (&[PhysicsKind], &[Option<usize>]),
    worlds: &[SimWorld],
    json: bool,
) -> Result<()> {
    if agents.contains(&0) || steps == 0 || threads == 0 {
        usage!("--agents, --steps and --threads must be positive");
    }
    let mut rows = Vec::new();
    print_sim_header();
    let runs = agents.iter().flat_map(|n| physics.iter().map(move |p| (*n, *p)));
    let runs = runs.flat_map(|r| lanes.iter().map(move |l| (r, *l)));
    for (((n, kind), fresh), world) in runs.flat_map(|r| worlds.iter().map(move |w| (r, w))) {
        let mut env = world.env(n, threads, kind, fresh)?;
        let map = world.map_name();
        // A fixed pseudo-random action pattern: agents crash and reset as in training.
        let actions = |t: usize| -> Vec<u8> {
            (0..n).map(|i| (((t * 31 + i * 17) >> 2) % 2) as u8).collect()
        };
        for t in 0..3 {
            env.step(&actions(t))?;
        }
        let (mut phys, mut rend, mut reset) = (0u64, 0u64, 0u64);
        let start = Instant::now();
        for t in 0..steps {
            env.step(&actions(t + 3))?;
            let tm = env.timing();
            phys += tm.physics_ns;
            rend += tm.render_ns;
            reset += tm.reset_ns;
        }
        let wall = start.elapsed().as_secs_f64();
        let per = |ns: u64| ns as f64 / 1e6 / steps as f64;
        let sps = (n * steps) as f64 / wall;
        let lanes_name = fresh.map_or_else(|| "fixed".to_string(), |e| format!("fresh/{e}"));
        println!(
            "{:>7} {:>8} {:>9} {:>6} {:>16.0} {:>12.3} {:>11.3} {:>11.3} {:>11.3} {:>15.2} {:>14.2}",
            n,
            physics_name(kind),
            lanes_name,
            map,
            sps,
            wall * 1e3 / steps as f64,
            per(phys),
            per(rend),
            per(reset),
            per(phys) * 1e3 / n as f64,
            per(rend) * 1e3 / n as f64
        );
        rows.push(json!({
            "agents": n,
            "physics": physics_name(kind),
            "lanes": lanes_name,
            "map": map,
            "map_bytes_per_agent": env.map_bytes_per_agent(),
            "fresh_layouts_flown": env.fresh_stats().renewed,
            "fresh_wait_ms": env.fresh_stats().wait_ns as f64 / 1e6,
            "agent_steps_per_s": sps,
            "step_ms": wall * 1e3 / steps as f64,
            "stage_ms": { "physics": per(phys), "render": per(rend), "reset": per(reset) },
            "physics_us_per_agent": per(phys) * 1e3 / n as f64,
            "render_us_per_agent": per(rend) * 1e3 / n as f64,
        }));
    }
    if json {
        let out = if rows.len() == 1 {
            rows.remove(0)
        } else {
            json!({ "threads": threads, "rows": rows })
        };
        println!("{out}");
    }
    Ok(())
}

/// Times the rendering stage of `VecEnv::step` (all agents' depth images
/// drawn and read back into the observation buffer) with the same agents
/// and actions in both modes: batched (one call, one submission, one
/// synchronisation per step) and non-batched (one of each per agent).
fn bench_render(
    agents: &[usize],
    (renderer, steps, threads, camera): (&str, usize, usize, rotorhive_sim::CameraSpec),
    arena: &std::path::Path,
    plot: &std::path::Path,
    json: bool,
) -> Result<()> {
    if agents.contains(&0) || steps == 0 {
        usage!("--agents and --steps must be positive");
    }
    let kind = match renderer {
        "cpu" => RendererKind::Cpu,
        "wgpu" => RendererKind::Wgpu,
        other => usage!("--renderer must be cpu or wgpu, got {other:?}"),
    };
    let arena = Arena::load(arena)?;
    let threads = if threads == 0 {
        std::thread::available_parallelism().map_or(1, |n| n.get())
    } else {
        threads
    };
    let mut adapter =
        format!("cpu ray casting, {threads} thread{}", if threads == 1 { "" } else { "s" });
    let setup = RenderSetup { kind, threads, steps, arena: &arena, camera };
    let mut measure = |n: usize, batched: bool| -> Result<(f64, f64)> {
        let (render, total, gpu) = setup.measure(n, batched)?;
        adapter = gpu.unwrap_or(adapter.clone());
        Ok((render, total))
    };
    println!(
        "{:>7} {:>12} {:>15} {:>8}   {:>17} {:>20}",
        "agents",
        "batched ms",
        "non-batched ms",
        "ratio",
        "batched render ms",
        "non-batched render ms"
    );
    let mut rows = Vec::new();
    let (mut b_pts, mut nb_pts) = (Vec::new(), Vec::new());
    for &n in agents {
        let (br, b) = measure(n, true)?;
        let (nbr, nb) = measure(n, false)?;
        println!("{n:>7} {b:>12.3} {nb:>15.3} {:>7.1}x   {br:>17.3} {nbr:>20.3}", nb / b);
        b_pts.push((n as f64, b));
        nb_pts.push((n as f64, nb));
        rows.push(json!({ "agents": n, "batched_ms": b, "non_batched_ms": nb, "ratio": nb / b, "batched_render_ms": br, "non_batched_render_ms": nbr }));
    }
    println!(
        "renderer {renderer} ({adapter}), camera {}; observations carried through iceoryx2 to a gathering thread as in training",
        rotorhive_roles::config::camera::camera_name(&camera)
    );
    println!("paper (AirSim, RTX 2070): 10 agents 61 ms batched, 197 ms non-batched");
    if let Some(dir) = plot.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir)?;
    }
    rotorhive_records::plot::lines_plot(
        &format!("observation gathering per step ({renderer})"),
        "agents",
        "ms per step",
        &[("batched".to_string(), b_pts), ("non-batched".to_string(), nb_pts)],
        plot,
    )?;
    println!("plot: {}", plot.display());
    if json {
        println!(
            "{}",
            json!({ "renderer": renderer, "adapter": adapter, "threads": threads, "steps": steps, "rows": rows, "plot": plot.display().to_string() })
        );
    }
    Ok(())
}

/// What every measurement of `bench render` shares.
struct RenderSetup<'a> {
    kind: RendererKind,
    threads: usize,
    steps: usize,
    arena: &'a Arena,
    camera: rotorhive_sim::CameraSpec,
}

impl RenderSetup<'_> {
    /// `n` agents batched or not: (render, render + transport) ms per step,
    /// and the GPU adapter's name where the renderer has one.
    fn measure(&self, n: usize, batched: bool) -> Result<(f64, f64, Option<String>)> {
        let cfg = SimConfig {
            agents: n,
            renderer: self.kind,
            batched,
            render_threads: self.threads,
            camera: self.camera,
            ..SimConfig::default()
        };
        let shapes = cfg.shapes();
        let mut env = VecEnv::new(cfg, self.arena.clone(), 1)?;
        // As in `hive sim`: observations are assembled in the loaned sample.
        env.drop_observation_buffer();
        let adapter = env.gpu().map(|g| g.adapter().to_string());
        let mut hop = ObsHop::new(n, batched, shapes)?;
        let actions = |t: usize| -> Vec<u8> {
            (0..n).map(|i| (((t * 31 + i * 17) >> 2) % 2) as u8).collect()
        };
        let (mut render, mut total) = (0u64, 0u64);
        for t in 0..self.steps + 2 {
            env.step(&actions(t))?;
            let hop_ns = hop.carry(&env, t as u64, batched)?;
            if t >= 2 {
                render += env.timing().render_ns;
                total += env.timing().render_ns + hop_ns;
            }
        }
        hop.finish()?;
        let ms = |ns: u64| ns as f64 / 1e6 / self.steps as f64;
        Ok((ms(render), ms(total), adapter))
    }
}

/// Carries a sim's observations of one step to a receiving thread through
/// iceoryx2 shared memory, exactly as `hive sim` publishes them to its actor
/// (one message per step batched, one per agent non-batched, on the
/// training's observation channel) and as the actor gathers them.
struct ObsHop {
    _hub: rotorhive_transport::Hub<rotorhive_transport::Ipc>,
    tx: rotorhive_transport::Sender<rotorhive_transport::Ipc, f32, rotorhive_msg::ObsHeader>,
    gathered: std::sync::mpsc::Receiver<u64>,
    stop: std::sync::Arc<std::sync::atomic::AtomicBool>,
    thread: Option<std::thread::JoinHandle<Result<()>>>,
}

impl ObsHop {
    fn new(n: usize, batched: bool, shapes: rotorhive_msg::Shapes) -> Result<Self> {
        use rotorhive_transport::{Channel, Hub, Ipc};
        let prefix = rotorhive_transport::unique_prefix(&format!("bench-render-{n}-{batched}"));
        let ch = Channel::obs(0, if batched { 1 } else { n });
        let hub = Hub::<Ipc>::new(&prefix, "bench-render-sim")?;
        let tx = hub.sender::<f32, rotorhive_msg::ObsHeader>(
            &ch,
            shapes.obs_batch_len(n),
            std::time::Duration::from_secs(5),
        )?;
        let (done_tx, gathered) = std::sync::mpsc::channel();
        let (ready_tx, ready) = std::sync::mpsc::channel();
        let stop = std::sync::Arc::new(std::sync::atomic::AtomicBool::new(false));
        let halt = stop.clone();
        let thread = std::thread::spawn(move || -> Result<()> {
            let hub = Hub::<Ipc>::new(&prefix, "bench-render-actor")?;
            let mut rx = hub.receiver::<f32, rotorhive_msg::ObsHeader>(&ch)?;
            let _ = ready_tx.send(());
            let mut gather = rotorhive_roles::actor::Gather::new(n, shapes.obs_len());
            while !halt.load(std::sync::atomic::Ordering::Relaxed) {
                let Some(m) = rx.recv_timeout(std::time::Duration::from_millis(10))? else {
                    continue;
                };
                let h = *m.user_header();
                // A whole batch is used in place (the actor's network reads it
                // from shared memory); per-agent messages are copied together.
                // Completion is the header's (all agents of the step), never a
                // payload value: the payload's tail holds the teacher's labels,
                // `NO_EXPERT = -1.0` where there is none.
                let complete = if h.agents == h.total {
                    std::hint::black_box(m.payload()[m.payload().len() - 1]);
                    h.first == 0 && h.total as usize == n
                } else {
                    gather.add(&h, m.payload())
                };
                if complete && done_tx.send(h.step).is_err() {
                    break;
                }
            }
            Ok(())
        });
        ready.recv_timeout(std::time::Duration::from_secs(10)).map_err(|_| {
            BenchError::Failed("the gathering thread of bench render did not start".into())
        })?;
        Ok(Self { _hub: hub, tx, gathered, stop, thread: Some(thread) })
    }

    /// Publishes the step's observations and waits until they are gathered;
    /// the nanoseconds this took.
    fn carry(&mut self, env: &VecEnv, step: u64, batched: bool) -> Result<u64> {
        let t = Instant::now();
        rotorhive_roles::sim::send_obs(&mut self.tx, env, step, batched, None)?;
        let got = self.gathered.recv_timeout(std::time::Duration::from_secs(10)).map_err(|_| {
            BenchError::Failed(format!("step {step}'s observations were not gathered within 10 s"))
        })?;
        if got != step {
            failed!("gathered step {got}, expected {step}");
        }
        Ok(t.elapsed().as_nanos() as u64)
    }

    fn finish(mut self) -> Result<()> {
        self.stop.store(true, std::sync::atomic::Ordering::Relaxed);
        match self.thread.take().map(std::thread::JoinHandle::join) {
            Some(Ok(r)) => r,
            Some(Err(_)) => failed!("the gathering thread of bench render panicked"),
            None => Ok(()),
        }
    }
}
