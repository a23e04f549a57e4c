//! `hive bench seeds`: an experiment over seeds. Runs every seed of every
//! arm (a config plus `--set` overrides) one at a time, interleaved
//! (A B, then B A, ...) so that the machine's drift hits every arm alike,
//! each free-running to a fixed wall budget without early stop (or
//! deterministic to a step budget), then scores each run from its records:
//! time to the threshold (recomputed from `metrics.csv` with the clock of
//! `hive train`, censored at the budget), time to the first greedy
//! validation at `eval.target_success`, best, final and result validation
//! success, and the result's success on the test arena over fresh episodes.
//! Per arm it reports k/N converged, the median and the IQM of the times
//! with percentile-bootstrap intervals, and for every pair of arms the
//! probability that a run of one beats a run of the other (rliable's
//! probability of improvement) with its interval.

use std::path::{Path, PathBuf};
use std::process::Command;

use crate::error::{BenchError, Doing, Result, failed, usage};
use rand::SeedableRng;
use rand_pcg::Pcg64Mcg;
use serde::Deserialize;

use rotorhive_records::rows::{EvalRow, MetricsKind, MetricsRow};
use rotorhive_records::{Rolling, Summary};

use crate::stats::{bootstrap, iqm, median, prob_lower, quantile};
use rotorhive_roles::{Config, Exploration};

mod files;

/// The command line of `hive bench seeds`.
#[derive(clap::Args, Debug)]
pub struct SeedsArgs {
    /// Config of every arm (default: the built-in defaults).
    pub config: Option<PathBuf>,
    /// Seeds: a range `1-10` or a list `1,4,7`.
    #[arg(long, default_value = "1-5")]
    pub seeds: String,
    /// An arm: `NAME:key=value,key=value` (no `--arm`: one arm, the config
    /// as it is). Values that contain commas go in an arms file.
    #[arg(long = "arm")]
    pub arms: Vec<String>,
    /// Arms from a TOML file: `[[arm]]` tables with `name` and `set = [...]`.
    #[arg(long)]
    pub arms_file: Option<PathBuf>,
    /// `key=value` for every arm.
    #[arg(long = "set")]
    pub set: Vec<String>,
    /// Wall budget per run (s).
    #[arg(long, default_value_t = 180.0)]
    pub budget_s: f64,
    /// Deterministic runs of this many agent-steps instead of free-running
    /// ones on the wall budget (0: free-running).
    #[arg(long, default_value_t = 0)]
    pub deterministic_steps: u64,
    /// Held-out episodes that score each run's result (shared evenly among
    /// the test layouts).
    #[arg(long, default_value_t = 500)]
    pub test_episodes: usize,
    /// A test arena instead of the config's held-out test set (`eval.test_arenas`
    /// and `eval.test_layouts`).
    #[arg(long)]
    pub test_arena: Option<PathBuf>,
    /// Bootstrap resamples of every interval.
    #[arg(long, default_value_t = 5000)]
    pub resamples: usize,
    /// Directory of the runs and the report.
    #[arg(long, default_value = "runs/seeds")]
    pub out: PathBuf,
    /// Print one JSON object as the last line.
    #[arg(long)]
    pub json: bool,
    /// Keep the runs of an interrupted experiment that finished (their
    /// `summary.json` exists) and score them again instead of training them
    /// again; give the same command line as before.
    #[arg(long)]
    pub resume: bool,
}

/// One arm: a name and its overrides.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Arm {
    /// Its name in the report.
    pub name: String,
    /// `key=value` overrides.
    #[serde(default)]
    pub set: Vec<String>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct ArmsFile {
    arm: Vec<Arm>,
}

/// Parses `1-10` or `1,4,7`.
pub fn parse_seeds(s: &str) -> Result<Vec<u64>> {
    let bad = || {
        BenchError::Usage(format!("--seeds {s:?}: expected a range like 1-10 or a list like 1,4,7"))
    };
    let seeds: Vec<u64> = match s.split_once('-') {
        Some((a, b)) => {
            let (a, b): (u64, u64) =
                (a.trim().parse().map_err(|_| bad())?, b.trim().parse().map_err(|_| bad())?);
            if a > b {
                return Err(bad());
            }
            (a..=b).collect()
        }
        None => s.split(',').map(|v| v.trim().parse().map_err(|_| bad())).collect::<Result<_>>()?,
    };
    if seeds.is_empty() {
        return Err(bad());
    }
    Ok(seeds)
}

