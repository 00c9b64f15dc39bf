//! Rendering of deformed objects: offscreen to an image or a PNG file, or into a caller's colour
//! view (a window's surface texture) in the caller's encoder.
//!
//! The surface comes from a [`Deformer`] (the GPU pass: positions and normals never visit the
//! CPU), lit with Blinn-Phong from a fixed key light, with a depth buffer and optional MSAA
//! ([`RenderOptions::samples`]: 4 for images, [`live_samples`] for a window). The offscreen
//! entry points frame the rest bounding box from a fixed 3/4 view ([`Camera::framing`]); a
//! window uses an [`Orbit`] camera and [`pick`]s the surface under the pointer. The finger tips
//! (red) and god-objects (blue) are small spheres, as in the paper's Figure 1; where the surface
//! hides them they show through as a ghost. The force on a finger is an arrow from its tip
//! ([`ForceArrow`], drawn at a stated scale in mm per N). The surface is one colour or
//! coloured by the displacement's magnitude |u| ([`Coloring::Displacement`]: viridis over a
//! fixed full scale, |u| read from the vertex that the deformation pass wrote), explained by a
//! legend ([`legend_image`], in mm). The wireframe overlay draws the surface edges
//! ([`Edges`]); an [`Overlay`] draws a status line of text or the legend.
//!
//! * [`Renderer::render`] / [`Renderer::render_with`]: one object, offscreen, as the goldens
//!   are judged (4× MSAA, [`COLOR_FORMAT`]);
//! * [`Renderer::render_frame`]: several objects offscreen, framing the union of their bounds;
//! * [`Renderer::render_to_image`]: a [`Frame`] offscreen (the demo's frames: its camera,
//!   colouring, arrows and legend);
//! * [`Renderer::draw`]: a [`Frame`] (several objects, each with its scene-frame offset, a
//!   camera, spheres, overlay) into any colour view of the renderer's size and format.
//!
//! ```no_run
//! # fn main() -> Result<(), touchfem_gpu::render::RenderError> {
//! use touchfem_core::{compliance::{Compliance, Selection}, mesh::cube};
//! use touchfem_gpu::render;
//! let mesh = cube();
//! let c = Compliance::compute(&mesh, &Selection::default()).unwrap();
//! let scene = render::Picture::at_rest(&mesh, &c);
//! render::render_png("cube.png".as_ref(), [640, 480], &scene)?;
//! # Ok(()) }
//! ```

mod camera;
mod edges;
mod legend;
mod overlay;
mod pixels;
pub use text::FONT;
mod pick;
mod pipelines;
mod text;
mod view;

pub(crate) use camera::FULL_FRAME;
pub use camera::{Camera, Orbit, VIEW_DIR};
pub use edges::Edges;
pub use legend::{
    arrow_label, arrow_scale, displacement_scale, format_significant, legend_image, length_ticks,
    viridis, LegendSpec, LengthTicks, VIRIDIS,
};
pub use overlay::{Anchor, Overlay};
pub use pick::{pick, Hit};
pub use pixels::RgbaPixels;
pub use view::{
    frame_objects, median, rest_surfaces, PointerPress, SampleMarks, ViewScales, OUTSIDE_M,
};

use bytemuck::{Pod, Zeroable};
use glam::DVec3;
#[cfg(feature = "png")]
use std::path::Path;
use thiserror::Error;

#[cfg(feature = "png")]
use crate::context::Gpu;
use crate::context::GpuError;
use crate::deform::Deformer;
#[cfg(feature = "png")]
use crate::input::DeformerOptions;
use touchfem_core::compliance::Compliance;
use touchfem_core::mesh::Mesh;

/// The WGSL source of the renderer (`shaders/render.wgsl`).
pub(crate) const RENDER_WGSL: &str = include_str!("../../../../shaders/render.wgsl");

/// Colour format of the rendered image (8-bit sRGB, straight to PNG).
pub const COLOR_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8UnormSrgb;
/// Depth format.
pub(crate) const DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;
/// MSAA sample count of the offscreen images (and of [`RenderOptions::default`]).
pub const SAMPLES: u32 = 4;
/// Sphere radius as a fraction of the scene's size ([`Frame::scale`], the rest bounding box's
/// diagonal).
pub(crate) const SPHERE_RADIUS: f64 = 0.018;
/// Most objects one [`Frame`] may hold.
pub const MAX_FRAME_OBJECTS: usize = 8;
/// Most spheres (fingers, god-objects and contact-patch dots) one [`Frame`] may hold.
pub(crate) const MAX_SPHERES: usize = 16 + MAX_PATCH_MARKS;
/// Most contact-patch dots ([`Frame::patch`]) one frame may hold.
pub const MAX_PATCH_MARKS: usize = 256;
/// A contact-patch dot's radius relative to a finger marker's.
const PATCH_DOT: f64 = 0.3;
/// Most force arrows one [`Frame`] may hold.
pub(crate) const MAX_ARROWS: usize = 8;
/// Force arrow shaft radius as a fraction of the scene's size (its head is 4 radii long and
/// 2.5 radii wide).
pub(crate) const ARROW_RADIUS: f64 = 0.008;

