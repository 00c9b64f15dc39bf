//! Golden frames of the paper's cube, compared with NVIDIA's FLIP metric (`nv-flip`).
//!
//! * `golden/cube_rest.png`: at rest;
//! * `golden/cube_push_top.png`: the god-object on the top-centre node (15, 15, 30) mm, the
//!   finger 5 mm below it: `F = L_ii⁻¹·(0, 0, −5 mm)`;
//! * `golden/cube_push_side.png`: the god-object on (0, 15, 15) mm, the finger 5 mm inside:
//!   `F = L_ii⁻¹·(+5 mm, 0, 0)`.
//!
//! A frame passes when its mean FLIP against the golden is at most [`MEAN_FLIP_THRESHOLD`]. On a
//! failure `golden/<name>.actual.png` and `golden/<name>.diff.png` (FLIP error map, magma) are
//! written next to the golden. Run with `TOUCHFEM_UPDATE_GOLDEN=1` to regenerate the goldens.
//! Needs a GPU adapter (fails without one): `WGPU_BACKEND=vulkan cargo test --test golden`.

use std::path::PathBuf;
use std::sync::OnceLock;

use glam::DVec3;
use touchfem::compliance::{Compliance, Selection};
use touchfem::gpu::Gpu;
use touchfem::mesh::{cube, Mesh};
use touchfem::render::{Renderer, Scene};

/// Largest mean FLIP error accepted against a golden frame. Renders on one driver are
/// bit-identical (0.0); this leaves room for other rasterisers' edge and MSAA differences.
const MEAN_FLIP_THRESHOLD: f32 = 0.01;
/// A push must differ from the rest frame by at least this many thresholds.
const DISTINCT_FACTOR: f32 = 5.0;
const SIZE: [u32; 2] = [320, 240];

struct Fixture {
    gpu: Gpu,
    renderer: Renderer,
    mesh: Mesh,
    c: Compliance,
}

fn fixture() -> &'static Fixture {
    static F: OnceLock<Fixture> = OnceLock::new();
    F.get_or_init(|| {
        let gpu = Gpu::new_headless().unwrap_or_else(|e| {
            panic!("golden tests need an adapter and must not be skipped: {e}")
        });
        let renderer = Renderer::new(&gpu.device, SIZE).expect("renderer");
        let mesh = cube();
        let c = Compliance::compute(&mesh, &Selection::default()).expect("cube compliance");
        Fixture {
            gpu,
            renderer,
            mesh,
            c,
        }
    })
}

fn golden_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("golden")
}

fn node_at(mesh: &Mesh, mm: [f64; 3]) -> u32 {
    let p = DVec3::from(mm) * 1e-3;
    mesh.nodes
        .iter()
        .position(|q| q.distance(p) < 1e-9)
        .unwrap() as u32
}

/// Renders the cube with the god-object on the node at `at_mm` and the finger displaced by `u`.
fn render(push: Option<([f64; 3], DVec3)>) -> image::RgbaImage {
    let f = fixture();
    let (forces, finger, proxy) = match push {
        Some((at_mm, u)) => {
            let node = node_at(&f.mesh, at_mm);
            let col = f.c.col_of(node).expect("touchable");
            let force = (f.c.diag_inv(col) * u).as_vec3().to_array();
            let p = f.mesh.nodes[node as usize];
            (vec![(col as u32, force)], Some(p + u), Some(p))
        }
        None => (vec![], None, None),
    };
    let scene = Scene {
        mesh: &f.mesh,
        compliance: &f.c,
        forces: &forces,
        finger,
        proxy,
        wireframe: true,
    };
    f.renderer
        .render(&f.gpu.device, &f.gpu.queue, &scene)
        .expect("render")
}

fn rgb(img: &image::RgbaImage) -> nv_flip::FlipImageRgb8 {
    let data: Vec<u8> = img.pixels().flat_map(|p| [p[0], p[1], p[2]]).collect();
    nv_flip::FlipImageRgb8::with_data(img.width(), img.height(), &data)
}

/// Mean FLIP error between two images, and the error map as a colour image.
fn flip(reference: &image::RgbaImage, test: &image::RgbaImage) -> (f32, image::RgbImage) {
    let err = nv_flip::flip(
        rgb(reference),
        rgb(test),
        nv_flip::DEFAULT_PIXELS_PER_DEGREE,
    );
    let mean = nv_flip::FlipPool::from_image(&err).mean();
    let vis = err.apply_color_lut(&nv_flip::magma_lut());
    let map = image::RgbImage::from_raw(vis.width(), vis.height(), vis.to_vec()).unwrap();
    (mean, map)
}

fn update() -> bool {
    std::env::var("TOUCHFEM_UPDATE_GOLDEN").is_ok_and(|v| v == "1")
}

