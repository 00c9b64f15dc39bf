//! The surface every layout of `L` draws and shades, written once: the triangles in vertex (row)
//! indices and their index buffer, the rows of the mesh nodes, the triangles without a crease
//! (put first), the vertex → triangle-fan adjacency, and the normal pass that gathers over it —
//! from a storage buffer ([`NormalPass::Buffers`], `shaders/deform.wgsl`'s `normals`: the
//! storage-buffer and hierarchical layouts) or from a texture of fixed fan slots
//! ([`NormalPass::Texture`], `shaders/deform_texture.wgsl`'s). [`Surface::set_triangles`]
//! replaces the surface (a cut's opened one) in every layout.

use glam::DVec3;
use wgpu::util::DeviceExt;

use crate::bind::{
    buffer, compute_pipeline, storage_entry, storage_texture_entry, uniform_entry, view,
};
use crate::context::GpuError;
use crate::input::{FrameGpu, WORKGROUP};

/// Cosine of the largest angle between a triangle's and its vertices' normals on a surface
/// without creases: render.wgsl's `fs_surface` shades with the vertex normal alone from this
/// cosine on.
pub(crate) const CREASE_COS: f64 = 0.99;

/// The surface drawn: triangles in vertex (row) indices, their index buffer, and per mesh node
/// its row.
pub(crate) struct Surface {
    /// For each mesh node up to the largest row's, its row or `u32::MAX`.
    row_of: Vec<u32>,
    triangles: Vec<[u32; 3]>,
    index_buffer: wgpu::Buffer,
    /// Words of the index buffer to bind (at least 4).
    index_words: u64,
    /// Leading triangles without a crease.
    smooth: u32,
    /// Bumped by each [`set_triangles`](Self::set_triangles).
    generation: u64,
    /// The mesh nodes mapped to extra vertices ([`set_extras`](Self::set_extras)).
    extras: Vec<u32>,
    /// A closed slit's line: edges in vertex indices ([`set_slit`](Self::set_slit)).
    slit: Vec<[u32; 2]>,
}

impl Surface {
    /// The surface of `triangles` (mesh nodes) over the displayed `rows` (mesh nodes), whose
    /// rest positions are `rest_rows`: the triangles without a crease first, each part in the
    /// given order. An error names the first node that is not a displayed row.
    pub(crate) fn new(
        device: &wgpu::Device,
        rows: &[u32],
        rest_rows: &[[f32; 4]],
        triangles: &[[u32; 3]],
    ) -> Result<Surface, GpuError> {
        let max_node = rows.iter().copied().max().unwrap_or(0) as usize;
        let mut row_of = vec![u32::MAX; max_node + 1];
        for (i, &node) in rows.iter().enumerate() {
            row_of[node as usize] = i as u32;
        }
        let tris = rows_of_triangles(&row_of, triangles)?;
        // Triangles without a crease first (a renderer shades them more cheaply), each part in
        // the given order.
        let smooth = smooth_mask(rest_rows, &tris);
        let n_smooth = smooth.iter().filter(|&&s| s).count() as u32;
        let tris: Vec<[u32; 3]> = (tris.iter().zip(&smooth).filter(|p| *p.1))
            .chain(tris.iter().zip(&smooth).filter(|p| !*p.1))
            .map(|p| *p.0)
            .collect();
        let (index_buffer, index_words) = index_buffer(device, &tris);
        Ok(Surface {
            row_of,
            triangles: tris,
            index_buffer,
            index_words,
            smooth: n_smooth,
            generation: 0,
            extras: Vec::new(),
            slit: Vec::new(),
        })
    }

    /// Replaces the triangles (mesh nodes): the index buffer and `normals`' adjacency are
    /// rebuilt; a cut's faces meet the surface at an edge, so none is counted smooth. Errors
    /// (and then changes nothing): a node that is not a displayed row, adjacency beyond the
    /// device's limits.
    pub(crate) fn set_triangles(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        normals: &mut NormalPass,
        triangles: &[[u32; 3]],
    ) -> Result<(), GpuError> {
        let tris = rows_of_triangles(&self.row_of, triangles)?;
        let (index_buffer, index_words) = index_buffer(device, &tris);
        normals.rebuild(device, queue, &tris, (&index_buffer, index_words))?;
        self.index_buffer = index_buffer;
        self.index_words = index_words;
        self.triangles = tris;
        self.generation += 1;
        self.smooth = 0;
        self.slit.clear();
        Ok(())
    }

