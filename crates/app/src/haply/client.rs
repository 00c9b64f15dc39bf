//! The Haply Inverse Service's client: one WebSocket (`tungstenite`, blocking) on an I/O thread
//! of its own per Haply finger, exchanging positions and forces with the haptic loop through
//! the finger's [`ExternalPort`] (wait-free triple buffers; the tick never sees the network).
//!
//! * **Connect** (on the calling thread, so a missing service is an error at once): TCP with
//!   `TCP_NODELAY`, the WebSocket handshake, then the inventory the service sends; the finger's
//!   Inverse3 is the one named by `device_id`, else the first.
//! * **Exchange**: the service answers each client message with exactly one state update, so
//!   the client sets the rate. Each state received is published (the cursor position mapped
//!   into the scene) and answered at once with one `set_cursor_force` carrying the newest force
//!   the haptic loop wrote (zero when it is older than the watchdog, or service has ended).
//!   One message is in flight at a time, and commands go out at most at the haptic loop's
//!   rate (deadlines one period apart): faster would only repeat a tick's force.
//!   The first state after a stall restarts the exchange (polls it did not answer may never
//!   be).
//! * **Watchdog**: no state for longer than the watchdog → a stale period (counted): the finger
//!   has no valid position (the loop's side ages the reading out by itself) and the client
//!   sends a zero force every watchdog period, which also asks the service for a state.
//! * **Malformed or unexpected** messages (not JSON of the expected shape, no entry for the
//!   device, no cursor position, binary frames) are counted and never stop the exchange.
//! * **Disconnect**: the finger lifts at once; the client reconnects every
//!   [`RECONNECT_WAIT`] to the same device (counted); a press resumed after it is ramped in.
//! * **Stop**: the last message is a zero force, then a WebSocket close.

use glam::DVec3;
use std::io::ErrorKind;
use std::net::{SocketAddr, TcpStream, ToSocketAddrs};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use touchfem_core::devices::external::ExternalPort;
use touchfem_core::devices::workspace::Workspace;
use tungstenite::protocol::WebSocket;
use tungstenite::Message;

use super::wire::{ClientMessage, ServiceUpdate};

/// How long a connection, its handshake and the inventory may take.
pub const CONNECT_TIMEOUT: Duration = Duration::from_secs(2);
/// How long the client waits between tries to reconnect after a disconnect.
pub const RECONNECT_WAIT: Duration = Duration::from_millis(250);
/// The I/O thread's longest blocking read: how soon it sees its stop flag and the watchdog.
const READ_POLL: Duration = Duration::from_millis(1);
/// Unanswered watchdog polls after which the older ones are taken as lost.
const MAX_POLLS: u32 = 4;
/// Round trips kept in the histogram, 1 µs bins (longer ones fall in the last).
const RTT_BINS: usize = 20_000;

/// One Haply finger's client settings.
#[derive(Clone, Debug)]
pub struct ClientConfig {
    /// The service (`ws://HOST:PORT[/PATH]`).
    pub url: String,
    /// The device to drive (`None`: the first Inverse3 of the inventory).
    pub device_id: Option<String>,
    /// The device's workspace in the scene.
    pub workspace: Workspace,
    /// No state for longer than this: zero force.
    pub watchdog: Duration,
    /// The shortest time between two commands: the haptic loop's period (a state that comes
    /// sooner is answered at the next period, with the force of a newer tick).
    pub period: Duration,
}

