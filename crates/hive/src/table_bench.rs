//! `hive bench table`: the paper's Table II on this machine. Runs `hive
//! train` for every cell of the grid (observation mode × environments ×
//! agents × seed) as a child process, and writes `agent-table.md`,
//! `agent-table.csv` and `agent-table.png` (rolling reward against wall time
//! per cell), with the paper's numbers beside ours.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::Command;

use anyhow::{Context, Result, bail};
use serde::Deserialize;
use serde_json::{Value, json};

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct TableConfig {
    config: PathBuf,
    budget_s: f64,
    seeds: Vec<u64>,
    modes: Vec<String>,
    cells: Vec<[usize; 2]>,
    #[serde(default)]
    set: Vec<String>,
}

/// The paper's Table II: (mode, envs, agents) → (train time, CPU %, GPU %, GPU W).
fn paper(mode: &str, envs: usize, agents: usize) -> Option<(&'static str, u32, u32, u32)> {
    match (mode, envs, agents) {
        ("non-batched", 1, 1) => Some(("3.8 h", 24, 53, 101)),
        ("non-batched", 1, 50) => Some(("18 min", 62, 59, 95)),
        ("batched", 1, 1) => Some(("3.9 h", 24, 54, 92)),
        ("batched", 1, 25) => Some(("17 min", 27, 53, 93)),
        ("batched", 1, 50) => Some(("14 min", 73, 55, 95)),
        ("batched", 2, 37) => Some(("11 min", 31, 56, 91)),
        _ => None,
    }
}

fn load(path: &Path) -> Result<TableConfig> {
    let text = std::fs::read_to_string(path).with_context(|| format!("table config {}: cannot read", path.display()))?;
    let c: TableConfig = toml::from_str(&text).map_err(|e| anyhow::anyhow!("table config {}: {}", path.display(), e.to_string().trim_end()))?;
    if !(c.budget_s.is_finite() && c.budget_s > 0.0) {
        bail!("table config {}: key `budget_s` must be positive, got {}", path.display(), c.budget_s);
    }
    if c.seeds.is_empty() || c.cells.is_empty() || c.modes.is_empty() {
        bail!("table config {}: keys `seeds`, `cells` and `modes` must not be empty", path.display());
    }
    if let Some(m) = c.modes.iter().find(|m| !["batched", "non-batched"].contains(&m.as_str())) {
        bail!("table config {}: key `modes`: {m:?} is neither \"batched\" nor \"non-batched\"", path.display());
    }
    if let Some(cell) = c.cells.iter().find(|c| c[0] == 0 || c[1] == 0) {
        bail!("table config {}: key `cells`: {cell:?} has zero environments or agents", path.display());
    }
    Ok(c)
}

fn fmt_opt(v: &Value, digits: usize) -> String {
    v.as_f64().map_or("—".to_string(), |x| format!("{x:.digits$}"))
}

/// One line per cell over its seeds: how many reached the threshold and the
/// median time to it, a run that missed it counting as slower than the budget
/// (one seed's time swings by tens of seconds; the median reads the trend).
fn medians(md: &mut String, rows: &[Value], budget_s: f64) -> Result<()> {
    writeln!(md, "\nMedian over seeds (a run that missed the threshold counts as slower than the budget):\n")?;
    writeln!(md, "| observations | envs | agents | converged | median time to 300 (s) | median agent-steps/s | median updates/s |")?;
    writeln!(md, "|---|---|---|---|---|---|---|")?;
    let mut cells: Vec<(&str, u64, u64)> = Vec::new();
    for r in rows {
        let cell = (r["mode"].as_str().unwrap_or(""), r["envs"].as_u64().unwrap_or(0), r["agents"].as_u64().unwrap_or(0));
        if !cells.contains(&cell) {
            cells.push(cell);
        }
    }
    let median = |mut v: Vec<f64>| -> f64 {
        v.sort_by(f64::total_cmp);
        let n = v.len();
        if n == 0 { f64::NAN } else if n % 2 == 1 { v[n / 2] } else { (v[n / 2 - 1] + v[n / 2]) / 2.0 }
    };
    for (mode, envs, agents) in cells {
        let of: Vec<&Value> = rows.iter().filter(|r| r["mode"] == mode && r["envs"] == envs && r["agents"] == agents).collect();
        let times: Vec<f64> = of.iter().map(|r| r["time_to_threshold_s"].as_f64().unwrap_or(f64::INFINITY)).collect();
        let converged = times.iter().filter(|t| t.is_finite()).count();
        let t = median(times);
        let time = if t.is_finite() { format!("{t:.0}") } else { format!("> {budget_s:.0}") };
        let of_key = |k: &str| median(of.iter().filter_map(|r| r[k].as_f64()).collect());
        writeln!(md, "| {mode} | {envs} | {agents} | {converged}/{} | {time} | {:.0} | {:.0} |", of.len(), of_key("env_steps_per_s"), of_key("updates_per_s"))?;
    }
    Ok(())
}

