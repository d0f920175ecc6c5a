//! Property checks behind the cargo-fuzz targets, one function per target.
//!
//! Each check feeds arbitrary bytes to a parser the way its caller does (the xArm client's
//! reply loop, the report reader, the mock UR controller's RTDE session, the servo bus and
//! mock bus loops, the Piper feedback decoder) and asserts what must hold whenever a parse
//! succeeds: re-encoding gives back the consumed bytes, length fields and checksums agree,
//! decoders are inverses of their encoders, and a stream parser fed the same bytes split at
//! other points (whole, byte by byte, pseudo-random chunks) finds the same frames at the same
//! offsets. A violated property panics, which libFuzzer reports as a crash.
//!
//! This file is also compiled into `mocks/tests/fuzz_seeds.rs` (`#[path]` module), which
//! replays `fuzz/seeds/` and `fuzz/regressions/` through the same checks on stable Rust.

use std::future::Future;
use std::io;
use std::pin::Pin;
use std::task::{Context, Poll, Waker};

use easyhec_drivers::dynamixel::packet::{self, PacketError, Protocol};
use easyhec_drivers::piper::frame::{self as piper, CanFrame, ModeCommand, StatusFrame};
use easyhec_drivers::xarm::frame::{
    self as xframe, FrameError, MoveJoint, RawFrame, Reply, Version, HEADER_LEN, MAX_BODY_LEN,
};
use easyhec_drivers::xarm::report::{
    self, announced_len, Report, MAX_REPORT_LEN, NORMAL_LEN, NORMAL_OLD_LEN, REAL_LEN,
};
use easyhec_mocks::ur::wire::{self, FieldType, Package, Value};
use tokio::io::{AsyncRead, ReadBuf};

/// The fuzz targets, by name (also the folder names under `fuzz/seeds/`).
pub const TARGETS: [&str; 6] = [
    "xarm_reply",
    "xarm_report",
    "rtde",
    "dynamixel",
    "feetech",
    "piper",
];

/// Runs the check of `target` on `data`.
///
/// # Panics
/// When a property fails, or for an unknown target name.
pub fn check(target: &str, data: &[u8]) {
    match target {
        "xarm_reply" => xarm_reply(data),
        "xarm_report" => xarm_report(data),
        "rtde" => rtde(data),
        "dynamixel" => dynamixel(data),
        "feetech" => feetech(data),
        "piper" => piper(data),
        other => panic!("no fuzz target {other:?}"),
    }
}

// ---------------------------------------------------------------------------------------
// Splitting a byte stream into reads.

/// How a byte stream is cut into the pieces a reader receives.
#[derive(Clone, Copy, Debug)]
pub enum Plan {
    /// Everything in one read.
    Whole,
    /// One byte per read.
    Bytes,
    /// Reads of 1–48 bytes from an xorshift generator with this seed.
    Random(u64),
}

/// The plans every stream check compares with [`Plan::Whole`]: two pseudo-random cuttings
/// seeded by the data, and byte by byte for inputs up to 1 KiB.
pub fn plans(data: &[u8]) -> Vec<Plan> {
    // FNV-1a: the cut points follow the data, so the fuzzer explores them too.
    let hash = data.iter().fold(0xcbf2_9ce4_8422_2325u64, |h, &b| {
        (h ^ u64::from(b)).wrapping_mul(0x0000_0100_0000_01b3)
    });
    let mut v = vec![
        Plan::Random(hash),
        Plan::Random(hash ^ 0x9e37_79b9_7f4a_7c15),
    ];
    if data.len() <= 1024 {
        v.push(Plan::Bytes);
    }
    v
}

/// Hands out read sizes following a [`Plan`].
struct Cutter {
    plan: Plan,
    state: u64,
}

impl Cutter {
    fn new(plan: Plan) -> Cutter {
        let state = match plan {
            Plan::Random(seed) => seed | 1,
            _ => 1,
        };
        Cutter { plan, state }
    }

    fn next_len(&mut self) -> usize {
        match self.plan {
            Plan::Whole => usize::MAX,
            Plan::Bytes => 1,
            Plan::Random(_) => {
                self.state ^= self.state << 13;
                self.state ^= self.state >> 7;
                self.state ^= self.state << 17;
                1 + (self.state % 48) as usize
            }
        }
    }
}

/// The pieces of `data` under `plan`.
fn pieces(data: &[u8], plan: Plan) -> Vec<&[u8]> {
    let mut cut = Cutter::new(plan);
    let mut out = Vec::new();
    let mut rest = data;
    while !rest.is_empty() {
        let n = cut.next_len().min(rest.len());
        out.push(&rest[..n]);
        rest = &rest[n..];
    }
    out
}

