//! The daemon API part of the bad-input corpus ("Nothing wrong passes quietly"): one daemon on
//! a simulated cell, on loopback with a token, gets malformed and hostile requests sent as raw
//! bytes over TCP (so headers, content types and framing are exactly what each case says).
//!
//! Each case must get its 4xx with a JSON `{"error": …}` body whose message is one line and
//! names the field or parameter it is about, or, for the framing cases hyper answers itself
//! (a header over its buffer, a broken request line), any 4xx or a clean close. Each must be
//! answered within [`HANG_GUARD`] (a client timeout against hangs, not a performance bound).
//! Afterwards the daemon still answers `/healthz`, and the data folder (`index.json`,
//! `active.json`, `runs/`, everything in it) is byte-identical to before the bad requests.
//! All failures are collected and reported together, with the case names.

mod common;

use std::collections::BTreeMap;
use std::io::{ErrorKind, Read, Write};
use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use common::daemon::{
    call, call_as, get_bytes, real_time_arm, record, result_json, start, wait_final, wait_for,
    write_config, write_index, write_result, POSE, TOKEN,
};
use serde_json::{json, Value};

/// Longest wait for an answer or a close: a hang guard, not a performance assertion.
const HANG_GUARD: Duration = Duration::from_secs(10);

/// What a case must get.
#[derive(Clone, Copy, Debug)]
enum Expect {
    /// This status, with a one-line JSON error naming each of these words.
    Error(u16, &'static [&'static str]),
    /// A framing error: any 4xx or a clean close (hyper answers these itself, with no body).
    Framing,
}

struct Case {
    name: String,
    raw: Vec<u8>,
    expect: Expect,
}

/// What came back: `status` is `None` when the connection closed without an answer.
struct Answer {
    status: Option<u16>,
    head: String,
    body: Vec<u8>,
}

/// A request as bytes, `Connection: close`, with a `Content-Length` unless `headers` frame the
/// body themselves.
fn req(method: &str, path: &str, headers: &[(&str, &str)], body: &[u8]) -> Vec<u8> {
    let mut s = format!("{method} {path} HTTP/1.1\r\nHost: localhost\r\nConnection: close\r\n");
    for (k, v) in headers {
        s += &format!("{k}: {v}\r\n");
    }
    let framed = headers.iter().any(|(k, _)| {
        k.eq_ignore_ascii_case("content-length") || k.eq_ignore_ascii_case("transfer-encoding")
    });
    if !framed && (!body.is_empty() || method == "POST") {
        s += &format!("Content-Length: {}\r\n", body.len());
    }
    s += "\r\n";
    let mut raw = s.into_bytes();
    raw.extend_from_slice(body);
    raw
}

/// Sends `raw` on a new connection and reads until the server closes it.
fn send(addr: &str, raw: &[u8]) -> Result<Answer, String> {
    let start = Instant::now();
    let mut s = TcpStream::connect(addr).map_err(|e| format!("connect: {e}"))?;
    s.set_write_timeout(Some(HANG_GUARD)).unwrap();
    // The server may answer and close before reading everything (a header over its limit):
    // a failed write is not a failure yet; what comes back decides.
    let _ = s.write_all(raw);
    let mut got = Vec::new();
    let mut buf = [0u8; 8192];
    loop {
        let left = HANG_GUARD.saturating_sub(start.elapsed());
        if left.is_zero() {
            return Err(format!("no answer or close within {HANG_GUARD:?}"));
        }
        s.set_read_timeout(Some(left)).unwrap();
        match s.read(&mut buf) {
            Ok(0) => break,
            Ok(n) => got.extend_from_slice(&buf[..n]),
            Err(e) if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut) => {
                return Err(format!("no answer or close within {HANG_GUARD:?}"));
            }
            // A reset after (or instead of) the answer: the connection is closed.
            Err(_) => break,
        }
    }
    Ok(parse(&got))
}

fn parse(got: &[u8]) -> Answer {
    let Some(end) = got.windows(4).position(|w| w == b"\r\n\r\n") else {
        return Answer {
            status: None,
            head: String::from_utf8_lossy(got).into_owned(),
            body: Vec::new(),
        };
    };
    let head = String::from_utf8_lossy(&got[..end]).into_owned();
    let status = head
        .lines()
        .next()
        .and_then(|l| l.split_whitespace().nth(1))
        .and_then(|c| c.parse().ok());
    let mut body = got[end + 4..].to_vec();
    if head
        .to_ascii_lowercase()
        .contains("transfer-encoding: chunked")
    {
        body = dechunk(&body);
    }
    Answer { status, head, body }
}