/// Parses `NAME:key=value,key=value` (or a bare `NAME`).
pub fn parse_arm(s: &str) -> Result<Arm> {
    let (name, sets) = s.split_once(':').unwrap_or((s, ""));
    if name.trim().is_empty() {
        usage!("--arm {s:?}: the arm needs a name (NAME:key=value,...)");
    }
    let set: Vec<String> =
        sets.split(',').map(str::trim).filter(|v| !v.is_empty()).map(String::from).collect();
    if let Some(v) = set.iter().find(|v| !v.contains('=')) {
        usage!("--arm {s:?}: {v:?} is not key=value");
    }
    Ok(Arm { name: name.trim().to_string(), set })
}

/// The arms of the command line and the arms file (one unnamed arm if none).
fn arms_of(a: &SeedsArgs) -> Result<Vec<Arm>> {
    let mut arms: Vec<Arm> = a.arms.iter().map(|s| parse_arm(s)).collect::<Result<_>>()?;
    if let Some(f) = &a.arms_file {
        let text =
            std::fs::read_to_string(f).doing_with(|| format!("arms file {}", f.display()))?;
        let file: ArmsFile = toml::from_str(&text).map_err(|e| {
            BenchError::Usage(format!("arms file {}: {}", f.display(), e.to_string().trim_end()))
        })?;
        arms.extend(file.arm);
    }
    if arms.is_empty() {
        arms.push(Arm { name: "config".into(), set: vec![] });
    }
    for (i, a) in arms.iter().enumerate() {
        if arms[..i].iter().any(|b| b.name == a.name) {
            usage!("two arms are named {:?}", a.name);
        }
    }
    Ok(arms)
}

/// What one run gave.
#[derive(Debug, Clone, Default)]
pub struct RunResult {
    arm: String,
    seed: u64,
    dir: PathBuf,
    /// Time to threshold, recomputed from `metrics.csv`.
    time_s: Option<f64>,
    /// The same time, censored at the run's wall time when not reached.
    time_censored_s: f64,
    time_to_target_s: Option<f64>,
    /// Agent-steps to the first greedy validation at the target: the
    /// learning metric.
    env_steps_to_target: Option<u64>,
    /// Agent-steps, updates and epsilon when the rolling reward crossed.
    at_threshold: (Option<u64>, Option<u64>, Option<f64>),
    best_validation: Option<f64>,
    final_validation: Option<f64>,
    result_validation: Option<f64>,
    /// The result on the held-out test set.
    test: Option<TestScore>,
    env_steps_per_s: f64,
    updates_per_s: f64,
    skipped_updates: u64,
    failure: Option<String>,
    /// Rolling reward and validation success against wall time.
    curve: Vec<(f64, f64)>,
    validation: Vec<(f64, f64)>,
}

/// (wall s, value) points of a run.
pub type Curve = Vec<(f64, f64)>;

impl RunResult {
    /// The run's figures as shown: times to threshold and target (s), best,
    /// final and result validation and test success (%).
    fn cells(&self) -> [String; 6] {
        [
            opt(self.time_s, 1),
            opt(self.time_to_target_s, 1),
            pct(self.best_validation),
            pct(self.final_validation),
            pct(self.result_validation),
            pct(self.test.map(|t| t.success)),
        ]
    }
}

/// Time to threshold from a run's `metrics.csv`, with the clock `hive
/// train` uses (its config's window, threshold and exploration floor),
/// and the rolling-reward curve of its `tick` rows.
pub fn threshold_time(run_dir: &Path) -> Result<(Option<f64>, Curve)> {
    let cfg = Config::load(Some(&run_dir.join("config.toml")), &[])?;
    let floor =
        (cfg.actor.exploration == Exploration::PerActor).then_some(cfg.actor.eps_end as f32);
    let mut rolling = Rolling::new(cfg.rolling_window, cfg.threshold, floor);
    let mut curve = Vec::new();
    for row in rotorhive_records::rows::read::<MetricsRow>(&run_dir.join("metrics.csv"))? {
        match row.kind {
            MetricsKind::Episode => {
                let (Some(r), Some(eps)) = (row.episode_reward, row.epsilon) else {
                    failed!(
                        "{}: an episode row without its return or epsilon at {} s",
                        run_dir.join("metrics.csv").display(),
                        row.wall_s
                    )
                };
                rolling.push(row.wall_s, r, false, eps as f32);
            }
            MetricsKind::Tick => {
                if let Some(r) = row.rolling_reward.filter(|r| r.is_finite()) {
                    curve.push((row.wall_s, r));
                }
            }
            MetricsKind::Restart | MetricsKind::Resume => {}
        }
    }
    Ok((rolling.crossed_at, curve))
}

