//! The chunked tile container: the one place that knows bytes on disk
//! (docs/design.md section 2).
//!
//! One file per artifact:
//!
//! ```text
//! [header: 64 bytes]  magic "BTFQUILT", format version, offsets and lengths of
//!                     the metadata and index blocks, total file length, xxh3
//!                     of the header
//! [chunks ...]        each: element bytes → byte-shuffle → zstd
//! [metadata block]    xxh3 (8 bytes) + bincode(Metadata)
//! [index block]       xxh3 (8 bytes) + bincode(chunk entries per array)
//! ```
//!
//! Writers stream chunks out as they are produced, then append the metadata and
//! index, then fill in the header, into a temporary file that is renamed into
//! place only when complete: a killed run never leaves a file that looks
//! finished. Readers map the file (see `mmap`) and decode chunks on demand
//! into a cache bounded by a byte budget ([`MemoryBudget`]).

mod cache;
pub mod codec;
mod mmap;
mod scratch;

use std::fs::File;
use std::io::{BufWriter, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};
use std::sync::Arc;

use bincode::{Decode, Encode};

use cache::ChunkCache;
pub use cache::{BoundedCache, Held, MemoryBudget, SharedCache, Weighed};
pub use codec::{ChunkData, DType, Element, EncodedChunk};
use mmap::ByteSource;
pub use scratch::Scratch;

use crate::{Error, Result};

mod header;
mod spec;
mod writer;
pub use header::*;
pub use spec::*;
pub use writer::*;

/// The eight bytes every container starts with.
pub const MAGIC: [u8; 8] = *b"BTFQUILT";
/// The format version this build writes and the newest it reads.
pub const FORMAT_VERSION: u32 = 1;
const HEADER_LEN: usize = 64;
/// Default zstd level: 1-3 is the sweet spot for shuffled f16 data.
pub const DEFAULT_ZSTD_LEVEL: i32 = 3;

/// The zstd levels a container is written with.
pub const ZSTD_LEVELS: std::ops::RangeInclusive<i32> = 1..=19;

/// Errors unless `level` is one of [`ZSTD_LEVELS`].
pub fn check_level(level: i32) -> Result<()> {
    if ZSTD_LEVELS.contains(&level) {
        Ok(())
    } else {
        Err(Error::Config(format!(
            "zstd level {level}: must be {}..={}",
            ZSTD_LEVELS.start(),
            ZSTD_LEVELS.end()
        )))
    }
}
/// Most dimensions an array may have (the writers use up to 4).
pub const MAX_DIMS: usize = 8;
/// Largest decoded chunk, in bytes, that a reader will allocate. The writers'
/// chunks are far smaller (a few KiB to a few MiB: 64×64-texel tiles, 16×16
/// BTF tiles of one band, 65536 mesh rows); the bound keeps a crafted file
/// from asking for terabytes (readers check every spec on opening).
pub const MAX_CHUNK_BYTES: u64 = 1 << 30;
/// Largest decoded array, in bytes (256 TiB): big BTFs are streamed chunk by
/// chunk, so this only rules out sizes that overflow later arithmetic.
pub const MAX_ARRAY_BYTES: u64 = 1 << 48;
/// Most decoded bytes one stored byte can stand for: a zstd block holds at
/// most 128 KiB and takes at least 4 bytes (an RLE block), so no chunk decodes
/// to more than 32768 times its stored size (all-zero data comes close:
/// 1 GiB of zeros stores as ~33 KiB). Readers refuse arrays that claim more.
pub const MAX_ZSTD_RATIO: u64 = 32768;

fn bincode_config() -> impl bincode::config::Config {
    bincode::config::standard()
}

/// A decoded chunk of `T`, shared with the cache.
#[derive(Clone)]
pub struct Chunk<T: Element> {
    data: Arc<ChunkData>,
    _t: std::marker::PhantomData<T>,
}

impl<T: Element> std::ops::Deref for Chunk<T> {
    type Target = [T];
    fn deref(&self) -> &[T] {
        T::slice(&self.data).expect("dtype checked when the chunk was read")
    }
}

/// A finished artifact opened for reading.
pub struct Container {
    path: PathBuf,
    source: ByteSource,
    file_len: u64,
    meta: Metadata,
    index: Vec<Vec<ChunkEntry>>,
    content_hash: u64,
    cache: ChunkCache,
}

