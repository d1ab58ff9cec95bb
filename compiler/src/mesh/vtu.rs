//! VTK XML unstructured grids (`.vtu`), read here without `vtkio`: the XML structure through
//! `quick-xml`, the data arrays by [`super::blocks`] (ASCII; inline base64 binary; appended
//! raw or base64 data; uncompressed, zlib or LZ4 blocks), every size a file claims checked
//! before it is allocated (docs/limits.md). Errors name the file, the piece, the `DataArray`
//! and its line.
//!
//! What is read (anything else in the file is skipped): `<VTKFile type="UnstructuredGrid">`
//! with its `byte_order`, `header_type` and `compressor`; per `<Piece NumberOfPoints
//! NumberOfCells>`, the `Points` array (3 components), the `Cells` arrays `connectivity`,
//! `offsets` and `types`, and the `CellData` arrays of one integer component (groups, see
//! [`super::vtk`]). Point counts, cell counts and array lengths must agree.
//!
//! The file must be whole and text: every element closed through `</VTKFile>` (after
//! `</AppendedData>` for appended data), else it is refused as cut short, naming the element or
//! `DataArray` it ends inside, how many values that array has, and the closing tags missing;
//! and UTF-8 outside raw appended data, else the first invalid byte is named by its offset in
//! the file and its line.

use std::borrow::Cow;

use quick_xml::events::{BytesStart, Event};
use quick_xml::Reader;

use super::blocks::{self, Base64, Budget, Compressor, Encoding, Raw, Scalar, Source, Values};

/// One piece of an unstructured grid, whatever file it came from.
pub(super) struct GridPiece {
    /// Point coordinates, 3 per point.
    pub points: Vec<f64>,
    /// Point ids of every cell, one after the other (ids local to the piece).
    pub connectivity: Vec<u64>,
    /// Each cell's (offset, length) in `connectivity`.
    pub ranges: Vec<(usize, usize)>,
    /// VTK cell type of each cell.
    pub types: Vec<u8>,
    /// Integer cell-data arrays of one component: (name, one value per cell).
    pub arrays: Vec<(String, Vec<i64>)>,
}

/// What an XML data set element or `type` attribute holds, in words.
pub(super) fn data_set_description(kind: &str) -> &'static str {
    match kind {
        "ImageData" => "image data (structured points)",
        "StructuredGrid" => "structured grid",
        "RectilinearGrid" => "rectilinear grid",
        "UnstructuredGrid" => "unstructured grid",
        "PolyData" => "poly data (surface)",
        _ => "non-grid",
    }
}

/// `format` of a `DataArray`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Format {
    Ascii,
    Binary,
    Appended,
}

/// Where in a piece a `DataArray` sits.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Section {
    Points,
    Cells,
    CellData,
}

/// A `DataArray` element as found, before decoding.
struct ArrayTag<'a> {
    section: Section,
    name: String,
    scalar: Option<Scalar>,
    type_name: String,
    components: u64,
    format: Format,
    offset: Option<u64>,
    /// Text content (ASCII values or inline base64), in pieces as the XML reader gives them.
    text: Vec<Cow<'a, [u8]>>,
    line: usize,
}

/// A `<Piece>` as found.
#[derive(Default)]
struct PieceTag<'a> {
    points: u64,
    cells: u64,
    arrays: Vec<ArrayTag<'a>>,
    line: usize,
}

fn attributes(e: &BytesStart<'_>) -> Result<Vec<(String, String)>, String> {
    e.attributes()
        .map(|a| {
            let a = a.map_err(|err| format!("malformed attribute ({err})"))?;
            let key = String::from_utf8_lossy(a.key.as_ref()).into_owned();
            let value = a
                .unescape_value()
                .map_err(|err| format!("attribute {key}: {err}"))?
                .into_owned();
            Ok((key, value))
        })
        .collect()
}

fn get<'v>(attrs: &'v [(String, String)], key: &str) -> Option<&'v str> {
    attrs
        .iter()
        .find(|(k, _)| k == key)
        .map(|(_, v)| v.as_str())
}

