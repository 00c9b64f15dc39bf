//! The force bound: the last stage of every finger's force, after the model, the ramp and the
//! device's coupling, on every path (`demo`, `view`, `serve`, `replay`).
//!
//! What a device receives, per finger, every tick:
//! 1. **finite**, else zero;
//! 2. **rate-limited** in measured time: the force vector changes by at most
//!    `bound / RISE_S` newtons per second (the whole bound in [`RISE_S`]), so a one-tick
//!    position glitch into the object cannot give a step; a release to exactly zero (no
//!    contact, no valid position) is never delayed;
//! 3. **held to the continuous force** where the device states one: while the force's root
//!    mean square over `CONTINUOUS_TAU_S` exceeds `max_continuous_force_n`, the bound is that
//!    force (a motor's I²t rule);
//! 4. **at most the bound** `min(scene max_force_n, device max_force_n)` — this holds whatever
//!    came before, and is checked last.

use glam::DVec3;

use crate::devices::limits::DeviceLimits;

/// Seconds in which the force may rise from zero to the whole bound.
pub const RISE_S: f64 = 0.02;
/// Time constant (s) of the root-mean-square force held to a device's continuous force.
pub(crate) const CONTINUOUS_TAU_S: f64 = 1.0;

/// One finger's force bound and its state (see the module docs). Allocates nothing.
#[derive(Clone, Copy, Debug)]
pub(crate) struct ForceBound {
    bound: f64,
    continuous: Option<f64>,
    last: DVec3,
    mean_square: f64,
    holding: bool,
}

impl ForceBound {
    /// The bound of a finger in a scene whose `[haptics] max_force_n` is `scene_max_n`, with
    /// its device's `limits` if any. A bound that is not finite and positive is zero: such a
    /// finger is sent no force.
    pub fn new(scene_max_n: f64, limits: Option<&DeviceLimits>) -> ForceBound {
        let device = limits.map_or(f64::INFINITY, |l| l.max_force_n);
        let bound = scene_max_n.min(device);
        ForceBound {
            bound: if bound.is_finite() && bound > 0.0 {
                bound
            } else {
                0.0
            },
            continuous: limits
                .and_then(|l| l.max_continuous_force_n)
                .filter(|c| c.is_finite() && *c > 0.0),
            last: DVec3::ZERO,
            mean_square: 0.0,
            holding: false,
        }
    }

    /// The bound, N: the smaller of the scene's and the device's peak force.
    pub fn bound(&self) -> f64 {
        self.bound
    }

    /// Forgets the last force: the next one rises from zero.
    pub fn reset(&mut self) {
        self.last = DVec3::ZERO;
    }

    /// The force to send for the wanted force `want`, `dt` seconds (measured) after the last
    /// call. Always finite with `|F| ≤ bound`. Returns the force and whether the bound
    /// changed it by more than 1 % (or 1 µN).
    pub fn apply(&mut self, want: DVec3, dt: f64) -> (DVec3, bool) {
        let dt = if dt.is_finite() { dt.max(0.0) } else { 0.0 };
        let want_ok = if want.is_finite() { want } else { DVec3::ZERO };
        // The continuous force, as a motor's I²t: the bound drops to it once the mean square
        // over the last CONTINUOUS_TAU_S exceeds it, until that falls 10 % below.
        let mut cap = self.bound;
        if let Some(c) = self.continuous {
            if self.mean_square > c * c {
                self.holding = true;
            } else if self.mean_square < 0.81 * c * c {
                self.holding = false;
            }
            if self.holding {
                cap = cap.min(c);
            }
        }
        let target = want_ok.clamp_length_max(cap);
        let out = if target == DVec3::ZERO {
            DVec3::ZERO
        } else {
            let step = (self.bound / RISE_S) * dt;
            self.last + (target - self.last).clamp_length_max(step)
        };
        // Applied last: whatever the stages above did, the bound holds.
        let out = if out.is_finite() {
            out.clamp_length_max(cap)
        } else {
            DVec3::ZERO
        };
        if self.continuous.is_some() {
            let a = (dt / CONTINUOUS_TAU_S).min(1.0);
            self.mean_square += (out.length_squared() - self.mean_square) * a;
        }
        self.last = out;
        let limited = (out - want).length() > 0.01 * want.length() + 1e-6 || !want.is_finite();
        (out, limited)
    }
}

