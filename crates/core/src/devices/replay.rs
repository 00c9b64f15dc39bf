//! A device that plays back recorded finger positions, tick by tick.

use glam::DVec3;

use super::HapticDevice;

/// Plays back one finger's recorded positions, one per call to `position` (the tick's time is
/// ignored: replay is tick-exact, not time-exact). After the last one it repeats it.
#[derive(Clone, Debug)]
pub struct ReplayDevice {
    positions: Vec<DVec3>,
    next: usize,
    /// The forces sent, one per tick.
    pub forces: Vec<DVec3>,
}

impl ReplayDevice {
    /// A device replaying `positions` (one per tick).
    pub fn new(positions: Vec<DVec3>) -> ReplayDevice {
        let n = positions.len();
        ReplayDevice {
            positions,
            next: 0,
            forces: Vec::with_capacity(n),
        }
    }
}

impl HapticDevice for ReplayDevice {
    fn position(&mut self, _t: f64) -> DVec3 {
        let i = self.next.min(self.positions.len().saturating_sub(1));
        self.next += 1;
        self.positions.get(i).copied().unwrap_or(DVec3::NAN)
    }
    fn set_force(&mut self, f: DVec3) {
        if self.forces.len() < self.forces.capacity() {
            self.forces.push(f);
        }
    }
}