fn dechunk(mut b: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    while let Some(eol) = b.windows(2).position(|w| w == b"\r\n") {
        let size = std::str::from_utf8(&b[..eol])
            .ok()
            .and_then(|s| usize::from_str_radix(s.trim(), 16).ok())
            .unwrap_or(0);
        if size == 0 || b.len() < eol + 2 + size {
            break;
        }
        out.extend_from_slice(&b[eol + 2..eol + 2 + size]);
        b = &b[(eol + 4 + size).min(b.len())..];
    }
    out
}

/// Whether `a` is what `expect` asks for.
fn check(expect: Expect, a: &Answer) -> Result<(), String> {
    let (code, words) = match expect {
        Expect::Framing => return framing(a.status),
        Expect::Error(code, words) => (code, words),
    };
    let body = String::from_utf8_lossy(&a.body);
    if a.status != Some(code) {
        return Err(format!("status {:?}, expected {code}: {body}", a.status));
    }
    if !a
        .head
        .to_ascii_lowercase()
        .contains("content-type: application/json")
    {
        return Err(format!(
            "not a JSON answer: {}",
            a.head.replace("\r\n", " | ")
        ));
    }
    let v: Value = serde_json::from_str(&body).map_err(|e| format!("body {body:?}: {e}"))?;
    let m = v["error"]
        .as_str()
        .ok_or_else(|| format!("no \"error\" string: {body}"))?;
    if m.contains(['\n', '\r']) {
        return Err(format!("multi-line message: {m:?}"));
    }
    if m.chars().count() > 400 {
        return Err(format!("message of {} characters", m.chars().count()));
    }
    match words.iter().find(|w| !m.contains(**w)) {
        Some(w) => Err(format!("message does not name {w:?}: {m}")),
        None => Ok(()),
    }
}

/// A framing case: any 4xx, or closed without an answer.
fn framing(status: Option<u16>) -> Result<(), String> {
    match status {
        None => Ok(()),
        Some(c) if (400..500).contains(&c) => Ok(()),
        Some(c) => Err(format!("status {c}, expected a 4xx or a close")),
    }
}

/// Runs every case; the failures, as `name: why`.
fn run_cases(addr: &str, cases: &[Case]) -> Vec<String> {
    let mut failures = Vec::new();
    for c in cases {
        let outcome = send(addr, &c.raw).and_then(|a| check(c.expect, &a));
        if let Err(why) = outcome {
            failures.push(format!("{}: {why}", c.name));
        }
    }
    failures
}

fn case(name: &str, raw: Vec<u8>, expect: Expect) -> Case {
    Case {
        name: name.into(),
        raw,
        expect,
    }
}

const CALS: &str = "/api/v1/calibrations";

