//! One checked description per board: every figure that differs between the NUCLEO-H743ZI2
//! (and its `tmc-drivers` build), QEMU's mps2-an500 and the simulator, in one place each
//! (as Hubris keeps one `app-*.toml` per board).
//!
//! The board firmware, the QEMU firmware and sim-host read their [`BoardProfile`] and build
//! their step timing ([`BoardProfile::step_timing`]) and controller configuration
//! ([`BoardProfile::controller_config`]) from it; they declare none of these figures
//! themselves. The figures a host sees (STATUS `max_step_rate_hz`, `step_budget_hz`,
//! `capacity`, `pwm_timer_clock_hz`) come from here, and the tests check STATUS and the
//! docs' tables (docs/PROTOCOL.md "Figures per board", docs/BOARD.md, README.md) against
//! these constants (sim-host/tests/profile.rs, tests/tests/qemu.rs).
//!
//! Everything here is const-evaluated: the firmware images hold only the figures they use,
//! and a profile that breaks a rule ([`BoardProfile::check`]) does not compile.
//!
//! The step producer's queue is sized in time per board ([`BoardProfile::lookahead_us`],
//! [`BoardProfile::step_queue`]); the bus's queues and the host window
//! ([`protocol::limits::HOST_WINDOW`]) are the same on every board, declared once with
//! their reasons where they are used.

use arm_step::{MAX_JOINTS, StepTiming};

use crate::config::{
    ControllerConfig, DEFAULT_RETURN_ACCEL, DEFAULT_RETURN_SEGMENT_US, DEFAULT_RETURN_SPEED,
    ServoOnStop,
};

/// A driver's timing requirements (its datasheet's figures), in nanoseconds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DriverTiming {
    /// Least STEP high time.
    pub high_ns: u32,
    /// Least STEP low time between pulses.
    pub low_ns: u32,
    /// Least time from a DIR change to the next rising STEP edge.
    pub dir_setup_ns: u32,
}

impl DriverTiming {
    /// DM542, TB6600 and other opto-isolated drivers: 2.5 us high, 2.5 us low, 5 us DIR
    /// setup (safe for DRV8825 and A4988 too). 200 kHz per joint.
    pub const OPTO: DriverTiming = DriverTiming {
        high_ns: 2_500,
        low_ns: 2_500,
        dir_setup_ns: 5_000,
    };

    /// TMC2209/TMC5160-class drivers: 100 ns high, 100 ns low, 20 ns DIR setup: 5 MHz by
    /// the driver, 1 MHz by the NUCLEO ([`BoardProfile::step_rate_ceiling_hz`]).
    pub const TMC: DriverTiming = DriverTiming {
        high_ns: 100,
        low_ns: 100,
        dir_setup_ns: 20,
    };
}

/// Every per-board figure of the controller.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BoardProfile {
    /// The board's name, as the docs' tables head their columns.
    pub name: &'static str,
    /// Input clock of the joints' step timers, Hz: the resolution of every STEP edge.
    pub step_timer_hz: u32,
    /// The STEP/DIR drivers' timing this board is built for.
    pub driver: DriverTiming,
    /// Longest wait of a DIR change behind its tick, ns, added to the driver's DIR setup
    /// time so that the driver still sees its setup.
    pub dir_latency_ns: u32,
    /// Per-joint step rate the board itself takes, whatever the drivers allow, Hz.
    pub step_rate_ceiling_hz: u32,
    /// Steps per second of all joints together the board takes on (STATUS
    /// `step_budget_hz`, the controller's boot value).
    pub step_budget_hz: u32,
    /// Steps per second of all joints together the board's step side can place while a
    /// run's time is warped (issue 32: HOLD, RESUME, OVERRIDE, a factor other than 100 %;
    /// each such pulse inverts arm-step's `Warp`, some 40 times an unwarped pulse's cost);
    /// 0: no limit. The controller refuses a warp above it (`OVERRIDE_REFUSED`, MOTION
    /// `STEP_BUDGET`) rather than let the step buffers run dry.
    pub warp_budget_hz: u32,
    /// Trajectory points buffered (STATUS `capacity`; the controller's compile-time size).
    pub trajectory_capacity: usize,
    /// Input clock of the gripper timer, Hz (STATUS `pwm_timer_clock_hz`).
    pub pwm_timer_clock_hz: u32,
    /// Periods per step DMA buffer half (the `HALF` of the board's `StepStreams`).
    pub step_buffer_half: usize,
    /// Longest period each joint's step timer makes, in its ticks.
    pub step_timer_max_period_ticks: [u32; MAX_JOINTS],
    /// Motion the step side holds ahead of the pulses being made, at least, microseconds:
    /// the trajectory task may be kept from feeding it this long without the run running
    /// dry (issue 19). Sets the step producer's queue ([`BoardProfile::step_queue`]).
    pub lookahead_us: u32,
    /// Shortest timer period the step outputs can be reloaded for, ns: where a DMA burst
    /// loads each period, the burst of one update must land before the next update
    /// (0: periods are played in software, any length works). At least
    /// [`BoardProfile::dma_burst_latency_ns`] (checked).
    pub min_dma_period_ns: u32,
    /// The step DMA's timing model ([`StepDma::NONE`]: periods are played in software).
    pub step_dma: StepDma,
}

