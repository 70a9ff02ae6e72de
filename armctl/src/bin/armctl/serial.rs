//! `armctl serial`: stdin and stdout bridged to the controller's serial port.

use std::io::{BufRead, Write};
use std::sync::mpsc;
use std::time::{Duration, Instant};

use armctl::Client;
use protocol::UartInit;

use crate::CliResult;

/// Runs `serial`: stdin to the controller's serial port, what it receives to stdout.
pub fn execute(arm: &Client, baud: u32, mode: u32, keep_open: bool) -> CliResult {
    let rx = arm.serial_rx();
    arm.serial_open(UartInit {
        baud_rate: baud,
        mode,
        ..UartInit::default()
    })
    .map_err(|e| e.to_string())?;
    let (tx_in, rx_in) = mpsc::channel::<Option<Vec<u8>>>();
    std::thread::spawn(move || {
        let stdin = std::io::stdin();
        let mut input = stdin.lock();
        loop {
            let mut buf = vec![0u8; protocol::MAX_SERIAL_CHUNK];
            // Line-buffered terminals hand over a line at a time; pipes whole chunks.
            let n = match input.fill_buf() {
                Ok([]) | Err(_) => 0,
                Ok(available) => {
                    let n = available.len().min(buf.len());
                    buf[..n].copy_from_slice(&available[..n]);
                    n
                }
            };
            if n == 0 {
                let _ = tx_in.send(None);
                return;
            }
            input.consume(n);
            buf.truncate(n);
            if tx_in.send(Some(buf)).is_err() {
                return;
            }
        }
    });
    let mut stdout = std::io::stdout();
    let mut last_status = Instant::now();
    let mut eof_at: Option<Instant> = None;
    loop {
        let mut reader_gone = false;
        while let Ok(bytes) = rx.try_recv() {
            let written = stdout.write_all(&bytes).and_then(|()| stdout.flush());
            // A closed pipe ends the bridge (and main, the tool: crate::out).
            if crate::out::closed(&written) {
                reader_gone = true;
                break;
            }
        }
        if reader_gone {
            break;
        }
        match rx_in.recv_timeout(Duration::from_millis(10)) {
            Ok(Some(bytes)) => arm.serial_send(&bytes).map_err(|e| e.to_string())?,
            Ok(None) | Err(mpsc::RecvTimeoutError::Disconnected) => {
                eof_at.get_or_insert_with(Instant::now);
            }
            Err(mpsc::RecvTimeoutError::Timeout) => {}
        }
        // After the end of input, a moment for the last replies.
        if eof_at.is_some_and(|t| t.elapsed() >= Duration::from_millis(300)) {
            break;
        }
        if last_status.elapsed() >= Duration::from_secs(1) {
            last_status = Instant::now();
            arm.status().map_err(|e| e.to_string())?;
        }
    }
    if !keep_open {
        arm.serial_close().map_err(|e| e.to_string())?;
    }
    Ok(())
}
