//! Camera intrinsics from calibration files.
//!
//! Neither V4L2 nor GenICam carries a camera matrix, so a hardware camera's intrinsics always
//! come from a file made by a calibration tool, at one image size. Two formats are read:
//!
//! - ROS `camera_info` YAML (camera_calibration_parsers): `image_width`, `image_height`,
//!   `camera_matrix: {rows, cols, data}`, `distortion_model`, `distortion_coefficients`;
//!   `rectification_matrix` and `projection_matrix` are ignored (they describe a rectified
//!   stereo image, not the raw frames we grab).
//! - OpenCV `FileStorage` YAML: a `%YAML:1.0` first line and matrices tagged
//!   `!!opencv-matrix` (`rows`, `cols`, `dt`, `data`), keys `camera_matrix` / `cameraMatrix`,
//!   `distortion_coefficients` / `dist_coeffs` / `distCoeffs`, `image_width` / `image_height`
//!   (or `image_size` / `imageSize` as `[w, h]`).
//!
//! A generic YAML parser rejects OpenCV's `%YAML:1.0` directive (YAML wants a space), so that
//! line is dropped before parsing; tags are unwrapped after. Every error names the file, the
//! field and what to do, in one line.
//!
//! Only what [`Intrinsics`] can represent is accepted: a pinhole matrix without skew and
//! `plumb_bob` distortion. Four coefficients (k1 k2 p1 p2) get k3 = 0; eight `rational`
//! coefficients are accepted when k4 k5 k6 are zero (then they are `plumb_bob`); fisheye
//! (`equidistant`) and non-zero rational or thin-prism terms are refused, since silently
//! dropping them would bias the calibration. All-zero distortion is stored as `None` (an ideal
//! pinhole), which spares the solver a no-op resampling.

use std::path::{Path, PathBuf};

use serde_yaml_ng::Value;

use crate::Intrinsics;

/// A calibration file that cannot be used, with the file, the field at fault and the fix.
#[derive(Clone, Debug, PartialEq, thiserror::Error)]
#[error("{}: {field}: {message}", file.display())]
pub struct IntrinsicsError {
    /// The calibration file.
    pub file: PathBuf,
    /// The YAML key at fault (`camera_matrix.data`, `image_width`, …).
    pub field: String,
    /// What is wrong and how to fix it.
    pub message: String,
}

impl IntrinsicsError {
    fn new(file: &Path, field: impl Into<String>, message: impl Into<String>) -> Self {
        IntrinsicsError {
            file: file.to_path_buf(),
            field: field.into(),
            message: message.into(),
        }
    }
}

/// Which tool wrote a calibration file (only used to word messages and for tests).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CalibrationFormat {
    /// ROS `camera_info` YAML.
    RosCameraInfo,
    /// OpenCV `FileStorage` YAML (`%YAML:1.0`, `!!opencv-matrix`).
    OpenCv,
}

/// Largest calibration file read, bytes.
const MAX_CALIBRATION_FILE_BYTES: u64 = 1 << 20;

/// Reads a calibration file (ROS `camera_info` or OpenCV YAML, told apart by content).
pub fn load_intrinsics(file: &Path) -> Result<Intrinsics, IntrinsicsError> {
    // A FIFO or a device would block, and a calibration file is a few kB.
    if let Ok(meta) = std::fs::metadata(file) {
        if !meta.is_file() || meta.len() > MAX_CALIBRATION_FILE_BYTES {
            return Err(IntrinsicsError::new(
                file,
                "intrinsics",
                format!("allowed: a regular file of at most {MAX_CALIBRATION_FILE_BYTES} bytes"),
            ));
        }
    }
    let text = std::fs::read_to_string(file).map_err(|e| {
        IntrinsicsError::new(
            file,
            "intrinsics",
            format!("cannot read the calibration file: {e}"),
        )
    })?;
    parse_intrinsics(&text, file).map(|(intrinsics, _)| intrinsics)
}

