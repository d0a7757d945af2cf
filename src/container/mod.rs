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
pub use cache::{BoundedCache, MemoryBudget, SharedCache, Weighed};
pub use codec::{ChunkData, DType, Element, EncodedChunk};
use mmap::ByteSource;
pub use scratch::Scratch;

use crate::{Error, Result};

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

/// A named parameter value in an artifact's metadata.
#[derive(Clone, Debug, PartialEq, Encode, Decode)]
pub enum Param {
    Int(i64),
    Float(f64),
    Text(String),
    Floats(Vec<f64>),
}

impl std::fmt::Display for Param {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Param::Int(v) => write!(f, "{v}"),
            Param::Float(v) => write!(f, "{v}"),
            Param::Text(v) => write!(f, "{v:?}"),
            Param::Floats(v) if v.len() > 8 => write!(f, "[{} values]", v.len()),
            Param::Floats(v) => write!(f, "{v:?}"),
        }
    }
}

/// The hash of one input an artifact was made from.
#[derive(Clone, Debug, PartialEq, Encode, Decode)]
pub struct InputHash {
    /// What the input was (e.g. a file name or role).
    pub name: String,
    /// xxh3-64 of its content (for containers: of their metadata and index).
    pub hash: u64,
}

/// Shape and chunking of one named array.
#[derive(Clone, Debug, PartialEq, Eq, Encode, Decode)]
pub struct ArraySpec {
    pub name: String,
    pub dtype: DType,
    /// Extent per dimension, slowest first (row-major).
    pub shape: Vec<u64>,
    /// Chunk extent per dimension; edge chunks are clipped to the shape.
    pub chunk_shape: Vec<u64>,
}

impl ArraySpec {
    /// A spec; errors if it breaks a rule of [`ArraySpec::check`] (the
    /// dimensions disagree, a chunk extent is zero, a chunk is too large...).
    pub fn new(name: &str, dtype: DType, shape: &[u64], chunk_shape: &[u64]) -> Result<ArraySpec> {
        let spec = ArraySpec {
            name: name.to_string(),
            dtype,
            shape: shape.to_vec(),
            chunk_shape: chunk_shape.to_vec(),
        };
        spec.check()
            .map_err(|reason| Error::Config(format!("array '{name}': {reason}")))?;
        Ok(spec)
    }

    /// Checks that the spec can be read without overflow or an outsize
    /// allocation: 1..=[`MAX_DIMS`] dimensions, as many chunk extents as
    /// shape extents, every chunk extent positive, element and chunk counts
    /// that fit in `u64`, at most [`MAX_ARRAY_BYTES`] in all and at most
    /// [`MAX_CHUNK_BYTES`] per decoded chunk. Every other method of the spec
    /// assumes this holds; readers check it when opening a file, writers in
    /// [`ArraySpec::new`]. The error says what is wrong (the caller names
    /// the file and array).
    pub fn check(&self) -> std::result::Result<(), String> {
        let (shape, chunk) = (&self.shape, &self.chunk_shape);
        if shape.is_empty() || shape.len() > MAX_DIMS || shape.len() != chunk.len() {
            return Err(format!(
                "shape {shape:?} and chunk shape {chunk:?} must have the same number of dimensions, 1 to {MAX_DIMS}"
            ));
        }
        if chunk.iter().any(|&c| c == 0) {
            return Err(format!("chunk extents must be positive, got {chunk:?}"));
        }
        let size = self.dtype.size() as u64;
        let bytes = shape
            .iter()
            .try_fold(size, |acc, &s| acc.checked_mul(s))
            .filter(|&b| b <= MAX_ARRAY_BYTES);
        if bytes.is_none() {
            return Err(format!(
                "shape {shape:?} of {} exceeds the {} an array may hold",
                self.dtype.name(),
                human_bytes(MAX_ARRAY_BYTES)
            ));
        }
        // the largest (unclipped) chunk actually inside the shape
        let chunk_bytes = shape
            .iter()
            .zip(chunk)
            .try_fold(size, |acc, (&s, &c)| acc.checked_mul(s.min(c)))
            .filter(|&b| b <= MAX_CHUNK_BYTES);
        if chunk_bytes.is_none() {
            return Err(format!(
                "chunk shape {chunk:?} of {} exceeds the {} a decoded chunk may hold",
                self.dtype.name(),
                human_bytes(MAX_CHUNK_BYTES)
            ));
        }
        // the chunk grid is at most the element count, which fits (above)
        Ok(())
    }

