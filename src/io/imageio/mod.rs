//! Images in and out as linear-light float RGB: PNG, JPEG, TIFF and OpenEXR.
//!
//! 8/16-bit formats are treated as sRGB-encoded; OpenEXR is linear. Every
//! write goes to a temporary file in the destination directory that is
//! renamed into place only once it is complete ([`write_atomic`]).

use std::fs::File;
use std::io::{BufReader, BufWriter, Read, Write};
use std::path::Path;
use std::sync::OnceLock;

use exr::prelude as x;
use exr::prelude::{ReadChannels, ReadLayers, WritableImage};
use half::f16;
use image::{DynamicImage, ImageFormat};

use crate::math;
use crate::{Error, Result};

/// A linear-light RGB image, row-major, 3 f32 per pixel.
#[derive(Clone, Debug, PartialEq)]
pub struct RgbImage {
    pub width: usize,
    pub height: usize,
    pub data: Vec<f32>,
}

mod dilation;
mod sampling;
mod write;
pub use dilation::*;
pub use sampling::*;
pub use write::*;

impl RgbImage {
    /// A black image of the given size.
    pub fn new(width: usize, height: usize) -> Self {
        RgbImage {
            width,
            height,
            data: vec![0.0; width * height * 3],
        }
    }
}

/// Bit depth for PNG output.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PngDepth {
    Eight,
    Sixteen,
}

/// The file kinds this module reads.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Kind {
    Raster(ImageFormat),
    Exr,
}

/// Extensions (lower case) of the image files every stage reads.
pub const IMAGE_EXTENSIONS: [&str; 7] = ["png", "jpg", "jpeg", "tif", "tiff", "gif", "exr"];

/// Whether `path` names an image (by its case-insensitive extension) rather
/// than an artifact or another input.
pub fn is_image_path(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| IMAGE_EXTENSIONS.contains(&e.to_ascii_lowercase().as_str()))
}

/// Picks the format from the (case-insensitive) extension.
fn kind_of(path: &Path) -> Result<Kind> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .map(|e| e.to_ascii_lowercase())
        .unwrap_or_default();
    match ext.as_str() {
        "png" => Ok(Kind::Raster(ImageFormat::Png)),
        "jpg" | "jpeg" => Ok(Kind::Raster(ImageFormat::Jpeg)),
        "tif" | "tiff" => Ok(Kind::Raster(ImageFormat::Tiff)),
        "gif" => Ok(Kind::Raster(ImageFormat::Gif)),
        "exr" => Ok(Kind::Exr),
        _ => Err(Error::input(
            path,
            format!(
                "unsupported image extension '{ext}' (expected .png, .jpg, .jpeg, .tif, .tiff, .gif or .exr)"
            ),
        )),
    }
}

/// Opens a file for buffered reading; a missing file is an I/O error.
fn open(path: &Path) -> Result<BufReader<File>> {
    File::open(path)
        .map(BufReader::new)
        .map_err(|e| Error::io(path, e))
}

/// Maps an `image` error: I/O stays I/O, everything else is bad input (a
/// file ending early among it: the decoder reports that as I/O).
fn image_err(path: &Path, e: image::ImageError) -> Error {
    match e {
        image::ImageError::IoError(io) if io.kind() == std::io::ErrorKind::UnexpectedEof => ends_early(path),
        image::ImageError::IoError(io) => Error::io(path, io),
        other => Error::input(path, format!("cannot decode image: {other}")),
    }
}

/// An image whose file ends before its pixels do.
fn ends_early(path: &Path) -> Error {
    Error::input(path, "cannot decode image: the file ends early (truncated)")
}

/// Maps an `exr` error: I/O stays I/O, everything else is bad input.
fn exr_err(path: &Path, e: x::Error) -> Error {
    match e {
        x::Error::Io(io) => Error::io(path, io),
        other => Error::input(path, format!("OpenEXR: {other}")),
    }
}

/// The longest side, in pixels, of any image btfquilt reads. Samples and
/// masks are photographs or atlases of at most a few thousand pixels; a
/// header declaring more than this is refused before anything is decoded.
pub const MAX_IMAGE_SIDE: usize = 32768;

/// The decoded size an image read may reach when the caller has no memory
/// budget at hand: 4 GiB of linear f32 RGB (12 bytes a pixel), about a
/// 18900² image.
pub const DEFAULT_DECODE_BYTES: u64 = 4 << 30;

