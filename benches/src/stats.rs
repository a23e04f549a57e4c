//! The statistics of the benches: median, interquartile mean, quantiles,
//! the probability of improvement and percentile-bootstrap intervals.

use rand::Rng;
use rand_pcg::Pcg64Mcg;

/// The `q` quantile (0-1) of sorted values, nearest rank (NaN when empty).
pub fn quantile(sorted: &[f64], q: f64) -> f64 {
    match sorted.len() {
        0 => f64::NAN,
        n => sorted[((q * (n - 1) as f64).round() as usize).min(n - 1)],
    }
}

/// The median of `v` (NaN when empty).
pub fn median(v: &[f64]) -> f64 {
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    match s.len() {
        0 => f64::NAN,
        n if n % 2 == 1 => s[n / 2],
        n => (s[n / 2 - 1] + s[n / 2]) / 2.0,
    }
}

/// The interquartile mean (rliable's IQM, scipy's `trim_mean(v, 0.25)`):
/// the mean of what is left after cutting a quarter of the values, rounded
/// down, from each end.
pub fn iqm(v: &[f64]) -> f64 {
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    let cut = s.len() / 4;
    let mid = &s[cut..s.len() - cut];
    if mid.is_empty() { f64::NAN } else { mid.iter().sum::<f64>() / mid.len() as f64 }
}

/// The probability that a draw of `b` is lower (better) than a draw of `a`,
/// ties counted half: the Mann-Whitney U over `a.len() · b.len()`.
pub fn prob_lower(a: &[f64], b: &[f64]) -> f64 {
    let mut wins = 0.0;
    for x in a {
        for y in b {
            wins += if y < x {
                1.0
            } else if y == x {
                0.5
            } else {
                0.0
            };
        }
    }
    wins / (a.len() * b.len()).max(1) as f64
}

/// A 95 % percentile-bootstrap interval of `stat` over resamples (with
/// replacement) of each sample in `samples`.
pub fn bootstrap(
    samples: &[&[f64]],
    resamples: usize,
    rng: &mut Pcg64Mcg,
    stat: impl Fn(&[Vec<f64>]) -> f64,
) -> [f64; 2] {
    let mut values: Vec<f64> = (0..resamples)
        .map(|_| {
            let drawn: Vec<Vec<f64>> = samples
                .iter()
                .map(|s| (0..s.len()).map(|_| s[rng.random_range(0..s.len())]).collect())
                .collect();
            stat(&drawn)
        })
        .filter(|v| v.is_finite())
        .collect();
    values.sort_by(f64::total_cmp);
    [quantile(&values, 0.025), quantile(&values, 0.975)]
}