    /// Sets the slit's line ([`touchfem_core::mesh::slit_edges`], mesh nodes) over the
    /// triangles now (cleared by [`set_triangles`](Self::set_triangles)); an edge with a node
    /// that has no vertex is left out.
    pub(crate) fn set_slit(&mut self, edges: &[[u32; 2]]) {
        self.slit = (edges.iter())
            .filter_map(|e| Some([self.row_of(e[0])?, self.row_of(e[1])?]))
            .collect();
    }

    /// The slit's line in vertex indices.
    pub(crate) fn slit(&self) -> &[[u32; 2]] {
        &self.slit
    }

    /// Maps `nodes` (without a row) to the vertices `base..` after the rows, in order,
    /// instead of the nodes mapped before; the triangles stay until
    /// [`set_triangles`](Self::set_triangles).
    pub(crate) fn set_extras(&mut self, nodes: &[u32], base: u32) {
        for &n in &self.extras {
            self.row_of[n as usize] = u32::MAX;
        }
        self.extras.clear();
        for (k, &n) in nodes.iter().enumerate() {
            let n = n as usize;
            if n >= self.row_of.len() {
                self.row_of.resize(n + 1, u32::MAX);
            }
            if self.row_of[n] == u32::MAX {
                self.row_of[n] = base + k as u32;
                self.extras.push(n as u32);
            }
        }
    }

    /// The vertex index of mesh node `node`: its row, or its extra vertex.
    pub(crate) fn row_of(&self, node: u32) -> Option<u32> {
        self.row_of
            .get(node as usize)
            .copied()
            .filter(|&r| r != u32::MAX)
    }

    /// The triangles in row indices, in the index buffer's order.
    pub(crate) fn triangles(&self) -> &[[u32; 3]] {
        &self.triangles
    }

    /// The index buffer (`INDEX | STORAGE`).
    pub(crate) fn index_buffer(&self) -> &wgpu::Buffer {
        &self.index_buffer
    }

    /// The index buffer and the words of it to bind.
    pub(crate) fn index(&self) -> (&wgpu::Buffer, u64) {
        (&self.index_buffer, self.index_words)
    }

    /// Leading triangles without a crease.
    pub(crate) fn smooth(&self) -> u32 {
        self.smooth
    }

    /// How many times the triangles were replaced.
    pub(crate) fn generation(&self) -> u64 {
        self.generation
    }
}

/// What a layout gives the normal pass: its shader module (with the `normals` entry), its frame
/// uniform (the first 32 bytes are a [`FrameGpu`]), the output binding, and for the texture
/// layout the deformed positions its deformation pass writes.
pub(crate) struct NormalsIo<'a> {
    pub module: &'a wgpu::ShaderModule,
    pub frame: &'a wgpu::Buffer,
    pub out: (&'a wgpu::Buffer, u64, u64),
    pub positions: Option<&'a wgpu::TextureView>,
    pub n_vertices: usize,
    pub max_binding: u64,
}

/// The normal pass of every layout: area-weighted vertex normals of the deformed surface, a
/// gather over each vertex's triangle fans (WGSL has no float atomics).
pub(crate) enum NormalPass {
    /// From the output buffer, over a CSR list in a storage buffer (`deform.wgsl`).
    Buffers(BufferNormals),
    /// From the deformed-position texture, over fixed fan slots in a texture
    /// (`deform_texture.wgsl`).
    Texture(TextureNormals),
}

/// The storage-buffer normal pass's bindings and pipeline.
pub(crate) struct BufferNormals {
    layout: wgpu::BindGroupLayout,
    group: wgpu::BindGroup,
    pipeline: wgpu::ComputePipeline,
    frame: wgpu::Buffer,
    out: (wgpu::Buffer, u64, u64),
    n_vertices: usize,
    max_binding: u64,
}

/// The texture normal pass's bindings and pipeline.
pub(crate) struct TextureNormals {
    layout: wgpu::BindGroupLayout,
    group: wgpu::BindGroup,
    pipeline: wgpu::ComputePipeline,
    frame: wgpu::Buffer,
    out: (wgpu::Buffer, u64, u64),
    positions: wgpu::TextureView,
    n_vertices: usize,
}