/// Start bodies that are not `{"max_views": 1..=100, "dry_run": bool}`, sent as JSON with
/// the token: each a 400 naming the field (or the body).
fn start_body_cases() -> Vec<Case> {
    let deep = format!(
        "{{\"max_views\": {}{}}}",
        "[".repeat(1000),
        "]".repeat(1000)
    );
    let bodies: Vec<(&str, String, &'static [&'static str])> = vec![
        (
            "start_invalid_json",
            r#"{"max_views": 2"#.into(),
            &["request body"],
        ),
        ("start_not_an_object", "[1, 2]".into(), &["request body"]),
        ("start_null_body", "null".into(), &["request body"]),
        (
            "start_trailing_garbage",
            r#"{"max_views": 2} x"#.into(),
            &["request body"],
        ),
        (
            "start_unknown_field",
            r#"{"max_view": 2}"#.into(),
            &["max_view"],
        ),
        (
            "start_unknown_field_with_newline",
            r#"{"a\nb": 1}"#.into(),
            &["unknown field"],
        ),
        (
            "start_max_views_string",
            r#"{"max_views": "4"}"#.into(),
            &["max_views"],
        ),
        (
            "start_max_views_null",
            r#"{"max_views": null}"#.into(),
            &["max_views"],
        ),
        (
            "start_max_views_object",
            r#"{"max_views": {"n": 2}}"#.into(),
            &["max_views"],
        ),
        (
            "start_dry_run_null",
            r#"{"dry_run": null}"#.into(),
            &["dry_run"],
        ),
        (
            "start_dry_run_string",
            r#"{"dry_run": "yes"}"#.into(),
            &["dry_run"],
        ),
        (
            "start_max_views_zero",
            r#"{"max_views": 0}"#.into(),
            &["max_views"],
        ),
        (
            "start_max_views_1e9",
            r#"{"max_views": 1e9}"#.into(),
            &["max_views"],
        ),
        (
            "start_max_views_billion",
            r#"{"max_views": 1000000000}"#.into(),
            &["max_views"],
        ),
        (
            "start_max_views_101",
            r#"{"max_views": 101}"#.into(),
            &["max_views"],
        ),
        (
            "start_max_views_negative",
            r#"{"max_views": -3}"#.into(),
            &["max_views"],
        ),
        (
            "start_max_views_beyond_u64",
            r#"{"max_views": 99999999999999999999999}"#.into(),
            &["max_views"],
        ),
        (
            "start_max_views_fraction",
            r#"{"max_views": 2.5}"#.into(),
            &["max_views"],
        ),
        (
            "start_max_views_twice",
            r#"{"max_views": 2, "max_views": 3}"#.into(),
            &["max_views"],
        ),
        ("start_deeply_nested", deep, &["request body"]),
    ];
    let bearer = format!("Bearer {TOKEN}");
    bodies
        .into_iter()
        .map(|(name, body, words)| {
            let h = [
                ("Authorization", bearer.as_str()),
                ("Content-Type", "application/json"),
            ];
            case(
                name,
                req("POST", CALS, &h, body.as_bytes()),
                Expect::Error(400, words),
            )
        })
        .collect()
}

/// Content types, body sizes and framing of a start request.
fn start_framing_cases() -> Vec<Case> {
    let bearer = format!("Bearer {TOKEN}");
    let auth = ("Authorization", bearer.as_str());
    let mut big = br#"{"max_views": 2"#.to_vec();
    big.resize(100_000, b' ');
    big.push(b'}');
    let mut chunked = format!("{:x}\r\n", big.len()).into_bytes();
    chunked.extend_from_slice(&big);
    chunked.extend_from_slice(b"\r\n0\r\n\r\n");
    let te = ("Transfer-Encoding", "chunked");
    let json_ct = ("Content-Type", "application/json");
    let body = br#"{"max_views": 2}"#;
    vec![
        case(
            "start_text_plain",
            req("POST", CALS, &[auth, ("Content-Type", "text/plain")], body),
            Expect::Error(415, &["Content-Type"]),
        ),
        case(
            "start_form_urlencoded",
            req(
                "POST",
                CALS,
                &[auth, ("Content-Type", "application/x-www-form-urlencoded")],
                b"max_views=2",
            ),
            Expect::Error(415, &["Content-Type"]),
        ),
        case(
            "start_body_over_limit",
            req("POST", CALS, &[auth, json_ct], &big),
            Expect::Error(413, &["request body"]),
        ),
        case(
            "start_chunked_body_over_limit",
            req("POST", CALS, &[auth, json_ct, te], &chunked),
            Expect::Error(413, &["request body"]),
        ),
        case(
            "start_absurd_content_length_no_body",
            req(
                "POST",
                CALS,
                &[auth, json_ct, ("Content-Length", "99999999999")],
                b"",
            ),
            Expect::Error(413, &["Content-Length"]),
        ),
        case(
            "start_absurd_content_length_no_token",
            req("POST", CALS, &[("Content-Length", "99999999999")], b""),
            Expect::Error(413, &["Content-Length"]),
        ),
        // Closed by the idle timeout (3 s here): 10 of 100 bytes, then nothing.
        case(
            "start_stalled_body",
            req(
                "POST",
                CALS,
                &[auth, json_ct, ("Content-Length", "100")],
                br#"{"dry_run""#,
            ),
            Expect::Framing,
        ),
        case(
            "negative_content_length",
            req("POST", CALS, &[auth, ("Content-Length", "-1")], b""),
            Expect::Framing,
        ),
        case(
            "two_content_lengths",
            req(
                "POST",
                CALS,
                &[auth, ("Content-Length", "2"), ("Content-Length", "16")],
                body,
            ),
            Expect::Framing,
        ),
    ]
}

