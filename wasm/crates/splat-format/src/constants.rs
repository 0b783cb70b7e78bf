//! The guards of web/docs/splatting-math.md, in one place for Rust. `shaders/constants.wgsl` mirrors them
//! for the GPU; a test (`tests/shaders.rs`) checks the two agree value by value.

/// Near plane: keep only camera-space z > NEAR (metres).
pub const NEAR: f32 = 0.2;
/// Low-pass dilation added to the 2D covariance diagonal (px^2).
pub const DILATION: f32 = 0.3;
/// Jacobian clamp factor on tan(fov/2).
pub const CLAMP: f32 = 1.3;
/// Floor under the eigenvalue discriminant.
pub const EIG_FLOOR: f32 = 0.1;
/// Smallest accepted determinant of the dilated 2D covariance.
pub const DET_MIN: f32 = 1e-12;
/// Extent of the quad in standard deviations of the dilated footprint.
pub const EXTENT_SIGMA: f32 = 3.0;
/// Largest quad radius in pixels.
pub const RADIUS_MAX: f32 = 4096.0;
/// Support: a Gaussian touches a pixel only if the Mahalanobis distance squared is <= D_MAX (= EXTENT_SIGMA^2).
pub const D_MAX: f32 = EXTENT_SIGMA * EXTENT_SIGMA;
/// Per-Gaussian alpha cap.
pub const ALPHA_MAX: f32 = 0.99;
/// Contributions below this alpha are skipped; opacities below it are dropped.
pub const ALPHA_MIN: f32 = 1.0 / 255.0;
/// Front-to-back compositing stops before transmittance falls below this (reference only; see viewer.md).
pub const T_MIN: f32 = 1e-4;
/// Quaternions shorter than this become the identity rotation.
pub const QUAT_EPS: f32 = 1e-6;
/// Scale clamp (metres, standard deviation).
pub const SCALE_MIN: f32 = 1e-6;
pub const SCALE_MAX: f32 = 1e3;
/// Range of the 16-bit log-scale in the GPU record: ln(SCALE_MIN) .. ln(SCALE_MAX).
pub const LOG_SCALE_LO: f32 = -13.815511;
pub const LOG_SCALE_HI: f32 = 6.9077554;
/// Largest lateral track shift the viewer offers (metres, either side).
pub const SHIFT_MAX_M: f32 = 8.0;

/// Name/value pairs of every constant the WGSL mirrors (used by the mirror test).
pub const MIRRORED: &[(&str, f32)] = &[
    ("NEAR", NEAR),
    ("DILATION", DILATION),
    ("CLAMP", CLAMP),
    ("EIG_FLOOR", EIG_FLOOR),
    ("DET_MIN", DET_MIN),
    ("EXTENT_SIGMA", EXTENT_SIGMA),
    ("RADIUS_MAX", RADIUS_MAX),
    ("D_MAX", D_MAX),
    ("ALPHA_MAX", ALPHA_MAX),
    ("ALPHA_MIN", ALPHA_MIN),
    ("LOG_SCALE_LO", LOG_SCALE_LO),
    ("LOG_SCALE_HI", LOG_SCALE_HI),
];
