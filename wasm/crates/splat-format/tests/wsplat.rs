//! .wsplat v1 decoder: round trip through the spec encoder, progressive parsing at any split, every shared
//! vector in tests/vectors/wsplat/, the malformed cases the spec names, and a bounded seeded mutation test
//! (no panic, errors carry an offset inside the data, streaming never disagrees with whole-buffer decoding).

use splat_format::gaussians::Gaussian;
use splat_format::scene::{bake_objects, read_wsplat, StreamingScene};
use splat_format::wsplat::dyna_range;
use splat_format::wsplat::{encode::encode, Decoder, ErrorKind, Event};
use std::path::Path;

struct Rng(u64);
impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 << 13;
        self.0 ^= self.0 >> 7;
        self.0 ^= self.0 << 17;
        self.0
    }
    fn f(&mut self) -> f32 {
        (self.next() % 1_000_000) as f32 / 1_000_000.0
    }
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n.max(1) as u64) as usize
    }
}

fn gaussians(rng: &mut Rng, n: usize) -> Vec<Gaussian> {
    (0..n)
        .map(|_| Gaussian {
            mean: [rng.f() * 40.0 - 20.0, rng.f() * 40.0 - 20.0, rng.f() * 5.0],
            quat: [rng.f() - 0.5, rng.f() - 0.5, rng.f() - 0.5, rng.f() - 0.5],
            scale: [0.01 + rng.f(), 0.01 + rng.f(), 0.01 + rng.f()],
            opacity: 0.05 + 0.9 * rng.f(),
            color: [rng.f(), rng.f(), rng.f()],
        })
        .collect()
}

fn sample() -> (Vec<u8>, Vec<Gaussian>, Vec<Vec<Gaussian>>) {
    let mut rng = Rng(42);
    let statics = gaussians(&mut rng, 700);
    let dynamic = vec![gaussians(&mut rng, 30), vec![], gaussians(&mut rng, 12)];
    (encode(&statics, &dynamic, 10.0, 256, 300), statics, dynamic)
}

#[test]
fn round_trip_within_quantization() {
    let (bytes, statics, dynamic) = sample();
    let mut dec = Decoder::new();
    let events = dec.push(&bytes).unwrap();
    dec.finish().unwrap();
    let mut got = Vec::new();
    let mut dyn_got = vec![Vec::new(); 3];
    for e in events {
        match e {
            Event::Static(g) => got.extend(g),
            Event::Dynamic { frame, gaussians } => dyn_got[frame].extend(gaussians),
            _ => {}
        }
    }
    assert_eq!(got.len(), statics.len());
    assert_eq!(dyn_got.iter().map(Vec::len).collect::<Vec<_>>(), dynamic.iter().map(Vec::len).collect::<Vec<_>>());
    for (a, b) in got.iter().zip(&statics) {
        let b = b.sanitized().unwrap();
        for k in 0..3 {
            assert!((a.mean[k] - b.mean[k]).abs() < 40.0 / 32767.0 + 1e-4, "mean {:?} vs {:?}", a.mean, b.mean);
            assert!((a.color[k] - b.color[k]).abs() <= 0.5 / 255.0 + 1e-6);
        }
        // Quaternions up to sign.
        let dot: f32 = (0..4).map(|k| a.quat[k] * b.quat[k]).sum();
        assert!(dot.abs() > 0.998, "quat {:?} vs {:?}", a.quat, b.quat);
        assert!((a.opacity - b.opacity).abs() <= 0.5 / 255.0 + 1e-6);
    }
    let s = read_wsplat(&bytes).unwrap();
    assert_eq!((s.statics.len(), s.dynamic[0].len(), s.dynamic[2].len(), s.fps), (700, 30, 12, 10.0));
}

#[test]
fn progressive_parse_gives_the_same_scene_at_any_split() {
    let (bytes, _, _) = sample();
    let whole = read_wsplat(&bytes).unwrap();
    let mut rng = Rng(7);
    for _ in 0..20 {
        let mut s = StreamingScene::default();
        let mut at = 0;
        let mut first_static_at = None;
        while at < bytes.len() {
            let n = 1 + rng.below(600);
            let end = (at + n).min(bytes.len());
            let p = s.push(&bytes[at..end]).unwrap();
            if first_static_at.is_none() && !s.scene.statics.is_empty() {
                first_static_at = Some(end);
                assert!(!p.done && p.static_decoded == 300, "the first STAT chunk is usable on its own");
            }
            at = end;
        }
        s.finish().unwrap();
        assert!(first_static_at.unwrap() < bytes.len() * 3 / 4);
        assert_eq!(s.scene.statics, whole.statics);
        assert_eq!(s.scene.dynamic, whole.dynamic);
    }
}

