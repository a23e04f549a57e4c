//! `hive replay`: the FIFO replay memory. Inserts every transition batch the
//! actors publish (checking each actor's sequence numbers for loss) and keeps
//! the learner's minibatch queue full once the memory holds `min_fill`.

use std::time::{Duration, Instant};

use crate::error::{Doing, Result};
use rotorhive_msg::{
    MinibatchHeader, PICK_WORDS, PriorityHeader, Receipt, ReplayStage, RoleKind, RowLayout,
    SeqTracker, Telemetry, TransitionHeader,
};
use rotorhive_replay::{Acted, Journal, Pick, Replay};
use rotorhive_transport::{Channel, TransportError};

use rotorhive_transport::Service;

use crate::ctx::{Counters, Ctx, roles_of};

mod scheduled;

/// The replay role's state: the memory and its journal, the channels in and
/// out, its counters and the learner's priority feedback.
struct Memory<'a, S: Service> {
    cfg: &'a crate::config::Config,
    hub: &'a rotorhive_transport::Hub<S>,
    mem: Replay,
    journal: Option<Journal>,
    /// The teacher's demonstrations, kept apart (`teacher.demo_agents`).
    demos: Option<Demos>,
    rx: rotorhive_transport::Receiver<S, u16, TransitionHeader>,
    tx: rotorhive_transport::Sender<S, u16, MinibatchHeader>,
    tel: Counters<S>,
    receipts: Receipts<S>,
    seq_log: SeqLog,
    prio: Feedback<S>,
    picks: Vec<Pick>,
    last_sync: Instant,
    /// What a row holds (transitions, or sequences), and `min_fill` in
    /// rows: both from the config, once.
    rows: RowLayout,
    min_fill: usize,
    /// Minibatches of demonstrations alone first (`teacher.pretrain_updates`;
    /// none where the memory was restored: the run goes on).
    pretrain: u64,
}

/// Runs the replay memory until the run stops.
pub fn run<S: Service>(cx: Ctx<'_, S>) -> Result<()> {
    let (cfg, hub) = (cx.cfg, cx.hub);
    let r = &cfg.replay;
    let (mut mem, journal) = open_memory(cfg, cx.run_dir)?;
    let demos = open_demos(cfg, cx.run_dir)?;
    if r.prioritized {
        mem.set_prioritized(r.priority_alpha, r.priority_eps);
    }
    let prio = Feedback::new(hub, cfg)?;
    let mut rx = hub.receiver::<u16, TransitionHeader>(&Channel::transitions(cfg.sim.envs))?;
    // Transitions are throughput, not latency: sleep at once when idle.
    rx.set_spin(Duration::ZERO);
    // A full learner queue is normal (the learner is busy): the send gives up
    // after a millisecond and the replay goes back to inserting.
    let tx = hub.sender::<u16, MinibatchHeader>(
        &Channel::minibatches(r.prefetch),
        minibatch_len(cfg.row_len(), r.batch),
        Duration::from_millis(1),
    )?;
    let tel = crate::ctx::counters(hub, RoleKind::Replay, 0, roles_of(cfg))?;
    let receipts = Receipts::new(hub, cfg.sim.envs)?;
    let seq_log = SeqLog::open(cx.run_dir, hub.prefix(), cfg.sim.envs);
    let picks = vec![Pick::default(); r.batch];
    let last_sync = Instant::now();
    let pretrain = if mem.is_empty() { cfg.teacher.pretrain_updates() } else { 0 };
    let mut m = Memory {
        cfg,
        hub,
        mem,
        journal,
        demos,
        rx,
        tx,
        tel,
        receipts,
        seq_log,
        prio,
        picks,
        last_sync,
        rows: cfg.rows(),
        min_fill: cfg.replay_rows().1,
        pretrain,
    };
    if cfg.deterministic {
        m.run_scheduled()?
    } else {
        m.run_free()?
    }
    if let Some(j) = &m.journal {
        j.sync()?;
    }
    if let Some(j) = m.demos.as_ref().and_then(|d| d.journal.as_ref()) {
        j.sync()?;
    }
    m.tel.tick(true, Telemetry::beat);
    Ok(())
}

