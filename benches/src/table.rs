//! `hive bench table`: the paper's Table II on this machine. Runs `hive
//! train` for every cell of the grid (observation mode × environments ×
//! agents × seed) as a child process, and writes `agent-table.md`,
//! `agent-table.csv` and `agent-table.png` (rolling reward against wall time
//! per cell), with the paper's numbers beside ours.

use std::fmt::Write as _;
use std::path::{Path, PathBuf};
use std::process::Command;

use crate::error::{BenchError, Doing, Result, usage};
use serde::Deserialize;
use serde_json::json;

use crate::stats::median;
use rotorhive_records::rows::{MetricsKind, MetricsRow};

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
    /// Cells of E > 1 environments run as E hosts, as the paper's two PCs:
    /// the head (`hive train --listen`) with one environment and E − 1
    /// workers (`hive worker`) with one each, every host in its own
    /// shared-memory domain, joined over TCP loopback.
    #[serde(default)]
    split_hosts: bool,
    /// When above 0, every cell is a deterministic run (`deterministic =
    /// true`) of this many agent-steps: a cell gives the same episodes and
    /// weights every time, so cells differ only by what they are, not by the
    /// processes' timing (the wall-clock `budget_s` still bounds each run).
    #[serde(default)]
    deterministic_env_steps: u64,
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
    let text = std::fs::read_to_string(path)
        .doing_with(|| format!("table config {}: cannot read", path.display()))?;
    let c: TableConfig = toml::from_str(&text).map_err(|e| {
        BenchError::Usage(format!("table config {}: {}", path.display(), e.to_string().trim_end()))
    })?;
    if !(c.budget_s.is_finite() && c.budget_s > 0.0) {
        usage!(
            "table config {}: key `budget_s` must be positive, got {}",
            path.display(),
            c.budget_s
        );
    }
    if c.seeds.is_empty() || c.cells.is_empty() || c.modes.is_empty() {
        usage!(
            "table config {}: keys `seeds`, `cells` and `modes` must not be empty",
            path.display()
        );
    }
    if let Some(m) = c.modes.iter().find(|m| !["batched", "non-batched"].contains(&m.as_str())) {
        usage!(
            "table config {}: key `modes`: {m:?} is neither \"batched\" nor \"non-batched\"",
            path.display()
        );
    }
    if c.deterministic_env_steps > 0 && c.split_hosts {
        usage!(
            "table config {}: `deterministic_env_steps` cannot be combined with `split_hosts` (deterministic runs are one host's)",
            path.display()
        );
    }
    if let Some(cell) = c.cells.iter().find(|c| c[0] == 0 || c[1] == 0) {
        usage!(
            "table config {}: key `cells`: {cell:?} has zero environments or agents",
            path.display()
        );
    }
    Ok(c)
}

/// One run of the grid: the row of `agent-table.csv` and of the JSON's
/// `rows`, read from the run's typed summary and profile (`None` where the
/// run wrote no summary).
#[derive(Debug, Clone, serde::Serialize)]
struct CellRow {
    mode: String,
    envs: usize,
    agents: usize,
    agents_total: usize,
    seed: u64,
    hosts: usize,
    converged: bool,
    time_to_threshold_s: Option<f64>,
    wall_s: Option<f64>,
    env_steps_per_s: Option<f64>,
    updates_per_s: Option<f64>,
    cpu_util_mean_pct: Option<f64>,
    gpu_util_mean_pct: Option<f64>,
    gpu_power_mean_w: Option<f64>,
    /// The role and stage that set the pace: `learner-0 forward`.
    bottleneck: Option<String>,
    bottleneck_busy_pct: Option<f64>,
    rolling_reward: Option<f64>,
    peak_rss_mb: Option<f64>,
    failure: Option<String>,
    run_dir: String,
}

impl CellRow {
    /// The bottleneck as the table shows it: `learner-0 forward (52 %)`.
    fn bottleneck_cell(&self) -> String {
        match (&self.bottleneck, self.bottleneck_busy_pct) {
            (Some(b), Some(p)) => format!("{b} ({p:.0} %)"),
            _ => "—".to_string(),
        }
    }
}

fn fmt_opt(v: Option<f64>, digits: usize) -> String {
    v.map_or("—".to_string(), |x| format!("{x:.digits$}"))
}