/// Everything of the file that the mesh needs, parsed.
struct Document<'a> {
    encoding: Encoding,
    pieces: Vec<PieceTag<'a>>,
    /// `(encoding is raw, payload)` of `<AppendedData>`, payload after its `_`.
    appended: Option<(bool, &'a [u8], usize)>,
    /// When the file is cut short after `<AppendedData>` (its closing tag or `</VTKFile>`
    /// missing): what is missing, completed by [`read`] with the array that runs past the end.
    cut: Option<String>,
}

/// Where the bytes given to [`read`] start in the file: their byte offset and the number of
/// lines before them (a byte-order mark and blank lines before `<?xml`).
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct Origin {
    /// Byte offset in the file.
    pub offset: usize,
    /// Line breaks before it.
    pub lines: usize,
}

/// `Ok` when `bytes[range]` is UTF-8; else a message naming the first invalid byte by its
/// offset in the file (0-based) and its line. Outside raw appended data a VTK XML file is
/// text: VTK and meshio write ASCII (and UTF-8 names).
fn check_utf8(bytes: &[u8], range: std::ops::Range<usize>, origin: Origin) -> Result<(), String> {
    let Err(e) = std::str::from_utf8(&bytes[range.clone()]) else {
        return Ok(());
    };
    let at = range.start + e.valid_up_to();
    let line = origin.lines + line_at(bytes, at);
    let declared = declared_encoding(bytes)
        .filter(|d| !d.eq_ignore_ascii_case("utf-8") && !d.eq_ignore_ascii_case("utf8"))
        .map(|d| format!(" (its XML declaration says encoding=\"{d}\", which crokf does not read)"))
        .unwrap_or_default();
    Err(format!(
        "the file is not UTF-8 text: byte {} (0-based offset in the file, line {line}) is \
         0x{:02X}, which is not valid UTF-8 there{declared}; outside raw appended data a VTK \
         XML file must be UTF-8 (VTK and meshio write ASCII): a name or comment saved in \
         another encoding, or a damaged file? Convert it (e.g. `iconv -f LATIN1 -t UTF-8 \
         in.vtu > out.vtu`) or write it again",
        origin.offset + at,
        bytes[at]
    ))
}

/// The `encoding` of the `<?xml ...?>` declaration, if the file starts with one that states it.
fn declared_encoding(bytes: &[u8]) -> Option<String> {
    let decl = bytes.strip_prefix(b"<?xml")?;
    let end = decl.windows(2).position(|w| w == b"?>")?;
    let decl = String::from_utf8_lossy(&decl[..end]).into_owned();
    let rest = &decl[decl.find("encoding")? + "encoding".len()..];
    let rest = rest.trim_start().strip_prefix('=')?.trim_start();
    let quote = rest.chars().next().filter(|&c| c == '"' || c == '\'')?;
    let value = &rest[1..];
    Some(value[..value.find(quote)?].to_owned())
}

/// The closing tags of the open elements `stack` (outermost first), innermost first, in words:
/// "the closing </Piece>, </UnstructuredGrid> and </VTKFile> tags are missing".
fn missing_tags(stack: &[(Vec<u8>, usize)]) -> String {
    let tags: Vec<String> = stack
        .iter()
        .rev()
        .map(|(name, _)| format!("</{}>", String::from_utf8_lossy(name)))
        .collect();
    match tags.as_slice() {
        [] => "no closing tag is missing".to_owned(),
        [one] => format!("the closing {one} tag is missing"),
        [init @ .., last] => format!(
            "the closing {} and {last} tags are missing",
            init.join(", ")
        ),
    }
}

const CUT_HINT: &str = "an interrupted write, copy or download? write or copy the file again";

