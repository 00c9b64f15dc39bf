//! Recorded sessions: every haptic tick's finger positions and the forces sent, in a versioned,
//! self-describing file that carries its scene, so `touchfem replay` can run the positions
//! through the haptic path again and compare the forces.
//!
//! # File format (version 1)
//! ```text
//! TFSESSION 1\n                      magic and version
//! {JSON header}\n                    one line: see SessionHeader (scene text, scene hash, layout)
//! records                            ticks × (fingers × 3 f64 position, m; fingers × 3 f64 force, N), little-endian
//! ```
//! The haptic loop pushes each tick into a wait-free ring ([`rtrb`]); a writer thread drains
//! it to disk, so the loop never blocks on the file and allocates nothing.

use glam::DVec3;
use std::io::{BufWriter, Read, Write};
use std::path::{Path, PathBuf};
use std::time::Duration;

use super::haptic::HapticWorld;
use super::sample::WorldSample;
use crate::force::MAX_FINGERS;
use crate::scene::World;
use crate::Error;

/// The first line of a session file.
pub const MAGIC: &str = "TFSESSION 1";
/// Ticks the ring between the haptic loop and the writer holds (16 s at 1 kHz).
const RING: usize = 1 << 14;

/// The header line of a session file.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SessionHeader {
    /// Always "touchfem-session".
    pub format: String,
    /// File format version (1).
    pub version: u32,
    /// The touchfem version that wrote it.
    pub touchfem: String,
    /// The scene's name.
    pub scene_name: String,
    /// The scene's hash (`World::hash`), hexadecimal.
    pub scene_hash: String,
    /// The scene file's text.
    pub scene_toml: String,
    /// The directory the scene's relative mesh paths are resolved from.
    pub scene_dir: PathBuf,
    /// The haptic loop's rate, Hz.
    pub rate_hz: f64,
    /// Fingers per tick.
    pub fingers: usize,
    /// Bytes per tick record.
    pub record_bytes: usize,
    /// What a record holds, in words.
    pub layout: String,
    /// Each finger's device limits when it ran (they may come from the command line, not
    /// the scene); replay renders through the same couplings. Absent in older files.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub finger_limits: Vec<Option<crate::devices::limits::DeviceLimits>>,
}

/// One tick: the fingers' positions (m) and the forces sent (N).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct TickRecord {
    /// Number of fingers.
    pub n: usize,
    /// Positions, m, scene frame.
    pub positions: [DVec3; MAX_FINGERS],
    /// Forces sent, N.
    pub forces: [DVec3; MAX_FINGERS],
}

impl TickRecord {
    /// A record of `positions` and `forces` (equal lengths, at most [`MAX_FINGERS`]).
    pub fn new(positions: &[DVec3], forces: &[DVec3]) -> TickRecord {
        let mut r = TickRecord {
            n: positions.len().min(MAX_FINGERS),
            ..Default::default()
        };
        r.positions[..r.n].copy_from_slice(&positions[..r.n]);
        r.forces[..r.n].copy_from_slice(&forces[..r.n]);
        r
    }
}

/// The haptic loop's end of a recording (wait-free push, no allocation).
pub struct Recorder {
    producer: rtrb::Producer<TickRecord>,
    dropped: u64,
}

impl Recorder {
    /// Queues a tick; counts it as dropped if the writer has fallen 16 s behind.
    #[inline]
    pub fn push(&mut self, r: &TickRecord) {
        if self.producer.push(*r).is_err() {
            self.dropped += 1;
        }
    }
    /// Ticks that did not fit the ring.
    pub fn dropped(&self) -> u64 {
        self.dropped
    }
}

