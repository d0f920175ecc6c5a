//! A simulated chain of serial servos (Dynamixel Protocol 2.0 or Feetech STS) on the far end
//! of a pseudo-terminal, for the `ServoArm` driver: the same bytes as a real bus, decoded with
//! the driver crate's codec (the codec itself rests on the documented vectors).
//!
//! Each servo keeps a byte-for-byte control table; reads are served from it (present
//! position and the moving flag computed live), writes land in it with the family's rules
//! (Dynamixel: EEPROM only with torque off, goals beyond 0…4095 refused as a data-limit
//! error). A goal moves the servo at its profile velocity (constant speed; the acceleration
//! is recorded, not simulated). Every instruction packet and every goal is recorded so tests
//! can check what went over the wire. Faults: a servo that stops answering, and hardware
//! errors (torque drops, replies carry the alert, Dynamixel's register 70 says why).

use std::io::{Read, Write};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use easyhec_drivers::dynamixel::packet::{instruction, Instruction, PacketError, BROADCAST_ID};
use easyhec_drivers::dynamixel::table::{ControlTable, Field};
use easyhec_drivers::dynamixel::Family;
use serialport::{SerialPort, TTYPort};

/// Encoder ticks per revolution of the simulated servos.
const TICKS_PER_REV: u32 = 4096;
/// Speed used when the profile velocity is 0 ("unlimited"), ticks/s.
const UNLIMITED_TICKS_S: f64 = 4096.0;

/// One simulated servo's start state.
#[derive(Clone, Debug)]
pub struct MockServo {
    /// Bus id.
    pub id: u8,
    /// Present position at start, ticks.
    pub start_ticks: i64,
    /// Operating mode at start (default: position mode).
    pub operating_mode: Option<u8>,
}

impl MockServo {
    /// A servo at `start_ticks` in position mode.
    pub fn new(id: u8, start_ticks: i64) -> MockServo {
        MockServo {
            id,
            start_ticks,
            operating_mode: None,
        }
    }
}

/// A goal position as a servo received it, with the profile then in its table.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct GoalRecord {
    /// The servo.
    pub id: u8,
    /// Goal, ticks.
    pub goal_ticks: i64,
    /// Profile velocity register, family units.
    pub velocity_units: i64,
    /// Acceleration register, family units.
    pub accel_units: i64,
    /// Whether torque was on (a goal with torque off does not move the servo).
    pub torque_on: bool,
}

/// One instruction packet as it arrived.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct PacketRecord {
    /// The bytes on the wire.
    pub raw: Vec<u8>,
    /// Decoded.
    pub packet: Instruction,
}

struct Motion {
    from: f64,
    goal: i64,
    started: Instant,
    ticks_per_s: f64,
}

struct Servo {
    id: u8,
    table: Vec<u8>,
    /// Where the servo is when not moving, ticks.
    rest: f64,
    motion: Option<Motion>,
    silent: bool,
    /// Hardware condition bits (Dynamixel register 70 / Feetech status bits).
    hardware: u8,
}

struct State {
    family: Family,
    speedup: f64,
    servos: Vec<Servo>,
    goals: Vec<GoalRecord>,
    packets: Vec<PacketRecord>,
}

/// The mock bus; dropping it stops the simulation thread.
pub struct MockServoBus {
    state: Arc<Mutex<State>>,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
    port_name: String,
}

fn lock(state: &Mutex<State>) -> MutexGuard<'_, State> {
    state.lock().unwrap_or_else(|p| p.into_inner())
}

