//! GigE Vision and USB3 Vision cameras through Aravis 0.8.
//!
//! The camera ([`AravisCamera`], feature `aravis`: libaravis 0.8 through the `aravis` crate,
//! Debian `libaravis-dev` + `libusb-1.0-0-dev`) delivers raw sensor buffers; turning them into
//! RGB is here and always compiled, so it is tested without the library:
//!
//! - [`PixelFormat`]: the formats we configure (Mono8, the four 8-bit Bayer mosaics, RGB8),
//!   named as GenICam names them, with their PFNC codes;
//! - [`demosaic_bilinear`]: Bayer → RGB by averaging each missing colour over the 3×3
//!   neighbourhood, our own implementation (the `aravis` crate's optional one is left off);
//! - [`raw_to_rgb`]: any of the formats above to row-major RGB8.

use std::fmt;
use std::str::FromStr;

pub use crate::v4l2::FrameError;

#[cfg(feature = "aravis")]
mod camera;
#[cfg(feature = "aravis")]
pub use camera::{AravisCamera, AravisConfig};

/// The colour filter over the top-left 2×2 pixels of a Bayer sensor, read row by row.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BayerPattern {
    /// R G / G B.
    Rggb,
    /// G R / B G.
    Grbg,
    /// B G / G R.
    Bggr,
    /// G B / R G.
    Gbrg,
}

impl BayerPattern {
    /// Which channel (0 = R, 1 = G, 2 = B) the sensor samples at pixel (x, y).
    pub fn channel_at(self, x: usize, y: usize) -> usize {
        let cell = (y % 2) * 2 + (x % 2);
        let layout: [usize; 4] = match self {
            BayerPattern::Rggb => [0, 1, 1, 2],
            BayerPattern::Grbg => [1, 0, 2, 1],
            BayerPattern::Bggr => [2, 1, 1, 0],
            BayerPattern::Gbrg => [1, 2, 0, 1],
        };
        layout[cell]
    }
}

/// The 8-bit pixel formats this driver configures and converts.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum PixelFormat {
    /// One grey byte per pixel.
    Mono8,
    /// One byte per pixel under a Bayer colour filter.
    Bayer8(BayerPattern),
    /// Three bytes R G B per pixel ("RGB8Packed" in older GenICam files).
    Rgb8,
}

impl PixelFormat {
    /// The GenICam PFNC code (what `PixelFormat` holds on the camera).
    pub fn pfnc(self) -> u32 {
        match self {
            PixelFormat::Mono8 => 0x0108_0001,
            PixelFormat::Bayer8(BayerPattern::Grbg) => 0x0108_0008,
            PixelFormat::Bayer8(BayerPattern::Rggb) => 0x0108_0009,
            PixelFormat::Bayer8(BayerPattern::Gbrg) => 0x0108_000A,
            PixelFormat::Bayer8(BayerPattern::Bggr) => 0x0108_000B,
            PixelFormat::Rgb8 => 0x0218_0014,
        }
    }

    /// The format with PFNC code `code`, if it is one we convert.
    pub fn from_pfnc(code: u32) -> Option<PixelFormat> {
        [
            PixelFormat::Mono8,
            PixelFormat::Bayer8(BayerPattern::Rggb),
            PixelFormat::Bayer8(BayerPattern::Grbg),
            PixelFormat::Bayer8(BayerPattern::Bggr),
            PixelFormat::Bayer8(BayerPattern::Gbrg),
            PixelFormat::Rgb8,
        ]
        .into_iter()
        .find(|f| f.pfnc() == code)
    }

    /// Bytes per pixel.
    pub fn bytes_per_pixel(self) -> usize {
        match self {
            PixelFormat::Rgb8 => 3,
            _ => 1,
        }
    }

    /// The GenICam enumeration entry name.
    pub fn genicam_name(self) -> &'static str {
        match self {
            PixelFormat::Mono8 => "Mono8",
            PixelFormat::Bayer8(BayerPattern::Rggb) => "BayerRG8",
            PixelFormat::Bayer8(BayerPattern::Grbg) => "BayerGR8",
            PixelFormat::Bayer8(BayerPattern::Bggr) => "BayerBG8",
            PixelFormat::Bayer8(BayerPattern::Gbrg) => "BayerGB8",
            PixelFormat::Rgb8 => "RGB8",
        }
    }
}

impl fmt::Display for PixelFormat {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.genicam_name())
    }
}

impl FromStr for PixelFormat {
    type Err = String;

