//! The wire contract of ASI and its configuration tree.
//!
//! - [`config`]: the [`Config`] tree (defaults < TOML < `--set`), validated once, every problem
//!   reported at once.
//! - [`services`]: iceoryx2 service names under the per-run namespace `asi/<run-id>/…`.
//! - [`payload`]: fixed-layout (`#[repr(C)]`, `ZeroCopySend`) headers and messages, id newtypes,
//!   [`check_version`].
//! - [`step`]: the f32 record of one env step inside a trajectory chunk ([`StepLayout`]).
//! - [`graph`]: graph-service requests and responses (postcard bodies, fixed headers).
//! - [`transport`]: iceoryx2 slice channels with wake-up events (publisher, subscriber).
//!
//! Invariants: every header or message carries [`PROTOCOL_VERSION`] and receivers refuse
//! another version with an error naming both; decoding never panics on malformed input.
//! This crate knows nothing of candle or rapier.

pub mod config;
pub mod error;
pub mod graph;
pub mod payload;
pub mod services;
pub mod step;
pub mod transport;

pub use config::{Config, ConfigError, ConfigErrors, ConfigIssue};
pub use error::ProtocolError;
pub use graph::{decode, encode, GraphRequest, GraphResponse, LatentPoint};
pub use payload::{
    check_version, ActorId, ControlCommand, ControlMessage, EpisodeId, MetricsSample, PhiVersion,
    PolicyVersion, ProcessRole, ProgressMessage, RunSchedule, TrajectoryFlags, TrajectoryHeader,
    Versioned, WeightsHeader,
};
pub use services::{RunId, RunIdError, Service};
pub use step::{DecisionKind, StepLayout, StepRecord, StepView};

/// Version of the wire format. Bump it whenever a payload type, header, step record layout or
/// postcard message changes shape or meaning; processes of different versions refuse each other.
pub const PROTOCOL_VERSION: u32 = 3;

/// FNV-1a 64-bit offset basis.
const FNV_OFFSET: u64 = 0xcbf2_9ce4_8422_2325;
/// FNV-1a 64-bit prime.
const FNV_PRIME: u64 = 0x0000_0100_0000_01b3;

/// Hash of a network layout: which tensors exist and their shapes, not their values.
///
/// Each tensor becomes the string `"<name>:<d0>x<d1>x…"` (a scalar is `"<name>:"`); the strings
/// are sorted bytewise, and FNV-1a 64 runs over them in order, each followed by a `\n` byte (so
/// that `["ab", "c"]` and `["a", "bc"]` differ). The result is independent of input order.
/// Sender and receiver compare it before loading weights ([`WeightsHeader::check`]).
pub fn layout_hash<'a>(names_and_shapes: impl IntoIterator<Item = (&'a str, &'a [usize])>) -> u64 {
    let mut entries: Vec<String> = names_and_shapes
        .into_iter()
        .map(|(name, shape)| {
            let dims: Vec<String> = shape.iter().map(usize::to_string).collect();
            format!("{name}:{}", dims.join("x"))
        })
        .collect();
    entries.sort_unstable();
    entries.iter().fold(FNV_OFFSET, |hash, entry| {
        let bytes = entry.bytes().chain(std::iter::once(b'\n'));
        bytes.fold(hash, fnv1a_step)
    })
}

/// One FNV-1a step: xor the byte in, multiply by the prime.
fn fnv1a_step(hash: u64, byte: u8) -> u64 {
    (hash ^ u64::from(byte)).wrapping_mul(FNV_PRIME)
}
