//! The `builtin` segmenter: no training, only what the cell already knows.
//!
//! The camera is fixed and the robot moves between views, so the pixels the robot leaves free
//! in other views give a background plate; the silhouette rendered under the current estimate
//! (when there is one) bounds where the robot can be. Per view:
//!
//! 1. exposure: a per-frame, per-channel gain fitted on pixels that agree with the plate;
//! 2. plate: the per-pixel median over views whose prior band does not cover the pixel (all
//!    views when there is no prior), refitted once with each view's own mask cut out;
//! 3. change evidence: a shadow-tolerant colour distance to the plate (a pixel that is the
//!    plate's colour scaled darker is a shadow, not robot), in units of the estimated noise;
//! 4. prior evidence: the signed distance to the rendered silhouette against the band width
//!    (far outside the band is background; inside it only nudges);
//! 5. colour evidence: robot and background colour histograms learned from the confident
//!    pixels of all views (decides where the plate is unknown: pixels covered in every view);
//! 6. refinement: mean-field smoothing of the summed log-odds with contrast-sensitive
//!    4-neighbour coupling (a graph-cut style prior that snaps boundaries to image edges),
//!    then connected components that touch the prior (or, without one, the large ones) are
//!    kept and pinholes filled.

use easyhec_drivers::Frame;
use rayon::prelude::*;

use crate::error::{Error, Result};
use crate::mask::{edt_squared, Mask};

/// One view handed to [`segment_views`]: the frame and, when an estimate exists, the robot's
/// silhouette rendered under it in the frame's own (distorted) image.
pub struct ViewInput<'a> {
    /// The colour frame.
    pub frame: &'a Frame,
    /// Rendered silhouette under the current estimate, same size as the frame.
    pub prior: Option<&'a Mask>,
    /// How far (pixels) the true outline may lie from the prior's: the prior's uncertainty
    /// projected into the image plus whatever the fit left unexplained.
    pub band_px: f32,
}

/// Tuning of the builtin segmenter (defaults fit the simulator and the Panda photographs).
#[derive(Clone, Debug)]
pub struct BuiltinParams {
    /// Change distance (in noise sigmas) where the evidence for robot is neutral.
    pub change_threshold_sigmas: f32,
    /// Weight of the learned colour log-likelihood ratio.
    pub colour_weight: f32,
    /// Coupling of neighbouring labels in the smoothing step.
    pub smoothness: f32,
    /// Mean-field iterations.
    pub iterations: usize,
    /// Holes smaller than this (pixels) are filled.
    pub max_hole_px: usize,
}

impl Default for BuiltinParams {
    fn default() -> Self {
        BuiltinParams {
            change_threshold_sigmas: 5.0,
            colour_weight: 0.8,
            smoothness: 0.9,
            iterations: 6,
            max_hole_px: 60,
        }
    }
}

pub(super) type Rgb = [f32; 3];

/// A frame's pixels as floating-point RGB.
pub(super) fn rgb_of(frame: &Frame) -> Vec<Rgb> {
    frame
        .rgb
        .chunks_exact(3)
        .map(|c| [f32::from(c[0]), f32::from(c[1]), f32::from(c[2])])
        .collect()
}

