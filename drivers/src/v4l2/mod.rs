//! UVC webcams through V4L2.
//!
//! The device itself ([`V4l2Camera`], feature `v4l2`: the `v4l` crate, whose bindings are
//! generated with bindgen and so need libclang to build) is a thin shell around what is here and
//! always compiled, so that it is tested on machines without a `/dev/video*`:
//!
//! - [`yuyv_to_rgb`]: packed 4:2:2 `Y0 U Y1 V` to RGB8 with the BT.601 integer formulas
//!   (limited or full range, as the driver reports);
//! - [`mjpeg_to_rgb`]: Motion-JPEG frames to RGB8 (pure-Rust `zune-jpeg`). Many UVC cameras
//!   leave the Huffman tables out of their frames and rely on the standard ones (ITU-T T.81
//!   Annex K.3); those are put back before decoding;
//! - [`pick_device_by_name`]: which `/dev/videoN` a configured camera name means, over the
//!   device list the caller gathers (sysfs names plus capture capability), so the rule is tested
//!   with injected data.
//!
//! Intrinsics never come from V4L2 (it has no camera-matrix API); the camera takes them from
//! a calibration file ([`crate::intrinsics`]) and refuses a stream of another size.

use std::path::PathBuf;

#[cfg(feature = "v4l2")]
mod device;
#[cfg(feature = "v4l2")]
pub use device::{list_devices, V4l2Camera, V4l2Config};

/// The stream formats a webcam is asked for (both are what nearly every UVC camera offers).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum V4l2PixelFormat {
    /// Packed 4:2:2 `YUYV`: uncompressed, so low resolutions or frame rates over USB 2.
    Yuyv,
    /// Motion-JPEG `MJPG`: compressed, the usual way to full resolution at full rate.
    Mjpeg,
}

impl V4l2PixelFormat {
    /// The V4L2 four-character code.
    pub fn fourcc(self) -> [u8; 4] {
        match self {
            V4l2PixelFormat::Yuyv => *b"YUYV",
            V4l2PixelFormat::Mjpeg => *b"MJPG",
        }
    }
}

impl std::str::FromStr for V4l2PixelFormat {
    type Err = String;

    /// `YUYV` (or `YUY2`), `MJPG` (or `MJPEG`), case-insensitive.
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.to_ascii_uppercase().as_str() {
            "YUYV" | "YUY2" => Ok(V4l2PixelFormat::Yuyv),
            "MJPG" | "MJPEG" => Ok(V4l2PixelFormat::Mjpeg),
            _ => Err(format!("{s:?} is not supported: use \"YUYV\" or \"MJPG\"")),
        }
    }
}

/// A frame buffer that cannot be turned into RGB.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum FrameError {
    /// The buffer holds fewer bytes than its format and size need.
    #[error("frame buffer has {got} bytes; {width}x{height} needs {needed}")]
    TooShort {
        /// Bytes present.
        got: usize,
        /// Bytes needed.
        needed: usize,
        /// Frame width, pixels.
        width: u32,
        /// Frame height, pixels.
        height: u32,
    },
    /// The size cannot be stored in this format (odd YUYV width, a zero side, a short stride).
    #[error("{0}")]
    Geometry(String),
    /// A Motion-JPEG frame that does not decode, or decodes to another size.
    #[error("MJPEG frame: {0}")]
    Jpeg(String),
}

/// How the luma and chroma codes of a YUV frame map to light levels.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum YuvRange {
    /// "Studio" range: Y in 16..=235, U/V in 16..=240 (the V4L2 default for YUYV).
    Limited,
    /// Y and U/V over the whole 0..=255 (V4L2 `quantization = FullRange`, some JPEG-based
    /// cameras).
    Full,
}

fn clamp_u8(v: i32) -> u8 {
    v.clamp(0, 255) as u8
}

