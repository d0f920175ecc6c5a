//! Triangle meshes: loading (STL, Collada, OBJ), welding, primitive shapes, and the edge
//! adjacency that silhouette-edge extraction needs.

use std::collections::HashMap;
use std::path::Path;

use nalgebra::{Isometry3, Point3, Vector3};

use crate::error::{Error, Result};

/// Marker for an edge with a single adjacent triangle (open border or non-manifold edge).
pub const NO_TRIANGLE: u32 = u32::MAX;

/// An edge of a welded mesh and the (up to two) triangles that share it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Edge {
    /// First vertex index.
    pub a: u32,
    /// Second vertex index.
    pub b: u32,
    /// A triangle containing the edge.
    pub t0: u32,
    /// The other triangle, or [`NO_TRIANGLE`] for a border/non-manifold edge.
    pub t1: u32,
}

/// An indexed triangle mesh with welded vertices and edge adjacency.
#[derive(Clone, Debug, Default)]
pub struct TriMesh {
    /// Vertex positions, metres, in the mesh's own frame.
    pub vertices: Vec<Point3<f64>>,
    /// Triangles as vertex-index triples.
    pub triangles: Vec<[u32; 3]>,
    /// Unique edges with their adjacent triangles.
    pub edges: Vec<Edge>,
}

impl TriMesh {
    /// Builds a mesh from a triangle soup: welds vertices closer than `weld_m` and computes
    /// edge adjacency. Degenerate triangles (two equal corners after welding) are dropped.
    pub fn from_soup(positions: &[Point3<f64>], triangles: &[[u32; 3]], weld_m: f64) -> TriMesh {
        let mut index_of: HashMap<[i64; 3], u32> = HashMap::new();
        let mut vertices = Vec::new();
        let mut remap = Vec::with_capacity(positions.len());
        for p in positions {
            let key = [
                (p.x / weld_m).round() as i64,
                (p.y / weld_m).round() as i64,
                (p.z / weld_m).round() as i64,
            ];
            let idx = *index_of.entry(key).or_insert_with(|| {
                vertices.push(*p);
                (vertices.len() - 1) as u32
            });
            remap.push(idx);
        }
        let tris: Vec<[u32; 3]> = triangles
            .iter()
            .map(|t| {
                [
                    remap[t[0] as usize],
                    remap[t[1] as usize],
                    remap[t[2] as usize],
                ]
            })
            .filter(|t| t[0] != t[1] && t[1] != t[2] && t[0] != t[2])
            .collect();
        let mut mesh = TriMesh {
            vertices,
            triangles: tris,
            edges: Vec::new(),
        };
        mesh.build_edges();
        mesh
    }

    /// Recomputes `edges` from `triangles`.
    pub fn build_edges(&mut self) {
        let mut slot: HashMap<(u32, u32), usize> = HashMap::with_capacity(self.triangles.len() * 2);
        let mut edges: Vec<Edge> = Vec::with_capacity(self.triangles.len() * 3 / 2);
        let mut count: Vec<u8> = Vec::new();
        for (ti, t) in self.triangles.iter().enumerate() {
            for k in 0..3 {
                let (a, b) = (t[k], t[(k + 1) % 3]);
                let key = (a.min(b), a.max(b));
                match slot.get(&key) {
                    Some(&e) => {
                        count[e] = count[e].saturating_add(1);
                        if count[e] == 2 {
                            edges[e].t1 = ti as u32;
                        } else {
                            // Non-manifold: treat as an open border so both sides get tested.
                            edges[e].t1 = NO_TRIANGLE;
                        }
                    }
                    None => {
                        slot.insert(key, edges.len());
                        edges.push(Edge {
                            a: key.0,
                            b: key.1,
                            t0: ti as u32,
                            t1: NO_TRIANGLE,
                        });
                        count.push(1);
                    }
                }
            }
        }
        self.edges = edges;
    }

    /// Applies a per-axis scale then a rigid transform to every vertex (URDF visual `scale`
    /// then `<origin>`).
    pub fn transformed(&self, scale: Vector3<f64>, pose: &Isometry3<f64>) -> TriMesh {
        let mut out = self.clone();
        for v in &mut out.vertices {
            *v = pose * Point3::new(v.x * scale.x, v.y * scale.y, v.z * scale.z);
        }
        out
    }

    /// Axis-aligned bounds `(min, max)`; `None` for an empty mesh.
    pub fn bounds(&self) -> Option<(Point3<f64>, Point3<f64>)> {
        let first = *self.vertices.first()?;
        let mut lo = first;
        let mut hi = first;
        for v in &self.vertices {
            lo = lo.inf(v);
            hi = hi.sup(v);
        }
        Some((lo, hi))
    }

