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
//! on the thread count. Memory: the factors (O((texels + columns)·k)) plus one
//! chunk per worker; chunks are cached only when the whole BTF fits the budget.
//! One extra pass measures ‖A − A_n‖_F / ‖A‖_F.

use std::path::{Path, PathBuf};
use std::time::Instant;

use faer::linalg::matmul::matmul;
use faer::{Accum, Mat, MatRef, Par};
use half::f16;
use half::slice::HalfFloatSliceExt;
use rayon::prelude::*;

use crate::artifact::btf::{Angles, Btf, BtfLayout, BtfWriter};
use crate::artifact::svd::SvdArtifact;
use crate::container::{codec, ArrayId, ArraySpec, Container, ContainerWriter, DType, MemoryBudget, Param};
use crate::io::imageio::{self, RgbImage};
use crate::progress::Progress;
use crate::{Error, Result};

/// The artifact kind of a factorization.
pub const KIND: &str = "svd";
/// The number of rotated copies of the geometry maps (5° steps).
pub const DEFAULT_ROTATIONS: usize = 72;
/// Edge of the spatial chunks of the `.svd` arrays.
const SVD_TILE: u64 = 64;

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

/// One texel tile's rows of the matrix: rows are ordered tile by tile
/// (row-major inside each tile), so a tile's rows are contiguous.
#[derive(Clone, Copy, Debug)]
struct TileRows {
    tx: usize,
    ty: usize,
    x0: usize,
    y0: usize,
    w: usize,
    h: usize,
    row0: usize,
}

impl TileRows {
    fn rows(&self) -> usize {
        self.w * self.h
    }
}

/// The BTF seen as a matrix streamed chunk by chunk.
struct MatrixStream<'a> {
    btf: &'a Btf,
    rgb: ArrayId,
    tiles: Vec<TileRows>,
    rows: usize,
    cols: usize,
    /// First column and column count of each band.
    bands: Vec<(usize, usize)>,
}

impl<'a> MatrixStream<'a> {
    fn new(btf: &'a Btf) -> Result<Self> {
        let l = btf.layout();
        let (ntx, nty) = l.tiles();
        let mut tiles = Vec::with_capacity(ntx * nty);
        let mut row0 = 0;
        for ty in 0..nty {
            for tx in 0..ntx {
                let (x0, y0) = (tx * l.tile, ty * l.tile);
                let t = TileRows {
                    tx,
                    ty,
                    x0,
                    y0,
                    w: l.tile.min(l.width - x0),
                    h: l.tile.min(l.height - y0),
                    row0,
                };
                row0 += t.rows();
                tiles.push(t);
            }
        }
        let bands = (0..l.bands())
            .map(|b| {
                let p0 = b * l.band;
                let p1 = (p0 + l.band).min(l.pairs());
                (p0 * 3, (p1 - p0) * 3)
            })
            .collect();
        Ok(MatrixStream {
            btf,
            rgb: btf.container().array("rgb")?,
            tiles,
            rows: row0,
            cols: l.pairs() * 3,
            bands,
        })
    }

