//! Devices: the `--device` and `--device-spec` arguments, scripted trajectories (values and
//! one-line errors), and the UDP device over loopback (drops by reason, keep-alive, the
//! force fading to zero when packets stop, addresses that cannot be bound).
//!
//! Network: loopback only (127.0.0.1, OS-chosen ports); every loop is bounded.

#[path = "haptics_common.rs"]
mod common;

use common::{temp_path, Wall};
use glam::DVec3;
use palpate::haptics::model::flags;
use palpate::haptics::protocol::{DropCounts, ForcePacket, PosePacket, POSE_LEN};
use palpate::haptics::{
    open_device, DeviceArg, DeviceReading, DeviceSpec, HapticDevice, ServoConfig, ServoCore,
    Trajectory, UdpDevice,
};
use std::net::UdpSocket;
use std::time::{Duration, Instant};

fn one_line(e: &palpate::PalpateError) -> String {
    let s = e.to_string();
    assert!(!s.contains('\n'), "multi-line error: {s}");
    s
}

// ---------------------------------------------------------------- specs and arguments

#[test]
fn device_specs_by_name() {
    for name in ["touch", "omni", "desktop", "omega3", "falcon"] {
        assert_eq!(DeviceSpec::by_name(name).unwrap().name, name);
    }
    assert_eq!(DeviceSpec::by_name("Omega.3").unwrap(), DeviceSpec::OMEGA3);
    assert_eq!(
        DeviceSpec::by_name("phantom-omni").unwrap(),
        DeviceSpec::OMNI
    );
    let s = DeviceSpec::TOUCH;
    assert_eq!(
        (
            s.max_force,
            s.max_stiffness,
            s.max_damping,
            s.workspace_radius
        ),
        (3.3, 400.0, 4.0, 0.075)
    );
    let e = one_line(&DeviceSpec::by_name("phantom").unwrap_err());
    assert!(
        e.contains("phantom") && e.contains("touch, omni, desktop, omega3, falcon"),
        "{e}"
    );
    let e = one_line(&open_device("null", Some("nope")).err().unwrap());
    assert!(e.contains("nope"), "{e}");
}

#[test]
fn device_argument_errors_are_one_line() {
    for (arg, needle) in [
        ("joystick", "unknown device"),
        ("scripted:", "missing trajectory file"),
        ("udp:", "missing address"),
        ("udp:999999", "999999"),
        ("udp:example.com:4242", "not an IP address"),
    ] {
        let e = one_line(&DeviceArg::parse(arg).unwrap_err());
        assert!(
            e.contains(needle) && e.contains(arg.split(':').next().unwrap()),
            "{arg}: {e}"
        );
    }
    let e = one_line(&open_device("udp:999999", None).err().unwrap());
    assert!(e.contains("999999"), "{e}");
}

// ---------------------------------------------------------------- scripted trajectories

fn write(name: &str, text: &str) -> std::path::PathBuf {
    let p = temp_path(name);
    std::fs::write(&p, text).unwrap();
    p
}

#[test]
fn scripted_trajectory_interpolates_and_holds() {
    let path = write(
        "ok.csv",
        "# a press\nt,x,y,z\n0.0, 0, 0, 0.002\n\n1.0, 0.001, 0, -0.003 # bottom\n2.0,0,0,0.002\n",
    );
    let t = Trajectory::from_file(&path).unwrap();
    assert_eq!(t.len(), 3);
    assert_eq!(t.end_time(), 2.0);
    let close = |a: DVec3, b: DVec3| (a - b).length() < 1e-15;
    assert!(
        close(t.at(-1.0), DVec3::new(0.0, 0.0, 0.002)),
        "held before the first row"
    );
    assert!(close(t.at(0.5), DVec3::new(0.0005, 0.0, -0.0005)));
    assert!(close(t.at(1.0), DVec3::new(0.001, 0.0, -0.003)));
    assert!(close(t.at(1.25), DVec3::new(0.00075, 0.0, -0.00175)));
    assert!(
        close(t.at(9.0), DVec3::new(0.0, 0.0, 0.002)),
        "held after the last row"
    );

    // The device plays it from its first read; its velocity comes from the estimator.
    let mut dev = DeviceArg::parse(&format!("scripted:{}", path.display()))
        .unwrap()
        .open(DeviceSpec::TOUCH)
        .unwrap();
    assert_eq!(dev.duration(), Some(2.0));
    let mut r = DeviceReading::default();
    for k in 0..=100 {
        r = dev.read(10.0 + k as f64 * 1e-3);
    }
    assert!(r.fresh);
    assert!(close(r.position, t.at(0.1)));
    assert!(
        (r.velocity - DVec3::new(0.001, 0.0, -0.005)).length() < 1e-9,
        "{}",
        r.velocity
    );
    std::fs::remove_file(path).ok();

    // Saved by a spreadsheet: a byte-order mark before the header, CRLF line ends.
    let bom = write("bom.csv", "\u{feff}t,x,y,z\r\n0,0,0,0\r\n1,0,0,0.001\r\n");
    let t = Trajectory::from_file(&bom).unwrap();
    assert_eq!((t.len(), t.end_time()), (2, 1.0));
    std::fs::remove_file(bom).ok();
}

