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

use crate::{Error, Result};

/// A linear-light RGB image, row-major, 3 f32 per pixel.
#[derive(Clone, Debug, PartialEq)]
pub struct RgbImage {
    pub width: usize,
    pub height: usize,
    pub data: Vec<f32>,
}

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

/// Maps an `image` error: I/O stays I/O, everything else is bad input.
fn image_err(path: &Path, e: image::ImageError) -> Error {
    match e {
        image::ImageError::IoError(io) => Error::io(path, io),
        other => Error::input(path, format!("cannot decode image: {other}")),
    }
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
            let img = decode_raster(path, format, DEFAULT_DECODE_BYTES)?;
            (
                img.width() as usize,
                img.height() as usize,
                img.to_rgb32f().into_raw(),
            )
        }
    };
    if (w, h) != (width, height) {
        return Err(Error::input(
            path,
            format!("decoded size {w}×{h} differs from its header {width}×{height}"),
        ));
    }
    Ok(rgb
        .chunks_exact(3)
        .map(|p| p.iter().fold(0f32, |a, &b| a.max(b)).clamp(0.0, 1.0))
        .collect())
}

/// Read PNG (8/16-bit, grey/grey-alpha/RGB/RGBA), JPEG, TIFF, or OpenEXR into linear RGB.
///
/// PNG/JPEG/TIFF are decoded from sRGB with the exact transfer function
/// (a float TIFF is taken as already linear); EXR is read as is. Alpha is
/// Bilinear lookup in an RGB image at pixel coordinates (clamped).
pub fn bilinear(img: &RgbImage, x: f32, y: f32) -> [f32; 3] {
    let w = img.width;
    bilinear_with(img.width, img.height, x, y, |x, y| {
        let p = &img.data[(y * w + x) * 3..(y * w + x) * 3 + 3];
        [p[0], p[1], p[2]]
    })
}

/// [`bilinear`] over a `w`×`h` image whose pixel `(x, y)` is `px(x, y)`.
pub fn bilinear_with(
    w: usize,
    h: usize,
    x: f32,
    y: f32,
    mut px: impl FnMut(usize, usize) -> [f32; 3],
) -> [f32; 3] {
    let x = x.clamp(0.0, (w - 1) as f32);
    let y = y.clamp(0.0, (h - 1) as f32);
    let (x0, y0) = (x.floor() as usize, y.floor() as usize);
    let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
    let (fx, fy) = (x - x0 as f32, y - y0 as f32);
    let (p00, p10, p01, p11) = (px(x0, y0), px(x1, y0), px(x0, y1), px(x1, y1));
    let mut out = [0f32; 3];
    for c in 0..3 {
        let top = p00[c] + (p10[c] - p00[c]) * fx;
        let bottom = p01[c] + (p11[c] - p01[c]) * fx;
        out[c] = top + (bottom - top) * fy;
    }
    out
}

/// Per output pixel of a 1-D resampling from `n` to `m` pixels: the source
/// pixels and their weights (summing to 1). Shrinking averages each output
/// pixel's footprint (a box filter, so no aliasing); enlarging interpolates
/// linearly between pixel centres.
fn resample_weights(n: usize, m: usize) -> Vec<Vec<(usize, f32)>> {
    let s = n as f64 / m as f64;
    (0..m)
        .map(|o| {
            if s > 1.0 {
                let (a, b) = (o as f64 * s, (o as f64 + 1.0) * s);
                let mut w = Vec::new();
                let mut i = a.floor() as usize;
                while (i as f64) < b && i < n {
                    let cover = (b.min(i as f64 + 1.0) - a.max(i as f64)) / s;
                    if cover > 0.0 {
                        w.push((i, cover as f32));
                    }
                    i += 1;
                }
                w
            } else {
                let x = ((o as f64 + 0.5) * s - 0.5).clamp(0.0, (n - 1) as f64);
                let i = x.floor() as usize;
                let f = (x - i as f64) as f32;
                if f > 0.0 && i + 1 < n {
                    vec![(i, 1.0 - f), (i + 1, f)]
                } else {
                    vec![(i, 1.0)]
                }
            }
        })
        .collect()
}

