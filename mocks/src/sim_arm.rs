//! A simulated position-controlled arm.

use std::sync::{Arc, Mutex, MutexGuard};
use std::time::Duration;

use async_trait::async_trait;
use easyhec_drivers::{Arm, ArmStatus, DriverError, JointLimit, Motion, Result};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use rand_distr::{Distribution, Normal};

/// A fault to inject on a given move (0-based count of `move_to` calls).
#[derive(Clone, Debug, PartialEq)]
pub enum Fault {
    /// The controller rejects move `on_move` without moving.
    Refuse {
        /// Which move.
        on_move: usize,
    },
    /// Move `on_move` faults after covering `at_fraction` of the path.
    ErrorMidMove {
        /// Which move.
        on_move: usize,
        /// Fraction of the path covered before the fault, 0..1.
        at_fraction: f64,
    },
    /// Move `on_move` stops making progress at `at_fraction` of the path.
    Stall {
        /// Which move.
        on_move: usize,
        /// Fraction of the path covered before the stall, 0..1.
        at_fraction: f64,
    },
}

/// Simulated arm settings.
#[derive(Clone, Debug)]
pub struct SimArmConfig {
    /// Joints with the limits the simulated controller enforces.
    pub joints: Vec<JointLimit>,
    /// True joint positions at start.
    pub start: Vec<f64>,
    /// Standard deviation of the reported joint noise, radians.
    pub encoder_noise_rad: f64,
    /// Simulated seconds per wall second (`f64::INFINITY`: no sleeping, motion still stepped).
    pub speedup: f64,
    /// Faults to inject.
    pub faults: Vec<Fault>,
    /// Seed of the encoder noise.
    pub seed: u64,
}

/// One `move_to` call as the simulated controller saw it.
#[derive(Clone, Debug, PartialEq)]
pub struct CommandRecord {
    /// True joints when the command arrived.
    pub from: Vec<f64>,
    /// Commanded target.
    pub target: Vec<f64>,
    /// Commanded speed of the fastest joint, rad/s.
    pub speed_rad_s: f64,
    /// Whether the controller accepted it.
    pub accepted: bool,
    /// How it ended: `None` while moving, `Some("arrived")`, or the failure.
    pub outcome: Option<String>,
}

struct State {
    q_true: Vec<f64>,
    status: ArmStatus,
    moves: usize,
    log: Vec<CommandRecord>,
    rng: ChaCha8Rng,
    /// Bumped by `stop` and by every new move; a motion task stops when it changes.
    generation: u64,
}

/// Simulated arm (see the crate docs). Cloning shares the same arm.
#[derive(Clone)]
pub struct SimArm {
    cfg: Arc<SimArmConfig>,
    state: Arc<Mutex<State>>,
}

/// Simulated control period.
const STEP_S: f64 = 0.02;

impl SimArm {
    /// A simulated arm at `cfg.start`.
    ///
    /// # Panics
    /// If `cfg.start` and `cfg.joints` differ in length (a programming error in the caller).
    pub fn new(cfg: SimArmConfig) -> SimArm {
        assert_eq!(cfg.start.len(), cfg.joints.len(), "start vector length");
        let state = State {
            q_true: cfg.start.clone(),
            status: ArmStatus::Idle,
            moves: 0,
            log: Vec::new(),
            rng: ChaCha8Rng::seed_from_u64(cfg.seed),
            generation: 0,
        };
        SimArm {
            cfg: Arc::new(cfg),
            state: Arc::new(Mutex::new(state)),
        }
    }

    fn lock(&self) -> MutexGuard<'_, State> {
        // A panic while holding the lock cannot leave the state half-updated in a way that
        // matters for a simulation, so a poisoned lock is still usable.
        self.state.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// The arm's true joints (no encoder noise): the simulated camera's side channel.
    pub fn true_joints(&self) -> Vec<f64> {
        self.lock().q_true.clone()
    }

    /// Every command received, in order.
    pub fn commands(&self) -> Vec<CommandRecord> {
        self.lock().log.clone()
    }

    fn refuse(&self, st: &mut State, rec: CommandRecord, why: String) -> DriverError {
        st.log.push(CommandRecord {
            accepted: false,
            outcome: Some(why.clone()),
            ..rec
        });
        DriverError::Refused(why)
    }
}

