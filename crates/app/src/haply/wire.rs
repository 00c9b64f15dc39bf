//! The Haply Inverse Service's WebSocket messages (service v3.5+), as small serde types of our
//! own: only the fields touchfem reads or writes, with the vendor's names and shapes.
//!
//! They are the `haply` crate's (1.3.1) on every message used — `tools/haply-wire-check`
//! serializes each of ours and parses it with the crate's types, and the crate's with ours,
//! and compares the fields (it runs in `.ci/run`, outside the test command: the crate pulls in
//! tokio, reqwest and ~220 packages). The crate's types and ours:
//!
//! | here | `haply` 1.3.1 |
//! |------|---------------|
//! | [`ServiceUpdate`] (inventory, with `session_id`) | `ServiceData` |
//! | [`ServiceUpdate`] (a state update) | `ServiceState` |
//! | [`Inverse3Entry`] | `Inverse3Device` / `Inverse3Message` |
//! | [`Inverse3State`], [`Inverse3Status`] | `Inverse3State`, `Inverse3Status` |
//! | [`ClientMessage`], [`SessionMsg`] | `ServiceMsg`, `SessionMsg` |
//! | [`Inverse3Command`], [`Inverse3Commands`] | `Inverse3OutMsg`, `Inverse3Commands` |
//! | [`SetCursorForce`] | `SetCursorForceCmd` (`vector`; the pre-3.5 `values` read too) |
//! | [`Vec3`] | `Vec3D` (`f32` there) |
//!
//! Every field the service may add and these types do not name is ignored on reading. This
//! file depends on `serde` only, so the wire check can build it on its own.

use serde::{Deserialize, Serialize};

/// A vector (m, m/s or N).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Vec3 {
    /// x.
    pub x: f64,
    /// y.
    pub y: f64,
    /// z.
    pub z: f64,
}

impl Vec3 {
    /// The vector of an array.
    pub fn new(v: [f64; 3]) -> Vec3 {
        Vec3 {
            x: v[0],
            y: v[1],
            z: v[2],
        }
    }
    /// The array of the vector.
    pub fn to_array(self) -> [f64; 3] {
        [self.x, self.y, self.z]
    }
}

/// A message from the service: the inventory when a client connects (with `session_id`, each
/// device with its `config`, which touchfem does not read), then one state update for each
/// message the client sends.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ServiceUpdate {
    /// The session (the inventory carries it).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub session_id: Option<u64>,
    /// The Inverse3 devices (Inverse3, Inverse3x, Minverse).
    #[serde(default)]
    pub inverse3: Vec<Inverse3Entry>,
}

/// One Inverse3 in a [`ServiceUpdate`].
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Inverse3Entry {
    /// Its id (e.g. `"049D"`).
    pub device_id: String,
    /// Its state.
    #[serde(default)]
    pub state: Inverse3State,
    /// Its status.
    #[serde(default)]
    pub status: Inverse3Status,
}

fn idle() -> String {
    "idle".into()
}

/// An Inverse3's state (units: m, m/s).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Inverse3State {
    /// The cursor's position, m, device frame (+X right, +Y forward, +Z up, origin at the
    /// base).
    #[serde(default)]
    pub cursor_position: Option<Vec3>,
    /// The cursor's velocity, m/s.
    #[serde(default)]
    pub cursor_velocity: Option<Vec3>,
    /// The device's mode (`idle`, `position`, `angular`, …): kept as text, so a mode this file
    /// does not know is no malformed message.
    #[serde(default = "idle")]
    pub mode: String,
}

impl Default for Inverse3State {
    fn default() -> Self {
        Inverse3State {
            cursor_position: None,
            cursor_velocity: None,
            mode: idle(),
        }
    }
}

/// An Inverse3's status.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Inverse3Status {
    /// Calibrated.
    #[serde(default)]
    pub calibrated: bool,
    /// In use by a client.
    #[serde(default)]
    pub in_use: bool,
    /// Powered.
    #[serde(default)]
    pub power_supply: bool,
    /// Ready.
    #[serde(default)]
    pub ready: bool,
    /// Started.
    #[serde(default)]
    pub started: bool,
}

/// A message to the service (the crate's `ServiceMsg`): session fields (none sent here) and
/// each device's commands.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct ClientMessage {
    /// The session part (empty).
    pub session: SessionMsg,
    /// Commands for Inverse3 devices.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub inverse3: Vec<Inverse3Command>,
}

/// The session part of a [`ClientMessage`]: touchfem asks for nothing at the session level.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct SessionMsg {}

/// One Inverse3's part of a [`ClientMessage`].
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Inverse3Command {
    /// The device.
    pub device_id: String,
    /// Its commands this tick.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub commands: Option<Inverse3Commands>,
}

/// An Inverse3's commands for one tick.
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct Inverse3Commands {
    /// The force on the cursor (not kept by the service: one every tick).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub set_cursor_force: Option<SetCursorForce>,
}

fn yes() -> bool {
    true
}

/// `set_cursor_force`: the force, N, device frame.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct SetCursorForce {
    /// The force (`vector` since service 3.5; `values` before, accepted on reading).
    #[serde(alias = "values")]
    pub vector: Vec3,
    /// Apply it (always `true` here; the service's default).
    #[serde(default = "yes")]
    pub execute: bool,
}

impl ClientMessage {
    /// The message that sets device `device_id`'s cursor force to `force` (N).
    pub fn cursor_force(device_id: &str, force: [f64; 3]) -> ClientMessage {
        ClientMessage {
            session: SessionMsg {},
            inverse3: vec![Inverse3Command {
                device_id: device_id.into(),
                commands: Some(Inverse3Commands {
                    set_cursor_force: Some(SetCursorForce {
                        vector: Vec3::new(force),
                        execute: true,
                    }),
                }),
            }],
        }
    }

    /// The force this message sets on `device_id`, if it sets one.
    pub fn force_for(&self, device_id: &str) -> Option<[f64; 3]> {
        self.inverse3
            .iter()
            .find(|c| c.device_id == device_id)
            .and_then(|c| c.commands)
            .and_then(|c| c.set_cursor_force)
            .map(|f| f.vector.to_array())
    }
}

impl ServiceUpdate {
    /// The cursor position (m, device frame) of `device_id`, if this update carries it.
    pub fn cursor_of(&self, device_id: &str) -> Option<[f64; 3]> {
        self.inverse3
            .iter()
            .find(|d| d.device_id == device_id)
            .and_then(|d| d.state.cursor_position)
            .map(Vec3::to_array)
    }
}
