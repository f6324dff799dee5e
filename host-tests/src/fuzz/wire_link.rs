//! [`wire_decode`]: the SPI feature-frame decoder (`stjpdacf::wire`) and its receiver.

use arbitrary::Unstructured;
use stjpdacf::tables::DEFAULT;
use stjpdacf::tracker::{Instant, ReferenceTracker};
use stjpdacf::wire::{self, FrameInfo, LinkStats, Receiver, WireError};

use super::{byte, check_output, check_tracker, decode_frame, Mix, PsdCheck, MEAS};

/// Frames per [`wire_decode`] input the tracker steps on at most.
pub const MAX_FRAMES: usize = 16;
/// Buffers per [`wire_decode`] input offered to the receiver at most (per part).
pub const MAX_OFFERS: usize = 64;
/// Decoded frames per [`wire_decode`] input whose mutations (bit flips, truncations,
/// extensions) are checked.
const MUTATED_FRAMES: usize = 4;
/// Bit flips at pseudo-random positions per mutated frame (besides every bit of the header).
const FLIPS: usize = 32;
/// What a point buffer holds before a call: any write shows (no decodable point is beyond ±128 m).
const SENTINEL: [f32; 2] = [-999.0, 999.0];

/// The outcome the documented layout (`stjpdacf::wire` module docs) gives for `bytes` with
/// capacity `cap`: the checks in their documented order (length of the header, magic, version
/// and flags, count against the capacity, length of the frame, CRC-32/ISO-HDLC computed by
/// `crc32fast`), written independently of the decoder.
fn wire_spec(bytes: &[u8], cap: usize) -> Result<(u32, i64, usize), WireError> {
    if bytes.len() < wire::HEADER_LEN {
        return Err(WireError::Truncated);
    }
    if bytes[..4] != wire::MAGIC {
        return Err(WireError::BadMagic);
    }
    if bytes[4] != wire::VERSION || bytes[5] != 0 {
        return Err(WireError::BadVersion);
    }
    let n = u16::from_le_bytes([bytes[6], bytes[7]]);
    if usize::from(n) > cap {
        return Err(WireError::Oversized { count: n });
    }
    let len = 24 + 4 * usize::from(n);
    if bytes.len() < len {
        return Err(WireError::Truncated);
    }
    let crc = u32::from_le_bytes([
        bytes[len - 4],
        bytes[len - 3],
        bytes[len - 2],
        bytes[len - 1],
    ]);
    if crc32fast::hash(&bytes[..len - 4]) != crc {
        return Err(WireError::BadCrc);
    }
    let seq = u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]);
    let mut t = [0u8; 8];
    t.copy_from_slice(&bytes[12..20]);
    Ok((seq, i64::from_le_bytes(t), usize::from(n)))
}

/// A decoded frame: its header and its points.
pub type Decoded = (FrameInfo, Vec<[f32; 2]>);

/// `wire::decode` of `bytes` into a buffer of `cap` sentinel points, checked: the result is the
/// layout's ([`wire_spec`]: same error, or same header); on error no point is written; on
/// success exactly `count ≤ cap` points are written, each finite, within ±128 m and a multiple of
/// `LSB_M`, and the frame re-encodes to the same bytes (round trip).
fn checked_decode(bytes: &[u8], cap: usize) -> Result<Result<Decoded, WireError>, String> {
    let mut buf = vec![SENTINEL; cap];
    let r = wire::decode(bytes, &mut buf);
    let spec = wire_spec(bytes, cap);
    match r {
        Err(e) => {
            if spec != Err(e) {
                return Err(format!("decode gives {e:?}, the layout {spec:?}"));
            }
            if buf.iter().any(|p| *p != SENTINEL) {
                return Err(format!("decode failed with {e:?} and wrote points"));
            }
            Ok(Err(e))
        }
        Ok(info) => {
            let got = (info.seq, info.time.as_micros(), info.count);
            if spec != Ok(got) {
                return Err(format!("decode gives {got:?}, the layout {spec:?}"));
            }
            let n = info.count;
            if buf[n..].iter().any(|p| *p != SENTINEL) {
                return Err(format!("decode of {n} points wrote beyond them"));
            }
            for (i, p) in buf[..n].iter().enumerate() {
                let ok =
                    |v: f32| v.is_finite() && v.abs() <= 128.0 && (v / wire::LSB_M).fract() == 0.0;
                if !(ok(p[0]) && ok(p[1])) {
                    return Err(format!("decoded point {i} is {p:?}"));
                }
            }
            let len = wire::frame_len(n);
            let mut again = vec![0u8; len];
            match wire::encode(info.seq, info.time, &buf[..n], &mut again) {
                Ok(l) if l == len && again[..] == bytes[..len] => {}
                r => {
                    let at = again.iter().zip(bytes).position(|(a, b)| a != b);
                    return Err(format!(
                        "round trip: re-encoding gives {r:?}, first differing byte {at:?}"
                    ));
                }
            }
            buf.truncate(n);
            Ok(Ok((info, buf)))
        }
    }
}

