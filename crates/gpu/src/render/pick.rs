//! Picking: the first surface point under a pixel.

use glam::DVec3;

use super::Camera;
use touchfem_core::contact::Surface;

/// What the ray through a pixel hits first.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Hit {
    /// Index of the object hit (in the slice given to [`pick`]).
    pub object: usize,
    /// The triangle hit, in that object's [`Surface::tris`].
    pub triangle: u32,
    /// The point hit, scene frame, metres.
    pub point: DVec3,
    /// The triangle's unit outward normal.
    pub normal: DVec3,
    /// Distance from the eye, metres.
    pub distance: f64,
}

/// The first point of the objects' **rest** surfaces on the ray through window position
/// `pixel` (see `Camera::ray`) of a `size` image. `objects`: each object's rest surface (in
/// its own frame) and its offset in the scene. Uses [`Surface::first_entry`] (front faces
/// only) on the segment from the eye to twice the far plane.
pub fn pick(
    camera: &Camera,
    size: [u32; 2],
    pixel: [f64; 2],
    objects: &[(&Surface, DVec3)],
) -> Option<Hit> {
    let (eye, dir) = camera.ray(pixel, size);
    let reach = 2.0 * camera.far.max((camera.target - camera.eye).length());
    let mut best: Option<Hit> = None;
    for (i, (surface, offset)) in objects.iter().enumerate() {
        let p0 = eye - *offset;
        let Some((t, p)) = surface.first_entry(p0, p0 + dir * reach) else {
            continue;
        };
        let distance = (p - p0).length();
        if best.is_none_or(|b| distance < b.distance) {
            best = Some(Hit {
                object: i,
                triangle: t,
                point: p + *offset,
                normal: surface.normals[t as usize],
                distance,
            });
        }
    }
    best
}

#[cfg(test)]
mod tests {
    use super::*;
    use touchfem_core::mesh::cube;

    /// A ray through the projected centre of the cube's top face hits the top face there,
    /// from the 3/4 view and from an orbited view; an offset object is hit where it sits.
    #[test]
    fn pick_hits_the_top_face_centre() {
        let mesh = cube();
        let surface = Surface::new(&mesh);
        let (lo, hi) = mesh.bounds();
        let size = [640, 480];
        let top = DVec3::new(0.015, 0.015, 0.030);
        let mut orbit = super::super::Orbit::framing(lo, hi, 640.0 / 480.0);
        for camera in [Camera::framing(lo, hi, 640.0 / 480.0), {
            orbit.rotate(120.0, 40.0);
            orbit.camera()
        }] {
            let px = camera.project(top, size).expect("in front");
            let hit = pick(&camera, size, px, &[(&surface, DVec3::ZERO)]).expect("a hit");
            assert_eq!(hit.object, 0);
            assert!(
                hit.point.distance(top) < 1e-9,
                "hit {} not {top}",
                hit.point
            );
            assert!(
                hit.normal.distance(DVec3::Z) < 1e-9,
                "normal {}",
                hit.normal
            );
            assert!((hit.distance - camera.eye.distance(top)).abs() < 1e-9);
            // Well off the cube: nothing.
            assert!(pick(&camera, size, [2.0, 2.0], &[(&surface, DVec3::ZERO)]).is_none());
        }
        // Two cubes, the second 0.1 m along x: the pixel of its top centre picks it.
        let camera = Camera::framing(lo, hi + DVec3::new(0.1, 0.0, 0.0), 640.0 / 480.0);
        let off = DVec3::new(0.1, 0.0, 0.0);
        let px = camera.project(top + off, size).unwrap();
        let objs = [(&surface, DVec3::ZERO), (&surface, off)];
        let hit = pick(&camera, size, px, &objs).expect("a hit");
        assert_eq!(hit.object, 1);
        assert!(hit.point.distance(top + off) < 1e-9);
    }

    /// `ray` and `project` are inverses, and `ray` agrees with the GPU's view-projection.
    #[test]
    fn ray_inverts_project_and_matches_view_proj() {
        let cam = Camera::framing(DVec3::ZERO, DVec3::splat(0.03), 4.0 / 3.0);
        let size = [640, 480];
        let vp = cam.view_proj(4.0 / 3.0);
        for p in [
            DVec3::new(0.01, 0.02, 0.03),
            DVec3::new(0.0, 0.03, 0.0),
            DVec3::splat(0.015),
        ] {
            let px = cam.project(p, size).unwrap();
            let (o, d) = cam.ray(px, size);
            let off = (p - o) - d * (p - o).dot(d);
            assert!(off.length() < 1e-12, "{p}: off the ray by {}", off.length());
            let c = vp * p.as_vec3().extend(1.0);
            let ndc = c.truncate() / c.w;
            let gx = 0.5 * (f64::from(ndc.x) + 1.0) * 640.0;
            let gy = 0.5 * (1.0 - f64::from(ndc.y)) * 480.0;
            assert!(
                (gx - px[0]).abs() < 1e-3 && (gy - px[1]).abs() < 1e-3,
                "{px:?} vs {gx},{gy}"
            );
        }
    }
}
