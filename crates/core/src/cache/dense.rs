//! The dense cache format, version 3: `L` as it is, column batch by column batch, so that a
//! file can be written from many threads at once, resumed after an interruption, and read back
//! in ranges without holding it ([`load_near`]).
//!
//! Its layout is in the [cache module's](super) documentation.
//! The fields up to the shard are [`format`](super::format)'s, shared with the compressed
//! format. Files are written to a unique temporary name, synced, renamed, and the directory
//! synced.

use std::path::{Path, PathBuf};
use xxhash_rust::xxh3::{xxh3_64, Xxh3};

use super::atomic::{sync_dir, unique_tmp};
use super::error::CacheError;
use super::format::{
    self, common_fields, range_inconsistency, u32_at, u64_at, Common, Shard, Source, BYTES_NAME,
    DENSE_VERSION,
};
use crate::compliance::near::NearBlocks;
use crate::compliance::{Compliance, BATCH_COLS};

const HEADER: usize = 72;

/// The header of a cache file or shard: what it was made for and which columns it holds.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Header {
    /// Mesh node count.
    pub n_nodes: u32,
    /// Displayed nodes R.
    pub rows: u32,
    /// Touchable nodes C (all of them, also in a shard).
    pub cols: u32,
    /// Columns per batch.
    pub batch: u32,
    /// Mesh + material + selection hash ([`key`](super::key)).
    pub key: u64,
    /// Shard index, 1-based.
    pub shard_index: u32,
    /// Shard count (1: a complete file).
    pub shard_count: u32,
    /// First column held.
    pub col_begin: u32,
    /// One past the last column held.
    pub col_end: u32,
    /// Free DOFs of K.
    pub free_dofs: u32,
    /// Rows that hold `L` (the first ones; the clamped rows after them are not stored).
    pub l_rows: u32,
    /// max |K·x − e| over the checked columns held.
    pub residual_bits: u64,
}

impl Header {
    fn to_bytes(&self) -> [u8; HEADER] {
        let mut h = [0u8; HEADER];
        self.common().put(&mut h, DENSE_VERSION);
        let mut put = |o: usize, v: u32| h[o..o + 4].copy_from_slice(&v.to_le_bytes());
        put(28, self.batch);
        put(48, self.col_begin);
        put(52, self.col_end);
        put(56, self.free_dofs);
        put(60, self.l_rows);
        h[64..72].copy_from_slice(&self.residual_bits.to_le_bytes());
        h
    }

    /// The fields shared with the compressed format.
    fn common(&self) -> Common {
        common_fields!(of self)
    }

    /// Parses a header whose magic, version and precision are right (no size is checked).
    fn parse(b: &[u8; HEADER]) -> Result<Header, String> {
        let c = Common::read(b, DENSE_VERSION, "dense")?;
        Ok(common_fields!(c => Header {
            batch: u32_at(b, 28),
            col_begin: u32_at(b, 48),
            col_end: u32_at(b, 52),
            free_dofs: u32_at(b, 56),
            l_rows: u32_at(b, 60),
            residual_bits: u64_at(b, 64),
        }))
    }

    fn held_batches(&self) -> usize {
        self.col_end
            .saturating_sub(self.col_begin)
            .div_ceil(self.batch.max(1)) as usize
    }

    /// Bytes of the L values held (only for a header that passed [`Header::checked_file_len`]).
    fn l_bytes(&self) -> u64 {
        72 * self.l_rows as u64 * self.col_end.saturating_sub(self.col_begin) as u64
    }

    /// Byte offset of held batch `i`.
    fn batch_offset(&self, i: usize) -> u64 {
        HEADER as u64
            + self.lists_len() as u64
            + 72 * self.l_rows as u64 * (i as u64 * self.batch as u64)
    }

    /// Total file length the header implies (only for a header that passed
    /// [`Header::checked_file_len`]).
    fn file_len(&self) -> u64 {
        HEADER as u64
            + 4 * (self.rows as u64 + self.cols as u64)
            + self.l_bytes()
            + 8 * self.held_batches() as u64
            + 8
    }

