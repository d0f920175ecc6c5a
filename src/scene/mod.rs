//! Colour frames of a simulated cell: a procedurally textured wall, floor and wooden table,
//! the robot shaded with a directional light (z-buffered triangles, two link colours like real
//! arms), Gaussian sensor noise and optional `plumb_bob` lens distortion. The ground-truth mask
//! comes from the same silhouette renderer the solver uses, warped by the same lens.
//!
//! Frames are meant to be realistic enough to develop a segmenter on: the robot's white links
//! sit on a light wall in places, the table's grain has edges, shading varies along links.
//!
//! # Harder frames
//!
//! A segmenter that works on the plain frames can still fail on a real cell, so five effects
//! make frames harder, each switchable and seeded by [`SceneSettings::seed`] and the frame index
//! (the same seed and index always give the same frame):
//! - [`ClutterSettings`]: posters, shelves of books, clocks and cables on the wall; paper,
//!   books, cutting mats, keyboards, tape and cables on the table and floor (edges at every
//!   scale); the floor then ends at walls 3 m from the base, so wall shows behind the table;
//! - [`PaletteSettings`]: robot link colours and wall colour, by default a white and light-grey
//!   robot in front of a light wall (low contrast in places);
//! - [`ShadowSettings`]: a light in the base frame whose shadow map (the robot and distractors
//!   seen from the light) darkens the table, the floor and the robot itself;
//! - [`ExposureSettings`]: a per-frame gain, white balance and offset, as auto-exposure does;
//! - [`DistractorSettings`]: boxes standing on the table and a person's arm reaching over it, at
//!   new places every frame. They are
//!   never part of the truth mask; by default they never hide the robot (drawn behind it), and
//!   with `occludes_robot` they do and the truth mask leaves out the hidden robot pixels.
//!
//! [`ScenePreset::Hard`] (`[scene] preset = "hard"`, [`SceneSettings::hard`]) turns all five on;
//! an effect's own table overrides the preset (`shadows = { enabled = false }` turns one off).
//! Partial truncation at the image border is a camera placement, not dressing:
//! [`crate::synth::Truncation`].

mod raster;
mod texture;

use std::sync::{Arc, RwLock};

use easyhec_drivers::Intrinsics;
use easyhec_mocks::{SceneFrame, SceneRenderer};
use nalgebra::{Isometry3, Point3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

use crate::camera::LensWarp;
use crate::config::scene::{SceneEffects, SceneSettings};
use crate::mask::Mask;
use crate::render::{CpuRenderer, PosedRobot, SilhouetteRenderer};
use crate::robot::RobotModel;
use raster::{box_triangles, limb_triangles, sphere_triangles, ShadowMap, TriangleBuffer};
use texture::{fractal, mix, table_clutter, wall_clutter};

/// One frame's exposure: what auto-exposure and auto white balance did to it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FrameExposure {
    /// Per-channel gain on linear light.
    pub gain_rgb: [f64; 3],
    /// Offset added after gamma, grey levels.
    pub offset_levels: f64,
}

impl FrameExposure {
    /// No change.
    pub const NEUTRAL: FrameExposure = FrameExposure {
        gain_rgb: [1.0; 3],
        offset_levels: 0.0,
    };
}

/// A box standing on the table in one frame.
#[derive(Clone, Debug, PartialEq)]
pub struct DistractorBox {
    /// Centre, base frame, metres.
    pub centre_in_base: Point3<f64>,
    /// Half edge lengths along the box's own x, y, z, metres.
    pub half_size_m: [f64; 3],
    /// Turn about the base z axis, radians.
    pub yaw_rad: f64,
    /// Linear RGB albedo.
    pub colour: [f64; 3],
}

/// A person's arm reaching over the table in one frame (a distractor that is no box).
#[derive(Clone, Debug, PartialEq)]
pub struct ReachingArm {
    /// Shoulder, base frame, metres (outside the table).
    pub shoulder_in_base: Point3<f64>,
    /// Elbow, base frame, metres.
    pub elbow_in_base: Point3<f64>,
    /// Centre of the hand, base frame, metres (over the table).
    pub hand_in_base: Point3<f64>,
    /// Linear RGB albedo of the sleeve.
    pub sleeve_colour: [f64; 3],
    /// Linear RGB albedo of the skin.
    pub skin_colour: [f64; 3],
}

