//! The crokf model file: types, validation and the versioned, hashed encoding.
//!
//! Layout (all integers little-endian; see `docs/model-format.md`):
//!
//! | offset | size | content                                   |
//! |-------:|-----:|-------------------------------------------|
//! | 0      | 8    | magic `b"CROKF\0\r\n"`                    |
//! | 8      | 4    | format version, u32 ([`version_of`]: 7, 9 or 10) |
//! | 12     | 8    | payload length L, u64                     |
//! | 20     | 32   | SHA-256 of the payload                    |
//! | 52     | L    | payload: MessagePack of [`Model`], named fields |
//!
//! Encoding is deterministic: the same [`Model`] always gives the same bytes.

mod contact;
mod matrix;
mod model;
pub mod output;
#[cfg(feature = "synthetic")]
pub mod synthetic;
mod tier;
mod validate;
pub mod vtk;

pub use contact::ContactRegion;
pub use matrix::Matrix;
pub use model::{
    component_label, CompileReport, InputChannel, InputKind, InputsDigest, KalmanGains,
    KalmanPhase, LoadGroup, MeasurementChannel, Model, NodeSet, SensorInfo,
};
pub use tier::{
    CorotationalTier, EnvelopeLoad, ForceAdaptation, ForceLevel, ScheduledFilter, TierElement,
    TrainingEnvelope, TrainingHistory,
};

use sha2::{Digest, Sha256};

/// File magic, 8 bytes.
pub const MAGIC: [u8; 8] = *b"CROKF\0\r\n";
/// The format version of a model without a contact region or a failed tier.
///
/// A model with a contact region is written as [`CONTACT_FORMAT_VERSION`] (9), one whose tier
/// failed the compiler's check as [`FAILED_CHECK_FORMAT_VERSION`] (10); any other is written,
/// byte for byte, as version 7 was ([`version_of`]), and this crate reads the three.
/// Version 7 adds the levels of the tier's force σ and the statistic that moves between them
/// (`CorotationalTier::force_levels`, `CorotationalTier::adaptation`, docs/design.md §11.10).
/// Version 6 adds the tier's measured model error (`CorotationalTier::model_error`, the filter's
/// model-error process noise, docs/design.md §11.9).
/// Version 5 adds the gain schedule of the tier's filter (`CorotationalTier::scheduled`) and its
/// optional force-rate states (`CorotationalTier::force_rates`, docs/design.md §11.5). Version 4 adds the random-walk force states to the tier's filter (`CorotationalTier::
/// force_loads`, docs/design.md §11.4; the tier's Kalman state grows from 3r to 3r + 3 per
/// group). Version 3 adds the optional co-rotational tier section (`Model::tier`, docs/design.md §10).
/// Version 2 stores the measurement noise once per channel (`kalman.measurement_variance`);
/// version 1 also had a lossy per-sensor `noise_std` (the largest σ over its components).
pub const FORMAT_VERSION: u32 = 7;
/// The version of a model file with a contact region (`Model::contact`, docs/contact.md):
/// readers of version 7 refuse it by its version. Version 9 adds the region's θ-point rows
/// (`ContactRegion::theta_rows`: the contact step enforces its gap at t + θΔt); version 8
/// contact files are refused by their version.
pub const CONTACT_FORMAT_VERSION: u32 = 9;
/// The version of a model file whose co-rotational tier failed the compiler's own check and was
/// written all the same (`CorotationalTier::failed_check`): readers of versions 7 and 9 refuse
/// it by its version, so no older runtime steps it as if it were fine. A model is written with
/// the lowest of the versions this crate reads that holds it ([`version_of`]).
pub const FAILED_CHECK_FORMAT_VERSION: u32 = 10;
/// The versions this crate reads, oldest first.
pub const READ_VERSIONS: [u32; 3] = [
    FORMAT_VERSION,
    CONTACT_FORMAT_VERSION,
    FAILED_CHECK_FORMAT_VERSION,
];
/// Header length in bytes (magic + version + payload length + SHA-256).
pub const HEADER_LEN: usize = 8 + 4 + 8 + 32;

