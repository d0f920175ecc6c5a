//! `[segmenter] kind = "sam"`: a SAM-family encoder and decoder written here byte by byte
//! (no weights exist in the repository and none are downloaded) segment a frame from the
//! prompt the segmenter builds out of a render. The encoder is a "redness" logit pooled to a
//! low-resolution embedding; the decoder takes the box the prompt's first two points span and
//! keeps the red inside it. So a mask that matches the robot proves the frame was fitted to the
//! encoder's square, the box was mapped into that square and the decoder's logits mapped back,
//! for both resize modes; the decoders' inputs are declared in another order than the
//! encoder's outputs, so they are wired by name. Red clutter outside the box, and inside the
//! box but beyond the band from the render, stays out. Bad models fail when the segmenter is
//! built, with one line naming the config, the field and the file.

mod common;

use easyhec::config::SegmenterConfig;

#[cfg(not(feature = "onnx"))]
#[test]
fn without_the_feature_a_sam_config_says_how_to_rebuild() {
    let cfg: SegmenterConfig =
        toml::from_str("kind = \"sam\"\nencoder = \"e.onnx\"\ndecoder = \"d.onnx\"\n").unwrap();
    let err = match easyhec::segment::build(&cfg, std::path::Path::new("cell.toml")) {
        Ok(_) => panic!("a sam segmenter was built without the onnx feature"),
        Err(e) => e.to_string(),
    };
    assert_eq!(
        err,
        "cell.toml: segmenter.kind: \"sam\" runs the model with tract, which this build leaves out: rebuild with --features onnx"
    );
}

#[test]
fn prompt_sizes_are_bounded_before_any_model_is_read() {
    let cfg: SegmenterConfig =
        toml::from_str("kind = \"sam\"\nencoder = \"e.onnx\"\ndecoder = \"d.onnx\"\npoints = 17\n")
            .unwrap();
    let err = cfg
        .validate(std::path::Path::new("cell.toml"))
        .unwrap_err()
        .to_string();
    assert_eq!(
        err,
        "cell.toml: segmenter.points: is 17: allowed 0 to 16 interior points per view"
    );
    let unknown = toml::from_str::<SegmenterConfig>(
        "kind = \"sam\"\nencoder = \"e.onnx\"\ndecoder = \"d.onnx\"\nresize = \"crop\"\n",
    )
    .unwrap_err()
    .to_string();
    assert!(
        unknown.contains("longest-side") && unknown.contains("stretch"),
        "{unknown}"
    );
}

#[test]
fn a_segmenter_file_is_checked_as_a_cell_config_would_be() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("sam.toml");
    let write = |body: &str| std::fs::write(&path, format!("[segmenter]\n{body}")).unwrap();
    write("kind = \"sam\"\nencoder = \"m/e.onnx\"\ndecoder = \"m/d.onnx\"\nresize = \"stretch\"\n");
    let SegmenterConfig::Sam(sam) = SegmenterConfig::from_file(&path).unwrap() else {
        panic!("not a sam table")
    };
    // Paths stay relative to the file, which the segmenter is built against.
    assert_eq!(sam.encoder, std::path::Path::new("m/e.onnx"));
    write("kind = \"sam\"\nencoder = \"e.onnx\"\ndecoder = \"d.onnx\"\npoints = 40\n");
    let err = SegmenterConfig::from_file(&path).unwrap_err().to_string();
    assert_eq!(
        err,
        format!(
            "{}: segmenter.points: is 40: allowed 0 to 16 interior points per view",
            path.display()
        )
    );
    write("kind = \"sam\"\nencoder = \"e.onnx\"\ndecodr = \"d.onnx\"\n");
    // The line is the table's: a table tagged by `kind` is read whole before its keys are.
    let err = SegmenterConfig::from_file(&path).unwrap_err().to_string();
    assert!(
        err.starts_with(&format!(
            "{}: line 1: unknown field `decodr`",
            path.display()
        )),
        "{err}"
    );
    write("kind = \"sam\"\nencoder = \"e.onnx\"\ndecoder = \"d.onnx\"\npoints = \"three\"\n");
    let err = SegmenterConfig::from_file(&path).unwrap_err().to_string();
    assert!(
        err.starts_with(&format!("{}: line 1: ", path.display())) && err.contains("three"),
        "{err}"
    );
    write("kind = \"sim-truth\"\n");
    let err = SegmenterConfig::from_file(&path).unwrap_err().to_string();
    assert_eq!(
        err,
        format!(
            "{}: segmenter.kind: \"sim-truth\" reads a simulated camera's truth, which recorded images do not carry; allowed: builtin, onnx, sam",
            path.display()
        )
    );
    // Through the command line, a missing model is named beside the file that names it.
    write("kind = \"sam\"\nencoder = \"e.onnx\"\ndecoder = \"d.onnx\"\n");
    let run = dir.path().join("run");
    common::synth_run(
        &run,
        "xarm6",
        &["--seed", "1", "--views", "2", "--images", "easy"],
    );
    let out = common::solve_run(
        &run,
        &["--segmenter", path.to_str().unwrap(), "--ignore-masks"],
    );
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert!(!out.status.success());
    let expected = if cfg!(feature = "onnx") {
        "segmenter.encoder: "
    } else {
        "segmenter.kind: \"sam\" runs the model with tract"
    };
    assert!(
        stderr.contains(&format!("{}: {expected}", path.display())),
        "{stderr}"
    );
    assert!(!run.join("result.json").exists());
}

