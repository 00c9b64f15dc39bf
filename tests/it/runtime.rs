//! The multi-finger runtime: several fingers solved together, fingers on different objects,
//! fingers that start inside, jumps across thin parts, NaN positions, a panicking haptic
//! thread, and a GPU that is lost or hangs mid-run.

use glam::DVec3;
use std::sync::atomic::Ordering;
use std::time::Duration;

use touchfem::compliance::{Compliance, NodeSet, Selection};
use touchfem::contact::force::{finger_force, ForceBc, ForceModel};
use touchfem::contact::{ContactPoint, GodObject};
use touchfem::devices::{HapticDevice, KeyframePath};
use touchfem::runtime::haptic::{RAMP_S, SKIN};
use touchfem::runtime::{
    join_haptic, run_haptic, sample_channel, DoneGuard, HapticWorld, LiveStatus, WorldSample,
};
use touchfem::scene::World;
use touchfem_app::visual::Visual;

fn world(toml: &str) -> World {
    crate::common::world_from_text(toml).unwrap()
}

const CUBE_ONE: &str = r#"
unit = "mm"
[[object]]
mesh = "cube"
[[finger]]
device = "pointer"
"#;

const CUBE_TWO: &str = r#"
unit = "mm"
[[object]]
mesh = "cube"
[[finger]]
device = "pointer"
[[finger]]
device = "pointer"
"#;

/// Steps `hw` with fixed positions `n` times; returns the last forces and sample.
fn hold(hw: &mut HapticWorld<'_>, pos: &[DVec3], n: usize) -> ([DVec3; 4], WorldSample) {
    let mut f = [DVec3::ZERO; 4];
    let mut s = WorldSample::default();
    for _ in 0..n {
        hw.step(pos, &mut f[..pos.len()], &mut s);
    }
    (f, s)
}

/// Moves fingers from `from` to `to` in `steps` ticks (so they enter from outside).
fn press(
    hw: &mut HapticWorld<'_>,
    from: &[DVec3],
    to: &[DVec3],
    steps: usize,
) -> ([DVec3; 4], WorldSample) {
    let mut f = [DVec3::ZERO; 4];
    let mut s = WorldSample::default();
    let mut p = vec![DVec3::ZERO; from.len()];
    for k in 0..=steps {
        let a = k as f64 / steps as f64;
        for i in 0..from.len() {
            p[i] = from[i].lerp(to[i], a);
        }
        hw.step(&p, &mut f[..from.len()], &mut s);
    }
    (f, s)
}

/// The displacement of a contact point under a boundary condition: Σ_i α_i u(node_i).
fn point_displacement(c: &Compliance, contact: &ContactPoint, bc: &ForceBc) -> DVec3 {
    let mut u = vec![DVec3::ZERO; c.rows().len()];
    c.displace(bc.entries(), &mut u);
    (0..3)
        .map(|i| {
            c.row_of(contact.nodes[i])
                .map_or(DVec3::ZERO, |r| u[r] * contact.alpha[i])
        })
        .sum()
}

fn contact_at(w: &World, x: DVec3, from: DVec3) -> ContactPoint {
    let s = &w.objects[0].body.surface;
    let mut g = GodObject::new(from);
    g.update(s, x).expect("in contact")
}

const MM: f64 = 1e-3;

