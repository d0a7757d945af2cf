//!  Element>:Writing a container: chunks compressed in parallel, streamed to a
//! staged file and renamed into place when complete.

use super::*;

/// Streams an artifact to disk: declare arrays, write chunks in any order,
/// [`finish`](ContainerWriter::finish). Until `finish` returns, the data sits
/// in a temporary file beside the destination that is deleted if the writer is
/// dropped (or the process killed before the rename).
pub struct ContainerWriter {
    pub(super) path: PathBuf,
    tmp: Option<tempfile::NamedTempFile>,
    out: BufWriter<File>,
    pub(super) offset: u64,
    meta: Metadata,
    pub(super) index: Vec<Vec<Option<ChunkEntry>>>,
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
        self.out.write_all(&index_block).map_err(io)?;
        let header = Header::for_trailer(meta_offset, meta_block.len() as u64, index_block.len() as u64);
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
    let index_block = encode_block(&index);
    bytes.extend_from_slice(&index_block);
    let header = Header::for_trailer(meta_offset, meta_block.len() as u64, index_block.len() as u64);
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
