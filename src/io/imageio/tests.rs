#[test]
fn the_8_bit_encoding_equals_the_power_law_everywhere() {
    let slow = |v: f32| encode_srgb(v, 255.0) as u8;
    // every 997th positive float; 8192 ulp either side of a float at
    // most 4096 ulp past each threshold (so the threshold too); specials
    let mut values: Vec<f32> = (0..=f32::MAX.to_bits())
        .step_by(997)
        .map(f32::from_bits)
        .collect();
    for k in 1..=255u32 {
        let t = (0..=f32::MAX.to_bits())
            .step_by(1 << 12)
            .map(f32::from_bits)
            .find(|&v| slow(v) as u32 >= k)
            .unwrap();
        for d in -(1 << 13)..(1 << 13) {
            values.push(f32::from_bits((t.to_bits() as i64 + d) as u32));
        }
    }
    values.extend([-1.0, -0.0, f32::NAN, f32::INFINITY, f32::NEG_INFINITY, 1.0, 2.0]);
    for v in values {
        assert_eq!(linear_to_srgb8(v), slow(v), "{v:e} ({:#x})", v.to_bits());
    }
}

#[test]
fn mask_lookup_wraps_only_tileable_samples() {
    // 3×2: column values 0, 1, 0.5 on both rows
    let v = [0.0, 1.0, 0.5, 0.0, 1.0, 0.5];
    let at = |x: f64, y: f64, t: bool| mask_bilinear(&v, 3, 2, [x, y], t);
    // inside, both agree and interpolate between pixel centres
    for t in [false, true] {
        assert_eq!(at(0.5, 0.0, t), 0.5);
        assert_eq!(at(1.0, 0.7, t), 1.0);
        assert_eq!(at(1.5, 1.0, t), 0.75);
    }
    // between the last column and the first: a tileable sample blends
    // them, any other reads nothing there
    assert_eq!(at(2.5, 0.0, true), 0.25);
    assert_eq!(at(2.5, 0.0, false), 0.0);
    assert_eq!(at(-0.5, 0.0, true), 0.25);
    assert_eq!(at(-0.5, 0.0, false), 0.0);
    assert_eq!(at(4.0, 0.0, true), 1.0);
    assert_eq!(at(f64::NAN, 0.0, true), 0.0);
}

use super::*;

/// Deterministic pseudo-random numbers (xorshift64*).
struct Rng(u64);
impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }
    fn unit(&mut self) -> f32 {
        (self.next() >> 40) as f32 / (1u64 << 24) as f32
    }
}

fn random_image(w: usize, h: usize, seed: u64) -> RgbImage {
    let mut rng = Rng(seed);
    RgbImage {
        width: w,
        height: h,
        data: (0..w * h * 3).map(|_| rng.unit()).collect(),
    }
}

fn files_in(dir: &Path) -> Vec<String> {
    let mut v: Vec<String> = std::fs::read_dir(dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    v.sort();
    v
}

#[test]
fn srgb_functions_are_inverse_and_standard() {
    assert_eq!(srgb_to_linear(0.0), 0.0);
    assert!((srgb_to_linear(1.0) - 1.0).abs() < 1e-7);
    // Known value: sRGB 0.5 is about 0.214041 linear.
    assert!((srgb_to_linear(0.5) - 0.214_041_14).abs() < 1e-6);
    for i in 0..=1000 {
        let v = i as f32 / 1000.0;
        assert!((linear_to_srgb(srgb_to_linear(v)) - v).abs() < 1e-6, "{v}");
    }
    // Monotone across the segment boundary.
    let mut prev = -1.0;
    for i in 0..=4096 {
        let s = linear_to_srgb(i as f32 / 4096.0);
        assert!(s > prev);
        prev = s;
    }
}

#[test]
fn exr_half_round_trip_is_bit_exact() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("a.exr");
    let mut rng = Rng(7);
    let (w, h) = (13, 9);
    let data: Vec<f32> = (0..w * h * 3)
        .map(|_| loop {
            let v = f16::from_bits(rng.next() as u16);
            if v.is_finite() {
                break v.to_f32();
            }
        })
        .collect();
    let img = RgbImage {
        width: w,
        height: h,
        data,
    };
    write_exr(&path, &img, true).unwrap();
    let back = read_rgb(&path).unwrap();
    assert_eq!((back.width, back.height), (w, h));
    let a: Vec<u32> = img.data.iter().map(|v| v.to_bits()).collect();
    let b: Vec<u32> = back.data.iter().map(|v| v.to_bits()).collect();
    assert_eq!(a, b);
    assert_eq!(image_size(&path).unwrap(), (w, h));
}

