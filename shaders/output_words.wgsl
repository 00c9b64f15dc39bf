// Prelude of deform_texture.wgsl: vertices go to a caller's buffer at any 4-byte offset and
// stride (touchfem::gpu::OutputTarget), three f32 words each for the position and the normal;
// the other words are left untouched (the displacement u is not written).

@group(0) @binding(2) var<storage, read_write> out: array<f32>;

fn store_position(r: u32, p: vec3<f32>, u: vec3<f32>) {
    let o = frame.out_offset + r * frame.out_stride;
    out[o] = p.x;
    out[o + 1u] = p.y;
    out[o + 2u] = p.z;
}

fn store_normal(v: u32, n: vec3<f32>) {
    let o = frame.out_offset + v * frame.out_stride + frame.normal_offset;
    out[o] = n.x;
    out[o + 1u] = n.y;
    out[o + 2u] = n.z;
}