/// What an array cut off by the end of the file holds: its count of values against what the
/// piece needs, or why its binary data cannot be decoded.
fn partial_array(
    tag: &ArrayTag<'_>,
    piece: Option<&PieceTag<'_>>,
    encoding: Option<Encoding>,
) -> String {
    let text: Vec<u8> = tag.text.iter().flat_map(|c| c.iter().copied()).collect();
    let count = match tag.format {
        Format::Ascii => Ok(text
            .split(u8::is_ascii_whitespace)
            .filter(|t| !t.is_empty())
            .count() as u64),
        Format::Binary => match (encoding, tag.scalar) {
            (Some(enc), Some(scalar)) => {
                blocks::read_array(&mut Base64::new(&text, 0), enc, &mut Budget::default())
                    .and_then(|b| blocks::values(&b, scalar, enc.big_endian))
                    .map(|v| v.len() as u64)
            }
            _ => return String::new(),
        },
        Format::Appended => return String::new(),
    };
    let expected = piece
        .and_then(|p| match (tag.section, tag.name.as_str()) {
            (Section::Points, _) => Some(p.points),
            (Section::Cells, "offsets" | "types") | (Section::CellData, _) => Some(p.cells),
            _ => None,
        })
        .and_then(|n| n.checked_mul(tag.components));
    match (count, expected) {
        (Ok(n), Some(want)) if n < want => format!(", which has {n} of its {want} values"),
        (Ok(_), Some(_)) => String::new(),
        (Ok(n), None) => format!(", which has {n} values where the file ends"),
        (Err(e), _) => format!(", whose data is cut short ({e})"),
    }
}

fn line_at(bytes: &[u8], offset: usize) -> usize {
    super::line_of(bytes, offset)
}

