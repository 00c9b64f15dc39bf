//! Fingertip command line: `poke --sphere/--friction/--slide/--steps` and `info --sphere/--friction`
//! (docs/reference/cli.md): the numbers they print, the VTU's `contact_force`, and bad values
//! named with exit status 2.

use crate::common::touchfem_status as touchfem;

/// `touchfem ARGS --json`, asserted to succeed, parsed.
fn json(args: &[&str]) -> serde_json::Value {
    let mut all = args.to_vec();
    all.push("--json");
    let (code, out, err) = touchfem(&all);
    assert_eq!(code, 0, "{all:?}: {err}");
    serde_json::from_str(out.trim()).unwrap_or_else(|e| panic!("not JSON ({e}): {out}"))
}

fn vec3(v: &serde_json::Value) -> [f64; 3] {
    let a: Vec<f64> = v
        .as_array()
        .unwrap_or_else(|| panic!("not an array: {v}"))
        .iter()
        .map(|x| x.as_f64().unwrap())
        .collect();
    [a[0], a[1], a[2]]
}

fn trace(v: &serde_json::Value) -> Vec<[f64; 4]> {
    v["trace"]
        .as_array()
        .unwrap_or_else(|| panic!("no trace: {v}"))
        .iter()
        .map(|e| {
            let e: Vec<f64> = e
                .as_array()
                .unwrap()
                .iter()
                .map(|x| x.as_f64().unwrap())
                .collect();
            assert_eq!(e.len(), 4, "{e:?}");
            [e[0], e[1], e[2], e[3]]
        })
        .collect()
}

const TOP: [&str; 6] = ["poke", "cube", "--at", "15,15,30", "--push", "0,0,-3"];

