//! Embedding `touchfem::gpu::Deformer` in your own wgpu renderer.
//!
//! The host application owns the device, the queue, the encoder and the render pipeline; the
//! deformer only records its compute pass into the host's encoder and exposes a vertex buffer
//! and an index buffer to draw. This example renders the paper's cube pushed 5 mm down at the
//! top centre with flat shading, headless, and writes `target/embed.png` (or the path given as
//! the first argument).
//!
//! ```sh
//! WGPU_BACKEND=vulkan cargo run --example embed -- /tmp/embed.png
//! ```
//!
//! No argument, more than one, or an option: the usage on stderr, exit status 2.

use glam::{DVec3, Mat4, Vec3};
use touchfem::compliance::{Compliance, Selection};
use touchfem::gpu::{Deformer, DeformerOptions, Vertex};
use touchfem::mesh::cube;
use touchfem::wgpu; // the same wgpu version as the deformer's

const SHADER: &str = r#"
@group(0) @binding(0) var<uniform> view_proj: mat4x4<f32>;

struct Out {
    @builtin(position) clip: vec4<f32>,
    @location(0) world: vec3<f32>,
}

@vertex
fn vs(@location(0) pos: vec4<f32>) -> Out {
    return Out(view_proj * vec4<f32>(pos.xyz, 1.0), pos.xyz);
}

@fragment
fn fs(in: Out) -> @location(0) vec4<f32> {
    // Flat shading from screen-space derivatives.
    let n = normalize(cross(dpdx(in.world), dpdy(in.world)));
    let light = normalize(vec3<f32>(-0.3, -0.6, 1.0));
    let k = 0.25 + 0.75 * abs(dot(n, light));
    return vec4<f32>(vec3<f32>(0.3, 0.6, 0.85) * k, 1.0);
}
"#;

