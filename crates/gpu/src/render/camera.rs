//! The cameras: the fixed 3/4 view ([`Camera::framing`], [`Camera::fit`]), a view of the
//! touched point from outside ([`Camera::contact`]), an orbit/zoom camera ([`Orbit`]), and the
//! ray through a pixel ([`Camera::ray`]) for picking.

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

/// The whole image less a 5 % margin, in normalised device coordinates `[x0, x1, y0, y1]`:
/// the region [`Camera::framing`] fills.
pub(crate) const FULL_FRAME: [f64; 4] = [-0.95, 0.95, -0.95, 0.95];

impl Camera {
    /// Frames the axis-aligned box `[min, max]` (e.g. the rest bounding box) from [`VIEW_DIR`]:
    /// its eight corners fill the image at `aspect` (width/height) up to a 5 % margin
    /// ([`fit`](Self::fit) over `FULL_FRAME`).
    pub fn framing(min: DVec3, max: DVec3, aspect: f64) -> Camera {
        let corners: Vec<DVec3> = (0..8)
            .map(|i| {
                DVec3::new(
                    if i & 1 == 0 { min.x } else { max.x },
                    if i & 2 == 0 { min.y } else { max.y },
                    if i & 4 == 0 { min.z } else { max.z },
                )
            })
            .collect();
        Camera::fit(&corners, VIEW_DIR, aspect, FULL_FRAME)
    }

