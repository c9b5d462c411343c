//! Fixed-size histograms of durations, for the loop's run summary: recording allocates
//! nothing, so the loop can keep one for every tick.

use std::time::Duration;

/// Buckets of 1 µs below this, µs.
const FINE_US: u64 = 1_000;
/// Buckets of 10 µs from [`FINE_US`] up to this, µs; longer values share the last bucket.
const COARSE_US: u64 = 100_000;
const COARSE_STEP_US: u64 = 10;
const BUCKETS: usize = (FINE_US + (COARSE_US - FINE_US) / COARSE_STEP_US + 1) as usize;

/// A histogram of durations: 1 µs resolution below 1 ms, 10 µs up to 100 ms.
#[derive(Clone)]
pub struct Histogram {
    counts: Vec<u64>,
    total: u64,
    max_us: f64,
}

impl std::fmt::Debug for Histogram {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Histogram")
            .field("total", &self.total)
            .field("summary", &self.summary())
            .finish()
    }
}

impl Default for Histogram {
    fn default() -> Self {
        Self::new()
    }
}

/// Percentiles of a [`Histogram`], µs (bucket upper edges, so never optimistic).
#[derive(Debug, Clone, Copy, PartialEq, Default, serde::Serialize)]
pub struct Percentiles {
    /// Values recorded.
    pub count: u64,
    /// Median, µs.
    pub p50_us: f64,
    /// 99th percentile, µs.
    pub p99_us: f64,
    /// Largest value, µs.
    pub max_us: f64,
}

impl Histogram {
    /// Empty.
    pub fn new() -> Self {
        Self {
            counts: vec![0; BUCKETS],
            total: 0,
            max_us: 0.0,
        }
    }

    fn bucket(us: u64) -> usize {
        if us < FINE_US {
            us as usize
        } else {
            let coarse = ((us.min(COARSE_US) - FINE_US) / COARSE_STEP_US) as usize;
            FINE_US as usize + coarse
        }
    }

    fn upper_edge_us(bucket: usize) -> f64 {
        let b = bucket as u64;
        if b < FINE_US {
            (b + 1) as f64
        } else {
            (FINE_US + (b - FINE_US + 1) * COARSE_STEP_US) as f64
        }
    }

    /// Counts one duration.
    pub fn record(&mut self, d: Duration) {
        let us = d.as_micros().min(u128::from(u64::MAX)) as u64;
        self.counts[Self::bucket(us)] += 1;
        self.total += 1;
        self.max_us = self.max_us.max(d.as_secs_f64() * 1e6);
    }

    /// Forgets everything recorded.
    pub fn clear(&mut self) {
        self.counts.iter_mut().for_each(|c| *c = 0);
        self.total = 0;
        self.max_us = 0.0;
    }

    /// The value below which a fraction `q` of the recorded ones lie, µs (0 when empty).
    pub fn quantile_us(&self, q: f64) -> f64 {
        if self.total == 0 {
            return 0.0;
        }
        let rank = ((self.total as f64) * q).ceil().max(1.0) as u64;
        let mut seen = 0;
        for (i, &c) in self.counts.iter().enumerate() {
            seen += c;
            if seen >= rank {
                if i == BUCKETS - 1 {
                    return self.max_us;
                }
                return Self::upper_edge_us(i).min(self.max_us.max(0.0).ceil().max(1.0));
            }
        }
        self.max_us
    }

    /// Median, 99th percentile and maximum.
    pub fn summary(&self) -> Percentiles {
        Percentiles {
            count: self.total,
            p50_us: self.quantile_us(0.5),
            p99_us: self.quantile_us(0.99),
            max_us: self.max_us,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quantiles_of_a_known_spread() {
        let mut h = Histogram::new();
        for us in 1..=1000u64 {
            h.record(Duration::from_micros(us * 10));
        }
        let s = h.summary();
        assert_eq!(s.count, 1000);
        // 5000 µs is the 500th value; the bucket edge is at most 10 µs above.
        assert!((5000.0..=5010.0).contains(&s.p50_us), "{s:?}");
        assert!((9900.0..=9910.0).contains(&s.p99_us), "{s:?}");
        assert_eq!(s.max_us, 10_000.0);
    }

    #[test]
    fn fine_values_keep_their_microsecond() {
        let mut h = Histogram::new();
        for _ in 0..99 {
            h.record(Duration::from_nanos(41_300));
        }
        h.record(Duration::from_millis(250));
        assert_eq!(h.quantile_us(0.5), 42.0);
        assert_eq!(h.quantile_us(0.99), 42.0);
        assert_eq!(h.quantile_us(1.0), 250_000.0);
        h.clear();
        assert_eq!(h.summary(), Percentiles::default());
    }
}
