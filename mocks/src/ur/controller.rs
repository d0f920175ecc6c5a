//! The simulated UR controller behind the mock's three ports: the arm (linear joint-space
//! motion at the commanded speed), the robot/safety/runtime state machine the dashboard
//! drives, the RTDE registers, and an emulation of what ur_rtde's uploaded control script
//! does with them (docs/protocols.md §2.5, point 4), so `RTDEControlInterface` runs unmodified.

use std::time::Instant;

use easyhec_drivers::ur::model::{
    self, RUNTIME_PLAYING, SAFETY_BIT_PROTECTIVE_STOP, SAFETY_MODE_NORMAL,
    SAFETY_MODE_PROTECTIVE_STOP,
};

use super::wire::Value;
use super::{MockUrConfig, MockUrFault, ScriptUpload, UrMoveRecord};

/// `runtime_state` STOPPED.
pub(super) const RUNTIME_STOPPED: u32 = 1;
/// `runtime_state` PAUSED.
pub(super) const RUNTIME_PAUSED: u32 = 4;

/// ur_rtde command ids (rtde.h `RobotCommand`).
mod cmd {
    pub const NONE: i32 = 0;
    pub const MOVE_J: i32 = 1;
    pub const SPEED_J: i32 = 9;
    pub const SPEED_L: i32 = 10;
    pub const SERVO_J: i32 = 11;
    pub const FORCE_MODE: i32 = 6;
    pub const SERVO_C: i32 = 24;
    pub const STOP_L: i32 = 33;
    pub const STOP_J: i32 = 34;
    pub const WATCHDOG: i32 = 99;
    pub const STOP_SCRIPT: i32 = 255;
}

struct ActiveMove {
    index: usize,
    from: Vec<f64>,
    target: Vec<f64>,
    start_s: f64,
    duration_s: f64,
    asynchronous: bool,
}

pub(super) struct Controller {
    pub(super) cfg: MockUrConfig,
    last_wall: Instant,
    /// Simulated seconds since start (RTDE `timestamp`).
    sim_s: f64,
    q: Vec<f64>,
    motion: Option<ActiveMove>,
    pub(super) robot_mode: i32,
    pub(super) safety_mode: i32,
    pub(super) runtime: u32,
    pub(super) remote_control: bool,
    pub(super) in_int: [i32; 48],
    pub(super) in_double: [f64; 48],
    out_int: [i32; 48],
    out_double: [f64; 48],
    /// The script is inside a command (it saw a non-zero command id and has not seen 0 since).
    executing: bool,
    /// Change counter of the asynchronous-progress register (7 bits).
    async_writes: i32,
    /// Operation id of the asynchronous-progress register (7 bits).
    async_op: i32,
    pub(super) log: Vec<UrMoveRecord>,
    pub(super) script_commands: Vec<i32>,
    pub(super) uploads: Vec<ScriptUpload>,
    pub(super) dashboard: Vec<String>,
    faults: Vec<MockUrFault>,
    /// A drop a fault asked for, fired by the caller after unlocking (`Some(refuse)`).
    pub(super) drop_now: Option<bool>,
}

impl Controller {
    pub(super) fn new(cfg: MockUrConfig) -> Controller {
        let q = cfg.start.clone();
        let faults = cfg.faults.clone();
        Controller {
            remote_control: cfg.remote_control,
            cfg,
            last_wall: Instant::now(),
            sim_s: 0.0,
            q,
            motion: None,
            robot_mode: model::ROBOT_MODE_RUNNING,
            safety_mode: SAFETY_MODE_NORMAL,
            runtime: RUNTIME_STOPPED,
            in_int: [0; 48],
            in_double: [0.0; 48],
            out_int: [0; 48],
            out_double: [0.0; 48],
            executing: false,
            async_writes: 0,
            async_op: 0,
            log: Vec::new(),
            script_commands: Vec::new(),
            uploads: Vec::new(),
            dashboard: Vec::new(),
            faults,
            drop_now: None,
        }
    }

    pub(super) fn true_joints(&self) -> Vec<f64> {
        self.q.clone()
    }

