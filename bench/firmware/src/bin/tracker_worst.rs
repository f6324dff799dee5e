//! The whole tracker on scenario `worst` (see `stjpdacf_tools::fwscenario`), from
//! `scenarios/worst.stjf`.
#![no_std]
#![no_main]

use panic_semihosting as _;

stjpdacf_firmware::scenario_main!(run_tracker(
    "worst",
    include_bytes!("../../scenarios/worst.stjf"),
));
