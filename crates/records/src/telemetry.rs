//! `telemetry.csv`: one row per role (and one for the supervisor) about once
//! a second, written and read through [`TelemetryRow`] so the writer and
//! every reader (`hive profile`, `hive bench table`) agree on its columns.

use std::path::Path;

use crate::rows::round;
use crate::{Member, RecordsError, Result};
pub use rotorhive_msg::Learning;
use serde::{Deserialize, Serialize};

/// The file's header: the column names in order.
pub const HEADER: &str = "wall_s,role,index,pid,cpu_pct,rss_mb,machine_cpu_pct,heartbeat,work,work2,weight_version,lost,stage0_ms,stage1_ms,stage2_ms,stage3_ms,gpu_util_pct,gpu_mem_mb,gpu_power_w,value,policy_lag,max_q,td_abs,terminal_share,skipped_updates,eps_min,eps_max,priority_updates,stale_priorities";

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

    /// The row as a line of the file (with its newline), through csv.
    pub fn to_line(&self) -> Result<String> {
        crate::rows::line(&Flat::from(self))
    }
}

/// A row as the file holds it: one column a field, each named as in
/// [`HEADER`], rounded to what the file keeps.
#[derive(Debug, Serialize, Deserialize)]
struct Flat {
    wall_s: f64,
    role: Member,
    index: u32,
    pid: u32,
    cpu_pct: f64,
    rss_mb: f64,
    machine_cpu_pct: f64,
    heartbeat: u64,
    work: u64,
    work2: u64,
    weight_version: u64,
    lost: u64,
    stage0_ms: f64,
    stage1_ms: f64,
    stage2_ms: f64,
    stage3_ms: f64,
    gpu_util_pct: Option<f64>,
    gpu_mem_mb: Option<f64>,
    gpu_power_w: Option<f64>,
    value: String,
    policy_lag: Option<f64>,
    max_q: Option<f64>,
    td_abs: Option<f64>,
    terminal_share: Option<f64>,
    skipped_updates: Option<u32>,
    eps_min: Option<f64>,
    eps_max: Option<f64>,
    priority_updates: Option<u32>,
    stale_priorities: Option<u32>,
}

impl From<&TelemetryRow> for Flat {
    fn from(r: &TelemetryRow) -> Self {
        let l = r.learning;
        let lf = |f: fn(&Learning) -> f32, digits| l.map(|l| round(f(&l) as f64, digits));
        let [s0, s1, s2, s3] = r.stage_ms.map(|v| round(v, 1));
        Flat {
            wall_s: round(r.wall_s, 3),
            role: r.role,
            index: r.index,
            pid: r.pid,
            cpu_pct: round(r.cpu_pct, 1),
            rss_mb: round(r.rss_mb, 1),
            machine_cpu_pct: round(r.machine_cpu_pct, 1),
            heartbeat: r.heartbeat,
            work: r.work,
            work2: r.work2,
            weight_version: r.weight_version,
            lost: r.lost,
            stage0_ms: s0,
            stage1_ms: s1,
            stage2_ms: s2,
            stage3_ms: s3,
            gpu_util_pct: r.gpu.map(|g| round(g[0], 1)),
            gpu_mem_mb: r.gpu.map(|g| round(g[1], 1)),
            gpu_power_w: r.gpu.map(|g| round(g[2], 1)),
            value: r.value.clone(),
            policy_lag: r.policy_lag.map(|v| round(v, 3)),
            max_q: lf(|l| l.mean_max_q, 3),
            td_abs: lf(|l| l.mean_abs_td, 3),
            terminal_share: lf(|l| l.terminal_share, 4),
            skipped_updates: l.map(|l| l.skipped_updates),
            eps_min: lf(|l| l.eps_min, 5),
            eps_max: lf(|l| l.eps_max, 5),
            priority_updates: l.map(|l| l.priority_updates),
            stale_priorities: l.map(|l| l.stale_priorities),
        }
    }
}