    /// Number of chunks along each dimension.
    pub fn chunk_grid(&self) -> Vec<u64> {
        self.shape
            .iter()
            .zip(&self.chunk_shape)
            .map(|(&s, &c)| s.div_ceil(c))
            .collect()
    }

    /// Total number of chunks.
    pub fn chunk_count(&self) -> u64 {
        self.chunk_grid().iter().product()
    }

    /// Total number of elements.
    pub fn len(&self) -> u64 {
        self.shape.iter().product()
    }

    /// Whether the array has no elements.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Raw (decoded) size in bytes.
    pub fn raw_bytes(&self) -> u64 {
        self.len() * self.dtype.size() as u64
    }

    /// Linear chunk index of chunk-grid coordinates (row-major).
    pub fn chunk_index(&self, coords: &[u64]) -> u64 {
        let grid = self.chunk_grid();
        coords.iter().zip(&grid).fold(0, |acc, (&c, &g)| {
            debug_assert!(c < g);
            acc * g + c
        })
    }

    /// Chunk-grid coordinates of a linear chunk index.
    pub fn chunk_coords(&self, mut index: u64) -> Vec<u64> {
        let grid = self.chunk_grid();
        let mut coords = vec![0; grid.len()];
        for d in (0..grid.len()).rev() {
            coords[d] = index % grid[d];
            index /= grid[d];
        }
        coords
    }

    /// Element origin and clipped extent of a chunk.
    pub fn chunk_region(&self, index: u64) -> (Vec<u64>, Vec<u64>) {
        let coords = self.chunk_coords(index);
        let origin: Vec<u64> = coords
            .iter()
            .zip(&self.chunk_shape)
            .map(|(&c, &s)| c * s)
            .collect();
        let extent = origin
            .iter()
            .zip(&self.chunk_shape)
            .zip(&self.shape)
            .map(|((&o, &c), &s)| c.min(s - o))
            .collect();
        (origin, extent)
    }

    /// Number of elements in a (possibly clipped) chunk.
    pub fn chunk_len(&self, index: u64) -> usize {
        self.chunk_region(index).1.iter().product::<u64>() as usize
    }
}

/// Everything an artifact says about itself.
#[derive(Clone, Debug, PartialEq, Encode, Decode)]
pub struct Metadata {
    /// What the artifact is: "btf", "svd", "gim", "quilt", ...
    pub kind: String,
    /// The program that wrote it (name and version, no time stamp).
    pub producer: String,
    /// The seed of any random choice made while producing it.
    pub seed: Option<u64>,
    /// Hashes of the inputs it was made from.
    pub inputs: Vec<InputHash>,
    /// Named parameters, in insertion order.
    pub params: Vec<(String, Param)>,
    /// The arrays, in declaration order.
    pub arrays: Vec<ArraySpec>,
}

impl Metadata {
    /// A parameter by name.
    pub fn param(&self, name: &str) -> Option<&Param> {
        self.params.iter().find(|(k, _)| k == name).map(|(_, v)| v)
    }
}

/// Where one chunk sits in the file.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Encode, Decode)]
struct ChunkEntry {
    offset: u64,
    stored_len: u64,
    checksum: u64,
}

/// Index of an array within one container.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct ArrayId(pub u32);

struct Header {
    version: u32,
    meta_offset: u64,
    meta_len: u64,
    index_offset: u64,
    index_len: u64,
    file_len: u64,
}

impl Header {
    fn to_bytes(&self) -> [u8; HEADER_LEN] {
        let mut b = [0u8; HEADER_LEN];
        b[0..8].copy_from_slice(&MAGIC);
        b[8..12].copy_from_slice(&self.version.to_le_bytes());
        b[12..16].copy_from_slice(&(HEADER_LEN as u32).to_le_bytes());
        for (i, v) in [
            self.meta_offset,
            self.meta_len,
            self.index_offset,
            self.index_len,
            self.file_len,
        ]
        .iter()
        .enumerate()
        {
            b[16 + 8 * i..24 + 8 * i].copy_from_slice(&v.to_le_bytes());
        }
        let sum = codec::checksum(&b[..56]);
        b[56..64].copy_from_slice(&sum.to_le_bytes());
        b
    }

