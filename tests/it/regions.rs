//! Regions of another material: the loaders' tet groups, touchfem's displacement against an
//! independent dense FEM with a material per element, every bad region as a typed error (API,
//! scene file, command line), the cache key, `info --json`, the VTU cell arrays, and the
//! bundled phantom's nodule felt through the finger.

use glam::DVec3;
use nalgebra::{DMatrix, DVector, Matrix4, SMatrix};
use std::path::{Path, PathBuf};
use std::process::Command;
use touchfem::cache::{self, CacheOutcome};
use touchfem::compliance::{Compliance, NodeSet, Selection};
use touchfem::contact::force::ForceModel;
use touchfem::fem::solve_static;
use touchfem::mesh::io;
use touchfem::scene::{Body, SceneSource, World};
use touchfem::{LengthUnit, Material, Mesh, MeshError};

const ENCODINGS: [&str; 4] = [
    "two_regions_v41.msh",
    "two_regions_v41_bin.msh",
    "two_regions_v22.msh",
    "two_regions_v22_bin.msh",
];

fn data(name: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data")
        .join(name)
}

const SOFT: Material = Material {
    young_pa: 2000.0,
    poisson: 0.3,
};
const HARD: Material = Material {
    young_pa: 50_000.0,
    poisson: 0.45,
};

/// The two-region block (mm), bottom clamped, base material `SOFT`, no regions yet.
fn block(name: &str) -> Mesh {
    let raw = io::read(&data(name)).expect("fixture reads");
    let mut m = Mesh::from_raw(raw, LengthUnit::Millimetre, SOFT).expect("valid");
    m.set_fixed_group("fixed").expect("clamped bottom");
    m
}

fn centroid(m: &Mesh, t: u32) -> DVec3 {
    m.tets[t as usize]
        .iter()
        .map(|&i| m.nodes[i as usize])
        .sum::<DVec3>()
        / 4.0
}

// ---------------------------------------------------------------------------------------------
// Loaders
// ---------------------------------------------------------------------------------------------

/// Every encoding gives the same tet groups: `soft` (x < 12 mm) and `hard` (x > 12 mm),
/// disjoint, covering the tets; the surface groups hold no tets.
#[test]
fn physical_volumes_become_tet_groups_in_every_encoding() {
    let reference = block(ENCODINGS[0]);
    for name in ENCODINGS {
        let m = block(name);
        let names: Vec<&str> = m.tet_groups.keys().map(String::as_str).collect();
        assert_eq!(names, ["hard", "soft"], "{name}");
        assert_eq!(m.tet_groups, reference.tet_groups, "{name}");
        let (soft, hard) = (&m.tet_groups["soft"], &m.tet_groups["hard"]);
        assert_eq!(soft.len() + hard.len(), m.tets.len(), "{name}");
        assert!(soft.iter().all(|&t| centroid(&m, t).x < 0.012), "{name}");
        assert!(hard.iter().all(|&t| centroid(&m, t).x > 0.012), "{name}");
        assert!(soft.len() > 50 && hard.len() > 50, "{name}: {}", soft.len());
        // Node groups are still there, of every dimension.
        assert!(m.groups.contains_key("fixed") && m.groups.contains_key("top"));
    }
    // The older fixtures: their one volume group holds every tet.
    for name in ["box_v41.msh", "box_v22_bin.msh"] {
        let raw = io::read(&data(name)).unwrap();
        assert_eq!(raw.tet_groups.len(), 1, "{name}");
        assert_eq!(
            raw.tet_groups["body"],
            (0..raw.tets.len()).collect::<Vec<_>>()
        );
    }
    // TetGen has no groups of tets.
    assert!(io::read(&data("box.ele")).unwrap().tet_groups.is_empty());
}

/// Validation reorients inverted tets in place: their index, and so their group, is kept.
#[test]
fn reoriented_tets_keep_their_group() {
    let good = block(ENCODINGS[0]);
    let mut raw = io::read(&data(ENCODINGS[0])).unwrap();
    let hard0 = raw.tet_groups["hard"][0];
    let soft3 = raw.tet_groups["soft"][3];
    for t in [hard0, soft3] {
        raw.tets[t].swap(0, 1);
    }
    let m = Mesh::from_raw(raw, LengthUnit::Millimetre, SOFT).unwrap();
    let mut flipped = vec![hard0, soft3];
    flipped.sort_unstable();
    assert_eq!(m.report.reoriented_tets, flipped);
    assert_eq!(m.tet_groups, good.tet_groups);
    // The same tets, the same physics.
    for t in 0..m.tets.len() {
        let mut a = m.tets[t];
        let mut b = good.tets[t];
        a.sort_unstable();
        b.sort_unstable();
        assert_eq!(a, b);
    }
}

