//! Feature frames on the wire: the binary frame the vision front end sends to the MCU, its
//! allocation-free encoder and decoder, and a reader that pulls one frame through an
//! `embedded-hal` 1.0 [`SpiDevice`].
//!
//! # Byte layout (version 1)
//!
//! All integers little-endian. `n` is the point count.
//!
//! | offset | size | field |
//! |---|---|---|
//! | 0 | 4 | magic [`MAGIC`] = `b"STJF"` |
//! | 4 | 1 | version [`VERSION`] = 1 |
//! | 5 | 1 | flags, reserved: must be 0 |
//! | 6 | 2 | `n`, point count (`u16`) |
//! | 8 | 4 | frame sequence number (`u32`), strictly increasing; gaps are dropped frames |
//! | 12 | 8 | timestamp, microseconds (`i64`, the [`Instant`] of the frame), strictly increasing |
//! | 20 | 4·n | points: `u` then `x` (BEV metres ahead / lateral), each an `i16` in units of [`LSB_M`] = 1/256 m |
//! | 20 + 4·n | 4 | CRC-32 (ISO-HDLC: the zlib / Ethernet CRC) of bytes `0 .. 20 + 4·n` |
//!
//! A frame is [`frame_len`]`(n) = 24 + 4·n` bytes: 1,048 bytes for the reference `M = 256`.
//! Fixed point keeps a frame compact and makes every decodable point finite: the range is
//! −128 m to +127.996 m (the reference tables' BEV window is 3–80 m ahead; the tracker does not
//! limit the lateral position) in steps of 3.9 mm, far below the 10 cm feature-point noise.
//! Points outside the tracker's window in `u` are the tracker's business (it rejects and counts
//! them, `rejected_window`).
//!
//! # API
//!
//! * [`encode`] — points → frame bytes (host, tests, the firmware's scenarios).
//! * [`decode`] — frame bytes → points, stateless: checks magic, version, count against the
//!   caller's capacity, length and CRC, and writes nothing unless all pass.
//! * [`Receiver`] — the MCU side: [`Receiver::accept`] (a frame from a buffer) and
//!   [`Receiver::read`] (a frame through SPI) add the sequence and time checks and count every
//!   outcome in [`LinkStats`]. A frame that fails any check leaves the caller's point buffer
//!   untouched, so the tracker never sees it.
//!
//! # SPI protocol
//!
//! The MCU is the SPI controller. Every chip-select window reads the front end's current frame
//! from its first byte. [`Receiver::read`] uses two windows per frame: one of [`HEADER_LEN`]
//! bytes to learn `n`, then one of [`frame_len`]`(n)` bytes (the header again, the points and the
//! CRC), which is decoded on its own, so a frame the front end replaced between the two windows
//! is either consistent or rejected by its CRC. A header that is garbage or announces more
//! points than the buffers hold is rejected without the second window.
//!
//! ```
//! use stjpdacf::tracker::Instant;
//! use stjpdacf::wire::{self, Receiver, WireError};
//! let pts = [[10.0f32, -1.75], [12.5, 1.8]];
//! let mut buf = [0u8; wire::frame_len(2)];
//! let len = wire::encode(7, Instant::from_micros(50_000), &pts, &mut buf)?;
//!
//! let mut rx = Receiver::new();
//! let mut out = [[0.0f32; 2]; 256];
//! let frame = rx.accept(&buf[..len], &mut out)?;
//! assert_eq!((frame.seq, frame.count), (7, 2));
//! assert_eq!(out[0], [10.0, -1.75]);
//! // The same frame again is stale; a flipped bit fails the CRC. Both are counted.
//! assert_eq!(rx.accept(&buf, &mut out), Err(WireError::NonIncreasingSequence));
//! buf[21] ^= 0x10;
//! assert_eq!(rx.accept(&buf, &mut out), Err(WireError::BadCrc));
//! assert_eq!((rx.stats().frames, rx.stats().rejected()), (1, 2));
//! # Ok::<(), Box<dyn core::error::Error>>(())
//! ```

