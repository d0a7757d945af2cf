//! The tall matrices of the randomized SVD, one row per texel: the sketch
//! Y = A M and its orthonormal basis Q (`m` × `k`), and the geometry maps
//! G = Q W (`m` × terms). Held whole when the QR fits its share of
//! `--memory` (12 bytes an entry); otherwise each in a plain scratch file
//! beside the output ([`beside`]) as f64 column pieces of blocks of whole
//! tiles, which the passes over the BTF read and write a block at a time
//! and the QR a column or a piece of one at a time
//! ([`Stored::orthonormalize`]). The values are
//! the same either way: a stored f32 is widened and narrowed back exactly,
//! and every sum runs in the same order.

use std::ops::Range;

use super::*;
use crate::container::Scratch;
use crate::dense::Columns;
use stream::TileRows;

/// Y, Q or G: held whole (row-major, tile order) or stored by blocks.
pub(super) enum Tall {
    Held(Matrix),
    Stored(Stored),
}

impl Tall {
    pub(super) fn cols(&self) -> usize {
        match self {
            Tall::Held(m) => m.cols,
            Tall::Stored(s) => s.cols,
        }
    }

    /// The blocks of rows the passes take at a time (one, when held).
    pub(super) fn blocks(&self) -> usize {
        match self {
            Tall::Held(_) => 1,
            Tall::Stored(s) => s.blocks.len(),
        }
    }

    /// Block `b`: its tiles, its first row and its rows (row-major f32,
    /// into `buf` when stored).
    pub(super) fn block<'a>(
        &'a mut self,
        b: usize,
        tiles: usize,
        buf: &'a mut Vec<f32>,
    ) -> Result<(Range<usize>, usize, &'a [f32])> {
        match self {
            Tall::Held(m) => Ok((0..tiles, 0, &m.data)),
            Tall::Stored(s) => {
                s.read_block(b, buf)?;
                let block = &s.blocks[b];
                Ok((block.tiles.clone(), block.row0, &buf[..]))
            }
        }
    }

    /// `self · w` (m × `w.cols`) for `w` (k × `w.cols`): held whole when
    /// `self` is, else stored in the same blocks beside `beside`.
    pub(super) fn times(&mut self, w: &Matrix, beside: &Path) -> Result<Tall> {
        let (k, n) = (self.cols(), w.cols);
        match self {
            Tall::Held(q) => {
                let mut out = Matrix::zeros(q.rows, n);
                dense::mul_add(&mut out.data, n, (&q.data, k), (&w.data, n), (q.rows, k, n));
                Ok(Tall::Held(out))
            }
            Tall::Stored(s) => {
                let mut out = s.like(beside, n)?;
                let (mut buf, mut y) = (Vec::new(), Vec::new());
                for b in 0..s.blocks.len() {
                    s.read_block(b, &mut buf)?;
                    let r = s.blocks[b].rows;
                    y.clear();
                    y.resize(r * n, 0.0);
                    dense::mul_add(&mut y, n, (&buf, k), (&w.data, n), (r, k, n));
                    out.write_block(b, &y)?;
                }
                Ok(Tall::Stored(out))
            }
        }
    }

    /// The rows of the consecutive tiles `range` of `tiles` (row-major
    /// f32) into `out`.
    pub(super) fn tile_rows(
        &mut self,
        tiles: &[TileRows],
        range: Range<usize>,
        out: &mut Vec<f32>,
    ) -> Result<()> {
        let k = self.cols();
        let last = &tiles[range.end - 1];
        let (r0, r1) = (tiles[range.start].row0, last.row0 + last.rows());
        match self {
            Tall::Held(m) => {
                out.clear();
                out.extend_from_slice(&m.data[r0 * k..r1 * k]);
                Ok(())
            }
            Tall::Stored(s) => s.read_rows(r0, r1 - r0, out),
        }
    }
}

/// A block: consecutive tiles and their rows.
#[derive(Clone)]
struct Block {
    tiles: Range<usize>,
    row0: usize,
    rows: usize,
}

/// A tall matrix's f64 columns in a plain scratch file, a record per
/// (column, block).
pub(super) struct Stored {
    scratch: Scratch,
    blocks: Vec<Block>,
    rows: usize,
    cols: usize,
    /// One block's column piece, widened.
    piece: Vec<f64>,
}

impl Stored {
    /// A store of `cols` columns over `tiles`, in blocks of whole tiles of
    /// at most `block_rows` rows (at least one tile), beside `beside`.
    pub(super) fn over_tiles(
        beside: &Path,
        tiles: &[TileRows],
        cols: usize,
        block_rows: usize,
    ) -> Result<Stored> {
        let mut blocks: Vec<Block> = Vec::new();
        let mut row0 = 0;
        for (i, t) in tiles.iter().enumerate() {
            match blocks.last_mut() {
                Some(b) if b.rows + t.rows() <= block_rows => {
                    b.tiles.end = i + 1;
                    b.rows += t.rows();
                }
                _ => blocks.push(Block {
                    tiles: i..i + 1,
                    row0,
                    rows: t.rows(),
                }),
            }
            row0 += t.rows();
        }
        Self::new(beside, blocks, row0, cols)
    }

    /// A store of `cols` columns in the same blocks, beside `beside`.
    fn like(&self, beside: &Path, cols: usize) -> Result<Stored> {
        Self::new(beside, self.blocks.clone(), self.rows, cols)
    }

    fn new(beside: &Path, blocks: Vec<Block>, rows: usize, cols: usize) -> Result<Stored> {
        Ok(Stored {
            scratch: Scratch::create_plain_beside(beside, cols * blocks.len())?,
            rows,
            cols,
            piece: Vec::new(),
            blocks,
        })
    }

