//! Silhouette rendering: the union mask of all robot links plus samples of its outline.
//!
//! The outline samples are what makes the objective differentiable: each sample is a point on
//! a mesh silhouette edge (an edge between a front- and a back-facing triangle, or an open
//! border) that lies on the outer boundary of the union silhouette, with its 3D point, outward
//! image normal and the outline length it stands for. The boundary-integral gradient
//! (docs/method.md §3) and the solver's sub-pixel residuals are sums over these samples.
//!
//! [`SilhouetteRenderer`] is the seam for other backends (wgpu): the solver only sees
//! [`Silhouette`]s. This module only renders: scoring many poses in a batch belongs to the
//! `scoring` module and choosing a backend to `backend`, both above this one, so rendering
//! depends on nothing but geometry, meshes, robots, cameras and masks.

use std::sync::{Arc, OnceLock};

use nalgebra::{Isometry3, Matrix2x6, Point3};
use rayon::prelude::*;

use crate::camera::Intrinsics;
use crate::mask::Mask;
use crate::mesh::{Edge, TriMesh, NO_TRIANGLE};
use crate::robot::{JointMotion, RobotModel};

/// Points closer to the camera than this (metres) are not rendered.
pub const NEAR_PLANE_M: f64 = 0.01;

/// A robot at one joint configuration: visual vertices in the base frame and the shared mesh
/// topology. Built once per view; every render of the view only transforms these.
#[derive(Clone, Debug)]
pub struct PosedRobot {
    /// Vertices in the base frame.
    pub vertices_base: Vec<Point3<f64>>,
    /// Triangles and edges (indices into `vertices_base`).
    pub topology: Arc<TriMesh>,
    /// Link index of every vertex (empty when unknown): which body a sample moves with.
    pub vertex_link: Arc<Vec<u32>>,
    /// Each actuated joint's axis at this pose and the links it moves (empty when unknown):
    /// how an error in a reported joint moves the outline, for the covariance.
    pub joint_motions: Arc<Vec<JointMotion>>,
    /// Per link: joined to the base link by fixed joints only (empty when unknown). A camera
    /// on a link has those links taken out of what it sees, so for it none is left.
    pub fixed_links: Arc<Vec<bool>>,
    /// [`PosedRobot::mount`], worked out on first use and shared by the clones (which
    /// must not change the vertices, links or fixed links after that).
    pub(crate) mount_cache: Arc<OnceLock<Option<Mount>>>,
}

/// How far above the lowest point of the robot's fixed links the outline counts as where the
/// robot stands on its mount (metres): about a mount plate's thickness with its bolt heads,
/// and as measured on the real xArm7 set, where the plate is the base's colour
/// (docs/benchmarks.md, "Real frames").
pub const MOUNT_CONTACT_HEIGHT_M: f64 = 0.015;

/// Where a robot stands on its mount: the vertices of the links no actuated joint moves, and
/// the height of their lowest point.
#[derive(Clone, Debug)]
pub struct Mount {
    /// Per vertex: whether its link is fixed.
    fixed: Vec<bool>,
    /// Base-frame z of the lowest fixed vertex, metres (z points away from the mount).
    floor_z: f64,
}

/// Per link of `robot`: joined to its base link by fixed joints only.
fn fixed_links(robot: &RobotModel) -> Vec<bool> {
    let mut fixed = vec![false; robot.links.len()];
    for l in robot.links_fixed_to(robot.base) {
        fixed[l] = true;
    }
    fixed
}

impl Mount {
    /// Whether outline sample `s` (rendered with `base_from_camera`'s inverse) lies at the
    /// mount contact: on a fixed link, and its own point less than
    /// [`MOUNT_CONTACT_HEIGHT_M`] above the floor. The sample's point decides, not its
    /// edge's vertex: an edge can run from the foot far up the base's side.
    pub fn holds(&self, s: &BoundarySample, base_from_camera: &Isometry3<f64>) -> bool {
        self.fixed.get(s.vertex as usize).copied().unwrap_or(false)
            && (base_from_camera * s.point_camera).z < self.floor_z + MOUNT_CONTACT_HEIGHT_M
    }
}

impl PosedRobot {
    /// Poses `robot` at actuated joint positions `q`.
    pub fn new(robot: &RobotModel, q: &[f64]) -> PosedRobot {
        PosedRobot {
            vertices_base: robot.posed_vertices(q),
            topology: robot.visual.clone(),
            vertex_link: robot.vertex_link.clone(),
            joint_motions: Arc::new(robot.joint_motions(q)),
            fixed_links: Arc::new(fixed_links(robot)),
            mount_cache: Arc::default(),
        }
    }