/// An optional value for CSV: empty when absent.
fn csv_opt(v: Option<f64>, digits: usize) -> String {
    v.map_or(String::new(), |x| format!("{x:.digits$}"))
}

/// One cell of the grid over its seeds.
#[derive(Debug)]
struct CellMedian {
    mode: String,
    envs: u64,
    agents: u64,
    runs: usize,
    converged: usize,
    /// Median time to the threshold; infinite when the median run missed it.
    time: f64,
    steps_per_s: f64,
    updates_per_s: f64,
    /// The bottleneck most of the cell's runs name.
    bottleneck: Option<String>,
}

/// The distinct items of `it`, in order of first appearance.
fn distinct<T: PartialEq>(it: impl IntoIterator<Item = T>) -> Vec<T> {
    let mut out = Vec::new();
    for x in it {
        if !out.contains(&x) {
            out.push(x);
        }
    }
    out
}

/// The cells of `rows` in order of first appearance, with the medians over
/// their seeds; a run that missed the threshold counts as slower than any.
fn cell_medians(rows: &[CellRow]) -> Vec<CellMedian> {
    distinct(rows.iter().map(|r| (r.mode.as_str(), r.envs, r.agents)))
        .into_iter()
        .map(|(mode, envs, agents)| {
            let of: Vec<&CellRow> = rows
                .iter()
                .filter(|r| r.mode == mode && r.envs == envs && r.agents == agents)
                .collect();
            let times: Vec<f64> =
                of.iter().map(|r| r.time_to_threshold_s.unwrap_or(f64::INFINITY)).collect();
            let med = |f: fn(&CellRow) -> Option<f64>| {
                median(&of.iter().filter_map(|r| f(r)).collect::<Vec<_>>())
            };
            let named: Vec<&str> = of.iter().filter_map(|r| r.bottleneck.as_deref()).collect();
            let bottleneck = named
                .iter()
                .max_by_key(|b| named.iter().filter(|x| x == b).count())
                .map(|b| b.to_string());
            CellMedian {
                mode: mode.to_string(),
                envs: envs as u64,
                agents: agents as u64,
                runs: of.len(),
                converged: times.iter().filter(|t| t.is_finite()).count(),
                time: median(&times),
                steps_per_s: med(|r| r.env_steps_per_s),
                updates_per_s: med(|r| r.updates_per_s),
                bottleneck,
            }
        })
        .collect()
}

fn fmt_time(t: f64, budget_s: f64) -> String {
    if t.is_finite() { format!("{t:.0}") } else { format!("> {budget_s:.0}") }
}

/// One line per cell over its seeds: how many reached the threshold and the
/// median time to it, a run that missed it counting as slower than the budget
/// (one seed's time swings by tens of seconds; the median reads the trend).
fn medians(md: &mut String, cells: &[CellMedian], budget_s: f64) -> Result<()> {
    writeln!(
        md,
        "\nMedian over seeds (a run that missed the threshold counts as slower than the budget):\n"
    )?;
    writeln!(
        md,
        "| observations | envs | agents | converged | median time to 300 (s) | median agent-steps/s | median updates/s | bottleneck |"
    )?;
    writeln!(md, "|---|---|---|---|---|---|---|---|")?;
    for c in cells {
        writeln!(
            md,
            "| {} | {} | {} | {}/{} | {} | {:.0} | {:.0} | {} |",
            c.mode,
            c.envs,
            c.agents,
            c.converged,
            c.runs,
            fmt_time(c.time, budget_s),
            c.steps_per_s,
            c.updates_per_s,
            c.bottleneck.as_deref().unwrap_or("—")
        )?;
    }
    Ok(())
}

/// Agent-steps/s within this fraction of each other count as the same pace.
const SAME_PACE: f64 = 0.15;

/// How much faster (+) or slower (−) cell `b` ran than cell `a`, in agent-steps/s.
fn pace_change(a: &CellMedian, b: &CellMedian) -> f64 {
    b.steps_per_s / a.steps_per_s - 1.0
}

