//! The engine's settings from the environment, read in this one place (a leaf: it names no
//! other module). `TOUCHFEM_CACHE_DIR` (where compliances are cached; empty: off),
//! `TOUCHFEM_PRECOMPUTE`, `TOUCHFEM_ORDERING`, `TOUCHFEM_FACTOR`, `TOUCHFEM_HOST_L`, `TOUCHFEM_FOLD` and `TOUCHFEM_CUT`
//! (expert switches of the precompute and of what a session holds; the docs list them).
//! Without the `native` feature (e.g. on `wasm32-unknown-unknown`) nothing is read: every
//! setting is its default and caching is off.

use std::path::PathBuf;

/// Where the compliance cache lives, if caching is on (never without the `native` feature:
/// no environment, no files).
#[cfg(not(feature = "native"))]
pub fn cache_dir() -> Option<PathBuf> {
    None
}

/// Where the compliance cache lives, if caching is on.
#[cfg(feature = "native")]
pub fn cache_dir() -> Option<PathBuf> {
    match std::env::var_os("TOUCHFEM_CACHE_DIR") {
        Some(d) if d.is_empty() => None,
        Some(d) => Some(PathBuf::from(d)),
        None => std::env::var_os("XDG_CACHE_HOME")
            .map(PathBuf::from)
            .or_else(|| std::env::var_os("HOME").map(|h| PathBuf::from(h).join(".cache")))
            .map(|d| d.join("touchfem")),
    }
}

/// The value of the engine's environment variable `name` (`TOUCHFEM_…`), if set and UTF-8.
/// Without the `native` feature there is no environment: always `None` (the defaults).
pub fn var(name: &str) -> Option<String> {
    #[cfg(feature = "native")]
    {
        std::env::var(name).ok()
    }
    #[cfg(not(feature = "native"))]
    {
        let _ = name;
        None
    }
}