#[test]
fn exr_f32_round_trip_is_exact() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("b.EXR");
    let mut img = random_image(17, 5, 3);
    img.data[0] = -3.5e7;
    img.data[1] = 1e-30;
    write_exr(&path, &img, false).unwrap();
    assert_eq!(read_rgb(&path).unwrap(), img);
    // write_rgb on .exr stores half.
    write_rgb(&path, &img).unwrap();
    let back = read_rgb(&path).unwrap();
    for (a, b) in img.data.iter().zip(&back.data).skip(2) {
        assert_eq!(*b, f16::from_f32(*a).to_f32());
    }
}

#[test]
fn png16_round_trip_within_one_code() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("c.png");
    let img = random_image(11, 7, 5);
    write_png(&path, &img, PngDepth::Sixteen).unwrap();
    let back = read_rgb(&path).unwrap();
    assert_eq!((back.width, back.height), (11, 7));
    for (a, b) in img.data.iter().zip(&back.data) {
        let d = (linear_to_srgb(*a) - linear_to_srgb(*b)).abs();
        assert!(d <= 0.5 / 65535.0 + 1e-6, "{a} {b} {d}");
    }
    assert_eq!(image_size(&path).unwrap(), (11, 7));
}

#[test]
fn png8_round_trip_within_one_code_and_clamps() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("d.png");
    let mut img = random_image(6, 10, 9);
    img.data[0] = -1.0;
    img.data[1] = 7.0;
    img.data[2] = f32::NAN;
    write_rgb(&path, &img).unwrap();
    let back = read_rgb(&path).unwrap();
    assert_eq!(&back.data[..3], &[0.0, 1.0, 0.0]);
    for (a, b) in img.data.iter().zip(&back.data).skip(3) {
        let d = (linear_to_srgb(*a) - linear_to_srgb(*b)).abs();
        assert!(d <= 0.5 / 255.0 + 1e-6, "{a} {b} {d}");
    }
}

#[test]
fn mask_png_round_trip() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("m.png");
    let values: Vec<f32> = (0..256).map(|i| i as f32 / 255.0).collect();
    write_mask_png(&path, 16, 16, &values).unwrap();
    let back = read_sized_mask(&path, 16, 16, "it must be").unwrap();
    for (a, b) in values.iter().zip(&back) {
        assert!((a - b).abs() < 1e-6);
    }
    let e = read_sized_mask(&path, 16, 8, "a region mask must be the atlas size")
        .unwrap_err()
        .to_string();
    assert!(
        e.contains("m.png") && e.contains("16×16") && e.contains("atlas size 16×8"),
        "{e}"
    );
    // the largest channel counts, as stored: an RGB mask with a pure red
    // foreground reads 1 there
    let rgb = dir.path().join("rgb.png");
    image::ImageBuffer::from_fn(2, 1, |x, _| {
        image::Rgb(if x == 0 { [255u8, 0, 0] } else { [0, 64, 0] })
    })
    .save(&rgb)
    .unwrap();
    let m = read_sized_mask(&rgb, 2, 1, "").unwrap();
    assert_eq!(m, vec![1.0, 64.0 / 255.0]);
}

