//! The compressed cache format, version 4: a hierarchical compliance ([`HMatrix`]) stored as
//! its panels (dense near blocks and low-rank far blocks), so that the file is about as small
//! as what the GPU holds. The dense format (version 3) is untouched: with no tolerance `L`
//! stays dense, bit for bit.
//!
//! Format (little-endian), version 4. A file holds the panels `panel_begin..panel_end` of the
//! plan: all of them for a complete cache, a contiguous run for a shard
//! ([`crate::compliance::shard_panels`]).
//! ```text
//! offset
//!   0  magic        8 bytes  "TFEMCMP\0" (as version 3)
//!   8  version      u32      4
//!  12  precision    u32      8 (f64 values)
//!  16  n_nodes      u32
//!  20  rows         u32      R (displayed nodes)
//!  24  cols         u32      C (touchable nodes)
//!  28  l_rows       u32      R' ≤ R: the rows that hold L (listed first)
//!  32  key          u64      cache::key_hier (mesh, selection and the options below)
//!  40  shard        u32 ×2   index I (1-based) and count N; a complete file is 1 of 1
//!  48  panels       u32      panels of the plan
//!  52  panel range  u32 ×2   panel_begin, panel_end
//!  60  free_dofs    u32
//!  64  tolerance    f64      HOptions::tolerance
//!  72  eta          f64      HOptions::eta
//!  80  leaf_size    u32      HOptions::leaf_size
//!  84  panel_size   u32      HOptions::panel_size
//!  88  residual     f64      max |K·x − e| over the checked columns held
//!  96  header sum   u64      xxh3 of bytes 0..96
//! 104  lists        R u32 row nodes, C u32 column nodes
//!      points       R'×3 f64 positions of the held rows, C×3 f64 positions of the columns
//!      lists sum    u64      xxh3 of lists + points
//!      panels       for each panel of the range, in order:
//!        index        u32
//!        blocks       u32      b
//!        values       u64      v
//!        norm_sq      f64      ‖panel's blocks‖_F²
//!        discarded_sq f64      what their truncation discarded
//!        ranks        b × u32  each block's rank, 0xFFFFFFFF for a dense block
//!        values       v × f64  the blocks' values (HMatrix layout)
//!        panel sum    u64      xxh3 of this panel's bytes from `index` to its last value
//!      checksum     u64      xxh3 of every byte before it
//! ```
//! No block table is stored or trusted: the loader rebuilds the plan from the points and the
//! options ([`HPlan::new`], deterministic) and checks every panel against it
//! ([`HMatrix::from_panels`]). Every count is bounded by the bytes left in the file before
//! anything is allocated. Files are written atomically as version 3's. A compressed
//! precompute is not resumable (no `.partial`): an interrupted one starts afresh.

use std::io::{BufReader, BufWriter, Read, Write};
use std::path::{Path, PathBuf};

use glam::DVec3;
use xxhash_rust::xxh3::{xxh3_64, Xxh3};

use super::atomic::AtomicFile;
use super::error::CacheError;
use super::format::{
    self, common_fields, f64_at, range_inconsistency, u32_at, u64_at, Common, Shard, BYTES_NAME,
    HIER_VERSION,
};
use crate::compliance::hmatrix::{HMatrix, HOptions, HPlan, Panel};
use crate::compliance::{Compliance, HierParts};

/// The compressed format's version.
pub const FORMAT_VERSION: u32 = HIER_VERSION;
/// Bytes of the header, its checksum included.
pub const HEADER: usize = 104;
const PANEL_HEAD: usize = 32;
/// The rank that marks a dense block.
const DENSE: u32 = u32::MAX;

/// The header of a compressed cache file or shard.
#[derive(Clone, Debug, PartialEq)]
pub struct Header {
    /// Mesh node count.
    pub n_nodes: u32,
    /// Displayed nodes R.
    pub rows: u32,
    /// Touchable nodes C.
    pub cols: u32,
    /// Rows that hold `L` (the first ones).
    pub l_rows: u32,
    /// Mesh + selection + options hash (`cache::key_hier`).
    pub key: u64,
    /// Shard index, 1-based.
    pub shard_index: u32,
    /// Shard count (1: a complete file).
    pub shard_count: u32,
    /// Panels of the plan.
    pub panels: u32,
    /// First panel held.
    pub panel_begin: u32,
    /// One past the last panel held.
    pub panel_end: u32,
    /// Free DOFs of K.
    pub free_dofs: u32,
    /// The options `L` was compressed with.
    pub opts: HOptions,
    /// max |K·x − e| over the checked columns held.
    pub residual: f64,
}

