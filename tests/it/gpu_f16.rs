//! Half-float storage of `L` on the GPU ([`LStorage::BuffersF16`], [`LStorage::TextureF16`]):
//! its displacements against the
//! f64 `L·F` on the CPU, beside f32 storage. Needs an adapter (lavapipe works).

use glam::DVec3;
use touchfem::compliance::{Compliance, Selection};
use touchfem::gpu::{Deformer, DeformerOptions, Gpu, LStorage};
use touchfem::mesh::{cube, mouse, Mesh};

/// Max |u_gpu − u_f64| over the displayed rows, relative to max |u_f64|, for `storage`.
fn rel_error(g: &Gpu, mesh: &Mesh, c: &Compliance, storage: LStorage, cols: &[u32]) -> f64 {
    let opts = DeformerOptions {
        storage,
        ..Default::default()
    };
    let mut d =
        Deformer::new(&g.device, &g.queue, c, &mesh.nodes, &mesh.surface, &opts).expect("deformer");
    assert_eq!(d.stats().storage, storage);
    // Forces of 50 .. 250 mN in mixed directions on the given columns (displacements of
    // millimetres, so that the f32 rounding of the rest positions stays below 1e-6 of them).
    let forces: Vec<(u32, DVec3)> = cols
        .iter()
        .enumerate()
        .map(|(k, &col)| {
            let s = 0.05 * (1.0 + (k % 5) as f64) * mesh.material.young_pa / 1000.0;
            (col, DVec3::new(0.3 * s, -0.5 * s, -s))
        })
        .collect();
    let f32s: Vec<(u32, [f32; 3])> = forces
        .iter()
        .map(|&(c, f)| (c, f.as_vec3().to_array()))
        .collect();
    d.set_forces(&g.queue, &f32s).expect("forces");
    let mut enc = g.device.create_command_encoder(&Default::default());
    d.encode(&mut enc);
    g.queue.submit([enc.finish()]);
    let (got, _) = d.read_back(&g.device, &g.queue).expect("read back");
    let nr = c.rows().len();
    let mut u = vec![DVec3::ZERO; nr];
    c.displace(&forces, &mut u);
    let max_u = u.iter().map(|v| v.length()).fold(0.0, f64::max);
    assert!(max_u > 0.0);
    let mut err = 0.0f64;
    for (r, &node) in c.rows().iter().enumerate() {
        let rest = mesh.nodes[node as usize].as_vec3().as_dvec3();
        let p = got[r];
        let gpu = DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64) - rest;
        err = err.max((gpu - u[r]).length());
    }
    err / max_u
}

#[test]
fn half_float_l_stays_within_2e_3_of_the_f64_displacement() {
    let g = Gpu::new_headless()
        .unwrap_or_else(|e| panic!("GPU tests need an adapter and must not be skipped: {e}"));
    // A stiff cube too: L of ~1e-9 m/N would be subnormal in half floats without the scale.
    let mut stiff = cube();
    stiff.material.young_pa = 1e9;
    for (name, mesh) in [("cube", cube()), ("stiff cube", stiff), ("mouse", mouse())] {
        let c = Compliance::compute(&mesh, &Selection::default()).unwrap();
        let nc = c.cols().len() as u32;
        // One contact triangle's nodes, then a spread of columns.
        for cols in [vec![0, 1, 2], (0..nc).step_by(7).collect::<Vec<_>>()] {
            let e32 = rel_error(&g, &mesh, &c, LStorage::Buffers, &cols);
            let e16 = rel_error(&g, &mesh, &c, LStorage::BuffersF16, &cols);
            let t32 = rel_error(&g, &mesh, &c, LStorage::Texture, &cols);
            let t16 = rel_error(&g, &mesh, &c, LStorage::TextureF16, &cols);
            println!(
                "{name}, {} columns: buffers f32 {e32:.2e}, f16 {e16:.2e}; texture f32 {t32:.2e}, f16 {t16:.2e}",
                cols.len()
            );
            for (layout, e32, e16) in [("buffers", e32, e16), ("texture", t32, t16)] {
                assert!(e32 <= 1e-5, "{name}, {layout}: f32 error {e32}");
                assert!(e16 <= 2e-3, "{name}, {layout}: f16 error {e16}");
                // It is the half-float rounding, not a layout error: well above f32's.
                assert!(e16 > 10.0 * e32, "{name}, {layout}: f16 {e16} vs f32 {e32}");
            }
            // The two layouts round L the same way: the same f16 error to f32 precision.
            assert!(
                (e16 - t16).abs() <= 1e-3 * e16 + 1e-6,
                "{name}: {e16} vs {t16}"
            );
        }
    }
}