/// Bytes of the linear f32 RGB a `width`×`height` image decodes to.
fn decoded_bytes(width: usize, height: usize) -> u128 {
    width as u128 * height as u128 * 12
}

/// `bytes` for a message: "3.2 GiB", "512.0 MiB", "900 bytes".
fn human_bytes(bytes: u128) -> String {
    const KIB: f64 = 1024.0;
    let b = bytes as f64;
    if b >= KIB * KIB * KIB {
        format!("{:.1} GiB", b / (KIB * KIB * KIB))
    } else if b >= KIB * KIB {
        format!("{:.1} MiB", b / (KIB * KIB))
    } else if b >= KIB {
        format!("{:.1} KiB", b / KIB)
    } else {
        format!("{bytes} bytes")
    }
}

/// Refuses, from the size a file's header declares and before any decoding,
/// an empty image, one with a side over [`MAX_IMAGE_SIDE`], or one whose
/// decoded linear RGB would exceed `max_bytes`.
fn check_declared(path: &Path, width: usize, height: usize, max_bytes: u64) -> Result<()> {
    if width == 0 || height == 0 {
        return Err(Error::input(
            path,
            format!("declares an empty {width}×{height} image"),
        ));
    }
    if width > MAX_IMAGE_SIDE || height > MAX_IMAGE_SIDE {
        return Err(Error::input(
            path,
            format!(
                "declares {width}×{height} pixels, more than the largest image btfquilt reads ({MAX_IMAGE_SIDE} px a side)"
            ),
        ));
    }
    let need = decoded_bytes(width, height);
    if need > max_bytes as u128 {
        return Err(Error::input(
            path,
            format!(
                "declares {width}×{height} pixels, which would need {} decoded, over the memory budget of {} (see --memory)",
                human_bytes(need),
                human_bytes(max_bytes as u128)
            ),
        ));
    }
    Ok(())
}

/// The size a PNG/JPEG/TIFF/GIF header declares, without decoding pixels.
/// A PNG's is read from its IHDR chunk directly: the `image` PNG decoder
/// sets up its row buffers (and checks them against its limits) already
/// when it reads the header.
fn raster_size(path: &Path, format: ImageFormat) -> Result<(usize, usize)> {
    if format == ImageFormat::Png {
        let mut head = Vec::with_capacity(24);
        open(path)?
            .take(24)
            .read_to_end(&mut head)
            .map_err(|e| Error::io(path, e))?;
        if head.len() < 24 || &head[..8] != b"\x89PNG\r\n\x1a\n" || &head[12..16] != b"IHDR" {
            return Err(Error::input(
                path,
                "cannot decode image: not a PNG (it does not start with the PNG signature and IHDR header)",
            ));
        }
        let be = |b: &[u8]| u32::from_be_bytes([b[0], b[1], b[2], b[3]]) as usize;
        return Ok((be(&head[16..20]), be(&head[20..24])));
    }
    let (w, h) = image::ImageReader::with_format(open(path)?, format)
        .into_dimensions()
        .map_err(|e| image_err(path, e))?;
    Ok((w as usize, h as usize))
}

/// An OpenEXR's headers (no pixels are read).
fn exr_meta(path: &Path) -> Result<x::MetaData> {
    x::MetaData::read_from_buffered(open(path)?, false).map_err(|e| exr_err(path, e))
}

/// The size of an OpenEXR's largest layer as its header declares it (the
/// header only; no pixels are read).
fn exr_size(path: &Path) -> Result<(usize, usize)> {
    let meta = exr_meta(path)?;
    let mut largest: Option<(usize, usize)> = None;
    for header in &meta.headers {
        let size = (header.layer_size.width(), header.layer_size.height());
        if largest.map_or(true, |l| decoded_bytes(size.0, size.1) > decoded_bytes(l.0, l.1)) {
            largest = Some(size);
        }
    }
    largest.ok_or_else(|| Error::input(path, "OpenEXR file has no layers"))
}

/// The declared size of any image this module reads.
fn declared_size(path: &Path, kind: Kind) -> Result<(usize, usize)> {
    match kind {
        Kind::Exr => exr_size(path),
        Kind::Raster(format) => raster_size(path, format),
    }
}

