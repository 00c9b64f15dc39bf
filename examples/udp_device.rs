//! A simulated haptic device speaking touchfem's UDP protocol (version 1, CONTRACTS.md): a
//! hand, modelled as a mass on a spring and damper that pulls it along a target path, holds the
//! device's end effector; every millisecond the client sends the position, and the force that
//! comes back pushes on the hand. It is the shape of any real driver's 1 kHz callback
//! (OpenHaptics' `hdScheduleAsynchronous`, Force Dimension's `dhdGetPosition`/`dhdSetForce`):
//! read the position, send it, apply the latest force. With `serve --clock device` the force
//! computed from a position comes back within the same millisecond.
//!
//! ```sh
//! touchfem serve cube --udp 127.0.0.1:47800 --clock device &
//! cargo run --release --example udp_device -- 127.0.0.1:47800 3
//! # with a shared secret: both sides sign every packet (HMAC-SHA256)
//! head -c 32 /dev/urandom > key
//! touchfem serve cube --udp 127.0.0.1:47800 --key key &
//! cargo run --release --example udp_device -- 127.0.0.1:47800 3 --key key
//! ```
//! Prints one JSON line: round trips (send → matching force packet), forces, packets.

use glam::DVec3;
use std::net::{SocketAddr, UdpSocket};
use std::time::{Duration, Instant};

use touchfem::devices::udp::{
    decode_force, encode_position, Key, FLAG_RELEASED, FLAG_TOUCHING, MAX_PACKET, TAG_LEN,
};

/// The hand: mass (kg), spring (N/m) and damper (N·s/m) towards the target.
#[derive(Clone, Copy, Debug, PartialEq)]
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

impl Hand {
    /// Moves the hand at `x` with velocity `v` for `dt` under `force` (held), pulled towards
    /// `target`, in `sub` semi-implicit Euler steps; returns the work the force did on it, J.
    pub fn step(
        &self,
        x: &mut DVec3,
        v: &mut DVec3,
        target: DVec3,
        force: DVec3,
        dt: f64,
        sub: u32,
    ) -> f64 {
        let h = dt / f64::from(sub);
        let mut work = 0.0;
        for _ in 0..sub {
            let a = (self.k * (target - *x) - self.b * *v + force) / self.mass;
            *v += a * h;
            let dx = *v * h;
            work += force.dot(dx);
            *x += dx;
        }
        work
    }
}

/// What a run measured.
#[derive(Clone, Debug, Default, serde::Serialize)]
pub struct ClientReport {
    /// Ticks run.
    pub ticks: u64,
    /// Force packets received.
    pub forces_received: u64,
    /// Ticks whose force did not arrive in time (the previous force was held).
    pub late: u64,
    /// Round trip from sending a position to receiving the force computed from it, µs.
    pub rtt_us_p50: f64,
    /// Its 99th percentile, µs.
    pub rtt_us_p99: f64,
    /// Its largest value, µs.
    pub rtt_us_max: f64,
    /// Largest force received, N.
    pub max_force_n: f64,
    /// Ticks whose latest force packet said "touching".
    pub touching_ticks: u64,
    /// The hand's final position, m.
    pub final_position: [f64; 3],
    /// Force packets whose tag did not verify under the key (dropped).
    pub rejected: u64,
    /// Whether a release packet (flag bit 3) arrived.
    pub released: bool,
    /// Work the device's force has done on the hand up to each tick, J (a passivity
    /// observer in the manner of Hannaford & Ryu).
    #[serde(skip)]
    pub work: Vec<f64>,
    /// The hand's position at each tick, m.
    #[serde(skip)]
    pub positions: Vec<DVec3>,
    /// Ticks the machine disturbed, with how late each started, s: a tick more than a period
    /// late (the client was stalled), or one whose force did not arrive in time (counted as
    /// the wait, 100 ms in lockstep). touchfem sees such a gap as it is: one over its watchdog
    /// releases the contact and ramps the force back in, and the hand moves.
    #[serde(skip)]
    pub stalls: Vec<(u64, f64)>,
}

