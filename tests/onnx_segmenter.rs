//! `[segmenter] kind = "onnx"`: models written here byte by byte (a hand-rolled protobuf
//! encoder; no file is downloaded) segment a synthetic frame whose robot region is known.
//! A 1x1 convolution over RGB makes a "redness" logit, so a red robot on a grey, white, green
//! and dark scene is separable exactly; the tests check the mask's IoU against the region at
//! the frame size, through a smaller model input, through torchvision-style normalisation in
//! BGR 0–255, through a 2-class softmax (both channels) and a channels-last model. Bad models
//! and keys fail when the segmenter is built with one line naming the config, the field and
//! the model. Without the `onnx` feature a cell that asks for it says how to rebuild.

mod common;

use easyhec::cell::Cell;
use easyhec::config::SegmenterConfig;

/// A cell on the shipped xArm6 URDF with a simulated arm and camera and `segmenter` as its
/// segmenter table.
fn cell_text(segmenter: &str) -> String {
    format!(
        r#"[robot]
urdf = "{}"

[arm]
kind = "sim"
start = [0.0, -0.35, -0.6, 0.0, 0.95, 0.0]

[camera]
kind = "sim"
width = 320
height = 240
fx = 300.0
fy = 300.0
cx = 160.0
cy = 120.0
truth = {{ eye = [1.25, 0.55, 0.75], look_at = [0.15, 0.0, 0.3] }}

{segmenter}
"#,
        common::repo_root()
            .join("robots/xarm6/robot.urdf")
            .display()
    )
}

#[cfg(not(feature = "onnx"))]
#[test]
fn without_the_feature_an_onnx_cell_says_how_to_rebuild() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("cell.toml");
    std::fs::write(
        &path,
        cell_text("[segmenter]\nkind = \"onnx\"\nmodel = \"robot.onnx\"\n"),
    )
    .unwrap();
    let err = match Cell::open(&path) {
        Ok(_) => panic!("an onnx cell opened without the onnx feature"),
        Err(e) => e.to_string(),
    };
    assert_eq!(
        err,
        format!(
            "{}: segmenter.kind: \"onnx\" runs the model with tract, which this build leaves out: rebuild with --features onnx",
            path.display()
        )
    );
    // The table itself parses: only building needs the feature.
    let parsed: SegmenterConfig = toml::from_str("kind = \"onnx\"\nmodel = \"m.onnx\"\n").unwrap();
    assert!(matches!(parsed, SegmenterConfig::Onnx(_)));
}

#[cfg(feature = "onnx")]
mod with_tract {
    use super::*;
    use std::path::Path;

    use easyhec::mask::Mask;
    use easyhec::segment::Segmenter;
    use easyhec_drivers::Frame;

    use crate::common::onnx_pb::{
        initializer, model, node, value_info, with_int, Dim, Fixed, Named,
    };

    /// The redness logit of an RGB pixel in 0–1: positive on the robot's red, at most -12 on
    /// the scene's other colours.
    const REDNESS: [f32; 3] = [20.0, -20.0, -20.0];
    const REDNESS_BIAS: f32 = -4.0;

    /// A 1x1 convolution with `weights` (`out` rows of `input_channels`) and `bias`, then
    /// `tail` (an activation, or nothing), from `image` [1, C, H, W] to `mask`.
    fn conv_model(
        input_dims: [Dim; 4],
        weights: &[f32],
        bias: &[f32],
        tail: Option<&str>,
    ) -> Vec<u8> {
        let out = bias.len() as i64;
        let in_c = weights.len() as i64 / out;
        let conv_out = if tail.is_some() { "logits" } else { "mask" };
        let mut nodes = vec![node("Conv", &["image", "W", "B"], conv_out, &[])];
        if let Some(op) = tail {
            nodes.push(node(op, &["logits"], "mask", &[]));
        }
        model(
            nodes,
            vec![
                initializer("W", &[out, in_c, 1, 1], weights),
                initializer("B", &[out], bias),
            ],
            value_info("image", &input_dims),
            value_info(
                "mask",
                &[Fixed(1), Fixed(out), input_dims[2], input_dims[3]],
            ),
        )
    }

    /// The redness model (raw logits, for the default `activation = "sigmoid"`), fixed at
    /// `w`x`h`.
    fn redness(w: i64, h: i64) -> Vec<u8> {
        conv_model(
            [Fixed(1), Fixed(3), Fixed(h), Fixed(w)],
            &REDNESS,
            &[REDNESS_BIAS],
            None,
        )
    }

    // ---- The scene. ----

