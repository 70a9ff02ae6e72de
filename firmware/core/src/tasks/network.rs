//! The network task: the UDP socket's both directions.

use embassy_futures::join::join;
use heapless::Vec;
use protocol::MAX_DATAGRAM;

use crate::bus::{Bus, Datagram};
use crate::hw::{Clock, Datagrams};
use crate::log_limit::{LogLimit, LogVerdict};
use crate::outgoing::{MAX_REPORT_FRAME, MAX_SEALED_FRAME, ReportEncoder, Sealer, Sealing};

/// Receives datagrams and routes them ([`Bus::route`]), and sends what `bus.outbox`
/// holds, both at once. ACKs and STATUS reports go to their requester, LOCATION and
/// USART_RECV as last published in `bus.reports`. Failures a datagram can cause are
/// logged at most once a second each ([`LogLimit`]), with the count.
pub async fn network_task<D: Datagrams, C: Clock>(socket: &D, bus: &Bus, clock: &C) -> ! {
    let rx = async {
        let mut buf = [0u8; MAX_DATAGRAM];
        let mut failures = LogLimit::new();
        // Frames the board dropped with its receive ring full (the MAC for want of a
        // descriptor, or the NUCLEO's interrupt making room: the oldest), as last logged.
        let mut ring_dropped = bus.rx_ring().dropped;
        let mut ring_full = LogLimit::new();
        loop {
            match socket.recv(&mut buf).await {
                Ok((n, from)) => {
                    let bytes =
                        Vec::from_slice(buf.get(..n).unwrap_or_default()).unwrap_or_default();
                    bus.route(Datagram::new(from, bytes), clock.now_us());
                    let dropped = bus.rx_ring().dropped;
                    let new = dropped.wrapping_sub(ring_dropped);
                    if let LogVerdict::Log { suppressed } = ring_full.events(new, clock.now_us()) {
                        warn!(
                            "receive ring full: {} frames dropped since the last such line ({} in all)",
                            suppressed.saturating_add(new),
                            dropped
                        );
                    }
                    ring_dropped = dropped;
                }
                Err(e) => {
                    if let LogVerdict::Log { suppressed } = failures.event(clock.now_us()) {
                        warn!(
                            "receive failed: {:?} ({} more since the last such line)",
                            debug_value!(e),
                            suppressed
                        );
                    }
                }
            }
        }
    };
    let tx = async {
        let mut encoder = ReportEncoder::new();
        let mut buf = [0u8; MAX_REPORT_FRAME];
        let mut sealer = Sealer::new();
        let mut sealed = [0u8; MAX_SEALED_FRAME];
        let mut failures = LogLimit::new();
        let mut outbox_full = LogLimit::new();
        loop {
            let out = bus.outbox.receive().await;
            let drops = bus.take_outbox_drops();
            if let LogVerdict::Log { suppressed } = outbox_full.events(drops, clock.now_us()) {
                warn!(
                    "outbox full: {} frames dropped since the last such line",
                    suppressed.saturating_add(drops)
                );
            }
            let routes = bus.report_settings();
            let Some((destinations, n)) = encoder.encode(&out, &routes, clock.now_us(), &mut buf)
            else {
                continue;
            };
            for to in destinations {
                let frame = buf.get(..n).unwrap_or_default();
                let bytes = match sealer.seal(&out, frame, to, &routes.seal, &mut sealed) {
                    Sealing::Plain => frame,
                    Sealing::Sealed(m) => sealed.get(..m).unwrap_or_default(),
                    Sealing::Withheld => continue,
                };
                if let Err(e) = socket.send(to, bytes).await
                    && let LogVerdict::Log { suppressed } = failures.event(clock.now_us())
                {
                    warn!(
                        "send failed: {:?} ({} more since the last such line)",
                        debug_value!(e),
                        suppressed
                    );
                }
            }
        }
    };
    match join(rx, tx).await {}
}
