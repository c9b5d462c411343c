//! The loop's statistics: fixed-size histograms of durations for the run summary, the
//! window of recent ticks that telemetry's rate and 99th percentile come from, overruns, the
//! running totals, and the transport counters, all behind one [`Stats::reset`]. Recording
//! allocates nothing, so the loop keeps them for every tick.

use std::time::{Duration, Instant};

use crate::protocol::Counters;

use super::Summary;

/// Ticks the loop-rate and tick-time statistics look back over.
pub const WINDOW: usize = 1000;

/// The fewest ticks in the window over which the loop is judged behind its rate.
pub const BEHIND_MIN_TICKS: usize = 10;

/// Overrun messages come at most this often.
const OVERRUN_LOG_EVERY: Duration = Duration::from_secs(1);

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

/// Times of the last [`WINDOW`] ticks, in fixed buffers.
#[derive(Debug, Clone)]
struct Window {
    starts: Vec<Instant>,
    work_us: Vec<f64>,
    /// Per tick, whether it ran past its period.
    late: Vec<bool>,
    /// How many of the window's ticks ran late.
    late_count: usize,
    scratch: Vec<f64>,
    next: usize,
    filled: usize,
    p99_us: f64,
}

impl Window {
    fn new(now: Instant) -> Self {
        Self {
            starts: vec![now; WINDOW],
            work_us: vec![0.0; WINDOW],
            late: vec![false; WINDOW],
            late_count: 0,
            scratch: vec![0.0; WINDOW],
            next: 0,
            filled: 0,
            p99_us: 0.0,
        }
    }

    fn record(&mut self, start: Instant, work_us: f64, late: bool) {
        self.starts[self.next] = start;
        self.work_us[self.next] = work_us;
        if self.filled == WINDOW && self.late[self.next] {
            self.late_count -= 1;
        }
        self.late[self.next] = late;
        self.late_count += usize::from(late);
        self.next = (self.next + 1) % WINDOW;
        self.filled = (self.filled + 1).min(WINDOW);
        // The percentile is refreshed every tenth tick: a selection over 1000 values.
        if self.next % 10 == 0 {
            let n = self.filled;
            self.scratch[..n].copy_from_slice(&self.work_us[..n]);
            let k = ((n as f64) * 0.99).ceil() as usize;
            let k = k.clamp(1, n) - 1;
            let (_, p, _) = self.scratch[..n].select_nth_unstable_by(k, f64::total_cmp);
            self.p99_us = *p;
        }
    }

    /// Ticks per second over the window.
    fn rate_hz(&self) -> f64 {
        if self.filled < 2 {
            return 0.0;
        }
        let newest = self.starts[(self.next + WINDOW - 1) % WINDOW];
        let oldest = if self.filled == WINDOW {
            self.starts[self.next]
        } else {
            self.starts[0]
        };
        let span = newest.saturating_duration_since(oldest).as_secs_f64();
        if span > 0.0 {
            (self.filled - 1) as f64 / span
        } else {
            0.0
        }
    }

    /// More than half the window's ticks ran late, over at least [`BEHIND_MIN_TICKS`]: the
    /// loop runs back to back, below its configured rate. (One late tick alone, the first after
    /// start-up or a `reset_stats`, tells nothing, and no rate can be measured yet.)
    fn behind(&self) -> bool {
        self.filled >= BEHIND_MIN_TICKS && 2 * self.late_count > self.filled
    }

    fn clear(&mut self) {
        self.next = 0;
        self.filled = 0;
        self.late_count = 0;
        self.late.iter_mut().for_each(|l| *l = false);
        self.p99_us = 0.0;
    }
}

/// Everything the loop counts.
#[derive(Debug, Clone)]
pub struct Stats {
    window: Window,
    tick: Histogram,
    solve: Histogram,
    latency: Histogram,
    overruns: u64,
    overruns_logged: u64,
    last_overrun_log: Option<Instant>,
    peak_total: f64,
    m3_total: f64,
    /// Start of the span the summary covers, and the ticks and overruns before it.
    since: Instant,
    ticks_before: u64,
    overruns_before: u64,
    /// Transport counters: never reset, a client tracks their growth.
    pub counters: Counters,
    write_errors: u64,
}

impl Stats {
    /// Nothing counted yet, at `now`.
    pub fn new(now: Instant) -> Self {
        Self {
            window: Window::new(now),
            tick: Histogram::new(),
            solve: Histogram::new(),
            latency: Histogram::new(),
            overruns: 0,
            overruns_logged: 0,
            last_overrun_log: None,
            peak_total: 0.0,
            m3_total: 0.0,
            since: now,
            ticks_before: 0,
            overruns_before: 0,
            counters: Counters::default(),
            write_errors: 0,
        }
    }

    /// `reset_stats` at `tick`: the summary, the window, the histograms and the running totals
    /// start again; the transport counters and the overrun total go on.
    pub fn reset(&mut self, now: Instant, tick: u64) {
        self.window.clear();
        self.tick.clear();
        self.solve.clear();
        self.latency.clear();
        self.peak_total = 0.0;
        self.m3_total = 0.0;
        self.since = now;
        self.ticks_before = tick;
        self.overruns_before = self.overruns;
    }

    /// A tick that started at `start`, worked for `work`, and ended past its period when
    /// `late`.
    pub fn record_tick(&mut self, start: Instant, work: Duration, late: bool) {
        self.window.record(start, work.as_secs_f64() * 1e6, late);
        self.tick.record(work);
    }

