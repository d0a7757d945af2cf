//! Image bombs and broken images: a header declaring 2³⁰×2³⁰ pixels, a
//! 30000² all-zero PNG that compresses to a few megabytes, an OpenEXR header
//! declaring a huge layer, a truncated PNG and a text file named `.png`, each
//! through every command that reads an image (`factorize`, `tile --sample`,
//! `tile --sample-mask`, `paint --region`): refused before decoding, the
//! file named, nothing at `-o`. Plus a seeded mutation loop over a small
//! valid PNG through `factorize`.

use std::path::{Path, PathBuf};

use crate::common;
use crate::robustness::{fuzz_cases, mutate, refuses, Rng};

/// CRC-32 (IEEE, reflected) as PNG chunks use it.
fn crc32(bytes: &[u8]) -> u32 {
    let mut c = !0u32;
    for &b in bytes {
        c ^= b as u32;
        for _ in 0..8 {
            c = if c & 1 != 0 {
                0xEDB8_8320 ^ (c >> 1)
            } else {
                c >> 1
            };
        }
    }
    !c
}

/// One PNG chunk: length, type, data, CRC over type and data.
fn chunk(kind: &[u8; 4], data: &[u8]) -> Vec<u8> {
    let mut out = (data.len() as u32).to_be_bytes().to_vec();
    let mut body = kind.to_vec();
    body.extend_from_slice(data);
    out.extend_from_slice(&body);
    out.extend_from_slice(&crc32(&body).to_be_bytes());
    out
}

/// A PNG of 8-bit grey `width`×`height` whose IDAT holds `zlib`.
fn grey_png(width: u32, height: u32, zlib: &[u8]) -> Vec<u8> {
    let mut ihdr = width.to_be_bytes().to_vec();
    ihdr.extend_from_slice(&height.to_be_bytes());
    ihdr.extend_from_slice(&[8, 0, 0, 0, 0]); // depth 8, grey, deflate, filter 0, no interlace
    let mut png = b"\x89PNG\r\n\x1a\n".to_vec();
    png.extend(chunk(b"IHDR", &ihdr));
    png.extend(chunk(b"IDAT", zlib));
    png.extend(chunk(b"IEND", &[]));
    png
}

/// Deflate bits, least significant first.
struct Bits {
    out: Vec<u8>,
    acc: u64,
    n: u32,
}

impl Bits {
    fn put(&mut self, value: u64, count: u32) {
        self.acc |= value << self.n;
        self.n += count;
        while self.n >= 8 {
            self.out.push(self.acc as u8);
            self.acc >>= 8;
            self.n -= 8;
        }
    }
    /// A Huffman code, most significant bit first.
    fn code(&mut self, code: u32, len: u32) {
        let rev = (0..len).fold(0u64, |r, i| r | (((code >> i) & 1) as u64) << (len - 1 - i));
        self.put(rev, len);
    }
}

/// A zlib stream of `n` zero bytes: one fixed-Huffman block of a literal 0
/// and then length-258 matches at distance 1 (13 bits per 258 bytes).
fn zlib_zeros(n: u64) -> Vec<u8> {
    let mut b = Bits {
        out: vec![0x78, 0x01],
        acc: 0,
        n: 0,
    };
    b.put(1, 1); // final block
    b.put(1, 2); // fixed Huffman
    let literal0 = |b: &mut Bits| b.code(0x30, 8);
    literal0(&mut b);
    let rest = n - 1;
    for _ in 0..rest / 258 {
        b.code(0b1100_0101, 8); // length symbol 285: 258
        b.code(0, 5); // distance symbol 0: 1
    }
    for _ in 0..rest % 258 {
        literal0(&mut b);
    }
    b.code(0, 7); // end of block
    b.put(0, 7); // flush to a byte
    let adler = ((n % 65521) << 16 | 1) as u32; // a stays 1, b sums it n times
    b.out.extend_from_slice(&adler.to_be_bytes());
    b.out
}

/// An all-zero 8-bit grey PNG of `w`×`h`, small however large it is.
fn zero_png(w: u32, h: u32) -> Vec<u8> {
    grey_png(w, h, &zlib_zeros(h as u64 * (w as u64 + 1)))
}