use embedded_hal::spi::SpiDevice;

use crate::time::Instant;

/// First four bytes of every frame.
pub const MAGIC: [u8; 4] = *b"STJF";
/// The layout version this module reads and writes.
pub const VERSION: u8 = 1;
/// Bytes before the points.
pub const HEADER_LEN: usize = 20;
/// Bytes per point (`u` and `x`, one `i16` each).
pub const POINT_LEN: usize = 4;
/// Bytes of the trailing CRC.
pub const CRC_LEN: usize = 4;
/// Metres per least significant bit of a coordinate (1/256 m).
pub const LSB_M: f32 = 1.0 / 256.0;

/// Length in bytes of a frame with `n` points: `HEADER_LEN + POINT_LEN·n + CRC_LEN`.
/// Saturates at `usize::MAX` (no such frame fits in memory).
pub const fn frame_len(n: usize) -> usize {
    POINT_LEN
        .saturating_mul(n)
        .saturating_add(HEADER_LEN + CRC_LEN)
}

/// Why a frame was rejected. Every variant is counted in [`LinkStats`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum WireError {
    /// Fewer bytes than the header, or than the frame its header announces.
    Truncated,
    /// The first four bytes are not [`MAGIC`].
    BadMagic,
    /// A version other than [`VERSION`], or reserved flags set.
    BadVersion,
    /// The header announces more points than the caller's buffers hold.
    Oversized {
        /// Points announced.
        count: u16,
    },
    /// The CRC does not match the frame's bytes.
    BadCrc,
    /// The sequence number is not after the last accepted frame's.
    NonIncreasingSequence,
    /// The timestamp is not after the last accepted frame's.
    NonIncreasingTime,
}

impl core::fmt::Display for WireError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Truncated => f.write_str("frame truncated"),
            Self::BadMagic => f.write_str("bad frame magic"),
            Self::BadVersion => f.write_str("unsupported frame version or flags"),
            Self::Oversized { count } => write!(f, "frame announces {count} points, too many"),
            Self::BadCrc => f.write_str("frame CRC mismatch"),
            Self::NonIncreasingSequence => f.write_str("frame sequence number does not increase"),
            Self::NonIncreasingTime => f.write_str("frame timestamp does not increase"),
        }
    }
}

impl core::error::Error for WireError {}

/// Error of [`Receiver::read`]: the SPI device failed, or the frame was rejected.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub enum ReadError<E> {
    /// The SPI transaction failed.
    Spi(E),
    /// The bytes read are not an acceptable frame.
    Frame(WireError),
}

impl<E: core::fmt::Debug> core::fmt::Display for ReadError<E> {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::Spi(e) => write!(f, "SPI error: {e:?}"),
            Self::Frame(e) => write!(f, "{e}"),
        }
    }
}

impl<E: core::fmt::Debug> core::error::Error for ReadError<E> {}

impl<E> From<WireError> for ReadError<E> {
    fn from(e: WireError) -> Self {
        Self::Frame(e)
    }
}

/// Error of [`encode`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
#[non_exhaustive]
pub enum EncodeError {
    /// More than `u16::MAX` points.
    TooManyPoints,
    /// `out` is shorter than [`frame_len`] of the points.
    BufferTooSmall {
        /// Bytes needed.
        needed: usize,
    },
    /// A coordinate is not finite or does not round into the `i16` range, −128 m to +127.996 m
    /// (`i16::MAX`·[`LSB_M`]).
    PointOutOfRange {
        /// Index of the point.
        index: usize,
    },
}

impl core::fmt::Display for EncodeError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            Self::TooManyPoints => f.write_str("more than 65535 points"),
            Self::BufferTooSmall { needed } => write!(f, "output buffer needs {needed} bytes"),
            Self::PointOutOfRange { index } => {
                write!(f, "point {index} is not finite or outside ±128 m")
            }
        }
    }
}