    /// Looks along `dir` (from the points towards the eye; z up, or y up when `dir` is nearly
    /// vertical) so that the projections of `points` fill `region` = `[x0, x1, y0, y1]` in
    /// normalised device coordinates (−1..1, y up): their extent is centred in it and spans
    /// its width or its height. A 30° vertical field of view; the clip planes enclose the
    /// points. Non-finite points are ignored; no finite point gives a unit view of the origin.
    pub fn fit(points: &[DVec3], dir: DVec3, aspect: f64, region: [f64; 4]) -> Camera {
        let fov_y_deg: f64 = 30.0;
        let dir = if dir.length() > 0.0 && dir.is_finite() {
            dir.normalize()
        } else {
            VIEW_DIR.normalize()
        };
        let up = if dir.z.abs() > 0.99 {
            DVec3::Y
        } else {
            DVec3::Z
        };
        let pts: Vec<DVec3> = points.iter().copied().filter(|p| p.is_finite()).collect();
        let (lo, hi) = pts.iter().fold(
            (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
            |(lo, hi), p| (lo.min(*p), hi.max(*p)),
        );
        if pts.is_empty() {
            return Camera {
                eye: dir,
                target: DVec3::ZERO,
                up,
                fov_y_deg,
                near: 0.01,
                far: 10.0,
            };
        }
        let aspect = if aspect.is_finite() && aspect > 0.0 {
            aspect
        } else {
            1.0
        };
        let ty = (0.5 * fov_y_deg).to_radians().tan();
        let tx = ty * aspect;
        let f = -dir;
        let right = f.cross(up).normalize();
        let cam_up = right.cross(f);
        let [x0, x1, y0, y1] = region;
        let (hx, hy) = (
            0.5 * (x1 - x0).abs().max(1e-3),
            0.5 * (y1 - y0).abs().max(1e-3),
        );
        let (cx, cy) = (0.5 * (x0 + x1), 0.5 * (y0 + y1));
        let radius = (0.5 * (hi - lo).length()).max(1e-9);
        let mut target = 0.5 * (lo + hi);
        let mut d = radius / (ty.atan().min(tx.atan())).sin();
        // Alternate: scale the distance so the extent spans the region, then shift the target
        // so the extent is centred in it (converges in a few rounds for any point cloud).
        for _ in 0..8 {
            let eye = target + dir * d;
            let (mut ax, mut bx, mut ay, mut by) = (f64::MAX, f64::MIN, f64::MAX, f64::MIN);
            let mut min_depth = f64::MAX;
            for p in &pts {
                let v = *p - eye;
                let z = v.dot(f).max(1e-6 * d);
                min_depth = min_depth.min(v.dot(f));
                let (nx, ny) = (v.dot(right) / (z * tx), v.dot(cam_up) / (z * ty));
                ax = ax.min(nx);
                bx = bx.max(nx);
                ay = ay.min(ny);
                by = by.max(ny);
            }
            let ratio = ((bx - ax) / (2.0 * hx)).max((by - ay) / (2.0 * hy));
            if min_depth <= 0.0 {
                // A point behind the eye: step back.
                d *= 2.0;
                continue;
            }
            target += right * ((0.5 * (ax + bx) - cx) * tx * d)
                + cam_up * ((0.5 * (ay + by) - cy) * ty * d);
            if ratio.is_finite() && ratio > 0.0 {
                // Keep the nearest point in front of the eye.
                d = (d * ratio).max(d - min_depth + 0.05 * radius);
            }
        }
        let eye = target + dir * d;
        let (near, far) = pts.iter().fold((f64::MAX, 0.0f64), |(n, fa), p| {
            let z = (*p - eye).dot(f);
            (n.min(z), fa.max(z))
        });
        Camera {
            eye,
            target,
            up,
            fov_y_deg,
            near: (near - 0.5 * radius).max(0.02 * d).max(1e-9),
            far: far + 0.5 * radius + 1e-9,
        }
    }

    /// Looks at a touched `point` (m) from outside the surface, whose outward unit normal there
    /// is `normal`: the eye is on the normal's side, tilted 55° towards [`VIEW_DIR`] so that a
    /// dent shows its depth, and `points` (e.g. the surface within some radius of the touch,
    /// the finger, the arrow's tip) fill `region` as in [`fit`](Self::fit).
    pub fn contact(
        point: DVec3,
        normal: DVec3,
        points: &[DVec3],
        aspect: f64,
        region: [f64; 4],
    ) -> Camera {
        let n = if normal.is_finite() && normal.length() > 0.0 {
            normal.normalize()
        } else {
            VIEW_DIR.normalize()
        };
        let v = VIEW_DIR.normalize();
        let mut t = v - n * v.dot(n);
        if t.length() < 1e-6 {
            t = n.any_orthonormal_vector();
        }
        let dir = n * 55f64.to_radians().cos() + t.normalize() * 55f64.to_radians().sin();
        let mut all: Vec<DVec3> = points.to_vec();
        all.push(point);
        Camera::fit(&all, dir, aspect, region)
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
    pub(crate) fn light_dir(&self) -> Vec3 {
        Vec3::new(-0.3, -0.6, 1.0).normalize()
    }
}

impl Camera {
    /// The unit forward direction (eye → target).
    pub fn forward(&self) -> DVec3 {
        (self.target - self.eye).normalize()
    }

    /// The ray through window position `pixel` (x right, y down, in pixels, `(0, 0)` the
    /// top-left corner of the top-left pixel) of a `size` (width, height) image: the eye and the
    /// unit direction. The inverse of [`project`](Self::project).
    pub fn ray(&self, pixel: [f64; 2], size: [u32; 2]) -> (DVec3, DVec3) {
        let (w, h) = (f64::from(size[0].max(1)), f64::from(size[1].max(1)));
        let aspect = w / h;
        let f = self.forward();
        let right = f.cross(self.up).normalize();
        let up = right.cross(f);
        let t = (0.5 * self.fov_y_deg).to_radians().tan();
        let ndc_x = 2.0 * pixel[0] / w - 1.0;
        let ndc_y = 1.0 - 2.0 * pixel[1] / h;
        let d = f + right * (ndc_x * t * aspect) + up * (ndc_y * t);
        (self.eye, d.normalize())
    }

    /// Where the point `p` (m) appears in a `size` image, in the pixel coordinates of
    /// `ray`; `None` behind the eye.
    pub fn project(&self, p: DVec3, size: [u32; 2]) -> Option<[f64; 2]> {
        let (w, h) = (f64::from(size[0].max(1)), f64::from(size[1].max(1)));
        let f = self.forward();
        let right = f.cross(self.up).normalize();
        let up = right.cross(f);
        let v = p - self.eye;
        let z = v.dot(f);
        if z <= 0.0 {
            return None;
        }
        let t = (0.5 * self.fov_y_deg).to_radians().tan();
        let ndc_x = v.dot(right) / (z * t * (w / h));
        let ndc_y = v.dot(up) / (z * t);
        Some([0.5 * (ndc_x + 1.0) * w, 0.5 * (1.0 - ndc_y) * h])
    }

    /// The camera of an [`Orbit`].
    pub fn orbit(orbit: &Orbit) -> Camera {
        let dir = orbit.direction();
        let d = orbit.distance;
        let r = orbit.radius.max(1e-9);
        Camera {
            eye: orbit.target + dir * d,
            target: orbit.target,
            up: DVec3::Z,
            fov_y_deg: orbit.fov_y_deg,
            near: (d - 2.0 * r).max(0.01 * d),
            far: d + 4.0 * r,
        }
    }
}

/// An orbit/zoom camera: the eye on a sphere around `target`, z up. Turn it with
/// [`rotate`](Self::rotate) (a right drag), move it in and out with [`zoom`](Self::zoom) (the
/// wheel), and get the [`Camera`] with [`camera`](Self::camera).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Orbit {
    /// The point orbited (m).
    pub target: DVec3,
    /// Azimuth of the eye around +z from +x, radians.
    pub yaw: f64,
    /// Elevation of the eye above the xy plane, radians (kept within ±`Orbit::MAX_PITCH`).
    pub pitch: f64,
    /// Eye-to-target distance (m).
    pub distance: f64,
    /// Radius of the scene's bounding sphere (m): sets the clip planes and the zoom range.
    pub radius: f64,
    /// Vertical field of view, degrees.
    pub fov_y_deg: f64,
}

impl Orbit {
    /// Largest |pitch|, radians (just short of the poles, where z-up is undefined).
    pub(crate) const MAX_PITCH: f64 = 1.55;
    /// Radians turned per pixel dragged.
    pub(crate) const RADIANS_PER_PIXEL: f64 = 0.008;

