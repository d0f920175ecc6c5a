//! [`ServoArm`]: a chain of position-controlled servos on one bus as an [`Arm`].
//!
//! Defence in depth: targets outside each joint's limits (which never exceed the servo's
//! position-mode range) are refused before a byte is written, and speed and acceleration are
//! clamped to the configured caps. Each move is one sync write of (acceleration, profile
//! velocity, goal) per servo, the three registers being adjacent on both families; every
//! joint's velocity and acceleration are scaled by its share of the move, so all joints
//! start and end together (the straight joint-space line the safety checker validated).
//!
//! Bring-up (before the first move) never drops the arm: torque is switched off only on a
//! servo whose operating mode must change (an EEPROM write needs it), and the goal is set to
//! the present position before torque comes on. `stop` writes goal = present position and
//! leaves torque on, so the arm holds where it is instead of falling.
//!
//! Serial I/O is blocking; every bus transaction runs in `spawn_blocking` under one lock.

use std::f64::consts::PI;
use std::sync::{Arc, Mutex, MutexGuard};
use std::time::{Duration, Instant};

use async_trait::async_trait;
use serialport::SerialPort;

use super::bus::ServoBus;
use super::table::{describe_dynamixel_hardware_error, describe_feetech_conditions, Family, Field};
use super::ServoError;
use crate::{Arm, ArmStatus, DriverError, JointLimit, Motion, Result};

/// One joint: which servo drives it and how ticks map to radians.
///
/// `angle_rad = offset_rad + direction · (ticks − ticks_per_rev/2) · 2π / ticks_per_rev`,
/// i.e. `offset_rad` is the joint angle at the servo's centre tick.
#[derive(Clone, Debug)]
pub struct ServoJoint {
    /// Joint name, matching the URDF.
    pub name: String,
    /// Servo id on the bus.
    pub id: u8,
    /// Joint angle at the centre tick, radians.
    pub offset_rad: f64,
    /// +1 if ticks grow with the joint angle, −1 if the servo is mounted reversed.
    pub direction: i8,
    /// Encoder ticks per revolution (4096 on X series and STS3215).
    pub ticks_per_rev: u32,
    /// Lowest allowed angle (default: the servo's range).
    pub lower_rad: Option<f64>,
    /// Highest allowed angle (default: the servo's range).
    pub upper_rad: Option<f64>,
}

impl ServoJoint {
    /// A joint with offset 0, direction +1, 4096 ticks per revolution, the servo's range.
    pub fn new(name: impl Into<String>, id: u8) -> ServoJoint {
        ServoJoint {
            name: name.into(),
            id,
            offset_rad: 0.0,
            direction: 1,
            ticks_per_rev: 4096,
            lower_rad: None,
            upper_rad: None,
        }
    }
}

/// Bus and motion settings of a [`ServoArm`].
#[derive(Clone, Debug)]
pub struct ServoArmConfig {
    /// Servo family (framing and control table).
    pub family: Family,
    /// Serial device, e.g. `/dev/ttyUSB0`.
    pub port: String,
    /// Baud rate (Dynamixel factory default 57 600; Feetech STS 1 000 000).
    pub baud: u32,
    /// Joints in the arm's order.
    pub joints: Vec<ServoJoint>,
    /// Speed cap of the fastest joint, rad/s; faster requests are slowed to it.
    pub speed_cap_rad_s: f64,
    /// Acceleration of the fastest joint, rad/s².
    pub accel_rad_s2: f64,
    /// Limit for one servo's reply.
    pub reply_timeout: Duration,
    /// Interval of present-position polls while a move runs.
    pub poll_interval: Duration,
    /// Slack on top of 1.5x the expected motion time before a move is stopped as timed out.
    pub motion_timeout_margin: Duration,
    /// Largest joint error at which the arm counts as arrived, radians (at least one tick).
    pub arrival_tolerance_rad: f64,
}

