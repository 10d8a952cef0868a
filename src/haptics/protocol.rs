//! The UDP device protocol: pose packets in (device → palpate), force packets out
//! (palpate → device). Fixed sizes, little-endian, versioned, sequence-numbered and
//! time-stamped. `docs/haptic-protocol.md` documents every byte; this file is the code that
//! page describes (the page's worked example is checked against it by a test).
//!
//! Every packet starts with a 16-byte header:
//!
//! | offset | type | field |
//! |---|---|---|
//! | 0 | `[u8; 4]` | magic `PLPT` |
//! | 4 | `u16` | version ([`VERSION`]) |
//! | 6 | `u16` | type: 1 pose, 2 force |
//! | 8 | `u64` | sequence number, strictly increasing per sender |

use glam::{DMat3, DVec3};
use serde::Serialize;
use std::fmt;

/// First four bytes of every packet.
pub const MAGIC: [u8; 4] = *b"PLPT";
/// Protocol version this build speaks.
pub const VERSION: u16 = 1;
/// Packet type of a [`PosePacket`].
pub const TYPE_POSE: u16 = 1;
/// Packet type of a [`ForcePacket`].
pub const TYPE_FORCE: u16 = 2;
/// Bytes of the common header.
pub const HEADER_LEN: usize = 16;
/// Bytes of a pose packet.
pub const POSE_LEN: usize = 80;
/// Bytes of a force packet.
pub const FORCE_LEN: usize = 208;
/// [`PosePacket::flags`] bit: the packet's velocity is measured (else palpate estimates it).
pub const POSE_VELOCITY_VALID: u32 = 1;

/// Why a received datagram was dropped.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DropReason {
    /// Shorter than its header or its type's size.
    Short,
    /// Does not start with [`MAGIC`].
    BadMagic,
    /// A version other than [`VERSION`].
    WrongVersion,
    /// Not the expected packet type.
    WrongType,
    /// Longer than its type's size.
    WrongSize,
    /// A number in it is NaN or infinite.
    NonFinite,
    /// Same sequence number as the last accepted packet.
    Duplicate,
    /// Older sequence number than the last accepted packet (reordered or late).
    Stale,
    /// From another address than the current peer while the peer is alive.
    OtherSender,
    /// A position more than [`crate::haptics::device::DeviceSpec::REACH`] workspace radii
    /// from the tool's home: no device gets there (a corrupt or mis-scaled pose).
    OutOfReach,
}

impl fmt::Display for DropReason {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            DropReason::Short => "short packet",
            DropReason::BadMagic => "bad magic",
            DropReason::WrongVersion => "wrong version",
            DropReason::WrongType => "wrong packet type",
            DropReason::WrongSize => "wrong packet size",
            DropReason::NonFinite => "non-finite value",
            DropReason::Duplicate => "duplicate sequence number",
            DropReason::Stale => "older sequence number",
            DropReason::OtherSender => "other sender",
            DropReason::OutOfReach => "position beyond the device's reach",
        })
    }
}

/// Dropped packets by reason.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct DropCounts {
    /// [`DropReason::Short`].
    pub short: u64,
    /// [`DropReason::BadMagic`].
    pub bad_magic: u64,
    /// [`DropReason::WrongVersion`].
    pub wrong_version: u64,
    /// [`DropReason::WrongType`].
    pub wrong_type: u64,
    /// [`DropReason::WrongSize`].
    pub wrong_size: u64,
    /// [`DropReason::NonFinite`].
    pub non_finite: u64,
    /// [`DropReason::Duplicate`].
    pub duplicate: u64,
    /// [`DropReason::Stale`].
    pub stale: u64,
    /// [`DropReason::OtherSender`].
    pub other_sender: u64,
    /// [`DropReason::OutOfReach`].
    pub out_of_reach: u64,
}

impl DropCounts {
    /// Count one drop.
    pub fn add(&mut self, reason: DropReason) {
        *match reason {
            DropReason::Short => &mut self.short,
            DropReason::BadMagic => &mut self.bad_magic,
            DropReason::WrongVersion => &mut self.wrong_version,
            DropReason::WrongType => &mut self.wrong_type,
            DropReason::WrongSize => &mut self.wrong_size,
            DropReason::NonFinite => &mut self.non_finite,
            DropReason::Duplicate => &mut self.duplicate,
            DropReason::Stale => &mut self.stale,
            DropReason::OtherSender => &mut self.other_sender,
            DropReason::OutOfReach => &mut self.out_of_reach,
        } += 1;
    }

    /// All drops.
    pub fn total(&self) -> u64 {
        self.short
            + self.bad_magic
            + self.wrong_version
            + self.wrong_type
            + self.wrong_size
            + self.non_finite
            + self.duplicate
            + self.stale
            + self.other_sender
            + self.out_of_reach
    }
}