/// How a board's step periods reach its timers by DMA: the figures the aggregate step-rate
/// ceiling ([`BoardProfile::dma_step_ceiling_hz`]) and the latest burst
/// ([`BoardProfile::dma_burst_latency_ns`]) are derived from (issue 34). The model is
/// RM0433's "DMA arbitration": each controller moves one item at a time; among the
/// requests pending, the highest priority goes first, then the lower stream number, and
/// arbitration is made again after every item. Renode's DMA model
/// (tests/renode/STM32H7_StepDMA.cs) follows it with the same time per item.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct StepDma {
    /// Time of one item (a word read from SRAM and written to a timer's DMAR), ns.
    pub item_ns: u32,
    /// DMA controllers the step streams are spread over.
    pub controllers: u32,
    /// Step streams on each controller (all at the same, very high, priority).
    pub streams_per_controller: u32,
    /// Items of other streams of the same priority that can be under way on a controller
    /// when a step burst is requested (an item is never cut): one, the serial port's.
    pub other_items: u32,
}

impl StepDma {
    /// No DMA: periods played in software.
    pub const NONE: StepDma = StepDma {
        item_ns: 0,
        controllers: 0,
        streams_per_controller: 0,
        other_items: 0,
    };
}

/// Items a step period's DMA burst moves: ARR, RCR, CCR1 through the timer's DMAR
/// (firmware/board's `step_dma`, which checks its `WORDS_PER_PERIOD` against this).
pub const DMA_WORDS_PER_PERIOD: u32 = 3;

/// `ns` in ticks of a `tick_hz` clock, rounded up (a driver's least time is never cut).
#[allow(
    clippy::cast_possible_truncation,
    reason = "const-evaluated for the drivers' figures: at most a few thousand ticks"
)]
const fn ns_to_ticks(ns: u32, tick_hz: u32) -> u32 {
    (ns as u64 * tick_hz as u64).div_ceil(1_000_000_000) as u32
}

impl BoardProfile {
    /// The step timing of every joint on the board's step timer clock.
    pub const fn step_timing(&self) -> StepTiming {
        self.step_timing_at(self.step_timer_hz)
    }

    /// The board's driver timing on a step timer at `tick_hz` (the simulator's
    /// `--tick-hz`): each figure rounded up to whole ticks.
    pub const fn step_timing_at(&self, tick_hz: u32) -> StepTiming {
        let pulse_width_ticks = ns_to_ticks(self.driver.high_ns, tick_hz);
        // The least low time is lengthened where pulse + low would be a shorter period
        // than the step DMA can reload (issue 20): then no two pulses of a joint, hence no
        // period, are closer than that.
        let driver_low = ns_to_ticks(self.driver.low_ns, tick_hz);
        let dma_low =
            ns_to_ticks(self.min_dma_period_ns, tick_hz).saturating_sub(pulse_width_ticks);
        StepTiming {
            tick_hz,
            pulse_width_ticks,
            dir_setup_ticks: ns_to_ticks(self.driver.dir_setup_ns + self.dir_latency_ns, tick_hz),
            step_low_ticks: if dma_low > driver_low {
                dma_low
            } else {
                driver_low
            },
        }
    }

