//! A loaded scene: its objects (each with mesh, rest surface and the compliance the scene
//! needs), its fingers and the haptic loop's settings, all in SI units in the scene's frame.

use glam::DVec3;

use super::Body;
use crate::contact::force::ForceModel;
use crate::devices::limits::DeviceLimits;
use crate::mesh::units::LengthUnit;

/// One object of a scene.
pub struct Object {
    /// Its name (scene file `name`, else the mesh's name or file stem).
    pub name: String,
    /// Mesh, rest surface and compliance, in the object's own frame (metres).
    pub body: Body,
    /// Where the mesh's origin sits in the scene, metres.
    pub offset: DVec3,
    /// Its Coulomb friction (`None`: frictionless, the paper's god-object).
    pub friction: Option<crate::contact::Friction>,
    /// Where a blade may cut it (`None`: nowhere, the default; it behaves as if no blade
    /// existed).
    pub cuttable: Option<CutRegion>,
}

/// The tets of an object a blade may remove (scene key `cuttable`).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct CutRegion {
    tets: Vec<bool>,
}

impl CutRegion {
    /// The region of the tets `tets[t]` marks.
    pub fn new(tets: Vec<bool>) -> CutRegion {
        CutRegion { tets }
    }
    /// Per tet of the object's mesh: whether it may be cut.
    pub fn mask(&self) -> &[bool] {
        &self.tets
    }
    /// Whether tet `t` may be cut.
    pub fn contains(&self, t: usize) -> bool {
        self.tets.get(t).copied().unwrap_or(false)
    }
    /// How many tets may be cut.
    pub fn len(&self) -> usize {
        self.tets.iter().filter(|&&x| x).count()
    }
    /// Whether no tet may be cut.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }
}

/// Which device drives a finger.
#[derive(Clone, Debug, PartialEq)]
pub enum DeviceSpec {
    /// Keyframes `(t, position)`, metres and seconds, strictly increasing in time.
    Script(Vec<(f64, DVec3)>),
    /// The `view` window's pointer.
    Pointer,
    /// A UDP device (`touchfem serve`).
    Udp,
    /// Positions from a recorded session.
    Replay,
    /// A Haply Inverse3 through the Haply Inverse Service (`touchfem serve --haply`).
    Haply(HaplySpec),
}

/// The default Haply Inverse Service address.
pub const HAPLY_DEFAULT_URL: &str = "ws://127.0.0.1:10001";

/// A Haply finger's settings (the finger's `haply` table), SI.
#[derive(Clone, Debug, PartialEq)]
pub struct HaplySpec {
    /// The service's WebSocket address (`ws://…`).
    pub url: String,
    /// The Inverse3 to drive (`None`: the first in the service's inventory).
    pub device_id: Option<String>,
    /// Where the device's workspace lies in the scene.
    pub workspace: crate::devices::workspace::Workspace,
}

/// One finger of a scene.
#[derive(Clone, Debug, PartialEq)]
pub struct FingerSpec {
    /// Its device.
    pub device: DeviceSpec,
    /// The force formula for a single contact (several fingers on one object are always
    /// solved together; see `runtime`).
    pub model: ForceModel,
    /// The device's limits: its force is then rendered through a virtual coupling sized from
    /// them ([`crate::runtime::coupling`]); `None`: the paper's force, saturated at
    /// `max_force_n`.
    pub limits: Option<DeviceLimits>,
    /// What it touches with: the paper's point (default) or a sphere.
    pub tool: crate::contact::Tool,
}

/// The haptic loop's settings.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HapticSettings {
    /// Loop rate, Hz.
    pub rate_hz: f64,
    /// The largest force sent to a finger, N.
    pub max_force_n: f64,
}

impl Default for HapticSettings {
    fn default() -> Self {
        HapticSettings {
            rate_hz: 1000.0,
            max_force_n: 8.5,
        }
    }
}

/// A scene ready to run.
pub struct World {
    /// The scene's name (file stem or bundled name).
    pub name: String,
    /// The unit the scene file's coordinates were given in.
    pub unit: LengthUnit,
    /// Its objects (at most [`crate::limits::MAX_OBJECTS`]).
    pub objects: Vec<Object>,
    /// Its fingers (at most [`crate::limits::MAX_FINGERS`]).
    pub fingers: Vec<FingerSpec>,
    /// The haptic loop's settings.
    pub haptics: HapticSettings,
    /// The scene file's text (for session files).
    pub source: String,
    /// The directory relative mesh paths are resolved from.
    pub dir: std::path::PathBuf,
    /// xxh3 of the scene file's text and of every object's compliance cache key.
    pub hash: u64,
}

impl World {
    /// The bounds of every object at rest, scene frame, metres.
    pub fn bounds(&self) -> (DVec3, DVec3) {
        let mut lo = DVec3::splat(f64::INFINITY);
        let mut hi = DVec3::splat(f64::NEG_INFINITY);
        for o in &self.objects {
            let (a, b) = o.body.mesh.bounds();
            lo = lo.min(a + o.offset);
            hi = hi.max(b + o.offset);
        }
        (lo, hi)
    }
}
