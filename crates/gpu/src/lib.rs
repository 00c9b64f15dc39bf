//! # touchfem-gpu
//!
//! The GPU side of the visual loop: a wgpu compute pass that evaluates `u = L·F` over the active
//! columns straight into a vertex buffer, and recomputes the deformed surface's vertex normals;
//! and the offscreen [`render`]er.
//!
//! * [`Deformer`] is the embeddable piece (in the style of glyphon or egui-wgpu): it borrows the
//!   caller's [`wgpu::Device`] and [`wgpu::Queue`], uploads `L` once ([`DeformerInput`], in the
//!   [`LStorage`] layout of [`DeformerOptions`]), takes a force boundary condition per frame
//!   with [`Deformer::set_forces`] and records its passes into the caller's encoder with
//!   [`Deformer::encode`]. A cut's correction and opened surface go on it with
//!   [`install_cut`]; [`Deformer::stats`] tells what it holds.
//! * [`Gpu`] is a small headless context (instance, adapter, device, queue) for tools, tests and
//!   the offscreen [`crate::render`]er; it honours `WGPU_BACKEND`, `WGPU_ADAPTER_NAME` and
//!   `WGPU_POWER_PREF`.
//!
//! Use the re-exported [`crate::wgpu`] so that your wgpu version matches ours.

mod bind;
mod buffer_path;
mod context;
mod correct;
mod deform;
mod hier_path;
mod input;
mod options;
pub mod render;
mod shaders;
mod surface;
mod texture_path;

pub use wgpu;

pub use context::{read_buffer, AdapterSelection, Gpu, GpuError};
pub use deform::{install_cut, Deformer, DeformerStats};
pub use hier_path::{hier_gpu_bytes, HIER_VALUE_BINDINGS};
pub use input::{
    DeformerInput, DeformerOptions, LData, LStorage, OutputTarget, Vertex, MAX_ACTIVE,
    VERTEX_STRIDE,
};
pub use shaders::INLINE_ACTIVE;

#[cfg(test)]
mod tests {
    use crate::buffer_path::{deform_f16_wgsl, pack_f16};
    use crate::correct::MAX_CORRECTION_RANK;
    use crate::input::MAX_ACTIVE;
    use crate::shaders::*;

    fn validate(name: &str, src: &str, caps: naga::valid::Capabilities) {
        let module = naga::front::wgsl::parse_str(src)
            .unwrap_or_else(|e| panic!("{name}: {}", e.emit_to_string(src)));
        naga::valid::Validator::new(naga::valid::ValidationFlags::all(), caps)
            .validate(&module)
            .unwrap_or_else(|e| panic!("{name}: {}", e.emit_to_string(src)));
    }

    /// The half-float variant of `deform.wgsl` validates, and packing keeps the low half first.
    #[test]
    fn f16_shader_validates_and_packs_low_half_first() {
        validate(
            "deform.wgsl (f16)",
            &deform_f16_wgsl(),
            naga::valid::Capabilities::SHADER_FLOAT16_IN_FLOAT32,
        );
        let w = pack_f16(&[1.0, -2.0, 0.5]);
        assert_eq!(w, [0x3c00 | (0xc000 << 16), 0x3800]);
    }

    /// `deform_hier.wgsl` for every number of value buffers, in f32 and half floats,
    /// validates, reads each buffer in use and sums them.
    #[test]
    fn hier_shader_variants_validate() {
        use super::hier_path::deform_hier_wgsl;
        for n in 1..=super::HIER_VALUE_BINDINGS {
            for half in [false, true] {
                let src = deform_hier_wgsl(n, half);
                let name = format!("deform_hier.wgsl ({n} buffers, half {half})");
                assert_eq!(src.contains("unpack2x16float"), half, "{name}");
                assert!(!src.contains("MORE BUFFERS"), "{name}");
                for k in 0..super::HIER_VALUE_BINDINGS {
                    let reads = src.contains(&format!("v{k}[i"));
                    assert_eq!(reads, k < n, "{name}: v{k}");
                    if k > 0 {
                        assert_eq!(src.contains(&format!("u += add{k}(h, r);")), k < n);
                        assert_eq!(src.contains(&format!("z += reduce{k}(")), k < n);
                    }
                }
                validate(
                    &name,
                    &src,
                    naga::valid::Capabilities::SHADER_FLOAT16_IN_FLOAT32,
                );
            }
        }
    }