    pub(super) fn moving(&self) -> bool {
        self.motion.is_some()
    }

    /// Brings the simulation up to the wall clock, then lets the script react to its inputs.
    pub(super) fn advance(&mut self) {
        let now = Instant::now();
        let dt = now.duration_since(self.last_wall).as_secs_f64() * self.cfg.speedup;
        self.last_wall = now;
        self.sim_s += dt;
        self.advance_motion();
        self.script_tick();
    }

    fn advance_motion(&mut self) {
        let Some(m) = &self.motion else { return };
        let s = if m.duration_s > 0.0 {
            ((self.sim_s - m.start_s) / m.duration_s).clamp(0.0, 1.0)
        } else {
            1.0
        };
        let index = m.index;
        // Faults on this move whose fraction has been reached fire in path order.
        let mut fired: Option<(usize, f64)> = None;
        for (k, f) in self.faults.iter().enumerate() {
            let (on_move, at) = match f {
                MockUrFault::ProtectiveStop {
                    on_move,
                    at_fraction,
                }
                | MockUrFault::DropMidMove {
                    on_move,
                    at_fraction,
                    ..
                } => (*on_move, *at_fraction),
            };
            if on_move == index && at <= s && fired.is_none_or(|(_, a)| at < a) {
                fired = Some((k, at));
            }
        }
        if let Some((k, at)) = fired {
            let fault = self.faults.remove(k);
            self.set_path_fraction(at);
            match fault {
                MockUrFault::ProtectiveStop { .. } => self.protective_stop(),
                MockUrFault::DropMidMove {
                    refuse_reconnect, ..
                } => {
                    self.drop_now = Some(refuse_reconnect);
                }
            }
            // The rest of the path (if the arm still moves) is handled on the next call.
            return;
        }
        self.set_path_fraction(s);
        if s >= 1.0 {
            self.finish_move("arrived");
        }
    }

    fn set_path_fraction(&mut self, s: f64) {
        if let Some(m) = &self.motion {
            self.q = m
                .from
                .iter()
                .zip(&m.target)
                .map(|(a, b)| if s >= 1.0 { *b } else { a + (b - a) * s })
                .collect();
        }
    }

    /// Ends the running move with `outcome`, where the arm is now.
    fn finish_move(&mut self, outcome: &str) {
        let Some(m) = self.motion.take() else { return };
        if let Some(r) = self.log.get_mut(m.index) {
            r.outcome = Some(outcome.to_string());
        }
        if m.asynchronous {
            self.signal_async_finished();
        } else if self.runtime == RUNTIME_PLAYING && self.executing {
            // The script's blocking movej returned.
            self.out_int[0] = 2;
        }
    }

    /// ur_rtde 1.6's progress register (`output_int_register_2`): bits 24–30 operation id
    /// (bumped when an operation starts), 16–23 change counter, bit 15 running, 0–14
    /// progress; a negative `value` means finished.
    fn write_async_progress(&mut self, value: i32) {
        self.async_writes = (self.async_writes + 1) % 128;
        if value == 0 {
            self.async_op = (self.async_op + 1) % 128;
        }
        let mut reg = (self.async_writes << 16) + (self.async_op << 24);
        if value >= 0 {
            reg += (value & 0x7FFF) + 0x8000;
        }
        self.out_int[2] = reg;
    }

    fn signal_async_finished(&mut self) {
        self.write_async_progress(-1);
    }

    /// Halts the arm where it is (a stop, a safety event, a lost link with halting on).
    pub(super) fn halt(&mut self, outcome: &str) {
        self.finish_move(outcome);
    }

    pub(super) fn protective_stop(&mut self) {
        self.halt("protective stop");
        self.safety_mode = SAFETY_MODE_PROTECTIVE_STOP;
        if self.runtime == RUNTIME_PLAYING {
            self.runtime = RUNTIME_PAUSED;
        }
    }

    /// The program ends (dashboard `stop`, a runtime error, STOP_SCRIPT): the arm halts.
    pub(super) fn stop_program(&mut self, outcome: &str) {
        self.halt(outcome);
        self.runtime = RUNTIME_STOPPED;
        self.executing = false;
    }