#[test]
fn two_fingers_are_solved_together_and_each_contact_moves_by_its_displacement() {
    let w = world(CUBE_TWO);
    let c = &w.objects[0].body.compliance;
    let mut hw = HapticWorld::new(&w);
    // Pinch the cube from x = 0 and x = 30 mm at mid-height, 3 mm each.
    let from = [
        DVec3::new(-5.0, 13.0, 17.0) * MM,
        DVec3::new(35.0, 16.0, 19.0) * MM,
    ];
    let to = [
        DVec3::new(3.0, 13.0, 17.0) * MM,
        DVec3::new(27.0, 16.0, 19.0) * MM,
    ];
    let (f, s) = press(&mut hw, &from, &to, 20);
    assert_eq!(s.contacts(0), 2);
    assert!(s.bc(0).len() >= 6, "both fingers' nodes: {}", s.bc(0).len());
    // The coupled solve: the contact points, interpolated from the nodal displacement of the
    // whole boundary condition (independently, with the CPU product), move by the fingers'
    // displacements up to the fingertip compliance (SKIN × tr(W)/3 × G, at most a few SKIN of
    // the displacement for the cube's anisotropic point compliance).
    for (i, x) in to.iter().enumerate() {
        let ct = contact_at(&w, *x, from[i]);
        let u = point_displacement(c, &ct, s.bc(0));
        let want = ct.displacement();
        assert!(
            (u - want).length() <= 5.0 * SKIN * want.length(),
            "finger {i}: moved {u} for {want}"
        );
        // The force pushes the finger back out (opposite to its displacement).
        assert!(f[i].dot(want) < 0.0);
    }
    // Squeezing symmetric points: opposite x forces of nearly equal size.
    assert!(f[0].x < 0.0 && f[1].x > 0.0);
    assert!((f[0].x + f[1].x).abs() < 0.2 * f[0].x.abs(), "{f:?}");
}

#[test]
fn two_fingers_at_the_same_point_share_the_load_of_one() {
    let w = world(CUBE_TWO);
    let c = &w.objects[0].body.compliance;
    let mut hw = HapticWorld::new(&w);
    let from = DVec3::new(11.0, 13.0, 35.0) * MM;
    let to = DVec3::new(11.0, 13.0, 28.0) * MM;
    let (f, s) = press(&mut hw, &[from, from], &[to, to], 20);
    assert_eq!(s.contacts(0), 2);
    // One finger alone, exact model (the coupled solve generalises it).
    let ct = contact_at(&w, to, from);
    let mut bc = ForceBc::default();
    let one = finger_force(c, &ct, ForceModel::Exact, &mut bc).feedback;
    let total = f[0] + f[1];
    assert!(
        (total - one).length() <= 3.0 * SKIN * one.length(),
        "{total} vs {one}"
    );
    assert!(
        (f[0] - f[1]).length() <= 1e-9 * one.length(),
        "equal shares"
    );
    for v in f.iter().take(2) {
        assert!(v.is_finite() && v.length() <= 8.5);
    }
}

#[test]
fn two_fingers_on_one_triangle_are_finite_and_consistent() {
    let w = world(CUBE_TWO);
    let c = &w.objects[0].body.compliance;
    let s0 = &w.objects[0].body.surface;
    // Two points inside one top triangle.
    let top = (0..s0.tris.len())
        .find(|&t| s0.normals[t].z > 0.99)
        .unwrap();
    let [a, b, cc] = s0.tris[top].map(|i| s0.nodes[i as usize]);
    let p1 = a * 0.6 + b * 0.2 + cc * 0.2;
    let p2 = a * 0.2 + b * 0.2 + cc * 0.6;
    let up = DVec3::new(0.0, 0.0, 5.0 * MM);
    let down = DVec3::new(0.0, 0.0, -2.0 * MM);
    let mut hw = HapticWorld::new(&w);
    let (f, s) = press(&mut hw, &[p1 + up, p2 + up], &[p1 + down, p2 + down], 20);
    assert_eq!(s.contacts(0), 2);
    for (i, p) in [p1, p2].iter().enumerate() {
        assert!(
            f[i].is_finite() && f[i].z > 0.0 && f[i].length() <= 8.5,
            "{f:?}"
        );
        let ct = contact_at(&w, *p + down, *p + up);
        assert_eq!(ct.tri as usize, top);
        let u = point_displacement(c, &ct, s.bc(0));
        assert!((u - down).length() <= 5.0 * SKIN * down.length(), "{u}");
    }
}