impl ReachingArm {
    /// The arm's triangles (base frame) with their colours.
    fn triangles(&self) -> Vec<([Point3<f64>; 3], [f64; 3])> {
        let wrist = self.elbow_in_base + (self.hand_in_base - self.elbow_in_base) * 0.8;
        let mut out = Vec::new();
        let mut add = |tris: Vec<[Point3<f64>; 3]>, colour: [f64; 3]| {
            out.extend(tris.into_iter().map(|t| (t, colour)));
        };
        add(
            limb_triangles(&self.shoulder_in_base, &self.elbow_in_base, 0.05),
            self.sleeve_colour,
        );
        add(
            limb_triangles(&self.elbow_in_base, &wrist, 0.042),
            self.sleeve_colour,
        );
        add(
            limb_triangles(&wrist, &self.hand_in_base, 0.03),
            self.skin_colour,
        );
        add(
            sphere_triangles(&self.hand_in_base, 0.048),
            self.skin_colour,
        );
        out
    }
}

/// One rendered frame with everything a test or a segmenter benchmark may want to know.
#[derive(Clone, Debug)]
pub struct SimFrame {
    /// Row-major RGB8 in the camera's (distorted) image.
    pub rgb: Vec<u8>,
    /// The robot pixels the frame shows (distractor-hidden pixels left out).
    pub truth_mask: Mask,
    /// Pixels showing a distractor box.
    pub distractor_mask: Mask,
    /// Robot silhouette pixels hidden behind a distractor (empty unless `occludes_robot`).
    pub occluded_mask: Mask,
    /// The exposure of this frame.
    pub exposure: FrameExposure,
}

/// A simulated camera's view of the cell from a fixed, true pose.
pub struct SimScene {
    robot: Arc<RobotModel>,
    camera: Intrinsics,
    /// The true pose: `camera_from_base`, or `camera_from_<mount link>` for a camera on a
    /// link. Behind a lock so tests can bump the camera ([`SimScene::set_camera_from_base`]).
    camera_from_base: RwLock<Isometry3<f64>>,
    /// The link a wrist camera is fixed to (`None`: fixed in the cell).
    mount: Option<usize>,
    intrinsics: Intrinsics,
    settings: SceneSettings,
    effects: SceneEffects,
}

/// Distance from the base to the walls of a cluttered room, metres.
const ROOM_RADIUS_M: f64 = 3.0;

/// Stream constants that keep each effect's draws independent of the others.
const EXPOSURE_STREAM: u64 = 0x4558_504F;
const DISTRACTOR_STREAM: u64 = 0x4449_5354;
const FLOOR_STREAM: u64 = 0x464C_4F4F;
const ARM_STREAM: u64 = 0x4152_4D53;

/// Light of the plain frames: fixed in the camera frame, from the upper left behind the camera.
fn camera_light() -> Vector3<f64> {
    Vector3::new(0.35, -0.75, -0.55).normalize()
}

/// A surface the colour pass sees at a pixel.
#[derive(Clone, Copy)]
enum Seen {
    Background,
    Robot(u32),
    Distractor(u32),
}

/// One pinhole frame prepared for the colour pass (see [`SimScene::colour_pass`]).
struct PinholeFrame {
    cam: Intrinsics,
    base_from_camera: Isometry3<f64>,
    robot_cam: Vec<[Point3<f64>; 3]>,
    distractor_cam: Vec<[Point3<f64>; 3]>,
    distractor_colour: Vec<[f64; 3]>,
    robot_buf: TriangleBuffer,
    distractor_buf: TriangleBuffer,
    /// The shadow map and its strength, when shadows are on.
    shadow: Option<(ShadowMap, f64)>,
    /// Unit direction to the light, camera frame.
    light_cam: Vector3<f64>,
    silhouette: Mask,
    occludes: bool,
}

