//! Round trips and damage detection of the chunked tile container.

use std::path::Path;

use btfquilt::container::{ArraySpec, Container, ContainerWriter, DType, Element, MemoryBudget, Param};
use btfquilt::Error;
use half::f16;
use proptest::prelude::*;

fn write_one<T: Element>(path: &Path, spec: ArraySpec, values: &[T]) {
    let mut w = ContainerWriter::create(path, "test").unwrap();
    w.set_seed(7);
    w.set_param("answer", Param::Int(42));
    w.add_input("nothing", 0xdead_beef);
    let id = w.add_array(spec).unwrap();
    w.write_array(id, values).unwrap();
    w.finish().unwrap();
}

/// Brute-force copy of a region out of a row-major array.
fn slice_region<T: Copy>(shape: &[u64], data: &[T], origin: &[u64], extent: &[u64]) -> Vec<T> {
    let n: u64 = extent.iter().product();
    let mut out = Vec::with_capacity(n as usize);
    for flat in 0..n {
        let mut rem = flat;
        let mut idx = vec![0u64; shape.len()];
        for d in (0..shape.len()).rev() {
            idx[d] = origin[d] + rem % extent[d];
            rem /= extent[d];
        }
        let off = idx.iter().zip(shape).fold(0u64, |acc, (&i, &s)| acc * s + i);
        out.push(data[off as usize]);
    }
    out
}

fn check_round_trip<T: Element + PartialEq + std::fmt::Debug>(
    shape: Vec<u64>,
    chunk: Vec<u64>,
    values: Vec<T>,
    region: (Vec<u64>, Vec<u64>),
) {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("a.bq");
    let spec = ArraySpec::new("data", T::DTYPE, &shape, &chunk).unwrap();
    write_one(&path, spec.clone(), &values);
    // a tiny cache forces re-decoding
    let c = Container::open(&path, MemoryBudget(4096)).unwrap();
    let m = c.metadata();
    assert_eq!(m.kind, "test");
    assert_eq!(m.seed, Some(7));
    assert_eq!(m.param("answer"), Some(&Param::Int(42)));
    assert_eq!(m.inputs[0].hash, 0xdead_beef);
    let id = c.array("data").unwrap();
    assert_eq!(c.spec(id), &spec);
    let all: Vec<T> = c.read_array(id).unwrap();
    assert_eq!(all, values);
    // every chunk holds exactly its clipped region
    for k in 0..spec.chunk_count() {
        let (o, e) = spec.chunk_region(k);
        let chunk = c.read_chunk::<T>(id, k).unwrap();
        assert_eq!(&chunk[..], &slice_region(&shape, &values, &o, &e)[..]);
    }
    let (o, e) = region;
    let got: Vec<T> = c.read_region(id, &o, &e).unwrap();
    assert_eq!(got, slice_region(&shape, &values, &o, &e));
    c.verify().unwrap();
}

/// Shape, chunk shape and a region inside the shape.
fn layout() -> impl Strategy<Value = (Vec<u64>, Vec<u64>, (Vec<u64>, Vec<u64>))> {
    prop::collection::vec((1u64..12, 1u64..15, 0u64..100, 0u64..100), 1..=4).prop_map(|dims| {
        let shape: Vec<u64> = dims.iter().map(|d| d.0).collect();
        let chunk: Vec<u64> = dims.iter().map(|d| d.1).collect();
        let origin: Vec<u64> = dims.iter().map(|d| d.2 % d.0).collect();
        let extent: Vec<u64> = dims
            .iter()
            .zip(&origin)
            .map(|(d, &o)| 1 + d.3 % (d.0 - o))
            .collect();
        (shape, chunk, (origin, extent))
    })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(48))]

    #[test]
    fn f16_arrays_round_trip((shape, chunk, region) in layout(), seed in any::<u64>()) {
        let n: u64 = shape.iter().product();
        let values: Vec<f16> = (0..n).map(|i| f16::from_bits(((i ^ seed).wrapping_mul(2654435761) >> 7) as u16 & 0x7bff)).collect();
        check_round_trip(shape, chunk, values, region);
    }

    #[test]
    fn f32_arrays_round_trip((shape, chunk, region) in layout(), seed in any::<u32>()) {
        let n: u64 = shape.iter().product();
        let values: Vec<f32> = (0..n).map(|i| ((i as f32) * 0.37 + seed as f32).sin()).collect();
        check_round_trip(shape, chunk, values, region);
    }

    #[test]
    fn u32_arrays_round_trip((shape, chunk, region) in layout(), seed in any::<u32>()) {
        let n: u64 = shape.iter().product();
        let values: Vec<u32> = (0..n as u32).map(|i| i.wrapping_mul(seed | 1)).collect();
        check_round_trip(shape, chunk, values, region);
    }

    #[test]
    fn u8_arrays_round_trip((shape, chunk, region) in layout(), seed in any::<u8>()) {
        let n: u64 = shape.iter().product();
        let values: Vec<u8> = (0..n).map(|i| (i as u8).wrapping_add(seed)).collect();
        check_round_trip(shape, chunk, values, region);
    }
}