    /// What is wrong with the header's sizes, if anything: the column range must lie in
    /// `0..=cols` on the batch grid, `l_rows ≤ rows`, the shard index in `1..=count`.
    fn inconsistency(&self) -> Option<String> {
        let grid = |c: u32| self.batch != 0 && (c.is_multiple_of(self.batch) || c == self.cols);
        let common = self.common();
        if self.batch == 0 {
            Some("a batch of 0 columns".into())
        } else if let Some(why) = common.rows_inconsistency(self.l_rows) {
            Some(why)
        } else if let Some(why) =
            range_inconsistency(self.col_begin, self.col_end, self.cols, "columns")
        {
            Some(why)
        } else if !grid(self.col_begin) || !grid(self.col_end) {
            Some(format!(
                "columns {}..{} are not on the grid of {}-column batches",
                self.col_begin, self.col_end, self.batch
            ))
        } else {
            common.shard_inconsistency()
        }
    }

    /// The total file length the header implies, computed without overflow; `None` if the
    /// header is inconsistent ([`Header::inconsistency`]) or the length does not fit a `u64`.
    fn checked_file_len(&self) -> Option<u64> {
        if self.inconsistency().is_some() {
            return None;
        }
        let held = (self.col_end - self.col_begin) as u64;
        let l = 72u64.checked_mul(self.l_rows as u64)?.checked_mul(held)?;
        (HEADER as u64)
            .checked_add(4 * (self.rows as u64 + self.cols as u64))?
            .checked_add(l)?
            .checked_add(8 * self.held_batches() as u64)?
            .checked_add(8)
    }

    fn lists_len(&self) -> usize {
        4 * (self.rows as usize + self.cols as usize)
    }
}

/// A cache file or shard being written: a unique temporary file of the final size, filled
/// batch by batch (from any thread, in any order), then checksummed, synced and renamed.
/// Dropped without [`Writer::finish`], the temporary is removed.
pub(crate) struct Writer {
    path: PathBuf,
    tmp: PathBuf,
    file: std::fs::File,
    head: Header,
    lists: Vec<u8>,
    sums: std::sync::Mutex<Vec<Option<u64>>>,
    done: bool,
}

/// Asks the kernel to start writing `len` bytes at `off` to disk now, without waiting, so
/// that the final sync of a multi-gigabyte file finds little left to write. Advisory: the
/// final `sync_all` is what guarantees the data.
fn start_writeback(file: &std::fs::File, off: u64, len: usize) {
    #[cfg(all(feature = "native", target_os = "linux"))]
    {
        use std::os::fd::AsRawFd;
        // SAFETY: a valid open descriptor; the call only schedules writeback of its pages.
        unsafe {
            libc::sync_file_range(
                file.as_raw_fd(),
                off as libc::off64_t,
                len as libc::off64_t,
                libc::SYNC_FILE_RANGE_WRITE,
            );
        }
    }
    #[cfg(not(all(feature = "native", target_os = "linux")))]
    let _ = (file, off, len);
}

impl Writer {
    /// Starts writing `head` with the row and column node lists to `path`.
    pub fn create(
        path: &Path,
        head: Header,
        rows: &[u32],
        cols: &[u32],
    ) -> Result<Writer, CacheError> {
        let io = |source| CacheError::Io {
            path: path.to_path_buf(),
            source,
        };
        let Some(len) = head.checked_file_len() else {
            return Err(CacheError::Format {
                path: path.to_path_buf(),
                msg: format!(
                    "cannot write a file of {} rows ({} of L) and {} columns: {}",
                    head.rows,
                    head.l_rows,
                    head.cols,
                    head.inconsistency()
                        .unwrap_or_else(|| "its length does not fit 64 bits".into())
                ),
            });
        };
        if rows.len() != head.rows as usize || cols.len() != head.cols as usize {
            return Err(CacheError::Format {
                path: path.to_path_buf(),
                msg: format!(
                    "{} row and {} column nodes for a header of {} and {}",
                    rows.len(),
                    cols.len(),
                    head.rows,
                    head.cols
                ),
            });
        }
        if let Some(dir) = path.parent() {
            if !dir.as_os_str().is_empty() {
                std::fs::create_dir_all(dir).map_err(io)?;
            }
        }
        let lists = lists_of(rows, cols);
        let tmp = unique_tmp(path);
        let file = std::fs::File::create_new(&tmp).map_err(io)?;
        let w = Writer {
            path: path.to_path_buf(),
            tmp,
            file,
            sums: std::sync::Mutex::new(vec![None; head.held_batches()]),
            head,
            lists,
            done: false,
        };
        use super::format::FileAt;
        (|| {
            w.file.set_len(len)?;
            w.file.write_all_at(&w.head.to_bytes(), 0)?;
            w.file.write_all_at(&w.lists, HEADER as u64)
        })()
        .map_err(io)?;
        Ok(w)
    }

