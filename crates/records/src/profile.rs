//! `hive profile RUN_DIR`: where the time of a run went. Reads the run's
//! `telemetry.csv` (cumulative stage timings and CPU % of every role, once a
//! second), and reports each role's share of CPU time and of wall time per
//! stage, and names the bottleneck: the role that waits least on the others,
//! at its busiest stage.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::Path;

use crate::{RecordsError, Result};
use rotorhive_msg::{RoleKind, stage_names};

use crate::Member;
use crate::telemetry::TelemetryRow;

/// One role's figures over a run.
pub struct RoleProfile {
    /// `learner-0`, `sim-1`, …
    pub name: String,
    /// Its kind.
    pub kind: RoleKind,
    /// Mean CPU % of the process (100 = one core).
    pub cpu: f64,
    /// Stage names and the share of the role's wall time in each.
    pub stages: [(&'static str, f64); 4],
    /// Share of wall time spent waiting on other processes.
    pub wait: f64,
}

/// The bottleneck of a run: the role that waits least on the others.
pub struct Bottleneck {
    /// The role, as `learner-0`.
    pub role: String,
    /// Its busiest stage.
    pub stage: &'static str,
    /// That stage's share of the role's wall time.
    pub busy: f64,
    /// The role's share of wall time spent waiting on others.
    pub wait: f64,
}

impl std::fmt::Display for Bottleneck {
    /// The sentence the run prints at its end and `profile.md` shows.
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "Bottleneck: {}, stage `{}` ({:.0} % of its wall time; it waits on others only {:.0} % \
             of the time).",
            self.role,
            self.stage,
            self.busy * 100.0,
            self.wait * 100.0
        )
    }
}

/// What `hive profile` reads from a run's telemetry.
pub struct Profile {
    /// Every role, in name order.
    pub roles: Vec<RoleProfile>,
    /// Mean whole-machine CPU % (100 = every core busy).
    pub machine_cpu: f64,
    /// None when no role ran long enough to tell.
    pub bottleneck: Option<Bottleneck>,
    /// Mean CPU % of `hive train`'s own process (monitor, evaluator and, on
    /// a head, the link), when the roles ran as processes of their own.
    pub supervisor_cpu: Option<f64>,
    /// Mean policy lag of the learner's minibatches (weight versions).
    pub policy_lag: Option<f64>,
    /// The learner's diagnostics over the run: (wall s, mean max-Q, mean
    /// |TD error|, terminal share) per telemetry row.
    pub learning: Vec<(f64, f64, f64, f64)>,
    /// Updates the learner skipped for a non-finite loss or gradient.
    pub skipped_updates: u32,
    /// The smallest and largest epsilon of every actor at the end.
    pub epsilon_spread: Option<(f64, f64)>,
    /// The teacher's planner's share of each sim's wall time (outside the
    /// sims' stages), from `summary.json`; none without a teacher.
    pub teacher_share: Option<f64>,
    /// What the teacher gave and what it cost, from `summary.json` (a run
    /// still going, or one without a teacher, has none).
    pub teaching: Option<crate::Teaching>,
}

impl Profile {
    /// Whether the machine's cores were busy almost all the time.
    pub fn saturated(&self) -> bool {
        self.machine_cpu > 85.0
    }
}