/// Per observation mode: the median times in order of total agents, whether
/// they fall at every step, and, where they do not, whether the two cells ran
/// at the same pace (agent-steps/s), i.e. the machine gave the larger cell no
/// more work per second than the smaller one.
fn trend(md: &mut String, cells: &[CellMedian], budget_s: f64) -> Result<()> {
    let modes = distinct(cells.iter().map(|c| c.mode.as_str()));
    writeln!(md, "\nTrend of the time to the threshold as agents rise:\n")?;
    for mode in modes {
        let mut of: Vec<&CellMedian> = cells.iter().filter(|c| c.mode == mode).collect();
        of.sort_by_key(|c| c.envs * c.agents);
        let path: Vec<String> = of
            .iter()
            .map(|c| {
                let n = c.envs * c.agents;
                format!(
                    "{n} agent{} {} s",
                    if n == 1 { "" } else { "s" },
                    fmt_time(c.time, budget_s)
                )
            })
            .collect();
        let flat: Vec<(&CellMedian, &CellMedian)> = of
            .windows(2)
            .map(|w| (w[0], w[1]))
            .filter(|(a, b)| b.time.partial_cmp(&a.time) != Some(std::cmp::Ordering::Less))
            .collect();
        if of.len() < 2 {
            writeln!(md, "- {mode}: {} (one cell, no trend).", path.join(""))?;
        } else if flat.is_empty() {
            writeln!(md, "- {mode}: {}: falls at every step, as in the paper.", path.join(" → "))?;
        } else {
            let pairs: Vec<String> = flat
                .iter()
                .map(|(a, b)| {
                    let pace = pace_change(a, b);
                    let same = if pace.abs() <= SAME_PACE { ", same pace" } else { "" };
                    format!(
                        "{} → {} agents ({:+.0} % agent-steps/s{same})",
                        a.envs * a.agents,
                        b.envs * b.agents,
                        pace * 100.0
                    )
                })
                .collect();
            writeln!(
                md,
                "- {mode}: {}: **does not fall** at {}.",
                path.join(" → "),
                pairs.join(", ")
            )?;
            if flat.iter().all(|(a, b)| pace_change(a, b).abs() <= SAME_PACE) {
                let named = distinct(
                    flat.iter().flat_map(|(a, b)| [a, b]).filter_map(|c| c.bottleneck.as_deref()),
                );
                let by = if named.is_empty() {
                    String::new()
                } else {
                    format!(" (bottleneck: {})", named.join(", "))
                };
                writeln!(
                    md,
                    "  Where it does not fall, the larger cell ran no more agent-steps per second than the smaller{by}: this machine gives both the same work per second, so the extra agents cannot shorten the run and the difference is run-to-run spread. More cores or a GPU learner raise that ceiling."
                )?;
            }
        }
    }
    Ok(())
}

/// Runs one cell (`mode`, `envs` × `agents`, `seed`; number `of.0` of
/// `of.1`) with its worker hosts if split: its row and its reward curve.
#[allow(clippy::type_complexity)]
fn run_cell(
    tc: &TableConfig,
    out: &Path,
    exe: &Path,
    mode: &str,
    [envs, agents]: [usize; 2],
    seed: u64,
    of: (usize, usize),
) -> Result<(CellRow, (String, Vec<(f64, f64)>))> {
    let name = format!("{mode}-{envs}x{agents}-seed{seed}");
    let dir = out.join(&name);
    let _ = std::fs::remove_dir_all(&dir);
    eprintln!("[{}/{}] {name}: up to {:.0} s", of.0, of.1, tc.budget_s);
    let hosts = if tc.split_hosts { envs } else { 1 };
    let mut cmd = Command::new(exe);
    let endpoint = format!(
        "tcp/127.0.0.1:{}",
        std::net::TcpListener::bind("127.0.0.1:0")?.local_addr()?.port()
    );
    if hosts > 1 {
        cmd.args(["--domain", "table-host0"]);
    }
    cmd.arg("train")
        .arg(&tc.config)
        .arg("--quiet")
        .arg("--run-dir")
        .arg(&dir)
        .arg("--max-seconds")
        .arg(tc.budget_s.to_string());
    let mut sets = vec![
        format!("sim.envs={}", if hosts > 1 { 1 } else { envs }),
        format!("sim.agents={agents}"),
        format!("sim.observation_mode=\"{mode}\""),
        format!("seed={seed}"),
    ];
    if tc.deterministic_env_steps > 0 {
        sets.extend([
            "deterministic=true".to_string(),
            format!("max_env_steps={}", tc.deterministic_env_steps),
        ]);
    }
    if hosts > 1 {
        cmd.args(["--listen", &endpoint]);
        sets.push(format!("cluster.workers={}", hosts - 1));
    }
    for s in tc.set.iter().cloned().chain(sets) {
        cmd.arg("--set").arg(s);
    }
    // A killed harness stops its cell's hosts, as Ctrl-C would.
    rotorhive_transport::dies_with_this_process(&mut cmd, rustix::process::Signal::INT);
    let mut head = cmd.spawn().doing_with(|| format!("cell {name}: cannot start hive train"))?;
    let mut workers = Vec::new();
    for h in 1..hosts {
        let mut w = Command::new(exe);
        w.args(["--domain", &format!("table-host{h}"), "worker", "--connect", &endpoint]);
        w.args(["--agents", &agents.to_string(), "--name", &format!("host{h}"), "--run-dir"])
            .arg(dir.join(format!("worker-{h}")));
        w.stdout(std::process::Stdio::null());
        rotorhive_transport::dies_with_this_process(&mut w, rustix::process::Signal::INT);
        workers.push(w.spawn().doing_with(|| format!("cell {name}: cannot start hive worker"))?);
    }
    let status = head.wait()?;
    for mut w in workers {
        let _ = w.wait();
    }
    let curve: Vec<(f64, f64)> =
        rotorhive_records::rows::read::<MetricsRow>(&dir.join("metrics.csv"))
            .unwrap_or_default()
            .into_iter()
            .filter(|r| r.kind == MetricsKind::Tick)
            .filter_map(|r| Some((r.wall_s, r.rolling_reward?)))
            .filter(|p| p.1.is_finite())
            .collect();
    let row = CellRow::read(&dir, (mode, [envs, agents], seed, hosts), status);
    Ok((row, (format!("{mode} {envs}x{agents} s{seed}"), curve)))
}

