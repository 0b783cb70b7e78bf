//! Any bytes, fed whole and in two pieces split at the first byte's value: the decoder must never panic, errors
//! must point inside the data, and progressive decoding must agree with whole-buffer decoding. v2 too: the input is
//! decoded as it is (v1, v2 or garbage), and again as the STAT payload of a valid v2 file (CRC made right), so the
//! fuzzer reaches the sections (filters, lengths, zstd frames, values, Morton deltas) without forging a CRC.
#![no_main]
use libfuzzer_sys::fuzz_target;
use splat_core::scene::{read_wsplat, StreamingScene};

const V2: &[u8] = include_bytes!("../../../tests/vectors/wsplat/valid_v2_iso.wsplat");

fn check(data: &[u8]) {
    let whole = read_wsplat(data);
    if let Err(e) = &whole {
        assert!(e.offset <= data.len() as u64);
    }
    let split = data.first().map_or(0, |&b| b as usize).min(data.len());
    let mut s = StreamingScene::default();
    let streamed = s.push(&data[..split]).and_then(|_| s.push(&data[split..])).and_then(|_| s.finish());
    match (&whole, &streamed) {
        (Ok(w), Ok(_)) => assert_eq!(w.statics, s.scene.statics),
        (Err(a), Err(b)) => assert_eq!((a.kind, a.offset), (b.kind, b.offset)),
        _ => panic!("whole and streamed decoding disagree"),
    }
}

/// `payload` as the first STAT chunk of the v2 vector (length and CRC made consistent).
fn as_v2_stat(payload: &[u8]) -> Vec<u8> {
    let head_len = u32::from_le_bytes(V2[16..20].try_into().unwrap()) as usize;
    let stat_at = 12 + 12 + head_len;
    let old = u32::from_le_bytes(V2[stat_at + 4..stat_at + 8].try_into().unwrap()) as usize;
    let mut out = V2[..stat_at].to_vec();
    out.extend_from_slice(b"STAT");
    out.extend_from_slice(&(payload.len() as u32).to_le_bytes());
    out.extend_from_slice(payload);
    let crc = crc32fast::hash(&out[stat_at..]);
    out.extend_from_slice(&crc.to_le_bytes());
    out.extend_from_slice(&V2[stat_at + 12 + old..]);
    out
}

fuzz_target!(|data: &[u8]| {
    check(data);
    check(&as_v2_stat(data));
});
