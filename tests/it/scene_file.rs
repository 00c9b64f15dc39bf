//! Scene files: the bundled scenes, what they precompute, units, relative mesh paths, and a
//! typed error naming the key and line for every bad file.

use glam::DVec3;
use proptest::prelude::*;
use touchfem::compliance::{Compliance, NodeSet, Selection};
use touchfem::contact::force::ForceModel;
use touchfem::scene::{DeviceSpec, SceneSource, World};

fn load(text: &str, dir: &std::path::Path) -> Result<World, touchfem::Error> {
    World::from_source_with(
        &SceneSource {
            name: "t".into(),
            text: text.into(),
            dir: dir.into(),
            label: "t.toml".into(),
        },
        None,
    )
}

fn err(text: &str) -> String {
    match load(text, std::path::Path::new(".")) {
        Ok(_) => panic!("accepted:\n{text}"),
        Err(e) => e.to_string(),
    }
}

#[test]
fn the_bundled_scenes_load_with_only_what_they_need() {
    let fig1 = World::load_with("fig1", "script", None).unwrap();
    let o = &fig1.objects[0];
    assert_eq!((o.name.as_str(), o.body.mesh.nodes.len()), ("cube", 125));
    assert_eq!(o.body.compliance.rows().len(), 98);
    assert_eq!(o.body.compliance.cols().len(), 73);
    assert_eq!(fig1.fingers.len(), 1);
    let DeviceSpec::Script(keys) = &fig1.fingers[0].device else {
        panic!()
    };
    // mm in the file, metres inside.
    assert_eq!(keys[1], (1.0, DVec3::new(0.015, 0.015, 0.025)));
    assert_eq!(fig1.haptics.rate_hz, 1000.0);

    let pinch = World::load_with("pinch", "script", None).unwrap();
    let m = &pinch.objects[0].body.mesh;
    let c = &pinch.objects[0].body.compliance;
    // The ball's free-surface nodes, counted independently.
    let centre = DVec3::new(0.015, 0.015, 0.018);
    let want: Vec<u32> = m
        .free_surface_nodes()
        .into_iter()
        .filter(|&n| m.nodes[n as usize].distance(centre) <= 0.018)
        .collect();
    assert_eq!(c.cols(), &want[..]);
    assert!(want.len() < 73 && want.len() > 10, "{}", want.len());
    assert_eq!(c.rows().len(), 98, "every displayed surface node");
    // The columns it has equal those of the full precompute (same L, fewer columns).
    let full = Compliance::compute(m, &Selection::default()).unwrap();
    for (j, &node) in c.cols().iter().enumerate() {
        let jf = full.col_of(node).unwrap();
        for r in 0..c.rows().len() {
            let d = c.block(r, j) - full.block(r, jf);
            assert!(d.abs().to_cols_array().iter().all(|v| *v < 1e-15), "{d}");
        }
    }
    assert_eq!(pinch.fingers.len(), 2);
    let fig2 = World::load_with("fig2", "script", None).unwrap();
    assert_eq!(fig2.objects[0].body.mesh.nodes.len(), 1699);
    assert_ne!(
        fig1.hash, pinch.hash,
        "the selection is part of the scene hash"
    );
}

#[test]
fn the_cache_key_includes_the_selection() {
    let m = touchfem::mesh::cube();
    let all = Selection::default();
    let some = Selection {
        rows: NodeSet::Surface,
        cols: NodeSet::Nodes(m.free_surface_nodes()[..5].to_vec()),
    };
    assert_ne!(
        touchfem::cache::key(&m, &all),
        touchfem::cache::key(&m, &some)
    );
}

