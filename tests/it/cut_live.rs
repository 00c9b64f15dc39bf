//! A cut carried live: the correction beside `L` ([`touchfem::compliance::correction`]) read by the
//! compliance's accessors, against a full precompute of the cut mesh.

use std::sync::Arc;

use glam::{DMat3, DVec3};
use touchfem::compliance::{Compliance, Selection};
use touchfem::cut::{tets_near_keeping_nodes, Cut};
use touchfem::Mesh;

fn max_abs(m: DMat3) -> f64 {
    m.to_cols_array().iter().fold(0.0f64, |a, v| a.max(v.abs()))
}

/// Cuts `n` tets near `at`, carries the correction beside `L`, and compares blocks, `L_ii⁻¹`
/// and displacements with a full precompute of the remaining tets. Returns the worst relative
/// differences (blocks, displacements) and the rank.
fn carried_against_recompute(mesh: &Mesh, at: DVec3, n: usize) -> (f64, f64, usize) {
    let base = Compliance::compute(mesh, &Selection::default()).unwrap();
    let mut cut = Cut::new(mesh).unwrap();
    let rep = cut
        .remove(mesh, &tets_near_keeping_nodes(mesh, at, n))
        .unwrap();
    assert_eq!(rep.nodes_pinned, 0, "{rep:?}");
    let carried = base
        .with_correction(Arc::new(cut.correction(&base).unwrap()))
        .unwrap();
    let (b, u) = against_recompute(&carried, mesh, cut.removed());
    (b, u, rep.rank)
}

/// The worst relative differences (blocks and `L_ii⁻¹`, displacements) between `carried`
/// (a compliance of `mesh` with a cut's correction, or folded) and a full precompute of the
/// tets not `removed`.
fn against_recompute(carried: &Compliance, mesh: &Mesh, removed: &[bool]) -> (f64, f64) {
    let base = carried;
    let cut_mesh = mesh.without_tets(removed);
    let full = Compliance::compute(&cut_mesh, &Selection::default()).unwrap();
    // Columns both have (a cut's exposed nodes are columns of the recompute only).
    let common: Vec<u32> = base
        .cols()
        .iter()
        .copied()
        .filter(|&v| full.col_of(v).is_some())
        .collect();
    assert!(common.len() > 50);
    let scale = common
        .iter()
        .map(|&v| max_abs(full.touch_block(full.col_of(v).unwrap(), full.col_of(v).unwrap())))
        .fold(0.0f64, f64::max);
    let mut worst_block = 0.0f64;
    for (k, &vi) in common.iter().enumerate().step_by(7) {
        for &vj in common.iter().skip(k % 5).step_by(11) {
            let (ci, cj) = (carried.col_of(vi).unwrap(), carried.col_of(vj).unwrap());
            let (fi, fj) = (full.col_of(vi).unwrap(), full.col_of(vj).unwrap());
            let d = carried.touch_block(ci, cj) - full.touch_block(fi, fj);
            worst_block = worst_block.max(max_abs(d) / scale);
        }
        let ci = carried.col_of(vi).unwrap();
        let fi = full.col_of(vi).unwrap();
        let d = carried.diag_inv(ci) - full.diag_inv(fi);
        worst_block = worst_block.max(max_abs(d) / max_abs(full.diag_inv(fi)));
    }
    // Displacements under two forces, at every row both display.
    let f = [
        (common[common.len() / 3], DVec3::new(0.0, 0.0, -0.2)),
        (common[2 * common.len() / 3], DVec3::new(0.05, -0.03, 0.02)),
    ];
    let fc: Vec<(u32, DVec3)> = f
        .iter()
        .map(|&(v, x)| (carried.col_of(v).unwrap() as u32, x))
        .collect();
    let ff: Vec<(u32, DVec3)> = f
        .iter()
        .map(|&(v, x)| (full.col_of(v).unwrap() as u32, x))
        .collect();
    let mut uc = vec![DVec3::ZERO; carried.rows().len()];
    let mut uf = vec![DVec3::ZERO; full.rows().len()];
    carried.displace(&fc, &mut uc);
    full.displace(&ff, &mut uf);
    let (mut num, mut den) = (0.0f64, 0.0f64);
    for (r, &v) in carried.rows().iter().enumerate() {
        if let Some(rf) = full.row_of(v) {
            num = num.max((uc[r] - uf[rf]).length());
            den = den.max(uf[rf].length());
        }
    }
    (worst_block, num / den)
}

