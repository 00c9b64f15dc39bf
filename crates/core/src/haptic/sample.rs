//! What the haptic path hands to the visual path each tick, and the live status a window shows.

use glam::DVec3;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};

use crate::contact::force::{ForceBc, MAX_FINGERS};

pub use crate::limits::MAX_OBJECTS;

/// One finger as the visual path sees it.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct FingerView {
    /// The device position, metres, scene frame (NaN while the device gives no reading).
    pub position: DVec3,
    /// The god-object, metres, scene frame, while touching.
    pub proxy: Option<DVec3>,
    /// The object it touches.
    pub object: Option<u8>,
    /// The force sent to the device this tick, N.
    pub force: DVec3,
}

/// Everything the haptic loop publishes each tick (`Copy`, fixed size: it crosses threads
/// through a wait-free triple buffer).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct WorldSample {
    /// The tick this sample comes from (0 before the first).
    pub tick: u64,
    /// Per object, the force boundary condition on its touchable columns.
    pub bcs: [ForceBc; MAX_OBJECTS],
    /// Number of objects.
    pub n_objects: usize,
    /// Per finger.
    pub fingers: [FingerView; MAX_FINGERS],
    /// Number of fingers.
    pub n_fingers: usize,
}

impl Default for WorldSample {
    fn default() -> Self {
        WorldSample {
            tick: 0,
            bcs: [ForceBc::default(); MAX_OBJECTS],
            n_objects: 0,
            fingers: [FingerView::default(); MAX_FINGERS],
            n_fingers: 0,
        }
    }
}

impl WorldSample {
    /// The boundary condition of object `o`.
    pub fn bc(&self, o: usize) -> &ForceBc {
        &self.bcs[o]
    }
    /// The fingers.
    pub fn fingers(&self) -> &[FingerView] {
        &self.fingers[..self.n_fingers]
    }
    /// Fingers touching object `o`.
    pub fn contacts(&self, o: usize) -> usize {
        self.fingers()
            .iter()
            .filter(|f| f.object == Some(o as u8))
            .count()
    }
}

/// The writer end of the lock-free channel (haptic side).
pub type SampleWriter = triple_buffer::Input<WorldSample>;
/// The reader end (visual side): always the latest complete sample.
pub type SampleReader = triple_buffer::Output<WorldSample>;

/// A wait-free single-producer single-consumer channel for the latest [`WorldSample`].
pub fn sample_channel() -> (SampleWriter, SampleReader) {
    triple_buffer::triple_buffer(&WorldSample::default())
}

/// Live counters of the haptic loop for a status line (atomics only; no lock).
#[derive(Debug, Default)]
pub struct LiveStatus {
    /// Ticks run so far.
    pub ticks: AtomicU64,
    /// Nanoseconds since the loop started, at the last tick.
    pub elapsed_ns: AtomicU64,
    /// Deadlines missed so far.
    pub missed: AtomicU64,
    /// Set when the haptic loop has ended (normally or by a panic).
    pub done: AtomicBool,
    /// Set when the haptic loop ended by a panic.
    pub panicked: AtomicBool,
    /// Set by anyone to ask the haptic loop to stop.
    pub stop: AtomicBool,
    /// Set by the visual side once `L` is on the GPU: `view` starts its haptic loop only then
    /// (or on `stop`), so that the upload's reads of a multi-gigabyte cache file cost the loop
    /// no deadlines.
    pub visual_ready: AtomicBool,
    /// The cut bodies the cutter's thread has built, for the visual loop.
    pub cuts: std::sync::Arc<super::cutter::CutFeed>,
}

impl LiveStatus {
    /// Waits until [`LiveStatus::visual_ready`] or [`LiveStatus::stop`] is set; `true` if the
    /// visual side is ready. Sleeps between looks: only with the `native` feature.
    #[cfg(feature = "native")]
    pub fn wait_visual_ready(&self) -> bool {
        loop {
            if self.stop.load(Ordering::SeqCst) {
                return false;
            }
            if self.visual_ready.load(Ordering::SeqCst) {
                return true;
            }
            std::thread::sleep(std::time::Duration::from_millis(2));
        }
    }

    /// The haptic rate over the whole run so far, Hz.
    pub fn rate_hz(&self) -> f64 {
        let t = self.elapsed_ns.load(Ordering::Relaxed) as f64 * 1e-9;
        let n = self.ticks.load(Ordering::Relaxed);
        if t > 0.0 && n > 1 {
            (n - 1) as f64 / t
        } else {
            0.0
        }
    }
}

#[cfg(all(any(test, feature = "self-check"), feature = "native"))]
pub(crate) mod tests {
    use super::*;

    /// Asserts the order of events, not a duration: the waiter returns only after a flag was
    /// set (a busy machine may start the waiting thread late, which changes nothing here).
    #[cfg_attr(test, test)]
    pub(crate) fn the_haptic_side_waits_for_the_visual_side_or_a_stop() {
        for (ready, stop, want) in [(true, false, true), (false, true, false)] {
            let s = LiveStatus::default();
            let set = AtomicBool::new(false);
            let (got, after) = std::thread::scope(|sc| {
                let h = sc.spawn(|| {
                    let got = s.wait_visual_ready();
                    (got, set.load(Ordering::SeqCst))
                });
                std::thread::sleep(std::time::Duration::from_millis(30));
                assert!(!h.is_finished(), "returned before either flag");
                set.store(true, Ordering::SeqCst);
                s.visual_ready.store(ready, Ordering::SeqCst);
                s.stop.store(stop, Ordering::SeqCst);
                h.join().expect("waiter")
            });
            assert_eq!(got, want);
            assert!(after, "the waiter returned before a flag was set");
        }
    }
}
