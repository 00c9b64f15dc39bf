//! What a [`crate::Deformer`] is given and what it hands its layouts of `L` (buffers, textures, hierarchical): the validated input
//! ([`DeformerInput`], [`LData`]), the options, the vertex format, and the per-frame uniforms.

use bytemuck::{Pod, Zeroable};

use crate::context::GpuError;
use touchfem_core::compliance::Compliance;

/// Most entries a force boundary condition may have per frame (the active-list buffer's size).
/// [`Deformer::set_forces`](crate::Deformer::set_forces) rejects more with [`GpuError::TooManyActive`].
pub const MAX_ACTIVE: usize = 1024;

/// Byte stride of the deformer's own vertex buffer: see [`Vertex`].
pub const VERTEX_STRIDE: u64 = std::mem::size_of::<Vertex>() as u64;

/// `normal_offset` value in the shader meaning "write no normals".
pub(crate) const NO_NORMALS: u32 = u32::MAX;

/// Invocations per workgroup of every deformer pass (the shaders' `@workgroup_size`).
pub(crate) const WORKGROUP: u32 = 64;

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
/// node); [`Deformer::index_buffer`](crate::Deformer::index_buffer) holds the surface triangles in these indices.
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
    pub(crate) const ATTRIBUTES: [wgpu::VertexAttribute; 2] =
        wgpu::vertex_attr_array![0 => Float32x4, 1 => Float32x4];

    /// The vertex buffer layout of [`Deformer::vertex_buffer`](crate::Deformer::vertex_buffer) when no [`OutputTarget`] was given.
    pub fn layout() -> wgpu::VertexBufferLayout<'static> {
        wgpu::VertexBufferLayout {
            array_stride: VERTEX_STRIDE,
            step_mode: wgpu::VertexStepMode::Vertex,
            attributes: &Self::ATTRIBUTES,
        }
    }
}

/// The compliance data the deformer needs, borrowed: displayed rows, column count and the f32
/// `L` in [`touchfem_core::compliance`]'s column-major layout. Build it from a [`Compliance`] with
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
            l: c.stored_l().into(),
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
    File(&'a dyn touchfem_core::compliance::LSource),
    /// Hierarchical (dense near blocks, low-rank far blocks).
    Hier(&'a touchfem_core::compliance::hmatrix::HMatrix),
}

impl<'a> From<touchfem_core::compliance::StoredL<'a>> for LData<'a> {
    fn from(l: touchfem_core::compliance::StoredL<'a>) -> Self {
        match l {
            touchfem_core::compliance::StoredL::Host(l) => LData::F64(l),
            touchfem_core::compliance::StoredL::File(f) => LData::File(f),
            touchfem_core::compliance::StoredL::Hier(h) => LData::Hier(h),
        }
    }
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
            LData::Hier(h) => h.dense_values(),
        }
    }

    /// Whether there are no entries.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Entries `range` in f32 (borrowed when already f32); an error if the file cannot be
    /// read or the range is out of bounds.
    pub(crate) fn f32_range(
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
            LData::Hier(_) => Err(GpuError::BadInput(
                "a hierarchical L has no dense entries to upload".into(),
            )),
        }
    }

    /// [`touchfem_core::compliance::f16_scale`] of the f32 entries.
    pub fn f16_scale(&self) -> f32 {
        let max = match *self {
            LData::F32(l) => l.iter().fold(0.0f32, |m, v| m.max(v.abs())),
            LData::F64(l) => l.iter().fold(0.0f32, |m, &v| m.max((v as f32).abs())),
            LData::File(f) => f.max_abs_f32(),
            LData::Hier(h) => h
                .values()
                .iter()
                .fold(0.0f32, |m, &v| m.max((v as f32).abs())),
        };
        touchfem_core::compliance::f16_scale_of_max(max)
    }
}

/// Where the deformer writes vertices: a caller's buffer (usage must include `STORAGE`; add
/// `VERTEX` to draw from it and `COPY_SRC` for [`Deformer::read_back`](crate::Deformer::read_back)).
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