/// Missing and wrong tokens on every POST route: 401 naming the token, nothing done.
fn token_cases(run: &str) -> Vec<Case> {
    let routes = [
        ("start", CALS.to_string()),
        ("activate", format!("{CALS}/cal-0001/activate")),
        ("cancel", format!("{CALS}/{run}/cancel")),
        ("check", "/api/v1/checks".to_string()),
    ];
    let wrong = [
        ("no_token", None),
        ("wrong_token", Some("Bearer not-the-token")),
        ("basic_auth", Some("Basic dGVzdDp0ZXN0")),
        ("empty_bearer", Some("Bearer ")),
        ("token_without_scheme", Some(TOKEN)),
    ];
    let mut out = Vec::new();
    for (route, path) in &routes {
        for (what, header) in wrong {
            let h: Vec<(&str, &str)> = header.map(|v| ("Authorization", v)).into_iter().collect();
            out.push(case(
                &format!("{route}_{what}"),
                req("POST", path, &h, b""),
                Expect::Error(401, &["token"]),
            ));
        }
    }
    out
}

/// Ids that are not daemon ids, ids of the wrong calibration, and overlay view indices.
fn id_cases(run: &str) -> Vec<Case> {
    let bearer = format!("Bearer {TOKEN}");
    let auth = [("Authorization", bearer.as_str())];
    let long = format!("cal-{}", "9".repeat(5000));
    let id = |w: &'static [&'static str]| Expect::Error(404, w);
    let cid: &'static [&'static str] = &["calibration id"];
    let get = |path: String| req("GET", &path, &[], b"");
    let post = |path: String| req("POST", &path, &auth, b"");
    vec![
        case(
            "status_huge_id",
            get(format!("{CALS}/cal-18446744073709551615")),
            id(cid),
        ),
        case(
            "status_traversal",
            get(format!("{CALS}/..%2F..%2Fetc%2Fpasswd")),
            id(cid),
        ),
        case(
            "status_very_long_id",
            get(format!("{CALS}/{long}")),
            id(cid),
        ),
        case(
            "status_newline_id",
            get(format!("{CALS}/cal-0001%0D%0AX-Evil:%201")),
            id(cid),
        ),
        case(
            "status_leading_zeros",
            get(format!("{CALS}/cal-00001")),
            id(cid),
        ),
        case(
            "status_unknown",
            get(format!("{CALS}/cal-0999")),
            id(&["cal-0999"]),
        ),
        case(
            "events_traversal",
            get(format!("{CALS}/..%2F..%2Fetc%2Fpasswd/events")),
            id(cid),
        ),
        case(
            "events_unknown",
            get(format!("{CALS}/cal-0999/events")),
            id(&["cal-0999"]),
        ),
        case(
            "events_invalid_utf8",
            get(format!("{CALS}/%FF%FE/events")),
            Expect::Error(400, &[]),
        ),
        case(
            "activate_huge_id",
            post(format!("{CALS}/cal-18446744073709551615/activate")),
            id(cid),
        ),
        case(
            "activate_traversal",
            post(format!("{CALS}/..%2F..%2Fetc%2Fpasswd/activate")),
            id(cid),
        ),
        case(
            "activate_dot_segments",
            post(format!("{CALS}/cal-0001/../x/activate")),
            id(&["no such route"]),
        ),
        case(
            "activate_empty_id",
            post(format!("{CALS}//activate")),
            id(&[]),
        ),
        case(
            "activate_very_long_id",
            post(format!("{CALS}/{long}/activate")),
            id(cid),
        ),
        case(
            "activate_unknown",
            post(format!("{CALS}/cal-0999/activate")),
            id(&["cal-0999"]),
        ),
        case(
            "activate_cancelled",
            post(format!("{CALS}/{run}/activate")),
            Expect::Error(409, &["state"]),
        ),
        case(
            "activate_dry_run",
            post(format!("{CALS}/cal-0002/activate")),
            Expect::Error(409, &["dry_run"]),
        ),
        case(
            "activate_other_mount",
            post(format!("{CALS}/cal-0003/activate")),
            Expect::Error(409, &["result.json base_link", "link6", "[camera] mount"]),
        ),
        case(
            "cancel_cancelled",
            post(format!("{CALS}/{run}/cancel")),
            Expect::Error(409, &["cancelled"]),
        ),
        case(
            "cancel_unknown",
            post(format!("{CALS}/cal-0999/cancel")),
            id(&["cal-0999"]),
        ),
        case(
            "cancel_traversal",
            post(format!("{CALS}/..%2F..%2Fetc%2Fpasswd/cancel")),
            id(cid),
        ),
        case(
            "overlay_out_of_range",
            get(format!("{CALS}/{run}/views/999/overlay.png")),
            id(&["view 999"]),
        ),
        case(
            "overlay_negative",
            get(format!("{CALS}/{run}/views/-1/overlay.png")),
            Expect::Error(400, &["view"]),
        ),
        case(
            "overlay_huge_index",
            get(format!(
                "{CALS}/{run}/views/99999999999999999999999/overlay.png"
            )),
            Expect::Error(400, &["view"]),
        ),
        case(
            "overlay_not_a_number",
            get(format!("{CALS}/{run}/views/abc/overlay.png")),
            Expect::Error(400, &["view"]),
        ),
        case(
            "overlay_dry_run",
            get(format!("{CALS}/cal-0002/views/0/overlay.png")),
            id(&["cal-0002"]),
        ),
        case(
            "overlay_traversal",
            get(format!("{CALS}/..%2F..%2Fetc%2Fpasswd/views/0/overlay.png")),
            id(cid),
        ),
    ]
}

