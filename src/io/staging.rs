//! Staged outputs: every file or folder a command writes is built under a
//! hidden name beside its destination and renamed into place only when it is
//! complete, so a failed or killed run never leaves a file that looks
//! finished and never replaces a good one with half of a new one.
//!
//! A staged file is named `.NAME.WRITER.RANDOM.partial` (a folder
//! `.NAME.WRITER.RANDOM.partial.d`), where WRITER is `PID-HOST-BOOT`: the
//! writing process and hashes of its machine's host name and boot id
//! (`Writer`; HOST also covers the process-id namespace, so containers
//! sharing a host name differ). Before a new output is staged, partial files
//! of the same destination left by a process of this machine that no longer
//! runs (a killed run) are removed; what was removed is kept for the caller
//! to report ([`take_removed_partials`]). Liveness is read from `/proc`:
//! where it is absent, nothing is removed. A partial written on another
//! machine (a filesystem several share), or before a reboot, is never
//! removed: its process cannot be seen from here.
//!
//! [`check_output`] refuses an output that is one of the command's inputs (or
//! a file an input depends on), after resolving links: writing it would
//! destroy the input.

use std::path::{Path, PathBuf};
use std::sync::Mutex;

use crate::{Error, Result};

const SUFFIX: &str = ".partial";
const DIR_SUFFIX: &str = ".partial.d";

/// A partial output left by a process that no longer runs, and removed.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct RemovedPartial {
    /// The partial file or folder that was removed.
    pub path: PathBuf,
    /// The process that had written it.
    pub pid: u32,
    /// Its size in bytes (files only; 0 for a folder).
    pub bytes: u64,
}

static REMOVED: Mutex<Vec<RemovedPartial>> = Mutex::new(Vec::new());

/// The stale partial outputs removed so far by this process (and forgets
/// them), for the command line to say what it cleaned up.
pub fn take_removed_partials() -> Vec<RemovedPartial> {
    std::mem::take(&mut *crate::lock(&REMOVED))
}

/// The folder a destination lives in (`.` for a bare file name).
pub fn parent_dir(dest: &Path) -> &Path {
    match dest.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    }
}

fn file_name(dest: &Path) -> Result<String> {
    dest.file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .ok_or_else(|| Error::input(dest, "not a file path"))
}

/// Whether process `pid` is running, if this system can tell.
pub(crate) fn process_alive(pid: u32) -> Option<bool> {
    let proc = Path::new("/proc");
    if !proc.join("self").exists() {
        return None;
    }
    Some(proc.join(pid.to_string()).exists())
}

/// The writer of a partial file: a process on a machine.
///
/// Partial names carry `PID-HOST-BOOT`: HOST and BOOT are 8 hexadecimal
/// digits hashing this machine's host name and its kernel's boot id, so on
/// a filesystem several machines share, a process judges only its own
/// machine's partials by process id, and never removes one that a process
/// elsewhere may still be writing.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Writer {
    pub(crate) pid: u32,
    /// `None` in names without a machine (taken as this machine's).
    pub(crate) machine: Option<Machine>,
}

/// A machine's identity in partial names.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Machine {
    host: u32,
    boot: u32,
}

/// This machine's host name, where the system tells it.
pub(crate) fn host_name() -> Option<String> {
    static NAME: std::sync::OnceLock<Option<String>> = std::sync::OnceLock::new();
    NAME.get_or_init(|| {
        std::fs::read_to_string("/proc/sys/kernel/hostname")
            .or_else(|_| std::fs::read_to_string("/etc/hostname"))
            .ok()
            .map(|s| s.trim().to_string())
    })
    .clone()
}

/// This machine: hashes of its host name with its process-id namespace, and
/// of its boot id; 0 where they cannot be read (then nothing of it is ever
/// judged gone).
pub(crate) fn this_machine() -> Machine {
    static MACHINE: std::sync::OnceLock<Machine> = std::sync::OnceLock::new();
    *MACHINE.get_or_init(|| {
        let hash = |text: Option<String>| {
            text.map(|s| (xxhash_rust::xxh3::xxh3_64(s.trim().as_bytes()) as u32).max(1))
                .unwrap_or(0)
        };
        // containers sharing a host name but not their process ids differ
        let pid_ns = std::fs::read_link("/proc/self/ns/pid").ok();
        let host = match (host_name(), pid_ns) {
            (Some(h), Some(ns)) => Some(format!("{h}\n{}", ns.display())),
            _ => None,
        };
        Machine {
            host: hash(host),
            boot: hash(std::fs::read_to_string("/proc/sys/kernel/random/boot_id").ok()),
        }
    })
}

