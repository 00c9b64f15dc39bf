//! The storage-buffer layout of `L` (`shaders/deform.wgsl`): the f32 column-major `L` split by
//! column nodes into storage buffers no larger than the device's binding limit; one dispatch
//! per buffer with active columns (the normal pass is [`crate::surface`]'s).
//! The natural layout for hardware GPUs (neighbouring invocations read neighbouring words).

use bytemuck::{Pod, Zeroable};
use wgpu::util::DeviceExt;

use crate::bind::{buffer, specialised_pipeline, storage_entry, uniform_entry};
use crate::context::GpuError;
use crate::input::{Shared, MAX_ACTIVE, WORKGROUP};
use crate::shaders::{deform_source, DEFORM_WGSL};

/// `shaders/deform.wgsl` (after `frame.wgsl`) with `L` read as half floats, two per `u32` word
/// ([`crate::LStorage::BuffersF16`]).
pub(crate) fn deform_f16_wgsl() -> String {
    const F32_DECL: &str = "var<storage, read> l: array<f32>;";
    const F32_LOAD: &str = "return vec3<f32>(l[i], l[i + 1u], l[i + 2u]);";
    assert!(DEFORM_WGSL.contains(F32_DECL) && DEFORM_WGSL.contains(F32_LOAD));
    deform_source()
        .replace(F32_DECL, "var<storage, read> l: array<u32>;")
        .replace(
            F32_LOAD,
            "return vec3<f32>(half_at(i), half_at(i + 1u), half_at(i + 2u));",
        )
        + "\n// Entry i of L: half i & 1 of word i / 2 (the low half first).\n\
           fn half_at(i: u32) -> f32 {\n\
           \x20   let w = unpack2x16float(l[i >> 1u]);\n\
           \x20   return select(w.x, w.y, (i & 1u) == 1u);\n\
           }\n"
}

/// `values` as IEEE binary16, packed two per little-endian `u32` (the first in the low half),
/// zero-padded to a whole word.
pub(crate) fn pack_f16(values: &[f32]) -> Vec<u32> {
    values
        .chunks(2)
        .map(|p| {
            let lo = half::f16::from_f32(p[0]).to_bits() as u32;
            let hi = p
                .get(1)
                .map_or(0, |&v| half::f16::from_f32(v).to_bits() as u32);
            lo | (hi << 16)
        })
        .collect()
}

const CHUNK_PARAM_BYTES: u64 = 16;

#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
struct ActiveGpu {
    force: [f32; 3],
    col: u32,
}

#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
struct ChunkGpu {
    first: u32,
    count: u32,
    init: u32,
    _pad: u32,
}

struct Chunk {
    /// Holds this chunk's L columns (kept alive by the bind group too).
    l: wgpu::Buffer,
    bind_group: wgpu::BindGroup,
    /// Active entries this frame.
    count: u32,
}

/// `L` in storage buffers, and the passes that read it.
pub(super) struct BufferPath {
    half: bool,
    /// Forces are multiplied by this before upload: `L` is stored divided by it (a power of
    /// two near max |L|, so that half floats keep their precision whatever the material's
    /// units; 1 for f32).
    force_scale: f32,
    cols_per_chunk: usize,
    chunks: Vec<Chunk>,
    chunk_param_stride: u64,
    chunk_params: wgpu::Buffer,
    active: wgpu::Buffer,
    bind_group: wgpu::BindGroup,
    frame_buf: wgpu::Buffer,
    /// The shader module (its `normals` entry is the normal pass's).
    module: wgpu::ShaderModule,
    deform: wgpu::ComputePipeline,
    scratch: Vec<ActiveGpu>,
    first: Vec<u32>,
}