    /// Writes the held batch `i` (0-based within the file's range): `values` are its
    /// `9·R'·columns` f64 ([`Header::l_rows`]). Callable from several threads.
    pub(crate) fn write_batch(&self, i: usize, values: &[f64]) -> Result<(), CacheError> {
        use super::format::FileAt;
        let h = &self.head;
        let held = h.held_batches();
        let want = if i < held {
            let first = h.col_begin as usize + i * h.batch as usize;
            9 * h.l_rows as usize * (h.col_end as usize - first).min(h.batch as usize)
        } else {
            0
        };
        if i >= held || values.len() != want {
            return Err(CacheError::Format {
                path: self.path.clone(),
                msg: format!(
                    "batch {i} of {held} with {} values, expected {want}",
                    values.len()
                ),
            });
        }
        let bytes: &[u8] = bytemuck::cast_slice(values);
        let off = self.head.batch_offset(i);
        self.file
            .write_all_at(bytes, off)
            .map_err(|source| CacheError::Io {
                path: self.path.clone(),
                source,
            })?;
        start_writeback(&self.file, off, bytes.len());
        let sum = xxh3_64(bytes);
        self.sums.lock().unwrap_or_else(|e| e.into_inner())[i] = Some(sum);
        Ok(())
    }

    /// Reads rows `r0 .. r0 + out.len()` of DOF column `q` (counted from the file's first
    /// column) as written so far.
    pub(crate) fn read_column(
        &self,
        q: usize,
        r0: usize,
        out: &mut [f64],
    ) -> Result<(), CacheError> {
        use super::format::FileAt;
        let off =
            self.head.batch_offset(0) + 8 * (q as u64 * 3 * self.head.l_rows as u64 + r0 as u64);
        self.file
            .read_exact_at(bytemuck::cast_slice_mut(out), off)
            .map_err(|source| CacheError::Io {
                path: self.path.clone(),
                source,
            })
    }

    /// Continues an interrupted write of the same `head` from `partial` (left by
    /// [`Writer::keep_partial`]): its complete batches (checksums verified) are kept. Returns the
    /// writer, the held batches already done and the residual over them. `None` if `partial`
    /// does not exist; an error if it was made for another mesh, selection or shard.
    pub fn resume(
        path: &Path,
        partial: &Path,
        head: &Header,
    ) -> Result<Option<(Writer, Vec<bool>, f64)>, CacheError> {
        if !partial.exists() {
            return Ok(None);
        }
        let part = Part::open(partial)?;
        let same = Header {
            residual_bits: head.residual_bits,
            ..part.head.clone()
        };
        if &same != head {
            return Err(CacheError::Mismatch {
                path: partial.to_path_buf(),
                msg: "an interrupted precompute of another mesh, material, selection or shard:                       delete it to start afresh"
                    .into(),
            });
        }
        let mut done = vec![false; part.batches()];
        let mut sums = vec![None; part.batches()];
        let mut buf = Vec::new();
        for (i, d) in done.iter_mut().enumerate() {
            if part.sums[i] != 0 && part.read_batch(i, &mut buf).is_ok() {
                *d = true;
                sums[i] = Some(part.sums[i]);
            }
        }
        let residual = f64::from_bits(part.head.residual_bits);
        let mut lists = Vec::with_capacity(4 * (part.rows.len() + part.cols.len()));
        for &v in part.rows.iter().chain(&part.cols) {
            lists.extend_from_slice(&v.to_le_bytes());
        }
        drop(part);
        let io = |source| CacheError::Io {
            path: path.to_path_buf(),
            source,
        };
        let tmp = unique_tmp(path);
        std::fs::rename(partial, &tmp).map_err(io)?;
        let file = std::fs::OpenOptions::new()
            .read(true)
            .write(true)
            .open(&tmp)
            .map_err(io)?;
        Ok(Some((
            Writer {
                path: path.to_path_buf(),
                tmp,
                file,
                head: head.clone(),
                lists,
                sums: std::sync::Mutex::new(sums),
                done: false,
            },
            done,
            residual,
        )))
    }

