//! Hard cases, each held to a bound (the numbers are printed; README "Hard cases" quotes them):
//! nearly incompressible material, slivers and needles that pass validation, extreme scales,
//! volumetric locking, and contact where it is hardest — next to the clamp, exactly on an edge
//! or a vertex, on a near-zero-area triangle, with no press, with a press many times the
//! object's size, and sweeping fast across edges.

use glam::DVec3;

use touchfem::runtime::{HapticWorld, WorldSample};
use touchfem::scene::{SceneSource, World};
use touchfem_lab::hard;

#[test]
fn every_hard_body_is_accurate_in_f64_and_f32() {
    let cases = hard::cases().unwrap();
    for c in &cases {
        eprintln!(
            "{:26} nodes {:4} quality {:.1e} residual {:.1e} f64 {:.1e} f32 {:.1e} f16 {:.1e} press {:.4e} N",
            c.case, c.nodes, c.worst_quality, c.residual, c.f64_error, c.f32_error, c.f16_error, c.press_force_n
        );
        assert!(c.residual < 1e-12, "{}: residual {:e}", c.case, c.residual);
        assert!(c.f64_error < 1e-10, "{}: f64 {:e}", c.case, c.f64_error);
        assert!(c.f32_error < 1e-5, "{}: f32 {:e}", c.case, c.f32_error);
        assert!(c.f16_error < 2e-3, "{}: f16 {:e}", c.case, c.f16_error);
        assert!(
            c.press_force_n.is_finite() && c.press_force_n > 0.0,
            "{}: {}",
            c.case,
            c.press_force_n
        );
    }
    let by = |name: &str| cases.iter().find(|c| c.case == name).unwrap();
    // The slivers and needles passed validation, barely well shaped.
    assert!(by("sliver layer (1 µm)").worst_quality < 1e-3);
    assert!(by("needle column (1 µm)").worst_quality < 1e-3);
    // Linear elasticity has no length or stiffness scale: the press (a sixth of the edge)
    // gives F = E·edge²·const, the same constant from 1 Pa and 1 m to 1 GPa and 1 mm, in
    // millimetres or metres.
    let k = |c: &hard::HardCase| c.press_force_n / (c.young_pa * c.size_m * c.size_m);
    let a = k(by("E=1 Pa, 1 m"));
    for name in ["E=1 GPa, 1 mm", "E=1 GPa, 1 mm, in metres"] {
        let b = k(by(name));
        assert!((a - b).abs() < 1e-9 * a, "{name}: {b} vs {a}");
    }
    // The sliver layer and the needle column move a plane of nodes: against the well-shaped
    // mesh with the same cell counts the press differs by the discretisation, stated here
    // and in the README.
    for (name, well) in [
        ("sliver layer (1 µm)", "well-shaped 4x4x5"),
        ("needle column (1 µm)", "well-shaped 6x4x4"),
    ] {
        let w = by(well).press_force_n;
        let d = (by(name).press_force_n - w).abs() / w;
        eprintln!(
            "{name}: the press differs from the {well} mesh by {:.1} %",
            100.0 * d
        );
        assert!(d < 0.5, "{name}: {d}");
    }
}

