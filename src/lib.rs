//! Fixed-capacity spatio-temporal JPDA coupled filter (ST-JPDACF) for tracking lane lines on a
//! microcontroller. No heap, no `unsafe`, no panics, bounded work per frame.
//!
//! The model (see `docs/design.md` in the repository for the mathematics):
//!
//! * a lane is a curve `x = c + g(u)` in bird's-eye-view (BEV) coordinates, `u` metres ahead of
//!   the camera and `x` metres lateral from its axis (the origin is the camera's foot point, which
//!   the ray test of [`persist::ray`] relies on); `g` has an RBF Gaussian-process prior along `u`, run as a Taylor-order-`NT`
//!   state-space model ([`kernel::RbfStateSpace`]);
//! * lanes are coupled through a coregionalisation matrix `B` over lane slots (rank from the left);
//! * each index point `u^f_i` of each lane evolves in time as a Matérn-3/2 process
//!   ([`kernel::Matern32`]).
//!
//! Everything that needs a factorisation or a root finder is computed offline on the host and
//! stored in static [`tables::Tables`], which can live in flash.
//!
//! # Glossary
//! * `NT` — spatial state size (Taylor order of the RBF approximation).
//! * `LANES` (D) — lane slots; `POINTS` (N) — index points per lane; `MEAS` (M) — feature points per
//!   frame; `ROWS` (R_max) — BEV rows walked per frame; `EVENTS` (E) — joint events per row;
//!   `LAG` (L) — smoother lag in frames, 1..=[`temporal::smoother::MAX_LAG`] (7).
//!
//! # Contract
//! No function in this crate panics, for any finite or non-finite input: numerical failure is
//! returned as a value. The crate never allocates.
//!
//! # Feature flags
//! * `defmt` — derive `defmt::Format` on the configuration, report, error and wire types
//!   (`TrackerConfig`, `StepReport` and their parts; `Tables` prints its header); not on
//!   `LaneEstimate`, `StepOutput` or the stateful types (the crate itself logs nothing).
//!
//! # MSRV
//! Rust 1.85 (edition 2021, `core::error::Error`, inline `const` blocks).
#![cfg_attr(not(test), no_std)]
#![forbid(unsafe_code)]
#![deny(missing_docs)]

pub mod kernel;
pub mod linalg;
pub mod math;
pub mod observation;
pub mod persist;
pub mod probe;
pub mod spatial;
pub mod tables;
pub mod temporal;
pub mod time;
pub mod tracker;
pub mod wire;

/// The README's firmware example, compiled and run as a doctest (`cargo test --doc -p stjpdacf`).
#[cfg(doctest)]
#[doc = include_str!("../README.md")]
pub struct ReadmeDoctests;
