//! `ingest` and `export-btf`: BTF image folders (Bonn/UTIA names or a CSV
//! manifest) into a BTF artifact, and BTF images back out.
//!
//! Ingest streams one direction band at a time: the images of a band are
//! decoded (in parallel), cut into texel tiles, encoded (in parallel) and
//! written in a fixed order, so memory is bounded by the band, not the BTF,
//! and the output does not depend on the thread count.

use std::path::{Path, PathBuf};

use half::f16;
use half::slice::HalfFloatSliceExt;
use rayon::prelude::*;

use crate::artifact::btf::{Angles, Btf, BtfLayout, BtfWriter};
use crate::container::{codec, MemoryBudget, Param, DEFAULT_ZSTD_LEVEL};
use crate::io::imageio::{self, RgbImage};
use crate::io::naming::{self, PairFile};
use crate::progress::Progress;
use crate::{Error, Result};

/// Options of [`ingest`].
#[derive(Clone, Debug)]
pub struct IngestConfig {
    /// Memory budget: bounds the images held at once (one band).
    pub memory: MemoryBudget,
    /// Texel tile edge of the chunks.
    pub tile: usize,
    /// zstd level.
    pub level: i32,
}

impl Default for IngestConfig {
    fn default() -> Self {
        IngestConfig {
            memory: MemoryBudget::default(),
            tile: crate::artifact::btf::DEFAULT_TILE,
            level: DEFAULT_ZSTD_LEVEL,
        }
    }
}

/// What [`ingest`] read.
#[derive(Clone, Debug)]
pub struct IngestReport {
    pub width: usize,
    pub height: usize,
    pub views: usize,
    pub lights: usize,
}

/// Lists the images of `input`: a folder of Bonn/UTIA-named images, or a CSV
/// manifest (`file,theta_v,phi_v,theta_l,phi_l`).
pub fn list_inputs(input: &Path) -> Result<Vec<PairFile>> {
    if input.is_dir() {
        naming::scan_folder(input)
    } else if input.extension().is_some_and(|e| e.eq_ignore_ascii_case("csv")) {
        naming::read_manifest(input)
    } else if input.exists() {
        Err(Error::input(
            input,
            "expected a folder of BTF images or a .csv manifest",
        ))
    } else {
        Err(Error::io(
            input,
            std::io::Error::new(std::io::ErrorKind::NotFound, "no such file or folder"),
        ))
    }
}

/// Builds a BTF artifact at `out` from the images listed by `input`.
/// Every problem with the inputs (names, duplicate or missing directions,
/// differing sizes, unreadable images) is found before anything is written,
/// except unreadable pixel data, which aborts the write and leaves no output.
pub fn ingest(input: &Path, out: &Path, cfg: &IngestConfig, progress: &dyn Progress) -> Result<IngestReport> {
    let files = list_inputs(input)?;
    let mut inputs = vec![("the input", input)];
    inputs.extend(files.iter().map(|f| ("an input image", f.path.as_path())));
    crate::io::staging::check_output(out, &inputs)?;
    let (views, lights, grid) = naming::organise_pairs(input, &files)?;
    // all images must share one size: check headers before streaming
    let (width, height) = imageio::image_size(&files[0].path)?;
    for f in &files[1..] {
        let size = imageio::image_size(&f.path)?;
        if size != (width, height) {
            return Err(Error::input(
                &f.path,
                format!(
                    "is {}×{} but {} is {width}×{height}: all images of a BTF must have the same size",
                    size.0,
                    size.1,
                    files[0].path.display()
                ),
            ));
        }
    }
    let mut layout = BtfLayout::new(width, height, views.clone(), lights.clone());
    layout.tile = cfg.tile.max(1);
    // a band's images (f32 while decoding) must fit in a quarter of the budget
    let per_image = (width * height * 3 * 4) as u64;
    let [band, ..] = cfg.memory.split([1, 1, 1, 1]);
    let fit = (band.bytes() / per_image.max(1)).max(1) as usize;
    layout.band = layout.band.min(fit);

    let mut writer = BtfWriter::create(out, layout.clone())?;
    writer.container().set_level(cfg.level);
    writer
        .container()
        .set_param("source", Param::Text(input.display().to_string()));
    let (ntx, nty) = layout.tiles();
    progress.begin("ingest", layout.pairs() as u64);
    for band in 0..layout.bands() {
        let p0 = band * layout.band;
        let p1 = (p0 + layout.band).min(layout.pairs());
        let images: Vec<RgbImage> = (p0..p1)
            .into_par_iter()
            .map(|p| {
                let f = &files[grid[p]];
                // the budget sizes the bands (at least one image each), so
                // one image is held to the default decode bound, not to it
                let img = imageio::read_rgb(&f.path)?;
                if (img.width, img.height) != (width, height) {
                    return Err(Error::input(
                        &f.path,
                        format!(
                            "decoded size {}×{} differs from its header",
                            img.width, img.height
                        ),
                    ));
                }
                Ok(img)
            })
            .collect::<Result<_>>()?;
        let tiles: Vec<(usize, usize)> = (0..nty).flat_map(|ty| (0..ntx).map(move |tx| (tx, ty))).collect();
        let encoded: Vec<_> = tiles
            .par_iter()
            .map(|&(tx, ty)| {
                let chunk = tile_band_values(&layout, &images, tx, ty);
                codec::encode(&chunk, cfg.level)
            })
            .collect();
        for (&(tx, ty), e) in tiles.iter().zip(encoded) {
            writer.write_encoded(tx, ty, band, e)?;
        }
        progress.advance((p1 - p0) as u64);
    }
    writer.finish()?;
    progress.end();
    Ok(IngestReport {
        width,
        height,
        views: views.len(),
        lights: lights.len(),
    })
}

