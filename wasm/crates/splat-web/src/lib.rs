//! The Viewer JS API (see web/docs/viewer.md) over splat-core.
pub use splat_core;