#[test]
fn fingers_on_different_objects_feel_each_object_alone() {
    let w = world(
        r#"
unit = "mm"
[[object]]
name = "left"
mesh = "cube"
[[object]]
name = "right"
mesh = "cube"
offset = [100.0, 0.0, 0.0]
[[finger]]
device = "pointer"
model = "exact"
[[finger]]
device = "pointer"
model = "exact"
"#,
    );
    let mut hw = HapticWorld::new(&w);
    let off = DVec3::new(0.1, 0.0, 0.0);
    let from = [
        DVec3::new(10.0, 12.0, 35.0) * MM,
        DVec3::new(20.0, 14.0, 35.0) * MM + off,
    ];
    let to = [
        DVec3::new(10.0, 12.0, 27.0) * MM,
        DVec3::new(20.0, 14.0, 26.0) * MM + off,
    ];
    let (f, s) = press(&mut hw, &from, &to, 20);
    assert_eq!((s.contacts(0), s.contacts(1)), (1, 1));
    assert_eq!(s.fingers()[1].object, Some(1));
    assert!(!s.bc(0).is_empty() && !s.bc(1).is_empty());
    for (i, o) in [0usize, 1].iter().enumerate() {
        let obj = &w.objects[*o];
        let ct = contact_at(&w, to[i] - obj.offset, from[i] - obj.offset);
        let mut bc = ForceBc::default();
        let alone = finger_force(&obj.body.compliance, &ct, ForceModel::Exact, &mut bc).feedback;
        assert!(
            (f[i] - alone).length() <= 1e-12 * alone.length(),
            "{} vs {alone}",
            f[i]
        );
        let proxy = s.fingers()[i].proxy.unwrap();
        assert!((proxy - (ct.proxy + obj.offset)).length() < 1e-12);
    }
}

#[test]
fn a_finger_that_starts_inside_is_attached_at_the_nearest_point_and_ramped_in() {
    let w = world(CUBE_ONE);
    let inside = DVec3::new(14.0, 16.0, 27.5) * MM; // 2.5 mm under the top face
    let mut hw = HapticWorld::new(&w);
    let (f1, s1) = hold(&mut hw, &[inside], 1);
    assert_eq!(s1.contacts(0), 1, "it touches at once");
    let proxy = s1.fingers()[0].proxy.unwrap();
    assert!(
        (proxy - DVec3::new(14.0, 16.0, 30.0) * MM).length() < 1e-12,
        "{proxy}"
    );
    // The same press entered from outside: the reference force.
    let mut reference = HapticWorld::new(&w);
    let (fr, _) = press(&mut reference, &[inside + DVec3::Z * 0.01], &[inside], 10);
    let ticks = (RAMP_S * 1000.0) as usize;
    assert!(
        f1[0].length() < 0.05 * fr[0].length(),
        "ramped: {} vs {}",
        f1[0],
        fr[0]
    );
    let (fh, _) = hold(&mut hw, &[inside], ticks / 2 - 1);
    assert!(
        (fh[0].length() / fr[0].length() - 0.5).abs() < 0.03,
        "half-way: {}",
        fh[0]
    );
    let (ff, _) = hold(&mut hw, &[inside], ticks);
    assert!(
        (ff[0] - fr[0]).length() <= 1e-12 * fr[0].length(),
        "{} vs {}",
        ff[0],
        fr[0]
    );
}

#[test]
fn a_finger_that_reappears_inside_after_nan_is_attached_again_and_nan_gives_zero_force() {
    let w = world(CUBE_ONE);
    let mut hw = HapticWorld::new(&w);
    let (f, _) = press(
        &mut hw,
        &[DVec3::new(15.0, 15.0, 35.0) * MM],
        &[DVec3::new(15.0, 15.0, 27.0) * MM],
        10,
    );
    assert!(f[0].z > 0.0);
    let (f, s) = hold(&mut hw, &[DVec3::NAN], 1);
    assert_eq!(f[0], DVec3::ZERO);
    assert!(s.bc(0).is_empty() && s.contacts(0) == 0);
    let (f, s) = hold(&mut hw, &[DVec3::new(f64::INFINITY, 0.0, 0.0)], 1);
    assert_eq!(f[0], DVec3::ZERO);
    assert!(s.bc(0).is_empty());
    let (f, s) = hold(&mut hw, &[DVec3::new(15.0, 15.0, 27.0) * MM], 1);
    assert_eq!(s.contacts(0), 1);
    assert!(
        f[0].is_finite() && f[0].length() < 0.05,
        "ramped in again: {}",
        f[0]
    );
}

