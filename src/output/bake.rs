//! `bake`: the decorated surface's preview colour in atlas space (the sample's
//! preview, front-parallel view under head-on light, looked up at each
//! texel's sample coordinate), with the empty gutter filled by dilation so no
//! dark lines appear at chart borders when the texture is mipmapped.

use std::path::Path;
use std::sync::Mutex;

use super::{colour_rows, open_samples, BAND_ROWS};
use crate::container::{BoundedCache, MemoryBudget};
use crate::io::imageio::{self, dilate_with, CoveredMean, RgbImage};
use crate::quilt::Quilt;
use crate::Result;

/// Gutter texels filled around the charts (one per dilation pass).
const DILATE: usize = 16;

/// Bakes the quilt's preview colour to `out` (PNG or EXR), gutter dilated.
/// Computed band by band (64 rows with 16 rows of context each side, and
/// the whole atlas's mean colour from a first pass, so the result is exactly
/// that of the whole image dilated) and written as the bands come: a PNG in
/// order, an EXR in whatever order its writer asks, a few bands held.
pub fn bake(quilt_path: &Path, sample: Option<&Path>, out: &Path, budget: MemoryBudget) -> Result<()> {
    // decoded chunks of the quilt and of the samples
    let [quilt_budget, sample_budget] = budget.less(super::PROGRAM_BYTES).split([3, 1]);
    let quilt = Quilt::open(quilt_path, quilt_budget)?;
    quilt.check_output(out)?;
    if let Some(s) = sample {
        crate::io::staging::check_output(out, &[("the sample", s)])?;
    }
    let samples = open_samples(&quilt, sample, [sample_budget, budget])?;
    let previews = samples
        .iter()
        .map(|s| s.svd.preview())
        .collect::<Result<Vec<_>>>()?;
    let r = quilt.resolution;
    // what dilation leaves empty gets the mean of the whole atlas: a first pass
    let mut mean = CoveredMean::default();
    for y0 in (0..r).step_by(BAND_ROWS) {
        let (colour, covered) = colour_rows(&quilt, &previews, y0, (y0 + BAND_ROWS).min(r))?;
        mean.add(&colour, &covered);
    }
    let fill = mean.colour();
    if out.extension().is_some_and(|e| e.eq_ignore_ascii_case("png")) {
        let mut y0 = 0;
        imageio::write_png_bands(out, r, r, || {
            let band = dilated_band(&quilt, &previews, fill, y0);
            y0 += BAND_ROWS;
            band
        })
    } else {
        // the EXR writer asks for pixels in any order from several threads:
        // the bands it needs are computed on demand, the last few held
        let budget = MemoryBudget((4 * BAND_ROWS * r * 12) as u64);
        let held: Mutex<BoundedCache<usize, Vec<f32>>> = Mutex::new(BoundedCache::new(budget));
        imageio::write_exr_rgb_fn(out, r, r, |x, y| {
            let mut cache = crate::lock(&held);
            let b = y / BAND_ROWS;
            if !cache.contains(&b) {
                let band = dilated_band(&quilt, &previews, fill, b * BAND_ROWS)?;
                let bytes = (band.len() * 4) as u64;
                cache.insert(b, band, bytes);
            }
            let band = cache.get(&b).expect("just inserted");
            let i = ((y - b * BAND_ROWS) * r + x) * 3;
            Ok([band[i], band[i + 1], band[i + 2]])
        })
    }
}

/// Rows `y0..y0 + BAND_ROWS` (fewer at the bottom) of the baked atlas:
/// computed with [`DILATE`] rows of context each side and dilated, so they
/// equal those rows of the whole image dilated (`fill` being the whole
/// atlas's covered mean).
fn dilated_band(quilt: &Quilt, previews: &[RgbImage], fill: [f32; 3], y0: usize) -> Result<Vec<f32>> {
    let r = quilt.resolution;
    let y1 = (y0 + BAND_ROWS).min(r);
    let (lo, hi) = (y0.saturating_sub(DILATE), (y1 + DILATE).min(r));
    let (colour, covered) = colour_rows(quilt, previews, lo, hi)?;
    let mut img = RgbImage {
        width: r,
        height: hi - lo,
        data: colour,
    };
    dilate_with(&mut img, &covered, DILATE, fill);
    Ok(img.data[(y0 - lo) * r * 3..(y1 - lo) * r * 3].to_vec())
}
