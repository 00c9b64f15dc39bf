//! The haptic path: allocation-free, bounded and finite, lock-free publication.

use glam::DVec3;
use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::sync::atomic::{AtomicUsize, Ordering};
use touchfem::compliance::{Compliance, Selection};
use touchfem::contact::finger::Finger;
use touchfem::contact::force::ForceModel;
use touchfem::contact::Surface;
use touchfem::mesh::cube;

/// Counts allocations made by threads that armed the counter.
struct Counting;
static ALLOCS: AtomicUsize = AtomicUsize::new(0);
thread_local!(static ARMED: Cell<bool> = const { Cell::new(false) });

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, l: Layout) -> *mut u8 {
        if ARMED.try_with(|a| a.get()).unwrap_or(false) {
            ALLOCS.fetch_add(1, Ordering::Relaxed);
        }
        unsafe { System.alloc(l) }
    }
    unsafe fn dealloc(&self, p: *mut u8, l: Layout) {
        unsafe { System.dealloc(p, l) }
    }
    unsafe fn realloc(&self, p: *mut u8, l: Layout, n: usize) -> *mut u8 {
        if ARMED.try_with(|a| a.get()).unwrap_or(false) {
            ALLOCS.fetch_add(1, Ordering::Relaxed);
        }
        unsafe { System.realloc(p, l, n) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

fn setup() -> (Surface, Compliance) {
    let m = cube();
    let c = Compliance::compute(&m, &Selection::default()).unwrap();
    (Surface::new(&m), c)
}

/// A finger that comes down on the top face, slides across it (crossing edges and vertices)
/// and lifts off, position in metres at tick i of n.
fn path(i: usize, n: usize) -> DVec3 {
    let t = i as f64 / n as f64;
    let depth = 4e-3 * (std::f64::consts::PI * t).sin() - 1e-3;
    DVec3::new(0.004 + 0.022 * t, 0.006 + 0.018 * t, 0.03 - depth)
}

#[test]
fn the_force_step_allocates_nothing() {
    let (s, c) = setup();
    for model in [ForceModel::Paper, ForceModel::Exact] {
        let mut f = Finger::new(DVec3::new(0.004, 0.006, 0.032));
        let n = 5000;
        ALLOCS.store(0, Ordering::SeqCst);
        ARMED.with(|a| a.set(true));
        let mut touching = 0;
        for i in 0..=n {
            let force = f.step(&s, &c, path(i, n), model, 8.5);
            touching += f.contact.is_some() as usize;
            std::hint::black_box(force);
        }
        ARMED.with(|a| a.set(false));
        assert_eq!(ALLOCS.load(Ordering::SeqCst), 0, "{model:?} allocated");
        assert!(
            touching > n / 2,
            "the path must press the surface ({touching} ticks)"
        );
    }
}

#[test]
fn the_force_is_always_finite_and_bounded() {
    let (s, c) = setup();
    let mut f = Finger::new(DVec3::new(0.015, 0.015, 0.035));
    // Press 25 mm into a 30 mm cube: far beyond the limit.
    let mut last = DVec3::ZERO;
    for i in 0..=100 {
        let x = DVec3::new(0.015, 0.015, 0.035 - 0.03 * i as f64 / 100.0);
        last = f.step(&s, &c, x, ForceModel::Exact, 2.0);
        assert!(last.is_finite() && last.length() <= 2.0 + 1e-12);
    }
    assert!(
        (last.length() - 2.0).abs() < 1e-12,
        "saturated at the limit: {last}"
    );
    // The boundary condition is scaled to the force actually rendered (eq. 12 still holds).
    let sum: DVec3 = f.bc.entries().iter().map(|e| e.1).sum();
    assert!((sum + last).length() < 1e-9 * last.length());
    // Device glitches: NaN and infinite positions give zero force, never NaN.
    for bad in [DVec3::NAN, DVec3::new(f64::INFINITY, 0.0, 0.0)] {
        let g = f.step(&s, &c, bad, ForceModel::Paper, 2.0);
        assert_eq!(g, DVec3::ZERO);
        assert!(f.bc.is_empty());
    }
}

#[test]
fn the_multi_finger_tick_and_its_recording_allocate_nothing() {
    use touchfem::runtime::{sample_channel, session, HapticWorld, WorldSample};
    let world = touchfem::scene::World::load_with("pinch", "script", None).unwrap();
    let dir = tempfile::tempdir().unwrap();
    let (mut rec, writer) = session::record(&dir.path().join("s.tfsession"), &world).unwrap();
    let (mut w, mut r) = sample_channel();
    let mut hw = HapticWorld::new(&world);
    let mut sample = WorldSample::default();
    let mut f = [DVec3::ZERO; 2];
    let n = 3000;
    let mut both = 0;
    ALLOCS.store(0, Ordering::SeqCst);
    ARMED.with(|a| a.set(true));
    for i in 0..=n {
        let t = i as f64 / n as f64;
        let d = 14e-3 * (std::f64::consts::PI * t).sin();
        let mut pos = [
            DVec3::new(-0.010 + d, 0.015, 0.018),
            DVec3::new(0.040 - d, 0.015, 0.018),
        ];
        if i == n / 2 {
            pos[0] = DVec3::NAN; // a glitch: the finger reappears inside next tick
        }
        hw.step(&pos, &mut f, &mut sample);
        rec.push(&session::TickRecord::new(1e-3, &pos, &f));
        w.write(sample);
        both += (sample.contacts(0) == 2) as usize;
    }
    ARMED.with(|a| a.set(false));
    assert_eq!(ALLOCS.load(Ordering::SeqCst), 0, "the tick allocated");
    assert!(both > n / 3, "both fingers pressed ({both} ticks)");
    assert_eq!(r.read().tick, sample.tick);
    drop(rec);
    assert_eq!(writer.join().unwrap().unwrap(), n as u64 + 1);
}

#[test]
fn the_sphere_tick_with_friction_allocates_nothing() {
    use touchfem::runtime::{HapticWorld, WorldSample};
    use touchfem::scene::{SceneSource, World};
    let src = SceneSource {
        name: "sphere".into(),
        text: "unit = \"mm\"\n[[object]]\nmesh = \"mouse\"\nfriction = { static = 0.6, dynamic = 0.4 }\n[[finger]]\ndevice = \"pointer\"\ntool = { sphere = 8.0 }\n[[finger]]\ndevice = \"pointer\"\n".into(),
        dir: ".".into(),
        label: "sphere scene".into(),
    };
    let world = World::from_source_with(&src, None).unwrap();
    let mut hw = HapticWorld::new(&world);
    let mut sample = WorldSample::default();
    let mut f = [DVec3::ZERO; 2];
    let n = 1500;
    let mut pressing = 0;
    // Warm up off the surface (the first tick places the fingers).
    hw.step(&[DVec3::new(-0.01, 0.0, 0.07); 2], &mut f, &mut sample);
    ALLOCS.store(0, Ordering::SeqCst);
    ARMED.with(|a| a.set(true));
    for i in 0..=n {
        let t = i as f64 / n as f64;
        let d = 6e-3 * (std::f64::consts::PI * t).sin();
        let pos = [
            DVec3::new(-0.010 + 0.01 * t, 0.0, 0.054 - d),
            DVec3::new(0.02, 0.0, 0.07 - d),
        ];
        hw.step(&pos, &mut f, &mut sample);
        pressing += (sample.bc(0).len() > 3) as usize;
    }
    ARMED.with(|a| a.set(false));
    assert_eq!(
        ALLOCS.load(Ordering::SeqCst),
        0,
        "the sphere tick allocated"
    );
    assert!(pressing > n / 3, "the sphere pressed ({pressing} ticks)");
}