    /// Stops an interrupted write: the batches written so far stay in `partial` (a valid file
    /// whose missing batches have checksum 0), from which [`Writer::resume`] continues.
    pub(crate) fn keep_partial(mut self, partial: &Path) -> Result<(), CacheError> {
        let sums: Vec<u64> = self
            .sums
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .iter()
            .map(|s| s.unwrap_or(0))
            .collect();
        let tmp = self.tmp.clone();
        self.write_tail(&sums)?;
        std::fs::rename(&tmp, partial).map_err(|source| CacheError::Io {
            path: partial.to_path_buf(),
            source,
        })?;
        self.done = true;
        sync_dir(partial).map_err(|source| CacheError::Io {
            path: partial.to_path_buf(),
            source,
        })
    }

    /// Writes header, batch sums and checksum, and syncs the file.
    fn write_tail(&self, sums: &[u64]) -> Result<(), CacheError> {
        use super::format::FileAt;
        let io = |source| CacheError::Io {
            path: self.path.clone(),
            source,
        };
        let (head, tail, l_end) = tail_of(&self.head, &self.lists, sums);
        self.file.write_all_at(&head, 0).map_err(io)?;
        self.file.write_all_at(&tail, l_end).map_err(io)?;
        self.file.sync_all().map_err(io)
    }

    /// Sets the residual stored in the header.
    pub(crate) fn set_residual(&mut self, residual: f64) {
        self.head.residual_bits = residual.to_bits();
    }

    /// Writes the checksums, syncs, renames to the final name and syncs the directory. Fails
    /// if a batch was not written.
    pub fn finish(mut self) -> Result<u64, CacheError> {
        let io = |source| CacheError::Io {
            path: self.path.clone(),
            source,
        };
        let sums = std::mem::take(&mut *self.sums.lock().unwrap_or_else(|e| e.into_inner()));
        let mut table = Vec::with_capacity(sums.len());
        for (i, s) in sums.iter().enumerate() {
            table.push(s.ok_or_else(|| CacheError::Format {
                path: self.path.clone(),
                msg: format!("batch {i} was never written"),
            })?);
        }
        self.write_tail(&table)?;
        std::fs::rename(&self.tmp, &self.path).map_err(io)?;
        self.done = true;
        sync_dir(&self.path).map_err(io)?;
        Ok(self.head.file_len())
    }
}

impl Drop for Writer {
    fn drop(&mut self) {
        if !self.done {
            let _ = std::fs::remove_file(&self.tmp);
        }
    }
}

/// Writes a complete dense compliance to `path` as version 3 (atomically: a unique temporary
/// file, synced, then a rename and a sync of the directory).
pub fn save(path: &Path, c: &Compliance, key: u64, n_nodes: usize) -> Result<(), CacheError> {
    let nr = c.l_rows();
    let head = header_for(c, key, n_nodes);
    let w = Writer::create(path, head, c.rows(), c.cols())?;
    let l = c.l_f64();
    for (i, chunk) in l.chunks(9 * nr * BATCH_COLS).enumerate() {
        w.write_batch(i, chunk)?;
    }
    w.finish().map(|_| ())
}

/// The row and column node lists as the file stores them.
fn lists_of(rows: &[u32], cols: &[u32]) -> Vec<u8> {
    let mut lists = Vec::with_capacity(4 * (rows.len() + cols.len()));
    for &v in rows.iter().chain(cols) {
        lists.extend_from_slice(&v.to_le_bytes());
    }
    lists
}

/// The header's bytes, the tail (the batch checksums and the checksum of header, lists and
/// table) and the tail's offset: what a file or a buffer ends with.
fn tail_of(head: &Header, lists: &[u8], sums: &[u64]) -> ([u8; HEADER], Vec<u8>, u64) {
    let mut tail = Vec::with_capacity(8 * sums.len() + 8);
    for s in sums {
        tail.extend_from_slice(&s.to_le_bytes());
    }
    let bytes = head.to_bytes();
    let mut h = Xxh3::new();
    h.update(&bytes);
    h.update(lists);
    h.update(&tail);
    tail.extend_from_slice(&h.digest().to_le_bytes());
    let l_end = HEADER as u64 + lists.len() as u64 + head.l_bytes();
    (bytes, tail, l_end)
}

