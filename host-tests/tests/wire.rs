//! The SPI feature-frame format (`stjpdacf::wire`): layout, every rejection and its counter, the
//! two-window SPI protocol (scripted with embedded-hal-mock, and a small front-end mock for SPI
//! failures and frames replaced between windows), a tracker fed through a receiver that sees bad
//! frames, and properties: arbitrary bytes never panic and never yield a frame with non-finite or
//! over-capacity content.

use embedded_hal::spi::{ErrorKind, ErrorType, Operation, SpiDevice};
use embedded_hal_mock::eh1::spi::{Mock as SpiMock, Transaction as T};
use proptest::prelude::*;
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use stjpdacf::tables::DEFAULT;
use stjpdacf::tracker::{Instant, ReferenceTracker};
use stjpdacf::wire::{
    self, crc32, decode, encode, frame_len, EncodeError, LinkStats, ReadError, Receiver, WireError,
    CRC_LEN, HEADER_LEN, LSB_M,
};
use stjpdacf_tools::scenario::{Scenario, ScenarioConfig};

const CAP: usize = 256;
/// What the caller's point buffer holds before a call: any write shows.
const SENTINEL: [f32; 2] = [-999.0, 999.0];

fn frame(seq: u32, t_us: i64, points: &[[f32; 2]]) -> Vec<u8> {
    let mut buf = vec![0u8; frame_len(points.len())];
    let n = encode(seq, Instant::from_micros(t_us), points, &mut buf).unwrap();
    assert_eq!(n, buf.len());
    buf
}

fn some_points(n: usize, seed: u64) -> Vec<[f32; 2]> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..n)
        .map(|_| [rng.random_range(3.0..80.0), rng.random_range(-12.0..12.0)])
        .collect()
}

/// Rewrites the CRC after editing a frame's bytes.
fn reseal(f: &mut [u8]) {
    let body = f.len() - CRC_LEN;
    let crc = crc32(&f[..body]);
    f[body..].copy_from_slice(&crc.to_le_bytes());
}

#[test]
fn round_trip_quantises_to_the_lsb_and_matches_crc32fast() {
    let pts = some_points(CAP, 1);
    let f = frame(42, 1_234_567, &pts);
    assert_eq!(f.len(), 24 + 4 * CAP);
    assert_eq!(f.len(), 1048);
    let body = f.len() - 4;
    assert_eq!(
        u32::from_le_bytes(f[body..].try_into().unwrap()),
        crc32fast::hash(&f[..body])
    );
    let mut out = [SENTINEL; CAP];
    let info = decode(&f, &mut out).unwrap();
    assert_eq!(
        (info.seq, info.time, info.count),
        (42, Instant::from_micros(1_234_567), CAP)
    );
    for (a, b) in pts.iter().zip(&out) {
        for k in 0..2 {
            assert!((a[k] - b[k]).abs() <= LSB_M / 2.0 + 1e-6, "{a:?} vs {b:?}");
            // Decoded values are exact multiples of the LSB.
            assert_eq!((b[k] / LSB_M).fract(), 0.0);
        }
    }
    // Bytes after the frame are ignored (frames back to back in one buffer).
    let mut two = f.clone();
    two.extend(frame(43, 1_300_000, &pts[..3]));
    assert_eq!(decode(&two, &mut out).unwrap().count, CAP);
    let info = decode(&two[f.len()..], &mut out).unwrap();
    assert_eq!((info.seq, info.count), (43, 3));
    // An empty frame is valid.
    assert_eq!(decode(&frame(1, 0, &[]), &mut out).unwrap().count, 0);
}

#[test]
fn encoder_rejects_what_the_format_cannot_carry() {
    let mut buf = vec![0u8; frame_len(2)];
    let t = Instant::from_micros(0);
    assert_eq!(
        encode(0, t, &[[1.0, 1.0]; 3], &mut buf),
        Err(EncodeError::BufferTooSmall {
            needed: frame_len(3)
        })
    );
    for bad in [
        f32::NAN,
        f32::INFINITY,
        f32::NEG_INFINITY,
        128.0,
        -128.01,
        1e9,
    ] {
        assert_eq!(
            encode(0, t, &[[1.0, 1.0], [1.0, bad]], &mut buf),
            Err(EncodeError::PointOutOfRange { index: 1 })
        );
        assert_eq!(
            encode(0, t, &[[bad, 1.0]], &mut buf),
            Err(EncodeError::PointOutOfRange { index: 0 })
        );
    }
    let many = vec![[0.0f32; 2]; 65_536];
    let mut big = vec![0u8; frame_len(many.len())];
    assert_eq!(
        encode(0, t, &many, &mut big),
        Err(EncodeError::TooManyPoints)
    );
    assert_eq!(frame_len(usize::MAX), usize::MAX);
}

