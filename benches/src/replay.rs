//! `hive bench replay`: the replay role as its own process, fed by P
//! producer processes over shared memory and drained by this process acting
//! as the learner. Three phases: inserts alone (the memory fills before any
//! sampling starts), minibatch sampling alone, and both at once; for each
//! variant of the replay's settings (the insert limiter off and on, the
//! journal on and off). The top-level figures are the replay as the default
//! config runs it (uniform sampling, its journal) with the limiter off,
//! which would otherwise hold sampling to the insert rate.

use std::io::{BufRead, BufReader};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use crate::error::{Doing, Result, failed, usage};
use rotorhive_msg::{
    MinibatchHeader, PICK_WORDS, Pick, PriorityHeader, Shapes, Telemetry, TransitionHeader,
};
use rotorhive_roles::replay::minibatch_len;
use rotorhive_transport::{Channel, Hub, Ipc, services_of_run};
use serde_json::json;

const OBS_LEN: usize = Shapes::PAPER.obs_len();
const PACKED_LEN: usize = Shapes::PAPER.packed_len();

/// Transitions per producer message (one actor's batch for 50 agents).
const PER_MSG: usize = 50;

/// A producer: sends `batches` transition batches as fast as the replay
/// takes them, then prints the seconds it took.
pub fn producer(prefix: &str, index: usize, producers: usize, batches: usize) -> Result<()> {
    let hub = Hub::<Ipc>::new(prefix, &format!("bench-producer-{index}"))?;
    let mut tx = hub.sender::<u16, TransitionHeader>(
        &Channel::transitions(producers),
        PER_MSG * PACKED_LEN,
        Duration::from_secs(5),
    )?;
    // Valid packed transitions (action and done 0 or 1), as an actor sends.
    let mut src = vec![0u16; PER_MSG * PACKED_LEN];
    let obs = vec![0.5f32; OBS_LEN];
    for (i, t) in src.chunks_exact_mut(PACKED_LEN).enumerate() {
        Shapes::PAPER.pack(
            &obs,
            &obs,
            [(i % 2) as f32, 3.0, 0.0, rotorhive_msg::NO_EXPERT, 0.0],
            t,
        );
    }
    // A burst sent right after a publisher's creation can lose messages to
    // the subscriber made before it (iceoryx2 0.10, seen in `bench link`
    // too, not yet understood): let it settle, as an actor does while its
    // sim starts. The clock starts after.
    std::thread::sleep(Duration::from_millis(500));
    let t = Instant::now();
    for seq in 0..batches as u64 {
        tx.send_with(PER_MSG * PACKED_LEN, |h, out| {
            *h = TransitionHeader {
                actor: index as u32,
                count: PER_MSG as u32,
                seq,
                weight_version: 0,
            };
            out.copy_from_slice(&src);
        })?;
    }
    println!("{}", t.elapsed().as_secs_f64());
    Ok(())
}

struct Procs(Vec<Child>);

impl Drop for Procs {
    fn drop(&mut self) {
        for c in &mut self.0 {
            // SIGTERM, unless already reaped (its pid may be another's then).
            if matches!(c.try_wait(), Ok(None)) {
                let pid = rustix::process::Pid::from_child(c);
                let _ = rustix::process::kill_process(pid, rustix::process::Signal::TERM);
            }
        }
        for c in &mut self.0 {
            let _ = c.wait();
        }
    }
}

fn spawn_producers(prefix: &str, producers: usize, batches: usize) -> Result<Vec<Child>> {
    let exe = std::env::current_exe()?;
    (0..producers)
        .map(|i| {
            Command::new(&exe)
                .args([
                    "bench",
                    "replay-producer",
                    "--prefix",
                    prefix,
                    "--index",
                    &i.to_string(),
                    "--producers",
                    &producers.to_string(),
                    "--batches",
                    &batches.to_string(),
                ])
                .stdout(Stdio::piped())
                .spawn()
                .doing("starting a producer")
        })
        .collect()
}

/// Waits for producers and returns the longest time any of them took.
fn join_producers(children: Vec<Child>) -> Result<f64> {
    let mut worst = 0.0f64;
    for mut c in children {
        let mut line = String::new();
        BufReader::new(c.stdout.take().doing("producer stdout")?).read_line(&mut line)?;
        let status = c.wait()?;
        if !status.success() {
            failed!("a producer failed ({status})");
        }
        worst = worst
            .max(line.trim().parse::<f64>().doing_with(|| format!("producer printed {line:?}"))?);
    }
    Ok(worst)
}