/// Parses the XML structure (everything before `<AppendedData>`, then that tag). The file must
/// be UTF-8 outside raw appended data, and complete: every element closed, through
/// `</VTKFile>` (a file cut short is refused, naming where it ends and what is missing).
fn parse(bytes: &[u8], origin: Origin) -> Result<Document<'_>, String> {
    const OPEN: &[u8] = b"<AppendedData";
    let open = bytes.windows(OPEN.len()).position(|w| w == OPEN);
    let head = &bytes[..open.unwrap_or(bytes.len())];
    check_utf8(bytes, 0..head.len(), origin)?;
    let mut reader = Reader::from_reader(head);
    // Open elements: (name, line of the start tag).
    let mut stack: Vec<(Vec<u8>, usize)> = Vec::new();
    let mut encoding = None;
    let mut grid = false;
    let mut pieces: Vec<PieceTag<'_>> = Vec::new();
    let mut in_piece = false;
    let mut section: Option<(Section, usize)> = None;
    let mut array: Option<(ArrayTag<'_>, usize)> = None;
    loop {
        let at = reader.buffer_position() as usize;
        let event = match reader.read_event() {
            Ok(event) => event,
            // Syntax errors are tags, comments or declarations the input ends inside.
            Err(quick_xml::Error::Syntax(_)) if open.is_none() => {
                let shown: String = String::from_utf8_lossy(&head[at..])
                    .chars()
                    .take(24)
                    .map(|c| if c.is_control() { ' ' } else { c })
                    .collect();
                let within = format!(
                    ", in the middle of `{}` on line {}",
                    shown.trim_end(),
                    line_at(bytes, at)
                );
                return Err(cut_short(
                    &stack,
                    array.as_ref().map(|(t, _)| t),
                    &pieces,
                    encoding,
                    &within,
                ));
            }
            Err(e) => return Err(format!("line {}: malformed XML ({e})", line_at(bytes, at))),
        };
        let line = || line_at(bytes, at);
        match event {
            Event::Start(ref e) | Event::Empty(ref e) => {
                let empty = matches!(event, Event::Empty(_));
                let name = e.local_name().as_ref().to_vec();
                let attrs = attributes(e).map_err(|m| format!("line {}: {m}", line()))?;
                match name.as_slice() {
                    b"VTKFile" => {
                        encoding = Some(file_tag(&attrs).map_err(|m| at_line(line(), m))?)
                    }
                    b"UnstructuredGrid" => grid = true,
                    b"PUnstructuredGrid" => return Err(parallel(line())),
                    b"PolyData" | b"ImageData" | b"RectilinearGrid" | b"StructuredGrid" => {
                        return Err(other_data_set(&String::from_utf8_lossy(&name)))
                    }
                    b"Piece" if grid && !in_piece => {
                        if let Some(source) = get(&attrs, "Source") {
                            return Err(format!(
                                "line {}: piece {} is stored in another file ({source}): \
                                 parallel (.pvtu) data sets are not read; merge the pieces into \
                                 one .vtu (ParaView: Merge Blocks, then Save Data)",
                                line(),
                                pieces.len() + 1
                            ));
                        }
                        let count = |key: &str| -> Result<u64, String> {
                            let v = get(&attrs, key)
                                .ok_or_else(|| format!("line {}: <Piece> without {key}", line()))?;
                            v.trim().parse().map_err(|_| {
                                format!(
                                    "line {}: <Piece> {key}={v:?} is not a non-negative integer",
                                    line()
                                )
                            })
                        };
                        pieces.push(PieceTag {
                            points: count("NumberOfPoints")?,
                            cells: count("NumberOfCells")?,
                            arrays: Vec::new(),
                            line: line(),
                        });
                        in_piece = !empty;
                    }
                    b"Points" if in_piece && !empty => {
                        section = Some((Section::Points, stack.len() + 1));
                    }
                    b"Cells" if in_piece && !empty => {
                        section = Some((Section::Cells, stack.len() + 1));
                    }
                    b"CellData" if in_piece && !empty => {
                        section = Some((Section::CellData, stack.len() + 1));
                    }
                    b"DataArray" if array.is_none() => {
                        if let Some((s, _)) = section.filter(|&(_, d)| d == stack.len()) {
                            let tag = array_tag(s, &attrs, line())?;
                            if empty {
                                finish_array(&mut pieces, tag);
                            } else {
                                array = Some((tag, stack.len() + 1));
                            }
                        }
                    }
                    _ => {}
                }
                if !empty {
                    stack.push((name, line()));
                }
            }
            Event::End(ref e) => {
                let depth = stack.len();
                stack.pop();
                if array.as_ref().is_some_and(|(_, d)| *d == depth) {
                    if let Some((tag, _)) = array.take() {
                        finish_array(&mut pieces, tag);
                    }
                }
                if section.is_some_and(|(_, d)| d == depth) {
                    section = None;
                }
                if e.local_name().as_ref() == b"Piece" {
                    in_piece = false;
                }
            }
            Event::Text(t) => {
                if let Some((tag, d)) = &mut array {
                    if *d == stack.len() {
                        tag.text.push(t.into_inner());
                    }
                }
            }
            Event::CData(t) => {
                if let Some((tag, d)) = &mut array {
                    if *d == stack.len() {
                        tag.text.push(t.into_inner());
                    }
                }
            }
            Event::Eof => break,
            _ => {}
        }
    }
    let root = stack.first().filter(|(name, _)| name == b"VTKFile");
    if open.is_none() && !stack.is_empty() {
        return Err(cut_short(
            &stack,
            array.as_ref().map(|(t, _)| t),
            &pieces,
            encoding,
            "",
        ));
    }
    let encoding = encoding.ok_or("no <VTKFile> element: not a VTK XML file")?;
    if !grid {
        return Err("no <UnstructuredGrid> element".into());
    }
    let (appended, cut) = match open {
        None => (None, None),
        Some(open) => {
            if root.is_none() || stack.len() > 1 {
                let (name, line) = stack.last().cloned().unwrap_or_default();
                return Err(format!(
                    "line {}: <AppendedData> must be a child of <VTKFile>, but <{}> (line \
                     {line}) is still open",
                    line_at(bytes, open),
                    String::from_utf8_lossy(&name)
                ));
            }
            let (data, cut) = appended_data(bytes, open, &stack, origin)?;
            (Some(data), cut)
        }
    };
    Ok(Document {
        encoding,
        pieces,
        appended,
        cut,
    })
}