impl core::error::Error for EncodeError {}

/// A decoded frame's header; its points are in the caller's buffer, `points[..count]`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct FrameInfo {
    /// Sequence number.
    pub seq: u32,
    /// Timestamp.
    pub time: Instant,
    /// Points written to the caller's buffer. The frame was [`frame_len`]`(count)` bytes.
    pub count: usize,
}

/// Counters of a [`Receiver`] (saturating). Every call to [`Receiver::accept`] or
/// [`Receiver::read`] increments exactly one of `frames` and the rejection counters;
/// `skipped` adds up the sequence gaps between accepted frames.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct LinkStats {
    /// Frames accepted.
    pub frames: u32,
    /// Frames missing between accepted ones (sum of the sequence gaps).
    pub skipped: u32,
    /// [`WireError::Truncated`].
    pub truncated: u32,
    /// [`WireError::BadMagic`].
    pub bad_magic: u32,
    /// [`WireError::BadVersion`].
    pub bad_version: u32,
    /// [`WireError::Oversized`].
    pub oversized: u32,
    /// [`WireError::BadCrc`].
    pub bad_crc: u32,
    /// [`WireError::NonIncreasingSequence`].
    pub non_increasing_seq: u32,
    /// [`WireError::NonIncreasingTime`].
    pub non_increasing_time: u32,
    /// [`ReadError::Spi`].
    pub spi_errors: u32,
}

impl LinkStats {
    /// Frames rejected, for any reason.
    pub fn rejected(&self) -> u32 {
        self.truncated
            .saturating_add(self.bad_magic)
            .saturating_add(self.bad_version)
            .saturating_add(self.oversized)
            .saturating_add(self.bad_crc)
            .saturating_add(self.non_increasing_seq)
            .saturating_add(self.non_increasing_time)
            .saturating_add(self.spi_errors)
    }

    fn count(&mut self, e: WireError) {
        let c = match e {
            WireError::Truncated => &mut self.truncated,
            WireError::BadMagic => &mut self.bad_magic,
            WireError::BadVersion => &mut self.bad_version,
            WireError::Oversized { .. } => &mut self.oversized,
            WireError::BadCrc => &mut self.bad_crc,
            WireError::NonIncreasingSequence => &mut self.non_increasing_seq,
            WireError::NonIncreasingTime => &mut self.non_increasing_time,
        };
        *c = c.saturating_add(1);
    }
}

/// The receiving end of a frame stream: decoding, sequence and time checks, counters.
///
/// A frame is accepted when it decodes and both its sequence number and its timestamp are
/// strictly greater than those of the last accepted frame (so `Tracker::step` never sees a
/// non-increasing time). After the front end restarts its numbering, call [`Receiver::reset`]
/// (and start a new tracker: its time must increase too).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
#[cfg_attr(feature = "defmt", derive(defmt::Format))]
pub struct Receiver {
    last: Option<(u32, Instant)>,
    stats: LinkStats,
}

impl Receiver {
    /// A receiver that accepts any first frame.
    pub const fn new() -> Self {
        Self {
            last: None,
            stats: LinkStats {
                frames: 0,
                skipped: 0,
                truncated: 0,
                bad_magic: 0,
                bad_version: 0,
                oversized: 0,
                bad_crc: 0,
                non_increasing_seq: 0,
                non_increasing_time: 0,
                spi_errors: 0,
            },
        }
    }

    /// The counters.
    pub fn stats(&self) -> &LinkStats {
        &self.stats
    }

    /// Forget the last frame's sequence number and time (the counters stay).
    pub fn reset(&mut self) {
        self.last = None;
    }