    /// Segments the step producer's queue holds: [`BoardProfile::lookahead_us`] of the
    /// shortest common points ([`crate::step_shared::step_queue_for`]).
    pub const fn step_queue(&self) -> usize {
        crate::step_shared::step_queue_for(self.lookahead_us)
    }

    /// The latest a period's DMA burst lands after its update event, ns: on a controller
    /// whose every step stream asks at the same instant, the last stream's three words
    /// come after every other step stream's three and after an item of another stream
    /// already under way: `(streams * 3 + other) * item`. 0 without DMA.
    pub const fn dma_burst_latency_ns(&self) -> u32 {
        let dma = self.step_dma;
        (dma.streams_per_controller * DMA_WORDS_PER_PERIOD + dma.other_items) * dma.item_ns
    }

    /// The most steps per second of all joints together the step DMA carries, Hz
    /// (`u32::MAX` without DMA): every joint at its shortest period
    /// ([`BoardProfile::min_dma_period_ns`], which outlasts the latest burst), and no
    /// more than the controllers move (one item per `item_ns` each, three a step).
    pub const fn dma_step_ceiling_hz(&self) -> u32 {
        dma_step_ceiling_hz(self.step_dma, self.min_dma_period_ns)
    }

    /// [`BoardProfile::min_dma_period_ns`] in step timer ticks (rounded up).
    pub const fn min_dma_period_ticks(&self) -> u64 {
        ns_to_ticks(self.min_dma_period_ns, self.step_timer_hz) as u64
    }

    /// Per-joint maximum step rate (STATUS `max_step_rate_hz`): what the drivers allow on
    /// the step timer's clock, within the board's ceiling.
    pub const fn max_step_rate_hz(&self) -> u32 {
        let driver = self.step_timing().max_step_rate_hz();
        if driver < self.step_rate_ceiling_hz {
            driver
        } else {
            self.step_rate_ceiling_hz
        }
    }

    /// The controller's configuration on this board: its limits, buffer, gripper clock and
    /// the default RETURN limits. (The step budget is not in it: the controller boots with
    /// [`BOOT_STEP_BUDGET_HZ`], every profile's.)
    pub const fn controller_config(&self) -> ControllerConfig {
        ControllerConfig {
            max_step_rate_hz: self.max_step_rate_hz(),
            capacity: self.trajectory_capacity,
            pwm_timer_clock_hz: self.pwm_timer_clock_hz,
            return_speed: [DEFAULT_RETURN_SPEED; MAX_JOINTS],
            return_accel: [DEFAULT_RETURN_ACCEL; MAX_JOINTS],
            return_segment_us: DEFAULT_RETURN_SEGMENT_US,
            servo_on_stop: ServoOnStop::Hold,
        }
    }

