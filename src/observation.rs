//! The contract between the spatial and the temporal stage: one frame's observation of a lane
//! (pseudo-measurements at the index points, docs/design.md §4.1 step 7) and the life stage of
//! the spatial track it comes from. Both stages depend on this module, not on each other.

use nalgebra::{SMatrix, SVector};

/// Life stage of a spatial track.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Status {
    /// Started from consistent points, not yet confirmed.
    Tentative,
    /// Confirmed by `confirm_hits` hits.
    Confirmed,
    /// Confirmed, then `max_misses` consecutive misses: takes no more points.
    Ended,
}

/// One confirmed lane of this frame, ready for the temporal filter.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LaneObservation<const POINTS: usize> {
    /// `Confirmed` or `Ended` (tentative tracks are not reported).
    pub status: Status,
    /// Index point `i` has a pseudo-measurement (inside the lane's observed extent).
    pub present: [bool; POINTS],
    /// Smoothed lateral position at each present index point, metres.
    pub z: SVector<f32, POINTS>,
    /// Covariance of the present pseudo-measurements (zero rows/columns for absent ones), m².
    pub cov: SMatrix<f32, POINTS, POINTS>,
    /// First row with support, metres ahead.
    pub u_first: f32,
    /// Last row with support, metres ahead.
    pub u_last: f32,
    /// Hits over the track's life divided by its rows (hits + misses).
    pub existence: f32,
    /// Rank from the left among this frame's tracks (B's slot at the end of the walk).
    pub rank: u8,
    /// The track's existence evidence over its observed extent: `Σ ln Λ_r` of its rows from
    /// its start to its last hit, each with the one-step-ahead prediction of the row walk and
    /// `P_D` = 0.5 (docs/design.md §11.8); its own starting point is not counted.
    pub llr: f32,
}

impl<const POINTS: usize> LaneObservation<POINTS> {
    /// A blank observation (tentative, no point present, all zero): the filler of output arrays.
    pub const EMPTY: Self = Self {
        status: Status::Tentative,
        present: [false; POINTS],
        z: SMatrix::from_array_storage(nalgebra::ArrayStorage([[0.0; POINTS]; 1])),
        cov: SMatrix::from_array_storage(nalgebra::ArrayStorage([[0.0; POINTS]; POINTS])),
        u_first: 0.0,
        u_last: 0.0,
        existence: 0.0,
        rank: 0,
        llr: 0.0,
    };
}
