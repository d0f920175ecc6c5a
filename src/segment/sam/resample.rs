//! Resizing a frame into the encoder's square as the SAM families' own preprocessing does.
//!
//! SAM's published preprocessing scales an image with PIL's bilinear resize and SAM 2's with
//! torchvision's antialiased one: both are a triangle filter whose width grows with the
//! reduction, so each output pixel averages the frame pixels it covers. Plain bilinear
//! sampling reads only the four nearest pixels: fitting a 1920x1080 frame into 1024, it weighs
//! some frame pixels seven times as much as others (a 4K frame: nearly half the columns not at
//! all), so a thin edge shows or not by where it falls, and fine texture aliases into patterns
//! the encoder never saw. When enlarging, the filter is exactly bilinear interpolation.

/// One output pixel's taps along one axis: the first input index and the normalised weights
/// of it and the indices after it.
struct Taps {
    first: usize,
    weights: Vec<f32>,
}

/// The taps of every output pixel when `n` input pixels become `out` (pixel centres at
/// integer coordinates on both sides), clamped to the input.
fn axis_taps(n: usize, out: usize) -> Vec<Taps> {
    let scale = out as f64 / n as f64;
    let support = (1.0 / scale).max(1.0);
    (0..out)
        .map(|o| {
            let centre = ((o as f64 + 0.5) / scale - 0.5).clamp(0.0, (n - 1) as f64);
            let lo = ((centre - support).floor() as i64 + 1).max(0) as usize;
            let hi = ((centre + support).ceil() as i64 - 1).min(n as i64 - 1) as usize;
            let raw: Vec<f64> = (lo..=hi)
                .map(|i| (1.0 - (i as f64 - centre).abs() / support).max(0.0))
                .collect();
            let total: f64 = raw.iter().sum();
            Taps {
                first: lo,
                weights: raw.iter().map(|w| (w / total) as f32).collect(),
            }
        })
        .collect()
}

/// `rgb` (interleaved, `w`x`h`) resized to `out_w`x`out_h`, as three planes of `f32` (R, G,
/// B, each row-major `out_w`x`out_h`).
pub(super) fn resized_planes(
    rgb: &[u8],
    w: usize,
    h: usize,
    out_w: usize,
    out_h: usize,
) -> [Vec<f32>; 3] {
    let rows = resized_rows(rgb, w, h, out_w);
    resized_columns(&rows, out_w, h, out_h)
}

/// Each of the `h` rows of `rgb` resized to `out_w` pixels, channels still interleaved.
fn resized_rows(rgb: &[u8], w: usize, h: usize, out_w: usize) -> Vec<f32> {
    let across = axis_taps(w, out_w);
    let mut rows = vec![0f32; h * out_w * 3];
    for (line, out) in rgb
        .chunks_exact(w * 3)
        .zip(rows.chunks_exact_mut(out_w * 3))
    {
        for (t, px) in across.iter().zip(out.chunks_exact_mut(3)) {
            for (k, &wt) in t.weights.iter().enumerate() {
                let at = (t.first + k) * 3;
                for c in 0..3 {
                    px[c] += wt * f32::from(line[at + c]);
                }
            }
        }
    }
    rows
}

/// The `h` rows of `rows` (`width` interleaved pixels each) resized to `out_h`, as planes.
fn resized_columns(rows: &[f32], width: usize, h: usize, out_h: usize) -> [Vec<f32>; 3] {
    let down = axis_taps(h, out_h);
    let mut planes = [
        vec![0f32; width * out_h],
        vec![0f32; width * out_h],
        vec![0f32; width * out_h],
    ];
    for (v, t) in down.iter().enumerate() {
        for (k, &wt) in t.weights.iter().enumerate() {
            let row = &rows[(t.first + k) * width * 3..(t.first + k + 1) * width * 3];
            for (u, px) in row.chunks_exact(3).enumerate() {
                for c in 0..3 {
                    planes[c][v * width + u] += wt * px[c];
                }
            }
        }
    }
    planes
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::segment::onnx::taps;

    /// A `w`x`h` frame whose channels vary independently and smoothly.
    fn gradient_frame(w: usize, h: usize) -> Vec<u8> {
        let mut rgb = Vec::with_capacity(w * h * 3);
        for y in 0..h {
            for x in 0..w {
                rgb.extend([
                    (x * 7 % 256) as u8,
                    (y * 11 % 256) as u8,
                    ((x + y) * 3 % 256) as u8,
                ]);
            }
        }
        rgb
    }

    #[test]
    fn enlarging_is_bilinear_interpolation() {
        let (w, h, out_w, out_h) = (13, 9, 31, 20);
        let rgb = gradient_frame(w, h);
        let planes = resized_planes(&rgb, w, h, out_w, out_h);
        let (sx, sy) = (out_w as f32 / w as f32, out_h as f32 / h as f32);
        for v in 0..out_h {
            let (y0, y1, ty) = taps((v as f32 + 0.5) / sy - 0.5, h);
            for u in 0..out_w {
                let (x0, x1, tx) = taps((u as f32 + 0.5) / sx - 0.5, w);
                for (c, plane) in planes.iter().enumerate() {
                    let p = |x: usize, y: usize| f32::from(rgb[(y * w + x) * 3 + c]);
                    let top = p(x0, y0) + (p(x1, y0) - p(x0, y0)) * tx;
                    let bottom = p(x0, y1) + (p(x1, y1) - p(x0, y1)) * tx;
                    let expected = top + (bottom - top) * ty;
                    let got = plane[v * out_w + u];
                    assert!(
                        (got - expected).abs() < 1e-3,
                        "({u},{v}) c{c}: {got} vs {expected}"
                    );
                }
            }
        }
    }

    #[test]
    fn reducing_weighs_every_frame_pixel_alike_along_both_axes() {
        // A 1920-pixel side (1080p's width) fitted into SAM's 1024: by linearity, the output
        // sum of a frame dark but for one pixel is that pixel's weight. Averaging gives every
        // pixel about 1024/1920 of one output pixel (within 3%; the two at each border a
        // little less); sampling the four nearest gives some 0.94 and others 0.13, so a thin
        // edge's place in the frame sets how much it shows.
        let (n, out) = (1920, 1024);
        let ideal = out as f32 / n as f32;
        for along_rows in [true, false] {
            let (w, h, out_w, out_h) = if along_rows {
                (n, 1, out, 1)
            } else {
                (1, n, 1, out)
            };
            for at in (2..n - 2).step_by(7) {
                let mut rgb = vec![0u8; n * 3];
                rgb[at * 3] = 255;
                let planes = resized_planes(&rgb, w, h, out_w, out_h);
                let weight = planes[0].iter().sum::<f32>() / 255.0;
                assert!(
                    (weight - ideal).abs() < 0.02,
                    "pixel {at} (along rows: {along_rows}) weighs {weight}, not about {ideal}"
                );
            }
        }
    }

    #[test]
    fn a_flat_frame_stays_flat_at_every_size() {
        let (w, h) = (37, 23);
        let rgb: Vec<u8> = (0..w * h).flat_map(|_| [10u8, 200, 77]).collect();
        for (out_w, out_h) in [(5, 3), (16, 16), (37, 23), (100, 61)] {
            let planes = resized_planes(&rgb, w, h, out_w, out_h);
            for (plane, want) in planes.iter().zip([10.0f32, 200.0, 77.0]) {
                assert!(
                    plane.iter().all(|p| (p - want).abs() < 1e-3),
                    "{out_w}x{out_h}"
                );
            }
        }
    }
}
