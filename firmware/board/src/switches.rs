//! The limit and home switch inputs (issue 33): twelve pins, two per joint 0-5, each on an
//! EXTI line of its own (docs/BOARD.md, "Limit and home switches", has the pin map and why).
//! Input A of a joint is its home switch *and* its min limit (one switch at the min end,
//! fed to both inputs of arm-core's switch bank), input B its max limit.
//!
//! The path, as the wired e-stop's ([`crate::estop`]):
//! 1. An edge interrupts at P0 (EXTI1, EXTI2, EXTI3, EXTI9_5, EXTI15_10, all at P0, above
//!    the step lock). The handler ([`on_edges`]) stamps it with the controller's clock
//!    (embassy-time, the clock the trajectory task's debounce looks at), reads the pin, and
//!    for a limit becoming active, that is not active already and not masked by the homing
//!    cycle, stops every STEP output with register writes alone
//!    ([`crate::step_dma::kill_step_outputs`]). It records the edge and pends the step
//!    service.
//! 2. The step service (P2, may take the step lock; [`service`]) reads the joints' counts
//!    and feeds each recorded edge to arm-core's [`SwitchLine::edge`]: a trip halts the
//!    step backend there (positions unwound to the pulses played, no run until the
//!    controller took it) and wakes the trajectory task, which latches the controller.
//!
//! The handler's "would this trip" question (the input not active yet, the side not
//! masked) gets the same answer in the service, because nothing can change it in between:
//! the service is pended at P2 and runs before any thread-mode code, and only the service
//! feeds edges. A bounce inside the service's latency is not lost: an activation seen by
//! the handler is fed first (its own instant), then the level the pin reads then.
//!
//! Memory: the switch line (the bank, its queue of events) is about 2 KiB and AXI SRAM has
//! a few hundred bytes left, so it lives in SRAM1 (non-cacheable, a NOLOAD section written
//! once at boot by [`start`]); AXI SRAM keeps only the pointer to it.

use core::cell::RefCell;
use core::mem::MaybeUninit;
use core::ptr::addr_of_mut;
use core::sync::atomic::{AtomicPtr, Ordering};

use arm_core::switch_line::SwitchLine;
use arm_core::switches::{InputConfig, PerSwitch, Side, Switch, SwitchConfig};
use embassy_stm32::interrupt::{InterruptExt, Priority};
use embassy_stm32::pac::gpio::vals::{Idr, Moder, Pupdr};
use embassy_stm32::{Peri, interrupt, pac, peripherals};
use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::blocking_mutex::raw::CriticalSectionRawMutex;

use crate::step_dma::STEP;
use crate::step_timer::STEP_TIMER;

/// What one input is to its joint.
#[derive(Clone, Copy, PartialEq, Eq)]
enum Role {
    /// The home switch and the min limit (one switch at the min end of travel).
    HomeAndMin,
    /// The max limit.
    Max,
}

/// One switch input: where it is and how it is wired.
#[derive(Clone, Copy)]
struct Input {
    /// GPIO port: 0 = A, 1 = B, 4 = E (SYSCFG_EXTICR's numbering).
    port: u8,
    /// Pin number, and so the EXTI line.
    pin: u8,
    /// The joint (0-based).
    joint: u8,
    /// Which inputs of the joint's switch bank it feeds.
    role: Role,
    /// The level that means active (tripped): high for the recommended normally closed
    /// switch to GND with the pull-up (a broken wire reads tripped too).
    active_high: bool,
    /// The pin's internal pull.
    pull: Pupdr,
}

const PORT_A: u8 = 0;
const PORT_B: u8 = 1;
const PORT_E: u8 = 4;

/// The recommended wiring: normally closed to GND, pull-up, active high.
const fn nc(port: u8, pin: u8, joint: u8, role: Role) -> Input {
    Input {
        port,
        pin,
        joint,
        role,
        active_high: true,
        pull: Pupdr::PULL_UP,
    }
}

