//! The spatial JPDACF alone on every scenario (see `stjpdacf_tools::fwscenario`): it runs on the
//! reference MCU's memory map while the whole tracker does not fit yet.
#![no_std]
#![no_main]

use panic_semihosting as _;

stjpdacf_firmware::scenario_main!(run_spatial(&[
    ("typical", include_bytes!("../../scenarios/typical.stjf")),
    ("worst", include_bytes!("../../scenarios/worst.stjf")),
    (
        "worst_patterns",
        include_bytes!("../../scenarios/worst_patterns.stjf"),
    ),
]));