/// The GPU pass itself (lavapipe here), in both layouts and both precisions, on every hard
/// body: the extreme scales and the bad cells change nothing.
#[test]
fn on_the_gpu_every_hard_body_stays_within_f32_and_f16_bounds() {
    use touchfem::compliance::{Compliance, NodeSet, Selection};
    use touchfem::gpu::{Deformer, DeformerOptions, Gpu, LStorage};
    let g = Gpu::new_headless()
        .unwrap_or_else(|e| panic!("GPU tests need an adapter and must not be skipped: {e}"));
    for (name, mesh) in hard::bodies().unwrap() {
        let sel = Selection {
            rows: NodeSet::Surface,
            cols: NodeSet::FreeSurface,
        };
        let c = Compliance::compute(&mesh, &sel).unwrap();
        // One contact triangle's worth of columns, forces sized to move the body by ~1/20
        // of its size.
        let (lo, hi) = mesh.bounds();
        let size = (hi - lo).max_element();
        let k = 0.05 * size / c.block(c.col_row(0), 0).z_axis.z;
        let forces: Vec<(u32, DVec3)> = (0..3u32)
            .map(|i| {
                (
                    i * 5,
                    DVec3::new(0.2, -0.3, -1.0) * k * (1.0 + f64::from(i)),
                )
            })
            .collect();
        let mut u = vec![DVec3::ZERO; c.rows().len()];
        c.displace(&forces, &mut u);
        let max_u = u.iter().map(|v| v.length()).fold(0.0, f64::max);
        for storage in [
            LStorage::Texture,
            LStorage::TextureF16,
            LStorage::Buffers,
            LStorage::BuffersF16,
        ] {
            let opts = DeformerOptions {
                storage,
                ..Default::default()
            };
            let mut d =
                Deformer::new(&g.device, &g.queue, &c, &mesh.nodes, &mesh.surface, &opts).unwrap();
            let f32s: Vec<(u32, [f32; 3])> = forces
                .iter()
                .map(|&(col, f)| (col, f.as_vec3().to_array()))
                .collect();
            d.set_forces(&g.queue, &f32s).unwrap();
            let mut enc = g.device.create_command_encoder(&Default::default());
            d.encode(&mut enc);
            g.queue.submit([enc.finish()]);
            let (got, _) = d.read_back(&g.device, &g.queue).unwrap();
            let err = c
                .rows()
                .iter()
                .enumerate()
                .map(|(r, &node)| {
                    let rest = mesh.nodes[node as usize].as_vec3().as_dvec3();
                    let p = DVec3::new(got[r][0].into(), got[r][1].into(), got[r][2].into());
                    (p - rest - u[r]).length()
                })
                .fold(0.0, f64::max)
                / max_u;
            eprintln!("{name:26} {storage:?}: {err:.2e}");
            assert!(err.is_finite());
            let bound = match storage {
                LStorage::TextureF16 | LStorage::BuffersF16 => 2e-3,
                _ => 1e-5,
            };
            assert!(err < bound, "{name}, {storage:?}: {err:e}");
        }
    }
}

#[test]
fn linear_tets_lock_as_poisson_nears_one_half() {
    let rows = hard::locking().unwrap();
    for r in &rows {
        let [a, b, c] = r.settlement_m;
        eprintln!(
            "nu {}: settlement 4^3 {:.3} um, 8^3 {:.3} um, 16^3 {:.3} um (4^3/16^3 {:.3}); press 4^3 {:.4} N, 8^3 {:.4} N",
            r.poisson, a * 1e6, b * 1e6, c * 1e6, a / c, r.press_force_n[0], r.press_force_n[1]
        );
        assert!(r.settlement_m.iter().all(|u| u.is_finite() && *u > 0.0));
        // Refinement softens the discrete body: it converges from the stiff side.
        assert!(a < b && b < c, "{r:?}");
    }
    // Locking: the coarse mesh's settlement falls further short of the fine one's as ν → 0.5.
    let short = |i: usize| rows[i].settlement_m[0] / rows[i].settlement_m[2];
    assert!(
        (1..rows.len()).all(|i| short(i) < short(i - 1)),
        "{:?}",
        (0..rows.len()).map(short).collect::<Vec<_>>()
    );
    assert!(short(4) < 0.8 * short(0), "{} vs {}", short(4), short(0));
    // The locking-free rows: the same at ν = 0.3 (to 2 %), converging from the stiff side at
    // every ν, and far less short at ν = 0.4999 than the standard element.
    for r in &rows {
        let [a, b, c] = r.locking_free_settlement_m;
        assert!(a < b && b < c, "{r:?}");
    }
    let lf_short =
        |i: usize| rows[i].locking_free_settlement_m[0] / rows[i].locking_free_settlement_m[2];
    assert!((lf_short(0) / short(0) - 1.0).abs() < 0.02);
    assert!(
        lf_short(4) > short(4) + 0.15,
        "{} vs {}",
        lf_short(4),
        short(4)
    );
    assert!(rows[4].locking_free_press_force_n[0] < 0.8 * rows[4].press_force_n[0]);
}

