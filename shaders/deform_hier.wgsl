// touchfem deformation from a hierarchical L (issue 29): u = L_H·F over the active columns, where
// L_H is a block partition of dense near blocks and low-rank far blocks U·Vᵀ. Used by
// `touchfem::gpu::Deformer` for a hierarchical compliance; its normal pass is deform.wgsl's.
//
// Two dispatches a frame:
// * `reduce`: one workgroup per hit low-rank block b (a far block over an active column), its
//   threads over the rank: z_b = V_bᵀ·f summed over the block's active columns, into `work`.
// * `deform`: one thread per output row. Rows in 0..l_rows are row *positions* of the row
//   cluster tree (neighbouring threads read neighbouring entries of a block); row index
//   row_perm[p] is written. For each active column leaf, the block holding the row is read from
//   the leaf × row-segment table (a segment: rows between two block starts, in one block of
//   every leaf);
//   a dense block adds B[row, leaf's active columns]·f, a low-rank one U[row, :]·z_b once (at the
//   block's first active leaf). Rows from l_rows on stay at rest.
//
// The host (touchfem-gpu's hier_path.rs) sorts the active columns by position and lists the
// active leaves and hit blocks; nothing is read back. All counts come from uniforms.

struct Frame {
    // Displayed vertices (output rows).
    n_rows: u32,
    // Output: first f32 word of vertex 0 in `out`, and the vertex stride in f32 words.
    out_offset: u32,
    out_stride: u32,
    // Normal's first word relative to the vertex start (deform.wgsl's normal pass reads it).
    normal_offset: u32,
    // Rows that hold L (the row positions of the cluster tree).
    l_rows: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
    // Word offsets in `idx` of row_perm (then each row position's segment), of the block table
    // (8 words a block: row start, m, column start, n with the transposed flag in bit 31, rank,
    // buffer, first value, z) and of the leaf × segment table (a block per entry); of z in `work`.
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
    // Active leaves and hit low-rank blocks this frame.
    n_leaves: u32,
    n_hits: u32,
    _pad0: u32,
    _pad1: u32,
    // Sorted by column position. 1024 = touchfem::gpu::MAX_ACTIVE.
    actives: array<Active, 1024>,
    // Per active leaf: its row of the leaf × segment table, unused, and its run of `actives`.
    leaves: array<vec4<u32>, 1024>,
}

// A block's rank when it is stored dense.
const DENSE: u32 = 0xffffffffu;

// Word of a vertex (relative to its start) that receives |u| (the deformer's own Vertex layout:
// 3, position.w); 0xffffffff: not written.
override DISPLACEMENT_WORD: u32 = 0xffffffffu;

// f32 values; the half-float variant reads u32 words holding two halves each.
alias Word = f32;

@group(0) @binding(0) var<uniform> frame: Frame;
@group(0) @binding(1) var<uniform> params: Params;
// Rest positions (4 words a row, f32 bits), row_perm, the block table and the leaf lists.
@group(0) @binding(2) var<storage, read> idx: array<u32>;
@group(0) @binding(3) var<storage, read_write> out: array<f32>;
// The hit list (4 words a hit: block, first and end active entry, pad), then z (f32 bits).
@group(0) @binding(4) var<storage, read_write> work: array<u32>;
// The values, split over up to five bindings, whole blocks each (WGSL cannot index an array of
// buffers at run time); unused ones are bound to a small dummy buffer.
@group(1) @binding(0) var<storage, read> v0: array<Word>;
@group(1) @binding(1) var<storage, read> v1: array<Word>;
@group(1) @binding(2) var<storage, read> v2: array<Word>;
@group(1) @binding(3) var<storage, read> v3: array<Word>;
@group(1) @binding(4) var<storage, read> v4: array<Word>;

// Value buffers in use (1..=5): with one, loads skip the switch.
override VALUE_BUFFERS: u32 = 5u;

fn word(b: u32, i: u32) -> Word {
    if VALUE_BUFFERS == 1u {
        return v0[i];
    }
    switch b {
        case 0u: {
            return v0[i];
        }
        case 1u: {
            return v1[i];
        }
        case 2u: {
            return v2[i];
        }
        case 3u: {
            return v3[i];
        }
        default: {
            return v4[i];
        }
    }
}

// Value i of buffer b.
fn val(b: u32, i: u32) -> f32 {
    return word(b, i);
}

fn val3(b: u32, i: u32) -> vec3<f32> {
    return vec3<f32>(val(b, i), val(b, i + 1u), val(b, i + 2u));
}

struct Block {
    row_start: u32,
    // Row nodes.
    m: u32,
    col_start: u32,
    // Column nodes.
    n: u32,
    // Read as the transpose of its source block's values (a mirror: the source's U and V
    // swapped, a dense source read across).
    t: bool,
    // DENSE or k.
    rank: u32,
    buf: u32,
    // First value in its buffer.
    off: u32,
    // Its z in `work` (after z_off).
    z: u32,
}

