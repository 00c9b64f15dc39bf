//! Every kind of bad mesh, material, clamp set and cache gets its own typed error; nothing
//! panics and nothing stale or corrupt is used.

use crate::common;

use std::collections::BTreeMap;
use touchfem::cache::{self, CacheError, CacheOutcome};
use touchfem::compliance::{Compliance, Selection};
use touchfem::fem::FemError;
use touchfem::mesh::cube;
use touchfem::mesh::units::MaterialError;
use touchfem::{Formulation, LengthUnit, Material, Mesh, MeshError, RawMesh};

fn two_tets() -> RawMesh {
    RawMesh {
        nodes: vec![
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [0.0, 0.0, 1.0],
            [1.0, 1.0, 1.0],
        ],
        tets: vec![[0, 1, 2, 3], [1, 2, 3, 4]],
        node_groups: BTreeMap::new(),
        tet_groups: BTreeMap::new(),
    }
}

fn load(raw: RawMesh) -> Result<Mesh, MeshError> {
    Mesh::from_raw(raw, LengthUnit::Metre, Material::DEFAULT)
}

#[test]
fn no_tets() {
    let raw = RawMesh {
        tets: vec![],
        ..two_tets()
    };
    assert!(matches!(load(raw), Err(MeshError::NoTets)));
}

#[test]
fn nan_and_inf_coordinates_name_the_node() {
    for bad in [f64::NAN, f64::INFINITY, f64::NEG_INFINITY] {
        let mut raw = two_tets();
        raw.nodes[3][1] = bad;
        match load(raw) {
            Err(MeshError::NonFinite { node: 3, .. }) => {}
            other => panic!("{other:?}"),
        }
    }
    // A non-finite node that no tet uses is dropped, not an error.
    let mut raw = two_tets();
    raw.nodes.push([f64::NAN, 0.0, 0.0]);
    let m = load(raw).unwrap();
    assert_eq!(m.report.dropped_nodes, vec![5]);
}

#[test]
fn index_out_of_range_names_tet_and_index() {
    let mut raw = two_tets();
    raw.tets[1][2] = 9;
    match load(raw) {
        Err(MeshError::IndexOutOfRange {
            tet: 1,
            index: 9,
            nodes: 5,
        }) => {}
        other => panic!("{other:?}"),
    }
}

#[test]
fn degenerate_tets_name_the_tet() {
    // Coplanar nodes.
    let mut raw = two_tets();
    raw.nodes[4] = [0.5, 0.5, 0.0];
    raw.tets[1] = [0, 1, 2, 4];
    match load(raw) {
        Err(MeshError::Degenerate { tet: 1, volume, .. }) => assert!(volume.abs() < 1e-15),
        other => panic!("{other:?}"),
    }
    // A repeated node.
    let mut raw = two_tets();
    raw.tets[0] = [0, 1, 1, 3];
    assert!(matches!(
        load(raw),
        Err(MeshError::Degenerate { tet: 0, .. })
    ));
    // A sliver far below the quality threshold.
    let mut raw = two_tets();
    raw.nodes[3] = [0.3, 0.3, 1e-12];
    raw.tets.truncate(1);
    assert!(matches!(
        load(raw),
        Err(MeshError::Degenerate { tet: 0, .. })
    ));
}

#[test]
fn inverted_tets_are_reoriented_and_reported_with_identical_physics() {
    let good = cube();
    let mut raw = RawMesh {
        nodes: good.nodes.iter().map(|p| p.to_array()).collect(),
        tets: good.tets.iter().map(|t| t.map(|i| i as usize)).collect(),
        node_groups: BTreeMap::new(),
        tet_groups: BTreeMap::new(),
    };
    for t in [3usize, 100, 257] {
        raw.tets[t].swap(0, 1);
    }
    let mut m = Mesh::from_raw(raw, LengthUnit::Metre, good.material).unwrap();
    assert_eq!(m.report.reoriented_tets, vec![3, 100, 257]);
    m.fixed = good.fixed.clone();
    let a = Compliance::compute(&good, &Selection::default()).unwrap();
    let b = Compliance::compute(&m, &Selection::default()).unwrap();
    let d = a
        .l_f64()
        .iter()
        .zip(b.l_f64())
        .map(|(x, y)| (x - y).abs())
        .fold(0.0, f64::max);
    assert!(d < 1e-15, "{d:e}");
    assert_eq!(m.surface.len(), 192);
}

