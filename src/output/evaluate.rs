//! `evaluate`: quality figures of a decorated surface, as an
//! [`EvaluateReport`] (which `btfquilt evaluate` prints as JSON).
//!
//! - seams: colour differences across grid edges where the patch changes,
//!   against those inside patches;
//! - zippers: mean colour difference across zipper links divided by the mean
//!   across grid links inside charts (≈ 1 means chart seams are invisible);
//! - coherence: mean RGB distance from 5×5 output windows to their nearest
//!   5×5 window of the sample (turned by the window's rotation);
//! - scale: the size of the sample on the surface, measured from the stored
//!   sample coordinates against the 3D positions (mesh units).

use std::path::Path;

use serde::Serialize;

use crate::artifact::gim::EMPTY;
use crate::container::MemoryBudget;
use crate::factorize::rotate_maps;
use crate::io::imageio::RgbImage;
use crate::output::{atlas_colour, open_samples, OpenSample};
use crate::quilt::{Quilt, NO_PATCH};
use crate::Result;

fn diff(img: &RgbImage, a: usize, b: usize) -> f64 {
    (0..3)
        .map(|k| ((img.data[a * 3 + k] - img.data[b * 3 + k]) as f64).powi(2))
        .sum::<f64>()
        .sqrt()
}

/// The quality figures of a decorated surface. Serialized (serde), its
/// field names and nesting are those of `btfquilt evaluate`'s JSON.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct EvaluateReport {
    /// Covered atlas texels.
    pub texels: usize,
    /// Distinct patches in the synthesis.
    pub patches: usize,
    /// The painting measures, for a painted surface only.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub painting: Option<PaintingFigures>,
    pub seam: SeamFigures,
    pub zipper: ZipperFigures,
    pub coherence: CoherenceFigures,
    pub scale: ScaleFigures,
}

/// The sample's size on the surface, measured: over grid edges inside one
/// patch of the first sample, the median of |Δ sample coordinate| (original
/// sample pixels) / |Δ position| (mesh units).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ScaleFigures {
    /// Grid edges measured.
    pub edges: usize,
    /// Median sample pixels per mesh unit along the surface.
    pub sample_pixels_per_unit: f64,
    /// The first sample's width in mesh units it spans on the surface
    /// (its width in pixels over the median above): a brick `p` sample
    /// pixels long is `p / sample_pixels_per_unit` units long.
    pub sample_width_units: f64,
}

/// Colour differences across grid edges inside charts where the patch
/// changes (seam edges), against those inside patches.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct SeamFigures {
    /// Seam edges.
    pub edges: usize,
    /// Seam edges / all grid edges inside charts.
    pub fraction_of_edges: f64,
    /// Mean RGB distance across seam edges.
    pub mean_colour_difference: f64,
    pub median: f64,
    pub p95: f64,
    pub max: f64,
    /// Mean RGB distance across edges inside patches.
    pub inside_patches_mean: f64,
    /// `mean_colour_difference / inside_patches_mean`.
    pub ratio_to_inside: f64,
}

/// Colour differences across zipper links (chart seams) against grid edges
/// inside charts.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ZipperFigures {
    /// Covered zipper links.
    pub links: usize,
    pub mean_colour_difference: f64,
    pub inside_charts_mean: f64,
    /// `mean_colour_difference / inside_charts_mean` (≈ 1: chart seams are invisible).
    pub ratio: f64,
}

/// How closely 5×5 output windows resemble the sample.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct CoherenceFigures {
    /// Windows measured.
    pub windows: usize,
    pub mean_rgb_distance_to_nearest_sample_window: f64,
}

/// The painting measures of a painted surface (§IV).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct PaintingFigures {
    /// Texels of F (m0 = 1).
    pub region_texels: usize,
    /// Fraction of F covered by foreground texels.
    pub region_covered_by_foreground: f64,
    /// Texels of the painted sample with m_σ ≥ ½.
    pub foreground_texels: usize,
    /// Fraction of the foreground texels outside F and its transition zone (m0 = 0).
    pub foreground_outside_region_and_transition: f64,
}