impl NormalPass {
    /// The normal pass for `surface` with what the layout gives (`io`): the texture variant
    /// when it gives deformed positions.
    pub(crate) fn new(
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        io: &NormalsIo<'_>,
        surface: &Surface,
    ) -> Result<NormalPass, GpuError> {
        let (out, start, size) = io.out;
        let out = (out.clone(), start, size);
        match io.positions {
            None => {
                let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                    label: Some("touchfem normals"),
                    entries: &[
                        uniform_entry(0),
                        storage_entry(3, false),
                        storage_entry(4, true),
                        storage_entry(5, true),
                    ],
                });
                let adj = checked_adjacency(
                    io.n_vertices,
                    surface.triangles(),
                    surface.index().1,
                    io.max_binding,
                )?;
                let group = buffer_group(device, &layout, io.frame, &out, surface.index(), &adj);
                Ok(NormalPass::Buffers(BufferNormals {
                    pipeline: compute_pipeline(device, io.module, "normals", &[&layout], 0),
                    layout,
                    group,
                    frame: io.frame.clone(),
                    out,
                    n_vertices: io.n_vertices,
                    max_binding: io.max_binding,
                }))
            }
            Some(positions) => {
                let layout = device.create_bind_group_layout(&wgpu::BindGroupLayoutDescriptor {
                    label: Some("touchfem normals (texture)"),
                    entries: &[
                        uniform_entry(0),
                        storage_entry(2, false),
                        storage_texture_entry(
                            6,
                            wgpu::StorageTextureAccess::ReadOnly,
                            wgpu::TextureFormat::Rgba32Float,
                            wgpu::TextureViewDimension::D2,
                        ),
                        storage_texture_entry(
                            8,
                            wgpu::StorageTextureAccess::ReadOnly,
                            wgpu::TextureFormat::Rgba32Uint,
                            wgpu::TextureViewDimension::D2,
                        ),
                    ],
                });
                let fans = fan_texture(device, queue, io.n_vertices, surface.triangles())?;
                let group = texture_group(device, &layout, io.frame, &out, positions, &fans);
                Ok(NormalPass::Texture(TextureNormals {
                    pipeline: compute_pipeline(device, io.module, "normals", &[&layout], 0),
                    layout,
                    group,
                    frame: io.frame.clone(),
                    out,
                    positions: positions.clone(),
                    n_vertices: io.n_vertices,
                }))
            }
        }
    }

    /// Rebuilds the adjacency and the bindings for new triangles (row indices, checked;
    /// `index` holds them). Errors (and then changes nothing): adjacency beyond the device's
    /// limits.
    fn rebuild(
        &mut self,
        device: &wgpu::Device,
        queue: &wgpu::Queue,
        tris: &[[u32; 3]],
        index: (&wgpu::Buffer, u64),
    ) -> Result<(), GpuError> {
        match self {
            NormalPass::Buffers(p) => {
                let adj = checked_adjacency(p.n_vertices, tris, index.1, p.max_binding)?;
                p.group = buffer_group(device, &p.layout, &p.frame, &p.out, index, &adj);
            }
            NormalPass::Texture(p) => {
                let fans = fan_texture(device, queue, p.n_vertices, tris)?;
                p.group = texture_group(device, &p.layout, &p.frame, &p.out, &p.positions, &fans);
            }
        }
        Ok(())
    }

    /// Records the normal pass (one dispatch, a thread a vertex).
    pub(crate) fn record(&self, pass: &mut wgpu::ComputePass<'_>, n_vertices: u32) {
        let (pipeline, group) = match self {
            NormalPass::Buffers(p) => (&p.pipeline, &p.group),
            NormalPass::Texture(p) => (&p.pipeline, &p.group),
        };
        pass.set_pipeline(pipeline);
        pass.set_bind_group(0, group, &[]);
        pass.dispatch_workgroups(n_vertices.div_ceil(WORKGROUP), 1, 1);
    }
}

