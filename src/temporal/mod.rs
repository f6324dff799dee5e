//! The temporal side of the tracker (docs/design.md §1 steps 3–5, 4.2, 4.3, 5).
//!
//! * [`identity`] — lane identity: assigns each frame's spatial lanes
//!   ([`crate::spatial::filter::LaneObservation`]) to the temporal lanes by gating in curve space
//!   and an optimal, bounded assignment; starts, coasts and removes lanes; keeps stable ids.

pub mod filter;
pub mod identity;
pub mod smoother;
