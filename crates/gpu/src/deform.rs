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
use crate::surface::{NormalPass, NormalsIo, Surface};
use crate::texture_path::TexturePath;
use touchfem_core::compliance::correction::Correction;
use touchfem_core::compliance::Compliance;

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
/// at all for a short list passed as immediates, see [`DeformerStats::uses_immediates`]);
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
    /// The rows and the vertices reserved for a separating cut's extra nodes
    /// ([`DeformerOptions::extra_vertices`]).
    n_vertices: u32,
    n_cols: usize,
    /// Extra columns the correction carried adds ([`Correction::extra`]): forces on columns
    /// `n_cols..n_cols + extra_cols` go to the correction alone.
    extra_cols: usize,
    /// Extra vertices the correction carried draws (its extra nodes without a row).
    extra_drawn: usize,
    l_rows: usize,
    path: Path,
    target: OutputTarget,
    write_normals: bool,
    /// The surface drawn and shaded, and its normal pass.
    surface: Surface,
    normals: NormalPass,
    /// Rest positions per row (the correction pass puts pinned rows back there).
    rest_rows: Vec<[f32; 4]>,
    /// The mesh node of each row.
    row_nodes: Vec<u32>,
    /// The output binding: start and size in bytes.
    out_binding: (u64, u64),
    /// The frame uniform every layout starts from (the correction pass's too).
    frame: FrameGpu,
    vertex_layout: bool,
    max_binding: u64,
    /// The cut's correction, once one was set.
    correction: Option<CorrectionPass>,
    /// This frame's forces (the correction's weights are recomputed from them when it changes).
    forces: Vec<(u32, [f32; 3])>,
    /// This frame's forces on columns of `L` (what the layouts take).
    l_forces: Vec<(u32, [f32; 3])>,
}