/// The template a cell with its own SAM export copies: a hardware camera, a guess to prompt
/// from, and the model files named relative to the config.
#[test]
fn the_shipped_template_names_a_sam_export_and_a_guess() {
    let cfg = easyhec::config::read_config(
        &common::repo_root().join("config/sam-segmenter.toml.example"),
    )
    .unwrap_or_else(|e| panic!("{e}"));
    let SegmenterConfig::Sam(sam) = &cfg.segmenter else {
        panic!("{:?}", cfg.segmenter)
    };
    assert_eq!(sam.encoder, std::path::Path::new("sam_vit_b.encoder.onnx"));
    assert_eq!(sam.decoder, std::path::Path::new("sam_vit_b.decoder.onnx"));
    assert_eq!(
        sam.resize,
        easyhec::config::segmenter::SamResize::LongestSide
    );
    assert!(cfg.calibration.initial_guess.is_some());
}

#[cfg(feature = "onnx")]
mod with_tract {
    use super::*;

    use crate::common::onnx_pb::{
        graph_model, initializer, int64_initializer, node, value_info, with_int, with_tensor, Dim,
        Fixed, Named, Pb,
    };
    use easyhec::mask::Mask;
    use easyhec::segment::{Segmenter, ViewInput};
    use easyhec_drivers::Frame;

    /// The encoder's square side and the decoder's low-resolution side (2 px per cell).
    const SIDE: i64 = 64;
    const LOW: i64 = 32;

    /// The redness logit of a SAM-normalised pixel: about +7 on the robot's red, below -4 on
    /// the scene's grey and on the zero padding.
    const REDNESS: [f32; 3] = [4.0, -4.0, 0.0];
    const REDNESS_BIAS: f32 = -4.0;

    /// An encoder `image` [1,3,64,64] -> the redness at full resolution and pooled 2x2, under
    /// the names `embedding` and `detail` (in that order).
    fn encoder(input_dims: [i64; 4]) -> Vec<u8> {
        graph_model(
            vec![
                node("Conv", &["image", "W", "B"], "detail", &[]),
                node(
                    "AveragePool",
                    &["detail"],
                    "embedding",
                    &[("kernel_shape", &[2, 2]), ("strides", &[2, 2])],
                ),
            ],
            vec![
                initializer("W", &[1, 3, 1, 1], &REDNESS),
                initializer("B", &[1], &[REDNESS_BIAS]),
            ],
            vec![value_info("image", &input_dims.map(Fixed))],
            vec![
                value_info("embedding", &[Fixed(1), Fixed(1), Fixed(LOW), Fixed(LOW)]),
                value_info("detail", &[Fixed(1), Fixed(1), Fixed(SIDE), Fixed(SIDE)]),
            ],
        )
    }

