//! `result.json`'s `uncertainty`: the reported figures, the terms they are made of and the
//! segmenter's outline offset, as a solve's report gives them.

use nalgebra::Matrix6;
use serde::{Deserialize, Serialize};

/// `uncertainty`.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq, utoipa::ToSchema)]
pub struct UncertaintyEntry {
    /// Rotation about camera x, y, z, degrees (1 sigma).
    pub rotation_deg: [f64; 3],
    /// Translation along camera x, y, z, millimetres (1 sigma).
    pub translation_mm: [f64; 3],
    /// Radius of the ball around the estimated camera centre that holds the true one with
    /// 95% probability, millimetres.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub camera_centre_95_mm: Option<f64>,
    /// Covariance of the left increment `(rho, phi)` of `camera_from_base` (`rho` metres,
    /// `phi` radians, both in the camera frame), row-major 6x6: what the figures above
    /// summarise, for tools that propagate it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub covariance: Option<Box<[[f64; 6]; 6]>>,
    /// What the figures are made of (absent in results written before the terms were split).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub terms: Option<Box<UncertaintyTerms>>,
    /// The segmenter's outline offset, estimated with the pose (absent unless asked for):
    /// the figures above already hold what not knowing it costs.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mask_offset: Option<MaskOffsetEntry>,
}

/// `uncertainty.mask_offset`: how far the masks' outline lay outward of the rendered robot.
#[derive(Clone, Copy, Debug, Serialize, Deserialize, PartialEq, utoipa::ToSchema)]
#[serde(deny_unknown_fields)]
pub struct MaskOffsetEntry {
    /// Pixels outward (negative: the masks were thin).
    pub px: f64,
    /// Its 1 sigma, pixels.
    pub sigma_px: f64,
}

/// `uncertainty.terms`: the parts of the reported covariance, each as the 95% camera-centre
/// bound it would give on its own.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq, utoipa::ToSchema)]
pub struct UncertaintyTerms {
    /// The term that sets the figures: `statistical` (the outline residuals' own scatter),
    /// `inter-view` (the views' disagreement, from a view jackknife), `mask bias` (not
    /// knowing the segmenter's outline offset), `segmentation` (the pixels the segmenter
    /// could not decide) or `model floor`.
    pub dominant: String,
    /// The statistical term's bound, millimetres.
    pub statistical_centre_95_mm: f64,
    /// The inter-view term's bound, millimetres; absent when it was not measured (fewer
    /// than three views).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub inter_view_centre_95_mm: Option<f64>,
    /// The mask-bias term's bound (what estimating the segmenter's outline offset added),
    /// millimetres; absent when the offset was not estimated.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub mask_bias_centre_95_mm: Option<f64>,
    /// The segmentation term's bound (how far the pixels the segmenter could not decide
    /// could move the pose), millimetres; absent when not measured (masks given, or a
    /// segmenter without per-pixel evidence).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub segmentation_centre_95_mm: Option<f64>,
    /// Why the segmentation term could not be measured, when the masks' segmenter has the
    /// evidence for it but the measurement failed (the segmenter, a frame read again, a
    /// relabelled solve, or the loop's frames and views not matching): the figures then leave
    /// out how far its undecided pixels could move the pose. Absent otherwise.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub segmentation_not_measured: Option<String>,
    /// The segmentation term's own covariance, in `covariance`'s frame and units (when
    /// measured): a bump check takes it out, since the same segmenter on the same scene
    /// repeats the error it stands for.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub segmentation_covariance: Option<Box<[[f64; 6]; 6]>>,
}

impl UncertaintyEntry {
    /// The entry for `u`, or `None` for a degenerate fit (no meaningful curvature): the
    /// field is then left out rather than written as nulls.
    pub fn of(u: &crate::solve::Uncertainty) -> Option<UncertaintyEntry> {
        let covariance = rows_of(&u.covariance);
        u.rotation_deg
            .iter()
            .chain(&u.translation_mm)
            .chain(std::iter::once(&u.camera_centre_95_mm))
            .chain(covariance.iter().flatten())
            .all(|v| v.is_finite())
            .then_some(UncertaintyEntry {
                rotation_deg: u.rotation_deg,
                translation_mm: u.translation_mm,
                camera_centre_95_mm: Some(u.camera_centre_95_mm),
                covariance: Some(Box::new(covariance)),
                terms: None,
                mask_offset: None,
            })
    }

