//! How a device's workspace maps into a scene (the Haply finger's `haply` table): the device's
//! axes are the scene's (no rotation); its points are scaled about a centre and moved,
//!
//! ```text
//! scene point  = scene_centre + scale · (device point − device_centre)
//! device force = scene force
//! ```
//!
//! The scale changes lengths only: a force is the same vector in both frames (the transposed
//! rotation, here the identity, maps it back), so the force the hand feels is the force the
//! object pushes the finger with. A scale above 1 makes the object feel softer by that factor
//! (the hand moves `1/scale` as far for the same press).

use glam::DVec3;

/// A device workspace's place in the scene (SI: metres in both frames).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Workspace {
    /// The device point (device frame, m) that maps to `scene_centre`.
    pub device_centre: DVec3,
    /// Where `device_centre` lands in the scene (scene frame, m).
    pub scene_centre: DVec3,
    /// Scene metres per device metre (finite, positive).
    pub scale: f64,
}

/// The default `device_centre`, m: in front of an Inverse3's base, at handle height (the
/// contract's example; the device's origin is on its base, +Y forward, +Z up).
pub const DEFAULT_DEVICE_CENTRE: [f64; 3] = [0.0, -0.12, 0.15];

impl Workspace {
    /// The scene point of a device point. A non-finite input gives a non-finite output (the
    /// finger then has no valid reading).
    #[inline]
    pub fn to_scene(&self, device: DVec3) -> DVec3 {
        self.scene_centre + self.scale * (device - self.device_centre)
    }

    /// The device point of a scene point (the inverse of [`Workspace::to_scene`]).
    #[inline]
    pub fn to_device(&self, scene: DVec3) -> DVec3 {
        self.device_centre + (scene - self.scene_centre) / self.scale
    }

    /// The force to send the device for a force in the scene's frame: the same vector (no
    /// rotation; the scale maps positions only).
    #[inline]
    pub fn force_to_device(&self, scene: DVec3) -> DVec3 {
        scene
    }
}

#[cfg(any(test, feature = "self-check"))]
pub(crate) mod tests {
    use super::*;

    #[cfg_attr(test, test)]
    pub(crate) fn points_map_both_ways_and_forces_are_unchanged() {
        let w = Workspace {
            device_centre: DVec3::from_array(DEFAULT_DEVICE_CENTRE),
            scene_centre: DVec3::new(0.015, 0.015, 0.030),
            scale: 0.5,
        };
        let d = DVec3::new(0.01, -0.13, 0.14);
        let s = w.to_scene(d);
        assert!(
            (s - DVec3::new(0.020, 0.010, 0.025)).length() < 1e-15,
            "{s}"
        );
        assert!((w.to_device(s) - d).length() < 1e-15);
        assert_eq!(w.force_to_device(DVec3::X), DVec3::X);
        assert!(!w.to_scene(DVec3::NAN).is_finite());
    }
}