fn kind_of(bytes: &[u8]) -> (ErrorKind, u64) {
    let e = read_wsplat(bytes).unwrap_err();
    (e.kind, e.offset)
}

fn fix_crc(bytes: &mut [u8], chunk_at: usize) {
    let len = u32::from_le_bytes(bytes[chunk_at + 4..chunk_at + 8].try_into().unwrap()) as usize;
    let crc = crc32fast::hash(&bytes[chunk_at..chunk_at + 8 + len]);
    bytes[chunk_at + 8 + len..chunk_at + 12 + len].copy_from_slice(&crc.to_le_bytes());
}

#[test]
fn malformed_streams_name_kind_and_offset() {
    let (bytes, _, _) = sample();
    let head_len = u32::from_le_bytes(bytes[16..20].try_into().unwrap()) as usize;
    let stat_at = 12 + 12 + head_len;
    let mut b = bytes.clone();
    b[0] = b'X';
    assert_eq!(kind_of(&b).0, ErrorKind::BadMagic);
    let mut b = bytes.clone();
    b[8] = 5; // 1 to 4 are read
    assert_eq!(kind_of(&b), (ErrorKind::BadVersion, 8));
    assert_eq!(kind_of(&bytes[..bytes.len() - 3]).0, ErrorKind::Truncated);
    assert_eq!(kind_of(&bytes[..5]).0, ErrorKind::Truncated);
    let mut b = bytes.clone();
    b[stat_at + 20] ^= 1;
    assert_eq!(kind_of(&b).0, ErrorKind::BadCrc);
    let mut b = bytes.clone();
    b[stat_at..stat_at + 4].copy_from_slice(b"STAX");
    assert_eq!(kind_of(&b), (ErrorKind::BadTag, stat_at as u64));
    let mut b = bytes.clone();
    b[stat_at + 4..stat_at + 8].copy_from_slice(&(65u32 << 20).to_le_bytes());
    assert_eq!(kind_of(&b).0, ErrorKind::ChunkTooLarge);
    let mut b = bytes.clone();
    b.push(0);
    assert_eq!(kind_of(&b).0, ErrorKind::TrailingData);
    // A second HEAD where a STAT belongs.
    let mut b = bytes.clone();
    b[stat_at..stat_at + 4].copy_from_slice(b"HEAD");
    fix_crc(&mut b, stat_at);
    assert_eq!(kind_of(&b), (ErrorKind::BadOrder, stat_at as u64));
    // STAT count that disagrees with the payload length.
    let mut b = bytes.clone();
    b[stat_at + 8..stat_at + 12].copy_from_slice(&301u32.to_le_bytes());
    fix_crc(&mut b, stat_at);
    assert_eq!(kind_of(&b).0, ErrorKind::BadPayload);
    // A header with fps 0, and one with an unknown layout field.
    let head = std::str::from_utf8(&bytes[20..20 + head_len]).unwrap();
    for (from, to, kind) in [("\"fps\":10.0", "\"fps\":0.00", ErrorKind::BadHeader), ("[\"o\",8]", "[\"w\",8]", ErrorKind::BadLayout)] {
        assert!(head.contains(from), "{from} not in header");
        let mut b = bytes.clone();
        let h = head.replace(from, to);
        b[20..20 + head_len].copy_from_slice(h.as_bytes());
        fix_crc(&mut b, 12);
        let (k, off) = kind_of(&b);
        assert_eq!(k, kind, "{to}");
        assert_eq!(off, 20);
    }
    // Fewer static Gaussians than HEAD promises.
    let mut rng = Rng(3);
    let short = encode(&gaussians(&mut rng, 10), &[vec![]], 10.0, 4, 10);
    let hl = u32::from_le_bytes(short[16..20].try_into().unwrap()) as usize;
    let h = std::str::from_utf8(&short[20..20 + hl]).unwrap().replace("\"num_static\":10", "\"num_static\":11");
    let mut b = short[..20].to_vec();
    b[16..20].copy_from_slice(&(h.len() as u32).to_le_bytes());
    b.extend_from_slice(h.as_bytes());
    b.extend_from_slice(&[0; 4]);
    fix_crc(&mut b, 12);
    b.extend_from_slice(&short[20 + hl + 4..]);
    assert_eq!(kind_of(&b).0, ErrorKind::CountMismatch);
}

