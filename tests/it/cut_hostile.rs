//! Hostile cuts through the live path (blade finger → strokes → cutter → cut body installed in
//! the haptic world): fuzzed blade paths, a cut along the clamp, a blade that starts inside,
//! a single-tet-thick sliver cut through, and blades of depth 0 or NaN. None may panic, make
//! anything non-finite, or send a force past the bound.

use glam::DVec3;
use touchfem::cut::{blade_tets, Cut};
use touchfem::runtime::cutting::{CutMode, Cutter, Stroke};
use touchfem::runtime::{HapticWorld, WorldSample};
use touchfem::scene::World;

use crate::common::{rand01, world_from_text};

/// A scene of `mesh` (bundled, mm), cuttable everywhere, with a blade of `depth_mm` as finger
/// 0 and a 4 mm fingertip as finger 1 (both driven by the test, not by their scripts).
fn scene(mesh: &str, depth_mm: &str) -> Result<World, touchfem::Error> {
    world_from_text(&format!(
        r#"
unit = "mm"
[[object]]
name = "body"
mesh = "{mesh}"
cuttable = "all"
[[finger]]
device = "script"
tool = {{ blade = {depth_mm} }}
path = [[0.0, 0.0, 0.0, 100.0]]
[[finger]]
device = "script"
tool = {{ sphere = 4.0 }}
path = [[0.0, 0.0, 0.0, 100.0]]
[haptics]
max_force_n = 8.5
"#
    ))
}

/// Counts of what a run did (and the cutter's deferred folds between its passes).
#[derive(Debug, Default)]
struct Tally {
    passes: crate::common::CutPasses,
    ticks: usize,
    strokes: usize,
    bodies: usize,
    tets_removed: usize,
    /// The most copies a body of a separating cutter had made.
    copies: usize,
    pieces: usize,
    folds: u32,
    max_force: f64,
}

/// Drives `world`'s blade and fingertip through `positions` (blade, fingertip per tick),
/// passing the strokes to a cutter every `every` ticks and installing its bodies; asserts
/// every force finite and within the bound.
fn drive(
    world: &World,
    cutter: &mut Cutter,
    hw: &mut HapticWorld<'_>,
    positions: &[[DVec3; 2]],
    every: usize,
    tally: &mut Tally,
) {
    let bound = world.haptics.max_force_n;
    let mut sample = WorldSample::default();
    let mut f = [DVec3::ZERO; 2];
    let mut strokes = Vec::new();
    for (k, x) in positions.iter().enumerate() {
        hw.step(x, &mut f, &mut sample);
        tally.ticks += 1;
        for v in &f {
            assert!(
                v.is_finite() && v.length() <= bound + 1e-12,
                "force {v} at {x:?}"
            );
            tally.max_force = tally.max_force.max(v.length());
        }
        strokes.extend_from_slice(hw.strokes());
        if (k + 1) % every == 0 || k + 1 == positions.len() {
            tally.strokes += strokes.len();
            for (o, body) in tally.passes.pass(cutter, &strokes) {
                tally.bodies += 1;
                tally.tets_removed = tally.tets_removed.max(body.tets_removed);
                tally.copies = tally.copies.max(body.nodes_split);
                tally.pieces += body.report.pieces_removed;
                tally.folds = tally.folds.max(body.folds);
                assert!(body.surface.normals.iter().all(|n| n.is_finite()));
                hw.install_cut(o, body);
            }
            strokes.clear();
        }
    }
}

