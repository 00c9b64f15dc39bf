//! [`Deformer`]: `u = L·F` and vertex normals on the GPU, into a vertex buffer.

use bytemuck::{Pod, Zeroable};
use glam::DVec3;
use wgpu::util::DeviceExt;

use super::{GpuError, DEFORM_WGSL};
use crate::compliance::Compliance;

/// Most entries a force boundary condition may have per frame (the active-list buffer's size).
/// [`Deformer::set_forces`] rejects more with [`GpuError::TooManyActive`].
pub const MAX_ACTIVE: usize = 1024;

/// Byte stride of the deformer's own vertex buffer: see [`Vertex`].
pub const VERTEX_STRIDE: u64 = std::mem::size_of::<Vertex>() as u64;

/// `normal_offset` value in the shader meaning "write no normals".
pub const NO_NORMALS: u32 = u32::MAX;

const WORKGROUP: u32 = 64;
const CHUNK_PARAM_BYTES: u64 = 16;

/// One vertex of the deformer's own vertex buffer: 32 bytes, interleaved.
///
/// | bytes  | WGSL        | content                                          | location |
/// |--------|-------------|--------------------------------------------------|----------|
/// | 0..16  | `vec4<f32>` | deformed position in metres, `w = 1`             | 0        |
/// | 16..32 | `vec4<f32>` | unit area-weighted vertex normal, `w = 0`        | 1        |
///
/// Vertex `i` is displayed row `i` of the compliance ([`Compliance::rows`]`()[i]` is its mesh
/// node); [`Deformer::index_buffer`] holds the surface triangles in these indices.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct Vertex {
    /// Deformed position (m), `w = 1`.
    pub position: [f32; 4],
    /// Unit normal, `w = 0`.
    pub normal: [f32; 4],
}

impl Vertex {
    /// Attributes: position at location 0, normal at location 1, both `Float32x4`.
    pub const ATTRIBUTES: [wgpu::VertexAttribute; 2] =
        wgpu::vertex_attr_array![0 => Float32x4, 1 => Float32x4];

    /// The vertex buffer layout of [`Deformer::vertex_buffer`] when no [`OutputTarget`] was given.
    pub fn layout() -> wgpu::VertexBufferLayout<'static> {
        wgpu::VertexBufferLayout {
            array_stride: VERTEX_STRIDE,
            step_mode: wgpu::VertexStepMode::Vertex,
            attributes: &Self::ATTRIBUTES,
        }
    }
}

/// The compliance data the deformer needs, borrowed: displayed rows, column count and the f32
/// `L` in [`crate::compliance`]'s column-major layout. Build it from a [`Compliance`] with
/// `From`, or directly for synthetic data.
#[derive(Clone, Copy, Debug)]
pub struct DeformerInput<'a> {
    /// Displayed mesh nodes; vertex `i` of the output is `rows[i]`.
    pub rows: &'a [u32],
    /// Number of touchable columns C.
    pub n_cols: usize,
    /// `L`, `9·R·C` entries, entry (row r, axis a; column c, axis b) at `(3c+b)·3R + 3r + a`.
    pub l: &'a [f32],
}

impl<'a> From<&'a Compliance> for DeformerInput<'a> {
    fn from(c: &'a Compliance) -> Self {
        DeformerInput {
            rows: c.rows(),
            n_cols: c.cols().len(),
            l: c.l_f32(),
        }
    }
}

/// Where the deformer writes vertices: a caller's buffer (usage must include `STORAGE`; add
/// `VERTEX` to draw from it and `COPY_SRC` for [`Deformer::read_back`]).
///
/// Vertex `i`'s position is three `f32` at byte `offset + i·stride`; its normal three `f32` at
/// `offset + i·stride + normal_offset`. Other bytes are left untouched.
#[derive(Clone, Debug)]
pub struct OutputTarget {
    /// The buffer.
    pub buffer: wgpu::Buffer,
    /// Byte offset of vertex 0 (multiple of 4).
    pub offset: u64,
    /// Byte stride between vertices (multiple of 4, at least 12).
    pub stride: u64,
    /// Byte offset of the normal inside a vertex (multiple of 4, at least 12, with
    /// `normal_offset + 12 <= stride`), or `None` to skip the normal pass.
    pub normal_offset: Option<u64>,
}