#[test]
fn scripted_trajectory_errors_name_the_file_and_line() {
    let cases = [
        (
            "fields.csv",
            "t,x,y,z\n0,0,0,0\n1,0,0\n",
            "line 3",
            "expected 4",
        ),
        (
            "number.csv",
            "0,0,0,0\n1,0,abc,0\n",
            "line 2",
            "y = 'abc' is not a number",
        ),
        ("nan.csv", "0,0,0,0\n1,0,0,nan\n", "line 2", "not finite"),
        (
            "old_mac.csv",
            "t,x,y,z\r0,0,0,0\r1,0,0,0\r",
            "line 1",
            "found 10 (its lines end in a carriage return alone",
        ),
        (
            "order.csv",
            "0,0,0,0\n# c\n0.5,0,0,0\n0.5,0,0,1\n",
            "line 4",
            "strictly increase",
        ),
        (
            "negative.csv",
            "-1,0,0,0\n0.1,0,0,0\n",
            "line 1",
            "before the session's start at 0 s",
        ),
        (
            "back.csv",
            "0,0,0,0\n1,0,0,0\n0.2,0,0,0\n",
            "line 3",
            "strictly increase",
        ),
        (
            "header_late.csv",
            "0,0,0,0\nt,x,y,z\n",
            "line 2",
            "'t' is not a number",
        ),
        (
            "empty.csv",
            "# nothing\n\nt,x,y,z\n",
            "no data rows",
            "no data rows",
        ),
        (
            "columns.csv",
            "x,y,z,t\n0,0,0,0\n1,0,0,0.01\n",
            "line 1",
            "does not name the columns t,x,y,z",
        ),
    ];
    for (name, text, at, what) in cases {
        let path = write(name, text);
        let e = one_line(&Trajectory::from_file(&path).unwrap_err());
        assert!(
            e.starts_with(&path.display().to_string()) && e.contains(at) && e.contains(what),
            "{name}: {e}"
        );
        let e = one_line(
            &DeviceArg::parse(&format!("scripted:{}", path.display()))
                .unwrap()
                .open(DeviceSpec::TOUCH)
                .err()
                .unwrap(),
        );
        assert!(e.contains(at), "{e}");
        std::fs::remove_file(path).ok();
    }
    let missing = temp_path("does-not-exist.csv");
    let e = one_line(&Trajectory::from_file(&missing).unwrap_err());
    assert!(
        e.contains("does-not-exist.csv") && e.contains("cannot read trajectory"),
        "{e}"
    );
}

// ---------------------------------------------------------------- UDP over loopback

fn pose(sequence: u64, z: f64) -> [u8; POSE_LEN] {
    PosePacket {
        sequence,
        device_time: sequence as f64 * 1e-3,
        position: DVec3::new(0.0, 0.0, z),
        ..Default::default()
    }
    .encode()
}

fn loopback_device(spec: DeviceSpec) -> (UdpDevice, UdpSocket) {
    let dev = UdpDevice::bind("127.0.0.1:0".parse().unwrap(), spec).unwrap();
    let client = UdpSocket::bind("127.0.0.1:0").unwrap();
    client.connect(dev.local_addr()).unwrap();
    (dev, client)
}