#[test]
fn a_10_mm_jump_across_a_thin_plate_does_not_pop_through() {
    // A 40 × 40 × 2 mm plate clamped along one edge, finger pressing its top.
    let raw = touchfem::mesh::grid_raw([8, 8, 1], [0.04, 0.04, 0.002], |_, _, _| true);
    let mut mesh = touchfem::Mesh::from_raw(
        raw,
        touchfem::LengthUnit::Metre,
        touchfem::Material::DEFAULT,
    )
    .unwrap();
    mesh.set_fixed_where(|p| p.x < 1e-9);
    let c = Compliance::compute(
        &mesh,
        &Selection {
            rows: NodeSet::Surface,
            cols: NodeSet::FreeSurface,
        },
    )
    .unwrap();
    let w = World {
        name: "plate".into(),
        unit: touchfem::LengthUnit::Metre,
        objects: vec![touchfem::scene::Object {
            name: "plate".into(),
            body: touchfem::scene::Body::with_compliance(mesh, c),
            offset: DVec3::ZERO,
            friction: None,
            cuttable: None,
        }],
        fingers: vec![touchfem::scene::FingerSpec {
            device: touchfem::scene::DeviceSpec::Pointer,
            model: ForceModel::Paper,
            limits: None,
            tool: Default::default(),
        }],
        haptics: Default::default(),
        source: String::new(),
        dir: ".".into(),
        hash: 0,
    };
    let mut hw = HapticWorld::new(&w);
    let above = DVec3::new(0.03, 0.02, 0.004);
    let on = DVec3::new(0.03, 0.02, 0.0015); // 0.5 mm into the top
    let (f0, _) = press(&mut hw, &[above], &[on], 10);
    assert!(f0[0].z > 0.0);
    // One tick: 10 mm straight down, through the plate and out of its bottom.
    let below = on - DVec3::new(0.0, 0.0, 0.010);
    let (f1, s1) = hold(&mut hw, &[below], 1);
    assert_eq!(s1.contacts(0), 1, "still touching the top");
    let proxy = s1.fingers()[0].proxy.unwrap();
    assert!(
        (proxy.z - 0.002).abs() < 1e-12,
        "the proxy stays on the top face: {proxy}"
    );
    assert!(
        f1[0].z > 0.0 && f1[0].length() <= 8.5 + 1e-12,
        "pushes the finger up: {}",
        f1[0]
    );
}

/// A device whose reading panics after `after` seconds.
struct Panicky(f64);
impl HapticDevice for Panicky {
    fn position(&mut self, t: f64) -> DVec3 {
        assert!(t < self.0, "device driver crashed");
        DVec3::splat(1.0)
    }
    fn set_force(&mut self, _f: DVec3) {}
}

#[test]
fn a_panicking_haptic_thread_stops_the_visual_loop_with_an_error() {
    let w = world(CUBE_ONE);
    let status = LiveStatus::default();
    let (mut writer, mut reader) = sample_channel();
    let t0 = std::time::Instant::now();
    let mut frames = 0u64;
    let out = std::thread::scope(|sc| {
        let h = sc.spawn(|| {
            let _g = DoneGuard(&status);
            let mut devs: Vec<Box<dyn HapticDevice>> = vec![Box::new(Panicky(0.05))];
            run_haptic(&w, &mut devs, None, &mut writer, &status, None)
        });
        // The visual loop, as demo and view run it.
        while !status.done.load(Ordering::Acquire) {
            std::hint::black_box(reader.read());
            frames += 1;
            assert!(
                t0.elapsed() < Duration::from_secs(20),
                "the visual loop spins forever"
            );
            std::thread::sleep(Duration::from_millis(1));
        }
        join_haptic(h)
    });
    assert!(status.panicked.load(Ordering::Acquire));
    let err = out.unwrap_err().to_string();
    assert!(
        err.contains("haptic thread panicked") && err.contains("device driver crashed"),
        "{err}"
    );
    assert!(frames > 0);
}