#[test]
fn seeded_mutations_never_panic_and_streaming_agrees() {
    let (bytes, _, _) = sample();
    let mut rng = Rng(0x5eed);
    let mut errors = 0;
    for round in 0..800 {
        let mut b = bytes.clone();
        match round % 5 {
            0 => {
                let i = rng.below(b.len());
                b[i] ^= 1 << rng.below(8);
            }
            1 => b.truncate(rng.below(b.len())),
            2 => {
                let i = rng.below(b.len());
                let n = 1 + rng.below(16);
                for k in i..(i + n).min(b.len()) {
                    b[k] = rng.next() as u8;
                }
            }
            3 => {
                let i = rng.below(b.len());
                b.insert(i, rng.next() as u8);
            }
            _ => {
                // Corrupt a length field and keep the CRC consistent, so the payload checks are exercised.
                let i = 12 + rng.below(b.len() - 12);
                b[i] = rng.next() as u8;
            }
        }
        let whole = read_wsplat(&b);
        if let Err(e) = &whole {
            errors += 1;
            assert!(e.offset <= b.len() as u64, "offset {} past {} bytes: {e}", e.offset, b.len());
            assert!(e.to_string().contains("offset"));
        }
        let mut s = StreamingScene::default();
        let mut at = 0;
        let mut streamed = Ok(());
        while at < b.len() {
            let end = (at + 1 + rng.below(900)).min(b.len());
            if let Err(e) = s.push(&b[at..end]) {
                streamed = Err(e);
                break;
            }
            at = end;
        }
        let streamed = streamed.and_then(|_| s.finish().map(|_| ()));
        match (&whole, &streamed) {
            (Ok(w), Ok(())) => assert_eq!(w.statics, s.scene.statics),
            (Err(a), Err(b2)) => assert_eq!((a.kind, a.offset), (b2.kind, b2.offset), "round {round}"),
            _ => panic!("round {round}: whole {:?} vs streamed {:?}", whole.as_ref().err(), streamed.err()),
        }
    }
    assert!(errors > 500, "mutations must be caught ({errors} errors)");
}

