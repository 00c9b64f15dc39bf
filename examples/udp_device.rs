//! A simulated haptic device speaking touchfem's UDP protocol (version 1, CONTRACTS.md): a
//! hand, modelled as a mass on a spring and damper that pulls it along a target path, holds the
//! device's end effector; every millisecond the client sends the position, and the force that
//! comes back pushes on the hand. It is the shape of any real driver's 1 kHz callback
//! (OpenHaptics' `hdScheduleAsynchronous`, Force Dimension's `dhdGetPosition`/`dhdSetForce`):
//! read the position, send it, apply the latest force.
//!
//! ```sh
//! touchfem serve cube --udp 127.0.0.1:47800 &
//! cargo run --release --example udp_device -- 127.0.0.1:47800 3
//! ```
//! Prints one JSON line: round trips (send → matching force packet), forces, packets.

use glam::DVec3;
use std::net::{SocketAddr, UdpSocket};
use std::time::{Duration, Instant};

use touchfem::devices::udp::{decode_force, encode_position, FLAG_TOUCHING};

/// The hand: mass (kg), spring (N/m) and damper (N·s/m) towards the target.
#[derive(Clone, Copy, Debug)]
pub struct Hand {
    /// Mass, kg.
    pub mass: f64,
    /// Stiffness of the arm towards the target, N/m.
    pub k: f64,
    /// Damping, N·s/m.
    pub b: f64,
}

impl Default for Hand {
    fn default() -> Self {
        // A relaxed grip: 0.1 kg, 100 N/m, 2 N·s/m (a lightly damped arm).
        Hand {
            mass: 0.1,
            k: 100.0,
            b: 2.0,
        }
    }
}

/// What a run measured.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct ClientReport {
    /// Ticks run.
    pub ticks: u64,
    /// Force packets received.
    pub forces_received: u64,
    /// Round trip from sending a position to receiving the force computed from it, µs.
    pub rtt_us_p50: f64,
    /// Its 99th percentile, µs.
    pub rtt_us_p99: f64,
    /// Largest force received, N.
    pub max_force_n: f64,
    /// Ticks whose latest force packet said "touching".
    pub touching_ticks: u64,
    /// The hand's final position, m.
    pub final_position: [f64; 3],
}

/// Runs the hand for `seconds` against touchfem at `to`, following `target(t)`, starting at
/// `target(0)`. Sends one position a millisecond.
pub fn run_client(
    to: SocketAddr,
    seconds: f64,
    hand: Hand,
    target: impl Fn(f64) -> DVec3,
) -> std::io::Result<ClientReport> {
    let sock = UdpSocket::bind("127.0.0.1:0")?;
    sock.set_nonblocking(true)?;
    let dt = 1e-3;
    let n = (seconds / dt) as u64;
    let mut x = target(0.0);
    let mut v = DVec3::ZERO;
    let mut force = DVec3::ZERO;
    let mut sent_at = vec![None::<Instant>; n as usize + 1];
    let mut rtts = Vec::with_capacity(n as usize);
    let mut rep = ClientReport::default();
    let mut out = [0u8; 64];
    let mut inp = [0u8; 256];
    let t0 = Instant::now();
    for i in 0..n {
        let due = t0 + Duration::from_secs_f64(i as f64 * dt);
        while Instant::now() < due {
            std::hint::spin_loop();
        }
        // Apply the newest force that has arrived.
        while let Ok((len, _)) = sock.recv_from(&mut inp) {
            if let Some(p) = decode_force(&inp[..len]) {
                force = p.forces[0];
                rep.forces_received += 1;
                rep.max_force_n = rep.max_force_n.max(force.length());
                if p.flags[0] & FLAG_TOUCHING != 0 {
                    rep.touching_ticks += 1;
                }
                if let Some(Some(s)) = sent_at.get(p.seq as usize) {
                    rtts.push(s.elapsed().as_secs_f64() * 1e6);
                }
            }
        }
        // The hand: m a = k (target − x) − b v + F.
        let t = i as f64 * dt;
        let a = (hand.k * (target(t) - x) - hand.b * v + force) / hand.mass;
        v += a * dt;
        x += v * dt;
        let seq = i as u32 + 1;
        let len = encode_position(seq, &[x], &mut out);
        sent_at[seq as usize] = Some(Instant::now());
        sock.send_to(&out[..len], to)?;
        rep.ticks += 1;
    }
    rtts.sort_by(|a, b| a.total_cmp(b));
    let q = |p: f64| {
        rtts.get(((rtts.len() as f64 - 1.0) * p).round() as usize)
            .copied()
            .unwrap_or(f64::NAN)
    };
    rep.rtt_us_p50 = q(0.5);
    rep.rtt_us_p99 = q(0.99);
    rep.final_position = x.to_array();
    Ok(rep)
}

/// The cube's press: from 6 mm above the top face's centre down to 4 mm into it over the first
/// half, then held.
pub fn press_cube(t: f64, seconds: f64) -> DVec3 {
    let s = (2.0 * t / seconds).min(1.0);
    DVec3::new(0.015, 0.015, 0.036 - 0.010 * s)
}

#[allow(dead_code)]
fn main() {
    let mut args = std::env::args().skip(1);
    let to: SocketAddr = args
        .next()
        .unwrap_or_else(|| "127.0.0.1:47800".into())
        .parse()
        .expect("ADDR like 127.0.0.1:47800");
    let seconds: f64 = args.next().map_or(3.0, |s| s.parse().expect("seconds"));
    let rep =
        run_client(to, seconds, Hand::default(), |t| press_cube(t, seconds)).expect("UDP client");
    println!("{}", serde_json::to_string(&rep).expect("serialisable"));
}
