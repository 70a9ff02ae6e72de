//! Prints the worked example frames of `docs/PROTOCOL.md`, as they appear there.
//!
//! `cargo run -p protocol --example doc_frames`. The test `tests/doc_frames.rs` checks
//! that every block printed here is in the document, byte for byte.

use protocol::{
    Ack, Command, EncodeError, Location, MAX_DATAGRAM, MAX_JOINTS, MoreFlags, Point, PointList,
    Pwm, Report, State, StatusCode, StatusFlags, StatusReport, UartInit, VERSION,
};

/// One worked example: a heading and the frame's bytes.
pub struct DocFrame {
    /// What the frame is, as the document's caption.
    pub caption: String,
    /// The whole datagram.
    pub bytes: Vec<u8>,
    /// Whether it goes host to controller (`Command`) or back (`Report`).
    pub to_controller: bool,
}

/// Bytes per line of a hex block.
const HEX_LINE: usize = 16;

impl DocFrame {
    /// The frame as the document shows it ([`hex_block`]).
    pub fn hex_block(&self) -> String {
        hex_block(&self.bytes)
    }
}

/// Bytes as the document shows them: lower-case hex, 16 bytes a line.
pub fn hex_block(bytes: &[u8]) -> String {
    bytes
        .chunks(HEX_LINE)
        .map(|line| {
            line.iter()
                .map(|b| format!("{b:02x}"))
                .collect::<Vec<_>>()
                .join(" ")
        })
        .collect::<Vec<_>>()
        .join("\n")
}

fn command(caption: &str, seq: u8, cmd: Command<'_>) -> DocFrame {
    example(caption, true, |buf| cmd.encode(seq, buf))
}

fn report(caption: &str, seq: u8, report: Report<'_>) -> DocFrame {
    example(caption, false, |buf| report.encode(seq, buf))
}

/// The frame `encode` writes (an example: it must be valid).
fn example(
    caption: &str,
    to_controller: bool,
    encode: impl FnOnce(&mut [u8]) -> Result<usize, EncodeError>,
) -> DocFrame {
    let mut buf = [0u8; MAX_DATAGRAM];
    let n = encode(&mut buf).unwrap_or_else(|e| panic!("{caption}: {e}"));
    DocFrame {
        caption: caption.to_owned(),
        bytes: buf[..n].to_vec(),
        to_controller,
    }
}

/// Joint positions with the first three joints set.
fn joints(a: i32, b: i32, c: i32) -> [i32; MAX_JOINTS] {
    [a, b, c, 0, 0, 0, 0, 0]
}

