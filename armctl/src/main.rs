//! `armctl`: the command-line tool that drives an arm controller. `armctl --help` lists
//! the commands.

mod cli;

use std::io::{BufRead, IsTerminal, Write};
use std::process::ExitCode;
use std::sync::mpsc;
use std::time::{Duration, Instant};

use armctl::record::{self, Recorder};
use armctl::trajectory::{self, ArmConfig};
use armctl::{Controller, Options, RunOptions};
use clap::Parser;
use protocol::{Location, MAX_JOINTS, Point, State, StatusFlags, StatusReport, UartInit};

use cli::{Cli, Cmd, FrameCmd, NetCmd, OnOff, PwmCmd, RunArgs};

/// A failure with the message to print; exit code 1 (clap exits with 2 on a usage error).
type CliResult = Result<(), String>;

fn main() -> ExitCode {
    let mut cli = Cli::parse();
    cli.controller = cli::controller_address(&cli.controller);
    if let Some(warning) = cli::resend_warning(cli.ack_timeout_ms, cli.attempts) {
        eprintln!("warning: {warning}");
    }
    match execute(cli) {
        Ok(()) => ExitCode::SUCCESS,
        Err(message) => {
            eprintln!("error: {message}");
            ExitCode::FAILURE
        }
    }
}

fn connect(cli: &Cli) -> Result<Controller, String> {
    let options = Options {
        ack_timeout: Duration::from_millis(cli.ack_timeout_ms.max(1)),
        attempts: cli.attempts.max(1),
        bind: cli.bind,
        ..Options::default()
    };
    let controller = Controller::open(cli.controller.as_str(), options)
        .map_err(|e| format!("{}: {e}", cli.controller))?;
    if let Some(path) = &cli.pcap {
        let log = armctl::pcap::PcapLog::create(path)
            .map_err(|e| format!("--pcap {}: {e}", path.display()))?;
        controller.capture(std::sync::Arc::new(log));
    }
    match cli.command {
        // Anyone may stop the arm: no STATUS first, which another host's controller
        // would refuse (NOT_OWNER).
        Cmd::Stop => Ok(controller),
        // As Controller::connect_with: check that the controller answers.
        _ => match controller.status() {
            Ok(_) => Ok(controller),
            Err(e) => Err(format!("{}: {e}", cli.controller)),
        },
    }
}

fn done(ack: armctl::Result<protocol::Ack>) -> CliResult {
    let ack = ack.map_err(|e| e.to_string())?;
    println!("OK (state {})", ack.state.name());
    Ok(())
}

fn execute(cli: Cli) -> CliResult {
    match &cli.command {
        Cmd::Frame(FrameCmd::Decode { hex, direction }) => {
            let bytes = cli::parse_hex(&hex.join(" "))?;
            println!("{}", cli::decode_frame(&bytes, *direction)?);
            Ok(())
        }
        Cmd::Frame(FrameCmd::Encode { seq, command }) => {
            println!("{}", cli::encode_frame(*seq, command)?);
            Ok(())
        }
        Cmd::Plot(args) => {
            println!("{}", cli::plot(args)?);
            Ok(())
        }
        Cmd::Discover {
            to,
            wait_ms,
            rounds,
            json,
        } => discover(&cli, *to, *wait_ms, *rounds, *json),
        Cmd::Net(NetCmd::Show) => {
            let to = match cli.controller.parse::<std::net::SocketAddr>() {
                Ok(std::net::SocketAddr::V4(to)) => to,
                _ => return Err(format!("{}: give an IPv4 address:port", cli.controller)),
            };
            discover(&cli, to, 300, 3, false)
        }
        Cmd::Run(args) if args.dry_run => {
            let converted = convert(args, &[0; 8], None, Some(args.max_step_rate))?;
            print_points_summary(&converted.points);
            println!(
                "step rates checked against {} (at most {} steps/s per joint, --max-step-rate)",
                if args.config.is_some() {
                    "the joint config"
                } else {
                    "the controller's limit"
                },
                args.max_step_rate
            );
            Ok(())
        }
        _ => {
            let controller = connect(&cli)?;
            execute_online(&cli, &controller)
        }
    }
}