/// A small valid EXR, then its dataWindow patched to declare
/// `side`×`side` pixels.
fn huge_exr(dir: &Path, side: i32) -> PathBuf {
    let p = dir.join("huge.exr");
    let img = btfquilt::io::imageio::RgbImage {
        width: 4,
        height: 4,
        data: vec![0.5; 48],
    };
    btfquilt::io::imageio::write_exr(&p, &img, true).unwrap();
    let mut bytes = std::fs::read(&p).unwrap();
    let key = b"dataWindow\0box2i\0";
    let at = bytes
        .windows(key.len())
        .position(|w| w == key)
        .expect("dataWindow attribute")
        + key.len()
        + 4;
    bytes[at + 8..at + 12].copy_from_slice(&(side - 1).to_le_bytes());
    bytes[at + 12..at + 16].copy_from_slice(&(side - 1).to_le_bytes());
    std::fs::write(&p, bytes).unwrap();
    p
}

/// The small fixtures the image-reading commands need: the square's atlas
/// (64²) and a tiling of it with a 32² brick crop.
struct Fixture {
    dir: tempfile::TempDir,
    gim: PathBuf,
    quilt: PathBuf,
}

fn fixture() -> Fixture {
    let dir = tempfile::tempdir().unwrap();
    let obj = common::square_obj(dir.path());
    let brick = common::brick_crop(dir.path(), 32, None);
    let gim = dir.path().join("sq.gim");
    let quilt = dir.path().join("q.quilt");
    common::ok(&[
        "atlas",
        &common::s(&obj),
        "--resolution",
        "64",
        "-o",
        &common::s(&gim),
    ]);
    common::ok(&[
        "tile",
        "--gim",
        &common::s(&gim),
        "--sample",
        &common::s(&brick),
        "-o",
        &common::s(&quilt),
    ]);
    Fixture { dir, gim, quilt }
}

/// Runs `img` through every command that reads an image, asserting each
/// refuses naming the file (and `needles`), with nothing at `-o`. A mask
/// must have a given size, so a bomb there is refused for its declared size
/// (from the header) not matching.
fn refused_everywhere(f: &Fixture, img: &Path, needles: &[&str]) {
    let name = img.file_name().unwrap().to_string_lossy().into_owned();
    let mut want = vec![name.as_str()];
    want.extend_from_slice(needles);
    let out = f.dir.path().join("out.any");
    let (gim, quilt, img_s, out_s) = (
        common::s(&f.gim),
        common::s(&f.quilt),
        common::s(img),
        common::s(&out),
    );
    let brick_path = f.dir.path().join("brick32.png");
    let brick = common::s(&brick_path);
    refuses(&["factorize", &img_s, "-o", &out_s], &want, Some(&out));
    refuses(
        &["tile", "--gim", &gim, "--sample", &img_s, "-o", &out_s],
        &want,
        Some(&out),
    );
    // a mask of the wrong size is refused for that already; the size check
    // must come from the header, before decoding
    refuses(
        &[
            "tile",
            "--gim",
            &gim,
            "--sample",
            &brick,
            "--sample-mask",
            &img_s,
            "-o",
            &out_s,
        ],
        &want,
        Some(&out),
    );
    let all_path = f.dir.path().join("all32.png");
    common::write_mask_png(&all_path, 32, 32, |_, _| true);
    let all = common::s(&all_path);
    refuses(
        &[
            "paint",
            &quilt,
            "--sample-mask",
            all,
            "--region",
            &img_s,
            "-o",
            &out_s,
        ],
        &want,
        Some(&out),
    );
    let region_path = f.dir.path().join("all64.png");
    common::write_mask_png(&region_path, 64, 64, |_, _| true);
    let region = common::s(&region_path);
    refuses(
        &[
            "paint",
            &quilt,
            "--sample-mask",
            &img_s,
            "--region",
            region,
            "-o",
            &out_s,
        ],
        &want,
        Some(&out),
    );
}

#[test]
fn zero_png_generator_is_a_valid_png() {
    // the bomb generator's output decodes (at a small size) to zeros, so the
    // large one is a real image, not just a broken file
    let png = zero_png(300, 200);
    let img = image::load_from_memory_with_format(&png, image::ImageFormat::Png).unwrap();
    assert_eq!((img.width(), img.height()), (300, 200));
    assert!(img.to_luma8().into_raw().iter().all(|&v| v == 0));
    let huge = zero_png(30000, 30000);
    assert!(huge.len() < 8 << 20, "{} bytes", huge.len());
}