#[test]
fn metres_and_millimetres_give_the_same_scene() {
    let mm = load(
        r#"unit = "mm"
[[object]]
mesh = "cube"
touchable = { center = [115, 15, 30], radius = 10 }
offset = [100, 0, 0]
[[finger]]
device = "script"
path = [[0, 115, 15, 40], [1, 115, 15, 25]]
"#,
        ".".as_ref(),
    )
    .unwrap();
    let m = load(
        r#"[[object]]
mesh = "cube"
touchable = { center = [0.115, 0.015, 0.030], radius = 0.010 }
offset = [0.1, 0, 0]
[[finger]]
device = "script"
model = "exact"
path = [[0, 0.115, 0.015, 0.040], [1, 0.115, 0.015, 0.025]]
"#,
        ".".as_ref(),
    )
    .unwrap();
    assert_eq!(mm.objects[0].offset, DVec3::new(0.1, 0.0, 0.0));
    assert_eq!(
        mm.objects[0].body.compliance.cols(),
        m.objects[0].body.compliance.cols()
    );
    assert_eq!(m.fingers[0].model, ForceModel::Exact);
    let (DeviceSpec::Script(a), DeviceSpec::Script(b)) =
        (&mm.fingers[0].device, &m.fingers[0].device)
    else {
        panic!()
    };
    for (x, y) in a.iter().zip(b) {
        assert!((x.1 - y.1).length() < 1e-15);
    }
}

#[test]
fn a_mesh_path_is_relative_to_the_scene_file() {
    let dir = tempfile::tempdir().unwrap();
    let sub = dir.path().join("meshes");
    std::fs::create_dir(&sub).unwrap();
    let here = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    std::fs::copy(here.join("tests/data/box_v41.msh"), sub.join("box.msh")).unwrap();
    let text = r#"unit = "mm"
[[object]]
name = "box"
mesh = "meshes/box.msh"
mesh_unit = "mm"
young = 3000.0
poisson = 0.45
touchable = "all"
[[finger]]
device = "pointer"
[haptics]
rate_hz = 500.0
max_force_n = 3.0
"#;
    std::fs::write(dir.path().join("s.toml"), text).unwrap();
    let w = World::load_with(dir.path().join("s.toml").to_str().unwrap(), "script", None).unwrap();
    let o = &w.objects[0];
    assert_eq!(o.name, "box");
    assert_eq!(o.body.mesh.material.young_pa, 3000.0);
    let (lo, hi) = o.body.mesh.bounds();
    assert!((hi - lo).max_element() < 0.1, "mm converted: {lo} {hi}");
    assert_eq!((w.haptics.rate_hz, w.haptics.max_force_n), (500.0, 3.0));
    assert_eq!(w.fingers[0].device, DeviceSpec::Pointer);
}