/// (wall, screening success) of each evaluation in `evals.csv`.
fn validation_curve(run_dir: &Path) -> Vec<(f64, f64)> {
    // A run that never evaluated, or whose table is damaged, has no curve.
    rotorhive_records::rows::read::<EvalRow>(&run_dir.join("evals.csv"))
        .unwrap_or_default()
        .iter()
        .map(|r| (r.wall_s, r.success_rate))
        .collect()
}

/// The held-out test set of `cfg`, or the one arena `--test-arena` names.
fn test_set(cfg: &Config, arena: Option<&Path>) -> Result<Vec<rotorhive_sim::Arena>> {
    match arena {
        Some(p) => Ok(vec![rotorhive_sim::Arena::load(p)?]),
        None => Ok(cfg.test_arenas()?),
    }
}

/// The pooled success rate of `pilot` on the held-out test set over
/// `episodes` fresh episodes (shared among the layouts), flown with the
/// simulator settings of `cfg`.
fn pooled_success(
    cfg: &Config,
    pilot: rotorhive_roles::evaluation::Pilot<'_>,
    arena: Option<&Path>,
    episodes: usize,
) -> Result<TestScore> {
    let layouts = test_set(cfg, arena)?;
    let sim =
        rotorhive_sim::SimConfig { renderer: rotorhive_sim::RendererKind::Cpu, ..cfg.sim_config() };
    let stats = rotorhive_roles::evaluation::fly_layouts(pilot, &sim, &layouts, episodes, 12345)?;
    let (quartiles, under_half) = rotorhive_roles::evaluation::layout_spread(&stats);
    Ok(TestScore {
        success: rotorhive_roles::evaluation::EvalStats::pooled(&stats).success_rate(),
        quartiles,
        under_half,
    })
}

/// A policy on the held-out test set: pooled success, and its spread over
/// the layouts (quartiles of per-layout success, layouts under 50 %).
#[derive(Debug, Clone, Copy)]
pub(crate) struct TestScore {
    pub(crate) success: f64,
    pub(crate) quartiles: [f64; 3],
    pub(crate) under_half: usize,
}

/// The success rate of a run's result on the held-out test set, flown
/// with the run's own simulator settings.
fn test_success(
    run_dir: &Path,
    checkpoint: &Path,
    arena: Option<&Path>,
    episodes: usize,
) -> Result<TestScore> {
    let cfg = Config::load(Some(&run_dir.join("config.toml")), &[])?;
    let net = rotorhive_roles::evaluation::network_for(&cfg)?;
    net.load_checkpoint(checkpoint)?;
    pooled_success(&cfg, rotorhive_roles::evaluation::Pilot::Net(&net), arena, episodes)
}

