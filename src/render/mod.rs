//! Offscreen rendering of a deformed object to an image or a PNG file.
//!
//! The surface comes from a [`Deformer`] (the GPU pass: positions and normals never visit the
//! CPU), lit with Blinn-Phong from a fixed key light, with a depth buffer and 4× MSAA. The
//! camera frames the rest bounding box from a fixed 3/4 view ([`Camera::framing`]). The finger
//! tip (red) and the god-object (blue) are small spheres, as in the paper's Figure 1; where the
//! surface hides them they show through as a ghost. The wireframe overlay draws the surface
//! edges.
//!
//! ```no_run
//! # fn main() -> Result<(), touchfem::render::RenderError> {
//! use touchfem::{compliance::{Compliance, Selection}, mesh::cube, render};
//! let mesh = cube();
//! let c = Compliance::compute(&mesh, &Selection::default()).unwrap();
//! let scene = render::Scene::at_rest(&mesh, &c);
//! render::render_png("cube.png".as_ref(), [640, 480], &scene)?;
//! # Ok(()) }
//! ```

mod camera;

pub use camera::{Camera, VIEW_DIR};

use bytemuck::{Pod, Zeroable};
use glam::DVec3;
use std::path::Path;
use thiserror::Error;
use wgpu::util::DeviceExt;

use crate::compliance::Compliance;
use crate::gpu::{Deformer, DeformerOptions, Gpu, GpuError, Vertex};
use crate::mesh::Mesh;

/// The WGSL source of the renderer (`shaders/render.wgsl`).
pub const RENDER_WGSL: &str = include_str!("../../shaders/render.wgsl");

/// Colour format of the rendered image (8-bit sRGB, straight to PNG).
pub const COLOR_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Rgba8UnormSrgb;
/// Depth format.
pub const DEPTH_FORMAT: wgpu::TextureFormat = wgpu::TextureFormat::Depth32Float;
/// MSAA sample count.
pub const SAMPLES: u32 = 4;
/// Sphere radius as a fraction of the rest bounding box's diagonal.
pub const SPHERE_RADIUS: f64 = 0.035;

/// Background colour (linear RGB).
const BACKGROUND: wgpu::Color = wgpu::Color {
    r: 0.82,
    g: 0.85,
    b: 0.90,
    a: 1.0,
};
const SURFACE: [f32; 4] = [0.85, 0.50, 0.28, 1.0];
const LINES: [f32; 4] = [0.06, 0.05, 0.05, 1.0];
const FINGER: [f32; 4] = [0.80, 0.08, 0.06, 1.0];
const PROXY: [f32; 4] = [0.10, 0.30, 0.85, 1.0];

/// Errors while rendering.
#[derive(Debug, Error)]
pub enum RenderError {
    /// The GPU side failed (no adapter, bad forces, …).
    #[error(transparent)]
    Gpu(#[from] GpuError),
    /// Writing the PNG failed.
    #[error("cannot write image: {0}")]
    Image(#[from] image::ImageError),
    /// The image size is zero or beyond the device's texture limit.
    #[error("image size {0:?} is not supported (1 ..= {1} per side)")]
    BadSize([u32; 2], u32),
}

/// What to draw: the object under a force boundary condition, the finger and the god-object.
#[derive(Clone, Copy, Debug)]
pub struct Scene<'a> {
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
    /// Overlay the surface edges.
    pub wireframe: bool,
}

impl<'a> Scene<'a> {
    /// The object at rest, no spheres, no wireframe.
    pub fn at_rest(mesh: &'a Mesh, compliance: &'a Compliance) -> Scene<'a> {
        Scene {
            mesh,
            compliance,
            forces: &[],
            finger: None,
            proxy: None,
            wireframe: false,
        }
    }
}

/// Renders `scene` at `size` (width, height) on a headless GPU chosen by the environment
/// (`WGPU_BACKEND`, `WGPU_ADAPTER_NAME`) and writes a PNG to `path`.
pub fn render_png(path: &Path, size: [u32; 2], scene: &Scene<'_>) -> Result<(), RenderError> {
    render_image(size, scene)?.save_with_format(path, image::ImageFormat::Png)?;
    Ok(())
}

/// Renders `scene` at `size` on a headless GPU chosen by the environment.
pub fn render_image(size: [u32; 2], scene: &Scene<'_>) -> Result<image::RgbaImage, RenderError> {
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
}