/// Options for [`Deformer::new`].
#[derive(Clone, Debug, Default)]
pub struct DeformerOptions {
    /// Cap on the bytes of one `L` chunk binding, below the device's
    /// `max_storage_buffer_binding_size` and `max_buffer_size` (mainly to test the split).
    pub max_binding_bytes: Option<u64>,
    /// Write into this buffer instead of a new one with the [`Vertex`] layout.
    pub output: Option<OutputTarget>,
}

#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
struct FrameGpu {
    n_rows: u32,
    out_offset: u32,
    out_stride: u32,
    normal_offset: u32,
}

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
    _l: wgpu::Buffer,
    bind_group: wgpu::BindGroup,
    /// Active entries this frame.
    count: u32,
}

/// Evaluates the deformation `x = x_rest + Σ_active L[:, c]·F_c` and the vertex normals of the
/// deformed surface on the GPU, writing straight into a vertex buffer.
///
/// `L` is uploaded once (f32), split by column nodes into chunks no larger than the device's
/// storage binding limit. Per frame, [`set_forces`](Self::set_forces) writes only the active
/// columns and forces (16 bytes each) and one 16-byte record per chunk;
/// [`encode`](Self::encode) records one compute pass into the caller's encoder: one dispatch
/// per chunk with active columns (chunk 0 always), then the normal pass, which gathers over a
/// precomputed vertex → triangle CSR list (WGSL has no float atomics).
pub struct Deformer {
    n_rows: u32,
    n_cols: usize,
    cols_per_chunk: usize,
    chunks: Vec<Chunk>,
    chunk_param_stride: u64,
    chunk_params: wgpu::Buffer,
    active: wgpu::Buffer,
    bind_group: wgpu::BindGroup,
    deform_pipeline: wgpu::ComputePipeline,
    normals_pipeline: wgpu::ComputePipeline,
    target: OutputTarget,
    write_normals: bool,
    index_buffer: wgpu::Buffer,
    triangles: Vec<[u32; 3]>,
    scratch: Vec<ActiveGpu>,
}

impl std::fmt::Debug for Deformer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Deformer")
            .field("n_rows", &self.n_rows)
            .field("n_cols", &self.n_cols)
            .field("cols_per_chunk", &self.cols_per_chunk)
            .field("chunks", &self.chunks.len())
            .field("target", &self.target)
            .finish_non_exhaustive()
    }
}

fn storage_entry(binding: u32, read_only: bool) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Storage { read_only },
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}

fn uniform_entry(binding: u32) -> wgpu::BindGroupLayoutEntry {
    wgpu::BindGroupLayoutEntry {
        binding,
        visibility: wgpu::ShaderStages::COMPUTE,
        ty: wgpu::BindingType::Buffer {
            ty: wgpu::BufferBindingType::Uniform,
            has_dynamic_offset: false,
            min_binding_size: None,
        },
        count: None,
    }
}

fn binding(
    binding: u32,
    buffer: &wgpu::Buffer,
    offset: u64,
    size: u64,
) -> wgpu::BindGroupEntry<'_> {
    wgpu::BindGroupEntry {
        binding,
        resource: wgpu::BindingResource::Buffer(wgpu::BufferBinding {
            buffer,
            offset,
            size: wgpu::BufferSize::new(size),
        }),
    }
}