/// Runs one seed of one arm and scores it.
fn run_one(a: &SeedsArgs, exe: &Path, arm: &Arm, seed: u64, dir: &Path) -> Result<RunResult> {
    let status = if a.resume && dir.join("summary.json").is_file() {
        eprintln!("      finished before: scored again (--resume)");
        None
    } else {
        Some(train(a, exe, arm, seed, dir)?)
    };
    let exited = |status: &Option<std::process::ExitStatus>| match status {
        Some(s) => format!("hive train exited with {s}"),
        None => "the run of an earlier experiment".to_string(),
    };
    // A run that failed counts as unconverged at the budget (and is named
    // in the report); the experiment goes on.
    let failed = |why: String| RunResult {
        arm: arm.name.clone(),
        seed,
        dir: dir.to_path_buf(),
        time_censored_s: a.budget_s,
        failure: Some(why),
        ..RunResult::default()
    };
    let summary = match Summary::read(dir) {
        Ok(s) => s,
        Err(e) => return Ok(failed(format!("{}: {e:#}", exited(&status)))),
    };
    let (time_s, curve) = match threshold_time(dir) {
        Ok(t) => t,
        Err(e) => return Ok(failed(format!("{e:#}"))),
    };
    let test = match &summary.checkpoint {
        Some(c) if a.test_episodes > 0 => {
            Some(test_success(dir, Path::new(c), a.test_arena.as_deref(), a.test_episodes)?)
        }
        _ => None,
    };
    let validation = validation_curve(dir);
    // The replay memory's file (hundreds of MB per run) is not part of the
    // result: an experiment of tens of runs would fill the disk.
    let _ = std::fs::remove_file(dir.join("replay.bin"));
    let failure = summary
        .failure
        .clone()
        .or_else(|| status.filter(|s| !s.success()).map(|s| format!("hive train exited with {s}")));
    Ok(RunResult {
        arm: arm.name.clone(),
        seed,
        dir: dir.to_path_buf(),
        time_s,
        time_censored_s: time_s.unwrap_or(if a.deterministic_steps > 0 {
            summary.wall_s
        } else {
            a.budget_s
        }),
        time_to_target_s: summary.time_to_target_success_s,
        env_steps_to_target: summary.env_steps_to_target,
        at_threshold: (
            summary.env_steps_at_threshold,
            summary.updates_at_threshold,
            summary.epsilon_at_threshold,
        ),
        best_validation: validation.iter().map(|p| p.1).reduce(f64::max),
        final_validation: summary.final_validation_success,
        result_validation: summary.result_validation_success,
        test,
        env_steps_per_s: summary.env_steps_per_s,
        updates_per_s: summary.updates_per_s,
        skipped_updates: summary.skipped_updates,
        failure,
        curve,
        validation,
    })
}

/// Trains one seed of one arm into `dir` (emptied first).
fn train(
    a: &SeedsArgs,
    exe: &Path,
    arm: &Arm,
    seed: u64,
    dir: &Path,
) -> Result<std::process::ExitStatus> {
    let _ = std::fs::remove_dir_all(dir);
    let mut cmd = Command::new(exe);
    cmd.arg("train");
    if let Some(c) = &a.config {
        cmd.arg(c);
    }
    let budget = if a.deterministic_steps > 0 { a.budget_s.max(3600.0) } else { a.budget_s };
    cmd.arg("--quiet").arg("--run-dir").arg(dir).arg("--max-seconds").arg(budget.to_string());
    let mut sets = vec![format!("seed={seed}"), "early_stop=false".to_string()];
    if a.deterministic_steps > 0 {
        sets.extend([
            "deterministic=true".to_string(),
            format!("max_env_steps={}", a.deterministic_steps),
        ]);
    }
    for s in sets.iter().chain(&a.set).chain(&arm.set) {
        cmd.arg("--set").arg(s);
    }
    cmd.stdout(std::process::Stdio::null());
    // A killed harness stops its run, as Ctrl-C would (it would train on).
    rotorhive_transport::dies_with_this_process(&mut cmd, rustix::process::Signal::INT);
    cmd.status().doing_with(|| format!("arm {} seed {seed}: cannot start hive train", arm.name))
}

/// (x, IQM, 25th, 75th percentile) over runs on a grid of `step` seconds,
/// each run's value at x being its newest point at or before x.
fn band(curves: &[&Vec<(f64, f64)>], step: f64, end: f64) -> Vec<(f64, f64, f64, f64)> {
    let mut out = Vec::new();
    let mut x = step;
    while x <= end + 1e-9 {
        let vals: Vec<f64> =
            curves.iter().filter_map(|c| c.iter().rev().find(|p| p.0 <= x).map(|p| p.1)).collect();
        if !vals.is_empty() {
            let mut s = vals.clone();
            s.sort_by(f64::total_cmp);
            out.push((x, iqm(&vals), quantile(&s, 0.25), quantile(&s, 0.75)));
        }
        x += step;
    }
    out
}

fn opt(v: Option<f64>, digits: usize) -> String {
    v.map_or("—".into(), |v| format!("{v:.digits$}"))
}

fn pct(v: Option<f64>) -> String {
    v.map_or("—".into(), |v| format!("{:.1}", v * 100.0))
}