fn with<'a>(base: &[&'a str], extra: &[&'a str]) -> Vec<&'a str> {
    base.iter().chain(extra).copied().collect()
}

#[test]
fn a_sphere_presses_back_at_least_as_hard_as_a_point_at_the_same_depth() {
    let point = json(&TOP);
    let sphere = json(&with(&TOP, &["--sphere", "8"]));
    let fp = vec3(&point["force"]);
    let fs = vec3(&sphere["force"]);
    assert!(fs.iter().all(|x| x.is_finite()), "{fs:?}");
    assert!(fs[2] > 0.0, "{fs:?}");
    // By symmetry about x = y = 15 mm the force is vertical.
    assert!(
        fs[0].abs() <= 1e-9 * fs[2] && fs[1].abs() <= 1e-9 * fs[2],
        "{fs:?}"
    );
    assert_eq!(sphere["tool"], "sphere");
    assert!((sphere["sphere_m"].as_f64().unwrap() - 0.008).abs() < 1e-15);
    let nodes = sphere["contact_nodes"].as_array().unwrap();
    assert!(!nodes.is_empty(), "{sphere}");
    // R = 8 mm on the cube's 7.5 mm grid, 3 mm deep: above the top centre node's neighbours
    // the sphere is 8 − √(8² − 7.5²) = 5.2 mm above its bottom, 2.2 mm above the rest top,
    // and they only sink: it presses that one node as the point does, with the same force.
    assert!(fs[2] >= fp[2] * (1.0 - 1e-9), "sphere {fs:?} point {fp:?}");
    // The sphere's bottom sinks by the push: the node under it moves 3 mm.
    let u = sphere["max_displacement"].as_f64().unwrap();
    assert!((u - 0.003).abs() < 1e-9, "{u}");
    // The start centre is R above the touched point along the top's normal, the end centre
    // 3 mm lower.
    let c0 = vec3(&sphere["start_centre"]);
    let c1 = vec3(&sphere["centre"]);
    assert!(
        (c0[2] - 0.038).abs() < 1e-12 && (c1[2] - 0.035).abs() < 1e-12,
        "{c0:?} {c1:?}"
    );
    // A wider sphere deeper presses a patch of nodes: more force than a point at that depth.
    let push5 = ["poke", "cube", "--at", "15,15,30", "--push", "0,0,-5"];
    let fp5 = vec3(&json(&push5)["force"]);
    let wide = json(&with(&push5, &["--sphere", "20"]));
    let fw = vec3(&wide["force"]);
    assert!(
        wide["contact_nodes"].as_array().unwrap().len() >= 5,
        "{wide}"
    );
    assert!(fw[2] > 1.2 * fp5[2], "sphere {fw:?} point {fp5:?}");
    // The point finger's contact nodes: the touched node alone (area coordinates 1, 0, 0).
    assert_eq!(point["contact_nodes"], serde_json::json!([112]));
    assert_eq!(point["tool"], "point");
    // Pulled away: not in contact, no nodes.
    let free = json(&["poke", "cube", "--at", "15,15,30", "--push", "0,0,3"]);
    assert_eq!(free["contact_nodes"], serde_json::json!([]));
    let free_s = json(&[
        "poke", "cube", "--at", "15,15,30", "--push", "0,0,3", "--sphere", "8",
    ]);
    assert_eq!(free_s["contact_nodes"], serde_json::json!([]));
    assert_eq!(vec3(&free_s["force"]), [0.0; 3]);
}

#[test]
fn a_sliding_sphere_stays_inside_the_static_cone() {
    let v = json(&with(
        &TOP,
        &[
            "--sphere",
            "8",
            "--slide",
            "5,0,0",
            "--steps",
            "10",
            "--friction",
            "0.6,0.4",
        ],
    ));
    assert_eq!(v["friction"], serde_json::json!([0.6, 0.4]));
    let t = trace(&v);
    assert_eq!(t.len(), 10);
    for (k, e) in t.iter().enumerate() {
        assert!(e.iter().all(|x| x.is_finite()), "step {k}: {e:?}");
        assert!(
            (e[0] - 0.0005 * (k + 1) as f64).abs() < 1e-12,
            "step {k}: {e:?}"
        );
        assert!(e[3] > 0.0, "step {k}: {e:?}");
        // The finger is dragged along +x: friction pulls it back.
        assert!(e[1] <= 0.0, "step {k}: {e:?}");
        let ft = (e[1] * e[1] + e[2] * e[2]).sqrt();
        assert!(ft <= 0.6 * e[3] * (1.0 + 1e-6) + 1e-12, "step {k}: {e:?}");
    }
    assert!((t[9][0] - 0.005).abs() < 1e-12);
    // The last entry is the final force.
    let f = vec3(&v["force"]);
    assert_eq!([t[9][1], t[9][2], t[9][3]], f);
    assert!(!v["contact_nodes"].as_array().unwrap().is_empty());
    // Slipping at the end: the whole patch at the dynamic cone's edge.
    assert!(v["patch"]["slipping"].as_u64().unwrap() > 0, "{v}");
    assert!((f[0].abs() / f[2] - 0.4).abs() < 1e-3, "{f:?}");
}

#[test]
fn a_sliding_point_sticks_then_slips_at_the_dynamic_coefficient() {
    // 3 mm deep, dragged 8 mm along x in 40 steps of 0.2 mm: the god-object sticks until
    // |F_x| reaches 0.5 F_z (at about 4 mm on this cube: 4 mm only just stays inside), then
    // slides with |F_x| = 0.3 F_z.
    let v = json(&with(
        &TOP,
        &["--friction", "0.5,0.3", "--slide", "8,0,0", "--steps", "40"],
    ));
    let t = trace(&v);
    assert_eq!(t.len(), 40);
    let ratio = |e: &[f64; 4]| e[1].abs() / e[3];
    // Slipping starts where the ratio first drops (from the static cone to the dynamic one).
    let first_slip = (1..t.len())
        .find(|&k| ratio(&t[k]) < ratio(&t[k - 1]))
        .unwrap_or_else(|| panic!("never slips: {t:?}"));
    assert!(first_slip >= 5, "slipped at once: {t:?}");
    for (k, e) in t.iter().enumerate() {
        assert!(e.iter().all(|x| x.is_finite()), "step {k}: {e:?}");
        assert!(e[3] > 0.0 && e[1] <= 0.0, "step {k}: {e:?}");
        if k < first_slip {
            // Stuck: the tangential force grows inside the static cone.
            assert!(ratio(e) < 0.5, "step {k}: {e:?}");
            if k > 0 {
                assert!(ratio(e) > ratio(&t[k - 1]), "step {k}: {e:?}");
            }
        } else {
            assert!((ratio(e) / 0.3 - 1.0).abs() < 0.01, "step {k}: {e:?}");
        }
    }
    assert!(ratio(&t[first_slip - 1]) > 0.45, "{t:?}");
    // The stuck proxy has moved off the start node: two nodes of the triangle carry force.
    assert_eq!(v["contact_nodes"].as_array().unwrap().len(), 2, "{v}");
    // Friction without a slide: pressing straight down feels the frictionless force.
    let plain = vec3(&json(&TOP)["force"]);
    let fr = json(&with(&TOP, &["--friction", "0.5,0.3"]));
    assert!(fr.get("trace").is_none());
    let f = vec3(&fr["force"]);
    for k in 0..3 {
        assert!(
            (f[k] - plain[k]).abs() <= 1e-12 * plain[2],
            "{f:?} {plain:?}"
        );
    }
    // No friction: nothing resists the slide (the paper's interpolation between the nodes
    // even pushes the finger on a little: fx ≥ 0).
    let v0 = json(&with(&TOP, &["--slide", "4,0,0", "--steps", "8"]));
    assert_eq!(trace(&v0).len(), 8);
    for e in trace(&v0) {
        assert!(e[1] >= -1e-12 * e[3] && e[3] > 0.0, "{e:?}");
    }
}

/// The numbers of the VTU's point array `name` (3 components per node).
fn vtu_array(text: &str, name: &str, nodes: usize) -> Vec<[f64; 3]> {
    let block = text
        .split(&format!(
            "Name=\"{name}\" NumberOfComponents=\"3\" format=\"ascii\">\n"
        ))
        .nth(1)
        .unwrap_or_else(|| panic!("no {name} array"));
    block
        .lines()
        .take(nodes)
        .map(|l| {
            let x: Vec<f64> = l.split_whitespace().map(|x| x.parse().unwrap()).collect();
            [x[0], x[1], x[2]]
        })
        .collect()
}

#[test]
fn the_vtu_holds_the_contact_forces_equal_and_opposite_to_the_feedback() {
    let dir = tempfile::tempdir().unwrap();
    for (name, extra) in [
        ("sphere", &["--sphere", "20", "--push", "0,0,-5"][..]),
        (
            "slide",
            &[
                "--sphere",
                "8",
                "--slide",
                "5,0,0",
                "--steps",
                "10",
                "--friction",
                "0.6,0.4",
            ][..],
        ),
        ("point", &["--friction", "0.5,0.3", "--slide", "8,0,0"][..]),
    ] {
        let path = dir.path().join(format!("{name}.vtu"));
        let base = ["poke", "cube", "--at", "15,15,30"];
        let mut args = with(&base, extra);
        if !extra.contains(&"--push") {
            args.extend(["--push", "0,0,-3"]);
        }
        args.extend(["--vtu", path.to_str().unwrap()]);
        let v = json(&args);
        let f = vec3(&v["force"]);
        let text = std::fs::read_to_string(&path).unwrap();
        let cf = vtu_array(&text, "contact_force", 125);
        let force = vtu_array(&text, "force", 125);
        assert_eq!(cf.len(), 125);
        // For a sphere or a point the nodal forces are the contact forces.
        assert_eq!(cf, force, "{name}");
        let sum = cf
            .iter()
            .fold([0.0; 3], |s, x| [s[0] + x[0], s[1] + x[1], s[2] + x[2]]);
        let norm = f.iter().map(|x| x * x).sum::<f64>().sqrt();
        assert!(norm > 0.1, "{name}: {f:?}");
        for k in 0..3 {
            assert!(
                (sum[k] + f[k]).abs() <= 1e-9 * norm,
                "{name}: sum {sum:?} against the force {f:?}"
            );
        }
        // Non-zero exactly on the contact nodes.
        let loaded: Vec<u64> = (0..125u64)
            .filter(|&i| cf[i as usize] != [0.0; 3])
            .collect();
        let mut nodes: Vec<u64> = v["contact_nodes"]
            .as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_u64().unwrap())
            .collect();
        nodes.sort_unstable();
        assert_eq!(loaded, nodes, "{name}");
        // The displacement array's largest magnitude is max_displacement.
        let u = vtu_array(&text, "displacement", 125);
        let max_u = u
            .iter()
            .map(|x| (x[0] * x[0] + x[1] * x[1] + x[2] * x[2]).sqrt())
            .fold(0.0, f64::max);
        let want = v["max_displacement"].as_f64().unwrap();
        assert!(
            (max_u - want).abs() <= 1e-9 * want,
            "{name}: {max_u} {want}"
        );
    }
}

