//! [`StepStreams`]: the producer with every joint's double-buffered DMA buffer, and the
//! work the half/complete interrupt of a joint's stream does ([`StepStreams::refill`]).
//!
//! Each joint's DMA stream plays `periods` circularly: half 0, then half 1, then half 0
//! again. When a half has been handed to the timer, the stream's interrupt refills it
//! with the next periods while the other half plays. Before a run starts,
//! [`StepStreams::prime`] fills the two periods the timer's registers take directly and
//! both halves. The pulses' directions are marked beside the periods (`signs`, not read
//! by the DMA), so that a stop can take back exactly the pulses that were written but not
//! played ([`StepStreams::unwind`]).
//!
//! The DIR changes the producer hands out wait in a small queue per joint
//! ([`StepStreams::next_dir_change`]) for whoever makes them at their tick (on the board
//! a compare interrupt, one per reversal).
//!
//! Hardware-independent: the board and sim-host own the registers; the step-cost script
//! runs `refill` under QEMU to count its instructions per step.

use core::mem::MaybeUninit;

use crate::dir_queue::DirQueues;
use crate::producer::{PulsePeriod, PulseProducer, sign_of};
use crate::{MAX_JOINTS, Segment, StepTiming, write_each};

/// Periods the timer's registers take before the DMA starts: the first period goes into
/// the active registers (through an update event), the second into the preload ones.
pub const PRELUDE: usize = 2;

/// DIR changes a joint can have waiting: one per pulse at most, and the producer is at
/// most two halves (plus the prelude) ahead of the hardware.
const fn dir_queue_len(half: usize) -> usize {
    2 * half + PRELUDE + 2
}

/// DIR ring capacity: enough for halves of up to 64 periods.
pub(crate) const DIR_RING: usize = dir_queue_len(64);

/// A DIR change to make at `tick` (stream ticks).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct DirChange {
    /// When, in ticks since the streams started.
    pub tick: u64,
    /// The level: true = positive steps.
    pub positive: bool,
}

/// One joint's DMA buffer: `2 * HALF` periods, played circularly. Lives where the DMA
/// can read it (on the H7: AXI SRAM or SRAM1-3, never DTCM).
#[repr(C, align(32))]
#[derive(Debug)]
pub struct JointBuffer<const HALF: usize> {
    /// Half 0, then half 1.
    pub periods: [[PulsePeriod; HALF]; 2],
}

impl<const HALF: usize> JointBuffer<HALF> {
    /// Zeroed (so that a static of these goes to .bss, not flash).
    pub const ZERO: Self = JointBuffer {
        periods: [[PulsePeriod::ZERO; HALF]; 2],
    };
}

/// What one refill found.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Refill {
    /// Segments every joint has now gone through.
    pub segments_finished: u32,
    /// A DIR queue overflowed: the run must stop (cannot happen with the queue sized as
    /// above; checked rather than assumed).
    pub dir_overflow: bool,
}

/// One joint's DIR changes waiting to be made, oldest first: the tick, with the level in
/// bit 63 (8 bytes each; ticks never reach 2^63).
#[derive(Clone, Copy, Debug)]
struct DirRing {
    changes: [u64; DIR_RING],
    head: usize,
    len: usize,
}

/// Bit of a packed DIR change that holds the level.
const DIR_LEVEL: u64 = 1 << 63;

impl DirRing {
    const EMPTY: DirRing = DirRing {
        changes: [0; DIR_RING],
        head: 0,
        len: 0,
    };

    /// Queues a change; false if full.
    #[allow(
        clippy::indexing_slicing,
        reason = "at is reduced modulo DIR_RING, the ring's length"
    )]
    fn push(&mut self, tick: u64, positive: bool) -> bool {
        if self.len >= DIR_RING {
            return false;
        }
        let at = (self.head + self.len) % DIR_RING;
        self.changes[at] = (tick & !DIR_LEVEL) | if positive { DIR_LEVEL } else { 0 };
        self.len += 1;
        true
    }
}

/// How a buffer half's running sums are kept ([`StepStreams::unplayed_steps`]).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum HalfSums {
    /// In the half's `sums` table.
    Table,
    /// Every period is a pulse of this sign (one straight cruise wrote the half).
    Every(i8),
    /// Every pulse has this sign, and bit `i` of `pulses` is set if period `i` holds one
    /// (halves of up to 64 periods whose marks are all of one sign).
    OneSign {
        /// The pulses' sign.
        sign: i8,
        /// Which periods hold a pulse.
        pulses: u64,
    },
    /// No period holds a pulse.
    NoPulse,
}

