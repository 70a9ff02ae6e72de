//! What the pendant's browser tests share (`tests/tests/pendant.rs`, `pendant_bench.rs`):
//! `armctl serve` against a simulator with a described arm, its page opened in headless
//! Chromium ([`crate::webdriver`]), the STOPPED frames of its `--pcap` capture, the page's
//! e-stop clicks. Without Chromium and chromedriver the tests say `SKIPPED` and pass;
//! `PENDANT_REQUIRED=1` (`.ci/run`) makes that a failure.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::Duration;

use crate::webdriver::{Driver, Session, missing_browser};
use crate::{SimHost, armctl_bin, config_init_degrees_arm, run_armctl};

/// How long the page may take to show what the test waits for (bounded waits, never
/// sleeps for the controller's work).
pub const PAGE_WAIT: Duration = Duration::from_secs(20);

/// Whether the browser is there; if not, the message (and a failure under PENDANT_REQUIRED).
pub fn browser_or_skip(test: &str) -> bool {
    match missing_browser() {
        None => true,
        Some(why) if std::env::var_os("PENDANT_REQUIRED").is_some() => {
            panic!("{test}: PENDANT_REQUIRED is set but {why}")
        }
        Some(why) => {
            eprintln!("SKIPPED {test}: {why}");
            false
        }
    }
}

/// `armctl serve` on a free 127.0.0.1 port, its datagrams captured to a pcap; stopped
/// on drop.
pub struct Pendant {
    child: Child,
    /// The page's URL.
    pub url: String,
    /// The capture of the pendant's datagrams.
    pub pcap: PathBuf,
}

impl Pendant {
    pub fn start(sim: &SimHost) -> Pendant {
        Pendant::start_with(sim, &[], &[])
    }

    /// With global options `global` (`--key-file FILE`) and serve's `options`.
    pub fn start_with(sim: &SimHost, global: &[&str], options: &[&str]) -> Pendant {
        let pcap = sim.dir().join("pendant.pcap");
        let mut child = Command::new(armctl_bin())
            .arg("--controller")
            .arg(sim.addr.to_string())
            .arg("--pcap")
            .arg(&pcap)
            .args(global)
            .args(["serve", "--listen", "127.0.0.1:0"])
            .args(options)
            .stdin(Stdio::null())
            .stdout(Stdio::piped())
            .stderr(Stdio::inherit())
            .spawn()
            .expect("start armctl serve");
        let stdout = child.stdout.take().expect("piped stdout");
        let (tx, rx) = std::sync::mpsc::channel();
        std::thread::spawn(move || {
            for line in BufReader::new(stdout).lines().map_while(Result::ok) {
                let _ = tx.send(line);
            }
        });
        let line = rx
            .recv_timeout(Duration::from_secs(20))
            .expect("armctl serve says where it serves");
        let url = line
            .split(" at ")
            .nth(1)
            .unwrap_or_else(|| panic!("{line}"))
            .to_string();
        Pendant { child, url, pcap }
    }
}

impl Drop for Pendant {
    fn drop(&mut self) {
        // SIGTERM: it stops what it moves and exits.
        let _ = Command::new("kill")
            .arg(self.child.id().to_string())
            .status();
        let _ = self.child.wait();
    }
}

/// A simulator with the scripted users' degrees arm (`base`, `shoulder`, 44.44 steps a
/// degree) described on it (`armctl config push`).
pub fn described_sim() -> SimHost {
    let sim = SimHost::start_traced(&["--joints", "2"]);
    let config = sim.dir().join("arm.json");
    let (ok, out, err) = config_init_degrees_arm(&config, "10000");
    assert!(ok, "config init: {out}{err}");
    let (ok, out, err) = run_armctl(Some(&sim), &["config", "push", config.to_str().unwrap()]);
    assert!(ok, "config push: {out}{err}");
    sim
}

/// Opens the page and waits until it shows the controller.
pub fn open(driver: &Driver, url: &str) -> Session {
    let page = driver.session();
    page.goto(url);
    assert!(
        page.wait_for(
            "return document.getElementById('conn').textContent === 'connected' \
             && document.querySelectorAll('#joints tr').length > 0",
            PAGE_WAIT
        ),
        "the page never showed a connected controller: {}",
        page.text("body")
    );
    page
}