/// A valid two-array file for the damage tests; returns its path.
fn sample_file(dir: &Path) -> std::path::PathBuf {
    let path = dir.join("sample.bq");
    let mut w = ContainerWriter::create(&path, "test").unwrap();
    let a = w
        .add_array(ArraySpec::new("smooth", DType::F32, &[64, 64], &[16, 16]).unwrap())
        .unwrap();
    let values: Vec<f32> = (0..64 * 64).map(|i| (i as f32 * 0.01).cos()).collect();
    w.write_array(a, &values).unwrap();
    w.finish().unwrap();
    path
}

#[test]
fn not_a_container_is_named() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("notes.txt");
    std::fs::write(&path, "hello, this is text and not a container").unwrap();
    let err = Container::open(&path, MemoryBudget::default()).err().unwrap();
    assert!(matches!(err, Error::NotContainer { .. }), "{err}");
    assert!(err.to_string().contains("notes.txt"), "{err}");
    let empty = dir.path().join("empty.bq");
    std::fs::write(&empty, b"").unwrap();
    let err = Container::open(&empty, MemoryBudget::default()).err().unwrap();
    assert!(err.to_string().contains("empty.bq"), "{err}");
}

#[test]
fn newer_format_version_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let path = sample_file(dir.path());
    let mut bytes = std::fs::read(&path).unwrap();
    bytes[8..12].copy_from_slice(&99u32.to_le_bytes());
    let sum = xxhash_rust::xxh3::xxh3_64(&bytes[..56]);
    bytes[56..64].copy_from_slice(&sum.to_le_bytes());
    std::fs::write(&path, &bytes).unwrap();
    let err = Container::open(&path, MemoryBudget::default()).err().unwrap();
    assert!(
        matches!(err, Error::UnsupportedVersion { found: 99, .. }),
        "{err}"
    );
    assert!(
        err.to_string().contains("sample.bq") && err.to_string().contains("99"),
        "{err}"
    );
}

#[test]
fn truncated_file_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let path = sample_file(dir.path());
    let len = std::fs::metadata(&path).unwrap().len();
    for cut in [1, len / 2, len - 40] {
        let f = std::fs::OpenOptions::new().write(true).open(&path).unwrap();
        f.set_len(len - cut).unwrap();
        let err = Container::open(&path, MemoryBudget::default()).err().unwrap();
        assert!(matches!(err, Error::Truncated { .. }), "cut {cut}: {err}");
        assert!(err.to_string().contains("sample.bq"), "{err}");
    }
}

#[test]
fn flipped_chunk_byte_names_array_and_chunk() {
    let dir = tempfile::tempdir().unwrap();
    let path = sample_file(dir.path());
    let mut bytes = std::fs::read(&path).unwrap();
    bytes[64 + 5] ^= 0x10; // inside the first chunk
    std::fs::write(&path, &bytes).unwrap();
    let c = Container::open(&path, MemoryBudget::default()).unwrap();
    let id = c.array("smooth").unwrap();
    let err = c.read_chunk::<f32>(id, 0).err().unwrap();
    assert!(matches!(err, Error::Corrupt { .. }), "{err}");
    let msg = err.to_string();
    assert!(
        msg.contains("sample.bq") && msg.contains("'smooth'") && msg.contains("chunk 0"),
        "{msg}"
    );
    // the other chunks are intact, and verify finds the damage
    c.read_chunk::<f32>(id, 1).unwrap();
    assert!(c.verify().is_err());
}

#[test]
fn flipped_metadata_byte_is_detected() {
    let dir = tempfile::tempdir().unwrap();
    let path = sample_file(dir.path());
    let mut bytes = std::fs::read(&path).unwrap();
    let meta_offset = u64::from_le_bytes(bytes[16..24].try_into().unwrap()) as usize;
    bytes[meta_offset + 12] ^= 0x01;
    std::fs::write(&path, &bytes).unwrap();
    let err = Container::open(&path, MemoryBudget::default()).err().unwrap();
    assert!(matches!(err, Error::Corrupt { .. }), "{err}");
    assert!(err.to_string().contains("metadata"), "{err}");
}

#[test]
fn reading_with_the_wrong_type_or_name_is_an_error() {
    let dir = tempfile::tempdir().unwrap();
    let path = sample_file(dir.path());
    let c = Container::open(&path, MemoryBudget::default()).unwrap();
    let err = c.array("nope").err().unwrap();
    assert!(err.to_string().contains("'nope'"));
    let id = c.array("smooth").unwrap();
    let err = c.read_chunk::<u8>(id, 0).err().unwrap();
    assert!(err.to_string().contains("f32"), "{err}");
}

fn dir_is_empty(dir: &Path) -> bool {
    std::fs::read_dir(dir).unwrap().next().is_none()
}