impl BufferPath {
    pub(super) fn new(sh: &Shared<'_>) -> Result<BufferPath, GpuError> {
        let (device, queue, nr, nc) = (sh.device, sh.queue, sh.nr, sh.nc);
        let limits = device.limits();
        sh.check("rest positions", 16 * nr as u64)?;

        // f32: 9R' floats per column node; f16: 9R' halves (+ a pad half per chunk).
        let bytes_per_col = if sh.half { 18 } else { 36 } * sh.nl.max(1) as u64;
        let avail = if sh.half {
            sh.max_chunk.saturating_sub(4)
        } else {
            sh.max_chunk
        };
        let cols_per_chunk = (avail / bytes_per_col) as usize;
        if cols_per_chunk == 0 {
            return Err(GpuError::BufferTooLarge {
                what: "one column node of L",
                bytes: bytes_per_col,
                limit: sh.max_chunk,
            });
        }
        let n_chunks = nc.div_ceil(cols_per_chunk).max(1);
        let chunk_param_stride =
            u64::from(limits.min_uniform_buffer_offset_alignment).max(CHUNK_PARAM_BYTES);

        let usage_ro = wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST;
        let frame_buf = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("touchfem frame"),
            contents: bytemuck::bytes_of(&sh.frame),
            usage: wgpu::BufferUsages::UNIFORM,
        });
        let active = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("touchfem active columns"),
            size: (MAX_ACTIVE * std::mem::size_of::<ActiveGpu>()) as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let rest_buf = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("touchfem rest positions"),
            contents: bytemuck::cast_slice(sh.rest_rows),
            usage: wgpu::BufferUsages::STORAGE,
        });
        let chunk_params = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("touchfem chunk params"),
            size: chunk_param_stride * n_chunks as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });

        let layout0 = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("touchfem deform group 0"),
            entries: &[
                uniform_entry(0),
                uniform_entry(1),
                storage_entry(2, true),
                storage_entry(3, false),
            ],
        });
        let layout1 = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("touchfem deform group 1 (L chunk)"),
            entries: &[uniform_entry(0), storage_entry(1, true)],
        });
        let (out, out_start, out_size) = sh.out;
        let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("touchfem deform group 0"),
            layout: &layout0,
            entries: &[
                buffer(
                    0,
                    &frame_buf,
                    0,
                    std::mem::size_of::<crate::input::FrameGpu>() as u64,
                ),
                buffer(1, &active, 0, active.size()),
                buffer(2, &rest_buf, 0, 16 * nr as u64),
                buffer(3, out, out_start, out_size),
            ],
        });

        let mut chunks = Vec::with_capacity(n_chunks);
        let col_len = 9 * sh.nl;
        let force_scale = if sh.half { sh.l.f16_scale() } else { 1.0 };
        for k in 0..n_chunks {
            let c0 = (k * cols_per_chunk).min(nc);
            let c1 = ((k + 1) * cols_per_chunk).min(nc);
            let data = sh.l.f32_range(c0 * col_len..c1 * col_len)?;
            let packed;
            let bytes: &[u8] = if sh.half {
                let scaled: Vec<f32> = data.iter().map(|v| v / force_scale).collect();
                packed = pack_f16(&scaled);
                bytemuck::cast_slice(&packed)
            } else {
                bytemuck::cast_slice(&data[..])
            };
            let size = (bytes.len() as u64).max(16);
            let l = device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("touchfem L chunk"),
                size,
                usage: usage_ro,
                mapped_at_creation: false,
            });
            if !bytes.is_empty() {
                queue.write_buffer(&l, 0, bytes);
                // Flush each chunk's staging copy so that peak memory stays near one chunk.
                queue.submit([]);
            }
            let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("touchfem L chunk"),
                layout: &layout1,
                entries: &[
                    buffer(
                        0,
                        &chunk_params,
                        k as u64 * chunk_param_stride,
                        CHUNK_PARAM_BYTES,
                    ),
                    buffer(1, &l, 0, size),
                ],
            });
            chunks.push(Chunk {
                l,
                bind_group,
                count: 0,
            });
        }

        let source = if sh.half {
            deform_f16_wgsl().into()
        } else {
            deform_source().into()
        };
        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("touchfem deform.wgsl"),
            source: wgpu::ShaderSource::Wgsl(source),
        });
        Ok(BufferPath {
            half: sh.half,
            force_scale,
            cols_per_chunk,
            first: Vec::with_capacity(chunks.len()),
            chunks,
            chunk_param_stride,
            chunk_params,
            active,
            bind_group,
            frame_buf,
            // The deformer's own `Vertex`es carry |u| in position.w (word 3).
            deform: specialised_pipeline(
                device,
                &module,
                "deform",
                &[&layout0, &layout1],
                0,
                if sh.vertex_layout {
                    &[("DISPLACEMENT_WORD", 3.0)]
                } else {
                    &[]
                },
            ),
            module,
            scratch: Vec::with_capacity(MAX_ACTIVE),
        })
    }

    /// Writes the active list grouped by chunk (counting sort, columns local to their chunk)
    /// and one record per chunk. `forces` is already validated.
    pub(super) fn set_forces(&mut self, queue: &wgpu::Queue, forces: &[(u32, [f32; 3])]) {
        let cpc = self.cols_per_chunk;
        for ch in &mut self.chunks {
            ch.count = 0;
        }
        for &(col, _) in forces {
            self.chunks[col as usize / cpc].count += 1;
        }
        self.first.clear();
        let mut acc = 0u32;
        for (k, ch) in self.chunks.iter().enumerate() {
            self.first.push(acc);
            let p = ChunkGpu {
                first: acc,
                count: ch.count,
                init: u32::from(k == 0),
                _pad: 0,
            };
            queue.write_buffer(
                &self.chunk_params,
                k as u64 * self.chunk_param_stride,
                bytemuck::bytes_of(&p),
            );
            acc += ch.count;
        }
        self.scratch.clear();
        self.scratch.resize(forces.len(), ActiveGpu::default());
        for &(col, force) in forces {
            let k = col as usize / cpc;
            self.scratch[self.first[k] as usize] = ActiveGpu {
                force: force.map(|f| f * self.force_scale),
                col: (col as usize - k * cpc) as u32,
            };
            self.first[k] += 1;
        }
        if !self.scratch.is_empty() {
            queue.write_buffer(&self.active, 0, bytemuck::cast_slice(&self.scratch));
        }
    }

    /// Records one dispatch per chunk with active columns (chunk 0 always: it starts from the
    /// rest pose).
    pub(super) fn record_deform(&self, pass: &mut wgpu::ComputePass<'_>, n_rows: u32) {
        let groups = n_rows.div_ceil(WORKGROUP);
        pass.set_pipeline(&self.deform);
        pass.set_bind_group(0, &self.bind_group, &[]);
        for (k, ch) in self.chunks.iter().enumerate() {
            if k == 0 || ch.count > 0 {
                pass.set_bind_group(1, &ch.bind_group, &[]);
                pass.dispatch_workgroups(groups, 1, 1);
            }
        }
    }

    /// Whether `L` is stored as half floats.
    pub(super) fn half(&self) -> bool {
        self.half
    }

    pub(super) fn chunk_count(&self) -> usize {
        self.chunks.len()
    }

    pub(super) fn cols_per_chunk(&self) -> usize {
        self.cols_per_chunk
    }

    /// Bytes of the `L` buffers.
    pub(super) fn l_bytes(&self) -> u64 {
        self.chunks.iter().map(|c| c.l.size()).sum()
    }

    /// The shader module (the normal pass's `normals` entry).
    pub(super) fn module(&self) -> &wgpu::ShaderModule {
        &self.module
    }

    /// The frame uniform.
    pub(super) fn frame(&self) -> &wgpu::Buffer {
        &self.frame_buf
    }
}
