//! Chunk encoding: element bytes → byte-shuffle → zstd, with an xxh3 checksum
//! of the decoded bytes (docs/design.md section 2).

use bincode::{Decode, Encode};
use half::f16;

/// Element type of a stored array.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, Encode, Decode)]
pub enum DType {
    F16,
    F32,
    U32,
    U8,
}

impl DType {
    /// Bytes per element.
    pub fn size(self) -> usize {
        match self {
            DType::F16 => 2,
            DType::F32 | DType::U32 => 4,
            DType::U8 => 1,
        }
    }

    /// Lower-case name for display.
    pub fn name(self) -> &'static str {
        match self {
            DType::F16 => "f16",
            DType::F32 => "f32",
            DType::U32 => "u32",
            DType::U8 => "u8",
        }
    }
}

/// The decoded elements of one chunk, typed.
#[derive(Debug, Clone, PartialEq)]
pub enum ChunkData {
    F16(Vec<f16>),
    F32(Vec<f32>),
    U32(Vec<u32>),
    U8(Vec<u8>),
}

impl ChunkData {
    /// Heap bytes held (for the cache budget).
    pub fn byte_len(&self) -> usize {
        match self {
            ChunkData::F16(v) => v.len() * 2,
            ChunkData::F32(v) => v.len() * 4,
            ChunkData::U32(v) => v.len() * 4,
            ChunkData::U8(v) => v.len(),
        }
    }
}

/// A plain-old-data element type that an array can hold.
pub trait Element: bytemuck::Pod + Send + Sync + 'static {
    /// The stored dtype.
    const DTYPE: DType;
    /// Borrow typed elements out of decoded chunk data of the same dtype.
    fn slice(data: &ChunkData) -> Option<&[Self]>;
    /// Wrap a vector as chunk data.
    fn wrap(v: Vec<Self>) -> ChunkData;
}

macro_rules! element {
    ($t:ty, $variant:ident) => {
        impl Element for $t {
            const DTYPE: DType = DType::$variant;
            fn slice(data: &ChunkData) -> Option<&[Self]> {
                match data {
                    ChunkData::$variant(v) => Some(v),
                    _ => None,
                }
            }
            fn wrap(v: Vec<Self>) -> ChunkData {
                ChunkData::$variant(v)
            }
        }
    };
}
element!(f16, F16);
element!(f32, F32);
element!(u32, U32);
element!(u8, U8);

#[cfg(target_endian = "big")]
compile_error!("btfquilt containers store little-endian elements; big-endian targets are not supported");

/// A chunk ready to be written: compressed bytes plus the checksum of the
/// decoded bytes.
#[derive(Debug, Clone)]
pub struct EncodedChunk {
    pub(crate) bytes: Vec<u8>,
    pub(crate) checksum: u64,
    pub(crate) dtype: DType,
    pub(crate) elements: u64,
}

impl EncodedChunk {
    /// Compressed size in bytes.
    pub fn stored_len(&self) -> usize {
        self.bytes.len()
    }
}

/// Checksum of decoded bytes (xxh3, 64-bit).
pub fn checksum(bytes: &[u8]) -> u64 {
    xxhash_rust::xxh3::xxh3_64(bytes)
}

/// Groups byte `b` of every element together: `out[b * n + i] = raw[i * size + b]`.
/// Neighbouring f16 values share their high bytes, which zstd then finds.
pub fn shuffle(raw: &[u8], size: usize) -> Vec<u8> {
    let mut out = vec![0u8; raw.len()];
    match size {
        1 => out.copy_from_slice(raw),
        2 => shuffle_n::<2>(raw, &mut out),
        4 => shuffle_n::<4>(raw, &mut out),
        _ => {
            let n = raw.len() / size;
            for (i, elem) in raw.chunks_exact(size).enumerate() {
                for (b, &byte) in elem.iter().enumerate() {
                    out[b * n + i] = byte;
                }
            }
        }
    }
    out
}