/// Bit flips, truncations and extensions of a decoded frame `frame` (exactly its bytes):
/// every truncation is `Truncated`; an extension (bytes after the frame) decodes to the same
/// frame; a single bit flip (every bit of the header, [`FLIPS`] pseudo-random bits anywhere) is
/// an error or the same frame.
fn check_mutations(frame: &[u8], want: &Decoded) -> Result<(), String> {
    let same = |r: &Result<Decoded, WireError>| matches!(r, Ok(d) if d == want);
    for cut in 0..frame.len() {
        let r = checked_decode(&frame[..cut], MEAS)?;
        if r.as_ref().err() != Some(&WireError::Truncated) {
            return Err(format!(
                "frame of {} bytes cut at {cut}: {:?}",
                frame.len(),
                r.err()
            ));
        }
    }
    let mut longer = frame.to_vec();
    for tail in [&[0u8][..], &[0xFF, 0x5A, 0x00], frame] {
        longer.truncate(frame.len());
        longer.extend_from_slice(tail);
        let r = checked_decode(&longer, MEAS)?;
        if !same(&r) {
            return Err(format!(
                "frame extended by {} bytes: {:?}",
                tail.len(),
                r.err()
            ));
        }
    }
    let mut mix = Mix(u64::from(wire::crc32(frame)));
    let header_bits = 8 * wire::HEADER_LEN.min(frame.len());
    let random = (0..FLIPS).map(|_| (mix.next() % (8 * frame.len() as u64)) as usize);
    let mut flipped = frame.to_vec();
    for bit in (0..header_bits).chain(random) {
        flipped[bit / 8] ^= 1 << (bit % 8);
        let r = checked_decode(&flipped, MEAS)?;
        flipped[bit / 8] ^= 1 << (bit % 8);
        if r.is_ok() && !same(&r) {
            let d = r.as_ref().map(|d| d.0);
            return Err(format!("bit {bit} flipped: decoded as another frame {d:?}"));
        }
    }
    Ok(())
}

/// A receiver, the independent model of what it must do, and the tracker it feeds.
struct Link {
    rx: Receiver,
    /// The model: sequence number and time of the last frame that must have been accepted.
    last: Option<(u32, Instant)>,
    /// The model's counters.
    stats: LinkStats,
    tracker: Box<ReferenceTracker>,
    /// Frames the tracker stepped on.
    stepped: usize,
    /// Frames whose mutations were checked.
    mutated: usize,
    /// Buffers offered.
    offers: usize,
}

/// What [`Link::offer`] saw: the stateless decode and the receiver's verdict.
struct Offered {
    decoded: Result<Decoded, WireError>,
    accepted: Result<FrameInfo, WireError>,
}

impl Link {
    fn new() -> Self {
        Self {
            rx: Receiver::new(),
            last: None,
            stats: LinkStats::default(),
            tracker: Box::new(ReferenceTracker::new(&DEFAULT)),
            stepped: 0,
            mutated: 0,
            offers: 0,
        }
    }