/// The chunk `[y][x][pair][rgb]` of tile (tx, ty) from a band's images.
fn tile_band_values(layout: &BtfLayout, images: &[RgbImage], tx: usize, ty: usize) -> Vec<f16> {
    let x0 = tx * layout.tile;
    let y0 = ty * layout.tile;
    let w = layout.tile.min(layout.width - x0);
    let h = layout.tile.min(layout.height - y0);
    let mut values = Vec::with_capacity(w * h * images.len() * 3);
    for y in y0..y0 + h {
        for x in x0..x0 + w {
            let i = (y * layout.width + x) * 3;
            for img in images {
                values.extend_from_slice(&img.data[i..i + 3]);
            }
        }
    }
    let mut out = vec![f16::ZERO; values.len()];
    out.convert_from_f32_slice(&values);
    out
}

/// Output format of exported images (`export-btf --format`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, clap::ValueEnum)]
pub enum ImageFormat {
    /// 16-bit sRGB PNG (lossy).
    Png,
    /// OpenEXR with half channels: exact for the stored f16 values.
    #[default]
    Exr,
}

impl ImageFormat {
    /// The file extension.
    pub fn ext(self) -> &'static str {
        match self {
            ImageFormat::Png => "png",
            ImageFormat::Exr => "exr",
        }
    }

    /// `png` or `exr` (case-insensitive; the names clap accepts).
    pub fn parse(s: &str) -> Result<ImageFormat> {
        <Self as clap::ValueEnum>::from_str(s, true)
            .map_err(|_| Error::Config(format!("image format '{s}': expected png or exr")))
    }
}

/// One direction pair of a BTF as an image.
pub fn pair_image(btf: &Btf, view: Angles, light: Angles) -> Result<RgbImage> {
    let p = btf.find_pair(view, light)?;
    let l = btf.layout();
    Ok(RgbImage {
        width: l.width,
        height: l.height,
        data: btf.read_pair_images(p..p + 1)?,
    })
}

/// Writes every (view, light) image of a BTF into `dir`, named the way
/// [`ingest`] reads (`btf_tlΘ_plΦ_tvΘ_pvΦ.ext`), plus a `manifest.csv`.
/// The folder is staged and renamed into place whole; an existing `dir` must
/// be empty or a previous export (it holds a `manifest.csv`), which is
/// replaced. Returns the number of images written.
pub fn export_all(
    btf: &Btf,
    dir: &Path,
    format: ImageFormat,
    memory: MemoryBudget,
    progress: &dyn Progress,
) -> Result<usize> {
    crate::io::staging::check_output_dir(dir, &["manifest.csv"], &[("the BTF", btf.container().path())])?;
    // the folder is built whole beside `dir` and renamed into place at the end
    let stage = crate::io::staging::StagedDir::new(dir, Some("manifest.csv"))?;
    let l = btf.layout();
    let per_image = (l.width * l.height * 3 * 4) as u64;
    let [images, ..] = memory.split([1, 1, 1, 1]);
    let group = ((images.bytes() / per_image.max(1)) as usize).clamp(1, l.band);
    progress.begin("export", l.pairs() as u64);
    let mut listed = Vec::with_capacity(l.pairs());
    let mut p0 = 0;
    while p0 < l.pairs() {
        // stay inside one band so each group decodes its chunks once
        let band_end = (p0 / l.band + 1) * l.band;
        let p1 = (p0 + group).min(band_end).min(l.pairs());
        let data = btf.read_pair_images(p0..p1)?;
        let texels = l.width * l.height;
        let names: Vec<(PathBuf, PairFile)> = (p0..p1)
            .map(|p| {
                let view = l.views[p / l.lights.len()];
                let light = l.lights[p % l.lights.len()];
                let name = naming::format_pair_name("btf", view, light, format.ext());
                let path = stage.path().join(&name);
                (path.clone(), PairFile { path, view, light })
            })
            .collect();
        names.par_iter().enumerate().try_for_each(|(k, (path, _))| {
            let img = RgbImage {
                width: l.width,
                height: l.height,
                data: data[k * texels * 3..(k + 1) * texels * 3].to_vec(),
            };
            match format {
                ImageFormat::Png => imageio::write_png(path, &img, imageio::PngDepth::Sixteen),
                ImageFormat::Exr => imageio::write_exr(path, &img, true),
            }
        })?;
        listed.extend(names.into_iter().map(|(_, f)| f));
        progress.advance((p1 - p0) as u64);
        p0 = p1;
    }
    naming::write_manifest(&stage.path().join("manifest.csv"), &listed)?;
    stage.commit()?;
    progress.end();
    Ok(listed.len())
}
