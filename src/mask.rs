//! Binary masks: PNG I/O, resampling, IoU, and the exact Euclidean distance transform the
//! solver's sub-pixel boundary residual is built on.

use std::path::Path;

use easyhec_drivers::MAX_IMAGE_SIDE;

use crate::error::{Error, Result};

/// A binary image, row-major, one byte per pixel (0 or 1).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Mask {
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// Row-major pixels, 0 = background, 1 = robot.
    pub data: Vec<u8>,
}

impl Mask {
    /// An all-background mask.
    pub fn new(width: u32, height: u32) -> Mask {
        Mask {
            width,
            height,
            data: vec![0; width as usize * height as usize],
        }
    }

    /// Pixel value (false outside the image).
    #[inline]
    pub fn get(&self, u: i64, v: i64) -> bool {
        u >= 0
            && v >= 0
            && u < i64::from(self.width)
            && v < i64::from(self.height)
            && self.data[(v as usize) * self.width as usize + u as usize] != 0
    }

    /// Sets one pixel.
    #[inline]
    pub fn set(&mut self, u: u32, v: u32, value: bool) {
        self.data[v as usize * self.width as usize + u as usize] = u8::from(value);
    }

    /// Value of the pixel containing continuous position `(x, y)` (centres at integers).
    #[inline]
    pub fn at(&self, x: f64, y: f64) -> bool {
        self.get(x.round() as i64, y.round() as i64)
    }

    /// Bilinear interpolation of the 0/1 values, clamped at the border.
    pub fn sample_bilinear(&self, x: f64, y: f64) -> f64 {
        let (w, h) = (i64::from(self.width), i64::from(self.height));
        if x < -0.5 || y < -0.5 || x > w as f64 - 0.5 || y > h as f64 - 0.5 {
            return 0.0;
        }
        self.sample_bilinear_clamped(x, y)
    }

    /// Bilinear interpolation that extends the image by repeating its border pixels: outside
    /// the image, the robot continues as it leaves the frame and background stays background.
    pub fn sample_bilinear_clamped(&self, x: f64, y: f64) -> f64 {
        let (w, h) = (i64::from(self.width), i64::from(self.height));
        let (x, y) = (x.clamp(-0.5, w as f64 - 0.5), y.clamp(-0.5, h as f64 - 0.5));
        let x0 = x.floor();
        let y0 = y.floor();
        let (fx, fy) = (x - x0, y - y0);
        let g =
            |u: i64, v: i64| f64::from(u8::from(self.get(u.clamp(0, w - 1), v.clamp(0, h - 1))));
        let (u, v) = (x0 as i64, y0 as i64);
        (1.0 - fy) * ((1.0 - fx) * g(u, v) + fx * g(u + 1, v))
            + fy * ((1.0 - fx) * g(u, v + 1) + fx * g(u + 1, v + 1))
    }

    /// Mid-points between 4-adjacent pixel centres where the mask changes: the outline's
    /// crossings of the pixel grid, as the observed side of the boundary residual uses them.
    pub fn outline_crossings(&self) -> Vec<[f64; 2]> {
        let (w, h) = (i64::from(self.width), i64::from(self.height));
        let mut out = Vec::new();
        for v in 0..h {
            for u in 0..w {
                let here = self.get(u, v);
                if u + 1 < w && self.get(u + 1, v) != here {
                    out.push([u as f64 + 0.5, v as f64]);
                }
                if v + 1 < h && self.get(u, v + 1) != here {
                    out.push([u as f64, v as f64 + 0.5]);
                }
            }
        }
        out
    }

    /// Where `self`'s outline lies against `reference`'s: for every crossing of the
    /// reference's outline with a pixel row or column, the signed distance (pixels, positive
    /// when `self` reaches further out of the robot) to the nearest crossing of `self` of the
    /// same sense on that row or column, within `reach_px`; crossings with none are left out.
    /// A mean near 0 means no boundary bias, whatever the holes or blobs (those find no match
    /// or are counted by the IoU).
    pub fn boundary_offsets(&self, reference: &Mask, reach_px: u32) -> Vec<f64> {
        let (w, h) = (i64::from(reference.width), i64::from(reference.height));
        let reach = i64::from(reach_px);
        let mut out = Vec::new();
        // One line (row when `rows`) through `fixed`; `at(mask, k)` reads position k on it.
        let mut scan = |len: i64, at: &dyn Fn(&Mask, i64) -> bool| {
            for k in 0..len - 1 {
                let (a, b) = (at(reference, k), at(reference, k + 1));
                if a == b {
                    continue;
                }
                // Outward is towards the background side: +1 when the robot is at k.
                let outward = if a { 1 } else { -1 };
                let same_sense =
                    |j: i64| j >= 0 && j + 1 < len && at(self, j) == a && at(self, j + 1) == b;
                // The nearest match; a tie between outward and inward is ambiguous and skipped.
                let found = (0..=reach).find_map(|d| {
                    match (same_sense(k + d * outward), same_sense(k - d * outward)) {
                        (true, true) if d > 0 => Some(None),
                        (true, _) => Some(Some(d as f64)),
                        (false, true) => Some(Some(-d as f64)),
                        (false, false) => None,
                    }
                });
                out.extend(found.flatten());
            }
        };
        for v in 0..h {
            scan(w, &|m: &Mask, k| m.get(k, v));
        }
        for u in 0..w {
            scan(h, &|m: &Mask, k| m.get(u, k));
        }
        out
    }

