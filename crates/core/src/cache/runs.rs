//! The order of a merge's parts: each shard once, their runs (of columns, or of panels)
//! contiguous from 0 to the whole.

use std::path::Path;

use super::error::CacheError;

/// One part as a merge sees it: its file, shard index (1-based) and the run it holds.
pub(crate) struct PartRun<'a> {
    pub path: &'a Path,
    pub shard_index: u32,
    pub begin: u32,
    pub end: u32,
}

/// Checks that `parts` (sorted by shard index) are shards 1..=n once each, their runs
/// following each other from 0 to `total` (`what`: "columns" or "panels").
pub(crate) fn check_runs(parts: &[PartRun<'_>], total: u32, what: &str) -> Result<(), CacheError> {
    let mismatch = |path: &Path, msg: String| {
        Err(CacheError::Mismatch {
            path: path.to_path_buf(),
            msg,
        })
    };
    let mut next = 0u32;
    for (i, p) in parts.iter().enumerate() {
        if p.shard_index as usize != i + 1 {
            return mismatch(
                p.path,
                format!(
                    "part {} is given twice or part {} is missing",
                    p.shard_index,
                    i + 1
                ),
            );
        }
        if p.begin != next {
            return mismatch(
                p.path,
                format!(
                    "holds {what} {}..{}, expected them to start at {next}",
                    p.begin, p.end
                ),
            );
        }
        next = p.end;
    }
    match parts.last() {
        Some(last) if next != total => mismatch(
            last.path,
            format!(
                "the parts end at {} {next} of {total}",
                what.trim_end_matches('s')
            ),
        ),
        _ => Ok(()),
    }
}