/// `n` random blade paths over `world`'s object, each a few ticks from a random point near
/// or inside the body to another (some start inside, some pass through NaN), with the
/// fingertip pressing somewhere at random; a fresh cutter every 50 paths, cutting as `mode`
/// says.
fn fuzz(world: &World, n: usize, seed: u64, mode: CutMode) -> Tally {
    let (lo, hi) = world.objects[0].body.mesh.bounds();
    let span = hi - lo;
    let mut s = seed;
    let r = |s: &mut u64| rand01(s);
    let mut tally = Tally::default();
    let mut cutter = Cutter::new(world).unwrap();
    cutter.set_fold_rank(200);
    cutter.set_cut_mode(mode);
    let mut hw = HapticWorld::new(world);
    for path in 0..n {
        if path % 50 == 49 {
            cutter = Cutter::new(world).unwrap();
            cutter.set_fold_rank(200);
            cutter.set_cut_mode(mode);
            hw = HapticWorld::new(world);
            // (Folds of the old cutter are not the new one's.)
            tally.passes = Default::default();
        }
        let pick = |s: &mut u64| {
            lo - 0.1 * span
                + DVec3::new(
                    r(s) * 1.2 * span.x,
                    r(s) * 1.2 * span.y,
                    r(s) * 1.2 * span.z,
                )
        };
        let (a, b) = (pick(&mut s), pick(&mut s));
        let press = pick(&mut s);
        let ticks = 3 + (r(&mut s) * 12.0) as usize;
        let nan_at = if r(&mut s) < 0.05 {
            (r(&mut s) * ticks as f64) as usize
        } else {
            usize::MAX
        };
        let mut xs: Vec<[DVec3; 2]> = (0..ticks)
            .map(|k| {
                let t = k as f64 / (ticks - 1) as f64;
                let blade = if k == nan_at {
                    DVec3::NAN
                } else {
                    a.lerp(b, t)
                };
                [blade, press]
            })
            .collect();
        // Lift both away at the end of the path.
        xs.push([hi + span, hi + span]);
        drive(world, &mut cutter, &mut hw, &xs, 6, &mut tally);
    }
    tally
}

#[test]
fn a_thousand_fuzzed_blade_paths_on_the_cube_and_the_mouse_stay_finite_and_bounded() {
    for (mesh, n, seed) in [("cube", 850, 7u64), ("mouse", 150, 11)] {
        let world = scene(mesh, "3.0").unwrap();
        let t = fuzz(&world, n, seed, CutMode::Remove);
        eprintln!("{mesh}: {n} paths, {t:?}");
        // The fuzz did cut: strokes became bodies, and the bodies removed tets.
        assert!(t.strokes > n / 10, "{t:?}");
        assert!(t.bodies > n / 20 && t.tets_removed > 0, "{t:?}");
        if mesh == "cube" {
            // Random cuts through a small cube cut pieces off: each reported and removed.
            assert!(t.pieces > 0, "{t:?}");
        }
    }
}

#[test]
fn fuzzed_separating_blades_on_the_cube_stay_finite_and_bounded() {
    // The engine's separating cutter (`CutMode::Separate`) under the same fuzz: every pass a
    // body or nothing, never an error or a panic, every force finite and within the bound,
    // its folds deferred and adopted.
    let world = scene("cube", "10.0").unwrap();
    let n = 1000;
    let t = fuzz(&world, n, 23, CutMode::Separate);
    eprintln!("cube, separating: {n} paths, {t:?}");
    assert!(t.strokes > n / 10 && t.bodies > n / 20, "{t:?}");
    assert!(t.copies > 0 && t.folds > 0, "{t:?}");
}