#[test]
fn the_haptic_loop_keeps_its_rate_while_the_gpu_is_lost_and_the_visual_path_falls_back() {
    let w = world(
        r#"
unit = "mm"
[[object]]
mesh = "cube"
[[finger]]
device = "script"
path = [[0.0, 15, 15, 35], [0.3, 15, 15, 26], [1.0, 15, 15, 26]]
"#,
    );
    let gpu = touchfem::gpu::Gpu::new_headless().expect("lavapipe or a GPU");
    let status = LiveStatus::default();
    let (mut writer, mut reader) = sample_channel();
    let secs = 0.6;
    let (run, backend, checked) = std::thread::scope(|sc| {
        let h = sc.spawn(|| {
            let _g = DoneGuard(&status);
            let touchfem::scene::DeviceSpec::Script(keys) = &w.fingers[0].device else {
                unreachable!()
            };
            let mut devs: Vec<Box<dyn HapticDevice>> =
                vec![Box::new(KeyframePath::new(keys.clone()).unwrap())];
            run_haptic(&w, &mut devs, Some(secs), &mut writer, &status, None)
        });
        let mut visual = Visual::new(&w, Some(&gpu));
        assert!(visual.gpu_ok());
        let mut lost = false;
        let mut checked = 0;
        while !status.done.load(Ordering::Acquire) {
            let s = *reader.read();
            visual.update(&s);
            if !lost && s.tick > 350 {
                gpu.device.destroy(); // the device is lost mid-run
                lost = true;
            }
            if lost && !visual.gpu_ok() && !s.bc(0).is_empty() {
                // The fallback is the CPU product, exactly.
                let c = &w.objects[0].body.compliance;
                let mut u = vec![DVec3::ZERO; c.rows().len()];
                c.displace(s.bc(0).entries(), &mut u);
                assert_eq!(visual.cpu_displacement(0), &u[..]);
                checked += 1;
            }
        }
        (join_haptic(h).unwrap(), visual.backend(), checked)
    });
    assert!(backend.starts_with("cpu-f64 (gpu failed"), "{backend}");
    assert!(checked > 0);
    // The haptic loop ran every tick it was asked for at its rate.
    assert_eq!(run.stats.ticks, 600);
    assert!(run.stats.haptic_rate_hz > 900.0, "{:?}", run.stats);
    assert!(run.stats.max_force_n > 0.1);
}

#[test]
fn a_gpu_wait_that_times_out_falls_back_to_the_cpu() {
    let w = world(
        r#"
unit = "mm"
[[object]]
mesh = "mouse"
[[finger]]
device = "pointer"
"#,
    );
    let gpu = touchfem::gpu::Gpu::new_headless().expect("lavapipe or a GPU");
    let mut visual = Visual::new(&w, Some(&gpu));
    visual.set_timeout(Duration::ZERO);
    let mut s = WorldSample::default();
    let mut hw = HapticWorld::new(&w);
    let mut f = [DVec3::ZERO];
    for k in 0..=10 {
        let x = DVec3::new(-10.0, 0.0, 60.0 - 2.4 * k as f64) * MM;
        hw.step(&[x], &mut f, &mut s);
    }
    assert!(!s.bc(0).is_empty());
    // Many frames: at least one wait must not have completed in zero time.
    for _ in 0..50 {
        visual.update(&s);
        if !visual.gpu_ok() {
            break;
        }
    }
    assert!(!visual.gpu_ok(), "a zero timeout never expired");
    assert!(
        visual.failure().unwrap().contains("waiting"),
        "{:?}",
        visual.failure()
    );
    visual.update(&s);
    let c = &w.objects[0].body.compliance;
    let mut u = vec![DVec3::ZERO; c.rows().len()];
    c.displace(s.bc(0).entries(), &mut u);
    assert_eq!(visual.cpu_displacement(0), &u[..]);
}