impl Writer {
    /// This process on this machine.
    pub(crate) fn me() -> Writer {
        Writer {
            pid: std::process::id(),
            machine: Some(this_machine()),
        }
    }

    /// Parses `PID` or `PID-HOST-BOOT`.
    pub(crate) fn parse(s: &str) -> Option<Writer> {
        let mut parts = s.split('-');
        let pid = parts.next()?.parse().ok()?;
        let machine = match (parts.next(), parts.next(), parts.next()) {
            (None, ..) => None,
            (Some(h), Some(b), None) if h.len() == 8 && b.len() == 8 => Some(Machine {
                host: u32::from_str_radix(h, 16).ok()?,
                boot: u32::from_str_radix(b, 16).ok()?,
            }),
            _ => return None,
        };
        Some(Writer { pid, machine })
    }

    /// Whether the writer is known to be gone: a process of this machine
    /// (same host name, process-id namespace and boot) that no longer runs,
    /// as `/proc` tells. A writer elsewhere, or on a machine that cannot
    /// name itself, is never known to be gone.
    pub(crate) fn is_gone(&self) -> bool {
        let here = this_machine();
        let same_machine = match self.machine {
            None => true,
            Some(m) => m == here && m.host != 0 && m.boot != 0,
        };
        same_machine && self.pid != std::process::id() && process_alive(self.pid) == Some(false)
    }
}

impl std::fmt::Display for Writer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}", self.pid)?;
        if let Some(m) = self.machine {
            write!(f, "-{:08x}-{:08x}", m.host, m.boot)?;
        }
        Ok(())
    }
}

/// The writer of a partial name `.NAME.WRITER.RANDOM<suffix>` for
/// destination `NAME`, if the name is one.
fn partial_writer(entry: &str, name: &str, suffix: &str) -> Option<Writer> {
    let rest = entry.strip_prefix('.')?.strip_prefix(name)?.strip_prefix('.')?;
    let rest = rest.strip_suffix(suffix)?;
    let (writer, random) = rest.split_once('.')?;
    if random.is_empty() || random.contains('.') {
        return None;
    }
    Writer::parse(writer)
}

/// Removes partial outputs of `dest` whose writing process is gone.
fn remove_stale(dest: &Path) {
    let Ok(name) = file_name(dest) else { return };
    let dir = parent_dir(dest);
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for entry in entries.flatten() {
        let entry_name = entry.file_name().to_string_lossy().into_owned();
        let (writer, is_dir) = match (
            partial_writer(&entry_name, &name, SUFFIX),
            partial_writer(&entry_name, &name, DIR_SUFFIX),
        ) {
            (Some(w), _) => (w, false),
            (None, Some(w)) => (w, true),
            (None, None) => continue,
        };
        if !writer.is_gone() {
            continue;
        }
        let pid = writer.pid;
        let path = entry.path();
        let bytes = if is_dir {
            0
        } else {
            entry.metadata().map(|m| m.len()).unwrap_or(0)
        };
        let removed = if is_dir {
            std::fs::remove_dir_all(&path)
        } else {
            std::fs::remove_file(&path)
        };
        if removed.is_ok() {
            crate::lock(&REMOVED).push(RemovedPartial { path, pid, bytes });
        }
    }
}

/// A new staged file for `dest`: a temporary file beside it, deleted when
/// dropped, to be renamed onto `dest` with `persist` once complete. Stale
/// partial files of the same destination are removed first.
pub fn staged_file(dest: &Path) -> Result<tempfile::NamedTempFile> {
    let name = file_name(dest)?;
    remove_stale(dest);
    let prefix = format!(".{name}.{}.", Writer::me());
    let mut b = tempfile::Builder::new();
    b.prefix(&prefix).suffix(SUFFIX).rand_bytes(8);
    #[cfg(unix)]
    {
        // the usual mode for new files (the umask applies), not tempfile's 0600
        use std::os::unix::fs::PermissionsExt;
        b.permissions(std::fs::Permissions::from_mode(0o666));
    }
    b.tempfile_in(parent_dir(dest)).map_err(|e| Error::io(dest, e))
}

