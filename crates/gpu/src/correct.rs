//! A cut's correction on the GPU (`shaders/correct.wgsl`): `U` on the rows that hold `L` as
//! `rank` extra f32 columns, their weights `z = Σ_c V_cᵀ F_c` computed on the CPU from each
//! frame's forces ([`Correction::weights`]), and the pinned rows put back at rest. One more
//! dispatch of the deformer's compute pass, between the deformation and the normals, the same
//! whatever layout `L` is stored in (`U` is always f32, a `vec4` a row and column: its
//! `16·R'·rank` bytes are small beside `L`'s). The weights are one uniform binding of 16 KiB:
//! a rank above [`MAX_CORRECTION_RANK`] is an error (draw that cut with the CPU's `displace`).

use glam::DVec3;
use wgpu::util::DeviceExt;

use crate::bind::{buffer, specialised_pipeline, storage_entry, uniform_entry};
use crate::context::GpuError;
use crate::input::{FrameGpu, WORKGROUP};
use crate::shaders::correct_source;
use touchfem_core::compliance::correction::Correction;

/// Largest rank the GPU pass carries (the weights' uniform array, `shaders/correct.wgsl`).
pub(crate) const MAX_CORRECTION_RANK: usize = 4096;

/// Bytes of the weights' uniform binding.
const WEIGHT_BYTES: u64 = 4 * MAX_CORRECTION_RANK as u64;

#[repr(C)]
#[derive(Clone, Copy, Debug, Default, bytemuck::Pod, bytemuck::Zeroable)]
struct ParamsGpu {
    frame: FrameGpu,
    rank4: u32,
    _pad: [u32; 3],
}

/// Byte offset of `rank4` in [`ParamsGpu`].
const RANK4_OFFSET: u64 = std::mem::size_of::<FrameGpu>() as u64;

/// Where the correction pass writes: the deformer's output binding, and for the texture layout
/// the deformed-position texture its normal pass reads.
pub(crate) struct CorrectionTarget<'a> {
    /// Output buffer, binding start and size in bytes.
    pub out: (&'a wgpu::Buffer, u64, u64),
    /// The deformer's frame (first word of vertex 0 inside the binding, the stride in words,
    /// the rows that hold `L`).
    pub frame: FrameGpu,
    /// The output is the deformer's own `Vertex` layout (|u| in word 3).
    pub vertex_layout: bool,
    /// The texture layout's deformed positions (`None` for the storage-buffer layout).
    pub positions: Option<&'a wgpu::TextureView>,
    /// Rest positions of the rows that hold `L`, `w = 1`.
    pub rest_rows: &'a [[f32; 4]],
}

/// The correction's buffers and its dispatch.
pub(crate) struct CorrectionPass {
    pipeline: wgpu::ComputePipeline,
    layout: wgpu::BindGroupLayout,
    params: wgpu::Buffer,
    rest: wgpu::Buffer,
    dead: wgpu::Buffer,
    out: (wgpu::Buffer, u64, u64),
    positions: Option<wgpu::TextureView>,
    /// `U`, room for `capacity` columns (a multiple of 4), and the weights.
    u_rows: wgpu::Buffer,
    weights: wgpu::Buffer,
    capacity: usize,
    /// `U` in the shader's layout (kept to upload without allocating per cut).
    staging: Vec<[f32; 4]>,
    bind_group: wgpu::BindGroup,
    l_rows: usize,
    /// What the weights need of the correction (`rank`, `v_cols`, `dead_cols`; the rest empty).
    weights_of: Correction,
    /// Whether the dispatch does anything (a rank or a pinned row).
    active: bool,
    z: Vec<f64>,
    z32: Vec<f32>,
    forces: Vec<(u32, DVec3)>,
}

/// `BufferTooLarge` if a rank-`rank` `U` on `l_rows` rows does not fit one binding or its
/// weights the uniform array.
pub(crate) fn check_size(l_rows: usize, rank: usize, max_binding: u64) -> Result<(), GpuError> {
    if rank > MAX_CORRECTION_RANK {
        return Err(GpuError::BufferTooLarge {
            what: "the cut's correction weights (one uniform binding)",
            bytes: 4 * rank as u64,
            limit: WEIGHT_BYTES,
        });
    }
    let bytes = 16 * l_rows as u64 * rank.div_ceil(4) as u64 * 4;
    if bytes > max_binding {
        return Err(GpuError::BufferTooLarge {
            what: "the cut's correction (U on the displayed rows)",
            bytes,
            limit: max_binding,
        });
    }
    Ok(())
}

