//! The UDP device bridge over a real loopback socket: a press gives the library's force, and
//! the bridge survives lost, reordered, duplicated, malformed and random datagrams, a client
//! that vanishes (watchdog), one that restarts, and two at once.

mod common;

use glam::DVec3;
use std::net::{SocketAddr, UdpSocket};
use std::sync::atomic::AtomicBool;
use std::time::{Duration, Instant};

use touchfem::contact::GodObject;
use touchfem::devices::udp::{
    decode_force, encode_position, Clock, ForcePacket, FLAG_STALE, FLAG_TOUCHING,
};
use touchfem::force::{finger_force, ForceBc, ForceModel};
use touchfem::runtime::serve::{serve, ServeOptions, ServeReport};
use touchfem::scene::{SceneSource, World};

const MM: f64 = 1e-3;

fn cube_world() -> World {
    World::from_source_with(
        &SceneSource {
            name: "udp".into(),
            text: "unit = \"mm\"\n[[object]]\nmesh = \"cube\"\n[[finger]]\ndevice = \"udp\"\n[[finger]]\ndevice = \"udp\"\n".into(),
            dir: ".".into(),
            label: "udp scene".into(),
        },
        None,
    )
    .unwrap()
}

/// Runs `serve` for `secs` on a free loopback port in a thread; calls `client(addr)` meanwhile.
fn with_server(secs: f64, client: impl FnOnce(SocketAddr)) -> ServeReport {
    with_server_clocked(secs, Clock::Host, client)
}

/// [`with_server`] with the given clock.
fn with_server_clocked(secs: f64, clock: Clock, client: impl FnOnce(SocketAddr)) -> ServeReport {
    let world = cube_world();
    let stop = AtomicBool::new(false);
    let (tx, rx) = std::sync::mpsc::channel();
    std::thread::scope(|s| {
        let h = s.spawn(|| {
            let opts = ServeOptions {
                addr: "127.0.0.1:0".parse().unwrap(),
                allow_remote: false,
                seconds: Some(secs),
                record: None,
                watchdog: Duration::from_millis(20),
                clock,
                placement: Default::default(),
                floor_seconds: None,
            };
            serve(&world, &opts, &stop, |a| tx.send(a).unwrap()).unwrap()
        });
        let addr = rx.recv_timeout(Duration::from_secs(30)).unwrap();
        client(addr);
        h.join().unwrap()
    })
}

struct Client {
    sock: UdpSocket,
    to: SocketAddr,
    buf: [u8; 256],
}

impl Client {
    fn new(to: SocketAddr) -> Client {
        let sock = UdpSocket::bind("127.0.0.1:0").unwrap();
        sock.set_read_timeout(Some(Duration::from_millis(50)))
            .unwrap();
        Client {
            sock,
            to,
            buf: [0; 256],
        }
    }
    fn send(&mut self, seq: u32, p: &[DVec3]) {
        let mut b = [0u8; 128];
        let n = encode_position(seq, p, &mut b);
        self.sock.send_to(&b[..n], self.to).unwrap();
    }
    fn raw(&self, bytes: &[u8]) {
        self.sock.send_to(bytes, self.to).unwrap();
    }
    /// Drains force packets; returns the newest.
    fn latest(&mut self) -> Option<ForcePacket> {
        let mut last = None;
        self.sock.set_nonblocking(true).unwrap();
        while let Ok((n, _)) = self.sock.recv_from(&mut self.buf) {
            last = decode_force(&self.buf[..n]).or(last);
        }
        self.sock.set_nonblocking(false).unwrap();
        last
    }
    /// Sends `p` with increasing seq from `seq0` every millisecond for `ms`; returns the
    /// newest force packet and the next seq.
    fn hold(&mut self, seq0: u32, p: &[DVec3], ms: u32) -> (Option<ForcePacket>, u32) {
        let mut last = None;
        for k in 0..ms {
            self.send(seq0 + k, p);
            std::thread::sleep(Duration::from_millis(1));
            last = self.latest().or(last);
        }
        (last, seq0 + ms)
    }
}

fn above() -> DVec3 {
    DVec3::new(12.0, 14.0, 36.0) * MM
}
fn pressed() -> DVec3 {
    DVec3::new(12.0, 14.0, 27.0) * MM
}