    fn parse(b: &[u8], path: &Path, actual_len: u64) -> Result<Header> {
        let not = |reason: &str| Error::NotContainer {
            path: path.to_path_buf(),
            reason: reason.to_string(),
        };
        if b.len() < 8 || b[0..8] != MAGIC {
            return Err(not("missing the BTFQUILT magic bytes"));
        }
        if b.len() < HEADER_LEN {
            return Err(Error::Truncated {
                path: path.to_path_buf(),
                expected: HEADER_LEN as u64,
                actual: actual_len,
            });
        }
        let u32_at = |i: usize| u32::from_le_bytes(b[i..i + 4].try_into().unwrap());
        let u64_at = |i: usize| u64::from_le_bytes(b[i..i + 8].try_into().unwrap());
        let version = u32_at(8);
        if version > FORMAT_VERSION {
            return Err(Error::UnsupportedVersion {
                path: path.to_path_buf(),
                found: version,
                supported: FORMAT_VERSION,
            });
        }
        if version == 0 {
            return Err(not("format version 0 (an unfinished file)"));
        }
        if u64_at(56) != codec::checksum(&b[..56]) {
            return Err(not("header checksum mismatch (damaged header)"));
        }
        let h = Header {
            version,
            meta_offset: u64_at(16),
            meta_len: u64_at(24),
            index_offset: u64_at(32),
            index_len: u64_at(40),
            file_len: u64_at(48),
        };
        if actual_len < h.file_len {
            return Err(Error::Truncated {
                path: path.to_path_buf(),
                expected: h.file_len,
                actual: actual_len,
            });
        }
        let end = |o: u64, l: u64| o.checked_add(l).is_some_and(|e| e <= h.file_len);
        if !end(h.meta_offset, h.meta_len) || !end(h.index_offset, h.index_len) {
            return Err(not("header block offsets point outside the file"));
        }
        Ok(h)
    }
}

fn encode_block<T: Encode>(value: &T) -> Vec<u8> {
    let body =
        bincode::encode_to_vec(value, bincode_config()).expect("encoding metadata into a Vec cannot fail");
    let mut out = Vec::with_capacity(body.len() + 8);
    out.extend_from_slice(&codec::checksum(&body).to_le_bytes());
    out.extend_from_slice(&body);
    out
}

fn decode_block<T: Decode<()>>(bytes: &[u8], path: &Path, what: &str) -> Result<T> {
    let corrupt = |reason: String| Error::Corrupt {
        path: path.to_path_buf(),
        array: format!("<{what}>"),
        chunk: "-".into(),
        reason,
    };
    if bytes.len() < 8 {
        return Err(corrupt("block too short".into()));
    }
    let (sum, body) = bytes.split_at(8);
    if u64::from_le_bytes(sum.try_into().unwrap()) != codec::checksum(body) {
        return Err(corrupt("checksum mismatch".into()));
    }
    let (value, _) = bincode::decode_from_slice(body, bincode_config())
        .map_err(|e| corrupt(format!("cannot decode: {e}")))?;
    Ok(value)
}

/// Streams an artifact to disk: declare arrays, write chunks in any order,
/// [`finish`](ContainerWriter::finish). Until `finish` returns, the data sits
/// in a temporary file beside the destination that is deleted if the writer is
/// dropped (or the process killed before the rename).
pub struct ContainerWriter {
    path: PathBuf,
    tmp: Option<tempfile::NamedTempFile>,
    out: BufWriter<File>,
    offset: u64,
    meta: Metadata,
    index: Vec<Vec<Option<ChunkEntry>>>,
    level: i32,
}

impl ContainerWriter {
    /// Starts an artifact of `kind` that will be renamed to `path`.
    pub fn create(path: &Path, kind: &str) -> Result<ContainerWriter> {
        let tmp = crate::io::staging::staged_file(path)?;
        let file = tmp.as_file().try_clone().map_err(|e| Error::io(path, e))?;
        let mut out = BufWriter::with_capacity(1 << 20, file);
        // A zeroed header (version 0) marks the file unfinished until `finish`.
        out.write_all(&[0u8; HEADER_LEN])
            .map_err(|e| Error::io(path, e))?;
        Ok(ContainerWriter {
            path: path.to_path_buf(),
            tmp: Some(tmp),
            out,
            offset: HEADER_LEN as u64,
            meta: Metadata {
                kind: kind.to_string(),
                producer: concat!("btfquilt ", env!("CARGO_PKG_VERSION")).to_string(),
                seed: None,
                inputs: Vec::new(),
                params: Vec::new(),
                arrays: Vec::new(),
            },
            index: Vec::new(),
            level: DEFAULT_ZSTD_LEVEL,
        })
    }