/// Background colour (linear RGB).
const BACKGROUND: wgpu::Color = wgpu::Color {
    r: 0.82,
    g: 0.85,
    b: 0.90,
    a: 1.0,
};
const SURFACE: [f32; 4] = [0.85, 0.50, 0.28, 1.0];
const LINES: [f32; 4] = [0.06, 0.05, 0.05, 1.0];
/// Opacity of the wireframe over a colour-mapped surface (fainter, so the colours read).
const LINES_OVER_COLORS: f32 = 0.4;
/// The finger: red, translucent (the dent it presses shows through).
const FINGER: [f32; 4] = [0.80, 0.08, 0.06, 0.55];
const PROXY: [f32; 4] = [0.10, 0.30, 0.85, 1.0];
const ARROW: [f32; 4] = [0.85, 0.06, 0.05, 1.0];
/// Byte stride of the per-draw uniform records (a dynamic offset must be a multiple of the
/// device's `min_uniform_buffer_offset_alignment`, at most 256).
const UNIFORM_STRIDE: u64 = 256;

/// Errors while rendering.
#[derive(Debug, Error)]
pub enum RenderError {
    /// The GPU side failed (no adapter, bad forces, …).
    #[error(transparent)]
    Gpu(#[from] GpuError),
    #[cfg(feature = "png")]
    /// Writing the PNG failed.
    #[error("cannot write image: {0}")]
    Image(#[from] image::ImageError),
    /// The image size is zero or beyond the device's texture limit.
    #[error("image size {0:?} is not supported (1 ..= {1} per side)")]
    BadSize([u32; 2], u32),
    /// A frame holds more objects or spheres than the renderer draws.
    #[error("a frame holds {count} {what}; at most {max} are drawn")]
    TooMany {
        /// "objects" or "spheres".
        what: &'static str,
        /// How many the frame holds.
        count: usize,
        /// The limit ([`MAX_FRAME_OBJECTS`], `MAX_SPHERES`).
        max: usize,
    },
    /// The sample count or colour format is not usable.
    #[error("unsupported render options: {0}")]
    Options(String),
}

/// How the surface is coloured.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub enum Coloring {
    /// One colour (terracotta), shaded.
    #[default]
    Plain,
    /// By the displacement's magnitude |u|, viridis from 0 (dark violet) to `full_scale_m`
    /// (yellow; beyond it stays yellow), shaded. Keep the scale fixed over a session so that
    /// its frames compare; the legend ticks every `step_m`. See [`Coloring::displacement`].
    Displacement {
        /// |u| drawn yellow, metres.
        full_scale_m: f64,
        /// The legend's tick step, metres.
        step_m: f64,
    },
}

impl Coloring {
    /// [`Coloring::Displacement`] with the nice scale [`displacement_scale`] of a largest
    /// displacement `max_m` (m).
    pub fn displacement(max_m: f64) -> Coloring {
        let (full_scale_m, step_m) = displacement_scale(max_m);
        Coloring::Displacement {
            full_scale_m,
            step_m,
        }
    }

    /// The shader's `colormap.x`: 1 / full scale, or 0 for plain.
    fn inverse_scale(&self) -> f32 {
        match *self {
            Coloring::Plain => 0.0,
            Coloring::Displacement { full_scale_m, .. } if full_scale_m > 0.0 => {
                (1.0 / full_scale_m) as f32
            }
            Coloring::Displacement { .. } => 0.0,
        }
    }
}

/// The force fed back to a finger, drawn as an arrow from `at` along the force, `m_per_n`
/// metres long per newton (the legend states it in mm/N). Start it at the finger's god-object
/// (where it touches the rest surface): then it points out of the dent without covering it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ForceArrow {
    /// Where the arrow starts, metres (scene frame): the god-object, or the finger tip.
    pub at: DVec3,
    /// The force on the finger, newtons.
    pub force_n: DVec3,
    /// Arrow length per newton, metres.
    pub m_per_n: f64,
}

/// Where the offscreen camera looks from.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub enum View {
    /// The fixed 3/4 view ([`VIEW_DIR`]), the object filling the frame ([`Camera::fit`] over
    /// its surface, the spheres and the arrow).
    #[default]
    Auto,
    /// The touched point from outside the surface ([`Camera::contact`]), framing the surface
    /// within `radius_m` of it.
    Contact {
        /// The touched point, metres.
        point: DVec3,
        /// The outward unit normal there.
        normal: DVec3,
        /// Radius of the surface framed around it, metres.
        radius_m: f64,
    },
}

/// A picture to draw of one object under a force boundary condition, with the finger and the
/// god-object ([`render_png`], `render_image`); a window or animation draws [`Frame`]s.
#[derive(Clone, Copy, Debug)]
pub struct Picture<'a> {
    /// The mesh: rest positions (`nodes`) and surface triangles.
    pub mesh: &'a Mesh,
    /// Its compliance (rows must cover the surface nodes).
    pub compliance: &'a Compliance,
    /// The force boundary condition: (column index, force in N).
    pub forces: &'a [(u32, [f32; 3])],
    /// Finger tip (haptic device position), metres; drawn red.
    pub finger: Option<DVec3>,
    /// God-object (proxy) position, metres; drawn blue.
    pub proxy: Option<DVec3>,
    /// The finger's sphere radius (m), when it is a sphere: drawn at that size.
    pub finger_radius: Option<f64>,
    /// The contact patch: the nodes in contact (m, deformed), drawn as small blue dots.
    pub patch: &'a [DVec3],
    /// Overlay the surface edges.
    pub wireframe: bool,
    /// How the surface is coloured.
    pub coloring: Coloring,
    /// The force on the finger, drawn as an arrow.
    pub arrow: Option<ForceArrow>,
    /// Where the camera looks from.
    pub view: View,
    /// Draw the legend (top right): the colour scale in mm when coloured by displacement, the
    /// arrow's scale in mm/N and the force in N when there is an arrow.
    pub legend: bool,
}