/// The producer and every joint's buffer bookkeeping. `Q` = segments held, `HALF` =
/// periods per buffer half.
#[derive(Debug)]
pub struct StepStreams<const Q: usize, const HALF: usize> {
    producer: PulseProducer<Q>,
    /// Direction marks of each half's pulses, per joint (see [`PulseProducer::fill`]).
    signs: [[[i8; HALF]; 2]; MAX_JOINTS],
    /// The prelude's pulses: their position change, per joint.
    prelude_deltas: [[i8; PRELUDE]; MAX_JOINTS],
    /// The prelude's periods, per joint (for `unwind`).
    prelude: [[PulsePeriod; PRELUDE]; MAX_JOINTS],
    /// The idle period each half holds throughout, if it does (then an idle joint's
    /// refill that would write the same writes nothing), per joint.
    half_idle: [[Option<u32>; 2]; MAX_JOINTS],
    /// Whether only the first sign mark of each half can be set (it was last filled by one
    /// straight cruise), per joint: then a cruise refill need not clear the others.
    marks_clean: [[bool; 2]; MAX_JOINTS],
    /// Position change of the last period of each half, per joint.
    last_sign: [[i8; 2]; MAX_JOINTS],
    /// Position change of the last period a half held before its latest refill wrote over
    /// it, per joint: that period may still be in the timer's preload register.
    evicted: [[i8; 2]; MAX_JOINTS],
    /// Running sums of each half, per joint: element `i` is the signed pulses of the half's
    /// periods `0..=i`, written with the half ([`StepStreams::refill`]). They make
    /// [`StepStreams::unplayed_steps`] constant time: a LOCATION report reads the positions
    /// inside the step lock, which a walk over every joint's unplayed periods held for
    /// 10,100 instructions (issue 20, `scripts/step-cost`).
    sums: [[[i16; HALF]; 2]; MAX_JOINTS],
    /// Per joint and half: how to read its sums without `sums` where a refill could say
    /// it more cheaply (the common refills write no sums).
    half_sums: [[HalfSums; 2]; MAX_JOINTS],
    dirs: [DirRing; MAX_JOINTS],
}

/// A static's place for [`StepStreams`], built in place once at boot
/// ([`StreamsSlot::init`]). Not an `Option`: its `None` would use a niche of the streams'
/// fields and not be all zeros, and the static holding it would go to `.data` (a 14 KiB
/// image in flash, copied at boot) instead of `.bss`. The NUCLEO and the QEMU board hold
/// their streams in one.
pub struct StreamsSlot<const Q: usize, const HALF: usize> {
    ready: bool,
    value: MaybeUninit<StepStreams<Q, HALF>>,
}

impl<const Q: usize, const HALF: usize> StreamsSlot<Q, HALF> {
    /// No streams yet: all zero bytes.
    pub const EMPTY: Self = StreamsSlot {
        ready: false,
        value: MaybeUninit::uninit(),
    };

    /// Builds idle streams in the slot, once (in place: never on the stack).
    pub fn init(&mut self, timing: StepTiming, max_period_ticks: [u32; MAX_JOINTS]) {
        if !self.ready {
            StepStreams::init_in_place(&mut self.value, timing, max_period_ticks);
            self.ready = true;
        }
    }

    /// The streams, once built.
    pub fn get_mut(&mut self) -> Option<&mut StepStreams<Q, HALF>> {
        // SAFETY: `ready` is set only after `value` was written.
        self.ready.then(|| unsafe { self.value.assume_init_mut() })
    }

    /// The streams, once built, read-only.
    pub fn get(&self) -> Option<&StepStreams<Q, HALF>> {
        // SAFETY: as in `get_mut`.
        self.ready.then(|| unsafe { self.value.assume_init_ref() })
    }

    /// Queues a segment in the producer; gives it back when it is full or the streams are
    /// not built yet.
    pub fn push(&mut self, segment: Segment) -> Result<(), Segment> {
        match self.get_mut() {
            Some(streams) => streams.producer().push(segment),
            None => Err(segment),
        }
    }

    /// Segments the producer holds.
    pub fn queued(&self) -> usize {
        self.get().map_or(0, |s| s.producer_ref().queued())
    }
}

/// The idle value of one joint's share of every [`StepStreams`] field but the producer
/// (all of them are per joint arrays), written once for [`StepStreams::new`] (a struct
/// literal: the compiler checks that no field is missing) and [`StepStreams::init_in_place`]
/// (the same list, each joint's element written where it lies). `$emit!($($head)* ; field:
/// value, ...)` is called with the list.
macro_rules! with_idle_joint_fields {
    ($emit:ident!($($head:tt)*)) => {
        $emit!($($head)* ;
            signs: [[0; HALF]; 2],
            prelude_deltas: [0; PRELUDE],
            prelude: [PulsePeriod::ZERO; PRELUDE],
            half_idle: [None; 2],
            marks_clean: [false; 2],
            last_sign: [0; 2],
            evicted: [0; 2],
            sums: [[0; HALF]; 2],
            half_sums: [HalfSums::NoPulse; 2],
            dirs: DirRing::EMPTY,
        )
    };
}

/// `StepStreams { producer, idle joint fields }`: see `with_idle_joint_fields`.
macro_rules! streams_literal {
    ($producer:expr ; $($field:ident : $value:expr),* $(,)?) => {
        StepStreams {
            producer: $producer,
            $($field: [$value; MAX_JOINTS]),*
        }
    };
}