/// The message for a file that ends inside the elements `stack` (and inside `array`, if one
/// is open), `within` saying where exactly (e.g. in the middle of a tag).
fn cut_short(
    stack: &[(Vec<u8>, usize)],
    array: Option<&ArrayTag<'_>>,
    pieces: &[PieceTag<'_>],
    encoding: Option<Encoding>,
    within: &str,
) -> String {
    let (name, line) = stack.last().cloned().unwrap_or_default();
    let inside = match array {
        Some(tag) => format!(
            "DataArray '{}' (line {}, piece {}){}",
            tag.name,
            tag.line,
            pieces.len(),
            partial_array(tag, pieces.last(), encoding)
        ),
        None if stack.is_empty() => "the XML declaration, before <VTKFile>".to_owned(),
        None => format!("<{}> (line {line})", String::from_utf8_lossy(&name)),
    };
    format!(
        "the file is cut short: it ends inside {inside}{within}; {} ({CUT_HINT})",
        missing_tags(stack)
    )
}

fn at_line(line: usize, message: String) -> String {
    format!("line {line}: {message}")
}

fn parallel(line: usize) -> String {
    format!(
        "line {line}: a parallel (.pvtu) data set is not read; merge the pieces into one .vtu \
         (ParaView: Merge Blocks, then Save Data)"
    )
}

fn other_data_set(kind: &str) -> String {
    format!(
        "the file holds a {} data set; crokf reads unstructured grids (<UnstructuredGrid>, \
         DATASET UNSTRUCTURED_GRID) of tetrahedra",
        data_set_description(kind)
    )
}

/// `<VTKFile>`: data set type, byte order, header type and compressor.
fn file_tag(attrs: &[(String, String)]) -> Result<Encoding, String> {
    match get(attrs, "type") {
        Some("UnstructuredGrid") | None => {}
        Some("PUnstructuredGrid") => {
            return Err(
                "a parallel (.pvtu) data set is not read; merge the pieces into one .vtu \
                 (ParaView: Merge Blocks, then Save Data)"
                    .into(),
            )
        }
        Some(other) => return Err(other_data_set(other)),
    }
    let header = match get(attrs, "header_type") {
        Some("UInt64") => 8,
        Some("UInt32") | None => 4,
        Some(other) => return Err(format!("header_type {other:?} is not UInt32 or UInt64")),
    };
    let big_endian = match get(attrs, "byte_order") {
        Some("BigEndian") => true,
        Some("LittleEndian") | None => false,
        Some(other) => {
            return Err(format!(
                "byte_order {other:?} is not LittleEndian or BigEndian"
            ))
        }
    };
    let compressor = match get(attrs, "compressor").map(str::trim) {
        None | Some("") => Compressor::None,
        Some("vtkZLibDataCompressor") => Compressor::Zlib,
        Some("vtkLZ4DataCompressor") => Compressor::Lz4,
        Some(other) => {
            return Err(format!(
                "compressor {other:?} is not read (crokf reads zlib and LZ4): save the file \
                 with zlib compression or none"
            ))
        }
    };
    Ok(Encoding {
        header,
        big_endian,
        compressor,
    })
}

fn array_tag<'a>(
    section: Section,
    attrs: &[(String, String)],
    line: usize,
) -> Result<ArrayTag<'a>, String> {
    let name = get(attrs, "Name").unwrap_or("").to_owned();
    let what = format!("line {line}: DataArray '{name}'");
    let type_name = get(attrs, "type").unwrap_or("").to_owned();
    let components = match get(attrs, "NumberOfComponents") {
        None => 1,
        Some(v) => v.trim().parse().map_err(|_| {
            format!("{what}: NumberOfComponents={v:?} is not a non-negative integer")
        })?,
    };
    let format = match get(attrs, "format") {
        Some("ascii") | None => Format::Ascii,
        Some("binary") => Format::Binary,
        Some("appended") => Format::Appended,
        Some(other) => {
            return Err(format!(
                "{what}: format {other:?} is not ascii, binary or appended"
            ))
        }
    };
    let offset = match get(attrs, "offset") {
        None => None,
        Some(v) => Some(
            v.trim()
                .parse()
                .map_err(|_| format!("{what}: offset {v:?} is not a non-negative integer"))?,
        ),
    };
    Ok(ArrayTag {
        section,
        name,
        scalar: Scalar::parse(&type_name),
        type_name,
        components,
        format,
        offset,
        text: Vec::new(),
        line,
    })
}