// ---------------------------------------------------------------------------------------------
// An independent dense FEM
// ---------------------------------------------------------------------------------------------

/// The 12×12 stiffness of a linear tet written from the textbook: shape functions from the
/// inverse of [1 x y z], the 6×12 strain matrix B (engineering shear strains), the isotropic
/// D from E and ν, K = V Bᵀ D B.
fn reference_element(p: [DVec3; 4], e: f64, nu: f64) -> SMatrix<f64, 12, 12> {
    let c = Matrix4::from_fn(|r, k| if k == 0 { 1.0 } else { p[r][k - 1] });
    let vol = c.determinant().abs() / 6.0;
    let inv = c.try_inverse().expect("non-degenerate tet");
    // N_a = Σ_k inv[k][a] · (1, x, y, z)_k: ∂N_a/∂x_j = inv[j + 1][a].
    let mut b = SMatrix::<f64, 6, 12>::zeros();
    for a in 0..4 {
        let (dx, dy, dz) = (inv[(1, a)], inv[(2, a)], inv[(3, a)]);
        let col = 3 * a;
        b[(0, col)] = dx;
        b[(1, col + 1)] = dy;
        b[(2, col + 2)] = dz;
        b[(3, col)] = dy;
        b[(3, col + 1)] = dx;
        b[(4, col + 1)] = dz;
        b[(4, col + 2)] = dy;
        b[(5, col)] = dz;
        b[(5, col + 2)] = dx;
    }
    let f = e / ((1.0 + nu) * (1.0 - 2.0 * nu));
    let mut d = SMatrix::<f64, 6, 6>::zeros();
    for i in 0..3 {
        for j in 0..3 {
            d[(i, j)] = f * if i == j { 1.0 - nu } else { nu };
        }
        d[(i + 3, i + 3)] = f * (1.0 - 2.0 * nu) / 2.0;
    }
    b.transpose() * d * b * vol
}

/// Dense assembly with a material per tet (`material_of`), the clamped DOFs removed, and a
/// dense Cholesky solve; the displacement of every node.
fn reference_solve(
    m: &Mesh,
    material_of: impl Fn(usize) -> Material,
    forces: &[(u32, DVec3)],
) -> Vec<DVec3> {
    let n = 3 * m.nodes.len();
    let mut k = DMatrix::<f64>::zeros(n, n);
    for (t, tet) in m.tets.iter().enumerate() {
        let mat = material_of(t);
        let ke = reference_element(tet.map(|i| m.nodes[i as usize]), mat.young_pa, mat.poisson);
        for a in 0..4 {
            for b in 0..4 {
                for i in 0..3 {
                    for j in 0..3 {
                        k[(3 * tet[a] as usize + i, 3 * tet[b] as usize + j)] +=
                            ke[(3 * a + i, 3 * b + j)];
                    }
                }
            }
        }
    }
    let free: Vec<usize> = (0..n).filter(|d| !m.fixed[d / 3]).collect();
    let kff = DMatrix::from_fn(free.len(), free.len(), |r, c| k[(free[r], free[c])]);
    let mut rhs = DVector::<f64>::zeros(free.len());
    for &(node, f) in forces {
        for a in 0..3 {
            if let Some(r) = free.iter().position(|&d| d == 3 * node as usize + a) {
                rhs[r] += f[a];
            }
        }
    }
    let x = kff.cholesky().expect("K is positive definite").solve(&rhs);
    let mut u = vec![DVec3::ZERO; m.nodes.len()];
    for (r, &d) in free.iter().enumerate() {
        u[d / 3][d % 3] = x[r];
    }
    u
}

/// Largest |a − b| relative to the largest |b|.
fn rel_err(a: &[DVec3], b: &[DVec3]) -> f64 {
    let scale = b.iter().map(|v| v.length()).fold(0.0, f64::max);
    a.iter()
        .zip(b)
        .map(|(x, y)| (*x - *y).length())
        .fold(0.0, f64::max)
        / scale
}

/// Forces on the top face's nodes, varied so that every direction is loaded.
fn top_forces(m: &Mesh) -> Vec<(u32, DVec3)> {
    m.groups["top"]
        .iter()
        .enumerate()
        .map(|(k, &n)| {
            let s = (k % 7) as f64 - 3.0;
            (
                n,
                DVec3::new(1e-3 * s, -5e-4 * (k % 3) as f64, -2e-3 - 1e-4 * s),
            )
        })
        .collect()
}