#[test]
fn grey_png_reads_as_equal_rgb() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("g.png");
    let values: Vec<f32> = (0..20).map(|i| i as f32 / 19.0).collect();
    write_mask_png(&path, 5, 4, &values).unwrap();
    let img = read_rgb(&path).unwrap();
    for (p, v) in img.data.chunks_exact(3).zip(&values) {
        assert_eq!(p[0], p[1]);
        assert_eq!(p[1], p[2]);
        // Grey PNG is sRGB-decoded like any other.
        assert!((p[0] - srgb_to_linear((v * 255.0).round() / 255.0)).abs() < 1e-6);
    }
}

#[test]
fn reads_grey_alpha_rgba_tiff_and_jpeg() {
    let dir = tempfile::tempdir().unwrap();
    // 16-bit grey + alpha PNG: alpha dropped, grey replicated, sRGB-decoded.
    let la: Vec<u16> = (0..12u16).flat_map(|i| [i * 5000, 123]).collect();
    let p = dir.path().join("la.png");
    image::ImageBuffer::<image::LumaA<u16>, _>::from_raw(4, 3, la.clone())
        .unwrap()
        .save(&p)
        .unwrap();
    let img = read_rgb(&p).unwrap();
    for (px, g) in img.data.chunks_exact(3).zip(la.chunks_exact(2)) {
        assert_eq!(px, &[srgb_to_linear(g[0] as f32 / 65535.0); 3]);
    }
    // 8-bit RGBA PNG and RGB TIFF.
    let rgba: Vec<u8> = (0..24u8).map(|i| i * 10).collect();
    let rgb: Vec<u8> = rgba.chunks_exact(4).flat_map(|p| [p[0], p[1], p[2]]).collect();
    let p = dir.path().join("rgba.png");
    image::ImageBuffer::<image::Rgba<u8>, _>::from_raw(3, 2, rgba)
        .unwrap()
        .save(&p)
        .unwrap();
    let t = dir.path().join("rgb.TIF");
    image::ImageBuffer::<image::Rgb<u8>, _>::from_raw(3, 2, rgb.clone())
        .unwrap()
        .save_with_format(&t, ImageFormat::Tiff)
        .unwrap();
    let want: Vec<f32> = rgb.iter().map(|&v| srgb_to_linear(v as f32 / 255.0)).collect();
    assert_eq!(read_rgb(&p).unwrap().data, want);
    assert_eq!(read_rgb(&t).unwrap().data, want);
    assert_eq!(image_size(&t).unwrap(), (3, 2));
    // JPEG of a flat mid grey decodes close to it.
    let j = dir.path().join("flat.jpeg");
    image::ImageBuffer::<image::Rgb<u8>, _>::from_pixel(16, 8, image::Rgb([128, 128, 128]))
        .save_with_format(&j, ImageFormat::Jpeg)
        .unwrap();
    let img = read_rgb(&j).unwrap();
    assert_eq!((img.width, img.height), (16, 8));
    let mid = srgb_to_linear(128.0 / 255.0);
    assert!(img.data.iter().all(|v| (v - mid).abs() < 0.01));
    assert_eq!(image_size(&j).unwrap(), (16, 8));
}

#[test]
fn reads_gif_palette_images_like_the_classic_samples() {
    // a two-colour GIF (the classic basket, jelly and nuts samples are
    // palette GIFs): both colours come back exactly, sRGB-decoded
    let dir = tempfile::tempdir().unwrap();
    let p = dir.path().join("two.GIF");
    let (a, b) = ([200u8, 40, 10], [0u8, 90, 250]);
    image::ImageBuffer::from_fn(5, 4, |x, y| {
        image::Rgba(if (x + y) % 2 == 0 {
            [a[0], a[1], a[2], 255]
        } else {
            [b[0], b[1], b[2], 255]
        })
    })
    .save_with_format(&p, ImageFormat::Gif)
    .unwrap();
    assert!(is_image_path(&p) && crate::factorize::is_image_path(&p));
    let img = read_rgb(&p).unwrap();
    assert_eq!((img.width, img.height), (5, 4));
    for (i, px) in img.data.chunks_exact(3).enumerate() {
        let (x, y) = (i % 5, i / 5);
        let want = if (x + y) % 2 == 0 { a } else { b };
        let want = want.map(|v| srgb_to_linear(v as f32 / 255.0));
        assert_eq!(px, &want, "pixel ({x}, {y})");
    }
}

