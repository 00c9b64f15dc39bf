//! Mesh file loaders: the fixtures of `scripts/gen_fixtures.py` (a 30 mm box meshed by Gmsh) read
//! from every encoding agree to the number, and no malformed input panics.

use std::collections::BTreeSet;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::{Path, PathBuf};
use touchfem::mesh::{io, tet_volume};
use touchfem::{LengthUnit, Material, Mesh, MeshError, RawMesh};

const EDGE: f64 = 30.0;
const GMSH: [&str; 4] = [
    "box_v41.msh",
    "box_v41_bin.msh",
    "box_v22.msh",
    "box_v22_bin.msh",
];

fn data(name: &str) -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data")
        .join(name)
}

fn read(name: &str) -> RawMesh {
    io::read(&data(name)).unwrap_or_else(|e| panic!("{name}: {e}"))
}

fn validate(raw: RawMesh) -> Mesh {
    Mesh::from_raw(raw, LengthUnit::Millimetre, Material::DEFAULT).expect("valid mesh")
}

/// Raw node indices whose coordinates satisfy `pred`, counted from the coordinates alone.
fn nodes_where(raw: &RawMesh, pred: impl Fn([f64; 3]) -> bool) -> Vec<usize> {
    (0..raw.nodes.len())
        .filter(|&i| pred(raw.nodes[i]))
        .collect()
}

fn on(v: f64, at: f64) -> bool {
    (v - at).abs() < 1e-9
}

fn is_parse(r: &Result<RawMesh, MeshError>) -> bool {
    matches!(r, Err(MeshError::Parse { .. }))
}

fn parse_msg(r: Result<RawMesh, MeshError>) -> String {
    match r {
        Err(MeshError::Parse { msg, .. }) => msg,
        Err(e) => panic!("expected a Parse error, got {e:?}"),
        Ok(m) => panic!(
            "expected a Parse error, got a mesh of {} nodes",
            m.nodes.len()
        ),
    }
}

fn msh(text: &str) -> Result<RawMesh, MeshError> {
    io::parse_msh(text.as_bytes(), Path::new("test.msh"))
}

// ---------------------------------------------------------------------------------------------
// The fixtures
// ---------------------------------------------------------------------------------------------

#[test]
fn four_gmsh_encodings_agree() {
    let reference = read(GMSH[0]);
    let ref_mesh = validate(reference.clone());
    assert_eq!(reference.nodes.len(), 144);
    assert_eq!(reference.tets.len(), 392);
    for name in GMSH {
        let raw = read(name);
        assert_eq!(raw.nodes.len(), reference.nodes.len(), "{name}: nodes");
        assert_eq!(raw.tets.len(), reference.tets.len(), "{name}: tets");
        // Same nodes in the same order (Gmsh writes 16 significant digits in ASCII).
        for (a, b) in raw.nodes.iter().zip(&reference.nodes) {
            for k in 0..3 {
                assert!(
                    (a[k] - b[k]).abs() <= 1e-12 * EDGE,
                    "{name}: {a:?} vs {b:?}"
                );
            }
        }
        assert_eq!(raw.tets, reference.tets, "{name}: tets");
        let names: Vec<&str> = raw.node_groups.keys().map(String::as_str).collect();
        assert_eq!(names, ["7", "body", "fixed"], "{name}: groups");

        // `fixed` (physical surface z = 0) is exactly the nodes with z == 0.
        let bottom = nodes_where(&raw, |p| on(p[2], 0.0));
        assert_eq!(bottom.len(), 31, "{name}");
        assert_eq!(raw.node_groups["fixed"], bottom, "{name}: fixed");
        // The unnamed physical surface 7 (z = 30) is group "7".
        assert_eq!(
            raw.node_groups["7"],
            nodes_where(&raw, |p| on(p[2], EDGE)),
            "{name}: 7"
        );
        // The physical volume holds every node.
        assert_eq!(
            raw.node_groups["body"],
            (0..raw.nodes.len()).collect::<Vec<_>>()
        );

        let mut mesh = validate(raw.clone());
        assert!(mesh.report.dropped_nodes.is_empty(), "{name}");
        let volume: f64 = mesh
            .tets
            .iter()
            .map(|t| {
                let [a, b, c, d] = t.map(|i| mesh.nodes[i as usize]);
                tet_volume(a, b, c, d)
            })
            .sum();
        assert!(
            (volume - 2.7e-5).abs() <= 1e-9 * 2.7e-5,
            "{name}: volume {volume:e} m³"
        );
        assert_eq!(
            mesh.surface.len(),
            ref_mesh.surface.len(),
            "{name}: surface"
        );
        assert_eq!(mesh.surface, ref_mesh.surface, "{name}: surface");
        // Boundary nodes are exactly the nodes on a face of the box.
        let on_box = nodes_where(&raw, |p| p.iter().any(|&c| on(c, 0.0) || on(c, EDGE)));
        assert_eq!(mesh.surface_nodes.len(), on_box.len(), "{name}");
        mesh.set_fixed_group("fixed").unwrap();
        assert_eq!(mesh.fixed_count(), 31, "{name}");
        for (i, p) in mesh.nodes.iter().enumerate() {
            assert_eq!(mesh.fixed[i], p.z == 0.0, "{name}: node {i} at {p}");
        }
        assert!(matches!(
            mesh.set_fixed_group("nope"),
            Err(MeshError::MissingGroup { .. })
        ));
    }
    // Euler for a closed triangulated sphere: T = 2V − 4 boundary triangles.
    assert_eq!(ref_mesh.surface.len(), 2 * ref_mesh.surface_nodes.len() - 4);
}

