//! Golden frames of the paper's cube, compared with NVIDIA's FLIP metric (`nv-flip`).
//!
//! * `golden/cube_rest.png`: at rest;
//! * `golden/cube_push_top.png`: the god-object on the top-centre node (15, 15, 30) mm, the
//!   finger 5 mm below it: `F = L_ii⁻¹·(0, 0, −5 mm)`;
//! * `golden/cube_push_side.png`: the god-object on (0, 15, 15) mm, the finger 5 mm inside:
//!   `F = L_ii⁻¹·(+5 mm, 0, 0)`;
//! * `golden/mouse_rest.png`, `golden/mouse_pressed.png`: the mouse at rest and pressed 10 mm
//!   on its back through the haptic pipeline;
//! * the colour map (`Coloring::Displacement`, with the force arrow and the legend):
//!   `golden/cube_push_top_displacement.png` (Fig. 1b), `golden/mouse_pressed_displacement.png`
//!   (the mouse pressed 8 mm, as `poke mouse --at -10,0,60 --push 0,0,-8 --png` draws it) and
//!   `golden/mouse_pressed_contact.png` (the same from the touched side, `--view contact`);
//! * `golden/palpate_pressed_displacement.png`: the bundled phantom with its nodule ten times
//!   stiffer (the scene `palpate`), pressed 3 mm straight down above the nodule, coloured by
//!   |u| with the arrow and the legend.
//!
//! Besides the goldens, numbers: under the colour map the pressed cube and mouse show at least
//! three hues (30° sectors), each on at least 2 % of the object's coloured pixels, the resting
//! mouse one; by default the object spans at least half the image's width.
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
use touchfem::render::{Coloring, ForceArrow, Picture, Renderer, View};

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
    let scene = Picture {
        mesh: &f.mesh,
        compliance: &f.c,
        forces: &forces,
        finger,
        proxy,
        wireframe: true,
        ..Picture::at_rest(&f.mesh, &f.c)
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

pub(crate) fn check_golden(name: &str, actual: &image::RgbaImage) {
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
fn mouse_scene() -> &'static touchfem::scene::Body {
    static S: OnceLock<touchfem::scene::Body> = OnceLock::new();
    S.get_or_init(|| {
        touchfem::scene::Body::new(touchfem::mesh::mouse(), &Selection::default())
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
            .poke(at, push, touchfem::contact::force::ForceModel::Paper, 50)
            .expect("poke");
        let c = p.contact.expect("the finger presses the mouse's back");
        let (f32s, n) = p.bc.to_f32();
        (f32s[..n].to_vec(), Some(c.finger), Some(c.proxy))
    } else {
        (vec![], None, None)
    };
    let scene = Picture {
        mesh: &s.mesh,
        compliance: &s.compliance,
        forces: &forces,
        finger: finger.filter(|_| spheres),
        proxy: proxy.filter(|_| spheres),
        wireframe: true,
        ..Picture::at_rest(&s.mesh, &s.compliance)
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

/// Everything `touchfem poke --png` draws for a press, in the library's terms: the god-object
/// and finger, the forces, the colour scale (the largest |u| of `u = L·F` over the surface), the
/// arrow (a quarter of the object's size for this force, in nice mm/N) and the touched point's
/// outward normal.
struct Press {
    forces: Vec<(u32, [f32; 3])>,
    finger: DVec3,
    proxy: DVec3,
    normal: DVec3,
    coloring: Coloring,
    arrow: ForceArrow,
    radius_m: f64,
}

fn press(s: &touchfem::scene::Body, at: DVec3, push: DVec3) -> Press {
    let p = s
        .poke(at, push, touchfem::contact::force::ForceModel::Paper, 50)
        .expect("poke");
    let c = p.contact.expect("the finger touches");
    let (f32s, n) = p.bc.to_f32();
    let mut u = vec![DVec3::ZERO; s.compliance.rows().len()];
    s.compliance.displace(p.bc.entries(), &mut u);
    let max_u = u.iter().map(|v| v.length()).fold(0.0, f64::max);
    let (lo, hi) = s.mesh.bounds();
    let diag = (hi - lo).length();
    let [a, b, cc] = c.nodes.map(|i| s.mesh.nodes[i as usize]);
    let finger = p.touch_point + push;
    Press {
        forces: f32s[..n].to_vec(),
        finger,
        proxy: c.proxy,
        normal: (b - a).cross(cc - a).normalize(),
        coloring: Coloring::displacement(max_u),
        arrow: ForceArrow {
            at: c.proxy,
            force_n: p.feedback,
            m_per_n: touchfem::render::arrow_scale(p.feedback.length(), 0.25 * diag),
        },
        radius_m: (3.0 * push.length()).max(0.2 * diag),
    }
}

/// The cube as a `Scene` (its compliance kept with it).
fn cube_scene() -> &'static touchfem::scene::Body {
    static S: OnceLock<touchfem::scene::Body> = OnceLock::new();
    S.get_or_init(|| {
        touchfem::scene::Body::new(cube(), &Selection::default()).expect("cube compliance")
    })
}

/// The presses of the issue: the mouse 8 mm on its back, the cube 5 mm on the top (Fig. 1b).
fn mouse_press() -> Press {
    press(
        mouse_scene(),
        DVec3::new(-0.01, 0.0, 0.06),
        DVec3::new(0.0, 0.0, -0.008),
    )
}

fn cube_press() -> Press {
    press(
        cube_scene(),
        DVec3::new(0.015, 0.015, 0.03),
        DVec3::new(0.0, 0.0, -0.005),
    )
}

/// What to draw of a press.
#[derive(Clone, Copy, PartialEq)]
enum Show {
    /// As `poke --png`: spheres, arrow, legend.
    Everything,
    /// The object alone (for counting its colours).
    ObjectOnly,
}

fn render_press(
    renderer: &Renderer,
    s: &touchfem::scene::Body,
    p: Option<&Press>,
    view: bool,
    show: Show,
) -> image::RgbaImage {
    let f = fixture();
    let all = show == Show::Everything;
    let scene = Picture {
        forces: p.map_or(&[][..], |p| &p.forces[..]),
        finger: p.map(|p| p.finger).filter(|_| all),
        proxy: p.map(|p| p.proxy).filter(|_| all),
        wireframe: true,
        // At rest: the mouse press's scale, so that the rest frame compares with it.
        coloring: p.map_or(Coloring::displacement(8e-3), |p| p.coloring),
        arrow: p.map(|p| p.arrow).filter(|_| all),
        view: match p {
            Some(p) if view => View::Contact {
                point: p.proxy,
                normal: p.normal,
                radius_m: p.radius_m,
            },
            _ => View::Auto,
        },
        legend: all,
        ..Picture::at_rest(&s.mesh, &s.compliance)
    };
    renderer
        .render(&f.gpu.device, &f.gpu.queue, &scene)
        .expect("render")
}

#[test]
fn golden_cube_push_top_displacement() {
    let f = fixture();
    let p = cube_press();
    check_golden(
        "cube_push_top_displacement",
        &render_press(&f.renderer, cube_scene(), Some(&p), false, Show::Everything),
    );
}

#[test]
fn golden_mouse_pressed_displacement() {
    let f = fixture();
    let p = mouse_press();
    check_golden(
        "mouse_pressed_displacement",
        &render_press(
            &f.renderer,
            mouse_scene(),
            Some(&p),
            false,
            Show::Everything,
        ),
    );
}

#[test]
fn golden_mouse_pressed_contact() {
    let f = fixture();
    let p = mouse_press();
    check_golden(
        "mouse_pressed_contact",
        &render_press(&f.renderer, mouse_scene(), Some(&p), true, Show::Everything),
    );
}

/// The phantom of the scene `palpate` (nodule E = 30 kPa in tissue of 3 kPa), its columns
/// the free-surface nodes within 8 mm of the top face's centre.
fn palpate_scene() -> &'static touchfem::scene::Body {
    static S: OnceLock<touchfem::scene::Body> = OnceLock::new();
    S.get_or_init(|| {
        let mut mesh = touchfem::mesh::phantom();
        let nodule = touchfem::Material {
            young_pa: 30_000.0,
            poisson: 0.45,
        };
        mesh.set_regions(&[("nodule".into(), nodule)])
            .expect("nodule");
        let centre = DVec3::new(0.0, 0.0, 0.02);
        let cols = mesh
            .free_surface_nodes()
            .into_iter()
            .filter(|&n| mesh.nodes[n as usize].distance(centre) < 0.008)
            .collect();
        let sel = Selection {
            rows: touchfem::compliance::NodeSet::Surface,
            cols: touchfem::compliance::NodeSet::Nodes(cols),
        };
        touchfem::scene::Body::new(mesh, &sel).expect("phantom compliance")
    })
}

#[test]
fn golden_palpate_pressed_displacement() {
    let f = fixture();
    let p = press(
        palpate_scene(),
        DVec3::new(0.0, 0.0, 0.02),
        DVec3::new(0.0, 0.0, -0.003),
    );
    check_golden(
        "palpate_pressed_displacement",
        &render_press(
            &f.renderer,
            palpate_scene(),
            Some(&p),
            false,
            Show::Everything,
        ),
    );
}

/// A 640×480 renderer, the size the issue measures at.
fn big_renderer() -> &'static Renderer {
    static R: OnceLock<Renderer> = OnceLock::new();
    R.get_or_init(|| Renderer::new(&fixture().gpu.device, [640, 480]).expect("renderer"))
}

/// The object's pixels (those differing from the corner's background by more than 12 in a
/// channel), how many of them are coloured (HSV saturation ≥ 0.2 and value ≥ 0.12: not the
/// wireframe's grey nor the shadows), and the coloured ones per 30° hue sector.
fn hue_census(img: &image::RgbaImage) -> (usize, usize, [usize; 12]) {
    let bg = *img.get_pixel(0, 0);
    let (mut object, mut coloured, mut sectors) = (0, 0, [0usize; 12]);
    for p in img.pixels() {
        if (0..3).all(|k| (i32::from(p[k]) - i32::from(bg[k])).abs() <= 12) {
            continue;
        }
        object += 1;
        let [r, g, b] = [p[0], p[1], p[2]].map(|c| f64::from(c) / 255.0);
        let max = r.max(g).max(b);
        let min = r.min(g).min(b);
        let (s, v) = (if max > 0.0 { (max - min) / max } else { 0.0 }, max);
        if s < 0.2 || v < 0.12 {
            continue;
        }
        let d = max - min;
        let h = if max == r {
            60.0 * ((g - b) / d).rem_euclid(6.0)
        } else if max == g {
            60.0 * ((b - r) / d + 2.0)
        } else {
            60.0 * ((r - g) / d + 4.0)
        };
        coloured += 1;
        sectors[((h / 30.0) as usize).min(11)] += 1;
    }
    (object, coloured, sectors)
}

/// Hue sectors holding at least 2 % of the coloured pixels, as "sector°: %".
fn distinct_hues(what: &str, img: &image::RgbaImage) -> usize {
    let (object, coloured, sectors) = hue_census(img);
    let shares: Vec<String> = sectors
        .iter()
        .enumerate()
        .filter(|(_, &n)| n > 0)
        .map(|(i, &n)| format!("{}°: {:.1} %", 30 * i, 100.0 * n as f64 / coloured as f64))
        .collect();
    let n = sectors
        .iter()
        .filter(|&&n| n as f64 >= 0.02 * coloured as f64)
        .count();
    eprintln!(
        "{what}: {object} object pixels, {coloured} coloured; {n} hues ≥ 2 % ({})",
        shares.join(", ")
    );
    assert!(
        coloured as f64 > 0.5 * object as f64,
        "{what}: few coloured pixels"
    );
    n
}

/// Under the colour map the pressed mouse (8 mm) and cube (Fig. 1b, 5 mm) show at least three
/// distinct hues, each on at least 2 % of the object's coloured pixels; at rest, one.
#[test]
fn colour_map_shows_the_press_in_hues() {
    let r = big_renderer();
    let mouse = distinct_hues(
        "mouse pressed 8 mm",
        &render_press(
            r,
            mouse_scene(),
            Some(&mouse_press()),
            false,
            Show::ObjectOnly,
        ),
    );
    assert!(mouse >= 3, "the pressed mouse shows {mouse} hues");
    let cube = distinct_hues(
        "cube pressed 5 mm",
        &render_press(
            r,
            cube_scene(),
            Some(&cube_press()),
            false,
            Show::ObjectOnly,
        ),
    );
    assert!(cube >= 3, "the pressed cube shows {cube} hues");
    let rest = distinct_hues(
        "mouse at rest",
        &render_press(r, mouse_scene(), None, false, Show::ObjectOnly),
    );
    assert_eq!(rest, 1, "the resting mouse shows {rest} hues");
    let rest = distinct_hues(
        "cube at rest",
        &render_press(r, cube_scene(), None, false, Show::ObjectOnly),
    );
    assert_eq!(rest, 1, "the resting cube shows {rest} hues");
}

/// Fraction of the image's width between the first and the last column holding object pixels,
/// outside the legend (`legend` pixels, width × height, in the top-right corner, 8 pixels from
/// the edges).
fn span(img: &image::RgbaImage, legend: [u32; 2]) -> f64 {
    let (w, h) = img.dimensions();
    let bg = *img.get_pixel(0, h - 1);
    let in_legend = |x: u32, y: u32| x + 8 + legend[0] >= w && y < 8 + legend[1];
    let cols: Vec<u32> = (0..w)
        .filter(|&x| {
            (0..h).any(|y| {
                !in_legend(x, y)
                    && (0..3)
                        .any(|k| (i32::from(img.get_pixel(x, y)[k]) - i32::from(bg[k])).abs() > 12)
            })
        })
        .collect();
    f64::from(cols.last().unwrap() - cols.first().unwrap() + 1) / f64::from(w)
}

/// By default the object fills the frame: the pressed mouse and cube, legend and all, span at
/// least half of the image's width; the contact view is closer still.
#[test]
fn default_view_fills_the_frame() {
    let r = big_renderer();
    for (what, s, p) in [
        ("mouse", mouse_scene(), mouse_press()),
        ("cube", cube_scene(), cube_press()),
    ] {
        let img = render_press(r, s, Some(&p), false, Show::Everything);
        let legend = touchfem::render::legend_image(&touchfem::render::LegendSpec {
            bar_px: touchfem::render::LegendSpec::bar_for(480),
            displacement: match p.coloring {
                Coloring::Displacement {
                    full_scale_m,
                    step_m,
                } => Some((full_scale_m, step_m)),
                Coloring::Plain => None,
            },
            arrow_m_per_n: Some(p.arrow.m_per_n),
            force_n: Some(p.arrow.force_n.length()),
        })
        .expect("a legend");
        let x = span(&img, [legend.width(), legend.height()]);
        eprintln!("{what}: spans {:.1} % of the width", 100.0 * x);
        assert!(
            x >= 0.5,
            "{what} spans only {:.1} % of the width",
            100.0 * x
        );
    }
}

/// The contact view looks at the touched point from outside: the point projects near the
/// image's centre (left of the legend), in front of the eye, and the eye is on the outward
/// normal's side.
#[test]
fn contact_view_looks_at_the_touched_point_from_outside() {
    let r = big_renderer();
    let s = mouse_scene();
    let p = mouse_press();
    let scene = Picture {
        finger: Some(p.finger),
        proxy: Some(p.proxy),
        arrow: Some(p.arrow),
        view: View::Contact {
            point: p.proxy,
            normal: p.normal,
            radius_m: p.radius_m,
        },
        ..Picture::at_rest(&s.mesh, &s.compliance)
    };
    let cam = r.scene_camera(&scene, None);
    assert!(
        (cam.eye - p.proxy).dot(p.normal) > 0.0,
        "the eye is inside the surface"
    );
    let [x, y] = cam
        .project(p.proxy, [640, 480])
        .expect("in front of the eye");
    assert!(
        (x - 320.0).abs() < 200.0 && (y - 240.0).abs() < 160.0,
        "touched point at ({x}, {y})"
    );
    let auto = r.scene_camera(
        &Picture {
            view: View::Auto,
            ..scene
        },
        None,
    );
    assert!(
        cam.eye.distance(p.proxy) < 0.7 * auto.eye.distance(p.proxy),
        "the contact view is not closer than the whole-object view"
    );
}

/// A fingertip's picture: the body under the sphere's contact forces, the sphere drawn at its
/// size (centre `centre`, radius `r`), the contact patch's nodes as dots on the deformed
/// surface, and the force on the finger from the patch's centre.
fn render_fingertip(
    s: &touchfem::scene::Body,
    forces: &[(u32, DVec3)],
    centre: DVec3,
    r: f64,
    feedback: DVec3,
) -> image::RgbaImage {
    let f = fixture();
    let mut u = vec![DVec3::ZERO; s.compliance.rows().len()];
    s.compliance.displace(forces, &mut u);
    let max_u = u.iter().map(|v| v.length()).fold(0.0, f64::max);
    let patch: Vec<DVec3> = forces
        .iter()
        .map(|&(c, _)| {
            let node = s.compliance.cols()[c as usize];
            s.mesh.nodes[node as usize] + u[s.compliance.row_of(node).unwrap()]
        })
        .collect();
    let mid = patch.iter().copied().sum::<DVec3>() / patch.len().max(1) as f64;
    let f32s: Vec<(u32, [f32; 3])> = forces
        .iter()
        .map(|&(c, v)| (c, v.as_vec3().to_array()))
        .collect();
    let (lo, hi) = s.mesh.bounds();
    let diag = (hi - lo).length();
    let scene = Picture {
        forces: &f32s,
        finger: Some(centre),
        finger_radius: Some(r),
        patch: &patch,
        proxy: None,
        wireframe: true,
        coloring: Coloring::displacement(max_u),
        arrow: Some(ForceArrow {
            at: mid,
            force_n: feedback,
            m_per_n: touchfem::render::arrow_scale(feedback.length(), 0.25 * diag),
        }),
        view: View::Auto,
        legend: true,
        ..Picture::at_rest(&s.mesh, &s.compliance)
    };
    f.renderer
        .render(&f.gpu.device, &f.gpu.queue, &scene)
        .expect("render")
}

/// The scene `palpate`'s fingertip (R = 8 mm) pressed 3 mm over the nodule, frictionless.
#[test]
fn golden_palpate_fingertip() {
    let s = palpate_scene();
    let p = s
        .poke_sphere(
            DVec3::new(0.0, 0.0, 0.02),
            DVec3::new(0.0, 0.0, -0.003),
            8e-3,
            None,
            None,
        )
        .expect("sphere poke");
    assert!(
        p.contact_nodes.len() >= 3,
        "{} nodes",
        p.contact_nodes.len()
    );
    check_golden(
        "palpate_fingertip",
        &render_fingertip(s, &p.forces, p.centre, 8e-3, p.feedback),
    );
}

/// The scene `rub` half-way through its stroke (t = 2.5 s, just past the nodule), replayed
/// through the haptic path: the fingertip with friction, the patch, the force leaning back
/// against the stroke.
#[test]
fn golden_rub_mid_stroke() {
    use touchfem::runtime::{HapticWorld, WorldSample};
    use touchfem::scene::{DeviceSpec, World};
    let w = World::load_with("rub", "script", None).expect("rub");
    let DeviceSpec::Script(keys) = &w.fingers[0].device else {
        panic!("a scripted finger")
    };
    let mut hw = HapticWorld::new(&w);
    let mut sample = WorldSample::default();
    let mut f = [DVec3::ZERO; 1];
    let mut x = DVec3::ZERO;
    for k in 0..=2500 {
        let t = k as f64 / 1000.0;
        let i = keys.iter().rposition(|k| k.0 <= t).unwrap_or(0);
        x = match keys.get(i + 1) {
            None => keys[i].1,
            Some(n) => keys[i]
                .1
                .lerp(n.1, ((t - keys[i].0) / (n.0 - keys[i].0)).clamp(0.0, 1.0)),
        };
        hw.step(&[x], &mut f, &mut sample);
    }
    assert!(f[0].x < 0.0 && f[0].z > 0.0, "{:?}", f[0]);
    let body = &w.objects[0].body;
    let forces = sample.bc(0).entries().to_vec();
    check_golden(
        "rub_mid_stroke",
        &render_fingertip(body, &forces, x - w.objects[0].offset, 8e-3, f[0]),
    );
}