    /// Whether pixel centre (`x`, `y`) of a `w`x`h` frame is on the robot: a base block, a
    /// slanted capsule link and a disc joint, scaled with the frame.
    fn on_robot(x: f64, y: f64, w: f64, h: f64) -> bool {
        let (u, v) = (x / w, y / h);
        let base = (0.35..0.6).contains(&u) && (0.75..0.95).contains(&v);
        // Capsule from (0.47, 0.8) to (0.7, 0.3), radius 0.05 of the width.
        let (ax, ay, bx, by) = (0.47 * w, 0.8 * h, 0.7 * w, 0.3 * h);
        let (dx, dy) = (bx - ax, by - ay);
        let t = (((x - ax) * dx + (y - ay) * dy) / (dx * dx + dy * dy)).clamp(0.0, 1.0);
        let (px, py) = (ax + t * dx - x, ay + t * dy - y);
        let link = px * px + py * py <= (0.05 * w).powi(2);
        let joint = (x - bx).powi(2) + (y - by).powi(2) <= (0.08 * w).powi(2);
        base || link || joint
    }

    /// A `w`x`h` frame: the red robot (shaded) on a grey floor with a white table, a green
    /// box and a dark cable, plus a little deterministic texture; and its true mask.
    fn scene(w: u32, h: u32) -> (Frame, Mask) {
        let mut rgb = Vec::with_capacity((w * h * 3) as usize);
        let mut truth = Mask::new(w, h);
        for y in 0..h {
            for x in 0..w {
                let (fx, fy) = (x as f64 + 0.5, y as f64 + 0.5);
                let (u, v) = (fx / w as f64, fy / h as f64);
                let texture = ((x * 7 + y * 13) % 11) as i32 - 5;
                let px: [i32; 3] = if on_robot(fx, fy, w as f64, h as f64) {
                    truth.set(x, y, true);
                    let shade = (40.0 * u) as i32;
                    [190 + shade, 25 + texture, 35 + texture]
                } else if u < 0.3 && v < 0.5 {
                    [230, 228, 225]
                } else if u > 0.8 && v > 0.6 {
                    [50, 150, 60]
                } else if (v - 0.6).abs() < 0.02 {
                    [25, 25, 30]
                } else {
                    [128 + texture, 126 + texture, 124 + texture]
                };
                rgb.extend(px.iter().map(|&c| c.clamp(0, 255) as u8));
            }
        }
        let frame = Frame {
            width: w,
            height: h,
            rgb,
            captured_at: std::time::SystemTime::now(),
            sequence: 0,
        };
        (frame, truth)
    }

