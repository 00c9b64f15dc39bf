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

/// The bundled `incision` scene run through the haptic path with a cutter applied in step (a
/// pass every 20 ms, folding at `fold_rank`), as the demo runs it on the cutter's thread.
pub struct IncisionRun {
    /// The scene.
    pub world: touchfem::scene::World,
    /// The sample at t = 6 s (the fingertip pressing beside the open cut).
    pub sample: touchfem::runtime::WorldSample,
    /// The fingertip's force at the end of the press before the cut (t = 1.2 s) and at 6 s.
    pub before: glam::DVec3,
    /// See `before`.
    pub after: glam::DVec3,
    /// The final cut body.
    pub body: std::sync::Arc<touchfem::runtime::cutting::CutBody>,
    /// The tets it removed.
    pub removed: Vec<bool>,
    /// The cut's nodes at rest at the end (copies after the mesh's), m.
    pub cut_nodes: Vec<glam::DVec3>,
    /// The cut's tets not removed at the end (naming copies on a split's further side).
    pub cut_tets: Vec<[u32; 4]>,
    /// The strokes of each pass of the cutter, in order.
    pub passes: Vec<Vec<touchfem::runtime::cutting::Stroke>>,
}

/// See [`IncisionRun`]; every force is checked finite and within the bound on the way.
pub fn run_incision(fold_rank: usize) -> IncisionRun {
    run_incision_in(
        fold_rank,
        touchfem::runtime::cutting::FoldMode::Deferred,
        touchfem::runtime::cutting::CutMode::Remove,
    )
}

/// A cutter's passes as its thread makes them, synchronously: the folds finished since the
/// last pass adopted first (each with a body of its own; half of the cuts since its snapshot
/// made again by `Folded::catch_up`, as the fold's thread does, the rest by the adoption),
/// then the strokes, then the folds due handed out and run at once, to be adopted at the next
/// pass. In [`FoldMode::Inline`] the cutter folds by itself.
#[derive(Default)]
pub struct CutPasses {
    ready: Vec<touchfem::runtime::cutting::Folded>,
    /// Folds adopted.
    pub adopted: usize,
}

impl std::fmt::Debug for CutPasses {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} fold(s) waiting, {} adopted",
            self.ready.len(),
            self.adopted
        )
    }
}

impl CutPasses {
    /// One pass of `cutter` over `strokes`: the bodies made, in order.
    pub fn pass(
        &mut self,
        cutter: &mut touchfem::runtime::cutting::Cutter,
        strokes: &[touchfem::runtime::cutting::Stroke],
    ) -> Vec<(usize, std::sync::Arc<touchfem::runtime::cutting::CutBody>)> {
        let mut out = Vec::new();
        for mut f in self.ready.drain(..) {
            let o = f.object();
            // Half of the cuts since the snapshot made again as the fold's thread would, the
            // rest by the adoption.
            let ops = cutter.fold_ops(o);
            f.catch_up(&ops[..ops.len() / 2])
                .expect("the fold catches up");
            cutter.adopt(f).expect("a fold is adopted");
            out.push((o, cutter.body_now(o).expect("the adopted body")));
            self.adopted += 1;
        }
        let bodies = cutter.apply_all(strokes).expect("a cut never errors");
        let any = !bodies.is_empty();
        out.extend(bodies);
        if any {
            for job in cutter.take_folds().expect("folds handed out") {
                self.ready.push(job.run().1.expect("a fold runs"));
            }
            cutter.fold_due().expect("an inline fold");
        }
        out
    }
}

/// The incision with a blade that removes (the default), its correction carried whole
/// (`run_incision(usize::MAX)`): run once for every test that reads it.
pub fn removing_incision() -> &'static IncisionRun {
    static RUN: std::sync::OnceLock<IncisionRun> = std::sync::OnceLock::new();
    RUN.get_or_init(|| run_incision(usize::MAX))
}

/// The incision with a blade that separates (`CutMode::Separate`), its correction carried
/// whole: run once for every test that reads it.
pub fn separated_incision() -> &'static IncisionRun {
    static RUN: std::sync::OnceLock<IncisionRun> = std::sync::OnceLock::new();
    RUN.get_or_init(|| {
        run_incision_in(
            usize::MAX,
            touchfem::runtime::cutting::FoldMode::Deferred,
            touchfem::runtime::cutting::CutMode::Separate,
        )
    })
}