fn block(bi: u32) -> Block {
    let o = frame.blocks_off + 8u * bi;
    let n = idx[o + 3u];
    return Block(
        idx[o], idx[o + 1u], idx[o + 2u], n & 0x7fffffffu, (n >> 31u) == 1u,
        idx[o + 4u], idx[o + 5u], idx[o + 6u], idx[o + 7u],
    );
}

@compute @workgroup_size(64)
fn reduce(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_id) lid: vec3<u32>,
) {
    for (var h = wid.x; h < params.n_hits; h += nwg.x) {
        let b = block(work[4u * h]);
        let a0 = work[4u * h + 1u];
        let a1 = work[4u * h + 2u];
        let k = b.rank;
        // V (3n × k, row-major) follows U (3m × k); a transposed block's "V" is its source's
        // U (3n × k, column-major, first).
        let v = b.off + 3u * b.m * k;
        let n3 = 3u * b.n;
        for (var l = lid.x; l < k; l += 64u) {
            var z = 0.0;
            for (var a = a0; a < a1; a += 1u) {
                let e = params.actives[a];
                let c = 3u * (e.pos - b.col_start);
                if b.t {
                    z += dot(val3(b.buf, b.off + l * n3 + c), e.force);
                } else {
                    let i = v + c * k + l;
                    z += val(b.buf, i) * e.force.x + val(b.buf, i + k) * e.force.y
                        + val(b.buf, i + 2u * k) * e.force.z;
                }
            }
            work[frame.z_off + b.z + l] = bitcast<u32>(z);
        }
    }
}

@compute @workgroup_size(64)
fn deform(@builtin(global_invocation_id) gid: vec3<u32>) {
    let t = gid.x;
    if t >= frame.n_rows {
        return;
    }
    var u = vec3<f32>(0.0);
    var r = t;
    if t < frame.l_rows {
        let p = t;
        r = idx[frame.perm_off + p];
        for (var q = 0u; q < params.n_leaves; q += 1u) {
            let leaf = params.leaves[q];
            // The row's block in this leaf: the leaf × segment table at the row's segment.
            let seg = idx[frame.perm_off + frame.l_rows + p];
            let b = block(idx[frame.lb_off + leaf.x + seg]);
            let m3 = 3u * b.m;
            let i = 3u * (p - b.row_start);
            let n3 = 3u * b.n;
            if b.rank == DENSE && b.t {
                // The source is 3n × 3m column-major: this row's entries run down its columns.
                for (var a = leaf.z; a < leaf.w; a += 1u) {
                    let e = params.actives[a];
                    let c = b.off + i * n3 + 3u * (e.pos - b.col_start);
                    u += vec3<f32>(
                        dot(val3(b.buf, c), e.force),
                        dot(val3(b.buf, c + n3), e.force),
                        dot(val3(b.buf, c + 2u * n3), e.force),
                    );
                }
            } else if b.rank == DENSE {
                // 3m × 3n column-major.
                for (var a = leaf.z; a < leaf.w; a += 1u) {
                    let e = params.actives[a];
                    let c = b.off + 3u * (e.pos - b.col_start) * m3 + i;
                    u += val3(b.buf, c) * e.force.x + val3(b.buf, c + m3) * e.force.y
                        + val3(b.buf, c + 2u * m3) * e.force.z;
                }
            } else if leaf.z == 0u || params.actives[leaf.z - 1u].pos < b.col_start {
                // This is the block's first active leaf: U (3m × k, column-major)·z_b; for a
                // transposed block its source's V (3m × k, row-major, after its U).
                let z = frame.z_off + b.z;
                if b.t {
                    let v = b.off + n3 * b.rank + i * b.rank;
                    for (var l = 0u; l < b.rank; l += 1u) {
                        let zl = bitcast<f32>(work[z + l]);
                        u += vec3<f32>(
                            val(b.buf, v + l),
                            val(b.buf, v + b.rank + l),
                            val(b.buf, v + 2u * b.rank + l),
                        ) * zl;
                    }
                } else {
                    for (var l = 0u; l < b.rank; l += 1u) {
                        u += val3(b.buf, b.off + l * m3 + i) * bitcast<f32>(work[z + l]);
                    }
                }
            }
        }
    }
    let s = 4u * r;
    let x = vec3<f32>(bitcast<f32>(idx[s]), bitcast<f32>(idx[s + 1u]), bitcast<f32>(idx[s + 2u])) + u;
    let o = frame.out_offset + r * frame.out_stride;
    out[o] = x.x;
    out[o + 1u] = x.y;
    out[o + 2u] = x.z;
    if DISPLACEMENT_WORD != 0xffffffffu {
        out[o + DISPLACEMENT_WORD] = length(u);
    }
}