/// An [`AsyncRead`] over a byte slice that is never pending and returns at most one piece of
/// its [`Plan`] per read.
pub struct Chunked<'a> {
    data: &'a [u8],
    at: usize,
    cut: Cutter,
}

impl<'a> Chunked<'a> {
    /// A reader of `data` cut by `plan`.
    pub fn new(data: &'a [u8], plan: Plan) -> Chunked<'a> {
        Chunked {
            data,
            at: 0,
            cut: Cutter::new(plan),
        }
    }

    /// Bytes handed out so far.
    pub fn position(&self) -> usize {
        self.at
    }
}

impl AsyncRead for Chunked<'_> {
    fn poll_read(
        mut self: Pin<&mut Self>,
        _cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        let this = &mut *self;
        let n = this
            .cut
            .next_len()
            .min(this.data.len() - this.at)
            .min(buf.remaining());
        buf.put_slice(&this.data[this.at..this.at + n]);
        this.at += n;
        Poll::Ready(Ok(()))
    }
}

/// Polls `f` once; a reader that is never pending must let it finish.
fn ready<F: Future>(f: F) -> F::Output {
    let mut f = std::pin::pin!(f);
    match f.as_mut().poll(&mut Context::from_waker(Waker::noop())) {
        Poll::Ready(v) => v,
        Poll::Pending => panic!("parser waits although its reader is never pending"),
    }
}

// ---------------------------------------------------------------------------------------
// xArm command port (client reading replies, mock reading requests).

/// What a command-port reader makes of a stream: frames with their offsets, the offset where
/// the stream went out of step (if it did) and the bytes left waiting (0 after that).
type XArmStream = (Vec<(usize, RawFrame)>, Option<usize>, usize);

fn xarm_stream(data: &[u8], plan: Plan) -> XArmStream {
    let mut frames = Vec::new();
    let mut buf: Vec<u8> = Vec::new();
    let mut base = 0;
    for piece in pieces(data, plan) {
        buf.extend_from_slice(piece);
        loop {
            match RawFrame::parse(&buf) {
                Ok((frame, used)) => {
                    assert!(used <= buf.len(), "used {used} of {}", buf.len());
                    frames.push((base, frame));
                    buf.drain(..used);
                    base += used;
                }
                Err(FrameError::Incomplete) => break,
                // Client and mock both give up on a stream out of step (what they had
                // buffered past that point depends on the cuts, so it is not compared).
                Err(FrameError::Invalid(_)) => return (frames, Some(base), 0),
            }
        }
    }
    let left = buf.len();
    (frames, None, left)
}

/// One command-port frame `raw` (exactly the bytes `RawFrame::parse` consumed).
fn xarm_frame(raw: &[u8], frame: &RawFrame) {
    let len = usize::from(u16::from_be_bytes([raw[4], raw[5]]));
    assert!((1..=MAX_BODY_LEN).contains(&len), "length field {len}");
    assert_eq!(
        raw.len(),
        HEADER_LEN + len,
        "frame size = header + length field"
    );
    assert_eq!(RawFrame::check(raw), Ok(raw.len()));
    for cut in 0..raw.len() {
        assert_eq!(
            RawFrame::check(&raw[..cut]),
            Err(FrameError::Incomplete),
            "a proper prefix ({cut} of {} bytes) is incomplete",
            raw.len()
        );
    }
    assert_eq!(frame.encode(), raw, "frame re-encodes byte for byte");
    assert_eq!(frame.register(), raw[HEADER_LEN]);

    // As a reply (the client's view).
    match Reply::from_frame(frame.clone()) {
        Ok(reply) => {
            assert!(frame.body.len() >= 2);
            assert_eq!(reply.encode(), raw, "reply re-encodes byte for byte");
            assert_eq!((reply.register, reply.status), (raw[6], raw[7]));
            assert_eq!(reply.data, &raw[8..]);
            assert_eq!(reply.has_error(), reply.status & 0x40 != 0);
            assert_eq!(reply.has_warning(), reply.status & 0x20 != 0);
            assert_eq!(reply.not_ready(), reply.status & 0x10 != 0);
            f32s(&reply.data);
            version(&reply.data);
        }
        Err(_) => assert!(
            frame.body.len() < 2,
            "a reply with a status byte is refused"
        ),
    }

    // As a request (the mock's view): register, then parameters.
    let params = &frame.body[1..];
    f32s(params);
    if matches!(
        frame.register(),
        xframe::reg::MOVE_JOINT | xframe::reg::MOVE_JOINTB
    ) {
        match MoveJoint::decode(params) {
            Some(mv) => {
                assert_eq!(params.len(), 40);
                assert_eq!(mv.encode(), params, "MOVE_JOINT parameters re-encode");
            }
            None => assert_ne!(params.len(), 40, "40 parameter bytes always decode"),
        }
    }
}