impl PinholeFrame {
    /// Colour of a surface point `p_cam` on triangle `tri` (camera frame): ambient plus
    /// diffuse and specular from the light, both dimmed where the shadow map says so.
    fn shade(
        &self,
        tri: &[Point3<f64>; 3],
        albedo: [f64; 3],
        p_cam: Point3<f64>,
        spec_k: f64,
    ) -> [f64; 3] {
        let light_cam = self.light_cam;
        let [a, b, c] = tri;
        let mut n = (b - a).cross(&(c - a));
        n = n.try_normalize(1e-15).unwrap_or_else(Vector3::z);
        if n.dot(&p_cam.coords) > 0.0 {
            n = -n;
        }
        let lit = match &self.shadow {
            Some((map, _)) => 1.0 - map.shadowed_fraction(&(self.base_from_camera * p_cam), 0.02),
            None => 1.0,
        };
        let view = -p_cam.coords.try_normalize(1e-12).unwrap_or_else(Vector3::z);
        let half = (light_cam + view).try_normalize(1e-12).unwrap_or(view);
        let diffuse = n.dot(&light_cam).max(0.0) * lit;
        let spec = n.dot(&half).max(0.0).powi(24) * spec_k * lit;
        let k = 0.3 + 0.7 * diffuse;
        albedo.map(|c| (c * k + spec).min(1.0))
    }
}

impl SimScene {
    /// A scene seen by `camera` (possibly distorted) from `camera_from_base`.
    pub fn new(
        robot: Arc<RobotModel>,
        camera: Intrinsics,
        camera_from_base: Isometry3<f64>,
        settings: SceneSettings,
    ) -> SimScene {
        let intrinsics = camera.clone();
        let effects = settings.effects();
        SimScene {
            robot,
            camera,
            camera_from_base: RwLock::new(camera_from_base),
            mount: None,
            intrinsics,
            settings,
            effects,
        }
    }

    /// The same scene seen by a camera fixed to link `link`: the pose given to
    /// [`SimScene::new`] is then `camera_from_<link>`, and each frame's camera pose follows
    /// the true joints. `robot` should leave out the links that move with the camera
    /// (`RobotModel::without_links_fixed_to`).
    pub fn mounted_on(mut self, link: usize) -> SimScene {
        self.mount = Some(link);
        self
    }

    /// Where the camera is at true joints `q`: the fixed pose, or the mount's pose composed
    /// with the forward kinematics.
    pub fn camera_from_base_at(&self, q: &[f64]) -> Isometry3<f64> {
        let pose = self.camera_from_base();
        match self.mount {
            Some(link) => pose * self.robot.base_from_links(q)[link].inverse(),
            None => pose,
        }
    }

    /// The true pose (tests and the final error report only): `camera_from_base`, or
    /// `camera_from_<link>` for a camera on a link.
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

    /// The effects in force.
    pub fn effects(&self) -> &SceneEffects {
        &self.effects
    }

    /// The exposure of frame `frame_index` ([`FrameExposure::NEUTRAL`] without the effect).
    pub fn frame_exposure(&self, frame_index: u64) -> FrameExposure {
        let Some(e) = &self.effects.exposure else {
            return FrameExposure::NEUTRAL;
        };
        let mut rng =
            ChaCha8Rng::seed_from_u64(mix(self.settings.seed, frame_index, EXPOSURE_STREAM));
        let gain = 1.0 + e.gain_spread * rng.random_range(-1.0..=1.0);
        let mut gain_rgb = [gain; 3];
        for g in &mut gain_rgb {
            *g *= 1.0 + e.white_balance_spread * rng.random_range(-1.0..=1.0);
        }
        FrameExposure {
            gain_rgb,
            offset_levels: e.offset_spread * rng.random_range(-1.0..=1.0),
        }
    }