    /// GenICam names, case-insensitive: `Mono8`, `BayerRG8`, `BayerGR8`, `BayerBG8`,
    /// `BayerGB8`, `RGB8` (or `RGB8Packed`).
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Ok(match s.to_ascii_lowercase().as_str() {
            "mono8" => PixelFormat::Mono8,
            "bayerrg8" => PixelFormat::Bayer8(BayerPattern::Rggb),
            "bayergr8" => PixelFormat::Bayer8(BayerPattern::Grbg),
            "bayerbg8" => PixelFormat::Bayer8(BayerPattern::Bggr),
            "bayergb8" => PixelFormat::Bayer8(BayerPattern::Gbrg),
            "rgb8" | "rgb8packed" => PixelFormat::Rgb8,
            _ => {
                return Err(format!(
                "{s:?} is not supported: use Mono8, BayerRG8, BayerGR8, BayerBG8, BayerGB8 or RGB8"
            ))
            }
        })
    }
}

/// Bilinear demosaicing of an 8-bit Bayer image to row-major RGB8.
///
/// Each pixel keeps the colour its filter passed; each missing colour is the rounded mean of
/// the neighbours (3×3, inside the image) that sampled it. That is the classic bilinear
/// scheme: at a red site green is the mean of the four edge neighbours and blue of the four
/// corners; at a green site red and blue each come from the two neighbours on one axis. A
/// colour varying linearly across the image is reproduced exactly away from the border.
pub fn demosaic_bilinear(
    raw: &[u8],
    width: u32,
    height: u32,
    pattern: BayerPattern,
) -> Result<Vec<u8>, FrameError> {
    let (w, h) = (width as usize, height as usize);
    check_len(raw, w * h, width, height)?;
    let mut rgb = vec![0u8; w * h * 3];
    for y in 0..h {
        for x in 0..w {
            let own = pattern.channel_at(x, y);
            let mut sum = [0u32; 3];
            let mut count = [0u32; 3];
            for ny in y.saturating_sub(1)..=(y + 1).min(h - 1) {
                for nx in x.saturating_sub(1)..=(x + 1).min(w - 1) {
                    let c = pattern.channel_at(nx, ny);
                    sum[c] += u32::from(raw[ny * w + nx]);
                    count[c] += 1;
                }
            }
            let out = &mut rgb[(y * w + x) * 3..(y * w + x) * 3 + 3];
            for c in 0..3 {
                out[c] = if c == own {
                    raw[y * w + x]
                } else {
                    // A 1-pixel-wide image lacks some colours entirely: fall back to the sample.
                    (sum[c] + count[c] / 2)
                        .checked_div(count[c])
                        .map_or(raw[y * w + x], |mean| mean as u8)
                };
            }
        }
    }
    Ok(rgb)
}

fn check_len(buf: &[u8], needed: usize, width: u32, height: u32) -> Result<(), FrameError> {
    if width == 0 || height == 0 {
        return Err(FrameError::Geometry(format!(
            "{width}x{height}: both sides must be non-zero"
        )));
    }
    if buf.len() < needed {
        return Err(FrameError::TooShort {
            got: buf.len(),
            needed,
            width,
            height,
        });
    }
    Ok(())
}

