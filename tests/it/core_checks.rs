//! The engine's unit checks (`#[test]`s beside the code they check, in `crates/core/src`),
//! run here from the library's `self_check` registry, one test per room: the engine is not
//! compiled a second time as a unit-test harness. A check added to the engine but not to the
//! registry fails `every_unit_check_of_the_engine_is_registered`.

use touchfem_core::self_check::{all, Check};

/// The engine's rooms that have unit checks, each run by its test below.
const ROOMS: [&str; 10] = [
    "cache",
    "compliance",
    "cut",
    "devices",
    "fem",
    "haptic",
    "mesh",
    "runtime",
    "scene",
    "threads",
];

/// Runs every check of `room` (the first segment of its module path) and says how many.
fn run_room(room: &str) -> usize {
    let checks: Vec<Check> = all()
        .into_iter()
        .filter(|c| c.module.split("::").next() == Some(room))
        .collect();
    for c in &checks {
        eprintln!("{}::{}", c.module, c.name);
        (c.run)();
    }
    checks.len()
}

#[test]
fn cache_checks() {
    assert!(run_room("cache") > 0);
}

#[test]
fn compliance_checks() {
    assert!(run_room("compliance") > 0);
}

#[test]
fn cut_checks() {
    assert!(run_room("cut") > 0);
}

#[test]
fn devices_checks() {
    assert!(run_room("devices") > 0);
}

#[test]
fn fem_checks() {
    assert!(run_room("fem") > 0);
}

#[test]
fn haptic_checks() {
    assert!(run_room("haptic") > 0);
}

#[test]
fn mesh_checks() {
    assert!(run_room("mesh") > 0);
}

#[test]
fn runtime_checks() {
    assert!(run_room("runtime") > 0);
}

#[test]
fn scene_checks() {
    assert!(run_room("scene") > 0);
}

#[test]
fn threads_checks() {
    assert!(run_room("threads") > 0);
}

/// Every `#[test]` in the engine's sources is a registered check: the number of test
/// functions there equals the registry's (on Linux with `native`, where all are built), and
/// no plain `#[test]` is left (it would run only under `cargo test -p touchfem-core --lib`).
#[test]
fn every_unit_check_of_the_engine_is_registered() {
    fn walk(dir: &std::path::Path, marked: &mut usize, plain: &mut Vec<String>) {
        for e in std::fs::read_dir(dir).unwrap() {
            let p = e.unwrap().path();
            if p.is_dir() {
                walk(&p, marked, plain);
            } else if p.extension().is_some_and(|x| x == "rs") {
                let text = std::fs::read_to_string(&p).unwrap();
                *marked += text.matches("#[cfg_attr(test, test)]").count();
                if text.lines().any(|l| l.trim() == "#[test]") {
                    plain.push(p.display().to_string());
                }
            }
        }
    }
    let (mut marked, mut plain) = (0, Vec::new());
    let src = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("crates/core/src");
    walk(&src, &mut marked, &mut plain);
    assert!(
        plain.is_empty(),
        "plain #[test] in {plain:?}: make it a check"
    );
    assert!(marked > 0);
    assert_eq!(
        all().len(),
        marked,
        "a check is missing from self_check::all"
    );
    // Each check belongs to a room that has a test above.
    for c in all() {
        assert!(
            ROOMS.contains(&c.module.split("::").next().unwrap()),
            "{}",
            c.module
        );
    }
}
