//! `bake`: the decorated surface's preview colour in atlas space (the sample's
//! preview, front-parallel view under head-on light, looked up at each
//! texel's sample coordinate), with the empty gutter filled by dilation so no
//! dark lines appear at chart borders when the texture is mipmapped.

use std::path::Path;

use super::{atlas_colour, open_samples};
use crate::container::MemoryBudget;
use crate::io::imageio::{self, dilate, PngDepth};
use crate::quilt::Quilt;
use crate::Result;

/// Bakes the quilt's preview colour to `out` (PNG or EXR), gutter dilated.
pub fn bake(quilt_path: &Path, sample: Option<&Path>, out: &Path, budget: MemoryBudget) -> Result<()> {
    let quilt = Quilt::open(quilt_path, budget)?;
    quilt.check_output(out)?;
    if let Some(s) = sample {
        crate::io::staging::check_output(out, &[("the sample", s)])?;
    }
    let samples = open_samples(&quilt, sample, budget)?;
    let previews = samples
        .iter()
        .map(|s| s.svd.preview())
        .collect::<Result<Vec<_>>>()?;
    let (mut img, covered) = atlas_colour(&quilt, &previews)?;
    dilate(&mut img, &covered, 16);
    if out.extension().is_some_and(|e| e.eq_ignore_ascii_case("png")) {
        imageio::write_png(out, &img, PngDepth::Eight)
    } else {
        imageio::write_rgb(out, &img)
    }
}