/// Why a byte string is not a valid model file. Never a panic, on any input.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum FormatError {
    /// Shorter than the fixed header.
    #[error("model file too short: {len} bytes, the header alone is {HEADER_LEN} bytes")]
    TooShort {
        /// Length of the input.
        len: usize,
    },
    /// The first 8 bytes are not [`MAGIC`].
    #[error("not a crokf model file: magic bytes {found:02x?}, expected {MAGIC:02x?}")]
    BadMagic {
        /// The first 8 bytes.
        found: [u8; 8],
    },
    /// Written by another (older, newer or unknown) format version.
    #[error("{}", version_message(*found, *supported))]
    UnsupportedVersion {
        /// Version in the file.
        found: u32,
        /// Newest version this build reads.
        supported: u32,
    },
    /// The payload is shorter than the header says.
    #[error("model file truncated: header announces {expected} payload bytes, {found} present")]
    Truncated {
        /// Payload length from the header.
        expected: u64,
        /// Bytes present after the header.
        found: u64,
    },
    /// Bytes after the payload.
    #[error("model file has {extra} unexpected bytes after the {expected}-byte payload")]
    TrailingBytes {
        /// Payload length from the header.
        expected: u64,
        /// Extra bytes.
        extra: u64,
    },
    /// The payload does not hash to the header's SHA-256.
    #[error("model file corrupted: payload SHA-256 is {found}, header says {expected}")]
    HashMismatch {
        /// Hex digest from the header.
        expected: String,
        /// Hex digest of the payload.
        found: String,
    },
    /// The payload is not a MessagePack [`Model`].
    #[error("model payload is not a valid crokf model (MessagePack): {0}")]
    MessagePack(String),
    /// A matrix's data length does not match its declared shape.
    #[error("{matrix}: declared {rows}×{cols} but holds {len} values")]
    DataLength {
        /// Path of the matrix, e.g. `sensors[0] 'tip'.displacement_rows`.
        matrix: String,
        /// Declared rows.
        rows: u32,
        /// Declared columns.
        cols: u32,
        /// Number of f64 values present.
        len: usize,
    },
    /// A matrix has the wrong shape for its role.
    #[error("{matrix}: expected {expected_rows}×{expected_cols}, found {rows}×{cols}")]
    Shape {
        /// Path of the matrix.
        matrix: String,
        /// Required rows.
        expected_rows: u64,
        /// Required columns.
        expected_cols: u64,
        /// Declared rows.
        rows: u32,
        /// Declared columns.
        cols: u32,
    },
    /// NaN or infinity in a matrix or a numeric field.
    #[error("{matrix}: non-finite value {value} at ({row}, {col})")]
    NonFinite {
        /// Path of the matrix or field.
        matrix: String,
        /// Row (0 for vectors and scalars).
        row: usize,
        /// Column or vector index.
        col: usize,
        /// The offending value.
        value: f64,
    },
    /// Any other inconsistency (index out of range, duplicates, non-positive values...).
    #[error("{path}: {message}")]
    Invalid {
        /// Path of the offending field.
        path: String,
        /// What is wrong.
        message: String,
    },
}

/// "model format v8, this runtime reads v7, v9, v10: recompile the model with crokf-compile"
/// (or, for a newer file, "…: use a runtime that reads it, …").
fn version_message(found: u32, supported: u32) -> String {
    let remedy = if found < supported {
        "recompile the model with crokf-compile"
    } else {
        "use a runtime that reads it, or recompile the model with this crokf-compile"
    };
    let read: Vec<String> = READ_VERSIONS.iter().map(|v| format!("v{v}")).collect();
    format!(
        "model format v{found}, this runtime reads {}: {remedy}",
        read.join(", ")
    )
}

/// The version a model is written as: the lowest of [`READ_VERSIONS`] whose sections it uses —
/// [`FAILED_CHECK_FORMAT_VERSION`] when its tier carries a failed check, else
/// [`CONTACT_FORMAT_VERSION`] with a contact region, else [`FORMAT_VERSION`] (byte for byte as
/// version 7 files were written).
pub fn version_of(model: &Model) -> u32 {
    if model
        .tier
        .as_ref()
        .is_some_and(|t| t.failed_check.is_some())
    {
        FAILED_CHECK_FORMAT_VERSION
    } else if model.contact.is_some() {
        CONTACT_FORMAT_VERSION
    } else {
        FORMAT_VERSION
    }
}

/// Lowercase hex of a byte string.
pub fn hex(bytes: &[u8]) -> String {
    const DIGITS: &[u8; 16] = b"0123456789abcdef";
    let mut s = String::with_capacity(bytes.len() * 2);
    for b in bytes {
        s.push(DIGITS[(b >> 4) as usize] as char);
        s.push(DIGITS[(b & 15) as usize] as char);
    }
    s
}

/// SHA-256 of `bytes`, lowercase hex (for [`InputsDigest`]).
pub fn sha256_hex(bytes: &[u8]) -> String {
    hex(&Sha256::digest(bytes))
}

/// The fixed header of a model file.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Header {
    /// Format version.
    pub version: u32,
    /// Payload length in bytes.
    pub payload_len: u64,
    /// SHA-256 of the payload.
    pub payload_sha256: [u8; 32],
}

impl Header {
    /// The header of a payload (current version).
    pub fn for_payload(payload: &[u8]) -> Header {
        Header {
            version: FORMAT_VERSION,
            payload_len: payload.len() as u64,
            payload_sha256: Sha256::digest(payload).into(),
        }
    }

    /// The 52 header bytes.
    pub fn to_bytes(&self) -> [u8; HEADER_LEN] {
        let mut h = [0u8; HEADER_LEN];
        h[0..8].copy_from_slice(&MAGIC);
        h[8..12].copy_from_slice(&self.version.to_le_bytes());
        h[12..20].copy_from_slice(&self.payload_len.to_le_bytes());
        h[20..52].copy_from_slice(&self.payload_sha256);
        h
    }

