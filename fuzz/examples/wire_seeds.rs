//! Writes the hand-made part of the `wire_decode` seed corpus (`fuzz/seeds/wire_decode/`, files
//! named `frame-*` and `stream-*`) from the firmware's scenario files
//! (`bench/firmware/scenarios/*.stjf`, frames in the wire format back to back): single frames,
//! short streams, and streams with a corrupted, replayed or stale frame in the middle.
//! `cargo run --release --manifest-path fuzz/Cargo.toml --example wire_seeds`
use std::path::Path;

use stjpdacf::tracker::Instant;
use stjpdacf::wire;

/// The frames of a scenario file, each as its bytes.
fn frames(path: &Path) -> Vec<Vec<u8>> {
    let data = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    let mut out = Vec::new();
    let mut pts = vec![[0.0f32; 2]; 256];
    let mut p = 0;
    while p < data.len() {
        let info = wire::decode(&data[p..], &mut pts).expect("a scenario frame");
        let len = wire::frame_len(info.count);
        out.push(data[p..p + len].to_vec());
        p += len;
    }
    out
}

fn main() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let dir = root.join("fuzz/seeds/wire_decode");
    std::fs::create_dir_all(&dir).expect("seed dir");
    let sc = |n: &str| frames(&root.join(format!("bench/firmware/scenarios/{n}.stjf")));
    let (typical, worst, patterns) = (sc("typical"), sc("worst"), sc("worst_patterns"));
    let mut seeds: Vec<(String, Vec<u8>)> = Vec::new();
    for k in (0..typical.len()).step_by(6) {
        seeds.push((format!("frame-typical-{:02}", k + 1), typical[k].clone()));
    }
    for (name, s) in [("worst", &worst), ("worst_patterns", &patterns)] {
        for k in [0, s.len() - 1] {
            seeds.push((format!("frame-{name}-{:02}", k + 1), s[k].clone()));
        }
    }
    let mut empty = vec![0u8; wire::frame_len(0)];
    wire::encode(1, Instant::from_micros(0), &[], &mut empty).expect("empty frame");
    seeds.push(("frame-empty".into(), empty));
    let cat = |fs: &[Vec<u8>]| fs.concat();
    seeds.push(("stream-typical-01-04".into(), cat(&typical[0..4])));
    seeds.push(("stream-typical-31-34".into(), cat(&typical[30..34])));
    seeds.push(("stream-worst-01-03".into(), cat(&worst[0..3])));
    seeds.push(("stream-worst_patterns-10-12".into(), cat(&patterns[9..12])));
    // Corrupted mid-stream: a flipped bit in frame 6, frame 6 again (replayed sequence number),
    // frame 5's timestamp on frame 8 (stale time, CRC resealed), frame 7 cut short.
    let mut flipped = typical[5].clone();
    flipped[100] ^= 0x08;
    seeds.push((
        "stream-typical-05-07-bitflip".into(),
        cat(&[typical[4].clone(), flipped, typical[6].clone()]),
    ));
    seeds.push((
        "stream-typical-05-07-replay".into(),
        cat(&[
            typical[4].clone(),
            typical[5].clone(),
            typical[5].clone(),
            typical[6].clone(),
        ]),
    ));
    let mut stale = typical[7].clone();
    stale[12..20].copy_from_slice(&typical[4][12..20]);
    let body = stale.len() - wire::CRC_LEN;
    let crc = wire::crc32(&stale[..body]);
    stale[body..].copy_from_slice(&crc.to_le_bytes());
    seeds.push((
        "stream-typical-05-09-stale-time".into(),
        cat(&[
            typical[4].clone(),
            typical[5].clone(),
            stale,
            typical[8].clone(),
        ]),
    ));
    let cut = typical[6][..typical[6].len() / 2].to_vec();
    seeds.push((
        "stream-typical-06-08-truncated".into(),
        cat(&[typical[5].clone(), cut, typical[7].clone()]),
    ));
    let mut total = 0;
    for (name, bytes) in &seeds {
        std::fs::write(dir.join(name), bytes).expect("write seed");
        total += bytes.len();
    }
    println!("{} seeds, {total} bytes, in {}", seeds.len(), dir.display());
}