#[test]
fn shared_vectors() {
    let dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../../tests/vectors/wsplat");
    let Ok(entries) = std::fs::read_dir(&dir) else {
        println!("tests/vectors/wsplat not present yet; the spec cases above cover the decoder");
        return;
    };
    let mut n = 0;
    let mut paths: Vec<_> = entries.map(|e| e.unwrap().path()).filter(|p| p.extension().is_some_and(|x| x == "wsplat")).collect();
    paths.sort();
    for p in paths {
        let name = p.file_stem().unwrap().to_string_lossy().to_string();
        let expect: serde_json::Value = serde_json::from_str(&std::fs::read_to_string(p.with_extension("json")).unwrap()).unwrap();
        let bytes = std::fs::read(&p).unwrap();
        let got = read_wsplat(&bytes);
        if expect["ok"] == true {
            let s = got.unwrap_or_else(|e| panic!("{name}: {e}"));
            let tol = expect["tolerance"].as_f64().unwrap_or(1e-4) as f32;
            let mut dec = Decoder::new();
            let (mut statics, mut dynamic) = (Vec::new(), vec![0u64; s.num_frames()]);
            for e in dec.push(&bytes).unwrap() {
                match e {
                    Event::Static(g) => statics.extend(g),
                    Event::Dynamic { frame, gaussians } => dynamic[frame] += gaussians.len() as u64,
                    Event::StaticColours { first, colours } => recolour(&mut statics, first, &colours),
                    _ => {}
                }
            }
            assert_eq!(statics.len() as u64, expect["num_static"].as_u64().unwrap(), "{name}: num_static");
            if let Some(nd) = expect["num_dynamic"].as_array() {
                let want: Vec<u64> = nd.iter().map(|x| x.as_u64().unwrap()).collect();
                assert_eq!(dynamic, want, "{name}: num_dynamic");
            } else {
                assert_eq!(dynamic.iter().sum::<u64>(), expect["num_dynamic"].as_u64().unwrap(), "{name}: num_dynamic");
            }
            assert_eq!(s.num_frames() as u64, expect["frames"].as_u64().unwrap(), "{name}: frames");
            // first_static: record 0 of the first STAT chunk (v4: recoloured); first_dynamic: record 0 of the first
            // DYNA chunk.
            for (key, dynamic) in [("first_static", false), ("first_dynamic", true)] {
                let Some(first) = expect.get(key).filter(|v| !v.is_null()) else { continue };
                let mut dec = Decoder::new();
                let g = if dynamic {
                    dec.push(&bytes)
                        .unwrap()
                        .into_iter()
                        .find_map(|e| match e {
                            Event::Dynamic { gaussians, .. } => Some(gaussians[0]),
                            _ => None,
                        })
                        .unwrap()
                } else {
                    statics[0]
                };
                let close = |field: &str, got: &[f32]| {
                    let want: Vec<f32> = match &first[field] {
                        serde_json::Value::Array(a) => a.iter().map(|x| x.as_f64().unwrap() as f32).collect(),
                        v => vec![v.as_f64().unwrap() as f32],
                    };
                    assert_eq!(got.len(), want.len(), "{name}: {key}.{field}");
                    for (a, b) in got.iter().zip(&want) {
                        assert!((a - b).abs() <= tol * b.abs().max(1.0), "{name}: {key}.{field}: {got:?} vs {want:?}");
                    }
                };
                close("mean", &g.mean);
                close("quat", &g.quat);
                close("scale", &g.scale);
                close("opacity", &[g.opacity]);
                close("color", &g.color);
            }
            // range-coded files: the last record of the last DYNA chunk and the sum of every dynamic mean (each chunk
            // decodes with the models of the chunks before it)
            if let Some(last) = expect.get("last_dynamic") {
                let chunks: Vec<Vec<Gaussian>> = Decoder::new()
                    .push(&bytes)
                    .unwrap()
                    .into_iter()
                    .filter_map(|e| match e {
                        Event::Dynamic { gaussians, .. } => Some(gaussians),
                        _ => None,
                    })
                    .collect();
                let g = *chunks.last().unwrap().last().unwrap();
                let want = |k: &str| -> Vec<f64> {
                    match &last[k] {
                        serde_json::Value::Array(a) => a.iter().map(|x| x.as_f64().unwrap()).collect(),
                        v => vec![v.as_f64().unwrap()],
                    }
                };
                let got: [(&str, Vec<f32>); 5] = [
                    ("mean", g.mean.to_vec()),
                    ("quat", g.quat.to_vec()),
                    ("scale", g.scale.to_vec()),
                    ("opacity", vec![g.opacity]),
                    ("color", g.color.to_vec()),
                ];
                for (k, v) in got {
                    for (a, b) in v.iter().zip(want(k)) {
                        assert!((*a as f64 - b).abs() <= tol as f64 * b.abs().max(1.0), "{name}: last_dynamic.{k}: {v:?} vs {:?}", want(k));
                    }
                }
                let mut sum = [0f64; 3];
                for g in chunks.iter().flatten() {
                    (0..3).for_each(|k| sum[k] += g.mean[k] as f64);
                }
                let want: Vec<f64> = expect["dynamic_mean_sum"].as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect();
                for k in 0..3 {
                    assert!((sum[k] - want[k]).abs() <= 1e-2, "{name}: dynamic_mean_sum {sum:?} vs {want:?}");
                }
            }
            if expect.get("objects").is_some() {
                check_objects(&name, &bytes, &expect);
            }
            if let Some(want) = expect.get("static_color_sum") {
                // v4: every static colour as decoded, its SCOL chunks applied; the scene's packed statics recoloured alike
                let mut sum = [0f64; 3];
                statics.iter().for_each(|g| (0..3).for_each(|k| sum[k] += g.color[k] as f64));
                let tol = expect["tolerance"]["static_color_sum"].as_f64().unwrap();
                for (a, b) in sum.iter().zip(want.as_array().unwrap()) {
                    assert!((a - b.as_f64().unwrap()).abs() <= tol, "{name}: static_color_sum {sum:?} vs {want}");
                }
                let packed: Vec<_> = statics.iter().filter_map(Gaussian::pack).collect();
                assert_eq!(s.statics, packed, "{name}: the scene's statics are the recoloured Gaussians packed");
            }
        } else {
            let e = got.err().unwrap_or_else(|| panic!("{name}: decoded, but expected {}", expect["error_kind"]));
            assert_eq!(e.kind.name(), expect["error_kind"].as_str().unwrap(), "{name}: {e}");
            if let Some(off) = expect["offset"].as_u64() {
                assert_eq!(e.offset, off, "{name}: {e}");
            }
            if (name.contains("v2") || name.contains("v3") || name.contains("v4")) && e.kind == ErrorKind::BadPayload {
                // v2's payload errors start with the field the spec names (e.g. "STAT.pos[1].filter: ...")
                let field = expect["field"].as_str().unwrap();
                assert!(e.message.starts_with(&format!("{field}:")), "{name}: {e} does not name {field}");
            }
        }
        n += 1;
    }
    assert!(n > 0, "tests/vectors/wsplat exists but holds no vectors");
    println!("{n} shared wsplat vectors pass");
}