#[test]
fn exr_channels_round_trip_with_exr_crate() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("geo.exr");
    let (w, h) = (7, 3);
    let chans: Vec<(String, Vec<f32>)> = ["pos.x", "pos.y", "depth"]
        .iter()
        .enumerate()
        .map(|(k, n)| {
            (
                n.to_string(),
                (0..w * h).map(|i| i as f32 * 0.37 + k as f32).collect(),
            )
        })
        .collect();
    write_exr_channels(&path, w, h, &chans, false).unwrap();
    let img = x::read_first_flat_layer_from_file(&path).unwrap();
    let layer = img.layer_data;
    assert_eq!((layer.size.width(), layer.size.height()), (w, h));
    assert_eq!(layer.channel_data.list.len(), 3);
    for (name, values) in &chans {
        let c = layer
            .channel_data
            .list
            .iter()
            .find(|c| c.name.to_string() == *name)
            .unwrap();
        let back: Vec<f32> = c.sample_data.values_as_f32().collect();
        assert_eq!(&back, values);
    }
    // A single non-RGB channel reads as grey.
    let path1 = dir.path().join("one.exr");
    write_exr_channels(&path1, w, h, &chans[2..], true).unwrap();
    let grey = read_rgb(&path1).unwrap();
    for (p, v) in grey.data.chunks_exact(3).zip(&chans[2].1) {
        assert_eq!(p, &[f16::from_f32(*v).to_f32(); 3]);
    }
    // Two non-RGB channels are ambiguous.
    let err = read_rgb(&path).unwrap_err().to_string();
    assert!(err.contains("geo.exr") && err.contains("depth"), "{err}");
    // Duplicate names are refused.
    let dup = vec![chans[0].clone(), chans[0].clone()];
    assert!(write_exr_channels(&path1, w, h, &dup, false).is_err());
}

#[test]
fn missing_directory_is_io_error_naming_path() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("nope").join("x.png");
    let err = write_png(&path, &random_image(2, 2, 1), PngDepth::Eight).unwrap_err();
    assert!(matches!(err, Error::Io { .. }), "{err:?}");
    assert!(err.to_string().contains("x.png"));
    assert!(!path.exists());
}

#[test]
fn failed_write_leaves_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("out.png");
    let err = write_atomic(&path, |w| {
        w.write_all(&[1u8; 100_000]).unwrap();
        Err(Error::input(&path, "boom"))
    })
    .unwrap_err();
    assert!(err.to_string().contains("boom"));
    assert!(files_in(dir.path()).is_empty());
    // Bad buffer: refused before anything is created.
    let bad = RgbImage {
        width: 4,
        height: 4,
        data: vec![0.0; 5],
    };
    assert!(write_exr(&path, &bad, true).is_err());
    assert!(files_in(dir.path()).is_empty());
    // Rename onto a directory fails; the temp file is cleaned up.
    let sub = dir.path().join("taken.exr");
    std::fs::create_dir(&sub).unwrap();
    let err = write_exr(&sub, &random_image(3, 3, 2), true).unwrap_err();
    assert!(matches!(err, Error::Io { .. }));
    assert_eq!(files_in(dir.path()), vec!["taken.exr".to_string()]);
    assert!(sub.is_dir());
    // A successful write over an existing file replaces it.
    write_png(&path, &random_image(2, 3, 4), PngDepth::Eight).unwrap();
    write_png(&path, &random_image(5, 1, 4), PngDepth::Eight).unwrap();
    assert_eq!(image_size(&path).unwrap(), (5, 1));
    assert_eq!(files_in(dir.path()).len(), 2);
}

