use core::sync::atomic::{AtomicBool, AtomicPtr, AtomicUsize, Ordering, fence};

use vcell::VolatileCell;

use crate::eth::{Packet, RX_BUFFER_SIZE, TX_BUFFER_SIZE};
use crate::pac::ETH;

/// Transmit and Receive Descriptor fields
#[allow(dead_code)]
mod emac_consts {
    pub const EMAC_DES3_OWN: u32 = 0x8000_0000;
    pub const EMAC_DES3_CTXT: u32 = 0x4000_0000;
    pub const EMAC_DES3_FD: u32 = 0x2000_0000;
    pub const EMAC_DES3_LD: u32 = 0x1000_0000;
    pub const EMAC_DES3_ES: u32 = 0x0000_8000;
    pub const EMAC_DES0_BUF1AP: u32 = 0xFFFF_FFFF;

    pub const EMAC_TDES2_IOC: u32 = 0x8000_0000;
    pub const EMAC_TDES2_B1L: u32 = 0x0000_3FFF;

    pub const EMAC_RDES3_IOC: u32 = 0x4000_0000;
    pub const EMAC_RDES3_PL: u32 = 0x0000_7FFF;
    pub const EMAC_RDES3_BUF1V: u32 = 0x0100_0000;
    pub const EMAC_RDES3_PKTLEN: u32 = 0x0000_7FFF;
}
use emac_consts::*;

/// Transmit Descriptor representation
///
/// * tdes0: transmit buffer address
/// * tdes1:
/// * tdes2: buffer lengths
/// * tdes3: control and payload/frame length
#[repr(C)]
pub(crate) struct TDes {
    tdes0: VolatileCell<u32>,
    tdes1: VolatileCell<u32>,
    tdes2: VolatileCell<u32>,
    tdes3: VolatileCell<u32>,
}

impl TDes {
    pub const fn new() -> Self {
        Self {
            tdes0: VolatileCell::new(0),
            tdes1: VolatileCell::new(0),
            tdes2: VolatileCell::new(0),
            tdes3: VolatileCell::new(0),
        }
    }

    /// Return true if this TDes is not currently owned by the DMA
    fn available(&self) -> bool {
        self.tdes3.get() & EMAC_DES3_OWN == 0
    }
}

pub(crate) struct TDesRing<'a> {
    descriptors: &'a mut [TDes],
    buffers: &'a mut [Packet<TX_BUFFER_SIZE>],
    index: usize,
}

impl<'a> TDesRing<'a> {
    /// Initialise this TDesRing. Assume TDesRing is corrupt.
    pub fn new(descriptors: &'a mut [TDes], buffers: &'a mut [Packet<TX_BUFFER_SIZE>]) -> Self {
        assert!(descriptors.len() > 0);
        assert!(descriptors.len() == buffers.len());

        for td in descriptors.iter_mut() {
            *td = TDes::new();
        }

        // Initialize the pointers in the DMA engine. (There will be a memory barrier later
        // before the DMA engine is enabled.)
        let dma = ETH.ethernet_dma();
        dma.dmactx_dlar().write(|w| w.0 = descriptors.as_mut_ptr() as u32);
        dma.dmactx_rlr().write(|w| w.set_tdrl((descriptors.len() as u16) - 1));
        dma.dmactx_dtpr().write(|w| w.0 = 0);

        Self {
            descriptors,
            buffers,
            index: 0,
        }
    }

    pub(crate) fn len(&self) -> usize {
        self.descriptors.len()
    }

    /// Return the next available packet buffer for transmitting, or None
    pub(crate) fn available(&mut self) -> Option<&mut [u8]> {
        let d = &mut self.descriptors[self.index];
        if d.available() {
            Some(&mut self.buffers[self.index].0)
        } else {
            None
        }
    }