    /// The square's coordinate of each low-resolution cell centre along x (or y).
    fn centres(along_x: bool) -> Vec<f32> {
        let cell = (SIDE / LOW) as f32;
        let mut v = Vec::with_capacity((LOW * LOW) as usize);
        for y in 0..LOW {
            for x in 0..LOW {
                let k = if along_x { x } else { y } as f32;
                v.push((k + 0.5) * cell - 0.5);
            }
        }
        v
    }

    /// The decoder's nodes: the box of prompt points 0 and 1 (as x0, y0, x1, y1), its signed
    /// inside distance per cell, and that distance capped by the red embedding: `right`.
    fn box_nodes() -> (Vec<Pb>, Vec<Pb>) {
        let gather = |from: &str, index: &str, out: &str| {
            with_int(node("Gather", &[from, index], out, &[]), "axis", 1)
        };
        let nodes = vec![
            gather("point_coords", "i0", "c0"),
            gather("point_coords", "i1", "c1"),
            gather("c0", "i0", "x0"),
            gather("c0", "i1", "y0"),
            gather("c1", "i0", "x1"),
            gather("c1", "i1", "y1"),
            node("Sub", &["gx", "x0"], "dx0", &[]),
            node("Sub", &["x1", "gx"], "dx1", &[]),
            node("Sub", &["gy", "y0"], "dy0", &[]),
            node("Sub", &["y1", "gy"], "dy1", &[]),
            node("Min", &["dx0", "dx1", "dy0", "dy1"], "inside", &[]),
            node("Min", &["inside", "embedding"], "right", &[]),
        ];
        let grid = [1, 1, LOW, LOW];
        let inits = vec![
            int64_initializer("i0", &[], &[0]),
            int64_initializer("i1", &[], &[1]),
            initializer("gx", &grid, &centres(true)),
            initializer("gy", &grid, &centres(false)),
        ];
        (nodes, inits)
    }

    /// Nodes that turn `right` into `checked`: the same where `point_labels` are the box's
    /// corners then three interior points, and `orig_im_size` is the frame's height and
    /// width; nothing anywhere otherwise.
    fn prompt_checks() -> (Vec<Pb>, Vec<Pb>) {
        let all_equal = |a: &str, b: &str, out: &str| {
            let eq = format!("{out}_eq");
            let f = format!("{out}_f");
            vec![
                node("Equal", &[a, b], &eq, &[]),
                with_int(node("Cast", &[&eq], &f, &[]), "to", 1),
                with_int(node("ReduceMin", &[&f], out, &[]), "keepdims", 0),
            ]
        };
        let mut nodes = all_equal("point_labels", "want_labels", "labels_ok");
        nodes.extend(all_equal("orig_im_size", "want_size", "size_ok"));
        nodes.extend([
            node("Mul", &["labels_ok", "size_ok"], "ok", &[]),
            node("Mul", &["ok", "thousand"], "ok_k", &[]),
            node("Sub", &["ok_k", "five_hundred"], "gate", &[]),
            node("Min", &["right", "gate"], "checked", &[]),
        ]);
        let inits = vec![
            initializer("want_labels", &[1, 5], &[2.0, 3.0, 1.0, 1.0, 1.0]),
            initializer("want_size", &[2], &[H as f32, W as f32]),
            initializer("thousand", &[], &[1000.0]),
            initializer("five_hundred", &[], &[500.0]),
        ];
        (nodes, inits)
    }