/// A folder output built whole under a hidden name beside its destination
/// and renamed into place by [`StagedDir::commit`]; dropped uncommitted, it is
/// removed.
pub struct StagedDir {
    dest: PathBuf,
    tmp: Option<tempfile::TempDir>,
}

impl StagedDir {
    /// Stages the folder `dest`. It may not exist yet, be empty, or hold a
    /// previous output of the same kind (`marker`, e.g. its `manifest.csv`),
    /// which the commit replaces whole; a folder holding anything else is
    /// refused, so no user file is ever removed.
    pub fn new(dest: &Path, marker: Option<&str>) -> Result<StagedDir> {
        let name = file_name(dest)?;
        if dest.exists() {
            if !dest.is_dir() {
                return Err(Error::input(dest, "exists and is not a folder"));
            }
            let empty = std::fs::read_dir(dest)
                .map_err(|e| Error::io(dest, e))?
                .next()
                .is_none();
            let ours = marker.is_some_and(|m| dest.join(m).is_file());
            if !empty && !ours {
                return Err(Error::input(
                    dest,
                    "is a folder that holds other files: give a new or empty folder",
                ));
            }
        }
        let dir = parent_dir(dest);
        std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
        remove_stale(dest);
        let prefix = format!(".{name}.{}.", Writer::me());
        let tmp = tempfile::Builder::new()
            .prefix(&prefix)
            .suffix(DIR_SUFFIX)
            .rand_bytes(8)
            .tempdir_in(dir)
            .map_err(|e| Error::io(dest, e))?;
        Ok(StagedDir {
            dest: dest.to_path_buf(),
            tmp: Some(tmp),
        })
    }

    /// The staging folder: write the output's files here.
    pub fn path(&self) -> &Path {
        self.tmp.as_ref().expect("an uncommitted stage").path()
    }

    /// The destination folder.
    pub fn dest(&self) -> &Path {
        &self.dest
    }

    /// Renames the staged folder onto the destination unless a folder with
    /// content is there already (another writer's): then the staged folder
    /// is removed and `false` returned. An empty folder there is replaced.
    pub fn commit_unless_present(mut self) -> Result<bool> {
        let tmp = self.tmp.take().expect("commit runs once");
        let staged = tmp.keep();
        let dest = self.dest.clone();
        match std::fs::rename(&staged, &dest) {
            Ok(()) => Ok(true),
            Err(e) => {
                let _ = std::fs::remove_dir_all(&staged);
                let occupied = std::fs::read_dir(&dest).is_ok_and(|mut d| d.next().is_some());
                if occupied {
                    Ok(false)
                } else {
                    Err(Error::io(&dest, e))
                }
            }
        }
    }

    /// Renames the staged folder onto the destination, replacing a previous
    /// output there whole (moved aside first, removed after).
    pub fn commit(mut self) -> Result<PathBuf> {
        let tmp = self.tmp.take().expect("commit runs once");
        let staged = tmp.keep();
        let dest = self.dest.clone();
        let fail = |e: std::io::Error| {
            let _ = std::fs::remove_dir_all(&staged);
            Error::io(&dest, e)
        };
        if dest.exists() {
            let name = file_name(&dest)?;
            let aside = parent_dir(&dest).join(format!(".{name}.{}.old{DIR_SUFFIX}", Writer::me()));
            std::fs::rename(&dest, &aside).map_err(fail)?;
            if let Err(e) = std::fs::rename(&staged, &dest) {
                let _ = std::fs::rename(&aside, &dest);
                return Err(fail(e));
            }
            let _ = std::fs::remove_dir_all(&aside);
        } else {
            std::fs::rename(&staged, &dest).map_err(fail)?;
        }
        Ok(dest)
    }
}

/// The identity of an existing file after resolving links (device and inode
/// on Unix, the canonical path elsewhere).
fn identity(path: &Path) -> Option<(u64, u64, PathBuf)> {
    let canonical = std::fs::canonicalize(path).ok()?;
    #[cfg(unix)]
    {
        use std::os::unix::fs::MetadataExt;
        let m = std::fs::metadata(&canonical).ok()?;
        Some((m.dev(), m.ino(), PathBuf::new()))
    }
    #[cfg(not(unix))]
    {
        Some((0, 0, canonical))
    }
}

