//! embassy-time's driver on two CMSDK APB timers, and the 64-bit SYSCLK time base the step
//! timer shares.
//!
//! Timer 0 counts down from 2^32 - 1 over and over at SYSCLK (25 MHz, one wrap every
//! 172 s); its interrupt counts the wraps. Time is wraps * 2^32 + (2^32 - 1 - VALUE); a
//! wrap that happened but was not yet counted is seen in the interrupt status and added,
//! inside one critical section, so time never goes back. embassy-time ticks at 1 MHz:
//! 25 SYSCLK cycles per tick.
//!
//! Timer 1 is the alarm: loaded with the cycles to the next expiration of the timer queue,
//! it interrupts when it reaches zero; the handler stops it and wakes what is due.

use core::cell::{Cell, RefCell};

use critical_section::{CriticalSection, Mutex};
use embassy_time_driver::Driver;
use embassy_time_queue_utils::Queue;

use crate::mps2::{self, Irq, SYSCLK_HZ, TIMER0, TIMER1, read, write};

/// CMSDK timer registers.
mod reg {
    /// Control: enable (0), interrupt enable (3).
    pub const CTRL: usize = 0x0;
    /// Current value (counts down).
    pub const VALUE: usize = 0x4;
    /// Value loaded when the counter reaches zero.
    pub const RELOAD: usize = 0x8;
    /// Interrupt status (read) / clear (write 1).
    pub const INT: usize = 0xC;
}
const CTRL_ENABLE: u32 = 1;
const CTRL_IRQ: u32 = 1 << 3;

/// SYSCLK cycles per embassy-time tick.
const CYCLES_PER_TICK: u64 = SYSCLK_HZ as u64 / embassy_time_driver::TICK_HZ;
const _: () = assert!(CYCLES_PER_TICK * embassy_time_driver::TICK_HZ == SYSCLK_HZ as u64);

/// Wraps of timer 0 counted so far.
static WRAPS: Mutex<Cell<u32>> = Mutex::new(Cell::new(0));

struct Mps2Time {
    queue: Mutex<RefCell<Queue>>,
}

embassy_time_driver::time_driver_impl!(static DRIVER: Mps2Time = Mps2Time {
    queue: Mutex::new(RefCell::new(Queue::new())),
});

/// Starts the time base and enables both timers' interrupts. Call once, first.
pub fn init() {
    write(TIMER0, reg::CTRL, 0);
    write(TIMER0, reg::RELOAD, u32::MAX);
    write(TIMER0, reg::VALUE, u32::MAX);
    write(TIMER0, reg::INT, 1);
    write(TIMER0, reg::CTRL, CTRL_ENABLE | CTRL_IRQ);
    write(TIMER1, reg::CTRL, 0);
    write(TIMER1, reg::INT, 1);
    mps2::enable(Irq::Timer0, mps2::priority::TIME);
    mps2::enable(Irq::Timer1, mps2::priority::TIME);
}

fn now_cycles_cs(cs: CriticalSection<'_>) -> u64 {
    let value = read(TIMER0, reg::VALUE);
    let wraps = u64::from(WRAPS.borrow(cs).get());
    if read(TIMER0, reg::INT) & 1 != 0 {
        // Wrapped before the status read: the value read now is after the wrap.
        let value = read(TIMER0, reg::VALUE);
        ((wraps + 1) << 32) + u64::from(u32::MAX - value)
    } else {
        (wraps << 32) + u64::from(u32::MAX - value)
    }
}

/// SYSCLK cycles since [`init`] (the step timer's tick).
pub fn now_cycles() -> u64 {
    critical_section::with(now_cycles_cs)
}

/// Arms the alarm for tick `at`; false if `at` has already passed.
fn set_alarm(cs: CriticalSection<'_>, at: u64) -> bool {
    write(TIMER1, reg::CTRL, 0);
    write(TIMER1, reg::INT, 1);
    if at == u64::MAX {
        return true;
    }
    let now = now_cycles_cs(cs);
    let due = at.saturating_mul(CYCLES_PER_TICK);
    if due <= now {
        return false;
    }
    // Farther than one count of the timer: wake early and look again.
    let cycles = u32::try_from(due - now).unwrap_or(u32::MAX);
    // The handler stops it; until then a reload would be 172 s away.
    write(TIMER1, reg::RELOAD, u32::MAX);
    write(TIMER1, reg::VALUE, cycles);
    write(TIMER1, reg::CTRL, CTRL_ENABLE | CTRL_IRQ);
    true
}

impl Mps2Time {
    fn rearm(&self, cs: CriticalSection<'_>) {
        let mut queue = self.queue.borrow(cs).borrow_mut();
        let mut next = queue.next_expiration(self.now());
        while !set_alarm(cs, next) {
            next = queue.next_expiration(self.now());
        }
    }
}

impl Driver for Mps2Time {
    fn now(&self) -> u64 {
        now_cycles() / CYCLES_PER_TICK
    }

    fn schedule_wake(&self, at: u64, waker: &core::task::Waker) {
        critical_section::with(|cs| {
            let changed = self.queue.borrow(cs).borrow_mut().schedule_wake(at, waker);
            if changed {
                self.rearm(cs);
            }
        })
    }
}

/// Timer 0 reached zero: one more wrap.
pub fn on_wrap_interrupt() {
    critical_section::with(|cs| {
        if read(TIMER0, reg::INT) & 1 != 0 {
            write(TIMER0, reg::INT, 1);
            let wraps = WRAPS.borrow(cs);
            wraps.set(wraps.get().wrapping_add(1));
        }
    })
}

/// The alarm fired: wake what is due, arm the next.
pub fn on_alarm_interrupt() {
    critical_section::with(|cs| DRIVER.rearm(cs))
}
