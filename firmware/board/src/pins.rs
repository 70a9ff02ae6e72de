//! Pin map of the NUCLEO-H743ZI2 (MB1364) as the arm controller uses it.
//!
//! Every pin is on a ST Zio connector (CN7-CN10), and none is one the board itself uses:
//! the RMII Ethernet (PA1, PA2, PA7, PB13, PC1, PC4, PC5, PG11, PG13), the ST-LINK (PA13,
//! PA14, PB3 SWD/SWO; PD8, PD9 virtual COM port; PH0 MCO), USB OTG (PA8-PA12, PG6, PG7),
//! the green and yellow LEDs (PB0, PE1) are left alone; the user button (PC13) is read once at boot (held: the authentication key is cleared, issue 21). The
//! red LED's PB14 is the encoder bus's UART4_DE (AF8; `encoder.rs`): UART4's other DE pin,
//! PA15, is joint 0's STEP.
//!
//! "Dnn" is the Zio name as CircuitPython's `nucleo_h743zi_2` board definition numbers the
//! MB1364's pins. The first-generation NUCLEO-H743ZI numbers several differently (and has
//! PF12-PF15 on Zio where the ZI2 has PG12, PG14, PE14, PF3), so check UM2407's connector
//! tables before wiring: the port pins below are what the firmware drives.
//!
//! | signal | pin | Zio | why there |
//! |---|---|---|---|
//! | STEP joint 0 | PA15 = TIM2_CH1 (AF1) | D20 | 32-bit timer: any gap up to 21 s in one period |
//! | STEP joint 1 | PA0 = TIM5_CH1 (AF2) | D32 | the other 32-bit timer (TIM5_CH2/CH3 are on the RMII pins PA1/PA2) |
//! | STEP joint 2 | PA6 = TIM3_CH1 (AF2) | D12 | 16-bit; CH1 so every joint's DMA burst has the same layout |
//! | STEP joint 3 | PD12 = TIM4_CH1 (AF2) | D36 | 16-bit |
//! | STEP joint 4 | PE9 = TIM1_CH1 (AF1) | D6 | 16-bit advanced timer (MOE set) |
//! | STEP joint 5 | PA5 = TIM8_CH1N (AF3) | D13 | TIM8_CH1 is PC6 (USART6 TX): its complementary output, driven alone, follows OC1REF |
//! | STEP joint 6 | PB8 = TIM16_CH1 (AF1) | D15 | 16-bit, one channel, own update DMA request |
//! | STEP joint 7 | PB9 = TIM17_CH1 (AF1) | D14 | 16-bit, one channel, own update DMA request |
//! | DIR joint 0..7 | PD0..PD7 | D67 D66 D48 D55 D54 D53 D52 D51 | one port, consecutive bits; changed by the step clock's compare interrupt at reversals only |
//! | ENABLE joint 0..7 | PF0 PF1 PF2 PF7 PF8 PF9 PG0 PG1 | D68 D69 D70 D62 D61 D63 D65 D64 | not speed critical: one pin at a time |
//! | ENABLE gripper | PE3 | D60 | next to the gripper's other two lines |
//! | gripper PWM | PE5 = TIM15_CH1 (AF4) | D58 | 16-bit timer with a repetition counter and one-pulse mode: counted bursts stop in hardware |
//! | gripper DIR | PE4 | D57 | |
//! | PIN0 / PIN1 | PG2 / PG3 | D49 / D50 | |
//! | serial TX / RX | PC6 / PC7 = USART6 (AF7) | D16 / D21 | |
//! | encoder bus TX / RX / DE | PC10 / PC11 / PB14 = UART4 (AF8) | - | RS-485, hardware DE; PB14 also lights LD3 (red) while sending |
//! | wired e-stop input | PC0, input with pull-up, EXTI line 0 | A1 | normally-closed contact to GND (open or broken wire: high, stop); EXTI0 is a vector of its own; `estop.rs`, docs/BOARD.md "Wired e-stop input" |
//!
//! The STEP timers and alternate functions are from the STM32H743 datasheet's (DS12110)
//! alternate-function table as embassy-stm32's generated pin traits give it (checked by
//! the compiler for these pins: `TimerPin<Ch1>` / `TimerComplementaryPin<Ch1>`). Every
//! joint has a timer of its own because each STEP period is reloaded by that timer's
//! update DMA (ARR and CCR1 per period, see `step_dma/`); TIM2 and TIM5 are the only
//! 32-bit ones, TIM12/13/14 have no DMA request, TIM15 is the gripper's, TIM6/7 have no
//! output. embassy-time runs on TIM12 and the step clock (DIR changes, end of run) on
//! TIM13, neither of which has a use for its pins here.
//!
//! ENABLE polarity: the common stepper drivers (A4988, DRV8825, TMC2208, TB6600 opto
//! inputs wired common-anode) take an active-low enable, so "enabled" drives the line low
//! ([`ENABLE_ACTIVE_LOW`]). DIR high = positive steps. STEP pulses are active high.

