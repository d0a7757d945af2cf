//! `generate-btf`: streams a synthetic BTF to disk block by block.
//!
//! The texels are cut into blocks (64×64); for each block the light-dependent
//! work (shadow maps) is prepared once, then views are rendered in parallel in
//! small groups, cut into the container's texel tiles, encoded in parallel and
//! written in a fixed order (block, view, tile). Memory is bounded by one
//! view group of one block, whatever the BTF size, and the bytes written do
//! not depend on the thread count.

use std::path::Path;
use std::time::Instant;

use half::f16;
use half::slice::HalfFloatSliceExt;
use rayon::prelude::*;

use super::material::{Family, Imperfection, MaterialParams, Mesostructure};
use super::render::{direction, BlockRenderer};
use crate::artifact::btf::{Angles, BtfLayout, BtfWriter};
use crate::container::{codec, human_bytes, MemoryBudget, Param, DEFAULT_ZSTD_LEVEL};
use crate::progress::Progress;
use crate::{io::imageio, Error, Result};

/// Options of [`generate_btf`].
#[derive(Clone, Debug)]
pub struct GenerateConfig {
    pub family: Family,
    pub imperfection: Imperfection,
    pub width: usize,
    pub height: usize,
    pub views: Vec<Angles>,
    pub lights: Vec<Angles>,
    pub seed: u64,
    /// Bounds the rendered values held at once.
    pub memory: MemoryBudget,
    /// zstd level.
    pub level: i32,
    /// Edge of the render blocks in texels (a multiple of the tile edge).
    pub block: usize,
}

impl Default for GenerateConfig {
    fn default() -> Self {
        GenerateConfig {
            family: Family::Bricks,
            imperfection: Imperfection::None,
            width: 128,
            height: 128,
            views: crate::artifact::btf::default_grid(),
            lights: crate::artifact::btf::default_grid(),
            seed: 1,
            memory: MemoryBudget::default(),
            level: DEFAULT_ZSTD_LEVEL,
            block: 64,
        }
    }
}

impl GenerateConfig {
    /// Largest side of a generated BTF in texels.
    pub const MAX_SIZE: usize = 1 << 16;

    /// Checks the numbers a user gives, naming what is wrong.
    pub fn validate(&self) -> Result<()> {
        if self.width == 0 || self.height == 0 || self.width > Self::MAX_SIZE || self.height > Self::MAX_SIZE
        {
            return Err(Error::Config(format!(
                "BTF size {}×{} must be 1..={} texels per side",
                self.width,
                self.height,
                Self::MAX_SIZE
            )));
        }
        if self.views.is_empty() || self.lights.is_empty() {
            return Err(Error::Config(format!(
                "{} view and {} light directions: give at least one of each",
                self.views.len(),
                self.lights.len()
            )));
        }
        if self.block == 0 {
            return Err(Error::Config(
                "render block of 0 texels: must be at least 1".into(),
            ));
        }
        crate::container::check_level(self.level)
    }
}

/// What [`generate_btf`] made.
#[derive(Clone, Debug)]
pub struct GenerateReport {
    pub width: usize,
    pub height: usize,
    pub pairs: usize,
    pub raw_bytes: u64,
    pub stored_bytes: u64,
    pub seconds: f64,
    /// The imperfection mask PNG, when one was written.
    pub mask: Option<std::path::PathBuf>,
}

impl std::fmt::Display for GenerateReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{}×{} texels × {} direction pairs, raw {} f16, stored {} (ratio {:.2}), {:.1} s, {:.0} MB/s raw",
            self.width,
            self.height,
            self.pairs,
            human_bytes(self.raw_bytes),
            human_bytes(self.stored_bytes),
            self.raw_bytes as f64 / self.stored_bytes.max(1) as f64,
            self.seconds,
            self.raw_bytes as f64 / 1e6 / self.seconds.max(1e-9)
        )?;
        if let Some(m) = &self.mask {
            write!(f, "; imperfection mask {}", m.display())?;
        }
        Ok(())
    }
}

/// The path of the imperfection mask written beside a generated BTF:
/// `sample.btf` → `sample.mask.png`.
pub fn mask_path(out: &Path) -> std::path::PathBuf {
    out.with_extension("mask.png")
}