fn execute_online(cli: &Cli, arm: &Controller) -> CliResult {
    match &cli.command {
        Cmd::Status { json } => {
            let status = arm.status().map_err(|e| e.to_string())?;
            if *json {
                println!(
                    "{}",
                    serde_json::to_string_pretty(&status).map_err(|e| e.to_string())?
                );
            } else {
                print_status(&status);
            }
            Ok(())
        }
        Cmd::Watch { record, duration } => watch(arm, record.as_deref(), *duration),
        Cmd::Run(args) => run(arm, args),
        Cmd::Stop => done(arm.stop()),
        Cmd::Return { wait } => {
            done(arm.go_home())?;
            if *wait {
                let status = arm
                    .wait_stopped(Duration::from_secs(600))
                    .map_err(|e| e.to_string())?;
                println!("state {}", status.state.name());
            }
            Ok(())
        }
        Cmd::Joints { n } => done(arm.set_joints(*n)),
        Cmd::SetLocation { positions } => done(arm.set_location(positions)),
        Cmd::Enable { mask } => done(arm.toggle_enable(*mask)),
        Cmd::Pin { pin, level } => done(arm.pin(*pin, *level == OnOff::On)),
        Cmd::Pwm(PwmCmd::Stop) => done(arm.pwm_stop()),
        Cmd::Pwm(PwmCmd::Raw(raw)) => done(arm.pwm_start((*raw).into())),
        Cmd::Pwm(PwmCmd::Servo { freq, duty }) => {
            let clock = arm.status().map_err(|e| e.to_string())?.pwm_timer_clock_hz;
            let pwm = armctl::pwm::settings(clock, *freq, *duty, 0)?;
            println!(
                "PSC {} ARR {} CCR1 {}: {:.3} Hz, duty {:.4}",
                pwm.psc,
                pwm.arr,
                pwm.ccr1,
                pwm.frequency_hz(clock),
                pwm.duty()
            );
            done(arm.pwm_start(pwm))
        }
        Cmd::Pwm(PwmCmd::Stepper { pulses, freq }) => {
            if *pulses == 0 {
                return Err("--pulses 0 would be servo mode: give a non-zero count".into());
            }
            let clock = arm.status().map_err(|e| e.to_string())?.pwm_timer_clock_hz;
            let pwm = armctl::pwm::settings(clock, *freq, 0.5, *pulses)?;
            done(arm.pwm_start(pwm))
        }
        Cmd::Serial {
            baud,
            mode,
            keep_open,
        } => serial(arm, *baud, mode.code(), *keep_open),
        Cmd::UploadPeriod { us } => done(arm.upload_period(*us)),
        Cmd::Reports { state } => done(arm.reports(*state == OnOff::On)),
        Cmd::Net(NetCmd::Set { ip, gateway, dhcp }) => {
            let net = if *dhcp {
                protocol::NetSettings::DHCP
            } else {
                let (ip, prefix) = armctl::discover::parse_cidr(ip.as_deref().unwrap_or_default())?;
                protocol::NetSettings::fixed(ip, prefix, gateway.map(|g| g.octets()))
            };
            if !net.is_valid() {
                return Err(format!(
                    "{}: not usable (a unicast address with a prefix of 1..32 and a gateway \
                     inside its subnet, or --dhcp)",
                    armctl::discover::net_string(&net)
                ));
            }
            let ack = arm.net_set(net).map_err(|e| e.to_string())?;
            println!(
                "stored {} (state {}): the controller uses it after its next reset",
                armctl::discover::net_string(&net),
                ack.state.name()
            );
            Ok(())
        }
        Cmd::Frame(_) | Cmd::Plot { .. } | Cmd::Discover { .. } | Cmd::Net(NetCmd::Show) => Ok(()),
    }
}

