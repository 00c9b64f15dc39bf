//! A cache file for the precomputed compliance, so that the factorisation and solves run once.
//!
//! Two formats share one magic and the first fields of one header (`format`): the dense one
//! (version 3, `dense`) and the compressed one (version 4, [`hier`]): a hierarchical `L`
//! stored to a tolerance. [`load`], [`load_bytes`], [`save`], [`load_near`] and [`merge`]
//! dispatch on the version. With no tolerance `L` stays dense, bit for bit.
//!
//! The dense format (little-endian), version 3. A file holds the columns `col_begin..col_end`
//! of L: all of them for a complete cache, one part of them for a shard
//! (`touchfem precompute --shard I/N`).
//! ```text
//! magic        8 bytes  "TFEMCMP\0"
//! version      u32      3
//! precision    u32      8 (f64 values)
//! n_nodes      u32
//! rows         u32      R
//! cols         u32      C
//! batch        u32      columns per batch (compliance::BATCH_COLS)
//! key          u64      xxh3 of mesh nodes + tets + material + regions (+ formulation unless standard, with the locking-free element's name) + fixed set + row/column selection
//! shard        u32 ×2   index I (1-based) and count N; a complete file is 1 of 1
//! col range    u32 ×2   col_begin, col_end (on the batch grid)
//! free_dofs    u32
//! l_rows       u32      R' ≤ R: the rows that hold L (the free ones, listed first); the
//!                       clamped rows after them are zero and not stored
//! residual     f64      max |K·x − e| over the checked columns
//! lists        R u32 row nodes, C u32 column nodes (all of them, also in a shard)
//! L            9·R'·(col_end − col_begin) f64 (layout of `compliance`, those columns only)
//! batch sums   one u64 per batch of the range: xxh3 of that batch's L bytes
//! checksum     u64      xxh3 of header + lists + batch sums
//! ```
//!
//! Every file is self-describing (the key names the mesh, material and selection), so a merge of
//! parts made for different meshes, materials or selections is refused ([`CacheError::Mismatch`]).
//! A missing, stale (other key), truncated or corrupt (bad checksum) file is reported as a
//! [`CacheError`] and [`load_or_compute`] recomputes and rewrites it; nothing stale is used.
//! A file made with another compression than asked for is [`CacheError::Compression`], named
//! with both tolerances; [`load_or_compute_file`] keeps a compressed file compressed.
//! Files are written to a unique temporary name, synced, renamed, and the directory synced.
//! Every parse reads bytes: a cache is read from a file or from `&[u8]` ([`load_bytes`]).

use std::path::{Path, PathBuf};

mod atomic;
mod dense;
mod error;
pub(crate) mod format;
pub mod hier;
mod key;
mod runs;

pub use atomic::write_atomic;
#[cfg(feature = "native")]
pub(crate) use atomic::AtomicFile;
pub(crate) use dense::{load_near_part, shard_batches, Writer};
pub use dense::{Header, Part};
pub use error::CacheError;
pub use key::{key, key_for, key_hier};

use crate::compliance::hmatrix::HOptions;
use crate::compliance::{Compliance, Selection};
use crate::mesh::Mesh;

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

/// The cache file of an object: `NAME-KEY.tfc` in `dir`, the name made file-safe.
pub fn file_in(dir: &Path, name: &str, key: u64) -> PathBuf {
    let safe: String = name
        .chars()
        .map(|c| if c.is_ascii_alphanumeric() { c } else { '_' })
        .collect();
    dir.join(format!("{safe}-{key:016x}.tfc"))
}

/// The name of shard `(I, N)` of `path`: `path` itself for a complete file (`N = 1`), else
/// `path` with `.part-I-of-N` appended.
pub fn shard_file(path: PathBuf, shard: (usize, usize)) -> PathBuf {
    if shard.1 == 1 {
        return path;
    }
    let mut s = path.into_os_string();
    s.push(format!(".part-{}-of-{}", shard.0, shard.1));
    PathBuf::from(s)
}

/// Reads a complete compliance from `path`, checking magic, version, precision, key, length,
/// checksums and that it is not a shard. A dense (version 3) file streams `L` into memory batch
/// by batch (no second copy of the file); a compressed (version 4) one gives a hierarchical
/// compliance ([`hier::load`]). The key alone says what the file must be; see
/// [`load_made_with`] to check the compression too.
pub fn load(path: &Path, expected_key: u64, n_nodes: usize) -> Result<Compliance, CacheError> {
    if hier::is_compressed(path) {
        return hier::load(path, expected_key, n_nodes, None);
    }
    dense::load(Part::open(path)?, expected_key, n_nodes)
}

