//! What both cache formats share: the magic, the fields every header holds at the same
//! offsets (one reader and one writer for them), the checks of those fields, the little-endian
//! helpers, where a file's bytes come from (a file or a byte slice), and the merge's checks of
//! its parts. The dense format ([`super::dense`], version 3) and the compressed one
//! ([`super::hier`], version 4) lay out the rest of their headers on top.
//!
//! ```text
//! offset
//!   0  magic        8 bytes  "TFEMCMP\0"
//!   8  version      u32      3 (dense) or 4 (compressed)
//!  12  precision    u32      8 (f64 values)
//!  16  n_nodes      u32
//!  20  rows         u32      R (displayed nodes)
//!  24  cols         u32      C (touchable nodes)
//!  28  (the format's own field)
//!  32  key          u64
//!  40  shard        u32 ×2   index I (1-based) and count N; a complete file is 1 of 1
//! ```
//! Every parse here reads a byte slice: the same code reads a file and bytes in memory.

use std::path::{Path, PathBuf};

use super::error::CacheError;
use super::runs::{check_runs, PartRun};

/// The magic of every touchfem cache file (both versions).
pub(crate) const MAGIC: &[u8; 8] = b"TFEMCMP\0";
/// The dense format's version.
pub(crate) const DENSE_VERSION: u32 = 3;
/// The compressed format's version.
pub(crate) const HIER_VERSION: u32 = 4;
/// The name errors give to a cache read from bytes in memory.
pub(crate) const BYTES_NAME: &str = "(bytes)";

pub(crate) fn u32_at(b: &[u8], o: usize) -> u32 {
    u32::from_le_bytes(b[o..o + 4].try_into().expect("4 bytes"))
}
pub(crate) fn u64_at(b: &[u8], o: usize) -> u64 {
    u64::from_le_bytes(b[o..o + 8].try_into().expect("8 bytes"))
}
pub(crate) fn f64_at(b: &[u8], o: usize) -> f64 {
    f64::from_bits(u64_at(b, o))
}

/// Which format a file's first bytes name.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Kind {
    /// The magic and version 3.
    Dense,
    /// Version 4 (with the magic, or with a damaged magic but the version intact).
    Compressed,
    /// The magic with another version: a damaged version field, or a format this build does
    /// not know.
    Unknown,
    /// Too short, or not a touchfem cache.
    Other,
}

/// The format `prefix` (a file's first bytes, at least 12 to tell) names.
pub(crate) fn kind(prefix: &[u8]) -> Kind {
    if prefix.len() < 12 {
        return Kind::Other;
    }
    let magic = &prefix[..8] == MAGIC;
    match u32_at(prefix, 8) {
        DENSE_VERSION if magic => Kind::Dense,
        HIER_VERSION => Kind::Compressed,
        _ if magic => Kind::Unknown,
        _ => Kind::Other,
    }
}

/// Whether `prefix` starts with the magic and `version`.
pub(crate) fn is_version(prefix: &[u8], version: u32) -> bool {
    prefix.len() >= 12 && &prefix[..8] == MAGIC && u32_at(prefix, 8) == version
}

/// The header fields both formats hold at the same offsets.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Common {
    pub n_nodes: u32,
    pub rows: u32,
    pub cols: u32,
    pub key: u64,
    pub shard_index: u32,
    pub shard_count: u32,
}

impl Common {
    /// Writes the magic, `version`, the precision (8) and these fields into `h` (a header of
    /// at least 48 bytes).
    pub fn put(&self, h: &mut [u8], version: u32) {
        h[..8].copy_from_slice(MAGIC);
        let mut put = |o: usize, v: &[u8]| h[o..o + v.len()].copy_from_slice(v);
        put(8, &version.to_le_bytes());
        put(12, &8u32.to_le_bytes());
        put(16, &self.n_nodes.to_le_bytes());
        put(20, &self.rows.to_le_bytes());
        put(24, &self.cols.to_le_bytes());
        put(32, &self.key.to_le_bytes());
        put(40, &self.shard_index.to_le_bytes());
        put(44, &self.shard_count.to_le_bytes());
    }

    /// Reads the fields of a header of at least 48 bytes after checking the magic, that the
    /// version is `version` (`what`: the format's name in the message) and the precision.
    pub fn read(h: &[u8], version: u32, what: &str) -> Result<Common, String> {
        if &h[..8] != MAGIC {
            return Err("not a touchfem compliance cache".into());
        }
        let v = u32_at(h, 8);
        if v != version {
            return Err(format!("format version {v}, expected {version} ({what})"));
        }
        if u32_at(h, 12) != 8 {
            return Err(format!("precision {} bytes, expected 8", u32_at(h, 12)));
        }
        Ok(Common {
            n_nodes: u32_at(h, 16),
            rows: u32_at(h, 20),
            cols: u32_at(h, 24),
            key: u64_at(h, 32),
            shard_index: u32_at(h, 40),
            shard_count: u32_at(h, 44),
        })
    }