    /// A SAM-style decoder: `masks` masks scored by `iou_predictions` (two: the wrong one
    /// first, scored lower; four: SAM's single-mask token first, scored lowest), every optional
    /// prompt input declared before the embedding, the prompt checked, and a full-size output
    /// as SAM's export has.
    fn sam_decoder(masks: usize) -> Vec<u8> {
        let (mut nodes, mut inits) = box_nodes();
        let (checks, check_inits) = prompt_checks();
        nodes.extend(checks);
        inits.extend(check_inits);
        nodes.push(node("Neg", &["checked"], "wrong", &[]));
        let (order, scores): (&[&str], &[f32]) = if masks == 2 {
            (&["wrong", "checked"], &[0.1, 0.9])
        } else {
            (
                &["checked", "wrong", "wrong", "wrong"],
                &[0.1, 0.5, 0.6, 0.9],
            )
        };
        nodes.push(with_int(
            node("Concat", order, "low_res_masks", &[]),
            "axis",
            1,
        ));
        let k = masks as i64;
        nodes.push(with_tensor(
            node("Constant", &[], "iou_predictions", &[]),
            "value",
            initializer("", &[1, k], scores),
        ));
        // SAM's full-size masks, shaped by the values of `orig_im_size`: never typed, since
        // the segmenter prunes it.
        nodes.push(with_int(
            node("Cast", &["orig_im_size"], "size_i64", &[]),
            "to",
            7,
        ));
        nodes.push(node("ConstantOfShape", &["size_i64"], "masks", &[]));
        graph_model(
            nodes,
            inits,
            vec![
                value_info("point_coords", &[Fixed(1), Fixed(5), Fixed(2)]),
                value_info("point_labels", &[Fixed(1), Fixed(5)]),
                value_info("mask_input", &[Fixed(1), Fixed(1), Fixed(LOW), Fixed(LOW)]),
                value_info("has_mask_input", &[Fixed(1)]),
                value_info("orig_im_size", &[Fixed(2)]),
                value_info("embedding", &[Fixed(1), Fixed(1), Fixed(LOW), Fixed(LOW)]),
            ],
            vec![
                value_info(
                    "low_res_masks",
                    &[Fixed(1), Fixed(k), Fixed(LOW), Fixed(LOW)],
                ),
                value_info("iou_predictions", &[Fixed(1), Fixed(k)]),
                value_info("masks", &[Named("h"), Named("w")]),
            ],
        )
    }

    /// A SAM 2-style decoder, as samexporter writes one: both encoder outputs, in the other
    /// order, a `mask_input` whose first dimension is symbolic, and three masks called `masks`
    /// (the right one scored highest) with their `iou_predictions`.
    fn sam2_decoder() -> Vec<u8> {
        let (mut nodes, inits) = box_nodes();
        nodes.push(node("Neg", &["right"], "wrong", &[]));
        nodes.push(with_int(
            node("Concat", &["wrong", "right", "wrong"], "masks", &[]),
            "axis",
            1,
        ));
        nodes.push(with_tensor(
            node("Constant", &[], "iou_predictions", &[]),
            "value",
            initializer("", &[1, 3], &[0.2, 0.9, 0.5]),
        ));
        graph_model(
            nodes,
            inits,
            vec![
                value_info("detail", &[Fixed(1), Fixed(1), Fixed(SIDE), Fixed(SIDE)]),
                value_info("embedding", &[Fixed(1), Fixed(1), Fixed(LOW), Fixed(LOW)]),
                value_info("point_coords", &[Fixed(1), Named("n"), Fixed(2)]),
                value_info("point_labels", &[Fixed(1), Named("n")]),
                value_info(
                    "mask_input",
                    &[Named("n"), Fixed(1), Fixed(LOW), Fixed(LOW)],
                ),
                value_info("has_mask_input", &[Fixed(1)]),
            ],
            vec![
                value_info("masks", &[Fixed(1), Fixed(3), Fixed(LOW), Fixed(LOW)]),
                value_info("iou_predictions", &[Fixed(1), Fixed(3)]),
            ],
        )
    }

    /// Frame size: wider than tall, so `longest-side` pads the square below the frame.
    const W: u32 = 96;
    const H: u32 = 64;

    fn rect(x0: u32, y0: u32, x1: u32, y1: u32) -> impl Fn(u32, u32) -> bool {
        move |x, y| (x0..=x1).contains(&x) && (y0..=y1).contains(&y)
    }

    /// The robot: an L of two bars.
    fn on_robot(x: u32, y: u32) -> bool {
        rect(20, 10, 59, 25)(x, y) || rect(20, 10, 35, 55)(x, y)
    }

    /// Red clutter: inside the L's box but beyond the band from it, and outside the box.
    fn on_clutter(x: u32, y: u32) -> bool {
        rect(46, 38, 56, 50)(x, y) || rect(75, 20, 90, 40)(x, y)
    }