/// Asserts exit status 2, exactly one `error:` line on stderr, naming `flag`, and no panic.
fn assert_named(args: &[&str], flag: &str) {
    let (code, _, err) = touchfem(args);
    assert_eq!(code, 2, "{args:?}: {err}");
    assert!(!err.contains("panicked"), "{args:?} panicked: {err}");
    let errors: Vec<&str> = err.lines().filter(|l| l.starts_with("error:")).collect();
    assert!(err.starts_with("error:"), "{args:?}: {err}");
    assert_eq!(errors.len(), 1, "{args:?}: {err}");
    assert!(
        errors[0].contains(flag),
        "{args:?}: should name {flag}: {err}"
    );
}

#[test]
fn bad_fingertip_values_name_the_flag_and_exit_2() {
    let bad: &[(&str, &str)] = &[
        ("--sphere", "0"),
        ("--sphere", "-1"),
        ("--sphere", "nan"),
        ("--sphere", "inf"),
        ("--sphere", "1e6"),
        ("--sphere", "abc"),
        ("--friction", "-0.1,0"),
        ("--friction", "0.3,0.5"),
        ("--friction", "nan,0"),
        ("--friction", "0.3,nan"),
        ("--friction", "0.3"),
        ("--slide", "1,nan,0"),
        ("--slide", "1,0"),
        ("--slide", "1e300,0,0"),
        ("--steps", "0"),
    ];
    for &(flag, value) in bad {
        assert_named(&with(&TOP, &[flag, value]), flag);
        assert_named(
            &with(&TOP, &["--sphere", "8", "--slide", "1,0,0", flag, value]),
            flag,
        );
        if flag == "--sphere" || flag == "--friction" {
            assert_named(&["info", "cube", flag, value], flag);
        }
    }
    // Just larger than the cube's diagonal (30√3 = 51.96 mm).
    assert_named(&["info", "cube", "--sphere", "52"], "--sphere");
    assert_named(&with(&TOP, &["--sphere", "52"]), "--sphere");
    // The sphere has no paper/exact force model.
    assert_named(&with(&TOP, &["--sphere", "8", "--exact"]), "--sphere");
}

