//! The live view in a real browser: `flowgate demo --view ADDR` serves the page while the
//! robot drives; headless Chromium (Debian's, driven through chromedriver by Selenium) loads
//! it, sees the robot marker move, the state, the obstacle with its planning circle, the
//! streamlines and the latency histogram, and takes a screenshot. The page's JSON frame and
//! its refusals are checked over plain HTTP too.

#[path = "support/python.rs"]
mod python;

use std::io::{Read, Write};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

fn get(addr: std::net::SocketAddr, request: &str) -> Option<String> {
    let mut s = std::net::TcpStream::connect(addr).ok()?;
    s.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
    write!(s, "{request}\r\nHost: localhost\r\n\r\n").unwrap();
    let mut out = String::new();
    s.read_to_string(&mut out).ok()?;
    Some(out)
}

#[test]
fn the_live_view_draws_the_run_in_headless_chromium() {
    let dir = std::env::temp_dir().join(format!("flowgate-view-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let addr = std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap();
    // The browser first: Chromium takes seconds to start on a loaded machine, and the demo
    // lasts nine. The script says "ready" with its browser up, then waits for the view.
    let python = python::python();
    let shot = std::env::var("FLOWGATE_VIEW_SCREENSHOT").unwrap_or_else(|_| dir.join("view.png").display().to_string());
    let mut browser = Command::new(python)
        .arg(python::peer("view"))
        .args([&format!("http://{addr}/"), &shot])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut browser_out = std::io::BufReader::new(browser.stdout.take().unwrap());
    let mut ready = String::new();
    std::io::BufRead::read_line(&mut browser_out, &mut ready).unwrap();
    if ready.trim() != "ready" {
        let mut err = String::new();
        browser.stderr.take().unwrap().read_to_string(&mut err).unwrap();
        panic!("the browser did not start: {ready}{err}");
    }
    let mut demo = Command::new(env!("CARGO_BIN_EXE_flowgate"))
        .args(["demo", "--out", dir.to_str().unwrap(), "--view", &addr.to_string()])
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    // The view answers once the gateway is up (its first frame follows the first scene).
    let started = Instant::now();
    let frame = loop {
        assert!(started.elapsed() < Duration::from_secs(20), "the view never answered on {addr}");
        match get(addr, "GET /frame.json HTTP/1.1") {
            Some(reply) if reply.contains("\"seq\"") => break reply,
            _ => std::thread::sleep(Duration::from_millis(100)), // polling for the port to open
        }
    };
    assert!(frame.starts_with("HTTP/1.1 200 OK") && frame.contains("application/json"), "{frame}");
    let body: serde_json::Value = serde_json::from_str(frame.split_once("\r\n\r\n").unwrap().1).unwrap();
    assert_eq!(body["lane_half_width"], 0.2);
    assert!(get(addr, "POST / HTTP/1.1").unwrap().starts_with("HTTP/1.1 405"), "the view takes no commands");
    assert!(get(addr, "GET /arm HTTP/1.1").unwrap().starts_with("HTTP/1.1 404"));

    let mut stdout = Vec::new();
    browser_out.read_to_end(&mut stdout).unwrap();
    let mut stderr = String::new();
    browser.stderr.take().unwrap().read_to_string(&mut stderr).unwrap();
    let status = browser.wait().unwrap();
    let seen: serde_json::Value =
        serde_json::from_slice(&stdout).unwrap_or_else(|_| panic!("{}{stderr}", String::from_utf8_lossy(&stdout)));
    assert!(status.success() && seen["failures"].as_array().unwrap().is_empty(), "{seen}");
    let (x0, x1) = (seen["first"][0].as_f64().unwrap(), seen["second"][0].as_f64().unwrap());
    assert!(x1 - x0 > 0.02, "the robot marker moved {x0} -> {x1}: {seen}");
    assert_eq!(seen["obstacles"], 1);
    // The final screen against what the gateway reports: its cycle count, and the robot
    // within the goal's tolerance (5 cm) of it.
    let final_ = &seen["final"];
    assert_eq!(final_["link"], "run ended: its last state", "{seen}");
    assert!(final_["goal"].as_f64().unwrap() <= 0.05, "{seen}");
    let png = std::fs::read(&shot).unwrap();
    assert!(png.starts_with(b"\x89PNG") && png.len() > 10_000, "a screenshot of {} bytes", png.len());

    let status = demo.wait().unwrap();
    let mut text = String::new();
    demo.stdout.take().unwrap().read_to_string(&mut text).unwrap();
    assert!(status.success() && text.contains("goal reached, no contact"), "{text}");
    let reported: u64 = text
        .lines()
        .find_map(|l| l.strip_prefix("cycles")?.split_whitespace().next()?.parse().ok())
        .unwrap_or_else(|| panic!("no cycle count in the report: {text}"));
    assert_eq!(final_["cycles"].as_u64(), Some(reported), "the page's count against the report's: {seen}");
    assert_eq!(final_["histogram_cycles"].as_u64(), Some(reported), "{seen}");
    let _ = std::fs::remove_dir_all(&dir);
}
