//! The Wireshark dissector `tools/wireshark/arm_controller.lua` against the protocol crate.
//!
//! 1. Every golden frame of `shared/vectors/frames.json` goes through `text2pcap` (UDP
//!    headers with the controller's port on the right side) and `tshark -X lua_script:`;
//!    each field the dissector shows must equal what `protocol`'s own decoder makes of the
//!    same bytes, and for an invalid frame its verdict (`armctl.verdict`) must be the status
//!    the file names and the crate gives.
//! 2. A capture written by `sim-host --pcap` and one by `armctl --pcap` of the same session
//!    open in tshark: each command is paired with its ACK (with the round trip), and a
//!    command resent with the same bytes is marked as a retransmission.
//!
//! Needs `tshark` and `text2pcap` (Debian: `apt-get install tshark`; `.ci/run` installs
//! it); without them each test says so and passes.

use std::collections::HashMap;
use std::net::UdpSocket;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::time::Duration;

use protocol::{Command as Cmd, Report, crc8};
use serde_json::Value;
use system_tests::{SimHost, armctl_bin};

const DISSECTOR: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../tools/wireshark/arm_controller.lua"
);
const DEFAULT_VECTORS: &str = concat!(
    env!("CARGO_MANIFEST_DIR"),
    "/../../shared/vectors/frames.json"
);

/// Whether tshark and text2pcap run here; prints why not.
fn have_wireshark(test: &str) -> bool {
    for tool in ["tshark", "text2pcap"] {
        let found = Command::new(tool)
            .arg("--version")
            .output()
            .is_ok_and(|o| o.status.success());
        if !found {
            eprintln!(
                "SKIP {test}: needs `{tool}` (Debian: apt-get install tshark; .ci/run installs it)"
            );
            return false;
        }
    }
    true
}

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("wireshark-test-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("scratch dir");
    dir
}

/// A capture written by hand through armctl's pcap writer: datagrams between a host
/// (127.0.0.1:40000) and the controller's port, in a scratch folder of its own, which goes
/// with it (kept when the test failed, beside the failure). One builder for the tests
/// that each wrote this out.
struct HandCapture {
    dir: PathBuf,
    pcap: PathBuf,
    log: Option<armctl::pcap::PcapLog>,
}

impl HandCapture {
    const HOST: &str = "127.0.0.1:40000";

    /// A new capture `file` in the scratch folder `name`.
    fn new(name: &str, file: &str) -> HandCapture {
        let dir = scratch(name);
        let pcap = dir.join(file);
        let log = armctl::pcap::PcapLog::create(&pcap).expect("create the capture");
        HandCapture {
            dir,
            pcap,
            log: Some(log),
        }
    }

    fn record(&self, from: std::net::SocketAddr, to: std::net::SocketAddr, datagram: &[u8]) {
        self.log
            .as_ref()
            .expect("the capture is still open")
            .record(from, to, datagram)
            .unwrap();
    }

    fn ends() -> (std::net::SocketAddr, std::net::SocketAddr) {
        let host = Self::HOST.parse().unwrap();
        let controller = format!("127.0.0.1:{}", protocol::PORT).parse().unwrap();
        (host, controller)
    }

    /// A datagram from the host to the controller.
    fn to_controller(&self, datagram: &[u8]) {
        let (host, controller) = Self::ends();
        self.record(host, controller, datagram);
    }

    /// A datagram from the controller to the host.
    fn to_host(&self, datagram: &[u8]) {
        let (host, controller) = Self::ends();
        self.record(controller, host, datagram);
    }

    /// Closes the file; its path, for tshark.
    fn finish(&mut self) -> PathBuf {
        self.log = None;
        self.pcap.clone()
    }
}

impl Drop for HandCapture {
    fn drop(&mut self) {
        if !std::thread::panicking() {
            let _ = std::fs::remove_dir_all(&self.dir);
        }
    }
}

/// The packets of `pcap` as tshark with the dissector shows them: one map of field name to
/// value (all occurrences, comma separated) per packet. `two_pass`: analysis that needs
/// later frames (an ACK's frame number in its command). `port`: the controller's UDP port
/// when it is not 8510 (decoded as armctl, as Wireshark's "Decode As" does).
fn dissect(
    pcap: &Path,
    fields: &[&str],
    two_pass: bool,
    port: Option<u16>,
) -> Vec<HashMap<String, String>> {
    let mut command = Command::new("tshark");
    command
        .arg("-r")
        .arg(pcap)
        .arg("-X")
        .arg(format!("lua_script:{DISSECTOR}"))
        .args(["-T", "fields", "-E", "occurrence=a", "-E", "aggregator=,"]);
    if two_pass {
        command.arg("-2");
    }
    if let Some(port) = port {
        command.args(["-d", &format!("udp.port=={port},armctl")]);
    }
    for field in fields {
        command.args(["-e", field]);
    }
    let out = command.output().expect("run tshark");
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(out.status.success(), "tshark failed: {stderr}");
    assert!(
        !stderr.contains("Lua"),
        "the dissector raised an error in tshark: {stderr}"
    );
    String::from_utf8_lossy(&out.stdout)
        .lines()
        .map(|line| {
            fields
                .iter()
                .zip(line.split('\t'))
                .filter(|(_, v)| !v.is_empty())
                .map(|(k, v)| (k.to_string(), v.to_string()))
                .collect()
        })
        .collect()
}

/// A tshark value as numbers: decimal or 0x hex, comma separated.
fn numbers(value: &str) -> Vec<i64> {
    value
        .split(',')
        .map(|v| {
            let v = v.trim();
            match v.strip_prefix("0x") {
                Some(hex) => i64::from_str_radix(hex, 16),
                None => v.parse(),
            }
            .unwrap_or_else(|_| panic!("not a number: {v:?} in {value:?}"))
        })
        .collect()
}

fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

fn from_hex(s: &str) -> Vec<u8> {
    (0..s.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(&s[i..i + 2], 16).expect("hex"))
        .collect()
}