#[test]
fn unused_nodes_are_dropped_and_reported_groups_renumbered() {
    let mut raw = two_tets();
    raw.nodes.insert(0, [9.0, 9.0, 9.0]);
    for t in &mut raw.tets {
        for i in t.iter_mut() {
            *i += 1;
        }
    }
    raw.node_groups.insert("fixed".into(), vec![0, 1, 2, 3]);
    let mut m = load(raw).unwrap();
    assert_eq!(m.report.dropped_nodes, vec![0]);
    assert_eq!(m.nodes.len(), 5);
    assert_eq!(m.groups["fixed"], vec![0, 1, 2]);
    m.set_fixed_group("fixed").unwrap();
    assert_eq!(m.fixed_count(), 3);
}

#[test]
fn non_manifold_boundaries() {
    // Two tets sharing only an edge.
    let raw = RawMesh {
        nodes: vec![
            [0.0, 0.0, 0.0],
            [1.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [0.0, 0.0, 1.0],
            [1.0, -1.0, 0.0],
            [0.0, -1.0, -1.0],
        ],
        tets: vec![[0, 1, 2, 3], [0, 1, 4, 5]],
        node_groups: BTreeMap::new(),
        tet_groups: BTreeMap::new(),
    };
    assert!(matches!(load(raw), Err(MeshError::NonManifold { .. })));
    // Three tets on one face.
    let mut raw = two_tets();
    raw.nodes.push([-1.0, -1.0, -1.0]);
    raw.nodes.push([0.2, 0.2, 0.2]);
    raw.tets.push([1, 2, 3, 5]);
    raw.tets.push([1, 2, 3, 6]);
    match load(raw) {
        Err(MeshError::NonManifold { what }) => assert!(what.contains("face"), "{what}"),
        other => panic!("{other:?}"),
    }
}

#[test]
fn missing_group_lists_the_available_ones() {
    let mut m = cube();
    match m.set_fixed_group("clamp") {
        Err(MeshError::MissingGroup { name, available }) => {
            assert_eq!(name, "clamp");
            assert_eq!(available, "fixed");
        }
        other => panic!("{other:?}"),
    }
}

#[test]
fn no_fixed_node_is_an_error_not_nans() {
    let mut m = cube();
    m.set_fixed_where(|_| false);
    assert!(matches!(
        Compliance::compute(&m, &Selection::default()),
        Err(FemError::NoFixedNodes)
    ));
}

#[test]
fn a_floating_part_is_named() {
    // Two separate blocks; only the first is clamped.
    let mut m = common::grid_mesh([5, 1, 1], [0.01; 3], Material::DEFAULT, |i, _, _| i != 2);
    m.set_fixed_where(|p| p.x < 1e-9);
    match Compliance::compute(&m, &Selection::default()) {
        Err(FemError::Unconstrained {
            part_nodes,
            fixed_in_part: 0,
            ..
        }) => assert_eq!(part_nodes, 12),
        other => panic!("{:?}", other.err()),
    }
    // Clamped on one line only: it can rotate about it.
    let mut m = common::grid_mesh([2, 2, 2], [0.01; 3], Material::DEFAULT, |_, _, _| true);
    m.set_fixed_where(|p| p.x < 1e-9 && p.z < 1e-9);
    match Compliance::compute(&m, &Selection::default()) {
        Err(FemError::Unconstrained {
            fixed_in_part: 3,
            how,
            ..
        }) => assert!(how.contains("collinear")),
        other => panic!("{:?}", other.err()),
    }
}

#[test]
fn bad_material_and_selection() {
    for (e, nu) in [
        (-1.0, 0.3),
        (0.0, 0.3),
        (f64::NAN, 0.3),
        (1000.0, -1.0),
        (1000.0, f64::INFINITY),
    ] {
        let mut m = cube();
        m.material = Material {
            young_pa: e,
            poisson: nu,
        };
        assert!(
            matches!(
                Compliance::compute(&m, &Selection::default()),
                Err(FemError::Material(MaterialError::BadMaterial(_)))
            ),
            "E={e} ν={nu}"
        );
    }
    // ν = 0.5 exactly: its own error, for both formulations.
    for f in [Formulation::Standard, Formulation::LockingFree] {
        let mut m = cube();
        m.material.poisson = 0.5;
        m.formulation = f;
        assert!(
            matches!(
                Compliance::compute(&m, &Selection::default()),
                Err(FemError::Material(MaterialError::Incompressible))
            ),
            "{f}"
        );
    }
    let m = cube();
    let sel = Selection {
        cols: touchfem::compliance::NodeSet::Nodes(vec![0]),
        ..Selection::default()
    };
    assert!(m.fixed[0]);
    assert!(matches!(
        Compliance::compute(&m, &sel),
        Err(FemError::BadSelection(_))
    ));
}

#[test]
fn cache_roundtrip_and_every_kind_of_bad_file() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("cube.tfc");
    let m = cube();
    let sel = Selection::default();
    let (c1, o1) = cache::load_or_compute(&path, &m, &sel).unwrap();
    assert!(matches!(
        o1,
        CacheOutcome::Recomputed(CacheError::Io { .. })
    ));
    let (c2, o2) = cache::load_or_compute(&path, &m, &sel).unwrap();
    assert!(matches!(o2, CacheOutcome::Hit));
    assert_eq!(c1.l_f64(), c2.l_f64());
    assert_eq!(c1.rows(), c2.rows());
    assert_eq!(c1.cols(), c2.cols());
    assert_eq!(c1.diag_inv(5), c2.diag_inv(5));
    assert_eq!(c1.stats.residual, c2.stats.residual);
    let good = std::fs::read(&path).unwrap();
    let key = cache::key(&m, &sel);

    // Stale: another material.
    let mut soft = cube();
    soft.material.young_pa = 5000.0;
    assert!(matches!(
        cache::load(&path, cache::key(&soft, &sel), 125),
        Err(CacheError::Stale { .. })
    ));
    let (c3, o3) = cache::load_or_compute(&path, &soft, &sel).unwrap();
    assert!(matches!(
        o3,
        CacheOutcome::Recomputed(CacheError::Stale { .. })
    ));
    // Half the Young's modulus, twice the compliance.
    let (a, b) = (c1.touch_block(7, 7).x_axis.x, c3.touch_block(7, 7).x_axis.x);
    assert!(a > 0.0 && (b - 2.0 * a).abs() < 1e-12 * a);

    // Truncated, at several lengths.
    for cut in [0, 10, 40, 41, good.len() / 2, good.len() - 1] {
        std::fs::write(&path, &good[..cut]).unwrap();
        assert!(
            matches!(
                cache::load(&path, key, 125),
                Err(CacheError::Truncated { .. })
            ),
            "cut {cut}"
        );
    }
    // One flipped bit anywhere in the payload or checksum.
    for pos in [41, 500, good.len() / 2, good.len() - 9, good.len() - 1] {
        let mut b = good.clone();
        b[pos] ^= 0x10;
        std::fs::write(&path, &b).unwrap();
        assert!(
            matches!(
                cache::load(&path, key, 125),
                Err(CacheError::Corrupt { .. })
            ),
            "pos {pos}"
        );
    }
    // Not ours; another version.
    let mut b = good.clone();
    b[0] = b'X';
    std::fs::write(&path, &b).unwrap();
    assert!(matches!(
        cache::load(&path, key, 125),
        Err(CacheError::Format { .. })
    ));
    let mut b = good.clone();
    b[8] = 99;
    std::fs::write(&path, &b).unwrap();
    assert!(matches!(
        cache::load(&path, key, 125),
        Err(CacheError::Format { .. })
    ));
    // A corrupt file is recomputed and rewritten, then hits again.
    let (c4, o4) = cache::load_or_compute(&path, &m, &sel).unwrap();
    assert!(matches!(
        o4,
        CacheOutcome::Recomputed(CacheError::Format { .. })
    ));
    assert_eq!(c4.l_f64(), c1.l_f64());
    assert!(matches!(
        cache::load_or_compute(&path, &m, &sel).unwrap().1,
        CacheOutcome::Hit
    ));
}

