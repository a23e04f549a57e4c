//! `hive play`: a video of a checkpoint's greedy policy flying, as an
//! animated GIF: the arena from above with every drone's path, and beside
//! it the depth frames one drone sees with its Q-values and chosen action
//! (`rotorhive_sim::view`), frame by frame.

use std::borrow::Cow;
use std::path::PathBuf;
use std::time::Instant;

use anyhow::{Context, Result, bail};
use clap::Args;
use rotorhive_model::PolicyNet;
use rotorhive_sim::view::{self, Canvas, Focus, Tracks};
use rotorhive_sim::{Arena, Autoreset, SimConfig, VecEnv};

#[derive(Args, Debug)]
pub struct PlayArgs {
    /// Weights (safetensors) written by `hive train`.
    #[arg(long)]
    pub checkpoint: PathBuf,
    /// Arena to fly in.
    #[arg(long, default_value = "configs/arenas/test.toml")]
    pub arena: PathBuf,
    /// Drones flying at once.
    #[arg(long, default_value_t = 8)]
    pub agents: usize,
    /// Episodes per drone, one after another in the same video.
    #[arg(long, default_value_t = 1)]
    pub episodes: usize,
    /// Seed of the spawn positions.
    #[arg(long, default_value_t = 12345)]
    pub seed: u64,
    /// The drone whose view is shown (the next one still flying once it ends).
    #[arg(long, default_value_t = 0)]
    pub focus: usize,
    /// Frames (actions) per second of the video.
    #[arg(long, default_value_t = 8)]
    pub fps: u16,
    /// Output file (.gif).
    #[arg(long)]
    pub out: PathBuf,
    /// Also write one frame as a PNG: the frame of action step 20 of the
    /// first episode (or its last, if shorter).
    #[arg(long)]
    pub still: Option<PathBuf>,
    /// Print one JSON object as the last line.
    #[arg(long)]
    pub json: bool,
}

pub fn run(a: PlayArgs) -> Result<()> {
    if a.agents == 0 || a.episodes == 0 || a.fps == 0 || a.fps > 100 {
        bail!("--agents and --episodes must be positive, --fps in 1..=100");
    }
    if a.focus >= a.agents {
        bail!("--focus {} names no drone (there are {})", a.focus, a.agents);
    }
    if a.out.extension().and_then(|e| e.to_str()) != Some("gif") {
        bail!("--out {}: only .gif videos are written", a.out.display());
    }
    // Either network, as the checkpoint's header says (shapes, memory).
    let net = PolicyNet::load(&a.checkpoint)?;
    let sim = sim_config(&a, &net)?;
    let arena = Arena::load(&a.arena)?;
    let start = Instant::now();
    let file = std::fs::File::create(&a.out)
        .with_context(|| format!("cannot write {}", a.out.display()))?;
    let mut gif = gif::Encoder::new(
        std::io::BufWriter::new(file),
        view::WIDTH as u16,
        view::HEIGHT as u16,
        &view::palette(),
    )?;
    gif.set_repeat(gif::Repeat::Infinite)?;
    let delay = (100 / a.fps).max(1);
    let mut rec = Recording { gif, delay, frames: 0, goals: 0, crashes: 0, still_written: false };
    for round in 0..a.episodes {
        rec.round(&a, (&net, &sim), &arena, round)?;
    }
    let Recording { gif, frames, goals, crashes, .. } = rec;
    drop(gif);
    let bytes = std::fs::metadata(&a.out).map(|m| m.len()).unwrap_or(0);
    let secs = start.elapsed().as_secs_f64();
    let episodes = a.agents * a.episodes;
    println!(
        "{}: {frames} frames of {episodes} episodes ({goals} reached the goal, {crashes} collided) in {secs:.1} s, {:.1} MB",
        a.out.display(),
        bytes as f64 / 1e6
    );
    if a.json {
        println!(
            "{}",
            serde_json::json!({ "out": a.out.display().to_string(), "frames": frames, "episodes": episodes, "goals": goals, "collisions": crashes, "seconds": secs, "bytes": bytes })
        );
    }
    Ok(())
}