/// `path` relative to the folder of `artifact` (both resolved), or `path`
/// made absolute when no relative form exists.
pub fn relative_to_folder_of(artifact: &Path, path: &Path) -> String {
    let folder = parent_dir(artifact);
    let (Ok(from), Ok(to)) = (std::fs::canonicalize(folder), std::fs::canonicalize(path)) else {
        return std::path::absolute(path)
            .unwrap_or_else(|_| path.to_path_buf())
            .display()
            .to_string();
    };
    let (a, b): (Vec<_>, Vec<_>) = (from.components().collect(), to.components().collect());
    let common = a.iter().zip(&b).take_while(|(x, y)| x == y).count();
    if common == 0 {
        return to.display().to_string();
    }
    let mut rel = PathBuf::new();
    for _ in common..a.len() {
        rel.push("..");
    }
    for c in &b[common..] {
        rel.push(c);
    }
    rel.display().to_string()
}

/// A path recorded in `artifact`, resolved against the artifact's folder
/// (absolute paths stay as they are).
pub fn resolve_in_folder_of(artifact: &Path, recorded: &Path) -> PathBuf {
    if recorded.is_absolute() {
        recorded.to_path_buf()
    } else {
        parent_dir(artifact).join(recorded)
    }
}

/// Whether `a` and `b` name the same existing file (links resolved).
pub fn same_file(a: &Path, b: &Path) -> bool {
    match (identity(a), identity(b)) {
        (Some(x), Some(y)) => x == y,
        _ => false,
    }
}

/// Refuses to write `output` when it is (the same file as) one of `inputs`:
/// the command's own inputs and the files they depend on. `role` names what
/// the input is, for the message.
pub fn check_output(output: &Path, inputs: &[(&str, &Path)]) -> Result<()> {
    for (role, input) in inputs {
        if same_file(output, input) {
            let named = if output == *input {
                String::new()
            } else {
                format!(" {}", input.display())
            };
            return Err(Error::input(
                output,
                format!("is {role}{named}: writing it would destroy it; choose another output"),
            ));
        }
    }
    Ok(())
}

/// Refuses to write into the folder `dir` when one of `inputs` lies inside
/// it under one of `names` (the files the folder output will hold).
pub fn check_output_dir(dir: &Path, names: &[&str], inputs: &[(&str, &Path)]) -> Result<()> {
    for name in names {
        check_output(&dir.join(name), inputs)?;
    }
    for (role, input) in inputs {
        if same_file(dir, input) {
            return Err(Error::input(
                dir,
                format!("is {role} {}; choose another output folder", input.display()),
            ));
        }
    }
    Ok(())
}