    /// The rules every profile keeps (evaluated at compile time for each one below).
    pub const fn check(&self) {
        let timing = self.step_timing();
        let max = self.max_step_rate_hz();
        // Within what the drivers and the board (DMA, CPU) take.
        assert!(max <= timing.max_step_rate_hz() && max <= self.step_rate_ceiling_hz);
        // The protocol's usual 100 kHz per joint is always available.
        assert!(max >= 100_000);
        // One joint at its full rate fits in the budget of all joints.
        assert!(self.step_budget_hz >= max);
        // The budget is within what the step DMA carries, and every reloadable period
        // outlasts the latest burst (issue 34); a DMA carries every joint.
        assert!(self.step_budget_hz <= self.dma_step_ceiling_hz());
        assert!(self.min_dma_period_ns >= self.dma_burst_latency_ns());
        assert!(
            self.step_dma.item_ns == 0
                || (self.step_dma.controllers * self.step_dma.streams_per_controller) as usize
                    == MAX_JOINTS
        );
        // No pulse period is shorter than the step DMA reloads (the producer's other
        // periods are never shorter than a pulse period: tests/profile_periods.rs).
        assert!(timing.min_pulse_period_ticks() >= self.min_dma_period_ticks());
        // At least 50 ms of motion ahead (issue 19's range: 50-100 ms).
        assert!(self.lookahead_us >= 50_000);
        // Every driver time is at least one tick: a pulse and a gap are always made.
        assert!(timing.pulse_width_ticks >= 1 && timing.step_low_ticks >= 1);
        assert!(timing.dir_setup_ticks >= 1);
        // STATUS `capacity` is a u16; a buffer holds at least one point.
        assert!(self.trajectory_capacity >= 1 && self.trajectory_capacity <= u16::MAX as usize);
        assert!(self.step_buffer_half >= 2);
        // A period of a 16-bit timer can hold the shortest pulse period and the DIR setup.
        let mut j = 0;
        while j < MAX_JOINTS {
            #[allow(clippy::indexing_slicing, reason = "const-evaluated: j < MAX_JOINTS")]
            let range = self.step_timer_max_period_ticks[j] as u64;
            assert!(range >= timing.min_pulse_period_ticks());
            assert!(range > timing.dir_setup_ticks as u64);
            j += 1;
        }
        assert!(self.pwm_timer_clock_hz > 0);
    }
}

/// The NUCLEO's step DMA (firmware/board/src/step_dma, issue 34): joints 0-3 (the APB1
/// timers) on DMA1 streams 0-3, joints 4-7 (APB2) on DMA2 streams 0-3, each controller
/// writing through its own AHB-to-APB bridge, the buffers in SRAM2 (no Ethernet DMA there).
/// An item is about ten 200 MHz bus cycles (the word read from SRAM2 and the write through
/// the bridge to the timer; RM0433 publishes no figure, ST's DMA application notes break a
/// transfer into cycles of this order): 50 ns. The one other item that can be under way is
/// the serial port's (DMA1 streams 4-5, the same very high priority, higher numbers: it
/// never wins a tie, but an item under way is not cut).
pub const NUCLEO_STEP_DMA: StepDma = StepDma {
    item_ns: 50,
    controllers: 2,
    streams_per_controller: 4,
    other_items: 1,
};

/// The NUCLEO's CPU budget for steps: at the measured 42.4 instructions per step
/// (scripts/step-cost, the whole step path with 8 joints at distinct rates, the worse of
/// its 8-joint trajectories, after issue 20's BASEPRI lock and running sums), about 1.3
/// cycles each on the Cortex-M7 at 400 MHz, 4 M steps/s is 4e6 * 42.4 * 1.3 / 400e6 = 55%
/// of the CPU, leaving the rest to the network and the tasks (docs/PROTOCOL.md, "Step rate
/// budget"; it was 31.3 and 41%).
const NUCLEO_CPU_STEP_BUDGET_HZ: u32 = 4_000_000;

/// The NUCLEO's budget for warped steps (issue 32, [`BoardProfile::warp_budget_hz`]): a
/// warped pulse cost the step path's interrupts 1,947-2,173 instructions during a ramp
/// (100 -> 50 %: six joints at 8,400 steps/s, one at 50 kHz, eight at 69,600 together) and
/// 2,119 at a steady 50 % (tests/tests/renode_cost.rs
/// `step_path_instructions_per_step_during_a_ramp`, the `cargo fw` ELF on Renode at 400
/// MIPS: `Warp::warped_tick`'s u128 bisection and division are 1,770-1,920 of them), against
/// 34-42 unwarped. At the same 55 % of the CPU as the unwarped budget: 0.55 * 400e6 /
/// (2,200 * 1.3) = 77 k steps/s; 75,000. The eight joints at 69,600 ramped without a step
/// stream running dry there.
const NUCLEO_WARP_STEP_BUDGET_HZ: u32 = 75_000;

/// The NUCLEO's step DMA ceiling ([`BoardProfile::dma_step_ceiling_hz`] of its
/// `min_dma_period_ns` and [`NUCLEO_STEP_DMA`]): 8 joints at the 1 us floor, 8 M steps/s
/// (the two controllers could move 2 / (3 * 50 ns) = 13.3 M).
const NUCLEO_DMA_STEP_CEILING_HZ: u32 =
    dma_step_ceiling_hz(NUCLEO_STEP_DMA, NUCLEO_MIN_DMA_PERIOD_NS);

