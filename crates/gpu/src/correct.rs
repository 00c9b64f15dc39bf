//! A cut's correction on the GPU (`shaders/correct.wgsl`): `U` on the rows that hold `L` as
//! `rank` extra f32 columns, their weights `z = Σ_c V_cᵀ F_c` computed on the CPU from each
//! frame's forces ([`Correction::weights`]), and the pinned rows put back at rest. A separating
//! cut's correction also moves the rows whose rest position it snapped (a shift per row), and
//! writes the vertices of the nodes it added that have no row (`rest + U_x z + w_p(x)`, into
//! the vertices reserved after the rows). One more dispatch of the deformer's compute pass,
//! between the deformation and the normals, the same whatever layout `L` is stored in (`U` is
//! always f32, a `vec4` a row and column: its `16·(R'+X)·rank` bytes are small beside `L`'s).
//! The weights are one uniform binding of 16 KiB: a rank above [`MAX_CORRECTION_RANK`] is an
//! error (draw that cut with the CPU's `displace`).

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
    n_extra: u32,
    u_stride: u32,
    shift_base: u32,
}

/// Byte offset of `rank4` in [`ParamsGpu`] (`n_extra` follows).
const RANK4_OFFSET: u64 = std::mem::size_of::<FrameGpu>() as u64;

/// Where the correction pass writes: the deformer's output binding, and for the texture layout
/// the deformed-position texture its normal pass reads.
pub(crate) struct CorrectionTarget<'a> {
    /// Output buffer, binding start and size in bytes.
    pub out: (&'a wgpu::Buffer, u64, u64),
    /// The deformer's frame (first word of vertex 0 inside the binding, the stride in words,
    /// the rows, the rows that hold `L`, the vertices).
    pub frame: FrameGpu,
    /// The output is the deformer's own `Vertex` layout (|u| in word 3).
    pub vertex_layout: bool,
    /// The texture layout's deformed positions (`None` for the storage-buffer layout).
    pub positions: Option<&'a wgpu::TextureView>,
}

/// What a correction draws beyond `U` on the rows: its extra nodes without a row, and the
/// rows' rest positions as the cut left them.
pub(crate) struct Extras<'a> {
    /// Per extra vertex (in order after the rows), its index among [`Correction::extra`].
    pub of: &'a [usize],
    /// Per vertex (the rows, then the extra vertices), its rest position, `w = 1`.
    pub rest: &'a [[f32; 4]],
    /// Per row, how far the cut moved its rest position from the one the deformation pass
    /// adds `u` to (`w = 0`).
    pub shift: &'a [[f32; 4]],
}

/// The correction's buffers and its dispatch.
pub(crate) struct CorrectionPass {
    pipeline: wgpu::ComputePipeline,
    layout: wgpu::BindGroupLayout,
    params: wgpu::Buffer,
    /// Rest positions of the rows and extra vertices, then the rows' shifts.
    points: wgpu::Buffer,
    dead: wgpu::Buffer,
    places: wgpu::Buffer,
    out: (wgpu::Buffer, u64, u64),
    positions: Option<wgpu::TextureView>,
    /// `U`, room for `capacity` columns (a multiple of 4), the weights `z` and `w`.
    u_rows: wgpu::Buffer,
    weights: wgpu::Buffer,
    w_cols: wgpu::Buffer,
    capacity: usize,
    /// `U` in the shader's layout (kept to upload without allocating per cut).
    staging: Vec<[f32; 4]>,
    bind_group: wgpu::BindGroup,
    n_rows: usize,
    l_rows: usize,
    /// Extra vertices reserved after the rows.
    reserved: usize,
    /// Extra vertices written now.
    n_extra: usize,
    /// What the weights need of the correction (`rank`, `u_cols`, `v_cols`, `dead_cols`,
    /// `extra`, `v_extra`; the rest empty).
    weights_of: Correction,
    /// Whether the dispatch does anything (a rank, a pinned row, a shift, an extra vertex).
    active: bool,
    z: Vec<f64>,
    z32: Vec<f32>,
    w: Vec<f64>,
    w32: Vec<f32>,
    forces: Vec<(u32, DVec3)>,
}

