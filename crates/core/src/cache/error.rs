//! Why a cache file was not used: the one error type of every cache format.

use std::path::PathBuf;
use thiserror::Error;

use crate::compliance::hmatrix::HOptions;
use crate::compliance::ComplianceError;
use crate::fem::FemError;

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
    /// Made with another compression than asked for: another tolerance (or other options),
    /// or compressed where a dense `L` was asked for, or the other way round.
    #[error("cache {path} {}", compression_words(.found.as_ref(), .asked.as_ref()))]
    Compression {
        /// The file.
        path: PathBuf,
        /// The options it was made with; `None`: dense.
        found: Option<HOptions>,
        /// The options asked for; `None`: dense.
        asked: Option<HOptions>,
    },
    /// A compressed file that cannot be read, where no tolerance was asked for: it is not
    /// replaced by a dense one (which can be many times larger).
    #[error("cache {path} is not a readable compressed cache ({why}); it is not replaced by a dense one, which can be many times larger: give the tolerance it was made with to recompute it compressed, or remove it")]
    Unreadable {
        /// The file.
        path: PathBuf,
        /// Why it cannot be read.
        why: String,
    },
    /// The compliance could not be computed (after the file could not be used).
    #[error(transparent)]
    Compute(#[from] ComplianceError),
}

impl From<FemError> for CacheError {
    fn from(e: FemError) -> Self {
        CacheError::Compute(ComplianceError::Fem(e))
    }
}

/// The words of [`CacheError::Compression`] after the file's name.
fn compression_words(found: Option<&HOptions>, asked: Option<&HOptions>) -> String {
    match (found, asked) {
        (Some(f), Some(a)) if f.tolerance != a.tolerance => format!(
            "was made for tolerance {:e}, not {:e}",
            f.tolerance, a.tolerance
        ),
        (Some(f), Some(a)) => format!(
            "was made with other compression options (admissibility {}, leaves of {}, panels of {}; asked: {}, {}, {})",
            f.eta, f.leaf_size, f.panel_size, a.eta, a.leaf_size, a.panel_size
        ),
        (Some(f), None) => format!(
            "is compressed (tolerance {:e}), but a dense one was asked for",
            f.tolerance
        ),
        (None, Some(a)) => format!(
            "is dense, but one compressed to tolerance {:e} was asked for",
            a.tolerance
        ),
        (None, None) => "was made with the compression asked for".into(),
    }
}