    fn mask_of(f: impl Fn(u32, u32) -> bool) -> Mask {
        let mut m = Mask::new(W, H);
        for y in 0..H {
            for x in 0..W {
                m.set(x, y, f(x, y));
            }
        }
        m
    }

    /// The red robot and red clutter on grey, with a little texture.
    fn frame() -> Frame {
        let mut rgb = Vec::with_capacity((W * H * 3) as usize);
        for y in 0..H {
            for x in 0..W {
                let t = ((x * 7 + y * 13) % 11) as i32 - 5;
                let px: [i32; 3] = if on_robot(x, y) || on_clutter(x, y) {
                    [200 + t, 30 + t, 40 + t]
                } else {
                    [128 + t, 126 + t, 124 + t]
                };
                rgb.extend(px.map(|c| c.clamp(0, 255) as u8));
            }
        }
        Frame {
            width: W,
            height: H,
            rgb,
            captured_at: std::time::SystemTime::now(),
            sequence: 0,
        }
    }

    /// The segmenter of `table` (a `[segmenter]` body), with `encoder` and `decoder` written
    /// beside the config as `e.onnx` and `d.onnx`.
    fn build(encoder: &[u8], decoder: &[u8], table: &str) -> Result<Box<dyn Segmenter>, String> {
        let dir = tempfile::tempdir().unwrap();
        std::fs::write(dir.path().join("e.onnx"), encoder).unwrap();
        std::fs::write(dir.path().join("d.onnx"), decoder).unwrap();
        let cfg: SegmenterConfig = toml::from_str(table).unwrap();
        easyhec::segment::build(&cfg, &dir.path().join("cell.toml")).map_err(|e| e.to_string())
    }

    fn error(encoder: &[u8], decoder: &[u8], table: &str) -> String {
        match build(encoder, decoder, table) {
            Ok(_) => panic!("accepted:\n{table}"),
            Err(e) => e,
        }
    }

    const SAM: &str = "kind = \"sam\"\nencoder = \"e.onnx\"\ndecoder = \"d.onnx\"\n";
    const SQUARE: [i64; 4] = [1, 3, SIDE, SIDE];

    /// The mask drawn with the robot's own silhouette as the render, and a 4 px band.
    fn prompted_mask(s: &dyn Segmenter) -> Mask {
        prompted_mask_with_band(s, 4.0)
    }

    /// The mask drawn with the robot's own silhouette as the render, and `band_px`.
    fn prompted_mask_with_band(s: &dyn Segmenter, band_px: f32) -> Mask {
        let frame = frame();
        let prior = mask_of(on_robot);
        let views = [ViewInput {
            frame: &frame,
            prior: Some(&prior),
            band_px,
        }];
        let mut masks = s.segment_views(&views).unwrap_or_else(|e| panic!("{e}"));
        masks.remove(0)
    }

    /// Checks `mask` against the robot: high IoU, no clutter.
    fn assert_robot_only(mask: &Mask, what: &str) {
        let robot = mask_of(on_robot);
        let iou = mask.iou(&robot);
        assert!(iou >= 0.9, "{what}: IoU {iou}");
        let clutter = (0..H)
            .flat_map(|y| (0..W).map(move |x| (x, y)))
            .filter(|&(x, y)| on_clutter(x, y) && mask.get(i64::from(x), i64::from(y)))
            .count();
        assert_eq!(clutter, 0, "{what}: {clutter} clutter pixels in the mask");
    }

    #[test]
    fn a_sam_style_model_draws_the_robot_from_the_render_alone() {
        for masks in [2, 4] {
            let s =
                build(&encoder(SQUARE), &sam_decoder(masks), SAM).unwrap_or_else(|e| panic!("{e}"));
            assert_eq!(s.name(), "sam");
            assert!(s.uses_context());
            let what = format!("sam, longest-side, {masks} masks");
            assert_robot_only(&prompted_mask(s.as_ref()), &what);
            // A frame with no robot in it is not served the last frame's encoder outputs.
            let mut empty = frame();
            for px in empty.rgb.chunks_exact_mut(3) {
                px.copy_from_slice(&[128, 126, 124]);
            }
            let prior = mask_of(on_robot);
            let views = [ViewInput {
                frame: &empty,
                prior: Some(&prior),
                band_px: 4.0,
            }];
            let drawn = s.segment_views(&views).unwrap().remove(0);
            assert!(
                drawn.data.iter().all(|&m| m == 0),
                "{what}: a stale encoding"
            );
        }
        // A band too wide for any interior point to be sure: the prompt carries the box and
        // padding only, and this decoder, which wants three points, draws nothing.
        let s = build(&encoder(SQUARE), &sam_decoder(2), SAM).unwrap();
        let drawn = prompted_mask_with_band(s.as_ref(), 7.0);
        assert!(
            drawn.data.iter().all(|&m| m == 0),
            "the labels went unchecked"
        );
    }