/// Segments all views of one static camera together (see the module docs).
pub fn segment_views(views: &[ViewInput<'_>], params: &BuiltinParams) -> Result<Vec<Mask>> {
    Ok(segment(views, params, false)?.0)
}

/// [`segment_views`], also returning each view's per-pixel log-odds for robot before
/// smoothing, without the prior's term (change and colour evidence only).
pub fn segment_views_with_evidence(
    views: &[ViewInput<'_>],
    params: &BuiltinParams,
) -> Result<super::Evidence> {
    let (masks, log_odds) = segment(views, params, true)?;
    Ok(super::Evidence { masks, log_odds })
}

/// A silhouette's region score: `evidence` (from [`segment_views_with_evidence`]) summed over
/// the robot pixels of `mask`, the same size. Higher where the silhouette covers what changed.
pub fn evidence_over(mask: &Mask, evidence: &[f32]) -> f64 {
    mask.data
        .iter()
        .zip(evidence)
        .filter(|(m, _)| **m != 0)
        .map(|(_, e)| f64::from(*e))
        .sum()
}

/// Both entry points; the last pass's evidence is kept only `with_evidence` (empty otherwise).
fn segment(
    views: &[ViewInput<'_>],
    params: &BuiltinParams,
    with_evidence: bool,
) -> Result<(Vec<Mask>, Vec<Vec<f32>>)> {
    let Some(first) = views.first() else {
        return Ok((Vec::new(), Vec::new()));
    };
    let (w, h) = (first.frame.width as usize, first.frame.height as usize);
    for (i, v) in views.iter().enumerate() {
        if v.frame.width as usize != w || v.frame.height as usize != h {
            return Err(Error::Hardware(format!(
                "segmenter 'builtin': view {i} is {}x{} but view 0 is {w}x{h}: all views must come from the same camera",
                v.frame.width, v.frame.height
            )));
        }
        if v.frame.rgb.len() != w * h * 3 {
            return Err(Error::Hardware(format!(
                "segmenter 'builtin': view {i} has {} bytes for {w}x{h} RGB",
                v.frame.rgb.len()
            )));
        }
        if let Some(p) = v.prior {
            if p.width as usize != w || p.height as usize != h {
                return Err(Error::Hardware(format!(
                    "segmenter 'builtin': view {i}'s prior is {}x{}, the frame {w}x{h}",
                    p.width, p.height
                )));
            }
        }
    }
    if views.len() < 2 && views[0].prior.is_none() {
        return Err(Error::Hardware(
            "segmenter 'builtin' needs a second view of the same camera or a prior pose: give the cell an [calibration] initial_guess (or the run an initial_guess)".into(),
        ));
    }
    let images: Vec<Vec<Rgb>> = views.par_iter().map(|v| rgb_of(v.frame)).collect();
    // Signed distance to each prior (positive inside), pixels.
    let priors: Vec<Option<Vec<f32>>> = views
        .par_iter()
        .map(|v| v.prior.map(|p| signed_distance(p, w, h)))
        .collect();
    let bands: Vec<f32> = views.iter().map(|v| v.band_px.max(2.0)).collect();
    // Pixels a view may not lend to the plate: inside its prior band.
    let mut excluded: Vec<Vec<bool>> = priors
        .iter()
        .zip(&bands)
        .map(|(p, &band)| match p {
            Some(sd) => sd.iter().map(|&d| d > -band).collect(),
            None => vec![false; w * h],
        })
        .collect();
    let mut gains = vec![[1f32; 3]; views.len()];
    let mut masks: Vec<Mask> = Vec::new();
    let mut evidence: Vec<Vec<f32>> = Vec::new();
    for pass in 0..2 {
        let plate = background_plate(&images, &gains, &excluded, w * h);
        gains = images
            .par_iter()
            .zip(&excluded)
            .map(|(img, ex)| fit_gain(img, &plate.colour, |i| !ex[i] && plate.support[i] >= 2))
            .collect();
        let plate = background_plate(&images, &gains, &excluded, w * h);
        let change: Vec<Vec<f32>> = images
            .par_iter()
            .zip(&gains)
            .map(|(img, g)| change_distance(img, g, &plate))
            .collect();
        let sigma = noise_sigma(&change, &plate);
        let unary: Vec<Vec<f32>> = (0..views.len())
            .into_par_iter()
            .map(|v| {
                (0..w * h)
                    .map(|i| {
                        let mut l = 0.0;
                        let n = plate.support[i];
                        if n > 0 {
                            let d = change[v][i] / sigma;
                            let c = ((d - params.change_threshold_sigmas) / 1.5).clamp(-2.5, 4.0);
                            // One lending view cannot outvote an error in it.
                            l += if n == 1 { 0.5 * c } else { c };
                        }
                        if let Some(sd) = &priors[v] {
                            l += prior_llr(sd[i], bands[v]);
                        }
                        l
                    })
                    .collect()
            })
            .collect();
        let colour = ColourModel::learn(&images, &gains, &unary);
        let keep_evidence = with_evidence && pass == 1;
        (masks, evidence) = (0..views.len())
            .into_par_iter()
            .map(|v| {
                let img = &images[v];
                let g = gains[v];
                let total: Vec<f32> = unary[v]
                    .iter()
                    .zip(img)
                    .map(|(&u, px)| u + params.colour_weight * colour.llr(&scaled(px, &g)))
                    .collect();
                let reach = live_reach(bands[v], params);
                let live: Option<Vec<bool>> = priors[v]
                    .as_ref()
                    .map(|sd| sd.iter().map(|&d| d > -reach).collect());
                let labels = mean_field(&total, img, w, h, params, live.as_deref());
                let mask = cleanup(labels, priors[v].as_deref(), bands[v], w, h, params);
                let evidence = match (&priors[v], keep_evidence) {
                    (_, false) => Vec::new(),
                    (None, true) => total,
                    (Some(sd), true) => total
                        .iter()
                        .zip(sd)
                        .map(|(&t, &d)| t - prior_llr(d, bands[v]))
                        .collect(),
                };
                (mask, evidence)
            })
            .unzip();
        if pass == 0 {
            // Second pass: each view lends exactly the pixels its own mask leaves free (with
            // a margin), which is tighter than a wide prior band and exists without a prior.
            for (ex, m) in excluded.iter_mut().zip(&masks) {
                let d = edt_squared(w, h, |i| m.data[i] != 0);
                for (e, &dd) in ex.iter_mut().zip(&d) {
                    *e = dd <= 36.0;
                }
            }
        }
    }
    Ok((masks, evidence))
}

/// Positive inside the mask, negative outside, pixels.
pub(crate) fn signed_distance(mask: &Mask, w: usize, h: usize) -> Vec<f32> {
    let to_bg = edt_squared(w, h, |i| mask.data[i] == 0);
    let to_fg = edt_squared(w, h, |i| mask.data[i] != 0);
    (0..w * h)
        .map(|i| {
            if mask.data[i] != 0 {
                to_bg[i].sqrt().min(1e4)
            } else {
                -to_fg[i].sqrt().min(1e4)
            }
        })
        .collect()
}

/// Log-odds from the prior: strongly background beyond the band, leaning background in its
/// outer half, a mild pull inside the outline and a firmer one deep inside (where a robot the
/// colour of the wall behind it shows no change).
fn prior_llr(sd: f32, band: f32) -> f32 {
    if sd <= -band {
        -6.0
    } else if sd < 0.0 {
        sd / band * 2.5
    } else {
        (sd / band).min(1.0) * 1.2 + ((sd - band) / band).clamp(0.0, 1.0) * 1.5
    }
}

pub(super) fn scaled(px: &Rgb, g: &Rgb) -> Rgb {
    [px[0] * g[0], px[1] * g[1], px[2] * g[2]]
}

/// The per-pixel background estimate and how many views lent to it.
struct Plate {
    colour: Vec<Rgb>,
    support: Vec<usize>,
}

/// Colour distance (grey levels) within which two views agree on a background pixel.
const AGREE: f32 = 16.0;

/// The per-pixel background: the largest group of mutually agreeing lending views (the
/// mode, not the median: where the robot covers a pixel in most views its colours vary from
/// view to view, while the background's repeats), averaged.
fn background_plate(images: &[Vec<Rgb>], gains: &[Rgb], excluded: &[Vec<bool>], n: usize) -> Plate {
    let (colour, support): (Vec<Rgb>, Vec<usize>) = (0..n)
        .into_par_iter()
        .map_init(Vec::new, |buf: &mut Vec<Rgb>, i| {
            buf.clear();
            for ((img, g), ex) in images.iter().zip(gains).zip(excluded) {
                if !ex[i] {
                    buf.push(scaled(&img[i], g));
                }
            }
            if buf.is_empty() {
                return ([0.0; 3], 0);
            }
            let mut best = (0usize, f32::INFINITY, 0usize);
            for (j, a) in buf.iter().enumerate() {
                let (mut count, mut spread) = (0, 0.0);
                for b in buf.iter() {
                    let d = dist(a, b);
                    if d < AGREE {
                        count += 1;
                        spread += d;
                    }
                }
                if count > best.0 || (count == best.0 && spread < best.1) {
                    best = (count, spread, j);
                }
            }
            let centre = buf[best.2];
            let mut sum = [0f32; 3];
            for b in buf.iter().filter(|b| dist(&centre, b) < AGREE) {
                for c in 0..3 {
                    sum[c] += b[c];
                }
            }
            let k = best.0 as f32;
            ([sum[0] / k, sum[1] / k, sum[2] / k], best.0)
        })
        .unzip();
    Plate { colour, support }
}

/// The median, by selection rather than a full sort (the gain fit takes one over a third of
/// a frame's pixels per channel, every segmentation).
pub(super) fn median_f32(v: &mut [f32]) -> f32 {
    let n = v.len();
    if n == 0 {
        return f32::NAN;
    }
    let (lower, &mut middle, _) = v.select_nth_unstable_by(n / 2, f32::total_cmp);
    if n % 2 == 1 {
        middle
    } else {
        let below = lower
            .iter()
            .copied()
            .max_by(f32::total_cmp)
            .unwrap_or(middle);
        0.5 * (below + middle)
    }
}

/// Per-channel gain mapping this frame onto `target` (the plate, or another frame), fitted on
/// the `usable` pixels (median of ratios: robust to the robot and to shadows covering some of
/// them); 1 where 100 pixels or fewer are usable.
pub(super) fn fit_gain(img: &[Rgb], target: &[Rgb], usable: impl Fn(usize) -> bool) -> Rgb {
    let mut out = [1f32; 3];
    for (c, o) in out.iter_mut().enumerate() {
        let mut ratios: Vec<f32> = (0..img.len())
            .step_by(3)
            .filter(|&i| usable(i) && img[i][c] > 12.0)
            .map(|i| target[i][c] / img[i][c])
            .collect();
        if ratios.len() > 100 {
            *o = median_f32(&mut ratios).clamp(0.25, 4.0);
        }
    }
    out
}

/// Colour distance to the plate that forgives shadows ([`shadow_tolerant_distance`]), each
/// pixel first scaled by the frame's gain `g`.
fn change_distance(img: &[Rgb], g: &Rgb, plate: &Plate) -> Vec<f32> {
    img.iter()
        .zip(&plate.colour)
        .map(|(px, p)| shadow_tolerant_distance(&scaled(px, g), p))
        .collect()
}

/// Colour distance from `f` to `p` that forgives shadows: `f` is compared with `p` scaled by
/// the best darkening factor in [0.35, 1], plus a small cost for darkening.
fn shadow_tolerant_distance(f: &Rgb, p: &Rgb) -> f32 {
    let direct = dist(f, p);
    let pp = p[0] * p[0] + p[1] * p[1] + p[2] * p[2];
    if pp < 1.0 {
        return direct;
    }
    let alpha = ((f[0] * p[0] + f[1] * p[1] + f[2] * p[2]) / pp).clamp(0.35, 1.0);
    let shadow = dist(f, &[p[0] * alpha, p[1] * alpha, p[2] * alpha]);
    direct.min(shadow + 20.0 * (1.0 - alpha))
}

pub(super) fn dist(a: &Rgb, b: &Rgb) -> f32 {
    ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2)).sqrt()
}

/// Sensor noise sigma from the median change distance (most pixels are background; the
/// median of a 3-channel Gaussian distance is about 1.54 sigma).
fn noise_sigma(change: &[Vec<f32>], plate: &Plate) -> f32 {
    let mut all: Vec<f32> = change
        .iter()
        .flat_map(|c| {
            c.iter()
                .enumerate()
                .step_by(7)
                .filter(|(i, _)| plate.support[*i] >= 2)
                .map(|(_, &d)| d)
        })
        .collect();
    if all.is_empty() {
        return 3.0;
    }
    (median_f32(&mut all) / 1.54).clamp(1.0, 12.0)
}

const BINS: usize = 16;

/// Robot and background colour histograms (16³ RGB bins) from confident pixels.
struct ColourModel {
    llr: Vec<f32>,
}

impl ColourModel {
    fn bin(px: &Rgb) -> usize {
        let q = |v: f32| ((v.max(0.0) as usize) * BINS / 256).min(BINS - 1);
        (q(px[0]) * BINS + q(px[1])) * BINS + q(px[2])
    }

    fn learn(images: &[Vec<Rgb>], gains: &[Rgb], unary: &[Vec<f32>]) -> ColourModel {
        let n = BINS * BINS * BINS;
        let mut fg = vec![0f32; n];
        let mut bg = vec![0f32; n];
        for ((img, g), u) in images.iter().zip(gains).zip(unary) {
            for (px, &l) in img.iter().zip(u) {
                if l > 2.5 {
                    fg[Self::bin(&scaled(px, g))] += 1.0;
                } else if l < -2.5 {
                    bg[Self::bin(&scaled(px, g))] += 1.0;
                }
            }
        }
        let (sf, sb) = (fg.iter().sum::<f32>(), bg.iter().sum::<f32>());
        if sf < 200.0 || sb < 200.0 {
            return ColourModel { llr: vec![0.0; n] };
        }
        let llr = fg
            .iter()
            .zip(&bg)
            .map(|(&f, &b)| {
                (((f + 1.0) / (sf + n as f32)) / ((b + 1.0) / (sb + n as f32)))
                    .ln()
                    .clamp(-3.0, 3.0)
            })
            .collect();
        ColourModel { llr }
    }

    fn llr(&self, px: &Rgb) -> f32 {
        self.llr[Self::bin(px)]
    }
}

/// How far outside a prior's silhouette (pixels) [`mean_field`] must still update labels for
/// those within the band to come out as a smoothing of the whole image would leave them: a
/// label moves its neighbours one pixel per iteration, and beyond the band the cleanup
/// clears every label anyway.
fn live_reach(band: f32, params: &BuiltinParams) -> f32 {
    band + params.iterations as f32 + 1.0
}

/// Mean-field smoothing of the log-odds with contrast-sensitive 4-neighbour coupling. Only
/// the `live` pixels (all when `None`) are smoothed; the rest come out background, and no
/// label within the band ever reads them. Why: under a prior most of a 1280x720 frame lies
/// far outside its band, and smoothing it was a fifth of an images-only solve's time (see
/// [`live_reach`]).
fn mean_field(
    unary: &[f32],
    img: &[Rgb],
    w: usize,
    h: usize,
    params: &BuiltinParams,
    live: Option<&[bool]>,
) -> Vec<bool> {
    let is_live = |i: usize| live.is_none_or(|l| l[i]);
    // Edge weights right and down: strong coupling across flat colour, weak across edges.
    // A pair's weight is read only by its live ends.
    let contrast = |a: &Rgb, b: &Rgb| {
        let d2 = (a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) + (a[2] - b[2]).powi(2);
        (-d2 / (2.0 * 18.0 * 18.0)).exp()
    };
    let right: Vec<f32> = (0..w * h)
        .into_par_iter()
        .map(|i| {
            if (i + 1) % w != 0 && (is_live(i) || is_live(i + 1)) {
                contrast(&img[i], &img[i + 1])
            } else {
                0.0
            }
        })
        .collect();
    let down: Vec<f32> = (0..w * h)
        .into_par_iter()
        .map(|i| {
            if i + w < w * h && (is_live(i) || is_live(i + w)) {
                contrast(&img[i], &img[i + w])
            } else {
                0.0
            }
        })
        .collect();
    let mut m: Vec<f32> = unary
        .par_iter()
        .enumerate()
        .map(|(i, &u)| if is_live(i) { (u * 0.5).tanh() } else { 0.0 })
        .collect();
    for _ in 0..params.iterations {
        m = (0..w * h)
            .into_par_iter()
            .map(|i| {
                if !is_live(i) {
                    return m[i];
                }
                let (x, y) = (i % w, i / w);
                let mut s = 0.0;
                if x + 1 < w {
                    s += right[i] * m[i + 1];
                }
                if x > 0 {
                    s += right[i - 1] * m[i - 1];
                }
                if y + 1 < h {
                    s += down[i] * m[i + w];
                }
                if y > 0 {
                    s += down[i - w] * m[i - w];
                }
                ((unary[i] + params.smoothness * s) * 0.5).tanh()
            })
            .collect();
    }
    m.iter()
        .enumerate()
        .map(|(i, &v)| is_live(i) && v > 0.0)
        .collect()
}

/// Connected components (4-connected) of `fg` (or of its complement): label per pixel and
/// component sizes.
fn components(fg: &[bool], want: bool, w: usize, h: usize) -> (Vec<u32>, Vec<usize>) {
    let mut label = vec![u32::MAX; w * h];
    let mut sizes = Vec::new();
    let mut stack = Vec::new();
    for start in 0..w * h {
        if fg[start] != want || label[start] != u32::MAX {
            continue;
        }
        let id = sizes.len() as u32;
        let mut size = 0;
        label[start] = id;
        stack.push(start);
        while let Some(i) = stack.pop() {
            size += 1;
            let (x, y) = (i % w, i / w);
            let mut visit = |j: usize| {
                if fg[j] == want && label[j] == u32::MAX {
                    label[j] = id;
                    stack.push(j);
                }
            };
            if x + 1 < w {
                visit(i + 1);
            }
            if x > 0 {
                visit(i - 1);
            }
            if y + 1 < h {
                visit(i + w);
            }
            if y > 0 {
                visit(i - w);
            }
        }
        sizes.push(size);
    }
    (label, sizes)
}

/// Drops distractors (components that do not touch the prior, or small ones without a
/// prior) and fills pinholes.
fn cleanup(
    mut fg: Vec<bool>,
    prior: Option<&[f32]>,
    band: f32,
    w: usize,
    h: usize,
    params: &BuiltinParams,
) -> Mask {
    if let Some(sd) = prior {
        // The prior bounds where to look: nothing beyond its band is robot, whatever
        // changed there (a box moved against the robot, a shadow, a colour like the robot's).
        for (f, &d) in fg.iter_mut().zip(sd) {
            *f = *f && d > -band;
        }
    }
    let (label, sizes) = components(&fg, true, w, h);
    let largest = sizes.iter().copied().max().unwrap_or(0);
    let mut keep = vec![false; sizes.len()];
    match prior {
        Some(sd) => {
            // A component is the robot when enough of it lies inside the prior band.
            let mut inside = vec![0usize; sizes.len()];
            for (i, &l) in label.iter().enumerate() {
                if l != u32::MAX && sd[i] > -0.5 * band {
                    inside[l as usize] += 1;
                }
            }
            for (k, keep) in keep.iter_mut().enumerate() {
                *keep = inside[k] * 2 >= sizes[k] && sizes[k] >= 30;
            }
        }
        None => {
            for (k, keep) in keep.iter_mut().enumerate() {
                *keep = sizes[k] >= (largest / 20).max(100);
            }
        }
    }
    for (f, &l) in fg.iter_mut().zip(&label) {
        if l != u32::MAX {
            *f = keep[l as usize];
        }
    }
    let (holes, hole_sizes) = components(&fg, false, w, h);
    // Holes touching the border are background proper.
    let mut border = vec![false; hole_sizes.len()];
    for x in 0..w {
        for i in [x, (h - 1) * w + x] {
            if holes[i] != u32::MAX {
                border[holes[i] as usize] = true;
            }
        }
    }
    for y in 0..h {
        for i in [y * w, y * w + w - 1] {
            if holes[i] != u32::MAX {
                border[holes[i] as usize] = true;
            }
        }
    }
    for (f, &l) in fg.iter_mut().zip(&holes) {
        if l != u32::MAX && !border[l as usize] && hole_sizes[l as usize] <= params.max_hole_px {
            *f = true;
        }
    }
    Mask {
        width: w as u32,
        height: h as u32,
        data: fg.into_iter().map(u8::from).collect(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_median_by_selection_is_the_sorted_middle() {
        let mut odd = [5.0, -1.0, 3.0, 9.0, 0.5];
        assert_eq!(median_f32(&mut odd), 3.0);
        let mut even = [4.0, 1.0, 8.0, 2.0, 7.0, 3.0];
        assert_eq!(median_f32(&mut even), 3.5);
        assert!(median_f32(&mut []).is_nan());
    }

    #[test]
    fn smoothing_only_near_the_prior_keeps_the_labels_within_its_band() {
        // Undecided pixels in the band and 2 px beyond it, then something robot-like, all on
        // a flat colour: smoothing carries its pull into the band, so a reach too short to
        // carry it changes labels within the band.
        let (w, h) = (64usize, 48usize);
        let img = vec![[120.0f32, 120.0, 120.0]; w * h];
        let mut prior = Mask::new(w as u32, h as u32);
        for y in 14..34 {
            for x in 20..44 {
                prior.set(x, y, true);
            }
        }
        let params = BuiltinParams::default();
        let band = 4.0;
        let sd = signed_distance(&prior, w, h);
        let unary: Vec<f32> = sd
            .iter()
            .map(|&d| {
                if d > 0.0 {
                    2.0
                } else if d > -band - 2.0 {
                    -0.1
                } else {
                    3.0
                }
            })
            .collect();
        let live: Vec<bool> = sd.iter().map(|&d| d > -live_reach(band, &params)).collect();
        assert!(
            live.iter().any(|l| !l),
            "the test needs pixels beyond the reach"
        );
        let whole = mean_field(&unary, &img, w, h, &params, None);
        let near = mean_field(&unary, &img, w, h, &params, Some(&live));
        let in_band = |i: usize| sd[i] > -band;
        let band_alone: Vec<bool> = sd.iter().map(|&d| d > -band - 0.5).collect();
        let cut_short = mean_field(&unary, &img, w, h, &params, Some(&band_alone));
        assert!(
            (0..w * h).any(|i| in_band(i) && cut_short[i] != whole[i]),
            "smoothing the band alone must change labels in it, or this test shows nothing"
        );
        for i in (0..w * h).filter(|&i| in_band(i)) {
            assert_eq!(whole[i], near[i], "pixel {i} differs within the band");
        }
    }
}