#[test]
fn fixed_as_points_and_as_curves() {
    for name in ["box_points_v41.msh", "box_points_v22.msh"] {
        let raw = read(name);
        let corners = nodes_where(&raw, |p| {
            on(p[2], 0.0) && (on(p[0], 0.0) || on(p[0], EDGE)) && (on(p[1], 0.0) || on(p[1], EDGE))
        });
        assert_eq!(corners.len(), 4);
        assert_eq!(raw.node_groups["fixed"], corners, "{name}");
        let mut mesh = validate(raw);
        mesh.set_fixed_group("fixed").unwrap();
        assert_eq!(mesh.fixed_count(), 4, "{name}");
    }
    for name in ["box_curves_v41.msh", "box_curves_v22.msh"] {
        let raw = read(name);
        let edges = nodes_where(&raw, |p| {
            on(p[2], 0.0) && (on(p[0], 0.0) || on(p[0], EDGE) || on(p[1], 0.0) || on(p[1], EDGE))
        });
        assert_eq!(edges.len(), 16); // 4 edges of 30 mm at 7.5 mm: 4 × 4 segments
        assert_eq!(raw.node_groups["fixed"], edges, "{name}");
        let mut mesh = validate(raw);
        mesh.set_fixed_group("fixed").unwrap();
        assert_eq!(mesh.fixed_count(), 16, "{name}");
    }
}

#[test]
fn tetgen_matches_the_gmsh_mesh_it_was_written_from() {
    // Written with full precision, so compare with the binary file (exact doubles).
    let gmsh = read("box_v41_bin.msh");
    let gmsh_mesh = validate(gmsh.clone());
    for name in ["box.node", "box.ele"] {
        let raw = read(name);
        assert_eq!(raw.nodes.len(), gmsh.nodes.len());
        assert_eq!(raw.tets.len(), gmsh.tets.len());
        for (a, b) in raw.nodes.iter().zip(&gmsh.nodes) {
            assert_eq!(a, b);
        }
        assert_eq!(raw.tets, gmsh.tets);
        // Boundary markers: 1 = bottom face, 2 = other boundary nodes, 0 (interior) no group.
        let names: Vec<&str> = raw.node_groups.keys().map(String::as_str).collect();
        assert_eq!(names, ["1", "2"]);
        assert_eq!(raw.node_groups["1"], nodes_where(&raw, |p| on(p[2], 0.0)));
        let mut mesh = validate(raw);
        assert_eq!(mesh.surface.len(), gmsh_mesh.surface.len());
        assert_eq!(
            mesh.groups["1"].len() + mesh.groups["2"].len(),
            mesh.surface_nodes.len()
        );
        mesh.set_fixed_group("1").unwrap();
        assert_eq!(mesh.fixed_count(), 31);
    }
}

#[test]
fn fixture_files_are_small() {
    for entry in std::fs::read_dir(data("")).unwrap() {
        let entry = entry.unwrap();
        let len = entry.metadata().unwrap().len();
        assert!(len < 200_000, "{:?} is {len} bytes", entry.path());
    }
}

// ---------------------------------------------------------------------------------------------
// Hand-made files
// ---------------------------------------------------------------------------------------------