    #[test]
    fn a_sam2_style_model_fed_a_stretched_frame_draws_the_same() {
        let table = format!("{SAM}resize = \"stretch\"\n");
        let s = build(&encoder(SQUARE), &sam2_decoder(), &table).unwrap_or_else(|e| panic!("{e}"));
        assert_robot_only(&prompted_mask(s.as_ref()), "sam 2, stretch");
    }

    /// A decoder that ignores its prompt and marks the top half of the square.
    fn top_half_decoder() -> Vec<u8> {
        graph_model(
            vec![node("Sub", &["half", "gy"], "low_res_masks", &[])],
            vec![
                initializer("half", &[1], &[(SIDE as f32 - 1.0) / 2.0]),
                initializer("gy", &[1, 1, LOW, LOW], &centres(false)),
            ],
            vec![
                value_info("embedding", &[Fixed(1), Fixed(1), Fixed(LOW), Fixed(LOW)]),
                value_info("point_coords", &[Fixed(1), Fixed(5), Fixed(2)]),
                value_info("point_labels", &[Fixed(1), Fixed(5)]),
            ],
            vec![value_info(
                "low_res_masks",
                &[Fixed(1), Fixed(1), Fixed(LOW), Fixed(LOW)],
            )],
        )
    }

    #[test]
    fn the_square_maps_back_onto_the_frame_as_the_resize_says() {
        let frame = frame();
        let everywhere = mask_of(|_, _| true);
        let rows_marked = |table: &str| {
            let s = build(&encoder(SQUARE), &top_half_decoder(), table).unwrap();
            let views = [ViewInput {
                frame: &frame,
                prior: Some(&everywhere),
                band_px: 4.0,
            }];
            let mask = s.segment_views(&views).unwrap().remove(0);
            let full_rows: Vec<u32> = (0..H)
                .filter(|&y| (0..W).all(|x| mask.get(i64::from(x), i64::from(y))))
                .collect();
            let empty_rows = (0..H)
                .filter(|&y| (0..W).all(|x| !mask.get(i64::from(x), i64::from(y))))
                .count() as u32;
            assert_eq!(full_rows.len() as u32 + empty_rows, H, "{table}");
            full_rows
        };
        // Longest side: the 96x64 frame fills 64x43 of the square, so its top half (32 rows
        // of 64) is the frame's top 48 rows; stretched, the frame's top 32.
        assert_eq!(rows_marked(SAM), (0..48).collect::<Vec<_>>());
        let stretch = format!("{SAM}resize = \"stretch\"\n");
        assert_eq!(rows_marked(&stretch), (0..32).collect::<Vec<_>>());
    }