/// Every kind of bad frame: the typed error, its counter, the point buffer untouched, and the
/// receiver still accepting the next good frame.
#[test]
fn every_rejection_is_typed_counted_and_harmless() {
    let pts = some_points(10, 2);
    let good = frame(10, 1_000_000, &pts);
    let mut rx = Receiver::new();
    let mut out = [SENTINEL; 16];
    // (bytes, capacity, error)
    let mut cases: Vec<(Vec<u8>, usize, WireError)> = Vec::new();
    // Truncated: every cut of the frame.
    for cut in 0..good.len() {
        cases.push((good[..cut].to_vec(), 16, WireError::Truncated));
    }
    let mut magic = good.clone();
    magic[0] = b'X';
    cases.push((magic, 16, WireError::BadMagic));
    let mut version = good.clone();
    version[4] = 2;
    reseal(&mut version);
    cases.push((version, 16, WireError::BadVersion));
    let mut flags = good.clone();
    flags[5] = 0x80;
    reseal(&mut flags);
    cases.push((flags, 16, WireError::BadVersion));
    let mut crc = good.clone();
    *crc.last_mut().unwrap() ^= 1;
    cases.push((crc, 16, WireError::BadCrc));
    let mut payload = good.clone();
    payload[30] ^= 0x04;
    cases.push((payload, 16, WireError::BadCrc));
    // 10 points into a buffer of 8 (checked before the length and the CRC).
    cases.push((good.clone(), 8, WireError::Oversized { count: 10 }));
    cases.push((
        good[..HEADER_LEN].to_vec(),
        8,
        WireError::Oversized { count: 10 },
    ));
    for (bytes, cap, want) in &cases {
        assert_eq!(rx.accept(bytes, &mut out[..*cap]), Err(*want), "{want:?}");
        assert_eq!(decode(bytes, &mut out[..*cap]), Err(*want));
        assert!(out.iter().all(|p| *p == SENTINEL));
    }
    let n_trunc = good.len() as u32;
    assert_eq!(
        *rx.stats(),
        LinkStats {
            truncated: n_trunc,
            bad_magic: 1,
            bad_version: 2,
            bad_crc: 2,
            oversized: 2,
            ..LinkStats::default()
        }
    );

    // Sequence and time: accepted, then stale copies are refused.
    let mut big = [SENTINEL; CAP];
    assert_eq!(rx.accept(&good, &mut big).unwrap().count, 10);
    let mut small = [SENTINEL; CAP];
    for (bytes, want) in [
        (good.clone(), WireError::NonIncreasingSequence), // duplicate
        (frame(9, 2_000_000, &pts), WireError::NonIncreasingSequence),
        (frame(11, 1_000_000, &pts), WireError::NonIncreasingTime),
        (frame(12, 999_999, &pts), WireError::NonIncreasingTime),
    ] {
        assert_eq!(rx.accept(&bytes, &mut small), Err(want));
        assert!(small.iter().all(|p| *p == SENTINEL));
    }
    // The next good frame after the refusals; the sequence gap 10 → 14 counts 3 skipped.
    assert_eq!(
        rx.accept(&frame(14, 1_100_000, &pts), &mut small)
            .unwrap()
            .seq,
        14
    );
    let s = *rx.stats();
    assert_eq!((s.frames, s.skipped), (2, 3));
    assert_eq!((s.non_increasing_seq, s.non_increasing_time), (2, 2));
    assert_eq!(s.rejected(), n_trunc + 1 + 2 + 2 + 2 + 4);
    // After a front-end restart, `reset` accepts a lower sequence and time.
    rx.reset();
    assert!(rx.accept(&frame(0, 0, &pts), &mut small).is_ok());
    assert_eq!(rx.stats().frames, 3);
}

/// Every single-bit error in a frame is rejected (CRC-32 detects all of them; a flip in the
/// header may be caught earlier as magic, version, oversized or truncated).
#[test]
fn every_single_bit_flip_is_rejected() {
    let good = frame(5, 77, &some_points(6, 3));
    let mut out = [SENTINEL; 16];
    for bit in 0..good.len() * 8 {
        let mut f = good.clone();
        f[bit / 8] ^= 1 << (bit % 8);
        assert!(decode(&f, &mut out).is_err(), "bit {bit}");
        assert!(out.iter().all(|p| *p == SENTINEL));
    }
}