    /// Where this robot stands on its mount: its links joined to the base by fixed joints
    /// only. `None` when they have no vertex: for a camera on a link (whose own rigid links
    /// are not drawn), or when the links are unknown.
    pub fn mount(&self) -> Option<&Mount> {
        self.mount_cache
            .get_or_init(|| {
                if self.vertex_link.len() != self.vertices_base.len() {
                    return None;
                }
                let fixed: Vec<bool> = self
                    .vertex_link
                    .iter()
                    .map(|&l| self.fixed_links.get(l as usize).copied().unwrap_or(false))
                    .collect();
                let floor_z = self
                    .vertices_base
                    .iter()
                    .zip(&fixed)
                    .filter(|(_, &f)| f)
                    .map(|(p, _)| p.z)
                    .fold(f64::INFINITY, f64::min);
                floor_z.is_finite().then_some(Mount { fixed, floor_z })
            })
            .as_ref()
    }

    /// A coarse copy by vertex clustering on a `cell_m` grid, link by link (a vertex never
    /// merges across links, so every sample still knows its body): silhouettes change by at
    /// most about one cell, and coarse searches at low resolution get many times cheaper.
    pub fn decimated(&self, cell_m: f64) -> PosedRobot {
        let link_of = |v: u32| self.vertex_link.get(v as usize).copied().unwrap_or(0);
        let mut index_of: std::collections::HashMap<(u32, [i64; 3]), u32> =
            std::collections::HashMap::new();
        let mut vertices_base = Vec::new();
        let mut vertex_link = Vec::new();
        let remap: Vec<u32> = self
            .vertices_base
            .iter()
            .enumerate()
            .map(|(i, p)| {
                let link = link_of(i as u32);
                let key = [
                    (p.x / cell_m).round() as i64,
                    (p.y / cell_m).round() as i64,
                    (p.z / cell_m).round() as i64,
                ];
                *index_of.entry((link, key)).or_insert_with(|| {
                    vertices_base.push(*p);
                    vertex_link.push(link);
                    (vertices_base.len() - 1) as u32
                })
            })
            .collect();
        let mut seen = std::collections::HashSet::with_capacity(self.topology.triangles.len());
        let triangles: Vec<[u32; 3]> = self
            .topology
            .triangles
            .iter()
            .map(|t| t.map(|v| remap[v as usize]))
            .filter(|t| {
                if t[0] == t[1] || t[1] == t[2] || t[0] == t[2] {
                    return false;
                }
                let mut k = *t;
                k.sort_unstable();
                seen.insert(k)
            })
            .collect();
        let mut topology = TriMesh {
            vertices: vertices_base.clone(),
            triangles,
            edges: Vec::new(),
        };
        topology.build_edges();
        PosedRobot {
            vertices_base,
            topology: Arc::new(topology),
            vertex_link: Arc::new(vertex_link),
            joint_motions: self.joint_motions.clone(),
            fixed_links: self.fixed_links.clone(),
            mount_cache: Arc::default(),
        }
    }
}

/// A robot's meshes decimated once, link by link in each link's own frame: exploration poses
/// thousands of joint samples a round, and posing this costs one transform per coarse vertex,
/// with one topology shared by every pose (a GPU uploads it once).
#[derive(Clone, Debug)]
pub struct CoarseRobot {
    /// Clustered vertices in their link's frame.
    vertices_link: Vec<Point3<f64>>,
    /// Link of every coarse vertex.
    vertex_link: Arc<Vec<u32>>,
    /// Shared topology.
    topology: Arc<TriMesh>,
}

impl CoarseRobot {
    /// Clusters `robot`'s visual vertices on a `cell_m` grid per link, in link frames.
    pub fn new(robot: &RobotModel, cell_m: f64) -> CoarseRobot {
        let local = PosedRobot {
            vertices_base: robot.visual.vertices.clone(),
            topology: robot.visual.clone(),
            vertex_link: robot.vertex_link.clone(),
            joint_motions: Arc::new(Vec::new()),
            fixed_links: Arc::default(),
            mount_cache: Arc::default(),
        }
        .decimated(cell_m);
        CoarseRobot {
            vertices_link: local.vertices_base,
            vertex_link: local.vertex_link,
            topology: local.topology,
        }
    }

    /// The coarse robot at joint positions `q`.
    pub fn pose(&self, robot: &RobotModel, q: &[f64]) -> PosedRobot {
        let poses = robot.base_from_links(q);
        PosedRobot {
            vertices_base: self
                .vertices_link
                .iter()
                .zip(self.vertex_link.iter())
                .map(|(v, &l)| poses[l as usize] * v)
                .collect(),
            topology: self.topology.clone(),
            vertex_link: self.vertex_link.clone(),
            // Coarse poses are only scored, never solved from: no covariance reads their
            // joints, and thousands are posed per round.
            joint_motions: Arc::new(Vec::new()),
            fixed_links: Arc::default(),
            mount_cache: Arc::default(),
        }
    }
}