/// `read_f32s_le` reads whole f32s and re-encodes to the same bytes.
fn f32s(bytes: &[u8]) {
    let n = bytes.len() / 4;
    let v = xframe::read_f32s_le(bytes, n).expect("n whole f32s are there");
    assert_eq!(v.len(), n);
    assert_eq!(xframe::f32s_le(&v), &bytes[..4 * n], "f32 bits survive");
    assert!(xframe::read_f32s_le(bytes, n + 1).is_none());
}

/// A parsed version string survives the controller's 40-byte encoding.
fn version(data: &[u8]) {
    let Some(v) = Version::parse(data) else {
        return;
    };
    assert!(!v.text.contains('\0'));
    assert_eq!(v.text, v.text.trim());
    if v.text.len() <= 40 {
        assert_eq!(
            Version::parse(&Version::encode_text(&v.text)),
            Some(v),
            "version re-parses from its encoding"
        );
    }
}

/// Target `xarm_reply`: the command-port framing as the client's reply loop and the mock's
/// request loop read it.
pub fn xarm_reply(data: &[u8]) {
    let whole = xarm_stream(data, Plan::Whole);
    let (frames, invalid, left) = &whole;
    for (at, frame) in frames {
        let len = HEADER_LEN + frame.body.len();
        xarm_frame(&data[*at..at + len], frame);
    }
    let end = frames
        .last()
        .map_or(0, |(at, f)| at + HEADER_LEN + f.body.len());
    match invalid {
        Some(at) => {
            assert_eq!(*at, end);
            let len = data
                .get(at + 4..at + 6)
                .map(|b| usize::from(u16::from_be_bytes([b[0], b[1]])))
                .expect("an invalid frame has its length field");
            assert!(len == 0 || len > MAX_BODY_LEN, "refused length {len}");
        }
        None => assert_eq!(end + left, data.len(), "every byte is a frame or waits"),
    }
    if invalid.is_some() {
        assert_eq!(*left, 0);
    }
    for plan in plans(data) {
        assert_eq!(xarm_stream(data, plan), whole, "same frames under {plan:?}");
    }
}

// ---------------------------------------------------------------------------------------
// xArm report ports.

/// One report frame: parse, then what must hold of the result (or of a refusal).
fn xarm_report_frame(frame: &[u8]) {
    let parsed = Report::parse(frame);
    let Ok(r) = parsed else {
        // Refusals must have one of the documented reasons.
        let announced = frame
            .get(..4)
            .map(|h| announced_len([h[0], h[1], h[2], h[3]]));
        let reason = frame.len() < REAL_LEN
            || announced != Some(frame.len())
            || frame[4] >> 4 > 11
            || frame[4] & 0x0F > 9
            || (frame.len() >= NORMAL_OLD_LEN && (frame[131] > 5 || frame[132] > 5));
        assert!(reason, "report refused without a reason: {parsed:?}");
        return;
    };
    assert!(frame.len() >= REAL_LEN);
    assert_eq!(
        announced_len([frame[0], frame[1], frame[2], frame[3]]),
        frame.len()
    );
    assert!(r.state <= 9 && r.mode <= 11);
    assert_eq!(frame[4], (r.mode << 4) | r.state);
    assert_eq!(r.cmd_num, u16::from_be_bytes([frame[5], frame[6]]));
    assert_eq!(r.normal.is_some(), frame.len() >= NORMAL_OLD_LEN);
    let e = r.encode();
    let want_len = if r.normal.is_some() {
        NORMAL_LEN
    } else {
        REAL_LEN
    };
    assert_eq!(e.len(), want_len);
    assert_eq!(e[..4], (want_len as u32).to_be_bytes());
    assert_eq!(e[4..REAL_LEN], frame[4..REAL_LEN], "real fields re-encode");
    if let Some(n) = &r.normal {
        assert!(n.collision_sensitivity <= 5 && n.teach_sensitivity <= 5);
        assert_eq!(n.gravity.is_some(), frame.len() >= NORMAL_LEN);
        assert_eq!(e[REAL_LEN..NORMAL_OLD_LEN], frame[REAL_LEN..NORMAL_OLD_LEN]);
        if frame.len() >= NORMAL_LEN {
            assert_eq!(e[NORMAL_OLD_LEN..], frame[NORMAL_OLD_LEN..NORMAL_LEN]);
        } else {
            assert!(e[NORMAL_OLD_LEN..].iter().all(|&b| b == 0));
        }
    }
    if frame.len() == e.len() && frame[..4] == e[..4] {
        assert_eq!(e, frame, "a canonical frame re-encodes byte for byte");
    }
    let again = Report::parse(&e).expect("an encoded report parses");
    assert_eq!(
        again.encode(),
        e,
        "parse ∘ encode is the identity on encodings"
    );
}

