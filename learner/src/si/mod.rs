//! Hierarchical self-imitation (SI; paper Eq. 11–12, SPEC §6.7, digest §8).
//!
//! After `asi.si_start_episode` training episodes, once per completed training episode, the
//! learner takes one high-level and then one low-level imitation step, each on its own uniform
//! batch of (s_0, s_t, g) entries:
//! 1. φ(s_t), φ(s_0) and φ(g̃) (g̃ = s_t with its first `goal_dim` coordinates replaced by the
//!    goal xy) under the learner's current encoder;
//! 2. routes R = route(φ(s_t), φ(g̃)) from the graph-service, with the fallback to a random
//!    frontier seen from φ(s_0) ([`routes`]);
//! 3. a target index and reference indices along each usable route ([`indices`]);
//! 4. the losses ([`losses`]) and one Adam step of the level's policy optimiser.
//!
//! - [`buffer`]: the SI buffer (one entry per env step, episode starts stored once).
//! - [`indices`]: target index k and the low level's reference indices.
//! - [`losses`]: the two losses as pure functions.
//! - [`routes`]: the [`RouteSource`] abstraction the binary implements over the graph-service.
//! - [`step`]: [`SelfImitation`], the schedule, the two steps and their counters.

pub mod buffer;
pub mod indices;
pub mod losses;
pub mod routes;
pub mod step;

pub use buffer::{EpisodeRef, SiBuffer, SiBufferParts, SiEntry};
pub use indices::{reference_indices, target_index, MIN_HIGH_ROUTE_LEN, MIN_LOW_ROUTE_LEN};
pub use losses::{high_si_loss, low_si_loss, SiLossStats};
pub use routes::{NoRouteSource, RouteSource, RoutesReply};
pub use step::{SelfImitation, SiParams, SiSkip, SiStats, SI_PHI_MISMATCH_ATTEMPTS};