/// How the client keeps time.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Timing {
    /// Real time: one position a millisecond; the force computed from it is waited for until
    /// the next millisecond, then the newest force is held (as a driver's servo loop does).
    RealTime,
    /// Lockstep: each tick starts on time, as in real time, and waits for the force computed
    /// from its position (up to 100 ms) before the hand moves on, so no force is ever late
    /// and the hand's physics does not depend on the machine's load. (touchfem measures the
    /// time between a device's packets, so a client must not run faster than real time.)
    Lockstep,
}

/// Runs the hand for `seconds` against touchfem at `to`, following `target(t)`, starting at
/// `target(0)`: every tick it sends the position, receives the force and integrates the hand
/// under it (zero-order hold, ten 0.1 ms steps).
pub fn run_client(
    to: SocketAddr,
    seconds: f64,
    hand: Hand,
    timing: Timing,
    target: impl Fn(f64) -> DVec3,
) -> std::io::Result<ClientReport> {
    run_client_keyed(to, seconds, hand, timing, None, target)
}

/// [`run_client`] with a shared secret: every position packet ends with its HMAC-SHA256 tag,
/// and force packets whose tag does not verify are dropped.
pub fn run_client_keyed(
    to: SocketAddr,
    seconds: f64,
    hand: Hand,
    timing: Timing,
    key: Option<&Key>,
    target: impl Fn(f64) -> DVec3,
) -> std::io::Result<ClientReport> {
    let sock = UdpSocket::bind("127.0.0.1:0")?;
    let dt = 1e-3;
    let sub = 10u32;
    let n = (seconds / dt).round() as u64;
    let mut x = target(0.0);
    let mut v = DVec3::ZERO;
    let mut force = DVec3::ZERO;
    let mut rtts = Vec::with_capacity(n as usize);
    let mut rep = ClientReport::default();
    let mut out = [0u8; MAX_PACKET];
    let mut inp = [0u8; 512];
    let mut work = 0.0;
    let period = Duration::from_secs_f64(dt);
    let mut next = Instant::now();
    for i in 0..n {
        // A tick more than a period late is not caught up with a burst of packets (a device's
        // servo loop drops it): touchfem measures the time between packets.
        let now = Instant::now();
        if now > next + period {
            rep.stalls.push((i, (now - next).as_secs_f64()));
            next = now;
        }
        let due = next;
        next += period;
        {
            // Sleep, then spin the last 200 µs (sleeping all the way wakes late).
            let now = Instant::now();
            if due > now + Duration::from_micros(300) {
                std::thread::sleep(due - now - Duration::from_micros(200));
            }
            while Instant::now() < due {
                std::hint::spin_loop();
            }
        }
        let seq = i as u32 + 1;
        let mut len = encode_position(seq, &[x], &mut out);
        if let Some(k) = key {
            let tag = k.tag(&out[..len]);
            out[len..len + TAG_LEN].copy_from_slice(&tag);
            len += TAG_LEN;
        }
        let sent = Instant::now();
        sock.send_to(&out[..len], to)?;
        rep.ticks += 1;
        // Wait for the force computed from this position: until the next tick in real time,
        // up to 100 ms in lockstep.
        let until = match timing {
            Timing::RealTime => due + Duration::from_secs_f64(dt),
            Timing::Lockstep => sent + Duration::from_millis(100),
        };
        let mut got = false;
        loop {
            let now = Instant::now();
            if now >= until {
                break;
            }
            sock.set_read_timeout(Some((until - now).max(Duration::from_micros(1))))?;
            let Ok((len, _)) = sock.recv_from(&mut inp) else {
                break;
            };
            let body = match key {
                Some(k) => match k.open(&inp[..len]) {
                    Some(b) => b,
                    None => {
                        rep.rejected += 1;
                        continue;
                    }
                },
                None => &inp[..len],
            };
            let Some(p) = decode_force(body) else {
                continue;
            };
            rep.forces_received += 1;
            if p.flags[0] & FLAG_RELEASED != 0 {
                rep.released = true;
            }
            force = p.forces[0];
            rep.max_force_n = rep.max_force_n.max(force.length());
            if p.seq == seq {
                rtts.push(sent.elapsed().as_secs_f64() * 1e6);
                if p.flags[0] & FLAG_TOUCHING != 0 {
                    rep.touching_ticks += 1;
                }
                got = true;
                break;
            }
        }
        if !got {
            rep.late += 1;
            rep.stalls.push((i, (until - due).as_secs_f64()));
        }
        // The hand: m a = k (target − x) − b v + F, the force held over the tick.
        let t = i as f64 * dt;
        work += hand.step(&mut x, &mut v, target(t), force, dt, sub);
        rep.work.push(work);
        rep.positions.push(x);
    }
    rtts.sort_by(|a, b| a.total_cmp(b));
    let q = |p: f64| {
        rtts.get(((rtts.len() as f64 - 1.0) * p).round() as usize)
            .copied()
            .unwrap_or(f64::NAN)
    };
    rep.rtt_us_p50 = q(0.5);
    rep.rtt_us_p99 = q(0.99);
    rep.rtt_us_max = q(1.0);
    rep.final_position = x.to_array();
    Ok(rep)
}

