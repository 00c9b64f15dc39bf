//! Mesh builders and a command runner shared by the integration tests.

use touchfem::mesh::grid_raw;
use touchfem::{LengthUnit, Material, Mesh};

/// A structured grid of `cells` cells of size `h` (metres), five tets per kept cell (see
/// [`grid_raw`]); nothing is clamped.
pub fn grid_mesh(
    cells: [usize; 3],
    h: [f64; 3],
    material: Material,
    keep: impl Fn(usize, usize, usize) -> bool,
) -> Mesh {
    let size = [0, 1, 2].map(|a| cells[a] as f64 * h[a]);
    Mesh::from_raw(grid_raw(cells, size, keep), LengthUnit::Metre, material)
        .expect("valid grid mesh")
}

/// A deterministic pseudo-random number in [0, 1) (SplitMix64).
pub fn rand01(state: &mut u64) -> f64 {
    *state = state.wrapping_add(0x9E37_79B9_7F4A_7C15);
    let mut z = *state;
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^= z >> 31;
    (z >> 11) as f64 / (1u64 << 53) as f64
}

/// Runs `touchfem ARGS` with no compliance cache, whatever its outcome: (exit status, stdout,
/// stderr).
pub fn touchfem_status(args: &[&str]) -> (i32, String, String) {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_touchfem"))
        .args(args)
        .env("TOUCHFEM_CACHE_DIR", "")
        .output()
        .expect("run touchfem");
    (
        out.status.code().unwrap_or(-1),
        String::from_utf8_lossy(&out.stdout).into_owned(),
        String::from_utf8_lossy(&out.stderr).into_owned(),
    )
}

/// Runs the `touchfem` binary with `args` and no compliance cache (so that two runs compute
/// the same bits whatever an older build left in the user's cache); asserts that it succeeded
/// and returns its standard output.
pub fn touchfem_uncached(args: &[&str]) -> Vec<u8> {
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_touchfem"))
        .args(args)
        .env("TOUCHFEM_CACHE_DIR", "")
        .output()
        .expect("run touchfem");
    assert!(
        out.status.success(),
        "touchfem {args:?}: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    out.stdout
}

/// `touchfem replay SESSION --json`, uncached, parsed.
pub fn replay_json(session: &std::path::Path) -> serde_json::Value {
    let out = touchfem_uncached(&["replay", session.to_str().expect("utf-8 path"), "--json"]);
    serde_json::from_slice(&out).expect("replay prints JSON")
}

/// A scene from its TOML text (relative paths from the working directory).
pub fn world_from_text(toml: &str) -> Result<touchfem::scene::World, touchfem::Error> {
    let src = touchfem::scene::SceneSource {
        name: "test".into(),
        text: toml.into(),
        dir: ".".into(),
        label: "test scene".into(),
    };
    touchfem::scene::World::from_source_with(&src, None)
}
