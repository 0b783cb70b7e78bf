//! Any bytes, fed whole and in two pieces split at the first byte's value: the decoder must never panic, errors
//! must point inside the data, and progressive decoding must agree with whole-buffer decoding. v2 too: the input is
//! decoded as it is (v1, v2 or garbage), and again as the STAT payload of a valid v2 file (CRC made right), so the
//! fuzzer reaches the sections (filters, lengths, zstd frames, values, Morton deltas) without forging a CRC. Range-coded
//! dynamic records (HEAD dynamic_codec "range") too: the input as the first DYNA payload of a valid range-coded file
//! (boxes, word count, stream), and as the words of that chunk's stream (its frame, count, boxes and word count kept
//! consistent), so the fuzzer reaches the range decoder, its models and the stream's end checks; the models carry on
//! into the file's later DYNA chunks. v3's object records too: the input as the first OBJC payload and as the POSE
//! payload of a valid v3 file, so the fuzzer reaches the object headers, their sections, the present bits and poses.
//! v4's colour update: the input as the first SCOL payload of a valid v4 file (its range, bound and sections).
#![no_main]
use libfuzzer_sys::fuzz_target;
use splat_format::scene::{read_wsplat, StreamingScene};

const V2: &[u8] = include_bytes!("../../../tests/vectors/wsplat/valid_v2_iso.wsplat");
const RANGE: &[u8] = include_bytes!("../../../tests/vectors/wsplat/valid_v2_range_aniso.wsplat");
const V3: &[u8] = include_bytes!("../../../tests/vectors/wsplat/valid_v3_objects.wsplat");
const V4: &[u8] = include_bytes!("../../../tests/vectors/wsplat/valid_v4_recoloured.wsplat");

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

/// `file` with the payload of its first chunk tagged `tag` replaced (length and CRC made consistent).
fn replace_first(file: &[u8], tag: &[u8; 4], payload: &[u8]) -> Vec<u8> {
    let mut at = 12;
    loop {
        let len = u32::from_le_bytes(file[at + 4..at + 8].try_into().unwrap()) as usize;
        if &file[at..at + 4] == tag {
            let mut out = file[..at].to_vec();
            out.extend_from_slice(tag);
            out.extend_from_slice(&(payload.len() as u32).to_le_bytes());
            out.extend_from_slice(payload);
            let crc = crc32fast::hash(&out[at..]);
            out.extend_from_slice(&crc.to_le_bytes());
            out.extend_from_slice(&file[at + 12 + len..]);
            return out;
        }
        at += 12 + len;
    }
}

/// `words` (the input cut to whole words) as the stream of the range-coded file's first DYNA chunk.
fn as_range_stream(data: &[u8]) -> Vec<u8> {
    let mut at = 12;
    while &RANGE[at..at + 4] != b"DYNA" {
        at += 12 + u32::from_le_bytes(RANGE[at + 4..at + 8].try_into().unwrap()) as usize;
    }
    let p = &RANGE[at + 8..];
    let count = u32::from_le_bytes(p[4..8].try_into().unwrap()) as usize;
    let words_at = 8 + 32 * count.div_ceil(256);
    let mut payload = p[..words_at].to_vec();
    let n = data.len() / 4;
    payload.extend_from_slice(&(n as u32).to_le_bytes());
    payload.extend_from_slice(&data[..4 * n]);
    replace_first(RANGE, b"DYNA", &payload)
}

fuzz_target!(|data: &[u8]| {
    check(data);
    check(&as_v2_stat(data));
    check(&replace_first(RANGE, b"DYNA", data));
    check(&as_range_stream(data));
    check(&replace_first(V3, b"OBJC", data));
    check(&replace_first(V3, b"POSE", data));
    check(&replace_first(V4, b"SCOL", data));
});