fn finish_array<'a>(pieces: &mut [PieceTag<'a>], tag: ArrayTag<'a>) {
    if let Some(p) = pieces.last_mut() {
        p.arrays.push(tag);
    }
}

/// The appended data and, when the file is cut short after `<AppendedData>`, what is missing.
type Appended<'a> = ((bool, &'a [u8], usize), Option<String>);

/// `<AppendedData encoding="raw|base64">_…`: the encoding and the payload after the `_`
/// (up to `</AppendedData>`, or the end of the file), with the payload's byte offset; and,
/// when `</AppendedData>` or the `</VTKFile>` after it is missing, what is (`stack`: the open
/// elements before `<AppendedData>`, i.e. `<VTKFile>`). Everything but raw data must be UTF-8.
fn appended_data<'a>(
    bytes: &'a [u8],
    open: usize,
    stack: &[(Vec<u8>, usize)],
    origin: Origin,
) -> Result<Appended<'a>, String> {
    let line = line_at(bytes, open);
    let tag_end = bytes[open..]
        .iter()
        .position(|&b| b == b'>')
        .map(|p| open + p)
        .ok_or_else(|| format!("line {line}: unterminated <AppendedData> tag"))?;
    let mut reader = Reader::from_reader(&bytes[open..=tag_end]);
    let attrs = match reader.read_event() {
        Ok(Event::Start(e)) | Ok(Event::Empty(e)) => attributes(&e)?,
        _ => return Err(format!("line {line}: malformed <AppendedData> tag")),
    };
    let raw = match get(&attrs, "encoding") {
        Some("raw") => true,
        Some("base64") => false,
        other => {
            return Err(format!(
                "line {line}: <AppendedData> encoding {other:?} is not raw or base64"
            ))
        }
    };
    let underscore = bytes[tag_end..]
        .iter()
        .position(|&b| b == b'_')
        .map(|p| tag_end + p)
        .ok_or_else(|| format!("line {line}: appended data without its leading `_`"))?;
    let start = underscore + 1;
    check_utf8(bytes, open..start, origin)?;
    const CLOSE: &[u8] = b"</AppendedData>";
    let close = bytes
        .windows(CLOSE.len())
        .rposition(|w| w == CLOSE)
        .filter(|&e| e >= start);
    let end = close.unwrap_or(bytes.len());
    if !raw {
        check_utf8(bytes, start..end, origin)?;
    }
    let data = (raw, &bytes[start..end], start);
    let mut open_tags = stack.to_vec();
    let Some(close) = close else {
        open_tags.push((b"AppendedData".to_vec(), line));
        return Ok((
            data,
            Some(format!(
                "the file is cut short: it ends inside <AppendedData> (line {line}); {}",
                missing_tags(&open_tags)
            )),
        ));
    };
    // After </AppendedData>: comments and blank text, then </VTKFile>.
    let tail = close + CLOSE.len();
    check_utf8(bytes, tail..bytes.len(), origin)?;
    let mut reader = Reader::from_reader(&bytes[tail..]);
    reader.config_mut().allow_unmatched_ends = true;
    loop {
        let at = tail + reader.buffer_position() as usize;
        match reader.read_event() {
            Ok(Event::End(e)) if e.local_name().as_ref() == b"VTKFile" => return Ok((data, None)),
            Ok(Event::Text(t)) if t.iter().all(u8::is_ascii_whitespace) => {}
            Ok(Event::Comment(_) | Event::PI(_)) => {}
            Ok(Event::Eof) | Err(quick_xml::Error::Syntax(_)) => {
                let (_, root) = stack.first().cloned().unwrap_or_default();
                return Ok((
                    data,
                    Some(format!(
                        "the file is cut short: it ends inside <VTKFile> (line {root}), after \
                         </AppendedData> (line {}); {}",
                        line_at(bytes, close),
                        missing_tags(&open_tags)
                    )),
                ));
            }
            _ => {
                return Err(format!(
                    "line {}: after </AppendedData> the file must end with </VTKFile>",
                    line_at(bytes, at)
                ))
            }
        }
    }
}

