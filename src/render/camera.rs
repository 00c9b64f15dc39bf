//! The fixed 3/4 view camera.

use glam::camera::rh::{proj::directx::perspective, view::look_at_mat4};
use glam::{DVec3, Mat4, Vec3};

/// A perspective camera, z up.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Camera {
    /// Eye position (m).
    pub eye: DVec3,
    /// Point looked at (m).
    pub target: DVec3,
    /// Up direction.
    pub up: DVec3,
    /// Vertical field of view, degrees.
    pub fov_y_deg: f64,
    /// Near and far clip distances (m).
    pub near: f64,
    /// Far clip distance (m).
    pub far: f64,
}

/// Direction from the object's centre towards the eye: from −x, −y and above, so that the top,
/// the y = min face and the x = min face are all visible.
pub const VIEW_DIR: DVec3 = DVec3::new(-0.75, -1.25, 0.95);

impl Camera {
    /// Frames the axis-aligned box `[min, max]` (e.g. the rest bounding box) from [`VIEW_DIR`]:
    /// the box's bounding sphere, with a 10 % margin, fits the image at `aspect` (width/height).
    pub fn framing(min: DVec3, max: DVec3, aspect: f64) -> Camera {
        let target = 0.5 * (min + max);
        let radius = (0.5 * (max - min).length()).max(1e-9);
        let fov_y_deg: f64 = 30.0;
        let half_y = (0.5 * fov_y_deg).to_radians();
        let half_x = (half_y.tan() * aspect).atan();
        let dist = 1.1 * radius / half_y.min(half_x).sin();
        Camera {
            eye: target + VIEW_DIR.normalize() * dist,
            target,
            up: DVec3::Z,
            fov_y_deg,
            near: (dist - 2.0 * radius).max(0.05 * dist),
            far: dist + 4.0 * radius,
        }
    }

    /// The view-projection matrix (right-handed, depth 0..1 as wgpu expects).
    pub fn view_proj(&self, aspect: f64) -> Mat4 {
        let view = look_at_mat4(self.eye.as_vec3(), self.target.as_vec3(), self.up.as_vec3());
        // Depth 0..1, y up: wgpu's clip space (the "directx" convention).
        let proj = perspective(
            self.fov_y_deg.to_radians() as f32,
            aspect as f32,
            self.near as f32,
            self.far as f32,
        );
        proj * view
    }

    /// Unit direction towards the key light: above, slightly towards the viewer's left.
    pub fn light_dir(&self) -> Vec3 {
        Vec3::new(-0.3, -0.6, 1.0).normalize()
    }
}
