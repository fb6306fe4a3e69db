//! dlib imglab XML datasets (`training_with_face_landmarks.xml` style).
//!
//! ```text
//! <dataset>
//!   <name>...</name> <comment>...</comment>
//!   <images>
//!     <image file='2007_007763.jpg' [width='500' height='375']>
//!       <box top='90' left='194' width='37' height='37' [ignore='1']>
//!         [<label>face</label>]
//!         <part name='00' x='201' y='107'/> ... <part name='67' .../>
//!       </box>
//!     </image>
//!   </images>
//! </dataset>
//! ```
//!
//! Coordinates are 0-based pixels, as in memory; no conversion. A box maps to
//! [`Rect`] `{ left, top, width, height }` (dlib's inclusive `right = left + width - 1`).
//! Parts keep their names; [`DlibBox::landmarks68`] turns parts `00`..`67` into
//! [`Landmarks68`]. Unknown box/image attributes (`difficult`, `angle`, ...) are
//! ignored on read. dlib stores integers, so the writer rounds coordinates to the
//! nearest integer (data read from dlib files round-trips exactly). Non-ASCII text
//! in a file that is not UTF-8 is decoded as ISO-8859-1 (the encoding dlib declares).

use std::fmt::Write as _;
use std::path::Path;

use nalgebra::Point2;
use quick_xml::escape::escape;
use quick_xml::events::{BytesStart, Event};
use quick_xml::Reader;

use super::line_of;
use facecap_core::atomic::write_atomic;
use facecap_core::error::{Error, Result};
use facecap_core::landmarks::{Landmarks68, Rect, NUM_LANDMARKS};

const FORMAT: &str = "dlib XML";

/// A whole imglab dataset.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct DlibDataset {
    /// `<name>` text, if any.
    pub name: Option<String>,
    /// `<comment>` text, if any.
    pub comment: Option<String>,
    /// Images in file order.
    pub images: Vec<DlibImage>,
}

/// One `<image>`.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct DlibImage {
    /// The `file` attribute (relative to the XML file's folder).
    pub file: String,
    /// Optional `width` attribute.
    pub width: Option<u32>,
    /// Optional `height` attribute.
    pub height: Option<u32>,
    /// Face boxes in file order.
    pub boxes: Vec<DlibBox>,
}

impl DlibImage {
    /// The image's path: `file` resolved against the folder of the XML file it was
    /// read from (absolute `file`s are kept as they are).
    pub fn resolve_path(&self, xml_path: &Path) -> std::path::PathBuf {
        match xml_path.parent() {
            Some(dir) => dir.join(&self.file),
            None => std::path::PathBuf::from(&self.file),
        }
    }
}

/// One `<box>` with its parts.
#[derive(Debug, Clone, PartialEq)]
pub struct DlibBox {
    /// The box (0-based pixels).
    pub rect: Rect,
    /// `ignore='1'`.
    pub ignore: bool,
    /// `<label>` text, if any.
    pub label: Option<String>,
    /// `(name, 0-based point)` in file order.
    pub parts: Vec<(String, Point2<f64>)>,
}

impl DlibBox {
    /// The 68 landmarks from parts named `0`..`67` (any zero padding, any order);
    /// `None` when the box has no parts.
    ///
    /// # Errors
    /// [`Error::Parse`] when parts exist but are not exactly the 68 indices 0..67.
    pub fn landmarks68(&self) -> Result<Option<Landmarks68>> {
        if self.parts.is_empty() {
            return Ok(None);
        }
        let mut xy: [Option<(f64, f64)>; NUM_LANDMARKS] = [None; NUM_LANDMARKS];
        for (name, p) in &self.parts {
            let i: usize = name
                .parse()
                .ok()
                .filter(|&i| i < NUM_LANDMARKS)
                .ok_or_else(|| Error::parse(FORMAT, "", format!("part name {name:?} is not 00..67")))?;
            if xy[i].replace((p.x, p.y)).is_some() {
                return Err(Error::parse(FORMAT, "", format!("part {name:?} appears twice")));
            }
        }
        let pts: Vec<(f64, f64)> = xy
            .iter()
            .enumerate()
            .map(|(i, v)| v.ok_or_else(|| Error::parse(FORMAT, "", format!("part {i:02} missing"))))
            .collect::<Result<_>>()?;
        Landmarks68::from_slice(&pts).map(Some)
    }

