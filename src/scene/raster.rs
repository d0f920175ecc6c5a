//! Triangle scan conversion for the colour frames: a z-buffer that keeps, per pixel, the
//! nearest triangle's index (shading happens afterwards, once per pixel), and an orthographic
//! shadow map seen from a directional light.

use nalgebra::{Point3, Vector3};

use crate::camera::Intrinsics;

/// Calls `f(x, y, [w0, w1, w2])` for every pixel centre of a `width` x `height` grid inside the
/// 2-D triangle `p` (barycentric weights of `p[0]`, `p[1]`, `p[2]`).
fn for_each_covered_pixel(
    p: [[f64; 2]; 3],
    width: usize,
    height: usize,
    mut f: impl FnMut(usize, usize, [f64; 3]),
) {
    let [pa, pb, pc] = p;
    let area = (pb[0] - pa[0]) * (pc[1] - pa[1]) - (pb[1] - pa[1]) * (pc[0] - pa[0]);
    if area.abs() < 1e-12 || !area.is_finite() {
        return;
    }
    let x0 = pa[0].min(pb[0]).min(pc[0]).floor().max(0.0);
    let y0 = pa[1].min(pb[1]).min(pc[1]).floor().max(0.0);
    let x1 = pa[0].max(pb[0]).max(pc[0]).ceil().min(width as f64 - 1.0);
    let y1 = pa[1].max(pb[1]).max(pc[1]).ceil().min(height as f64 - 1.0);
    if x1 < x0 || y1 < y0 {
        return;
    }
    let (x0, x1, y0, y1) = (x0 as usize, x1 as usize, y0 as usize, y1 as usize);
    for y in y0..=y1 {
        let py = y as f64;
        for x in x0..=x1 {
            let px = x as f64;
            let w0 = ((pb[0] - px) * (pc[1] - py) - (pb[1] - py) * (pc[0] - px)) / area;
            let w1 = ((pc[0] - px) * (pa[1] - py) - (pc[1] - py) * (pa[0] - px)) / area;
            let w2 = 1.0 - w0 - w1;
            if w0 >= 0.0 && w1 >= 0.0 && w2 >= 0.0 {
                f(x, y, [w0, w1, w2]);
            }
        }
    }
}

/// A depth buffer holding, per pixel, the nearest triangle's index (`u32::MAX`: none).
pub(crate) struct TriangleBuffer {
    /// Camera-frame depth of the nearest surface, metres (`INFINITY`: none).
    pub depth: Vec<f64>,
    /// Index of the triangle seen there.
    pub triangle: Vec<u32>,
}

impl TriangleBuffer {
    /// An empty buffer for `width * height` pixels.
    pub fn new(pixels: usize) -> TriangleBuffer {
        TriangleBuffer {
            depth: vec![f64::INFINITY; pixels],
            triangle: vec![u32::MAX; pixels],
        }
    }

    /// Whether a triangle covers pixel `i`.
    pub fn covered(&self, i: usize) -> bool {
        self.triangle[i] != u32::MAX
    }

    /// Z-buffers camera-frame triangles (pinhole `cam`); triangle `k` is stored as index `k`.
    /// Triangles reaching closer than 5 cm to the camera are skipped, as the mask renderer does.
    pub fn draw(&mut self, cam: &Intrinsics, triangles_in_camera: &[[Point3<f64>; 3]]) {
        let (w, h) = (cam.width as usize, cam.height as usize);
        for (k, tri) in triangles_in_camera.iter().enumerate() {
            let [a, b, c] = tri;
            if a.z < 0.05 || b.z < 0.05 || c.z < 0.05 {
                continue;
            }
            let inv_z = [1.0 / a.z, 1.0 / b.z, 1.0 / c.z];
            let projected = [cam.project(a), cam.project(b), cam.project(c)];
            for_each_covered_pixel(projected, w, h, |x, y, bary| {
                let z = 1.0 / (bary[0] * inv_z[0] + bary[1] * inv_z[1] + bary[2] * inv_z[2]);
                let i = y * w + x;
                if z < self.depth[i] {
                    self.depth[i] = z;
                    self.triangle[i] = k as u32;
                }
            });
        }
    }
}

/// Depth of the scene seen from a directional light, on a regular grid in a plane across the
/// light's direction: a point is in shadow when something sits between it and the light.
pub(crate) struct ShadowMap {
    /// Unit vector from the scene towards the light, base frame.
    to_light: Vector3<f64>,
    /// Grid axes across the light, base frame.
    axis_u: Vector3<f64>,
    axis_v: Vector3<f64>,
    /// Grid origin (light-plane coordinates of cell 0's centre) and cell size, metres.
    origin: [f64; 2],
    cell_m: f64,
    width: usize,
    height: usize,
    /// Per cell, the highest `p · to_light` of any caster (nearest to the light).
    nearest: Vec<f64>,
}

