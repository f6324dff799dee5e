//! Prints the memory cost of the core's types at the reference configuration (bytes):
//! `cargo run -p stjpdacf-test-support --example sizes`.
use std::mem::size_of;

/// Prints `<label>: <size of the type> B`.
macro_rules! size {
    ($label:literal, $t:ty) => {
        println!(concat!($label, ": {} B"), size_of::<$t>())
    };
}

fn main() {
    size!(
        "ReferenceTables (flash, one static)",
        stjpdacf::tables::ReferenceTables
    );
    size!("spatial::Stacked<3, 6>", stjpdacf::spatial::Stacked<3, 6>);
    size!("spatial::filter::SpatialFilter<3, 6, 64, 16>", stjpdacf::spatial::filter::SpatialFilter<3, 6, 64, 16>);
    size!(
        "spatial::filter::LaneObservation<16> (one per lane of output)",
        stjpdacf::spatial::filter::LaneObservation<16>
    );
    size!(
        "spatial::row::RowOutcome<6> (one per pass)",
        stjpdacf::spatial::row::RowOutcome<6>
    );
    size!("temporal::filter::TemporalFilter<6, 16, 7, 84>", stjpdacf::temporal::filter::TemporalFilter<6, 16, 7, 84>);
    size!(
        "temporal::identity::LaneTable<6>",
        stjpdacf::temporal::identity::LaneTable<6>
    );
    size!("temporal::smoother::Temporal<6, 16, 7, 84, 42, 4> (filter + L = 4 window)", stjpdacf::temporal::smoother::Temporal<6, 16, 7, 84, 42, 4>);
    size!(
        "persist::Persist<6, 16, 64> (the known-lane stage)",
        stjpdacf::persist::Persist<6, 16, 64>
    );
    size!(
        "persist::PassMemory<7, 6> (the known-lane pass's working memory)",
        stjpdacf::persist::PassMemory<7, 6>
    );
    size!(
        "tracker::ReferenceTracker (the whole tracker)",
        stjpdacf::tracker::ReferenceTracker
    );
}
