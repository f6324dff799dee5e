//! The whole tracker on scenario `typical`, printing every lane of every frame exactly: the
//! reference output of the C API's Cortex-M4F example (`capi/examples/m4f`, compared by
//! `cargo xtask capi`). Not a benchmark: `cargo xtask firmware` leaves it out.
#![no_std]
#![no_main]

use panic_semihosting as _;

stjpdacf_firmware::scenario_main!(run_lanes(
    "typical",
    include_bytes!("../../scenarios/typical.stjf"),
));