    /// The controller's time in a tick, its joint-speed peak and metric-3 increment.
    pub fn record_solve(&mut self, solve: Duration, peak_joint_speed_rad_s: f64, m3_rad2: f64) {
        self.solve.record(solve);
        self.peak_total = self.peak_total.max(peak_joint_speed_rad_s);
        self.m3_total += m3_rad2;
    }

    /// From a command's line read to the write of the tick that applied it.
    pub fn record_latency(&mut self, latency: Duration) {
        self.latency.record(latency);
    }

    /// More than half the last [`WINDOW`] ticks ran past their period: the loop runs back to
    /// back at the rate its work allows ([`Stats::rate_hz`]), below the configured one.
    pub fn behind(&self) -> bool {
        self.window.behind()
    }

    /// `missed` periods skipped at `now`; the count to log, at most once a second.
    pub fn overrun(&mut self, missed: u64, now: Instant) -> Option<(u64, u64)> {
        self.overruns += missed;
        let due = self
            .last_overrun_log
            .is_none_or(|t| now.saturating_duration_since(t) >= OVERRUN_LOG_EVERY);
        if !due {
            return None;
        }
        let since_last = self.overruns - self.overruns_logged;
        self.last_overrun_log = Some(now);
        self.overruns_logged = self.overruns;
        Some((since_last, self.overruns))
    }

    /// A goal write failed; true when the count reaches a power of two (worth a log line).
    pub fn write_failed(&mut self) -> (u64, bool) {
        self.write_errors += 1;
        (self.write_errors, self.write_errors.is_power_of_two())
    }

    /// Ticks per second over the window.
    pub fn rate_hz(&self) -> f64 {
        self.window.rate_hz()
    }

    /// The window's 99th percentile of tick work, µs.
    pub fn tick_p99_us(&self) -> f64 {
        self.window.p99_us
    }

    /// Periods skipped since start.
    pub fn overruns(&self) -> u64 {
        self.overruns
    }

    /// The fastest joint speed since the last reset, rad/s.
    pub fn peak_total(&self) -> f64 {
        self.peak_total
    }

    /// Metric 3 summed since the last reset, rad².
    pub fn m3_total(&self) -> f64 {
        self.m3_total
    }

    /// The run summary as of `tick` at `now`.
    pub fn summary(&self, tick: u64, now: Instant) -> Summary {
        Summary {
            ticks: tick - self.ticks_before,
            overruns: self.overruns - self.overruns_before,
            elapsed_s: now.saturating_duration_since(self.since).as_secs_f64(),
            tick: self.tick.summary(),
            solve: self.solve.summary(),
            command_to_wire: self.latency.summary(),
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

    #[test]
    fn behind_once_most_of_the_window_ran_late_and_no_longer_after_it_slides_past() {
        let t0 = Instant::now();
        let mut s = Stats::new(t0);
        let tick = |s: &mut Stats, k: u32, late: bool| {
            s.record_tick(t0 + k * Duration::from_millis(10), Duration::ZERO, late);
        };
        for k in 0..10 {
            tick(&mut s, k, k % 2 == 0);
        }
        assert!(!s.behind(), "half the ticks late is not behind");
        tick(&mut s, 10, true);
        assert!(s.behind(), "6 of 11 late");
        // A whole window on time slides the late ones out.
        for k in 11..11 + WINDOW as u32 {
            tick(&mut s, k, false);
        }
        assert!(!s.behind());
        s.reset(t0, 0);
        for k in 0..BEHIND_MIN_TICKS as u32 {
            assert!(!s.behind(), "{k} ticks tell nothing yet");
            tick(&mut s, k, true);
        }
        assert!(s.behind(), "after a reset, the window starts again");
        assert!(s.rate_hz() > 0.0, "and the rate it then tells is measured");
    }

    #[test]
    fn one_reset_starts_every_statistic_again_but_the_counters() {
        let t0 = Instant::now();
        let mut s = Stats::new(t0);
        s.counters.dropped = 3;
        for k in 0..20u32 {
            s.record_tick(
                t0 + k * Duration::from_millis(10),
                Duration::from_micros(200),
                k % 2 == 0,
            );
        }
        s.record_solve(Duration::from_micros(50), 1.5, 0.25);
        s.record_latency(Duration::from_micros(900));
        assert!(s.overrun(2, t0).is_some());
        assert!(
            s.overrun(1, t0 + Duration::from_millis(10)).is_none(),
            "throttled"
        );
        assert_eq!(
            s.overrun(1, t0 + Duration::from_secs(1)),
            Some((2, 4)),
            "the count since the last message, and the total"
        );
        assert!((s.rate_hz() - 100.0).abs() < 1e-6, "{}", s.rate_hz());
        assert_eq!(s.tick_p99_us(), 200.0);
        let before = s.summary(20, t0 + Duration::from_millis(200));
        assert_eq!((before.ticks, before.overruns), (20, 4));
        assert_eq!(before.solve.count, 1);

        s.reset(t0 + Duration::from_secs(2), 20);
        let after = s.summary(25, t0 + Duration::from_secs(3));
        assert_eq!((after.ticks, after.overruns), (5, 0));
        assert_eq!(after.elapsed_s, 1.0);
        assert_eq!(
            (
                after.tick.count,
                after.solve.count,
                after.command_to_wire.count
            ),
            (0, 0, 0)
        );
        assert_eq!(
            (s.peak_total(), s.m3_total(), s.rate_hz(), s.tick_p99_us()),
            (0.0, 0.0, 0.0, 0.0)
        );
        assert_eq!(s.overruns(), 4, "the total goes on");
        assert_eq!(s.counters.dropped, 3, "the counters go on");
    }
}