impl<'a> Picture<'a> {
    /// The object at rest, no spheres, no wireframe, plain, the 3/4 view, no legend.
    pub fn at_rest(mesh: &'a Mesh, compliance: &'a Compliance) -> Picture<'a> {
        Picture {
            mesh,
            compliance,
            forces: &[],
            finger: None,
            proxy: None,
            finger_radius: None,
            patch: &[],
            wireframe: false,
            coloring: Coloring::Plain,
            arrow: None,
            view: View::Auto,
            legend: false,
        }
    }

    /// What its legend shows (see [`Picture::legend`]) in an image `height` pixels high.
    #[cfg(feature = "png")]
    pub(crate) fn legend_spec(&self, height: u32) -> LegendSpec {
        LegendSpec {
            bar_px: LegendSpec::bar_for(height),
            displacement: match self.coloring {
                Coloring::Displacement {
                    full_scale_m,
                    step_m,
                } => Some((full_scale_m, step_m)),
                Coloring::Plain => None,
            },
            arrow_m_per_n: self.arrow.map(|a| a.m_per_n),
            force_n: self.arrow.map(|a| a.force_n.length()),
        }
    }
}

/// The region of the image (normalised device coordinates, [`Camera::fit`]) left of a legend
/// `legend_px` (width, height) in the top-right corner of a `size` image, less a 5 % margin.
pub fn region_beside_legend(size: [u32; 2], legend_px: Option<[u32; 2]>) -> [f64; 4] {
    match legend_px {
        Some([lw, _]) if size[0] > 0 => {
            let x1 = 1.0 - 2.0 * f64::from(lw + 16) / f64::from(size[0]);
            [-0.95, x1.max(-0.5), -0.95, 0.95]
        }
        _ => FULL_FRAME,
    }
}

/// How a [`Renderer`] draws: MSAA samples and the colour target's format.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RenderOptions {
    /// MSAA sample count: 1 (none) or 4. 4× MSAA costs most of a frame on a software
    /// rasteriser; see [`live_samples`].
    pub samples: u32,
    /// Format of the colour view drawn into (any 8-bit RGBA/BGRA format a surface offers; the
    /// offscreen entry points need `Rgba8*` or `Bgra8*`).
    pub format: wgpu::TextureFormat,
}

impl Default for RenderOptions {
    /// [`SAMPLES`] and [`COLOR_FORMAT`]: the offscreen images and goldens.
    fn default() -> Self {
        RenderOptions {
            samples: SAMPLES,
            format: COLOR_FORMAT,
        }
    }
}

/// The MSAA sample count for a live (windowed) loop on `adapter`: 1 on a CPU adapter (a
/// software rasteriser such as lavapipe, where 4× MSAA is most of the frame's cost), 4
/// elsewhere.
pub fn live_samples(adapter: &wgpu::AdapterInfo) -> u32 {
    if adapter.device_type == wgpu::DeviceType::Cpu {
        1
    } else {
        4
    }
}

/// Fewest pixels per surface edge at which a live view draws the wireframe by default.
pub(crate) const WIREFRAME_PX_PER_EDGE: u64 = 24;

/// Whether a live view should draw the wireframe of `triangles` surface triangles at `size`
/// by default: only while the edges (about 1.5 a triangle) are sparser than one per
/// `WIREFRAME_PX_PER_EDGE` pixels. Denser, the lines grey the whole surface over and, on a
/// software rasteriser, cost as much as the surface itself (45k-node organ, 30k edges at
/// 640×480 on llvmpipe: 7–10 ms of a frame).
pub fn wireframe_by_default(triangles: usize, size: [u32; 2]) -> bool {
    let edges = triangles as u64 * 3 / 2;
    edges * WIREFRAME_PX_PER_EDGE <= u64::from(size[0]) * u64::from(size[1])
}

#[cfg(feature = "png")]
/// Renders `scene` at `size` (width, height) on a headless GPU chosen by the environment
/// (`WGPU_BACKEND`, `WGPU_ADAPTER_NAME`) and writes a PNG to `path`.
pub fn render_png(path: &Path, size: [u32; 2], scene: &Picture<'_>) -> Result<(), RenderError> {
    render_image(size, scene)?.save_with_format(path, image::ImageFormat::Png)?;
    Ok(())
}

#[cfg(feature = "png")]
/// Renders `scene` at `size` on a headless GPU chosen by the environment.
pub(crate) fn render_image(
    size: [u32; 2],
    scene: &Picture<'_>,
) -> Result<image::RgbaImage, RenderError> {
    let gpu = Gpu::new_headless()?;
    Renderer::new(&gpu.device, size)?.render(&gpu.device, &gpu.queue, scene)
}

#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct CameraGpu {
    view_proj: [[f32; 4]; 4],
    eye: [f32; 4],
    light_dir: [f32; 4],
    base_color: [f32; 4],
    line_color: [f32; 4],
    /// The drawn object's offset in the scene (xyz, m); zero for the spheres.
    offset: [f32; 4],
    /// x: 1 / the colour map's full scale (1/m), 0: plain.
    colormap: [f32; 4],
}

#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
struct ArrowInstance {
    base_len: [f32; 4],
    dir_radius: [f32; 4],
    color: [f32; 4],
}

#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
struct SphereInstance {
    center_radius: [f32; 4],
    color: [f32; 4],
}

