//! The fixed header and the bincode blocks behind it (metadata and
//! chunk index), encoded and decoded with checks.

use super::*;

/// Where one chunk sits in the file.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Encode, Decode)]
pub(super) struct ChunkEntry {
    pub(super) offset: u64,
    pub(super) stored_len: u64,
    pub(super) checksum: u64,
}

/// Index of an array within one container.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct ArrayId(pub u32);

pub(super) struct Header {
    pub(super) version: u32,
    pub(super) meta_offset: u64,
    pub(super) meta_len: u64,
    pub(super) index_offset: u64,
    pub(super) index_len: u64,
    file_len: u64,
}

impl Header {
    /// The header of a file that ends with its metadata block (`meta_len`
    /// bytes at `meta_offset`) followed by its index block (`index_len`).
    pub(super) fn for_trailer(meta_offset: u64, meta_len: u64, index_len: u64) -> Header {
        let index_offset = meta_offset + meta_len;
        Header {
            version: FORMAT_VERSION,
            meta_offset,
            meta_len,
            index_offset,
            index_len,
            file_len: index_offset + index_len,
        }
    }

    pub(super) fn to_bytes(&self) -> [u8; HEADER_LEN] {
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

    pub(super) fn parse(b: &[u8], path: &Path, actual_len: u64) -> Result<Header> {
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

pub(super) fn encode_block<T: Encode>(value: &T) -> Vec<u8> {
    let body =
        bincode::encode_to_vec(value, bincode_config()).expect("encoding metadata into a Vec cannot fail");
    let mut out = Vec::with_capacity(body.len() + 8);
    out.extend_from_slice(&codec::checksum(&body).to_le_bytes());
    out.extend_from_slice(&body);
    out
}

pub(super) fn decode_block<T: Decode<()>>(bytes: &[u8], path: &Path, what: &str) -> Result<T> {
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
