//! The golden frames of `shared/vectors/frames.json` against the crate: every valid frame
//! decodes to exactly its listed fields and re-encodes to exactly its bytes (the two
//! tolerated forms re-encode to the canonical form), and every invalid frame is refused
//! with the status the file names.
//!
//! The file sits beside the repository (`shared/` next to the work tree, in CI too);
//! `ARM_VECTORS=/path/to/frames.json` points elsewhere.

use std::path::PathBuf;

use protocol::{
    Command, DecodeError, DecodeErrorKind, Frame, MAX_DATAGRAM, Point, PointList, Report,
    StatusCode, Tag, crc8, size,
};
use serde_json::{Value, json};

/// Default location: `<repo>/../shared/vectors/frames.json`.
const DEFAULT_VECTORS: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../../shared/vectors/frames.json"
);

fn vectors_path() -> PathBuf {
    std::env::var_os("ARM_VECTORS").map_or_else(|| PathBuf::from(DEFAULT_VECTORS), PathBuf::from)
}

/// One entry of the file's `frames` array.
struct Vector {
    name: String,
    direction: String,
    bytes: Vec<u8>,
    entry: Value,
}

fn load() -> Vec<Vector> {
    let path = vectors_path();
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| {
        panic!(
            "golden vectors not readable at {}: {e}\n\
             The file is shared/vectors/frames.json beside the repository; \
             set ARM_VECTORS=/path/to/frames.json to use another copy.",
            path.display()
        )
    });
    let root: Value = serde_json::from_str(&text)
        .unwrap_or_else(|e| panic!("{} is not JSON: {e}", path.display()));
    let frames = root["frames"]
        .as_array()
        .unwrap_or_else(|| panic!("{} has no `frames` array", path.display()));
    assert!(!frames.is_empty(), "{} lists no frames", path.display());
    frames
        .iter()
        .map(|entry| {
            let name = entry["name"]
                .as_str()
                .expect("frame without a name")
                .to_owned();
            let direction = entry["direction"]
                .as_str()
                .unwrap_or_else(|| panic!("{name}: no direction"))
                .to_owned();
            let hex = entry["hex"]
                .as_str()
                .unwrap_or_else(|| panic!("{name}: no hex"));
            Vector {
                bytes: from_hex(hex).unwrap_or_else(|| panic!("{name}: bad hex {hex}")),
                name,
                direction,
                entry: entry.clone(),
            }
        })
        .collect()
}

fn from_hex(hex: &str) -> Option<Vec<u8>> {
    if !hex.len().is_multiple_of(2) {
        return None;
    }
    (0..hex.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(hex.get(i..i + 2)?, 16).ok())
        .collect()
}

fn to_hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

/// Whether the entry names an expected refusal (`expect_status`, possibly null).
fn is_invalid(v: &Vector) -> bool {
    v.entry.get("expect_status").is_some()
}

fn point_fields(p: &Point) -> Value {
    json!({
        "duration": p.duration,
        "numberOfFullPeriod": p.number_of_full_period,
        "restPeriod": p.rest_period,
        "numberOfPeriod": p.number_of_period,
        "period": p.period,
        "position": p.position,
    })
}