#[test]
fn info_checks_and_echoes_the_tool() {
    let v = json(&["info", "cube", "--sphere", "8", "--friction", "0.6,0.4"]);
    assert!(
        (v["sphere_m"].as_f64().unwrap() - 0.008).abs() < 1e-15,
        "{v}"
    );
    assert_eq!(v["friction"], serde_json::json!([0.6, 0.4]));
    assert_eq!(v["nodes"], 125);
    // Equal coefficients are allowed; without the flags the keys are absent.
    let v = json(&["info", "cube", "--friction", "0.5,0.5"]);
    assert_eq!(v["friction"], serde_json::json!([0.5, 0.5]));
    assert!(v.get("sphere_m").is_none());
    let v = json(&["info", "cube"]);
    assert!(v.get("sphere_m").is_none() && v.get("friction").is_none());
    // The whole cube's diagonal (52 mm) still fits.
    json(&["info", "cube", "--sphere", "51"]);
}

#[test]
fn poke_without_the_new_flags_is_unchanged() {
    // tests/it/cli.rs's Fig. 1b: the top centre node moves exactly 5 mm, no sideways force,
    // paper = exact on a node; the same force as the point finger through the slide path
    // with zero friction and no slide.
    let v = json(&["poke", "cube", "--at", "15,15,30", "--push", "0,0,-5"]);
    let f = vec3(&v["force"]);
    assert!(f[2] > 0.1 && f[2] < 10.0, "{f:?}");
    assert!(f[0].abs() < 1e-9 * f[2] && f[1].abs() < 1e-9 * f[2]);
    assert!((v["max_displacement"].as_f64().unwrap() - 0.005).abs() < 1e-12);
    assert_eq!(v["paper_exact_difference"].as_f64().unwrap(), 0.0);
    assert_eq!(v["model"], "paper");
    assert!(v.get("trace").is_none() && v.get("friction").is_none());
    let z = json(&crate::common::poke_cube(&["--friction", "0,0"]));
    assert_eq!(z["force"], v["force"]);
    // The text output names the finger.
    let (code, out, err) = touchfem(&with(&TOP, &["--sphere", "8"]));
    assert_eq!(code, 0, "{err}");
    assert!(
        out.contains("(sphere)") && out.contains("1 node(s) in contact"),
        "{out}"
    );
}