use embassy_stm32::gpio::{Level, Output, Speed};
use embassy_stm32::timer::{Ch1, TimerComplementaryPin, TimerPin};
use embassy_stm32::{Peri, pac, peripherals};
use static_cell::StaticCell;

use crate::MAX_JOINTS;

/// First bit of the DIR lines in GPIOD: joint `j` is PD(j).
pub const DIR_SHIFT: u32 = 0;
/// Every STEP line as (port, pin), joint order: the fault path makes them plain low
/// outputs, taking them from their timers.
pub const STEP_LINES: [(pac::gpio::Gpio, usize); MAX_JOINTS] = [
    (pac::GPIOA, 15),
    (pac::GPIOA, 0),
    (pac::GPIOA, 6),
    (pac::GPIOD, 12),
    (pac::GPIOE, 9),
    (pac::GPIOA, 5),
    (pac::GPIOB, 8),
    (pac::GPIOB, 9),
];
/// Whether an enabled driver's ENABLE line is low.
pub const ENABLE_ACTIVE_LOW: bool = true;

/// The STEP pins, each the CH1 (joint 5: CH1N) output of its joint's timer; the types say
/// which timer and channel, so a wrong pin does not compile.
pub struct StepPins {
    /// Joint 0: TIM2_CH1.
    pub joint0: Peri<'static, peripherals::PA15>,
    /// Joint 1: TIM5_CH1.
    pub joint1: Peri<'static, peripherals::PA0>,
    /// Joint 2: TIM3_CH1.
    pub joint2: Peri<'static, peripherals::PA6>,
    /// Joint 3: TIM4_CH1.
    pub joint3: Peri<'static, peripherals::PD12>,
    /// Joint 4: TIM1_CH1.
    pub joint4: Peri<'static, peripherals::PE9>,
    /// Joint 5: TIM8_CH1N.
    pub joint5: Peri<'static, peripherals::PA5>,
    /// Joint 6: TIM16_CH1.
    pub joint6: Peri<'static, peripherals::PB8>,
    /// Joint 7: TIM17_CH1.
    pub joint7: Peri<'static, peripherals::PB9>,
}

/// A STEP pin: its port, pin number and alternate function.
#[derive(Clone, Copy)]
struct AfPin {
    port: pac::gpio::Gpio,
    pin: usize,
    af: u8,
}

impl AfPin {
    /// `pin` as the timer output whose alternate function is `af`.
    fn new<P: embassy_stm32::gpio::Pin>(pin: &Peri<'static, P>, af: u8) -> Self {
        let port = match pin.port() {
            0 => pac::GPIOA,
            1 => pac::GPIOB,
            2 => pac::GPIOC,
            3 => pac::GPIOD,
            _ => pac::GPIOE,
        };
        AfPin {
            port,
            pin: usize::from(pin.pin()),
            af,
        }
    }
}

/// The alternate function that makes `P` CH1 of timer `T` (a pin that is not does not
/// compile).
fn ch1<T: embassy_stm32::timer::GeneralInstance4Channel, P: TimerPin<T, Ch1>>(
    pin: &Peri<'static, P>,
) -> AfPin {
    AfPin::new(pin, pin.af_num())
}

/// The alternate function that makes `P` CH1N of timer `T`.
fn ch1n<T: embassy_stm32::timer::AdvancedInstance4Channel, P: TimerComplementaryPin<T, Ch1>>(
    pin: &Peri<'static, P>,
) -> AfPin {
    AfPin::new(pin, pin.af_num())
}