#[async_trait]
impl Arm for SimArm {
    fn joints(&self) -> &[JointLimit] {
        &self.cfg.joints
    }

    async fn read_joints(&self) -> Result<Vec<f64>> {
        let mut st = self.lock();
        let sigma = self.cfg.encoder_noise_rad;
        let q = st.q_true.clone();
        if sigma <= 0.0 {
            return Ok(q);
        }
        let noise = Normal::new(0.0, sigma).map_err(|e| DriverError::Backend(Box::new(e)))?;
        Ok(q.iter().map(|v| v + noise.sample(&mut st.rng)).collect())
    }

    async fn move_to(&self, target: &[f64], speed_rad_s: f64) -> Result<Motion> {
        let (from, generation, fault) = {
            let mut st = self.lock();
            let rec = CommandRecord {
                from: st.q_true.clone(),
                target: target.to_vec(),
                speed_rad_s,
                accepted: true,
                outcome: None,
            };
            let index = st.moves;
            st.moves += 1;
            if st.status == ArmStatus::Moving {
                return Err(self.refuse(&mut st, rec, "already moving".into()));
            }
            if target.len() != self.cfg.joints.len() {
                let why = format!(
                    "target has {} joints, arm has {}",
                    target.len(),
                    self.cfg.joints.len()
                );
                return Err(self.refuse(&mut st, rec, why));
            }
            for (j, (v, lim)) in target.iter().zip(&self.cfg.joints).enumerate() {
                if !v.is_finite() || *v < lim.lower || *v > lim.upper {
                    let why = format!(
                        "joint {j} ({}) target {v} outside [{}, {}]",
                        lim.name, lim.lower, lim.upper
                    );
                    return Err(self.refuse(&mut st, rec, why));
                }
            }
            let cap = self
                .cfg
                .joints
                .iter()
                .map(|l| l.max_velocity)
                .fold(f64::INFINITY, f64::min);
            if !(speed_rad_s > 0.0 && speed_rad_s <= cap) {
                let why = format!("speed {speed_rad_s} rad/s outside (0, {cap}]");
                return Err(self.refuse(&mut st, rec, why));
            }
            let fault = self.cfg.faults.iter().find(|f| match f {
                Fault::Refuse { on_move }
                | Fault::ErrorMidMove { on_move, .. }
                | Fault::Stall { on_move, .. } => *on_move == index,
            });
            if let Some(Fault::Refuse { .. }) = fault {
                return Err(self.refuse(&mut st, rec, "injected refusal".into()));
            }
            st.generation += 1;
            st.status = ArmStatus::Moving;
            st.log.push(rec);
            (st.q_true.clone(), st.generation, fault.cloned())
        };
        let distance = from
            .iter()
            .zip(target)
            .map(|(a, b)| (b - a).abs())
            .fold(0.0, f64::max);
        let duration_s = distance / speed_rad_s;
        let steps = ((duration_s / STEP_S).ceil() as usize).max(1);
        let (stop_at, failure) = match fault {
            Some(Fault::ErrorMidMove { at_fraction, .. }) => (
                at_fraction.clamp(0.0, 1.0),
                Some(DriverError::MotionFailed("injected fault mid-move".into())),
            ),
            Some(Fault::Stall { at_fraction, .. }) => (
                at_fraction.clamp(0.0, 1.0),
                Some(DriverError::Stalled("injected stall: no progress".into())),
            ),
            _ => (1.0, None),
        };
        let arm = self.clone();
        let target = target.to_vec();
        let speedup = self.cfg.speedup;
        let task = tokio::spawn(async move {
            for k in 1..=steps {
                let s = (k as f64 / steps as f64).min(stop_at);
                {
                    let mut st = arm.lock();
                    if st.generation != generation {
                        return Err(DriverError::MotionFailed("stopped".into()));
                    }
                    st.q_true = from
                        .iter()
                        .zip(&target)
                        .map(|(a, b)| a + (b - a) * s)
                        .collect();
                }
                if speedup.is_finite() && speedup > 0.0 {
                    tokio::time::sleep(Duration::from_secs_f64(STEP_S / speedup)).await;
                } else {
                    tokio::task::yield_now().await;
                }
                if s >= stop_at && stop_at < 1.0 {
                    break;
                }
            }
            let mut st = arm.lock();
            let outcome = match &failure {
                None => "arrived".to_string(),
                Some(e) => e.to_string(),
            };
            st.status = match &failure {
                None => ArmStatus::Idle,
                Some(e) => ArmStatus::Fault(e.to_string()),
            };
            if let Some(rec) = st.log.iter_mut().rev().find(|r| r.accepted) {
                rec.outcome = Some(outcome);
            }
            match failure {
                None => Ok(()),
                Some(e) => Err(e),
            }
        });
        Ok(Motion::new(async move {
            task.await
                .map_err(|e| DriverError::MotionFailed(format!("motion task: {e}")))?
        }))
    }