    /// Where the distractor boxes stand in frame `frame_index` (empty without the effect):
    /// on the table, clear of the robot's base and of each other, with their centres inside
    /// the image (when 60 tries find such a place).
    pub fn distractor_boxes(&self, frame_index: u64) -> Vec<DistractorBox> {
        let Some(d) = &self.effects.distractors else {
            return Vec::new();
        };
        let s = &self.settings;
        let cam = self.camera.undistorted();
        let camera_from_base = self.camera_from_base();
        let mut rng =
            ChaCha8Rng::seed_from_u64(mix(self.settings.seed, frame_index, DISTRACTOR_STREAM));
        const BOX_COLOURS: [[f64; 3]; 6] = [
            [0.55, 0.4, 0.24],
            [0.62, 0.48, 0.3],
            [0.85, 0.85, 0.83],
            [0.1, 0.25, 0.6],
            [0.6, 0.1, 0.08],
            [0.12, 0.12, 0.13],
        ];
        let mut placed: Vec<DistractorBox> = Vec::new();
        for _ in 0..d.count {
            let half_size_m = [0, 1, 2].map(|_| rng.random_range(d.size_m[0]..=d.size_m[1]) / 2.0);
            let yaw_rad = rng.random_range(0.0..std::f64::consts::PI);
            let colour = BOX_COLOURS[rng.random_range(0..BOX_COLOURS.len())];
            let [x0, x1, y0, y1] = s.table_extent_m;
            let footprint = |h: &[f64; 3]| h[0].hypot(h[1]);
            let r = footprint(&half_size_m);
            let mut centre = Point3::new((x0 + x1) / 2.0, (y0 + y1) / 2.0, 0.0);
            for _ in 0..60 {
                let x = rng.random_range(x0 + r..=(x1 - r).max(x0 + r));
                let y = rng.random_range(y0 + r..=(y1 - r).max(y0 + r));
                centre = Point3::new(x, y, s.table_height_m + half_size_m[2]);
                // Clear of the robot's base and of the boxes already placed.
                let clear = x.hypot(y) >= 0.2 + r
                    && placed.iter().all(|b| {
                        let other = b.centre_in_base;
                        (x - other.x).hypot(y - other.y) > r + footprint(&b.half_size_m)
                    });
                if !clear {
                    continue;
                }
                let c = camera_from_base * centre;
                let [u, v] = cam.project(&c);
                let (w, h) = (f64::from(cam.width), f64::from(cam.height));
                if c.z > 0.1 && u > 0.05 * w && u < 0.95 * w && v > 0.05 * h && v < 0.95 * h {
                    break;
                }
            }
            placed.push(DistractorBox {
                centre_in_base: centre,
                half_size_m,
                yaw_rad,
                colour,
            });
        }
        placed
    }

    /// Where the person-like arms reach in frame `frame_index` (empty without the effect): from
    /// a shoulder 1.05 m from the base, 45 cm above the table, to a hand 5–30 cm above it, with
    /// the hand inside the image (when 40 tries find such a place).
    pub fn distractor_arms(&self, frame_index: u64) -> Vec<ReachingArm> {
        let Some(d) = &self.effects.distractors else {
            return Vec::new();
        };
        let table_z = self.settings.table_height_m;
        let cam = self.camera.undistorted();
        let camera_from_base = self.camera_from_base();
        let mut rng = ChaCha8Rng::seed_from_u64(mix(self.settings.seed, frame_index, ARM_STREAM));
        const SLEEVES: [[f64; 3]; 5] = [
            [0.08, 0.12, 0.3],
            [0.45, 0.05, 0.05],
            [0.18, 0.18, 0.19],
            [0.82, 0.82, 0.8],
            [0.28, 0.35, 0.18],
        ];
        const SKIN: [[f64; 3]; 4] = [
            [0.75, 0.52, 0.4],
            [0.55, 0.36, 0.24],
            [0.32, 0.2, 0.13],
            [0.85, 0.65, 0.52],
        ];
        (0..d.arms)
            .map(|_| {
                let sleeve_colour = SLEEVES[rng.random_range(0..SLEEVES.len())];
                let skin_colour = SKIN[rng.random_range(0..SKIN.len())];
                let mut arm = None;
                for _ in 0..40 {
                    let azimuth: f64 = rng.random_range(0.0..std::f64::consts::TAU);
                    let (radial, across) = (
                        Vector3::new(azimuth.cos(), azimuth.sin(), 0.0),
                        Vector3::new(-azimuth.sin(), azimuth.cos(), 0.0),
                    );
                    let shoulder = Point3::new(0.0, 0.0, table_z + 0.45) + radial * 1.05;
                    let hand = Point3::new(0.0, 0.0, table_z + rng.random_range(0.05..0.3))
                        + radial * rng.random_range(0.3..0.7)
                        + across * rng.random_range(-0.15..0.15);
                    let elbow = shoulder
                        + (hand - shoulder) * 0.5
                        + Vector3::new(0.0, 0.0, 0.08)
                        + across * rng.random_range(-0.08..0.08);
                    let candidate = ReachingArm {
                        shoulder_in_base: shoulder,
                        elbow_in_base: elbow,
                        hand_in_base: hand,
                        sleeve_colour,
                        skin_colour,
                    };
                    let c = camera_from_base * hand;
                    let [u, v] = cam.project(&c);
                    let (w, h) = (f64::from(cam.width), f64::from(cam.height));
                    let visible =
                        c.z > 0.1 && u > 0.05 * w && u < 0.95 * w && v > 0.05 * h && v < 0.95 * h;
                    arm = Some(candidate);
                    if visible {
                        break;
                    }
                }
                arm.expect("at least one try")
            })
            .collect()
    }

