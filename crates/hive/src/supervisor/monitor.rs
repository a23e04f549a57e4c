//! The monitor: the roles' telemetry (cumulative counters, stage timers)
//! joined once a second with each process's CPU and memory, the machine's
//! CPU and the GPU's readings, written as typed rows of `telemetry.csv`
//! (`rotorhive_records::TelemetryRow`), and summed for the progress line and
//! `summary.json`.

use std::collections::BTreeMap;
use std::path::Path;
use std::sync::Arc;

use anyhow::Result;
use rotorhive_msg::{Counters, RoleKind, Telemetry};
use rotorhive_records::{HostRole, HostSummary, Member, TelemetryRow};
use rotorhive_roles::Config;
use rotorhive_transport::Receiver;
use rotorhive_transport::Service;
use sysinfo::{Pid, ProcessesToUpdate, System};

use super::records::{Counts, Mean, Series, Table};
use crate::gpu_monitor::{GpuMonitor, GpuReading};

/// What the monitor knows of a run.
pub(super) struct Monitor {
    table: Table,
    /// Each role's newest telemetry sample, by (role, index).
    pub(super) latest: BTreeMap<(u32, u32), Telemetry>,
    /// What earlier processes of each role counted before they were
    /// restarted (the counters a new process starts again at 0), by
    /// (role, index): a restarted role's work and losses stay in the run's
    /// totals.
    carried: BTreeMap<(u32, u32), Carried>,
    sys: System,
    gpu: GpuMonitor,
    /// Whole-machine CPU %, over the run.
    pub(super) cpu: Mean,
    /// GPU utilisation, power and memory, over the run.
    pub(super) gpu_util: Mean,
    pub(super) gpu_power: Mean,
    pub(super) gpu_mem: Mean,
    /// The learner's policy lag, over the run.
    pub(super) policy_lag: Mean,
    /// CPU % of the machine per process, for `utilisation.png`.
    pub(super) util: BTreeMap<String, Series>,
    /// Peak of the processes' summed resident memory.
    pub(super) peak_rss_mb: f64,
}

/// One second's reading, for the progress line.
pub(super) struct Reading {
    pub(super) machine_cpu: f64,
    pub(super) gpu: Option<GpuReading>,
    /// The rows written to `telemetry.csv`.
    pub(super) rows: Vec<TelemetryRow>,
}

impl Monitor {
    /// Opens `telemetry.csv` (appended to when the run is resumed).
    pub(super) fn open(run_dir: &Path, resumed: bool) -> Result<Self> {
        Ok(Self {
            table: Table::open(
                run_dir,
                "telemetry.csv",
                rotorhive_records::telemetry::HEADER,
                resumed,
            )?,
            latest: BTreeMap::new(),
            carried: BTreeMap::new(),
            sys: System::new()
                .map_err(|e| anyhow::anyhow!("cannot read system statistics: {e}"))?,
            gpu: GpuMonitor::new(),
            cpu: Mean::default(),
            gpu_util: Mean::default(),
            gpu_power: Mean::default(),
            gpu_mem: Mean::default(),
            policy_lag: Mean::default(),
            util: BTreeMap::new(),
            peak_rss_mb: 0.0,
        })
    }

    /// Takes every telemetry sample waiting.
    pub(super) fn receive<S: Service>(
        &mut self,
        rx: &mut Receiver<S, u8, Telemetry>,
    ) -> Result<()> {
        while let Some(m) = rx.try_recv()? {
            self.take(*m.user_header());
        }
        Ok(())
    }

    /// Takes one sample: the role's newest, and, when it comes from a new
    /// process of the role, what the ended one counted is carried.
    fn take(&mut self, t: Telemetry) {
        let key = (t.role, t.index);
        if let Some(old) = self.latest.get(&key).filter(|old| restarted(old, &t)) {
            self.carried.entry(key).or_default().add(old);
        }
        self.latest.insert(key, t);
    }

