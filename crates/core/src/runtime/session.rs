//! Recorded sessions: every haptic tick's finger positions and the forces sent, in a versioned,
//! self-describing file that carries its scene, so `touchfem replay` can run the positions
//! through the haptic path again and compare the forces.
//!
//! # File format (header version 2)
//! ```text
//! TFSESSION 1\n                      magic
//! {JSON header}\n                    one line: see SessionHeader (version, scene text, scene hash, layout)
//! records                            ticks × (f64 dt, s; fingers × 3 f64 position, m; fingers × 3 f64 force, N), little-endian
//! ```
//! `dt` is the measured time since the previous tick that the haptic path used (the ramp,
//! the coupling and the force bound count seconds), so a session replays bit for bit under
//! either clock. Header version 1 (no `dt`; one nominal period a tick) still reads.
//!
//! A scene that can be cut (a blade and a cuttable object) is recorded as version 3: each
//! tick's record is followed by a u32 count of the cut bodies installed after that tick, each
//! as u32 object, u32 strokes, then per stroke 10 f64 (from, to, inward, depth; object
//! frame, m). Replaying them at the same ticks builds the same bodies, so the forces replay
//! bit for bit whatever the cutter's thread's timing was. Version 4 is version 3
//! with bit 31 of the object word set on a body that follows a deferred fold's adoption
//! ([`crate::haptic::cutter::FoldMode::Deferred`]): the replay adopts its fold there, where
//! the live run did. A version 3 session replays with the folds inline, as it was recorded.
//! Version 5 is version 4 for blades that separate the material ([`CutMode::Separate`], the
//! default); versions 3 and 4 replay with blades that remove the tets they sweep
//! (`TOUCHFEM_CUT=remove`).
//! The haptic loop pushes each tick into a wait-free ring ([`rtrb`]); a writer thread drains
//! it to disk, so the loop never blocks on the file and allocates nothing.

use glam::DVec3;
use std::io::{BufWriter, Read, Write};
use std::path::{Path, PathBuf};
use std::time::Duration;

use super::cutting::{CutMode, FoldMode};
use crate::haptic::HapticWorld;
use crate::haptic::WorldSample;
use crate::limits::MAX_FINGERS;
use crate::scene::World;
use crate::Error;

/// The first line of a session file.
pub(crate) const MAGIC: &str = "TFSESSION 1";
/// Ticks the ring between the haptic loop and the writer holds (16 s at 1 kHz).
const RING: usize = 1 << 14;

/// The header line of a session file.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SessionHeader {
    /// Always "touchfem-session".
    pub format: String,
    /// File format version (2; 1 has no `dt` in its records).
    pub version: u32,
    /// The touchfem version that wrote it.
    pub touchfem: String,
    /// The scene's name.
    pub scene_name: String,
    /// The scene's hash (`World::hash`), hexadecimal.
    pub scene_hash: String,
    /// The scene file's text.
    pub scene_toml: String,
    /// The directory the scene's relative mesh paths are resolved from: absolute in files
    /// written by this version, so a session replays from any directory (a relative one, from
    /// older files, is tried from the working directory, then from the session file's). A
    /// name that is not UTF-8 is stored as `{"os_bytes": [...]}` (its bytes, Unix).
    #[serde(with = "os_path")]
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

/// A path in the header: a string when it is UTF-8, else its bytes (Unix), so that nothing is
/// lost and nothing fails on a directory whose name is not UTF-8.
mod os_path {
    use serde::{Deserialize, Deserializer, Serialize, Serializer};
    use std::path::{Path, PathBuf};

    #[derive(Serialize, Deserialize)]
    #[serde(untagged)]
    enum Repr {
        Text(String),
        Bytes { os_bytes: Vec<u8> },
    }

    pub(crate) fn serialize<S: Serializer>(p: &Path, s: S) -> Result<S::Ok, S::Error> {
        if let Some(t) = p.to_str() {
            return t.serialize(s);
        }
        #[cfg(unix)]
        {
            use std::os::unix::ffi::OsStrExt;
            Repr::Bytes {
                os_bytes: p.as_os_str().as_bytes().to_vec(),
            }
            .serialize(s)
        }
        #[cfg(not(unix))]
        Err(serde::ser::Error::custom(format!(
            "the directory {} is not valid Unicode",
            p.display()
        )))
    }

