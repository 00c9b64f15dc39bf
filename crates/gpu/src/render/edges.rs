//! The line-list index buffers a renderer draws over a deformer's surface: its edges (the
//! wireframe) and a closed slit's line.

use std::ops::Range;

use wgpu::util::DeviceExt;

use crate::Deformer;

/// The surface edges of a [`Deformer`]'s triangles as a line-list index buffer, for the
/// wireframe overlay, followed by its slit's line ([`Deformer::slit`]), which a renderer draws
/// whether or not the wireframe is on. Build once per deformer (again when its surface
/// changes) and keep it with the frame loop.
#[derive(Debug)]
pub struct Edges {
    buffer: Option<wgpu::Buffer>,
    /// Indices of the wireframe (two an edge), then of the slit's line.
    count: u32,
    slit: u32,
}

impl Edges {
    /// The unique undirected edges of `deformer`'s triangles, then its slit's edges.
    pub fn new(device: &wgpu::Device, deformer: &Deformer) -> Edges {
        let mut e = edge_list(deformer.triangles());
        let count = e.len() as u32;
        e.extend(deformer.slit().iter().flatten());
        Edges {
            buffer: (!e.is_empty()).then(|| {
                device.create_buffer_init(&wgpu::util::BufferInitDescriptor {
                    label: Some("touchfem edges"),
                    contents: bytemuck::cast_slice(&e),
                    usage: wgpu::BufferUsages::INDEX,
                })
            }),
            count,
            slit: e.len() as u32 - count,
        }
    }

    /// Number of the wireframe's indices (two per edge).
    pub fn index_count(&self) -> u32 {
        self.count
    }

    /// Number of the slit line's indices (two per edge; 0 without a separating cut).
    pub fn slit_index_count(&self) -> u32 {
        self.slit
    }

    /// The buffer and the range in it of the slit's line (`slit`) or of the wireframe, if
    /// that has any.
    pub(crate) fn lines(&self, slit: bool) -> Option<(&wgpu::Buffer, Range<u32>)> {
        let range = if slit {
            self.count..self.count + self.slit
        } else {
            0..self.count
        };
        let b = self.buffer.as_ref().filter(|_| !range.is_empty())?;
        Some((b, range))
    }
}

/// Unique undirected edges of `tris`, as a line-list index array.
fn edge_list(tris: &[[u32; 3]]) -> Vec<u32> {
    let mut e: Vec<(u32, u32)> = tris
        .iter()
        .flat_map(|t| [(t[0], t[1]), (t[1], t[2]), (t[2], t[0])])
        .map(|(a, b)| (a.min(b), a.max(b)))
        .collect();
    e.sort_unstable();
    e.dedup();
    e.into_iter().flat_map(|(a, b)| [a, b]).collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn edges_are_unique() {
        let e = edge_list(&[[0, 1, 2], [2, 1, 3]]);
        assert_eq!(e, vec![0, 1, 0, 2, 1, 2, 1, 3, 2, 3]);
    }
}
