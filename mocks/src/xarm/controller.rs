//! The mock controller's state machine: what each register does to the simulated arm and
//! what the controller answers (docs/protocols.md §1.3–1.5). No I/O here; `super` moves the bytes.

use std::time::Instant;

use easyhec_drivers::xarm::frame::{f32s_le, reg, status, MoveJoint, Version};
use easyhec_drivers::xarm::report::{NormalFields, Report};
use easyhec_drivers::xarm::Model;

use super::rich::{self, RichFields};
use super::{MockFault, MockXArmConfig, MoveRecord, RequestRecord};

/// Which report a report port streams.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum ReportKind {
    /// Port 30003, 87 bytes.
    Real,
    /// Port 30001, 145 bytes.
    Normal,
    /// Port 30002, [`rich::RICH_LEN`] bytes.
    Rich,
}

/// Motor temperature reported for every joint, °C (nothing heats up in a simulation).
const MOTOR_TEMPERATURE_C: i8 = 30;
/// Joint supply voltage reported, hundredths of a volt (the arm's 48 V bus).
const JOINT_VOLTAGE_CV: u16 = 4800;

/// What happens when a move reaches a fault's fraction.
#[derive(Clone, Debug)]
enum FaultAction {
    Error(u8),
    Stall,
    Drop { refuse_reconnect: bool },
}

#[derive(Clone, Debug)]
struct Segment {
    from: Vec<f64>,
    target: Vec<f64>,
    start_s: f64,
    duration_s: f64,
    /// Index into the move log.
    record: usize,
    /// Fraction of the path where the arm stops progressing (1 unless stalled).
    cap: f64,
    fault: Option<(f64, FaultAction)>,
}

impl Segment {
    fn fraction(&self, now_s: f64) -> f64 {
        if self.duration_s <= 0.0 {
            1.0
        } else {
            ((now_s - self.start_s) / self.duration_s).clamp(0.0, 1.0)
        }
    }

    fn at(&self, s: f64) -> Vec<f64> {
        if s >= 1.0 {
            return self.target.clone();
        }
        self.from
            .iter()
            .zip(&self.target)
            .map(|(a, b)| a + (b - a) * s)
            .collect()
    }

    /// Speed of each joint while moving, rad/s (simulated time).
    fn velocity(&self) -> Vec<f64> {
        self.from
            .iter()
            .zip(&self.target)
            .map(|(a, b)| {
                if self.duration_s > 0.0 {
                    (b - a) / self.duration_s
                } else {
                    0.0
                }
            })
            .collect()
    }
}

/// The simulated controller.
pub(super) struct Controller {
    cfg: MockXArmConfig,
    limits: Vec<(f64, f64)>,
    t0: Instant,
    q: Vec<f64>,
    seg: Option<Segment>,
    /// A paused move: its target, speed and record, resumed by SET_STATE 0.
    paused: Option<(Vec<f64>, f64, usize)>,
    enabled: bool,
    mode: u8,
    /// The state last set (2 ready, 4 stopped, 5 reset), shown when not moving or paused.
    state: u8,
    error: u8,
    warning: u8,
    moves: usize,
    pub(super) log: Vec<MoveRecord>,
    pub(super) requests: Vec<RequestRecord>,
    /// Set when a drop fault fires; taken by the server, which closes the connections.
    pub(super) drop_now: Option<bool>,
}

impl Controller {
    pub(super) fn new(cfg: MockXArmConfig) -> Controller {
        let limits = cfg.model.joint_limits();
        let q = cfg
            .start
            .clone()
            .unwrap_or_else(|| vec![0.0; cfg.model.axes()]);
        Controller {
            cfg,
            limits,
            t0: Instant::now(),
            q,
            seg: None,
            paused: None,
            enabled: false,
            mode: 0,
            state: 4,
            error: 0,
            warning: 0,
            moves: 0,
            log: Vec::new(),
            requests: Vec::new(),
            drop_now: None,
        }
    }

