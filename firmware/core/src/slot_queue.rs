//! A queue of fixed slots whose critical sections move slot numbers, never the values
//! (issue 34): the bus's datagram and frame queues ([`crate::bus::Bus`]).
//!
//! embassy-sync's `Channel` copies each value into and out of its ring inside its critical
//! section, and the bus's critical sections mask every interrupt (`cortex-m`'s single-core
//! implementation), the DIR changes' (TIM13) and the e-stop input's too. Measured on the
//! board's ELF on Renode (`tests/tests/renode_cost.rs`) during a flood with 1 kHz LOCATION
//! reports: 3,809 instructions masked routing one datagram (a 1,484-byte `memcpy`), 1,277
//! peeking at the inbox (`try_peek` clones the datagram), 400 queueing a frame to send:
//! 9.5 us against the 1 us goal.
//!
//! Here a sender reserves a free slot (a short critical section: a bit in a mask), moves its
//! value in with interrupts running, then commits the slot's number to the ready ring
//! (another short one, which also wakes the receiver). A receiver pops a number, moves the
//! value out with interrupts running, and frees the slot. A slot is reserved or popped by
//! one party at a time, so the moves need no lock. [`Filled::commit_with`] lets the one
//! who commits change the value in the same critical section as something else (the bus
//! stamps a datagram with the STOPPEDs routed before it, atomically with its place).

use core::cell::{RefCell, UnsafeCell};
use core::future::poll_fn;
use core::mem::MaybeUninit;
use core::task::Poll;

use embassy_sync::blocking_mutex::Mutex;
use embassy_sync::channel::{TryReceiveError, TrySendError};
use embassy_sync::waitqueue::WakerRegistration;
use heapless::Deque;

use crate::bus::Cs;

/// Most slots a queue may have: the in-use mask is a `u128`.
pub const MAX_SLOTS: usize = 128;

/// Which slots are taken and which hold a value ready to receive.
struct Index<const N: usize> {
    /// Bit `i`: slot `i` is reserved, ready or being read.
    used: u128,
    /// Ready slots, oldest first.
    ready: Deque<u8, N>,
    /// The receiver waiting for a value.
    receiver: WakerRegistration,
}

/// A first-in first-out queue of `N` values of `T` (see the module docs).
pub struct SlotQueue<T, const N: usize> {
    slots: [UnsafeCell<MaybeUninit<T>>; N],
    index: Mutex<Cs, RefCell<Index<N>>>,
}

// SAFETY: a slot's contents are touched only by the one party that holds it (reserved by
// a sender until committed, popped by a receiver until freed), as the index says; the
// index itself is behind a critical-section mutex. Values cross tasks and interrupts, so
// `T: Send`.
unsafe impl<T: Send, const N: usize> Sync for SlotQueue<T, N> {}

impl<T, const N: usize> Default for SlotQueue<T, N> {
    fn default() -> Self {
        Self::new()
    }
}

impl<T, const N: usize> SlotQueue<T, N> {
    /// An empty queue.
    pub const fn new() -> Self {
        const {
            assert!(N > 0 && N <= MAX_SLOTS, "a SlotQueue has 1 to 128 slots");
        }
        SlotQueue {
            slots: [const { UnsafeCell::new(MaybeUninit::uninit()) }; N],
            index: Mutex::new(RefCell::new(Index {
                used: 0,
                ready: Deque::new(),
                receiver: WakerRegistration::new(),
            })),
        }
    }

    /// Reserves a free slot and moves `value` into it (outside any critical section); the
    /// value comes back if every slot is taken.
    pub fn try_fill(&self, value: T) -> Result<Filled<'_, T, N>, T> {
        let slot = self.index.lock(|index| {
            let mut index = index.borrow_mut();
            let free = (!index.used).trailing_zeros() as usize;
            (free < N).then(|| {
                index.used |= 1 << free;
                free
            })
        });
        let Some(slot) = slot else {
            return Err(value);
        };
        // SAFETY: the slot was free and is now reserved by this call alone.
        unsafe { (*self.cell(slot).get()).write(value) };
        Ok(Filled {
            queue: self,
            slot: Some(slot),
        })
    }

    /// Queues `value` (a full queue gives it back).
    pub fn try_send(&self, value: T) -> Result<(), TrySendError<T>> {
        match self.try_fill(value) {
            Ok(filled) => {
                filled.commit_with(|_| {});
                Ok(())
            }
            Err(value) => Err(TrySendError::Full(value)),
        }
    }

    /// Takes the oldest value, moved out outside any critical section.
    pub fn try_receive(&self) -> Result<T, TryReceiveError> {
        let slot = self
            .index
            .lock(|index| index.borrow_mut().ready.pop_front())
            .ok_or(TryReceiveError::Empty)?;
        Ok(self.take(usize::from(slot)))
    }

    /// Waits for the oldest value and takes it.
    pub async fn receive(&self) -> T {
        let slot = poll_fn(|cx| {
            self.index.lock(|index| {
                let mut index = index.borrow_mut();
                match index.ready.pop_front() {
                    Some(slot) => Poll::Ready(slot),
                    None => {
                        index.receiver.register(cx.waker());
                        Poll::Pending
                    }
                }
            })
        })
        .await;
        self.take(usize::from(slot))
    }

    /// `f` of the oldest value, in the critical section (keep `f` short: a field read).
    pub fn peek_with<R>(&self, f: impl FnOnce(&T) -> R) -> Option<R> {
        self.index.lock(|index| {
            let index = index.borrow();
            let slot = usize::from(*index.ready.front()?);
            // SAFETY: a ready slot holds a value, and no one moves it out while its
            // number is in the ready ring, which this critical section keeps.
            Some(f(unsafe { (*self.cell(slot).get()).assume_init_ref() }))
        })
    }

    /// Values ready to receive.
    pub fn len(&self) -> usize {
        self.index.lock(|index| index.borrow().ready.len())
    }

    /// Whether no value is ready.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Slots neither ready nor being filled or read.
    pub fn free_capacity(&self) -> usize {
        N - self
            .index
            .lock(|index| index.borrow().used.count_ones() as usize)
    }

    /// Slot `slot`'s cell. Slot numbers come only from the index, always below `N`.
    #[allow(clippy::indexing_slicing)]
    fn cell(&self, slot: usize) -> &UnsafeCell<MaybeUninit<T>> {
        &self.slots[slot]
    }

    /// Moves the value out of a slot popped from the ready ring, then frees the slot.
    fn take(&self, slot: usize) -> T {
        // SAFETY: the slot was ready (holds a value) and was popped by the caller alone.
        let value = unsafe { (*self.cell(slot).get()).assume_init_read() };
        self.index
            .lock(|index| index.borrow_mut().used &= !(1 << slot));
        value
    }
}