/// Parses calibration YAML; `file` only names the source in errors.
pub fn parse_intrinsics(
    text: &str,
    file: &Path,
) -> Result<(Intrinsics, CalibrationFormat), IntrinsicsError> {
    let format = if text.trim_start().starts_with("%YAML:") {
        CalibrationFormat::OpenCv
    } else {
        CalibrationFormat::RosCameraInfo
    };
    // OpenCV's directive is not valid YAML 1.1/1.2; it only ever sits on the first lines.
    let body: String = text
        .lines()
        .filter(|line| !line.trim_start().starts_with("%YAML"))
        .map(|line| format!("{line}\n"))
        .collect();
    let root: Value = serde_yaml_ng::from_str(&body).map_err(|e| {
        let at = e
            .location()
            .map(|l| format!("line {}", l.line() + 1))
            .unwrap_or_else(|| "yaml".to_string());
        IntrinsicsError::new(file, at, format!("not valid YAML: {e}").replace('\n', " "))
    })?;
    let root = untag(root);
    if !root.is_mapping() {
        return Err(IntrinsicsError::new(
            file,
            "(top level)",
            "expected a mapping with camera_matrix and image_width/image_height (ROS camera_info or OpenCV calibration YAML)",
        ));
    }
    let reader = Reader { file, root: &root };
    let (width, height) = reader.image_size()?;
    let (matrix_key, k) = reader.matrix(&["camera_matrix", "cameraMatrix", "K"], 3, 3)?;
    let k_field = format!("{matrix_key}.data");
    if k[3] != 0.0 || k[6] != 0.0 || k[7] != 0.0 || (k[8] - 1.0).abs() > 1e-9 {
        return Err(IntrinsicsError::new(
            file,
            k_field,
            format!(
                "{k:?} is not a camera matrix [fx 0 cx; 0 fy cy; 0 0 1]: use the raw intrinsic matrix K, not a projection or rectification matrix"
            ),
        ));
    }
    let (fx, skew, cx, fy, cy) = (k[0], k[1], k[2], k[4], k[5]);
    for (name, v) in [("fx", fx), ("fy", fy)] {
        if !(v.is_finite() && v > 0.0) {
            return Err(IntrinsicsError::new(
                file,
                k_field,
                format!("{name} = {v}: focal lengths must be positive pixels"),
            ));
        }
    }
    if !(cx.is_finite() && cy.is_finite()) {
        return Err(IntrinsicsError::new(
            file,
            k_field,
            "the principal point is not a finite number",
        ));
    }
    if skew.abs() > 1e-9 * fx {
        return Err(IntrinsicsError::new(
            file,
            k_field,
            format!("skew {skew} is not supported: recalibrate with zero skew (OpenCV's default)"),
        ));
    }
    let distortion = reader.distortion()?;
    let intrinsics = Intrinsics {
        width,
        height,
        fx,
        fy,
        cx,
        cy,
        distortion,
    };
    if let Some((field, allowed)) = intrinsics.range_problem() {
        return Err(IntrinsicsError::new(file, field, allowed));
    }
    Ok((intrinsics, format))
}

/// Refuses frames of a size other than the one the intrinsics were calibrated at: the focal
/// lengths and principal point are in that image's pixels, and a rescaled or cropped stream
/// would silently shift every projection.
pub fn check_frame_size(
    intrinsics: &Intrinsics,
    file: &Path,
    width: u32,
    height: u32,
) -> Result<(), IntrinsicsError> {
    if intrinsics.width == width && intrinsics.height == height {
        return Ok(());
    }
    let field = if intrinsics.width != width {
        "image_width"
    } else {
        "image_height"
    };
    Err(IntrinsicsError::new(
        file,
        field,
        format!(
            "calibrated at {}x{} but the camera delivers {width}x{height}: set the camera to {}x{} or calibrate at {width}x{height}",
            intrinsics.width, intrinsics.height, intrinsics.width, intrinsics.height
        ),
    ))
}

