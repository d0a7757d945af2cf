//! `factorize`: out-of-core randomized SVD of a BTF into geometry maps and
//! eigen point appearance functions (Liu et al. 2004, as used by Zhou et al.),
//! plus the 72 rotated copies of the geometry maps used by patch matching.
//!
//! The BTF is the matrix A with one row per texel and one column per
//! (direction pair, colour channel). A ≈ Σ_{i≤n} g_i p_iᵀ with g_i = σ_i u_i
//! (the geometry maps) and p_i = v_i (the appearance functions), computed by
//! randomized subspace iteration (Halko, Martinsson & Tropp 2011, Alg. 4.4):
//!
//! ```text
//! Y = A Ω                    (Ω: n × k Gaussian, k = n_terms + oversampling)
//! Q = qr(Y)
//! repeat q times:  Z = qr(Aᵀ Q);  Q = qr(A Z)
//! Bᵀ = Aᵀ Q                  (n × k)
//! Bᵀ = U' Σ V'ᵀ              (small dense SVD)  ⇒  A ≈ (Q V') Σ U'ᵀ
//! ```
//!
//! Every product with A is one streaming pass over the BTF's chunks (texel
//! tile × direction band): `A M` sums over bands inside each tile, `Aᵀ Q` sums
//! over tiles inside each band. Each sum runs sequentially in a fixed order
//! inside one task, and tasks are independent, so the result does not depend
//! on the thread count. Memory: one chunk per worker (chunks are cached only
//! when the whole BTF fits half the budget), the factors on the columns' side
//! (O(columns·k)), and the tall ones (O(texels·k)) held whole only when they
//! fit what is left, else kept in scratch files beside the output (`tall`).
//! One extra pass measures ‖A − A_n‖_F / ‖A‖_F.

use std::path::{Path, PathBuf};
use std::time::Instant;

use half::f16;
use half::slice::HalfFloatSliceExt;
use rayon::prelude::*;

use crate::artifact::btf::{Angles, Btf, BtfLayout, BtfWriter};
use crate::artifact::svd::SvdArtifact;
use crate::container::{codec, ArrayId, ArraySpec, ContainerWriter, DType, MemoryBudget, Param};
use crate::dense::{self, Matrix};
use crate::io::imageio::{self, RgbImage};
use crate::math;
use crate::progress::Progress;
use crate::{Error, Result};

mod maps;
mod rotate;
mod stream;
mod tall;
use maps::Maps;
pub use rotate::*;
use stream::MatrixStream;
use tall::{beside, orth_within, Stored, Tall};

pub use crate::artifact::svd::KIND;

/// The number of rotated copies of the geometry maps (5° steps).
pub const DEFAULT_ROTATIONS: usize = 72;
/// Edge of the spatial chunks of the `.svd` arrays.
const SVD_TILE: u64 = 64;
/// What `factorize` holds besides its chunk cache and the tall matrices
/// (the program itself, a chunk per worker), taken off `--memory` before
/// their share (at most half of it).
const PROGRAM_BYTES: u64 = 24 << 20;

/// Options of [`factorize`].
#[derive(Clone, Debug)]
pub struct FactorizeConfig {
    /// Number of terms n; `None` = 40, or fewer when the matrix is smaller.
    pub terms: Option<usize>,
    /// Extra random directions beyond n (Halko et al.'s p).
    pub oversampling: usize,
    /// Power (subspace) iterations q.
    pub power_iterations: usize,
    /// Seed of the random test matrix Ω.
    pub seed: u64,
    /// Budget for cached chunks.
    pub memory: MemoryBudget,
    /// Rotated copies of the geometry maps (0 for none).
    pub rotations: usize,
    /// Whether the sample wraps around (rotated copies sample it toroidally
    /// and are valid everywhere) or not (texels rotated from outside the sample
    /// are marked invalid).
    pub tileable: bool,
    /// zstd level.
    pub level: i32,
}