/// MSH 4.1 with sparse node tags (10, 30, 20, 55 in a volume block, 100 in a point block), a named
/// physical point and a named physical volume; node 55 is used by no element.
const SPARSE_41: &str = "$MeshFormat
4.1 0 8
$EndMeshFormat
$PhysicalNames
2
0 5 \"tip\"
3 9 \"solid\"
$EndPhysicalNames
$Entities
1 0 0 1
7 0 0 1 1 5
1 0 0 0 1 1 1 1 9 0
$EndEntities
$Nodes
2 5 10 100
0 7 0 1
100
0 0 1
3 1 0 4
10
30
20
55
0 0 0
0 1 0
1 0 0
5 5 5
$EndNodes
$Elements
2 2 1 2
0 7 15 1
1 100
3 1 4 1
2 10 20 30 100
$EndElements
";

#[test]
fn sparse_node_tags_msh41() {
    let raw = msh(SPARSE_41).unwrap();
    assert_eq!(
        raw.nodes,
        [
            [0.0, 0.0, 1.0],
            [0.0, 0.0, 0.0],
            [0.0, 1.0, 0.0],
            [1.0, 0.0, 0.0],
            [5.0, 5.0, 5.0]
        ]
    );
    // Tags 10, 20, 30, 100 → indices 1, 3, 2, 0.
    assert_eq!(raw.tets, [[1, 3, 2, 0]]);
    assert_eq!(raw.node_groups["tip"], [0]);
    assert_eq!(raw.node_groups["solid"], [0, 1, 2, 3]);
    let mesh = Mesh::from_raw(raw, LengthUnit::Metre, Material::DEFAULT).unwrap();
    assert_eq!(mesh.report.dropped_nodes, [4]);
    assert!(mesh.report.reoriented_tets.is_empty());
    let [a, b, c, d] = mesh.tets[0].map(|i| mesh.nodes[i as usize]);
    assert!((tet_volume(a, b, c, d) - 1.0 / 6.0).abs() < 1e-15);
}

/// The same single tet in MSH 2.2 ASCII, sparse tags, an unnamed physical point 5 and `extra`
/// sections that must be skipped.
const TET_22: &str = "$MeshFormat
2.2 0 8
$EndMeshFormat
$Comments
anything $Nodes
$EndComments
$PhysicalNames
1
3 9 \"solid\"
$EndPhysicalNames
$Nodes
5
100 0 0 1
10 0 0 0
30 0 1 0
20 1 0 0
55 5 5 5
$EndNodes
$Elements
2
1 15 2 5 7 100
2 4 2 9 1 10 20 30 100
$EndElements
$NodeData
1
\"u\"
$EndNodeData
";

#[test]
fn sparse_node_tags_msh22() {
    let raw = msh(TET_22).unwrap();
    assert_eq!(raw.nodes.len(), 5);
    assert_eq!(raw.tets, [[1, 3, 2, 0]]);
    assert_eq!(raw.node_groups["5"], [0]);
    assert_eq!(raw.node_groups["solid"], [0, 1, 2, 3]);
}

/// Writes the tet of [`TET_22`] as binary MSH 2.2 in the given byte order.
fn tet_22_binary(big_endian: bool) -> Vec<u8> {
    let i = |v: i32| {
        if big_endian {
            v.to_be_bytes()
        } else {
            v.to_le_bytes()
        }
    };
    let f = |v: f64| {
        if big_endian {
            v.to_be_bytes()
        } else {
            v.to_le_bytes()
        }
    };
    let mut b = b"$MeshFormat\n2.2 1 8\n".to_vec();
    b.extend(i(1));
    b.extend(b"\n$EndMeshFormat\n$Nodes\n5\n");
    for (tag, p) in [
        (100, [0.0, 0.0, 1.0]),
        (10, [0.0, 0.0, 0.0]),
        (30, [0.0, 1.0, 0.0]),
        (20, [1.0, 0.0, 0.0]),
        (55, [5.0, 5.0, 5.0]),
    ] {
        b.extend(i(tag));
        for c in p {
            b.extend(f(c));
        }
    }
    b.extend(b"\n$EndNodes\n$Elements\n2\n");
    for v in [15, 1, 2, 1, 5, 7, 100] {
        b.extend(i(v)); // block header (type 15, 1 element, 2 tags), then tag, tags, node
    }
    for v in [4, 1, 2, 2, 9, 1, 10, 20, 30, 100] {
        b.extend(i(v));
    }
    b.extend(b"\n$EndElements\n");
    b
}

#[test]
fn msh22_binary_both_byte_orders() {
    for big in [false, true] {
        let raw = io::parse_msh(&tet_22_binary(big), Path::new("t.msh")).unwrap();
        assert_eq!(raw.nodes[3], [1.0, 0.0, 0.0], "big endian: {big}");
        assert_eq!(raw.tets, [[1, 3, 2, 0]]);
        assert_eq!(raw.node_groups["5"], [0]);
        assert_eq!(raw.node_groups["9"], [0, 1, 2, 3]);
    }
}