/// One sample of the silhouette outline.
#[derive(Clone, Copy, Debug)]
pub struct BoundarySample {
    /// Image position, pixels (pinhole image).
    pub pixel: [f64; 2],
    /// The 3D point on the mesh edge that projects there, camera frame, metres.
    pub point_camera: Point3<f64>,
    /// Outward unit normal of the outline in the image.
    pub normal: [f64; 2],
    /// Outline length this sample stands for, pixels.
    pub length_px: f64,
    /// Which grid segment the outline crosses here: [`ROW_CROSSING`] (between horizontally
    /// adjacent pixel centres) or [`COLUMN_CROSSING`].
    pub axis: u8,
    /// A mesh vertex of the edge the sample lies on (its link is the body the sample moves
    /// with; see [`PosedRobot::vertex_link`]).
    pub vertex: u32,
}

/// [`BoundarySample::axis`] of a crossing between horizontally adjacent pixel centres.
pub const ROW_CROSSING: u8 = 0;
/// [`BoundarySample::axis`] of a crossing between vertically adjacent pixel centres.
pub const COLUMN_CROSSING: u8 = 1;

impl BoundarySample {
    /// 2x6 derivative of the sample's pixel position with respect to a left se(3) increment
    /// `(rho, phi)` of `camera_from_base` (see [`crate::geometry`]).
    #[inline]
    pub fn pixel_jacobian(&self, camera: &Intrinsics) -> Matrix2x6<f64> {
        pixel_jacobian(camera, &self.point_camera)
    }
}

/// 2x6 derivative of the projection of camera-frame point `p` under a left se(3) increment.
#[inline]
pub fn pixel_jacobian(camera: &Intrinsics, p: &Point3<f64>) -> Matrix2x6<f64> {
    let iz = 1.0 / p.z;
    let (x, y) = (p.x * iz, p.y * iz);
    let (fx, fy) = (camera.fx * iz, camera.fy * iz);
    // d(u,v)/dP = [[fx/z, 0, -fx x/z], [0, fy/z, -fy y/z]]; dP/dxi = [I, -[P]x].
    let (px, py, pz) = (p.x, p.y, p.z);
    let du = [fx, 0.0, -fx * x];
    let dv = [0.0, fy, -fy * y];
    // -[P]x columns (e_k x P): phi_x -> (0, -pz, py), phi_y -> (pz, 0, -px), phi_z -> (-py, px, 0).
    let rot = |d: &[f64; 3]| {
        [
            -d[1] * pz + d[2] * py,
            d[0] * pz - d[2] * px,
            -d[0] * py + d[1] * px,
        ]
    };
    let ru = rot(&du);
    let rv = rot(&dv);
    Matrix2x6::new(
        du[0], du[1], du[2], ru[0], ru[1], ru[2], dv[0], dv[1], dv[2], rv[0], rv[1], rv[2],
    )
}

/// A rendered view.
#[derive(Clone, Debug)]
pub struct Silhouette {
    /// Union of all rendered links, pixel-centre sampled.
    pub mask: Mask,
    /// Samples of the outer outline (empty unless requested).
    pub boundary: Vec<BoundarySample>,
}

/// What a renderer backend must provide. Implementations must agree with [`CpuRenderer`] to
/// the pixel on masks (pixel centre inside any triangle) and sample the same outline.
pub trait SilhouetteRenderer: Send + Sync {
    /// Backend name for logs.
    fn name(&self) -> &str;

    /// Renders one view. `boundary_step_px` is the outline sample spacing; `None` renders the
    /// mask only.
    fn render(
        &self,
        robot: &PosedRobot,
        camera: &Intrinsics,
        camera_from_base: &Isometry3<f64>,
        boundary_step_px: Option<f64>,
    ) -> Silhouette;

    /// Renders several views of the same camera pose; backends may batch.
    fn render_many(
        &self,
        robots: &[&PosedRobot],
        camera: &Intrinsics,
        camera_from_base: &Isometry3<f64>,
        boundary_step_px: Option<f64>,
    ) -> Vec<Silhouette> {
        robots
            .par_iter()
            .map(|r| self.render(r, camera, camera_from_base, boundary_step_px))
            .collect()
    }
}

/// The reference renderer: scan-converts every triangle on the CPU (rayon over views, or
/// over triangle chunks when there are fewer views than threads), then walks silhouette edges.
#[derive(Clone, Copy, Debug, Default)]
pub struct CpuRenderer;