impl Header {
    fn to_bytes(&self) -> [u8; HEADER] {
        let mut h = [0u8; HEADER];
        self.common().put(&mut h, FORMAT_VERSION);
        let mut put = |o: usize, v: &[u8]| h[o..o + v.len()].copy_from_slice(v);
        put(28, &self.l_rows.to_le_bytes());
        put(48, &self.panels.to_le_bytes());
        put(52, &self.panel_begin.to_le_bytes());
        put(56, &self.panel_end.to_le_bytes());
        put(60, &self.free_dofs.to_le_bytes());
        put(64, &self.opts.tolerance.to_bits().to_le_bytes());
        put(72, &self.opts.eta.to_bits().to_le_bytes());
        // `check_opts` keeps both sizes within u32 before a header is written.
        put(80, &(self.opts.leaf_size as u32).to_le_bytes());
        put(84, &(self.opts.panel_size as u32).to_le_bytes());
        put(88, &self.residual.to_bits().to_le_bytes());
        let sum = xxh3_64(&h[..96]);
        h[96..].copy_from_slice(&sum.to_le_bytes());
        h
    }

    /// The fields shared with the dense format.
    fn common(&self) -> Common {
        common_fields!(of self)
    }

    /// Parses a header whose magic, version and precision are right (its checksum is not
    /// checked here).
    fn parse(b: &[u8; HEADER]) -> Result<Header, String> {
        let c = Common::read(b, FORMAT_VERSION, "compressed")?;
        Ok(common_fields!(c => Header {
            l_rows: u32_at(b, 28),
            panels: u32_at(b, 48),
            panel_begin: u32_at(b, 52),
            panel_end: u32_at(b, 56),
            free_dofs: u32_at(b, 60),
            opts: HOptions {
                tolerance: f64::from_bits(u64_at(b, 64)),
                eta: f64::from_bits(u64_at(b, 72)),
                leaf_size: u32_at(b, 80) as usize,
                panel_size: u32_at(b, 84) as usize,
            },
            residual: f64::from_bits(u64_at(b, 88)),
        }))
    }

    /// What is wrong with the header's sizes, if anything.
    fn inconsistency(&self) -> Option<String> {
        let common = self.common();
        common
            .rows_inconsistency(self.l_rows)
            .or_else(|| common.shard_inconsistency())
            .or_else(|| {
                range_inconsistency(self.panel_begin, self.panel_end, self.panels, "panels")
            })
            .or_else(|| check_opts(&self.opts).err())
    }

    /// Bytes of the lists, the points and their checksum.
    fn lists_len(&self) -> u64 {
        4 * (self.rows as u64 + self.cols as u64) + 24 * (self.l_rows as u64 + self.cols as u64) + 8
    }

    /// Panels held.
    pub fn held(&self) -> usize {
        (self.panel_end - self.panel_begin) as usize
    }
}

/// The options' ranges ([`HOptions::check`]) and sizes that fit the header's u32 fields.
fn check_opts(o: &HOptions) -> Result<(), String> {
    o.check().map_err(|e| e.to_string())?;
    if o.panel_size > u32::MAX as usize {
        return Err(format!("a panel size of {}", o.panel_size));
    }
    Ok(())
}

/// Whether `path` starts like a compressed (version 4) cache file: the magic and version 4.
/// `false` for anything else, also an unreadable file (its reader reports why).
pub fn is_compressed(path: &Path) -> bool {
    let mut b = [0u8; 12];
    std::fs::File::open(path)
        .and_then(|mut f| f.read_exact(&mut b))
        .is_ok()
        && format::is_version(&b, FORMAT_VERSION)
}

/// A compressed file or shard being written: streamed through an atomic file, hashing as it
/// goes.
struct Writer {
    path: PathBuf,
    out: BufWriter<AtomicFile>,
    hash: Xxh3,
    bytes: u64,
}