impl From<Flat> for TelemetryRow {
    fn from(f: Flat) -> Self {
        let gpu = match (f.gpu_util_pct, f.gpu_mem_mb, f.gpu_power_w) {
            (Some(u), Some(m), Some(p)) => Some([u, m, p]),
            _ => None,
        };
        let learning = f.max_q.map(|q| Learning {
            mean_max_q: q as f32,
            mean_abs_td: f.td_abs.unwrap_or(0.0) as f32,
            terminal_share: f.terminal_share.unwrap_or(0.0) as f32,
            skipped_updates: f.skipped_updates.unwrap_or(0),
            eps_min: f.eps_min.unwrap_or(0.0) as f32,
            eps_max: f.eps_max.unwrap_or(0.0) as f32,
            priority_updates: f.priority_updates.unwrap_or(0),
            stale_priorities: f.stale_priorities.unwrap_or(0),
        });
        TelemetryRow {
            wall_s: f.wall_s,
            role: f.role,
            index: f.index,
            pid: f.pid,
            cpu_pct: f.cpu_pct,
            rss_mb: f.rss_mb,
            machine_cpu_pct: f.machine_cpu_pct,
            heartbeat: f.heartbeat,
            work: f.work,
            work2: f.work2,
            weight_version: f.weight_version,
            lost: f.lost,
            stage_ms: [f.stage0_ms, f.stage1_ms, f.stage2_ms, f.stage3_ms],
            gpu,
            value: f.value,
            policy_lag: f.policy_lag,
            learning,
        }
    }
}

/// Every row of a run's `telemetry.csv` (a resumed run's file holds one
/// header per part; they are skipped); a row that does not parse names the
/// file, its line and the column.
pub fn read(run_dir: &Path) -> Result<Vec<TelemetryRow>> {
    let path = run_dir.join("telemetry.csv");
    if !path.exists() {
        return Err(RecordsError::Io {
            action: "read",
            file: path.display().to_string(),
            err: std::io::ErrorKind::NotFound.into(),
        });
    }
    Ok(crate::rows::read::<Flat>(&path)?.into_iter().map(TelemetryRow::from).collect())
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
        let dir = std::env::temp_dir().join(format!("rotorhive-telemetry-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let gpu = TelemetryRow {
            gpu: Some([50.0, 1024.0, 80.0]),
            policy_lag: None,
            cpu_pct: f64::NAN,
            ..row.clone()
        };
        let plain = TelemetryRow { learning: None, role: Member::Supervisor, ..row.clone() };
        let lines: Vec<String> =
            [&row, &gpu, &plain].iter().map(|r| r.to_line().unwrap()).collect();
        assert_eq!(lines[0].trim_end().split(',').count(), HEADER.split(',').count());
        // A resumed run's file: a second header inside.
        std::fs::write(
            dir.join("telemetry.csv"),
            format!("{HEADER}\n{}{}{HEADER}\n{}", lines[0], lines[1], lines[2]),
        )
        .unwrap();
        let back = read(&dir).unwrap();
        assert_eq!(back.len(), 3);
        assert_eq!(back[0], TelemetryRow { rss_mb: 310.4, ..row.clone() });
        assert_eq!((back[1].gpu, back[1].policy_lag), (gpu.gpu, None));
        assert!(back[1].cpu_pct.is_nan());
        assert_eq!((back[2].learning, back[2].role), (None, Member::Supervisor));
        std::fs::write(
            dir.join("telemetry.csv"),
            format!("{HEADER}\n{}", lines[0].replace(",2400,", ",many,")),
        )
        .unwrap();
        let e = read(&dir).unwrap_err().to_string();
        assert!(e.contains("telemetry.csv") && e.contains("work"), "{e}");
        std::fs::write(dir.join("telemetry.csv"), format!("{HEADER}\n1,2,3\n")).unwrap();
        assert!(read(&dir).unwrap_err().to_string().contains("telemetry.csv"));
        let _ = std::fs::remove_dir_all(&dir);
    }
}