/// The NUCLEO's shortest reloadable step period (its profile's `min_dma_period_ns`, with
/// the reason there).
const NUCLEO_MIN_DMA_PERIOD_NS: u32 = 1_000;

/// [`BoardProfile::dma_step_ceiling_hz`] of a step DMA and a shortest period.
#[allow(
    clippy::cast_possible_truncation,
    reason = "const-evaluated, clamped to u32::MAX first"
)]
const fn dma_step_ceiling_hz(dma: StepDma, min_dma_period_ns: u32) -> u32 {
    if dma.item_ns == 0 || min_dma_period_ns == 0 {
        return u32::MAX;
    }
    let joints = dma.controllers * dma.streams_per_controller;
    let at_floor = joints as u64 * 1_000_000_000 / min_dma_period_ns as u64;
    let throughput =
        dma.controllers as u64 * 1_000_000_000 / (DMA_WORDS_PER_PERIOD * dma.item_ns) as u64;
    let ceiling = if at_floor < throughput {
        at_floor
    } else {
        throughput
    };
    if ceiling > u32::MAX as u64 {
        u32::MAX
    } else {
        ceiling as u32
    }
}

/// The lesser of two rates.
const fn min_hz(a: u32, b: u32) -> u32 {
    if a < b { a } else { b }
}

/// The NUCLEO-H743ZI2 board firmware (`cargo fw`) with opto-isolated drivers.
pub const NUCLEO_H743ZI2: BoardProfile = BoardProfile {
    name: "NUCLEO-H743ZI2",
    // The joint timers' input clock: APB1 and APB2 timer clocks at 200 MHz with the CPU at
    // 400 MHz (firmware/board/src/clocks.rs; the step clock checks it at boot).
    step_timer_hz: 200_000_000,
    // The default build: opto-isolated drivers' timing is safe for all drivers.
    driver: DriverTiming::OPTO,
    // The step clock's interrupt at P1 makes the DIR changes. No step-path section masks
    // it (issue 20: the step lock is BASEPRI at P2); what can hold it off is a critical
    // section (PRIMASK) anywhere in the firmware. Measured on the `cargo fw` ELF itself
    // on Renode (issue 34, tests/tests/renode_cost.rs: 8 joints reversing together, 1 kHz
    // LOCATION reports, a flood of 2,000 datagrams), in instructions: the longest span
    // masking it 372 (a task's poll; 3,809 before the bus's slot queues and 1,097 before
    // the logger stopped masking), and the handler's own run before its last DIR write
    // 429 (563 in all). 801 instructions at 1.3 cycles each at 400 MHz, plus the 12
    // cycles of exception entry, is 2.6 us; 3 us covers it. The latest DIR write measured
    // there came 1.07 us after its compare (TIM13 CNT - CCR1, the emulator at one
    // instruction a cycle). Flash wait states on a cold I-cache are not counted (bring-up
    // check 24 measures the span with the DWT). It was 4 us from the step path's copy
    // under QEMU, 35 us while the step path's critical sections masked it, and 5 us from
    // an estimate before.
    dir_latency_ns: 3_000,
    // A period's DMA burst (three words into an APB timer, behind at most three other step
    // streams' on its controller: `step_dma`) must land within the shortest period, 1 us
    // (`min_dma_period_ns`). Also the ceiling of the CPU budget per joint
    // (`step_budget_hz` / 8 joints would be 500 kHz; one joint may take more while the
    // others rest).
    step_rate_ceiling_hz: 1_000_000,
    // The lesser of the CPU's budget and the step DMA's ceiling (issue 34):
    // min(4,000,000, 8,000,000) = 4,000,000 (8 joints x 500 kHz).
    step_budget_hz: min_hz(NUCLEO_CPU_STEP_BUDGET_HZ, NUCLEO_DMA_STEP_CEILING_HZ),
    warp_budget_hz: NUCLEO_WARP_STEP_BUDGET_HZ,
    // 8192 * 36 bytes = 288 KiB of the 512 KiB AXI SRAM, i.e. 80 s of 10 ms points, so a
    // host streaming over a congested link has seconds of slack before an underrun.
    trajectory_capacity: 8192,
    // TIM15 (the gripper) counts at the APB timer clock, 200 MHz (the board passes its
    // measured clock at boot anyway; the simulator uses this figure, so that a host
    // computes the same PSC/ARR for both).
    pwm_timer_clock_hz: 200_000_000,
    // Declared with its reason in arm-step (the producer's benchmarks use it too).
    step_buffer_half: arm_step::NUCLEO_STEP_BUFFER_HALF,
    // TIM2 and TIM5 (32-bit) for joints 0-1, 16-bit timers for the others (arm-step).
    step_timer_max_period_ticks: arm_step::NUCLEO_STEP_TIMER_MAX_PERIOD_TICKS,
    // The update's burst lands at worst 650 ns after its update event
    // (`dma_burst_latency_ns` of `step_dma` below: 13 items of 50 ns); 1 us leaves 35 % for
    // what the estimate leaves out (the CPU's own accesses on the APB bridges). Before issue
    // 34 all eight streams were on DMA2: 24 items, 1.2 us, over this floor (Renode with DMA
    // time: a 1 MHz joint 7 made 1,142 extra pulses in 6 ms). The opto drivers' 5 us
    // periods are far above it; TMC timing (0.2 us) is raised to it, which is the board's
    // 1 MHz ceiling anyway.
    min_dma_period_ns: NUCLEO_MIN_DMA_PERIOD_NS,
    step_dma: NUCLEO_STEP_DMA,
    // Nothing long runs on the board during a run (a settings write needs STOPPED; the
    // tasks' polls and interrupts take microseconds): 50 ms is hundreds of times its
    // trajectory task's worst wake-up latency. 256 segments of 64 bytes, 16 KiB of the AXI
    // SRAM, which the trajectory buffer mostly fills.
    lookahead_us: 50_000,
};

