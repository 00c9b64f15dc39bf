// touchfem deformation passes, texture layout: the same maths as deform.wgsl (u = L·F over the
// active columns, then area-weighted vertex normals), with L, the rest pose, the deformed
// positions and the adjacency read with textureLoad from read-only storage textures instead of
// storage buffers.
//
// Why: on software rasterisers (Mesa's lavapipe/llvmpipe), a storage-buffer load whose address
// differs per invocation is scalarised lane by lane, while an image load is a vector gather;
// measured on lavapipe 22.3 a texel (4 floats) costs about what one scalar storage load does.
// Used by `touchfem::gpu::Deformer` with `LStorage::Texture` (the default on CPU adapters).
//
// Layouts (all linear indices t map to texels with W = 1024 texels a row):
//   x = t & (W − 1), y = (t >> 10) & (2^log_h − 1), layer = t >> (10 + log_h)
// * L: texel t = c_s·R + r holds (L[3r, c_s], L[3r+1, c_s], L[3r+2, c_s], 0) for scalar column
//   c_s = 3c + b, R = the rows that hold L (frame.l_rows, the free ones; the clamped rows
//   after them stay at rest): exactly the f32 column-major L with a zero after every third
//   entry.
// * rest, pos: texel r = vertex r (metres, w = 1); pos is written by `deform`, read by `normals`.
// * fan: vertex v's neighbours as chains (touchfem::mesh::vertex_fans): an entry with FAN_START
//   begins a chain, and consecutive entries a, b of a chain are one incident triangle (v, a, b),
//   so that cross(p_a − p_v, p_b − p_v) is twice its area times its outward normal. One
//   position load per neighbour (a closed fan of k triangles is k + 1 entries), not two per
//   triangle. Texels 2v and 2v + 1: 8 slots read without a count, padded with FAN_START | v
//   (adds nothing); a longer fan's last slot is FAN_MORE | t: at texel t a count k, then the
//   remaining k entries (touchfem::gpu's fan_slots).
// All counts come from uniforms: nothing relies on arrayLength (VERTEX buffers are padded).
//
// This file is completed by two preludes (touchfem::gpu::deform_texture_source):
// * where the active list lives, defining displacement(r, nr), the sum of column_term over the
//   active entries: active_uniform.wgsl (the uniform buffer `forces`) or active_immediate.wgsl
//   (immediates, when the device has them: short lists need no upload);
// * how vertices are written, defining `out` (binding 2), store_position(r, p, u) and
//   store_normal:
//   output_words.wgsl (any offset and stride, word by word) or output_vertex.wgsl (the
//   deformer's own 32-byte Vertex layout, one vec4 store each).

const LOG_W: u32 = 10u;
const W_MASK: u32 = 1023u;
const FAN_START: u32 = 0x80000000u;
const FAN_MORE: u32 = 0x40000000u;

struct Frame {
    // Displayed vertices (rows of L).
    n_rows: u32,
    // Output: first f32 word of vertex 0 in `out`, and the vertex stride in f32 words.
    out_offset: u32,
    out_stride: u32,
    // Normal's first word relative to the vertex start; 0xffffffff: no normals written.
    normal_offset: u32,
    // log2 of the rows per layer of the L texture.
    log_h: u32,
    // Entries of `forces` this frame (written per frame; unused with active_immediate.wgsl).
    n_active: u32,
    // Rows that hold L (≤ n_rows): the first ones.
    l_rows: u32,
    // Vertices the normal pass shades (≥ n_rows; frame.wgsl's).
    n_vertices: u32,
}

// One active column node of the force boundary condition: F_c (newtons) and c.
struct Active {
    force: vec3<f32>,
    col: u32,
}