/// The storage-buffer normal pass's group: frame, output, triangles and their adjacency
/// (uploaded here).
fn buffer_group(
    device: &wgpu::Device,
    layout: &wgpu::BindGroupLayout,
    frame: &wgpu::Buffer,
    out: &(wgpu::Buffer, u64, u64),
    index: (&wgpu::Buffer, u64),
    adj: &[u32],
) -> wgpu::BindGroup {
    let adj_buf = device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
        label: Some("touchfem vertex-triangle CSR"),
        contents: bytemuck::cast_slice(adj),
        usage: wgpu::BufferUsages::STORAGE,
    });
    device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some("touchfem normals"),
        layout,
        entries: &[
            buffer(0, frame, 0, std::mem::size_of::<FrameGpu>() as u64),
            buffer(3, &out.0, out.1, out.2),
            buffer(4, index.0, 0, 4 * index.1),
            buffer(5, &adj_buf, 0, 4 * adj.len() as u64),
        ],
    })
}

/// The texture normal pass's group: the frame, the output, the deformed positions and the fans.
fn texture_group(
    device: &wgpu::Device,
    layout: &wgpu::BindGroupLayout,
    frame: &wgpu::Buffer,
    out: &(wgpu::Buffer, u64, u64),
    positions: &wgpu::TextureView,
    fans: &wgpu::TextureView,
) -> wgpu::BindGroup {
    device.create_bind_group(&wgpu::BindGroupDescriptor {
        label: Some("touchfem normals (texture)"),
        layout,
        entries: &[
            buffer(0, frame, 0, 32),
            buffer(2, &out.0, out.1, out.2),
            view(6, positions),
            view(8, fans),
        ],
    })
}