/// What the report reader makes of a stream: (offset, re-encoded report) per frame, then the
/// error that ended it.
type ReportStream = (Vec<(usize, Vec<u8>)>, String);

fn report_stream(data: &[u8], plan: Plan) -> ReportStream {
    let mut r = Chunked::new(data, plan);
    let mut out = Vec::new();
    loop {
        let at = r.position();
        match ready(report::read_report(&mut r)) {
            Ok(rep) => out.push((at, rep.encode())),
            Err(e) => return (out, e.to_string()),
        }
    }
}

/// The frames a report reader should find, computed by hand from the length headers.
fn report_frames_by_hand(data: &[u8]) -> Vec<(usize, Vec<u8>)> {
    let mut out = Vec::new();
    let mut at = 0;
    while let Some(h) = data.get(at..at + 4) {
        let len = announced_len([h[0], h[1], h[2], h[3]]);
        if !(REAL_LEN..=MAX_REPORT_LEN).contains(&len) {
            break;
        }
        let Some(frame) = data.get(at..at + len) else {
            break;
        };
        match Report::parse(frame) {
            Ok(r) => out.push((at, r.encode())),
            Err(_) => break,
        }
        at += len;
    }
    out
}

/// Target `xarm_report`: `Report::parse` on the whole input as one frame, and
/// `read_report` on it as a stream, compared with a reading by hand and under other cuts.
pub fn xarm_report(data: &[u8]) {
    xarm_report_frame(data);
    let whole = report_stream(data, Plan::Whole);
    assert_eq!(
        whole.0,
        report_frames_by_hand(data),
        "stream = frames by hand"
    );
    for (at, _) in &whole.0 {
        let h = &data[*at..at + 4];
        let len = announced_len([h[0], h[1], h[2], h[3]]);
        xarm_report_frame(&data[*at..at + len]);
    }
    for plan in plans(data) {
        assert_eq!(
            report_stream(data, plan),
            whole,
            "same reports under {plan:?}"
        );
    }
}

// ---------------------------------------------------------------------------------------
// RTDE (mock controller's server side and the small client).

const FIELD_TYPES: [FieldType; 10] = [
    FieldType::Bool,
    FieldType::Uint8,
    FieldType::Uint32,
    FieldType::Uint64,
    FieldType::Int32,
    FieldType::Double,
    FieldType::Vector3d,
    FieldType::Vector6d,
    FieldType::Vector6Int32,
    FieldType::Vector6Uint32,
];

/// What the package reader makes of a stream: (offset, package) per package, then how it
/// ended (`None`: clean end of stream).
type RtdeStream = (Vec<(usize, Package)>, Option<String>);

fn rtde_stream(data: &[u8], plan: Plan) -> RtdeStream {
    let mut r = Chunked::new(data, plan);
    let mut out = Vec::new();
    loop {
        let at = r.position();
        match ready(wire::read_package(&mut r)) {
            Ok(Some(p)) => out.push((at, p)),
            Ok(None) => return (out, None),
            Err(e) => return (out, Some(format!("{:?}: {e}", e.kind()))),
        }
    }
}

/// Decoding `types` from `bytes` succeeds exactly when the sizes add up, and the values
/// encode back to the same bytes.
fn rtde_values(types: &[FieldType], bytes: &[u8]) {
    let total: usize = types.iter().map(|t| t.size()).sum();
    let Some(values) = wire::decode_values(types, bytes) else {
        assert_ne!(total, bytes.len(), "fields of the right size decode");
        return;
    };
    assert_eq!(total, bytes.len());
    assert_eq!(values.len(), types.len());
    let mut again = Vec::with_capacity(bytes.len());
    for (t, v) in types.iter().zip(&values) {
        let _ = v.as_f64();
        encode_checked(&mut again, *t, v);
    }
    assert_eq!(again, bytes, "decoded fields re-encode byte for byte");
}

fn encode_checked(out: &mut Vec<u8>, t: FieldType, v: &Value) {
    let before = out.len();
    wire::encode_value(out, t, v);
    assert_eq!(
        out.len() - before,
        t.size(),
        "{} is {} bytes",
        t.name(),
        t.size()
    );
}