/// Read at loop time `now` until the device has received `n` datagrams in all (bounded).
fn pump(dev: &mut UdpDevice, now: f64, n: u64) -> DeviceReading {
    let give_up = Instant::now() + Duration::from_secs(2);
    loop {
        let r = dev.read(now);
        if dev.stats().received >= n || Instant::now() > give_up {
            return r;
        }
        std::thread::sleep(Duration::from_micros(200));
    }
}

#[test]
fn udp_drops_bad_packets_by_reason_and_goes_on() {
    let (mut dev, client) = loopback_device(DeviceSpec::TOUCH);
    let mut wrong_version = pose(20, 0.0);
    wrong_version[4] = 2;
    let mut long = [0u8; POSE_LEN + 1];
    long[..POSE_LEN].copy_from_slice(&pose(21, 0.0));
    let non_finite = PosePacket {
        sequence: 22,
        position: DVec3::new(f64::NAN, 0.0, 0.0),
        ..Default::default()
    }
    .encode();
    let garbage: Vec<u8> = (0..80u32).map(|i| (i * 37 % 251) as u8).collect();
    let datagrams: Vec<Vec<u8>> = vec![
        pose(10, -0.001).to_vec(),                // accepted
        pose(11, 0.0)[..20].to_vec(),             // short
        garbage,                                  // bad magic
        wrong_version.to_vec(),                   // wrong version
        ForcePacket::default().encode().to_vec(), // wrong type
        pose(10, 0.5).to_vec(),                   // duplicate
        pose(12, -0.002).to_vec(),                // accepted
        pose(11, 0.5).to_vec(),                   // stale (older sequence)
        long.to_vec(),                            // wrong size
        non_finite.to_vec(),                      // non-finite
        vec![],                                   // empty: short
        pose(13, 1e300).to_vec(),                 // out of reach
        pose(14, 0.76).to_vec(),                  // out of reach: > 10 × 0.075 m
    ];
    for d in &datagrams {
        client.send(d).unwrap();
    }
    let r = pump(&mut dev, 0.0, datagrams.len() as u64);
    let s = dev.stats();
    assert_eq!(s.received, datagrams.len() as u64);
    assert_eq!(s.accepted, 2);
    assert_eq!(
        s.dropped,
        DropCounts {
            short: 2,
            bad_magic: 1,
            wrong_version: 1,
            wrong_type: 1,
            wrong_size: 1,
            non_finite: 1,
            duplicate: 1,
            stale: 1,
            other_sender: 0,
            out_of_reach: 2,
        }
    );
    assert!(r.fresh);
    assert_eq!(
        r.position,
        DVec3::new(0.0, 0.0, -0.002),
        "the newest valid pose"
    );

    // A second sender is refused while the peer is alive, accepted once it has gone quiet.
    let intruder = UdpSocket::bind("127.0.0.1:0").unwrap();
    intruder.send_to(&pose(100, 0.3), dev.local_addr()).unwrap();
    let r = pump(&mut dev, 0.05, s.received + 1);
    assert_eq!(dev.stats().dropped.other_sender, 1);
    assert_eq!(r.position.z, -0.002);
    intruder.send_to(&pose(1, 0.3), dev.local_addr()).unwrap();
    let r = pump(&mut dev, 0.5, s.received + 2);
    assert!(
        r.fresh && r.position.z == 0.3,
        "a new session after the keep-alive"
    );
    assert_eq!(dev.peer(), Some(intruder.local_addr().unwrap()));
}

#[test]
fn udp_keepalive_expires() {
    let (dev, client) = loopback_device(DeviceSpec::TOUCH);
    let mut dev = dev.with_keepalive(0.1);
    client.send(&pose(1, 0.0)).unwrap();
    assert!(pump(&mut dev, 0.0, 1).fresh);
    assert!(dev.read(0.09).fresh);
    assert!(!dev.read(0.2).fresh);
    assert!(!dev.read(0.3).fresh);
    assert_eq!(dev.stats().keepalive_timeouts, 1);
    client.send(&pose(2, 0.0)).unwrap();
    assert!(pump(&mut dev, 0.4, 2).fresh);
}

