//! What changed between two frames of one fixed camera: the evidence a scene gives before
//! anything is known of where the robot is (the initialisation from images scores camera
//! poses on it, `init::change`).

use easyhec_drivers::Frame;

use super::builtin::{dist, fit_gain, median_f32, rgb_of, scaled};
use crate::mask::Mask;

/// A pixel has changed when its colour distance exceeds this many times the pair's median
/// distance (most of a frame is static, so the median is the sensor's noise)...
const CHANGE_OVER_MEDIAN: f32 = 5.0;
/// ... and at least this many grey levels.
const MIN_CHANGE: f32 = 6.0;
/// Every this many pixels sampled for the median.
const SAMPLE_STRIDE: usize = 7;

/// The pixels whose colour differs between `a` and `b` (the same size) past the noise, `b`
/// first scaled per channel onto `a`'s exposure. Shadows count as change: forgiving them (as
/// the segmenter does against its plate) also forgives a white robot in front of a grey wall,
/// which differs from it mostly in brightness (on the real xArm7 set the best start's overlap
/// fell from 0.62 to 0.31).
pub fn changed_between(a: &Frame, b: &Frame) -> Mask {
    let (a_rgb, b_rgb) = (rgb_of(a), rgb_of(b));
    let gain = fit_gain(&b_rgb, &a_rgb, |_| true);
    let distance: Vec<f32> = a_rgb
        .iter()
        .zip(&b_rgb)
        .map(|(pa, pb)| dist(&scaled(pb, &gain), pa))
        .collect();
    let mut sample: Vec<f32> = distance.iter().step_by(SAMPLE_STRIDE).copied().collect();
    let noise = if sample.is_empty() {
        0.0
    } else {
        median_f32(&mut sample)
    };
    let threshold = (CHANGE_OVER_MEDIAN * noise).max(MIN_CHANGE);
    Mask {
        width: a.width,
        height: a.height,
        data: distance.iter().map(|&d| u8::from(d > threshold)).collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(width: u32, height: u32, rgb: Vec<u8>) -> Frame {
        Frame {
            width,
            height,
            rgb,
            captured_at: std::time::SystemTime::UNIX_EPOCH,
            sequence: 0,
        }
    }

    #[test]
    fn an_exposure_change_is_not_change_but_a_new_colour_is() {
        let (w, h) = (40u32, 30u32);
        let mut a = vec![0u8; (w * h * 3) as usize];
        for (i, px) in a.chunks_exact_mut(3).enumerate() {
            let v = 60 + (i % 37) as u8 * 3;
            px.copy_from_slice(&[v, v / 2 + 20, 200 - v]);
        }
        // The same scene 20% brighter, with a 5x5 red patch painted over.
        let mut b: Vec<u8> = a
            .iter()
            .map(|&v| (f32::from(v) * 1.2).min(255.0) as u8)
            .collect();
        let at = |x: u32, y: u32| 3 * (y * w + x) as usize;
        for y in 10..15 {
            for x in 20..25 {
                b[at(x, y)..at(x, y) + 3].copy_from_slice(&[255, 0, 0]);
            }
        }
        let m = changed_between(&frame(w, h, a), &frame(w, h, b));
        let set: Vec<usize> = (0..m.data.len()).filter(|&i| m.data[i] != 0).collect();
        assert_eq!(set.len(), 25, "{set:?}");
        let ws = w as usize;
        assert!(set
            .iter()
            .all(|&i| (10..15).contains(&(i / ws)) && (20..25).contains(&(i % ws))));
    }
}
