//! The serial task: the USART pass-through's both directions.

use embassy_futures::join::join;
use embassy_futures::select::{Either, select};
use protocol::{MAX_SERIAL_CHUNK, UartInit, UartMode};

use crate::bus::Bus;
use crate::hw::{Clock, SerialError, SerialPort};
use crate::outgoing::Outgoing;
use crate::serial::{SerialBatcher, byte_time_us};

/// The serial pass-through: writes USART_SEND payloads, and reads the port into
/// USART_RECV reports (sent when 255 bytes wait, after one byte time of idle line, or 1 ms
/// after data arrived). `port.read` must be cancel-safe (a read dropped before it
/// completes loses no byte), since it is raced against the batch deadline.
pub async fn serial_task<P: SerialPort, C: Clock>(port: &P, bus: &Bus, clock: &C) -> ! {
    let writer = async {
        loop {
            let bytes = bus.serial_tx.receive().await;
            if let Err(e) = port.write(&bytes).await {
                warn!("serial write failed: {:?}", e);
            }
        }
    };
    let reader = async {
        let mut open: Option<UartInit> = None;
        let mut batch = SerialBatcher::new(0);
        let mut buf = [0u8; MAX_SERIAL_CHUNK];
        loop {
            if let Some(init) = bus.serial_opened.try_take() {
                open = Some(init);
            }
            let init = match open {
                Some(init) if init.mode() != UartMode::TransmitOnly => init,
                _ => {
                    // Closed, or nothing to read: wait for the next USART_START.
                    batch.clear();
                    open = Some(bus.serial_opened.wait().await);
                    continue;
                }
            };
            batch.set_byte_time_us(byte_time_us(&init));
            let room = batch.room().min(buf.len());
            let read = port.read(buf.get_mut(..room).unwrap_or_default());
            let outcome = match batch.deadline_us() {
                Some(deadline) => match select(read, clock.sleep_until(deadline)).await {
                    Either::First(r) => Some(r),
                    Either::Second(()) => None,
                },
                None => Some(read.await),
            };
            match outcome {
                Some(Ok(n)) => {
                    batch.push(buf.get(..n).unwrap_or_default(), clock.now_us());
                }
                Some(Err(SerialError::Closed)) => {
                    batch.clear();
                    open = None;
                }
                Some(Err(e)) => warn!("serial read failed: {:?}", e),
                None => {}
            }
            if batch.is_due(clock.now_us()) {
                bus.send(Outgoing::UsartRecv(batch.take()));
            }
        }
    };
    match join(writer, reader).await {}
}