    /// The chunk (tile, band) as f32 values, row-major (texel × column), into
    /// `buf`; non-finite values are an error naming the texel and pair.
    fn chunk<'b>(&self, t: &TileRows, band: usize, buf: &'b mut Vec<f32>) -> Result<MatRef<'b, f32>> {
        let l = self.btf.layout();
        let chunk = self
            .btf
            .container()
            .read_chunk::<f16>(self.rgb, l.chunk(t.tx, t.ty, band))?;
        buf.clear();
        buf.resize(chunk.len(), 0.0);
        // the slice conversion: per-value f16 conversions are ~50× slower on
        // threads that have just run faer's wide-vector kernels
        chunk.convert_to_f32_slice(buf);
        let (_, ncols) = self.bands[band];
        if let Some(i) = buf.iter().position(|v| !v.is_finite()) {
            let (texel, col) = (i / ncols, i % ncols);
            let pair = self.bands[band].0 / 3 + col / 3;
            let (v, li) = (pair / l.lights.len(), pair % l.lights.len());
            return Err(Error::input(
                self.btf.container().path(),
                format!(
                    "array 'rgb' holds a non-finite value ({}) at texel ({}, {}), view θ {} φ {}, light θ {} φ {}: cannot factorize",
                    buf[i],
                    t.x0 + texel % t.w,
                    t.y0 + texel / t.w,
                    l.views[v].theta,
                    l.views[v].phi,
                    l.lights[li].theta,
                    l.lights[li].phi
                ),
            ));
        }
        Ok(MatRef::from_row_major_slice(&buf[..], t.rows(), ncols))
    }

    /// `A M` (rows × k) for `M` (cols × k): one pass, parallel over tiles.
    fn times(&self, m: &Mat<f32>, progress: &dyn Progress) -> Result<Mat<f32>> {
        let k = m.ncols();
        let parts: Vec<Mat<f32>> = self
            .tiles
            .par_iter()
            .map(|t| {
                let mut y = Mat::<f32>::zeros(t.rows(), k);
                let mut buf = Vec::new();
                for (b, &(c0, nc)) in self.bands.iter().enumerate() {
                    let a = self.chunk(t, b, &mut buf)?;
                    matmul(
                        y.as_mut(),
                        Accum::Add,
                        a,
                        m.as_ref().subrows(c0, nc),
                        1.0f32,
                        Par::Seq,
                    );
                }
                progress.advance(1);
                Ok(y)
            })
            .collect::<Result<_>>()?;
        let mut out = Mat::<f32>::zeros(self.rows, k);
        for (t, y) in self.tiles.iter().zip(&parts) {
            out.as_mut().subrows_mut(t.row0, t.rows()).copy_from(y);
        }
        Ok(out)
    }

    /// `Aᵀ Q` (cols × k) for `Q` (rows × k): one pass, parallel over bands.
    fn transpose_times(&self, q: &Mat<f32>, progress: &dyn Progress) -> Result<Mat<f32>> {
        let k = q.ncols();
        let parts: Vec<Mat<f32>> = (0..self.bands.len())
            .into_par_iter()
            .map(|b| {
                let mut z = Mat::<f32>::zeros(self.bands[b].1, k);
                let mut buf = Vec::new();
                for t in &self.tiles {
                    let a = self.chunk(t, b, &mut buf)?;
                    matmul(
                        z.as_mut(),
                        Accum::Add,
                        a.transpose(),
                        q.as_ref().subrows(t.row0, t.rows()),
                        1.0f32,
                        Par::Seq,
                    );
                }
                progress.advance(1);
                Ok(z)
            })
            .collect::<Result<_>>()?;
        let mut out = Mat::<f32>::zeros(self.cols, k);
        for (&(c0, nc), z) in self.bands.iter().zip(&parts) {
            out.as_mut().subrows_mut(c0, nc).copy_from(z);
        }
        Ok(out)
    }

    /// (‖A − G Pᵀ‖²_F, ‖A‖²_F): one pass, summed in chunk order.
    fn residual(&self, g: &Mat<f32>, p: &Mat<f32>, progress: &dyn Progress) -> Result<(f64, f64)> {
        let per_tile: Vec<(f64, f64)> = self
            .tiles
            .par_iter()
            .map(|t| {
                let mut buf = Vec::new();
                let (mut err, mut norm) = (0f64, 0f64);
                for (b, &(c0, nc)) in self.bands.iter().enumerate() {
                    let a = self.chunk(t, b, &mut buf)?;
                    let mut r = a.to_owned();
                    matmul(
                        r.as_mut(),
                        Accum::Add,
                        g.as_ref().subrows(t.row0, t.rows()),
                        p.as_ref().subrows(c0, nc).transpose(),
                        -1.0f32,
                        Par::Seq,
                    );
                    err += sum_squares(r.as_ref());
                    norm += sum_squares(a);
                }
                progress.advance(1);
                Ok((err, norm))
            })
            .collect::<Result<_>>()?;
        Ok(per_tile
            .iter()
            .fold((0.0, 0.0), |acc, x| (acc.0 + x.0, acc.1 + x.1)))
    }

    /// Reorders rows from tile order to image order (y · width + x).
    fn to_image_order(&self, m: &Mat<f32>) -> Mat<f32> {
        let width = self.btf.layout().width;
        let mut out = Mat::<f32>::zeros(self.rows, m.ncols());
        for t in &self.tiles {
            for r in 0..t.rows() {
                let (x, y) = (t.x0 + r % t.w, t.y0 + r / t.w);
                out.as_mut().row_mut(y * width + x).copy_from(m.row(t.row0 + r));
            }
        }
        out
    }
}