/// Inputs fitted (docs/BOARD.md's pin map). Polarity and pull are per input: a normally
/// open switch to 3.3 V would be `active_high: true` with `Pupdr::PULL_DOWN`.
const INPUTS: [Input; 12] = [
    nc(PORT_E, 2, 0, Role::HomeAndMin),
    nc(PORT_A, 3, 0, Role::Max),
    nc(PORT_E, 6, 1, Role::HomeAndMin),
    nc(PORT_E, 7, 1, Role::Max),
    nc(PORT_E, 8, 2, Role::HomeAndMin),
    nc(PORT_B, 1, 2, Role::Max),
    nc(PORT_E, 10, 3, Role::HomeAndMin),
    nc(PORT_E, 11, 3, Role::Max),
    nc(PORT_E, 12, 4, Role::HomeAndMin),
    nc(PORT_E, 13, 4, Role::Max),
    nc(PORT_E, 14, 5, Role::HomeAndMin),
    nc(PORT_E, 15, 5, Role::Max),
];

/// How long an input must read released before it counts, microseconds: mechanical
/// switches bounce for 0.5-1 ms.
const DEBOUNCE_US: u32 = 2_000;

/// The EXTI lines of [`INPUTS`], as a mask.
#[allow(clippy::indexing_slicing)] // evaluated at compile time: out of range fails the build
const LINES: u32 = {
    let mut mask = 0;
    let mut i = 0;
    while i < INPUTS.len() {
        mask |= 1 << INPUTS[i].pin;
        i += 1;
    }
    mask
};

// Each input on an EXTI line of its own, none on the e-stop's line 0, at most 16 inputs
// (the `u16` masks of `Pending`): checked when the table changes.
const _: () =
    assert!(LINES.count_ones() as usize == INPUTS.len() && LINES & 1 == 0 && INPUTS.len() <= 16);

/// arm-core's switch bank configuration for [`INPUTS`].
#[allow(clippy::indexing_slicing)] // evaluated at compile time: out of range fails the build
const CONFIG: SwitchConfig = {
    let mut config = SwitchConfig::NONE;
    let mut i = 0;
    while i < INPUTS.len() {
        let input = INPUTS[i];
        let fitted = InputConfig {
            fitted: true,
            active_high: input.active_high,
            debounce_us: DEBOUNCE_US,
        };
        let j = input.joint as usize;
        let old = config.inputs[j];
        config.inputs[j] = match input.role {
            Role::HomeAndMin => PerSwitch {
                home: fitted,
                min: fitted,
                max: old.max,
            },
            Role::Max => PerSwitch {
                home: old.home,
                min: old.min,
                max: fitted,
            },
        };
        i += 1;
    }
    config
};

/// Edges seen by the handlers since the service last looked, per [`INPUTS`] index.
#[derive(Clone, Copy)]
struct Pending {
    /// Inputs with an edge.
    changed: u16,
    /// Inputs that read active at an edge (fed as an activation first).
    activated: u16,
    /// A handler stopped the STEP outputs (the service's halt follows).
    killed: bool,
    /// The first activation's instant, per input.
    active_at: [u64; INPUTS.len()],
    /// The last edge's instant, per input.
    last_at: [u64; INPUTS.len()],
}

impl Pending {
    /// Input `i` had an edge at `at_us`, reading `active`.
    fn record(&mut self, i: usize, active: bool, at_us: u64) {
        let bit = 1 << i;
        if active
            && self.activated & bit == 0
            && let Some(at) = self.active_at.get_mut(i)
        {
            self.activated |= bit;
            *at = at_us;
        }
        if let Some(at) = self.last_at.get_mut(i) {
            self.changed |= bit;
            *at = at_us;
        }
    }

    const NONE: Pending = Pending {
        changed: 0,
        activated: 0,
        killed: false,
        active_at: [0; INPUTS.len()],
        last_at: [0; INPUTS.len()],
    };
}

/// What the handlers and the service share.
struct Shared {
    line: SwitchLine,
    pending: Mutex<CriticalSectionRawMutex, RefCell<Pending>>,
}