#[test]
fn cutting_folding_and_cutting_again_reads_a_full_recompute() {
    // Cut, fold the correction into a new L, start the cut afresh from it (a new factor of
    // the remaining tets), cut again, fold again, cut a third time: at every step what both
    // paths read equals a full precompute of the remaining tets, and after each fold the
    // carried rank starts from what was cut since.
    for (mesh, at, n) in [
        (touchfem::mesh::cube(), DVec3::new(0.015, 0.015, 0.026), 30),
        (touchfem::mesh::mouse(), DVec3::new(-0.01, 0.0, 0.04), 30),
    ] {
        let order = tets_near_keeping_nodes(&mesh, at, n);
        let mut base = Compliance::compute(&mesh, &Selection::default()).unwrap();
        let mut cut = Cut::new(&mesh).unwrap();
        for (step, tets) in order.chunks(n / 3).enumerate() {
            let rep = cut.remove(&mesh, tets).unwrap();
            let carried = base
                .with_correction(Arc::new(cut.correction(&base).unwrap()))
                .unwrap();
            let (b, u) = against_recompute(&carried, &mesh, cut.removed());
            let folded = cut.fold(&base).unwrap();
            let (fb, fu) = against_recompute(&folded, &mesh, cut.removed());
            eprintln!(
                "step {step}: rank {} carried: blocks {b:.1e}, displacements {u:.1e}; folded: {fb:.1e}, {fu:.1e}",
                rep.rank
            );
            assert!(
                b < 1e-9 && u < 1e-9 && fb < 1e-9 && fu < 1e-9,
                "step {step}"
            );
            assert!(!folded.shares_l(&base));
            assert_eq!(folded.cols(), base.cols());
            assert_eq!(folded.correction().map(|k| k.rank), Some(0));
            // The rank carried after a fold counts only the DOFs cut since.
            let fresh: std::collections::BTreeSet<u32> =
                tets.iter().flat_map(|&t| mesh.tets[t]).collect();
            if step > 0 {
                assert!(
                    rep.rank <= 3 * fresh.len(),
                    "{} > 3·{}",
                    rep.rank,
                    fresh.len()
                );
            }
            cut = cut.rebase(&mesh).unwrap();
            assert_eq!(cut.rank(), 0);
            base = folded;
        }
    }
}

#[test]
fn a_cutter_that_folds_feels_what_one_that_carries_feels() {
    // The incision (blades that remove) with the cutter folding whenever the rank reaches 60 (several folds) and
    // with no fold: the press after the cut and every block read the same to round-off.
    // Deferred (the default: each fold adopted a pass after its snapshot, that pass's cuts
    // made again on the folded L) and inline.
    // (Blades that remove; `cut_grown.rs` has a separating cutter's folds.)
    use touchfem::runtime::cutting::{CutMode, FoldMode};
    let removing =
        |fold_rank, mode| crate::common::run_incision_in(fold_rank, mode, CutMode::Remove);
    let run = crate::common::removing_incision();
    let (carried_f, carried) = (run.after, run.body.clone());
    let run = removing(60, FoldMode::Deferred);
    let (folded_f, folded) = (run.after, run.body);
    let inline = removing(60, FoldMode::Inline);
    let e_inline = (carried_f - inline.after).length() / carried_f.length();
    eprintln!(
        "inline: {} folds, press {} ({e_inline:.1e})",
        inline.body.folds, inline.after
    );
    assert!(inline.body.folds >= 2, "{}", inline.body.folds);
    assert!(e_inline < 1e-9, "{e_inline}");
    assert_eq!(inline.body.tets_removed, folded.tets_removed);
    let e = (carried_f - folded_f).length() / carried_f.length();
    assert!(carried_f.length() > 0.01, "{carried_f}");
    eprintln!(
        "incision: {} folds, rank carried {} against {}; press {folded_f} against {carried_f} ({e:.1e})",
        folded.folds,
        folded.compliance.correction().map_or(0, |k| k.rank),
        carried.compliance.correction().map_or(0, |k| k.rank),
    );
    assert!(folded.folds >= 2, "{}", folded.folds);
    assert_eq!(carried.folds, 0);
    assert!(e < 1e-9, "{e}");
    let (a, b) = (&carried.compliance, &folded.compliance);
    assert_eq!(a.cols(), b.cols());
    let mut worst = 0.0f64;
    let scale = (0..a.cols().len())
        .filter(|&c| a.col_of(a.cols()[c]).is_some())
        .map(|c| max_abs(a.touch_block(c, c)))
        .fold(0.0f64, f64::max);
    for i in (0..a.cols().len()).step_by(13) {
        assert_eq!(a.col_of(a.cols()[i]), b.col_of(b.cols()[i]));
        for j in (0..a.cols().len()).step_by(17) {
            worst = worst.max(max_abs(a.touch_block(i, j) - b.touch_block(i, j)) / scale);
        }
    }
    eprintln!("blocks differ by {worst:.1e} of the largest diagonal");
    assert!(worst < 1e-9, "{worst}");
}

