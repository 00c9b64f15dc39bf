//! The [`Renderer`]'s pipelines and fixed buffers, built once by [`Renderer::with_options`],
//! and the marker meshes (spheres and arrows).

use wgpu::util::DeviceExt;

use super::{
    attachments, check_size, depth_state, legend, multisample, uniform_layout, ArrowInstance,
    CameraGpu, RenderError, RenderOptions, Renderer, SphereInstance, MAX_ARROWS, MAX_FRAME_OBJECTS,
    MAX_SPHERES, RENDER_WGSL, UNIFORM_STRIDE,
};
use crate::input::Vertex;

impl Renderer {
    /// Builds the pipelines for `size` (width, height), `options.samples` MSAA samples and
    /// colour target `options.format`.
    pub fn with_options(
        device: &wgpu::Device,
        size: [u32; 2],
        options: RenderOptions,
    ) -> Result<Renderer, RenderError> {
        check_size(device, size)?;
        if !matches!(options.samples, 1 | 4) {
            return Err(RenderError::Options(format!(
                "{} samples (1 or 4 are supported)",
                options.samples
            )));
        }
        if options.format.is_depth_stencil_format() || options.format.is_compressed() {
            return Err(RenderError::Options(format!(
                "{:?} is not a colour target format",
                options.format
            )));
        }
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("touchfem render.wgsl"),
            source: wgpu::ShaderSource::Wgsl(RENDER_WGSL.into()),
        });
        let camera_size = std::mem::size_of::<CameraGpu>() as u64;
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("touchfem camera"),
            entries: &[
                uniform_layout(
                    0,
                    wgpu::ShaderStages::VERTEX_FRAGMENT,
                    true,
                    wgpu::BufferSize::new(camera_size),
                ),
                uniform_layout(
                    1,
                    wgpu::ShaderStages::FRAGMENT,
                    false,
                    wgpu::BufferSize::new(16 * legend::LUT_LEN as u64),
                ),
            ],
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
        let arrow_attrs = wgpu::vertex_attr_array![0 => Float32x4, 1 => Float32x3];
        let arrow_instance_attrs =
            wgpu::vertex_attr_array![2 => Float32x4, 3 => Float32x4, 4 => Float32x4];
        let arrow_buffers = [
            Some(wgpu::VertexBufferLayout {
                array_stride: 28,
                step_mode: wgpu::VertexStepMode::Vertex,
                attributes: &arrow_attrs,
            }),
            Some(wgpu::VertexBufferLayout {
                array_stride: std::mem::size_of::<ArrowInstance>() as u64,
                step_mode: wgpu::VertexStepMode::Instance,
                attributes: &arrow_instance_attrs,
            }),
        ];
        let surface_buffers = [Some(Vertex::layout())];
        let pipeline = |label: &str,
                        vs: &str,
                        fs: &str,
                        buffers: &[Option<wgpu::VertexBufferLayout<'_>>],
                        topology: wgpu::PrimitiveTopology,
                        cull_mode: Option<wgpu::Face>,
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
                    cull_mode,
                    ..Default::default()
                },
                depth_stencil: Some(depth_state(depth_write, compare)),
                multisample: multisample(options.samples),
                fragment: Some(wgpu::FragmentState {
                    module: &module,
                    entry_point: Some(fs),
                    compilation_options: Default::default(),
                    targets: &[Some(wgpu::ColorTargetState {
                        format: options.format,
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
        let surface_with = |label, fs| {
            pipeline(
                label,
                "vs_surface",
                fs,
                &surface_buffers,
                T::TriangleList,
                // A tet mesh's boundary is closed and counter-clockwise seen from outside: its
                // back faces are hidden anyway (culling them saves their fragments on a CPU
                // rasteriser).
                Some(wgpu::Face::Back),
                true,
                C::Less,
                None,
            )
        };
        let surface = surface_with("touchfem surface", "fs_surface");
        let surface_smooth = surface_with("touchfem surface (no creases)", "fs_surface_smooth");
        let lines = pipeline(
            "touchfem wireframe",
            "vs_line",
            "fs_line",
            &surface_buffers,
            T::LineList,
            None,
            false,
            C::LessEqual,
            Some(wgpu::BlendState::ALPHA_BLENDING),
        );
        let slit = pipeline(
            "touchfem slit",
            "vs_line",
            "fs_slit",
            &surface_buffers,
            T::LineList,
            None,
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
            None,
            true,
            C::Less,
            Some(wgpu::BlendState::ALPHA_BLENDING),
        );
        let sphere_hidden = pipeline(
            "touchfem hidden spheres",
            "vs_sphere",
            "fs_sphere_hidden",
            &sphere_buffers,
            T::TriangleList,
            None,
            false,
            C::Greater,
            Some(wgpu::BlendState::ALPHA_BLENDING),
        );
        let arrow = pipeline(
            "touchfem arrows",
            "vs_arrow",
            "fs_sphere",
            &arrow_buffers,
            T::TriangleList,
            None,
            true,
            C::Less,
            None,
        );
        let arrow_hidden = pipeline(
            "touchfem hidden arrows",
            "vs_arrow",
            "fs_sphere_hidden",
            &arrow_buffers,
            T::TriangleList,
            None,
            false,
            C::Greater,
            Some(wgpu::BlendState::ALPHA_BLENDING),
        );
        let (av, ai) = arrow_mesh(16);
        let (sv, si) = uv_sphere(12, 20);
        let uniforms = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("touchfem camera"),
            size: UNIFORM_STRIDE * (1 + MAX_FRAME_OBJECTS as u64),
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let lut = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("touchfem colour map"),
            contents: bytemuck::cast_slice(&legend::colormap_lut()),
            usage: wgpu::BufferUsages::UNIFORM,
        });
        let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("touchfem camera"),
            layout: &layout,
            entries: &[
                wgpu::BindGroupEntry {
                    binding: 0,
                    resource: wgpu::BindingResource::Buffer(wgpu::BufferBinding {
                        buffer: &uniforms,
                        offset: 0,
                        size: wgpu::BufferSize::new(camera_size),
                    }),
                },
                wgpu::BindGroupEntry {
                    binding: 1,
                    resource: lut.as_entire_binding(),
                },
            ],
        });
        let instances = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("touchfem sphere instances"),
            size: (MAX_SPHERES * std::mem::size_of::<SphereInstance>()) as u64,
            usage: wgpu::BufferUsages::VERTEX | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        Ok(Renderer {
            size,
            options,
            surface,
            surface_smooth,
            lines,
            slit,
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
            arrow,
            arrow_hidden,
            arrow_vertices: device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("touchfem arrow vertices"),
                contents: bytemuck::cast_slice(&av),
                usage: wgpu::BufferUsages::VERTEX,
            }),
            arrow_indices: device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                label: Some("touchfem arrow indices"),
                contents: bytemuck::cast_slice(&ai),
                usage: wgpu::BufferUsages::INDEX,
            }),
            arrow_index_count: ai.len() as u32,
            arrow_instances: device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("touchfem arrow instances"),
                size: (MAX_ARROWS * std::mem::size_of::<ArrowInstance>()) as u64,
                usage: wgpu::BufferUsages::VERTEX | wgpu::BufferUsages::COPY_DST,
                mapped_at_creation: false,
            }),
            uniforms,
            instances,
            bind_group,
            attachments: attachments(device, size, options),
            offscreen: std::sync::Mutex::new(()),
        })
    }
}

