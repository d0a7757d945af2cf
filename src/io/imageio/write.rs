//! Writing images: PNG (8/16-bit sRGB, whole or in bands), masks, EXR
//! (half or float, any channels) and staged writes renamed into place.

use super::*;

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
pub(super) fn encode_srgb(v: f32, max: f32) -> f32 {
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