/// Unknown routes, wrong methods and requests hyper cannot parse.
fn route_cases() -> Vec<Case> {
    let bearer = format!("Bearer {TOKEN}");
    let auth = [("Authorization", bearer.as_str())];
    let junk = "a".repeat(600_000);
    let many: String = (0..500).map(|i| format!("X-H{i}: {i}\r\n")).collect();
    let too_many = format!("GET /healthz HTTP/1.1\r\nHost: x\r\n{many}Connection: close\r\n\r\n");
    vec![
        case(
            "unknown_route",
            req("GET", "/api/v2/calibrations", &[], b""),
            Expect::Error(404, &["no such route"]),
        ),
        case(
            "unknown_post_route",
            req("POST", &format!("{CALS}/cal-0001/delete"), &auth, b""),
            Expect::Error(404, &["no such route"]),
        ),
        case(
            "delete_history",
            req("DELETE", CALS, &auth, b""),
            Expect::Error(405, &["DELETE"]),
        ),
        case(
            "get_activate",
            req("GET", &format!("{CALS}/cal-0001/activate"), &[], b""),
            Expect::Error(405, &["GET"]),
        ),
        case(
            "post_healthz",
            req("POST", "/healthz", &auth, b""),
            Expect::Error(405, &["POST"]),
        ),
        case(
            "put_checks",
            req("PUT", "/api/v1/checks", &auth, b"{}"),
            Expect::Error(405, &["PUT"]),
        ),
        case(
            "patch_active",
            req("PATCH", "/api/v1/calibration", &auth, b"{}"),
            Expect::Error(405, &["PATCH"]),
        ),
        case(
            "header_line_over_limit",
            req("GET", "/healthz", &[("X-Junk", &junk)], b""),
            Expect::Framing,
        ),
        case("too_many_headers", too_many.into_bytes(), Expect::Framing),
        case(
            "garbage_request_line",
            b"HELLO\r\n\r\n".to_vec(),
            Expect::Framing,
        ),
        case(
            "binary_garbage",
            vec![0u8, 255, 1, 254, b'\r', b'\n', b'\r', b'\n'],
            Expect::Framing,
        ),
        // Closed by the header-read timeout (2 s here).
        case(
            "unfinished_head",
            b"GET /healthz HTTP/1.1\r\nHost: x\r\n".to_vec(),
            Expect::Framing,
        ),
    ]
}

/// Every file under `dir` (relative path → bytes; folders as empty entries ending in `/`).
fn snapshot(dir: &Path) -> BTreeMap<PathBuf, Vec<u8>> {
    fn walk(root: &Path, dir: &Path, out: &mut BTreeMap<PathBuf, Vec<u8>>) {
        let Ok(entries) = std::fs::read_dir(dir) else {
            return;
        };
        for e in entries.flatten() {
            let p = e.path();
            let rel = p.strip_prefix(root).unwrap().to_path_buf();
            if p.is_dir() {
                out.insert(rel.join(""), Vec::new());
                walk(root, &p, out);
            } else {
                out.insert(rel, std::fs::read(&p).unwrap_or_default());
            }
        }
    }
    let mut out = BTreeMap::new();
    walk(dir, dir, &mut out);
    out
}