/// A hidden staging folder inside `dir` for an output made of several files
/// that are renamed into `dir` one by one (`name` tells outputs apart);
/// removed when dropped. Stale ones of dead writers are removed first.
pub fn staging_dir_in(dir: &Path, name: &str) -> Result<tempfile::TempDir> {
    remove_stale(&dir.join(name));
    tempfile::Builder::new()
        .prefix(&format!(".{name}.{}.", Writer::me()))
        .suffix(DIR_SUFFIX)
        .rand_bytes(8)
        .tempdir_in(dir)
        .map_err(|e| Error::io(dir, e))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pid(pid: u32) -> Option<Writer> {
        Some(Writer { pid, machine: None })
    }

    #[test]
    fn partial_names_parse_only_for_their_destination() {
        assert_eq!(
            partial_writer(".a.gim.123.Xy7Qz0aB.partial", "a.gim", SUFFIX),
            pid(123)
        );
        let me = Writer::me();
        let name = format!(".a.gim.{me}.Xy7Qz0aB.partial");
        assert_eq!(partial_writer(&name, "a.gim", SUFFIX), Some(me));
        assert_eq!(Writer::parse(&me.to_string()), Some(me));
        for bad in [
            "12-abc-def",
            "12-0000000g-00000000",
            "12-00000000",
            "12-00000000-00000000-0",
            "-1",
        ] {
            assert_eq!(Writer::parse(bad), None, "{bad}");
        }
        assert_eq!(
            partial_writer(".a.gim.123.Xy7Qz0aB.partial", "b.gim", SUFFIX),
            None
        );
        assert_eq!(partial_writer(".a.gim.x.Xy7Qz0aB.partial", "a.gim", SUFFIX), None);
        assert_eq!(partial_writer("a.gim.123.Xy.partial", "a.gim", SUFFIX), None);
        assert_eq!(partial_writer(".d.7.abc.partial.d", "d", DIR_SUFFIX), pid(7));
    }

    #[test]
    fn stale_partials_of_dead_writers_are_removed_live_ones_kept() {
        if process_alive(std::process::id()) != Some(true) {
            eprintln!("no /proc: liveness unknown, nothing is removed; skipped");
            return;
        }
        let dir = tempfile::tempdir().unwrap();
        let dest = dir.path().join("x.quilt");
        // a pid that cannot be running: above the kernel's pid_max (2^22)
        let dead = dir.path().join(".x.quilt.4294967.abcdefgh.partial");
        let live = dir
            .path()
            .join(format!(".x.quilt.{}.abcdefgh.partial", std::process::id()));
        let other = dir.path().join(".y.quilt.4294967.abcdefgh.partial");
        // the same with this machine named: removed; with another host
        // (a shared filesystem) or another boot of this one: kept whatever
        // its pid, since no process there can be seen from here
        let here = this_machine();
        let named = |pid: u32, m: Machine| {
            let w = Writer {
                pid,
                machine: Some(m),
            };
            dir.path().join(format!(".x.quilt.{w}.abcdefgh.partial"))
        };
        let dead_here = named(4294967, here);
        let elsewhere = named(
            4294967,
            Machine {
                host: here.host ^ 1,
                ..here
            },
        );
        let rebooted = named(
            4294967,
            Machine {
                boot: here.boot ^ 1,
                ..here
            },
        );
        for p in [&dead, &live, &other, &dead_here, &elsewhere, &rebooted] {
            std::fs::write(p, b"partial").unwrap();
        }
        let tmp = staged_file(&dest).unwrap();
        assert!(!dead.exists(), "the dead writer's partial stays");
        assert!(!dead_here.exists());
        assert!(live.exists() && other.exists() && elsewhere.exists() && rebooted.exists());
        assert!(tmp.path().to_string_lossy().contains(&Writer::me().to_string()));
        let removed = take_removed_partials();
        assert!(removed
            .iter()
            .any(|r| r.path == dead && r.pid == 4294967 && r.bytes == 7));
        drop(tmp);
    }

    #[test]
    fn output_equal_to_an_input_is_refused_through_links() {
        let dir = tempfile::tempdir().unwrap();
        let input = dir.path().join("m.obj");
        std::fs::write(&input, b"v 0 0 0\n").unwrap();
        let e = check_output(&input, &[("the input mesh", &input)]).unwrap_err();
        assert!(e.to_string().contains("m.obj") && e.to_string().contains("would destroy"));
        #[cfg(unix)]
        {
            let link = dir.path().join("link.obj");
            std::os::unix::fs::symlink(&input, &link).unwrap();
            assert!(check_output(&link, &[("the input mesh", &input)]).is_err());
        }
        let other = dir.path().join("out.gim");
        assert!(check_output(&other, &[("the input mesh", &input)]).is_ok());
    }

    #[test]
    fn staged_dir_replaces_its_own_output_and_refuses_foreign_folders() {
        let dir = tempfile::tempdir().unwrap();
        let dest = dir.path().join("out");
        let s = StagedDir::new(&dest, Some("manifest.csv")).unwrap();
        std::fs::write(s.path().join("manifest.csv"), b"one").unwrap();
        std::fs::write(s.path().join("a.png"), b"a").unwrap();
        s.commit().unwrap();
        let s = StagedDir::new(&dest, Some("manifest.csv")).unwrap();
        std::fs::write(s.path().join("manifest.csv"), b"two").unwrap();
        s.commit().unwrap();
        assert_eq!(std::fs::read(dest.join("manifest.csv")).unwrap(), b"two");
        assert!(!dest.join("a.png").exists(), "the old output is replaced whole");
        let foreign = dir.path().join("mine");
        std::fs::create_dir(&foreign).unwrap();
        std::fs::write(foreign.join("notes.txt"), b"keep").unwrap();
        assert!(StagedDir::new(&foreign, Some("manifest.csv")).is_err());
        assert_eq!(std::fs::read(foreign.join("notes.txt")).unwrap(), b"keep");
        // dropped uncommitted: nothing is left
        let s = StagedDir::new(&dir.path().join("never"), None).unwrap();
        drop(s);
        let left: Vec<_> = std::fs::read_dir(dir.path())
            .unwrap()
            .flatten()
            .map(|e| e.file_name())
            .collect();
        assert_eq!(left.len(), 2, "{left:?}");
    }
}
