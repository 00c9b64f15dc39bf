//! Mesh file loaders: Gmsh MSH 4.1 and 2.2 (ASCII and binary), TetGen `.node`/`.ele`.
//! Each returns a [`RawMesh`] in the file's own length unit; [`Mesh::from_raw`](super::Mesh::from_raw)
//! validates it.
//!
//! * `.msh`: the version in `$MeshFormat` picks the parser. 4.1 goes through the `mshio` crate
//!   (plus our own `$PhysicalNames` reader); 2.0–2.2 through our own parser. MSH 4.0 and 1.0 are
//!   rejected with a message saying so.
//! * `.node` / `.ele`: TetGen; given either, the sibling with the same stem is read too.
//!
//! Node groups: every Gmsh physical group (of points, curves, surfaces or volumes) becomes a group
//! holding the nodes of its elements (and, in 4.1, the nodes of its point entities), named by
//! `$PhysicalNames` or, when unnamed, by its number (`"7"`). Groups of different dimensions with
//! the same name are merged. TetGen boundary markers M ≠ 0 become groups `"M"`.
//!
//! Only linear tetrahedra (Gmsh type 4, TetGen 4 nodes per tet) are read: second-order tets and
//! other 3-D elements (hexahedra, prisms, pyramids) are a [`MeshError::Parse`] rather than being
//! silently dropped or truncated to their corners. Lower-dimensional elements only feed groups.
//!
//! No input makes these functions panic: every malformed file is a [`MeshError::Parse`] naming the
//! file and the line (ASCII) or byte offset (binary) where known.

mod cursor;
mod msh22;
mod msh41;
mod tetgen;

use super::{MeshError, RawMesh};
use cursor::Cursor;
use std::collections::{BTreeMap, HashMap};
use std::path::Path;

/// Reads a mesh file, choosing the format by extension (`.msh`, `.node`, `.ele`).
pub fn read(path: &Path) -> Result<RawMesh, MeshError> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(|e| e.to_ascii_lowercase());
    match ext.as_deref() {
        Some("msh") => read_msh(path),
        Some("node") | Some("ele") => tetgen::read(path),
        _ => Err(MeshError::Parse {
            path: path.to_path_buf(),
            msg: "unknown mesh file extension: expected .msh (Gmsh), .node or .ele (TetGen)".into(),
        }),
    }
}

/// Reads a Gmsh `.msh` file of format 4.1 or 2.x (ASCII or binary).
pub(crate) fn read_msh(path: &Path) -> Result<RawMesh, MeshError> {
    let data = read_bytes(path)?;
    parse_msh(&data, path)
}

/// Parses the bytes of a Gmsh `.msh` file; `path` only names the file in errors.
pub fn parse_msh(data: &[u8], path: &Path) -> Result<RawMesh, MeshError> {
    let header = MshHeader::parse(data, path)?;
    match header.version.as_str() {
        "4.1" => msh41::parse(data, path, &header),
        v if v.starts_with("2.") || v == "2" => msh22::parse(data, path),
        v => Err(MeshError::Parse {
            path: path.to_path_buf(),
            msg: format!(
                "line {}: unsupported MSH format version {v}: only 4.1 and 2.2 are read \
                 (re-save with Gmsh, Mesh.MshFileVersion = 4.1 or 2.2)",
                header.version_line
            ),
        }),
    }
}

/// Parses the contents of a TetGen `.node` and `.ele` file; the paths only name them in errors.
pub fn parse_tetgen(
    node_data: &[u8],
    node_path: &Path,
    ele_data: &[u8],
    ele_path: &Path,
) -> Result<RawMesh, MeshError> {
    tetgen::parse(node_data, node_path, ele_data, ele_path)
}

/// Reads a whole file, mapping the OS error to [`MeshError::Io`].
fn read_bytes(path: &Path) -> Result<Vec<u8>, MeshError> {
    std::fs::read(path).map_err(|source| MeshError::Io {
        path: path.to_path_buf(),
        source,
    })
}

/// The first line of `$MeshFormat`: `version file-type data-size`.
#[derive(Debug)]
struct MshHeader {
    /// The version token as written, e.g. `4.1`, `2.2`.
    version: String,
    /// 1-based line of the version line.
    version_line: usize,
    /// True for binary files (file-type 1).
    binary: bool,
    /// The data-size field (size of `size_t` in 4.1, of a double in 2.2).
    data_size: usize,
}