    fn now_s(&self) -> f64 {
        self.t0.elapsed().as_secs_f64() * self.cfg.speedup
    }

    /// Brings the simulated arm up to now: motion progress and faults that fire on the way.
    pub(super) fn advance(&mut self) {
        let now = self.now_s();
        let Some(seg) = self.seg.as_mut() else { return };
        let s = seg.fraction(now);
        if let Some((at, action)) = seg.fault.take_if(|(at, _)| s >= *at) {
            let q = seg.at(at);
            let record = seg.record;
            if matches!(action, FaultAction::Stall) {
                seg.cap = at;
            }
            self.q = q;
            match action {
                FaultAction::Error(code) => {
                    self.seg = None;
                    self.error = code;
                    self.state = 4;
                    self.finish(
                        record,
                        format!("controller error C{code} at {at:.2} of the path"),
                    );
                }
                FaultAction::Stall => {}
                FaultAction::Drop { refuse_reconnect } => {
                    self.drop_now = Some(refuse_reconnect);
                    self.finish(
                        record,
                        format!("connections dropped at {at:.2} of the path"),
                    );
                    if self.cfg.halt_on_disconnect {
                        self.halt("halted on connection loss");
                        self.state = 4;
                    }
                }
            }
            return;
        }
        let s = s.min(seg.cap);
        let q = seg.at(s);
        let record = seg.record;
        self.q = q;
        if s >= 1.0 {
            self.seg = None;
            self.finish(record, "arrived".into());
        }
    }

    fn finish(&mut self, record: usize, outcome: String) {
        if let Some(r) = self.log.get_mut(record) {
            // A drop note stays; the move's end is appended to it.
            r.outcome = Some(match r.outcome.take() {
                Some(prev) if prev.starts_with("connections dropped") => {
                    format!("{prev}; {outcome}")
                }
                _ => outcome,
            });
        }
    }

    /// Ends any motion where the arm is now (stop, enable, mode change, error clearing).
    pub(super) fn halt(&mut self, why: &str) {
        self.paused = None;
        if let Some(seg) = self.seg.take() {
            let s = seg.fraction(self.now_s()).min(seg.cap);
            self.finish(seg.record, format!("{why} at {s:.2} of the path"));
        }
    }

    /// Raises a controller error now: the arm stops where it is (state 4).
    pub(super) fn raise_error(&mut self, code: u8) {
        self.halt(&format!("halted by controller error C{code}"));
        self.error = code;
        self.state = 4;
    }

    /// A command connection closed.
    pub(super) fn client_gone(&mut self) {
        if self.cfg.halt_on_disconnect && self.seg.is_some() {
            self.halt("halted on connection loss");
            self.state = 4;
        }
    }

    pub(super) fn model(&self) -> Model {
        self.cfg.model
    }

    pub(super) fn firmware(&self) -> &str {
        &self.cfg.firmware
    }

    /// The state the controller reports (§1.4).
    pub(super) fn reported_state(&self) -> u8 {
        if self.error != 0 {
            4
        } else if self.seg.is_some() {
            1
        } else if self.paused.is_some() {
            3
        } else {
            self.state
        }
    }

    fn status_byte(&self) -> u8 {
        let st = self.reported_state();
        let mut b = 0;
        if self.error != 0 {
            b |= status::ERROR;
        }
        if self.warning != 0 {
            b |= status::WARNING;
        }
        if !self.enabled || st == 4 || st == 5 {
            b |= status::NOT_READY;
        }
        b
    }

    pub(super) fn true_joints(&self) -> Vec<f64> {
        self.q.clone()
    }

    fn joints7(&self, values: &[f64]) -> Vec<f32> {
        let mut v: Vec<f32> = values.iter().map(|&x| x as f32).collect();
        v.resize(7, 0.0);
        v
    }