/// Decodes a PNG/JPEG/TIFF/GIF whose header [`check_declared`] has passed
/// into a `DynamicImage`, with the decoder itself held to the same bounds (a
/// file changed in between, or a decoder's own buffers, cannot exceed them).
fn decode_raster(path: &Path, format: ImageFormat, max_bytes: u64) -> Result<DynamicImage> {
    let mut limits = image::Limits::default();
    limits.max_image_width = Some(MAX_IMAGE_SIDE as u32);
    limits.max_image_height = Some(MAX_IMAGE_SIDE as u32);
    limits.max_alloc = Some(max_bytes);
    let mut reader = image::ImageReader::with_format(open(path)?, format);
    reader.limits(limits);
    reader.decode().map_err(|e| image_err(path, e))
}

/// Pixel count of a `width` x `height` image times `channels`, checked.
fn sample_count(path: &Path, width: usize, height: usize, channels: usize) -> Result<usize> {
    width
        .checked_mul(height)
        .and_then(|n| n.checked_mul(channels))
        .ok_or_else(|| Error::input(path, format!("image size {width}x{height} is too large")))
}

/// Exact sRGB decoding of an 8-bit code value, via a table.
fn srgb8_table() -> &'static [f32; 256] {
    static T: OnceLock<[f32; 256]> = OnceLock::new();
    T.get_or_init(|| std::array::from_fn(|i| srgb_to_linear(i as f32 / 255.0)))
}

/// Exact sRGB decoding of a 16-bit code value, via a table.
fn srgb16_table() -> &'static [f32] {
    static T: OnceLock<Vec<f32>> = OnceLock::new();
    T.get_or_init(|| {
        (0..=u16::MAX)
            .map(|i| srgb_to_linear(i as f32 / 65535.0))
            .collect()
    })
}

/// True if the decoded image stores floats (e.g. a float TIFF).
fn is_float(img: &DynamicImage) -> bool {
    let c = img.color();
    c.bytes_per_pixel() / c.channel_count() == 4
}

/// True if the decoded image has 8 bits per channel.
fn is_8bit(img: &DynamicImage) -> bool {
    let c = img.color();
    c.bytes_per_pixel() / c.channel_count() == 1
}

/// A painting mask (a sample's foreground, a region): per pixel its largest
/// channel as stored — a mask is data, not colour, so there is no sRGB
/// decoding (grey 128 is 0.502, as `generate-btf` writes it) — clamped to
/// 0..1. It must be `width`×`height`; `must_be` names that size for the
/// error (e.g. "a region mask must be the atlas size").
///
/// The size is checked from the file's header before anything is decoded,
/// and the decoded image is held to [`DEFAULT_DECODE_BYTES`].
pub fn read_sized_mask(path: &Path, width: usize, height: usize, must_be: &str) -> Result<Vec<f32>> {
    let mut mask = Vec::with_capacity(width * height);
    each_mask_value(path, width, height, must_be, |v| mask.push(v))?;
    Ok(mask)
}

/// The pixels (row-major indices, ascending) where the mask of
/// [`read_sized_mask`] is at least one half, without holding its values: a
/// region mask at a large atlas's size keeps only its decoded image.
pub fn read_mask_marked(path: &Path, width: usize, height: usize, must_be: &str) -> Result<Vec<u32>> {
    let (mut marked, mut k) = (Vec::new(), 0u32);
    each_mask_value(path, width, height, must_be, |v| {
        if v >= 0.5 {
            marked.push(k);
        }
        k += 1;
    })?;
    Ok(marked)
}