/// The dense header [`save`] writes for `c`.
fn header_for(c: &Compliance, key: u64, n_nodes: usize) -> Header {
    let nc = c.cols().len();
    Header {
        n_nodes: n_nodes as u32,
        rows: c.rows().len() as u32,
        l_rows: c.l_rows() as u32,
        cols: nc as u32,
        batch: BATCH_COLS as u32,
        key,
        shard_index: 1,
        shard_count: 1,
        col_begin: 0,
        col_end: nc as u32,
        free_dofs: c.stats.free_dofs as u32,
        residual_bits: c.stats.residual.to_bits(),
    }
}

/// The bytes [`save`] would write for a dense compliance, in memory (for a place without
/// files: the web page's worker hands them to the page, which reads them with
/// [`super::load_bytes`]). Equal, byte for byte, to the file.
pub fn to_bytes(c: &Compliance, key: u64, n_nodes: usize) -> Result<Vec<u8>, CacheError> {
    let head = header_for(c, key, n_nodes);
    let bad = |msg: String| CacheError::Format {
        path: PathBuf::from("(bytes)"),
        msg,
    };
    let len = head
        .checked_file_len()
        .and_then(|l| usize::try_from(l).ok())
        .ok_or_else(|| bad("the compliance does not fit a cache in memory".into()))?;
    if !c.holds_l() || c.hier().is_some() {
        return Err(bad(
            "only a dense L held in memory is written to bytes".into()
        ));
    }
    let lists = lists_of(c.rows(), c.cols());
    let mut out = vec![0u8; len];
    out[HEADER..HEADER + lists.len()].copy_from_slice(&lists);
    let l = c.l_f64();
    let mut sums = Vec::with_capacity(head.held_batches());
    for (i, chunk) in l.chunks(9 * c.l_rows() * BATCH_COLS).enumerate() {
        let bytes: &[u8] = bytemuck::cast_slice(chunk);
        let off = head.batch_offset(i) as usize;
        out[off..off + bytes.len()].copy_from_slice(bytes);
        sums.push(xxh3_64(bytes));
    }
    let (h, tail, l_end) = tail_of(&head, &lists, &sums);
    out[..HEADER].copy_from_slice(&h);
    out[l_end as usize..].copy_from_slice(&tail);
    Ok(out)
}

/// An opened cache file or shard (or bytes in memory) whose header, lists and checksum table
/// were checked; the L values are read (and checked batch by batch) on demand.
pub struct Part<'a> {
    /// The file (for bytes in memory, a name for the messages).
    pub path: PathBuf,
    /// Its header.
    pub head: Header,
    /// Row nodes.
    pub rows: Vec<u32>,
    /// Column nodes.
    pub cols: Vec<u32>,
    sums: Vec<u64>,
    src: Source<'a>,
}

impl Part<'static> {
    /// Opens `path`: checks magic, version, precision, length and the checksum of header,
    /// lists and batch sums.
    pub fn open(path: &Path) -> Result<Part<'static>, CacheError> {
        let file = std::fs::File::open(path).map_err(|source| CacheError::Io {
            path: path.to_path_buf(),
            source,
        })?;
        Part::read(path, Source::File(file))
    }
}