impl Deformer {
    /// Uploads `L`, the rest positions and the surface, and builds the pipelines.
    ///
    /// * `input`: the compliance (`&Compliance` converts), R rows and C columns;
    /// * `rest`: rest positions indexed by **mesh node** (e.g. `mesh.nodes`), metres;
    /// * `triangles`: surface triangles as **mesh node** indices, counter-clockwise seen from
    ///   outside (e.g. `mesh.surface`); every node must be a displayed row.
    ///
    /// Starts at the rest pose (no active columns).
    pub fn new<'a>(
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        input: impl Into<DeformerInput<'a>>,
        rest: &[DVec3],
        triangles: &[[u32; 3]],
        options: &DeformerOptions,
    ) -> Result<Deformer, GpuError> {
        let input = input.into();
        let nr = input.rows.len();
        let nc = input.n_cols;
        if nr == 0 {
            return Err(GpuError::BadInput("no displayed rows".into()));
        }
        if input.l.len() != 9 * nr * nc {
            return Err(GpuError::BadInput(format!(
                "L has {} entries, expected 9·{nr}·{nc}",
                input.l.len()
            )));
        }
        let limits = device.limits();
        let max_binding = limits
            .max_storage_buffer_binding_size
            .min(limits.max_buffer_size);
        let max_chunk = options
            .max_binding_bytes
            .map_or(max_binding, |m| m.min(max_binding));
        let max_groups = u64::from(limits.max_compute_workgroups_per_dimension);
        if (nr as u64).div_ceil(u64::from(WORKGROUP)) > max_groups {
            return Err(GpuError::BufferTooLarge {
                what: "the displayed rows (one invocation each)",
                bytes: nr as u64,
                limit: max_groups * u64::from(WORKGROUP),
            });
        }
        let check = |what: &'static str, bytes: u64| {
            if bytes > max_binding {
                Err(GpuError::BufferTooLarge {
                    what,
                    bytes,
                    limit: max_binding,
                })
            } else {
                Ok(())
            }
        };

        // Rest positions, per row.
        let mut rest_rows = Vec::with_capacity(nr);
        for &node in input.rows {
            let p = rest.get(node as usize).ok_or_else(|| {
                GpuError::BadInput(format!(
                    "row node {node} has no rest position ({} given)",
                    rest.len()
                ))
            })?;
            rest_rows.push([p.x as f32, p.y as f32, p.z as f32, 1.0]);
        }
        check("rest positions", 16 * nr as u64)?;

        // Triangles in row indices, and the vertex → triangle CSR list.
        let max_node = input.rows.iter().copied().max().unwrap_or(0) as usize;
        let mut row_of = vec![u32::MAX; max_node + 1];
        for (i, &node) in input.rows.iter().enumerate() {
            row_of[node as usize] = i as u32;
        }
        let mut tris = Vec::with_capacity(triangles.len());
        for (t, tri) in triangles.iter().enumerate() {
            let mut out = [0u32; 3];
            for (k, &node) in tri.iter().enumerate() {
                out[k] = row_of.get(node as usize).copied().unwrap_or(u32::MAX);
                if out[k] == u32::MAX {
                    return Err(GpuError::BadInput(format!(
                        "triangle {t} {tri:?} uses node {node}, which is not a displayed row"
                    )));
                }
            }
            tris.push(out);
        }
        // The shader reads offsets[0..=nr] followed by the triangle ids, in one buffer.
        let (mut adj, list) = crate::mesh::vertex_triangles(nr, &tris);
        adj.extend_from_slice(&list);
        check("triangle list", 12 * tris.len() as u64)?;
        check("vertex-triangle adjacency", 4 * adj.len() as u64)?;

        // Output target.
        let target = match &options.output {
            Some(t) => t.clone(),
            None => {
                let init: Vec<Vertex> = rest_rows
                    .iter()
                    .map(|&position| Vertex {
                        position,
                        normal: [0.0, 0.0, 1.0, 0.0],
                    })
                    .collect();
                check("vertex buffer", VERTEX_STRIDE * nr as u64)?;
                OutputTarget {
                    buffer: device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                        label: Some("touchfem vertices"),
                        contents: bytemuck::cast_slice(&init),
                        usage: wgpu::BufferUsages::STORAGE
                            | wgpu::BufferUsages::VERTEX
                            | wgpu::BufferUsages::COPY_SRC
                            | wgpu::BufferUsages::COPY_DST,
                    }),
                    offset: 0,
                    stride: VERTEX_STRIDE,
                    normal_offset: Some(16),
                }
            }
        };
        let (out_start, out_size, out_word, normal_word) =
            validate_target(&target, nr as u64, &limits)?;
        check("output binding", out_size)?;

        // L, chunked by column nodes.
        let bytes_per_col = 36 * nr as u64;
        let cols_per_chunk = (max_chunk / bytes_per_col) as usize;
        if cols_per_chunk == 0 {
            return Err(GpuError::BufferTooLarge {
                what: "one column node of L",
                bytes: bytes_per_col,
                limit: max_chunk,
            });
        }
        let n_chunks = nc.div_ceil(cols_per_chunk).max(1);
        let chunk_param_stride =
            u64::from(limits.min_uniform_buffer_offset_alignment).max(CHUNK_PARAM_BYTES);

        let usage_ro = wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::COPY_DST;
        let frame = FrameGpu {
            n_rows: nr as u32,
            out_offset: out_word,
            out_stride: (target.stride / 4) as u32,
            normal_offset: normal_word,
        };
        let frame_buf = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("touchfem frame"),
            contents: bytemuck::bytes_of(&frame),
            usage: wgpu::BufferUsages::UNIFORM,
        });
        let active = device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("touchfem active columns"),
            size: (MAX_ACTIVE * std::mem::size_of::<ActiveGpu>()) as u64,
            usage: usage_ro,
            mapped_at_creation: false,
        });
        let rest_buf = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("touchfem rest positions"),
            contents: bytemuck::cast_slice(&rest_rows),
            usage: wgpu::BufferUsages::STORAGE,
        });
        let mut tri_words: Vec<u32> = tris.iter().flatten().copied().collect();
        let n_tri_words = tri_words.len().max(1);
        tri_words.resize(n_tri_words.max(4), 0);
        let index_buffer = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("touchfem triangles"),
            contents: bytemuck::cast_slice(&tri_words),
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::INDEX,
        });
        let adj_buf = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("touchfem vertex-triangle CSR"),
            contents: bytemuck::cast_slice(&adj),
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
                storage_entry(1, true),
                storage_entry(2, true),
                storage_entry(3, false),
                storage_entry(4, true),
                storage_entry(5, true),
            ],
        });
        let layout1 = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
            label: Some("touchfem deform group 1 (L chunk)"),
            entries: &[uniform_entry(0), storage_entry(1, true)],
        });
        let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
            label: Some("touchfem deform group 0"),
            layout: &layout0,
            entries: &[
                binding(0, &frame_buf, 0, 16),
                binding(1, &active, 0, active.size()),
                binding(2, &rest_buf, 0, 16 * nr as u64),
                binding(3, &target.buffer, out_start, out_size),
                binding(4, &index_buffer, 0, 4 * tri_words.len() as u64),
                binding(5, &adj_buf, 0, 4 * adj.len() as u64),
            ],
        });

        let mut chunks = Vec::with_capacity(n_chunks);
        let col_len = 9 * nr;
        for k in 0..n_chunks {
            let c0 = (k * cols_per_chunk).min(nc);
            let c1 = ((k + 1) * cols_per_chunk).min(nc);
            let data = &input.l[c0 * col_len..c1 * col_len];
            let size = (4 * data.len() as u64).max(16);
            let l = device.create_buffer(&wgpu::BufferDescriptor {
                label: Some("touchfem L chunk"),
                size,
                usage: usage_ro,
                mapped_at_creation: false,
            });
            if !data.is_empty() {
                queue.write_buffer(&l, 0, bytemuck::cast_slice(data));
                // Flush each chunk's staging copy so that peak memory stays near one chunk.
                queue.submit([]);
            }
            let bind_group = device.create_bind_group(&wgpu::BindGroupDescriptor {
                label: Some("touchfem L chunk"),
                layout: &layout1,
                entries: &[
                    binding(
                        0,
                        &chunk_params,
                        k as u64 * chunk_param_stride,
                        CHUNK_PARAM_BYTES,
                    ),
                    binding(1, &l, 0, size),
                ],
            });
            chunks.push(Chunk {
                _l: l,
                bind_group,
                count: 0,
            });
        }

        let module = device.create_shader_module(wgpu::ShaderModuleDescriptor {
            label: Some("touchfem deform.wgsl"),
            source: wgpu::ShaderSource::Wgsl(DEFORM_WGSL.into()),
        });
        let pl_deform = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("touchfem deform"),
            bind_group_layouts: &[Some(&layout0), Some(&layout1)],
            immediate_size: 0,
        });
        let pl_normals = device.create_pipeline_layout(&wgpu::PipelineLayoutDescriptor {
            label: Some("touchfem normals"),
            bind_group_layouts: &[Some(&layout0)],
            immediate_size: 0,
        });
        let pipeline = |layout: &wgpu::PipelineLayout, entry: &str| {
            device.create_compute_pipeline(&wgpu::ComputePipelineDescriptor {
                label: Some(entry),
                layout: Some(layout),
                module: &module,
                entry_point: Some(entry),
                compilation_options: Default::default(),
                cache: None,
            })
        };
        let deform_pipeline = pipeline(&pl_deform, "deform");
        let normals_pipeline = pipeline(&pl_normals, "normals");

        let mut d = Deformer {
            n_rows: nr as u32,
            n_cols: nc,
            cols_per_chunk,
            chunks,
            chunk_param_stride,
            chunk_params,
            active,
            bind_group,
            deform_pipeline,
            normals_pipeline,
            write_normals: target.normal_offset.is_some(),
            target,
            index_buffer,
            triangles: tris,
            scratch: Vec::with_capacity(MAX_ACTIVE),
        };
        d.set_forces(queue, &[])?;
        Ok(d)
    }

    /// Sets this frame's force boundary condition: `(column index, force in newtons)` pairs.
    /// Columns may repeat (their forces add). Writes `16·forces.len()` bytes plus 16 bytes per
    /// chunk; takes effect for the next [`encode`](Self::encode)d pass submitted after it.
    ///
    /// Errors (and then changes nothing): more than [`MAX_ACTIVE`] entries, a column out of
    /// range, a non-finite force.
    pub fn set_forces(
        &mut self,
        queue: &wgpu::Queue,
        forces: &[(u32, [f32; 3])],
    ) -> Result<(), GpuError> {
        if forces.len() > MAX_ACTIVE {
            return Err(GpuError::TooManyActive {
                count: forces.len(),
                max: MAX_ACTIVE,
            });
        }
        for &(col, force) in forces {
            if col as usize >= self.n_cols {
                return Err(GpuError::ColumnOutOfRange {
                    col,
                    n_cols: self.n_cols,
                });
            }
            if !force.iter().all(|v| v.is_finite()) {
                return Err(GpuError::NonFiniteForce { col, force });
            }
        }
        // Group the entries by chunk (counting sort), columns local to their chunk.
        let cpc = self.cols_per_chunk;
        for ch in &mut self.chunks {
            ch.count = 0;
        }
        for &(col, _) in forces {
            self.chunks[col as usize / cpc].count += 1;
        }
        let mut first = Vec::with_capacity(self.chunks.len());
        let mut acc = 0u32;
        for (k, ch) in self.chunks.iter().enumerate() {
            first.push(acc);
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
            self.scratch[first[k] as usize] = ActiveGpu {
                force,
                col: (col as usize - k * cpc) as u32,
            };
            first[k] += 1;
        }
        if !self.scratch.is_empty() {
            queue.write_buffer(&self.active, 0, bytemuck::cast_slice(&self.scratch));
        }
        Ok(())
    }

    /// Records the deformation and normal passes (one compute pass) into `encoder`. Draw from
    /// [`vertex_buffer`](Self::vertex_buffer) in a later pass of the same or a later submission.
    pub fn encode(&self, encoder: &mut wgpu::CommandEncoder) {
        let groups = self.n_rows.div_ceil(WORKGROUP);
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("touchfem deform"),
            timestamp_writes: None,
        });
        pass.set_pipeline(&self.deform_pipeline);
        pass.set_bind_group(0, &self.bind_group, &[]);
        for (k, ch) in self.chunks.iter().enumerate() {
            if k == 0 || ch.count > 0 {
                pass.set_bind_group(1, &ch.bind_group, &[]);
                pass.dispatch_workgroups(groups, 1, 1);
            }
        }
        if self.write_normals {
            pass.set_pipeline(&self.normals_pipeline);
            pass.set_bind_group(0, &self.bind_group, &[]);
            pass.dispatch_workgroups(groups, 1, 1);
        }
    }

    /// The buffer the vertices are written to: the deformer's own (layout: [`Vertex`],
    /// usage `STORAGE | VERTEX | COPY_SRC | COPY_DST`) or the [`OutputTarget`]'s.
    pub fn vertex_buffer(&self) -> &wgpu::Buffer {
        &self.target.buffer
    }

    /// Where and how vertices are written (offset, stride, normal offset).
    pub fn output(&self) -> &OutputTarget {
        &self.target
    }

    /// The surface triangles in vertex (row) indices, `u32`, usage `INDEX | STORAGE`; draw
    /// [`index_count`](Self::index_count) indices.
    pub fn index_buffer(&self) -> &wgpu::Buffer {
        &self.index_buffer
    }

    /// Number of indices in [`index_buffer`](Self::index_buffer) (3 per triangle).
    pub fn index_count(&self) -> u32 {
        3 * self.triangles.len() as u32
    }

    /// The surface triangles in vertex (row) indices (CPU copy).
    pub fn triangles(&self) -> &[[u32; 3]] {
        &self.triangles
    }

    /// Number of displayed vertices R.
    pub fn vertex_count(&self) -> u32 {
        self.n_rows
    }

    /// Number of touchable columns C.
    pub fn column_count(&self) -> usize {
        self.n_cols
    }

    /// Number of storage buffers `L` is split into.
    pub fn chunk_count(&self) -> usize {
        self.chunks.len()
    }

    /// Column nodes per chunk.
    pub fn columns_per_chunk(&self) -> usize {
        self.cols_per_chunk
    }

    /// Reads the vertices back (waits for the GPU): positions, and normals if written. The
    /// output buffer needs `COPY_SRC`. For tests and tools, not for the frame loop.
    #[allow(clippy::type_complexity)]
    pub fn read_back(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
    ) -> Result<(Vec<[f32; 3]>, Option<Vec<[f32; 3]>>), GpuError> {
        let t = &self.target;
        if !t.buffer.usage().contains(wgpu::BufferUsages::COPY_SRC) {
            return Err(GpuError::Readback(
                "the output buffer's usage lacks COPY_SRC".into(),
            ));
        }
        let n = u64::from(self.n_rows);
        let end = t.offset + (n - 1) * t.stride + t.normal_offset.unwrap_or(0) + 12;
        let start = t.offset & !3;
        let bytes = super::read_buffer(device, queue, &t.buffer, start, (end - start + 3) & !3)?;
        let word = |o: u64| -> [f32; 3] {
            let o = (o - start) as usize;
            let f =
                |i: usize| f32::from_le_bytes(bytes[o + 4 * i..o + 4 * i + 4].try_into().unwrap());
            [f(0), f(1), f(2)]
        };
        let pos = (0..n).map(|i| word(t.offset + i * t.stride)).collect();
        let nrm = t
            .normal_offset
            .map(|no| (0..n).map(|i| word(t.offset + i * t.stride + no)).collect());
        Ok((pos, nrm))
    }
}