/// Calls `f` with the value of [`read_sized_mask`] at each pixel in turn.
fn each_mask_value(
    path: &Path,
    width: usize,
    height: usize,
    must_be: &str,
    mut f: impl FnMut(f32),
) -> Result<()> {
    let kind = kind_of(path)?;
    let (w, h) = declared_size(path, kind)?;
    if (w, h) != (width, height) {
        return Err(Error::input(
            path,
            format!("is {w}×{h}, but {must_be} {width}×{height}"),
        ));
    }
    check_declared(path, w, h, DEFAULT_DECODE_BYTES)?;
    let (w, h, rgb) = match kind {
        Kind::Exr => {
            let img = read_exr_rgb(path, DEFAULT_DECODE_BYTES)?;
            (img.width, img.height, img.data)
        }
        Kind::Raster(format) => {
            if format == ImageFormat::Png && each_png_mask_row(path, (width, height), &mut f)? {
                return Ok(());
            }
            let img = decode_raster(path, format, DEFAULT_DECODE_BYTES)?;
            let (w, h) = (img.width() as usize, img.height() as usize);
            if (w, h) != (width, height) {
                return Err(decoded_size_differs(path, (w, h), (width, height)));
            }
            // 8-bit masks (the usual ones) straight from their bytes: the
            // largest colour channel, alpha dropped, without a float RGB
            // copy of the whole image
            match &img {
                DynamicImage::ImageLuma8(b) => each_eight_bit_value(b.as_raw(), 1, 1, &mut f),
                DynamicImage::ImageLumaA8(b) => each_eight_bit_value(b.as_raw(), 2, 1, &mut f),
                DynamicImage::ImageRgb8(b) => each_eight_bit_value(b.as_raw(), 3, 3, &mut f),
                DynamicImage::ImageRgba8(b) => each_eight_bit_value(b.as_raw(), 4, 3, &mut f),
                other => largest_channel(&other.to_rgb32f().into_raw())
                    .into_iter()
                    .for_each(f),
            }
            return Ok(());
        }
    };
    if (w, h) != (width, height) {
        return Err(decoded_size_differs(path, (w, h), (width, height)));
    }
    largest_channel(&rgb).into_iter().for_each(f);
    Ok(())
}

/// A PNG opened to be read a row at a time, palette and low-bit grey
/// expanded to 8 bits as the image crate expands them.
fn png_rows(path: &Path) -> Result<png::Reader<BufReader<File>>> {
    let mut decoder = png::Decoder::new(open(path)?);
    decoder.set_transformations(png::Transformations::EXPAND);
    decoder.read_info().map_err(|e| png_err(path, e))
}

/// Maps a `png` error as [`image_err`] maps the image crate's.
fn png_err(path: &Path, e: png::DecodingError) -> Error {
    match e {
        png::DecodingError::IoError(io) if io.kind() == std::io::ErrorKind::UnexpectedEof => ends_early(path),
        png::DecodingError::IoError(io) => Error::io(path, io),
        other => Error::input(path, format!("cannot decode image: {other}")),
    }
}

/// An 8-bit, non-interlaced PNG mask (the usual ones, palette and low-bit
/// grey expanded to 8 bits as the image crate expands them) read a row at a
/// time, calling `f` per pixel as [`each_mask_value`] does: a region mask at
/// a large atlas's size is never held whole. `false`, having called `f` on
/// nothing, for the layouts it leaves to the whole-image path (16-bit or
/// interlaced).
fn each_png_mask_row(path: &Path, (width, height): (usize, usize), f: &mut impl FnMut(f32)) -> Result<bool> {
    let png_err = |e| png_err(path, e);
    let mut reader = png_rows(path)?;
    let (colour, depth) = reader.output_color_type();
    if depth != png::BitDepth::Eight || reader.info().interlaced {
        return Ok(false);
    }
    let (w, h) = (reader.info().width as usize, reader.info().height as usize);
    if (w, h) != (width, height) {
        return Err(decoded_size_differs(path, (w, h), (width, height)));
    }
    let (channels, colours) = match colour {
        png::ColorType::Grayscale => (1, 1),
        png::ColorType::GrayscaleAlpha => (2, 1),
        png::ColorType::Rgb => (3, 3),
        png::ColorType::Rgba => (4, 3),
        png::ColorType::Indexed => return Ok(false),
    };
    for _ in 0..h {
        let row = reader
            .next_row()
            .map_err(png_err)?
            .ok_or_else(|| ends_early(path))?;
        each_eight_bit_value(&row.data()[..w * channels], channels, colours, f);
    }
    Ok(true)
}

/// Calls `f` with the mask value of each pixel of `px` (8-bit, `channels`
/// interleaved): the image crate's float of its largest of the first
/// `colours` channels (alpha dropped).
fn each_eight_bit_value(px: &[u8], channels: usize, colours: usize, f: &mut impl FnMut(f32)) {
    let float = eight_bit_floats(channels);
    for p in px.chunks_exact(channels) {
        f(float[p[..colours].iter().copied().max().unwrap_or(0) as usize]);
    }
}

