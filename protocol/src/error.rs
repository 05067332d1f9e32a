//! [`ProtocolError`]: everything that can be wrong with a message crossing a process boundary.
//! Receivers turn these into a refused message and a counted, logged drop; never a panic.

/// A malformed, mismatched or unsupported message.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ProtocolError {
    /// The peer was built with another protocol version.
    #[error(
        "protocol version mismatch: this process speaks version {expected}, the message carries version {found}; \
         run all processes from the same build"
    )]
    VersionMismatch {
        /// [`crate::PROTOCOL_VERSION`] of this process.
        expected: u32,
        /// The version found in the message.
        found: u32,
    },
    /// Weights were produced for another network layout.
    #[error("weights layout hash mismatch: expected {expected:#018x}, received {found:#018x}; the sender's networks differ from ours")]
    LayoutHashMismatch {
        /// Hash of this process's networks.
        expected: u64,
        /// Hash carried by the message.
        found: u64,
    },
    /// A length (payload, field, record) differs from what the header or layout says.
    #[error("{what}: expected length {expected}, found {found}")]
    LengthMismatch {
        /// Which length.
        what: String,
        /// What the header or layout implies.
        expected: usize,
        /// What was received.
        found: usize,
    },
    /// A NaN or infinite value in numeric data.
    #[error("non-finite value {value} in `{field}` at index {index}")]
    NonFinite {
        /// The record field.
        field: &'static str,
        /// Index inside the field (or inside the message's point list).
        index: usize,
        /// The offending value.
        value: f32,
    },
    /// A boolean stored as f32 is neither 0.0 nor 1.0.
    #[error("`{field}` must be 0 or 1, found {value}")]
    InvalidFlag {
        /// The record field.
        field: &'static str,
        /// The offending value.
        value: f32,
    },
    /// An enum code (u32 on the wire) that this version does not know.
    #[error("unknown {what} code {code}")]
    UnknownCode {
        /// The enum's name.
        what: &'static str,
        /// The received code.
        code: u32,
    },
    /// Flag bits that this version does not define.
    #[error("unknown {what} bits {bits:#x}")]
    UnknownFlags {
        /// The flag set's name.
        what: &'static str,
        /// The unknown bits.
        bits: u32,
    },
    /// Header dimensions that cannot describe a valid record.
    #[error("invalid dimensions: {0}")]
    InvalidDims(String),
    /// postcard could not encode a value.
    #[error("cannot encode {what}: {message}")]
    Encode {
        /// The type being encoded.
        what: &'static str,
        /// postcard's message.
        message: String,
    },
    /// Bytes that are not a valid postcard encoding of the expected type.
    #[error("malformed {what}: {message}")]
    Decode {
        /// The type being decoded.
        what: &'static str,
        /// postcard's message, or the number of trailing bytes.
        message: String,
    },
    /// A metric name that does not fit the fixed-size field or has bad characters.
    #[error("metric name {name:?}: {reason}")]
    InvalidMetricName {
        /// The rejected name (lossy if it was not UTF-8).
        name: String,
        /// Why.
        reason: String,
    },
}
