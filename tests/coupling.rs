//! Stable contact on the hand: a simulated hand (mass, spring and damper towards a target)
//! presses a stiff object through the haptic path at 1 kHz for 10 s of simulated time, the
//! device force held between ticks (zero-order hold) and the hand integrated in 0.1 ms steps.
//! With the virtual coupling sized for the Falcon the energy the device puts into the hand
//! stops growing and the motion settles; without it, the same press oscillates.

use glam::DVec3;

use touchfem::devices::limits::DeviceLimits;
use touchfem::runtime::coupling::VirtualCoupling;
use touchfem::runtime::{HapticWorld, WorldSample};
use touchfem::scene::{SceneSource, World};

const MM: f64 = 1e-3;

fn stiff_cube() -> World {
    World::from_source_with(
        &SceneSource {
            name: "stiff".into(),
            text: "unit = \"mm\"\n[[object]]\nmesh = \"cube\"\nyoung = 1.0e6\n[[finger]]\ndevice = \"pointer\"\n[haptics]\nmax_force_n = 8.0\n".into(),
            dir: ".".into(),
            label: "stiff cube".into(),
        },
        None,
    )
    .unwrap()
}

struct Outcome {
    /// Work done by the device on the hand, J, at each tick.
    work: Vec<f64>,
    /// Hand positions at each tick.
    x: Vec<DVec3>,
    max_force: f64,
}

/// Presses from `start` to `end` (hand target) over 1 s, then holds for 9 s.
fn press(world: &World, start: DVec3, end: DVec3, coupled: bool) -> Outcome {
    let falcon = DeviceLimits::preset("falcon").unwrap();
    let mut vc = VirtualCoupling::new(&falcon, 1000.0);
    let mut hw = HapticWorld::new(world);
    let mut s = WorldSample::default();
    let (m, k_h, b_h) = (0.1, 100.0, 1.0); // a relaxed hand: 0.1 kg, 100 N/m, 1 N·s/m
    let mut x = start;
    let mut v = DVec3::ZERO;
    let mut out = Outcome {
        work: Vec::new(),
        x: Vec::new(),
        max_force: 0.0,
    };
    let mut work = 0.0;
    for tick in 0..10_000 {
        let t = tick as f64 * 1e-3;
        let target = start.lerp(end, t.min(1.0));
        let mut f = [DVec3::ZERO];
        hw.step(&[x], &mut f, &mut s);
        let force = if coupled {
            vc.render(f[0], hw.contact_stiffness(0), x)
        } else {
            f[0]
        };
        out.max_force = out.max_force.max(force.length());
        for _ in 0..10 {
            let dt = 1e-4;
            let a = (k_h * (target - x) - b_h * v + force) / m;
            v += a * dt;
            let dx = v * dt;
            work += force.dot(dx);
            x += dx;
        }
        out.work.push(work);
        out.x.push(x);
    }
    out
}

fn peak_to_peak(xs: &[DVec3]) -> f64 {
    let lo = xs
        .iter()
        .fold(DVec3::splat(f64::INFINITY), |a, b| a.min(*b));
    let hi = xs
        .iter()
        .fold(DVec3::splat(f64::NEG_INFINITY), |a, b| a.max(*b));
    (hi - lo).max_element()
}

fn check(start: DVec3, end: DVec3, what: &str) {
    let w = stiff_cube();
    let with = press(&w, start, end, true);
    let without = press(&w, start, end, false);
    let late = |o: &Outcome| peak_to_peak(&o.x[9000..]);
    // Energy the device put into the hand from 2 s on (the hold): it never grows.
    let grow = |o: &Outcome| {
        o.work[2000..]
            .iter()
            .map(|e| e - o.work[2000])
            .fold(f64::NEG_INFINITY, f64::max)
    };
    eprintln!(
        "{what}: coupled p-p {:.2e} m, energy growth {:.2e} J, max F {:.3} N; uncoupled p-p {:.2e} m, energy growth {:.2e} J, max F {:.3} N",
        late(&with), grow(&with), with.max_force, late(&without), grow(&without), without.max_force
    );
    assert!(late(&with) < 1e-6, "{what}: the coupled press settles");
    assert!(
        grow(&with) < 1e-6,
        "{what}: the coupling puts no energy into the hand"
    );
    assert!(with.max_force <= 8.0 + 1e-9 && with.max_force > 0.05);
    // The same press without the coupling oscillates: the test can fail.
    assert!(
        late(&without) > 10.0 * late(&with).max(1e-7) || grow(&without) > 1e-4,
        "{what}: without the coupling the press should not be stable"
    );
}

#[test]
fn pressing_the_stiff_cube_is_stable_with_the_coupling_and_not_without() {
    check(
        DVec3::new(15.0, 15.0, 33.0) * MM,
        DVec3::new(15.0, 15.0, 27.0) * MM,
        "top",
    );
}

#[test]
fn pressing_next_to_the_clamp_is_stable_with_the_coupling_and_not_without() {
    check(
        DVec3::new(-3.0, 15.0, 7.5) * MM,
        DVec3::new(3.0, 15.0, 7.5) * MM,
        "next to the clamp",
    );
}
