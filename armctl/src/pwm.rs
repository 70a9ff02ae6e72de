//! Gripper timer settings from a frequency and duty cycle (docs/PROTOCOL.md, "Pwm (16 bytes)"):
//! frequency = clock / ((PSC+1)(ARR+1)), duty = CCR1 / (ARR+1).

use protocol::Pwm;

/// The slowest servo signal: a frame of 50 ms; slower, servos go limp between pulses.
pub const SERVO_MIN_HZ: f64 = 20.0;
/// The fastest servo signal: a period of 2.5 ms, the longest servo pulse (digital servos
/// refresh at up to 333-400 Hz); faster, the pulse cannot fit the period.
pub const SERVO_MAX_HZ: f64 = 400.0;
/// The fastest stepper pulse train: 500 kHz is above the step input of any driver a
/// gripper uses (opto-isolated inputs stop near 200 kHz); a faster one is a typo.
pub const STEPPER_MAX_HZ: f64 = 500_000.0;

/// Registers for `freq_hz` at `duty` (0..=1) from a timer clocked at `clock_hz`, with the
/// finest duty resolution the 16-bit registers allow; `pulse_count` 0 is servo mode.
/// Servo mode takes [`SERVO_MIN_HZ`] to [`SERVO_MAX_HZ`], a pulse train at most
/// [`STEPPER_MAX_HZ`]: the message names the range.
pub fn settings(clock_hz: u32, freq_hz: f64, duty: f64, pulse_count: i32) -> Result<Pwm, String> {
    if !(freq_hz.is_finite() && freq_hz > 0.0) {
        return Err(format!("frequency {freq_hz} Hz must be above 0"));
    }
    if pulse_count == 0 && !(SERVO_MIN_HZ..=SERVO_MAX_HZ).contains(&freq_hz) {
        return Err(format!(
            "servo frequency {freq_hz} Hz: servos take {SERVO_MIN_HZ} to {SERVO_MAX_HZ} Hz \
             (50 Hz for most); for another signal use `pwm raw`"
        ));
    }
    if pulse_count != 0 && freq_hz > STEPPER_MAX_HZ {
        return Err(format!(
            "stepper frequency {freq_hz} Hz: at most {STEPPER_MAX_HZ} Hz (the step input of \
             a gripper's driver); for another signal use `pwm raw`"
        ));
    }
    if !(0.0..=1.0).contains(&duty) {
        return Err(format!("duty {duty} must be between 0 and 1"));
    }
    let exact = f64::from(clock_hz) / freq_hz;
    let ticks = exact.round();
    let max_ticks = 65_536.0 * 65_536.0;
    if exact < 1.0 || ticks > max_ticks {
        return Err(format!(
            "{freq_hz} Hz cannot be made from a {clock_hz} Hz timer clock: {:.3} Hz to {} Hz",
            f64::from(clock_hz) / max_ticks,
            clock_hz
        ));
    }
    // The smallest prescaler that lets ARR fit 16 bits keeps ARR, the duty resolution, large.
    let psc = ((ticks / 65_536.0).ceil() - 1.0).max(0.0);
    let arr = ((ticks / (psc + 1.0)).round() - 1.0).clamp(0.0, 65_535.0);
    let ccr1 = (duty * (arr + 1.0)).round().min(arr);
    Ok(Pwm {
        psc: psc as u32,
        arr: arr as u32,
        ccr1: ccr1 as u32,
        pulse_count,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Issue 23: a 100 MHz "servo" signal was accepted.
    #[test]
    fn signals_no_servo_or_stepper_takes_are_refused() {
        let err = settings(240_000_000, 100e6, 0.075, 0).unwrap_err();
        assert!(err.contains("servos take 20 to 400 Hz"), "{err}");
        assert!(settings(240_000_000, 10.0, 0.075, 0).is_err());
        assert!(settings(240_000_000, 333.0, 0.5, 0).is_ok());
        let err = settings(240_000_000, 1e6, 0.5, 200).unwrap_err();
        assert!(err.contains("at most 500000 Hz"), "{err}");
        assert!(settings(240_000_000, 100_000.0, 0.5, -200).is_ok());
    }

    #[test]
    fn servo_50_hz_at_7_5_percent() {
        let pwm = settings(240_000_000, 50.0, 0.075, 0).unwrap();
        assert!(pwm.psc <= 0xFFFF && pwm.arr <= 0xFFFF && pwm.ccr1 <= pwm.arr);
        assert!((pwm.frequency_hz(240_000_000) - 50.0).abs() < 0.01);
        assert!((pwm.duty() - 0.075).abs() < 0.001);
    }

    #[test]
    fn fast_clock_division_without_prescaler() {
        let pwm = settings(1_000_000, 1000.0, 0.5, 200).unwrap();
        assert_eq!(
            (pwm.psc, pwm.arr, pwm.ccr1, pwm.pulse_count),
            (0, 999, 500, 200)
        );
    }

    #[test]
    fn refuses_impossible_values() {
        assert!(settings(1_000_000, 0.0, 0.5, 0).is_err());
        assert!(settings(1_000_000, 2_000_000.0, 0.5, 0).is_err());
        assert!(settings(1_000_000, 100.0, 1.5, 0).is_err());
        assert!(settings(240_000_000, 0.01, 0.5, 0).is_err());
    }
}