/// The values of one array.
fn decode(doc: &Document<'_>, tag: &ArrayTag<'_>, budget: &mut Budget) -> Result<Values, String> {
    let scalar = tag.scalar.ok_or_else(|| {
        format!(
            "type {:?} is not a VTK scalar type (Int8 … UInt64, Float32, Float64)",
            tag.type_name
        )
    })?;
    let joined;
    let text: &[u8] = match tag.text.as_slice() {
        [] => &[],
        [one] => one,
        many => {
            joined = many
                .iter()
                .flat_map(|c| c.iter().copied())
                .collect::<Vec<u8>>();
            &joined
        }
    };
    let enc = doc.encoding;
    let bytes = match tag.format {
        Format::Ascii => return blocks::ascii_values(text, scalar),
        Format::Binary => {
            if text.iter().all(u8::is_ascii_whitespace) {
                return Err("binary data array without data".into());
            }
            blocks::read_array(&mut Base64::new(text, 0), enc, budget)?
        }
        Format::Appended => {
            let (raw, payload, _) = doc
                .appended
                .ok_or("format=\"appended\" but the file has no <AppendedData>")?;
            let offset = tag.offset.ok_or("format=\"appended\" without an offset")?;
            let start = usize::try_from(offset)
                .ok()
                .filter(|&o| o < payload.len())
                .ok_or_else(|| {
                    format!(
                        "offset {offset} is beyond the appended data ({} {})",
                        payload.len(),
                        if raw { "bytes" } else { "characters" }
                    )
                })?;
            let mut source: Box<dyn Source<'_>> = if raw {
                Box::new(Raw::new(payload, start))
            } else {
                Box::new(Base64::new(payload, start))
            };
            blocks::read_array(source.as_mut(), enc, budget)?
        }
    };
    blocks::values(&bytes, scalar, enc.big_endian)
}

