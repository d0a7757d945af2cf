//! A scratch store beside an output: evicted atlas tiles written back
//! compressed (zstd) while a long run pages its working set, or records
//! kept as they are (the factorization's f64 columns, which do not
//! compress) while a matrix is taken apart column by column. It is named
//! after the output and the process (`.NAME.PID-HOST-BOOT.scratch`), removed when
//! dropped, and removed by the next run beside the same output if the
//! process that made it died (on Linux, where a dead process is seen in
//! `/proc`; elsewhere only a file of the same process id is replaced).

use std::fs::{File, OpenOptions};
use std::io::{Read, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};

use crate::{Error, Result};

/// zstd level of written-back tiles: fast, they are read back soon.
const LEVEL: i32 = 1;

/// Where a record sits in the scratch file and its stored length.
#[derive(Clone, Copy, Debug)]
struct Extent {
    offset: u64,
    stored: u32,
    capacity: u32,
}

/// Records by key (small integers: tile ids) in one file; a rewritten record
/// reuses its extent when it fits, else goes to the end.
pub struct Scratch {
    path: PathBuf,
    file: File,
    end: u64,
    extents: Vec<Option<Extent>>,
    written: u64,
    /// `None` for a store of plain records.
    compressor: Option<zstd::bulk::Compressor<'static>>,
}

impl Scratch {
    /// The scratch path of an output for process `pid`.
    pub fn path_for(output: &Path, pid: u32) -> PathBuf {
        let writer = crate::io::staging::Writer {
            pid,
            machine: Some(crate::io::staging::this_machine()),
        };
        output.with_file_name(format!(".{}.{writer}.scratch", Self::name_of(output)))
    }

    fn name_of(output: &Path) -> String {
        output
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_else(|| "output".into())
    }

    /// Removes the scratch files beside `output` of processes that are gone.
    fn remove_stale(output: &Path) {
        let (prefix, suffix) = (format!(".{}.", Self::name_of(output)), ".scratch");
        let dir = match output.parent() {
            Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
            _ => PathBuf::from("."),
        };
        let Ok(entries) = std::fs::read_dir(&dir) else {
            return;
        };
        let me = crate::io::staging::Writer::me();
        for e in entries.flatten() {
            let name = e.file_name().to_string_lossy().into_owned();
            let Some(writer) = name
                .strip_prefix(&prefix)
                .and_then(|r| r.strip_suffix(suffix))
                .and_then(crate::io::staging::Writer::parse)
            else {
                continue;
            };
            // this process's own (left by an earlier store of the same
            // output), or a writer known to be gone
            let mine = writer.pid == me.pid && writer.machine.map_or(true, |m| Some(m) == me.machine);
            if mine || writer.is_gone() {
                let _ = std::fs::remove_file(e.path());
            }
        }
    }

    /// A fresh scratch store beside `output` for keys `0..keys`, after
    /// removing those dead runs left.
    pub fn create_beside(output: &Path, keys: usize) -> Result<Scratch> {
        Self::remove_stale(output);
        let path = Self::path_for(output, std::process::id());
        let file = OpenOptions::new()
            .read(true)
            .write(true)
            .create(true)
            .truncate(true)
            .open(&path)
            .map_err(|e| Error::io(&path, e))?;
        let compressor = Some(zstd::bulk::Compressor::new(LEVEL).map_err(|e| Error::io(&path, e))?);
        Ok(Scratch {
            path,
            file,
            end: 0,
            extents: vec![None; keys],
            written: 0,
            compressor,
        })
    }

    /// [`Scratch::create_beside`] for records stored as they are, read back
    /// with [`Scratch::read_plain`].
    pub fn create_plain_beside(output: &Path, keys: usize) -> Result<Scratch> {
        let mut s = Self::create_beside(output, keys)?;
        s.compressor = None;
        Ok(s)
    }

    /// Whether `key` holds a record.
    pub fn contains(&self, key: usize) -> bool {
        self.extents[key].is_some()
    }

    /// Bytes written so far (compressed), for reports.
    pub fn written(&self) -> u64 {
        self.written
    }

    /// Stores `bytes` under `key`, compressed unless the store is plain.
    pub fn put(&mut self, key: usize, bytes: &[u8]) -> Result<()> {
        let packed = match &mut self.compressor {
            Some(c) => std::borrow::Cow::Owned(c.compress(bytes).map_err(|e| Error::io(&self.path, e))?),
            None => std::borrow::Cow::Borrowed(bytes),
        };
        let stored = packed.len() as u32;
        let extent = match self.extents[key] {
            Some(e) if e.capacity >= stored => Extent { stored, ..e },
            _ => {
                let e = Extent {
                    offset: self.end,
                    stored,
                    capacity: stored,
                };
                self.end += stored as u64;
                e
            }
        };
        self.file
            .seek(SeekFrom::Start(extent.offset))
            .and_then(|_| self.file.write_all(&packed))
            .map_err(|e| Error::io(&self.path, e))?;
        self.extents[key] = Some(extent);
        self.written += stored as u64;
        Ok(())
    }