/// Triangles per parallel rasterisation job.
const RASTER_CHUNK: usize = 8192;

/// Marks every pixel whose centre lies inside (or on) any of `triangles` (corners indexing
/// `pixels`; a NaN corner, behind the camera, drops its triangle).
///
/// One winding goes first, the other second: on a closed mesh each winding alone covers the
/// whole silhouette, so nearly every triangle of the second pass finds its box already
/// marked and is skipped ([`fill_triangle`]). The union is the same in any order.
pub fn fill_triangles(mask: &mut Mask, triangles: &[[u32; 3]], pixels: &[[f64; 2]]) {
    for first_pass in [true, false] {
        for t in triangles {
            let [a, b, c] = t.map(|i| pixels[i as usize]);
            if a[0].is_nan() || b[0].is_nan() || c[0].is_nan() {
                continue;
            }
            let area = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]);
            if (area > 0.0) == first_pass {
                fill_triangle(mask, a, b, c);
            }
        }
    }
}

/// Marks every pixel whose centre lies inside (or on) triangle `a b c`.
#[inline]
pub fn fill_triangle(mask: &mut Mask, a: [f64; 2], b: [f64; 2], c: [f64; 2]) {
    let area = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]);
    if area.abs() < 1e-12 || !area.is_finite() {
        return;
    }
    let (w, h) = (f64::from(mask.width), f64::from(mask.height));
    let ymin = a[1].min(b[1]).min(c[1]).ceil().max(0.0);
    let ymax = a[1].max(b[1]).max(c[1]).floor().min(h - 1.0);
    let xmin = a[0].min(b[0]).min(c[0]).ceil().max(0.0);
    let xmax = a[0].max(b[0]).max(c[0]).floor().min(w - 1.0);
    if ymin > ymax || xmin > xmax {
        return;
    }
    let width = mask.width as usize;
    let (x0, x1, y0, y1) = (xmin as usize, xmax as usize, ymin as usize, ymax as usize);
    let small = x1 - x0 <= 4;
    // Marking only ever sets pixels, so a triangle whose whole box is already marked adds
    // nothing. Behind the robot's near side that is most of its far side.
    if small && (y0..=y1).all(|y| !mask.data[y * width + x0..=y * width + x1].contains(&0)) {
        return;
    }
    let s = area.signum();
    // Edge functions E(x, y) = ka x + kb y + kc, >= 0 inside (for either winding).
    let edge = |p: [f64; 2], q: [f64; 2]| {
        let (ex, ey) = (q[0] - p[0], q[1] - p[1]);
        [-s * ey, s * ex, s * (ey * p[0] - ex * p[1])]
    };
    let e = [edge(a, b), edge(b, c), edge(c, a)];
    if small {
        // Small triangles (most of a robot mesh): test pixel centres directly.
        for y in y0..=y1 {
            let yf = y as f64;
            let row = y * width;
            let base = [
                e[0][1] * yf + e[0][2],
                e[1][1] * yf + e[1][2],
                e[2][1] * yf + e[2][2],
            ];
            // Branch-free: which of a few pixels a triangle covers is not predictable, and
            // mispredicted branches cost more than the three tests.
            for (x, px) in (x0..=x1).zip(&mut mask.data[row + x0..=row + x1]) {
                let xf = x as f64;
                let inside = (e[0][0] * xf + base[0] >= 0.0)
                    & (e[1][0] * xf + base[1] >= 0.0)
                    & (e[2][0] * xf + base[2] >= 0.0);
                *px |= u8::from(inside);
            }
        }
        return;
    }
    for y in y0..=y1 {
        let row = y * width;
        // As for a small triangle's box, a row of the box already marked needs no span.
        if !mask.data[row + x0..=row + x1].contains(&0) {
            continue;
        }
        let yf = y as f64;
        let (mut lo, mut hi) = (xmin, xmax);
        for k in &e {
            // k0 x + (k1 y + k2) >= 0.
            let rest = k[1] * yf + k[2];
            if k[0] > 0.0 {
                lo = lo.max((-rest / k[0]).ceil());
            } else if k[0] < 0.0 {
                hi = hi.min((-rest / k[0]).floor());
            } else if rest < 0.0 {
                hi = lo - 1.0;
            }
        }
        if lo <= hi {
            mask.data[row + lo as usize..=row + hi as usize].fill(1);
        }
    }
}

