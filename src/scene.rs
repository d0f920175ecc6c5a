//! Colour frames of a simulated cell: a procedurally textured wall, floor and wooden table,
//! the robot shaded with a directional light (z-buffered triangles, two link colours like real
//! arms), Gaussian sensor noise and optional `plumb_bob` lens distortion. The ground-truth mask
//! comes from the same silhouette renderer the solver uses, warped by the same lens.
//!
//! Frames are meant to be realistic enough to develop a segmenter on: the robot's white links
//! sit on a light wall in places, the table's grain has edges, shading varies along links.

use std::sync::{Arc, RwLock};

use easyhec_drivers::Intrinsics;
use easyhec_mocks::{SceneFrame, SceneRenderer};
use nalgebra::{Isometry3, Point3, Vector3};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};
use serde::{Deserialize, Serialize};

use crate::camera::Camera;
use crate::render::{CpuRenderer, PosedRobot, SilhouetteRenderer};
use crate::robot::RobotModel;

/// Scene dressing.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct SceneSettings {
    /// Table top height in the base frame, metres (the base stands on it).
    #[serde(default)]
    pub table_height_m: f64,
    /// Table extent `[x_min, x_max, y_min, y_max]` in the base frame, metres.
    #[serde(default = "default_table")]
    pub table_extent_m: [f64; 4],
    /// Floor height, metres.
    #[serde(default = "default_floor")]
    pub floor_height_m: f64,
    /// Sensor noise standard deviation, grey levels (0–255).
    #[serde(default = "default_noise")]
    pub noise_sigma: f64,
    /// Seed of the sensor noise.
    #[serde(default)]
    pub seed: u64,
}

fn default_table() -> [f64; 4] {
    [-0.4, 1.0, -0.8, 0.8]
}
fn default_floor() -> f64 {
    -0.75
}
fn default_noise() -> f64 {
    2.5
}

impl Default for SceneSettings {
    fn default() -> Self {
        SceneSettings {
            table_height_m: 0.0,
            table_extent_m: default_table(),
            floor_height_m: default_floor(),
            noise_sigma: default_noise(),
            seed: 0,
        }
    }
}

/// A simulated camera's view of the cell from a fixed, true pose.
pub struct SimScene {
    robot: Arc<RobotModel>,
    camera: Camera,
    /// Behind a lock so tests can bump the camera ([`SimScene::set_camera_from_base`]).
    camera_from_base: RwLock<Isometry3<f64>>,
    intrinsics: Intrinsics,
    settings: SceneSettings,
}

/// Smooth value noise in [0, 1] (hash lattice, bilinear), for textures.
fn value_noise(x: f64, y: f64, seed: u32) -> f64 {
    fn hash(ix: i64, iy: i64, seed: u32) -> f64 {
        let mut h = (ix as u64).wrapping_mul(0x9E37_79B9_7F4A_7C15)
            ^ (iy as u64).wrapping_mul(0xC2B2_AE3D_27D4_EB4F)
            ^ u64::from(seed).wrapping_mul(0x1656_67B1_9E37_79F9);
        h ^= h >> 29;
        h = h.wrapping_mul(0xBF58_476D_1CE4_E5B9);
        h ^= h >> 32;
        (h & 0xFFFF) as f64 / 65535.0
    }
    let (fx, fy) = (x.floor(), y.floor());
    let (tx, ty) = (x - fx, y - fy);
    let (sx, sy) = (tx * tx * (3.0 - 2.0 * tx), ty * ty * (3.0 - 2.0 * ty));
    let (ix, iy) = (fx as i64, fy as i64);
    let a = hash(ix, iy, seed) * (1.0 - sx) + hash(ix + 1, iy, seed) * sx;
    let b = hash(ix, iy + 1, seed) * (1.0 - sx) + hash(ix + 1, iy + 1, seed) * sx;
    a * (1.0 - sy) + b * sy
}

fn fractal(x: f64, y: f64, seed: u32) -> f64 {
    (value_noise(x, y, seed) * 0.5
        + value_noise(x * 2.1, y * 2.1, seed + 1) * 0.3
        + value_noise(x * 4.3, y * 4.3, seed + 2) * 0.2)
        .clamp(0.0, 1.0)
}

impl SimScene {
    /// A scene seen by `camera` (possibly distorted) from `camera_from_base`.
    pub fn new(
        robot: Arc<RobotModel>,
        camera: Camera,
        camera_from_base: Isometry3<f64>,
        settings: SceneSettings,
    ) -> SimScene {
        let intrinsics = camera.intrinsics();
        SimScene {
            robot,
            camera,
            camera_from_base: RwLock::new(camera_from_base),
            intrinsics,
            settings,
        }
    }

    /// The true pose (tests and the final error report only).
    pub fn camera_from_base(&self) -> Isometry3<f64> {
        *self
            .camera_from_base
            .read()
            .unwrap_or_else(std::sync::PoisonError::into_inner)
    }