/// The worked examples, in the order the document shows them.
pub fn doc_frames() -> Vec<DocFrame> {
    // Joint 0 +100 steps, joint 1 -50 steps in 10 ms, from zero.
    let first = Point::from_motion(10_000, &[0; MAX_JOINTS], &joints(100, -50, 0));
    // Joint 2 one step in 100 ms: its period, 100000 us, needs the 16-bit split.
    let slow = Point::from_motion(100_000, &first.position, &joints(100, -50, 1));
    vec![
        command(
            "NEW, seq 0x01, 300 points",
            0x01,
            Command::New { count: 300 },
        ),
        command(
            "PENDING, seq 0x02, one point: 10 ms, joint 0 to +100, joint 1 to -50",
            0x02,
            Command::Pending(PointList::Points(&[first])),
        ),
        command(
            "PENDING, seq 0x03, one point: 100 ms, joint 2 one step (period split)",
            0x03,
            Command::Pending(PointList::Points(&[slow])),
        ),
        command("RUNING, seq 0x04", 0x04, Command::Runing),
        command("STOPPED, seq 0x05", 0x05, Command::Stopped),
        command("UPLOAD_START, seq 0x06", 0x06, Command::UploadStart),
        command("UPLOAD_STOP, seq 0x07", 0x07, Command::UploadStop),
        command(
            "PWM_START, seq 0x08, servo: PSC 239, ARR 19999, CCR1 1500, PluseCount 0",
            0x08,
            Command::PwmStart(Pwm {
                psc: 239,
                arr: 19_999,
                ccr1: 1_500,
                pulse_count: 0,
            }),
        ),
        command(
            "PWM_START, seq 0x09, stepper: 200 pulses backwards",
            0x09,
            Command::PwmStart(Pwm {
                psc: 239,
                arr: 999,
                ccr1: 500,
                pulse_count: -200,
            }),
        ),
        command("PWM_STOP, seq 0x0a", 0x0a, Command::PwmStop),
        command(
            "USART_START, seq 0x0b, 115200 baud 8N1, both directions",
            0x0b,
            Command::UsartStart(UartInit {
                baud_rate: 115_200,
                ..UartInit::default()
            }),
        ),
        command(
            "USART_SEND, seq 0x0c, \"hi\\r\\n\"",
            0x0c,
            Command::UsartSend(b"hi\r\n"),
        ),
        command("USART_STOP, seq 0x0d", 0x0d, Command::UsartStop),
        command("PIN0_ON, seq 0x0e", 0x0e, Command::Pin0On),
        command("PIN0_OFF, seq 0x0f", 0x0f, Command::Pin0Off),
        command("PIN1_ON, seq 0x10", 0x10, Command::Pin1On),
        command("PIN1_OFF, seq 0x11", 0x11, Command::Pin1Off),
        command(
            "TOGGLE_ENABLE_PINS, seq 0x12, every driver",
            0x12,
            Command::ToggleEnablePins { mask: None },
        ),
        command(
            "TOGGLE_ENABLE_PINS, seq 0x13, joints 0 and 1 and the gripper (mask 0x0103)",
            0x13,
            Command::ToggleEnablePins { mask: Some(0x0103) },
        ),
        command("RETURN, seq 0x14", 0x14, Command::Return),
        command(
            "JOINTS_COUNT, seq 0x15, 6 joints",
            0x15,
            Command::JointsCount(6),
        ),
        command(
            "LOCATION_SETTING, seq 0x16, joint 0 at 1000, joint 1 at -1000",
            0x16,
            Command::LocationSetting(Location {
                position: joints(1_000, -1_000, 0),
                state: 0,
            }),
        ),
        command("STATUS, seq 0x17", 0x17, Command::Status),
        command(
            "UPLOAD_PERIOD, seq 0x18, 20000 us",
            0x18,
            Command::UploadPeriod { period_us: 20_000 },
        ),
        command("ESTOP_RESET, seq 0x19", 0x19, Command::EstopReset),
        command("UNLOCK, seq 0x21", 0x21, Command::Unlock),
        command("HOLD, seq 0x30", 0x30, Command::Hold),
        command("RESUME, seq 0x31", 0x31, Command::Resume),
        command(
            "OVERRIDE, seq 0x32, 50 %",
            0x32,
            Command::Override { percent: 50 },
        ),
        command(
            "ESTOP_CATEGORY, seq 0x3a, category 1 (a controlled stop)",
            0x3a,
            Command::EstopCategory(protocol::EStopCategory::Controlled),
        ),
        command(
            "STATUS, seq 0x33, with the MOTION report (request byte 0x10)",
            0x33,
            Command::StatusWith(protocol::StatusAsk {
                motion: true,
                ..protocol::StatusAsk::default()
            }),
        ),
        report(
            "MOTION report, seq 0x34: override 50 %, held and at rest (rate 0), the last controlled stop a HOLD, no override refused",
            0x34,
            Report::Motion(protocol::MotionReport {
                factor_percent: 50,
                flags: protocol::MotionFlags(
                    protocol::MotionFlags::HELD | protocol::MotionFlags::AT_REST,
                ),
                rate_permille: 0,
                last_stop: Some(protocol::ControlledStop::Hold),
                refused_joint: 0xFF,
                refused_limit: None,
                estop_category: Some(protocol::EStopCategory::Instant),
            }),
        ),
        report(
            "MOTION report, seq 0x36: a controlled underrun slowing (issue 32): override 100 %, ramping, rate 50 %, the last controlled stop UNDERRUN",
            0x36,
            Report::Motion(protocol::MotionReport {
                factor_percent: 100,
                flags: protocol::MotionFlags(
                    protocol::MotionFlags::RAMPING | protocol::MotionFlags::UNDERRUN_RAMP,
                ),
                rate_permille: 500,
                last_stop: Some(protocol::ControlledStop::Underrun),
                refused_joint: 0xFF,
                refused_limit: None,
                estop_category: Some(protocol::EStopCategory::Instant),
            }),
        ),
        report(
            "MOTION report, seq 0x38: a category 1 e-stop ramping down (issue 32): override 100 %, ramping, rate 40 %, the e-stop ramp under way, the last controlled stop ESTOP, category 1 (byte 7)",
            0x38,
            Report::Motion(protocol::MotionReport {
                factor_percent: 100,
                flags: protocol::MotionFlags(
                    protocol::MotionFlags::RAMPING | protocol::MotionFlags::ESTOP_RAMP,
                ),
                rate_permille: 400,
                last_stop: Some(protocol::ControlledStop::EStop),
                refused_joint: 0xFF,
                refused_limit: None,
                estop_category: Some(protocol::EStopCategory::Controlled),
            }),
        ),
        report(
            "MOTION report, seq 0x39: an OVERRIDE refused for the warp budget (issue 32): override 100 %, rate 100 %, the refusal the whole run's (joint 0xff) and STEP_BUDGET (3)",
            0x39,
            Report::Motion(protocol::MotionReport {
                factor_percent: 100,
                flags: protocol::MotionFlags(0),
                rate_permille: 1000,
                last_stop: None,
                refused_joint: 0xFF,
                refused_limit: Some(protocol::OverrideLimit::StepBudget),
                estop_category: Some(protocol::EStopCategory::Instant),
            }),
        ),
        report(
            "STOP_CAUSE report, seq 0x37: the last run ended by a controlled underrun (detail 1)",
            0x37,
            Report::StopCause(protocol::StopReport {
                detail: 1,
                ..protocol::StopReport::of(protocol::StopCause::Underrun)
            }),
        ),
        report(
            "ACK refusing an OVERRIDE with seq 0x35: OVERRIDE_REFUSED, state RUNNING",
            0x35,
            Report::Ack(Ack {
                acked_tag: 0x29,
                status: StatusCode::OverrideRefused,
                state: State::Running,
                next_seq: 0x0c,
                buffered: 200,
                free: 8_000,
            }),
        ),
        command(
            "HOMING_SET, seq 0x22: joint 0 towards min, seek 2000 steps/s, back-off and approach 200 steps/s, back-off 400 steps, travel 20000 steps, offset 100",
            0x22,
            Command::HomingSet(homing_example()),
        ),
        command(
            "HOMING_GET, seq 0x23, joint 0",
            0x23,
            Command::HomingGet { joint: 0 },
        ),
        command("HOME, seq 0x24", 0x24, Command::Home),
        command(
            "SET_ENABLE, seq 0x1b, disable joints 0 and 1 (mask 0x0003)",
            0x1b,
            Command::SetEnable {
                mask: 0x0003,
                enable: false,
            },
        ),
        command(
            "STATUS, seq 0x1d, look only, with a LOCATION (request byte 0x03)",
            0x1d,
            Command::StatusWith(protocol::StatusAsk {
                location: true,
                look_only: true,
                stop_cause: false,
                counters: false,
                diag: false,
                motion: false,
                switches: false,
            }),
        ),
        command("RELEASE, seq 0x1e", 0x1e, Command::Release),
        command(
            "LIMITS_SET, seq 0x1f, joint 1: -16000..16000 steps, 4000 steps/s",
            0x1f,
            Command::LimitsSet(protocol::LimitsSet {
                joint: 1,
                limits: protocol::JointLimits {
                    min: -16_000,
                    max: 16_000,
                    max_rate_hz: 4_000,
                },
            }),
        ),
        command("LIMITS_GET, seq 0x20", 0x20, Command::LimitsGet),
        command(
            "ACCEL_SET, seq 0x23, joint 0: 100000 steps/s²",
            0x23,
            Command::AccelSet {
                joint: 0,
                max_accel_steps_s2: 100_000,
            },
        ),
        command(
            "JOINT_DESC_SET, seq 0x25, joint 1 \"shoulder\", degrees, zero at 0, 16000 steps per turn",
            0x25,
            Command::JointDescSet(shoulder()),
        ),
        command(
            "JOINT_DESC_GET, seq 0x26, joint 1",
            0x26,
            Command::JointDescGet { joint: 1 },
        ),
        report(
            "JOINT_DESC report, seq 0x30, joint 1",
            0x30,
            Report::JointDesc(shoulder()),
        ),
        command(
            "LIMITS_GET, seq 0x24, with the accelerations (request byte 0x01)",
            0x24,
            Command::LimitsGetWithAccel,
        ),
        command(
            "STATUS, seq 0x22, with the STOP_CAUSE report (request byte 0x04)",
            0x22,
            Command::StatusWith(protocol::StatusAsk {
                location: false,
                look_only: false,
                stop_cause: true,
                motion: false,
                counters: false,
                diag: false,
                switches: false,
            }),
        ),
        command(
            "STATUS, seq 0x25, with the receive counters (request byte 0x08)",
            0x25,
            Command::StatusWith(protocol::StatusAsk {
                location: false,
                look_only: false,
                motion: false,
                stop_cause: false,
                counters: true,
                diag: false,
                switches: false,
            }),
        ),
        command(
            "STATUS, seq 0x26, with the STOP_CAUSE and the receive counters (request byte 0x0c)",
            0x26,
            Command::StatusWith(protocol::StatusAsk {
                location: false,
                motion: false,
                look_only: false,
                stop_cause: true,
                counters: true,
                diag: false,
                switches: false,
            }),
        ),
        command(
            "SET_ENABLE, seq 0x1c, enable every driver (mask 0x01ff)",
            0x1c,
            Command::SetEnable {
                mask: 0x01ff,
                enable: true,
            },
        ),
        report(
            "ACK of the NEW above: OK, state NEW, next_seq 0x02, 0 buffered, 8192 free",
            0x01,
            Report::Ack(Ack {
                acked_tag: 0x00,
                status: StatusCode::Ok,
                state: State::New,
                next_seq: 0x02,
                buffered: 0,
                free: 8_192,
            }),
        ),
        report(
            "ACK refusing a PENDING with seq 0x05: OUT_OF_ORDER, resend from seq 0x03",
            0x05,
            Report::Ack(Ack {
                acked_tag: 0x01,
                status: StatusCode::OutOfOrder,
                state: State::Pending,
                next_seq: 0x03,
                buffered: 12,
                free: 8_180,
            }),
        ),
        report(
            "ACK refusing a RUNING with seq 0x1a: ESTOP_LATCHED, state STOPPED",
            0x1a,
            Report::Ack(Ack {
                acked_tag: 0x02,
                status: StatusCode::EstopLatched,
                state: State::Stopped,
                next_seq: 0x00,
                buffered: 0,
                free: 8_192,
            }),
        ),
        report(
            "HOMING report (the answer to HOMING_GET), report seq 0x31",
            0x31,
            Report::Homing(homing_example()),
        ),
        report(
            "SWITCHES report, report seq 0x32: homing failed on joint 2 (the seek travelled its maximum), joints 0 and 1 homed, joint 2's max limit pressed and latched",
            0x32,
            Report::Switches(protocol::SwitchesReport {
                phase: protocol::HomingPhase::Failed,
                joint: 2,
                error: Some(protocol::HomingFailure::SeekTravel),
                homed: 0b011,
                home_active: 0,
                min_active: 0,
                max_active: 0b100,
                latched: Some(0x82),
            }),
        ),
        report(
            "ACK refusing a RUNING with seq 0x20: LIMIT_LATCHED, state PENDING",
            0x20,
            Report::Ack(Ack {
                acked_tag: 0x02,
                status: StatusCode::LimitLatched,
                state: State::Pending,
                next_seq: 0x03,
                buffered: 12,
                free: 8_180,
            }),
        ),
        report(
            "LOCATION, report seq 0x2a, RUNNING, joint 0 at 100, joint 1 at -50",
            0x2a,
            Report::Location(Location {
                position: joints(100, -50, 0),
                state: State::Running as u8,
            }),
        ),
        report(
            "USART_RECV, report seq 0x2b, \"ok\\r\\n\"",
            0x2b,
            Report::UsartRecv(b"ok\r\n"),
        ),
        report(
            "LIMITS report, seq 0x2c: joint 1 limited, the last refusal: PENDING seq 0x21, point 3, joint 1 above its max (16100 against 16000)",
            0x2c,
            Report::Limits(limits_example()),
        ),
        report(
            "STOP_CAUSE report, seq 0x2d: the last run ended by a STOPPED from 127.0.0.2, port 40001",
            0x2d,
            Report::StopCause(protocol::StopReport {
                from_ip: [127, 0, 0, 2],
                from_port: 40_001,
                ..protocol::StopReport::of(protocol::StopCause::Stopped)
            }),
        ),
        report(
            "RX_COUNTERS report, seq 0x2e: the MAC dropped 12 frames (the ring full 3 times), 20 STOPPEDs halted in the receive interrupt, 5,000 datagrams shed",
            0x2e,
            Report::RxCounters(protocol::RxCounters {
                ring_dropped: 12,
                ring_full: 3,
                interrupt_stops: 20,
                shed: 5_000,
                inbox_dropped: 0,
                group_ignored: 0,
            }),
        ),
        command(
            "STATUS, seq 0x31, look only, with the receive counters and DIAG (request byte 0x4a: what `armctl diag` sends)",
            0x31,
            Command::StatusWith(protocol::StatusAsk {
                location: false,
                look_only: true,
                stop_cause: false,
                counters: true,
                motion: false,
                switches: false,
                diag: true,
            }),
        ),
        report(
            "DIAG report, seq 0x2f: a NUCLEO (400 MHz CPU, 200 MHz step clock) whose longest masked span was 812 cycles (2.03 us) opened at 0x08012345, 96,000 spans; the latest DIR change 37 ticks (185 ns) after its compare, 24 changes; the least DMA slack 4,321 ticks (21.6 us) over 51,200 refills",
            0x2f,
            Report::Diag(protocol::Diag {
                cpu_hz: 400_000_000,
                masked_max_cycles: 812,
                masked_opener: 0x0801_2345,
                masked_spans: 96_000,
                step_hz: 200_000_000,
                dir_late_max_ticks: 37,
                dir_writes: 24,
                dma_slack_min_ticks: 4_321,
                dma_refills: 51_200,
            }),
        ),
        report(
            "STATUS report, seq 0x17",
            0x17,
            Report::Status(StatusReport {
                version: VERSION,
                joints: 6,
                state: State::Stopped,
                flags: StatusFlags(StatusFlags::REPORTS_ON | StatusFlags::DRIVERS_ENABLED),
                window: 32,
                buffered: 0,
                expected: 300,
                received: 300,
                executed: 300,
                capacity: 8_192,
                more_flags: MoreFlags(0),
                upload_period_us: 10_000,
                pwm_timer_clock_hz: 240_000_000,
                max_step_rate_hz: 100_000,
                step_budget_hz: 0,
            }),
        ),
    ]
}