/// One YUV sample to RGB, BT.601. Limited range uses the integer form of Microsoft's
/// "Converting between YUV and RGB" (C = Y − 16, D = U − 128, E = V − 128;
/// R = (298C + 409E + 128) >> 8, G = (298C − 100D − 208E + 128) >> 8,
/// B = (298C + 516D + 128) >> 8); full range uses 1.402 / 0.344 / 0.714 / 1.772 in 8.8 fixed
/// point.
fn yuv_pixel(y: u8, u: u8, v: u8, range: YuvRange) -> [u8; 3] {
    let d = i32::from(u) - 128;
    let e = i32::from(v) - 128;
    match range {
        YuvRange::Limited => {
            let c = 298 * (i32::from(y) - 16);
            [
                clamp_u8((c + 409 * e + 128) >> 8),
                clamp_u8((c - 100 * d - 208 * e + 128) >> 8),
                clamp_u8((c + 516 * d + 128) >> 8),
            ]
        }
        YuvRange::Full => {
            // 1.402 ≈ 359/256, 0.344 ≈ 88/256, 0.714 ≈ 183/256, 1.772 ≈ 454/256.
            let c = i32::from(y) << 8;
            [
                clamp_u8((c + 359 * e + 128) >> 8),
                clamp_u8((c - 88 * d - 183 * e + 128) >> 8),
                clamp_u8((c + 454 * d + 128) >> 8),
            ]
        }
    }
}

/// Converts a packed YUYV (`Y0 U Y1 V`, two pixels sharing U and V) frame to row-major RGB8.
/// `stride_bytes` is the driver's bytes per line (at least `2 * width`; padding is skipped).
pub fn yuyv_to_rgb(
    buf: &[u8],
    width: u32,
    height: u32,
    stride_bytes: u32,
    range: YuvRange,
) -> Result<Vec<u8>, FrameError> {
    if width == 0 || height == 0 || !width.is_multiple_of(2) {
        return Err(FrameError::Geometry(format!(
            "YUYV {width}x{height}: the width must be even and both sides non-zero"
        )));
    }
    let row_bytes = 2 * width as usize;
    let stride = stride_bytes as usize;
    if stride < row_bytes {
        return Err(FrameError::Geometry(format!(
            "YUYV stride {stride} bytes is shorter than a {width}-pixel row ({row_bytes} bytes)"
        )));
    }
    let needed = stride * (height as usize - 1) + row_bytes;
    if buf.len() < needed {
        return Err(FrameError::TooShort {
            got: buf.len(),
            needed,
            width,
            height,
        });
    }
    let mut rgb = Vec::with_capacity(width as usize * height as usize * 3);
    for row in 0..height as usize {
        let line = &buf[row * stride..row * stride + row_bytes];
        for quad in line.chunks_exact(4) {
            let (y0, u, y1, v) = (quad[0], quad[1], quad[2], quad[3]);
            rgb.extend_from_slice(&yuv_pixel(y0, u, v, range));
            rgb.extend_from_slice(&yuv_pixel(y1, u, v, range));
        }
    }
    Ok(rgb)
}

