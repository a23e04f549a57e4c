//! A run sized to its machine: the keys left at 0 (`sim.envs`,
//! `sim.render_threads`, `actor.threads`, `learner.threads`) take values
//! in proportion to the cores the run is given (`cores`, all of the
//! machine's by default). On two cores the sizing is the paper's setup
//! scaled to them, one of each, as every run had before there was sizing.

use serde::Serialize;

use super::Config;

/// What the sizing chose, printed at a run's start and written to
/// `summary.json` (`sizing`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
pub struct Sizing {
    /// Cores this machine offers the process (its affinity and cgroup
    /// quota counted).
    pub cores_available: usize,
    /// Cores the run was sized for: `cores` where set (at most the
    /// machine's), else all of them; a deterministic run without `cores`
    /// is sized for 2, so that it repeats on any machine.
    pub cores: usize,
    /// Simulator processes (one actor process each).
    pub envs: usize,
    /// Render (and physics) threads of each simulator.
    pub render_threads: usize,
    /// Inference threads of each actor.
    pub actor_threads: usize,
    /// The learner's threads.
    pub learner_threads: usize,
}

impl Sizing {
    /// The sizing for `cores` cores (of `available`).
    ///
    /// Up to two cores: one environment, one thread each (the setup every
    /// default result was measured with). Beyond: the learner, the run's
    /// bottleneck wherever it was profiled, takes half the cores (at most
    /// 8: `hive bench learner` gains little past 8 threads on 16 cores,
    /// 473 against 520 updates/s at 16 on the H100 machine of
    /// `docs/results/performance.md`);
    /// the replay a core; what is left goes to environments of two render
    /// threads and one actor thread each (one render thread while fewer
    /// than six cores are left).
    pub fn for_cores(cores: usize, available: usize) -> Self {
        let c = cores.max(1);
        let one = Sizing {
            cores_available: available,
            cores: c,
            envs: 1,
            render_threads: 1,
            actor_threads: 1,
            learner_threads: 1,
        };
        if c <= 2 {
            return one;
        }
        let learner_threads = (c / 2).clamp(1, 8);
        let rest = c.saturating_sub(learner_threads + 1).max(1);
        let render_threads = if rest >= 6 { 2 } else { 1 };
        let envs = (rest / (render_threads + 1)).max(1);
        Sizing { envs, render_threads, learner_threads, ..one }
    }

    /// The cores this process may use (1 when the system cannot say).
    pub fn machine_cores() -> usize {
        std::thread::available_parallelism().map_or(1, |n| n.get())
    }
}

/// The most cores a config may name (`cores`).
pub(super) const MAX_CORES: usize = 1024;

/// The keys that sizing fills where a config leaves them at 0.
pub const SIZED_KEYS: [&str; 4] =
    ["sim.envs", "sim.render_threads", "actor.threads", "learner.threads"];

impl Config {
    /// The sizing for this config on a machine of `available` cores.
    pub fn sizing_for(&self, available: usize) -> Sizing {
        let cores = match self.cores {
            0 if self.deterministic => 2,
            0 => available,
            n if self.deterministic => n,
            n => n.min(available),
        };
        Sizing::for_cores(cores, available)
    }

    /// Fills the keys left at 0 from the sizing for `available` cores;
    /// the keys it filled.
    pub(super) fn size(&mut self, available: usize) -> Vec<&'static str> {
        let s = self.sizing_for(available);
        let keys = [
            (&mut self.sim.envs, s.envs),
            (&mut self.sim.render_threads, s.render_threads),
            (&mut self.actor.threads, s.actor_threads),
            (&mut self.learner.threads, s.learner_threads),
        ];
        let mut sized = Vec::new();
        for ((key, value), name) in keys.into_iter().zip(SIZED_KEYS) {
            if *key == 0 {
                *key = value;
                sized.push(name);
            }
        }
        sized
    }

    /// What this run uses, as `summary.json` and the start of a run give
    /// it: the sizing's cores and the keys' values after sizing.
    pub fn sizing(&self) -> Sizing {
        Sizing {
            envs: self.sim.envs,
            render_threads: self.sim.render_threads,
            actor_threads: self.actor.threads,
            learner_threads: self.learner.threads,
            ..self.sizing_for(Sizing::machine_cores())
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn two_cores_are_sized_as_every_run_was_before_and_more_cores_spread() {
        let s = |c| {
            let z = Sizing::for_cores(c, 64);
            (z.envs, z.render_threads, z.actor_threads, z.learner_threads)
        };
        assert_eq!(s(1), (1, 1, 1, 1));
        assert_eq!(s(2), (1, 1, 1, 1));
        assert_eq!(s(4), (1, 1, 1, 2));
        assert_eq!(s(8), (1, 1, 1, 4));
        assert_eq!(s(16), (2, 2, 1, 8));
        assert_eq!(s(32), (7, 2, 1, 8));
        // Past four cores, never more busy threads than cores.
        for c in 3..=128 {
            let z = Sizing::for_cores(c, c);
            let used = z.learner_threads + 1 + z.envs * (z.render_threads + z.actor_threads);
            assert!(used <= c.max(5), "{c} cores: {used} threads");
        }
    }

    #[test]
    fn keys_left_at_zero_are_sized_and_set_ones_are_kept() {
        let mut cfg = Config::default();
        (cfg.sim.envs, cfg.actor.threads, cfg.learner.threads) = (0, 2, 3);
        cfg.cores = 16;
        assert_eq!(cfg.size(64), vec!["sim.envs", "sim.render_threads"]);
        let got = (cfg.sim.envs, cfg.sim.render_threads, cfg.actor.threads, cfg.learner.threads);
        assert_eq!(got, (2, 2, 2, 3));
        // `cores` limits; it never adds cores the machine has not.
        assert_eq!(cfg.sizing_for(8).cores, 8);
        cfg.cores = 0;
        assert_eq!(cfg.sizing_for(12).cores, 12);
        // A deterministic run is sized for two cores, on any machine.
        cfg.deterministic = true;
        assert_eq!(cfg.sizing_for(12).cores, 2);
        cfg.cores = 16;
        assert_eq!(cfg.sizing_for(12).cores, 16);
        // Refused by its name, before the keys it sized are checked.
        let e = Config::load(None, &["cores=100000".into(), "deterministic=true".into()]);
        assert!(e.unwrap_err().to_string().contains("key `cores` must be at most 1024"));
    }
}