    /// What is wrong with `l_rows` against the rows, if anything.
    pub fn rows_inconsistency(&self, l_rows: u32) -> Option<String> {
        (l_rows > self.rows).then(|| format!("{} rows of L, {} rows", l_rows, self.rows))
    }

    /// What is wrong with the shard index and count, if anything.
    pub fn shard_inconsistency(&self) -> Option<String> {
        (self.shard_index == 0 || self.shard_index > self.shard_count)
            .then(|| format!("part {} of {}", self.shard_index, self.shard_count))
    }

    /// Whether the file is a shard where a complete file is needed.
    pub fn partial(&self, path: &Path, begin: u32, end: u32, total: u32) -> Option<CacheError> {
        (self.shard_count != 1 || begin != 0 || end != total).then(|| CacheError::Partial {
            path: path.to_path_buf(),
            index: self.shard_index,
            count: self.shard_count,
        })
    }

    /// [`CacheError::Stale`] unless the key and node count are those expected.
    pub fn fresh(&self, path: &Path, key: u64, n_nodes: usize) -> Result<(), CacheError> {
        if self.key != key || self.n_nodes as usize != n_nodes {
            return Err(CacheError::Stale {
                path: path.to_path_buf(),
            });
        }
        Ok(())
    }
}

/// The shared fields between [`Common`] and a format's header, whose fields of the same names
/// hold them: `common_fields!(of HEADER)` is its [`Common`]; `common_fields!(COMMON => Header {
/// rest })` a `Header` of those fields and the rest.
macro_rules! common_fields {
    (of $h:expr) => {{
        let h = $h;
        $crate::cache::format::Common {
            n_nodes: h.n_nodes,
            rows: h.rows,
            cols: h.cols,
            key: h.key,
            shard_index: h.shard_index,
            shard_count: h.shard_count,
        }
    }};
    ($c:expr => $header:ident { $($rest:tt)* }) => {{
        let c: $crate::cache::format::Common = $c;
        $header {
            n_nodes: c.n_nodes,
            rows: c.rows,
            cols: c.cols,
            key: c.key,
            shard_index: c.shard_index,
            shard_count: c.shard_count,
            $($rest)*
        }
    }};
}
pub(crate) use common_fields;

/// What is wrong with a run `begin..end` of `total` (`what`: "columns" or "panels").
pub(crate) fn range_inconsistency(begin: u32, end: u32, total: u32, what: &str) -> Option<String> {
    (begin > end || end > total).then(|| format!("{what} {begin}..{end} of {total}"))
}

/// Positioned reads and writes of a file (the batch writers share it across threads): Unix's
/// `FileExt`; elsewhere (e.g. `wasm32-unknown-unknown`, which has no files) an `Unsupported`
/// error.
pub(crate) trait FileAt {
    /// Fills `buf` from offset `off`.
    fn read_exact_at(&self, buf: &mut [u8], off: u64) -> std::io::Result<()>;
    /// Writes all of `buf` at offset `off`.
    fn write_all_at(&self, buf: &[u8], off: u64) -> std::io::Result<()>;
}

impl FileAt for std::fs::File {
    fn read_exact_at(&self, buf: &mut [u8], off: u64) -> std::io::Result<()> {
        #[cfg(unix)]
        {
            std::os::unix::fs::FileExt::read_exact_at(self, buf, off)
        }
        #[cfg(not(unix))]
        {
            let _ = (buf, off);
            Err(std::io::ErrorKind::Unsupported.into())
        }
    }

    fn write_all_at(&self, buf: &[u8], off: u64) -> std::io::Result<()> {
        #[cfg(unix)]
        {
            std::os::unix::fs::FileExt::write_all_at(self, buf, off)
        }
        #[cfg(not(unix))]
        {
            let _ = (buf, off);
            Err(std::io::ErrorKind::Unsupported.into())
        }
    }
}

/// Where a cache's bytes come from: a file (read at offsets), or bytes in memory.
pub(crate) enum Source<'a> {
    /// An open file.
    File(std::fs::File),
    /// Bytes in memory.
    Bytes(&'a [u8]),
}

impl Source<'_> {
    /// The length in bytes.
    pub fn len(&self) -> std::io::Result<u64> {
        match self {
            Source::File(f) => Ok(f.metadata()?.len()),
            Source::Bytes(b) => Ok(b.len() as u64),
        }
    }

    /// Fills `buf` from offset `off`; an `UnexpectedEof` error if the source ends first.
    pub fn read_exact_at(&self, buf: &mut [u8], off: u64) -> std::io::Result<()> {
        match self {
            Source::File(f) => FileAt::read_exact_at(f, buf, off),
            Source::Bytes(b) => {
                let at = usize::try_from(off).ok();
                let part = at.and_then(|a| b.get(a..a.checked_add(buf.len())?));
                match part {
                    Some(p) => {
                        buf.copy_from_slice(p);
                        Ok(())
                    }
                    None => Err(std::io::ErrorKind::UnexpectedEof.into()),
                }
            }
        }
    }
}

