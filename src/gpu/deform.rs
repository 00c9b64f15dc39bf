//! [`Deformer`]: `u = L·F` and vertex normals on the GPU, into a vertex buffer.

use bytemuck::{Pod, Zeroable};
use glam::DVec3;
use wgpu::util::DeviceExt;

use super::buffer_path::BufferPath;
use super::texture_path::TexturePath;
use super::GpuError;
use crate::compliance::Compliance;

/// Most entries a force boundary condition may have per frame (the active-list buffer's size).
/// [`Deformer::set_forces`] rejects more with [`GpuError::TooManyActive`].
pub const MAX_ACTIVE: usize = 1024;

/// Byte stride of the deformer's own vertex buffer: see [`Vertex`].
pub const VERTEX_STRIDE: u64 = std::mem::size_of::<Vertex>() as u64;

/// `normal_offset` value in the shader meaning "write no normals".
pub const NO_NORMALS: u32 = u32::MAX;

/// Invocations per workgroup of every deformer pass (the shaders' `@workgroup_size`).
pub(super) const WORKGROUP: u32 = 64;

/// One vertex of the deformer's own vertex buffer: 32 bytes, interleaved.
///
/// | bytes  | WGSL        | content                                          | location |
/// |--------|-------------|--------------------------------------------------|----------|
/// | 0..16  | `vec4<f32>` | deformed position in metres, `w` = \|u\| (m)      | 0        |
/// | 16..32 | `vec4<f32>` | unit area-weighted vertex normal, `w = 0`        | 1        |
///
/// `w` of the position is the magnitude of the vertex's displacement `u = L·F` in metres (0 at
/// rest), written by the same pass: the renderer colours the surface by it. Vertex `i` is
/// displayed row `i` of the compliance ([`Compliance::rows`]`()[i]` is its mesh
/// node); [`Deformer::index_buffer`] holds the surface triangles in these indices.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct Vertex {
    /// Deformed position (m), `w` = \|u\|, the displacement's magnitude (m).
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
    /// How many of the first `rows` hold `L` (R'); the others (clamped nodes) stay at rest.
    /// `rows.len()` when every row is stored.
    pub l_rows: usize,
    /// Number of touchable columns C.
    pub n_cols: usize,
    /// `L`, `9·R'·C` entries, entry (row r, axis a; column c, axis b) at
    /// `(3c+b)·3R' + 3r + a`.
    pub l: LData<'a>,
}

impl<'a> From<&'a Compliance> for DeformerInput<'a> {
    fn from(c: &'a Compliance) -> Self {
        DeformerInput {
            rows: c.rows(),
            l_rows: c.l_rows(),
            n_cols: c.cols().len(),
            l: c.l_data(),
        }
    }
}