impl Container {
    /// Opens and validates an artifact; chunk data is decoded lazily into a
    /// cache of at most `budget` bytes.
    pub fn open(path: &Path, budget: MemoryBudget) -> Result<Container> {
        let file = File::open(path).map_err(|e| Error::io(path, e))?;
        let file_len = file.metadata().map_err(|e| Error::io(path, e))?.len();
        let source = ByteSource::new(file, path);
        let head_len = (HEADER_LEN as u64).min(file_len) as usize;
        let head = source
            .with_bytes(0, head_len, |b| b.to_vec())
            .map_err(|e| Error::io(path, e))?;
        let header = Header::parse(&head, path, file_len)?;
        let read_block = |o: u64, l: u64| {
            source
                .with_bytes(o, l as usize, |b| b.to_vec())
                .map_err(|e| Error::io(path, e))
        };
        let meta_bytes = read_block(header.meta_offset, header.meta_len)?;
        let index_bytes = read_block(header.index_offset, header.index_len)?;
        let meta: Metadata = decode_block(&meta_bytes, path, "metadata")?;
        let index: Vec<Vec<ChunkEntry>> = decode_block(&index_bytes, path, "chunk index")?;
        let bad_index = |reason: String| Error::Corrupt {
            path: path.to_path_buf(),
            array: "<chunk index>".into(),
            chunk: "-".into(),
            reason,
        };
        if index.len() != meta.arrays.len() {
            return Err(bad_index(format!(
                "{} arrays in the index, {} in the metadata",
                index.len(),
                meta.arrays.len()
            )));
        }
        for spec in &meta.arrays {
            spec.check()
                .map_err(|reason| Error::input(path, format!("array '{}': {reason}", spec.name)))?;
        }
        for (spec, entries) in meta.arrays.iter().zip(&index) {
            if entries.len() as u64 != spec.chunk_count() {
                return Err(bad_index(format!(
                    "array '{}' has {} chunks, expected {}",
                    spec.name,
                    entries.len(),
                    spec.chunk_count()
                )));
            }
            let stored = entries
                .iter()
                .fold(0u64, |acc, e| acc.saturating_add(e.stored_len));
            if spec.raw_bytes() > stored.saturating_mul(MAX_ZSTD_RATIO) {
                return Err(Error::input(
                    path,
                    format!(
                        "array '{}' declares {} of data ({} {}) in {} stored bytes, more than zstd can expand to",
                        spec.name,
                        human_bytes(spec.raw_bytes()),
                        dims(&spec.shape),
                        spec.dtype.name(),
                        stored
                    ),
                ));
            }
            if let Some(e) = entries.iter().find(|e| {
                e.offset
                    .checked_add(e.stored_len)
                    .map_or(true, |end| end > header.meta_offset)
            }) {
                return Err(bad_index(format!(
                    "array '{}' has a chunk at {}+{} outside the data region",
                    spec.name, e.offset, e.stored_len
                )));
            }
        }
        let mut hasher = xxhash_rust::xxh3::Xxh3::new();
        hasher.update(&meta_bytes);
        hasher.update(&index_bytes);
        let _ = header.version;
        Ok(Container {
            path: path.to_path_buf(),
            source,
            file_len,
            meta,
            index,
            content_hash: hasher.digest(),
            cache: ChunkCache::new(budget),
        })
    }

    /// Opens an artifact and checks that it is of `kind`.
    pub fn open_kind(path: &Path, kind: &str, budget: MemoryBudget) -> Result<Container> {
        let c = Container::open(path, budget)?;
        if c.meta.kind != kind {
            return Err(Error::input(
                path,
                format!("is a '{}' artifact, expected '{kind}'", c.meta.kind),
            ));
        }
        Ok(c)
    }

    /// The file this container was opened from.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Its metadata.
    pub fn metadata(&self) -> &Metadata {
        &self.meta
    }

    /// Hash identifying the content (metadata plus every chunk checksum).
    pub fn content_hash(&self) -> u64 {
        self.content_hash
    }

    /// File length in bytes.
    pub fn file_len(&self) -> u64 {
        self.file_len
    }

    /// Whether reads go through a memory map.
    pub fn is_mapped(&self) -> bool {
        self.source.is_mapped()
    }

