//! The gripper output: TIM15 channel 1 on PE5, with its DIR line on PE4.
//!
//! The host sends the timer's own registers (PSC, ARR, CCR1; PROTOCOL.md "Pwm (16 bytes)"), so
//! they are written as they come. The channel runs in PWM mode 2 with the compare value
//! `ARR + 1 - CCR1`: the output is high for the last CCR1 ticks of each period, which is
//! the requested duty, and low whenever the counter rests at 0, so a stopped timer always
//! leaves the line low.
//!
//! Stepper mode (a pulse count) uses the repetition counter: an update event, and so an
//! interrupt, comes only every `RCR + 1` periods, and in one-pulse mode the counter stops
//! by itself at the update event that ends the last burst. So the count is exact in
//! hardware and the interrupt only has to program the next burst while the current one
//! runs:
//! - up to 256 pulses: one burst, one-pulse mode from the start, no interrupt at all;
//! - more: bursts of 256, with the remainder split so that no burst is shorter than 128
//!   periods; the interrupt at the end of burst k (burst k + 1 is running) loads the size
//!   of burst k + 2 into RCR, or sets one-pulse mode when k + 1 is the last. It has at
//!   least 128 periods to do so.
//!
//! # Stops (issue 30)
//! A STOPPED or the wired e-stop input stops the gripper as the joints: the controller cuts
//! a counted burst (and a servo PWM under `ServoOnStop::Cut`) through [`Gripper::stop`].
//! Where the steps are halted before any task runs, [`cut_at_stop`] cuts the gripper too:
//! the wired input's interrupt (EXTI0, P0, right after the STEP outputs) and the receive
//! path's halt of a STOPPED (`arm_wiring::controller_tasks!`'s `halt_also`). It stops the
//! counter and forces the output low, two register writes, when [`CUT_AT_STOP`] says what
//! runs is to be cut. From EXTI0 it may preempt [`Gripper::start`] before that start's
//! critical section and be undone by it; the controller's stop for the same opening,
//! applied before the trajectory task handles anything else, then cuts it.
//!

use core::cell::Cell;
use core::sync::atomic::{AtomicBool, Ordering};

use arm_core::config::ServoOnStop;
use arm_core::hw::Gripper;

use board_logic::gripper::{next_burst, rcr_for};
use embassy_stm32::gpio::{Level, Output, OutputType, Speed};
use embassy_stm32::interrupt::{InterruptExt, Priority};
use embassy_stm32::peripherals::{PE4, PE5, TIM15};
use embassy_stm32::timer::Ch1;
use embassy_stm32::timer::low_level::Timer;
use embassy_stm32::timer::simple_pwm::PwmPin;
use embassy_stm32::{Peri, interrupt, pac};
use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;
use protocol::Pwm;

/// TIM15 status flags that exist (UIF, CC1IF, CC2IF, COMIF, TIF, BIF, CC1OF, CC2OF).
const SR_FLAGS: u32 = 0x06E7;
/// UIF.
const SR_UPDATE: u32 = 1 << 0;

/// Pulses of the current stepper-mode run not yet loaded into the repetition counter.
static UNLOADED_PULSES: Mutex<CriticalSectionRawMutex, Cell<u32>> = Mutex::new(Cell::new(0));

/// What runs is cut by a stop's own cut ([`cut_at_stop`]): a counted burst, or a servo PWM
/// under [`ServoOnStop::Cut`]. Set by `start`, cleared by `stop`.
static CUT_AT_STOP: AtomicBool = AtomicBool::new(false);

/// The gripper timer ([`arm_core::hw::Gripper`]).
pub struct GripperPwm {
    _timer: Timer<'static, TIM15>,
    _pin: PwmPin<'static, TIM15, Ch1>,
    dir: Output<'static>,
    clock_hz: u32,
    servo_on_stop: ServoOnStop,
}

impl GripperPwm {
    /// Takes TIM15, its channel 1 pin and the DIR pin; the output stays low until `start`.
    /// `servo_on_stop` is the controller's (`ControllerConfig::servo_on_stop`), for a
    /// stop's own cut ([`cut_at_stop`]).
    pub fn new(
        tim: Peri<'static, TIM15>,
        pwm_pin: Peri<'static, PE5>,
        dir_pin: Peri<'static, PE4>,
        servo_on_stop: ServoOnStop,
    ) -> Self {
        let timer = Timer::new(tim);
        let clock_hz = timer.get_clock_frequency().0;
        let pin = PwmPin::new(pwm_pin, OutputType::PushPull);
        let dir = Output::new(dir_pin, Level::Low, Speed::Low);

        let regs = pac::TIM15;
        // Only counter overflows raise update events; UG just loads the registers.
        regs.cr1()
            .write(|w| w.set_urs(pac::timer::vals::Urs::COUNTER_ONLY));
        regs.ccmr_output().modify(|w| {
            w.set_ocm(0, pac::timer::vals::Ocm::FORCE_INACTIVE);
            w.set_ocpe(0, true);
        });
        regs.ccer().modify(|w| w.set_cce(0, true));
        // The channel has a complementary output: its main output enable gates both.
        regs.bdtr().modify(|w| w.set_moe(true));

        interrupt::TIM15.set_priority(Priority::P2);
        // SAFETY: the handler touches only TIM15's registers and UNLOADED_PULSES.
        unsafe { interrupt::TIM15.enable() };
        GripperPwm {
            _timer: timer,
            _pin: pin,
            dir,
            clock_hz,
            servo_on_stop,
        }
    }
}

