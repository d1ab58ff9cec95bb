//! The binary data of VTK XML files, decoded here with every claimed size checked before
//! anything of that size is allocated (docs/limits.md).
//!
//! Layout (VTK XML format, `header_type` UInt32 or UInt64, `byte_order` of the file):
//! - uncompressed: one header integer n, then n bytes;
//! - compressed (`compressor="vtkZLibDataCompressor"` or `"vtkLZ4DataCompressor"`): the header
//!   `[nb, nu, np, nc_1 … nc_nb]` (nb blocks of nu bytes each before compression, the last of
//!   np bytes, or nu when np = 0; block i takes nc_i bytes compressed), then the nb compressed
//!   blocks one after the other.
//!
//! Inline (`format="binary"`) and appended base64 data encode the header and the data either
//! as one base64 stream or as two (VTK and meshio write both); [`Base64`] decodes either
//! byte by byte across padding. Appended raw data is read as it is ([`Raw`]).
//!
//! Checks, each naming the block: an uncompressed size at most the bytes that follow; a block
//! count whose sizes fit in the bytes that follow; a block size > 0; a last block no larger
//! than the others; compressed sizes > 0 that fit in the bytes that follow; a block's claimed
//! size at most [`limits::ZLIB_RATIO`] (zlib) or [`limits::LZ4_RATIO`] (LZ4) times its
//! compressed size; all decoded arrays of a file together at most
//! [`limits::VTU_DECODED_BYTES`]; and each block decompressing to exactly its claimed size.

use std::borrow::Cow;

use super::limits;

/// Compression of the binary blocks (`compressor` attribute of `<VTKFile>`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Compressor {
    /// No compression.
    None,
    /// `vtkZLibDataCompressor`.
    Zlib,
    /// `vtkLZ4DataCompressor` (LZ4 block format).
    Lz4,
}

impl Compressor {
    fn name(self) -> &'static str {
        match self {
            Compressor::None => "uncompressed",
            Compressor::Zlib => "zlib",
            Compressor::Lz4 => "LZ4",
        }
    }

    /// Largest expansion a block of this compressor can have.
    fn ratio(self) -> u64 {
        match self {
            Compressor::None => 1,
            Compressor::Zlib => limits::ZLIB_RATIO,
            Compressor::Lz4 => limits::LZ4_RATIO,
        }
    }
}

/// How the binary data of a file is laid out.
#[derive(Clone, Copy, Debug)]
pub(super) struct Encoding {
    /// Bytes per header integer: 4 (UInt32) or 8 (UInt64).
    pub header: usize,
    /// `byte_order="BigEndian"`.
    pub big_endian: bool,
    /// Compression of the blocks.
    pub compressor: Compressor,
}

/// What is left of a file's allowance of decoded bytes ([`limits::VTU_DECODED_BYTES`]).
#[derive(Debug)]
pub(super) struct Budget {
    left: u64,
}

impl Default for Budget {
    fn default() -> Self {
        Budget {
            left: limits::VTU_DECODED_BYTES,
        }
    }
}

impl Budget {
    fn charge(&mut self, bytes: u64) -> Result<(), String> {
        if bytes > self.left {
            return Err(format!(
                "the data arrays of this file would decode to more than {} bytes (4 GiB, the \
                 limit stated in docs/limits.md); this block alone claims {bytes} bytes",
                limits::VTU_DECODED_BYTES
            ));
        }
        self.left -= bytes;
        Ok(())
    }
}

/// A source of binary bytes: raw appended data or base64 text.
pub(super) trait Source<'a> {
    /// Largest number of bytes that can still be taken.
    fn available(&self) -> u64;
    /// The next `n` bytes; an error when fewer remain.
    fn take(&mut self, n: usize) -> Result<Cow<'a, [u8]>, String>;
}

/// Raw bytes (appended data with `encoding="raw"`).
pub(super) struct Raw<'a> {
    bytes: &'a [u8],
    pos: usize,
}

impl<'a> Raw<'a> {
    /// Bytes from `start` on (an offset past the end gives an empty source).
    pub(super) fn new(bytes: &'a [u8], start: usize) -> Self {
        Raw {
            bytes,
            pos: start.min(bytes.len()),
        }
    }
}

impl<'a> Source<'a> for Raw<'a> {
    fn available(&self) -> u64 {
        (self.bytes.len() - self.pos) as u64
    }

    fn take(&mut self, n: usize) -> Result<Cow<'a, [u8]>, String> {
        let end = self
            .pos
            .checked_add(n)
            .filter(|&e| e <= self.bytes.len())
            .ok_or_else(|| {
                format!(
                    "the data ends {} bytes into a {n}-byte read",
                    self.bytes.len() - self.pos
                )
            })?;
        let out = &self.bytes[self.pos..end];
        self.pos = end;
        Ok(Cow::Borrowed(out))
    }
}