/// One object of a [`Frame`].
#[derive(Clone, Copy, Debug)]
pub struct FrameObject<'a> {
    /// Its deformer (vertices in the object's own frame), forces already set and its pass
    /// encoded by [`Renderer::draw`] into the caller's encoder.
    pub deformer: &'a Deformer,
    /// Where the object's origin sits in the scene, metres.
    pub offset: DVec3,
    /// Its rest bounding box in its own frame (min, max), metres: used to frame the camera by
    /// [`Renderer::render_frame`] and `union_bounds`.
    pub bounds: (DVec3, DVec3),
    /// Its edges, for the wireframe (skipped when `None`; [`Renderer::render_frame`] builds
    /// them when missing).
    pub edges: Option<&'a Edges>,
    /// Its deformation pass already ran for the forces set (e.g. by the app's
    /// `Visual::update`): [`Renderer::draw`] does not encode it again.
    pub deformed: bool,
}

/// Everything one image shows, for [`Renderer::draw`]. Positions are in the scene frame.
#[derive(Clone, Copy, Debug)]
pub struct Frame<'a> {
    /// The objects (at most [`MAX_FRAME_OBJECTS`]).
    pub objects: &'a [FrameObject<'a>],
    /// The camera.
    pub camera: Camera,
    /// Finger tips, drawn red (non-finite positions are skipped).
    pub fingers: &'a [DVec3],
    /// Per finger, the radius (m) of its sphere tool, drawn at that size; missing or 0: the
    /// marker size (`SPHERE_RADIUS` × `scale`).
    pub finger_radii: &'a [f64],
    /// Nodes in contact with a sphere (scene frame), drawn as small blue dots: the patch.
    pub patch: &'a [DVec3],
    /// God-objects, drawn blue (non-finite positions are skipped).
    pub proxies: &'a [DVec3],
    /// The scene's size, metres (e.g. its rest bounding box's diagonal): the spheres' radius is
    /// `SPHERE_RADIUS` times this, the wireframe is lifted towards the eye by 0.2 % of it.
    pub scale: f64,
    /// Overlay the surface edges of objects that have [`FrameObject::edges`].
    pub wireframe: bool,
    /// A text overlay (status line) drawn on top, if any.
    pub overlay: Option<&'a Overlay>,
    /// How the surfaces are coloured.
    pub coloring: Coloring,
    /// Force arrows (at most `MAX_ARROWS`; non-finite or zero ones are skipped).
    pub arrows: &'a [ForceArrow],
    /// A second overlay drawn on top, e.g. the legend ([`legend_image`], [`Anchor::TopRight`]).
    pub legend: Option<&'a Overlay>,
}

