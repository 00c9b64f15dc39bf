//! A mock Haply Inverse Service on loopback, for tests and measurements without hardware: a
//! WebSocket server (`tungstenite`, one connection at a time) that sends the inventory, then
//! answers each client message with one state update whose cursor follows a scripted path,
//! built on the same wire types as the client ([`super::wire`]). It can stall, send malformed
//! messages, list several devices and drop the connection, and it records every force sent.

use std::io::ErrorKind;
use std::net::{SocketAddr, TcpListener, TcpStream};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use tungstenite::Message;

use super::wire::{
    ClientMessage, Inverse3Entry, Inverse3State, Inverse3Status, ServiceUpdate, Vec3,
};

/// A cursor path: device frame position (m) at `t` seconds since the service started.
pub type Path = Arc<dyn Fn(f64) -> [f64; 3] + Send + Sync>;

/// What the mock does.
#[derive(Clone)]
pub struct MockConfig {
    /// The inventory: each device's id and cursor path.
    pub devices: Vec<(String, Path)>,
    /// `(from, for)`, seconds: no reply to any message in that window (a stalled service).
    pub stall: Option<(f64, f64)>,
    /// Every n-th reply is not JSON (0: none).
    pub malformed_every: u64,
    /// At this time (s) the connection is dropped without a close (once); the service then
    /// accepts a new connection.
    pub disconnect_at: Option<f64>,
}

impl std::fmt::Debug for MockConfig {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("MockConfig")
            .field(
                "devices",
                &self.devices.iter().map(|d| &d.0).collect::<Vec<_>>(),
            )
            .field("stall", &self.stall)
            .field("malformed_every", &self.malformed_every)
            .field("disconnect_at", &self.disconnect_at)
            .finish()
    }
}

impl MockConfig {
    /// One device `id` following `path`, nothing else.
    pub fn one(id: &str, path: impl Fn(f64) -> [f64; 3] + Send + Sync + 'static) -> MockConfig {
        MockConfig {
            devices: vec![(id.into(), Arc::new(path))],
            stall: None,
            malformed_every: 0,
            disconnect_at: None,
        }
    }
}

/// One command the mock received.
#[derive(Clone, Debug, PartialEq)]
pub struct Received {
    /// Seconds since the service started.
    pub t: f64,
    /// The device it was for.
    pub device_id: String,
    /// The force it set, N.
    pub force: [f64; 3],
}

/// What the mock saw.
#[derive(Clone, Debug, Default)]
pub struct MockLog {
    /// Every force command, in order.
    pub received: Vec<Received>,
    /// Client messages that were not a [`ClientMessage`].
    pub unreadable: u64,
    /// Connections accepted.
    pub connections: u64,
    /// Connections the client closed with a WebSocket close.
    pub clean_closes: u64,
    /// State updates sent.
    pub states_sent: u64,
}

/// A running mock service (see the module docs).
#[derive(Debug)]
pub struct MockService {
    addr: SocketAddr,
    stop: Arc<AtomicBool>,
    log: Arc<Mutex<MockLog>>,
    handle: Option<std::thread::JoinHandle<()>>,
}

impl MockService {
    /// Starts the service on a free loopback port.
    pub fn start(cfg: MockConfig) -> std::io::Result<MockService> {
        let listener = TcpListener::bind("127.0.0.1:0")?;
        listener.set_nonblocking(true)?;
        let addr = listener.local_addr()?;
        let stop = Arc::new(AtomicBool::new(false));
        let log = Arc::new(Mutex::new(MockLog::default()));
        let handle = std::thread::Builder::new()
            .name("haply-mock".into())
            .spawn({
                let (stop, log) = (stop.clone(), log.clone());
                move || serve(&listener, &cfg, &stop, &log)
            })?;
        Ok(MockService {
            addr,
            stop,
            log,
            handle: Some(handle),
        })
    }

    /// Its address, `ws://127.0.0.1:PORT`.
    pub fn url(&self) -> String {
        format!("ws://{}", self.addr)
    }

    /// What it saw so far.
    pub fn log(&self) -> MockLog {
        self.log.lock().map(|l| l.clone()).unwrap_or_default()
    }