/// The standard Huffman tables of ITU-T T.81 Annex K.3 as one DHT segment body: per table, the
/// class/id byte, 16 code-length counts and the symbols. Motion-JPEG streams without a DHT
/// marker are coded with these.
fn standard_dht_segment() -> Vec<u8> {
    const LUMA_DC_COUNTS: [u8; 16] = [0, 1, 5, 1, 1, 1, 1, 1, 1, 0, 0, 0, 0, 0, 0, 0];
    const CHROMA_DC_COUNTS: [u8; 16] = [0, 3, 1, 1, 1, 1, 1, 1, 1, 1, 1, 0, 0, 0, 0, 0];
    const LUMA_AC_COUNTS: [u8; 16] = [0, 2, 1, 3, 3, 2, 4, 3, 5, 5, 4, 4, 0, 0, 1, 125];
    const CHROMA_AC_COUNTS: [u8; 16] = [0, 2, 1, 2, 4, 4, 3, 4, 7, 5, 4, 4, 0, 1, 2, 119];
    // Both DC tables code the magnitude categories 0..=11 in order.
    const DC_SYMBOLS: [u8; 12] = [0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11];
    const LUMA_AC_SYMBOLS: [u8; 162] = [
        0x01, 0x02, 0x03, 0x00, 0x04, 0x11, 0x05, 0x12, 0x21, 0x31, 0x41, 0x06, 0x13, 0x51, 0x61,
        0x07, 0x22, 0x71, 0x14, 0x32, 0x81, 0x91, 0xa1, 0x08, 0x23, 0x42, 0xb1, 0xc1, 0x15, 0x52,
        0xd1, 0xf0, 0x24, 0x33, 0x62, 0x72, 0x82, 0x09, 0x0a, 0x16, 0x17, 0x18, 0x19, 0x1a, 0x25,
        0x26, 0x27, 0x28, 0x29, 0x2a, 0x34, 0x35, 0x36, 0x37, 0x38, 0x39, 0x3a, 0x43, 0x44, 0x45,
        0x46, 0x47, 0x48, 0x49, 0x4a, 0x53, 0x54, 0x55, 0x56, 0x57, 0x58, 0x59, 0x5a, 0x63, 0x64,
        0x65, 0x66, 0x67, 0x68, 0x69, 0x6a, 0x73, 0x74, 0x75, 0x76, 0x77, 0x78, 0x79, 0x7a, 0x83,
        0x84, 0x85, 0x86, 0x87, 0x88, 0x89, 0x8a, 0x92, 0x93, 0x94, 0x95, 0x96, 0x97, 0x98, 0x99,
        0x9a, 0xa2, 0xa3, 0xa4, 0xa5, 0xa6, 0xa7, 0xa8, 0xa9, 0xaa, 0xb2, 0xb3, 0xb4, 0xb5, 0xb6,
        0xb7, 0xb8, 0xb9, 0xba, 0xc2, 0xc3, 0xc4, 0xc5, 0xc6, 0xc7, 0xc8, 0xc9, 0xca, 0xd2, 0xd3,
        0xd4, 0xd5, 0xd6, 0xd7, 0xd8, 0xd9, 0xda, 0xe1, 0xe2, 0xe3, 0xe4, 0xe5, 0xe6, 0xe7, 0xe8,
        0xe9, 0xea, 0xf1, 0xf2, 0xf3, 0xf4, 0xf5, 0xf6, 0xf7, 0xf8, 0xf9, 0xfa,
    ];
    const CHROMA_AC_SYMBOLS: [u8; 162] = [
        0x00, 0x01, 0x02, 0x03, 0x11, 0x04, 0x05, 0x21, 0x31, 0x06, 0x12, 0x41, 0x51, 0x07, 0x61,
        0x71, 0x13, 0x22, 0x32, 0x81, 0x08, 0x14, 0x42, 0x91, 0xa1, 0xb1, 0xc1, 0x09, 0x23, 0x33,
        0x52, 0xf0, 0x15, 0x62, 0x72, 0xd1, 0x0a, 0x16, 0x24, 0x34, 0xe1, 0x25, 0xf1, 0x17, 0x18,
        0x19, 0x1a, 0x26, 0x27, 0x28, 0x29, 0x2a, 0x35, 0x36, 0x37, 0x38, 0x39, 0x3a, 0x43, 0x44,
        0x45, 0x46, 0x47, 0x48, 0x49, 0x4a, 0x53, 0x54, 0x55, 0x56, 0x57, 0x58, 0x59, 0x5a, 0x63,
        0x64, 0x65, 0x66, 0x67, 0x68, 0x69, 0x6a, 0x73, 0x74, 0x75, 0x76, 0x77, 0x78, 0x79, 0x7a,
        0x82, 0x83, 0x84, 0x85, 0x86, 0x87, 0x88, 0x89, 0x8a, 0x92, 0x93, 0x94, 0x95, 0x96, 0x97,
        0x98, 0x99, 0x9a, 0xa2, 0xa3, 0xa4, 0xa5, 0xa6, 0xa7, 0xa8, 0xa9, 0xaa, 0xb2, 0xb3, 0xb4,
        0xb5, 0xb6, 0xb7, 0xb8, 0xb9, 0xba, 0xc2, 0xc3, 0xc4, 0xc5, 0xc6, 0xc7, 0xc8, 0xc9, 0xca,
        0xd2, 0xd3, 0xd4, 0xd5, 0xd6, 0xd7, 0xd8, 0xd9, 0xda, 0xe2, 0xe3, 0xe4, 0xe5, 0xe6, 0xe7,
        0xe8, 0xe9, 0xea, 0xf2, 0xf3, 0xf4, 0xf5, 0xf6, 0xf7, 0xf8, 0xf9, 0xfa,
    ];
    let tables: [(u8, &[u8; 16], &[u8]); 4] = [
        (0x00, &LUMA_DC_COUNTS, &DC_SYMBOLS),
        (0x10, &LUMA_AC_COUNTS, &LUMA_AC_SYMBOLS),
        (0x01, &CHROMA_DC_COUNTS, &DC_SYMBOLS),
        (0x11, &CHROMA_AC_COUNTS, &CHROMA_AC_SYMBOLS),
    ];
    let mut body = Vec::with_capacity(420);
    for (class_id, counts, symbols) in tables {
        body.push(class_id);
        body.extend_from_slice(counts);
        body.extend_from_slice(symbols);
    }
    body
}

