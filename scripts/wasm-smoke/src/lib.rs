//! A wasm module that exercises the pure engine: a haptic press on the bundled fig1 scene, the
//! cube's dense and hierarchical compliance. Built and run by `scripts/check-wasm.sh --run`.

use glam::DVec3;
use touchfem_core::compliance::hmatrix::HOptions;
use touchfem_core::compliance::{Compliance, Selection};
use touchfem_core::haptic::{HapticWorld, WorldSample};
use touchfem_core::scene::{SceneSource, World};

/// fig1: 300 steps pressing 5 mm; the last force's z (N).
#[no_mangle]
pub extern "C" fn press_force_z() -> f64 {
    let src = SceneSource::find("fig1").unwrap().unwrap();
    let world = World::from_source_with(&src, None).unwrap();
    let mut hw = HapticWorld::new(&world);
    let mut sample = WorldSample::default();
    let mut f = [DVec3::ZERO; 1];
    for k in 0..=300 {
        let z = 40.0 - 15.0 * (k as f64 / 300.0);
        hw.step(&[DVec3::new(15.0, 15.0, z) * 1e-3], &mut f, &mut sample);
    }
    f[0].z
}

/// The cube's compliance: the sum of the touch blocks' xx.
#[no_mangle]
pub extern "C" fn cube_trace() -> f64 {
    let mesh = touchfem_core::mesh::cube();
    let c = Compliance::compute(&mesh, &Selection::default()).unwrap();
    (0..c.cols().len())
        .map(|j| c.touch_block(j, j).x_axis.x)
        .sum()
}

/// The cube's hierarchical compliance (1e-6): the sum of the touch blocks' xx.
#[no_mangle]
pub extern "C" fn cube_hier_trace() -> f64 {
    let mesh = touchfem_core::mesh::cube();
    let c = Compliance::compute_hier(
        &mesh,
        &Selection::default(),
        &HOptions::new(1e-6),
        &mut |_, _| {},
    )
    .unwrap();
    (0..c.cols().len())
        .map(|j| c.touch_block(j, j).x_axis.x)
        .sum()
}