impl Default for FactorizeConfig {
    fn default() -> Self {
        FactorizeConfig {
            terms: None,
            oversampling: 10,
            power_iterations: 2,
            seed: 1,
            memory: MemoryBudget::default(),
            rotations: DEFAULT_ROTATIONS,
            tileable: false,
            level: crate::container::DEFAULT_ZSTD_LEVEL,
        }
    }
}

impl FactorizeConfig {
    /// Most rotated copies: a decorated surface stores a texel's rotation
    /// index in a byte.
    pub const MAX_ROTATIONS: usize = 256;
    /// Most power iterations (each is two more passes over the BTF; Halko et
    /// al. find q = 1–2 enough for slowly decaying spectra).
    pub const MAX_POWER_ITERATIONS: usize = 32;

    /// Checks the numbers a user gives, naming the command-line flag.
    pub fn validate(&self) -> Result<()> {
        if self.terms == Some(0) {
            return Err(Error::Config("--terms 0: must be at least 1".into()));
        }
        if self.rotations > Self::MAX_ROTATIONS {
            return Err(Error::Config(format!(
                "--rotations {}: at most {} (a surface stores a rotation index in a byte)",
                self.rotations,
                Self::MAX_ROTATIONS
            )));
        }
        if self.power_iterations > Self::MAX_POWER_ITERATIONS {
            return Err(Error::Config(format!(
                "--power-iterations {}: at most {} (each is two passes over the BTF)",
                self.power_iterations,
                Self::MAX_POWER_ITERATIONS
            )));
        }
        crate::container::check_level(self.level)
    }
}

/// What [`factorize`] made.
#[derive(Clone, Debug)]
pub struct FactorizeReport {
    pub rows: usize,
    pub columns: usize,
    pub terms: usize,
    pub relative_error: f64,
    pub passes: usize,
    /// Raw f16 bytes of the BTF read by each pass.
    pub bytes_per_pass: u64,
    pub seconds: f64,
    /// Seconds spent in the streaming passes (decode + products).
    pub pass_seconds: f64,
    pub singular_values: Vec<f64>,
}

impl std::fmt::Display for FactorizeReport {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} × {} matrix, {} terms, relative Frobenius error {:.5}, {} passes of {:.2} GB in {:.1} s ({:.2} GB/s per pass), total {:.1} s",
            self.rows,
            self.columns,
            self.terms,
            self.relative_error,
            self.passes,
            self.bytes_per_pass as f64 / 1e9,
            self.pass_seconds,
            self.bytes_per_pass as f64 * self.passes as f64 / 1e9 / self.pass_seconds.max(1e-9),
            self.seconds
        )
    }
}

/// Whether `path` names a plain image rather than an artifact.
pub fn is_image_path(path: &Path) -> bool {
    imageio::is_image_path(path)
}

/// Writes a colour image as a BTF with one view and one light (both along
/// the normal): the path by which colour samples enter every stage. The
/// image is read a row of tiles at a time ([`imageio::each_rgb_band`]: an
/// 8- or 16-bit PNG is never held whole; other images are held to
/// `budget` decoded).
pub fn image_to_btf(image: &Path, out: &Path, budget: MemoryBudget) -> Result<()> {
    let (width, height) = imageio::declared_rgb_size(image)?;
    let head_on = Angles { theta: 0.0, phi: 0.0 };
    let layout = BtfLayout::new(width, height, vec![head_on], vec![head_on]);
    let mut w = BtfWriter::create(out, layout.clone())?;
    let (ntx, tile) = (layout.tiles().0, layout.tile);
    imageio::each_rgb_band(image, budget.bytes(), tile, |y0, rows| {
        let h = rows.len() / (width * 3);
        for tx in 0..ntx {
            let x0 = tx * tile;
            let mut v = Vec::new();
            for y in 0..h {
                for x in x0..(x0 + tile).min(width) {
                    let i = (y * width + x) * 3;
                    v.extend(rows[i..i + 3].iter().map(|&c| f16::from_f32(c)));
                }
            }
            w.write_tile_band(tx, y0 / tile, 0, &v)?;
        }
        Ok(())
    })?;
    w.finish()
}

