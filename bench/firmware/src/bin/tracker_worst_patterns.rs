//! The whole tracker on scenario `worst_patterns` (see `stjpdacf_tools::fwscenario`), from
//! `scenarios/worst_patterns.stjf`.
#![no_std]
#![no_main]

use panic_semihosting as _;

#[cortex_m_rt::entry]
fn main() -> ! {
    match cortex_m::Peripherals::take() {
        Some(p) => stjpdacf_firmware::run_tracker(
            "worst_patterns",
            include_bytes!("../../scenarios/worst_patterns.stjf"),
            p.SYST,
        ),
        None => loop {
            cortex_m::asm::nop();
        },
    }
}