    /// An array by name; the error names the file and the array.
    pub fn array(&self, name: &str) -> Result<ArrayId> {
        self.meta
            .arrays
            .iter()
            .position(|a| a.name == name)
            .map(|i| ArrayId(i as u32))
            .ok_or_else(|| Error::input(&self.path, format!("has no array named '{name}'")))
    }

    /// An array that must hold `dtype` in `shape`; `why` says where the
    /// expected shape comes from (e.g. "parameter 'resolution' is 100000").
    /// The error names the file, the array, what it is and what was expected.
    pub fn array_shaped(&self, name: &str, dtype: DType, shape: &[u64], why: &str) -> Result<ArrayId> {
        let id = self.array(name)?;
        let spec = self.spec(id);
        if spec.dtype != dtype || spec.shape != shape {
            return Err(Error::input(
                &self.path,
                format!(
                    "{why} but array '{name}' is {} {} (expected {} {})",
                    dims(&spec.shape),
                    spec.dtype.name(),
                    dims(shape),
                    dtype.name()
                ),
            ));
        }
        Ok(id)
    }

    /// The spec of an array.
    pub fn spec(&self, id: ArrayId) -> &ArraySpec {
        &self.meta.arrays[id.0 as usize]
    }

    /// Bytes the array occupies on disk (compressed chunks).
    pub fn stored_bytes(&self, id: ArrayId) -> u64 {
        self.index[id.0 as usize].iter().map(|e| e.stored_len).sum()
    }

    /// Reads one chunk (row-major elements of its clipped region), through the cache.
    pub fn read_chunk<T: Element>(&self, id: ArrayId, chunk: u64) -> Result<Chunk<T>> {
        let spec = self.spec(id);
        let corrupt = |reason: String| Error::Corrupt {
            path: self.path.clone(),
            array: spec.name.clone(),
            chunk: format!("{} {:?}", chunk, spec.chunk_coords(chunk)),
            reason,
        };
        if spec.dtype != T::DTYPE {
            return Err(Error::input(
                &self.path,
                format!(
                    "array '{}' holds {}, read as {}",
                    spec.name,
                    spec.dtype.name(),
                    T::DTYPE.name()
                ),
            ));
        }
        if chunk >= spec.chunk_count() {
            return Err(Error::input(
                &self.path,
                format!("array '{}' has no chunk {chunk}", spec.name),
            ));
        }
        let data = self.cache.get_or_load((id.0, chunk), || {
            let e = self.index[id.0 as usize][chunk as usize];
            self.source
                .with_bytes(e.offset, e.stored_len as usize, |bytes| {
                    codec::decode(bytes, spec.dtype, spec.chunk_len(chunk), e.checksum)
                })
                .map_err(|e| Error::io(&self.path, e))?
                .map_err(corrupt)
        })?;
        Ok(Chunk {
            data,
            _t: std::marker::PhantomData,
        })
    }