/// The library's force for the same press (paper model).
fn expected() -> DVec3 {
    let w = cube_world();
    let o = &w.objects[0].scene;
    let c = GodObject::new(above())
        .update(&o.surface, pressed())
        .unwrap();
    finger_force(
        &o.compliance,
        &c,
        ForceModel::Paper,
        &mut ForceBc::default(),
    )
    .feedback
}

#[test]
fn a_press_over_loopback_gets_the_librarys_force_and_survives_bad_packets() {
    let want = expected();
    let mut malformed_sent = 0u64;
    let mut old_sent = 0u64;
    let r = with_server(1.5, |addr| {
        let mut c = Client::new(addr);
        let far = DVec3::new(0.5, 0.5, 0.5);
        let (f, seq) = c.hold(1, &[above(), far], 50);
        let f = f.expect("force packets arrive");
        assert_eq!(f.n, 2);
        assert_eq!(f.forces[0], DVec3::ZERO);
        assert_eq!(f.flags[0] & FLAG_TOUCHING, 0);
        // Press in over 100 ms, then hold.
        let mut seq = seq;
        for k in 0..=100 {
            let p = above().lerp(pressed(), k as f64 / 100.0);
            c.send(seq, &[p, far]);
            seq += 1;
            std::thread::sleep(Duration::from_millis(1));
        }
        let (f, mut seq) = c.hold(seq, &[pressed(), far], 100);
        let f = f.unwrap();
        assert!(f.flags[0] & FLAG_TOUCHING != 0, "{f:?}");
        assert!(
            (f.forces[0] - want).length() <= 1e-9 * want.length(),
            "{:?} vs {want}",
            f.forces[0]
        );
        assert!(
            f.seq < seq && f.seq >= seq - 20,
            "the force answers a recent packet: {}",
            f.seq
        );

        // Old, duplicate and reordered packets: dropped; the force stays.
        for s in [1, seq - 1, seq - 50, 3] {
            c.send(s, &[DVec3::new(15.0, 15.0, 20.0) * MM, far]);
            old_sent += 1;
        }
        // Malformed: sizes, magic, counts, NaN; then random datagrams (a fuzz run).
        let mut b = [0u8; 128];
        let n = encode_position(seq + 1000, &[pressed()], &mut b);
        let mut cases: Vec<Vec<u8>> = vec![
            b[..n - 1].to_vec(),
            [&b[..n], &[0u8]].concat(),
            [b"TFQ1".as_slice(), &b[4..n]].concat(),
            vec![],
        ];
        let mut zero_n = b[..n].to_vec();
        zero_n[8] = 0;
        cases.push(zero_n);
        let mut five = b[..n].to_vec();
        five[8] = 5;
        cases.push(five);
        let mut nan = b[..n].to_vec();
        nan[20..28].copy_from_slice(&f64::NAN.to_le_bytes());
        cases.push(nan);
        let mut rng = 0x9E3779B97F4A7C15u64;
        for _ in 0..2000 {
            rng ^= rng << 13;
            rng ^= rng >> 7;
            rng ^= rng << 17;
            let len = (rng % 120) as usize;
            let mut d: Vec<u8> = (0..len).map(|i| (rng >> (i % 56)) as u8).collect();
            if rng.is_multiple_of(3) && len >= 4 {
                d[..4].copy_from_slice(b"TFP1"); // right magic, wrong rest
            }
            cases.push(d);
        }
        for d in &cases {
            if touchfem::devices::udp::decode_position(d).is_none() {
                c.raw(d);
                malformed_sent += 1;
                if malformed_sent.is_multiple_of(20) {
                    c.send(seq, &[pressed(), far]);
                    seq += 1;
                    std::thread::sleep(Duration::from_millis(1));
                }
            }
        }
        let (f, _) = c.hold(seq, &[pressed(), far], 50);
        let f = f.unwrap();
        assert!(
            (f.forces[0] - want).length() <= 1e-9 * want.length(),
            "after the storm: {f:?}"
        );
    });
    // Every malformed datagram is counted (a few may be lost by the kernel's loopback buffer
    // on a loaded machine before the bridge reads them: allow 1 %).
    assert!(
        r.udp.malformed * 100 >= malformed_sent * 99,
        "{:?} vs {malformed_sent}",
        r.udp
    );
    assert!(r.udp.malformed <= malformed_sent);
    assert!(r.udp.out_of_order >= old_sent, "{:?}", r.udp);
    assert_eq!(
        r.packets_dropped,
        r.udp.malformed + r.udp.out_of_order + r.udp.foreign
    );
    assert_eq!(r.ticks, 1500);
    assert!(r.max_force_n > 0.1 && r.max_force_n <= 8.5);
}

