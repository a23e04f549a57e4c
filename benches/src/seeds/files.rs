//! What an experiment over seeds writes: `seeds.csv` (one row per run),
//! `seeds.md` (how the runs were made, each arm's statistics, the pairs'
//! probabilities of improvement, every run's scores) and the plots.

use std::fmt::Write as _;
use std::path::Path;

use rotorhive_records::plot;

use super::{Arm, ArmStats, Pair, RunResult, SeedsArgs, band};
use crate::error::{Doing, Result};

/// `seeds.png` (rolling reward) and `seeds-validation.png` (greedy
/// validation success): IQM and quartile band of each arm over time. A plot
/// that cannot be drawn is reported and skipped.
pub(super) fn plot(a: &SeedsArgs, arms: &[Arm], by_arm: &[Vec<&RunResult>], results: &[RunResult]) {
    let end = if a.deterministic_steps > 0 {
        results.iter().flat_map(|r| r.curve.last().map(|p| p.0)).fold(1.0, f64::max)
    } else {
        a.budget_s
    };
    let step = (end / 90.0).max(1.0);
    let bands_of = |curve: &dyn Fn(&RunResult) -> Vec<(f64, f64)>| -> Vec<plot::Band> {
        let named = arms.iter().zip(by_arm);
        named
            .map(|(arm, runs)| {
                let curves: Vec<Vec<(f64, f64)>> = runs.iter().map(|r| curve(r)).collect();
                (arm.name.clone(), band(&curves.iter().collect::<Vec<_>>(), step, end))
            })
            .collect()
    };
    let plots = [
        (
            "rolling episode reward: IQM over seeds, band 25-75 %",
            "reward",
            bands_of(&|r| r.curve.clone()),
            (-110.0, 460.0),
            "seeds.png",
        ),
        (
            "greedy validation success (%): IQM over seeds, band 25-75 %",
            "%",
            bands_of(&|r| r.validation.iter().map(|p| (p.0, p.1 * 100.0)).collect()),
            (0.0, 100.0),
            "seeds-validation.png",
        ),
    ];
    for (title, y, bands, range, file) in plots {
        let path = a.out.join(file);
        if let Err(e) = plot::band_plot(title, "wall time (s)", y, &bands, range, &path) {
            eprintln!("{file} not written: {e:#}");
        }
    }
}

pub(super) fn write_csv(path: &Path, results: &[RunResult]) -> Result<()> {
    let mut csv = String::from(
        "arm,seed,converged,time_to_threshold_s,time_censored_s,time_to_target_s,best_validation,final_validation,result_validation,test_success,test_layout_median,test_layouts_under_half,env_steps_per_s,updates_per_s,skipped_updates,failure,run_dir\n",
    );
    let o = |v: Option<f64>| v.map_or(String::new(), |v| format!("{v:.4}"));
    for r in results {
        writeln!(
            csv,
            "{},{},{},{},{:.3},{},{},{},{},{},{},{},{:.1},{:.1},{},{},{}",
            r.arm,
            r.seed,
            r.time_s.is_some(),
            o(r.time_s),
            r.time_censored_s,
            o(r.time_to_target_s),
            o(r.best_validation),
            o(r.final_validation),
            o(r.result_validation),
            o(r.test.map(|t| t.success)),
            o(r.test.map(|t| t.quartiles[1])),
            r.test.map_or(String::new(), |t| t.under_half.to_string()),
            r.env_steps_per_s,
            r.updates_per_s,
            r.skipped_updates,
            r.failure.as_deref().unwrap_or("").replace(',', ";"),
            r.dir.display()
        )?;
    }
    std::fs::write(path, csv).doing_with(|| format!("cannot write {}", path.display()))
}

/// `seeds.md`: how the runs were made, each arm's statistics, the pairs'
/// probabilities of improvement, and every run's scores.
pub(super) fn write_md(
    a: &SeedsArgs,
    stats: &[ArmStats],
    pairs: &[Pair],
    results: &[RunResult],
) -> Result<()> {
    let mut md = String::from("# Seeds\n\n");
    let how = if a.deterministic_steps > 0 {
        format!("deterministic, {} agent-steps", a.deterministic_steps)
    } else {
        format!("free-running, {:.0} s wall budget, no early stop", a.budget_s)
    };
    let test_set = a
        .test_arena
        .as_ref()
        .map_or("the config's held-out test set".to_string(), |p| format!("`{}`", p.display()));
    writeln!(
        md,
        "Runs: {how}; interleaved A B / B A by seed; unconverged runs count at the budget. \
         Test success: the run's result on {test_set} over {} episodes, pooled; the reactive \
         rule on the same. Learning: agent-steps (and seconds) until a greedy validation first \
         reached the target. Intervals: 95 % percentile bootstrap ({} resamples).\n",
        a.test_episodes, a.resamples
    )?;
    writeln!(
        md,
        "| arm | reached target | median agent-steps to target | median time to target (s) \
         | test success min / median / IQM (%) | reactive rule (%) | converged \
         | median time to threshold (s) | IQM (s) [95 % CI] | epsilon at threshold \
         | max collapse (best − final validation, points) | agent-steps/s | updates/s |"
    )?;
    writeln!(md, "|---|---|---|---|---|---|---|---|---|---|---|---|---|")?;
    for s in stats {
        writeln!(md, "{}", s.md_row())?;
    }
    if !pairs.is_empty() {
        writeln!(
            md,
            "\nProbability that a run of b reaches the threshold sooner than a run of a, \
             reaches the validation target sooner, and flies more of the held-out test set \
             (rliable's probability of improvement; 0.5 = no difference):\n"
        )?;
        writeln!(
            md,
            "| a | b | P(b sooner to threshold) | 95 % CI | P(b sooner to validation target) \
             | 95 % CI | P(b more of the test set) | 95 % CI |"
        )?;
        writeln!(md, "|---|---|---|---|---|---|---|---|")?;
        for q in pairs {
            let test = match (q.p_test, q.ci_test) {
                (Some(p), Some(ci)) => format!("{p:.2} | [{:.2}, {:.2}]", ci[0], ci[1]),
                _ => "— | —".to_string(),
            };
            writeln!(
                md,
                "| {} | {} | {:.2} | [{:.2}, {:.2}] | {:.2} | [{:.2}, {:.2}] | {test} |",
                q.a, q.b, q.p, q.ci[0], q.ci[1], q.p_target, q.ci_target[0], q.ci_target[1]
            )?;
        }
    }
    writeln!(
        md,
        "\n| arm | seed | time to threshold (s) | time to target (s) \
         | validation best / final / result (%) | test (%) | agent-steps/s |"
    )?;
    writeln!(md, "|---|---|---|---|---|---|---|")?;
    for r in results {
        let [t, g, best, last, result, test] = r.cells();
        writeln!(
            md,
            "| {} | {} | {t} | {g} | {best} / {last} / {result} | {test} | {:.0} |",
            r.arm, r.seed, r.env_steps_per_s
        )?;
    }
    let path = a.out.join("seeds.md");
    std::fs::write(&path, md).doing_with(|| format!("cannot write {}", path.display()))
}
