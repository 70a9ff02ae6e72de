//! `armctl serve`: a pendant in the browser (issue 35). One local page for one controller:
//! live positions by name in the arm's units, state, flags, stop cause, buffer and
//! progress, a live plot of the run, the e-stop (button and Space/Escape), jog, home,
//! enable, and a trajectory file run after its check.
//!
//! - The page (`page.html`: HTML, CSS and plain JS, no library) is built into the binary;
//!   nothing is fetched from anywhere else.
//! - Live updates go over server-sent events (`GET /api/events`): one stream per page,
//!   each sending the shared snapshot ([`live::Live`]) when it changes, at the report
//!   rate. Several browsers see the same snapshot; one poller thread reads the controller.
//! - Commands are `POST /api/...`, one request per action (`act`), served by a thread per
//!   connection ([`MAX_CONNECTIONS`] at most). The HTTP is std's TCP and `http`'s small
//!   parser: no web framework, no async runtime.
//! - It binds 127.0.0.1 by default. `--listen` on an address other than loopback needs a
//!   token, printed at start in the page's URL, for every command but STOPPED (which the
//!   controller takes from anyone anyway).
//! - Another host owning the controller: the page is read-only and names the owner. With
//!   `--key-file`, every frame goes through the key (the client's envelopes).

mod act;
mod http;
mod live;

use std::net::{SocketAddr, TcpListener, TcpStream};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use armctl::Client;
use clap::Args;
use serde_json::json;

use act::{InFlight, Pendant};
use live::Live;

use crate::CliResult;

/// The page, built into the binary.
const PAGE: &str = include_str!("page.html");

/// Connections served at once: each page holds one event stream and makes a request or two
/// at a time; 64 covers a dozen browsers, and bounds the threads a misbehaving client
/// can start.
pub const MAX_CONNECTIONS: usize = 64;

/// How often an event stream sends the snapshot when nothing changes: the page's
/// "not answering" and the age of the last report stay current.
const IDLE_EVENT: Duration = Duration::from_millis(250);

/// The least time between two events of one stream: the default report period (10 ms),
/// so that a run's many progress updates do not flood a page beyond the report rate.
const MIN_EVENT_GAP: Duration = Duration::from_millis(10);

/// `serve` options.
#[derive(Args, Debug)]
pub struct ServeArgs {
    /// Where the page is served. An address other than loopback (127.0.0.0/8, ::1) needs
    /// this option explicitly, and then a token printed at start for every command that
    /// moves the arm.
    #[arg(long, default_value = "127.0.0.1:8520", value_name = "ADDR:PORT")]
    pub listen: SocketAddr,
    /// Ask for the token on loopback too (a machine other users share).
    #[arg(long)]
    pub require_token: bool,
}

/// The token moving the arm needs when the page is served beyond loopback (or `required`).
fn token_for(listen: &SocketAddr, required: bool) -> Result<Option<String>, String> {
    if listen.ip().is_loopback() && !required {
        return Ok(None);
    }
    armctl::auth::new_key_hex()
        .map(|hex| Some(hex[..32].to_string()))
        .map_err(|e| format!("a token for --listen {listen}: {e}"))
}

/// Counts a connection while it lives.
struct Slot(Arc<AtomicUsize>);

impl Drop for Slot {
    fn drop(&mut self) {
        self.0.fetch_sub(1, Ordering::Relaxed);
    }
}