/// [`shuffle`] for a size known at compile time, so the inner loop unrolls.
fn shuffle_n<const S: usize>(raw: &[u8], out: &mut [u8]) {
    let n = raw.len() / S;
    for b in 0..S {
        let plane = &mut out[b * n..(b + 1) * n];
        for (o, e) in plane.iter_mut().zip(raw.chunks_exact(S)) {
            *o = e[b];
        }
    }
}

/// Inverse of [`shuffle`], writing into `out` (same length as `shuffled`).
pub fn unshuffle(shuffled: &[u8], size: usize, out: &mut [u8]) {
    match size {
        1 => out.copy_from_slice(shuffled),
        2 => unshuffle_n::<2>(shuffled, out),
        4 => unshuffle_n::<4>(shuffled, out),
        _ => {
            let n = shuffled.len() / size;
            for (i, elem) in out.chunks_exact_mut(size).enumerate() {
                for (b, byte) in elem.iter_mut().enumerate() {
                    *byte = shuffled[b * n + i];
                }
            }
        }
    }
}

/// [`unshuffle`] for a size known at compile time.
fn unshuffle_n<const S: usize>(shuffled: &[u8], out: &mut [u8]) {
    let n = shuffled.len() / S;
    let planes: [&[u8]; S] = std::array::from_fn(|b| &shuffled[b * n..(b + 1) * n]);
    for (i, elem) in out.chunks_exact_mut(S).enumerate() {
        for b in 0..S {
            elem[b] = planes[b][i];
        }
    }
}

/// Encodes elements: shuffle, zstd at `level` (1-3 recommended), checksum.
pub fn encode<T: Element>(values: &[T], level: i32) -> EncodedChunk {
    let raw: &[u8] = bytemuck::cast_slice(values);
    let shuffled = shuffle(raw, T::DTYPE.size());
    let bytes = compress(&shuffled, level);
    EncodedChunk {
        bytes,
        checksum: checksum(raw),
        dtype: T::DTYPE,
        elements: values.len() as u64,
    }
}

