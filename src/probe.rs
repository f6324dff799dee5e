//! Stage probes: where a frame's work goes.
//!
//! [`crate::tracker::Tracker::step_probed`] calls [`Probe::enter`] each time the pipeline moves
//! from one stage to the next (several times per BEV row for the spatial stages). A probe that
//! reads a cycle or instruction counter at each call can charge the work between two calls to the
//! stage that was entered first: that is how the firmware measures instruction counts per stage.
//! [`NoProbe`] compiles to nothing; [`crate::tracker::Tracker::step`] uses it.
//!
//! ```
//! use stjpdacf::probe::{Probe, Stage};
//! /// Counts how often each stage is entered.
//! struct Count([u32; Stage::COUNT]);
//! impl Probe for Count {
//!     fn enter(&mut self, stage: Stage) {
//!         if let Some(c) = self.0.get_mut(stage as usize) {
//!             *c += 1;
//!         }
//!     }
//! }
//! let mut c = Count([0; Stage::COUNT]);
//! c.enter(Stage::Gating);
//! assert_eq!(c.0[Stage::Gating as usize], 1);
//! ```

/// A stage of the per-frame pipeline.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[repr(u8)]
pub enum Stage {
    /// Input checks and binning of the points into BEV rows.
    Binning = 0,
    /// Spatial prediction from one row to the next.
    RowPredict = 1,
    /// Spatial gating (and the joint innovation covariance of the row).
    Gating = 2,
    /// Joint-event enumeration, weights and mixture moments (with pruning when over budget).
    Events = 3,
    /// The coupled moment-matched state update of the row.
    Update = 4,
    /// Spatial track management: initiation, confirmation, ending, merging, history records.
    Management = 5,
    /// The spatial backward (RTS) pass and the pseudo-measurements.
    Backward = 6,
    /// Lane identity (association of spatial lanes to temporal lanes).
    Identity = 7,
    /// The temporal coupled filter (prediction, lane starts, updates).
    Temporal = 8,
    /// The fixed-lag smoother's window.
    Smoother = 9,
    /// Output assembly (filtered and smoothed lanes).
    Output = 10,
    /// The known lanes' association against their temporal prediction, their evidence and
    /// existence (docs/design.md §11, [`crate::persist`]).
    Known = 11,
    /// The frame is done (nothing is charged after this).
    Done = 12,
}

impl Stage {
    /// Number of stages.
    pub const COUNT: usize = 13;

    /// Every stage, in order.
    pub const ALL: [Stage; Stage::COUNT] = [
        Stage::Binning,
        Stage::RowPredict,
        Stage::Gating,
        Stage::Events,
        Stage::Update,
        Stage::Management,
        Stage::Backward,
        Stage::Identity,
        Stage::Temporal,
        Stage::Smoother,
        Stage::Output,
        Stage::Known,
        Stage::Done,
    ];

    /// A short lower-case name (for reports).
    pub const fn name(self) -> &'static str {
        match self {
            Stage::Binning => "binning",
            Stage::RowPredict => "row_predict",
            Stage::Gating => "gating",
            Stage::Events => "events",
            Stage::Update => "update",
            Stage::Management => "management",
            Stage::Backward => "backward",
            Stage::Identity => "identity",
            Stage::Temporal => "temporal",
            Stage::Smoother => "smoother",
            Stage::Output => "output",
            Stage::Known => "known",
            Stage::Done => "done",
        }
    }
}

/// Receives stage transitions.
pub trait Probe {
    /// The pipeline enters `stage` now.
    fn enter(&mut self, stage: Stage);
}

/// The probe that does nothing (compiled away).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct NoProbe;

impl Probe for NoProbe {
    #[inline(always)]
    fn enter(&mut self, _stage: Stage) {}
}