/// Strips YAML tags (`!!opencv-matrix`) everywhere, keeping the tagged values.
fn untag(value: Value) -> Value {
    match value {
        Value::Tagged(tagged) => untag(tagged.value),
        Value::Mapping(map) => {
            Value::Mapping(map.into_iter().map(|(k, v)| (k, untag(v))).collect())
        }
        Value::Sequence(seq) => Value::Sequence(seq.into_iter().map(untag).collect()),
        other => other,
    }
}

/// Field lookups with errors that name the file and key.
struct Reader<'a> {
    file: &'a Path,
    root: &'a Value,
}

impl Reader<'_> {
    fn err(&self, field: impl Into<String>, message: impl Into<String>) -> IntrinsicsError {
        IntrinsicsError::new(self.file, field, message)
    }

    /// The first of `keys` present at the top level, with its key.
    fn first<'k>(&self, keys: &[&'k str]) -> Option<(&'k str, &Value)> {
        keys.iter().find_map(|k| self.root.get(*k).map(|v| (*k, v)))
    }

    fn image_size(&self) -> Result<(u32, u32), IntrinsicsError> {
        let dim = |key: &str, v: &Value| -> Result<u32, IntrinsicsError> {
            v.as_u64()
                .filter(|&n| n > 0)
                .and_then(|n| u32::try_from(n).ok())
                .ok_or_else(|| {
                    self.err(
                        key,
                        format!("{}: expected a positive whole number of pixels", show(v)),
                    )
                })
        };
        if let (Some(w), Some(h)) = (self.root.get("image_width"), self.root.get("image_height")) {
            return Ok((dim("image_width", w)?, dim("image_height", h)?));
        }
        if let Some((key, v)) = self.first(&["image_size", "imageSize"]) {
            let pair = v
                .as_sequence()
                .filter(|s| s.len() == 2)
                .ok_or_else(|| self.err(key, format!("{}: expected [width, height]", show(v))))?;
            return Ok((dim(key, &pair[0])?, dim(key, &pair[1])?));
        }
        let missing = if self.root.get("image_width").is_some() {
            "image_height"
        } else {
            "image_width"
        };
        Err(self.err(
            missing,
            "missing: the file must record the image size it was calibrated at (image_width and image_height)",
        ))
    }

    /// A `{rows, cols, data}` matrix (ROS or OpenCV) under one of `keys`, row-major, checked
    /// to be `rows`×`cols` when those are given; a bare list is accepted as well.
    fn matrix(
        &self,
        keys: &[&'static str],
        rows: usize,
        cols: usize,
    ) -> Result<(&'static str, Vec<f64>), IntrinsicsError> {
        let (key, v) = self.first(keys).ok_or_else(|| {
            self.err(
                keys[0],
                format!(
                    "missing: expected the {rows}x{cols} camera matrix under {}",
                    keys.join(" or ")
                ),
            )
        })?;
        let data = self.numbers(key, v)?;
        if data.len() != rows * cols {
            return Err(self.err(
                format!("{key}.data"),
                format!(
                    "{} values: expected {rows}x{cols} = {}",
                    data.len(),
                    rows * cols
                ),
            ));
        }
        Ok((key, data))
    }

    /// The numbers of a matrix value: `data` of a `{rows, cols, data}` map (checking
    /// rows·cols against its length) or a bare sequence.
    fn numbers(&self, key: &str, v: &Value) -> Result<Vec<f64>, IntrinsicsError> {
        let (field, seq) = match v {
            Value::Sequence(seq) => (key.to_string(), seq),
            Value::Mapping(_) => {
                let field = format!("{key}.data");
                let seq = v.get("data").and_then(Value::as_sequence).ok_or_else(|| {
                    self.err(&field, "missing: expected a list of numbers (row-major)")
                })?;
                if let (Some(r), Some(c)) = (
                    v.get("rows").and_then(Value::as_u64),
                    v.get("cols").and_then(Value::as_u64),
                ) {
                    if r * c != seq.len() as u64 {
                        return Err(self.err(
                            &field,
                            format!("{} values but rows x cols = {r}x{c}", seq.len()),
                        ));
                    }
                }
                (field, seq)
            }
            other => {
                return Err(self.err(
                    key,
                    format!(
                        "{}: expected {{rows, cols, data}} or a list of numbers",
                        show(other)
                    ),
                ))
            }
        };
        seq.iter()
            .enumerate()
            .map(|(i, x)| {
                x.as_f64().filter(|f| f.is_finite()).ok_or_else(|| {
                    self.err(
                        &field,
                        format!("entry {i} ({}) is not a finite number", show(x)),
                    )
                })
            })
            .collect()
    }

    /// `plumb_bob` coefficients, or `None` for an ideal lens.
    fn distortion(&self) -> Result<Option<[f64; 5]>, IntrinsicsError> {
        let model = match self.root.get("distortion_model") {
            None => None,
            Some(v) => Some(v.as_str().ok_or_else(|| {
                self.err(
                    "distortion_model",
                    format!("{}: expected a model name", show(v)),
                )
            })?),
        };
        let Some((key, v)) = self.first(&[
            "distortion_coefficients",
            "dist_coeffs",
            "distCoeffs",
            "distortion_coeffs",
            "D",
        ]) else {
            return Ok(None);
        };
        let d = self.numbers(key, v)?;
        let field = format!("{key}.data");
        match model {
            None | Some("plumb_bob" | "rational_polynomial") => {}
            Some("equidistant" | "fisheye") => {
                return Err(self.err(
                    "distortion_model",
                    format!("{:?} (fisheye) cannot be represented: recalibrate with the plumb_bob (pinhole) model", model.unwrap_or_default()),
                ))
            }
            Some(other) => {
                return Err(self.err(
                    "distortion_model",
                    format!("{other:?} is not supported: use plumb_bob (k1 k2 p1 p2 k3)"),
                ))
            }
        }
        let coeffs: [f64; 5] = match d.len() {
            0 => return Ok(None),
            4 => [d[0], d[1], d[2], d[3], 0.0],
            5 => [d[0], d[1], d[2], d[3], d[4]],
            8 | 12 | 14 if d[5..].iter().all(|&x| x == 0.0) => [d[0], d[1], d[2], d[3], d[4]],
            8 | 12 | 14 => {
                return Err(self.err(
                    field,
                    format!(
                        "{} coefficients with non-zero terms beyond k3 ({:?}): only plumb_bob (k1 k2 p1 p2 k3) is supported; recalibrate without the rational/thin-prism/tilt model",
                        d.len(),
                        &d[5..]
                    ),
                ))
            }
            n => {
                return Err(self.err(
                    field,
                    format!("{n} coefficients: expected 4 or 5 (k1 k2 p1 p2 [k3]), or 8 with k4 k5 k6 = 0"),
                ))
            }
        };
        if model == Some("plumb_bob") && d.len() > 5 {
            return Err(self.err(
                field,
                format!("plumb_bob has 5 coefficients, the file gives {}", d.len()),
            ));
        }
        Ok(if coeffs.iter().all(|&x| x == 0.0) {
            None
        } else {
            Some(coeffs)
        })
    }
}

