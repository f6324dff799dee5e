//! The whole tracker on scenario `worst_patterns` (see `stjpdacf_tools::fwscenario`), from
//! `scenarios/worst_patterns.stjf`.
#![no_std]
#![no_main]

use panic_semihosting as _;

stjpdacf_firmware::scenario_main!(run_tracker(
    "worst_patterns",
    include_bytes!("../../scenarios/worst_patterns.stjf"),
));