fn cube(extra: &str) -> World {
    World::from_source_with(
        &SceneSource {
            name: "hard".into(),
            text: format!("unit = \"mm\"\n[[object]]\nmesh = \"cube\"\n{extra}[[finger]]\ndevice = \"pointer\"\n[haptics]\nmax_force_n = 8.5\n"),
            dir: ".".into(),
            label: "hard".into(),
        },
        None,
    )
    .unwrap()
}

/// Drives one finger along `path` (scene metres) and returns each tick's force.
fn drive(world: &World, path: impl Iterator<Item = DVec3>) -> Vec<DVec3> {
    let mut hw = HapticWorld::new(world);
    let mut s = WorldSample::default();
    path.map(|x| {
        let mut f = [DVec3::ZERO];
        hw.step(&[x], &mut f, &mut s);
        f[0]
    })
    .collect()
}

fn mm(x: f64, y: f64, z: f64) -> DVec3 {
    DVec3::new(x, y, z) * 1e-3
}

/// Largest change between consecutive forces, relative to the largest force.
fn worst_jump(f: &[DVec3]) -> f64 {
    let max = f.iter().map(|v| v.length()).fold(0.0, f64::max);
    f.windows(2)
        .map(|w| (w[1] - w[0]).length())
        .fold(0.0, f64::max)
        / max
}

#[test]
fn sliding_onto_the_clamp_stays_finite_bounded_and_continuous() {
    let w = cube("");
    // In through the side face x = 0 by 2 mm at z = 8 mm, then down the face to 0.2 mm above
    // the clamped bottom edge in 0.02 mm steps: triangles with clamped vertices at the end.
    let inn = (0..100).map(|i| mm(-3.0 + 5.0 * f64::from(i) / 99.0, 15.0, 8.0));
    let down = (0..=390).map(|i| mm(2.0, 15.0, 8.0 - 0.02 * f64::from(i)));
    let f = drive(&w, inn.chain(down));
    let last = f.last().unwrap().length();
    let jump = worst_jump(&f[100..]);
    eprintln!(
        "near the clamp: |F| from {:.3} to {last:.3} N, worst step {:.2} %",
        f[100].length(),
        100.0 * jump
    );
    assert!(f.iter().all(|v| v.is_finite() && v.length() <= 8.5 + 1e-12));
    assert!(last > 0.0);
    assert!(
        jump < 0.05,
        "the force jumps by {:.1} % in one 0.02 mm step",
        100.0 * jump
    );
}

#[test]
fn exactly_on_an_edge_and_a_vertex_no_nan_and_continuous() {
    let w = cube("");
    // The cube's top face is cut at x, y = 0, 7.5, 15, 22.5, 30 mm: (7.5, y) is exactly on an
    // edge, (7.5, 7.5) exactly a vertex. Press straight down there, then slide across.
    for (what, x, y) in [("edge", 7.5, 11.0), ("vertex", 7.5, 7.5)] {
        let down = (0..=50).map(|i| mm(x, y, 31.0 - 0.1 * f64::from(i)));
        let across = (0..=200).map(|i| mm(x - 2.0 + 0.02 * f64::from(i), y, 26.0));
        let f = drive(&w, down.chain(across));
        assert!(f.iter().all(|v| v.is_finite()), "{what}");
        let jump = worst_jump(&f[51..]);
        eprintln!(
            "{what}: |F| {:.4} N, worst step {:.2} %",
            f[50].length(),
            100.0 * jump
        );
        assert!(f[50].length() > 0.01, "{what}");
        assert!(jump < 0.05, "{what}: {jump}");
    }
}