/// Writes each joint's element of each field through the pointer `$slot`: see
/// `with_idle_joint_fields`.
macro_rules! write_joint_fields {
    ($slot:expr ; $($field:ident : $value:expr),* $(,)?) => {{
        $( write_each(&raw mut (*$slot).$field, $value); )*
    }};
}

impl<const Q: usize, const HALF: usize> StepStreams<Q, HALF> {
    const FITS: () = assert!(
        dir_queue_len(HALF) <= DIR_RING && HALF > 0 && HALF <= i16::MAX as usize,
        "a half's DIR changes fit the ring and its pulse count fits the i16 running sums"
    );

    /// Idle streams.
    pub const fn new(timing: StepTiming, max_period_ticks: [u32; MAX_JOINTS]) -> Self {
        let () = Self::FITS;
        with_idle_joint_fields!(streams_literal!(PulseProducer::new(
            timing,
            max_period_ticks
        )))
    }

    /// Builds idle streams in place, in `slot` (a static's storage), and returns them: the
    /// same value as [`StepStreams::new`], but never built on the stack first. The board's
    /// streams are 15 KiB; `slot.write(new(..))` builds them in the caller's frame and
    /// copies them, as the compiler does not elide that copy.
    pub fn init_in_place(
        slot: &mut MaybeUninit<Self>,
        timing: StepTiming,
        max_period_ticks: [u32; MAX_JOINTS],
    ) -> &mut Self {
        let () = Self::FITS;
        let p = slot.as_mut_ptr();
        // SAFETY: `p` points to `slot`'s storage, valid for writes and aligned; every field
        // is written below (the producer by its own in-place constructor, the others joint
        // by joint from the list that `new`'s struct literal proves complete), so the value
        // is initialised.
        unsafe {
            PulseProducer::init_in_place(&raw mut (*p).producer, timing, max_period_ticks);
            with_idle_joint_fields!(write_joint_fields!(p));
            slot.assume_init_mut()
        }
    }

    /// The producer (push segments, positions, stop).
    pub fn producer(&mut self) -> &mut PulseProducer<Q> {
        &mut self.producer
    }

    /// The producer, read-only.
    pub fn producer_ref(&self) -> &PulseProducer<Q> {
        &self.producer
    }

