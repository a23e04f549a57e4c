//! Every random stream a run derives from its `seed`, in one place, each
//! with a named salt, so that no two streams share a seed by accident and
//! a reader sees at once which stream a number feeds. The formulas are the
//! ones runs have always used: changing one changes every recorded result
//! (and the seed harness's figures), so a change is a change of default.

/// The network's initial weights (learner and actors alike: an actor's
/// first weights equal the learner's before any are published).
pub fn network(seed: u64) -> u64 {
    seed
}

/// Simulator `env` (global environment index, across hosts): spawns,
/// lane draws and resets.
pub fn sim(seed: u64, env: usize) -> u64 {
    seed.wrapping_mul(SIM_STRIDE).wrapping_add(env as u64)
}

/// Actor `env`'s exploration (epsilon draws and random actions).
pub fn actor(seed: u64, env: usize) -> u64 {
    seed ^ ACTOR_SALT.wrapping_add(env as u64)
}

/// The replay's sampling.
pub fn replay(seed: u64) -> u64 {
    seed ^ REPLAY_SALT
}

/// The replay's sampling of the teacher's demonstrations.
pub fn demos(seed: u64) -> u64 {
    seed ^ DEMO_SALT
}

/// Simulator `env`'s teacher: which of the student's steps it labels.
pub fn teacher(seed: u64, env: usize) -> u64 {
    seed ^ TEACHER_SALT.wrapping_add(env as u64)
}

/// Generated training lane `lane` of environment `env`: seeds no shipped
/// arena uses.
pub fn lane(seed: u64, env: usize, lane: usize) -> u64 {
    LANE_BASE
        .wrapping_add(seed.wrapping_mul(LANE_SEED_STRIDE))
        .wrapping_add(env as u64 * LANE_ENV_STRIDE)
        .wrapping_add(lane as u64)
}

/// Fresh layout `n` (0, 1, …) of environment `env` (`sim.fresh_layouts`):
/// seeds of their own, above every lane's and below every test layout's
/// (for run seeds below 2^13, environments below 2^10 and 2^26 renewals).
pub fn fresh_lane(seed: u64, env: usize, n: u64) -> u64 {
    FRESH_LANE_BASE
        .wrapping_add(seed.wrapping_mul(FRESH_SEED_STRIDE))
        .wrapping_add(env as u64 * FRESH_ENV_STRIDE)
        .wrapping_add(n)
}

/// Generated validation arena `k`: the same for every seed, so that
/// validations of different runs compare.
pub fn validation_arena(k: usize) -> u64 {
    VALIDATION_ARENA_BASE + k as u64
}

/// Generated held-out test layout `k` of a level (`eval.test_layouts`):
/// the same for every run, and far from every lane's and validation
/// arena's seed, so no run trains or validates on one.
pub fn test_layout(k: usize) -> u64 {
    TEST_LAYOUT_BASE + k as u64
}

/// The spawns of the validations during training.
pub fn validation(seed: u64) -> u64 {
    seed.wrapping_add(VALIDATION_SALT)
}

/// The fresh spawns of confirmation number `n` (1, 2, …) of a candidate
/// result.
pub fn confirmation(seed: u64, n: u64) -> u64 {
    seed.wrapping_add(CONFIRMATION_STRIDE.wrapping_mul(n))
}

/// Simulators of a run are `SIM_STRIDE` seeds apart per run seed.
const SIM_STRIDE: u64 = 1000;
/// Actors' exploration streams start here (xor).
const ACTOR_SALT: u64 = 0xac70;
/// The replay's sampling stream (xor).
const REPLAY_SALT: u64 = 0x5e1a;
/// The demonstrations' sampling stream (xor; "demoresv").
const DEMO_SALT: u64 = 0x6465_6d6f_7265_7376;
/// The teachers' label draws start here (xor; "teacher1").
const TEACHER_SALT: u64 = 0x7465_6163_6865_7231;
/// Generated training lanes: above every shipped arena's seed.
const LANE_BASE: u64 = 1_000_000;
/// Lanes of two run seeds are this far apart.
const LANE_SEED_STRIDE: u64 = 100_000;
/// Lanes of two environments of a run are this far apart.
const LANE_ENV_STRIDE: u64 = 1000;
/// Fresh layouts: far above every lane.
const FRESH_LANE_BASE: u64 = 1 << 50;
/// Fresh layouts of two run seeds are this far apart.
const FRESH_SEED_STRIDE: u64 = 1 << 36;
/// Fresh layouts of two environments of a run are this far apart.
const FRESH_ENV_STRIDE: u64 = 1 << 26;
/// Generated validation arenas.
const VALIDATION_ARENA_BASE: u64 = 4242;
/// Held-out test layouts: past any lane of a run seed below 10^13.
const TEST_LAYOUT_BASE: u64 = 1 << 60;
/// The validations' spawns.
const VALIDATION_SALT: u64 = 7777;
/// Confirmations' spawns, a prime apart.
const CONFIRMATION_STRIDE: u64 = 1_000_003;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_streams_of_one_kind_never_share_a_seed() {
        for seed in 0..50u64 {
            // Spawn streams (simulators and greedy evaluations), arena
            // generators and sampling streams: a clash within a kind would
            // make two of them draw the same numbers.
            let mut spawns = vec![validation(seed)];
            spawns.extend((1..5).map(|n| confirmation(seed, n)));
            let mut arenas: Vec<u64> =
                (0..32).map(validation_arena).chain((0..64).map(test_layout)).collect();
            let mut sampling = vec![replay(seed)];
            for e in 0..64 {
                spawns.push(sim(seed, e));
                sampling.push(actor(seed, e));
                arenas.extend((0..256).map(|k| lane(seed, e, k)));
                arenas.extend((0..64).map(|n| fresh_lane(seed, e, n)));
            }
            for (kind, v) in [("spawn", spawns), ("arena", arenas), ("sampling", sampling)] {
                let unique: std::collections::HashSet<_> = v.iter().collect();
                assert_eq!(unique.len(), v.len(), "seed {seed}: two {kind} streams share a seed");
            }
        }
        // The formulas runs have always used (recorded results depend on them).
        assert_eq!(
            (sim(3, 2), actor(3, 2), replay(3), lane(3, 2, 1)),
            (3002, 3 ^ 0xac72, 3 ^ 0x5e1a, 1_302_001)
        );
        assert_eq!(
            (validation(3), confirmation(3, 2), validation_arena(1)),
            (7780, 2_000_009, 4243)
        );
    }
}