impl Servo {
    fn t(&self, family: Family) -> &'static ControlTable {
        family.table()
    }

    fn get(&self, family: Family, field: Field) -> i64 {
        let a = usize::from(field.addr);
        family.decode(field, &self.table[a..a + usize::from(field.len)])
    }

    fn set(&mut self, family: Family, field: Field, v: i64) {
        let a = usize::from(field.addr);
        let bytes = family.encode(field, v);
        self.table[a..a + bytes.len()].copy_from_slice(&bytes);
    }

    fn present(&self, speedup: f64) -> f64 {
        match &self.motion {
            None => self.rest,
            Some(m) => {
                let travelled = m.started.elapsed().as_secs_f64() * speedup * m.ticks_per_s;
                let d = m.goal as f64 - m.from;
                if travelled >= d.abs() {
                    m.goal as f64
                } else {
                    m.from + d.signum() * travelled
                }
            }
        }
    }

    /// Freezes any motion where it is now.
    fn halt(&mut self, speedup: f64) {
        self.rest = self.present(speedup);
        self.motion = None;
    }

    /// Refreshes the live registers before a read.
    fn refresh(&mut self, family: Family, speedup: f64) {
        let t = self.t(family);
        let p = self.present(speedup);
        if let Some(m) = &self.motion {
            if p == m.goal as f64 {
                self.rest = p;
                self.motion = None;
            }
        }
        self.set(family, t.present_position, p.round() as i64);
        self.set(family, t.moving, i64::from(self.motion.is_some()));
        if let Some(f) = t.hardware_error {
            self.set(family, f, i64::from(self.hardware));
        }
    }

    fn error_byte(&self, family: Family, number: u8) -> u8 {
        match family {
            Family::Dynamixel => number | if self.hardware != 0 { 0x80 } else { 0 },
            Family::Feetech => self.hardware,
        }
    }

    /// Applies a write; returns the Dynamixel error number (0 = fine).
    fn write(
        &mut self,
        family: Family,
        speedup: f64,
        addr: u16,
        data: &[u8],
        goals: &mut Vec<GoalRecord>,
    ) -> u8 {
        let t = self.t(family);
        let end = usize::from(addr) + data.len();
        if end > self.table.len() || data.is_empty() {
            return 4;
        }
        let covers = |f: Field| addr <= f.addr && usize::from(f.addr + f.len) <= end;
        let torque_on = self.get(family, t.torque_enable) != 0;
        if family == Family::Dynamixel && addr < t.ram_start && torque_on {
            return 7;
        }
        let mut next = self.table.clone();
        next[usize::from(addr)..end].copy_from_slice(data);
        let probe = Servo {
            id: self.id,
            table: next,
            rest: 0.0,
            motion: None,
            silent: false,
            hardware: 0,
        };
        if covers(t.goal_position) {
            let goal = probe.get(family, t.goal_position);
            if family == Family::Dynamixel && !(0..i64::from(TICKS_PER_REV)).contains(&goal) {
                return 6;
            }
        }
        self.halt_if_torque_changes(family, speedup, &probe, covers(t.torque_enable));
        self.table = probe.table;
        if covers(t.goal_position) {
            let torque_on = self.get(family, t.torque_enable) != 0;
            let rec = GoalRecord {
                id: self.id,
                goal_ticks: self.get(family, t.goal_position),
                velocity_units: self.get(family, t.profile_velocity),
                accel_units: self.get(family, t.profile_acceleration),
                torque_on,
            };
            if torque_on && self.hardware == 0 {
                let from = self.present(speedup);
                let unit = family.velocity_unit_rad_s(TICKS_PER_REV) * f64::from(TICKS_PER_REV)
                    / (2.0 * std::f64::consts::PI);
                let ticks_per_s = if rec.velocity_units > 0 {
                    rec.velocity_units as f64 * unit
                } else {
                    UNLIMITED_TICKS_S
                };
                self.rest = from;
                self.motion = Some(Motion {
                    from,
                    goal: rec.goal_ticks,
                    started: Instant::now(),
                    ticks_per_s,
                });
            }
            goals.push(rec);
        }
        0
    }

    fn halt_if_torque_changes(
        &mut self,
        family: Family,
        speedup: f64,
        next: &Servo,
        touched: bool,
    ) {
        let t = self.t(family);
        if touched && next.get(family, t.torque_enable) == 0 {
            self.halt(speedup);
        }
    }
}

impl State {
    fn servo(&mut self, id: u8) -> Option<&mut Servo> {
        self.servos.iter_mut().find(|s| s.id == id && !s.silent)
    }