impl<T, const N: usize> Drop for SlotQueue<T, N> {
    fn drop(&mut self) {
        while self.try_receive().is_ok() {}
    }
}

/// A reserved slot holding a value not yet queued: [`Filled::commit_with`] queues it;
/// dropped, it drops the value and frees the slot.
pub struct Filled<'a, T, const N: usize> {
    queue: &'a SlotQueue<T, N>,
    /// `None` once committed.
    slot: Option<usize>,
}

impl<T, const N: usize> Filled<'_, T, N> {
    /// Queues the value after `f` has changed it, both in one critical section (so that
    /// what `f` reads of the caller's state and the value's place agree); `f` must be
    /// short. Wakes the receiver.
    pub fn commit_with(mut self, f: impl FnOnce(&mut T)) {
        let Some(slot) = self.slot.take() else {
            return;
        };
        self.queue.index.lock(|index| {
            // SAFETY: the slot is reserved by this `Filled` alone and holds its value.
            f(unsafe { (*self.queue.cell(slot).get()).assume_init_mut() });
            let mut index = index.borrow_mut();
            // Cannot fail: at most N slots are used, so at most N are ready. The cast
            // cannot truncate: N <= MAX_SLOTS = 128.
            #[allow(clippy::cast_possible_truncation)]
            let _ = index.ready.push_back(slot as u8);
            index.receiver.wake();
        });
    }
}

impl<T, const N: usize> Drop for Filled<'_, T, N> {
    fn drop(&mut self) {
        if let Some(slot) = self.slot.take() {
            // SAFETY: reserved by this `Filled` alone, holding its value.
            unsafe { (*self.queue.cell(slot).get()).assume_init_drop() };
            self.queue
                .index
                .lock(|index| index.borrow_mut().used &= !(1 << slot));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use core::future::Future;

    #[test]
    fn first_in_first_out_and_full_gives_the_value_back() {
        let q: SlotQueue<u32, 3> = SlotQueue::new();
        for v in [1, 2, 3] {
            q.try_send(v).unwrap();
        }
        assert_eq!(q.len(), 3);
        assert_eq!(q.free_capacity(), 0);
        assert!(matches!(q.try_send(4), Err(TrySendError::Full(4))));
        assert_eq!(q.try_receive(), Ok(1));
        q.try_send(5).unwrap();
        assert_eq!(q.peek_with(|v| *v), Some(2));
        assert_eq!(q.try_receive(), Ok(2));
        assert_eq!(q.try_receive(), Ok(3));
        assert_eq!(q.try_receive(), Ok(5));
        assert_eq!(q.try_receive(), Err(TryReceiveError::Empty));
        assert!(q.is_empty());
        assert_eq!(q.free_capacity(), 3);
    }

    #[test]
    fn a_filled_slot_is_not_ready_until_committed_and_freed_if_dropped() {
        let q: SlotQueue<u32, 2> = SlotQueue::new();
        let a = q.try_fill(10).unwrap();
        assert_eq!(q.len(), 0);
        assert_eq!(q.free_capacity(), 1);
        q.try_send(11).unwrap();
        a.commit_with(|v| *v += 1);
        assert_eq!(q.try_receive(), Ok(11));
        assert_eq!(q.try_receive(), Ok(11));
        drop(q.try_fill(12).unwrap());
        assert_eq!(q.free_capacity(), 2);
        assert!(q.is_empty());
    }

    #[test]
    fn receive_waits_for_a_commit() {
        let q: SlotQueue<u32, 2> = SlotQueue::new();
        let mut receive = core::pin::pin!(q.receive());
        let waker = core::task::Waker::noop();
        let mut cx = core::task::Context::from_waker(waker);
        assert!(receive.as_mut().poll(&mut cx).is_pending());
        q.try_send(7).unwrap();
        assert_eq!(receive.as_mut().poll(&mut cx), Poll::Ready(7));
    }

    #[test]
    fn values_left_queued_are_dropped_with_the_queue() {
        let counter = std::rc::Rc::new(());
        {
            let q: SlotQueue<std::rc::Rc<()>, 4> = SlotQueue::new();
            q.try_send(counter.clone()).unwrap();
            q.try_send(counter.clone()).unwrap();
            assert_eq!(std::rc::Rc::strong_count(&counter), 3);
        }
        assert_eq!(std::rc::Rc::strong_count(&counter), 1);
    }
}