/// A scene of the cube with one finger, `max_force_n`, and `limits` (TOML, or "" for none).
fn cube_bounded(max_force_n: f64, limits: &str) -> World {
    world(&format!(
        "unit = \"mm\"\n[[object]]\nmesh = \"cube\"\n[[finger]]\ndevice = \"pointer\"\n{limits}\n[haptics]\nmax_force_n = {max_force_n}\n"
    ))
}

/// Presses straight down into the top face at `speed` metres per tick for `ticks`, `dt`
/// seconds apart; returns every force.
fn dive(hw: &mut HapticWorld<'_>, speed: f64, ticks: usize, dt: f64) -> Vec<DVec3> {
    let mut f = [DVec3::ZERO; 1];
    let mut s = WorldSample::default();
    let top = DVec3::new(14.0, 16.0, 31.0) * MM;
    (0..ticks)
        .map(|k| {
            let x = top - DVec3::Z * (speed * k as f64).min(25.0 * MM);
            hw.step_dt(dt, &[x], &mut f, &mut s);
            f[0]
        })
        .collect()
}

/// The review's case: `max_force_n = 0.1` with the Falcon's limits, the finger moving 1 mm a
/// tick. Before, the coupling's damping came after the saturation: 2.46 N.
#[test]
fn the_force_bound_holds_after_the_coupling_and_its_damping() {
    for limits in ["limits = \"falcon\"", "limits = \"phantom-omni\"", ""] {
        let w = cube_bounded(0.1, limits);
        let mut hw = HapticWorld::new(&w);
        assert_eq!(hw.force_bound(0), 0.1);
        let forces = dive(&mut hw, 1.0 * MM, 60, 1e-3);
        let max = forces.iter().map(|f| f.length()).fold(0.0, f64::max);
        assert!(max <= 0.1 + 1e-12, "{limits}: {max} N");
        assert!(max > 0.099, "{limits}: the bound is reached ({max} N)");
        assert!(forces.iter().all(|f| f.is_finite()));
    }
    // The device's peak is the bound when it is the smaller one.
    let w = cube_bounded(50.0, "limits = \"phantom-omni\"");
    let mut hw = HapticWorld::new(&w);
    assert_eq!(hw.force_bound(0), 4.0);
    let max = dive(&mut hw, 1.0 * MM, 60, 1e-3)
        .iter()
        .map(|f| f.length())
        .fold(0.0, f64::max);
    assert!(max <= 4.0 + 1e-12, "{max}");
}

/// Without device limits a one-tick glitch of the position 5 mm into the object gave the
/// whole force at once; now the force rises at most `bound / RISE_S`.
#[test]
fn a_one_tick_position_glitch_gives_no_force_step() {
    use touchfem::runtime::bound::RISE_S;
    let w = cube_bounded(0.2, "");
    let mut hw = HapticWorld::new(&w);
    let mut f = [DVec3::ZERO; 1];
    let mut s = WorldSample::default();
    let above = DVec3::new(14.0, 16.0, 31.0) * MM;
    for _ in 0..10 {
        hw.step_dt(1e-3, &[above], &mut f, &mut s);
    }
    // The glitch: one tick 5 mm in (the paper's force there is about 0.3 N, over the bound).
    let inside = DVec3::new(14.0, 16.0, 25.0) * MM;
    hw.step_dt(1e-3, &[inside], &mut f, &mut s);
    let step = f[0].length();
    assert!(
        step <= 0.2 * 1e-3 / RISE_S + 1e-12,
        "a glitch gives {step} N in one tick"
    );
    assert!(step > 0.0);
    assert!(hw.limited(0));
    // Back out at once: zero at once.
    hw.step_dt(1e-3, &[above], &mut f, &mut s);
    assert_eq!(f[0], DVec3::ZERO);
}

