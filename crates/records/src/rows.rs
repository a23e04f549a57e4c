//! The run's CSV tables as typed rows, written and read through `csv` and
//! serde so that the writer and every reader agree on the columns by name:
//! `metrics.csv` (written by `hive train`, read by `hive bench seeds` and
//! `hive bench table`) and `evals.csv` (written by the evaluator, read back
//! on a resume and by `hive bench seeds`).

use std::path::Path;

use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};

use crate::{RecordsError, Result};

/// What a row of `metrics.csv` records.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum MetricsKind {
    /// A finished episode.
    Episode,
    /// The once-a-second state of the run.
    Tick,
    /// A role died and was started again.
    Restart,
    /// The run was resumed here (its clock starts again).
    Resume,
}

/// The header of `metrics.csv`.
pub const METRICS_HEADER: &str =
    "kind,wall_s,env_steps,episodes,episode_reward,rolling_reward,epsilon,updates,replay_size";

/// One row of `metrics.csv`; `restart` and `resume` rows carry only their
/// kind and time.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct MetricsRow {
    /// What the row records.
    pub kind: MetricsKind,
    /// Seconds since the run (or its resume) started.
    pub wall_s: f64,
    /// Agent-steps so far.
    pub env_steps: Option<u64>,
    /// Episodes so far.
    pub episodes: Option<u64>,
    /// The episode's return (episode rows).
    pub episode_reward: Option<f32>,
    /// Mean return of the rolling window (NaN before any episode).
    pub rolling_reward: Option<f64>,
    /// The episode's exploration rate (episode rows), the actors' largest
    /// (tick rows).
    pub epsilon: Option<f64>,
    /// Learner updates so far.
    pub updates: Option<u64>,
    /// Transitions in the replay.
    pub replay_size: Option<i64>,
}

impl MetricsRow {
    /// A row of `kind` at `wall_s` with no counters (`restart`, `resume`).
    pub fn mark(kind: MetricsKind, wall_s: f64) -> Self {
        Self {
            kind,
            wall_s: round(wall_s, 3),
            env_steps: None,
            episodes: None,
            episode_reward: None,
            rolling_reward: None,
            epsilon: None,
            updates: None,
            replay_size: None,
        }
    }
}

/// The header of `evals.csv`.
pub const EVALS_HEADER: &str = "wall_s,updates,version,episodes,success_rate,mean_reward,best,confirmed_episodes,confirmed_success_rate,confirmed_mean_reward,env_steps";

/// One greedy validation of `evals.csv`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct EvalRow {
    /// Seconds since the run started.
    pub wall_s: f64,
    /// The learner updates of the weights validated.
    pub updates: u64,
    /// Their publication version.
    pub version: u64,
    /// Episodes of the screening.
    pub episodes: u64,
    /// The screening's success rate.
    pub success_rate: f64,
    /// Its mean return.
    pub mean_reward: f64,
    /// 1 when these weights became `best.safetensors`.
    pub best: u8,
    /// Episodes of the confirmation on fresh spawns, when one was made.
    pub confirmed_episodes: Option<u64>,
    /// The confirmation's success rate.
    pub confirmed_success_rate: Option<f64>,
    /// Its mean return.
    pub confirmed_mean_reward: Option<f64>,
    /// Agent-steps of the run (every host's) when the weights were taken
    /// (absent in tables of runs before the fourth wave).
    #[serde(default)]
    pub env_steps: Option<u64>,
}

/// `v` rounded to `digits` decimals (what the tables keep: they would
/// otherwise grow by every float's 17 digits).
pub fn round(v: f64, digits: i32) -> f64 {
    let p = 10f64.powi(digits);
    if v.is_finite() { (v * p).round() / p } else { v }
}

/// One row as a line of its table (with the newline, without a header).
pub fn line<R: Serialize>(row: &R) -> Result<String> {
    let mut w = csv::WriterBuilder::new().has_headers(false).from_writer(Vec::new());
    w.serialize(row).map_err(|e| RecordsError::Csv(e.to_string()))?;
    let bytes = w.into_inner().map_err(|e| RecordsError::Csv(e.to_string()))?;
    String::from_utf8(bytes).map_err(|e| RecordsError::Csv(e.to_string()))
}