/// A unit arrow along +z for `vs_arrow`: per vertex `[x, y, a, b]` (across, and along =
/// a·length + b·head) and its normal `[nx, ny, nz]` in the arrow's frame; u16 indices. A
/// shaft of radius 1 with a base cap, and a cone head of radius 2.5.
fn arrow_mesh(slices: u16) -> (Vec<[f32; 7]>, Vec<u16>) {
    let mut v: Vec<[f32; 7]> = Vec::new();
    let mut idx: Vec<u16> = Vec::new();
    let ring = |v: &mut Vec<[f32; 7]>, r: f32, a: f32, b: f32, nz: f32| -> u16 {
        let start = v.len() as u16;
        let k = (1.0 + nz * nz).sqrt();
        for j in 0..slices {
            let ph = std::f32::consts::TAU * f32::from(j) / f32::from(slices);
            let (s, c) = ph.sin_cos();
            v.push([r * c, r * s, a, b, c / k, s / k, nz / k]);
        }
        start
    };
    let quad = |idx: &mut Vec<u16>, lo: u16, hi: u16| {
        for j in 0..slices {
            let j1 = (j + 1) % slices;
            idx.extend_from_slice(&[lo + j, lo + j1, hi + j, hi + j, lo + j1, hi + j1]);
        }
    };
    // Shaft: from along 0 to length − head.
    let s0 = ring(&mut v, 1.0, 0.0, 0.0, 0.0);
    let s1 = ring(&mut v, 1.0, 1.0, -1.0, 0.0);
    quad(&mut idx, s0, s1);
    // Base cap.
    let centre = v.len() as u16;
    v.push([0.0, 0.0, 0.0, 0.0, 0.0, 0.0, -1.0]);
    let cap = v.len() as u16;
    for j in 0..slices {
        let ph = std::f32::consts::TAU * f32::from(j) / f32::from(slices);
        v.push([ph.cos(), ph.sin(), 0.0, 0.0, 0.0, 0.0, -1.0]);
    }
    for j in 0..slices {
        idx.extend_from_slice(&[centre, cap + (j + 1) % slices, cap + j]);
    }
    // Head: the underside (a disc of radius 2.5) and the cone (slope 2.5 : 4).
    let hc = v.len() as u16;
    v.push([0.0, 0.0, 1.0, -1.0, 0.0, 0.0, -1.0]);
    let under = v.len() as u16;
    for j in 0..slices {
        let ph = std::f32::consts::TAU * f32::from(j) / f32::from(slices);
        v.push([2.5 * ph.cos(), 2.5 * ph.sin(), 1.0, -1.0, 0.0, 0.0, -1.0]);
    }
    for j in 0..slices {
        idx.extend_from_slice(&[hc, under + (j + 1) % slices, under + j]);
    }
    let c0 = ring(&mut v, 2.5, 1.0, -1.0, 2.5 / 4.0);
    let c1 = ring(&mut v, 0.0, 1.0, 0.0, 2.5 / 4.0);
    quad(&mut idx, c0, c1);
    (v, idx)
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