/// A snapshot once two taken 300 ms apart agree (a run thread may still be writing its last
/// record after its final state is visible).
fn settled(dir: &Path) -> BTreeMap<PathBuf, Vec<u8>> {
    let start = Instant::now();
    let mut last = snapshot(dir);
    loop {
        std::thread::sleep(Duration::from_millis(300));
        let now = snapshot(dir);
        if now == last || start.elapsed() > Duration::from_secs(20) {
            return now;
        }
        last = now;
    }
}

/// The paths that differ between two snapshots (changed, added, removed), except `skip`.
fn changed(
    before: &BTreeMap<PathBuf, Vec<u8>>,
    after: &BTreeMap<PathBuf, Vec<u8>>,
    skip: impl Fn(&Path) -> bool,
) -> Vec<String> {
    let mut out = Vec::new();
    for (p, b) in before {
        match after.get(p) {
            Some(a) if a == b => {}
            Some(_) if !skip(p) => out.push(format!("changed {}", p.display())),
            None if !skip(p) => out.push(format!("removed {}", p.display())),
            _ => {}
        }
    }
    for p in after.keys() {
        if !before.contains_key(p) && !skip(p) {
            out.push(format!("added {}", p.display()));
        }
    }
    out
}

/// The records of `index.json` by id, without their `null` fields (the daemon writes every
/// field of a record it rewrites; the seeded records left the empty ones out).
fn index_records(snap: &BTreeMap<PathBuf, Vec<u8>>) -> BTreeMap<String, Value> {
    let index: Value = serde_json::from_slice(&snap[Path::new("index.json")]).unwrap();
    index["calibrations"]
        .as_array()
        .unwrap()
        .iter()
        .map(|r| {
            let mut r = r.clone();
            r.as_object_mut().unwrap().retain(|_, v| !v.is_null());
            (r["id"].as_str().unwrap().to_string(), r)
        })
        .collect()
}