/// A v3 vector's objects (agent id, class, size, count, first canonical Gaussian), poses per frame and the baked frames
/// (each frame's DYNA records plus its posed objects: counts and the sum of their means).
fn check_objects(name: &str, bytes: &[u8], expect: &serde_json::Value) {
    let s = read_wsplat(bytes).unwrap();
    let want = expect["objects"].as_array().unwrap();
    let tol = &expect["tolerance"];
    assert_eq!(s.objects.len(), want.len(), "{name}: objects");
    let f64s = |v: &serde_json::Value| -> Vec<f64> { v.as_array().unwrap().iter().map(|x| x.as_f64().unwrap()).collect() };
    for (i, (o, w)) in s.objects.iter().zip(want).enumerate() {
        assert_eq!(
            (o.agent_id as u64, o.cls as u64, o.gaussians.len() as u64),
            (w["agent_id"].as_u64().unwrap(), w["cls"].as_u64().unwrap(), w["count"].as_u64().unwrap()),
            "{name}: object {i}"
        );
        for (a, b) in o.size.iter().zip(f64s(&w["size"])) {
            assert!((*a as f64 - b).abs() < 1e-6, "{name}: object {i} size");
        }
        if let Some(first) = w.get("first").filter(|v| !v.is_null()) {
            for (a, b) in o.gaussians[0].mean.iter().zip(f64s(&first["mean"])) {
                assert!((*a as f64 - b).abs() <= tol["mean"].as_f64().unwrap() * b.abs().max(1.0), "{name}: object {i} first mean");
            }
        }
        let present: Vec<bool> = w["present"].as_array().unwrap().iter().map(|x| x.as_bool().unwrap()).collect();
        for (f, p) in present.iter().enumerate() {
            let got = s.object_poses[f].get(i).copied().flatten();
            assert_eq!(got.is_some(), *p, "{name}: object {i} present in frame {f}");
            if let Some(pose) = got {
                let m = pose.matrix();
                for (r, row) in w["poses"][f].as_array().unwrap().iter().enumerate() {
                    for (c, x) in f64s(row).iter().enumerate() {
                        assert!((m[r][c] - x).abs() <= 1e-5, "{name}: object {i} frame {f} pose[{r}][{c}] {} vs {x}", m[r][c]);
                    }
                }
            }
        }
    }
    let mut dyna: Vec<Vec<Gaussian>> = vec![Vec::new(); s.num_frames()];
    for e in Decoder::new().push(bytes).unwrap() {
        if let Event::Dynamic { frame, gaussians } = e {
            dyna[frame].extend(gaussians);
        }
    }
    for (f, want_sum) in expect["baked_mean_sum"].as_array().unwrap().iter().enumerate() {
        let mut frame = dyna[f].clone();
        frame.extend(bake_objects(&s.objects, &s.object_poses[f]));
        assert_eq!(frame.len() as u64, expect["baked_num_dynamic"][f].as_u64().unwrap(), "{name}: baked frame {f}");
        assert_eq!(s.dynamic_at(f).len(), frame.iter().filter_map(Gaussian::pack).count(), "{name}: the scene's baked frame {f}");
        let mut sum = [0f64; 3];
        frame.iter().for_each(|g| (0..3).for_each(|k| sum[k] += g.mean[k] as f64));
        for (a, b) in sum.iter().zip(f64s(want_sum)) {
            assert!((a - b).abs() <= 1e-2, "{name}: baked frame {f} mean sum {sum:?} vs {want_sum}");
        }
    }
}

/// v4: statics `first..` take `colours` (a SCOL chunk, applied as a reader does).
fn recolour(statics: &mut [Gaussian], first: usize, colours: &[[f32; 3]]) {
    for (g, c) in statics[first..].iter_mut().zip(colours) {
        g.color = *c;
    }
}

fn vector(name: &str) -> Vec<u8> {
    std::fs::read(Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("../../../tests/vectors/wsplat/{name}.wsplat"))).unwrap()
}

#[test]
fn v2_progressive_parse_gives_the_same_scene_at_any_split() {
    let bytes = vector("valid_v2_multi_chunk");
    let whole = read_wsplat(&bytes).unwrap();
    assert_eq!(whole.statics.len(), 5000);
    let mut rng = Rng(11);
    for _ in 0..10 {
        let mut s = StreamingScene::default();
        let mut at = 0;
        let mut first = None;
        while at < bytes.len() {
            let end = (at + 1 + rng.below(3000)).min(bytes.len());
            let p = s.push(&bytes[at..end]).unwrap();
            if first.is_none() && !s.scene.statics.is_empty() {
                first = Some(p.static_decoded);
            }
            at = end;
        }
        s.finish().unwrap();
        assert_eq!(first, Some(4096), "the first STAT chunk (FIRST_CHUNK records) renders on its own");
        assert_eq!(s.scene.statics, whole.statics);
    }
}