/// `BufferTooLarge` if a rank-`rank` `U` on `u_rows` rows does not fit one binding or its
/// weights the uniform array.
pub(crate) fn check_size(u_rows: usize, rank: usize, max_binding: u64) -> Result<(), GpuError> {
    if rank > MAX_CORRECTION_RANK {
        return Err(GpuError::BufferTooLarge {
            what: "the cut's correction weights (one uniform binding)",
            bytes: 4 * rank as u64,
            limit: WEIGHT_BYTES,
        });
    }
    let bytes = 16 * u_rows as u64 * rank.div_ceil(4) as u64 * 4;
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

/// A storage buffer of `bytes` (at least 16) that the host writes.
fn storage(device: &wgpu::Device, label: &str, bytes: u64) -> wgpu::Buffer {
    device.create_buffer(&wgpu::BufferDescriptor {
        label: Some(label),
        size: bytes.max(16),
        usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST,
        mapped_at_creation: false,
    })
}

impl CorrectionPass {
    /// Builds the pipeline and the buffers for rank `0` (nothing to do until [`Self::set`]).
    pub(crate) fn new(device: &wgpu::Device, t: &CorrectionTarget<'_>) -> CorrectionPass {
        let n_rows = t.frame.n_rows as usize;
        let l_rows = t.frame.l_rows as usize;
        let reserved = t.frame.n_vertices as usize - n_rows;
        let mut entries = vec![
            uniform_entry(0),
            storage_entry(1, true),
            uniform_entry(2),
            storage_entry(3, true),
            storage_entry(4, true),
            storage_entry(5, false),
            storage_entry(6, true),
            storage_entry(7, true),
        ];
        if t.positions.is_some() {
            entries.push(crate::bind::storage_texture_entry(
                8,
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
                n_extra: 0,
                u_stride: (l_rows + reserved) as u32,
                shift_base: (n_rows + reserved) as u32,
            }),
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
        });
        let points = storage(
            device,
            "touchfem correction rest and shifts",
            16 * (2 * n_rows + reserved) as u64,
        );
        let dead = storage(device, "touchfem correction pinned rows", f32_bytes(l_rows));
        let places = storage(device, "touchfem correction places", 16 * reserved as u64);
        let u_rows = storage(device, "touchfem correction U", 0);
        let w_cols = storage(device, "touchfem correction w", 0);
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
            [&params, &u_rows, &weights, &dead, &points, &w_cols, &places],
            &out,
            positions.as_ref(),
        );
        CorrectionPass {
            pipeline,
            layout,
            params,
            points,
            dead,
            places,
            out,
            positions,
            u_rows,
            weights,
            w_cols,
            capacity: 0,
            staging: Vec::new(),
            bind_group,
            n_rows,
            l_rows,
            reserved,
            n_extra: 0,
            weights_of: Correction::default(),
            active: false,
            z: Vec::new(),
            z32: Vec::new(),
            w: Vec::new(),
            w32: Vec::new(),
            forces: Vec::with_capacity(crate::input::MAX_ACTIVE),
        }
    }

    /// Rows of `U` a column: the rows that hold `L`, then the reserved extra vertices.
    fn u_stride(&self) -> usize {
        self.l_rows + self.reserved
    }

    /// The bind group over `b` (params, `U`, `z`, pinned rows, points, `w`, places), the
    /// output and the texture layout's positions.
    fn group(
        device: &wgpu::Device,
        layout: &wgpu::BindGroupLayout,
        b: [&wgpu::Buffer; 7],
        out: &(wgpu::Buffer, u64, u64),
        positions: Option<&wgpu::TextureView>,
    ) -> wgpu::BindGroup {
        let slots = [0u32, 1, 2, 3, 4, 6, 7];
        let mut entries: Vec<wgpu::BindGroupEntry<'_>> = b
            .iter()
            .zip(slots)
            .map(|(buf, i)| buffer(i, buf, 0, buf.size()))
            .collect();
        entries.push(buffer(5, &out.0, out.1, out.2));
        if let Some(v) = positions {
            entries.push(crate::bind::view(8, v));
        }
        device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("touchfem correction"),
            layout,
            entries: &entries,
        })
    }

    /// Uploads `k` (already checked against the deformer's rows and columns) and what it
    /// draws beyond `U` on the rows (`x`: at most the reserved extra vertices); re-allocates
    /// when the rank outgrows the buffers (by half again, so that a growing cut re-allocates
    /// seldom).
    pub(crate) fn set(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        k: &Correction,
        x: &Extras<'_>,
        max_binding: u64,
    ) -> Result<(), GpuError> {
        let rank = k.rank;
        let rank4 = rank.div_ceil(4) * 4;
        let stride = self.u_stride();
        check_size(stride, rank, max_binding)?;
        if rank4 > self.capacity {
            let grown = rank4.max((self.capacity + self.capacity / 2).div_ceil(4) * 4);
            let cap = if check_size(stride, grown, max_binding).is_ok() {
                grown
            } else {
                rank4
            };
            self.u_rows = storage(device, "touchfem correction U", f32_bytes(4 * stride * cap));
            self.w_cols = storage(device, "touchfem correction w", f32_bytes(cap));
            self.capacity = cap;
            self.bind_group = Self::group(
                device,
                &self.layout,
                [
                    &self.params,
                    &self.u_rows,
                    &self.weights,
                    &self.dead,
                    &self.points,
                    &self.w_cols,
                    &self.places,
                ],
                &self.out,
                self.positions.as_ref(),
            );
        }
        let n_extra = x.of.len();
        if rank > 0 {
            // Column q, row i at q·S + i, (x, y, z, 0); the padding columns zero.
            let n = self.l_rows;
            self.staging.clear();
            self.staging.resize(rank4 * stride, [0.0; 4]);
            for (q, col) in k.rows.chunks_exact(3 * n).enumerate().take(rank) {
                for (r, u) in col.chunks_exact(3).enumerate() {
                    self.staging[q * stride + r] = [u[0] as f32, u[1] as f32, u[2] as f32, 0.0];
                }
            }
            for (j, &e) in x.of.iter().enumerate() {
                let u = &k.u_extra[3 * e * rank..][..3 * rank];
                for q in 0..rank {
                    self.staging[q * stride + n + j] =
                        [u[q] as f32, u[rank + q] as f32, u[2 * rank + q] as f32, 0.0];
                }
            }
            queue.write_buffer(&self.u_rows, 0, bytemuck::cast_slice(&self.staging));
        }
        let dead: Vec<u32> = k.dead_rows.iter().map(|&d| u32::from(d)).collect();
        if !dead.is_empty() {
            queue.write_buffer(&self.dead, 0, bytemuck::cast_slice(&dead));
        }
        // The points: the rows' and extra vertices' rest positions, then the rows' shifts.
        let mut points = Vec::with_capacity(2 * self.n_rows + self.reserved);
        points.extend_from_slice(&x.rest[..self.n_rows + n_extra]);
        points.resize(self.n_rows + self.reserved, [0.0; 4]);
        points.extend_from_slice(x.shift);
        points.resize(2 * self.n_rows + self.reserved, [0.0; 4]);
        queue.write_buffer(&self.points, 0, bytemuck::cast_slice(&points));
        if n_extra > 0 {
            let places: Vec<[u32; 4]> = (x.of.iter())
                .map(|&e| {
                    let p = k.extra_place[e];
                    [p[0], p[1], p[2], 0]
                })
                .collect();
            queue.write_buffer(&self.places, 0, bytemuck::cast_slice(&places));
        }
        let sizes = [(rank4 / 4) as u32, n_extra as u32];
        queue.write_buffer(&self.params, RANK4_OFFSET, bytemuck::cast_slice(&sizes));
        self.weights_of = Correction {
            rank,
            u_cols: if n_extra > 0 {
                k.u_cols.clone()
            } else {
                Default::default()
            },
            v_cols: k.v_cols.clone(),
            dead_cols: k.dead_cols.clone(),
            extra: k.extra.clone(),
            v_extra: k.v_extra.clone(),
            ..Default::default()
        };
        self.n_extra = n_extra;
        self.z.resize(rank, 0.0);
        self.w.resize(rank, 0.0);
        // Padded to whole vec4s: the padding weights stay zero.
        self.z32.clear();
        self.z32.resize(rank4, 0.0);
        self.w32.clear();
        self.w32.resize(rank4, 0.0);
        self.active = rank > 0
            || n_extra > 0
            || k.dead_rows.iter().any(|&d| d)
            || x.shift.iter().any(|s| s.iter().any(|&v| v != 0.0));
        Ok(())
    }

    /// The correction's rank (0 when it has none).
    pub(crate) fn rank(&self) -> usize {
        self.weights_of.rank
    }

    /// Computes this frame's weights from `forces` (validated) and uploads them (`4·rank`
    /// bytes, rounded up to 16, and as many again for the extra vertices' `w`; nothing at
    /// rank 0).
    pub(crate) fn set_forces(&mut self, queue: &wgpu::Queue, forces: &[(u32, [f32; 3])]) {
        let k = &self.weights_of;
        let rank = k.rank;
        if rank == 0 {
            return;
        }
        self.forces.clear();
        self.forces.extend(
            forces
                .iter()
                .map(|&(c, f)| (c, DVec3::from(f.map(f64::from)))),
        );
        k.weights(&self.forces, &mut self.z);
        for (o, &z) in self.z32.iter_mut().zip(&self.z) {
            *o = z as f32;
        }
        queue.write_buffer(&self.weights, 0, bytemuck::cast_slice(&self.z32));
        if self.n_extra > 0 {
            k.column_weights(&self.forces, &mut self.w);
            for (o, &w) in self.w32.iter_mut().zip(&self.w) {
                *o = w as f32;
            }
            queue.write_buffer(&self.w_cols, 0, bytemuck::cast_slice(&self.w32));
        }
    }

    /// Records the dispatch (nothing when the correction does nothing).
    pub(crate) fn record(&self, pass: &mut wgpu::ComputePass<'_>) {
        if !self.active || self.n_rows == 0 {
            return;
        }
        pass.set_pipeline(&self.pipeline);
        pass.set_bind_group(0, &self.bind_group, &[]);
        let lanes = (self.n_rows + self.n_extra) as u32;
        pass.dispatch_workgroups(lanes.div_ceil(WORKGROUP), 1, 1);
    }
}
