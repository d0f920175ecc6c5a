//! `easyhec --version`: the version and the cargo features this binary was built with, so a
//! bug report says which drivers and renderers were in it.

use std::sync::OnceLock;

/// `0.1.0 (features: sim, wgpu)`.
pub fn version_line() -> &'static str {
    static LINE: OnceLock<String> = OnceLock::new();
    LINE.get_or_init(|| {
        let on: Vec<&str> = easyhec::FEATURES
            .iter()
            .filter(|(_, enabled)| *enabled)
            .map(|(name, _)| *name)
            .collect();
        let features = if on.is_empty() {
            "none".to_string()
        } else {
            on.join(", ")
        };
        format!("{} (features: {features})", env!("CARGO_PKG_VERSION"))
    })
}
