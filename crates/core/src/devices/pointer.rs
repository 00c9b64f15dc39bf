//! The `view` window's pointer as a haptic device: the window writes the finger position, the
//! haptic loop reads it, through atomics (no lock is shared between the two loops).

use glam::DVec3;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;

use super::HapticDevice;

/// The pointer's finger position shared between the window (writer) and the haptic loop
/// (reader). Each coordinate is an `f64` stored as bits; a NaN position means "lifted".
#[derive(Debug)]
pub struct PointerShared {
    xyz: [AtomicU64; 3],
    force: [AtomicU64; 3],
}

impl Default for PointerShared {
    fn default() -> Self {
        let nan = f64::NAN.to_bits();
        PointerShared {
            xyz: [
                AtomicU64::new(nan),
                AtomicU64::new(nan),
                AtomicU64::new(nan),
            ],
            force: [AtomicU64::new(0), AtomicU64::new(0), AtomicU64::new(0)],
        }
    }
}

impl PointerShared {
    /// Sets the finger position (metres, scene frame); NaN lifts the finger away.
    pub fn set_position(&self, p: DVec3) {
        for (a, v) in self.xyz.iter().zip(p.to_array()) {
            a.store(v.to_bits(), Ordering::Relaxed);
        }
    }
    /// The finger position last set.
    pub fn position(&self) -> DVec3 {
        DVec3::from_array(
            self.xyz
                .each_ref()
                .map(|a| f64::from_bits(a.load(Ordering::Relaxed))),
        )
    }
    /// The force the haptic loop last sent, N.
    pub fn force(&self) -> DVec3 {
        DVec3::from_array(
            self.force
                .each_ref()
                .map(|a| f64::from_bits(a.load(Ordering::Relaxed))),
        )
    }
}

/// The haptic loop's end of the pointer.
#[derive(Clone, Debug, Default)]
pub struct PointerDevice(pub Arc<PointerShared>);

impl HapticDevice for PointerDevice {
    fn position(&mut self, _t: f64) -> DVec3 {
        // NaN while lifted: zero force. A finger that reappears inside the object is treated
        // as one that starts inside (see `runtime`).
        self.0.position()
    }
    fn set_force(&mut self, f: DVec3) {
        for (a, v) in self.0.force.iter().zip(f.to_array()) {
            a.store(v.to_bits(), Ordering::Relaxed);
        }
    }
}
