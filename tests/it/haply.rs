//! The Haply Inverse3 through a mock Haply Inverse Service on loopback (no hardware): a scripted
//! cursor presses into the cube, holds and lifts; the forces the service receives are zero
//! outside the object, bounded, equal to the library's coupled force once the press settled,
//! and zero after stop and within the watchdog of a stall; malformed messages, a second device
//! and a disconnect are counted and never stop the service.

use glam::{DMat3, DVec3};
use std::sync::atomic::AtomicBool;
use std::time::Duration;

use touchfem::contact::force::{finger_force, ForceBc, ForceModel};
use touchfem::contact::GodObject;
use touchfem::runtime::serve::LoopOptions;
use touchfem::scene::{DeviceSpec, SceneSource, World};
use touchfem_app::haply::mock::{MockConfig, MockLog, MockService};
use touchfem_app::haply::{serve_haply, HaplyOptions, HaplyReport};

const MM: f64 = 1e-3;
/// The device point that maps to the top face's middle (15, 15, 30) mm: the default centre.
const CENTRE: [f64; 3] = [0.0, -0.12, 0.15];
const WATCHDOG_MS: u64 = 20;

/// The cube with one Haply finger at `url` (device `id` if given), its workspace centred on
/// the middle of the top face, scale 1.
fn cube(url: &str, id: Option<&str>, max_force_n: f64) -> World {
    let id = id.map_or(String::new(), |i| format!(", device_id = \"{i}\""));
    let text = format!(
        "unit = \"mm\"\n[[object]]\nmesh = \"cube\"\n[[finger]]\ndevice = \"haply\"\nlimits = \"inverse3\"\nhaply = {{ url = \"{url}\"{id}, scene_centre = [15.0, 15.0, 30.0] }}\n[haptics]\nmax_force_n = {max_force_n}\n"
    );
    World::from_source_with(
        &SceneSource {
            name: "haply".into(),
            text,
            dir: ".".into(),
            label: "haply scene".into(),
        },
        None,
    )
    .unwrap()
}

/// A scene point (mm) as the device's point (m).
fn device(scene_mm: [f64; 3]) -> [f64; 3] {
    [
        CENTRE[0] + (scene_mm[0] - 15.0) * MM,
        CENTRE[1] + (scene_mm[1] - 15.0) * MM,
        CENTRE[2] + (scene_mm[2] - 30.0) * MM,
    ]
}

const ABOVE: [f64; 3] = [12.0, 14.0, 36.0];
const PRESSED: [f64; 3] = [12.0, 14.0, 27.0];

/// Above until 0.3 s, down to 3 mm into the top face by 0.5 s, held until 1.3 s, up by 1.5 s.
fn press(t: f64) -> [f64; 3] {
    let lerp = |a: [f64; 3], b: [f64; 3], s: f64| {
        let s = s.clamp(0.0, 1.0);
        device([0, 1, 2].map(|i| a[i] + (b[i] - a[i]) * s))
    };
    match t {
        t if t < 0.3 => device(ABOVE),
        t if t < 0.5 => lerp(ABOVE, PRESSED, (t - 0.3) / 0.2),
        t if t < 1.3 => device(PRESSED),
        t => lerp(PRESSED, ABOVE, (t - 1.3) / 0.2),
    }
}

/// The library's force for the held press, through the Inverse3's coupling at rest:
/// `(I + K/k_c)⁻¹ F`, with `F` the paper's force and `K` the paper's contact stiffness.
fn expected(w: &World) -> DVec3 {
    let o = &w.objects[0].body;
    let c = GodObject::new(DVec3::from_array(ABOVE) * MM)
        .update(&o.surface, DVec3::from_array(PRESSED) * MM)
        .unwrap();
    let f = finger_force(
        &o.compliance,
        &c,
        ForceModel::Paper,
        &mut ForceBc::default(),
    )
    .feedback;
    let mut k = DMat3::ZERO;
    for a in 0..3 {
        let kv = match o.compliance.col_of(c.nodes[a]) {
            Some(col) => o.compliance.diag_inv(col),
            None => DMat3::from_diagonal(DVec3::splat(1.0 / o.compliance.clamp_compliance())),
        };
        k += kv * c.alpha[a];
    }
    let k_c = w.fingers[0].limits.as_ref().unwrap().max_stiffness_n_per_m;
    (DMat3::IDENTITY + k / k_c).inverse() * f
}

/// Serves `world` for `secs` against `mock` with the test's watchdog ([`WATCHDOG_MS`]);
/// returns the report and the mock's log.
fn run(world: &World, mock: MockService, secs: f64) -> (HaplyReport, MockLog) {
    run_with(world, mock, secs, WATCHDOG_MS)
}