    /// A role's counters over the run: its newest sample plus what its
    /// earlier processes counted.
    fn total(&self, t: &Telemetry) -> Carried {
        let c = self.carried.get(&(t.role, t.index)).copied().unwrap_or_default();
        Carried { work: c.work + t.work, lost: c.lost + t.lost }
    }

    /// The main work counter summed over every instance of `role`, across
    /// restarts.
    pub(super) fn sum_work(&self, role: RoleKind) -> u64 {
        let of = self.latest.values().filter(|t| t.role == role as u32);
        of.map(|t| self.total(t).work).sum()
    }

    /// What the teachers did: the sims' labels, demonstrated steps and
    /// planner time, the actors' demonstrations and labelled transitions
    /// sent (their newest samples; a restarted role's count starts again).
    pub(super) fn teacher(&self) -> rotorhive_msg::TeacherCounts {
        let mut c = rotorhive_msg::TeacherCounts::default();
        for t in self.latest.values() {
            let x = &t.teacher;
            if t.role == RoleKind::Sim as u32 {
                c.labels += x.labels;
                c.demo_steps += x.demo_steps;
                c.label_ns += x.label_ns;
                c.demo_ns += x.demo_ns;
            } else if t.role == RoleKind::Actor as u32 {
                c.demo_transitions += x.demo_transitions;
                c.labelled_transitions += x.labelled_transitions;
            }
        }
        c
    }

    /// Messages lost (sequence gaps, batches given up), every role, across
    /// restarts.
    pub(super) fn lost(&self) -> u64 {
        self.latest.values().map(|t| self.total(t).lost).sum()
    }

    /// Agent-steps, learner updates and replay size, from the telemetry.
    pub(super) fn counts(&self) -> Counts {
        let replay = match self.latest.get(&(RoleKind::Replay as u32, 0)).and_then(|t| t.counters())
        {
            Some(Counters::Replay { size, .. }) => size as i64,
            _ => 0,
        };
        (self.sum_work(RoleKind::Sim), self.sum_work(RoleKind::Learner), replay)
    }

    /// Agent-steps of the sims of environments `from..to`.
    pub(super) fn steps_of(&self, from: u32, to: u32) -> u64 {
        self.latest
            .values()
            .filter(|t| t.role == RoleKind::Sim as u32 && (from..to).contains(&t.index))
            .map(|t| self.total(t).work)
            .sum()
    }

    /// Reads CPU, memory and GPU and writes one row per role to
    /// `telemetry.csv`, plus the supervisor's own row when the roles are
    /// processes of their own (in serial mode its CPU is the whole run's).
    pub(super) fn sample(
        &mut self,
        wall: f64,
        mut pids: Vec<Pid>,
        processes: bool,
    ) -> Result<Reading> {
        let me = Pid::from_u32(std::process::id());
        // The link runs in this process: its telemetry carries this pid.
        pids.push(me);
        self.sys.refresh_cpu_usage();
        self.sys.refresh_processes(ProcessesToUpdate::Some(&pids), true);
        let machine = self.sys.global_cpu_usage() as f64;
        self.cpu.add(machine);
        let gpu = self.gpu.read();
        if let Some(g) = gpu {
            self.gpu_util.add(g.util_pct);
            self.gpu_power.add(g.power_w);
            self.gpu_mem.add(g.mem_mb);
            self.util.entry("GPU".into()).or_default().push((wall, g.util_pct));
        }
        self.util.entry("machine CPU".into()).or_default().push((wall, machine));
        let cores = self.sys.cpus().len().max(1) as f64;
        let mut rows: Vec<TelemetryRow> =
            self.latest.values().map(|t| role_row(t, wall, machine, gpu)).collect();
        if processes {
            rows.push(TelemetryRow {
                role: Member::Supervisor,
                pid: me.as_u32(),
                ..role_row(&Telemetry::default(), wall, machine, gpu)
            });
        }
        let mut rss_total = 0.0;
        for row in &mut rows {
            if let Some(p) = self.sys.process(Pid::from_u32(row.pid)) {
                (row.cpu_pct, row.rss_mb) = (p.cpu_usage() as f64, p.memory() as f64 / 1e6);
                rss_total += row.rss_mb;
                // Per-process CPU is in % of one core; the plot shows % of the machine.
                self.util.entry(row.member_name()).or_default().push((wall, row.cpu_pct / cores));
            }
            if let Some(lag) = row.policy_lag {
                self.policy_lag.add(lag);
            }
            write!(self.table, "{}", row.to_line()?)?;
        }
        self.peak_rss_mb = self.peak_rss_mb.max(rss_total);
        Ok(Reading { machine_cpu: machine, gpu, rows })
    }