    /// Number of robot pixels.
    pub fn count(&self) -> usize {
        self.data.iter().filter(|&&v| v != 0).count()
    }

    /// Intersection over union; 1.0 when both are empty.
    pub fn iou(&self, other: &Mask) -> f64 {
        let (mut inter, mut union) = (0usize, 0usize);
        for (a, b) in self.data.iter().zip(&other.data) {
            inter += usize::from(*a != 0 && *b != 0);
            union += usize::from(*a != 0 || *b != 0);
        }
        if union == 0 {
            1.0
        } else {
            inter as f64 / union as f64
        }
    }

    /// Box-filter downsampling by an integer factor: a pixel is robot when at least half of the
    /// source pixels it covers are.
    pub fn downsample(&self, factor: u32) -> Mask {
        if factor == 1 {
            return self.clone();
        }
        let (w, h, set, count) = self.block_counts(factor);
        Mask {
            width: w,
            height: h,
            data: set
                .iter()
                .zip(&count)
                .map(|(&s, &c)| u8::from(2 * s >= c))
                .collect(),
        }
    }

    /// The fraction of robot pixels in each `factor` x `factor` block, row-major over the
    /// [`Mask::downsample`]d size (an edge block counts only the pixels it covers).
    pub fn block_fractions(&self, factor: u32) -> Vec<f32> {
        let (_, _, set, count) = self.block_counts(factor.max(1));
        set.iter()
            .zip(&count)
            .map(|(&s, &c)| s as f32 / c.max(1) as f32)
            .collect()
    }

    /// Per `factor` x `factor` block: the downsampled width and height, the robot pixels and
    /// all pixels of each block.
    fn block_counts(&self, factor: u32) -> (u32, u32, Vec<u32>, Vec<u32>) {
        let (w, h) = (self.width.div_ceil(factor), self.height.div_ceil(factor));
        let mut set = vec![0u32; (w * h) as usize];
        let mut count = vec![0u32; (w * h) as usize];
        for v in 0..self.height {
            for u in 0..self.width {
                let i = ((v / factor) * w + u / factor) as usize;
                set[i] += u32::from(self.data[(v * self.width + u) as usize] != 0);
                count[i] += 1;
            }
        }
        (w, h, set, count)
    }

    /// The width and height a mask file's header states (see [`image_size`]).
    pub fn dimensions(path: &Path) -> Result<(u32, u32)> {
        image_size(path, "mask")
    }

    /// Reads an 8-bit (or any) PNG/JPEG; a pixel >= 128 in its first channel is robot.
    pub fn load(path: &Path) -> Result<Mask> {
        Mask::dimensions(path)?;
        let img = image::open(path)
            .map_err(|e| Error::input(path, "mask", format!("cannot decode image: {e}")))?;
        let grey = img.to_luma8();
        Ok(Mask {
            width: grey.width(),
            height: grey.height(),
            data: grey.pixels().map(|p| u8::from(p.0[0] >= 128)).collect(),
        })
    }

    /// Encodes as an 8-bit grey PNG (0 / 255).
    pub fn to_png_bytes(&self) -> Vec<u8> {
        let buf: Vec<u8> = self
            .data
            .iter()
            .map(|&v| if v != 0 { 255 } else { 0 })
            .collect();
        let img =
            image::GrayImage::from_raw(self.width, self.height, buf).expect("buffer size matches");
        let mut out = std::io::Cursor::new(Vec::new());
        img.write_to(&mut out, image::ImageFormat::Png)
            .expect("PNG encoding to memory cannot fail");
        out.into_inner()
    }
}