    /// Accepts one frame from the start of `bytes` (bytes after the frame are ignored) and writes
    /// its points to `points[..count]`; `points.len()` is the capacity.
    ///
    /// # Errors
    /// Any [`WireError`]; it is counted, and `points` and the receiver's sequence and time are
    /// untouched.
    ///
    /// # Complexity
    /// O(`frame_len(count)`): one CRC pass (a 1 KiB table lookup per byte) and one pass over the
    /// points. No allocation.
    pub fn accept(
        &mut self,
        bytes: &[u8],
        points: &mut [[f32; 2]],
    ) -> Result<FrameInfo, WireError> {
        let r = self.check(bytes, points.len());
        match r {
            Ok(h) => {
                fill(bytes, h.count, points);
                if let Some((seq, _)) = self.last {
                    let gap = h.seq.wrapping_sub(seq).saturating_sub(1);
                    self.stats.skipped = self.stats.skipped.saturating_add(gap);
                }
                self.last = Some((h.seq, h.time));
                self.stats.frames = self.stats.frames.saturating_add(1);
                Ok(h)
            }
            Err(e) => {
                self.stats.count(e);
                Err(e)
            }
        }
    }

    fn check(&self, bytes: &[u8], capacity: usize) -> Result<FrameInfo, WireError> {
        let h = verify(bytes, capacity)?;
        if let Some((seq, time)) = self.last {
            if h.seq <= seq {
                return Err(WireError::NonIncreasingSequence);
            }
            if h.time <= time {
                return Err(WireError::NonIncreasingTime);
            }
        }
        Ok(h)
    }

    /// Reads one frame through `spi` into `buf` (two chip-select windows, see the module docs)
    /// and accepts it as [`Receiver::accept`] does. The capacity is the smaller of
    /// `points.len()` and what fits in `buf`: give `buf` at least [`frame_len`]`(points.len())`
    /// bytes.
    ///
    /// # Errors
    /// [`ReadError::Spi`] when a transaction fails, [`ReadError::Frame`] when the frame is
    /// rejected; both are counted and leave `points` and the receiver's state untouched.
    ///
    /// # Complexity
    /// Two SPI transactions (`HEADER_LEN` and `frame_len(count)` bytes) and
    /// [`Receiver::accept`].
    pub fn read<S: SpiDevice>(
        &mut self,
        spi: &mut S,
        buf: &mut [u8],
        points: &mut [[f32; 2]],
    ) -> Result<FrameInfo, ReadError<S::Error>> {
        let capacity = points
            .len()
            .min(buf.len().saturating_sub(HEADER_LEN + CRC_LEN) / POINT_LEN);
        let Some(head) = buf.get_mut(..HEADER_LEN) else {
            self.stats.count(WireError::Truncated);
            return Err(WireError::Truncated.into());
        };
        if let Err(e) = spi.read(head) {
            self.stats.spi_errors = self.stats.spi_errors.saturating_add(1);
            return Err(ReadError::Spi(e));
        }
        let count = match header(head, capacity) {
            Ok(h) => h.count,
            Err(e) => {
                self.stats.count(e);
                return Err(e.into());
            }
        };
        let Some(frame) = buf.get_mut(..frame_len(count)) else {
            // Only a `buf` shorter than an empty frame (`frame_len(0)`): otherwise `header`
            // checked `count <= capacity`, which fits in `buf`.
            self.stats.count(WireError::Truncated);
            return Err(WireError::Truncated.into());
        };
        if let Err(e) = spi.read(frame) {
            self.stats.spi_errors = self.stats.spi_errors.saturating_add(1);
            return Err(ReadError::Spi(e));
        }
        Ok(self.accept(frame, points)?)
    }
}

/// Decodes one frame from the start of `bytes` (bytes after it are ignored) into
/// `points[..count]`, with no sequence or time check and no counting (see [`Receiver`]).
///
/// # Errors
/// [`WireError::Truncated`], [`WireError::BadMagic`], [`WireError::BadVersion`],
/// [`WireError::Oversized`] (more points than `points.len()`), [`WireError::BadCrc`]. On error
/// `points` is untouched.
///
/// # Complexity
/// O(`frame_len(count)`), no allocation.
pub fn decode(bytes: &[u8], points: &mut [[f32; 2]]) -> Result<FrameInfo, WireError> {
    let h = verify(bytes, points.len())?;
    fill(bytes, h.count, points);
    Ok(h)
}

