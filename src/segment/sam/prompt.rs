//! The prompt a render makes, and the geometry between a frame and the encoder's square.
//!
//! Both SAM families take a square image: SAM scales the frame so its longer side fills it and
//! pads the rest, SAM 2 stretches it. Prompt points and the decoder's low-resolution logits live
//! in that square; these mappings keep pixel centres at integer coordinates on both sides
//! (OpenCV's convention), so a frame pixel and its place in the square describe one point.

use super::super::onnx::taps;
use crate::config::segmenter::SamResize;
use crate::mask::Mask;

/// How far inside the render an interior point must lie beyond the band, pixels: the band is
/// how far the true outline may be from the render, and 2 px more keeps a point off the
/// outline's own blur and the segmenter's rim errors.
const POINT_MARGIN_PX: f32 = 2.0;

/// A prompt in frame pixels: the box's corners, then interior points.
#[derive(Clone, Debug, PartialEq)]
pub struct Prompt {
    /// Top-left and bottom-right corners of the box, `[x, y]`.
    pub corners: [[f32; 2]; 2],
    /// Foreground points, `[x, y]`, deepest first.
    pub points: Vec<[f32; 2]>,
}

/// Where a frame lies in the encoder's square: its scaled size there and the scales.
#[derive(Clone, Copy, Debug)]
pub struct Fit {
    /// The frame's size in the square, pixels.
    pub(super) width: usize,
    pub(super) height: usize,
    /// Square pixels per frame pixel, across and down.
    pub(super) sx: f32,
    pub(super) sy: f32,
}

impl Fit {
    /// A `w`x`h` frame in a square of `side`, as `resize` says.
    pub fn of(w: usize, h: usize, side: usize, resize: SamResize) -> Fit {
        let (width, height) = match resize {
            SamResize::Stretch => (side, side),
            SamResize::LongestSide => {
                let scale = side as f64 / w.max(h) as f64;
                let fitted = |n: usize| ((n as f64 * scale).round() as usize).clamp(1, side);
                (fitted(w), fitted(h))
            }
        };
        Fit {
            width,
            height,
            sx: width as f32 / w as f32,
            sy: height as f32 / h as f32,
        }
    }

    /// A frame pixel position in the square's pixels (pixel centres at integers in both).
    pub fn in_square(&self, [x, y]: [f32; 2]) -> [f32; 2] {
        [(x + 0.5) * self.sx - 0.5, (y + 0.5) * self.sy - 0.5]
    }
}

/// One mask's logits over the encoder's square.
pub(super) struct LowRes {
    pub(super) width: usize,
    pub(super) height: usize,
    pub(super) logits: Vec<f32>,
    pub(super) side: usize,
}

impl LowRes {
    /// The frame's mask: each pixel's logit, bilinear at its place in the square, over
    /// `threshold`.
    pub(super) fn sampled(&self, fit: &Fit, w: usize, h: usize, threshold: f32) -> Mask {
        let mut mask = Mask::new(w as u32, h as u32);
        let (cx, cy) = (
            self.width as f32 / self.side as f32,
            self.height as f32 / self.side as f32,
        );
        for y in 0..h {
            let v = (y as f32 + 0.5) * fit.sy - 0.5;
            let (y0, y1, ty) = taps((v + 0.5) * cy - 0.5, self.height);
            for x in 0..w {
                let u = (x as f32 + 0.5) * fit.sx - 0.5;
                let (x0, x1, tx) = taps((u + 0.5) * cx - 0.5, self.width);
                let l = |xx: usize, yy: usize| self.logits[yy * self.width + xx];
                let top = l(x0, y0) + (l(x1, y0) - l(x0, y0)) * tx;
                let bottom = l(x0, y1) + (l(x1, y1) - l(x0, y1)) * tx;
                if top + (bottom - top) * ty > threshold {
                    mask.data[y * w + x] = 1;
                }
            }
        }
        mask
    }
}

/// `prompt`'s `point_coords` and `point_labels` for `n` points, in the encoder's square: the
/// box's corners (labels 2 and 3), the interior points (1), then padding (-1, which SAM's
/// prompt encoder ignores) up to `n`.
pub fn prompt_tensors(prompt: &Prompt, fit: &Fit, n: usize) -> (Vec<f32>, Vec<f32>) {
    let mut coords = Vec::with_capacity(2 * n);
    let mut labels = Vec::with_capacity(n);
    for (corner, label) in prompt.corners.iter().zip([2.0, 3.0]) {
        coords.extend(fit.in_square(*corner));
        labels.push(label);
    }
    for p in prompt.points.iter().take(n.saturating_sub(2)) {
        coords.extend(fit.in_square(*p));
        labels.push(1.0);
    }
    while labels.len() < n {
        coords.extend([0.0, 0.0]);
        labels.push(-1.0);
    }
    (coords, labels)
}