#[test]
fn decoder_limits_catch_the_zero_png_bomb() {
    // the `image` decoder with a byte limit refuses the 30000² bomb (900 MB
    // of grey) without decoding it, the second line of defence behind
    // btfquilt's own header check
    let png = zero_png(30000, 30000);
    let mut reader = image::ImageReader::with_format(std::io::Cursor::new(png), image::ImageFormat::Png);
    let mut limits = image::Limits::default();
    limits.max_alloc = Some(256 << 20);
    reader.limits(limits);
    match reader.decode() {
        Err(image::ImageError::Limits(_)) => {}
        Err(e) => panic!("expected a limits error, got {e}"),
        Ok(i) => panic!("decoded a {}×{} image past the limit", i.width(), i.height()),
    }
}

#[test]
fn image_bombs_and_broken_images_are_refused_by_every_reader() {
    let f = fixture();
    let d = f.dir.path();
    // 2³⁰ × 2³⁰ in a 69-byte file
    let bomb = d.join("bomb.png");
    std::fs::write(&bomb, grey_png(1 << 30, 1 << 30, &zlib_zeros(16))).unwrap();
    assert!(std::fs::metadata(&bomb).unwrap().len() < 100);
    refused_everywhere(&f, &bomb, &["1073741824×1073741824"]);
    let svd = d.join("b.svd");
    refuses(
        &["factorize", &common::s(&bomb), "-o", &common::s(&svd)],
        &[
            "bomb.png",
            "declares 1073741824×1073741824 pixels",
            "32768 px a side",
        ],
        Some(&svd),
    );
    // 30000² zeros: under the side limit, over any memory budget
    let zeros = d.join("zeros.png");
    std::fs::write(&zeros, zero_png(30000, 30000)).unwrap();
    refused_everywhere(&f, &zeros, &["30000×30000"]);
    let e = refuses(
        &[
            "factorize",
            &common::s(&zeros),
            "-o",
            &common::s(&d.join("z.svd")),
        ],
        &["zeros.png", "memory budget"],
        Some(&d.join("z.svd")),
    );
    assert!(e.contains("GiB"), "{e}");
    // an OpenEXR header declaring a 2²⁹-sided layer (about the largest the
    // format allows)
    let exr = huge_exr(d, 1 << 29);
    refused_everywhere(&f, &exr, &["536870912×536870912"]);
    // a truncated PNG (a valid crop cut in half) and a text file named .png
    let good = std::fs::read(d.join("brick32.png")).unwrap();
    let cut = d.join("cut.png");
    std::fs::write(&cut, &good[..good.len() / 2]).unwrap();
    refused_everywhere(&f, &cut, &[]);
    let text = d.join("text.png");
    std::fs::write(&text, "this is not a picture\n").unwrap();
    refused_everywhere(&f, &text, &[]);
}

/// Rewrites the CRC of every whole chunk of a (damaged) PNG.
fn fix_crcs(png: &mut [u8]) {
    let mut at = 8;
    while at + 12 <= png.len() {
        let len = u32::from_be_bytes(png[at..at + 4].try_into().unwrap()) as usize;
        let Some(end) = (at + 8).checked_add(len).filter(|e| e + 4 <= png.len()) else {
            return;
        };
        let crc = crc32(&png[at + 4..end]);
        png[end..end + 4].copy_from_slice(&crc.to_be_bytes());
        at = end + 4;
    }
}

#[test]
fn mutated_pngs_are_read_or_refused_cleanly() {
    let dir = tempfile::tempdir().unwrap();
    let good = std::fs::read(common::brick_crop(dir.path(), 16, None)).unwrap();
    let img = dir.path().join("m.png");
    let out = dir.path().join("m.svd");
    let mut rng = Rng(0x1a2b_3c4d);
    let cases = fuzz_cases(40);
    let (mut read, mut refused) = (0, 0);
    for case in 0..cases {
        let mut bytes = mutate(&good, &mut rng);
        if case % 2 == 1 {
            // half the cases get their CRCs repaired, so the damage reaches
            // the decoder instead of stopping at a checksum
            fix_crcs(&mut bytes);
        }
        std::fs::write(&img, bytes).unwrap();
        let args = ["factorize", &common::s(&img), "-o", &common::s(&out)];
        if crate::robustness::read_or_refused(&format!("PNG case {case}"), &args, &img, &out) {
            read += 1;
        } else {
            refused += 1;
        }
    }
    eprintln!("mutated PNGs: {cases} cases, {read} read, {refused} refused");
}