/// Reads a run's `telemetry.csv`.
pub fn analyse(run_dir: &Path) -> Result<Profile> {
    let mut rows: BTreeMap<(Member, u32), Vec<TelemetryRow>> = BTreeMap::new();
    for row in crate::telemetry::read(run_dir)? {
        rows.entry((row.role, row.index)).or_default().push(row);
    }
    if rows.is_empty() {
        return Err(RecordsError::NoTelemetry(run_dir.join("telemetry.csv").display().to_string()));
    }
    let mut roles = Vec::new();
    let mut machine = Vec::new();
    let supervisor_cpu =
        rows.get(&(Member::Supervisor, 0)).map(|r| mean(r.iter().map(|x| x.cpu_pct)));
    let policy_lag = rows
        .get(&(Member::Learner, 0))
        .map(|r| mean(r.iter().filter_map(|x| x.policy_lag)))
        .filter(|v| v.is_finite());
    let learner_rows = rows.get(&(Member::Learner, 0)).map(Vec::as_slice).unwrap_or(&[]);
    let learning: Vec<(f64, f64, f64, f64)> = learner_rows
        .iter()
        .filter_map(|x| {
            x.learning.map(|l| {
                (x.wall_s, l.mean_max_q as f64, l.mean_abs_td as f64, l.terminal_share as f64)
            })
        })
        .filter(|l| l.1 != 0.0)
        .collect();
    let skipped_updates = learner_rows
        .iter()
        .filter_map(|x| x.learning)
        .map(|l| l.skipped_updates)
        .max()
        .unwrap_or(0);
    let ends = rows
        .iter()
        .filter(|((role, _), _)| *role == Member::Actor)
        .filter_map(|(_, r)| r.last()?.learning);
    let epsilon_spread = ends.fold(None, |acc: Option<(f64, f64)>, l| {
        let (lo, hi) = (l.eps_min as f64, l.eps_max as f64);
        Some(acc.map_or((lo, hi), |(a, b)| (a.min(lo), b.max(hi))))
    });
    for ((role, index), r) in &rows {
        if let Some(p) = role_profile(*role, *index, r) {
            machine.extend(r.iter().map(|x| x.machine_cpu_pct));
            roles.push(p);
        }
    }
    let summary = crate::Summary::read(run_dir).ok();
    let teacher_share = summary.as_ref().and_then(|s| teacher_share(s, &roles));
    let bottleneck = bottleneck(&roles, teacher_share);
    Ok(Profile {
        roles,
        machine_cpu: mean(machine.into_iter()),
        bottleneck,
        supervisor_cpu,
        policy_lag,
        learning,
        skipped_updates,
        epsilon_spread,
        teacher_share,
        teaching: summary.map(|s| s.teaching).filter(|t| t.teacher.is_some()),
    })
}

/// The role that waits least on the others, at its busiest stage; a sim's
/// teacher (its planner, timed outside the sims' stages) counts as a stage
/// of its own, `teacher`.
fn bottleneck(roles: &[RoleProfile], teacher_share: Option<f64>) -> Option<Bottleneck> {
    roles.iter().min_by(|a, b| a.wait.total_cmp(&b.wait)).map(|r| {
        let (stage, busy) = r
            .stages
            .iter()
            .filter(|(n, _)| *n != "transport_wait" && *n != "idle")
            .fold(("", -1.0), |a, b| if b.1 > a.1 { *b } else { a });
        let (stage, busy) = match teacher_share {
            Some(t) if r.kind == RoleKind::Sim && t > busy => ("teacher", t),
            _ => (stage, busy),
        };
        Bottleneck { role: r.name.clone(), stage, busy, wait: r.wait }
    })
}

/// The planner's share of each sim's wall time: the seconds of the run's
/// teacher (`summary.json`'s `teacher_s`, every sim's together) over the
/// sims' wall time; none without a teacher or a sim.
fn teacher_share(s: &crate::Summary, roles: &[RoleProfile]) -> Option<f64> {
    let sims = roles.iter().filter(|r| r.kind == RoleKind::Sim).count();
    (s.teaching.teacher_s > 0.0 && sims > 0 && s.wall_s > 0.0)
        .then(|| s.teaching.teacher_s / (sims as f64 * s.wall_s))
}

/// A role's share of its wall time in each stage (cumulative timings: the
/// difference over its rows) and how much of it it waited on others; none
/// for a member that is not a role or whose rows span no time.
fn role_profile(role: Member, index: u32, r: &[TelemetryRow]) -> Option<RoleProfile> {
    let kind = role.role()?;
    let names = stage_names(kind);
    let (first, last) = (r.first()?, r.last()?);
    let span_ms = (last.wall_s - first.wall_s) * 1e3;
    if span_ms <= 0.0 {
        return None;
    }
    let share: [f64; 4] = std::array::from_fn(|k| (last.stage_ms[k] - first.stage_ms[k]) / span_ms);
    // The waiting stage: transport for every role, idle for the replay.
    let wait = match kind {
        RoleKind::Replay => share[2] + share[3],
        // A link waits for the network (receive) or for its receiver (send_wait).
        RoleKind::Link => share[0] + share[3],
        _ => share[3],
    };
    Some(RoleProfile {
        name: format!("{role}-{index}"),
        kind,
        cpu: mean(r.iter().map(|x| x.cpu_pct)),
        stages: std::array::from_fn(|k| (names[k], share[k])),
        wait,
    })
}

