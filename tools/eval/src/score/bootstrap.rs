//! Is variant A better than variant B, or is the difference noise? A paired percentile bootstrap
//! over per-frame (or per-sequence) scores of the two on the same input.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;

/// The mean paired difference a − b with its 95 % percentile-bootstrap interval.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct PairedDifference {
    /// Mean of `a[i] − b[i]`.
    pub mean_diff: f64,
    /// 2.5th and 97.5th percentiles of the resampled means.
    pub ci95_low: f64,
    pub ci95_high: f64,
    /// Pairs.
    pub n: usize,
}

/// Why no interval could be computed.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
pub enum BootstrapError {
    #[error("paired samples differ in length: {a} and {b}")]
    LengthMismatch { a: usize, b: usize },
    #[error("no pairs to compare")]
    Empty,
    #[error("pair {index} is not finite: ({a}, {b})")]
    NotFinite { index: usize, a: f64, b: f64 },
    #[error("the bootstrap needs at least one resample")]
    NoResamples,
}

/// The paired difference a − b (`a[i]` and `b[i]` measured on the same frame or sequence) with a
/// percentile bootstrap: `resamples` times, draw n pairs with replacement and take the mean
/// difference; the interval is the 2.5th and 97.5th percentiles of those means (linear
/// interpolation between order statistics, numpy's default). Deterministic for a `seed`.
///
/// Pairs are resampled as units, which keeps the correlation between a and b (both variants saw
/// the same input) out of the interval's width. Consecutive frames are correlated too; resample
/// per-sequence (or per-window) means where that matters, since an i.i.d. bootstrap over frames
/// gives too narrow an interval then.
pub fn paired_bootstrap(
    a: &[f64],
    b: &[f64],
    resamples: usize,
    seed: u64,
) -> Result<PairedDifference, BootstrapError> {
    if a.len() != b.len() {
        return Err(BootstrapError::LengthMismatch {
            a: a.len(),
            b: b.len(),
        });
    }
    if a.is_empty() {
        return Err(BootstrapError::Empty);
    }
    if resamples == 0 {
        return Err(BootstrapError::NoResamples);
    }
    if let Some(index) = (0..a.len()).find(|&i| !(a[i].is_finite() && b[i].is_finite())) {
        return Err(BootstrapError::NotFinite {
            index,
            a: a[index],
            b: b[index],
        });
    }
    let d: Vec<f64> = a.iter().zip(b).map(|(x, y)| x - y).collect();
    let n = d.len();
    // ChaCha8 rather than rand's StdRng: StdRng's algorithm may change between rand releases, a
    // named ChaCha stream does not, so a seed keeps giving the same interval.
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let mut means: Vec<f64> = (0..resamples)
        .map(|_| (0..n).map(|_| d[rng.random_range(0..n)]).sum::<f64>() / n as f64)
        .collect();
    means.sort_by(f64::total_cmp);
    Ok(PairedDifference {
        mean_diff: d.iter().sum::<f64>() / n as f64,
        ci95_low: quantile(&means, 0.025),
        ci95_high: quantile(&means, 0.975),
        n,
    })
}

/// The `p` quantile of ascending `sorted` (non-empty), interpolating linearly between order
/// statistics at rank p·(len − 1) (Hyndman & Fan type 7).
fn quantile(sorted: &[f64], p: f64) -> f64 {
    let rank = p * (sorted.len() - 1) as f64;
    let (lo, hi) = (rank.floor() as usize, rank.ceil() as usize);
    sorted[lo] + (sorted[hi] - sorted[lo]) * (rank - lo as f64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_constant_difference_has_a_point_interval() {
        let a: Vec<f64> = (0..50).map(|k| 1.0 + 0.1 * f64::from(k)).collect();
        let b: Vec<f64> = a.iter().map(|x| x - 0.25).collect();
        let r = paired_bootstrap(&a, &b, 500, 7).unwrap();
        assert_eq!(r.n, 50);
        assert!((r.mean_diff - 0.25).abs() < 1e-12);
        assert!((r.ci95_low - 0.25).abs() < 1e-12, "{r:?}");
        assert!((r.ci95_high - 0.25).abs() < 1e-12, "{r:?}");
    }

    #[test]
    fn a_symmetric_zero_mean_difference_covers_zero_with_the_expected_width() {
        // d alternates ±1: mean 0, standard deviation 1, so the mean of 400 pairs has a standard
        // error of 1/√400 = 0.05 and a 95 % interval of about ±1.96·0.05 = ±0.098.
        let a: Vec<f64> = (0..400)
            .map(|k| if k % 2 == 0 { 3.0 } else { 1.0 })
            .collect();
        let b = vec![2.0; 400];
        let r = paired_bootstrap(&a, &b, 2000, 1).unwrap();
        assert_eq!(r.mean_diff, 0.0);
        assert!(r.ci95_low < 0.0 && r.ci95_high > 0.0, "{r:?}");
        for bound in [-r.ci95_low, r.ci95_high] {
            assert!((0.08..0.12).contains(&bound), "{r:?}");
        }
    }

    #[test]
    fn a_clear_improvement_excludes_zero() {
        // b is a plus 0.5 plus noise in [-0.5, 0.5): a − b is −0.5 on average, far from 0.
        let a: Vec<f64> = (0..200).map(|k| f64::from(k % 17)).collect();
        let b: Vec<f64> = a
            .iter()
            .enumerate()
            .map(|(k, x)| x + 0.5 + ((k * 37 % 100) as f64 / 100.0 - 0.5))
            .collect();
        let r = paired_bootstrap(&a, &b, 1000, 3).unwrap();
        assert!(r.ci95_high < 0.0, "{r:?}");
        assert!(r.ci95_low <= r.mean_diff && r.mean_diff <= r.ci95_high);
    }

    #[test]
    fn deterministic_for_a_seed() {
        let a: Vec<f64> = (0..100).map(|k| (f64::from(k) * 0.7).sin()).collect();
        let b: Vec<f64> = (0..100).map(|k| (f64::from(k) * 0.3).cos()).collect();
        let first = paired_bootstrap(&a, &b, 300, 42).unwrap();
        assert_eq!(first, paired_bootstrap(&a, &b, 300, 42).unwrap());
        assert_ne!(first, paired_bootstrap(&a, &b, 300, 43).unwrap());
    }

    #[test]
    fn refuses_what_it_cannot_pair() {
        assert_eq!(
            paired_bootstrap(&[1.0, 2.0], &[1.0], 10, 0),
            Err(BootstrapError::LengthMismatch { a: 2, b: 1 })
        );
        assert_eq!(
            paired_bootstrap(&[], &[], 10, 0),
            Err(BootstrapError::Empty)
        );
        assert_eq!(
            paired_bootstrap(&[1.0], &[1.0], 0, 0),
            Err(BootstrapError::NoResamples)
        );
        assert!(matches!(
            paired_bootstrap(&[1.0, f64::NAN], &[1.0, 2.0], 10, 0),
            Err(BootstrapError::NotFinite { index: 1, .. })
        ));
    }

    #[test]
    fn quantile_interpolates_between_order_statistics() {
        let v = [0.0, 1.0, 2.0, 3.0, 4.0];
        assert_eq!(quantile(&v, 0.0), 0.0);
        assert_eq!(quantile(&v, 1.0), 4.0);
        assert_eq!(quantile(&v, 0.5), 2.0);
        assert!((quantile(&v, 0.025) - 0.1).abs() < 1e-12);
    }
}
