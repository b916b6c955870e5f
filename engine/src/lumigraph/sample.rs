//! Sampling one grid point of the repository (system paper §5.2.2): its six images rendered
//! from the hierarchy by the server renderer, each kept as albedo, normals and depth
//! ([`super::image`]), an image that shows nothing as the paper's empty flag, and a point
//! enclosed by the surface as no images at all.

use crate::lod::Culling;
use crate::render::{Cut, Frame, Outputs, RenderError, RenderModel, RenderOptions, Renderer};

use super::grid::Grid;
use super::image::{self, ImageError, Quality};

/// Fraction of its pixels every image of a point must show for the point to count as inside
/// the object (a little under 1: scans are rarely watertight).
pub const ENCLOSED_COVERAGE: f32 = 0.99;
/// Projected error of the cut the images are drawn with, in pixels (local rendering's).
pub const PIXEL_ERROR: f32 = 1.0;

/// Why a point could not be sampled.
#[derive(Debug, thiserror::Error)]
pub enum SampleError {
    #[error(transparent)]
    Render(#[from] RenderError),
    #[error(transparent)]
    Image(#[from] ImageError),
    #[error("the renderer returned no {0} buffer")]
    Missing(&'static str),
}

/// The six images of a grid point.
#[derive(Debug, Clone, PartialEq)]
pub enum PointImages {
    /// The point lies inside the object: nothing it sees serves a view from outside.
    Inside,
    /// Each direction's encoded image, `None` where it shows nothing.
    Images([Option<Vec<u8>>; 6]),
}

/// Bytes one image render holds at its peak, for admission control.
pub fn frame_bytes(grid: &Grid) -> u64 {
    OUTPUTS.frame_bytes(grid.size, grid.size) + grid.size as u64 * grid.size as u64 * 8
}

const OUTPUTS: Outputs = Outputs {
    color: true,
    normal: true,
    depth: true,
    ids: false,
};

/// Renders and encodes the six images of grid point `key`. Back faces are drawn (a scan is
/// seen from both sides; the normal faces the camera either way), the albedo is read with
/// ambient light 1 (no shading), and `with_albedo` false keeps none (a model without colours
/// or texture: its albedo is the base colour). `quality`: how finely its sections are coded.
pub fn sample_point(
    renderer: &Renderer,
    model: &RenderModel,
    grid: &Grid,
    key: [u32; 3],
    with_albedo: bool,
    quality: Quality,
) -> Result<PointImages, SampleError> {
    let options = options();
    let mut frames = Vec::with_capacity(6);
    let mut coverage = [0f32; 6];
    for d in 0..6u32 {
        let camera = grid.camera(key[0], key[1], key[2], d);
        let frame = renderer.render(model, &camera, &options, &[])?;
        let depth = frame
            .depth
            .as_deref()
            .ok_or(SampleError::Missing("depth"))?;
        coverage[d as usize] = image::coverage(depth);
        frames.push(frame);
    }
    if coverage.iter().all(|&c| c >= ENCLOSED_COVERAGE) {
        return Ok(PointImages::Inside);
    }
    let mut out: [Option<Vec<u8>>; 6] = Default::default();
    for (d, frame) in frames.into_iter().enumerate() {
        if coverage[d] > 0.0 {
            out[d] = encode(grid.size, &frame, d / 2, with_albedo, quality)?;
        }
    }
    Ok(PointImages::Images(out))
}

/// Renders and encodes image `key` = `(x, y, z, d)` of refinement level `level` alone (a refined
/// point's image, rendered when first asked for: a view that needs it stands outside the
/// object, so no inside test), `None` where it shows nothing. As [`sample_point`] otherwise.
pub fn sample_image(
    renderer: &Renderer,
    model: &RenderModel,
    grid: &Grid,
    level: u32,
    [x, y, z, d]: [u32; 4],
    with_albedo: bool,
    quality: Quality,
) -> Result<Option<Vec<u8>>, SampleError> {
    let camera = grid.level_camera(level, [x, y, z], d);
    let frame = renderer.render(model, &camera, &options(), &[])?;
    encode(grid.size, &frame, d as usize / 2, with_albedo, quality)
}

fn options() -> RenderOptions {
    RenderOptions {
        cut: Cut::View {
            pixel_error: PIXEL_ERROR,
            culling: Culling {
                frustum: true,
                backface: false,
            },
        },
        outputs: OUTPUTS,
        ambient: 1.0,
        ..RenderOptions::default()
    }
}

fn encode(
    size: u32,
    frame: &Frame,
    axis: usize,
    with_albedo: bool,
    quality: Quality,
) -> Result<Option<Vec<u8>>, SampleError> {
    let depth = frame
        .depth
        .as_deref()
        .ok_or(SampleError::Missing("depth"))?;
    let normal = frame
        .normal
        .as_deref()
        .ok_or(SampleError::Missing("normal"))?;
    let albedo = match (with_albedo, frame.color.as_deref()) {
        (true, Some(c)) => Some(c),
        (true, None) => return Err(SampleError::Missing("colour")),
        (false, _) => None,
    };
    Ok(image::encode(size, albedo, normal, depth, axis, quality)?)
}