    /// A control script arrived on the script port: it replaces any running program.
    pub(super) fn start_script(&mut self, upload: ScriptUpload) {
        self.uploads.push(upload);
        if self.robot_mode != model::ROBOT_MODE_RUNNING || self.safety_mode != SAFETY_MODE_NORMAL {
            // A real controller refuses to start a program then.
            return;
        }
        self.halt("replaced by a new program");
        self.runtime = RUNTIME_PLAYING;
        self.executing = false;
        self.out_int = [0; 48];
        self.out_double = [0.0; 48];
        // The script's start-up: reset_async_progress(), then signal_ready().
        self.signal_async_finished();
        self.out_int[0] = 1;
    }

    /// One pass of the control script's main loop.
    fn script_tick(&mut self) {
        if self.runtime != RUNTIME_PLAYING {
            return;
        }
        let id = self.in_int[0];
        match id {
            cmd::SERVO_J | cmd::SPEED_J | cmd::SPEED_L | cmd::FORCE_MODE | cmd::SERVO_C => {
                if !self.executing || self.script_commands.last() != Some(&id) {
                    self.script_commands.push(id);
                }
                // Streaming commands are not modelled: the arm holds still.
                self.out_int[0] = 1;
            }
            cmd::NONE => {
                self.executing = false;
                if self.motion.as_ref().is_none_or(|m| m.asynchronous) {
                    self.out_int[0] = 1;
                }
            }
            _ if !self.executing => {
                self.executing = true;
                self.script_commands.push(id);
                self.process(id);
            }
            _ => {}
        }
    }

    fn process(&mut self, id: i32) {
        match id {
            cmd::MOVE_J => {
                let target: Vec<f64> = self.in_double[..6].to_vec();
                let speed = self.in_double[6];
                let accel = self.in_double[7];
                let asynchronous = self.in_int[1] == 1;
                // stop_async_move(): a new move replaces a running asynchronous one.
                self.halt("replaced by a new move");
                if let Err(why) = self.start_move(target, speed, accel, asynchronous) {
                    // A movej the controller cannot execute ends the program with a runtime
                    // error; the arm stays where it is.
                    let _ = why;
                    self.stop_program("refused");
                    return;
                }
                if asynchronous {
                    self.write_async_progress(0);
                    self.out_int[0] = 2;
                }
                // A synchronous move signals "done" when it ends (finish_move).
            }
            cmd::STOP_J | cmd::STOP_L => {
                self.halt("stopped");
                self.out_int[0] = 2;
            }
            cmd::STOP_SCRIPT => self.stop_program("script stopped"),
            cmd::WATCHDOG => self.out_int[0] = 2,
            _ => {
                // Not modelled: the program halts, as a real one would on an unknown command
                // in a script that does not implement it. Tests see it in script_commands().
                self.stop_program("unsupported command");
            }
        }
    }

    /// Records and starts a move, or records why it was refused.
    pub(super) fn start_move(
        &mut self,
        target: Vec<f64>,
        speed_rad_s: f64,
        accel_rad_s2: f64,
        asynchronous: bool,
    ) -> Result<(), String> {
        let index = self.log.len();
        let refusal = if !model::within_limits(&target, &self.cfg.limits) {
            Some(format!(
                "refused: target {target:?} outside the joint limits"
            ))
        } else if !(speed_rad_s.is_finite()
            && speed_rad_s > 0.0
            && speed_rad_s <= self.cfg.speed_cap_rad_s)
        {
            Some(format!(
                "refused: speed {speed_rad_s} rad/s outside (0, {}]",
                self.cfg.speed_cap_rad_s
            ))
        } else if !(accel_rad_s2.is_finite()
            && accel_rad_s2 > 0.0
            && accel_rad_s2 <= self.cfg.accel_cap_rad_s2)
        {
            Some(format!(
                "refused: acceleration {accel_rad_s2} rad/s² outside (0, {}]",
                self.cfg.accel_cap_rad_s2
            ))
        } else if self.safety_mode != SAFETY_MODE_NORMAL {
            Some(format!(
                "refused: safety mode {}",
                model::safety_mode_name(self.safety_mode)
            ))
        } else {
            None
        };
        self.log.push(UrMoveRecord {
            index,
            from: self.q.clone(),
            target: target.clone(),
            speed_rad_s,
            accel_rad_s2,
            asynchronous,
            accepted: refusal.is_none(),
            outcome: refusal.clone(),
        });
        if let Some(why) = refusal {
            return Err(why);
        }
        let distance = self
            .q
            .iter()
            .zip(&target)
            .map(|(a, b)| (a - b).abs())
            .fold(0.0, f64::max);
        self.motion = Some(ActiveMove {
            index,
            from: self.q.clone(),
            target,
            start_s: self.sim_s,
            duration_s: distance / speed_rad_s,
            asynchronous,
        });
        Ok(())
    }