    /// The view of [`Camera::framing`]: from [`VIEW_DIR`], the box's corners filling the image
    /// at `aspect` up to a 5 % margin.
    pub fn framing(min: DVec3, max: DVec3, aspect: f64) -> Orbit {
        let c = Camera::framing(min, max, aspect);
        let v = c.eye - c.target;
        let distance = v.length();
        Orbit {
            target: c.target,
            yaw: v.y.atan2(v.x),
            pitch: (v.z / distance).asin(),
            distance,
            radius: (0.5 * (max - min).length()).max(1e-9),
            fov_y_deg: c.fov_y_deg,
        }
    }

    /// Unit direction from the target towards the eye.
    pub fn direction(&self) -> DVec3 {
        let (sy, cy) = self.yaw.sin_cos();
        let (sp, cp) = self.pitch.sin_cos();
        DVec3::new(cp * cy, cp * sy, sp)
    }

    /// Turns by a drag of (`dx`, `dy`) pixels: right drags the scene right (the eye goes left
    /// around +z), down tilts the eye up.
    pub fn rotate(&mut self, dx: f64, dy: f64) {
        self.yaw -= dx * Self::RADIANS_PER_PIXEL;
        self.pitch =
            (self.pitch + dy * Self::RADIANS_PER_PIXEL).clamp(-Self::MAX_PITCH, Self::MAX_PITCH);
    }

    /// Zooms by `steps` wheel notches (positive: closer), 10 % each, keeping the eye between
    /// 0.6 and 40 scene radii from the target.
    pub fn zoom(&mut self, steps: f64) {
        let r = self.radius.max(1e-9);
        self.distance = (self.distance * 0.9f64.powf(steps)).clamp(0.6 * r, 40.0 * r);
    }

    /// The camera.
    pub fn camera(&self) -> Camera {
        Camera::orbit(self)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The orbit's framing is the fixed 3/4 view; rotating keeps the distance and target,
    /// clamps the pitch, and zooming moves the eye along the view direction within bounds.
    #[test]
    fn orbit_camera() {
        let (lo, hi) = (DVec3::ZERO, DVec3::splat(0.03));
        let fixed = Camera::framing(lo, hi, 4.0 / 3.0);
        let mut o = Orbit::framing(lo, hi, 4.0 / 3.0);
        let c = o.camera();
        assert!(
            c.eye.distance(fixed.eye) < 1e-12,
            "{} vs {}",
            c.eye,
            fixed.eye
        );
        assert_eq!(c.target, fixed.target);
        assert!(c.near > 0.0 && c.near < c.far);
        o.rotate(100.0, 0.0);
        let r = o.camera();
        assert!(((r.eye - r.target).length() - o.distance).abs() < 1e-12);
        assert!((r.eye.z - c.eye.z).abs() < 1e-12, "yaw keeps the height");
        assert!(r.eye.distance(c.eye) > 0.01);
        o.rotate(0.0, 1e6);
        assert_eq!(o.pitch, Orbit::MAX_PITCH);
        o.rotate(0.0, -1e6);
        assert_eq!(o.pitch, -Orbit::MAX_PITCH);
        let d = o.distance;
        o.zoom(1.0);
        assert!((o.distance - 0.9 * d).abs() < 1e-12);
        o.zoom(1000.0);
        assert!((o.distance - 0.6 * o.radius).abs() < 1e-12);
        assert!(o.camera().near > 0.0);
        o.zoom(-1000.0);
        assert!((o.distance - 40.0 * o.radius).abs() < 1e-12);
    }
}