/// The image crate's float value of each 8-bit code in an image of
/// `channels` 8-bit channels (its `to_rgb32f`, which converts grey and
/// colour layouts differently in the last bit), so masks read from their
/// bytes equal those read through it.
fn eight_bit_floats(channels: usize) -> &'static [f32; 256] {
    static T: OnceLock<[[f32; 256]; 4]> = OnceLock::new();
    let tables = T.get_or_init(|| {
        let code = |x: u32| x as u8;
        let layouts = [
            DynamicImage::ImageLuma8(image::ImageBuffer::from_fn(256, 1, |x, _| image::Luma([code(x)]))),
            DynamicImage::ImageLumaA8(image::ImageBuffer::from_fn(256, 1, |x, _| {
                image::LumaA([code(x), 255])
            })),
            DynamicImage::ImageRgb8(image::ImageBuffer::from_fn(256, 1, |x, _| {
                image::Rgb([code(x); 3])
            })),
            DynamicImage::ImageRgba8(image::ImageBuffer::from_fn(256, 1, |x, _| {
                let c = code(x);
                image::Rgba([c, c, c, 255])
            })),
        ];
        layouts.map(|img| {
            let rgb = img.to_rgb32f().into_raw();
            std::array::from_fn(|k| rgb[3 * k])
        })
    });
    &tables[channels - 1]
}

/// Per pixel of linear RGB, its largest channel within [0, 1].
fn largest_channel(rgb: &[f32]) -> Vec<f32> {
    rgb.chunks_exact(3)
        .map(|p| p.iter().fold(0f32, |a, &b| a.max(b)).clamp(0.0, 1.0))
        .collect()
}

fn decoded_size_differs(path: &Path, (w, h): (usize, usize), (width, height): (usize, usize)) -> Error {
    Error::input(
        path,
        format!("decoded size {w}×{h} differs from its header {width}×{height}"),
    )
}

/// dropped; a grey image or a single-channel EXR is replicated into R, G, B.
///
/// The decoded image is held to [`DEFAULT_DECODE_BYTES`]; see
/// [`read_rgb_within`] to pass a memory budget instead.
pub fn read_rgb(path: &Path) -> Result<RgbImage> {
    read_rgb_within(path, DEFAULT_DECODE_BYTES)
}

/// [`read_rgb`] with the decoded linear RGB held to `max_bytes` (e.g. the
/// command's memory budget): the size the header declares is checked against
/// it, and against [`MAX_IMAGE_SIDE`], before anything is decoded.
pub fn read_rgb_within(path: &Path, max_bytes: u64) -> Result<RgbImage> {
    let kind = kind_of(path)?;
    let (w, h) = declared_size(path, kind)?;
    check_declared(path, w, h, max_bytes)?;
    match kind {
        Kind::Exr => read_exr_rgb(path, max_bytes),
        Kind::Raster(format) => {
            let img = decode_raster(path, format, max_bytes)?;
            let (width, height) = (img.width() as usize, img.height() as usize);
            let data: Vec<f32> = if is_float(&img) {
                img.to_rgb32f().into_raw()
            } else if is_8bit(&img) {
                let t = srgb8_table();
                img.to_rgb8()
                    .into_raw()
                    .into_iter()
                    .map(|v| t[v as usize])
                    .collect()
            } else {
                let t = srgb16_table();
                img.to_rgb16()
                    .into_raw()
                    .into_iter()
                    .map(|v| t[v as usize])
                    .collect()
            };
            Ok(RgbImage { width, height, data })
        }
    }
}

/// The size an image declares, checked as [`read_rgb_within`] checks it
/// but for the budget.
pub fn declared_rgb_size(path: &Path) -> Result<(usize, usize)> {
    let (w, h) = declared_size(path, kind_of(path)?)?;
    check_declared(path, w, h, u64::MAX)?;
    Ok((w, h))
}

/// [`read_rgb_within`] a band of `band` rows at a time: `f(y0, rgb)` gets
/// rows `y0..` (fewer at the bottom), linear RGB, in order, the same values.
/// An 8- or 16-bit non-interlaced PNG is decoded a row at a time and never
/// held whole; other images are decoded whole. Either way an image whose
/// decoded size exceeds `max_bytes` is refused, as [`read_rgb_within`]
/// refuses it (a colour sample is held whole by the stages that quilt
/// with it, and a small file declaring a huge image is a bomb). Returns
/// the size.
pub fn each_rgb_band(
    path: &Path,
    max_bytes: u64,
    band: usize,
    mut f: impl FnMut(usize, &[f32]) -> Result<()>,
) -> Result<(usize, usize)> {
    let band = band.max(1);
    let kind = kind_of(path)?;
    let (w, h) = declared_size(path, kind)?;
    check_declared(path, w, h, max_bytes)?;
    if kind == Kind::Raster(ImageFormat::Png) && each_png_rgb_band(path, (w, h), band, &mut f)? {
        return Ok((w, h));
    }
    let img = read_rgb_within(path, max_bytes)?;
    for (i, rows) in img.data.chunks(band * img.width * 3).enumerate() {
        f(i * band, rows)?;
    }
    Ok((img.width, img.height))
}