/// Device → palpate, 80 bytes: the device pose.
///
/// | offset | type | field |
/// |---|---|---|
/// | 0 | header | type 1 |
/// | 16 | `f64` | device time stamp, s (the device's clock, any origin) |
/// | 24 | `3 × f64` | position x, y, z, m (relative to the tool home) |
/// | 48 | `3 × f64` | velocity, m/s |
/// | 72 | `u32` | buttons, bit i = button i |
/// | 76 | `u32` | flags: bit 0 = velocity valid |
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PosePacket {
    /// Sequence number, strictly increasing per sender.
    pub sequence: u64,
    /// The device's time stamp, s.
    pub device_time: f64,
    /// m.
    pub position: DVec3,
    /// m/s (meaningful when `flags & POSE_VELOCITY_VALID`).
    pub velocity: DVec3,
    /// Bit i = button i.
    pub buttons: u32,
    /// [`POSE_VELOCITY_VALID`].
    pub flags: u32,
}

/// Palpate → device, 208 bytes: the force to apply and the hand-side local model, so a
/// driver running faster than the packets can extrapolate F(x) = f0 + K·(x − x0).
///
/// | offset | type | field |
/// |---|---|---|
/// | 0 | header | type 2 |
/// | 16 | `u64` | echo: sequence of the last accepted pose packet |
/// | 24 | `f64` | echo: that packet's device time stamp, s |
/// | 32 | `f64` | palpate's time stamp (loop clock), s |
/// | 40 | `3 × f64` | force to apply to the hand, N |
/// | 64 | `3 × f64` | f0: the position-dependent part of the force, N |
/// | 88 | `9 × f64` | K: stiffness, N/m, row-major (K₀₀ K₀₁ K₀₂ K₁₀ …) |
/// | 160 | `3 × f64` | x0: the device position f0 and K were computed at, m |
/// | 184 | `f64` | age of the physics model, s (+∞ before the first) |
/// | 192 | `u32` | flags ([`crate::haptics::model::flags`]) |
/// | 196 | `u32` | reserved, 0 |
/// | 200 | `f64` | the device's force limit, N |
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ForcePacket {
    /// Sequence number, 1, 2, … per palpate run.
    pub sequence: u64,
    /// Sequence of the last accepted pose packet.
    pub echo_sequence: u64,
    /// Device time stamp of the last accepted pose packet, s.
    pub echo_device_time: f64,
    /// Palpate's loop clock when sent, s.
    pub time: f64,
    /// N.
    pub force: DVec3,
    /// f0, N.
    pub model_force: DVec3,
    /// K, N/m.
    pub stiffness: DMat3,
    /// x0, m.
    pub model_position: DVec3,
    /// s.
    pub model_age: f64,
    /// Flag bits.
    pub flags: u32,
    /// N.
    pub max_force: f64,
}

impl Default for ForcePacket {
    fn default() -> Self {
        ForcePacket {
            sequence: 0,
            echo_sequence: 0,
            echo_device_time: 0.0,
            time: 0.0,
            force: DVec3::ZERO,
            model_force: DVec3::ZERO,
            stiffness: DMat3::ZERO,
            model_position: DVec3::ZERO,
            model_age: f64::INFINITY,
            flags: 0,
            max_force: 0.0,
        }
    }
}

/// Little-endian writer into a fixed buffer.
struct Writer<'a> {
    buf: &'a mut [u8],
    at: usize,
}

impl Writer<'_> {
    fn bytes(&mut self, b: &[u8]) {
        self.buf[self.at..self.at + b.len()].copy_from_slice(b);
        self.at += b.len();
    }
    fn u16(&mut self, v: u16) {
        self.bytes(&v.to_le_bytes());
    }
    fn u32(&mut self, v: u32) {
        self.bytes(&v.to_le_bytes());
    }
    fn u64(&mut self, v: u64) {
        self.bytes(&v.to_le_bytes());
    }
    fn f64(&mut self, v: f64) {
        self.bytes(&v.to_le_bytes());
    }
    fn vec3(&mut self, v: DVec3) {
        self.f64(v.x);
        self.f64(v.y);
        self.f64(v.z);
    }
    fn header(&mut self, kind: u16, sequence: u64) {
        self.bytes(&MAGIC);
        self.u16(VERSION);
        self.u16(kind);
        self.u64(sequence);
    }
}

/// Little-endian reader over a buffer whose length was checked.
struct Reader<'a> {
    buf: &'a [u8],
    at: usize,
}