#[test]
fn bad_scene_files_name_the_key_and_the_line() {
    let cases: &[(&str, &[&str])] = &[
        // unknown key
        (
            "[[object]]\nmesh = \"cube\"\ncolour = \"red\"\n",
            &["line 3", "colour"],
        ),
        // wrong type
        (
            "[[object]]\nmesh = \"cube\"\nyoung = \"soft\"\n",
            &["line 3", "young"],
        ),
        ("unit = 3\n[[object]]\nmesh = \"cube\"\n", &["line 1", "unit"]),
        // a tolerance out of (0, 1), an unknown compression key, compression on a cuttable object
        (
            "[[object]]\nmesh = \"cube\"\ncompression = { tolerance = 2.0 }\n",
            &["line 3", "`compression`", "in (0, 1)"],
        ),
        (
            "[[object]]\nmesh = \"cube\"\ncompression = { tol = 1e-3 }\n",
            &["line 3", "compression"],
        ),
        (
            "[[object]]\nmesh = \"cube\"\ncuttable = \"all\"\ncompression = { tolerance = 1e-3 }\n",
            &["line 4", "`compression`", "dense L"],
        ),
        // missing mesh file
        (
            "\n[[object]]\nmesh = \"no/such.msh\"\n",
            &["line 3", "`mesh`", "no/such.msh"],
        ),
        // no mesh key at all
        ("[[object]]\nname = \"x\"\n", &["mesh"]),
        // a ball that holds no free-surface node (the cube's centre, 5 mm)
        (
            "unit = \"mm\"\n[[object]]\nmesh = \"cube\"\ntouchable = { center = [15, 15, 15], radius = 5 }\n",
            &["line 4", "`touchable`", "no free-surface node"],
        ),
        // a path whose times do not increase
        (
            "[[object]]\nmesh = \"cube\"\n[[finger]]\ndevice = \"script\"\npath = [[0, 0, 0, 1], [1, 0, 0, 0.9], [1, 0, 0, 0.8]]\n",
            &["line 5", "`path`", "increase", "keyframe 3"],
        ),
        // device limits: an unknown preset, a bad number, an unknown key
        (
            "[[object]]\nmesh = \"cube\"\n[[finger]]\ndevice = \"udp\"\nlimits = \"phantom\"\n",
            &["line 5", "`limits`", "'phantom' is not a device preset", "falcon"],
        ),
        (
            "[[object]]\nmesh = \"cube\"\n[[finger]]\ndevice = \"udp\"\nlimits = { max_force_n = 5.0, max_stiffness_n_per_m = -1.0, max_damping_ns_per_m = 5.0, workspace_radius_m = 0.1 }\n",
            &["line 5", "`limits`", "max_stiffness_n_per_m must be finite and positive"],
        ),
        (
            "[[object]]\nmesh = \"cube\"\n[[finger]]\ndevice = \"udp\"\nlimits = { max_force = 5.0 }\n",
            &["line 5", "limits"],
        ),
        // unknown device, model, unit, group
        (
            "[[object]]\nmesh = \"cube\"\n[[finger]]\ndevice = \"joystick\"\n",
            &["line 4", "`device`", "joystick"],
        ),
        (
            "[[object]]\nmesh = \"cube\"\n[[finger]]\ndevice = \"pointer\"\nmodel = \"magic\"\n",
            &["line 5", "`model`"],
        ),
        ("unit = \"inch\"\n[[object]]\nmesh = \"cube\"\n", &["line 1", "`unit`", "inch"]),
        (
            "[[object]]\nmesh = \"cube\"\nfixed = \"base\"\n",
            &["line 3", "`fixed`", "base"],
        ),
        (
            "[[object]]\nmesh = \"cube\"\ntouchable = \"lid\"\n",
            &["line 3", "`touchable`", "lid"],
        ),
        (
            "[[object]]\nmesh = \"cube\"\npoisson = 0.5\n",
            &["line 3", "`poisson`"],
        ),
        (
            "[[object]]\nmesh = \"cube\"\n[haptics]\nmax_force_n = -1\n",
            &["line 4", "`max_force_n`"],
        ),
        // a script finger without a path; a path on a pointer
        (
            "[[object]]\nmesh = \"cube\"\n[[finger]]\ndevice = \"script\"\n",
            &["line 4", "`path`"],
        ),
        (
            "[[object]]\nmesh = \"cube\"\n[[finger]]\ndevice = \"pointer\"\npath = [[0, 0, 0, 0]]\n",
            &["line 5", "`path`"],
        ),
        ("unit = \"mm\"\n", &["no [[object]]"]),
        ("[[object]\nmesh = \"cube\"\n", &["line 1"]),
        (
            "[[object]]\nmesh = \"cube\"\n[[finger]]\ndevice = \"pointer\"\n[[finger]]\ndevice = \"pointer\"\n[[finger]]\ndevice = \"pointer\"\n[[finger]]\ndevice = \"pointer\"\n[[finger]]\ndevice = \"pointer\"\n",
            &["line 11", "at most 4 fingers"],
        ),
    ];
    for (text, wants) in cases {
        let e = err(text);
        for w in *wants {
            assert!(e.contains(w), "error for\n{text}\nlacks '{w}':\n{e}");
        }
        assert!(e.starts_with("t.toml"), "names the file: {e}");
    }
}

#[test]
fn a_bad_scene_on_the_command_line_is_an_error_not_a_panic() {
    let dir = tempfile::tempdir().unwrap();
    let f = dir.path().join("bad.toml");
    std::fs::write(&f, "[[object]]\nmesh = \"cube\"\nyoung = -5\n").unwrap();
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_touchfem"))
        .args(["demo", f.to_str().unwrap(), "--seconds", "0.1"])
        .env("TOUCHFEM_CACHE_DIR", "")
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{err}");
    assert!(err.contains("line 3") && err.contains("`young`"), "{err}");
    assert!(!err.contains("panicked"), "{err}");
    let missing = std::process::Command::new(env!("CARGO_BIN_EXE_touchfem"))
        .args(["demo", "nothere.toml"])
        .output()
        .unwrap();
    assert_eq!(missing.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&missing.stderr).contains("nothere.toml"));
}

// ---------------------------------------------------------------------------------------------
// Fuzzing: random and mutated scene files never panic
// ---------------------------------------------------------------------------------------------