/// Resamples row-major `channels`-channel maps of `width`×`height` pixels to
/// `to_width`×`to_height` (separable: a box filter where it shrinks, linear
/// where it enlarges). Used to bring a sample to the atlas's texel density.
pub fn resample(
    maps: &[f32],
    width: usize,
    height: usize,
    channels: usize,
    to_width: usize,
    to_height: usize,
) -> Vec<f32> {
    let (wx, wy) = (
        resample_weights(width, to_width),
        resample_weights(height, to_height),
    );
    let mut rows = vec![0f32; height * to_width * channels];
    for y in 0..height {
        for (x, taps) in wx.iter().enumerate() {
            let out = &mut rows[(y * to_width + x) * channels..(y * to_width + x + 1) * channels];
            for &(i, w) in taps {
                let src = &maps[(y * width + i) * channels..(y * width + i + 1) * channels];
                for (o, v) in out.iter_mut().zip(src) {
                    *o += w * v;
                }
            }
        }
    }
    let mut out = vec![0f32; to_height * to_width * channels];
    for (y, taps) in wy.iter().enumerate() {
        let dst = &mut out[y * to_width * channels..(y + 1) * to_width * channels];
        for &(i, w) in taps {
            let src = &rows[i * to_width * channels..(i + 1) * to_width * channels];
            for (o, v) in dst.iter_mut().zip(src) {
                *o += w * v;
            }
        }
    }
    out
}

/// A foreground mask value at sample coordinates `c` (pixel indices, `[y][x]`
/// storage), bilinear between pixel centres. A tileable sample wraps round
/// its borders; any other reads 0 outside `[0, width − 1] × [0, height − 1]`.
/// The one mask lookup of the synthesis and of `evaluate`'s painting
/// measures, so both count the same texels as foreground.
pub fn mask_bilinear(values: &[f32], width: usize, height: usize, c: [f64; 2], tileable: bool) -> f32 {
    let (w, h) = (width, height);
    if w == 0 || h == 0 || values.len() < w * h {
        return 0.0;
    }
    let (mut x, mut y) = (c[0], c[1]);
    if !(x.is_finite() && y.is_finite()) {
        return 0.0;
    }
    if tileable {
        x = x.rem_euclid(w as f64);
        y = y.rem_euclid(h as f64);
    } else if !(x >= 0.0 && y >= 0.0 && x <= (w - 1) as f64 && y <= (h - 1) as f64) {
        return 0.0;
    }
    let (x0, y0) = ((x.floor() as usize).min(w - 1), (y.floor() as usize).min(h - 1));
    let (x1, y1) = if tileable {
        ((x0 + 1) % w, (y0 + 1) % h)
    } else {
        ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1))
    };
    let (fx, fy) = ((x - x0 as f64) as f32, (y - y0 as f64) as f32);
    let top = values[y0 * w + x0] + (values[y0 * w + x1] - values[y0 * w + x0]) * fx;
    let bottom = values[y1 * w + x0] + (values[y1 * w + x1] - values[y1 * w + x0]) * fx;
    top + (bottom - top) * fy
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

/// Checks dimensions and buffer length before writing.
fn check_write(path: &Path, width: usize, height: usize, channels: usize, len: usize) -> Result<()> {
    if width == 0 || height == 0 {
        return Err(Error::input(
            path,
            format!("cannot write an empty {width}x{height} image"),
        ));
    }
    let n = sample_count(path, width, height, channels)?;
    if len != n {
        return Err(Error::input(
            path,
            format!("image buffer has {len} values, {width}x{height}x{channels} expected"),
        ));
    }
    Ok(())
}

/// Image dimensions as u32 for the `image` encoders.
fn dims_u32(path: &Path, width: usize, height: usize) -> Result<(u32, u32)> {
    match (u32::try_from(width), u32::try_from(height)) {
        (Ok(w), Ok(h)) => Ok((w, h)),
        _ => Err(Error::input(
            path,
            format!("image size {width}x{height} is too large for PNG"),
        )),
    }
}