/// The report as Markdown text.
pub fn report(run_dir: &Path) -> Result<String> {
    analyse(run_dir)?.markdown(run_dir)
}

impl Profile {
    /// The report as Markdown text (`profile.md`), for the run in `run_dir`.
    pub fn markdown(&self, run_dir: &Path) -> Result<String> {
        markdown(self, run_dir)
    }
}

fn markdown(p: &Profile, run_dir: &Path) -> Result<String> {
    let mut out = String::new();
    writeln!(out, "# Profile of {}\n", run_dir.display())?;
    writeln!(
        out,
        "| role | CPU % (mean) | share of CPU | {} |",
        ["stage 0", "stage 1", "stage 2", "stage 3"].join(" | ")
    )?;
    writeln!(out, "|---|---|---|---|---|---|---|")?;
    let total_cpu: f64 =
        p.roles.iter().map(|r| r.cpu).chain(p.supervisor_cpu).filter(|v| v.is_finite()).sum();
    for r in &p.roles {
        let cells: Vec<String> =
            r.stages.iter().map(|(n, s)| format!("{n} {:.0} %", s * 100.0)).collect();
        if r.cpu.is_finite() {
            writeln!(
                out,
                "| {} | {:.0} | {:.0} % | {} |",
                r.name,
                r.cpu,
                r.cpu / total_cpu * 100.0,
                cells.join(" | ")
            )?;
        } else {
            // Roles of other hosts: their CPU is not this machine's to read.
            writeln!(out, "| {} | — (other host) | — | {} |", r.name, cells.join(" | "))?;
        }
    }
    if let Some(cpu) = p.supervisor_cpu.filter(|c| c.is_finite()) {
        writeln!(
            out,
            "| supervisor (monitor, evaluator, link) | {cpu:.0} | {:.0} % | — | — | — | — |",
            cpu / total_cpu * 100.0
        )?;
    }
    writeln!(
        out,
        "\nStage columns: share of the role's wall time spent in each stage; `transport_wait` / `idle` is time spent waiting on another process."
    )?;
    if let Some(lag) = p.policy_lag {
        writeln!(
            out,
            "Policy lag: the learner trained on transitions acted {lag:.1} weight versions behind its own, on average."
        )?;
    }
    learning_section(&mut out, p)?;
    teacher_section(&mut out, p)?;
    writeln!(
        out,
        "Machine CPU: {:.0} % on average over {} cores.",
        p.machine_cpu,
        std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1)
    )?;
    if let Some(b) = &p.bottleneck {
        writeln!(out, "\n**{b}**")?;
        if p.saturated() {
            writeln!(
                out,
                "The machine's CPU is saturated ({:.0} %): the roles compete for cores, so the run is CPU-bound, as in the paper.",
                p.machine_cpu
            )?;
        }
    }
    Ok(out)
}

/// The learning diagnostics: where the learner's values and errors went
/// over the run (a collapse shows as max-Q drifting up while the TD error
/// grows), the terminal share of its minibatches and the exploration spread.
fn learning_section(out: &mut String, p: &Profile) -> Result<()> {
    if !p.learning.is_empty() {
        writeln!(out, "\nLearning (learner telemetry; values in reward units):\n")?;
        writeln!(
            out,
            "| wall (s) | mean max-Q | mean abs TD error | terminal share of minibatches |"
        )?;
        writeln!(out, "|---|---|---|---|")?;
        // About eight rows spread over the run, the last one included.
        let step = p.learning.len().div_ceil(8).max(1);
        let last = p.learning.len() - 1;
        for (_, (t, q, td, term)) in
            p.learning.iter().enumerate().filter(|(i, _)| i % step == 0 || *i == last)
        {
            writeln!(out, "| {t:.0} | {q:.2} | {td:.3} | {:.2} % |", term * 100.0)?;
        }
        writeln!(out)?;
    }
    if p.skipped_updates > 0 {
        writeln!(out, "Skipped updates (non-finite loss or gradient): {}.", p.skipped_updates)?;
    }
    if let Some((lo, hi)) = p.epsilon_spread {
        writeln!(
            out,
            "Exploration at the end: epsilon from {lo:.4} to {hi:.3} across the agents."
        )?;
    }
    Ok(())
}