/// [`run_incision`] with the cutter folding in `mode` and its blade cutting as `cut` says.
pub fn run_incision_in(
    fold_rank: usize,
    mode: touchfem::runtime::cutting::FoldMode,
    cut: touchfem::runtime::cutting::CutMode,
) -> IncisionRun {
    use glam::DVec3;
    use touchfem::runtime::cutting::Cutter;
    use touchfem::runtime::{HapticWorld, WorldSample};
    use touchfem::scene::{DeviceSpec, World};
    let world = World::load_with("incision", "script", None).expect("incision");
    let keys: Vec<Vec<(f64, DVec3)>> = world
        .fingers
        .iter()
        .map(|f| match &f.device {
            DeviceSpec::Script(k) => k.clone(),
            _ => panic!("scripted fingers"),
        })
        .collect();
    let at = |k: &[(f64, DVec3)], t: f64| {
        let i = k.iter().rposition(|k| k.0 <= t).unwrap_or(0);
        match k.get(i + 1) {
            None => k[i].1,
            Some(n) => k[i]
                .1
                .lerp(n.1, ((t - k[i].0) / (n.0 - k[i].0)).clamp(0.0, 1.0)),
        }
    };
    let mut cutter = Cutter::new(&world).unwrap();
    cutter.set_fold_rank(fold_rank);
    cutter.set_fold_mode(mode);
    cutter.set_cut_mode(cut);
    let mut passes = CutPasses::default();
    let mut strokes_of = Vec::new();
    let bound = world.haptics.max_force_n;
    let (sample, before, after, body) = {
        let mut hw = HapticWorld::new(&world);
        let mut sample = WorldSample::default();
        let mut f = [DVec3::ZERO; 2];
        let mut before = DVec3::ZERO;
        let mut strokes = Vec::new();
        for k in 0..=6000 {
            let t = k as f64 / 1000.0;
            hw.step(&[at(&keys[0], t), at(&keys[1], t)], &mut f, &mut sample);
            assert!(f
                .iter()
                .all(|v| v.is_finite() && v.length() <= bound + 1e-12));
            strokes.extend_from_slice(hw.strokes());
            if k % 20 == 0 {
                strokes_of.push(strokes.clone());
                for (o, body) in passes.pass(&mut cutter, &strokes) {
                    hw.install_cut(o, body);
                }
                strokes.clear();
            }
            if k == 1200 {
                before = f[0];
            }
        }
        let body = hw.cut_body(0).expect("the blade cut").clone();
        (sample, before, f[0], body)
    };
    let removed = cutter.removed(0).unwrap().to_vec();
    let cut = cutter.cut(0).expect("the tissue is cuttable");
    let cut_nodes = cut.nodes().to_vec();
    let cut_tets = (cut.tets().iter().zip(&removed))
        .filter(|(_, &r)| !r)
        .map(|(t, _)| *t)
        .collect();
    IncisionRun {
        world,
        sample,
        before,
        after,
        body,
        removed,
        cut_nodes,
        cut_tets,
        passes: strokes_of,
    }
}

/// Area-weighted unit normals of `tris` (row indices) at positions `x`: what the GPU's normal
/// pass computes.
pub fn cpu_normals(x: &[glam::DVec3], tris: &[[u32; 3]]) -> Vec<glam::DVec3> {
    let mut n = vec![glam::DVec3::ZERO; x.len()];
    for t in tris {
        let [a, b, c] = t.map(|i| x[i as usize]);
        let f = (b - a).cross(c - a);
        for &i in t {
            n[i as usize] += f;
        }
    }
    n.iter().map(|v| v.normalize_or_zero()).collect()
}

/// The paper's poke on the bundled cube, `poke cube --at 15,15,30 --push 0,0,-5`, followed by
/// `extra`.
pub fn poke_cube<'a>(extra: &[&'a str]) -> Vec<&'a str> {
    let mut args = vec!["poke", "cube", "--at", "15,15,30", "--push", "0,0,-5"];
    args.extend_from_slice(extra);
    args
}

/// A proptest runner for `cases` cases from a fixed ChaCha seed (the same cases every run),
/// writing no regression files.
pub fn fuzz_runner(cases: u32) -> proptest::test_runner::TestRunner {
    use proptest::test_runner::{Config, RngAlgorithm, TestRng, TestRunner};
    let config = Config {
        cases,
        failure_persistence: None,
        rng_algorithm: RngAlgorithm::ChaCha,
        ..Config::default()
    };
    TestRunner::new_with_rng(config, TestRng::deterministic_rng(RngAlgorithm::ChaCha))
}

/// `TOUCHFEM_FUZZ_CASES` when set (`TOUCHFEM_FUZZ_CASES=N` runs a deeper search than CI's few
/// seconds), else `default`.
pub fn fuzz_cases(default: u32) -> u32 {
    std::env::var("TOUCHFEM_FUZZ_CASES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

/// A small deterministic xorshift generator (seed it with a nonzero value).
pub struct Xorshift(pub u64);

impl Xorshift {
    /// The next 64 bits.
    pub fn next(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }
    /// A number in `0..n` (0 when `n` is 0).
    pub fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
}

/// The native GPU tests' tolerance for a vertex position against `rest + u` in f64: 1e-5 of the
/// largest displacement plus 4 f32 ulps of the largest rest coordinate. Returns (tolerance,
/// max |u|), m.
pub fn gpu_tolerance(u: &[glam::DVec3], rest: &[glam::DVec3]) -> (f64, f64) {
    let umax = u.iter().fold(0.0f64, |m, v| m.max(v.abs().max_element()));
    let xmax = rest
        .iter()
        .fold(0.0f64, |m, v| m.max(v.abs().max_element()));
    (1e-5 * umax + 4.0 * f64::from(f32::EPSILON) * xmax, umax)
}

/// The relative error `‖a − b‖ / ‖b‖` of two displacement fields (node by node).
pub fn rel_err(a: &[glam::DVec3], b: &[glam::DVec3]) -> f64 {
    assert_eq!(a.len(), b.len());
    let num: f64 = a
        .iter()
        .zip(b)
        .map(|(x, y)| (*x - *y).length_squared())
        .sum();
    let den: f64 = b.iter().map(|y| y.length_squared()).sum();
    (num / den).sqrt()
}