fn sum_squares(m: MatRef<'_, f32>) -> f64 {
    let mut s = 0f64;
    for j in 0..m.ncols() {
        let mut c = 0f32;
        for i in 0..m.nrows() {
            let v = m[(i, j)];
            c += v * v;
        }
        s += c as f64;
    }
    s
}

fn to_f64(m: &Mat<f32>) -> Mat<f64> {
    Mat::from_fn(m.nrows(), m.ncols(), |i, j| m[(i, j)] as f64)
}

fn to_f32(m: MatRef<'_, f64>) -> Mat<f32> {
    Mat::from_fn(m.nrows(), m.ncols(), |i, j| m[(i, j)] as f32)
}

/// Orthonormal basis of the columns (thin Householder QR).
fn orth(m: &Mat<f32>) -> Mat<f32> {
    to_f32(to_f64(m).qr().compute_thin_Q().as_ref())
}

/// Whether `path` names a plain image rather than an artifact.
pub fn is_image_path(path: &Path) -> bool {
    imageio::is_image_path(path)
}

/// Writes a colour image as a BTF with one view and one light (both along
/// the normal): the path by which colour samples enter every stage.
/// The image is held to `budget` decoded (see [`imageio::read_rgb_within`]).
pub fn image_to_btf(image: &Path, out: &Path, budget: MemoryBudget) -> Result<()> {
    let img = imageio::read_rgb_within(image, budget.bytes())?;
    let head_on = Angles { theta: 0.0, phi: 0.0 };
    let layout = BtfLayout::new(img.width, img.height, vec![head_on], vec![head_on]);
    let mut w = BtfWriter::create(out, layout.clone())?;
    let (ntx, nty) = layout.tiles();
    for ty in 0..nty {
        for tx in 0..ntx {
            let (x0, y0) = (tx * layout.tile, ty * layout.tile);
            let mut v = Vec::new();
            for y in y0..(y0 + layout.tile).min(img.height) {
                for x in x0..(x0 + layout.tile).min(img.width) {
                    let i = (y * img.width + x) * 3;
                    v.extend(img.data[i..i + 3].iter().map(|&c| f16::from_f32(c)));
                }
            }
            w.write_tile_band(tx, ty, 0, &v)?;
        }
    }
    w.finish()
}

/// Factorizes the BTF (or colour image) at `input` into the `.svd` artifact `out`.
///
/// The dense steps run on a thread of their own: faer's matrix products
/// keep a workspace per thread that used them (twice the L3 cache, reserved
/// and touched as far as the matrices need) for the thread's lifetime,
/// which would otherwise stay with the caller (a whole `tile` run).
pub fn factorize(
    input: &Path,
    out: &Path,
    cfg: &FactorizeConfig,
    progress: &dyn Progress,
) -> Result<FactorizeReport> {
    std::thread::scope(
        |s| match s.spawn(|| factorize_here(input, out, cfg, progress)).join() {
            Ok(result) => result,
            Err(panic) => std::panic::resume_unwind(panic),
        },
    )
}