// ---------------------------------------------------------------------------------------------
// Errors
// ---------------------------------------------------------------------------------------------

#[test]
fn dispatch_and_file_errors() {
    let r = io::read(Path::new("mesh.stl"));
    assert!(parse_msg(r).contains("extension"));
    assert!(matches!(
        io::read(Path::new("/nonexistent/x.msh")),
        Err(MeshError::Io { .. })
    ));
    // A .node without its .ele: the I/O error names the .ele.
    let dir = tempfile::tempdir().unwrap();
    let node = dir.path().join("lone.node");
    std::fs::copy(data("box.node"), &node).unwrap();
    match io::read(&node) {
        Err(MeshError::Io { path, .. }) => assert_eq!(path, dir.path().join("lone.ele")),
        other => panic!("{other:?}"),
    }
    assert!(is_parse(&msh("")));
    assert!(parse_msg(msh("hello\n")).contains("not a Gmsh mesh"));
    assert!(parse_msg(msh("$MeshFormat\n4 0 8\n$EndMeshFormat\n")).contains("version 4"));
    assert!(parse_msg(msh("$MeshFormat\n3.0 0 8\n$EndMeshFormat\n")).contains("version 3.0"));
    assert!(parse_msg(msh("$NOD\n1\n1 0 0 0\n$ENDNOD\n")).contains("1.0"));
    let m = parse_msg(msh("$MeshFormat\n4.1 1 3\n$EndMeshFormat\n"));
    assert!(m.contains("data-size 3"), "{m}");
    let m = parse_msg(msh("$MeshFormat\n2.2 0 8\n$EndMeshFormat\n"));
    assert!(m.contains("no $Nodes"), "{m}");
}

#[test]
fn second_order_tets_are_refused() {
    let m = parse_msg(msh(&TET_22.replace(
        "2 4 2 9 1 10 20 30 100",
        "2 11 2 9 1 10 20 30 100 10 20 30 100 10 20",
    )));
    assert!(m.contains("line 22") && m.contains("only linear"), "{m}");
    let m = parse_msg(msh(&SPARSE_41.replace(
        "3 1 4 1\n2 10 20 30 100",
        "3 1 11 1\n2 10 20 30 100 10 20 30 100 10 20",
    )));
    assert!(m.contains("only linear"), "{m}");
    let node = std::fs::read(data("box.node")).unwrap();
    let ele = b"1 10 0\n1 1 2 3 4 5 6 7 8 9 10\n";
    let m = parse_msg(io::parse_tetgen(
        &node,
        Path::new("b.node"),
        ele,
        Path::new("b.ele"),
    ));
    assert!(m.contains("only linear"), "{m}");
}

#[test]
fn wrong_counts() {
    let m = parse_msg(msh(&TET_22.replace("$Nodes\n5\n", "$Nodes\n6\n")));
    assert!(m.contains("declares 6 nodes but holds 5"), "{m}");
    let m = parse_msg(msh(&TET_22.replace("$Nodes\n5\n", "$Nodes\n4\n")));
    assert!(
        m.contains("line 17") && m.contains("expected $EndNodes"),
        "{m}"
    );
    let m = parse_msg(msh(&TET_22.replace("$Elements\n2\n", "$Elements\n3\n")));
    assert!(m.contains("declares 3 elements"), "{m}");
    let m = parse_msg(msh(
        &TET_22.replace("$PhysicalNames\n1\n", "$PhysicalNames\n2\n")
    ));
    assert!(m.contains("declares 2 names"), "{m}");
    let m = parse_msg(msh(&SPARSE_41.replace("2 5 10 100", "2 6 10 100")));
    assert!(m.contains("declares 6 nodes"), "{m}");
    let m = parse_msg(msh(&SPARSE_41.replace("2 5 10 100", "2 0 10 100")));
    assert!(m.contains("$Nodes declares 0"), "{m}");
    let m = parse_msg(msh(&SPARSE_41.replace("2 2 1 2", "2 0 1 2")));
    assert!(m.contains("$Elements declares 0"), "{m}");
    let m = parse_msg(msh(&SPARSE_41.replace("3 1 0 4", "3 1 0 5")));
    assert!(m.contains("line"), "{m}");

    let node = std::fs::read_to_string(data("box.node")).unwrap();
    let ele = std::fs::read(data("box.ele")).unwrap();
    let tg = |node: &str, ele: &[u8]| {
        io::parse_tetgen(
            node.as_bytes(),
            Path::new("b.node"),
            ele,
            Path::new("b.ele"),
        )
    };
    let m = parse_msg(tg(&node.replace("144 3 1 1", "145 3 1 1"), &ele));
    assert!(m.contains("after 144 of 145 nodes"), "{m}");
    let m = parse_msg(tg(&node.replace("144 3 1 1", "143 3 1 1"), &ele));
    assert!(m.contains("line 147") && m.contains("after the 143"), "{m}");
    let m = parse_msg(tg(&node.replace("144 3 1 1", "144 3 0 1"), &ele));
    assert!(
        m.contains("line 4") && m.contains("expected 5 fields, found 6"),
        "{m}"
    );
    let m = parse_msg(tg(&node.replace("\n3 ", "\n4 "), &ele));
    assert!(
        m.contains("line 6") && m.contains("expected 3, found 4"),
        "{m}"
    );
    let ele_s = String::from_utf8(ele.clone()).unwrap();
    let m = parse_msg(tg(&node, ele_s.replace("392 4 1", "393 4 1").as_bytes()));
    assert!(m.contains("after 392 of 393"), "{m}");
}