/// In SRAM1 (NOLOAD): written once by [`start`] before any EXTI line is enabled.
#[unsafe(link_section = ".sram1.switches")]
static mut SHARED_MEM: MaybeUninit<Shared> = MaybeUninit::uninit();

/// [`SHARED_MEM`] once written (null before [`start`]: the service does nothing).
static SHARED: AtomicPtr<Shared> = AtomicPtr::new(core::ptr::null_mut());

fn shared() -> Option<&'static Shared> {
    // SAFETY: null, or SHARED_MEM after its one write, never written again.
    unsafe { SHARED.load(Ordering::Acquire).as_ref() }
}

fn port(input: &Input) -> pac::gpio::Gpio {
    match input.port {
        PORT_A => pac::GPIOA,
        PORT_B => pac::GPIOB,
        _ => pac::GPIOE,
    }
}

/// The pin's electrical level (true: high).
fn level(input: &Input) -> bool {
    port(input).idr().read().idr(usize::from(input.pin)) == Idr::HIGH
}

/// The joint's inputs that `input` feeds, and the limit side it guards.
fn switches_of(input: &Input) -> (&'static [Switch], Switch, Side) {
    match input.role {
        Role::HomeAndMin => (&[Switch::Home, Switch::Min], Switch::Min, Side::Min),
        Role::Max => (&[Switch::Max], Switch::Max, Side::Max),
    }
}

/// The pins, taken so that nothing else drives them (configured by register in [`start`]).
#[allow(missing_docs, dead_code)]
pub struct SwitchPins {
    pub pe2: Peri<'static, peripherals::PE2>,
    pub pa3: Peri<'static, peripherals::PA3>,
    pub pe6: Peri<'static, peripherals::PE6>,
    pub pe7: Peri<'static, peripherals::PE7>,
    pub pe8: Peri<'static, peripherals::PE8>,
    pub pb1: Peri<'static, peripherals::PB1>,
    pub pe10: Peri<'static, peripherals::PE10>,
    pub pe11: Peri<'static, peripherals::PE11>,
    pub pe12: Peri<'static, peripherals::PE12>,
    pub pe13: Peri<'static, peripherals::PE13>,
    pub pe14: Peri<'static, peripherals::PE14>,
    pub pe15: Peri<'static, peripherals::PE15>,
}

/// The EXTI vectors of [`INPUTS`]'s lines.
const VECTORS: [interrupt::Interrupt; 5] = [
    interrupt::EXTI1,
    interrupt::EXTI2,
    interrupt::EXTI3,
    interrupt::EXTI9_5,
    interrupt::EXTI15_10,
];

/// Makes the pins inputs with their pulls, routes them to their EXTI lines on both edges
/// at P0, and records every input's level now as an edge (an input active at boot trips
/// at once). Call once, after the step outputs and the e-stop input are set up.
pub fn start(_pins: SwitchPins) -> &'static SwitchLine {
    // SAFETY: called once from main, before any EXTI line below is enabled, so nothing
    // reads SHARED_MEM yet; never written again.
    let shared: &'static mut Shared = unsafe {
        (*addr_of_mut!(SHARED_MEM)).write(Shared {
            line: SwitchLine::new(CONFIG),
            pending: Mutex::new(RefCell::new(Pending::NONE)),
        })
    };
    SHARED.store(shared, Ordering::Release);
    let shared: &'static Shared = shared;
    pac::RCC.apb4enr().modify(|w| w.set_syscfgen(true));
    let exti = pac::EXTI;
    for input in &INPUTS {
        let gpio = port(input);
        let pin = usize::from(input.pin);
        gpio.pupdr().modify(|w| w.set_pupdr(pin, input.pull));
        gpio.moder().modify(|w| w.set_moder(pin, Moder::INPUT));
        pac::SYSCFG
            .exticr(pin / 4)
            .modify(|w| w.set_exti(pin % 4, input.port));
        exti.rtsr(0).modify(|w| w.set_line(pin, true));
        exti.ftsr(0).modify(|w| w.set_line(pin, true));
        exti.imr(0).modify(|w| w.set_line(pin, true));
    }
    // The levels now, as edges (under the lock: an edge from here on adds to them).
    let now = embassy_time::Instant::now().as_micros();
    shared.pending.lock(|p| {
        let mut p = p.borrow_mut();
        for (i, input) in INPUTS.iter().enumerate() {
            p.record(i, level(input) == input.active_high, now);
        }
    });
    for irq in VECTORS {
        irq.set_priority(Priority::P0);
        // SAFETY: the handlers touch EXTI's pending bits, the inputs' IDR, the step
        // outputs' registers (kill_step_outputs) and `Shared` under critical sections,
        // and pend the step service; they never take the step lock.
        unsafe { irq.enable() };
    }
    cortex_m::peripheral::NVIC::pend(crate::step_dma::SERVICE_IRQ);
    &shared.line
}

