//! The UDP device bridge ("UDP device protocol, version 1" in the reference, `docs/`): any
//! device driver — OpenHaptics, Force Dimension, Haply, CHAI3D, a robot — sends finger positions
//! in datagrams and receives the forces, one packet per haptic tick.
//!
//! * A receiver thread blocks on the socket, checks each datagram (the gate) and hands the
//!   newest accepted position to the haptic loop through a wait-free triple buffer, so the
//!   haptic thread never reads the socket: a flood of junk costs it nothing.
//! * Two clocks ([`Clock`]). **Host** (default): the haptic loop keeps its own 1 kHz deadlines.
//!   **Device**: the device's own callback is the clock, as in OpenHaptics' servo loop; the
//!   haptic thread parks until the receiver wakes it with the next accepted position (at most
//!   the watchdog), computes and answers at once.
//! * Sequence numbers compare in 32-bit serial-number arithmetic (RFC 1982, `seq_newer`): a
//!   client's counter may wrap. A packet that is not newer than the last accepted one is
//!   dropped; so is every malformed packet (size, magic, finger count, non-finite numbers),
//!   and, with a [`Key`], every packet whose HMAC-SHA256 tag does not verify. All are counted.
//! * The sender of the first accepted packet owns the session; packets from elsewhere are
//!   counted and dropped until the owner has been silent for the watchdog (20 ms by default).
//!   A new owner's first tick places its fingers afresh (ramped in if inside).
//! * Watchdog: no accepted packet for longer than the watchdog → every finger's position is
//!   NaN (zero force; the contact is released) and the force packets carry the stale flag,
//!   for at most `STALE_SEND`; then nothing is sent until a new position arrives. After a
//!   stale period a client may restart with any sequence number.
//! * Release: when service ends ([`FingerDevices::release`], or the bridge is dropped) and
//!   when another client takes over, the client gets a last zero-force packet flagged
//!   [`FLAG_RELEASED`]; only the haptic thread sends, so that packet is the client's last.
//! * Force packets (`TFF1`, seq of the position packet used, n, n × force, n × flags[, tag]) go
//!   to the owner's address from a fixed buffer with `MSG_DONTWAIT`; a send that would block
//!   is dropped and counted.
//!
//! Without the `native` feature (no sockets, threads or clock) only the protocol remains: the
//! packets' encoding, the [`Key`], the flags and [`UdpError`]; the bridge is native.

use glam::DVec3;
use hmac::{Hmac, Mac};
use sha2::Sha256;
use std::net::SocketAddr;
#[cfg(feature = "native")]
use std::net::UdpSocket;
use std::path::Path;
#[cfg(feature = "native")]
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
#[cfg(feature = "native")]
use std::sync::{Arc, OnceLock};
use std::time::Duration;
#[cfg(feature = "native")]
use std::time::Instant;

#[cfg(feature = "native")]
use super::{FingerDevices, ForceState};
use crate::limits::MAX_FINGERS;

/// Magic of a position packet.
pub(crate) const POSITION_MAGIC: &[u8; 4] = b"TFP1";
/// Magic of a force packet.
pub(crate) const FORCE_MAGIC: &[u8; 4] = b"TFF1";
/// Flag: the finger touches the object.
pub const FLAG_TOUCHING: u32 = 1;
/// Flag: the force was limited by a device limit.
pub const FLAG_LIMITED: u32 = 2;
/// Flag: no valid position for longer than the watchdog; the force is zero.
pub const FLAG_STALE: u32 = 4;
/// Flag: touchfem no longer serves this client (end of service, or another client took
/// over); the force is zero and no other packet follows.
pub const FLAG_RELEASED: u32 = 8;
/// The default watchdog.
pub(crate) const WATCHDOG: Duration = Duration::from_millis(20);
#[cfg(feature = "native")]
/// How long stale packets are sent after the watchdog expires; then nothing until a new
/// position arrives.
pub(crate) const STALE_SEND: Duration = Duration::from_millis(100);
/// Bytes of the HMAC-SHA256 tag a keyed packet ends with.
pub const TAG_LEN: usize = 32;
/// The shortest key, bytes.
pub(crate) const MIN_KEY_LEN: usize = 16;
/// The largest datagram the bridge reads or writes, bytes.
pub const MAX_PACKET: usize = 12 + 28 * MAX_FINGERS + TAG_LEN;

