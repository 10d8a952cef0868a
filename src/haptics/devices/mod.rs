//! The devices palpate ships: `null`, `scripted:FILE` and `udp:ADDR`, and the parser of the
//! `--device` argument.

pub mod null;
pub mod scripted;
pub mod udp;

pub use null::NullDevice;
pub use scripted::{ScriptedDevice, Trajectory};
pub use udp::UdpDevice;

use super::device::{DeviceSpec, HapticDevice};
use crate::error::{PalpateError, Result};
use std::net::{IpAddr, Ipv4Addr, SocketAddr};
use std::path::PathBuf;

/// A parsed `--device` argument.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum DeviceArg {
    /// `null`: a device resting at the origin.
    Null,
    /// `scripted:FILE`: a trajectory CSV `t,x,y,z` (s, m).
    Scripted(PathBuf),
    /// `udp:ADDR`: a network device speaking `docs/haptic-protocol.md`.
    Udp(SocketAddr),
}

impl DeviceArg {
    /// Parse `null`, `scripted:FILE` or `udp:ADDR`, where ADDR is `PORT` (bound to
    /// 127.0.0.1), `IP:PORT` or `[IPv6]:PORT` (an explicit address, loopback or not, is used
    /// as given), or `localhost:PORT`. Host names other than `localhost` are refused (no
    /// name lookups). Errors are one line naming the argument.
    pub fn parse(arg: &str) -> Result<DeviceArg> {
        let usage = |what: &str| {
            PalpateError::Usage(format!(
                "--device {arg}: {what}; expected null, scripted:FILE or udp:ADDR (ADDR = PORT or HOST:PORT)"
            ))
        };
        if arg == "null" {
            return Ok(DeviceArg::Null);
        }
        if let Some(file) = arg.strip_prefix("scripted:") {
            if file.is_empty() {
                return Err(usage("missing trajectory file"));
            }
            return Ok(DeviceArg::Scripted(PathBuf::from(file)));
        }
        if let Some(addr) = arg.strip_prefix("udp:") {
            return parse_udp_addr(addr)
                .map(DeviceArg::Udp)
                .map_err(|what| PalpateError::Usage(format!("--device udp:{addr}: {what}")));
        }
        Err(usage("unknown device"))
    }

    /// Open the device with `spec`. Errors (unreadable trajectory, address that cannot be
    /// bound) are one line.
    pub fn open(&self, spec: DeviceSpec) -> Result<Box<dyn HapticDevice>> {
        Ok(match self {
            DeviceArg::Null => Box::new(NullDevice::new(spec)),
            DeviceArg::Scripted(path) => Box::new(ScriptedDevice::from_file(path, spec)?),
            DeviceArg::Udp(addr) => Box::new(UdpDevice::bind(*addr, spec)?),
        })
    }
}

/// Parse and open a device from the `--device` and `--device-spec` arguments (`None` = the
/// default spec, [`DeviceSpec::DEFAULT_NAME`]).
pub fn open_device(device: &str, spec: Option<&str>) -> Result<Box<dyn HapticDevice>> {
    let spec = DeviceSpec::by_name(spec.unwrap_or(DeviceSpec::DEFAULT_NAME))?;
    DeviceArg::parse(device)?.open(spec)
}

/// `PORT`, `IP:PORT`, `[IPv6]:PORT` or `localhost:PORT`.
fn parse_udp_addr(addr: &str) -> std::result::Result<SocketAddr, String> {
    let port = |p: &str| {
        p.parse::<u16>()
            .map_err(|_| format!("port '{p}' is not a number in 0..=65535"))
    };
    if addr.is_empty() {
        return Err("missing address".into());
    }
    if addr.bytes().all(|b| b.is_ascii_digit()) {
        return Ok(SocketAddr::new(
            IpAddr::V4(Ipv4Addr::LOCALHOST),
            port(addr)?,
        ));
    }
    if let Ok(sa) = addr.parse::<SocketAddr>() {
        return Ok(sa);
    }
    if let Some(rest) = addr.strip_prefix('[') {
        // [IPv6]:PORT, brackets once around the address.
        let Some((ip, after)) = rest.split_once(']') else {
            return Err("'[' without its ']': expected [IPv6]:PORT".into());
        };
        let Ok(v6) = ip.parse::<std::net::Ipv6Addr>() else {
            return Err(format!("'[{ip}]' is not an IPv6 address in brackets"));
        };
        let Some(p) = after.strip_prefix(':').filter(|p| !p.is_empty()) else {
            return Err(format!("missing port after [{ip}]: expected [IPv6]:PORT"));
        };
        return Ok(SocketAddr::new(IpAddr::V6(v6), port(p)?));
    }
    let Some((host, p)) = addr.rsplit_once(':') else {
        return Err("expected PORT or HOST:PORT".into());
    };
    let port = port(p)?;
    if host.eq_ignore_ascii_case("localhost") {
        return Ok(SocketAddr::new(IpAddr::V4(Ipv4Addr::LOCALHOST), port));
    }
    match host.parse::<IpAddr>() {
        Ok(ip) => Ok(SocketAddr::new(ip, port)),
        Err(_) => Err(format!(
            "host '{host}' is not an IP address (give an IP literal or localhost)"
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_device_args() {
        assert_eq!(DeviceArg::parse("null").unwrap(), DeviceArg::Null);
        assert_eq!(
            DeviceArg::parse("scripted:a.csv").unwrap(),
            DeviceArg::Scripted("a.csv".into())
        );
        assert_eq!(
            DeviceArg::parse("udp:4242").unwrap(),
            DeviceArg::Udp("127.0.0.1:4242".parse().unwrap())
        );
        assert_eq!(
            DeviceArg::parse("udp:localhost:5").unwrap(),
            DeviceArg::Udp("127.0.0.1:5".parse().unwrap())
        );
        assert_eq!(
            DeviceArg::parse("udp:[::1]:7").unwrap(),
            DeviceArg::Udp("[::1]:7".parse().unwrap())
        );
        for bad in [
            "udp:999999",
            "udp:",
            "udp:host.example:5",
            "foo",
            "scripted:",
        ] {
            let e = DeviceArg::parse(bad).unwrap_err().to_string();
            assert!(!e.contains('\n') && e.contains(bad), "{e}");
        }
        // IPv6 in brackets: each malformed form says what is wrong with it.
        for (bad, says) in [
            ("udp:[::1]", "missing port after [::1]"),
            ("udp:[::1", "'[' without its ']'"),
            ("udp:[[::1]]:4242", "is not an IPv6 address in brackets"),
            ("udp:]::1[:4243", "host ']::1[' is not an IP address"),
            ("udp:[127.0.0.1]:5", "is not an IPv6 address in brackets"),
        ] {
            let e = DeviceArg::parse(bad).unwrap_err().to_string();
            assert!(e.contains(says), "{bad}: {e}");
        }
    }
}