fn check_golden(name: &str, actual: &image::RgbaImage) {
    let dir = golden_dir();
    let path = dir.join(format!("{name}.png"));
    if update() {
        std::fs::create_dir_all(&dir).unwrap();
        actual.save(&path).unwrap();
        eprintln!("updated {}", path.display());
        return;
    }
    let golden = image::open(&path)
        .unwrap_or_else(|e| {
            panic!(
                "{}: {e} (run with TOUCHFEM_UPDATE_GOLDEN=1 to create it)",
                path.display()
            )
        })
        .to_rgba8();
    assert_eq!(golden.dimensions(), actual.dimensions(), "{name}: size");
    let (mean, map) = flip(&golden, actual);
    eprintln!("{name}: mean FLIP {mean:.5} (threshold {MEAN_FLIP_THRESHOLD})");
    if mean > MEAN_FLIP_THRESHOLD {
        let actual_path = dir.join(format!("{name}.actual.png"));
        let diff_path = dir.join(format!("{name}.diff.png"));
        actual.save(&actual_path).unwrap();
        map.save(&diff_path).unwrap();
        panic!(
            "{name}: mean FLIP {mean:.5} > {MEAN_FLIP_THRESHOLD}; wrote {} and {}",
            actual_path.display(),
            diff_path.display()
        );
    }
}

const TOP: ([f64; 3], DVec3) = ([15.0, 15.0, 30.0], DVec3::new(0.0, 0.0, -5e-3));
const SIDE: ([f64; 3], DVec3) = ([0.0, 15.0, 15.0], DVec3::new(5e-3, 0.0, 0.0));

#[test]
fn golden_cube_rest() {
    check_golden("cube_rest", &render(None));
}

#[test]
fn golden_cube_push_top() {
    check_golden("cube_push_top", &render(Some(TOP)));
}

#[test]
fn golden_cube_push_side() {
    check_golden("cube_push_side", &render(Some(SIDE)));
}

/// The goldens can tell a pushed cube from a resting one (and the two pushes apart).
#[test]
fn goldens_distinguish_pushes() {
    let rest = render(None);
    let top = render(Some(TOP));
    let side = render(Some(SIDE));
    for (a, b, what) in [
        (&rest, &top, "rest vs top push"),
        (&rest, &side, "rest vs side push"),
        (&top, &side, "top vs side push"),
    ] {
        let (mean, _) = flip(a, b);
        eprintln!("{what}: mean FLIP {mean:.5}");
        assert!(
            mean > DISTINCT_FACTOR * MEAN_FLIP_THRESHOLD,
            "{what}: mean FLIP {mean:.5} is not well above the threshold {MEAN_FLIP_THRESHOLD}"
        );
    }
    // Rendering is deterministic on one device.
    let (again, _) = flip(&top, &render(Some(TOP)));
    assert!(
        again <= MEAN_FLIP_THRESHOLD / 10.0,
        "re-render differs: {again}"
    );
}

/// The bundled mouse and its compliance, shared by the mouse goldens.
fn mouse_scene() -> &'static touchfem::scene::Scene {
    static S: OnceLock<touchfem::scene::Scene> = OnceLock::new();
    S.get_or_init(|| {
        touchfem::scene::Scene::new(touchfem::mesh::mouse(), &Selection::default())
            .expect("mouse compliance")
    })
}

/// The mouse at rest, or pressed 10 mm on its back through the whole haptic pipeline
/// (god-object + the paper's force), optionally without the finger and god-object spheres.
fn render_mouse(pressed: bool, spheres: bool) -> image::RgbaImage {
    let f = fixture();
    let s = mouse_scene();
    let (forces, finger, proxy) = if pressed {
        let at = DVec3::new(-0.01, 0.0, 0.06);
        let push = DVec3::new(0.0, 0.0, -0.01);
        let p = s
            .poke(at, push, touchfem::force::ForceModel::Paper, 50)
            .expect("poke");
        let c = p.contact.expect("the finger presses the mouse's back");
        let (f32s, n) = p.bc.to_f32();
        (f32s[..n].to_vec(), Some(c.finger), Some(c.proxy))
    } else {
        (vec![], None, None)
    };
    let scene = Scene {
        mesh: &s.mesh,
        compliance: &s.compliance,
        forces: &forces,
        finger: finger.filter(|_| spheres),
        proxy: proxy.filter(|_| spheres),
        wireframe: true,
    };
    f.renderer
        .render(&f.gpu.device, &f.gpu.queue, &scene)
        .expect("render")
}

#[test]
fn golden_mouse_rest() {
    check_golden("mouse_rest", &render_mouse(false, true));
}

#[test]
fn golden_mouse_pressed() {
    check_golden("mouse_pressed", &render_mouse(true, true));
}

/// The dent alone (no spheres drawn) is visible to the metric.
#[test]
fn mouse_dent_is_visible_without_the_spheres() {
    let (mean, _) = flip(&render_mouse(false, false), &render_mouse(true, false));
    eprintln!("mouse rest vs pressed, no spheres: mean FLIP {mean:.5}");
    assert!(
        mean > 2.0 * MEAN_FLIP_THRESHOLD,
        "the dent changes the mouse frame by only {mean:.5}"
    );
}