#[test]
fn a_carried_cut_reads_what_a_full_recompute_of_the_cut_mesh_gives() {
    let cube = touchfem::mesh::cube();
    for n in [1, 10, 25] {
        let (b, u, rank) = carried_against_recompute(&cube, DVec3::new(0.015, 0.015, 0.026), n);
        eprintln!("cube, {n} tets, rank {rank}: blocks {b:.2e}, displacements {u:.2e}");
        assert!(b < 1e-9 && u < 1e-9, "cube {n}: {b} {u}");
    }
    let mouse = touchfem::mesh::mouse();
    let (b, u, rank) = carried_against_recompute(&mouse, DVec3::new(-0.01, 0.0, 0.04), 10);
    eprintln!("mouse, 10 tets, rank {rank}: blocks {b:.2e}, displacements {u:.2e}");
    assert!(b < 1e-9 && u < 1e-9, "mouse: {b} {u}");
}

#[test]
fn pinned_nodes_are_no_longer_touchable_and_do_not_move() {
    let mesh = touchfem::mesh::cube();
    let base = Compliance::compute(&mesh, &Selection::default()).unwrap();
    let mut cut = Cut::new(&mesh).unwrap();
    // Every tet around one surface node: it is left with none.
    let v = *base
        .cols()
        .iter()
        .find(|&&v| {
            let p = mesh.nodes[v as usize];
            p.z > 0.029 && (p.x - 0.015).abs() < 0.006 && (p.y - 0.015).abs() < 0.006
        })
        .unwrap();
    let around: Vec<usize> = (0..mesh.tets.len())
        .filter(|&t| mesh.tets[t].contains(&v))
        .collect();
    let rep = cut.remove(&mesh, &around).unwrap();
    assert!(rep.nodes_pinned >= 1, "{rep:?}");
    let carried = base
        .with_correction(Arc::new(cut.correction(&base).unwrap()))
        .unwrap();
    assert_eq!(carried.col_of(v), None);
    assert!(base.col_of(v).is_some());
    let other = base.cols()[0];
    let f = [(
        carried.col_of(other).unwrap() as u32,
        DVec3::new(0.0, 0.0, -0.1),
    )];
    let mut u = vec![DVec3::ZERO; carried.rows().len()];
    carried.displace(&f, &mut u);
    assert_eq!(u[carried.row_of(v).unwrap()], DVec3::ZERO);
    assert!(u.iter().all(|x| x.is_finite()));
    // A correction that does not fit is refused.
    let bad = touchfem::compliance::correction::Correction {
        rank: 1,
        ..Default::default()
    };
    assert!(base.with_correction(Arc::new(bad)).is_err());
}

/// The blade and press of the live-cut tests: finger 0 a blade 8 mm deep, finger 1 a point.
const CUT_SCENE: &str = r#"
unit = "mm"
[[object]]
mesh = "cube"
cuttable = "all"
[[finger]]
device = "pointer"
tool = { blade = 8.0 }
[[finger]]
device = "pointer"
model = "exact"
"#;

fn mm(x: f64, y: f64, z: f64) -> DVec3 {
    DVec3::new(x, y, z) * 1e-3
}

/// Finger 1 presses from above down to 2 mm into the top at (15, 22) (finger 0 held at
/// `blade`); returns the last force and checks every force on the way.
fn press(
    hw: &mut touchfem::runtime::HapticWorld,
    bound: f64,
    blade: DVec3,
    sample: &mut touchfem::runtime::WorldSample,
) -> DVec3 {
    let mut f = [DVec3::ZERO; 2];
    for k in 0..=200 {
        let z = 35.0 - 7.0 * f64::from(k) / 200.0;
        hw.step(&[blade, mm(15.0, 22.0, z)], &mut f, sample);
        assert!(f
            .iter()
            .all(|v| v.is_finite() && v.length() <= bound + 1e-12));
        assert_eq!(f[0], DVec3::ZERO, "a blade presses nothing");
    }
    f[1]
}

