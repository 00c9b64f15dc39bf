//! TetGen `.node` / `.ele` pairs.
//!
//! `.node`: `n dim nattr nbmark` (`dim` = 3; `nattr`, `nbmark` default 0), then `n` lines
//! `i x y z [attrs…] [marker]`. `.ele`: `n nodes_per_tet nattr`, then `n` lines
//! `i a b c d [attrs…]`. `#` starts a comment anywhere. The first node's index (0 or 1) sets the
//! numbering of both files; indices must then run consecutively. Nodes with boundary marker
//! M ≠ 0 form the group `"M"` (0 means "no marker" in TetGen and is not a group). A tet referencing
//! a node beyond the last one is passed on for [`Mesh::from_raw`](crate::mesh::Mesh::from_raw) to
//! report as `IndexOutOfRange`; one below the first index is a parse error.

use super::cursor::{self, Cursor};
use super::{finish_groups, read_bytes, Groups};
use crate::mesh::{MeshError, RawMesh};
use std::path::Path;

/// Reads the `.node`/`.ele` pair that `path` (either of them) belongs to.
pub(super) fn read(path: &Path) -> Result<RawMesh, MeshError> {
    let node_path = path.with_extension("node");
    let ele_path = path.with_extension("ele");
    let node_data = read_bytes(&node_path)?;
    let ele_data = read_bytes(&ele_path)?;
    parse(&node_data, &node_path, &ele_data, &ele_path)
}

/// Parses the contents of a `.node` and an `.ele` file (the paths only name them in errors).
pub(super) fn parse(
    node_data: &[u8],
    node_path: &Path,
    ele_data: &[u8],
    ele_path: &Path,
) -> Result<RawMesh, MeshError> {
    let (nodes, base, groups) = parse_node(node_data, node_path)?;
    let tets = parse_ele(ele_data, ele_path, base)?;
    Ok(RawMesh {
        nodes,
        tets,
        node_groups: finish_groups(groups),
        tet_groups: Default::default(),
    })
}

/// The next line with content, comment removed, trimmed; `None` at the end of the file.
fn data_line<'a>(c: &mut Cursor<'a>) -> Result<Option<(usize, &'a str)>, MeshError> {
    while let Some((pos, raw)) = c.text_line()? {
        let text = match raw.find('#') {
            Some(i) => raw[..i].trim(),
            None => raw,
        };
        if !text.is_empty() {
            return Ok(Some((pos, text)));
        }
    }
    Ok(None)
}

/// A line's whitespace-separated fields, checking their number; `what` and `k` name the line.
fn fields<'a>(
    c: &Cursor,
    pos: usize,
    line: &'a str,
    want: usize,
    (what, k): (&str, usize),
) -> Result<Vec<&'a str>, MeshError> {
    let f: Vec<&str> = line.split_ascii_whitespace().collect();
    if f.len() != want {
        return Err(c.err(
            pos,
            format!("{what} line {k}: expected {want} fields, found {}", f.len()),
        ));
    }
    Ok(f)
}

fn parse_node(data: &[u8], path: &Path) -> Result<(Vec<[f64; 3]>, usize, Groups), MeshError> {
    let mut c = Cursor::new(data, path);
    let (pos, line) = data_line(&mut c)?
        .ok_or_else(|| c.err(0, "empty .node file: expected 'n dim nattr nbmark'"))?;
    let head: Vec<&str> = line.split_ascii_whitespace().collect();
    let e = |m: String| c.err(pos, format!(".node header: {m}"));
    if head.len() > 4 {
        return Err(e(format!(
            "expected 'n dim nattr nbmark', found {} fields",
            head.len()
        )));
    }
    let n: usize = cursor::parse_num(head.first().copied(), "number of nodes").map_err(e)?;
    let dim: usize = cursor::parse_num(head.get(1).copied(), "dimension").map_err(e)?;
    let nattr: usize = match head.get(2) {
        Some(t) => cursor::parse_num(Some(t), "number of attributes").map_err(e)?,
        None => 0,
    };
    let nbmark: usize = match head.get(3) {
        Some(t) => cursor::parse_num(Some(t), "number of boundary markers").map_err(e)?,
        None => 0,
    };
    if dim != 3 {
        return Err(e(format!("dimension must be 3, found {dim}")));
    }
    if nbmark > 1 {
        return Err(e(format!(
            "boundary markers must be 0 or 1, found {nbmark}"
        )));
    }
    if n == 0 {
        return Err(e("the file declares 0 nodes".into()));
    }
    let want = 4usize.saturating_add(nattr).saturating_add(nbmark);
    let mut nodes = Vec::with_capacity(n.min(data.len() / 8));
    let mut groups = Groups::new();
    let mut base = 0;
    for i in 0..n {
        let (pos, line) = data_line(&mut c)?.ok_or_else(|| {
            c.err(
                usize::MAX,
                format!("unexpected end of file after {i} of {n} nodes"),
            )
        })?;
        let f = fields(&c, pos, line, want, ("node", i + 1))?;
        let e = |m: String| c.err(pos, format!("node line {}: {m}", i + 1));
        let index: usize = cursor::parse_num(Some(f[0]), "node index").map_err(e)?;
        if i == 0 {
            if index > 1 {
                return Err(e(format!(
                    "the first node index must be 0 or 1, found {index}"
                )));
            }
            base = index;
        } else if index != base + i {
            return Err(e(format!(
                "node indices must run consecutively: expected {}, found {index}",
                base + i
            )));
        }
        let mut xyz = [0.0; 3];
        for (k, v) in xyz.iter_mut().enumerate() {
            *v = cursor::parse_num(Some(f[1 + k]), ["x", "y", "z"][k]).map_err(e)?;
        }
        for a in &f[4..4 + nattr] {
            let _: f64 = cursor::parse_num(Some(a), "attribute").map_err(e)?;
        }
        if nbmark == 1 {
            let mark: i64 = cursor::parse_num(Some(f[4 + nattr]), "boundary marker").map_err(e)?;
            if mark != 0 {
                groups.entry(mark.to_string()).or_default().push(i);
            }
        }
        nodes.push(xyz);
    }
    if let Some((pos, _)) = data_line(&mut c)? {
        return Err(c.err(pos, format!("unexpected data after the {n} declared nodes")));
    }
    Ok((nodes, base, groups))
}