/// Byte changes inside the payloads of `chunks` ((offset, payload length) of each; CRC fixed so they reach what the
/// payloads hold): never a panic, errors inside the data, streaming agrees with whole-buffer decoding. The number of
/// rounds that failed.
fn payload_mutations(bytes: &[u8], chunks: &[(usize, usize)], seed: u64) -> usize {
    let mut rng = Rng(seed);
    let mut errors = 0;
    for round in 0..600 {
        let mut b = bytes.to_vec();
        let (chunk_at, len) = chunks[rng.below(chunks.len())];
        for _ in 0..1 + rng.below(3) {
            let i = chunk_at + 8 + rng.below(len);
            b[i] = if round % 2 == 0 { b[i] ^ (1 << rng.below(8)) } else { rng.next() as u8 };
        }
        fix_crc(&mut b, chunk_at);
        let whole = read_wsplat(&b);
        if let Err(e) = &whole {
            errors += 1;
            assert!(e.offset <= b.len() as u64, "offset {} past {} bytes: {e}", e.offset, b.len());
        }
        let split = rng.below(b.len());
        let mut s = StreamingScene::default();
        let streamed = s.push(&b[..split]).and_then(|_| s.push(&b[split..])).and_then(|_| s.finish());
        match (&whole, &streamed) {
            (Ok(w), Ok(_)) => assert!(w.statics == s.scene.statics && w.dynamic == s.scene.dynamic, "round {round}"),
            (Err(a), Err(b2)) => assert_eq!((a.kind, a.offset), (b2.kind, b2.offset), "round {round}"),
            _ => panic!("round {round}: whole {:?} vs streamed {:?}", whole.as_ref().err(), streamed.err()),
        }
    }
    errors
}

/// The (offset, payload length) of every chunk tagged `tag`.
fn chunks_tagged(bytes: &[u8], tag: &[u8; 4]) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    let mut at = 12;
    while at < bytes.len() {
        let len = u32::from_le_bytes(bytes[at + 4..at + 8].try_into().unwrap()) as usize;
        if &bytes[at..at + 4] == tag {
            out.push((at, len));
        }
        at += 12 + len;
    }
    out
}

/// Mutations inside the sections of a v2 STAT chunk (CRC fixed so they reach the zstd frames, filters, lengths
/// and values).
#[test]
fn v2_seeded_mutations_never_panic_and_streaming_agrees() {
    let bytes = vector("valid_v2_aniso");
    let errors = payload_mutations(&bytes, &chunks_tagged(&bytes, b"STAT")[..1], 0xbeef);
    // a flipped literal inside a zstd frame often still decodes (only the chunk CRC, fixed here, catches it)
    assert!(errors > 100, "mutations must be caught ({errors} errors)");
}

const RANGE_VECTORS: [&str; 6] = [
    "valid_v2_range_iso",
    "valid_v2_range_aniso",
    "valid_v2_range_streamed",
    "valid_v2_range_streamed_iso",
    "valid_v2_range_custom",
    "valid_v2_range_degenerate",
];