    #[test]
    fn views_without_an_estimate_are_drawn_by_the_builtin_segmenter() {
        let s = build(&encoder(SQUARE), &sam_decoder(2), SAM).unwrap();
        let still = frame();
        // A second frame with the robot's upright bar moved right: the builtin segmenter
        // draws what changed, with no prompt.
        let mut moved = frame();
        for y in 0..H {
            for x in 0..W {
                let red =
                    rect(20, 10, 59, 25)(x, y) || rect(38, 10, 53, 55)(x, y) || on_clutter(x, y);
                if red != (on_robot(x, y) || on_clutter(x, y)) {
                    let i = ((y * W + x) * 3) as usize;
                    let px = if red { [200, 30, 40] } else { [128, 126, 124] };
                    moved.rgb[i..i + 3].copy_from_slice(&px);
                }
            }
        }
        let views = [
            ViewInput {
                frame: &still,
                prior: None,
                band_px: 8.0,
            },
            ViewInput {
                frame: &moved,
                prior: None,
                band_px: 8.0,
            },
        ];
        let drawn = s.segment_views(&views).unwrap();
        let builtin =
            easyhec::segment::builtin::segment_views(&views, &Default::default()).unwrap();
        assert_eq!(drawn, builtin);
        // With an estimate for one view only, that one is prompted and the other drawn as the
        // builtin segmenter draws it.
        let prior = mask_of(on_robot);
        let mixed = [
            ViewInput {
                frame: &moved,
                prior: None,
                band_px: 8.0,
            },
            ViewInput {
                frame: &still,
                prior: Some(&prior),
                band_px: 4.0,
            },
        ];
        let drawn = s.segment_views(&mixed).unwrap();
        let builtin =
            easyhec::segment::builtin::segment_views(&mixed, &Default::default()).unwrap();
        assert_eq!(drawn[0], builtin[0]);
        assert_robot_only(&drawn[1], "the prompted view beside an unprompted one");
        // One frame with no estimate and no other view has nothing to prompt from.
        let err = s.segment(&still).unwrap_err().to_string();
        assert!(err.contains("initial_guess"), "{err}");
    }

    /// A decoder whose `low_res_masks` are its input `source` as is, with the prompt inputs
    /// `prompts` (of `point_coords` and `point_labels`) besides.
    fn identity_decoder(source: &str, prompts: &[&str]) -> Vec<u8> {
        let low = [Fixed(1), Fixed(1), Fixed(LOW), Fixed(LOW)];
        let mut inputs = vec![value_info(source, &low)];
        for &p in prompts {
            inputs.push(match p {
                "point_coords" => value_info(p, &[Fixed(1), Fixed(5), Fixed(2)]),
                _ => value_info(p, &[Fixed(1), Fixed(5)]),
            });
        }
        graph_model(
            vec![node("Identity", &[source], "low_res_masks", &[])],
            vec![],
            inputs,
            vec![value_info("low_res_masks", &low)],
        )
    }

    #[test]
    fn a_bump_check_draws_only_its_new_frame() {
        // The recorded view's frame is broken: drawing it would fail, so a mask means the
        // check left it alone, as a prompted view needs nothing from the others.
        let s = build(&encoder(SQUARE), &sam_decoder(2), SAM).unwrap();
        assert!(s.prompted_views_stand_alone());
        let robot = common::load_robot("xarm6");
        let camera = easyhec::camera::Intrinsics {
            width: W,
            height: H,
            fx: 60.0,
            fy: 60.0,
            cx: 47.5,
            cy: 31.5,
            distortion: None,
        };
        let pose = easyhec::nalgebra::Isometry3::look_at_rh(
            &easyhec::nalgebra::Point3::new(1.6, 0.2, 0.6),
            &easyhec::nalgebra::Point3::new(0.0, 0.0, 0.35),
            &easyhec::nalgebra::Vector3::z(),
        );
        let joints = vec![0.0, -0.35, -0.6, 0.0, 0.95, 0.0];
        let mut broken = frame();
        broken.rgb.truncate(10);
        let recorded = vec![(broken, vec![0.4, -0.2, -0.9, 0.0, 0.8, 0.0])];
        let mask = easyhec::pipeline::segment_solve::segment_among_recorded(
            &easyhec::render::CpuRenderer,
            s.as_ref(),
            &robot,
            &camera,
            frame(),
            &joints,
            recorded,
            &pose,
            4.0,
        )
        .unwrap_or_else(|e| panic!("{e}"));
        assert!(mask.is_some());
    }

