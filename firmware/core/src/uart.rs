//! USART_START's settings (docs/PROTOCOL.md, "UartInit (28 bytes)"): the STM32F4 HAL codes
//! mapped to the frame format the controller's USART is set to, and the settings it cannot
//! make, refused by the [`crate::Controller`] with `INVALID_CONFIG` before the port is
//! touched, so the board and the simulator refuse the same ones.
//!
//! The HAL counts the parity bit in the word length, the H7's USART (and embassy) does not:
//! an 8-bit HAL word with parity is 7 data bits plus parity. Hardware flow control is
//! refused (no RTS/CTS pins are wired). Oversampling is chosen by the driver for the baud
//! rate, so both HAL values are accepted.

use protocol::{UartInit, limits};

use crate::hw::SerialError;

/// STM32F4 HAL codes in `UartInit`.
pub mod hal {
    /// UART_WORDLENGTH_9B: 9 bits on the line (8 data + parity, or 9 data).
    pub const WORD_9B: u32 = 0x1000;
    /// UART_STOPBITS_2.
    pub const STOP_2: u32 = 0x2000;
    /// UART_PARITY_EVEN.
    pub const PARITY_EVEN: u32 = 0x0400;
    /// UART_PARITY_ODD.
    pub const PARITY_ODD: u32 = 0x0600;
    /// UART_OVERSAMPLING_8.
    pub const OVERSAMPLING_8: u32 = 0x8000;
}

/// Data bits per character, parity not counted.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum DataBits {
    /// 7 data bits.
    Seven,
    /// 8 data bits.
    Eight,
    /// 9 data bits.
    Nine,
}

/// Parity bit.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum Parity {
    /// No parity bit.
    None,
    /// Even parity.
    Even,
    /// Odd parity.
    Odd,
}

/// Stop bits.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum StopBits {
    /// One stop bit.
    One,
    /// Two stop bits.
    Two,
}

/// A USART frame format.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct UartFrame {
    /// Bits per second.
    pub baud_rate: u32,
    /// Data bits.
    pub data_bits: DataBits,
    /// Parity.
    pub parity: Parity,
    /// Stop bits.
    pub stop_bits: StopBits,
}

/// The frame format for `init`, or why this board cannot apply it.
pub fn uart_frame(init: &UartInit) -> Result<UartFrame, SerialError> {
    if !limits::BAUD_RATE.contains(&init.baud_rate) || init.hw_flow_ctl != 0 {
        return Err(SerialError::Unsupported);
    }
    if init.over_sampling != 0 && init.over_sampling != hal::OVERSAMPLING_8 {
        return Err(SerialError::Unsupported);
    }
    let parity = match init.parity {
        0 => Parity::None,
        hal::PARITY_EVEN => Parity::Even,
        hal::PARITY_ODD => Parity::Odd,
        _ => return Err(SerialError::Unsupported),
    };
    let with_parity = parity != Parity::None;
    let data_bits = match (init.word_length, with_parity) {
        (0, false) => DataBits::Eight,
        (0, true) => DataBits::Seven,
        (hal::WORD_9B, false) => DataBits::Nine,
        (hal::WORD_9B, true) => DataBits::Eight,
        _ => return Err(SerialError::Unsupported),
    };
    let stop_bits = match init.stop_bits {
        0 => StopBits::One,
        hal::STOP_2 => StopBits::Two,
        _ => return Err(SerialError::Unsupported),
    };
    Ok(UartFrame {
        baud_rate: init.baud_rate,
        data_bits,
        parity,
        stop_bits,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn init(word_length: u32, stop_bits: u32, parity: u32) -> UartInit {
        UartInit {
            baud_rate: 115_200,
            word_length,
            stop_bits,
            parity,
            mode: 0,
            hw_flow_ctl: 0,
            over_sampling: 0,
        }
    }

    #[test]
    fn the_hal_word_length_counts_the_parity_bit() {
        let f = uart_frame(&init(0, 0, 0)).unwrap();
        assert_eq!(
            (f.data_bits, f.parity, f.stop_bits),
            (DataBits::Eight, Parity::None, StopBits::One)
        );
        let f = uart_frame(&init(0, 0, hal::PARITY_EVEN)).unwrap();
        assert_eq!((f.data_bits, f.parity), (DataBits::Seven, Parity::Even));
        let f = uart_frame(&init(hal::WORD_9B, 0, hal::PARITY_ODD)).unwrap();
        assert_eq!((f.data_bits, f.parity), (DataBits::Eight, Parity::Odd));
        let f = uart_frame(&init(hal::WORD_9B, hal::STOP_2, 0)).unwrap();
        assert_eq!((f.data_bits, f.stop_bits), (DataBits::Nine, StopBits::Two));
        assert_eq!(f.baud_rate, 115_200);
    }

    #[test]
    fn both_oversampling_codes_are_accepted() {
        let mut i = init(0, 0, 0);
        i.over_sampling = hal::OVERSAMPLING_8;
        assert!(uart_frame(&i).is_ok());
        i.over_sampling = 0x4000;
        assert_eq!(uart_frame(&i), Err(SerialError::Unsupported));
    }

    #[test]
    fn unknown_codes_flow_control_and_baud_out_of_range_are_refused() {
        for bad in [
            init(0x0800, 0, 0),
            init(0, 0x1000, 0),
            init(0, 0, 0x0200),
            UartInit {
                hw_flow_ctl: 0x0300,
                ..init(0, 0, 0)
            },
            UartInit {
                baud_rate: 299,
                ..init(0, 0, 0)
            },
            UartInit {
                baud_rate: 4_000_001,
                ..init(0, 0, 0)
            },
        ] {
            assert_eq!(uart_frame(&bad), Err(SerialError::Unsupported), "{bad:?}");
        }
    }
}