impl ServoArmConfig {
    /// Settings with the defaults: 1 rad/s, 4 rad/s², 100 ms replies, 20 ms polls.
    pub fn new(
        family: Family,
        port: impl Into<String>,
        baud: u32,
        joints: Vec<ServoJoint>,
    ) -> Self {
        ServoArmConfig {
            family,
            port: port.into(),
            baud,
            joints,
            speed_cap_rad_s: 1.0,
            accel_rad_s2: 4.0,
            reply_timeout: Duration::from_millis(100),
            poll_interval: Duration::from_millis(20),
            motion_timeout_margin: Duration::from_secs(5),
            arrival_tolerance_rad: 0.005,
        }
    }
}

/// A validated joint.
#[derive(Clone, Debug)]
struct Mapped {
    id: u8,
    offset: f64,
    dir: f64,
    tpr: f64,
    lower: f64,
    upper: f64,
    tolerance_ticks: i64,
}

impl Mapped {
    fn rad(&self, ticks: i64) -> f64 {
        self.offset + self.dir * (ticks as f64 - self.tpr / 2.0) * 2.0 * PI / self.tpr
    }

    fn ticks(&self, rad: f64) -> i64 {
        (self.tpr / 2.0 + self.dir * (rad - self.offset) * self.tpr / (2.0 * PI)).round() as i64
    }
}

struct Link {
    bus: Option<ServoBus>,
    armed: bool,
    stopped_by_us: bool,
    /// Bumped by `stop`: a motion being watched ends when it changes.
    epoch: u64,
}

struct Inner {
    cfg: ServoArmConfig,
    joints: Vec<JointLimit>,
    map: Vec<Mapped>,
    ids: Vec<u8>,
    link: Mutex<Link>,
}

/// A serial servo arm (Dynamixel X series or Feetech STS). Cloning shares the bus.
#[derive(Clone)]
pub struct ServoArm {
    inner: Arc<Inner>,
}

impl std::fmt::Debug for ServoArm {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let c = &self.inner.cfg;
        write!(
            f,
            "ServoArm({} on {} at {} baud)",
            c.family.name(),
            c.port,
            c.baud
        )
    }
}

fn config_error(msg: String) -> DriverError {
    DriverError::Backend(Box::new(ServoError::Config(msg)))
}

impl ServoArm {
    /// A driver for the servos on `cfg.port`; the port is opened on first use.
    pub fn new(cfg: ServoArmConfig) -> Result<ServoArm> {
        ServoArm::build(cfg, None)
    }

    /// A driver on an already open port (tests: one end of a pseudo-terminal pair).
    pub fn with_port(cfg: ServoArmConfig, port: Box<dyn SerialPort>) -> Result<ServoArm> {
        let bus = ServoBus::from_port(port, cfg.family, cfg.reply_timeout);
        ServoArm::build(cfg, Some(bus))
    }

