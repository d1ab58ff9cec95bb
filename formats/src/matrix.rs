//! Dense row-major `f64` matrix, serialised as its shape plus raw little-endian bytes.

use serde::de::{self, Deserializer, MapAccess, Visitor};
use serde::ser::{SerializeStruct, Serializer};
use serde::{Deserialize, Serialize};
use std::fmt;

/// A dense matrix, row-major: entry (i, j) is `data[i * cols + j]`.
///
/// On disk (MessagePack, named fields) it is the map
/// `{"rows": u32, "cols": u32, "data": bin}` where `data` holds `rows·cols` IEEE-754 doubles,
/// little-endian, row-major. `Model::validate` checks `data.len() == rows·cols`; decoding
/// fails if the byte string is not a whole number of doubles.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Matrix {
    /// Number of rows.
    pub rows: u32,
    /// Number of columns.
    pub cols: u32,
    /// Entries, row-major, length `rows·cols`.
    pub data: Vec<f64>,
}

impl Matrix {
    /// A `rows × cols` matrix of zeros.
    pub fn zeros(rows: u32, cols: u32) -> Self {
        Matrix {
            rows,
            cols,
            data: vec![0.0; rows as usize * cols as usize],
        }
    }

    /// The `n × n` identity.
    pub fn identity(n: u32) -> Self {
        let mut m = Matrix::zeros(n, n);
        for i in 0..n as usize {
            m.data[i * n as usize + i] = 1.0;
        }
        m
    }

    /// Builds a matrix from row-major data; `None` if `data.len() != rows·cols`.
    pub fn from_row_major(rows: u32, cols: u32, data: Vec<f64>) -> Option<Self> {
        (data.len() as u64 == rows as u64 * cols as u64).then_some(Matrix { rows, cols, data })
    }

    /// Builds a matrix entry by entry: `f(i, j)`.
    pub fn from_fn(rows: u32, cols: u32, mut f: impl FnMut(usize, usize) -> f64) -> Self {
        let (r, c) = (rows as usize, cols as usize);
        let mut data = Vec::with_capacity(r * c);
        for i in 0..r {
            for j in 0..c {
                data.push(f(i, j));
            }
        }
        Matrix { rows, cols, data }
    }

    /// Shape `(rows, cols)` as `usize`.
    pub fn shape(&self) -> (usize, usize) {
        (self.rows as usize, self.cols as usize)
    }

    /// Entry (i, j). Panics if out of range (like slice indexing).
    pub fn get(&self, i: usize, j: usize) -> f64 {
        self.data[i * self.cols as usize + j]
    }

    /// Row `i` as a slice. Panics if out of range.
    pub fn row(&self, i: usize) -> &[f64] {
        let c = self.cols as usize;
        &self.data[i * c..(i + 1) * c]
    }

    /// `y = A x` into a caller buffer (`x.len() == cols`, `y.len() == rows`).
    pub fn mul_vec_into(&self, x: &[f64], y: &mut [f64]) {
        let c = self.cols as usize;
        for (yi, row) in y.iter_mut().zip(self.data.chunks_exact(c.max(1))) {
            *yi = row.iter().zip(x).map(|(a, b)| a * b).sum();
        }
        if c == 0 {
            y.iter_mut().for_each(|v| *v = 0.0);
        }
    }

    /// The raw little-endian bytes of `data` (what is stored on disk).
    pub fn to_le_bytes(&self) -> Vec<u8> {
        let mut out = Vec::with_capacity(self.data.len() * 8);
        for v in &self.data {
            out.extend_from_slice(&v.to_le_bytes());
        }
        out
    }
}

impl Serialize for Matrix {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        let mut s = serializer.serialize_struct("Matrix", 3)?;
        s.serialize_field("rows", &self.rows)?;
        s.serialize_field("cols", &self.cols)?;
        s.serialize_field("data", serde_bytes::Bytes::new(&self.to_le_bytes()))?;
        s.end()
    }
}

impl<'de> Deserialize<'de> for Matrix {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        const FIELDS: &[&str] = &["rows", "cols", "data"];
        struct MatrixVisitor;

        fn from_bytes<E: de::Error>(rows: u32, cols: u32, bytes: &[u8]) -> Result<Matrix, E> {
            if bytes.len() & 7 != 0 {
                return Err(E::custom(format!(
                    "matrix {rows}×{cols}: data has {} bytes, not a whole number of f64",
                    bytes.len()
                )));
            }
            let data = bytes
                .chunks_exact(8)
                .map(|c| f64::from_le_bytes([c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7]]))
                .collect();
            Ok(Matrix { rows, cols, data })
        }

        impl<'de> Visitor<'de> for MatrixVisitor {
            type Value = Matrix;

            fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
                f.write_str("a matrix {rows, cols, data: bytes}")
            }

            fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> Result<Matrix, A::Error> {
                let mut rows: Option<u32> = None;
                let mut cols: Option<u32> = None;
                let mut data: Option<serde_bytes::ByteBuf> = None;
                while let Some(key) = map.next_key::<String>()? {
                    match key.as_str() {
                        "rows" if rows.is_none() => rows = Some(map.next_value()?),
                        "cols" if cols.is_none() => cols = Some(map.next_value()?),
                        "data" if data.is_none() => data = Some(map.next_value()?),
                        "rows" | "cols" | "data" => {
                            return Err(de::Error::custom(format!(
                                "matrix: duplicate field `{key}`"
                            )))
                        }
                        other => return Err(de::Error::unknown_field(other, FIELDS)),
                    }
                }
                let rows = rows.ok_or_else(|| de::Error::missing_field("rows"))?;
                let cols = cols.ok_or_else(|| de::Error::missing_field("cols"))?;
                let data = data.ok_or_else(|| de::Error::missing_field("data"))?;
                from_bytes(rows, cols, &data)
            }

            fn visit_seq<A: de::SeqAccess<'de>>(self, mut seq: A) -> Result<Matrix, A::Error> {
                let rows: u32 = seq
                    .next_element()?
                    .ok_or_else(|| de::Error::invalid_length(0, &self))?;
                let cols: u32 = seq
                    .next_element()?
                    .ok_or_else(|| de::Error::invalid_length(1, &self))?;
                let data: serde_bytes::ByteBuf = seq
                    .next_element()?
                    .ok_or_else(|| de::Error::invalid_length(2, &self))?;
                from_bytes(rows, cols, &data)
            }
        }

        deserializer.deserialize_struct("Matrix", FIELDS, MatrixVisitor)
    }
}
