//! The daemon's web page in headless Chromium, driven over WebDriver (Debian's `chromium` and
//! `chromium-driver`): open `/?token=…`, click Calibrate, watch the run finish live, see the
//! result with its uncertainty, the overlays and the per-round chart, run a bump check,
//! download every export format, and pick the run again from the history after a newer one to
//! see its overlays; a screenshot goes to `target/daemon-browser.png`. Without Chromium the test fails under CI (`CI=true`) and
//! prints SKIPPED elsewhere.

mod common;

use std::net::TcpListener;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use common::daemon::{
    assert_refused, call, get_bytes, start, wait_final, write_config, write_shipped_config, TOKEN,
};
use serde_json::{json, Value};

fn find(names: &[&str]) -> Option<PathBuf> {
    let path = std::env::var_os("PATH")?;
    for dir in std::env::split_paths(&path) {
        for n in names {
            let p = dir.join(n);
            if p.is_file() {
                return Some(p);
            }
        }
    }
    None
}

/// chromedriver on a free loopback port, killed on drop.
struct Driver {
    child: Child,
    base: String,
}

impl Drop for Driver {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

fn agent() -> ureq::Agent {
    ureq::AgentBuilder::new()
        .timeout_connect(Duration::from_secs(5))
        .timeout_read(Duration::from_secs(60))
        .build()
}

/// One WebDriver command; returns its `value`.
fn wd(method: &str, url: &str, body: Option<Value>) -> Value {
    let req = agent().request(method, url);
    let resp = match body {
        Some(b) => req.send_json(b),
        None => req.call(),
    };
    let resp = match resp {
        Ok(r) => r,
        Err(ureq::Error::Status(code, r)) => {
            panic!(
                "WebDriver {method} {url}: {code} {}",
                r.into_string().unwrap_or_default()
            )
        }
        Err(e) => panic!("WebDriver {method} {url}: {e}"),
    };
    let v: Value = resp.into_json().expect("WebDriver JSON");
    v["value"].clone()
}

fn start_driver(chromedriver: &Path) -> Driver {
    let port = TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port();
    let child = Command::new(chromedriver)
        .arg(format!("--port={port}"))
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("chromedriver starts");
    let driver = Driver {
        child,
        base: format!("http://127.0.0.1:{port}"),
    };
    let t = Instant::now();
    loop {
        if let Ok(r) = agent().get(&format!("{}/status", driver.base)).call() {
            if r.into_json::<Value>()
                .is_ok_and(|v| v["value"]["ready"] == true)
            {
                return driver;
            }
        }
        assert!(
            t.elapsed() < Duration::from_secs(30),
            "chromedriver not ready"
        );
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// Runs `script` in the page (WebDriver execute/sync) and returns its result.
fn js(session: &str, script: &str) -> Value {
    wd(
        "POST",
        &format!("{session}/execute/sync"),
        Some(json!({ "script": script, "args": [] })),
    )
}

/// Whether JavaScript would count `v` as true. Scripts end in `a && b && value`, which
/// yields the first false operand, so an empty text or a zero must mean "not yet" as
/// `null` and `false` do; otherwise a wait returns while the page is still filling in.
fn is_truthy(v: &Value) -> bool {
    match v {
        Value::Null | Value::Bool(false) => false,
        Value::String(s) => !s.is_empty(),
        Value::Number(n) => n.as_f64().is_some_and(|x| x != 0.0 && !x.is_nan()),
        _ => true,
    }
}

/// Polls `script` until it yields a value JavaScript counts as true, panicking with the
/// page's text after `timeout`.
fn wait_js(session: &str, script: &str, timeout: Duration, what: &str) -> Value {
    let t = Instant::now();
    loop {
        let v = js(session, script);
        if is_truthy(&v) {
            return v;
        }
        if t.elapsed() > timeout {
            let state = js(session, "return document.body.innerText");
            panic!("{what}: not within {timeout:?}; page text:\n{state}");
        }
        std::thread::sleep(Duration::from_millis(100));
    }
}

/// Standard base64 decoding (the screenshot), without a dependency for it.
fn base64_decode(s: &str) -> Vec<u8> {
    let val = |c: u8| -> Option<u32> {
        Some(match c {
            b'A'..=b'Z' => u32::from(c - b'A'),
            b'a'..=b'z' => u32::from(c - b'a') + 26,
            b'0'..=b'9' => u32::from(c - b'0') + 52,
            b'+' => 62,
            b'/' => 63,
            _ => return None,
        })
    };
    let mut out = Vec::with_capacity(s.len() * 3 / 4);
    let (mut acc, mut bits) = (0u32, 0);
    for c in s.bytes().filter_map(val) {
        acc = (acc << 6) | c;
        bits += 6;
        if bits >= 8 {
            bits -= 8;
            out.push((acc >> bits) as u8);
        }
    }
    out
}

fn screenshot(session: &str, path: &Path) {
    let b64 = wd("GET", &format!("{session}/screenshot"), None);
    let png = base64_decode(b64.as_str().expect("base64 screenshot"));
    std::fs::create_dir_all(path.parent().unwrap()).unwrap();
    std::fs::write(path, &png).unwrap();
    let img = image::load_from_memory(&png).expect("screenshot is a PNG");
    assert!(
        img.width() >= 800,
        "screenshot {}x{}",
        img.width(),
        img.height()
    );
}

/// Chromium and chromedriver, or `None` (and SKIPPED) outside CI.
fn browser() -> Option<(PathBuf, PathBuf)> {
    let chromium = find(&["chromium", "chromium-browser", "google-chrome"]);
    let chromedriver = find(&["chromedriver"]);
    let (Some(chromium), Some(chromedriver)) = (chromium, chromedriver) else {
        if std::env::var("CI").is_ok_and(|v| v == "true" || v == "1") {
            panic!("chromium and chromedriver are required under CI: apt-get install chromium chromium-driver");
        }
        eprintln!("SKIPPED: chromium / chromedriver not installed (apt-get install chromium chromium-driver)");
        return None;
    };
    Some((chromium, chromedriver))
}

/// A headless browser session on `driver`: its WebDriver URL.
fn new_session(driver: &Driver, chromium: &Path) -> String {
    let caps = json!({
        "capabilities": { "alwaysMatch": {
            "browserName": "chrome",
            "goog:chromeOptions": {
                "binary": chromium.to_string_lossy(),
                "args": ["--headless=new", "--no-sandbox", "--disable-gpu",
                         "--disable-dev-shm-usage", "--window-size=1400,1200"]
            }
        }}
    });
    let created = wd("POST", &format!("{}/session", driver.base), Some(caps));
    format!(
        "{}/session/{}",
        driver.base,
        created["sessionId"].as_str().expect("a session id")
    )
}

/// Runs `steps` in a browser session on `base`'s page, closing the session and the driver
/// whatever happens.
fn with_page(chromium: &Path, chromedriver: &Path, steps: impl FnOnce(&str)) {
    let driver = start_driver(chromedriver);
    let session = new_session(&driver, chromium);
    let result = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| steps(&session)));
    let _ = agent().delete(&session).call();
    drop(driver);
    if let Err(e) = result {
        std::panic::resume_unwind(e);
    }
}

/// Opens the page with the token in the address and waits for it to show.
fn open_page(session: &str, base: &str) {
    wd(
        "POST",
        &format!("{session}/url"),
        Some(json!({ "url": format!("{base}/?token={TOKEN}") })),
    );
    wait_js(
        session,
        "return !document.getElementById('app').hidden && document.getElementById('start') !== null",
        Duration::from_secs(20),
        "the page",
    );
}

#[test]
fn web_page_calibrates_with_one_click_and_shows_the_result() {
    let Some((chromium, chromedriver)) = browser() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    // Reads need the token too, so a wrong one shows on the first refresh.
    let config = write_config(dir.path(), |c| c.daemon.protect_reads = true);
    let d = start(&config, &dir.path().join("data"));
    with_page(&chromium, &chromedriver, |session| {
        let session = session.to_string();
        // A wrong token is refused and the page asks for one.
        wd(
            "POST",
            &format!("{session}/url"),
            Some(json!({ "url": format!("{}/?token=wrong", d.base) })),
        );
        wait_js(
            &session,
            "return !document.getElementById('login').hidden",
            Duration::from_secs(20),
            "the login form after a wrong token",
        );
        // The token in the address: stored for the tab and removed from the address bar.
        open_page(&session, &d.base);
        let url = js(&session, "return window.location.href");
        assert!(!url.as_str().unwrap().contains("token"), "{url}");
        previews_the_camera(&session);
        let dry = draws_a_dry_runs_plan_without_moving(&session, &d);
        click(&session, "#start");
        // Live progress: the new run shows running, then succeeded.
        let this_run =
            format!("document.getElementById('cal-id').textContent.split(' ')[0] !== '{dry}'");
        wait_js(
            &session,
            &format!("const s = document.getElementById('state').textContent; return {this_run} && (s === 'running' || s === 'succeeded')"),
            Duration::from_secs(20),
            "the run starting",
        );
        let id = wait_js(
            &session,
            &format!("return {this_run} && document.getElementById('state').textContent === 'succeeded' && document.getElementById('cal-id').textContent"),
            Duration::from_secs(120),
            "the run finishing",
        );
        let id = id.as_str().unwrap().to_string();
        // The result with its uncertainty, and the overlays loaded.
        let shown = wait_js(
            &session,
            "const r = document.getElementById('result-id').textContent; return r && !document.getElementById('result-body').hidden && r",
            Duration::from_secs(20),
            "the active result",
        );
        assert_eq!(shown.as_str(), Some(id.as_str()));
        let unc = js(
            &session,
            "return document.getElementById('unc-rot').textContent",
        );
        assert!(unc.as_str().unwrap().contains('°'), "{unc}");
        let centre = js(
            &session,
            "return document.getElementById('unc-centre').textContent",
        );
        assert!(centre.as_str().unwrap().starts_with("within "), "{centre}");
        // Which term sets the figures, with the statistical term's own bound beside it.
        let dominant = js(
            &session,
            "return document.getElementById('unc-dominant').textContent",
        );
        let dominant = dominant.as_str().unwrap();
        assert!(
            ["statistical (", "inter-view (", "model floor ("]
                .iter()
                .any(|t| dominant.starts_with(t))
                && dominant.contains("statistical ")
                && dominant.ends_with(" mm)"),
            "{dominant}"
        );
        let matrix = js(
            &session,
            "return document.getElementById('matrix').textContent",
        );
        assert_eq!(matrix.as_str().unwrap().lines().count(), 4, "{matrix}");
        let loaded = wait_js(
            &session,
            "const imgs = [...document.querySelectorAll('#overlays img')]; return imgs.length >= 3 && imgs.every(i => i.complete && i.naturalWidth === 320) && imgs.length",
            Duration::from_secs(30),
            "the overlays",
        );
        let views = d.daemon.store().record(&id).unwrap().views;
        assert_eq!(loaded.as_u64(), Some(views as u64));
        // History lists it; a bump check reports the camera in place.
        let history = js(
            &session,
            "return document.getElementById('history').textContent",
        );
        assert!(history.as_str().unwrap().contains(&id), "{history}");
        click(&session, "#check");
        wait_js(
            &session,
            "return document.getElementById('check-verdict').textContent === 'camera has not moved'",
            Duration::from_secs(30),
            "the bump check verdict",
        );
        // The chart has a point per solved round.
        let points = wait_js(
            &session,
            "const n = Number(document.getElementById('chart').dataset.points); return n >= 1 && n",
            Duration::from_secs(10),
            "the chart",
        );
        assert!(points.as_u64().unwrap() >= 1, "{points}");
        downloads_every_export_format(&session, &d, &id);
        let target = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("target/daemon-browser.png");
        screenshot(&session, &target);
        eprintln!("screenshot: {}", target.display());
        shows_a_past_runs_overlays(&session, &d, &id, views);
    });
}

/// A cell of several cameras: one click calibrates every camera, the page lists each camera
/// with its active calibration, draws every camera's views at that camera's size, fetches
/// every camera's downloads, and a bump check gives one verdict over all cameras.
#[test]
fn web_page_follows_every_camera_of_a_list() {
    let Some((chromium, chromedriver)) = browser() else {
        return;
    };
    let dir = tempfile::tempdir().unwrap();
    let config = write_shipped_config(dir.path(), "sim-xarm6-three-cameras.toml");
    let d = start(&config, &dir.path().join("data"));
    with_page(&chromium, &chromedriver, |session| {
        open_page(session, &d.base);
        previews_every_camera(session);
        draws_every_cameras_plan(session, &d);
        click(session, "#start");
        let rows = wait_js(
            session,
            "const rows = [...document.querySelectorAll('#cameras tr')]; return rows.length === 3 && rows.every(r => r.children[1].textContent.startsWith('cal-') && r.children[2].textContent === 'fits') && rows.map(r => r.dataset.camera).join(',')",
            Duration::from_secs(120),
            "every camera's active calibration",
        );
        assert_eq!(rows.as_str(), Some("front,side,high"));
        assert!(js(
            session,
            "return document.getElementById('result-body').hidden"
        )
        .as_bool()
        .unwrap());
        let id = d.daemon.store().active_all()[0].id.clone();
        let views = d.daemon.store().record(&id).unwrap().views;
        let sizes = wait_js(
            session,
            &format!("const imgs = [...document.querySelectorAll('#overlays img')]; return imgs.length === {} && imgs.every(i => i.complete && i.naturalWidth > 0) && [...new Set(imgs.map(i => i.alt.split(' ')[0] + ' ' + i.naturalWidth))].sort().join(',')", views * 3),
            Duration::from_secs(60),
            "every camera's overlays",
        );
        assert_eq!(sizes.as_str(), Some("front 640,high 512,side 800"));
        // One row of downloads per camera; every button fetches its camera's file.
        js(
            session,
            "document.querySelectorAll('#downloads button').forEach(b => b.click()); return true",
        );
        let fetched = wait_js(
            session,
            "const b = [...document.querySelectorAll('#downloads button')]; return b.length === 15 && b.every(x => x.dataset.status === '200' && Number(x.dataset.bytes) > 0) && [...document.querySelectorAll('#downloads > div')].map(r => r.dataset.camera).join(',')",
            Duration::from_secs(30),
            "every camera's downloads",
        );
        assert_eq!(fetched.as_str(), Some("front,side,high"));
        click(session, "#check");
        wait_js(
            session,
            "return document.getElementById('check-verdict').textContent === 'no camera has moved'",
            Duration::from_secs(60),
            "the bump check verdict",
        );
        let checked = wait_js(
            session,
            "const rows = [...document.querySelectorAll('#cameras tr')]; return rows.every(r => r.children[4].textContent.includes('not moved')) && rows.length",
            Duration::from_secs(20),
            "each camera's last check",
        );
        assert_eq!(checked.as_u64(), Some(3));
    });
}

/// Clicks every download button: each fetch succeeds, and the daemon's file is exactly what
/// `easyhec export` writes for that result.
fn downloads_every_export_format(session: &str, d: &common::daemon::Running, id: &str) {
    let formats = easyhec::interop::ExportFormat::ALL.map(easyhec::interop::ExportFormat::name);
    for format in &formats {
        click(
            session,
            &format!("#downloads button[data-format='{format}']"),
        );
    }
    wait_js(
        session,
        "return [...document.querySelectorAll('#downloads button')].every(b => b.dataset.status === '200' && Number(b.dataset.bytes) > 0)",
        Duration::from_secs(20),
        "every download",
    );
    let record = d.daemon.store().record(id).unwrap();
    let run_dir = d.daemon.store().dir().join(&record.run_dir);
    let result = easyhec::run::ResultFile::read(&run_dir.join("result.json")).unwrap();
    let edge = easyhec::daemon::exports::edge(None, &result).unwrap();
    for format in &formats {
        let (code, _, body) = get_bytes(&format!(
            "{}/api/v1/calibrations/{id}/export/{format}",
            d.base
        ));
        assert_eq!(code, 200, "{format}");
        let kind =
            <easyhec::interop::ExportFormat as clap::ValueEnum>::from_str(format, false).unwrap();
        let want = easyhec::interop::export(&result, kind, &edge).unwrap();
        assert_eq!(String::from_utf8(body).unwrap(), want, "{format}");
    }
    let (code, _, body) = get_bytes(&format!("{}/api/v1/calibrations/{id}/export/yaml", d.base));
    assert_eq!(code, 400, "{}", String::from_utf8_lossy(&body));
    // A cell of one camera has no camera to pick.
    let url = format!(
        "{}/api/v1/calibrations/{id}/export/urdf?camera=front",
        d.base
    );
    assert_refused("GET", &url, None, "one [camera] table");
}

/// After a newer (dry) run, picking the first run in the history shows its overlays again.
fn shows_a_past_runs_overlays(session: &str, d: &common::daemon::Running, id: &str, views: usize) {
    let (code, body) = call(
        "POST",
        &format!("{}/api/v1/calibrations", d.base),
        Some(&json!({"dry_run": true})),
    );
    assert_eq!(code, 202, "{body}");
    let newer = body["id"].as_str().unwrap().to_string();
    wait_final(&d.base, &newer);
    wait_js(
        session,
        &format!("return document.getElementById('cal-id').textContent.startsWith('{newer}')"),
        Duration::from_secs(30),
        "the newer run on the page",
    );
    // In one script: the history table is rebuilt every 5 s, so a found element can go stale
    // before a separate click reaches it.
    js(
        session,
        &format!(
            "document.querySelector(\"#history button[data-id='{id}']\").click(); return true"
        ),
    );
    let loaded = wait_js(
        session,
        &format!("const imgs = [...document.querySelectorAll('#overlays img')]; return document.getElementById('cal-id').textContent.startsWith('{id}') && imgs.length >= 1 && imgs.every(i => i.complete && i.naturalWidth === 320) && imgs.length"),
        Duration::from_secs(30),
        "the past run's overlays",
    );
    assert_eq!(loaded.as_u64(), Some(views as u64));
    // It stays shown across the page's periodic refresh.
    std::thread::sleep(Duration::from_secs(6));
    let still = js(
        session,
        "return document.getElementById('cal-id').textContent",
    );
    assert!(still.as_str().unwrap().starts_with(id), "{still}");
}

/// Clicks `selector` (the first match).
fn click(session: &str, selector: &str) {
    let found = wd(
        "POST",
        &format!("{session}/element"),
        Some(json!({ "using": "css selector", "value": selector })),
    );
    let element = found
        .as_object()
        .and_then(|o| o.values().next())
        .and_then(Value::as_str)
        .unwrap_or_else(|| panic!("no {selector}: {found}"))
        .to_string();
    wd(
        "POST",
        &format!("{session}/element/{element}/click"),
        Some(json!({})),
    );
}

/// "Preview camera" shows a live frame at the camera's size.
fn previews_the_camera(session: &str) {
    click(session, "#preview-button");
    wait_js(
        session,
        "const i = document.getElementById('preview'); return !!i && i.complete && i.naturalWidth === 320",
        Duration::from_secs(20),
        "the camera preview",
    );
}

/// In a list, "Preview camera" shows one live frame per camera, each at its own size.
fn previews_every_camera(session: &str) {
    click(session, "#preview-button");
    let sizes = wait_js(
        session,
        "const imgs = [...document.querySelectorAll('#previews img')]; return imgs.length === 3 && imgs.every(i => i.complete && i.naturalWidth > 0) && imgs.map(i => i.dataset.camera + ' ' + i.naturalWidth).join(',')",
        Duration::from_secs(30),
        "every camera's preview",
    );
    assert_eq!(sizes.as_str(), Some("front 640,side 800,high 512"));
}

/// In a list, a dry run's planned poses are drawn over every camera's first view, each under
/// that camera's estimate (a camera without one would give no image), and nothing moves.
fn draws_every_cameras_plan(session: &str, d: &common::daemon::Running) {
    let arm = d.daemon.cell().sim_arm().unwrap();
    let before = arm.commands().len();
    click(session, "#dry-run");
    click(session, "#start");
    let drawn = wait_js(
        session,
        "const imgs = [...document.querySelectorAll('#overlays img')].filter(i => i.dataset.key.includes('/plan-')); \
         return document.getElementById('state').textContent === 'succeeded' && imgs.length > 0 \
         && imgs.every(i => i.complete && i.naturalWidth > 0) \
         && [...new Set(imgs.map(i => i.dataset.key.split('/')[0] + ' ' + i.naturalWidth))].join(',') + ' ' + imgs.length",
        Duration::from_secs(60),
        "every camera's planned poses",
    );
    let planned = d
        .daemon
        .store()
        .records()
        .iter()
        .find(|r| r.dry_run)
        .and_then(|r| r.planned_poses)
        .unwrap();
    assert_eq!(
        drawn.as_str().map(str::to_string),
        Some(format!("front 640,side 800,high 512 {}", 3 * planned))
    );
    assert_eq!(arm.commands().len(), before, "a dry run moved the arm");
    click(session, "#dry-run");
}

/// With "dry run" ticked, Calibrate plans and draws each planned pose over the first view,
/// and the arm receives no command.
fn draws_a_dry_runs_plan_without_moving(session: &str, d: &common::daemon::Running) -> String {
    let arm = d.daemon.cell().sim_arm().unwrap();
    let before = arm.commands().len();
    click(session, "#dry-run");
    click(session, "#start");
    let drawn = wait_js(
        session,
        "const imgs = [...document.querySelectorAll('#overlays img')].filter(i => i.dataset.key.startsWith('plan-')); \
         return document.getElementById('state').textContent === 'succeeded' && imgs.length > 0 \
         && imgs.every(i => i.complete && i.naturalWidth === 320) && imgs.length",
        Duration::from_secs(60),
        "the planned poses",
    );
    let id = js(
        session,
        "return document.getElementById('cal-id').textContent",
    );
    let id = id
        .as_str()
        .unwrap()
        .split_whitespace()
        .next()
        .unwrap()
        .to_string();
    let record = d.daemon.store().record(&id).unwrap();
    assert!(record.dry_run, "{record:?}");
    assert_eq!(drawn.as_u64(), record.planned_poses.map(|n| n as u64));
    assert_eq!(arm.commands().len(), before, "a dry run moved the arm");
    click(session, "#dry-run");
    let ticked = js(session, "return document.getElementById('dry-run').checked");
    assert_eq!(ticked, json!(false));
    id
}