#[test]
fn exr_from_a_pixel_function_equals_the_whole_image_and_fails_cleanly() {
    let dir = tempfile::tempdir().unwrap();
    let img = random_image(37, 29, 7);
    let (whole, from_fn) = (dir.path().join("whole.exr"), dir.path().join("fn.exr"));
    write_exr(&whole, &img, true).unwrap();
    let at = |x: usize, y: usize| {
        let i = (y * img.width + x) * 3;
        [img.data[i], img.data[i + 1], img.data[i + 2]]
    };
    write_exr_rgb_fn(&from_fn, 37, 29, |x, y| Ok(at(x, y))).unwrap();
    let (a, b) = (read_rgb(&whole).unwrap(), read_rgb(&from_fn).unwrap());
    assert_eq!((b.width, b.height), (37, 29));
    assert!(a
        .data
        .iter()
        .zip(&b.data)
        .all(|(p, q)| p.to_bits() == q.to_bits()));
    // a pixel that fails: its error, and the file already there untouched
    let before = std::fs::read(&from_fn).unwrap();
    let err = write_exr_rgb_fn(&from_fn, 37, 29, |x, y| {
        if (x, y) == (30, 20) {
            Err(Error::input(Path::new("q.quilt"), "damaged chunk"))
        } else {
            Ok(at(x, y))
        }
    })
    .unwrap_err();
    assert!(err.to_string().contains("damaged chunk"), "{err}");
    assert_eq!(std::fs::read(&from_fn).unwrap(), before);
    assert_eq!(files_in(dir.path()).len(), 2);
}

#[test]
fn exr_channels_from_a_pixel_function_are_the_same_file() {
    let dir = tempfile::tempdir().unwrap();
    let (w, h) = (23, 17);
    let value = |c: usize, t: usize| {
        if t % 5 == 0 {
            f32::NAN
        } else {
            (t * 8 + c) as f32 * 0.37 - 3.0
        }
    };
    let names = ["u", "v", "angle", "dudX", "dvdX", "dudY", "dvdY", "sample"];
    for n in [7, 8] {
        let planes: Vec<(String, Vec<f32>)> = (0..n)
            .map(|c| (names[c].to_string(), (0..w * h).map(|t| value(c, t)).collect()))
            .collect();
        let (a, b) = (
            dir.path().join(format!("a{n}.exr")),
            dir.path().join(format!("b{n}.exr")),
        );
        write_exr_channels(&a, w, h, &planes, false).unwrap();
        if n == 7 {
            let seven: [&str; 7] = std::array::from_fn(|c| names[c]);
            write_exr_f32_fn(&b, w, h, seven, |x, y| {
                Ok(std::array::from_fn(|c| value(c, y * w + x)))
            })
            .unwrap();
        } else {
            write_exr_f32_fn(&b, w, h, names, |x, y| {
                Ok(std::array::from_fn(|c| value(c, y * w + x)))
            })
            .unwrap();
        }
        assert_eq!(
            std::fs::read(&a).unwrap(),
            std::fs::read(&b).unwrap(),
            "{n} channels"
        );
    }
}

#[test]
fn read_errors() {
    let dir = tempfile::tempdir().unwrap();
    let missing = dir.path().join("missing.png");
    assert!(matches!(read_rgb(&missing), Err(Error::Io { .. })));
    assert!(matches!(image_size(&missing), Err(Error::Io { .. })));
    let odd = dir.path().join("pic.bmp");
    std::fs::write(&odd, b"BM").unwrap();
    let err = read_rgb(&odd).unwrap_err();
    assert!(matches!(err, Error::Input { .. }) && err.to_string().contains("pic.bmp"));
    assert!(write_rgb(&odd, &random_image(1, 1, 1)).is_err());
    for name in ["junk.png", "junk.exr", "junk.jpg", "junk.tif"] {
        let p = dir.path().join(name);
        std::fs::write(&p, b"definitely not an image").unwrap();
        let err = read_rgb(&p).unwrap_err();
        assert!(matches!(err, Error::Input { .. }), "{name}: {err:?}");
        assert!(err.to_string().contains(name));
        assert!(image_size(&p).is_err());
    }
}