/// A name list splits into trimmed, non-empty names without commas, and re-joining it splits
/// the same way.
fn rtde_names(bytes: &[u8]) -> Vec<String> {
    let names = wire::split_names(bytes);
    for n in &names {
        assert!(!n.is_empty() && !n.contains(',') && n.trim() == n, "{n:?}");
    }
    assert_eq!(wire::split_names(names.join(",").as_bytes()), names);
    names
}

/// A type looked up by name agrees with itself: size and name fit the table.
fn rtde_type(t: Option<FieldType>) -> Option<FieldType> {
    if let Some(t) = t {
        let i = FIELD_TYPES
            .iter()
            .position(|x| *x == t)
            .expect("known type");
        assert_eq!(FIELD_TYPES[i].name(), t.name());
        assert!([1, 4, 8, 24, 48].contains(&t.size()));
    }
    t
}

/// Target `rtde`: `read_package` over the stream as the mock's session reads a client (and
/// the client reads the mock), then each package handled the way the session handles it.
pub fn rtde(data: &[u8]) {
    let whole = rtde_stream(data, Plan::Whole);
    let mut end = 0;
    for (at, p) in &whole.0 {
        assert_eq!(*at, end, "packages are back to back");
        let raw = p.encode();
        assert!((3..=wire::MAX_PACKAGE).contains(&raw.len()));
        assert_eq!(
            &data[*at..at + raw.len()],
            raw,
            "package re-encodes byte for byte"
        );
        end += raw.len();
    }
    match &whole.1 {
        None => assert_eq!(end, data.len(), "a clean end leaves no bytes"),
        Some(_) => assert!(
            end < data.len(),
            "an error needs bytes after the last package"
        ),
    }
    for plan in plans(data) {
        assert_eq!(
            rtde_stream(data, plan),
            whole,
            "same packages under {plan:?}"
        );
    }

    // The session model: protocol version, recipes, data packages.
    let mut protocol = 1u16;
    let mut inputs: Vec<Vec<FieldType>> = Vec::new();
    let mut output: Option<Vec<FieldType>> = None;
    for (_, p) in &whole.0 {
        match p.kind {
            wire::kind::PROTOCOL_VERSION => {
                if let Some(b) = p.payload.get(..2) {
                    let v = u16::from_be_bytes([b[0], b[1]]);
                    if matches!(v, 1 | 2) {
                        protocol = v;
                    }
                }
            }
            wire::kind::SETUP_OUTPUTS => {
                let names = if protocol >= 2 && p.payload.len() >= 8 {
                    let f = f64::from_be_bytes(p.payload[..8].try_into().expect("8 bytes"));
                    assert_eq!(f.to_be_bytes(), p.payload[..8]);
                    rtde_names(&p.payload[8..])
                } else {
                    rtde_names(&p.payload)
                };
                let types: Option<Vec<FieldType>> = names
                    .iter()
                    .map(|n| rtde_type(wire::output_type(n)))
                    .collect();
                if let Some(types) = types.filter(|t| !t.is_empty()) {
                    output = Some(types);
                }
            }
            wire::kind::SETUP_INPUTS => {
                let names = rtde_names(&p.payload);
                let types: Option<Vec<FieldType>> = names
                    .iter()
                    .map(|n| rtde_type(wire::input_type(n)))
                    .collect();
                if let Some(types) = types.filter(|t| !t.is_empty()) {
                    inputs.push(types);
                }
            }
            wire::kind::DATA => {
                let Some((&id, fields)) = p.payload.split_first() else {
                    continue;
                };
                // The session's input recipes, then the client's output recipe.
                if let Some(types) = inputs.get(usize::from(id).wrapping_sub(1)) {
                    rtde_values(types, fields);
                }
                if let Some(types) = &output {
                    rtde_values(types, fields);
                }
                // The client's `actual_q` recipe.
                rtde_values(&[FieldType::Vector6d], fields);
                // Every type, as many times as the fields hold it.
                for t in FIELD_TYPES {
                    if fields.len() % t.size() == 0 && fields.len() / t.size() <= 64 {
                        rtde_values(&vec![t; fields.len() / t.size()], fields);
                    }
                }
            }
            _ => {}
        }
    }
}

// ---------------------------------------------------------------------------------------
// Dynamixel 2.0 and Feetech serial packets.

/// Removes Dynamixel byte stuffing, written from the protocol text independently of the
/// driver: wherever the raw bytes read `FF FF FD FD`, the last `FD` goes.
fn reference_unstuff(raw: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(raw.len());
    let mut i = 0;
    while i < raw.len() {
        if raw[i..].starts_with(&[0xFF, 0xFF, 0xFD, 0xFD]) {
            out.extend_from_slice(&[0xFF, 0xFF, 0xFD]);
            i += 4;
        } else {
            out.push(raw[i]);
            i += 1;
        }
    }
    out
}

