//! Import from EasyHeC's offline folder and export to the forms other tools read.

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

use nalgebra::{Isometry3, UnitQuaternion};

use crate::error::{Error, Result};
use crate::geometry::to_rows;
use crate::io::{write_atomic, write_json_atomic};
use crate::mask::Mask;
use crate::run::{CameraEntry, PoseEntry, ResultFile, RobotEntry, RunFile, ViewEntry, RUN_FORMAT};

/// Reads a whitespace-separated numeric text file (comments after `#`).
pub fn read_numbers(path: &Path) -> Result<Vec<f64>> {
    let text =
        std::fs::read_to_string(path).map_err(|e| Error::io(path, format!("cannot read: {e}")))?;
    let mut out = Vec::new();
    for (ln, line) in text.lines().enumerate() {
        let line = line.split('#').next().unwrap_or("");
        for tok in line
            .split(|c: char| c.is_whitespace() || c == ',')
            .filter(|t| !t.is_empty())
        {
            let v: f64 = tok.parse().map_err(|_| {
                Error::input(
                    path,
                    format!("line {}", ln + 1),
                    format!("'{tok}' is not a number"),
                )
            })?;
            if !v.is_finite() {
                return Err(Error::input(
                    path,
                    format!("line {}", ln + 1),
                    "not a finite number",
                ));
            }
            out.push(v);
        }
    }
    Ok(out)
}

/// Options for `easyhec import easyhec`.
#[derive(Clone, Debug)]
pub struct EasyHecImport {
    /// EasyHeC offline folder (`color/ mask/ qpos/ K.txt`).
    pub source: PathBuf,
    /// Output run directory.
    pub out: PathBuf,
    /// URDF path as written into `run.json` (absolute or relative to `out`).
    pub urdf: String,
    /// Actuated joint names in qpos order; extra qpos values (fingers) are dropped.
    pub joints: Vec<String>,
    /// Links not rendered.
    pub ignore_links: Vec<String>,
    /// Initial-guess file (4x4); defaults to `initial_guess.txt` in the source when present.
    pub initial_guess: Option<PathBuf>,
}

fn sorted_files(dir: &Path, exts: &[&str]) -> Result<Vec<PathBuf>> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(|e| Error::io(dir, format!("cannot list: {e}")))?
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| {
            p.extension()
                .and_then(|e| e.to_str())
                .is_some_and(|e| exts.contains(&e.to_ascii_lowercase().as_str()))
        })
        .collect();
    v.sort();
    Ok(v)
}

/// Converts EasyHeC's offline example layout into an `easyhec-run/1` directory.
pub fn import_easyhec(opts: &EasyHecImport) -> Result<RunFile> {
    let src = &opts.source;
    let k = read_numbers(&src.join("K.txt"))?;
    if k.len() != 9 {
        return Err(Error::input(
            src.join("K.txt"),
            "K",
            format!("expected a 3x3 matrix (9 numbers), found {}", k.len()),
        ));
    }
    let masks = sorted_files(&src.join("mask"), &["png"])?;
    let qpos = sorted_files(&src.join("qpos"), &["txt"])?;
    if masks.is_empty() {
        return Err(Error::input(src.join("mask"), "mask", "no mask PNGs found"));
    }
    if masks.len() != qpos.len() {
        return Err(Error::input(
            src,
            "qpos",
            format!("{} masks but {} qpos files", masks.len(), qpos.len()),
        ));
    }
    std::fs::create_dir_all(opts.out.join("views")).map_err(|e| Error::io(&opts.out, e))?;
    let (mut width, mut height) = (0, 0);
    let mut views = Vec::new();
    for (i, (mp, qp)) in masks.iter().zip(&qpos).enumerate() {
        let mask = Mask::load(mp)?;
        if i == 0 {
            (width, height) = (mask.width, mask.height);
        } else if (mask.width, mask.height) != (width, height) {
            return Err(Error::input(
                mp,
                "mask",
                format!(
                    "is {}x{}, the first mask is {width}x{height}",
                    mask.width, mask.height
                ),
            ));
        }
        let q = read_numbers(qp)?;
        if q.len() < opts.joints.len() {
            return Err(Error::input(
                qp,
                "qpos",
                format!("has {} values, {} joints named", q.len(), opts.joints.len()),
            ));
        }
        let mask_rel = format!("views/{i:03}.mask.png");
        write_atomic(&opts.out.join(&mask_rel), &mask.to_png_bytes())?;
        let stem = mp.file_stem().and_then(|s| s.to_str()).unwrap_or("");
        let color = src.join("color").join(format!("{stem}.png"));
        let image = if color.exists() {
            let rel = format!("views/{i:03}.png");
            let bytes = std::fs::read(&color).map_err(|e| Error::io(&color, e))?;
            write_atomic(&opts.out.join(&rel), &bytes)?;
            Some(rel)
        } else {
            None
        };
        views.push(ViewEntry {
            joints: q[..opts.joints.len()].to_vec(),
            mask: Some(mask_rel),
            image,
            captured_at: None,
        });
    }
    let guess_path = opts
        .initial_guess
        .clone()
        .or_else(|| Some(src.join("initial_guess.txt")).filter(|p| p.exists()));
    let initial_guess = match guess_path {
        Some(p) => {
            let n = read_numbers(&p)?;
            if n.len() != 16 {
                return Err(Error::input(
                    &p,
                    "camera_from_base",
                    format!("expected a 4x4 matrix (16 numbers), found {}", n.len()),
                ));
            }
            let rows = [0, 1, 2, 3].map(|r| [0, 1, 2, 3].map(|c| n[r * 4 + c]));
            crate::geometry::from_rows(&rows)
                .map_err(|m| Error::input(&p, "camera_from_base", m))?;
            Some(PoseEntry {
                camera_from_base: rows,
            })
        }
        None => None,
    };
    let run = RunFile {
        format: RUN_FORMAT.into(),
        robot: RobotEntry {
            urdf: opts.urdf.clone(),
            package_dirs: BTreeMap::new(),
            base_link: None,
            ignore_links: opts.ignore_links.clone(),
            joints: opts.joints.clone(),
        },
        camera: CameraEntry {
            width,
            height,
            fx: k[0],
            fy: k[4],
            cx: k[2],
            cy: k[5],
            distortion_model: None,
            distortion: None,
        },
        initial_guess,
        views,
    };
    write_json_atomic(&opts.out.join("run.json"), &run)?;
    Ok(run)
}