/// The ramp of a finger attached from inside, and the rate limit, count seconds: a device
/// clocking the loop at 8 kHz gets the same ramp in time as one at 1 kHz, not 8 times faster.
#[test]
fn the_ramp_and_the_rate_limit_count_seconds_not_ticks() {
    let w = world(CUBE_ONE);
    let inside = DVec3::new(14.0, 16.0, 27.0) * MM;
    let run = |dt: f64, seconds: f64| {
        let mut hw = HapticWorld::new(&w);
        let mut f = [DVec3::ZERO; 1];
        let mut s = WorldSample::default();
        let ticks = (seconds / dt).round() as usize;
        for _ in 0..ticks {
            hw.step_dt(dt, &[inside], &mut f, &mut s);
        }
        f[0].length()
    };
    let full = run(1e-3, 0.5);
    assert!(full > 0.05, "{full}");
    for dt in [1e-3, 2.5e-4, 1.25e-4] {
        // Half the ramp's time: about half the force, at any tick rate.
        let half = run(dt, RAMP_S / 2.0);
        assert!(
            (half / full - 0.5).abs() < 0.03,
            "dt {dt}: {half} of {full} after RAMP_S/2"
        );
    }
}

/// `max_continuous_force_n` is enforced: a press held above it falls to it within seconds,
/// while the peak is allowed at first.
#[test]
fn a_held_force_falls_to_the_devices_continuous_force() {
    let limits = "limits = { max_force_n = 8.0, max_continuous_force_n = 0.05, max_stiffness_n_per_m = 3000.0, max_damping_ns_per_m = 20.0, workspace_radius_m = 0.1 }";
    let w = cube_bounded(8.5, limits);
    let mut hw = HapticWorld::new(&w);
    let forces = dive(&mut hw, 0.05 * MM, 4000, 1e-3);
    let early = forces[..300].iter().map(|f| f.length()).fold(0.0, f64::max);
    let late = forces[3000..]
        .iter()
        .map(|f| f.length())
        .fold(0.0, f64::max);
    assert!(early > 0.06, "the peak is allowed at first: {early}");
    assert!(late <= 0.05 + 1e-9, "held to the continuous force: {late}");
    assert!(late > 0.045, "{late}");
}

/// `workspace_radius_m` is enforced: a device cannot move more than its workspace's diameter
/// in one tick, so such a reading is a glitch: zero force, flagged, and the finger placed
/// afresh (ramped in) at its next reading.
#[test]
fn a_jump_beyond_the_workspace_is_a_glitch() {
    let limits = "limits = { max_force_n = 8.0, max_stiffness_n_per_m = 3000.0, max_damping_ns_per_m = 20.0, workspace_radius_m = 0.005 }";
    let w = cube_bounded(8.5, limits);
    let mut hw = HapticWorld::new(&w);
    let forces = dive(&mut hw, 0.05 * MM, 200, 1e-3);
    let held = forces[199];
    assert!(held.length() > 0.01, "{held}");
    let mut f = [DVec3::ZERO; 1];
    let mut s = WorldSample::default();
    let x = DVec3::new(14.0, 16.0, 31.0 - 0.05 * 199.0) * MM;
    // 12 mm away in one tick: more than 2 × 5 mm.
    hw.step_dt(1e-3, &[x + DVec3::X * 12.0 * MM], &mut f, &mut s);
    assert_eq!(f[0], DVec3::ZERO);
    assert!(hw.limited(0));
    // Back at the press: attached afresh and ramped in, not the held force at once.
    hw.step_dt(1e-3, &[x], &mut f, &mut s);
    assert!(f[0].length() < 0.1 * held.length(), "{} vs {held}", f[0]);
}