/// [`run`] with a watchdog of `watchdog_ms`.
fn run_with(
    world: &World,
    mock: MockService,
    secs: f64,
    watchdog_ms: u64,
) -> (HaplyReport, MockLog) {
    let opts = HaplyOptions {
        loop_options: LoopOptions {
            seconds: Some(secs),
            ..LoopOptions::default()
        },
        watchdog: Duration::from_millis(watchdog_ms),
    };
    let report = serve_haply(world, &opts, &AtomicBool::new(false), |_| {}).unwrap();
    // Let the close reach the mock before it stops.
    std::thread::sleep(Duration::from_millis(50));
    (report, mock.stop())
}

#[test]
fn a_press_through_the_mock_service_gets_the_librarys_force_and_zero_at_the_end() {
    let mock = MockService::start(MockConfig::one("049D", press)).unwrap();
    let world = cube(&mock.url(), None, 8.5);
    let want = expected(&world);
    // This test checks the forces and the close, not the watchdog (the stall test does): a
    // watchdog of 200 ms, so that a loaded machine (the tests run three at a time on two
    // cores) that delays the mock's thread past 20 ms does not turn the press stale.
    let (r, log) = run_with(&world, mock, 1.8, 200);
    let rec = &log.received;
    assert!(rec.len() > 500, "{} commands in 1.8 s", rec.len());
    let bound = 8.5f64.min(10.0);
    for m in rec {
        let f = DVec3::from_array(m.force);
        assert!(f.is_finite() && f.length() <= bound + 1e-9, "{m:?}");
        // Outside the object (before the press, after the lift, with 50 ms for the exchange).
        if m.t < 0.3 || m.t > 1.55 {
            assert_eq!(f, DVec3::ZERO, "a force outside the object: {m:?}");
        }
    }
    // Held: the force once the press settled (the last 200 ms of the hold).
    let held: Vec<DVec3> = rec
        .iter()
        .filter(|m| m.t > 1.05 && m.t < 1.25)
        .map(|m| DVec3::from_array(m.force))
        .collect();
    assert!(held.len() > 50, "{}", held.len());
    for f in &held {
        let err = (*f - want).length() / want.length();
        // The same god-object, model, coupling and bound as the engine: at rest the coupled
        // force is (I + K/k_c)⁻¹ F exactly; the positions cross the wire as f64 JSON (exact),
        // so only rounding remains.
        assert!(err < 1e-6, "held {f} vs {want} ({err:e})");
    }
    assert!(want.length() > 0.05 && want.z > 0.0, "{want}");
    let last = rec.last().unwrap();
    assert_eq!(last.force, [0.0; 3], "the last message is a zero force");
    assert_eq!(log.clean_closes, 1, "a WebSocket close");
    assert_eq!(r.haply_messages, rec.len() as u64);
    assert_eq!(
        (r.haply_stale, r.haply_malformed, r.haply_reconnects),
        (0, 0, 0)
    );
    assert_eq!(r.devices, ["049D"]);
    assert!(r.run.max_force_n <= bound && r.run.max_force_n > 0.05);
    assert!(r.haply[0].rtt_us_p99.is_finite());
}

#[test]
fn a_stalled_service_gets_zero_force_within_the_watchdog() {
    let mut cfg = MockConfig::one("A", |t| {
        if t < 0.3 {
            device(ABOVE)
        } else {
            device(PRESSED)
        }
    });
    cfg.stall = Some((0.8, 0.3));
    let mock = MockService::start(cfg).unwrap();
    let world = cube(&mock.url(), None, 8.5);
    let (r, log) = run(&world, mock, 1.5);
    let rec = &log.received;
    // Pressing before the stall; during it, every force sent after the watchdog is zero.
    assert!(rec
        .iter()
        .any(|m| m.t > 0.6 && m.t < 0.8 && DVec3::from_array(m.force).length() > 0.05));
    let during: Vec<_> = rec
        .iter()
        .filter(|m| m.t > 0.8 + WATCHDOG_MS as f64 * 1e-3 + 0.002 && m.t < 1.1)
        .collect();
    assert!(
        during.len() >= 5,
        "zero-force polls while stalled: {}",
        during.len()
    );
    assert!(during.iter().all(|m| m.force == [0.0; 3]), "{during:?}");
    // The press resumes after the stall (ramped in), and the end is a zero force.
    assert!(rec
        .iter()
        .any(|m| m.t > 1.2 && DVec3::from_array(m.force).length() > 0.05));
    assert_eq!(rec.last().unwrap().force, [0.0; 3]);
    assert!(r.haply_stale >= 1, "{r:?}");
    assert_eq!(r.stale_periods, r.haply_stale);
}