/// Export targets.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ExportFormat {
    /// OpenCV FileStorage YAML with the 4x4 `camera_from_base` and `base_from_camera`, plus a
    /// plain-text 4x4 when written to a `.txt` path.
    Opencv,
    /// ROS: `static_transform_publisher` arguments and a tf YAML with quaternion.
    Ros,
    /// easy_handeye calibration YAML (eye-on-base).
    EasyHandeye,
    /// A URDF `<joint>` snippet placing the camera optical frame on the base link.
    Urdf,
}

impl std::str::FromStr for ExportFormat {
    type Err = String;
    fn from_str(s: &str) -> std::result::Result<Self, String> {
        Ok(match s {
            "opencv" => ExportFormat::Opencv,
            "ros" => ExportFormat::Ros,
            "easy-handeye" => ExportFormat::EasyHandeye,
            "urdf" => ExportFormat::Urdf,
            other => {
                return Err(format!(
                    "unknown export format '{other}': use opencv, ros, easy-handeye or urdf"
                ))
            }
        })
    }
}

fn quat_xyzw(q: &UnitQuaternion<f64>) -> [f64; 4] {
    [q.i, q.j, q.k, q.w]
}

/// Renders `result` in `format`. `camera_frame` names the optical frame for ROS/URDF forms.
pub fn export(result: &ResultFile, format: ExportFormat, camera_frame: &str) -> String {
    let cfb = result.camera_from_base();
    let bfc: Isometry3<f64> = cfb.inverse();
    let base = &result.base_link;
    let t = bfc.translation.vector;
    let q = quat_xyzw(&bfc.rotation);
    let mut s = String::new();
    match format {
        ExportFormat::Opencv => {
            let mat = |s: &mut String, name: &str, rows: [[f64; 4]; 4]| {
                let data: Vec<String> =
                    rows.iter().flatten().map(|v| format!("{v:.12e}")).collect();
                let _ = writeln!(
                    s,
                    "{name}: !!opencv-matrix\n   rows: 4\n   cols: 4\n   dt: d\n   data: [ {} ]",
                    data.join(", ")
                );
            };
            s.push_str("%YAML:1.0\n---\n");
            let _ = writeln!(s, "# camera_from_base maps base-frame ({base}) points to the OpenCV optical frame, metres");
            mat(&mut s, "camera_from_base", to_rows(&cfb));
            mat(&mut s, "base_from_camera", to_rows(&bfc));
        }
        ExportFormat::Ros => {
            let _ = writeln!(s, "# static_transform_publisher x y z qx qy qz qw frame_id child_frame_id (parent = {base})");
            let _ = writeln!(
                s,
                "# rosrun tf2_ros static_transform_publisher {:.9} {:.9} {:.9} {:.9} {:.9} {:.9} {:.9} {base} {camera_frame}",
                t.x, t.y, t.z, q[0], q[1], q[2], q[3]
            );
            let _ = writeln!(
                s,
                "header:\n  frame_id: {base}\nchild_frame_id: {camera_frame}\ntransform:"
            );
            let _ = writeln!(
                s,
                "  translation:\n    x: {:.12}\n    y: {:.12}\n    z: {:.12}",
                t.x, t.y, t.z
            );
            let _ = writeln!(
                s,
                "  rotation:\n    x: {:.12}\n    y: {:.12}\n    z: {:.12}\n    w: {:.12}",
                q[0], q[1], q[2], q[3]
            );
        }
        ExportFormat::EasyHandeye => {
            let _ = writeln!(s, "eye_on_hand: false\nrobot_base_frame: {base}\ntracking_base_frame: {camera_frame}\ntransformation:");
            let _ = writeln!(s, "  x: {:.12}\n  y: {:.12}\n  z: {:.12}\n  qx: {:.12}\n  qy: {:.12}\n  qz: {:.12}\n  qw: {:.12}", t.x, t.y, t.z, q[0], q[1], q[2], q[3]);
        }
        ExportFormat::Urdf => {
            let (r, p, y) = bfc.rotation.euler_angles();
            let _ = writeln!(s, "<!-- camera pose from easyhec: base_from_camera ({base} -> {camera_frame}, OpenCV optical frame) -->");
            let _ = writeln!(s, "<link name=\"{camera_frame}\"/>");
            let _ = writeln!(
                s,
                "<joint name=\"{camera_frame}_joint\" type=\"fixed\">\n  <parent link=\"{base}\"/>\n  <child link=\"{camera_frame}\"/>\n  <origin xyz=\"{:.12} {:.12} {:.12}\" rpy=\"{:.12} {:.12} {:.12}\"/>\n</joint>",
                t.x, t.y, t.z, r, p, y
            );
        }
    }
    s
}