    /// The value of output variable `name` now.
    pub(super) fn output(&self, name: &str) -> Value {
        if let Some(n) = name
            .strip_prefix("output_int_register_")
            .and_then(|s| s.parse::<usize>().ok())
        {
            return Value::Int(self.out_int.get(n).copied().unwrap_or(0) as i64);
        }
        if let Some(n) = name
            .strip_prefix("output_double_register_")
            .and_then(|s| s.parse::<usize>().ok())
        {
            return Value::Double(self.out_double.get(n).copied().unwrap_or(0.0));
        }
        if let Some(n) = name
            .strip_prefix("input_int_register_")
            .and_then(|s| s.parse::<usize>().ok())
        {
            return Value::Int(self.in_int.get(n).copied().unwrap_or(0) as i64);
        }
        if let Some(n) = name
            .strip_prefix("input_double_register_")
            .and_then(|s| s.parse::<usize>().ok())
        {
            return Value::Double(self.in_double.get(n).copied().unwrap_or(0.0));
        }
        match name {
            "timestamp" => Value::Double(self.sim_s),
            "actual_q" | "target_q" => Value::Doubles(self.q.clone()),
            "actual_qd" | "target_qd" => Value::Doubles(self.velocity()),
            "robot_mode" => Value::Int(self.robot_mode as i64),
            "safety_mode" => Value::Int(self.safety_mode as i64),
            "runtime_state" => Value::Int(self.runtime as i64),
            "safety_status_bits" => {
                let bits = if self.safety_mode == SAFETY_MODE_PROTECTIVE_STOP {
                    SAFETY_BIT_PROTECTIVE_STOP
                } else if self.safety_mode == SAFETY_MODE_NORMAL {
                    1
                } else {
                    0
                };
                Value::Int(bits as i64)
            }
            "robot_status_bits" => {
                let mut bits = 0;
                if self.robot_mode >= 4 {
                    bits |= 1;
                }
                if self.runtime == RUNTIME_PLAYING {
                    bits |= 2;
                }
                Value::Int(bits)
            }
            "speed_scaling" | "target_speed_fraction" => Value::Double(1.0),
            // JOINT_RUNNING_MODE on every joint.
            "joint_mode" => Value::Ints(vec![253; 6]),
            _ => Value::Int(0),
        }
    }

    fn velocity(&self) -> Vec<f64> {
        match &self.motion {
            Some(m) if m.duration_s > 0.0 => m
                .from
                .iter()
                .zip(&m.target)
                .map(|(a, b)| (b - a) / m.duration_s)
                .collect(),
            _ => vec![0.0; self.q.len()],
        }
    }

    /// Applies an input variable the client wrote.
    pub(super) fn input(&mut self, name: &str, value: &Value) {
        if let Some(n) = name
            .strip_prefix("input_int_register_")
            .and_then(|s| s.parse::<usize>().ok())
        {
            if let Some(slot) = self.in_int.get_mut(n) {
                *slot = value.as_f64() as i32;
            }
        } else if let Some(n) = name
            .strip_prefix("input_double_register_")
            .and_then(|s| s.parse::<usize>().ok())
        {
            if let Some(slot) = self.in_double.get_mut(n) {
                *slot = value.as_f64();
            }
        }
    }
}
