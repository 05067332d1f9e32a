//! The one error enum of the `nets` crate.
//!
//! Every variant names what it is about (a layer, a tensor) and carries the dimensions involved,
//! so that a shape bug reads as "high_policy.trunk.l0: expected input features = 31, got 29"
//! rather than a bare candle error.

use thiserror::Error;

/// Errors raised while building, running, saving or loading networks.
#[derive(Debug, Error)]
pub enum NetsError {
    /// An input tensor has the wrong number of dimensions.
    #[error("{layer}: expected a rank-{expected} input {expected_shape}, got shape {got:?}")]
    Rank {
        /// The layer or network that checked its input (its parameter prefix).
        layer: String,
        /// The rank it needs.
        expected: usize,
        /// A human-readable form of the expected shape, e.g. `[batch, 31]`.
        expected_shape: String,
        /// The shape it got.
        got: Vec<usize>,
    },
    /// An input tensor has the right rank but a wrong size along one dimension.
    #[error("{layer}: expected {what} = {expected}, got {got} (input shape {shape:?})")]
    Dim {
        /// The layer or network that checked its input (its parameter prefix).
        layer: String,
        /// Which dimension, e.g. `input features` or `ensemble size`.
        what: &'static str,
        /// The size it needs.
        expected: usize,
        /// The size it got.
        got: usize,
        /// The whole input shape.
        shape: Vec<usize>,
    },
    /// A network specification is unusable (zero sizes, non-finite scales, …).
    #[error("invalid network spec: {0}")]
    Spec(String),
    /// A tensor that the receiving parameter set has is absent from the payload.
    #[error("tensor `{name}` (shape {expected:?}) is missing from the safetensors payload")]
    MissingTensor {
        /// Parameter name.
        name: String,
        /// Its shape in the receiving set.
        expected: Vec<usize>,
    },
    /// The payload holds a tensor that the receiving parameter set does not have.
    #[error("safetensors payload has tensor `{name}` (shape {shape:?}) that the receiving parameter set lacks")]
    UnexpectedTensor {
        /// Parameter name.
        name: String,
        /// Its shape in the payload.
        shape: Vec<usize>,
    },
    /// A tensor's shape differs between the payload and the receiving parameter set.
    #[error(
        "tensor `{name}`: shape {got:?} in the payload, but the parameter set expects {expected:?}"
    )]
    ShapeMismatch {
        /// Parameter name.
        name: String,
        /// Shape in the receiving set.
        expected: Vec<usize>,
        /// Shape in the payload.
        got: Vec<usize>,
    },
    /// A tensor's element type differs from the receiving parameter's.
    #[error(
        "tensor `{name}`: dtype {got} in the payload, but the parameter set expects {expected}"
    )]
    DType {
        /// Parameter name.
        name: String,
        /// Dtype in the receiving set.
        expected: String,
        /// Dtype in the payload.
        got: String,
    },
    /// The bytes are not a valid safetensors buffer.
    #[error("invalid safetensors payload: {0}")]
    Safetensors(#[from] safetensors::SafeTensorError),
    /// An error from a candle tensor operation.
    #[error(transparent)]
    Candle(#[from] candle_core::Error),
}

/// Result alias for this crate.
pub type Result<T> = std::result::Result<T, NetsError>;
