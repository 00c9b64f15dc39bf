// touchfem cut correction pass: the exact low-rank term of a cut (touchfem::correction),
// u += U_R z over the rows that hold L, and the rows the cut pinned put back at rest. Used by
// `touchfem::gpu::Deformer` in every storage mode of L, as one more dispatch of the same compute
// pass: after the deformation dispatch(es) (which leave rest + L·F in `out`), before the normals.
//
// U is f32, by column (rank `rank` columns of 3R' entries, R' = l_rows): entry (column q, row r,
// axis a) at q·3R' + 3r + a — L's own column layout, so these are `rank` extra scalar columns of
// L whose weights z = Σ_c V_cᵀ F_c come from the CPU each frame.
//
// This file is completed by a prelude defining store_texture(r, p): nothing (storage-buffer
// layout) or a store into the deformed-position texture the texture layout's normal pass reads.

struct Params {
    // Rows that hold L (the first ones).
    l_rows: u32,
    // Columns of U (the correction's rank).
    rank: u32,
    // Output: first f32 word of vertex 0 in `out`, and the vertex stride in f32 words.
    out_offset: u32,
    out_stride: u32,
}

// Word of a vertex that receives |u| (the deformer's own Vertex layout: 3); 0xffffffff: none.
override DISPLACEMENT_WORD: u32 = 0xffffffffu;

@group(0) @binding(0) var<uniform> params: Params;
@group(0) @binding(1) var<storage, read> u_rows: array<f32>;
// z: one weight per column of U.
@group(0) @binding(2) var<storage, read> weights: array<f32>;
// Per row that holds L: 1 if the cut pinned its node (it does not move).
@group(0) @binding(3) var<storage, read> dead: array<u32>;
@group(0) @binding(4) var<storage, read> rest: array<vec4<f32>>;
@group(0) @binding(5) var<storage, read_write> out: array<f32>;

@compute @workgroup_size(64)
fn correct(@builtin(global_invocation_id) gid: vec3<u32>) {
    let r = gid.x;
    if r >= params.l_rows {
        return;
    }
    let o = params.out_offset + r * params.out_stride;
    let x0 = rest[r].xyz;
    var p = x0;
    if dead[r] == 0u {
        let nr3 = 3u * params.l_rows;
        var u = vec3<f32>(0.0);
        for (var q = 0u; q < params.rank; q += 1u) {
            let i = q * nr3 + 3u * r;
            u += vec3<f32>(u_rows[i], u_rows[i + 1u], u_rows[i + 2u]) * weights[q];
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