/// Generates a synthetic BTF into `out` (and its imperfection mask beside it).
pub fn generate_btf(cfg: &GenerateConfig, out: &Path, progress: &dyn Progress) -> Result<GenerateReport> {
    let start = Instant::now();
    cfg.validate()?;
    let mut layout = BtfLayout::new(cfg.width, cfg.height, cfg.views.clone(), cfg.lights.clone());
    layout.band = cfg.lights.len(); // one view per band: a chunk is one view's lights
    let block = (cfg.block.max(layout.tile) / layout.tile) * layout.tile;
    let mut writer = BtfWriter::create(out, layout.clone())?;
    writer.container().set_level(cfg.level);
    writer.container().set_seed(cfg.seed);
    writer
        .container()
        .set_param("generator", Param::Text("btfquilt generate-btf".into()));
    writer
        .container()
        .set_param("family", Param::Text(cfg.family.name().into()));
    writer
        .container()
        .set_param("imperfection", Param::Text(cfg.imperfection.name().into()));

    let meso = Mesostructure::generate(&MaterialParams {
        family: cfg.family,
        imperfection: cfg.imperfection,
        width: cfg.width,
        height: cfg.height,
        seed: cfg.seed,
    });
    let lights: Vec<[f32; 3]> = cfg.lights.iter().map(|a| direction(a.theta, a.phi)).collect();
    let views: Vec<[f32; 3]> = cfg.views.iter().map(|a| direction(a.theta, a.phi)).collect();
    let nl = lights.len();

    // views rendered at once: bounded by a quarter of the budget (f32 values)
    let per_view = (block * block * nl * 3 * 4) as u64;
    let [rendered, ..] = cfg.memory.split([1, 1, 1, 1]);
    let group = ((rendered.bytes() / per_view.max(1)) as usize).clamp(1, 16);

    let nbx = cfg.width.div_ceil(block);
    let nby = cfg.height.div_ceil(block);
    progress.begin("generate", (nbx * nby * views.len()) as u64);
    // Rendering and encoding run on the rayon pool while a writer thread
    // appends the previous group's chunks; the bounded channel keeps at most
    // two groups in flight and the write order fixed.
    let (send, receive) = std::sync::mpsc::sync_channel::<Vec<(usize, usize, usize, codec::EncodedChunk)>>(2);
    let stored = std::thread::scope(|scope| -> Result<u64> {
        let writing = scope.spawn(move || -> Result<(BtfWriter, u64)> {
            let mut stored = 0u64;
            for group in receive {
                for (tx, ty, v, e) in group {
                    stored += e.bytes.len() as u64;
                    writer.write_encoded(tx, ty, v, e)?;
                }
            }
            Ok((writer, stored))
        });
        'blocks: for by in 0..nby {
            for bx in 0..nbx {
                let (x0, y0) = (bx * block, by * block);
                let bw = block.min(cfg.width - x0);
                let bh = block.min(cfg.height - y0);
                let renderer = BlockRenderer::new(&meso, x0, y0, bw, bh, &lights);
                for v0 in (0..views.len()).step_by(group) {
                    let v1 = (v0 + group).min(views.len());
                    let encoded: Vec<Vec<_>> = (v0..v1)
                        .into_par_iter()
                        .map(|v| {
                            let mut values = vec![0f32; bw * bh * nl * 3];
                            renderer.render_view(views[v], &mut values);
                            block_tiles(&layout, x0, y0, bw, bh, nl, &values)
                                .into_par_iter()
                                .map(|(tx, ty, chunk)| (tx, ty, v, codec::encode(&chunk, cfg.level)))
                                .collect()
                        })
                        .collect();
                    if send.send(encoded.into_iter().flatten().collect()).is_err() {
                        break 'blocks; // the writer failed: its error is reported below
                    }
                    progress.advance((v1 - v0) as u64);
                }
            }
        }
        drop(send);
        let (writer, stored) = writing.join().expect("the writer thread does not panic")?;
        writer.finish()?;
        Ok(stored)
    })?;
    progress.end();
    let mask = if cfg.imperfection != Imperfection::None {
        let path = mask_path(out);
        imageio::write_mask_png(&path, cfg.width, cfg.height, &meso.mask)?;
        Some(path)
    } else {
        None
    };
    Ok(GenerateReport {
        width: cfg.width,
        height: cfg.height,
        pairs: layout.pairs(),
        raw_bytes: layout.raw_bytes(),
        stored_bytes: stored,
        seconds: start.elapsed().as_secs_f64(),
        mask,
    })
}

/// Cuts a block's rendered values `[y][x][light][rgb]` into the container's
/// tiles (tile x, tile y, f16 values `[y][x][light][rgb]`), in row-major tile order.
fn block_tiles(
    layout: &BtfLayout,
    x0: usize,
    y0: usize,
    bw: usize,
    bh: usize,
    nl: usize,
    values: &[f32],
) -> Vec<(usize, usize, Vec<f16>)> {
    let t = layout.tile;
    let mut out = Vec::new();
    for ty0 in (0..bh).step_by(t) {
        for tx0 in (0..bw).step_by(t) {
            let tw = t.min(bw - tx0);
            let th = t.min(bh - ty0);
            let row_len = tw * nl * 3;
            let mut chunk = vec![f16::ZERO; th * row_len];
            for (y, out) in (ty0..ty0 + th).zip(chunk.chunks_exact_mut(row_len)) {
                let start = (y * bw + tx0) * nl * 3;
                out.convert_from_f32_slice(&values[start..start + row_len]);
            }
            out.push(((x0 + tx0) / t, (y0 + ty0) / t, chunk));
        }
    }
    out
}