    /// [`UncertaintyEntry::of`] the report's uncertainty, with the terms it is made of.
    pub fn of_report(
        report: &crate::solve::SolveReport,
        opts: &crate::solve::SolveOptions,
    ) -> Option<UncertaintyEntry> {
        let (statistical, inter_view) = report.term_bounds_mm();
        let mask_bias = report.mask_bias_bound_mm();
        let segmentation = report.segmentation_bound_mm();
        let mut entry = UncertaintyEntry::of(&report.uncertainty)?;
        let finite = statistical.is_finite()
            && inter_view.is_none_or(f64::is_finite)
            && mask_bias.is_none_or(f64::is_finite)
            && segmentation.is_none_or(f64::is_finite);
        entry.terms = finite.then(|| {
            Box::new(UncertaintyTerms {
                dominant: report.dominant_term(opts).name().into(),
                statistical_centre_95_mm: statistical,
                inter_view_centre_95_mm: inter_view,
                mask_bias_centre_95_mm: mask_bias,
                segmentation_centre_95_mm: segmentation,
                segmentation_not_measured: match &report.segmentation {
                    crate::solve::SegmentationTerm::Unavailable(why) => Some(why.clone()),
                    _ => None,
                },
                segmentation_covariance: report
                    .segmentation
                    .covariance()
                    .map(|c| Box::new(rows_of(c))),
            })
        });
        entry.mask_offset = report
            .mask_offset
            .filter(|m| m.px.is_finite() && m.sigma_px.is_finite())
            .map(|m| MaskOffsetEntry {
                px: m.px,
                sigma_px: m.sigma_px,
            });
        Some(entry)
    }

    /// The part of this covariance that can move the outline between the calibration and a
    /// later check of it: `covariance` less the cell's model-error `floor` and less the
    /// segmentation term. A URDF or intrinsics error is the same at the calibration and at
    /// the check, and so is the error of the pixels the segmenter could not decide (the same
    /// segmenter on the same scene), so neither explains outline motion between them, and
    /// either left in would hide real bumps. Negative variances this leaves (a floor raised
    /// after the calibration) count as none in
    /// [`crate::solve::predicted_outline_motion_px`]. `None` without a covariance.
    pub fn moving_between_checks(&self, floor: &Matrix6<f64>) -> Option<Matrix6<f64>> {
        let segmentation = self
            .terms
            .as_ref()
            .and_then(|t| t.segmentation_covariance.as_deref())
            .map_or_else(Matrix6::zeros, matrix_of);
        Some(self.covariance_matrix()? - floor - segmentation)
    }

    /// `covariance` as a matrix, when written.
    pub fn covariance_matrix(&self) -> Option<Matrix6<f64>> {
        self.covariance.as_deref().map(matrix_of)
    }

    /// The first value that no solve could have written, as `(field path, problem)`: every
    /// figure finite and not negative, the mask offset finite, each covariance symmetric with a
    /// non-negative diagonal, and the segmentation term's only beside a covariance it fits in.
    pub fn problem(&self) -> Option<(String, String)> {
        let figures = self
            .rotation_deg
            .iter()
            .map(|v| ("rotation_deg", *v))
            .chain(self.translation_mm.iter().map(|v| ("translation_mm", *v)))
            .chain(self.camera_centre_95_mm.map(|v| ("camera_centre_95_mm", v)));
        for (field, v) in figures {
            if !(v.is_finite() && v >= 0.0) {
                return Some((
                    format!("uncertainty.{field}"),
                    format!("is {v}; allowed: a finite number >= 0"),
                ));
            }
        }
        if let Some(m) = &self.mask_offset {
            if !(m.px.is_finite() && m.sigma_px.is_finite() && m.sigma_px >= 0.0) {
                return Some((
                    "uncertainty.mask_offset".into(),
                    format!(
                        "is {} px ± {} px; allowed: finite, with a sigma >= 0",
                        m.px, m.sigma_px
                    ),
                ));
            }
        }
        let covariance = self.covariance.as_deref();
        if let Some(p) = covariance.and_then(|c| covariance_problem("uncertainty.covariance", c)) {
            return Some(p);
        }
        let terms = self.terms.as_deref()?;
        let segmentation = terms.segmentation_covariance.as_deref()?;
        let field = "uncertainty.terms.segmentation_covariance";
        if let Some(p) = covariance_problem(field, segmentation) {
            return Some(p);
        }
        let Some(covariance) = covariance else {
            return Some((
                field.into(),
                "is present without uncertainty.covariance; allowed: only as a part of it".into(),
            ));
        };
        if terms.segmentation_not_measured.is_some() {
            return Some((
                field.into(),
                "is present beside segmentation_not_measured; allowed: one or the other".into(),
            ));
        }
        part_problem(field, segmentation, covariance)
    }
}

/// A covariance as `result.json` writes it: row-major rows.
fn rows_of(m: &Matrix6<f64>) -> [[f64; 6]; 6] {
    std::array::from_fn(|r| std::array::from_fn(|c| m[(r, c)]))
}

/// The matrix of rows [`rows_of`] wrote.
fn matrix_of(rows: &[[f64; 6]; 6]) -> Matrix6<f64> {
    Matrix6::from_fn(|r, c| rows[r][c])
}

