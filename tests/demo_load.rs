//! The demo under load: the simulator (on a thread of its own, paced by its deadlines)
//! and the gateway keep their pace with a browser rendering the live view and two threads
//! spinning on both CPUs. Its own test binary, so that nothing else of the suite runs
//! beside it.

#[path = "support/python.rs"]
mod python;

use std::io::Write;
use std::process::{Command, Stdio};

/// The demo keeps its pace on a loaded machine: ten runs of `flowgate demo --view`, each
/// with the page open in headless Chromium, beside two threads that spin on both of this
/// machine's CPUs all along. Every run reaches its goal without contact.
#[test]
fn the_demo_reaches_its_goal_ten_times_in_ten_under_load() {
    use std::io::BufRead;
    use std::sync::atomic::{AtomicBool, Ordering};
    use std::sync::Arc;
    let dir = std::env::temp_dir().join(format!("flowgate-view-load-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let addr = std::net::TcpListener::bind("127.0.0.1:0").unwrap().local_addr().unwrap();
    let python = python::python();
    let mut browser = Command::new(python)
        .arg(python::peer("demo_load"))
        .arg(format!("http://{addr}/"))
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .spawn()
        .unwrap();
    let mut to_browser = browser.stdin.take().unwrap();
    let mut from_browser = std::io::BufReader::new(browser.stdout.take().unwrap()).lines();
    assert_eq!(from_browser.next().unwrap().unwrap(), "ready");
    let spinning = Arc::new(AtomicBool::new(true));
    let hogs: Vec<_> = (0..2)
        .map(|_| {
            let spinning = spinning.clone();
            std::thread::spawn(move || {
                while spinning.load(Ordering::Relaxed) {
                    std::hint::spin_loop();
                }
            })
        })
        .collect();
    let mut outcomes = Vec::new();
    for run in 1..=10 {
        let demo = Command::new(env!("CARGO_BIN_EXE_flowgate"))
            .args(["demo", "--out", dir.to_str().unwrap(), "--view", &addr.to_string()])
            .stdout(Stdio::piped())
            .spawn()
            .unwrap();
        writeln!(to_browser, "run").unwrap();
        let drawn = from_browser.next().map(|l| l.unwrap_or_default()).unwrap_or_default();
        let out = demo.wait_with_output().unwrap();
        let text = String::from_utf8_lossy(&out.stdout).into_owned();
        let ok = out.status.success() && text.contains("goal reached, no contact");
        let mut said = text.lines().find(|l| l.starts_with("final state")).unwrap_or("").to_string();
        if !ok {
            said += &pace(&dir);
        }
        outcomes.push((run, ok, drawn, said));
    }
    spinning.store(false, Ordering::Relaxed);
    for h in hogs {
        h.join().unwrap();
    }
    drop(to_browser);
    let _ = browser.wait();
    let failed: Vec<_> = outcomes.iter().filter(|o| !o.1 || o.2 != format!("drawn {}", o.0)).collect();
    assert!(failed.is_empty(), "{} of 10 runs failed: {failed:#?}", failed.len());
    let _ = std::fs::remove_dir_all(&dir);
}

/// What a failed run's telemetry says of its pace, to tell a host that stopped running the
/// demo from a fault of its own: the longest wait between two cycles' reads, the last
/// cycle's read (on the gateway's clock, as the events' `t_s`) and the last events.
fn pace(dir: &std::path::Path) -> String {
    let cycles = std::fs::read_to_string(dir.join("cycles.csv")).unwrap_or_default();
    let mut lines = cycles.lines();
    let column = lines.next().and_then(|h| h.split(',').position(|c| c == "rx_ns"));
    let rx: Vec<u64> = match column {
        Some(k) => lines.filter_map(|l| l.split(',').nth(k)?.parse().ok()).collect(),
        None => Vec::new(),
    };
    let longest = rx.windows(2).map(|w| w[1].saturating_sub(w[0])).max().unwrap_or(0);
    let last = rx.last().map_or(f64::NAN, |&ns| ns as f64 * 1e-9);
    let events = std::fs::read_to_string(dir.join("events.jsonl")).unwrap_or_default();
    let latest: Vec<&str> = events.lines().rev().take(3).collect();
    format!(
        "; {} cycles, the longest wait between two {:.1} ms, the last at {last:.3} s; the last events {latest:?}",
        rx.len(),
        longest as f64 / 1e6
    )
}