    /// Handles one instruction; returns the bytes to send back.
    fn handle(&mut self, ins: &Instruction) -> Vec<u8> {
        let fam = self.family;
        let proto = fam.protocol();
        let speedup = self.speedup;
        let mut out = Vec::new();
        match ins.instruction {
            instruction::PING => {
                let ids: Vec<u8> = if ins.id == BROADCAST_ID {
                    let mut v: Vec<u8> = self.servos.iter().map(|s| s.id).collect();
                    v.sort_unstable();
                    v
                } else {
                    vec![ins.id]
                };
                for id in ids {
                    if let Some(s) = self.servo(id) {
                        let params = match fam {
                            Family::Dynamixel => {
                                let mut p = s.table[..2].to_vec();
                                p.push(45);
                                p
                            }
                            Family::Feetech => vec![],
                        };
                        out.extend(proto.encode_status(id, s.error_byte(fam, 0), &params));
                    }
                }
            }
            instruction::READ => {
                let Some((addr, len)) = proto.decode_read(&ins.params) else {
                    return out;
                };
                if let Some(s) = self.servo(ins.id) {
                    out.extend(read_reply(s, fam, speedup, addr, len));
                }
            }
            instruction::WRITE => {
                let Some((addr, data)) = proto.decode_write(&ins.params) else {
                    return out;
                };
                let goals = &mut self.goals;
                if let Some(s) = self.servos.iter_mut().find(|s| s.id == ins.id && !s.silent) {
                    let e = s.write(fam, speedup, addr, &data, goals);
                    out.extend(proto.encode_status(s.id, s.error_byte(fam, e), &[]));
                }
            }
            instruction::SYNC_READ => {
                let Some((addr, len, ids)) = proto.decode_sync_read(&ins.params) else {
                    return out;
                };
                for id in ids {
                    if let Some(s) = self.servo(id) {
                        out.extend(read_reply(s, fam, speedup, addr, len));
                    }
                }
            }
            instruction::SYNC_WRITE => {
                let Some((addr, _, items)) = proto.decode_sync_write(&ins.params) else {
                    return out;
                };
                let goals = &mut self.goals;
                for (id, data) in items {
                    if let Some(s) = self.servos.iter_mut().find(|s| s.id == id && !s.silent) {
                        s.write(fam, speedup, addr, &data, goals);
                    }
                }
            }
            instruction::REBOOT if fam == Family::Dynamixel => {
                if let Some(s) = self.servo(ins.id) {
                    out.extend(proto.encode_status(s.id, s.error_byte(fam, 0), &[]));
                    s.halt(speedup);
                    s.hardware = 0;
                    let t = fam.table();
                    s.set(fam, t.torque_enable, 0);
                }
            }
            _ => {
                if let Some(s) = self.servo(ins.id) {
                    out.extend(proto.encode_status(s.id, s.error_byte(fam, 2), &[]));
                }
            }
        }
        out
    }
}

fn read_reply(s: &mut Servo, fam: Family, speedup: f64, addr: u16, len: u16) -> Vec<u8> {
    let proto = fam.protocol();
    s.refresh(fam, speedup);
    let (a, n) = (usize::from(addr), usize::from(len));
    if a + n > s.table.len() {
        return proto.encode_status(s.id, s.error_byte(fam, 4), &[]);
    }
    proto.encode_status(s.id, s.error_byte(fam, 0), &s.table[a..a + n])
}

