//! The data matrix of a BTF streamed by tiles (rows: texels, columns:
//! direction pairs) for the randomized SVD passes, whose tall operands and
//! results are held whole or stored by blocks of tiles ([`Tall`]).

use super::tall::{Stored, Tall};
use super::*;
use crate::dense::{self, Matrix};

/// One texel tile's rows of the matrix: rows are ordered tile by tile
/// (row-major inside each tile), so a tile's rows are contiguous.
#[derive(Clone, Copy, Debug)]
pub(super) struct TileRows {
    tx: usize,
    ty: usize,
    pub(super) x0: usize,
    pub(super) y0: usize,
    pub(super) w: usize,
    pub(super) h: usize,
    pub(super) row0: usize,
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
    fn chunk<'b>(&self, t: &TileRows, band: usize, buf: &'b mut Vec<f32>) -> Result<&'b [f32]> {
        let l = self.btf.layout();
        let chunk = self
            .btf
            .container()
            .read_chunk::<f16>(self.rgb, l.chunk(t.tx, t.ty, band))?;
        // every value is overwritten: no clearing first
        buf.resize(chunk.len(), 0.0);
        // the slice conversion: per-value f16 conversions are ~50× slower on
        // threads that have just run wide-vector kernels
        chunk.convert_to_f32_slice(buf);
        let (_, ncols) = self.bands[band];
        // a branch-free test per block (vectorised), the position only on failure
        let finite = |b: &[f32]| b.iter().fold(true, |ok, v| ok & v.is_finite());
        if let Some(i) = (!buf.chunks(1024).all(finite))
            .then(|| buf.iter().position(|v| !v.is_finite()))
            .flatten()
        {
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
        Ok(&buf[..])
    }

    /// `A M` (rows × k) for `M` (cols × k): one pass, parallel over tiles;
    /// each tile's rows sum the bands in order.
    pub(super) fn times(&self, m: &Matrix, progress: &dyn Progress) -> Result<Matrix> {
        let mut out = Matrix::zeros(self.rows, m.cols);
        self.tiles_times(&self.tiles, m, &mut out.data, progress)?;
        Ok(out)
    }

    /// [`MatrixStream::times`] into `store`, a block of tiles at a time.
    pub(super) fn times_into(&self, m: &Matrix, store: &mut Stored, progress: &dyn Progress) -> Result<()> {
        let mut y = Vec::new();
        for b in 0..store.block_count() {
            let tiles = &self.tiles[store.block_tiles(b)];
            y.clear();
            y.resize(tiles.iter().map(|t| t.rows()).sum::<usize>() * m.cols, 0.0);
            self.tiles_times(tiles, m, &mut y, progress)?;
            store.write_block(b, &y)?;
        }
        Ok(())
    }

    /// The rows of consecutive `tiles` of `A M` into `out` (zeros), each
    /// tile's rows written in place.
    fn tiles_times(
        &self,
        tiles: &[TileRows],
        m: &Matrix,
        out: &mut [f32],
        progress: &dyn Progress,
    ) -> Result<()> {
        let k = m.cols;
        let mut parts = Vec::with_capacity(tiles.len());
        let mut rest = out;
        for t in tiles {
            let (part, after) = rest.split_at_mut(t.rows() * k);
            parts.push((t, part));
            rest = after;
        }
        parts.into_par_iter().try_for_each(|(t, y)| {
            let mut buf = Vec::new();
            for (b, &(c0, nc)) in self.bands.iter().enumerate() {
                let a = self.chunk(t, b, &mut buf)?;
                dense::mul_add(y, k, (a, nc), (m.rows_from(c0, nc), k), (t.rows(), nc, k));
            }
            progress.advance(1);
            Ok(())
        })
    }

    /// `Aᵀ Q` (cols × k) for `Q` (rows × k): one pass, a block of `Q`'s
    /// rows at a time, parallel over bands; each band's rows sum the tiles
    /// in order.
    pub(super) fn transpose_times(&self, q: &mut Tall, progress: &dyn Progress) -> Result<Matrix> {
        let k = q.cols();
        let blocks = q.blocks();
        // (Aᵀ Q)ᵀ = Qᵀ A, so the products run along the chunk's rows; each
        // output still sums the texels in order
        let mut zts: Vec<Vec<f32>> = self.bands.iter().map(|&(_, nc)| vec![0f32; k * nc]).collect();
        let mut held = Vec::new();
        for b in 0..blocks {
            let (tiles, row0, rows) = q.block(b, self.tiles.len(), &mut held)?;
            zts.par_iter_mut().enumerate().try_for_each(|(band, zt)| {
                let nc = self.bands[band].1;
                let (mut buf, mut qt) = (Vec::new(), Vec::new());
                for t in &self.tiles[tiles.clone()] {
                    let a = self.chunk(t, band, &mut buf)?;
                    let n = t.rows();
                    let r0 = t.row0 - row0;
                    dense::transpose_into(&rows[r0 * k..(r0 + n) * k], n, k, &mut qt);
                    dense::mul_add(zt, nc, (&qt, n), (a, nc), (k, n, nc));
                }
                if b + 1 == blocks {
                    progress.advance(1);
                }
                Ok::<_, Error>(())
            })?;
        }
        let mut out = Matrix::zeros(self.cols, k);
        let mut z = Vec::new();
        for (&(c0, nc), zt) in self.bands.iter().zip(&zts) {
            dense::transpose_into(zt, k, nc, &mut z);
            out.data[c0 * k..(c0 + nc) * k].copy_from_slice(&z);
        }
        Ok(out)
    }

    /// (‖A − G Pᵀ‖²_F, ‖A‖²_F): one pass, a block of `G`'s rows at a time,
    /// summed in chunk order.
    pub(super) fn residual(&self, g: &mut Tall, p: &Matrix, progress: &dyn Progress) -> Result<(f64, f64)> {
        let terms = g.cols();
        // Pᵀ (terms × cols), so a band's columns are contiguous in each row
        let mut pt = Vec::new();
        dense::transpose_into(&p.data, self.cols, terms, &mut pt);
        let mut per_tile: Vec<(f64, f64)> = Vec::with_capacity(self.tiles.len());
        let mut held = Vec::new();
        for b in 0..g.blocks() {
            let (tiles, row0, rows) = g.block(b, self.tiles.len(), &mut held)?;
            let part: Vec<(f64, f64)> = self.tiles[tiles]
                .par_iter()
                .map(|t| {
                    let (mut buf, mut r) = (Vec::new(), Vec::new());
                    let r0 = t.row0 - row0;
                    let minus_g: Vec<f32> = rows[r0 * terms..(r0 + t.rows()) * terms]
                        .iter()
                        .map(|v| -v)
                        .collect();
                    let (mut err, mut norm) = (0f64, 0f64);
                    for (b, &(c0, nc)) in self.bands.iter().enumerate() {
                        let a = self.chunk(t, b, &mut buf)?;
                        r.clear();
                        r.extend_from_slice(a);
                        let mg = (&minus_g[..], terms);
                        dense::mul_add(&mut r, nc, mg, (&pt[c0..], self.cols), (t.rows(), terms, nc));
                        err += dense::sum_squares(&r, nc);
                        norm += dense::sum_squares(a, nc);
                    }
                    progress.advance(1);
                    Ok((err, norm))
                })
                .collect::<Result<_>>()?;
            per_tile.extend(part);
        }
        Ok(per_tile
            .iter()
            .fold((0.0, 0.0), |acc, x| (acc.0 + x.0, acc.1 + x.1)))
    }

    /// Reorders rows from tile order to image order (y · width + x).
    pub(super) fn to_image_order(&self, m: &mut Matrix) {
        let width = self.btf.layout().width;
        let k = m.cols;
        // stream row → image row: tiles are in row order, found by their first row
        let image_row = |s: usize| {
            let t = &self.tiles[self.tiles.partition_point(|t| t.row0 <= s) - 1];
            let r = s - t.row0;
            (t.y0 + r / t.w) * width + t.x0 + r % t.w
        };
        // moved in place along the permutation's cycles, a row carried at a time
        let mut moved = vec![false; self.rows];
        let mut carry = vec![0f32; k];
        for start in 0..self.rows {
            if moved[start] {
                continue;
            }
            carry.copy_from_slice(m.row(start));
            let mut at = start;
            loop {
                let to = image_row(at);
                moved[to] = true;
                m.data[to * k..(to + 1) * k].swap_with_slice(&mut carry);
                if to == start {
                    break;
                }
                at = to;
            }
        }
    }
}