#[test]
fn a_vanished_client_gets_zero_force_and_may_restart_a_second_one_waits() {
    let r = with_server(1.2, |addr| {
        let mut a = Client::new(addr);
        let mut b = Client::new(addr);
        let far = DVec3::new(0.5, 0.5, 0.5);
        for (seq, k) in (1000u32..).zip(0..=60) {
            let p = above().lerp(pressed(), (k as f64 / 40.0).min(1.0));
            a.send(seq, &[p, far]);
            // A second client sends at the same time: not its session.
            b.send(seq, &[DVec3::new(15.0, 15.0, 10.0) * MM, far]);
            std::thread::sleep(Duration::from_millis(1));
        }
        let f = a.latest().unwrap();
        assert!(
            f.flags[0] & FLAG_TOUCHING != 0 && f.forces[0].length() > 0.05,
            "{f:?}"
        );
        assert!(b.latest().is_none(), "the second client gets no forces");
        // A vanishes mid-press: after the 20 ms watchdog, zero force and the stale flag.
        let t0 = Instant::now();
        let mut stale_after = None;
        while t0.elapsed() < Duration::from_millis(200) {
            if let Some(f) = a.latest() {
                if f.flags[0] & FLAG_STALE != 0 {
                    assert_eq!(f.forces[0], DVec3::ZERO);
                    stale_after.get_or_insert(t0.elapsed());
                }
            }
            std::thread::sleep(Duration::from_millis(1));
        }
        let after = stale_after.expect("the watchdog fired");
        assert!(after < Duration::from_millis(60), "stale after {after:?}");
        // A restarts with lower sequence numbers: accepted after the watchdog.
        let (f, _) = a.hold(1, &[pressed(), far], 150);
        let f = f.unwrap();
        assert_eq!(f.flags[0] & FLAG_STALE, 0);
        assert!(f.flags[0] & FLAG_TOUCHING != 0, "{f:?}");
        assert!(f.seq < 200);
        // A goes away; B takes the session once A's watchdog expired.
        std::thread::sleep(Duration::from_millis(40));
        let (f, _) = b.hold(7, &[above(), far], 60);
        let f = f.expect("B now owns the session");
        assert_eq!(f.flags[0] & FLAG_STALE, 0);
    });
    assert!(r.udp.foreign >= 50, "{:?}", r.udp);
    assert!(r.udp.stale_periods >= 1);
}

#[test]
fn a_non_loopback_address_needs_an_explicit_flag() {
    let e = touchfem::devices::udp::UdpBridge::bind(
        "0.0.0.0:0".parse().unwrap(),
        &touchfem::devices::udp::BridgeConfig::default(),
    )
    .unwrap_err();
    assert!(e.to_string().contains("--allow-remote"), "{e}");
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_touchfem"))
        .args(["serve", "cube", "--udp", "0.0.0.0:0", "--seconds", "0.1"])
        .env("TOUCHFEM_CACHE_DIR", "")
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&out.stderr).contains("not a loopback address"));
}

#[test]
fn serve_reports_the_contract_keys() {
    let dir = tempfile::tempdir().unwrap();
    let rep = dir.path().join("r.json");
    let session = dir.path().join("s.tfsession");
    let port = UdpSocket::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    common::touchfem_uncached(&[
        "serve",
        "cube",
        "--udp",
        &format!("127.0.0.1:{port}"),
        "--seconds",
        "0.3",
        "--report",
        rep.to_str().unwrap(),
        "--record",
        session.to_str().unwrap(),
    ]);
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(&rep).unwrap()).unwrap();
    for k in [
        "ticks",
        "packets_received",
        "packets_dropped",
        "missed_deadlines",
        "period_error_us_p999",
        "max_force_n",
    ] {
        assert!(v[k].is_number(), "{k}: {v}");
    }
    assert_eq!(v["ticks"], 300);
    // A bare mesh serves four UDP fingers; its recorded session names them all and replays.
    assert_eq!(v["limits"].as_array().map(Vec::len), Some(4), "{v}");
    let r = common::replay_json(&session);
    assert_eq!(r["ticks"], 300, "{r}");
    assert_eq!(r["max_force_diff_n"].as_f64(), Some(0.0), "{r}");
}