/// The width and height a PNG/JPEG's header states, refused beyond [`MAX_IMAGE_SIDE`]; errors
/// name `field`. A small file can state a huge image, so this is read before any decode, and
/// only from a regular file (a FIFO or a device would block the read). `io` sits in this
/// module's layer, so its file check is not shared here.
pub fn image_size(path: &Path, field: &str) -> Result<(u32, u32)> {
    let meta = std::fs::metadata(path).map_err(|e| Error::io(path, e))?;
    if !meta.is_file() {
        return Err(Error::input(path, field, "is not a regular file"));
    }
    let (w, h) = image::image_dimensions(path)
        .map_err(|e| Error::input(path, field, format!("cannot decode image: {e}")))?;
    if w.max(h) > MAX_IMAGE_SIDE {
        return Err(Error::input(
            path,
            field,
            format!("is {w}x{h} px; allowed: sides up to {MAX_IMAGE_SIDE}"),
        ));
    }
    Ok((w, h))
}

impl Mask {
    /// This mask with its outline moved outward by `px` pixels (inward when negative), to
    /// the nearest pixel: what a segmenter `px` fatter would have drawn.
    pub fn with_outline_offset(&self, px: f64) -> Mask {
        if px == 0.0 {
            return self.clone();
        }
        let sdf = SignedDistance::of(self);
        let mut out = self.clone();
        for (o, &d) in out.data.iter_mut().zip(&sdf.data) {
            *o = u8::from(f64::from(d) < px);
        }
        out
    }
}

/// Signed distance field of a mask's boundary, pixels: negative inside the robot, positive
/// outside, zero half-way between a robot pixel and a background pixel. Pixels outside the
/// image do not count as background (an image border is not a robot boundary).
#[derive(Clone, Debug)]
pub struct SignedDistance {
    /// Width, pixels.
    pub width: u32,
    /// Height, pixels.
    pub height: u32,
    /// Row-major distances.
    pub data: Vec<f32>,
}

/// Largest distance stored; farther pixels saturate (keeps robust weights meaningful).
const SDF_CAP_PX: f32 = 1.0e4;

impl SignedDistance {
    /// Exact EDT (Felzenszwalb–Huttenlocher) on both sides of the boundary.
    pub fn of(mask: &Mask) -> SignedDistance {
        let (w, h) = (mask.width as usize, mask.height as usize);
        let to_bg = edt_squared(w, h, |i| mask.data[i] == 0);
        let to_fg = edt_squared(w, h, |i| mask.data[i] != 0);
        let data = (0..w * h)
            .map(|i| {
                if mask.data[i] != 0 {
                    -(to_bg[i].sqrt() - 0.5).min(SDF_CAP_PX)
                } else {
                    (to_fg[i].sqrt() - 0.5).min(SDF_CAP_PX)
                }
            })
            .collect();
        SignedDistance {
            width: mask.width,
            height: mask.height,
            data,
        }
    }

    /// Bilinear value and gradient at `(x, y)`; `None` outside the pixel-centre grid.
    #[inline]
    pub fn sample(&self, x: f64, y: f64) -> Option<(f64, [f64; 2])> {
        let (w, h) = (self.width as usize, self.height as usize);
        if !(x >= 0.0 && y >= 0.0) || x > (w - 1) as f64 || y > (h - 1) as f64 {
            return None;
        }
        let u = (x.floor() as usize).min(w.saturating_sub(2));
        let v = (y.floor() as usize).min(h.saturating_sub(2));
        let (fx, fy) = (x - u as f64, y - v as f64);
        let g = |uu: usize, vv: usize| f64::from(self.data[vv * w + uu]);
        let (a, b, c, d) = (g(u, v), g(u + 1, v), g(u, v + 1), g(u + 1, v + 1));
        let value = (1.0 - fy) * ((1.0 - fx) * a + fx * b) + fy * ((1.0 - fx) * c + fx * d);
        let dx = (1.0 - fy) * (b - a) + fy * (d - c);
        let dy = (1.0 - fx) * (c - a) + fx * (d - b);
        Some((value, [dx, dy]))
    }
}

/// Squared Euclidean distance from every pixel to the nearest pixel where `is_site` holds
/// (infinite when there is none).
pub fn edt_squared(w: usize, h: usize, is_site: impl Fn(usize) -> bool) -> Vec<f32> {
    const INF: f32 = 1.0e20;
    let mut grid: Vec<f32> = (0..w * h)
        .map(|i| if is_site(i) { 0.0 } else { INF })
        .collect();
    let n = w.max(h);
    let mut f = vec![0f32; n];
    let mut d = vec![0f32; n];
    let mut vtx = vec![0usize; n];
    let mut z = vec![0f32; n + 1];
    // Columns then rows.
    for x in 0..w {
        for y in 0..h {
            f[y] = grid[y * w + x];
        }
        dt_1d(&f[..h], &mut d[..h], &mut vtx, &mut z);
        for y in 0..h {
            grid[y * w + x] = d[y];
        }
    }
    for y in 0..h {
        f[..w].copy_from_slice(&grid[y * w..(y + 1) * w]);
        dt_1d(&f[..w], &mut d[..w], &mut vtx, &mut z);
        grid[y * w..(y + 1) * w].copy_from_slice(&d[..w]);
    }
    grid
}