/// touchfem's f64 displacement (the direct sparse solve and the precomputed L·F) equals an
/// independent dense FEM with E and ν per element to 1e-10 relative, on a mesh of two regions
/// (one of them the object's own material, one region, then two regions covering all);
/// and differs from the one-material answer by far more.
#[test]
fn two_regions_match_an_independent_dense_fem() {
    let base = block(ENCODINGS[0]);
    let forces = top_forces(&base);
    let hard_set = base.tet_groups["hard"].clone();
    let in_hard = |t: usize| hard_set.binary_search(&(t as u32)).is_ok();
    let uniform = reference_solve(&base, |_| SOFT, &forces);
    let third = Material {
        young_pa: 800.0,
        poisson: -0.2,
    };
    type MaterialOf<'a> = Box<dyn Fn(usize) -> Material + 'a>;
    let cases: [(Vec<(String, Material)>, MaterialOf); 2] = [
        (
            vec![("hard".into(), HARD)],
            Box::new(move |t| if in_hard(t) { HARD } else { SOFT }),
        ),
        (
            vec![("soft".into(), third), ("hard".into(), HARD)],
            Box::new(move |t| if in_hard(t) { HARD } else { third }),
        ),
    ];
    for (specs, material_of) in cases {
        let mut m = base.clone();
        m.set_regions(&specs).unwrap();
        for t in 0..m.tets.len() {
            assert_eq!(m.tet_material(t), material_of(t));
        }
        let want = reference_solve(&m, &material_of, &forces);
        let got = solve_static(&m, &forces).unwrap();
        let e = rel_err(&got, &want);
        eprintln!("{specs:?}: solve_static vs dense {e:.1e}");
        assert!(e < 1e-10, "{specs:?}: solve_static vs dense {e:e}");
        // The precomputed compliance, L·F over the surface.
        let cols: Vec<u32> = forces.iter().map(|f| f.0).collect();
        let sel = Selection {
            rows: NodeSet::Surface,
            cols: NodeSet::Nodes(cols),
        };
        let c = Compliance::compute(&m, &sel).unwrap();
        let entries: Vec<(u32, DVec3)> = forces
            .iter()
            .map(|&(n, f)| (c.col_of(n).unwrap() as u32, f))
            .collect();
        let mut u = vec![DVec3::ZERO; c.rows().len()];
        c.displace(&entries, &mut u);
        let want_rows: Vec<DVec3> = c.rows().iter().map(|&n| want[n as usize]).collect();
        let e = rel_err(&u, &want_rows);
        eprintln!("{specs:?}: L·F vs dense {e:.1e}");
        assert!(e < 1e-10, "{specs:?}: L·F vs dense {e:e}");
        // The regions matter: far from the one-material answer.
        let d = rel_err(&want, &uniform);
        assert!(d > 0.1, "{specs:?}: regions change u by only {d:e}");
    }
    // No regions: the one-material answer.
    let e = rel_err(&solve_static(&base, &forces).unwrap(), &uniform);
    assert!(e < 1e-10, "{e:e}");
}

// ---------------------------------------------------------------------------------------------
// Errors
// ---------------------------------------------------------------------------------------------

/// The two-region fixture (MSH 2.2 ASCII) with an extra, empty physical volume `ghost`.
fn with_empty_volume_group() -> String {
    let text = std::fs::read_to_string(data("two_regions_v22.msh")).unwrap();
    let start = text.find("$PhysicalNames\n").unwrap() + "$PhysicalNames\n".len();
    let end = start + text[start..].find('\n').unwrap();
    let n: usize = text[start..end].trim().parse().unwrap();
    format!(
        "{}{}\n3 99 \"ghost\"{}",
        &text[..start],
        n + 1,
        &text[end..]
    )
}

