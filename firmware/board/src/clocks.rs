//! Clock tree of the NUCLEO-H743ZI2.
//!
//! The board's ST-LINK feeds its 8 MHz MCO into the H743's OSC_IN (HSE in bypass mode, no
//! crystal fitted in the default solder-bridge setting). PLL1 makes 400 MHz for the core:
//! the highest frequency that voltage scale 1 allows on every silicon revision (480 MHz needs
//! VOS0, revision V only, and buys nothing for this workload).
//!
//! | clock | frequency | used by |
//! |---|---|---|
//! | SYSCLK (PLL1P) | 400 MHz | Cortex-M7 |
//! | HCLK (AHB) | 200 MHz | AXI SRAM, Ethernet MAC/DMA, DMA1/2 |
//! | APB1..APB4 | 100 MHz | USARTs, timers' bus side |
//! | APB1/APB2 timer clocks | 200 MHz | TIM2 (steps), TIM5 (embassy-time), TIM15 (gripper) |
//! | HSI48 | 48 MHz | RNG (network stack seed) |
//!
//! The ST-LINK's MCO exists only while the ST-LINK part of the board runs, and embassy waits
//! for HSE-ready without a limit. So [`probe_hse`] asks first, with a bounded wait
//! (board-logic's `clock` module), and [`config`] falls back to the internal 64 MHz HSI
//! (64 / 4 = 16 MHz PLL input, x50 = 800 MHz VCO, /2 = 400 MHz: the same tree) when it is
//! missing. `main` logs which one runs: "clock: HSE 8 MHz (ST-LINK MCO)" or
//! "clock: HSE missing, running on HSI".

use embassy_stm32::Config;
use embassy_stm32::pac;
use embassy_stm32::rcc::{
    AHBPrescaler, APBPrescaler, Hse, HseMode, Pll, PllDiv, PllMul, PllPreDiv, PllSource, Sysclk,
    VoltageScale,
};
use embassy_stm32::time::Hertz;

pub use board_logic::clock::ClockSource;
use board_logic::clock::{HSE_READY_POLLS, choose_source, wait_ready};

/// Frequency of the ST-LINK MCO that drives HSE.
const HSE_HZ: u32 = 8_000_000;

/// CPU cycles between two polls of HSE-ready: 1 us at the 64 MHz HSI the chip boots on.
const CYCLES_PER_POLL: u32 = 64;

/// Starts HSE in bypass mode and waits for it at most `HSE_READY_POLLS` us (10 ms); stops
/// it again (embassy's clock setup starts it for real), and says which source to use.
/// Call before `embassy_stm32::init`, on the reset clock tree.
pub fn probe_hse() -> ClockSource {
    let rcc = pac::RCC;
    rcc.cr().modify(|w| w.set_hseon(false));
    rcc.cr().modify(|w| w.set_hsebyp(true));
    rcc.cr().modify(|w| w.set_hseon(true));
    let ready = wait_ready(
        || rcc.cr().read().hserdy(),
        HSE_READY_POLLS,
        || cortex_m::asm::delay(CYCLES_PER_POLL),
    );
    rcc.cr().modify(|w| w.set_hseon(false));
    // HSEBYP may only change while HSE is off and not ready (RM0433 RCC_CR).
    wait_ready(
        || !rcc.cr().read().hserdy(),
        HSE_READY_POLLS,
        || cortex_m::asm::delay(CYCLES_PER_POLL),
    );
    rcc.cr().modify(|w| w.set_hsebyp(false));
    choose_source(ready)
}

/// The clock configuration described in the module documentation, on `source`.
pub fn config(source: ClockSource) -> Config {
    let mut config = Config::default();
    let rcc = &mut config.rcc;
    rcc.hsi48 = Some(Default::default());
    rcc.pll1 = Some(match source {
        ClockSource::Hse => {
            rcc.hse = Some(Hse {
                freq: Hertz(HSE_HZ),
                mode: HseMode::Bypass,
            });
            // 8 MHz / 2 = 4 MHz PLL input, x200 = 800 MHz VCO, /2 = 400 MHz.
            Pll {
                source: PllSource::HSE,
                prediv: PllPreDiv::DIV2,
                mul: PllMul::MUL200,
                fracn: None,
                divp: Some(PllDiv::DIV2),
                divq: None,
                divr: None,
            }
        }
        // 64 MHz / 4 = 16 MHz PLL input, x50 = 800 MHz VCO, /2 = 400 MHz.
        ClockSource::HsiFallback => Pll {
            source: PllSource::HSI,
            prediv: PllPreDiv::DIV4,
            mul: PllMul::MUL50,
            fracn: None,
            divp: Some(PllDiv::DIV2),
            divq: None,
            divr: None,
        },
    });
    rcc.sys = Sysclk::PLL1_P;
    rcc.ahb_pre = AHBPrescaler::DIV2;
    rcc.apb1_pre = APBPrescaler::DIV2;
    rcc.apb2_pre = APBPrescaler::DIV2;
    rcc.apb3_pre = APBPrescaler::DIV2;
    rcc.apb4_pre = APBPrescaler::DIV2;
    rcc.voltage_scale = VoltageScale::Scale1;
    config
}