/// A YAML value in one line, for messages.
fn show(v: &Value) -> String {
    serde_yaml_ng::to_string(v)
        .map(|s| s.trim().replace('\n', " "))
        .unwrap_or_else(|_| "?".to_string())
}

#[cfg(test)]
mod tests {
    use super::*;

    const ROS: &str = "\
image_width: 640
image_height: 480
camera_name: webcam
camera_matrix:
  rows: 3
  cols: 3
  data: [610.5, 0, 321.25, 0, 612.0, 238.75, 0, 0, 1]
distortion_model: plumb_bob
distortion_coefficients:
  rows: 1
  cols: 5
  data: [-0.11, 0.042, 0.0005, -0.0003, 0]
rectification_matrix:
  rows: 3
  cols: 3
  data: [1, 0, 0, 0, 1, 0, 0, 0, 1]
projection_matrix:
  rows: 3
  cols: 4
  data: [600, 0, 320, 0, 0, 600, 240, 0, 0, 0, 1, 0]
";

    const OPENCV: &str = "%YAML:1.0
---
calibration_time: \"Mon 01 Jan 2024\"
image_width: 640
image_height: 480
flags: 0
camera_matrix: !!opencv-matrix
   rows: 3
   cols: 3
   dt: d
   data: [ 6.1050000000000000e+02, 0., 3.2125000000000000e+02, 0.,
       612., 2.3875000000000000e+02, 0., 0., 1. ]
distortion_coefficients: !!opencv-matrix
   rows: 5
   cols: 1
   dt: d
   data: [ -1.1000000000000000e-01, 4.2000000000000000e-02,
       5.0000000000000001e-04, -2.9999999999999997e-04, 0. ]
avg_reprojection_error: 2.1e-01
";