/// Whether a JPEG stream defines Huffman tables before its first scan (walks the marker
/// segments from SOI to SOS). `None` when the header is malformed, leaving the decoder to
/// report it.
fn has_dht_before_scan(jpeg: &[u8]) -> Option<bool> {
    if jpeg.get(..2)? != [0xFF, 0xD8] {
        return None;
    }
    let mut at = 2;
    loop {
        // Fill bytes (0xFF runs) may precede a marker.
        while *jpeg.get(at)? == 0xFF && *jpeg.get(at + 1)? == 0xFF {
            at += 1;
        }
        if *jpeg.get(at)? != 0xFF {
            return None;
        }
        match *jpeg.get(at + 1)? {
            0xC4 => return Some(true),
            0xDA => return Some(false),
            // Standalone markers carry no length.
            0x01 | 0xD0..=0xD7 => at += 2,
            _ => {
                let len = usize::from(u16::from_be_bytes([*jpeg.get(at + 2)?, *jpeg.get(at + 3)?]));
                if len < 2 {
                    return None;
                }
                at += 2 + len;
            }
        }
    }
}

/// Decodes one Motion-JPEG frame to row-major RGB8 and checks it is `width`×`height`.
/// Frames without Huffman tables get the standard ones inserted after SOI. Only the bytes the
/// driver filled (`bytesused`) should be passed: the rest of a mapped buffer is stale.
pub fn mjpeg_to_rgb(jpeg: &[u8], width: u32, height: u32) -> Result<Vec<u8>, FrameError> {
    use zune_jpeg::zune_core::bytestream::ZCursor;
    use zune_jpeg::zune_core::colorspace::ColorSpace;
    use zune_jpeg::zune_core::options::DecoderOptions;

    let patched;
    let data = if has_dht_before_scan(jpeg) == Some(false) {
        let dht = standard_dht_segment();
        let mut with_tables = Vec::with_capacity(jpeg.len() + dht.len() + 4);
        with_tables.extend_from_slice(&jpeg[..2]);
        with_tables.extend_from_slice(&[0xFF, 0xC4]);
        // The segment length counts its own two bytes; 420 fits easily.
        with_tables.extend_from_slice(&((dht.len() + 2) as u16).to_be_bytes());
        with_tables.extend_from_slice(&dht);
        with_tables.extend_from_slice(&jpeg[2..]);
        patched = with_tables;
        &patched[..]
    } else {
        jpeg
    };
    let options = DecoderOptions::default().jpeg_set_out_colorspace(ColorSpace::RGB);
    let mut decoder = zune_jpeg::JpegDecoder::new_with_options(ZCursor::new(data), options);
    let rgb = decoder
        .decode()
        .map_err(|e| FrameError::Jpeg(format!("{e:?}").replace('\n', " ")))?;
    let info = decoder
        .info()
        .ok_or_else(|| FrameError::Jpeg("no image header".to_string()))?;
    let (got_w, got_h) = (u32::from(info.width), u32::from(info.height));
    if (got_w, got_h) != (width, height) {
        return Err(FrameError::Jpeg(format!(
            "decoded {got_w}x{got_h}, the stream was set to {width}x{height}"
        )));
    }
    let needed = width as usize * height as usize * 3;
    if rgb.len() != needed {
        return Err(FrameError::Jpeg(format!(
            "decoded {} bytes, RGB {width}x{height} is {needed}",
            rgb.len()
        )));
    }
    Ok(rgb)
}