impl<S: Service> Memory<'_, S> {
    /// The free-running replay: inserts what comes, and samples while the
    /// learner takes minibatches and the sample limit allows.
    fn run_free(&mut self) -> Result<()> {
        // Actors of other hosts come through the link with indexes after ours.
        // This host's actors only: another host's gaps are its link's to
        // count (the head's link takes each host's batches in order).
        let mut next_seq = self.seq_log.resume();
        let mut mb_seq = 0u64;
        let mut backoff_until = Instant::now();
        let mut limit = SampleLimit::new(self.cfg);
        while !self.hub.shutdown_requested() {
            self.prio.apply_all(&mut self.mem, &mut self.tel.sample.learning)?;
            let mut got = false;
            let t = Instant::now();
            // A bounded number of batches per loop, so minibatches keep flowing
            // to the learner even while producers flood the memory.
            for _ in 0..INGEST_PER_LOOP {
                let Some(m) = self.rx.try_recv().doing("receiving transitions")? else {
                    break;
                };
                let lost = &mut self.tel.sample.lost;
                let seen = (&mut next_seq, lost);
                let stores = Stores {
                    mem: &mut self.mem,
                    journal: self.journal.as_mut(),
                    demos: self.demos.as_mut(),
                };
                ingest(&m, self.rows, stores, seen)?;
                self.receipts.took(m.user_header());
                self.seq_log.record(m.user_header());
                got = true;
            }
            self.tel.sample.time_stage(ReplayStage::Insert, t);
            // Pre-training waits for a demonstration to draw.
            let ready = self.ready() && (mb_seq >= self.pretrain || self.holds_demos());
            let mut sent = false;
            let allowed = limit.may_send(ready, mb_seq, self.pretrain, self.inserted());
            if allowed && Instant::now() >= backoff_until {
                match self.send_fresh(mb_seq)? {
                    true => {
                        mb_seq += 1;
                        sent = true;
                    }
                    false => backoff_until = Instant::now() + Duration::from_millis(2),
                }
            }
            self.housekeep(mb_seq)?;
            if !got && !sent {
                let t = Instant::now();
                // Nothing to do: sleep on the transitions channel.
                let wait = if ready { Duration::from_millis(2) } else { crate::ctx::POLL };
                if let Some(m) = self.rx.recv_timeout(wait).doing("waiting for transitions")? {
                    let lost = &mut self.tel.sample.lost;
                    let seen = (&mut next_seq, lost);
                    let stores = Stores {
                        mem: &mut self.mem,
                        journal: self.journal.as_mut(),
                        demos: self.demos.as_mut(),
                    };
                    ingest(&m, self.rows, stores, seen)?;
                    self.receipts.took(m.user_header());
                    self.seq_log.record(m.user_header());
                }
                self.tel.sample.time_stage(ReplayStage::Idle, t);
            }
        }
        Ok(())
    }

    /// The memories as [`store`] fills them.
    fn stores(&mut self) -> Stores<'_> {
        Stores { mem: &mut self.mem, journal: self.journal.as_mut(), demos: self.demos.as_mut() }
    }

    /// Transitions inserted so far, demonstrations included.
    fn inserted(&self) -> u64 {
        self.mem.inserted() + self.demos.as_ref().map_or(0, |d| d.mem.inserted())
    }

    /// Whether the memory holds enough to sample: `min_fill` transitions
    /// (demonstrations included) and a minibatch of the student's.
    fn ready(&self) -> bool {
        let r = &self.cfg.replay;
        let demos = self.demos.as_ref().map_or(0, |d| d.mem.len());
        self.mem.len() + demos >= self.min_fill.max(r.batch) && self.mem.len() >= r.batch
    }

    /// Whether the demonstrations' reservoir holds any.
    fn holds_demos(&self) -> bool {
        self.demos.as_ref().is_some_and(|d| !d.mem.is_empty())
    }

    /// Minibatch `seq`'s rows drawn from the demonstrations, and the
    /// teacher's weight ([`demo_rows`]).
    fn demo_rows(&self, seq: u64) -> (usize, f32) {
        let held = self.holds_demos();
        let plan = DemoPlan { pretrain: self.pretrain, batch: self.cfg.replay.batch };
        demo_rows(&self.cfg.teacher, plan, seq, (held, self.inserted()))
    }

    /// Samples minibatch `seq` straight into a loan and sends it; false when
    /// the learner's queue stayed full.
    fn send_fresh(&mut self, seq: u64) -> Result<bool> {
        let (batch, beta) = (self.cfg.replay.batch, self.cfg.replay.priority_beta);
        let t = Instant::now();
        let (demo_rows, teacher) = self.demo_rows(seq);
        let (mem, picks) = (&mut self.mem, &mut self.picks);
        let demos = self.demos.as_mut().map(|d| &mut d.mem);
        let res = self.tx.send_with(minibatch_len(self.rows.packed_len(), batch), |h, out| {
            let acted = sample(mem, demos, demo_rows, out, picks, beta);
            *h = minibatch_header(batch, seq, acted, (demo_rows, teacher));
        });
        self.tel.sample.time_stage(ReplayStage::Sample, t);
        sent_or_stalled(res)
    }

    /// Syncs the journal when due and publishes the receipts and counters.
    fn housekeep(&mut self, minibatches: u64) -> Result<()> {
        sync_due(self.journal.as_ref(), &mut self.last_sync, self.cfg)?;
        self.receipts.publish();
        self.tel.sample.work = self.mem.inserted();
        self.tel.sample.work2 = minibatches;
        self.tel.sample.value_milli = self.mem.len() as i64;
        // In transitions: with memory a row is a sequence of trained steps.
        let per_row = self.cfg.steps_per_row() as u64;
        self.tel.sample.teacher.demo_transitions =
            self.demos.as_ref().map_or(0, |d| d.mem.len()) as u64 * per_row;
        self.tel.tick(false, Telemetry::beat);
        Ok(())
    }
}