    async fn stop(&self) -> Result<()> {
        let mut st = self.lock();
        st.generation += 1;
        if st.status == ArmStatus::Moving {
            st.status = ArmStatus::Stopped;
        }
        Ok(())
    }

    async fn status(&self) -> Result<ArmStatus> {
        Ok(self.lock().status.clone())
    }

    async fn clear_fault(&self) -> Result<()> {
        self.reset();
        Ok(())
    }
}

impl SimArm {
    /// Resets a faulted or stopped arm to idle (what an operator's reset does).
    pub fn reset(&self) {
        let mut st = self.lock();
        if st.status != ArmStatus::Moving {
            st.status = ArmStatus::Idle;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn arm(faults: Vec<Fault>) -> SimArm {
        SimArm::new(SimArmConfig {
            joints: (0..2)
                .map(|i| JointLimit {
                    name: format!("j{i}"),
                    lower: -1.0,
                    upper: 1.0,
                    max_velocity: 1.0,
                })
                .collect(),
            start: vec![0.0, 0.0],
            encoder_noise_rad: 0.0,
            speedup: f64::INFINITY,
            faults,
            seed: 1,
        })
    }

    #[tokio::test]
    async fn moves_along_the_joint_line_and_arrives() {
        let a = arm(vec![]);
        a.move_to(&[0.5, -0.25], 0.5)
            .await
            .unwrap()
            .wait()
            .await
            .unwrap();
        assert_eq!(a.true_joints(), vec![0.5, -0.25]);
        assert_eq!(a.commands()[0].outcome.as_deref(), Some("arrived"));
        assert_eq!(a.status().await.unwrap(), ArmStatus::Idle);
    }

    #[tokio::test]
    async fn refuses_out_of_limit_targets_and_speeds() {
        let a = arm(vec![]);
        assert!(a.move_to(&[1.5, 0.0], 0.5).await.is_err());
        assert!(a.move_to(&[0.5, 0.0], 2.0).await.is_err());
        assert!(a.move_to(&[f64::NAN, 0.0], 0.5).await.is_err());
        assert_eq!(a.true_joints(), vec![0.0, 0.0]);
        assert!(a.commands().iter().all(|c| !c.accepted));
    }

    #[tokio::test]
    async fn injected_faults_stop_partway_on_the_line() {
        let a = arm(vec![
            Fault::Refuse { on_move: 0 },
            Fault::ErrorMidMove {
                on_move: 1,
                at_fraction: 0.5,
            },
            Fault::Stall {
                on_move: 2,
                at_fraction: 0.25,
            },
        ]);
        assert!(matches!(
            a.move_to(&[0.8, 0.0], 1.0).await,
            Err(DriverError::Refused(_))
        ));
        let e = a.move_to(&[0.8, 0.4], 1.0).await.unwrap().wait().await;
        assert!(matches!(e, Err(DriverError::MotionFailed(_))));
        let q = a.true_joints();
        assert!(
            (q[0] - 0.4).abs() < 1e-9 && (q[1] - 0.2).abs() < 1e-9,
            "{q:?}"
        );
        assert!(matches!(a.status().await.unwrap(), ArmStatus::Fault(_)));
        a.reset();
        let e = a.move_to(&[0.0, 0.0], 1.0).await.unwrap().wait().await;
        assert!(matches!(e, Err(DriverError::Stalled(_))));
        let q = a.true_joints();
        assert!(
            (q[0] - 0.3).abs() < 1e-9 && (q[1] - 0.15).abs() < 1e-9,
            "{q:?}"
        );
    }
}
