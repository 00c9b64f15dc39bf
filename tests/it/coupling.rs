//! Stable contact on the hand: a simulated hand (mass, spring and damper towards a target)
//! presses a stiff object (the cube at E = 1 MPa) for 10 s of simulated time at 1 kHz, the
//! device force held between ticks (zero-order hold) and the hand integrated in 0.1 ms steps.
//! With the finger's limits set to the Falcon preset (its force rendered through the virtual
//! coupling) the energy the device puts into the hand stops growing and the motion settles;
//! without them, the same press oscillates. Run twice: in process through `HapticWorld`, and
//! over a real loopback socket with `serve --clock device` and the example device
//! (`examples/udp_device.rs`) in lockstep.

use glam::DVec3;
use std::sync::atomic::AtomicBool;
use std::time::Duration;

use touchfem::devices::udp::Clock;
use touchfem::runtime::serve::{serve, ServeOptions};
use touchfem::runtime::{HapticWorld, WorldSample};
use touchfem::scene::{SceneSource, World};

use crate::udp_device;

const MM: f64 = 1e-3;
/// The relaxed hand of both runs: 0.1 kg, 100 N/m, 1 N·s/m.
const HAND: udp_device::Hand = udp_device::Hand {
    mass: 0.1,
    k: 100.0,
    b: 1.0,
};