    /// Every shader in `shaders/` parses and validates with naga (no GPU needed): the
    /// stand-alone ones as they are, `deform.wgsl` after `frame.wgsl`, the texture layout's body
    /// with each of its preludes, the correction with each of its endings.
    #[test]
    fn shaders_validate_with_naga() {
        use naga::valid::Capabilities;
        let dir = concat!(env!("CARGO_MANIFEST_DIR"), "/../../shaders");
        let parts = [
            "frame.wgsl",
            "deform.wgsl",
            "deform_hier.wgsl",
            "deform_texture.wgsl",
            "active_uniform.wgsl",
            "active_immediate.wgsl",
            "output_words.wgsl",
            "output_vertex.wgsl",
            "correct.wgsl",
        ];
        let mut n = 0;
        for entry in std::fs::read_dir(dir).expect("shaders/ exists") {
            let path = entry.unwrap().path();
            if path.extension().and_then(|e| e.to_str()) != Some("wgsl") {
                continue;
            }
            n += 1;
            let name = path.file_name().unwrap().to_str().unwrap().to_string();
            if parts.contains(&name.as_str()) {
                continue;
            }
            let src = std::fs::read_to_string(&path).unwrap();
            validate(&name, &src, Capabilities::empty());
        }
        assert!(
            n >= 8,
            "expected frame.wgsl, deform.wgsl, render.wgsl, correct.wgsl and the texture layout's five parts, found {n}"
        );
        validate("deform.wgsl", &deform_source(), Capabilities::empty());
        for positions in [false, true] {
            validate(
                &format!("correct (positions texture {positions})"),
                &correct_source(positions),
                Capabilities::empty(),
            );
        }
        for immediates in [false, true] {
            for vertex in [false, true] {
                for half in [false, true] {
                    let caps = if immediates {
                        Capabilities::IMMEDIATES
                    } else {
                        Capabilities::empty()
                    };
                    let src = deform_texture_source(immediates, vertex, half);
                    assert_eq!(src.contains("rgba16float"), half);
                    validate(
                        &format!(
                            "deform_texture (immediates {immediates}, vertex layout {vertex}, half {half})"
                        ),
                        &src,
                        caps,
                    );
                }
            }
        }
    }

    /// The correction pass's uniform weights hold exactly `MAX_CORRECTION_RANK` of them.
    #[test]
    fn correction_weights_match_max_rank() {
        let decl = format!("array<vec4<f32>, {}>", MAX_CORRECTION_RANK / 4);
        assert!(CORRECT_WGSL.contains(&decl), "{decl} not found");
    }

    /// The shaders' fixed-size active lists hold exactly `MAX_ACTIVE` entries.
    #[test]
    fn shaders_active_lists_match_max_active() {
        let decl = format!("array<Active, {}>", MAX_ACTIVE);
        for src in [DEFORM_WGSL, DEFORM_TEXTURE_WGSL, DEFORM_HIER_WGSL] {
            assert!(src.contains(&decl), "{decl} not found");
        }
        // And the hierarchical pass's per-frame window, its vec4s.
        let window = format!("array<vec4<u32>, {}>", super::hier_path::WINDOW_VEC4S);
        assert!(DEFORM_HIER_WGSL.contains(&window), "{window} not found");
        let inline = INLINE_ACTIVE;
        assert_eq!(16 + 16 * inline as u32, IMMEDIATE_BYTES);
        for decl in [
            format!("array<Active, {inline}>"),
            format!("imm.entries[{}]", inline - 1),
            format!("ACTIVE_INLINE > {}u", inline - 1),
        ] {
            assert!(ACTIVE_IMMEDIATE_WGSL.contains(&decl), "{decl} not found");
        }
    }

    /// `frame.wgsl` is put before each shader that reads `Frame`, which none declares itself;
    /// its `Frame` is as large as the host's `FrameGpu`.
    #[test]
    fn frame_preamble_is_shared() {
        for (name, body) in [
            ("deform.wgsl", DEFORM_WGSL),
            ("deform_hier.wgsl", DEFORM_HIER_WGSL),
            ("correct.wgsl", CORRECT_WGSL),
        ] {
            assert!(body.contains("Frame"), "{name} reads Frame");
            assert!(!body.contains("struct Frame {"), "{name} declares Frame");
        }
        for src in [
            deform_source(),
            deform_f16_wgsl(),
            crate::hier_path::deform_hier_wgsl(1, false),
            correct_source(false),
        ] {
            assert!(src.starts_with(FRAME_WGSL));
        }
        let module = naga::front::wgsl::parse_str(FRAME_WGSL).unwrap();
        let mut layouter = naga::proc::Layouter::default();
        layouter.update(module.to_ctx()).unwrap();
        let frame = module
            .types
            .iter()
            .find(|(_, t)| t.name.as_deref() == Some("Frame"))
            .map(|(h, _)| h)
            .unwrap();
        assert_eq!(
            layouter[frame].size as usize,
            std::mem::size_of::<crate::input::FrameGpu>()
        );
    }

    #[test]
    fn embedded_shaders_are_the_files() {
        for (name, embedded) in [
            ("deform.wgsl", DEFORM_WGSL),
            ("deform_texture.wgsl", DEFORM_TEXTURE_WGSL),
            ("deform_hier.wgsl", DEFORM_HIER_WGSL),
            ("active_uniform.wgsl", ACTIVE_UNIFORM_WGSL),
            ("active_immediate.wgsl", ACTIVE_IMMEDIATE_WGSL),
            ("output_words.wgsl", OUTPUT_WORDS_WGSL),
            ("output_vertex.wgsl", OUTPUT_VERTEX_WGSL),
            ("correct.wgsl", CORRECT_WGSL),
            ("frame.wgsl", FRAME_WGSL),
        ] {
            let path = format!("{}/../../shaders/{name}", env!("CARGO_MANIFEST_DIR"));
            assert_eq!(std::fs::read_to_string(path).unwrap(), embedded, "{name}");
        }
    }
}