/// A decoded command in the file's field names.
fn command_fields(cmd: &Command<'_>) -> Value {
    match cmd {
        Command::New { count } => json!({ "count": count }),
        Command::Pending(points) => {
            json!({ "points": points.iter().map(|p| point_fields(&p)).collect::<Vec<_>>() })
        }
        Command::PwmStart(pwm) => json!({
            "psc": pwm.psc,
            "arr": pwm.arr,
            "ccr1": pwm.ccr1,
            "pulse_count": pwm.pulse_count,
        }),
        Command::UsartStart(init) => json!({
            "baud_rate": init.baud_rate,
            "word_length": init.word_length,
            "stop_bits": init.stop_bits,
            "parity": init.parity,
            "mode": init.mode,
            "hw_flow_ctl": init.hw_flow_ctl,
            "over_sampling": init.over_sampling,
        }),
        Command::UsartSend(bytes) => json!({ "bytes_hex": to_hex(bytes) }),
        Command::ToggleEnablePins { mask: Some(mask) } => json!({ "mask": mask }),
        Command::JointsCount(joints) => json!({ "joints": joints }),
        // The state byte of LOCATION_SETTING is ignored, so the file does not list it.
        Command::LocationSetting(loc) => json!({ "position": loc.position }),
        Command::UploadPeriod { period_us } => json!({ "period_us": period_us }),
        // Not in the shared golden file (PROTOCOL.md, "Finding controllers and setting
        // their address", adds them; protocol/tests/net.rs).
        Command::NetSet(net) => json!({ "net": format!("{net:?}") }),
        // Not in the shared golden file either (issue 21's authentication:
        // protocol/tests/auth.rs).
        Command::Hello { nonce } => json!({ "nonce_hex": to_hex(nonce) }),
        Command::SetKey(key) => json!({ "key_set": key.is_some() }),
        // Not in the shared golden file either (issue 23).
        Command::SetEnable { mask, enable } => json!({ "mask": mask, "enable": enable }),
        Command::StatusWith(ask) => json!({ "ask": ask.byte() }),
        Command::Release | Command::LimitsGet | Command::LimitsGetWithAccel | Command::Unlock => {
            json!({})
        }
        Command::AccelSet {
            joint,
            max_accel_steps_s2,
        } => json!({ "joint": joint, "max_accel_steps_s2": max_accel_steps_s2 }),
        // Issue 31's arm description: protocol/tests/joint_desc.rs.
        Command::JointDescSet(set) => json!({ "joint_desc": format!("{set:?}") }),
        Command::JointDescGet { joint } => json!({ "joint": joint }),
        // Not in the shared golden file either (issue 32): protocol/tests/motion.rs.
        Command::Hold | Command::Resume => json!({}),
        Command::Override { percent } => json!({ "percent": percent }),
        Command::EstopCategory(category) => json!({ "category": *category as u8 }),
        // Issue 33's homing: protocol/tests/homing.rs.
        Command::HomingSet(set) => json!({ "homing": format!("{set:?}") }),
        Command::HomingGet { joint } => json!({ "joint": joint }),
        Command::Home => json!({}),
        Command::LimitsSet(set) => json!({
            "joint": set.joint,
            "min": set.limits.min,
            "max": set.limits.max,
            "max_rate_hz": set.limits.max_rate_hz,
        }),
        // Not in the shared golden file either (issue 18's wired e-stop input).
        Command::EstopReset
        | Command::Discover
        | Command::Runing
        | Command::Stopped
        | Command::UploadStart
        | Command::UploadStop
        | Command::PwmStop
        | Command::UsartStop
        | Command::Pin0On
        | Command::Pin0Off
        | Command::Pin1On
        | Command::Pin1Off
        | Command::ToggleEnablePins { mask: None }
        | Command::Return
        | Command::Status => json!({}),
    }
}

/// A decoded report in the file's field names.
fn report_fields(report: &Report<'_>) -> Value {
    match report {
        Report::Ack(ack) => json!({
            "acked_tag": ack.acked_tag,
            "status": ack.status as u8,
            "state": ack.state as u8,
            "next_seq": ack.next_seq,
            "buffered": ack.buffered,
            "free": ack.free,
        }),
        Report::Location(loc) => json!({ "position": loc.position, "state": loc.state }),
        Report::UsartRecv(bytes) => json!({ "bytes_hex": to_hex(bytes) }),
        Report::Status(st) => json!({
            "version": st.version,
            "joints": st.joints,
            "state": st.state as u8,
            "flags": st.flags.0,
            "buffered": st.buffered,
            "expected": st.expected,
            "received": st.received,
            "executed": st.executed,
            "capacity": st.capacity,
            "upload_period_us": st.upload_period_us,
            "pwm_timer_clock_hz": st.pwm_timer_clock_hz,
            "max_step_rate_hz": st.max_step_rate_hz,
        }),
        // Not in the shared golden file (issue 23): protocol/tests/wire_tools.rs.
        Report::Limits(l) => json!({ "limits": format!("{l:?}") }),
        Report::StopCause(s) => json!({ "stop_cause": format!("{s:?}") }),
        // Nor this (issue 30): protocol/tests/rx_counters.rs.
        Report::RxCounters(c) => json!({ "rx_counters": format!("{c:?}") }),
        // Nor this (issue 34): protocol/tests/diag.rs.
        Report::Diag(d) => json!({ "diag": format!("{d:?}") }),
        Report::JointDesc(d) => json!({ "joint_desc": format!("{d:?}") }),
        // Nor this (issue 32): protocol/tests/motion.rs.
        Report::Motion(m) => json!({ "motion": format!("{m:?}") }),
        // Issue 33: protocol/tests/homing.rs.
        Report::Homing(h) => json!({ "homing": format!("{h:?}") }),
        Report::Switches(s) => json!({ "switches": format!("{s:?}") }),
    }
}