/// A setting of the replay to measure.
struct Variant {
    name: &'static str,
    samples_per_insert: f64,
    journal: bool,
    /// Prioritized sampling, with this process sending a priority back for
    /// every row of every minibatch, as the learner does.
    prioritized: bool,
}

/// The settings measured, the default config's replay first.
fn variants() -> Vec<Variant> {
    let variant = |name, samples_per_insert, journal, prioritized| Variant {
        name,
        samples_per_insert,
        journal,
        prioritized,
    };
    let mut variants = vec![
        variant("uniform, journal on, limiter off", 0.0, true, false),
        variant("prioritized + feedback, journal on, limiter off", 0.0, true, true),
        variant("uniform, journal off, limiter off", 0.0, false, false),
        variant("prioritized + feedback, journal off, limiter off", 0.0, false, true),
        variant("uniform, journal on, limiter on (samples_per_insert = 1)", 1.0, true, false),
        variant("prioritized + feedback, journal on, limiter on", 1.0, true, true),
    ];
    if rotorhive_roles::Config::default().replay.prioritized {
        variants.swap(0, 1);
    }
    variants
}

/// One setting's rates: a row of the JSON's `rows`.
#[derive(Debug, serde::Serialize)]
struct ReplayRow {
    name: &'static str,
    samples_per_insert: f64,
    journal: bool,
    prioritized: bool,
    /// Priorities the replay says it applied.
    priority_updates: u64,
    inserts_per_s: f64,
    samples_per_s: f64,
    together_inserts_per_s: f64,
    together_samples_per_s: f64,
}

pub fn run(producers: usize, seconds: f64, json_out: bool) -> Result<()> {
    if producers == 0 || !(seconds.is_finite() && seconds > 0.0) {
        usage!("--producers and --seconds must be positive");
    }
    let mut rows = Vec::new();
    println!(
        "{:<58} {:>16} {:>16} {:>22} {:>22}",
        "variant",
        "inserts/s alone",
        "samples/s alone",
        "inserts/s (together)",
        "samples/s (together)"
    );
    for v in &variants() {
        let r = measure(producers, seconds, v)?;
        println!(
            "{:<58} {:>16.0} {:>16.0} {:>22.0} {:>22.0}",
            v.name,
            r.inserts_per_s,
            r.samples_per_s,
            r.together_inserts_per_s,
            r.together_samples_per_s
        );
        rows.push(r);
    }
    println!(
        "{producers} producers; packed transitions of {PACKED_LEN} u16 words ({:.1} KiB: 16-bit \
         depth), {PER_MSG} per message; minibatches of 32; the first row is the default config's \
         replay; cpprb (in-process, Python) on this machine: 538,000 inserts/s, 15,500 samples/s",
        PACKED_LEN as f64 * 2.0 / 1024.0
    );
    let top = &rows[0];
    let out = json!({
        "bench": "replay",
        "producers": producers,
        "inserts_per_s": top.inserts_per_s,
        "samples_per_s": top.samples_per_s,
        "together_inserts_per_s": top.together_inserts_per_s,
        "together_samples_per_s": top.together_samples_per_s,
        "transition_bytes": PACKED_LEN * 2,
        "batch": 32,
        "rows": rows,
    });
    if json_out {
        println!("{out}");
    }
    Ok(())
}

