// Mirror of splat-core/src/constants.rs (web/docs/splatting-math.md); tests/shaders.rs checks they agree.
const NEAR: f32 = 0.2;
const DILATION: f32 = 0.3;
const CLAMP: f32 = 1.3;
const EIG_FLOOR: f32 = 0.1;
const DET_MIN: f32 = 1e-12;
const EXTENT_SIGMA: f32 = 3.0;
const RADIUS_MAX: f32 = 4096.0;
const D_MAX: f32 = 9.0;
const ALPHA_MAX: f32 = 0.99;
const ALPHA_MIN: f32 = 0.003921569;
const LOG_SCALE_LO: f32 = -13.815511;
const LOG_SCALE_HI: f32 = 6.9077554;