impl Writer {
    fn create(path: &Path) -> Result<Writer, CacheError> {
        if let Some(dir) = path.parent() {
            if !dir.as_os_str().is_empty() {
                std::fs::create_dir_all(dir).map_err(|source| CacheError::Io {
                    path: path.to_path_buf(),
                    source,
                })?;
            }
        }
        let f = AtomicFile::create(path).map_err(|source| CacheError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        Ok(Writer {
            path: path.to_path_buf(),
            out: BufWriter::with_capacity(1 << 20, f),
            hash: Xxh3::new(),
            bytes: 0,
        })
    }

    fn put(&mut self, b: &[u8]) -> Result<(), CacheError> {
        self.hash.update(b);
        self.bytes += b.len() as u64;
        self.out.write_all(b).map_err(|source| CacheError::Io {
            path: self.path.clone(),
            source,
        })
    }

    /// Writes the checksum, syncs and renames; the file's length.
    fn finish(mut self) -> Result<u64, CacheError> {
        let io = |path: &Path| {
            let path = path.to_path_buf();
            move |source| CacheError::Io { path, source }
        };
        let sum = self.hash.digest().to_le_bytes();
        self.put(&sum)?;
        let f = self.out.into_inner().map_err(|e| CacheError::Io {
            path: self.path.clone(),
            source: e.into_error(),
        })?;
        f.commit().map_err(io(&self.path))?;
        Ok(self.bytes)
    }
}

/// The lists and points section (with its checksum) of a file.
fn lists_bytes(rows: &[u32], cols: &[u32], row_points: &[DVec3], col_points: &[DVec3]) -> Vec<u8> {
    let mut b = Vec::with_capacity(
        4 * (rows.len() + cols.len()) + 24 * (row_points.len() + cols.len()) + 8,
    );
    for &v in rows.iter().chain(cols) {
        b.extend_from_slice(&v.to_le_bytes());
    }
    for p in row_points.iter().chain(col_points) {
        for c in p.to_array() {
            b.extend_from_slice(&c.to_bits().to_le_bytes());
        }
    }
    let sum = xxh3_64(&b);
    b.extend_from_slice(&sum.to_le_bytes());
    b
}

/// One panel's bytes, its checksum included.
fn panel_bytes(p: &Panel) -> Vec<u8> {
    let mut b = Vec::with_capacity(PANEL_HEAD + 4 * p.ranks.len() + 8 * p.data.len() + 8);
    b.extend_from_slice(&(p.index as u32).to_le_bytes());
    b.extend_from_slice(&(p.ranks.len() as u32).to_le_bytes());
    b.extend_from_slice(&(p.data.len() as u64).to_le_bytes());
    b.extend_from_slice(&p.norm_sq.to_bits().to_le_bytes());
    b.extend_from_slice(&p.discarded_sq.to_bits().to_le_bytes());
    for r in &p.ranks {
        b.extend_from_slice(&r.unwrap_or(DENSE).to_le_bytes());
    }
    b.extend_from_slice(bytemuck::cast_slice(&p.data));
    let sum = xxh3_64(&b);
    b.extend_from_slice(&sum.to_le_bytes());
    b
}

/// Everything a file holds besides its panels.
struct Layout<'a> {
    head: Header,
    rows: &'a [u32],
    cols: &'a [u32],
    row_points: &'a [DVec3],
    col_points: &'a [DVec3],
}

/// Writes a file of `layout` with `panels` (those of `head`'s range, in order); its length.
fn write(
    path: &Path,
    layout: &Layout<'_>,
    panels: &mut dyn Iterator<Item = Panel>,
) -> Result<u64, CacheError> {
    let h = &layout.head;
    let format = |msg: String| CacheError::Format {
        path: path.to_path_buf(),
        msg,
    };
    if let Some(why) = h.inconsistency() {
        return Err(format(format!("cannot write a compressed cache: {why}")));
    }
    if layout.rows.len() != h.rows as usize
        || layout.cols.len() != h.cols as usize
        || layout.row_points.len() != h.l_rows as usize
        || layout.col_points.len() != h.cols as usize
    {
        return Err(format(format!(
            "{} rows ({} points) and {} columns ({} points) for a header of {} ({} held) and {}",
            layout.rows.len(),
            layout.row_points.len(),
            layout.cols.len(),
            layout.col_points.len(),
            h.rows,
            h.l_rows,
            h.cols
        )));
    }
    let mut w = Writer::create(path)?;
    w.put(&h.to_bytes())?;
    w.put(&lists_bytes(
        layout.rows,
        layout.cols,
        layout.row_points,
        layout.col_points,
    ))?;
    let mut next = h.panel_begin as usize;
    for p in panels {
        if p.index != next || next >= h.panel_end as usize {
            return Err(format(format!(
                "panel {} where panel {next} of {}..{} was due",
                p.index, h.panel_begin, h.panel_end
            )));
        }
        if p.ranks.len() > u32::MAX as usize {
            return Err(format(format!("panel {} has too many blocks", p.index)));
        }
        w.put(&panel_bytes(&p))?;
        next += 1;
    }
    if next != h.panel_end as usize {
        return Err(format(format!(
            "panels {}..{next} written of {}..{}",
            h.panel_begin, h.panel_begin, h.panel_end
        )));
    }
    w.finish()
}