#[test]
fn a_blade_opens_the_body_and_the_haptic_path_reads_the_cut_from_the_next_tick() {
    use touchfem::runtime::cutting::Cutter;
    use touchfem::runtime::{HapticWorld, WorldSample};
    let w = crate::common::world_from_text(CUT_SCENE).unwrap();
    let bound = w.haptics.max_force_n;
    // (A blade that removes: the press is checked against a recompute of the remaining tets
    // below; a separating blade's against its recompute is `cut_grown.rs`'s.)
    let mut cutter = Cutter::new(&w).unwrap();
    cutter.set_cut_mode(touchfem::runtime::cutting::CutMode::Remove);
    let mut hw = HapticWorld::new(&w);
    let mut sample = WorldSample::default();
    let away = mm(15.0, 15.0, 60.0);
    let before = press(&mut hw, bound, away, &mut sample);
    // Lift finger 1; the blade enters at (3, 14) and is drawn to (27, 14) just under the top.
    let lift = mm(15.0, 22.0, 35.0);
    let mut f = [DVec3::ZERO; 2];
    let path = std::iter::once(mm(3.0, 14.0, 31.0))
        .chain((0..=20).map(|k| mm(3.0, 14.0, 31.0 - 1.5 * f64::from(k) / 20.0)))
        .chain((0..=240).map(|k| mm(3.0 + 24.0 * f64::from(k) / 240.0, 14.0, 29.5)));
    let mut installed = 0;
    for x in path {
        hw.step(&[x, lift], &mut f, &mut sample);
        assert!(f
            .iter()
            .all(|v| v.is_finite() && v.length() <= bound + 1e-12));
        let strokes = hw.strokes().to_vec();
        for (o, body) in cutter.apply_all(&strokes).unwrap() {
            hw.install_cut(o, body);
            installed += 1;
        }
    }
    let body = hw.cut_body(0).expect("the blade cut").clone();
    assert!(installed > 3, "{installed} bodies");
    assert!(body.tets_removed > 10, "{:?}", body.report);
    eprintln!(
        "{} tets removed in {installed} passes, rank {}",
        body.tets_removed, body.report.rank
    );
    let after = press(&mut hw, bound, mm(15.0, 15.0, 60.0), &mut sample);
    assert!(
        after.length() < 0.97 * before.length(),
        "beside the cut {after} against {before} before"
    );
    // The same press on a full precompute of the remaining tets (orphan nodes clamped, the
    // opened surface's nodes displayed and touchable).
    let mesh = &w.objects[0].body.mesh;
    let removed = cutter.removed(0).unwrap().to_vec();
    let mut cut_mesh = mesh.without_tets(&removed);
    cut_mesh.surface = mesh.open_surface(&removed);
    let mut has_tet = vec![false; cut_mesh.nodes.len()];
    for t in &cut_mesh.tets {
        for &v in t {
            has_tet[v as usize] = true;
        }
    }
    for (fx, h) in cut_mesh.fixed.iter_mut().zip(&has_tet) {
        *fx |= !h;
    }
    let on_surface: std::collections::BTreeSet<u32> =
        cut_mesh.surface.iter().flatten().copied().collect();
    let sel = Selection {
        rows: touchfem::compliance::NodeSet::Nodes(on_surface.iter().copied().collect()),
        cols: touchfem::compliance::NodeSet::Nodes(
            on_surface
                .iter()
                .copied()
                .filter(|&v| !cut_mesh.fixed[v as usize])
                .collect(),
        ),
    };
    let reference = touchfem::scene::World {
        name: "reference".into(),
        unit: touchfem::LengthUnit::Millimetre,
        objects: vec![touchfem::scene::Object {
            name: "cut".into(),
            body: touchfem::scene::Body::new(cut_mesh, &sel).unwrap(),
            offset: DVec3::ZERO,
            friction: None,
            cuttable: None,
        }],
        fingers: w.fingers.clone(),
        haptics: w.haptics,
        source: String::new(),
        dir: ".".into(),
        hash: 0,
    };
    let mut hr = HapticWorld::new(&reference);
    let mut sr = WorldSample::default();
    let full = press(&mut hr, bound, mm(15.0, 15.0, 60.0), &mut sr);
    let e = (after - full).length() / full.length();
    eprintln!("beside the cut: {after} (full recompute {full}, {e:.1e}); before {before}");
    assert!(e < 1e-9, "carried {after} against recomputed {full}: {e}");
}

/// Runs the bundled `incision` scene through the haptic path with the cutter applied in step
/// (the demo runs it on its own thread); returns the fingertip's force at the end of the
/// press before the cut (t = 1.2 s) and after (t = 6 s), and the final cut body.
fn incision_through_the_haptic_path() -> (
    DVec3,
    DVec3,
    std::sync::Arc<touchfem::runtime::cutting::CutBody>,
) {
    let run = crate::common::removing_incision();
    (run.before, run.after, run.body.clone())
}

#[test]
fn the_incision_scene_opens_a_cut_and_the_same_press_beside_it_needs_less_force() {
    let (before, after, body) = incision_through_the_haptic_path();
    eprintln!(
        "incision: {} tets removed, rank {}; press before {before}, after {after}",
        body.tets_removed, body.report.rank
    );
    assert!(body.tets_removed > 20, "{}", body.tets_removed);
    assert!(before.length() > 0.01, "{before}");
    assert!(
        after.length() < 0.95 * before.length(),
        "{after} against {before}"
    );
    // The same incision with a blade that separates (`CutMode::Separate`): copies of the
    // nodes along its path, slivers dropped. A closed slit barely changes a press beside it
    // that does not part its lips (their opening under a press that spreads them is
    // `the_lips_of_a_cut_open…`).
    let run = crate::common::separated_incision();
    let b = &run.body;
    eprintln!(
        "incision, separating: {} copies, {} slivers, rank {}; press before {}, after {}",
        b.nodes_split, b.tets_removed, b.report.rank, run.before, run.after
    );
    assert!(b.nodes_split > 10, "{}", b.nodes_split);
    assert!(b.tets_removed <= 3 * b.nodes_split, "{}", b.tets_removed);
    assert!(
        (run.after - run.before).length() < 0.02 * run.before.length(),
        "{} against {}",
        run.after,
        run.before
    );
    // The same passes on a fresh cutter: the same body to the bit (a replay's is the live
    // run's; each cut's hash maps iterate in their own order, and the snap once summed the
    // boundary normals in that order).
    let mut cutter = touchfem::runtime::cutting::Cutter::new(&run.world).unwrap();
    cutter.set_cut_mode(touchfem::runtime::cutting::CutMode::Separate);
    let mut last = None;
    for strokes in &run.passes {
        for (_, body) in cutter.apply_all(strokes).unwrap() {
            last = Some(body);
        }
    }
    let bits = |b: &touchfem::runtime::cutting::CutBody| -> Vec<[u64; 3]> {
        (b.rest.iter())
            .map(|p| p.to_array().map(f64::to_bits))
            .collect()
    };
    assert!(
        bits(&last.unwrap()) == bits(b),
        "the same strokes separated to other bits"
    );
}