/// Decodes a stored chunk of `elements` values of `dtype`, verifying the
/// checksum. The error string says what is wrong (the caller adds file,
/// array and chunk). Never allocates more than the chunk's declared raw size
/// (which readers bound by [`super::MAX_CHUNK_BYTES`]), and nothing at all
/// when the zstd frame header announces a different size.
pub fn decode(stored: &[u8], dtype: DType, elements: usize, expect: u64) -> Result<ChunkData, String> {
    let raw_len = elements
        .checked_mul(dtype.size())
        .ok_or_else(|| format!("{elements} elements of {} overflow", dtype.name()))?;
    if raw_len as u64 > (stored.len() as u64).saturating_mul(super::MAX_ZSTD_RATIO) {
        return Err(format!(
            "{} stored bytes cannot decode to the chunk's {raw_len}",
            stored.len()
        ));
    }
    match zstd::zstd_safe::get_frame_content_size(stored) {
        Ok(Some(n)) if n != raw_len as u64 => {
            return Err(format!(
                "the compressed frame holds {n} bytes, the chunk {raw_len}"
            ))
        }
        Ok(_) => {}
        Err(_) => return Err("not a zstd frame".into()),
    }
    let shuffled = decompress(stored, raw_len).map_err(|e| format!("zstd: {e}"))?;
    if shuffled.len() != raw_len {
        return Err(format!("decoded {} bytes, expected {raw_len}", shuffled.len()));
    }
    fn typed<T: Element>(shuffled: &[u8], n: usize, expect: u64) -> Result<ChunkData, String> {
        let mut v = vec![T::zeroed(); n];
        let out: &mut [u8] = bytemuck::cast_slice_mut(&mut v);
        unshuffle(shuffled, T::DTYPE.size(), out);
        let got = checksum(out);
        if got != expect {
            return Err(format!("checksum mismatch (stored {expect:016x}, decoded bytes hash to {got:016x}): the file is corrupt"));
        }
        Ok(T::wrap(v))
    }
    match dtype {
        DType::F16 => typed::<f16>(&shuffled, elements, expect),
        DType::F32 => typed::<f32>(&shuffled, elements, expect),
        DType::U32 => typed::<u32>(&shuffled, elements, expect),
        DType::U8 => typed::<u8>(&shuffled, elements, expect),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_encoded_chunk_holds_about_its_compressed_bytes() {
        // a 64² tile of f32 that compresses well: chunks wait in batches
        // before they are written, and must not keep zstd's room for the
        // bound on their size (about the raw size)
        let values: Vec<f32> = (0..64 * 64).map(|i| (i / 64) as f32).collect();
        let e = encode(&values, 3);
        let raw = values.len() * 4;
        assert!(e.bytes.len() < raw / 20, "{} of {raw} bytes", e.bytes.len());
        assert!(
            e.bytes.capacity() < raw / 10,
            "{} bytes held for {} compressed",
            e.bytes.capacity(),
            e.bytes.len()
        );
        assert_eq!(
            decode(&e.bytes, DType::F32, values.len(), e.checksum).unwrap(),
            ChunkData::F32(values)
        );
    }

    #[test]
    fn shuffle_round_trips_and_groups_bytes() {
        let raw: Vec<u8> = (0..40u8).collect();
        let s = shuffle(&raw, 4);
        assert_eq!(&s[..10], &[0, 4, 8, 12, 16, 20, 24, 28, 32, 36]);
        let mut back = vec![0; 40];
        unshuffle(&s, 4, &mut back);
        assert_eq!(back, raw);
        // the sizes with their own loops agree with the general one
        let raw: Vec<u8> = (0..48u8).collect();
        let mut back = vec![0; 48];
        for size in [2, 3, 4, 8] {
            let n = raw.len() / size;
            let s = shuffle(&raw, size);
            for (i, &byte) in raw.iter().enumerate() {
                assert_eq!(s[(i % size) * n + i / size], byte, "size {size}");
            }
            unshuffle(&s, size, &mut back);
            assert_eq!(back, raw, "size {size}");
        }
    }

    #[test]
    fn encode_decode_round_trip_and_checksum_detects_change() {
        let v: Vec<f32> = (0..1000).map(|i| (i as f32).sin()).collect();
        let e = encode(&v, 3);
        let d = decode(&e.bytes, DType::F32, v.len(), e.checksum).unwrap();
        assert_eq!(d, ChunkData::F32(v.clone()));
        let err = decode(&e.bytes, DType::F32, v.len(), e.checksum ^ 1).unwrap_err();
        assert!(err.contains("checksum"), "{err}");
    }
}

thread_local! {
    /// One zstd decompression context per thread: making one per chunk
    /// costs more than decoding a small chunk.
    static DECOMPRESSOR: std::cell::RefCell<Option<zstd::bulk::Decompressor<'static>>> =
        const { std::cell::RefCell::new(None) };
}

/// zstd-decompresses `stored` into at most `capacity` bytes with this
/// thread's context.
pub(crate) fn decompress(stored: &[u8], capacity: usize) -> std::io::Result<Vec<u8>> {
    DECOMPRESSOR.with(|cell| {
        let mut cell = cell.borrow_mut();
        if cell.is_none() {
            *cell = Some(zstd::bulk::Decompressor::new()?);
        }
        cell.as_mut().expect("made above").decompress(stored, capacity)
    })
}

thread_local! {
    /// One zstd compression context per thread and level, for the same
    /// reason as [`DECOMPRESSOR`]; the frames are the ones a fresh context makes.
    static COMPRESSOR: std::cell::RefCell<Option<(i32, zstd::bulk::Compressor<'static>)>> =
        const { std::cell::RefCell::new(None) };
}

/// zstd-compresses `raw` at `level` with this thread's context.
fn compress(raw: &[u8], level: i32) -> Vec<u8> {
    const MSG: &str = "zstd compression of an in-memory buffer cannot fail";
    COMPRESSOR.with(|cell| {
        let mut cell = cell.borrow_mut();
        if cell.as_ref().map(|(l, _)| *l) != Some(level) {
            *cell = Some((level, zstd::bulk::Compressor::new(level).expect(MSG)));
        }
        let mut out = cell.as_mut().expect("made above").1.compress(raw).expect(MSG);
        // (made with room for the bound on the compressed size, about the
        // raw size: chunks held in batches before they are written would
        // keep it)
        out.shrink_to_fit();
        out
    })
}