    /// Colour of the wall, floor or table along `ray_base` from `eye`, and the ground point
    /// hit (table or floor; `None` for the wall) for shadows.
    fn background(
        &self,
        ray_base: &Vector3<f64>,
        eye: &Point3<f64>,
    ) -> ([f64; 3], Option<Point3<f64>>) {
        let s = &self.settings;
        let clutter = self.effects.clutter.as_ref();
        if ray_base.z < -1e-9 {
            let t = (s.table_height_m - eye.z) / ray_base.z;
            if t > 0.0 {
                let p = eye + ray_base * t;
                let [x0, x1, y0, y1] = s.table_extent_m;
                if p.x >= x0 && p.x <= x1 && p.y >= y0 && p.y <= y1 {
                    if let Some(c) = clutter.and_then(|c| {
                        table_clutter(p.x, p.y, s.seed, c.table_density, c.table_cables)
                    }) {
                        return (c, Some(p));
                    }
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
                    return ([0.66 * k, 0.49 * k, 0.33 * k], Some(p));
                }
            }
            let t = (s.floor_height_m - eye.z) / ray_base.z;
            // With clutter the room has walls: the floor ends where they stand.
            let beyond_wall = |p: &Point3<f64>| clutter.is_some() && p.x.hypot(p.y) > ROOM_RADIUS_M;
            if t > 0.0 && !beyond_wall(&(eye + ray_base * t)) {
                let p = eye + ray_base * t;
                if let Some(c) = clutter.and_then(|c| {
                    table_clutter(
                        p.x,
                        p.y,
                        s.seed.rotate_left(17) ^ FLOOR_STREAM,
                        c.table_density * 0.6,
                        c.table_cables,
                    )
                }) {
                    return (c, Some(p));
                }
                let tile = ((p.x * 2.0).floor() as i64 + (p.y * 2.0).floor() as i64).rem_euclid(2);
                let k =
                    if tile == 0 { 0.42 } else { 0.36 } + 0.08 * fractal(p.x * 8.0, p.y * 8.0, 13);
                return ([k, k * 0.98, k * 0.95], Some(p));
            }
        }
        // Walls: a cylinder of radius 3 m around the base, painted panels with noise.
        let az = ray_base.y.atan2(ray_base.x);
        let el = ray_base.z.atan2(ray_base.xy().norm());
        if let Some(c) =
            clutter.and_then(|c| wall_clutter(az, el, s.seed, c.wall_density, c.wall_cables))
        {
            return (c, None);
        }
        let panel = if ((az * 6.0 / std::f64::consts::PI).fract().abs()) < 0.015 {
            0.7
        } else {
            1.0
        };
        let k = (0.72 + 0.18 * fractal(az * 8.0, el * 8.0, 14)) * panel;
        let wall = self.effects.palette.wall_colour;
        ([k * wall[0], k * wall[1], k * wall[2]], None)
    }

    /// Renders the ideal pinhole colour image (linear 0..1), the visible robot mask, the
    /// distractor mask and the hidden-robot mask.
    fn render_pinhole(&self, q: &[f64], frame_index: u64) -> (Vec<[f64; 3]>, Mask, Mask, Mask) {
        let cam = self.camera.undistorted();
        // One pose for the whole frame, even if a test bumps the camera meanwhile.
        let camera_from_base = self.camera_from_base_at(q);
        let frame = self.pinhole_frame(q, frame_index, cam, camera_from_base);
        self.colour_pass(&frame)
    }

