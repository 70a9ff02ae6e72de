//! The fault path: a panic, a HardFault (including a stack overflow into the guard region)
//! or an unexpected interrupt logs what happened, stops the step output, and ends QEMU
//! with a failure status through semihosting, so that a test sees the fault and its log.
//!
//! The stack guard: the MPU makes the 1 KiB above `.bss` (the stack's lowest addresses; the
//! stack grows down towards it) inaccessible. An overflow faults there instead of silently
//! corrupting statics; the MPU is off in the HardFault handler (HFNMIENA clear), so the
//! handler can still push onto the guard region and report.

use cortex_m::peripheral::MPU;
use cortex_m_rt::ExceptionFrame;

use crate::logger::raw;

/// The guard region's size.
const GUARD_BYTES: u32 = 1024;

/// Semihosting SYS_EXIT.
const SYS_EXIT: u32 = 0x18;
/// ADP_Stopped_RunTimeErrorUnknown: QEMU exits with status 1.
const ADP_STOPPED_RUNTIME_ERROR: u32 = 0x20023;
/// Semihosting exit reason: normal end (QEMU exits with status 0).
const ADP_STOPPED_APPLICATION_EXIT: u32 = 0x20026;

unsafe extern "C" {
    /// End of `.bss`/`.uninit` (cortex-m-rt): the lowest address the stack may reach.
    static __sheap: u32;
}

/// Makes the 1 KiB above `.bss` a no-access MPU region and enables the MPU (default map
/// for everything else).
pub fn install_stack_guard(mpu: &mut MPU) {
    let end_of_statics = &raw const __sheap as u32;
    let guard = end_of_statics.next_multiple_of(GUARD_BYTES);
    // RASR: XN, AP = no access, size 2^(9+1) = 1 KiB, enabled.
    let rasr = (1 << 28) | (9 << 1) | 1;
    // SAFETY: region 0 only covers the guard, which nothing may access; PRIVDEFENA keeps
    // the default memory map for everything else.
    unsafe {
        mpu.rnr.write(0);
        mpu.rbar.write(guard);
        mpu.rasr.write(rasr);
        // ENABLE | PRIVDEFENA; HFNMIENA clear: the MPU is off in the fault handler.
        mpu.ctrl.write(1 | (1 << 2));
    }
    cortex_m::asm::dsb();
    cortex_m::asm::isb();
    log::info!(
        "stack guard at {:#010x}..{:#010x}",
        guard,
        guard + GUARD_BYTES
    );
}

/// Stops the steps, then ends the emulation with a failure status.
fn safe_stop() -> ! {
    crate::step_out::STEP.stop();
    raw(format_args!("FATAL: steps stopped, exiting"));
    // SAFETY: semihosting SYS_EXIT; QEMU is started with semihosting enabled. Without it
    // the breakpoint escalates to a lockup, which also stops everything.
    unsafe {
        cortex_m::asm::semihosting_syscall(SYS_EXIT, ADP_STOPPED_RUNTIME_ERROR);
    }
    loop {
        cortex_m::asm::wfi();
    }
}

#[panic_handler]
fn panic(info: &core::panic::PanicInfo<'_>) -> ! {
    cortex_m::interrupt::disable();
    raw(format_args!("PANIC: {}", info));
    safe_stop()
}

#[cortex_m_rt::exception]
unsafe fn HardFault(frame: &ExceptionFrame) -> ! {
    // SAFETY: reading the fault status registers has no side effect.
    let (cfsr, hfsr, mmfar, bfar) = unsafe {
        (
            core::ptr::read_volatile(0xE000_ED28 as *const u32),
            core::ptr::read_volatile(0xE000_ED2C as *const u32),
            core::ptr::read_volatile(0xE000_ED34 as *const u32),
            core::ptr::read_volatile(0xE000_ED38 as *const u32),
        )
    };
    raw(format_args!(
        "HARDFAULT: pc={:#010x} lr={:#010x} xpsr={:#010x} cfsr={:#010x} hfsr={:#010x} mmfar={:#010x} bfar={:#010x}",
        frame.pc(),
        frame.lr(),
        frame.xpsr(),
        cfsr,
        hfsr,
        mmfar,
        bfar
    ));
    if cfsr & (1 << 4) != 0 || (cfsr & (1 << 7) != 0 && mmfar & !0x3FF == guard_address()) {
        raw(format_args!("HARDFAULT: stack overflow (guard region hit)"));
    }
    safe_stop()
}

fn guard_address() -> u32 {
    (&raw const __sheap as u32).next_multiple_of(GUARD_BYTES)
}

#[cortex_m_rt::exception]
unsafe fn DefaultHandler(irqn: i16) {
    raw(format_args!(
        "FAULT: unexpected exception or interrupt {}",
        irqn
    ));
    safe_stop()
}

