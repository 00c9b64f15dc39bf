//! Deadline pacing for the 1 kHz loop and its timing statistics, kept in fixed histograms so a
//! loop of any length allocates nothing after start-up. The same pacer runs the bare *floor*
//! loop ([`run_floor`]): what this machine's scheduler gives a loop that does no work, measured
//! on the same core in the same run, so the haptic loop's timing can be judged against it.

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

/// Period-error histogram: 1 µs bins up to 50 ms.
const ERR_BINS: usize = 50_000;
/// Step-time histogram: 10 ns bins up to 200 µs.
const STEP_BINS: usize = 20_000;
/// Sleep until this long before the deadline, then spin (a SCHED_FIFO thread that only spins
/// is throttled by the kernel; one that sleeps all the way wakes late).
const SPIN: Duration = Duration::from_micros(250);

/// Paces a loop to fixed deadlines (sleep, then spin) and records its timing.
#[derive(Debug)]
pub(crate) struct Pacer {
    period: Duration,
    t0: Instant,
    due: Instant,
    last_start: Option<Instant>,
    first_start: Option<Instant>,
    err_hist: Vec<u32>,
    step_hist: Vec<u32>,
    missed: u64,
    ticks: u64,
    /// Ticks are started by a device ([`Pacer::arrived`]), not by deadlines.
    external: bool,
    /// When the device's previous reading started a tick.
    prev_reading: Option<Instant>,
}

impl Pacer {
    /// A pacer at `rate_hz`; the first deadline is now.
    pub fn new(rate_hz: f64) -> Pacer {
        let t0 = Instant::now();
        Pacer {
            period: Duration::from_secs_f64(1.0 / rate_hz.clamp(1.0, 100_000.0)),
            t0,
            due: t0,
            last_start: None,
            first_start: None,
            err_hist: vec![0; ERR_BINS],
            step_hist: vec![0; STEP_BINS],
            missed: 0,
            ticks: 0,
            external: false,
            prev_reading: None,
        }
    }

    /// Waits for the next deadline; returns the tick's start and its time since the pacer
    /// was made, seconds.
    #[inline]
    pub fn wait(&mut self) -> (Instant, f64) {
        let now = Instant::now();
        if self.due > now {
            let wait = self.due - now;
            if wait > SPIN + Duration::from_micros(50) {
                std::thread::sleep(wait - SPIN);
            }
            while Instant::now() < self.due {
                std::hint::spin_loop();
            }
        }
        self.start_now()
    }

    /// Starts a tick now, for a loop clocked by its device: `reading` says whether a reading
    /// arrived (else the wait timed out). The period error is then the spacing of consecutive
    /// readings against the nominal period, and a tick counts as missed when its own work
    /// takes longer than a period.
    #[inline]
    pub fn arrived(&mut self, reading: bool) -> (Instant, f64) {
        self.external = true;
        let start = Instant::now();
        self.first_start.get_or_insert(start);
        if reading {
            if let Some(prev) = self.prev_reading {
                let err = ((start - prev).as_secs_f64() - self.period.as_secs_f64()).abs() * 1e6;
                self.err_hist[(err as usize).min(ERR_BINS - 1)] += 1;
            }
            self.prev_reading = Some(start);
        } else {
            // Not a tick of the device's clock: the next reading's spacing is not measured.
            self.prev_reading = None;
        }
        self.last_start = Some(start);
        (start, (start - self.t0).as_secs_f64())
    }

    #[inline]
    fn start_now(&mut self) -> (Instant, f64) {
        let start = Instant::now();
        if let Some(last) = self.last_start {
            let err = ((start - last).as_secs_f64() - self.period.as_secs_f64()).abs() * 1e6;
            self.err_hist[(err as usize).min(ERR_BINS - 1)] += 1;
        } else {
            self.first_start = Some(start);
        }
        self.last_start = Some(start);
        (start, (start - self.t0).as_secs_f64())
    }

    /// Ends the tick that started at `start`: records its work time and whether it overran
    /// the next deadline.
    #[inline]
    pub fn end(&mut self, start: Instant) {
        let end = Instant::now();
        let ns = (end - start).as_nanos() as usize;
        self.step_hist[(ns / 10).min(STEP_BINS - 1)] += 1;
        self.ticks += 1;
        if self.external {
            if end - start > self.period {
                self.missed += 1;
            }
            return;
        }
        self.due += self.period;
        if end > self.due {
            self.missed += 1;
        }
    }