/// The header of a compliance's hierarchical `L` (complete: 1 of 1, every panel).
fn header_of(c: &Compliance, h: &HMatrix, key: u64, n_nodes: usize) -> Header {
    Header {
        n_nodes: n_nodes as u32,
        rows: c.rows().len() as u32,
        cols: c.cols().len() as u32,
        l_rows: c.l_rows() as u32,
        key,
        shard_index: 1,
        shard_count: 1,
        panels: h.panels() as u32,
        panel_begin: 0,
        panel_end: h.panels() as u32,
        free_dofs: c.stats.free_dofs as u32,
        opts: *h.options(),
        residual: c.stats.residual,
    }
}

/// Writes a hierarchical compliance to `path` as a complete version-4 file (atomically).
/// A compliance without a hierarchical `L` is a [`CacheError::Format`] error.
pub fn save(path: &Path, c: &Compliance, key: u64, n_nodes: usize) -> Result<u64, CacheError> {
    let Some(h) = c.hier() else {
        return Err(CacheError::Format {
            path: path.to_path_buf(),
            msg: "not a hierarchical compliance".into(),
        });
    };
    let layout = Layout {
        head: header_of(c, h, key, n_nodes),
        rows: c.rows(),
        cols: c.cols(),
        row_points: h.row_points(),
        col_points: h.col_points(),
    };
    write(
        path,
        &layout,
        &mut (0..h.panels()).filter_map(|p| h.panel(p)),
    )
}

/// Writes the panels of `parts` (shard `shard = (I, N)` of its plan, as
/// [`Compliance::compute_hier_parts`] made them) to `path`; the file's length.
pub fn write_parts(
    path: &Path,
    parts: &HierParts,
    key: u64,
    n_nodes: usize,
    shard: (usize, usize),
) -> Result<u64, CacheError> {
    let plan = &parts.plan;
    let range = crate::compliance::shard_panels(plan.panels(), shard.0, shard.1);
    let layout = Layout {
        head: Header {
            n_nodes: n_nodes as u32,
            rows: parts.rows.len() as u32,
            cols: parts.cols.len() as u32,
            l_rows: parts.l_rows as u32,
            key,
            shard_index: shard.0 as u32,
            shard_count: shard.1 as u32,
            panels: plan.panels() as u32,
            panel_begin: range.start as u32,
            panel_end: range.end as u32,
            free_dofs: parts.stats.free_dofs as u32,
            opts: *plan.options(),
            residual: parts.stats.residual,
        },
        rows: &parts.rows,
        cols: &parts.cols,
        row_points: plan.row_points(),
        col_points: plan.col_points(),
    };
    write(path, &layout, &mut parts.panels.iter().cloned())
}

/// An opened compressed file or shard: header and lists checked; panels read in order, each
/// checked against its checksum, then the file's checksum ([`Reader::finish`]).
struct Reader<R: Read> {
    path: PathBuf,
    file: R,
    len: u64,
    /// Bytes read so far.
    pos: u64,
    hash: Xxh3,
    head: Header,
    /// The lists and points section as stored (with its checksum).
    lists: Vec<u8>,
    next: u32,
}

impl Reader<BufReader<std::fs::File>> {
    fn open(path: &Path) -> Result<Self, CacheError> {
        let io = |source| CacheError::Io {
            path: path.to_path_buf(),
            source,
        };
        let file = std::fs::File::open(path).map_err(io)?;
        let len = file.metadata().map_err(io)?.len();
        Reader::start(path, BufReader::with_capacity(1 << 20, file), len)
    }
}