/// Where the free-running replay's view of its own host's actors'
/// sequence numbers stands, kept in `RUN_DIR/replay-seq` as it goes (the
/// run's prefix hashed, then each actor's next batch plus one, 0 for none;
/// one 8-byte write a batch): a replay that dies and is started again in
/// the same run takes it up, so what its predecessor's queue held shows as
/// a gap at each actor's next batch and is counted lost. A file of another
/// run (another prefix) is not taken up.
struct SeqLog {
    file: Option<std::fs::File>,
    next: Vec<Option<u64>>,
}

impl SeqLog {
    /// The log of run `prefix` for `envs` actors in `run_dir` (none without
    /// one: a thread run), taking up what a predecessor of this run wrote.
    fn open(run_dir: Option<&std::path::Path>, prefix: &str, envs: usize) -> Self {
        use std::hash::{Hash, Hasher};
        let mut h = std::collections::hash_map::DefaultHasher::new();
        prefix.hash(&mut h);
        let tag = h.finish().to_le_bytes();
        let Some(path) = run_dir.map(|d| d.join("replay-seq")) else {
            return Self { file: None, next: vec![None; envs] };
        };
        let old = std::fs::read(&path).unwrap_or_default();
        let next = match old.len() == 8 * (envs + 1) && old[..8] == tag {
            true => old[8..]
                .chunks_exact(8)
                .map(|c| u64::from_le_bytes(c.try_into().unwrap_or_default()).checked_sub(1))
                .collect(),
            false => vec![None; envs],
        };
        if next.iter().any(Option::is_some) {
            tracing::info!("taking up the sequence numbers of this run's earlier replay");
        }
        let mut bytes = tag.to_vec();
        for n in &next {
            bytes.extend_from_slice(&n.map_or(0, |n: u64| n + 1).to_le_bytes());
        }
        let file = std::fs::File::create(&path)
            .and_then(|mut f| std::io::Write::write_all(&mut f, &bytes).map(|()| f))
            .map_err(|e| tracing::warn!("cannot keep {}: {e}", path.display()))
            .ok();
        Self { file, next }
    }

    /// The tracker to go on with.
    fn resume(&self) -> SeqTracker {
        SeqTracker::resume(self.next.clone())
    }