/// The separating blade parts the material along its whole path: between its ends and above
/// its edge (each by more than an edge), no face is left joining a tet on one side of the
/// blade's plane (y = 0) to one on the other. Before, a node beside the pocket of a dropped
/// flat sliver could only slide along it, never reach the plane: 56 crossings were left
/// stuck, and 3 such faces in this window (x = −13.9, −10.4, −7.7 mm; tissue joined under
/// the slit).
#[test]
fn the_separating_incision_leaves_no_tissue_joined_across_its_path() {
    let run = crate::common::separated_incision();
    let (p, tets) = (&run.cut_nodes, &run.cut_tets);
    let mut faces: std::collections::HashMap<[u32; 3], Vec<usize>> = Default::default();
    for (t, tv) in tets.iter().enumerate() {
        for f in [[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]] {
            let mut k = f.map(|i| tv[i]);
            k.sort_unstable();
            faces.entry(k).or_default().push(t);
        }
    }
    let centre = |t: usize| tets[t].iter().map(|&v| p[v as usize]).sum::<DVec3>() / 4.0;
    let joined: Vec<DVec3> = (faces.iter())
        .filter(|(_, ts)| ts.len() == 2 && centre(ts[0]).y * centre(ts[1]).y < 0.0)
        .map(|(f, _)| f.iter().map(|&v| p[v as usize]).sum::<DVec3>() / 3.0)
        // The path from x = −25 to −5 mm, its edge 8 mm under the top (z = 20 mm); the
        // phantom's mean edge is about 2.2 mm.
        .filter(|c| c.x > -0.0225 && c.x < -0.0075 && c.z > 0.0145)
        .collect();
    eprintln!(
        "faces joining the blade's sides along its path: {}",
        joined.len()
    );
    assert!(
        joined.is_empty(),
        "joined at (mm) {:?}",
        joined
            .iter()
            .map(|c| (*c * 1e3).to_array())
            .collect::<Vec<_>>()
    );
    // And the blade did separate along it (a blade that cut nothing would join nothing).
    assert!(run.body.nodes_split >= 20, "{}", run.body.nodes_split);
}

/// `touchfem demo incision --seconds SECONDS` under `TOUCHFEM_CUT=CUT`, recorded into `dir`:
/// its report and the session's path.
fn record_incision(
    dir: &std::path::Path,
    seconds: &str,
    cut: &str,
) -> (serde_json::Value, std::path::PathBuf) {
    let rec = dir.join("incision.tfsession");
    let report = dir.join("report.json");
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_touchfem"))
        .args(["demo", "incision", "--seconds", seconds, "--out"])
        .arg(dir.join("out"))
        .arg("--record")
        .arg(&rec)
        .arg("--report")
        .arg(&report)
        .env("TOUCHFEM_CUT", cut)
        .env(
            "WGPU_BACKEND",
            std::env::var("WGPU_BACKEND").unwrap_or("vulkan".into()),
        )
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let r = serde_json::from_str(&std::fs::read_to_string(&report).unwrap()).unwrap();
    (r, rec)
}

#[test]
fn a_recorded_separating_incision_is_version_5_and_replays_bit_for_bit() {
    // `TOUCHFEM_CUT=separate`: the live cutter's blade separates the phantom's top (the
    // script stretched to 2 s); its session is version 5 and replays (the cuts
    // rebuilt from their chords, the trails of the blade included) bit for bit.
    let dir = tempfile::tempdir().unwrap();
    let (r, rec) = record_incision(dir.path(), "2", "separate");
    let cuts = &r["objects"][0]["cuts"];
    eprintln!("separating incision: {cuts}");
    // Copies, and no tet removed but slivers (a few per copy).
    let split = cuts["nodes_split"].as_u64().unwrap();
    assert!(split >= 1, "{cuts}");
    // Its bodies reached the haptic loop: a run ending on time waits for the cutter's
    // strokes in flight (`CUT_DRAIN`), however slow the machine.
    assert!(cuts["delays"].as_u64().unwrap() >= 1, "{cuts}");
    assert!(
        cuts["tets_removed"].as_u64().unwrap() <= 3 * split,
        "{cuts}"
    );
    let s = touchfem::runtime::session::read(&rec).unwrap();
    assert_eq!(s.header.version, 5);
    assert!(!s.cuts.is_empty());
    let w = touchfem::runtime::session::world(&s, "test").unwrap();
    let rep = touchfem::runtime::session::replay(&w, &s).unwrap();
    assert_eq!(rep.max_force_diff_n, 0.0, "{rep:?}");
    assert_eq!(rep.ticks, s.ticks.len());
}