#[test]
fn non_numeric_fields_name_the_line() {
    let m = parse_msg(msh(&TET_22.replace("30 0 1 0", "30 0 abc 0")));
    assert!(m.contains("line 15") && m.contains("'abc'"), "{m}");
    let m = parse_msg(msh(&TET_22.replace("2 4 2 9 1", "2 4 x 9 1")));
    assert!(m.contains("line 22") && m.contains("number of tags"), "{m}");
    let m = parse_msg(msh(&SPARSE_41.replace("0 1 0\n", "0 one 0\n")));
    assert!(m.contains("line 25"), "{m}");
    let m = parse_msg(msh(&SPARSE_41.replace("0 5 \"tip\"", "0 5 tip")));
    assert!(m.contains("line 6") && m.contains("quoted"), "{m}");
    let node = std::fs::read_to_string(data("box.node")).unwrap();
    let ele = std::fs::read(data("box.ele")).unwrap();
    let m = parse_msg(io::parse_tetgen(
        node.replacen("1 0.0 0.0 30.0", "1 0.0 zero 30.0", 1)
            .as_bytes(),
        Path::new("b.node"),
        &ele,
        Path::new("b.ele"),
    ));
    assert!(m.contains("line 4") && m.contains("'zero'"), "{m}");
}

#[test]
fn node_references_out_of_range() {
    let m = parse_msg(msh(&TET_22.replace("10 20 30 100", "10 20 30 999")));
    assert!(m.contains("999") && m.contains("not in $Nodes"), "{m}");
    let m = parse_msg(msh(&SPARSE_41.replace("2 10 20 30 100", "2 10 20 30 999")));
    assert!(m.contains("999") && m.contains("not in $Nodes"), "{m}");
    // TetGen indices go through to validation, which names the tet and the index.
    let node = std::fs::read(data("box.node")).unwrap();
    let ele = std::fs::read_to_string(data("box.ele")).unwrap();
    let raw = io::parse_tetgen(
        &node,
        Path::new("b.node"),
        ele.replacen("135 140 103 143", "135 140 103 999", 1)
            .as_bytes(),
        Path::new("b.ele"),
    )
    .unwrap();
    match Mesh::from_raw(raw, LengthUnit::Millimetre, Material::DEFAULT) {
        Err(MeshError::IndexOutOfRange { tet, index, nodes }) => {
            assert_eq!((tet, index, nodes), (0, 998, 144));
        }
        other => panic!("{other:?}"),
    }
    // Below the 1-based numbering: a parse error.
    let m = parse_msg(io::parse_tetgen(
        &node,
        Path::new("b.node"),
        ele.replacen("135 140 103 143", "135 140 0 143", 1)
            .as_bytes(),
        Path::new("b.ele"),
    ));
    assert!(
        m.contains("line 3") && m.contains("below the first index 1"),
        "{m}"
    );
}

fn assert_non_finite(raw: RawMesh, node: usize) {
    match Mesh::from_raw(raw, LengthUnit::Millimetre, Material::DEFAULT) {
        Err(MeshError::NonFinite { node: n, .. }) => assert_eq!(n, node),
        other => panic!("{other:?}"),
    }
}