/// Encodes a frame with sequence number `seq`, time `time` and `points` (`[u, x]`, metres) into
/// the start of `out`; returns its length, [`frame_len`]`(points.len())`. Coordinates are rounded
/// to the nearest multiple of [`LSB_M`].
///
/// # Errors
/// [`EncodeError`]; `out` may be partly written.
///
/// # Complexity
/// O(`points.len()`), no allocation.
pub fn encode(
    seq: u32,
    time: Instant,
    points: &[[f32; 2]],
    out: &mut [u8],
) -> Result<usize, EncodeError> {
    let n = u16::try_from(points.len()).map_err(|_| EncodeError::TooManyPoints)?;
    let len = frame_len(points.len());
    let frame = out
        .get_mut(..len)
        .ok_or(EncodeError::BufferTooSmall { needed: len })?;
    let Some((head, rest)) = frame.split_at_mut_checked(HEADER_LEN) else {
        return Err(EncodeError::BufferTooSmall { needed: len });
    };
    put(head, 0, &MAGIC);
    put(head, 4, &[VERSION, 0]);
    put(head, 6, &n.to_le_bytes());
    put(head, 8, &seq.to_le_bytes());
    put(head, 12, &time.as_micros().to_le_bytes());
    for (i, (p, dst)) in points
        .iter()
        .zip(rest.chunks_exact_mut(POINT_LEN))
        .enumerate()
    {
        let u = quantise(p[0]).ok_or(EncodeError::PointOutOfRange { index: i })?;
        let x = quantise(p[1]).ok_or(EncodeError::PointOutOfRange { index: i })?;
        put(dst, 0, &u.to_le_bytes());
        put(dst, 2, &x.to_le_bytes());
    }
    let body = len - CRC_LEN;
    let crc = crc32(frame.get(..body).unwrap_or(&[]));
    put(frame, body, &crc.to_le_bytes());
    Ok(len)
}

/// CRC-32/ISO-HDLC (polynomial 0x04C11DB7 reflected, initial value and final XOR 0xFFFFFFFF: the
/// CRC of zlib, PNG and Ethernet) of `bytes`.
///
/// # Complexity
/// One 1 KiB-table lookup per byte.
pub fn crc32(bytes: &[u8]) -> u32 {
    let mut crc = u32::MAX;
    for &b in bytes {
        let i = usize::from((crc as u8) ^ b);
        crc = (crc >> 8) ^ CRC_TABLE.get(i).copied().unwrap_or(0);
    }
    !crc
}

/// The byte-wise CRC table, computed at compile time (an out-of-bounds index here would be a
/// compile error, not a run-time panic).
#[allow(clippy::indexing_slicing)]
const CRC_TABLE: [u32; 256] = {
    let mut t = [0u32; 256];
    let mut i = 0;
    while i < 256 {
        let mut c = i as u32;
        let mut k = 0;
        while k < 8 {
            c = if c & 1 != 0 {
                0xEDB8_8320 ^ (c >> 1)
            } else {
                c >> 1
            };
            k += 1;
        }
        t[i] = c;
        i += 1;
    }
    t
};

/// Nearest `i16` multiple of [`LSB_M`], or `None` when not finite or out of range.
fn quantise(v: f32) -> Option<i16> {
    let s = v * 256.0;
    if !(s.is_finite() && s > -32768.5 && s < 32767.5) {
        return None;
    }
    // Round half away from zero; the cast truncates toward zero and the range is checked above.
    let r = if s >= 0.0 { s + 0.5 } else { s - 0.5 };
    Some(r as i16)
}

fn put(dst: &mut [u8], at: usize, src: &[u8]) {
    if let Some(d) = dst.get_mut(at..at + src.len()) {
        d.copy_from_slice(src);
    }
}