    /// Starts a run: segments from `at_tick`, streams from tick 0 (the timers' start).
    /// Fills `prelude[j]` (for joint `j`'s timer registers) and both halves of `buffers[j]`.
    /// The DIR changes at tick 0 are queued like the others: make them before starting
    /// the timers.
    #[allow(
        clippy::indexing_slicing,
        reason = "joint enumerates [_; MAX_JOINTS] arrays, the length of the per-joint ones indexed"
    )]
    pub fn prime(
        &mut self,
        at_tick: u64,
        prelude: &mut [[PulsePeriod; PRELUDE]; MAX_JOINTS],
        buffers: &mut [&mut JointBuffer<HALF>; MAX_JOINTS],
    ) -> Refill {
        self.prime_inner(at_tick, prelude, buffers, None)
    }

    /// [`StepStreams::prime`], with the DIR changes queued in `dirs` (cleared first: its
    /// consumer must not run meanwhile) instead of this value's own queues: for a consumer
    /// that reads them without the lock around these streams (the NUCLEO's step clock).
    pub fn prime_shared(
        &mut self,
        at_tick: u64,
        prelude: &mut [[PulsePeriod; PRELUDE]; MAX_JOINTS],
        buffers: &mut [&mut JointBuffer<HALF>; MAX_JOINTS],
        dirs: &DirQueues,
    ) -> Refill {
        dirs.clear();
        self.prime_inner(at_tick, prelude, buffers, Some(dirs))
    }

    #[allow(
        clippy::indexing_slicing,
        reason = "joint enumerates [_; MAX_JOINTS] arrays, the length of the per-joint ones indexed"
    )]
    fn prime_inner(
        &mut self,
        at_tick: u64,
        prelude: &mut [[PulsePeriod; PRELUDE]; MAX_JOINTS],
        buffers: &mut [&mut JointBuffer<HALF>; MAX_JOINTS],
        shared: Option<&DirQueues>,
    ) -> Refill {
        self.prime_begin(at_tick);
        let mut outcome = Refill::default();
        for (joint, (prelude, buffer)) in prelude.iter_mut().zip(buffers.iter_mut()).enumerate() {
            let r = self.prime_joint_inner(joint, prelude, buffer, shared);
            outcome.segments_finished += r.segments_finished;
            outcome.dir_overflow |= r.dir_overflow;
        }
        outcome
    }

    /// [`StepStreams::prime_shared`] in pieces, so that whoever serialises these streams
    /// with a lock need not hold it for the whole start (the NUCLEO's run start, issue 20):
    /// this begins the run (every joint's DIR queue cleared, `dirs` too, whose consumer
    /// must not run meanwhile), then [`StepStreams::prime_joint_shared`] primes each
    /// joint, in any lock sections, in joint order. Between the pieces the producer may be
    /// pushed to, and a joint not primed yet has written nothing of the run (its position
    /// is the producer's); a primed joint's pulses have not played
    /// ([`StepStreams::unstarted_steps`]). The same periods and DIR changes as
    /// `prime_shared` (tested).
    pub fn prime_begin_shared(&mut self, at_tick: u64, dirs: &DirQueues) {
        dirs.clear();
        self.prime_begin(at_tick);
    }

    /// One joint's piece of [`StepStreams::prime_begin_shared`]: fills `prelude` (for its
    /// timer's registers) and both halves of `buffer`, its DIR changes queued in `dirs`.
    pub fn prime_joint_shared(
        &mut self,
        joint: usize,
        prelude: &mut [PulsePeriod; PRELUDE],
        buffer: &mut JointBuffer<HALF>,
        dirs: &DirQueues,
    ) -> Refill {
        self.prime_joint_inner(joint, prelude, buffer, Some(dirs))
    }

    fn prime_begin(&mut self, at_tick: u64) {
        for dirs in &mut self.dirs {
            dirs.len = 0;
        }
        self.producer.start_new_clock(at_tick);
    }

    #[allow(
        clippy::indexing_slicing,
        reason = "the joint number is masked to 0..MAX_JOINTS, the per-joint arrays' length"
    )]
    fn prime_joint_inner(
        &mut self,
        joint: usize,
        prelude: &mut [PulsePeriod; PRELUDE],
        buffer: &mut JointBuffer<HALF>,
        shared: Option<&DirQueues>,
    ) -> Refill {
        let joint = joint & (MAX_JOINTS - 1);
        let dirs = &mut self.dirs[joint];
        let mut overflow = false;
        let mut signs = [0i8; PRELUDE];
        let filled = self
            .producer
            .fill(joint, prelude, &mut signs, &mut |tick, positive| {
                overflow |= !match shared {
                    Some(queues) => queues.push(joint, tick, positive),
                    None => dirs.push(tick, positive),
                }
            });
        for (delta, sign) in self.prelude_deltas[joint]
            .iter_mut()
            .zip(sign_of(prelude, &signs, 1))
        {
            *delta = sign;
        }
        self.prelude[joint] = *prelude;
        let mut outcome = Refill {
            segments_finished: filled.segments_finished,
            dir_overflow: overflow,
        };
        for (half, periods) in buffer.periods.iter_mut().enumerate() {
            let r = self.refill_inner(joint, half, periods, shared);
            outcome.segments_finished += r.segments_finished;
            outcome.dir_overflow |= r.dir_overflow;
        }
        outcome
    }

    /// Refills `half` (0 or 1) of `joint`'s buffer (`periods`: that half) once the DMA has
    /// moved on to the other half: the body of the stream's half/complete interrupt.
    #[inline]
    #[allow(
        clippy::indexing_slicing,
        reason = "the joint number is masked to 0..MAX_JOINTS and the half to 0..2, the arrays' lengths"
    )]
    pub fn refill(
        &mut self,
        joint: usize,
        half: usize,
        periods: &mut [PulsePeriod; HALF],
    ) -> Refill {
        self.refill_inner(joint, half, periods, None)
    }

    /// [`StepStreams::refill`], with the DIR changes queued in `dirs` (see
    /// [`StepStreams::prime_shared`]).
    #[inline]
    pub fn refill_shared(
        &mut self,
        joint: usize,
        half: usize,
        periods: &mut [PulsePeriod; HALF],
        dirs: &DirQueues,
    ) -> Refill {
        self.refill_inner(joint, half, periods, Some(dirs))
    }

    #[inline]
    #[allow(
        clippy::indexing_slicing,
        reason = "the joint number is masked to 0..MAX_JOINTS and the half to 0..2, the arrays' lengths"
    )]
    fn refill_inner(
        &mut self,
        joint: usize,
        half: usize,
        periods: &mut [PulsePeriod; HALF],
        shared: Option<&DirQueues>,
    ) -> Refill {
        let j = joint & (MAX_JOINTS - 1);
        let h = half & 1;
        self.evicted[j][h] = self.last_sign[j][h];
        if let Some(period) = self.producer.idle_period(j)
            && self.half_idle[j][h] == Some(period)
        {
            // An idle joint, and this half already holds its idle periods.
            self.producer.skip_idle(j, HALF, period);
            self.last_sign[j][h] = 0;
            return Refill::default();
        }
        let dirs = &mut self.dirs[j];
        let mut overflow = false;
        let signs = &mut self.signs[j][h];
        let cruise = self.producer.will_cruise(j, HALF);
        if !(cruise && self.marks_clean[j][h]) {
            *signs = [0; HALF];
        }
        self.marks_clean[j][h] = cruise;
        let filled = self
            .producer
            .fill(j, periods, signs, &mut |tick, positive| {
                overflow |= !match shared {
                    Some(queues) => queues.push(j, tick, positive),
                    None => dirs.push(tick, positive),
                }
            });
        self.half_idle[j][h] = filled.uniform_idle;
        self.last_sign[j][h] = filled.last_sign;
        self.half_sums[j][h] = if cruise {
            // Every period a pulse of the first mark's sign: no sums needed.
            HalfSums::Every(self.signs[j][h][0])
        } else if filled.pulses == 0 {
            HalfSums::NoPulse
        } else if let Some(one_sign) = self.one_sign(j, h, periods) {
            one_sign
        } else {
            self.sum_half(j, h, periods);
            HalfSums::Table
        };
        Refill {
            segments_finished: filled.segments_finished,
            dir_overflow: overflow,
        }
    }

    /// The oldest DIR change of `joint` not made yet.
    pub fn next_dir_change(&self, joint: usize) -> Option<DirChange> {
        let dirs = self.dirs.get(joint)?;
        let packed = *dirs.changes.get(dirs.head).filter(|_| dirs.len > 0)?;
        Some(DirChange {
            tick: packed & !DIR_LEVEL,
            positive: packed & DIR_LEVEL != 0,
        })
    }

    /// Drops the oldest DIR change of `joint` (made).
    pub fn pop_dir_change(&mut self, joint: usize) {
        if let Some(dirs) = self.dirs.get_mut(joint)
            && dirs.len > 0
        {
            dirs.head = (dirs.head + 1) % DIR_RING;
            dirs.len -= 1;
        }
    }

    /// After a stop: takes back the pulses written for `joint` but never played
    /// ([`StepStreams::unplayed_steps`]).
    pub fn unwind(
        &mut self,
        joint: usize,
        periods: &JointBuffer<HALF>,
        first_unplayed: Option<usize>,
        other_half_played: bool,
    ) {
        let steps = self.unplayed_steps(joint, periods, first_unplayed, other_half_played);
        self.producer.unwind(joint & (MAX_JOINTS - 1), steps);
    }

    /// Like [`StepStreams::unwind`] when the first unplayed period is the last of its half
    /// and that half has been refilled since the DMA read it (the period lives on only in
    /// the timer's preload register): takes back that period's pulse and both halves.
    pub fn unwind_evicted(&mut self, joint: usize, periods: &JointBuffer<HALF>, half: usize) {
        let steps = self.unplayed_evicted(joint, periods, half);
        self.producer.unwind(joint & (MAX_JOINTS - 1), steps);
    }

    /// After a start that was cut before the timers started (the board's e-stop input
    /// opening during it): takes back every pulse written for `joint`, the prelude's first
    /// period's too.
    #[allow(
        clippy::indexing_slicing,
        reason = "the joint number is masked to 0..MAX_JOINTS"
    )]
    pub fn unwind_unstarted(&mut self, joint: usize, periods: &JointBuffer<HALF>) {
        let steps = self.unstarted_steps(joint, periods);
        self.producer.unwind(joint & (MAX_JOINTS - 1), steps);
    }

    /// Every pulse written for `joint` since the run's start (its prelude and both halves
    /// of `periods`), when none has played: what [`StepStreams::unwind_unstarted`] takes
    /// back, and what a joint primed but not started holds.
    #[allow(
        clippy::indexing_slicing,
        reason = "the joint number is masked to 0..MAX_JOINTS"
    )]
    pub fn unstarted_steps(&self, joint: usize, periods: &JointBuffer<HALF>) -> i32 {
        let j = joint & (MAX_JOINTS - 1);
        i32::from(self.prelude_deltas[j][0]) + self.unplayed_steps(j, periods, None, false)
    }

    /// The unplayed pulses in the case of [`StepStreams::unwind_evicted`].
    #[allow(
        clippy::indexing_slicing,
        reason = "the joint number is masked to 0..MAX_JOINTS and the half to 0..2, the arrays' lengths"
    )]
    pub fn unplayed_evicted(&self, joint: usize, periods: &JointBuffer<HALF>, half: usize) -> i32 {
        let j = joint & (MAX_JOINTS - 1);
        let h = half & 1;
        // Both halves hold periods after it: the other half's (refilled before) and this
        // half's new ones.
        i32::from(self.evicted[j][h]) + self.unplayed_steps(j, periods, Some(0), false)
    }

    /// The signed pulses written for `joint` (in `periods`, its buffer) that have not
    /// started yet: the producer's positions minus these are the motors' positions.
    /// `first_unplayed`: buffer index (0..2*HALF) of the first period that has not
    /// started, or `None` if the second prelude period has not either (the DMA has not
    /// transferred anything). The rest of that period's half is unplayed, and so is the
    /// other half unless `other_half_played` (its refill interrupt is still pending: it
    /// holds periods that already played). Constant time: it reads the running sums the
    /// refills wrote, not `periods` (kept in the signature: the callers hold the buffer
    /// these sums describe).
    #[allow(
        clippy::indexing_slicing,
        reason = "the joint number is masked to 0..MAX_JOINTS; h = index / HALF < 2 (index < 2 * HALF), from <= HALF, the halves' length; PRELUDE - 1 < PRELUDE"
    )]
    pub fn unplayed_steps(
        &self,
        joint: usize,
        periods: &JointBuffer<HALF>,
        first_unplayed: Option<usize>,
        other_half_played: bool,
    ) -> i32 {
        let j = joint & (MAX_JOINTS - 1);
        let _ = periods;
        let sums = &self.sums[j];
        let half_sums = &self.half_sums[j];
        // Signed pulses of half `h` from period `from` (0..=HALF) on: the half's total less
        // those before `from`, from the running sums its refill wrote (or, for a half of
        // one straight cruise, one pulse per period).
        #[allow(
            clippy::cast_possible_wrap,
            clippy::cast_possible_truncation,
            reason = "HALF - from <= HALF <= i16::MAX (FITS)"
        )]
        let sum = |h: usize, from: usize| {
            match half_sums[h] {
                HalfSums::Every(sign) => {
                    return i32::from(sign) * HALF.saturating_sub(from) as i32;
                }
                HalfSums::NoPulse => return 0,
                HalfSums::OneSign { sign, pulses } => {
                    let after = pulses.checked_shr(from as u32).unwrap_or(0);
                    return i32::from(sign) * after.count_ones() as i32;
                }
                HalfSums::Table => {}
            }
            let total = i32::from(sums[h][HALF - 1]);
            match from.checked_sub(1) {
                Some(before) => total - i32::from(sums[h][before.min(HALF - 1)]),
                None => total,
            }
        };
        match first_unplayed {
            None => i32::from(self.prelude_deltas[j][PRELUDE - 1]) + sum(0, 0) + sum(1, 0),
            Some(index) => {
                let index = index % (2 * HALF);
                let (h, i) = (index / HALF, index % HALF);
                if other_half_played {
                    sum(h, i)
                } else {
                    sum(h, i) + sum(1 - h, 0)
                }
            }
        }
    }

    /// `joint`'s half `half` (`periods`, just filled) as [`HalfSums::OneSign`], if its
    /// marks are all of one sign and it has at most 64 periods: cheaper to write than the
    /// running sums (a bit per period, the marks read four at a time), and as exact.
    /// `None`: both signs marked (a reversal inside the half, or the period closed from
    /// the half before), or a half too long for the bit mask.
    #[allow(
        clippy::indexing_slicing,
        clippy::cast_sign_loss,
        reason = "j < MAX_JOINTS and h < 2 (the caller masks them), i < HALF <= 64; the marks' bytes are read as bits"
    )]
    fn one_sign(&self, j: usize, h: usize, periods: &[PulsePeriod; HALF]) -> Option<HalfSums> {
        if HALF > 64 {
            return None;
        }
        let signs = &self.signs[j][h];
        // Marks are -1 (0xFF), 0 or +1 (0x01): a byte with bit 0 and not bit 7 is +1.
        let (mut positive, mut negative) = (0u32, 0u32);
        for four in signs.chunks_exact(4) {
            let w =
                u32::from_le_bytes([four[0] as u8, four[1] as u8, four[2] as u8, four[3] as u8]);
            positive |= w & !(w >> 7) & 0x0101_0101;
            negative |= w & 0x8080_8080;
        }
        for &mark in signs.chunks_exact(4).remainder() {
            positive |= u32::from(mark > 0);
            negative |= u32::from(mark < 0);
        }
        if positive != 0 && negative != 0 {
            return None;
        }
        let mut pulses = 0u64;
        for (i, period) in periods.iter().enumerate() {
            if period.high != 0 {
                pulses |= 1 << i;
            }
        }
        // The half's first pulse is marked with the sign of all of them.
        let first = pulses.trailing_zeros() as usize;
        let sign = *signs.get(first)?;
        (sign != 0).then_some(HalfSums::OneSign { sign, pulses })
    }

    /// Writes the running sums of `joint`'s half `half` (`periods`, just filled): the
    /// signed pulses of periods `0..=i`, each pulse's sign the last mark at or before it
    /// (every half's first pulse is marked).
    #[allow(
        clippy::indexing_slicing,
        clippy::cast_possible_truncation,
        reason = "j < MAX_JOINTS and h < 2 (the caller masks them), i < HALF; |sum| <= HALF <= i16::MAX (FITS)"
    )]
    fn sum_half(&mut self, j: usize, h: usize, periods: &[PulsePeriod; HALF]) {
        let signs = &self.signs[j][h];
        let sums = &mut self.sums[j][h];
        let mut sign = 1i16;
        let mut sum = 0i16;
        for i in 0..HALF {
            let mark = i16::from(signs[i]);
            sign = if mark != 0 { mark } else { sign };
            sum += if periods[i].high != 0 { sign } else { 0 };
            sums[i] = sum;
        }
    }

    /// Drops every queued DIR change (after a stop).
    pub fn clear_dir_changes(&mut self) {
        for dirs in &mut self.dirs {
            dirs.len = 0;
        }
    }
}

