// Prelude of deform_texture.wgsl: the active list lives in the uniform buffer `forces` and its
// length in `frame.n_active`, both written with Queue::write_buffer each frame. Used when the
// device lacks the IMMEDIATES feature (or the caller turned immediates off).

// u at row r: Σ over the active entries of L[r, c]·F_c.
fn displacement(r: u32, nr: u32) -> vec3<f32> {
    var u = vec3<f32>(0.0);
    for (var k = 0u; k < frame.n_active; k += 1u) {
        u += column_term(forces[k], r, nr);
    }
    return u;
}