#[test]
fn eight_bit_masks_read_as_their_float_conversion() {
    // every code value in every 8-bit layout reads exactly as the largest
    // channel of the image crate's float RGB (which drops alpha)
    let dir = tempfile::tempdir().unwrap();
    let v = |x: u32, y: u32| ((x * 7 + y * 16) % 256) as u8;
    let images: Vec<(&str, image::DynamicImage)> = vec![
        (
            "l8",
            image::DynamicImage::ImageLuma8(image::ImageBuffer::from_fn(16, 16, |x, y| {
                image::Luma([v(x, y)])
            })),
        ),
        (
            "la8",
            image::DynamicImage::ImageLumaA8(image::ImageBuffer::from_fn(16, 16, |x, y| {
                image::LumaA([v(x, y), 255 - v(y, x)])
            })),
        ),
        (
            "rgb8",
            image::DynamicImage::ImageRgb8(image::ImageBuffer::from_fn(16, 16, |x, y| {
                image::Rgb([v(x, y), v(y, x), v(x + 3, y)])
            })),
        ),
        (
            "rgba8",
            image::DynamicImage::ImageRgba8(image::ImageBuffer::from_fn(16, 16, |x, y| {
                image::Rgba([v(y, x), v(x, y), 9, v(x + 1, y)])
            })),
        ),
    ];
    for (name, img) in images {
        let path = dir.path().join(format!("{name}.png"));
        img.save(&path).unwrap();
        let expected = super::largest_channel(&img.to_rgb32f().into_raw());
        assert_eq!(read_sized_mask(&path, 16, 16, "").unwrap(), expected, "{name}");
        // the marked pixels alone: those at one half or more
        let marked: Vec<u32> = (0..256).filter(|&k| expected[k as usize] >= 0.5).collect();
        assert!(!marked.is_empty() && marked.len() < 256, "{name}");
        assert_eq!(
            super::read_mask_marked(&path, 16, 16, "").unwrap(),
            marked,
            "{name}"
        );
    }
}

/// Writes a PNG of `data` (rows packed as the layout packs them) with an
/// optional palette and transparency.
fn encode_png(
    path: &Path,
    (w, h): (u32, u32),
    (colour, depth): (png::ColorType, png::BitDepth),
    (palette, trns): (Option<&[u8]>, Option<&[u8]>),
    data: &[u8],
) {
    let mut enc = png::Encoder::new(std::fs::File::create(path).unwrap(), w, h);
    enc.set_color(colour);
    enc.set_depth(depth);
    if let Some(p) = palette {
        enc.set_palette(p.to_vec());
    }
    if let Some(t) = trns {
        enc.set_trns(t.to_vec());
    }
    enc.write_header().unwrap().write_image_data(data).unwrap();
}