/// The union of the objects' rest bounds in the scene frame (each [`FrameObject::bounds`]
/// moved by its offset).
#[cfg(feature = "png")]
pub(crate) fn union_bounds(objects: &[FrameObject<'_>]) -> (DVec3, DVec3) {
    objects.iter().fold(
        (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
        |(lo, hi), o| (lo.min(o.bounds.0 + o.offset), hi.max(o.bounds.1 + o.offset)),
    )
}

/// Colour (multisampled) and depth attachments of one size.
#[derive(Debug)]
struct Attachments {
    msaa: Option<wgpu::TextureView>,
    depth: wgpu::TextureView,
}

/// A reusable renderer for one image size, sample count and colour format on one device.
///
/// It keeps its uniform and sphere buffers and its depth (and multisampled colour) attachment,
/// so a frame loop ([`draw`](Self::draw)) allocates nothing on the device. One
/// [`draw`](Self::draw) per submission: its uniforms are written with
/// [`wgpu::Queue::write_buffer`].
#[derive(Debug)]
pub struct Renderer {
    size: [u32; 2],
    options: RenderOptions,
    surface: wgpu::RenderPipeline,
    /// The surface without the per-pixel facet normal ([`DeformerStats::smooth_triangles`](crate::DeformerStats::smooth_triangles)).
    surface_smooth: wgpu::RenderPipeline,
    lines: wgpu::RenderPipeline,
    /// A closed slit's line ([`Edges`]), drawn with or without the wireframe.
    slit: wgpu::RenderPipeline,
    sphere: wgpu::RenderPipeline,
    sphere_hidden: wgpu::RenderPipeline,
    sphere_vertices: wgpu::Buffer,
    sphere_indices: wgpu::Buffer,
    sphere_index_count: u32,
    arrow: wgpu::RenderPipeline,
    arrow_hidden: wgpu::RenderPipeline,
    arrow_vertices: wgpu::Buffer,
    arrow_indices: wgpu::Buffer,
    arrow_index_count: u32,
    arrow_instances: wgpu::Buffer,
    uniforms: wgpu::Buffer,
    instances: wgpu::Buffer,
    bind_group: wgpu::BindGroup,
    attachments: Attachments,
    /// Held from `draw` to `submit` by the offscreen renders, which take `&self` and may be
    /// called from several threads: the uniforms and attachments are the renderer's own.
    #[cfg_attr(not(feature = "png"), allow(dead_code))]
    offscreen: std::sync::Mutex<()>,
}

impl Renderer {
    /// Builds the pipelines for images of `size` (width, height) with [`RenderOptions::default`]
    /// (4× MSAA, [`COLOR_FORMAT`]).
    pub fn new(device: &wgpu::Device, size: [u32; 2]) -> Result<Renderer, RenderError> {
        Renderer::with_options(device, size, RenderOptions::default())
    }

    /// Image size (width, height).
    pub fn size(&self) -> [u32; 2] {
        self.size
    }

    /// The options it was built with.
    pub fn options(&self) -> RenderOptions {
        self.options
    }

    /// Changes the image size (a window was resized): rebuilds the depth and multisampled
    /// attachments.
    pub fn resize(&mut self, device: &wgpu::Device, size: [u32; 2]) -> Result<(), RenderError> {
        check_size(device, size)?;
        if size != self.size {
            self.size = size;
            self.attachments = attachments(device, size, self.options);
        }
        Ok(())
    }

    #[cfg(feature = "png")]
    /// Renders `scene`: uploads its compliance into a [`Deformer`], runs the deformation pass
    /// and draws, all in one submission, then reads the image back.
    pub fn render(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        scene: &Picture<'_>,
    ) -> Result<image::RgbaImage, RenderError> {
        let mut deformer = Deformer::new(
            device,
            queue,
            scene.compliance,
            &scene.mesh.nodes,
            &scene.mesh.surface,
            &DeformerOptions::default(),
        )?;
        deformer.set_forces(queue, scene.forces)?;
        self.render_with(device, queue, &deformer, scene)
    }

    #[cfg(feature = "png")]
    /// Renders with a caller-kept [`Deformer`] (built for `scene`'s mesh and compliance) whose
    /// forces the caller has already set. `scene.forces` is not used here. With
    /// [`Picture::legend`] it builds the legend's overlay on every call: for a frame loop with a
    /// legend, keep an [`Overlay`] and use [`render_to_image`](Self::render_to_image).
    pub fn render_with(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        deformer: &Deformer,
        scene: &Picture<'_>,
    ) -> Result<image::RgbaImage, RenderError> {
        let (min, max) = bounds(&scene.mesh.nodes);
        let scale = (max - min).length();
        let legend = if scene.legend {
            legend_image(&scene.legend_spec(self.size[1])).map(|img| {
                let mut o = Overlay::new(device, self.options);
                o.set_anchor(Anchor::TopRight);
                o.set_image(device, queue, Some(&img));
                o
            })
        } else {
            None
        };
        let camera = self.scene_camera(scene, legend.as_ref().and_then(Overlay::image_size));
        let edges = scene.wireframe.then(|| Edges::new(device, deformer));
        let objects = [FrameObject {
            deformer,
            offset: DVec3::ZERO,
            bounds: (min, max),
            edges: edges.as_ref(),
            deformed: false,
        }];
        let fingers: Vec<DVec3> = scene.finger.into_iter().collect();
        let radii: Vec<f64> = scene.finger_radius.into_iter().collect();
        let proxies: Vec<DVec3> = scene.proxy.into_iter().collect();
        let arrows: Vec<ForceArrow> = scene.arrow.into_iter().collect();
        let frame = Frame {
            objects: &objects,
            camera,
            fingers: &fingers,
            finger_radii: &radii,
            patch: scene.patch,
            proxies: &proxies,
            scale,
            wireframe: scene.wireframe,
            overlay: None,
            coloring: scene.coloring,
            arrows: &arrows,
            legend: legend.as_ref(),
        };
        self.render_to_image(device, queue, &frame)
    }

    /// The camera [`render_with`](Self::render_with) uses for `scene` with a legend of
    /// `legend_px` (width, height) in the top-right corner: [`View::Auto`] fits the rest
    /// surface, the spheres and the arrow's tip into the image left of the legend;
    /// [`View::Contact`] looks at the touched point from outside, framing the surface within
    /// the radius, the spheres and the arrow.
    pub fn scene_camera(&self, scene: &Picture<'_>, legend_px: Option<[u32; 2]>) -> Camera {
        let [w, h] = self.size;
        let aspect = f64::from(w) / f64::from(h);
        let region = region_beside_legend(self.size, legend_px);
        let mut extra: Vec<DVec3> = scene.finger.into_iter().chain(scene.proxy).collect();
        if let Some(a) = scene.arrow {
            extra.push(a.at + a.force_n * a.m_per_n);
        }
        let surface = scene
            .mesh
            .surface
            .iter()
            .flatten()
            .map(|&n| scene.mesh.nodes[n as usize]);
        match scene.view {
            View::Auto => {
                let pts: Vec<DVec3> = surface.chain(extra).collect();
                Camera::fit(&pts, VIEW_DIR, aspect, region)
            }
            View::Contact {
                point,
                normal,
                radius_m,
            } => {
                let pts: Vec<DVec3> = surface
                    .filter(|p| p.distance(point) <= radius_m)
                    .chain(extra)
                    .collect();
                Camera::contact(point, normal, &pts, aspect, region)
            }
        }
    }

    #[cfg(feature = "png")]
    /// Renders several objects offscreen (their forces already set), the camera framing the
    /// union of their rest bounds from the fixed 3/4 view ([`Camera::framing`]); builds the
    /// wireframe's [`Edges`] of objects that have none when `wireframe` is set. Spheres:
    /// `fingers` red, `proxies` blue, scene frame.
    pub fn render_frame(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        objects: &[FrameObject<'_>],
        fingers: &[DVec3],
        proxies: &[DVec3],
        wireframe: bool,
    ) -> Result<image::RgbaImage, RenderError> {
        let (min, max) = union_bounds(objects);
        if !(min.is_finite() && max.is_finite()) {
            return Err(RenderError::Options(
                "render_frame needs at least one object".into(),
            ));
        }
        let [w, h] = self.size;
        let built: Vec<Option<Edges>> = objects
            .iter()
            .map(|o| (wireframe && o.edges.is_none()).then(|| Edges::new(device, o.deformer)))
            .collect();
        let objects: Vec<FrameObject<'_>> = objects
            .iter()
            .zip(&built)
            .map(|(o, e)| FrameObject {
                edges: o.edges.or(e.as_ref()),
                ..*o
            })
            .collect();
        let frame = Frame {
            objects: &objects,
            camera: Camera::framing(min, max, f64::from(w) / f64::from(h)),
            fingers,
            finger_radii: &[],
            patch: &[],
            proxies,
            scale: (max - min).length(),
            wireframe,
            overlay: None,
            coloring: Coloring::Plain,
            arrows: &[],
            legend: None,
        };
        self.render_to_image(device, queue, &frame)
    }

    #[cfg(feature = "png")]
    /// Draws `frame` offscreen in one submission and reads the image back (the renderer's
    /// format must be 8-bit RGBA or BGRA).
    pub fn render_to_image(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        frame: &Frame<'_>,
    ) -> Result<image::RgbaImage, RenderError> {
        use wgpu::TextureFormat as F;
        let bgra = match self.options.format {
            F::Rgba8Unorm | F::Rgba8UnormSrgb => false,
            F::Bgra8Unorm | F::Bgra8UnormSrgb => true,
            f => {
                return Err(RenderError::Options(format!(
                    "offscreen images need an 8-bit RGBA or BGRA format, not {f:?}"
                )))
            }
        };
        let [w, h] = self.size;
        let extent = wgpu::Extent3d {
            width: w,
            height: h,
            depth_or_array_layers: 1,
        };
        let usage = wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC;
        let resolved = frame_texture(
            device,
            "touchfem image",
            self.size,
            self.options.format,
            usage,
        );
        let resolved_view = resolved.create_view(&Default::default());
        let row_bytes = (4 * w).div_ceil(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT)
            * wgpu::COPY_BYTES_PER_ROW_ALIGNMENT;
        let readback = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("touchfem image readback"),
            size: u64::from(row_bytes) * u64::from(h),
            usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
            mapped_at_creation: false,
        });
        let mut enc = device.create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("touchfem render"),
        });
        let guard = self
            .offscreen
            .lock()
            .unwrap_or_else(std::sync::PoisonError::into_inner);
        self.draw(device, queue, &mut enc, &resolved_view, frame)?;
        enc.copy_texture_to_buffer(
            wgpu::TexelCopyTextureInfo {
                texture: &resolved,
                mip_level: 0,
                origin: wgpu::Origin3d::ZERO,
                aspect: wgpu::TextureAspect::All,
            },
            wgpu::TexelCopyBufferInfo {
                buffer: &readback,
                layout: wgpu::TexelCopyBufferLayout {
                    offset: 0,
                    bytes_per_row: Some(row_bytes),
                    rows_per_image: Some(h),
                },
            },
            extent,
        );
        queue.submit([enc.finish()]);
        drop(guard);
        let bytes = crate::context::map_read(device, &readback)?;
        let mut pixels = Vec::with_capacity((4 * w * h) as usize);
        for row in bytes.chunks(row_bytes as usize) {
            pixels.extend_from_slice(&row[..(4 * w) as usize]);
        }
        if bgra {
            for p in pixels.chunks_exact_mut(4) {
                p.swap(0, 2);
            }
        }
        Ok(image::RgbaImage::from_raw(w, h, pixels).expect("w·h·4 bytes"))
    }

    /// Records `frame` into `encoder`: each object's deformation pass, then one render pass
    /// that clears `target` (a colour view of [`size`](Self::size) in the renderer's format,
    /// e.g. a window's surface texture) and draws the objects (each moved by its offset), the
    /// wireframe, the spheres and the overlay. Writes the renderer's uniforms with
    /// `queue.write_buffer` (so: one `draw` per submission); allocates nothing.
    pub fn draw(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        encoder: &mut wgpu::CommandEncoder,
        target: &wgpu::TextureView,
        frame: &Frame<'_>,
    ) -> Result<(), RenderError> {
        let _ = device;
        let n = frame.objects.len();
        if n > MAX_FRAME_OBJECTS {
            return Err(RenderError::TooMany {
                what: "objects",
                count: n,
                max: MAX_FRAME_OBJECTS,
            });
        }
        let [w, h] = self.size;
        let aspect = f64::from(w) / f64::from(h);
        let camera = &frame.camera;
        let mut cam = CameraGpu {
            view_proj: camera.view_proj(aspect).to_cols_array_2d(),
            eye: [
                camera.eye.x as f32,
                camera.eye.y as f32,
                camera.eye.z as f32,
                (2e-3 * frame.scale) as f32,
            ],
            light_dir: camera.light_dir().extend(0.0).to_array(),
            base_color: SURFACE,
            line_color: match frame.coloring {
                Coloring::Plain => LINES,
                Coloring::Displacement { .. } => [LINES[0], LINES[1], LINES[2], LINES_OVER_COLORS],
            },
            offset: [0.0; 4],
            colormap: [frame.coloring.inverse_scale(), 0.0, 0.0, 0.0],
        };
        let mut records = [0u8; UNIFORM_STRIDE as usize * (1 + MAX_FRAME_OBJECTS)];
        let camera_size = std::mem::size_of::<CameraGpu>();
        records[..camera_size].copy_from_slice(bytemuck::bytes_of(&cam));
        for (i, o) in frame.objects.iter().enumerate() {
            cam.offset = [o.offset.x as f32, o.offset.y as f32, o.offset.z as f32, 0.0];
            let at = UNIFORM_STRIDE as usize * (i + 1);
            records[at..at + camera_size].copy_from_slice(bytemuck::bytes_of(&cam));
        }
        queue.write_buffer(
            &self.uniforms,
            0,
            &records[..UNIFORM_STRIDE as usize * n + camera_size],
        );

        let radius = (SPHERE_RADIUS * frame.scale) as f32;
        let mut instances = [SphereInstance::default(); MAX_SPHERES];
        let mut count = 0;
        let wanted = frame.fingers.len() + frame.proxies.len() + frame.patch.len();
        let finger_r = |i: usize| match frame.finger_radii.get(i) {
            Some(&r) if r.is_finite() && r > 0.0 => r as f32,
            _ => radius,
        };
        let dot = radius * PATCH_DOT as f32;
        for (p, color, r) in frame
            .fingers
            .iter()
            .enumerate()
            .map(|(i, p)| (p, FINGER, finger_r(i)))
            .chain(frame.proxies.iter().map(|p| (p, PROXY, radius)))
            .chain(frame.patch.iter().map(|p| (p, PROXY, dot)))
            .filter(|(p, _, _)| p.is_finite())
        {
            if count == MAX_SPHERES {
                return Err(RenderError::TooMany {
                    what: "spheres",
                    count: wanted,
                    max: MAX_SPHERES,
                });
            }
            instances[count] = SphereInstance {
                center_radius: [p.x as f32, p.y as f32, p.z as f32, r],
                color,
            };
            count += 1;
        }
        if count > 0 {
            queue.write_buffer(
                &self.instances,
                0,
                bytemuck::cast_slice(&instances[..count]),
            );
        }
        let arrow_radius = (ARROW_RADIUS * frame.scale) as f32;
        let mut arrows = [ArrowInstance::default(); MAX_ARROWS];
        let mut n_arrows = 0;
        for a in frame.arrows {
            let v = a.force_n * a.m_per_n;
            let len = v.length();
            if !(a.at.is_finite() && len.is_finite() && len > 0.0) {
                continue;
            }
            if n_arrows == MAX_ARROWS {
                return Err(RenderError::TooMany {
                    what: "arrows",
                    count: frame.arrows.len(),
                    max: MAX_ARROWS,
                });
            }
            let d = v / len;
            arrows[n_arrows] = ArrowInstance {
                base_len: [a.at.x as f32, a.at.y as f32, a.at.z as f32, len as f32],
                dir_radius: [d.x as f32, d.y as f32, d.z as f32, arrow_radius],
                color: ARROW,
            };
            n_arrows += 1;
        }
        if n_arrows > 0 {
            queue.write_buffer(
                &self.arrow_instances,
                0,
                bytemuck::cast_slice(&arrows[..n_arrows]),
            );
        }
        if let Some(o) = frame.overlay {
            o.prepare(queue, self.size);
        }
        if let Some(o) = frame.legend {
            o.prepare(queue, self.size);
        }
        for o in frame.objects.iter().filter(|o| !o.deformed) {
            o.deformer.encode(encoder);
        }

        let (view, resolve_target, store) = match &self.attachments.msaa {
            Some(msaa) => (msaa, Some(target), wgpu::StoreOp::Discard),
            None => (target, None, wgpu::StoreOp::Store),
        };
        let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
            label: Some("touchfem render"),
            color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                view,
                depth_slice: None,
                resolve_target,
                ops: wgpu::Operations {
                    load: wgpu::LoadOp::Clear(BACKGROUND),
                    store,
                },
            })],
            depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                view: &self.attachments.depth,
                depth_ops: Some(wgpu::Operations {
                    load: wgpu::LoadOp::Clear(1.0),
                    store: wgpu::StoreOp::Discard,
                }),
                stencil_ops: None,
            }),
            timestamp_writes: None,
            occlusion_query_set: None,
            multiview_mask: None,
        });
        let record = |i: usize| (UNIFORM_STRIDE * (i as u64 + 1)) as u32;
        for (i, o) in frame.objects.iter().enumerate() {
            pass.set_bind_group(0, &self.bind_group, &[record(i)]);
            pass.set_vertex_buffer(0, o.deformer.vertex_buffer().slice(..));
            pass.set_index_buffer(
                o.deformer.index_buffer().slice(..),
                wgpu::IndexFormat::Uint32,
            );
            // Triangles without a crease (first) skip the per-pixel facet normal: most of a
            // software rasteriser's fragment cost on a large organ.
            let (smooth, all) = (3 * o.deformer.smooth_triangles(), o.deformer.index_count());
            for (pipeline, range) in [
                (&self.surface_smooth, 0..smooth),
                (&self.surface, smooth..all),
            ] {
                if !range.is_empty() {
                    pass.set_pipeline(pipeline);
                    pass.draw_indexed(range, 0, 0..1);
                }
            }
        }
        // The wireframe where asked, a closed slit's line always (its own colour, over it).
        for (pipeline, slit) in [(&self.lines, false), (&self.slit, true)] {
            if !slit && !frame.wireframe {
                continue;
            }
            pass.set_pipeline(pipeline);
            for (i, o) in frame.objects.iter().enumerate() {
                let Some((buf, range)) = o.edges.and_then(|e| e.lines(slit)) else {
                    continue;
                };
                pass.set_bind_group(0, &self.bind_group, &[record(i)]);
                pass.set_vertex_buffer(0, o.deformer.vertex_buffer().slice(..));
                pass.set_index_buffer(buf.slice(..), wgpu::IndexFormat::Uint32);
                pass.draw_indexed(range, 0, 0..1);
            }
        }
        if count > 0 {
            let n = count as u32;
            pass.set_bind_group(0, &self.bind_group, &[0]);
            pass.set_vertex_buffer(0, self.sphere_vertices.slice(..));
            pass.set_vertex_buffer(1, self.instances.slice(..));
            pass.set_index_buffer(self.sphere_indices.slice(..), wgpu::IndexFormat::Uint16);
            pass.set_pipeline(&self.sphere);
            pass.draw_indexed(0..self.sphere_index_count, 0, 0..n);
            pass.set_pipeline(&self.sphere_hidden);
            pass.draw_indexed(0..self.sphere_index_count, 0, 0..n);
        }
        if n_arrows > 0 {
            let n = n_arrows as u32;
            pass.set_bind_group(0, &self.bind_group, &[0]);
            pass.set_vertex_buffer(0, self.arrow_vertices.slice(..));
            pass.set_vertex_buffer(1, self.arrow_instances.slice(..));
            pass.set_index_buffer(self.arrow_indices.slice(..), wgpu::IndexFormat::Uint16);
            pass.set_pipeline(&self.arrow);
            pass.draw_indexed(0..self.arrow_index_count, 0, 0..n);
            pass.set_pipeline(&self.arrow_hidden);
            pass.draw_indexed(0..self.arrow_index_count, 0, 0..n);
        }
        if let Some(o) = frame.overlay {
            o.record(&mut pass);
        }
        if let Some(o) = frame.legend {
            o.record(&mut pass);
        }
        Ok(())
    }
}

