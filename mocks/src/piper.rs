//! A mock AgileX Piper on a CAN bus (any [`CanBus`]; in CI the in-process one): answers
//! enable (0x471), mode (0x151), joint targets (0x155–0x157), resume/stop (0x150); moves
//! linearly in joint space at the commanded speed percentage; pushes joint feedback
//! (0x2A5–0x2A7), status (0x2A1) and driver states (0x261–0x266) at a fixed period; and
//! records every target it received so tests can check limits and speed on the wire.
//!
//! Like the SDK, it refuses a target beyond its joint limits by reporting arm status 4
//! ("target exceeds limit") with the joints' over-limit bits. Faults: a collision (status 7)
//! partway through a given move, and a silent arm.

use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use easyhec_drivers::piper::frame::{
    decode_joint_pair, driver_state_frame, id, joint_feedback_frames, millideg_to_rad,
    rad_to_millideg, ModeCommand, StatusFrame, CONTROL_MODE_CAN, MOVE_J,
};
use easyhec_drivers::piper::{CanBus, CanFrame, PIPER_LIMITS_RAD};
use tokio::task::JoinHandle;

/// An injected fault.
#[derive(Clone, Debug)]
pub enum PiperFault {
    /// Collision detected (arm status 7) after `at_fraction` of move `on_move` (0-based,
    /// counting accepted new targets).
    Collision {
        /// Which move.
        on_move: usize,
        /// Fraction of the path covered when it hits.
        at_fraction: f64,
    },
}

/// Settings of a [`MockPiper`].
#[derive(Clone, Debug)]
pub struct MockPiperConfig {
    /// Joints at start, radians.
    pub start: [f64; 6],
    /// Joint limits it enforces, radians.
    pub limits: [(f64, f64); 6],
    /// Joint speed at 100 %, rad/s.
    pub full_speed_rad_s: f64,
    /// Period of the feedback frames (wall time).
    pub feedback_period: Duration,
    /// Simulated seconds per wall second.
    pub speedup: f64,
    /// Time from the enable frame to the drivers reporting enabled (wall time).
    pub enable_delay: Duration,
    /// Injected faults.
    pub faults: Vec<PiperFault>,
}

impl Default for MockPiperConfig {
    fn default() -> MockPiperConfig {
        MockPiperConfig {
            start: [0.0, 0.5, -0.5, 0.0, 0.0, 0.0],
            limits: PIPER_LIMITS_RAD,
            full_speed_rad_s: std::f64::consts::PI,
            feedback_period: Duration::from_millis(5),
            speedup: 1.0,
            enable_delay: Duration::from_millis(20),
            faults: Vec::new(),
        }
    }
}

/// A joint target set as the arm received it.
#[derive(Clone, Debug, PartialEq)]
pub struct TargetRecord {
    /// Targets on the wire, 0.001°.
    pub millideg: [i32; 6],
    /// The speed byte of the mode frame in force.
    pub speed_pct: u8,
    /// Whether the arm started (or kept) moving to it.
    pub accepted: bool,
}

struct Move {
    from: [f64; 6],
    goal: [f64; 6],
    goal_millideg: [i32; 6],
    started: Instant,
    duration_s: f64,
    index: usize,
}

struct State {
    cfg: MockPiperConfig,
    rest: [f64; 6],
    motion: Option<Move>,
    enable_at: Option<Instant>,
    mode: Option<ModeCommand>,
    pending: [Option<(i32, i32)>; 3],
    status: StatusFrame,
    moves: usize,
    silent: bool,
    targets: Vec<TargetRecord>,
    received: Vec<CanFrame>,
}

/// The mock arm; dropping it ends its task.
pub struct MockPiper {
    state: Arc<Mutex<State>>,
    task: JoinHandle<()>,
}

fn lock(s: &Mutex<State>) -> MutexGuard<'_, State> {
    s.lock().unwrap_or_else(|p| p.into_inner())
}

impl State {
    fn enabled(&self) -> bool {
        self.enable_at.is_some_and(|t| Instant::now() >= t)
    }

    fn progress(&self, m: &Move) -> f64 {
        if m.duration_s <= 0.0 {
            return 1.0;
        }
        (m.started.elapsed().as_secs_f64() * self.cfg.speedup / m.duration_s).min(1.0)
    }

    fn at(m: &Move, s: f64) -> [f64; 6] {
        std::array::from_fn(|k| m.from[k] + (m.goal[k] - m.from[k]) * s)
    }

    fn present(&self) -> [f64; 6] {
        self.motion
            .as_ref()
            .map_or(self.rest, |m| State::at(m, self.progress(m)))
    }

    fn halt(&mut self) {
        self.rest = self.present();
        self.motion = None;
    }

    /// Advances the simulation: arrival and injected faults.
    fn step(&mut self) {
        let Some(m) = &self.motion else { return };
        let s = self.progress(m);
        for f in &self.cfg.faults {
            let PiperFault::Collision {
                on_move,
                at_fraction,
            } = *f;
            if on_move == m.index && s >= at_fraction {
                self.rest = State::at(m, at_fraction);
                self.motion = None;
                self.status.arm_status = 7;
                return;
            }
        }
        if s >= 1.0 {
            self.rest = m.goal;
            self.motion = None;
        }
    }