    /// Ticks so far.
    pub fn ticks(&self) -> u64 {
        self.ticks
    }
    /// Deadlines missed so far.
    pub fn missed(&self) -> u64 {
        self.missed
    }
    /// Time since the pacer was made.
    pub fn elapsed(&self) -> Duration {
        self.t0.elapsed()
    }

    /// The statistics so far (`max_force_n` and `realtime` are left for the caller).
    pub fn stats(&self) -> HapticStats {
        let span = match (self.first_start, self.last_start) {
            (Some(a), Some(b)) => (b - a).as_secs_f64(),
            _ => 0.0,
        };
        HapticStats {
            haptic_rate_hz: if span > 0.0 {
                (self.ticks.saturating_sub(1)) as f64 / span
            } else {
                0.0
            },
            period_error_us_p999: quantile(&self.err_hist, 0.999) as f64 + 0.5,
            missed_deadlines: self.missed,
            seconds: self.t0.elapsed().as_secs_f64(),
            step_us_median: (quantile(&self.step_hist, 0.5) as f64 + 0.5) * 0.01,
            ticks: self.ticks,
            max_force_n: 0.0,
            realtime: false,
            contact_budget_exhausted: 0,
        }
    }
}

/// The bin below which a fraction `q` of the counts lie.
fn quantile(hist: &[u32], q: f64) -> usize {
    let total: u64 = hist.iter().map(|&c| u64::from(c)).sum();
    if total == 0 {
        return 0;
    }
    let want = (q * total as f64).ceil() as u64;
    let mut acc = 0u64;
    for (i, &c) in hist.iter().enumerate() {
        acc += u64::from(c);
        if acc >= want.max(1) {
            return i;
        }
    }
    hist.len() - 1
}

/// The floor: a bare loop that only paces (sleep, then spin; no work) for `seconds` at
/// `rate_hz` on the calling thread, or until `stop`. Its statistics are what the haptic loop is
/// held to.
pub fn run_floor(rate_hz: f64, seconds: f64, stop: &AtomicBool) -> HapticStats {
    let mut p = Pacer::new(rate_hz);
    let n = (seconds * rate_hz).ceil().max(1.0) as u64;
    while p.ticks() < n && !stop.load(Ordering::Relaxed) {
        let (start, _) = p.wait();
        std::hint::black_box(start);
        p.end(start);
    }
    p.stats()
}

#[cfg(any(test, feature = "self-check"))]
pub(crate) mod tests {
    use super::*;

    #[cfg_attr(test, test)]
    pub(crate) fn quantiles_of_a_histogram() {
        let mut h = vec![0u32; 10];
        h[1] = 998;
        h[7] = 2;
        assert_eq!(quantile(&h, 0.5), 1);
        assert_eq!(quantile(&h, 0.998), 1);
        assert_eq!(quantile(&h, 0.999), 7);
        assert_eq!(quantile(&[0; 4], 0.5), 0);
    }

    #[cfg_attr(test, test)]
    pub(crate) fn the_floor_runs_at_its_rate() {
        let s = run_floor(1000.0, 0.2, &AtomicBool::new(false));
        assert_eq!(s.ticks, 200);
        // 199 periods of 1 ms: the rate is 1 kHz unless the machine stalled for a long time.
        assert!((s.haptic_rate_hz - 1000.0).abs() < 100.0, "{s:?}");
    }
}

/// Timing of a haptic run.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct HapticStats {
    /// Ticks per second achieved.
    pub haptic_rate_hz: f64,
    /// 99.9th percentile of |period − nominal period|, microseconds.
    pub period_error_us_p999: f64,
    /// Ticks whose work finished after the next tick was due.
    pub missed_deadlines: u64,
    /// Wall time of the run, seconds.
    pub seconds: f64,
    /// Median force-step time (god-object + solve), microseconds.
    pub step_us_median: f64,
    /// Ticks run.
    pub ticks: u64,
    /// Largest force sent, N.
    pub max_force_n: f64,
    /// Whether the loop ran at real-time priority.
    pub realtime: bool,
    /// Sphere contact solves that ran out of their budget (each still sent a finite, bounded
    /// force; 0 without spheres).
    pub contact_budget_exhausted: u64,
}

/// The q-quantile (0..=1) of sorted data; 0 when empty.
pub fn percentile(sorted: &[f64], q: f64) -> f64 {
    if sorted.is_empty() {
        return 0.0;
    }
    let i = ((sorted.len() - 1) as f64 * q).round() as usize;
    sorted[i.min(sorted.len() - 1)]
}