impl MshHeader {
    fn parse(data: &[u8], path: &Path) -> Result<MshHeader, MeshError> {
        let mut c = Cursor::new(data, path);
        let (pos, first) = c.expect_text_line("the $MeshFormat section")?;
        if first != "$MeshFormat" {
            let msg = if first.starts_with("$NOD") {
                "this is an MSH 1.0 file ($NOD): only 4.1 and 2.2 are read".to_string()
            } else {
                format!(
                    "not a Gmsh mesh: expected '$MeshFormat', found '{}'",
                    cursor::shorten(first)
                )
            };
            return Err(c.err(pos, msg));
        }
        let (pos, line) =
            c.expect_text_line("the MSH format line 'version file-type data-size'")?;
        let mut tok = line.split_ascii_whitespace();
        let version = tok.next().unwrap_or_default().to_string();
        let file_type: u8 =
            cursor::parse_num(tok.next(), "the file-type (0 or 1)").map_err(|m| c.err(pos, m))?;
        let data_size: usize =
            cursor::parse_num(tok.next(), "the data-size").map_err(|m| c.err(pos, m))?;
        if file_type > 1 {
            return Err(c.err(
                pos,
                format!("file-type must be 0 (ASCII) or 1 (binary), found {file_type}"),
            ));
        }
        Ok(MshHeader {
            version,
            version_line: c.line_no(pos),
            binary: file_type == 1,
            data_size,
        })
    }
}

/// Physical names: (dimension, physical tag) → name.
type PhysicalNames = HashMap<(i32, i32), String>;

/// Finds the `$PhysicalNames` section (a line of its own, ASCII even in binary files) and parses
/// it. Absent → empty.
fn find_physical_names(data: &[u8], path: &Path) -> Result<PhysicalNames, MeshError> {
    let Some(start) = cursor::find_line(data, b"$PhysicalNames", 0) else {
        return Ok(PhysicalNames::new());
    };
    let mut c = Cursor::new(data, path);
    c.seek(start);
    c.expect_text_line("$PhysicalNames")?;
    parse_physical_names(&mut c)
}

/// Parses a `$PhysicalNames` body (the cursor is just after the `$PhysicalNames` line) up to and
/// including `$EndPhysicalNames`: `n`, then `n` lines `dim tag "name"`.
fn parse_physical_names(c: &mut Cursor) -> Result<PhysicalNames, MeshError> {
    let (pos, line) = c.expect_text_line("the number of physical names")?;
    let n: usize = cursor::parse_single(line, "the number of physical names")
        .map_err(|m| c.err(pos, format!("$PhysicalNames: {m}")))?;
    let mut names = PhysicalNames::new();
    for k in 0..n {
        let (pos, line) = c.expect_text_line("a physical name 'dim tag \"name\"'")?;
        if line.starts_with('$') {
            return Err(c.err(
                pos,
                format!("$PhysicalNames declares {n} names but holds only {k}"),
            ));
        }
        let e = |m: String| c.err(pos, format!("$PhysicalNames entry {}: {m}", k + 1));
        let mut parts = line.splitn(3, |ch: char| ch.is_ascii_whitespace());
        let dim: i32 = cursor::parse_num(parts.next(), "dimension").map_err(e)?;
        let tag: i32 = cursor::parse_num(parts.next(), "physical tag").map_err(e)?;
        if !(0..=3).contains(&dim) {
            return Err(e(format!("dimension must be 0 to 3, found {dim}")));
        }
        let raw = parts.next().unwrap_or("").trim();
        let name = if raw.len() >= 2 && raw.starts_with('"') && raw.ends_with('"') {
            &raw[1..raw.len() - 1]
        } else {
            return Err(e(format!(
                "expected a quoted name, found '{}'",
                cursor::shorten(raw)
            )));
        };
        names.insert((dim, tag), name.to_string());
    }
    let (pos, line) = c.expect_text_line("$EndPhysicalNames")?;
    if line != "$EndPhysicalNames" {
        return Err(c.err(
            pos,
            format!(
                "expected $EndPhysicalNames after {n} names, found '{}'",
                cursor::shorten(line)
            ),
        ));
    }
    Ok(names)
}

/// The name of a physical group: its `$PhysicalNames` entry, or its number.
fn group_name(names: &PhysicalNames, dim: i32, tag: i32) -> String {
    names
        .get(&(dim, tag))
        .cloned()
        .unwrap_or_else(|| tag.to_string())
}

/// Group node sets under construction; [`finish_groups`] sorts and deduplicates them.
type Groups = BTreeMap<String, Vec<usize>>;

fn finish_groups(mut groups: Groups) -> Groups {
    for v in groups.values_mut() {
        v.sort_unstable();
        v.dedup();
    }
    groups
}