/// The LIMITS report of the example: joint 1 limited, the others not.
fn limits_example() -> protocol::LimitsReport {
    let mut joints = [protocol::JointLimits::NONE; MAX_JOINTS];
    joints[1] = protocol::JointLimits {
        min: -16_000,
        max: 16_000,
        max_rate_hz: 4_000,
    };
    protocol::LimitsReport {
        max_accel: None,
        joints,
        last_refusal: protocol::Refusal {
            seq: 0x21,
            tag: 0x01,
            point: 3,
            joint: 1,
            reason: protocol::RefusalReason::AboveMax,
            value: 16_100,
            limit: 16_000,
        },
    }
}

#[allow(dead_code)] // The test includes this file for `doc_frames` alone.
fn main() {
    for frame in doc_frames() {
        println!("{}:\n```text\n{}\n```\n", frame.caption, frame.hex_block());
    }
}

/// PROTOCOL.md's HOMING_SET example (issue 33): joint 0 homes towards its min side.
fn homing_example() -> protocol::HomingSet {
    protocol::HomingSet {
        joint: 0,
        settings: protocol::HomingSettings {
            enabled: true,
            towards_max: false,
            switch_is_limit: false,
            order: 0,
            seek_rate_hz: 2_000,
            approach_rate_hz: 200,
            backoff_steps: 400,
            max_travel_steps: 20_000,
            offset: 100,
        },
    }
}

/// PROTOCOL.md's JOINT_DESC example: joint 1 "shoulder" in degrees, 16000 steps per turn
/// (16000 / 2π steps per radian).
fn shoulder() -> protocol::JointDescSet {
    protocol::JointDescSet {
        joint: 1,
        desc: protocol::JointDesc {
            name_bytes: *b"shoulder\0\0\0\0\0\0\0\0",
            unit: protocol::JointUnit::Degrees,
            zero_offset_steps: 0,
            scale_bits: (16000.0 / core::f64::consts::TAU).to_bits(),
        },
    }
}