impl CellRow {
    /// The row of a finished run in `dir`: (mode, [envs, agents], seed,
    /// hosts) and what its summary and profile say; `status` is `hive
    /// train`'s exit, named when the run wrote no summary.
    fn read(
        dir: &Path,
        (mode, [envs, agents], seed, hosts): (&str, [usize; 2], u64, usize),
        status: std::process::ExitStatus,
    ) -> Self {
        // The cell's result, read through the typed summary `hive train` writes.
        let summary = rotorhive_records::Summary::read(dir);
        let s = summary.as_ref().ok();
        let failure = match &summary {
            Ok(s) => s.failure.clone(),
            Err(e) => Some(format!("hive train exited with {status}: {e:#}")),
        };
        // The paper's finding per cell: which role set the pace.
        let bottleneck = rotorhive_records::profile::analyse(dir).ok().and_then(|p| p.bottleneck);
        Self {
            mode: mode.to_string(),
            envs,
            agents,
            agents_total: envs * agents,
            seed,
            hosts,
            converged: s.is_some_and(|s| s.converged),
            time_to_threshold_s: s.and_then(|s| s.time_to_threshold_s),
            wall_s: s.map(|s| s.wall_s),
            env_steps_per_s: s.map(|s| s.env_steps_per_s),
            updates_per_s: s.map(|s| s.updates_per_s),
            cpu_util_mean_pct: s.and_then(|s| s.cpu_util_mean_pct),
            gpu_util_mean_pct: s.and_then(|s| s.gpu_util_mean_pct),
            gpu_power_mean_w: s.and_then(|s| s.gpu_power_mean_w),
            bottleneck: bottleneck.as_ref().map(|b| format!("{} {}", b.role, b.stage)),
            bottleneck_busy_pct: bottleneck.map(|b| b.busy * 100.0),
            rolling_reward: s.and_then(|s| s.rolling_reward),
            peak_rss_mb: s.map(|s| s.peak_rss_mb),
            failure,
            run_dir: dir.display().to_string(),
        }
    }
}