/// Adds Dynamixel byte stuffing: an `FD` after every `FF FF FD` of the unstuffed bytes.
fn reference_stuff(body: &[u8]) -> Vec<u8> {
    let mut out = Vec::with_capacity(body.len() + 4);
    for (i, &b) in body.iter().enumerate() {
        out.push(b);
        if i >= 2 && body[i - 2..=i] == [0xFF, 0xFF, 0xFD] {
            out.push(0xFD);
        }
    }
    out
}

/// A packet event of a serial stream reader.
#[derive(Clone, Debug, PartialEq, Eq)]
enum PacketEvent {
    /// A packet of `len` bytes at `at`.
    Packet { at: usize, len: usize },
    /// A corrupt packet at `at`; `skip` bytes dropped.
    Invalid { at: usize, skip: usize },
}

/// What a bus reader (status packets) or the mock bus (instruction packets) makes of a stream.
fn packet_stream(p: Protocol, data: &[u8], plan: Plan, status: bool) -> (Vec<PacketEvent>, usize) {
    let mut events = Vec::new();
    let mut buf: Vec<u8> = Vec::new();
    let mut base = 0;
    for piece in pieces(data, plan) {
        buf.extend_from_slice(piece);
        loop {
            let r = if status {
                p.parse_status(&buf).map(|(_, n)| n)
            } else {
                p.parse_instruction(&buf).map(|(_, n)| n)
            };
            let drop = match r {
                Ok(used) => {
                    events.push(PacketEvent::Packet {
                        at: base,
                        len: used,
                    });
                    used
                }
                Err(PacketError::Skip(n)) => {
                    skipped_noise(p, &buf, n, status);
                    n
                }
                Err(PacketError::Invalid { skip, .. }) => {
                    events.push(PacketEvent::Invalid { at: base, skip });
                    skip
                }
                Err(PacketError::Incomplete) => break,
            };
            assert!(
                (1..=buf.len()).contains(&drop),
                "drop {drop} of {}",
                buf.len()
            );
            buf.drain(..drop);
            base += drop;
        }
    }
    let left = buf.len();
    (events, left)
}

/// What `Skip(n)` drops is noise: no whole header starts in it, unless it is a whole
/// instruction packet a status reader passes over (an echo).
fn skipped_noise(p: Protocol, buf: &[u8], n: usize, status: bool) {
    if status {
        if let Ok((ins, used)) = p.parse_instruction(buf) {
            if used == n {
                assert!(
                    ins.instruction != packet::instruction::STATUS || ins.params.is_empty(),
                    "a status packet skipped as an echo"
                );
                return;
            }
        }
    }
    for j in 0..n {
        let header = match p {
            Protocol::Dynamixel2 => {
                buf.len() >= j + 4 && buf[j..j + 3] == [0xFF, 0xFF, 0xFD] && buf[j + 3] != 0xFD
            }
            Protocol::Feetech => {
                buf.len() >= j + 3 && buf[j..j + 2] == [0xFF, 0xFF] && buf[j + 2] != 0xFF
            }
        };
        assert!(!header, "skipped a header at {j} of {n} skipped bytes");
    }
}

