//! Why a cache file was not used: the one error type of every cache format.

use std::path::PathBuf;
use thiserror::Error;

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
    /// The checksum does not match, or the header's sizes contradict each other.
    #[error("cache {path} is corrupt ({why})")]
    Corrupt {
        /// The file.
        path: PathBuf,
        /// What is wrong ("checksum mismatch", or the header's inconsistency).
        why: String,
    },
    /// A shard (part of the columns) where a complete file is needed.
    #[error("{path} is part {index} of {count} of a sharded precompute: merge the parts first (touchfem precompute --merge)")]
    Partial {
        /// The file.
        path: PathBuf,
        /// Its shard index (1-based).
        index: u32,
        /// The shard count.
        count: u32,
    },
    /// Parts that do not belong together (another mesh, material or selection; a missing,
    /// repeated or overlapping part).
    #[error("cannot merge {path}: {msg}")]
    Mismatch {
        /// The offending part.
        path: PathBuf,
        /// What does not match.
        msg: String,
    },
}