#[test]
fn masks_of_every_png_layout_read_as_the_image_crate_decodes_them() {
    // palette and low-bit grey are expanded row by row as the image crate
    // expands them; 16-bit masks take the whole-image path: all equal the
    // largest channel of the crate's float RGB
    let dir = tempfile::tempdir().unwrap();
    let (w, h) = (13u32, 9u32);
    let write =
        |name: &str, colour: png::ColorType, depth: png::BitDepth, palette: Option<&[u8]>, data: &[u8]| {
            let path = dir.path().join(format!("{name}.png"));
            encode_png(&path, (w, h), (colour, depth), (palette, None), data);
            path
        };
    let bits = |per_px: usize, f: &dyn Fn(u32, u32) -> u8| -> Vec<u8> {
        // rows packed at `per_px` bits, each row padded to a byte
        let mut out = Vec::new();
        for y in 0..h {
            let mut row = vec![0u8; (w as usize * per_px).div_ceil(8)];
            for x in 0..w {
                let bit = x as usize * per_px;
                row[bit / 8] |= f(x, y) << (8 - per_px - bit % 8);
            }
            out.extend(row);
        }
        out
    };
    let palette = [0u8, 0, 0, 200, 10, 10, 40, 250, 90, 128, 128, 128];
    let grey16: Vec<u8> = (0..w * h)
        .flat_map(|k| ((k * 997) as u16).to_be_bytes())
        .collect();
    let cases: [(&str, png::ColorType, png::BitDepth, Option<&[u8]>, Vec<u8>); 4] = [
        (
            "grey1",
            png::ColorType::Grayscale,
            png::BitDepth::One,
            None,
            bits(1, &|x, y| ((x + y) % 2) as u8),
        ),
        (
            "grey4",
            png::ColorType::Grayscale,
            png::BitDepth::Four,
            None,
            bits(4, &|x, y| ((x * 3 + y) % 16) as u8),
        ),
        (
            "palette2",
            png::ColorType::Indexed,
            png::BitDepth::Two,
            Some(&palette),
            bits(2, &|x, y| ((x + 2 * y) % 4) as u8),
        ),
        (
            "grey16",
            png::ColorType::Grayscale,
            png::BitDepth::Sixteen,
            None,
            grey16,
        ),
    ];
    for (name, colour, depth, palette, data) in cases {
        let path = write(name, colour, depth, palette, &data);
        let img = image::open(&path).unwrap();
        let expected = super::largest_channel(&img.to_rgb32f().into_raw());
        let n = (w * h) as usize;
        assert_eq!(
            read_sized_mask(&path, w as usize, h as usize, "").unwrap(),
            expected,
            "{name}"
        );
        let marked: Vec<u32> = (0..n as u32).filter(|&k| expected[k as usize] >= 0.5).collect();
        assert!(!marked.is_empty() && marked.len() < n, "{name}");
        assert_eq!(
            super::read_mask_marked(&path, w as usize, h as usize, "").unwrap(),
            marked,
            "{name}"
        );
    }
}

#[test]
fn a_mask_cut_short_is_refused_by_name() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("region.png");
    let img = image::DynamicImage::ImageLuma8(image::ImageBuffer::from_fn(64, 64, |x, y| {
        image::Luma([((x * 31 + y * 17) % 256) as u8])
    }));
    img.save(&path).unwrap();
    let bytes = std::fs::read(&path).unwrap();
    std::fs::write(&path, &bytes[..bytes.len() / 2]).unwrap();
    let e = super::read_mask_marked(&path, 64, 64, "")
        .unwrap_err()
        .to_string();
    assert!(e.contains("region.png") && e.contains("ends early"), "{e}");
}