/// A fault the emulator's command line asks for (`-append inject-fault=KIND`), so that the
/// tests can check that each kind ends QEMU with a failure and its log. Only QEMU's command
/// line can ask: nothing on the network can.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum InjectedFault {
    /// A Rust panic.
    Panic,
    /// A load from an address with nothing behind it (precise bus fault, escalated).
    HardFault,
    /// Unbounded recursion into the MPU guard region.
    StackOverflow,
}

/// Semihosting SYS_GET_CMDLINE.
const SYS_GET_CMDLINE: u32 = 0x15;

/// Room for QEMU's command line (the kernel's path and `-append`'s words).
const CMDLINE_BYTES: u32 = 512;

/// QEMU's command line, read through semihosting into `buf` (`None` if unreadable).
fn command_line(buf: &mut [u8; CMDLINE_BYTES as usize]) -> Option<&str> {
    // QEMU puts the kernel's path first (an absolute path can be long) and refuses the
    // call if the whole line does not fit.
    let mut block: [u32; 2] = [buf.as_mut_ptr() as u32, CMDLINE_BYTES];
    // SAFETY: SYS_GET_CMDLINE writes at most `block[1]` bytes into `buf` and the length
    // back into `block[1]`; QEMU runs with semihosting enabled.
    let result =
        unsafe { cortex_m::asm::semihosting_syscall(SYS_GET_CMDLINE, block.as_mut_ptr() as u32) };
    if result != 0 {
        log::warn!("QEMU command line unreadable (semihosting SYS_GET_CMDLINE failed)");
        return None;
    }
    let len = (block[1] as usize).min(buf.len());
    core::str::from_utf8(buf.get(..len)?).ok()
}

/// What QEMU's command line (`-append`) asks of this boot.
#[derive(Clone, Copy, Debug, Default)]
pub struct Requested {
    /// `check-runtime`: check arm-wiring's run-time routines first.
    pub runtime_check: bool,
    /// `inject-fault=...`: the fault to commit once the tasks run.
    pub fault: Option<InjectedFault>,
}

/// Reads QEMU's command line once (a semihosting call) and says what it asks for.
pub fn requested() -> Requested {
    let mut buf = [0u8; CMDLINE_BYTES as usize];
    let Some(line) = command_line(&mut buf) else {
        return Requested::default();
    };
    log::info!("QEMU command line: {:?}", line);
    let mut requested = Requested::default();
    for word in line.split_whitespace() {
        let fault = match word {
            "check-runtime" => {
                requested.runtime_check = true;
                None
            }
            "inject-fault=panic" => Some(InjectedFault::Panic),
            "inject-fault=hardfault" => Some(InjectedFault::HardFault),
            "inject-fault=stack-overflow" => Some(InjectedFault::StackOverflow),
            _ => None,
        };
        // The first fault named wins.
        requested.fault = requested.fault.or(fault);
    }
    requested
}

/// Commits the fault.
pub fn inject(fault: InjectedFault) -> ! {
    log::warn!("injecting {:?} (QEMU command line)", fault);
    match fault {
        InjectedFault::Panic => panic!("injected panic"),
        InjectedFault::HardFault => {
            // SAFETY: deliberately faulting: 0xE0100000 is past the private peripheral bus,
            // nothing answers there.
            let value = unsafe { core::ptr::read_volatile(0xE010_0000 as *const u32) };
            panic!("read {:#x} where a bus fault was expected", value)
        }
        InjectedFault::StackOverflow => {
            let depth = recurse(0);
            panic!("recursion returned at depth {}", depth)
        }
    }
}

/// Recurses with a 1 KiB frame that the optimiser must keep, until the guard stops it.
#[inline(never)]
fn recurse(depth: u32) -> u32 {
    let mut frame = [0u8; 1024];
    let [depth_low, ..] = depth.to_le_bytes();
    if let Some(byte) = frame.get_mut(depth as usize % 1024) {
        *byte = depth_low;
    }
    let frame = core::hint::black_box(frame);
    if depth == u32::MAX {
        return u32::from(frame[0]);
    }
    recurse(depth + 1).wrapping_add(u32::from(frame[1]))
}

/// Runs arm-wiring's check of the linked `memcpy`, `memmove`, `memset`, `memcmp` and u64
/// division (compiler-builtins') against their models, logs the outcome and ends the
/// emulation: status 0 if every case matched, a failure otherwise.
pub fn run_runtime_check() -> ! {
    let outcome = arm_wiring::runtime_check::check();
    log::info!(
        "runtime check: {} cases, {} failures",
        outcome.cases,
        outcome.failures
    );
    let reason = if outcome.failures == 0 {
        ADP_STOPPED_APPLICATION_EXIT
    } else {
        ADP_STOPPED_RUNTIME_ERROR
    };
    // SAFETY: semihosting SYS_EXIT, as in `safe_stop`.
    unsafe {
        cortex_m::asm::semihosting_syscall(SYS_EXIT, reason);
    }
    loop {
        cortex_m::asm::wfi();
    }
}