#[test]
fn a_recorded_incision_holds_its_cuts_and_replays_bit_for_bit() {
    let dir = tempfile::tempdir().unwrap();
    let (r, rec) = record_incision(dir.path(), "6", "remove");
    let cuts = &r["objects"][0]["cuts"];
    assert!(cuts["bodies"].as_u64().unwrap() >= 1, "{cuts}");
    assert!(cuts["tets_removed"].as_u64().unwrap() > 20, "{cuts}");
    // The incision's rank passes the fold rank: the live cutter hands out a fold, and the
    // replay below adopts it where the live run did.
    let folds = cuts["folds"].as_u64().unwrap();
    let s = touchfem::runtime::session::read(&rec).unwrap();
    assert_eq!(s.header.version, 4);
    // Its folds were deferred: each adopted between two passes, a body of its own, recorded
    // so that the replay below adopts it there too.
    let adopted = s.cuts.iter().filter(|e| e.fold_adopted).count();
    eprintln!(
        "{} cut events, {adopted} adopting a fold; the cutter's longest pass {} s, fold {} s, adoption {} s; stroke to haptic loop: median {} s, longest {} s over {} bodies",
        s.cuts.len(),
        cuts["max_pass_s"],
        cuts["max_fold_s"],
        cuts["max_adopt_s"],
        cuts["median_delay_s"],
        cuts["max_delay_s"],
        cuts["delays"],
    );
    // (Every fold adopted was installed and recorded, unless the run ended first. On a
    // starved machine a fold may not be done within the run: it runs in the haptic core's
    // idle time. The synchronous tests adopt folds whatever the machine.)
    assert!(
        adopted as u64 <= folds,
        "{adopted} adoptions recorded, {folds} folds"
    );
    if adopted == 0 {
        eprintln!("no fold was adopted within the run: the replay checks the cuts alone");
    }
    assert!(cuts["delays"].as_u64().unwrap() >= 1, "{cuts}");
    assert!(!s.cuts.is_empty());
    // Every body but an adoption's was made by strokes.
    let strokes: usize = s.cuts.iter().map(|e| e.strokes.len()).sum();
    assert!(strokes >= s.cuts.len() - adopted);
    assert!(s
        .cuts
        .iter()
        .all(|e| e.fold_adopted || !e.strokes.is_empty()));
    // Every tick's forces again, the cuts rebuilt from their strokes at the same ticks.
    let w = touchfem::runtime::session::world(&s, "test").unwrap();
    let rep = touchfem::runtime::session::replay(&w, &s).unwrap();
    assert_eq!(rep.max_force_diff_n, 0.0, "{rep:?}");
    assert_eq!(rep.ticks, s.ticks.len());
    // When the live cutter's last body landed (the cutter's thread runs beside the haptic
    // loop in real time: on a starved machine, e.g. two busy cores running this suite, it can
    // land seconds after the blade, after the press that should feel it).
    let last_cut = s.cuts.iter().map(|e| e.after_tick).max().unwrap();
    let built = cuts["bodies"].as_u64().unwrap() as usize;
    // The second press reaches its depth at 4.8 s (scenes/incision.toml, 1 kHz); bodies the
    // cutter finished after the run ended were never installed, nor recorded.
    if last_cut >= 4_800 || s.cuts.len() < built {
        eprintln!(
            "the cutter installed {} of its {built} bodies, the last after tick {last_cut}: it \
             fell behind the press (its longest pass {} s); the replay above holds the cuts it \
             made bit for bit, and the cut's effect on a press is checked by the synchronous \
             tests",
            s.cuts.len(),
            cuts["max_pass_s"]
        );
        return;
    }
    // Replayed without its cuts, the press after the blade is the press before.
    let mut uncut = s.clone();
    uncut.cuts.clear();
    let rep = touchfem::runtime::session::replay(&w, &uncut).unwrap();
    assert!(
        rep.max_force_diff_n > 1e-4,
        "last cut after tick {last_cut}: {rep:?}"
    );
    // The trace the demo wrote (the session replayed) shows the softer press after the cut.
    let csv =
        std::fs::read_to_string(dir.path().join("out").join("incision_tissue_force.csv")).unwrap();
    let f: Vec<f64> = csv
        .lines()
        .skip(1)
        .map(|l| l.split(',').nth(4).unwrap().parse().unwrap())
        .collect();
    let n = f.len();
    let before = f[n / 6..n / 4].iter().copied().fold(0.0, f64::max);
    let after = f[n - n / 10..].iter().copied().fold(0.0, f64::max);
    // (How much softer depends on how far the cutter's thread had got by then: the
    // synchronous test above checks the size.)
    assert!(
        after < before && after > 0.5 * before,
        "{after} after, {before} before"
    );
}

