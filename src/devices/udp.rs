//! The UDP device bridge ("UDP device protocol, version 1" in `../shared/CONTRACTS.md`): any
//! device driver — OpenHaptics, Force Dimension, Haply, CHAI3D, a robot — sends finger positions
//! in datagrams and receives the forces, one packet per haptic tick.
//!
//! * Two clocks ([`Clock`]). **Host** (default): the haptic loop keeps its own 1 kHz deadlines;
//!   a receiver thread blocks on the socket, checks each datagram and hands the newest
//!   accepted position to the loop through a wait-free triple buffer, so a tick never touches
//!   the receiving side of the socket. **Device**: the device's own 1 kHz callback is the
//!   clock, as in OpenHaptics' servo loop; the haptic thread waits for the next position
//!   packet (between ticks, at most the watchdog), computes and answers at once, so a round
//!   trip is one tick's work plus the kernel's wake-up.
//! * A packet whose seq is not greater than the last accepted one is dropped; so is every
//!   malformed packet (size, magic, finger count, non-finite numbers). All are counted.
//! * The sender of the first accepted packet owns the session; packets from elsewhere are
//!   counted and dropped until the owner has been silent for the watchdog (20 ms by default).
//! * Watchdog: no accepted packet for longer than the watchdog → every finger's position is
//!   NaN (zero force; the contact is released) and the force packets carry the stale flag.
//!   After a stale period a client may restart with lower sequence numbers. A finger that
//!   reappears inside the object is attached and its force ramped in (see `runtime::haptic`).
//! * Force packets (`TFF1`, seq of the position packet used, n, n × force, n × flags) go to the
//!   owner's address each tick from a fixed buffer with `MSG_DONTWAIT`; a send that
//!   would block is dropped and counted.

use glam::DVec3;
use std::net::{SocketAddr, UdpSocket};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use super::{FingerDevices, ForceState};
use crate::force::MAX_FINGERS;

/// Magic of a position packet.
pub const POSITION_MAGIC: &[u8; 4] = b"TFP1";
/// Magic of a force packet.
pub const FORCE_MAGIC: &[u8; 4] = b"TFF1";
/// Flag: the finger touches the object.
pub const FLAG_TOUCHING: u32 = 1;
/// Flag: the force was limited by a device limit.
pub const FLAG_LIMITED: u32 = 2;
/// Flag: no valid position for longer than the watchdog; the force is zero.
pub const FLAG_STALE: u32 = 4;
/// The default watchdog.
pub const WATCHDOG: Duration = Duration::from_millis(20);

/// Counters of the bridge.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct UdpCounters {
    /// Datagrams read.
    pub packets_received: u64,
    /// Datagrams dropped: malformed, old or duplicate, or from a second client.
    pub packets_dropped: u64,
    /// Of those, malformed.
    pub malformed: u64,
    /// Of those, not newer than the last accepted.
    pub out_of_order: u64,
    /// Of those, from a client that does not own the session.
    pub foreign: u64,
    /// Force packets sent.
    pub forces_sent: u64,
    /// Force packets that could not be sent.
    pub send_errors: u64,
    /// Times the watchdog expired.
    pub stale_periods: u64,
}

/// A decoded position packet.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct PositionPacket {
    /// Sequence number.
    pub seq: u32,
    /// Fingers.
    pub n: usize,
    /// Positions, metres.
    pub positions: [DVec3; MAX_FINGERS],
}