#[test]
fn nan_and_inf_reach_validation() {
    assert_non_finite(msh(&TET_22.replace("30 0 1 0", "30 0 nan 0")).unwrap(), 2);
    assert_non_finite(msh(&TET_22.replace("30 0 1 0", "30 -inf 1 0")).unwrap(), 2);
    assert_non_finite(msh(&SPARSE_41.replace("0 1 0\n", "0 NaN 0\n")).unwrap(), 2);
    assert_non_finite(msh(&SPARSE_41.replace("0 1 0\n", "0 inf 0\n")).unwrap(), 2);
    let mut bin = tet_22_binary(false);
    let one = 1.0f64.to_le_bytes();
    let at = bin.windows(8).position(|w| w == one).unwrap(); // z of tag 100 (node 0)
    bin[at..at + 8].copy_from_slice(&f64::NAN.to_le_bytes());
    assert_non_finite(io::parse_msh(&bin, Path::new("t.msh")).unwrap(), 0);
    let node = std::fs::read_to_string(data("box.node")).unwrap();
    let ele = std::fs::read(data("box.ele")).unwrap();
    let raw = io::parse_tetgen(
        node.replacen("1 0.0 0.0 30.0", "1 0.0 inf 30.0", 1)
            .as_bytes(),
        Path::new("b.node"),
        &ele,
        Path::new("b.ele"),
    )
    .unwrap();
    assert_non_finite(raw, 0);
}

// ---------------------------------------------------------------------------------------------
// Robustness: truncations, garbage and mutations never panic
// ---------------------------------------------------------------------------------------------

use crate::common::Xorshift as Rng;

/// Parses `bytes` as the fixture `name` would be (for TetGen, as the `.node` with the real
/// `.ele`, or the real `.node` with these bytes as `.ele`); a panic fails the test with the input.
fn parse_as(name: &str, bytes: &[u8]) -> Result<RawMesh, MeshError> {
    let run = || {
        if name.ends_with(".msh") {
            io::parse_msh(bytes, Path::new(name))
        } else if name.ends_with(".node") {
            let ele = std::fs::read(data("box.ele")).unwrap();
            io::parse_tetgen(bytes, Path::new(name), &ele, Path::new("box.ele"))
        } else {
            let node = std::fs::read(data("box.node")).unwrap();
            io::parse_tetgen(&node, Path::new("box.node"), bytes, Path::new(name))
        }
    };
    match catch_unwind(AssertUnwindSafe(run)) {
        Ok(r) => r,
        Err(_) => {
            let dump = std::env::temp_dir().join("touchfem_mesh_io_panic.bin");
            let _ = std::fs::write(&dump, bytes);
            panic!("parsing {name}-like input panicked; input saved to {dump:?}")
        }
    }
}

/// Parses an accepted input all the way through validation too: that must not panic either.
fn validate_any(r: Result<RawMesh, MeshError>) {
    if let Ok(raw) = r {
        let _ = Mesh::from_raw(raw, LengthUnit::Millimetre, Material::DEFAULT);
    }
}

const ALL_FIXTURES: [&str; 10] = [
    "box_v41.msh",
    "box_v41_bin.msh",
    "box_v22.msh",
    "box_v22_bin.msh",
    "box_points_v41.msh",
    "box_points_v22.msh",
    "box_curves_v41.msh",
    "box_curves_v22.msh",
    "box.node",
    "box.ele",
];

#[test]
fn truncated_files_are_parse_errors() {
    for name in ALL_FIXTURES {
        let full_bytes = std::fs::read(data(name)).unwrap();
        let full = parse_as(name, &full_bytes).unwrap();
        let len = full_bytes.len();
        // Every byte of the first 300 and the last 300, and ~500 cuts in between.
        let step = (len / 500).max(1);
        let cuts: BTreeSet<usize> = (0..300.min(len))
            .chain((len.saturating_sub(300))..len)
            .chain((0..len).step_by(step))
            .collect();
        for cut in cuts {
            match parse_as(name, &full_bytes[..cut]) {
                Err(MeshError::Parse { msg, .. }) => assert!(!msg.is_empty()),
                Err(e) => panic!("{name} cut at {cut}: not a parse error: {e:?}"),
                // Only whitespace or a trailing comment may be cut off without an error.
                Ok(raw) => {
                    assert_eq!(raw.nodes, full.nodes, "{name} cut at {cut}");
                    assert_eq!(raw.tets, full.tets, "{name} cut at {cut}");
                    assert!(
                        len - cut <= 16,
                        "{name} cut at {cut} of {len} bytes was accepted"
                    );
                }
            }
        }
    }
}