    /// Appends another mesh (indices shifted).
    pub fn append(&mut self, other: &TriMesh) {
        let vo = self.vertices.len() as u32;
        let to = self.triangles.len() as u32;
        self.vertices.extend_from_slice(&other.vertices);
        self.triangles.extend(
            other
                .triangles
                .iter()
                .map(|t| [t[0] + vo, t[1] + vo, t[2] + vo]),
        );
        self.edges.extend(other.edges.iter().map(|e| Edge {
            a: e.a + vo,
            b: e.b + vo,
            t0: e.t0 + to,
            t1: if e.t1 == NO_TRIANGLE {
                NO_TRIANGLE
            } else {
                e.t1 + to
            },
        }));
    }

    /// An axis-aligned box centred on the origin.
    pub fn cuboid(size: [f64; 3]) -> TriMesh {
        let h = [size[0] / 2.0, size[1] / 2.0, size[2] / 2.0];
        let mut p = Vec::new();
        for i in 0..8 {
            p.push(Point3::new(
                if i & 1 == 0 { -h[0] } else { h[0] },
                if i & 2 == 0 { -h[1] } else { h[1] },
                if i & 4 == 0 { -h[2] } else { h[2] },
            ));
        }
        let t = [
            [0, 2, 3],
            [0, 3, 1],
            [4, 5, 7],
            [4, 7, 6],
            [0, 1, 5],
            [0, 5, 4],
            [2, 6, 7],
            [2, 7, 3],
            [0, 4, 6],
            [0, 6, 2],
            [1, 3, 7],
            [1, 7, 5],
        ];
        TriMesh::from_soup(&p, &t, 1e-9)
    }

    /// A closed cylinder along z, centred on the origin.
    pub fn cylinder(radius: f64, length: f64, segments: u32) -> TriMesh {
        let mut p = vec![
            Point3::new(0.0, 0.0, -length / 2.0),
            Point3::new(0.0, 0.0, length / 2.0),
        ];
        for i in 0..segments {
            let a = std::f64::consts::TAU * f64::from(i) / f64::from(segments);
            p.push(Point3::new(
                radius * a.cos(),
                radius * a.sin(),
                -length / 2.0,
            ));
            p.push(Point3::new(
                radius * a.cos(),
                radius * a.sin(),
                length / 2.0,
            ));
        }
        let mut t = Vec::new();
        for i in 0..segments {
            let j = (i + 1) % segments;
            let (b0, t0, b1, t1) = (2 + 2 * i, 3 + 2 * i, 2 + 2 * j, 3 + 2 * j);
            t.extend_from_slice(&[[0, b1, b0], [1, t0, t1], [b0, b1, t1], [b0, t1, t0]]);
        }
        TriMesh::from_soup(&p, &t, 1e-9)
    }

    /// A UV sphere centred on the origin, optionally stretched along z into a capsule whose
    /// cylindrical part has length `stretch`.
    pub fn capsule(radius: f64, stretch: f64, rings: u32, segments: u32) -> TriMesh {
        // Rows of constant polar angle; the equator is emitted twice (top and bottom cap) so the
        // cylindrical band is explicit. Pole rows collapse to one vertex when welded.
        let mut rows: Vec<(f64, f64)> = Vec::new();
        for r in 0..=rings {
            let polar = std::f64::consts::PI * f64::from(r) / f64::from(rings);
            if 2 * r == rings {
                rows.push((polar, stretch / 2.0));
                rows.push((polar, -stretch / 2.0));
            } else {
                rows.push((
                    polar,
                    if 2 * r < rings {
                        stretch / 2.0
                    } else {
                        -stretch / 2.0
                    },
                ));
            }
        }
        let mut p = Vec::new();
        for &(polar, offset) in &rows {
            for s in 0..segments {
                let az = std::f64::consts::TAU * f64::from(s) / f64::from(segments);
                p.push(Point3::new(
                    radius * polar.sin() * az.cos(),
                    radius * polar.sin() * az.sin(),
                    radius * polar.cos() + offset,
                ));
            }
        }
        let mut t = Vec::new();
        for r in 0..rows.len() as u32 - 1 {
            for s in 0..segments {
                let s1 = (s + 1) % segments;
                let (a, b, c, d) = (
                    r * segments + s,
                    r * segments + s1,
                    (r + 1) * segments + s,
                    (r + 1) * segments + s1,
                );
                t.push([a, c, d]);
                t.push([a, d, b]);
            }
        }
        TriMesh::from_soup(&p, &t, 1e-9)
    }
}