/// Computes the figures.
pub fn evaluate(
    quilt_path: &Path,
    gim_path: Option<&Path>,
    sample: Option<&Path>,
    budget: MemoryBudget,
) -> Result<EvaluateReport> {
    let quilt = Quilt::open(quilt_path, budget)?;
    let gim = quilt.open_gim(gim_path, budget)?;
    let samples = open_samples(&quilt, sample, budget)?;
    let previews = samples
        .iter()
        .map(|s| s.svd.preview())
        .collect::<Result<Vec<_>>>()?;
    let (img, covered) = atlas_colour(&quilt, &previews)?;
    let r = quilt.resolution;
    let (patches, index) = (quilt.patches()?, quilt.sample_index()?);
    let chart: Vec<u32> = gim.read("chart")?;
    // seam steps are kept (their percentiles are reported); steps inside
    // patches only summed, in the order a list would sum them
    let mut seam = Vec::new();
    let (mut inner_sum, mut inner_count) = (0f64, 0usize);
    for y in 0..r {
        for x in 0..r {
            let t = y * r + x;
            if chart[t] == EMPTY || !covered[t] {
                continue;
            }
            for n in [(x + 1 < r).then(|| t + 1), (y + 1 < r).then(|| t + r)]
                .into_iter()
                .flatten()
            {
                if chart[n] == chart[t] && covered[n] {
                    if patches[n] != patches[t] {
                        seam.push(diff(&img, t, n));
                    } else {
                        inner_sum += diff(&img, t, n);
                        inner_count += 1;
                    }
                }
            }
        }
    }
    let mean = |v: &[f64]| v.iter().sum::<f64>() / v.len().max(1) as f64;
    let mut sorted = seam.clone();
    sorted.sort_by(f64::total_cmp);
    let pct = |p: f64| {
        sorted
            .get(((sorted.len() as f64 - 1.0) * p).round() as usize)
            .copied()
            .unwrap_or(0.0)
    };
    let links = gim.zipper_links()?;
    let zip: Vec<f64> = links
        .iter()
        .filter(|l| covered[l[0] as usize] && covered[l[1] as usize])
        .map(|l| diff(&img, l[0] as usize, l[1] as usize))
        .collect();
    let inner_mean = inner_sum / inner_count.max(1) as f64;
    let inside_mean = seam.iter().fold(inner_sum, |a, &d| a + d) / (inner_count + seam.len()).max(1) as f64;
    let zipper_ratio = mean(&zip) / inside_mean.max(1e-12) + 0.0;
    let coherence = coherence(&quilt, &img, &covered, &chart, &index, &previews)?;
    let seams_fraction = seam.len() as f64 / (seam.len() + inner_count).max(1) as f64;
    let patch_count = {
        let mut p: Vec<u32> = patches.iter().copied().filter(|&p| p != NO_PATCH).collect();
        p.sort_unstable();
        p.dedup();
        p.len()
    };
    let painting = painting_measures(&quilt, &chart, &samples)?;
    let width = previews.first().map_or(0, |p| p.width);
    let scale = scale(&quilt, &gim, &chart, &patches, &index, width)?;
    Ok(EvaluateReport {
        texels: covered.iter().filter(|&&c| c).count(),
        patches: patch_count,
        painting,
        seam: SeamFigures {
            edges: seam.len(),
            fraction_of_edges: seams_fraction,
            mean_colour_difference: mean(&seam),
            median: pct(0.5),
            p95: pct(0.95),
            max: pct(1.0),
            inside_patches_mean: inner_mean,
            ratio_to_inside: mean(&seam) / inner_mean.max(1e-12),
        },
        zipper: ZipperFigures {
            links: zip.len(),
            mean_colour_difference: mean(&zip),
            inside_charts_mean: inside_mean,
            ratio: zipper_ratio,
        },
        coherence: CoherenceFigures {
            windows: coherence.1,
            mean_rgb_distance_to_nearest_sample_window: coherence.0,
        },
        scale,
    })
}

/// [`ScaleFigures`] of the first sample, `width` pixels wide.
fn scale(
    quilt: &Quilt,
    gim: &crate::artifact::gim::Gim,
    chart: &[u32],
    patches: &[u32],
    index: &[u8],
    width: usize,
) -> Result<ScaleFigures> {
    let r = quilt.resolution;
    let coords = quilt.coords()?;
    let position: Vec<f32> = gim.read("position")?;
    let p = |t: usize| glam::Vec3::from_slice(&position[t * 3..t * 3 + 3]);
    let mut ratios = Vec::new();
    for y in 0..r {
        for x in 0..r {
            let t = y * r + x;
            if chart[t] == EMPTY || patches[t] == NO_PATCH || index[t] != 0 {
                continue;
            }
            for n in [(x + 1 < r).then(|| t + 1), (y + 1 < r).then(|| t + r)]
                .into_iter()
                .flatten()
            {
                if chart[n] != chart[t] || patches[n] != patches[t] || index[n] != 0 {
                    continue;
                }
                let units = p(t).distance(p(n)) as f64;
                let (a, b) = (coords[t], coords[n]);
                let pixels = ((a[0] - b[0]) as f64).hypot((a[1] - b[1]) as f64);
                if units > 0.0 && pixels.is_finite() {
                    ratios.push(pixels / units);
                }
            }
        }
    }
    ratios.sort_by(f64::total_cmp);
    let median = ratios.get(ratios.len() / 2).copied().unwrap_or(0.0);
    Ok(ScaleFigures {
        edges: ratios.len(),
        sample_pixels_per_unit: median,
        sample_width_units: if median > 0.0 { width as f64 / median } else { 0.0 },
    })
}

