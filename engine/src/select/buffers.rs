//! The rendered buffers a selection runs on (system paper §4.1.1: "we render another image
//! that has the value of the surface normal instead of the pixel color on the background
//! buffer ... the depth image rendered on the back buffer"; §4.1.2: the index image).

use super::SelectError;
use crate::render::{Frame, NO_NODE};

/// Borrowed per-pixel buffers of one view, row-major, top row first: shaded colour, unit normal
/// facing the viewer, linear view depth (`INFINITY` off the model) and the drawn node
/// ([`NO_NODE`] off the model).
#[derive(Debug, Clone, Copy)]
pub struct Buffers<'a> {
    pub width: u32,
    pub height: u32,
    pub color: &'a [[u8; 4]],
    pub normal: &'a [[f32; 3]],
    pub depth: &'a [f32],
    pub node: &'a [u32],
    /// Original vertex id at each pixel (the drawn triangle's corner nearest the pixel centre).
    pub vertex: &'a [u32],
}

impl<'a> Buffers<'a> {
    /// The buffers of a frame rendered with colour, normal, depth and ids.
    pub fn from_frame(frame: &'a Frame) -> Result<Buffers<'a>, SelectError> {
        let ids = frame.ids.as_ref().ok_or(SelectError::MissingBuffer("id"))?;
        let b = Buffers {
            width: frame.width,
            height: frame.height,
            color: frame
                .color
                .as_deref()
                .ok_or(SelectError::MissingBuffer("colour"))?,
            normal: frame
                .normal
                .as_deref()
                .ok_or(SelectError::MissingBuffer("normal"))?,
            depth: frame
                .depth
                .as_deref()
                .ok_or(SelectError::MissingBuffer("depth"))?,
            node: &ids.node,
            vertex: &ids.vertex,
        };
        b.check()?;
        Ok(b)
    }

    /// Checks that every buffer has one value per pixel.
    pub fn check(&self) -> Result<(), SelectError> {
        let n = self.len();
        let lens = [
            ("colour buffer", self.color.len()),
            ("normal buffer", self.normal.len()),
            ("depth buffer", self.depth.len()),
            ("node buffer", self.node.len()),
            ("vertex buffer", self.vertex.len()),
        ];
        for (what, len) in lens {
            if len != n {
                return Err(SelectError::SizeMismatch {
                    what,
                    got_w: len as u32,
                    got_h: 1,
                    width: self.width,
                    height: self.height,
                });
            }
        }
        Ok(())
    }

    /// Pixels.
    pub fn len(&self) -> usize {
        self.width as usize * self.height as usize
    }

    /// Whether the view has no pixels.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Whether pixel `i` shows the model.
    #[inline]
    pub fn covered(&self, i: usize) -> bool {
        self.node[i] != NO_NODE && self.depth[i].is_finite()
    }

    /// Covered pixels.
    pub fn covered_count(&self) -> usize {
        (0..self.len()).filter(|&i| self.covered(i)).count()
    }
}

/// Owned buffers (synthetic tests and tools).
#[derive(Debug, Clone, Default)]
pub struct OwnedBuffers {
    pub width: u32,
    pub height: u32,
    pub color: Vec<[u8; 4]>,
    pub normal: Vec<[f32; 3]>,
    pub depth: Vec<f32>,
    pub node: Vec<u32>,
    pub vertex: Vec<u32>,
}

impl OwnedBuffers {
    /// A view where every pixel shows node 0 facing the viewer at depth 1, in grey.
    pub fn flat(width: u32, height: u32) -> OwnedBuffers {
        let n = width as usize * height as usize;
        OwnedBuffers {
            width,
            height,
            color: vec![[128, 128, 128, 255]; n],
            normal: vec![[0.0, 0.0, 1.0]; n],
            depth: vec![1.0; n],
            node: vec![0; n],
            vertex: (0..n as u32).collect(),
        }
    }

    /// [`OwnedBuffers::flat`] with a crease: pixels from column `crease_x` on face 37° away.
    pub fn creased(width: u32, height: u32, crease_x: u32) -> OwnedBuffers {
        let mut b = OwnedBuffers::flat(width, height);
        for (i, n) in b.normal.iter_mut().enumerate() {
            if i % width as usize >= crease_x as usize {
                *n = [0.6, 0.0, 0.8];
            }
        }
        b
    }

    /// Borrows them.
    pub fn view(&self) -> Buffers<'_> {
        Buffers {
            width: self.width,
            height: self.height,
            color: &self.color,
            normal: &self.normal,
            depth: &self.depth,
            node: &self.node,
            vertex: &self.vertex,
        }
    }
}