/// Checks seq, tag and every listed field (and that nothing decoded is missing from the
/// list); returns the problems found.
fn compare(v: &Vector, seq: u8, tag: Tag, decoded: &Value) -> Vec<String> {
    let mut problems = Vec::new();
    if v.entry["seq"] != json!(seq) {
        problems.push(format!("seq: file {}, decoded {seq}", v.entry["seq"]));
    }
    if v.entry["tag"] != json!(tag as u8) {
        problems.push(format!(
            "tag: file {}, decoded {:#04x}",
            v.entry["tag"], tag as u8
        ));
    }
    let listed = v.entry["fields"]
        .as_object()
        .unwrap_or_else(|| panic!("{}: no `fields` object", v.name));
    let decoded = decoded.as_object().expect("fields are an object");
    for (key, want) in listed {
        match decoded.get(key) {
            Some(got) if got == want => {}
            Some(got) => problems.push(format!("field {key}: file {want}, decoded {got}")),
            None => problems.push(format!(
                "field {key}: listed, but the command has no such field"
            )),
        }
    }
    for key in decoded.keys().filter(|k| !listed.contains_key(*k)) {
        problems.push(format!("field {key}: decoded, but not listed in the file"));
    }
    problems
}

/// The canonical form of a tolerated frame, built from the bytes (not by the crate):
/// the 33-byte Location gains 3 zero padding bytes, the 32-byte UartInit loses its second
/// `Parity` word (data bytes 16..20).
fn canonical_of_tolerated(bytes: &[u8]) -> Option<Vec<u8>> {
    let data = &bytes[2..bytes.len() - 1];
    let mut out = bytes[..2].to_vec();
    match (Tag::from_u8(bytes[1])?, data.len()) {
        (Tag::Location, size::LOCATION_PACKED) => {
            out.extend_from_slice(data);
            out.extend_from_slice(&[0, 0, 0]);
        }
        (Tag::UsartStart, size::UART_INIT_MANUAL) => {
            out.extend_from_slice(&data[..16]);
            out.extend_from_slice(&data[20..]);
        }
        _ => return None,
    }
    out.push(crc8(&out));
    Some(out)
}

/// `v` decoded by `decode`, its fields (`fields`: tag and JSON) compared with the file's;
/// `None` if it does not decode. Failures go to `failures`.
fn decoded<'a, T>(
    v: &'a Vector,
    failures: &mut Vec<String>,
    decode: fn(&'a [u8]) -> Result<Frame<T>, DecodeError>,
    fields: impl Fn(&T) -> (Tag, Value),
) -> Option<Frame<T>> {
    let frame = decode(&v.bytes)
        .map_err(|e| failures.push(format!("{}: does not decode: {e}", v.name)))
        .ok()?;
    let (tag, decoded) = fields(&frame.body);
    for p in compare(v, frame.seq, tag, &decoded) {
        failures.push(format!("{}: {p}", v.name));
    }
    Some(frame)
}

/// The failure when `v` re-encodes to `encoded` rather than `want`.
fn mismatch(v: &Vector, encoded: &[u8], want: &[u8]) -> Option<String> {
    (encoded != want).then(|| {
        format!(
            "{}: re-encodes to\n  {}\nnot\n  {}",
            v.name,
            to_hex(encoded),
            to_hex(want)
        )
    })
}

fn fail_if_any(kind: &str, checked: usize, failures: &[String]) {
    assert!(
        failures.is_empty(),
        "{} of {checked} {kind} golden frames failed:\n{}",
        failures.len(),
        failures.join("\n")
    );
    assert!(
        checked > 0,
        "no {kind} golden frames in {}",
        vectors_path().display()
    );
}