/// The NUCLEO-H743ZI2 built with `--features tmc-drivers`: TMC-class driver timing, so the
/// board's own 1 MHz ceiling is the limit; everything else is [`NUCLEO_H743ZI2`]'s.
pub const NUCLEO_H743ZI2_TMC: BoardProfile = BoardProfile {
    name: "NUCLEO-H743ZI2 tmc-drivers",
    driver: DriverTiming::TMC,
    ..NUCLEO_H743ZI2
};

/// The board firmware on QEMU's mps2-an500 (`cargo qemu-fw`): it emulates the NUCLEO's step
/// hardware (producer, buffer halves, timer ranges in time) in software.
pub const QEMU_MPS2_AN500: BoardProfile = BoardProfile {
    name: "QEMU mps2-an500",
    // The step "timers" count SYSCLK, the only clock of the emulated board (25 MHz: a
    // step tick is 40 ns; firmware/qemu-mps2 checks it against its SYSCLK_HZ).
    step_timer_hz: QEMU_SYSCLK_HZ,
    // The NUCLEO's default drivers, so that the same trajectories are timed alike.
    driver: DriverTiming::OPTO,
    // The software player makes each DIR change at its tick, in order with the edges.
    dir_latency_ns: 0,
    // Its figure since it first ran: the steps are played in software on an emulated CPU
    // whose speed is the host's, and CI's tests stay at or below 100 kHz per joint. (The
    // driver timing would allow 198 kHz at 25 MHz: 2.5 us is 63 ticks.)
    step_rate_ceiling_hz: 100_000,
    // The NUCLEO's: uploads are refused alike.
    step_budget_hz: NUCLEO_H743ZI2.step_budget_hz,
    // The NUCLEO's: a speed change is refused alike (its own cost, a software player on
    // the host's emulated CPU, is not measured).
    warp_budget_hz: NUCLEO_H743ZI2.warp_budget_hz,
    // The NUCLEO's, so that uploads (flow control) behave the same.
    trajectory_capacity: NUCLEO_H743ZI2.trajectory_capacity,
    // The gripper "timer" counts SYSCLK, as a CMSDK timer would.
    pwm_timer_clock_hz: QEMU_SYSCLK_HZ,
    // The NUCLEO's halves: refills come where they come there.
    step_buffer_half: NUCLEO_H743ZI2.step_buffer_half,
    // The NUCLEO's timer ranges in time (its 16-bit timers' 2^16 ticks at 200 MHz are
    // 327.68 us, 8192 ticks here; its 32-bit ones' 21 s), so that gaps are split into the
    // same periods and refills come as often as there.
    step_timer_max_period_ticks: scaled_periods(
        NUCLEO_H743ZI2.step_timer_max_period_ticks,
        NUCLEO_H743ZI2.step_timer_hz,
        QEMU_SYSCLK_HZ,
    ),
    // The NUCLEO's floor, so that the same trajectories give the same periods.
    min_dma_period_ns: NUCLEO_H743ZI2.min_dma_period_ns,
    // No DMA: the periods are played in software.
    step_dma: StepDma::NONE,
    // The emulated CPU runs on a host thread among others: the simulator's reason, and
    // its 4 MiB of RAM hold it easily.
    lookahead_us: SIMULATOR_LOOKAHEAD_US,
};