    fn build(cfg: ServoArmConfig, bus: Option<ServoBus>) -> Result<ServoArm> {
        let positive = |v: f64| v.is_finite() && v > 0.0;
        if !positive(cfg.speed_cap_rad_s) || !positive(cfg.accel_rad_s2) {
            return Err(config_error(format!(
                "speed_cap_rad_s {} and accel_rad_s2 {} must be positive numbers",
                cfg.speed_cap_rad_s, cfg.accel_rad_s2
            )));
        }
        if cfg.joints.is_empty() {
            return Err(config_error("joints: list at least one joint".into()));
        }
        let max_id = match cfg.family {
            Family::Dynamixel => 252,
            Family::Feetech => 253,
        };
        let mut map = Vec::new();
        let mut joints = Vec::new();
        for (k, j) in cfg.joints.iter().enumerate() {
            let at = format!("joints[{k}] ({})", j.name);
            if j.id > max_id {
                return Err(config_error(format!(
                    "{at}: id {} is not a {} servo id (0–{max_id})",
                    j.id,
                    cfg.family.name()
                )));
            }
            if let Some(other) = cfg.joints[..k].iter().find(|o| o.id == j.id) {
                return Err(config_error(format!(
                    "{at}: id {} is also joint {}'s: give every servo its own id",
                    j.id, other.name
                )));
            }
            if j.direction != 1 && j.direction != -1 {
                return Err(config_error(format!(
                    "{at}: direction {}: use 1 or -1",
                    j.direction
                )));
            }
            if j.ticks_per_rev < 2 || !j.offset_rad.is_finite() {
                return Err(config_error(format!(
                    "{at}: ticks_per_rev {} and offset_rad {} must be ≥ 2 and finite",
                    j.ticks_per_rev, j.offset_rad
                )));
            }
            let mut m = Mapped {
                id: j.id,
                offset: j.offset_rad,
                dir: f64::from(j.direction),
                tpr: f64::from(j.ticks_per_rev),
                lower: 0.0,
                upper: 0.0,
                tolerance_ticks: 1,
            };
            // Position mode spans ticks 0 … ticks_per_rev − 1.
            let (a, b) = (m.rad(0), m.rad(i64::from(j.ticks_per_rev) - 1));
            let (lo, hi) = (a.min(b), a.max(b));
            let lower = j.lower_rad.unwrap_or(lo);
            let upper = j.upper_rad.unwrap_or(hi);
            if !(lower.is_finite() && upper.is_finite() && lower < upper) {
                return Err(config_error(format!(
                    "{at}: limits [{lower}, {upper}] rad: lower_rad must be below upper_rad"
                )));
            }
            if lower < lo - 1e-9 || upper > hi + 1e-9 {
                return Err(config_error(format!(
                    "{at}: limits [{lower:.4}, {upper:.4}] rad leave the servo's position range \
                     [{lo:.4}, {hi:.4}] rad (offset_rad {}, direction {}): narrow them or fix offset_rad",
                    j.offset_rad, j.direction
                )));
            }
            m.lower = lower;
            m.upper = upper;
            m.tolerance_ticks =
                ((cfg.arrival_tolerance_rad * m.tpr / (2.0 * PI)).round() as i64).max(1);
            joints.push(JointLimit {
                name: j.name.clone(),
                lower,
                upper,
                max_velocity: cfg.speed_cap_rad_s,
            });
            map.push(m);
        }
        let ids = map.iter().map(|m| m.id).collect();
        Ok(ServoArm {
            inner: Arc::new(Inner {
                cfg,
                joints,
                map,
                ids,
                link: Mutex::new(Link {
                    bus,
                    armed: false,
                    stopped_by_us: false,
                    epoch: 0,
                }),
            }),
        })
    }

    /// Runs `f` on the bus in a blocking task, under the bus lock.
    async fn blocking<T: Send + 'static>(
        &self,
        f: impl FnOnce(&Inner, &mut Link) -> Result<T> + Send + 'static,
    ) -> Result<T> {
        run_blocking(self.inner.clone(), f).await
    }

    /// Pings every servo, switches them to position mode where needed and enables torque
    /// holding the present position: what the first move does implicitly.
    pub async fn bring_up(&self) -> Result<()> {
        self.blocking(|inner, link| inner.bring_up(link)).await
    }

    /// The present positions in raw ticks, in joint order.
    pub async fn read_ticks(&self) -> Result<Vec<i64>> {
        self.blocking(|inner, link| Ok(inner.present(link)?.0))
            .await
    }
}

async fn run_blocking<T: Send + 'static>(
    inner: Arc<Inner>,
    f: impl FnOnce(&Inner, &mut Link) -> Result<T> + Send + 'static,
) -> Result<T> {
    tokio::task::spawn_blocking(move || {
        let mut link = inner.lock();
        f(&inner, &mut link)
    })
    .await
    .map_err(|e| DriverError::Connection(format!("servo bus task: {e}")))?
}