#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct SphereInstance {
    center_radius: [f32; 4],
    color: [f32; 4],
}

/// A reusable offscreen renderer for one image size on one device.
#[derive(Debug)]
pub struct Renderer {
    size: [u32; 2],
    layout: wgpu::BindGroupLayout,
    surface: wgpu::RenderPipeline,
    lines: wgpu::RenderPipeline,
    sphere: wgpu::RenderPipeline,
    sphere_hidden: wgpu::RenderPipeline,
    sphere_vertices: wgpu::Buffer,
    sphere_indices: wgpu::Buffer,
    sphere_index_count: u32,
}

impl Renderer {
    /// Builds the pipelines for images of `size` (width, height).
    pub fn new(device: &wgpu::Device, size: [u32; 2]) -> Result<Renderer, RenderError> {
        let max = device.limits().max_texture_dimension_2d;
        if size[0] == 0 || size[1] == 0 || size[0] > max || size[1] > max {
            return Err(RenderError::BadSize(size, max));
        }
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("touchfem render.wgsl"),
            source: wgpu::ShaderSource::Wgsl(RENDER_WGSL.into()),
        });
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("touchfem camera"),
            entries: &[wgpu::BindGroupLayoutEntry {
                binding: 0,
                visibility: wgpu::ShaderStages::VERTEX_FRAGMENT,
                ty: wgpu::BindingType::Buffer {
                    ty: wgpu::BufferBindingType::Uniform,
                    has_dynamic_offset: false,
                    min_binding_size: None,
                },
                count: None,
            }],
        });
        let pl = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("touchfem render"),
            bind_group_layouts: &[Some(&layout)],
            immediate_size: 0,
        });
        let sphere_attrs = wgpu::vertex_attr_array![0 => Float32x3];
        let instance_attrs = wgpu::vertex_attr_array![2 => Float32x4, 3 => Float32x4];
        let sphere_buffers = [
            Some(wgpu::VertexBufferLayout {
                array_stride: 12,
                step_mode: wgpu::VertexStepMode::Vertex,
                attributes: &sphere_attrs,
            }),
            Some(wgpu::VertexBufferLayout {
                array_stride: std::mem::size_of::<SphereInstance>() as u64,
                step_mode: wgpu::VertexStepMode::Instance,
                attributes: &instance_attrs,
            }),
        ];
        let surface_buffers = [Some(Vertex::layout())];
        let pipeline = |label: &str,
                        vs: &str,
                        fs: &str,
                        buffers: &[Option<wgpu::VertexBufferLayout<'_>>],
                        topology: wgpu::PrimitiveTopology,
                        depth_write: bool,
                        compare: wgpu::CompareFunction,
                        blend: Option<wgpu::BlendState>| {
            device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
                label: Some(label),
                layout: Some(&pl),
                vertex: wgpu::VertexState {
                    module: &module,
                    entry_point: Some(vs),
                    compilation_options: Default::default(),
                    buffers,
                },
                primitive: wgpu::PrimitiveState {
                    topology,
                    ..Default::default()
                },
                depth_stencil: Some(wgpu::DepthStencilState {
                    format: DEPTH_FORMAT,
                    depth_write_enabled: Some(depth_write),
                    depth_compare: Some(compare),
                    stencil: Default::default(),
                    bias: Default::default(),
                }),
                multisample: wgpu::MultisampleState {
                    count: SAMPLES,
                    ..Default::default()
                },
                fragment: Some(wgpu::FragmentState {
                    module: &module,
                    entry_point: Some(fs),
                    compilation_options: Default::default(),
                    targets: &[Some(wgpu::ColorTargetState {
                        format: COLOR_FORMAT,
                        blend,
                        write_mask: wgpu::ColorWrites::ALL,
                    })],
                }),
                multiview_mask: None,
                cache: None,
            })
        };
        use wgpu::CompareFunction as C;
        use wgpu::PrimitiveTopology as T;
        let surface = pipeline(
            "touchfem surface",
            "vs_surface",
            "fs_surface",
            &surface_buffers,
            T::TriangleList,
            true,
            C::Less,
            None,
        );
        let lines = pipeline(
            "touchfem wireframe",
            "vs_line",
            "fs_line",
            &surface_buffers,
            T::LineList,
            false,
            C::LessEqual,
            None,
        );
        let sphere = pipeline(
            "touchfem spheres",
            "vs_sphere",
            "fs_sphere",
            &sphere_buffers,
            T::TriangleList,
            true,
            C::Less,
            None,
        );
        let sphere_hidden = pipeline(
            "touchfem hidden spheres",
            "vs_sphere",
            "fs_sphere_hidden",
            &sphere_buffers,
            T::TriangleList,
            false,
            C::Greater,
            Some(wgpu::BlendState::ALPHA_BLENDING),
        );
        let (sv, si) = uv_sphere(12, 20);
        Ok(Renderer {
            size,
            layout,
            surface,
            lines,
            sphere,
            sphere_hidden,
            sphere_vertices: device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("touchfem sphere vertices"),
                contents: bytemuck::cast_slice(&sv),
                usage: wgpu::BufferUsages::VERTEX,
            }),
            sphere_indices: device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("touchfem sphere indices"),
                contents: bytemuck::cast_slice(&si),
                usage: wgpu::BufferUsages::INDEX,
            }),
            sphere_index_count: si.len() as u32,
        })
    }

    /// Image size (width, height).
    pub fn size(&self) -> [u32; 2] {
        self.size
    }

    /// Renders `scene`: uploads its compliance into a [`Deformer`], runs the deformation pass
    /// and draws, all in one submission, then reads the image back.
    pub fn render(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        scene: &Scene<'_>,
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

    /// Renders with a caller-kept [`Deformer`] (built for `scene`'s mesh and compliance) whose
    /// forces the caller has already set: the visual loop's per-frame call. `scene.forces` is
    /// not used here.
    pub fn render_with(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        deformer: &Deformer,
        scene: &Scene<'_>,
    ) -> Result<image::RgbaImage, RenderError> {
        let (min, max) = bounds(&scene.mesh.nodes);
        let [w, h] = self.size;
        let aspect = f64::from(w) / f64::from(h);
        let camera = Camera::framing(min, max, aspect);
        let diag = (max - min).length();
        let cam = CameraGpu {
            view_proj: camera.view_proj(aspect).to_cols_array_2d(),
            eye: [
                camera.eye.x as f32,
                camera.eye.y as f32,
                camera.eye.z as f32,
                (2e-3 * diag) as f32,
            ],
            light_dir: camera.light_dir().extend(0.0).to_array(),
            base_color: SURFACE,
            line_color: LINES,
        };
        let cam_buf = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("touchfem camera"),
            contents: bytemuck::bytes_of(&cam),
            usage: wgpu::BufferUsages::UNIFORM,
        });
        let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("touchfem camera"),
            layout: &self.layout,
            entries: &[wgpu::BindGroupEntry {
                binding: 0,
                resource: cam_buf.as_entire_binding(),
            }],
        });
        let radius = (SPHERE_RADIUS * diag) as f32;
        let instances: Vec<SphereInstance> = [(scene.finger, FINGER), (scene.proxy, PROXY)]
            .into_iter()
            .filter_map(|(p, color)| {
                p.map(|p| SphereInstance {
                    center_radius: [p.x as f32, p.y as f32, p.z as f32, radius],
                    color,
                })
            })
            .collect();
        let instance_buf = (!instances.is_empty()).then(|| {
            device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("touchfem sphere instances"),
                contents: bytemuck::cast_slice(&instances),
                usage: wgpu::BufferUsages::VERTEX,
            })
        });
        let edges = edge_list(deformer.triangles());
        let edge_buf = (scene.wireframe && !edges.is_empty()).then(|| {
            device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("touchfem edges"),
                contents: bytemuck::cast_slice(&edges),
                usage: wgpu::BufferUsages::INDEX,
            })
        });

        let extent = wgpu::Extent3d {
            width: w,
            height: h,
            depth_or_array_layers: 1,
        };
        let texture = |label, format, samples, usage| {
            device
                .create_texture(&wgpu::TextureDescriptor {
                    label: Some(label),
                    size: extent,
                    mip_level_count: 1,
                    sample_count: samples,
                    dimension: wgpu::TextureDimension::D2,
                    format,
                    usage,
                    view_formats: &[],
                })
                .create_view(&Default::default())
        };
        let msaa = texture(
            "touchfem msaa",
            COLOR_FORMAT,
            SAMPLES,
            wgpu::TextureUsages::RENDER_ATTACHMENT,
        );
        let depth = texture(
            "touchfem depth",
            DEPTH_FORMAT,
            SAMPLES,
            wgpu::TextureUsages::RENDER_ATTACHMENT,
        );
        let resolved = device.create_texture(&wgpu::TextureDescriptor {
            label: Some("touchfem image"),
            size: extent,
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: COLOR_FORMAT,
            usage: wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC,
            view_formats: &[],
        });
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
        deformer.encode(&mut enc);
        {
            let mut pass = enc.begin_render_pass(&wgpu::RenderPassDescriptor {
                label: Some("touchfem render"),
                color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                    view: &msaa,
                    depth_slice: None,
                    resolve_target: Some(&resolved_view),
                    ops: wgpu::Operations {
                        load: wgpu::LoadOp::Clear(BACKGROUND),
                        store: wgpu::StoreOp::Discard,
                    },
                })],
                depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                    view: &depth,
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
            pass.set_bind_group(0, &bind_group, &[]);
            pass.set_pipeline(&self.surface);
            pass.set_vertex_buffer(0, deformer.vertex_buffer().slice(..));
            pass.set_index_buffer(deformer.index_buffer().slice(..), wgpu::IndexFormat::Uint32);
            pass.draw_indexed(0..deformer.index_count(), 0, 0..1);
            if let Some(edges_buf) = &edge_buf {
                pass.set_pipeline(&self.lines);
                pass.set_index_buffer(edges_buf.slice(..), wgpu::IndexFormat::Uint32);
                pass.draw_indexed(0..edges.len() as u32, 0, 0..1);
            }
            if let Some(inst) = &instance_buf {
                let n = instances.len() as u32;
                pass.set_vertex_buffer(0, self.sphere_vertices.slice(..));
                pass.set_vertex_buffer(1, inst.slice(..));
                pass.set_index_buffer(self.sphere_indices.slice(..), wgpu::IndexFormat::Uint16);
                pass.set_pipeline(&self.sphere);
                pass.draw_indexed(0..self.sphere_index_count, 0, 0..n);
                pass.set_pipeline(&self.sphere_hidden);
                pass.draw_indexed(0..self.sphere_index_count, 0, 0..n);
            }
        }
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
        let bytes = crate::gpu::map_read(device, &readback)?;
        let mut pixels = Vec::with_capacity((4 * w * h) as usize);
        for row in bytes.chunks(row_bytes as usize) {
            pixels.extend_from_slice(&row[..(4 * w) as usize]);
        }
        Ok(image::RgbaImage::from_raw(w, h, pixels).expect("w·h·4 bytes"))
    }
}