/// The teacher's cost: the planner's time per action it gave, and what it
/// gave.
fn teacher_section(out: &mut String, p: &Profile) -> Result<()> {
    let share = p.teacher_share.unwrap_or(0.0);
    if let Some(s) = &p.teaching {
        let ms = |v: Option<f64>| v.map_or("—".to_string(), |v| format!("{v:.3} ms"));
        writeln!(
            out,
            "Teacher (the sims' planner, outside their stages): {} per label, {} per demonstrated step ({:.0} % of each sim's wall time); {} demonstrations and {} labelled transitions sent.",
            ms(s.teacher_ms_per_label),
            ms(s.teacher_ms_per_demo_step),
            share * 100.0,
            s.demo_transitions,
            s.labelled_transitions
        )?;
    }
    Ok(())
}

fn mean(it: impl Iterator<Item = f64>) -> f64 {
    let v: Vec<f64> = it.filter(|x| x.is_finite()).collect();
    if v.is_empty() { f64::NAN } else { v.iter().sum::<f64>() / v.len() as f64 }
}

/// `hive profile RUN_DIR`: prints the report and writes `profile.md`.
pub fn run(run_dir: &Path) -> Result<()> {
    let r = report(run_dir)?;
    print!("{r}");
    let path = run_dir.join("profile.md");
    std::fs::write(&path, &r).map_err(RecordsError::io("write", &path))?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn role(kind: RoleKind, busy: [f64; 3], wait: f64) -> RoleProfile {
        let names = stage_names(kind);
        RoleProfile {
            name: format!("{}-0", Member::from(kind)),
            kind,
            cpu: 50.0,
            stages: std::array::from_fn(|k| (names[k], if k < 3 { busy[k] } else { wait })),
            wait,
        }
    }

    #[test]
    fn a_sims_teacher_is_its_busiest_stage_where_it_takes_the_most_time() {
        // A run with a teacher, as measured on L1 (labels on every step):
        // the sim waits least, its stages fill a fifth of its time.
        let roles = [
            role(RoleKind::Sim, [0.01, 0.09, 0.0], 0.12),
            role(RoleKind::Learner, [0.42, 0.28, 0.04], 0.25),
        ];
        let b = bottleneck(&roles, Some(0.56)).expect("roles");
        assert_eq!((b.role.as_str(), b.stage), ("sim-0", "teacher"));
        assert!((b.busy - 0.56).abs() < 1e-12);
        // Without a teacher (or with a cheap one) the sim's busiest stage.
        assert_eq!(bottleneck(&roles, None).expect("roles").stage, "render");
        assert_eq!(bottleneck(&roles, Some(0.05)).expect("roles").stage, "render");
        // The teacher is a sim's: another role's bottleneck keeps its stage.
        let learner_bound = [
            role(RoleKind::Sim, [0.01, 0.09, 0.0], 0.40),
            role(RoleKind::Learner, [0.42, 0.28, 0.04], 0.10),
        ];
        let b = bottleneck(&learner_bound, Some(0.56)).expect("roles");
        assert_eq!((b.role.as_str(), b.stage), ("learner-0", "forward"));
    }

    #[test]
    fn the_teachers_line_gives_its_costs_and_is_absent_without_one() {
        let mut p = Profile {
            roles: vec![role(RoleKind::Sim, [0.01, 0.09, 0.0], 0.12)],
            machine_cpu: 90.0,
            bottleneck: None,
            supervisor_cpu: None,
            policy_lag: None,
            learning: Vec::new(),
            skipped_updates: 0,
            epsilon_spread: None,
            teacher_share: Some(0.49),
            teaching: None,
        };
        let mut out = String::new();
        teacher_section(&mut out, &p).expect("write");
        assert_eq!(out, "");
        // L2's camera planner, as `runs/l2-ten` measured it: labels only.
        p.teaching = Some(crate::Teaching {
            teacher: Some(serde_json::json!({"policy": "planner", "sight": "view"})),
            demo_transitions: 0,
            labelled_transitions: 94_384,
            teacher_ms_per_label: Some(0.313),
            teacher_ms_per_demo_step: None,
            teacher_s: 147.0,
        });
        teacher_section(&mut out, &p).expect("write");
        for part in ["0.313 ms per label", "— per demonstrated step", "(49 % of", "94384 labelled"]
        {
            assert!(out.contains(part), "{part:?} missing from {out:?}");
        }
    }
}