/// Requests against a running calibration: activating it, a second start, a negative view,
/// a cancel and an activation without the right token.
fn running_cases(run: &str) -> Vec<Case> {
    let bearer = format!("Bearer {TOKEN}");
    let auth = [("Authorization", bearer.as_str())];
    let json_ct = ("Content-Type", "application/json");
    vec![
        case(
            "activate_running",
            req("POST", &format!("{CALS}/{run}/activate"), &auth, b""),
            Expect::Error(409, &["state"]),
        ),
        case(
            "start_while_running",
            req("POST", CALS, &[auth[0], json_ct], br#"{"max_views": 2}"#),
            Expect::Error(409, &["running"]),
        ),
        case(
            "start_while_running_bad_body",
            req("POST", CALS, &[auth[0], json_ct], br#"{"max_views": -1}"#),
            Expect::Error(400, &["max_views"]),
        ),
        case(
            "overlay_running_negative_view",
            req(
                "GET",
                &format!("{CALS}/{run}/views/-1/overlay.png"),
                &[],
                b"",
            ),
            Expect::Error(400, &["view"]),
        ),
        case(
            "cancel_running_wrong_token",
            req(
                "POST",
                &format!("{CALS}/{run}/cancel"),
                &[("Authorization", "Bearer x")],
                b"",
            ),
            Expect::Error(401, &["token"]),
        ),
        case(
            "activate_running_no_token",
            req("POST", &format!("{CALS}/{run}/activate"), &[], b""),
            Expect::Error(401, &["token"]),
        ),
    ]
}

#[test]
fn malformed_and_hostile_api_requests_get_one_line_4xx_and_change_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let config = write_config(dir.path(), |c| {
        real_time_arm(c);
        c.daemon.header_read_timeout_s = Some(2.0);
        c.daemon.idle_timeout_s = Some(3.0);
    });
    let data = dir.path().join("data");
    write_result(&data.join("runs/cal-0001"), &result_json(POSE, "converged"));
    // A wrist camera's result (camera_from_link6) in a cell whose camera is fixed.
    let mut wrist = result_json(POSE, "converged");
    wrist["base_link"] = "link6".into();
    write_result(&data.join("runs/cal-0003"), &wrist);
    write_index(
        &data,
        &[
            record("cal-0001", "succeeded", false, "runs/cal-0001"),
            record("cal-0002", "succeeded", true, "runs/cal-0002"),
            record("cal-0003", "succeeded", false, "runs/cal-0003"),
        ],
    );
    let d = start(&config, &data);
    let base = d.base.clone();
    let addr = base.trim_start_matches("http://").to_string();
    let (code, a) = call("POST", &format!("{base}{CALS}/cal-0001/activate"), None);
    assert_eq!(code, 200, "{a}");
    let mut failures = Vec::new();
    let mut count = 0;

    // A running calibration: the refusals while it runs, then a cancel.
    let before_run = settled(&data);
    let (code, s) = call(
        "POST",
        &format!("{base}{CALS}"),
        Some(&json!({"max_views": 4})),
    );
    assert_eq!(code, 202, "{s}");
    let run = s["id"].as_str().unwrap().to_string();
    wait_for(&base, &run, Duration::from_secs(120), |s| {
        let ended = !matches!(s["state"].as_str(), Some("queued" | "running"));
        s["views"].as_u64().unwrap_or(0) >= 1 || ended
    });
    let cases = running_cases(&run);
    count += cases.len();
    let (_, s) = call("GET", &format!("{base}{CALS}/{run}"), None);
    assert_eq!(
        s["state"], "running",
        "{run} ended before the running cases: {s}"
    );
    failures.extend(run_cases(&addr, &cases));
    let (code, c) = call("POST", &format!("{base}{CALS}/{run}/cancel"), None);
    assert_eq!(code, 202, "{c}");
    assert_eq!(wait_final(&base, &run)["state"], "cancelled");
    let after_run = settled(&data);
    // index.json legitimately gained the run's record and runs/ its directory; everything
    // else (active.json above all) and the older records must be as they were.
    let own = Path::new("runs").join(&run);
    for why in changed(&before_run, &after_run, |p| {
        p == Path::new("index.json") || p.starts_with(&own)
    }) {
        failures.push(format!("running cases: data folder: {why}"));
    }
    let (old, new) = (index_records(&before_run), index_records(&after_run));
    for (id, r) in &old {
        if new.get(id) != Some(r) {
            let now = new.get(id).map_or("gone".into(), Value::to_string);
            failures.push(format!(
                "running cases: index.json record {id} changed: {r} -> {now}"
            ));
        }
    }

    // Everything else against the settled folder: nothing may change at all.
    let mut cases = start_body_cases();
    cases.extend(start_framing_cases());
    cases.extend(token_cases(&run));
    cases.extend(id_cases(&run));
    cases.extend(route_cases());
    count += cases.len();
    failures.extend(run_cases(&addr, &cases));
    let (code, h) = call_as("GET", &format!("{base}/healthz"), None, None);
    if code != 200 || h["status"] != "ok" || !h["busy"].is_null() {
        failures.push(format!("healthz afterwards: {code} {h}"));
    }
    let (code, a) = call("GET", &format!("{base}/api/v1/calibration"), None);
    if code != 200 || a["id"] != "cal-0001" {
        failures.push(format!("active calibration afterwards: {code} {a}"));
    }
    for why in changed(&after_run, &settled(&data), |_| false) {
        failures.push(format!("data folder: {why}"));
    }

    // A run folder edited on disk: view 0's mask no longer has the camera's size. The overlay
    // must be refused with one line naming the mask, not drawn out of bounds.
    let mask = data.join("runs").join(&run).join("views/000.mask.png");
    image::GrayImage::new(1280, 960).save(&mask).unwrap();
    let (code, _, body) = get_bytes(&format!("{base}{CALS}/{run}/views/0/overlay.png"));
    let body = String::from_utf8_lossy(&body);
    count += 1;
    if code != 500 || !body.contains("000.mask.png") || body.contains("panicked") {
        failures.push(format!("overlay of a resized mask: {code} {body}"));
    }

    println!("{count} daemon bad-input cases, {} failed", failures.len());
    assert!(count >= 25, "only {count} cases");
    assert!(
        failures.is_empty(),
        "{} failures in {count} cases:\n{}",
        failures.len(),
        failures.join("\n")
    );
}
