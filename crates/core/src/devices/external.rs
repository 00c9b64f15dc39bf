//! A finger whose device is driven by someone else's thread — a network client the program
//! runs (the Haply Inverse Service's WebSocket client in `touchfem-app`), a vendor callback —
//! exchanging positions and forces with the haptic loop through memory only.
//!
//! [`external_link`] makes the two ends of one finger's link:
//! * [`ExternalFinger`], the haptic loop's end (a [`HapticDevice`]; several make
//!   [`ExternalFingers`], a [`FingerDevices`]). Each tick it reads the newest reading and
//!   writes its force, each through a wait-free triple buffer: it allocates nothing, takes no
//!   lock and never waits for the other thread.
//! * [`ExternalPort`], the device thread's end: it publishes each reading (already in the
//!   scene's frame, with the time it arrived) or lifts the finger, and reads the newest force
//!   with its age and whether service has ended.
//!
//! The rules of the UDP bridge hold on this path: a reading older than the watchdog, or none,
//! is no valid position (the finger lifts: zero force, the contact released, and a later
//! press is ramped in afresh); the force the loop writes is already bounded (the force
//! bound is the haptic world's last stage); when the loop ends, every finger is released
//! ([`FingerDevices::release`]: a zero force marked released) and the device thread sends its
//! device a last zero force. No network, clock source or thread lives here.

use glam::DVec3;
use std::time::{Duration, Instant};

use super::{FingerDevices, ForceState, HapticDevice};

/// One reading of the device: where the finger is (scene frame, metres) and when the reading
/// arrived.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Reading {
    /// The finger's position, scene frame, m.
    pub position: DVec3,
    /// When it arrived.
    pub at: Instant,
}

/// The newest force the haptic loop wrote for one finger.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ForceSample {
    /// The force, N, scene frame (bounded; zero when not touching or released).
    pub force: DVec3,
    /// When it was written (`None`: never).
    pub at: Option<Instant>,
    /// Whether the finger touches an object.
    pub touching: bool,
    /// Whether service has ended: the force is zero and no other follows.
    pub released: bool,
}

impl ForceSample {
    /// The force to send now: the written one while it is younger than `max_age` and service
    /// goes on, else zero (a loop that stopped writing never leaves a force on the device).
    pub fn fresh_force(&self, now: Instant, max_age: Duration) -> DVec3 {
        match self.at {
            Some(at) if !self.released && now.saturating_duration_since(at) <= max_age => {
                self.force
            }
            _ => DVec3::ZERO,
        }
    }
}

/// The haptic loop's end of one finger's link (see the module docs).
pub struct ExternalFinger {
    readings: triple_buffer::Output<Option<Reading>>,
    forces: triple_buffer::Input<ForceSample>,
    watchdog: Duration,
}

impl std::fmt::Debug for ExternalFinger {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ExternalFinger")
            .field("watchdog", &self.watchdog)
            .finish_non_exhaustive()
    }
}

/// The device thread's end of one finger's link (see the module docs).
pub struct ExternalPort {
    readings: triple_buffer::Input<Option<Reading>>,
    forces: triple_buffer::Output<ForceSample>,
}

impl std::fmt::Debug for ExternalPort {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("ExternalPort").finish_non_exhaustive()
    }
}

/// The two ends of one finger's link; a reading older than `watchdog` is no valid position.
pub fn external_link(watchdog: Duration) -> (ExternalFinger, ExternalPort) {
    let (r_in, r_out) = triple_buffer::triple_buffer(&None);
    let (f_in, f_out) = triple_buffer::triple_buffer(&ForceSample::default());
    (
        ExternalFinger {
            readings: r_out,
            forces: f_in,
            watchdog,
        },
        ExternalPort {
            readings: r_in,
            forces: f_out,
        },
    )
}

impl ExternalFinger {
    /// The position for a tick at `now`: the newest reading if it is finite and no older than
    /// the watchdog, else NaN (no valid reading).
    fn position_at(&mut self, now: Instant) -> DVec3 {
        match *self.readings.read() {
            Some(r)
                if r.position.is_finite()
                    && now.saturating_duration_since(r.at) <= self.watchdog =>
            {
                r.position
            }
            _ => DVec3::NAN,
        }
    }