/// Runs `serve` until SIGINT, SIGTERM or SIGHUP (a motion in progress is then STOPPED).
pub fn execute(arm: Client, args: &ServeArgs) -> CliResult {
    let token = token_for(&args.listen, args.require_token)?;
    let listener =
        TcpListener::bind(args.listen).map_err(|e| format!("--listen {}: {e}", args.listen))?;
    let local = listener.local_addr().map_err(|e| e.to_string())?;
    let dir = std::env::temp_dir().join(format!("armctl-serve-{}", std::process::id()));
    std::fs::create_dir_all(&dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    let arm = Arc::new(arm);
    let live = Arc::new(Live::default());
    live.update(|s| s.token_needed = token.is_some());
    let pendant = Arc::new(Pendant::new(
        Arc::clone(&arm),
        Arc::clone(&live),
        dir.clone(),
    ));
    let quit = Arc::new(AtomicBool::new(false));
    let poller = {
        let (arm, live, quit) = (Arc::clone(&arm), Arc::clone(&live), Arc::clone(&quit));
        std::thread::spawn(move || live::poll(&arm, &live, &quit))
    };
    let cancel = crate::interrupt::watch()?;
    match &token {
        Some(t) => println!("pendant for {} at http://{local}/?token={t}", arm.addr()),
        None => println!("pendant for {} at http://{local}/", arm.addr()),
    }
    let count = Arc::new(AtomicUsize::new(0));
    {
        let pendant = Arc::clone(&pendant);
        std::thread::spawn(move || {
            for stream in listener.incoming() {
                let Ok(stream) = stream else {
                    // Out of file descriptors, say: not a busy loop.
                    std::thread::sleep(Duration::from_millis(50));
                    continue;
                };
                if count.fetch_add(1, Ordering::Relaxed) >= MAX_CONNECTIONS {
                    count.fetch_sub(1, Ordering::Relaxed);
                    let mut stream = stream;
                    let _ = http::respond(
                        &mut stream,
                        "503 Service Unavailable",
                        "text/plain",
                        b"too many connections",
                    );
                    continue;
                }
                let slot = Slot(Arc::clone(&count));
                let pendant = Arc::clone(&pendant);
                let token = token.clone();
                std::thread::spawn(move || {
                    let _slot = slot;
                    serve_one(stream, &pendant, token.as_deref());
                });
            }
        });
    }
    while !cancel.is_cancelled() {
        std::thread::sleep(armctl::CANCEL_POLL);
    }
    // A motion the pendant started is stopped; a pendant that only watched leaves the arm
    // alone (another host's run goes on).
    let moving = pendant.live.lock().run.active;
    if moving {
        let _ = arm.stop();
        eprintln!("interrupted: STOPPED sent (a motion was in progress)");
    }
    quit.store(true, Ordering::Relaxed);
    let _ = poller.join();
    let _ = std::fs::remove_dir_all(&dir);
    std::process::exit(130);
}

/// One connection: requests and their answers until it closes, idles out or becomes an
/// event stream.
fn serve_one(mut stream: TcpStream, pendant: &Arc<Pendant>, token: Option<&str>) {
    let _ = stream.set_read_timeout(Some(http::READ_TIMEOUT));
    let _ = stream.set_nodelay(true);
    loop {
        let request = match http::read_request(&mut stream) {
            Ok(r) => r,
            Err(http::HttpError::Closed) => return,
            Err(e) => {
                let _ = http::respond(&mut stream, e.status(), "text/plain", e.status().as_bytes());
                return;
            }
        };
        if request.method == "GET" && request.path == "/api/events" {
            events(stream, &pendant.live);
            return;
        }
        if answer(&mut stream, &request, pendant, token).is_err() {
            return;
        }
    }
}

/// The answer to one request.
fn answer(
    stream: &mut TcpStream,
    request: &http::Request,
    pendant: &Arc<Pendant>,
    token: Option<&str>,
) -> std::io::Result<()> {
    match (request.method.as_str(), request.path.as_str()) {
        ("GET", "/" | "/index.html") => http::respond(
            stream,
            "200 OK",
            "text/html; charset=utf-8",
            PAGE.as_bytes(),
        ),
        ("GET", "/api/state") => {
            let value = pendant.live.lock().to_json(Instant::now());
            http::respond_json(stream, "200 OK", &value)
        }
        ("POST", path) if path.starts_with("/api/") => {
            // When the request was read (ms since the epoch): the benchmark splits the
            // click-to-STOPPED latency into the browser's part and the server's.
            let received_ms = std::time::SystemTime::now()
                .duration_since(std::time::UNIX_EPOCH)
                .map_or(0.0, |d| d.as_secs_f64() * 1e3);
            let action = &path["/api/".len()..];
            // STOPPED and HOLD from anyone, as the controller takes them; the rest needs
            // the token.
            let allowed = matches!(action, "stop" | "hold")
                || token.is_none_or(|t| request.param("token") == Some(t));
            let result = if !allowed {
                Err("this command needs the token printed when `armctl serve` started (the page's URL ?token=...)".to_string())
            } else {
                act_on(pendant, action, request)
            };
            let (status, value) = match result {
                Ok(message) => (
                    "200 OK",
                    json!({"ok": true, "message": message, "received_ms": received_ms}),
                ),
                Err(message) if !allowed => {
                    ("403 Forbidden", json!({"ok": false, "message": message}))
                }
                Err(message) => ("409 Conflict", json!({"ok": false, "message": message})),
            };
            http::respond_json(stream, status, &value)
        }
        _ => http::respond(stream, "404 Not Found", "text/plain", b"not found"),
    }
}

/// The command `action` with the request's parameters.
fn act_on(pendant: &Arc<Pendant>, action: &str, request: &http::Request) -> Result<String, String> {
    let number = |name: &str| -> Result<f64, String> {
        request
            .param(name)
            .and_then(|v| v.parse::<f64>().ok())
            .filter(|v| v.is_finite())
            .ok_or_else(|| format!("{action}: give {name}=NUMBER"))
    };
    match action {
        "stop" => pendant.stop(),
        "home" | "estop-reset" | "unlock" => pendant.simple(action, None),
        "enable" => pendant.simple("enable", Some(request.param("on") != Some("0"))),
        "jog" => {
            let joint = number("joint")?;
            if !(0.0..8.0).contains(&joint) || joint.fract() != 0.0 {
                return Err(format!("joint {joint}: 0 to 7"));
            }
            pendant.jog(joint as usize, number("by")?)
        }
        "check" => pendant.check(request.param("name").unwrap_or(""), &request.body),
        "run" => pendant.run(),
        "hold" => pendant.in_flight(InFlight::Hold),
        "resume" => pendant.in_flight(InFlight::Resume),
        "override" => {
            let percent = number("percent")?.clamp(0.0, 255.0) as u8;
            pendant.in_flight(InFlight::Override(percent))
        }
        _ => Err(format!("unknown command {action}")),
    }
}

/// A page's event stream: the run's commanded points when a run starts, and the snapshot
/// whenever it changes (at least every [`IDLE_EVENT`]), until the page goes away.
fn events(mut stream: TcpStream, live: &Live) {
    if http::start_events(&mut stream).is_err() {
        return;
    }
    let mut version;
    let mut plot_sent = (u64::MAX, usize::MAX);
    let mut last_sent = Instant::now();
    loop {
        let since = last_sent.elapsed();
        if since < MIN_EVENT_GAP {
            std::thread::sleep(MIN_EVENT_GAP - since);
        }
        last_sent = Instant::now();
        let (snap, plot) = {
            let s = live.lock();
            version = s.version;
            let plot_now = (s.plot.id, s.plot.t_ms.len());
            let plot = (plot_now != plot_sent).then(|| {
                plot_sent = plot_now;
                s.plot_json().to_string()
            });
            (s.to_json(Instant::now()).to_string(), plot)
        };
        if let Some(plot) = plot
            && http::write_event(&mut stream, "run", &plot).is_err()
        {
            return;
        }
        if http::write_event(&mut stream, "snap", &snap).is_err() {
            return;
        }
        live.wait(version, IDLE_EVENT);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_token_only_beyond_loopback_or_when_required() {
        for loopback in ["127.0.0.1:8520", "127.0.0.2:0", "[::1]:8520"] {
            let at = loopback.parse().unwrap();
            assert_eq!(token_for(&at, false), Ok(None), "{loopback}");
            assert!(token_for(&at, true).unwrap().is_some(), "{loopback}");
        }
        let token = token_for(&"0.0.0.0:8520".parse().unwrap(), false).unwrap();
        assert_eq!(token.map(|t| t.len()), Some(32));
    }
}