    /// Batch `h` was taken (another host's is its link's to track).
    fn record(&self, h: &TransitionHeader) {
        use std::os::unix::fs::FileExt;
        if let Some(f) = &self.file
            && (h.actor as usize) < self.next.len()
        {
            let at = 8 * (h.actor as u64 + 1);
            let _ = f.write_all_at(&h.seq.saturating_add(2).to_le_bytes(), at);
        }
    }
}

/// The replay sends a receipt at most this often.
const RECEIPT_EVERY: Duration = Duration::from_millis(1);

/// The replay's receipts for other hosts' batches to its host's link
/// ([`Receipt`]): the head acknowledges a worker's batch once it is here,
/// not when the replay's queue took it.
pub struct Receipts<S: Service> {
    out: rotorhive_transport::Periodic<S, Receipt>,
    /// This host's environments: actors from here on are other hosts'.
    local: usize,
    /// Batches taken at the last receipt sent, and when it went.
    sent: u64,
    sent_at: Instant,
}

impl<S: Service> Receipts<S> {
    /// A new incarnation's receipts, for a host of `local` environments
    /// (the first, for no batch, goes at once).
    pub fn new(hub: &rotorhive_transport::Hub<S>, local: usize) -> Result<Self> {
        let first = Receipt { incarnation: rotorhive_transport::fresh_id(), ..Receipt::default() };
        let mut out = rotorhive_transport::Periodic::new(hub, &Channel::receipts(), first)
            .doing("opening the receipts channel")?;
        out.send(first);
        Ok(Self { out, local, sent: 0, sent_at: Instant::now() })
    }

    /// Takes note of a batch taken off the transitions channel.
    pub fn took(&mut self, h: &TransitionHeader) {
        if h.actor as usize >= self.local {
            self.out.sample.took(h);
        }
    }

    /// Sends the receipt when it covers new batches (at most every
    /// millisecond: the link reads them no more often).
    pub fn publish(&mut self) {
        if self.out.sample.batches != self.sent && self.sent_at.elapsed() >= RECEIPT_EVERY {
            (self.sent, self.sent_at) = (self.out.sample.batches, Instant::now());
            self.out.send(self.out.sample);
        }
    }
}

/// A send's outcome: true when sent, false when the receiver's queue stayed
/// full (a stall is normal back-pressure), an error otherwise.
fn sent_or_stalled(res: std::result::Result<(), TransportError>) -> Result<bool> {
    match res {
        Ok(()) => Ok(true),
        Err(TransportError::Stalled { .. }) => Ok(false),
        Err(e) => Err(e).doing("sending a minibatch"),
    }
}

/// Words of a minibatch message of `batch` rows: the packed rows, then a
/// [`Pick`] per row.
pub fn minibatch_len(row_len: usize, batch: usize) -> usize {
    batch * (row_len + PICK_WORDS)
}

/// Samples a minibatch into a message's payload: the rows (the first
/// `demo_rows` from the demonstrations, the rest from the student's
/// memory), then each row's pick (its place and importance weight).
fn sample(
    mem: &mut Replay,
    demos: Option<&mut Replay>,
    demo_rows: usize,
    out: &mut [u16],
    picks: &mut [Pick],
    beta: f64,
) -> Acted {
    let w = mem.width();
    let (rows, tail) = out.split_at_mut(picks.len() * w);
    let (demo_out, own) = rows.split_at_mut(demo_rows * w);
    let (demo_picks, own_picks) = picks.split_at_mut(demo_rows);
    let mut acted = mem.sample_into(own, own_picks, beta);
    if let Some(d) = demos.filter(|_| demo_rows > 0) {
        let a = d.sample_into(demo_out, demo_picks, beta);
        acted.known += a.known;
        acted.version_sum += a.version_sum;
    }
    for (p, w) in picks.iter().zip(tail.chunks_exact_mut(PICK_WORDS)) {
        p.pack(w);
    }
    acted
}

