// touchfem deformation from a hierarchical L: u = L_H·F over the active columns, where
// L_H is a block partition of dense near blocks and low-rank far blocks U·Vᵀ. Used by
// `touchfem::gpu::Deformer` for a hierarchical compliance; its normal pass is deform.wgsl's.
//
// Per frame the host (touchfem-gpu's hier_path.rs) sorts the active columns by position, lists
// the active column leaves and, per leaf, every block of its column (a "hit": the block's
// values as a matrix in rows × listed columns, and its coefficients). Two dispatches:
// * `reduce`: one workgroup per low-rank hit b (a far block over active columns), its threads
//   over the rank: z_b = V_bᵀ·f over the block's active columns, written into `work` as
//   (l, z_l) pairs; the encoder then copies them into the window's coefficients.
// * `deform`: one thread per output row. Rows in 0..l_rows are row *positions* of the row
//   cluster tree (neighbouring threads read neighbouring entries of a block); row index
//   row_perm[p] is written. For each active leaf, the row's hit is found through the leaf ×
//   segment table (a segment: rows between two block starts, in one block of every leaf) and
//   adds Σ_j B[row, col_j]·c_j: a dense block's active columns times the forces, a low-rank
//   block's U times z_b (listed at the block's first active leaf only).
//   Rows from l_rows on stay at rest.
//
// Written for software rasterisers as much as GPUs: llvmpipe (lavapipe) runs every branch of
// divergent code for every lane and loads storage buffers lane by lane. So the row pass has a
// single code path (dense, low-rank and transposed blocks differ only in the hit's base and
// strides), its per-frame tables are in a uniform buffer (`tab`), and the values are read from
// one buffer per loop (`add0`, repeated per value buffer by the host; a hit's loops for other
// buffers run no iteration).
// A frame whose tables exceed one 64 KiB window is dispatched once per window, each adding
// to the last.

// The deformer's frame (frame.wgsl, put before this file by the host) and, after it, where
// the tables start.
struct HierFrame {
    base: Frame,
    // Word offsets in `idx` of row_perm (then each row position's segment), of the block table
    // (7 words a block: row start, m, column start, n with the transposed flag in bit 31, rank,
    // buffer, first value) and of the leaf × segment table (an index into the leaf's hits);
    // of the (l, z_l) pairs in `work`.
    perm_off: u32,
    blocks_off: u32,
    lb_off: u32,
    z_off: u32,
}

// One active entry: F (newtons, times the half-float scale) and its column position.
struct Active {
    force: vec3<f32>,
    pos: u32,
}

struct Params {
    // Hit low-rank blocks this frame.
    n_hits: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
    // Sorted by column position. 1024 = touchfem::gpu::MAX_ACTIVE.
    actives: array<Active, 1024>,
}

// A block's rank in the block table when it is stored dense.
const DENSE: u32 = 0xffffffffu;

// Word of a vertex (relative to its start) that receives |u| (the deformer's own Vertex layout:
// 3, position.w); 0xffffffff: not written.
override DISPLACEMENT_WORD: u32 = 0xffffffffu;

// f32 values; the half-float variant reads u32 words holding two halves each.
alias Word = f32;

@group(0) @binding(0) var<uniform> frame: HierFrame;
@group(0) @binding(1) var<uniform> params: Params;
// Rest positions (4 words a row, f32 bits), row_perm, segments, the block table and the leaf ×
// segment table.
@group(0) @binding(2) var<storage, read> idx: array<u32>;
@group(0) @binding(3) var<storage, read_write> out: array<f32>;
// The low-rank hits (4 words each: block, first and end active entry, first pair), then the
// (l, z_l) pairs.
@group(0) @binding(4) var<storage, read_write> work: array<u32>;
// One window of this frame's tables (bound at a dynamic offset), in vec4s: [0] the number of
// active leaves and whether this is the frame's first window; per leaf (from 1) its row of the
// leaf × segment table and its first hit; per hit two vec4s (first value, row stride, column
// stride, first row position; columns, first coefficient pair, value buffer); the
// coefficients, (column, value bits) pairs, two a vec4.
@group(0) @binding(5) var<uniform> tab: array<vec4<u32>, 4096>;
// The values, split over up to five bindings, whole blocks each (WGSL cannot index an array of
// buffers at run time); unused ones are bound to a small dummy buffer.
@group(1) @binding(0) var<storage, read> v0: array<Word>;
@group(1) @binding(1) var<storage, read> v1: array<Word>;
@group(1) @binding(2) var<storage, read> v2: array<Word>;
@group(1) @binding(3) var<storage, read> v3: array<Word>;
@group(1) @binding(4) var<storage, read> v4: array<Word>;

// A hit: entry (r, c) of its block at base + r·rs + c·cs; `cols` coefficient pairs from `coef`
// (pair index in the window); its values in buffer `buf`.
struct Hit {
    base: u32,
    rs: u32,
    cs: u32,
    row_start: u32,
    cols: u32,
    coef: u32,
    buf: u32,
}

// Coefficient pair j of the window: (column, value).
fn coef(j: u32) -> vec2<u32> {
    let w = tab[j >> 1u];
    return select(w.xy, w.zw, (j & 1u) == 1u);
}