/// A stop's own cut of the gripper, before the controller's (see "Stops" above): when what
/// runs is to be cut ([`CUT_AT_STOP`]), the counter stopped and the output forced low at
/// once. A short critical section, as every other write of these registers (the burst
/// reloads' interrupt at P2 writes CR1 too); from EXTI0, at P0, it masks nothing more. The
/// burst's bookkeeping is reset by the controller's [`Gripper::stop`] that follows.
pub fn cut_at_stop() {
    if !CUT_AT_STOP.load(Ordering::SeqCst) {
        return;
    }
    let regs = pac::TIM15;
    critical_section::with(|_| {
        regs.cr1().modify(|w| w.set_cen(false));
        regs.ccmr_output()
            .modify(|w| w.set_ocm(0, pac::timer::vals::Ocm::FORCE_INACTIVE));
    });
}

impl Gripper for GripperPwm {
    fn timer_clock_hz(&self) -> u32 {
        self.clock_hz
    }

    fn start(&mut self, pwm: &Pwm) {
        self.stop();
        let regs = pac::TIM15;
        // Decode checked PSC, ARR <= 0xFFFF and CCR1 <= ARR; saturate anyway rather than
        // trust it.
        let psc = pwm.psc.min(0xFFFF) as u16;
        let arr = pwm.arr.min(0xFFFF);
        // CCR1 <= ARR keeps the compare value >= 1, so a resting counter (0) is low.
        let high_ticks = pwm.ccr1.min(arr);
        regs.psc().write_value(psc);
        regs.arr().write(|w| w.set_arr(arr as u16));
        // PWM mode 2 compare value: 1..=ARR, which fits 16 bits.
        let mode = if high_ticks == 0 {
            pac::timer::vals::Ocm::FORCE_INACTIVE
        } else {
            let compare = u16::try_from(arr + 1 - high_ticks).unwrap_or(u16::MAX);
            regs.ccr(0).write(|w| w.set_ccr(compare));
            pac::timer::vals::Ocm::PWM_MODE2
        };
        self.dir.set_level(Level::from(pwm.pulse_count >= 0));

        let pulses = pwm.pulse_count.unsigned_abs();
        let cut = self.servo_on_stop.cuts(pwm.pulse_count);
        critical_section::with(|cs| {
            CUT_AT_STOP.store(cut, Ordering::SeqCst);
            let unloaded = UNLOADED_PULSES.borrow(cs);
            if pulses == 0 {
                // Servo mode: run until stopped.
                regs.rcr().write(|w| w.set_rep(0));
                regs.egr().write(|w| w.set_ug(true));
                // Only now that the counter is back at 0, so the line starts low.
                regs.ccmr_output().modify(|w| w.set_ocm(0, mode));
                regs.cr1().modify(|w| {
                    w.set_opm(false);
                    w.set_cen(true);
                });
                return;
            }
            let first = next_burst(pulses);
            regs.rcr().write(|w| w.set_rep(rcr_for(first)));
            // Loads PSC, ARR, CCR1 and the repetition counter; the counter restarts at 0.
            regs.egr().write(|w| w.set_ug(true));
            let mut remaining = pulses - first;
            if remaining > 0 {
                // Preload the second burst: the repetition counter takes it at the end of
                // the first.
                let second = next_burst(remaining);
                regs.rcr().write(|w| w.set_rep(rcr_for(second)));
                remaining -= second;
            }
            unloaded.set(remaining);
            regs.ccmr_output().modify(|w| w.set_ocm(0, mode));
            regs.sr().write_value(pac::timer::regs::Sr2chCmp(0));
            regs.dier().write(|w| w.set_uie(first < pulses));
            regs.cr1().modify(|w| {
                w.set_opm(first == pulses);
                w.set_cen(true);
            });
        });
    }

    fn stop(&mut self) {
        let regs = pac::TIM15;
        critical_section::with(|cs| {
            CUT_AT_STOP.store(false, Ordering::SeqCst);
            regs.cr1().modify(|w| w.set_cen(false));
            regs.dier().write(|w| w.set_uie(false));
            regs.ccmr_output()
                .modify(|w| w.set_ocm(0, pac::timer::vals::Ocm::FORCE_INACTIVE));
            // FORCE_INACTIVE acts at once, without waiting for an update event.
            UNLOADED_PULSES.borrow(cs).set(0);
        });
    }

    fn is_active(&self) -> bool {
        // One-pulse mode clears CEN in hardware at the end of the last burst.
        pac::TIM15.cr1().read().cen()
    }
}

#[interrupt]
fn TIM15() {
    let regs = pac::TIM15;
    if !regs.sr().read().uif() {
        return;
    }
    // rc_w0: clear UIF only; other flags (and reserved bits) are written as their
    // no-effect values.
    regs.sr()
        .write_value(pac::timer::regs::Sr2chCmp(!SR_UPDATE & SR_FLAGS));
    critical_section::with(|cs| {
        let unloaded = UNLOADED_PULSES.borrow(cs);
        // A burst just ended and the next one (already loaded) is running.
        let remaining = unloaded.get();
        if remaining == 0 {
            // The running burst is the last: stop at its end.
            regs.cr1().modify(|w| w.set_opm(true));
            regs.dier().write(|w| w.set_uie(false));
        } else {
            let burst = next_burst(remaining);
            regs.rcr().write(|w| w.set_rep(rcr_for(burst)));
            unloaded.set(remaining - burst);
        }
    });
}
