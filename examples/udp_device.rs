//! A haptic device driver over UDP, as `docs/haptic-protocol.md` describes it: plays a
//! trajectory as pose packets to `palpate haptic --device udp:PORT`, receives the force
//! packets, and prints a short summary. It uses palpate's own protocol code
//! (`palpate::haptics::protocol`), so it is also the reference driver.
//!
//! ```sh
//! palpate haptic --device udp:4242 --seconds 5 &
//! cargo run --release --example udp_device -- 4242                 # built-in press
//! cargo run --release --example udp_device -- 127.0.0.1:4242 --csv path.csv --rate 1000
//! ```
//!
//! The built-in press starts at the tool's home, goes `--depth` (default 8 mm) along
//! `--direction` (default −z) over 1 s, holds 0.5 s, comes back over 1 s and rests 0.3 s:
//! set them so that the press reaches a few millimetres into the tissue of the scene (the
//! default haptic scene `lv_touch` is pressed along −x: `--direction -1,0,0 --depth 0.004`).
//!
//! `--faults N` exercises palpate's packet checks: after every N-th pose it also sends a
//! short datagram, one with a bad magic, one with a wrong version, a duplicate of the pose
//! and a stale pose (an older sequence number); palpate counts each by its reason in
//! `summary.json` (`haptic.device_stats.dropped`) and goes on.

use clap::Parser;
use glam::DVec3;
use palpate::haptics::model::flags;
use palpate::haptics::protocol::{ForcePacket, PosePacket, POSE_VELOCITY_VALID};
use palpate::haptics::{DeviceArg, Trajectory};
use palpate::{PalpateError, Result};
use std::net::{IpAddr, Ipv4Addr, Ipv6Addr, SocketAddr, UdpSocket};
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::{Duration, Instant};

#[derive(Parser)]
#[command(about = "Play a trajectory to palpate over UDP as a haptic device driver would")]
struct Args {
    /// palpate's address: PORT (on 127.0.0.1), IP:PORT or localhost:PORT.
    target: String,
    /// Trajectory CSV `t,x,y,z` (s, m, relative to the tool home); default: a built-in press.
    #[arg(long)]
    csv: Option<PathBuf>,
    /// Pose packets per second.
    #[arg(long, default_value_t = 1000.0)]
    rate: f64,
    /// Seconds to run (default: the trajectory's length + 0.2 s).
    #[arg(long)]
    duration: Option<f64>,
    /// Depth of the built-in press from the tool home, m.
    #[arg(long, default_value_t = 0.008)]
    depth: f64,
    /// Direction of the built-in press, `x,y,z` (normalised).
    #[arg(long, default_value = "0,0,-1", allow_hyphen_values = true)]
    direction: String,
    /// After every N-th pose, also send five faulty datagrams (0: none).
    #[arg(long, default_value_t = 0)]
    faults: u64,
}

/// The driver's keep-alive: with no force packet for this long, it outputs zero force.
const KEEPALIVE: f64 = 0.1;

fn main() -> ExitCode {
    match run(Args::parse()) {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::FAILURE
        }
    }
}

fn usage(message: String) -> PalpateError {
    PalpateError::Usage(message)
}

