//! What a finished quilt is turned into: the atlas texture ([`bake`]), a
//! picture of the decorated mesh ([`render`]), files for other tools
//! ([`export`]), quality figures ([`evaluate`], and [`compare`] for any
//! image against its sample) and a look inside any artifact ([`show`]).
//! Each reads `.quilt`/`.gim`/`.svd` artifacts (`compare` reads images) and
//! writes new files; none writes an artifact another stage reads.

pub mod bake;
mod band;
pub mod compare;
pub mod continuation;
pub mod courses;
pub mod evaluate;
pub mod export;
mod ranks;
pub mod render;
pub mod show;
pub(crate) mod texels;

use std::path::{Path, PathBuf};

use crate::artifact::svd::SvdArtifact;
use crate::container::MemoryBudget;
use crate::io::imageio::{self, RgbImage};
use crate::quilt::{Quilt, NO_PATCH};
use crate::{Error, Result};

/// What `bake`, `render` and `evaluate` hold besides the shares of
/// `--memory` they divide among their caches: code and libraries (about 12
/// MB resident on Linux x86-64), a band's or a tile's buffers (about 10 MB
/// for a band of a 4096² atlas) and the allocator's slack. Taken off
/// `--memory` first ([`MemoryBudget::less`]), so that from 64 MiB up they
/// peak within it on Spot 4096² (docs/measurements.md, "Render and export").
pub(crate) const PROGRAM_BYTES: u64 = 24 << 20;

/// Whether two paths name the same file, or are equal as text.
fn same_file_or_equal(a: &Path, b: &Path) -> bool {
    a == b || crate::io::staging::same_file(a, b)
}

/// A sample opened for reading: its `.svd`, and the temporary directory
/// holding it when it was factorized from a colour image.
pub struct OpenSample {
    pub svd: SvdArtifact,
    _tmp: Option<tempfile::TempDir>,
}

/// Opens sample `k` of `quilt` from `path` with `budget` for its decoded
/// chunks (a colour image is factorized into a temporary `.svd` within
/// `memory`, the command's `--memory`: nothing else is cached yet); the
/// error names the surface and the sample when the file is gone.
fn open_one(quilt: &Quilt, k: usize, path: &Path, [budget, memory]: [MemoryBudget; 2]) -> Result<OpenSample> {
    if !path.exists() {
        let how = if k == 0 && same_file_or_equal(path, &quilt.samples[0]) {
            "put it back, or give --sample".to_string()
        } else if k == 0 {
            "check the --sample path".to_string()
        } else {
            format!("it was painted in ('sample_{k}'); put it back")
        };
        return Err(Error::input(
            quilt.container().path(),
            format!("its sample {} is gone: {how}", path.display()),
        ));
    }
    let role = if k == 0 {
        "sample".to_string()
    } else {
        format!("sample_{k}")
    };
    quilt.verify(&role, path)?;
    let (svd_path, tmp) = crate::quilt::sample_svd(path, false, memory, &crate::progress::Silent)?;
    Ok(OpenSample {
        svd: SvdArtifact::open(&svd_path, budget)?,
        _tmp: tmp,
    })
}

/// Opens the sample a quilt was tiled with (`sample` overrides the
/// recorded path); `budgets`: its decoded chunks' and the command's
/// `--memory` ([`open_one`]).
pub fn open_sample(quilt: &Quilt, sample: Option<&Path>, budgets: [MemoryBudget; 2]) -> Result<OpenSample> {
    let path: PathBuf = sample
        .map(Path::to_path_buf)
        .unwrap_or_else(|| quilt.samples[0].clone());
    open_one(quilt, 0, &path, budgets)
}

/// Opens every sample a quilt draws from, in [`Quilt::samples`] order
/// (`first` overrides the tiling's sample), and checks that they share one
/// direction set, so their values are comparable. `budgets`: each
/// sample's decoded chunks' and the command's `--memory` ([`open_one`]).
pub fn open_samples(
    quilt: &Quilt,
    first: Option<&Path>,
    budgets: [MemoryBudget; 2],
) -> Result<Vec<OpenSample>> {
    let mut out = vec![open_sample(quilt, first, budgets)?];
    for (k, path) in quilt.samples.iter().enumerate().skip(1) {
        let s = open_one(quilt, k, path, budgets)?;
        crate::artifact::svd::same_directions(&out[0].svd, &s.svd)?;
        out.push(s);
    }
    Ok(out)
}

/// Rows an output command reads and computes at a time: one row of the
/// quilt's chunks, so a band decodes each chunk once.
pub(crate) const BAND_ROWS: usize = crate::artifact::gim::TILE;

/// The atlas-space preview colour of a quilt, `(image, covered mask)`:
/// each texel looks its colour up in the preview of its own sample
/// (`previews` in [`Quilt::samples`] order). Built band by band, so only
/// the image itself is held whole.
pub fn atlas_colour(quilt: &Quilt, previews: &[RgbImage]) -> Result<(RgbImage, Vec<bool>)> {
    let r = quilt.resolution;
    let mut data = Vec::with_capacity(r * r * 3);
    let mut covered = Vec::with_capacity(r * r);
    for y0 in (0..r).step_by(BAND_ROWS) {
        let (rows, c) = colour_rows(quilt, previews, y0, (y0 + BAND_ROWS).min(r))?;
        data.extend_from_slice(&rows);
        covered.extend_from_slice(&c);
    }
    Ok((
        RgbImage {
            width: r,
            height: r,
            data,
        },
        covered,
    ))
}

/// Rows `y0..y1` of [`atlas_colour`]: RGB values row-major (0 where no
/// patch covers the texel) and the covered mask.
pub fn colour_rows(
    quilt: &Quilt,
    previews: &[RgbImage],
    y0: usize,
    y1: usize,
) -> Result<(Vec<f32>, Vec<bool>)> {
    colour_region(quilt, previews, 0, y0, quilt.resolution, y1 - y0)
}

/// The atlas region `(x0, y0, w, h)` of [`atlas_colour`], row-major.
pub fn colour_region(
    quilt: &Quilt,
    previews: &[RgbImage],
    x0: usize,
    y0: usize,
    w: usize,
    h: usize,
) -> Result<(Vec<f32>, Vec<bool>)> {
    if previews.len() != quilt.samples.len() {
        return Err(Error::Config(format!(
            "{} previews for the {} samples of {}",
            previews.len(),
            quilt.samples.len(),
            quilt.container().path().display()
        )));
    }
    let coords = quilt.coord_region(x0, y0, w, h)?;
    let patches = quilt.patch_region(x0, y0, w, h)?;
    let index = quilt.sample_region(x0, y0, w, h)?;
    let mut data = vec![0f32; w * h * 3];
    let covered: Vec<bool> = patches.iter().map(|&p| p != NO_PATCH).collect();
    for t in 0..w * h {
        if covered[t] {
            let c = imageio::bilinear(&previews[index[t] as usize], coords[t][0], coords[t][1]);
            data[t * 3..t * 3 + 3].copy_from_slice(&c);
        }
    }
    Ok((data, covered))
}
