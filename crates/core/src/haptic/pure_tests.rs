//! The pure engine, as the browser runs it: one thread, bytes in and bytes out. These tests run
//! with and without the `native` feature (`cargo test -p touchfem-core --no-default-features
//! --lib` runs the sequential fallbacks, no METIS, no clock, no environment) and assert the same
//! numbers: bit for bit with `native`, and to 1e-12 without, where METIS is absent and the
//! factorisation takes the coordinate nested dissection (another order of the same sums).

use glam::DVec3;

use crate::cache;
use crate::compliance::hmatrix::HOptions;
use crate::compliance::{Compliance, Selection};
use crate::haptic::{HapticWorld, WorldSample};
use crate::mesh::units::{LengthUnit, Material};
use crate::mesh::{io, Mesh};
use crate::scene::file::SceneSource;
use crate::scene::World;

/// Bit for bit with `native`; to `1e-12` of the largest value without.
fn assert_same(got: &[f64], native: &[f64], what: &str) {
    assert_eq!(got.len(), native.len(), "{what}: length");
    let scale = native.iter().fold(0.0f64, |m, v| m.max(v.abs()));
    for (i, (g, n)) in got.iter().zip(native).enumerate() {
        if cfg!(feature = "native") {
            assert_eq!(g.to_bits(), n.to_bits(), "{what}[{i}]: {g:e} != {n:e}");
        } else {
            assert!(
                (g - n).abs() <= 1e-12 * scale,
                "{what}[{i}]: {g:e} vs {n:e}"
            );
        }
    }
}

/// A 3×3×3-cell block (30 mm, five tets a cell), written as TetGen text and parsed back: the
/// mesh comes from bytes, not a file. Bottom face clamped.
fn block_from_text() -> Mesh {
    let raw = crate::mesh::grid_raw([3, 3, 3], [30.0; 3], |_, _, _| true);
    let mut node = format!("{} 3 0 0\n", raw.nodes.len());
    for (i, p) in raw.nodes.iter().enumerate() {
        node += &format!("{i} {:?} {:?} {:?}\n", p[0], p[1], p[2]);
    }
    let mut ele = format!("{} 4 0\n", raw.tets.len());
    for (i, t) in raw.tets.iter().enumerate() {
        ele += &format!("{i} {} {} {} {}\n", t[0], t[1], t[2], t[3]);
    }
    let parsed = io::parse_tetgen(
        node.as_bytes(),
        "block.node".as_ref(),
        ele.as_bytes(),
        "block.ele".as_ref(),
    )
    .unwrap();
    assert_eq!((parsed.nodes, parsed.tets), (raw.nodes, raw.tets));
    let material = Material {
        young_pa: 10_000.0,
        poisson: 0.45,
    };
    let mut mesh = Mesh::from_raw(
        io::parse_tetgen(
            node.as_bytes(),
            "block.node".as_ref(),
            ele.as_bytes(),
            "block.ele".as_ref(),
        )
        .unwrap(),
        LengthUnit::Millimetre,
        material,
    )
    .unwrap();
    mesh.set_fixed_where(|p| p.z < 1e-9);
    mesh
}

/// A few entries of `L` (m/N) spread over the matrix, and its diagonal's sum.
fn probe(c: &Compliance) -> Vec<f64> {
    let l = c.l_f64();
    let mut out: Vec<f64> = (0..7).map(|k| l[k * (l.len() - 1) / 6]).collect();
    out.push(
        (0..c.cols().len())
            .map(|j| c.touch_block(j, j).x_axis.x)
            .sum(),
    );
    out
}

/// The compliance of a mesh parsed from text, with the solve fanned out over threads
/// (`native`) or run on the calling thread: the same numbers.
#[cfg_attr(test, test)]
pub(crate) fn compliance_from_text_matches_the_threaded_solve() {
    let mesh = block_from_text();
    let c = Compliance::compute(&mesh, &Selection::default()).unwrap();
    let got = probe(&c);
    assert_same(&got, &COMPLIANCE_PROBE, "L");
}