impl<'a> Reader<&'a [u8]> {
    /// A reader of a whole file's bytes in memory.
    fn bytes(b: &'a [u8]) -> Result<Self, CacheError> {
        Reader::start(Path::new(BYTES_NAME), b, b.len() as u64)
    }
}

impl<R: Read> Reader<R> {
    /// Reads and checks the header and the lists of `len` bytes from `file`.
    fn start(path: &Path, file: R, len: u64) -> Result<Self, CacheError> {
        let mut r = Reader {
            path: path.to_path_buf(),
            file,
            len,
            pos: 0,
            hash: Xxh3::new(),
            head: Header {
                n_nodes: 0,
                rows: 0,
                cols: 0,
                l_rows: 0,
                key: 0,
                shard_index: 0,
                shard_count: 0,
                panels: 0,
                panel_begin: 0,
                panel_end: 0,
                free_dofs: 0,
                opts: HOptions::new(0.5),
                residual: 0.0,
            },
            lists: Vec::new(),
            next: 0,
        };
        // The magic first (a file that is not a cache is named so, however short), then the
        // rest of the header.
        let first = r.take(len.min(8) as usize)?;
        if first.len() == 8 && first != format::MAGIC {
            return Err(r.format("not a touchfem compliance cache".into()));
        }
        let mut hb = [0u8; HEADER];
        hb[..first.len()].copy_from_slice(&first);
        let rest = r.take(HEADER - first.len())?;
        hb[first.len()..].copy_from_slice(&rest);
        let head = Header::parse(&hb).map_err(|msg| r.format(msg))?;
        if xxh3_64(&hb[..96]) != u64_at(&hb, 96) {
            return Err(r.corrupt("header checksum mismatch".into()));
        }
        if let Some(why) = head.inconsistency() {
            return Err(r.corrupt(format!("header: {why}")));
        }
        r.head = head;
        // Bounded by the file before it is allocated (a u64 of u32 products: no overflow).
        let n = r.head.lists_len();
        r.need(n)?;
        let lists = r.take(n as usize)?;
        let body = lists.len() - 8;
        if xxh3_64(&lists[..body]) != u64_at(&lists, body) {
            return Err(r.corrupt("checksum mismatch in the node lists".into()));
        }
        // Every held panel takes at least its head and checksum.
        r.need(r.head.held() as u64 * (PANEL_HEAD as u64 + 8))?;
        r.lists = lists;
        r.next = r.head.panel_begin;
        Ok(r)
    }

    fn format(&self, msg: String) -> CacheError {
        CacheError::Format {
            path: self.path.clone(),
            msg,
        }
    }

    fn corrupt(&self, why: String) -> CacheError {
        CacheError::Corrupt {
            path: self.path.clone(),
            why,
        }
    }

    /// An error unless `n` more bytes and the final checksum lie in the file.
    fn need(&self, n: u64) -> Result<(), CacheError> {
        let end = self.pos.saturating_add(n).saturating_add(8);
        if end > self.len {
            return Err(CacheError::Truncated {
                path: self.path.clone(),
                len: usize::try_from(self.len).unwrap_or(usize::MAX),
                expected: usize::try_from(end).unwrap_or(usize::MAX),
            });
        }
        Ok(())
    }

    /// The next `n` bytes (hashed), or [`CacheError::Truncated`] if the file ends first.
    fn take(&mut self, n: usize) -> Result<Vec<u8>, CacheError> {
        let b = self.take_unhashed(n)?;
        self.hash.update(&b);
        Ok(b)
    }

    fn take_unhashed(&mut self, n: usize) -> Result<Vec<u8>, CacheError> {
        let end = self.pos.saturating_add(n as u64);
        if end > self.len {
            return Err(CacheError::Truncated {
                path: self.path.clone(),
                len: usize::try_from(self.len).unwrap_or(usize::MAX),
                expected: usize::try_from(end).unwrap_or(usize::MAX),
            });
        }
        let mut b = vec![0u8; n];
        self.file
            .read_exact(&mut b)
            .map_err(|source| CacheError::Io {
                path: self.path.clone(),
                source,
            })?;
        self.pos = end;
        Ok(b)
    }

