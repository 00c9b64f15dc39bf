//! [`Deformer`]: `u = L·F` and vertex normals on the GPU, into a vertex buffer.

use glam::DVec3;
use wgpu::util::DeviceExt;

use crate::buffer_path::BufferPath;
use crate::context::GpuError;
use crate::correct::{CorrectionPass, CorrectionTarget};
use crate::hier_path::HierPath;
use crate::input::{
    DeformerInput, DeformerOptions, FrameGpu, LData, LStorage, OutputTarget, Shared, Vertex,
    MAX_ACTIVE, NO_NORMALS, VERTEX_STRIDE, WORKGROUP,
};
use crate::texture_path::TexturePath;
use touchfem_core::compliance::correction::Correction;

enum Path {
    Buffers(BufferPath),
    Texture(TexturePath),
    Hier(HierPath),
}

/// Evaluates the deformation `x = x_rest + Σ_active L[:, c]·F_c` and the vertex normals of the
/// deformed surface on the GPU, writing straight into a vertex buffer.
///
/// `L` is uploaded once (f32, or half floats) in the [`LStorage`] layout; a hierarchical `L`
/// ([`LData::Hier`]) in its compressed form ([`LStorage::Hier`]). Per frame,
/// [`set_forces`](Self::set_forces) writes only the active columns and forces (16 bytes each,
/// plus a 16-byte record per `L` buffer, or the 4-byte count for the texture layout — nothing
/// at all for a short list passed as immediates, see [`uses_immediates`](Self::uses_immediates));
/// [`encode`](Self::encode) records one compute pass into the caller's encoder: the
/// deformation dispatch(es), then the normal pass, which gathers over precomputed per-vertex
/// adjacency (incident triangles, or triangle fans in the texture layout; WGSL has no float
/// atomics).
///
/// **Cuts.** [`set_correction`](Self::set_correction) carries a cut's exact low-rank correction
/// ([`Correction`]: `u = L·F + U_R z`) as one more dispatch between the two, whatever the
/// [`LStorage`]; [`set_triangles`](Self::set_triangles) takes the opened surface.
pub struct Deformer {
    n_rows: u32,
    n_cols: usize,
    l_rows: usize,
    path: Path,
    target: OutputTarget,
    write_normals: bool,
    index_buffer: wgpu::Buffer,
    triangles: Vec<[u32; 3]>,
    /// For each mesh node up to the largest row's, its row or `u32::MAX`.
    row_of: Vec<u32>,
    /// Rest positions per row (the correction pass puts pinned rows back there).
    rest_rows: Vec<[f32; 4]>,
    /// The output binding: start and size in bytes, vertex 0's word and the stride in words.
    out_binding: (u64, u64, u32, u32),
    vertex_layout: bool,
    max_binding: u64,
    /// The cut's correction, once one was set.
    correction: Option<CorrectionPass>,
    /// This frame's forces (the correction's weights are recomputed from them when it changes).
    forces: Vec<(u32, [f32; 3])>,
    /// Bumped by each [`set_triangles`](Self::set_triangles).
    surface_generation: u64,
    /// Leading triangles without a crease ([`smooth_triangles`](Self::smooth_triangles)).
    smooth: u32,
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
        let tris = rows_of_triangles(&row_of, triangles)?;
        // Triangles without a crease first (a renderer shades them more cheaply), each part in
        // the given order.
        let smooth = smooth_mask(&rest_rows, &tris);
        let n_smooth = smooth.iter().filter(|&&s| s).count() as u32;
        let tris: Vec<[u32; 3]> = (tris.iter().zip(&smooth).filter(|p| *p.1))
            .chain(tris.iter().zip(&smooth).filter(|p| !*p.1))
            .map(|p| *p.0)
            .collect();

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

        let (index_buffer, index_words) = index_buffer(device, &tris);