/// Projects every vertex; vertices behind the near plane get NaN.
pub fn project_vertices(
    vertices_base: &[Point3<f64>],
    camera: &Intrinsics,
    camera_from_base: &Isometry3<f64>,
) -> (Vec<[f64; 2]>, Vec<Point3<f64>>) {
    vertices_base
        .par_iter()
        .map(|v| {
            let p = camera_from_base * v;
            if p.z > NEAR_PLANE_M {
                (camera.project(&p), p)
            } else {
                ([f64::NAN, f64::NAN], p)
            }
        })
        .unzip()
}

/// Rasterises the union silhouette from projected vertices.
pub fn rasterize(topology: &TriMesh, pixels: &[[f64; 2]], width: u32, height: u32) -> Mask {
    // One chunk per thread: each chunk costs a full-image buffer and an OR pass.
    let chunk = topology
        .triangles
        .len()
        .div_ceil(rayon::current_num_threads())
        .max(RASTER_CHUNK);
    rasterize_in_chunks(topology, pixels, width, height, chunk)
}

/// [`rasterize`] on the calling thread, into one buffer: for callers that already keep every
/// thread busy (one view each), where splitting a view only adds buffers and OR passes.
fn rasterize_serial(topology: &TriMesh, pixels: &[[f64; 2]], width: u32, height: u32) -> Mask {
    let everything = topology.triangles.len().max(1);
    rasterize_in_chunks(topology, pixels, width, height, everything)
}

/// The union silhouette, rasterised `chunk` triangles per job.
fn rasterize_in_chunks(
    topology: &TriMesh,
    pixels: &[[f64; 2]],
    width: u32,
    height: u32,
    chunk: usize,
) -> Mask {
    topology
        .triangles
        .par_chunks(chunk)
        .fold(
            || Mask::new(width, height),
            |mut m, tris| {
                fill_triangles(&mut m, tris, pixels);
                m
            },
        )
        .reduce(
            || Mask::new(width, height),
            |mut a, b| {
                for (x, y) in a.data.iter_mut().zip(&b.data) {
                    *x |= *y;
                }
                a
            },
        )
}

/// A silhouette-edge crossing of the segment between two 4-adjacent pixel centres.
#[derive(Clone, Copy)]
struct Crossing {
    /// Slot of the pixel pair: rows first (`v * (w-1) + u`), then columns.
    slot: u32,
    /// Distance from the crossing to the outside pixel centre (smaller is outermost).
    to_outside: f64,
    sample: BoundarySample,
}

/// Samples the outer outline of `mask` exactly where it crosses the pixel grid.
///
/// Candidate edges are mesh silhouette edges (front/back-facing neighbours, or open borders).
/// For every pair of 4-adjacent pixels where the mask changes, the outline crosses the segment
/// between their centres; among the candidate edges crossing it, the one nearest the outside
/// pixel is the outline (inner folds and duplicate shells lose). Each such crossing is one
/// sample standing for `1 / (|n_x| + |n_y|)` pixels of outline, so row and column crossings
/// together integrate the outline exactly once, whatever its direction. `step_px` > 1
/// thins the samples (used only to save work; the weights stay exact in expectation).
pub fn outline_samples(
    topology: &TriMesh,
    pixels: &[[f64; 2]],
    points_camera: &[Point3<f64>],
    mask: &Mask,
    step_px: f64,
) -> Vec<BoundarySample> {
    let facing = triangle_facing(topology, pixels);
    // One buffer per rayon job, concatenated in edge order (as a sequential pass would).
    let mut crossings: Vec<Crossing> = topology
        .edges
        .par_iter()
        .fold(Vec::new, |mut out, e| {
            if let Some(edge) = silhouette_edge(e, topology, pixels, &facing) {
                edge_crossings(e, edge, points_camera, mask, step_px, &mut out);
            }
            out
        })
        .reduce(Vec::new, |mut a, mut b| {
            a.append(&mut b);
            a
        });
    crossings.par_sort_unstable_by(|a, b| {
        a.slot
            .cmp(&b.slot)
            .then(a.to_outside.total_cmp(&b.to_outside))
    });
    crossings.dedup_by_key(|c| c.slot);
    crossings.into_iter().map(|c| c.sample).collect()
}

/// Sign of each projected triangle's area (`i8::MIN` when a vertex is behind the camera): an
/// edge between opposite signs, or an open border, is a silhouette edge.
fn triangle_facing(topology: &TriMesh, pixels: &[[f64; 2]]) -> Vec<i8> {
    topology
        .triangles
        .par_iter()
        .map(|t| {
            let (a, b, c) = (
                pixels[t[0] as usize],
                pixels[t[1] as usize],
                pixels[t[2] as usize],
            );
            let area = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]);
            if area.is_nan() {
                i8::MIN
            } else {
                area.signum() as i8
            }
        })
        .collect()
}