/// Decodes a position packet; `None` if it is malformed.
pub fn decode_position(b: &[u8]) -> Option<PositionPacket> {
    if b.len() < 12 || &b[..4] != POSITION_MAGIC {
        return None;
    }
    let u32_at = |o: usize| u32::from_le_bytes([b[o], b[o + 1], b[o + 2], b[o + 3]]);
    let seq = u32_at(4);
    let n = u32_at(8) as usize;
    if !(1..=MAX_FINGERS).contains(&n) || b.len() != 12 + 24 * n {
        return None;
    }
    let mut positions = [DVec3::ZERO; MAX_FINGERS];
    for (k, p) in positions.iter_mut().enumerate().take(n) {
        let f = |i: usize| {
            let o = 12 + 24 * k + 8 * i;
            f64::from_le_bytes(b[o..o + 8].try_into().expect("8 bytes"))
        };
        *p = DVec3::new(f(0), f(1), f(2));
        if !p.is_finite() {
            return None;
        }
    }
    Some(PositionPacket { seq, n, positions })
}

/// Encodes a position packet into `out`; returns its length.
pub fn encode_position(seq: u32, positions: &[DVec3], out: &mut [u8]) -> usize {
    let n = positions.len();
    out[..4].copy_from_slice(POSITION_MAGIC);
    out[4..8].copy_from_slice(&seq.to_le_bytes());
    out[8..12].copy_from_slice(&(n as u32).to_le_bytes());
    for (k, p) in positions.iter().enumerate() {
        for (i, v) in p.to_array().iter().enumerate() {
            let o = 12 + 24 * k + 8 * i;
            out[o..o + 8].copy_from_slice(&v.to_le_bytes());
        }
    }
    12 + 24 * n
}

/// A decoded force packet.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ForcePacket {
    /// Sequence number of the position packet the forces were computed from.
    pub seq: u32,
    /// Fingers.
    pub n: usize,
    /// Forces, newtons.
    pub forces: [DVec3; MAX_FINGERS],
    /// Flags per finger.
    pub flags: [u32; MAX_FINGERS],
}

/// Encodes a force packet into `out`; returns its length.
pub fn encode_force(seq: u32, forces: &[DVec3], flags: &[u32], out: &mut [u8]) -> usize {
    let n = forces.len();
    out[..4].copy_from_slice(FORCE_MAGIC);
    out[4..8].copy_from_slice(&seq.to_le_bytes());
    out[8..12].copy_from_slice(&(n as u32).to_le_bytes());
    for (k, f) in forces.iter().enumerate() {
        for (i, v) in f.to_array().iter().enumerate() {
            let o = 12 + 24 * k + 8 * i;
            out[o..o + 8].copy_from_slice(&v.to_le_bytes());
        }
    }
    for (k, fl) in flags.iter().enumerate() {
        let o = 12 + 24 * n + 4 * k;
        out[o..o + 4].copy_from_slice(&fl.to_le_bytes());
    }
    12 + 28 * n
}

/// Decodes a force packet; `None` if it is malformed.
pub fn decode_force(b: &[u8]) -> Option<ForcePacket> {
    if b.len() < 12 || &b[..4] != FORCE_MAGIC {
        return None;
    }
    let u32_at = |o: usize| u32::from_le_bytes([b[o], b[o + 1], b[o + 2], b[o + 3]]);
    let n = u32_at(8) as usize;
    if !(1..=MAX_FINGERS).contains(&n) || b.len() != 12 + 28 * n {
        return None;
    }
    let mut p = ForcePacket {
        seq: u32_at(4),
        n,
        forces: [DVec3::ZERO; MAX_FINGERS],
        flags: [0; MAX_FINGERS],
    };
    for k in 0..n {
        let f = |i: usize| {
            let o = 12 + 24 * k + 8 * i;
            f64::from_le_bytes(b[o..o + 8].try_into().expect("8 bytes"))
        };
        p.forces[k] = DVec3::new(f(0), f(1), f(2));
        p.flags[k] = u32_at(12 + 24 * n + 4 * k);
    }
    Some(p)
}

/// What paces the haptic loop of a bridge.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Clock {
    /// touchfem's own deadlines (the pacer); positions arrive through a receiver thread.
    #[default]
    Host,
    /// Each position packet starts a tick, answered at once (lowest round trip).
    Device,
}