#[cfg(test)]
mod tests {
    extern crate std;
    use std::boxed::Box;
    use std::vec;

    use super::*;

    const HALF: usize = 8;
    const TIMING: StepTiming = StepTiming {
        tick_hz: 10_000_000,
        pulse_width_ticks: 20,
        dir_setup_ticks: 50,
        step_low_ticks: 20,
    };

    /// The scan `unplayed_steps` did before it kept running sums (issue 20): the signed
    /// pulses of `joint`'s buffer from `first_unplayed` on, walked period by period.
    fn scanned<const Q: usize>(
        streams: &StepStreams<Q, HALF>,
        joint: usize,
        periods: &JointBuffer<HALF>,
        first_unplayed: Option<usize>,
        other_half_played: bool,
    ) -> i32 {
        let signs = &streams.signs[joint];
        let sum = |h: usize, from: usize| {
            let start = signs[h][..from].iter().rev().find(|&&m| m != 0).copied();
            sign_of(
                &periods.periods[h][from..],
                &signs[h][from..],
                start.unwrap_or(1),
            )
            .map(i32::from)
            .sum::<i32>()
        };
        match first_unplayed {
            None => i32::from(streams.prelude_deltas[joint][PRELUDE - 1]) + sum(0, 0) + sum(1, 0),
            Some(index) => {
                let (h, i) = (index / HALF, index % HALF);
                if other_half_played {
                    sum(h, i)
                } else {
                    sum(h, i) + sum(1 - h, 0)
                }
            }
        }
    }

