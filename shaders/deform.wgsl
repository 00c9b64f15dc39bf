// touchfem deformation passes (Hirota & Kaneko eq. 8): u = L·F over the active columns, then
// area-weighted vertex normals of the deformed surface. Used by `touchfem::gpu::Deformer`.
//
// L is column-major (3R')×(3C) over the first R' rows (the free ones; the clamped rows after
// them are zero and not stored, so those vertices stay at rest), split by column nodes into
// chunks (one storage binding each, to
// stay under max_storage_buffer_binding_size). `deform` is dispatched once per chunk that has
// active columns (chunk 0 always, it starts from the rest pose); later chunks accumulate.
// All counts come from uniforms: nothing relies on arrayLength (VERTEX buffers are padded).

// `Frame` (the uniform at binding 0) is frame.wgsl's, put before this file by the host.

// One active column of the force boundary condition: F_c (newtons) and c, local to its chunk.
struct Active {
    force: vec3<f32>,
    col: u32,
}

struct Chunk {
    // This chunk's entries are active[first .. first + count].
    first: u32,
    count: u32,
    // 1: start from the rest position; 0: add to what `out` holds.
    init: u32,
    _pad: u32,
}

// Word of a vertex (relative to its start) that receives |u|, the displacement's magnitude in
// metres (the deformer's own Vertex layout: 3, position.w); 0xffffffff: not written.
override DISPLACEMENT_WORD: u32 = 0xffffffffu;

@group(0) @binding(0) var<uniform> frame: Frame;
// Uniform, not storage: every invocation reads the same entry, and llvmpipe (lavapipe) turns a
// storage load into per-lane loads even then. 1024 = touchfem::gpu::MAX_ACTIVE.
@group(0) @binding(1) var<uniform> active_list: array<Active, 1024>;
@group(0) @binding(2) var<storage, read> rest: array<vec4<f32>>;
@group(0) @binding(3) var<storage, read_write> out: array<f32>;
// Surface triangles as row indices, 3 per triangle (the normal pass reads their fans instead).
@group(0) @binding(4) var<storage, read> tris: array<u32>;
// Per vertex its triangle fans: offsets[0..=n_vertices], then the neighbours, each chain's first
// marked by FAN_START (touchfem_core::mesh::vertex_fans).
@group(0) @binding(5) var<storage, read> adj: array<u32>;

@group(1) @binding(0) var<uniform> chunk: Chunk;
@group(1) @binding(1) var<storage, read> l: array<f32>;

fn load_l(i: u32) -> vec3<f32> {
    return vec3<f32>(l[i], l[i + 1u], l[i + 2u]);
}

@compute @workgroup_size(64)
fn deform(@builtin(global_invocation_id) gid: vec3<u32>) {
    let r = gid.x;
    if r >= frame.n_rows {
        return;
    }
    let nr3 = 3u * frame.l_rows;
    var u = vec3<f32>(0.0);
    // A clamped row (r ≥ R') has no entries: it stays at rest.
    let count = select(0u, chunk.count, r < frame.l_rows);
    for (var k = 0u; k < count; k += 1u) {
        let a = active_list[chunk.first + k];
        // Entry (row r, axis 0; column c, axis b) sits at (3c + b)·3R' + 3r.
        let base = 3u * a.col * nr3 + 3u * r;
        u += load_l(base) * a.force.x + load_l(base + nr3) * a.force.y
            + load_l(base + 2u * nr3) * a.force.z;
    }
    let o = frame.out_offset + r * frame.out_stride;
    var p: vec3<f32>;
    if chunk.init != 0u {
        p = rest[r].xyz + u;
    } else {
        p = vec3<f32>(out[o], out[o + 1u], out[o + 2u]) + u;
    }
    out[o] = p.x;
    out[o + 1u] = p.y;
    out[o + 2u] = p.z;
    // Every chunk writes the magnitude so far: after the last one it is |u| of the whole sum.
    if DISPLACEMENT_WORD != 0xffffffffu {
        out[o + DISPLACEMENT_WORD] = length(p - rest[r].xyz);
    }
}

fn position(v: u32) -> vec3<f32> {
    let o = frame.out_offset + v * frame.out_stride;
    return vec3<f32>(out[o], out[o + 1u], out[o + 2u]);
}

// Marks the first neighbour of a chain in `adj` (touchfem_core::mesh::FAN_START).
const FAN_START: u32 = 0x80000000u;

@compute @workgroup_size(64)
fn normals(@builtin(global_invocation_id) gid: vec3<u32>) {
    let v = gid.x;
    if v >= frame.n_vertices || frame.normal_offset == 0xffffffffu {
        return;
    }
    let pv = position(v);
    var n = vec3<f32>(0.0);
    var prev = vec3<f32>(0.0);
    let list = frame.n_vertices + 1u;
    for (var i = adj[v]; i < adj[v + 1u]; i += 1u) {
        // Consecutive neighbours a, b of a chain: the triangle (v, a, b), counter-clockwise.
        // |cross| is twice the area: the sum is area-weighted.
        let e = adj[list + i];
        let p = position(e & ~FAN_START) - pv;
        n += select(cross(prev, p), vec3<f32>(0.0), (e & FAN_START) != 0u);
        prev = p;
    }
    let len = length(n);
    if len > 0.0 {
        n = n / len;
    }
    let o = frame.out_offset + v * frame.out_stride + frame.normal_offset;
    out[o] = n.x;
    out[o + 1u] = n.y;
    out[o + 2u] = n.z;
}