    /// The zstd level used by [`write_chunk`](Self::write_chunk).
    pub fn level(&self) -> i32 {
        self.level
    }

    /// Sets the zstd level (1-19).
    pub fn set_level(&mut self, level: i32) {
        self.level = level.clamp(*ZSTD_LEVELS.start(), *ZSTD_LEVELS.end());
    }

    /// Records the seed.
    pub fn set_seed(&mut self, seed: u64) {
        self.meta.seed = Some(seed);
    }

    /// Records (or replaces) a parameter.
    pub fn set_param(&mut self, name: &str, value: Param) {
        match self.meta.params.iter_mut().find(|(k, _)| k == name) {
            Some(slot) => slot.1 = value,
            None => self.meta.params.push((name.to_string(), value)),
        }
    }

    /// Records the hash of an input.
    pub fn add_input(&mut self, name: &str, hash: u64) {
        self.meta.inputs.push(InputHash {
            name: name.to_string(),
            hash,
        });
    }

    /// Declares an array; its chunks may then be written.
    pub fn add_array(&mut self, spec: ArraySpec) -> Result<ArrayId> {
        if self.meta.arrays.iter().any(|a| a.name == spec.name) {
            return Err(Error::Config(format!("array '{}' declared twice", spec.name)));
        }
        self.index.push(vec![None; spec.chunk_count() as usize]);
        self.meta.arrays.push(spec);
        Ok(ArrayId(self.meta.arrays.len() as u32 - 1))
    }

    /// The spec of a declared array.
    pub fn spec(&self, id: ArrayId) -> &ArraySpec {
        &self.meta.arrays[id.0 as usize]
    }

    /// Encodes and writes one chunk (row-major elements of its clipped region).
    pub fn write_chunk<T: Element>(&mut self, id: ArrayId, chunk: u64, values: &[T]) -> Result<()> {
        let encoded = codec::encode(values, self.level);
        self.write_encoded(id, chunk, encoded)
    }

    /// Writes a chunk encoded elsewhere (e.g. in parallel with [`codec::encode`]).
    pub fn write_encoded(&mut self, id: ArrayId, chunk: u64, encoded: EncodedChunk) -> Result<()> {
        let spec = self
            .meta
            .arrays
            .get(id.0 as usize)
            .ok_or_else(|| Error::Config(format!("no array {id:?}")))?;
        let bad = |reason: String| Error::Config(format!("array '{}', chunk {chunk}: {reason}", spec.name));
        if encoded.dtype != spec.dtype {
            return Err(bad(format!(
                "dtype {} written to a {} array",
                encoded.dtype.name(),
                spec.dtype.name()
            )));
        }
        if chunk >= spec.chunk_count() {
            return Err(bad(format!("out of range ({} chunks)", spec.chunk_count())));
        }
        let expect = spec.chunk_len(chunk) as u64;
        if encoded.elements != expect {
            return Err(bad(format!(
                "{} elements given, the chunk holds {expect}",
                encoded.elements
            )));
        }
        let slot = &mut self.index[id.0 as usize][chunk as usize];
        if slot.is_some() {
            return Err(bad("written twice".into()));
        }
        self.out
            .write_all(&encoded.bytes)
            .map_err(|e| Error::io(&self.path, e))?;
        *slot = Some(ChunkEntry {
            offset: self.offset,
            stored_len: encoded.bytes.len() as u64,
            checksum: encoded.checksum,
        });
        self.offset += encoded.bytes.len() as u64;
        Ok(())
    }

    /// Writes a whole small array from one slice (row-major), chunk by chunk.
    pub fn write_array<T: Element>(&mut self, id: ArrayId, values: &[T]) -> Result<()> {
        let spec = self.spec(id).clone();
        if values.len() as u64 != spec.len() {
            return Err(Error::Config(format!(
                "array '{}': {} values given for shape {:?}",
                spec.name,
                values.len(),
                spec.shape
            )));
        }
        let mut buf = Vec::new();
        for c in 0..spec.chunk_count() {
            let (origin, extent) = spec.chunk_region(c);
            buf.clear();
            for_each_row(&spec.shape, &origin, &extent, |src, len| {
                buf.extend_from_slice(&values[src..src + len])
            });
            self.write_chunk(id, c, &buf)?;
        }
        Ok(())
    }