    fn extent(&self, key: usize) -> Result<Extent> {
        self.extents[key].ok_or_else(|| Error::Config(format!("scratch record {key} was never written")))
    }

    /// The plain record under `key` into `out`, which has its length.
    pub fn read_plain(&mut self, key: usize, out: &mut [u8]) -> Result<()> {
        let e = self.extent(key)?;
        if e.stored as usize != out.len() {
            return Err(Error::input(
                &self.path,
                format!(
                    "scratch record {key} holds {} bytes, expected {}",
                    e.stored,
                    out.len()
                ),
            ));
        }
        self.read_plain_at(key, 0, out)
    }

    /// Bytes `at..at + out.len()` of the plain record under `key` into `out`.
    pub fn read_plain_at(&mut self, key: usize, at: usize, out: &mut [u8]) -> Result<()> {
        let e = self.plain_part(key, at, out.len())?;
        self.file
            .seek(SeekFrom::Start(e.offset + at as u64))
            .and_then(|_| self.file.read_exact(out))
            .map_err(|err| Error::io(&self.path, err))
    }

    /// Overwrites bytes `at..at + data.len()` of the plain record under `key`.
    pub fn write_plain_at(&mut self, key: usize, at: usize, data: &[u8]) -> Result<()> {
        let e = self.plain_part(key, at, data.len())?;
        self.file
            .seek(SeekFrom::Start(e.offset + at as u64))
            .and_then(|_| self.file.write_all(data))
            .map_err(|err| Error::io(&self.path, err))?;
        self.written += data.len() as u64;
        Ok(())
    }

    /// The extent of plain record `key`, which holds bytes `at..at + len`.
    fn plain_part(&self, key: usize, at: usize, len: usize) -> Result<Extent> {
        let e = self.extent(key)?;
        if self.compressor.is_some() || at + len > e.stored as usize {
            return Err(Error::input(
                &self.path,
                format!(
                    "scratch record {key} holds {} bytes, not bytes {at}..{} plain",
                    e.stored,
                    at + len
                ),
            ));
        }
        Ok(e)
    }

    /// The record under `key`, decompressed to `len` bytes.
    pub fn get(&mut self, key: usize, len: usize) -> Result<Vec<u8>> {
        let e = self.extent(key)?;
        if self.compressor.is_none() {
            let mut out = vec![0u8; len];
            self.read_plain(key, &mut out)?;
            return Ok(out);
        }
        let mut packed = vec![0u8; e.stored as usize];
        self.file
            .seek(SeekFrom::Start(e.offset))
            .and_then(|_| self.file.read_exact(&mut packed))
            .map_err(|err| Error::io(&self.path, err))?;
        let bytes = super::codec::decompress(&packed, len).map_err(|err| Error::io(&self.path, err))?;
        if bytes.len() != len {
            return Err(Error::input(
                &self.path,
                format!("scratch record {key} holds {} bytes, expected {len}", bytes.len()),
            ));
        }
        Ok(bytes)
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        let _ = std::fs::remove_file(&self.path);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn records_round_trip_and_the_file_goes_with_the_store() {
        let dir = tempfile::tempdir().unwrap();
        let out = dir.path().join("deco.quilt");
        // a scratch file a dead run left is removed (a process id above
        // the kernel's largest), one of a live process kept
        let dead = Scratch::path_for(&out, 4_194_305);
        let live = Scratch::path_for(&out, 1);
        std::fs::write(&dead, b"stale").unwrap();
        std::fs::write(&live, b"busy").unwrap();
        let mut s = Scratch::create_beside(&out, 3).unwrap();
        let a: Vec<u8> = (0..5000u32).map(|i| (i * 7 % 251) as u8).collect();
        let b = vec![9u8; 300];
        s.put(2, &a).unwrap();
        s.put(0, &b).unwrap();
        assert!(s.contains(2) && s.contains(0) && !s.contains(1));
        assert_eq!(s.get(2, a.len()).unwrap(), a);
        assert_eq!(s.get(0, b.len()).unwrap(), b);
        // a rewrite that fits stays in place, a longer one moves
        s.put(0, &vec![1u8; 300]).unwrap();
        assert_eq!(s.get(0, 300).unwrap(), vec![1u8; 300]);
        s.put(0, &a).unwrap();
        assert_eq!(s.get(0, a.len()).unwrap(), a);
        assert_eq!(s.get(2, a.len()).unwrap(), a);
        assert!(s.get(1, 10).is_err());
        assert!(s.get(2, 10).is_err(), "a wrong length is an error");
        if Path::new("/proc/self").exists() {
            assert!(!dead.exists());
        }
        assert!(live.exists());
        let path = Scratch::path_for(&out, std::process::id());
        assert!(path.exists());
        drop(s);
        assert!(!path.exists());
    }
}