    /// One buffer: the checked stateless decode (and, for the first few frames, its
    /// mutations), then `Receiver::accept` against the model (same verdict, same points, point
    /// buffer untouched on refusal, same counters), then, when accepted, `Tracker::step` on the
    /// frame (up to [`MAX_FRAMES`]): it must accept the frame (its time increases) and keep
    /// every invariant (`check_output`, `check_tracker`). A refused buffer never reaches the
    /// tracker; the next acceptable frame is accepted and stepped on.
    fn offer(&mut self, bytes: &[u8]) -> Result<Offered, String> {
        let k = self.offers;
        self.offers += 1;
        let decoded = checked_decode(bytes, MEAS).map_err(|e| format!("buffer {k}: {e}"))?;
        if let Ok(d) = &decoded {
            if self.mutated < MUTATED_FRAMES {
                self.mutated += 1;
                check_mutations(&bytes[..wire::frame_len(d.0.count)], d)
                    .map_err(|e| format!("buffer {k}: {e}"))?;
            }
        }
        let model = match &decoded {
            Err(e) => Err(*e),
            Ok((info, _)) => match self.last {
                Some((seq, _)) if info.seq <= seq => Err(WireError::NonIncreasingSequence),
                Some((_, time)) if info.time <= time => Err(WireError::NonIncreasingTime),
                _ => Ok(*info),
            },
        };
        let mut pts = vec![SENTINEL; MEAS];
        let accepted = self.rx.accept(bytes, &mut pts);
        if accepted != model {
            return Err(format!(
                "buffer {k}: receiver gives {accepted:?}, expected {model:?}"
            ));
        }
        match (&accepted, &decoded) {
            (Ok(info), Ok((_, want))) => {
                let n = info.count;
                if pts[..n] != want[..] || pts[n..].iter().any(|p| *p != SENTINEL) {
                    return Err(format!(
                        "buffer {k}: receiver wrote other points than decode"
                    ));
                }
                if let Some((seq, _)) = self.last {
                    self.stats.skipped = self.stats.skipped.saturating_add(info.seq - seq - 1);
                }
                self.stats.frames += 1;
                self.last = Some((info.seq, info.time));
            }
            (Err(e), _) => {
                if pts.iter().any(|p| *p != SENTINEL) {
                    return Err(format!("buffer {k}: refused ({e:?}) but points written"));
                }
                let c = match e {
                    WireError::Truncated => &mut self.stats.truncated,
                    WireError::BadMagic => &mut self.stats.bad_magic,
                    WireError::BadVersion => &mut self.stats.bad_version,
                    WireError::Oversized { .. } => &mut self.stats.oversized,
                    WireError::BadCrc => &mut self.stats.bad_crc,
                    WireError::NonIncreasingSequence => &mut self.stats.non_increasing_seq,
                    WireError::NonIncreasingTime => &mut self.stats.non_increasing_time,
                    _ => return Err(format!("buffer {k}: unknown error {e:?}")),
                };
                *c += 1;
            }
            (Ok(_), Err(_)) => {
                return Err(format!("buffer {k}: model accepted an undecodable frame"))
            }
        }
        if *self.rx.stats() != self.stats {
            return Err(format!(
                "buffer {k}: counters {:?}, expected {:?}",
                self.rx.stats(),
                self.stats
            ));
        }
        if let Ok(info) = &accepted {
            if self.stepped < MAX_FRAMES {
                self.stepped += 1;
                let frames = self.tracker.frames();
                let n = info.count;
                let out = self.tracker.step(info.time, &pts[..n]).map_err(|e| {
                    format!("buffer {k}: accepted frame refused by the tracker: {e}")
                })?;
                check_output(&out, n).map_err(|e| format!("buffer {k}: {e}"))?;
                check_tracker(&self.tracker, PsdCheck::Cholesky)
                    .map_err(|e| format!("buffer {k}: {e}"))?;
                if self.tracker.frames() != frames + 1 {
                    return Err(format!("buffer {k}: tracker did not count the frame"));
                }
            }
        }
        Ok(Offered { decoded, accepted })
    }
}

