//! Fresh layouts: an environment's generated lanes renewed one at a time
//! from the generator as training goes on, so a run trains on as many
//! layouts as it has time for instead of a fixed few.
//!
//! A thread of its own builds the next world whole (the new lane's arena,
//! the lanes side by side, the collision geometry and the CPU scene) while
//! the environment steps. The environment then retires the lane the next
//! layout replaces (no episode starts there), and once no agent is left in
//! it swaps the prebuilt world in between two steps: no episode is cut, no
//! agent moves (every other lane keeps its place), and the step path only
//! moves the built parts in (and uploads the scene with the wgpu renderer).
//! Which lane is renewed when depends only on the simulation, never on the
//! thread's timing: a run stays bit-reproducible (when a swap is due and
//! the world is not built yet, the step waits for it, and that wait is
//! counted).

use std::sync::Mutex;
use std::sync::mpsc::{Receiver, SyncSender, sync_channel};
use std::thread::JoinHandle;
use std::time::Instant;

use crate::arena::{Arena, ArenaError, Lanes};
use crate::geometry::Geometry;
use crate::render::Scene;
use crate::render::wgpu::GpuError;

use super::{Done, LanesError, Physics, PhysicsKind, VecEnv, gpu_scene};

/// The arena of renewal number `n` (0, 1, …): a layout never trained on
/// before (the caller's seeds keep it off every held-out one).
pub type LayoutMaker = Box<dyn FnMut(u64) -> Arena + Send>;

/// A world built off the step path for renewal `n`.
pub(crate) struct Built {
    pub(crate) n: u64,
    pub(crate) lanes: Lanes,
    pub(crate) geometry: Geometry,
    pub(crate) scene: Scene,
}

/// What renewing lanes has done so far.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct FreshStats {
    /// Lanes renewed (new layouts flown).
    pub renewed: u64,
    /// Nanoseconds steps waited for a world not yet built.
    pub wait_ns: u64,
}

/// The renewal of an environment's lanes: the builder thread and where
/// the next renewal stands.
pub(crate) struct Fresh {
    /// Episodes (finished in this environment) between renewals.
    every: usize,
    /// The first lane that may be renewed (after a shipped arena).
    first: usize,
    /// Lanes in the world.
    lanes: usize,
    /// Episodes finished since the last renewal began.
    since: usize,
    /// The lane retired for the renewal under way.
    pub(crate) retiring: Option<usize>,
    next: u64,
    /// The builder's worlds (in a mutex: an environment is shared with
    /// its pool's threads, a receiver may not be).
    built: Mutex<Receiver<Result<Built, ArenaError>>>,
    ask: Option<SyncSender<u64>>,
    thread: Option<JoinHandle<()>>,
    pub(crate) stats: FreshStats,
    /// Why renewing stopped, if it did.
    pub(crate) error: Option<String>,
}

impl Fresh {
    /// Renews lanes `first..` of the world of `arenas` (as the environment
    /// was built from them) every `every` finished episodes, each with
    /// `make`'s next arena; the first world is built at once.
    pub(crate) fn start(every: usize, first: usize, arenas: Vec<Arena>, make: LayoutMaker) -> Self {
        let lanes = arenas.len();
        let (ask, asked) = sync_channel::<u64>(1);
        let (send, built) = sync_channel(1);
        let thread = std::thread::Builder::new()
            .name("fresh-layouts".into())
            .spawn(move || build_worlds(arenas, first, make, &asked, &send))
            .ok();
        let _ = ask.send(0);
        Self {
            every: every.max(1),
            first,
            lanes,
            since: 0,
            retiring: None,
            next: 0,
            built: Mutex::new(built),
            ask: Some(ask),
            thread,
            stats: FreshStats::default(),
            error: None,
        }
    }

    /// Counts `finished` episodes; retires the next lane when a renewal is
    /// due.
    pub(crate) fn count(&mut self, finished: usize) {
        self.since += finished;
        if self.retiring.is_none() && self.since >= self.every && self.ask.is_some() {
            self.since = 0;
            self.retiring = Some(slot(self.first, self.lanes, self.next));
        }
    }

