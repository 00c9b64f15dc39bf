//! A live view of a scene, shared by every front end that draws one (the window, the demo's
//! frames, the web page): the scales a view derives from the scene's size and stiffness, what
//! a frame shows of a haptic sample ([`SampleMarks`]) and the frame's objects
//! ([`frame_objects`]).

use glam::DVec3;
use touchfem_core::haptic::WorldSample;
use touchfem_core::limits::MAX_FINGERS;
use touchfem_core::scene::World;

use super::{arrow_scale, displacement_scale, Edges, ForceArrow, FrameObject};
use crate::Deformer;

/// Where the finger starts before a pointer press: this far outside the touched point, m.
pub const OUTSIDE_M: f64 = 1e-3;
/// Least press depth per pixel dragged, m.
const MIN_DEPTH_PER_PX: f64 = 0.06e-3;
/// Press depth per pixel as a fraction of the scene's diagonal.
const DEPTH_PER_PX_OF_DIAGONAL: f64 = 0.002;
/// The colour map's full scale as a fraction of the scene's diagonal (rounded to a nice
/// number): a 100-pixel drag on the cube presses 6 mm, its scale is 6 mm.
const COLOR_SCALE_OF_DIAGONAL: f64 = 0.1;
/// Least depth of a blade's top under the surface it was pressed on, m.
const MIN_BLADE_SINK_M: f64 = 0.2e-3;
/// A blade's top under the surface as a fraction of the scene's diagonal.
const BLADE_SINK_OF_DIAGONAL: f64 = 0.005;

/// Each object's rest surface and its offset in the scene: what [`super::pick`] and
/// [`PointerPress::drag`] take.
pub fn rest_surfaces(world: &World) -> Vec<(&touchfem_core::contact::Surface, DVec3)> {
    world
        .objects
        .iter()
        .map(|o| (&o.body.surface, o.offset))
        .collect()
}

/// A pointer press that hit an object, and where it puts the finger the pointer drives: a
/// left drag presses along the normal by the distance dragged; a blade (`B`) hangs
/// [`ViewScales::blade_sink_m`] under the surface point under the cursor, so it follows a
/// curved surface (off the object's silhouette it slides in the plane tangent at the press).
/// The window and the web page both press this way.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PointerPress {
    /// The pixel the press started at.
    pub pixel: [f64; 2],
    /// The surface point it touched, scene frame, m.
    pub point: DVec3,
    /// The outward surface normal there.
    pub normal: DVec3,
    /// The object it touched: its index in the objects given to [`super::pick`] (and to
    /// [`PointerPress::drag`]).
    pub object: usize,
}

impl PointerPress {
    /// Where the finger goes when the press starts: [`OUTSIDE_M`] outside the touched point,
    /// or a blade's sink under it.
    pub fn start(&self, blade: bool, scales: &ViewScales) -> DVec3 {
        if blade {
            self.point - self.normal * scales.blade_sink_m
        } else {
            self.point + self.normal * OUTSIDE_M
        }
    }

    /// Where the finger goes when the pointer is at `cursor` (pixels of a `size` view seen by
    /// `camera`): a finger into the surface by the distance dragged; a blade under the point of
    /// the pressed object's rest surface under the cursor (`objects` as given to
    /// [`super::pick`]), along that point's normal, or, where the cursor is off the object,
    /// under the point of the tangent plane at the press. `None`: it stays (no drag yet, or a
    /// ray that misses both).
    pub fn drag(
        &self,
        camera: &super::Camera,
        size: [u32; 2],
        cursor: [f64; 2],
        blade: bool,
        scales: &ViewScales,
        objects: &[(&touchfem_core::contact::Surface, DVec3)],
    ) -> Option<DVec3> {
        if blade {
            let on = objects
                .get(self.object)
                .and_then(|o| super::pick(camera, size, cursor, std::slice::from_ref(o)));
            if let Some(h) = on {
                return Some(h.point - h.normal * scales.blade_sink_m);
            }
            let (eye, dir) = camera.ray(cursor, size);
            let along = dir.dot(self.normal);
            if along.abs() <= 1e-9 {
                return None;
            }
            let t = (self.point - eye).dot(self.normal) / along;
            return (t.is_finite() && t > 0.0)
                .then(|| eye + dir * t - self.normal * scales.blade_sink_m);
        }
        let px = ((cursor[0] - self.pixel[0]).powi(2) + (cursor[1] - self.pixel[1]).powi(2)).sqrt();
        (px > 0.0).then(|| self.point - self.normal * (px * scales.depth_per_px))
    }
}

/// The scales a live view of a scene uses, from its rest bounds and its stiffness.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ViewScales {
    /// The rest bounding box's diagonal, m.
    pub diag: f64,
    /// The colour map's full scale and step, m ([`displacement_scale`]).
    pub color_scale: (f64, f64),
    /// The force arrow's length per newton, m/N.
    pub arrow_m_per_n: f64,
    /// Press depth per pixel dragged, m.
    pub depth_per_px: f64,
    /// A blade's top under the surface it was pressed on, m.
    pub blade_sink_m: f64,
}

