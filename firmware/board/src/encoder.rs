//! Absolute multi-turn encoders on RS-485 (Modbus RTU), for RETURN: UART4 with hardware
//! driver-enable, interrupt-driven (no DMA). The protocol, checks and timeouts are
//! board-logic's `encoder` module (host-tested, and the same code sim-host runs against its
//! simulated encoders); this is the bus.
//!
//! | signal | pin | to the transceiver (e.g. MAX3485, THVD1450 at 3.3 V) |
//! |---|---|---|
//! | UART4_TX | PC10 (AF8) | DI |
//! | UART4_RX | PC11 (AF8) | RO |
//! | UART4_DE | PA15 (AF8) | DE and /RE tied together |
//!
//! The USART drives DE itself (RS-485 driver-enable mode): high from the start bit of the
//! first byte to the end of the last stop bit, so the bus is released the moment the
//! request is out and the reply is never cut.
//!
//! At boot, [`ModbusEncoders::detect`] asks the joints in use once each: if none answers, the
//! board has no encoders and RETURN trusts the step count (as before); if any answers,
//! every later RETURN needs every joint's encoder, and one that does not answer ends the
//! RETURN in STOPPED without moving (logged, and `Controller::return_fault`).

use arm_core::hw::{EncoderFault, Encoders};
use board_logic::encoder::{self, EncoderBus, EncoderConfig};
use defmt::{info, warn};
use embassy_stm32::usart::{self, BufferedUart};
use embassy_time::{Duration, Timer, with_timeout};
use embedded_io_async::{Read, Write};
use protocol::MAX_JOINTS;

/// The encoders' settings: joint j at Modbus address j + 1, positions in steps, 115200
/// baud 8N1, 20 ms response timeout, 3 attempts. Change here to match your encoders
/// (docs/BOARD.md, "Absolute encoders").
pub const ENCODER_CONFIG: EncoderConfig = EncoderConfig::DEFAULT;

/// Receive buffer of the UART: two replies.
pub const RX_BYTES: usize = 32;
/// Transmit buffer: one request.
pub const TX_BYTES: usize = 16;

/// The UART settings for [`ENCODER_CONFIG`].
pub fn uart_config() -> usart::Config {
    let mut config = usart::Config::default();
    config.baudrate = encoder::DEFAULT_BAUD;
    config
}

/// The RS-485 bus ([`EncoderBus`]).
pub struct Rs485 {
    uart: BufferedUart<'static>,
}

impl Rs485 {
    /// On a UART set up with hardware DE.
    pub fn new(uart: BufferedUart<'static>) -> Self {
        Rs485 { uart }
    }

    /// Drops whatever arrived since the last transaction (a late reply, noise).
    async fn discard_stale(&mut self) {
        let mut scratch = [0u8; RX_BYTES];
        while let Ok(Ok(n)) =
            with_timeout(Duration::from_ticks(0), self.uart.read(&mut scratch)).await
        {
            if n == 0 {
                break;
            }
        }
    }
}

impl EncoderBus for Rs485 {
    async fn send(&mut self, frame: &[u8]) -> Result<(), ()> {
        self.discard_stale().await;
        self.uart.write_all(frame).await.map_err(|_| ())?;
        // Until the last stop bit is out: the reply timeout starts from there.
        self.uart.flush().await.map_err(|_| ())
    }

    async fn receive(
        &mut self,
        buf: &mut [u8],
        first_byte_timeout_us: u32,
        silent_us: u32,
    ) -> usize {
        let mut n = 0;
        let mut timeout = first_byte_timeout_us;
        while n < buf.len() {
            let Some(rest) = buf.get_mut(n..) else { break };
            match with_timeout(
                Duration::from_micros(u64::from(timeout)),
                self.uart.read(rest),
            )
            .await
            {
                Ok(Ok(got)) if got > 0 => n += got,
                // Silence (end of frame or no reply), or a framing/parity/noise error: the
                // CRC check decides what the bytes are worth.
                _ => break,
            }
            timeout = silent_us;
        }
        n
    }

    async fn pause(&mut self, us: u32) {
        Timer::after_micros(u64::from(us)).await;
    }
}

/// [`Encoders`] over Modbus RTU.
pub struct ModbusEncoders {
    bus: Rs485,
    /// Encoders answered at boot.
    fitted: bool,
}

impl ModbusEncoders {
    /// Asks the first `joints` encoders once each; logs what it found.
    pub async fn detect(mut bus: Rs485, joints: u8) -> Self {
        let fitted = encoder::probe(&mut bus, &ENCODER_CONFIG, joints).await;
        if fitted {
            info!("encoders: Modbus RTU encoders answer: RETURN reads them");
        } else {
            info!("encoders: none answers on UART4: RETURN trusts the step count");
        }
        ModbusEncoders { bus, fitted }
    }
}

impl Encoders for ModbusEncoders {
    async fn read(&mut self) -> Option<[i32; MAX_JOINTS]> {
        self.read_joints(MAX_JOINTS as u8).await.ok().flatten()
    }

    async fn read_joints(&mut self, joints: u8) -> Result<Option<[i32; MAX_JOINTS]>, EncoderFault> {
        if !self.fitted {
            return Ok(None);
        }
        let read = encoder::read_positions(&mut self.bus, &ENCODER_CONFIG, joints).await;
        if let Err(fault) = read {
            warn!("encoders: joint {} failed: {}", fault.joint, fault.kind);
        }
        read.map(Some)
    }
}