/// What the harness did to a frame of a structured [`wire_decode`] input before sending it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Fault {
    /// Sent as encoded.
    None,
    /// 1–3 bits flipped.
    Flip,
    /// Cut short.
    Truncate,
    /// Bytes appended.
    Extend,
    /// Arbitrary bytes instead of the frame.
    Garbage,
    /// The last good frame sent again (its sequence number replayed).
    Replay,
    /// A new sequence number with a timestamp at or before the last good frame's.
    StaleTime,
    /// A count above the budget `MEAS`, under a correct CRC.
    Oversized,
    /// Magic, version or flags changed, under a correct CRC.
    BadHeader,
}

/// One buffer of a structured [`wire_decode`] input.
#[derive(Debug, Clone)]
pub struct Sent {
    /// The bytes sent.
    pub bytes: Vec<u8>,
    /// What was done to the frame.
    pub fault: Fault,
    /// The frame before the fault (for `Flip`, `Truncate`, `Extend`).
    pub original: Option<Vec<u8>>,
}

/// Rewrites the CRC of a frame (all of `f`) after an edit.
fn reseal(f: &mut [u8]) {
    let body = f.len() - wire::CRC_LEN;
    let crc = wire::crc32(&f[..body]);
    f[body..].copy_from_slice(&crc.to_le_bytes());
}

/// The buffers a structured [`wire_decode`] input describes: up to [`MAX_FRAMES`] frames
/// encoded with `wire::encode` (lane-like and raw points as in `tracker_step`, those the format
/// can carry, cut to `MEAS`; sequence numbers increasing with gaps, wrapping at `u32::MAX`;
/// times increasing), each sent as is or with a [`Fault`] (the faulty copy alone, or followed by
/// the good frame).
pub fn decode_wire_input(data: &[u8]) -> Vec<Sent> {
    let mut u = Unstructured::new(data);
    let mut seq = u.arbitrary::<u32>().unwrap_or(0);
    let mut t = i64::from(u.arbitrary::<i32>().unwrap_or(0));
    let mut last_good: Option<(Vec<u8>, i64)> = None;
    let mut sent = Vec::new();
    for _ in 0..MAX_FRAMES {
        if u.is_empty() {
            break;
        }
        seq = seq.wrapping_add(1 + u32::from(byte(&mut u) % 8).saturating_sub(5));
        t = t.saturating_add(1 + 1000 * i64::from(u.arbitrary::<u8>().unwrap_or(50)));
        let mut pts = decode_frame(&mut u);
        pts.retain(|p| p.iter().all(|v| v.is_finite() && v.abs() < 127.0));
        let fault = match byte(&mut u) % 16 {
            0..=6 => Fault::None,
            7 => Fault::Flip,
            8 => Fault::Truncate,
            9 => Fault::Extend,
            10 => Fault::Garbage,
            11 => Fault::Replay,
            12 => Fault::StaleTime,
            13 => Fault::Oversized,
            _ => Fault::BadHeader,
        };
        let all = pts.clone();
        pts.truncate(MEAS);
        let mut good = vec![0u8; wire::frame_len(pts.len())];
        if wire::encode(seq, Instant::from_micros(t), &pts, &mut good).is_err() {
            continue;
        }
        let len = good.len();
        let (bytes, original) = match fault {
            Fault::None => (good.clone(), None),
            Fault::Flip => {
                let mut f = good.clone();
                for _ in 0..1 + byte(&mut u) % 3 {
                    let bit = usize::from(u.arbitrary::<u16>().unwrap_or(0)) % (8 * len);
                    f[bit / 8] ^= 1 << (bit % 8);
                }
                (f, Some(good.clone()))
            }
            Fault::Truncate => {
                let cut = usize::from(u.arbitrary::<u16>().unwrap_or(0)) % len;
                (good[..cut].to_vec(), Some(good.clone()))
            }
            Fault::Extend => {
                let mut f = good.clone();
                let n = usize::from(byte(&mut u));
                f.extend((0..n).map(|_| byte(&mut u)));
                (f, Some(good.clone()))
            }
            Fault::Garbage => {
                let n = usize::from(u.arbitrary::<u16>().unwrap_or(0)) % 1200;
                ((0..n).map(|_| byte(&mut u)).collect(), None)
            }
            Fault::Replay => match &last_good {
                Some((f, _)) => (f.clone(), None),
                None => (good.clone(), None),
            },
            Fault::StaleTime => {
                let back = i64::from(u.arbitrary::<u16>().unwrap_or(0));
                let at = last_good
                    .as_ref()
                    .map_or(t, |(_, lt)| lt.saturating_sub(back));
                let mut f = vec![0u8; len];
                let _ = wire::encode(seq, Instant::from_micros(at), &pts, &mut f);
                (f, None)
            }
            Fault::Oversized => {
                let mut f = good.clone();
                if all.len() > MEAS {
                    // The frame with every point (encodable: `all` holds at most ~870).
                    f = vec![0u8; wire::frame_len(all.len())];
                    let _ = wire::encode(seq, Instant::from_micros(t), &all, &mut f);
                } else {
                    let n = (MEAS + 1 + usize::from(u.arbitrary::<u16>().unwrap_or(0)))
                        .min(usize::from(u16::MAX)) as u16;
                    f[6..8].copy_from_slice(&n.to_le_bytes());
                    reseal(&mut f);
                }
                (f, None)
            }
            Fault::BadHeader => {
                let mut f = good.clone();
                let at = usize::from(byte(&mut u)) % 6;
                f[at] ^= byte(&mut u).max(1);
                reseal(&mut f);
                (f, None)
            }
        };
        let resend = fault != Fault::None && byte(&mut u) & 1 == 0;
        sent.push(Sent {
            bytes,
            fault,
            original,
        });
        if resend {
            sent.push(Sent {
                bytes: good.clone(),
                fault: Fault::None,
                original: None,
            });
        }
        if fault == Fault::None || resend {
            last_good = Some((good, t));
        }
    }
    sent
}