/// Factorizes the BTF (or colour image) at `input` into the `.svd` artifact
/// `out`. The result is the same bytes on every machine and thread count
/// (see [`crate::dense`]).
pub fn factorize(
    input: &Path,
    out: &Path,
    cfg: &FactorizeConfig,
    progress: &dyn Progress,
) -> Result<FactorizeReport> {
    let start = Instant::now();
    cfg.validate()?;
    crate::io::staging::check_output(out, &[("the input", input)])?;
    let _tmp_dir;
    let (btf_path, source_kind): (PathBuf, &str) = if is_image_path(input) {
        let dir = tempfile::tempdir().map_err(|e| Error::io(std::env::temp_dir(), e))?;
        let p = dir.path().join("image.btf");
        image_to_btf(input, &p, cfg.memory)?;
        _tmp_dir = dir;
        (p, "image")
    } else {
        (input.to_path_buf(), "btf")
    };
    let btf = Btf::open(&btf_path, MemoryBudget(0))?;
    let raw: u64 = btf
        .container()
        .metadata()
        .arrays
        .iter()
        .map(|a| a.raw_bytes())
        .sum();
    let (m, n) = (btf.layout().width * btf.layout().height, btf.layout().pairs() * 3);
    let max_rank = m.min(n);
    let terms = match cfg.terms {
        Some(t) if t == 0 || t > max_rank => {
            return Err(Error::Config(format!(
                "--terms {t}: {} is a {m} × {n} matrix (texels × direction pairs·3), so 1..={max_rank} terms are possible",
                input.display()
            )))
        }
        Some(t) => t,
        None => 40.min(max_rank),
    };
    let k = (terms + cfg.oversampling).min(max_rank);
    // the tall m × k sketch and its Q are held whole when their QR (12
    // bytes an entry) fits what the program, Ω or Z (n × k in f32) and the
    // chunk cache leave, else stored beside the output and factored a panel
    // of columns at a time; the small n × k ones likewise
    let share_beside = |cache: MemoryBudget| {
        (cfg.memory)
            .less(PROGRAM_BYTES + 4 * (n * k) as u64)
            .bytes()
            .saturating_sub(cache.bytes())
    };
    // chunks are cached across passes only if the whole BTF fits half the
    // budget and the tall factors fit beside it: a cache that would push
    // them to scratch in small pieces costs more than it saves
    let [half, _] = cfg.memory.split([1, 1]);
    let cache = if raw <= half.bytes() && 12 * (m * k) as u64 <= share_beside(half) {
        half
    } else {
        MemoryBudget(0)
    };
    let btf = if cache.bytes() > 0 {
        Btf::open(&btf_path, cache)?
    } else {
        btf
    };
    let stream = MatrixStream::new(&btf)?;
    let passes = 3 + 2 * cfg.power_iterations;
    let pass_jobs = |rowwise: bool| if rowwise { stream.tiles.len() } else { stream.bands.len() } as u64;
    progress.begin(
        "factorize",
        (2 + cfg.power_iterations) as u64 * pass_jobs(true)
            + (1 + cfg.power_iterations) as u64 * pass_jobs(false),
    );
    let t_pass = Instant::now();
    let omega = Matrix::from_fn(n, k, |i, j| {
        crate::rng::gaussian(cfg.seed, (i * k + j) as u64) as f32
    });
    let share = share_beside(cache);
    let held = 12 * (m * k) as u64 <= share;
    let mut store = None;
    let sketch = |by: &Matrix, reuse: &mut Option<Stored>| -> Result<Tall> {
        if held {
            return Ok(Tall::Held(tall::orth(stream.times(by, progress)?)));
        }
        // a block's rows in f32 and a column piece in f64: an eighth of the share
        let block_rows = (share / 8 / (4 * k as u64 + 8)) as usize;
        let mut s = match reuse.take() {
            Some(s) => s,
            None => Stored::over_tiles(&beside(out, "q"), &stream.tiles, k, block_rows)?,
        };
        stream.times_into(by, &mut s, progress)?;
        s.orthonormalize(share - share / 8)?;
        Ok(Tall::Stored(s))
    };
    let mut q = sketch(&omega, &mut store)?;
    drop(omega);
    for _ in 0..cfg.power_iterations {
        let z = orth_within(
            stream.transpose_times(&mut q, progress)?,
            share,
            &beside(out, "z"),
        )?;
        if let Tall::Stored(s) = q {
            store = Some(s);
        } else {
            drop(q);
        }
        q = sketch(&z, &mut store)?;
    }
    let bt = stream.transpose_times(&mut q, progress)?; // n × k
    let mut pass_seconds = t_pass.elapsed().as_secs_f64();
    // Bᵀ = U_b S V_bᵀ (column-major U_b: n × k, V_b: k × k)
    let svd = dense::thin_svd(bt.column_major(), n, k);
    drop(bt);
    let sigma = svd.sigma;
    if let Some(s) = sigma.iter().find(|s| !s.is_finite()) {
        return Err(Error::Config(format!(
            "{}: the small dense SVD gave a non-finite singular value ({s})",
            input.display()
        )));
    }
    // p_i = U_b[:, i]; g_i = σ_i Q V_b[:, i]; signs fixed so Σ_j p_i[j] ≥ 0
    let mut p = Matrix::zeros(n, terms);
    let mut w = Matrix::zeros(k, terms);
    for i in 0..terms {
        let u_i = &svd.u[i * n..(i + 1) * n];
        let sum: f64 = u_i.iter().sum();
        let sign = if sum < 0.0 { -1.0 } else { 1.0 };
        for (r, &u) in u_i.iter().enumerate() {
            p.data[r * terms + i] = (sign * u) as f32;
        }
        for r in 0..k {
            w.data[r * terms + i] = (sign * sigma[i] * svd.v[i * k + r]) as f32;
        }
    }
    // g = Q W, stored in Q's blocks when Q is
    let mut g = q.times(&w, &beside(out, "g"))?;
    drop(q);
    let t_err = Instant::now();
    let (err2, norm2) = stream.residual(&mut g, &p, progress)?;
    pass_seconds += t_err.elapsed().as_secs_f64();
    progress.end();
    let relative_error = if norm2 > 0.0 { (err2 / norm2).sqrt() } else { 0.0 };
    if let Tall::Held(g) = &mut g {
        stream.to_image_order(g);
    }

    let layout = btf.layout().clone();
    write_svd(
        out,
        cfg,
        &btf,
        input,
        source_kind,
        g,
        &stream.tiles,
        &p,
        &sigma[..terms],
        relative_error,
        progress,
    )?;
    Ok(FactorizeReport {
        rows: m,
        columns: n,
        terms,
        relative_error,
        passes,
        bytes_per_pass: layout.raw_bytes(),
        seconds: start.elapsed().as_secs_f64(),
        pass_seconds,
        singular_values: sigma,
    })
}