#[test]
fn sliding_across_near_zero_area_triangles_is_continuous() {
    let mesh = hard::sliver_cube().unwrap();
    let sel = touchfem::compliance::Selection::default();
    let w = World {
        name: "sliver".into(),
        unit: touchfem::LengthUnit::Millimetre,
        objects: vec![touchfem::scene::Object {
            name: "sliver".into(),
            body: touchfem::scene::Body::new(mesh, &sel).unwrap(),
            offset: DVec3::ZERO,
            friction: None,
            cuttable: None,
        }],
        fingers: vec![touchfem::scene::FingerSpec {
            device: touchfem::scene::DeviceSpec::Pointer,
            model: touchfem::contact::force::ForceModel::Paper,
            limits: None,
            tool: Default::default(),
        }],
        haptics: Default::default(),
        source: String::new(),
        dir: ".".into(),
        hash: 0,
    };
    // In through the side face x = 0 by 1.5 mm at z = 14 mm, then down across the 1 µm layer
    // (z = 12.001 … 12 mm: triangles of 7.5 mm × 1 µm) to z = 10 mm in 0.01 mm steps.
    let inn = (0..=30).map(|i| mm(-1.5 + 0.1 * f64::from(i), 11.0, 14.0));
    let down = (0..=400).map(|i| mm(1.5, 11.0, 14.0 - 0.01 * f64::from(i)));
    let f = drive(&w, inn.chain(down));
    assert!(f.iter().all(|v| v.is_finite()));
    let jump = worst_jump(&f[31..]);
    eprintln!(
        "across the 1 µm layer: |F| {:.4} … {:.4} N, worst 0.01 mm step {:.2} %",
        f[31].length(),
        f.last().unwrap().length(),
        100.0 * jump
    );
    assert!(f[31..].iter().all(|v| v.length() > 0.01));
    assert!(jump < 0.05, "{jump}");
}

#[test]
fn no_press_gives_exactly_zero_and_a_huge_one_is_clamped() {
    let w = cube("");
    // Touching without pressing: a finger resting exactly on the top face.
    let f = drive(&w, (0..10).map(|_| mm(15.0, 15.0, 30.0)));
    assert!(f.iter().all(|v| *v == DVec3::ZERO), "{f:?}");
    let f = drive(
        &w,
        (0..=100).map(|i| mm(15.0, 15.0, 31.0 - 0.01 * f64::from(i))),
    );
    assert!(f.iter().all(|v| v.is_finite()));
    // Several times the object's size: 150 mm below the 30 mm cube's top, in one tick, then
    // held. The force bound rises at most 8.5 N / RISE_S (0.425 N a millisecond), then clamps.
    let f = drive(
        &w,
        [mm(15.0, 15.0, 31.0), mm(15.0, 15.0, 29.0)]
            .into_iter()
            .chain(std::iter::repeat_n(mm(15.0, 15.0, -120.0), 40)),
    );
    let rise = 8.5 * 1e-3 / touchfem::runtime::bound::RISE_S;
    for w in f.windows(2) {
        assert!((w[1] - w[0]).length() <= rise + 1e-9, "{w:?}");
    }
    let last = f.last().unwrap().length();
    eprintln!(
        "a 150 mm press: |F| {} N after one tick, {last} N held (clamped at 8.5)",
        f[2].length()
    );
    assert!(last.is_finite() && (last - 8.5).abs() < 1e-9, "{last}");
}

#[test]
fn a_fast_sweep_across_edges_never_pops_through_or_spikes() {
    let w = cube("");
    // Down into the top face at x = 2 mm, then 2 mm deep across the whole top face and over
    // the far edge, 0.5 mm a tick (0.5 m/s).
    let enter = (0..=30).map(|i| mm(2.0, 15.0, 28.0 + 3.0 * f64::from(30 - i) / 30.0));
    let sweep = (0..=68).map(|i| mm(2.0 + 0.5 * f64::from(i), 15.0, 28.0));
    let f = drive(&w, enter.chain(sweep));
    assert!(f.iter().all(|v| v.is_finite() && v.length() <= 8.5 + 1e-12));
    // Past the far edge the finger is outside: zero force, it did not stay inside.
    assert_eq!(*f.last().unwrap(), DVec3::ZERO);
    // Over the top face (x < 30 mm) the force points out of it (up), never through it, and
    // changes smoothly from step to step (it varies over the face with the contact point's
    // compliance, from the middle of a triangle to a node): no spike.
    let over: Vec<DVec3> = f[31..31 + 56].to_vec();
    let (lo, hi) = over.iter().fold((f64::INFINITY, 0.0f64), |(a, b), v| {
        (a.min(v.length()), b.max(v.length()))
    });
    let jump = worst_jump(&over);
    eprintln!(
        "sweep over the top: |F| {lo:.3} … {hi:.3} N, worst 0.5 mm step {:.1} %",
        100.0 * jump
    );
    for v in &over {
        assert!(v.z > 0.0, "{v}");
    }
    assert!(jump < 0.15, "a spike: {:.1} % in one step", 100.0 * jump);
}