#[test]
fn rgb_bands_of_every_png_layout_are_the_whole_image() {
    // 8- and 16-bit grey, grey with alpha, RGB and RGBA, palettes with and
    // without transparency, low-bit grey (all read a row at a time), and a
    // JPEG (read whole): band after band, the values of the whole-image
    // path, in bands of 1, 4 and 16 rows
    let dir = tempfile::tempdir().unwrap();
    let (w, h) = (13u32, 9u32);
    let n = (w * h) as usize;
    let code = |k: usize, c: usize| ((k * 37 + c * 101) % 256) as u8;
    let wide = |k: usize, c: usize| ((k * 9973 + c * 12345) % 65536) as u16;
    let eight = |ch: usize| -> Vec<u8> { (0..n).flat_map(|k| (0..ch).map(move |c| code(k, c))).collect() };
    let sixteen = |ch: usize| -> Vec<u8> {
        (0..n)
            .flat_map(|k| (0..ch).flat_map(move |c| wide(k, c).to_be_bytes()))
            .collect()
    };
    let grey2: Vec<u8> = (0..h)
        .flat_map(|y| {
            let mut row = vec![0u8; (w as usize * 2).div_ceil(8)];
            for x in 0..w as usize {
                row[x * 2 / 8] |= (((x + y as usize) % 4) as u8) << (6 - x * 2 % 8);
            }
            row
        })
        .collect();
    let palette = [0u8, 0, 0, 200, 10, 10, 40, 250, 90, 128, 128, 128];
    let indices: Vec<u8> = (0..n).map(|k| (k % 4) as u8).collect();
    use png::{BitDepth as D, ColorType as C};
    let cases: Vec<(&str, C, D, Option<&[u8]>, bool, Vec<u8>)> = vec![
        ("grey8", C::Grayscale, D::Eight, None, false, eight(1)),
        ("grey16", C::Grayscale, D::Sixteen, None, false, sixteen(1)),
        ("greyalpha8", C::GrayscaleAlpha, D::Eight, None, false, eight(2)),
        ("rgb8", C::Rgb, D::Eight, None, false, eight(3)),
        ("rgba8", C::Rgba, D::Eight, None, false, eight(4)),
        ("rgb16", C::Rgb, D::Sixteen, None, false, sixteen(3)),
        ("rgba16", C::Rgba, D::Sixteen, None, false, sixteen(4)),
        ("grey2", C::Grayscale, D::Two, None, false, grey2),
        (
            "palette",
            C::Indexed,
            D::Eight,
            Some(&palette),
            false,
            indices.clone(),
        ),
        (
            "palette_trns",
            C::Indexed,
            D::Eight,
            Some(&palette),
            true,
            indices,
        ),
    ];
    let mut paths = Vec::new();
    for (name, colour, depth, palette, trns, data) in cases {
        let path = dir.path().join(format!("{name}.png"));
        let trns = trns.then_some(&[255u8, 0, 128, 255][..]);
        encode_png(&path, (w, h), (colour, depth), (palette, trns), &data);
        paths.push((name, path));
    }
    let jpeg = dir.path().join("photo.jpg");
    image::RgbImage::from_fn(w, h, |x, y| image::Rgb([(x * 19) as u8, (y * 27) as u8, 90]))
        .save(&jpeg)
        .unwrap();
    paths.push(("jpeg", jpeg));
    for (name, path) in paths {
        let whole = read_rgb_within(&path, 1 << 20).unwrap();
        for band in [1, 4, 16] {
            let mut got = Vec::new();
            let mut next = 0;
            let size = each_rgb_band(&path, 1 << 20, band, |y0, rows| {
                assert_eq!(y0, next, "{name}: bands in order");
                next += rows.len() / (w as usize * 3);
                got.extend_from_slice(rows);
                Ok(())
            })
            .unwrap();
            assert_eq!(size, (w as usize, h as usize), "{name}");
            let same = got.len() == whole.data.len()
                && got
                    .iter()
                    .zip(&whole.data)
                    .all(|(a, b)| a.to_bits() == b.to_bits());
            assert!(same, "{name} in bands of {band}");
        }
    }
}

#[test]
fn a_png_read_in_bands_keeps_the_budget_and_names_a_truncated_file() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("big.png");
    let img = image::DynamicImage::ImageRgb8(image::ImageBuffer::from_fn(300, 200, |x, y| {
        image::Rgb([(x % 256) as u8, (y % 256) as u8, ((x * y) % 256) as u8])
    }));
    img.save(&path).unwrap();
    // 300 × 200 × 12 bytes decoded: refused over 64 KiB as the whole-image
    // path refuses it, read in bands within 1 MiB
    let over = each_rgb_band(&path, 64 << 10, 16, |_, _| Ok(()))
        .unwrap_err()
        .to_string();
    let whole = read_rgb_within(&path, 64 << 10).unwrap_err().to_string();
    assert_eq!(over, whole);
    assert!(
        over.contains("big.png") && over.contains("memory budget"),
        "{over}"
    );
    let mut rows = 0;
    each_rgb_band(&path, 1 << 20, 16, |_, band| {
        rows += band.len() / (300 * 3);
        Ok(())
    })
    .unwrap();
    assert_eq!(rows, 200);
    let bytes = std::fs::read(&path).unwrap();
    std::fs::write(&path, &bytes[..bytes.len() / 2]).unwrap();
    let e = each_rgb_band(&path, 1 << 20, 16, |_, _| Ok(()))
        .unwrap_err()
        .to_string();
    assert!(e.contains("big.png") && e.contains("ends early"), "{e}");
}