#[test]
fn every_bad_region_is_a_typed_error() {
    let m = block(ENCODINGS[0]);
    let set = |specs: &[(&str, Material)]| {
        let specs: Vec<(String, Material)> =
            specs.iter().map(|(g, m)| (g.to_string(), *m)).collect();
        let mut mesh = m.clone();
        let r = mesh.set_regions(&specs);
        // On error the mesh is unchanged.
        if r.is_err() {
            assert!(mesh.regions.is_empty());
            assert_eq!(mesh.tet_material(0), SOFT);
        }
        r
    };
    match set(&[("nodule", HARD)]) {
        Err(MeshError::NoVolumeGroup { name, available }) => {
            assert_eq!(
                (name.as_str(), available.as_str()),
                ("nodule", "hard, soft")
            )
        }
        other => panic!("{other:?}"),
    }
    for surface in ["fixed", "top"] {
        assert!(
            matches!(set(&[(surface, HARD)]), Err(MeshError::NotVolumeGroup { ref name, .. }) if name == surface)
        );
    }
    match set(&[("hard", HARD), ("soft", SOFT), ("hard", SOFT)]) {
        Err(MeshError::OverlappingRegions { first, second, tet }) => {
            assert_eq!((first.as_str(), second.as_str()), ("hard", "hard"));
            assert!(m.tet_groups["hard"].contains(&tet));
        }
        other => panic!("{other:?}"),
    }
    for (e, nu) in [
        (0.0, 0.3),
        (-1.0, 0.3),
        (f64::NAN, 0.3),
        (f64::INFINITY, 0.3),
        (1000.0, 0.5),
        (1000.0, -1.0),
        (1000.0, f64::NAN),
    ] {
        let bad = Material {
            young_pa: e,
            poisson: nu,
        };
        assert!(
            matches!(set(&[("hard", bad)]), Err(MeshError::BadRegionMaterial { ref group, .. }) if group == "hard"),
            "{e} {nu}"
        );
    }
    // An empty physical volume group.
    let raw = io::parse_msh(with_empty_volume_group().as_bytes(), Path::new("e.msh")).unwrap();
    assert_eq!(raw.tet_groups["ghost"], Vec::<usize>::new());
    let mut e = Mesh::from_raw(raw, LengthUnit::Millimetre, SOFT).unwrap();
    assert!(matches!(
        e.set_regions(&[("ghost".into(), HARD)]),
        Err(MeshError::EmptyVolumeGroup { ref name }) if name == "ghost"
    ));
    // A region's material edited after it was set is still checked before K is built.
    let mut ok = m.clone();
    ok.set_regions(&[("hard".into(), HARD)]).unwrap();
    ok.regions[0].material.poisson = 0.5;
    let err = solve_static(&ok, &[]).unwrap_err().to_string();
    assert!(err.contains("region 'hard'"), "{err}");
}

fn scene_err(text: &str, dir: &Path) -> String {
    let src = SceneSource {
        name: "t".into(),
        text: text.into(),
        dir: dir.into(),
        label: "t.toml".into(),
    };
    match World::from_source_with(&src, None) {
        Ok(_) => panic!("accepted:\n{text}"),
        Err(e) => e.to_string(),
    }
}

const SCENE_HEAD: &str = "unit = \"mm\"\n[[object]]\nmesh = \"two_regions_v41.msh\"\nmesh_unit = \"mm\"\nyoung = 2000.0\npoisson = 0.3\n";

/// Each bad region in a scene file names the file, the line and the key.
#[test]
fn bad_regions_in_a_scene_name_the_line_and_key() {
    let dir = data("");
    let region = |body: &str| format!("{SCENE_HEAD}[[object.region]]\n{body}");
    let cases: Vec<(String, &str, &str)> = vec![
        (
            region("group = \"nodule\"\nyoung = 3e4\n"),
            "line 8, key `region.group`",
            "no physical volume group named 'nodule'",
        ),
        (
            region("group = \"top\"\nyoung = 3e4\n"),
            "line 8, key `region.group`",
            "not a physical volume group",
        ),
        (
            region(
                "group = \"hard\"\nyoung = 3e4\n[[object.region]]\ngroup = \"hard\"\nyoung = 5e4\n",
            ),
            "line 11, key `region.group`",
            "regions 'hard' and 'hard' overlap",
        ),
        (
            region("group = \"hard\"\nyoung = 0.0\n"),
            "line 9, key `region.young`",
            "outside (0,",
        ),
        (
            region("group = \"hard\"\nyoung = -3.0\n"),
            "line 9, key `region.young`",
            "outside (0,",
        ),
        (
            region("group = \"hard\"\nyoung = nan\n"),
            "line 9, key `region.young`",
            "outside (0,",
        ),
        (
            region("group = \"hard\"\nyoung = 3e4\npoisson = 0.5\n"),
            "line 10, key `region.poisson`",
            "outside (-1, 0.5)",
        ),
        (
            region("group = \"hard\"\nyoung = 3e4\npoisson = -1.0\n"),
            "line 10, key `region.poisson`",
            "outside (-1, 0.5)",
        ),
        (
            region("group = \"hard\"\nyoung = 3e4\nstiff = true\n"),
            "unknown field `stiff`",
            "",
        ),
        (region("young = 3e4\n"), "missing field `group`", ""),
    ];
    for (text, want, also) in &cases {
        let e = scene_err(text, &dir);
        assert!(
            e.starts_with("t.toml") && e.contains(want) && e.contains(also),
            "{text}\n→ {e}"
        );
    }
    // An empty volume group, from a file.
    let tmp = tempfile::tempdir().unwrap();
    std::fs::write(tmp.path().join("e.msh"), with_empty_volume_group()).unwrap();
    let text = "[[object]]\nmesh = \"e.msh\"\n[[object.region]]\ngroup = \"ghost\"\nyoung = 3e4\n";
    let e = scene_err(text, tmp.path());
    assert!(
        e.contains("line 4, key `region.group`") && e.contains("'ghost' holds no tetrahedra"),
        "{e}"
    );
}