    /// Every joint's unplayed pulses, at every place a stream can stand, equal the scan's
    /// after the prime and after each refill of a run that reverses within halves (marks
    /// in the middle of a half) and has idle stretches.
    #[test]
    fn unplayed_steps_equal_the_scan_at_every_index() {
        let mut streams = Box::new(StepStreams::<16, HALF>::new(TIMING, [1 << 16; MAX_JOINTS]));
        // 40 us segments: 5-12 pulses each, so a half of 8 periods holds reversals.
        // Then two long segments (200 us, 30 pulses): halves of one straight cruise.
        for (n, steps) in [5, -7, 12, -3, 0, 9, -12, 4, -1, 6, 30, -30]
            .into_iter()
            .enumerate()
        {
            let mut joints = [0i32; MAX_JOINTS];
            for (j, s) in joints.iter_mut().enumerate() {
                *s = if j % 2 == 0 {
                    steps
                } else {
                    -steps / (1 + n as i32 % 3)
                };
            }
            let segment = Segment {
                duration_us: if steps.abs() >= 30 { 200 } else { 40 },
                steps: joints,
            };
            assert!(streams.producer().push(segment).is_ok());
        }
        let mut prelude = [[PulsePeriod::ZERO; PRELUDE]; MAX_JOINTS];
        let mut buffers: [JointBuffer<HALF>; MAX_JOINTS] =
            core::array::from_fn(|_| JointBuffer::ZERO);
        {
            let [b0, b1, b2, b3, b4, b5, b6, b7] = &mut buffers;
            streams.prime(100, &mut prelude, &mut [b0, b1, b2, b3, b4, b5, b6, b7]);
        }
        let check = |streams: &StepStreams<16, HALF>, buffers: &[JointBuffer<HALF>]| {
            for (joint, buffer) in buffers.iter().enumerate() {
                let mut places = vec![None];
                places.extend((0..2 * HALF).map(Some));
                for first in places {
                    for other in [false, true] {
                        assert_eq!(
                            streams.unplayed_steps(joint, buffer, first, other),
                            scanned(streams, joint, buffer, first, other),
                            "joint {joint}, first unplayed {first:?}, other half played {other}"
                        );
                    }
                }
                for half in 0..2 {
                    assert_eq!(
                        streams.unplayed_evicted(joint, buffer, half),
                        i32::from(streams.evicted[joint][half])
                            + scanned(streams, joint, buffer, Some(0), false)
                    );
                }
            }
        };
        check(&streams, &buffers);
        let mut pulses = 0;
        // Which ways of keeping the sums the run went through: all four must be checked.
        let mut kinds = [false; 4];
        for round in 0..40 {
            let half = round % 2;
            for (joint, buffer) in buffers.iter_mut().enumerate() {
                streams.refill(joint, half, &mut buffer.periods[half]);
                pulses += buffer.periods[half].iter().filter(|p| p.high != 0).count();
                kinds[match streams.half_sums[joint][half] {
                    HalfSums::Table => 0,
                    HalfSums::Every(_) => 1,
                    HalfSums::OneSign { .. } => 2,
                    HalfSums::NoPulse => 3,
                }] = true;
            }
            check(&streams, &buffers);
        }
        assert!(pulses > 100, "the run wrote pulses: {pulses}");
        assert_eq!(kinds, [true; 4], "table, every, one sign, no pulse");
    }