/// Largest mesh file read, bytes: a robot part's mesh is a few MB; a FIFO, a device or a
/// multi-GB file behind a mesh path is a mistake that would block or fill memory.
const MAX_MESH_FILE_BYTES: u64 = 512 << 20;

/// Loads a mesh file (STL, DAE, OBJ: chosen by extension). Collada unit and node transforms
/// are applied by the loader, so the result is in the file's declared metres.
pub fn load_mesh_file(path: &Path) -> Result<TriMesh> {
    let ext = path
        .extension()
        .and_then(|e| e.to_str())
        .unwrap_or("")
        .to_ascii_lowercase();
    if !matches!(ext.as_str(), "stl" | "dae" | "obj") {
        return Err(Error::input(
            path,
            "mesh",
            format!("unsupported mesh format '.{ext}': use STL, DAE (Collada) or OBJ"),
        ));
    }
    let Ok(meta) = std::fs::metadata(path) else {
        return Err(Error::io(
            path,
            "mesh file not found: check the URDF <mesh filename>, package_dirs and package_paths",
        ));
    };
    // `io::input_file_problem` says the same, but `io` sits in this module's layer.
    if !meta.is_file() || meta.len() > MAX_MESH_FILE_BYTES {
        return Err(Error::input(
            path,
            "mesh",
            format!("allowed: a regular file of at most {MAX_MESH_FILE_BYTES} bytes"),
        ));
    }
    // The Collada reader can panic on inconsistent index streams: contain it as an input error,
    // with the default hook silenced meanwhile so the user sees one line, not a backtrace.
    let previous_hook = std::panic::take_hook();
    std::panic::set_hook(Box::new(|_| {}));
    let loaded =
        std::panic::catch_unwind(|| mesh_loader::Loader::default().merge_meshes(true).load(path));
    std::panic::set_hook(previous_hook);
    let scene = match loaded {
        Ok(Ok(scene)) => scene,
        Ok(Err(e)) => {
            return Err(Error::input(
                path,
                "mesh",
                format!("cannot parse mesh: {e}"),
            ))
        }
        Err(_) => {
            return Err(Error::input(
                path,
                "mesh",
                "malformed mesh (inconsistent index data)",
            ))
        }
    };
    let mut positions = Vec::new();
    let mut tris = Vec::new();
    for m in &scene.meshes {
        let base = positions.len() as u32;
        positions.extend(
            m.vertices
                .iter()
                .map(|v| Point3::new(f64::from(v[0]), f64::from(v[1]), f64::from(v[2]))),
        );
        tris.extend(
            m.faces
                .iter()
                .map(|f| [f[0] + base, f[1] + base, f[2] + base]),
        );
    }
    if tris.is_empty() {
        return Err(Error::input(path, "mesh", "mesh has no triangles"));
    }
    if tris
        .iter()
        .flatten()
        .any(|&i| i as usize >= positions.len())
    {
        return Err(Error::input(
            path,
            "mesh",
            "a face refers to a vertex that does not exist",
        ));
    }
    if positions
        .iter()
        .any(|p| !p.coords.iter().all(|c| c.is_finite()))
    {
        return Err(Error::input(
            path,
            "mesh",
            "mesh has non-finite vertex coordinates",
        ));
    }
    // Weld at a micrometre: merges the per-face copies STL writes, keeps real detail.
    Ok(TriMesh::from_soup(&positions, &tris, 1e-6))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn closed_primitives_are_manifold() {
        for m in [
            TriMesh::cuboid([0.1, 0.2, 0.3]),
            TriMesh::cylinder(0.05, 0.2, 24),
            TriMesh::capsule(0.05, 0.1, 8, 16),
        ] {
            assert!(!m.triangles.is_empty());
            let open = m.edges.iter().filter(|e| e.t1 == NO_TRIANGLE).count();
            assert_eq!(open, 0, "primitive has {open} open edges");
            // Euler characteristic of a sphere-like surface.
            let chi = m.vertices.len() as i64 - m.edges.len() as i64 + m.triangles.len() as i64;
            assert_eq!(chi, 2);
        }
    }

    #[test]
    fn welding_merges_stl_style_soup() {
        let c = TriMesh::cuboid([1.0, 1.0, 1.0]);
        let mut soup = Vec::new();
        let mut tris = Vec::new();
        for t in &c.triangles {
            for &i in t {
                soup.push(c.vertices[i as usize] + Vector3::new(1e-8, 0.0, 0.0));
            }
            let n = soup.len() as u32;
            tris.push([n - 3, n - 2, n - 1]);
        }
        let w = TriMesh::from_soup(&soup, &tris, 1e-6);
        assert_eq!(w.vertices.len(), 8);
        assert_eq!(w.edges.len(), 18);
    }
}