#[test]
fn garbage_is_a_parse_error() {
    let mut rng = Rng(0x9E37_79B9_7F4A_7C15);
    let headers: [&[u8]; 6] = [
        b"",
        b"$MeshFormat\n4.1 0 8\n$EndMeshFormat\n",
        b"$MeshFormat\n4.1 1 8\n\x01\x00\x00\x00\n$EndMeshFormat\n",
        b"$MeshFormat\n2.2 0 8\n$EndMeshFormat\n",
        b"$MeshFormat\n2.2 1 8\n\x01\x00\x00\x00\n$EndMeshFormat\n",
        b"$MeshFormat\n4.1 0 8\n$EndMeshFormat\n$Nodes\n",
    ];
    for round in 0..400 {
        let mut bytes = headers[round % headers.len()].to_vec();
        let n = rng.below(2000);
        for _ in 0..n {
            // Half the time printable digits and separators, to get further into the parsers.
            let b = if rng.below(2) == 0 {
                b"0123456789 \n.-$e"[rng.below(16)]
            } else {
                rng.next() as u8
            };
            bytes.push(b);
        }
        for name in ["g.msh", "g.node", "g.ele"] {
            let r = parse_as(name, &bytes);
            assert!(is_parse(&r), "{name} round {round}: {r:?}");
        }
    }
}

#[test]
fn mutated_fixtures_never_panic() {
    let mut rng = Rng(12345);
    for name in ALL_FIXTURES {
        let orig = std::fs::read(data(name)).unwrap();
        for _ in 0..300 {
            let mut bytes = orig.clone();
            for _ in 0..1 + rng.below(4) {
                let at = rng.below(bytes.len());
                match rng.below(4) {
                    0 => bytes[at] = rng.next() as u8,
                    1 => bytes[at] = b"0123456789-. \n$"[rng.below(15)],
                    2 => {
                        bytes.remove(at);
                    }
                    _ => bytes.insert(at, b"0123456789-. \n"[rng.below(14)]),
                }
            }
            validate_any(parse_as(name, &bytes));
        }
    }
}

#[test]
fn mshio_panics_become_parse_errors() {
    // A second `$Nodes` with 0 nodes (the pre-check looks at the first only) makes mshio 0.4.2
    // compute 0 − 1: a panic where overflow checks are on, caught and reported.
    let r = msh(&SPARSE_41.replace("$Elements", "$Nodes\n0 0 1 1\n$EndNodes\n$Elements"));
    let m = parse_msg(r);
    assert!(
        m.contains("panicked") || m.contains("Multiple node sections"),
        "{m}"
    );
    // mshio's own errors carry a line number.
    let m = parse_msg(msh(&SPARSE_41.replace("3 1 4 1", "3 1 4 x")));
    assert!(m.contains("line 33") && m.contains("element block"), "{m}");
}

/// Dense node tags (1–4) that are not in file order: mshio 0.4.2 drops such tags, the loader
/// must read them itself rather than assume 1, 2, 3, 4.
const PERMUTED_41: &str = "$MeshFormat
4.1 0 8
$EndMeshFormat
$Nodes
2 4 1 4
3 1 0 2
3
1
0 0 0
1 0 0
3 2 0 2
4
2
0 1 0
0 0 1
$EndNodes
$Elements
1 1 1 1
3 1 4 1
1 1 2 3 4
$EndElements
";

#[test]
fn dense_but_permuted_node_tags_msh41() {
    let raw = msh(PERMUTED_41).unwrap();
    // Tags in file order: 3, 1, 4, 2 → tag t is at index [1, 3, 0, 2][t − 1].
    assert_eq!(raw.tets, [[1, 3, 0, 2]]);
    assert!(raw.node_groups.is_empty());
    // The same in binary (size_t = 8, little endian).
    let mut b = b"$MeshFormat\n4.1 1 8\n".to_vec();
    b.extend(1i32.to_le_bytes());
    b.extend(b"\n$EndMeshFormat\n$Nodes\n");
    for v in [2u64, 4, 1, 4] {
        b.extend(v.to_le_bytes());
    }
    for (tags, coords) in [
        ([3u64, 1], [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]]),
        ([4, 2], [[0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]),
    ] {
        for v in [3i32, 1, 0] {
            b.extend(v.to_le_bytes());
        }
        b.extend(2u64.to_le_bytes());
        for t in tags {
            b.extend(t.to_le_bytes());
        }
        for p in coords {
            for c in p {
                b.extend(f64::to_le_bytes(c));
            }
        }
    }
    b.extend(b"\n$EndNodes\n$Elements\n");
    for v in [1u64, 1, 1, 1] {
        b.extend(v.to_le_bytes());
    }
    for v in [3i32, 1, 4] {
        b.extend(v.to_le_bytes());
    }
    for v in [1u64, 1, 1, 2, 3, 4] {
        b.extend(v.to_le_bytes());
    }
    b.extend(b"\n$EndElements\n");
    let raw = io::parse_msh(&b, Path::new("p.msh")).unwrap();
    assert_eq!(raw.nodes[1], [1.0, 0.0, 0.0]);
    assert_eq!(raw.tets, [[1, 3, 0, 2]]);
}