/// One `/dev/video*` node as the name lookup sees it.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct DeviceCandidate {
    /// Its path, e.g. `/dev/video0`.
    pub path: PathBuf,
    /// The driver's card name (sysfs `name`, e.g. "HD Pro Webcam C920").
    pub name: String,
    /// Whether the node captures video. A UVC camera also exposes a metadata node with the
    /// same name, which must not be picked.
    pub can_capture: bool,
}

/// Picks the capture node a configured name means: an exact (case-insensitive) name match
/// wins, else the only node whose name contains the text. Several matches are an error that
/// lists them (configure the path instead); so is none, listing what exists.
pub fn pick_device_by_name(
    candidates: &[DeviceCandidate],
    wanted: &str,
) -> Result<PathBuf, String> {
    let wanted_lower = wanted.trim().to_lowercase();
    let capture: Vec<&DeviceCandidate> = candidates.iter().filter(|c| c.can_capture).collect();
    let exact: Vec<&&DeviceCandidate> = capture
        .iter()
        .filter(|c| c.name.trim().to_lowercase() == wanted_lower)
        .collect();
    let matches: Vec<&&DeviceCandidate> = if exact.is_empty() {
        capture
            .iter()
            .filter(|c| c.name.to_lowercase().contains(&wanted_lower))
            .collect()
    } else {
        exact
    };
    let describe = |list: &mut dyn Iterator<Item = &DeviceCandidate>| -> String {
        let all: Vec<String> = list
            .map(|c| format!("{} ({:?})", c.path.display(), c.name))
            .collect();
        if all.is_empty() {
            "none".to_string()
        } else {
            all.join(", ")
        }
    };
    match matches.as_slice() {
        [one] => Ok(one.path.clone()),
        [] => Err(format!(
            "no capture device named {wanted:?}; capture devices: {}",
            describe(&mut capture.iter().copied())
        )),
        several => Err(format!(
            "{wanted:?} matches several capture devices: {}; give the device path instead",
            describe(&mut several.iter().map(|c| **c))
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn yuyv_limited_range_matches_hand_computed_pixels() {
        // Pixel pairs worked by hand with the BT.601 integer formulas:
        // Y=16,U=V=128 → C=0,D=E=0 → (128>>8)=0: black for both pixels.
        // Y=235 → C=219: 298·219+128 = 65390 → 255 (65390>>8 = 255.4): white.
        // Y=81,U=90,V=240 (studio red): C=65, D=-38, E=112:
        //   R = (19370 + 45808 + 128) >> 8 = 65306 >> 8 = 255
        //   G = (19370 + 3800 − 23296 + 128) >> 8 = 2 >> 8 = 0
        //   B = (19370 − 19608 + 128) >> 8 = −110 >> 8 = −1 → 0
        // Y=145,U=54,V=34 (studio green): C=129, D=-74, E=-94:
        //   R = (38442 − 38446 + 128) >> 8 = 124 >> 8 = 0
        //   G = (38442 + 7400 + 19552 + 128) >> 8 = 65522 >> 8 = 255
        //   B = (38442 − 38184 + 128) >> 8 = 386 >> 8 = 1
        let buf = [16, 128, 235, 128, 81, 90, 81, 240, 145, 54, 145, 34];
        let rgb = yuyv_to_rgb(&buf, 6, 1, 12, YuvRange::Limited).unwrap();
        assert_eq!(
            rgb,
            vec![0, 0, 0, 255, 255, 255, 255, 0, 0, 255, 0, 0, 0, 255, 1, 0, 255, 1]
        );
    }

    #[test]
    fn yuyv_mid_grey_and_full_range() {
        // Y=126,U=V=128 limited: C=110 → (32780+128)>>8 = 128 for all channels.
        let limited = yuyv_to_rgb(&[126, 128, 126, 128], 2, 1, 4, YuvRange::Limited).unwrap();
        assert_eq!(limited, vec![128; 6]);
        // Full range: Y passes through when U=V=128; Y=100,U=200,V=50:
        //   D=72,E=-78: R=(25600−28002+128)>>8 = −2274>>8 = −9 → 0
        //   G=(25600−6336+14274+128)>>8 = 33666>>8 = 131
        //   B=(25600+32688+128)>>8 = 58416>>8 = 228
        let full = yuyv_to_rgb(
            &[77, 128, 200, 128, 100, 200, 100, 50],
            4,
            1,
            8,
            YuvRange::Full,
        )
        .unwrap();
        assert_eq!(
            full,
            vec![77, 77, 77, 200, 200, 200, 0, 131, 228, 0, 131, 228]
        );
    }

    #[test]
    fn yuyv_skips_row_padding_and_rejects_bad_geometry() {
        // Two rows of one pixel pair each, stride 6 (2 padding bytes, 0xEE, never read).
        let buf = [16, 128, 16, 128, 0xEE, 0xEE, 235, 128, 235, 128];
        let rgb = yuyv_to_rgb(&buf, 2, 2, 6, YuvRange::Limited).unwrap();
        assert_eq!(rgb, [vec![0u8; 6], vec![255u8; 6]].concat());
        assert!(matches!(
            yuyv_to_rgb(&buf[..9], 2, 2, 6, YuvRange::Limited),
            Err(FrameError::TooShort {
                got: 9,
                needed: 10,
                ..
            })
        ));
        assert!(matches!(
            yuyv_to_rgb(&buf, 3, 1, 6, YuvRange::Limited),
            Err(FrameError::Geometry(m)) if m.contains("even")
        ));
        assert!(matches!(
            yuyv_to_rgb(&buf, 2, 2, 3, YuvRange::Limited),
            Err(FrameError::Geometry(m)) if m.contains("stride")
        ));
    }

    /// A 32x16 test card (four flat colour quadrants), JPEG-encoded by the `image` crate.
    fn test_jpeg() -> (Vec<u8>, Vec<u8>) {
        let (w, h) = (32u32, 16u32);
        let mut rgb = Vec::new();
        for y in 0..h {
            for x in 0..w {
                rgb.extend_from_slice(match (x < w / 2, y < h / 2) {
                    (true, true) => &[220, 30, 30],
                    (false, true) => &[30, 200, 40],
                    (true, false) => &[20, 40, 210],
                    (false, false) => &[240, 240, 240],
                });
            }
        }
        let mut jpeg = Vec::new();
        image::codecs::jpeg::JpegEncoder::new_with_quality(&mut jpeg, 95)
            .encode(&rgb, w, h, image::ExtendedColorType::Rgb8)
            .unwrap();
        (jpeg, rgb)
    }

    fn max_abs_diff(a: &[u8], b: &[u8]) -> u8 {
        a.iter().zip(b).map(|(x, y)| x.abs_diff(*y)).max().unwrap()
    }

    #[test]
    fn mjpeg_decodes_to_the_encoded_colours() {
        let (jpeg, rgb) = test_jpeg();
        assert_eq!(has_dht_before_scan(&jpeg), Some(true));
        let decoded = mjpeg_to_rgb(&jpeg, 32, 16).unwrap();
        assert_eq!(decoded.len(), rgb.len());
        // Quadrant centres are far from the edges where 4:2:0 chroma blurs.
        for (x, y) in [(4, 4), (27, 4), (4, 12), (27, 12)] {
            let i = (y * 32 + x) * 3;
            assert!(
                max_abs_diff(&decoded[i..i + 3], &rgb[i..i + 3]) <= 6,
                "pixel ({x},{y}): {:?} vs {:?}",
                &decoded[i..i + 3],
                &rgb[i..i + 3]
            );
        }
    }

    /// Removes every DHT segment before the scan, as UVC cameras send MJPEG.
    fn strip_dht(jpeg: &[u8]) -> Vec<u8> {
        let mut out = jpeg[..2].to_vec();
        let mut at = 2;
        while jpeg[at + 1] != 0xDA {
            let len = usize::from(u16::from_be_bytes([jpeg[at + 2], jpeg[at + 3]]));
            if jpeg[at + 1] != 0xC4 {
                out.extend_from_slice(&jpeg[at..at + 2 + len]);
            }
            at += 2 + len;
        }
        out.extend_from_slice(&jpeg[at..]);
        out
    }

    #[test]
    fn mjpeg_without_huffman_tables_uses_the_standard_ones() {
        let (jpeg, _) = test_jpeg();
        let stripped = strip_dht(&jpeg);
        assert!(stripped.len() < jpeg.len());
        assert_eq!(has_dht_before_scan(&stripped), Some(false));
        // The encoder used the Annex K tables, so re-inserting them restores the exact image.
        assert_eq!(
            mjpeg_to_rgb(&stripped, 32, 16).unwrap(),
            mjpeg_to_rgb(&jpeg, 32, 16).unwrap()
        );
    }

    #[test]
    fn mjpeg_wrong_size_and_garbage_are_errors() {
        let (jpeg, _) = test_jpeg();
        let e = mjpeg_to_rgb(&jpeg, 640, 480).unwrap_err();
        assert!(e.to_string().contains("decoded 32x16"), "{e}");
        assert!(matches!(
            mjpeg_to_rgb(&[1, 2, 3], 32, 16),
            Err(FrameError::Jpeg(_))
        ));
        assert!(matches!(
            mjpeg_to_rgb(&jpeg[..40], 32, 16),
            Err(FrameError::Jpeg(_))
        ));
    }

    fn node(n: u32, name: &str, can_capture: bool) -> DeviceCandidate {
        DeviceCandidate {
            path: PathBuf::from(format!("/dev/video{n}")),
            name: name.to_string(),
            can_capture,
        }
    }

    #[test]
    fn pixel_formats_parse() {
        assert_eq!(
            "yuyv".parse::<V4l2PixelFormat>().unwrap().fourcc(),
            *b"YUYV"
        );
        assert_eq!(
            "MJPEG".parse::<V4l2PixelFormat>().unwrap().fourcc(),
            *b"MJPG"
        );
        let e = "RGB3".parse::<V4l2PixelFormat>().unwrap_err();
        assert!(e.contains("RGB3") && e.contains("YUYV"), "{e}");
    }

    #[test]
    fn device_by_name_prefers_capture_nodes_and_exact_names() {
        let nodes = [
            node(0, "HD Pro Webcam C920", true),
            node(1, "HD Pro Webcam C920", false),
            node(2, "Integrated Camera: Integrated C", true),
            node(3, "Integrated Camera: Integrated C", false),
            node(4, "C920", true),
        ];
        assert_eq!(
            pick_device_by_name(&nodes, "hd pro webcam c920").unwrap(),
            PathBuf::from("/dev/video0")
        );
        assert_eq!(
            pick_device_by_name(&nodes, "Integrated").unwrap(),
            PathBuf::from("/dev/video2")
        );
        // "C920" is the exact name of video4, although video0's name contains it too.
        assert_eq!(
            pick_device_by_name(&nodes, "C920").unwrap(),
            PathBuf::from("/dev/video4")
        );
        // video1 has the same name but is the metadata node.
        assert_eq!(
            pick_device_by_name(&nodes, "Webcam C9").unwrap(),
            PathBuf::from("/dev/video0")
        );
        let e = pick_device_by_name(&nodes, "C9").unwrap_err();
        assert!(
            e.contains("several") && e.contains("/dev/video0") && e.contains("/dev/video4"),
            "{e}"
        );
        assert!(
            !e.contains("/dev/video1") && !e.contains("/dev/video2"),
            "{e}"
        );
        let e = pick_device_by_name(&nodes, "Brio").unwrap_err();
        assert!(e.contains("no capture device named \"Brio\""), "{e}");
        let e = pick_device_by_name(&[], "Brio").unwrap_err();
        assert!(e.ends_with("capture devices: none"), "{e}");
    }
}