    pub(crate) fn deserialize<'de, D: Deserializer<'de>>(d: D) -> Result<PathBuf, D::Error> {
        match Repr::deserialize(d)? {
            Repr::Text(t) => Ok(PathBuf::from(t)),
            #[cfg(unix)]
            Repr::Bytes { os_bytes } => {
                use std::os::unix::ffi::OsStringExt;
                Ok(PathBuf::from(std::ffi::OsString::from_vec(os_bytes)))
            }
            #[cfg(not(unix))]
            Repr::Bytes { os_bytes } => String::from_utf8(os_bytes)
                .map(PathBuf::from)
                .map_err(|_| serde::de::Error::custom("a directory name that is not UTF-8")),
        }
    }
}

/// One tick: the time since the last (s), the fingers' positions (m) and the forces sent (N).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct TickRecord {
    /// Seconds since the previous tick, as the haptic path used them.
    pub dt: f64,
    /// Number of fingers.
    pub n: usize,
    /// Positions, m, scene frame.
    pub positions: [DVec3; MAX_FINGERS],
    /// Forces sent, N.
    pub forces: [DVec3; MAX_FINGERS],
}

impl TickRecord {
    /// A record of a tick `dt` seconds after the last, with `positions` and `forces` (equal
    /// lengths, at most [`MAX_FINGERS`]).
    pub fn new(dt: f64, positions: &[DVec3], forces: &[DVec3]) -> TickRecord {
        let mut r = TickRecord {
            dt,
            n: positions.len().min(MAX_FINGERS),
            ..Default::default()
        };
        r.positions[..r.n].copy_from_slice(&positions[..r.n]);
        r.forces[..r.n].copy_from_slice(&forces[..r.n]);
        r
    }
}

/// A cut body installed after a tick, as the recording gets it.
pub struct CutRecord {
    /// The tick after which it was installed (0-based index of the records).
    pub after_tick: u64,
    /// Its object.
    pub object: usize,
    /// The body (its strokes are what is written).
    pub body: std::sync::Arc<super::cutting::CutBody>,
}

/// A cut event read back from a session: after tick `after_tick`, object `object`'s strokes.
#[derive(Clone, Debug, PartialEq)]
pub struct CutEvent {
    /// The tick after which the body was installed.
    pub after_tick: u64,
    /// Its object.
    pub object: usize,
    /// The strokes that built it from the object's previous body.
    pub strokes: Vec<super::cutting::Stroke>,
    /// Whether a deferred fold was adopted before them (versions 4 and 5).
    pub fold_adopted: bool,
}

/// The haptic loop's end of a recording (wait-free push, no allocation).
pub struct Recorder {
    producer: rtrb::Producer<TickRecord>,
    cuts: Option<rtrb::Producer<CutRecord>>,
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
    /// Queues a cut body installed after tick `after_tick` (before that tick's record is
    /// pushed); ignored when the session is not recording cuts.
    #[inline]
    pub fn push_cut(&mut self, r: CutRecord) {
        if let Some(p) = &mut self.cuts {
            if p.push(r).is_err() {
                self.dropped += 1;
            }
        }
    }
}

/// Whether `world` can be cut (a blade finger and a cuttable object): its session records
/// cuts (version 5; 4 or 3 for blades that remove).
fn records_cuts(world: &World) -> bool {
    world.fingers.iter().any(|f| f.tool.blade_depth().is_some())
        && world.objects.iter().any(|o| o.cuttable.is_some())
}