/// A variance of the term `part` above the covariance it is part of, as `(field path,
/// problem)`: a term taken out of `whole` must leave a covariance.
fn part_problem(
    field: &str,
    part: &[[f64; 6]; 6],
    whole: &[[f64; 6]; 6],
) -> Option<(String, String)> {
    (0..6)
        .find(|&r| part[r][r] > whole[r][r] * (1.0 + 1e-9))
        .map(|r| {
            (
                format!("{field}[{r}][{r}]"),
                format!(
                    "is {}, above uncertainty.covariance[{r}][{r}] = {}; allowed: at most the \
                     variance it is part of",
                    part[r][r], whole[r][r]
                ),
            )
        })
}

/// The first entry of `c` that is not finite, breaks its symmetry or is a negative variance,
/// as `(field path, problem)`.
fn covariance_problem(field: &str, c: &[[f64; 6]; 6]) -> Option<(String, String)> {
    for r in 0..6 {
        for k in 0..6 {
            let v = c[r][k];
            let bad = !v.is_finite()
                || (r == k && v < 0.0)
                || (v - c[k][r]).abs() > 1e-9 * (c[r][r].abs() + c[k][k].abs()).max(1e-30);
            if bad {
                return Some((
                    format!("{field}[{r}][{k}]"),
                    format!("is {v}; allowed: finite, symmetric, diagonal >= 0"),
                ));
            }
        }
    }
    None
}

#[cfg(test)]
mod tests {
    use super::*;

    fn entry(mask_offset: Option<MaskOffsetEntry>) -> UncertaintyEntry {
        UncertaintyEntry {
            rotation_deg: [0.1; 3],
            translation_mm: [0.5; 3],
            camera_centre_95_mm: Some(2.0),
            covariance: None,
            terms: None,
            mask_offset,
        }
    }

    #[test]
    fn a_mask_offset_reads_back_and_a_broken_one_is_named() {
        let good = entry(Some(MaskOffsetEntry {
            px: -0.87,
            sigma_px: 0.04,
        }));
        assert_eq!(good.problem(), None);
        let json = serde_json::to_string(&good).unwrap();
        assert!(
            json.contains("\"mask_offset\":{\"px\":-0.87,\"sigma_px\":0.04}"),
            "{json}"
        );
        assert_eq!(
            serde_json::from_str::<UncertaintyEntry>(&json).unwrap(),
            good
        );
        assert!(!serde_json::to_string(&entry(None))
            .unwrap()
            .contains("mask_offset"));
        let broken = entry(Some(MaskOffsetEntry {
            px: 1.0,
            sigma_px: f64::NAN,
        }));
        let (field, _) = broken.problem().expect("a NaN sigma is refused");
        assert_eq!(field, "uncertainty.mask_offset");
    }

    #[test]
    fn a_segmentation_covariance_must_be_a_symmetric_part_of_the_covariance() {
        let with_term = |total: Option<f64>, c: [[f64; 6]; 6], not_measured: bool| {
            let mut e = entry(None);
            e.covariance = total.map(|v| {
                let mut t = [[0.0; 6]; 6];
                (0..6).for_each(|r| t[r][r] = v);
                Box::new(t)
            });
            e.terms = Some(Box::new(UncertaintyTerms {
                dominant: "segmentation".into(),
                statistical_centre_95_mm: 1.0,
                inter_view_centre_95_mm: None,
                mask_bias_centre_95_mm: None,
                segmentation_centre_95_mm: Some(3.0),
                segmentation_not_measured: not_measured.then(|| "a solve failed".into()),
                segmentation_covariance: Some(Box::new(c)),
            }));
            e
        };
        let field_of = |e: &UncertaintyEntry| e.problem().map(|(field, _)| field);
        let mut c = [[0.0; 6]; 6];
        c[2][2] = 1e-5;
        let good = with_term(Some(2e-5), c, false);
        assert_eq!(good.problem(), None);
        // A term may be all of a variance (nothing else in that direction).
        assert_eq!(with_term(Some(1e-5), c, false).problem(), None);
        let json = serde_json::to_string(&good).unwrap();
        assert_eq!(
            serde_json::from_str::<UncertaintyEntry>(&json).unwrap(),
            good
        );
        let field = "uncertainty.terms.segmentation_covariance";
        assert_eq!(field_of(&with_term(None, c, false)).as_deref(), Some(field));
        assert_eq!(
            field_of(&with_term(Some(2e-5), c, true)).as_deref(),
            Some(field)
        );
        let larger = format!("{field}[2][2]");
        assert_eq!(field_of(&with_term(Some(5e-6), c, false)), Some(larger));
        c[0][1] = 1e-6;
        let (asymmetric, problem) = with_term(Some(2e-5), c, false).problem().unwrap();
        assert_eq!(asymmetric, format!("{field}[0][1]"));
        assert!(problem.contains("symmetric"), "{problem}");
    }
}