/// Why the client cannot start.
#[derive(Debug, thiserror::Error)]
pub enum HaplyError {
    /// Not a `ws://` address.
    #[error("'{0}' is not a WebSocket address: give ws://HOST:PORT (the Haply Inverse Service's default is ws://127.0.0.1:10001)")]
    Url(String),
    /// The service cannot be reached.
    #[error("cannot reach the Haply Inverse Service at {0}: {1} (is the service installed and running?)")]
    Connect(String, std::io::Error),
    /// The WebSocket handshake failed.
    #[error("the WebSocket handshake with {0} failed: {1}")]
    Handshake(String, String),
    /// No inventory came, or it was not one.
    #[error("no device inventory from {0}: {1}")]
    Inventory(String, String),
    /// The inventory holds no Inverse3 (or not the one asked for).
    #[error("{url}: {}", match wanted {
        Some(w) => format!("no Inverse3 '{w}' in the inventory (found: {})", if found.is_empty() { "none".into() } else { found.join(", ") }),
        None => "no Inverse3 in the inventory: is it plugged in and powered?".into(),
    })]
    NoDevice {
        /// The service.
        url: String,
        /// The device asked for.
        wanted: Option<String>,
        /// The devices found.
        found: Vec<String>,
    },
    /// The I/O thread could not be started.
    #[error("cannot start the Haply I/O thread: {0}")]
    Thread(std::io::Error),
}

/// What a client counted.
#[derive(Clone, Debug, Default, PartialEq, serde::Serialize)]
pub struct HaplyCounters {
    /// `set_cursor_force` commands sent.
    pub messages: u64,
    /// State updates received and used.
    pub states: u64,
    /// Watchdog periods: times no state came for longer than the watchdog.
    pub stale: u64,
    /// Malformed or unexpected messages.
    pub malformed: u64,
    /// Reconnections after a disconnect.
    pub reconnects: u64,
    /// Disconnects seen.
    pub disconnects: u64,
    /// Round trips (command sent → state received), µs: median.
    pub rtt_us_p50: f64,
    /// Round trips, µs: 99th percentile.
    pub rtt_us_p99: f64,
    /// State updates per second, from the first state used to the last (each connection).
    pub rate_hz: f64,
}

#[derive(Debug)]
struct Shared {
    stop: AtomicBool,
    messages: AtomicU64,
    states: AtomicU64,
    stale: AtomicU64,
    malformed: AtomicU64,
    reconnects: AtomicU64,
    disconnects: AtomicU64,
    /// Round-trip histogram and connected time (only the I/O thread writes; read at the end).
    rtt: Mutex<(Vec<u64>, Duration)>,
}

/// A running client (see the module docs).
#[derive(Debug)]
pub struct HaplyClient {
    shared: Arc<Shared>,
    handle: Option<std::thread::JoinHandle<()>>,
    device_id: String,
}

type Ws = WebSocket<TcpStream>;

/// Connects to `url`, reads the inventory and picks the device. Returns the socket, the
/// device's id and its cursor position in the inventory (if given).
fn open(url: &str, wanted: Option<&str>) -> Result<(Ws, String, Option<[f64; 3]>), HaplyError> {
    let addr = socket_addr(url)?;
    let tcp = TcpStream::connect_timeout(&addr, CONNECT_TIMEOUT)
        .map_err(|e| HaplyError::Connect(url.into(), e))?;
    let _ = tcp.set_nodelay(true);
    tcp.set_read_timeout(Some(CONNECT_TIMEOUT))
        .and_then(|_| tcp.set_write_timeout(Some(CONNECT_TIMEOUT)))
        .map_err(|e| HaplyError::Connect(url.into(), e))?;
    let (mut ws, _) = tungstenite::client::client(url, tcp)
        .map_err(|e| HaplyError::Handshake(url.into(), e.to_string()))?;
    let inventory = loop {
        match ws.read() {
            Ok(Message::Text(t)) => {
                break serde_json::from_str::<ServiceUpdate>(t.as_str())
                    .map_err(|e| HaplyError::Inventory(url.into(), e.to_string()))?
            }
            Ok(Message::Close(_)) => {
                return Err(HaplyError::Inventory(
                    url.into(),
                    "the service closed".into(),
                ))
            }
            Ok(_) => continue,
            Err(e) => return Err(HaplyError::Inventory(url.into(), e.to_string())),
        }
    };
    let found: Vec<String> = inventory
        .inverse3
        .iter()
        .map(|d| d.device_id.clone())
        .collect();
    let pick = match wanted {
        Some(w) => found.iter().find(|d| *d == w),
        None => found.first(),
    };
    let Some(id) = pick.cloned() else {
        return Err(HaplyError::NoDevice {
            url: url.into(),
            wanted: wanted.map(String::from),
            found,
        });
    };
    let cursor = inventory.cursor_of(&id);
    Ok((ws, id, cursor))
}

