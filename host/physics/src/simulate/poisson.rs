//! Poisson samples for shot noise, one mean per pixel.
//!
//! `rand_distr::Poisson` sets up each mean with a log-gamma and draws by rejection
//! against a Cauchy with another log-gamma (and a tangent) per try: 170 ns a pixel,
//! 40 % of the virtual camera's frame. Means of 10 and more are drawn here by
//! Hörmann's transformed rejection with squeeze (PTRS: W. Hörmann, "The transformed
//! rejection method for generating Poisson random variables", Insurance: Mathematics
//! and Economics 12, 39–45, 1993), which accepts most draws from two uniforms and a
//! few multiplications and needs log k! only for the rest; smaller means by
//! multiplying uniforms (Knuth). Both are exact samplers of the Poisson distribution.

use rand::Rng;

/// One draw from the Poisson distribution of `mean` (0 for a mean of 0 or below; a
/// mean that is not finite is returned as it is).
pub(crate) fn sample(mean: f64, rng: &mut (impl Rng + ?Sized)) -> f64 {
    if !mean.is_finite() {
        return mean;
    }
    if mean <= 0.0 {
        0.0
    } else if mean < 10.0 {
        by_products(mean, rng)
    } else {
        transformed_rejection(mean, rng)
    }
}

/// Knuth: the number of uniforms whose running product stays above e^−mean.
fn by_products(mean: f64, rng: &mut (impl Rng + ?Sized)) -> f64 {
    let limit = (-mean).exp();
    let mut k = 0.0;
    let mut product: f64 = rng.gen();
    while product > limit {
        k += 1.0;
        product *= rng.gen::<f64>();
    }
    k
}

/// PTRS (Hörmann 1993), for means of 10 and more.
fn transformed_rejection(mean: f64, rng: &mut (impl Rng + ?Sized)) -> f64 {
    let root = mean.sqrt();
    let log_mean = mean.ln();
    let b = 0.931 + 2.53 * root;
    let a = -0.059 + 0.02483 * b;
    let log_inv_alpha = (1.1239 + 1.1328 / (b - 3.4)).ln();
    let v_r = 0.9277 - 3.6224 / (b - 2.0);
    loop {
        let u = rng.gen::<f64>() - 0.5;
        let v: f64 = rng.gen();
        let us = 0.5 - u.abs();
        let k = ((2.0 * a / us + b) * u + mean + 0.43).floor();
        // The squeeze: most draws end here.
        if us >= 0.07 && v <= v_r {
            return k;
        }
        if k < 0.0 || (us < 0.013 && v > us) {
            continue;
        }
        if v.ln() + log_inv_alpha - (a / (us * us) + b).ln()
            <= -mean + k * log_mean - log_factorial(k)
        {
            return k;
        }
    }
}

/// ln k! for whole k ≥ 0: Stirling's series, exact to double precision from 7 on;
/// below, taken there and stepped down.
fn log_factorial(k: f64) -> f64 {
    // B₂ⱼ / (2j(2j − 1)), the Bernoulli numbers' terms of the series.
    const SERIES: [f64; 10] = [
        1.0 / 12.0,
        -1.0 / 360.0,
        1.0 / 1260.0,
        -1.0 / 1680.0,
        1.0 / 1188.0,
        -691.0 / 360_360.0,
        1.0 / 156.0,
        -3617.0 / 122_400.0,
        43_867.0 / 244_188.0,
        -174_611.0 / 125_400.0,
    ];
    let x = k + 1.0; // ln k! = ln Γ(k + 1)
    if x <= 2.0 {
        return 0.0;
    }
    let shift = if x < 7.0 { (7.0 - x).floor() } else { 0.0 };
    let x0 = x + shift;
    let inv2 = 1.0 / (x0 * x0);
    let series = SERIES.iter().rev().fold(0.0, |acc, &c| acc * inv2 + c);
    let mut lg = series / x0 + 0.5 * (2.0 * std::f64::consts::PI).ln() + (x0 - 0.5) * x0.ln() - x0;
    let mut y = x0;
    for _ in 0..shift as usize {
        y -= 1.0;
        lg -= y.ln();
    }
    lg
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn log_factorials_are_the_products() {
        let mut exact = 0.0f64;
        for k in 0..200u32 {
            if k > 0 {
                exact += f64::from(k).ln();
            }
            let got = log_factorial(f64::from(k));
            assert!(
                (got - exact).abs() <= 1e-10 * exact.max(1.0),
                "{k}: {got} against {exact}"
            );
        }
    }

    /// Each sampler's histogram against the Poisson probabilities (χ² over the bins
    /// holding at least 20 expected draws, the rest pooled into the tails), at means on
    /// both sides of the switch and far above it, with the mean and variance.
    #[test]
    fn draws_follow_the_poisson_distribution() {
        let mut rng = rand::rngs::StdRng::seed_from_u64(7);
        let n = 200_000;
        for mean in [0.3, 2.5, 9.99, 10.0, 37.5, 412.0, 25_000.0] {
            let draws: Vec<f64> = (0..n).map(|_| sample(mean, &mut rng)).collect();
            assert!(draws.iter().all(|&k| k >= 0.0 && k == k.floor()), "{mean}");
            let m = draws.iter().sum::<f64>() / n as f64;
            let var = draws.iter().map(|k| (k - m).powi(2)).sum::<f64>() / (n - 1) as f64;
            let se = (mean / n as f64).sqrt();
            assert!((m - mean).abs() < 5.0 * se, "mean {m} for {mean}");
            assert!((var / mean - 1.0).abs() < 0.03, "variance {var} for {mean}");
            // χ² over the values k with n·p(k) ≥ 20, all others pooled into one bin.
            let pmf = |k: f64| (-mean + k * mean.ln() - log_factorial(k)).exp();
            let lo = (mean - 10.0 * mean.sqrt()).floor().max(0.0);
            let hi = (mean + 10.0 * mean.sqrt()).ceil() + 20.0;
            let mut seen = vec![0usize; (hi - lo) as usize + 1];
            for &d in &draws {
                if (lo..=hi).contains(&d) {
                    seen[(d - lo) as usize] += 1;
                }
            }
            let (mut chi2, mut bins) = (0.0, 0usize);
            let (mut rest_expected, mut rest_seen) = (n as f64, n);
            for (i, &count) in seen.iter().enumerate() {
                let expected = n as f64 * pmf(lo + i as f64);
                if expected >= 20.0 {
                    chi2 += (count as f64 - expected).powi(2) / expected;
                    bins += 1;
                    rest_expected -= expected;
                    rest_seen -= count;
                }
            }
            if rest_expected >= 5.0 {
                chi2 += (rest_seen as f64 - rest_expected).powi(2) / rest_expected;
                bins += 1;
            }
            // χ² with `bins − 1` degrees of freedom: mean dof, sd √(2·dof); 5 sd is a
            // failure for any honest sampler one time in millions.
            let dof = (bins - 1) as f64;
            assert!(
                chi2 < dof + 5.0 * (2.0 * dof).sqrt(),
                "mean {mean}: χ² {chi2:.1} over {bins} bins"
            );
        }
    }
}