/// The rows of the table at `path` (none when it does not exist); a header
/// line repeated inside (one per part of a resumed run) is skipped, and a
/// row that does not parse names the file, the line and the column.
pub fn read<R: DeserializeOwned>(path: &Path) -> Result<Vec<R>> {
    let mut r = match csv::ReaderBuilder::new().flexible(false).from_path(path) {
        Ok(r) => r,
        Err(e) if matches!(e.kind(), csv::ErrorKind::Io(io) if io.kind() == std::io::ErrorKind::NotFound) =>
        {
            return Ok(Vec::new());
        }
        Err(e) => {
            return Err(RecordsError::Table {
                file: path.display().to_string(),
                message: e.to_string(),
            });
        }
    };
    let bad = |e: csv::Error| RecordsError::Table {
        file: path.display().to_string(),
        message: e.to_string(),
    };
    let header = r.headers().map_err(bad)?.clone();
    let mut out = Vec::new();
    for rec in r.records() {
        let rec = rec.map_err(bad)?;
        if rec == header {
            continue;
        }
        out.push(rec.deserialize(Some(&header)).map_err(|e| match e.kind() {
            // Name the column, not only its number.
            csv::ErrorKind::Deserialize { pos, err } => RecordsError::Table {
                file: path.display().to_string(),
                message: format!(
                    "line {}: column `{}`: {}",
                    pos.as_ref().map_or(0, |p| p.line()),
                    err.field().and_then(|i| header.get(i as usize)).unwrap_or("?"),
                    err.kind()
                ),
            },
            _ => bad(e),
        })?);
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rows_read_back_what_they_write_under_their_headers() {
        let dir = std::env::temp_dir().join(format!("rotorhive-rows-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let m = [
            MetricsRow {
                kind: MetricsKind::Episode,
                wall_s: 1.25,
                env_steps: Some(10),
                episodes: Some(1),
                episode_reward: Some(-97.5),
                rolling_reward: Some(f64::NAN),
                epsilon: Some(0.4),
                updates: Some(0),
                replay_size: Some(5),
            },
            MetricsRow::mark(MetricsKind::Restart, 2.0004),
        ];
        let text = format!(
            "{METRICS_HEADER}\n{}{}{METRICS_HEADER}\n{}",
            line(&m[0]).unwrap(),
            line(&m[1]).unwrap(),
            line(&m[0]).unwrap()
        );
        assert!(text.contains("restart,2.0,,,,,,,\n"), "{text}");
        std::fs::write(dir.join("metrics.csv"), text).unwrap();
        let back: Vec<MetricsRow> = read(&dir.join("metrics.csv")).unwrap();
        assert_eq!(back.len(), 3);
        assert!(back[0].rolling_reward.unwrap().is_nan() && back[0].episode_reward == Some(-97.5));
        assert_eq!(back[1], m[1]);
        let e = EvalRow {
            wall_s: 3.5,
            updates: 100,
            version: 2,
            episodes: 300,
            success_rate: 0.95,
            mean_reward: 250.0,
            best: 1,
            confirmed_episodes: None,
            confirmed_success_rate: None,
            confirmed_mean_reward: None,
            env_steps: Some(12_000),
        };
        std::fs::write(dir.join("evals.csv"), format!("{EVALS_HEADER}\n{}", line(&e).unwrap()))
            .unwrap();
        assert_eq!(read::<EvalRow>(&dir.join("evals.csv")).unwrap(), vec![e]);
        // A row of another shape names the file and what is wrong.
        std::fs::write(dir.join("evals.csv"), format!("{EVALS_HEADER}\n1,x,2,3,0.5,1,0,,,,\n"))
            .unwrap();
        let err = read::<EvalRow>(&dir.join("evals.csv")).unwrap_err().to_string();
        assert!(err.contains("evals.csv") && err.contains("updates"), "{err}");
        assert!(read::<EvalRow>(&dir.join("none.csv")).unwrap().is_empty());
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn the_header_constants_are_the_rows_field_names() {
        let mut w = csv::Writer::from_writer(Vec::new());
        w.serialize(MetricsRow::mark(MetricsKind::Tick, 0.0)).unwrap();
        let text = String::from_utf8(w.into_inner().unwrap()).unwrap();
        assert_eq!(text.lines().next(), Some(METRICS_HEADER));
        let mut w = csv::Writer::from_writer(Vec::new());
        w.serialize(EvalRow {
            wall_s: 0.0,
            updates: 0,
            version: 0,
            episodes: 0,
            success_rate: 0.0,
            mean_reward: 0.0,
            best: 0,
            confirmed_episodes: None,
            confirmed_success_rate: None,
            confirmed_mean_reward: None,
            env_steps: None,
        })
        .unwrap();
        let text = String::from_utf8(w.into_inner().unwrap()).unwrap();
        assert_eq!(text.lines().next(), Some(EVALS_HEADER));
    }
}