/// The frames of a raw [`wire_decode`] input taken as a byte stream: a frame at the start, then
/// frames back to back; after bytes that do not decode, the stream resumes at the next `MAGIC`
/// (at most [`MAX_OFFERS`] buffers; each is offered from its start to the end of the input).
fn raw_stream(data: &[u8], link: &mut Link) -> Result<(), String> {
    let mut p = 0;
    while p < data.len() && link.offers < MAX_OFFERS {
        let o = link.offer(&data[p..])?;
        p += match o.decoded {
            Ok((info, _)) => wire::frame_len(info.count),
            Err(_) => {
                1 + data[p + 1..]
                    .windows(4)
                    .position(|w| w == wire::MAGIC)
                    .unwrap_or(data.len() - p - 1)
            }
        };
    }
    Ok(())
}

/// The SPI frame decoder and receiver on arbitrary bytes, with the invariants of `fuzz/README.md`:
/// no panic; every buffer decodes as the documented layout says or gives its typed error, never a
/// partial frame (`checked_decode`); a decoded frame re-encodes to the same bytes and holds at
/// most `MEAS` points; its bit flips, truncations and extensions give an error or the same
/// frame (`check_mutations`); the receiver accepts exactly the frames that decode with an
/// increasing sequence number and time, counts every outcome, and feeds only those to
/// `Tracker::step`, which keeps every invariant and resumes on the next good frame
/// (`Link::offer`).
///
/// Two parts, each with its own receiver and tracker: the input as a raw byte stream (frames
/// back to back, corrupted frames mid-stream: what the seed corpus of real frames turns into
/// under mutation), and, unless the input starts with `MAGIC`, the input as a description of
/// frames and the faults applied to them ([`decode_wire_input`]: bit flips, truncation,
/// extension, garbage, a replayed sequence number, a stale timestamp, an oversized count, a bad
/// header), with the effect each fault must have.
///
/// # Errors
/// A description of the first invariant violated.
pub fn wire_decode(data: &[u8]) -> Result<(), String> {
    let mut raw = Link::new();
    raw_stream(data, &mut raw).map_err(|e| format!("raw stream: {e}"))?;
    if data.starts_with(&wire::MAGIC) {
        return Ok(());
    }
    let mut link = Link::new();
    let mut accepted: Vec<Vec<u8>> = Vec::new();
    for (k, s) in decode_wire_input(data).into_iter().enumerate() {
        let last = link.last;
        let o = link
            .offer(&s.bytes)
            .map_err(|e| format!("structured: {e}"))?;
        let orig = s
            .original
            .as_deref()
            .map(|f| checked_decode(f, MEAS).map_err(|e| format!("structured {k}: {e}")))
            .transpose()?;
        let ok = match s.fault {
            Fault::None => o.decoded.is_ok(),
            Fault::Flip => o.decoded.is_err() || orig.as_ref() == Some(&o.decoded),
            Fault::Truncate => o.decoded.as_ref().err() == Some(&WireError::Truncated),
            Fault::Extend => orig.as_ref() == Some(&o.decoded),
            Fault::Garbage => true,
            Fault::Replay => {
                !accepted.contains(&s.bytes) || o.accepted == Err(WireError::NonIncreasingSequence)
            }
            Fault::StaleTime => {
                let stale = match (&o.decoded, last) {
                    (Ok((info, _)), Some((_, lt))) => info.time <= lt,
                    _ => false,
                };
                !stale
                    || matches!(
                        o.accepted,
                        Err(WireError::NonIncreasingTime | WireError::NonIncreasingSequence)
                    )
            }
            Fault::Oversized => matches!(
                o.decoded,
                Err(WireError::Oversized { count }) if usize::from(count) > MEAS
            ),
            Fault::BadHeader => {
                matches!(o.decoded, Err(WireError::BadMagic | WireError::BadVersion))
            }
        };
        if !ok {
            return Err(format!(
                "structured {k}: fault {:?} gave decode {:?}, receiver {:?}",
                s.fault,
                o.decoded.as_ref().map(|d| d.0),
                o.accepted
            ));
        }
        if let Ok(info) = o.accepted {
            accepted.push(s.bytes[..wire::frame_len(info.count)].to_vec());
        }
    }
    Ok(())
}