/// Reads a VTK XML unstructured grid into pieces; `origin` places `bytes` in the file (for
/// the offset of a byte that is not UTF-8).
pub(super) fn read(bytes: &[u8], origin: Origin) -> Result<Vec<GridPiece>, String> {
    let doc = parse(bytes, origin)?;
    if let Some(cut) = &doc.cut {
        // Name the first array whose appended data runs past the end, if one does.
        let mut budget = Budget::default();
        let short = doc.pieces.iter().enumerate().find_map(|(k, p)| {
            let mut appended = p.arrays.iter().filter(|t| t.format == Format::Appended);
            appended.find_map(|tag| {
                decode(&doc, tag, &mut budget).err().map(|e| {
                    format!(
                        "; piece {}, DataArray '{}' (line {}) runs past the end: {e}",
                        k + 1,
                        tag.name,
                        tag.line
                    )
                })
            })
        });
        return Err(format!("{cut}{} ({CUT_HINT})", short.unwrap_or_default()));
    }
    if doc.pieces.is_empty() {
        return Err("the <UnstructuredGrid> has no <Piece>".into());
    }
    let mut budget = Budget::default();
    let mut out = Vec::with_capacity(doc.pieces.len());
    for (k, piece) in doc.pieces.iter().enumerate() {
        let here = |tag: &ArrayTag<'_>| {
            format!(
                "piece {}, DataArray '{}' (line {}, {})",
                k + 1,
                tag.name,
                tag.line,
                match tag.format {
                    Format::Ascii => "ascii".to_owned(),
                    Format::Binary => format!("binary, {}", compression(doc.encoding)),
                    Format::Appended => format!("appended, {}", compression(doc.encoding)),
                }
            )
        };
        let find = |section: Section, name: Option<&str>| {
            piece
                .arrays
                .iter()
                .find(|a| a.section == section && name.is_none_or(|n| a.name == n))
        };
        let missing =
            |what: &str| format!("piece {} (line {}): no {what} DataArray", k + 1, piece.line);
        let mut decoded = |tag: &ArrayTag<'_>| {
            decode(&doc, tag, &mut budget).map_err(|m| format!("{}: {m}", here(tag)))
        };
        let expect = |tag: &ArrayTag<'_>, values: &Values, n: u64, what: &str| {
            let want = n.checked_mul(tag.components).ok_or_else(|| {
                format!(
                    "{}: {n} × {} components overflows",
                    here(tag),
                    tag.components
                )
            })?;
            if values.len() as u64 != want {
                return Err(format!(
                    "{}: {} values, expected {want} ({what} {n} × {} components)",
                    here(tag),
                    values.len(),
                    tag.components
                ));
            }
            Ok(())
        };

        let points_tag = find(Section::Points, None).ok_or_else(|| missing("Points"))?;
        if points_tag.components != 3 {
            return Err(format!(
                "{}: points have {} components, expected 3",
                here(points_tag),
                points_tag.components
            ));
        }
        let points = decoded(points_tag)?;
        expect(points_tag, &points, piece.points, "NumberOfPoints")?;

        let integers = |tag: &ArrayTag<'_>, values: Values| match values {
            Values::Int(v) => Ok(v),
            Values::Float(_) => Err(format!(
                "{}: type {} is not an integer type",
                here(tag),
                tag.type_name
            )),
        };
        let conn_tag = find(Section::Cells, Some("connectivity"))
            .ok_or_else(|| missing("Cells/connectivity"))?;
        let off_tag =
            find(Section::Cells, Some("offsets")).ok_or_else(|| missing("Cells/offsets"))?;
        let types_tag =
            find(Section::Cells, Some("types")).ok_or_else(|| missing("Cells/types"))?;
        let offsets_values = decoded(off_tag)?;
        expect(off_tag, &offsets_values, piece.cells, "NumberOfCells")?;
        let offsets = integers(off_tag, offsets_values)?;
        let types_values = decoded(types_tag)?;
        expect(types_tag, &types_values, piece.cells, "NumberOfCells")?;
        let types = integers(types_tag, types_values)?;
        let connectivity = integers(conn_tag, decoded(conn_tag)?)?;

        let n_points = piece.points;
        let mut conn = Vec::with_capacity(connectivity.len());
        for (i, &v) in connectivity.iter().enumerate() {
            match u64::try_from(v) {
                Ok(v) if v < n_points => conn.push(v),
                _ => {
                    return Err(format!(
                        "{}: entry {i} is point {v}, but the piece has {n_points} points (ids \
                         0 to {})",
                        here(conn_tag),
                        n_points.saturating_sub(1)
                    ))
                }
            }
        }
        let mut ranges = Vec::with_capacity(offsets.len());
        let mut start = 0usize;
        for (c, &off) in offsets.iter().enumerate() {
            let end = usize::try_from(off)
                .ok()
                .filter(|&e| e >= start && e <= conn.len())
                .ok_or_else(|| {
                    format!(
                        "{}: cell {c} ends at {off}, outside {start}..={} (the connectivity \
                         has {} entries)",
                        here(off_tag),
                        conn.len(),
                        conn.len()
                    )
                })?;
            ranges.push((start, end - start));
            start = end;
        }
        let mut cell_types = Vec::with_capacity(types.len());
        for (c, &t) in types.iter().enumerate() {
            cell_types.push(u8::try_from(t).map_err(|_| {
                format!(
                    "{}: cell {c} has type {t}, not a VTK cell type (0 to 255)",
                    here(types_tag)
                )
            })?);
        }
        let mut arrays = Vec::new();
        for tag in piece
            .arrays
            .iter()
            .filter(|a| a.section == Section::CellData)
        {
            if tag.components != 1 || !tag.scalar.is_some_and(Scalar::is_integer) {
                continue;
            }
            let values = decoded(tag)?;
            expect(tag, &values, piece.cells, "NumberOfCells")?;
            if let Values::Int(v) = values {
                arrays.push((tag.name.clone(), v));
            }
        }
        out.push(GridPiece {
            points: points.into_f64(),
            connectivity: conn,
            ranges,
            types: cell_types,
            arrays,
        });
    }
    Ok(out)
}

fn compression(enc: Encoding) -> &'static str {
    match enc.compressor {
        Compressor::None => "uncompressed",
        Compressor::Zlib => "zlib",
        Compressor::Lz4 => "LZ4",
    }
}