    /// Transmit the packet written in a buffer returned by `available`.
    pub(crate) fn transmit(&mut self, len: usize) {
        let td = &mut self.descriptors[self.index];
        assert!(td.available());
        assert!(len as u32 <= EMAC_TDES2_B1L);

        // Read format
        td.tdes0.set(self.buffers[self.index].0.as_ptr() as u32);
        td.tdes2.set(len as u32 & EMAC_TDES2_B1L | EMAC_TDES2_IOC);

        // FD: Contains first buffer of packet
        // LD: Contains last buffer of packet
        // Give the DMA engine ownership
        td.tdes3.set(EMAC_DES3_FD | EMAC_DES3_LD | EMAC_DES3_OWN);

        // Ensure changes to the descriptor are committed before DMA engine sees tail pointer store.
        // This will generate an DMB instruction.
        // "Preceding reads and writes cannot be moved past subsequent writes."
        fence(Ordering::Release);

        // signal DMA it can try again.
        // See issue #2129
        ETH.ethernet_dma().dmactx_dtpr().write(|w| w.0 = &td as *const _ as u32);

        self.index = (self.index + 1) % self.descriptors.len();
    }
}

/// Receive Descriptor representation
///
/// * rdes0: receive buffer address
/// * rdes1:
/// * rdes2:
/// * rdes3: OWN and Status
#[repr(C)]
pub(crate) struct RDes {
    rdes0: VolatileCell<u32>,
    rdes1: VolatileCell<u32>,
    rdes2: VolatileCell<u32>,
    rdes3: VolatileCell<u32>,
}

impl RDes {
    pub const fn new() -> Self {
        Self {
            rdes0: VolatileCell::new(0),
            rdes1: VolatileCell::new(0),
            rdes2: VolatileCell::new(0),
            rdes3: VolatileCell::new(0),
        }
    }

    /// Return true if this RDes is acceptable to us
    #[inline(always)]
    fn valid(&self) -> bool {
        // Write-back descriptor is valid if:
        //
        // Contains first buffer of packet AND contains last buf of
        // packet AND no errors AND not a context descriptor
        self.rdes3.get() & (EMAC_DES3_FD | EMAC_DES3_LD | EMAC_DES3_ES | EMAC_DES3_CTXT)
            == (EMAC_DES3_FD | EMAC_DES3_LD)
    }

    /// Return true if this RDes is not currently owned by the DMA
    #[inline(always)]
    fn available(&self) -> bool {
        self.rdes3.get() & EMAC_DES3_OWN == 0 // Owned by us
    }

    #[inline(always)]
    fn set_ready(&self, buf: *const u8) {
        self.rdes0.set(buf as u32);
        self.rdes3.set(EMAC_RDES3_BUF1V | EMAC_RDES3_IOC | EMAC_DES3_OWN);
    }
}

// armctl patch (issue 30): the receive ring is shared with the application's ETH interrupt,
// which may drop the oldest frame while the ring is full ([`rx_drop_oldest`]), so that the
// MAC always has a descriptor for the next frame and the interrupt sees every frame (a
// STOPPED among them) however long the stack's runner waits. Embassy's ring index was a
// private field; it is here a static the interrupt reads, with `RX_HELD`, which says the
// driver holds a frame (from `available` to `pop_packet`): the interrupt then leaves the
// ring alone. Single core: the interrupt preempts the driver and never the other way round,
// so each side's sequence of steps is never interleaved with the other's except at the
// points where the driver has set `RX_HELD` (before it reads the index or a descriptor) or
// cleared it (after it gave its frame back). Only one Ethernet exists.

/// The ring's descriptors, buffers and length for [`rx_drop_oldest`] (null until the ring
/// is made).
static RX_DESCRIPTORS: AtomicPtr<RDes> = AtomicPtr::new(core::ptr::null_mut());
static RX_BUFFERS: AtomicPtr<Packet<RX_BUFFER_SIZE>> = AtomicPtr::new(core::ptr::null_mut());
static RX_LEN: AtomicUsize = AtomicUsize::new(0);
/// The driver's next descriptor (embassy's `index`).
static RX_INDEX: AtomicUsize = AtomicUsize::new(0);
/// The driver may be using descriptor `RX_INDEX` and its buffer.
static RX_HELD: AtomicBool = AtomicBool::new(false);