/// One packet `raw` (exactly the bytes the parser consumed), by both readings.
fn packet(p: Protocol, raw: &[u8]) {
    let (ins, used) = p.parse_instruction(raw).expect("a packet parses alone");
    assert_eq!(used, raw.len());
    // Framing fields.
    let body_raw = match p {
        Protocol::Dynamixel2 => {
            assert_eq!(raw[..4], [0xFF, 0xFF, 0xFD, 0x00]);
            assert_eq!(
                usize::from(u16::from_le_bytes([raw[5], raw[6]])),
                raw.len() - 7
            );
            assert!(raw.len() >= 10);
            let n = raw.len();
            assert_eq!(
                packet::crc16(&raw[..n - 2]),
                u16::from_le_bytes([raw[n - 2], raw[n - 1]]),
                "CRC over header and stuffed body"
            );
            &raw[7..n - 2]
        }
        Protocol::Feetech => {
            assert_eq!(raw[..2], [0xFF, 0xFF]);
            assert_ne!(raw[2], 0xFF);
            assert_eq!(usize::from(raw[3]), raw.len() - 4);
            assert!(raw.len() >= 6);
            let n = raw.len();
            assert_eq!(packet::feetech_checksum(&raw[2..n - 1]), raw[n - 1]);
            &raw[4..n - 1]
        }
    };
    let id = match p {
        Protocol::Dynamixel2 => raw[4],
        Protocol::Feetech => raw[2],
    };
    assert_eq!(ins.id, id);
    let mut body = vec![ins.instruction];
    body.extend_from_slice(&ins.params);
    let canonical = match p {
        Protocol::Dynamixel2 => {
            assert_eq!(body, reference_unstuff(body_raw), "unstuffing per the spec");
            reference_stuff(&body) == body_raw
        }
        Protocol::Feetech => {
            assert_eq!(body, body_raw);
            true
        }
    };
    let again = p.encode_instruction(ins.id, ins.instruction, &ins.params);
    if canonical {
        assert_eq!(again, raw, "a canonical packet re-encodes byte for byte");
    }
    let (ins2, used2) = p
        .parse_instruction(&again)
        .expect("an encoded packet parses");
    assert_eq!(
        (&ins2, used2),
        (&ins, again.len()),
        "parse ∘ encode ∘ parse = parse"
    );

    // The status reading of the same bytes.
    match p.parse_status(raw) {
        Ok((st, used)) => {
            assert_eq!((used, st.id), (raw.len(), id));
            let rest = match p {
                Protocol::Dynamixel2 => {
                    assert_eq!(ins.instruction, packet::instruction::STATUS);
                    &ins.params[..]
                }
                Protocol::Feetech => &body[..],
            };
            assert_eq!(st.error, rest[0]);
            assert_eq!(st.params, &rest[1..]);
            let again = p.encode_status(st.id, st.error, &st.params);
            if canonical {
                assert_eq!(again, raw, "a canonical status re-encodes byte for byte");
            }
            assert_eq!(p.parse_status(&again), Ok((st, again.len())));
        }
        Err(PacketError::Skip(n)) => {
            assert_eq!(
                p,
                Protocol::Dynamixel2,
                "every Feetech packet reads as a status"
            );
            assert_eq!(n, raw.len());
            assert!(ins.instruction != packet::instruction::STATUS || ins.params.is_empty());
        }
        Err(e) => panic!("a packet is not a status: {e:?}"),
    }

    // Parameter layouts the mock decodes: decoding then encoding gives the same bytes.
    let prm = &ins.params;
    if let Some((addr, len)) = p.decode_read(prm) {
        assert_eq!(p.read_params(addr, len), *prm);
    }
    if let Some((addr, data)) = p.decode_write(prm) {
        assert_eq!(p.write_params(addr, &data), *prm);
    }
    if let Some((addr, len, ids)) = p.decode_sync_read(prm) {
        assert_eq!(p.sync_read_params(addr, len, &ids), *prm);
    }
    if let Some((addr, len, items)) = p.decode_sync_write(prm) {
        assert!(items.iter().all(|(_, d)| d.len() == usize::from(len)));
        assert_eq!(p.sync_write_params(addr, len, &items), *prm);
    }
}

/// The encoder's side: the input read as (id, instruction, parameters) encodes to a packet
/// that parses back to the same values (within what the wire can say).
fn packet_encoded(p: Protocol, data: &[u8]) {
    let [id, ins, params @ ..] = data else {
        return;
    };
    let params = &params[..params.len().min(1100)];
    let fits = match p {
        Protocol::Dynamixel2 => true,
        // One length byte, and an id of FF would read as idle line.
        Protocol::Feetech => params.len() <= 253 && *id != 0xFF,
    };
    if !fits {
        return;
    }
    let wire = p.encode_instruction(*id, *ins, params);
    match p.parse_instruction(&wire) {
        Ok((got, used)) => {
            assert_eq!(used, wire.len());
            assert_eq!(
                (got.id, got.instruction, &got.params[..]),
                (*id, *ins, params)
            );
        }
        Err(e) => {
            let len = usize::from(u16::from_le_bytes([wire[5], wire[6]]));
            assert!(
                p == Protocol::Dynamixel2 && len > 1024,
                "encoded packet refused: {e:?}"
            );
        }
    }
    let wire = p.encode_status(*id, *ins, params);
    if let Ok((got, used)) = p.parse_status(&wire) {
        assert_eq!(used, wire.len());
        assert_eq!((got.id, got.error, &got.params[..]), (*id, *ins, params));
    } else {
        let len = usize::from(u16::from_le_bytes([wire[5], wire[6]]));
        assert!(
            p == Protocol::Dynamixel2 && len > 1024,
            "encoded status refused"
        );
    }
}

