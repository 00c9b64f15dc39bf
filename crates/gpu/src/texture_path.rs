//! The texture layout of `L` (`shaders/deform_texture.wgsl`): `L`, the rest pose, the deformed
//! positions and the surface adjacency live in read-only storage textures read with
//! `textureLoad`; one dispatch for `u = L·F`, one for the normals ([`crate::surface`]'s
//! texture variant: a gather over triangle fans, one position load per neighbour). The active list's length, and the list itself when
//! short, travel as immediates where the device has them, so a one-finger frame uploads
//! nothing.
//!
//! The layout for software rasterisers. Mesa's lavapipe (llvmpipe) scalarises a storage-buffer
//! load whose address differs per invocation, lane by lane, while an image load is one vector
//! gather of four floats: on lavapipe 22.3 this path is 5–7× faster than [`crate::buffer_path`]
//! on the mouse-sized case (see the `deform` benchmark). Storage rather than sampled textures:
//! the deformed positions stay in the `GENERAL` layout between the two dispatches (no layout
//! transition each frame), and `L` loads measured faster. `L` costs a third more memory (one
//! padding float per three).

use bytemuck::{Pod, Zeroable};
use wgpu::util::DeviceExt;

use crate::bind::{
    buffer, compute_pipeline, specialised_pipeline, storage_entry, storage_texture_entry,
    uniform_entry, view,
};
use crate::context::GpuError;
use crate::input::{Shared, MAX_ACTIVE, WORKGROUP};
use crate::shaders::{deform_texture_source, IMMEDIATE_BYTES, INLINE_ACTIVE};

/// Texels per texture row (the shader's `LOG_W`).
const LOG_W: u32 = 10;
const W: u64 = 1 << LOG_W;

#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
struct FrameGpu {
    n_rows: u32,
    out_offset: u32,
    out_stride: u32,
    normal_offset: u32,
    log_h: u32,
    n_active: u32,
    l_rows: u32,
    n_vertices: u32,
}

/// Byte offset of `n_active` in [`FrameGpu`].
const N_ACTIVE_OFFSET: u64 = 20;

/// `L` and the pose in textures, and the passes that read them.
pub(super) struct TexturePath {
    layers: u32,
    /// Bytes of the `L` texture.
    l_bytes: u64,
    active: wgpu::Buffer,
    deform_group: wgpu::BindGroup,
    pos_view: wgpu::TextureView,
    /// The shader module (its `normals` entry is the normal pass's).
    module: wgpu::ShaderModule,
    /// The deformation pipeline; with immediates one per inline entry count
    /// (0..=[`INLINE_ACTIVE`]) and a last one for uploaded lists.
    deform: Vec<wgpu::ComputePipeline>,
    /// The pass parameters (`n_active` changes per frame).
    frame: wgpu::Buffer,
    /// One `[fx, fy, fz, col]` per entry (bit patterns).
    scratch: Vec<[u32; 4]>,
    /// The immediates (`shaders/active_immediate.wgsl`'s `Immediates`), if the device has
    /// them: count, inline flag, two pads, then up to [`INLINE_ACTIVE`] entries.
    immediates: Option<[u32; IMMEDIATE_WORDS]>,
    /// `L` is stored as half floats (`Rgba16Float`), divided by this power of two near
    /// max |L|; the forces are multiplied by it (1 for f32).
    force_scale: f32,
    half: bool,
}

/// 32-bit words of immediates.
const IMMEDIATE_WORDS: usize = IMMEDIATE_BYTES as usize / 4;

/// Width and height of a 2D texture holding `n` texels linearly (`W` a row).
fn extent_2d(n: u64) -> (u32, u32) {
    let n = n.max(1);
    (n.min(W) as u32, n.div_ceil(W) as u32)
}