    /// The distractor triangles of a frame (boxes, then arms) in the base frame, with their
    /// colours.
    fn distractor_triangles(&self, frame_index: u64) -> (Vec<[Point3<f64>; 3]>, Vec<[f64; 3]>) {
        let boxes = self.distractor_boxes(frame_index);
        let mut distractor_base: Vec<[Point3<f64>; 3]> = Vec::new();
        let mut distractor_colour: Vec<[f64; 3]> = Vec::new();
        for b in &boxes {
            for tri in box_triangles(&b.centre_in_base, b.half_size_m, b.yaw_rad) {
                distractor_base.push(tri);
                distractor_colour.push(b.colour);
            }
        }
        for arm in self.distractor_arms(frame_index) {
            for (tri, colour) in arm.triangles() {
                distractor_base.push(tri);
                distractor_colour.push(colour);
            }
        }
        (distractor_base, distractor_colour)
    }

    /// Everything the colour pass reads: triangles in the camera frame and their depth
    /// buffers, the shadow map and light, and the robot's silhouette.
    fn pinhole_frame(
        &self,
        q: &[f64],
        frame_index: u64,
        cam: Intrinsics,
        camera_from_base: Isometry3<f64>,
    ) -> PinholeFrame {
        let (w, h) = (cam.width as usize, cam.height as usize);
        let base_from_camera = camera_from_base.inverse();

        // Geometry: robot and distractor triangles, base and camera frames.
        let posed = self.robot.posed_vertices(q);
        let mesh = &self.robot.visual;
        let robot_base: Vec<[Point3<f64>; 3]> = mesh
            .triangles
            .iter()
            .map(|t| t.map(|i| posed[i as usize]))
            .collect();
        let (distractor_base, distractor_colour) = self.distractor_triangles(frame_index);
        let to_camera = |tris: &[[Point3<f64>; 3]]| -> Vec<[Point3<f64>; 3]> {
            tris.iter()
                .map(|t| t.map(|p| camera_from_base * p))
                .collect()
        };
        let robot_cam = to_camera(&robot_base);
        let distractor_cam = to_camera(&distractor_base);

        let mut robot_buf = TriangleBuffer::new(w * h);
        robot_buf.draw(&cam, &robot_cam);
        let mut distractor_buf = TriangleBuffer::new(w * h);
        distractor_buf.draw(&cam, &distractor_cam);

        let shadow = self.effects.shadows.as_ref().map(|s| {
            let casters: Vec<[Point3<f64>; 3]> =
                robot_base.iter().chain(&distractor_base).copied().collect();
            (
                ShadowMap::build(&casters, &Vector3::from(s.to_light_in_base), 0.005),
                s.strength,
            )
        });
        let light_cam = match &self.effects.shadows {
            Some(s) => (camera_from_base.rotation * Vector3::from(s.to_light_in_base))
                .try_normalize(1e-12)
                .unwrap_or_else(camera_light),
            None => camera_light(),
        };

        let silhouette = CpuRenderer
            .render(
                &PosedRobot::new(&self.robot, q),
                &cam,
                &camera_from_base,
                None,
            )
            .mask;
        let occludes = self
            .effects
            .distractors
            .as_ref()
            .is_some_and(|d| d.occludes_robot);
        PinholeFrame {
            cam,
            base_from_camera,
            robot_cam,
            distractor_cam,
            distractor_colour,
            robot_buf,
            distractor_buf,
            shadow,
            light_cam,
            silhouette,
            occludes,
        }
    }