/// The simulator every round flies: `--agents` drones, and what the
/// checkpoint's header says it was trained with (a goal, the hold action,
/// its frames, its camera; the goal's default settings) and its run's
/// camera map.
fn sim_config(a: &PlayArgs, net: &PolicyNet) -> Result<SimConfig> {
    let shapes = net.shapes();
    let mut cfg = SimConfig {
        agents: a.agents,
        frames: shapes.frames,
        frame_stride: shapes.stride,
        camera: rotorhive_roles::config::camera::checkpoint_camera(&a.checkpoint)?,
        hold_action: shapes.actions > rotorhive_msg::NUM_ACTIONS,
        ..SimConfig::default()
    };
    cfg.goal.enabled = shapes.goal();
    let (map, tracks) = crate::eval::memory_of(&a.checkpoint)?;
    cfg.map = map.unwrap_or_default();
    cfg.tracks = tracks.unwrap_or_default();
    Ok(cfg)
}

/// The video being written and what it has shown so far.
struct Recording<W: std::io::Write> {
    gif: gif::Encoder<W>,
    /// Hundredths of a second per frame.
    delay: u16,
    frames: usize,
    goals: usize,
    crashes: usize,
    still_written: bool,
}

impl<W: std::io::Write> Recording<W> {
    /// Flies round `round` (`--agents` drones, one episode each, seeded
    /// `seed + round`) to its end, a frame per action step, following the
    /// focused drone and then the next one still flying.
    fn round(
        &mut self,
        a: &PlayArgs,
        (net, cfg): (&PolicyNet, &SimConfig),
        arena: &Arena,
        round: usize,
    ) -> Result<()> {
        let shapes = net.shapes();
        let mut env = VecEnv::new(cfg.clone(), arena.clone(), a.seed + round as u64)?;
        env.set_autoreset(Autoreset::Disabled);
        let mut tracks = Tracks::new(&env);
        let obs_len = env.obs_len();
        let mut canvas = Canvas::default();
        let mut focus = a.focus;
        // A recurrent network's states: zeros at the round's start (one
        // episode per drone, no resets within it).
        let mut state = Vec::new();
        for _ in 0..=env.config().max_steps {
            let q = net.q_values(env.observations(), &mut state)?;
            let na = shapes.actions;
            let actions: Vec<u8> =
                q.chunks_exact(na).map(|c| rotorhive_model::argmax(c) as u8).collect();
            let depth =
                &env.observations()[focus * obs_len..focus * obs_len + obs_len - shapes.scalars];
            let focus_q = &q[na * focus..na * focus + na];
            let shown =
                Focus { agent: focus, depth, q: Some(focus_q), action: Some(actions[focus]) };
            view::draw(&env, &tracks, shown, &mut canvas);
            write_frame(&mut self.gif, &canvas, self.delay)?;
            self.frames += 1;
            let still_due = self.frames == STILL_FRAME || tracks.all_ended();
            if let Some(p) =
                a.still.as_ref().filter(|_| round == 0 && !self.still_written && still_due)
            {
                write_png(&canvas, p)?;
                self.still_written = true;
            }
            if tracks.all_ended() {
                break;
            }
            env.step(&actions)?;
            for e in env.finished() {
                match e.done {
                    rotorhive_sim::Done::Goal => self.goals += 1,
                    rotorhive_sim::Done::Collision => self.crashes += 1,
                    _ => {}
                }
            }
            tracks.record(&env, true);
            if let Some(next) =
                (0..a.agents).map(|k| (focus + k) % a.agents).find(|i| !tracks.ended(*i))
            {
                focus = next;
            }
        }
        Ok(())
    }
}

/// The frame `--still` writes.
const STILL_FRAME: usize = 21;

fn write_png(canvas: &Canvas, path: &std::path::Path) -> Result<()> {
    let img = image::RgbImage::from_raw(view::WIDTH as u32, view::HEIGHT as u32, canvas.rgb())
        .context("a picture of the right size")?;
    img.save(path).with_context(|| format!("cannot write {}", path.display()))
}

fn write_frame<W: std::io::Write>(
    gif: &mut gif::Encoder<W>,
    canvas: &Canvas,
    delay: u16,
) -> Result<()> {
    let frame = gif::Frame {
        width: view::WIDTH as u16,
        height: view::HEIGHT as u16,
        delay,
        buffer: Cow::Borrowed(&canvas.px),
        ..gif::Frame::default()
    };
    gif.write_frame(&frame).context("cannot encode the video")
}
