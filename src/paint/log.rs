//! The paint log: each stroke and verbatim copy recorded as JSON lines,
//! so a painted surface can be replayed onto its base quilt.

use super::*;

/// A stroke in the paint log's JSON. The fields are written in this order;
/// `sample` is absent from logs written before strokes recorded it.
#[derive(serde::Serialize, serde::Deserialize)]
pub(super) struct StrokeRecord {
    #[serde(default)]
    pub(super) sample: Option<String>,
    pub(super) sample_mask: String,
    #[serde(default)]
    pub(super) region: Option<String>,
    #[serde(default)]
    pub(super) verbatim: Option<VerbatimRecord>,
    pub(super) transition: usize,
    pub(super) seed: u64,
    #[serde(default)]
    pub(super) patch_radius: Option<usize>,
    pub(super) seam_threshold: f64,
    pub(super) constraint_weight: f64,
    /// Mesh units the sample's width spans; absent: one pixel per texel.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub(super) sample_width: Option<f64>,
    /// Mesh units one sample pixel spans (instead of `sample_width`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub(super) sample_pixel: Option<f64>,
    /// The stroke's courses were locked to the surface's stripe pattern;
    /// absent: free.
    #[serde(default, skip_serializing_if = "std::ops::Not::not")]
    pub(super) locked_courses: bool,
}

/// A verbatim copy in the paint log's JSON.
#[derive(serde::Serialize, serde::Deserialize)]
pub(super) struct VerbatimRecord {
    pub(super) at: [f32; 3],
    pub(super) angle: f64,
}

/// The paint log's JSON: its base, the base's content hash (16 hex digits)
/// and the strokes.
#[derive(serde::Serialize, serde::Deserialize)]
struct LogRecord {
    pub(super) base: String,
    pub(super) base_hash: String,
    pub(super) strokes: Vec<StrokeRecord>,
}

/// The paint log's JSON layout, as logs have always been written (they are
/// stored in `.quilt` files and replayed): `", "` and `": "` between items,
/// numbers as Rust prints them (`3`, not `3.0`), and control characters
/// other than a line feed as `\u00XX`.
struct LogFormatter;

impl serde_json::ser::Formatter for LogFormatter {
    fn begin_array_value<W: ?Sized + std::io::Write>(
        &mut self,
        w: &mut W,
        first: bool,
    ) -> std::io::Result<()> {
        if first {
            Ok(())
        } else {
            w.write_all(b", ")
        }
    }

    fn begin_object_key<W: ?Sized + std::io::Write>(
        &mut self,
        w: &mut W,
        first: bool,
    ) -> std::io::Result<()> {
        self.begin_array_value(w, first)
    }

    fn begin_object_value<W: ?Sized + std::io::Write>(&mut self, w: &mut W) -> std::io::Result<()> {
        w.write_all(b": ")
    }

    fn write_f32<W: ?Sized + std::io::Write>(&mut self, w: &mut W, v: f32) -> std::io::Result<()> {
        write!(w, "{v}")
    }

    fn write_f64<W: ?Sized + std::io::Write>(&mut self, w: &mut W, v: f64) -> std::io::Result<()> {
        write!(w, "{v}")
    }

    fn write_char_escape<W: ?Sized + std::io::Write>(
        &mut self,
        w: &mut W,
        escape: serde_json::ser::CharEscape,
    ) -> std::io::Result<()> {
        use serde_json::ser::CharEscape as E;
        match escape {
            E::Quote => w.write_all(b"\\\""),
            E::ReverseSolidus => w.write_all(b"\\\\"),
            E::Solidus => w.write_all(b"/"),
            E::LineFeed => w.write_all(b"\\n"),
            E::Backspace => write!(w, "\\u{:04x}", 0x08),
            E::FormFeed => write!(w, "\\u{:04x}", 0x0c),
            E::CarriageReturn => write!(w, "\\u{:04x}", 0x0d),
            E::Tab => write!(w, "\\u{:04x}", 0x09),
            E::AsciiControl(c) => write!(w, "\\u{c:04x}"),
        }
    }
}

impl PaintLog {
    /// The log with every path it records made relative to the folder of
    /// the quilt `out` that will store it, so a painted surface and its
    /// inputs can move together and be replayed from any working directory.
    pub(super) fn relative_to(&self, out: &Path) -> PaintLog {
        let rel = |p: &Path| PathBuf::from(crate::io::staging::relative_to_folder_of(out, p));
        PaintLog {
            base: rel(&self.base),
            base_hash: self.base_hash,
            strokes: self
                .strokes
                .iter()
                .map(|s| Stroke {
                    sample: rel(&s.sample),
                    sample_mask: rel(&s.sample_mask),
                    region: s.region.as_deref().map(rel),
                    ..s.clone()
                })
                .collect(),
        }
    }

    /// The log read from the quilt `file`, its paths resolved against that
    /// quilt's folder.
    pub(super) fn resolved_in(self, file: &Path) -> PaintLog {
        let abs = |p: &Path| crate::io::staging::resolve_in_folder_of(file, p);
        PaintLog {
            base: abs(&self.base),
            base_hash: self.base_hash,
            strokes: self
                .strokes
                .into_iter()
                .map(|s| Stroke {
                    sample: abs(&s.sample),
                    sample_mask: abs(&s.sample_mask),
                    region: s.region.as_deref().map(abs),
                    ..s
                })
                .collect(),
        }
    }
}

