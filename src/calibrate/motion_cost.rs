//! What a view costs in time: the move to it plus the work done at it.
//!
//! On a real arm most of a calibration's wall time is motion. The planner therefore ranks a
//! candidate by the information it adds per second it costs: the predicted cost reduction
//! divided by `overhead + travel`. `travel` is the commanded move's time (the fastest joint at
//! the commanded speed, the way `SafeArm` sends it). `overhead` is what each view costs besides
//! the move: capture, segmentation, solve and planning, as measured so far in this run. When
//! travel is short next to the overhead, the ranking is the pure information ranking. When a
//! far pose adds little more than a near one, the near one wins.

use crate::config::SimArmSettings;
use crate::config::{ArmConfig, CellConfig};

/// The time model of one planning round.
#[derive(Clone, Debug)]
pub struct MotionCost {
    /// Where the arm stands.
    pub from: Vec<f64>,
    /// Commanded speed of the fastest joint, rad/s.
    pub speed_rad_s: f64,
    /// Wall seconds per second of commanded motion: 1 on hardware and protocol mocks, 0 for
    /// the simulated arm, which arrives at once unless slowed (`[arm] speedup`).
    pub time_scale: f64,
    /// Seconds each view costs besides the move.
    pub overhead_s: f64,
}

impl MotionCost {
    /// Wall seconds of a move to `q` plus the view's overhead.
    pub fn seconds_to(&self, q: &[f64]) -> f64 {
        self.overhead_s + self.time_scale * travel_s(&self.from, q, self.speed_rad_s)
    }

    /// `gain` (a cost reduction, higher is better) per second of reaching `q`. A negative gain
    /// (the first rounds, before the covariance is finite) is scaled the other way, so a
    /// shorter move still ranks higher.
    pub fn rate(&self, gain: f64, q: &[f64]) -> f64 {
        let s = self.seconds_to(q).max(1e-3);
        if gain >= 0.0 {
            gain / s
        } else {
            gain * s
        }
    }
}

/// Seconds of a commanded move from `from` to `to`: the farthest joint's travel at
/// `speed_rad_s`, the way `SafeArm` sends a move.
pub fn travel_s(from: &[f64], to: &[f64], speed_rad_s: f64) -> f64 {
    let farthest = from
        .iter()
        .zip(to)
        .map(|(a, b)| (a - b).abs())
        .fold(0.0, f64::max);
    farthest / speed_rad_s
}

/// Wall seconds per second of commanded motion for the arm `config` drives.
pub fn time_scale(config: &CellConfig) -> f64 {
    match &config.arm {
        ArmConfig::Sim(SimArmSettings { speedup, .. }) => match speedup {
            Some(s) if s.is_finite() && *s > 0.0 => 1.0 / s,
            _ => 0.0,
        },
        _ => 1.0,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cost(time_scale: f64) -> MotionCost {
        MotionCost {
            from: vec![0.0, 0.0],
            speed_rad_s: 0.5,
            time_scale,
            overhead_s: 2.0,
        }
    }

    #[test]
    fn the_farthest_joint_at_the_commanded_speed_sets_the_time() {
        assert!((cost(1.0).seconds_to(&[1.0, -0.5]) - 4.0).abs() < 1e-12);
        // An arm that arrives at once costs only the overhead.
        assert!((cost(0.0).seconds_to(&[1.0, -0.5]) - 2.0).abs() < 1e-12);
    }

    #[test]
    fn only_arms_whose_moves_take_time_have_a_time_scale() {
        let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("config/sim-xarm6.toml");
        let mut cfg = crate::config::read_config(&path).unwrap();
        assert_eq!(time_scale(&cfg), 0.0, "the simulated arm arrives at once");
        if let ArmConfig::Sim(SimArmSettings { speedup, .. }) = &mut cfg.arm {
            *speedup = Some(20.0);
        }
        assert_eq!(time_scale(&cfg), 0.05);
        let mock = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("config/mock-xarm.toml");
        assert_eq!(time_scale(&crate::config::read_config(&mock).unwrap()), 1.0);
    }

    #[test]
    fn nearer_poses_rank_higher_at_equal_gain_whatever_its_sign() {
        let c = cost(1.0);
        let (near, far) = ([0.2, 0.0], [2.0, 0.0]);
        assert!(c.rate(1.0, &near) > c.rate(1.0, &far));
        assert!(c.rate(-1.0, &near) > c.rate(-1.0, &far));
        // A far pose must add more to be worth its time.
        assert!(c.rate(3.0, &far) > c.rate(1.0, &near));
    }
}