/// One arm's statistics: the JSON of `--json` (`arms`) and the rows of
/// `seeds.md`. Times and steps are medians over the arm's runs where the
/// name says so; a statistic of no runs is NaN (JSON `null`).
#[derive(Debug, Clone, serde::Serialize)]
pub struct ArmStats {
    name: String,
    runs: usize,
    converged: usize,
    seeds: Vec<u64>,
    times_s: Vec<Option<f64>>,
    median_time_s: f64,
    median_time_ci: [f64; 2],
    iqm_time_s: f64,
    iqm_time_ci: [f64; 2],
    reached_target: usize,
    /// Only when every run reached the target.
    median_time_to_target_s: Option<f64>,
    /// Only when every run reached the target.
    median_env_steps_to_target: Option<f64>,
    env_steps_to_target: Vec<Option<u64>>,
    median_env_steps_at_threshold: f64,
    median_updates_at_threshold: f64,
    median_epsilon_at_threshold: f64,
    /// The reactive rule's pooled success on the arm's test set.
    reactive_test_success: Option<f64>,
    times_to_target_s: Vec<Option<f64>>,
    test_success: Vec<Option<f64>>,
    /// Per run: the quartiles of its per-layout test success.
    test_layout_quartiles: Vec<Option<[f64; 3]>>,
    /// Per run: the test layouts it flies under 50 %.
    test_layouts_under_half: Vec<Option<usize>>,
    test_success_min: Option<f64>,
    test_success_iqm: f64,
    result_validation: Vec<Option<f64>>,
    best_validation: Vec<Option<f64>>,
    final_validation: Vec<Option<f64>>,
    collapse_max: Option<f64>,
    env_steps_per_s: f64,
    updates_per_s: f64,
    skipped_updates: u64,
    failures: usize,
}

impl ArmStats {
    /// The statistics of an arm's finished runs, with the reactive rule's
    /// pooled test success on the arm's test set.
    fn of(
        name: &str,
        runs: &[&RunResult],
        resamples: usize,
        rng: &mut Pcg64Mcg,
        reactive: Option<f64>,
    ) -> Self {
        let times: Vec<f64> = runs.iter().map(|r| r.time_censored_s).collect();
        let targets: Vec<f64> = runs.iter().filter_map(|r| r.time_to_target_s).collect();
        let steps_to_target: Vec<f64> =
            runs.iter().filter_map(|r| r.env_steps_to_target.map(|s| s as f64)).collect();
        let all = |v: &[f64]| (v.len() == runs.len() && !runs.is_empty()).then(|| median(v));
        let med = |f: &dyn Fn(&RunResult) -> Option<f64>| {
            median(&runs.iter().filter_map(|r| f(r)).collect::<Vec<_>>())
        };
        let each = |f: &dyn Fn(&RunResult) -> Option<f64>| runs.iter().map(|r| f(r)).collect();
        let tests: Vec<f64> = runs.iter().filter_map(|r| Some(r.test?.success)).collect();
        let collapse = runs.iter().filter_map(|r| Some(r.best_validation? - r.final_validation?));
        Self {
            name: name.to_string(),
            runs: runs.len(),
            converged: runs.iter().filter(|r| r.time_s.is_some()).count(),
            seeds: runs.iter().map(|r| r.seed).collect(),
            times_s: each(&|r| r.time_s),
            median_time_s: median(&times),
            median_time_ci: bootstrap(&[&times], resamples, rng, |d| median(&d[0])),
            iqm_time_s: iqm(&times),
            iqm_time_ci: bootstrap(&[&times], resamples, rng, |d| iqm(&d[0])),
            reached_target: targets.len(),
            median_time_to_target_s: all(&targets),
            median_env_steps_to_target: all(&steps_to_target),
            env_steps_to_target: runs.iter().map(|r| r.env_steps_to_target).collect(),
            median_env_steps_at_threshold: med(&|r| r.at_threshold.0.map(|v| v as f64)),
            median_updates_at_threshold: med(&|r| r.at_threshold.1.map(|v| v as f64)),
            median_epsilon_at_threshold: med(&|r| r.at_threshold.2),
            reactive_test_success: reactive,
            times_to_target_s: each(&|r| r.time_to_target_s),
            test_success: each(&|r| Some(r.test?.success)),
            test_layout_quartiles: runs.iter().map(|r| r.test.map(|t| t.quartiles)).collect(),
            test_layouts_under_half: runs.iter().map(|r| r.test.map(|t| t.under_half)).collect(),
            test_success_min: tests.iter().copied().reduce(f64::min),
            test_success_iqm: iqm(&tests),
            result_validation: each(&|r| r.result_validation),
            best_validation: each(&|r| r.best_validation),
            final_validation: each(&|r| r.final_validation),
            collapse_max: collapse.reduce(f64::max),
            env_steps_per_s: med(&|r| Some(r.env_steps_per_s)),
            updates_per_s: med(&|r| Some(r.updates_per_s)),
            skipped_updates: runs.iter().map(|r| r.skipped_updates).sum(),
            failures: runs.iter().filter(|r| r.failure.is_some()).count(),
        }
    }