/// What [`rx_drop_oldest`] did.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum RxOldest {
    /// The oldest frame was given back to the DMA (the driver will not see it).
    Dropped,
    /// The DMA owns the driver's next descriptor: no frame waits.
    Empty,
    /// The driver holds the oldest frame (or the ring is not made yet): nothing done.
    Held,
    /// `keep` said keep it: nothing done.
    Kept,
}

/// For the ETH interrupt only (armctl patch, issue 30): the oldest received frame the
/// driver has not taken yet (its bytes if the descriptor is a valid whole frame, `None`
/// otherwise) goes to `keep`; unless that says keep it, its descriptor is given back to
/// the DMA (the frame is dropped, as the MAC drops new frames when the ring is full) and the
/// driver's next frame is the one after it. Frames stay in order.
///
/// # Safety
/// Call only from the Ethernet interrupt (or anything that the driver's code never
/// preempts and that never preempts itself), on a single core.
pub unsafe fn rx_drop_oldest(keep: impl FnOnce(Option<&[u8]>) -> bool) -> RxOldest {
    let descriptors = RX_DESCRIPTORS.load(Ordering::Acquire);
    let buffers = RX_BUFFERS.load(Ordering::Acquire);
    let len = RX_LEN.load(Ordering::Acquire);
    if descriptors.is_null() || buffers.is_null() || len == 0 || RX_HELD.load(Ordering::SeqCst) {
        return RxOldest::Held;
    }
    let index = RX_INDEX.load(Ordering::SeqCst) % len;
    // SAFETY: `index < len`, the ring `RDesRing::new` published; descriptors are volatile
    // cells, shared with the DMA and the driver by shared references.
    let descriptor = unsafe { &*descriptors.add(index) };
    if !descriptor.available() {
        return RxOldest::Empty;
    }
    fence(Ordering::SeqCst);
    // SAFETY: the buffer of a descriptor the DMA gave back and the driver does not hold
    // (RX_HELD is clear, and the driver cannot run before this returns): no one writes it.
    let frame = descriptor.valid().then(|| unsafe {
        let packet = &*buffers.add(index);
        let len = (descriptor.rdes3.get() & EMAC_RDES3_PKTLEN) as usize;
        &packet.0[..len.min(RX_BUFFER_SIZE)]
    });
    if keep(frame) {
        return RxOldest::Kept;
    }
    // SAFETY: as above; the DMA may write the buffer again once the descriptor is its own.
    descriptor.set_ready(unsafe { (*buffers.add(index)).0.as_ptr() });
    fence(Ordering::Release);
    ETH.ethernet_dma().dmacrx_dtpr().write(|w| w.0 = descriptor as *const _ as u32);
    RX_INDEX.store((index + 1) % len, Ordering::SeqCst);
    RxOldest::Dropped
}

/// Rx ring of descriptors and packets (armctl patch: shared with the ETH interrupt, see
/// [`rx_drop_oldest`]).
pub(crate) struct RDesRing<'a> {
    descriptors: &'a [RDes],
    buffers: *mut Packet<RX_BUFFER_SIZE>,
    _buffers: core::marker::PhantomData<&'a mut [Packet<RX_BUFFER_SIZE>]>,
}

// SAFETY: as embassy's ring, which held `&mut` to its buffers: the ring is their only user
// besides the DMA and `rx_drop_oldest` (an interrupt, which leaves the held frame alone).
unsafe impl Send for RDesRing<'_> {}

