//! The byte source under a container reader: a read-only memory map, with
//! plain positioned reads as the fallback.
//!
//! This module holds the crate's only `unsafe` code.
//!
//! # Safety contract
//!
//! Mapping a file is only sound while no one truncates or rewrites it; a
//! truncated mapping raises `SIGBUS` and a rewritten one changes bytes under a
//! `&[u8]`. btfquilt upholds its side: a finished artifact is never modified in
//! place (every writer writes a temporary file and renames it over the
//! destination, which leaves the inode that readers have mapped untouched).
//! Other programs must not modify an artifact while btfquilt reads it, the same
//! contract as any memory-mapping tool.
//!
//! What btfquilt does when someone breaks the contract anyway: before every
//! read through the map it asks the kept file handle for the file's current
//! length (one `fstat`, well under a microsecond next to decoding a chunk) and
//! returns an I/O error naming the file — "changed size while being read (was
//! N bytes, now M)" — instead of touching the mapping if the file shrank. This
//! turns the common accident (an artifact truncated or overwritten in place
//! by another program while a long `tile`/`bake` runs) into a clean error. It
//! cannot close the race entirely: a file truncated between the check and the
//! access (within the one `f` call) still raises `SIGBUS`; btfquilt installs
//! no signal handler to catch it. Bytes rewritten in place at the same size
//! are caught by the chunk checksums: every chunk's decoded bytes are verified.
//! Set `BTFQUILT_NO_MMAP=1` to use plain reads instead (slower on random access,
//! no contract needed: a shrunk file then gives an ordinary read error).
#![allow(unsafe_code)]

use std::fs::File;
use std::path::Path;
use std::sync::atomic::{AtomicU64, Ordering};

use memmap2::{Mmap, UncheckedAdvice};

/// After this many bytes read through the map, its pages are released.
const RELEASE_EVERY: u64 = 32 << 20;
/// Each read counts as at least this many bytes: a fault may map a whole
/// page-cache folio (up to megabytes) around a small chunk, so many small
/// reads map far more than they read.
const READ_CHARGE: u64 = RELEASE_EVERY / 32;

/// Read-only random access to the bytes of one file.
pub(crate) enum ByteSource {
    /// The whole file mapped read-only, the file (to check its length before
    /// each read), and the bytes read since its pages were last released.
    Mapped(Mmap, File, AtomicU64),
    /// Positioned reads (`pread`) on the open file.
    Plain(File),
}

impl ByteSource {
    /// Opens `file` for reading: a memory map unless `BTFQUILT_NO_MMAP` is set
    /// or mapping fails (then plain reads).
    pub(crate) fn new(file: File, _path: &Path) -> ByteSource {
        let no_mmap = std::env::var_os("BTFQUILT_NO_MMAP").is_some_and(|v| v != "0");
        if !no_mmap {
            // SAFETY: the file is opened read-only and the module's safety
            // contract above holds: btfquilt never modifies a finished artifact
            // in place, and the mapping is only ever read through `&[u8]`.
            if let Ok(map) = unsafe { Mmap::map(&file) } {
                // Chunks are read in any order: no readahead into large folios
                // that a fault would then map whole.
                let _ = map.advise(memmap2::Advice::Random);
                return ByteSource::Mapped(map, file, AtomicU64::new(0));
            }
        }
        ByteSource::Plain(file)
    }

    /// Calls `f` with the bytes `[offset, offset + len)`. The caller has
    /// checked the range against the file length.
    pub(crate) fn with_bytes<R>(
        &self,
        offset: u64,
        len: usize,
        f: impl FnOnce(&[u8]) -> R,
    ) -> std::io::Result<R> {
        match self {
            ByteSource::Mapped(map, file, since_release) => {
                let start = usize::try_from(offset).unwrap_or(usize::MAX);
                let bytes = start
                    .checked_add(len)
                    .and_then(|end| map.get(start..end))
                    .ok_or_else(|| {
                        std::io::Error::new(std::io::ErrorKind::UnexpectedEof, "range past end of file")
                    })?;
                // A file truncated under the map would raise SIGBUS on access:
                // refuse instead (see the module's safety contract).
                let was = map.len() as u64;
                let now = file.metadata()?.len();
                if now < was {
                    return Err(std::io::Error::new(
                        std::io::ErrorKind::UnexpectedEof,
                        format!("changed size while being read (was {was} bytes, now {now})"),
                    ));
                }
                // Random advice turns readahead off, so a range not in the
                // page cache would come in a page per fault: ask for all of it
                // at once.
                if len > 4096 {
                    let _ = map.advise_range(memmap2::Advice::WillNeed, start, len);
                }
                let out = f(bytes);
                // Decoded chunks live in the cache; mapped pages would only
                // add to resident memory (and the kernel maps whole page-cache
                // folios around each fault, far beyond the chunk read). Every
                // RELEASE_EVERY bytes (or 32 reads), let the kernel drop them all, so resident
                // memory stays bounded by the cache budget, not the file size.
                let charge = (len as u64).max(READ_CHARGE);
                if since_release.fetch_add(charge, Ordering::Relaxed) + charge >= RELEASE_EVERY {
                    since_release.store(0, Ordering::Relaxed);
                    // SAFETY: MADV_DONTNEED on a read-only, file-backed mapping
                    // only discards this process's page-table entries; the next
                    // access faults the unchanged file contents back in, so a
                    // range another thread is reading right now stays correct.
                    // No Rust reference into the map outlives its `f` call.
                    let _ = unsafe { map.unchecked_advise(UncheckedAdvice::DontNeed) };
                }
                Ok(out)
            }
            ByteSource::Plain(file) => {
                let mut buf = vec![0u8; len];
                read_exact_at(file, &mut buf, offset)?;
                Ok(f(&buf))
            }
        }
    }

    /// Whether reads go through a memory map (for `info`).
    pub(crate) fn is_mapped(&self) -> bool {
        matches!(self, ByteSource::Mapped(..))
    }
}

#[cfg(unix)]
fn read_exact_at(file: &File, buf: &mut [u8], offset: u64) -> std::io::Result<()> {
    std::os::unix::fs::FileExt::read_exact_at(file, buf, offset)
}

#[cfg(not(unix))]
fn read_exact_at(file: &File, buf: &mut [u8], offset: u64) -> std::io::Result<()> {
    use std::io::{Read, Seek, SeekFrom};
    let mut f = file.try_clone()?;
    f.seek(SeekFrom::Start(offset))?;
    f.read_exact(buf)
}