/// One-dimensional squared-distance transform of sampled function `f` (lower envelope of
/// parabolas).
fn dt_1d(f: &[f32], d: &mut [f32], v: &mut [usize], z: &mut [f32]) {
    let n = f.len();
    if n == 0 {
        return;
    }
    let mut k = 0usize;
    v[0] = 0;
    z[0] = f32::NEG_INFINITY;
    z[1] = f32::INFINITY;
    for q in 1..n {
        loop {
            let p = v[k];
            let s = ((f[q] + (q * q) as f32) - (f[p] + (p * p) as f32))
                / (2.0 * q as f32 - 2.0 * p as f32);
            if s <= z[k] && k > 0 {
                k -= 1;
                continue;
            }
            if s <= z[k] {
                // k == 0: replace the only parabola.
                v[0] = q;
                z[0] = f32::NEG_INFINITY;
                z[1] = f32::INFINITY;
                break;
            }
            k += 1;
            v[k] = q;
            z[k] = s;
            z[k + 1] = f32::INFINITY;
            break;
        }
    }
    k = 0;
    for (q, dq) in d.iter_mut().enumerate().take(n) {
        while z[k + 1] < q as f32 {
            k += 1;
        }
        let p = v[k];
        let diff = q as f32 - p as f32;
        *dq = diff * diff + f[p];
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn square(size: u32, lo: u32, hi: u32) -> Mask {
        let mut m = Mask::new(size, size);
        for v in lo..hi {
            for u in lo..hi {
                m.set(u, v, true);
            }
        }
        m
    }

    #[test]
    fn block_fractions_count_only_the_pixels_an_edge_block_covers() {
        let mut m = Mask::new(10, 3);
        for u in [0, 1, 8, 9] {
            m.set(u, 0, true);
        }
        // 8x8 blocks: the first covers 8x3 pixels (2 set), the second 2x3 (2 set).
        let f = m.block_fractions(8);
        assert_eq!(f.len(), 2);
        assert!((f[0] - 2.0 / 24.0).abs() < 1e-6, "{f:?}");
        assert!((f[1] - 2.0 / 6.0).abs() < 1e-6, "{f:?}");
        // Downsampling thresholds the same counts at one half.
        assert_eq!(m.downsample(8).data, vec![0, 0]);
        m.set(9, 1, true);
        assert_eq!(m.downsample(8).data, vec![0, 1]);
    }

    #[test]
    fn boundary_offsets_measure_a_grown_outline_outward() {
        let reference = square(40, 10, 30);
        let grown = square(40, 9, 31);
        let offsets = grown.boundary_offsets(&reference, 4);
        // Every row and column crossing the square twice: 2 x 20 x 2 crossings.
        assert_eq!(offsets.len(), 80);
        assert!(offsets.iter().all(|&d| d == 1.0), "{offsets:?}");
        let shrunk = square(40, 12, 28);
        let inward = shrunk.boundary_offsets(&reference, 4);
        // Rows and columns 10, 11, 28 and 29 no longer cross `shrunk`.
        assert_eq!(inward.len(), 64);
        assert!(inward.iter().all(|&d| d == -2.0), "{inward:?}");
        assert!(shrunk.boundary_offsets(&reference, 1).is_empty());
    }

    #[test]
    fn edt_matches_brute_force() {
        let (w, h) = (23usize, 17usize);
        let sites: Vec<bool> = (0..w * h).map(|i| (i * 7919) % 37 == 0).collect();
        let fast = edt_squared(w, h, |i| sites[i]);
        for y in 0..h {
            for x in 0..w {
                let mut best = f32::INFINITY;
                for yy in 0..h {
                    for xx in 0..w {
                        if sites[yy * w + xx] {
                            let d =
                                ((x as f32 - xx as f32).powi(2)) + ((y as f32 - yy as f32).powi(2));
                            best = best.min(d);
                        }
                    }
                }
                assert_eq!(fast[y * w + x], best, "at {x},{y}");
            }
        }
    }

    #[test]
    fn sdf_zero_crossing_is_half_way() {
        let mut m = Mask::new(20, 10);
        for v in 0..10 {
            for u in 0..8 {
                m.set(u, v, true);
            }
        }
        let s = SignedDistance::of(&m);
        let (at_edge, grad) = s.sample(7.5, 5.0).unwrap();
        assert!(at_edge.abs() < 1e-6, "{at_edge}");
        assert!((grad[0] - 1.0).abs() < 1e-6 && grad[1].abs() < 1e-6);
        assert!((s.sample(10.0, 5.0).unwrap().0 - 2.5).abs() < 1e-6);
    }
}
