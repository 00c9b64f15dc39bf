//! The Haply Inverse3 through the Haply Inverse Service (`touchfem serve SCENE --haply [URL]`).
//!
//! * [`wire`]: the service's JSON messages, small serde types of our own that equal the `haply`
//!   crate's on every message used (checked by `tools/haply-wire-check`);
//! * [`client`]: one WebSocket client on an I/O thread per Haply finger, trading positions and
//!   forces with the haptic loop through the engine's external-device link
//!   (`touchfem_core::devices::external`): the tick allocates nothing, takes no lock shared
//!   with the I/O and never waits for the network;
//! * [`mock`]: a loopback mock of the service for the tests and the measurements.
//!
//! The WebSocket lives here, in the program, and never in the engine's or the GPU crate's
//! dependency tree; the engine only knows a Haply finger as scene data (`device = "haply"`,
//! its `haply` table) and an external device's positions and forces.

pub mod cli;
pub mod client;
pub mod mock;
pub mod wire;

use std::sync::atomic::AtomicBool;
use std::time::Duration;

pub use client::{ClientConfig, HaplyClient, HaplyCounters, HaplyError};
use touchfem_core::devices::external::{external_link, ExternalFingers};
use touchfem_core::runtime::serve::{headless, serve_devices_with, LoopOptions, LoopReport};
use touchfem_core::scene::{DeviceSpec, World};

use crate::error::Error;

/// The default watchdog of a Haply finger (`serve --haply-watchdog-ms`).
pub const DEFAULT_WATCHDOG_MS: f64 = 20.0;

/// Options of `serve --haply`.
#[derive(Clone, Debug)]
pub struct HaplyOptions {
    /// How long, recording, placement, floor.
    pub loop_options: LoopOptions,
    /// No state for longer than this: zero force.
    pub watchdog: Duration,
}

/// The report of `serve --haply` (the keys of `serve`'s report, and the Haply ones in
/// CONTRACTS.md).
#[derive(Clone, Debug, serde::Serialize)]
pub struct HaplyReport {
    /// The service (the first Haply finger's).
    pub address: String,
    /// The Inverse3 each finger drives.
    pub devices: Vec<String>,
    /// UDP datagrams read (none on this path; the key of every `serve` report).
    pub packets_received: u64,
    /// UDP datagrams dropped (none on this path).
    pub packets_dropped: u64,
    /// UDP packets rejected (none on this path).
    pub packets_rejected: u64,
    /// Watchdog periods (the same as `haply_stale`).
    pub stale_periods: u64,
    /// `set_cursor_force` commands sent, every finger.
    pub haply_messages: u64,
    /// Watchdog periods: times no state came for longer than the watchdog.
    pub haply_stale: u64,
    /// Malformed or unexpected messages from the service.
    pub haply_malformed: u64,
    /// State updates used.
    pub haply_states: u64,
    /// Reconnections after a disconnect.
    pub haply_reconnects: u64,
    /// The watchdog, ms.
    pub haply_watchdog_ms: f64,
    /// Each finger's client counters (round trips, rate).
    pub haply: Vec<HaplyCounters>,
    /// The loop: ticks, deadlines, forces, limits, timing, recording.
    #[serde(flatten)]
    pub run: LoopReport,
}

/// Serves `world`'s Haply fingers (every finger must be one; see
/// `touchfem_core::runtime::serve::haply_world`) headless until `opts`' seconds or `stop`:
/// connects each finger's client (an error at once if the service or the device is missing),
/// runs the haptic loop, then stops the clients (each sends a last zero force and closes).
/// `connected(device_ids)` is called once every client is connected.
pub fn serve_haply(
    world: &World,
    opts: &HaplyOptions,
    stop: &AtomicBool,
    connected: impl FnOnce(&[String]),
) -> Result<HaplyReport, Error> {
    let mut clients = Vec::new();
    let mut address = String::new();
    let open = || -> Result<ExternalFingers, Error> {
        let mut fingers = Vec::new();
        for (i, f) in world.fingers.iter().enumerate() {
            let DeviceSpec::Haply(spec) = &f.device else {
                return Err(Error::Body(format!(
                    "scene '{}': finger {} is not a haply finger",
                    world.name,
                    i + 1
                )));
            };
            let (finger, port) = external_link(opts.watchdog);
            let cfg = ClientConfig {
                url: spec.url.clone(),
                device_id: spec.device_id.clone(),
                workspace: spec.workspace,
                watchdog: opts.watchdog,
                period: Duration::from_secs_f64(1.0 / world.haptics.rate_hz),
            };
            if address.is_empty() {
                address = spec.url.clone();
            }
            // The client's error, as one line (the program's error does not name this module).
            let client =
                HaplyClient::connect(&cfg, port).map_err(|e| Error::Input(e.to_string()))?;
            clients.push(client);
            fingers.push(finger);
        }
        let ids: Vec<String> = clients.iter().map(|c| c.device_id().to_string()).collect();
        connected(&ids);
        Ok(ExternalFingers(fingers))
    };
    let served = serve_devices_with(world, &opts.loop_options, stop, open, |reader, status| {
        headless(world, reader, status);
        Ok::<(), Error>(())
    });
    // The loop has released every finger (zero force); each client now sends its last zero
    // force and closes, also when serving failed.
    let devices: Vec<String> = clients.iter().map(|c| c.device_id().to_string()).collect();
    let counters: Vec<HaplyCounters> = clients.into_iter().map(HaplyClient::stop).collect();
    let (served, _) = served?;
    let sum = |f: fn(&HaplyCounters) -> u64| counters.iter().map(f).sum::<u64>();
    Ok(HaplyReport {
        address,
        devices,
        packets_received: 0,
        packets_dropped: 0,
        packets_rejected: 0,
        stale_periods: sum(|c| c.stale),
        haply_messages: sum(|c| c.messages),
        haply_stale: sum(|c| c.stale),
        haply_malformed: sum(|c| c.malformed),
        haply_states: sum(|c| c.states),
        haply_reconnects: sum(|c| c.reconnects),
        haply_watchdog_ms: opts.watchdog.as_secs_f64() * 1e3,
        haply: counters,
        run: LoopReport::of(world, served),
    })
}