/// `discover` (and `net show`): one line per controller that answered.
fn discover(
    cli: &Cli,
    to: std::net::SocketAddrV4,
    wait_ms: u64,
    rounds: u32,
    json: bool,
) -> CliResult {
    use armctl::discover::{DiscoverOptions, mac_string, net_string};
    let bind = match cli.bind {
        Some(std::net::SocketAddr::V4(b)) => Some(b),
        Some(other) => return Err(format!("--bind {other}: DISCOVER is IPv4")),
        None => None,
    };
    let found = armctl::discover::discover(&DiscoverOptions {
        target: to,
        bind,
        wait: Duration::from_millis(wait_ms.max(1)),
        rounds,
    })
    .map_err(|e| format!("DISCOVER to {to}: {e}"))?;
    if json {
        let list: Vec<serde_json::Value> = found
            .iter()
            .map(|f| serde_json::json!({ "address": f.from.to_string(), "reply": f.reply }))
            .collect();
        println!(
            "{}",
            serde_json::to_string_pretty(&list).map_err(|e| e.to_string())?
        );
        return Ok(());
    }
    for f in &found {
        match &f.reply {
            Some(r) => {
                let owner = match r.owner {
                    protocol::OwnerState::Free => "free".to_string(),
                    protocol::OwnerState::Asker => "owned by this host".to_string(),
                    protocol::OwnerState::Other => {
                        let [a, b, c, d] = r.owner_ip;
                        format!("owned by {a}.{b}.{c}.{d}")
                    }
                };
                let pending = if r.pending_reset {
                    " (after reset)"
                } else {
                    ""
                };
                println!(
                    "{:<21} mac {}  version {}.{}.{}  {} joints  {:<8} {}  stored {}{pending}",
                    f.from.to_string(),
                    mac_string(&r.mac),
                    r.version[0],
                    r.version[1],
                    r.version[2],
                    r.joints,
                    r.state.name(),
                    owner,
                    net_string(&r.net)
                );
            }
            None => println!(
                "{:<21} a controller without DISCOVER (protocol 1.0): `armctl --controller {} status` tells more",
                f.from.to_string(),
                f.from
            ),
        }
    }
    println!("{} controller(s) answered DISCOVER to {to}", found.len());
    Ok(())
}

fn print_status(s: &StatusReport) {
    let flag = |bit| if s.flags.has(bit) { "yes" } else { "no" };
    println!(
        "version          {}.{}.{}",
        s.version[0], s.version[1], s.version[2]
    );
    println!("state            {}", s.state.name());
    println!("joints           {}", s.joints);
    println!(
        "buffer           {} of {} points ({} free)",
        s.buffered,
        s.capacity,
        s.capacity.saturating_sub(s.buffered)
    );
    println!(
        "trajectory       {} announced, {} received, {} executed",
        s.expected, s.received, s.executed
    );
    println!(
        "window           {} datagrams back to back{}",
        armctl::window_of(s),
        if s.window == 0 {
            " (not advertised: assumed)"
        } else {
            ""
        }
    );
    println!("report period    {} us", s.upload_period_us);
    println!("max step rate    {} steps/s", s.max_step_rate_hz);
    println!("pwm timer clock  {} Hz", s.pwm_timer_clock_hz);
    println!(
        "reports {}  drivers enabled {}  serial open {}  pin0 {}  pin1 {}  pwm {}",
        flag(StatusFlags::REPORTS_ON),
        flag(StatusFlags::DRIVERS_ENABLED),
        flag(StatusFlags::SERIAL_OPEN),
        flag(StatusFlags::PIN0_HIGH),
        flag(StatusFlags::PIN1_HIGH),
        flag(StatusFlags::PWM_ACTIVE)
    );
    println!(
        "last run ended by underrun {}  by STOPPED {}",
        flag(StatusFlags::UNDERRUN),
        flag(StatusFlags::STOPPED_BY_HOST)
    );
    if s.more_flags.has(protocol::MoreFlags::UPLOAD_DROPPED) {
        println!("an unstarted upload was dropped when another host took the controller over");
    }
}

fn location_line(location: &Location, joints: usize) -> String {
    let mut line = format!("{:<8}", record::state_name(location.state));
    for (j, p) in location.position.iter().take(joints).enumerate() {
        line.push_str(&format!(" j{j} {p:>9}"));
    }
    line
}