/// The frames a [`wire_decode`] input makes its two receivers accept, as `(buffer index,
/// points)`: the raw stream's, then the structured part's (empty when the input starts with
/// `MAGIC`). Public so that a crash input can be classified (`examples/classify.rs`).
pub fn wire_accepted_frames(data: &[u8]) -> [Vec<(usize, Vec<[f32; 2]>)>; 2] {
    let mut pts = vec![[0.0f32; 2]; MEAS];
    let mut raw = Vec::new();
    let mut rx = Receiver::new();
    let mut p = 0;
    let mut k = 0;
    while p < data.len() && k < MAX_OFFERS {
        if let Ok(i) = rx.accept(&data[p..], &mut pts) {
            raw.push((k, pts[..i.count].to_vec()));
        }
        p += match wire::decode(&data[p..], &mut pts) {
            Ok(i) => wire::frame_len(i.count),
            Err(_) => {
                1 + data[p + 1..]
                    .windows(4)
                    .position(|w| w == wire::MAGIC)
                    .unwrap_or(data.len() - p - 1)
            }
        };
        k += 1;
    }
    let mut structured = Vec::new();
    if !data.starts_with(&wire::MAGIC) {
        let mut rx = Receiver::new();
        for (k, s) in decode_wire_input(data).iter().enumerate() {
            if let Ok(i) = rx.accept(&s.bytes, &mut pts) {
                structured.push((k, pts[..i.count].to_vec()));
            }
        }
    }
    [raw, structured]
}