/// An error unless `size` is a non-empty image the device can hold.
fn check_size(device: &wgpu::Device, size: [u32; 2]) -> Result<(), RenderError> {
    let max = device.limits().max_texture_dimension_2d;
    if size[0] == 0 || size[1] == 0 || size[0] > max || size[1] > max {
        return Err(RenderError::BadSize(size, max));
    }
    Ok(())
}

/// The attachments of `size` for `options`.
fn attachments(device: &wgpu::Device, size: [u32; 2], options: RenderOptions) -> Attachments {
    let view = |label, format| {
        let usage = wgpu::TextureUsages::RENDER_ATTACHMENT;
        texture_2d(device, label, size, options.samples, format, usage)
            .create_view(&Default::default())
    };
    Attachments {
        msaa: (options.samples > 1).then(|| view("touchfem msaa", options.format)),
        depth: view("touchfem depth", DEPTH_FORMAT),
    }
}

/// A 2D texture of `size` pixels with `samples` samples a pixel.
fn texture_2d(
    device: &wgpu::Device,
    label: &str,
    size: [u32; 2],
    samples: u32,
    format: wgpu::TextureFormat,
    usage: wgpu::TextureUsages,
) -> wgpu::Texture {
    device.create_texture(&wgpu::TextureDescriptor {
        label: Some(label),
        size: wgpu::Extent3d {
            width: size[0],
            height: size[1],
            depth_or_array_layers: 1,
        },
        mip_level_count: 1,
        sample_count: samples,
        dimension: wgpu::TextureDimension::D2,
        format,
        usage,
        view_formats: &[],
    })
}