/// As [`load`], from a whole cache file's bytes in memory (either format); errors name the
/// file `(bytes)`.
pub fn load_bytes(
    bytes: &[u8],
    expected_key: u64,
    n_nodes: usize,
) -> Result<Compliance, CacheError> {
    if format::is_version(bytes, hier::FORMAT_VERSION) {
        return hier::load_bytes(bytes, expected_key, n_nodes, None);
    }
    dense::load(Part::from_bytes(bytes)?, expected_key, n_nodes)
}

/// As [`load`], and the file must have been made with `compression` (`None`: dense): a file
/// made with another tolerance or options, or compressed where dense `L` is asked for (or the
/// other way round), is [`CacheError::Compression`]. A compressed file's header options are
/// checked against `compression` themselves, so a header whose tolerance was changed (and its
/// checksums fixed) is refused though its key still matches.
pub fn load_made_with(
    path: &Path,
    expected_key: u64,
    n_nodes: usize,
    compression: Option<&HOptions>,
) -> Result<Compliance, CacheError> {
    let asked = compression.copied();
    if hier::is_compressed(path) {
        if asked.is_none() {
            return Err(CacheError::Compression {
                path: path.to_path_buf(),
                found: Some(hier::header(path)?.opts),
                asked,
            });
        }
        return hier::load(path, expected_key, n_nodes, compression);
    }
    let part = Part::open(path)?;
    if asked.is_some() {
        return Err(CacheError::Compression {
            path: path.to_path_buf(),
            found: None,
            asked,
        });
    }
    dense::load(part, expected_key, n_nodes)
}

/// Loads a complete compliance from `path` (checked as [`load`]). A dense file is loaded
/// without holding `L`: each batch is read, checked and dropped, keeping only the blocks of the
/// near pairs of `triangles` for the haptic path; the deformer reads `L` from the file again
/// ([`Compliance::stored_l`]). A compressed (version 4) file is loaded whole: it is small.
pub fn load_near(
    path: &Path,
    expected_key: u64,
    n_nodes: usize,
    triangles: &[[u32; 3]],
) -> Result<Compliance, CacheError> {
    if hier::is_compressed(path) {
        return hier::load(path, expected_key, n_nodes, None);
    }
    load_near_part(Part::open(path)?, expected_key, n_nodes, triangles)
}

/// Writes a complete compliance to `path` (atomically: a unique temporary file, synced, then a
/// rename and a sync of the directory): a dense one as version 3, a hierarchical one
/// ([`Compliance::hier`]) as version 4 ([`hier`]).
pub fn save(path: &Path, c: &Compliance, key: u64, n_nodes: usize) -> Result<(), CacheError> {
    if c.hier().is_some() {
        return hier::save(path, c, key, n_nodes).map(|_| ());
    }
    dense::save(path, c, key, n_nodes)
}

/// The bytes [`save`] writes for a dense compliance, in memory and without a file (the web
/// page's worker): equal to the file byte for byte, read back with [`load_bytes`]. A
/// hierarchical compliance is refused.
pub fn to_bytes(c: &Compliance, key: u64, n_nodes: usize) -> Result<Vec<u8>, CacheError> {
    dense::to_bytes(c, key, n_nodes)
}

/// What a merge wrote.
#[derive(Clone, Debug)]
pub struct MergeInfo {
    /// Displayed nodes.
    pub rows: usize,
    /// Touchable nodes.
    pub cols: usize,
    /// Bytes of the merged file.
    pub bytes: u64,
    /// The compression tolerance of compressed (version 4) parts; `None` for dense ones.
    pub tolerance: Option<f64>,
}