/// A silhouette edge in the image: endpoints, direction `d = pb - pa`, unit normal toward
/// its outer side, and whether it is an open border (whose side is unknown).
#[derive(Clone, Copy)]
struct SilhouetteEdge {
    pa: [f64; 2],
    pb: [f64; 2],
    d: [f64; 2],
    n: [f64; 2],
    open: bool,
}

/// `e` as a [`SilhouetteEdge`], or `None` when it is not one (both triangles facing the same
/// way, a vertex behind the camera, or a degenerate projection).
fn silhouette_edge(
    e: &Edge,
    topology: &TriMesh,
    pixels: &[[f64; 2]],
    facing: &[i8],
) -> Option<SilhouetteEdge> {
    let f0 = facing[e.t0 as usize];
    if f0 == i8::MIN {
        return None;
    }
    let open = e.t1 == NO_TRIANGLE;
    if !open {
        let f1 = facing[e.t1 as usize];
        if f1 == i8::MIN || f1 == f0 {
            return None;
        }
    }
    let (pa, pb) = (pixels[e.a as usize], pixels[e.b as usize]);
    let d = [pb[0] - pa[0], pb[1] - pa[1]];
    let len = d[0].hypot(d[1]);
    if len < 1e-12 {
        return None;
    }
    let mut n = [d[1] / len, -d[0] / len];
    // Both triangles of a silhouette edge project to its inner side.
    let tri = topology.triangles[e.t0 as usize];
    let k = tri.iter().position(|&v| v != e.a && v != e.b).unwrap_or(0);
    let pc = pixels[tri[k] as usize];
    if n[0] * (pc[0] - pa[0]) + n[1] * (pc[1] - pa[1]) > 0.0 {
        n = [-n[0], -n[1]];
    }
    Some(SilhouetteEdge { pa, pb, d, n, open })
}

/// Appends to `out` the crossings of one silhouette edge with the pixel-centre rows and
/// columns where the mask changes (see [`outline_samples`]), thinned to every `step_px`-th
/// scan line.
fn edge_crossings(
    e: &Edge,
    edge: SilhouetteEdge,
    points_camera: &[Point3<f64>],
    mask: &Mask,
    step_px: f64,
    out: &mut Vec<Crossing>,
) {
    let SilhouetteEdge { pa, pb, d, n, open } = edge;
    let (w, h) = (i64::from(mask.width), i64::from(mask.height));
    let row_slots = (h * (w - 1)).max(0);
    let (qa, qb) = (points_camera[e.a as usize], points_camera[e.b as usize]);
    let ds = 1.0 / (n[0].abs() + n[1].abs());
    let stride = step_px.round().max(1.0) as i64;
    let mut emit =
        |t: f64, x: [f64; 2], outside: (i64, i64), slot: i64, normal: [f64; 2], axis: u8| {
            // Perspective-correct parameter along the 3D edge.
            let s = t * qa.z / ((1.0 - t) * qb.z + t * qa.z);
            let p = qa + (qb - qa) * s;
            let to_outside = (x[0] - outside.0 as f64).abs() + (x[1] - outside.1 as f64).abs();
            out.push(Crossing {
                slot: slot as u32,
                to_outside,
                sample: BoundarySample {
                    pixel: x,
                    point_camera: p,
                    normal,
                    length_px: ds * stride as f64,
                    axis,
                    vertex: e.a,
                },
            });
        };
    // Row crossings (pixel-centre rows y = k, crossing along x), then column crossings.
    let thin = |i: i64| i % stride == 0;
    for axis in [ROW_CROSSING, COLUMN_CROSSING] {
        // `along`: the coordinate the crossing varies in; `fixed`: the scan line's.
        let (along, fixed, along_len, fixed_len) = if axis == ROW_CROSSING {
            (0, 1, w, h)
        } else {
            (1, 0, h, w)
        };
        if d[fixed].abs() <= 1e-12 {
            continue;
        }
        let k0 = pa[fixed].min(pb[fixed]).ceil().max(0.0) as i64;
        let k1 = pa[fixed].max(pb[fixed]).floor().min((fixed_len - 1) as f64) as i64;
        for k in k0..=k1 {
            if !thin(k) {
                continue;
            }
            let t = (k as f64 - pa[fixed]) / d[fixed];
            if !(0.0..=1.0).contains(&t) {
                continue;
            }
            let c = pa[along] + t * d[along];
            let i = c.floor() as i64;
            if i < 0 || i + 1 >= along_len {
                continue;
            }
            let at = |j: i64| {
                if axis == ROW_CROSSING {
                    mask.get(j, k)
                } else {
                    mask.get(k, j)
                }
            };
            let (first, second) = (at(i), at(i + 1));
            if first == second {
                continue;
            }
            let (inside, outside) = if first { (i, i + 1) } else { (i + 1, i) };
            let toward = (outside - inside) as f64;
            let normal = if open && n[along] * toward < 0.0 {
                [-n[0], -n[1]]
            } else {
                n
            };
            if normal[along] * toward <= 0.0 {
                continue;
            }
            if axis == ROW_CROSSING {
                emit(
                    t,
                    [c, k as f64],
                    (outside, k),
                    k * (w - 1) + i,
                    normal,
                    axis,
                );
            } else {
                emit(
                    t,
                    [k as f64, c],
                    (k, outside),
                    row_slots + i * w + k,
                    normal,
                    axis,
                );
            }
        }
    }
}