/// Linear value to a clamped, rounded sRGB code value in 0..=max.
fn encode_srgb(v: f32, max: f32) -> f32 {
    let s = linear_to_srgb(v);
    let s = if s.is_nan() { 0.0 } else { s.clamp(0.0, 1.0) };
    (s * max).round()
}

/// [`encode_srgb`] to 8 bits, exactly, without a power per value: the
/// code is the number of the 255 thresholds (the least f32 giving each code
/// 1..=255, found once by bisection over the ordered bit patterns of the
/// positive floats) that `v` reaches.
pub fn linear_to_srgb8(v: f32) -> u8 {
    static THRESHOLDS: std::sync::OnceLock<Vec<f32>> = std::sync::OnceLock::new();
    let t = THRESHOLDS.get_or_init(|| {
        (1..=255u32)
            .map(|k| {
                // least bits with code ≥ k among the finite positive floats
                let (mut lo, mut hi) = (0u32, f32::MAX.to_bits());
                while lo < hi {
                    let mid = lo + (hi - lo) / 2;
                    if encode_srgb(f32::from_bits(mid), 255.0) as u32 >= k {
                        hi = mid;
                    } else {
                        lo = mid + 1;
                    }
                }
                f32::from_bits(lo)
            })
            .collect()
    });
    t.partition_point(|&x| x <= v) as u8
}

/// Write PNG: linear -> sRGB encode, clamp to 0..1, round to nearest, 8 or 16 bit RGB.
pub fn write_png(path: &Path, img: &RgbImage, depth: PngDepth) -> Result<()> {
    check_write(path, img.width, img.height, 3, img.data.len())?;
    let (w, h) = dims_u32(path, img.width, img.height)?;
    match depth {
        PngDepth::Eight => {
            let raw: Vec<u8> = img.data.iter().map(|&v| linear_to_srgb8(v)).collect();
            let buf = image::ImageBuffer::<image::Rgb<u8>, _>::from_raw(w, h, raw)
                .ok_or_else(|| Error::input(path, "image buffer size mismatch"))?;
            write_atomic(path, |out| {
                buf.write_with_encoder(image::codecs::png::PngEncoder::new(out))
                    .map_err(|e| image_err(path, e))
            })
        }
        PngDepth::Sixteen => {
            let raw: Vec<u16> = img.data.iter().map(|&v| encode_srgb(v, 65535.0) as u16).collect();
            let buf = image::ImageBuffer::<image::Rgb<u16>, _>::from_raw(w, h, raw)
                .ok_or_else(|| Error::input(path, "image buffer size mismatch"))?;
            write_atomic(path, |out| {
                buf.write_with_encoder(image::codecs::png::PngEncoder::new(out))
                    .map_err(|e| image_err(path, e))
            })
        }
    }
}

/// Writes an 8-bit RGB PNG band by band, encoded as [`write_png`] encodes:
/// `next` returns the following rows of linear RGB (whole rows, `width * 3`
/// values each) until `height` rows are written, so only one band is held at
/// a time. Staged like every output.
pub fn write_png_bands<F>(path: &Path, width: usize, height: usize, mut next: F) -> Result<()>
where
    F: FnMut() -> Result<Vec<f32>>,
{
    check_write(path, width, height, 3, width * height * 3)?;
    let (w, h) = dims_u32(path, width, height)?;
    let png_err = |e: png::EncodingError| Error::input(path, format!("cannot encode PNG: {e}"));
    write_atomic(path, |out| {
        let mut encoder = png::Encoder::new(out, w, h);
        encoder.set_color(png::ColorType::Rgb);
        encoder.set_depth(png::BitDepth::Eight);
        encoder.set_compression(png::Compression::Balanced);
        encoder.set_filter(png::Filter::Adaptive);
        let mut writer = encoder.write_header().map_err(png_err)?;
        let mut stream = writer.stream_writer().map_err(png_err)?;
        let mut rows = 0;
        while rows < height {
            let band = next()?;
            if band.is_empty() || band.len() % (width * 3) != 0 || rows + band.len() / (width * 3) > height {
                return Err(Error::Config(format!(
                    "{}: a band of {} values for rows of {width} RGB pixels from row {rows} of {height}",
                    path.display(),
                    band.len()
                )));
            }
            rows += band.len() / (width * 3);
            let bytes: Vec<u8> = band.iter().map(|&v| encode_srgb(v, 255.0) as u8).collect();
            stream.write_all(&bytes).map_err(|e| Error::io(path, e))?;
        }
        stream.finish().map_err(png_err)?;
        writer.finish().map_err(png_err)
    })
}