    #[test]
    fn models_that_do_not_fit_the_contract_are_refused_when_built() {
        let err = error(&encoder([1, 3, 64, 48]), &sam_decoder(2), SAM);
        assert!(
            err.contains("cell.toml: segmenter.encoder: ")
                && err.ends_with("e.onnx takes a 1x3x64x48 input: a SAM encoder takes a fixed square 1x3xSxS image (S up to 4096); export it with its input size fixed"),
            "{err}"
        );
        // A decoder with no point labels cannot be prompted.
        let no_labels = identity_decoder("embedding", &["point_coords"]);
        let err = error(&encoder(SQUARE), &no_labels, SAM);
        assert!(
            err.contains("cell.toml: segmenter.decoder: ")
                && err.ends_with("d.onnx has no input 'point_labels': a SAM decoder is prompted through point_coords and point_labels"),
            "{err}"
        );
        // An input the encoder does not make is named, with what the encoder does make.
        let stranger = identity_decoder("embedding2", &["point_coords", "point_labels"]);
        let err = error(&encoder(SQUARE), &stranger, SAM);
        assert!(
            err.contains("takes an input 'embedding2' that is neither an encoder output (embedding, detail) nor a prompt"),
            "{err}"
        );
        // A mask_input is filled with zeros when the decoder is loaded, so its shape must be
        // fixed (but for the prompt count) and bounded.
        let with_mask_input = |dims: &[Dim]| {
            let (mut nodes, inits) = box_nodes();
            nodes.push(node("Identity", &["right"], "low_res_masks", &[]));
            let inputs = vec![
                value_info("embedding", &[Fixed(1), Fixed(1), Fixed(LOW), Fixed(LOW)]),
                value_info("point_coords", &[Fixed(1), Fixed(5), Fixed(2)]),
                value_info("point_labels", &[Fixed(1), Fixed(5)]),
                value_info("mask_input", dims),
            ];
            let out = value_info(
                "low_res_masks",
                &[Fixed(1), Fixed(1), Fixed(LOW), Fixed(LOW)],
            );
            graph_model(nodes, inits, inputs, vec![out])
        };
        let huge = with_mask_input(&[Fixed(1), Fixed(1), Fixed(4096), Fixed(2048)]);
        let err = error(&encoder(SQUARE), &huge, SAM);
        assert!(
            err.ends_with("d.onnx takes a mask_input of 1x1x4096x2048: allowed at most 4194304 values (SAM: 1x1x256x256)"),
            "{err}"
        );
        let shapeless = with_mask_input(&[Fixed(1), Named("c"), Fixed(LOW), Fixed(LOW)]);
        let err = error(&encoder(SQUARE), &shapeless, SAM);
        assert!(
            err.ends_with("d.onnx has a mask_input with no fixed shape: export it with one (SAM: 1x1x256x256)"),
            "{err}"
        );
        // A decoder whose masks go by another name; `masks` only counts where no
        // `orig_im_size` could have sized them to the frame.
        let renamed = |name: &str, with_size: bool| {
            let (mut nodes, inits) = box_nodes();
            nodes.push(node("Identity", &["right"], name, &[]));
            let mut inputs = vec![
                value_info("embedding", &[Fixed(1), Fixed(1), Fixed(LOW), Fixed(LOW)]),
                value_info("point_coords", &[Fixed(1), Fixed(5), Fixed(2)]),
                value_info("point_labels", &[Fixed(1), Fixed(5)]),
            ];
            if with_size {
                inputs.push(value_info("orig_im_size", &[Fixed(2)]));
            }
            let out = value_info(name, &[Fixed(1), Fixed(1), Fixed(LOW), Fixed(LOW)]);
            graph_model(nodes, inits, inputs, vec![out])
        };
        let err = error(&encoder(SQUARE), &renamed("logits", false), SAM);
        assert!(
            err.ends_with("d.onnx has no output 'low_res_masks' or 'masks': a SAM decoder returns its masks' logits over the encoder's square under that name"),
            "{err}"
        );
        let err = error(&encoder(SQUARE), &renamed("masks", true), SAM);
        assert!(err.contains("has no output 'low_res_masks': "), "{err}");
        // Files that are not there are named.
        let dir = tempfile::tempdir().unwrap();
        let cfg: SegmenterConfig = toml::from_str(SAM).unwrap();
        let err = easyhec::segment::build(&cfg, &dir.path().join("cell.toml"))
            .err()
            .unwrap()
            .to_string();
        assert!(
            err.contains("segmenter.encoder: ") && err.contains("e.onnx: no such file"),
            "{err}"
        );
    }
}
