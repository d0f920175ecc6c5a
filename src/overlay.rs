//! Agreement overlays: one PNG per view so a user sees at a glance why a result is right or
//! wrong. Green = rendered and observed agree on robot, red = observed robot the render misses,
//! blue = rendered robot the mask does not show; drawn over the colour frame (dimmed) when the
//! run has one, else over the grey mask.

use std::path::Path;

use image::{Rgb, RgbImage};

use crate::error::{Error, Result};
use crate::mask::Mask;

/// Colour for pixels where both agree on robot.
pub const AGREE: [u8; 3] = [40, 200, 60];
/// Colour for observed robot that the render misses.
pub const MISSED: [u8; 3] = [230, 40, 40];
/// Colour for rendered robot that the observation does not show.
pub const EXTRA: [u8; 3] = [50, 90, 240];

/// Composes the overlay image.
pub fn overlay_image(rendered: &Mask, observed: &Mask, background: Option<&RgbImage>) -> RgbImage {
    let (w, h) = (observed.width, observed.height);
    RgbImage::from_fn(w, h, |u, v| {
        let i = (v * w + u) as usize;
        let (r, o) = (rendered.data[i] != 0, observed.data[i] != 0);
        let base = match background {
            Some(img) if img.width() == w && img.height() == h => {
                let p = img.get_pixel(u, v).0;
                [p[0] / 2, p[1] / 2, p[2] / 2]
            }
            _ => {
                let g = if o { 90 } else { 20 };
                [g, g, g]
            }
        };
        let tint = match (r, o) {
            (true, true) => Some(AGREE),
            (false, true) => Some(MISSED),
            (true, false) => Some(EXTRA),
            (false, false) => None,
        };
        Rgb(match tint {
            Some(t) => [0, 1, 2].map(|k| ((u16::from(base[k]) + 2 * u16::from(t[k])) / 3) as u8),
            None => base,
        })
    })
}

/// Writes an overlay PNG atomically.
pub fn write_overlay(
    path: &Path,
    rendered: &Mask,
    observed: &Mask,
    image_path: Option<&Path>,
) -> Result<()> {
    let background = image_path
        .and_then(|p| image::open(p).ok())
        .map(|i| i.to_rgb8());
    let img = overlay_image(rendered, observed, background.as_ref());
    let mut bytes = std::io::Cursor::new(Vec::new());
    img.write_to(&mut bytes, image::ImageFormat::Png)
        .map_err(|e| Error::io(path, e))?;
    crate::io::write_atomic(path, &bytes.into_inner())
}