/// One rule for every length a user gives (`Tool::check_fits` and `check_length`): a tool's
/// size (`--sphere`, `--depth`, a scene's `tool`) and a finger's motion (`--push`, `--slide`,
/// unless zero) is at least 1e-6 of the object's size, and a sphere is no larger than the
/// object. The same typed error, exit 2, whether the value is 1e-300 or underflows to 0 m
/// converting from mm; a huge value's message stays short.
#[test]
fn one_rule_for_every_length_a_user_gives() {
    const CUT: [&str; 2] = ["--cut", "5,15,30:25,15,30"];
    let poke = |extra: &[&str]| {
        let mut a = vec!["poke", "cube", "--at", "15,15,30", "--push", "0,0,-1"];
        a.extend_from_slice(extra);
        a.into_iter().map(String::from).collect::<Vec<_>>()
    };
    let too_short: Vec<(Vec<String>, &str)> = vec![
        (
            poke(&[CUT[0], CUT[1], "--depth", "1e-300"]),
            "--depth 1e-300: blade depth",
        ),
        (
            poke(&[CUT[0], CUT[1], "--depth", "5e-324"]),
            "--depth 5e-324: blade depth 0 m",
        ),
        (
            poke(&["--sphere", "5e-324"]),
            "--sphere 5e-324: sphere radius 0 m",
        ),
        (
            poke(&["--sphere", "1e-300"]),
            "--sphere 1e-300: sphere radius 1e-303 m",
        ),
        (
            ["info", "cube", "--sphere", "5e-324"]
                .map(String::from)
                .to_vec(),
            "--sphere 5e-324: sphere radius 0 m",
        ),
        (
            ["poke", "cube", "--at", "15,15,30", "--push", "0,0,-1e-300"]
                .map(String::from)
                .to_vec(),
            "--push 0,0,-1e-300: push 1e-303 m",
        ),
        (
            poke(&["--slide", "5e-324,0,0"]),
            "--slide 5e-324,0,0: slide 0 m",
        ),
        (
            ["view", "cube", "--sphere", "5e-324"]
                .map(String::from)
                .to_vec(),
            "--sphere 5e-324: sphere radius 0 m",
        ),
    ];
    for (args, want) in &too_short {
        let a: Vec<&str> = args.iter().map(String::as_str).collect();
        let (code, _, err) = touchfem(&a);
        assert_eq!(code, 2, "{a:?}: {err}");
        assert!(
            err.starts_with("error: ") && err.lines().count() == 1,
            "{err}"
        );
        assert!(
            err.contains(want)
                && err.contains(
                    "is shorter than 5.196e-8 m, the smallest length touchfem resolves on this \
                     object (1e-6 of its 0.05196 m across)"
                ),
            "{a:?}: {err}"
        );
    }
    // 1 µm is a length the cube resolves, and a motion of zero is allowed.
    let (code, out, err) = touchfem(
        &poke(&[CUT[0], CUT[1], "--depth", "1e-3", "--json"])
            .iter()
            .map(String::as_str)
            .collect::<Vec<_>>(),
    );
    assert_eq!(code, 0, "{err}");
    let v: serde_json::Value = serde_json::from_str(out.trim()).unwrap();
    assert!(v["tets_removed"].as_u64().is_some(), "{v}");
    assert_eq!(v["blade"]["depth_m"].as_f64(), Some(1e-6));
    let v = json(&["poke", "cube", "--at", "15,15,30", "--push", "0,0,0"]);
    assert_eq!(vec3(&v["force"]), [0.0; 3]);
    // Too large: short messages, whatever the number (no 309-digit radius).
    for (args, want) in [
        (
            &["info", "cube", "--sphere", "1e308"][..],
            "sphere radius 1e308 must be a positive, finite length of at most 1e9",
        ),
        (
            &[
                "poke", "cube", "--at", "15,15,30", "--push", "0,0,-1", "--sphere", "1e9",
            ],
            "--sphere 1e9: sphere radius 1e6 m is larger than the object (0.05196 m across)",
        ),
        (
            &[
                "poke", "cube", "--at", "15,15,30", "--push", "0,0,-1", "--sphere", "1e308",
            ],
            "sphere radius 1e308 must be a positive, finite length of at most 1e9",
        ),
        (
            &[
                "poke", "cube", "--at", "15,15,30", "--push", "0,0,-1", "--young", "1e300",
            ],
            "1e300 is outside (0, 10000000000000]",
        ),
    ] {
        let (code, _, err) = touchfem(args);
        assert_eq!(code, 2, "{args:?}: {err}");
        assert!(err.contains(want), "{args:?}: {err}");
        assert!(err.len() < 300, "{args:?}: {} bytes: {err}", err.len());
    }
}