/// `L`'s entries as the deformer reads them: f32, f64 (a [`Compliance`]'s own) or a cache
/// file (a compliance that holds only the haptic blocks), rounded to f32 a chunk at a time
/// while uploading, so the host never holds an f32 copy of `L`.
#[derive(Clone, Copy, Debug)]
pub enum LData<'a> {
    /// Single precision, as stored on the GPU.
    F32(&'a [f32]),
    /// Double precision, rounded on upload.
    F64(&'a [f64]),
    /// In a checked cache file, read and rounded on upload.
    File(&'a crate::cache::FileL),
}

impl<'a> From<&'a [f32]> for LData<'a> {
    fn from(l: &'a [f32]) -> Self {
        LData::F32(l)
    }
}

impl<'a> LData<'a> {
    /// Number of entries.
    pub fn len(&self) -> usize {
        match self {
            LData::F32(l) => l.len(),
            LData::F64(l) => l.len(),
            LData::File(f) => f.len(),
        }
    }

    /// Whether there are no entries.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Entries `range` in f32 (borrowed when already f32); an error if the file cannot be
    /// read or the range is out of bounds.
    pub fn f32_range(
        &self,
        range: std::ops::Range<usize>,
    ) -> Result<std::borrow::Cow<'a, [f32]>, GpuError> {
        let bad = || GpuError::BadInput(format!("L entries {range:?} of {}", self.len()));
        match *self {
            LData::F32(l) => l.get(range.clone()).map(Into::into).ok_or_else(bad),
            LData::F64(l) => l
                .get(range.clone())
                .map(|v| v.iter().map(|&v| v as f32).collect())
                .ok_or_else(bad),
            LData::File(f) => f
                .read_f32(range)
                .map(Into::into)
                .map_err(|e| GpuError::BadInput(e.to_string())),
        }
    }

    /// [`crate::compliance::f16_scale`] of the f32 entries.
    pub fn f16_scale(&self) -> f32 {
        let max = match *self {
            LData::F32(l) => l.iter().fold(0.0f32, |m, v| m.max(v.abs())),
            LData::F64(l) => l.iter().fold(0.0f32, |m, &v| m.max((v as f32).abs())),
            LData::File(f) => f.max_abs_f32(),
        };
        crate::compliance::f16_scale_of_max(max)
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

/// How `L` is stored on the device. Both layouts compute the same `u = L·F` (to f32 rounding)
/// and write the same vertices.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum LStorage {
    /// [`Texture`](Self::Texture) on CPU adapters (software rasterisers such as lavapipe) that
    /// allow three storage textures per stage, [`Buffers`](Self::Buffers) on everything else.
    #[default]
    Auto,
    /// Storage buffers, split by column nodes under `max_storage_buffer_binding_size`:
    /// coalesced reads on hardware GPUs; `9·R'·C` floats (R' = [`DeformerInput::l_rows`]).
    Buffers,
    /// Read-only storage textures (a 2D array for `L`) read with `textureLoad`: vector gathers
    /// on software rasterisers, 5–7× faster than storage buffers on lavapipe; `12·R'·C` floats
    /// (one pad per three).
    Texture,
    /// Storage buffers of half floats (IEEE binary16, two per `u32` word, read with WGSL's
    /// `unpack2x16float`: wgpu's downlevel flag `SHADER_F16_IN_F32`, which every native
    /// backend has, not the `shader-f16` feature): half the memory of
    /// [`Buffers`](Self::Buffers), `4.5·R'·C` words. Its error against the f64 `L·F` is at most
    /// 2·10⁻³ of the largest displacement (`tests/gpu_f16.rs`).
    BuffersF16,
    /// [`Texture`](Self::Texture) with `L` as half floats (`Rgba16Float`, scaled like
    /// [`BuffersF16`](Self::BuffersF16)): half the memory of the f32 texture, the software
    /// rasteriser's fast path.
    TextureF16,
    /// [`Auto`](Self::Auto)'s layout in half floats: [`TextureF16`](Self::TextureF16) or
    /// [`BuffersF16`](Self::BuffersF16).
    AutoF16,
}

impl LStorage {
    /// The storage a live session asks for in `TOUCHFEM_GPU_L`: `auto` (or unset), `f16`
    /// (auto's layout in half floats), `buffers`, `texture`, `buffers-f16`, `texture-f16`.
    /// Anything else is an error naming the accepted values.
    pub fn from_env() -> Result<LStorage, GpuError> {
        match std::env::var("TOUCHFEM_GPU_L") {
            Err(_) => Ok(LStorage::Auto),
            Ok(v) => match v.trim() {
                "" | "auto" => Ok(LStorage::Auto),
                "f16" => Ok(LStorage::AutoF16),
                "buffers" => Ok(LStorage::Buffers),
                "texture" => Ok(LStorage::Texture),
                "buffers-f16" => Ok(LStorage::BuffersF16),
                "texture-f16" => Ok(LStorage::TextureF16),
                other => Err(GpuError::BadInput(format!(
                    "TOUCHFEM_GPU_L={other:?}: expected auto, f16, buffers, texture, \
                     buffers-f16 or texture-f16"
                ))),
            },
        }
    }
}

/// Options for [`Deformer::new`].
#[derive(Clone, Debug, Default)]
pub struct DeformerOptions {
    /// Cap on the bytes of one `L` storage buffer ([`LStorage::Buffers`]) or texture layer
    /// ([`LStorage::Texture`]), below the device's limits (mainly to test the split).
    pub max_binding_bytes: Option<u64>,
    /// Write into this buffer instead of a new one with the [`Vertex`] layout.
    pub output: Option<OutputTarget>,
    /// How to store `L`.
    pub storage: LStorage,
    /// Never pass the active list as immediates, even where the device has
    /// [`wgpu::Features::IMMEDIATES`] (the texture layout uses them by default; see
    /// [`Deformer::uses_immediates`]).
    pub no_immediates: bool,
}

/// The fixed part of the pass parameters, common to both layouts.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
pub(super) struct FrameGpu {
    pub n_rows: u32,
    pub out_offset: u32,
    pub out_stride: u32,
    pub normal_offset: u32,
    /// Rows that hold `L` (the first ones; the others stay at rest).
    pub l_rows: u32,
    pub _pad: [u32; 3],
}

/// What [`Deformer::new`] hands to a layout: validated input, in row indices.
pub(super) struct Shared<'a> {
    pub device: &'a wgpu::Device,
    pub queue: &'a wgpu::Queue,
    /// Column-major `L` ([`DeformerInput::l`]).
    pub l: LData<'a>,
    pub nr: usize,
    /// Rows that hold `L` ([`DeformerInput::l_rows`]).
    pub nl: usize,
    pub nc: usize,
    /// Rest positions per row, metres, `w = 1`.
    pub rest_rows: &'a [[f32; 4]],
    /// Surface triangles in row indices.
    pub tris: &'a [[u32; 3]],
    /// The triangles as `u32` words (`STORAGE | INDEX`), and how many words to bind.
    pub index_buffer: &'a wgpu::Buffer,
    pub index_words: u64,
    pub frame: FrameGpu,
    /// Output buffer, binding start and size in bytes.
    pub out: (&'a wgpu::Buffer, u64, u64),
    /// Byte cap of one `L` buffer or texture layer.
    pub max_chunk: u64,
    /// `min(max_storage_buffer_binding_size, max_buffer_size)`.
    pub max_binding: u64,
    /// Pass the active list as immediates ([`super::IMMEDIATE_BYTES`] of them).
    pub immediates: bool,
    /// The output is the deformer's own buffer of [`Vertex`]es (offset 0, stride 32, `w`
    /// components defined), bound whole.
    pub vertex_layout: bool,
    /// Store `L` as half floats ([`LStorage::BuffersF16`]).
    pub half: bool,
}

impl Shared<'_> {
    /// `BufferTooLarge` if a binding of `bytes` exceeds the device's storage binding limit.
    pub(super) fn check(&self, what: &'static str, bytes: u64) -> Result<(), GpuError> {
        if bytes > self.max_binding {
            Err(GpuError::BufferTooLarge {
                what,
                bytes,
                limit: self.max_binding,
            })
        } else {
            Ok(())
        }
    }
}