impl Inner {
    fn lock(&self) -> MutexGuard<'_, Link> {
        self.link.lock().unwrap_or_else(|p| p.into_inner())
    }

    fn bus<'a>(&self, link: &'a mut Link) -> Result<&'a mut ServoBus> {
        if link.bus.is_none() {
            let c = &self.cfg;
            link.bus = Some(ServoBus::open(&c.port, c.baud, c.family, c.reply_timeout)?);
        }
        Ok(link.bus.as_mut().expect("opened above"))
    }

    fn joint_name(&self, id: u8) -> &str {
        self.map
            .iter()
            .position(|m| m.id == id)
            .map_or("?", |k| self.joints[k].name.as_str())
    }

    /// Present positions (ticks) and each servo's status error byte.
    fn present(&self, link: &mut Link) -> Result<(Vec<i64>, Vec<u8>)> {
        let fam = self.cfg.family;
        let field = fam.table().present_position;
        let replies = self
            .bus(link)?
            .sync_read(field.addr, field.len, &self.ids)?;
        Ok(replies
            .iter()
            .map(|r| (fam.decode(field, &r.data), r.error))
            .unzip())
    }

    /// The hardware conditions behind alert bits, as one sentence (None if all is well).
    fn alerts(&self, link: &mut Link, errors: &[u8]) -> Result<Option<String>> {
        let fam = self.cfg.family;
        let mut parts = Vec::new();
        for (m, &e) in self.map.iter().zip(errors) {
            if !fam.has_alert(e) {
                continue;
            }
            let text = match fam.table().hardware_error {
                Some(field) => {
                    let r = self.bus(link)?.read(m.id, field.addr, field.len)?;
                    describe_dynamixel_hardware_error(r.data[0])
                }
                None => describe_feetech_conditions(e),
            };
            parts.push(format!(
                "servo {} ({}): {text}",
                m.id,
                self.joint_name(m.id)
            ));
        }
        Ok((!parts.is_empty()).then(|| parts.join("; ")))
    }

    fn write_goal_field(&self, link: &mut Link, ticks: &[i64]) -> Result<()> {
        let fam = self.cfg.family;
        let field = fam.table().goal_position;
        let items: Vec<(u8, Vec<u8>)> = self
            .ids
            .iter()
            .zip(ticks)
            .map(|(&id, &t)| (id, fam.encode(field, t)))
            .collect();
        self.bus(link)?.sync_write(field.addr, field.len, &items)
    }

    fn bring_up(&self, link: &mut Link) -> Result<()> {
        let c = &self.cfg;
        let fam = c.family;
        let t = fam.table();
        for m in &self.map {
            match self.bus(link)?.ping(m.id) {
                Ok(_) => {}
                Err(DriverError::Timeout(_)) => {
                    return Err(DriverError::Connection(format!(
                        "{} servo {} ({}) does not answer on {} at {} baud: check its id, the baud rate and power",
                        fam.name(),
                        m.id,
                        self.joint_name(m.id),
                        c.port,
                        c.baud
                    )))
                }
                Err(e) => return Err(e),
            }
        }
        let (present, errors) = self.present(link)?;
        if let Some(text) = self.alerts(link, &errors)? {
            return Err(DriverError::Refused(format!(
                "{text}; clear the cause, then clear_fault"
            )));
        }
        for m in &self.map {
            let bus = self.bus(link)?;
            let mode = bus.read(m.id, t.operating_mode.addr, t.operating_mode.len)?;
            if mode.data[0] != t.position_mode {
                // EEPROM write: torque must be off (and Feetech's lock open) for it.
                if let Some(lock) = t.lock {
                    bus.write(m.id, lock.addr, &[0])?;
                }
                bus.write(m.id, t.torque_enable.addr, &[0])?;
                bus.write(m.id, t.operating_mode.addr, &[t.position_mode])?;
            }
        }
        self.write_goal_field(link, &present)?;
        for m in &self.map {
            let bus = self.bus(link)?;
            bus.write(m.id, t.torque_enable.addr, &[1])?;
            if let Some(lock) = t.lock {
                bus.write(m.id, lock.addr, &[1])?;
            }
        }
        link.armed = true;
        link.stopped_by_us = false;
        Ok(())
    }

    /// One move's sync-write block for a servo: acceleration, velocity, (time,) goal.
    fn motion_block(&self, accel: i64, velocity: i64, goal: i64) -> (u16, Vec<u8>) {
        let fam = self.cfg.family;
        let t = fam.table();
        let mut fields: Vec<(Field, i64)> = vec![
            (t.profile_acceleration, accel),
            (t.profile_velocity, velocity),
            (t.goal_position, goal),
        ];
        fields.extend(t.goal_time.map(|f| (f, 0)));
        let start = fields.iter().map(|(f, _)| f.addr).min().unwrap_or(0);
        let end = fields
            .iter()
            .map(|(f, _)| f.addr + f.len)
            .max()
            .unwrap_or(0);
        let mut block = vec![0u8; usize::from(end - start)];
        for (f, v) in fields {
            let at = usize::from(f.addr - start);
            block[at..at + usize::from(f.len)].copy_from_slice(&fam.encode(f, v));
        }
        (start, block)
    }

    /// Sends the move; returns (goal ticks, expected duration, epoch).
    fn start_move(
        &self,
        link: &mut Link,
        target: &[f64],
        speed: f64,
    ) -> Result<(Vec<i64>, Duration, u64)> {
        if !link.armed {
            self.bring_up(link)?;
        }
        let (present, errors) = self.present(link)?;
        if let Some(text) = self.alerts(link, &errors)? {
            return Err(DriverError::Refused(format!("{text}; call clear_fault")));
        }
        let fam = self.cfg.family;
        let from: Vec<f64> = self
            .map
            .iter()
            .zip(&present)
            .map(|(m, &t)| m.rad(t))
            .collect();
        let goals: Vec<i64> = self
            .map
            .iter()
            .zip(target)
            .map(|(m, &q)| m.ticks(q))
            .collect();
        let dist: Vec<f64> = from
            .iter()
            .zip(target)
            .map(|(a, b)| (a - b).abs())
            .collect();
        let dmax = dist.iter().cloned().fold(0.0, f64::max);
        let mut items = Vec::new();
        let mut start = 0;
        let mut fastest = speed;
        for (k, m) in self.map.iter().enumerate() {
            let share = if dmax > 0.0 { dist[k] / dmax } else { 0.0 };
            let tpr = m.tpr as u32;
            let units =
                |v: f64, unit: f64, max: u32| ((v / unit).floor() as i64).clamp(1, i64::from(max));
            let vel_unit = fam.velocity_unit_rad_s(tpr);
            let vel = units(speed * share, vel_unit, fam.max_velocity_units());
            let acc = units(
                self.cfg.accel_rad_s2 * share,
                fam.accel_unit_rad_s2(tpr),
                fam.max_accel_units(),
            );
            if dist[k] == dmax {
                fastest = vel as f64 * vel_unit;
                if fastest > speed * (1.0 + 1e-9) {
                    // The least velocity unit is faster than asked: refuse rather than
                    // move faster than the checked speed.
                    return Err(DriverError::Refused(format!(
                        "speed {speed} rad/s is below joint {}'s least velocity step ({fastest} rad/s)",
                        m.id
                    )));
                }
            }
            let (addr, block) = self.motion_block(acc, vel, goals[k]);
            start = addr;
            items.push((m.id, block));
        }
        let len = items[0].1.len() as u16;
        self.bus(link)?.sync_write(start, len, &items)?;
        link.stopped_by_us = false;
        let expected = Duration::from_secs_f64(dmax / fastest + fastest / self.cfg.accel_rad_s2);
        Ok((goals, expected, link.epoch))
    }

    fn stop(&self, link: &mut Link) -> Result<()> {
        link.epoch += 1;
        let (present, _) = self.present(link)?;
        self.write_goal_field(link, &present)?;
        link.stopped_by_us = true;
        Ok(())
    }

    /// One poll of a running move: Some(()) when arrived.
    fn poll_move(&self, link: &mut Link, goals: &[i64], epoch: u64) -> Result<Option<()>> {
        if link.epoch != epoch {
            return Err(DriverError::MotionFailed("stopped before arriving".into()));
        }
        let (present, errors) = self.present(link)?;
        if let Some(text) = self.alerts(link, &errors)? {
            // Hold the others where they are; the faulted servo has dropped torque.
            let _ = self.write_goal_field(link, &present);
            link.stopped_by_us = true;
            return Err(DriverError::MotionFailed(text));
        }
        let arrived = self
            .map
            .iter()
            .zip(present.iter().zip(goals))
            .all(|(m, (p, g))| (p - g).abs() <= m.tolerance_ticks);
        Ok(arrived.then_some(()))
    }
}

