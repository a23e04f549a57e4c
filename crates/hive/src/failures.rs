//! `hive eval --failures DIR`: the failure map. Every episode that did not
//! reach its end, with where it ended and its last steps; one picture per
//! layout from above with the policy's paths and crash points beside the
//! planner's paths from the same spawns; and the traps, places where at
//! least a fifth of a layout's episodes end within a metre of each other.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use rotorhive_roles::Config;
use rotorhive_roles::evaluation::{
    EpisodeLog, EvalStats, LAST_STEPS, LogSpec, Pilot, fly_logged, traps,
};
use rotorhive_sim::{Arena, Done, Sight};

/// What the failure map found.
pub struct Traps {
    /// Where it was written.
    pub dir: PathBuf,
    /// Episodes that did not reach their end.
    pub failures: usize,
    /// Traps over every layout.
    pub traps: usize,
    /// Failed episodes that end in a trap.
    pub in_traps: usize,
}

impl Traps {
    /// Share of the failures that end in a trap (0 without failures).
    pub fn share(&self) -> f64 {
        if self.failures == 0 { 0.0 } else { self.in_traps as f64 / self.failures as f64 }
    }
}

/// Writes the failure map of a logged evaluation into `dir`: `failures.csv`,
/// `last-observations.npy` (failures × [`LAST_STEPS`] × observation, NaN
/// before an episode's first step) and `LAYOUT.png` per layout with a
/// failure. `seed` is the evaluation's (the planner flies the same spawns).
pub fn write(
    dir: &Path,
    cfg: &Config,
    (layouts, stats, logs): (&[Arena], &[EvalStats], &[Vec<EpisodeLog>]),
    seed: u64,
) -> Result<Traps> {
    std::fs::create_dir_all(dir).with_context(|| format!("cannot create {}", dir.display()))?;
    let mut csv =
        String::from("layout,episode,done,end_x,end_y,steps,last_actions,trap,trap_x,trap_y\n");
    let obs_len = cfg.shapes().obs_len();
    let (mut obs, mut rows) = (Vec::new(), 0usize);
    let mut found = Traps { dir: dir.to_path_buf(), failures: 0, traps: 0, in_traps: 0 };
    for (k, ((layout, st), log)) in layouts.iter().zip(stats).zip(logs).enumerate() {
        let failed: Vec<usize> = (0..log.len()).filter(|&e| log[e].failed()).collect();
        if failed.is_empty() {
            continue;
        }
        let ends: Vec<[f32; 2]> = failed.iter().map(|&e| log[e].end()).collect();
        let layout_traps = traps(&ends, st.episodes);
        found.failures += failed.len();
        found.traps += layout_traps.len();
        found.in_traps += layout_traps.iter().map(|t| t.episodes).sum::<usize>();
        for (j, &e) in failed.iter().enumerate() {
            let ep = &log[e];
            let trap = layout_traps.iter().position(|t| t.members.contains(&j));
            let actions: Vec<String> = ep.last_actions.iter().map(u8::to_string).collect();
            let [x, y] = ep.end();
            let (tn, tx, ty) = match trap {
                Some(t) => {
                    let at = layout_traps[t].at;
                    ((t + 1).to_string(), format!("{:.2}", at[0]), format!("{:.2}", at[1]))
                }
                None => Default::default(),
            };
            writeln!(
                csv,
                "{},{e},{},{x:.2},{y:.2},{},{},{tn},{tx},{ty}",
                layout.name,
                done_name(ep.done),
                ep.path.len() - 1,
                actions.join(" ")
            )?;
            let pad = LAST_STEPS - ep.last_obs.len();
            obs.extend(std::iter::repeat_n(f32::NAN, pad * obs_len));
            for o in &ep.last_obs {
                obs.extend(o.iter().copied().chain(std::iter::repeat(f32::NAN)).take(obs_len));
            }
            rows += 1;
        }
        // The planner (knowing everything) from the same spawns.
        let spec = LogSpec { audit: None, horizon: 0 };
        let one = std::slice::from_ref(layout);
        let sim = cfg.sim_config();
        let planned = fly_logged(
            Pilot::Planner(Sight::All),
            sim,
            one,
            st.episodes,
            seed.wrapping_add(k as u64),
            Some(spec),
        )?
        .1;
        let path = |l: &EpisodeLog| l.path.iter().map(|p| (p[0], p[1])).collect::<Vec<_>>();
        let overlay = crate::draw::Overlay {
            paths: log.iter().map(path).collect(),
            guides: planned.iter().map(path).collect(),
            crashes: ends.iter().map(|p| (p[0], p[1])).collect(),
            traps: layout_traps.iter().map(|t| (t.at[0], t.at[1])).collect(),
        };
        let png = dir.join(format!("{}.png", file_name(&layout.name)));
        crate::draw::draw_arena(layout, &overlay, &png)?;
    }
    let path = dir.join("failures.csv");
    std::fs::write(&path, csv).with_context(|| format!("cannot write {}", path.display()))?;
    let path = dir.join("last-observations.npy");
    std::fs::write(&path, npy(&obs, [rows, LAST_STEPS, obs_len]))
        .with_context(|| format!("cannot write {}", path.display()))?;
    Ok(found)
}

/// How an episode ended, as the CSV writes it.
fn done_name(d: Option<Done>) -> &'static str {
    match d {
        Some(Done::Collision) => "collision",
        Some(Done::Goal) => "goal",
        Some(Done::Timeout) => "timeout",
        Some(Done::Running) | None => "unfinished",
    }
}

/// A layout's name as a file name (letters, digits, `-` and `_` kept).
fn file_name(name: &str) -> String {
    name.chars().map(|c| if c.is_ascii_alphanumeric() || c == '_' { c } else { '-' }).collect()
}

/// `data` as a NumPy `.npy` file (version 1.0, little-endian f32, C order)
/// of `shape`: numpy's format is a short text header and the raw values,
/// so no crate is needed to write it.
fn npy(data: &[f32], shape: [usize; 3]) -> Vec<u8> {
    let dict = format!(
        "{{'descr': '<f4', 'fortran_order': False, 'shape': ({}, {}, {}), }}",
        shape[0], shape[1], shape[2]
    );
    // Magic (6) + version (2) + header length (2) + header, padded with
    // spaces and a newline to a multiple of 64.
    let len = (10 + dict.len() + 1).div_ceil(64) * 64 - 10;
    let mut header = format!("{dict:<0$}", len - 1);
    header.push('\n');
    let mut out = b"\x93NUMPY\x01\x00".to_vec();
    out.extend_from_slice(&(len as u16).to_le_bytes());
    out.extend_from_slice(header.as_bytes());
    out.extend(data.iter().flat_map(|v| v.to_le_bytes()));
    out
}

#[cfg(test)]
mod tests {
    #[test]
    fn an_npy_file_has_numpys_header_and_the_values() {
        let b = super::npy(&[1.0, 2.0], [1, 1, 2]);
        assert!(b.starts_with(b"\x93NUMPY\x01\x00"));
        let len = u16::from_le_bytes([b[8], b[9]]) as usize;
        assert_eq!((10 + len) % 64, 0);
        let header = std::str::from_utf8(&b[10..10 + len]).unwrap();
        assert!(header.contains("'shape': (1, 1, 2)") && header.ends_with('\n'), "{header}");
        assert_eq!(&b[10 + len..], [1.0f32.to_le_bytes(), 2.0f32.to_le_bytes()].concat());
    }
}