enum Path {
    Buffers(BufferPath),
    Texture(TexturePath),
}

/// Evaluates the deformation `x = x_rest + Σ_active L[:, c]·F_c` and the vertex normals of the
/// deformed surface on the GPU, writing straight into a vertex buffer.
///
/// `L` is uploaded once (f32) in the [`LStorage`] layout. Per frame,
/// [`set_forces`](Self::set_forces) writes only the active columns and forces (16 bytes each,
/// plus a 16-byte record per `L` buffer, or the 4-byte count for the texture layout — nothing
/// at all for a short list passed as immediates, see [`uses_immediates`](Self::uses_immediates));
/// [`encode`](Self::encode) records one compute pass into the caller's encoder: the
/// deformation dispatch(es), then the normal pass, which gathers over precomputed per-vertex
/// adjacency (incident triangles, or triangle fans in the texture layout; WGSL has no float
/// atomics).
pub struct Deformer {
    n_rows: u32,
    n_cols: usize,
    path: Path,
    target: OutputTarget,
    write_normals: bool,
    index_buffer: wgpu::Buffer,
    triangles: Vec<[u32; 3]>,
}

impl std::fmt::Debug for Deformer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Deformer")
            .field("n_rows", &self.n_rows)
            .field("n_cols", &self.n_cols)
            .field("storage", &self.storage())
            .field("chunks", &self.chunk_count())
            .field("target", &self.target)
            .finish_non_exhaustive()
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
        let nl = input.l_rows;
        if nr == 0 {
            return Err(GpuError::BadInput("no displayed rows".into()));
        }
        if nl > nr || input.l.len() != 9 * nl * nc {
            return Err(GpuError::BadInput(format!(
                "L has {} entries, expected 9·{nl}·{nc} ({nl} of {nr} rows stored)",
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
        let list_bytes = 16 * MAX_ACTIVE as u64;
        if limits.max_uniform_buffer_binding_size < list_bytes {
            return Err(GpuError::BufferTooLarge {
                what: "the active-column list (one uniform binding)",
                bytes: list_bytes,
                limit: limits.max_uniform_buffer_binding_size,
            });
        }
        let max_groups = u64::from(limits.max_compute_workgroups_per_dimension);
        if (nr as u64).div_ceil(u64::from(WORKGROUP)) > max_groups {
            return Err(GpuError::BufferTooLarge {
                what: "the displayed rows (one invocation each)",
                bytes: nr as u64,
                limit: max_groups * u64::from(WORKGROUP),
            });
        }

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

        // Triangles in row indices.
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

        // Output target.
        let target = match &options.output {
            Some(t) => t.clone(),
            None => {
                let init: Vec<Vertex> = rest_rows
                    .iter()
                    .map(|&[x, y, z, _]| Vertex {
                        position: [x, y, z, 0.0],
                        normal: [0.0, 0.0, 1.0, 0.0],
                    })
                    .collect();
                let bytes = VERTEX_STRIDE * nr as u64;
                if bytes > max_binding {
                    return Err(GpuError::BufferTooLarge {
                        what: "vertex buffer",
                        bytes,
                        limit: max_binding,
                    });
                }
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
        let (out_start, mut out_size, out_word, normal_word) =
            validate_target(&target, nr as u64, &limits)?;
        // The deformer's own buffer holds whole `Vertex`es: the texture layout writes them one
        // vec4 at a time and binds all of it.
        let vertex_layout = options.output.is_none();
        if vertex_layout {
            out_size = VERTEX_STRIDE * nr as u64;
        }

        let mut tri_words: Vec<u32> = tris.iter().flatten().copied().collect();
        let n_tri_words = tri_words.len().max(1);
        tri_words.resize(n_tri_words.max(4), 0);
        let index_buffer = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
            label: Some("touchfem triangles"),
            contents: bytemuck::cast_slice(&tri_words),
            usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::INDEX,
        });

        let shared = Shared {
            half: matches!(
                options.storage,
                LStorage::BuffersF16 | LStorage::TextureF16 | LStorage::AutoF16
            ),
            device,
            queue,
            l: input.l,
            nr,
            nl,
            nc,
            rest_rows: &rest_rows,
            tris: &tris,
            index_buffer: &index_buffer,
            index_words: tri_words.len() as u64,
            frame: FrameGpu {
                n_rows: nr as u32,
                out_offset: out_word,
                out_stride: (target.stride / 4) as u32,
                normal_offset: normal_word,
                l_rows: nl as u32,
                _pad: [0; 3],
            },
            out: (&target.buffer, out_start, out_size),
            max_chunk,
            max_binding,
            vertex_layout,
            immediates: !options.no_immediates
                && device.features().contains(wgpu::Features::IMMEDIATES)
                && limits.max_immediate_size >= super::IMMEDIATE_BYTES,
        };
        shared.check("output binding", out_size)?;
        // The texture passes bind three storage textures each.
        let textures_ok = limits.max_storage_textures_per_shader_stage >= 3;
        let texture = match options.storage {
            LStorage::Texture | LStorage::TextureF16 if !textures_ok => {
                return Err(GpuError::Unsupported(format!(
                    "LStorage::Texture: it needs 3 storage textures per shader stage, the \
                     device allows {}",
                    limits.max_storage_textures_per_shader_stage
                )))
            }
            LStorage::Texture | LStorage::TextureF16 => true,
            LStorage::Buffers | LStorage::BuffersF16 => false,
            LStorage::Auto | LStorage::AutoF16 => {
                textures_ok && device.adapter_info().device_type == wgpu::DeviceType::Cpu
            }
        };
        let auto = matches!(options.storage, LStorage::Auto | LStorage::AutoF16);
        let path = if texture {
            // A texture too large for the device's memory (the f32 texture of a 45k-node
            // organ's whole surface, 3.8 GB, on lavapipe): `Auto` falls back to the buffers,
            // which need a quarter less (no pad); an asked-for texture is an error that says so.
            let oom = device.push_error_scope(wgpu::ErrorFilter::OutOfMemory);
            let invalid = device.push_error_scope(wgpu::ErrorFilter::Validation);
            let made = TexturePath::new(&shared);
            let invalid = pollster::block_on(invalid.pop());
            match (made, pollster::block_on(oom.pop()), invalid) {
                (Ok(t), None, None) => Path::Texture(t),
                (Err(e), None, _) => return Err(e),
                (_, None, Some(e)) => return Err(GpuError::BadInput(e.to_string())),
                (_, Some(_), _) if auto => Path::Buffers(BufferPath::new(&shared)?),
                (_, Some(e), _) => {
                    return Err(GpuError::BadInput(format!(
                        "L as a texture ({} bytes) does not fit the device's memory ({e}); \
                         the buffers (TOUCHFEM_GPU_L=buffers) need a quarter less, half \
                         floats (f16) half of that",
                        shared.l.len() / 3 * 4 * if shared.half { 2 } else { 4 }
                    )))
                }
            }
        } else {
            Path::Buffers(BufferPath::new(&shared)?)
        };

        let mut d = Deformer {
            n_rows: nr as u32,
            n_cols: nc,
            path,
            write_normals: target.normal_offset.is_some(),
            target,
            index_buffer,
            triangles: tris,
        };
        d.set_forces(queue, &[])?;
        Ok(d)
    }

    /// Sets this frame's force boundary condition: `(column index, force in newtons)` pairs.
    /// Columns may repeat (their forces add). Writes `16·forces.len()` bytes plus 16 bytes per
    /// chunk, or nothing when the list fits the immediates ([`uses_immediates`](Self::uses_immediates));
    /// takes effect for the next [`encode`](Self::encode)d pass submitted after it.
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
        match &mut self.path {
            Path::Buffers(p) => p.set_forces(queue, forces),
            Path::Texture(p) => p.set_forces(queue, forces),
        }
        Ok(())
    }

    /// Records the deformation and normal passes (one compute pass) into `encoder`. Draw from
    /// [`vertex_buffer`](Self::vertex_buffer) in a later pass of the same or a later submission.
    pub fn encode(&self, encoder: &mut wgpu::CommandEncoder) {
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("touchfem deform"),
            timestamp_writes: None,
        });
        match &self.path {
            Path::Buffers(p) => p.record(&mut pass, self.n_rows, self.write_normals),
            Path::Texture(p) => p.record(&mut pass, self.n_rows, self.write_normals),
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

    /// The layout `L` is stored in ([`LStorage::Auto`] and [`LStorage::AutoF16`] resolved).
    pub fn storage(&self) -> LStorage {
        match self.path {
            Path::Buffers(ref b) if b.half() => LStorage::BuffersF16,
            Path::Buffers(_) => LStorage::Buffers,
            Path::Texture(ref t) if t.half() => LStorage::TextureF16,
            Path::Texture(_) => LStorage::Texture,
        }
    }

    /// Whether the active list travels as immediates (Vulkan push constants): the texture
    /// layout on a device with [`wgpu::Features::IMMEDIATES`] and 128 bytes of them, unless
    /// [`DeformerOptions::no_immediates`]. Then a frame with at most
    /// [`INLINE_ACTIVE`](super::INLINE_ACTIVE) entries (two contact triangles' nodes) uploads
    /// nothing; [`set_forces`](Self::set_forces) keeps the list for the next
    /// [`encode`](Self::encode).
    pub fn uses_immediates(&self) -> bool {
        match &self.path {
            Path::Buffers(_) => false,
            Path::Texture(p) => p.uses_immediates(),
        }
    }

    /// Number of storage buffers ([`LStorage::Buffers`]) or texture array layers
    /// ([`LStorage::Texture`]) `L` is split into.
    pub fn chunk_count(&self) -> usize {
        match &self.path {
            Path::Buffers(p) => p.chunk_count(),
            Path::Texture(p) => p.layer_count(),
        }
    }

    /// Column nodes per storage buffer ([`LStorage::Buffers`]); `None` for the texture layout,
    /// which splits `L` by texel rows instead.
    pub fn columns_per_chunk(&self) -> Option<usize> {
        match &self.path {
            Path::Buffers(p) => Some(p.cols_per_chunk()),
            Path::Texture(_) => None,
        }
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

#[cfg(test)]
mod tests {
    use super::{LData, LStorage};

    #[test]
    fn storage_from_env_names_every_layout() {
        // The only test that touches TOUCHFEM_GPU_L.
        for (v, want) in [
            ("auto", LStorage::Auto),
            ("f16", LStorage::AutoF16),
            (" texture-f16 ", LStorage::TextureF16),
            ("buffers", LStorage::Buffers),
            ("buffers-f16", LStorage::BuffersF16),
            ("texture", LStorage::Texture),
        ] {
            std::env::set_var("TOUCHFEM_GPU_L", v);
            assert_eq!(LStorage::from_env().unwrap(), want, "{v}");
        }
        std::env::set_var("TOUCHFEM_GPU_L", "half");
        let e = LStorage::from_env().unwrap_err().to_string();
        assert!(e.contains("\"half\"") && e.contains("texture-f16"), "{e}");
        std::env::remove_var("TOUCHFEM_GPU_L");
        assert_eq!(LStorage::from_env().unwrap(), LStorage::Auto);
    }

    #[test]
    fn f64_data_uploads_as_its_f32_rounding() {
        let l64 = [1.0e-3, -2.5e-7, 3.0e-4 + 1e-12, 0.1, -0.7];
        let l32: Vec<f32> = l64.iter().map(|&v| v as f32).collect();
        let (a, b) = (LData::F64(&l64), LData::F32(&l32));
        assert_eq!(a.len(), 5);
        assert_eq!(
            a.f32_range(1..4).unwrap().as_ref(),
            b.f32_range(1..4).unwrap().as_ref()
        );
        assert_eq!(a.f32_range(0..5).unwrap().as_ref(), &l32[..]);
        assert!(a.f32_range(3..6).is_err());
        assert!(b.f32_range(6..6).is_err());
        // max |L| = 0.7: the nearest power of two in the log is 0.5.
        assert_eq!(a.f16_scale(), 0.5);
        assert_eq!(a.f16_scale(), crate::compliance::f16_scale(&l32));
        assert_eq!(LData::F64(&[]).f16_scale(), 1.0);
    }
}