fn run(args: Args) -> Result<()> {
    let DeviceArg::Udp(target) = DeviceArg::parse(&format!("udp:{}", args.target))? else {
        return Err(usage(format!("{}: not a UDP address", args.target)));
    };
    if !(args.rate.is_finite() && args.rate > 0.0 && args.rate <= 20_000.0) {
        return Err(usage(format!(
            "--rate {}: must be in (0, 20000] Hz",
            args.rate
        )));
    }
    let trajectory = match &args.csv {
        Some(path) => Trajectory::from_file(path)?,
        None => {
            let d = parse_direction(&args.direction)? * args.depth.abs();
            Trajectory::new(&[
                (0.0, DVec3::ZERO),
                (1.0, d),
                (1.5, d),
                (2.5, DVec3::ZERO),
                (2.8, DVec3::ZERO),
            ])?
        }
    };
    let duration = args.duration.unwrap_or(trajectory.end_time() + 0.2);
    if !(duration.is_finite() && duration >= 0.0) {
        return Err(usage(format!("--duration {duration}: must be ≥ 0 s")));
    }

    // Answers come back to the socket the poses leave from.
    let local = match target.ip() {
        ip if ip.is_loopback() => SocketAddr::new(ip, 0),
        IpAddr::V4(_) => SocketAddr::new(IpAddr::V4(Ipv4Addr::UNSPECIFIED), 0),
        IpAddr::V6(_) => SocketAddr::new(IpAddr::V6(Ipv6Addr::UNSPECIFIED), 0),
    };
    let socket = UdpSocket::bind(local)
        .and_then(|s| s.set_nonblocking(true).map(|()| s))
        .map_err(|e| usage(format!("cannot open a UDP socket at {local}: {e}")))?;
    println!(
        "udp_device: {} → {target}, {:.0} Hz for {duration:.2} s ({} trajectory rows)",
        socket.local_addr().map_or("?".into(), |a| a.to_string()),
        args.rate,
        trajectory.len()
    );

    let period = Duration::from_secs_f64(1.0 / args.rate);
    let start = Instant::now();
    let mut deadline = start;
    let mut buf = [0u8; 512];
    let (mut sent, mut send_errors, mut received, mut bad) = (0u64, 0u64, 0u64, 0u64);
    let mut faulty = 0u64;
    let (mut max_force, mut clamped, mut fading) = (0.0f64, 0u64, 0u64);
    let mut newest: Option<(ForcePacket, f64)> = None;
    let mut round_trips: Vec<f64> = Vec::new();
    let mut last_x = trajectory.at(0.0);
    let mut next_print = 0.0;
    loop {
        let now = start.elapsed().as_secs_f64();
        if now >= duration {
            break;
        }
        let x = trajectory.at(now);
        let v = (x - last_x) * args.rate;
        last_x = x;
        sent += 1;
        let pose = PosePacket {
            sequence: sent,
            device_time: now,
            position: x,
            velocity: v,
            buttons: 0,
            flags: POSE_VELOCITY_VALID,
        };
        let bytes = pose.encode();
        if socket.send_to(&bytes, target).is_err() {
            send_errors += 1;
        }
        if args.faults > 0 && sent % args.faults == 0 {
            let mut bad_magic = bytes;
            bad_magic[0] ^= 0xff;
            let mut wrong_version = bytes;
            wrong_version[4] = wrong_version[4].wrapping_add(1);
            let stale = PosePacket {
                sequence: sent.saturating_sub(1).max(1) - 1,
                ..pose
            }
            .encode();
            for datagram in [
                &bytes[..7],
                &bad_magic[..],
                &wrong_version[..],
                &bytes[..],
                &stale[..],
            ] {
                if socket.send_to(datagram, target).is_err() {
                    send_errors += 1;
                }
            }
            faulty += 5;
        }
        // Drain the answers; keep the newest.
        loop {
            match socket.recv(&mut buf) {
                Ok(n) => match ForcePacket::decode(&buf[..n]) {
                    Ok(p) => {
                        received += 1;
                        round_trips.push(now - p.echo_device_time);
                        max_force = max_force.max(p.force.length());
                        clamped += u64::from(p.flags & flags::CLAMPED != 0);
                        fading += u64::from(p.flags & flags::FADING != 0);
                        if newest.is_none_or(|(q, _)| p.sequence > q.sequence) {
                            newest = Some((p, now));
                        }
                    }
                    Err(_) => bad += 1,
                },
                Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => break,
                // palpate not (yet) listening: ICMP port unreachable; keep going.
                Err(_) => break,
            }
        }
        // What a real driver would apply: the newest model extrapolated to the current
        // position, or nothing when palpate has gone quiet.
        let applied = match newest {
            Some((p, at)) if now - at <= KEEPALIVE => p.extrapolate(x),
            _ => DVec3::ZERO,
        };
        if now >= next_print {
            println!(
                "t = {now:5.2} s  x = ({:+6.2}, {:+6.2}, {:+6.2}) mm  force = ({:+.2}, {:+.2}, {:+.2}) N",
                x.x * 1e3,
                x.y * 1e3,
                x.z * 1e3,
                applied.x,
                applied.y,
                applied.z
            );
            next_print += 0.5;
        }
        deadline += period;
        let after = Instant::now();
        if deadline > after {
            std::thread::sleep(deadline - after);
        } else {
            deadline = after; // late: no burst of catch-up packets
        }
    }

    round_trips.sort_by(f64::total_cmp);
    let pct = |p: f64| {
        round_trips
            .get(((p * round_trips.len() as f64) as usize).min(round_trips.len().saturating_sub(1)))
            .map_or(f64::NAN, |s| s * 1e3)
    };
    println!(
        "sent {sent} pose packets and {faulty} faulty datagrams ({send_errors} send errors), received {received} force packets ({bad} undecodable)"
    );
    println!(
        "max |force| {max_force:.3} N, clamped in {clamped}, fading in {fading}; round trip p50 {:.2} ms, p99 {:.2} ms",
        pct(0.5),
        pct(0.99)
    );
    if received == 0 {
        println!(
            "no answer: is `palpate haptic --device udp:{}` running?",
            target.port()
        );
    }
    Ok(())
}

/// `x,y,z` → a unit vector.
fn parse_direction(text: &str) -> Result<DVec3> {
    let parts: Vec<f64> = text
        .split(',')
        .map(|p| p.trim().parse::<f64>())
        .collect::<std::result::Result<_, _>>()
        .map_err(|_| usage(format!("--direction {text}: expected three numbers x,y,z")))?;
    let d = match parts[..] {
        [x, y, z] => DVec3::new(x, y, z),
        _ => {
            return Err(usage(format!(
                "--direction {text}: expected three numbers x,y,z"
            )))
        }
    };
    if !(d.is_finite() && d.length() > 0.0) {
        return Err(usage(format!(
            "--direction {text}: must be a non-zero vector"
        )));
    }
    Ok(d.normalize())
}