/// The first socket address of a `ws://HOST[:PORT][/PATH]` URL.
fn socket_addr(url: &str) -> Result<SocketAddr, HaplyError> {
    let bad = || HaplyError::Url(url.into());
    let rest = url.strip_prefix("ws://").ok_or_else(bad)?;
    let host_port = rest.split('/').next().unwrap_or("");
    if host_port.is_empty() {
        return Err(bad());
    }
    let with_port = if host_port.ends_with(']') || !host_port.contains(':') {
        format!("{host_port}:80")
    } else {
        host_port.to_string()
    };
    with_port
        .to_socket_addrs()
        .map_err(|e| HaplyError::Connect(url.into(), e))?
        .next()
        .ok_or_else(bad)
}

impl HaplyClient {
    /// Connects (see the module docs) and starts the I/O thread, which drives `port`.
    pub fn connect(cfg: &ClientConfig, mut port: ExternalPort) -> Result<HaplyClient, HaplyError> {
        let (ws, device_id, cursor) = open(&cfg.url, cfg.device_id.as_deref())?;
        if let Some(c) = cursor {
            port.publish(cfg.workspace.to_scene(DVec3::from_array(c)), Instant::now());
        }
        let shared = Arc::new(Shared {
            stop: AtomicBool::new(false),
            messages: AtomicU64::new(0),
            states: AtomicU64::new(0),
            stale: AtomicU64::new(0),
            malformed: AtomicU64::new(0),
            reconnects: AtomicU64::new(0),
            disconnects: AtomicU64::new(0),
            rtt: Mutex::new((Vec::new(), Duration::ZERO)),
        });
        let handle = std::thread::Builder::new()
            .name("touchfem-haply".into())
            .spawn({
                let (shared, cfg, id) = (shared.clone(), cfg.clone(), device_id.clone());
                move || io_thread(ws, &cfg, &id, port, &shared)
            })
            .map_err(HaplyError::Thread)?;
        Ok(HaplyClient {
            shared,
            handle: Some(handle),
            device_id,
        })
    }

    /// The device driven.
    pub fn device_id(&self) -> &str {
        &self.device_id
    }

    /// The counters so far (round trips and rate once stopped).
    pub fn counters(&self) -> HaplyCounters {
        let g = |a: &AtomicU64| a.load(Ordering::Relaxed);
        let s = &self.shared;
        let mut c = HaplyCounters {
            messages: g(&s.messages),
            states: g(&s.states),
            stale: g(&s.stale),
            malformed: g(&s.malformed),
            reconnects: g(&s.reconnects),
            disconnects: g(&s.disconnects),
            ..HaplyCounters::default()
        };
        if let Ok(r) = s.rtt.lock() {
            let (hist, connected) = &*r;
            c.rtt_us_p50 = percentile(hist, 0.5);
            c.rtt_us_p99 = percentile(hist, 0.99);
            let secs = connected.as_secs_f64();
            c.rate_hz = if secs > 0.0 {
                c.states as f64 / secs
            } else {
                0.0
            };
        }
        c
    }

    /// Ends the exchange: the last message sent is a zero force, then the WebSocket closes.
    /// Returns the counters.
    pub fn stop(mut self) -> HaplyCounters {
        self.halt();
        self.counters()
    }

    fn halt(&mut self) {
        self.shared.stop.store(true, Ordering::Relaxed);
        if let Some(h) = self.handle.take() {
            let _ = h.join();
        }
    }
}

impl Drop for HaplyClient {
    fn drop(&mut self) {
        self.halt();
    }
}