fn watch(arm: &Controller, record: Option<&std::path::Path>, duration: Option<f64>) -> CliResult {
    let status = arm.status().map_err(|e| e.to_string())?;
    let joints = usize::from(status.joints).clamp(1, 8);
    let locations = arm.locations();
    // LOCATION reports go to the tool that asked last: this one, from now on.
    arm.claim_locations().map_err(|e| e.to_string())?;
    let mut recorder = record
        .map(|path| Recorder::create(path, joints).map_err(|e| format!("{}: {e}", path.display())))
        .transpose()?;
    let started = Instant::now();
    let end = duration.map(|s| started + Duration::from_secs_f64(s.max(0.0)));
    let tty = std::io::stdout().is_terminal();
    let mut last_print = Instant::now() - Duration::from_secs(1);
    let mut last_status = Instant::now();
    let mut seen = 0u64;
    loop {
        if end.is_some_and(|e| Instant::now() >= e) {
            break;
        }
        match locations.recv_timeout(Duration::from_millis(200)) {
            Ok(location) => {
                seen += 1;
                if let Some(r) = recorder.as_mut() {
                    r.record(&location)
                        .and_then(|()| r.flush())
                        .map_err(|e| e.to_string())?;
                }
                // At most 10 lines a second on screen, every state change included.
                if last_print.elapsed() >= Duration::from_millis(100) {
                    last_print = Instant::now();
                    let line = location_line(&location, joints);
                    if tty {
                        print!("\r{line}");
                        let _ = std::io::stdout().flush();
                    } else {
                        println!("{line}");
                    }
                }
            }
            Err(mpsc::RecvTimeoutError::Timeout) => {}
            Err(mpsc::RecvTimeoutError::Disconnected) => break,
        }
        // STATUS now and then keeps this host the owner (reports go to the owner).
        if last_status.elapsed() >= Duration::from_secs(1) {
            last_status = Instant::now();
            arm.status().map_err(|e| e.to_string())?;
        }
    }
    if tty {
        println!();
    }
    println!("{seen} location reports");
    Ok(())
}

/// A trajectory file converted to points.
struct Converted {
    points: Vec<Point>,
    /// How messages name each joint: `joint 2 (elbow)`, or `joint 2` without a name.
    joint_names: Vec<String>,
}

/// The trajectory file as points, from `current`.
fn convert(
    args: &RunArgs,
    current: &[i32; 8],
    controller_joints: Option<usize>,
    controller_max_rate: Option<u32>,
) -> Result<Converted, String> {
    let (waypoints, config) =
        trajectory::load_files(&args.file, args.config.as_deref()).map_err(|e| e.to_string())?;
    let joints = waypoints.positions.first().map_or(0, Vec::len);
    if let Some(n) = controller_joints
        && joints > n
    {
        return Err(format!(
            "{}: {joints} joints in the file, the controller drives {n} (`armctl joints N`)",
            args.file.display()
        ));
    }
    let config = config
        .unwrap_or_else(|| ArmConfig::unlimited(joints, controller_max_rate.unwrap_or(u32::MAX)));
    if !(args.segment_ms.is_finite() && args.segment_ms > 0.0) {
        return Err("--segment-ms must be above 0".into());
    }
    let segment_us = (args.segment_ms * 1000.0).round().clamp(1.0, 1e9) as u32;
    let points = trajectory::to_points(
        &waypoints,
        current,
        segment_us,
        &config,
        controller_max_rate,
    )
    .map_err(|e| e.with_joint_names(&config).to_string())?;
    let joint_names = (0..MAX_JOINTS)
        .map(
            |j| match config.joints.get(j).and_then(|c| c.name.as_ref()) {
                Some(name) => format!("joint {j} ({name})"),
                None => format!("joint {j}"),
            },
        )
        .collect();
    Ok(Converted {
        points,
        joint_names,
    })
}

fn print_points_summary(points: &[Point]) {
    let us: i64 = points.iter().map(|p| i64::from(p.duration)).sum();
    println!(
        "{} points, {:.3} s, ends at {:?}",
        points.len(),
        us as f64 / 1e6,
        points.last().map(|p| p.position).unwrap_or_default()
    );
}