/// The Python encoder (constriction's Python binding) and this crate's model write the same words: every DYNA
/// stream of the range-coded vectors, decoded here with the models carried from chunk to chunk and encoded again
/// here, is the file's stream (plus the zero words an encoder pads a degenerate chunk with).
#[test]
fn range_streams_are_the_words_the_python_encoder_wrote() {
    for name in RANGE_VECTORS {
        let bytes = vector(name);
        let payload = |(at, len): (usize, usize)| &bytes[at + 8..at + 8 + len];
        let head: serde_json::Value = serde_json::from_slice(payload(chunks_tagged(&bytes, b"HEAD")[0])).unwrap();
        assert_eq!(head["dynamic_codec"], "range", "{name}");
        let layout: Vec<(&'static str, u32)> = head["dynamic_layout"]
            .as_array()
            .unwrap()
            .iter()
            .map(|f| {
                let n = f[0].as_str().unwrap();
                let name = ["px", "py", "pz", "qx", "qy", "qz", "sx", "sy", "sz", "s", "o", "r", "g", "b"].into_iter().find(|x| *x == n).unwrap();
                (name, f[1].as_u64().unwrap() as u32)
            })
            .collect();
        let block_size = head["block_size"].as_u64().unwrap() as usize;
        let (mut dec, mut enc) = (dyna_range::Models::new(&layout), dyna_range::Models::new(&layout));
        let mut n = 0;
        for p in chunks_tagged(&bytes, b"DYNA").into_iter().map(payload) {
            let count = u32::from_le_bytes(p[4..8].try_into().unwrap()) as usize;
            let words_at = 8 + 32 * count.div_ceil(block_size);
            let nw = u32::from_le_bytes(p[words_at..words_at + 4].try_into().unwrap()) as usize;
            let words: Vec<u32> = p[words_at + 4..].chunks_exact(4).map(|w| u32::from_le_bytes(w.try_into().unwrap())).collect();
            assert_eq!(words.len(), nw);
            let (deltas, values) = dyna_range::decode_chunk(&mut dec, words.clone(), count).unwrap();
            let again = dyna_range::encode_chunk(&mut enc, &deltas, &values);
            assert_eq!(&words[..again.len()], &again[..], "{name}: chunk {n}");
            assert!(words[again.len()..].iter().all(|&w| w == 0), "{name}: chunk {n}: padding");
            assert_eq!(dec, enc);
            n += 1;
        }
        assert!(n >= 1, "{name}: no DYNA chunk");
        if name == "valid_v2_range_degenerate" {
            let p = payload(chunks_tagged(&bytes, b"DYNA")[0]);
            assert_eq!(&p[p.len() - 8..], &[0; 8], "the degenerate vector's stream ends in padding");
        }
    }
}

/// A streaming parse of `bytes` pushed in pieces of 1-2000 bytes, finished.
fn pushed_in_random_pieces(bytes: &[u8], rng: &mut Rng) -> StreamingScene {
    let mut s = StreamingScene::default();
    let mut at = 0;
    while at < bytes.len() {
        let end = (at + 1 + rng.below(2000)).min(bytes.len());
        s.push(&bytes[at..end]).unwrap();
        at = end;
    }
    s.finish().unwrap();
    s
}

#[test]
fn range_progressive_parse_gives_the_same_scene_at_any_split() {
    for name in ["valid_v2_range_streamed", "valid_v2_range_iso"] {
        let bytes = vector(name);
        let whole = read_wsplat(&bytes).unwrap();
        let mut rng = Rng(5);
        for _ in 0..10 {
            let s = pushed_in_random_pieces(&bytes, &mut rng);
            assert_eq!(s.scene.statics, whole.statics, "{name}");
            assert_eq!(s.scene.dynamic, whole.dynamic, "{name}");
        }
    }
}

/// Mutations inside the range-coded DYNA chunks (CRC fixed so they reach the boxes, the word count and the
/// streams); a changed stream decodes with the models of the chunks before it, and the chunks after it with its.
#[test]
fn range_seeded_mutations_never_panic_and_streaming_agrees() {
    let bytes = vector("valid_v2_range_aniso");
    let errors = payload_mutations(&bytes, &chunks_tagged(&bytes, b"DYNA"), 0xd1a);
    assert!(errors > 300, "mutations must be caught ({errors} errors)");
}

/// `file` with chunk `index`'s payload replaced (length and CRC made consistent).
fn with_chunk_payload(file: &[u8], index: usize, payload: &[u8]) -> Vec<u8> {
    let mut at = 12;
    for _ in 0..index {
        at += 12 + u32::from_le_bytes(file[at + 4..at + 8].try_into().unwrap()) as usize;
    }
    let len = u32::from_le_bytes(file[at + 4..at + 8].try_into().unwrap()) as usize;
    let mut out = file[..at + 4].to_vec();
    out.extend_from_slice(&(payload.len() as u32).to_le_bytes());
    out.extend_from_slice(payload);
    let crc = crc32fast::hash(&out[at..]);
    out.extend_from_slice(&crc.to_le_bytes());
    out.extend_from_slice(&file[at + 12 + len..]);
    out
}

#[test]
fn v3_object_and_pose_payload_mutations_never_panic_and_streaming_agrees() {
    let bytes = vector("valid_v3_objects");
    let mut chunks = Vec::new(); // (chunk index, payload) of the OBJC and POSE chunks
    let (mut at, mut index) = (12, 0);
    while at < bytes.len() {
        let len = u32::from_le_bytes(bytes[at + 4..at + 8].try_into().unwrap()) as usize;
        if matches!(&bytes[at..at + 4], b"OBJC" | b"POSE") {
            chunks.push((index, bytes[at + 8..at + 8 + len].to_vec()));
        }
        at += 12 + len;
        index += 1;
    }
    let mut rng = Rng(0x0b1ec7);
    let mut errors = 0;
    for round in 0..600 {
        let (index, payload) = &chunks[rng.below(chunks.len())];
        let mut p = payload.clone();
        match round % 3 {
            0 => {
                let i = rng.below(p.len().min(64));
                p[i] ^= 1 << rng.below(8);
            }
            1 => p.truncate(rng.below(p.len())),
            _ => {
                let i = rng.below(p.len().min(40));
                p[i] = rng.next() as u8;
            }
        }
        let b = with_chunk_payload(&bytes, *index, &p);
        let whole = read_wsplat(&b);
        if let Err(e) = &whole {
            errors += 1;
            assert!(e.offset <= b.len() as u64, "offset {} past {} bytes: {e}", e.offset, b.len());
        }
        let mut s = StreamingScene::default();
        let streamed = s.push(&b[..b.len() / 2]).and_then(|_| s.push(&b[b.len() / 2..])).and_then(|_| s.finish());
        match (&whole, &streamed) {
            (Ok(w), Ok(_)) => {
                assert_eq!((&w.objects, &w.object_poses, &w.dynamic), (&s.scene.objects, &s.scene.object_poses, &s.scene.dynamic))
            }
            (Err(a), Err(b2)) => assert_eq!((a.kind, a.offset), (b2.kind, b2.offset), "round {round}"),
            _ => panic!("round {round}: whole {:?} vs streamed {:?}", whole.as_ref().err(), streamed.err()),
        }
    }
    assert!(errors > 300, "mutations must be caught ({errors} errors)");
}

#[test]
fn v3_streamed_frames_arrive_in_order_as_their_pose_chunks_do() {
    let bytes = vector("valid_v3_streamed");
    let whole = read_wsplat(&bytes).unwrap();
    assert_eq!(whole.frames_arrived(), whole.num_frames(), "every frame of the whole file has its agents");
    let mut s = StreamingScene::default();
    let mut seen = vec![0];
    for piece in bytes.chunks(7) {
        s.push(piece).unwrap();
        let n = s.scene.frames_arrived();
        assert!(n >= *seen.last().unwrap(), "frames_arrived went back: {seen:?} then {n}");
        // the frames that arrived are the first n: a later frame never has its agents before an earlier one
        for t in 0..n {
            assert!(!s.scene.object_poses[t].is_empty() || !s.scene.dynamic[t].is_empty(), "frame {t} of {n}");
        }
        seen.push(n);
    }
    s.finish().unwrap();
    assert_eq!(s.scene.frames_arrived(), whole.num_frames());
    assert!(seen.iter().any(|&n| n > 0 && n < whole.num_frames()), "a prefix of the stream has some frames: {seen:?}");
}

/// v4: a SCOL chunk's colours reach the scene's packed statics wherever the stream is cut (the scene keeps each
/// static dropped at packing, so a recolour skips it: `valid_v4_recoloured` has one, opacity 0 as stored), the
/// recolour count goes up once per SCOL chunk, and positions, shapes and opacities stay as the STAT chunks gave them.
#[test]
fn v4_recolours_reach_the_packed_statics_at_any_split() {
    let bytes = vector("valid_v4_recoloured");
    let whole = read_wsplat(&bytes).unwrap();
    let scol = chunks_tagged(&bytes, b"SCOL").len() as u64;
    assert_eq!(whole.static_recolours, scol);
    assert_eq!(whole.static_dropped.len(), 1, "the static whose opacity is stored as 0");
    let mut plain = StreamingScene::default(); // the same stream without its SCOL chunks
    let mut at = 12;
    plain.push(&bytes[..12]).unwrap();
    while at < bytes.len() {
        let len = u32::from_le_bytes(bytes[at + 4..at + 8].try_into().unwrap()) as usize;
        if &bytes[at..at + 4] != b"SCOL" {
            plain.push(&bytes[at..at + 12 + len]).unwrap();
        }
        at += 12 + len;
    }
    plain.finish().unwrap();
    assert_eq!(plain.scene.statics.len(), whole.statics.len());
    let colour_differs = whole.statics.iter().zip(&plain.scene.statics).filter(|(a, b)| a.rgba & 0xff_ffff != b.rgba & 0xff_ffff).count();
    assert!(colour_differs > whole.statics.len() / 2, "{colour_differs} of {} recoloured", whole.statics.len());
    for (a, b) in whole.statics.iter().zip(&plain.scene.statics) {
        assert_eq!((a.mean, a.shape, a.rgba >> 24), (b.mean, b.shape, b.rgba >> 24));
    }
    let mut rng = Rng(44);
    for _ in 0..10 {
        let s = pushed_in_random_pieces(&bytes, &mut rng);
        assert_eq!(s.scene.statics, whole.statics);
        assert_eq!(s.scene.static_recolours, scol);
    }
}

/// Mutations inside the SCOL chunks of a v4 file (CRC fixed): never a panic, errors inside the data, streaming
/// agrees with whole-buffer decoding.
#[test]
fn v4_scol_mutations_never_panic_and_streaming_agrees() {
    let bytes = vector("valid_v4_recoloured");
    let errors = payload_mutations(&bytes, &chunks_tagged(&bytes, b"SCOL"), 0x5c01);
    // most of these bytes are random colours that zstd keeps as raw blocks: a changed one there is another colour,
    // which only the chunk CRC (fixed here) catches (87 of the 600 rounds fail)
    assert!(errors > 50, "mutations must be caught ({errors} errors)");
}