/// The cube's press: from 6 mm above the top face's centre down to 4 mm into it over the first
/// half, then held.
pub fn press_cube(t: f64, seconds: f64) -> DVec3 {
    let s = (2.0 * t / seconds).min(1.0);
    DVec3::new(0.015, 0.015, 0.036 - 0.010 * s)
}

const USAGE: &str = "usage: udp_device ADDR [SECONDS] [--key FILE]\n  ADDR: touchfem serve's --udp address (e.g. 127.0.0.1:47800)\n  SECONDS: how long to press, in (0, 3600] (default 3)\n  --key FILE: the secret `serve --key FILE` was given";

/// Prints `msg` and the usage, and exits with status 2.
fn usage(msg: &str) -> ! {
    eprintln!("error: {msg}\n{USAGE}");
    std::process::exit(2)
}

#[allow(dead_code)]
fn main() {
    let mut positional = Vec::new();
    let mut key = None;
    let mut args = std::env::args().skip(1);
    while let Some(a) = args.next() {
        match a.as_str() {
            "--key" => {
                let Some(p) = args.next() else {
                    usage("--key needs a FILE")
                };
                key = Some(
                    Key::from_file(std::path::Path::new(&p))
                        .unwrap_or_else(|e| usage(&format!("--key: {e}"))),
                );
            }
            "-h" | "--help" => {
                println!("{USAGE}");
                return;
            }
            _ => positional.push(a),
        }
    }
    if positional.len() > 2 {
        usage("too many arguments");
    }
    let Some(addr) = positional.first() else {
        usage("expected ADDR, touchfem serve's --udp address")
    };
    let to: SocketAddr = addr
        .parse()
        .unwrap_or_else(|_| usage("ADDR must look like 127.0.0.1:47800"));
    let seconds: f64 = match positional.get(1) {
        None => 3.0,
        Some(s) => match s.parse::<f64>() {
            Ok(v) if v.is_finite() && v > 0.0 && v <= 3600.0 => v,
            _ => usage(&format!("SECONDS must be in (0, 3600], not {s:?}")),
        },
    };
    // A driver's servo loop runs at real-time priority where the OS allows it; here one step
    // below touchfem's haptic loop (SCHED_FIFO 80), so on a shared core it never delays it.
    // SAFETY: plain FFI call on the current thread with a fully initialised parameter.
    let realtime = unsafe {
        let param = libc::sched_param { sched_priority: 70 };
        libc::pthread_setschedparam(libc::pthread_self(), libc::SCHED_FIFO, &param) == 0
    };
    eprintln!("client: real-time priority {realtime}");
    let rep = match run_client_keyed(
        to,
        seconds,
        Hand::default(),
        Timing::RealTime,
        key.as_ref(),
        |t| press_cube(t, seconds),
    ) {
        Ok(r) => r,
        Err(e) => {
            eprintln!("error: UDP client: {e}");
            std::process::exit(1)
        }
    };
    match serde_json::to_string(&rep) {
        Ok(s) => println!("{s}"),
        Err(e) => {
            eprintln!("error: {e}");
            std::process::exit(1)
        }
    }
}