/// How `L` is stored on the device. The dense layouts compute the same `u = L·F` (to f32
/// rounding) and write the same vertices; the hierarchical one computes `u = L_H·F` of the
/// compressed `L`, as [`HMatrix::displace`](touchfem_core::compliance::hmatrix::HMatrix::displace) does.
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
    /// A hierarchical `L` ([`LData::Hier`]) in its compressed form: dense near blocks and
    /// low-rank factors in f32 storage buffers (whole blocks each, up to
    /// [`HIER_VALUE_BINDINGS`](crate::HIER_VALUE_BINDINGS)) and its block tables; per frame
    /// `z = Vᵀf` for the far blocks the active columns hit, then `u` per row
    /// (`shaders/deform_hier.wgsl`). A hierarchical `L` always gets this layout (or
    /// [`HierF16`](Self::HierF16) when the option asks for half floats); asking for it with a
    /// dense `L` is [`GpuError::Unsupported`].
    Hier,
    /// [`Hier`](Self::Hier) with the values in half floats (the dense blocks and `U` scaled
    /// like [`BuffersF16`](Self::BuffersF16), `V` as is).
    HierF16,
}

impl LStorage {
    /// The storage a live session asks for in `TOUCHFEM_GPU_L`: `auto` (or unset), `f16`
    /// (auto's layout in half floats), `buffers`, `texture`, `buffers-f16`, `texture-f16`.
    /// Anything else is an error naming the accepted values.
    pub fn from_env() -> Result<LStorage, GpuError> {
        match crate::options::var("TOUCHFEM_GPU_L") {
            None => Ok(LStorage::Auto),
            Some(v) => match v.trim() {
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

/// Options for [`Deformer::new`](crate::Deformer::new).
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
    /// [`DeformerStats::uses_immediates`](crate::DeformerStats::uses_immediates)).
    pub no_immediates: bool,
    /// Vertices reserved after the displayed rows for the nodes a separating cut adds (the
    /// copies of split nodes, and exposed nodes that are not displayed rows): a grown
    /// correction ([`Deformer::set_correction_at`](crate::Deformer::set_correction_at)) draws
    /// up to this many. The vertex buffer holds `rows + extra_vertices` vertices (an
    /// [`OutputTarget`] must too). 0 (the default): none.
    pub extra_vertices: usize,
}

/// The fixed part of the pass parameters (`shaders/frame.wgsl`'s `Frame`), shared by the
/// buffer and hierarchical layouts and the correction pass.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, Pod, Zeroable)]
pub(crate) struct FrameGpu {
    pub n_rows: u32,
    pub out_offset: u32,
    pub out_stride: u32,
    pub normal_offset: u32,
    /// Rows that hold `L` (the first ones; the others stay at rest).
    pub l_rows: u32,
    /// Vertices the normal pass shades: the rows and the reserved extra vertices.
    pub n_vertices: u32,
    pub _pad: [u32; 2],
}

/// What [`Deformer::new`] hands to a layout: validated input, in row indices.
pub(crate) struct Shared<'a> {
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
    pub frame: FrameGpu,
    /// Output buffer, binding start and size in bytes.
    pub out: (&'a wgpu::Buffer, u64, u64),
    /// Byte cap of one `L` buffer or texture layer.
    pub max_chunk: u64,
    /// `min(max_storage_buffer_binding_size, max_buffer_size)`.
    pub max_binding: u64,
    /// Pass the active list as immediates ([`crate::shaders::IMMEDIATE_BYTES`] of them).
    pub immediates: bool,
    /// The output is the deformer's own buffer of [`Vertex`]es (offset 0, stride 32, `w`
    /// components defined), bound whole.
    pub vertex_layout: bool,
    /// Store `L` as half floats ([`LStorage::BuffersF16`]).
    pub half: bool,
}

impl Shared<'_> {
    /// `BufferTooLarge` if a binding of `bytes` exceeds the device's storage binding limit.
    pub(crate) fn check(&self, what: &'static str, bytes: u64) -> Result<(), GpuError> {
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