    /// The segmenter of `table` (a `[segmenter]` body without the header), with `model`
    /// written as `robot.onnx` beside the config.
    fn build(model: &[u8], table: &str) -> Result<Box<dyn Segmenter>, String> {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("robot.onnx"), model).unwrap();
        let cfg: SegmenterConfig = toml::from_str(table).unwrap();
        easyhec::segment::build(&cfg, &dir.path().join("cell.toml")).map_err(|e| e.to_string())
    }

    fn segmenter(model: &[u8], table: &str) -> Box<dyn Segmenter> {
        build(model, table).unwrap_or_else(|e| panic!("{e}"))
    }

    /// The build error of `table` (the test fails if it builds).
    fn error(model: &[u8], table: &str) -> String {
        match build(model, table) {
            Ok(_) => panic!("accepted:\n{table}"),
            Err(e) => e,
        }
    }

    const PLAIN: &str = "kind = \"onnx\"\nmodel = \"robot.onnx\"\n";

    fn iou(s: &dyn Segmenter, w: u32, h: u32) -> f64 {
        let (frame, truth) = scene(w, h);
        let mask = s.segment(&frame).unwrap();
        assert_eq!((mask.width, mask.height), (w, h));
        mask.iou(&truth)
    }

    #[test]
    fn redness_model_at_frame_size_finds_the_robot() {
        let s = segmenter(&redness(320, 240), PLAIN);
        assert_eq!(s.name(), "onnx");
        let logits_iou = iou(s.as_ref(), 320, 240);
        assert!(logits_iou >= 0.99, "IoU {logits_iou}");
        // A model that ends in its own Sigmoid wants activation = "none"; the default would
        // apply a second sigmoid (always above 0.5) and take the whole frame.
        let with_sigmoid = conv_model(
            [Fixed(1), Fixed(3), Fixed(240), Fixed(320)],
            &REDNESS,
            &[REDNESS_BIAS],
            Some("Sigmoid"),
        );
        let s = segmenter(&with_sigmoid, &format!("{PLAIN}activation = \"none\"\n"));
        let probs_iou = iou(s.as_ref(), 320, 240);
        assert!(probs_iou >= 0.99, "IoU {probs_iou}");
        let doubled = iou(segmenter(&with_sigmoid, PLAIN).as_ref(), 320, 240);
        assert!(doubled < 0.2, "IoU {doubled} with a second sigmoid");
    }

    #[test]
    fn frame_is_resized_to_the_model_input_and_back() {
        // A 4x smaller fixed input; its size comes from the model.
        let s = segmenter(&redness(80, 60), PLAIN);
        let iou_small = iou(s.as_ref(), 320, 240);
        assert!(iou_small >= 0.95, "IoU {iou_small} through an 80x60 input");
        // A model with symbolic height and width runs at the configured size.
        let dynamic = conv_model(
            [Fixed(1), Fixed(3), Named("height"), Named("width")],
            &REDNESS,
            &[REDNESS_BIAS],
            None,
        );
        let s = segmenter(
            &dynamic,
            &format!("{PLAIN}input_width = 320\ninput_height = 240\n"),
        );
        let iou_full = iou(s.as_ref(), 320, 240);
        assert!(iou_full >= 0.99, "IoU {iou_full} at 320x240");
        // Non-square stretch: a 200x100 input for a 320x240 frame.
        let s = segmenter(
            &dynamic,
            &format!("{PLAIN}input_width = 200\ninput_height = 100\n"),
        );
        let iou_stretched = iou(s.as_ref(), 320, 240);
        assert!(iou_stretched >= 0.95, "IoU {iou_stretched} through 200x100");
    }

    #[test]
    fn normalisation_and_channel_order_reach_the_model() {
        // A model trained on BGR in 0-255 with torchvision's mean/std: its weights undo the
        // normalisation, so only the right preprocessing gives back the redness logit.
        let mean_rgb = [0.485f32 * 255.0, 0.456 * 255.0, 0.406 * 255.0];
        let std_rgb = [0.229f32 * 255.0, 0.224 * 255.0, 0.225 * 255.0];
        let bgr = [2, 1, 0];
        let mean: Vec<f32> = bgr.iter().map(|&c| mean_rgb[c]).collect();
        let std: Vec<f32> = bgr.iter().map(|&c| std_rgb[c]).collect();
        let weights: Vec<f32> = bgr
            .iter()
            .map(|&c| REDNESS[c] * std_rgb[c] / 255.0)
            .collect();
        let bias = REDNESS_BIAS
            + (0..3)
                .map(|c| REDNESS[c] * mean_rgb[c] / 255.0)
                .sum::<f32>();
        let model = conv_model(
            [Fixed(1), Fixed(3), Fixed(240), Fixed(320)],
            &weights,
            &[bias],
            None,
        );
        let table = format!(
            "{PLAIN}channel_order = \"bgr\"\npixel_range = \"0-255\"\nmean = [{}, {}, {}]\nstd = [{}, {}, {}]\n",
            mean[0], mean[1], mean[2], std[0], std[1], std[2]
        );
        let good = iou(segmenter(&model, &table).as_ref(), 320, 240);
        assert!(good >= 0.99, "IoU {good} with the model's preprocessing");
        // The same model fed plain RGB 0-1 finds something else.
        let plain = iou(segmenter(&model, PLAIN).as_ref(), 320, 240);
        assert!(plain < 0.5, "IoU {plain} without normalisation");
        // RGB instead of BGR, the rest right: also wrong.
        let swapped = iou(
            segmenter(&model, &table.replace("\"bgr\"", "\"rgb\"")).as_ref(),
            320,
            240,
        );
        assert!(swapped < 0.5, "IoU {swapped} with the channels swapped");
    }

    #[test]
    fn softmax_output_channel_selects_the_class() {
        // Two raw logits per pixel: background (negated redness), robot.
        let weights: Vec<f32> = REDNESS.iter().map(|w| -w).chain(REDNESS).collect();
        let model = conv_model(
            [Fixed(1), Fixed(3), Fixed(120), Fixed(160)],
            &weights,
            &[-REDNESS_BIAS, REDNESS_BIAS],
            None,
        );
        let robot = segmenter(
            &model,
            &format!("{PLAIN}activation = \"softmax\"\nchannel = 1\n"),
        );
        let robot_iou = iou(robot.as_ref(), 160, 120);
        assert!(robot_iou >= 0.99, "IoU {robot_iou} of channel 1");
        // Channel 0 is the background: the complement of the robot.
        let background = segmenter(
            &model,
            &format!("{PLAIN}activation = \"softmax\"\nchannel = 0\n"),
        );
        let (frame, truth) = scene(160, 120);
        let mask = background.segment(&frame).unwrap();
        let complement = Mask {
            data: truth.data.iter().map(|&v| 1 - v).collect(),
            ..truth.clone()
        };
        let bg_iou = mask.iou(&complement);
        assert!(
            bg_iou >= 0.99,
            "IoU {bg_iou} of channel 0 with the background"
        );
        assert!(mask.iou(&truth) < 0.01);
        // Raw logits with threshold 0 give the same robot.
        let raw = segmenter(
            &model,
            &format!("{PLAIN}activation = \"none\"\nthreshold = 0.0\nchannel = 1\n"),
        );
        let raw_iou = iou(raw.as_ref(), 160, 120);
        assert!(raw_iou >= 0.99, "IoU {raw_iou} of raw logits");
    }

    #[test]
    fn channels_last_model_reads_and_writes_nhwc() {
        // [1, H, W, 3] -> NCHW -> 2-class conv -> softmax -> back to [1, H, W, 2].
        let weights: Vec<f32> = REDNESS.iter().map(|w| -w).chain(REDNESS).collect();
        let bytes = model(
            vec![
                node("Transpose", &["image"], "chw", &[("perm", &[0, 3, 1, 2])]),
                node("Conv", &["chw", "W", "B"], "logits", &[]),
                // Opset 13's Softmax defaults to the last axis: the classes are axis 1 here.
                with_int(node("Softmax", &["logits"], "probs", &[]), "axis", 1),
                node("Transpose", &["probs"], "mask", &[("perm", &[0, 2, 3, 1])]),
            ],
            vec![
                initializer("W", &[2, 3, 1, 1], &weights),
                initializer("B", &[2], &[-REDNESS_BIAS, REDNESS_BIAS]),
            ],
            value_info("image", &[Fixed(1), Fixed(60), Fixed(80), Fixed(3)]),
            value_info("mask", &[Fixed(1), Fixed(60), Fixed(80), Fixed(2)]),
        );
        let s = segmenter(
            &bytes,
            &format!("{PLAIN}layout = \"nhwc\"\nactivation = \"none\"\nchannel = 1\n"),
        );
        let iou = iou(s.as_ref(), 320, 240);
        assert!(iou >= 0.95, "IoU {iou} through an 80x60 NHWC model");
        // Read as NCHW, the same model is refused with the fix.
        let err = error(&bytes, PLAIN);
        assert!(
            err.contains("segmenter.model: ")
                && err.contains("takes 60 input channel(s) (1x60x80x3)")
                && err.ends_with("the channels look last, set layout = \"nhwc\""),
            "{err}"
        );
    }

    #[test]
    fn missing_or_unreadable_model_names_config_field_and_file() {
        let dir = tempfile::tempdir().unwrap();
        let config = dir.path().join("cell.toml");
        let cfg: SegmenterConfig =
            toml::from_str("kind = \"onnx\"\nmodel = \"models/nope.onnx\"\n").unwrap();
        let err = easyhec::segment::build(&cfg, &config)
            .err()
            .unwrap()
            .to_string();
        assert_eq!(
            err,
            format!(
                "{}: segmenter.model: {}: no such file (the path is relative to this config)",
                config.display(),
                dir.path().join("models/nope.onnx").display()
            )
        );
        for junk in [&b"not a model, just text\n"[..], &[0xff, 0xff, 0xff, 0x01]] {
            let err = error(junk, PLAIN);
            assert!(
                err.contains("cell.toml: segmenter.model: ")
                    && err.contains("robot.onnx is not an ONNX model tract can read (")
                    && err.ends_with("export it with torch.onnx.export (weights inside the file)")
                    && !err.contains('\n'),
                "{err}"
            );
        }
    }

    #[test]
    fn wrong_input_shape_is_refused_at_load() {
        let rank3 = model(
            vec![node("Sigmoid", &["image"], "mask", &[])],
            vec![],
            value_info("image", &[Fixed(1), Fixed(3), Fixed(40)]),
            value_info("mask", &[Fixed(1), Fixed(3), Fixed(40)]),
        );
        let err = error(&rank3, PLAIN);
        assert!(
            err.contains("segmenter.model: ")
                && err.ends_with("robot.onnx takes a rank-3 input (1x3x40): the onnx segmenter feeds one colour image, 1x3xHxW (layout = \"nchw\")"),
            "{err}"
        );
        let grey = conv_model(
            [Fixed(1), Fixed(1), Fixed(40), Fixed(40)],
            &[1.0],
            &[0.0],
            None,
        );
        let err = error(&grey, PLAIN);
        assert!(
            err.ends_with("robot.onnx takes 1 input channel(s) (1x1x40x40), not 3 colour channels: the onnx segmenter feeds 1x3xHxW (layout = \"nchw\")"),
            "{err}"
        );
        let batch4 = conv_model(
            [Fixed(4), Fixed(3), Fixed(40), Fixed(40)],
            &REDNESS,
            &[0.0],
            None,
        );
        let err = error(&batch4, PLAIN);
        assert!(err.contains("takes a batch of 4 (4x3x40x40)"), "{err}");
        // A fixed size the config contradicts; a symbolic one the config leaves open.
        let err = error(&redness(80, 60), &format!("{PLAIN}input_width = 100\n"));
        assert!(
            err.contains("segmenter.input_width: is 100 but ")
                && err.ends_with("takes a fixed width of 80 (1x3x60x80): set 80 or leave it out"),
            "{err}"
        );
        let dynamic = conv_model(
            [Fixed(1), Fixed(3), Named("h"), Named("w")],
            &REDNESS,
            &[0.0],
            None,
        );
        let err = error(&dynamic, PLAIN);
        assert!(
            err.contains("segmenter.input_width: ")
                && err.ends_with("does not fix its input width (1x3x?x?): set input_width and input_height to the size it was trained at"),
            "{err}"
        );
    }

    #[test]
    fn output_and_channel_out_of_range_are_refused_at_load() {
        let m = redness(80, 60);
        let err = error(&m, &format!("{PLAIN}channel = 1\n"));
        assert!(
            err.contains("cell.toml: segmenter.channel: ")
                && err.ends_with("robot.onnx: channel 1 is out of range: output 0 (1x1x60x80) has 1 channel(s) (0..=0)"),
            "{err}"
        );
        let err = error(&m, &format!("{PLAIN}output = 2\n"));
        assert!(
            err.contains("segmenter.output: output 2 is out of range: ")
                && err.ends_with("robot.onnx has 1 output(s) (0..=0)"),
            "{err}"
        );
        let err = error(&m, &format!("{PLAIN}activation = \"softmax\"\n"));
        assert!(
            err.contains("segmenter.activation: ")
                && err.ends_with("use activation = \"sigmoid\" or \"none\""),
            "{err}"
        );
        let err = error(&m, &format!("{PLAIN}std = [1.0, 0.0, 1.0]\n"));
        assert!(
            err.ends_with("segmenter.std: entry 1 is 0: give a finite, non-zero divisor"),
            "{err}"
        );
    }

    #[test]
    fn cell_with_an_onnx_segmenter_builds() {
        let dir = tempfile::tempdir().unwrap();
        std::fs::create_dir(dir.path().join("models")).unwrap();
        std::fs::write(dir.path().join("models/robot.onnx"), redness(80, 60)).unwrap();
        let path = dir.path().join("cell.toml");
        std::fs::write(
            &path,
            cell_text(
                "[segmenter]\nkind = \"onnx\"\nmodel = \"models/robot.onnx\"\nmean = [0.0, 0.0, 0.0]\nthreshold = 0.5\n",
            ),
        )
        .unwrap();
        let cell = Cell::open(&path).unwrap_or_else(|e| panic!("{e}"));
        assert_eq!(cell.units[0].segmenter.name(), "onnx");
        let (frame, truth) = scene(320, 240);
        let iou = cell.units[0].segmenter.segment(&frame).unwrap().iou(&truth);
        assert!(iou >= 0.95, "IoU {iou}");
        // A model that is not there stops the cell before the arm or camera is opened.
        std::fs::remove_file(dir.path().join("models/robot.onnx")).unwrap();
        let err = Cell::open(&path).err().unwrap().to_string();
        assert!(err.contains("segmenter.model: "), "{err}");
        // Unknown keys are refused by name.
        std::fs::write(
            &path,
            cell_text("[segmenter]\nkind = \"onnx\"\nmodel = \"m.onnx\"\nthreshhold = 0.5\n"),
        )
        .unwrap();
        let err = Cell::open(&path).err().unwrap().to_string();
        assert!(err.contains("threshhold"), "{err}");
    }

    #[test]
    fn shipped_template_parses() {
        let cfg = easyhec::config::read_config(
            &common::repo_root().join("config/onnx-segmenter.toml.example"),
        )
        .unwrap_or_else(|e| panic!("{e}"));
        let SegmenterConfig::Onnx(onnx) = &cfg.segmenter else {
            panic!("{:?}", cfg.segmenter)
        };
        assert_eq!(onnx.model, Path::new("robot-seg.onnx"));
        assert_eq!(onnx.mean, [0.485, 0.456, 0.406]);
        assert_eq!((onnx.channel, onnx.threshold), (1, 0.5));
    }
}