/// Base64 text decoded on the fly (whitespace skipped; one stream or several concatenated,
/// each ending in its padding).
pub(super) struct Base64<'a> {
    text: &'a [u8],
    pos: usize,
    /// Decoded bytes of the last group not taken yet.
    pending: Vec<u8>,
}

impl<'a> Base64<'a> {
    /// Text from character `start` on.
    pub(super) fn new(text: &'a [u8], start: usize) -> Self {
        Base64 {
            text,
            pos: start.min(text.len()),
            pending: Vec::new(),
        }
    }

    fn value(c: u8) -> Option<u32> {
        match c {
            b'A'..=b'Z' => Some(u32::from(c - b'A')),
            b'a'..=b'z' => Some(u32::from(c - b'a') + 26),
            b'0'..=b'9' => Some(u32::from(c - b'0') + 52),
            b'+' => Some(62),
            b'/' => Some(63),
            _ => None,
        }
    }

    /// Decodes the next group of four characters into `pending` (1 to 3 bytes); `Ok(false)` at
    /// the end of the text.
    fn group(&mut self) -> Result<bool, String> {
        let mut chars = [0u8; 4];
        let mut got = 0;
        let mut first = None;
        while got < 4 {
            let Some(&c) = self.text.get(self.pos) else {
                if got == 0 {
                    return Ok(false);
                }
                return Err(format!(
                    "the base64 text ends inside a group of four characters (character {})",
                    self.pos
                ));
            };
            self.pos += 1;
            if c.is_ascii_whitespace() {
                continue;
            }
            first.get_or_insert(self.pos - 1);
            chars[got] = c;
            got += 1;
        }
        let at = first.unwrap_or(self.pos);
        let pad = chars.iter().rev().take_while(|&&c| c == b'=').count();
        if pad > 2 {
            return Err(format!("misplaced base64 padding at character {at}"));
        }
        let mut n: u32 = 0;
        for (k, &c) in chars[..4 - pad].iter().enumerate() {
            let v = Self::value(c).ok_or_else(|| {
                format!(
                    "character {:?} at character {} is not base64",
                    char::from(c),
                    at + k
                )
            })?;
            n |= v << (18 - 6 * k);
        }
        let bytes = [(n >> 16) as u8, (n >> 8) as u8, n as u8];
        self.pending.extend_from_slice(&bytes[..3 - pad]);
        Ok(true)
    }
}

impl<'a> Source<'a> for Base64<'a> {
    fn available(&self) -> u64 {
        ((self.text.len() - self.pos) as u64 / 4) * 3 + 3 + self.pending.len() as u64
    }

    fn take(&mut self, n: usize) -> Result<Cow<'a, [u8]>, String> {
        if n as u64 > self.available() {
            return Err(format!(
                "{n} bytes asked of base64 text that holds at most {}",
                self.available()
            ));
        }
        let mut out = Vec::with_capacity(n);
        loop {
            let k = (n - out.len()).min(self.pending.len());
            out.extend(self.pending.drain(..k));
            if out.len() == n {
                return Ok(Cow::Owned(out));
            }
            if !self.group()? {
                return Err(format!(
                    "the base64 text ends {} bytes into a {n}-byte read",
                    out.len()
                ));
            }
        }
    }
}

fn integer(bytes: &[u8], big_endian: bool) -> u64 {
    let mut v: u64 = 0;
    for k in 0..bytes.len() {
        let b = if big_endian {
            bytes[k]
        } else {
            bytes[bytes.len() - 1 - k]
        };
        v = (v << 8) | u64::from(b);
    }
    v
}

fn header_int<'a>(src: &mut dyn Source<'a>, enc: Encoding, what: &str) -> Result<u64, String> {
    let b = src
        .take(enc.header)
        .map_err(|e| format!("the block header is cut short ({what}): {e}"))?;
    Ok(integer(&b, enc.big_endian))
}

