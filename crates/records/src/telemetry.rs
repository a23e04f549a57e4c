//! `telemetry.csv`: one row per role (and one for the supervisor) about once
//! a second, written and read through [`TelemetryRow`] so the writer and
//! every reader (`hive profile`, `hive bench table`) agree on its columns.

use std::path::Path;

use crate::{Member, RecordsError, Result};
pub use rotorhive_msg::Learning;

/// The file's header: the column names in order.
pub const HEADER: &str = "wall_s,role,index,pid,cpu_pct,rss_mb,machine_cpu_pct,heartbeat,work,work2,weight_version,lost,stage0_ms,stage1_ms,stage2_ms,stage3_ms,gpu_util_pct,gpu_mem_mb,gpu_power_w,value,policy_lag,max_q,td_abs,terminal_share,skipped_updates,eps_min,eps_max,priority_updates,stale_priorities";

/// Columns of [`HEADER`].
const COLUMNS: usize = 29;

/// One row of `telemetry.csv`.
#[derive(Debug, Clone, PartialEq)]
pub struct TelemetryRow {
    /// Seconds since the run started.
    pub wall_s: f64,
    /// The role, or the supervisor.
    pub role: Member,
    /// Instance index (environment for sims and actors).
    pub index: u32,
    /// Process id.
    pub pid: u32,
    /// CPU % of the process (100 = one core); NaN for a role of another host.
    pub cpu_pct: f64,
    /// Resident memory (MB); NaN for a role of another host.
    pub rss_mb: f64,
    /// Whole-machine CPU % (100 = every core busy).
    pub machine_cpu_pct: f64,
    /// Telemetry samples the role has sent.
    pub heartbeat: u64,
    /// The role's main work counter (cumulative).
    pub work: u64,
    /// Its secondary counter (cumulative).
    pub work2: u64,
    /// Weight version in use (actor) or published (learner).
    pub weight_version: u64,
    /// Messages lost (sequence gaps).
    pub lost: u64,
    /// Cumulative milliseconds in each of the role's four stages.
    pub stage_ms: [f64; 4],
    /// GPU utilisation, memory and power, when the machine has one.
    pub gpu: Option<[f64; 3]>,
    /// The role's gauge in its own unit (loss, epsilon, replay size), or empty.
    pub value: String,
    /// Learner rows: mean policy lag of its recent minibatches (versions).
    pub policy_lag: Option<f64>,
    /// Learner, actor and replay rows: the learning diagnostics (mean
    /// max-Q, mean |TD error|, terminal share, skipped updates; the actor's
    /// epsilon spread; the replay's priority updates applied and stale),
    /// empty for the other roles.
    pub learning: Option<Learning>,
}

impl TelemetryRow {
    /// The member's name in plots and logs: `supervisor`, or the role and
    /// its index (`sim-0`, `learner-0`).
    pub fn member_name(&self) -> String {
        match self.role {
            Member::Supervisor => self.role.to_string(),
            role => format!("{role}-{}", self.index),
        }
    }

    /// The row as a line of the file (with its newline).
    pub fn to_line(&self) -> String {
        let opt = |v: Option<f64>, digits: usize| v.map_or(String::new(), |v| format!("{v:.digits$}"));
        let gpu = self.gpu.map_or(",,".to_string(), |g| format!("{:.1},{:.1},{:.1}", g[0], g[1], g[2]));
        let s = &self.stage_ms;
        let learning = self.learning.map_or(",,,,,,,".to_string(), |l| {
            format!(
                "{:.3},{:.3},{:.4},{},{:.5},{:.5},{},{}",
                l.mean_max_q, l.mean_abs_td, l.terminal_share, l.skipped_updates, l.eps_min, l.eps_max, l.priority_updates, l.stale_priorities
            )
        });
        format!(
            "{:.3},{},{},{},{:.1},{:.1},{:.1},{},{},{},{},{},{:.1},{:.1},{:.1},{:.1},{gpu},{},{},{learning}\n",
            self.wall_s,
            self.role,
            self.index,
            self.pid,
            self.cpu_pct,
            self.rss_mb,
            self.machine_cpu_pct,
            self.heartbeat,
            self.work,
            self.work2,
            self.weight_version,
            self.lost,
            s[0],
            s[1],
            s[2],
            s[3],
            self.value,
            opt(self.policy_lag, 3),
        )
    }

