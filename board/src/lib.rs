//! Board example: what an integrator's firmware does around the tracker, on any HAL.
//!
//! Per frame, [`Board::poll`]: read one feature frame through an `embedded-hal` 1.0
//! [`SpiDevice`] with the core's [`Receiver`] (wire format of `stjpdacf::wire`, CRC, sequence and
//! time checks), step the tracker, and write the filtered lanes to a UART (any
//! [`embedded_io::Write`]) as one frame of the lane format below. defmt logs what happened.
//!
//! # Lane frames on the UART (version 1)
//!
//! All integers little-endian, floats IEEE-754 `f32`. `n` is the lane count (≤ 6).
//!
//! | offset | size | field |
//! |---|---|---|
//! | 0 | 4 | magic [`LANE_MAGIC`] = `b"STJL"` |
//! | 4 | 1 | version [`LANE_VERSION`] = 1 |
//! | 5 | 1 | `n`, lanes |
//! | 6 | 2 | reserved, 0 |
//! | 8 | 4 | sequence number of the feature frame (`u32`) |
//! | 12 | 8 | its timestamp, microseconds (`i64`) |
//! | 20 | 156·n | lanes: id `u32`, slot `u8`, reserved `u8`, misses `u16`, age `u32`, hits `u32`, u_first, u_last, existence, z[16], var[16] (`f32`) |
//! | 20 + 156·n | 4 | CRC-32 (the wire format's, [`wire::crc32`]) of the bytes before it |
//!
//! A frame is [`lane_frame_len`]`(n)` = 24 + 156·n bytes (960 at 6 lanes: 8.3 ms at 1 Mbaud).
#![no_std]
#![forbid(unsafe_code)]
#![deny(missing_docs)]

use embedded_hal::spi::SpiDevice;
use stjpdacf::tracker::{LaneEstimate, ReferenceTracker, TrackerConfig};
use stjpdacf::wire::{self, frame_len, ReadError, Receiver};

/// Magic of a lane frame.
pub const LANE_MAGIC: [u8; 4] = *b"STJL";
/// Version of the lane format.
pub const LANE_VERSION: u8 = 1;
/// Bytes per lane in a lane frame.
pub const LANE_LEN: usize = 156;
/// Points a feature frame may carry (the reference tracker's `MEAS`).
pub const MAX_POINTS: usize = 256;
/// Lane slots (the reference tracker's `LANES`).
pub const MAX_LANES: usize = 6;

/// Bytes of a lane frame with `n` lanes.
pub const fn lane_frame_len(n: usize) -> usize {
    24 + LANE_LEN * n
}

/// Writes a lane frame (`seq`, `time_us`, `lanes`, at most [`MAX_LANES`]) into the start of
/// `out` (at least [`lane_frame_len`]`(MAX_LANES)` bytes); returns its length, or `None` when
/// `out` is too short.
pub fn encode_lanes(
    seq: u32,
    time_us: i64,
    lanes: &[LaneEstimate<16>],
    out: &mut [u8],
) -> Option<usize> {
    let lanes = lanes.get(..lanes.len().min(MAX_LANES))?;
    let len = lane_frame_len(lanes.len());
    let frame = out.get_mut(..len)?;
    let mut at = 0usize;
    let mut put = |bytes: &[u8]| {
        if let Some(d) = frame.get_mut(at..at + bytes.len()) {
            d.copy_from_slice(bytes);
        }
        at += bytes.len();
    };
    put(&LANE_MAGIC);
    put(&[LANE_VERSION, lanes.len() as u8, 0, 0]);
    put(&seq.to_le_bytes());
    put(&time_us.to_le_bytes());
    for l in lanes {
        put(&l.id.0.to_le_bytes());
        put(&[l.slot, 0]);
        put(&l.misses.to_le_bytes());
        put(&l.age.to_le_bytes());
        put(&l.hits.to_le_bytes());
        for v in [l.u_first, l.u_last, l.existence]
            .iter()
            .chain(l.z.iter())
            .chain(l.var.iter())
        {
            put(&v.to_le_bytes());
        }
    }
    let crc = wire::crc32(frame.get(..len - 4)?);
    frame
        .get_mut(len - 4..)?
        .copy_from_slice(&crc.to_le_bytes());
    Some(len)
}