    pub(super) fn block_tiles(&self, b: usize) -> Range<usize> {
        self.blocks[b].tiles.clone()
    }

    pub(super) fn block_count(&self) -> usize {
        self.blocks.len()
    }

    fn key(&self, col: usize, b: usize) -> usize {
        col * self.blocks.len() + b
    }

    /// Stores block `b`'s rows (row-major f32), widened.
    pub(super) fn write_block(&mut self, b: usize, y: &[f32]) -> Result<()> {
        let k = self.cols;
        for c in 0..k {
            self.piece.clear();
            self.piece.extend(y.chunks_exact(k).map(|row| row[c] as f64));
            self.scratch
                .put(self.key(c, b), bytemuck::cast_slice(&self.piece))?;
        }
        Ok(())
    }

    /// Block `b`'s rows (row-major f32), narrowed, into `out`.
    fn read_block(&mut self, b: usize, out: &mut Vec<f32>) -> Result<()> {
        let Block { row0, rows, .. } = self.blocks[b];
        self.read_rows(row0, rows, out)
    }

    /// Rows `r0..r0 + n` (row-major f32), narrowed, into `out`: of each
    /// column, only the pieces of the blocks they fall in.
    fn read_rows(&mut self, r0: usize, n: usize, out: &mut Vec<f32>) -> Result<()> {
        let k = self.cols;
        out.resize(n * k, 0.0);
        let mut piece = std::mem::take(&mut self.piece);
        piece.resize(n, 0.0);
        for c in 0..k {
            self.read(c, r0, &mut piece)?;
            for (row, &v) in out.chunks_exact_mut(k).zip(&piece) {
                row[c] = v as f32;
            }
        }
        self.piece = piece;
        Ok(())
    }

    /// Replaces the columns by their Q within `share` bytes: a panel of as
    /// many columns as it holds besides one ([`dense::qr_by_panels`]), or,
    /// when it holds fewer than two, the columns streamed in pieces of
    /// rows ([`dense::qr_in_rows`], three pieces held).
    pub(super) fn orthonormalize(&mut self, share: u64) -> Result<()> {
        let (rows, cols) = (self.rows, self.cols);
        let column = 8 * rows as u64;
        if share >= 2 * column {
            let panel = (share / column - 1) as usize;
            dense::qr_by_panels(self, rows, cols, panel)?;
        } else {
            dense::qr_in_rows(self, rows, cols, (share / 24) as usize)?;
        }
        Ok(())
    }
}

impl Columns for Stored {
    type Error = Error;
    fn read(&mut self, col: usize, r0: usize, out: &mut [f64]) -> Result<()> {
        for (b, lo, hi) in self.pieces(r0, out.len()) {
            let (key, at) = (self.key(col, b), (lo - self.blocks[b].row0) * 8);
            let part = &mut out[lo - r0..hi - r0];
            self.scratch
                .read_plain_at(key, at, bytemuck::cast_slice_mut(part))?;
        }
        Ok(())
    }
    fn write(&mut self, col: usize, r0: usize, data: &[f64]) -> Result<()> {
        for (b, lo, hi) in self.pieces(r0, data.len()) {
            let (key, at) = (self.key(col, b), (lo - self.blocks[b].row0) * 8);
            let part = &data[lo - r0..hi - r0];
            self.scratch.write_plain_at(key, at, bytemuck::cast_slice(part))?;
        }
        Ok(())
    }
}

impl Stored {
    /// The blocks rows `r0..r0 + n` fall in, each with the rows in it.
    fn pieces(&self, r0: usize, n: usize) -> Vec<(usize, usize, usize)> {
        let first = self.blocks.partition_point(|b| b.row0 + b.rows <= r0);
        (self.blocks[first..].iter().enumerate())
            .take_while(|(_, b)| b.row0 < r0 + n)
            .map(|(i, b)| (first + i, b.row0.max(r0), (b.row0 + b.rows).min(r0 + n)))
            .collect()
    }
}

/// [`orth`] of a matrix held whole, within `share` bytes. When its 12
/// bytes an entry do not fit, its columns go through a plain scratch file
/// beside `beside` (one block of all its rows) and are factored there
/// ([`Stored::orthonormalize`]): held then are `m` or the result (4 bytes
/// an entry) and what the QR holds within `share`.
pub(super) fn orth_within(m: Matrix, share: u64, beside: &Path) -> Result<Matrix> {
    let (rows, cols) = (m.rows, m.cols);
    if 12 * (rows * cols) as u64 <= share {
        return Ok(orth(m));
    }
    let block = Block {
        tiles: 0..0,
        row0: 0,
        rows,
    };
    let mut store = Stored::new(beside, vec![block], rows, cols)?;
    store.write_block(0, &m.data)?;
    drop(m);
    store.orthonormalize(share)?;
    let mut q = Vec::new();
    store.read_block(0, &mut q)?;
    Ok(Matrix { rows, cols, data: q })
}

/// Orthonormal basis of the columns (thin Householder QR in f64). `m` is
/// consumed as soon as it is copied: the peak is its f64 copy and the f32
/// result, 12 bytes per entry.
pub(super) fn orth(m: Matrix) -> Matrix {
    let (rows, cols) = (m.rows, m.cols);
    let a = m.column_major();
    drop(m);
    let q = dense::qr(a, rows, cols).q;
    Matrix::from_fn(rows, cols, |r, c| q[c * rows + r] as f32)
}

/// Where a store named `what` of the factorization `out` keeps its scratch
/// file (`.OUT.WHAT.PID-HOST-BOOT.scratch`): one name per store, so stores
/// alive at once never share a file.
pub(super) fn beside(out: &Path, what: &str) -> PathBuf {
    let name = out
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_default();
    out.with_file_name(format!("{name}.{what}"))
}
