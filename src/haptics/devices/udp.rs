//! `udp:ADDR`: a network device speaking the protocol of `docs/haptic-protocol.md`.
//!
//! * The socket is non-blocking; each `read` drains every pending datagram (at most
//!   [`MAX_DATAGRAMS_PER_READ`], the rest wait for the next tick), decodes it and keeps the
//!   newest valid pose. Every dropped datagram is counted by its [`DropReason`].
//! * The first valid pose packet's sender becomes the peer. While the peer is alive, poses
//!   from other addresses are dropped ([`DropReason::OtherSender`]) and sequence numbers
//!   must strictly increase (equal: duplicate, smaller: stale).
//! * Keep-alive: with no valid pose for `keepalive` seconds (default 100 ms) the reading is
//!   not fresh (the servo fades the force to zero); the next valid packet, from any sender
//!   and with any sequence number, starts a new session.
//! * `send` answers the peer with a force packet every tick for `answer_for` seconds
//!   (default 1 s) after its last valid pose, so a driver sees the fade, then falls silent.

use crate::error::{PalpateError, Result};
use crate::haptics::device::{
    DeviceReading, DeviceSpec, DeviceStats, HapticDevice, VelocityEstimator,
};
use crate::haptics::model::ForceCommand;
use crate::haptics::protocol::{
    DropReason, ForcePacket, PosePacket, SequenceFilter, POSE_VELOCITY_VALID,
};
use std::io::ErrorKind;
use std::net::{SocketAddr, UdpSocket};

/// Datagrams one `read` drains at most (a flood cannot hold the servo tick).
pub const MAX_DATAGRAMS_PER_READ: usize = 256;

/// A device on a UDP socket.
#[derive(Debug)]
pub struct UdpDevice {
    spec: DeviceSpec,
    socket: UdpSocket,
    local: SocketAddr,
    keepalive: f64,
    answer_for: f64,
    peer: Option<SocketAddr>,
    last_valid: f64,
    was_fresh: bool,
    filter: SequenceFilter,
    pose: PosePacket,
    velocity: VelocityEstimator,
    stats: DeviceStats,
    send_sequence: u64,
}

impl UdpDevice {
    /// Default keep-alive, s.
    pub const DEFAULT_KEEPALIVE: f64 = 0.1;
    /// Default time palpate keeps answering after the last valid pose, s.
    pub const DEFAULT_ANSWER_FOR: f64 = 1.0;

    /// Bind a non-blocking socket at `addr` (port 0: the OS picks one, see
    /// [`local_addr`](Self::local_addr)). The error is one line naming the address.
    pub fn bind(addr: SocketAddr, spec: DeviceSpec) -> Result<Self> {
        let fail = |e: std::io::Error| {
            PalpateError::Usage(format!("--device udp:{addr}: cannot bind: {e}"))
        };
        let socket = UdpSocket::bind(addr).map_err(fail)?;
        socket.set_nonblocking(true).map_err(fail)?;
        let local = socket.local_addr().map_err(fail)?;
        Ok(UdpDevice {
            spec,
            socket,
            local,
            keepalive: Self::DEFAULT_KEEPALIVE,
            answer_for: Self::DEFAULT_ANSWER_FOR,
            peer: None,
            last_valid: f64::NEG_INFINITY,
            was_fresh: false,
            filter: SequenceFilter::default(),
            pose: PosePacket::default(),
            velocity: VelocityEstimator::new(VelocityEstimator::DEFAULT_WINDOW),
            stats: DeviceStats::default(),
            send_sequence: 0,
        })
    }

    /// Set the keep-alive, s.
    pub fn with_keepalive(mut self, seconds: f64) -> Self {
        self.keepalive = seconds;
        self
    }

    /// The address the socket is bound to.
    pub fn local_addr(&self) -> SocketAddr {
        self.local
    }

    /// The current peer (the sender of the last accepted pose).
    pub fn peer(&self) -> Option<SocketAddr> {
        self.peer
    }

    fn alive(&self, now: f64) -> bool {
        self.peer.is_some() && now - self.last_valid <= self.keepalive
    }

    fn accept(
        &mut self,
        bytes: &[u8],
        from: SocketAddr,
        now: f64,
    ) -> std::result::Result<(), DropReason> {
        let pose = PosePacket::decode(bytes)?;
        if pose.position.length() > DeviceSpec::REACH * self.spec.workspace_radius {
            return Err(DropReason::OutOfReach);
        }
        if self.alive(now) {
            if Some(from) != self.peer {
                return Err(DropReason::OtherSender);
            }
        } else {
            // A new session: any sender, any sequence number.
            self.filter.reset();
            self.velocity.clear();
            self.peer = Some(from);
        }
        self.filter.check(pose.sequence)?;
        self.pose = pose;
        self.last_valid = now;
        self.velocity.push(pose.device_time, pose.position);
        Ok(())
    }
}

impl HapticDevice for UdpDevice {
    fn spec(&self) -> DeviceSpec {
        self.spec
    }

    fn describe(&self) -> String {
        format!("udp:{}", self.local)
    }

    fn read(&mut self, now: f64) -> DeviceReading {
        let mut buf = [0u8; 256];
        for _ in 0..MAX_DATAGRAMS_PER_READ {
            match self.socket.recv_from(&mut buf) {
                Ok((n, from)) => {
                    self.stats.received += 1;
                    match self.accept(&buf[..n], from, now) {
                        Ok(()) => self.stats.accepted += 1,
                        Err(reason) => self.stats.dropped.add(reason),
                    }
                }
                Err(e) if e.kind() == ErrorKind::WouldBlock => break,
                // An ICMP "port unreachable" from an earlier send to a peer that went away.
                Err(e)
                    if matches!(
                        e.kind(),
                        ErrorKind::ConnectionRefused | ErrorKind::ConnectionReset
                    ) => {}
                Err(_) => break,
            }
        }
        let fresh = self.alive(now);
        if self.was_fresh && !fresh {
            self.stats.keepalive_timeouts += 1;
        }
        self.was_fresh = fresh;
        let velocity = if self.pose.flags & POSE_VELOCITY_VALID != 0 {
            self.pose.velocity
        } else {
            self.velocity.velocity()
        };
        DeviceReading {
            position: self.pose.position,
            velocity,
            buttons: self.pose.buttons,
            fresh,
            sampled: self.last_valid.is_finite().then_some(self.last_valid),
        }
    }

    fn send(&mut self, now: f64, command: &ForceCommand) {
        let Some(peer) = self.peer else { return };
        if now - self.last_valid > self.answer_for {
            return;
        }
        self.send_sequence += 1;
        let packet = ForcePacket {
            sequence: self.send_sequence,
            echo_sequence: self.pose.sequence,
            echo_device_time: self.pose.device_time,
            time: now,
            force: command.force,
            model_force: command.model_force,
            stiffness: command.stiffness,
            model_position: command.at,
            model_age: command.model_age,
            flags: command.flags,
            max_force: self.spec.max_force,
        };
        match self.socket.send_to(&packet.encode(), peer) {
            Ok(_) => self.stats.sent += 1,
            Err(_) => self.stats.send_errors += 1,
        }
    }

    fn stats(&self) -> DeviceStats {
        self.stats
    }
}