// Shared with tests/coupling.rs, which uses what this file does not.
#[allow(dead_code)]
#[path = "../examples/udp_device.rs"]
mod udp_device;

#[test]
fn the_example_device_presses_the_cube_over_loopback() {
    let mut rep = None;
    let r = with_server(2.0, |addr| {
        let secs = 1.2;
        rep = Some(
            udp_device::run_client(
                addr,
                secs,
                udp_device::Hand::default(),
                udp_device::Timing::RealTime,
                |t| udp_device::press_cube(t, secs),
            )
            .unwrap(),
        );
    });
    let rep = rep.unwrap();
    eprintln!("{}", serde_json::to_string(&rep).unwrap());
    assert_eq!(rep.ticks, 1200);
    assert!(rep.forces_received >= 1000, "{rep:?}");
    assert!(rep.touching_ticks > 300, "{rep:?}");
    assert!(rep.max_force_n > 0.05 && rep.max_force_n <= 8.5, "{rep:?}");
    assert!(rep.rtt_us_p50.is_finite() && rep.rtt_us_p99 >= rep.rtt_us_p50);
    // The object pushes back: the hand rests above its target (4 mm into the top face).
    assert!(rep.final_position[2] > 0.026 + 1e-4, "{rep:?}");
    assert_eq!(r.packets_dropped, 0);
}

/// After a stale period a finger that comes back inside the object is attached at the nearest
/// surface point and its force ramped in over `RAMP_S`: no jolt. With both clocks.
#[test]
fn a_press_resumed_after_a_stale_period_is_ramped_in_with_either_clock() {
    for clock in [Clock::Host, Clock::Device] {
        with_server_clocked(1.2, clock, |addr| {
            let mut a = Client::new(addr);
            let far = DVec3::new(0.5, 0.5, 0.5);
            let mut seq = 1;
            for k in 0..=60 {
                let p = above().lerp(pressed(), (k as f64 / 40.0).min(1.0));
                a.send(seq, &[p, far]);
                seq += 1;
                std::thread::sleep(Duration::from_millis(1));
            }
            let (held, next) = a.hold(seq, &[pressed(), far], 50);
            let held = held.unwrap().forces[0].length();
            assert!(held > 0.05, "{clock:?}: {held}");
            // Silence for three watchdogs: the contact is released.
            std::thread::sleep(Duration::from_millis(60));
            let _ = a.latest();
            // Back, at the same pressed position: the first forces are a fraction of the
            // held one, rising to it within the ramp.
            let mut first = Vec::new();
            let mut s = next;
            for _ in 0..25 {
                a.send(s, &[pressed(), far]);
                s += 1;
                std::thread::sleep(Duration::from_millis(1));
                if let Some(f) = a.latest() {
                    if f.flags[0] & FLAG_STALE == 0 {
                        first.push(f.forces[0].length());
                    }
                }
            }
            let (back, _) = a.hold(s, &[pressed(), far], 150);
            let back = back.unwrap().forces[0].length();
            eprintln!(
                "{clock:?}: held {held:.4} N, first after the gap {first:?}, back {back:.4} N"
            );
            assert!(!first.is_empty(), "{clock:?}: forces resumed");
            assert!(
                first[0] < 0.35 * held,
                "{clock:?}: no jolt: {} of {held}",
                first[0]
            );
            assert!(
                first.windows(2).all(|w| w[1] >= w[0] - 1e-12),
                "{clock:?}: the ramp rises: {first:?}"
            );
            assert!(
                (back - held).abs() < 0.02 * held,
                "{clock:?}: {back} vs {held}"
            );
        });
    }
}