/// The pair closest to a front-parallel view under head-on light.
fn preview_pair(l: &BtfLayout) -> usize {
    let nearest = |d: &[Angles]| {
        (0..d.len())
            .min_by(|&a, &b| d[a].theta.total_cmp(&d[b].theta).then(a.cmp(&b)))
            .unwrap_or(0)
    };
    l.pair(nearest(&l.views), nearest(&l.lights))
}

#[allow(clippy::too_many_arguments)]
fn write_svd(
    out: &Path,
    cfg: &FactorizeConfig,
    btf: &Btf,
    input: &Path,
    source_kind: &str,
    mut g: Tall,
    tiles: &[stream::TileRows],
    p: &Matrix,
    sigma: &[f64],
    relative_error: f64,
    progress: &dyn Progress,
) -> Result<()> {
    let l = btf.layout();
    let (w, h, terms) = (l.width as u64, l.height as u64, sigma.len() as u64);
    let mut c = ContainerWriter::create(out, KIND)?;
    c.set_level(cfg.level);
    c.set_seed(cfg.seed);
    // the source is named relative to the factorization's folder, so its
    // bytes do not depend on the working directory it was made from
    let source = crate::io::staging::relative_to_folder_of(out, input);
    c.add_input(&source, btf.container().content_hash());
    c.set_param("source", Param::Text(source));
    c.set_param("source_kind", Param::Text(source_kind.into()));
    c.set_param("width", Param::Int(w as i64));
    c.set_param("height", Param::Int(h as i64));
    c.set_param("terms", Param::Int(terms as i64));
    c.set_param("oversampling", Param::Int(cfg.oversampling as i64));
    c.set_param("power_iterations", Param::Int(cfg.power_iterations as i64));
    c.set_param("relative_error", Param::Float(relative_error));
    c.set_param("rotations", Param::Int(cfg.rotations as i64));
    c.set_param("tileable", Param::Int(cfg.tileable as i64));
    c.set_param("preview_pair", Param::Int(preview_pair(l) as i64));
    for (name, dirs) in [("view_dirs", &l.views), ("light_dirs", &l.lights)] {
        let nd = dirs.len() as u64;
        let id = c.add_array(ArraySpec::new(name, DType::F32, &[nd, 2], &[nd, 2])?)?;
        c.write_array(
            id,
            &dirs.iter().flat_map(|a| [a.theta, a.phi]).collect::<Vec<_>>(),
        )?;
    }
    let id = c.add_array(ArraySpec::new("singular_values", DType::F32, &[terms], &[terms])?)?;
    c.write_array(id, &sigma.iter().map(|&s| s as f32).collect::<Vec<_>>())?;
    let t = SVD_TILE;
    let id = c.add_array(ArraySpec::new(
        "geometry_maps",
        DType::F32,
        &[h, w, terms],
        &[t, t, terms],
    )?)?;
    // held maps are in image order; stored ones are written a row of
    // chunks at a time and kept as chunks for the rotations (their cache
    // an eighth of the budget, as the batches of turned chunks)
    let maps = match g {
        Tall::Held(ref g) => {
            c.write_array(id, &g.data)?;
            Maps::Whole(&g.data)
        }
        Tall::Stored(_) => {
            let cache = cfg.memory.split([1, 7])[0];
            Maps::Chunks(Box::new(maps::write_stored(
                &mut c, id, &mut g, tiles, l.width, out, cache,
            )?))
        }
    };
    let pairs = l.pairs() as u64;
    let id = c.add_array(ArraySpec::new(
        "appearance",
        DType::F32,
        &[pairs, 3, terms],
        &[l.band as u64, 3, terms],
    )?)?;
    c.write_array(id, &p.data)?;
    // the preview pair's image, read chunk by chunk
    let id = c.add_array(ArraySpec::new("preview", DType::F32, &[h, w, 3], &[t, t, 3])?)?;
    let spec = c.spec(id).clone();
    for k in 0..spec.chunk_count() {
        let (o, e) = spec.chunk_region(k);
        let rect = (o[1] as usize, o[0] as usize, e[1] as usize, e[0] as usize);
        c.write_chunk(id, k, &btf.read_pair_rect(preview_pair(l), rect)?)?;
    }
    if cfg.rotations > 0 {
        write_rotations(&mut c, cfg, l.width, l.height, sigma.len(), maps, progress)?;
    }
    c.finish()
}

/// PSNR in dB of `test` against `reference`, peak = the reference's maximum.
pub fn psnr(reference: &RgbImage, test: &RgbImage) -> f64 {
    let peak = reference.data.iter().fold(0f32, |a, &b| a.max(b)) as f64;
    let mse = reference
        .data
        .iter()
        .zip(&test.data)
        .map(|(a, b)| ((a - b) as f64).powi(2))
        .sum::<f64>()
        / reference.data.len().max(1) as f64;
    if mse == 0.0 {
        f64::INFINITY
    } else {
        10.0 * math::log10(peak * peak / mse)
    }
}