    /// Parses one line; the error names the column.
    pub fn parse(line: &str) -> std::result::Result<Self, String> {
        let f: Vec<&str> = line.split(',').collect();
        if f.len() != COLUMNS {
            return Err(format!("expected {COLUMNS} fields, found {}", f.len()));
        }
        let name = |k: usize| HEADER.split(',').nth(k).unwrap_or("?");
        let float = |k: usize| f[k].parse::<f64>().map_err(|_| format!("column `{}` is not a number: {:?}", name(k), f[k]));
        let int = |k: usize| f[k].parse::<u64>().map_err(|_| format!("column `{}` is not a count: {:?}", name(k), f[k]));
        let opt = |k: usize| if f[k].is_empty() { Ok(None) } else { float(k).map(Some) };
        let gpu = match (opt(16)?, opt(17)?, opt(18)?) {
            (Some(u), Some(m), Some(p)) => Some([u, m, p]),
            _ => None,
        };
        let learning = match opt(21)? {
            None => None,
            Some(q) => Some(Learning {
                mean_max_q: q as f32,
                mean_abs_td: float(22)? as f32,
                terminal_share: float(23)? as f32,
                skipped_updates: int(24)? as u32,
                eps_min: float(25)? as f32,
                eps_max: float(26)? as f32,
                priority_updates: int(27)? as u32,
                stale_priorities: int(28)? as u32,
            }),
        };
        Ok(Self {
            wall_s: float(0)?,
            role: Member::parse(f[1]).ok_or_else(|| format!("column `role` names no role: {:?}", f[1]))?,
            index: int(2)? as u32,
            pid: int(3)? as u32,
            cpu_pct: float(4)?,
            rss_mb: float(5)?,
            machine_cpu_pct: float(6)?,
            heartbeat: int(7)?,
            work: int(8)?,
            work2: int(9)?,
            weight_version: int(10)?,
            lost: int(11)?,
            stage_ms: [float(12)?, float(13)?, float(14)?, float(15)?],
            gpu,
            value: f[19].to_string(),
            policy_lag: opt(20)?,
            learning,
        })
    }
}

/// Every row of a run's `telemetry.csv` (a resumed run's file holds one
/// header per part; they are skipped).
pub fn read(run_dir: &Path) -> Result<Vec<TelemetryRow>> {
    let path = run_dir.join("telemetry.csv");
    let text = std::fs::read_to_string(&path).map_err(RecordsError::io("read", &path))?;
    let mut rows = Vec::new();
    for (i, line) in text.lines().enumerate() {
        if line == HEADER || line.is_empty() {
            continue;
        }
        rows.push(TelemetryRow::parse(line).map_err(|message| RecordsError::Telemetry { file: path.display().to_string(), line: i + 1, message })?);
    }
    Ok(rows)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_row_round_trips_and_a_bad_one_names_its_column() {
        let row = TelemetryRow {
            wall_s: 12.5,
            role: Member::Learner,
            index: 0,
            pid: 42,
            cpu_pct: 99.5,
            rss_mb: 310.44,
            machine_cpu_pct: 97.0,
            heartbeat: 12,
            work: 2400,
            work2: 240,
            weight_version: 241,
            lost: 0,
            stage_ms: [1.5, 2.5, 0.5, 100.0],
            gpu: None,
            value: "0.012345".into(),
            policy_lag: Some(3.25),
            learning: Some(Learning {
                mean_max_q: 2.5,
                mean_abs_td: 0.25,
                terminal_share: 0.0625,
                skipped_updates: 3,
                priority_updates: 7,
                ..Learning::default()
            }),
        };
        let line = row.to_line();
        assert_eq!(line.trim_end().split(',').count(), HEADER.split(',').count());
        let back = TelemetryRow::parse(line.trim_end()).unwrap();
        assert_eq!(back, TelemetryRow { rss_mb: 310.4, ..row.clone() });
        let gpu = TelemetryRow { gpu: Some([50.0, 1024.0, 80.0]), policy_lag: None, cpu_pct: f64::NAN, ..row.clone() };
        let back = TelemetryRow::parse(gpu.to_line().trim_end()).unwrap();
        assert_eq!((back.gpu, back.policy_lag), (gpu.gpu, None));
        let plain = TelemetryRow { learning: None, ..row.clone() };
        assert_eq!(TelemetryRow::parse(plain.to_line().trim_end()).unwrap().learning, None);
        assert!(back.cpu_pct.is_nan());
        let e = TelemetryRow::parse(&line.trim_end().replace(",2400,", ",many,")).unwrap_err().to_string();
        assert!(e.contains("`work`"), "{e}");
        assert!(TelemetryRow::parse("1,2,3").unwrap_err().to_string().contains("29 fields"));
    }
}