const USAGE: &str = "usage: embed OUT.png   (renders the pressed cube headless into OUT.png)";

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().skip(1).collect();
    if args.len() != 1 || args.iter().any(|a| a.starts_with('-') || a.is_empty()) {
        eprintln!("error: expected one argument, the output PNG's path");
        eprintln!("{USAGE}");
        std::process::exit(2);
    }
    let out = args[0].clone();
    let (w, h) = (400u32, 300u32);

    // --- The host's own wgpu setup (honours WGPU_BACKEND / WGPU_ADAPTER_NAME). ---
    let instance =
        wgpu::Instance::new(wgpu::InstanceDescriptor::new_without_display_handle_from_env());
    let adapter = pollster::block_on(wgpu::util::initialize_adapter_from_env_or_default(
        &instance, None,
    ))
    .map_err(|e| format!("no GPU adapter (try WGPU_BACKEND=vulkan): {e}"))?;
    let (device, queue) = pollster::block_on(adapter.request_device(&wgpu::DeviceDescriptor {
        label: Some("embed"),
        // Optional: with immediates the deformer's short force lists need no upload.
        required_features: adapter.features() & wgpu::Features::IMMEDIATES,
        required_limits: adapter.limits(),
        ..Default::default()
    }))?;
    println!("adapter: {}", adapter.get_info().name);

    // --- The soft object: mesh, precomputed compliance, deformer. ---
    let mesh = cube();
    let c = Compliance::compute(&mesh, &Selection::default())?;
    let mut deformer = Deformer::new(
        &device,
        &queue,
        &c,
        &mesh.nodes,
        &mesh.surface,
        &DeformerOptions::default(),
    )?;
    println!(
        "deformer: {:?} layout, immediates: {}",
        deformer.stats().storage,
        deformer.stats().uses_immediates
    );
    // Push the top-centre node 5 mm down: F = L_ii⁻¹·u (eq. 7).
    let top = DVec3::new(0.015, 0.015, 0.03);
    let node = (0..mesh.nodes.len())
        .min_by(|&a, &b| {
            let (da, db) = (mesh.nodes[a].distance(top), mesh.nodes[b].distance(top));
            da.total_cmp(&db)
        })
        .expect("nodes") as u32;
    let col = c.col_of(node).expect("touchable");
    let force = c.diag_inv(col) * DVec3::new(0.0, 0.0, -5e-3);
    deformer.set_forces(&queue, &[(col as u32, force.as_vec3().to_array())])?;

    // --- The host's own pipeline, drawing the deformer's vertex buffer. ---
    let view_proj = glam::camera::rh::proj::directx::perspective(
        35f32.to_radians(),
        w as f32 / h as f32,
        0.01,
        1.0,
    ) * glam::camera::rh::view::look_at_mat4(
        Vec3::new(-0.04, -0.07, 0.07),
        Vec3::splat(0.015),
        Vec3::Z,
    );
    let uniform = wgpu::util::DeviceExt::create_buffer_init(
        &device,
        &wgpu::util::BufferInitDescriptor {
            label: Some("view_proj"),
            contents: bytemuck::cast_slice(&Mat4::to_cols_array(&view_proj)),
            usage: wgpu::BufferUsages::UNIFORM,
        },
    );
    let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
        label: Some("embed"),
        source: wgpu::ShaderSource::Wgsl(SHADER.into()),
    });
    let pipeline = device.create_render_pipeline(&wgpu::RenderPipelineDescriptor {
        label: Some("embed"),
        layout: None,
        vertex: wgpu::VertexState {
            module: &module,
            entry_point: Some("vs"),
            compilation_options: Default::default(),
            // Position (location 0) and normal (location 1), 32-byte stride.
            buffers: &[Some(Vertex::layout())],
        },
        primitive: Default::default(),
        depth_stencil: Some(wgpu::DepthStencilState {
            format: wgpu::TextureFormat::Depth32Float,
            depth_write_enabled: Some(true),
            depth_compare: Some(wgpu::CompareFunction::Less),
            stencil: Default::default(),
            bias: Default::default(),
        }),
        multisample: Default::default(),
        fragment: Some(wgpu::FragmentState {
            module: &module,
            entry_point: Some("fs"),
            compilation_options: Default::default(),
            targets: &[Some(wgpu::TextureFormat::Rgba8UnormSrgb.into())],
        }),
        multiview_mask: None,
        cache: None,
    });
    let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some("embed"),
        layout: &pipeline.get_bind_group_layout(0),
        entries: &[wgpu::BindGroupEntry {
            binding: 0,
            resource: uniform.as_entire_binding(),
        }],
    });
    let extent = wgpu::Extent3d {
        width: w,
        height: h,
        depth_or_array_layers: 1,
    };
    let target = |format, usage| {
        device.create_texture(&wgpu::TextureDescriptor {
            label: None,
            size: extent,
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format,
            usage,
            view_formats: &[],
        })
    };
    let color = target(
        wgpu::TextureFormat::Rgba8UnormSrgb,
        wgpu::TextureUsages::RENDER_ATTACHMENT | wgpu::TextureUsages::COPY_SRC,
    );
    let depth = target(
        wgpu::TextureFormat::Depth32Float,
        wgpu::TextureUsages::RENDER_ATTACHMENT,
    );
    let row =
        (4 * w).div_ceil(wgpu::COPY_BYTES_PER_ROW_ALIGNMENT) * wgpu::COPY_BYTES_PER_ROW_ALIGNMENT;
    let readback = device.create_buffer(&wgpu::BufferDescriptor {
        label: Some("readback"),
        size: u64::from(row * h),
        usage: wgpu::BufferUsages::COPY_DST | wgpu::BufferUsages::MAP_READ,
        mapped_at_creation: false,
    });

    // --- One frame: the deformer's compute pass, then our render pass, one submission. ---
    let mut encoder = device.create_command_encoder(&Default::default());
    deformer.encode(&mut encoder);
    {
        let color_view = color.create_view(&Default::default());
        let depth_view = depth.create_view(&Default::default());
        let mut pass = encoder.begin_render_pass(&wgpu::RenderPassDescriptor {
            label: Some("embed"),
            color_attachments: &[Some(wgpu::RenderPassColorAttachment {
                view: &color_view,
                depth_slice: None,
                resolve_target: None,
                ops: wgpu::Operations {
                    load: wgpu::LoadOp::Clear(wgpu::Color::WHITE),
                    store: wgpu::StoreOp::Store,
                },
            })],
            depth_stencil_attachment: Some(wgpu::RenderPassDepthStencilAttachment {
                view: &depth_view,
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
        pass.set_pipeline(&pipeline);
        pass.set_bind_group(0, &bind_group, &[]);
        pass.set_vertex_buffer(0, deformer.vertex_buffer().slice(..));
        pass.set_index_buffer(deformer.index_buffer().slice(..), wgpu::IndexFormat::Uint32);
        pass.draw_indexed(0..deformer.index_count(), 0, 0..1);
    }
    encoder.copy_texture_to_buffer(
        color.as_image_copy(),
        wgpu::TexelCopyBufferInfo {
            buffer: &readback,
            layout: wgpu::TexelCopyBufferLayout {
                offset: 0,
                bytes_per_row: Some(row),
                rows_per_image: None,
            },
        },
        extent,
    );
    queue.submit([encoder.finish()]);

    readback.map_async(wgpu::MapMode::Read, .., |r| r.expect("map readback"));
    device.poll(wgpu::PollType::wait_indefinitely())?;
    let data = readback.get_mapped_range(..)?;
    let mut pixels = Vec::with_capacity((4 * w * h) as usize);
    for r in data.chunks(row as usize) {
        pixels.extend_from_slice(&r[..(4 * w) as usize]);
    }
    image::RgbaImage::from_raw(w, h, pixels)
        .ok_or("image size")?
        .save(&out)?;
    println!("wrote {out}");
    Ok(())
}