#[cfg(any(test, feature = "self-check"))]
pub(crate) mod tests {
    use super::*;

    fn falcon() -> DeviceLimits {
        DeviceLimits::preset("falcon").unwrap()
    }

    #[cfg_attr(test, test)]
    pub(crate) fn the_bound_is_the_smaller_of_the_scene_and_the_device() {
        assert_eq!(ForceBound::new(0.1, Some(&falcon())).bound(), 0.1);
        assert_eq!(ForceBound::new(20.0, Some(&falcon())).bound(), 8.0);
        assert_eq!(ForceBound::new(3.0, None).bound(), 3.0);
        assert_eq!(ForceBound::new(f64::NAN, None).bound(), 0.0);
        assert_eq!(ForceBound::new(-1.0, None).bound(), 0.0);
    }

    #[cfg_attr(test, test)]
    pub(crate) fn any_input_gives_a_finite_force_within_the_bound() {
        let mut b = ForceBound::new(0.1, Some(&falcon()));
        let wants = [
            DVec3::new(5.0, 0.0, 0.0),
            DVec3::new(f64::NAN, 1.0, 0.0),
            DVec3::splat(f64::INFINITY),
            DVec3::new(0.0, -1e300, 0.0),
            DVec3::new(0.05, 0.0, 0.0),
        ];
        for k in 0..2000 {
            let dt = [1e-3, 0.0, 1e9, f64::NAN, -1.0][k % 5];
            let (f, _) = b.apply(wants[(k / 5) % wants.len()], dt);
            assert!(f.is_finite() && f.length() <= 0.1, "{f:?}");
        }
    }

    #[cfg_attr(test, test)]
    pub(crate) fn the_force_rises_at_the_rate_in_measured_time() {
        // 1 N bound: 50 N/s. A step to 1 N reaches 0.05 N after 1 ms, whether that
        // millisecond is one tick or eight.
        let want = DVec3::new(0.0, 0.0, 1.0);
        let mut one = ForceBound::new(1.0, None);
        let (f, limited) = one.apply(want, 1e-3);
        assert!((f.z - 0.05).abs() < 1e-12 && limited);
        let mut eight = ForceBound::new(1.0, None);
        let mut f = DVec3::ZERO;
        for _ in 0..8 {
            f = eight.apply(want, 1.25e-4).0;
        }
        assert!((f.z - 0.05).abs() < 1e-12, "{f:?}");
        // After RISE_S the whole force is there, and a release to zero is immediate.
        for _ in 0..19 {
            f = one.apply(want, 1e-3).0;
        }
        assert!((f.z - 1.0).abs() < 1e-12);
        assert_eq!(one.apply(DVec3::ZERO, 1e-3).0, DVec3::ZERO);
    }

    #[cfg_attr(test, test)]
    pub(crate) fn a_held_force_falls_to_the_continuous_force() {
        let mut l = falcon();
        l.max_continuous_force_n = Some(2.0);
        let mut b = ForceBound::new(8.5, Some(&l));
        let want = DVec3::new(3.0, 0.0, 0.0);
        let mut first_second_max: f64 = 0.0;
        let mut f = DVec3::ZERO;
        for k in 0..5000 {
            f = b.apply(want, 1e-3).0;
            if k < 300 {
                first_second_max = first_second_max.max(f.length());
            }
        }
        // The peak is allowed for a while, then the continuous force holds.
        assert!((first_second_max - 3.0).abs() < 1e-9);
        assert!((f.length() - 2.0).abs() < 1e-9, "{f:?}");
    }
}
