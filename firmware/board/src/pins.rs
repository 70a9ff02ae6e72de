//! Pin map of the NUCLEO-H743ZI2 (MB1364) as the arm controller uses it.
//!
//! Every pin is on a ST Zio connector (CN7-CN10), and none is one the board itself uses:
//! the RMII Ethernet (PA1, PA2, PA7, PB13, PC1, PC4, PC5, PG11, PG13), the ST-LINK (PA13,
//! PA14, PB3 SWD/SWO; PD8, PD9 virtual COM port; PH0 MCO), USB OTG (PA8-PA12, PG6, PG7),
//! the LEDs (PB0, PE1, PB14) and the user button (PC13) are all left alone.
//!
//! "Dnn" is the Zio name as CircuitPython's `nucleo_h743zi_2` board definition numbers the
//! MB1364's pins. The first-generation NUCLEO-H743ZI numbers several differently (and has
//! PF12-PF15 on Zio where the ZI2 has PG12, PG14, PE14, PF3), so check UM2407's connector
//! tables before wiring: the port pins below are what the firmware drives.
//!
//! | signal | pin | Zio | why there |
//! |---|---|---|---|
//! | STEP joint 0..7 | PE8..PE15 | D42 D6 D40 D5 D39 D3 D4 D37 | one port, consecutive bits: one BSRR write raises or lowers any set of STEP lines |
//! | DIR joint 0..7 | PD0..PD7 | D67 D66 D48 D55 D54 D53 D52 D51 | one port, consecutive bits |
//! | ENABLE joint 0..7 | PF0 PF1 PF2 PF7 PF8 PF9 PG0 PG1 | D68 D69 D70 D62 D61 D63 D65 D64 | not speed critical: one pin at a time |
//! | ENABLE gripper | PE3 | D60 | next to the gripper's other two lines |
//! | gripper PWM | PE5 = TIM15_CH1 (AF4) | D58 | 16-bit timer with a repetition counter and one-pulse mode: counted bursts stop in hardware |
//! | gripper DIR | PE4 | D57 | |
//! | PIN0 / PIN1 | PG2 / PG3 | D49 / D50 | |
//! | serial TX / RX | PC6 / PC7 = USART6 (AF7) | D16 / D21 | |
//!
//! ENABLE polarity: the common stepper drivers (A4988, DRV8825, TMC2208, TB6600 opto
//! inputs wired common-anode) take an active-low enable, so "enabled" drives the line low
//! ([`ENABLE_ACTIVE_LOW`]). DIR high = positive steps. STEP pulses are active high.

use embassy_stm32::gpio::{Level, Output, Speed};
use embassy_stm32::{Peri, pac, peripherals};
use static_cell::StaticCell;

use crate::MAX_JOINTS;

/// First bit of the STEP lines in GPIOE: joint `j` is PE(8 + j).
pub const STEP_SHIFT: u32 = 8;
/// First bit of the DIR lines in GPIOD: joint `j` is PD(j).
pub const DIR_SHIFT: u32 = 0;
/// Whether an enabled driver's ENABLE line is low.
pub const ENABLE_ACTIVE_LOW: bool = true;

/// The STEP and DIR lines of every joint, configured as fast push-pull outputs. The step
/// timer interrupt drives them through the ports' BSRR registers, which need no ownership;
/// holding the [`Output`]s keeps the pins configured and out of anyone else's hands.
pub struct StepDirPins {
    /// STEP, joint order.
    pub step: [Peri<'static, embassy_stm32::gpio::AnyPin>; MAX_JOINTS],
    /// DIR, joint order.
    pub dir: [Peri<'static, embassy_stm32::gpio::AnyPin>; MAX_JOINTS],
}

/// The configured STEP/DIR outputs, kept for the program's life.
static STEP_DIR_OUTPUTS: StaticCell<[Output<'static>; 2 * MAX_JOINTS]> = StaticCell::new();

impl StepDirPins {
    /// Configures every line as a low push-pull output; returns the writer the step timer
    /// interrupt uses. Call once.
    pub fn into_writer(self) -> StepDirWriter {
        let [s0, s1, s2, s3, s4, s5, s6, s7] = self.step;
        let [d0, d1, d2, d3, d4, d5, d6, d7] = self.dir;
        // STEP edges of 2.5 us want sharp edges; DIR is less critical but cheap to match.
        let out = |p| Output::new(p, Level::Low, Speed::VeryHigh);
        STEP_DIR_OUTPUTS.init([
            out(s0),
            out(s1),
            out(s2),
            out(s3),
            out(s4),
            out(s5),
            out(s6),
            out(s7),
            out(d0),
            out(d1),
            out(d2),
            out(d3),
            out(d4),
            out(d5),
            out(d6),
            out(d7),
        ]);
        StepDirWriter { _private: () }
    }
}

/// Writes STEP and DIR through BSRR: one store per set of edges, atomic with respect to
/// every other pin of the port (no read-modify-write, so it never races other code).
pub struct StepDirWriter {
    _private: (),
}

impl arm_step::StepPins for StepDirWriter {
    fn set_direction(&mut self, joint: usize, positive: bool) {
        if joint >= MAX_JOINTS {
            return;
        }
        let bit = 1u32 << (DIR_SHIFT + joint as u32);
        let bsrr = if positive { bit } else { bit << 16 };
        pac::GPIOD.bsrr().write_value(pac::gpio::regs::Bsrr(bsrr));
    }

    fn step_high(&mut self, joints: arm_step::JointMask) {
        if joints != 0 {
            pac::GPIOE
                .bsrr()
                .write_value(pac::gpio::regs::Bsrr(u32::from(joints) << STEP_SHIFT));
        }
    }

    fn step_low(&mut self, joints: arm_step::JointMask) {
        if joints != 0 {
            pac::GPIOE.bsrr().write_value(pac::gpio::regs::Bsrr(
                u32::from(joints) << (STEP_SHIFT + 16),
            ));
        }
    }
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