/// The PNG part of [`each_rgb_band`]: `false`, having called `f` on
/// nothing, for the layouts it leaves to the whole-image path (interlaced,
/// or a colour type it does not expand to grey or RGB). The codes map as
/// the image crate's `to_rgb8` and `to_rgb16` map them (grey to all three
/// channels, alpha dropped), through the same tables.
fn each_png_rgb_band(
    path: &Path,
    (width, height): (usize, usize),
    band: usize,
    f: &mut impl FnMut(usize, &[f32]) -> Result<()>,
) -> Result<bool> {
    let png_err = |e| png_err(path, e);
    let mut reader = png_rows(path)?;
    let (colour, depth) = reader.output_color_type();
    let bytes = match depth {
        png::BitDepth::Eight => 1,
        png::BitDepth::Sixteen => 2,
        _ => return Ok(false),
    };
    if reader.info().interlaced {
        return Ok(false);
    }
    let (w, h) = (reader.info().width as usize, reader.info().height as usize);
    if (w, h) != (width, height) {
        return Err(decoded_size_differs(path, (w, h), (width, height)));
    }
    let channels = match colour {
        png::ColorType::Grayscale => 1,
        png::ColorType::GrayscaleAlpha => 2,
        png::ColorType::Rgb => 3,
        png::ColorType::Rgba => 4,
        png::ColorType::Indexed => return Ok(false),
    };
    let (t8, t16) = (srgb8_table(), srgb16_table());
    let mut rgb = Vec::with_capacity(band.min(h) * w * 3);
    for y in 0..h {
        let row = reader
            .next_row()
            .map_err(png_err)?
            .ok_or_else(|| ends_early(path))?;
        for p in row.data()[..w * channels * bytes].chunks_exact(channels * bytes) {
            for c in 0..3 {
                // grey (with or without alpha) to all three channels
                let at = if channels < 3 { 0 } else { c } * bytes;
                rgb.push(match bytes {
                    1 => t8[p[at] as usize],
                    _ => t16[u16::from_be_bytes([p[at], p[at + 1]]) as usize],
                });
            }
        }
        if (y + 1) % band == 0 || y + 1 == h {
            f(y + 1 - rgb.len() / (w * 3), &rgb)?;
            rgb.clear();
        }
    }
    Ok(true)
}

/// Reads the first valid layer of an EXR with all its channels.
/// Before reading, every layer's declared samples (all its channels, as
/// stored) are held to `max_bytes`, as the whole layer is decoded at once.
fn read_exr_layer(path: &Path, max_bytes: u64) -> Result<x::Layer<x::AnyChannels<x::FlatSamples>>> {
    for header in &exr_meta(path)?.headers {
        let (w, h) = (header.layer_size.width(), header.layer_size.height());
        check_declared(path, w, h, max_bytes)?;
        let per_pixel: u128 = header
            .channels
            .list
            .iter()
            .map(|c| c.sample_type.bytes_per_sample() as u128)
            .sum();
        let stored = w as u128 * h as u128 * per_pixel;
        if stored > max_bytes as u128 {
            return Err(Error::input(
                path,
                format!(
                    "OpenEXR layer of {w}×{h} pixels and {} channels would need {} decoded, over the memory budget of {} (see --memory)",
                    header.channels.list.len(),
                    human_bytes(stored),
                    human_bytes(max_bytes as u128)
                ),
            ));
        }
    }
    let image = x::read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .first_valid_layer()
        .all_attributes()
        .from_buffered(open(path)?)
        .map_err(|e| exr_err(path, e))?;
    Ok(image.layer_data)
}