/// Starts recording `world`'s session to `path`: writes the header, and returns the loop's
/// [`Recorder`] and the writer thread (join it after the loop to flush; it ends when the
/// recorder is dropped). Returns the number of ticks written.
pub fn record(
    path: &Path,
    world: &World,
) -> Result<(Recorder, std::thread::JoinHandle<Result<u64, Error>>), Error> {
    let n = world.fingers.len();
    let header = SessionHeader {
        format: "touchfem-session".into(),
        version: 1,
        touchfem: env!("CARGO_PKG_VERSION").into(),
        scene_name: world.name.clone(),
        scene_hash: format!("{:016x}", world.hash),
        scene_toml: world.source.clone(),
        scene_dir: world.dir.clone(),
        rate_hz: world.haptics.rate_hz,
        fingers: n,
        record_bytes: 48 * n,
        layout: format!(
            "per tick, little-endian f64: {n} finger position(s) [x, y, z] in m, scene frame; then {n} force(s) [fx, fy, fz] in N, as sent to the devices"
        ),
        finger_limits: if world.fingers.iter().any(|f| f.limits.is_some()) {
            world.fingers.iter().map(|f| f.limits.clone()).collect()
        } else {
            Vec::new()
        },
    };
    let werr = |source| Error::Write {
        path: path.to_path_buf(),
        source,
    };
    let file = std::fs::File::create(path).map_err(werr)?;
    let mut w = BufWriter::new(file);
    let json = serde_json::to_string(&header).expect("serialisable");
    writeln!(w, "{MAGIC}\n{json}").map_err(werr)?;
    let (producer, mut consumer) = rtrb::RingBuffer::<TickRecord>::new(RING);
    let path = path.to_path_buf();
    let writer = std::thread::Builder::new()
        .name("touchfem-record".into())
        .spawn(move || -> Result<u64, Error> {
            let werr = |source| Error::Write {
                path: path.clone(),
                source,
            };
            let mut ticks = 0u64;
            let mut buf = Vec::with_capacity(48 * MAX_FINGERS);
            loop {
                let abandoned = consumer.is_abandoned();
                while let Ok(r) = consumer.pop() {
                    buf.clear();
                    for v in r.positions[..n].iter().chain(&r.forces[..n]) {
                        for c in v.to_array() {
                            buf.extend_from_slice(&c.to_le_bytes());
                        }
                    }
                    w.write_all(&buf).map_err(werr)?;
                    ticks += 1;
                }
                if abandoned {
                    break;
                }
                std::thread::sleep(Duration::from_millis(5));
            }
            w.flush().map_err(werr)?;
            Ok(ticks)
        })
        .map_err(|e| Error::Input(format!("cannot start the recorder thread: {e}")))?;
    Ok((
        Recorder {
            producer,
            dropped: 0,
        },
        writer,
    ))
}

/// A session read back.
#[derive(Clone, Debug)]
pub struct Session {
    /// Its header.
    pub header: SessionHeader,
    /// Its ticks.
    pub ticks: Vec<TickRecord>,
    /// Bytes at the end that did not make a whole record (a session cut off mid-write).
    pub trailing_bytes: usize,
}

/// Reads a session file. A wrong magic, version, header or record size is a typed error.
pub fn read(path: &Path) -> Result<Session, Error> {
    let bad = |msg: String| Error::Session(format!("{}: {msg}", path.display()));
    let mut bytes = Vec::new();
    std::fs::File::open(path)
        .and_then(|mut f| f.read_to_end(&mut bytes))
        .map_err(|e| bad(format!("cannot read: {e}")))?;
    let line = |from: usize| {
        bytes[from..]
            .iter()
            .position(|&b| b == b'\n')
            .map(|i| (from, from + i))
    };
    let (a, b) = line(0).ok_or_else(|| bad("not a touchfem session (no header)".into()))?;
    let magic = std::str::from_utf8(&bytes[a..b]).unwrap_or("");
    if magic != MAGIC {
        return Err(bad(format!(
            "not a touchfem session version 1 (first line '{}')",
            magic.chars().take(40).collect::<String>()
        )));
    }
    let (c, d) = line(b + 1).ok_or_else(|| bad("truncated header".into()))?;
    let header: SessionHeader =
        serde_json::from_slice(&bytes[c..d]).map_err(|e| bad(format!("bad header: {e}")))?;
    let n = header.fingers;
    if header.version != 1 || n == 0 || n > MAX_FINGERS || header.record_bytes != 48 * n {
        return Err(bad(format!(
            "unsupported header: version {}, {} finger(s), {} bytes a record",
            header.version, n, header.record_bytes
        )));
    }
    let body = &bytes[d + 1..];
    let rb = header.record_bytes;
    let mut ticks = Vec::with_capacity(body.len() / rb);
    for rec in body.chunks_exact(rb) {
        let f = |i: usize| f64::from_le_bytes(rec[8 * i..8 * i + 8].try_into().expect("8 bytes"));
        let mut t = TickRecord {
            n,
            ..Default::default()
        };
        for k in 0..n {
            t.positions[k] = DVec3::new(f(3 * k), f(3 * k + 1), f(3 * k + 2));
            let o = 3 * n + 3 * k;
            t.forces[k] = DVec3::new(f(o), f(o + 1), f(o + 2));
        }
        ticks.push(t);
    }
    Ok(Session {
        trailing_bytes: body.len() % rb,
        header,
        ticks,
    })
}