    fn parse(text: &str) -> Result<(Intrinsics, CalibrationFormat), IntrinsicsError> {
        parse_intrinsics(text, Path::new("cam.yaml"))
    }

    fn expected() -> Intrinsics {
        Intrinsics {
            width: 640,
            height: 480,
            fx: 610.5,
            fy: 612.0,
            cx: 321.25,
            cy: 238.75,
            distortion: Some([-0.11, 0.042, 0.0005, -0.0003, 0.0]),
        }
    }

    #[test]
    fn ros_camera_info_reads_k_and_plumb_bob() {
        let (i, format) = parse(ROS).unwrap();
        assert_eq!(format, CalibrationFormat::RosCameraInfo);
        assert_eq!(i, expected());
    }

    #[test]
    fn opencv_file_storage_reads_the_same_intrinsics() {
        let (i, format) = parse(OPENCV).unwrap();
        assert_eq!(format, CalibrationFormat::OpenCv);
        assert_eq!(i.width, 640);
        assert_eq!(i.height, 480);
        assert_eq!((i.fx, i.fy, i.cx, i.cy), (610.5, 612.0, 321.25, 238.75));
        let d = i.distortion.unwrap();
        for (a, b) in d.iter().zip(expected().distortion.unwrap()) {
            assert!((a - b).abs() < 1e-15, "{d:?}");
        }
    }

    #[test]
    fn opencv_camel_case_keys_and_image_size_pair() {
        let text = "%YAML:1.0\nimageSize: [ 1280, 720 ]\ncameraMatrix: !!opencv-matrix\n   rows: 3\n   cols: 3\n   dt: d\n   data: [ 900., 0., 640., 0., 901., 360., 0., 0., 1. ]\ndistCoeffs: !!opencv-matrix\n   rows: 1\n   cols: 4\n   dt: d\n   data: [ 0.1, -0.2, 0.001, 0.002 ]\n";
        let (i, _) = parse(text).unwrap();
        assert_eq!(
            (i.width, i.height, i.fx, i.fy, i.cx, i.cy),
            (1280, 720, 900.0, 901.0, 640.0, 360.0)
        );
        assert_eq!(i.distortion, Some([0.1, -0.2, 0.001, 0.002, 0.0]));
    }

    #[test]
    fn rational_with_zero_extra_terms_is_plumb_bob_and_zero_distortion_is_none() {
        let rational = ROS.replace("plumb_bob", "rational_polynomial").replace(
            "cols: 5\n  data: [-0.11, 0.042, 0.0005, -0.0003, 0]",
            "cols: 8\n  data: [-0.11, 0.042, 0.0005, -0.0003, 0, 0, 0, 0]",
        );
        assert_ne!(rational, ROS);
        assert_eq!(parse(&rational).unwrap().0, expected());
        let zero = ROS.replace("[-0.11, 0.042, 0.0005, -0.0003, 0]", "[0, 0, 0, 0, 0]");
        assert_eq!(parse(&zero).unwrap().0.distortion, None);
    }