    /// Reads the region `origin + extent` of an array into a row-major vector,
    /// decoding only the chunks it touches.
    pub fn read_region<T: Element>(&self, id: ArrayId, origin: &[u64], extent: &[u64]) -> Result<Vec<T>> {
        let spec = self.spec(id).clone();
        let nd = spec.shape.len();
        if origin.len() != nd
            || extent.len() != nd
            || (0..nd).any(|d| {
                origin[d]
                    .checked_add(extent[d])
                    .map_or(true, |e| e > spec.shape[d])
            })
        {
            return Err(Error::Config(format!(
                "{}: region {origin:?}+{extent:?} is outside array '{}' of shape {:?}",
                self.path.display(),
                spec.name,
                spec.shape
            )));
        }
        // A region that is exactly one chunk is that chunk's values.
        if (0..nd).all(|d| origin[d] % spec.chunk_shape[d] == 0 && extent[d] > 0) {
            let cc: Vec<u64> = (0..nd).map(|d| origin[d] / spec.chunk_shape[d]).collect();
            let chunk_id = spec.chunk_index(&cc);
            if spec.chunk_region(chunk_id).1 == extent {
                return Ok(self.read_chunk::<T>(id, chunk_id)?.to_vec());
            }
        }
        let n = extent.iter().product::<u64>() as usize;
        let mut out = Vec::new();
        out.try_reserve_exact(n).map_err(|_| {
            Error::input(
                &self.path,
                format!(
                    "array '{}': cannot allocate {} for a region of {}",
                    spec.name,
                    human_bytes(n as u64 * spec.dtype.size() as u64),
                    dims(extent)
                ),
            )
        })?;
        out.resize(n, T::zeroed());
        // chunk-grid range that the region touches
        let lo: Vec<u64> = (0..nd).map(|d| origin[d] / spec.chunk_shape[d]).collect();
        let hi: Vec<u64> = (0..nd)
            .map(|d| {
                if extent[d] == 0 {
                    lo[d]
                } else {
                    (origin[d] + extent[d] - 1) / spec.chunk_shape[d] + 1
                }
            })
            .collect();
        if (0..nd).any(|d| hi[d] <= lo[d]) {
            return Ok(out);
        }
        let mut cc = lo.clone();
        loop {
            let chunk_id = spec.chunk_index(&cc);
            let (corg, cext) = spec.chunk_region(chunk_id);
            let data = self.read_chunk::<T>(id, chunk_id)?;
            // intersection of chunk and region
            let iorg: Vec<u64> = (0..nd).map(|d| corg[d].max(origin[d])).collect();
            let iext: Vec<u64> = (0..nd)
                .map(|d| (corg[d] + cext[d]).min(origin[d] + extent[d]) - iorg[d])
                .collect();
            let in_chunk: Vec<u64> = (0..nd).map(|d| iorg[d] - corg[d]).collect();
            let in_out: Vec<u64> = (0..nd).map(|d| iorg[d] - origin[d]).collect();
            let mut dst_rows = Vec::new();
            for_each_row(extent, &in_out, &iext, |o, _| dst_rows.push(o));
            let mut k = 0;
            for_each_row(&cext, &in_chunk, &iext, |src, len| {
                let dst = dst_rows[k];
                out[dst..dst + len].copy_from_slice(&data[src..src + len]);
                k += 1;
            });
            // next chunk coordinate
            let mut d = nd;
            loop {
                if d == 0 {
                    return Ok(out);
                }
                d -= 1;
                cc[d] += 1;
                if cc[d] < hi[d] {
                    break;
                }
                cc[d] = lo[d];
            }
        }
    }

    /// Reads a whole (small) array.
    pub fn read_array<T: Element>(&self, id: ArrayId) -> Result<Vec<T>> {
        let shape = self.spec(id).shape.clone();
        self.read_region(id, &vec![0; shape.len()], &shape)
    }

    /// Test support: the stored (still compressed) chunks of every array, in
    /// chunk order, to rewrite with [`write_unchecked`]. Not for use outside
    /// tests.
    #[doc(hidden)]
    pub fn stored_chunks(&self) -> Result<Vec<Vec<EncodedChunk>>> {
        let mut out = Vec::new();
        for (spec, entries) in self.meta.arrays.iter().zip(&self.index) {
            let mut array = Vec::new();
            for (c, e) in entries.iter().enumerate() {
                let bytes = self
                    .source
                    .with_bytes(e.offset, e.stored_len as usize, |b| b.to_vec())
                    .map_err(|err| Error::io(&self.path, err))?;
                array.push(EncodedChunk {
                    bytes,
                    checksum: e.checksum,
                    dtype: spec.dtype,
                    elements: spec.chunk_len(c as u64) as u64,
                });
            }
            out.push(array);
        }
        Ok(out)
    }

    /// Decodes and checks every chunk of every array (in parallel, bypassing
    /// the cache); reports the first damaged chunk in file-index order.
    pub fn verify(&self) -> Result<()> {
        use rayon::prelude::*;
        let chunks: Vec<(usize, u64)> = self
            .meta
            .arrays
            .iter()
            .enumerate()
            .flat_map(|(a, spec)| (0..spec.chunk_count()).map(move |c| (a, c)))
            .collect();
        let results: Vec<Result<()>> = chunks
            .par_iter()
            .map(|&(a, c)| {
                let spec = &self.meta.arrays[a];
                let e = self.index[a][c as usize];
                self.source
                    .with_bytes(e.offset, e.stored_len as usize, |bytes| {
                        codec::decode(bytes, spec.dtype, spec.chunk_len(c), e.checksum).map(|_| ())
                    })
                    .map_err(|e| Error::io(&self.path, e))?
                    .map_err(|reason| Error::Corrupt {
                        path: self.path.clone(),
                        array: spec.name.clone(),
                        chunk: format!("{} {:?}", c, spec.chunk_coords(c)),
                        reason,
                    })
            })
            .collect();
        results.into_iter().collect()
    }