/// Joins the shards `parts` (any order) into one complete file at `out`, equal byte for byte to
/// the unsharded precompute. Refuses parts made for another mesh, material or selection (or
/// compressed with other options), and a missing, repeated or overlapping part
/// ([`CacheError::Mismatch`]); checks every checksum while copying. The first part's version
/// says which format is merged ([`hier::merge`] for compressed parts).
pub fn merge(parts: &[PathBuf], out: &Path) -> Result<MergeInfo, CacheError> {
    if parts.first().is_some_and(|p| hier::is_compressed(p)) {
        let (h, bytes) = hier::merge(parts, out)?;
        return Ok(MergeInfo {
            rows: h.rows as usize,
            cols: h.cols as usize,
            bytes,
            tolerance: Some(h.opts.tolerance),
        });
    }
    let (h, bytes) = dense::merge(parts, out)?;
    Ok(MergeInfo {
        rows: h.rows as usize,
        cols: h.cols as usize,
        bytes,
        tolerance: None,
    })
}

/// The compression the file at `path` was made with: `None` for a dense file, a missing or
/// unreadable file, or one that is no touchfem cache; the header's options for a compressed
/// one. A file that says it is compressed (its version field; or the magic with a version
/// that is neither format's) but whose header cannot be read is
/// [`CacheError::Unreadable`]: nobody can tell its tolerance, and replacing it with a dense
/// `L` could make it many times larger.
pub fn stored_compression(path: &Path) -> Result<Option<HOptions>, CacheError> {
    use std::io::Read;
    let mut prefix = Vec::with_capacity(12);
    let read = std::fs::File::open(path).and_then(|f| f.take(12).read_to_end(&mut prefix));
    if read.is_err() {
        return Ok(None);
    }
    match format::kind(&prefix) {
        format::Kind::Dense | format::Kind::Other => Ok(None),
        format::Kind::Compressed | format::Kind::Unknown => match hier::header(path) {
            Ok(h) => Ok(Some(h.opts)),
            Err(e) => Err(CacheError::Unreadable {
                path: path.to_path_buf(),
                why: match e {
                    CacheError::Corrupt { why, .. } => why,
                    CacheError::Format { msg, .. } => msg,
                    e => e.to_string(),
                },
            }),
        },
    }
}

/// Loads the compliance from `path` if it is valid for this mesh and selection; otherwise
/// computes it and (re)writes the file. Never uses a stale, truncated or corrupt file; a file
/// that cannot be written never throws the computed compliance away
/// ([`CacheOutcome::NotSaved`]).
pub fn load_or_compute(
    path: &Path,
    mesh: &Mesh,
    sel: &Selection,
) -> Result<(Compliance, CacheOutcome), CacheError> {
    load_or_compute_with(path, mesh, sel, None)
}

/// As [`load_or_compute`]; with `compression`, `L` is stored hierarchically to its tolerance:
/// a compressed (version 4) file with [`key_hier`]'s key and those options is loaded, or the
/// compliance is computed with [`Compliance::compute_hier`] and saved as one. `None`: the
/// dense cache. A file made with other options (or the other kind) is recomputed, the note
/// saying so ([`CacheError::Compression`], checked by [`load_made_with`]).
pub fn load_or_compute_with(
    path: &Path,
    mesh: &Mesh,
    sel: &Selection,
    compression: Option<&HOptions>,
) -> Result<(Compliance, CacheOutcome), CacheError> {
    let n = mesh.nodes.len();
    let k = key_for(mesh, sel, compression);
    match load_made_with(path, k, n, compression) {
        Ok(c) => Ok((c, CacheOutcome::Hit)),
        Err(why) => {
            let c = match compression {
                Some(opts) => Compliance::compute_hier(mesh, sel, opts, &mut |_, _| {})?,
                None => Compliance::compute(mesh, sel)?,
            };
            match save(path, &c, k, n) {
                Ok(()) => Ok((c, CacheOutcome::Recomputed(why))),
                Err(e) => Ok((c, CacheOutcome::NotSaved(why, e))),
            }
        }
    }
}

/// As [`load_or_compute_with`] for a file the user named: with `compression`, as there; with
/// `None`, the file's own kind ([`stored_compression`]): a compressed file stays compressed
/// (loaded, or recomputed with its header's options), and a compressed file whose header
/// cannot be read is an error ([`CacheError::Unreadable`]) rather than rewritten dense.
pub fn load_or_compute_file(
    path: &Path,
    mesh: &Mesh,
    sel: &Selection,
    compression: Option<&HOptions>,
) -> Result<(Compliance, CacheOutcome), CacheError> {
    let compression = match compression {
        Some(o) => Some(*o),
        None => stored_compression(path)?,
    };
    load_or_compute_with(path, mesh, sel, compression.as_ref())
}
