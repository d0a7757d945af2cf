//! A band of atlas rows of a decorated surface as the figures read it
//! (`evaluate` and the continuation figures): preview colour, coverage,
//! patches, samples, charts, stored coordinates and Jacobians.

use crate::artifact::gim::Gim;
use crate::io::imageio::RgbImage;
use crate::output::colour_rows;
use crate::quilt::Quilt;
use crate::Result;

/// The RGB distance between texels `a` and `b` of `colour` (3 values a texel).
pub(super) fn diff(colour: &[f32], a: usize, b: usize) -> f64 {
    rgb_distance(&colour[a * 3..a * 3 + 3], &colour[b * 3..b * 3 + 3])
}

/// The distance between two RGB colours (their first 3 values).
pub(super) fn rgb_distance(a: &[f32], b: &[f32]) -> f64 {
    (0..3).map(|k| ((a[k] - b[k]) as f64).powi(2)).sum::<f64>().sqrt()
}

/// Atlas rows `y0..hi` read for the band's own rows `first..first +
/// own / r` (the rows around them are there for the neighbours of its
/// texels): preview colour, covered mask, patch, sample index, chart,
/// rotation, stored sample coordinates and Jacobians, row-major from `y0`.
pub(super) struct ColourBand {
    pub(super) y0: usize,
    /// The band's first own row.
    pub(super) first: usize,
    /// Where the own rows start in the arrays (`(first - y0) * r`).
    start: usize,
    /// Texels of the band's own rows.
    pub(super) own: usize,
    pub(super) colour: Vec<f32>,
    pub(super) covered: Vec<bool>,
    pub(super) patch: Vec<u32>,
    pub(super) index: Vec<u8>,
    pub(super) chart: Vec<u32>,
    /// The mesh face each texel samples.
    pub(super) face: Vec<u32>,
    pub(super) rotation: Vec<u8>,
    /// Stored sample coordinates (sample pixels).
    pub(super) coords: Vec<[f32; 2]>,
    /// Stored Jacobians (sample offset per atlas step, as
    /// [`Quilt::jacobians`]); `None` for a quilt that stores none.
    pub(super) jacobian: Option<Vec<[f32; 4]>>,
}

impl ColourBand {
    /// Atlas rows `y0..hi`, rows `first..y1` the band's own.
    pub(super) fn read(
        quilt: &Quilt,
        gim: &Gim,
        previews: &[RgbImage],
        y0: usize,
        first: usize,
        y1: usize,
        hi: usize,
    ) -> Result<ColourBand> {
        let (r, h) = (quilt.resolution, hi - y0);
        let (colour, covered) = colour_rows(quilt, previews, y0, hi)?;
        let (chart, face) = gim.chart_face_region(0, y0, r, h)?;
        Ok(ColourBand {
            y0,
            first,
            start: (first - y0) * r,
            own: (y1 - first) * r,
            colour,
            covered,
            patch: quilt.patch_region(0, y0, r, h)?,
            index: quilt.sample_region(0, y0, r, h)?,
            chart,
            face,
            rotation: quilt.rotation_region(0, y0, r, h)?,
            coords: quilt.coord_region(0, y0, r, h)?,
            jacobian: quilt.jacobian_region(0, y0, r, h)?,
        })
    }

    /// A band from its arrays (tests): every row its own, faces and
    /// rotations zero.
    #[cfg(test)]
    #[allow(clippy::too_many_arguments)]
    pub(super) fn from_parts(
        y0: usize,
        first: usize,
        own: usize,
        colour: Vec<f32>,
        covered: Vec<bool>,
        patch: Vec<u32>,
        index: Vec<u8>,
        chart: Vec<u32>,
        coords: Vec<[f32; 2]>,
    ) -> ColourBand {
        let n = covered.len();
        ColourBand {
            y0,
            first,
            start: 0,
            own,
            colour,
            covered,
            patch,
            index,
            chart,
            face: vec![0; n],
            rotation: vec![0; n],
            coords,
            jacobian: None,
        }
    }

    /// The indices (into the band's arrays) of its own rows' texels.
    pub(super) fn own_texels(&self) -> std::ops::Range<usize> {
        self.start..self.start + self.own
    }
}