pub fn run(config: &Path, out: &Path, json_out: bool) -> Result<()> {
    let tc = load(config)?;
    std::fs::create_dir_all(out).with_context(|| format!("cannot create {}", out.display()))?;
    let exe = std::env::current_exe()?;
    let mut rows = Vec::new();
    let mut curves = Vec::new();
    let total = tc.modes.len() * tc.cells.len() * tc.seeds.len();
    let mut k = 0;
    for mode in &tc.modes {
        for &[envs, agents] in &tc.cells {
            for &seed in &tc.seeds {
                k += 1;
                let name = format!("{mode}-{envs}x{agents}-seed{seed}");
                let dir = out.join(&name);
                let _ = std::fs::remove_dir_all(&dir);
                eprintln!("[{k}/{total}] {name}: up to {:.0} s", tc.budget_s);
                let mut cmd = Command::new(&exe);
                cmd.arg("train").arg(&tc.config).arg("--quiet").arg("--run-dir").arg(&dir).arg("--max-seconds").arg(tc.budget_s.to_string());
                for s in tc.set.iter().cloned().chain([format!("sim.envs={envs}"), format!("sim.agents={agents}"), format!("sim.observation_mode=\"{mode}\""), format!("seed={seed}")]) {
                    cmd.arg("--set").arg(s);
                }
                let status = cmd.status().with_context(|| format!("cell {name}: cannot start hive train"))?;
                let summary: Value = std::fs::read_to_string(dir.join("summary.json"))
                    .ok()
                    .and_then(|t| serde_json::from_str(&t).ok())
                    .unwrap_or_else(|| json!({ "failure": format!("hive train exited with {status} and wrote no summary") }));
                let curve: Vec<(f64, f64)> = std::fs::read_to_string(dir.join("metrics.csv"))
                    .unwrap_or_default()
                    .lines()
                    .filter(|l| l.starts_with("tick,"))
                    .filter_map(|l| {
                        let f: Vec<&str> = l.split(',').collect();
                        Some((f.get(1)?.parse().ok()?, f.get(5)?.parse().ok()?))
                    })
                    .filter(|p: &(f64, f64)| p.1.is_finite())
                    .collect();
                curves.push((format!("{mode} {envs}x{agents} s{seed}"), curve));
                rows.push(json!({
                    "mode": mode, "envs": envs, "agents": agents, "agents_total": envs * agents, "seed": seed,
                    "converged": summary["converged"], "time_to_threshold_s": summary["time_to_threshold_s"],
                    "wall_s": summary["wall_s"], "env_steps_per_s": summary["env_steps_per_s"], "updates_per_s": summary["updates_per_s"],
                    "cpu_util_mean_pct": summary["cpu_util_mean_pct"], "gpu_util_mean_pct": summary["gpu_util_mean_pct"], "gpu_power_mean_w": summary["gpu_power_mean_w"],
                    "rolling_reward": summary["rolling_reward"], "peak_rss_mb": summary["peak_rss_mb"], "failure": summary["failure"],
                    "run_dir": dir.display().to_string(),
                }));
            }
        }
    }
    let mut md = String::new();
    writeln!(md, "# Agent-count table (the paper's Table II) on this machine\n")?;
    writeln!(md, "Budget {:.0} s per cell; threshold: rolling mean of the last 50 episodes ≥ the config's threshold. Paper: i7-11700K + RTX 2070 Super, AirSim.\n", tc.budget_s)?;
    writeln!(md, "| observations | envs | agents | total | seed | time to 300 (s) | agent-steps/s | updates/s | CPU % | GPU % | GPU W | paper time | paper CPU % | paper GPU % | paper GPU W |")?;
    writeln!(md, "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")?;
    let mut csv = String::from("mode,envs,agents,agents_total,seed,converged,time_to_threshold_s,wall_s,env_steps_per_s,updates_per_s,cpu_util_mean_pct,gpu_util_mean_pct,gpu_power_mean_w,paper_time,paper_cpu_pct,paper_gpu_pct,paper_gpu_w\n");
    for r in &rows {
        let (mode, envs, agents) = (r["mode"].as_str().unwrap_or(""), r["envs"].as_u64().unwrap_or(0) as usize, r["agents"].as_u64().unwrap_or(0) as usize);
        let p = paper(mode, envs, agents);
        let time = match r["time_to_threshold_s"].as_f64() {
            Some(t) => format!("{t:.0}"),
            None => format!("> {}", fmt_opt(&r["wall_s"], 0)),
        };
        let pc = |f: fn(&(&str, u32, u32, u32)) -> String| p.as_ref().map_or("—".to_string(), f);
        writeln!(
            md,
            "| {mode} | {envs} | {agents} | {} | {} | {time} | {} | {} | {} | {} | {} | {} | {} | {} | {} |",
            envs * agents,
            r["seed"],
            fmt_opt(&r["env_steps_per_s"], 0),
            fmt_opt(&r["updates_per_s"], 0),
            fmt_opt(&r["cpu_util_mean_pct"], 0),
            fmt_opt(&r["gpu_util_mean_pct"], 0),
            fmt_opt(&r["gpu_power_mean_w"], 0),
            pc(|p| p.0.to_string()),
            pc(|p| p.1.to_string()),
            pc(|p| p.2.to_string()),
            pc(|p| p.3.to_string()),
        )?;
        writeln!(
            csv,
            "{mode},{envs},{agents},{},{},{},{},{},{},{},{},{},{},{},{},{},{}",
            envs * agents,
            r["seed"],
            r["converged"],
            r["time_to_threshold_s"].as_f64().map_or(String::new(), |v| format!("{v:.1}")),
            fmt_opt(&r["wall_s"], 1),
            fmt_opt(&r["env_steps_per_s"], 0),
            fmt_opt(&r["updates_per_s"], 1),
            fmt_opt(&r["cpu_util_mean_pct"], 1),
            r["gpu_util_mean_pct"].as_f64().map_or(String::new(), |v| format!("{v:.1}")),
            r["gpu_power_mean_w"].as_f64().map_or(String::new(), |v| format!("{v:.1}")),
            pc(|p| p.0.to_string()),
            pc(|p| p.1.to_string()),
            pc(|p| p.2.to_string()),
            pc(|p| p.3.to_string()),
        )?;
    }
    if tc.seeds.len() > 1 {
        medians(&mut md, &rows, tc.budget_s)?;
    }
    writeln!(md, "\nGPU columns are empty without an NVIDIA GPU. Runs: {}.", out.display())?;
    std::fs::write(out.join("agent-table.md"), &md)?;
    std::fs::write(out.join("agent-table.csv"), &csv)?;
    crate::draw::lines_plot("rolling reward per cell", "wall time (s)", "rolling reward (50 episodes)", &curves, &out.join("agent-table.png"))?;
    print!("{md}");
    println!("written: {}/agent-table.{{md,csv,png}}", out.display());
    if json_out {
        println!("{}", json!({ "budget_s": tc.budget_s, "rows": rows, "table": out.join("agent-table.md").display().to_string() }));
    }
    Ok(())
}