/// A 2D texture of `n` texels from `data` (texels of the format's size), zero-padded, `W`
/// texels a row.
pub(crate) fn texture_2d(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    what: &'static str,
    format: wgpu::TextureFormat,
    usage: wgpu::TextureUsages,
    n: u64,
    data: &[u8],
) -> Result<wgpu::Texture, GpuError> {
    let max_dim = u64::from(device.limits().max_texture_dimension_2d);
    let (w, h) = extent_2d(n);
    if u64::from(h) > max_dim {
        return Err(GpuError::BufferTooLarge {
            what,
            bytes: 16 * n,
            limit: 16 * W * max_dim,
        });
    }
    let texel = format.block_copy_size(None).unwrap_or(16) as usize;
    let mut bytes = data.to_vec();
    bytes.resize(texel * w as usize * h as usize, 0);
    Ok(device.create_texture_with_data(
        queue,
        &wgpu::TextureDescriptor {
            label: Some(what),
            size: wgpu::Extent3d {
                width: w,
                height: h,
                depth_or_array_layers: 1,
            },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format,
            usage,
            view_formats: &[],
        },
        wgpu::util::TextureDataOrder::LayerMajor,
        &bytes,
    ))
}

impl TexturePath {
    pub(super) fn new(sh: &Shared<'_>) -> Result<TexturePath, GpuError> {
        let (device, queue, nr, nc) = (sh.device, sh.queue, sh.nr as u64, sh.nc as u64);
        let limits = device.limits();
        let max_dim = u64::from(limits.max_texture_dimension_2d);
        let tb = wgpu::TextureUsages::STORAGE_BINDING | wgpu::TextureUsages::COPY_DST;

        let texture_2d = |what, format, usage, n, data: &[u8]| {
            texture_2d(device, queue, what, format, usage, n, data)
        };

        // Rest pose and the deformed positions (written by `deform`, read by `normals`).
        let rgba = wgpu::TextureFormat::Rgba32Float;
        let rest_bytes: &[u8] = bytemuck::cast_slice(sh.rest_rows);
        let rest = texture_2d("touchfem rest positions", rgba, tb, nr, rest_bytes)?;
        let nv = u64::from(sh.frame.n_vertices);
        let pos = texture_2d("touchfem deformed positions", rgba, tb, nv, rest_bytes)?;

        // L: texel t = (3c + b)·R + r, W texels a row, 2^log_h rows a layer; four f32 (16
        // bytes) or, with half floats, four f16 (8 bytes) a texel.
        let texel_bytes: u64 = if sh.half { 8 } else { 16 };
        let l_format = if sh.half {
            wgpu::TextureFormat::Rgba16Float
        } else {
            rgba
        };
        let texels = 3 * nc * sh.nl as u64;
        let rows = texels.div_ceil(W).max(1);
        let cap_rows = (sh.max_chunk / (texel_bytes * W)).min(max_dim);
        if cap_rows == 0 {
            return Err(GpuError::BufferTooLarge {
                what: "one row of the L texture",
                bytes: texel_bytes * W,
                limit: sh.max_chunk,
            });
        }
        let log_h = 63 - cap_rows.leading_zeros();
        let per_layer = 1u64 << log_h;
        let layers = rows.div_ceil(per_layer);
        if layers > u64::from(limits.max_texture_array_layers) || texels > u64::from(u32::MAX) {
            return Err(GpuError::BufferTooLarge {
                what: "L as a texture array",
                bytes: texel_bytes * texels,
                limit: texel_bytes * W * per_layer * u64::from(limits.max_texture_array_layers),
            });
        }
        let (width, height) = if layers == 1 {
            (texels.clamp(1, W), rows)
        } else {
            (W, per_layer)
        };
        let l_tex = device.create_texture(&wgpu::TextureDescriptor {
            label: Some("touchfem L"),
            size: wgpu::Extent3d {
                width: width as u32,
                height: height as u32,
                depth_or_array_layers: layers as u32,
            },
            mip_level_count: 1,
            sample_count: 1,
            dimension: wgpu::TextureDimension::D2,
            format: l_format,
            usage: tb,
            view_formats: &[],
        });
        let force_scale = if sh.half { sh.l.f16_scale() } else { 1.0 };
        let layer_texels = (width * height) as usize;
        // Uploaded in bands of texture rows, each read (and rounded) straight from `L`'s
        // source, so the host holds a band, not a layer, beside wgpu's staging copy.
        const BAND_ROWS: usize = 256;
        let band_texels = BAND_ROWS.min(height as usize) * width as usize;
        let mut staging: Vec<[f32; 4]> = Vec::with_capacity(band_texels);
        let mut staging16: Vec<[u16; 4]> =
            Vec::with_capacity(if sh.half { band_texels } else { 0 });
        for k in 0..layers as usize {
            for y0 in (0..height as usize).step_by(BAND_ROWS) {
                let band_rows = BAND_ROWS.min(height as usize - y0);
                let n = band_rows * width as usize;
                let t0 = (k * layer_texels + y0 * width as usize).min(texels as usize);
                let t1 = (t0 + n).min(texels as usize);
                let values = sh.l.f32_range(3 * t0..3 * t1)?;
                let data: &[u8] = if sh.half {
                    staging16.clear();
                    staging16.extend(values.chunks_exact(3).map(|v| {
                        let h = |x: f32| half::f16::from_f32(x / force_scale).to_bits();
                        [h(v[0]), h(v[1]), h(v[2]), 0]
                    }));
                    staging16.resize(n, [0; 4]);
                    bytemuck::cast_slice(&staging16)
                } else {
                    staging.clear();
                    staging.extend(values.chunks_exact(3).map(|v| [v[0], v[1], v[2], 0.0]));
                    staging.resize(n, [0.0; 4]);
                    bytemuck::cast_slice(&staging)
                };
                queue.write_texture(
                    wgpu::TexelCopyTextureInfo {
                        texture: &l_tex,
                        mip_level: 0,
                        origin: wgpu::Origin3d {
                            x: 0,
                            y: y0 as u32,
                            z: k as u32,
                        },
                        aspect: wgpu::TextureAspect::All,
                    },
                    data,
                    wgpu::TexelCopyBufferLayout {
                        offset: 0,
                        bytes_per_row: Some(texel_bytes as u32 * width as u32),
                        rows_per_image: Some(band_rows as u32),
                    },
                    wgpu::Extent3d {
                        width: width as u32,
                        height: band_rows as u32,
                        depth_or_array_layers: 1,
                    },
                );
            }
            // Flush each layer's staging copies so that peak memory stays near one layer.
            queue.submit([]);
        }

        let frame = FrameGpu {
            n_rows: sh.frame.n_rows,
            out_offset: sh.frame.out_offset,
            out_stride: sh.frame.out_stride,
            normal_offset: sh.frame.normal_offset,
            log_h,
            n_active: 0,
            l_rows: sh.frame.l_rows,
            n_vertices: sh.frame.n_vertices,
        };
        let frame_buf = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("touchfem frame"),
            contents: bytemuck::bytes_of(&frame),
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
        });
        let active = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("touchfem active columns"),
            size: 16 * MAX_ACTIVE as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });

        let (read, write) = (
            wgpu::StorageTextureAccess::ReadOnly,
            wgpu::StorageTextureAccess::WriteOnly,
        );
        let d2 = wgpu::TextureViewDimension::D2;
        let d2a = wgpu::TextureViewDimension::D2Array;
        let deform_layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("touchfem deform (texture)"),
            entries: &[
                uniform_entry(0),
                uniform_entry(1),
                storage_entry(2, false),
                storage_texture_entry(3, read, l_format, d2a),
                storage_texture_entry(4, read, rgba, d2),
                storage_texture_entry(5, write, rgba, d2),
            ],
        });
        let l_view = l_tex.create_view(&wgpu::TextureViewDescriptor {
            dimension: Some(wgpu::TextureViewDimension::D2Array),
            ..Default::default()
        });
        let v = |t: &wgpu::Texture| t.create_view(&Default::default());
        let (rest_view, pos_view) = (v(&rest), v(&pos));
        let (out, out_start, out_size) = sh.out;
        let deform_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("touchfem deform (texture)"),
            layout: &deform_layout,
            entries: &[
                buffer(0, &frame_buf, 0, 32),
                buffer(1, &active, 0, active.size()),
                buffer(2, out, out_start, out_size),
                view(3, &l_view),
                view(4, &rest_view),
                view(5, &pos_view),
            ],
        });
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("touchfem deform_texture.wgsl"),
            source: wgpu::ShaderSource::Wgsl(
                deform_texture_source(sh.immediates, sh.vertex_layout, sh.half).into(),
            ),
        });
        let imm_bytes = if sh.immediates { IMMEDIATE_BYTES } else { 0 };
        Ok(TexturePath {
            layers: layers as u32,
            l_bytes: texel_bytes * width * height * layers,
            active,
            deform: if sh.immediates {
                // ACTIVE_INLINE = 0..=INLINE_ACTIVE (inline), then INLINE_ACTIVE + 1 (uploaded).
                (0..=INLINE_ACTIVE + 1)
                    .map(|k| {
                        specialised_pipeline(
                            device,
                            &module,
                            "deform",
                            &[&deform_layout],
                            imm_bytes,
                            &[("ACTIVE_INLINE", k as f64)],
                        )
                    })
                    .collect()
            } else {
                vec![compute_pipeline(
                    device,
                    &module,
                    "deform",
                    &[&deform_layout],
                    0,
                )]
            },
            deform_group,
            pos_view,
            frame: frame_buf,
            module,
            scratch: Vec::with_capacity(MAX_ACTIVE),
            immediates: sh.immediates.then_some([0; IMMEDIATE_WORDS]),
            force_scale,
            half: sh.half,
        })
    }

    /// Whether `L` is stored as half floats.
    pub(super) fn half(&self) -> bool {
        self.half
    }

    /// Takes this frame's active list (`forces` is validated). With immediates, the count goes
    /// into them, and so do the entries if there are at most [`INLINE_ACTIVE`]: nothing is
    /// uploaded. Otherwise the entries are written to the uniform list (and, without
    /// immediates, the count to the frame uniform).
    pub(super) fn set_forces(&mut self, queue: &wgpu::Queue, forces: &[(u32, [f32; 3])]) {
        let k = self.force_scale;
        let entry = |&(col, f): &(u32, [f32; 3])| {
            [
                (f[0] * k).to_bits(),
                (f[1] * k).to_bits(),
                (f[2] * k).to_bits(),
                col,
            ]
        };
        let n = forces.len() as u32;
        if let Some(imm) = &mut self.immediates {
            let is_inline = forces.len() <= INLINE_ACTIVE;
            imm[..4].copy_from_slice(&[n, u32::from(is_inline), 0, 0]);
            if is_inline {
                for (k, e) in forces.iter().map(entry).enumerate() {
                    imm[4 + 4 * k..8 + 4 * k].copy_from_slice(&e);
                }
                return;
            }
        } else {
            queue.write_buffer(&self.frame, N_ACTIVE_OFFSET, bytemuck::bytes_of(&n));
        }
        self.scratch.clear();
        self.scratch.extend(forces.iter().map(entry));
        if !self.scratch.is_empty() {
            queue.write_buffer(&self.active, 0, bytemuck::cast_slice(&self.scratch));
        }
    }

    /// Whether the active list travels as immediates.
    pub(super) fn uses_immediates(&self) -> bool {
        self.immediates.is_some()
    }

    /// Records the deformation dispatch.
    pub(super) fn record_deform(&self, pass: &mut wgpu::ComputePass<'_>, n_rows: u32) {
        let groups = n_rows.div_ceil(WORKGROUP);
        // With immediates: the pipeline specialised for this many inline entries, or the last
        // one (uploaded list).
        let which = match &self.immediates {
            Some(imm) if imm[1] != 0 => imm[0] as usize,
            _ => self.deform.len() - 1,
        };
        pass.set_pipeline(&self.deform[which.min(self.deform.len() - 1)]);
        pass.set_bind_group(0, &self.deform_group, &[]);
        if let Some(imm) = &self.immediates {
            pass.set_immediates(0, bytemuck::cast_slice(imm));
        }
        pass.dispatch_workgroups(groups, 1, 1);
    }

    /// The deformed positions the normal pass reads (the correction pass writes them too).
    pub(super) fn positions(&self) -> &wgpu::TextureView {
        &self.pos_view
    }

    pub(super) fn layer_count(&self) -> usize {
        self.layers as usize
    }

    /// Bytes of the `L` texture.
    pub(super) fn l_bytes(&self) -> u64 {
        self.l_bytes
    }

    /// The shader module (the normal pass's `normals` entry).
    pub(super) fn module(&self) -> &wgpu::ShaderModule {
        &self.module
    }

    /// The frame uniform.
    pub(super) fn frame(&self) -> &wgpu::Buffer {
        &self.frame
    }
}