/// Reads one data array's bytes: its header, then its (decompressed) data.
pub(super) fn read_array<'a>(
    src: &mut dyn Source<'a>,
    enc: Encoding,
    budget: &mut Budget,
) -> Result<Vec<u8>, String> {
    if enc.compressor == Compressor::None {
        let n = header_int(src, enc, "size")?;
        let available = src.available();
        if n > available {
            return Err(format!(
                "the block header claims {n} bytes but at most {available} follow"
            ));
        }
        budget.charge(n)?;
        let n = usize::try_from(n).map_err(|_| format!("{n} bytes do not fit in memory"))?;
        return Ok(src.take(n)?.into_owned());
    }
    let name = enc.compressor.name();
    let blocks = header_int(src, enc, "number of blocks")?;
    let h = enc.header as u64;
    let available = src.available();
    if blocks
        .checked_add(2)
        .and_then(|n| n.checked_mul(h))
        .is_none_or(|need| need > available)
    {
        return Err(format!(
            "the {name} header claims {blocks} blocks, but the {available} bytes that follow \
             hold at most {} block sizes",
            (available / h).saturating_sub(2)
        ));
    }
    let block_size = header_int(src, enc, "block size")?;
    let last_size = header_int(src, enc, "last block size")?;
    let mut compressed = Vec::with_capacity(blocks as usize);
    for _ in 0..blocks {
        compressed.push(header_int(src, enc, "compressed block size")?);
    }
    if blocks == 0 {
        if last_size != 0 {
            return Err(format!(
                "the {name} header claims 0 blocks but a last block of {last_size} bytes"
            ));
        }
        return Ok(Vec::new());
    }
    if block_size == 0 {
        return Err(format!(
            "the {name} header gives a block size of 0 bytes for {blocks} block(s)"
        ));
    }
    if last_size > block_size {
        return Err(format!(
            "the {name} header gives a last block of {last_size} bytes, more than the block size \
             {block_size}"
        ));
    }
    let last = if last_size == 0 {
        block_size
    } else {
        last_size
    };
    let total = block_size
        .checked_mul(blocks - 1)
        .and_then(|t| t.checked_add(last))
        .ok_or_else(|| {
            format!(
                "the {name} header claims {blocks} blocks of {block_size} bytes: more than 2^64 \
                 bytes"
            )
        })?;
    let compressed_total = compressed
        .iter()
        .try_fold(0u64, |a, &c| a.checked_add(c))
        .unwrap_or(u64::MAX);
    let available = src.available();
    if compressed_total > available {
        return Err(format!(
            "the {name} header claims {compressed_total} compressed bytes in {blocks} block(s) \
             but at most {available} follow"
        ));
    }
    let ratio = enc.compressor.ratio();
    for (k, &c) in compressed.iter().enumerate() {
        let size = if k as u64 + 1 == blocks {
            last
        } else {
            block_size
        };
        if c == 0 {
            return Err(format!(
                "block {} of {blocks} has a compressed size of 0 bytes",
                k + 1
            ));
        }
        if size > c.saturating_mul(ratio) {
            return Err(format!(
                "block {} of {blocks} claims {size} bytes uncompressed from {c} compressed bytes; \
                 {name} expands at most {ratio}:1 (docs/limits.md)",
                k + 1
            ));
        }
    }
    budget.charge(total)?;
    let total =
        usize::try_from(total).map_err(|_| format!("{total} bytes do not fit in memory"))?;
    let mut out = vec![0u8; total];
    let mut at = 0usize;
    for (k, &c) in compressed.iter().enumerate() {
        let size = if k as u64 + 1 == blocks {
            last
        } else {
            block_size
        } as usize;
        let input = src
            .take(c as usize)
            .map_err(|e| format!("block {} of {blocks}: {e}", k + 1))?;
        let target = &mut out[at..at + size];
        let got = match enc.compressor {
            Compressor::Zlib => inflate(&input, target),
            Compressor::Lz4 => lz4_flex::block::decompress_into(&input, target)
                .map_err(|e| format!("not valid LZ4 data ({e})")),
            Compressor::None => Ok(size),
        }
        .map_err(|e| format!("block {} of {blocks}: {e}", k + 1))?;
        if got != size {
            return Err(format!(
                "block {} of {blocks} decompresses to {got} bytes, the header claims {size}",
                k + 1
            ));
        }
        at += size;
    }
    Ok(out)
}

/// Inflates one zlib stream into `out`; the number of bytes written, or an error when the
/// stream is not zlib or holds more than `out.len()` bytes.
fn inflate(input: &[u8], out: &mut [u8]) -> Result<usize, String> {
    use flate2::{Decompress, FlushDecompress, Status};
    let mut d = Decompress::new(true);
    let status = d
        .decompress(input, out, FlushDecompress::Finish)
        .map_err(|e| format!("not valid zlib data ({e})"))?;
    let written = usize::try_from(d.total_out()).unwrap_or(usize::MAX);
    match status {
        Status::StreamEnd => Ok(written),
        _ if written == out.len() => Err(format!(
            "holds more than the {} bytes the header claims",
            out.len()
        )),
        _ => Err(format!(
            "the zlib stream is cut short after {written} of {} bytes",
            out.len()
        )),
    }
}

/// Scalar types of VTK data arrays.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Scalar {
    I8,
    U8,
    I16,
    U16,
    I32,
    U32,
    I64,
    U64,
    F32,
    F64,
}

