//! The geometry maps of a factorization whose tall matrices are stored
//! ([`Tall::Stored`]): written to the `.svd` a row of chunks at a time, and
//! kept as chunk records in a scratch file for the rotated copies, which
//! read each turned chunk's source window through a bounded cache
//! ([`rotate_from`] reads the same texels as from the whole maps).

use std::sync::{Arc, Mutex};

use super::tall::{beside, Tall};
use super::*;
use crate::container::{Scratch, SharedCache};
use stream::TileRows;

/// The geometry maps the rotated copies read: whole (image order) or as
/// chunk records.
pub(super) enum Maps<'a> {
    Whole(&'a [f32]),
    Chunks(Box<ChunkMaps>),
}

/// The geometry maps' chunks (`SVD_TILE`² texels × terms, f32, as in the
/// `.svd`) in a plain scratch file, read through a cache shared by the
/// threads that turn chunks.
pub(super) struct ChunkMaps {
    store: Mutex<Scratch>,
    spec: ArraySpec,
    cache: SharedCache<u64, Vec<f32>>,
}

/// The texels of the maps a turned region reads: along each axis `len`
/// positions from `lo`, wrapped on a tileable sample.
pub(super) struct Window {
    lo: [i64; 2],
    len: [usize; 2],
    size: [usize; 2],
    channels: usize,
    data: Vec<f32>,
}

impl Window {
    /// Texel (x, y) of the maps, which must lie in the window.
    #[inline]
    pub(super) fn texel(&self, x: usize, y: usize) -> &[f32] {
        // wrapped only on a tileable sample, and then rarely
        let at = |i: usize, v: usize| {
            let (d, n) = (v as i64 - self.lo[i], self.size[i] as i64);
            if (0..n).contains(&d) {
                d as usize
            } else {
                d.rem_euclid(n) as usize
            }
        };
        let t = at(1, y) * self.len[0] + at(0, x);
        &self.data[t * self.channels..(t + 1) * self.channels]
    }
}

/// Writes the stored `g` (tile order over `tiles`) as the geometry maps
/// array `id` of `c` (`width` × `height`), a row of chunks at a time, and
/// keeps each chunk beside `out` for the rotated copies (read through a
/// cache of `cache` bytes).
pub(super) fn write_stored(
    c: &mut ContainerWriter,
    id: ArrayId,
    g: &mut Tall,
    tiles: &[TileRows],
    width: usize,
    out: &Path,
    cache: MemoryBudget,
) -> Result<ChunkMaps> {
    let spec = c.spec(id).clone();
    let terms = g.cols();
    let grid = spec.chunk_grid();
    let mut store = Scratch::create_plain_beside(&beside(out, "maps"), spec.chunk_count() as usize)?;
    let (mut rows, mut band, mut chunk) = (Vec::new(), Vec::new(), Vec::new());
    for cy in 0..grid[0] {
        let (o, e) = spec.chunk_region(spec.chunk_index(&[cy, 0, 0]));
        let (y0, y1) = (o[0] as usize, (o[0] + e[0]) as usize);
        // the tiles over these rows are consecutive (tiles go row by row)
        let first = tiles.iter().position(|t| t.y0 + t.h > y0).unwrap_or(0);
        let end = first + tiles[first..].iter().take_while(|t| t.y0 < y1).count();
        g.tile_rows(tiles, first..end, &mut rows)?;
        band.clear();
        band.resize((y1 - y0) * width * terms, 0.0);
        let base = tiles[first].row0;
        for t in &tiles[first..end] {
            for r in 0..t.rows() {
                let (x, y) = (t.x0 + r % t.w, t.y0 + r / t.w);
                if (y0..y1).contains(&y) {
                    let (s, d) = ((t.row0 - base + r) * terms, ((y - y0) * width + x) * terms);
                    band[d..d + terms].copy_from_slice(&rows[s..s + terms]);
                }
            }
        }
        for cx in 0..grid[1] {
            let k = spec.chunk_index(&[cy, cx, 0]);
            let (o, e) = spec.chunk_region(k);
            let (x0, w) = (o[1] as usize, e[1] as usize);
            chunk.clear();
            for y in 0..y1 - y0 {
                chunk.extend_from_slice(&band[(y * width + x0) * terms..(y * width + x0 + w) * terms]);
            }
            c.write_chunk(id, k, &chunk)?;
            store.put(k as usize, bytemuck::cast_slice(&chunk))?;
        }
    }
    Ok(ChunkMaps {
        store: Mutex::new(store),
        spec,
        cache: SharedCache::new(cache),
    })
}