        let shared = Shared {
            half: matches!(
                options.storage,
                LStorage::BuffersF16 | LStorage::TextureF16 | LStorage::AutoF16 | LStorage::HierF16
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
            index_words,
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
                && limits.max_immediate_size >= crate::shaders::IMMEDIATE_BYTES,
        };
        shared.check("output binding", out_size)?;
        let hier = match input.l {
            LData::Hier(h) => Some(h),
            _ => None,
        };
        // The texture passes bind three storage textures each.
        let textures_ok = limits.max_storage_textures_per_shader_stage >= 3;
        let texture = match options.storage {
            _ if hier.is_some() => false,
            LStorage::Hier | LStorage::HierF16 => {
                return Err(GpuError::Unsupported(
                    "LStorage::Hier for a dense L: only a hierarchical L (LData::Hier) has \
                     the compressed layout"
                        .into(),
                ))
            }
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
        let path = if let Some(h) = hier {
            Path::Hier(HierPath::new(&shared, h)?)
        } else if texture {
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
            l_rows: nl,
            path,
            write_normals: target.normal_offset.is_some(),
            target,
            index_buffer,
            triangles: tris,
            row_of,
            rest_rows,
            out_binding: (
                out_start,
                out_size,
                out_word,
                (options.output.as_ref().map_or(VERTEX_STRIDE, |t| t.stride) / 4) as u32,
            ),
            vertex_layout,
            max_binding,
            correction: None,
            forces: Vec::with_capacity(MAX_ACTIVE),
            surface_generation: 0,
            smooth: n_smooth,
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
            Path::Hier(p) => p.set_forces(queue, forces),
        }
        if let Some(c) = &mut self.correction {
            c.set_forces(queue, forces);
        }
        self.forces.clear();
        self.forces.extend_from_slice(forces);
        Ok(())
    }

    /// Carries a cut's correction (`None`: none): from the next [`encode`](Self::encode)d
    /// pass, `u = L·F + U_R z` with `z = Σ_c V_cᵀ F_c` computed on the CPU from the forces of
    /// each [`set_forces`](Self::set_forces) (and from the current ones now), `U` on the
    /// rows that hold `L` uploaded as `rank` extra f32 columns (in every [`LStorage`],
    /// f16 ones included), and the rows the cut pinned held at rest. This is
    /// [`Compliance::displace`](touchfem_core::compliance::Compliance::displace) of a compliance
    /// that carries `correction`. Uploads `16·R'·rank` bytes, re-allocating only when the rank
    /// outgrows what was allocated; a rank-0 correction that pins nothing costs no dispatch.
    ///
    /// Errors (and then changes nothing): a correction whose sizes do not fit this deformer's
    /// rows and columns ([`GpuError::BadInput`]), a rank above
    /// [`MAX_CORRECTION_RANK`](crate::MAX_CORRECTION_RANK) or `U` larger than a storage binding
    /// ([`GpuError::BufferTooLarge`]; draw that cut with the CPU's `displace`).
    pub fn set_correction(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        correction: Option<&Correction>,
    ) -> Result<(), GpuError> {
        let Some(k) = correction else {
            if let Some(c) = &mut self.correction {
                c.set(device, queue, &Correction::default(), self.max_binding)?;
            }
            return Ok(());
        };
        if matches!(self.path, Path::Hier(_)) {
            return Err(GpuError::Unsupported(
                "a cut's correction on a hierarchical L (a hierarchical compliance cannot be \
                 cut)"
                    .into(),
            ));
        }
        let (nl, nc, r) = (self.l_rows, self.n_cols, k.rank);
        if k.rows.len() != 3 * nl * r
            || k.v_cols.len() != 3 * nc * r
            || k.dead_rows.len() != nl
            || k.dead_cols.len() != nc
        {
            return Err(GpuError::BadInput(format!(
                "a correction of rank {r} for {} rows and {} columns does not fit the \
                 deformer's {nl} rows that hold L and {nc} columns",
                k.dead_rows.len(),
                k.dead_cols.len()
            )));
        }
        crate::correct::check_size(nl, r, self.max_binding)?;
        if self.correction.is_none() {
            let (start, size, word, stride) = self.out_binding;
            let positions = match &self.path {
                Path::Buffers(_) | Path::Hier(_) => None,
                Path::Texture(p) => Some(p.positions()),
            };
            let pass = CorrectionPass::new(
                device,
                &CorrectionTarget {
                    out: (&self.target.buffer, start, size),
                    out_word: word,
                    stride_words: stride,
                    vertex_layout: self.vertex_layout,
                    positions,
                    rest_rows: &self.rest_rows[..nl],
                },
            );
            self.correction = Some(pass);
        }
        let c = self.correction.as_mut().expect("just made");
        c.set(device, queue, k, self.max_binding)?;
        c.set_forces(queue, &self.forces);
        Ok(())
    }

    /// The rank of the correction carried ([`set_correction`](Self::set_correction)); 0 when
    /// none.
    pub fn correction_rank(&self) -> usize {
        self.correction.as_ref().map_or(0, |c| c.rank())
    }

    /// Replaces the surface drawn and shaded: `triangles` as **mesh node** indices,
    /// counter-clockwise seen from outside (as for [`new`](Self::new); e.g. a cut's opened
    /// surface, [`touchfem_core::Mesh::open_surface`]). Makes a new
    /// [`index_buffer`](Self::index_buffer) ([`index_count`](Self::index_count) follows) and
    /// the normal pass's adjacency, so that new faces get their normals from the next
    /// [`encode`](Self::encode)d pass. The vertices stay one per displayed row: every node of
    /// `triangles` must be one (a cuttable region's nodes are, see the scene key `cuttable`).
    ///
    /// Errors (and then changes nothing): a node that is not a displayed row
    /// ([`GpuError::BadInput`]), adjacency beyond the device's limits.
    pub fn set_triangles(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        triangles: &[[u32; 3]],
    ) -> Result<(), GpuError> {
        let tris = rows_of_triangles(&self.row_of, triangles)?;
        let (index_buffer, words) = index_buffer(device, &tris);
        match &mut self.path {
            Path::Buffers(p) => {
                p.set_triangles(device, &tris, (&index_buffer, words), self.max_binding)?
            }
            Path::Texture(p) => p.set_triangles(device, queue, &tris)?,
            Path::Hier(p) => {
                p.set_triangles(device, &tris, (&index_buffer, words), self.max_binding)?
            }
        }
        self.index_buffer = index_buffer;
        self.triangles = tris;
        self.surface_generation += 1;
        // A cut's faces meet the surface at an edge: shaded as creases, in the given order.
        self.smooth = 0;
        Ok(())
    }

    /// How many triangles, first in [`triangles`](Self::triangles) and the index buffer, have
    /// no crease: at rest each of their vertices' normals is within about 8° (cosine 0.99) of
    /// theirs. [`new`](Self::new) puts them first (the rest keep their order after them); after
    /// [`set_triangles`](Self::set_triangles) there are none. A renderer shades these with their
    /// vertex normals alone and the others with their facet normals at creases (found per
    /// pixel, most of a software rasteriser's fragment cost).
    pub fn smooth_triangles(&self) -> u32 {
        self.smooth
    }

    /// How many times [`set_triangles`](Self::set_triangles) replaced the surface (0 after
    /// [`new`](Self::new)): what a renderer compares to know when to rebuild what it derived
    /// from [`triangles`](Self::triangles) (e.g. its wireframe).
    pub fn surface_generation(&self) -> u64 {
        self.surface_generation
    }

    /// The vertex (row) index of mesh node `node`, if it is displayed.
    pub fn row_of(&self, node: u32) -> Option<u32> {
        self.row_of
            .get(node as usize)
            .copied()
            .filter(|&r| r != u32::MAX)
    }

    /// Records the deformation and normal passes (one compute pass) into `encoder`. Draw from
    /// [`vertex_buffer`](Self::vertex_buffer) in a later pass of the same or a later submission.
    pub fn encode(&self, encoder: &mut wgpu::CommandEncoder) {
        if let Path::Hier(p) = &self.path {
            p.record_reduce(encoder);
        }
        let mut pass = encoder.begin_compute_pass(&wgpu::ComputePassDescriptor {
            label: Some("touchfem deform"),
            timestamp_writes: None,
        });
        match &self.path {
            Path::Buffers(p) => p.record_deform(&mut pass, self.n_rows),
            Path::Texture(p) => p.record_deform(&mut pass, self.n_rows),
            Path::Hier(p) => p.record_deform(&mut pass, self.n_rows),
        }
        if let Some(c) = &self.correction {
            c.record(&mut pass);
        }
        if self.write_normals {
            match &self.path {
                Path::Buffers(p) => p.record_normals(&mut pass, self.n_rows),
                Path::Texture(p) => p.record_normals(&mut pass, self.n_rows),
                Path::Hier(p) => p.record_normals(&mut pass, self.n_rows),
            }
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

    /// The surface triangles in vertex (row) indices (CPU copy), in the index buffer's order:
    /// after [`new`](Self::new) those without a crease first
    /// ([`smooth_triangles`](Self::smooth_triangles)).
    pub fn triangles(&self) -> &[[u32; 3]] {
        &self.triangles
    }

    /// Number of displayed vertices R.
    pub fn vertex_count(&self) -> u32 {
        self.n_rows
    }

    /// The layout `L` is stored in ([`LStorage::Auto`] and [`LStorage::AutoF16`] resolved).
    pub fn storage(&self) -> LStorage {
        match self.path {
            Path::Buffers(ref b) if b.half() => LStorage::BuffersF16,
            Path::Buffers(_) => LStorage::Buffers,
            Path::Texture(ref t) if t.half() => LStorage::TextureF16,
            Path::Texture(_) => LStorage::Texture,
            Path::Hier(ref h) if h.half() => LStorage::HierF16,
            Path::Hier(_) => LStorage::Hier,
        }
    }

    /// Whether the active list travels as immediates (Vulkan push constants): the texture
    /// layout on a device with [`wgpu::Features::IMMEDIATES`] and 128 bytes of them, unless
    /// [`DeformerOptions::no_immediates`]. Then a frame with at most
    /// [`INLINE_ACTIVE`](crate::shaders::INLINE_ACTIVE) entries (two contact triangles' nodes) uploads
    /// nothing; [`set_forces`](Self::set_forces) keeps the list for the next
    /// [`encode`](Self::encode).
    pub fn uses_immediates(&self) -> bool {
        match &self.path {
            Path::Buffers(_) | Path::Hier(_) => false,
            Path::Texture(p) => p.uses_immediates(),
        }
    }

    /// Number of storage buffers ([`LStorage::Buffers`], or the values of [`LStorage::Hier`])
    /// or texture array layers ([`LStorage::Texture`]) `L` is split into.
    pub fn chunk_count(&self) -> usize {
        match &self.path {
            Path::Buffers(p) => p.chunk_count(),
            Path::Texture(p) => p.layer_count(),
            Path::Hier(p) => p.value_buffers(),
        }
    }

    /// Bytes the GPU holds for `L`: the storage buffers or the texture, and for
    /// [`LStorage::Hier`] its values, tables and per-frame work buffer (what
    /// [`hier_gpu_bytes`](crate::hier_gpu_bytes) estimates without a GPU).
    pub fn l_bytes(&self) -> u64 {
        match &self.path {
            Path::Buffers(p) => p.l_bytes(),
            Path::Texture(p) => p.l_bytes(),
            Path::Hier(p) => p.l_bytes(),
        }
    }

    /// For [`LStorage::Hier`], the uniform windows the last [`set_forces`](Self::set_forces)
    /// laid its tables out in (one a dispatch of the row pass; more than one only when many
    /// column leaves are active); `None` for the dense layouts.
    pub fn frame_windows(&self) -> Option<usize> {
        match &self.path {
            Path::Hier(p) => Some(p.frame_windows()),
            Path::Buffers(_) | Path::Texture(_) => None,
        }
    }

    /// Column nodes per storage buffer ([`LStorage::Buffers`]); `None` for the texture layout,
    /// which splits `L` by texel rows instead, and for the hierarchical one (by blocks).
    pub fn columns_per_chunk(&self) -> Option<usize> {
        match &self.path {
            Path::Buffers(p) => Some(p.cols_per_chunk()),
            Path::Texture(_) | Path::Hier(_) => None,
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
            return Err(crate::context::ReadbackError::NotCopySource.into());
        }
        let n = u64::from(self.n_rows);
        let end = t.offset + (n - 1) * t.stride + t.normal_offset.unwrap_or(0) + 12;
        let start = t.offset & !3;
        let bytes =
            crate::context::read_buffer(device, queue, &t.buffer, start, (end - start + 3) & !3)?;
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

/// `triangles` (mesh nodes) in row indices, through `row_of` (per node, its row or
/// `u32::MAX`); an error names the first node that is not a displayed row.
fn rows_of_triangles(row_of: &[u32], triangles: &[[u32; 3]]) -> Result<Vec<[u32; 3]>, GpuError> {
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
    Ok(tris)
}

/// The triangles' index buffer (`STORAGE | INDEX`, padded to at least 4 words) and how many
/// words of it to bind.
fn index_buffer(device: &wgpu::Device, tris: &[[u32; 3]]) -> (wgpu::Buffer, u64) {
    let mut words: Vec<u32> = tris.iter().flatten().copied().collect();
    let n = words.len().max(1);
    words.resize(n.max(4), 0);
    let b = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
        label: Some("touchfem triangles"),
        contents: bytemuck::cast_slice(&words),
        usage: wgpu::BufferUsages::STORAGE | wgpu::BufferUsages::INDEX,
    });
    (b, words.len() as u64)
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

/// Cosine of the largest angle between a triangle's and its vertices' normals on a surface
/// without creases: render.wgsl's `fs_surface` shades with the vertex normal alone from this
/// cosine on.
pub(crate) const CREASE_COS: f64 = 0.99;

/// Per triangle, whether it has no crease: its normal within acos([`CREASE_COS`]) of each of
/// its vertices' area-weighted normals (`rest`: positions per row; `tris`: row indices). A
/// degenerate triangle has a crease.
pub(crate) fn smooth_mask(rest: &[[f32; 4]], tris: &[[u32; 3]]) -> Vec<bool> {
    let at = |r: u32| {
        let p = rest[r as usize];
        DVec3::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2]))
    };
    let face = |t: &[u32; 3]| (at(t[1]) - at(t[0])).cross(at(t[2]) - at(t[0]));
    let mut vn = vec![DVec3::ZERO; rest.len()];
    for t in tris {
        let n = face(t);
        for &v in t {
            vn[v as usize] += n;
        }
    }
    tris.iter()
        .map(|t| {
            let n = face(t).normalize_or_zero();
            n != DVec3::ZERO
                && t.iter()
                    .all(|&v| n.dot(vn[v as usize].normalize_or_zero()) >= CREASE_COS)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use crate::input::{LData, LStorage};

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
        assert_eq!(a.f16_scale(), touchfem_core::compliance::f16_scale(&l32));
        assert_eq!(LData::F64(&[]).f16_scale(), 1.0);
    }

    /// The unit sphere subdivided `levels` times from an octahedron: positions and
    /// counter-clockwise triangles.
    fn sphere(levels: u32) -> (Vec<[f32; 4]>, Vec<[u32; 3]>) {
        let mut p: Vec<glam::DVec3> = [
            [1., 0., 0.],
            [-1., 0., 0.],
            [0., 1., 0.],
            [0., -1., 0.],
            [0., 0., 1.],
            [0., 0., -1.],
        ]
        .map(glam::DVec3::from)
        .to_vec();
        let mut t: Vec<[u32; 3]> = vec![
            [0, 2, 4],
            [2, 1, 4],
            [1, 3, 4],
            [3, 0, 4],
            [2, 0, 5],
            [1, 2, 5],
            [3, 1, 5],
            [0, 3, 5],
        ];
        for _ in 0..levels {
            let mut mid = std::collections::HashMap::new();
            let mut next = Vec::new();
            for &[a, b, c] in &t {
                let mut m = |i: u32, j: u32| {
                    *mid.entry((i.min(j), i.max(j))).or_insert_with(|| {
                        p.push((p[i as usize] + p[j as usize]).normalize());
                        p.len() as u32 - 1
                    })
                };
                let (ab, bc, ca) = (m(a, b), m(b, c), m(c, a));
                next.extend([[a, ab, ca], [ab, b, bc], [ca, bc, c], [ab, bc, ca]]);
            }
            t = next;
        }
        let rest = p
            .iter()
            .map(|v| [v.x as f32, v.y as f32, v.z as f32, 1.0])
            .collect();
        (rest, t)
    }

    #[test]
    fn creases_are_told_from_smooth_surfaces() {
        let smooth = |r: &[[f32; 4]], t: &[[u32; 3]]| {
            super::smooth_mask(r, t).iter().filter(|&&s| s).count()
        };
        // An octahedron's edges are creases, and a coarse sphere's (its facets 20° apart); a
        // finely subdivided sphere has none, however it is scaled.
        let (rest, t) = sphere(0);
        assert_eq!(smooth(&rest, &t), 0);
        let (rest, t) = sphere(1);
        assert_eq!(smooth(&rest, &t), 0);
        let (rest, t) = sphere(4);
        assert_eq!(smooth(&rest, &t), t.len());
        let big: Vec<[f32; 4]> = rest
            .iter()
            .map(|v| [v[0] * 80.0, v[1] * 80.0, v[2] * 80.0, 1.0])
            .collect();
        assert_eq!(smooth(&big, &t), t.len());
        // A sharp spike pulled out of the fine sphere: the triangles around it and their
        // neighbours (whose vertex normals it bends) are creased, the rest stay smooth.
        let mut spiked = rest.clone();
        spiked[0] = [3.0, 0.0, 0.0, 1.0];
        let around = t.iter().filter(|tri| tri.contains(&0)).count();
        let n = smooth(&spiked, &t);
        assert!(
            n < t.len() - around && n > t.len() * 9 / 10,
            "{n} of {}",
            t.len()
        );
        // A degenerate triangle is shaded as a crease.
        assert_eq!(smooth(&rest, &[[0, 0, 1]]), 0);
    }
}