impl ViewScales {
    /// The scales of `world`. The force arrow: a press as deep as the colour scale's full
    /// scale at the first object's median contact stiffness (the 3×3 `L_ii⁻¹` blocks' mean
    /// diagonal) is a quarter of the scene's size.
    pub fn of(world: &World) -> ViewScales {
        let (lo, hi) = world.bounds();
        let diag = if lo.is_finite() && hi.is_finite() {
            (hi - lo).length()
        } else {
            1.0
        };
        let arrow_m_per_n = match world.objects.first() {
            None => arrow_scale(1.0, 0.25 * diag),
            Some(o) => {
                let c = &o.body.compliance;
                let mut k: Vec<f64> = (0..c.cols().len())
                    .map(|i| {
                        let m = c.diag_inv(i);
                        (m.x_axis.x + m.y_axis.y + m.z_axis.z) / 3.0
                    })
                    .filter(|v| v.is_finite() && *v > 0.0)
                    .collect();
                arrow_scale(median(&mut k) * COLOR_SCALE_OF_DIAGONAL * diag, 0.25 * diag)
            }
        };
        ViewScales {
            diag,
            color_scale: displacement_scale(COLOR_SCALE_OF_DIAGONAL * diag),
            arrow_m_per_n,
            depth_per_px: MIN_DEPTH_PER_PX.max(DEPTH_PER_PX_OF_DIAGONAL * diag),
            blade_sink_m: MIN_BLADE_SINK_M.max(BLADE_SINK_OF_DIAGONAL * diag),
        }
    }
}

/// The median of `v` (sorted in place; 0 when empty).
pub fn median(v: &mut [f64]) -> f64 {
    if v.is_empty() {
        return 0.0;
    }
    v.sort_by(f64::total_cmp);
    let n = v.len();
    if n % 2 == 1 {
        v[n / 2]
    } else {
        0.5 * (v[n / 2 - 1] + v[n / 2])
    }
}

/// What a frame shows of a haptic sample besides the objects: each finger, its god-object and
/// its force arrow (`NaN` where a finger has no valid position or touches nothing, which the
/// renderer skips). With [`frame_objects`], the one place a frame is built from a sample.
/// Allocates nothing.
#[derive(Clone, Copy, Debug)]
pub struct SampleMarks {
    /// Finger positions, metres (scene frame).
    pub fingers: [DVec3; MAX_FINGERS],
    /// God-objects of the touching fingers (a sphere's: its patch's centre).
    pub proxies: [DVec3; MAX_FINGERS],
    /// Each finger's sphere radius, m (0 for a point): set by [`SampleMarks::with_tools`].
    pub radii: [f64; MAX_FINGERS],
    /// Force arrows from the god-objects of the touching fingers.
    pub arrows: [ForceArrow; MAX_FINGERS],
    /// Fingers in the sample.
    pub n: usize,
}

impl SampleMarks {
    /// The marks of `sample`, arrows `m_per_n` metres long per newton.
    pub fn of(sample: &WorldSample, m_per_n: f64) -> SampleMarks {
        let none = ForceArrow {
            at: DVec3::NAN,
            force_n: DVec3::ZERO,
            m_per_n,
        };
        let mut m = SampleMarks {
            fingers: [DVec3::NAN; MAX_FINGERS],
            proxies: [DVec3::NAN; MAX_FINGERS],
            arrows: [none; MAX_FINGERS],
            radii: [0.0; MAX_FINGERS],
            n: sample.n_fingers.min(MAX_FINGERS),
        };
        for (i, f) in sample.fingers().iter().enumerate().take(MAX_FINGERS) {
            m.fingers[i] = f.position;
            if let Some(p) = f.proxy.filter(|_| f.object.is_some()) {
                m.proxies[i] = p;
                m.arrows[i].at = p;
                m.arrows[i].force_n = f.force;
            }
        }
        m
    }

    /// The marks with each sphere finger of `world` drawn at its radius.
    pub fn with_tools(mut self, world: &World) -> SampleMarks {
        for (r, f) in self.radii.iter_mut().zip(&world.fingers) {
            *r = f.tool.radius().unwrap_or(0.0);
        }
        self
    }
}

/// Each object of `world` as a frame object: its deformer, where it sits, its rest bounds and,
/// where given, its edges.
pub fn frame_objects<'a>(
    world: &World,
    deformers: &'a [Deformer],
    edges: &'a [Edges],
) -> Vec<FrameObject<'a>> {
    world
        .objects
        .iter()
        .zip(deformers)
        .enumerate()
        .map(|(i, (o, d))| FrameObject {
            deformer: d,
            offset: o.offset,
            bounds: o.body.mesh.bounds(),
            edges: edges.get(i),
            deformed: false,
        })
        .collect()
}