/// Prioritized replay's feedback: the learner's new priorities, one
/// message per minibatch. Free-running, they are applied as they come; a
/// deterministic run applies them in minibatch order, exactly those of
/// minibatches up to `prefetch` behind the one it samples next, so that
/// what it samples does not depend on timing.
struct Feedback<S: Service> {
    rx: Option<rotorhive_transport::Receiver<S, u16, PriorityHeader>>,
    /// Feedback that arrived ahead of its turn (deterministic runs).
    held: std::collections::BTreeMap<u64, Vec<u16>>,
    /// Minibatches whose feedback has been applied (deterministic runs).
    applied: u64,
    lag: u64,
}

impl<S: Service> Feedback<S> {
    fn new(hub: &rotorhive_transport::Hub<S>, cfg: &crate::config::Config) -> Result<Self> {
        let rx = if cfg.replay.prioritized {
            Some(hub.receiver::<u16, PriorityHeader>(&Channel::priorities(cfg.replay.prefetch))?)
        } else {
            None
        };
        Ok(Self { rx, held: Default::default(), applied: 0, lag: cfg.replay.prefetch as u64 })
    }

    /// Applies every priority that has arrived (free-running).
    fn apply_all(&mut self, mem: &mut Replay, counts: &mut rotorhive_msg::Learning) -> Result<()> {
        let Some(rx) = &mut self.rx else {
            return Ok(());
        };
        while let Some(m) = rx.try_recv().doing("receiving priorities")? {
            apply(mem, m.payload(), counts);
        }
        Ok(())
    }

    /// A deterministic run, before it samples minibatch `next`: the
    /// feedback of every minibatch before `next − prefetch`, applied in
    /// order. False while some of it has not arrived yet.
    fn ready_for(
        &mut self,
        next: u64,
        mem: &mut Replay,
        counts: &mut rotorhive_msg::Learning,
    ) -> Result<bool> {
        let Some(rx) = &mut self.rx else {
            return Ok(true);
        };
        while let Some(m) = rx.try_recv().doing("receiving priorities")? {
            self.held.insert(m.user_header().seq, m.payload().to_vec());
        }
        let need = next.saturating_sub(self.lag);
        while self.applied < need {
            let Some(words) = self.held.remove(&self.applied) else {
                return Ok(false);
            };
            apply(mem, &words, counts);
            self.applied += 1;
        }
        Ok(true)
    }
}

/// Applies one priorities message, counting what was applied and what was
/// stale (a row overwritten since, or a pick that is not a row).
fn apply(mem: &mut Replay, words: &[u16], counts: &mut rotorhive_msg::Learning) {
    for w in words.chunks_exact(PICK_WORDS) {
        if mem.set_priority(&Pick::unpack(w)) {
            counts.priority_updates += 1;
        } else {
            counts.stale_priorities += 1;
        }
    }
}

/// The teacher's demonstrations, apart from the student's transitions (which
/// never overwrite them), and their journal.
struct Demos {
    mem: Replay,
    journal: Option<Journal>,
}

/// The demonstrations' reservoir of a run whose teacher flies agents,
/// written through to RUN_DIR/replay-demo.bin as the memory is.
fn open_demos(
    cfg: &crate::config::Config,
    run_dir: Option<&std::path::Path>,
) -> Result<Option<Demos>> {
    let t = &cfg.teacher;
    if !t.demos() {
        return Ok(None);
    }
    // With memory a row is a sequence: the capacity counts its trained
    // steps, as the memory's does.
    let (width, seed) = (cfg.row_len(), crate::streams::demos(cfg.seed));
    let rows = (t.demo_capacity / cfg.steps_per_row()).max(1);
    Ok(Some(match run_dir {
        Some(d) if cfg.replay.snapshot_every_s > 0.0 => {
            let (mem, j) = Journal::open(&d.join("replay-demo.bin"), rows, width, seed)
                .doing("restoring the demonstrations")?;
            Demos { mem, journal: Some(j) }
        }
        _ => Demos { mem: Replay::new(rows, width, seed), journal: None },
    }))
}

