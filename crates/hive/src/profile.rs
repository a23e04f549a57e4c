//! `hive profile RUN_DIR`: where the time of a run went. Reads the run's
//! `telemetry.csv` (cumulative stage timings and CPU % of every role, once a
//! second), and reports each role's share of CPU time and of wall time per
//! stage, and names the bottleneck: the role that waits least on the others,
//! at its busiest stage.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::Path;

use anyhow::{Context, Result, bail};
use rotorhive_msg::{RoleKind, stage_names};

struct Row {
    wall: f64,
    cpu: f64,
    machine: f64,
    stages: [f64; 4],
}

fn role_kind(name: &str) -> Option<RoleKind> {
    [RoleKind::Sim, RoleKind::Actor, RoleKind::Replay, RoleKind::Learner].into_iter().find(|r| r.name() == name)
}

/// The report as Markdown text.
pub fn report(run_dir: &Path) -> Result<String> {
    let path = run_dir.join("telemetry.csv");
    let text = std::fs::read_to_string(&path).with_context(|| format!("cannot read {}", path.display()))?;
    let mut rows: BTreeMap<(String, String), Vec<Row>> = BTreeMap::new();
    for (i, line) in text.lines().enumerate().skip(1) {
        let f: Vec<&str> = line.split(',').collect();
        if f.len() < 16 {
            bail!("{}: line {}: expected 16 fields, found {}", path.display(), i + 1, f.len());
        }
        let num = |k: usize| f[k].parse::<f64>().with_context(|| format!("{}: line {}: field {k} is not a number: {:?}", path.display(), i + 1, f[k]));
        let row = Row { wall: num(0)?, cpu: num(4).unwrap_or(f64::NAN), machine: num(6)?, stages: [num(12)?, num(13)?, num(14)?, num(15)?] };
        rows.entry((f[1].to_string(), f[2].to_string())).or_default().push(row);
    }
    if rows.is_empty() {
        bail!("{}: no telemetry rows", path.display());
    }
    let mut out = String::new();
    writeln!(out, "# Profile of {}\n", run_dir.display())?;
    writeln!(out, "| role | CPU % (mean) | share of CPU | {} |", ["stage 0", "stage 1", "stage 2", "stage 3"].join(" | "))?;
    writeln!(out, "|---|---|---|---|---|---|---|")?;
    let total_cpu: f64 = rows.values().map(|r| mean(r.iter().map(|x| x.cpu))).filter(|v| v.is_finite()).sum();
    let mut candidates = Vec::new();
    let mut machine = Vec::new();
    for ((role, index), r) in &rows {
        let Some(kind) = role_kind(role) else { continue };
        let names = stage_names(kind);
        // Cumulative timings: the difference over the run, after the first second.
        let (first, last) = (&r[0], &r[r.len() - 1]);
        let span_ms = (last.wall - first.wall) * 1e3;
        if span_ms <= 0.0 {
            continue;
        }
        let share: Vec<f64> = (0..4).map(|k| (last.stages[k] - first.stages[k]) / span_ms).collect();
        let cpu = mean(r.iter().map(|x| x.cpu));
        machine.extend(r.iter().map(|x| x.machine));
        let cells: Vec<String> = (0..4).map(|k| format!("{} {:.0} %", names[k], share[k] * 100.0)).collect();
        writeln!(out, "| {role}-{index} | {cpu:.0} | {:.0} % | {} |", cpu / total_cpu * 100.0, cells.join(" | "))?;
        // The waiting stage: transport for every role, idle for the replay.
        let wait = if kind == RoleKind::Replay { share[2] + share[3] } else { share[3] };
        let (busiest, busy) = (0..4).filter(|k| names[*k] != "transport_wait" && names[*k] != "idle").map(|k| (names[k], share[k])).fold(("", -1.0), |a, b| if b.1 > a.1 { b } else { a });
        candidates.push((wait, format!("{role}-{index}"), busiest, busy));
    }
    let machine_cpu = mean(machine.into_iter());
    writeln!(out, "\nStage columns: share of the role's wall time spent in each stage; `transport_wait` / `idle` is time spent waiting on another process.")?;
    writeln!(out, "Machine CPU: {machine_cpu:.0} % on average over {} cores.", std::thread::available_parallelism().map(|n| n.get()).unwrap_or(1))?;
    candidates.sort_by(|a, b| a.0.total_cmp(&b.0));
    if let Some((wait, role, stage, busy)) = candidates.first() {
        writeln!(out, "\n**Bottleneck: {role}, stage `{stage}`** ({:.0} % of its wall time; it waits on others only {:.0} % of the time).", busy * 100.0, wait * 100.0)?;
        if machine_cpu > 85.0 {
            writeln!(out, "The machine's CPU is saturated ({machine_cpu:.0} %): the roles compete for cores, so the run is CPU-bound, as in the paper.")?;
        }
    }
    Ok(out)
}

fn mean(it: impl Iterator<Item = f64>) -> f64 {
    let v: Vec<f64> = it.filter(|x| x.is_finite()).collect();
    if v.is_empty() { f64::NAN } else { v.iter().sum::<f64>() / v.len() as f64 }
}

/// `hive profile RUN_DIR`: prints the report and writes `profile.md`.
pub fn run(run_dir: &Path) -> Result<()> {
    let r = report(run_dir)?;
    print!("{r}");
    std::fs::write(run_dir.join("profile.md"), &r).with_context(|| format!("cannot write {}", run_dir.join("profile.md").display()))?;
    Ok(())
}