#[cfg(feature = "native")]
/// Whether sequence number `seq` is newer than `last` in 32-bit serial-number arithmetic
/// (RFC 1982): `(seq − last) mod 2³²` lies in `[1, 2³¹)`.
pub(crate) fn seq_newer(seq: u32, last: u32) -> bool {
    let d = seq.wrapping_sub(last);
    d != 0 && d < 1 << 31
}

/// A shared secret: every packet, both ways, ends with the HMAC-SHA256 of its bytes under it.
#[derive(Clone)]
pub struct Key {
    mac: Hmac<Sha256>,
}

impl std::fmt::Debug for Key {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("Key(..)")
    }
}

impl Key {
    /// A key from the secret's bytes (at least `MIN_KEY_LEN`).
    pub fn new(secret: &[u8]) -> Result<Key, UdpError> {
        if secret.len() < MIN_KEY_LEN {
            return Err(UdpError::ShortKey(secret.len()));
        }
        let mac = Hmac::<Sha256>::new_from_slice(secret).map_err(|_| UdpError::ShortKey(0))?;
        Ok(Key { mac })
    }

    /// The key in a file: all its bytes are the secret (a trailing newline included).
    pub fn from_file(path: &Path) -> Result<Key, UdpError> {
        let bytes =
            std::fs::read(path).map_err(|e| UdpError::KeyFile(path.display().to_string(), e))?;
        Key::new(&bytes)
    }

    /// The tag of `bytes`. Allocates nothing.
    pub fn tag(&self, bytes: &[u8]) -> [u8; TAG_LEN] {
        let mut m = self.mac.clone();
        m.update(bytes);
        m.finalize().into_bytes().into()
    }

    /// Whether `packet` ends with a valid tag of the bytes before it (constant time); returns
    /// those bytes.
    pub fn open<'a>(&self, packet: &'a [u8]) -> Option<&'a [u8]> {
        let body_len = packet.len().checked_sub(TAG_LEN)?;
        let (body, tag) = packet.split_at(body_len);
        let mut m = self.mac.clone();
        m.update(body);
        m.verify_slice(tag).ok().map(|_| body)
    }
}

