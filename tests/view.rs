//! The live view in a real browser, in a room: `flowgate demo --view ADDR` serves the page
//! while the robot drives through the doorway scenario; headless Chromium (Debian's, driven
//! through chromedriver by Selenium) loads it, sees the robot marker move, the state, the
//! obstacle with its planning circle, the streamlines, the room's walls and view's edge and
//! the latency histogram, and takes a screenshot. The page's JSON frame and its refusals are
//! checked over plain HTTP too. The same run serves Foxglove live and records to MCAP: an
//! independent Foxglove client and Python's `mcap` reader each decode the room from
//! `/arena` (`foxglove.SceneUpdate`). A fleet's run is drawn vehicle by vehicle, each named,
//! in the browser, through Foxglove live and in the recording, which replays byte for byte.

#[path = "support/python.rs"]
mod python;

use std::io::{Read, Write};
use std::path::Path;
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

/// Whether `p` is inside the polygon (crossings of a ray to +x).
fn inside(polygon: &[[f64; 2]], p: [f64; 2]) -> bool {
    let mut inside = false;
    for (k, a) in polygon.iter().enumerate() {
        let b = polygon[(k + 1) % polygon.len()];
        if (a[1] > p[1]) != (b[1] > p[1]) && p[0] < a[0] + (p[1] - a[1]) / (b[1] - a[1]) * (b[0] - a[0]) {
            inside = !inside;
        }
    }
    inside
}

/// A browser peer (`tests/peers/view.py ARGS`) started and up: it says "ready" with its
/// browser running, and waits for the view itself.
fn start_browser(args: &[&str]) -> (std::process::Child, std::io::BufReader<std::process::ChildStdout>) {
    let mut browser = python::niced(&python::python())
        .arg(python::peer("view"))
        .args(args)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    let mut out = std::io::BufReader::new(browser.stdout.take().unwrap());
    let mut ready = String::new();
    std::io::BufRead::read_line(&mut out, &mut ready).unwrap();
    if ready.trim() != "ready" {
        let mut err = String::new();
        browser.stderr.take().unwrap().read_to_string(&mut err).unwrap();
        panic!("the browser did not start: {ready}{err}");
    }
    (browser, out)
}

/// What the browser peer saw, once it is done; it must have seen no failure.
fn browser_said(
    mut browser: std::process::Child,
    mut out: std::io::BufReader<std::process::ChildStdout>,
) -> serde_json::Value {
    let mut stdout = Vec::new();
    out.read_to_end(&mut stdout).unwrap();
    let mut stderr = String::new();
    browser.stderr.take().unwrap().read_to_string(&mut stderr).unwrap();
    let status = browser.wait().unwrap();
    let seen: serde_json::Value =
        serde_json::from_slice(&stdout).unwrap_or_else(|_| panic!("{}{stderr}", String::from_utf8_lossy(&stdout)));
    assert!(status.success() && seen["failures"].as_array().unwrap().is_empty(), "{seen}");
    seen
}

/// `flowgate demo` of `scenario` into `dir`, serving the view on `view` and Foxglove on
/// `foxglove`, recording to `recording`; its output piped.
fn start_demo(
    scenario: &Path,
    dir: &Path,
    view: std::net::SocketAddr,
    foxglove: std::net::SocketAddr,
    recording: &Path,
) -> std::process::Child {
    Command::new(env!("CARGO_BIN_EXE_flowgate"))
        .args(["demo", "--scenario", scenario.to_str().unwrap(), "--out", dir.to_str().unwrap()])
        .args(["--view", &view.to_string(), "--foxglove", &foxglove.to_string()])
        .args(["--record", recording.to_str().unwrap()])
        .stdout(Stdio::piped())
        .spawn()
        .unwrap()
}

/// A free port on loopback.
fn free_port() -> std::net::SocketAddr {
    std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap()
}