impl SilhouetteRenderer for CpuRenderer {
    fn name(&self) -> &str {
        "cpu"
    }

    fn render(
        &self,
        robot: &PosedRobot,
        camera: &Intrinsics,
        camera_from_base: &Isometry3<f64>,
        boundary_step_px: Option<f64>,
    ) -> Silhouette {
        render_view(robot, camera, camera_from_base, boundary_step_px, false)
    }

    fn render_many(
        &self,
        robots: &[&PosedRobot],
        camera: &Intrinsics,
        camera_from_base: &Isometry3<f64>,
        boundary_step_px: Option<f64>,
    ) -> Vec<Silhouette> {
        // With a view per thread or more, the views are the parallel work and each is
        // rasterised whole on its thread.
        let whole = robots.len() >= rayon::current_num_threads();
        robots
            .par_iter()
            .map(|r| render_view(r, camera, camera_from_base, boundary_step_px, whole))
            .collect()
    }
}

/// One view on the CPU; `whole` rasterises it on the calling thread ([`rasterize_serial`]).
fn render_view(
    robot: &PosedRobot,
    camera: &Intrinsics,
    camera_from_base: &Isometry3<f64>,
    boundary_step_px: Option<f64>,
    whole: bool,
) -> Silhouette {
    let (pixels, points) = project_vertices(&robot.vertices_base, camera, camera_from_base);
    let mask = if whole {
        rasterize_serial(&robot.topology, &pixels, camera.width, camera.height)
    } else {
        rasterize(&robot.topology, &pixels, camera.width, camera.height)
    };
    silhouette_from(robot, &pixels, &points, mask, boundary_step_px)
}

/// A rendered view: its mask and, when `boundary_step_px` is given, its outline samples.
pub(crate) fn silhouette_from(
    robot: &PosedRobot,
    pixels: &[[f64; 2]],
    points: &[Point3<f64>],
    mask: Mask,
    boundary_step_px: Option<f64>,
) -> Silhouette {
    let boundary = match boundary_step_px {
        Some(step) => outline_samples(&robot.topology, pixels, points, &mask, step),
        None => Vec::new(),
    };
    Silhouette { mask, boundary }
}