/// Counters of the bridge.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize)]
pub struct UdpCounters {
    /// Datagrams read.
    pub packets_received: u64,
    /// Datagrams dropped: malformed, rejected, old or duplicate, or from a second client.
    pub packets_dropped: u64,
    /// Of those, malformed.
    pub malformed: u64,
    /// Of those, with a tag that does not verify under the key (or none).
    pub packets_rejected: u64,
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
    /// Release packets sent (end of service, or a client taken over from).
    pub releases_sent: u64,
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
#[cfg_attr(not(feature = "native"), allow(dead_code))]
pub(crate) fn encode_force(seq: u32, forces: &[DVec3], flags: &[u32], out: &mut [u8]) -> usize {
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
#[derive(Clone, Debug)]
pub struct BridgeConfig {
    /// Allow a non-loopback address (needs a key too).
    pub allow_remote: bool,
    /// Silence after which positions are stale.
    pub watchdog: Duration,
    /// What paces the loop.
    pub clock: Clock,
    /// The shared secret every packet is signed with, both ways.
    pub key: Option<Key>,
}

impl Default for BridgeConfig {
    fn default() -> Self {
        BridgeConfig {
            allow_remote: false,
            watchdog: WATCHDOG,
            clock: Clock::Host,
            key: None,
        }
    }
}

#[cfg(feature = "native")]
/// The newest accepted position packet.
#[derive(Clone, Copy, Debug)]
struct Accepted {
    packet: PositionPacket,
    from: SocketAddr,
    at: Instant,
}

#[cfg(feature = "native")]
/// The protocol's admission rules (key, sequence, owner, watchdog).
#[derive(Debug)]
struct Gate {
    watchdog: Duration,
    key: Option<Key>,
    owner: Option<SocketAddr>,
    last_seq: u32,
    last_accept: Option<Instant>,
}

#[cfg(feature = "native")]
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
        let body = match &self.key {
            // The size is checked first: junk costs no hash.
            Some(k) if bytes.len() <= MAX_PACKET => match k.open(bytes) {
                Some(b) => b,
                None => return drop(&c.packets_rejected),
            },
            Some(_) => return drop(&c.packets_rejected),
            None => bytes,
        };
        let Some(p) = decode_position(body) else {
            return drop(&c.malformed);
        };
        let expired = self
            .last_accept
            .is_none_or(|t| now.saturating_duration_since(t) > self.watchdog);
        if self.owner.is_some_and(|o| o != from) && !expired {
            return drop(&c.foreign);
        }
        if !expired && self.owner == Some(from) && !seq_newer(p.seq, self.last_seq) {
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

#[cfg(feature = "native")]
/// The counters, shared with the receiver thread.
#[derive(Debug, Default)]
struct AtomicCounters {
    packets_received: AtomicU64,
    packets_dropped: AtomicU64,
    malformed: AtomicU64,
    packets_rejected: AtomicU64,
    out_of_order: AtomicU64,
    foreign: AtomicU64,
    forces_sent: AtomicU64,
    send_errors: AtomicU64,
    stale_periods: AtomicU64,
    releases_sent: AtomicU64,
}

#[cfg(feature = "native")]
impl AtomicCounters {
    fn snapshot(&self) -> UdpCounters {
        let g = |a: &AtomicU64| a.load(Ordering::Relaxed);
        UdpCounters {
            packets_received: g(&self.packets_received),
            packets_dropped: g(&self.packets_dropped),
            malformed: g(&self.malformed),
            packets_rejected: g(&self.packets_rejected),
            out_of_order: g(&self.out_of_order),
            foreign: g(&self.foreign),
            forces_sent: g(&self.forces_sent),
            send_errors: g(&self.send_errors),
            stale_periods: g(&self.stale_periods),
            releases_sent: g(&self.releases_sent),
        }
    }
}

#[cfg(feature = "native")]
/// What the receiver thread shares with the haptic thread besides the triple buffer.
#[derive(Debug, Default)]
struct Shared {
    counters: AtomicCounters,
    stop: AtomicBool,
    /// Accepted packets so far (the device clock's wake-up condition).
    arrivals: AtomicU64,
    /// The haptic thread, once it has waited for a reading (device clock).
    waiter: OnceLock<std::thread::Thread>,
}

#[cfg(feature = "native")]
/// The client the haptic thread last sent to.
#[derive(Clone, Copy, Debug)]
struct Client {
    addr: SocketAddr,
    seq: u32,
    n: usize,
}

#[cfg(feature = "native")]
/// The bridge: serves up to [`MAX_FINGERS`] fingers over one UDP socket (see the module docs).
pub struct UdpBridge {
    socket: UdpSocket,
    watchdog: Duration,
    clock: Clock,
    key: Option<Key>,
    latest: triple_buffer::Output<Option<Accepted>>,
    shared: Arc<Shared>,
    handle: Option<std::thread::JoinHandle<()>>,
    seen_arrivals: u64,
    /// The accepted packet this tick works from.
    current: Option<Accepted>,
    /// The client being served (the last one sent to, not yet released).
    client: Option<Client>,
    /// Since when no fresh position has been seen (`None`: fresh).
    stale_since: Option<Instant>,
    out: [u8; MAX_PACKET],
}

#[cfg(feature = "native")]
impl std::fmt::Debug for UdpBridge {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("UdpBridge")
            .field("socket", &self.socket)
            .field("clock", &self.clock)
            .field("keyed", &self.key.is_some())
            .field("counters", &self.shared.counters.snapshot())
            .finish_non_exhaustive()
    }
}

/// Why the bridge cannot start.
#[derive(Debug, thiserror::Error)]
pub enum UdpError {
    /// The address is not loopback and remote clients were not allowed, or have no key.
    #[error("{0} is not a loopback address: forces would reach a person's hand from the network; pass --allow-remote and --key FILE to bind it")]
    NotLoopback(SocketAddr),
    /// Binding or configuring the socket failed.
    #[error("cannot bind UDP {0}: {1}")]
    Bind(SocketAddr, std::io::Error),
    /// The key is too short.
    #[error("the key has {0} bytes: it needs at least 16 (e.g. `head -c 32 /dev/urandom > key`)")]
    ShortKey(usize),
    /// The key file cannot be read.
    #[error("cannot read the key file {0}: {1}")]
    KeyFile(String, std::io::Error),
}

#[cfg(feature = "native")]
/// The receiver thread's `SCHED_FIFO` priority (the haptic loop's is 80).
const RECEIVER_PRIORITY: i32 = 79;

#[cfg(feature = "native")]
/// How long the receiver thread blocks before looking at its stop flag.
const RECEIVER_POLL: Duration = Duration::from_millis(20);

#[cfg(feature = "native")]
impl UdpBridge {
    /// Binds `addr` (loopback only unless `cfg.allow_remote` and a key) and starts the
    /// receiver thread.
    pub fn bind(addr: SocketAddr, cfg: &BridgeConfig) -> Result<UdpBridge, UdpError> {
        let remote_ok = cfg.allow_remote && cfg.key.is_some();
        if !addr.ip().is_loopback() && !remote_ok {
            return Err(UdpError::NotLoopback(addr));
        }
        let e = |err| UdpError::Bind(addr, err);
        let socket = UdpSocket::bind(addr).map_err(e)?;
        let shared = Arc::new(Shared::default());
        let gate = Gate {
            watchdog: cfg.watchdog,
            key: cfg.key.clone(),
            owner: None,
            last_seq: 0,
            last_accept: None,
        };
        let rx = socket.try_clone().map_err(e)?;
        rx.set_read_timeout(Some(RECEIVER_POLL)).map_err(e)?;
        let (input, latest) = triple_buffer::triple_buffer(&None);
        let handle = std::thread::Builder::new()
            .name("touchfem-udp-rx".into())
            .spawn({
                let shared = shared.clone();
                move || receive(rx, gate, input, &shared)
            })
            .map_err(e)?;
        // The socket stays blocking for the receiver's timed reads; sends pass MSG_DONTWAIT
        // and never wait.
        Ok(UdpBridge {
            socket,
            watchdog: cfg.watchdog,
            clock: cfg.clock,
            key: cfg.key.clone(),
            latest,
            shared,
            handle: Some(handle),
            seen_arrivals: 0,
            current: None,
            client: None,
            stale_since: None,
            out: [0; MAX_PACKET],
        })
    }

    /// The bound address.
    pub fn local_addr(&self) -> std::io::Result<SocketAddr> {
        self.socket.local_addr()
    }

    /// The counters so far.
    pub fn counters(&self) -> UdpCounters {
        self.shared.counters.snapshot()
    }

    /// What paces this bridge's loop.
    pub fn clock(&self) -> Clock {
        self.clock
    }

    /// Encodes, signs and sends a force packet to `to` from the fixed buffer; counts it.
    fn send(&mut self, to: SocketAddr, seq: u32, forces: &[DVec3], flags: &[u32]) -> bool {
        let mut len = encode_force(seq, forces, flags, &mut self.out);
        if let Some(k) = &self.key {
            let tag = k.tag(&self.out[..len]);
            self.out[len..len + TAG_LEN].copy_from_slice(&tag);
            len += TAG_LEN;
        }
        let ok = send_dontwait(&self.socket, &self.out[..len], to);
        let c = &self.shared.counters;
        if ok { &c.forces_sent } else { &c.send_errors }.fetch_add(1, Ordering::Relaxed);
        ok
    }

    /// Sends the client being served its release packet (zero force, [`FLAG_RELEASED`]), once.
    fn release_client(&mut self) {
        if let Some(c) = self.client.take() {
            let n = c.n.clamp(1, MAX_FINGERS);
            let zero = [DVec3::ZERO; MAX_FINGERS];
            let flags = [FLAG_RELEASED; MAX_FINGERS];
            self.send(c.addr, c.seq, &zero[..n], &flags[..n]);
            self.shared
                .counters
                .releases_sent
                .fetch_add(1, Ordering::Relaxed);
        }
    }
}

#[cfg(feature = "native")]
/// The receiver thread: blocks on the socket, admits datagrams through the gate, publishes
/// the newest accepted one and wakes a waiting haptic thread.
fn receive(
    socket: UdpSocket,
    mut gate: Gate,
    mut out: triple_buffer::Input<Option<Accepted>>,
    shared: &Shared,
) {
    // Just below the haptic loop's real-time priority, so that a busy machine (a flood of
    // junk, a build) never delays the client's positions; it only runs when a datagram comes.
    crate::threads::try_realtime_priority_at(RECEIVER_PRIORITY);
    let mut buf = [0u8; 2048];
    while !shared.stop.load(Ordering::Relaxed) {
        match socket.recv_from(&mut buf) {
            Ok((len, from)) => {
                let now = Instant::now();
                if let Some(a) = gate.offer(&buf[..len], from, now, &shared.counters) {
                    out.write(Some(a));
                    shared.arrivals.fetch_add(1, Ordering::Release);
                    if let Some(t) = shared.waiter.get() {
                        t.unpark();
                    }
                }
            }
            Err(_) => continue,
        }
    }
}

#[cfg(feature = "native")]
impl Drop for UdpBridge {
    fn drop(&mut self) {
        self.release_client();
        self.shared.stop.store(true, Ordering::Relaxed);
        if let Some(h) = self.handle.take() {
            let _ = h.join();
        }
    }
}

#[cfg(feature = "native")]
impl FingerDevices for UdpBridge {
    fn clocked(&self) -> bool {
        self.clock == Clock::Device
    }

    fn wait_reading(&mut self, timeout: Duration) -> bool {
        if self.clock != Clock::Device {
            return true;
        }
        let until = Instant::now() + timeout.min(self.watchdog);
        self.shared.waiter.get_or_init(std::thread::current);
        loop {
            let n = self.shared.arrivals.load(Ordering::Acquire);
            if n != self.seen_arrivals {
                self.seen_arrivals = n;
                return true;
            }
            let now = Instant::now();
            if now >= until {
                return false;
            }
            std::thread::park_timeout(until - now);
        }
    }

    fn read(&mut self, _t: f64, out: &mut [DVec3]) {
        self.current = *self.latest.read();
        let now = Instant::now();
        let fresh = self
            .current
            .filter(|a| now.saturating_duration_since(a.at) <= self.watchdog);
        match (fresh, self.stale_since) {
            (Some(_), _) => self.stale_since = None,
            // Fresh until now, and a client was being served: a stale period starts.
            (None, None) => {
                self.stale_since = Some(now);
                if self.client.is_some() {
                    self.shared
                        .counters
                        .stale_periods
                        .fetch_add(1, Ordering::Relaxed);
                }
            }
            (None, Some(_)) => {}
        }
        // Another client took over: the previous one is released, and the new one's fingers
        // are placed afresh at its next reading (no valid position this tick).
        let taken_over = match (fresh, self.client) {
            (Some(a), Some(c)) => a.from != c.addr,
            _ => false,
        };
        if taken_over {
            self.release_client();
        }
        for (i, o) in out.iter_mut().enumerate() {
            *o = match fresh {
                Some(a) if i < a.packet.n && !taken_over => a.packet.positions[i],
                _ => DVec3::NAN,
            };
        }
    }

    fn write(&mut self, forces: &[DVec3], state: &[ForceState]) {
        let Some(a) = self.current else {
            return;
        };
        let stale = self.stale_since.is_some();
        // After STALE_SEND of stale packets, silence until a new position arrives.
        if stale && self.stale_since.is_some_and(|s| s.elapsed() > STALE_SEND) {
            return;
        }
        let n = a.packet.n.min(forces.len()).clamp(1, MAX_FINGERS);
        let mut f = [DVec3::ZERO; MAX_FINGERS];
        let mut flags = [0u32; MAX_FINGERS];
        for k in 0..n {
            if stale {
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
        self.client = Some(Client {
            addr: a.from,
            seq: a.packet.seq,
            n,
        });
        self.send(a.from, a.packet.seq, &f[..n], &flags[..n]);
    }

    fn release(&mut self) {
        self.release_client();
    }
}

#[cfg(feature = "native")]
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

#[cfg(feature = "native")]
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

#[cfg(any(test, feature = "self-check"))]
pub(crate) mod tests {
    use super::*;

    #[cfg_attr(test, test)]
    pub(crate) fn packets_round_trip_and_malformed_ones_are_refused() {
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

#[cfg(all(any(test, feature = "self-check"), feature = "native"))]
pub(crate) mod gate_tests {
    use super::*;

    fn gate(key: Option<Key>) -> Gate {
        Gate {
            watchdog: WATCHDOG,
            key,
            owner: None,
            last_seq: 0,
            last_accept: None,
        }
    }

    fn packet(seq: u32, key: Option<&Key>) -> Vec<u8> {
        let mut b = [0u8; MAX_PACKET];
        let mut len = encode_position(seq, &[DVec3::new(0.01, 0.02, 0.03)], &mut b);
        if let Some(k) = key {
            let t = k.tag(&b[..len]);
            b[len..len + TAG_LEN].copy_from_slice(&t);
            len += TAG_LEN;
        }
        b[..len].to_vec()
    }

    #[cfg_attr(test, test)]
    pub(crate) fn sequence_numbers_compare_in_serial_arithmetic() {
        assert!(seq_newer(1, 0));
        assert!(seq_newer(0, u32::MAX), "the counter wraps");
        assert!(seq_newer(5, u32::MAX - 5));
        assert!(!seq_newer(7, 7));
        assert!(!seq_newer(6, 7));
        assert!(!seq_newer(u32::MAX, 100), "2³² − 101 behind, not ahead");
        assert!(seq_newer(100 + (1 << 31) - 1, 100));
        assert!(!seq_newer(100 + (1 << 31), 100));
    }

    #[cfg_attr(test, test)]
    pub(crate) fn a_wrapping_counter_loses_no_packet() {
        let c = AtomicCounters::default();
        let mut g = gate(None);
        let from: SocketAddr = "127.0.0.1:5000".parse().unwrap();
        let t0 = Instant::now();
        let mut accepted = 0;
        for k in 0..64u32 {
            let seq = (u32::MAX - 31).wrapping_add(k);
            let now = t0 + Duration::from_millis(u64::from(k));
            accepted += usize::from(g.offer(&packet(seq, None), from, now, &c).is_some());
        }
        assert_eq!(accepted, 64);
        assert_eq!(c.snapshot().packets_dropped, 0);
    }

    #[cfg_attr(test, test)]
    pub(crate) fn one_packet_with_seq_max_does_not_lock_the_client_out() {
        let c = AtomicCounters::default();
        let mut g = gate(None);
        let from: SocketAddr = "127.0.0.1:5000".parse().unwrap();
        let t0 = Instant::now();
        assert!(g.offer(&packet(100, None), from, t0, &c).is_some());
        // A spoofed packet from the same address, "far ahead" in plain comparison.
        let t1 = t0 + Duration::from_millis(1);
        assert!(g.offer(&packet(u32::MAX, None), from, t1, &c).is_none());
        assert_eq!(c.snapshot().out_of_order, 1);
        let t2 = t0 + Duration::from_millis(2);
        assert!(g.offer(&packet(101, None), from, t2, &c).is_some());
    }

    #[cfg_attr(test, test)]
    pub(crate) fn keyed_packets_verify_and_others_are_rejected() {
        let key = Key::new(b"0123456789abcdef-secret").unwrap();
        let other = Key::new(b"another key of 16+ bytes").unwrap();
        let c = AtomicCounters::default();
        let mut g = gate(Some(key.clone()));
        let from: SocketAddr = "127.0.0.1:5000".parse().unwrap();
        let t = Instant::now();
        assert!(g.offer(&packet(1, None), from, t, &c).is_none(), "untagged");
        assert!(
            g.offer(&packet(2, Some(&other)), from, t, &c).is_none(),
            "wrong key"
        );
        let mut flipped = packet(3, Some(&key));
        flipped[14] ^= 1;
        assert!(g.offer(&flipped, from, t, &c).is_none(), "altered");
        assert!(g.offer(&[0u8; 4000], from, t, &c).is_none(), "junk");
        let ok = g.offer(&packet(4, Some(&key)), from, t, &c).unwrap();
        assert_eq!(ok.packet.seq, 4);
        let s = c.snapshot();
        assert_eq!(
            (s.packets_rejected, s.packets_dropped, s.packets_received),
            (4, 4, 5)
        );
        assert!(matches!(Key::new(b"short"), Err(UdpError::ShortKey(5))));
    }

    #[cfg_attr(test, test)]
    pub(crate) fn random_and_mutated_datagrams_never_panic_the_gate() {
        // A fixed-seed xorshift64* stream (no proptest: the engine's checks build with the
        // library, and a dependency here would hold its compilation up).
        let mut state = 0x9E37_79B9_7F4A_7C15u64;
        let mut next = move || {
            state ^= state >> 12;
            state ^= state << 25;
            state ^= state >> 27;
            state.wrapping_mul(0x2545_F491_4F6C_DD1D)
        };
        let key = Key::new(b"fuzzing key, 16+ bytes").unwrap();
        let cases = 20_000u32;
        let base = packet(7, None);
        let counts = std::cell::Cell::new((0u64, 0u64));
        for _ in 0..cases {
            let len = (next() % 200) as usize;
            let noise: Vec<u8> = (0..len).map(|_| next() as u8).collect();
            let (mutate, seq, bits) = (next() & 1 == 1, next() as u32, next());
            // Either random bytes, or a valid packet with a field or a byte changed.
            let bytes = if mutate {
                let mut b = base.clone();
                b[4..8].copy_from_slice(&seq.to_le_bytes());
                let i = (bits as usize) % b.len();
                b[i] ^= (bits >> 32) as u8;
                if bits & 1 == 1 {
                    b[12..20].copy_from_slice(&f64::from_bits(bits).to_le_bytes());
                }
                b
            } else {
                noise
            };
            for k in [None, Some(key.clone())] {
                let c = AtomicCounters::default();
                let mut g = gate(k);
                let from: SocketAddr = "127.0.0.1:5000".parse().unwrap();
                let got = g.offer(&bytes, from, Instant::now(), &c);
                let (ok, dropped) = counts.get();
                if let Some(a) = got {
                    assert!(a.packet.positions[..a.packet.n]
                        .iter()
                        .all(|p| p.is_finite()));
                    counts.set((ok + 1, dropped));
                } else {
                    assert_eq!(c.snapshot().packets_dropped, 1);
                    counts.set((ok, dropped + 1));
                }
            }
        }
        let (ok, dropped) = counts.get();
        eprintln!("gate fuzz: {cases} datagrams × 2 gates: {ok} accepted, {dropped} dropped");
        assert_eq!(ok + dropped, 2 * u64::from(cases));
        assert!(ok > 0 && dropped > 0);
    }
}