async fn wait_arrival(
    inner: Arc<Inner>,
    goals: Vec<i64>,
    expected: Duration,
    epoch: u64,
) -> Result<()> {
    let started = Instant::now();
    let deadline = started + expected.mul_f64(1.5) + inner.cfg.motion_timeout_margin;
    loop {
        let g = goals.clone();
        let done = run_blocking(inner.clone(), move |i, link| i.poll_move(link, &g, epoch)).await?;
        if done.is_some() {
            return Ok(());
        }
        if Instant::now() >= deadline {
            let _ = run_blocking(inner.clone(), |i, link| i.stop(link)).await;
            return Err(DriverError::Timeout(started.elapsed()));
        }
        tokio::time::sleep(inner.cfg.poll_interval).await;
    }
}

#[async_trait]
impl Arm for ServoArm {
    fn joints(&self) -> &[JointLimit] {
        &self.inner.joints
    }

    async fn read_joints(&self) -> Result<Vec<f64>> {
        self.blocking(|inner, link| {
            let (ticks, _) = inner.present(link)?;
            Ok(inner.map.iter().zip(ticks).map(|(m, t)| m.rad(t)).collect())
        })
        .await
    }

    async fn move_to(&self, target: &[f64], speed_rad_s: f64) -> Result<Motion> {
        let inner = &self.inner;
        if target.len() != inner.map.len() {
            return Err(DriverError::Refused(format!(
                "target has {} joints; this arm has {}",
                target.len(),
                inner.map.len()
            )));
        }
        for (j, v) in inner.joints.iter().zip(target) {
            if !v.is_finite() || *v < j.lower || *v > j.upper {
                return Err(DriverError::Refused(format!(
                    "joint {} target {v} rad outside its limits [{:.4}, {:.4}]",
                    j.name, j.lower, j.upper
                )));
            }
        }
        if !(speed_rad_s.is_finite() && speed_rad_s > 0.0) {
            return Err(DriverError::Refused(format!(
                "speed {speed_rad_s} rad/s is not a positive number"
            )));
        }
        let speed = speed_rad_s.min(inner.cfg.speed_cap_rad_s);
        let target = target.to_vec();
        let (goals, expected, epoch) = self
            .blocking(move |inner, link| inner.start_move(link, &target, speed))
            .await?;
        Ok(Motion::new(wait_arrival(
            inner.clone(),
            goals,
            expected,
            epoch,
        )))
    }