/// Each joint's position as the page shows it.
pub fn shown_positions(page: &Session) -> Vec<String> {
    serde_json::from_value(
        page.eval(
            "return [...document.querySelectorAll('#joints tr .pos')].map(e => e.textContent)",
        ),
    )
    .unwrap_or_default()
}

/// STOPPED frames the pendant sent, with their times (s since the epoch), from its pcap.
pub fn stops_on_the_wire(pcap: &Path) -> Vec<f64> {
    let bytes = std::fs::read(pcap).unwrap_or_default();
    // The file header's magic says the byte order (pcap-file writes big-endian).
    let big = bytes.starts_with(&[0xa1, 0xb2, 0xc3, 0xd4]);
    let mut at = 24;
    let mut times = Vec::new();
    while at + 16 <= bytes.len() {
        let word = |o: usize| {
            let b: [u8; 4] = bytes[at + o..at + o + 4].try_into().unwrap();
            if big {
                u32::from_be_bytes(b)
            } else {
                u32::from_le_bytes(b)
            }
        };
        let (sec, usec, len) = (word(0), word(4), word(8) as usize);
        let start = at + 16;
        if start + len > bytes.len() {
            break;
        }
        // IPv4 (20 bytes) and UDP (8) headers, then the frame.
        let frame = &bytes[start..start + len];
        if frame.len() > 28
            && let Ok(f) = protocol::Command::decode(&frame[28..])
            && matches!(f.body, protocol::Command::Stopped)
        {
            times.push(f64::from(sec) + f64::from(usec) / 1e6);
        }
        at = start + len;
    }
    times
}

/// The page's e-stop clicks (ms since the epoch).
pub fn clicks(page: &Session) -> Vec<f64> {
    serde_json::from_value(page.eval("return window.pendantStopClicks")).unwrap_or_default()
}

/// A run of `seconds` from where the arm is (base 0, shoulder `shoulder` deg): base out to
/// 40 deg and back, shoulder down to -20 deg and back.
pub fn trajectory(dir: &Path, seconds: u32, shoulder: u32) -> PathBuf {
    let path = dir.join("out-and-back.csv");
    let half = f64::from(seconds) / 2.0;
    std::fs::write(
        &path,
        format!(
            "time_s,base,shoulder\n0,0,{shoulder}\n{half},40,-20\n{},0,{shoulder}\n",
            f64::from(seconds)
        ),
    )
    .unwrap();
    path
}

/// One request to the pendant at `url` (`http://127.0.0.1:PORT/...`): `method path` with
/// `body`; the status code and the body. Bounded by a 20 s read timeout.
pub fn request(url: &str, method: &str, path: &str, body: &[u8]) -> (u16, String) {
    use std::io::{Read, Write};
    let host = url
        .trim_start_matches("http://")
        .split('/')
        .next()
        .unwrap_or_default();
    let mut stream = std::net::TcpStream::connect(host).expect("connect to the pendant");
    stream
        .set_read_timeout(Some(Duration::from_secs(20)))
        .unwrap();
    write!(
        stream,
        "{method} {path} HTTP/1.1\r\nHost: {host}\r\nContent-Length: {}\r\n\r\n",
        body.len()
    )
    .unwrap();
    stream.write_all(body).unwrap();
    // The answer's head, then as many bytes as Content-Length says (the connection stays
    // open: keep-alive).
    let mut raw = Vec::new();
    let mut chunk = [0u8; 4096];
    loop {
        let n = stream.read(&mut chunk).unwrap_or(0);
        raw.extend_from_slice(&chunk[..n]);
        let text = String::from_utf8_lossy(&raw).into_owned();
        if let Some((head, rest)) = text.split_once("\r\n\r\n") {
            let length = head
                .to_ascii_lowercase()
                .lines()
                .find_map(|l| {
                    l.strip_prefix("content-length:")
                        .map(|v| v.trim().parse().unwrap_or(0))
                })
                .unwrap_or(0usize);
            if rest.len() >= length || n == 0 {
                let status = head
                    .split(' ')
                    .nth(1)
                    .and_then(|s| s.parse().ok())
                    .unwrap_or(0);
                return (status, rest.to_string());
            }
        }
        if n == 0 {
            return (0, text);
        }
    }
}