#[test]
fn a_cut_along_the_clamp_and_one_that_cuts_a_piece_off_leave_the_rest_touchable() {
    let world = scene("cube", "6.0").unwrap();
    let mm = |x: f64, y: f64, z: f64| DVec3::new(x, y, z) * 1e-3;
    let far = mm(15.0, 15.0, 100.0);
    for mode in [CutMode::Remove, CutMode::Separate] {
        let mut cutter = Cutter::new(&world).unwrap();
        cutter.set_cut_mode(mode);
        let mut hw = HapticWorld::new(&world);
        let mut t = Tally::default();
        // Along the clamp: the blade enters the side face y = 0 at z = 1 mm (the clamp is
        // z = 0) and is drawn along x, 6 mm deep into the cube.
        let mut xs: Vec<[DVec3; 2]> = vec![[mm(1.0, -2.0, 1.0), far]];
        xs.extend((0..=56).map(|k| [mm(1.0 + 0.5 * k as f64, 0.5, 1.0), far]));
        xs.push([mm(29.0, -20.0, 1.0), far]);
        drive(&world, &mut cutter, &mut hw, &xs, 5, &mut t);
        let along_clamp = (t.tets_removed, t.copies);
        match mode {
            CutMode::Remove => assert!(along_clamp.0 > 0, "{t:?}"),
            // A cut 1 mm above the clamp, in a mesh of 7.5 mm cells, separates nothing: the
            // clamped nodes may not leave the clamp's plane, the others are more than half an
            // edge away. It changes nothing, and errs nowhere.
            CutMode::Separate => assert_eq!(along_clamp, (0, 0), "{t:?}"),
        }
        // Then two blade paths 0.2 mm under the top along x = 6 and y = 6, each drawn across
        // the whole top, with the same blade.
        for path in [
            (0..=40)
                .map(|k| [mm(6.0, 0.75 * k as f64, 29.8), far])
                .collect::<Vec<_>>(),
            (0..=40)
                .map(|k| [mm(0.75 * k as f64, 6.0, 29.8), far])
                .collect(),
        ] {
            let mut xs = path;
            xs.push([mm(15.0, 15.0, 100.0), far]);
            drive(&world, &mut cutter, &mut hw, &xs, 5, &mut t);
        }
        eprintln!("{mode:?}: clamp {along_clamp:?}; then {t:?}");
        // Pressing the cube's top centre after all of that: a finite, non-zero force.
        let press: Vec<[DVec3; 2]> = (0..=300)
            .map(|k| {
                [
                    mm(15.0, -20.0, 100.0),
                    mm(20.0, 20.0, 34.0 - 7.0 * (k as f64 / 300.0)),
                ]
            })
            .collect();
        let mut sample = WorldSample::default();
        let mut f = [DVec3::ZERO; 2];
        for x in &press {
            hw.step(x, &mut f, &mut sample);
            assert!(f.iter().all(|v| v.is_finite() && v.length() <= 8.5 + 1e-12));
        }
        assert!(f[1].length() > 0.01, "{}", f[1]);
    }
}

#[test]
fn a_blade_that_starts_inside_engages_where_it_is_and_cuts() {
    let world = scene("cube", "4.0").unwrap();
    let mm = |x: f64, y: f64, z: f64| DVec3::new(x, y, z) * 1e-3;
    let far = mm(15.0, 15.0, 100.0);
    // The blade appears 2 mm under the top face and is drawn across it, a pass every 5 ticks
    // (0.5 mm a tick). (Not along y = 15 mm: that is a plane of the cube's faces, which no tet
    // crosses, so a blade drawn exactly in it removes nothing.)
    let xs: Vec<[DVec3; 2]> = (0..=40)
        .map(|k| [mm(5.0 + 0.5 * k as f64, 14.0, 28.0), far])
        .collect();
    for mode in [CutMode::Remove, CutMode::Separate] {
        let mut cutter = Cutter::new(&world).unwrap();
        cutter.set_cut_mode(mode);
        let mut hw = HapticWorld::new(&world);
        let mut t = Tally::default();
        drive(&world, &mut cutter, &mut hw, &xs, 5, &mut t);
        eprintln!("started inside, {mode:?}: {t:?}");
        assert!(t.strokes >= 30, "{t:?}");
        match mode {
            CutMode::Remove => assert!(t.tets_removed > 0, "{t:?}"),
            // Its 2.5 mm chords, each shorter than the cube's 7.5 mm cells, part the top face
            // between them: the node mid-way along the slit's top edge gets its copy.
            CutMode::Separate => assert!(t.copies >= 1 && t.tets_removed == 0, "{t:?}"),
        }
    }
}