/// What a replay found.
#[derive(Clone, Debug, serde::Serialize)]
pub struct ReplayReport {
    /// Ticks replayed.
    pub ticks: usize,
    /// Largest |recorded force − replayed force| over ticks and fingers, N.
    pub max_force_diff_n: f64,
    /// The tick where it occurred.
    pub worst_tick: usize,
    /// Largest recorded force, N.
    pub max_force_n: f64,
}

/// The scene a session was recorded with, loaded from its header (its errors are named by
/// `label`), with each finger's device limits as they were when it ran.
pub fn world(session: &Session, label: &str) -> Result<World, Error> {
    let h = &session.header;
    let src = crate::scene::SceneSource {
        name: h.scene_name.clone(),
        text: h.scene_toml.clone(),
        dir: h.scene_dir.clone(),
        label: label.into(),
    };
    let mut world = World::from_source(&src)?;
    if !h.finger_limits.is_empty() {
        if h.finger_limits.len() != world.fingers.len() {
            return Err(Error::Session(format!(
                "the header gives limits for {} finger(s), the scene has {}",
                h.finger_limits.len(),
                world.fingers.len()
            )));
        }
        for (f, l) in world.fingers.iter_mut().zip(&h.finger_limits) {
            if let Some(l) = l {
                l.validate()
                    .map_err(|e| Error::Session(format!("bad finger limits: {e}")))?;
            }
            f.limits = l.clone();
        }
    }
    Ok(world)
}

/// Runs a session's positions through `world`'s haptic path, tick by tick, and compares the
/// forces with the recorded ones. `world` must be the session's scene (same hash).
pub fn replay(world: &World, session: &Session) -> Result<ReplayReport, Error> {
    let want = &session.header.scene_hash;
    let have = format!("{:016x}", world.hash);
    if *want != have {
        return Err(Error::Session(format!(
            "the scene differs from the recorded one (hash {have}, recorded {want}): a mesh or the scene file changed"
        )));
    }
    if world.fingers.len() != session.header.fingers {
        return Err(Error::Session(format!(
            "the scene has {} finger(s), the session {}",
            world.fingers.len(),
            session.header.fingers
        )));
    }
    let mut hw = HapticWorld::new(world);
    let n = session.header.fingers;
    let mut sample = WorldSample::default();
    let mut forces = [DVec3::ZERO; MAX_FINGERS];
    let mut rep = ReplayReport {
        ticks: session.ticks.len(),
        max_force_diff_n: 0.0,
        worst_tick: 0,
        max_force_n: 0.0,
    };
    for (i, t) in session.ticks.iter().enumerate() {
        hw.step(&t.positions[..n], &mut forces[..n], &mut sample);
        for (k, f) in forces.iter().enumerate().take(n) {
            let d = (*f - t.forces[k]).length();
            // NaN differences count as infinitely large.
            let d = if d.is_nan() { f64::INFINITY } else { d };
            if d > rep.max_force_diff_n {
                rep.max_force_diff_n = d;
                rep.worst_tick = i;
            }
            rep.max_force_n = rep.max_force_n.max(t.forces[k].length());
        }
    }
    Ok(rep)
}