/// The memory, written through to RUN_DIR/replay.bin as it changes: a
/// restarted (or resumed) replay starts with every transition it had.
fn open_memory(
    cfg: &crate::config::Config,
    run_dir: Option<&std::path::Path>,
) -> Result<(Replay, Option<Journal>)> {
    let r = &cfg.replay;
    Ok(match run_dir {
        Some(d) if r.snapshot_every_s > 0.0 => {
            let (m, j) = Journal::open(
                &d.join("replay.bin"),
                cfg.replay_rows().0,
                cfg.row_len(),
                crate::streams::replay(cfg.seed),
            )
            .doing("restoring the replay memory")?;
            if !m.is_empty() {
                let what = if cfg.memory().is_some() { "sequences" } else { "transitions" };
                tracing::info!("replay restored {} {what} from {}", m.len(), j.path().display());
            }
            (m, Some(j))
        }
        _ => (
            Replay::new(cfg.replay_rows().0, cfg.row_len(), crate::streams::replay(cfg.seed)),
            None,
        ),
    })
}

/// The sample side of `replay.samples_per_insert` (the sims hold the insert
/// side): minibatches go out while the transitions sampled stay within
/// `samples_per_insert` times those inserted since sampling began, plus a
/// buffer. So a learner fed by too few agents waits for data instead of
/// replaying the same transitions over and over, as Reverb's
/// `SampleToInsertRatio` does. The buffer covers what the sims cannot see
/// yet (minibatches queued for the learner, updates not yet published), so
/// the two sides never wait on each other.
struct SampleLimit {
    per_insert: f64,
    batch: f64,
    buffer: f64,
    /// Transitions inserted when the first minibatch went out.
    base: Option<u64>,
}

impl SampleLimit {
    fn new(cfg: &crate::config::Config) -> Self {
        let r = &cfg.replay;
        let queued = (r.prefetch as u64 + cfg.learner.publish_every + 2) as f64;
        Self {
            per_insert: r.samples_per_insert,
            batch: r.batch as f64,
            buffer: 2.0 * queued * r.batch as f64,
            base: None,
        }
    }

    /// Whether minibatch `seq` (from 0, the first `pretrain` of them
    /// pre-training ones, which are not held to the ratio) may go out with
    /// `inserted` transitions in: never before the memory is `ready`, and
    /// the limit is asked only then (its first question fixes where
    /// sampling began).
    fn may_send(&mut self, ready: bool, seq: u64, pretrain: u64, inserted: u64) -> bool {
        ready && (seq < pretrain || self.allows(seq - pretrain, inserted))
    }

    /// Whether minibatch number `sent` (from 0) may go out; the first call
    /// fixes where sampling began.
    fn allows(&mut self, sent: u64, inserted: u64) -> bool {
        let base = *self.base.get_or_insert(inserted);
        self.per_insert <= 0.0
            || (sent + 1) as f64 * self.batch
                <= self.per_insert * inserted.saturating_sub(base) as f64 + self.buffer
    }
}

/// Counts, in transitions, a gap in the batch's actor's sequence numbers
/// (estimated at this batch's size; a restarted actor starts again at 0,
/// which is not loss) and its corrupt transitions; true
/// when the batch is clean (a batch with any corrupt transition, or whose
/// length is not whole transitions, is not stored: poison never reaches the
/// learner).
fn check<S: Service>(
    m: &rotorhive_transport::Msg<S, u16, TransitionHeader>,
    rows: RowLayout,
    next_seq: &mut SeqTracker,
    lost: &mut u64,
) -> bool {
    let h = m.user_header();
    *lost += next_seq.observe(h.actor as usize, h.seq).saturating_mul(h.count as u64);
    let bad = rows.corrupt_rows(m.payload());
    *lost += bad;
    let whole = m.payload().len().is_multiple_of(rows.packed_len());
    if !whole {
        *lost += (h.count as u64).max(1);
    }
    bad == 0 && whole
}

/// Transition batches taken per loop before the next minibatch is offered.
const INGEST_PER_LOOP: usize = 4;

/// Inserts one clean transition batch (and records it in the journal),
/// counting sequence gaps of its actor (a restarted actor starts again at 0,
/// which is not loss) and corrupt values; a corrupt batch is counted and
/// dropped.
fn ingest<S: Service>(
    m: &rotorhive_transport::Msg<S, u16, TransitionHeader>,
    rows: RowLayout,
    stores: Stores<'_>,
    (next_seq, lost): (&mut SeqTracker, &mut u64),
) -> Result<()> {
    if !check(m, rows, next_seq, lost) {
        return Ok(());
    }
    store(stores, rows, m.payload(), m.user_header().weight_version)
}