impl<'a> Part<'a> {
    /// As [`Part::open`], over a whole file's bytes in memory.
    pub fn from_bytes(bytes: &'a [u8]) -> Result<Part<'a>, CacheError> {
        Part::read(Path::new(BYTES_NAME), Source::Bytes(bytes))
    }

    fn read(path: &Path, src: Source<'a>) -> Result<Part<'a>, CacheError> {
        let p = || path.to_path_buf();
        let io = |source| CacheError::Io { path: p(), source };
        let len = src.len().map_err(io)?;
        let mut hb = [0u8; HEADER];
        let got = len.min(HEADER as u64) as usize;
        src.read_exact_at(&mut hb[..got], 0).map_err(io)?;
        if got >= 8 && &hb[..8] != format::MAGIC {
            return Err(CacheError::Format {
                path: p(),
                msg: "not a touchfem compliance cache".into(),
            });
        }
        if got < HEADER {
            return Err(CacheError::Truncated {
                path: p(),
                len: len as usize,
                expected: HEADER,
            });
        }
        let head = Header::parse(&hb).map_err(|msg| CacheError::Format { path: p(), msg })?;
        // Every size is checked, without overflow, and bounded by the real length before
        // anything is allocated: a crafted header cannot ask for more memory than the file.
        if let Some(why) = head.inconsistency() {
            return Err(CacheError::Corrupt {
                path: p(),
                why: format!("header: {why}"),
            });
        }
        let Some(expected) = head.checked_file_len() else {
            return Err(CacheError::Corrupt {
                path: p(),
                why: format!(
                    "header: {} rows ({} of L) and {} columns make a length beyond 64 bits",
                    head.rows, head.l_rows, head.cols
                ),
            });
        };
        if len != expected {
            // A flipped bit in the sizes reads as a wrong length; the checksum cannot be found.
            return Err(CacheError::Truncated {
                path: p(),
                len: usize::try_from(len).unwrap_or(usize::MAX),
                expected: usize::try_from(expected).unwrap_or(usize::MAX),
            });
        }
        let mut lists = vec![0u8; head.lists_len()];
        src.read_exact_at(&mut lists, HEADER as u64).map_err(io)?;
        let nb = head.held_batches();
        let mut table = vec![0u8; 8 * nb + 8];
        src.read_exact_at(&mut table, expected - 8 * nb as u64 - 8)
            .map_err(io)?;
        let mut h = Xxh3::new();
        h.update(&hb);
        h.update(&lists);
        h.update(&table[..8 * nb]);
        if h.digest() != u64_at(&table, 8 * nb) {
            return Err(CacheError::Corrupt {
                path: p(),
                why: "checksum mismatch".into(),
            });
        }
        let nr = head.rows as usize;
        let rows = (0..nr).map(|i| u32_at(&lists, 4 * i)).collect();
        let cols = (0..head.cols as usize)
            .map(|i| u32_at(&lists, 4 * (nr + i)))
            .collect();
        let sums = (0..nb).map(|i| u64_at(&table, 8 * i)).collect();
        Ok(Part {
            path: p(),
            head,
            rows,
            cols,
            sums,
            src,
        })
    }

    /// Reads held batch `i` into `out` (resized to its length) and checks its checksum.
    pub(crate) fn read_batch(&self, i: usize, out: &mut Vec<f64>) -> Result<(), CacheError> {
        let h = &self.head;
        let first = h.col_begin as usize + i * h.batch as usize;
        let ncols = (h.col_end as usize - first).min(h.batch as usize);
        let n = 9 * h.l_rows as usize * ncols;
        out.clear();
        out.resize(n, 0.0);
        let off = h.batch_offset(i);
        let bytes: &mut [u8] = bytemuck::cast_slice_mut(&mut out[..]);
        self.src
            .read_exact_at(bytes, off)
            .map_err(|source| CacheError::Io {
                path: self.path.clone(),
                source,
            })?;
        if xxh3_64(bytes) != self.sums[i] {
            return Err(CacheError::Corrupt {
                path: self.path.clone(),
                why: format!("checksum mismatch in batch {i}"),
            });
        }
        Ok(())
    }

    /// Batches held.
    pub fn batches(&self) -> usize {
        self.sums.len()
    }
}

/// `L` left in a checked cache file instead of memory: read back in ranges of entries (this
/// module's column-major layout, the file's own row and column order) when the GPU copy is
/// built. Its checksums were verified when it was loaded ([`load_near`]).
pub(crate) struct FileL {
    part: Part<'static>,
    max_abs_f32: f32,
}

impl std::fmt::Debug for FileL {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("FileL")
            .field("path", &self.part.path)
            .field("rows", &self.part.head.rows)
            .field("cols", &self.part.head.cols)
            .finish()
    }
}

impl FileL {
    /// Number of entries of `L`.
    pub fn len(&self) -> usize {
        9 * self.part.head.l_rows as usize * self.part.head.cols as usize
    }

    /// max |L| rounded to f32.
    pub fn max_abs_f32(&self) -> f32 {
        self.max_abs_f32
    }