/// Axis-aligned bounds of `pts`.
fn bounds(pts: &[DVec3]) -> (DVec3, DVec3) {
    pts.iter().fold(
        (DVec3::splat(f64::INFINITY), DVec3::splat(f64::NEG_INFINITY)),
        |(lo, hi), p| (lo.min(*p), hi.max(*p)),
    )
}

/// Unique undirected edges of `tris`, as a line-list index array.
fn edge_list(tris: &[[u32; 3]]) -> Vec<u32> {
    let mut e: Vec<(u32, u32)> = tris
        .iter()
        .flat_map(|t| [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])])
        .map(|(a, b)| (a.min(b), a.max(b)))
        .collect();
    e.sort_unstable();
    e.dedup();
    e.into_iter().flat_map(|(a, b)| [a, b]).collect()
}

/// A unit UV sphere: positions (= normals) and u16 triangle indices, counter-clockwise outside.
fn uv_sphere(stacks: u16, slices: u16) -> (Vec<[f32; 3]>, Vec<u16>) {
    let mut v = Vec::new();
    for i in 0..=stacks {
        let th = std::f32::consts::PI * f32::from(i) / f32::from(stacks);
        for j in 0..=slices {
            let ph = std::f32::consts::TAU * f32::from(j) / f32::from(slices);
            v.push([th.sin() * ph.cos(), th.sin() * ph.sin(), th.cos()]);
        }
    }
    let mut idx = Vec::new();
    let row = slices + 1;
    for i in 0..stacks {
        for j in 0..slices {
            let a = i * row + j;
            let b = a + row;
            idx.extend_from_slice(&[a, b, a + 1, a + 1, b, b + 1]);
        }
    }
    (v, idx)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn edges_are_unique() {
        let e = edge_list(&[[0, 1, 2], [2, 1, 3]]);
        assert_eq!(e, vec![0, 1, 0, 2, 1, 2, 1, 3, 2, 3]);
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