/// What one [`Board::poll`] did.
#[derive(Debug, Clone, Copy, PartialEq, Eq, defmt::Format)]
pub enum Polled {
    /// A frame was tracked; its lanes went out on the UART.
    Tracked {
        /// The frame's sequence number.
        seq: u32,
        /// Lanes written.
        lanes: usize,
    },
    /// The frame was rejected (counted in the receiver's `LinkStats`); nothing was written.
    Rejected,
    /// The tracker refused the frame: its time does not increase (cannot happen after the
    /// receiver's check), or [`Board::init`] was not called.
    Refused,
}

/// The SPI or the UART failed.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum BoardError<S, U> {
    /// The SPI device.
    Spi(S),
    /// The UART.
    Uart(U),
}

/// The tracker with its receiver and buffers (~158 KB: put it in a `static` of [`Board::UNINIT`]).
pub struct Board {
    tracker: ReferenceTracker,
    rx: Receiver,
    spi_buf: [u8; frame_len(MAX_POINTS)],
    points: [[f32; 2]; MAX_POINTS],
    out: [u8; lane_frame_len(MAX_LANES)],
}

impl Board {
    /// A board on the built-in tables (`const`: it can live in a `static`).
    pub const fn new() -> Self {
        Self {
            tracker: ReferenceTracker::new(&stjpdacf::tables::DEFAULT),
            rx: Receiver::new(),
            spi_buf: [0; frame_len(MAX_POINTS)],
            points: [[0.0; 2]; MAX_POINTS],
            out: [0; lane_frame_len(MAX_LANES)],
        }
    }

    /// A board whose tracker is [`ReferenceTracker::UNINIT`]: every byte zero, so a `static` of
    /// it is in `.bss` and takes no flash (a `static` [`Board::new`] stores its ~158 KB initial
    /// image in flash). Call [`Board::init`] before [`Board::poll`].
    pub const UNINIT: Self = Self {
        tracker: ReferenceTracker::UNINIT,
        rx: Receiver::new(),
        spi_buf: [0; frame_len(MAX_POINTS)],
        points: [[0.0; 2]; MAX_POINTS],
        out: [0; lane_frame_len(MAX_LANES)],
    };

    /// Makes this board [`Board::new`] in place (the tracker on the built-in tables, the
    /// receiver's counters zero); also restarts a running board.
    pub fn init(&mut self) {
        self.tracker
            .init(&stjpdacf::tables::DEFAULT, TrackerConfig::DEFAULT);
        self.rx = Receiver::new();
    }

    /// The receiver (its `LinkStats`).
    pub fn receiver(&self) -> &Receiver {
        &self.rx
    }

    /// One frame: SPI in, tracker step, lanes out on `uart`.
    ///
    /// # Errors
    /// [`BoardError::Spi`] when an SPI transaction fails (counted by the receiver),
    /// [`BoardError::Uart`] when the UART does.
    pub fn poll<S: SpiDevice, U: embedded_io::Write>(
        &mut self,
        spi: &mut S,
        uart: &mut U,
    ) -> Result<Polled, BoardError<S::Error, U::Error>> {
        let info = match self.rx.read(spi, &mut self.spi_buf, &mut self.points) {
            Ok(i) => i,
            Err(ReadError::Spi(e)) => return Err(BoardError::Spi(e)),
            Err(ReadError::Frame(e)) => {
                defmt::warn!("frame rejected: {}", e);
                return Ok(Polled::Rejected);
            }
        };
        let pts = self.points.get(..info.count).unwrap_or(&[]);
        let Ok(out) = self.tracker.step(info.time, pts) else {
            defmt::warn!("frame {} refused: time does not increase", info.seq);
            return Ok(Polled::Refused);
        };
        let time_us = info.time.as_micros();
        let n = encode_lanes(info.seq, time_us, &out.filtered, &mut self.out).unwrap_or(0);
        uart.write_all(self.out.get(..n).unwrap_or(&[]))
            .map_err(BoardError::Uart)?;
        uart.flush().map_err(BoardError::Uart)?;
        defmt::debug!(
            "frame {}: {} points, {} lanes, {} events",
            info.seq,
            info.count,
            out.filtered.len(),
            out.report.spatial.events
        );
        Ok(Polled::Tracked {
            seq: info.seq,
            lanes: out.filtered.len(),
        })
    }
}

impl Default for Board {
    fn default() -> Self {
        Self::new()
    }
}