/// mps2-an500's SYSCLK, which clocks every APB peripheral (timers, UARTs).
const QEMU_SYSCLK_HZ: u32 = 25_000_000;

/// The simulator (sim-host) by default: the NUCLEO-H743ZI2 with opto-isolated drivers, the
/// same limits and figures, its step timer at the NUCLEO's 200 MHz too. Its options deviate
/// explicitly (`--tick-hz`, `--buffer-capacity`).
pub const SIMULATOR: BoardProfile = BoardProfile {
    name: "sim-host",
    lookahead_us: SIMULATOR_LOOKAHEAD_US,
    ..NUCLEO_H743ZI2
};

/// The simulator's (and the QEMU board's) lookahead: it runs on a desktop scheduler, where
/// a thread on two loaded cores is delayed by tens of milliseconds (issue 19 measured runs
/// ending early with 12.8 ms held); 100 ms covers that with room. An emergency stop drops
/// whatever is held, so holding more never delays a stop.
const SIMULATOR_LOOKAHEAD_US: u32 = 100_000;

/// Every profile, for the tests that check STATUS and the docs against them.
pub const ALL: [&BoardProfile; 4] = [
    &NUCLEO_H743ZI2,
    &NUCLEO_H743ZI2_TMC,
    &QEMU_MPS2_AN500,
    &SIMULATOR,
];

const _: () = {
    let mut i = 0;
    while i < ALL.len() {
        #[allow(clippy::indexing_slicing, reason = "const-evaluated: i < ALL.len()")]
        ALL[i].check();
        i += 1;
    }
};
/// The step budget every controller boots with (STATUS `step_budget_hz`): every profile's
/// (checked below). Not a field of [`ControllerConfig`]: a constant costs the NUCLEO's flash
/// nothing, the field 36 bytes of copies (scripts/fw-size.sh), and no board differs.
pub const BOOT_STEP_BUDGET_HZ: u32 = NUCLEO_H743ZI2.step_budget_hz;
const _: () = {
    let mut i = 0;
    while i < ALL.len() {
        #[allow(clippy::indexing_slicing, reason = "const-evaluated: i < ALL.len()")]
        let budget = ALL[i].step_budget_hz;
        assert!(budget == BOOT_STEP_BUDGET_HZ);
        i += 1;
    }
};

// The drivers' figures give the rates the docs state: opto 200 kHz on the NUCLEO, TMC-class
// the board's 1 MHz ceiling.
const _: () = assert!(NUCLEO_H743ZI2.max_step_rate_hz() == 200_000);
const _: () = assert!(NUCLEO_H743ZI2_TMC.max_step_rate_hz() == 1_000_000);
// The simulator is the NUCLEO.
const _: () = assert!(SIMULATOR.max_step_rate_hz() == NUCLEO_H743ZI2.max_step_rate_hz());
// The step DMA's figures (issue 34): a burst lands within 650 ns, 8 M steps/s of all joints
// at the 1 us floor; the budget is the CPU's, the lesser.
const _: () = assert!(NUCLEO_H743ZI2.dma_burst_latency_ns() == 650);
const _: () = assert!(NUCLEO_H743ZI2.dma_step_ceiling_hz() == 8_000_000);
const _: () = assert!(NUCLEO_H743ZI2.step_budget_hz == NUCLEO_CPU_STEP_BUDGET_HZ);

