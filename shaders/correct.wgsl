// touchfem cut correction pass: the exact low-rank term of a cut (touchfem::correction),
// u += U_R z over the rows that hold L, the rows the cut pinned put back at rest, the rows whose
// rest position the cut moved (snapped onto the cut) shifted there, and the vertices of the
// nodes a separating cut added (its copies) written whole. Used by `touchfem::gpu::Deformer`
// in every storage mode of L, as one more dispatch of the same compute pass: after the
// deformation dispatch(es) (which leave rest + L·F in `out`), before the normals.
//
// U is f32, a vec4 (x, y, z, 0) per row and column: entry (column q, row i) at q·S + i, S =
// params.u_stride (L's column layout with a pad after every third float, as in the texture
// layout of L: one vector load a row and column, neighbouring rows side by side). Its rows are
// the rows that hold L (i < frame.l_rows), then the extra vertices (l_rows + k). These are
// `rank` extra scalar columns of L whose weights z = Σ_c V_cᵀ F_c come from the CPU each frame;
// the columns are padded with zeros to a multiple of four, the weights read four at a time.
//
// Invocation i is vertex i: a row (i < frame.n_rows) or extra vertex k = i − n_rows, an extra
// node x without a row of L, whose position is its rest position + U_x z + w_p(x): w =
// Σ_c U_cᵀ F_c over the columns of L (from the CPU each frame), p(x) its DOFs' places among
// U's columns (touchfem_core's Correction::extra_rows).
//
// This file is completed by a prelude defining store_texture(v, p): nothing (storage-buffer
// layout) or a store into the deformed-position texture the texture layout's normal pass reads.

// The deformer's frame (frame.wgsl, put before this file by the host) and the correction's
// sizes.
struct Params {
    frame: Frame,
    // Columns of U (the correction's rank) over four, rounded up.
    rank4: u32,
    // Extra vertices written (after the rows).
    n_extra: u32,
    // Rows of U a column: the rows that hold L, then the reserved extra vertices.
    u_stride: u32,
    // Where the rows' rest shifts start in `points`.
    shift_base: u32,
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
// Per vertex its rest position (the rows, then the extra vertices); from shift_base, per row,
// how far the cut moved its rest position from the one the deformation pass added u to.
@group(0) @binding(4) var<storage, read> points: array<vec4<f32>>;
@group(0) @binding(5) var<storage, read_write> out: array<f32>;
// w = Σ_c U_cᵀ F_c, one per column of U.
@group(0) @binding(6) var<storage, read> w_cols: array<f32>;
// Per extra vertex, its three DOFs' places among U's columns.
@group(0) @binding(7) var<storage, read> places: array<vec4<u32>>;

@compute @workgroup_size(64)
fn correct(@builtin(global_invocation_id) gid: vec3<u32>) {
    let i = gid.x;
    let nr = params.frame.n_rows;
    let nl = params.frame.l_rows;
    if i >= nr + params.n_extra {
        return;
    }
    let extra = i >= nr;
    let pinned = i < nl && dead[i] != 0u;
    let ur = select(i, nl + (i - nr), extra);
    let count = select(0u, params.rank4, (i < nl || extra) && !pinned);
    let s = params.u_stride;
    var u = vec3<f32>(0.0);
    for (var q = 0u; q < count; q += 1u) {
        let w = weights[q];
        let j = 4u * q * s + ur;
        u += u_rows[j].xyz * w.x + u_rows[j + s].xyz * w.y + u_rows[j + 2u * s].xyz * w.z
            + u_rows[j + 3u * s].xyz * w.w;
    }
    let o = params.frame.out_offset + i * params.frame.out_stride;
    let x0 = points[i].xyz;
    var p = x0;
    if extra {
        let m = places[i - nr];
        p = x0 + u + vec3<f32>(w_cols[m.x], w_cols[m.y], w_cols[m.z]);
    } else if !pinned {
        p = vec3<f32>(out[o], out[o + 1u], out[o + 2u]) + points[params.shift_base + i].xyz + u;
    }
    out[o] = p.x;
    out[o + 1u] = p.y;
    out[o + 2u] = p.z;
    if DISPLACEMENT_WORD != 0xffffffffu {
        out[o + DISPLACEMENT_WORD] = length(p - x0);
    }
    store_texture(i, p);
}
