// touchfem cut correction pass: the exact low-rank term of a cut (touchfem::correction),
// u += U_R z over the rows that hold L, and the rows the cut pinned put back at rest. Used by
// `touchfem::gpu::Deformer` in every storage mode of L, as one more dispatch of the same compute
// pass: after the deformation dispatch(es) (which leave rest + L·F in `out`), before the normals.
//
// U is f32, a vec4 (x, y, z, 0) per row and column: entry (column q, row r) at q·R' + r
// (R' = l_rows; L's column layout with a pad after every third float, as in the texture layout
// of L: one vector load a row and column, neighbouring rows side by side). These are `rank`
// extra scalar columns of L whose weights z = Σ_c V_cᵀ F_c come from the CPU each frame; the
// columns are padded with zeros to a multiple of four, the weights read four at a time.
//
// This file is completed by a prelude defining store_texture(r, p): nothing (storage-buffer
// layout) or a store into the deformed-position texture the texture layout's normal pass reads.

// The deformer's frame (frame.wgsl, put before this file by the host) and the correction's
// rank.
struct Params {
    frame: Frame,
    // Columns of U (the correction's rank) over four, rounded up.
    rank4: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

// Word of a vertex that receives |u| (the deformer's own Vertex layout: 3); 0xffffffff: none.
override DISPLACEMENT_WORD: u32 = 0xffffffffu;

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> u_rows: array<vec4<f32>>;
// z: one weight per column of U, four a vec4. Uniform, not storage: every invocation reads the
// same entry, and llvmpipe (lavapipe) loads storage lane by lane even then. 16 KiB: rank ≤ 4096.
@group(0) @binding(2) var<uniform> weights: array<vec4<f32>, 1024>;
// Per row that holds L: 1 if the cut pinned its node (it does not move).
@group(0) @binding(3) var<storage, read> dead: array<u32>;
@group(0) @binding(4) var<storage, read> rest: array<vec4<f32>>;
@group(0) @binding(5) var<storage, read_write> out: array<f32>;

@compute @workgroup_size(64)
fn correct(@builtin(global_invocation_id) gid: vec3<u32>) {
    let r = gid.x;
    if r >= params.frame.l_rows {
        return;
    }
    let o = params.frame.out_offset + r * params.frame.out_stride;
    let x0 = rest[r].xyz;
    var p = x0;
    if dead[r] == 0u {
        let n = params.frame.l_rows;
        var u = vec3<f32>(0.0);
        for (var q = 0u; q < params.rank4; q += 1u) {
            let w = weights[q];
            let i = 4u * q * n + r;
            u += u_rows[i].xyz * w.x + u_rows[i + n].xyz * w.y + u_rows[i + 2u * n].xyz * w.z
                + u_rows[i + 3u * n].xyz * w.w;
        }
        p = vec3<f32>(out[o], out[o + 1u], out[o + 2u]) + u;
    }
    out[o] = p.x;
    out[o + 1u] = p.y;
    out[o + 2u] = p.z;
    if DISPLACEMENT_WORD != 0xffffffffu {
        out[o + DISPLACEMENT_WORD] = length(p - x0);
    }
    store_texture(r, p);
}
