//! The haptic path: at 1 kHz, finger position → god-object → force solve → a finite, bounded
//! force to the device, and the force boundary condition published lock-free to the visual path.
//!
//! Rules of this path: no allocation after start-up, no lock shared with the visual path (the
//! boundary condition goes through a wait-free triple buffer), and the force sent to the device
//! is always finite and at most [`HapticConfig::max_force_n`].

use glam::DVec3;

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

/// Runs one finger's haptic loop for `seconds` at `cfg.rate_hz` on the calling thread: reads
/// the device, steps the finger, sends the force and publishes the boundary condition each
/// tick, paced by [`crate::runtime::pacer::Pacer`] (sleep, then spin to each deadline). Scenes
/// with several fingers or objects run [`crate::runtime::run_haptic`].
pub fn run_loop(
    surface: &Surface,
    compliance: &Compliance,
    device: &mut dyn HapticDevice,
    cfg: &HapticConfig,
    seconds: f64,
    publish: &mut BcWriter,
) -> HapticStats {
    let n = (seconds * cfg.rate_hz).ceil().max(1.0) as u64;
    let mut pacer = crate::runtime::pacer::Pacer::new(cfg.rate_hz);
    let mut max_force: f64 = 0.0;
    let mut finger = Finger::new(device.position(0.0));
    while pacer.ticks() < n {
        let (start, t) = pacer.wait();
        let x = device.position(t);
        let f = finger.step(surface, compliance, x, cfg.model, cfg.max_force_n);
        device.set_force(f);
        publish.write(finger.sample(x));
        max_force = max_force.max(f.length());
        pacer.end(start);
    }
    let mut stats = pacer.stats();
    stats.max_force_n = max_force;
    stats
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