impl std::fmt::Debug for Deformer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("Deformer")
            .field("n_rows", &self.n_rows)
            .field("n_cols", &self.n_cols)
            .field("stats", &self.stats())
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
        let nv = nr + options.extra_vertices;
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
        if (nv as u64).div_ceil(u64::from(WORKGROUP)) > max_groups || nv > u32::MAX as usize / 2 {
            return Err(GpuError::BufferTooLarge {
                what: "the displayed rows and reserved vertices (one invocation each)",
                bytes: nv as u64,
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

        // The surface, in row indices (an error names a node that is not a row).
        let surface = Surface::new(device, input.rows, &rest_rows, triangles)?;

        // Output target.
        let target = match &options.output {
            Some(t) => t.clone(),
            None => {
                let mut init: Vec<Vertex> = rest_rows
                    .iter()
                    .map(|&[x, y, z, _]| Vertex {
                        position: [x, y, z, 0.0],
                        normal: [0.0, 0.0, 1.0, 0.0],
                    })
                    .collect();
                init.resize(nv, Vertex::default());
                let bytes = VERTEX_STRIDE * nv as u64;
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
            validate_target(&target, nv as u64, &limits)?;
        // The deformer's own buffer holds whole `Vertex`es: the texture layout writes them one
        // vec4 at a time and binds all of it.
        let vertex_layout = options.output.is_none();
        if vertex_layout {
            out_size = VERTEX_STRIDE * nv as u64;
        }

        let frame = FrameGpu {
            n_rows: nr as u32,
            out_offset: out_word,
            out_stride: (target.stride / 4) as u32,
            normal_offset: normal_word,
            l_rows: nl as u32,
            n_vertices: nv as u32,
            _pad: [0; 2],
        };
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
            frame,
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
            // In a browser the buffers: the texture's out-of-memory check below waits on the
            // device, which a page's one thread cannot do.
            LStorage::Auto | LStorage::AutoF16 => {
                !cfg!(target_arch = "wasm32")
                    && textures_ok
                    && device.adapter_info().device_type == wgpu::DeviceType::Cpu
            }
        };
        let auto = matches!(options.storage, LStorage::Auto | LStorage::AutoF16);
        let path = if let Some(h) = hier {
            Path::Hier(HierPath::new(&shared, h)?)
        } else if texture && cfg!(target_arch = "wasm32") {
            // (No waiting on the device in a browser: an error surfaces as the device's.)
            Path::Texture(TexturePath::new(&shared)?)
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

        let normals = NormalPass::new(
            device,
            queue,
            &NormalsIo {
                module: match &path {
                    Path::Buffers(p) => p.module(),
                    Path::Texture(p) => p.module(),
                    Path::Hier(p) => p.normals_module(),
                },
                frame: match &path {
                    Path::Buffers(p) => p.frame(),
                    Path::Texture(p) => p.frame(),
                    Path::Hier(p) => p.frame(),
                },
                out: (&target.buffer, out_start, out_size),
                positions: match &path {
                    Path::Texture(p) => Some(p.positions()),
                    Path::Buffers(_) | Path::Hier(_) => None,
                },
                n_vertices: nv,
                max_binding,
            },
            &surface,
        )?;

        let mut d = Deformer {
            n_rows: nr as u32,
            n_vertices: nv as u32,
            n_cols: nc,
            extra_cols: 0,
            extra_drawn: 0,
            l_rows: nl,
            path,
            write_normals: target.normal_offset.is_some(),
            target,
            surface,
            normals,
            rest_rows,
            row_nodes: input.rows.to_vec(),
            out_binding: (out_start, out_size),
            frame,
            vertex_layout,
            max_binding,
            correction: None,
            forces: Vec::with_capacity(MAX_ACTIVE),
            l_forces: Vec::with_capacity(MAX_ACTIVE),
        };
        d.set_forces(queue, &[])?;
        Ok(d)
    }

    /// Sets this frame's force boundary condition: `(column index, force in newtons)` pairs.
    /// Columns may repeat (their forces add). Writes `16·forces.len()` bytes plus 16 bytes per
    /// chunk, or nothing when the list fits the immediates ([`DeformerStats::uses_immediates`]);
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
        let n_cols = self.n_cols + self.extra_cols;
        for &(col, force) in forces {
            if col as usize >= n_cols {
                return Err(GpuError::ColumnOutOfRange { col, n_cols });
            }
            if !force.iter().all(|v| v.is_finite()) {
                return Err(GpuError::NonFiniteForce { col, force });
            }
        }
        // The extra columns of a grown correction are the correction's alone.
        let l_forces = if self.extra_cols == 0 {
            forces
        } else {
            self.l_forces.clear();
            let nc = self.n_cols as u32;
            self.l_forces
                .extend(forces.iter().filter(|f| f.0 < nc).copied());
            &self.l_forces[..]
        };
        match &mut self.path {
            Path::Buffers(p) => p.set_forces(queue, l_forces),
            Path::Texture(p) => p.set_forces(queue, l_forces),
            Path::Hier(p) => p.set_forces(queue, l_forces),
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
    /// A separating cut's correction needs its body's rest positions:
    /// [`set_correction_at`](Self::set_correction_at).
    ///
    /// Errors (and then changes nothing): a correction whose sizes do not fit this deformer's
    /// rows and columns, or one that adds nodes without a row ([`GpuError::BadInput`]), a
    /// rank above 4,096 or `U` larger than a storage binding
    /// ([`GpuError::BufferTooLarge`]; draw that cut with the CPU's `displace`).
    pub fn set_correction(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        correction: Option<&Correction>,
    ) -> Result<(), GpuError> {
        self.carry(device, queue, correction, None)
    }

    /// [`set_correction`](Self::set_correction) for a cut body whose nodes' rest positions
    /// are `rest` (by **mesh node**, the copies of split nodes included: e.g.
    /// `CutBody::rest`), which a separating cut needs:
    ///
    /// * the rows whose rest position the cut moved (snapped onto the cut) are drawn from
    ///   there (`rest[node] + u`);
    /// * the nodes the correction adds that have no row of `L` ([`Correction::extra`] with no
    ///   [`Correction::extra_row`]: the copies) are drawn as the vertices reserved after the
    ///   rows ([`DeformerOptions::extra_vertices`]), `rest + U_x z + w_p(x)`
    ///   ([`Correction::extra_rows`]); [`row_of`](Self::row_of) gives their vertices, and
    ///   [`set_triangles`](Self::set_triangles) takes triangles over them;
    /// * [`set_forces`](Self::set_forces) takes forces on the extra columns (the grown
    ///   compliance's `n_cols`): they act through the correction alone.
    ///
    /// Errors (and then changes nothing): as [`set_correction`](Self::set_correction); a node
    /// `rest` lacks, or more nodes without a row than [`extra_capacity`](Self::extra_capacity)
    /// ([`GpuError::BadInput`]).
    pub fn set_correction_at(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        correction: Option<&Correction>,
        rest: &[DVec3],
    ) -> Result<(), GpuError> {
        self.carry(device, queue, correction, Some(rest))
    }

    /// The columns [`set_forces`](Self::set_forces) takes: those of `L`, and the extra
    /// columns of the correction carried ([`set_correction_at`](Self::set_correction_at)).
    pub fn column_count(&self) -> usize {
        self.n_cols + self.extra_cols
    }

    /// Moves the entries of `forces` on columns this deformer takes
    /// ([`column_count`](Self::column_count)) to its front, in order, and returns how many:
    /// a haptic sample taken from a separating cut's newer body than the one drawn may press
    /// its new copies' columns; a visual loop leaves them out for that frame.
    pub fn keep_known(&self, forces: &mut [(u32, [f32; 3])]) -> usize {
        let cols = self.column_count() as u32;
        let mut k = 0;
        for i in 0..forces.len() {
            if forces[i].0 < cols {
                forces.swap(k, i);
                k += 1;
            }
        }
        k
    }

    /// How many vertices this deformer reserves for a separating cut's added nodes
    /// ([`DeformerOptions::extra_vertices`]).
    pub fn extra_capacity(&self) -> usize {
        (self.n_vertices - self.n_rows) as usize
    }

    /// [`set_correction_at`](Self::set_correction_at), `rest` optional.
    fn carry(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        correction: Option<&Correction>,
        rest: Option<&[DVec3]>,
    ) -> Result<(), GpuError> {
        let nr = self.n_rows as usize;
        let Some(k) = correction else {
            if let Some(c) = &mut self.correction {
                let x = crate::correct::Extras {
                    of: &[],
                    rest: &self.rest_rows,
                    shift: &[],
                };
                c.set(device, queue, &Correction::default(), &x, self.max_binding)?;
            }
            self.surface.set_extras(&[], self.n_rows);
            (self.extra_cols, self.extra_drawn) = (0, 0);
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
        let ne = k.extra.len();
        if k.rows.len() != 3 * nl * r
            || k.v_cols.len() != 3 * nc * r
            || k.u_cols.len() != 3 * nc * r
            || k.dead_rows.len() != nl
            || k.dead_cols.len() != nc
            || k.u_extra.len() != 3 * ne * r
            || k.v_extra.len() != 3 * ne * r
            || k.extra_place.len() != ne
            || k.extra_row.len() != ne
        {
            return Err(GpuError::BadInput(format!(
                "a correction of rank {r} for {} rows, {} columns and {ne} extra nodes does \
                 not fit the deformer's {nl} rows that hold L and {nc} columns",
                k.dead_rows.len(),
                k.dead_cols.len()
            )));
        }
        // The extra nodes without a row, each a reserved vertex.
        let of: Vec<usize> = k.rowless_extras().collect();
        if of.len() > self.extra_capacity() {
            return Err(GpuError::BadInput(format!(
                "the cut adds {} nodes without a row; the deformer reserves {} vertices for \
                 them (DeformerOptions::extra_vertices)",
                of.len(),
                self.extra_capacity()
            )));
        }
        if let Some(&e) = (of.iter()).find(|&&e| k.extra_place[e].iter().any(|&p| p as usize >= r))
        {
            return Err(GpuError::BadInput(format!(
                "extra node {} has a place beyond the correction's rank {r}",
                k.extra[e]
            )));
        }
        // Rest positions: the rows' (and how far the cut moved them), the extra vertices'.
        let mut points = self.rest_rows.clone();
        let mut shift = Vec::new();
        match rest {
            None if !of.is_empty() => {
                return Err(GpuError::BadInput(
                    "a correction that adds nodes without a row needs their rest positions \
                     (Deformer::set_correction_at)"
                        .into(),
                ))
            }
            None => {}
            Some(rest) => {
                let at = |node: u32| {
                    rest.get(node as usize).copied().ok_or_else(|| {
                        GpuError::BadInput(format!(
                            "node {node} has no rest position ({} given)",
                            rest.len()
                        ))
                    })
                };
                shift.reserve(nr);
                for (p, &node) in points.iter_mut().zip(&self.row_nodes) {
                    let x = at(node)?;
                    let s = x - DVec3::new(f64::from(p[0]), f64::from(p[1]), f64::from(p[2]));
                    shift.push([s.x as f32, s.y as f32, s.z as f32, 0.0]);
                    *p = [x.x as f32, x.y as f32, x.z as f32, 1.0];
                }
                for &e in &of {
                    let x = at(k.extra[e])?;
                    points.push([x.x as f32, x.y as f32, x.z as f32, 1.0]);
                }
            }
        }
        crate::correct::check_size(nl + self.extra_capacity(), r, self.max_binding)?;
        if self.correction.is_none() {
            let (start, size) = self.out_binding;
            let positions = match &self.path {
                Path::Buffers(_) | Path::Hier(_) => None,
                Path::Texture(p) => Some(p.positions()),
            };
            let pass = CorrectionPass::new(
                device,
                &CorrectionTarget {
                    out: (&self.target.buffer, start, size),
                    frame: self.frame,
                    vertex_layout: self.vertex_layout,
                    positions,
                },
            );
            self.correction = Some(pass);
        }
        let c = self.correction.as_mut().expect("just made");
        let x = crate::correct::Extras {
            of: &of,
            rest: &points,
            shift: &shift,
        };
        c.set(device, queue, k, &x, self.max_binding)?;
        let drawn: Vec<u32> = of.iter().map(|&e| k.extra[e]).collect();
        self.surface.set_extras(&drawn, self.n_rows);
        (self.extra_cols, self.extra_drawn) = (ne, of.len());
        // The forces kept may name extra columns this correction no longer has.
        let n = (nc + ne) as u32;
        self.forces.retain(|f| f.0 < n);
        c.set_forces(queue, &self.forces);
        Ok(())
    }

    /// Replaces the surface drawn and shaded: `triangles` as **mesh node** indices,
    /// counter-clockwise seen from outside (as for [`new`](Self::new); e.g. a cut's opened
    /// surface, [`touchfem_core::Mesh::open_surface`]). Makes a new
    /// [`index_buffer`](Self::index_buffer) ([`index_count`](Self::index_count) follows) and
    /// the normal pass's adjacency, so that new faces get their normals from the next
    /// [`encode`](Self::encode)d pass. Every node of `triangles` must have a vertex: a
    /// displayed row (a cuttable region's nodes are, see the scene key `cuttable`), or a node
    /// the correction carried added ([`set_correction_at`](Self::set_correction_at)).
    ///
    /// Errors (and then changes nothing): a node without a vertex ([`GpuError::BadInput`]),
    /// adjacency beyond the device's limits.
    pub fn set_triangles(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        triangles: &[[u32; 3]],
    ) -> Result<(), GpuError> {
        self.surface
            .set_triangles(device, queue, &mut self.normals, triangles)?;
        Ok(())
    }

    /// Sets the line a separating cut's closed slit shows (mesh node pairs, e.g.
    /// [`touchfem_core::mesh::slit_edges`]; [`install_cut`] sets it), drawn by a renderer's
    /// [`Edges`](crate::render::Edges); cleared by [`set_triangles`](Self::set_triangles).
    /// An edge with a node that has no vertex is left out.
    pub fn set_slit(&mut self, edges: &[[u32; 2]]) {
        self.surface.set_slit(edges);
    }

    /// The slit's line ([`set_slit`](Self::set_slit)) in vertex indices.
    pub fn slit(&self) -> &[[u32; 2]] {
        self.surface.slit()
    }

    /// How many times [`set_triangles`](Self::set_triangles) replaced the surface (0 after
    /// [`new`](Self::new)): what a renderer compares to know when to rebuild what it derived
    /// from [`triangles`](Self::triangles) (e.g. its wireframe).
    pub fn surface_generation(&self) -> u64 {
        self.surface.generation()
    }

    /// The vertex index of mesh node `node`, if it is drawn: its row, or the extra vertex of
    /// a node a separating cut added ([`set_correction_at`](Self::set_correction_at)).
    pub fn row_of(&self, node: u32) -> Option<u32> {
        self.surface.row_of(node)
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
            self.normals.record(&mut pass, self.n_vertices);
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
        self.surface.index_buffer()
    }

    /// Number of indices in [`index_buffer`](Self::index_buffer) (3 per triangle).
    pub fn index_count(&self) -> u32 {
        3 * self.surface.triangles().len() as u32
    }

    /// The surface triangles in vertex (row) indices (CPU copy), in the index buffer's order:
    /// after [`new`](Self::new) those without a crease first
    /// ([`DeformerStats::smooth_triangles`]).
    pub fn triangles(&self) -> &[[u32; 3]] {
        self.surface.triangles()
    }

    /// Number of displayed rows R: the vertices `0..R`. A separating cut's added nodes are
    /// drawn as the vertices after them ([`extra_vertex_count`](Self::extra_vertex_count)).
    pub fn vertex_count(&self) -> u32 {
        self.n_rows
    }

    /// How many vertices after the rows the correction carried draws (the nodes a separating
    /// cut added without a row; [`set_correction_at`](Self::set_correction_at)).
    pub fn extra_vertex_count(&self) -> u32 {
        self.extra_drawn as u32
    }

    /// What the deformer holds and how it runs: its layout of `L`, chunks and bytes, the last
    /// frame's windows, the correction's rank, the smooth triangles. For tools, tests and
    /// reports; nothing here is needed to drive the pass.
    pub fn stats(&self) -> DeformerStats {
        let (chunks, columns_per_chunk, l_bytes, frame_windows) = match &self.path {
            Path::Buffers(p) => (p.chunk_count(), Some(p.cols_per_chunk()), p.l_bytes(), None),
            Path::Texture(p) => (p.layer_count(), None, p.l_bytes(), None),
            Path::Hier(p) => (
                p.value_buffers(),
                None,
                p.l_bytes(),
                Some(p.frame_windows()),
            ),
        };
        DeformerStats {
            storage: self.storage(),
            uses_immediates: match &self.path {
                Path::Buffers(_) | Path::Hier(_) => false,
                Path::Texture(p) => p.uses_immediates(),
            },
            chunks,
            columns_per_chunk,
            l_bytes,
            frame_windows,
            correction_rank: self.correction.as_ref().map_or(0, |c| c.rank()),
            smooth_triangles: self.surface.smooth(),
        }
    }

    /// Leading triangles without a crease ([`DeformerStats::smooth_triangles`]), for the
    /// renderer's draw.
    pub(crate) fn smooth_triangles(&self) -> u32 {
        self.surface.smooth()
    }

    /// The layout `L` is stored in.
    fn storage(&self) -> LStorage {
        match self.path {
            Path::Buffers(ref b) if b.half() => LStorage::BuffersF16,
            Path::Buffers(_) => LStorage::Buffers,
            Path::Texture(ref t) if t.half() => LStorage::TextureF16,
            Path::Texture(_) => LStorage::Texture,
            Path::Hier(ref h) if h.half() => LStorage::HierF16,
            Path::Hier(_) => LStorage::Hier,
        }
    }

    /// Reads the vertices back (waits for the GPU): positions, and normals if written, of the
    /// rows and then the extra vertices in use ([`extra_vertex_count`](Self::extra_vertex_count)).
    /// The output buffer needs `COPY_SRC`. For tests and tools, not for the frame loop.
    #[allow(clippy::type_complexity)]
    pub fn read_back(
        &self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
    ) -> Result<(Vec<[f32; 3]>, Option<Vec<[f32; 3]>>), GpuError> {
        let t = &self.target;
        if !t.buffer.usage().contains(wgpu::BufferUsages::COPY_SRC) {
            return Err(crate::context::ReadbackError::NotCopySource.into_gpu());
        }
        let n = u64::from(self.n_rows) + self.extra_drawn as u64;
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

/// What a [`Deformer`] holds and how it runs ([`Deformer::stats`]): diagnostics for tools,
/// tests and reports.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DeformerStats {
    /// The layout `L` is stored in ([`LStorage::Auto`] and [`LStorage::AutoF16`] resolved).
    pub storage: LStorage,
    /// Whether the active list travels as immediates (Vulkan push constants): the texture
    /// layout on a device with [`wgpu::Features::IMMEDIATES`] and 128 bytes of them, unless
    /// [`DeformerOptions::no_immediates`]. Then a frame with at most
    /// [`INLINE_ACTIVE`](crate::INLINE_ACTIVE) entries (two contact triangles' nodes) uploads
    /// nothing; [`Deformer::set_forces`] keeps the list for the next [`Deformer::encode`].
    pub uses_immediates: bool,
    /// Number of storage buffers ([`LStorage::Buffers`], or the values of [`LStorage::Hier`])
    /// or texture array layers ([`LStorage::Texture`]) `L` is split into.
    pub chunks: usize,
    /// Column nodes per storage buffer ([`LStorage::Buffers`]); `None` for the texture layout,
    /// which splits `L` by texel rows instead, and for the hierarchical one (by blocks).
    pub columns_per_chunk: Option<usize>,
    /// Bytes the GPU holds for `L`: the storage buffers or the texture, and for
    /// [`LStorage::Hier`] its values, tables and per-frame work buffer (what
    /// [`hier_gpu_bytes`](crate::hier_gpu_bytes) estimates without a GPU).
    pub l_bytes: u64,
    /// For [`LStorage::Hier`], the uniform windows the last [`Deformer::set_forces`] laid its
    /// tables out in (one a dispatch of the row pass; more than one only when many column
    /// leaves are active); `None` for the dense layouts.
    pub frame_windows: Option<usize>,
    /// The rank of the correction carried ([`Deformer::set_correction`]); 0 when none.
    pub correction_rank: usize,
    /// How many triangles, first in [`Deformer::triangles`] and the index buffer, have no
    /// crease: at rest each of their vertices' normals is within about 8° (cosine 0.99) of
    /// theirs. [`Deformer::new`] puts them first (the rest keep their order after them); after
    /// [`Deformer::set_triangles`] there are none. A renderer shades these with their vertex
    /// normals alone and the others with their facet normals at creases (found per pixel, most
    /// of a software rasteriser's fragment cost).
    pub smooth_triangles: u32,
}

/// Puts a cut body on `deformer`, which was built from `uploaded`: `L` again (a new
/// [`Deformer`] with `options`, its nodes at `rest`, the body's rest positions of every node)
/// when the body's `compliance` does not hold the `L` uploaded ([`Compliance::shares_l`]: a
/// cut folded into a new `L`), or when the deformer reserves too few vertices for the nodes a
/// separating cut added (then with twice the room needed); then its correction
/// ([`Deformer::set_correction_at`]: the snapped rows moved, the copies drawn) and its opened
/// surface `triangles` (node triples), with the line where a closed slit's faces meet the
/// surface ([`Deformer::set_slit`]). Triangles whose nodes are neither displayed rows nor
/// nodes the correction added (a cut beyond the `cuttable` region's nodes) are left out with
/// a warning. The caller rebuilds what it derived from the deformer's triangles (its
/// wireframe). On an error the deformer may hold part of the body: draw from the CPU's
/// `displace` then.
#[allow(clippy::too_many_arguments)]
pub fn install_cut(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    deformer: &mut Deformer,
    uploaded: &Compliance,
    compliance: &Compliance,
    triangles: &[[u32; 3]],
    rest: &[DVec3],
    options: &DeformerOptions,
) -> Result<(), GpuError> {
    let k = compliance.correction();
    let added = k.map_or(0, |k| k.rowless_extras().count());
    let drawable = |v: u32| {
        (v as usize) < rest.len()
            && (compliance.row_of(v).is_some()
                || k.is_some_and(|k| k.extra.binary_search(&v).is_ok()))
    };
    let (drawn, left_out): (Vec<[u32; 3]>, Vec<[u32; 3]>) = triangles
        .iter()
        .partition(|t| t.iter().all(|&v| drawable(v)));
    if !compliance.shares_l(uploaded) || added > deformer.extra_capacity() {
        log::info!("a cut body holds a new L, or adds more nodes than reserved; uploading L");
        let mut options = options.clone();
        options.extra_vertices = options.extra_vertices.max(2 * added);
        let rows: Vec<[u32; 3]> = (drawn.iter())
            .filter(|t| t.iter().all(|&v| compliance.row_of(v).is_some()))
            .copied()
            .collect();
        *deformer = Deformer::new(device, queue, compliance, rest, &rows, &options)?;
    }
    if !left_out.is_empty() {
        log::warn!(
            "{} of the cut surface's {} triangles use nodes that are not displayed rows; \
             they are not drawn",
            left_out.len(),
            triangles.len()
        );
    }
    deformer.set_correction_at(device, queue, k, rest)?;
    deformer.set_triangles(device, queue, &drawn)?;
    deformer.set_slit(&touchfem_core::mesh::slit_edges(&drawn, rest));
    Ok(())
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
}