/// Write an 8-bit grey PNG from values 0..1 (clamped, rounded), no sRGB encoding.
pub fn write_mask_png(path: &Path, width: usize, height: usize, values: &[f32]) -> Result<()> {
    check_write(path, width, height, 1, values.len())?;
    let (w, h) = dims_u32(path, width, height)?;
    let raw: Vec<u8> = values
        .iter()
        .map(|&v| {
            let v = if v.is_nan() { 0.0 } else { v.clamp(0.0, 1.0) };
            (v * 255.0).round() as u8
        })
        .collect();
    let buf = image::ImageBuffer::<image::Luma<u8>, _>::from_raw(w, h, raw)
        .ok_or_else(|| Error::input(path, "image buffer size mismatch"))?;
    write_atomic(path, |out| {
        buf.write_with_encoder(image::codecs::png::PngEncoder::new(out))
            .map_err(|e| image_err(path, e))
    })
}

/// Write OpenEXR with R,G,B channels as f16 (`half`) or f32, linear, ZIP-compressed.
pub fn write_exr(path: &Path, img: &RgbImage, half: bool) -> Result<()> {
    check_write(path, img.width, img.height, 3, img.data.len())?;
    let channels: Vec<(String, Vec<f32>)> = ["R", "G", "B"]
        .iter()
        .enumerate()
        .map(|(c, name)| {
            let plane = img.data.iter().skip(c).step_by(3).copied().collect();
            (name.to_string(), plane)
        })
        .collect();
    write_exr_channels(path, img.width, img.height, &channels, half)
}

/// Write an OpenEXR with arbitrary named channels: `channels[i]` is (name, width*height values).
///
/// Channels are stored as f16 when `half` (values rounded to nearest), else f32.
pub fn write_exr_channels(
    path: &Path,
    width: usize,
    height: usize,
    channels: &[(String, Vec<f32>)],
    half: bool,
) -> Result<()> {
    if channels.is_empty() {
        return Err(Error::input(
            path,
            "cannot write an OpenEXR file without channels",
        ));
    }
    let mut list = x::SmallVec::<[x::AnyChannel<x::FlatSamples>; 4]>::new();
    for (i, (name, values)) in channels.iter().enumerate() {
        check_write(path, width, height, 1, values.len())?;
        if name.is_empty() || channels[..i].iter().any(|(n, _)| n == name) {
            return Err(Error::input(
                path,
                format!("OpenEXR channel name '{name}' is empty or repeated"),
            ));
        }
        let text = x::Text::new_or_none(name)
            .ok_or_else(|| Error::input(path, format!("OpenEXR channel name '{name}' is not Latin-1")))?;
        let samples = if half {
            x::FlatSamples::F16(values.iter().map(|&v| f16::from_f32(v)).collect())
        } else {
            x::FlatSamples::F32(values.clone())
        };
        list.push(x::AnyChannel::new(text, samples));
    }
    let layer = x::Layer::new(
        (width, height),
        x::LayerAttributes::default(),
        x::Encoding::SMALL_LOSSLESS,
        x::AnyChannels::sort(list),
    );
    let image = x::Image::from_layer(layer);
    write_atomic(path, |out| {
        image.write().to_buffered(out).map_err(|e| exr_err(path, e))
    })
}

/// Writes one layer of `channels` (`SpecificChannels`) to `path` as
/// [`write_exr`] does, staged; `failed` (a pixel function's first error)
/// is checked before the file is renamed into place.
macro_rules! write_exr_layer {
    ($path:expr, $width:expr, $height:expr, $channels:expr, $failed:expr) => {{
        let layer = x::Layer::new(
            ($width, $height),
            x::LayerAttributes::default(),
            x::Encoding::SMALL_LOSSLESS,
            $channels,
        );
        let image = x::Image::from_layer(layer);
        write_atomic($path, |out| {
            image.write().to_buffered(out).map_err(|e| exr_err($path, e))?;
            match crate::lock(&$failed).take() {
                Some(e) => Err(e),
                None => Ok(()),
            }
        })
    }};
}