    async fn stop(&self) -> Result<()> {
        self.blocking(|inner, link| inner.stop(link)).await
    }

    async fn status(&self) -> Result<ArmStatus> {
        self.blocking(|inner, link| {
            let (_, errors) = inner.present(link)?;
            if let Some(text) = inner.alerts(link, &errors)? {
                return Ok(ArmStatus::Fault(text));
            }
            let field = inner.cfg.family.table().moving;
            let moving = inner
                .bus(link)?
                .sync_read(field.addr, field.len, &inner.ids)?;
            Ok(if moving.iter().any(|r| r.data[0] != 0) {
                ArmStatus::Moving
            } else if link.stopped_by_us {
                ArmStatus::Stopped
            } else {
                ArmStatus::Idle
            })
        })
        .await
    }

    /// Dynamixel: reboots every servo with a hardware error (the only way to clear one), then
    /// brings the arm up again. Feetech: brings it up again once the condition is gone.
    async fn clear_fault(&self) -> Result<()> {
        self.blocking(|inner, link| {
            let (_, errors) = inner.present(link)?;
            let fam = inner.cfg.family;
            if fam == Family::Dynamixel {
                for (m, &e) in inner.map.iter().zip(&errors) {
                    if fam.has_alert(e) {
                        inner.bus(link)?.reboot(m.id)?;
                        // The servo restarts; wait for it to answer again.
                        let until = Instant::now() + Duration::from_secs(3);
                        while inner.bus(link)?.ping(m.id).is_err() {
                            if Instant::now() >= until {
                                return Err(DriverError::Timeout(Duration::from_secs(3)));
                            }
                        }
                    }
                }
            }
            link.armed = false;
            inner.bring_up(link)
        })
        .await
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cfg(joints: Vec<ServoJoint>) -> ServoArmConfig {
        ServoArmConfig::new(Family::Dynamixel, "/dev/null", 57600, joints)
    }

    #[test]
    fn ticks_radians_mapping_and_limits() {
        let mut j = ServoJoint::new("elbow", 3);
        j.direction = -1;
        j.offset_rad = 0.5;
        let arm = ServoArm::new(cfg(vec![j])).unwrap();
        let m = &arm.inner.map[0];
        assert_eq!(m.ticks(0.5), 2048);
        assert_eq!(
            m.ticks(0.5 + PI / 2.0),
            1024,
            "reversed: angle up, ticks down"
        );
        assert!((m.rad(1024) - (0.5 + PI / 2.0)).abs() < 1e-12);
        // Default limits are the servo's range, mapped.
        let l = &arm.joints()[0];
        assert!((l.upper - (0.5 + PI)).abs() < 1e-12);
        assert!((l.lower - (0.5 - PI + 2.0 * PI / 4096.0)).abs() < 1e-12);
    }

    #[test]
    fn bad_configs_name_the_field() {
        let err = |joints| ServoArm::new(cfg(joints)).unwrap_err().to_string();
        let mut a = ServoJoint::new("a", 1);
        let b = ServoJoint::new("b", 1);
        assert!(err(vec![a.clone(), b]).contains("joints[1] (b): id 1 is also joint a's"));
        a.direction = 0;
        assert!(err(vec![a.clone()]).contains("joints[0] (a): direction 0: use 1 or -1"));
        a.direction = 1;
        a.upper_rad = Some(4.0);
        assert!(err(vec![a]).contains("leave the servo's position range"));
    }

    #[test]
    fn motion_block_layouts() {
        let d = ServoArm::new(cfg(vec![ServoJoint::new("a", 1)])).unwrap();
        let (addr, block) = d.inner.motion_block(10, 41, 2048);
        assert_eq!(addr, 108);
        assert_eq!(block, [10, 0, 0, 0, 41, 0, 0, 0, 0, 8, 0, 0]);
        let mut c = cfg(vec![ServoJoint::new("a", 1)]);
        c.family = Family::Feetech;
        let f = ServoArm::new(c).unwrap();
        let (addr, block) = f.inner.motion_block(26, 651, 3000);
        assert_eq!(addr, 41);
        // acc, goal (LE), time 0, speed (LE): the layout of Feetech's WritePosEx.
        assert_eq!(block, [26, 0xB8, 0x0B, 0, 0, 0x8B, 0x02]);
    }
}