/// The servo's computation with a UDP device in the loop (simulated loop time, real
/// loopback packets): the force builds up while poses arrive and fades to zero when they
/// stop; the driver receives force packets echoing its sequence numbers.
#[test]
fn udp_force_fades_to_zero_when_packets_stop() {
    let spec = DeviceSpec::TOUCH;
    let (mut dev, client) = loopback_device(spec);
    client.set_nonblocking(true).unwrap();
    let config = ServoConfig::new(spec);
    let mut core = ServoCore::new(&config);
    let mut wall = Wall::spring(5000.0);
    let (mut model, mut sequence) = (Default::default(), 0u64);
    let stop_sending = 1.5;
    let mut forces = Vec::new();
    let mut replies = Vec::new();
    let mut buf = [0u8; 512];
    for n in 0..1800u64 {
        let t = n as f64 * 1e-3;
        let z = if t < 0.1 { 0.001 } else { -0.002 };
        let received_before = dev.stats().received;
        if t < stop_sending {
            client.send(&pose(n + 1, z)).unwrap();
        }
        let want = received_before + u64::from(t < stop_sending);
        let reading = pump(&mut dev, t, want);
        let out = core.tick(t, &reading, &model, sequence);
        dev.send(t, &out.command);
        model = wall.step(1e-3, out.proxy, t);
        sequence += 1;
        forces.push((
            t,
            out.command.force.length(),
            reading.fresh,
            out.command.flags,
        ));
        while let Ok(k) = client.recv(&mut buf) {
            replies.push(ForcePacket::decode(&buf[..k]).expect("a valid force packet"));
        }
    }
    let at = |time: f64| forces[(time * 1e3).round() as usize];
    assert!(at(1.49).1 > 0.5, "pressing 2 mm: {:?}", at(1.49));
    assert!(at(1.59).2, "fresh within the keep-alive");
    assert!(!at(1.61).2, "not fresh after it");
    // Fades within 50 ms of the keep-alive expiring, smoothly, and stays at zero.
    let mut last = f64::INFINITY;
    for &(t, f, _, flags_) in &forces[1600..] {
        assert!(f <= last + 1e-12, "not monotone at {t}");
        assert!(f <= at(1.49).1 * 0.1 || t < 1.64, "still {f} N at {t}");
        assert!(flags_ & flags::DEVICE_STALE != 0);
        last = f;
    }
    assert_eq!(forces[1700..].iter().map(|x| x.1).fold(0.0, f64::max), 0.0);
    let steps: f64 = forces[1600..1700]
        .windows(2)
        .map(|w| (w[0].1 - w[1].1).abs())
        .fold(0.0, f64::max);
    assert!(
        steps < 0.1 * at(1.49).1,
        "a fade, not a drop: largest step {steps} N"
    );

    let s = dev.stats();
    println!("device stats: {s:?}; replies received {}", replies.len());
    assert_eq!(s.accepted, 1500);
    assert_eq!(s.dropped.total(), 0);
    assert!(replies.len() > 1500, "a force packet every tick");
    let mid = replies.iter().find(|p| p.time >= 1.0).unwrap();
    assert!(
        mid.echo_sequence >= 999 && mid.echo_sequence <= 1001,
        "{}",
        mid.echo_sequence
    );
    assert!(mid.force.z > 0.5 && mid.max_force == spec.max_force);
    assert!((mid.extrapolate(DVec3::new(0.0, 0.0, -0.002)) - mid.force).length() < 1e-9);
    let late = replies.last().unwrap();
    assert!(late.force == DVec3::ZERO && late.flags & flags::FADING != 0);
}

#[test]
fn udp_addresses_that_cannot_be_bound_are_one_line_errors() {
    let spec = DeviceSpec::TOUCH;
    // A port out of range.
    let e = one_line(&open_device("udp:999999", None).err().unwrap());
    assert!(e.contains("udp:999999"), "{e}");
    // An address of no local interface (TEST-NET-1, RFC 5737): bind fails, nothing is sent.
    let e = one_line(
        &DeviceArg::parse("udp:192.0.2.1:4242")
            .unwrap()
            .open(spec)
            .err()
            .unwrap(),
    );
    assert!(
        e.contains("192.0.2.1:4242") && e.contains("cannot bind"),
        "{e}"
    );
    // A loopback port already taken.
    let taken = UdpSocket::bind("127.0.0.1:0").unwrap();
    let port = taken.local_addr().unwrap().port();
    let e = one_line(&open_device(&format!("udp:{port}"), None).err().unwrap());
    assert!(
        e.contains(&port.to_string()) && e.contains("cannot bind"),
        "{e}"
    );
}
