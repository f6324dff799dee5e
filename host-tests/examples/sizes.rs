//! Prints the memory cost of the core's types at the reference configuration (bytes):
//! `cargo run -p stjpdacf-test-support --example sizes`.
use std::mem::size_of;

fn main() {
    println!(
        "ReferenceTables (flash, one static): {} B",
        size_of::<stjpdacf::tables::ReferenceTables>()
    );
    println!(
        "spatial::Stacked<3, 6>: {} B",
        size_of::<stjpdacf::spatial::Stacked<3, 6>>()
    );
    println!(
        "spatial::filter::SpatialFilter<3, 6, 64, 16>: {} B",
        size_of::<stjpdacf::spatial::filter::SpatialFilter<3, 6, 64, 16>>()
    );
    println!(
        "spatial::filter::LaneObservation<16> (one per lane of output): {} B",
        size_of::<stjpdacf::spatial::filter::LaneObservation<16>>()
    );
    println!(
        "spatial::row::RowOutcome<6> (stack, per row): {} B",
        size_of::<stjpdacf::spatial::row::RowOutcome<6>>()
    );
    println!(
        "temporal::filter::TemporalFilter<6, 16, 7, 84>: {} B",
        size_of::<stjpdacf::temporal::filter::TemporalFilter<6, 16, 7, 84>>()
    );
    println!(
        "temporal::identity::LaneTable<6>: {} B",
        size_of::<stjpdacf::temporal::identity::LaneTable<6>>()
    );
    println!(
        "temporal::smoother::Temporal<6, 16, 7, 84, 42, 4> (filter + L = 4 window): {} B",
        size_of::<stjpdacf::temporal::smoother::Temporal<6, 16, 7, 84, 42, 4>>()
    );
    println!(
        "tracker::ReferenceTracker (the whole tracker): {} B",
        size_of::<stjpdacf::tracker::ReferenceTracker>()
    );
}
