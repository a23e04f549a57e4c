//! The graded levels (`configs/levels/NAME.toml`), built into the binary
//! and the Python package so that `--level NAME` and the Gymnasium IDs work
//! from any directory. Each is an ordinary config.

use crate::error::{ConfigError, Result};

/// Every level: its name, its Gymnasium ID and its config.
pub const LEVELS: &[(&str, &str, &str)] = &[
    ("paper", "rotorhive/Navigate-v0", include_str!("../../../configs/levels/paper.toml")),
    ("dense", "rotorhive/Dense-v0", include_str!("../../../configs/levels/dense.toml")),
    ("forest", "rotorhive/Forest-v0", include_str!("../../../configs/levels/forest.toml")),
    ("noisy", "rotorhive/Noisy-v0", include_str!("../../../configs/levels/noisy.toml")),
    ("moving", "rotorhive/Moving-v0", include_str!("../../../configs/levels/moving.toml")),
    ("goal", "rotorhive/Goal-v0", include_str!("../../../configs/levels/goal.toml")),
];

/// The names of the levels, in order of difficulty.
pub fn names() -> Vec<&'static str> {
    LEVELS.iter().map(|l| l.0).collect()
}

/// The config text of level `name`; an unknown name is refused with the
/// list of known ones.
pub fn text(name: &str) -> Result<&'static str> {
    LEVELS.iter().find(|l| l.0 == name).map(|l| l.2).ok_or_else(|| {
        ConfigError::Invalid(format!(
            "unknown level `{name}`: the levels are {}",
            names().join(", ")
        ))
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::Config;

    #[test]
    fn every_level_loads_and_the_paper_level_is_the_default() {
        let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../..");
        std::env::set_current_dir(&root).unwrap();
        for name in names() {
            let c = Config::level(name, &[]).unwrap_or_else(|e| panic!("level {name}: {e:#}"));
            assert!(
                c.test_arenas().unwrap().len() >= 5,
                "level {name} has at least 5 test layouts"
            );
        }
        // The paper's level is the defaults with one environment and one
        // thread of each, on any machine.
        let ones = crate::SIZED_KEYS.map(|k| format!("{k}=1"));
        assert_eq!(
            Config::level("paper", &[]).unwrap().to_toml(),
            Config::load(None, &ones).unwrap().to_toml()
        );
        let e = Config::level("lava", &[]).unwrap_err().to_string();
        assert!(e.contains("lava") && e.contains("dense"), "{e}");
    }
}