    /// Joint speeds now, rad/s: the running segment's, otherwise 0. A stalled arm keeps
    /// reporting them, as it keeps reporting "moving".
    fn joint_velocity(&self) -> Vec<f64> {
        self.seg
            .as_ref()
            .map(|s| s.velocity())
            .unwrap_or_else(|| vec![0.0; self.q.len()])
    }

    /// The bytes of the report frame `kind` the controller pushes now.
    pub(super) fn report_frame(&self, kind: ReportKind) -> Vec<u8> {
        match kind {
            ReportKind::Real => self.report(false).encode(),
            ReportKind::Normal => self.report(true).encode(),
            ReportKind::Rich => rich::encode(self.report(true).encode(), &self.rich_fields()),
        }
    }

    /// The rich report's tail (§1.6.3), from the same state as the normal fields: the model's
    /// identity and joint ranges, the caps this mock enforces as the joint speed and
    /// acceleration limits, and the joints' speeds along the running move.
    fn rich_fields(&self) -> RichFields {
        let axes = self.cfg.model.axes();
        let mut temperatures = [0i8; 7];
        let mut voltages_cv = [0u16; 7];
        let mut reduced_joint_ranges = [(0f32, 0f32); 7];
        for (k, &(lo, hi)) in self.limits.iter().enumerate().take(7) {
            temperatures[k] = MOTOR_TEMPERATURE_C;
            voltages_cv[k] = JOINT_VOLTAGE_CV;
            reduced_joint_ranges[k] = (lo as f32, hi as f32);
        }
        let mut joint_speeds = [0f32; 7];
        joint_speeds.copy_from_slice(&self.joints7(&self.joint_velocity()));
        let speed_cap = self.cfg.speed_cap_rad_s as f32;
        RichFields {
            arm_type: self.cfg.model.device_type(),
            axes: axes as u8,
            version: format!("v{}", self.cfg.firmware),
            // The SDK's own defaults for the Cartesian limits: the mock has no kinematics.
            tcp_limits: [1000.0, 1.0, 50000.0, 0.1, 1000.0],
            joint_limits: [
                20.0,
                0.01,
                self.cfg.accel_cap_rad_s2 as f32,
                0.0001,
                speed_cap,
            ],
            rot_limits: [2.3, 2.7],
            temperatures,
            // The reported pose is 0 throughout, so the TCP never moves.
            tcp_speed: 0.0,
            joint_speeds,
            collision_detection: true,
            voltages_cv,
            reduced_max_speeds: [1000.0, speed_cap],
            reduced_joint_ranges,
        }
    }

    /// The report the controller pushes now (normal fields included or not).
    fn report(&self, normal: bool) -> Report {
        let mut joints = [0f32; 7];
        joints.copy_from_slice(&self.joints7(&self.q));
        let axes_mask = (1u8 << self.cfg.model.axes()) - 1;
        Report {
            state: self.reported_state(),
            mode: self.mode,
            cmd_num: u16::from(self.seg.is_some()),
            joints_rad: joints,
            tcp_pose: [0.0; 6],
            torques: [0.0; 7],
            normal: normal.then(|| NormalFields {
                brakes: if self.enabled { axes_mask } else { 0 },
                motors_enabled: if self.enabled { axes_mask } else { 0 },
                error_code: self.error,
                warning_code: self.warning,
                tcp_offset: [0.0; 6],
                payload: [0.0; 4],
                collision_sensitivity: 3,
                teach_sensitivity: 3,
                gravity: Some([0.0, 0.0, -1.0]),
            }),
        }
    }

    fn version_text(&self) -> String {
        let sn = match self.cfg.model {
            Model::Xarm6Sn1305 => "XI1305",
            Model::Lite6 => "LI1006",
            Model::Uf850 => "FX1003",
            _ => "XI1202",
        };
        format!(
            "{},{},{sn},AC1302,v{}",
            self.cfg.model.axes(),
            self.cfg.model.device_type(),
            self.cfg.firmware
        )
    }