#[test]
fn concurrent_cache_writes_use_unique_temporaries_and_leave_a_valid_file() {
    let m = cube();
    let sel = Selection::default();
    let c = Compliance::compute(&m, &sel).unwrap();
    let k = cache::key(&m, &sel);
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("cube.tfc");
    std::thread::scope(|s| {
        for _ in 0..4 {
            s.spawn(|| cache::save(&path, &c, k, m.nodes.len()).unwrap());
        }
    });
    let back = cache::load(&path, k, m.nodes.len()).unwrap();
    assert_eq!(back.l_f64(), c.l_f64());
    let names: Vec<String> = std::fs::read_dir(dir.path())
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    assert_eq!(names, ["cube.tfc"], "no temporary left behind");
}

#[test]
fn a_cache_that_cannot_be_written_keeps_the_computed_compliance() {
    let m = cube();
    let sel = Selection::default();
    let dir = tempfile::tempdir().unwrap();
    let blocker = dir.path().join("file");
    std::fs::write(&blocker, b"x").unwrap();
    // The cache's directory would have to be a regular file: nothing can be written.
    let (c, outcome) = cache::load_or_compute(&blocker.join("cube.tfc"), &m, &sel).unwrap();
    assert!(matches!(outcome, CacheOutcome::NotSaved(..)), "{outcome:?}");
    assert!(outcome.message().unwrap().starts_with("warning:"));
    let fresh = Compliance::compute(&m, &sel).unwrap();
    assert_eq!(c.l_f64(), fresh.l_f64());
}