    /// Parses and checks magic and version (not the payload).
    pub fn parse(bytes: &[u8]) -> Result<Header, FormatError> {
        if bytes.len() < HEADER_LEN {
            // A wrong magic is the more useful message when it is already visible.
            if bytes.len() >= 8 && bytes[..8] != MAGIC {
                return Err(FormatError::BadMagic {
                    found: first8(bytes),
                });
            }
            return Err(FormatError::TooShort { len: bytes.len() });
        }
        if bytes[..8] != MAGIC {
            return Err(FormatError::BadMagic {
                found: first8(bytes),
            });
        }
        let version = u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]);
        if !READ_VERSIONS.contains(&version) {
            return Err(FormatError::UnsupportedVersion {
                found: version,
                supported: FAILED_CHECK_FORMAT_VERSION,
            });
        }
        let mut len = [0u8; 8];
        len.copy_from_slice(&bytes[12..20]);
        let mut payload_sha256 = [0u8; 32];
        payload_sha256.copy_from_slice(&bytes[20..52]);
        Ok(Header {
            version,
            payload_len: u64::from_le_bytes(len),
            payload_sha256,
        })
    }
}

fn first8(bytes: &[u8]) -> [u8; 8] {
    let mut f = [0u8; 8];
    f.copy_from_slice(&bytes[..8]);
    f
}

/// The MessagePack payload of a model (named fields, deterministic).
pub fn encode_payload(model: &Model) -> Vec<u8> {
    // Serialising these plain structs (known-length maps and sequences) into a Vec cannot fail.
    rmp_serde::to_vec_named(model).expect("MessagePack serialisation of a Model is infallible")
}

/// Wraps a payload in the header: magic, version, length, SHA-256.
pub fn wrap_payload(payload: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(HEADER_LEN + payload.len());
    out.extend_from_slice(&Header::for_payload(payload).to_bytes());
    out.extend_from_slice(payload);
    out
}

/// The complete model file. Deterministic: the same model gives the same bytes.
///
/// Does not validate; a producer should call [`Model::validate`] first, since [`decode`] will.
pub fn encode(model: &Model) -> Vec<u8> {
    let payload = encode_payload(model);
    let mut header = Header::for_payload(&payload);
    header.version = version_of(model);
    let mut out = Vec::with_capacity(HEADER_LEN + payload.len());
    out.extend_from_slice(&header.to_bytes());
    out.extend_from_slice(&payload);
    out
}

/// Reads a model file: checks magic, version, length, SHA-256, the MessagePack structure,
/// then [`Model::validate`]. Typed errors, never a panic, on any byte string.
pub fn decode(bytes: &[u8]) -> Result<Model, FormatError> {
    let header = Header::parse(bytes)?;
    let present = (bytes.len() - HEADER_LEN) as u64;
    if present < header.payload_len {
        return Err(FormatError::Truncated {
            expected: header.payload_len,
            found: present,
        });
    }
    if present > header.payload_len {
        return Err(FormatError::TrailingBytes {
            expected: header.payload_len,
            extra: present - header.payload_len,
        });
    }
    let payload = &bytes[HEADER_LEN..];
    let digest: [u8; 32] = Sha256::digest(payload).into();
    if digest != header.payload_sha256 {
        return Err(FormatError::HashMismatch {
            expected: hex(&header.payload_sha256),
            found: hex(&digest),
        });
    }
    let model = decode_payload(payload)?;
    let needed = version_of(&model);
    if header.version != needed {
        let failed = model
            .tier
            .as_ref()
            .is_some_and(|t| t.failed_check.is_some());
        let (path, message) = if needed == FAILED_CHECK_FORMAT_VERSION {
            (
                "tier.failed_check",
                format!(
                    "a version {} file must not carry a tier that failed its check (version {needed})",
                    header.version
                ),
            )
        } else if header.version == FAILED_CHECK_FORMAT_VERSION && !failed {
            (
                "tier.failed_check",
                format!(
                    "a version {} file must carry a tier that failed its check",
                    header.version
                ),
            )
        } else {
            (
                "contact",
                format!(
                    "a version {} file {} a contact region",
                    header.version,
                    if model.contact.is_some() {
                        "must not carry"
                    } else {
                        "must carry"
                    }
                ),
            )
        };
        return Err(FormatError::Invalid {
            path: path.into(),
            message,
        });
    }
    model.validate()?;
    Ok(model)
}

/// Deserialises a payload (no header, no validation); rejects trailing bytes.
pub fn decode_payload(payload: &[u8]) -> Result<Model, FormatError> {
    use serde::Deserialize;
    let mut de = rmp_serde::Deserializer::from_read_ref(payload);
    let model = Model::deserialize(&mut de).map_err(|e| FormatError::MessagePack(e.to_string()))?;
    // Exactly one value: reading another marker must hit the end of the payload.
    match serde::de::IgnoredAny::deserialize(&mut de) {
        Err(rmp_serde::decode::Error::InvalidMarkerRead(e))
            if e.kind() == std::io::ErrorKind::UnexpectedEof =>
        {
            Ok(model)
        }
        _ => Err(FormatError::MessagePack(
            "unexpected data after the model in the payload".into(),
        )),
    }
}