    /// A human-readable description: metadata, and per array its shape,
    /// chunking, raw and stored size and compression ratio (`btfquilt info`).
    pub fn describe(&self) -> String {
        use std::fmt::Write as _;
        let m = &self.meta;
        let mut s = String::new();
        let _ = writeln!(s, "file:      {}", self.path.display());
        let _ = writeln!(s, "kind:      {}", m.kind);
        let _ = writeln!(
            s,
            "format:    version {FORMAT_VERSION}, {} bytes, written by {}",
            self.file_len, m.producer
        );
        let _ = writeln!(s, "content:   {:016x}", self.content_hash);
        if let Some(seed) = m.seed {
            let _ = writeln!(s, "seed:      {seed}");
        }
        for i in &m.inputs {
            let _ = writeln!(s, "input:     {} ({:016x})", i.name, i.hash);
        }
        if !m.params.is_empty() {
            let _ = writeln!(s, "params:");
            for (k, v) in &m.params {
                let _ = writeln!(s, "  {k} = {v}");
            }
        }
        let _ = writeln!(s, "arrays:");
        let (mut raw_total, mut stored_total) = (0u64, 0u64);
        for (a, spec) in m.arrays.iter().enumerate() {
            let raw = spec.raw_bytes();
            let stored = self.stored_bytes(ArrayId(a as u32));
            raw_total += raw;
            stored_total += stored;
            let _ = writeln!(
                s,
                "  {:<12} {:<4} shape {:?} chunks {:?} ({} chunks)  raw {}  stored {}  ratio {:.2}",
                spec.name,
                spec.dtype.name(),
                spec.shape,
                spec.chunk_shape,
                spec.chunk_count(),
                human_bytes(raw),
                human_bytes(stored),
                raw as f64 / stored.max(1) as f64
            );
        }
        let _ = writeln!(
            s,
            "total:     raw {}  stored {}  ratio {:.2}",
            human_bytes(raw_total),
            human_bytes(stored_total),
            raw_total as f64 / stored_total.max(1) as f64
        );
        s
    }
}

/// `[64, 64, 2]` → `"64×64×2"`.
pub fn dims(shape: &[u64]) -> String {
    shape.iter().map(|d| d.to_string()).collect::<Vec<_>>().join("×")
}

/// `1536` → `"1.50 KiB"`.
pub fn human_bytes(b: u64) -> String {
    const UNITS: [&str; 5] = ["B", "KiB", "MiB", "GiB", "TiB"];
    let mut v = b as f64;
    let mut u = 0;
    while v >= 1024.0 && u < UNITS.len() - 1 {
        v /= 1024.0;
        u += 1;
    }
    if u == 0 {
        format!("{b} B")
    } else {
        format!("{v:.2} {}", UNITS[u])
    }
}

/// What a file held, cheaply: its length and a content hash — for a
/// container, its [`Container::content_hash`] (metadata and every chunk's
/// checksum, read from its header); for any other file (an image, a mask),
/// the xxh3 of its bytes. Artifacts record it for each file they depend on,
/// and readers check it before trusting the file at that path.
pub fn file_identity(path: &Path) -> Result<(u64, u64)> {
    use std::io::Read;
    let mut file = File::open(path).map_err(|e| Error::io(path, e))?;
    let len = file.metadata().map_err(|e| Error::io(path, e))?.len();
    let mut head = [0u8; 8];
    let is_container = len >= HEADER_LEN as u64 && file.read_exact(&mut head).is_ok() && head == MAGIC;
    if is_container {
        let c = Container::open(path, MemoryBudget::default())?;
        return Ok((len, c.content_hash()));
    }
    file.seek(SeekFrom::Start(0)).map_err(|e| Error::io(path, e))?;
    let mut hasher = xxhash_rust::xxh3::Xxh3::new();
    let mut buf = vec![0u8; 1 << 20];
    loop {
        let n = file.read(&mut buf).map_err(|e| Error::io(path, e))?;
        if n == 0 {
            break;
        }
        hasher.update(&buf[..n]);
    }
    Ok((len, hasher.digest()))
}