    /// A box with the 68 landmarks as parts named `00`..`67`.
    pub fn with_landmarks(rect: Rect, landmarks: &Landmarks68) -> Self {
        DlibBox {
            rect,
            ignore: false,
            label: None,
            parts: landmarks
                .points
                .iter()
                .enumerate()
                .map(|(i, p)| (format!("{i:02}"), *p))
                .collect(),
        }
    }
}

/// Reads an imglab XML file.
///
/// # Errors
/// [`Error::Io`]; [`Error::Parse`] with the line for malformed XML, a `<box>`
/// outside an `<image>`, a `<part>` outside a `<box>`, missing or non-numeric
/// attributes, non-positive box sizes, unclosed elements (truncation).
pub fn read_dlib_xml(path: impl AsRef<Path>) -> Result<DlibDataset> {
    let path = path.as_ref();
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    let text = match std::str::from_utf8(&bytes) {
        Ok(t) => t.to_owned(),
        Err(_) => bytes.iter().map(|&b| char::from(b)).collect(), // ISO-8859-1
    };
    parse_dlib_xml(&text).map_err(|e| e.at_path(path))
}

fn attr_map(text: &str, pos: usize, e: &BytesStart) -> Result<Vec<(String, String)>> {
    let mut out = Vec::new();
    for a in e.attributes() {
        let a = a.map_err(|err| Error::parse(FORMAT, "", format!("line {}: {err}", line_of(text, pos))))?;
        let key = String::from_utf8_lossy(a.key.as_ref()).into_owned();
        let value = a
            .unescape_value()
            .map_err(|err| Error::parse(FORMAT, "", format!("line {}: {err}", line_of(text, pos))))?
            .into_owned();
        out.push((key, value));
    }
    Ok(out)
}

fn get<'a>(attrs: &'a [(String, String)], key: &str) -> Option<&'a str> {
    attrs.iter().find(|(k, _)| k == key).map(|(_, v)| v.as_str())
}

fn num(attrs: &[(String, String)], key: &str, elem: &str, line: usize) -> Result<f64> {
    let v = get(attrs, key)
        .ok_or_else(|| Error::parse(FORMAT, "", format!("line {line}: <{elem}> without attribute {key}")))?;
    let x: f64 = v.trim().parse().map_err(|_| {
        Error::parse(
            FORMAT,
            "",
            format!("line {line}: <{elem}> attribute {key}={v:?} is not a number"),
        )
    })?;
    if !x.is_finite() {
        return Err(Error::parse(
            FORMAT,
            "",
            format!("line {line}: <{elem}> {key}={v:?} is not finite"),
        ));
    }
    Ok(x)
}