/// The paint log stored in a painted quilt: its base and its strokes.
#[derive(Clone, Debug)]
pub(super) struct PaintLog {
    pub(super) base: PathBuf,
    pub(super) base_hash: u64,
    pub(super) strokes: Vec<Stroke>,
}

impl PaintLog {
    pub(super) fn to_json(&self) -> Result<String> {
        let record = LogRecord {
            base: self.base.display().to_string(),
            base_hash: format!("{:016x}", self.base_hash),
            strokes: self.strokes.iter().map(Stroke::to_record).collect(),
        };
        let mut out = Vec::new();
        let mut ser = serde_json::Serializer::with_formatter(&mut out, LogFormatter);
        serde::Serialize::serialize(&record, &mut ser)
            .map_err(|e| Error::Config(format!("cannot write the paint log: {e}")))?;
        String::from_utf8(out).map_err(|e| Error::Config(format!("cannot write the paint log: {e}")))
    }

    pub(super) fn parse(text: &str, file: &Path, base_sample: &Path) -> Result<PaintLog> {
        let bad = |why: String| Error::input(file, format!("has a malformed paint log: {why}"));
        let record: LogRecord = serde_json::from_str(text).map_err(|e| bad(e.to_string()))?;
        let base_hash = u64::from_str_radix(&record.base_hash, 16)
            .map_err(|e| bad(format!("base_hash \"{}\": {e}", record.base_hash)))?;
        Ok(PaintLog {
            base: PathBuf::from(record.base),
            base_hash,
            strokes: record
                .strokes
                .into_iter()
                .map(|s| Stroke::from_record(s, base_sample))
                .collect(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_paint_log_keeps_its_text_and_reads_back() {
        let stroke = |region: Option<&str>, verbatim| Stroke {
            sample: PathBuf::from("dir/s.png"),
            sample_mask: PathBuf::from("m \"q\"\\\ttab\nline.png"),
            region: region.map(PathBuf::from),
            verbatim,
            transition: 8,
            free_unless_fit: false,
            tile: Stroke::tiling(&TileConfig {
                seed: u64::MAX,
                patch_radius: Some(5),
                seam_threshold: 3.0,
                constraint_weight: 0.1,
                ..TileConfig::default()
            }),
        };
        let log = PaintLog {
            base: PathBuf::from("q.quilt"),
            base_hash: 0xa2c2_693c_3c2e_8b45,
            strokes: vec![
                stroke(Some("st.json"), None),
                stroke(
                    None,
                    Some(Verbatim {
                        at: [0.3, -0.6, 0.0],
                        angle: 12.5,
                    }),
                ),
            ],
        };
        let text = log.to_json().unwrap();
        // the text logs have always had: ", " and ": ", numbers as Rust
        // prints them, control characters but the line feed as \u00XX
        let s1 = "{\"sample\": \"dir/s.png\", \"sample_mask\": \"m \\\"q\\\"\\\\\\u0009tab\\nline.png\", ";
        let tail = "\"transition\": 8, \"seed\": 18446744073709551615, \"patch_radius\": 5, \"seam_threshold\": 3, \"constraint_weight\": 0.1}";
        let want = format!(
            "{{\"base\": \"q.quilt\", \"base_hash\": \"a2c2693c3c2e8b45\", \"strokes\": [\
             {s1}\"region\": \"st.json\", \"verbatim\": null, {tail}, \
             {s1}\"region\": null, \"verbatim\": {{\"at\": [0.3, -0.6, 0], \"angle\": 12.5}}, {tail}]}}"
        );
        assert_eq!(text, want);
        let back = PaintLog::parse(&text, Path::new("p.quilt"), Path::new("base.png")).unwrap();
        assert_eq!(back.to_json().unwrap(), text);
        assert_eq!(back.base_hash, log.base_hash);
        assert_eq!(back.strokes[1].verbatim, log.strokes[1].verbatim);
        // free courses are not written (the text above); locked are, and
        // read back
        let mut locked = log.clone();
        locked.strokes[0].tile.courses = CourseMode::Locked;
        let text = locked.to_json().unwrap();
        assert!(
            text.contains("\"constraint_weight\": 0.1, \"locked_courses\": true}, {"),
            "{text}"
        );
        let back = PaintLog::parse(&text, Path::new("p.quilt"), Path::new("base.png")).unwrap();
        let modes: Vec<CourseMode> = back.strokes.iter().map(|s| s.tile.courses).collect();
        assert_eq!(modes, [CourseMode::Locked, CourseMode::Free]);
        // a log without a stroke's sample (older logs) reads the base's
        let old = text.replacen("\"sample\": \"dir/s.png\", ", "", 1);
        let back = PaintLog::parse(&old, Path::new("p.quilt"), Path::new("base.png")).unwrap();
        assert_eq!(back.strokes[0].sample, PathBuf::from("base.png"));
        // malformed: named, with the position
        let e = PaintLog::parse("{\"base\": 1}", Path::new("p.quilt"), Path::new("b.png"))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("p.quilt") && e.contains("malformed paint log") && e.contains("column"),
            "{e}"
        );
    }
}