impl std::str::FromStr for Clock {
    type Err = String;
    fn from_str(s: &str) -> Result<Clock, String> {
        match s {
            "host" => Ok(Clock::Host),
            "device" => Ok(Clock::Device),
            other => Err(format!(
                "'{other}' is not a clock: use \"host\" or \"device\""
            )),
        }
    }
}

/// How a bridge is set up.
#[derive(Clone, Copy, Debug)]
pub struct BridgeConfig {
    /// Allow a non-loopback address.
    pub allow_remote: bool,
    /// Silence after which positions are stale.
    pub watchdog: Duration,
    /// What paces the loop.
    pub clock: Clock,
}

impl Default for BridgeConfig {
    fn default() -> Self {
        BridgeConfig {
            allow_remote: false,
            watchdog: WATCHDOG,
            clock: Clock::Host,
        }
    }
}

/// The newest accepted position packet.
#[derive(Clone, Copy, Debug)]
struct Accepted {
    packet: PositionPacket,
    from: SocketAddr,
    at: Instant,
}

/// The protocol's admission rules (sequence, owner, watchdog), shared by both clocks.
#[derive(Debug)]
struct Gate {
    watchdog: Duration,
    owner: Option<SocketAddr>,
    last_seq: u32,
    last_accept: Option<Instant>,
}

impl Gate {
    /// Checks one datagram received at `now`; counts it, and returns it when accepted.
    fn offer(
        &mut self,
        bytes: &[u8],
        from: SocketAddr,
        now: Instant,
        c: &AtomicCounters,
    ) -> Option<Accepted> {
        c.packets_received.fetch_add(1, Ordering::Relaxed);
        let drop = |which: &AtomicU64| {
            c.packets_dropped.fetch_add(1, Ordering::Relaxed);
            which.fetch_add(1, Ordering::Relaxed);
            None
        };
        let Some(p) = decode_position(bytes) else {
            return drop(&c.malformed);
        };
        let expired = self
            .last_accept
            .is_none_or(|t| now.saturating_duration_since(t) > self.watchdog);
        if self.owner.is_some_and(|o| o != from) && !expired {
            return drop(&c.foreign);
        }
        if !expired && self.owner == Some(from) && p.seq <= self.last_seq {
            return drop(&c.out_of_order);
        }
        self.owner = Some(from);
        self.last_seq = p.seq;
        self.last_accept = Some(now);
        Some(Accepted {
            packet: p,
            from,
            at: now,
        })
    }
}

/// The counters, shared with the receiver thread.
#[derive(Debug, Default)]
struct AtomicCounters {
    packets_received: AtomicU64,
    packets_dropped: AtomicU64,
    malformed: AtomicU64,
    out_of_order: AtomicU64,
    foreign: AtomicU64,
    forces_sent: AtomicU64,
    send_errors: AtomicU64,
    stale_periods: AtomicU64,
}

impl AtomicCounters {
    fn snapshot(&self) -> UdpCounters {
        let g = |a: &AtomicU64| a.load(Ordering::Relaxed);
        UdpCounters {
            packets_received: g(&self.packets_received),
            packets_dropped: g(&self.packets_dropped),
            malformed: g(&self.malformed),
            out_of_order: g(&self.out_of_order),
            foreign: g(&self.foreign),
            forces_sent: g(&self.forces_sent),
            send_errors: g(&self.send_errors),
            stale_periods: g(&self.stale_periods),
        }
    }
}

/// How the positions reach the haptic thread.
enum Inbox {
    /// From the receiver thread, wait-free.
    Thread {
        latest: triple_buffer::Output<Option<Accepted>>,
        stop: Arc<AtomicBool>,
        handle: Option<std::thread::JoinHandle<()>>,
    },
    /// Read by the haptic thread itself while it waits for the next tick.
    Direct { gate: Gate, buf: Box<[u8; 2048]> },
}