/// A single-sample 2D texture of `size` pixels in `format`: the target a caller hands
/// [`Renderer::render_frame`] (with [`wgpu::TextureUsages::RENDER_ATTACHMENT`]).
pub fn frame_texture(
    device: &wgpu::Device,
    label: &str,
    size: [u32; 2],
    format: wgpu::TextureFormat,
    usage: wgpu::TextureUsages,
) -> wgpu::Texture {
    texture_2d(device, label, size, 1, format, usage)
}

/// The depth test of a pipeline drawn into the renderer's pass.
fn depth_state(write: bool, compare: wgpu::CompareFunction) -> wgpu::DepthStencilState {
    wgpu::DepthStencilState {
        format: DEPTH_FORMAT,
        depth_write_enabled: Some(write),
        depth_compare: Some(compare),
        stencil: Default::default(),
        bias: Default::default(),
    }
}

/// A uniform buffer's bind-group layout entry (`dynamic`: bound at a dynamic offset).
fn uniform_layout(
    binding: u32,
    visibility: wgpu::ShaderStages,
    dynamic: bool,
    min_size: Option<wgpu::BufferSize>,
) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Uniform,
            has_dynamic_offset: dynamic,
            min_binding_size: min_size,
        },
        count: None,
    }
}

/// `samples` samples a pixel, every sample written.
fn multisample(samples: u32) -> wgpu::MultisampleState {
    wgpu::MultisampleState {
        count: samples,
        ..Default::default()
    }
}