    /// Moves the simulated camera: what a knock against the tripod does. Frames rendered
    /// afterwards show the cell from `camera_from_base` (bump-detection tests).
    pub fn set_camera_from_base(&self, camera_from_base: Isometry3<f64>) {
        *self
            .camera_from_base
            .write()
            .unwrap_or_else(std::sync::PoisonError::into_inner) = camera_from_base;
    }

    fn background(&self, ray_base: &Vector3<f64>, eye: &Point3<f64>) -> [f64; 3] {
        let s = &self.settings;
        if ray_base.z < -1e-9 {
            let t = (s.table_height_m - eye.z) / ray_base.z;
            if t > 0.0 {
                let p = eye + ray_base * t;
                let [x0, x1, y0, y1] = s.table_extent_m;
                if p.x >= x0 && p.x <= x1 && p.y >= y0 && p.y <= y1 {
                    // Wood: grain along x, warped by noise, with darker plank seams.
                    let warp = fractal(p.x * 3.0, p.y * 3.0, 11) * 2.0;
                    let grain = 0.5 + 0.5 * (p.y * 90.0 + warp * 6.0).sin();
                    let seam = if (p.y * 5.0).fract().abs() < 0.02 {
                        0.6
                    } else {
                        1.0
                    };
                    let k = (0.78 + 0.22 * grain)
                        * seam
                        * (0.9 + 0.2 * fractal(p.x * 20.0, p.y * 2.0, 12));
                    return [0.66 * k, 0.49 * k, 0.33 * k];
                }
            }
            let t = (s.floor_height_m - eye.z) / ray_base.z;
            if t > 0.0 {
                let p = eye + ray_base * t;
                let tile = ((p.x * 2.0).floor() as i64 + (p.y * 2.0).floor() as i64).rem_euclid(2);
                let k =
                    if tile == 0 { 0.42 } else { 0.36 } + 0.08 * fractal(p.x * 8.0, p.y * 8.0, 13);
                return [k, k * 0.98, k * 0.95];
            }
        }
        // Walls: a cylinder of radius 3 m around the base, painted panels with noise.
        let az = ray_base.y.atan2(ray_base.x);
        let el = ray_base.z.atan2(ray_base.xy().norm());
        let panel = if ((az * 6.0 / std::f64::consts::PI).fract().abs()) < 0.015 {
            0.7
        } else {
            1.0
        };
        let k = (0.72 + 0.18 * fractal(az * 8.0, el * 8.0, 14)) * panel;
        [k * 0.92, k * 0.9, k * 0.85]
    }

    /// Renders the ideal pinhole colour image (linear 0..1) and the robot mask.
    fn render_pinhole(&self, q: &[f64]) -> (Vec<[f64; 3]>, crate::mask::Mask) {
        let cam = self.camera.undistorted();
        let (w, h) = (cam.width as usize, cam.height as usize);
        // One pose for the whole frame, even if a test bumps the camera meanwhile.
        let camera_from_base = self.camera_from_base();
        let base_from_camera = camera_from_base.inverse();
        let eye = Point3::from(base_from_camera.translation.vector);
        let rot = base_from_camera.rotation;
        let mut rgb: Vec<[f64; 3]> = Vec::with_capacity(w * h);
        for v in 0..h {
            for u in 0..w {
                let d = Vector3::new(
                    (u as f64 - cam.cx) / cam.fx,
                    (v as f64 - cam.cy) / cam.fy,
                    1.0,
                );
                rgb.push(self.background(&(rot * d), &eye));
            }
        }
        // Robot: z-buffered, flat-shaded, double-sided triangles.
        let posed = self.robot.posed_vertices(q);
        let in_cam: Vec<Point3<f64>> = posed.iter().map(|p| camera_from_base * p).collect();
        let mut depth = vec![f64::INFINITY; w * h];
        let light = Vector3::new(0.35, -0.75, -0.55).normalize();
        let mesh = &self.robot.visual;
        for tri in &mesh.triangles {
            let [a, b, c] = tri.map(|i| in_cam[i as usize]);
            if a.z < 0.05 || b.z < 0.05 || c.z < 0.05 {
                continue;
            }
            let mut n = (b - a).cross(&(c - a));
            let len = n.norm();
            if len < 1e-15 {
                continue;
            }
            n /= len;
            if n.dot(&a.coords) > 0.0 {
                n = -n;
            }
            let link = self.robot.vertex_link[tri[0] as usize] as usize;
            let albedo = if link.is_multiple_of(2) {
                [0.86, 0.86, 0.84]
            } else {
                [0.22, 0.22, 0.24]
            };
            let view = -a.coords.normalize();
            let half = (light + view).normalize();
            let diffuse = n.dot(&light).max(0.0);
            let spec = n.dot(&half).max(0.0).powi(24) * 0.25;
            let shade = 0.3 + 0.7 * diffuse;
            let colour = albedo.map(|c| (c * shade + spec).min(1.0));
            let [pa, pb, pc] = [a, b, c].map(|p| cam.project(&p));
            let area = (pb[0] - pa[0]) * (pc[1] - pa[1]) - (pb[1] - pa[1]) * (pc[0] - pa[0]);
            if area.abs() < 1e-12 {
                continue;
            }
            let x0 = pa[0].min(pb[0]).min(pc[0]).floor().max(0.0) as usize;
            let x1 = (pa[0].max(pb[0]).max(pc[0]).ceil() as i64).min(w as i64 - 1);
            let y0 = pa[1].min(pb[1]).min(pc[1]).floor().max(0.0) as usize;
            let y1 = (pa[1].max(pb[1]).max(pc[1]).ceil() as i64).min(h as i64 - 1);
            if x1 < 0 || y1 < 0 {
                continue;
            }
            let (iz_a, iz_b, iz_c) = (1.0 / a.z, 1.0 / b.z, 1.0 / c.z);
            for y in y0..=y1 as usize {
                for x in x0..=x1 as usize {
                    let (px, py) = (x as f64, y as f64);
                    let w0 = ((pb[0] - px) * (pc[1] - py) - (pb[1] - py) * (pc[0] - px)) / area;
                    let w1 = ((pc[0] - px) * (pa[1] - py) - (pc[1] - py) * (pa[0] - px)) / area;
                    let w2 = 1.0 - w0 - w1;
                    if w0 < 0.0 || w1 < 0.0 || w2 < 0.0 {
                        continue;
                    }
                    let z = 1.0 / (w0 * iz_a + w1 * iz_b + w2 * iz_c);
                    let i = y * w + x;
                    if z < depth[i] {
                        depth[i] = z;
                        rgb[i] = colour;
                    }
                }
            }
        }
        let robot = PosedRobot::new(&self.robot, q);
        let mask = CpuRenderer
            .render(&robot, &cam, &camera_from_base, None)
            .mask;
        (rgb, mask)
    }