/// Values a mutation writes: non-finite, negative, huge and tiny numbers, wrong types, arrays and
/// tables of the shapes the schema uses, filled with the same.
const FUZZ_VALUES: &[&str] = &[
    "nan",
    "inf",
    "-inf",
    "-1.0",
    "0",
    "-0.0",
    "1e308",
    "-1e308",
    "1e-320",
    "4.9e-324",
    "9223372036854775807",
    "-9223372036854775808",
    "0.49999999999999994",
    "0.5",
    "\"x\"",
    "\"\"",
    "\"cube\"",
    "\"mouse\"",
    "\"/\"",
    "\".\"",
    "\"m.msh\"",
    "\"mm\"",
    "\"script\"",
    "\"udp\"",
    "\"falcon\"",
    "true",
    "[]",
    "{}",
    "[1, 2]",
    "[nan, 0, 0]",
    "[1e308, 1e308, 1e308]",
    "[-1e308, 0, 1e308]",
    "[[0, 0, 0, 0]]",
    "[[0, 1e308, 0, 0], [1e308, 0, 0, 0]]",
    "[[-1e308, 0, 0, 0], [1e308, 0, 0, 0]]",
    "[[1e-300, 0, 0, 0], [2e-300, 0, 0, 0]]",
    "[[0, nan, 0, 0]]",
    "[[0, 0, 0]]",
    "{ center = [1e308, 0, 0], radius = 1e308 }",
    "{ center = [0, 0, 0], radius = nan }",
    "{ center = [15, 15, 30], radius = 1e-300 }",
    "{ center = [15, 15, 30], radius = 1e9 }",
    "{ max_force_n = 1e308, max_stiffness_n_per_m = inf, max_damping_ns_per_m = 0, workspace_radius_m = -1 }",
    "{ max_force_n = 5, max_stiffness_n_per_m = 1e308, max_damping_ns_per_m = 1e308, workspace_radius_m = 1e308 }",
];

/// Keys a mutation adds (the schema's and some it does not know).
const FUZZ_KEYS: &[&str] = &[
    "young",
    "poisson",
    "offset",
    "radius",
    "center",
    "rate_hz",
    "max_force_n",
    "path",
    "unit",
    "mesh",
    "mesh_unit",
    "fixed",
    "touchable",
    "name",
    "device",
    "model",
    "limits",
    "bogus",
];

/// Headers a mutation adds.
const FUZZ_TABLES: &[&str] = &["[[object]]", "[[finger]]", "[haptics]", "[object]", "[[x]]"];

#[derive(Clone, Debug)]
enum SceneMutation {
    /// Replace the n-th number of the text with a value.
    Number(usize, usize),
    /// After the n-th line, insert `key = value`.
    Key(usize, usize, usize),
    /// After the n-th line, insert a table header.
    Table(usize, usize),
    /// Delete the n-th line.
    DeleteLine(usize),
    /// Keep only this many thousandths of the text.
    Truncate(usize),
    /// Set the byte at this position (of the text's length) to an ASCII character.
    Byte(usize, u8),
}

fn scene_mutation() -> impl Strategy<Value = SceneMutation> {
    prop_oneof![
        4 => (any::<usize>(), 0..FUZZ_VALUES.len()).prop_map(|(n, v)| SceneMutation::Number(n, v)),
        4 => (any::<usize>(), 0..FUZZ_KEYS.len(), 0..FUZZ_VALUES.len())
            .prop_map(|(l, k, v)| SceneMutation::Key(l, k, v)),
        1 => (any::<usize>(), 0..FUZZ_TABLES.len()).prop_map(|(l, t)| SceneMutation::Table(l, t)),
        1 => any::<usize>().prop_map(SceneMutation::DeleteLine),
        1 => (0usize..1000).prop_map(SceneMutation::Truncate),
        1 => (any::<usize>(), 0x20u8..0x7f).prop_map(|(p, b)| SceneMutation::Byte(p, b)),
    ]
}