    /// Its row of `seeds.md`'s summary table.
    fn md_row(&self) -> String {
        let tests: Vec<f64> = self.test_success.iter().flatten().copied().collect();
        let f = |v: f64| if v.is_finite() { format!("{v:.1}") } else { "—".to_string() };
        let ci = |v: [f64; 2]| format!("[{}, {}]", f(v[0]), f(v[1]));
        let p = |v: Option<f64>| v.filter(|x| x.is_finite()).map(|x| x * 100.0);
        let steps = self.median_env_steps_to_target.map(|x| format!("{x:.0}"));
        let eps = Some(self.median_epsilon_at_threshold).filter(|x| x.is_finite());
        format!(
            "| {} | {}/{} | {} | {} | {} / {} / {} | {} | {}/{} | {} {} | {} {} | {} | {} | {} | {} |",
            self.name,
            self.reached_target,
            self.runs,
            steps.unwrap_or("—".into()),
            opt(self.median_time_to_target_s, 1),
            opt(p(self.test_success_min), 1),
            opt(p(Some(median(&tests))), 1),
            opt(p(Some(self.test_success_iqm)), 1),
            opt(p(self.reactive_test_success), 1),
            self.converged,
            self.runs,
            f(self.median_time_s),
            ci(self.median_time_ci),
            f(self.iqm_time_s),
            ci(self.iqm_time_ci),
            opt(eps, 2),
            opt(p(self.collapse_max), 1),
            f(self.env_steps_per_s),
            f(self.updates_per_s),
        )
    }
}

/// The probability that a run of arm `b` is sooner than a run of arm `a`,
/// to the threshold and to the validation target, and that it flies more
/// of the held-out test set (none where a run has no test score), with
/// their intervals.
#[derive(Debug, Clone, serde::Serialize)]
struct Pair {
    a: String,
    b: String,
    p: f64,
    ci: [f64; 2],
    p_target: f64,
    ci_target: [f64; 2],
    p_test: Option<f64>,
    ci_test: Option<[f64; 2]>,
}

impl Pair {
    fn of(
        a: &SeedsArgs,
        (na, ra): (&str, &[&RunResult]),
        (nb, rb): (&str, &[&RunResult]),
        rng: &mut Pcg64Mcg,
    ) -> Self {
        let ta: Vec<f64> = ra.iter().map(|r| r.time_censored_s).collect();
        let tb: Vec<f64> = rb.iter().map(|r| r.time_censored_s).collect();
        let ci = bootstrap(&[&ta, &tb], a.resamples, rng, |d| prob_lower(&d[0], &d[1]));
        // The same on time to the validation target (unreached: the budget).
        let target = |runs: &[&RunResult]| -> Vec<f64> {
            runs.iter().map(|r| r.time_to_target_s.unwrap_or(a.budget_s)).collect()
        };
        let (ga, gb) = (target(ra), target(rb));
        let ci_target = bootstrap(&[&ga, &gb], a.resamples, rng, |d| prob_lower(&d[0], &d[1]));
        // Test success, higher is better: its negation, lower is better.
        let test = |runs: &[&RunResult]| -> Option<Vec<f64>> {
            runs.iter().map(|r| r.test.as_ref().map(|t| -t.success)).collect()
        };
        let (p_test, ci_test) = match (test(ra), test(rb)) {
            (Some(xa), Some(xb)) => (
                Some(prob_lower(&xa, &xb)),
                Some(bootstrap(&[&xa, &xb], a.resamples, rng, |d| prob_lower(&d[0], &d[1]))),
            ),
            _ => (None, None),
        };
        Self {
            a: na.to_string(),
            b: nb.to_string(),
            p: prob_lower(&ta, &tb),
            ci,
            p_target: prob_lower(&ga, &gb),
            ci_target,
            p_test,
            ci_test,
        }
    }
}

/// The last line of `hive bench seeds --json`.
#[derive(serde::Serialize)]
struct SeedsReport<'a> {
    bench: &'static str,
    budget_s: f64,
    deterministic_steps: u64,
    test_episodes: usize,
    arms: &'a [ArmStats],
    prob_improvement: &'a [Pair],
    out: String,
}