/// f32 channels `names` whose pixel tuple is `at(position)`'s values, in order.
macro_rules! f32_channels {
    ($at:expr; $($name:ident : $i:tt),+) => {
        x::SpecificChannels::build()
            $(.with_channel::<f32>($name))+
            .with_pixel_fn(|p| {
                let v = $at(p);
                ($(v[$i]),+)
            })
    };
}

/// Writes a linear RGB OpenEXR (f16, ZIP-compressed, as [`write_exr`]) whose
/// pixel `(x, y)` is `pixel(x, y)`, asked for in any order and from several
/// threads, so the image never has to be held whole. The first error a pixel
/// returns ends the write with nothing at `path`. Staged like every output.
pub fn write_exr_rgb_fn<F>(path: &Path, width: usize, height: usize, pixel: F) -> Result<()>
where
    F: Fn(usize, usize) -> Result<[f32; 3]> + Sync,
{
    check_write(path, width, height, 3, width * height * 3)?;
    let failed = std::sync::Mutex::new(None::<Error>);
    let channels = x::SpecificChannels::rgb(|p: x::Vec2<usize>| {
        let [r, g, b] = pixel(p.0, p.1).unwrap_or_else(|e| {
            crate::lock(&failed).get_or_insert(e);
            [0.0; 3]
        });
        (f16::from_f32(r), f16::from_f32(g), f16::from_f32(b))
    });
    write_exr_layer!(path, width, height, channels, failed)
}

/// Writes an f32 OpenEXR (ZIP-compressed, as [`write_exr_channels`]) of the
/// 7 or 8 channels `names` whose values at `(x, y)` are `pixel(x, y)`, asked
/// for in any order and from several threads. The first error a pixel
/// returns ends the write with nothing at `path`. Staged like every output.
pub fn write_exr_f32_fn<const N: usize, F>(
    path: &Path,
    width: usize,
    height: usize,
    names: [&str; N],
    pixel: F,
) -> Result<()>
where
    F: Fn(usize, usize) -> Result<[f32; N]> + Sync,
{
    check_write(path, width, height, 1, width * height)?;
    let failed = std::sync::Mutex::new(None::<Error>);
    let at = |p: x::Vec2<usize>| {
        pixel(p.0, p.1).unwrap_or_else(|e| {
            crate::lock(&failed).get_or_insert(e);
            [f32::NAN; N]
        })
    };
    match names[..] {
        [a, b, c, d, e, f, g] => {
            let channels = f32_channels!(at; a: 0, b: 1, c: 2, d: 3, e: 4, f: 5, g: 6);
            write_exr_layer!(path, width, height, channels, failed)
        }
        [a, b, c, d, e, f, g, h] => {
            let channels = f32_channels!(at; a: 0, b: 1, c: 2, d: 3, e: 4, f: 5, g: 6, h: 7);
            write_exr_layer!(path, width, height, channels, failed)
        }
        _ => Err(Error::Config(format!(
            "{}: {N} OpenEXR channels from a pixel function (7 or 8 are written)",
            path.display()
        ))),
    }
}

/// Write by extension: .png (8-bit sRGB) or .exr (f16). Other extensions are an input error.
pub fn write_rgb(path: &Path, img: &RgbImage) -> Result<()> {
    match kind_of(path)? {
        Kind::Raster(ImageFormat::Png) => write_png(path, img, PngDepth::Eight),
        Kind::Exr => write_exr(path, img, true),
        _ => Err(Error::input(path, "can only write .png or .exr images")),
    }
}