/// Syncs the journal to disk every `replay.snapshot_every_s`.
fn sync_due(
    journal: Option<&Journal>,
    last_sync: &mut Instant,
    cfg: &crate::config::Config,
) -> Result<()> {
    if let Some(j) = journal
        && last_sync.elapsed().as_secs_f64() >= cfg.replay.snapshot_every_s.max(1e-3)
    {
        j.sync()?;
        *last_sync = Instant::now();
    }
    Ok(())
}

/// Where [`store`] puts transitions: the memory and its journal, and the
/// demonstrations' reservoir where the run has one.
struct Stores<'a> {
    mem: &'a mut Replay,
    journal: Option<&'a mut Journal>,
    demos: Option<&'a mut Demos>,
}

impl Stores<'_> {
    fn reborrow(&mut self) -> Stores<'_> {
        Stores {
            mem: self.mem,
            journal: self.journal.as_deref_mut(),
            demos: self.demos.as_deref_mut(),
        }
    }
}

/// Inserts a batch of rows (transitions or sequences, as `rows` says)
/// acted with weight version `version` and records it in the journal; with
/// a reservoir, the demonstrations go there (each run of consecutive rows
/// of one kind in one insert).
fn store(stores: Stores<'_>, rows: RowLayout, batch: &[u16], version: u64) -> Result<()> {
    let Stores { mem, mut journal, demos } = stores;
    let w = mem.width();
    let Some(demos) = demos else {
        return insert(mem, journal, batch, version);
    };
    let mut it = batch.chunks_exact(w).enumerate().peekable();
    while let Some((start, first)) = it.next() {
        let demo = rows.is_demo(first);
        let mut end = start + 1;
        while it.next_if(|(_, r)| rows.is_demo(r) == demo).is_some() {
            end += 1;
        }
        let part = &batch[start * w..end * w];
        if demo {
            insert(&mut demos.mem, demos.journal.as_mut(), part, version)?;
        } else {
            insert(mem, journal.as_deref_mut(), part, version)?;
        }
    }
    Ok(())
}

/// Inserts transitions into one memory and records them in its journal.
fn insert(
    mem: &mut Replay,
    journal: Option<&mut Journal>,
    batch: &[u16],
    version: u64,
) -> Result<()> {
    if batch.is_empty() {
        return Ok(());
    }
    mem.insert_acted(batch, version);
    if let Some(j) = journal {
        j.record(mem, batch.len() / mem.width())?;
    }
    Ok(())
}

/// What decides a minibatch's demonstration rows besides the teacher's
/// section: the run's pre-training minibatches and its batch.
#[derive(Debug, Clone, Copy)]
struct DemoPlan {
    pretrain: u64,
    batch: usize,
}

/// Minibatch `seq`'s rows drawn from the demonstrations (none while the
/// reservoir is empty: `held`): all of them for the first `plan.pretrain`
/// (DQfD's pre-training), then `demo_batch_share` fading with the run's
/// `inserted` transitions; and the teacher's weight, the fade.
fn demo_rows(
    t: &crate::teacher::TeacherSection,
    plan: DemoPlan,
    seq: u64,
    (held, inserted): (bool, u64),
) -> (usize, f32) {
    let fade = t.fade(inserted);
    let rows = match () {
        _ if !held => 0,
        _ if seq < plan.pretrain => plan.batch,
        _ => (t.demo_batch_share * fade * plan.batch as f64).round() as usize,
    };
    (rows.min(plan.batch), fade as f32)
}

/// The header of minibatch `seq` of `batch` transitions just sampled, of
/// which `demo.0` demonstrations, with the teacher's weight `demo.1`.
fn minibatch_header(batch: usize, seq: u64, acted: Acted, demo: (usize, f32)) -> MinibatchHeader {
    MinibatchHeader {
        batch: batch as u32,
        acted: acted.known,
        seq,
        acted_version_sum: acted.version_sum,
        demo_rows: demo.0 as u32,
        teacher: demo.1,
    }
}

#[cfg(test)]
mod tests;