impl ShadowMap {
    /// Rasterises `casters` (base-frame triangles) as seen from `to_light` (need not be unit
    /// length) on a grid of `cell_m` cells.
    pub fn build(casters: &[[Point3<f64>; 3]], to_light: &Vector3<f64>, cell_m: f64) -> ShadowMap {
        let to_light = to_light.try_normalize(1e-12).unwrap_or_else(Vector3::z);
        let helper = if to_light.x.abs() < 0.9 {
            Vector3::x()
        } else {
            Vector3::y()
        };
        let axis_u = to_light.cross(&helper).normalize();
        let axis_v = to_light.cross(&axis_u);
        let mut lo = [f64::INFINITY; 2];
        let mut hi = [f64::NEG_INFINITY; 2];
        for p in casters.iter().flatten() {
            let uv = [p.coords.dot(&axis_u), p.coords.dot(&axis_v)];
            for k in 0..2 {
                lo[k] = lo[k].min(uv[k]);
                hi[k] = hi[k].max(uv[k]);
            }
        }
        if casters.is_empty() {
            lo = [0.0; 2];
            hi = [0.0; 2];
        }
        // Two spare cells on each side keep filtered look-ups at the edges inside the grid.
        let origin = [lo[0] - 2.0 * cell_m, lo[1] - 2.0 * cell_m];
        let width = ((hi[0] - lo[0]) / cell_m).ceil() as usize + 5;
        let height = ((hi[1] - lo[1]) / cell_m).ceil() as usize + 5;
        let mut map = ShadowMap {
            to_light,
            axis_u,
            axis_v,
            origin,
            cell_m,
            width,
            height,
            nearest: vec![f64::NEG_INFINITY; width * height],
        };
        for tri in casters {
            let grid = tri.map(|p| map.grid_of(&p));
            let toward = tri.map(|p| p.coords.dot(&map.to_light));
            let (w, h) = (map.width, map.height);
            let nearest = &mut map.nearest;
            for_each_covered_pixel(grid, w, h, |x, y, bary| {
                let d = bary[0] * toward[0] + bary[1] * toward[1] + bary[2] * toward[2];
                let i = y * w + x;
                if d > nearest[i] {
                    nearest[i] = d;
                }
            });
        }
        map
    }

    /// Grid coordinates (cell centres at integers) of a base-frame point.
    fn grid_of(&self, p: &Point3<f64>) -> [f64; 2] {
        [
            (p.coords.dot(&self.axis_u) - self.origin[0]) / self.cell_m,
            (p.coords.dot(&self.axis_v) - self.origin[1]) / self.cell_m,
        ]
    }

    /// Fraction (0 = lit, 1 = fully shadowed) of a 3x3 cell neighbourhood around `p` whose
    /// casters lie more than `bias_m` nearer to the light than `p`: soft-edged shadows.
    pub fn shadowed_fraction(&self, p: &Point3<f64>, bias_m: f64) -> f64 {
        let [gx, gy] = self.grid_of(p);
        let (cx, cy) = (gx.round(), gy.round());
        if cx < 1.0 || cy < 1.0 || cx >= (self.width - 1) as f64 || cy >= (self.height - 1) as f64 {
            return 0.0;
        }
        let (cx, cy) = (cx as usize, cy as usize);
        let d = p.coords.dot(&self.to_light) + bias_m;
        let mut hits = 0u32;
        for y in cy - 1..=cy + 1 {
            for x in cx - 1..=cx + 1 {
                if self.nearest[y * self.width + x] > d {
                    hits += 1;
                }
            }
        }
        f64::from(hits) / 9.0
    }
}

/// The twelve triangles of a box with half sizes `half_m`, turned by `yaw_rad` about z and
/// centred at `centre` (base frame).
pub(crate) fn box_triangles(
    centre: &Point3<f64>,
    half_m: [f64; 3],
    yaw_rad: f64,
) -> Vec<[Point3<f64>; 3]> {
    let (s, c) = yaw_rad.sin_cos();
    let corner = |i: usize| {
        let lx = if i & 1 == 0 { -half_m[0] } else { half_m[0] };
        let ly = if i & 2 == 0 { -half_m[1] } else { half_m[1] };
        let lz = if i & 4 == 0 { -half_m[2] } else { half_m[2] };
        centre + Vector3::new(c * lx - s * ly, s * lx + c * ly, lz)
    };
    // Faces as corner-index quads: -x, +x, -y, +y, -z, +z.
    const FACES: [[usize; 4]; 6] = [
        [0, 2, 6, 4],
        [1, 5, 7, 3],
        [0, 4, 5, 1],
        [2, 3, 7, 6],
        [0, 1, 3, 2],
        [4, 6, 7, 5],
    ];
    FACES
        .iter()
        .flat_map(|q| {
            [
                [corner(q[0]), corner(q[1]), corner(q[2])],
                [corner(q[0]), corner(q[2]), corner(q[3])],
            ]
        })
        .collect()
}