/// The bridge: serves up to [`MAX_FINGERS`] fingers over one UDP socket (see the module docs).
pub struct UdpBridge {
    socket: UdpSocket,
    watchdog: Duration,
    clock: Clock,
    inbox: Inbox,
    counters: Arc<AtomicCounters>,
    latest: Option<Accepted>,
    stale: bool,
    out: [u8; 12 + 28 * MAX_FINGERS],
}

impl std::fmt::Debug for UdpBridge {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("UdpBridge")
            .field("socket", &self.socket)
            .field("clock", &self.clock)
            .field("counters", &self.counters.snapshot())
            .finish_non_exhaustive()
    }
}

/// Why the bridge cannot start.
#[derive(Debug, thiserror::Error)]
pub enum UdpError {
    /// The address is not loopback and remote clients were not allowed.
    #[error("{0} is not a loopback address: forces would reach a person's hand from the network; pass --allow-remote to bind it")]
    NotLoopback(SocketAddr),
    /// Binding or configuring the socket failed.
    #[error("cannot bind UDP {0}: {1}")]
    Bind(SocketAddr, std::io::Error),
}

/// How long the receiver thread blocks before looking at its stop flag.
const RECEIVER_POLL: Duration = Duration::from_millis(20);

impl UdpBridge {
    /// Binds `addr` (loopback only unless `cfg.allow_remote`); with [`Clock::Host`] starts the
    /// receiver thread.
    pub fn bind(addr: SocketAddr, cfg: &BridgeConfig) -> Result<UdpBridge, UdpError> {
        if !addr.ip().is_loopback() && !cfg.allow_remote {
            return Err(UdpError::NotLoopback(addr));
        }
        let e = |err| UdpError::Bind(addr, err);
        let socket = UdpSocket::bind(addr).map_err(e)?;
        let counters = Arc::new(AtomicCounters::default());
        let gate = Gate {
            watchdog: cfg.watchdog,
            owner: None,
            last_seq: 0,
            last_accept: None,
        };
        let inbox = match cfg.clock {
            Clock::Host => {
                let rx = socket.try_clone().map_err(e)?;
                rx.set_read_timeout(Some(RECEIVER_POLL)).map_err(e)?;
                let (input, latest) = triple_buffer::triple_buffer(&None);
                let stop = Arc::new(AtomicBool::new(false));
                let handle = std::thread::Builder::new()
                    .name("touchfem-udp-rx".into())
                    .spawn({
                        let (stop, counters) = (stop.clone(), counters.clone());
                        move || receive(rx, gate, input, &stop, &counters)
                    })
                    .map_err(e)?;
                Inbox::Thread {
                    latest,
                    stop,
                    handle: Some(handle),
                }
            }
            Clock::Device => Inbox::Direct {
                gate,
                buf: Box::new([0; 2048]),
            },
        };
        // The socket stays blocking: its reads are timed (the receiver thread's, or the
        // haptic thread's between ticks with the device clock); sends pass MSG_DONTWAIT and
        // never wait. (A cloned socket shares O_NONBLOCK, so the two cannot differ.)
        Ok(UdpBridge {
            socket,
            watchdog: cfg.watchdog,
            clock: cfg.clock,
            inbox,
            counters,
            latest: None,
            stale: true,
            out: [0; 12 + 28 * MAX_FINGERS],
        })
    }

    /// The bound address.
    pub fn local_addr(&self) -> std::io::Result<SocketAddr> {
        self.socket.local_addr()
    }

    /// The counters so far.
    pub fn counters(&self) -> UdpCounters {
        self.counters.snapshot()
    }

    /// What paces this bridge's loop.
    pub fn clock(&self) -> Clock {
        self.clock
    }