fn stiff_cube(device: &str, limits: bool) -> World {
    let limits = if limits { "limits = \"falcon\"\n" } else { "" };
    World::from_source_with(
        &SceneSource {
            name: "stiff".into(),
            text: format!("unit = \"mm\"\n[[object]]\nmesh = \"cube\"\nyoung = 1.0e6\n[[finger]]\ndevice = \"{device}\"\n{limits}[haptics]\nmax_force_n = 8.0\n"),
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
    /// Ticks whose force a limit changed (`HapticWorld::limited`; in process only).
    limited: usize,
    /// First tick of the window in which the press must have settled: [`SETTLED_FROM`], or
    /// later over a socket when the machine stalled the loop inside that window.
    settled_from: usize,
}

/// The hand's target: from `start` to `end` over 1 s, then held.
fn target(start: DVec3, end: DVec3) -> impl Fn(f64) -> DVec3 {
    move |t| start.lerp(end, t.min(1.0))
}

/// The press in process, through the haptic path as `run_haptic` drives it.
fn press(world: &World, start: DVec3, end: DVec3) -> Outcome {
    press_on(world, None, start, end)
}

/// [`press`] on `world`'s object 0 cut to `cut` (installed before the first tick).
fn press_on(
    world: &World,
    cut: Option<std::sync::Arc<touchfem::runtime::cutting::CutBody>>,
    start: DVec3,
    end: DVec3,
) -> Outcome {
    let mut hw = HapticWorld::new(world);
    if let Some(body) = cut {
        hw.install_cut(0, body);
    }
    let mut s = WorldSample::default();
    let aim = target(start, end);
    let mut x = start;
    let mut v = DVec3::ZERO;
    let mut out = Outcome {
        work: Vec::new(),
        x: Vec::new(),
        max_force: 0.0,
        limited: 0,
        settled_from: SETTLED_FROM,
    };
    let mut work = 0.0;
    for tick in 0..10_000 {
        let t = tick as f64 * 1e-3;
        let mut f = [DVec3::ZERO];
        hw.step(&[x], &mut f, &mut s);
        let force = f[0];
        out.limited += usize::from(hw.limited(0));
        out.max_force = out.max_force.max(force.length());
        work += HAND.step(&mut x, &mut v, aim(t), force, 1e-3, 10);
        out.work.push(work);
        out.x.push(x);
    }
    out
}

/// The first tick of the window in which a press must have settled (the last second).
const SETTLED_FROM: usize = 9_000;

/// The same press over loopback: `serve --clock device` and the example device in lockstep,
/// recorded to `record`. A stall of this machine near the watchdog (20 ms) is a real
/// disturbance over a socket: the contact is released, the force ramped back in, and the hand
/// moves. A run with such a stall in or just before the settle window is run again (at most
/// five times; the stall is measured by the client's clock, not read from the outcome), and
/// so is one with more late answers than this VM's stalls explain. If every run stalled
/// there, the one whose last stall came earliest is judged on the ticks from
/// [`SETTLE_AFTER_STALL`] after that stall, at least [`SHORTEST_WINDOW`] of them.
/// Shorter stalls, every few ticks when the machine is loaded, leave the press settled.
fn press_over_udp(world: &World, start: DVec3, end: DVec3, record: &std::path::Path) -> Outcome {
    // The ramp (0.1 s) and the hand's decay in contact (~0.05 s) before the window.
    let quiet_from = (SETTLED_FROM - SETTLE_AFTER_STALL) as u64;
    let mut best: Option<(usize, Outcome)> = None;
    for attempt in 1..=5 {
        let (mut out, stalls, late) = press_over_udp_once(world, start, end, record);
        let long: Vec<(u64, f64)> = stalls.into_iter().filter(|s| s.1 >= 0.01).collect();
        eprintln!(
            "attempt {attempt}: {late} late answers; stalls of 10 ms or more (tick, s): {long:?}"
        );
        // Every force arrives in time but for the machine's own stalls: this VM misses 1–6
        // deadlines in 20 s even for a bare C loop while the other core is busy (the test
        // suite runs beside this test), and one such stall (80 ms) made one answer late here.
        if late > 5 {
            continue;
        }
        let last_stall = long.iter().map(|s| s.0).filter(|&t| t >= quiet_from).max();
        let Some(last_stall) = last_stall else {
            return out;
        };
        out.settled_from = last_stall as usize + SETTLE_AFTER_STALL;
        if best.as_ref().is_none_or(|b| out.settled_from < b.0) {
            best = Some((out.settled_from, out));
        }
    }
    let (from, out) =
        best.expect("every force arrived, all but a stall's: too many late in every run");
    assert!(
        from + SHORTEST_WINDOW <= out.x.len(),
        "the machine stalled the loop in every run's last {} ticks",
        out.x.len() - from
    );
    eprintln!("every run stalled in the settle window: judged from tick {from}");
    out
}

/// Ticks a press takes to settle again after a stall released its contact: the ramp
/// (0.1 s) and the hand's decay in contact (~0.05 s), with a margin.
const SETTLE_AFTER_STALL: usize = 300;

/// Fewest ticks a settle window may have.
const SHORTEST_WINDOW: usize = 200;

fn press_over_udp_once(
    world: &World,
    start: DVec3,
    end: DVec3,
    record: &std::path::Path,
) -> (Outcome, Vec<(u64, f64)>, u64) {
    let stop = AtomicBool::new(false);
    let (tx, rx) = std::sync::mpsc::channel();
    let rep = std::thread::scope(|s| {
        let server = s.spawn(|| {
            let opts = ServeOptions {
                addr: "127.0.0.1:0".parse().unwrap(),
                allow_remote: false,
                key: None,
                seconds: None,
                record: Some(record.to_path_buf()),
                watchdog: Duration::from_millis(20),
                clock: Clock::Device,
                placement: Default::default(),
                floor_seconds: None,
            };
            serve(world, &opts, &stop, |a| tx.send(a).unwrap()).unwrap()
        });
        let addr = rx.recv_timeout(Duration::from_secs(60)).unwrap();
        let rep = udp_device::run_client(
            addr,
            10.0,
            HAND,
            udp_device::Timing::Lockstep,
            target(start, end),
        )
        .unwrap();
        stop.store(true, std::sync::atomic::Ordering::Relaxed);
        let served = server.join().unwrap();
        assert_eq!(served.packets_dropped, 0, "{:?}", served.udp);
        assert_eq!(served.clock, "device");
        rep
    });
    assert_eq!(rep.ticks, 10_000);
    (
        Outcome {
            work: rep.work,
            x: rep.positions,
            max_force: rep.max_force_n,
            limited: 0,
            settled_from: SETTLED_FROM,
        },
        rep.stalls,
        rep.late,
    )
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

fn check(with: &Outcome, without: &Outcome, what: &str) {
    check_within(with, without, what, 1e-6);
}

/// [`check`] with the coupled press's energy growth held under `energy_j` (over a real
/// socket the device's measured tick times jitter, and the damping follows them).
fn check_within(with: &Outcome, without: &Outcome, what: &str, energy_j: f64) {
    let late = |o: &Outcome| peak_to_peak(&o.x[o.settled_from..]);
    // Energy the device put into the hand from 2 s on (the hold): it never grows.
    let grow = |o: &Outcome| {
        o.work[2000..]
            .iter()
            .map(|e| e - o.work[2000])
            .fold(f64::NEG_INFINITY, f64::max)
    };
    eprintln!(
        "{what}: coupled p-p {:.2e} m, energy growth {:.2e} J, max F {:.3} N; uncoupled p-p {:.2e} m, energy growth {:.2e} J, max F {:.3} N",
        late(with), grow(with), with.max_force, late(without), grow(without), without.max_force
    );
    assert!(late(with) < 1e-6, "{what}: the coupled press settles");
    assert!(
        grow(with) < energy_j,
        "{what}: the coupling puts no energy into the hand"
    );
    assert!(with.max_force <= 8.0 + 1e-9 && with.max_force > 0.05);
    // The same press without the coupling oscillates: the test can fail.
    assert!(
        late(without) > 10.0 * late(with).max(1e-7) || grow(without) > 1e-4,
        "{what}: without the coupling the press should not be stable"
    );
}

fn top() -> (DVec3, DVec3) {
    (
        DVec3::new(15.0, 15.0, 33.0) * MM,
        DVec3::new(15.0, 15.0, 27.0) * MM,
    )
}

fn next_to_the_clamp() -> (DVec3, DVec3) {
    (
        DVec3::new(-3.0, 15.0, 7.5) * MM,
        DVec3::new(3.0, 15.0, 7.5) * MM,
    )
}

#[test]
fn pressing_the_stiff_cube_is_stable_with_the_falcons_limits_and_not_without() {
    let (a, b) = top();
    let with = press(&stiff_cube("pointer", true), a, b);
    let without = press(&stiff_cube("pointer", false), a, b);
    check(&with, &without, "top");
    // The coupling shapes the force while touching (the limited flag). Without it only the
    // force bound's rate limit acts, on the buzzing hand: it stays under max_force_n.
    assert!(with.limited > 5000, "{}", with.limited);
    assert!(without.max_force <= 8.0 + 1e-12, "{}", without.max_force);
}

#[test]
fn pressing_next_to_the_clamp_is_stable_with_the_falcons_limits_and_not_without() {
    let (a, b) = next_to_the_clamp();
    let with = press(&stiff_cube("pointer", true), a, b);
    let without = press(&stiff_cube("pointer", false), a, b);
    check(&with, &without, "next to the clamp");
}

#[test]
fn over_udp_the_simulated_hand_is_stable_with_the_falcons_limits_and_not_without() {
    for (what, (a, b)) in [("udp top", top()), ("udp clamp", next_to_the_clamp())] {
        let dir = tempfile::tempdir().unwrap();
        let with_world = stiff_cube("udp", true);
        let rec = dir.path().join("with.tfsession");
        let with = press_over_udp(&with_world, a, b, &rec);
        // The device clocks the loop, and the haptic path counts its measured time (a
        // lockstep client answers faster than 1 kHz): the recorded session, with each tick's
        // dt, replays in process to the same forces bit for bit.
        let s = touchfem::runtime::session::read(&rec).unwrap();
        assert_eq!(s.header.version, 2);
        assert!(s.ticks.iter().all(|t| t.dt.is_finite() && t.dt >= 0.0));
        let r = touchfem::runtime::session::replay(&with_world, &s).unwrap();
        assert!(r.ticks >= 9_990, "{what}: {} ticks", r.ticks);
        assert_eq!(r.max_force_diff_n, 0.0, "{what}: over UDP vs replayed");
        let without = press_over_udp(
            &stiff_cube("udp", false),
            a,
            b,
            &dir.path().join("without.tfsession"),
        );
        // Over the wire: a thousandth of what the uncoupled press gains (about 3 J).
        check_within(&with, &without, what, 1e-3);
    }
}

/// The stiff cube touched by a fingertip (a 5 mm sphere) with friction, with or without the
/// Falcon's limits.
fn stiff_cube_fingertip(limits: bool) -> World {
    let limits = if limits { "limits = \"falcon\"\n" } else { "" };
    World::from_source_with(
        &SceneSource {
            name: "stiff".into(),
            text: format!("unit = \"mm\"\n[[object]]\nmesh = \"cube\"\nyoung = 1.0e6\nfriction = {{ static = 0.6, dynamic = 0.4 }}\n[[finger]]\ndevice = \"pointer\"\ntool = {{ sphere = 5.0 }}\n{limits}[haptics]\nmax_force_n = 8.0\n"),
            dir: ".".into(),
            label: "stiff cube, fingertip".into(),
        },
        None,
    )
    .unwrap()
}

#[test]
fn a_fingertip_with_friction_stays_passive_through_the_coupling_and_the_bound() {
    // Pressed straight down, and pressed while the hand is pulled sideways (a rub held at
    // its end): with the Falcon's limits the press settles and the device puts no energy
    // into the hand; friction only takes energy out.
    let r = DVec3::new(0.0, 0.0, 5.0) * MM;
    let (a, b) = top();
    for (what, end) in [
        ("press", b + r),
        ("rub", b + r + DVec3::new(4.0, 0.0, 0.0) * MM),
    ] {
        let with = press(&stiff_cube_fingertip(true), a + r, end);
        let late = peak_to_peak(&with.x[SETTLED_FROM..]);
        let grow = with.work[2000..]
            .iter()
            .map(|e| e - with.work[2000])
            .fold(f64::NEG_INFINITY, f64::max);
        eprintln!(
            "fingertip {what}: p-p {late:.2e} m, energy growth {grow:.2e} J, max F {:.3} N",
            with.max_force
        );
        assert!(late < 1e-6, "{what}: settles ({late})");
        assert!(grow < 1e-6, "{what}: energy growth {grow}");
        assert!(with.max_force <= 8.0 + 1e-9 && with.max_force > 0.05);
    }
}

#[test]
fn presses_beside_a_cut_stay_passive_through_the_coupling_and_the_bound() {
    // The stiff cube cut by a slit 10 mm deep across its top at x = 11 mm, pressed beside the
    // slit with a point and with a fingertip through the Falcon's limits: each press settles,
    // the device puts no energy into the hand, and the force stays within the bound.
    use touchfem::runtime::cutting::{Cutter, Stroke};
    for tool in ["", "tool = { sphere = 5.0 }\n"] {
        let world = World::from_source_with(
            &SceneSource {
                name: "stiff-cut".into(),
                text: format!("unit = \"mm\"\n[[object]]\nmesh = \"cube\"\nyoung = 1.0e6\ncuttable = \"all\"\n[[finger]]\ndevice = \"pointer\"\n{tool}limits = \"falcon\"\n[haptics]\nmax_force_n = 8.0\n"),
                dir: ".".into(),
                label: "stiff cube, cut".into(),
            },
            None,
        )
        .unwrap();
        let body = Cutter::new(&world)
            .unwrap()
            .apply(&Stroke {
                object: 0,
                from: DVec3::new(11.0, -1.0, 29.99) * MM,
                to: DVec3::new(11.0, 31.0, 29.99) * MM,
                inward: DVec3::NEG_Z,
                depth: 10.0 * MM,
            })
            .unwrap()
            .expect("the slit");
        let r = if tool.is_empty() {
            DVec3::ZERO
        } else {
            DVec3::new(0.0, 0.0, 5.0) * MM
        };
        let (a, b) = (
            DVec3::new(20.0, 15.0, 33.0) * MM + r,
            DVec3::new(20.0, 15.0, 27.0) * MM + r,
        );
        let cut = press_on(&world, Some(body.clone()), a, b);
        let uncut = press_on(&world, None, a, b);
        let late = peak_to_peak(&cut.x[SETTLED_FROM..]);
        let grow = cut.work[2000..]
            .iter()
            .map(|e| e - cut.work[2000])
            .fold(f64::NEG_INFINITY, f64::max);
        eprintln!(
            "beside a cut ({} copies, {} tets), {}: p-p {late:.2e} m, energy growth {grow:.2e} J, max F {:.3} N (uncut {:.3} N)",
            body.nodes_split,
            body.tets_removed,
            if tool.is_empty() { "point" } else { "fingertip" },
            cut.max_force,
            uncut.max_force
        );
        // The default blade parts the cube: copies of the nodes on the slit.
        assert!(body.nodes_split > 0);
        assert!(late < 1e-6, "settles ({late})");
        assert!(grow < 1e-6, "energy growth {grow}");
        assert!(cut.max_force <= 8.0 + 1e-9 && cut.max_force > 0.05);
    }
}
