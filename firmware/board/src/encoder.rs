//! Absolute multi-turn encoders on RS-485 (Modbus RTU), for RETURN: UART4 with hardware
//! driver-enable. The protocol, checks and timeouts are board-logic's `encoder` module
//! (host-tested, and the same code sim-host runs against its simulated encoders); this is
//! the bus.
//!
//! | signal | pin | to the transceiver (e.g. MAX3485, THVD1450 at 3.3 V) |
//! |---|---|---|
//! | UART4_TX | PC10 (AF8) | DI |
//! | UART4_RX | PC11 (AF8) | RO |
//! | UART4_DE | PB14 (AF8) | DE and /RE tied together |
//!
//! DE is on PB14, not UART4's other DE pin PA15: PA15 is joint 0's STEP (TIM2_CH1,
//! `pins.rs`). PB14 also drives the NUCLEO's red LED LD3, which so lights while a request
//! is sent.
//!
//! The USART drives DE itself (RS-485 driver-enable mode): high from the start bit of the
//! first byte to the end of the last stop bit, so the bus is released the moment the
//! request is out and the reply is never cut.
//!
//! The bus is polled, not interrupt- or DMA-driven: a request (8 bytes) and a reply (at
//! most 9) fit the USART's 16-byte FIFOs, so the driver fills the TX FIFO at once and then
//! looks at the RX FIFO every [`POLL_US`] (a byte takes 96 us at 115200 baud: the FIFO
//! holds 1.5 ms), yielding to the executor in between. That costs a fraction of the flash
//! of a buffered, interrupt-driven driver, needs no DMA buffer, and RETURN is the only
//! user.
//!
//! At boot, [`ModbusEncoders::detect`] reads the joints in use once (one attempt each): if
//! joint 0's encoder is silent, the board has no encoders and RETURN trusts the step count
//! (as before); if anything answers, every later RETURN needs every joint's encoder, and one that does not answer ends the
//! RETURN in STOPPED without moving (logged, and `Controller::return_fault`).

use arm_core::hw::{EncoderFault, Encoders};
use board_logic::encoder::{self, EncoderBus, EncoderConfig};
use defmt::{info, warn};
use embassy_stm32::mode::Blocking;
use embassy_stm32::usart::{self, Uart};
use embassy_time::{Duration, Instant, Timer};
use embedded_hal_nb::serial::Read;
use protocol::MAX_JOINTS;

/// The encoders' settings: joint j at Modbus address j + 1, positions in steps, 115200
/// baud 8N1, 20 ms response timeout, 3 attempts. Change here to match your encoders
/// (docs/BOARD.md, "Absolute encoders").
pub const ENCODER_CONFIG: EncoderConfig = EncoderConfig::DEFAULT;

/// How often the RX FIFO is looked at while a reply is due, microseconds.
pub const POLL_US: u64 = 200;

/// Bytes of stale input dropped before a request, at most (the FIFO's depth).
const STALE_BYTES_MAX: usize = 16;

/// Parity on the encoder bus. Modbus RTU's default is even parity (8E1), most RS-485
/// encoders ship with none (8N1, 2 stop bits would be the standard's alternative but
/// encoders accept 1). With parity on, a byte that fails it is dropped by the USART, so
/// the reply's CRC check fails and the request is retried.
pub const ENCODER_PARITY: usart::Parity = usart::Parity::ParityNone;

/// The UART settings for [`ENCODER_CONFIG`]: 8 data bits, [`ENCODER_PARITY`], 1 stop bit.
pub fn uart_config() -> usart::Config {
    let mut config = usart::Config::default();
    config.baudrate = encoder::DEFAULT_BAUD;
    config.data_bits = usart::DataBits::DataBits8;
    config.parity = ENCODER_PARITY;
    config
}

/// The RS-485 bus ([`EncoderBus`]) on UART4.
pub struct Rs485 {
    uart: Uart<'static, Blocking>,
    /// Line time of the request still leaving the TX FIFO when `send` returned: the reply
    /// timeout starts after it.
    sending_us: u32,
}

impl Rs485 {
    /// On UART4 set up with hardware DE (`Uart::new_blocking_with_de`).
    pub fn new(uart: Uart<'static, Blocking>) -> Self {
        Rs485 {
            uart,
            sending_us: 0,
        }
    }
}

impl EncoderBus for Rs485 {
    async fn send(&mut self, frame: &[u8]) -> Result<(), ()> {
        // A late reply or noise from before: not part of the next answer.
        for _ in 0..STALE_BYTES_MAX {
            if let Err(nb::Error::WouldBlock) = self.uart.read() {
                break;
            }
        }
        // Fits the TX FIFO: returns at once, the hardware sends it and drives DE.
        self.uart.blocking_write(frame).map_err(|_| ())?;
        self.sending_us = ENCODER_CONFIG.timing.frame_us(frame.len());
        Ok(())
    }

    async fn receive(
        &mut self,
        buf: &mut [u8],
        first_byte_timeout_us: u32,
        silent_us: u32,
    ) -> usize {
        let mut n = 0;
        let mut wait_us = self.sending_us + first_byte_timeout_us;
        let mut deadline = Instant::now() + Duration::from_micros(u64::from(wait_us));
        while n < buf.len() {
            match self.uart.read() {
                Ok(byte) => {
                    if let Some(slot) = buf.get_mut(n) {
                        *slot = byte;
                    }
                    n += 1;
                    wait_us = silent_us;
                    deadline = Instant::now() + Duration::from_micros(u64::from(wait_us));
                    continue;
                }
                // A framing, parity or noise error: the byte is lost, the CRC will say so.
                Err(nb::Error::Other(_)) => continue,
                Err(nb::Error::WouldBlock) => {}
            }
            if Instant::now() > deadline {
                break;
            }
            Timer::after_micros(POLL_US).await;
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
        let joints = u8::try_from(MAX_JOINTS).unwrap_or(u8::MAX);
        self.read_joints(joints).await.ok().flatten()
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