/// Byte ranges of the numbers in `text` (a digit run, with a sign, point and exponent).
fn numbers_in(text: &str) -> Vec<std::ops::Range<usize>> {
    let b = text.as_bytes();
    let mut out = Vec::new();
    let mut i = 0;
    while i < b.len() {
        let starts =
            b[i].is_ascii_digit() || (b[i] == b'-' && b.get(i + 1).is_some_and(u8::is_ascii_digit));
        if starts && (i == 0 || !(b[i - 1].is_ascii_alphanumeric() || b[i - 1] == b'_')) {
            let s = i;
            i += 1;
            while i < b.len() && (b[i].is_ascii_digit() || b"._eE+-".contains(&b[i])) {
                i += 1;
            }
            out.push(s..i);
        } else {
            i += 1;
        }
    }
    out
}

fn apply(text: &str, m: &SceneMutation) -> String {
    let lines: Vec<&str> = text.lines().collect();
    let insert = |after: usize, new: String| {
        let at = after % (lines.len() + 1);
        let mut l: Vec<String> = lines.iter().map(|s| s.to_string()).collect();
        l.insert(at, new);
        l.join("\n")
    };
    match *m {
        SceneMutation::Number(n, v) => {
            let nums = numbers_in(text);
            if nums.is_empty() {
                return text.to_string();
            }
            let r = nums[n % nums.len()].clone();
            format!("{}{}{}", &text[..r.start], FUZZ_VALUES[v], &text[r.end..])
        }
        SceneMutation::Key(l, k, v) => insert(l, format!("{} = {}", FUZZ_KEYS[k], FUZZ_VALUES[v])),
        SceneMutation::Table(l, t) => insert(l, FUZZ_TABLES[t].to_string()),
        SceneMutation::DeleteLine(l) => {
            let mut l2 = lines.clone();
            if !l2.is_empty() {
                l2.remove(l % lines.len());
            }
            l2.join("\n")
        }
        SceneMutation::Truncate(k) => {
            let mut at = text.len() * k / 1000;
            while !text.is_char_boundary(at) {
                at -= 1;
            }
            text[..at].to_string()
        }
        SceneMutation::Byte(p, b) => {
            let mut bytes = text.as_bytes().to_vec();
            if bytes.is_empty() {
                return text.to_string();
            }
            let at = p % bytes.len();
            // Keep the text UTF-8: only an ASCII byte is replaced.
            if bytes[at].is_ascii() {
                bytes[at] = b;
            }
            String::from_utf8(bytes).unwrap_or_else(|_| text.to_string())
        }
    }
}

/// A small scene around a mesh file `m.msh` (a mutated fixture) in the fuzz's directory.
const MESH_FILE_SCENE: &str = "unit = \"mm\"\n\n[[object]]\nmesh = \"m.msh\"\nmesh_unit = \"mm\"\nyoung = 3000.0\npoisson = 0.45\ntouchable = { center = [15, 15, 30], radius = 20 }\noffset = [0.0, 0.0, 1.0]\n\n[[finger]]\ndevice = \"script\"\npath = [[0.0, 15, 15, 40], [1.0, 15, 15, 25]]\nmodel = \"exact\"\nlimits = \"falcon\"\n\n[haptics]\nrate_hz = 2000.0\nmax_force_n = 3.0\n";