/// Parses imglab XML text (see [`read_dlib_xml`]; errors carry an empty path).
///
/// # Errors
/// As [`read_dlib_xml`].
pub fn parse_dlib_xml(text: &str) -> Result<DlibDataset> {
    let mut reader = Reader::from_str(text);
    reader.config_mut().trim_text(true);
    let mut ds = DlibDataset::default();
    let mut stack: Vec<String> = Vec::new();
    let mut seen_dataset = false;
    loop {
        // Start of the next event: skip the whitespace that `trim_text` drops.
        let pos = (reader.buffer_position() as usize).min(text.len());
        let pos = text
            .get(pos..)
            .map_or(pos, |rest| pos + rest.len() - rest.trim_start().len());
        let ev = reader.read_event().map_err(|e| {
            Error::parse(
                FORMAT,
                "",
                format!("line {}: {e}", line_of(text, reader.error_position() as usize)),
            )
        })?;
        let line = line_of(text, pos);
        let perr = |r: String| Error::parse(FORMAT, "", format!("line {line}: {r}"));
        match ev {
            Event::Start(ref e) | Event::Empty(ref e) => {
                let is_empty = matches!(ev, Event::Empty(_));
                let name = String::from_utf8_lossy(e.name().as_ref()).into_owned();
                let parent = stack.last().map(String::as_str);
                match name.as_str() {
                    "dataset" => {
                        if parent.is_some() || seen_dataset {
                            return Err(perr("nested or repeated <dataset>".into()));
                        }
                        seen_dataset = true;
                    }
                    "image" => {
                        if parent != Some("images") {
                            return Err(perr("<image> outside <images>".into()));
                        }
                        let attrs = attr_map(text, pos, e)?;
                        let file = get(&attrs, "file")
                            .ok_or_else(|| perr("<image> without attribute file".into()))?
                            .to_owned();
                        let dim = |k: &str| -> Result<Option<u32>> {
                            get(&attrs, k)
                                .map(|v| {
                                    v.trim()
                                        .parse::<u32>()
                                        .map_err(|_| perr(format!("<image> {k}={v:?} is not a pixel count")))
                                })
                                .transpose()
                        };
                        ds.images.push(DlibImage {
                            file,
                            width: dim("width")?,
                            height: dim("height")?,
                            boxes: Vec::new(),
                        });
                    }
                    "box" => {
                        if parent != Some("image") {
                            return Err(perr("<box> outside <image>".into()));
                        }
                        let attrs = attr_map(text, pos, e)?;
                        let rect = Rect::new(
                            num(&attrs, "left", "box", line)?,
                            num(&attrs, "top", "box", line)?,
                            num(&attrs, "width", "box", line)?,
                            num(&attrs, "height", "box", line)?,
                        )
                        .map_err(|err| perr(err.to_string()))?;
                        let ignore = match get(&attrs, "ignore").map(str::trim) {
                            None | Some("0") => false,
                            Some("1") => true,
                            Some(v) => return Err(perr(format!("<box> ignore={v:?} is not 0 or 1"))),
                        };
                        let img = ds
                            .images
                            .last_mut()
                            .ok_or_else(|| perr("<box> before any <image>".into()))?;
                        img.boxes.push(DlibBox {
                            rect,
                            ignore,
                            label: None,
                            parts: Vec::new(),
                        });
                    }
                    "part" => {
                        if parent != Some("box") {
                            return Err(perr("<part> outside <box>".into()));
                        }
                        let attrs = attr_map(text, pos, e)?;
                        let pname = get(&attrs, "name")
                            .ok_or_else(|| perr("<part> without attribute name".into()))?
                            .to_owned();
                        let p = Point2::new(num(&attrs, "x", "part", line)?, num(&attrs, "y", "part", line)?);
                        let b = ds
                            .images
                            .last_mut()
                            .and_then(|i| i.boxes.last_mut())
                            .ok_or_else(|| perr("<part> before any <box>".into()))?;
                        b.parts.push((pname, p));
                    }
                    "images" if parent != Some("dataset") => {
                        return Err(perr("<images> outside <dataset>".into()));
                    }
                    _ => {} // name, comment, label, unknown elements
                }
                if !is_empty {
                    stack.push(name);
                }
            }
            Event::End(e) => {
                let name = String::from_utf8_lossy(e.name().as_ref()).into_owned();
                match stack.pop() {
                    Some(open) if open == name => {}
                    other => {
                        return Err(perr(format!("</{name}> does not close {other:?}")));
                    }
                }
            }
            Event::Text(t) => {
                let s = t.unescape().map_err(|e| perr(e.to_string()))?.into_owned();
                let parents: Vec<&str> = stack.iter().map(String::as_str).collect();
                match parents.as_slice() {
                    ["dataset", "name"] => ds.name = Some(s),
                    ["dataset", "comment"] => ds.comment = Some(s),
                    [.., "box", "label"] => {
                        if let Some(b) = ds.images.last_mut().and_then(|i| i.boxes.last_mut()) {
                            b.label = Some(s);
                        }
                    }
                    _ => {}
                }
            }
            Event::Eof => break,
            _ => {} // declarations, processing instructions, comments, CDATA
        }
    }
    if let Some(open) = stack.last() {
        return Err(Error::parse(
            FORMAT,
            "",
            format!(
                "line {}: unclosed <{open}> at end of file (truncated?)",
                line_of(text, text.len())
            ),
        ));
    }
    if !seen_dataset {
        return Err(Error::parse(FORMAT, "", "no <dataset> element"));
    }
    Ok(ds)
}