    /// Device clock: receives until a position packet is accepted or `timeout` passes
    /// (the caller's watchdog); returns whether one was. Host clock: returns `true` at once.
    fn receive_direct(&mut self, timeout: Duration) -> bool {
        let Inbox::Direct { gate, buf } = &mut self.inbox else {
            return true;
        };
        let until = Instant::now() + timeout;
        loop {
            let now = Instant::now();
            if now >= until {
                return false;
            }
            // A zero timeout would mean "block forever".
            let wait = (until - now).max(Duration::from_micros(1));
            if self.socket.set_read_timeout(Some(wait)).is_err() {
                return false;
            }
            match self.socket.recv_from(&mut buf[..]) {
                Ok((len, from)) => {
                    if let Some(a) = gate.offer(&buf[..len], from, Instant::now(), &self.counters) {
                        self.latest = Some(a);
                        return true;
                    }
                }
                Err(e)
                    if matches!(
                        e.kind(),
                        std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                    ) =>
                {
                    return false
                }
                // ICMP errors from earlier sends (port unreachable) and the like: skip.
                Err(_) => {}
            }
        }
    }
}

/// The receiver thread: blocks on the socket, admits datagrams through the gate and publishes
/// the newest accepted one.
fn receive(
    socket: UdpSocket,
    mut gate: Gate,
    mut out: triple_buffer::Input<Option<Accepted>>,
    stop: &AtomicBool,
    counters: &AtomicCounters,
) {
    let mut buf = [0u8; 2048];
    while !stop.load(Ordering::Relaxed) {
        match socket.recv_from(&mut buf) {
            Ok((len, from)) => {
                if let Some(a) = gate.offer(&buf[..len], from, Instant::now(), counters) {
                    out.write(Some(a));
                }
            }
            Err(_) => continue,
        }
    }
}

impl Drop for UdpBridge {
    fn drop(&mut self) {
        if let Inbox::Thread { stop, handle, .. } = &mut self.inbox {
            stop.store(true, Ordering::Relaxed);
            if let Some(h) = handle.take() {
                let _ = h.join();
            }
        }
    }
}

impl FingerDevices for UdpBridge {
    fn clocked(&self) -> bool {
        self.clock == Clock::Device
    }

    fn wait_reading(&mut self, timeout: Duration) -> bool {
        self.receive_direct(timeout.min(self.watchdog))
    }

    fn read(&mut self, _t: f64, out: &mut [DVec3]) {
        if let Inbox::Thread { latest, .. } = &mut self.inbox {
            self.latest = *latest.read();
        }
        let now = Instant::now();
        let fresh = self
            .latest
            .filter(|a| now.saturating_duration_since(a.at) <= self.watchdog);
        if fresh.is_none() && !self.stale {
            self.counters.stale_periods.fetch_add(1, Ordering::Relaxed);
        }
        self.stale = fresh.is_none();
        for (i, o) in out.iter_mut().enumerate() {
            *o = match fresh {
                Some(a) if i < a.packet.n => a.packet.positions[i],
                _ => DVec3::NAN,
            };
        }
    }

    fn write(&mut self, forces: &[DVec3], state: &[ForceState]) {
        let Some(a) = self.latest else {
            return;
        };
        let n = a.packet.n.min(forces.len()).clamp(1, MAX_FINGERS);
        let mut f = [DVec3::ZERO; MAX_FINGERS];
        let mut flags = [0u32; MAX_FINGERS];
        for k in 0..n {
            if self.stale {
                flags[k] = FLAG_STALE;
                continue;
            }
            f[k] = forces.get(k).copied().unwrap_or(DVec3::ZERO);
            let s = state.get(k).copied().unwrap_or_default();
            if s.touching {
                flags[k] |= FLAG_TOUCHING;
            }
            if s.limited {
                flags[k] |= FLAG_LIMITED;
            }
        }
        let len = encode_force(a.packet.seq, &f[..n], &flags[..n], &mut self.out);
        // MSG_DONTWAIT: a datagram send only copies into the socket buffer, and never waits
        // for room.
        let c = if send_dontwait(&self.socket, &self.out[..len], a.from) {
            &self.counters.forces_sent
        } else {
            &self.counters.send_errors
        };
        c.fetch_add(1, Ordering::Relaxed);
    }
}