/// Renders at `factor`x resolution and keeps, per pixel, the covered fraction of its
/// `factor x factor` sub-pixels (a coverage reference for tests and the gradient check).
pub fn render_coverage(
    robot: &PosedRobot,
    camera: &Intrinsics,
    camera_from_base: &Isometry3<f64>,
    factor: u32,
) -> Vec<f32> {
    let f = f64::from(factor);
    let fine = Intrinsics {
        width: camera.width * factor,
        height: camera.height * factor,
        fx: camera.fx * f,
        fy: camera.fy * f,
        cx: (camera.cx + 0.5) * f - 0.5,
        cy: (camera.cy + 0.5) * f - 0.5,
        distortion: None,
    };
    let m = CpuRenderer
        .render(robot, &fine, camera_from_base, None)
        .mask;
    let mut cov = vec![0f32; (camera.width * camera.height) as usize];
    for v in 0..fine.height {
        for u in 0..fine.width {
            if m.data[(v * fine.width + u) as usize] != 0 {
                cov[((v / factor) * camera.width + u / factor) as usize] += 1.0;
            }
        }
    }
    let n = (factor * factor) as f32;
    cov.iter_mut().for_each(|c| *c /= n);
    cov
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fill_triangle_covers_pixel_centres() {
        let mut m = Mask::new(10, 10);
        fill_triangle(&mut m, [0.0, 0.0], [9.0, 0.0], [0.0, 9.0]);
        // Pixel (u, v) inside iff u + v <= 9.
        for v in 0..10 {
            for u in 0..10 {
                assert_eq!(m.get(u, v), u + v <= 9, "{u},{v}");
            }
        }
    }

    #[test]
    fn skipping_marked_boxes_leaves_the_union_of_the_triangles() {
        // Overlapping triangles of both windings, small and large, some partly off the image,
        // one with a corner behind the camera: the marked pixels are exactly the centres some
        // triangle covers, whatever the skipping.
        let (w, h) = (64u32, 48u32);
        let mut seed = 7u64;
        let mut next = move || {
            seed = seed
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (seed >> 11) as f64 / (1u64 << 53) as f64
        };
        let mut pixels = Vec::new();
        let mut triangles = Vec::new();
        for i in 0..400u32 {
            let size = if i % 4 == 0 { 30.0 } else { 4.0 };
            let (cx, cy) = (next() * 74.0 - 5.0, next() * 58.0 - 5.0);
            for _ in 0..3 {
                pixels.push([cx + (next() - 0.5) * size, cy + (next() - 0.5) * size]);
            }
            triangles.push([3 * i, 3 * i + 1, 3 * i + 2]);
        }
        pixels[5] = [f64::NAN, f64::NAN];
        let mut mask = Mask::new(w, h);
        fill_triangles(&mut mask, &triangles, &pixels);
        let inside = |t: &[u32; 3], x: f64, y: f64| {
            let [a, b, c] = t.map(|i| pixels[i as usize]);
            let side =
                |p: [f64; 2], q: [f64; 2]| (q[0] - p[0]) * (y - p[1]) - (q[1] - p[1]) * (x - p[0]);
            let (d0, d1, d2) = (side(a, b), side(b, c), side(c, a));
            (d0 >= 0.0 && d1 >= 0.0 && d2 >= 0.0) || (d0 <= 0.0 && d1 <= 0.0 && d2 <= 0.0)
        };
        let mut marked = 0;
        for v in 0..h {
            for u in 0..w {
                let expected = triangles
                    .iter()
                    .any(|t| inside(t, f64::from(u), f64::from(v)));
                assert_eq!(mask.get(i64::from(u), i64::from(v)), expected, "{u},{v}");
                marked += usize::from(expected);
            }
        }
        assert!(marked > 1000 && marked < (w * h) as usize, "{marked}");
    }

    #[test]
    fn views_rendered_together_match_views_rendered_alone() {
        let robot = crate::robot::RobotModel::from_urdf(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/robots/xarm6/robot.urdf"
        ))
        .unwrap();
        let camera = Intrinsics::pinhole(320, 240, 300.0, 300.0, 159.5, 119.5);
        let pose = crate::geometry::look_at_camera_from_base(
            &nalgebra::Vector3::new(1.2, 0.5, 0.7),
            &nalgebra::Vector3::new(0.2, 0.0, 0.3),
            &nalgebra::Vector3::z(),
        );
        let posed: Vec<PosedRobot> = (0..4)
            .map(|k| PosedRobot::new(&robot, &[0.3 * f64::from(k), -0.4, -0.5, 0.2, 0.9, 0.1]))
            .collect();
        let refs: Vec<&PosedRobot> = posed.iter().collect();
        // Two threads, as on CI: four views take the path that rasterises each view whole.
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(2)
            .build()
            .unwrap();
        let together = pool.install(|| CpuRenderer.render_many(&refs, &camera, &pose, Some(1.0)));
        for (r, t) in posed.iter().zip(&together) {
            let alone = CpuRenderer.render(r, &camera, &pose, Some(1.0));
            assert_eq!(alone.mask.data, t.mask.data);
            assert!(alone.mask.data.iter().filter(|&&v| v != 0).count() > 500);
            assert_eq!(alone.boundary.len(), t.boundary.len());
            for (a, b) in alone.boundary.iter().zip(&t.boundary) {
                assert_eq!((a.pixel, a.normal, a.vertex), (b.pixel, b.normal, b.vertex));
            }
        }
    }

    #[test]
    fn pixel_jacobian_matches_finite_difference() {
        let cam = Intrinsics::pinhole(640, 480, 600.0, 590.0, 320.0, 240.0);
        let p = Point3::new(0.2, -0.1, 1.3);
        let j = pixel_jacobian(&cam, &p);
        for k in 0..6 {
            let mut xi = crate::geometry::Twist::zeros();
            xi[k] = 1e-6;
            let a = cam.project(&(crate::geometry::exp_se3(&xi) * p));
            let b = cam.project(&(crate::geometry::exp_se3(&(-xi)) * p));
            for r in 0..2 {
                let fd = (a[r] - b[r]) / 2e-6;
                assert!(
                    (fd - j[(r, k)]).abs() < 1e-4 * (1.0 + fd.abs()),
                    "row {r} col {k}: {fd} vs {}",
                    j[(r, k)]
                );
            }
        }
    }
}