    /// Per pixel, what is seen (distractor, robot or background, by depth and the occlusion
    /// setting) and its shaded colour; also the visible-robot, distractor and hidden masks.
    fn colour_pass(&self, frame: &PinholeFrame) -> (Vec<[f64; 3]>, Mask, Mask, Mask) {
        let cam = &frame.cam;
        let (w, h) = (cam.width as usize, cam.height as usize);
        let eye = Point3::from(frame.base_from_camera.translation.vector);
        let rot = frame.base_from_camera.rotation;
        let mesh = &self.robot.visual;
        let (robot_buf, distractor_buf) = (&frame.robot_buf, &frame.distractor_buf);
        let (silhouette, occludes, shadow) = (&frame.silhouette, frame.occludes, &frame.shadow);
        let mut truth = silhouette.clone();
        let mut distractor_mask = Mask::new(cam.width, cam.height);
        let mut occluded_mask = Mask::new(cam.width, cam.height);

        let palette = &self.effects.palette.robot_colours;
        let mut rgb: Vec<[f64; 3]> = Vec::with_capacity(w * h);
        for v in 0..h {
            for u in 0..w {
                let i = v * w + u;
                let robot_z = robot_buf.depth[i];
                let distractor_z = distractor_buf.depth[i];
                let seen = if distractor_buf.covered(i) && (occludes && distractor_z < robot_z) {
                    if silhouette.data[i] != 0 {
                        occluded_mask.data[i] = 1;
                        truth.data[i] = 0;
                    }
                    Seen::Distractor(distractor_buf.triangle[i])
                } else if robot_buf.covered(i) {
                    Seen::Robot(robot_buf.triangle[i])
                } else if distractor_buf.covered(i) && (occludes || silhouette.data[i] == 0) {
                    Seen::Distractor(distractor_buf.triangle[i])
                } else {
                    Seen::Background
                };
                let ray_cam = Vector3::new(
                    (u as f64 - cam.cx) / cam.fx,
                    (v as f64 - cam.cy) / cam.fy,
                    1.0,
                );
                let colour = match seen {
                    Seen::Robot(k) => {
                        let first = mesh.triangles[k as usize][0] as usize;
                        let link = self.robot.vertex_link.get(first).copied().unwrap_or(0);
                        let albedo = palette[link as usize % palette.len()];
                        frame.shade(
                            &frame.robot_cam[k as usize],
                            albedo,
                            Point3::from(ray_cam * robot_z),
                            0.25,
                        )
                    }
                    Seen::Distractor(k) => {
                        distractor_mask.data[i] = 1;
                        let albedo = frame.distractor_colour[k as usize];
                        frame.shade(
                            &frame.distractor_cam[k as usize],
                            albedo,
                            Point3::from(ray_cam * distractor_z),
                            0.03,
                        )
                    }
                    Seen::Background => {
                        let (colour, ground) = self.background(&(rot * ray_cam), &eye);
                        match (shadow, ground) {
                            (Some((map, strength)), Some(p)) => {
                                let dark = 1.0 - strength * map.shadowed_fraction(&p, 0.01);
                                colour.map(|c| c * dark)
                            }
                            _ => colour,
                        }
                    }
                };
                rgb.push(colour);
            }
        }
        (rgb, truth, distractor_mask, occluded_mask)
    }

    /// Renders one frame with its truth, distractor and hidden-robot masks, all in the
    /// camera's (distorted) image.
    pub fn render_frame(&self, q: &[f64], frame_index: u64) -> SimFrame {
        let (pinhole, truth, distractors, occluded) = self.render_pinhole(q, frame_index);
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
        let exposure = self.frame_exposure(frame_index);
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
                for (c, gain) in value.into_iter().zip(exposure.gain_rgb) {
                    let linear = (c * gain).clamp(0.0, 1.0);
                    let g = linear.powf(1.0 / 2.2) * 255.0
                        + exposure.offset_levels
                        + noise.sample(&mut rng);
                    rgb.push(g.round().clamp(0.0, 255.0) as u8);
                }
            }
        }
        let distort = |m: &Mask| {
            if m.data.iter().any(|&x| x != 0) {
                cam.distort_mask(m)
            } else {
                Mask::new(cam.width, cam.height)
            }
        };
        SimFrame {
            rgb,
            truth_mask: cam.distort_mask(&truth),
            distractor_mask: distort(&distractors),
            occluded_mask: distort(&occluded),
            exposure,
        }
    }

    /// Renders one frame: colour (distorted, noisy, RGB8) and the true mask (distorted).
    pub fn frame(&self, q: &[f64], frame_index: u64) -> SceneFrame {
        let f = self.render_frame(q, frame_index);
        SceneFrame {
            rgb: f.rgb,
            mask: f
                .truth_mask
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

    fn render(
        &self,
        true_joints: &[f64],
        frame_index: u64,
    ) -> std::result::Result<SceneFrame, String> {
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