impl Reader<'_> {
    fn take<const N: usize>(&mut self) -> [u8; N] {
        let mut out = [0u8; N];
        out.copy_from_slice(&self.buf[self.at..self.at + N]);
        self.at += N;
        out
    }
    fn u32(&mut self) -> u32 {
        u32::from_le_bytes(self.take())
    }
    fn u64(&mut self) -> u64 {
        u64::from_le_bytes(self.take())
    }
    fn f64(&mut self) -> f64 {
        f64::from_le_bytes(self.take())
    }
    fn vec3(&mut self) -> DVec3 {
        DVec3::new(self.f64(), self.f64(), self.f64())
    }
}

/// Check the header and the size of a packet of type `kind` and length `len`; returns the
/// sequence number.
fn check_header(bytes: &[u8], kind: u16, len: usize) -> Result<u64, DropReason> {
    if bytes.len() < HEADER_LEN {
        return Err(DropReason::Short);
    }
    if bytes[0..4] != MAGIC {
        return Err(DropReason::BadMagic);
    }
    if u16::from_le_bytes([bytes[4], bytes[5]]) != VERSION {
        return Err(DropReason::WrongVersion);
    }
    if u16::from_le_bytes([bytes[6], bytes[7]]) != kind {
        return Err(DropReason::WrongType);
    }
    if bytes.len() < len {
        return Err(DropReason::Short);
    }
    if bytes.len() > len {
        return Err(DropReason::WrongSize);
    }
    let mut seq = [0u8; 8];
    seq.copy_from_slice(&bytes[8..16]);
    Ok(u64::from_le_bytes(seq))
}

impl PosePacket {
    /// The 80 bytes of this packet.
    pub fn encode(&self) -> [u8; POSE_LEN] {
        let mut buf = [0u8; POSE_LEN];
        let mut w = Writer {
            buf: &mut buf,
            at: 0,
        };
        w.header(TYPE_POSE, self.sequence);
        w.f64(self.device_time);
        w.vec3(self.position);
        w.vec3(self.velocity);
        w.u32(self.buttons);
        w.u32(self.flags);
        buf
    }

    /// Decode a pose packet, or say why it is dropped (sequence order is checked by a
    /// [`SequenceFilter`], not here).
    pub fn decode(bytes: &[u8]) -> Result<PosePacket, DropReason> {
        let sequence = check_header(bytes, TYPE_POSE, POSE_LEN)?;
        let mut r = Reader {
            buf: bytes,
            at: HEADER_LEN,
        };
        let p = PosePacket {
            sequence,
            device_time: r.f64(),
            position: r.vec3(),
            velocity: r.vec3(),
            buttons: r.u32(),
            flags: r.u32(),
        };
        let velocity_ok = p.flags & POSE_VELOCITY_VALID == 0 || p.velocity.is_finite();
        if !(p.device_time.is_finite() && p.position.is_finite() && velocity_ok) {
            return Err(DropReason::NonFinite);
        }
        Ok(p)
    }
}

impl ForcePacket {
    /// The 208 bytes of this packet.
    pub fn encode(&self) -> [u8; FORCE_LEN] {
        let mut buf = [0u8; FORCE_LEN];
        let mut w = Writer {
            buf: &mut buf,
            at: 0,
        };
        w.header(TYPE_FORCE, self.sequence);
        w.u64(self.echo_sequence);
        w.f64(self.echo_device_time);
        w.f64(self.time);
        w.vec3(self.force);
        w.vec3(self.model_force);
        for row in 0..3 {
            w.vec3(self.stiffness.row(row));
        }
        w.vec3(self.model_position);
        w.f64(self.model_age);
        w.u32(self.flags);
        w.u32(0);
        w.f64(self.max_force);
        buf
    }

    /// Decode a force packet, or say why it is dropped.
    pub fn decode(bytes: &[u8]) -> Result<ForcePacket, DropReason> {
        let sequence = check_header(bytes, TYPE_FORCE, FORCE_LEN)?;
        let mut r = Reader {
            buf: bytes,
            at: HEADER_LEN,
        };
        let echo_sequence = r.u64();
        let echo_device_time = r.f64();
        let time = r.f64();
        let force = r.vec3();
        let model_force = r.vec3();
        let rows = [r.vec3(), r.vec3(), r.vec3()];
        let p = ForcePacket {
            sequence,
            echo_sequence,
            echo_device_time,
            time,
            force,
            model_force,
            stiffness: DMat3::from_cols(rows[0], rows[1], rows[2]).transpose(),
            model_position: r.vec3(),
            model_age: r.f64(),
            flags: {
                let f = r.u32();
                let _reserved = r.u32();
                f
            },
            max_force: r.f64(),
        };
        let finite = p.force.is_finite()
            && p.model_force.is_finite()
            && p.stiffness.is_finite()
            && p.model_position.is_finite()
            && p.time.is_finite()
            && !p.model_age.is_nan();
        if !finite {
            return Err(DropReason::NonFinite);
        }
        Ok(p)
    }