fn run(arm: &Controller, args: &RunArgs) -> CliResult {
    let status = arm.status().map_err(|e| e.to_string())?;
    if status.state != State::Stopped {
        return Err(format!(
            "the controller is {}: `armctl stop` first, or wait for the run to end",
            status.state.name()
        ));
    }
    let joints = usize::from(status.joints).clamp(1, 8);
    let current = arm
        .current_location(Duration::from_secs(2))
        .map_err(|e| e.to_string())?;
    let Converted {
        points,
        joint_names,
    } = convert(
        args,
        &current.position,
        Some(joints),
        Some(status.max_step_rate_hz),
    )?;
    print_points_summary(&points);

    // Record from a thread that owns its own report stream.
    let recording = match &args.record {
        Some(path) => {
            let mut recorder =
                Recorder::create(path, joints).map_err(|e| format!("{}: {e}", path.display()))?;
            let locations = arm.locations();
            let (stop_tx, stop_rx) = mpsc::channel::<()>();
            let handle = std::thread::spawn(move || -> std::io::Result<()> {
                while stop_rx.try_recv().is_err() {
                    if let Ok(location) = locations.recv_timeout(Duration::from_millis(50)) {
                        recorder.record(&location)?;
                    }
                }
                // What arrived before the stop.
                while let Ok(location) = locations.try_recv() {
                    recorder.record(&location)?;
                }
                recorder.flush()
            });
            Some((stop_tx, handle))
        }
        None => None,
    };

    let bar = if args.quiet {
        indicatif::ProgressBar::hidden()
    } else {
        indicatif::ProgressBar::new(points.len() as u64)
    };
    bar.set_style(
        indicatif::ProgressStyle::with_template(
            "{spinner} [{elapsed_precise}] {bar:40} {pos}/{len} executed  {msg}",
        )
        .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    let options = RunOptions {
        // 0: the controller's advertised window.
        window: args.window.map_or(0, usize::from),
        start_after: args.start_after,
        ..RunOptions::default()
    };
    let result = arm.run_trajectory(&points, &options, |p| {
        bar.set_position(p.executed as u64);
        bar.set_message(format!(
            "{} sent, {} acked, {}",
            p.sent,
            p.acked,
            p.state.name()
        ));
    });
    bar.finish();
    if let Some((stop, handle)) = recording {
        // A last report or two after the end.
        std::thread::sleep(Duration::from_millis(50));
        let _ = stop.send(());
        match handle.join() {
            Ok(Ok(())) => {}
            Ok(Err(e)) => eprintln!("warning: recording: {e}"),
            Err(_) => eprintln!("warning: the recording thread failed"),
        }
    }
    let report = result.map_err(|e| e.to_string())?;
    println!(
        "uploaded {} points in {} frames, window {} ({} datagrams, {} resent, {} out of order, {} buffer full, {} timeouts) in {:.3} s; run took {:.3} s",
        report.points,
        report.frames,
        report.window,
        report.datagrams_sent,
        report.retransmissions,
        report.out_of_order,
        report.buffer_full,
        report.timeouts,
        report.upload_time.as_secs_f64(),
        report.total_time.as_secs_f64()
    );
    let expected = points.last().map(|p| p.position).unwrap_or_default();
    let Some(location) = report.final_location else {
        return Err("no LOCATION report after the run: cannot check the final positions".into());
    };
    let wrong: Vec<String> = (0..joints)
        .filter(|&j| location.position[j] != expected[j])
        .map(|j| {
            format!(
                "{} at {} steps, expected {}",
                joint_names[j], location.position[j], expected[j]
            )
        })
        .collect();
    if wrong.is_empty() {
        println!(
            "final positions match the last point: {:?}",
            &location.position[..joints]
        );
        Ok(())
    } else {
        Err(format!("final positions differ: {}", wrong.join("; ")))
    }
}

fn serial(arm: &Controller, baud: u32, mode: u32, keep_open: bool) -> CliResult {
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
        while let Ok(bytes) = rx.try_recv() {
            stdout.write_all(&bytes).map_err(|e| e.to_string())?;
            stdout.flush().map_err(|e| e.to_string())?;
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

#[cfg(test)]
mod tests;
