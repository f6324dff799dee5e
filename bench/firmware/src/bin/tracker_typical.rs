//! The whole tracker on scenario `typical` (see `stjpdacf_tools::fwscenario`), from
//! `scenarios/typical.stjf`.
#![no_std]
#![no_main]

use panic_semihosting as _;

stjpdacf_firmware::scenario_main!(run_tracker(
    "typical",
    include_bytes!("../../scenarios/typical.stjf"),
));