    /// The force a driver should apply at device position `x` between packets:
    /// F = f0 + K·(x − x0), zero where it would point against f0 (no pull), clamped in
    /// magnitude to `max_force` keeping its direction; plus the damping part of `force`.
    /// With `POSE_HELD` set, `force` as sent: palpate did not trust the pose, so the
    /// driver's own position is not to be trusted to extrapolate with either.
    pub fn extrapolate(&self, x: DVec3) -> DVec3 {
        if self.flags & crate::haptics::model::flags::POSE_HELD != 0 {
            return self.force;
        }
        let mut f = self.model_force + self.stiffness * (x - self.model_position);
        if f.dot(self.model_force) <= 0.0 {
            f = DVec3::ZERO;
        }
        f += self.force - self.model_force;
        let n = f.length();
        if n > self.max_force && n > 0.0 {
            f *= self.max_force / n;
        }
        f
    }
}

/// Accepts strictly increasing sequence numbers: the same number again is a
/// [`DropReason::Duplicate`], a smaller one [`DropReason::Stale`].
#[derive(Clone, Copy, Debug, Default)]
pub struct SequenceFilter {
    last: Option<u64>,
}

impl SequenceFilter {
    /// Accept `sequence` (and remember it) or say why not.
    pub fn check(&mut self, sequence: u64) -> Result<(), DropReason> {
        match self.last {
            Some(last) if sequence == last => Err(DropReason::Duplicate),
            Some(last) if sequence < last => Err(DropReason::Stale),
            _ => {
                self.last = Some(sequence);
                Ok(())
            }
        }
    }

    /// The last accepted sequence number.
    pub fn last(&self) -> Option<u64> {
        self.last
    }

    /// Accept any sequence number next (the peer restarted or changed).
    pub fn reset(&mut self) {
        self.last = None;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn round_trips() {
        let p = PosePacket {
            sequence: 42,
            device_time: 1.25,
            position: DVec3::new(0.001, -0.002, 0.003),
            velocity: DVec3::new(0.1, 0.2, -0.3),
            buttons: 5,
            flags: POSE_VELOCITY_VALID,
        };
        assert_eq!(PosePacket::decode(&p.encode()), Ok(p));
        let f = ForcePacket {
            sequence: 7,
            echo_sequence: 42,
            echo_device_time: 1.25,
            time: 3.5,
            force: DVec3::new(0.0, 0.0, 1.5),
            model_force: DVec3::new(0.0, 0.0, 1.4),
            stiffness: DMat3::from_cols_array(&[1., 2., 3., 4., 5., 6., 7., 8., 9.]),
            model_position: DVec3::new(0.0, 0.0, -0.004),
            model_age: 0.002,
            flags: 3,
            max_force: 3.3,
        };
        assert_eq!(ForcePacket::decode(&f.encode()), Ok(f));
        // Row-major on the wire: K[0][1] (row 0, column 1) is the second f64.
        let bytes = f.encode();
        let k01 = f64::from_le_bytes(bytes[96..104].try_into().unwrap());
        assert_eq!(k01, f.stiffness.row(0).y);
    }

    #[test]
    fn drop_reasons() {
        let good = PosePacket::default().encode();
        assert_eq!(PosePacket::decode(&good[..10]), Err(DropReason::Short));
        assert_eq!(PosePacket::decode(&good[..40]), Err(DropReason::Short));
        let mut b = good;
        b[0] = b'X';
        assert_eq!(PosePacket::decode(&b), Err(DropReason::BadMagic));
        let mut b = good;
        b[4] = 2;
        assert_eq!(PosePacket::decode(&b), Err(DropReason::WrongVersion));
        let mut b = good;
        b[6] = 2;
        assert_eq!(PosePacket::decode(&b), Err(DropReason::WrongType));
        let mut long = [0u8; POSE_LEN + 1];
        long[..POSE_LEN].copy_from_slice(&good);
        assert_eq!(PosePacket::decode(&long), Err(DropReason::WrongSize));
        let bad = PosePacket {
            position: DVec3::new(f64::NAN, 0.0, 0.0),
            ..Default::default()
        };
        assert_eq!(
            PosePacket::decode(&bad.encode()),
            Err(DropReason::NonFinite)
        );
        let mut s = SequenceFilter::default();
        assert_eq!(s.check(5), Ok(()));
        assert_eq!(s.check(5), Err(DropReason::Duplicate));
        assert_eq!(s.check(4), Err(DropReason::Stale));
        assert_eq!(s.check(9), Ok(()));
    }
}
