//! A cache file for the precomputed compliance, so that the factorisation and solves run once.
//!
//! Format (little-endian), version 1:
//! ```text
//! magic     8 bytes  "TFEMCMP\0"
//! version   u32      1
//! precision u32      8 (f64 values)
//! n_nodes   u32
//! rows      u32      R
//! cols      u32      C
//! reserved  u32      0
//! key       u64      xxh3 of mesh nodes + tets + material + fixed set + row/column selection
//! payload   R u32 row nodes, C u32 column nodes, 9·R·C f64 L (layout of `compliance`),
//!           4 f64 stats (residual, symmetry, seconds, free dofs)
//! checksum  u64      xxh3 of the payload
//! ```
//! A missing, stale (other key), truncated or corrupt (bad checksum) file is reported as a
//! [`CacheError`] and [`load_or_compute`] recomputes and rewrites it; nothing stale is used.

use std::io::Write;
use std::path::{Path, PathBuf};
use thiserror::Error;
use xxhash_rust::xxh3::{xxh3_64, Xxh3};

use crate::compliance::{Compliance, Selection};
use crate::mesh::Mesh;

const MAGIC: &[u8; 8] = b"TFEMCMP\0";
/// The cache format version this build reads and writes.
pub const FORMAT_VERSION: u32 = 1;
const HEADER: usize = 8 + 4 * 6 + 8;

/// Why a cache file was not used.
#[derive(Debug, Error)]
pub enum CacheError {
    /// No file, or it cannot be read or written.
    #[error("cache {path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The OS error.
        source: std::io::Error,
    },
    /// Not a touchfem cache, or another format version or precision.
    #[error("cache {path}: {msg}")]
    Format {
        /// The file.
        path: PathBuf,
        /// What is wrong.
        msg: String,
    },
    /// Made for another mesh, material, clamp set or selection.
    #[error("cache {path} is stale (made for another mesh, material or selection)")]
    Stale {
        /// The file.
        path: PathBuf,
    },
    /// Shorter than its header says.
    #[error("cache {path} is truncated ({len} bytes, expected {expected})")]
    Truncated {
        /// The file.
        path: PathBuf,
        /// Its length.
        len: usize,
        /// The length the header implies.
        expected: usize,
    },
    /// The checksum does not match.
    #[error("cache {path} is corrupt (checksum mismatch)")]
    Corrupt {
        /// The file.
        path: PathBuf,
    },
}

/// What happened when loading through the cache.
#[derive(Debug)]
pub enum CacheOutcome {
    /// The file was valid and used.
    Hit,
    /// The file could not be used (the reason), so L was recomputed and the file rewritten.
    Recomputed(CacheError),
    /// L was computed (the first error says why the file could not be used) but the file could
    /// not be written (the second): the compliance is kept in memory and the session goes on.
    NotSaved(CacheError, CacheError),
}

impl CacheOutcome {
    /// A one-line note (`note: …`) or warning (`warning: …`) for the user; `None` on a hit.
    pub fn message(&self) -> Option<String> {
        match self {
            CacheOutcome::Hit => None,
            CacheOutcome::Recomputed(why) => Some(format!("note: compliance recomputed ({why})")),
            CacheOutcome::NotSaved(_, e) => Some(format!(
                "warning: the compliance cache could not be written ({e}); going on with the computed compliance"
            )),
        }
    }
}

/// A temporary file name next to `path`, unique to this process, thread and call.
fn unique_tmp(path: &Path) -> std::path::PathBuf {
    use std::sync::atomic::{AtomicU64, Ordering};
    static N: AtomicU64 = AtomicU64::new(0);
    let n = N.fetch_add(1, Ordering::Relaxed);
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.subsec_nanos());
    let mut name = path.file_name().unwrap_or_default().to_os_string();
    name.push(format!(".{}.{n}.{nanos:08x}.tmp", std::process::id()));
    path.with_file_name(name)
}

/// The hash that a cache file must match: mesh geometry and topology, material, clamp set and
/// the row/column selection.
pub fn key(mesh: &Mesh, sel: &Selection) -> u64 {
    let mut h = Xxh3::new();
    h.update(&FORMAT_VERSION.to_le_bytes());
    for p in &mesh.nodes {
        for c in p.to_array() {
            h.update(&c.to_bits().to_le_bytes());
        }
    }
    for t in &mesh.tets {
        for i in t {
            h.update(&i.to_le_bytes());
        }
    }
    h.update(&mesh.material.young_pa.to_bits().to_le_bytes());
    h.update(&mesh.material.poisson.to_bits().to_le_bytes());
    for &f in &mesh.fixed {
        h.update(&[f as u8]);
    }
    for set in [&sel.rows, &sel.cols] {
        h.update(b"|");
        for n in set.resolve(mesh) {
            h.update(&n.to_le_bytes());
        }
    }
    h.digest()
}