    /// The shared queues get the same DIR changes, in the same order, as the streams' own.
    #[test]
    fn shared_dir_queues_get_the_changes_of_the_own_ones() {
        let make = || {
            let mut streams = Box::new(StepStreams::<16, HALF>::new(TIMING, [1 << 16; MAX_JOINTS]));
            for steps in [5, -7, 12, -3, 0, 9, -12, 4, -1, 6] {
                let segment = Segment {
                    duration_us: 40,
                    steps: [steps, -steps, steps / 2, 0, 1, -1, steps, 3],
                };
                assert!(streams.producer().push(segment).is_ok());
            }
            streams
        };
        let (mut own, mut shared) = (make(), make());
        let queues = DirQueues::new();
        let mut prelude = [[PulsePeriod::ZERO; PRELUDE]; MAX_JOINTS];
        let mut a: [JointBuffer<HALF>; MAX_JOINTS] = core::array::from_fn(|_| JointBuffer::ZERO);
        let mut b: [JointBuffer<HALF>; MAX_JOINTS] = core::array::from_fn(|_| JointBuffer::ZERO);
        {
            let [a0, a1, a2, a3, a4, a5, a6, a7] = &mut a;
            own.prime(100, &mut prelude, &mut [a0, a1, a2, a3, a4, a5, a6, a7]);
            let [b0, b1, b2, b3, b4, b5, b6, b7] = &mut b;
            shared.prime_shared(
                100,
                &mut prelude,
                &mut [b0, b1, b2, b3, b4, b5, b6, b7],
                &queues,
            );
        }
        let mut changes = 0;
        for round in 0..30 {
            let half = round % 2;
            for joint in 0..MAX_JOINTS {
                own.refill(joint, half, &mut a[joint].periods[half]);
                shared.refill_shared(joint, half, &mut b[joint].periods[half], &queues);
                assert_eq!(a[joint].periods[half], b[joint].periods[half]);
                while let Some(change) = own.next_dir_change(joint) {
                    assert_eq!(queues.peek(joint), Some(change), "joint {joint}");
                    own.pop_dir_change(joint);
                    queues.pop(joint);
                    changes += 1;
                }
                assert_eq!(queues.peek(joint), None);
            }
        }
        assert!(changes > 20, "the run reversed: {changes} DIR changes");
    }