/// The prompt of a render whose signed distance (positive inside, pixels) is `depth`: its
/// bounding box grown by `band_px` and clamped to the frame, and up to `points` interior
/// points at least the band plus [`POINT_MARGIN_PX`] deep, each the deepest pixel farther
/// than twice its own depth from those already taken. `None` for an empty render.
pub fn prompt_of(depth: &[f32], w: usize, h: usize, band_px: f32, points: usize) -> Option<Prompt> {
    let (mut x0, mut y0, mut x1, mut y1) = (usize::MAX, usize::MAX, 0, 0);
    for (i, _) in depth.iter().enumerate().filter(|(_, &d)| d > 0.0) {
        let (x, y) = (i % w, i / w);
        (x0, y0, x1, y1) = (x0.min(x), y0.min(y), x1.max(x), y1.max(y));
    }
    if x0 == usize::MAX {
        return None;
    }
    let grow = band_px.max(0.0);
    let corners = [
        [(x0 as f32 - grow).max(0.0), (y0 as f32 - grow).max(0.0)],
        [
            (x1 as f32 + grow).min((w - 1) as f32),
            (y1 as f32 + grow).min((h - 1) as f32),
        ],
    ];
    let deep_enough = grow + POINT_MARGIN_PX;
    let mut taken: Vec<([f32; 2], f32)> = Vec::with_capacity(points);
    while taken.len() < points {
        let best = depth
            .iter()
            .enumerate()
            .filter(|(_, &d)| d >= deep_enough)
            .map(|(i, &d)| ([(i % w) as f32, (i / w) as f32], d))
            .filter(|(p, _)| {
                taken
                    .iter()
                    .all(|(q, dq)| (p[0] - q[0]).hypot(p[1] - q[1]) > 2.0 * dq)
            })
            .max_by(|a, b| a.1.total_cmp(&b.1));
        match best {
            Some(point) => taken.push(point),
            None => break,
        }
    }
    Some(Prompt {
        corners,
        points: taken.into_iter().map(|(p, _)| p).collect(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::segment::builtin::signed_distance;

    /// Signed distances of a `w`x`h` frame with a filled rectangle (a crude but exact-enough
    /// render for the prompt's geometry).
    fn rectangle_depth(w: usize, h: usize, x0: usize, y0: usize, x1: usize, y1: usize) -> Vec<f32> {
        let mut mask = Mask::new(w as u32, h as u32);
        for y in y0..=y1 {
            for x in x0..=x1 {
                mask.data[y * w + x] = 1;
            }
        }
        signed_distance(&mask, w, h)
    }

    #[test]
    fn the_box_is_the_render_grown_by_the_band_and_kept_in_the_frame() {
        let depth = rectangle_depth(100, 80, 10, 20, 59, 29);
        let p = prompt_of(&depth, 100, 80, 15.0, 0).unwrap();
        assert_eq!(p.corners, [[0.0, 5.0], [74.0, 44.0]]);
        assert!(p.points.is_empty());
        assert!(prompt_of(&vec![-1.0; 100 * 80], 100, 80, 4.0, 3).is_none());
    }

    #[test]
    fn interior_points_are_deep_and_spread_and_none_where_the_render_is_thin() {
        // A 60x20 bar: its deepest pixels run along the middle row, 10 px deep.
        let depth = rectangle_depth(100, 60, 20, 20, 79, 39);
        let p = prompt_of(&depth, 100, 60, 4.0, 3).unwrap();
        assert!(!p.points.is_empty(), "{p:?}");
        for (k, a) in p.points.iter().enumerate() {
            let d = depth[a[1] as usize * 100 + a[0] as usize];
            assert!(d >= 4.0 + POINT_MARGIN_PX, "point {a:?} only {d} px deep");
            for b in &p.points[k + 1..] {
                assert!((a[0] - b[0]).hypot(a[1] - b[1]) > 2.0 * d - 1e-3, "{p:?}");
            }
        }
        // With a band wider than the bar is deep, no point is sure to be on the robot.
        let thin = prompt_of(&depth, 100, 60, 9.0, 3).unwrap();
        assert!(thin.points.is_empty(), "{thin:?}");
    }

    #[test]
    fn the_prompt_goes_in_as_box_corners_then_points_then_padding() {
        let fit = Fit::of(200, 100, 64, SamResize::LongestSide);
        let prompt = Prompt {
            corners: [[10.0, 20.0], [59.0, 44.0]],
            points: vec![[30.0, 30.0]],
        };
        let (coords, labels) = prompt_tensors(&prompt, &fit, 4);
        assert_eq!(labels, vec![2.0, 3.0, 1.0, -1.0]);
        let square = |x: f32| (x + 0.5) * 0.32 - 0.5;
        let expected = [
            square(10.0),
            square(20.0),
            square(59.0),
            square(44.0),
            square(30.0),
            square(30.0),
            0.0,
            0.0,
        ];
        for (got, want) in coords.iter().zip(expected) {
            assert!((got - want).abs() < 1e-5, "{coords:?}");
        }
        // More points than the model takes are cut, never overflowing its shape.
        let (coords, labels) = prompt_tensors(&prompt, &fit, 2);
        assert_eq!((coords.len(), labels), (4, vec![2.0, 3.0]));
    }

    #[test]
    fn the_square_holds_the_frame_as_each_resize_says() {
        let fit = Fit::of(200, 100, 64, SamResize::LongestSide);
        assert_eq!((fit.width, fit.height), (64, 32));
        // Pixel centres map to pixel centres: the first pixel's centre lies a scale's half
        // pixel in, and the frame's outer edge on the content's edge.
        let [u, v] = fit.in_square([0.0, 0.0]);
        assert!((u - (0.5 * 0.32 - 0.5)).abs() < 1e-6, "{u}");
        assert!((v - (0.5 * 0.32 - 0.5)).abs() < 1e-6, "{v}");
        let [u, v] = fit.in_square([199.5, 99.5]);
        assert!(
            (u - 63.5).abs() < 1e-4 && (v - 31.5).abs() < 1e-4,
            "{u} {v}"
        );
        let fit = Fit::of(200, 100, 64, SamResize::Stretch);
        assert_eq!((fit.width, fit.height), (64, 64));
        let [u, v] = fit.in_square([199.5, 99.5]);
        assert!(
            (u - 63.5).abs() < 1e-4 && (v - 63.5).abs() < 1e-4,
            "{u} {v}"
        );
    }
}