    fn send(&mut self, force: DVec3, touching: bool, released: bool, at: Instant) {
        let force = if force.is_finite() && !released {
            force
        } else {
            DVec3::ZERO
        };
        self.forces.write(ForceSample {
            force,
            at: Some(at),
            touching,
            released,
        });
    }
}

impl HapticDevice for ExternalFinger {
    fn position(&mut self, _t: f64) -> DVec3 {
        self.position_at(Instant::now())
    }
    fn set_force(&mut self, f: DVec3) {
        self.send(f, false, false, Instant::now());
    }
}

impl ExternalPort {
    /// Publishes a reading (the finger's position in the scene's frame, and when it arrived).
    pub fn publish(&mut self, position: DVec3, at: Instant) {
        self.readings.write(Some(Reading { position, at }));
    }

    /// No valid reading from now on (the device disconnected): the finger lifts at the next
    /// tick, without waiting for the watchdog.
    pub fn lift(&mut self) {
        self.readings.write(None);
    }

    /// The newest force the haptic loop wrote.
    pub fn force(&mut self) -> ForceSample {
        *self.forces.read()
    }
}

/// Every finger of a scene driven through [`ExternalFinger`]s: the haptic loop's devices.
#[derive(Debug, Default)]
pub struct ExternalFingers(pub Vec<ExternalFinger>);

impl FingerDevices for ExternalFingers {
    fn read(&mut self, _t: f64, out: &mut [DVec3]) {
        let now = Instant::now();
        for (p, d) in out.iter_mut().zip(self.0.iter_mut()) {
            *p = d.position_at(now);
        }
    }
    fn write(&mut self, forces: &[DVec3], state: &[ForceState]) {
        let now = Instant::now();
        for (i, (f, d)) in forces.iter().zip(self.0.iter_mut()).enumerate() {
            let touching = state.get(i).is_some_and(|s| s.touching);
            d.send(*f, touching, false, now);
        }
    }
    fn release(&mut self) {
        let now = Instant::now();
        for d in &mut self.0 {
            d.send(DVec3::ZERO, false, true, now);
        }
    }
}

#[cfg(any(test, feature = "self-check"))]
pub(crate) mod tests {
    use super::*;

    #[cfg_attr(test, test)]
    pub(crate) fn readings_age_out_forces_flow_and_release_is_final() {
        let (finger, mut port) = external_link(Duration::from_millis(20));
        let mut fingers = ExternalFingers(vec![finger]);
        let mut p = [DVec3::ZERO];
        fingers.read(0.0, &mut p);
        assert!(!p[0].is_finite(), "no reading yet");
        let t0 = Instant::now();
        port.publish(DVec3::new(0.01, 0.02, 0.03), t0);
        fingers.read(0.0, &mut p);
        assert_eq!(p[0], DVec3::new(0.01, 0.02, 0.03));
        // The same reading 30 ms later is stale.
        let late = fingers.0[0].position_at(t0 + Duration::from_millis(30));
        assert!(!late.is_finite());
        port.publish(DVec3::new(0.01, 0.02, f64::INFINITY), Instant::now());
        fingers.read(0.0, &mut p);
        assert!(!p[0].is_finite(), "a non-finite reading is no reading");
        port.publish(DVec3::X, Instant::now());
        port.lift();
        fingers.read(0.0, &mut p);
        assert!(!p[0].is_finite(), "lifted");

        assert_eq!(port.force(), ForceSample::default());
        let st = [ForceState {
            touching: true,
            limited: false,
        }];
        fingers.write(&[DVec3::new(0.0, 0.0, 1.5)], &st);
        let s = port.force();
        let now = Instant::now();
        assert_eq!(s.fresh_force(now, Duration::from_millis(20)).z, 1.5);
        assert!(s.touching && !s.released);
        let old = now + Duration::from_millis(50);
        assert_eq!(s.fresh_force(old, Duration::from_millis(20)), DVec3::ZERO);
        fingers.write(&[DVec3::NAN], &st);
        assert_eq!(port.force().force, DVec3::ZERO, "non-finite → zero");
        fingers.release();
        let s = port.force();
        assert!(s.released && s.force == DVec3::ZERO);
        assert_eq!(s.fresh_force(Instant::now(), Duration::MAX), DVec3::ZERO);
    }
}
