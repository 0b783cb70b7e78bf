//! Any bytes, fed whole and in two pieces split at the first byte's value: the decoder must never panic, errors
//! must point inside the data, and progressive decoding must agree with whole-buffer decoding.
#![no_main]
use libfuzzer_sys::fuzz_target;
use splat_core::scene::{read_wsplat, StreamingScene};

fuzz_target!(|data: &[u8]| {
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
});