/// A scene's regions reach the mesh: materials per tet, the default Poisson ratio the
/// object's, and the regions in the cache key.
#[test]
fn scene_regions_reach_the_mesh_and_the_key() {
    let text = format!(
        "{SCENE_HEAD}[[object.region]]\ngroup = \"hard\"\nyoung = 50000.0\n\n[[finger]]\ndevice = \"pointer\"\n"
    );
    let src = |text: &str| SceneSource {
        name: "t".into(),
        text: text.into(),
        dir: data(""),
        label: "t.toml".into(),
    };
    let plan = World::plan(&src(&text)).unwrap();
    let m = &plan[0].mesh;
    assert_eq!(m.regions.len(), 1);
    assert_eq!(
        m.regions[0].material,
        Material {
            young_pa: 50_000.0,
            poisson: 0.3
        }
    );
    assert_eq!(m.regions[0].tets, m.tet_groups["hard"]);
    let without = text.replace("[[object.region]]\ngroup = \"hard\"\nyoung = 50000.0\n", "");
    let plain = World::plan(&src(&without)).unwrap();
    assert!(plain[0].mesh.regions.is_empty());
    assert_ne!(plan[0].key, plain[0].key);
}

/// A cache file made without regions is not used with them, nor the other way round, nor
/// one made with another region material; without regions the key is what it always was
/// (the mesh, material, clamps and selection only).
#[test]
fn regions_count_in_the_cache_key() {
    let plain = block(ENCODINGS[0]);
    let mut hard = plain.clone();
    hard.set_regions(&[("hard".into(), HARD)]).unwrap();
    let mut harder = plain.clone();
    harder
        .set_regions(&[(
            "hard".into(),
            Material {
                young_pa: 60_000.0,
                ..HARD
            },
        )])
        .unwrap();
    let mut both = plain.clone();
    both.set_regions(&[("hard".into(), HARD), ("soft".into(), SOFT)])
        .unwrap();
    let sel = Selection {
        rows: NodeSet::Surface,
        cols: NodeSet::Nodes(plain.groups["top"].iter().copied().take(6).collect()),
    };
    let keys: Vec<u64> = [&plain, &hard, &harder, &both]
        .iter()
        .map(|m| cache::key(m, &sel))
        .collect();
    for i in 0..keys.len() {
        for j in 0..i {
            assert_ne!(keys[i], keys[j], "{i} {j}");
        }
    }
    // Clearing the regions gives the plain key back.
    let mut cleared = hard.clone();
    cleared.set_regions(&[]).unwrap();
    assert_eq!(cache::key(&cleared, &sel), keys[0]);

    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("l.tfc");
    let (c_plain, o) = cache::load_or_compute(&path, &plain, &sel).unwrap();
    assert!(matches!(o, CacheOutcome::Recomputed(_)));
    let (c_hard, o) = cache::load_or_compute(&path, &hard, &sel).unwrap();
    assert!(matches!(o, CacheOutcome::Recomputed(_)), "{o:?}");
    assert_ne!(c_plain.l_f64(), c_hard.l_f64());
    let (_, o) = cache::load_or_compute(&path, &hard, &sel).unwrap();
    assert!(matches!(o, CacheOutcome::Hit), "{o:?}");
    let (again, o) = cache::load_or_compute(&path, &plain, &sel).unwrap();
    assert!(matches!(o, CacheOutcome::Recomputed(_)), "{o:?}");
    assert_eq!(again.l_f64(), c_plain.l_f64());
}

// ---------------------------------------------------------------------------------------------
// The command line
// ---------------------------------------------------------------------------------------------