impl StepPins {
    /// Switches every STEP pin to its timer output (very high speed, push-pull). The timers
    /// hold their outputs inactive until a run starts (`step_dma::init` runs first).
    pub fn into_timer_outputs(self) {
        let pins = [
            ch1::<peripherals::TIM2, _>(&self.joint0),
            ch1::<peripherals::TIM5, _>(&self.joint1),
            ch1::<peripherals::TIM3, _>(&self.joint2),
            ch1::<peripherals::TIM4, _>(&self.joint3),
            ch1::<peripherals::TIM1, _>(&self.joint4),
            ch1n::<peripherals::TIM8, _>(&self.joint5),
            ch1::<peripherals::TIM16, _>(&self.joint6),
            ch1::<peripherals::TIM17, _>(&self.joint7),
        ];
        for p in pins {
            p.port
                .ospeedr()
                .modify(|w| w.set_ospeedr(p.pin, pac::gpio::vals::Ospeedr::VERY_HIGH_SPEED));
            p.port
                .otyper()
                .modify(|w| w.set_ot(p.pin, pac::gpio::vals::Ot::PUSH_PULL));
            p.port.afr(p.pin / 8).modify(|w| w.set_afr(p.pin % 8, p.af));
            p.port
                .moder()
                .modify(|w| w.set_moder(p.pin, pac::gpio::vals::Moder::ALTERNATE));
        }
    }
}

/// The DIR lines of every joint, configured as fast push-pull outputs, low. The step
/// clock's interrupt drives them through GPIOD's BSRR, which needs no ownership; holding
/// the [`Output`]s keeps the pins configured and out of anyone else's hands.
pub struct DirPins {
    /// DIR, joint order (PD0..PD7).
    pub dir: [Peri<'static, embassy_stm32::gpio::AnyPin>; MAX_JOINTS],
}

/// The configured DIR outputs, kept for the program's life.
static DIR_OUTPUTS: StaticCell<[Output<'static>; MAX_JOINTS]> = StaticCell::new();

impl DirPins {
    /// Configures every DIR line as a low push-pull output. Call once.
    pub fn configure(self) {
        let [d0, d1, d2, d3, d4, d5, d6, d7] = self.dir;
        let out = |p| Output::new(p, Level::Low, Speed::VeryHigh);
        DIR_OUTPUTS.init([
            out(d0),
            out(d1),
            out(d2),
            out(d3),
            out(d4),
            out(d5),
            out(d6),
            out(d7),
        ]);
    }
}

/// Sets joint `joint`'s DIR line (true = positive steps) through BSRR: one store, atomic
/// with respect to every other pin of the port.
pub fn set_direction(joint: usize, positive: bool) {
    if joint >= MAX_JOINTS {
        return;
    }
    let bit = 1u32 << (DIR_SHIFT as usize + joint);
    let bsrr = if positive { bit } else { bit << 16 };
    pac::GPIOD.bsrr().write_value(pac::gpio::regs::Bsrr(bsrr));
}

/// Level of an ENABLE line for a driver that should be `enabled`.
pub const fn enable_level(enabled: bool) -> Level {
    if enabled == ENABLE_ACTIVE_LOW {
        Level::Low
    } else {
        Level::High
    }
}

/// PIN0, PIN1 and the nine ENABLE lines ([`arm_core::hw::Outputs`]).
pub struct OutputLines {
    user: [Output<'static>; 2],
    /// Joints 0..7, then the gripper.
    enable: [Output<'static>; MAX_JOINTS + 1],
}

/// The pins [`OutputLines`] drives.
pub struct OutputPins {
    /// PIN0 (PG2).
    pub pin0: Peri<'static, peripherals::PG2>,
    /// PIN1 (PG3).
    pub pin1: Peri<'static, peripherals::PG3>,
    /// ENABLE of joints 0..7 then the gripper: PF0 PF1 PF2 PF7 PF8 PF9 PG0 PG1, PE3.
    pub enable: [Peri<'static, embassy_stm32::gpio::AnyPin>; MAX_JOINTS + 1],
}

impl OutputLines {
    /// User pins low; drivers enabled (holding), as the controller boots
    /// (`Controller::new`: "drivers enabled").
    pub fn new(pins: OutputPins) -> Self {
        let out = |p, level| Output::new(p, level, Speed::Low);
        let on = enable_level(true);
        let [e0, e1, e2, e3, e4, e5, e6, e7, e8] = pins.enable;
        OutputLines {
            user: [
                out(pins.pin0.into(), Level::Low),
                out(pins.pin1.into(), Level::Low),
            ],
            enable: [
                out(e0, on),
                out(e1, on),
                out(e2, on),
                out(e3, on),
                out(e4, on),
                out(e5, on),
                out(e6, on),
                out(e7, on),
                out(e8, on),
            ],
        }
    }
}

impl arm_core::hw::Outputs for OutputLines {
    fn set_user_pin(&mut self, pin: u8, high: bool) {
        if let Some(line) = self.user.get_mut(usize::from(pin)) {
            line.set_level(Level::from(high));
        }
    }

    fn set_enabled(&mut self, enabled: u16) {
        for (bit, line) in self.enable.iter_mut().enumerate() {
            line.set_level(enable_level(enabled & (1 << bit) != 0));
        }
    }
}