fn parse_ele(data: &[u8], path: &Path, base: usize) -> Result<Vec<[usize; 4]>, MeshError> {
    let mut c = Cursor::new(data, path);
    let (pos, line) = data_line(&mut c)?
        .ok_or_else(|| c.err(0, "empty .ele file: expected 'n nodes_per_tet nattr'"))?;
    let head: Vec<&str> = line.split_ascii_whitespace().collect();
    let e = |m: String| c.err(pos, format!(".ele header: {m}"));
    if head.len() > 3 {
        return Err(e(format!(
            "expected 'n nodes_per_tet nattr', found {} fields",
            head.len()
        )));
    }
    let n: usize = cursor::parse_num(head.first().copied(), "number of tetrahedra").map_err(e)?;
    let npt: usize = match head.get(1) {
        Some(t) => cursor::parse_num(Some(t), "nodes per tetrahedron").map_err(e)?,
        None => 4,
    };
    let nattr: usize = match head.get(2) {
        Some(t) => cursor::parse_num(Some(t), "number of attributes").map_err(e)?,
        None => 0,
    };
    if npt != 4 {
        return Err(e(format!(
            "{npt} nodes per tetrahedron: only linear 4-node tetrahedra are supported \
             (run TetGen without -o2)"
        )));
    }
    let want = 5usize.saturating_add(nattr);
    let mut tets = Vec::with_capacity(n.min(data.len() / 10));
    let mut ele_base = 0;
    for i in 0..n {
        let (pos, line) = data_line(&mut c)?.ok_or_else(|| {
            c.err(
                usize::MAX,
                format!("unexpected end of file after {i} of {n} tetrahedra"),
            )
        })?;
        let f = fields(&c, pos, line, want, ("tetrahedron", i + 1))?;
        let e = |m: String| c.err(pos, format!("tetrahedron line {}: {m}", i + 1));
        let index: usize = cursor::parse_num(Some(f[0]), "tetrahedron index").map_err(e)?;
        if i == 0 {
            if index > 1 {
                return Err(e(format!(
                    "the first tetrahedron index must be 0 or 1, found {index}"
                )));
            }
            ele_base = index;
        } else if index != ele_base + i {
            return Err(e(format!(
                "tetrahedron indices must run consecutively: expected {}, found {index}",
                ele_base + i
            )));
        }
        let mut t = [0usize; 4];
        for (k, v) in t.iter_mut().enumerate() {
            let node: usize = cursor::parse_num(Some(f[1 + k]), "node index").map_err(e)?;
            *v = node.checked_sub(base).ok_or_else(|| {
                e(format!(
                    "node index {node} is below the first index {base} of the .node file"
                ))
            })?;
        }
        for a in &f[5..] {
            let _: f64 = cursor::parse_num(Some(a), "attribute").map_err(e)?;
        }
        tets.push(t);
    }
    if let Some((pos, _)) = data_line(&mut c)? {
        return Err(c.err(
            pos,
            format!("unexpected data after the {n} declared tetrahedra"),
        ));
    }
    Ok(tets)
}