/// Triangles of a capsule-like limb: a cylinder of `radius_m` from `a` to `b` with a sphere at
/// each end, so chained limbs join without gaps.
pub(crate) fn limb_triangles(
    a: &Point3<f64>,
    b: &Point3<f64>,
    radius_m: f64,
) -> Vec<[Point3<f64>; 3]> {
    const SEGMENTS: usize = 12;
    let axis = (b - a).try_normalize(1e-12).unwrap_or_else(Vector3::z);
    let helper = if axis.x.abs() < 0.9 {
        Vector3::x()
    } else {
        Vector3::y()
    };
    let e1 = axis.cross(&helper).normalize();
    let e2 = axis.cross(&e1);
    let ring = |centre: &Point3<f64>, k: usize| {
        let t = std::f64::consts::TAU * k as f64 / SEGMENTS as f64;
        centre + (e1 * t.cos() + e2 * t.sin()) * radius_m
    };
    let mut out = Vec::with_capacity(SEGMENTS * 2 + 2 * SEGMENTS * 12);
    for k in 0..SEGMENTS {
        let (a0, a1, b0, b1) = (ring(a, k), ring(a, k + 1), ring(b, k), ring(b, k + 1));
        out.push([a0, a1, b1]);
        out.push([a0, b1, b0]);
    }
    for centre in [a, b] {
        out.extend(sphere_triangles(centre, radius_m));
    }
    out
}

/// A latitude-longitude sphere (6 bands, 12 sectors).
pub(crate) fn sphere_triangles(centre: &Point3<f64>, radius_m: f64) -> Vec<[Point3<f64>; 3]> {
    const BANDS: usize = 6;
    const SECTORS: usize = 12;
    let point = |band: usize, sector: usize| {
        let polar = std::f64::consts::PI * band as f64 / BANDS as f64;
        let azimuth = std::f64::consts::TAU * sector as f64 / SECTORS as f64;
        centre
            + Vector3::new(
                polar.sin() * azimuth.cos(),
                polar.sin() * azimuth.sin(),
                polar.cos(),
            ) * radius_m
    };
    let mut out = Vec::with_capacity(BANDS * SECTORS * 2);
    for band in 0..BANDS {
        for sector in 0..SECTORS {
            let (p00, p01) = (point(band, sector), point(band, sector + 1));
            let (p10, p11) = (point(band + 1, sector), point(band + 1, sector + 1));
            out.push([p00, p10, p11]);
            out.push([p00, p11, p01]);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_box_shadows_the_ground_below_it_and_not_beside_it() {
        let cube = box_triangles(&Point3::new(0.0, 0.0, 0.5), [0.1; 3], 0.3);
        let map = ShadowMap::build(&cube, &Vector3::z(), 0.01);
        assert_eq!(
            map.shadowed_fraction(&Point3::new(0.0, 0.0, 0.0), 0.01),
            1.0
        );
        assert_eq!(
            map.shadowed_fraction(&Point3::new(0.5, 0.0, 0.0), 0.01),
            0.0
        );
        // The box's own top face is not in its shadow.
        assert_eq!(
            map.shadowed_fraction(&Point3::new(0.0, 0.0, 0.6), 0.01),
            0.0
        );
    }

    #[test]
    fn the_nearest_triangle_wins_each_pixel() {
        let cam = Intrinsics::pinhole(40, 30, 30.0, 30.0, 20.0, 15.0);
        let far = [
            Point3::new(-1.0, -1.0, 2.0),
            Point3::new(1.0, -1.0, 2.0),
            Point3::new(0.0, 1.0, 2.0),
        ];
        let near = far.map(|p| Point3::new(p.x * 0.5, p.y * 0.5, 1.0));
        let mut buffer = TriangleBuffer::new(40 * 30);
        buffer.draw(&cam, &[far, near]);
        let centre = 15 * 40 + 20;
        assert_eq!(buffer.triangle[centre], 1);
        assert!((buffer.depth[centre] - 1.0).abs() < 1e-9);
        assert!(!buffer.covered(0));
    }
}