#[test]
fn unfinished_writes_leave_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("out.bq");
    {
        let mut w = ContainerWriter::create(&path, "test").unwrap();
        let a = w
            .add_array(ArraySpec::new("x", DType::U8, &[10], &[4]).unwrap())
            .unwrap();
        w.write_chunk(a, 0, &[1u8, 2, 3, 4]).unwrap();
        // dropped without finish
    }
    assert!(dir_is_empty(dir.path()));
    let mut w = ContainerWriter::create(&path, "test").unwrap();
    let a = w
        .add_array(ArraySpec::new("x", DType::U8, &[10], &[4]).unwrap())
        .unwrap();
    w.write_chunk(a, 0, &[1u8, 2, 3, 4]).unwrap();
    let err = w.finish().err().unwrap();
    assert!(err.to_string().contains("chunk 1 was never written"), "{err}");
    assert!(dir_is_empty(dir.path()));
}

#[test]
fn writer_rejects_wrong_chunks() {
    let dir = tempfile::tempdir().unwrap();
    let mut w = ContainerWriter::create(&dir.path().join("o.bq"), "test").unwrap();
    let a = w
        .add_array(ArraySpec::new("x", DType::U8, &[10], &[4]).unwrap())
        .unwrap();
    assert!(
        w.write_chunk(a, 2, &[1u8, 2, 3, 4]).is_err(),
        "edge chunk holds 2 elements"
    );
    assert!(w.write_chunk(a, 3, &[1u8]).is_err(), "out of range");
    assert!(w.write_chunk(a, 0, &[1.0f32; 4]).is_err(), "wrong dtype");
    w.write_chunk(a, 0, &[1u8; 4]).unwrap();
    assert!(w.write_chunk(a, 0, &[1u8; 4]).is_err(), "twice");
    assert!(ArraySpec::new("y", DType::U8, &[10, 2], &[4]).is_err());
    assert!(ArraySpec::new("y", DType::U8, &[10], &[0]).is_err());
}

#[test]
fn plain_reads_match_mapped_reads() {
    let dir = tempfile::tempdir().unwrap();
    let path = sample_file(dir.path());
    let mapped = Container::open(&path, MemoryBudget::default()).unwrap();
    let id = mapped.array("smooth").unwrap();
    let a: Vec<f32> = mapped.read_array(id).unwrap();
    // The environment is process-wide and the tests run as threads of one
    // process, so the plain read happens in a child process of this test
    // binary with BTFQUILT_NO_MMAP=1 (`plain_read_child`), which writes
    // whether it mapped the file and the values it read.
    let report = dir.path().join("plain.report");
    let child = std::process::Command::new(std::env::current_exe().unwrap())
        .args([
            "container::plain_read_child",
            "--exact",
            "--ignored",
            "--test-threads=1",
        ])
        .env("BTFQUILT_NO_MMAP", "1")
        .env(PLAIN_READ_FILE, &path)
        .env(PLAIN_READ_REPORT, &report)
        .output()
        .unwrap();
    assert!(
        child.status.success(),
        "child test failed: {}{}",
        String::from_utf8_lossy(&child.stdout),
        String::from_utf8_lossy(&child.stderr)
    );
    let bytes = std::fs::read(&report).unwrap();
    let plain_is_mapped = bytes[0] != 0;
    assert!(mapped.is_mapped() && !plain_is_mapped);
    let b: Vec<f32> = bytes[1..]
        .chunks_exact(4)
        .map(|q| f32::from_le_bytes(q.try_into().unwrap()))
        .collect();
    assert_eq!(a, b);
}

/// The container `plain_read_child` opens, and where it writes its report.
const PLAIN_READ_FILE: &str = "BTFQUILT_TEST_PLAIN_READ_FILE";
const PLAIN_READ_REPORT: &str = "BTFQUILT_TEST_PLAIN_READ_REPORT";

/// The plain-read half of `plain_reads_match_mapped_reads`, run by it in a
/// child process: opens the container named by `PLAIN_READ_FILE` and writes
/// to `PLAIN_READ_REPORT` one byte (1 if it was mapped) and the values of
/// its "smooth" array (f32, little-endian). Without those variables (a plain
/// `cargo test -- --ignored`) it does nothing.
#[test]
#[ignore = "a child process of plain_reads_match_mapped_reads"]
fn plain_read_child() {
    let (Some(path), Some(report)) = (
        std::env::var_os(PLAIN_READ_FILE),
        std::env::var_os(PLAIN_READ_REPORT),
    ) else {
        return;
    };
    let plain = Container::open(Path::new(&path), MemoryBudget::default()).unwrap();
    let b: Vec<f32> = plain.read_array(plain.array("smooth").unwrap()).unwrap();
    let mut bytes = vec![u8::from(plain.is_mapped())];
    for v in b {
        bytes.extend_from_slice(&v.to_le_bytes());
    }
    std::fs::write(report, bytes).unwrap();
}