    /// `summary.json`'s `hosts`: this host, then every worker host, with the
    /// agent-steps their sims reported and the transitions lost on the way.
    pub(super) fn hosts(
        &self,
        cfg: &Config,
        link: Option<&(Arc<rotorhive_link::HeadStats>, Vec<rotorhive_link::Host>)>,
    ) -> Vec<HostSummary> {
        let lost_here = self
            .latest
            .values()
            .filter(|t| t.role == RoleKind::Replay as u32)
            .map(|t| self.total(t).lost)
            .sum::<u64>();
        let envs = cfg.sim.envs as u32;
        let mut out = vec![HostSummary {
            name: super::launcher::host_name(),
            role: HostRole::Head,
            envs,
            agents: cfg.sim.agents as u32,
            env_steps: self.steps_of(0, envs),
            lost_transitions: lost_here,
            transitions_sent: 0,
            transitions_acknowledged: 0,
            transitions_resent: 0,
            duplicates_dropped: 0,
            rejected_messages: 0,
            rejected_by_reason: Default::default(),
        }];
        if let Some((stats, hosts)) = link {
            let lost = stats.lost_by_env.lock().map(|v| v.clone()).unwrap_or_default();
            for h in hosts {
                let (a, b) = (h.env_offset, h.env_offset + h.envs);
                let flow = stats.flow_of(h.slot);
                let gaps = lost.get(a as usize..b as usize).map_or(0, |l| l.iter().sum::<u64>());
                out.push(HostSummary {
                    name: h.name.clone(),
                    role: HostRole::Worker,
                    envs: h.envs,
                    agents: h.agents,
                    env_steps: self.steps_of(a, b),
                    lost_transitions: gaps + flow.lost,
                    transitions_sent: flow.sent,
                    transitions_acknowledged: flow.acknowledged,
                    transitions_resent: flow.resent,
                    duplicates_dropped: flow.duplicates,
                    rejected_messages: stats.rejected_from(h.slot),
                    rejected_by_reason: by_reason(stats, h.slot),
                });
            }
            // Messages on keys that name no host of the run.
            let unknown = stats.rejected_from(0);
            if unknown > 0 {
                out.push(HostSummary {
                    name: "unknown".into(),
                    role: HostRole::Unknown,
                    envs: 0,
                    agents: 0,
                    env_steps: 0,
                    lost_transitions: 0,
                    transitions_sent: 0,
                    transitions_acknowledged: 0,
                    transitions_resent: 0,
                    duplicates_dropped: 0,
                    rejected_messages: unknown,
                    rejected_by_reason: by_reason(stats, 0),
                });
            }
        }
        out
    }
}

/// The counters of a role's process that start again at 0 when it is
/// restarted. The learner's updates do not (it resumes from its saved
/// state), so its work is not carried.
#[derive(Debug, Clone, Copy, Default)]
struct Carried {
    work: u64,
    lost: u64,
}

impl Carried {
    /// Carries what an ended process `t` counted.
    fn add(&mut self, t: &Telemetry) {
        if t.role != RoleKind::Learner as u32 {
            self.work += t.work;
        }
        self.lost += t.lost;
    }
}

/// Whether `new` comes from a new process of the role `old` came from: its
/// heartbeat started again, or its process id changed (roles of another
/// host send 0).
fn restarted(old: &Telemetry, new: &Telemetry) -> bool {
    new.heartbeat < old.heartbeat || (new.pid != old.pid && new.pid != 0 && old.pid != 0)
}

