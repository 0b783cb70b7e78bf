//! naga validation of every shader the renderer compiles (no GPU needed), and the WGSL constant mirror.

use splat_core::renderer::{splat_shader_source, DrawPath, SHADER_BLIT, SHADER_CONSTANTS};
use splat_core::shaders::sort_shader_source;
use splat_format::constants::MIRRORED;

fn validate(name: &str, src: &str) -> naga::Module {
    let module = naga::front::wgsl::parse_str(src).unwrap_or_else(|e| panic!("{name}: {}", e.emit_to_string(src)));
    naga::valid::Validator::new(naga::valid::ValidationFlags::all(), naga::valid::Capabilities::default())
        .validate(&module)
        .unwrap_or_else(|e| panic!("{name}: {}", e.emit_to_string(src)));
    module
}

#[test]
fn every_shader_validates() {
    validate("splat (storage path)", &splat_shader_source(DrawPath::Storage));
    validate("splat (instanced path)", &splat_shader_source(DrawPath::Instanced));
    for items in [4, 16, 32] {
        let src = sort_shader_source(items);
        assert!(src.contains(&format!("const ITEMS: u32 = {items}u;")), "the sort shader takes {items} keys per thread");
        validate("radix sort", &src);
    }
    validate("blit", SHADER_BLIT);
}

#[test]
fn validation_catches_a_broken_shader() {
    let broken = splat_shader_source(DrawPath::Storage).replace("let alpha = min(ALPHA_MAX", "let alpha = min(1u");
    let parsed = naga::front::wgsl::parse_str(&broken);
    let failed = match parsed {
        Err(_) => true,
        Ok(m) => naga::valid::Validator::new(naga::valid::ValidationFlags::all(), naga::valid::Capabilities::default()).validate(&m).is_err(),
    };
    assert!(failed, "a type error must not validate");
}

#[test]
fn wgsl_constants_mirror_rust() {
    let module = validate("constants", SHADER_CONSTANTS);
    let mut seen = 0;
    for (_, c) in module.constants.iter() {
        let name = c.name.as_deref().unwrap_or("");
        let value = match module.global_expressions[c.init] {
            naga::Expression::Literal(naga::Literal::F32(v)) => v,
            ref e => panic!("constant {name} is not an f32 literal: {e:?}"),
        };
        let (_, want) = MIRRORED.iter().find(|(n, _)| *n == name).unwrap_or_else(|| panic!("WGSL constant {name} has no Rust twin"));
        assert_eq!(value, *want, "WGSL {name} = {value} but Rust says {want}");
        seen += 1;
    }
    assert_eq!(seen, MIRRORED.len(), "every mirrored Rust constant must appear in constants.wgsl");
}

#[test]
fn record_texture_width_mirrors_rust() {
    let line = format!("const RECORD_TEX_WIDTH: u32 = {}u;", splat_core::records::RECORD_TEX_WIDTH);
    assert!(splat_core::renderer::SHADER_SPLAT_INSTANCED.contains(&line), "splat_instanced.wgsl declares {line:?}");
}

#[test]
fn pose_table_mirrors_rust() {
    use splat_core::poses::{ObjectPoseRow, MAX_GPU_OBJECTS, POSE_TABLE_BYTES};
    let line = format!("const MAX_OBJECTS: u32 = {MAX_GPU_OBJECTS}u;");
    assert!(splat_core::shaders::SHADER_POSES.contains(&line), "poses.wgsl declares {line:?}");
    // The uniform's layout as naga lays it out equals the bytes `PoseTable::gpu_bytes` writes.
    let module = validate("splat (storage path)", &splat_shader_source(DrawPath::Storage));
    let mut layouter = naga::proc::Layouter::default();
    layouter.update(module.to_ctx()).unwrap();
    let size = |name: &str| {
        let (h, _) = module.types.iter().find(|(_, t)| t.name.as_deref() == Some(name)).unwrap_or_else(|| panic!("no struct {name}"));
        layouter[h].size as u64
    };
    assert_eq!(size("ObjectPose"), std::mem::size_of::<ObjectPoseRow>() as u64);
    assert_eq!(size("PoseTable"), POSE_TABLE_BYTES);
}