/// Axis-aligned bounds of `pts`.
#[cfg(feature = "png")]
fn bounds(pts: &[DVec3]) -> (DVec3, DVec3) {
    pts.iter().fold(
        (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
        |(lo, hi), p| (lo.min(*p), hi.max(*p)),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn wireframe_by_default_follows_the_edge_density() {
        // 640×480 = 307 200 px: up to 12 800 edges, 8 533 triangles.
        assert!(wireframe_by_default(8_533, [640, 480]));
        assert!(!wireframe_by_default(8_534, [640, 480]));
        // The 45k-node organ (20 172 triangles): off at 640×480, on at 1920×1080.
        assert!(!wireframe_by_default(20_172, [640, 480]));
        assert!(wireframe_by_default(20_172, [1920, 1080]));
        // The paper's cube (192 triangles) even in a small window.
        assert!(wireframe_by_default(192, [160, 120]));
    }

    #[test]
    fn camera_sees_the_whole_box() {
        let (min, max) = (DVec3::ZERO, DVec3::splat(0.03));
        let cam = Camera::framing(min, max, 4.0 / 3.0);
        let vp = cam.view_proj(4.0 / 3.0);
        for i in 0..8 {
            let p = DVec3::new(
                if i & 1 == 0 { 0.0 } else { 0.03 },
                if i & 2 == 0 { 0.0 } else { 0.03 },
                if i & 4 == 0 { 0.0 } else { 0.03 },
            );
            let c = vp * p.as_vec3().extend(1.0);
            let n = c.truncate() / c.w;
            assert!(n.x.abs() < 1.0 && n.y.abs() < 1.0, "corner {p} at {n}");
            assert!(n.z > 0.0 && n.z < 1.0, "corner {p} depth {}", n.z);
        }
    }
}