/// The exact bus traffic of `Receiver::read`, scripted: a header window, then one window of the
/// whole frame; nothing else.
#[test]
fn spi_reader_uses_two_windows_of_the_documented_sizes() {
    let pts = some_points(37, 4);
    let f = frame(3, 100, &pts);
    let mut spi = SpiMock::new(&[
        T::transaction_start(),
        T::read_vec(f[..HEADER_LEN].to_vec()),
        T::transaction_end(),
        T::transaction_start(),
        T::read_vec(f.clone()),
        T::transaction_end(),
    ]);
    let mut rx = Receiver::new();
    let mut buf = [0u8; frame_len(CAP)];
    let mut out = [SENTINEL; CAP];
    let info = rx.read(&mut spi, &mut buf, &mut out).unwrap();
    assert_eq!((info.seq, info.count), (3, 37));
    assert_eq!(rx.stats().frames, 1);
    spi.done();

    // A header that is garbage or over capacity ends the read after the first window.
    let mut magic = f.clone();
    magic[1] = 0;
    for (head, want) in [
        (magic[..HEADER_LEN].to_vec(), WireError::BadMagic),
        (f[..HEADER_LEN].to_vec(), WireError::Oversized { count: 37 }),
    ] {
        let mut spi = SpiMock::new(&[
            T::transaction_start(),
            T::read_vec(head),
            T::transaction_end(),
        ]);
        let mut small = [SENTINEL; 36];
        assert_eq!(
            rx.read(&mut spi, &mut buf, &mut small),
            Err(ReadError::Frame(want))
        );
        assert!(small.iter().all(|p| *p == SENTINEL));
        spi.done();
    }
    // The byte buffer bounds the capacity too: 37 points need 172 bytes.
    let mut spi = SpiMock::new(&[
        T::transaction_start(),
        T::read_vec(f[..HEADER_LEN].to_vec()),
        T::transaction_end(),
    ]);
    let mut short = [0u8; frame_len(36)];
    assert_eq!(
        rx.read(&mut spi, &mut short, &mut out),
        Err(ReadError::Frame(WireError::Oversized { count: 37 }))
    );
    spi.done();
    // A byte buffer shorter than the header: nothing is read.
    let mut spi = SpiMock::new(&[]);
    let mut tiny = [0u8; HEADER_LEN - 1];
    assert_eq!(
        rx.read(&mut spi, &mut tiny, &mut out),
        Err(ReadError::Frame(WireError::Truncated))
    );
    spi.done();
}

/// A front end as the protocol describes it: every chip-select window reads the current frame
/// from its first byte (zeros past its end); a window that reads the whole frame moves on to the
/// next one. Transactions listed in `fail` return an SPI error.
struct FrontEnd {
    frames: Vec<Vec<u8>>,
    current: usize,
    windows: usize,
    fail: Vec<usize>,
    /// Replace the current frame by the next one after this window (a frame replaced between
    /// the header window and the frame window).
    swap_after: Option<usize>,
}

impl FrontEnd {
    fn new(frames: Vec<Vec<u8>>) -> Self {
        Self {
            frames,
            current: 0,
            windows: 0,
            fail: Vec::new(),
            swap_after: None,
        }
    }
}

impl ErrorType for FrontEnd {
    type Error = ErrorKind;
}