    /// Stops it; returns what it saw.
    pub fn stop(mut self) -> MockLog {
        self.halt();
        self.log()
    }

    fn halt(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(h) = self.handle.take() {
            let _ = h.join();
        }
    }
}

impl Drop for MockService {
    fn drop(&mut self) {
        self.halt();
    }
}

fn serve(listener: &TcpListener, cfg: &MockConfig, stop: &AtomicBool, log: &Mutex<MockLog>) {
    let t0 = Instant::now();
    let mut dropped_once = false;
    while !stop.load(Ordering::Relaxed) {
        match listener.accept() {
            Ok((s, _)) => {
                if let Ok(mut l) = log.lock() {
                    l.connections += 1;
                }
                let _ = connection(s, cfg, t0, stop, log, &mut dropped_once);
            }
            Err(e) if e.kind() == ErrorKind::WouldBlock => {
                std::thread::sleep(Duration::from_millis(2))
            }
            Err(_) => std::thread::sleep(Duration::from_millis(2)),
        }
    }
}

fn state(cfg: &MockConfig, t: f64, session: Option<u64>) -> String {
    let update = ServiceUpdate {
        session_id: session,
        inverse3: cfg
            .devices
            .iter()
            .map(|(id, path)| Inverse3Entry {
                device_id: id.clone(),
                state: Inverse3State {
                    cursor_position: Some(Vec3::new(path(t))),
                    cursor_velocity: Some(Vec3::default()),
                    mode: "idle".into(),
                },
                status: Inverse3Status {
                    calibrated: true,
                    in_use: true,
                    power_supply: true,
                    ready: true,
                    started: true,
                },
            })
            .collect(),
    };
    serde_json::to_string(&update).unwrap_or_default()
}

fn connection(
    stream: TcpStream,
    cfg: &MockConfig,
    t0: Instant,
    stop: &AtomicBool,
    log: &Mutex<MockLog>,
    dropped_once: &mut bool,
) -> Result<(), tungstenite::Error> {
    stream.set_nonblocking(false)?;
    let _ = stream.set_nodelay(true);
    let mut ws = tungstenite::accept(stream).map_err(|e| match e {
        tungstenite::HandshakeError::Failure(e) => e,
        tungstenite::HandshakeError::Interrupted(_) => tungstenite::Error::ConnectionClosed,
    })?;
    ws.send(Message::text(state(
        cfg,
        t0.elapsed().as_secs_f64(),
        Some(1),
    )))?;
    ws.get_mut()
        .set_read_timeout(Some(Duration::from_millis(5)))?;
    let mut replies = 0u64;
    while !stop.load(Ordering::Relaxed) {
        match ws.read() {
            Ok(Message::Text(text)) => {
                let t = t0.elapsed().as_secs_f64();
                match serde_json::from_str::<ClientMessage>(text.as_str()) {
                    Ok(m) => {
                        if let Ok(mut l) = log.lock() {
                            for c in &m.inverse3 {
                                if let Some(force) = m.force_for(&c.device_id) {
                                    l.received.push(Received {
                                        t,
                                        device_id: c.device_id.clone(),
                                        force,
                                    });
                                }
                            }
                        }
                    }
                    Err(_) => {
                        if let Ok(mut l) = log.lock() {
                            l.unreadable += 1;
                        }
                    }
                }
                if cfg
                    .stall
                    .is_some_and(|(from, len)| t >= from && t < from + len)
                {
                    continue;
                }
                if !*dropped_once && cfg.disconnect_at.is_some_and(|d| t >= d) {
                    *dropped_once = true;
                    return Ok(());
                }
                replies += 1;
                let reply =
                    if cfg.malformed_every > 0 && replies.is_multiple_of(cfg.malformed_every) {
                        "not a state update".to_string()
                    } else {
                        state(cfg, t, None)
                    };
                ws.send(Message::text(reply))?;
                if let Ok(mut l) = log.lock() {
                    l.states_sent += 1;
                }
            }
            Ok(Message::Close(_)) => {
                if let Ok(mut l) = log.lock() {
                    l.clean_closes += 1;
                }
            }
            Ok(_) => {}
            Err(tungstenite::Error::Io(e))
                if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut) => {}
            Err(_) => return Ok(()),
        }
    }
    Ok(())
}