    fn handle(&mut self, f: &CanFrame) {
        self.received.push(*f);
        self.step();
        match f.id {
            id::ENABLE => {
                let all = f.data[0] == 7 || f.data[0] == 0xFF;
                if all && f.data[1] == 0x02 && self.enable_at.is_none() {
                    self.enable_at = Some(Instant::now() + self.cfg.enable_delay);
                } else if all && f.data[1] == 0x01 {
                    self.halt();
                    self.enable_at = None;
                }
            }
            id::MODE => self.mode = ModeCommand::decode(f),
            id::MOTION_CONTROL => match f.data[0] {
                1 => {
                    self.halt();
                    self.status.arm_status = 1;
                }
                2 => {
                    self.status.arm_status = 0;
                    self.status.over_limit = 0;
                }
                _ => {}
            },
            _ => {
                if let Some((k, a, b)) = decode_joint_pair(id::JOINT_TARGET_12, f) {
                    self.pending[k / 2] = Some((a, b));
                    if self.pending.iter().all(Option::is_some) {
                        let p = std::mem::take(&mut self.pending).map(|p| p.unwrap_or_default());
                        self.target([p[0].0, p[0].1, p[1].0, p[1].1, p[2].0, p[2].1]);
                    }
                }
            }
        }
    }

    fn target(&mut self, millideg: [i32; 6]) {
        let mode = self.mode.unwrap_or(ModeCommand::move_j(0));
        let speed_pct = mode.speed_pct.min(100);
        let ready = self.enabled()
            && self.status.arm_status == 0
            && mode.control_mode == CONTROL_MODE_CAN
            && mode.move_mode == MOVE_J
            && speed_pct > 0;
        let goal: [f64; 6] = millideg.map(millideg_to_rad);
        let over: u8 = (0..6)
            .filter(|&k| {
                goal[k] < self.cfg.limits[k].0 - 1e-5 || goal[k] > self.cfg.limits[k].1 + 1e-5
            })
            .fold(0, |b, k| b | (1 << k));
        let mut accepted = ready && over == 0;
        if ready && over != 0 {
            self.halt();
            self.status.arm_status = 4;
            self.status.over_limit = over;
        }
        let same = self
            .motion
            .as_ref()
            .is_some_and(|m| m.goal_millideg == millideg);
        if accepted && !same {
            let from = self.present();
            let dmax = (0..6)
                .map(|k| (goal[k] - from[k]).abs())
                .fold(0.0, f64::max);
            let speed = f64::from(speed_pct) / 100.0 * self.cfg.full_speed_rad_s;
            if dmax == 0.0 {
                self.rest = from;
                self.motion = None;
            } else {
                self.motion = Some(Move {
                    from,
                    goal,
                    goal_millideg: millideg,
                    started: Instant::now(),
                    duration_s: dmax / speed,
                    index: self.moves,
                });
                self.moves += 1;
            }
        }
        accepted &= ready;
        self.targets.push(TargetRecord {
            millideg,
            speed_pct,
            accepted,
        });
    }

    fn feedback(&mut self) -> Vec<CanFrame> {
        self.step();
        if self.silent {
            return Vec::new();
        }
        let q = self.present().map(|v| rad_to_millideg(v).unwrap_or(0));
        let mut out: Vec<CanFrame> = joint_feedback_frames(&q).to_vec();
        let mode = self.mode;
        self.status.control_mode = mode.map_or(0, |m| m.control_mode);
        self.status.mode_feedback = mode.map_or(0, |m| m.move_mode);
        self.status.motion_status = u8::from(self.motion.is_some());
        out.push(self.status.encode());
        let on = self.enabled();
        out.extend((0..6).map(|k| driver_state_frame(k, on)));
        out
    }
}

impl MockPiper {
    /// Starts the mock on `bus` (needs a tokio runtime).
    pub fn spawn(cfg: MockPiperConfig, bus: Arc<dyn CanBus>) -> MockPiper {
        let period = cfg.feedback_period;
        let state = Arc::new(Mutex::new(State {
            rest: cfg.start,
            cfg,
            motion: None,
            enable_at: None,
            mode: None,
            pending: [None; 3],
            status: StatusFrame::default(),
            moves: 0,
            silent: false,
            targets: Vec::new(),
            received: Vec::new(),
        }));
        let task = {
            let state = state.clone();
            tokio::spawn(async move {
                let mut tick = tokio::time::interval(period);
                loop {
                    tokio::select! {
                        frame = bus.recv() => match frame {
                            Ok(f) => lock(&state).handle(&f),
                            Err(_) => return,
                        },
                        _ = tick.tick() => {
                            let frames = lock(&state).feedback();
                            for f in frames {
                                if bus.send(&f).await.is_err() {
                                    return;
                                }
                            }
                        }
                    }
                }
            })
        };
        MockPiper { state, task }
    }

    /// Every complete target set received, in order (resends included).
    pub fn targets(&self) -> Vec<TargetRecord> {
        lock(&self.state).targets.clone()
    }

    /// Every frame received, in order.
    pub fn received(&self) -> Vec<CanFrame> {
        lock(&self.state).received.clone()
    }

    /// Where the arm truly is, radians.
    pub fn true_joints(&self) -> [f64; 6] {
        lock(&self.state).present()
    }

    /// Stops (or resumes) all feedback, as an arm whose CAN link dropped.
    pub fn set_silent(&self, silent: bool) {
        lock(&self.state).silent = silent;
    }
}

impl Drop for MockPiper {
    fn drop(&mut self) {
        self.task.abort();
    }
}