/// The table as markdown (its header and one line per cell) and as CSV.
fn table_text(tc: &TableConfig, rows: &[CellRow]) -> Result<(String, String)> {
    let mut md = String::new();
    writeln!(md, "# Agent-count table (the paper's Table II) on this machine\n")?;
    if tc.deterministic_env_steps > 0 {
        writeln!(
            md,
            "Every cell is a deterministic run of {} agent-steps (`deterministic = true`): \
             the same episodes and weights every time.\n",
            tc.deterministic_env_steps
        )?;
    }
    writeln!(
        md,
        "Budget {:.0} s per cell; threshold: rolling mean of the last 50 episodes ≥ the config's \
         threshold. Paper: i7-11700K + RTX 2070 Super, AirSim.\n",
        tc.budget_s
    )?;
    writeln!(
        md,
        "| observations | envs | agents | total | seed | time to 300 (s) | agent-steps/s \
         | updates/s | CPU % | bottleneck | GPU % | GPU W | paper time | paper CPU % \
         | paper GPU % | paper GPU W |"
    )?;
    writeln!(md, "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")?;
    let mut csv = String::from(
        "mode,envs,agents,agents_total,seed,converged,time_to_threshold_s,wall_s,\
         env_steps_per_s,updates_per_s,cpu_util_mean_pct,bottleneck,bottleneck_busy_pct,\
         gpu_util_mean_pct,gpu_power_mean_w,paper_time,paper_cpu_pct,paper_gpu_pct,paper_gpu_w\n",
    );
    for r in rows {
        writeln!(md, "{}", r.md_line())?;
        writeln!(csv, "{}", r.csv_line())?;
    }
    Ok((md, csv))
}

impl CellRow {
    /// The paper's (time, CPU %, GPU %, GPU W) for this cell, as text.
    fn paper_cells(&self) -> [String; 4] {
        match paper(&self.mode, self.envs, self.agents) {
            Some(p) => [p.0.to_string(), p.1.to_string(), p.2.to_string(), p.3.to_string()],
            None => std::array::from_fn(|_| "—".to_string()),
        }
    }

    /// Its line of `agent-table.md`.
    fn md_line(&self) -> String {
        let time = match self.time_to_threshold_s {
            Some(t) => format!("{t:.0}"),
            None => format!("> {}", fmt_opt(self.wall_s, 0)),
        };
        let envs =
            if self.hosts > 1 { format!("{} (hosts)", self.envs) } else { self.envs.to_string() };
        let [pt, pc, pg, pw] = self.paper_cells();
        format!(
            "| {} | {envs} | {} | {} | {} | {time} | {} | {} | {} | {} | {} | {} | {pt} | {pc} \
             | {pg} | {pw} |",
            self.mode,
            self.agents,
            self.agents_total,
            self.seed,
            fmt_opt(self.env_steps_per_s, 0),
            fmt_opt(self.updates_per_s, 0),
            fmt_opt(self.cpu_util_mean_pct, 0),
            self.bottleneck_cell(),
            fmt_opt(self.gpu_util_mean_pct, 0),
            fmt_opt(self.gpu_power_mean_w, 0),
        )
    }

    /// Its line of `agent-table.csv`.
    fn csv_line(&self) -> String {
        let [pt, pc, pg, pw] = self.paper_cells();
        format!(
            "{},{},{},{},{},{},{},{},{},{},{},{},{},{},{},{pt},{pc},{pg},{pw}",
            self.mode,
            self.envs,
            self.agents,
            self.agents_total,
            self.seed,
            self.converged,
            csv_opt(self.time_to_threshold_s, 1),
            fmt_opt(self.wall_s, 1),
            fmt_opt(self.env_steps_per_s, 0),
            fmt_opt(self.updates_per_s, 1),
            fmt_opt(self.cpu_util_mean_pct, 1),
            self.bottleneck.as_deref().unwrap_or(""),
            csv_opt(self.bottleneck_busy_pct, 0),
            csv_opt(self.gpu_util_mean_pct, 1),
            csv_opt(self.gpu_power_mean_w, 1),
        )
    }
}