impl Scalar {
    /// The `type` attribute's value (`Int32`, `Float64`, …).
    pub(super) fn parse(name: &str) -> Option<Scalar> {
        Some(match name {
            "Int8" | "Char" => Scalar::I8,
            "UInt8" | "UnsignedChar" => Scalar::U8,
            "Int16" => Scalar::I16,
            "UInt16" => Scalar::U16,
            "Int32" => Scalar::I32,
            "UInt32" => Scalar::U32,
            "Int64" => Scalar::I64,
            "UInt64" => Scalar::U64,
            "Float32" => Scalar::F32,
            "Float64" => Scalar::F64,
            _ => return None,
        })
    }

    /// Bytes per value.
    pub(super) fn size(self) -> usize {
        match self {
            Scalar::I8 | Scalar::U8 => 1,
            Scalar::I16 | Scalar::U16 => 2,
            Scalar::I32 | Scalar::U32 | Scalar::F32 => 4,
            Scalar::I64 | Scalar::U64 | Scalar::F64 => 8,
        }
    }

    /// Integer type (not Float32/Float64).
    pub(super) fn is_integer(self) -> bool {
        !matches!(self, Scalar::F32 | Scalar::F64)
    }
}

/// The values of a data array: integers for integer types, floats for Float32/Float64.
#[derive(Clone, Debug, PartialEq)]
pub(super) enum Values {
    /// Any integer type.
    Int(Vec<i64>),
    /// Float32 or Float64.
    Float(Vec<f64>),
}

impl Values {
    /// Number of values.
    pub(super) fn len(&self) -> usize {
        match self {
            Values::Int(v) => v.len(),
            Values::Float(v) => v.len(),
        }
    }

    /// As coordinates.
    pub(super) fn into_f64(self) -> Vec<f64> {
        match self {
            Values::Int(v) => v.into_iter().map(|i| i as f64).collect(),
            Values::Float(v) => v,
        }
    }
}

fn too_large(k: usize, v: u64) -> String {
    format!("value {k} ({v}) exceeds 2^63 − 1")
}

/// The values of a binary array (`bytes.len()` a multiple of the scalar size).
pub(super) fn values(bytes: &[u8], scalar: Scalar, big_endian: bool) -> Result<Values, String> {
    let size = scalar.size();
    if !bytes.len().is_multiple_of(size) {
        return Err(format!(
            "{} bytes are not a whole number of {size}-byte values",
            bytes.len()
        ));
    }
    let raw = bytes.chunks_exact(size).map(|b| integer(b, big_endian));
    Ok(match scalar {
        Scalar::F32 => Values::Float(raw.map(|u| f64::from(f32::from_bits(u as u32))).collect()),
        Scalar::F64 => Values::Float(raw.map(f64::from_bits).collect()),
        _ => Values::Int(
            raw.enumerate()
                .map(|(k, u)| match scalar {
                    Scalar::I8 => Ok(i64::from(u as u8 as i8)),
                    Scalar::I16 => Ok(i64::from(u as u16 as i16)),
                    Scalar::I32 => Ok(i64::from(u as u32 as i32)),
                    Scalar::I64 => Ok(u as i64),
                    _ => i64::try_from(u).map_err(|_| too_large(k, u)),
                })
                .collect::<Result<_, _>>()?,
        ),
    })
}

/// The values of an ASCII array; an error names the first token that is not a value of the
/// type (its 0-based index among the values).
pub(super) fn ascii_values(text: &[u8], scalar: Scalar) -> Result<Values, String> {
    let text = std::str::from_utf8(text).map_err(|_| "the text is not UTF-8".to_string())?;
    let bad = |k: usize, tok: &str| format!("value {k} ({tok:?}) is not a {scalar:?} number");
    let tokens = text.split_ascii_whitespace().enumerate();
    if !scalar.is_integer() {
        return Ok(Values::Float(
            tokens
                .map(|(k, tok)| tok.parse::<f64>().map_err(|_| bad(k, tok)))
                .collect::<Result<_, _>>()?,
        ));
    }
    let (lo, hi): (i128, i128) = match scalar {
        Scalar::I8 => (i8::MIN.into(), i8::MAX.into()),
        Scalar::U8 => (0, u8::MAX.into()),
        Scalar::I16 => (i16::MIN.into(), i16::MAX.into()),
        Scalar::U16 => (0, u16::MAX.into()),
        Scalar::I32 => (i32::MIN.into(), i32::MAX.into()),
        Scalar::U32 => (0, u32::MAX.into()),
        Scalar::I64 | Scalar::U64 => (i64::MIN.into(), i64::MAX.into()),
        Scalar::F32 | Scalar::F64 => (0, 0),
    };
    Ok(Values::Int(
        tokens
            .map(|(k, tok)| {
                let v = tok.parse::<i128>().map_err(|_| bad(k, tok))?;
                if !(lo..=hi).contains(&v) || (scalar == Scalar::U64 && v < 0) {
                    return Err(bad(k, tok));
                }
                Ok(v as i64)
            })
            .collect::<Result<_, _>>()?,
    ))
}