fn serial(p: Protocol, data: &[u8]) {
    for status in [true, false] {
        let whole = packet_stream(p, data, Plan::Whole, status);
        for e in &whole.0 {
            if let PacketEvent::Packet { at, len } = e {
                packet(p, &data[*at..at + len]);
            }
        }
        for plan in plans(data) {
            assert_eq!(
                packet_stream(p, data, plan, status),
                whole,
                "same packets under {plan:?} (status reader: {status})"
            );
        }
    }
    packet_encoded(p, data);
}

/// Target `dynamixel`: Protocol 2.0 status packets as the bus reads them and instruction
/// packets as the mock bus reads them.
pub fn dynamixel(data: &[u8]) {
    serial(Protocol::Dynamixel2, data);
}

/// Target `feetech`: the same for Feetech STS/SCS packets.
pub fn feetech(data: &[u8]) {
    serial(Protocol::Feetech, data);
}

// ---------------------------------------------------------------------------------------
// Piper CAN frames.

/// Bytes per CAN record in a `piper` input: id (u16 BE), data length, 8 data bytes.
pub const PIPER_RECORD: usize = 11;

fn can_frame(f: &CanFrame) {
    assert!(f.id <= 0x7FF && f.len <= 8);
    assert!(f.data[usize::from(f.len)..].iter().all(|&b| b == 0));
    let fb = piper::decode_joint_pair(piper::id::JOINT_FEEDBACK_12, f);
    let tg = piper::decode_joint_pair(piper::id::JOINT_TARGET_12, f);
    let st = StatusFrame::decode(f);
    let drv = piper::decode_driver_enabled(f);
    let mode = ModeCommand::decode(f);
    let claimed = [fb.is_some(), st.is_some(), drv.is_some()];
    assert!(
        claimed.iter().filter(|c| **c).count() <= 1,
        "feedback decoders claim disjoint ids"
    );
    for (base, pair, make) in [
        (
            piper::id::JOINT_FEEDBACK_12,
            fb,
            piper::joint_feedback_frames as fn(&[i32; 6]) -> [CanFrame; 3],
        ),
        (piper::id::JOINT_TARGET_12, tg, piper::joint_target_frames),
    ] {
        let Some((k, a, b)) = pair else {
            assert!(
                f.len != 8 || !(base..base + 3).contains(&f.id),
                "an 8-byte joint frame decodes"
            );
            continue;
        };
        assert!(k % 2 == 0 && k < 6);
        assert_eq!(f.id, base + (k / 2) as u16);
        let mut j = [0i32; 6];
        j[k] = a;
        j[k + 1] = b;
        assert_eq!(make(&j)[k / 2], *f, "joint frame re-encodes");
        for v in [a, b] {
            assert_eq!(piper::rad_to_millideg(piper::millideg_to_rad(v)), Some(v));
        }
    }
    if let Some(s) = st {
        assert_eq!(s.encode(), *f, "status re-encodes");
        let quiet = s.arm_status == 0 && s.over_limit & 0x3F == 0 && s.comm_error & 0x3F == 0;
        assert_eq!(
            s.fault().is_none(),
            quiet,
            "fault() is None exactly when all is well"
        );
    } else {
        assert!(f.id != piper::id::STATUS || f.len != 8);
    }
    if let Some((k, on)) = drv {
        assert!(k < 6);
        assert_eq!(f.id, piper::id::DRIVER_STATE_1 + k as u16);
        assert_eq!(
            piper::decode_driver_enabled(&piper::driver_state_frame(k, on)),
            Some((k, on))
        );
    }
    match mode {
        Some(m) => {
            assert!(f.id == piper::id::MODE && f.len >= 4);
            assert_eq!(m.encode().data[..4], f.data[..4]);
            assert_eq!(ModeCommand::decode(&m.encode()), Some(m));
        }
        None => assert!(f.id != piper::id::MODE || f.len < 4),
    }
}

/// Target `piper`: the input as CAN records (id u16 BE, length, 8 data bytes); each becomes a
/// frame if the id is 11-bit and the length ≤ 8, and runs through every decoder.
pub fn piper(data: &[u8]) {
    for rec in data.chunks(PIPER_RECORD) {
        let id = u16::from_be_bytes([rec[0], *rec.get(1).unwrap_or(&0)]);
        let len = usize::from(*rec.get(2).unwrap_or(&0));
        let payload = rec.get(3..).unwrap_or(&[]);
        let bytes = &payload[..len.min(payload.len())];
        match CanFrame::new(id, bytes) {
            Some(f) => {
                assert!(id <= 0x7FF);
                assert_eq!(f.bytes(), bytes);
                can_frame(&f);
            }
            None => assert!(id > 0x7FF, "{} bytes under {id:#x} refused", bytes.len()),
        }
    }
}