/// `view` checks `--sphere` as `poke`, `info` and a scene's `tool` do (it used to start with
/// `view cube --sphere 1e9` and flatten a face), before any window opens; on a mesh the
/// pointer becomes the sphere.
#[test]
fn view_checks_its_sphere_as_every_command_does() {
    for (scene, r, want) in [
        (
            "cube",
            "1e9",
            "--sphere 1e9: sphere radius 1e6 m is larger than the object (0.05196 m across)",
        ),
        (
            "cube",
            "52",
            "--sphere 52: sphere radius 0.052 m is larger than the object (0.05196 m across)",
        ),
        (
            "cube",
            "1e-300",
            "--sphere 1e-300: sphere radius 1e-303 m is shorter than 5.196e-8 m",
        ),
        (
            "palpate",
            "1e9",
            "--sphere 1e9: sphere radius 1e6 m is larger than the object (0.07483 m across)",
        ),
        (
            "palpate",
            "1e-300",
            "--sphere 1e-300: sphere radius 1e-303 m is shorter than 7.483e-8 m",
        ),
    ] {
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_touchfem"))
            .args(["view", scene, "--sphere", r])
            .env("TOUCHFEM_CACHE_DIR", "")
            .env("TOUCHFEM_VIEW_SECONDS", "0")
            .env_remove("DISPLAY")
            .env_remove("WAYLAND_DISPLAY")
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&out.stderr);
        assert_eq!(out.status.code(), Some(2), "{scene} {r}: {err}");
        assert!(err.contains(want), "{scene} {r}: {err}");
    }
    use touchfem_app::window::cli::load_with_pointer_as;
    let w = load_with_pointer_as("cube", None, Some(8.0)).unwrap();
    assert_eq!(w.fingers.len(), 1);
    assert_eq!(w.fingers[0].tool.radius(), Some(0.008));
}

/// The window's `|F|` ([`touchfem_app::window::force_readout`]) reads the force of a scripted
/// fingertip that presses, not only the pointer's: `view palpate` read 0.00 N while its
/// fingertip visibly pressed, because the readout was the pointer finger's, which touched
/// nothing. Here the palpate fingertip is driven to its press (3 mm into the top face) with
/// the pointer lifted.
#[test]
fn the_force_readout_is_the_pressing_fingers() {
    use glam::DVec3;
    use touchfem::runtime::{HapticWorld, WorldSample};
    use touchfem_app::window::cli::load_with_pointer;
    let w = load_with_pointer("palpate", None).unwrap();
    assert_eq!(w.fingers.len(), 2, "the fingertip and the pointer");
    let mut hw = HapticWorld::new(&w);
    let mut sample = WorldSample::default();
    let mut f = [DVec3::ZERO; 2];
    // The script's first second: from 34 mm down to 25 mm (its centre), 8 mm radius.
    for k in 0..=1000 {
        let z = 34.0 - 9.0 * (k as f64 / 1000.0);
        let tip = DVec3::new(-24.0, 0.0, z) * 1e-3;
        hw.step(&[tip, DVec3::NAN], &mut f, &mut sample);
    }
    let tip = sample.fingers()[0].force.length();
    let pointer = sample.fingers()[1].force.length();
    assert!(tip > 0.05 && tip < 8.5, "the fingertip presses: {tip} N");
    assert_eq!(pointer, 0.0);
    assert_eq!(touchfem_app::window::force_readout(&sample), tip);
    // Nothing touching: 0.
    assert_eq!(
        touchfem_app::window::force_readout(&WorldSample::default()),
        0.0
    );
}