/// Runs one replay process with the setting `v` through the three phases.
fn measure(producers: usize, seconds: f64, v: &Variant) -> Result<ReplayRow> {
    let prefix = rotorhive_transport::unique_prefix("bench-replay");
    let dir = std::env::temp_dir().join(&prefix);
    std::fs::create_dir_all(&dir)?;
    // Phase 1 fills the memory exactly: no sampling can start before it is full.
    let per_producer = 600usize;
    let capacity = producers * per_producer * PER_MSG;
    let cfg_path = replay_config(&dir, producers, capacity, v)?;
    let hub = Hub::<Ipc>::new(&prefix, "bench-learner")?;
    let mut rx = hub.receiver::<u16, MinibatchHeader>(&Channel::minibatches(4))?;
    let mut prio_tx = if v.prioritized {
        Some(hub.sender::<u16, PriorityHeader>(
            &Channel::priorities(4),
            32 * PICK_WORDS,
            Duration::from_millis(50),
        )?)
    } else {
        None
    };
    // What the learner does with a minibatch here: read its picks and send
    // each row a new priority (a made-up |TD error| that varies by row).
    let mut feed_back =
        move |m: &rotorhive_transport::Msg<Ipc, u16, MinibatchHeader>| -> Result<()> {
            let Some(tx) = &mut prio_tx else {
                return Ok(());
            };
            let tail = &m.payload()[32 * PACKED_LEN..];
            let seq = m.user_header().seq;
            tx.send_with(32 * PICK_WORDS, |h, out| {
                *h = PriorityHeader { count: 32, reserved: 0, seq };
                for (w, o) in tail.chunks_exact(PICK_WORDS).zip(out.chunks_exact_mut(PICK_WORDS)) {
                    let p = Pick::unpack(w);
                    Pick { value: (p.row % 97) as f32 * 0.01, ..p }.pack(o);
                }
            })?;
            Ok(())
        };
    let mut tel = hub.receiver::<u8, Telemetry>(&Channel::telemetry(2 * producers + 2))?;
    let procs = Procs(vec![start_replay(&cfg_path, &prefix, &dir)?]);
    let result = (|| -> Result<ReplayRow> {
        let inserts_per_s = fill(&prefix, producers, per_producer, &mut tel, &mut rx)?;
        // Phase 2: sampling alone (the memory is full now).
        let (n, secs) = sample_for(&mut rx, seconds, &mut feed_back)?;
        let samples_per_s = n as f64 / secs;
        // Phase 3: both at once (producers keep sending while we sample).
        let batches = ((inserts_per_s * seconds) / (PER_MSG * producers) as f64).max(10.0) as usize;
        let (got, mixed_secs) = together(&prefix, producers, batches, &mut rx, &mut feed_back)?;
        let mixed_inserts = (batches * PER_MSG * producers) as f64 / mixed_secs;
        // The replay applied the priorities sent back (its own count).
        let priority_updates = priority_updates(&mut tel)?;
        if v.prioritized && priority_updates == 0 {
            failed!("the replay applied none of the priorities sent back");
        }
        let mixed_samples = got as f64 / mixed_secs;
        Ok(ReplayRow {
            name: v.name,
            samples_per_insert: v.samples_per_insert,
            journal: v.journal,
            prioritized: v.prioritized,
            priority_updates,
            inserts_per_s,
            samples_per_s,
            together_inserts_per_s: mixed_inserts,
            together_samples_per_s: mixed_samples,
        })
    })();
    drop(procs);
    drop(feed_back);
    drop(rx);
    drop(tel);
    drop(hub);
    let _ = std::fs::remove_dir_all(&dir);
    let out = result?;
    let left = services_of_run::<Ipc>(&prefix);
    if !left.is_empty() {
        failed!("shared memory left behind: {left:?}");
    }
    Ok(out)
}

/// What the bench's learner does with a minibatch.
type FeedBack<'a> =
    dyn FnMut(&rotorhive_transport::Msg<Ipc, u16, MinibatchHeader>) -> Result<()> + 'a;

/// Phase 2: minibatches taken for `secs` (the memory full, no inserts);
/// returns how many and the seconds it took.
fn sample_for(
    rx: &mut rotorhive_transport::Receiver<Ipc, u16, MinibatchHeader>,
    secs: f64,
    feed_back: &mut FeedBack<'_>,
) -> Result<(u64, f64)> {
    let t = Instant::now();
    let mut n = 0u64;
    while t.elapsed().as_secs_f64() < secs {
        if let Some(m) = rx.recv_timeout(Duration::from_millis(500))? {
            if m.payload().len() != minibatch_len(Shapes::PAPER.packed_len(), 32) {
                failed!("minibatch of the wrong size");
            }
            feed_back(&m)?;
            n += 1;
        }
    }
    Ok((n, t.elapsed().as_secs_f64()))
}