/// Per vertex, its triangle fans in two texels of 4 slots ([`fan_slots`]), as a texture.
fn fan_texture(
    device: &wgpu::Device,
    queue: &wgpu::Queue,
    nr: usize,
    tris: &[[u32; 3]],
) -> Result<wgpu::TextureView, GpuError> {
    let fans = fan_slots(nr, tris)?;
    let tex = crate::texture_path::texture_2d(
        device,
        queue,
        "touchfem vertex fans",
        wgpu::TextureFormat::Rgba32Uint,
        wgpu::TextureUsages::STORAGE_BINDING | wgpu::TextureUsages::COPY_DST,
        fans.len() as u64 / 4,
        bytemuck::cast_slice(&fans),
    )?;
    Ok(tex.create_view(&Default::default()))
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

/// [`adjacency`] for `tris` (`index_words` words in the index buffer), each binding checked
/// against `max_binding` bytes.
fn checked_adjacency(
    nr: usize,
    tris: &[[u32; 3]],
    index_words: u64,
    max_binding: u64,
) -> Result<Vec<u32>, GpuError> {
    let adj = adjacency(nr, tris);
    for (what, bytes) in [
        ("triangle list", 4 * index_words),
        ("vertex-triangle adjacency", 4 * adj.len() as u64),
    ] {
        if bytes > max_binding {
            return Err(GpuError::BufferTooLarge {
                what,
                bytes,
                limit: max_binding,
            });
        }
    }
    Ok(adj)
}

/// The storage-buffer normal pass's adjacency: offsets[0..=nr], then each vertex's triangle
/// fans ([`vertex_fans`](touchfem_core::mesh::vertex_fans): its neighbours, each chain begun by
/// `FAN_START`), in one list. One position load per neighbour instead of three corners and
/// three positions per triangle.
fn adjacency(nr: usize, tris: &[[u32; 3]]) -> Vec<u32> {
    let (ranges, list) = touchfem_core::mesh::vertex_fans(nr, tris, false);
    let mut adj = Vec::with_capacity(nr + 1 + list.len());
    adj.extend(ranges.iter().map(|r| r[0]));
    adj.push(list.len() as u32);
    adj.extend_from_slice(&list);
    adj
}

/// Fan slots per vertex: two texels of four `u32`.
const FAN_SLOTS: usize = 8;

/// Marks the last slot of a vertex whose fan has more than [`FAN_SLOTS`] entries: the rest
/// of the slot is the texel where the fan continues.
const FAN_MORE: u32 = 1 << 30;

/// The texture normal pass's adjacency: vertex `v`'s triangle fans
/// ([`touchfem_core::mesh::vertex_fans`]) in texels `2v` and `2v + 1`, [`FAN_SLOTS`] `u32`
/// slots, read without a count: fixed, straight-line work per vertex, which llvmpipe runs much
/// faster than a loop whose trip count differs between lanes. Short fans are padded with
/// `FAN_START | v` — the vertex itself starting a chain, which adds nothing to the normal. A
/// longer fan (valence 8 and up; 1.5 % of the mouse's vertices) keeps its first 7 entries and
/// ends in `FAN_MORE | t`: at texel `t` (after the `2R` fixed texels) a count `k`, then the
/// remaining `k` entries.
fn fan_slots(nr: usize, tris: &[[u32; 3]]) -> Result<Vec<u32>, GpuError> {
    let (ranges, list) = touchfem_core::mesh::vertex_fans(nr, tris, false);
    let start = touchfem_core::mesh::FAN_START;
    if nr as u64 >= u64::from(FAN_MORE) {
        return Err(GpuError::BadInput(format!(
            "{nr} displayed vertices; the texture layout's normal pass takes at most {FAN_MORE}"
        )));
    }
    let mut slots = vec![0u32; FAN_SLOTS * nr];
    let mut extra: Vec<u32> = Vec::new();
    for (v, &[first, count]) in ranges.iter().enumerate() {
        let e = &list[first as usize..(first + count) as usize];
        let s = &mut slots[FAN_SLOTS * v..FAN_SLOTS * (v + 1)];
        if e.len() <= FAN_SLOTS {
            for (k, slot) in s.iter_mut().enumerate() {
                *slot = e.get(k).copied().unwrap_or(start | v as u32);
            }
            continue;
        }
        let texel = 2 * nr + extra.len() / 4;
        if texel as u64 >= u64::from(FAN_MORE) {
            return Err(GpuError::BadInput(format!(
                "the triangle fans need {texel} texels; at most {FAN_MORE} are supported"
            )));
        }
        s[..FAN_SLOTS - 1].copy_from_slice(&e[..FAN_SLOTS - 1]);
        s[FAN_SLOTS - 1] = FAN_MORE | texel as u32;
        let rest = &e[FAN_SLOTS - 1..];
        extra.push(rest.len() as u32);
        extra.extend_from_slice(rest);
        extra.resize(extra.len().next_multiple_of(4), start);
    }
    slots.extend(extra);
    if slots.is_empty() {
        slots.resize(4, start);
    }
    Ok(slots)
}

#[cfg(test)]
mod tests {
    use super::*;
    use touchfem_core::mesh::FAN_START;

    /// Decoding the slots as the shader does visits each vertex's fan entries in order: up to
    /// 8 inline, padding that restarts a chain at the vertex itself, or 7 inline and the rest
    /// behind `FAN_MORE`.
    #[test]
    fn fan_slots_round_trip() {
        // A cone of 12 triangles (apex fan of 13 entries), a lone triangle, an unused vertex.
        let mut tris: Vec<[u32; 3]> = (0..12).map(|k| [0, 1 + k, 1 + (k + 1) % 12]).collect();
        tris.push([13, 14, 15]);
        let n = 17;
        let slots = fan_slots(n, &tris).unwrap();
        let (ranges, list) = touchfem_core::mesh::vertex_fans(n, &tris, false);
        for v in 0..n {
            let s = &slots[8 * v..8 * v + 8];
            let mut seen: Vec<u32> = s[..7].to_vec();
            if s[7] & FAN_MORE != 0 {
                let t = (s[7] & !FAN_MORE) as usize;
                let k = slots[4 * t] as usize;
                seen.extend_from_slice(&slots[4 * t + 1..4 * t + 1 + k]);
            } else {
                seen.push(s[7]);
            }
            let [f, c] = ranges[v];
            let want = &list[f as usize..(f + c) as usize];
            assert_eq!(&seen[..want.len()], want, "vertex {v}");
            assert!(
                seen[want.len()..]
                    .iter()
                    .all(|&e| e == FAN_START | v as u32),
                "vertex {v}: padding"
            );
        }
        assert_eq!(
            slots[7],
            FAN_MORE | (2 * n as u32),
            "the apex continues after the fixed texels"
        );
        assert_eq!(slots[8 * n], 13 - 7, "with the 6 entries left");
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
        let smooth =
            |r: &[[f32; 4]], t: &[[u32; 3]]| smooth_mask(r, t).iter().filter(|&&s| s).count();
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
