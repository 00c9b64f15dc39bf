// touchfem's per-deformer uniform, shared by deform.wgsl, deform_hier.wgsl and correct.wgsl:
// the host (touchfem-gpu's shaders.rs) puts this file before each of them. The Rust side is
// `FrameGpu` (crates/gpu/src/input.rs).

struct Frame {
    // Displayed vertices (rows of L; the hierarchical layout's output rows).
    n_rows: u32,
    // Output: first f32 word of vertex 0 in `out`, and the vertex stride in f32 words.
    out_offset: u32,
    out_stride: u32,
    // Normal's first word relative to the vertex start; 0xffffffff: no normals written.
    normal_offset: u32,
    // Rows that hold L (R' ≤ n_rows): the first ones (the hierarchical layout: the row
    // positions of the cluster tree).
    l_rows: u32,
    // Vertices the normal pass shades (≥ n_rows): the rows, then the vertices reserved for
    // the nodes a separating cut adds (correct.wgsl writes their positions).
    n_vertices: u32,
    _pad1: u32,
    _pad2: u32,
}
