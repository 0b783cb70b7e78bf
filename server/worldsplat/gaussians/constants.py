"""Every numerical guard of the splatting math, in one place (web/docs/splatting-math.md, "Guards in one list").

The Rust viewer mirrors these in `wasm/crates/splat-format/src/constants.rs`; the shared vectors in
`tests/vectors/raster/` pin both to the same values.
"""

NEAR = 0.2  # m: keep only camera z > NEAR
DILATION = 0.3  # px^2 low-pass added to the 2D covariance diagonal (no opacity compensation)
CLAMP = 1.3  # Jacobian clamp: |x/z| <= CLAMP * tan(fov_x / 2) (likewise y)
EIG_FLOOR = 0.1  # floor under the discriminant when computing the largest eigenvalue
DET_MIN = 1e-12  # drop a Gaussian unless det(cov2d) > DET_MIN
EXTENT_SIGMA = 3.0  # radius = ceil(EXTENT_SIGMA * sqrt(lambda_max)); support d <= EXTENT_SIGMA^2
RADIUS_MAX = 4096  # px cap on the radius
ALPHA_MAX = 0.99  # alpha = min(ALPHA_MAX, o * exp(-d/2))
ALPHA_MIN = 1.0 / 255.0  # skip a Gaussian at a pixel when alpha < ALPHA_MIN; drop it when opacity < ALPHA_MIN
T_MIN = 1e-4  # stop compositing before a Gaussian that would push transmittance below T_MIN
QUAT_EPS = 1e-6  # |q| < QUAT_EPS -> identity rotation
SCALE_MIN = 1e-6  # m, scale clamp
SCALE_MAX = 1e3  # m

# Reference-rasterizer tiling (not part of the math: any tile size gives the same image).
TILE_SIZE = 16
CHUNK = 4096  # Gaussians per compositing chunk: bounds memory at TILE_SIZE^2 * CHUNK per tensor