#[test]
fn commands_decode_to_their_fields_and_reencode() {
    let mut failures = Vec::new();
    let mut checked = 0;
    let mut tolerated = 0;
    for v in load()
        .iter()
        .filter(|v| v.direction == "to_controller" && !is_invalid(v))
    {
        checked += 1;
        let Some(frame) = decoded(v, &mut failures, Command::decode, |c| {
            (c.tag(), command_fields(c))
        }) else {
            continue;
        };
        let mut buf = [0u8; MAX_DATAGRAM];
        let n = frame.body.encode(frame.seq, &mut buf).expect("re-encodes");
        let encoded = &buf[..n];
        assert_eq!(n, frame.body.encoded_len(), "{}: encoded_len", v.name);
        let want = match canonical_of_tolerated(&v.bytes) {
            Some(canonical) => {
                tolerated += 1;
                canonical
            }
            None => v.bytes.clone(),
        };
        failures.extend(mismatch(v, encoded, &want));
        // The canonical form carries a valid CRC and the same content.
        match Command::decode(encoded) {
            Ok(again) if again == frame => {}
            other => failures.push(format!("{}: re-encoded frame decodes to {other:?}", v.name)),
        }
    }
    fail_if_any("command", checked, &failures);
    assert_eq!(
        tolerated, 2,
        "expected both tolerated forms (33-byte Location, 32-byte UartInit) in the file"
    );
}

#[test]
fn reports_decode_to_their_fields_and_reencode_exactly() {
    let mut failures = Vec::new();
    let mut checked = 0;
    for v in load().iter().filter(|v| v.direction == "to_host") {
        checked += 1;
        let Some(frame) = decoded(v, &mut failures, Report::decode, |r| {
            (r.tag(), report_fields(r))
        }) else {
            continue;
        };
        let mut buf = [0u8; MAX_DATAGRAM];
        let n = frame.body.encode(frame.seq, &mut buf).expect("re-encodes");
        failures.extend(mismatch(v, &buf[..n], &v.bytes));
    }
    fail_if_any("report", checked, &failures);
}

#[test]
fn invalid_frames_give_the_named_status() {
    let mut failures = Vec::new();
    let mut checked = 0;
    for v in load().iter().filter(|v| is_invalid(v)) {
        checked += 1;
        assert_eq!(
            v.direction, "to_controller",
            "{}: refusals are ACKs",
            v.name
        );
        let want = match &v.entry["expect_status"] {
            Value::Null => None,
            Value::String(name) => Some(
                StatusCode::from_name(name)
                    .unwrap_or_else(|| panic!("{}: no status code named {name}", v.name)),
            ),
            other => panic!("{}: expect_status is {other}", v.name),
        };
        match Command::decode(&v.bytes) {
            Ok(frame) => failures.push(format!("{}: decodes to {:?}", v.name, frame)),
            Err(e) => {
                if e.status() != want {
                    failures.push(format!(
                        "{}: status {:?}, file says {want:?} ({e})",
                        v.name,
                        e.status()
                    ));
                }
                if want.is_none() && !matches!(e.kind, DecodeErrorKind::TooShort { .. }) {
                    failures.push(format!("{}: no reply expected, but {e}", v.name));
                }
            }
        }
    }
    fail_if_any("invalid", checked, &failures);
}

/// The file must exercise every command and report, so that a shortened file cannot make
/// the tests above pass by checking less.
/// The tags issue 23 added after the shared file (protocol/tests/wire_tools.rs has their
/// frames).
const ISSUE_23_TAGS: &[Tag] = &[
    Tag::SetEnable,
    Tag::Release,
    Tag::LimitsSet,
    Tag::LimitsGet,
    Tag::Limits,
];