impl MockServoBus {
    /// Starts a bus of `servos` speaking `family`; returns it and the driver's end of the
    /// pseudo-terminal. `speedup` is simulated seconds per wall second.
    pub fn spawn(
        family: Family,
        servos: &[MockServo],
        speedup: f64,
    ) -> std::io::Result<(MockServoBus, TTYPort)> {
        let (mut master, slave) = TTYPort::pair().map_err(std::io::Error::from)?;
        master
            .set_timeout(Duration::from_millis(5))
            .map_err(std::io::Error::from)?;
        let t = family.table();
        let servos = servos
            .iter()
            .map(|m| {
                let mut s = Servo {
                    id: m.id,
                    table: vec![0; usize::from(t.size)],
                    rest: m.start_ticks as f64,
                    motion: None,
                    silent: false,
                    hardware: 0,
                };
                let model = match family {
                    Family::Dynamixel => 1060,
                    Family::Feetech => 777,
                };
                s.set(family, t.model_number, model);
                s.set(
                    family,
                    t.operating_mode,
                    i64::from(m.operating_mode.unwrap_or(t.position_mode)),
                );
                s.set(family, t.goal_position, m.start_ticks);
                s.refresh(family, speedup);
                s
            })
            .collect();
        let state = Arc::new(Mutex::new(State {
            family,
            speedup,
            servos,
            goals: Vec::new(),
            packets: Vec::new(),
        }));
        let stop = Arc::new(AtomicBool::new(false));
        let port_name = slave.name().unwrap_or_default();
        let thread = {
            let (state, stop) = (state.clone(), stop.clone());
            std::thread::Builder::new()
                .name("mock-servo-bus".into())
                .spawn(move || serve(&mut master, &state, &stop))?
        };
        Ok((
            MockServoBus {
                state,
                stop,
                thread: Some(thread),
                port_name,
            },
            slave,
        ))
    }

    /// The driver end's device path (`/dev/pts/N`).
    pub fn port_name(&self) -> &str {
        &self.port_name
    }

    /// Every goal received, in order.
    pub fn goals(&self) -> Vec<GoalRecord> {
        lock(&self.state).goals.clone()
    }

    /// Every instruction packet received, in order.
    pub fn packets(&self) -> Vec<PacketRecord> {
        lock(&self.state).packets.clone()
    }

    /// Present position of servo `id`, ticks (rounded as the servo reports it).
    pub fn present_ticks(&self, id: u8) -> i64 {
        let st = lock(&self.state);
        let s = st.servos.iter().find(|s| s.id == id).expect("servo id");
        s.present(st.speedup).round() as i64
    }

    /// One byte of servo `id`'s control table.
    pub fn table_byte(&self, id: u8, addr: u16) -> u8 {
        let st = lock(&self.state);
        st.servos
            .iter()
            .find(|s| s.id == id)
            .expect("servo id")
            .table[usize::from(addr)]
    }

    /// Makes servo `id` stop (or resume) answering; a silent servo ignores writes too.
    pub fn set_silent(&self, id: u8, silent: bool) {
        let mut st = lock(&self.state);
        if let Some(s) = st.servos.iter_mut().find(|s| s.id == id) {
            s.silent = silent;
        }
    }

    /// Gives servo `id` hardware condition `bits` (Dynamixel register 70 bits, or Feetech
    /// status bits): it stops where it is and drops torque, as the real servos do.
    pub fn inject_hardware_error(&self, id: u8, bits: u8) {
        let mut st = lock(&self.state);
        let (fam, speedup) = (st.family, st.speedup);
        if let Some(s) = st.servos.iter_mut().find(|s| s.id == id) {
            s.halt(speedup);
            s.hardware = bits;
            let t = fam.table();
            s.set(fam, t.torque_enable, 0);
        }
    }
}

fn serve(master: &mut TTYPort, state: &Mutex<State>, stop: &AtomicBool) {
    let mut buf = Vec::new();
    let mut chunk = [0u8; 512];
    while !stop.load(Ordering::Relaxed) {
        match master.read(&mut chunk) {
            Ok(n) => buf.extend_from_slice(&chunk[..n]),
            Err(e) if e.kind() == std::io::ErrorKind::TimedOut => {}
            // No driver end open (EIO on a pty): wait for one.
            Err(_) => std::thread::sleep(Duration::from_millis(5)),
        }
        loop {
            let proto = lock(state).family.protocol();
            match proto.parse_instruction(&buf) {
                Ok((packet, used)) => {
                    let raw: Vec<u8> = buf.drain(..used).collect();
                    let reply = {
                        let mut st = lock(state);
                        let reply = st.handle(&packet);
                        st.packets.push(PacketRecord { raw, packet });
                        reply
                    };
                    if !reply.is_empty() {
                        let _ = master.write_all(&reply);
                    }
                }
                Err(PacketError::Skip(n)) | Err(PacketError::Invalid { skip: n, .. }) => {
                    buf.drain(..n);
                }
                Err(PacketError::Incomplete) => break,
            }
        }
    }
}

impl Drop for MockServoBus {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}
