//! Files written atomically: under a unique temporary name, synced, renamed over the final
//! name, and the directory synced.

use std::path::{Path, PathBuf};

/// A temporary file name next to `path`, unique to this process, thread and call.
pub(crate) fn unique_tmp(path: &Path) -> std::path::PathBuf {
    use std::sync::atomic::{AtomicU64, Ordering};
    static N: AtomicU64 = AtomicU64::new(0);
    let n = N.fetch_add(1, Ordering::Relaxed);
    // No clock and no process id without `native` (both panic on wasm32-unknown-unknown):
    // the counter alone.
    #[cfg(feature = "native")]
    let (pid, nanos) = (
        std::process::id(),
        std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .map_or(0, |d| d.subsec_nanos()),
    );
    #[cfg(not(feature = "native"))]
    let (pid, nanos) = (0u32, 0u32);
    let mut name = path.file_name().unwrap_or_default().to_os_string();
    name.push(format!(".{pid}.{n}.{nanos:08x}.tmp"));
    path.with_file_name(name)
}

/// A file written under a temporary name next to its final one and renamed over it only when
/// complete ([`AtomicFile::commit`]), so that nothing truncates or half-writes the file it
/// replaces; dropped without a commit, the temporary is removed and the old file is untouched.
/// A target that exists and is not a regular file (a device such as `/dev/null`, a pipe) is
/// written in place; a symbolic link's target is replaced, the link kept.
pub(crate) struct AtomicFile {
    path: PathBuf,
    tmp: Option<PathBuf>,
    file: std::fs::File,
    committed: bool,
}

impl AtomicFile {
    /// Starts writing `path` (its directory must exist).
    pub fn create(path: &Path) -> std::io::Result<AtomicFile> {
        let (path, in_place) = match std::fs::metadata(path) {
            Ok(m) if !m.is_file() => (path.to_path_buf(), true),
            // Replace what a link points to, not the link.
            Ok(_) => (
                std::fs::canonicalize(path).unwrap_or_else(|_| path.to_path_buf()),
                false,
            ),
            Err(_) => (path.to_path_buf(), false),
        };
        if in_place {
            let file = std::fs::OpenOptions::new().write(true).open(&path)?;
            return Ok(AtomicFile {
                path,
                tmp: None,
                file,
                committed: false,
            });
        }
        let tmp = unique_tmp(&path);
        let file = std::fs::File::create_new(&tmp)?;
        Ok(AtomicFile {
            path,
            tmp: Some(tmp),
            file,
            committed: false,
        })
    }

    /// Syncs the file and renames it to its final name (then syncs the directory).
    pub fn commit(mut self) -> std::io::Result<()> {
        use std::io::Write;
        self.file.flush()?;
        if let Some(tmp) = &self.tmp {
            self.file.sync_all()?;
            std::fs::rename(tmp, &self.path)?;
            self.committed = true;
            sync_dir(&self.path)?;
        }
        self.committed = true;
        Ok(())
    }
}

impl std::io::Write for AtomicFile {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.file.write(buf)
    }
    fn flush(&mut self) -> std::io::Result<()> {
        self.file.flush()
    }
}

impl Drop for AtomicFile {
    fn drop(&mut self) {
        if let (false, Some(tmp)) = (self.committed, &self.tmp) {
            let _ = std::fs::remove_file(tmp);
        }
    }
}

/// Writes `bytes` to `path` through an `AtomicFile`: `path` holds either its old content or
/// all of `bytes`, never a part.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    use std::io::Write;
    let mut f = AtomicFile::create(path)?;
    f.write_all(bytes)?;
    f.commit()
}

/// Syncs the directory that holds `path` (so that a rename into it is durable).
pub(crate) fn sync_dir(path: &Path) -> std::io::Result<()> {
    let dir = match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d,
        _ => Path::new("."),
    };
    std::fs::File::open(dir)?.sync_all()
}
