//! The UDP device bridge ("UDP device protocol, version 1" in `../shared/CONTRACTS.md`): any
//! device driver — OpenHaptics, Force Dimension, Haply, CHAI3D, a robot — sends finger positions
//! in datagrams and receives the forces, one packet per haptic tick.
//!
//! * Position packets (`TFP1`, seq, n, n × xyz f64) are read from a non-blocking socket at the
//!   start of each tick into a fixed buffer: no allocation, never a blocking call.
//! * A packet whose seq is not greater than the last accepted one is dropped; so is every
//!   malformed packet (size, magic, finger count, non-finite numbers). All are counted.
//! * The sender of the first accepted packet owns the session; packets from elsewhere are
//!   counted and dropped until the owner has been silent for the watchdog (20 ms by default).
//! * Watchdog: no accepted packet for longer than the watchdog → every finger's position is
//!   NaN (zero force; the contact is released) and the force packets carry the stale flag.
//!   After a stale period a client may restart with lower sequence numbers. A finger that
//!   reappears inside the object is attached and its force ramped in (see `runtime::haptic`).
//! * Force packets (`TFF1`, seq of the position packet used, n, n × force, n × flags) go to the
//!   owner's address each tick; a send that would block is dropped and counted.

use glam::DVec3;
use std::net::{SocketAddr, UdpSocket};
use std::time::{Duration, Instant};

use super::FingerDevices;
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

/// The bridge: a non-blocking UDP socket serving up to [`MAX_FINGERS`] fingers.
#[derive(Debug)]
pub struct UdpBridge {
    socket: UdpSocket,
    watchdog: Duration,
    max_force_n: f64,
    owner: Option<SocketAddr>,
    last_seq: u32,
    last_accept: Option<Instant>,
    n: usize,
    positions: [DVec3; MAX_FINGERS],
    stale: bool,
    buf: [u8; 2048],
    out: [u8; 12 + 28 * MAX_FINGERS],
    /// The counters.
    pub counters: UdpCounters,
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

impl UdpBridge {
    /// Binds `addr` (loopback only unless `allow_remote`) with the watchdog; forces at or above
    /// `max_force_n` are flagged as limited.
    pub fn bind(
        addr: SocketAddr,
        allow_remote: bool,
        watchdog: Duration,
        max_force_n: f64,
    ) -> Result<UdpBridge, UdpError> {
        if !addr.ip().is_loopback() && !allow_remote {
            return Err(UdpError::NotLoopback(addr));
        }
        let socket = UdpSocket::bind(addr).map_err(|e| UdpError::Bind(addr, e))?;
        socket
            .set_nonblocking(true)
            .map_err(|e| UdpError::Bind(addr, e))?;
        Ok(UdpBridge {
            socket,
            watchdog,
            max_force_n,
            owner: None,
            last_seq: 0,
            last_accept: None,
            n: 0,
            positions: [DVec3::NAN; MAX_FINGERS],
            stale: true,
            buf: [0; 2048],
            out: [0; 12 + 28 * MAX_FINGERS],
            counters: UdpCounters::default(),
        })
    }

    /// The bound address.
    pub fn local_addr(&self) -> std::io::Result<SocketAddr> {
        self.socket.local_addr()
    }

    /// Reads every waiting datagram (non-blocking), keeping the newest valid position.
    fn drain(&mut self, now: Instant) {
        loop {
            let (len, from) = match self.socket.recv_from(&mut self.buf) {
                Ok(r) => r,
                Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => break,
                // ICMP errors from earlier sends (port unreachable) and the like: skip.
                Err(_) => continue,
            };
            self.counters.packets_received += 1;
            let Some(p) = decode_position(&self.buf[..len]) else {
                self.counters.packets_dropped += 1;
                self.counters.malformed += 1;
                continue;
            };
            let expired = self
                .last_accept
                .is_none_or(|t| now.duration_since(t) > self.watchdog);
            if self.owner.is_some_and(|o| o != from) && !expired {
                self.counters.packets_dropped += 1;
                self.counters.foreign += 1;
                continue;
            }
            if !expired && self.owner == Some(from) && p.seq <= self.last_seq {
                self.counters.packets_dropped += 1;
                self.counters.out_of_order += 1;
                continue;
            }
            self.owner = Some(from);
            self.last_seq = p.seq;
            self.last_accept = Some(now);
            self.n = p.n;
            self.positions = p.positions;
        }
    }
}

impl FingerDevices for UdpBridge {
    fn read(&mut self, _t: f64, out: &mut [DVec3]) {
        let now = Instant::now();
        self.drain(now);
        let fresh = self
            .last_accept
            .is_some_and(|t| now.duration_since(t) <= self.watchdog);
        if !fresh && !self.stale {
            self.counters.stale_periods += 1;
        }
        self.stale = !fresh;
        for (i, o) in out.iter_mut().enumerate() {
            *o = if fresh && i < self.n {
                self.positions[i]
            } else {
                DVec3::NAN
            };
        }
    }

    fn write(&mut self, forces: &[DVec3], touching: &[bool]) {
        let Some(to) = self.owner else {
            return;
        };
        let n = self.n.min(forces.len()).clamp(1, MAX_FINGERS);
        let mut f = [DVec3::ZERO; MAX_FINGERS];
        let mut flags = [0u32; MAX_FINGERS];
        for k in 0..n {
            if self.stale {
                flags[k] = FLAG_STALE;
                continue;
            }
            f[k] = forces.get(k).copied().unwrap_or(DVec3::ZERO);
            if touching.get(k).copied().unwrap_or(false) {
                flags[k] |= FLAG_TOUCHING;
            }
            if f[k].length() >= self.max_force_n * (1.0 - 1e-9) {
                flags[k] |= FLAG_LIMITED;
            }
        }
        let len = encode_force(self.last_seq, &f[..n], &flags[..n], &mut self.out);
        match self.socket.send_to(&self.out[..len], to) {
            Ok(_) => self.counters.forces_sent += 1,
            Err(_) => self.counters.send_errors += 1,
        }
    }
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