fn touchfem(args: &[&str]) -> (i32, String, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_touchfem"))
        .args(args)
        .env("TOUCHFEM_CACHE_DIR", "")
        .output()
        .expect("runs");
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// Every bad `--region` is one `error:` line naming the flag, exit status 2, no panic.
#[test]
fn bad_region_flags_name_the_flag() {
    let mesh = data(ENCODINGS[0]);
    let mesh = mesh.to_str().unwrap();
    let tmp = tempfile::tempdir().unwrap();
    let empty = tmp.path().join("e.msh");
    std::fs::write(&empty, with_empty_volume_group()).unwrap();
    let empty = empty.to_str().unwrap();
    let poke = |file: &str, region: &str| -> Vec<String> {
        [
            "poke", file, "--unit", "mm", "--at", "15,10,10", "--push", "0,0,-1", "--region",
            region,
        ]
        .map(String::from)
        .to_vec()
    };
    let (m, e) = (mesh, empty);
    let mut cases: Vec<(Vec<String>, &str)> = vec![
        (
            poke(m, "nodule=30000,0.45"),
            "no physical volume group named 'nodule'",
        ),
        (poke(m, "top=30000,0.45"), "not a physical volume group"),
        (poke(m, "fixed=30000,0.45"), "not a physical volume group"),
        (poke(e, "ghost=30000,0.45"), "holds no tetrahedra"),
    ];
    for bad in [
        "hard=0,0.3",
        "hard=-5,0.3",
        "hard=nan,0.3",
        "hard=inf,0.3",
        "hard=1e14,0.3",
        "hard=3e4,0.5",
        "hard=3e4,-1",
        "hard=3e4,nan",
        "hard=3e4",
        "hard",
        "=3e4,0.3",
        "hard=a,b",
    ] {
        cases.push((poke(m, bad), "GROUP=E,NU"));
    }
    let mut overlap = poke(m, "hard=30000,0.45");
    overlap.extend(["--region".into(), "hard=40000,0.45".into()]);
    cases.push((overlap, "regions 'hard' and 'hard' overlap"));
    let mut info = vec![
        "info".to_string(),
        m.to_string(),
        "--unit".into(),
        "mm".into(),
    ];
    info.extend(["--region".into(), "nodule=1,0.3".into()]);
    cases.push((info, "no physical volume group"));
    for (args, want) in &cases {
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        let (code, _, err) = touchfem(&args);
        assert_eq!(code, 2, "{args:?}: {err}");
        assert!(!err.contains("panicked"), "{args:?}: {err}");
        assert!(
            err.starts_with("error:") && err.contains("--region") && err.contains(want),
            "{args:?}: {err}"
        );
    }
}

/// `info --json` lists the regions (group, tets, young, poisson) beside every earlier key;
/// none: an empty array.
#[test]
fn info_json_lists_the_regions() {
    let mesh = data(ENCODINGS[2]);
    let m = block(ENCODINGS[2]);
    let args = [
        "info",
        mesh.to_str().unwrap(),
        "--unit",
        "mm",
        "--json",
        "--young",
        "2000",
        "--region",
        "hard=50000,0.45",
        "--region",
        "soft=1500,0.25",
    ];
    let (code, out, err) = touchfem(&args);
    assert_eq!(code, 0, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    for k in [
        "nodes",
        "surface_nodes",
        "free_surface_nodes",
        "surface_triangles",
        "tets",
        "young_pa",
        "poisson",
        "condition_estimate",
        "f32_storage_error",
    ] {
        assert!(v.get(k).is_some(), "{k} missing: {v}");
    }
    assert_eq!(v["young_pa"], 2000.0);
    let r = v["regions"].as_array().unwrap();
    assert_eq!(r.len(), 2);
    assert_eq!(r[0]["group"], "hard");
    assert_eq!(r[0]["tets"], m.tet_groups["hard"].len());
    assert_eq!(r[0]["young"], 50000.0);
    assert_eq!(r[0]["poisson"], 0.45);
    assert_eq!(r[1]["group"], "soft");
    assert_eq!(r[1]["tets"], m.tet_groups["soft"].len());
    assert_eq!(r[1]["young"], 1500.0);
    assert_eq!(r[1]["poisson"], 0.25);
    let (_, out, _) = touchfem(&args[..5]);
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["regions"], serde_json::json!([]));
}

/// The numbers of one `<DataArray Name="NAME">` of a VTU file.
fn vtu_array(text: &str, name: &str) -> Vec<f64> {
    let tag = format!("Name=\"{name}\"");
    let start = text.find(&tag).unwrap_or_else(|| panic!("no {name}"));
    let body = &text[start..];
    let body = &body[body.find('>').unwrap() + 1..];
    let body = &body[..body.find("</DataArray>").unwrap()];
    body.split_ascii_whitespace()
        .map(|t| t.parse().unwrap())
        .collect()
}

/// `poke --vtu` writes young, poisson and region per cell, and keeps the point arrays; the
/// displacement it writes is the regions' (the independent FEM's, for the applied forces).
#[test]
fn vtu_has_the_material_cell_arrays() {
    let mesh = data(ENCODINGS[1]);
    let m = block(ENCODINGS[1]);
    let dir = tempfile::tempdir().unwrap();
    let vtu = dir.path().join("p.vtu");
    let (code, _, err) = touchfem(&[
        "poke",
        mesh.to_str().unwrap(),
        "--unit",
        "mm",
        "--young",
        "2000",
        "--at",
        "20,10,10",
        "--push",
        "0,0,-1",
        "--region",
        "hard=50000,0.45",
        "--vtu",
        vtu.to_str().unwrap(),
    ]);
    assert_eq!(code, 0, "{err}");
    let text = std::fs::read_to_string(&vtu).unwrap();
    let young = vtu_array(&text, "young");
    let poisson = vtu_array(&text, "poisson");
    let region = vtu_array(&text, "region");
    assert_eq!(young.len(), m.tets.len());
    let hard = &m.tet_groups["hard"];
    for t in 0..m.tets.len() {
        let is_hard = hard.binary_search(&(t as u32)).is_ok();
        let want = if is_hard {
            (50000.0, 0.45, 1.0)
        } else {
            (2000.0, 0.3, 0.0)
        };
        assert_eq!((young[t], poisson[t], region[t]), want, "tet {t}");
    }
    assert_eq!(young.iter().filter(|&&e| e == 50000.0).count(), hard.len());
    // The point arrays are still there, and the displacement is the two materials'.
    let n = m.nodes.len();
    let u = vtu_array(&text, "displacement");
    let f = vtu_array(&text, "force");
    assert_eq!(
        (u.len(), f.len(), vtu_array(&text, "fixed").len()),
        (3 * n, 3 * n, n)
    );
    let forces: Vec<(u32, DVec3)> = (0..n)
        .map(|i| (i as u32, DVec3::new(f[3 * i], f[3 * i + 1], f[3 * i + 2])))
        .filter(|(_, v)| *v != DVec3::ZERO)
        .collect();
    assert!(!forces.is_empty());
    let mut mr = m.clone();
    mr.set_regions(&[("hard".into(), HARD)]).unwrap();
    // The reference's materials from the group's tets, not from the crate's region lookup.
    let want = reference_solve(
        &mr,
        |t| {
            if hard.binary_search(&(t as u32)).is_ok() {
                HARD
            } else {
                SOFT
            }
        },
        &forces,
    );
    let got: Vec<DVec3> = (0..n)
        .map(|i| DVec3::new(u[3 * i], u[3 * i + 1], u[3 * i + 2]))
        .collect();
    // Written with `{:e}` (shortest round trip): the same numbers.
    let e = rel_err(&got, &want);
    assert!(e < 1e-10, "{e:e}");
}

// ---------------------------------------------------------------------------------------------
// The phantom: the nodule is felt
// ---------------------------------------------------------------------------------------------

/// The mean force (N) of a 2 mm press straight down at five points around (x, y) on the
/// phantom's top face (mm): the centre and ±2 mm along x and y.
fn press_force(body: &Body, x: f64, y: f64) -> f64 {
    let mut sum = 0.0;
    let spots = [(0.0, 0.0), (2.0, 0.0), (-2.0, 0.0), (0.0, 2.0), (0.0, -2.0)];
    for (dx, dy) in spots {
        let at = DVec3::new(x + dx, y + dy, 20.0) * 1e-3;
        let p = body
            .poke(at, DVec3::new(0.0, 0.0, -2e-3), ForceModel::Paper, 20)
            .unwrap();
        assert!(p.contact.is_some());
        sum += p.feedback.length();
    }
    sum / spots.len() as f64
}

/// The phantom with (or without) its nodule ten times stiffer, columns only around the
/// three press sites.
fn phantom_body(nodule: Option<f64>) -> Body {
    let mut mesh = touchfem::mesh::phantom();
    if let Some(e) = nodule {
        mesh.set_regions(&[(
            "nodule".into(),
            Material {
                young_pa: e,
                poisson: 0.45,
            },
        )])
        .unwrap();
    }
    let sites = [-18.0, 0.0, 18.0].map(|x| DVec3::new(x * 1e-3, 0.0, 0.02));
    let cols: Vec<u32> = mesh
        .free_surface_nodes()
        .into_iter()
        .filter(|&n| {
            sites
                .iter()
                .any(|s| mesh.nodes[n as usize].distance(*s) < 0.007)
        })
        .collect();
    Body::new(
        mesh,
        &Selection {
            rows: NodeSet::Surface,
            cols: NodeSet::Nodes(cols),
        },
    )
    .unwrap()
}

/// The same 2 mm press needs a clearly larger force above the nodule (3 mm under the
/// surface, E ten times the tissue's) than 18 mm to either side; with one material the two
/// forces are nearly equal, so the ratio is the nodule's.
///
/// Measured (2026-12-03, deterministic): with the nodule, over 0.0214 N, away 0.0183 N, ratio
/// **1.169**; with one material, over 0.0173 N, away 0.0183 N, ratio 0.946; so the nodule adds
/// 1.236×. A point contact's force is dominated by the tissue right under it, so the ratio
/// saturates with the nodule's stiffness (1.226 at E = 100 kPa, 1.247 at 300 kPa); 17 % is
/// above the ~10 % just-noticeable difference of a force. The bounds leave a few per cent.
#[test]
fn the_nodule_is_felt() {
    let ratio = |body: &Body| {
        let over = press_force(body, 0.0, 0.0);
        let away = 0.5 * (press_force(body, -18.0, 0.0) + press_force(body, 18.0, 0.0));
        (over, away, over / away)
    };
    let (over, away, with) = ratio(&phantom_body(Some(30_000.0)));
    let (over_u, away_u, without) = ratio(&phantom_body(None));
    eprintln!(
        "nodule: over {over:.4} N, away {away:.4} N, ratio {with:.3}; one material: over \
         {over_u:.4} N, away {away_u:.4} N, ratio {without:.3}"
    );
    assert!(with > 1.12, "the nodule is not felt: ratio {with}");
    assert!((without - 1.0).abs() < 0.08, "uniform ratio {without}");
    assert!(with / without > 1.18, "{with} vs {without}");
}

/// The bundled scene `palpate`, its scripted finger run through the haptic path at 1 kHz
/// (as the demo's force trace replays it): while the finger slides 3 mm deep across the top
/// face, the force rises over the nodule (x = 0) well above the force beside it (15–21 mm to
/// either side, where the finger slides over tissue only).
///
/// Measured (deterministic): with the point finger (2026-12-03) over the nodule 0.0346 N,
/// beside it 0.0275 N, ratio **1.261**; with the fingertip the scene now has (a sphere of
/// 8 mm, 2026-12-04) 0.1511 N against 0.0955 N, ratio **1.582**.
#[test]
fn the_palpate_trace_rises_over_the_nodule() {
    use touchfem::runtime::{HapticWorld, WorldSample};
    use touchfem::scene::DeviceSpec;
    let world = World::load_with("palpate", "script", None).unwrap();
    assert_eq!(world.objects.len(), 1);
    let mesh = &world.objects[0].body.mesh;
    assert_eq!(mesh.regions.len(), 1);
    assert_eq!(mesh.regions[0].group, "nodule");
    assert_eq!(mesh.regions[0].material.young_pa, 30_000.0);
    assert_eq!(mesh.material.young_pa, 3000.0);
    let DeviceSpec::Script(keys) = &world.fingers[0].device else {
        panic!("a scripted finger")
    };
    let at = |t: f64| -> DVec3 {
        let k = keys.iter().rposition(|k| k.0 <= t).unwrap_or(0);
        match keys.get(k + 1) {
            None => keys[k].1,
            Some(next) => {
                let s = (t - keys[k].0) / (next.0 - keys[k].0);
                keys[k].1.lerp(next.1, s.clamp(0.0, 1.0))
            }
        }
    };
    let mut hw = HapticWorld::new(&world);
    let mut sample = WorldSample::default();
    let mut f = [DVec3::ZERO; 1];
    let end = keys.last().unwrap().0;
    let slide_z = keys[1].1.z;
    let (mut over, mut beside, mut n_beside) = (0.0f64, 0.0, 0);
    for k in 0..=(end * 1000.0) as usize {
        let t = k as f64 / 1000.0;
        let x = at(t);
        hw.step(&[x], &mut f, &mut sample);
        // The slide, 3 mm deep.
        if (x.z - slide_z).abs() < 1e-9 {
            let mag = f[0].length();
            if x.x.abs() < 0.003 {
                over = over.max(mag);
            }
            if (0.015..0.021).contains(&x.x.abs()) {
                beside += mag;
                n_beside += 1;
            }
        }
    }
    let beside = beside / n_beside as f64;
    eprintln!(
        "palpate trace: over the nodule {over:.4} N, beside it {beside:.4} N, ratio {:.3}",
        over / beside
    );
    assert!(beside > 0.005, "the finger presses: {beside}");
    assert!(over / beside > 1.2, "{over} vs {beside}");
}

/// `view palpate` can be pressed: a scene of scripted fingers gets the window's pointer as
/// one more finger, written into the scene's text (so a recorded session replays it, the
/// hash of the text being the session's); a mesh keeps its one pointer finger.
#[test]
fn view_adds_the_pointer_to_a_scripted_scene() {
    use touchfem::scene::DeviceSpec;
    use touchfem_app::window::cli::load_with_pointer;
    let w = load_with_pointer("palpate", None).unwrap();
    assert_eq!(w.fingers.len(), 2);
    assert!(matches!(w.fingers[0].device, DeviceSpec::Script(_)));
    assert!(matches!(w.fingers[1].device, DeviceSpec::Pointer));
    assert_eq!(w.objects[0].body.mesh.regions.len(), 1);
    let again = World::from_source_with(
        &SceneSource {
            name: w.name.clone(),
            text: w.source.clone(),
            dir: w.dir.clone(),
            label: "palpate".into(),
        },
        None,
    )
    .unwrap();
    assert_eq!(again.hash, w.hash);
    assert_eq!(again.fingers, w.fingers);
    let cube = load_with_pointer("cube", None).unwrap();
    assert_eq!(cube.fingers.len(), 1);
    assert!(matches!(cube.fingers[0].device, DeviceSpec::Pointer));
}