fn le<const N: usize>(bytes: &[u8], at: usize) -> [u8; N] {
    bytes
        .get(at..)
        .and_then(|b| b.first_chunk::<N>())
        .copied()
        .unwrap_or([0; N])
}

/// Checks the header alone (magic, version and flags, count ≤ `capacity`).
fn header(bytes: &[u8], capacity: usize) -> Result<FrameInfo, WireError> {
    if bytes.len() < HEADER_LEN {
        return Err(WireError::Truncated);
    }
    if le::<4>(bytes, 0) != MAGIC {
        return Err(WireError::BadMagic);
    }
    if le::<2>(bytes, 4) != [VERSION, 0] {
        return Err(WireError::BadVersion);
    }
    let n = u16::from_le_bytes(le(bytes, 6));
    if usize::from(n) > capacity {
        return Err(WireError::Oversized { count: n });
    }
    Ok(FrameInfo {
        seq: u32::from_le_bytes(le(bytes, 8)),
        time: Instant::from_micros(i64::from_le_bytes(le(bytes, 12))),
        count: usize::from(n),
    })
}

/// Checks everything a frame carries: the header, the length and the CRC.
fn verify(bytes: &[u8], capacity: usize) -> Result<FrameInfo, WireError> {
    let h = header(bytes, capacity)?;
    let body = frame_len(h.count) - CRC_LEN;
    let (Some(data), Some(crc)) = (bytes.get(..body), bytes.get(body..)) else {
        return Err(WireError::Truncated);
    };
    let Some(crc) = crc.first_chunk::<CRC_LEN>() else {
        return Err(WireError::Truncated);
    };
    if crc32(data) != u32::from_le_bytes(*crc) {
        return Err(WireError::BadCrc);
    }
    Ok(h)
}

/// Writes the `count` points of a verified frame to `points`.
fn fill(bytes: &[u8], count: usize, points: &mut [[f32; 2]]) {
    let data = bytes
        .get(HEADER_LEN..HEADER_LEN + POINT_LEN * count)
        .unwrap_or(&[]);
    for (dst, src) in points.iter_mut().zip(data.chunks_exact(POINT_LEN)) {
        let u = i16::from_le_bytes(le(src, 0));
        let x = i16::from_le_bytes(le(src, 2));
        *dst = [f32::from(u) * LSB_M, f32::from(x) * LSB_M];
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn crc_check_value() {
        // The standard check value of CRC-32/ISO-HDLC.
        assert_eq!(crc32(b"123456789"), 0xCBF4_3926);
    }

    #[test]
    fn layout_is_as_documented() {
        let mut buf = [0u8; frame_len(1)];
        let len = encode(
            0x0102_0304,
            Instant::from_micros(-2),
            &[[1.0, -0.5]],
            &mut buf,
        )
        .unwrap();
        assert_eq!(len, 28);
        assert_eq!(&buf[..4], b"STJF");
        assert_eq!(&buf[4..8], &[1, 0, 1, 0]);
        assert_eq!(&buf[8..12], &[4, 3, 2, 1]);
        assert_eq!(&buf[12..20], &(-2i64).to_le_bytes());
        assert_eq!(&buf[20..24], &[0, 1, 0x80, 0xFF]);
        assert_eq!(&buf[24..], &crc32(&buf[..24]).to_le_bytes());
    }

    #[test]
    fn quantise_rounds_and_bounds() {
        assert_eq!(quantise(1.0 / 512.0), Some(1));
        assert_eq!(quantise(-1.0 / 512.0), Some(-1));
        assert_eq!(quantise(127.99), Some(32765));
        assert_eq!(quantise(-128.0), Some(-32768));
        assert_eq!(quantise(128.0), None);
        assert_eq!(quantise(f32::NAN), None);
        assert_eq!(quantise(f32::INFINITY), None);
    }
}