/// Phase 3: minibatches taken while `producers` send `batches` batches
/// each; returns how many and the seconds the producers took.
fn together(
    prefix: &str,
    producers: usize,
    batches: usize,
    rx: &mut rotorhive_transport::Receiver<Ipc, u16, MinibatchHeader>,
    feed_back: &mut FeedBack<'_>,
) -> Result<(u64, f64)> {
    let mut kids = spawn_producers(prefix, producers, batches)?;
    let t = Instant::now();
    let mut got = 0u64;
    while !kids.iter_mut().all(|c| matches!(c.try_wait(), Ok(Some(_)))) {
        if let Some(m) = rx.recv_timeout(Duration::from_millis(100))? {
            feed_back(&m)?;
            got += 1;
        }
    }
    let secs = t.elapsed().as_secs_f64();
    join_producers(kids)?;
    Ok((got, secs))
}

/// The replay's config for `producers` producers filling `capacity`.
fn replay_config(
    dir: &std::path::Path,
    producers: usize,
    capacity: usize,
    v: &Variant,
) -> Result<std::path::PathBuf> {
    let cfg = format!(
        "[sim]\nenvs = {producers}\n[replay]\ncapacity = {capacity}\nmin_fill = {capacity}\nbatch = 32\nprefetch = 4\nsamples_per_insert = {:?}\nsnapshot_every_s = {}\nprioritized = {}\n",
        v.samples_per_insert,
        if v.journal { "60.0" } else { "0.0" },
        v.prioritized
    );
    let cfg_path = dir.join("config.toml");
    std::fs::write(&cfg_path, cfg)?;
    Ok(cfg_path)
}

/// The replay role as a process of run `prefix`.
fn start_replay(
    cfg_path: &std::path::Path,
    prefix: &str,
    dir: &std::path::Path,
) -> Result<std::process::Child> {
    Command::new(std::env::current_exe()?)
        .arg("replay")
        .arg(cfg_path)
        .args(["--prefix", prefix, "--run-dir"])
        .arg(dir)
        .stdout(Stdio::null())
        .spawn()
        .doing("starting the replay role")
}

/// Phase 1: once the replay reports, `producers` fill its memory
/// (`per_producer` batches each) and it confirms every transition; returns
/// the inserts per second.
fn fill(
    prefix: &str,
    producers: usize,
    per_producer: usize,
    tel: &mut rotorhive_transport::Receiver<Ipc, u8, Telemetry>,
    rx: &mut rotorhive_transport::Receiver<Ipc, u16, MinibatchHeader>,
) -> Result<f64> {
    let capacity = producers * per_producer * PER_MSG;
    // The replay is ready once it reports (after allocating its memory).
    let t = Instant::now();
    while tel.recv_timeout(Duration::from_millis(100))?.is_none() {
        if t.elapsed() > Duration::from_secs(30) {
            failed!("the replay process did not start");
        }
    }
    // Phase 1: inserts alone.
    let wall = join_producers(spawn_producers(prefix, producers, per_producer)?)?;
    let inserts_per_s = capacity as f64 / wall;
    // Every transition sent arrived: the replay's own count says so (its
    // telemetry comes once a second, and minibatches nobody reads would
    // hold it up: they are taken and dropped meanwhile).
    let t = Instant::now();
    let mut inserted = 0;
    while inserted < capacity as u64 && t.elapsed() < Duration::from_secs(30) {
        if let Some(m) = tel.recv_timeout(Duration::from_millis(50))? {
            inserted = inserted.max(m.user_header().work);
        }
        while rx.try_recv()?.is_some() {}
    }
    if inserted != capacity as u64 {
        failed!("the replay inserted {inserted} of {capacity} transitions sent");
    }
    Ok(inserts_per_s)
}

/// The priority updates the replay reports having applied (its telemetry
/// over 1.5 s).
fn priority_updates(tel: &mut rotorhive_transport::Receiver<Ipc, u8, Telemetry>) -> Result<u64> {
    let mut priority_updates = 0u64;
    let t = Instant::now();
    while t.elapsed() < Duration::from_millis(1500) {
        if let Some(m) = tel.recv_timeout(Duration::from_millis(100))?
            && m.user_header().role == rotorhive_msg::RoleKind::Replay as u32
        {
            priority_updates =
                priority_updates.max(m.user_header().learning.priority_updates as u64);
        }
    }
    Ok(priority_updates)
}
