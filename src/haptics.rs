//! The haptic path: at 1 kHz, finger position → god-object → force solve → a finite, bounded
//! force to the device, and the force boundary condition published lock-free to the visual path.
//!
//! Rules of this path: no allocation after start-up, no lock shared with the visual path (the
//! boundary condition goes through a wait-free triple buffer), and the force sent to the device
//! is always finite and at most [`HapticConfig::max_force_n`].

use glam::DVec3;
use std::time::{Duration, Instant};

use crate::compliance::Compliance;
use crate::contact::{ContactPoint, GodObject, Surface};
use crate::force::{finger_force, saturate, ForceBc, ForceModel};

pub use crate::devices::{HapticDevice, ScriptedDevice};

/// Settings of the haptic loop.
#[derive(Clone, Copy, Debug)]
pub struct HapticConfig {
    /// Loop rate, Hz (the paper: 1000).
    pub rate_hz: f64,
    /// The largest force the device may be sent, N (a PHANToM 1.0 peaks at about 8.5 N).
    pub max_force_n: f64,
    /// Which force formula.
    pub model: ForceModel,
}

impl Default for HapticConfig {
    fn default() -> Self {
        HapticConfig {
            rate_hz: 1000.0,
            max_force_n: 8.5,
            model: ForceModel::Paper,
        }
    }
}

/// The per-finger state of the haptic path: god-object plus the last outputs.
#[derive(Clone, Debug)]
pub struct Finger {
    god: GodObject,
    /// The last contact, if touching.
    pub contact: Option<ContactPoint>,
    /// The last force boundary condition (what the visual path needs).
    pub bc: ForceBc,
}

impl Finger {
    /// A finger starting free at `x` (outside the object).
    pub fn new(x: DVec3) -> Finger {
        Finger {
            god: GodObject::new(x),
            contact: None,
            bc: ForceBc::default(),
        }
    }

    /// One haptic tick: god-object update and force solve. Returns the bounded force for the
    /// device. Allocates nothing.
    #[inline]
    pub fn step(
        &mut self,
        surface: &Surface,
        compliance: &Compliance,
        x: DVec3,
        model: ForceModel,
        max_force_n: f64,
    ) -> DVec3 {
        self.bc.clear();
        if !x.is_finite() {
            // A glitching device: keep the god-object, send nothing.
            self.contact = None;
            return DVec3::ZERO;
        }
        self.contact = self.god.update(surface, x);
        match &self.contact {
            Some(c) => {
                let f = finger_force(compliance, c, model, &mut self.bc).feedback;
                let out = saturate(f, max_force_n);
                if out != f {
                    // Scale the boundary condition with the force actually rendered.
                    let s = if f.length() > 0.0 && out.length() > 0.0 {
                        out.length() / f.length()
                    } else {
                        0.0
                    };
                    let mut scaled = ForceBc::default();
                    for &(col, v) in self.bc.entries() {
                        scaled.add(col, v * s);
                    }
                    self.bc = scaled;
                }
                out
            }
            None => DVec3::ZERO,
        }
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
}

/// What the haptic path publishes each tick for the visual path.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct HapticSample {
    /// The force boundary condition.
    pub bc: ForceBc,
    /// The finger position, m.
    pub finger: DVec3,
    /// The god-object, m, when touching.
    pub proxy: Option<DVec3>,
}

impl Finger {
    /// This tick's sample for the visual path.
    pub fn sample(&self, finger: DVec3) -> HapticSample {
        HapticSample {
            bc: self.bc,
            finger,
            proxy: self.contact.map(|c| c.proxy),
        }
    }
}

/// The writer end of the lock-free channel (haptic side).
pub type BcWriter = triple_buffer::Input<HapticSample>;
/// The reader end (visual side): always sees the latest complete sample.
pub type BcReader = triple_buffer::Output<HapticSample>;