    /// The next held panel's bytes (checksum included, verified); `None` after the last.
    fn next_raw(&mut self) -> Result<Option<Vec<u8>>, CacheError> {
        if self.next >= self.head.panel_end {
            return Ok(None);
        }
        self.need(PANEL_HEAD as u64)?;
        let mut b = self.take(PANEL_HEAD)?;
        let index = u32_at(&b, 0);
        let blocks = u32_at(&b, 4) as u64;
        let values = u64_at(&b, 8);
        let rest = values
            .checked_mul(8)
            .and_then(|v| v.checked_add(4 * blocks))
            .and_then(|v| v.checked_add(8));
        let Some(rest) = rest else {
            return Err(self.corrupt(format!("panel {index}: {values} values")));
        };
        self.need(rest)?;
        b.extend(self.take(rest as usize)?);
        let body = b.len() - 8;
        if xxh3_64(&b[..body]) != u64_at(&b, body) {
            return Err(self.corrupt(format!("checksum mismatch in panel {}", self.next)));
        }
        if index != self.next {
            return Err(self.corrupt(format!("panel {index} where panel {} was due", self.next)));
        }
        self.next += 1;
        Ok(Some(b))
    }

    /// Reads the file's checksum and checks it, and that nothing follows.
    fn finish(mut self) -> Result<(), CacheError> {
        if self.next != self.head.panel_end {
            return Err(self.format(format!(
                "finished at panel {} of {}..{}",
                self.next, self.head.panel_begin, self.head.panel_end
            )));
        }
        let digest = self.hash.digest();
        let sum = self.take_unhashed(8)?;
        if u64_at(&sum, 0) != digest {
            return Err(self.corrupt("checksum mismatch".into()));
        }
        if self.pos != self.len {
            return Err(self.corrupt(format!("{} bytes after the checksum", self.len - self.pos)));
        }
        Ok(())
    }

    /// The row and column node lists and the points.
    fn lists(&self) -> (Vec<u32>, Vec<u32>, Vec<DVec3>, Vec<DVec3>) {
        let (nr, nc, nl) = (
            self.head.rows as usize,
            self.head.cols as usize,
            self.head.l_rows as usize,
        );
        let b = &self.lists;
        let rows = (0..nr).map(|i| u32_at(b, 4 * i)).collect();
        let cols = (0..nc).map(|i| u32_at(b, 4 * (nr + i))).collect();
        let p0 = 4 * (nr + nc);
        let point = |i: usize| {
            let o = p0 + 24 * i;
            DVec3::new(f64_at(b, o), f64_at(b, o + 8), f64_at(b, o + 16))
        };
        let rp = (0..nl).map(point).collect();
        let cp = (nl..nl + nc).map(point).collect();
        (rows, cols, rp, cp)
    }
}

/// A panel from its checked bytes ([`Reader::next_raw`]).
fn parse_panel(b: &[u8]) -> Panel {
    let blocks = u32_at(b, 4) as usize;
    let values = u64_at(b, 8) as usize;
    let r0 = PANEL_HEAD;
    let v0 = r0 + 4 * blocks;
    Panel {
        index: u32_at(b, 0) as usize,
        ranks: (0..blocks)
            .map(|i| match u32_at(b, r0 + 4 * i) {
                DENSE => None,
                k => Some(k),
            })
            .collect(),
        data: (0..values).map(|i| f64_at(b, v0 + 8 * i)).collect(),
        norm_sq: f64_at(b, 16),
        discarded_sq: f64_at(b, 24),
    }
}

/// Reads the header of a compressed file or shard (its checksum checked).
pub fn header(path: &Path) -> Result<Header, CacheError> {
    Ok(Reader::open(path)?.head)
}

/// Reads a complete hierarchical compliance from `path`: checks magic, version, checksums,
/// key and node count ([`CacheError::Stale`]), that it is not a shard
/// ([`CacheError::Partial`]), rebuilds the plan from the stored points and options and checks
/// every panel against it. With `opts`, a file made with other options is
/// [`CacheError::Compression`] (its header's options are checked against the ones asked for,
/// not only its key).
pub fn load(
    path: &Path,
    expected_key: u64,
    n_nodes: usize,
    opts: Option<&HOptions>,
) -> Result<Compliance, CacheError> {
    load_from(Reader::open(path)?, expected_key, n_nodes, opts)
}