    /// Appends metadata and index, writes the header, syncs, and renames the
    /// file into place. Fails (leaving nothing at the destination) if any
    /// declared chunk was not written.
    pub fn finish(mut self) -> Result<()> {
        let mut index = Vec::with_capacity(self.index.len());
        for (a, entries) in self.index.iter().enumerate() {
            let mut full = Vec::with_capacity(entries.len());
            for (c, e) in entries.iter().enumerate() {
                full.push(e.ok_or_else(|| {
                    Error::Config(format!(
                        "array '{}': chunk {c} was never written",
                        self.meta.arrays[a].name
                    ))
                })?);
            }
            index.push(full);
        }
        let meta_block = encode_block(&self.meta);
        let index_block = encode_block(&index);
        let path = self.path.clone();
        let io = |e| Error::io(&path, e);
        let meta_offset = self.offset;
        self.out.write_all(&meta_block).map_err(io)?;
        let index_offset = meta_offset + meta_block.len() as u64;
        self.out.write_all(&index_block).map_err(io)?;
        let header = Header {
            version: FORMAT_VERSION,
            meta_offset,
            meta_len: meta_block.len() as u64,
            index_offset,
            index_len: index_block.len() as u64,
            file_len: index_offset + index_block.len() as u64,
        };
        self.out.flush().map_err(io)?;
        let file = self.out.get_mut();
        file.seek(SeekFrom::Start(0)).map_err(io)?;
        file.write_all(&header.to_bytes()).map_err(io)?;
        file.sync_all().map_err(io)?;
        let tmp = self.tmp.take().expect("finish runs once");
        tmp.persist(&self.path).map_err(|e| Error::io(&path, e.error))?;
        Ok(())
    }
}

/// Test support: writes `meta` and the given stored chunks (per array, in
/// chunk order) as a finished container at `path`, with valid checksums but
/// WITHOUT checking anything — so tests can craft hostile files that the
/// readers must refuse. Not for use outside tests.
#[doc(hidden)]
pub fn write_unchecked(path: &Path, meta: &Metadata, chunks: &[Vec<EncodedChunk>]) -> Result<()> {
    let mut bytes = vec![0u8; HEADER_LEN];
    let mut index = Vec::new();
    for array in chunks {
        let mut entries = Vec::new();
        for c in array {
            entries.push(ChunkEntry {
                offset: bytes.len() as u64,
                stored_len: c.bytes.len() as u64,
                checksum: c.checksum,
            });
            bytes.extend_from_slice(&c.bytes);
        }
        index.push(entries);
    }
    let meta_offset = bytes.len() as u64;
    let meta_block = encode_block(meta);
    bytes.extend_from_slice(&meta_block);
    let index_offset = bytes.len() as u64;
    let index_block = encode_block(&index);
    bytes.extend_from_slice(&index_block);
    let header = Header {
        version: FORMAT_VERSION,
        meta_offset,
        meta_len: meta_block.len() as u64,
        index_offset,
        index_len: index_block.len() as u64,
        file_len: bytes.len() as u64,
    };
    bytes[..HEADER_LEN].copy_from_slice(&header.to_bytes());
    std::fs::write(path, bytes).map_err(|e| Error::io(path, e))
}

/// Calls `f(source_offset, len)` for every contiguous innermost row of the
/// region `origin + extent` inside a row-major array of `shape`.
pub(crate) fn for_each_row(shape: &[u64], origin: &[u64], extent: &[u64], mut f: impl FnMut(usize, usize)) {
    let nd = shape.len();
    if extent.iter().any(|&e| e == 0) {
        return;
    }
    let row_len = extent[nd - 1] as usize;
    let mut idx = vec![0u64; nd - 1];
    loop {
        let mut off = 0u64;
        for d in 0..nd {
            let i = if d < nd - 1 { origin[d] + idx[d] } else { origin[d] };
            off = off * shape[d] + i;
        }
        f(off as usize, row_len);
        // advance the multi-index over the outer dimensions
        let mut d = nd - 1;
        loop {
            if d == 0 {
                return;
            }
            d -= 1;
            idx[d] += 1;
            if idx[d] < extent[d] {
                break;
            }
            idx[d] = 0;
        }
    }
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