/// Bytes of `n` f32 (at least 16: no empty binding).
fn f32_bytes(n: usize) -> u64 {
    (4 * n as u64).max(16)
}

impl CorrectionPass {
    /// Builds the pipeline and the buffers for rank `0` (nothing to do until [`Self::set`]).
    pub(crate) fn new(device: &wgpu::Device, t: &CorrectionTarget<'_>) -> CorrectionPass {
        let l_rows = t.rest_rows.len();
        let mut entries = vec![
            uniform_entry(0),
            storage_entry(1, true),
            uniform_entry(2),
            storage_entry(3, true),
            storage_entry(4, true),
            storage_entry(5, false),
        ];
        if t.positions.is_some() {
            entries.push(crate::bind::storage_texture_entry(
                6,
                wgpu::StorageTextureAccess::WriteOnly,
                wgpu::TextureFormat::Rgba32Float,
                wgpu::TextureViewDimension::D2,
            ));
        }
        let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("touchfem correction"),
            entries: &entries,
        });
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("touchfem correct.wgsl"),
            source: wgpu::ShaderSource::Wgsl(correct_source(t.positions.is_some()).into()),
        });
        let pipeline = specialised_pipeline(
            device,
            &module,
            "correct",
            &[&layout],
            0,
            if t.vertex_layout {
                &[("DISPLACEMENT_WORD", 3.0)]
            } else {
                &[]
            },
        );
        let params = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("touchfem correction params"),
            contents: bytemuck::bytes_of(&ParamsGpu {
                frame: t.frame,
                rank4: 0,
                _pad: [0; 3],
            }),
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
        });
        let mut rest: Vec<[f32; 4]> = t.rest_rows.to_vec();
        rest.resize(l_rows.max(1), [0.0; 4]);
        let rest = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("touchfem correction rest rows"),
            contents: bytemuck::cast_slice(&rest),
            usage: wgpu::BufferUsages::STORAGE,
        });
        let storage = wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST;
        let dead = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("touchfem correction pinned rows"),
            size: f32_bytes(l_rows),
            usage: storage,
            mapped_at_creation: false,
        });
        let u_rows = Self::columns(device, l_rows, 0);
        let weights = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("touchfem correction weights"),
            size: WEIGHT_BYTES,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let (ob, os, oz) = t.out;
        let out = (ob.clone(), os, oz);
        let positions = t.positions.cloned();
        let bind_group = Self::group(
            device,
            &layout,
            [&params, &u_rows, &weights, &dead, &rest],
            &out,
            positions.as_ref(),
        );
        CorrectionPass {
            pipeline,
            layout,
            params,
            rest,
            dead,
            out,
            positions,
            u_rows,
            weights,
            capacity: 0,
            staging: Vec::new(),
            bind_group,
            l_rows,
            weights_of: Correction::default(),
            active: false,
            z: Vec::new(),
            z32: Vec::new(),
            forces: Vec::with_capacity(crate::input::MAX_ACTIVE),
        }
    }

    /// `U`'s buffer for `cols` columns.
    fn columns(device: &wgpu::Device, l_rows: usize, cols: usize) -> wgpu::Buffer {
        device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("touchfem correction U"),
            size: f32_bytes(4 * l_rows * cols),
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        })
    }

    fn group(
        device: &wgpu::Device,
        layout: &wgpu::BindGroupLayout,
        b: [&wgpu::Buffer; 5],
        out: &(wgpu::Buffer, u64, u64),
        positions: Option<&wgpu::TextureView>,
    ) -> wgpu::BindGroup {
        let mut entries: Vec<wgpu::BindGroupEntry<'_>> = b
            .iter()
            .enumerate()
            .map(|(i, buf)| buffer(i as u32, buf, 0, buf.size()))
            .collect();
        entries.push(buffer(5, &out.0, out.1, out.2));
        if let Some(v) = positions {
            entries.push(crate::bind::view(6, v));
        }
        device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("touchfem correction"),
            layout,
            entries: &entries,
        })
    }

    /// Uploads `k` (already checked against the deformer's rows and columns); re-allocates
    /// when the rank outgrows the buffers (by half again, so that a growing cut re-allocates
    /// seldom).
    pub(crate) fn set(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        k: &Correction,
        max_binding: u64,
    ) -> Result<(), GpuError> {
        let rank = k.rank;
        let rank4 = rank.div_ceil(4) * 4;
        check_size(self.l_rows, rank, max_binding)?;
        if rank4 > self.capacity {
            let grown = rank4.max((self.capacity + self.capacity / 2).div_ceil(4) * 4);
            let cap = if check_size(self.l_rows, grown, max_binding).is_ok() {
                grown
            } else {
                rank4
            };
            self.u_rows = Self::columns(device, self.l_rows, cap);
            self.capacity = cap;
            self.bind_group = Self::group(
                device,
                &self.layout,
                [
                    &self.params,
                    &self.u_rows,
                    &self.weights,
                    &self.dead,
                    &self.rest,
                ],
                &self.out,
                self.positions.as_ref(),
            );
        }
        if rank > 0 {
            // Column q, row r at q·R' + r, (x, y, z, 0); the padding columns zero.
            let n = self.l_rows;
            self.staging.clear();
            self.staging.resize(rank4 * n, [0.0; 4]);
            for (q, col) in k.rows.chunks_exact(3 * n).enumerate().take(rank) {
                for (r, u) in col.chunks_exact(3).enumerate() {
                    self.staging[q * n + r] = [u[0] as f32, u[1] as f32, u[2] as f32, 0.0];
                }
            }
            queue.write_buffer(&self.u_rows, 0, bytemuck::cast_slice(&self.staging));
        }
        let dead: Vec<u32> = k.dead_rows.iter().map(|&d| u32::from(d)).collect();
        if !dead.is_empty() {
            queue.write_buffer(&self.dead, 0, bytemuck::cast_slice(&dead));
        }
        let rank4_vec4s = (rank4 / 4) as u32;
        queue.write_buffer(&self.params, RANK4_OFFSET, bytemuck::bytes_of(&rank4_vec4s));
        self.weights_of = Correction {
            rank,
            v_cols: k.v_cols.clone(),
            dead_cols: k.dead_cols.clone(),
            ..Default::default()
        };
        self.z.resize(rank, 0.0);
        // Padded to whole vec4s: the padding weights stay zero.
        self.z32.clear();
        self.z32.resize(rank4, 0.0);
        self.active = rank > 0 || k.dead_rows.iter().any(|&d| d);
        Ok(())
    }

    /// The correction's rank (0 when it has none).
    pub(crate) fn rank(&self) -> usize {
        self.weights_of.rank
    }

    /// Computes this frame's weights from `forces` (validated) and uploads them (`4·rank`
    /// bytes, rounded up to 16; nothing at rank 0).
    pub(crate) fn set_forces(&mut self, queue: &wgpu::Queue, forces: &[(u32, [f32; 3])]) {
        let rank = self.weights_of.rank;
        if rank == 0 {
            return;
        }
        self.forces.clear();
        self.forces.extend(
            forces
                .iter()
                .map(|&(c, f)| (c, DVec3::from(f.map(f64::from)))),
        );
        self.weights_of.weights(&self.forces, &mut self.z);
        for (o, &z) in self.z32.iter_mut().zip(&self.z) {
            *o = z as f32;
        }
        queue.write_buffer(&self.weights, 0, bytemuck::cast_slice(&self.z32));
    }

    /// Records the dispatch (nothing when the correction does nothing).
    pub(crate) fn record(&self, pass: &mut wgpu::ComputePass<'_>) {
        if !self.active || self.l_rows == 0 {
            return;
        }
        pass.set_pipeline(&self.pipeline);
        pass.set_bind_group(0, &self.bind_group, &[]);
        pass.dispatch_workgroups((self.l_rows as u32).div_ceil(WORKGROUP), 1, 1);
    }
}