/// Writes a file atomically: `write` fills a temporary file in the same
/// directory, which is flushed and renamed onto `path` only on success. On any
/// error the temporary file is removed and `path` is left untouched.
pub fn write_atomic<F>(path: &Path, write: F) -> Result<()>
where
    F: FnOnce(&mut BufWriter<&mut File>) -> Result<()>,
{
    if path.file_name().is_none() {
        return Err(Error::input(path, "not a file path"));
    }
    let mut tmp = crate::io::staging::staged_file(path)?;
    {
        let mut out = BufWriter::new(tmp.as_file_mut());
        write(&mut out)?;
        out.flush().map_err(|e| Error::io(path, e))?;
    }
    tmp.persist(path).map_err(|e| Error::io(path, e.error))?;
    Ok(())
}

/// The sRGB decoding function (IEC 61966-2-1): encoded value -> linear.
pub fn srgb_to_linear(v: f32) -> f32 {
    let v = f64::from(v);
    let l = if v <= 0.04045 {
        v / 12.92
    } else {
        ((v + 0.055) / 1.055).powf(2.4)
    };
    l as f32
}

/// The sRGB encoding function (IEC 61966-2-1): linear -> encoded value.
pub fn linear_to_srgb(v: f32) -> f32 {
    let v = f64::from(v);
    let s = if v <= 0.0031308 {
        v * 12.92
    } else {
        1.055 * v.powf(1.0 / 2.4) - 0.055
    };
    s as f32
}

/// Fills empty texels from their filled neighbours, ring by ring, so
/// mipmapping never blends in the background; what is still empty after
/// `passes` rings gets the mean colour of the covered texels.
pub fn dilate(img: &mut RgbImage, covered: &[bool], passes: usize) {
    let mut mean = CoveredMean::default();
    mean.add(&img.data, covered);
    dilate_with(img, covered, passes, mean.colour());
}

/// The mean colour of covered texels, summed in texel order (so a sum over
/// bands in order equals the sum over the whole image, bit for bit).
#[derive(Clone, Copy, Debug, Default)]
pub struct CoveredMean {
    sum: [f64; 3],
    n: usize,
}

impl CoveredMean {
    /// Adds the covered texels of RGB `data`.
    pub fn add(&mut self, data: &[f32], covered: &[bool]) {
        for (t, _) in covered.iter().enumerate().filter(|(_, &c)| c) {
            for k in 0..3 {
                self.sum[k] += data[t * 3 + k] as f64;
            }
            self.n += 1;
        }
    }

    /// The mean (0 when nothing is covered).
    pub fn colour(&self) -> [f32; 3] {
        self.sum.map(|s| (s / self.n.max(1) as f64) as f32)
    }
}

/// [`dilate`], with `fill` for what is still empty after `passes` rings.
pub fn dilate_with(img: &mut RgbImage, covered: &[bool], passes: usize, fill: [f32; 3]) {
    let (w, h) = (img.width, img.height);
    let mut filled = covered.to_vec();
    for _ in 0..passes {
        let mut next = filled.clone();
        let mut any = false;
        for y in 0..h {
            for x in 0..w {
                let t = y * w + x;
                if filled[t] {
                    continue;
                }
                let (mut s, mut c) = ([0f32; 3], 0);
                for (dx, dy) in [
                    (-1i32, 0i32),
                    (1, 0),
                    (0, -1),
                    (0, 1),
                    (-1, -1),
                    (1, -1),
                    (-1, 1),
                    (1, 1),
                ] {
                    let (nx, ny) = (x as i32 + dx, y as i32 + dy);
                    if nx < 0 || ny < 0 || nx >= w as i32 || ny >= h as i32 {
                        continue;
                    }
                    let n = ny as usize * w + nx as usize;
                    if filled[n] {
                        for k in 0..3 {
                            s[k] += img.data[n * 3 + k];
                        }
                        c += 1;
                    }
                }
                if c > 0 {
                    for k in 0..3 {
                        img.data[t * 3 + k] = s[k] / c as f32;
                    }
                    next[t] = true;
                    any = true;
                }
            }
        }
        filled = next;
        if !any {
            break;
        }
    }
    for t in 0..w * h {
        if !filled[t] {
            img.data[t * 3..t * 3 + 3].copy_from_slice(&fill);
        }
    }
}

#[cfg(test)]
mod tests {

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
}