/// Runs the experiment and writes `seeds.md`, `seeds.csv`, `seeds.png`.
pub fn run(a: &SeedsArgs) -> Result<()> {
    let seeds = parse_seeds(&a.seeds)?;
    let arms = arms_of(a)?;
    if !(a.budget_s.is_finite() && a.budget_s > 0.0) {
        usage!("--budget-s must be positive, got {}", a.budget_s);
    }
    // Every arm's config must load before hours of runs start.
    let configs: Vec<Config> = arms
        .iter()
        .map(|arm| {
            let sets: Vec<String> = a.set.iter().chain(&arm.set).cloned().collect();
            Config::load(a.config.as_deref(), &sets).doing_with(|| format!("arm {}", arm.name))
        })
        .collect::<Result<_>>()?;
    // The reactive rule on each arm's test set: the floor beside the arm.
    let reactive: Vec<Option<f64>> = configs
        .iter()
        .map(|cfg| {
            let pilot = rotorhive_roles::evaluation::Pilot::Reactive;
            (a.test_episodes > 0)
                .then(|| pooled_success(cfg, pilot, a.test_arena.as_deref(), a.test_episodes))
                .transpose()
                .map(|t| t.map(|t| t.success))
        })
        .collect::<Result<_>>()?;
    std::fs::create_dir_all(&a.out).doing_with(|| format!("cannot create {}", a.out.display()))?;
    let exe = std::env::current_exe()?;
    let total = seeds.len() * arms.len();
    let mut results = Vec::new();
    let mut k = 0;
    for (j, &seed) in seeds.iter().enumerate() {
        // A B, B A, A B, ...: each arm runs first as often as last.
        let order: Vec<&Arm> =
            if j % 2 == 0 { arms.iter().collect() } else { arms.iter().rev().collect() };
        for arm in order {
            k += 1;
            eprintln!(
                "[{k}/{total}] arm {} seed {seed}: {}",
                arm.name,
                if a.deterministic_steps > 0 {
                    format!("{} agent-steps", a.deterministic_steps)
                } else {
                    format!("{:.0} s", a.budget_s)
                }
            );
            let dir = a.out.join(format!("{}-seed{seed}", arm.name));
            let r = run_one(a, &exe, arm, seed, &dir)?;
            let [t, g, best, last, result, test] = r.cells();
            eprintln!(
                "      time to threshold {t} s, to target {g} s, validation best/final/result {best}/{last}/{result} %, test {test} %, {:.0} agent-steps/s{}",
                r.env_steps_per_s,
                r.failure.as_ref().map_or(String::new(), |f| format!(" (failed: {f})"))
            );
            results.push(r);
        }
    }
    report(a, &arms, &results, &reactive)
}

/// Statistics, tables, curves and the JSON line of finished runs.
fn report(
    a: &SeedsArgs,
    arms: &[Arm],
    results: &[RunResult],
    reactive: &[Option<f64>],
) -> Result<()> {
    let mut rng = Pcg64Mcg::seed_from_u64(0x5eed5);
    let by_arm: Vec<Vec<&RunResult>> =
        arms.iter().map(|arm| results.iter().filter(|r| r.arm == arm.name).collect()).collect();
    let stats: Vec<ArmStats> = arms
        .iter()
        .zip(&by_arm)
        .zip(reactive)
        .map(|((arm, runs), r)| ArmStats::of(&arm.name, runs, a.resamples, &mut rng, *r))
        .collect();
    let mut pairs = Vec::new();
    for i in 0..arms.len() {
        for j in (0..arms.len()).filter(|&j| j != i) {
            let (x, y) = ((&*arms[i].name, &*by_arm[i]), (&*arms[j].name, &*by_arm[j]));
            pairs.push(Pair::of(a, x, y, &mut rng));
        }
    }
    files::write_csv(&a.out.join("seeds.csv"), results)?;
    files::write_md(a, &stats, &pairs, results)?;
    files::plot(a, arms, &by_arm, results);
    print!("{}", std::fs::read_to_string(a.out.join("seeds.md"))?);
    if a.json {
        let report = SeedsReport {
            bench: "seeds",
            budget_s: a.budget_s,
            deterministic_steps: a.deterministic_steps,
            test_episodes: a.test_episodes,
            arms: &stats,
            prob_improvement: &pairs,
            out: a.out.display().to_string(),
        };
        println!("{}", serde_json::to_string(&report)?);
    }
    Ok(())
}

#[cfg(test)]
mod tests;
