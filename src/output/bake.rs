//! `bake`: the decorated surface's preview colour in atlas space (the sample's
//! preview, front-parallel view under head-on light, looked up at each
//! texel's sample coordinate), with the empty gutter filled by dilation so no
//! dark lines appear at chart borders when the texture is mipmapped.

use std::path::Path;

use super::{colour_rows, open_samples, BAND_ROWS};
use crate::container::MemoryBudget;
use crate::io::imageio::{self, dilate_with, CoveredMean, RgbImage};
use crate::quilt::Quilt;
use crate::Result;

/// Gutter texels filled around the charts (one per dilation pass).
const DILATE: usize = 16;

/// Bakes the quilt's preview colour to `out` (PNG or EXR), gutter dilated.
/// A PNG is computed and written band by band (64 rows with 16 rows of
/// context each side, and the whole atlas's mean colour
/// from a first pass, so the result is exactly that of the whole image); an
/// EXR is assembled whole before it is written.
pub fn bake(quilt_path: &Path, sample: Option<&Path>, out: &Path, budget: MemoryBudget) -> Result<()> {
    // decoded chunks of the quilt and of the samples
    let [quilt_budget, sample_budget] = budget.split([3, 1]);
    let quilt = Quilt::open(quilt_path, quilt_budget)?;
    quilt.check_output(out)?;
    if let Some(s) = sample {
        crate::io::staging::check_output(out, &[("the sample", s)])?;
    }
    let samples = open_samples(&quilt, sample, sample_budget)?;
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
    let mut bands = DilatedBands {
        quilt: &quilt,
        previews: &previews,
        fill: mean.colour(),
        colour: Vec::new(),
        covered: Vec::new(),
        lo: 0,
        hi: 0,
        next: 0,
    };
    if out.extension().is_some_and(|e| e.eq_ignore_ascii_case("png")) {
        imageio::write_png_bands(out, r, r, || bands.next_band())
    } else {
        let mut data = Vec::with_capacity(r * r * 3);
        while bands.next < r {
            data.extend(bands.next_band()?);
        }
        imageio::write_rgb(
            out,
            &RgbImage {
                width: r,
                height: r,
                data,
            },
        )
    }
}

/// The baked atlas in bands: a window of undilated rows `lo..hi` slides down
/// the atlas, each band dilated with [`DILATE`] rows of context.
struct DilatedBands<'a> {
    quilt: &'a Quilt,
    previews: &'a [RgbImage],
    /// The colour of texels dilation leaves empty.
    fill: [f32; 3],
    colour: Vec<f32>,
    covered: Vec<bool>,
    lo: usize,
    hi: usize,
    /// The first row of the next band.
    next: usize,
}

impl DilatedBands<'_> {
    /// The next [`BAND_ROWS`] rows (fewer at the bottom), dilated.
    fn next_band(&mut self) -> Result<Vec<f32>> {
        let r = self.quilt.resolution;
        let (y0, y1) = (self.next, (self.next + BAND_ROWS).min(r));
        let (want_lo, want_hi) = (y0.saturating_sub(DILATE), (y1 + DILATE).min(r));
        let drop = want_lo - self.lo;
        self.colour.drain(..drop * r * 3);
        self.covered.drain(..drop * r);
        self.lo = want_lo;
        if self.hi < want_hi {
            let (c, m) = colour_rows(self.quilt, self.previews, self.hi, want_hi)?;
            self.colour.extend_from_slice(&c);
            self.covered.extend_from_slice(&m);
            self.hi = want_hi;
        }
        let mut img = RgbImage {
            width: r,
            height: self.hi - self.lo,
            data: self.colour.clone(),
        };
        dilate_with(&mut img, &self.covered, DILATE, self.fill);
        self.next = y1;
        Ok(img.data[(y0 - self.lo) * r * 3..(y1 - self.lo) * r * 3].to_vec())
    }
}
