//! The data matrix of a BTF streamed by tiles (rows: texels, columns:
//! direction pairs) for the randomized SVD passes, and small dense helpers.

use super::*;

/// One texel tile's rows of the matrix: rows are ordered tile by tile
/// (row-major inside each tile), so a tile's rows are contiguous.
#[derive(Clone, Copy, Debug)]
pub(super) struct TileRows {
    tx: usize,
    ty: usize,
    x0: usize,
    pub(super) y0: usize,
    pub(super) w: usize,
    pub(super) h: usize,
    row0: usize,
}

impl TileRows {
    pub(super) fn rows(&self) -> usize {
        self.w * self.h
    }
}

/// The BTF seen as a matrix streamed chunk by chunk.
pub(super) struct MatrixStream<'a> {
    btf: &'a Btf,
    rgb: ArrayId,
    pub(super) tiles: Vec<TileRows>,
    pub(super) rows: usize,
    pub(super) cols: usize,
    /// First column and column count of each band.
    pub(super) bands: Vec<(usize, usize)>,
}

impl<'a> MatrixStream<'a> {
    pub(super) fn new(btf: &'a Btf) -> Result<Self> {
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
    pub(super) fn times(&self, m: &Mat<f32>, progress: &dyn Progress) -> Result<Mat<f32>> {
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
    pub(super) fn transpose_times(&self, q: &Mat<f32>, progress: &dyn Progress) -> Result<Mat<f32>> {
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
    pub(super) fn residual(&self, g: &Mat<f32>, p: &Mat<f32>, progress: &dyn Progress) -> Result<(f64, f64)> {
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
    pub(super) fn to_image_order(&self, m: &Mat<f32>) -> Mat<f32> {
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

pub(super) fn to_f64(m: &Mat<f32>) -> Mat<f64> {
    Mat::from_fn(m.nrows(), m.ncols(), |i, j| m[(i, j)] as f64)
}

fn to_f32(m: MatRef<'_, f64>) -> Mat<f32> {
    Mat::from_fn(m.nrows(), m.ncols(), |i, j| m[(i, j)] as f32)
}

/// Orthonormal basis of the columns (thin Householder QR).
pub(super) fn orth(m: &Mat<f32>) -> Mat<f32> {
    to_f32(to_f64(m).qr().compute_thin_Q().as_ref())
}