#[test]
fn the_lips_of_a_cut_open_under_a_press_that_spreads_them() {
    // A slit 12 mm deep across the cube's top (7.5 mm wide: the cube's cells); a 6 mm
    // fingertip pressed into its middle bears on both lips' edges and spreads them: the lips' faces move apart, several times more than
    // the same material planes do under the same press on the uncut cube.
    use touchfem::runtime::cutting::{Cutter, Stroke};
    use touchfem::runtime::{HapticWorld, WorldSample};
    let world = crate::common::world_from_text(
        r#"
unit = "mm"
[[object]]
name = "cube"
mesh = "cube"
cuttable = "all"
[[finger]]
device = "script"
tool = { sphere = 6.0 }
path = [[0.0, 15.0, 11.25, 40.0]]
"#,
    )
    .unwrap();
    let mesh = &world.objects[0].body.mesh;
    // (A blade that removes: the slit is the trench of the cells it sweeps.)
    let mut cutter = Cutter::new(&world).unwrap();
    cutter.set_cut_mode(touchfem::runtime::cutting::CutMode::Remove);
    let body = cutter
        .apply(&Stroke {
            object: 0,
            from: mm(-1.0, 14.0, 29.99),
            to: mm(31.0, 14.0, 29.99),
            inward: DVec3::NEG_Z,
            depth: 12e-3,
        })
        .unwrap()
        .expect("the blade cuts");
    // The lips: nodes of the cut's faces (on the opened surface, not on the cube's), above
    // the slit's floor, away from the side faces.
    let on_cube: std::collections::BTreeSet<u32> = mesh.surface_nodes.iter().copied().collect();
    let lips: Vec<u32> = body
        .triangles
        .iter()
        .flatten()
        .copied()
        .filter(|v| !on_cube.contains(v))
        .collect::<std::collections::BTreeSet<u32>>()
        .into_iter()
        .chain(on_cube.iter().copied().filter(|&v| {
            let p = body.rest[v as usize];
            (p.z - 0.03).abs() < 1e-9 && (p.y - 0.0075).abs() < 1e-9 || (p.y - 0.015).abs() < 1e-9
        }))
        .filter(|&v| {
            let p = body.rest[v as usize];
            p.z > 0.02 && p.x > 0.004 && p.x < 0.026 && body.compliance.row_of(v).is_some()
        })
        .collect();
    let left: Vec<u32> = lips
        .iter()
        .copied()
        .filter(|&v| body.rest[v as usize].y < 0.0113)
        .collect();
    let right: Vec<u32> = lips
        .iter()
        .copied()
        .filter(|&v| body.rest[v as usize].y > 0.0113)
        .collect();
    assert!(!left.is_empty() && !right.is_empty(), "{left:?} {right:?}");
    // The same press on the cut cube and on the uncut one.
    let opening = |cut: Option<&std::sync::Arc<touchfem::runtime::cutting::CutBody>>| {
        let mut hw = HapticWorld::new(&world);
        if let Some(b) = cut {
            hw.install_cut(0, b.clone());
        }
        let mut sample = WorldSample::default();
        let mut f = [DVec3::ZERO];
        for k in 0..=400 {
            let z = 40.0 - 8.0 * (k as f64 / 400.0).min(1.0);
            hw.step(&[mm(15.0, 11.25, z)], &mut f, &mut sample);
        }
        let c = match cut {
            Some(b) => &b.compliance,
            None => &world.objects[0].body.compliance,
        };
        let mut u = vec![DVec3::ZERO; c.rows().len()];
        c.displace(sample.bc(0).entries(), &mut u);
        let mean_y = |nodes: &[u32]| {
            nodes
                .iter()
                .map(|&v| u[c.row_of(v).unwrap()].y)
                .sum::<f64>()
                / nodes.len() as f64
        };
        (mean_y(&right) - mean_y(&left), mean_y(&left), f[0])
    };
    let (cut_open, cut_left, cut_f) = opening(Some(&body));
    let (plain_open, _, plain_f) = opening(None);
    eprintln!(
        "lips ({} left, {} right): open {:.3} mm cut (left lip {:.3} mm, force {cut_f}), {:.3} mm uncut (force {plain_f})",
        left.len(),
        right.len(),
        cut_open * 1e3,
        cut_left * 1e3,
        plain_open * 1e3
    );
    assert!(cut_left < 0.0, "the left lip moves left: {cut_left}");
    assert!(cut_open > 0.1e-3, "{cut_open}");
    assert!(
        cut_open > 2.0 * plain_open.max(0.0),
        "{cut_open} against {plain_open}"
    );
}

