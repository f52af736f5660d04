//! Percentiles of timing samples, the form every benchmark reports.

use serde::Serialize;

/// Latency percentiles of a set of samples.
#[derive(Debug, Clone, Copy, Serialize)]
pub struct Percentiles {
    /// Number of samples.
    pub count: usize,
    /// Median, µs.
    pub p50_us: f64,
    /// 99th percentile, µs.
    pub p99_us: f64,
    /// Largest, µs.
    pub max_us: f64,
    /// Mean, µs.
    pub mean_us: f64,
}

impl Percentiles {
    /// Summarise samples in µs (sorts them).
    pub fn of(samples: &mut [f64]) -> Self {
        samples.sort_by(|a, b| a.total_cmp(b));
        let n = samples.len();
        // fpm_physics::stats' one rank rule, on the sorted samples.
        let at = |q: f64| -> f64 {
            if n == 0 {
                return f64::NAN;
            }
            samples[fpm_physics::stats::rank(n, q)]
        };
        Self {
            count: n,
            p50_us: at(0.5),
            p99_us: at(0.99),
            max_us: at(1.0),
            mean_us: if n == 0 {
                f64::NAN
            } else {
                samples.iter().sum::<f64>() / n as f64
            },
        }
    }
}