pub fn run(config: &Path, train_config: Option<&Path>, out: &Path, json_out: bool) -> Result<()> {
    let mut tc = load(config)?;
    if let Some(c) = train_config {
        tc.config = c.to_path_buf();
    }
    std::fs::create_dir_all(out).doing_with(|| format!("cannot create {}", out.display()))?;
    let exe = std::env::current_exe()?;
    let mut rows = Vec::new();
    let mut curves = Vec::new();
    let total = tc.modes.len() * tc.cells.len() * tc.seeds.len();
    let mut k = 0;
    for mode in &tc.modes {
        for &[envs, agents] in &tc.cells {
            for &seed in &tc.seeds {
                k += 1;
                let (row, curve) =
                    run_cell(&tc, out, &exe, mode, [envs, agents], seed, (k, total))?;
                rows.push(row);
                curves.push(curve);
            }
        }
    }
    let (mut md, csv) = table_text(&tc, &rows)?;
    let cells = cell_medians(&rows);
    if tc.seeds.len() > 1 {
        medians(&mut md, &cells, tc.budget_s)?;
    }
    trend(&mut md, &cells, tc.budget_s)?;
    if rows.iter().all(|r| r.gpu_util_mean_pct.is_none()) {
        writeln!(md, "\nGPU columns are empty: no NVIDIA GPU was seen (NVML).")?;
    }
    if tc.split_hosts {
        writeln!(
            md,
            "\nCells marked (hosts) ran each environment as a host of its own (the head and `hive worker`s, each in its own shared-memory domain, joined by their links over TCP loopback), as the paper's two PCs; here they share this machine's cores."
        )?;
    }
    writeln!(md, "\nRuns: {}.", out.display())?;
    std::fs::write(out.join("agent-table.md"), &md)?;
    std::fs::write(out.join("agent-table.csv"), &csv)?;
    rotorhive_records::plot::lines_plot(
        "rolling reward per cell",
        "wall time (s)",
        "rolling reward (50 episodes)",
        &curves,
        &out.join("agent-table.png"),
    )?;
    print!("{md}");
    println!("written: {}/agent-table.{{md,csv,png}}", out.display());
    if json_out {
        println!(
            "{}",
            json!({ "budget_s": tc.budget_s, "rows": rows, "table": out.join("agent-table.md").display().to_string() })
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::{CellRow, cell_medians, trend};

    fn row(agents: usize, seed: u64, time: Option<f64>, steps: f64) -> CellRow {
        CellRow {
            mode: "batched".into(),
            envs: 1,
            agents,
            agents_total: agents,
            seed,
            hosts: 1,
            converged: time.is_some(),
            time_to_threshold_s: time,
            wall_s: Some(220.0),
            env_steps_per_s: Some(steps),
            updates_per_s: Some(100.0),
            cpu_util_mean_pct: None,
            gpu_util_mean_pct: None,
            gpu_power_mean_w: None,
            bottleneck: Some("learner-0 forward".into()),
            bottleneck_busy_pct: Some(90.0),
            rolling_reward: None,
            peak_rss_mb: None,
            failure: None,
            run_dir: String::new(),
        }
    }

    fn trend_of(rows: &[CellRow]) -> String {
        let mut md = String::new();
        trend(&mut md, &cell_medians(rows), 220.0).unwrap();
        md
    }

    #[test]
    fn medians_count_a_missed_threshold_as_slowest() {
        let rows = [
            row(1, 1, Some(140.0), 2000.0),
            row(1, 2, Some(150.0), 2200.0),
            row(25, 1, None, 4000.0),
            row(25, 2, Some(90.0), 3800.0),
        ];
        let cells = cell_medians(&rows);
        assert_eq!(cells.len(), 2);
        assert_eq!((cells[0].time, cells[0].converged, cells[0].steps_per_s), (145.0, 2, 2100.0));
        assert!(cells[1].time.is_infinite());
        assert_eq!(cells[1].converged, 1);
        assert_eq!(cells[1].bottleneck.as_deref(), Some("learner-0 forward"));
    }

    #[test]
    fn trend_says_whether_times_fall_and_names_same_pace_cells() {
        let falling = [
            row(1, 1, Some(140.0), 2000.0),
            row(25, 1, Some(90.0), 3800.0),
            row(50, 1, Some(80.0), 5000.0),
        ];
        let md = trend_of(&falling);
        assert!(md.contains("falls at every step"), "{md}");
        assert!(!md.contains("does not fall"), "{md}");

        // 25 → 50 agents: slower, at the same agent-steps/s (+5 %).
        let flat = [
            row(1, 1, Some(140.0), 2000.0),
            row(25, 1, Some(80.0), 3800.0),
            row(50, 1, None, 3990.0),
        ];
        let md = trend_of(&flat);
        assert!(
            md.contains("**does not fall** at 25 → 50 agents (+5 % agent-steps/s, same pace)"),
            "{md}"
        );
        assert!(md.contains("no more agent-steps per second"), "{md}");
        assert!(md.contains("learner-0 forward"), "{md}");

        // Slower with a much higher pace: not put down to the machine.
        let slower = [row(25, 1, Some(80.0), 3000.0), row(50, 1, Some(95.0), 6000.0)];
        let md = trend_of(&slower);
        assert!(md.contains("(+100 % agent-steps/s)"), "{md}");
        assert!(!md.contains("no more agent-steps per second"), "{md}");
    }
}