    #[test]
    fn unrepresentable_models_are_refused_with_the_field() {
        let cases = [
            (
                ROS.replace("plumb_bob", "equidistant").replace(
                    "cols: 5\n  data: [-0.11, 0.042, 0.0005, -0.0003, 0]",
                    "cols: 4\n  data: [0.1, 0.01, 0.001, 0.0001]",
                ),
                "distortion_model",
                "fisheye",
            ),
            (
                ROS.replace("plumb_bob", "rational_polynomial").replace(
                    "cols: 5\n  data: [-0.11, 0.042, 0.0005, -0.0003, 0]",
                    "cols: 8\n  data: [-0.11, 0.042, 0.0005, -0.0003, 0, 0.3, 0, 0]",
                ),
                "distortion_coefficients.data",
                "beyond k3",
            ),
            (
                ROS.replace(
                    "[-0.11, 0.042, 0.0005, -0.0003, 0]",
                    "[-0.11, 0.042, 0.0005]",
                )
                .replace("cols: 5", "cols: 3"),
                "distortion_coefficients.data",
                "3 coefficients",
            ),
            (
                ROS.replace("[610.5, 0, 321.25", "[610.5, 2.5, 321.25"),
                "camera_matrix.data",
                "skew",
            ),
            (
                ROS.replace("0, 0, 1]\ndistortion_model", "0, 0, 2]\ndistortion_model"),
                "camera_matrix.data",
                "not a camera matrix",
            ),
            (
                ROS.replace("238.75, 0, 0, 1]", "238.75, 0, 0]"),
                "camera_matrix.data",
                "8 values",
            ),
            (
                ROS.replace("image_height: 480\n", ""),
                "image_height",
                "missing",
            ),
            (
                ROS.replace("image_width: 640", "image_width: -640"),
                "image_width",
                "positive",
            ),
            (
                ROS.replace("camera_matrix:", "camera_matrx:"),
                "camera_matrix",
                "missing",
            ),
            (
                ROS.replace("data: [610.5,", "data: [abc,"),
                "camera_matrix.data",
                "entry 0",
            ),
        ];
        for (i, (text, field, needle)) in cases.iter().enumerate() {
            assert_ne!(text, ROS, "case {i} changed nothing");
            let e = parse(text).expect_err(&format!("case {i} accepted"));
            assert_eq!(e.field, *field, "case {i}: {e}");
            let line = e.to_string();
            assert!(
                line.starts_with("cam.yaml: ") && line.contains(needle) && !line.contains('\n'),
                "case {i}: {line}"
            );
        }
    }

    #[test]
    fn frame_size_mismatch_names_file_field_and_both_sizes() {
        let i = expected();
        assert!(check_frame_size(&i, Path::new("cam.yaml"), 640, 480).is_ok());
        let e = check_frame_size(&i, Path::new("cam.yaml"), 1280, 720).unwrap_err();
        assert_eq!(e.field, "image_width");
        let line = e.to_string();
        assert!(line.starts_with("cam.yaml: image_width: "), "{line}");
        assert!(
            line.contains("640x480") && line.contains("1280x720"),
            "{line}"
        );
        let e = check_frame_size(&i, Path::new("cam.yaml"), 640, 360).unwrap_err();
        assert_eq!(e.field, "image_height");
    }

    #[test]
    fn unreadable_and_malformed_files_get_one_line() {
        let e = load_intrinsics(Path::new("/nonexistent/cam.yaml")).unwrap_err();
        assert!(
            e.to_string()
                .starts_with("/nonexistent/cam.yaml: intrinsics: cannot read"),
            "{e}"
        );
        let e = parse("image_width: [1, 2\n").unwrap_err();
        assert!(e.field.starts_with("line "), "{e}");
        let e = parse("- 1\n- 2\n").unwrap_err();
        assert_eq!(e.field, "(top level)");
    }
}