#[test]
fn the_live_view_foxglove_and_the_recording_draw_the_run_and_its_room() {
    let dir = std::env::temp_dir().join(format!("flowgate-view-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let addr = free_port();
    // The browser first: Chromium takes seconds to start on a loaded machine, and the demo
    // lasts nine. The script says "ready" with its browser up, then waits for the view.
    let python = python::python();
    let shot = std::env::var("FLOWGATE_VIEW_SCREENSHOT").unwrap_or_else(|_| dir.join("view.png").display().to_string());
    let (browser, browser_out) = start_browser(&[&format!("http://{addr}/"), &shot]);
    let doorway = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/rooms/doorway.toml");
    let recording = dir.join("run.mcap");
    let foxglove = free_port();
    let mut demo = start_demo(&doorway, &dir, addr, foxglove, &recording);
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
    // The doorway's two walls as the scenario gives them, then the view's edge (a loop
    // around the start and the goal); no lane.
    assert!(body["lane_half_width"].is_null(), "{body}");
    let room = body["room"].as_array().unwrap();
    let kinds: Vec<_> = room.iter().map(|r| (r["kind"].as_str().unwrap(), r["closed"].as_bool().unwrap())).collect();
    assert_eq!(kinds, [("wall", false), ("wall", false), ("view", true)], "{body}");
    assert_eq!(room[0]["points"], serde_json::json!([[0.0, -1.0], [0.0, -0.175]]));
    assert_eq!(room[1]["points"], serde_json::json!([[0.0, 0.175], [0.0, 1.0]]));
    let view_edge: Vec<[f64; 2]> = serde_json::from_value(room[2]["points"].clone()).unwrap();
    assert!(inside(&view_edge, [-0.5, 0.35]) && inside(&view_edge, [0.5, -0.35]), "{view_edge:?}");

    // Foxglove live, while the robot drives: the room in `/arena`, as the page has it.
    let seen_live = python::niced(&python)
        .arg(python::peer("foxglove"))
        .args([&format!("ws://{foxglove}"), "25", "/arena"])
        .output()
        .unwrap();
    let live: serde_json::Value = serde_json::from_slice(&seen_live.stdout)
        .unwrap_or_else(|_| panic!("{}", String::from_utf8_lossy(&seen_live.stderr)));
    let live_rooms: Vec<&serde_json::Value> = live["messages"]["/arena"]
        .as_array()
        .unwrap()
        .iter()
        .flat_map(|a| a["entities"].as_array().unwrap())
        .filter(|e| e["id"] == "room")
        .collect();
    assert!(!live_rooms.is_empty(), "no room in 25 /arena updates: {live}");
    let live_lines = live_rooms[0]["lines"].as_array().unwrap();
    assert_eq!(live_lines.len(), 3, "{}", live_rooms[0]);
    assert_eq!(live_lines[2]["type"], "LINE_LOOP");
    for (line, item) in live_lines.iter().zip(room) {
        let drawn: Vec<[f64; 2]> = line["points"]
            .as_array()
            .unwrap()
            .iter()
            .map(|p| [p["x"].as_f64().unwrap_or(0.0), p["y"].as_f64().unwrap_or(0.0)])
            .collect();
        let page: Vec<[f64; 2]> = serde_json::from_value(item["points"].clone()).unwrap();
        assert_eq!(drawn.len(), page.len());
        assert!(drawn.iter().zip(&page).all(|(a, b)| (a[0] - b[0]).abs() < 1e-4 && (a[1] - b[1]).abs() < 1e-4));
    }
    assert!(get(addr, "POST / HTTP/1.1").unwrap().starts_with("HTTP/1.1 405"), "the view takes no commands");
    assert!(get(addr, "GET /arm HTTP/1.1").unwrap().starts_with("HTTP/1.1 404"));

    let seen = browser_said(browser, browser_out);
    let (x0, x1) = (seen["first"][0].as_f64().unwrap(), seen["second"][0].as_f64().unwrap());
    assert!(x1 - x0 > 0.02, "the robot marker moved {x0} -> {x1}: {seen}");
    assert_eq!(seen["obstacles"], 1);
    // The page draws the room: two walls as lines, the view's edge as a loop.
    let drawn: Vec<(&str, &str, u64)> = seen["room"]
        .as_array()
        .unwrap()
        .iter()
        .map(|r| (r["tag"].as_str().unwrap(), r["kind"].as_str().unwrap(), r["points"].as_u64().unwrap()))
        .collect();
    assert_eq!(drawn, [("polyline", "wall", 2), ("polyline", "wall", 2), ("polygon", "view", 4)], "{seen}");
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

    // The recording, read by Python's `mcap`: the room in `/arena` about once a second
    // (Foxglove keeps it between), the same lines as the page's.
    let out = Command::new(&python).arg(python::peer("replay")).arg("room").arg(&recording).output().unwrap();
    let recorded: serde_json::Value =
        serde_json::from_slice(&out.stdout).unwrap_or_else(|_| panic!("{}", String::from_utf8_lossy(&out.stderr)));
    let (updates, with_room) = (recorded["updates"].as_u64().unwrap(), recorded["with_room"].as_u64().unwrap());
    assert!(updates > 50 && with_room >= updates / 12, "{recorded}");
    assert_eq!(recorded["frame_id"], "floor");
    let types: Vec<_> = recorded["lines"].as_array().unwrap().iter().map(|l| l["type"].as_str().unwrap()).collect();
    assert_eq!(types, ["LINE_STRIP", "LINE_STRIP", "LINE_LOOP"], "{recorded}");
    for (line, item) in recorded["lines"].as_array().unwrap().iter().zip(room) {
        let drawn: Vec<[f64; 2]> = serde_json::from_value(line["points"].clone()).unwrap();
        let page: Vec<[f64; 2]> = serde_json::from_value(item["points"].clone()).unwrap();
        assert!(drawn.iter().zip(&page).all(|(a, b)| (a[0] - b[0]).abs() < 1e-4 && (a[1] - b[1]).abs() < 1e-4));
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// A fleet (E5 with its crossing obstacle a scripted vehicle): the page draws the crossing
/// vehicle, named, moving and with its distance from its script; Foxglove live and the
/// recording carry its pose on `/crossing/pose`, its numbers on `/vehicles` and its name over
/// it in `/arena`; the recording replays to the same CAN frames, byte for byte.
#[test]
fn a_fleets_run_is_drawn_vehicle_by_vehicle_live_and_in_the_recording() {
    let dir = std::env::temp_dir().join(format!("flowgate-view-fleet-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let addr = free_port();
    let python = python::python();
    let shot = dir.join("fleet.png");
    let (browser, browser_out) =
        start_browser(&["--fleet", &format!("http://{addr}/"), shot.to_str().unwrap(), "crossing"]);
    let e5 = Path::new(env!("CARGO_MANIFEST_DIR")).join("scenarios/fleet/e5-scripted.toml");
    let recording = dir.join("run.mcap");
    let foxglove = free_port();
    let mut demo = start_demo(&e5, &dir, addr, foxglove, &recording);

    let seen_live = python::niced(&python)
        .arg(python::peer("foxglove"))
        .args([&format!("ws://{foxglove}"), "10", "/arena", "/crossing/pose", "/vehicles"])
        .output()
        .unwrap();
    let live: serde_json::Value = serde_json::from_slice(&seen_live.stdout)
        .unwrap_or_else(|_| panic!("{}", String::from_utf8_lossy(&seen_live.stderr)));
    let names: std::collections::BTreeSet<&str> = live["messages"]["/arena"]
        .as_array()
        .unwrap()
        .iter()
        .flat_map(|a| a["entities"].as_array().unwrap())
        .flat_map(|e| e["texts"].as_array().into_iter().flatten())
        .filter_map(|t| t["text"].as_str())
        .collect();
    assert_eq!(names, ["crossing", "robot"].into(), "{live}");
    let poses = live["messages"]["/crossing/pose"].as_array().unwrap();
    assert!(poses.len() >= 10 && poses.iter().all(|p| p["frame_id"] == "floor"), "{live}");
    let listed = &live["messages"]["/vehicles"][0]["vehicles"][0];
    assert_eq!(listed["name"], "crossing", "{live}");

    let page = browser_said(browser, browser_out);
    let running = &page["running"]["crossing"];
    assert_eq!(running["label"], "crossing", "{page}");
    assert!(running["path"].as_u64().unwrap() > 5, "{page}");
    assert!(running["row"].as_str().unwrap().contains("mm off its script"), "{page}");
    let last = &page["final"]["crossing"];
    assert_eq!(last["state"], "stopped", "{page}");

    let status = demo.wait().unwrap();
    let mut text = String::new();
    demo.stdout.take().unwrap().read_to_string(&mut text).unwrap();
    assert!(status.success() && text.contains("at its script's end"), "{text}");

    // The recording, read by Python's `mcap`: the crossing vehicle's states in order, its
    // poses down its script (from (-0.08, 0.2), 7 cm/s toward -y), within 5 cm of it.
    let out = Command::new(&python).arg(python::peer("replay")).arg("vehicles").arg(&recording).output().unwrap();
    let recorded: serde_json::Value =
        serde_json::from_slice(&out.stdout).unwrap_or_else(|_| panic!("{}", String::from_utf8_lossy(&out.stderr)));
    let crossing = &recorded["vehicles"]["crossing"];
    assert_eq!(crossing["states"][0], "idle", "{recorded}");
    assert!(crossing["states"].as_array().unwrap().iter().any(|s| s == "running"), "{recorded}");
    assert_eq!(crossing["states"].as_array().unwrap().last().unwrap(), "stopped", "{recorded}");
    let error = crossing["script_error"].as_f64().unwrap();
    assert!(error > 0.0 && error < 0.05, "{recorded}");
    let [first, last] =
        [&crossing["first"], &crossing["last"]].map(|p| [p[0].as_f64().unwrap(), p[1].as_f64().unwrap()]);
    assert!((first[0] + 0.08).abs() < 0.02 && (first[1] - 0.2).abs() < 0.02, "{recorded}");
    assert!((last[0] + 0.08).abs() < 0.05 && last[1] < first[1] - 0.3, "{recorded}");
    assert!(crossing["poses"].as_u64().unwrap() > 50, "{recorded}");
    assert_eq!(recorded["pose_frames"], serde_json::json!(["floor"]));
    assert_eq!(recorded["arena_names"], serde_json::json!(["crossing", "robot"]));

    let replay = Command::new(env!("CARGO_BIN_EXE_flowgate")).arg("replay").arg(&recording).output().unwrap();
    let said = String::from_utf8_lossy(&replay.stdout);
    assert!(replay.status.success() && said.contains("identical, byte for byte"), "{said}");
    let _ = std::fs::remove_dir_all(&dir);
}
