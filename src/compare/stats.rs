//! Summary statistics of a set of non-negative errors (distances or relative errors).

use rayon::slice::ParallelSliceMut;
use serde::Serialize;

/// Statistics of a set of errors; percentiles interpolate linearly between order
/// statistics (the numpy default), so the median of `[1, 2, 3, 4]` is 2.5.
#[derive(Clone, Debug, Default, PartialEq, Serialize)]
pub struct ErrorStats {
    pub count: usize,
    pub mean: f64,
    pub median: f64,
    pub rms: f64,
    pub p95: f64,
    pub p99: f64,
    pub max: f64,
    /// For each threshold, the fraction of values strictly above it.
    pub over: Vec<Exceedance>,
}

#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct Exceedance {
    pub threshold: f64,
    pub fraction: f64,
}

/// The `q`-quantile (`0 ≤ q ≤ 1`) of ascending `sorted`; `NaN` when empty.
pub fn quantile_sorted(sorted: &[f64], q: f64) -> f64 {
    match sorted.len() {
        0 => f64::NAN,
        n => {
            let pos = q.clamp(0.0, 1.0) * (n - 1) as f64;
            let i = pos.floor() as usize;
            let j = (i + 1).min(n - 1);
            let t = pos - i as f64;
            sorted[i] + t * (sorted[j] - sorted[i])
        }
    }
}

/// The median of `values` (reordered in place); `NaN` when empty.
pub fn median_mut(values: &mut [f64]) -> f64 {
    let n = values.len();
    if n == 0 {
        return f64::NAN;
    }
    let (_, hi, _) = values.select_nth_unstable_by(n / 2, f64::total_cmp);
    let hi = *hi;
    if n % 2 == 1 {
        hi
    } else {
        let lo = values[..n / 2]
            .iter()
            .copied()
            .fold(f64::NEG_INFINITY, f64::max);
        0.5 * (lo + hi)
    }
}

impl ErrorStats {
    /// Statistics of `values` (sorted in place, in parallel); non-finite values must be
    /// removed by the caller. Thresholds are reported in the order given.
    pub fn from_values(values: &mut [f64], thresholds: &[f64]) -> Self {
        values.par_sort_unstable_by(f64::total_cmp);
        Self::from_sorted(values, thresholds)
    }

    /// Statistics of ascending `sorted` values.
    pub fn from_sorted(sorted: &[f64], thresholds: &[f64]) -> Self {
        let n = sorted.len();
        let over = thresholds
            .iter()
            .map(|&t| Exceedance {
                threshold: t,
                fraction: if n == 0 {
                    0.0
                } else {
                    (n - sorted.partition_point(|&v| v <= t)) as f64 / n as f64
                },
            })
            .collect();
        if n == 0 {
            return Self {
                over,
                ..Self::default()
            };
        }
        let sum: f64 = sorted.iter().sum();
        let sum_sq: f64 = sorted.iter().map(|v| v * v).sum();
        Self {
            count: n,
            mean: sum / n as f64,
            median: quantile_sorted(sorted, 0.5),
            rms: (sum_sq / n as f64).sqrt(),
            p95: quantile_sorted(sorted, 0.95),
            p99: quantile_sorted(sorted, 0.99),
            max: sorted[n - 1],
            over,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn statistics_of_a_known_array() {
        // 1..=100 shuffled: mean 50.5, median 50.5, p95 = 1 + 0.95·99 = 95.05.
        let mut v: Vec<f64> = (1..=100).map(|i| ((i * 37) % 100 + 1) as f64).collect();
        let s = ErrorStats::from_values(&mut v, &[10.0, 99.5, 100.0]);
        assert_eq!(s.count, 100);
        assert!((s.mean - 50.5).abs() < 1e-12);
        assert!((s.median - 50.5).abs() < 1e-12);
        assert!((s.p95 - 95.05).abs() < 1e-9);
        assert!((s.p99 - 99.01).abs() < 1e-9);
        assert_eq!(s.max, 100.0);
        let rms = ((100.0 * 101.0 * 201.0 / 6.0) / 100.0f64).sqrt();
        assert!((s.rms - rms).abs() < 1e-9);
        assert_eq!(s.over[0].fraction, 0.9);
        assert_eq!(s.over[1].fraction, 0.01);
        assert_eq!(s.over[2].fraction, 0.0);
    }

    #[test]
    fn medians_and_empty_input() {
        assert_eq!(median_mut(&mut [3.0, 1.0, 2.0]), 2.0);
        assert_eq!(median_mut(&mut [4.0, 1.0, 3.0, 2.0]), 2.5);
        assert!(median_mut(&mut []).is_nan());
        assert_eq!(quantile_sorted(&[7.0], 0.3), 7.0);
        let s = ErrorStats::from_values(&mut [], &[1.0]);
        assert_eq!(s.count, 0);
        assert_eq!(s.over[0].fraction, 0.0);
    }
}
