//! A dry run's planned poses, kept in its run directory as `plan.json` so the page can draw
//! them (`GET /api/v1/calibrations/{id}/plan/{k}/overlay.png`) before anything moves.

use std::path::Path;

use serde::{Deserialize, Serialize};

use super::Refusal;
use crate::calibrate::PlannedPose;
use crate::error::Result;

/// `plan.json` format tag.
pub const PLAN_FORMAT: &str = "easyhec-plan/1";
/// More poses than any config allows views (`calibration.max_views` is bounded far lower).
const MAX_POSES: usize = 1000;

/// `plan.json`: the joints of each planned pose, in visiting order.
#[derive(Serialize, Deserialize)]
struct PlanFile {
    format: String,
    joints: Vec<Vec<f64>>,
}

/// Writes the plan of a dry run.
pub fn write(run_dir: &Path, planned: &[PlannedPose]) -> Result<()> {
    let plan = PlanFile {
        format: PLAN_FORMAT.into(),
        joints: planned.iter().map(|p| p.joints.clone()).collect(),
    };
    crate::io::write_json_atomic(&run_dir.join("plan.json"), &plan)
}

/// Planned pose `k` from `path` (a run's `plan.json`, already checked to lie in the data
/// folder), checked: the format, the count, and `dof` finite joints. Missing is 404; a file
/// that does not read back is 500.
pub fn pose(path: &Path, k: usize, dof: usize) -> std::result::Result<Vec<f64>, Refusal> {
    if !path.is_file() {
        return Err(Refusal::NotFound(
            "this calibration has no plan (only a dry run has one)".into(),
        ));
    }
    let text = crate::io::read_text_input(path).map_err(|e| Refusal::Internal(e.to_string()))?;
    let plan: PlanFile = serde_json::from_str(&text)
        .map_err(|e| Refusal::Internal(format!("{}: {e}", path.display())))?;
    if plan.format != PLAN_FORMAT || plan.joints.len() > MAX_POSES {
        return Err(Refusal::Internal(format!(
            "{}: format {:?} with {} poses; allowed: {PLAN_FORMAT} with at most {MAX_POSES}",
            path.display(),
            plan.format,
            plan.joints.len()
        )));
    }
    let n = plan.joints.len();
    let q = plan.joints.into_iter().nth(k).ok_or_else(|| {
        Refusal::NotFound(format!("the plan has {n} poses; pose {k} does not exist"))
    })?;
    if q.len() != dof || q.iter().any(|v| !v.is_finite()) {
        return Err(Refusal::Internal(format!(
            "{}: joints[{k}]: {} values; allowed: {dof} finite values",
            path.display(),
            q.len()
        )));
    }
    Ok(q)
}