    /// Priming joint by joint gives the same periods, preludes, DIR changes and outcome as
    /// priming at once. (A segment pushed between two pieces would reach the joints primed
    /// before it as late segments do in a run: after their idle periods. On the board only
    /// the trajectory task pushes, and it is the one running the pieces.)
    #[test]
    fn priming_in_pieces_equals_priming_at_once() {
        let segments = [5, -7, 12, -3, 0, 9].map(|steps| Segment {
            duration_us: 40,
            steps: [steps, -steps, steps / 2, 0, 1, -1, steps, 3],
        });
        let make = || {
            let mut streams = Box::new(StepStreams::<16, HALF>::new(TIMING, [1 << 16; MAX_JOINTS]));
            for segment in &segments {
                assert!(streams.producer().push(*segment).is_ok());
            }
            streams
        };
        let (mut whole, mut pieces) = (make(), make());
        let (q1, q2) = (DirQueues::new(), DirQueues::new());
        let mut p1 = [[PulsePeriod::ZERO; PRELUDE]; MAX_JOINTS];
        let mut p2 = [[PulsePeriod::ZERO; PRELUDE]; MAX_JOINTS];
        let mut a: [JointBuffer<HALF>; MAX_JOINTS] = core::array::from_fn(|_| JointBuffer::ZERO);
        let mut b: [JointBuffer<HALF>; MAX_JOINTS] = core::array::from_fn(|_| JointBuffer::ZERO);
        let at_once = {
            let [a0, a1, a2, a3, a4, a5, a6, a7] = &mut a;
            whole.prime_shared(100, &mut p1, &mut [a0, a1, a2, a3, a4, a5, a6, a7], &q1)
        };
        pieces.prime_begin_shared(100, &q2);
        let mut in_pieces = Refill::default();
        for joint in 0..MAX_JOINTS {
            let r = pieces.prime_joint_shared(joint, &mut p2[joint], &mut b[joint], &q2);
            in_pieces.segments_finished += r.segments_finished;
            in_pieces.dir_overflow |= r.dir_overflow;
        }
        assert_eq!(at_once, in_pieces);
        assert_eq!(p1, p2);
        for joint in 0..MAX_JOINTS {
            assert_eq!(a[joint].periods, b[joint].periods, "joint {joint}");
            while let Some(change) = q1.peek(joint) {
                assert_eq!(q2.peek(joint), Some(change));
                q1.pop(joint);
                q2.pop(joint);
            }
            assert_eq!(q2.peek(joint), None);
            assert_eq!(
                whole.unstarted_steps(joint, &a[joint]),
                pieces.unstarted_steps(joint, &b[joint])
            );
            assert_eq!(
                whole.unstarted_steps(joint, &a[joint]),
                whole.producer_ref().positions()[joint],
                "nothing played: every pulse written is unstarted"
            );
        }
    }
}