#[test]
fn a_single_tet_thick_sliver_cut_through_loses_its_top_and_stays_exact() {
    // A wall 30 × 3 × 30 mm, one cell (five tets) thick, clamped at its foot: a blade drawn
    // right across it at mid height cuts the top half off (a piece no clamp holds); a slit
    // half way across leaves it standing.
    use touchfem::compliance::{Compliance, Selection};
    let wall = touchfem::mesh::cube_with(
        [4, 1, 4],
        [30.0, 3.0, 30.0],
        touchfem::mesh::units::Material {
            young_pa: 10_000.0,
            poisson: 0.45,
        },
    )
    .unwrap();
    let base = Compliance::compute(&wall, &Selection::default()).unwrap();
    let mm = |x: f64, y: f64, z: f64| DVec3::new(x, y, z) * 1e-3;
    // The slit: into the face y = 0, 6 mm deep (through the 3 mm wall), from x = 0 to 15.
    let mut cut = Cut::new(&wall).unwrap();
    let slit = blade_tets(
        &wall,
        mm(0.0, 0.0, 16.0),
        mm(15.0, 0.0, 16.0),
        DVec3::Y,
        6e-3,
    );
    let rep = cut.remove(&wall, &slit).unwrap();
    assert!(rep.tets_removed > 0 && rep.pieces_removed == 0, "{rep:?}");
    let carried = base
        .with_correction(std::sync::Arc::new(cut.correction(&base).unwrap()))
        .unwrap();
    let top = wall
        .surface_nodes
        .iter()
        .copied()
        .find(|&v| {
            let p = wall.nodes[v as usize];
            (p.z - 0.03).abs() < 1e-9 && p.x > 0.02
        })
        .unwrap();
    let f = [(top, DVec3::new(0.0, 0.01, -0.02))];
    let fc = [(carried.col_of(top).unwrap() as u32, f[0].1)];
    let mut u = vec![DVec3::ZERO; carried.rows().len()];
    carried.displace(&fc, &mut u);
    let direct = cut.displace(&f);
    let scale = direct.iter().map(|v| v.length()).fold(0.0, f64::max);
    let worst = carried
        .rows()
        .iter()
        .enumerate()
        .map(|(r, &v)| (u[r] - direct[v as usize]).length())
        .fold(0.0, f64::max);
    eprintln!(
        "slit: {rep:?}, carried against the cut's own solve {:.1e}",
        worst / scale
    );
    assert!(scale > 0.0 && worst < 1e-9 * scale);
    // Right across at mid height: the top half is cut off and goes; what is left is the
    // clamped foot, finite and still.
    let across = blade_tets(
        &wall,
        mm(-1.0, 0.0, 16.0),
        mm(31.0, 0.0, 16.0),
        DVec3::Y,
        6e-3,
    );
    let rep = cut.remove(&wall, &across).unwrap();
    eprintln!("across: {rep:?}");
    assert_eq!(rep.pieces_removed, 1, "{rep:?}");
    assert!(cut.pinned()[top as usize]);
    let u = cut.displace(&f);
    assert!(u.iter().all(|v| v.is_finite()));
    assert_eq!(u[top as usize], DVec3::ZERO);
    let left = carried_or_none(&base, &cut);
    assert!(left.is_some(), "the foot is still there to touch");
}

/// The cut's compliance, or `None` when nothing touchable is left.
fn carried_or_none(
    base: &touchfem::compliance::Compliance,
    cut: &Cut,
) -> Option<touchfem::compliance::Compliance> {
    let k = cut.correction(base).ok()?;
    let c = base.with_correction(std::sync::Arc::new(k)).ok()?;
    c.cols().iter().any(|&v| c.col_of(v).is_some()).then_some(c)
}

#[test]
fn a_blade_of_depth_zero_or_nan_is_refused_and_a_bad_stroke_cuts_nothing() {
    for d in ["0.0", "-1.0", "nan", "inf"] {
        let e = scene("cube", d).err().expect("refused").to_string();
        assert!(e.contains("blade depth"), "{d}: {e}");
    }
    let world = scene("cube", "3.0").unwrap();
    let mut cutter = Cutter::new(&world).unwrap();
    let good = Stroke {
        object: 0,
        from: DVec3::new(0.0, 0.014, 0.0299),
        to: DVec3::new(0.03, 0.014, 0.0299),
        inward: DVec3::NEG_Z,
        depth: 0.003,
    };
    for bad in [
        Stroke { depth: 0.0, ..good },
        Stroke {
            depth: f64::NAN,
            ..good
        },
        Stroke {
            depth: f64::INFINITY,
            ..good
        },
        Stroke {
            from: DVec3::NAN,
            ..good
        },
        Stroke {
            inward: DVec3::ZERO,
            ..good
        },
        Stroke {
            inward: DVec3::NAN,
            ..good
        },
        Stroke {
            to: good.from,
            ..good
        },
        Stroke { object: 7, ..good },
    ] {
        assert!(cutter.apply(&bad).unwrap().is_none(), "{bad:?}");
    }
    assert_eq!(cutter.removed(0).unwrap().iter().filter(|&&r| r).count(), 0);
    // The default blade separates: copies of the nodes on its quad.
    let body = cutter.apply(&good).unwrap().expect("the good stroke cuts");
    assert!(body.nodes_split > 0, "{}", body.nodes_split);
}