/// Bounded, deterministic fuzzing of scene files through the real parse and validate layer
/// ([`World::plan`]: everything but the precompute): the bundled scenes and a scene around a
/// mesh file, mutated (numbers replaced by NaN, inf, negative, huge and tiny values or wrong
/// types, keys and tables added, lines deleted, text truncated, bytes changed), and the mesh
/// file's bytes flipped. Nothing panics; every error is one non-empty line naming the file.
#[test]
fn fuzzed_scene_files_never_panic() {
    use proptest::test_runner::TestCaseError;
    use std::cell::Cell;
    use std::panic::{catch_unwind, AssertUnwindSafe};
    let dir = tempfile::tempdir().unwrap();
    let fixture = std::fs::read(
        std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/data/box_v41.msh"),
    )
    .unwrap();
    let mut bases: Vec<&str> = touchfem::scene::BUNDLED_SCENES
        .iter()
        .map(|(_, t)| *t)
        .collect();
    bases.push(MESH_FILE_SCENE);
    let n_bases = bases.len();
    let mut runner = crate::common::fuzz_runner(crate::common::fuzz_cases(1000));
    let (ran, ok, err) = (Cell::new(0u32), Cell::new(0u32), Cell::new(0u32));
    let strategy = (
        0..n_bases,
        proptest::collection::vec(scene_mutation(), 0..5),
        proptest::collection::vec((any::<usize>(), any::<u8>()), 0..4),
    );
    let result = runner.run(&strategy, |(base, mutations, flips)| {
        let mut text = bases[base].to_string();
        for m in &mutations {
            text = apply(&text, m);
        }
        let mut mesh = fixture.clone();
        for (at, b) in &flips {
            let i = at % mesh.len();
            mesh[i] = *b;
        }
        std::fs::write(dir.path().join("m.msh"), &mesh).unwrap();
        let src = SceneSource {
            name: "t".into(),
            text: text.clone(),
            dir: dir.path().into(),
            label: "t.toml".into(),
        };
        ran.set(ran.get() + 1);
        match catch_unwind(AssertUnwindSafe(|| World::plan(&src))) {
            Err(_) => Err(TestCaseError::fail(format!("panicked on:\n{text}"))),
            Ok(Ok(_)) => {
                ok.set(ok.get() + 1);
                Ok(())
            }
            Ok(Err(e)) => {
                err.set(err.get() + 1);
                let msg = e.to_string();
                if msg.trim().is_empty() || !msg.starts_with("t.toml") {
                    return Err(TestCaseError::fail(format!(
                        "error '{msg}' does not name the file, for:\n{text}"
                    )));
                }
                Ok(())
            }
        }
    });
    eprintln!(
        "scene fuzz: {} cases, {} Ok, {} Err",
        ran.get(),
        ok.get(),
        err.get()
    );
    if let Err(e) = result {
        panic!("{e}");
    }
    assert!(ok.get() > 0 && err.get() > 0);
}

/// Numbers too large to mean anything are refused with the key and line, before any
/// precompute: a Young's modulus above 1e13 Pa, offsets, ball centres and radii and keyframe
/// coordinates above 1e9 in magnitude, keyframe times above 1e6 s.
#[test]
fn huge_numbers_in_scene_files_name_the_key() {
    let cases: &[(&str, &[&str])] = &[
        (
            "[[object]]\nmesh = \"cube\"\nyoung = 1e300\n",
            &["line 3", "`young`"],
        ),
        (
            "[[object]]\nmesh = \"cube\"\noffset = [1e300, 0, 0]\n",
            &["line 3", "`offset`"],
        ),
        (
            "[[object]]\nmesh = \"cube\"\ntouchable = { center = [0, 0, 0], radius = 1e300 }\n",
            &["line 3", "`touchable`"],
        ),
        (
            "[[object]]\nmesh = \"cube\"\n[[finger]]\ndevice = \"script\"\npath = [[0, 0, 0, 0], [1e300, 0, 0, 0]]\n",
            &["line 5", "`path`", "keyframe 2"],
        ),
        (
            "[[object]]\nmesh = \"cube\"\n[[finger]]\ndevice = \"script\"\npath = [[0, 0, 0, 0], [1, 1e300, 0, 0]]\n",
            &["line 5", "`path`", "keyframe 2"],
        ),
    ];
    for (text, wants) in cases {
        let e = err(text);
        for w in *wants {
            assert!(e.contains(w), "error for\n{text}\nlacks '{w}':\n{e}");
        }
    }
}