/// The XML text of a dataset (coordinates rounded to integers, see module docs).
///
/// # Errors
/// [`Error::InvalidParameter`] for a non-finite coordinate or a part name that is
/// empty.
pub fn dlib_xml_to_string(ds: &DlibDataset) -> Result<String> {
    let mut s = String::new();
    s.push_str("<?xml version='1.0' encoding='UTF-8'?>\n");
    s.push_str("<?xml-stylesheet type='text/xsl' href='image_metadata_stylesheet.xsl'?>\n<dataset>\n");
    if let Some(n) = &ds.name {
        let _ = writeln!(s, "<name>{}</name>", escape(n.as_str()));
    }
    if let Some(c) = &ds.comment {
        let _ = writeln!(s, "<comment>{}</comment>", escape(c.as_str()));
    }
    s.push_str("<images>\n");
    let int = |v: f64, what: &str| -> Result<i64> {
        if v.is_finite() && v.abs() < 1e15 {
            Ok(v.round() as i64)
        } else {
            Err(Error::invalid(
                "dlib XML coordinate",
                format!("{what} = {v}"),
                "a finite number",
            ))
        }
    };
    for img in &ds.images {
        let _ = write!(s, "  <image file='{}'", escape(img.file.as_str()));
        if let Some(w) = img.width {
            let _ = write!(s, " width='{w}'");
        }
        if let Some(h) = img.height {
            let _ = write!(s, " height='{h}'");
        }
        s.push_str(">\n");
        for b in &img.boxes {
            let r = &b.rect;
            let _ = write!(
                s,
                "    <box top='{}' left='{}' width='{}' height='{}'",
                int(r.top, "box top")?,
                int(r.left, "box left")?,
                int(r.width, "box width")?,
                int(r.height, "box height")?
            );
            if b.ignore {
                s.push_str(" ignore='1'");
            }
            s.push_str(">\n");
            if let Some(l) = &b.label {
                let _ = writeln!(s, "      <label>{}</label>", escape(l.as_str()));
            }
            for (name, p) in &b.parts {
                if name.is_empty() {
                    return Err(Error::invalid("dlib XML part name", "\"\"", "a non-empty name"));
                }
                let _ = writeln!(
                    s,
                    "      <part name='{}' x='{}' y='{}'/>",
                    escape(name.as_str()),
                    int(p.x, "part x")?,
                    int(p.y, "part y")?
                );
            }
            s.push_str("    </box>\n");
        }
        s.push_str("  </image>\n");
    }
    s.push_str("</images>\n</dataset>\n");
    Ok(s)
}

/// Writes a dataset as imglab XML (atomically).
///
/// # Errors
/// As [`dlib_xml_to_string`], or [`Error::Io`].
pub fn write_dlib_xml(path: impl AsRef<Path>, ds: &DlibDataset) -> Result<()> {
    let text = dlib_xml_to_string(ds)?;
    write_atomic(path, |w| w.write_all(text.as_bytes()))
}
