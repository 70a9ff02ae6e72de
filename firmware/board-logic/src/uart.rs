//! UART_INIT's STM32F4 HAL codes mapped to the frame format the board's USART is set to:
//! declared once, in arm-core (the controller refuses what the board cannot make, on the
//! board and in the simulator alike); re-exported here for the board.

pub use arm_core::uart::{DataBits, Parity, StopBits, UartFrame, hal, uart_frame};