/// Numbers a header mutation writes: counts past u32, u64 and usize, negative, non-numeric.
const HUGE_COUNTS: &[&str] = &[
    "4294967295",
    "4294967296",
    "18446744073709551615",
    "18446744073709551616",
    "9223372036854775807",
    "99999999",
    "1e20",
    "-1",
    "0",
    "nan",
    "inf",
    "1e308",
];

/// Byte ranges of the decimal integers and numbers in `bytes`.
fn number_tokens(bytes: &[u8]) -> Vec<std::ops::Range<usize>> {
    let mut out = Vec::new();
    let mut i = 0;
    while i < bytes.len() {
        let at_start = i == 0 || bytes[i - 1].is_ascii_whitespace();
        if at_start && (bytes[i].is_ascii_digit() || bytes[i] == b'-') {
            let s = i;
            while i < bytes.len() && !bytes[i].is_ascii_whitespace() {
                i += 1;
            }
            out.push(s..i);
        } else {
            i += 1;
        }
    }
    out
}

/// Bounded, deterministic proptest fuzzing of every fixture: header and body numbers replaced by
/// huge, negative and non-numeric counts, bytes flipped, the file truncated; parsed as its kind
/// and, when accepted, validated. Nothing panics (or aborts on a huge allocation), and every
/// error has a message.
#[test]
fn fuzzed_mesh_files_with_huge_counts_never_panic() {
    use proptest::prelude::*;
    use proptest::test_runner::TestCaseError;
    use std::cell::Cell;
    let fixtures: Vec<Vec<u8>> = ALL_FIXTURES
        .iter()
        .map(|n| std::fs::read(data(n)).unwrap())
        .collect();
    let mut runner = crate::common::fuzz_runner(crate::common::fuzz_cases(3000));
    let (ran, ok, err) = (Cell::new(0u32), Cell::new(0u32), Cell::new(0u32));
    let strategy = (
        0..ALL_FIXTURES.len(),
        // (which number: mostly the first few, the headers; value)
        proptest::collection::vec(
            (prop_oneof![0usize..8, any::<usize>()], 0..HUGE_COUNTS.len()),
            0..3,
        ),
        proptest::collection::vec((any::<usize>(), any::<u8>()), 0..3),
        prop_oneof![3 => Just(None), 1 => (0usize..1000).prop_map(Some)],
    );
    let result = runner.run(&strategy, |(f, numbers, flips, cut)| {
        let name = ALL_FIXTURES[f];
        let mut bytes = fixtures[f].clone();
        for (n, v) in &numbers {
            let toks = number_tokens(&bytes);
            if toks.is_empty() {
                break;
            }
            let r = toks[n % toks.len()].clone();
            drop(bytes.splice(r, HUGE_COUNTS[*v].bytes()));
        }
        for (at, b) in &flips {
            let i = at % bytes.len();
            bytes[i] = *b;
        }
        if let Some(k) = cut {
            bytes.truncate(bytes.len() * k / 1000);
        }
        ran.set(ran.get() + 1);
        let r = catch_unwind(AssertUnwindSafe(|| {
            let r = parse_as(name, &bytes);
            let msg = r.as_ref().err().map(ToString::to_string);
            let validated =
                r.map(|raw| Mesh::from_raw(raw, LengthUnit::Millimetre, Material::DEFAULT));
            (msg, validated.map(|v| v.map_err(|e| e.to_string())))
        }));
        match r {
            Err(_) => Err(TestCaseError::fail(format!("{name} panicked"))),
            Ok((Some(msg), _)) | Ok((None, Ok(Err(msg)))) => {
                err.set(err.get() + 1);
                if msg.trim().is_empty() {
                    return Err(TestCaseError::fail(format!("{name}: an empty error")));
                }
                Ok(())
            }
            Ok(_) => {
                ok.set(ok.get() + 1);
                Ok(())
            }
        }
    });
    eprintln!(
        "mesh fuzz: {} cases, {} Ok, {} Err",
        ran.get(),
        ok.get(),
        err.get()
    );
    if let Err(e) = result {
        panic!("{e}");
    }
}