/// Starts recording `world`'s session to `path`: writes the header, and returns the loop's
/// [`Recorder`] and the writer thread (join it after the loop to flush; it ends when the
/// recorder is dropped). Returns the number of ticks written.
///
/// The session is written under a temporary name next to `path` and renamed to `path` when
/// the writer ends without error (`crate::cache::AtomicFile`): a recording that fails (a full
/// disk) leaves an existing `path` as it was, and the writer's error says so. Nothing is
/// created before the header is ready.
pub fn record(
    path: &Path,
    world: &World,
) -> Result<(Recorder, std::thread::JoinHandle<Result<u64, Error>>), Error> {
    let n = world.fingers.len();
    let cuts = records_cuts(world);
    let header = SessionHeader {
        format: "touchfem-session".into(),
        // (Blades that separate, the default, replay as version 5's; blades that remove,
        // `TOUCHFEM_CUT=remove`, as version 4's, or 3's with folds made inline,
        // `TOUCHFEM_FOLD=inline`.)
        version: match (cuts, super::cutting::cut_mode(), super::cutting::fold_mode()) {
            (false, _, _) => 2,
            (true, CutMode::Remove, FoldMode::Inline) => 3,
            (true, CutMode::Remove, FoldMode::Deferred) => 4,
            (true, CutMode::Separate, _) => 5,
        },
        touchfem: env!("CARGO_PKG_VERSION").into(),
        scene_name: world.name.clone(),
        scene_hash: format!("{:016x}", world.hash),
        scene_toml: world.source.clone(),
        scene_dir: absolute(&world.dir),
        rate_hz: world.haptics.rate_hz,
        fingers: n,
        record_bytes: 8 + 48 * n + if cuts { 4 } else { 0 },
        layout: format!(
            "per tick, little-endian f64: the seconds since the previous tick; then {n} finger position(s) [x, y, z] in m, scene frame; then {n} force(s) [fx, fy, fz] in N, as sent to the devices{}",
            if cuts {
                "; then a u32 count of cut bodies installed after the tick, each u32 object (bit 31 set: a deferred fold was adopted before the body's strokes), u32 strokes, and per stroke 10 f64: from, to, inward [x, y, z] and depth, object frame, m"
            } else {
                ""
            }
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
    let json = serde_json::to_string(&header)
        .map_err(|e| Error::Session(format!("{}: cannot write the header: {e}", path.display())))?;
    let file = crate::cache::AtomicFile::create(path).map_err(werr)?;
    let mut w = BufWriter::new(file);
    writeln!(w, "{MAGIC}\n{json}").map_err(werr)?;
    let (producer, mut consumer) = rtrb::RingBuffer::<TickRecord>::new(RING);
    let (cut_producer, mut cut_consumer) = if cuts {
        let (p, c) = rtrb::RingBuffer::<CutRecord>::new(1024);
        (Some(p), Some(c))
    } else {
        (None, None)
    };
    let path = path.to_path_buf();
    let writer = std::thread::Builder::new()
        .name("touchfem-record".into())
        .spawn(move || -> Result<u64, Error> {
            let werr = |source| Error::Write {
                path: path.clone(),
                source,
            };
            let mut ticks = 0u64;
            let mut buf = Vec::with_capacity(8 + 48 * MAX_FINGERS);
            loop {
                let abandoned = consumer.is_abandoned();
                while let Ok(r) = consumer.pop() {
                    buf.clear();
                    buf.extend_from_slice(&r.dt.to_le_bytes());
                    for v in r.positions[..n].iter().chain(&r.forces[..n]) {
                        for c in v.to_array() {
                            buf.extend_from_slice(&c.to_le_bytes());
                        }
                    }
                    if let Some(cc) = &mut cut_consumer {
                        // Every cut installed after this tick was queued before its record.
                        let mut events = Vec::new();
                        while cc.peek().is_ok_and(|e| e.after_tick <= ticks) {
                            if let Ok(e) = cc.pop() {
                                events.push(e);
                            }
                        }
                        buf.extend_from_slice(&(events.len() as u32).to_le_bytes());
                        for e in &events {
                            let adopted = if e.body.fold_adopted { 1u32 << 31 } else { 0 };
                            buf.extend_from_slice(&(e.object as u32 | adopted).to_le_bytes());
                            buf.extend_from_slice(&(e.body.strokes.len() as u32).to_le_bytes());
                            for st in &e.body.strokes {
                                for c in st
                                    .from
                                    .to_array()
                                    .into_iter()
                                    .chain(st.to.to_array())
                                    .chain(st.inward.to_array())
                                    .chain([st.depth])
                                {
                                    buf.extend_from_slice(&c.to_le_bytes());
                                }
                            }
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
            w.into_inner()
                .map_err(|e| werr(e.into_error()))?
                .commit()
                .map_err(werr)?;
            Ok(ticks)
        })
        .map_err(|e| Error::Input(format!("cannot start the recorder thread: {e}")))?;
    Ok((
        Recorder {
            producer,
            cuts: cut_producer,
            dropped: 0,
        },
        writer,
    ))
}

/// `dir` made absolute (canonical where it exists), so that a session records where its
/// relative mesh paths really are.
fn absolute(dir: &Path) -> PathBuf {
    let d = if dir.as_os_str().is_empty() {
        Path::new(".")
    } else {
        dir
    };
    d.canonicalize()
        .or_else(|_| std::env::current_dir().map(|c| c.join(d)))
        .unwrap_or_else(|_| d.to_path_buf())
}

/// A session read back.
#[derive(Clone, Debug)]
pub struct Session {
    /// The file it was read from.
    pub path: PathBuf,
    /// Its header.
    pub header: SessionHeader,
    /// Its ticks.
    pub ticks: Vec<TickRecord>,
    /// The cut bodies installed, in order (versions 3 to 5).
    pub cuts: Vec<CutEvent>,
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
    let with_dt = header.version >= 2;
    let with_cuts = header.version >= 3;
    let want_bytes = 48usize
        .saturating_mul(n)
        .saturating_add(if with_dt { 8 } else { 0 })
        .saturating_add(if with_cuts { 4 } else { 0 });
    if !(1..=5).contains(&header.version)
        || n == 0
        || n > MAX_FINGERS
        || header.record_bytes != want_bytes
        || !(header.rate_hz.is_finite() && header.rate_hz > 0.0)
    {
        return Err(bad(format!(
            "unsupported header: version {}, {} finger(s), {} bytes a record",
            header.version, n, header.record_bytes
        )));
    }
    let body = &bytes[d + 1..];
    let rb = header.record_bytes;
    let mut ticks = Vec::with_capacity(body.len() / rb);
    let mut cuts = Vec::new();
    let period = 1.0 / header.rate_hz;
    let mut at = 0usize;
    let f64_at = |b: &[u8], i: usize| f64::from_le_bytes(b[i..i + 8].try_into().expect("8 bytes"));
    let u32_at = |b: &[u8], i: usize| u32::from_le_bytes(b[i..i + 4].try_into().expect("4 bytes"));
    while body.len() - at >= rb {
        let rec = &body[at..at + rb];
        let (dt, rec) = if with_dt {
            let (d, rest) = rec.split_at(8);
            (f64::from_le_bytes(d.try_into().expect("8 bytes")), rest)
        } else {
            (period, rec)
        };
        let f = |i: usize| f64_at(rec, 8 * i);
        let mut t = TickRecord {
            dt,
            n,
            ..Default::default()
        };
        for k in 0..n {
            t.positions[k] = DVec3::new(f(3 * k), f(3 * k + 1), f(3 * k + 2));
            let o = 3 * n + 3 * k;
            t.forces[k] = DVec3::new(f(o), f(o + 1), f(o + 2));
        }
        let mut end = at + rb;
        if with_cuts {
            // The tick's cut events follow its fixed part; a session cut off inside them
            // ends at the tick before.
            let count = u32_at(body, at + rb - 4) as usize;
            let mut events = Vec::new();
            let mut ok = true;
            for _ in 0..count {
                if body.len() < end + 8 {
                    ok = false;
                    break;
                }
                let word = u32_at(body, end);
                let object = (word & !(1 << 31)) as usize;
                let fold_adopted = header.version >= 4 && word >> 31 == 1;
                let m = u32_at(body, end + 4) as usize;
                end += 8;
                if m > (body.len() - end) / 80 {
                    ok = false;
                    break;
                }
                let mut strokes = Vec::with_capacity(m);
                for _ in 0..m {
                    let v = |i: usize| f64_at(body, end + 8 * i);
                    strokes.push(super::cutting::Stroke {
                        object,
                        from: DVec3::new(v(0), v(1), v(2)),
                        to: DVec3::new(v(3), v(4), v(5)),
                        inward: DVec3::new(v(6), v(7), v(8)),
                        depth: v(9),
                    });
                    end += 80;
                }
                events.push(CutEvent {
                    after_tick: ticks.len() as u64,
                    object,
                    strokes,
                    fold_adopted,
                });
            }
            if !ok {
                break;
            }
            cuts.extend(events);
        }
        ticks.push(t);
        at = end;
    }
    Ok(Session {
        path: path.to_path_buf(),
        trailing_bytes: body.len() - at,
        header,
        ticks,
        cuts,
    })
}

/// A session's cuts replayed: a cutter for the scene, and the events in order. Call
/// [`CutReplay::after_tick`] after each replayed tick.
pub struct CutReplay<'s> {
    cutter: Option<super::cutting::Cutter>,
    events: &'s [CutEvent],
    next: usize,
    /// Deferred folds run at their snapshot, waiting for the event that adopts them.
    ready: Vec<super::cutting::Folded>,
}

impl<'s> CutReplay<'s> {
    /// The cut replay of `session` on `world` (no cutter when the session holds no cut). A
    /// version 3 session folds inline, as it was recorded; versions 4 and 5 defer their folds
    /// and adopt each where the recording says; version 5's blades separate.
    pub fn new(world: &World, session: &'s Session) -> Result<CutReplay<'s>, Error> {
        let cutter = if session.cuts.is_empty() {
            None
        } else {
            let mut c = super::cutting::Cutter::new(world)?;
            c.set_fold_mode(if session.header.version >= 4 {
                FoldMode::Deferred
            } else {
                FoldMode::Inline
            });
            c.set_cut_mode(if session.header.version >= 5 {
                CutMode::Separate
            } else {
                CutMode::Remove
            });
            Some(c)
        };
        Ok(CutReplay {
            cutter,
            events: &session.cuts,
            next: 0,
            ready: Vec::new(),
        })
    }

    /// Installs in `hw` every body recorded after tick `i`, built again from its strokes
    /// (after adopting its fold, where it follows one).
    pub fn after_tick(&mut self, i: usize, hw: &mut HapticWorld) -> Result<(), Error> {
        let Some(cutter) = &mut self.cutter else {
            return Ok(());
        };
        while let Some(e) = self.events.get(self.next) {
            if e.after_tick != i as u64 {
                break;
            }
            if e.fold_adopted {
                let k =
                    (self.ready.iter().position(|f| f.object() == e.object)).ok_or_else(|| {
                        Error::Session(format!(
                            "a cut after tick {i} adopts a fold of object {} that was never due",
                            e.object
                        ))
                    })?;
                // Its strokes were made before the adoption, and changed nothing (a
                // separating blade's chords; a removing blade's body has none).
                if cutter.feed_strokes(e.object, &e.strokes)? {
                    return Err(Error::Session(format!(
                        "a cut after tick {i} adopts a fold after strokes that cut"
                    )));
                }
                cutter.adopt(self.ready.swap_remove(k))?;
            }
            let body = if e.fold_adopted {
                Some(cutter.body_now(e.object)?)
            } else {
                cutter.apply_strokes(e.object, &e.strokes)?
            };
            if let Some(body) = body {
                hw.install_cut(e.object, body);
                // Folds due now, as the live cutter handed them out after a pass: run here.
                if !e.strokes.is_empty() {
                    for job in cutter.take_folds()? {
                        match job.run() {
                            (_, Ok(f)) => self.ready.push(f),
                            (o, Err(_)) => cutter.drop_fold(o),
                        }
                    }
                }
            }
            self.next += 1;
        }
        Ok(())
    }
}

/// What a replay found.
///
/// A recorded or replayed force that is not finite (NaN, infinite) makes that tick's
/// difference infinite: `max_force_diff_n` is then `+∞` and `non_finite_ticks` counts such
/// ticks. JSON has no infinity, so the number is written as `1.7976931348623157e308`
/// (`f64::MAX`), never `null`; `touchfem replay` then exits with an error.
#[derive(Clone, Debug, serde::Serialize)]
pub struct ReplayReport {
    /// Ticks replayed.
    pub ticks: usize,
    /// Largest |recorded force − replayed force| over ticks and fingers, N (`+∞` if a force
    /// was not finite).
    #[serde(serialize_with = "finite_or_max")]
    pub max_force_diff_n: f64,
    /// The tick where it occurred (the first non-finite one, if any).
    pub worst_tick: usize,
    /// Largest finite recorded force, N.
    #[serde(serialize_with = "finite_or_max")]
    pub max_force_n: f64,
    /// Ticks where a recorded or replayed force was not finite.
    pub non_finite_ticks: usize,
}

/// Writes a non-finite number as the largest finite one of its sign (NaN as `f64::MAX`):
/// JSON has no infinity, and `null` would read as "no value".
fn finite_or_max<S: serde::Serializer>(v: &f64, s: S) -> Result<S::Ok, S::Error> {
    let v = if v.is_finite() {
        *v
    } else if *v == f64::NEG_INFINITY {
        f64::MIN
    } else {
        f64::MAX
    };
    s.serialize_f64(v)
}

/// Where a session's relative mesh paths are: its header's directory; a relative one (an older
/// file) from the working directory if it exists there, else from the session file's.
fn scene_dir(session: &Session) -> PathBuf {
    let d = &session.header.scene_dir;
    if d.is_absolute() || d.as_os_str().is_empty() || d.is_dir() {
        return d.clone();
    }
    match session.path.parent() {
        Some(p) if p.join(d).is_dir() => p.join(d),
        _ => d.clone(),
    }
}

/// The scene a session was recorded with, loaded from its header (its errors are named by
/// `label`), with each finger's device limits as they were when it ran. The scene's hash is
/// checked against the recorded one before anything is precomputed.
pub fn world(session: &Session, label: &str) -> Result<World, Error> {
    let h = &session.header;
    let bad = |msg: String| Error::Session(format!("{}: {msg}", session.path.display()));
    let src = crate::scene::SceneSource {
        name: h.scene_name.clone(),
        text: h.scene_toml.clone(),
        dir: scene_dir(session),
        label: label.into(),
    };
    check_hash(session, World::hash_of(&src)?)?;
    let mut world = World::from_source(&src)?;
    if !h.finger_limits.is_empty() {
        if h.finger_limits.len() != world.fingers.len() {
            return Err(bad(format!(
                "the header gives limits for {} finger(s), the scene has {}",
                h.finger_limits.len(),
                world.fingers.len()
            )));
        }
        for (f, l) in world.fingers.iter_mut().zip(&h.finger_limits) {
            if let Some(l) = l {
                l.validate()
                    .map_err(|e| bad(format!("bad finger limits: {e}")))?;
            }
            f.limits = l.clone();
        }
    }
    Ok(world)
}

/// The scene hash `have` must be the recorded one.
fn check_hash(session: &Session, have: u64) -> Result<(), Error> {
    let want = &session.header.scene_hash;
    let have = format!("{have:016x}");
    if *want != have {
        return Err(Error::Session(format!(
            "{}: the scene differs from the recorded one (hash {have}, recorded {want}): a mesh or the scene file changed",
            session.path.display()
        )));
    }
    Ok(())
}

/// Runs a session's positions through `world`'s haptic path, tick by tick, and compares the
/// forces with the recorded ones. `world` must be the session's scene (same hash), and the
/// session must hold a tick.
pub fn replay(world: &World, session: &Session) -> Result<ReplayReport, Error> {
    check_hash(session, world.hash)?;
    if world.fingers.len() != session.header.fingers {
        return Err(Error::Session(format!(
            "{}: the scene has {} finger(s), the session {}",
            session.path.display(),
            world.fingers.len(),
            session.header.fingers
        )));
    }
    if session.ticks.is_empty() {
        return Err(Error::Session(format!(
            "{}: the session holds no tick: nothing to replay",
            session.path.display()
        )));
    }
    let mut hw = HapticWorld::new(world);
    let mut cuts = CutReplay::new(world, session)?;
    let n = session.header.fingers;
    let mut sample = WorldSample::default();
    let mut forces = [DVec3::ZERO; MAX_FINGERS];
    let mut rep = ReplayReport {
        ticks: session.ticks.len(),
        max_force_diff_n: 0.0,
        worst_tick: 0,
        max_force_n: 0.0,
        non_finite_ticks: 0,
    };
    for (i, t) in session.ticks.iter().enumerate() {
        hw.step_dt(t.dt, &t.positions[..n], &mut forces[..n], &mut sample);
        let mut finite = true;
        for (k, f) in forces.iter().enumerate().take(n) {
            let d = (*f - t.forces[k]).length();
            // NaN or infinite differences count as infinitely large.
            let d = if d.is_finite() {
                d
            } else {
                finite = false;
                f64::INFINITY
            };
            if d > rep.max_force_diff_n {
                rep.max_force_diff_n = d;
                rep.worst_tick = i;
            }
            let r = t.forces[k].length();
            if r.is_finite() {
                rep.max_force_n = rep.max_force_n.max(r);
            }
        }
        rep.non_finite_ticks += usize::from(!finite);
        cuts.after_tick(i, &mut hw)?;
    }
    Ok(rep)
}
