//! Quantiles of a stream in fixed memory: a histogram of logarithmic bins, each 0.5 % wide, so
//! a quantile is known to within 0.25 % of its value whatever the count. For latencies over a
//! long run, where keeping every sample grows without bound (the demo's summary did: 2 kB a
//! second at 120 pose frames/s). Not a thesis equation.

/// Relative width of a bin.
const STEP: f64 = 0.005;

/// Quantiles of non-negative values between `lo` and `hi` (smaller ones counted in the first
/// bin, larger in the last); exact minimum and maximum.
#[derive(Debug, Clone, PartialEq)]
pub struct LogHistogram {
    lo: f64,
    counts: Vec<u64>,
    total: u64,
    min: f64,
    max: f64,
}

impl LogHistogram {
    /// Bins from `lo` to `hi` (both above 0, `hi` above `lo`; at most 20 000 bins, about nine
    /// decades).
    pub fn new(lo: f64, hi: f64) -> Self {
        let lo = if lo.is_finite() && lo > 0.0 { lo } else { 1e-9 };
        let hi = if hi.is_finite() && hi > lo {
            hi
        } else {
            lo * 1e9
        };
        let bins = (((hi / lo).ln() / STEP.ln_1p()).ceil() as usize + 1).min(20_000);
        LogHistogram {
            lo,
            counts: vec![0; bins],
            total: 0,
            min: f64::INFINITY,
            max: f64::NEG_INFINITY,
        }
    }

    fn bin(&self, v: f64) -> usize {
        if v <= self.lo {
            return 0;
        }
        let k = ((v / self.lo).ln() / STEP.ln_1p()) as usize;
        k.min(self.counts.len() - 1)
    }

    /// Counts `v` (a value that is not finite is left out).
    pub fn add(&mut self, v: f64) {
        if !v.is_finite() {
            return;
        }
        let b = self.bin(v);
        self.counts[b] += 1;
        self.total += 1;
        self.min = self.min.min(v);
        self.max = self.max.max(v);
    }

    pub fn count(&self) -> u64 {
        self.total
    }

    /// The `q` quantile (0 ≤ q ≤ 1; the value at rank `round((n − 1)·q)` of the sorted values,
    /// to 0.25 %; the first and last ranks exact); NaN with no values.
    pub fn quantile(&self, q: f64) -> f64 {
        if self.total == 0 {
            return f64::NAN;
        }
        let rank = ((self.total - 1) as f64 * q.clamp(0.0, 1.0)).round() as u64;
        if rank == 0 {
            return self.min;
        }
        if rank == self.total - 1 {
            return self.max;
        }
        let mut seen = 0u64;
        for (k, c) in self.counts.iter().enumerate() {
            seen += c;
            if seen > rank {
                let mid = self.lo * (STEP.ln_1p() * (k as f64 + 0.5)).exp();
                return mid.clamp(self.min, self.max);
            }
        }
        self.max
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::random::SplitMix64;

    #[test]
    fn quantiles_are_within_a_quarter_percent_of_the_sorted_values() {
        let mut rng = SplitMix64::new(4);
        let mut h = LogHistogram::new(1e-4, 1e5);
        let mut all = Vec::new();
        for _ in 0..100_000 {
            // Latency-like: a lognormal body round 1 ms and a tail.
            let v = (rng.normal() * 0.6).exp() * if rng.uniform() < 0.02 { 20.0 } else { 1.0 };
            h.add(v);
            all.push(v);
        }
        h.add(f64::NAN);
        all.sort_by(f64::total_cmp);
        assert_eq!(h.count(), 100_000);
        for q in [0.0, 0.01, 0.5, 0.9, 0.99, 0.999, 1.0] {
            let want = all[((all.len() - 1) as f64 * q).round() as usize];
            let got = h.quantile(q);
            assert!(
                (got / want - 1.0).abs() <= 0.0026,
                "q {q}: {got} against {want}"
            );
        }
        assert!(LogHistogram::new(1.0, 10.0).quantile(0.5).is_nan());
    }

    #[test]
    fn values_outside_the_range_are_held_by_the_ends() {
        let mut h = LogHistogram::new(1.0, 100.0);
        for v in [0.0, 0.5, 1e6] {
            h.add(v);
        }
        assert_eq!(h.quantile(0.0), 0.0);
        assert_eq!(h.quantile(1.0), 1e6);
        assert!(h.quantile(0.5) <= 1.01);
    }
}