/// A host's refusals by reason, as `summary.json` names them.
fn by_reason(stats: &rotorhive_link::HeadStats, slot: u32) -> BTreeMap<String, u64> {
    let reasons = stats.rejected_by_reason(slot);
    reasons.into_iter().map(|(r, n)| (r.name().to_string(), n)).collect()
}

/// A role's row of `telemetry.csv` before its process is read (CPU and
/// memory NaN: a role of another host keeps them so).
fn role_row(t: &Telemetry, wall: f64, machine: f64, gpu: Option<GpuReading>) -> TelemetryRow {
    let role = RoleKind::from_code(t.role);
    TelemetryRow {
        wall_s: wall,
        // A code of no role cannot pass the transport's check; the
        // supervisor row is its own.
        role: role.map_or(Member::Supervisor, Member::from),
        index: t.index,
        pid: t.pid,
        cpu_pct: f64::NAN,
        rss_mb: f64::NAN,
        machine_cpu_pct: machine,
        heartbeat: t.heartbeat,
        work: t.work,
        work2: t.work2,
        weight_version: t.weight_version,
        lost: t.lost,
        stage_ms: std::array::from_fn(|i| t.stage_ns[i] as f64 / 1e6),
        gpu: gpu.map(|g| [g.util_pct, g.mem_mb, g.power_w]),
        value: gauge(t),
        policy_lag: (role == Some(RoleKind::Learner) && t.policy_lag_milli > 0)
            .then(|| t.policy_lag_milli as f64 / 1e3),
        learning: matches!(role, Some(RoleKind::Learner | RoleKind::Actor | RoleKind::Replay))
            .then_some(t.learning),
    }
}

/// The role's gauge of a telemetry sample in its own unit: the learner's
/// mean loss over the updates since its previous sample, the actor's
/// epsilon, the replay's size; empty for sims.
fn gauge(t: &Telemetry) -> String {
    match t.counters() {
        Some(Counters::Learner { loss, .. }) => format!("{loss:.6}"),
        Some(Counters::Actor { epsilon, .. }) => format!("{epsilon:.3}"),
        Some(Counters::Replay { size, .. }) => size.to_string(),
        _ => String::new(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample(role: RoleKind, index: u32, pid: u32, heartbeat: u64, work: u64) -> Telemetry {
        Telemetry { role: role as u32, index, pid, heartbeat, work, lost: 1, ..Default::default() }
    }

    #[test]
    fn what_a_restarted_role_counted_stays_in_the_runs_totals() {
        let dir = std::env::temp_dir().join(format!("rotorhive-monitor-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let mut m = Monitor::open(&dir, false).unwrap();
        // A sim killed after 100 agent-steps, and its new process (heartbeat
        // and work from 0 again, another pid).
        m.take(sample(RoleKind::Sim, 0, 10, 5, 100));
        m.take(sample(RoleKind::Sim, 0, 10, 6, 120));
        m.take(sample(RoleKind::Sim, 0, 11, 1, 20));
        // A worker's sim (pid 0 from another host) restarted: its heartbeat.
        m.take(sample(RoleKind::Sim, 1, 0, 7, 30));
        m.take(sample(RoleKind::Sim, 1, 0, 1, 5));
        // The learner resumes its update count from its saved state.
        m.take(sample(RoleKind::Learner, 0, 12, 9, 50));
        m.take(sample(RoleKind::Learner, 0, 13, 1, 55));
        assert_eq!(m.sum_work(RoleKind::Sim), 120 + 20 + 30 + 5);
        assert_eq!(m.steps_of(1, 2), 35);
        assert_eq!(m.sum_work(RoleKind::Learner), 55);
        // Every process's losses count (1 each): two processes of each of
        // sim 0, sim 1 and the learner.
        assert_eq!(m.lost(), 6);
        let _ = std::fs::remove_dir_all(&dir);
    }
}