/// As [`load`], from a whole file's bytes in memory.
pub fn load_bytes(
    bytes: &[u8],
    expected_key: u64,
    n_nodes: usize,
    opts: Option<&HOptions>,
) -> Result<Compliance, CacheError> {
    load_from(Reader::bytes(bytes)?, expected_key, n_nodes, opts)
}

fn load_from<R: Read>(
    mut r: Reader<R>,
    expected_key: u64,
    n_nodes: usize,
    opts: Option<&HOptions>,
) -> Result<Compliance, CacheError> {
    let h = r.head.clone();
    let path = r.path.clone();
    let path = path.as_path();
    if let Some(o) = opts.filter(|&o| *o != h.opts) {
        return Err(CacheError::Compression {
            path: path.to_path_buf(),
            found: Some(h.opts),
            asked: Some(*o),
        });
    }
    h.common().fresh(path, expected_key, n_nodes)?;
    if let Some(e) = h
        .common()
        .partial(path, h.panel_begin, h.panel_end, h.panels)
    {
        return Err(e);
    }
    let (rows, cols, rp, cp) = r.lists();
    let inconsistent = |e: String| CacheError::Format {
        path: path.to_path_buf(),
        msg: format!("inconsistent contents: {e}"),
    };
    let plan =
        HPlan::new(&rp, &cp, rows.len(), &h.opts).map_err(|e| inconsistent(e.to_string()))?;
    if plan.panels() != h.panels as usize {
        return Err(inconsistent(format!(
            "{} panels, the plan has {}",
            h.panels,
            plan.panels()
        )));
    }
    let mut panels = Vec::with_capacity(h.held());
    while let Some(b) = r.next_raw()? {
        panels.push(parse_panel(&b));
    }
    r.finish()?;
    let hm = HMatrix::from_panels(plan, panels).map_err(|e| inconsistent(e.to_string()))?;
    let mut c = Compliance::from_hier(rows, h.l_rows as usize, cols, hm, n_nodes)
        .map_err(|e| inconsistent(e.to_string()))?;
    c.stats.residual = h.residual;
    c.stats.free_dofs = h.free_dofs as usize;
    Ok(c)
}

impl<R: Read> Shard for Reader<R> {
    fn path(&self) -> &Path {
        &self.path
    }
    fn common(&self) -> Common {
        self.head.common()
    }
    fn run(&self) -> (u32, u32, u32) {
        (self.head.panel_begin, self.head.panel_end, self.head.panels)
    }
    fn residual(&self) -> f64 {
        self.head.residual
    }
    fn same_lists(&self, first: &Self) -> bool {
        self.lists == first.lists
    }
    fn other_make(&self, first: &Self) -> Option<String> {
        let (h, h0) = (&self.head, &first.head);
        (h.opts != h0.opts
            || h.panels != h0.panels
            || h.free_dofs != h0.free_dofs
            || h.l_rows != h0.l_rows)
            .then(|| "made with other compression options or stiffness".into())
    }
}

/// Joins compressed shards (any order) into one complete file at `out`, equal byte for byte to
/// the unsharded precompute (the shared merge checks say whether they belong together);
/// checks every panel's checksum and each part's file checksum while copying. Returns the
/// merged file's header and length.
pub fn merge(parts: &[PathBuf], out: &Path) -> Result<(Header, u64), CacheError> {
    let mut opened = parts
        .iter()
        .map(|p| Reader::open(p))
        .collect::<Result<Vec<_>, _>>()?;
    let residual = format::check_merge(
        &mut opened,
        parts,
        out,
        "panels",
        "mesh, material, selection or tolerance",
    )?;
    let (h0, lists0) = (opened[0].head.clone(), opened[0].lists.clone());
    let head = Header {
        shard_index: 1,
        shard_count: 1,
        panel_begin: 0,
        panel_end: h0.panels,
        residual,
        ..h0
    };
    let mut w = Writer::create(out)?;
    w.put(&head.to_bytes())?;
    w.put(&lists0)?;
    for mut p in opened {
        while let Some(b) = p.next_raw()? {
            w.put(&b)?;
        }
        p.finish()?;
    }
    let bytes = w.finish()?;
    Ok((head, bytes))
}