#[test]
fn bench_cut_rows_hold_the_cut_and_the_fold_to_a_full_recompute() {
    // `touchfem bench --cut --quick`'s rows (CPU): the mouse cut by one tet, the carried
    // body and its fold against a full precompute of the remaining tets.
    let rows = touchfem_lab::cutting::rows(None, true).unwrap();
    let get = |m: &str| rows.iter().find(|r| r.method == m).unwrap();
    for m in ["cut-pass", "fold"] {
        let r = get(m);
        assert!(r.rel_error < 1e-9 && r.time_us > 0.0, "{r:?}");
        assert_eq!((r.mesh.as_str(), r.tets_removed), ("mouse", 1));
    }
    assert_eq!(get("recompute").rel_error, 0.0);
    assert!(get("tick-point-exact").time_us > 0.0);
    // A separating blade's step: a correction, nothing removed (no sliver there).
    let sep = get("separate-pass");
    assert!(sep.rank > 0 && sep.time_us > 0.0, "{sep:?}");
    assert_eq!(sep.tets_removed, 0, "{sep:?}");
    // The same step solving every column as it goes: the same rank; the cutter that solves
    // the ball's columns up front takes longer to be ready (no timing asserted beyond > 0).
    let solving = get("separate-pass-solving");
    assert!(
        solving.rank == sep.rank && solving.time_us > 0.0,
        "{solving:?}"
    );
    for m in ["separate-cutter-ready", "separate-cutter-ready-solving"] {
        assert!(get(m).time_us > 0.0, "{m}");
    }
    // The finger's tick beside the slit (the press touched, or the rows are an error).
    let tick = get("separate-tick-point-exact");
    assert!(tick.time_us > 0.0 && tick.rank == sep.rank, "{tick:?}");
    // `--scene` with a mesh file that is not there: a typed error, no rows.
    assert!(touchfem_lab::cutting::scene_rows(None, "no/such/organ.msh", true).is_err());
}

/// A fold's adoption makes the same correction to the bit however the cuts made since its
/// snapshot are split between the fold's thread (`Folded::catch_up`) and the adoption: `V`
/// follows them by one rule either way (carried along, brought up to date whenever it falls
/// a quarter of `V` afresh behind), so a replay, which makes them all at the adoption, makes
/// what the live run made.
#[test]
fn an_adopted_fold_has_the_same_bits_however_its_catch_up_is_split() {
    use touchfem::runtime::cutting::{CutBody, CutMode, Cutter, FoldMode};
    let run = crate::common::separated_incision();
    // Each fold is adopted up to twelve passes after it was handed out, its catch-up making `share`
    // of the cuts made since: (cuts since, the adopted body) for each.
    let adopted = |share: fn(usize) -> usize| -> Vec<(usize, std::sync::Arc<CutBody>)> {
        let mut cutter = Cutter::new(&run.world).unwrap();
        cutter.set_cut_mode(CutMode::Separate);
        cutter.set_fold_mode(FoldMode::Deferred);
        cutter.set_fold_rank(60);
        let (mut out, mut ready): (_, Vec<touchfem::runtime::cutting::Folded>) =
            (Vec::new(), Vec::new());
        // (Four adoptions are enough, and half the incision's passes.)
        for (k, strokes) in run.passes.iter().enumerate() {
            if out.len() >= 4 {
                break;
            }
            if k % 12 == 0 {
                for mut f in std::mem::take(&mut ready) {
                    let o = f.object();
                    let ops = cutter.fold_ops(o).to_vec();
                    f.catch_up(&ops[..share(ops.len())]).unwrap();
                    let n = cutter.fold_ops(o).len();
                    cutter.adopt(f).unwrap();
                    out.push((n, cutter.body_now(o).unwrap()));
                }
            }
            if !cutter.apply_all(strokes).unwrap().is_empty() && ready.is_empty() {
                for job in cutter.take_folds().unwrap() {
                    ready.push(job.run().1.unwrap());
                }
            }
        }
        out
    };
    let (all_at_adoption, all_on_fold) = (adopted(|_| 0), adopted(|n| n));
    let v = |b: &CutBody| -> Vec<u64> {
        let k = b.compliance.correction().expect("a carried correction");
        (k.v_cols.iter().chain(k.rows.iter()))
            .map(|x| x.to_bits())
            .collect()
    };
    let since: Vec<usize> = all_at_adoption.iter().map(|p| p.0).collect();
    eprintln!("folds adopted after {since:?} cuts since their snapshots");
    assert!(all_at_adoption.len() >= 2, "{since:?}");
    assert!(since.iter().any(|&n| n >= 3), "{since:?}");
    assert_eq!(all_at_adoption.len(), all_on_fold.len());
    for ((n, a), (_, b)) in all_at_adoption.iter().zip(&all_on_fold) {
        assert!(a.compliance.correction().is_some_and(|k| k.rank > 0));
        assert!(v(a) == v(b), "the fold adopted after {n} cuts differs");
    }
}
