//! The whole tracker on scenario `typical` (see `stjpdacf_tools::fwscenario`), from
//! `scenarios/typical.stjf`.
#![no_std]
#![no_main]

use panic_semihosting as _;

#[cortex_m_rt::entry]
fn main() -> ! {
    match cortex_m::Peripherals::take() {
        Some(p) => stjpdacf_firmware::run_tracker(
            "typical",
            include_bytes!("../../scenarios/typical.stjf"),
            p.SYST,
        ),
        None => loop {
            cortex_m::asm::nop();
        },
    }
}