/// One opened part of a merge, as the shared checks see it.
pub(crate) trait Shard {
    /// Its file.
    fn path(&self) -> &Path;
    /// Its common header fields.
    fn common(&self) -> Common;
    /// The run it holds (columns or panels) and the whole's length.
    fn run(&self) -> (u32, u32, u32);
    /// The residual it stores.
    fn residual(&self) -> f64;
    /// Whether its node lists (and points) equal `first`'s.
    fn same_lists(&self, first: &Self) -> bool;
    /// Why it was made otherwise than `first` (batch size, options, stiffness), if it was.
    fn other_make(&self, first: &Self) -> Option<String>;
}

/// The shared checks of a merge of `opened` (the parts `given` names, in that order) into
/// `out`: at least one part; every part made for the first one's mesh, material and selection
/// (`made_for` names them in the message) and in the same way; each of the parts given once,
/// their runs (`what`) following each other from 0 to the whole. Sorts `opened` by shard index
/// and returns the largest residual.
pub(crate) fn check_merge<P: Shard>(
    opened: &mut [P],
    given: &[PathBuf],
    out: &Path,
    what: &str,
    made_for: &str,
) -> Result<f64, CacheError> {
    let Some(first) = opened.first() else {
        return Err(CacheError::Mismatch {
            path: out.to_path_buf(),
            msg: "no parts given".into(),
        });
    };
    let h0 = first.common();
    for p in opened.iter() {
        let h = p.common();
        let bad = |msg: String| {
            Err(CacheError::Mismatch {
                path: p.path().to_path_buf(),
                msg,
            })
        };
        if h.key != h0.key || h.n_nodes != h0.n_nodes || !p.same_lists(first) {
            return bad(format!(
                "made for another {made_for} than {} (key {:016x}, not {:016x})",
                given[0].display(),
                h.key,
                h0.key
            ));
        }
        if let Some(why) = p.other_make(first) {
            return bad(why);
        }
        if h.shard_count as usize != given.len() {
            return bad(format!(
                "is part {} of {}, but {} parts were given",
                h.shard_index,
                h.shard_count,
                given.len()
            ));
        }
    }
    opened.sort_by_key(|p| p.common().shard_index);
    let runs: Vec<PartRun<'_>> = opened
        .iter()
        .map(|p| PartRun {
            path: p.path(),
            shard_index: p.common().shard_index,
            begin: p.run().0,
            end: p.run().1,
        })
        .collect();
    check_runs(&runs, opened[0].run().2, what)?;
    Ok(opened.iter().map(|p| p.residual()).fold(0.0f64, f64::max))
}

#[cfg(any(test, feature = "self-check"))]
pub(crate) mod tests {
    use super::*;

    #[cfg_attr(test, test)]
    pub(crate) fn the_common_header_reads_what_it_writes() {
        let c = Common {
            n_nodes: 7,
            rows: 5,
            cols: 3,
            key: 0x0123_4567_89ab_cdef,
            shard_index: 2,
            shard_count: 3,
        };
        let mut h = [0u8; 48];
        c.put(&mut h, HIER_VERSION);
        assert_eq!(Common::read(&h, HIER_VERSION, "compressed"), Ok(c));
        assert_eq!(kind(&h), Kind::Compressed);
        assert!(Common::read(&h, DENSE_VERSION, "dense")
            .unwrap_err()
            .contains("format version 4, expected 3 (dense)"));
        h[0] ^= 1;
        assert_eq!(kind(&h), Kind::Compressed, "the version still tells");
        c.put(&mut h, DENSE_VERSION);
        assert_eq!(kind(&h), Kind::Dense);
        h[8] = 9;
        assert_eq!(kind(&h), Kind::Unknown);
        assert_eq!(kind(&h[..11]), Kind::Other);
    }

    #[cfg_attr(test, test)]
    pub(crate) fn byte_sources_read_within_their_length() {
        let b = [1u8, 2, 3, 4];
        let s = Source::Bytes(&b);
        let mut out = [0u8; 2];
        s.read_exact_at(&mut out, 2).unwrap();
        assert_eq!(out, [3, 4]);
        assert!(s.read_exact_at(&mut out, 3).is_err());
        assert!(s.read_exact_at(&mut out, u64::MAX).is_err());
        assert_eq!(s.len().unwrap(), 4);
    }
}