/// The longest period the step producer writes on any joint, ns: 2^16 ticks at 200 MHz,
/// the NUCLEO's 16-bit timers' range. Its 32-bit timers (joints 0-1) could take one period
/// per pulse however slow, but a HOLD, RESUME or OVERRIDE (issue 32) takes effect only
/// after every period already written, up to two buffer halves ahead of the pins: at 64
/// periods a half, a joint at 400 steps/s was 320 ms ahead (Renode: a HOLD taken 310 ms
/// after its ACK). Capped, two halves are at most 42 ms; the empty periods cost a refill
/// for a slow joint some 3,000 a second, a few tens of instructions each.
pub const STREAM_PERIOD_CAP_NS: u64 = 327_680;

impl BoardProfile {
    /// Each joint's longest period in the step streams: its timer's range, at most
    /// [`STREAM_PERIOD_CAP_NS`] (the boards and the simulator build their streams with it).
    #[allow(
        clippy::cast_possible_truncation,
        reason = "const-evaluated: the cap is below a period that is a u32"
    )]
    pub const fn stream_period_ticks(&self) -> [u32; MAX_JOINTS] {
        let cap = STREAM_PERIOD_CAP_NS * self.step_timer_hz as u64 / 1_000_000_000;
        let mut periods = self.step_timer_max_period_ticks;
        let mut j = 0;
        while j < MAX_JOINTS {
            #[allow(clippy::indexing_slicing, reason = "const-evaluated: j < MAX_JOINTS")]
            if periods[j] as u64 > cap {
                periods[j] = cap as u32;
            }
            j += 1;
        }
        periods
    }

    /// How far ahead of the STEP pins the step hardware's buffers may be written, ns: the
    /// prelude and two buffer halves of periods, each at most [`STREAM_PERIOD_CAP_NS`].
    /// A point counts in STATUS `executed` once all its periods are written, so up to
    /// this long before its last pulse (docs/PROTOCOL.md, STATUS).
    pub const fn step_dma_lead_ns(&self) -> u64 {
        (2 * self.step_buffer_half + arm_step::PRELUDE) as u64 * STREAM_PERIOD_CAP_NS
    }

    /// STATUS `executed` that says a run of points of `segment_ns` each has pulsed: one
    /// more than the points the lead may hold before the pins have begun them.
    pub const fn executed_once_pulsed(&self, segment_ns: u64) -> u64 {
        self.step_dma_lead_ns().div_ceil(segment_ns) + 1
    }
}

// 42.6 ms on the NUCLEO and the simulator: 2 x 64 periods and the prelude's 2.
const _: () = assert!(NUCLEO_H743ZI2.step_dma_lead_ns() == 42_598_400);

const _: () = assert!(NUCLEO_H743ZI2.stream_period_ticks()[0] == 1 << 16);
const _: () = assert!(NUCLEO_H743ZI2.stream_period_ticks()[7] == 1 << 16);

/// `ticks` of a `from_hz` clock in ticks of a `to_hz` clock (`to_hz <= from_hz`).
#[allow(
    clippy::cast_possible_truncation,
    reason = "const-evaluated: scaled down from a u32 (to_hz <= from_hz)"
)]
const fn scaled_periods(ticks: [u32; MAX_JOINTS], from_hz: u32, to_hz: u32) -> [u32; MAX_JOINTS] {
    assert!(to_hz <= from_hz);
    let mut scaled = [0; MAX_JOINTS];
    let mut j = 0;
    while j < MAX_JOINTS {
        #[allow(clippy::indexing_slicing, reason = "const-evaluated: j < MAX_JOINTS")]
        {
            scaled[j] = (ticks[j] as u64 * to_hz as u64 / from_hz as u64) as u32;
        }
        j += 1;
    }
    scaled
}