#[test]
fn malformed_messages_a_second_device_and_a_disconnect_are_counted_not_fatal() {
    // Two devices; the finger names the second, which presses; the first stays above.
    let mut cfg = MockConfig::one("FIRST", |_| device(ABOVE));
    cfg.devices.push((
        "SECOND".into(),
        std::sync::Arc::new(|t| {
            if t < 0.2 {
                device(ABOVE)
            } else {
                device(PRESSED)
            }
        }),
    ));
    cfg.malformed_every = 50;
    cfg.disconnect_at = Some(0.7);
    let mock = MockService::start(cfg).unwrap();
    let world = cube(&mock.url(), Some("SECOND"), 8.5);
    let (r, log) = run(&world, mock, 1.6);
    assert!(r.haply_malformed >= 5, "{r:?}");
    assert!(
        r.haply_reconnects >= 1 && r.haply[0].disconnects >= 1,
        "{r:?}"
    );
    assert_eq!(log.connections, 1 + r.haply_reconnects);
    assert!(log.received.iter().all(|m| m.device_id == "SECOND"));
    // Pressing before and after the disconnect: the second device's path drives the finger.
    let pressing = |a: f64, b: f64| {
        log.received
            .iter()
            .any(|m| m.t > a && m.t < b && DVec3::from_array(m.force).length() > 0.05)
    };
    assert!(pressing(0.4, 0.7) && pressing(1.2, 1.6));
    assert_eq!(log.received.last().unwrap().force, [0.0; 3]);
    // No device "MISSING": an error, not a panic.
    let mock = MockService::start(MockConfig::one("ONLY", |_| device(ABOVE))).unwrap();
    let world = cube(&mock.url(), Some("MISSING"), 8.5);
    let opts = HaplyOptions {
        loop_options: LoopOptions::default(),
        watchdog: Duration::from_millis(WATCHDOG_MS),
    };
    let e = serve_haply(&world, &opts, &AtomicBool::new(false), |_| {}).unwrap_err();
    assert!(
        e.to_string().contains("MISSING") && e.to_string().contains("ONLY"),
        "{e}"
    );
}

#[test]
fn a_small_scene_bound_caps_every_force_sent() {
    let mock = MockService::start(MockConfig::one("A", press)).unwrap();
    let world = cube(&mock.url(), None, 0.1);
    let (r, log) = run(&world, mock, 0.9);
    let max = log
        .received
        .iter()
        .map(|m| DVec3::from_array(m.force).length())
        .fold(0.0, f64::max);
    assert!(max <= 0.1 + 1e-12 && max > 0.09, "{max}");
    assert!(r.run.max_force_n <= 0.1 + 1e-12);
}

#[test]
fn haply_scenes_parse_and_refuse_bad_tables() {
    let w = cube("ws://127.0.0.1:1", Some("049D"), 8.5);
    let DeviceSpec::Haply(h) = &w.fingers[0].device else {
        panic!("{:?}", w.fingers[0].device)
    };
    assert_eq!(h.device_id.as_deref(), Some("049D"));
    assert!((h.workspace.scene_centre - DVec3::new(0.015, 0.015, 0.030)).length() < 1e-12);
    assert_eq!(h.workspace.device_centre, DVec3::from_array(CENTRE));
    for (bad, key) in [
        ("haply = { url = \"http://x\" }", "haply.url"),
        ("haply = { scale = -1.0 }", "haply.scale"),
        ("haply = { scale = 1.0, colour = 1 }", "colour"),
    ] {
        let text = format!(
            "unit = \"mm\"\n[[object]]\nmesh = \"cube\"\n[[finger]]\ndevice = \"haply\"\n{bad}\n"
        );
        let e = crate::common::world_from_text(&text)
            .err()
            .expect(bad)
            .to_string();
        assert!(e.contains(key), "{bad}: {e}");
    }
    let text =
        "unit = \"mm\"\n[[object]]\nmesh = \"cube\"\n[[finger]]\ndevice = \"udp\"\nhaply = {}\n";
    let e = crate::common::world_from_text(text)
        .err()
        .unwrap()
        .to_string();
    assert!(e.contains("only a haply finger"), "{e}");
}

#[test]
fn serve_cube_haply_against_the_mock_from_the_command_line() {
    let mock = MockService::start(MockConfig::one("049D", |_| device(ABOVE))).unwrap();
    let url = mock.url();
    let (code, out, err) =
        crate::common::touchfem_status(&["serve", "cube", "--haply", &url, "--seconds", "0.5"]);
    let log = mock.stop();
    assert_eq!(code, 0, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    for k in [
        "ticks",
        "max_force_n",
        "haply_messages",
        "haply_stale",
        "haply_malformed",
    ] {
        assert!(v[k].is_number(), "{k}: {v}");
    }
    assert_eq!(v["ticks"], 500);
    assert_eq!(v["limits"][0]["name"], "inverse3");
    assert_eq!(log.received.last().map(|m| m.force), Some([0.0; 3]));
    // No service there: one error line, status 2.
    let (code, _, err) =
        crate::common::touchfem_status(&["serve", "cube", "--haply", "ws://127.0.0.1:9"]);
    assert_eq!(code, 2, "{err}");
    assert!(err.contains("Haply Inverse Service"), "{err}");
}