/// Mean distance from 5×5 output windows (at seeded places inside one chart,
/// drawn from one sample) to the nearest 5×5 window of that sample's preview
/// turned by the window's rotation; and the number of windows.
fn coherence(
    quilt: &Quilt,
    img: &RgbImage,
    covered: &[bool],
    chart: &[u32],
    index: &[u8],
    previews: &[RgbImage],
) -> Result<(f64, usize)> {
    let r = quilt.resolution;
    let rotations = quilt.rotations()?;
    let steps = match quilt.container().metadata().param("rotations") {
        Some(crate::container::Param::Int(v)) if *v > 0 => *v as usize,
        _ => 72,
    };
    let mut cache: std::collections::BTreeMap<(u8, u8), (Vec<f32>, Vec<u8>)> = Default::default();
    let (mut total, mut count) = (0f64, 0usize);
    let mut k = 0u64;
    while count < 200 && k < 20_000 {
        k += 1;
        let t = (crate::rng::mix64(k) % (r * r) as u64) as usize;
        let (x, y) = (t % r, t / r);
        if x < 2 || y < 2 || x + 2 >= r || y + 2 >= r {
            continue;
        }
        let window: Vec<usize> = (0..25).map(|i| (y + i / 5 - 2) * r + x + i % 5 - 2).collect();
        if !window
            .iter()
            .all(|&w| covered[w] && chart[w] == chart[t] && index[w] == index[t])
        {
            continue;
        }
        let rot = rotations[t];
        let preview = &previews[index[t] as usize];
        let (sw, sh) = (preview.width, preview.height);
        let (maps, valid) = cache.entry((index[t], rot)).or_insert_with(|| {
            rotate_maps(&preview.data, sw, sh, 3, rot as f64 * 360.0 / steps as f64, false)
        });
        let mut best = f64::INFINITY;
        for sy in 2..sh.saturating_sub(2) {
            for sx in 2..sw.saturating_sub(2) {
                let mut ssd = 0f64;
                let mut ok = true;
                for i in 0..25 {
                    let s = (sy + i / 5 - 2) * sw + sx + i % 5 - 2;
                    if valid[s] == 0 {
                        ok = false;
                        break;
                    }
                    for c in 0..3 {
                        ssd += ((maps[s * 3 + c] - img.data[window[i] * 3 + c]) as f64).powi(2);
                    }
                    if ssd >= best {
                        break;
                    }
                }
                if ok && ssd < best {
                    best = ssd;
                }
            }
        }
        if best.is_finite() {
            total += (best / 25.0).sqrt();
            count += 1;
        }
    }
    Ok((total / count.max(1) as f64, count))
}

/// The painting measures of a painted surface (§IV) (`None` for a surface
/// that was not painted): the fraction of F (m0 = 1)
/// covered by foreground texels (texels of the painted sample with m_σ ≥ ½),
/// and the fraction of foreground texels outside F and its transition zone
/// (m0 = 0).
fn painting_measures(
    quilt: &Quilt,
    chart: &[u32],
    samples: &[OpenSample],
) -> Result<Option<PaintingFigures>> {
    let c = quilt.container();
    let (Ok(region), Some(mask_path)) = (c.array("region"), &quilt.sample_mask) else {
        return Ok(None);
    };
    quilt.verify("sample_mask", mask_path)?;
    let m0: Vec<f32> = c.read_array(region)?;
    let (mw, mh) = crate::io::imageio::image_size(mask_path)?;
    let mask = crate::io::imageio::read_sized_mask(mask_path, mw, mh, "")?;
    let coords = quilt.coords()?;
    let (index, painted) = (quilt.sample_index()?, quilt.mask_sample());
    // a generated BTF may be tileable; the synthesis then wraps its mask
    let tileable = samples.get(painted).is_some_and(|s| s.svd.tileable());
    let m = |t: usize| {
        if index[t] as usize != painted {
            return 0.0;
        }
        crate::io::imageio::mask_bilinear(&mask, mw, mh, coords[t].map(f64::from), tileable)
    };
    let (mut f, mut f_covered, mut fg, mut fg_outside) = (0usize, 0usize, 0usize, 0usize);
    for t in 0..m0.len() {
        if chart[t] == EMPTY {
            continue;
        }
        let foreground = m(t) >= 0.5;
        if m0[t] >= 1.0 {
            f += 1;
            f_covered += foreground as usize;
        }
        if foreground {
            fg += 1;
            fg_outside += (m0[t] <= 0.0) as usize;
        }
    }
    Ok(Some(PaintingFigures {
        region_texels: f,
        region_covered_by_foreground: f_covered as f64 / f.max(1) as f64,
        foreground_texels: fg,
        foreground_outside_region_and_transition: fg_outside as f64 / fg.max(1) as f64,
    }))
}