    /// Answers one private-protocol request: `(status, data)`, or `None` to stay silent.
    pub(super) fn handle(&mut self, register: u8, params: &[u8]) -> Option<(u8, Vec<u8>)> {
        if self
            .cfg
            .faults
            .iter()
            .any(|f| matches!(f, MockFault::NoReply { register: r } if *r == register))
        {
            return None;
        }
        let data = match register {
            reg::GET_VERSION => Version::encode_text(&self.version_text()),
            reg::GET_ROBOT_SN => {
                let mut v = b"XI1202A2110E01\0AC1302A2110E01".to_vec();
                v.resize(40, 0);
                v
            }
            reg::MOTION_EN => {
                let enable = params.get(1).copied().unwrap_or(0) == 1;
                self.halt("halted by motion enable");
                self.enabled = enable;
                self.state = if enable { 5 } else { 4 };
                Vec::new()
            }
            reg::SET_STATE => {
                match params.first().copied().unwrap_or(255) {
                    0 => {
                        if let Some((target, speed, record)) = self.paused.take() {
                            self.start_segment(target, speed, record, None);
                        } else if self.enabled && self.error == 0 {
                            self.state = 2;
                        }
                    }
                    3 => {
                        if let Some(seg) = self.seg.take() {
                            let speed = seg
                                .from
                                .iter()
                                .zip(&seg.target)
                                .map(|(a, b)| (b - a).abs())
                                .fold(0.0, f64::max)
                                / seg.duration_s.max(1e-9);
                            self.paused = Some((seg.target, speed, seg.record));
                        }
                    }
                    4 | 6 => {
                        self.halt("stopped by SET_STATE");
                        self.state = 4;
                    }
                    _ => self.warning = 12,
                }
                Vec::new()
            }
            reg::GET_STATE => vec![self.reported_state()],
            reg::GET_CMDNUM => u16::from(self.seg.is_some()).to_be_bytes().to_vec(),
            reg::GET_ERROR => vec![self.error, self.warning],
            reg::CLEAN_ERR => {
                if self.error != 0 {
                    self.halt("halted by error clearing");
                    self.error = 0;
                    self.state = 5;
                }
                Vec::new()
            }
            reg::CLEAN_WAR => {
                self.warning = 0;
                Vec::new()
            }
            reg::SET_MODE => {
                let mode = params.first().copied().unwrap_or(0);
                if mode != self.mode {
                    self.halt("halted by a mode change");
                    self.mode = mode;
                    self.state = 5;
                }
                Vec::new()
            }
            reg::MOVE_JOINT | reg::MOVE_JOINTB => self.move_joint(register, params),
            reg::GET_JOINT_POS => {
                let kinds = params.first().copied().unwrap_or(1).clamp(1, 3);
                let mut out = f32s_le(&self.joints7(&self.q));
                if kinds >= 2 {
                    out.extend(f32s_le(&self.joints7(&self.joint_velocity())));
                }
                if kinds >= 3 {
                    out.extend(f32s_le(&[0.0; 7]));
                }
                out
            }
            reg::GET_TCP_POSE => f32s_le(&[0.0; 6]),
            // Accepted and ignored: no effect on a simulated arm.
            reg::SYSTEM_CONTROL | reg::SET_BRAKE | reg::SET_FEEDBACK_TYPE | reg::FEEDBACK_CHECK => {
                Vec::new()
            }
            _ => {
                self.warning = 13;
                Vec::new()
            }
        };
        Some((self.status_byte(), data))
    }

    fn start_segment(
        &mut self,
        target: Vec<f64>,
        speed: f64,
        record: usize,
        fault: Option<(f64, FaultAction)>,
    ) {
        let distance = self
            .q
            .iter()
            .zip(&target)
            .map(|(a, b)| (b - a).abs())
            .fold(0.0, f64::max);
        self.seg = Some(Segment {
            from: self.q.clone(),
            target,
            start_s: self.now_s(),
            duration_s: distance / speed,
            record,
            cap: 1.0,
            fault,
        });
        self.state = 2;
        self.advance();
    }

