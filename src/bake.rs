//! `bake`: the decorated surface's preview colour in atlas space (the sample's
//! preview, front-parallel view under head-on light, looked up at each
//! texel's sample coordinate), with the empty gutter filled by dilation so no
//! dark lines appear at chart borders when the texture is mipmapped.

use std::path::{Path, PathBuf};

use crate::container::MemoryBudget;
use crate::factorize::SvdArtifact;
use crate::imageio::{self, PngDepth, RgbImage};
use crate::quilt::{Quilt, NO_PATCH};
use crate::{Error, Result};

/// Whether two paths name the same file, or are equal as text.
fn same_file_or_equal(a: &Path, b: &Path) -> bool {
    a == b || crate::staging::same_file(a, b)
}

/// A sample opened for reading: its `.svd`, and the temporary directory
/// holding it when it was factorized from a colour image.
pub struct OpenSample {
    pub svd: SvdArtifact,
    _tmp: Option<tempfile::TempDir>,
}

/// Opens sample `k` of `quilt` from `path` (a colour image is factorized
/// into a temporary `.svd`); the error names the surface and the sample
/// when the file is gone.
fn open_one(quilt: &Quilt, k: usize, path: &Path, budget: MemoryBudget) -> Result<OpenSample> {
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
    let (svd_path, tmp) = crate::quilt::sample_svd(path, false, &crate::progress::Silent)?;
    Ok(OpenSample {
        svd: SvdArtifact::open(&svd_path, budget)?,
        _tmp: tmp,
    })
}

/// Opens the sample a quilt was tiled with (`sample` overrides the
/// recorded path).
pub fn open_sample(quilt: &Quilt, sample: Option<&Path>, budget: MemoryBudget) -> Result<OpenSample> {
    let path: PathBuf = sample
        .map(Path::to_path_buf)
        .unwrap_or_else(|| quilt.samples[0].clone());
    open_one(quilt, 0, &path, budget)
}

/// Opens every sample a quilt draws from, in [`Quilt::samples`] order
/// (`first` overrides the tiling's sample), and checks that they share one
/// direction set, so their values are comparable.
pub fn open_samples(quilt: &Quilt, first: Option<&Path>, budget: MemoryBudget) -> Result<Vec<OpenSample>> {
    let mut out = vec![open_sample(quilt, first, budget)?];
    for (k, path) in quilt.samples.iter().enumerate().skip(1) {
        let s = open_one(quilt, k, path, budget)?;
        crate::factorize::same_directions(&out[0].svd, &s.svd)?;
        out.push(s);
    }
    Ok(out)
}

/// The atlas-space preview colour of a quilt, `(image, covered mask)`:
/// each texel looks its colour up in the preview of its own sample
/// (`previews` in [`Quilt::samples`] order).
pub fn atlas_colour(quilt: &Quilt, previews: &[RgbImage]) -> Result<(RgbImage, Vec<bool>)> {
    let r = quilt.resolution;
    let coords = quilt.coords()?;
    let patches = quilt.patches()?;
    let index = quilt.sample_index()?;
    if previews.len() != quilt.samples.len() {
        return Err(Error::Config(format!(
            "{} previews for the {} samples of {}",
            previews.len(),
            quilt.samples.len(),
            quilt.container().path().display()
        )));
    }
    let mut data = vec![0f32; r * r * 3];
    let covered: Vec<bool> = patches.iter().map(|&p| p != NO_PATCH).collect();
    for t in 0..r * r {
        if covered[t] {
            let c = imageio::bilinear(&previews[index[t] as usize], coords[t][0], coords[t][1]);
            data[t * 3..t * 3 + 3].copy_from_slice(&c);
        }
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

/// Fills empty texels from their filled neighbours, ring by ring, so
/// mipmapping never blends in the background; what is still empty after
/// `passes` rings gets the mean colour.
pub fn dilate(img: &mut RgbImage, covered: &[bool], passes: usize) {
    let (w, h) = (img.width, img.height);
    let mut filled = covered.to_vec();
    for _ in 0..passes {
        let mut next = filled.clone();
        let mut any = false;
        for y in 0..h {
            for x in 0..w {
                let t = y * w + x;
                if filled[t] {
                    continue;
                }
                let (mut s, mut c) = ([0f32; 3], 0);
                for (dx, dy) in [
                    (-1i32, 0i32),
                    (1, 0),
                    (0, -1),
                    (0, 1),
                    (-1, -1),
                    (1, -1),
                    (-1, 1),
                    (1, 1),
                ] {
                    let (nx, ny) = (x as i32 + dx, y as i32 + dy);
                    if nx < 0 || ny < 0 || nx >= w as i32 || ny >= h as i32 {
                        continue;
                    }
                    let n = ny as usize * w + nx as usize;
                    if filled[n] {
                        for k in 0..3 {
                            s[k] += img.data[n * 3 + k];
                        }
                        c += 1;
                    }
                }
                if c > 0 {
                    for k in 0..3 {
                        img.data[t * 3 + k] = s[k] / c as f32;
                    }
                    next[t] = true;
                    any = true;
                }
            }
        }
        filled = next;
        if !any {
            break;
        }
    }
    let (mut mean, mut n) = ([0f64; 3], 0usize);
    for t in 0..w * h {
        if covered[t] {
            for k in 0..3 {
                mean[k] += img.data[t * 3 + k] as f64;
            }
            n += 1;
        }
    }
    for t in 0..w * h {
        if !filled[t] {
            for k in 0..3 {
                img.data[t * 3 + k] = (mean[k] / n.max(1) as f64) as f32;
            }
        }
    }
}

/// Bakes the quilt's preview colour to `out` (PNG or EXR), gutter dilated.
pub fn bake(quilt_path: &Path, sample: Option<&Path>, out: &Path, budget: MemoryBudget) -> Result<()> {
    let quilt = Quilt::open(quilt_path, budget)?;
    quilt.check_output(out)?;
    if let Some(s) = sample {
        crate::staging::check_output(out, &[("the sample", s)])?;
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