    /// Entries `range`, rounded to f32.
    pub fn read_f32(&self, range: std::ops::Range<usize>) -> Result<Vec<f32>, CacheError> {
        if range.end > self.len() || range.start > range.end {
            return Err(CacheError::Format {
                path: self.part.path.clone(),
                msg: format!("entries {range:?} of {}", self.len()),
            });
        }
        let h = &self.part.head;
        let data = h.batch_offset(0);
        let mut out = Vec::with_capacity(range.len());
        let mut buf = vec![0.0f64; range.len().min(1 << 20)];
        let mut at = range.start;
        while at < range.end {
            let n = (range.end - at).min(buf.len());
            self.part
                .src
                .read_exact_at(
                    bytemuck::cast_slice_mut(&mut buf[..n]),
                    data + 8 * at as u64,
                )
                .map_err(|source| CacheError::Io {
                    path: self.part.path.clone(),
                    source,
                })?;
            out.extend(buf[..n].iter().map(|&v| v as f32));
            at += n;
        }
        Ok(out)
    }
}

impl crate::compliance::LSource for FileL {
    fn len(&self) -> usize {
        FileL::len(self)
    }
    fn max_abs_f32(&self) -> f32 {
        FileL::max_abs_f32(self)
    }
    fn read_f32(&self, range: std::ops::Range<usize>) -> std::io::Result<Vec<f32>> {
        FileL::read_f32(self, range).map_err(std::io::Error::other)
    }
}

/// Loads a complete dense compliance from a part opened from its file (checked as [`load`])
/// without holding `L`: each batch is read, checked and dropped, keeping only the blocks of
/// the near pairs of `triangles` ([`NearBlocks::pairs`]) for the haptic path; the deformer
/// reads `L` from the file again ([`Compliance::stored_l`]).
pub(crate) fn load_near_part(
    part: Part<'static>,
    expected_key: u64,
    n_nodes: usize,
    triangles: &[[u32; 3]],
) -> Result<Compliance, CacheError> {
    check_complete(&part, expected_key, n_nodes)?;
    let path = part.path.clone();
    let path = path.as_path();
    let h = &part.head;
    let nr3 = 3 * h.l_rows as usize;
    let format = |msg: String| CacheError::Format {
        path: path.to_path_buf(),
        msg,
    };
    let (row_of_node, col_of_node, col_row) =
        crate::compliance::index_maps(&part.rows, &part.cols, n_nodes)
            .map_err(|e| format(e.to_string()))?;
    // Every column's row holds L (is among the first `l_rows`): the blocks below read it.
    if let Some(i) = col_row.iter().position(|&r| r >= h.l_rows) {
        return Err(format(format!(
            "touchable node {} is among the clamped rows",
            part.cols[i]
        )));
    }
    let mut near = NearBlocks::pairs(part.cols.len(), triangles, &col_of_node);
    let mut buf = Vec::new();
    let mut max_abs = 0.0f64;
    for b in 0..part.batches() {
        part.read_batch(b, &mut buf)?;
        max_abs = buf.iter().fold(max_abs, |m, v| m.max(v.abs()));
        let c0 = b * h.batch as usize;
        for (jj, col) in buf.chunks_exact(3 * nr3).enumerate() {
            let j = c0 + jj;
            for k in 0..near.neighbours(j).len() {
                let i = near.neighbours(j)[k] as usize;
                let r = row_of_node[part.cols[i] as usize] as usize;
                let at = |bb: usize| {
                    let o = bb * nr3 + 3 * r;
                    glam::DVec3::new(col[o], col[o + 1], col[o + 2])
                };
                // L(node i, column j): the pairs are symmetric, so i lists j.
                near.set(i, j, glam::DMat3::from_cols(at(0), at(1), at(2)));
            }
        }
    }
    let rows = part.rows.clone();
    let l_rows = h.l_rows as usize;
    let cols = part.cols.clone();
    let residual = f64::from_bits(h.residual_bits);
    let file = FileL {
        part,
        max_abs_f32: max_abs as f32,
    };
    let mut c = Compliance::from_near(rows, l_rows, cols, near, Box::new(file), n_nodes, max_abs)
        .map_err(|e| CacheError::Format {
        path: path.to_path_buf(),
        msg: e.to_string(),
    })?;
    c.stats.residual = residual;
    Ok(c)
}

/// A stale (other key or node count) or partial (a shard) file is an error.
fn check_complete(part: &Part<'_>, expected_key: u64, n_nodes: usize) -> Result<(), CacheError> {
    let h = &part.head;
    h.common().fresh(&part.path, expected_key, n_nodes)?;
    match h
        .common()
        .partial(&part.path, h.col_begin, h.col_end, h.cols)
    {
        Some(e) => Err(e),
        None => Ok(()),
    }
}

/// Reads a complete dense compliance from a part opened from a file ([`Part::open`]) or from
/// bytes ([`Part::from_bytes`]), checking the key, that it is not a shard, and every batch's
/// checksum. Streams L into memory batch by batch (no second copy of the file).
pub fn load(part: Part<'_>, expected_key: u64, n_nodes: usize) -> Result<Compliance, CacheError> {
    check_complete(&part, expected_key, n_nodes)?;
    let path = part.path.as_path();
    let h = &part.head;
    let nr = h.l_rows as usize;
    let nc = h.cols as usize;
    let mut l: Vec<f64> = Vec::new();
    l.try_reserve_exact(9 * nr * nc)
        .map_err(|e| CacheError::Format {
            path: path.to_path_buf(),
            msg: format!("cannot hold L: {e}"),
        })?;
    let mut buf = Vec::new();
    for i in 0..part.batches() {
        part.read_batch(i, &mut buf)?;
        l.extend_from_slice(&buf);
    }
    let mut c = Compliance::from_stored(part.rows.clone(), nr, part.cols.clone(), l, n_nodes)
        .map_err(|e| CacheError::Format {
            path: path.to_path_buf(),
            msg: format!("inconsistent contents: {e}"),
        })?;
    c.stats.residual = f64::from_bits(h.residual_bits);
    c.stats.free_dofs = h.free_dofs as usize;
    Ok(c)
}

impl Shard for Part<'_> {
    fn path(&self) -> &Path {
        &self.path
    }
    fn common(&self) -> Common {
        self.head.common()
    }
    fn run(&self) -> (u32, u32, u32) {
        (self.head.col_begin, self.head.col_end, self.head.cols)
    }
    fn residual(&self) -> f64 {
        f64::from_bits(self.head.residual_bits)
    }
    fn same_lists(&self, first: &Self) -> bool {
        self.rows == first.rows && self.cols == first.cols
    }
    fn other_make(&self, first: &Self) -> Option<String> {
        let (h, h0) = (&self.head, &first.head);
        (h.batch != h0.batch || h.free_dofs != h0.free_dofs || h.l_rows != h0.l_rows)
            .then(|| "made with another batch size or stiffness".into())
    }
}