/// A dense cache written out and read back from bytes in memory gives `L` bit for bit; so
/// does a compressed (hierarchical) one, whose displacement is the dense one's to its
/// tolerance.
#[cfg_attr(test, test)]
pub(crate) fn caches_round_trip_through_bytes() {
    let mesh = block_from_text();
    let sel = Selection::default();
    let c = Compliance::compute(&mesh, &sel).unwrap();
    let key = cache::key(&mesh, &sel);
    // The file's bytes (`to_bytes` writes what `save` writes: tests/it/precompute.rs).
    let bytes = cache::to_bytes(&c, key, mesh.nodes.len()).unwrap();
    let back = cache::load_bytes(&bytes, key, mesh.nodes.len()).unwrap();
    assert_eq!(back.cols(), c.cols());
    assert!(back
        .l_f64()
        .iter()
        .zip(c.l_f64())
        .all(|(a, b)| a.to_bits() == b.to_bits()));
    assert_eq!(back.l_f64().len(), c.l_f64().len());

    let opts = HOptions::new(1e-6);
    let h = Compliance::compute_hier(&mesh, &sel, &opts, &mut |_, _| {}).unwrap();
    let hkey = cache::key_hier(&mesh, &sel, &opts);
    // A folder of its own under the system's temporary one, removed at the end (no tempfile
    // crate: the engine's checks build with the library).
    let dir = std::env::temp_dir().join(format!("touchfem-pure-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let hpath = dir.join("hier.tfc");
    cache::hier::save(&hpath, &h, hkey, mesh.nodes.len()).unwrap();
    let hb = std::fs::read(&hpath).unwrap();
    std::fs::remove_dir_all(&dir).unwrap();
    let hback = cache::load_bytes(&hb, hkey, mesh.nodes.len()).unwrap();
    assert!(hback.hier().is_some());
    let col = (c.cols().len() / 2) as u32;
    let load = [(col, DVec3::new(0.0, 0.0, -0.1))];
    let (mut ud, mut uh) = (
        vec![DVec3::ZERO; mesh.nodes.len()],
        vec![DVec3::ZERO; mesh.nodes.len()],
    );
    c.displace(&load, &mut ud);
    hback.displace(&load, &mut uh);
    let du = ud
        .iter()
        .zip(&uh)
        .map(|(a, b)| (*a - *b).length())
        .fold(0.0, f64::max);
    let umax = ud.iter().map(|u| u.length()).fold(0.0, f64::max);
    assert!(umax > 1e-4 && du <= 1e-5 * umax, "{du:e} of {umax:e}");
}

/// The paper's Fig. 1 scene (bundled text, bundled cube): a finger pressed 5 mm into the top
/// face over 300 haptic steps. The last step's force is the native engine's.
#[cfg_attr(test, test)]
pub(crate) fn a_haptic_press_gives_the_native_force() {
    let src = SceneSource::find("fig1").unwrap().unwrap();
    let world = World::from_source_with(&src, None).unwrap();
    let mut hw = HapticWorld::new(&world);
    let mut sample = WorldSample::default();
    let mut f = [DVec3::ZERO; 1];
    for k in 0..=300 {
        let z = 40.0 - 15.0 * (k as f64 / 300.0);
        hw.step(&[DVec3::new(15.0, 15.0, z) * 1e-3], &mut f, &mut sample);
    }
    let got = [f[0].x, f[0].y, f[0].z];
    assert!(f[0].z > 0.5, "pushes the finger up: {:?}", f[0]);
    assert_same(&got, &FORCE, "force");
}

/// [`crate::threads::fan_out`] returns the parts in order, the calling thread's first.
#[cfg_attr(test, test)]
pub(crate) fn fan_out_keeps_the_order() {
    let got: Vec<usize> = crate::threads::fan_out(4, || 10, |i| 10 + i)
        .into_iter()
        .map(|r| r.unwrap())
        .collect();
    assert_eq!(got, [10, 11, 12, 13]);
    assert_eq!(crate::threads::fan_out(1, || 5, |_| 0).len(), 1);
    let sw = crate::threads::Stopwatch::start();
    let s = sw.elapsed().as_secs_f64();
    assert!(if cfg!(feature = "native") {
        s >= 0.0
    } else {
        s == 0.0
    });
}

/// [`compliance_from_text_matches_the_threaded_solve`]'s probe, from the native engine.
const COMPLIANCE_PROBE: [f64; 8] = [
    0.01777462406705831,
    8.87360049899128e-6,
    -0.002081902616041391,
    0.007788755931583979,
    -0.005364690249625446,
    -0.006196927551463812,
    0.03952020984746421,
    1.071406457505832,
];

/// [`a_haptic_press_gives_the_native_force`]'s force (N), from the native engine.
const FORCE: [f64; 3] = [
    -5.845137142652431e-16,
    -7.355460908904301e-16,
    0.6756209949956736,
];