/// `formulation = "locking-free"` reaches the object's stiffness (the press on the paper's
/// cube, ν = 0.49, is softer than the standard one: locking relieved) and its cache key; an
/// unknown value names the key and the line; ν = 0.5 is the typed incompressibility error,
/// naming `poisson`, for both formulations.
#[test]
fn the_formulation_key_selects_the_stiffness() {
    let dir = std::path::Path::new(".");
    let press = |extra: &str| {
        let w = load(
            &format!("unit = \"mm\"\n[[object]]\nmesh = \"cube\"\n{extra}"),
            dir,
        )
        .unwrap();
        let o = &w.objects[0];
        let p = o
            .body
            .poke(
                DVec3::new(0.015, 0.015, 0.03),
                DVec3::new(0.0, 0.0, -0.005),
                ForceModel::Paper,
                20,
            )
            .unwrap();
        (
            o.body.mesh.formulation,
            p.feedback.length(),
            touchfem::cache::key(&o.body.mesh, &Selection::default()),
        )
    };
    let (fs, std_f, std_key) = press("");
    let (fs2, _, std_key2) = press("formulation = \"standard\"\n");
    let (fl, lf_f, lf_key) = press("formulation = \"locking-free\"\n");
    assert_eq!(fs, touchfem::Formulation::Standard);
    assert_eq!(fs2, touchfem::Formulation::Standard);
    assert_eq!(fl, touchfem::Formulation::LockingFree);
    assert_eq!(std_key, std_key2, "an explicit standard keeps the key");
    assert_ne!(std_key, lf_key);
    assert!(
        lf_f < 0.9 * std_f,
        "locking-free {lf_f} N vs standard {std_f} N"
    );
    let e = err("[[object]]\nmesh = \"cube\"\nformulation = \"mixed\"\n");
    assert!(
        e.contains("line 3") && e.contains("formulation") && e.contains("locking-free"),
        "{e}"
    );
    for f in ["standard", "locking-free"] {
        let e = err(&format!(
            "[[object]]\nmesh = \"cube\"\npoisson = 0.5\nformulation = \"{f}\"\n"
        ));
        assert!(
            e.contains("line 3") && e.contains("poisson") && e.contains("incompressible"),
            "{f}: {e}"
        );
    }
}

/// `compression = { tolerance }` gives the object a hierarchical `L` to that tolerance, under
/// its own cache key; without it the same object's `L` is dense, as before.
#[test]
fn the_compression_key_stores_l_hierarchically() {
    let dir = std::path::Path::new(".");
    let dense = load("[[object]]\nmesh = \"mouse\"\n", dir).expect("dense");
    let hier = load(
        "[[object]]\nmesh = \"mouse\"\ncompression = { tolerance = 1e-3 }\n",
        dir,
    )
    .expect("hierarchical");
    let (d, h) = (
        &dense.objects[0].body.compliance,
        &hier.objects[0].body.compliance,
    );
    assert!(d.hier().is_none() && d.holds_l());
    let hm = h.hier().expect("hierarchical L");
    assert_eq!(hm.options().tolerance, 1e-3);
    // Measured on the mouse: 0.33 of the dense values.
    let ratio = hm.stored_values() as f64 / hm.dense_values() as f64;
    assert!(ratio < 0.4, "ratio {ratio}");
    assert_eq!(d.cols().len(), h.cols().len());
    assert_ne!(
        dense.hash, hier.hash,
        "the scene hash must see the compression"
    );
}

/// A value of the wrong form names the forms the key accepts (not serde's "untagged enum
/// TouchableToml" or "struct FrictionToml"), and a table is a table only: serde's derived
/// structs also take an array of their fields (`friction = [0.6, 0.4]`), a form the schema
/// does not document, so it is refused with the documented one.
#[test]
fn a_value_of_the_wrong_form_names_the_forms_the_key_takes() {
    let obj = "[[object]]\nmesh = \"cube\"\n";
    let finger = "[[object]]\nmesh = \"cube\"\n[[finger]]\ndevice = \"udp\"\n";
    let cases: &[(String, &[&str])] = &[
        (
            format!("{obj}cuttable = 42\n"),
            &[
                "line 3, column 12, key `cuttable`",
                "\"all\", a group's name, or a ball { center = [x, y, z], radius = r }",
            ],
        ),
        (
            format!("{obj}touchable = [1, 2]\n"),
            &[
                "line 3, column 13, key `touchable`",
                "\"all\", a group's name, or a ball",
            ],
        ),
        (
            format!("{obj}friction = [0.6, 0.4]\n"),
            &[
                "line 3, column 12, key `friction`",
                "friction = { static = MS, dynamic = MD }",
            ],
        ),
        (
            format!("{obj}friction = 0.6\n"),
            &[
                "line 3",
                "key `friction`",
                "friction = { static = MS, dynamic = MD }",
            ],
        ),
        (
            format!("{obj}compression = [1e-3]\n"),
            &[
                "line 3",
                "key `compression`",
                "compression = { tolerance = EPS }",
            ],
        ),
        (
            format!("{finger}tool = [8.0]\n"),
            &["line 5", "key `tool`", "tool = { sphere = R }"],
        ),
        (
            format!("{finger}limits = 42\n"),
            &["line 5", "key `limits`", "a preset's name"],
        ),
        (
            format!("{obj}region = [3]\n"),
            &["line 3", "an `[[object.region]]` table"],
        ),
    ];
    for (text, wants) in cases {
        let e = err(text);
        for w in *wants {
            assert!(e.contains(w), "error for\n{text}\nlacks '{w}':\n{e}");
        }
        for internal in ["untagged", "Toml", "struct "] {
            assert!(
                !e.contains(internal),
                "names serde's internals ({internal}): {e}"
            );
        }
        assert_eq!(e.lines().count(), 1, "one line: {e}");
    }
    // The documented form still loads.
    let w = load(
        &format!("{obj}friction = {{ static = 0.6, dynamic = 0.4 }}\n"),
        std::path::Path::new("."),
    )
    .unwrap();
    let f = w.objects[0].friction.unwrap();
    assert_eq!((f.static_mu, f.dynamic_mu), (0.6, 0.4));
}