impl ChunkMaps {
    /// The texels [`rotate_from`] reads for `region` of the copy turned by
    /// `degrees`: the box about the region's corners turned back, two
    /// texels wider each way than the bilinear reads (clamped to the maps,
    /// or wrapped when `tileable`).
    pub(super) fn window(
        &self,
        degrees: f64,
        tileable: bool,
        (rx, ry, rw, rh): (usize, usize, usize, usize),
    ) -> Result<Window> {
        let (h, w, channels) = (
            self.spec.shape[0] as usize,
            self.spec.shape[1] as usize,
            self.spec.shape[2] as usize,
        );
        let (sin, cos) = math::sin_cos(degrees.to_radians());
        let (cx, cy) = ((w as f64 - 1.0) / 2.0, (h as f64 - 1.0) / 2.0);
        let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
        for (x, y) in [
            (rx, ry),
            (rx + rw - 1, ry),
            (rx, ry + rh - 1),
            (rx + rw - 1, ry + rh - 1),
        ] {
            let (dx, dy) = (x as f64 - cx, y as f64 - cy);
            let s = [cos * dx + sin * dy + cx, -sin * dx + cos * dy + cy];
            for i in 0..2 {
                lo[i] = lo[i].min(s[i]);
                hi[i] = hi[i].max(s[i]);
            }
        }
        let size = [w, h];
        let (mut from, mut len) = ([0i64; 2], [0usize; 2]);
        for i in 0..2 {
            let (a, b) = (lo[i].floor() as i64 - 2, hi[i].floor() as i64 + 3);
            let n = size[i] as i64;
            (from[i], len[i]) = if tileable {
                if b - a + 1 >= n {
                    (0, size[i])
                } else {
                    (a, (b - a + 1) as usize)
                }
            } else {
                let (a, b) = (a.max(0), b.min(n - 1));
                (a, (b - a + 1).max(0) as usize)
            };
        }
        // filled in order, a run of texels at a time
        let mut data = Vec::with_capacity(len[0] * len[1] * channels);
        let t = SVD_TILE as usize;
        let mut held: Vec<(u64, Arc<Vec<f32>>)> = Vec::new();
        for ly in 0..len[1] {
            let y = (from[1] + ly as i64).rem_euclid(h as i64) as usize;
            let mut lx = 0;
            while lx < len[0] {
                let x = (from[0] + lx as i64).rem_euclid(w as i64) as usize;
                // a run within one chunk and without a wrap
                let run = (t - x % t).min(w - x).min(len[0] - lx);
                let k = self.spec.chunk_index(&[(y / t) as u64, (x / t) as u64, 0]);
                let (o, e) = self.spec.chunk_region(k);
                // each chunk is looked up once per window
                let chunk = match held.iter().find(|(key, _)| *key == k) {
                    Some((_, c)) => c.clone(),
                    None => {
                        let c = self.chunk(k)?;
                        held.push((k, c.clone()));
                        c
                    }
                };
                let at = ((y - o[0] as usize) * e[1] as usize + x - o[1] as usize) * channels;
                data.extend_from_slice(&chunk[at..at + run * channels]);
                lx += run;
            }
        }
        Ok(Window {
            lo: from,
            len,
            size,
            channels,
            data,
        })
    }

    fn chunk(&self, k: u64) -> Result<Arc<Vec<f32>>> {
        self.cache.get_or_load(k, || {
            let mut c = vec![0f32; self.spec.chunk_len(k)];
            crate::lock(&self.store).read_plain(k as usize, bytemuck::cast_slice_mut(&mut c))?;
            Ok(c)
        })
    }
}