#[test]
fn vectors_cover_every_command_and_report() {
    let vectors = load();
    let valid = |dir: &str| {
        vectors
            .iter()
            .filter(move |v| v.direction == dir && !is_invalid(v))
            .collect::<Vec<_>>()
    };
    let commands: Vec<Tag> = valid("to_controller")
        .iter()
        .filter_map(|v| Command::decode(&v.bytes).ok().map(|f| f.body.tag()))
        .collect();
    let reports: Vec<Tag> = valid("to_host")
        .iter()
        .filter_map(|v| Report::decode(&v.bytes).ok().map(|f| f.body.tag()))
        .collect();
    let missing_commands: Vec<&str> = Tag::ALL
        .iter()
        .copied()
        .filter(|t| !matches!(t, Tag::UsartRecv | Tag::Ack))
        // PROTOCOL.md, "Finding controllers and setting their address", came after the
        // shared file: protocol/tests/net.rs.
        .filter(|t| !matches!(t, Tag::Discover | Tag::NetSet | Tag::DiscoverReply))
        // Issue 18's ESTOP_RESET came after it too: protocol/tests/estop_reset.rs.
        .filter(|t| *t != Tag::EstopReset)
        // Issue 21's authentication came after it as well: protocol/tests/auth.rs.
        .filter(|t| !matches!(t, Tag::Auth | Tag::Hello | Tag::SetKey | Tag::HelloReply))
        // Issue 23's wire tools as well: protocol/tests/wire_tools.rs.
        .filter(|t| !ISSUE_23_TAGS.contains(t))
        // Issue 31's STOP_CAUSE report and ACCEL_SET, issue 33's UNLOCK as well:
        // protocol/tests/stop_cause.rs, protocol/tests/switches.rs.
        .filter(|t| !matches!(t, Tag::StopCause | Tag::AccelSet | Tag::Unlock))
        // Issue 30's RX_COUNTERS report as well: protocol/tests/rx_counters.rs.
        .filter(|t| *t != Tag::RxCounters)
        // Issue 34's DIAG report as well: protocol/tests/diag.rs.
        .filter(|t| *t != Tag::Diag)
        // Issue 31's arm description as well: protocol/tests/joint_desc.rs.
        .filter(|t| !matches!(t, Tag::JointDescSet | Tag::JointDescGet | Tag::JointDesc))
        // Issue 32's HOLD, RESUME, OVERRIDE, MOTION and ESTOP_CATEGORY as well:
        // protocol/tests/motion.rs;
        // issue 33's homing: protocol/tests/homing.rs.
        .filter(|t| {
            !matches!(
                t,
                Tag::Hold
                    | Tag::Resume
                    | Tag::Override
                    | Tag::Motion
                    | Tag::EstopCategory
                    | Tag::Home
                    | Tag::HomingSet
                    | Tag::HomingGet
                    | Tag::Homing
                    | Tag::Switches
            )
        })
        .filter(|t| !commands.contains(t))
        .map(Tag::name)
        .collect();
    assert!(
        missing_commands.is_empty(),
        "no golden frame for {missing_commands:?}"
    );
    for tag in [Tag::Ack, Tag::Location, Tag::UsartRecv, Tag::Status] {
        assert!(
            reports.contains(&tag),
            "no golden report for {}",
            tag.name()
        );
    }
    // Both TOGGLE_ENABLE_PINS forms.
    let toggles: Vec<usize> = valid("to_controller")
        .iter()
        .filter_map(|v| match Command::decode(&v.bytes).ok()?.body {
            Command::ToggleEnablePins { mask } => Some(usize::from(mask.is_some())),
            _ => None,
        })
        .collect();
    assert!(
        toggles.contains(&0) && toggles.contains(&1),
        "TOGGLE_ENABLE_PINS forms"
    );
}

/// `Point::from_motion` reproduces the golden slow point: 3 steps in 5 s from zero, whose
/// 1666666 us period needs the 16-bit split.
#[test]
fn from_motion_matches_the_golden_slow_point() {
    let vectors = load();
    let v = vectors
        .iter()
        .find(|v| v.name == "PENDING slow point (period split)")
        .expect("the golden file has the slow point");
    let frame = Command::decode(&v.bytes).expect("decodes");
    let Command::Pending(points) = frame.body else {
        panic!("{}: not PENDING", v.name);
    };
    assert_eq!(points.len(), 1);
    let golden = points.get(0).expect("one point");
    let built = Point::from_motion(golden.duration, &[0; 8], &golden.position);
    assert_eq!(built, golden);
    // And the crate encodes it to the golden bytes.
    let mut buf = [0u8; MAX_DATAGRAM];
    let n = Command::Pending(PointList::Points(&[built]))
        .encode(frame.seq, &mut buf)
        .expect("encodes");
    assert_eq!(to_hex(&buf[..n]), to_hex(&v.bytes));
}