/// A TOML syntax or type error is one line, `FILE: line L, column C[, key `K`]: MESSAGE`, like
/// the scene's other errors (the `toml` crate's own text spans five); the command prints it as
/// one `error:` line and exits 2.
#[test]
fn toml_errors_are_one_line() {
    for (text, want) in [
        ("[[object]\nmesh = \"cube\"\n", "t.toml: line 1, column "),
        (
            "[[object]]\nmesh = \"cube\"\nyoung = \n",
            "t.toml: line 3, column ",
        ),
        ("unit = 'mm\n", "t.toml: line 1, column "),
        (
            "[[object]]\nmesh = \"cube\"\ncolour = 1\n",
            "t.toml: line 3, column 1: unknown field `colour`",
        ),
    ] {
        let e = err(text);
        assert!(e.starts_with(want), "{text:?}: {e}");
        assert_eq!(e.lines().count(), 1, "{text:?}: {e}");
        assert!(!e.contains("TOML parse error") && !e.contains(" | "), "{e}");
    }
    let dir = tempfile::tempdir().unwrap();
    let f = dir.path().join("bad.toml");
    std::fs::write(&f, "[[object]]\nmesh = \"cube\"\ncuttable = 42\n").unwrap();
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_touchfem"))
        .args(["demo", f.to_str().unwrap(), "--seconds", "0.1"])
        .env("TOUCHFEM_CACHE_DIR", "")
        .output()
        .unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{stderr}");
    assert_eq!(stderr.lines().count(), 1, "{stderr}");
    assert!(
        stderr.starts_with("error: ")
            && stderr.contains("bad.toml: line 3, column 12, key `cuttable`"),
        "{stderr}"
    );
}

/// A scene's tool keeps the one rule for a user's lengths (`Tool::check_fits`, as `--sphere`
/// and `--depth`): at least 1e-6 of the object's size, and a sphere no larger than the object;
/// a radius that underflows converting to metres is too short, not a sign error.
#[test]
fn a_scene_tool_keeps_the_rule_for_lengths() {
    let scene = |tool: &str| {
        format!(
            "unit = \"mm\"\n[[object]]\nmesh = \"cube\"\n[[finger]]\ndevice = \"pointer\"\ntool = {tool}\n"
        )
    };
    for tool in [
        "{ sphere = 1e-300 }",
        "{ sphere = 5e-324 }",
        "{ blade = 1e-300 }",
        "{ blade = 5e-324 }",
        "{ sphere = 1e-5 }",
    ] {
        let e = err(&scene(tool));
        assert!(
            e.contains("line 6")
                && e.contains("is shorter than")
                && e.contains("1e-6 of its 0.05196 m across"),
            "{tool}: {e}"
        );
    }
    let e = err(&scene("{ sphere = 1e8 }"));
    assert!(
        e.contains("sphere radius 1e5 m is larger than the object (0.05196 m across)"),
        "{e}"
    );
    for ok in ["{ sphere = 1e-4 }", "{ blade = 1e-4 }", "{ sphere = 51 }"] {
        load(&scene(ok), std::path::Path::new(".")).unwrap_or_else(|e| panic!("{ok}: {e}"));
    }
}