@group(0) @binding(0) var<uniform> frame: Frame;
// Uniform, not storage: every invocation reads the same entry, and llvmpipe (lavapipe) turns a
// storage load into per-lane loads even then (measured: 2.3× slower at 90 active columns).
// 1024 = touchfem::gpu::MAX_ACTIVE: 16 KiB, the smallest uniform binding every device allows.
@group(0) @binding(1) var<uniform> forces: array<Active, 1024>;
@group(0) @binding(3) var l_tex: texture_storage_2d_array<rgba32float, read>;
@group(0) @binding(4) var rest_tex: texture_storage_2d<rgba32float, read>;
@group(0) @binding(5) var pos_out: texture_storage_2d<rgba32float, write>;
@group(0) @binding(6) var pos_tex: texture_storage_2d<rgba32float, read>;
@group(0) @binding(8) var fan_tex: texture_storage_2d<rgba32uint, read>;

fn xy(t: u32) -> vec2<u32> {
    return vec2<u32>(t & W_MASK, t >> LOG_W);
}

fn load_l(t: u32) -> vec3<f32> {
    let y = t >> LOG_W;
    let h_mask = (1u << frame.log_h) - 1u;
    return textureLoad(l_tex, vec2<u32>(t & W_MASK, y & h_mask), y >> frame.log_h).xyz;
}

// F_c's contribution at row r: scalar columns 3c, 3c + 1, 3c + 2 are texels (3c + b)·R + r.
fn column_term(a: Active, r: u32, nr: u32) -> vec3<f32> {
    let t = 3u * a.col * nr + r;
    return load_l(t) * a.force.x + load_l(t + nr) * a.force.y + load_l(t + 2u * nr) * a.force.z;
}

@compute @workgroup_size(64)
fn deform(@builtin(global_invocation_id) gid: vec3<u32>) {
    let r = gid.x;
    if r >= frame.n_rows {
        return;
    }
    var u = vec3<f32>(0.0);
    if r < frame.l_rows {
        u = displacement(r, frame.l_rows);
    }
    let p = textureLoad(rest_tex, xy(r)).xyz + u;
    store_position(r, p, u);
    if frame.normal_offset != 0xffffffffu {
        textureStore(pos_out, xy(r), vec4<f32>(p, 1.0));
    }
}

// One fan entry: the neighbour's edge vector from v; closes a triangle with the previous one
// unless it starts a chain. |cross| is twice the area: the sum is area-weighted.
fn fan_step(e: u32, p: vec3<f32>, prev: ptr<function, vec3<f32>>, n: ptr<function, vec3<f32>>) {
    let q = textureLoad(pos_tex, xy(e & ~FAN_START)).xyz - p;
    if (e & FAN_START) == 0u {
        *n += cross(*prev, q);
    }
    *prev = q;
}

@compute @workgroup_size(64)
fn normals(@builtin(global_invocation_id) gid: vec3<u32>) {
    let v = gid.x;
    if v >= frame.n_vertices || frame.normal_offset == 0xffffffffu {
        return;
    }
    let f0 = textureLoad(fan_tex, xy(2u * v));
    let f1 = textureLoad(fan_tex, xy(2u * v + 1u));
    let p = textureLoad(pos_tex, xy(v)).xyz;
    var n = vec3<f32>(0.0);
    var prev = vec3<f32>(0.0);
    // Eight slots, straight-line (padding adds nothing); a long fan's eighth continues
    // elsewhere.
    fan_step(f0.x, p, &prev, &n);
    fan_step(f0.y, p, &prev, &n);
    fan_step(f0.z, p, &prev, &n);
    fan_step(f0.w, p, &prev, &n);
    fan_step(f1.x, p, &prev, &n);
    fan_step(f1.y, p, &prev, &n);
    fan_step(f1.z, p, &prev, &n);
    if (f1.w & FAN_MORE) == 0u {
        fan_step(f1.w, p, &prev, &n);
    } else {
        let t = f1.w & ~FAN_MORE;
        let k = textureLoad(fan_tex, xy(t)).x;
        for (var i = 0u; i < k; i += 1u) {
            let j = t * 4u + 1u + i;
            fan_step(textureLoad(fan_tex, xy(j >> 2u))[j & 3u], p, &prev, &n);
        }
    }
    let len = length(n);
    if len > 0.0 {
        n = n / len;
    }
    store_normal(v, n);
}
