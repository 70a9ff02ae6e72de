//! [`GuardedDriver`]: the boards' (and the simulator's TAP mode's) first look at a
//! datagram, inside the Ethernet driver's receive path, before embassy-net's socket.

use embassy_net_driver::{Capabilities, Driver, HardwareAddress, LinkState, RxToken};

use super::{Ingress, StepHalt, to_group, udp_payload};
use crate::bus::Bus;
use crate::hw::Clock;

/// An embassy-net driver that hands every IPv4/UDP frame to the controller's `port` to
/// [`Bus::receive_first`] as the stack consumes it, before smoltcp and the socket see it:
/// a CRC-valid STOPPED halts the steps and goes to `bus.estop` there; a datagram over its
/// sender's share is shed. The stack is then given an empty frame, which it drops as
/// malformed without a trace. Everything else (ARP, ICMP, other ports) passes untouched.
pub struct GuardedDriver<'a, D, H, C> {
    inner: D,
    bus: &'a Bus,
    halt: H,
    clock: &'a C,
    port: u16,
}

impl<'a, D: Driver, H: StepHalt, C: Clock> GuardedDriver<'a, D, H, C> {
    /// Guards `inner`'s frames to UDP `port` (the controller's, [`protocol::PORT`]).
    pub fn new(inner: D, bus: &'a Bus, halt: H, clock: &'a C, port: u16) -> Self {
        GuardedDriver {
            inner,
            bus,
            halt,
            clock,
            port,
        }
    }
}

/// The receive token of a [`GuardedDriver`].
pub struct GuardedRx<'a, T, H, C> {
    rx: T,
    bus: &'a Bus,
    halt: &'a H,
    clock: &'a C,
    port: u16,
}

impl<T: RxToken, H: StepHalt, C: Clock> RxToken for GuardedRx<'_, T, H, C> {
    fn consume<R, F>(self, f: F) -> R
    where
        F: FnOnce(&mut [u8]) -> R,
    {
        let GuardedRx {
            rx,
            bus,
            halt,
            clock,
            port,
        } = self;
        rx.consume(|frame| {
            let group = to_group(frame);
            let pass = match udp_payload(frame, port) {
                Some((from, payload)) => {
                    bus.receive_first(from, payload, group, clock.now_us(), halt) == Ingress::Admit
                }
                None => true,
            };
            if pass { f(frame) } else { f(&mut []) }
        })
    }
}

impl<D: Driver, H: StepHalt, C: Clock> Driver for GuardedDriver<'_, D, H, C> {
    type RxToken<'b>
        = GuardedRx<'b, D::RxToken<'b>, H, C>
    where
        Self: 'b;
    type TxToken<'b>
        = D::TxToken<'b>
    where
        Self: 'b;

    fn receive(
        &mut self,
        cx: &mut core::task::Context,
    ) -> Option<(Self::RxToken<'_>, Self::TxToken<'_>)> {
        let GuardedDriver {
            inner,
            bus,
            halt,
            clock,
            port,
        } = self;
        let (rx, tx) = inner.receive(cx)?;
        Some((
            GuardedRx {
                rx,
                bus,
                halt,
                clock,
                port: *port,
            },
            tx,
        ))
    }

    fn transmit(&mut self, cx: &mut core::task::Context) -> Option<Self::TxToken<'_>> {
        self.inner.transmit(cx)
    }

    fn link_state(&mut self, cx: &mut core::task::Context) -> LinkState {
        self.inner.link_state(cx)
    }

    fn capabilities(&self) -> Capabilities {
        self.inner.capabilities()
    }

    fn hardware_address(&self) -> HardwareAddress {
        self.inner.hardware_address()
    }
}
