//! Where a command's JSON report goes: standard output, or a file written atomically.

use crate::error::Error;

/// Prints a `serve` report (JSON) or writes it to `path`; then a failed recording
/// (`recording_error`) fails the command, after the report is out.
pub fn report_out(
    report: &impl serde::Serialize,
    path: Option<&std::path::Path>,
    recording_error: Option<&str>,
) -> Result<(), Error> {
    let json = serde_json::to_string_pretty(report).expect("serialisable");
    match path {
        Some(path) => {
            touchfem_core::cache::write_atomic(path, json.as_bytes()).map_err(|source| {
                Error::Write {
                    path: path.to_path_buf(),
                    source,
                }
            })?
        }
        None => println!("{json}"),
    }
    match recording_error {
        Some(e) => Err(Error::Session(format!("--record: {e}"))),
        None => Ok(()),
    }
}