/// Converts a tightly packed buffer of `format` to row-major RGB8: Mono8 is replicated into
/// the three channels, Bayer is demosaiced, RGB8 is copied.
pub fn raw_to_rgb(
    raw: &[u8],
    width: u32,
    height: u32,
    format: PixelFormat,
) -> Result<Vec<u8>, FrameError> {
    let pixels = width as usize * height as usize;
    match format {
        PixelFormat::Mono8 => {
            check_len(raw, pixels, width, height)?;
            Ok(raw[..pixels].iter().flat_map(|&v| [v, v, v]).collect())
        }
        PixelFormat::Bayer8(pattern) => demosaic_bilinear(raw, width, height, pattern),
        PixelFormat::Rgb8 => {
            check_len(raw, pixels * 3, width, height)?;
            Ok(raw[..pixels * 3].to_vec())
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const PATTERNS: [BayerPattern; 4] = [
        BayerPattern::Rggb,
        BayerPattern::Grbg,
        BayerPattern::Bggr,
        BayerPattern::Gbrg,
    ];

    /// What a sensor with `pattern` records of a scene given per pixel as RGB.
    fn mosaic(scene: &[[u8; 3]], w: usize, pattern: BayerPattern) -> Vec<u8> {
        scene
            .iter()
            .enumerate()
            .map(|(i, px)| px[pattern.channel_at(i % w, i / w)])
            .collect()
    }

    #[test]
    fn pattern_layouts_match_their_names() {
        let names = |p: BayerPattern| -> String {
            [(0, 0), (1, 0), (0, 1), (1, 1)]
                .iter()
                .map(|&(x, y)| ['R', 'G', 'B'][p.channel_at(x, y)])
                .collect()
        };
        assert_eq!(names(BayerPattern::Rggb), "RGGB");
        assert_eq!(names(BayerPattern::Grbg), "GRBG");
        assert_eq!(names(BayerPattern::Bggr), "BGGR");
        assert_eq!(names(BayerPattern::Gbrg), "GBRG");
        // The pattern repeats every 2 pixels.
        assert_eq!(
            BayerPattern::Rggb.channel_at(2, 2),
            BayerPattern::Rggb.channel_at(0, 0)
        );
    }

    #[test]
    fn flat_colour_demosaics_to_itself_for_every_pattern() {
        let (w, h) = (6, 4);
        let scene = vec![[200u8, 100, 50]; w * h];
        for p in PATTERNS {
            let rgb = demosaic_bilinear(&mosaic(&scene, w, p), w as u32, h as u32, p).unwrap();
            assert!(
                rgb.chunks(3).all(|px| px == [200, 100, 50]),
                "{p:?}: {rgb:?}"
            );
        }
    }

    #[test]
    fn linear_ramps_are_exact_inside_the_border() {
        let (w, h) = (8usize, 6usize);
        let scene: Vec<[u8; 3]> = (0..w * h)
            .map(|i| {
                let (x, y) = ((i % w) as u8, (i / w) as u8);
                [10 * x + 4 * y, 100 + 6 * y, 200 - 8 * x - 2 * y]
            })
            .collect();
        for p in PATTERNS {
            let rgb = demosaic_bilinear(&mosaic(&scene, w, p), w as u32, h as u32, p).unwrap();
            for y in 1..h - 1 {
                for x in 1..w - 1 {
                    let i = y * w + x;
                    assert_eq!(&rgb[i * 3..i * 3 + 3], &scene[i], "{p:?} at ({x},{y})");
                }
            }
        }
    }

    #[test]
    fn hand_worked_rggb_pixels() {
        // 4x2 RGGB mosaic:
        //   R=10  G=20  R=30  G=40
        //   G=50  B=60  G=70  B=80
        let raw = [10, 20, 30, 40, 50, 60, 70, 80];
        let rgb = demosaic_bilinear(&raw, 4, 2, BayerPattern::Rggb).unwrap();
        // (0,0) red site: G = mean(20, 50) = 35, B = 60.
        assert_eq!(&rgb[0..3], &[10, 35, 60]);
        // (1,0) green site: R = mean(10, 30) = 20, B = 60 (only neighbour below).
        assert_eq!(&rgb[3..6], &[20, 20, 60]);
        // (1,1) blue site: R = mean(10, 30) = 20, G = mean(20, 50, 70) = 46.67 → 47.
        assert_eq!(&rgb[15..18], &[20, 47, 60]);
        // (3,1) blue site at the corner: R = 30, G = mean(40, 70) = 55.
        assert_eq!(&rgb[21..24], &[30, 55, 80]);
    }

    #[test]
    fn mono_rgb_and_short_buffers() {
        assert_eq!(
            raw_to_rgb(&[0, 7, 255, 9], 2, 2, PixelFormat::Mono8).unwrap(),
            vec![0, 0, 0, 7, 7, 7, 255, 255, 255, 9, 9, 9]
        );
        let rgb: Vec<u8> = (0..12).collect();
        assert_eq!(raw_to_rgb(&rgb, 2, 2, PixelFormat::Rgb8).unwrap(), rgb);
        assert!(matches!(
            raw_to_rgb(&rgb[..11], 2, 2, PixelFormat::Rgb8),
            Err(FrameError::TooShort {
                got: 11,
                needed: 12,
                ..
            })
        ));
        assert!(matches!(
            raw_to_rgb(&[], 0, 2, PixelFormat::Mono8),
            Err(FrameError::Geometry(_))
        ));
    }

    #[test]
    fn formats_parse_by_genicam_name_and_pfnc() {
        for name in [
            "Mono8", "BayerRG8", "BayerGR8", "BayerBG8", "BayerGB8", "RGB8",
        ] {
            let f: PixelFormat = name.parse().unwrap();
            assert_eq!(f.genicam_name(), name);
            assert_eq!(PixelFormat::from_pfnc(f.pfnc()), Some(f));
        }
        // Codes from docs/protocols.md §5.2.
        assert_eq!(
            "bayerrg8".parse::<PixelFormat>().unwrap().pfnc(),
            0x01080009
        );
        assert_eq!(
            "RGB8Packed".parse::<PixelFormat>().unwrap().pfnc(),
            0x02180014
        );
        assert_eq!(PixelFormat::from_pfnc(0x01100007), None); // Mono16
        let e = "Mono16".parse::<PixelFormat>().unwrap_err();
        assert!(e.contains("Mono16") && e.contains("BayerRG8"), "{e}");
    }
}