/// The `q` quantile of a 1 µs histogram, µs (NaN when empty).
fn percentile(hist: &[u64], q: f64) -> f64 {
    let n: u64 = hist.iter().sum();
    if n == 0 {
        return f64::NAN;
    }
    let want = ((n as f64) * q).ceil().max(1.0) as u64;
    let mut seen = 0;
    for (i, c) in hist.iter().enumerate() {
        seen += c;
        if seen >= want {
            return i as f64;
        }
    }
    (hist.len() - 1) as f64
}

/// Why an exchange ended.
enum Ended {
    Stopped,
    Disconnected,
}

/// The I/O thread: exchanges over `ws` until stopped, reconnecting after a disconnect.
fn io_thread(ws: Ws, cfg: &ClientConfig, id: &str, mut port: ExternalPort, shared: &Shared) {
    let mut hist = vec![0u64; RTT_BINS];
    let mut connected = Duration::ZERO;
    let mut ws = Some(ws);
    while !shared.stop.load(Ordering::Relaxed) {
        let Some(socket) = ws.take() else {
            // Reconnect to the same device after a pause; the finger stays lifted meanwhile.
            let until = Instant::now() + RECONNECT_WAIT;
            while Instant::now() < until && !shared.stop.load(Ordering::Relaxed) {
                std::thread::sleep(Duration::from_millis(5));
            }
            if shared.stop.load(Ordering::Relaxed) {
                break;
            }
            if let Ok((s, _, cursor)) = open(&cfg.url, Some(id)) {
                shared.reconnects.fetch_add(1, Ordering::Relaxed);
                if let Some(c) = cursor {
                    port.publish(cfg.workspace.to_scene(DVec3::from_array(c)), Instant::now());
                }
                ws = Some(s);
            }
            continue;
        };
        let (ended, span) = exchange(socket, cfg, id, &mut port, shared, &mut hist);
        connected += span;
        if let Ended::Disconnected = ended {
            shared.disconnects.fetch_add(1, Ordering::Relaxed);
            port.lift();
        }
    }
    port.lift();
    if let Ok(mut r) = shared.rtt.lock() {
        *r = (hist, connected);
    }
}