fn factorize_here(
    input: &Path,
    out: &Path,
    cfg: &FactorizeConfig,
    progress: &dyn Progress,
) -> Result<FactorizeReport> {
    let start = Instant::now();
    cfg.validate()?;
    crate::io::staging::check_output(out, &[("the input", input)])?;
    // dense QR/SVD run sequentially: products with A are parallel over
    // chunks already, and a fixed order keeps results thread-count independent
    faer::set_global_parallelism(Par::Seq);
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
    // cache chunks across passes only if the whole BTF fits half the budget
    let raw = Container::open(&btf_path, MemoryBudget(0))?
        .metadata()
        .arrays
        .iter()
        .map(|a| a.raw_bytes())
        .sum::<u64>();
    let [half, _] = cfg.memory.split([1, 1]);
    let cache = if raw <= half.bytes() {
        half
    } else {
        MemoryBudget(0)
    };
    let btf = Btf::open(&btf_path, cache)?;
    let stream = MatrixStream::new(&btf)?;
    let (m, n) = (stream.rows, stream.cols);
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
    let passes = 3 + 2 * cfg.power_iterations;
    let pass_jobs = |rowwise: bool| if rowwise { stream.tiles.len() } else { stream.bands.len() } as u64;
    progress.begin(
        "factorize",
        (2 + cfg.power_iterations) as u64 * pass_jobs(true)
            + (1 + cfg.power_iterations) as u64 * pass_jobs(false),
    );
    let t_pass = Instant::now();
    let omega = Mat::<f32>::from_fn(n, k, |i, j| {
        crate::rng::gaussian(cfg.seed, (i * k + j) as u64) as f32
    });
    let mut q = orth(&stream.times(&omega, progress)?);
    drop(omega);
    for _ in 0..cfg.power_iterations {
        let z = orth(&stream.transpose_times(&q, progress)?);
        q = orth(&stream.times(&z, progress)?);
    }
    let bt = to_f64(&stream.transpose_times(&q, progress)?); // n × k
    let mut pass_seconds = t_pass.elapsed().as_secs_f64();
    let svd = bt.thin_svd().map_err(|e| {
        Error::Config(format!(
            "{}: the small dense SVD did not converge ({e:?})",
            input.display()
        ))
    })?;
    let (u_b, s, v_b) = (svd.U(), svd.S().column_vector(), svd.V()); // Bᵀ = U_b S V_bᵀ
    let sigma: Vec<f64> = (0..k).map(|i| s[i]).collect();
    // p_i = U_b[:, i]; g_i = σ_i Q V_b[:, i]; signs fixed so Σ_j p_i[j] ≥ 0
    let mut p = Mat::<f32>::zeros(n, terms);
    let mut w = Mat::<f32>::zeros(k, terms);
    for i in 0..terms {
        let sum: f64 = (0..n).map(|r| u_b[(r, i)]).sum();
        let sign = if sum < 0.0 { -1.0 } else { 1.0 };
        for r in 0..n {
            p[(r, i)] = (sign * u_b[(r, i)]) as f32;
        }
        for r in 0..k {
            w[(r, i)] = (sign * sigma[i] * v_b[(r, i)]) as f32;
        }
    }
    let mut g = Mat::<f32>::zeros(m, terms);
    matmul(
        g.as_mut(),
        Accum::Replace,
        q.as_ref(),
        w.as_ref(),
        1.0f32,
        Par::Seq,
    );
    drop(q);
    let t_err = Instant::now();
    let (err2, norm2) = stream.residual(&g, &p, progress)?;
    pass_seconds += t_err.elapsed().as_secs_f64();
    progress.end();
    let relative_error = if norm2 > 0.0 { (err2 / norm2).sqrt() } else { 0.0 };
    let g = stream.to_image_order(&g);

    let layout = btf.layout().clone();
    let preview = preview_image(&btf)?;
    write_svd(
        out,
        cfg,
        &btf,
        input,
        source_kind,
        &g,
        &p,
        &sigma[..terms],
        relative_error,
        &preview,
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

fn preview_image(btf: &Btf) -> Result<Vec<f32>> {
    let p = preview_pair(btf.layout());
    btf.read_pair_images(p..p + 1)
}

#[allow(clippy::too_many_arguments)]
fn write_svd(
    out: &Path,
    cfg: &FactorizeConfig,
    btf: &Btf,
    input: &Path,
    source_kind: &str,
    g: &Mat<f32>,
    p: &Mat<f32>,
    sigma: &[f64],
    relative_error: f64,
    preview: &[f32],
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
    let g_flat: Vec<f32> = (0..g.nrows())
        .flat_map(|r| (0..g.ncols()).map(move |i| (r, i)))
        .map(|(r, i)| g[(r, i)])
        .collect();
    c.write_array(id, &g_flat)?;
    let pairs = l.pairs() as u64;
    let id = c.add_array(ArraySpec::new(
        "appearance",
        DType::F32,
        &[pairs, 3, terms],
        &[l.band as u64, 3, terms],
    )?)?;
    let p_flat: Vec<f32> = (0..p.nrows())
        .flat_map(|r| (0..p.ncols()).map(move |i| (r, i)))
        .map(|(r, i)| p[(r, i)])
        .collect();
    c.write_array(id, &p_flat)?;
    let id = c.add_array(ArraySpec::new("preview", DType::F32, &[h, w, 3], &[t, t, 3])?)?;
    c.write_array(id, preview)?;
    if cfg.rotations > 0 {
        write_rotations(&mut c, cfg, l.width, l.height, sigma.len(), &g_flat, progress)?;
    }
    c.finish()
}

/// Writes `src` (whose geometry maps `maps` the caller has read) resampled
/// to `width`×`height` texels as the `.svd` `out`: the geometry maps and the
/// preview resampled
/// ([`crate::io::imageio::resample`]), the appearance functions, singular
/// values and directions unchanged (the BTF's columns do not depend on the
/// texel grid), and `rotations` rotated copies made from the resampled maps.
/// Quilting uses it to give a sample its size on the surface.
pub fn resample_svd(
    src: &SvdArtifact,
    maps: &[f32],
    out: &Path,
    width: usize,
    height: usize,
    rotations: usize,
    progress: &dyn Progress,
) -> Result<()> {
    let (w0, h0, terms) = (src.width, src.height, src.terms);
    let g = crate::io::imageio::resample(maps, w0, h0, terms, width, height);
    let preview = crate::io::imageio::resample(&src.preview()?.data, w0, h0, 3, width, height);
    let meta = src.container().metadata();
    let cfg = FactorizeConfig {
        rotations,
        tileable: src.tileable(),
        seed: meta.seed.unwrap_or(FactorizeConfig::default().seed),
        ..FactorizeConfig::default()
    };
    let (w, h, t) = (width as u64, height as u64, SVD_TILE);
    let mut c = ContainerWriter::create(out, KIND)?;
    c.set_level(cfg.level);
    c.set_seed(cfg.seed);
    c.add_input(
        &src.container().path().display().to_string(),
        src.container().content_hash(),
    );
    for (name, value) in &meta.params {
        let value = match name.as_str() {
            "width" => Param::Int(w as i64),
            "height" => Param::Int(h as i64),
            "rotations" => Param::Int(rotations as i64),
            _ => value.clone(),
        };
        c.set_param(name, value);
    }
    c.set_param("resampled_from", Param::Text(format!("{w0}x{h0}")));
    for name in ["view_dirs", "light_dirs", "singular_values"] {
        let id = src.container().array(name)?;
        let spec = src.container().spec(id).clone();
        let values: Vec<f32> = src.container().read_array(id)?;
        let id = c.add_array(spec)?;
        c.write_array(id, &values)?;
    }
    let id = c.add_array(ArraySpec::new(
        "geometry_maps",
        DType::F32,
        &[h, w, terms as u64],
        &[t, t, terms as u64],
    )?)?;
    c.write_array(id, &g)?;
    let id = src.container().array("appearance")?;
    let spec = src.container().spec(id).clone();
    let appearance: Vec<f32> = src.container().read_array(id)?;
    let id = c.add_array(spec)?;
    c.write_array(id, &appearance)?;
    let id = c.add_array(ArraySpec::new("preview", DType::F32, &[h, w, 3], &[t, t, 3])?)?;
    c.write_array(id, &preview)?;
    if rotations > 0 {
        write_rotations(&mut c, &cfg, width, height, terms, &g, progress)?;
    }
    c.finish()
}

/// Bilinear rotation of multi-channel maps about the sample centre: copy r
/// shows the sample turned by r·360°/R (output texel x reads the input at
/// R(−θ)(x − c) + c). Invalid where that point leaves the sample (unless
/// `tileable`, which wraps).
pub fn rotate_maps(
    maps: &[f32],
    width: usize,
    height: usize,
    channels: usize,
    degrees: f64,
    tileable: bool,
) -> (Vec<f32>, Vec<u8>) {
    let (sin, cos) = degrees.to_radians().sin_cos();
    let (cx, cy) = ((width as f64 - 1.0) / 2.0, (height as f64 - 1.0) / 2.0);
    let mut out = vec![0f32; width * height * channels];
    let mut valid = vec![0u8; width * height];
    let texel = |x: usize, y: usize| &maps[(y * width + x) * channels..(y * width + x + 1) * channels];
    for y in 0..height {
        for x in 0..width {
            let (dx, dy) = (x as f64 - cx, y as f64 - cy);
            let mut sx = cos * dx + sin * dy + cx;
            let mut sy = -sin * dx + cos * dy + cy;
            if tileable {
                sx = sx.rem_euclid(width as f64);
                sy = sy.rem_euclid(height as f64);
            } else {
                // snap rounding noise (e.g. at 90°) back onto the sample
                let snap = |v: f64, hi: f64| {
                    if v < 0.0 && v > -1e-9 {
                        0.0
                    } else if v > hi && v < hi + 1e-9 {
                        hi
                    } else {
                        v
                    }
                };
                sx = snap(sx, width as f64 - 1.0);
                sy = snap(sy, height as f64 - 1.0);
                if !(0.0..=width as f64 - 1.0).contains(&sx) || !(0.0..=height as f64 - 1.0).contains(&sy) {
                    continue;
                }
            }
            let (x0, y0) = (sx.floor() as usize, sy.floor() as usize);
            let (fx, fy) = ((sx - x0 as f64) as f32, (sy - y0 as f64) as f32);
            let (x0, y0) = (x0.min(width - 1), y0.min(height - 1));
            let x1 = if tileable {
                (x0 + 1) % width
            } else {
                (x0 + 1).min(width - 1)
            };
            let y1 = if tileable {
                (y0 + 1) % height
            } else {
                (y0 + 1).min(height - 1)
            };
            let (a, b, c, d) = (texel(x0, y0), texel(x1, y0), texel(x0, y1), texel(x1, y1));
            let o = &mut out[(y * width + x) * channels..(y * width + x + 1) * channels];
            for i in 0..channels {
                let top = a[i] + (b[i] - a[i]) * fx;
                let bottom = c[i] + (d[i] - c[i]) * fx;
                o[i] = top + (bottom - top) * fy;
            }
            valid[y * width + x] = 1;
        }
    }
    (out, valid)
}

fn write_rotations(
    c: &mut ContainerWriter,
    cfg: &FactorizeConfig,
    width: usize,
    height: usize,
    terms: usize,
    g: &[f32],
    progress: &dyn Progress,
) -> Result<()> {
    let r = cfg.rotations as u64;
    let (w, h, t) = (width as u64, height as u64, SVD_TILE);
    let maps = c.add_array(ArraySpec::new(
        "rotated_maps",
        DType::F16,
        &[r, h, w, terms as u64],
        &[1, t, t, terms as u64],
    )?)?;
    let valid = c.add_array(ArraySpec::new(
        "rotated_valid",
        DType::U8,
        &[r, h, w],
        &[1, t, t],
    )?)?;
    let (maps_spec, valid_spec) = (c.spec(maps).clone(), c.spec(valid).clone());
    let per_rotation = maps_spec.chunk_count() / r;
    progress.begin("rotations", r);
    let level = c.level();
    let group = 4;
    for r0 in (0..cfg.rotations).step_by(group) {
        let r1 = (r0 + group).min(cfg.rotations);
        let encoded: Vec<(Vec<codec::EncodedChunk>, Vec<codec::EncodedChunk>)> = (r0..r1)
            .into_par_iter()
            .map(|ri| {
                let degrees = 360.0 * ri as f64 / cfg.rotations as f64;
                let (rot, ok) = rotate_maps(g, width, height, terms, degrees, cfg.tileable);
                let mut rot16 = vec![f16::ZERO; rot.len()];
                rot16.convert_from_f32_slice(&rot);
                // the chunks of rotation ri: origin and extent of each → encoded
                let chunks = |spec: &ArraySpec, enc: &dyn Fn(&[u64], &[u64]) -> codec::EncodedChunk| {
                    (0..per_rotation)
                        .map(|k| {
                            let (o, e) = spec.chunk_region(ri as u64 * per_rotation + k);
                            enc(&o, &e)
                        })
                        .collect::<Vec<_>>()
                };
                let map_chunks = chunks(&maps_spec, &|o, e| {
                    let mut v = Vec::with_capacity((e[1] * e[2]) as usize * terms);
                    for y in o[1]..o[1] + e[1] {
                        let row = (y as usize * width + o[2] as usize) * terms;
                        v.extend_from_slice(&rot16[row..row + e[2] as usize * terms]);
                    }
                    codec::encode(&v, level)
                });
                let valid_chunks = chunks(&valid_spec, &|o, e| {
                    let mut v = Vec::with_capacity((e[1] * e[2]) as usize);
                    for y in o[1]..o[1] + e[1] {
                        let row = y as usize * width + o[2] as usize;
                        v.extend_from_slice(&ok[row..row + e[2] as usize]);
                    }
                    codec::encode(&v, level)
                });
                (map_chunks, valid_chunks)
            })
            .collect();
        for (ri, (mc, vc)) in (r0..r1).zip(encoded) {
            for (k, e) in mc.into_iter().enumerate() {
                c.write_encoded(maps, ri as u64 * per_rotation + k as u64, e)?;
            }
            for (k, e) in vc.into_iter().enumerate() {
                c.write_encoded(valid, ri as u64 * per_rotation + k as u64, e)?;
            }
        }
        progress.advance((r1 - r0) as u64);
    }
    progress.end();
    Ok(())
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
        10.0 * (peak * peak / mse).log10()
    }
}