/// Joins the dense shards `parts` (any order) into one complete file at `out`, equal byte for
/// byte to the unsharded precompute ([`format::check_merge`] checks that they belong
/// together); checks every batch's checksum while copying. Returns the merged file's header
/// and length.
pub fn merge(parts: &[PathBuf], out: &Path) -> Result<(Header, u64), CacheError> {
    let mut opened = parts
        .iter()
        .map(|p| Part::open(p))
        .collect::<Result<Vec<_>, _>>()?;
    let residual = format::check_merge(
        &mut opened,
        parts,
        out,
        "columns",
        "mesh, material or selection",
    )?;
    let first = &opened[0];
    let (h0, rows0, cols0) = (first.head.clone(), &first.rows, &first.cols);
    let head = Header {
        shard_index: 1,
        shard_count: 1,
        col_begin: 0,
        col_end: h0.cols,
        residual_bits: residual.to_bits(),
        ..h0
    };
    let w = Writer::create(out, head.clone(), rows0, cols0)?;
    let mut buf = Vec::new();
    let mut b = 0;
    for p in &opened {
        for i in 0..p.batches() {
            p.read_batch(i, &mut buf)?;
            w.write_batch(b, &buf)?;
            b += 1;
        }
    }
    let bytes = w.finish()?;
    Ok((head, bytes))
}

/// The batch range of shard `index` (1-based) of `count` over `batches` batches.
pub(crate) fn shard_batches(batches: usize, index: usize, count: usize) -> std::ops::Range<usize> {
    (batches * (index - 1) / count)..(batches * index / count)
}