impl SpiDevice for FrontEnd {
    fn transaction(&mut self, ops: &mut [Operation<'_, u8>]) -> Result<(), ErrorKind> {
        let window = self.windows;
        self.windows += 1;
        if self.fail.contains(&window) {
            return Err(ErrorKind::Overrun);
        }
        let f = self.frames.get(self.current).cloned().unwrap_or_default();
        let mut at = 0;
        for op in ops.iter_mut() {
            let Operation::Read(buf) = op else {
                panic!("the reader only reads")
            };
            for b in buf.iter_mut() {
                *b = f.get(at).copied().unwrap_or(0);
                at += 1;
            }
        }
        if (at >= f.len() && !f.is_empty()) || self.swap_after == Some(window) {
            self.current += 1;
        }
        Ok(())
    }
}

#[test]
fn spi_errors_and_replaced_frames_are_counted_and_harmless() {
    let pts = some_points(20, 5);
    let frames = vec![
        frame(1, 50_000, &pts[..5]),
        frame(2, 100_000, &pts[..7]),
        frame(3, 150_000, &pts[..7]),
        frame(4, 200_000, &pts),
    ];
    let mut fe = FrontEnd::new(frames);
    // Window 0 (header of frame 1) fails; so does window 4 (the whole of frame 2).
    fe.fail = vec![0, 4];
    let mut rx = Receiver::new();
    let mut buf = [0u8; frame_len(CAP)];
    let mut out = [SENTINEL; CAP];
    assert_eq!(
        rx.read(&mut fe, &mut buf, &mut out),
        Err(ReadError::Spi(ErrorKind::Overrun))
    );
    assert!(out.iter().all(|p| *p == SENTINEL));
    assert_eq!(rx.read(&mut fe, &mut buf, &mut out).unwrap().seq, 1);
    out = [SENTINEL; CAP];
    assert_eq!(
        rx.read(&mut fe, &mut buf, &mut out),
        Err(ReadError::Spi(ErrorKind::Overrun))
    );
    assert!(out.iter().all(|p| *p == SENTINEL));
    assert_eq!(rx.read(&mut fe, &mut buf, &mut out).unwrap().seq, 2);
    // Frame 3 replaced by frame 4 (more points) between the two windows: the second window reads
    // frame 4 cut at frame 3's length.
    fe.swap_after = Some(fe.windows);
    out = [SENTINEL; CAP];
    assert_eq!(
        rx.read(&mut fe, &mut buf, &mut out),
        Err(ReadError::Frame(WireError::Truncated))
    );
    assert!(out.iter().all(|p| *p == SENTINEL));
    // The front end is stuck on frame 4 now: it reads fine.
    fe.swap_after = None;
    let info = rx.read(&mut fe, &mut buf, &mut out).unwrap();
    assert_eq!((info.seq, info.count), (4, 20));
    let s = *rx.stats();
    assert_eq!(
        (s.frames, s.skipped, s.spi_errors, s.truncated, s.rejected()),
        (3, 1, 2, 1, 3)
    );

    // Through SPI as well: a frame sent twice, an older frame, a corrupted frame, garbage.
    let mut corrupted = frame(7, 400_000, &pts);
    corrupted[HEADER_LEN + 9] ^= 0x20;
    let mut fe = FrontEnd::new(vec![
        frame(5, 300_000, &pts),
        frame(5, 300_000, &pts),
        frame(6, 250_000, &pts),
        corrupted,
        vec![0xA5; 40],
        frame(8, 450_000, &pts),
    ]);
    let mut rx = Receiver::new();
    let mut want = vec![
        Ok(5),
        Err(WireError::NonIncreasingSequence),
        Err(WireError::NonIncreasingTime),
        Err(WireError::BadCrc),
        Err(WireError::BadMagic),
        Ok(8),
    ];
    want.reverse();
    while let Some(w) = want.pop() {
        out = [SENTINEL; CAP];
        let r = rx.read(&mut fe, &mut buf, &mut out);
        match w {
            Ok(seq) => assert_eq!(r.map(|i| i.seq), Ok(seq)),
            Err(e) => {
                assert_eq!(r, Err(ReadError::Frame(e)));
                assert!(out.iter().all(|p| *p == SENTINEL));
                // Garbage is only ever read as a header (the mock moves on after a window that
                // reads a whole frame): let the front end move on by hand.
                if e == WireError::BadMagic {
                    fe.current += 1;
                }
            }
        }
    }
    let s = *rx.stats();
    assert_eq!((s.frames, s.skipped, s.rejected()), (2, 2, 4));
}

/// A tracker fed through a receiver that also sees corrupted, stale, duplicated and oversized
/// frames ends in exactly the state of a tracker fed the good frames only.
#[test]
fn bad_frames_never_reach_the_tracker() {
    let cfg = ScenarioConfig {
        clutter_density: 0.02,
        ..ScenarioConfig::default()
    };
    let good: Vec<Vec<u8>> = (0..12u32)
        .map(|k| {
            let sc = Scenario::generate(&cfg, 700 + u64::from(k));
            let p: Vec<[f32; 2]> = sc
                .points
                .iter()
                .map(|&(u, x)| [u as f32, x as f32])
                .collect();
            frame(k + 1, i64::from(k + 1) * 50_000, &p[..p.len().min(CAP)])
        })
        .collect();
    let mut clean = Box::new(ReferenceTracker::new(&DEFAULT));
    let mut fed = Box::new(ReferenceTracker::new(&DEFAULT));
    let mut rx = Receiver::new();
    let mut pts = [[0.0f32; 2]; CAP];
    let mut rng = ChaCha8Rng::seed_from_u64(6);
    let mut outs_clean = Vec::new();
    let mut outs_fed = Vec::new();
    for (k, f) in good.iter().enumerate() {
        let mut direct = [[0.0f32; 2]; CAP];
        let info = decode(f, &mut direct).unwrap();
        outs_clean.push(clean.step(info.time, &direct[..info.count]).unwrap());
        // Before each good frame: a corrupted copy, a truncated copy, random bytes; after it a
        // duplicate and (from the second frame) the previous frame again.
        let mut bad = vec![f.clone(), f[..f.len() / 2].to_vec(), vec![0u8; 64]];
        let i = rng.random_range(0..f.len());
        bad[0][i] ^= 1 << rng.random_range(0..8);
        rng.fill(&mut bad[2][..]);
        for b in &bad {
            assert!(rx.accept(b, &mut pts).is_err());
        }
        let info = rx.accept(f, &mut pts).unwrap();
        outs_fed.push(fed.step(info.time, &pts[..info.count]).unwrap());
        assert!(rx.accept(f, &mut pts).is_err());
        if k > 0 {
            assert!(rx.accept(&good[k - 1], &mut pts).is_err());
        }
    }
    assert_eq!(outs_clean, outs_fed);
    assert!(outs_fed.last().unwrap().filtered.len() >= 2);
    let s = rx.stats();
    assert_eq!(s.frames, 12);
    assert_eq!(s.rejected(), 12 * 4 + 11);
}

fn check_frame(r: Result<wire::FrameInfo, WireError>, out: &[[f32; 2]]) {
    if let Ok(info) = r {
        assert!(info.count <= out.len());
        for p in &out[..info.count] {
            assert!(p[0].is_finite() && p[1].is_finite());
            assert!(p[0].abs() <= 128.0 && p[1].abs() <= 128.0);
        }
    }
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(2000))]

    /// Arbitrary bytes: no panic; a frame, if any, is within capacity and finite.
    #[test]
    fn arbitrary_bytes_never_panic(bytes in proptest::collection::vec(any::<u8>(), 0..1200),
                                   cap in 0usize..300) {
        let mut out = vec![SENTINEL; cap];
        let r = decode(&bytes, &mut out);
        check_frame(r, &out);
        if r.is_err() {
            prop_assert!(out.iter().all(|p| *p == SENTINEL));
        }
        let mut rx = Receiver::new();
        check_frame(rx.accept(&bytes, &mut out), &out);
        prop_assert_eq!(rx.stats().frames + rx.stats().rejected(), 1);
    }

    /// Arbitrary header fields and payload under a correct CRC (what random bytes almost never
    /// reach): still no panic, and a frame only within capacity.
    #[test]
    fn sealed_garbage_never_panics(magic_ok in any::<bool>(), version in 0u8..3, flags in 0u8..2,
                                   count in any::<u16>(), seq in any::<u32>(), t in any::<i64>(),
                                   payload in proptest::collection::vec(any::<u8>(), 0..1100),
                                   cap in 0usize..300) {
        let mut f = Vec::new();
        f.extend_from_slice(if magic_ok { b"STJF" } else { b"STJG" });
        f.extend_from_slice(&[version, flags]);
        f.extend_from_slice(&count.to_le_bytes());
        f.extend_from_slice(&seq.to_le_bytes());
        f.extend_from_slice(&t.to_le_bytes());
        f.extend_from_slice(&payload);
        let crc = crc32(&f);
        f.extend_from_slice(&crc.to_le_bytes());
        let mut out = vec![SENTINEL; cap];
        let r = decode(&f, &mut out);
        check_frame(r, &out);
        let consistent = magic_ok && version == 1 && flags == 0
            && usize::from(count) <= cap && payload.len() == 4 * usize::from(count);
        if consistent {
            prop_assert_eq!(r.map(|i| (i.seq, i.count)), Ok((seq, usize::from(count))));
        }
    }

    /// The SPI reader on a front end that sends arbitrary bytes.
    #[test]
    fn spi_garbage_never_panics(frames in proptest::collection::vec(
                                    proptest::collection::vec(any::<u8>(), 0..1100), 1..4)) {
        let mut fe = FrontEnd::new(frames.clone());
        let mut rx = Receiver::new();
        let mut buf = [0u8; frame_len(CAP)];
        let mut out = [SENTINEL; CAP];
        for _ in 0..frames.len() {
            let r = rx.read(&mut fe, &mut buf, &mut out).map_err(|e| match e {
                ReadError::Frame(w) => w,
                ReadError::Spi(_) => unreachable!(),
            });
            check_frame(r, &out);
        }
    }

    /// CRC-32 agrees with crc32fast on any input.
    #[test]
    fn crc_matches_crc32fast(bytes in proptest::collection::vec(any::<u8>(), 0..600)) {
        prop_assert_eq!(crc32(&bytes), crc32fast::hash(&bytes));
    }
}