impl<'a> RDesRing<'a> {
    pub(crate) fn new(descriptors: &'a mut [RDes], buffers: &'a mut [Packet<RX_BUFFER_SIZE>]) -> Self {
        assert!(descriptors.len() > 1);
        assert!(descriptors.len() == buffers.len());

        for (i, desc) in descriptors.iter_mut().enumerate() {
            *desc = RDes::new();
            desc.set_ready(buffers[i].0.as_mut_ptr());
        }

        let dma = ETH.ethernet_dma();
        dma.dmacrx_dlar().write(|w| w.0 = descriptors.as_mut_ptr() as u32);
        dma.dmacrx_rlr().write(|w| w.set_rdrl((descriptors.len() as u16) - 1));
        dma.dmacrx_dtpr().write(|w| w.0 = 0);

        let buffers = buffers.as_mut_ptr();
        let descriptors: &'a [RDes] = descriptors;
        RX_HELD.store(false, Ordering::SeqCst);
        RX_INDEX.store(0, Ordering::SeqCst);
        RX_LEN.store(descriptors.len(), Ordering::Release);
        RX_BUFFERS.store(buffers, Ordering::Release);
        RX_DESCRIPTORS.store(descriptors.as_ptr().cast_mut(), Ordering::Release);

        Self {
            descriptors,
            buffers,
            _buffers: core::marker::PhantomData,
        }
    }

    /// Get a received packet if any, or None. Holds the ring against the interrupt's
    /// [`rx_drop_oldest`] until [`RDesRing::pop_packet`] or [`RDesRing::release`].
    pub(crate) fn available(&mut self) -> Option<&mut [u8]> {
        RX_HELD.store(true, Ordering::SeqCst);
        // Not sure if the contents of the write buffer on the M7 can affects reads, so we are using
        // a DMB here just in case, it also serves as a hint to the compiler that we're syncing the
        // buffer (I think .-.)
        fence(Ordering::SeqCst);

        // We might have to process many packets, in case some have been rx'd but are invalid.
        let index = loop {
            let index = RX_INDEX.load(Ordering::SeqCst);
            let descriptor = &self.descriptors[index];
            if !descriptor.available() {
                self.release();
                return None;
            }

            // If packet is invalid, pop it and try again.
            if !descriptor.valid() {
                warn!("invalid packet: {:08x}", descriptor.rdes0.get());
                self.pop_packet();
                RX_HELD.store(true, Ordering::SeqCst);
                continue;
            }

            break index;
        };

        let descriptor = &self.descriptors[index];
        let len = (descriptor.rdes3.get() & EMAC_RDES3_PKTLEN) as usize;
        // SAFETY: buffer `index` of the ring; the DMA gave it back and the interrupt leaves
        // it alone while RX_HELD is set (until `pop_packet`); `&mut self` is the driver's.
        let packet = unsafe { &mut *self.buffers.add(index) };
        return Some(&mut packet.0[..len]);
    }

    /// The driver does not use the frame `available` returned (it takes it later, again
    /// with `available`): the interrupt may drop it meanwhile.
    pub(crate) fn release(&mut self) {
        RX_HELD.store(false, Ordering::SeqCst);
    }

    /// Pop the packet previously returned by `available`.
    pub(crate) fn pop_packet(&mut self) {
        let index = RX_INDEX.load(Ordering::SeqCst);
        let rd = &self.descriptors[index];
        assert!(rd.available());

        // SAFETY: buffer `index` of the ring (see `available`).
        rd.set_ready(unsafe { (*self.buffers.add(index)).0.as_ptr() });

        // "Preceding reads and writes cannot be moved past subsequent writes."
        fence(Ordering::Release);

        // signal DMA it can try again.
        // See issue #2129
        ETH.ethernet_dma().dmacrx_dtpr().write(|w| w.0 = &rd as *const _ as u32);

        // Increment index.
        RX_INDEX.store((index + 1) % self.descriptors.len(), Ordering::SeqCst);
        RX_HELD.store(false, Ordering::SeqCst);
    }
}