/// A wait-free single-producer single-consumer channel for the latest boundary condition.
pub fn bc_channel() -> (BcWriter, BcReader) {
    triple_buffer::triple_buffer(&HapticSample::default())
}

/// Runs the haptic loop for `seconds` at `cfg.rate_hz` on the calling thread: reads the device,
/// steps the finger, sends the force and publishes the boundary condition each tick. Sleeps
/// until shortly before each deadline and spins the rest, so ticks start on time.
pub fn run_loop(
    surface: &Surface,
    compliance: &Compliance,
    device: &mut dyn HapticDevice,
    cfg: &HapticConfig,
    seconds: f64,
    publish: &mut BcWriter,
) -> HapticStats {
    let period = Duration::from_secs_f64(1.0 / cfg.rate_hz);
    let n = (seconds * cfg.rate_hz).ceil().max(1.0) as usize;
    // All storage is allocated before the first tick.
    let mut starts: Vec<Instant> = Vec::with_capacity(n);
    let mut step_ns: Vec<u64> = Vec::with_capacity(n);
    let mut missed = 0u64;
    let mut max_force: f64 = 0.0;
    let mut finger = Finger::new(device.position(0.0));
    let t0 = Instant::now();
    let mut due = t0;
    for _ in 0..n {
        let now = Instant::now();
        if due > now {
            let wait = due - now;
            if wait > Duration::from_micros(300) {
                std::thread::sleep(wait - Duration::from_micros(250));
            }
            while Instant::now() < due {
                std::hint::spin_loop();
            }
        }
        let start = Instant::now();
        starts.push(start);
        let t = (start - t0).as_secs_f64();
        let x = device.position(t);
        let f = finger.step(surface, compliance, x, cfg.model, cfg.max_force_n);
        device.set_force(f);
        publish.write(finger.sample(x));
        max_force = max_force.max(f.length());
        let end = Instant::now();
        step_ns.push((end - start).as_nanos() as u64);
        due += period;
        if end > due {
            missed += 1;
        }
    }
    let total = starts
        .last()
        .map(|l| (*l - starts[0]).as_secs_f64())
        .unwrap_or(0.0);
    let nominal = period.as_secs_f64() * 1e6;
    let mut err: Vec<f64> = starts
        .windows(2)
        .map(|w| ((w[1] - w[0]).as_secs_f64() * 1e6 - nominal).abs())
        .collect();
    err.sort_by(|a, b| a.total_cmp(b));
    step_ns.sort_unstable();
    HapticStats {
        haptic_rate_hz: if total > 0.0 {
            (starts.len() - 1) as f64 / total
        } else {
            0.0
        },
        period_error_us_p999: percentile(&err, 0.999),
        missed_deadlines: missed,
        seconds: t0.elapsed().as_secs_f64(),
        step_us_median: step_ns.get(step_ns.len() / 2).copied().unwrap_or(0) as f64 / 1e3,
        ticks: starts.len() as u64,
        max_force_n: max_force,
        realtime: false,
    }
}

/// Asks the OS to run the calling thread at real-time priority (Linux `SCHED_FIFO`, priority
/// 80), so the 1 kHz loop keeps its rate whatever the visual path does. Returns false (and
/// changes nothing) where that is not permitted or not supported.
pub fn try_realtime_priority() -> bool {
    #[cfg(target_os = "linux")]
    {
        // SAFETY: plain FFI calls on the current thread with a fully initialised parameter.
        unsafe {
            let param = libc::sched_param { sched_priority: 80 };
            libc::pthread_setschedparam(libc::pthread_self(), libc::SCHED_FIFO, &param) == 0
        }
    }
    #[cfg(not(target_os = "linux"))]
    {
        false
    }
}

/// The q-quantile (0..=1) of sorted data; 0 when empty.
pub fn percentile(sorted: &[f64], q: f64) -> f64 {
    if sorted.is_empty() {
        return 0.0;
    }
    let i = ((sorted.len() - 1) as f64 * q).round() as usize;
    sorted[i.min(sorted.len() - 1)]
}