    /// The world of the renewal under way, once `empty` says no agent is
    /// left in its lane (waiting for the builder if it is not done yet).
    /// An error of the builder ends renewing (the lanes stay as they are).
    pub(crate) fn take(
        &mut self,
        empty: impl Fn(usize) -> bool,
    ) -> Option<Result<Built, ArenaError>> {
        let lane = self.retiring?;
        if !empty(lane) {
            return None;
        }
        let start = Instant::now();
        let got = self.built.get_mut().map_err(|_| ()).and_then(|r| r.recv().map_err(|_| ()));
        self.stats.wait_ns += start.elapsed().as_nanos() as u64;
        self.retiring = None;
        match got {
            Ok(Ok(b)) => {
                self.next = b.n + 1;
                self.stats.renewed += 1;
                if let Some(ask) = &self.ask {
                    let _ = ask.send(self.next);
                }
                Some(Ok(b))
            }
            Ok(Err(e)) => {
                self.ask = None;
                Some(Err(e))
            }
            Err(()) => {
                self.ask = None;
                None
            }
        }
    }
}

impl Drop for Fresh {
    fn drop(&mut self) {
        // The builder ends when its requests stop. At most one renewal is
        // asked for at a time and the channel holds its world, so the
        // builder never blocks on a send here.
        self.ask = None;
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

/// The lane renewal `n` replaces, of `lanes` whose first `first` are kept.
fn slot(first: usize, lanes: usize, n: u64) -> usize {
    first + (n % (lanes - first) as u64) as usize
}

/// The builder thread: for every renewal asked for, the new arena in its
/// lane and the world built from every lane.
fn build_worlds(
    mut arenas: Vec<Arena>,
    first: usize,
    mut make: LayoutMaker,
    asked: &Receiver<u64>,
    send: &SyncSender<Result<Built, ArenaError>>,
) {
    while let Ok(n) = asked.recv() {
        let k = slot(first, arenas.len(), n);
        arenas[k] = make(n);
        let built = Lanes::new(&arenas).map(|lanes| {
            let geometry = Geometry::new(&lanes.world);
            let scene = Scene::of_lanes(&lanes.world, &lanes.bounds);
            Built { n, lanes, geometry, scene }
        });
        if send.send(built).is_err() {
            return;
        }
    }
}

impl VecEnv {
    /// Renews the generated lanes `first..` with fresh layouts (see
    /// `env/fresh.rs`): every `every` finished episodes, the next lane is
    /// retired and, once its last episode ends, replaced by `make`'s next
    /// arena, built on a thread of its own. `arenas` are the ones the
    /// environment was built from. The direct physics only (the rapier
    /// pipeline's drones live in its world).
    pub fn renew_lanes(
        &mut self,
        every: usize,
        first: usize,
        arenas: Vec<Arena>,
        make: LayoutMaker,
    ) -> Result<(), LanesError> {
        if self.cfg.physics != PhysicsKind::Direct {
            return Err(LanesError::Fresh("fresh layouts need the direct physics"));
        }
        if arenas.len() != self.lane_offsets.len() || first >= arenas.len() {
            return Err(LanesError::Fresh(
                "fresh layouts need the arenas of the lanes and one to renew",
            ));
        }
        self.fresh = Some(Fresh::start(every, first, arenas, make));
        Ok(())
    }

    /// What renewing lanes has done (zeros when it is off).
    pub fn fresh_stats(&self) -> FreshStats {
        self.fresh.as_ref().map(|f| f.stats).unwrap_or_default()
    }

    /// Why renewing lanes stopped, if it did (the builder could not put a
    /// new layout beside the others).
    pub fn fresh_error(&self) -> Option<&str> {
        self.fresh.as_ref().and_then(|f| f.error.as_deref())
    }

    /// Counts the step's finished episodes toward the next renewal, and
    /// swaps the renewed world in once its retired lane is empty.
    pub(super) fn renew_lane(&mut self) -> Result<(), GpuError> {
        let Some(fresh) = self.fresh.as_mut() else {
            return Ok(());
        };
        fresh.count(self.finished.len());
        let (lanes, dones) = (&self.agent_lane, &self.dones);
        let empty =
            |k: usize| !lanes.iter().zip(dones).any(|(l, d)| *l == k && *d == Done::Running);
        let built = match fresh.take(empty) {
            None => return Ok(()),
            Some(Err(e)) => {
                // The lanes stay as they are; the run goes on, and the
                // caller reads why (`fresh_error`).
                fresh.error = Some(e.to_string());
                return Ok(());
            }
            Some(Ok(b)) => b,
        };
        let Built { lanes, geometry, scene, .. } = built;
        debug_assert_eq!(lanes.offsets, self.lane_offsets, "every lane keeps its place");
        self.gpu = gpu_scene(&self.cfg, &scene)?;
        (self.physics, self.scene, self.arena) = (Physics::Direct(geometry), scene, lanes.world);
        self.lane_offsets = lanes.offsets;
        self.lane_spawns = lanes.spawns;
        self.lane_bounds = lanes.bounds;
        Ok(())
    }
}