/// Finds a channel by name: exact (case-insensitive) or as the unique `layer.NAME`.
fn find_channel<'a>(channels: &'a [x::AnyChannel<x::FlatSamples>], name: &str) -> Option<&'a x::FlatSamples> {
    let exact = channels
        .iter()
        .find(|c| c.name.to_string().eq_ignore_ascii_case(name));
    if let Some(c) = exact {
        return Some(&c.sample_data);
    }
    let suffix = format!(".{}", name.to_ascii_lowercase());
    let mut hits = channels
        .iter()
        .filter(|c| c.name.to_string().to_ascii_lowercase().ends_with(&suffix));
    match (hits.next(), hits.next()) {
        (Some(c), None) => Some(&c.sample_data),
        _ => None,
    }
}

/// Reads R,G,B (or a single grey/Y channel) from an EXR as linear f32.
fn read_exr_rgb(path: &Path, max_bytes: u64) -> Result<RgbImage> {
    let layer = read_exr_layer(path, max_bytes)?;
    let (width, height) = (layer.size.width(), layer.size.height());
    let n = sample_count(path, width, height, 1)?;
    let list = &layer.channel_data.list;
    let names = || {
        list.iter()
            .map(|c| c.name.to_string())
            .collect::<Vec<_>>()
            .join(", ")
    };
    let rgb = ["R", "G", "B"].map(|c| find_channel(list, c));
    let sources: [&x::FlatSamples; 3] = match rgb {
        [Some(r), Some(g), Some(b)] => [r, g, b],
        [None, None, None] => {
            let named = |n: &str| {
                list.iter()
                    .find(|c| c.name.to_string().eq_ignore_ascii_case(n))
                    .map(|c| &c.sample_data)
            };
            let grey = named("Y")
                .or_else(|| named("grey"))
                .or_else(|| named("gray"))
                .or_else(|| (list.len() == 1).then(|| &list[0].sample_data));
            match grey {
                Some(y) => [y, y, y],
                None => {
                    return Err(Error::input(
                        path,
                        format!(
                            "OpenEXR has no R,G,B or single grey channel (channels: {})",
                            names()
                        ),
                    ))
                }
            }
        }
        _ => {
            return Err(Error::input(
                path,
                format!("OpenEXR lacks one of the R,G,B channels (channels: {})", names()),
            ))
        }
    };
    if sources.iter().any(|s| s.len() != n) {
        return Err(Error::input(
            path,
            "OpenEXR channel is subsampled or has the wrong number of samples",
        ));
    }
    let planes: Vec<Vec<f32>> = sources
        .iter()
        .map(|s| match s {
            x::FlatSamples::F32(v) => v.clone(),
            other => other.values_as_f32().collect(),
        })
        .collect();
    let mut data = Vec::with_capacity(n * 3);
    for ((r, g), b) in planes[0].iter().zip(&planes[1]).zip(&planes[2]) {
        data.extend_from_slice(&[*r, *g, *b]);
    }
    Ok(RgbImage { width, height, data })
}

/// Only the size, from the header (no pixels are decoded). A size no read
/// would accept (a side over [`MAX_IMAGE_SIDE`], more than
/// [`DEFAULT_DECODE_BYTES`] decoded, empty) is refused here already.
pub fn image_size(path: &Path) -> Result<(usize, usize)> {
    let (w, h) = declared_size(path, kind_of(path)?)?;
    check_declared(path, w, h, DEFAULT_DECODE_BYTES)?;
    Ok((w, h))
}

/// The sRGB decoding function (IEC 61966-2-1): encoded value -> linear.
pub fn srgb_to_linear(v: f32) -> f32 {
    let v = f64::from(v);
    let l = if v <= 0.04045 {
        v / 12.92
    } else {
        math::powf((v + 0.055) / 1.055, 2.4)
    };
    l as f32
}

/// The sRGB encoding function (IEC 61966-2-1): linear -> encoded value.
pub fn linear_to_srgb(v: f32) -> f32 {
    let v = f64::from(v);
    let s = if v <= 0.0031308 {
        v * 12.92
    } else {
        1.055 * math::powf(v, 1.0 / 2.4) - 0.055
    };
    s as f32
}

/// The mean luminance (Rec. 709 weights) of one row of RGB values.
pub fn row_luminance(row: &[f32]) -> f64 {
    let n = (row.len() / 3).max(1);
    row.chunks_exact(3)
        .map(|c| 0.2126 * c[0] as f64 + 0.7152 * c[1] as f64 + 0.0722 * c[2] as f64)
        .sum::<f64>()
        / n as f64
}

#[cfg(test)]
mod tests;