// BEGIN PER BUFFER: what reads value buffer 0. hier_path.rs repeats this block for v1 … v4
// (renaming val0, add0, reduce0, v0 and buffer 0), one a value buffer in use.

// Value i of buffer 0.
fn val0(i: u32) -> f32 {
    return v0[i];
}

// Σ_j B[3i + (0, 1, 2), col_j]·c_j for a hit in buffer b, zero for the others (their loop runs
// no iteration).
fn add0(h: Hit, r: u32) -> vec3<f32> {
    var u = vec3<f32>(0.0);
    let n = select(0u, h.cols, h.buf == 0u);
    for (var j = 0u; j < n; j += 1u) {
        let c = coef(h.coef + j);
        let e = h.base + r * h.rs + c.x * h.cs;
        u += vec3<f32>(val0(e), val0(e + h.rs), val0(e + 2u * h.rs)) * bitcast<f32>(c.y);
    }
    return u;
}
// z_l = Σ_a V[3(pos_a − col start) + (0, 1, 2), l]·f_a over the hit's active entries, V's
// entry (c, l) at base + c·rs + l·cs, in buffer b (0 for the others).
fn reduce0(base: u32, rs: u32, cs: u32, l: u32, a0: u32, a1: u32, col_start: u32, b: u32) -> f32 {
    var z = 0.0;
    let n = select(a0, a1, b == 0u);
    for (var a = a0; a < n; a += 1u) {
        let e = params.actives[a];
        let i = base + 3u * (e.pos - col_start) * rs + l * cs;
        z += val0(i) * e.force.x + val0(i + rs) * e.force.y + val0(i + 2u * rs) * e.force.z;
    }
    return z;
}
// END PER BUFFER

// Σ over the value buffers in use.
fn add(h: Hit, r: u32) -> vec3<f32> {
    var u = add0(h, r);
    // MORE BUFFERS: u += addB(h, r);
    return u;
}

@compute @workgroup_size(64)
fn deform(@builtin(global_invocation_id) gid: vec3<u32>) {
    let t = gid.x;
    if t >= frame.base.n_rows {
        return;
    }
    let head = tab[0];
    var u = vec3<f32>(0.0);
    var r = t;
    if t < frame.base.l_rows {
        let p = t;
        r = idx[frame.perm_off + p];
        let seg = idx[frame.perm_off + frame.base.l_rows + p];
        for (var q = 0u; q < head.x; q += 1u) {
            let leaf = tab[1u + q];
            // The row's hit in this leaf: the leaf × segment table at the row's segment.
            let hv = leaf.y + 2u * idx[frame.lb_off + leaf.x + seg];
            let a = tab[hv];
            let b = tab[hv + 1u];
            u += add(Hit(a.x, a.y, a.z, a.w, b.x, b.y, b.z), 3u * (p - a.w));
        }
    }
    let s = 4u * r;
    let rest = vec3<f32>(bitcast<f32>(idx[s]), bitcast<f32>(idx[s + 1u]), bitcast<f32>(idx[s + 2u]));
    let o = frame.base.out_offset + r * frame.base.out_stride;
    // The first window starts from the rest position, later ones add to it.
    let before = vec3<f32>(out[o], out[o + 1u], out[o + 2u]);
    let x = select(before, rest, head.y == 1u) + u;
    out[o] = x.x;
    out[o + 1u] = x.y;
    out[o + 2u] = x.z;
    if DISPLACEMENT_WORD != 0xffffffffu {
        out[o + DISPLACEMENT_WORD] = length(x - rest);
    }
}

struct Block {
    // Row and column nodes.
    m: u32,
    n: u32,
    // Read as the transpose of its source block's values (a mirror: the source's U and V
    // swapped).
    t: bool,
    rank: u32,
    buf: u32,
    // First value in its buffer.
    off: u32,
}

fn block(bi: u32) -> Block {
    let o = frame.blocks_off + 7u * bi;
    let n = idx[o + 3u];
    return Block(idx[o + 1u], n & 0x7fffffffu, (n >> 31u) == 1u, idx[o + 4u], idx[o + 5u],
        idx[o + 6u]);
}

@compute @workgroup_size(64)
fn reduce(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_id) lid: vec3<u32>,
) {
    for (var h = wid.x; h < params.n_hits; h += nwg.x) {
        let bi = work[4u * h];
        let b = block(bi);
        let col_start = idx[frame.blocks_off + 7u * bi + 2u];
        let a0 = work[4u * h + 1u];
        let a1 = work[4u * h + 2u];
        let pair = frame.z_off + 2u * work[4u * h + 3u];
        let k = b.rank;
        // V (3n × k, row-major) follows U (3m × k); a transposed block's "V" is its source's
        // U (3n × k, column-major, first).
        var base = b.off + 3u * b.m * k;
        var rs = k;
        var cs = 1u;
        if b.t {
            base = b.off;
            rs = 1u;
            cs = 3u * b.n;
        }
        for (var l = lid.x; l < k; l += 64u) {
            var z = reduce0(base, rs, cs, l, a0, a1, col_start, b.buf);
            // MORE BUFFERS: z += reduceB(base, rs, cs, l, a0, a1, col_start, b.buf);
            work[pair + 2u * l] = l;
            work[pair + 2u * l + 1u] = bitcast<u32>(z);
        }
    }
}