/// `sendto` with `MSG_DONTWAIT`: never blocks, whatever the socket's mode.
fn send_dontwait(socket: &UdpSocket, bytes: &[u8], to: SocketAddr) -> bool {
    use std::os::fd::AsRawFd;
    let (storage, len) = sockaddr(to);
    // SAFETY: `bytes` and `storage` are valid for the given lengths for the call's duration.
    let r = unsafe {
        libc::sendto(
            socket.as_raw_fd(),
            bytes.as_ptr().cast(),
            bytes.len(),
            libc::MSG_DONTWAIT,
            (&storage as *const libc::sockaddr_storage).cast(),
            len,
        )
    };
    r == bytes.len() as isize
}

/// A socket address in C's form.
fn sockaddr(a: SocketAddr) -> (libc::sockaddr_storage, libc::socklen_t) {
    // SAFETY: sockaddr_storage is plain old data; all-zero is a valid value.
    let mut s: libc::sockaddr_storage = unsafe { std::mem::zeroed() };
    let len = match a {
        SocketAddr::V4(v4) => {
            let sin = libc::sockaddr_in {
                sin_family: libc::AF_INET as libc::sa_family_t,
                sin_port: v4.port().to_be(),
                sin_addr: libc::in_addr {
                    s_addr: u32::from_ne_bytes(v4.ip().octets()),
                },
                sin_zero: [0; 8],
            };
            // SAFETY: sockaddr_storage is larger than and aligned for sockaddr_in.
            unsafe { std::ptr::write((&mut s as *mut libc::sockaddr_storage).cast(), sin) };
            std::mem::size_of::<libc::sockaddr_in>()
        }
        SocketAddr::V6(v6) => {
            let sin6 = libc::sockaddr_in6 {
                sin6_family: libc::AF_INET6 as libc::sa_family_t,
                sin6_port: v6.port().to_be(),
                sin6_flowinfo: v6.flowinfo(),
                sin6_addr: libc::in6_addr {
                    s6_addr: v6.ip().octets(),
                },
                sin6_scope_id: v6.scope_id(),
            };
            // SAFETY: sockaddr_storage is larger than and aligned for sockaddr_in6.
            unsafe { std::ptr::write((&mut s as *mut libc::sockaddr_storage).cast(), sin6) };
            std::mem::size_of::<libc::sockaddr_in6>()
        }
    };
    (s, len as libc::socklen_t)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn packets_round_trip_and_malformed_ones_are_refused() {
        let mut b = [0u8; 200];
        let p = [DVec3::new(1.0, 2.0, 3.0), DVec3::new(-1.0, 0.5, 1e-3)];
        let len = encode_position(7, &p, &mut b);
        assert_eq!(len, 12 + 48);
        let d = decode_position(&b[..len]).unwrap();
        assert_eq!((d.seq, d.n, d.positions[1]), (7, 2, p[1]));
        assert!(decode_position(&b[..len - 1]).is_none(), "size");
        let mut bad = b;
        bad[0] = b'X';
        assert!(decode_position(&bad[..len]).is_none(), "magic");
        let mut bad = b;
        bad[8] = 5;
        assert!(decode_position(&bad[..len]).is_none(), "count");
        let mut bad = b;
        bad[12..20].copy_from_slice(&f64::NAN.to_le_bytes());
        assert!(decode_position(&bad[..len]).is_none(), "NaN");
        let len = encode_force(9, &p, &[1, 6], &mut b);
        assert_eq!(len, 12 + 56);
        let f = decode_force(&b[..len]).unwrap();
        assert_eq!((f.seq, f.n, f.forces[0], f.flags[1]), (9, 2, p[0], 6));
    }
}