/// One connection's exchange (see the module docs).
fn exchange(
    mut ws: Ws,
    cfg: &ClientConfig,
    id: &str,
    port: &mut ExternalPort,
    shared: &Shared,
    hist: &mut [u64],
) -> (Ended, Duration) {
    if ws.get_mut().set_read_timeout(Some(READ_POLL)).is_err() {
        return (Ended::Disconnected, Duration::ZERO);
    }
    let send = |ws: &mut Ws, force: DVec3| -> bool {
        let f = cfg.workspace.force_to_device(force);
        let f = if f.is_finite() { f } else { DVec3::ZERO };
        let msg = ClientMessage::cursor_force(id, f.to_array());
        let Ok(text) = serde_json::to_string(&msg) else {
            return false;
        };
        let ok = ws.send(Message::text(text)).is_ok();
        if ok {
            shared.messages.fetch_add(1, Ordering::Relaxed);
        }
        ok
    };
    // The first command (zero force) starts the exchange.
    let mut last_state = Instant::now();
    let mut last_sent = Instant::now();
    if !send(&mut ws, DVec3::ZERO) {
        return (Ended::Disconnected, Duration::ZERO);
    }
    // The first and the latest state used: the exchange's span (its rate's denominator).
    let mut first_state: Option<Instant> = None;
    let mut in_flight: u32 = 1;
    let mut next_send = Instant::now();
    let mut stale = false;
    let ended = loop {
        if shared.stop.load(Ordering::Relaxed) {
            break Ended::Stopped;
        }
        match ws.read() {
            Ok(Message::Text(t)) => {
                let now = Instant::now();
                let rtt = now.saturating_duration_since(last_sent).as_micros() as usize;
                // The first state after a stall restarts the exchange: the polls it did not
                // answer may never be answered.
                in_flight = if stale {
                    0
                } else {
                    in_flight.saturating_sub(1)
                };
                match serde_json::from_str::<ServiceUpdate>(t.as_str())
                    .ok()
                    .and_then(|u| u.cursor_of(id))
                    .map(DVec3::from_array)
                    .filter(|p| p.is_finite())
                {
                    Some(p) => {
                        port.publish(cfg.workspace.to_scene(p), now);
                        shared.states.fetch_add(1, Ordering::Relaxed);
                        hist[rtt.min(hist.len() - 1)] += 1;
                        last_state = now;
                        first_state.get_or_insert(now);
                        stale = false;
                    }
                    None => {
                        shared.malformed.fetch_add(1, Ordering::Relaxed);
                    }
                }
                // One message in flight: answer each reply with the newest force.
                if in_flight == 0 {
                    let now = Instant::now();
                    if next_send > now {
                        std::thread::sleep(next_send - now);
                    }
                    let now = Instant::now();
                    next_send =
                        (next_send + cfg.period).max(now.checked_sub(cfg.period).unwrap_or(now));
                    let force = if stale {
                        DVec3::ZERO
                    } else {
                        port.force().fresh_force(Instant::now(), cfg.watchdog)
                    };
                    last_sent = Instant::now();
                    if !send(&mut ws, force) {
                        break Ended::Disconnected;
                    }
                    in_flight = 1;
                }
            }
            Ok(Message::Close(_)) => break Ended::Disconnected,
            Ok(Message::Binary(_)) => {
                shared.malformed.fetch_add(1, Ordering::Relaxed);
            }
            Ok(_) => {}
            Err(tungstenite::Error::Io(e))
                if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut) => {}
            Err(_) => break Ended::Disconnected,
        }
        // The watchdog: no state for too long → zero force, every watchdog period.
        let now = Instant::now();
        if now.saturating_duration_since(last_state) > cfg.watchdog {
            if !stale {
                stale = true;
                shared.stale.fetch_add(1, Ordering::Relaxed);
            }
            if now.saturating_duration_since(last_sent) > cfg.watchdog {
                last_sent = now;
                if !send(&mut ws, DVec3::ZERO) {
                    break Ended::Disconnected;
                }
                // Each poll is one more message in flight; past a few, the older ones are
                // taken as lost (the exchange must not wait for replies that never come).
                in_flight = if in_flight >= MAX_POLLS {
                    1
                } else {
                    in_flight + 1
                };
            }
        }
    };
    if let Ended::Stopped = ended {
        // The last message: a zero force; then a clean close (its reply awaited briefly).
        let _ = ws
            .get_mut()
            .set_read_timeout(Some(Duration::from_millis(5)));
        send(&mut ws, DVec3::ZERO);
        let _ = ws.close(None);
        let until = Instant::now() + Duration::from_millis(200);
        while Instant::now() < until {
            match ws.read() {
                Err(tungstenite::Error::Io(e))
                    if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut) =>
                {
                    let _ = ws.flush();
                }
                Err(_) => break,
                Ok(_) => {}
            }
        }
    }
    let span = first_state.map_or(Duration::ZERO, |f| last_state.saturating_duration_since(f));
    (ended, span)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn urls_and_percentiles() {
        assert!(matches!(socket_addr("http://x"), Err(HaplyError::Url(_))));
        assert!(matches!(socket_addr("ws://"), Err(HaplyError::Url(_))));
        assert_eq!(
            socket_addr("ws://127.0.0.1:10001/").unwrap(),
            "127.0.0.1:10001".parse().unwrap()
        );
        assert_eq!(socket_addr("ws://127.0.0.1").unwrap().port(), 80);
        let mut h = vec![0u64; 10];
        h[2] = 98;
        h[9] = 2;
        assert_eq!(percentile(&h, 0.5), 2.0);
        assert_eq!(percentile(&h, 0.99), 9.0);
        assert!(percentile(&[0; 4], 0.5).is_nan());
    }
}