/// Every EXTI handler of the switches: the lines of [`INPUTS`] pending are cleared, read,
/// stamped; a limit tripping stops every STEP output; the step service is pended.
fn on_edges() {
    let pending = pac::EXTI.pr(0).read().0 & LINES;
    // rc_w1: cleared before the pins are read, so an edge after a read pends again.
    pac::EXTI.pr(0).write(|w| w.0 = pending);
    let Some(shared) = shared() else { return };
    let now = embassy_time::Instant::now().as_micros();
    for (i, input) in INPUTS.iter().enumerate() {
        if pending & (1 << input.pin) == 0 {
            continue;
        }
        let active = level(input) == input.active_high;
        let (_, limit, side) = switches_of(input);
        // Would the service's edge trip (and halt)? Then the STEP lines go low now.
        let kill = active
            && !shared.line.is_active(input.joint, limit)
            && !shared.line.is_masked(input.joint, side);
        if kill {
            crate::step_dma::kill_step_outputs();
        }
        shared.pending.lock(|p| {
            let mut p = p.borrow_mut();
            p.record(i, active, now);
            p.killed |= kill;
        });
    }
    cortex_m::peripheral::NVIC::pend(crate::step_dma::SERVICE_IRQ);
}

/// The step service's share of the switches (P2, may take the step lock): every edge the
/// handlers recorded goes to [`SwitchLine::edge`] with the joint's count (a trip halts the
/// backend there and wakes the trajectory task).
pub fn service() {
    let Some(shared) = shared() else { return };
    // Copied out only when an edge came (the service runs for other reasons too).
    let taken = shared.pending.lock(|p| {
        let mut p = p.borrow_mut();
        (p.changed != 0).then(|| core::mem::replace(&mut *p, Pending::NONE))
    });
    let Some(p) = taken else { return };
    let positions = STEP.positions();
    let wake = &crate::BUS.step_progress;
    let stamps = p.active_at.iter().zip(&p.last_at);
    for ((i, input), (&active_at, &last_at)) in INPUTS.iter().enumerate().zip(stamps) {
        if p.changed & (1 << i) == 0 {
            continue;
        }
        let joint = input.joint;
        let position = positions.get(usize::from(joint)).copied().unwrap_or(0);
        let (switches, _, _) = switches_of(input);
        let edge = |level: bool, at_us: u64| {
            for &switch in switches {
                shared.line.edge(
                    joint,
                    switch,
                    level,
                    position,
                    at_us,
                    &STEP,
                    &STEP_TIMER,
                    wake,
                );
            }
        };
        if p.activated & (1 << i) != 0 {
            edge(input.active_high, active_at);
        }
        edge(level(input), last_at);
    }
    if p.killed {
        // The trip halted the backend above: outputs may be enabled again by a start,
        // which the halt refuses until the controller took the trip.
        crate::step_dma::kill_handled();
    }
}

#[interrupt]
fn EXTI1() {
    on_edges();
}

#[interrupt]
fn EXTI2() {
    on_edges();
}

#[interrupt]
fn EXTI3() {
    on_edges();
}

#[interrupt]
fn EXTI9_5() {
    on_edges();
}

#[interrupt]
fn EXTI15_10() {
    on_edges();
}