/// What the dissector must show for one frame, from the protocol crate's decoding.
#[derive(Default)]
struct Expected {
    numbers: Vec<(&'static str, Vec<i64>)>,
    strings: Vec<(&'static str, String)>,
}

impl Expected {
    fn num(&mut self, field: &'static str, values: impl IntoIterator<Item = i64>) {
        self.numbers.push((field, values.into_iter().collect()));
    }
    fn one(&mut self, field: &'static str, value: impl Into<i64>) {
        self.num(field, [value.into()]);
    }
    fn text(&mut self, field: &'static str, value: String) {
        self.strings.push((field, value));
    }
}

/// One per-joint field of a point, joint 0 first.
type PerJoint = fn(protocol::Point) -> [i64; protocol::MAX_JOINTS];

fn expect_command(frame: &protocol::Frame<Cmd<'_>>, e: &mut Expected) {
    e.one("armctl.verdict", 0);
    match frame.body {
        Cmd::New { count } => e.one("armctl.new.count", count),
        Cmd::Pending(points) => {
            e.one("armctl.points", points.len() as i64);
            e.num(
                "armctl.point.duration",
                points.iter().map(|p| i64::from(p.duration)),
            );
            // Per joint, joint 0 first in each point.
            let per_joint: [(&'static str, PerJoint); 5] = [
                ("armctl.point.position", |p| p.position.map(i64::from)),
                ("armctl.point.number_of_period", |p| {
                    p.number_of_period.map(i64::from)
                }),
                ("armctl.point.period", |p| p.period.map(i64::from)),
                ("armctl.point.number_of_full_period", |p| {
                    p.number_of_full_period.map(i64::from)
                }),
                ("armctl.point.rest_period", |p| p.rest_period.map(i64::from)),
            ];
            for (field, values) in per_joint {
                e.num(field, points.iter().flat_map(values));
            }
        }
        Cmd::PwmStart(pwm) => {
            e.one("armctl.pwm.psc", pwm.psc);
            e.one("armctl.pwm.arr", pwm.arr);
            e.one("armctl.pwm.ccr1", pwm.ccr1);
            e.one("armctl.pwm.pulse_count", pwm.pulse_count);
        }
        Cmd::UsartStart(init) => {
            e.one("armctl.uart.baud_rate", init.baud_rate);
            e.one("armctl.uart.word_length", init.word_length);
            e.one("armctl.uart.stop_bits", init.stop_bits);
            e.one("armctl.uart.parity", init.parity);
            e.one("armctl.uart.mode", init.mode);
            e.one("armctl.uart.hw_flow_ctl", init.hw_flow_ctl);
            e.one("armctl.uart.over_sampling", init.over_sampling);
        }
        Cmd::UsartSend(bytes) => e.text("armctl.usart.data", hex(bytes)),
        Cmd::ToggleEnablePins { mask: Some(mask) } => e.one("armctl.enable.mask", mask),
        Cmd::JointsCount(n) => e.one("armctl.joints", n),
        Cmd::LocationSetting(location) => {
            e.num("armctl.location.position", location.position.map(i64::from));
            e.one("armctl.location.state", location.state);
        }
        Cmd::UploadPeriod { period_us } => e.one("armctl.upload_period_us", period_us),
        _ => {}
    }
}

fn expect_report(frame: &protocol::Frame<Report<'_>>, e: &mut Expected) {
    match frame.body {
        Report::Ack(ack) => {
            e.one("armctl.ack.acked_tag", ack.acked_tag);
            e.one("armctl.ack.status", ack.status as u8);
            e.one("armctl.ack.state", ack.state as u8);
            e.one("armctl.ack.next_seq", ack.next_seq);
            e.one("armctl.ack.buffered", ack.buffered);
            e.one("armctl.ack.free", ack.free);
        }
        Report::Location(location) => {
            e.num("armctl.location.position", location.position.map(i64::from));
            e.one("armctl.location.state", location.state);
        }
        Report::UsartRecv(bytes) => {
            e.one("armctl.usart.len", bytes.len() as i64);
            e.text("armctl.usart.data", hex(bytes));
        }
        Report::Status(s) => {
            let [a, b, c] = s.version;
            e.text("armctl.status.version", format!("{a}.{b}.{c}"));
            e.one("armctl.status.joints", s.joints);
            e.one("armctl.status.state", s.state as u8);
            e.one("armctl.status.flags", s.flags.0);
            e.one("armctl.status.buffered", s.buffered);
            e.one("armctl.status.expected", s.expected);
            e.one("armctl.status.received", s.received);
            e.one("armctl.status.executed", s.executed);
            e.one("armctl.status.capacity", s.capacity);
            e.one("armctl.status.upload_period_us", s.upload_period_us);
            e.one("armctl.status.pwm_timer_clock_hz", s.pwm_timer_clock_hz);
            e.one("armctl.status.max_step_rate_hz", s.max_step_rate_hz);
        }
        // Not in the shared golden file (issues 23 and 31): issue_23_frames_decode_in_wireshark,
        // issue_31_stop_cause_decodes_in_wireshark.
        // Issue 31's JOINT_DESC: issue_31_joint_description_decodes_in_wireshark.
        Report::Limits(_) | Report::StopCause(_) | Report::JointDesc(_) => {}
        // Issue 30, after the golden file: protocol/tests/rx_counters.rs.
        Report::RxCounters(_) => {}
        // Issue 34: issue_34_diag_decodes_in_wireshark.
        Report::Diag(_) => {}
        // Issue 32's MOTION: issue_32_motion_frames_decode_in_wireshark.
        Report::Motion(_) => {}
        // Issue 33: issue_33_homing_decodes_in_wireshark.
        Report::Homing(_) | Report::Switches(_) => {}
    }
}

/// Every field the checks below read.
const FIELDS: &[&str] = &[
    "armctl.seq",
    "armctl.tag",
    "armctl.direction",
    "armctl.crc",
    "armctl.crc.status",
    "armctl.verdict",
    "armctl.new.count",
    "armctl.points",
    "armctl.point.duration",
    "armctl.point.position",
    "armctl.point.number_of_period",
    "armctl.point.period",
    "armctl.point.number_of_full_period",
    "armctl.point.rest_period",
    "armctl.pwm.psc",
    "armctl.pwm.arr",
    "armctl.pwm.ccr1",
    "armctl.pwm.pulse_count",
    "armctl.uart.baud_rate",
    "armctl.uart.word_length",
    "armctl.uart.stop_bits",
    "armctl.uart.parity",
    "armctl.uart.mode",
    "armctl.uart.hw_flow_ctl",
    "armctl.uart.over_sampling",
    "armctl.usart.len",
    "armctl.usart.data",
    "armctl.enable.mask",
    "armctl.joints",
    "armctl.upload_period_us",
    "armctl.location.position",
    "armctl.location.state",
    "armctl.ack.acked_tag",
    "armctl.ack.status",
    "armctl.ack.state",
    "armctl.ack.next_seq",
    "armctl.ack.buffered",
    "armctl.ack.free",
    "armctl.status.version",
    "armctl.status.joints",
    "armctl.status.state",
    "armctl.status.flags",
    "armctl.status.buffered",
    "armctl.status.expected",
    "armctl.status.received",
    "armctl.status.executed",
    "armctl.status.capacity",
    "armctl.status.upload_period_us",
    "armctl.status.pwm_timer_clock_hz",
    "armctl.status.max_step_rate_hz",
    "_ws.expert.message",
];

fn status_code(name: &str) -> u8 {
    protocol::StatusCode::from_name(name)
        .map(u8::from)
        .unwrap_or_else(|| panic!("unknown status name {name}"))
}

#[test]
fn golden_frames_decode_in_wireshark_as_in_the_protocol_crate() {
    if !have_wireshark("golden frames") {
        return;
    }
    let path =
        std::env::var_os("ARM_VECTORS").map_or(PathBuf::from(DEFAULT_VECTORS), PathBuf::from);
    let text = std::fs::read_to_string(&path).unwrap_or_else(|e| {
        panic!(
            "golden vectors not readable at {}: {e} (set ARM_VECTORS)",
            path.display()
        )
    });
    let root: Value = serde_json::from_str(&text).expect("frames.json is JSON");
    let vectors = root["frames"].as_array().expect("a frames array");
    assert!(!vectors.is_empty());

    // One text2pcap input, each frame marked inbound (to the controller's port 8510) or
    // outbound (from it): -D swaps the dummy addresses and ports for outbound frames.
    let dir = scratch("golden");
    let mut dump = String::new();
    for v in vectors {
        let bytes = from_hex(v["hex"].as_str().expect("hex"));
        let to_controller = v["direction"] == "to_controller";
        dump.push_str(if to_controller { "I\n" } else { "O\n" });
        for (i, chunk) in bytes.chunks(16).enumerate() {
            let line: Vec<String> = chunk.iter().map(|b| format!("{b:02x}")).collect();
            dump.push_str(&format!("{:06x} {}\n", i * 16, line.join(" ")));
        }
    }
    std::fs::write(dir.join("golden.txt"), dump).unwrap();
    let pcap = dir.join("golden.pcap");
    let status = Command::new("text2pcap")
        .args(["-q", "-D", "-u", &format!("50000,{}", protocol::PORT)])
        .arg(dir.join("golden.txt"))
        .arg(&pcap)
        .status()
        .expect("run text2pcap");
    assert!(status.success(), "text2pcap failed");
    let packets = dissect(&pcap, FIELDS, false, None);
    assert_eq!(packets.len(), vectors.len(), "one packet per golden frame");

    let mut checked_fields = 0;
    for (v, shown) in vectors.iter().zip(&packets) {
        let name = v["name"].as_str().unwrap_or("?");
        let bytes = from_hex(v["hex"].as_str().unwrap());
        let to_controller = v["direction"] == "to_controller";
        let get = |field: &str| shown.get(field).map(String::as_str);
        assert_eq!(
            get("armctl.direction"),
            Some(if to_controller { "0" } else { "1" }),
            "{name}: direction"
        );
        if bytes.len() < 3 {
            assert!(get("armctl.seq").is_none(), "{name}: no frame in {shown:?}");
            assert!(
                get("_ws.expert.message").is_some_and(|m| m.contains("too short")),
                "{name}: too short: {shown:?}"
            );
            continue;
        }
        assert_eq!(
            get("armctl.seq").map(numbers),
            Some(vec![i64::from(bytes[0])]),
            "{name}: seq"
        );
        assert_eq!(
            get("armctl.tag").map(numbers),
            Some(vec![i64::from(bytes[1])]),
            "{name}: tag"
        );
        assert_eq!(
            get("armctl.crc").map(numbers),
            Some(vec![i64::from(bytes[bytes.len() - 1])]),
            "{name}: crc"
        );
        let crc_good = crc8(&bytes[..bytes.len() - 1]) == bytes[bytes.len() - 1];
        assert_eq!(
            get("armctl.crc.status"),
            Some(if crc_good { "1" } else { "0" }),
            "{name}: crc status"
        );

        if let Some(expected) = v["expect_status"].as_str() {
            // An invalid frame: the dissector's verdict is the file's and the crate's.
            let crate_status = Cmd::decode(&bytes)
                .err()
                .and_then(|e| e.status())
                .map(|s| s.name());
            assert_eq!(crate_status, Some(expected), "{name}: the crate's verdict");
            assert_eq!(
                get("armctl.verdict").map(numbers),
                Some(vec![i64::from(status_code(expected))]),
                "{name}: the dissector's verdict ({shown:?})"
            );
            assert!(
                get("_ws.expert.message").is_some(),
                "{name}: an expert note says what is wrong"
            );
            continue;
        }

        let mut expected = Expected::default();
        if to_controller {
            let frame = Cmd::decode(&bytes).unwrap_or_else(|e| panic!("{name}: {e}"));
            expect_command(&frame, &mut expected);
        } else {
            let frame = Report::decode(&bytes).unwrap_or_else(|e| panic!("{name}: {e}"));
            expect_report(&frame, &mut expected);
        }
        for (field, values) in &expected.numbers {
            assert_eq!(
                get(field).map(numbers).unwrap_or_default(),
                *values,
                "{name}: {field}"
            );
            checked_fields += 1;
        }
        for (field, value) in &expected.strings {
            assert_eq!(get(field), Some(value.as_str()), "{name}: {field}");
            checked_fields += 1;
        }
        // Nothing shown that the crate did not decode (a field of another command).
        for field in shown.keys() {
            let generic = [
                "armctl.seq",
                "armctl.tag",
                "armctl.direction",
                "armctl.crc",
                "armctl.crc.status",
                "_ws.expert.message",
            ];
            let listed = expected.numbers.iter().any(|(f, _)| f == field)
                || expected.strings.iter().any(|(f, _)| f == field);
            assert!(
                generic.contains(&field.as_str()) || listed,
                "{name}: unexpected field {field} = {}",
                shown[field]
            );
        }
    }
    eprintln!(
        "wireshark: {} golden frames, {checked_fields} decoded fields equal to the protocol crate's",
        vectors.len()
    );
}

/// Sends `frame` from `socket` and waits (bounded) for its ACK.
fn send_and_ack(socket: &UdpSocket, frame: &[u8]) {
    socket.send(frame).expect("send");
    let mut buf = [0u8; 2048];
    for _ in 0..20 {
        let Ok(n) = socket.recv(&mut buf) else {
            continue;
        };
        if n == 11 && buf[1] == 0x14 && buf[0] == frame[0] {
            return;
        }
    }
    panic!("no ACK for seq {}", frame[0]);
}

/// A host whose first ACK came late resent the command (same bytes), and the controller
/// ACKed both copies: each copy is paired with its own ACK, in order, so no command is
/// shown unanswered (CI once saw the first copy left without one: both ACKs went to the
/// latest copy).
#[test]
fn a_resent_command_and_its_two_acks_pair_in_order() {
    if !have_wireshark("resend pairing") {
        return;
    }
    let mut capture = HandCapture::new("resend", "resend.pcap");
    let mut pin1_on = vec![123, 0x0e];
    pin1_on.push(crc8(&pin1_on));
    let ack = protocol::Report::Ack(protocol::Ack {
        acked_tag: 0x0e,
        status: protocol::StatusCode::Ok,
        state: protocol::State::New,
        next_seq: 0,
        buffered: 0,
        free: 100,
    });
    let mut ack_frame = [0u8; 16];
    let n = ack.encode(123, &mut ack_frame).expect("encode ACK");
    // Frames 1, 2: the command and its resend; 3, 4: the two ACKs.
    capture.to_controller(&pin1_on);
    capture.to_controller(&pin1_on);
    capture.to_host(&ack_frame[..n]);
    capture.to_host(&ack_frame[..n]);
    let pcap = capture.finish();

    let fields = [
        "frame.number",
        "armctl.response_in",
        "armctl.response_to",
        "armctl.retransmission",
    ];
    let packets = dissect(&pcap, &fields, true, None);
    let shown: Vec<(Option<&str>, Option<&str>, Option<&str>)> = packets
        .iter()
        .map(|p| {
            (
                p.get("armctl.response_in").map(String::as_str),
                p.get("armctl.response_to").map(String::as_str),
                p.get("armctl.retransmission").map(String::as_str),
            )
        })
        .collect();
    assert_eq!(
        shown,
        [
            (Some("3"), None, None),
            (Some("4"), None, Some("1")),
            (None, Some("1"), None),
            (None, Some("2"), None),
        ],
        "(response_in, response_to, retransmission) of frames 1-4"
    );
}

/// Issue 18: the controller ignores a STOPPED's data and stops all the same, so the
/// dissector shows the data as ignored and raises no length error (it did before).
#[test]
fn a_stopped_with_data_is_no_length_error() {
    if !have_wireshark("STOPPED with data") {
        return;
    }
    let mut capture = HandCapture::new("stopped-data", "stopped.pcap");
    let mut stop = vec![7, 0x03, 1, 2, 3, 4];
    stop.push(crc8(&stop));
    capture.to_controller(&stop);
    let pcap = capture.finish();
    let packets = dissect(&pcap, &["armctl.tag", "_ws.expert.message"], false, None);
    assert_eq!(packets.len(), 1);
    assert_eq!(
        packets[0].get("_ws.expert.message"),
        None,
        "{:?}",
        packets[0]
    );
}

#[test]
fn session_captures_pair_acks_and_mark_retransmissions() {
    if !have_wireshark("session captures") {
        return;
    }
    let dir = scratch("session");
    let sim_pcap = dir.join("sim-host.pcap");
    let mut sim = SimHost::start(&["--pcap", sim_pcap.to_str().unwrap()]);

    // A host that resends PIN0_ON with the same bytes (as after a lost ACK): the
    // controller re-ACKs it without executing it twice; the capture must say so.
    let socket = UdpSocket::bind("127.0.0.1:0").unwrap();
    socket.connect(sim.addr).unwrap();
    socket
        .set_read_timeout(Some(Duration::from_millis(200)))
        .unwrap();
    let mut pin = vec![0x42, 0x0c];
    pin.push(crc8(&pin));
    send_and_ack(&socket, &pin);
    send_and_ack(&socket, &pin);
    // DISCOVER: answered with a DISCOVER_REPLY, which the dissector pairs with it.
    let mut discover = vec![0x43, protocol::Tag::Discover as u8];
    discover.push(crc8(&discover));
    socket.send(&discover).unwrap();
    let mut buf = [0u8; 2048];
    // Bounded: other datagrams may keep arriving if the reply never does.
    let deadline = std::time::Instant::now() + Duration::from_secs(10);
    let reply = loop {
        assert!(
            std::time::Instant::now() < deadline,
            "no DISCOVER_REPLY within 10 s"
        );
        let n = socket.recv(&mut buf).expect("a DISCOVER_REPLY");
        if let Ok(frame) = protocol::DiscoverReply::decode(&buf[..n]) {
            break frame.body;
        }
    };
    drop(socket);

    // The CLI's own capture of the same session.
    let cli_pcap = dir.join("armctl.pcap");
    let out = Command::new(armctl_bin())
        .args(["--controller", &sim.addr.to_string(), "--pcap"])
        .arg(&cli_pcap)
        .args(["pin", "1", "on"])
        .output()
        .expect("run armctl");
    assert!(
        out.status.success(),
        "armctl pin: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    sim.terminate();

    let fields = [
        "frame.number",
        "armctl.direction",
        "armctl.tag",
        "armctl.seq",
        "armctl.response_in",
        "armctl.response_to",
        "armctl.time",
        "armctl.retransmission",
        "armctl.discover.mac",
        "armctl.discover.ip",
        "armctl.discover.prefix_len",
        "armctl.discover.version",
        "armctl.discover.joints",
        "armctl.discover.state",
        "armctl.discover.owner",
        "armctl.discover.owner_ip",
    ];
    // The controller's capture: commands are paired with their ACKs, the resend is marked.
    let port = Some(sim.addr.port());
    let packets = dissect(&sim_pcap, &fields, true, port);
    let commands: Vec<_> = packets
        .iter()
        .filter(|p| p.get("armctl.direction").is_some_and(|d| d == "0"))
        .collect();
    let acks: Vec<_> = packets
        .iter()
        .filter(|p| p.get("armctl.tag").is_some_and(|t| t == "0x14"))
        .collect();
    assert!(
        !commands.is_empty() && !acks.is_empty(),
        "{} packets, none dissected as commands and ACKs",
        packets.len()
    );
    for command in &commands {
        assert!(
            command.contains_key("armctl.response_in"),
            "command without its ACK: {command:?}"
        );
    }
    for ack in &acks {
        let to = ack.get("armctl.response_to").expect("ACK paired");
        let rtt: f64 = ack["armctl.time"].parse().expect("round trip in seconds");
        assert!((0.0..1.0).contains(&rtt), "round trip {rtt} s");
        let command = packets
            .iter()
            .find(|p| p.get("frame.number") == Some(to))
            .expect("the paired frame exists");
        assert_eq!(command.get("armctl.seq"), ack.get("armctl.seq"));
    }
    let pins: Vec<_> = commands
        .iter()
        .filter(|p| p.get("armctl.tag").is_some_and(|t| t == "0x0c"))
        .collect();
    assert_eq!(pins.len(), 2, "PIN0_ON twice: {pins:?}");
    assert!(!pins[0].contains_key("armctl.retransmission"));
    assert_eq!(
        pins[1].get("armctl.retransmission"),
        pins[0].get("frame.number"),
        "the resend points at the first copy"
    );
    // The last one: the harness's readiness DISCOVER (before this host owned anything)
    // is answered first in the simulator's capture.
    let shown = packets
        .iter()
        .rfind(|p| p.get("armctl.tag").is_some_and(|t| t == "0x22"))
        .expect("the DISCOVER_REPLY in the capture");
    let [a, b, c, d] = reply.net.ip;
    let [e, f, g, h] = reply.owner_ip;
    let [v0, v1, v2] = reply.version;
    let mac: Vec<String> = reply.mac.iter().map(|b| format!("{b:02x}")).collect();
    for (field, value) in [
        ("armctl.discover.mac", mac.join(":")),
        ("armctl.discover.ip", format!("{a}.{b}.{c}.{d}")),
        (
            "armctl.discover.prefix_len",
            reply.net.prefix_len.to_string(),
        ),
        ("armctl.discover.version", format!("{v0}.{v1}.{v2}")),
        ("armctl.discover.joints", reply.joints.to_string()),
        ("armctl.discover.state", (reply.state as u8).to_string()),
        ("armctl.discover.owner", (reply.owner as u8).to_string()),
        ("armctl.discover.owner_ip", format!("{e}.{f}.{g}.{h}")),
    ] {
        assert_eq!(shown.get(field), Some(&value), "DISCOVER_REPLY {field}");
    }
    assert!(
        shown.contains_key("armctl.response_to"),
        "paired with DISCOVER"
    );
    let pin1_in_sim = commands
        .iter()
        .any(|p| p.get("armctl.tag").is_some_and(|t| t == "0x0e"));
    assert!(
        pin1_in_sim,
        "armctl's PIN1_ON reached the controller's capture"
    );

    // armctl's capture: STATUS (connect) and PIN1_ON, each with its ACK.
    let packets = dissect(&cli_pcap, &fields, true, port);
    let tags: Vec<&str> = packets
        .iter()
        .filter(|p| p.get("armctl.direction").is_some_and(|d| d == "0"))
        .filter_map(|p| p.get("armctl.tag").map(String::as_str))
        .collect();
    assert!(
        tags.contains(&"0x15") && tags.contains(&"0x0e"),
        "armctl's capture holds STATUS and PIN1_ON: {tags:?}"
    );
    assert!(
        packets
            .iter()
            .filter(|p| p.get("armctl.direction").is_some_and(|d| d == "0"))
            .all(|p| p.contains_key("armctl.response_in")),
        "every command in armctl's capture got its ACK: {packets:?}"
    );
}

/// Authentication (issue 21, docs/PROTOCOL.md section 13): a keyed simulator's session as
/// `armctl --key-file` captures it. With the key in the dissector's preferences every
/// envelope's MAC is Good (the Lua BLAKE2s agrees with the crate's), with another key Bad,
/// and the inner frames are dissected as frames.
#[test]
fn authenticated_captures_have_their_macs_checked_with_the_preferences_key() {
    if !have_wireshark("authenticated captures") {
        return;
    }
    let dir = scratch("auth");
    let key_hex = "5a".repeat(32);
    let settings = dir.join("settings.txt");
    std::fs::write(
        &settings,
        format!("joints=6\nkey={key_hex}\nauth_epoch=9\n"),
    )
    .unwrap();
    let key_file = dir.join("arm.key");
    std::fs::write(&key_file, &key_hex).unwrap();
    let mut sim = SimHost::start(&["--settings", settings.to_str().unwrap()]);
    let pcap = dir.join("armctl.pcap");
    let out = Command::new(armctl_bin())
        .args(["--controller", &sim.addr.to_string(), "--key-file"])
        .arg(&key_file)
        .arg("--pcap")
        .arg(&pcap)
        .args(["pin", "1", "on"])
        .output()
        .expect("run armctl");
    assert!(
        out.status.success(),
        "armctl --key-file pin: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    sim.terminate();
    let macs = |key: &str| -> Vec<(String, String)> {
        let out = Command::new("tshark")
            .arg("-r")
            .arg(&pcap)
            .arg("-X")
            .arg(format!("lua_script:{DISSECTOR}"))
            .args(["-d", &format!("udp.port=={},armctl", sim.addr.port())])
            .args(["-o", &format!("armctl.key:{key}")])
            .args(["-T", "fields", "-E", "occurrence=a", "-E", "aggregator=,"])
            .args(["-e", "armctl.tag", "-e", "armctl.auth.mac.status"])
            .output()
            .expect("run tshark");
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(
            out.status.success() && !stderr.contains("Lua"),
            "tshark: {stderr}"
        );
        String::from_utf8_lossy(&out.stdout)
            .lines()
            .map(|l| {
                let (tag, mac) = l.split_once('\t').unwrap_or((l, ""));
                (tag.to_string(), mac.to_string())
            })
            .collect()
    };
    let good = macs(&key_hex);
    // HELLO (plain), then envelopes: HELLO_REPLY, STATUS and its ACK and report, PIN1_ON
    // and its ACK (and LOCATION reports).
    assert!(good.len() >= 6, "{good:?}");
    assert!(good[0].0.starts_with("0x51"), "{good:?}");
    let envelopes: Vec<_> = good.iter().filter(|(t, _)| t.starts_with("0x50")).collect();
    assert!(envelopes.len() >= 5, "{good:?}");
    for (tag, mac) in &envelopes {
        assert_eq!(mac, "1", "{tag}: MAC Good with the key: {good:?}");
        assert!(
            tag.contains(','),
            "the inner frame's tag is shown too: {tag}"
        );
    }
    let bad = macs(&"a5".repeat(32));
    assert!(
        bad.iter()
            .filter(|(t, _)| t.starts_with("0x50"))
            .all(|(_, mac)| mac == "0"),
        "{bad:?}"
    );
}

/// Issue 23's frames (not in the shared golden file): SET_ENABLE's mask and action, and
/// STATUS `more_flags` with each driver's ENABLE.
#[test]
fn issue_23_frames_decode_in_wireshark() {
    if !have_wireshark("issue 23 frames") {
        return;
    }
    let mut capture = HandCapture::new("issue23", "issue23.pcap");
    let mut buf = [0u8; protocol::MAX_DATAGRAM];
    let n = Cmd::SetEnable {
        mask: 0x0103,
        enable: false,
    }
    .encode(0x1b, &mut buf)
    .unwrap();
    capture.to_controller(&buf[..n]);
    let status = protocol::StatusReport {
        state: protocol::State::Stopped,
        more_flags: protocol::MoreFlags(protocol::MoreFlags::of_enabled(0x1FC)),
        ..protocol::StatusReport::default()
    };
    let n = Report::Status(status).encode(0x1c, &mut buf).unwrap();
    capture.to_host(&buf[..n]);
    let n = Cmd::StatusWith(protocol::StatusAsk {
        location: true,
        look_only: true,
        ..protocol::StatusAsk::default()
    })
    .encode(0x1d, &mut buf)
    .unwrap();
    capture.to_controller(&buf[..n]);
    let n = Cmd::Release.encode(0x1e, &mut buf).unwrap();
    capture.to_controller(&buf[..n]);
    let set = protocol::LimitsSet {
        joint: 1,
        limits: protocol::JointLimits {
            min: -16_000,
            max: 16_000,
            max_rate_hz: 4_000,
        },
    };
    let n = Cmd::LimitsSet(set).encode(0x1f, &mut buf).unwrap();
    capture.to_controller(&buf[..n]);
    let mut joints = [protocol::JointLimits::NONE; protocol::MAX_JOINTS];
    joints[1] = set.limits;
    let limits = protocol::LimitsReport {
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
    };
    let n = Report::Limits(limits).encode(0x2c, &mut buf).unwrap();
    capture.to_host(&buf[..n]);
    let pcap = capture.finish();
    let packets = dissect(
        &pcap,
        &[
            "armctl.status.ask.location",
            "armctl.status.ask.look_only",
            "armctl.limits.joint",
            "armctl.limits.min",
            "armctl.limits.max",
            "armctl.limits.max_rate_hz",
            "armctl.limits.refusal.reason",
            "armctl.limits.refusal.value",
            "armctl.tag",
            "armctl.enable.mask",
            "armctl.enable.action",
            "armctl.verdict",
            "armctl.status.more_flags.enables_reported",
            "armctl.status.more_flags.gripper_enabled",
            "armctl.status.joints_enabled",
        ],
        false,
        None,
    );
    assert_eq!(packets.len(), 6);
    let p = &packets[0];
    assert_eq!(numbers(&p["armctl.tag"]), [0x18], "{p:?}");
    assert_eq!(numbers(&p["armctl.enable.mask"]), [0x0103], "{p:?}");
    assert_eq!(numbers(&p["armctl.enable.action"]), [0], "{p:?}");
    assert_eq!(numbers(&p["armctl.verdict"]), [0], "{p:?}");
    let p = &packets[1];
    assert_eq!(p["armctl.status.more_flags.enables_reported"], "1", "{p:?}");
    assert_eq!(p["armctl.status.more_flags.gripper_enabled"], "1", "{p:?}");
    assert_eq!(numbers(&p["armctl.status.joints_enabled"]), [0xFC], "{p:?}");
    let p = &packets[2];
    assert_eq!(numbers(&p["armctl.tag"]), [0x15], "{p:?}");
    assert_eq!(p["armctl.status.ask.location"], "1", "{p:?}");
    assert_eq!(p["armctl.status.ask.look_only"], "1", "{p:?}");
    assert_eq!(numbers(&p["armctl.verdict"]), [0], "{p:?}");
    let p = &packets[3];
    assert_eq!(numbers(&p["armctl.tag"]), [0x19], "{p:?}");
    assert_eq!(numbers(&p["armctl.verdict"]), [0], "{p:?}");
    let p = &packets[4];
    assert_eq!(numbers(&p["armctl.tag"]), [0x1a], "{p:?}");
    assert_eq!(numbers(&p["armctl.limits.joint"]), [1], "{p:?}");
    assert_eq!(numbers(&p["armctl.limits.min"]), [-16_000], "{p:?}");
    assert_eq!(numbers(&p["armctl.limits.max"]), [16_000], "{p:?}");
    assert_eq!(numbers(&p["armctl.limits.max_rate_hz"]), [4_000], "{p:?}");
    assert_eq!(numbers(&p["armctl.verdict"]), [0], "{p:?}");
    let p = &packets[5];
    assert_eq!(numbers(&p["armctl.tag"]), [0x1c], "{p:?}");
    let mins = numbers(&p["armctl.limits.min"]);
    assert_eq!((mins.len(), mins[1]), (8, -16_000), "{p:?}");
    assert_eq!(numbers(&p["armctl.limits.refusal.reason"]), [2], "{p:?}");
    assert_eq!(
        numbers(&p["armctl.limits.refusal.value"]),
        [16_100],
        "{p:?}"
    );
}

/// Issue 31's stop cause: STATUS `more_flags` bits 5-7, STATUS's request byte bit 2 and
/// the STOP_CAUSE report with the STOPPED's sender.
#[test]
fn issue_31_stop_cause_decodes_in_wireshark() {
    if !have_wireshark("issue 31 frames") {
        return;
    }
    let mut capture = HandCapture::new("issue31", "issue31.pcap");
    let mut buf = [0u8; protocol::MAX_DATAGRAM];
    let n = Cmd::StatusWith(protocol::StatusAsk {
        stop_cause: true,
        ..protocol::StatusAsk::default()
    })
    .encode(0x30, &mut buf)
    .unwrap();
    capture.to_controller(&buf[..n]);
    let status = protocol::StatusReport {
        state: protocol::State::Stopped,
        more_flags: protocol::MoreFlags(protocol::MoreFlags::of_stop_cause(
            protocol::StopCause::EstopInput,
        )),
        ..protocol::StatusReport::default()
    };
    let n = Report::Status(status).encode(0x31, &mut buf).unwrap();
    capture.to_host(&buf[..n]);
    let stop = protocol::StopReport {
        from_ip: [127, 0, 0, 2],
        from_port: 40_001,
        ..protocol::StopReport::of(protocol::StopCause::Stopped)
    };
    let n = Report::StopCause(stop).encode(0x32, &mut buf).unwrap();
    capture.to_host(&buf[..n]);
    // ACCEL_SET and the LIMITS report with the accelerations.
    let n = Cmd::AccelSet {
        joint: 2,
        max_accel_steps_s2: 100_000,
    }
    .encode(0x33, &mut buf)
    .unwrap();
    capture.to_controller(&buf[..n]);
    let n = Cmd::LimitsGetWithAccel.encode(0x34, &mut buf).unwrap();
    capture.to_controller(&buf[..n]);
    let mut accel = [0u32; protocol::MAX_JOINTS];
    accel[2] = 100_000;
    let limits = protocol::LimitsReport {
        max_accel: Some(accel),
        ..protocol::LimitsReport::default()
    };
    let n = Report::Limits(limits).encode(0x35, &mut buf).unwrap();
    capture.to_host(&buf[..n]);
    let pcap = capture.finish();
    let packets = dissect(
        &pcap,
        &[
            "armctl.tag",
            "armctl.verdict",
            "armctl.status.ask.stop_cause",
            "armctl.status.more_flags.stop_cause",
            "armctl.stop.cause",
            "armctl.stop.from_ip",
            "armctl.stop.from_port",
            "armctl.limits.joint",
            "armctl.limits.max_accel_steps_s2",
            "armctl.limits.ask",
        ],
        false,
        None,
    );
    assert_eq!(packets.len(), 6);
    let p = &packets[3];
    assert_eq!(numbers(&p["armctl.tag"]), [0x1e], "{p:?}");
    assert_eq!(numbers(&p["armctl.limits.joint"]), [2], "{p:?}");
    assert_eq!(
        numbers(&p["armctl.limits.max_accel_steps_s2"]),
        [100_000],
        "{p:?}"
    );
    assert_eq!(numbers(&p["armctl.verdict"]), [0], "{p:?}");
    let p = &packets[4];
    assert_eq!(numbers(&p["armctl.limits.ask"]), [1], "{p:?}");
    assert_eq!(numbers(&p["armctl.verdict"]), [0], "{p:?}");
    let p = &packets[5];
    let accel = numbers(&p["armctl.limits.max_accel_steps_s2"]);
    assert_eq!((accel.len(), accel[2]), (8, 100_000), "{p:?}");
    let p = &packets[0];
    assert_eq!(numbers(&p["armctl.tag"]), [0x15], "{p:?}");
    assert_eq!(p["armctl.status.ask.stop_cause"], "1", "{p:?}");
    assert_eq!(numbers(&p["armctl.verdict"]), [0], "{p:?}");
    let p = &packets[1];
    assert_eq!(
        numbers(&p["armctl.status.more_flags.stop_cause"]),
        [3],
        "{p:?}"
    );
    let p = &packets[2];
    assert_eq!(numbers(&p["armctl.tag"]), [0x1d], "{p:?}");
    assert_eq!(numbers(&p["armctl.stop.cause"]), [2], "{p:?}");
    assert_eq!(p["armctl.stop.from_ip"], "127.0.0.2", "{p:?}");
    assert_eq!(numbers(&p["armctl.stop.from_port"]), [40_001], "{p:?}");
}

/// Issue 30's RX_COUNTERS beside issue 31's STOP_CAUSE: STATUS's request byte bit 3 (bit 2
/// is the STOP_CAUSE's), both asked in one STATUS (0x0c), the replies in the controller's
/// order (STATUS, STOP_CAUSE, RX_COUNTERS), and bit 7, unknown, refused (this sent bit 4
/// before issue 32's MOTION took it).
#[test]
fn issue_30_rx_counters_decode_in_wireshark() {
    if !have_wireshark("issue 30 frames") {
        return;
    }
    let mut capture = HandCapture::new("issue30", "issue30.pcap");
    let mut buf = [0u8; protocol::MAX_DATAGRAM];
    let n = Cmd::StatusWith(protocol::StatusAsk {
        stop_cause: true,
        counters: true,
        ..protocol::StatusAsk::default()
    })
    .encode(0x40, &mut buf)
    .unwrap();
    assert_eq!(buf[2], 0x0c);
    capture.to_controller(&buf[..n]);
    let n = Report::Status(protocol::StatusReport::default())
        .encode(0x41, &mut buf)
        .unwrap();
    capture.to_host(&buf[..n]);
    let n = Report::StopCause(protocol::StopReport::of(protocol::StopCause::Complete))
        .encode(0x42, &mut buf)
        .unwrap();
    capture.to_host(&buf[..n]);
    let counters = protocol::RxCounters {
        ring_dropped: 12,
        ring_full: 3,
        interrupt_stops: 20,
        shed: 5_000,
        inbox_dropped: 7,
        group_ignored: 1,
    };
    let n = Report::RxCounters(counters).encode(0x43, &mut buf).unwrap();
    capture.to_host(&buf[..n]);
    let mut unknown = vec![0x44, protocol::Tag::Status as u8, 0x80];
    unknown.push(crc8(&unknown));
    capture.to_controller(&unknown);
    let pcap = capture.finish();
    let packets = dissect(
        &pcap,
        &[
            "armctl.tag",
            "armctl.verdict",
            "armctl.status.ask.location",
            "armctl.status.ask.look_only",
            "armctl.status.ask.stop_cause",
            "armctl.status.ask.counters",
            "armctl.stop.cause",
            "armctl.rx.ring_dropped",
            "armctl.rx.ring_full",
            "armctl.rx.interrupt_stops",
            "armctl.rx.shed",
            "armctl.rx.inbox_dropped",
            "armctl.rx.group_ignored",
        ],
        false,
        None,
    );
    assert_eq!(packets.len(), 5);
    let p = &packets[0];
    assert_eq!(numbers(&p["armctl.tag"]), [0x15], "{p:?}");
    assert_eq!(p["armctl.status.ask.location"], "0", "{p:?}");
    assert_eq!(p["armctl.status.ask.look_only"], "0", "{p:?}");
    assert_eq!(p["armctl.status.ask.stop_cause"], "1", "{p:?}");
    assert_eq!(p["armctl.status.ask.counters"], "1", "{p:?}");
    assert_eq!(numbers(&p["armctl.verdict"]), [0], "{p:?}");
    let p = &packets[2];
    assert_eq!(numbers(&p["armctl.tag"]), [0x1d], "{p:?}");
    assert_eq!(numbers(&p["armctl.stop.cause"]), [1], "{p:?}");
    let p = &packets[3];
    assert_eq!(numbers(&p["armctl.tag"]), [0x24], "{p:?}");
    assert_eq!(numbers(&p["armctl.rx.ring_dropped"]), [12], "{p:?}");
    assert_eq!(numbers(&p["armctl.rx.ring_full"]), [3], "{p:?}");
    assert_eq!(numbers(&p["armctl.rx.interrupt_stops"]), [20], "{p:?}");
    assert_eq!(numbers(&p["armctl.rx.shed"]), [5_000], "{p:?}");
    assert_eq!(numbers(&p["armctl.rx.inbox_dropped"]), [7], "{p:?}");
    assert_eq!(numbers(&p["armctl.rx.group_ignored"]), [1], "{p:?}");
    // Bit 7 is no request: INVALID_CONFIG.
    let p = &packets[4];
    assert_eq!(numbers(&p["armctl.tag"]), [0x15], "{p:?}");
    assert_eq!(numbers(&p["armctl.verdict"]), [11], "{p:?}");
}

/// Issue 34's DIAG: STATUS's request byte bit 6 (what `armctl diag` sends, 0x4a), the
/// report field by field (PROTOCOL.md's worked example), and bit 7 still refused.
#[test]
fn issue_34_diag_decodes_in_wireshark() {
    if !have_wireshark("issue 34 frames") {
        return;
    }
    let dir = scratch("issue34");
    let pcap = dir.join("issue34.pcap");
    let host: std::net::SocketAddr = "127.0.0.1:40000".parse().unwrap();
    let controller: std::net::SocketAddr = format!("127.0.0.1:{}", protocol::PORT).parse().unwrap();
    let log = armctl::pcap::PcapLog::create(&pcap).expect("create the capture");
    let mut buf = [0u8; protocol::MAX_DATAGRAM];
    let n = Cmd::StatusWith(protocol::StatusAsk {
        look_only: true,
        counters: true,
        diag: true,
        ..protocol::StatusAsk::default()
    })
    .encode(0x31, &mut buf)
    .unwrap();
    assert_eq!(buf[2], 0x4a);
    log.record(host, controller, &buf[..n]).unwrap();
    let diag = protocol::Diag {
        cpu_hz: 400_000_000,
        masked_max_cycles: 812,
        masked_opener: 0x0801_2345,
        masked_spans: 96_000,
        step_hz: 200_000_000,
        dir_late_max_ticks: -3,
        dir_writes: 24,
        dma_slack_min_ticks: 4_321,
        dma_refills: 51_200,
    };
    let n = Report::Diag(diag).encode(0x2f, &mut buf).unwrap();
    log.record(controller, host, &buf[..n]).unwrap();
    let mut unknown = vec![0x44, protocol::Tag::Status as u8, 0xc0];
    unknown.push(crc8(&unknown));
    log.record(host, controller, &unknown).unwrap();
    drop(log);
    let packets = dissect(
        &pcap,
        &[
            "armctl.tag",
            "armctl.verdict",
            "armctl.status.ask.look_only",
            "armctl.status.ask.counters",
            "armctl.status.ask.diag",
            "armctl.diag.cpu_hz",
            "armctl.diag.masked_max_cycles",
            "armctl.diag.masked_opener",
            "armctl.diag.masked_spans",
            "armctl.diag.step_hz",
            "armctl.diag.dir_late_max_ticks",
            "armctl.diag.dir_writes",
            "armctl.diag.dma_slack_min_ticks",
            "armctl.diag.dma_refills",
        ],
        false,
        None,
    );
    assert_eq!(packets.len(), 3);
    let p = &packets[0];
    assert_eq!(numbers(&p["armctl.tag"]), [0x15], "{p:?}");
    assert_eq!(p["armctl.status.ask.look_only"], "1", "{p:?}");
    assert_eq!(p["armctl.status.ask.counters"], "1", "{p:?}");
    assert_eq!(p["armctl.status.ask.diag"], "1", "{p:?}");
    assert_eq!(numbers(&p["armctl.verdict"]), [0], "{p:?}");
    let p = &packets[1];
    assert_eq!(numbers(&p["armctl.tag"]), [0x32], "{p:?}");
    assert_eq!(numbers(&p["armctl.diag.cpu_hz"]), [400_000_000], "{p:?}");
    assert_eq!(numbers(&p["armctl.diag.masked_max_cycles"]), [812], "{p:?}");
    assert_eq!(
        numbers(&p["armctl.diag.masked_opener"]),
        [0x0801_2345],
        "{p:?}"
    );
    assert_eq!(numbers(&p["armctl.diag.masked_spans"]), [96_000], "{p:?}");
    assert_eq!(numbers(&p["armctl.diag.step_hz"]), [200_000_000], "{p:?}");
    assert_eq!(p["armctl.diag.dir_late_max_ticks"], "-3", "{p:?}");
    assert_eq!(numbers(&p["armctl.diag.dir_writes"]), [24], "{p:?}");
    assert_eq!(
        numbers(&p["armctl.diag.dma_slack_min_ticks"]),
        [4_321],
        "{p:?}"
    );
    assert_eq!(numbers(&p["armctl.diag.dma_refills"]), [51_200], "{p:?}");
    // Bit 7 is no request: INVALID_CONFIG.
    let p = &packets[2];
    assert_eq!(numbers(&p["armctl.verdict"]), [11], "{p:?}");
    let _ = std::fs::remove_dir_all(&dir);
}

/// Issue 31's arm description: JOINT_DESC_SET, JOINT_DESC_GET and the JOINT_DESC report
/// decode field by field (PROTOCOL.md's worked example), and a joint of 8 is flagged.
#[test]
fn issue_31_joint_description_decodes_in_wireshark() {
    if !have_wireshark("issue 31 joint description") {
        return;
    }
    let mut capture = HandCapture::new("issue31desc", "desc.pcap");
    let mut buf = [0u8; protocol::MAX_DATAGRAM];
    let set = protocol::JointDescSet {
        joint: 1,
        desc: protocol::JointDesc::new(
            "shoulder",
            protocol::JointUnit::Degrees,
            -5,
            16000.0 / std::f64::consts::TAU,
        )
        .unwrap(),
    };
    let n = Cmd::JointDescSet(set).encode(0x25, &mut buf).unwrap();
    capture.to_controller(&buf[..n]);
    let n = Cmd::JointDescGet { joint: 1 }
        .encode(0x26, &mut buf)
        .unwrap();
    capture.to_controller(&buf[..n]);
    let n = Report::JointDesc(set).encode(0x30, &mut buf).unwrap();
    capture.to_host(&buf[..n]);
    // JOINT_DESC_GET for joint 8: out of range.
    let mut bad = vec![0x27, 0x23, 8];
    bad.push(protocol::crc8(&bad));
    capture.to_controller(&bad);
    let pcap = capture.finish();
    let packets = dissect(
        &pcap,
        &[
            "armctl.tag",
            "armctl.verdict",
            "armctl.limits.joint",
            "armctl.desc.name",
            "armctl.desc.unit",
            "armctl.desc.zero_offset_steps",
            "armctl.desc.scale",
        ],
        false,
        None,
    );
    assert_eq!(packets.len(), 4);
    for p in [&packets[0], &packets[2]] {
        assert_eq!(p["armctl.desc.name"], "shoulder", "{p:?}");
        assert_eq!(numbers(&p["armctl.desc.unit"]), [1], "{p:?}");
        assert_eq!(numbers(&p["armctl.desc.zero_offset_steps"]), [-5], "{p:?}");
        let scale: f64 = p["armctl.desc.scale"].parse().unwrap();
        assert!((scale - 2546.479089).abs() < 1e-5, "{p:?}");
        assert_eq!(numbers(&p["armctl.limits.joint"]), [1], "{p:?}");
    }
    assert_eq!(numbers(&packets[0]["armctl.tag"]), [0x1f]);
    assert_eq!(numbers(&packets[0]["armctl.verdict"]), [0]);
    assert_eq!(numbers(&packets[1]["armctl.tag"]), [0x23]);
    assert_eq!(numbers(&packets[1]["armctl.verdict"]), [0]);
    assert_eq!(numbers(&packets[2]["armctl.tag"]), [0x26]);
    assert_eq!(
        numbers(&packets[3]["armctl.verdict"]),
        [11],
        "joint 8: INVALID_CONFIG"
    );
}

/// Issue 32's HOLD, RESUME, OVERRIDE and the MOTION report (PROTOCOL.md's worked
/// examples) decode field by field; STATUS's bit 4 asks for MOTION; an OVERRIDE of 0 is
/// flagged.
#[test]
fn issue_32_motion_frames_decode_in_wireshark() {
    if !have_wireshark("issue 32 frames") {
        return;
    }
    let dir = scratch("issue32");
    let pcap = dir.join("issue32.pcap");
    let host: std::net::SocketAddr = "127.0.0.1:40000".parse().unwrap();
    let controller: std::net::SocketAddr = format!("127.0.0.1:{}", protocol::PORT).parse().unwrap();
    let log = armctl::pcap::PcapLog::create(&pcap).expect("create the capture");
    let mut buf = [0u8; protocol::MAX_DATAGRAM];
    for (seq, cmd) in [
        (0x30, Cmd::Hold),
        (0x31, Cmd::Resume),
        (0x32, Cmd::Override { percent: 50 }),
        (
            0x33,
            Cmd::StatusWith(protocol::StatusAsk {
                motion: true,
                ..protocol::StatusAsk::default()
            }),
        ),
    ] {
        let n = cmd.encode(seq, &mut buf).unwrap();
        log.record(host, controller, &buf[..n]).unwrap();
    }
    let motion = protocol::MotionReport {
        factor_percent: 50,
        flags: protocol::MotionFlags(protocol::MotionFlags::HELD | protocol::MotionFlags::AT_REST),
        rate_permille: 0,
        last_stop: Some(protocol::ControlledStop::Hold),
        refused_joint: 0xFF,
        refused_limit: None,
        estop_category: Some(protocol::EStopCategory::Instant),
    };
    let n = Report::Motion(motion).encode(0x34, &mut buf).unwrap();
    log.record(controller, host, &buf[..n]).unwrap();
    // A controlled underrun slowing (MOTION flag bit 3, last stop 2).
    let underrun = protocol::MotionReport {
        factor_percent: 100,
        flags: protocol::MotionFlags(
            protocol::MotionFlags::RAMPING
                | protocol::MotionFlags::UNDERRUN_RAMP
                | protocol::MotionFlags::DOOR_OPEN,
        ),
        rate_permille: 500,
        last_stop: Some(protocol::ControlledStop::Underrun),
        refused_joint: 0xFF,
        refused_limit: None,
        estop_category: Some(protocol::EStopCategory::Instant),
    };
    let n = Report::Motion(underrun).encode(0x35, &mut buf).unwrap();
    log.record(controller, host, &buf[..n]).unwrap();
    let mut zero = vec![0x36, protocol::Tag::Override as u8, 0];
    zero.push(crc8(&zero));
    log.record(host, controller, &zero).unwrap();
    drop(log);
    let packets = dissect(
        &pcap,
        &[
            "armctl.tag",
            "armctl.verdict",
            "armctl.status.ask.motion",
            "armctl.override.percent",
            "armctl.motion.factor",
            "armctl.motion.held",
            "armctl.motion.at_rest",
            "armctl.motion.rate",
            "armctl.motion.underrun",
            "armctl.motion.door_open",
            "armctl.motion.last_stop",
            "armctl.motion.refused_joint",
        ],
        false,
        None,
    );
    assert_eq!(packets.len(), 7);
    for (p, tag) in packets.iter().zip([0x27, 0x28, 0x29, 0x15, 0x2a, 0x2a]) {
        assert_eq!(numbers(&p["armctl.tag"]), [tag], "{p:?}");
    }
    // The commands have a verdict (the reports none): valid.
    for p in &packets[..4] {
        assert_eq!(numbers(&p["armctl.verdict"]), [0], "{p:?}");
    }
    assert_eq!(numbers(&packets[2]["armctl.override.percent"]), [50]);
    assert_eq!(packets[3]["armctl.status.ask.motion"], "1");
    let p = &packets[4];
    assert_eq!(numbers(&p["armctl.motion.factor"]), [50], "{p:?}");
    assert_eq!(p["armctl.motion.held"], "1", "{p:?}");
    assert_eq!(p["armctl.motion.at_rest"], "1", "{p:?}");
    assert_eq!(numbers(&p["armctl.motion.rate"]), [0], "{p:?}");
    assert_eq!(numbers(&p["armctl.motion.last_stop"]), [1], "{p:?}");
    assert_eq!(numbers(&p["armctl.motion.refused_joint"]), [255], "{p:?}");
    assert_eq!(p["armctl.motion.underrun"], "0", "{p:?}");
    let p = &packets[5];
    assert_eq!(p["armctl.motion.underrun"], "1", "{p:?}");
    assert_eq!(p["armctl.motion.door_open"], "1", "{p:?}");
    assert_eq!(numbers(&p["armctl.motion.last_stop"]), [2], "{p:?}");
    assert_eq!(numbers(&p["armctl.motion.rate"]), [500], "{p:?}");
    // OVERRIDE 0: out of range, INVALID_CONFIG.
    assert_eq!(
        numbers(&packets[6]["armctl.verdict"]),
        [11],
        "{:?}",
        packets[6]
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// Issue 32's ESTOP_CATEGORY (PROTOCOL.md's worked example) and MOTION's e-stop fields
/// (flag bit 5, last stop 4 ESTOP, byte 7 the category) decode; a category of 2 is
/// flagged INVALID_CONFIG.
#[test]
fn issue_32_estop_category_decodes_in_wireshark() {
    if !have_wireshark("issue 32 e-stop category") {
        return;
    }
    let dir = scratch("issue32estop");
    let pcap = dir.join("estop.pcap");
    let host: std::net::SocketAddr = "127.0.0.1:40000".parse().unwrap();
    let controller: std::net::SocketAddr = format!("127.0.0.1:{}", protocol::PORT).parse().unwrap();
    let log = armctl::pcap::PcapLog::create(&pcap).expect("create the capture");
    let mut buf = [0u8; protocol::MAX_DATAGRAM];
    let n = Cmd::EstopCategory(protocol::EStopCategory::Controlled)
        .encode(0x3a, &mut buf)
        .unwrap();
    assert_eq!(&buf[..n], [0x3a, 0x2b, 0x01, 0x58], "PROTOCOL.md's example");
    log.record(host, controller, &buf[..n]).unwrap();
    let ramp = protocol::MotionReport {
        factor_percent: 100,
        flags: protocol::MotionFlags(
            protocol::MotionFlags::HELD
                | protocol::MotionFlags::RAMPING
                | protocol::MotionFlags::ESTOP_RAMP,
        ),
        rate_permille: 400,
        last_stop: Some(protocol::ControlledStop::EStop),
        refused_joint: 0xFF,
        refused_limit: None,
        estop_category: Some(protocol::EStopCategory::Controlled),
    };
    let n = Report::Motion(ramp).encode(0x3b, &mut buf).unwrap();
    log.record(controller, host, &buf[..n]).unwrap();
    let mut two = vec![0x3c, protocol::Tag::EstopCategory as u8, 2];
    two.push(crc8(&two));
    log.record(host, controller, &two).unwrap();
    drop(log);
    let packets = dissect(
        &pcap,
        &[
            "armctl.tag",
            "armctl.verdict",
            "armctl.estop_category",
            "armctl.motion.estop_ramp",
            "armctl.motion.last_stop",
        ],
        false,
        None,
    );
    assert_eq!(packets.len(), 3);
    for (p, tag) in packets.iter().zip([0x2b, 0x2a, 0x2b]) {
        assert_eq!(numbers(&p["armctl.tag"]), [tag], "{p:?}");
    }
    let p = &packets[0];
    assert_eq!(numbers(&p["armctl.verdict"]), [0], "{p:?}");
    assert_eq!(numbers(&p["armctl.estop_category"]), [1], "{p:?}");
    let p = &packets[1];
    assert_eq!(p["armctl.motion.estop_ramp"], "1", "{p:?}");
    assert_eq!(numbers(&p["armctl.motion.last_stop"]), [4], "{p:?}");
    assert_eq!(numbers(&p["armctl.estop_category"]), [1], "{p:?}");
    assert_eq!(
        numbers(&packets[2]["armctl.verdict"]),
        [11],
        "{:?}",
        packets[2]
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// Issue 33: HOME, HOMING_SET, HOMING_GET, the HOMING and SWITCHES reports, STATUS's
/// request bit 5 and HOMING_FAILED decode in Wireshark with their fields; a HOMING_SET
/// with a seek rate of 0 is flagged INVALID_CONFIG.
#[test]
fn issue_33_homing_decodes_in_wireshark() {
    if !have_wireshark("issue 33 homing") {
        return;
    }
    let dir = scratch("issue33homing");
    let pcap = dir.join("homing.pcap");
    let host: std::net::SocketAddr = "127.0.0.1:40000".parse().unwrap();
    let controller: std::net::SocketAddr = format!("127.0.0.1:{}", protocol::PORT).parse().unwrap();
    let log = armctl::pcap::PcapLog::create(&pcap).expect("create the capture");
    let mut buf = [0u8; protocol::MAX_DATAGRAM];
    let set = protocol::HomingSet {
        joint: 2,
        settings: protocol::HomingSettings {
            enabled: true,
            towards_max: true,
            switch_is_limit: false,
            order: 1,
            seek_rate_hz: 2_000,
            approach_rate_hz: 200,
            backoff_steps: 400,
            max_travel_steps: 20_000,
            offset: -100,
        },
    };
    let record = |from, to, n: usize, buf: &[u8]| log.record(from, to, &buf[..n]).unwrap();
    let n = Cmd::HomingSet(set).encode(0x22, &mut buf).unwrap();
    record(host, controller, n, &buf);
    let n = Cmd::HomingGet { joint: 2 }.encode(0x23, &mut buf).unwrap();
    record(host, controller, n, &buf);
    let n = Report::Homing(set).encode(0x31, &mut buf).unwrap();
    record(controller, host, n, &buf);
    let n = Cmd::Home.encode(0x24, &mut buf).unwrap();
    record(host, controller, n, &buf);
    let n = Cmd::StatusWith(protocol::StatusAsk {
        switches: true,
        ..protocol::StatusAsk::default()
    })
    .encode(0x25, &mut buf)
    .unwrap();
    record(host, controller, n, &buf);
    let switches = protocol::SwitchesReport {
        phase: protocol::HomingPhase::Failed,
        joint: 2,
        error: Some(protocol::HomingFailure::SeekTravel),
        homed: 0b011,
        home_active: 0,
        min_active: 0,
        max_active: 0b100,
        latched: Some(0x82),
    };
    let n = Report::Switches(switches).encode(0x32, &mut buf).unwrap();
    record(controller, host, n, &buf);
    let n = Report::Ack(protocol::Ack {
        acked_tag: 0x2c,
        status: protocol::StatusCode::HomingFailed,
        state: protocol::State::Stopped,
        next_seq: 0,
        buffered: 0,
        free: 100,
    })
    .encode(0x24, &mut buf)
    .unwrap();
    record(controller, host, n, &buf);
    // HOMING_SET with a seek rate of 0 on an enabled joint.
    let n = Cmd::HomingSet(set).encode(0x26, &mut buf).unwrap();
    let mut bad = buf[..n].to_vec();
    bad[6..10].copy_from_slice(&[0; 4]);
    let last = bad.len() - 1;
    bad[last] = protocol::crc8(&bad[..last]);

    log.record(host, controller, &bad).unwrap();
    drop(log);
    let packets = dissect(
        &pcap,
        &[
            "armctl.tag",
            "armctl.verdict",
            "armctl.homing.joint",
            "armctl.homing.flags",
            "armctl.homing.seek_rate_hz",
            "armctl.homing.offset",
            "armctl.status.ask.switches",
            "armctl.switches.phase",
            "armctl.switches.error",
            "armctl.switches.latched",
            "armctl.ack.status",
        ],
        false,
        None,
    );
    assert_eq!(packets.len(), 8);
    for p in [&packets[0], &packets[2]] {
        assert_eq!(numbers(&p["armctl.homing.joint"]), [2], "{p:?}");
        assert_eq!(numbers(&p["armctl.homing.flags"]), [0x03], "{p:?}");
        assert_eq!(numbers(&p["armctl.homing.seek_rate_hz"]), [2000], "{p:?}");
        assert_eq!(numbers(&p["armctl.homing.offset"]), [-100], "{p:?}");
    }
    assert_eq!(numbers(&packets[1]["armctl.homing.joint"]), [2]);
    assert_eq!(numbers(&packets[3]["armctl.tag"]), [0x2c]);
    assert_eq!(numbers(&packets[3]["armctl.verdict"]), [0]);
    assert!(
        ["True", "1"].contains(&packets[4]["armctl.status.ask.switches"].as_str()),
        "{:?}",
        packets[4]
    );
    assert_eq!(numbers(&packets[5]["armctl.switches.phase"]), [3]);
    assert_eq!(numbers(&packets[5]["armctl.switches.error"]), [1]);
    assert_eq!(numbers(&packets[5]["armctl.switches.latched"]), [0x82]);
    assert_eq!(numbers(&packets[6]["armctl.ack.status"]), [20]);
    assert_eq!(
        numbers(&packets[7]["armctl.verdict"]),
        [11],
        "seek rate 0: INVALID_CONFIG"
    );
}