    /// Renders one frame: colour (distorted, noisy, RGB8) and the true mask (distorted).
    pub fn frame(&self, q: &[f64], frame_index: u64) -> SceneFrame {
        let (pinhole, mask) = self.render_pinhole(q);
        let cam = &self.camera;
        let (w, h) = (cam.width as usize, cam.height as usize);
        let sample = |x: f64, y: f64| -> [f64; 3] {
            let x = x.clamp(0.0, (w - 1) as f64);
            let y = y.clamp(0.0, (h - 1) as f64);
            let (x0, y0) = (x.floor() as usize, y.floor() as usize);
            let (x1, y1) = ((x0 + 1).min(w - 1), (y0 + 1).min(h - 1));
            let (tx, ty) = (x - x0 as f64, y - y0 as f64);
            let p = |xx: usize, yy: usize| pinhole[yy * w + xx];
            let mut out = [0.0; 3];
            for (c, o) in out.iter_mut().enumerate() {
                let top = p(x0, y0)[c] * (1.0 - tx) + p(x1, y0)[c] * tx;
                let bottom = p(x0, y1)[c] * (1.0 - tx) + p(x1, y1)[c] * tx;
                *o = top * (1.0 - ty) + bottom * ty;
            }
            out
        };
        let mut rng =
            ChaCha8Rng::seed_from_u64(self.settings.seed ^ frame_index.wrapping_mul(0x9E37_79B9));
        let noise =
            Normal::new(0.0, self.settings.noise_sigma.max(0.0) + 1e-12).expect("finite sigma");
        let mut rgb = Vec::with_capacity(w * h * 3);
        for v in 0..h {
            for u in 0..w {
                let value = if cam.is_distorted() {
                    let xd = (u as f64 - cam.cx) / cam.fx;
                    let yd = (v as f64 - cam.cy) / cam.fy;
                    let (x, y) = cam.undistort_normalized(xd, yd);
                    sample(cam.fx * x + cam.cx, cam.fy * y + cam.cy)
                } else {
                    pinhole[v * w + u]
                };
                for c in value {
                    let g = c.powf(1.0 / 2.2) * 255.0 + noise.sample(&mut rng);
                    rgb.push(g.round().clamp(0.0, 255.0) as u8);
                }
            }
        }
        let mask = cam.distort_mask(&mask);
        SceneFrame {
            rgb,
            mask: mask
                .data
                .iter()
                .map(|&m| if m != 0 { 255 } else { 0 })
                .collect(),
        }
    }
}

impl SceneRenderer for SimScene {
    fn intrinsics(&self) -> &Intrinsics {
        &self.intrinsics
    }

    fn render(&self, true_joints: &[f64], frame_index: u64) -> Result<SceneFrame, String> {
        if true_joints.len() != self.robot.actuated.len() {
            return Err(format!(
                "scene got {} joints, robot has {}",
                true_joints.len(),
                self.robot.actuated.len()
            ));
        }
        Ok(self.frame(true_joints, frame_index))
    }
}
