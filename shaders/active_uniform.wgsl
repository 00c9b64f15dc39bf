// Prelude of deform_texture.wgsl: the active list lives in the uniform buffer `forces` and its
// length in `frame.n_active`, both written with Queue::write_buffer each frame. Used when the
// device lacks the IMMEDIATES feature (or the caller turned immediates off).

fn active_count() -> u32 {
    return frame.n_active;
}

fn active_entry(k: u32) -> Active {
    return forces[k];
}
