//! Scripted devices: a closure of time, or keyframes interpolated linearly.

use glam::DVec3;

use super::HapticDevice;

/// A device that follows a scripted path (for the demo, tests and benchmarks).
pub struct ScriptedDevice<F: FnMut(f64) -> DVec3 + Send> {
    path: F,
    /// The last force sent, N.
    pub last_force: DVec3,
    /// The largest force magnitude sent, N.
    pub max_force: f64,
}

impl<F: FnMut(f64) -> DVec3 + Send> ScriptedDevice<F> {
    /// A device whose finger is at `path(t)`.
    pub fn new(path: F) -> Self {
        ScriptedDevice {
            path,
            last_force: DVec3::ZERO,
            max_force: 0.0,
        }
    }
}

impl<F: FnMut(f64) -> DVec3 + Send> HapticDevice for ScriptedDevice<F> {
    fn position(&mut self, t: f64) -> DVec3 {
        (self.path)(t)
    }
    fn set_force(&mut self, f: DVec3) {
        self.last_force = f;
        self.max_force = self.max_force.max(f.length());
    }
}

/// Keyframes `(t, position)` with strictly increasing times, interpolated linearly and held
/// constant before the first and after the last (a scene file's `path`). Metres, seconds.
#[derive(Clone, Debug, PartialEq)]
pub struct KeyframePath {
    keys: Vec<(f64, DVec3)>,
    /// Index of the segment found last (the search starts there: O(1) per tick).
    cursor: usize,
}

impl KeyframePath {
    /// A path through `keys`; `None` when empty, times not strictly increasing, or not finite.
    pub fn new(keys: Vec<(f64, DVec3)>) -> Option<KeyframePath> {
        let ok = !keys.is_empty()
            && keys.iter().all(|(t, p)| t.is_finite() && p.is_finite())
            && keys.windows(2).all(|w| w[1].0 > w[0].0);
        ok.then_some(KeyframePath { keys, cursor: 0 })
    }

    /// The keyframes.
    pub fn keys(&self) -> &[(f64, DVec3)] {
        &self.keys
    }

    /// The time of the last keyframe, s.
    pub fn duration(&self) -> f64 {
        self.keys.last().map_or(0.0, |k| k.0)
    }

    /// The position at `t`. Allocates nothing.
    pub fn at(&mut self, t: f64) -> DVec3 {
        let k = &self.keys;
        if t <= k[0].0 || k.len() == 1 {
            return k[0].1;
        }
        let last = k.len() - 1;
        if t >= k[last].0 {
            return k[last].1;
        }
        if k[self.cursor].0 > t {
            self.cursor = 0;
        }
        while self.cursor + 1 < last && k[self.cursor + 1].0 <= t {
            self.cursor += 1;
        }
        let (t0, p0) = k[self.cursor];
        let (t1, p1) = k[self.cursor + 1];
        p0.lerp(p1, (t - t0) / (t1 - t0))
    }
}

impl HapticDevice for KeyframePath {
    fn position(&mut self, t: f64) -> DVec3 {
        self.at(t)
    }
    fn set_force(&mut self, _f: DVec3) {}
}

#[cfg(any(test, feature = "self-check"))]
pub(crate) mod tests {
    use super::*;

    #[cfg_attr(test, test)]
    pub(crate) fn keyframes_interpolate_and_hold() {
        let mut p = KeyframePath::new(vec![
            (0.0, DVec3::ZERO),
            (1.0, DVec3::new(1.0, 0.0, 0.0)),
            (3.0, DVec3::new(1.0, 2.0, 0.0)),
        ])
        .unwrap();
        assert_eq!(p.at(-1.0), DVec3::ZERO);
        assert_eq!(p.at(0.5), DVec3::new(0.5, 0.0, 0.0));
        assert_eq!(p.at(2.0), DVec3::new(1.0, 1.0, 0.0));
        assert_eq!(p.at(0.25), DVec3::new(0.25, 0.0, 0.0)); // going back in time
        assert_eq!(p.at(9.0), DVec3::new(1.0, 2.0, 0.0));
        assert!(KeyframePath::new(vec![(0.0, DVec3::ZERO), (0.0, DVec3::ONE)]).is_none());
        assert!(KeyframePath::new(vec![]).is_none());
    }
}