    fn move_joint(&mut self, register: u8, params: &[u8]) -> Vec<u8> {
        let index = self.moves;
        self.moves += 1;
        let n = self.cfg.model.axes();
        let Some(mv) = MoveJoint::decode(params) else {
            self.warning = 12;
            self.log.push(MoveRecord {
                index,
                register,
                from: self.q.clone(),
                target: Vec::new(),
                unused_slots: Vec::new(),
                speed_rad_s: f64::NAN,
                accel_rad_s2: f64::NAN,
                accepted: false,
                outcome: Some(format!(
                    "refused: {} parameter bytes, 40 expected",
                    params.len()
                )),
            });
            return vec![0, 0];
        };
        let target: Vec<f64> = mv.joints_rad[..n].iter().map(|&v| f64::from(v)).collect();
        let speed = f64::from(mv.speed_rad_s);
        let accel = f64::from(mv.accel_rad_s2);
        self.log.push(MoveRecord {
            index,
            register,
            from: self.q.clone(),
            target: target.clone(),
            unused_slots: mv.joints_rad[n..].to_vec(),
            speed_rad_s: speed,
            accel_rad_s2: accel,
            accepted: false,
            outcome: None,
        });
        let record = self.log.len() - 1;
        let state = self.reported_state();
        let refusal = if !self.enabled
            || self.error != 0
            || state == 4
            || state == 5
            || self.mode != 0
        {
            Some(format!(
                "not ready: enabled {}, state {state}, mode {}, error C{}",
                self.enabled, self.mode, self.error
            ))
        } else if mv.joints_rad[n..].iter().any(|v| *v != 0.0) {
            self.warning = 12;
            Some("unused joint slots are not 0 (warning W12)".into())
        } else if let Some((k, v)) = target
            .iter()
            .enumerate()
            .find(|(k, v)| !v.is_finite() || **v < self.limits[*k].0 || **v > self.limits[*k].1)
        {
            self.halt("halted by a limit error");
            self.error = 23;
            self.state = 4;
            Some(format!(
                "joint {} target {v} outside [{}, {}] (error C23)",
                k + 1,
                self.limits[k].0,
                self.limits[k].1
            ))
        } else if !within_cap(speed, self.cfg.speed_cap_rad_s)
            || !within_cap(accel, self.cfg.accel_cap_rad_s2)
        {
            self.halt("halted by a speed error");
            self.error = 24;
            self.state = 4;
            Some(format!(
                "speed {speed} rad/s or acceleration {accel} rad/s² above the caps {} / {} (error C24)",
                self.cfg.speed_cap_rad_s, self.cfg.accel_cap_rad_s2
            ))
        } else {
            None
        };
        if let Some(why) = refusal {
            self.log[record].outcome = Some(format!("refused: {why}"));
            return vec![0, 0];
        }
        self.log[record].accepted = true;
        let fault = self.cfg.faults.iter().find_map(|f| match *f {
            MockFault::ErrorMidMove {
                on_move,
                at_fraction,
                code,
            } if on_move == index => Some((at_fraction, FaultAction::Error(code))),
            MockFault::Stall {
                on_move,
                at_fraction,
            } if on_move == index => Some((at_fraction, FaultAction::Stall)),
            MockFault::DropMidMove {
                on_move,
                at_fraction,
                refuse_reconnect,
            } if on_move == index => Some((at_fraction, FaultAction::Drop { refuse_reconnect })),
            _ => None,
        });
        // A new move replaces a running one (no command queue in this mock).
        self.halt("replaced by a new move");
        self.start_segment(target, speed, record, fault);
        vec![0, 1]
    }
}

/// A commanded magnitude is positive and at most `cap` (allowing f32 rounding on the wire).
fn within_cap(value: f64, cap: f64) -> bool {
    value.is_finite() && value > 0.0 && value <= cap * (1.0 + 1e-6)
}
