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

use embassy_stm32::Config;
use embassy_stm32::rcc::{
    AHBPrescaler, APBPrescaler, Hse, HseMode, Pll, PllDiv, PllMul, PllPreDiv, PllSource, Sysclk,
    VoltageScale,
};
use embassy_stm32::time::Hertz;

/// Frequency of the ST-LINK MCO that drives HSE.
const HSE_HZ: u32 = 8_000_000;

/// The clock configuration described in the module documentation.
pub fn config() -> Config {
    let mut config = Config::default();
    let rcc = &mut config.rcc;
    rcc.hse = Some(Hse {
        freq: Hertz(HSE_HZ),
        mode: HseMode::Bypass,
    });
    rcc.hsi48 = Some(Default::default());
    // 8 MHz / 2 = 4 MHz PLL input, x200 = 800 MHz VCO, /2 = 400 MHz.
    rcc.pll1 = Some(Pll {
        source: PllSource::HSE,
        prediv: PllPreDiv::DIV2,
        mul: PllMul::MUL200,
        fracn: None,
        divp: Some(PllDiv::DIV2),
        divq: None,
        divr: None,
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