/// Checks an output target; returns (binding start, binding size, word offset of vertex 0
/// inside the binding, normal word offset or [`NO_NORMALS`]).
fn validate_target(
    t: &OutputTarget,
    n: u64,
    limits: &wgpu::Limits,
) -> Result<(u64, u64, u32, u32), GpuError> {
    let bad = |m: String| Err(GpuError::BadOutput(m));
    if !t.buffer.usage().contains(wgpu::BufferUsages::STORAGE) {
        return bad("the buffer's usage must include STORAGE".into());
    }
    if !t.offset.is_multiple_of(4) || !t.stride.is_multiple_of(4) {
        return bad(format!(
            "offset {} and stride {} must be multiples of 4",
            t.offset, t.stride
        ));
    }
    if t.stride < 12 {
        return bad(format!("stride {} is below 12 bytes", t.stride));
    }
    let span = match t.normal_offset {
        Some(no) => {
            if !no.is_multiple_of(4) || no < 12 || no + 12 > t.stride {
                return bad(format!(
                    "normal offset {no} must be a multiple of 4 in [12, stride − 12]"
                ));
            }
            no + 12
        }
        None => 12,
    };
    let end = t.offset + (n - 1) * t.stride + span;
    if end > t.buffer.size() {
        return bad(format!(
            "{n} vertices need {end} bytes, the buffer has {}",
            t.buffer.size()
        ));
    }
    let align = u64::from(limits.min_storage_buffer_offset_alignment);
    let start = t.offset / align * align;
    let word = (t.offset - start) / 4;
    Ok((
        start,
        end - start,
        word as u32,
        t.normal_offset.map_or(NO_NORMALS, |no| (no / 4) as u32),
    ))
}