/// Writes a compliance to `path` (atomically: a temporary file, then a rename).
pub fn save(path: &Path, c: &Compliance, key: u64, n_nodes: usize) -> Result<(), CacheError> {
    let io = |source| CacheError::Io {
        path: path.to_path_buf(),
        source,
    };
    let mut payload =
        Vec::with_capacity(4 * (c.rows().len() + c.cols().len()) + 8 * c.l_f64().len() + 32);
    for &r in c.rows() {
        payload.extend_from_slice(&r.to_le_bytes());
    }
    for &k in c.cols() {
        payload.extend_from_slice(&k.to_le_bytes());
    }
    for &v in c.l_f64() {
        payload.extend_from_slice(&v.to_le_bytes());
    }
    for v in [
        c.stats.residual,
        c.stats.symmetry,
        c.stats.seconds,
        c.stats.free_dofs as f64,
    ] {
        payload.extend_from_slice(&v.to_le_bytes());
    }
    let mut head = Vec::with_capacity(HEADER);
    head.extend_from_slice(MAGIC);
    for v in [
        FORMAT_VERSION,
        8,
        n_nodes as u32,
        c.rows().len() as u32,
        c.cols().len() as u32,
        0,
    ] {
        head.extend_from_slice(&v.to_le_bytes());
    }
    head.extend_from_slice(&key.to_le_bytes());
    if let Some(dir) = path.parent() {
        if !dir.as_os_str().is_empty() {
            std::fs::create_dir_all(dir).map_err(io)?;
        }
    }
    let tmp = unique_tmp(path);
    let written = (|| {
        let mut f = std::fs::File::create_new(&tmp)?;
        f.write_all(&head)?;
        f.write_all(&payload)?;
        f.write_all(&xxh3_64(&payload).to_le_bytes())?;
        f.sync_all()?;
        drop(f);
        std::fs::rename(&tmp, path)
    })();
    if written.is_err() {
        let _ = std::fs::remove_file(&tmp);
    }
    written.map_err(io)
}

fn u32_at(b: &[u8], o: usize) -> u32 {
    u32::from_le_bytes(b[o..o + 4].try_into().expect("4 bytes"))
}
fn u64_at(b: &[u8], o: usize) -> u64 {
    u64::from_le_bytes(b[o..o + 8].try_into().expect("8 bytes"))
}

/// Reads a compliance from `path`, checking magic, version, precision, key, length and checksum.
pub fn load(path: &Path, expected_key: u64, n_nodes: usize) -> Result<Compliance, CacheError> {
    let p = || path.to_path_buf();
    let b = std::fs::read(path).map_err(|source| CacheError::Io { path: p(), source })?;
    if b.len() < HEADER {
        return Err(CacheError::Truncated {
            path: p(),
            len: b.len(),
            expected: HEADER,
        });
    }
    if &b[..8] != MAGIC {
        return Err(CacheError::Format {
            path: p(),
            msg: "not a touchfem compliance cache".into(),
        });
    }
    let version = u32_at(&b, 8);
    if version != FORMAT_VERSION {
        return Err(CacheError::Format {
            path: p(),
            msg: format!("format version {version}, this build reads {FORMAT_VERSION}"),
        });
    }
    if u32_at(&b, 12) != 8 {
        return Err(CacheError::Format {
            path: p(),
            msg: format!("precision {} bytes, expected 8", u32_at(&b, 12)),
        });
    }
    let nn = u32_at(&b, 16) as usize;
    let nr = u32_at(&b, 20) as usize;
    let nc = u32_at(&b, 24) as usize;
    if u64_at(&b, 32) != expected_key || nn != n_nodes {
        return Err(CacheError::Stale { path: p() });
    }
    let payload_len = 4usize
        .checked_mul(nr + nc)
        .and_then(|x| x.checked_add(72usize.checked_mul(nr)?.checked_mul(nc)?))
        .and_then(|x| x.checked_add(32))
        .ok_or_else(|| CacheError::Format {
            path: p(),
            msg: "sizes overflow".into(),
        })?;
    let expected = HEADER + payload_len + 8;
    if b.len() != expected {
        return Err(CacheError::Truncated {
            path: p(),
            len: b.len(),
            expected,
        });
    }
    let payload = &b[HEADER..HEADER + payload_len];
    if xxh3_64(payload) != u64_at(&b, HEADER + payload_len) {
        return Err(CacheError::Corrupt { path: p() });
    }
    let rows: Vec<u32> = (0..nr).map(|i| u32_at(payload, 4 * i)).collect();
    let cols: Vec<u32> = (0..nc).map(|i| u32_at(payload, 4 * (nr + i))).collect();
    let lo = 4 * (nr + nc);
    let l: Vec<f64> = (0..9 * nr * nc)
        .map(|i| f64::from_bits(u64_at(payload, lo + 8 * i)))
        .collect();
    let so = lo + 72 * nr * nc;
    let stat = |k: usize| f64::from_bits(u64_at(payload, so + 8 * k));
    let mut c = Compliance::from_dense(rows, cols, l, n_nodes).map_err(|e| CacheError::Format {
        path: p(),
        msg: format!("inconsistent contents: {e}"),
    })?;
    c.stats.residual = stat(0);
    c.stats.seconds = stat(2);
    c.stats.free_dofs = stat(3) as usize;
    Ok(c)
}

/// Loads the compliance from `path` if it is valid for this mesh and selection; otherwise
/// computes it and (re)writes the file. Never uses a stale, truncated or corrupt file; a file
/// that cannot be written never throws the computed compliance away
/// ([`CacheOutcome::NotSaved`]).
pub fn load_or_compute(
    path: &Path,
    mesh: &Mesh,
    sel: &Selection,
) -> Result<(Compliance, CacheOutcome), crate::Error> {
    let k = key(mesh, sel);
    match load(path, k, mesh.nodes.len()) {
        Ok(c) => Ok((c, CacheOutcome::Hit)),
        Err(why) => {
            let c = Compliance::compute(mesh, sel)?;
            match save(path, &c, k, mesh.nodes.len()) {
                Ok(()) => Ok((c, CacheOutcome::Recomputed(why))),
                Err(e) => Ok((c, CacheOutcome::NotSaved(why, e))),
            }
        }
    }
}
